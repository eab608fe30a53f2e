//! Closed-form inverse kinematics of two-rotary machines: the rotary values that point the
//! tool along an axis.
//!
//! Every layout reduces to one problem: find angles α, β with
//! `Rot(w1, α) p = Rot(w2, β) q` for unit vectors `p`, `q` and axis directions `w1`, `w2`
//! (Paden–Kahan subproblem 2). The common vector lies on both cones; there are two
//! solutions, one when the cones touch, none when they miss (the orientation is out of
//! reach of this axis pair).

use nalgebra::{Rotation3, Unit, Vector3};
use smallvec::SmallVec;

use super::angle::wrap180;
use super::{Layout, Machine, Mount};

/// Rotary joint values that give a tool orientation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Orientation {
    /// Joint values of the two rotaries in listing order, degrees, each in (-180, 180].
    pub angles: [f64; 2],
    /// At a singularity: the rotary whose value does not matter (it was set to 0; hold
    /// the previous value instead with [`Machine::hold`]).
    pub free: Option<usize>,
}

/// `Rot(w1, s_a φ[ia]) p = Rot(w2, s_b φ[ib]) q`: the orientation condition of a layout,
/// with `φ` the physical rotary angles in listing order.
struct Condition {
    w1: Vector3<f64>,
    p: Vector3<f64>,
    ia: usize,
    sa: f64,
    w2: Vector3<f64>,
    q: Vector3<f64>,
    ib: usize,
    sb: f64,
}

/// The orientation condition `Rot(w1, s_a φ[ia]) p = Rot(w2, s_b φ[ib]) q` of a layout
/// with the tool axis left out (it is `p` or `q`, the other one is Z).
#[derive(Debug, Clone, Copy, PartialEq)]
struct InverseLayout {
    /// Coordinate index of `w1` (every rotary turns about X, Y or Z), its rotary and the
    /// sign of that rotary's angle.
    w1: usize,
    ia: usize,
    sa: f64,
    /// The same for `w2`.
    w2: usize,
    ib: usize,
    sb: f64,
    /// The tool axis is `p` (and `q` is Z); otherwise `p` is Z and `q` the tool axis.
    axis_is_p: bool,
}

/// The orientations [`Machine::inverse`] found (at most two; the value derefs to their
/// slice), with [`Machine::singularity_cos`] of the same axis and the sine and cosine of
/// each orientation's physical rotary angles.
#[derive(Debug, Clone, Copy)]
pub struct Solutions {
    found: [Orientation; 2],
    /// (sine, cosine) of the physical angle of each rotary of each orientation.
    trig: [[(f64, f64); 2]; 2],
    len: usize,
    /// [`Machine::singularity_cos`] of the tool axis.
    pub singularity_cos: f64,
}

impl Solutions {
    /// No orientation.
    const NONE: Solutions = Solutions {
        found: [Orientation {
            angles: [0.0; 2],
            free: None,
        }; 2],
        trig: [[(0.0, 1.0); 2]; 2],
        len: 0,
        singularity_cos: 0.0,
    };

    /// The orientations, at most two.
    pub fn orientations(&self) -> &[Orientation] {
        &self.found[..self.len]
    }

    /// The sine and cosine of the physical angle ([`Machine::physical`] of the joint value)
    /// of both rotaries of orientation `k` (an index into [`Solutions::orientations`]),
    /// listing order, as [`super::Turns`] for the kinematic chain: what the angles came
    /// from, without going through degrees and back. A whole turn of a joint value keeps
    /// them.
    pub fn sin_cos(&self, k: usize) -> super::Turns {
        self.trig[k]
    }

    fn push(&mut self, o: Orientation, trig: [(f64, f64); 2]) {
        self.found[self.len] = o;
        self.trig[self.len] = trig;
        self.len += 1;
    }
}

impl std::ops::Deref for Solutions {
    type Target = [Orientation];

    fn deref(&self) -> &[Orientation] {
        self.orientations()
    }
}

impl<'a> IntoIterator for &'a Solutions {
    type Item = &'a Orientation;
    type IntoIter = std::slice::Iter<'a, Orientation>;

    fn into_iter(self) -> Self::IntoIter {
        self.orientations().iter()
    }
}

impl IntoIterator for Solutions {
    type Item = Orientation;
    type IntoIter = std::iter::Take<std::array::IntoIter<Orientation, 2>>;

    fn into_iter(self) -> Self::IntoIter {
        self.found.into_iter().take(self.len)
    }
}

/// Below this, a vector's component across a rotation axis is treated as zero.
const DEGENERATE: f64 = 1e-12;

/// The angle that turns `from` towards `to` about unit `w` (exact when both make the same
/// angle with `w`, closest otherwise), radians; `None` when either lies along `w`.
fn angle_about(w: &Vector3<f64>, from: &Vector3<f64>, to: &Vector3<f64>) -> Option<f64> {
    let f = from - w * w.dot(from);
    let t = to - w * w.dot(to);
    if f.norm_squared() < DEGENERATE || t.norm_squared() < DEGENERATE {
        return None;
    }
    Some(w.dot(&f.cross(&t)).atan2(f.dot(&t)))
}

/// An angle from its `atan2` arguments, with its sine and cosine.
#[derive(Debug, Clone, Copy)]
struct Turn {
    /// The arguments, `y.atan2(x)`.
    y: f64,
    x: f64,
    /// Radians, in [-π, π].
    angle: f64,
    sin: f64,
    cos: f64,
}

impl Turn {
    /// The angle `y.atan2(x)` of `args = (y, x)`, with its sine and cosine.
    fn of(args: (f64, f64)) -> Turn {
        let (y, x) = args;
        // Both arguments are bounded and not both near zero (the coordinate solution's degenerate
        // tests), so the squares neither overflow nor underflow.
        let r = (y * y + x * x).sqrt();
        Turn {
            y,
            x,
            angle: y.atan2(x),
            sin: y / r,
            cos: x / r,
        }
    }

    /// [`Turn::of`] `args`, derived from `self` when the arguments are the same but for
    /// their signs: the second solution's usually differ from the first's so (`atan2` is
    /// odd in y, and negating x mirrors the angle about ±π/2). A derived angle is within
    /// an ulp or two of `atan2` (the subtraction from π rounds); the sine and cosine are
    /// `self`'s with signs changed, exactly.
    fn again(&self, args: (f64, f64)) -> Turn {
        let (y, x) = args;
        if y.abs() != self.y.abs() || x.abs() != self.x.abs() {
            return Turn::of(args);
        }
        let (mut angle, mut sin, mut cos) = (self.angle, self.sin, self.cos);
        // self.angle has the sign of self.y, which is not zero (the coordinate solution
        // leaves y = 0 to the general one): negating x takes it to ±π − angle, negating y
        // negates it.
        if x.is_sign_negative() != self.x.is_sign_negative() {
            angle = std::f64::consts::PI.copysign(self.angle) - self.angle;
            cos = -cos;
        }
        if y.is_sign_negative() != self.y.is_sign_negative() {
            angle = -angle;
            sin = -sin;
        }
        Turn {
            y,
            x,
            angle,
            sin,
            cos,
        }
    }
}

/// `(f × c, f · c)` of two vectors across a coordinate axis, given by their components
/// in cyclic order: `atan2`'s arguments for the angle from `f` to `c` about that axis.
fn cross_dot(f: (f64, f64), c: (f64, f64)) -> (f64, f64) {
    (f.0 * c.1 - f.1 * c.0, f.0 * c.0 + f.1 * c.1)
}

/// `angle_about`'s `atan2` arguments for α and β, `(w·(f×c), f·c)` with `f` (p across
/// w1, q across w2, in cyclic order) and the common vector `c` across w, for the common
/// vector with `c3` along the third axis. Across w1 the common vector has y (along w2)
/// and `c3`, across w2 x and `c3`; which comes first in cyclic order is the layout's
/// (`order`: whether w2 follows w1, whether w1 follows w2).
fn turn_args(
    (f1, f2): ((f64, f64), (f64, f64)),
    (x, y): (f64, f64),
    c3: f64,
    (w2_first, w1_first): (bool, bool),
) -> ((f64, f64), (f64, f64)) {
    let c1 = if w2_first { (y, c3) } else { (c3, y) };
    let c2 = if w1_first { (x, c3) } else { (c3, x) };
    (cross_dot(f1, c1), cross_dot(f2, c2))
}

impl Machine {
    /// Joint value of rotary `i` for a physical angle, degrees in (-180, 180].
    fn joint(&self, i: usize, rad: f64) -> f64 {
        let r = &self.rotary[i];
        wrap180(r.direction * rad.to_degrees() + r.zero_offset)
    }

    /// The machine's orientation condition without the tool axis in it.
    fn inverse_layout(&self) -> InverseLayout {
        // (w1's rotary, its sign, w2's rotary, its sign, whether the tool axis is p)
        let (ia, sa, ib, sb, axis_is_p) = match self.layout() {
            // R1 R2 t = z  ⇔  Rot(u2, φ2) t = Rot(u1, -φ1) z
            Layout::TableTable => (1, 1.0, 0, -1.0, true),
            // t = R1 R2 z  ⇔  Rot(u2, φ2) z = Rot(u1, -φ1) t
            Layout::HeadHead => (1, 1.0, 0, -1.0, false),
            // Rt t = Rh z
            Layout::HeadTable => {
                let (ti, hi) = if self.rotary[0].on == Mount::Table {
                    (0, 1)
                } else {
                    (1, 0)
                };
                (ti, 1.0, hi, 1.0, true)
            }
        };
        InverseLayout {
            w1: self.rotary[ia].axis.index(),
            ia,
            sa,
            w2: self.rotary[ib].axis.index(),
            ib,
            sb,
            axis_is_p,
        }
    }

    fn condition(&self, axis: &Vector3<f64>) -> Condition {
        let l = self.inverse_layout();
        let z = Vector3::z();
        let (p, q) = if l.axis_is_p { (*axis, z) } else { (z, *axis) };
        Condition {
            w1: Vector3::ith(l.w1, 1.0),
            p,
            ia: l.ia,
            sa: l.sa,
            w2: Vector3::ith(l.w2, 1.0),
            q,
            ib: l.ib,
            sb: l.sb,
        }
    }

    /// Every rotary orientation (up to two) that points the tool along `axis` (part frame,
    /// unit); empty when the axis pair cannot reach it. Limits are not applied here.
    ///
    /// Every rotary turns about X, Y or Z, so the vector algebra is written out in
    /// coordinates; the general vector solution takes the degenerate cases. The sines and
    /// cosines of the solutions' physical angles come with them
    /// ([`Solutions::sin_cos`]).
    pub fn inverse(&self, axis: Unit<Vector3<f64>>) -> Solutions {
        let layout = self.inverse_layout();
        self.inverse_coordinates(axis, &layout)
    }

    /// [`Machine::inverse`] for the rotation axes `w1` and `w2` of `layout`, along
    /// coordinates `i1` and `i2` (perpendicular: `i1 != i2`), with the tool axis as `p` or
    /// `q`. The first orientation is the general vector solution's to the bit: a product
    /// with 0 or 1 left out changes at most the sign of a zero, and where that sign could
    /// show (an `atan2` of zero, a degenerate case) the general solution runs instead. So is
    /// the second one's angle where only the sign of the `atan2` argument y differs; an
    /// angle whose x argument differs only in sign as well is derived from the first by a
    /// half turn or a mirror ([`Turn::again`]). The sines and cosines come from the `atan2`
    /// arguments.
    fn inverse_coordinates(&self, axis: Unit<Vector3<f64>>, layout: &InverseLayout) -> Solutions {
        let (i1, i2, axis_is_p) = (layout.w1, layout.w2, layout.axis_is_p);
        let t = [axis.x, axis.y, axis.z];
        // Bounded components keep every product finite, as the left-out ones were
        // (0 · ∞ would not be 0).
        if !t.iter().all(|v| v.abs() <= 2.0) {
            return self.inverse_general(axis);
        }
        let z = [0.0, 0.0, 1.0];
        let (p, q) = if axis_is_p { (t, z) } else { (z, t) };
        let (j1, k1, j2, k2) = ((i1 + 1) % 3, (i1 + 2) % 3, (i2 + 1) % 3, (i2 + 2) % 3);
        // e_i × e_(i+1) = e_(i+2): the sign of w1 × w2 along the third axis.
        let normal = if j1 == i2 { 1.0 } else { -1.0 };
        // Perpendicular axes: w1·w2 = 0, so the common vector is x w1 + y w2 ± zc w1×w2
        // with x = w1·p and y = w2·q.
        let x = p[i1];
        let y = q[i2];
        let singularity_cos = x.abs().max(y.abs()).min(1.0);
        let z2 = 1.0 - x * x - y * y;
        // Rounding makes an exactly reachable boundary orientation slightly negative.
        if z2 < -1e-12 {
            return Solutions {
                singularity_cos,
                ..Solutions::NONE
            };
        }
        let zc = z2.max(0.0).sqrt();
        // What p, q and the common vector have across each axis is the same for both
        // solutions (the common vector's w1 part is x, its w2 part y, the rest ±zc).
        if p[j1] * p[j1] + p[k1] * p[k1] < DEGENERATE
            || y * y + zc * zc < DEGENERATE
            || q[j2] * q[j2] + q[k2] * q[k2] < DEGENERATE
            || x * x + zc * zc < DEGENERATE
        {
            return self.inverse_general(axis);
        }
        // p across w1 and q across w2, in cyclic order.
        let f = ((p[j1], p[k1]), (q[j2], q[k2]));
        let order = (j1 == i2, j2 == i1);
        let (alpha, beta) = turn_args(f, (x, y), normal * zc, order);
        // With y = 0 the sign of the zero, which may differ, decides ±π.
        if alpha.0 == 0.0 || beta.0 == 0.0 {
            return self.inverse_general(axis);
        }
        let first = [Turn::of(alpha), Turn::of(beta)];
        let (o1, t1) = self.orientation_of(layout, &first);
        if zc <= 0.0 {
            return Solutions {
                found: [o1; 2],
                trig: [t1; 2],
                len: 1,
                singularity_cos,
            };
        }
        let (alpha, beta) = turn_args(f, (x, y), normal * -zc, order);
        if alpha.0 == 0.0 || beta.0 == 0.0 {
            return self.inverse_general(axis);
        }
        // The second solution's α and β usually follow from the first's.
        let second = [first[0].again(alpha), first[1].again(beta)];
        let (o2, t2) = self.orientation_of(layout, &second);
        Solutions {
            found: [o1, o2],
            trig: [t1, t2],
            len: 2,
            singularity_cos,
        }
    }

    /// The orientation of angles α and β of `layout`'s condition, with the sine and cosine
    /// of both rotaries' physical angles.
    fn orientation_of(
        &self,
        layout: &InverseLayout,
        [alpha, beta]: &[Turn; 2],
    ) -> (Orientation, [(f64, f64); 2]) {
        let mut phys = [0.0; 2];
        let mut trig = [(0.0, 1.0); 2];
        phys[layout.ia] = layout.sa * alpha.angle;
        trig[layout.ia] = (layout.sa * alpha.sin, alpha.cos);
        phys[layout.ib] = layout.sb * beta.angle;
        trig[layout.ib] = (layout.sb * beta.sin, beta.cos);
        let o = Orientation {
            angles: [self.joint(0, phys[0]), self.joint(1, phys[1])],
            free: None,
        };
        (o, trig)
    }

    /// [`Machine::inverse`] by vector algebra, for any rotation axes.
    fn inverse_general(&self, axis: Unit<Vector3<f64>>) -> Solutions {
        let mut out = Solutions::NONE;
        for o in self.inverse_vectors(axis) {
            // Rare (singular or zero-argument cases): the sine and cosine from the angles.
            out.push(o, [0, 1].map(|i| self.physical(i, o.angles[i]).sin_cos()));
        }
        out.singularity_cos = self.singularity_cos(axis);
        out
    }

    /// The Paden–Kahan solution of [`Machine::inverse`] in vectors.
    fn inverse_vectors(&self, axis: Unit<Vector3<f64>>) -> SmallVec<[Orientation; 2]> {
        let c = self.condition(&axis);
        let k = c.w1.dot(&c.w2);
        let n = 1.0 - k * k;
        let mut out = SmallVec::new();
        if n < DEGENERATE {
            return out;
        }
        let a = c.w1.dot(&c.p);
        let b = c.w2.dot(&c.q);
        let x = (a - k * b) / n;
        let y = (b - k * a) / n;
        let z2 = (1.0 - x * x - y * y - 2.0 * k * x * y) / n;
        // Rounding makes an exactly reachable boundary orientation slightly negative.
        if z2 < -1e-12 {
            return out;
        }
        let zc = z2.max(0.0).sqrt();
        let normal = c.w1.cross(&c.w2);
        let signs: &[f64] = if zc > 0.0 { &[1.0, -1.0] } else { &[1.0] };
        for &s in signs {
            let common = c.w1 * x + c.w2 * y + normal * (s * zc);
            let alpha = angle_about(&c.w1, &c.p, &common);
            let beta = angle_about(&c.w2, &c.q, &common);
            let mut phys = [0.0; 2];
            let mut free = None;
            match alpha {
                Some(v) => phys[c.ia] = c.sa * v,
                None => free = Some(c.ia),
            }
            match beta {
                Some(v) => phys[c.ib] = c.sb * v,
                None => free = Some(c.ib),
            }
            let mut angles = [self.joint(0, phys[0]), self.joint(1, phys[1])];
            if let Some(f) = free {
                // The free rotary sits at its kinematic zero; solve the other for it.
                let held = self.joint(f, 0.0);
                angles = self.hold(axis, f, held).angles;
            }
            out.push(Orientation { angles, free });
        }
        out
    }

    /// The orientation closest to `axis` with rotary `index` held at `value` (degrees):
    /// the other rotary turns the tool as near to `axis` as it can. Exact when `axis` is
    /// reachable with that value; used at singularities.
    pub fn hold(&self, axis: Unit<Vector3<f64>>, index: usize, value: f64) -> Orientation {
        let c = self.condition(&axis);
        let mut phys = [0.0; 2];
        phys[index] = self.physical(index, value);
        if index == c.ia {
            let v =
                Rotation3::from_axis_angle(&Unit::new_unchecked(c.w1), c.sa * phys[index]) * c.p;
            phys[c.ib] = c.sb * angle_about(&c.w2, &c.q, &v).unwrap_or(0.0);
        } else {
            let v =
                Rotation3::from_axis_angle(&Unit::new_unchecked(c.w2), c.sb * phys[index]) * c.q;
            phys[c.ia] = c.sa * angle_about(&c.w1, &c.p, &v).unwrap_or(0.0);
        }
        let other = 1 - index;
        let mut angles = [0.0; 2];
        angles[index] = value;
        angles[other] = self.joint(other, phys[other]);
        Orientation {
            angles,
            free: Some(index),
        }
    }

    /// The rotary whose value stops mattering as `axis` nears a singular orientation
    /// (the C table of a cradle when the tool stands vertical).
    pub fn singular_rotary(&self, axis: Unit<Vector3<f64>>) -> usize {
        let c = self.condition(&axis);
        let off = |w: &Vector3<f64>, v: &Vector3<f64>| 1.0 - w.dot(v).abs();
        if off(&c.w1, &c.p) <= off(&c.w2, &c.q) {
            c.ia
        } else {
            c.ib
        }
    }

    /// The cosine of [`Machine::singularity_distance`]: a pass tests every block against
    /// the cosine of its singularity cone, worked out once.
    pub fn singularity_cos(&self, axis: Unit<Vector3<f64>>) -> f64 {
        let c = self.condition(&axis);
        c.w1.dot(&c.p).abs().max(c.w2.dot(&c.q).abs()).min(1.0)
    }

    /// How far `axis` is from a singular orientation (where one rotary's value does not
    /// matter), degrees.
    pub fn singularity_distance(&self, axis: Unit<Vector3<f64>>) -> f64 {
        let c = self.condition(&axis);
        let off = |w: &Vector3<f64>, v: &Vector3<f64>| w.dot(v).abs().min(1.0).acos().to_degrees();
        off(&c.w1, &c.p).min(off(&c.w2, &c.q))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The built-in machines, each also with calibration offsets (other joint values at
    /// the kinematic zero) and flipped directions.
    fn machines() -> Vec<Machine> {
        let mut out = Vec::new();
        for name in ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"] {
            let m = crate::machine::builtin(name);
            let mut other = m.clone();
            other.rotary[0].zero_offset = 3.25;
            other.rotary[1].zero_offset = -17.5;
            other.rotary[0].direction *= -1.0;
            out.push(m);
            out.push(other);
        }
        out
    }

    /// Whether joint values `a` and `b` (degrees) are the same angle within `tol`, a whole
    /// turn apart allowed (a value near ±180 may wrap either way).
    fn same_angle(a: f64, b: f64, tol: f64) -> bool {
        let d = (a - b).rem_euclid(360.0);
        d <= tol || 360.0 - d <= tol
    }

    /// The written-out solution against the vector one: the first orientation to the bit,
    /// the second one's angles to the bit or, where derived from the first by a half turn
    /// or a mirror, within a few ulps; each sine and cosine that of the joint value's
    /// physical angle within a few ulps.
    fn check_coordinate_solution(axis: Vector3<f64>) -> Result<(), TestCaseError> {
        let axis = Unit::new_normalize(axis);
        for m in machines() {
            let fast = m.inverse(axis);
            let general = m.inverse_vectors(axis);
            let found = fast.orientations();
            let what = format!("{}: {axis:?}: {found:?} vs {general:?}", m.name);
            prop_assert_eq!(found.len(), general.len(), "{}", what);
            for (k, (a, b)) in found.iter().zip(&general).enumerate() {
                prop_assert_eq!(a.free, b.free, "{}", what);
                for i in 0..2 {
                    let bits = a.angles[i].to_bits() == b.angles[i].to_bits();
                    prop_assert!(
                        bits || (k == 1 && same_angle(a.angles[i], b.angles[i], 1e-13)),
                        "{}",
                        what
                    );
                    let (s, c) = fast.sin_cos(k)[i];
                    let (s0, c0) = m.physical(i, a.angles[i]).sin_cos();
                    prop_assert!(
                        (s - s0).abs() <= 2e-15 && (c - c0).abs() <= 2e-15,
                        "{}: rotary {} of {}: ({}, {}) vs ({}, {})",
                        what,
                        i,
                        k,
                        s,
                        c,
                        s0,
                        c0
                    );
                }
            }
            prop_assert_eq!(
                fast.singularity_cos.to_bits(),
                m.singularity_cos(axis).to_bits()
            );
        }
        Ok(())
    }

    #[test]
    fn coordinate_solution_is_the_vector_one_on_special_axes() {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        for axis in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [-0.0, -0.0, 1.0],
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, -0.0],
            [0.6, 0.0, 0.8],
            [-0.6, -0.0, 0.8],
            [0.0, 0.6, -0.8],
            [s, s, 0.0],
            [s, -s, 0.0],
            [0.0, s, s],
            [s, 0.0, -s],
            [1e-9, 0.0, 1.0],
            [0.0, -1e-9, 1.0],
        ] {
            check_coordinate_solution(Vector3::from(axis)).unwrap();
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]

        /// The written-out solution is the vector one (to the bit but for derived angles),
        /// zeros and all.
        #[test]
        fn coordinate_solution_is_the_vector_one(
            x in -1.0f64..1.0, y in -1.0f64..1.0, z in -1.0f64..1.0,
            zeroed in 0usize..8,
        ) {
            let mut v = [x, y, z];
            for (i, c) in v.iter_mut().enumerate() {
                if zeroed & (1 << i) != 0 && zeroed != 7 {
                    *c = 0.0;
                }
            }
            prop_assume!(Vector3::from(v).norm() > 1e-6);
            check_coordinate_solution(Vector3::from(v))?;
        }

        /// `atan2` is odd in y to the bit, which the second solution's β relies on.
        #[test]
        fn atan2_is_odd_in_y(y in -10.0f64..10.0, x in -10.0f64..10.0) {
            prop_assert_eq!((-y).atan2(x).to_bits(), (-(y.atan2(x))).to_bits());
        }
    }
}
