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

/// Below this size a quotient by 360 and a product with `1 / 360` are surely within
/// [`NOT_A_TIE`] of each other (both are within 2.3e-16 of the true quotient, relative).
const FAST_TURNS: f64 = 1e6;

/// Farther than this from a half turn, the product with `1 / 360` rounds as the quotient.
const NOT_A_TIE: f64 = 1e-9;

/// `round(d / 360.0)`, exactly, with a multiplication in place of the division where the
/// two cannot round apart: every CL point rounds several angle differences to whole
/// turns, each on the path to the next, and a `divsd` takes three times a `mulsd`.
///
/// `d * (1 / 360)` and `d / 360` both lie within 2.3e-16 relative of the true quotient;
/// more than [`NOT_A_TIE`] from a half-integer (and below [`FAST_TURNS`]) both round to
/// the same whole number, with the same sign (that of `d`, zeros too). Nearer a
/// half-integer (a tie, such as `d = 180`), beyond it and for NaN the division decides.
///
/// ```
/// use ncpost::machine::angle::{round, round_turns};
/// for d in [180.0, -180.0, 540.0, 179.99, -0.0, 1e9] {
///     assert_eq!(round_turns(d).to_bits(), round(d / 360.0).to_bits());
/// }
/// ```
#[inline(always)]
pub fn round_turns(d: f64) -> f64 {
    let q = d * (1.0 / 360.0);
    let a = q.abs();
    // Nearest, ties to even (exact below 2^52); `a - r` is exact, in [-0.5, 0.5].
    let r = (a + TWO_52) - TWO_52;
    // Predicted: real paths are never this near a half turn. NaN takes the division.
    if a < FAST_TURNS && (a - r).abs() < 0.5 - NOT_A_TIE {
        return r.copysign(q);
    }
    round(d / 360.0)
}

/// The angle `v + 360 k` nearest `target` (degrees).
///
/// ```
/// use ncpost::machine::angle::near_turn;
/// assert_eq!(near_turn(10.0, 700.0), 730.0);
/// ```
#[inline]
pub fn near_turn(v: f64, target: f64) -> f64 {
    v + 360.0 * round_turns(target - v)
}

/// [`near_turn`] for a `v` that is usually within a half turn of `target` already (a
/// value continued from the previous one): the same value, but in that case without the
/// rounding on the path from `target` to the result.
///
/// ```
/// use ncpost::machine::angle::{near_turn, near_turn_close};
/// for (v, t) in [(10.0, 20.0), (10.0, 700.0), (-0.0, 0.0), (0.0, -0.0), (-0.0, -1.0)] {
///     assert_eq!(near_turn_close(v, t).to_bits(), near_turn(v, t).to_bits());
/// }
/// ```
#[inline(always)]
pub fn near_turn_close(v: f64, target: f64) -> f64 {
    let d = target - v;
    // Below 179 degrees `round_turns(d)` is a zero with the sign of `d` (the product is
    // under 0.5 in size), and 360 times it is the same zero.
    if d.abs() < 179.0 {
        v + 0.0f64.copysign(d)
    } else {
        near_turn(v, target)
    }
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
    let want = prev.map_or(0.0, |p| round_turns(p - v));
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
    let want = round_turns(prev - v);
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

        /// The product rounds as the quotient, at and around half turns too.
        #[test]
        fn round_turns_is_round_of_the_quotient(
            k in -3000i64..3000,
            ulps in -64i64..64,
            scale in 0i32..40,
            x in proptest::num::f64::ANY,
            which in 0u8..3,
        ) {
            let d = match which {
                // A half turn and its neighbours, a few ulps either way.
                0 => {
                    let t = (k as f64) * 360.0 + 180.0;
                    f64::from_bits((t.to_bits() as i64 + ulps) as u64)
                }
                // Whole turns, where the quotient is an integer.
                1 => f64::from_bits((((k as f64) * 360.0).to_bits() as i64 + ulps) as u64),
                _ => x * 2f64.powi(-scale),
            };
            prop_assert!(same(round_turns(d), round(d / 360.0)), "{d}");
        }

        /// The shortcut is `near_turn`, zeros' signs and all.
        #[test]
        fn near_turn_close_is_near_turn(
            v in -1000.0f64..1000.0,
            d in -400.0f64..400.0,
            zero in 0u8..6,
        ) {
            let (v, t) = match zero {
                1 => (-0.0, 0.0),
                2 => (-0.0, -0.0),
                3 => (0.0, -0.0),
                4 => (-0.0, d),
                _ => (v, v + d),
            };
            prop_assert!(same(near_turn_close(v, t), near_turn(v, t)), "{v} {t}");
        }

        #[test]
        fn wrapping_matches_fmod(d in -2000.0f64..2000.0) {
            prop_assert!(same(wrap180(d), fmod_wrap(d)), "wrap {d}");
        }
    }
}
