//! Fixed-precision number printing: the one printer of positions, feeds and times.
//!
//! [`Decimals`] says how many digits each kind of value gets; [`to_units`] rounds a value
//! to them as the controller will read it, and [`write_units`] prints it.

use serde::{Deserialize, Serialize};

/// Digits after the decimal point, per kind of value.
///
/// What an axis gets is [`Decimals::axis`] (in the IR, which knows the axes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Decimals {
    /// Linear axes and arc offsets, mm.
    pub linear: u8,
    /// Rotary axes, degrees.
    pub rotary: u8,
    /// The extruder axis, mm.
    pub extruder: u8,
    /// Feed rates.
    pub feed: u8,
}

impl Default for Decimals {
    fn default() -> Self {
        Decimals {
            linear: 3,
            rotary: 3,
            extruder: 5,
            feed: 1,
        }
    }
}

/// Largest relative error of a printed F: a block's time on the controller is its
/// distance over the F it reads, so this is the share of a block's time that printing F
/// may cost (0.1 %, a tenth of the 1 % a block's time must hold).
pub const FEED_RESOLUTION: f64 = 1e-3;

/// Significant digits an F is printed with at least: half a unit in the fourth digit is
/// at most 0.05 % of the value, half of [`FEED_RESOLUTION`].
pub const FEED_SIGNIFICANT: u8 = 4;

/// Most decimals an F gets: a 32-bit float firmware (RepRapFirmware, Grbl, Marlin) keeps
/// about 7 significant digits, so `F0.012345` is still read as printed.
pub const FEED_MAX_DECIMALS: u8 = 6;

impl Decimals {
    /// The decimals F `value` is printed with: at least `feed`, and as many more (up to
    /// [`FEED_MAX_DECIMALS`]) as give it [`FEED_SIGNIFICANT`] significant digits, which
    /// hold it within half of [`FEED_RESOLUTION`]. A slow F (a rotary move's XYZ speed, a
    /// plunge) keeps its digits, where a fixed 2 decimals print 0.0628 as `F0.06`, 4.5 %
    /// fast. The places follow the value's magnitude, not its rounding error, so a
    /// printed F prints again as itself (`F23.88`, not `F23.9` on a second run).
    ///
    /// ```
    /// use ncpost::num::print::Decimals;
    /// let d = Decimals { feed: 2, ..Decimals::default() };
    /// assert_eq!(d.feed_decimals(1200.0), 2);
    /// assert_eq!(d.feed_decimals(16.0812), 2);
    /// assert_eq!(d.feed_decimals(0.0628), 5);
    /// assert_eq!(d.printed_feed(0.062834), Some(0.06283));
    /// let one = Decimals { feed: 1, ..Decimals::default() };
    /// let p = one.printed_feed(23.875).unwrap();
    /// assert_eq!(one.printed_feed(p), Some(p));
    /// ```
    pub fn feed_decimals(&self, value: f64) -> u8 {
        if !value.is_finite() || value == 0.0 {
            return self.feed;
        }
        // One more place while the value has fewer than FEED_SIGNIFICANT digits before
        // the last: `|v| 10^places < 10^(FEED_SIGNIFICANT - 1)`. (Comparing with exact
        // powers of ten, where `log10` of a value just below one rounds up to it.)
        let v = value.abs();
        let first_digit = POW10[usize::from(FEED_SIGNIFICANT - 1)];
        let most = FEED_MAX_DECIMALS.max(self.feed);
        let mut places = self.feed;
        while places < most && v * POW10[usize::from(places.min(9))] < first_digit {
            places += 1;
        }
        places
    }

    /// F `value` as the controller reads it: printed at [`Decimals::feed_decimals`];
    /// `None` when it does not fit.
    pub fn printed_feed(&self, value: f64) -> Option<f64> {
        printed(value, self.feed_decimals(value))
    }
}

/// Keeps `value` and its printed form as the `seen` pair that the next rounding of the
/// same value reuses (see `Decimals::printed_joints`).
///
/// ```
/// use ncpost::num::print::remember_printed;
/// let mut seen = None;
/// remember_printed(&mut seen, 1.2345, 1.235);
/// assert_eq!(seen, Some((1.2345, 1.235)));
/// ```
pub fn remember_printed<T>(seen: &mut Option<(T, T)>, value: T, printed: T) {
    *seen = Some((value, printed));
}

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
    // Half away from zero, as `f64::round`: below 2^53 the truncation is exact and so
    // is the fraction left over.
    let whole = x as i64;
    let fraction = x - whole as f64;
    Some(if fraction >= 0.5 {
        whole + 1
    } else if fraction <= -0.5 {
        whole - 1
    } else {
        whole
    })
}

/// `value` as the controller reads it when printed at `decimals` places (at most 9):
/// [`to_units`] and back; `None` when it does not fit.
///
/// ```
/// use ncpost::num::print::printed;
/// assert_eq!(printed(1.23456, 3), Some(1.235));
/// assert_eq!(printed(f64::INFINITY, 3), None);
/// ```
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
pub fn from_units(units: i64, decimals: u8) -> f64 {
    units as f64 / POW10[usize::from(decimals.min(9))]
}

/// `10^d` for the decimals a number is printed with (at most 9), exact.
const POW10: [f64; 10] = [1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9];

/// The bytes a number may take: a two-byte lead, a sign, 20 digits, the point and 9
/// decimals.
pub(crate) const ROOM: usize = 40;

/// Puts `lead[..lead_len]` (at most two ASCII bytes, such as `" X"`) and
/// `units * 10^-decimals` (decimals at most 9; more print as 9) at the start of `buf`
/// (at least [`ROOM`] bytes), trailing zeros trimmed when `trim` is set; returns the
/// length.
pub(crate) fn put_number(
    buf: &mut [u8],
    lead: [u8; 2],
    lead_len: usize,
    units: i64,
    decimals: u8,
    trim: bool,
) -> usize {
    let frac_digits = usize::from(decimals.min(9));
    let u = units.unsigned_abs();
    let scale = 10u64.pow(frac_digits as u32);
    let (whole, mut fraction) = (u / scale, u % scale);
    buf[..lead_len].copy_from_slice(&lead[..lead_len]);
    let mut at = lead_len;
    if units < 0 {
        buf[at] = b'-';
        at += 1;
    }
    let mut digits = itoa::Buffer::new();
    let whole = digits.format(whole).as_bytes();
    buf[at..at + whole.len()].copy_from_slice(whole);
    at += whole.len();
    let mut kept = frac_digits;
    if trim {
        while kept > 0 && fraction % 10 == 0 {
            fraction /= 10;
            kept -= 1;
        }
    }
    // The point goes only with digits after it.
    if kept > 0 {
        buf[at] = b'.';
        for slot in buf[at + 1..at + 1 + kept].iter_mut().rev() {
            *slot = b'0' + (fraction % 10) as u8;
            fraction /= 10;
        }
        at += 1 + kept;
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
    fn feed_places_follow_the_magnitude() {
        // The significant-digit rule as a formula, away from exact powers of ten (where
        // the formula's log10 may round either way).
        for feed in [0u8, 1, 2, 3, 7] {
            let d = Decimals {
                feed,
                ..Decimals::default()
            };
            for k in 0..4000 {
                let v = 10f64.powf(-7.0 + f64::from(k) * 0.00371);
                let magnitude = v.log10().floor() as i32;
                if (v.log10() - v.log10().round()).abs() < 1e-9 {
                    continue;
                }
                let want = (i32::from(FEED_SIGNIFICANT) - 1 - magnitude)
                    .clamp(i32::from(feed), i32::from(FEED_MAX_DECIMALS.max(feed)));
                assert_eq!(i32::from(d.feed_decimals(v)), want, "{v} at {feed}");
                assert_eq!(d.feed_decimals(-v), d.feed_decimals(v));
            }
            // A power of ten has its own digit count: 1000 needs no decimal for 4 digits.
            assert_eq!(d.feed_decimals(1000.0), feed);
            assert_eq!(
                d.feed_decimals(0.1),
                4.clamp(feed, FEED_MAX_DECIMALS.max(feed))
            );
        }
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
