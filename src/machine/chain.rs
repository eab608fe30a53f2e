//! The kinematic chain of a two-rotary machine, for every layout: forward kinematics (the
//! tool pose of joint values), the linear positions that put the tip on a point, and the
//! derivative bounds of the tip along a joint-linear move.
//!
//! The chain runs from the tool tip out through the head rotaries (outermost first), adds
//! the linear axes, and goes back through the table rotaries (base first) into the part
//! frame. Every rotary turns about X, Y or Z, so a turn changes the two coordinates across
//! its axis by the sine and cosine of its physical angle ([`Machine::physical`]). The
//! passes that know those sines and cosines already (`ik` from the inverse solution, `feed`
//! from the tables of the printed grid) hand them in as [`Turns`].

use nalgebra::{Point3, Unit, Vector3};

use super::{Machine, Mount, RotaryLetter};

/// The sine and cosine of each rotary's physical angle ([`Machine::physical`]), listing
/// order.
pub type Turns = [(f64, f64); 2];

/// A tool pose in the part frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolPose {
    /// Tool tip, mm.
    pub tip: Point3<f64>,
    /// Unit tool axis, from the tip into the spindle.
    pub axis: Unit<Vector3<f64>>,
}

/// One end of a joint-linear move, with what the move's derivative bounds
/// ([`Machine::path_bounds`]) need of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathEnd {
    /// X, Y, Z, mm.
    pub xyz: [f64; 3],
    /// Rotary joint values, degrees, listing order.
    pub angles: [f64; 2],
    /// [`Machine::turns`] of `angles`.
    pub turns: Turns,
    /// For each rotary, the distance from its axis of the tool tip's point in the chain as
    /// it enters that rotary's stage, mm.
    pub reach: [f64; 2],
}

/// Bounds of a point moving along the joint-linear path through the chain's stages.
#[derive(Debug, Clone, Copy)]
struct Jet {
    /// Bound of `|q'(s)|`.
    speed: f64,
    /// Bound of `|q''(s)|`.
    accel: f64,
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

impl RotaryLetter {
    /// `v` turned about this letter's axis by the angle whose sine and cosine are `s` and
    /// `c` (right-handed).
    fn turn(self, (s, c): (f64, f64), v: [f64; 3]) -> [f64; 3] {
        match self {
            RotaryLetter::A => [v[0], c * v[1] - s * v[2], s * v[1] + c * v[2]],
            RotaryLetter::B => [c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]],
            RotaryLetter::C => [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]],
        }
    }

    /// `v` turned back: the inverse of [`RotaryLetter::turn`].
    fn turn_back(self, (s, c): (f64, f64), v: [f64; 3]) -> [f64; 3] {
        match self {
            RotaryLetter::A => [v[0], c * v[1] + s * v[2], c * v[2] - s * v[1]],
            RotaryLetter::B => [c * v[0] - s * v[2], v[1], s * v[0] + c * v[2]],
            RotaryLetter::C => [c * v[0] + s * v[1], c * v[1] - s * v[0], v[2]],
        }
    }

    /// The distance of `d` from this letter's axis.
    fn off_axis(self, d: [f64; 3]) -> f64 {
        let [x, y, z] = d;
        match self {
            RotaryLetter::A => (y * y + z * z).sqrt(),
            RotaryLetter::B => (x * x + z * z).sqrt(),
            RotaryLetter::C => (x * x + y * y).sqrt(),
        }
    }
}

impl Machine {
    /// Physical rotation angle of rotary `i` at joint value `deg`, radians.
    pub fn physical(&self, i: usize, deg: f64) -> f64 {
        let r = &self.rotary[i];
        (r.direction * (deg - r.zero_offset)).to_radians()
    }

    /// The sines and cosines of both rotaries' physical angles at joint values `angles`
    /// (degrees, listing order).
    pub fn turns(&self, angles: [f64; 2]) -> Turns {
        [
            self.physical(0, angles[0]).sin_cos(),
            self.physical(1, angles[1]).sin_cos(),
        ]
    }

    /// The rotaries on `mount`, base outward.
    fn on(&self, mount: Mount) -> impl DoubleEndedIterator<Item = usize> + '_ {
        (0..2).filter(move |&i| self.rotary[i].on == mount)
    }

    /// `v` turned by rotary `i` about its pivot.
    fn turn_about(&self, i: usize, sc: (f64, f64), v: [f64; 3]) -> [f64; 3] {
        let c = self.rotary[i].pivot;
        add(c, self.rotary[i].axis.turn(sc, sub(v, c)))
    }

    /// `v` turned back by rotary `i` about its pivot.
    fn turn_back_about(&self, i: usize, sc: (f64, f64), v: [f64; 3]) -> [f64; 3] {
        let c = self.rotary[i].pivot;
        add(c, self.rotary[i].axis.turn_back(sc, sub(v, c)))
    }

    /// The tool tip in the part frame for linear positions `xyz` (mm) and rotary `turns`:
    /// the chain from the tip out through the head, the linear axes, and back through the
    /// table. `enter` sees each rotary with the tip's point as it enters that stage.
    fn walk(
        &self,
        xyz: [f64; 3],
        turns: &Turns,
        mut enter: impl FnMut(usize, [f64; 3]),
    ) -> [f64; 3] {
        let mut q = [0.0; 3];
        for i in self.on(Mount::Head).rev() {
            enter(i, q);
            q = self.turn_about(i, turns[i], q);
        }
        q = add(xyz, q);
        for i in self.on(Mount::Table) {
            enter(i, q);
            q = self.turn_back_about(i, turns[i], q);
        }
        q
    }

    /// The tool pose in the part frame for linear positions `xyz` (mm) and rotary joint
    /// values `angles` (degrees, listing order).
    pub fn forward(&self, xyz: &[f64; 3], angles: [f64; 2]) -> ToolPose {
        self.forward_at(*xyz, &self.turns(angles))
    }

    /// [`Machine::forward`] with the rotaries given by their [`Turns`].
    pub fn forward_at(&self, xyz: [f64; 3], turns: &Turns) -> ToolPose {
        ToolPose {
            tip: self.tip_at(xyz, turns),
            // A product of rotations keeps unit length to rounding; renormalise anyway so
            // the invariant holds exactly enough for long chains of computation.
            axis: Unit::new_normalize(self.axis_at(turns)),
        }
    }

    /// The tool tip of [`Machine::forward_at`] alone.
    pub fn tip_at(&self, xyz: [f64; 3], turns: &Turns) -> Point3<f64> {
        Point3::from(self.walk(xyz, turns, |_, _| {}))
    }

    /// The tool axis (the machine's Z turned by the head, seen from the part) before it is
    /// normalised.
    fn axis_at(&self, turns: &Turns) -> Vector3<f64> {
        let mut v = [0.0, 0.0, 1.0];
        for i in self.on(Mount::Head).rev() {
            v = self.rotary[i].axis.turn(turns[i], v);
        }
        for i in self.on(Mount::Table) {
            v = self.rotary[i].axis.turn_back(turns[i], v);
        }
        Vector3::from(v)
    }

    /// The linear positions (X, Y, Z, mm) that put the tool tip on `tip` (part frame) with
    /// the rotaries at `angles`.
    pub fn linear(&self, tip: &Point3<f64>, angles: [f64; 2]) -> [f64; 3] {
        self.linear_at(tip, &self.turns(angles))
    }

    /// [`Machine::linear`] with the rotaries given by their [`Turns`]: the table carries
    /// the tip into the machine frame (the outermost rotary first), and the head's offset
    /// of the tip is taken off.
    pub fn linear_at(&self, tip: &Point3<f64>, turns: &Turns) -> [f64; 3] {
        let mut on_table = [tip.x, tip.y, tip.z];
        for i in self.on(Mount::Table).rev() {
            on_table = self.turn_about(i, turns[i], on_table);
        }
        let mut head = [0.0; 3];
        for i in self.on(Mount::Head).rev() {
            head = self.turn_about(i, turns[i], head);
        }
        sub(on_table, head)
    }

    /// The position `xyz`, `angles` as one end of a joint-linear move.
    pub fn path_end(&self, xyz: [f64; 3], angles: [f64; 2]) -> PathEnd {
        let turns = self.turns(angles);
        let mut reach = [0.0; 2];
        self.walk(xyz, &turns, |i, q| {
            reach[i] = self.rotary[i].axis.off_axis(sub(q, self.rotary[i].pivot));
        });
        PathEnd {
            xyz,
            angles,
            turns,
            reach,
        }
    }

    /// Bounds of `|tip''(s)|` and `|axis''(s)|` along the joint-linear path from `a` to
    /// `b` (`s` from 0 to 1). Each rotary stage turning at `ω` rad per unit `s` about an
    /// axis at distance `ρ` adds `ω²ρ + 2ωV` to the tip's bound, `V` being the bound of the
    /// speed entering it; the tool axis turns at most at the sum of both rotaries' rates.
    pub fn path_bounds(&self, a: &PathEnd, b: &PathEnd) -> (f64, f64) {
        let mut jet = Jet {
            speed: 0.0,
            accel: 0.0,
        };
        for i in self.on(Mount::Head).rev() {
            jet = Self::stage(jet, i, a, b);
        }
        jet.speed += (Vector3::from(b.xyz) - Vector3::from(a.xyz)).norm();
        for i in self.on(Mount::Table) {
            jet = Self::stage(jet, i, a, b);
        }
        let omega: f64 = (0..2)
            .map(|i| (b.angles[i] - a.angles[i]).abs().to_radians())
            .sum();
        (jet.accel, omega * omega)
    }

    /// One rotary stage of [`Machine::path_bounds`]: `q ↦ c + Rot(θ(s)) (q - c)` (or the
    /// turn back).
    fn stage(jet: Jet, i: usize, a: &PathEnd, b: &PathEnd) -> Jet {
        let omega = (b.angles[i] - a.angles[i]).abs().to_radians();
        // The distance from the axis changes at most at `speed`, so between the ends it
        // stays below the meeting point of the two slopes.
        let rho = (a.reach[i] + b.reach[i] + jet.speed) / 2.0;
        Jet {
            speed: omega * rho + jet.speed,
            accel: omega * omega * rho + 2.0 * omega * jet.speed + jet.accel,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn machines() -> Vec<Machine> {
        ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"]
            .into_iter()
            .map(crate::machine::builtin)
            .collect()
    }

    /// The turns are nalgebra's rotations about the coordinate axes.
    #[test]
    fn turns_are_rotations() {
        let v = [1.5, -2.25, 3.125];
        for (letter, axis) in [
            (RotaryLetter::A, Vector3::x_axis()),
            (RotaryLetter::B, Vector3::y_axis()),
            (RotaryLetter::C, Vector3::z_axis()),
        ] {
            let r = Rotation3::from_axis_angle(&axis, 0.7);
            let sc = 0.7f64.sin_cos();
            let want = r * Vector3::from(v);
            let back = r.inverse() * Vector3::from(v);
            let got = Vector3::from(letter.turn(sc, v));
            let got_back = Vector3::from(letter.turn_back(sc, v));
            assert!((want - got).norm() < 1e-12, "{letter:?}");
            assert!((back - got_back).norm() < 1e-12, "{letter:?}");
        }
    }

    /// `linear` undoes `forward`'s tip, every layout.
    #[test]
    fn linear_inverts_the_tip() {
        for m in machines() {
            for angles in [[0.0, 0.0], [30.0, 45.0], [-20.0, 200.0]] {
                let xyz = [10.0, -20.0, 30.0];
                let tip = m.forward(&xyz, angles).tip;
                let back = m.linear(&tip, angles);
                for k in 0..3 {
                    assert!((back[k] - xyz[k]).abs() < 1e-9, "{}: {back:?}", m.name);
                }
            }
        }
    }
}
