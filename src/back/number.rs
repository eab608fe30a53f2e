//! Fixed-precision number printing without float formatting on the hot path.

/// Rounds `value` to `decimals` places as an integer count of units (`10^-decimals`).
///
/// Returns `None` when the value does not fit (non-finite, or beyond ±9e15 units).
///
/// ```
/// use ncpost::back::number::to_units;
/// assert_eq!(to_units(1.2345, 3), Some(1235));
/// assert_eq!(to_units(-0.0004, 3), Some(0));
/// ```
pub fn to_units(value: f64, decimals: u8) -> Option<i64> {
    let x = value * POW10[decimals.min(9) as usize];
    // From 2^52 on every f64 is whole, so this is the same test as on the rounded value.
    if !(x.is_finite() && x.abs() < 9e15) {
        return None;
    }
    // `f64::round` (half away from zero) without the libm call: below 2^53 the
    // truncation is exact and so is the fraction left over.
    // The carry is added, not branched on: on coordinates it is a coin toss, and the
    // mispredicted branch stalled every pass that rounds to printed values.
    let whole = x as i64;
    let fraction = x - whole as f64;
    // `fraction >= 0.5` is `fraction - 0.5` not negative (an exact 0.5 gives +0.0), read
    // off the sign bit so that the compiler keeps it arithmetic.
    let up = 1 - ((fraction - 0.5).to_bits() >> 63) as i64;
    let down = 1 - ((-0.5 - fraction).to_bits() >> 63) as i64;
    Some(whole + up - down)
}

/// `value` as the controller reads it when printed at `decimals` places (at most 9):
/// [`to_units`] and back; `None` when it does not fit.
///
/// ```
/// use ncpost::back::number::printed;
/// assert_eq!(printed(1.23456, 3), Some(1.235));
/// assert_eq!(printed(f64::INFINITY, 3), None);
/// ```
#[inline]
pub fn printed(value: f64, decimals: u8) -> Option<f64> {
    to_units(value, decimals).map(|u| from_units(u, decimals))
}

/// The value of `units` at `decimals` places (at most 9): what [`printed`] returns for
/// the value [`to_units`] rounded to them, for a caller that needs both.
///
/// ```
/// use ncpost::back::number::from_units;
/// assert_eq!(from_units(-1235, 3), -1.235);
/// ```
#[inline]
pub fn from_units(units: i64, decimals: u8) -> f64 {
    units as f64 / POW10[usize::from(decimals.min(9))]
}

/// `10^d` for the decimals a number is printed with (at most 9), exact.
const POW10: [f64; 10] = [1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9];

/// Where [`Digits`] ends the number in its buffer.
const DIGITS_END: usize = 24;

/// `00`, `01`, ..., `99`: two digits per division by 100, as itoa does.
const PAIRS: &[u8; 200] = b"0001020304050607080910111213141516171819\
2021222324252627282930313233343536373839\
4041424344454647484950515253545556575859\
6061626364656667686970717273747576777879\
8081828384858687888990919293949596979899";

/// A printed fixed-point number in a buffer with room on both sides, so that a caller can
/// put a letter and a space before it and copy it out in one fixed-size move (no
/// `memcpy` call of a variable length for every word of every line).
pub(crate) struct Digits {
    buf: [u8; 2 * DIGITS_END],
    /// The number is `buf[start..end]`, with `end <= DIGITS_END`.
    start: usize,
    end: usize,
}

/// Writes the two digits of `pair` (below 100) at `buf[i..i + 2]`.
#[inline(always)]
fn put_pair(buf: &mut [u8; 2 * DIGITS_END], i: usize, pair: u32) {
    let p = 2 * pair as usize;
    buf[i..i + 2].copy_from_slice(&PAIRS[p..p + 2]);
}

impl Digits {
    /// `units * 10^-decimals` (decimals at most 9), trailing zeros trimmed when `trim` is
    /// set. The number is at most 22 bytes long (a sign, 20 digits and the point), which
    /// leaves room for two prefixes.
    // Inlined always: called for every word of every line, and out of line it returned
    // its 64 bytes through memory.
    #[inline(always)]
    pub(crate) fn new(units: i64, decimals: u8, trim: bool) -> Digits {
        // One body per precision: the divisor and the number of fraction digits are
        // constants there, so the fraction is straight-line code with no loop counter.
        match decimals {
            0 => Digits::fixed::<0>(units, trim),
            1 => Digits::fixed::<1>(units, trim),
            2 => Digits::fixed::<2>(units, trim),
            3 => Digits::fixed::<3>(units, trim),
            4 => Digits::fixed::<4>(units, trim),
            5 => Digits::fixed::<5>(units, trim),
            6 => Digits::fixed::<6>(units, trim),
            7 => Digits::fixed::<7>(units, trim),
            8 => Digits::fixed::<8>(units, trim),
            _ => Digits::fixed::<9>(units, trim),
        }
    }

    /// [`Digits::new`] at `FRAC` decimals (at most 9).
    #[inline(always)]
    fn fixed<const FRAC: usize>(units: i64, trim: bool) -> Digits {
        let u = units.unsigned_abs();
        let frac = FRAC;
        // Whole and fractional part by a constant divisor (a multiplication), not by a
        // variable power of ten (a 64-bit `div`).
        let p = 10u64.pow(FRAC as u32);
        let (mut whole, fraction) = (u / p, u % p);
        let mut buf = [b'0'; 2 * DIGITS_END];
        let mut i = DIGITS_END;
        let mut end = DIGITS_END;
        if frac > 0 {
            // Below 10^9: 32-bit arithmetic.
            let mut f = fraction as u32;
            let mut left = frac;
            while left >= 2 {
                i -= 2;
                put_pair(&mut buf, i, f % 100);
                f /= 100;
                left -= 2;
            }
            if left == 1 {
                i -= 1;
                buf[i] = b'0' + (f % 10) as u8;
            }
            i -= 1;
            buf[i] = b'.';
            if trim {
                while buf[end - 1] == b'0' {
                    end -= 1;
                }
                if end == i + 1 {
                    end = i;
                }
            }
        }
        // The whole part, at least one digit (the buffer is '0' where nothing is put).
        while whole >= 100 {
            i -= 2;
            put_pair(&mut buf, i, (whole % 100) as u32);
            whole /= 100;
        }
        if whole >= 10 {
            i -= 2;
            put_pair(&mut buf, i, whole as u32);
        } else {
            i -= 1;
            buf[i] = b'0' + whole as u8;
        }
        if units < 0 {
            i -= 1;
            buf[i] = b'-';
        }
        Digits { buf, start: i, end }
    }

    /// Puts `c` (ASCII) just before the number.
    #[inline]
    pub(crate) fn prefix(&mut self, c: u8) {
        self.start -= 1;
        self.buf[self.start] = c;
    }

    /// The number (with its prefixes), ASCII.
    pub(crate) fn as_bytes(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }

    /// Appends the number to `out` with one copy of a fixed size: the whole tail of the
    /// buffer goes in, then `out` is cut back to the number's end.
    #[inline]
    pub(crate) fn append_to(&self, out: &mut Vec<u8>) {
        let len = out.len();
        out.extend_from_slice(&self.buf[self.start..self.start + DIGITS_END]);
        out.truncate(len + self.end - self.start);
    }
}

/// Appends `units * 10^-decimals` to `out`, trimming trailing zeros when `trim` is set
/// (`12.500` → `12.5`, `3.000` → `3`).
///
/// ```
/// use ncpost::back::number::write_units;
/// let mut s = String::new();
/// write_units(&mut s, -1250, 3, true);
/// assert_eq!(s, "-1.25");
/// s.clear();
/// write_units(&mut s, 5, 3, false);
/// assert_eq!(s, "0.005");
/// ```
pub fn write_units(out: &mut String, units: i64, decimals: u8, trim: bool) {
    out.extend(
        Digits::new(units, decimals, trim)
            .as_bytes()
            .iter()
            .map(|&b| char::from(b)),
    );
}

/// Prints `value` at `decimals` places (see [`write_units`]); `false` if it does not fit.
pub fn write_fixed(out: &mut String, value: f64, decimals: u8, trim: bool) -> bool {
    match to_units(value, decimals) {
        Some(u) => {
            write_units(out, u, decimals, trim);
            true
        }
        None => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fmt(v: f64, d: u8, trim: bool) -> String {
        let mut s = String::new();
        assert!(write_fixed(&mut s, v, d, trim));
        s
    }

    #[test]
    fn prints_fixed() {
        assert_eq!(fmt(0.0, 3, true), "0");
        assert_eq!(fmt(-0.0001, 3, true), "0");
        assert_eq!(fmt(10.0, 3, true), "10");
        assert_eq!(fmt(10.0, 3, false), "10.000");
        assert_eq!(fmt(-0.5, 3, true), "-0.5");
        assert_eq!(fmt(123.4567, 3, true), "123.457");
        assert_eq!(fmt(2400.0, 0, true), "2400");
        assert_eq!(fmt(0.00001, 5, true), "0.00001");
    }

    /// What `write_units` prints, by plain formatting of the whole and fractional parts.
    fn units_by_format(units: i64, decimals: u8, trim: bool) -> String {
        let d = u32::from(decimals.min(9));
        let u = u128::from(units.unsigned_abs());
        let p = 10u128.pow(d);
        let sign = if units < 0 { "-" } else { "" };
        let mut s = format!("{sign}{}", u / p);
        if d > 0 {
            let f = format!("{:0width$}", u % p, width = d as usize);
            let f = if trim { f.trim_end_matches('0') } else { &f };
            if !f.is_empty() {
                s.push('.');
                s.push_str(f);
            }
        }
        s
    }

    #[test]
    fn prints_units_at_the_ends_of_the_range() {
        for units in [i64::MIN, i64::MIN + 1, -1, 0, 1, 10, 100, i64::MAX] {
            for d in 0..=10 {
                for trim in [false, true] {
                    let mut s = String::new();
                    write_units(&mut s, units, d, trim);
                    assert_eq!(s, units_by_format(units, d, trim), "{units} {d} {trim}");
                }
            }
        }
    }

    proptest::proptest! {
        /// Any units at any precision print as plain formatting does, and with a letter
        /// and a space put before them and copied out in one go, the same bytes follow
        /// what is already in the line.
        #[test]
        fn units_print_as_plain_formatting_does(
            units in proptest::num::i64::ANY,
            small in -10_000_000i64..10_000_000,
            decimals in 0u8..11,
            trim: bool,
            before in "[ -~]{0,40}",
        ) {
            for u in [units, small] {
                let want = units_by_format(u, decimals, trim);
                let mut s = String::new();
                write_units(&mut s, u, decimals, trim);
                proptest::prop_assert_eq!(&s, &want);
                let mut line = before.clone().into_bytes();
                let mut digits = Digits::new(u, decimals, trim);
                digits.prefix(b'X');
                digits.prefix(b' ');
                digits.append_to(&mut line);
                proptest::prop_assert_eq!(line, format!("{before} X{want}").into_bytes());
            }
        }
    }

    /// The rounding `to_units` stands for.
    fn to_units_by_round(value: f64, decimals: u8) -> Option<i64> {
        let scaled = (value * POW10[decimals.min(9) as usize]).round();
        (scaled.is_finite() && scaled.abs() < 9e15).then_some(scaled as i64)
    }

    #[test]
    fn to_units_rounds_halves_away_from_zero_and_refuses_what_does_not_fit() {
        for (v, d) in [
            (0.5, 0),
            (-0.5, 0),
            (1.5, 0),
            (2.5, 0),
            (-2.5, 0),
            (0.49999999999999994, 0),
            (1.0005, 3),
            (-1.0005, 3),
            (8.999999999999999e15, 0),
            (9e15, 0),
            (-9e15, 0),
            (9.05e15, 0),
            (f64::NAN, 3),
            (f64::INFINITY, 3),
            (4503599627370495.5, 0),
            (-0.0, 3),
        ] {
            assert_eq!(to_units(v, d), to_units_by_round(v, d), "{v:e} at {d}");
        }
    }

    proptest::proptest! {
        /// The same as rounding with `f64::round`, for any finite value and precision.
        #[test]
        fn to_units_equals_f64_round(value in proptest::num::f64::ANY, decimals in 0u8..10) {
            proptest::prop_assert_eq!(to_units(value, decimals), to_units_by_round(value, decimals));
        }

        /// Halves and near-halves at every precision.
        #[test]
        fn to_units_equals_f64_round_near_halves(k in -1_000_000_000i64..1_000_000_000, d in 0u8..6, nudge in proptest::sample::select(vec![-1e-9, 0.0, 1e-9])) {
            let value = (k as f64 + 0.5) / 10f64.powi(d as i32) + nudge;
            proptest::prop_assert_eq!(to_units(value, d), to_units_by_round(value, d));
        }

        /// Every unit count at every precision, trimmed or not: what `format!` prints for
        /// the same decimal.
        #[test]
        fn units_print_as_std_prints_them(units in -9_000_000_000_000_000i64..9_000_000_000_000_000, decimals in 0u8..10, trim: bool) {
            let mut ours = String::new();
            write_units(&mut ours, units, decimals, trim);
            let d = decimals as u32;
            let scale = 10u128.pow(d);
            let abs = units.unsigned_abs() as u128;
            let mut std = format!("{}", abs / scale);
            if d > 0 {
                let frac = format!("{:0width$}", abs % scale, width = d as usize);
                let frac = if trim { frac.trim_end_matches('0').to_string() } else { frac };
                if !frac.is_empty() {
                    std.push('.');
                    std.push_str(&frac);
                }
            }
            if units < 0 {
                std.insert(0, '-');
            }
            proptest::prop_assert_eq!(ours, std);
        }
    }

    #[test]
    fn matches_std_formatting() {
        for i in -20000..20000 {
            let v = i as f64 * 0.0137;
            let ours = fmt(v, 4, false);
            let std = format!("{:.4}", (v * 1e4).round() / 1e4);
            let std = if std == "-0.0000" {
                "0.0000".to_string()
            } else {
                std
            };
            assert_eq!(ours, std, "{v}");
        }
    }
}
