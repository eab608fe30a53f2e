//! Geometry the 5-axis tests measure the printed path with: a point's distance to the
//! programmed segment, an axis's angle to the programmed great-circle arc, and the same
//! in the plane for the polar tests (and `benches/pieces.rs`).

use nalgebra::{Point3, Unit, Vector2, Vector3};

/// `densify`'s default tip tolerance, mm: how far the printed path may stray from the line.
pub const TIP_TOL: f64 = 0.01;
/// `densify`'s default axis tolerance, degrees.
pub const AXIS_TOL_DEG: f64 = 0.05;

/// Distance (mm) from `p` to the segment from `a` to `b`.
pub fn distance_to_segment(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let ab = b - a;
    let len2 = ab.norm_squared();
    let s = if len2 > 0.0 {
        ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * s)).norm()
}

/// Angle (deg) from `v` to the great-circle arc from `a` to `b`.
pub fn angle_to_arc(v: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let n = a.cross(b);
    let to_end = |w: &Vector3<f64>| v.angle(w).to_degrees();
    let ends = to_end(a).min(to_end(b));
    if n.norm() < 1e-12 {
        return ends;
    }
    let n = n.normalize();
    // The projection onto the arc's plane is on the arc when it lies between a and b.
    let proj = v - n * n.dot(v);
    if proj.norm() < 1e-12 {
        return ends;
    }
    let inside = a.cross(&proj).dot(&n) >= -1e-12 && proj.cross(b).dot(&n) >= -1e-12;
    if inside {
        v.angle(&proj).to_degrees()
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
    distance_to_segment(
        &Point3::new(p.x, p.y, 0.0),
        &Point3::new(a.x, a.y, 0.0),
        &Point3::new(b.x, b.y, 0.0),
    )
}
