//! Whole turns of rotary angles (degrees): the nearest turn, the turns a limited axis
//! allows, wrapping into (-180, 180].

/// [`f64::round`] (half away from zero).
///
/// ```
/// use ncpost::machine::angle::round;
/// assert_eq!(round(2.5), 3.0);
/// assert_eq!(round(-2.5), -3.0);
/// assert!(round(-0.2).is_sign_negative());
/// ```
pub fn round(x: f64) -> f64 {
    x.round()
}

/// The angle `v + 360 k` nearest `target` (degrees).
///
/// ```
/// use ncpost::machine::angle::near_turn;
/// assert_eq!(near_turn(10.0, 700.0), 730.0);
/// ```
pub fn near_turn(v: f64, target: f64) -> f64 {
    v + 360.0 * ((target - v) / 360.0).round()
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
pub fn turn_within(v: f64, lo: f64, hi: f64, prev: Option<f64>) -> Option<f64> {
    let kmin = ((lo - LIMIT_SLACK - v) / 360.0).ceil();
    let kmax = ((hi + LIMIT_SLACK - v) / 360.0).floor();
    if kmin > kmax {
        return None;
    }
    let want = prev.map_or(0.0, |p| ((p - v) / 360.0).round());
    Some(v + 360.0 * want.clamp(kmin, kmax))
}

/// Wraps degrees into (-180, 180].
///
/// ```
/// use ncpost::machine::angle::wrap180;
/// assert_eq!(wrap180(190.0), -170.0);
/// assert_eq!(wrap180(-180.0), 180.0);
/// ```
pub fn wrap180(deg: f64) -> f64 {
    let mut d = deg % 360.0;
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

    #[test]
    fn turns_within_limits() {
        assert_eq!(turn_within(370.0, -90.0, 90.0, None), Some(10.0));
        assert_eq!(turn_within(10.0, -90.0, 720.0, Some(700.0)), Some(370.0));
        assert_eq!(turn_within(10.0, -90.0, 300.0, Some(1000.0)), Some(10.0));
        assert_eq!(
            turn_within(90.0 + LIMIT_SLACK, -90.0, 90.0, None),
            Some(90.0 + LIMIT_SLACK)
        );
        assert_eq!(near_turn(10.0, -350.0), -350.0);
    }

    #[test]
    fn wrap180_range() {
        assert_eq!(wrap180(180.0), 180.0);
        assert_eq!(wrap180(-180.0), 180.0);
        assert_eq!(wrap180(540.0), 180.0);
        assert!((wrap180(-190.0) - 170.0).abs() < 1e-12);
    }
}
