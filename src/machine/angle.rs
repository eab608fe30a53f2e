//! Whole turns of rotary angles (degrees): the nearest turn, the turns a limited axis
//! allows, wrapping into (-180, 180].
//!
//! The x86-64 baseline has no rounding instruction (`roundsd` is SSE4.1), so `f64::round`,
//! `floor` and `ceil` are library calls; every CL point of a 5-axis program rounds
//! several angles. The versions here round by adding and taking off 2^52 instead,
//! exactly: the same value and sign as the standard functions (checked against them in
//! the tests).

/// Below this magnitude (under 2^52) [`nearest`] is exact; above it (and for NaN) the
/// standard function is used.
const EXACT: f64 = 4.5e15;

/// 2^52: from here to 2^53 the floats are the whole numbers.
const TWO_52: f64 = 4_503_599_627_370_496.0;

/// Whether `x` is below [`EXACT`] in magnitude (not NaN).
#[inline(always)]
fn exact(x: f64) -> bool {
    x.abs() < EXACT
}

/// The whole number nearest `x` (ties to even), with the sign of `x` kept on zero, for
/// `|x|` below [`EXACT`]. A sum in `[2^52, 2^53)` is rounded to a whole number (ties to
/// even, and 2^52 is even), and taking 2^52 off again is exact. Cheaper than a
/// truncation through `i64`, whose saturating conversion needs range and NaN tests.
#[inline(always)]
fn nearest(x: f64) -> f64 {
    ((x.abs() + TWO_52) - TWO_52).copysign(x)
}

/// [`f64::round`] (half away from zero), exactly.
///
/// ```
/// use ncpost::machine::angle::round;
/// assert_eq!(round(2.5), 3.0);
/// assert_eq!(round(-2.5), -3.0);
/// assert!(round(-0.2).is_sign_negative());
/// ```
#[inline]
pub fn round(x: f64) -> f64 {
    if !exact(x) {
        return x.round();
    }
    let a = x.abs();
    let r = (a + TWO_52) - TWO_52;
    // A tie went down to even: away from zero instead. `a - r` is exact (`r` is 0, or
    // within a factor of two of `a`), and only a tie taken down leaves 0.5.
    let r = if a - r == 0.5 { r + 1.0 } else { r };
    r.copysign(x)
}

/// [`f64::floor`], exactly.
///
/// ```
/// use ncpost::machine::angle::floor;
/// assert_eq!(floor(-0.5), -1.0);
/// assert_eq!(floor(1.5), 1.0);
/// ```
#[inline]
pub fn floor(x: f64) -> f64 {
    if !exact(x) {
        return x.floor();
    }
    // Within half a unit of `x`: one below it when above.
    let r = nearest(x);
    (if r > x { r - 1.0 } else { r }).copysign(x)
}

/// [`f64::ceil`], exactly.
///
/// ```
/// use ncpost::machine::angle::ceil;
/// assert_eq!(ceil(-0.5), 0.0);
/// assert!(ceil(-0.5).is_sign_negative());
/// assert_eq!(ceil(1.5), 2.0);
/// ```
#[inline]
pub fn ceil(x: f64) -> f64 {
    if !exact(x) {
        return x.ceil();
    }
    let r = nearest(x);
    (if r < x { r + 1.0 } else { r }).copysign(x)
}

/// The angle `v + 360 k` nearest `target` (degrees).
///
/// ```
/// use ncpost::machine::angle::near_turn;
/// assert_eq!(near_turn(10.0, 700.0), 730.0);
/// ```
#[inline]
pub fn near_turn(v: f64, target: f64) -> f64 {
    v + 360.0 * round((target - v) / 360.0)
}

/// Tolerance of a rotary limit (degrees): a value this far outside still counts as in.
pub const LIMIT_SLACK: f64 = 1e-9;

/// The turn of `v` within `lo..=hi` (degrees, with [`LIMIT_SLACK`]) nearest `prev`, or
/// the turn nearest zero when there is no previous value; `None` when no turn of `v` is
/// within the limits.
///
/// ```
/// use ncpost::machine::angle::turn_within;
/// assert_eq!(turn_within(-170.0, -90.0, 270.0, Some(180.0)), Some(190.0));
/// assert_eq!(turn_within(100.0, -90.0, 90.0, None), None);
/// ```
#[inline]
pub fn turn_within(v: f64, lo: f64, hi: f64, prev: Option<f64>) -> Option<f64> {
    let (low, high) = (lo - LIMIT_SLACK, hi + LIMIT_SLACK);
    let want = prev.map_or(0.0, |p| round((p - v) / 360.0));
    // The usual case, `v` in range and the nearest turn: then `kmin <= 0 <= kmax` below
    // (a difference of floats has the sign of the true one) and the clamp keeps `want`,
    // so this is the same value without the two divisions.
    if want == 0.0 && v >= low && v <= high {
        return Some(v + 360.0 * want);
    }
    let kmin = ceil((low - v) / 360.0);
    let kmax = floor((high - v) / 360.0);
    if kmin > kmax {
        return None;
    }
    Some(v + 360.0 * want.clamp(kmin, kmax))
}

/// [`near_turn`] of `v` to `prev` and [`turn_within`] of `v` for `prev` together: the
/// same two values, with the rounding shared (both want the turn nearest `prev`, and
/// usually that one is inside the limits).
///
/// ```
/// use ncpost::machine::angle::near_turn_and_within;
/// assert_eq!(near_turn_and_within(-170.0, -90.0, 270.0, 180.0), (190.0, Some(190.0)));
/// assert_eq!(near_turn_and_within(100.0, -90.0, 90.0, 80.0), (100.0, None));
/// ```
#[inline]
pub fn near_turn_and_within(v: f64, lo: f64, hi: f64, prev: f64) -> (f64, Option<f64>) {
    let want = round((prev - v) / 360.0);
    let near = v + 360.0 * want;
    // turn_within's usual case, where it takes this same value.
    if want == 0.0 && v >= lo - LIMIT_SLACK && v <= hi + LIMIT_SLACK {
        return (near, Some(near));
    }
    (near, turn_within(v, lo, hi, Some(prev)))
}

/// Wraps degrees into (-180, 180].
///
/// ```
/// use ncpost::machine::angle::wrap180;
/// assert_eq!(wrap180(190.0), -170.0);
/// assert_eq!(wrap180(-180.0), 180.0);
/// ```
#[inline]
pub fn wrap180(deg: f64) -> f64 {
    // `%` is a library call (fmod); below two turns it is one exact subtraction (the
    // operands are within a factor of two, so the difference is exact), with fmod's sign.
    let a = deg.abs();
    let mut d = if a < 360.0 {
        deg
    } else if a < 720.0 {
        (a - 360.0).copysign(deg)
    } else {
        deg % 360.0
    };
    if d <= -180.0 {
        d += 360.0;
    } else if d > 180.0 {
        d -= 360.0;
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn same(a: f64, b: f64) -> bool {
        a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
    }

    #[test]
    fn edges_match_the_standard_functions() {
        for x in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            0.49999999999999994,
            -0.49999999999999994,
            4503599627370495.5,
            -4503599627370495.5,
            4.5e15,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            // Ties and near-ties below EXACT, where the 2^52 sum decides.
            2.5,
            -3.5,
            0.5000000000000001,
            -0.5000000000000001,
            2251799813685248.5,
            -2251799813685247.5,
            4499999999999999.5,
            -4499999999999998.5,
            4499999999999999.0,
        ] {
            assert!(same(round(x), x.round()), "round {x}");
            assert!(same(floor(x), x.floor()), "floor {x}");
            assert!(same(ceil(x), x.ceil()), "ceil {x}");
        }
        for d in [
            0.0, -0.0, 180.0, -180.0, 360.0, -360.0, 540.0, -540.0, 719.9, -719.9, 720.0, -720.0,
            1e6, -1e6,
        ] {
            assert!(same(wrap180(d), fmod_wrap(d)), "wrap {d}");
        }
    }

    fn fmod_wrap(deg: f64) -> f64 {
        let mut d = deg % 360.0;
        if d <= -180.0 {
            d += 360.0;
        } else if d > 180.0 {
            d -= 360.0;
        }
        d
    }

    proptest! {
        #[test]
        fn rounding_matches_the_standard_functions(x in proptest::num::f64::ANY, scale in 0i32..60) {
            let y = x * 2f64.powi(-scale);
            prop_assert!(same(round(y), y.round()), "round {y}");
            prop_assert!(same(floor(y), y.floor()), "floor {y}");
            prop_assert!(same(ceil(y), y.ceil()), "ceil {y}");
        }

        #[test]
        fn turn_within_matches_the_formula(
            v in -1000.0f64..1000.0,
            lo in -400.0f64..100.0,
            span in 0.0f64..500.0,
            prev in proptest::option::of(-2000.0f64..2000.0),
            edge in 0u8..4,
        ) {
            let hi = lo + span;
            // Values on the limits and at the slack, where the fast path's tests decide.
            let v = match edge {
                1 => lo,
                2 => hi + LIMIT_SLACK,
                3 => lo - 2.0 * LIMIT_SLACK,
                _ => v,
            };
            let kmin = ((lo - LIMIT_SLACK - v) / 360.0).ceil();
            let kmax = ((hi + LIMIT_SLACK - v) / 360.0).floor();
            let expected = (kmin <= kmax).then(|| {
                let want = prev.map_or(0.0, |p: f64| ((p - v) / 360.0).round());
                v + 360.0 * want.clamp(kmin, kmax)
            });
            let got = turn_within(v, lo, hi, prev);
            prop_assert_eq!(got.map(f64::to_bits), expected.map(f64::to_bits), "{:?} {:?}", got, expected);
        }

        #[test]
        fn near_turn_and_within_is_both(
            v in -1000.0f64..1000.0,
            lo in -400.0f64..100.0,
            span in 0.0f64..500.0,
            prev in -2000.0f64..2000.0,
            edge in 0u8..4,
        ) {
            let hi = lo + span;
            let v = match edge {
                1 => lo,
                2 => hi + LIMIT_SLACK,
                3 => prev,
                _ => v,
            };
            let (near, within) = near_turn_and_within(v, lo, hi, prev);
            prop_assert_eq!(near.to_bits(), near_turn(v, prev).to_bits());
            prop_assert_eq!(
                within.map(f64::to_bits),
                turn_within(v, lo, hi, Some(prev)).map(f64::to_bits)
            );
        }

        #[test]
        fn wrapping_matches_fmod(d in -2000.0f64..2000.0) {
            prop_assert!(same(wrap180(d), fmod_wrap(d)), "wrap {d}");
        }
    }
}
