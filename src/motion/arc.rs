//! Arc geometry: the path of a G2/G3 block and its cutting into chords within a tolerance.
//!
//! One definition of "the arc" for every pass that needs points on it (`linearize-arcs`,
//! `polar-ik`), so they agree with each other and with [`super::arc_length`]:
//!
//! - The arc lies in its [`Plane`] with axes `(u, v)` and normal `n` (G17: X, Y, Z; G18:
//!   Z, X, Y; G19: Y, Z, X). The start angle is `atan2(v0 - cv, u0 - cu)`; the signed
//!   sweep goes clockwise (negative) for G2 and counter-clockwise (positive) for G3, seen
//!   from the positive side of the normal. An end point at the start angle (within
//!   1e-12 rad, so also an end point equal to the start) is a full circle; `P` adds
//!   [`Arc::extra_turns`] full turns.
//! - The path parameter is `t` in `[0, 1]`, proportional to the angle swept. The radius
//!   goes linearly in `t` from the start radius to the end radius (a circle when they
//!   are equal, as they are up to rounding for arcs the frontend accepted; a spiral, as
//!   LinuxCNC moves, when the source's end point was off the circle). Every other known
//!   axis, the normal one included (helical motion) and E, moves linearly in `t`.
//! - Chords: `n` equal angle steps. The sagitta of a chord over the angle `δ` of a circle
//!   of radius `r` is `r (1 - cos(δ/2))`; the chord count is the smallest `n` with
//!   `r_max (1 - cos(|sweep| / 2n)) <= tolerance` and `|sweep| / n <= π`, computed in
//!   closed form and then checked (and raised) against that inequality. For a spiral
//!   (start and end radii differ) the bound [`ArcPath::sagitta`] adds the chord error of
//!   the radius change. Along the normal
//!   axis chord and helix agree at equal `t`, so the helix stays within the same bound
//!   of its chords. Every vertex is computed on the arc (`c + r (cos φ, sin φ)`); the
//!   last one is the block's target exactly.

use nalgebra::Point3;

use crate::ir::{Arc, Axis, Joints, Plane};

/// Largest number of chords one arc is cut into (an arc of 1 km radius at a 1 nm
/// tolerance would need more; such an arc keeps this many, slightly over tolerance).
pub const MAX_CHORDS: usize = 10_000_000;

/// Below this many radians between the start and end angles an arc is a full circle.
pub const FULL_CIRCLE_EPS: f64 = 1e-12;

/// The path of one arc block from a known start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcPath {
    /// First plane axis.
    pub u: Axis,
    /// Second plane axis.
    pub v: Axis,
    /// The plane normal (the helix axis).
    pub n: Axis,
    /// Centre in the plane, `(u, v)`, mm.
    pub centre: [f64; 2],
    /// Radius at the start, mm.
    pub r0: f64,
    /// Radius at the end, mm.
    pub r1: f64,
    /// Start angle, rad.
    pub start_angle: f64,
    /// Signed angle swept, rad (negative clockwise), full turns included.
    pub sweep: f64,
    /// Start position.
    pub from: Joints,
    /// End position (the block's target).
    pub to: Joints,
}

/// The signed sweep from angle `f0` to `f1` (radians) in the arc's direction, with
/// `extra_turns` full turns added: `(0, 2π]` counter-clockwise, `[-2π, 0)` clockwise.
///
/// ```
/// use ncpost::motion::arc::sweep;
/// use std::f64::consts::{FRAC_PI_2, TAU};
/// assert!((sweep(0.0, FRAC_PI_2, false, 0) - FRAC_PI_2).abs() < 1e-15);
/// assert!((sweep(0.0, FRAC_PI_2, true, 0) + 3.0 * FRAC_PI_2).abs() < 1e-15);
/// assert_eq!(sweep(1.0, 1.0, true, 1), -2.0 * TAU); // full circle plus one turn
/// ```
pub fn sweep(f0: f64, f1: f64, clockwise: bool, extra_turns: u32) -> f64 {
    let tau = std::f64::consts::TAU;
    let mut s = if clockwise { f0 - f1 } else { f1 - f0 }.rem_euclid(tau);
    if s < FULL_CIRCLE_EPS || s >= tau {
        s = tau;
    }
    s += tau * f64::from(extra_turns);
    if clockwise { -s } else { s }
}

impl ArcPath {
    /// The path of `arc` from `from` to `to`; `None` when a plane axis of the start or
    /// the end is not known.
    ///
    /// ```
    /// use ncpost::ir::{Arc, Axis, Joints, Plane};
    /// use ncpost::motion::arc::ArcPath;
    /// use nalgebra::Vector3;
    /// let (mut a, mut b) = (Joints::default(), Joints::default());
    /// a.set(Axis::X, 10.0); a.set(Axis::Y, 0.0); a.set(Axis::Z, 0.0);
    /// b.set(Axis::X, 0.0); b.set(Axis::Y, 10.0); b.set(Axis::Z, -1.0);
    /// let arc = Arc { clockwise: false, plane: Plane::XY, center: Vector3::zeros(), extra_turns: 0 };
    /// let p = ArcPath::new(&a, &b, &arc).unwrap();
    /// let mid = p.point(0.5);
    /// assert!((mid.values[0] - 10.0 * 0.5f64.sqrt()).abs() < 1e-12);
    /// assert!((mid.values[2] + 0.5).abs() < 1e-12); // helical: Z linear in the angle
    /// ```
    pub fn new(from: &Joints, to: &Joints, arc: &Arc) -> Option<ArcPath> {
        let (u, v, n) = arc.plane.axes();
        let (su, sv) = (from.get(u)?, from.get(v)?);
        let (eu, ev) = (to.get(u)?, to.get(v)?);
        let centre = [arc.center[u.index()], arc.center[v.index()]];
        let (du0, dv0) = (su - centre[0], sv - centre[1]);
        let (du1, dv1) = (eu - centre[0], ev - centre[1]);
        let f0 = dv0.atan2(du0);
        let f1 = dv1.atan2(du1);
        Some(ArcPath {
            u,
            v,
            n,
            centre,
            r0: du0.hypot(dv0),
            r1: du1.hypot(dv1),
            start_angle: f0,
            sweep: sweep(f0, f1, arc.clockwise, arc.extra_turns),
            from: *from,
            to: *to,
        })
    }

    /// The plane the arc lies in.
    pub fn plane(&self) -> Plane {
        match self.u {
            Axis::X => Plane::XY,
            Axis::Z => Plane::ZX,
            _ => Plane::YZ,
        }
    }

    /// The radius at parameter `t`, mm.
    pub fn radius_at(&self, t: f64) -> f64 {
        self.r0 + (self.r1 - self.r0) * t
    }

    /// The position at parameter `t` in `[0, 1]` (`t = 1` is the target exactly).
    pub fn point(&self, t: f64) -> Joints {
        if t >= 1.0 {
            return self.to;
        }
        let mut j = self.to;
        for axis in self.to.known.iter() {
            if let Some(a) = self.from.get(axis) {
                let b = self.to.values[axis.index()];
                j.values[axis.index()] = a + (b - a) * t;
            }
        }
        let phi = self.start_angle + self.sweep * t;
        let r = self.radius_at(t);
        let (s, c) = phi.sin_cos();
        j.values[self.u.index()] = self.centre[0] + r * c;
        j.values[self.v.index()] = self.centre[1] + r * s;
        j
    }

    /// The larger of the start and end radii, mm.
    pub fn max_radius(&self) -> f64 {
        self.r0.max(self.r1)
    }

    /// The radius change per radian swept, mm/rad (0 for a circle).
    pub fn radius_rate(&self) -> f64 {
        if self.sweep == 0.0 {
            0.0
        } else {
            (self.r1 - self.r0) / self.sweep.abs()
        }
    }

    /// An upper bound of the distance of the path from its `n` equal chords, mm: the
    /// sagitta `r_max (1 - cos h)` of the circle of the larger radius over the half
    /// chord angle `h`, plus, for a spiral, the interpolation error of the radius change:
    /// with `r = r_m + k (φ - φ_m)` the path is the circle of radius `r_m` plus
    /// `f(φ) = k (φ - φ_m) e_r(φ)`, whose second derivative is at most
    /// `|k| sqrt(4 + h²)`, so its chord error is at most `|k| h² sqrt(4 + h²) / 2`.
    /// Exact for a circle.
    pub fn sagitta(&self, n: usize) -> f64 {
        let half = (self.sweep.abs() / (2 * n.max(1)) as f64).min(std::f64::consts::FRAC_PI_2);
        let circle = self.max_radius() * (1.0 - half.cos());
        let k = self.radius_rate().abs();
        if k == 0.0 {
            circle
        } else {
            circle + k * half * half * (4.0 + half * half).sqrt() / 2.0
        }
    }

    /// The smallest number of equal chords whose sagitta is within `tolerance` (> 0),
    /// each over at most half a turn; at most [`MAX_CHORDS`].
    pub fn chord_count(&self, tolerance: f64) -> usize {
        let total = self.sweep.abs();
        let r = self.max_radius();
        let pi = std::f64::consts::PI;
        let by_half_turns = (total / pi).ceil() as usize;
        let by_tolerance = if r > tolerance {
            let step = 2.0 * (1.0 - tolerance / r).acos();
            if step > 0.0 {
                (total / step).ceil().min(MAX_CHORDS as f64) as usize
            } else {
                MAX_CHORDS
            }
        } else {
            1
        };
        let mut n = by_half_turns.max(by_tolerance).clamp(1, MAX_CHORDS);
        // The closed form can be one short after rounding, or a spiral's radius change
        // needs more: check it.
        let mut steps = 0;
        while n < MAX_CHORDS && self.sagitta(n) > tolerance {
            n += 1;
            steps += 1;
            if steps == 8 {
                // A spiral: `h² (r_max / 2 + |k| sqrt(4 + π²/4) / 2) <= tolerance`
                // bounds the sagitta from above (1 - cos h <= h²/2, h <= π/2).
                let c = r / 2.0 + self.radius_rate().abs() * 1.19;
                let h = (tolerance / c).sqrt();
                let by_spiral = (total / (2.0 * h)).ceil().min(MAX_CHORDS as f64) as usize;
                n = n.max(by_spiral);
            }
        }
        n
    }

    /// The chord end points for `n` equal steps: the points after the start, the last
    /// being the target exactly.
    pub fn points(&self, n: usize) -> impl Iterator<Item = Joints> + '_ {
        let n = n.max(1);
        (1..=n).map(move |k| {
            if k == n {
                self.to
            } else {
                self.point(k as f64 / n as f64)
            }
        })
    }

    /// The chord end points within `tolerance` ([`ArcPath::chord_count`]).
    pub fn chords(&self, tolerance: f64) -> Vec<Joints> {
        let n = self.chord_count(tolerance);
        self.points(n).collect()
    }

    /// Travel along the normal axis from the start to the end, mm (0 when not known).
    pub fn normal_travel(&self) -> f64 {
        match (self.from.get(self.n), self.to.get(self.n)) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        }
    }

    /// Length of the stretch from parameter `t0` to `t1`, mm, in the plane and as a
    /// whole: the radius at its middle along the angle, with the radius change and the
    /// normal travel in quadrature. Exact for a circle and a helix; the one length of an
    /// arc that the passes time with and the readback checks times against.
    ///
    /// ```
    /// use ncpost::ir::{Arc, Axis, Joints, Plane};
    /// use ncpost::motion::arc::ArcPath;
    /// use nalgebra::Vector3;
    /// let (mut a, mut b) = (Joints::default(), Joints::default());
    /// a.set(Axis::X, 10.0); a.set(Axis::Y, 0.0); a.set(Axis::Z, 0.0);
    /// b.set(Axis::X, -10.0); b.set(Axis::Y, 0.0); b.set(Axis::Z, 0.0);
    /// let arc = Arc { clockwise: false, plane: Plane::XY, center: Vector3::zeros(), extra_turns: 0 };
    /// let p = ArcPath::new(&a, &b, &arc).unwrap();
    /// let (xy, whole) = p.stretch(0.0, 0.5);
    /// assert!((xy - 5.0 * std::f64::consts::PI).abs() < 1e-12 && xy == whole);
    /// assert!((p.length() - 10.0 * std::f64::consts::PI).abs() < 1e-12);
    /// ```
    pub fn stretch(&self, t0: f64, t1: f64) -> (f64, f64) {
        let dt = (t1 - t0).abs();
        let along = self.radius_at(0.5 * (t0 + t1)) * self.sweep.abs() * dt;
        let in_plane = along.hypot((self.r1 - self.r0) * dt);
        (in_plane, in_plane.hypot(self.normal_travel() * dt))
    }

    /// Length of the whole (helical) path, mm ([`ArcPath::stretch`] from 0 to 1).
    pub fn length(&self) -> f64 {
        self.stretch(0.0, 1.0).1
    }

    /// The path parameter of the point of the arc at the angle of `p` (a tool tip,
    /// X Y Z, mm: an arc's plane axes are linear axes) about the centre; of the turns
    /// that pass that angle, the one nearest `near`. An angle outside the sweep counts
    /// at the nearer end.
    pub fn param(&self, p: &Point3<f64>, near: f64) -> f64 {
        let total = self.sweep.abs();
        let (Some(su), Some(sv)) = (self.from.get(self.u), self.from.get(self.v)) else {
            return 0.0;
        };
        if total == 0.0 {
            return 0.0;
        }
        let [cu, cv] = self.centre;
        let (au, av) = (su - cu, sv - cv);
        let (pu, pv) = (p[self.u.index()] - cu, p[self.v.index()] - cv);
        // The one angle: from the start to p, in the sweep's direction, in [0, 2π).
        let tau = std::f64::consts::TAU;
        let turned = (au * pv - av * pu).atan2(au * pu + av * pv);
        let alpha = (turned * self.sweep.signum()).rem_euclid(tau);
        if alpha > total {
            return if alpha - total < tau - alpha {
                1.0
            } else {
                0.0
            };
        }
        let turns = ((total - alpha) / tau).floor();
        let k = ((near * total - alpha) / tau).round().clamp(0.0, turns);
        (alpha + k * tau) / total
    }

    /// Distance of `p` (a tool tip, X Y Z, mm) from the path: from the radius at `p`'s
    /// angle in the plane (the turn whose radius is nearest `p`'s), with the normal
    /// coordinate between the ends (an unknown one counts as 0, as the tip's does).
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        let [cu, cv] = self.centre;
        let rho = (p[self.u.index()] - cu).hypot(p[self.v.index()] - cv);
        let t = if self.r1 == self.r0 {
            0.0
        } else {
            self.param(p, (rho - self.r0) / (self.r1 - self.r0))
        };
        let radial = rho - self.radius_at(t);
        let (a, b) = (
            self.from.get(self.n).unwrap_or(0.0),
            self.to.get(self.n).unwrap_or(0.0),
        );
        let pn = p[self.n.index()];
        let dn = (a.min(b) - pn).max(pn - a.max(b)).max(0.0);
        radial.hypot(dn)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn j(x: f64, y: f64, z: f64) -> Joints {
        let mut p = Joints::default();
        p.set(Axis::X, x);
        p.set(Axis::Y, y);
        p.set(Axis::Z, z);
        p
    }

    #[test]
    fn full_circle_and_turns() {
        let arc = Arc {
            clockwise: true,
            plane: Plane::XY,
            center: Vector3::new(0.0, 0.0, 0.0),
            extra_turns: 2,
        };
        let p = ArcPath::new(&j(5.0, 0.0, 0.0), &j(5.0, 0.0, -3.0), &arc).unwrap();
        assert!((p.sweep + 3.0 * std::f64::consts::TAU).abs() < 1e-12);
        // a third of the way: one full turn down 1 mm, back at the start angle
        let q = p.point(1.0 / 3.0);
        assert!((q.values[0] - 5.0).abs() < 1e-9 && q.values[1].abs() < 1e-9);
        assert!((q.values[2] + 1.0).abs() < 1e-12);
    }

    #[test]
    fn chord_count_meets_tolerance_and_is_minimal() {
        let arc = Arc {
            clockwise: false,
            plane: Plane::ZX,
            center: Vector3::new(0.0, 0.0, 0.0),
            extra_turns: 0,
        };
        // G18: u = Z, v = X
        let a = j(0.0, 0.0, 30.0);
        let b = j(30.0, 0.0, 0.0);
        let p = ArcPath::new(&a, &b, &arc).unwrap();
        assert!((p.sweep - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        for tol in [0.1, 0.01, 0.002, 1e-5] {
            let n = p.chord_count(tol);
            assert!(p.sagitta(n) <= tol);
            assert!(n == 1 || p.sagitta(n - 1) > tol);
        }
    }
}
