//! Forward and closed-form inverse kinematics of two-rotary machines.
//!
//! Every layout reduces to one problem: find angles α, β with
//! `Rot(w1, α) p = Rot(w2, β) q` for unit vectors `p`, `q` and axis directions `w1`, `w2`
//! (Paden–Kahan subproblem 2). The common vector lies on both cones; there are two
//! solutions, one when the cones touch, none when they miss (the orientation is out of
//! reach of this axis pair).

use nalgebra::{Matrix3, Point3, Rotation3, Unit, Vector3};
use smallvec::SmallVec;

use super::angle::wrap180;
use super::{Layout, Machine, Mount};

/// A tool pose in the part frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolPose {
    /// Tool tip, mm.
    pub tip: Point3<f64>,
    /// Unit tool axis, from the tip into the spindle.
    pub axis: Unit<Vector3<f64>>,
}

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

/// Below this, a vector's component across a rotation axis is treated as zero.
const DEGENERATE: f64 = 1e-12;

fn unit_of(m: &Machine, i: usize) -> Vector3<f64> {
    match m.rotary[i].axis {
        super::RotaryLetter::A => Vector3::x(),
        super::RotaryLetter::B => Vector3::y(),
        super::RotaryLetter::C => Vector3::z(),
    }
}

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

impl Machine {
    /// Physical rotation angle of rotary `i` at joint value `deg`, radians.
    fn physical(&self, i: usize, deg: f64) -> f64 {
        let r = &self.rotary[i];
        (r.direction * (deg - r.zero_offset)).to_radians()
    }

    /// Joint value of rotary `i` for a physical angle, degrees in (-180, 180].
    fn joint(&self, i: usize, rad: f64) -> f64 {
        let r = &self.rotary[i];
        wrap180(r.direction * rad.to_degrees() + r.zero_offset)
    }

    fn rotation(&self, i: usize, deg: f64) -> Rotation3<f64> {
        let (s, c) = self.physical(i, deg).sin_cos();
        // Built directly: about a coordinate axis the matrix is known, and this runs for
        // every block (from_axis_angle would normalise and multiply out the general form).
        let m = match self.rotary[i].axis {
            super::RotaryLetter::A => Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c),
            super::RotaryLetter::B => Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c),
            super::RotaryLetter::C => Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
        };
        Rotation3::from_matrix_unchecked(m)
    }

    /// Both rotaries' rotations at joint values `angles` (degrees, listing order), for
    /// [`Machine::forward_with`]: a caller that needs them again can keep them.
    pub fn rotations(&self, angles: [f64; 2]) -> [Rotation3<f64>; 2] {
        [self.rotation(0, angles[0]), self.rotation(1, angles[1])]
    }

    /// Indices of the rotaries on `mount`, base outward.
    fn chain(&self, mount: Mount) -> ([usize; 2], usize) {
        let mut idx = [0; 2];
        let mut n = 0;
        for (i, r) in self.rotary.iter().enumerate() {
            if r.on == mount {
                idx[n] = i;
                n += 1;
            }
        }
        (idx, n)
    }

    /// Applies the chain `idx` (base outward) to a point: the outermost element turns
    /// first, then the one carrying it.
    fn chain_point(
        &self,
        idx: &[usize],
        rot: &[Rotation3<f64>; 2],
        mut x: Vector3<f64>,
    ) -> Vector3<f64> {
        for &i in idx.iter().rev() {
            let c = Vector3::from(self.rotary[i].pivot);
            x = c + rot[i] * (x - c);
        }
        x
    }

    fn chain_point_inverse(
        &self,
        idx: &[usize],
        rot: &[Rotation3<f64>; 2],
        mut x: Vector3<f64>,
    ) -> Vector3<f64> {
        for &i in idx.iter() {
            let c = Vector3::from(self.rotary[i].pivot);
            x = c + rot[i].inverse() * (x - c);
        }
        x
    }

    fn chain_rotation(&self, idx: &[usize], rot: &[Rotation3<f64>; 2]) -> Rotation3<f64> {
        let mut r = Rotation3::identity();
        for &i in idx {
            r *= rot[i];
        }
        r
    }

    /// The tool pose in the part frame for linear positions `xyz` (mm) and rotary joint
    /// values `angles` (degrees, listing order).
    pub fn forward(&self, xyz: &[f64; 3], angles: [f64; 2]) -> ToolPose {
        self.forward_with(xyz, &self.rotations(angles))
    }

    /// [`Machine::forward`] with the rotaries' rotations from [`Machine::rotations`].
    pub fn forward_with(&self, xyz: &[f64; 3], rot: &[Rotation3<f64>; 2]) -> ToolPose {
        if self.rotary[0].on == Mount::Table && self.rotary[1].on == Mount::Table {
            // The common table-table case written out (it runs for every block in
            // densify and feed): undo the base rotary, then the one it carries.
            let (c0, c1) = (
                Vector3::from(self.rotary[0].pivot),
                Vector3::from(self.rotary[1].pivot),
            );
            let (r0, r1) = (rot[0].matrix(), rot[1].matrix());
            let q = r0.tr_mul(&(Vector3::from(*xyz) - c0)) + c0 - c1;
            let tip = r1.tr_mul(&q) + c1;
            // The machine's Z seen from the part: R1ᵀ R0ᵀ z, and R0ᵀ z is R0's third row.
            let axis = r1.tr_mul(&Vector3::new(r0[(2, 0)], r0[(2, 1)], r0[(2, 2)]));
            return ToolPose {
                tip: Point3::from(tip),
                axis: Unit::new_normalize(axis),
            };
        }
        let rot = *rot;
        let (table, nt) = self.chain(Mount::Table);
        let (head, nh) = self.chain(Mount::Head);
        let (table, head) = (&table[..nt], &head[..nh]);
        let tip_machine = Vector3::from(*xyz) + self.chain_point(head, &rot, Vector3::zeros());
        let tip = self.chain_point_inverse(table, &rot, tip_machine);
        let axis_machine = self.chain_rotation(head, &rot) * Vector3::z();
        let axis = self.chain_rotation(table, &rot).inverse() * axis_machine;
        ToolPose {
            tip: Point3::from(tip),
            // A product of rotations keeps unit length to rounding; renormalise anyway so
            // the invariant holds exactly enough for long chains of computation.
            axis: Unit::new_normalize(axis),
        }
    }

    /// The linear positions (X, Y, Z, mm) that put the tool tip on `tip` (part frame) with
    /// the rotaries at `angles`.
    pub fn linear(&self, tip: &Point3<f64>, angles: [f64; 2]) -> [f64; 3] {
        let rot = self.rotations(angles);
        let (table, nt) = self.chain(Mount::Table);
        let (head, nh) = self.chain(Mount::Head);
        let tip_machine = self.chain_point(&table[..nt], &rot, tip.coords);
        let xyz = tip_machine - self.chain_point(&head[..nh], &rot, Vector3::zeros());
        [xyz.x, xyz.y, xyz.z]
    }

    fn condition(&self, axis: &Vector3<f64>) -> Condition {
        let z = Vector3::z();
        match self.layout() {
            // R1 R2 t = z  ⇔  Rot(u2, φ2) t = Rot(u1, -φ1) z
            Layout::TableTable => Condition {
                w1: unit_of(self, 1),
                p: *axis,
                ia: 1,
                sa: 1.0,
                w2: unit_of(self, 0),
                q: z,
                ib: 0,
                sb: -1.0,
            },
            // t = R1 R2 z  ⇔  Rot(u2, φ2) z = Rot(u1, -φ1) t
            Layout::HeadHead => Condition {
                w1: unit_of(self, 1),
                p: z,
                ia: 1,
                sa: 1.0,
                w2: unit_of(self, 0),
                q: *axis,
                ib: 0,
                sb: -1.0,
            },
            // Rt t = Rh z
            Layout::HeadTable => {
                let (ti, hi) = if self.rotary[0].on == Mount::Table {
                    (0, 1)
                } else {
                    (1, 0)
                };
                Condition {
                    w1: unit_of(self, ti),
                    p: *axis,
                    ia: ti,
                    sa: 1.0,
                    w2: unit_of(self, hi),
                    q: z,
                    ib: hi,
                    sb: 1.0,
                }
            }
        }
    }

    /// Every rotary orientation (up to two) that points the tool along `axis` (part frame,
    /// unit); empty when the axis pair cannot reach it. Limits are not applied here.
    pub fn inverse(&self, axis: Unit<Vector3<f64>>) -> SmallVec<[Orientation; 2]> {
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

    /// The cosine of [`Machine::singularity_distance`] (no inverse trigonometry: cheap
    /// enough to test every block against a precomputed cone).
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

    #[test]
    fn wrap180_range() {
        assert_eq!(wrap180(180.0), 180.0);
        assert_eq!(wrap180(-180.0), 180.0);
        assert_eq!(wrap180(540.0), 180.0);
        assert!((wrap180(-190.0) - 170.0).abs() < 1e-12);
    }
}
