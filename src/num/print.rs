//! Fixed-precision number printing without float formatting on the hot path.

use crate::num::decimal::{POW10_INT, ZEROS};

/// Rounds `value` to `decimals` places as an integer count of units (`10^-decimals`).
///
/// Returns `None` when the value does not fit (non-finite, or beyond ±9e15 units).
///
/// ```
/// use ncpost::num::print::to_units;
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
/// use ncpost::num::print::printed;
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
/// use ncpost::num::print::from_units;
/// assert_eq!(from_units(-1235, 3), -1.235);
/// ```
#[inline]
pub fn from_units(units: i64, decimals: u8) -> f64 {
    units as f64 / POW10[usize::from(decimals.min(9))]
}

/// `10^d` for the decimals a number is printed with (at most 9), exact.
const POW10: [f64; 10] = [1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9];

/// The bytes a number may take while it is built in place: a two-byte lead, a sign, 20
/// digits, the point, 9 decimals, and the slack of the last 8-byte store.
pub(crate) const ROOM: usize = 40;

/// The number of decimal digits of `x` (1 for 0), without a loop or a branch.
#[inline(always)]
fn decimal_len(x: u32) -> usize {
    // `x | 1` has as many digits as `x` (no power of ten is odd) and is never 0.
    let x = x | 1;
    let t = ((32 - x.leading_zeros()) * 1233) >> 12;
    t as usize + 1 - usize::from(u64::from(x) < POW10_INT[t as usize])
}

/// The eight decimal digits of `x` (below 10^8) as byte values 0..=9, the most
/// significant in the lowest byte (first in memory): in registers, by multiplications,
/// so that a number is stored in one move.
#[inline(always)]
fn digit_bytes(x: u32) -> u64 {
    let x = u64::from(x);
    // Four digits per 32-bit lane, then two per 16-bit lane, then one per byte: n / 100
    // is (n * 5243) >> 19 below 43699, n / 10 is (n * 103) >> 10 below 100.
    let v = (x / 10_000) | ((x % 10_000) << 32);
    let hundreds = ((v * 5243) >> 19) & 0x0000_007F_0000_007F;
    let v = hundreds | ((v - hundreds * 100) << 16);
    let tens = ((v * 103) >> 10) & 0x000F_000F_000F_000F;
    tens | ((v - tens * 10) << 8)
}

/// The four decimal digits of `x` (below 10^4) as byte values, like [`digit_bytes`]:
/// most numbers printed have at most four digits before and after the point.
#[inline(always)]
fn digit_bytes4(x: u32) -> u64 {
    let hundreds = (x * 5243) >> 19;
    let v = hundreds | ((x - hundreds * 100) << 16);
    let tens = ((v * 103) >> 10) & 0x000F_000F;
    u64::from(tens | ((v - tens * 10) << 8))
}

/// Stores the eight bytes of `v` at `buf[at..at + 8]`.
#[inline(always)]
fn store8(buf: &mut [u8], at: usize, v: u64) {
    buf[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

/// Puts the digits of `whole` at `buf[at..]` and returns where they end. Bytes after
/// the end may be overwritten (up to 8 past it).
#[inline(always)]
fn put_whole(buf: &mut [u8], at: usize, whole: u64) -> usize {
    if whole < 10_000 {
        let n = decimal_len(whole as u32);
        // Only the low four bytes are digits.
        store8(
            buf,
            at,
            (digit_bytes4(whole as u32) | (ZEROS & 0xFFFF_FFFF)) >> (8 * (4 - n)),
        );
        at + n
    } else if whole < 100_000_000 {
        let n = decimal_len(whole as u32);
        // The leading zeros of the eight digits are shifted out.
        store8(
            buf,
            at,
            (digit_bytes(whole as u32) | ZEROS) >> (8 * (8 - n)),
        );
        at + n
    } else {
        put_long_whole(buf, at, whole)
    }
}

/// [`put_whole`] from 10^8 on: the last eight digits after the others.
#[cold]
#[inline(never)]
fn put_long_whole(buf: &mut [u8], at: usize, whole: u64) -> usize {
    let at = put_whole(buf, at, whole / 100_000_000);
    store8(buf, at, digit_bytes((whole % 100_000_000) as u32) | ZEROS);
    at + 8
}

/// Puts `lead[..lead_len]` (at most two ASCII bytes, such as `" X"`) and
/// `units * 10^-decimals` (decimals at most 9) at the start of `buf` (at least
/// [`ROOM`] bytes, which it may overwrite), trailing zeros trimmed when `trim` is set;
/// returns the length. The number is built where it ends up, with a few
/// whole-register stores: built on the side and copied, its bytes were read back
/// before their narrow stores had landed, and the emitter stalled on every word.
#[inline(always)]
pub(crate) fn put_number(
    buf: &mut [u8],
    lead: [u8; 2],
    lead_len: usize,
    units: i64,
    decimals: u8,
    trim: bool,
) -> usize {
    // One body per precision: the divisor and the number of fraction digits are
    // constants there.
    match decimals {
        0 => put_fixed::<0>(buf, lead, lead_len, units, trim),
        1 => put_fixed::<1>(buf, lead, lead_len, units, trim),
        2 => put_fixed::<2>(buf, lead, lead_len, units, trim),
        3 => put_fixed::<3>(buf, lead, lead_len, units, trim),
        4 => put_fixed::<4>(buf, lead, lead_len, units, trim),
        5 => put_fixed::<5>(buf, lead, lead_len, units, trim),
        6 => put_fixed::<6>(buf, lead, lead_len, units, trim),
        7 => put_fixed::<7>(buf, lead, lead_len, units, trim),
        8 => put_fixed::<8>(buf, lead, lead_len, units, trim),
        _ => put_fixed::<9>(buf, lead, lead_len, units, trim),
    }
}

/// [`put_number`] at `FRAC` decimals (at most 9).
#[inline(always)]
fn put_fixed<const FRAC: usize>(
    buf: &mut [u8],
    lead: [u8; 2],
    lead_len: usize,
    units: i64,
    trim: bool,
) -> usize {
    let u = units.unsigned_abs();
    // A constant divisor: a multiplication, not a 64-bit `div`.
    let p = 10u64.pow(FRAC as u32);
    let (whole, fraction) = (u / p, u % p);
    buf[..2].copy_from_slice(&lead);
    let mut at = lead_len;
    // The sign is always stored and kept only for a negative number.
    buf[at] = b'-';
    at += usize::from(units < 0);
    at = put_whole(buf, at, whole);
    if FRAC > 0 {
        buf[at] = b'.';
        // The fraction's digits, and how many of them are trailing zeros.
        let zeros = if FRAC == 9 {
            let first = (fraction / 100_000_000) as u8;
            let rest = digit_bytes((fraction % 100_000_000) as u32);
            buf[at + 1] = b'0' + first;
            store8(buf, at + 2, rest | ZEROS);
            if rest == 0 {
                8 + usize::from(first == 0)
            } else {
                rest.leading_zeros() as usize / 8
            }
        } else {
            // Below 10^FRAC: the top 8 - FRAC digits are zeros, shifted out.
            let digits = if FRAC <= 4 {
                digit_bytes4(fraction as u32) >> (8 * (4 - FRAC))
            } else {
                digit_bytes(fraction as u32) >> (8 * (8 - FRAC))
            };
            store8(buf, at + 1, digits | ZEROS);
            digits.leading_zeros() as usize / 8 - (8 - FRAC)
        };
        let kept = if trim { FRAC - zeros } else { FRAC };
        // The point goes only with digits after it.
        at += kept + usize::from(kept > 0);
    }
    at
}

/// Appends `units * 10^-decimals` to `out`, trimming trailing zeros when `trim` is set
/// (`12.500` → `12.5`, `3.000` → `3`).
///
/// ```
/// use ncpost::num::print::write_units;
/// let mut s = String::new();
/// write_units(&mut s, -1250, 3, true);
/// assert_eq!(s, "-1.25");
/// s.clear();
/// write_units(&mut s, 5, 3, false);
/// assert_eq!(s, "0.005");
/// ```
pub fn write_units(out: &mut String, units: i64, decimals: u8, trim: bool) {
    let mut buf = [0; ROOM];
    let len = put_number(&mut buf, [0; 2], 0, units, decimals, trim);
    out.extend(buf[..len].iter().map(|&b| char::from(b)));
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
    fn digit_counts_and_digit_bytes_hold_for_every_number_below_10_to_the_8() {
        // Every 997th number and every one next to a power of ten.
        let edges = (0..9).flat_map(|k| {
            let p = 10u32.pow(k);
            [p.saturating_sub(1), p, p + 1]
        });
        for x in (0..100_000_000)
            .step_by(997)
            .chain(edges.filter(|&x| x < 100_000_000))
        {
            let text = x.to_string();
            assert_eq!(decimal_len(x), text.len(), "{x}");
            let want = format!("{x:08}")
                .bytes()
                .map(|b| b - b'0')
                .collect::<Vec<_>>();
            assert_eq!(digit_bytes(x).to_le_bytes().to_vec(), want, "{x}");
        }
        for x in 0..10_000 {
            let want = format!("{x:04}")
                .bytes()
                .map(|b| b - b'0')
                .collect::<Vec<_>>();
            assert_eq!(digit_bytes4(x).to_le_bytes()[..4], want, "{x}");
            assert_eq!(digit_bytes4(x) >> 32, 0, "{x}");
        }
        for x in [
            100_000_000,
            100_000_001,
            999_999_999,
            1_000_000_000,
            u32::MAX,
        ] {
            assert_eq!(decimal_len(x), x.to_string().len(), "{x}");
        }
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
        /// Any units at any precision print as plain formatting does, also after a
        /// letter, with or without a space before it.
        #[test]
        fn units_print_as_plain_formatting_does(
            units in proptest::num::i64::ANY,
            small in -10_000_000i64..10_000_000,
            decimals in 0u8..11,
            trim: bool,
        ) {
            for u in [units, small] {
                let want = units_by_format(u, decimals, trim);
                let mut s = String::new();
                write_units(&mut s, u, decimals, trim);
                proptest::prop_assert_eq!(&s, &want);
                let mut buf = [b'#'; ROOM];
                let len = put_number(&mut buf, *b" X", 2, u, decimals, trim);
                proptest::prop_assert_eq!(&buf[..len], format!(" X{want}").into_bytes());
                let len = put_number(&mut buf, [b'Y', 0], 1, u, decimals, trim);
                proptest::prop_assert_eq!(&buf[..len], format!("Y{want}").into_bytes());
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
