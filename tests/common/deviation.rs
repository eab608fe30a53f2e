//! How far a point or a tool axis is from a programmed move, for the tests (and
//! `benches/pieces.rs`) that read pieces back and measure them independently of the passes.

use nalgebra::{Point3, Unit, Vector2, Vector3};

/// Distance from `p` to the segment `a`–`b`.
pub fn segment_distance(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let d = b - a;
    let len2 = d.norm_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(&d) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + d * t)).norm()
}

/// Angle (degrees) from `v` to the nearest point of the shorter great-circle arc `u0`–`u1`,
/// by brute geometry (the angle to the arc's plane where `v` lies over the arc, else to the
/// nearer end).
pub fn arc_angle(v: &Vector3<f64>, u0: &Vector3<f64>, u1: &Vector3<f64>) -> f64 {
    let phi = u0.angle(u1);
    let to = |w: &Vector3<f64>| v.angle(w).to_degrees();
    let ends = to(u0).min(to(u1));
    if phi < 1e-12 {
        return ends;
    }
    let n = u0.cross(u1).normalize();
    let in_plane = v - n * n.dot(v);
    let e2 = n.cross(u0);
    let alpha = in_plane.dot(&e2).atan2(in_plane.dot(u0));
    if (0.0..=phi).contains(&alpha) {
        n.dot(v).abs().asin().to_degrees().min(ends)
    } else {
        ends
    }
}

/// The unit vector `tilt` degrees from Z towards the azimuth `azimuth` degrees from X.
pub fn unit(tilt: f64, azimuth: f64) -> Unit<Vector3<f64>> {
    let (st, ct) = tilt.to_radians().sin_cos();
    let (sp, cp) = azimuth.to_radians().sin_cos();
    Unit::new_normalize(Vector3::new(st * cp, st * sp, ct))
}

/// Distance from `p` to the arc about `centre` of `radius` from angle `start` (radians)
/// over the signed angle `sweep` (at most a turn).
pub fn arc_distance(
    p: &Vector2<f64>,
    centre: &Vector2<f64>,
    radius: f64,
    start: f64,
    sweep: f64,
) -> f64 {
    let v = p - centre;
    // The angle from the start in the arc's sense, in [0, 2π).
    let along = ((v.y.atan2(v.x) - start) * sweep.signum()).rem_euclid(std::f64::consts::TAU);
    if along <= sweep.abs() {
        return (v.norm() - radius).abs();
    }
    let end = |a: f64| centre + Vector2::new(a.cos(), a.sin()) * radius;
    (p - end(start)).norm().min((p - end(start + sweep)).norm())
}

/// Distance from `p` to the segment `a`–`b` in the plane.
pub fn segment_distance_xy(p: &Vector2<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    segment_distance(
        &Point3::new(p.x, p.y, 0.0),
        &Point3::new(a.x, a.y, 0.0),
        &Point3::new(b.x, b.y, 0.0),
    )
}
