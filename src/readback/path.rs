//! The programmed path as the verification compares against it: one [`Vertex`] per
//! programmed motion block (the IR before the machine passes), and the one kinematic chain
//! that maps printed joints back to the tool tip and axis in the programmed frame.

use crate::ir::{Axis, Block, BlockKind, Joints, MotionKind, Target, Tracker};
use crate::machine::Machine;
use crate::motion::polar_point;

/// How printed joint values map to the programmed tool pose.
#[derive(Debug, Clone)]
pub enum Kinematics {
    /// A two-rotary 5-axis machine without TCP: the machine's forward kinematics.
    Machine(Box<Machine>),
    /// The polar printer: r on `r`, θ on `theta`; the programmed XY has the table's axis
    /// at `center`.
    Polar {
        /// The axis letter of r.
        r: Axis,
        /// The axis letter of θ.
        theta: Axis,
        /// The input XY point on the table's axis.
        center: [f64; 2],
        /// The table's highest speed, rad/s, and acceleration, rad/s².
        table: [f64; 2],
    },
    /// X, Y, Z are the tip; the tool axis is +Z.
    Cartesian,
}

/// A tool tip and unit tool axis in the programmed frame.
pub type Pose = ([f64; 3], [f64; 3]);

const UP: [f64; 3] = [0.0, 0.0, 1.0];

fn xyz(j: &Joints) -> [f64; 3] {
    let v = |a: Axis| j.get(a).unwrap_or(0.0);
    [v(Axis::X), v(Axis::Y), v(Axis::Z)]
}

impl Kinematics {
    /// The tool pose of printed joints `j` (an unknown axis counts as 0).
    pub fn printed(&self, j: &Joints) -> Pose {
        match self {
            Kinematics::Machine(m) => {
                let [a, b] = m.rotary_axes();
                let angles = [j.get(a).unwrap_or(0.0), j.get(b).unwrap_or(0.0)];
                let pose = m.forward(&xyz(j), angles);
                (pose.tip.coords.into(), pose.axis.into_inner().into())
            }
            Kinematics::Polar {
                r, theta, center, ..
            } => {
                let p = polar_point(j, *r, *theta);
                let z = j.get(Axis::Z).unwrap_or(0.0);
                ([p.x + center[0], p.y + center[1], z], UP)
            }
            Kinematics::Cartesian => (xyz(j), UP),
        }
    }

    /// The tool pose of programmed joints `j` (before the machine passes): polar input is
    /// Cartesian, a 5-axis joint target goes through the forward kinematics.
    fn programmed(&self, j: &Joints) -> Pose {
        match self {
            Kinematics::Machine(_) => self.printed(j),
            _ => (xyz(j), UP),
        }
    }

    /// The lowest tip speed cap, mm/s, the machine's limits besides its axes' caps may
    /// ask of a printed move from `a` to `b`: a line passing the polar table's centre at
    /// `d` turns the table at up to `v / d` and accelerates it at up to
    /// `(3√3 / 8) v² / d²`, so the table's speed and acceleration cap the tip at
    /// `d · min(ω_max, √(8 α_max / (3√3)))`. `d` is the closest approach of the whole
    /// line the move lies on (it may lie beyond the move): no slowdown `polar-ik` gives
    /// near the centre is slower than this.
    pub fn speed_cap(&self, a: &Joints, b: &Joints) -> f64 {
        match self {
            Kinematics::Polar {
                r,
                theta,
                table: [w, al],
                ..
            } if self.curves(a, b) => {
                let (p, q) = (polar_point(a, *r, *theta), polar_point(b, *r, *theta));
                let (dx, dy) = (q.x - p.x, q.y - p.y);
                let len = dx.hypot(dy);
                let d = if len > 0.0 {
                    (p.x * dy - p.y * dx).abs() / len
                } else {
                    p.x.hypot(p.y)
                };
                let k = w.min((8.0 * al / (3.0 * 3f64.sqrt())).sqrt());
                if d * k > 0.0 { d * k } else { f64::INFINITY }
            }
            _ => f64::INFINITY,
        }
    }

    /// Whether the controller knows the axes the tool's place in the plane depends on
    /// at `j` (an unknown Z counts as 0 on both sides of the comparison).
    pub fn complete(&self, j: &Joints) -> bool {
        let known = |axes: &[Axis]| axes.iter().all(|&a| j.known.contains(a));
        match self {
            Kinematics::Machine(m) => known(&[Axis::X, Axis::Y]) && known(&m.rotary_axes()),
            Kinematics::Polar { r, theta, .. } => known(&[*r, *theta]),
            Kinematics::Cartesian => known(&[Axis::X, Axis::Y]),
        }
    }

    /// Whether a printed move from `a` to `b` can leave the straight line between its
    /// ends in the programmed frame (a rotary or θ changes).
    pub fn curves(&self, a: &Joints, b: &Joints) -> bool {
        let turns = |axis: Axis| a.get(axis) != b.get(axis);
        match self {
            Kinematics::Machine(m) => m.rotary_axes().into_iter().any(turns),
            Kinematics::Polar { theta, .. } => turns(*theta),
            Kinematics::Cartesian => false,
        }
    }
}

/// One programmed motion block: the end of the programmed segment that leads to it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertex {
    /// Tool tip, mm.
    pub tip: [f64; 3],
    /// Unit tool axis.
    pub axis: [f64; 3],
    /// Programmed feed, mm/min (0: a rapid or no feed).
    pub feed: f64,
    /// A rapid: its path is the controller's, only its end is compared.
    pub rapid: bool,
    /// The segment's start is not known (first move, after homing): only its end is
    /// compared.
    pub fresh: bool,
    /// Material the segment deposits (its E increase), slicer E units.
    pub material: f64,
    /// An arc's centre and the index (0 = X, 1 = Y, 2 = Z) of its plane's normal: the
    /// deviation is measured from its circle.
    pub arc: Option<([f64; 3], usize)>,
    /// The target leaves X or Y unknown (before homing ends, say): a printed end whose
    /// place in the plane the controller does not know reaches it. (An unknown Z counts
    /// as 0 on both sides.)
    pub partial: bool,
    /// Source line.
    pub line: u32,
}

/// Turns the IR before the machine passes into [`Vertex`]es.
#[derive(Debug, Clone)]
pub struct Tap {
    kin: Kinematics,
    tracker: Tracker,
    fresh: bool,
    /// E taken back by retractions and not yet restored: the slicer's restoring move
    /// deposits nothing new.
    retracted: f64,
}

impl Tap {
    /// A tap for the programmed frame of `kin`.
    pub fn new(kin: Kinematics) -> Tap {
        Tap {
            kin,
            tracker: Tracker::default(),
            fresh: true,
            retracted: 0.0,
        }
    }

    /// Appends the vertices of `blocks` to `out`.
    pub fn record(&mut self, blocks: &[Block], out: &mut impl Extend<Vertex>) {
        for b in blocks {
            if let Some(v) = self.vertex(b) {
                out.extend(std::iter::once(v));
            }
        }
    }

    fn vertex(&mut self, b: &Block) -> Option<Vertex> {
        let known = self.tracker.pos().known;
        let before = self.tracker.pos().get(Axis::E);
        let step = self.tracker.update(b);
        let BlockKind::Motion(m) = &b.kind else {
            if !step.forgotten.is_empty() || !step.declared.is_empty() {
                self.fresh = true;
            }
            return None;
        };
        let (tip, axis, e) = match &m.target {
            Target::Pose(p) => (p.tip.coords.into(), p.axis.into_inner().into(), None),
            Target::Joints(j) => {
                let (tip, axis) = self.kin.programmed(j);
                (tip, axis, j.get(Axis::E))
            }
        };
        let material = match (before, e) {
            (Some(a), Some(b)) => {
                let net = b - a - self.retracted;
                self.retracted = (-net).max(0.0);
                net.max(0.0)
            }
            _ => 0.0,
        };
        let rapid = m.kind == MotionKind::Rapid;
        let arc = match m.kind {
            MotionKind::Arc(a) => Some((a.center.into(), a.plane.axes().2.index())),
            _ => None,
        };
        // A move from a position not known (after homing, the first one) has no
        // programmed path: only its end is compared.
        let unknown = match &m.target {
            Target::Joints(j) => !j.known.difference(known).is_empty(),
            Target::Pose(_) => false,
        };
        let fresh = std::mem::replace(&mut self.fresh, m.machine_frame) || unknown;
        Some(Vertex {
            tip,
            axis,
            feed: if rapid {
                0.0
            } else {
                m.feed.rate.unwrap_or(0.0)
            },
            rapid,
            fresh,
            material,
            arc,
            partial: match &m.target {
                Target::Joints(j) => !(j.known.contains(Axis::X) && j.known.contains(Axis::Y)),
                Target::Pose(_) => false,
            },
            line: b.span.line,
        })
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// Distance between two points.
pub fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    norm(sub(a, b))
}

/// Distance of `p` from the programmed segment `a → b` (an arc about centre `c` with
/// its plane's normal on coordinate `n`: the distance from its circle in the plane, with
/// the normal coordinate between the ends).
pub fn off_segment(p: [f64; 3], a: [f64; 3], b: [f64; 3], arc: Option<([f64; 3], usize)>) -> f64 {
    if let Some((c, n)) = arc {
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        let radius = (a[u] - c[u]).hypot(a[v] - c[v]);
        let radial = (p[u] - c[u]).hypot(p[v] - c[v]) - radius;
        let (lo, hi) = (a[n].min(b[n]), a[n].max(b[n]));
        let dn = (lo - p[n]).max(p[n] - hi).max(0.0);
        return radial.hypot(dn);
    }
    let d = sub(b, a);
    let len2 = dot(d, d);
    let t = if len2 > 0.0 {
        (dot(sub(p, a), d) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    distance(p, [a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2]])
}

/// Angle, degrees, between unit vectors.
pub fn angle(a: [f64; 3], b: [f64; 3]) -> f64 {
    let cross = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    norm(cross).atan2(dot(a, b)).to_degrees()
}

/// Angle, degrees, of the unit vector `p` from the great-circle arc `a → b` (the tool
/// axis the programmed segment sweeps).
pub fn off_arc(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let n = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let nn = norm(n);
    let ends = angle(p, a).min(angle(p, b));
    if nn < 1e-12 {
        return ends;
    }
    let n = [n[0] / nn, n[1] / nn, n[2] / nn];
    // The foot of p on the great circle lies on the arc when it is on the inner side of
    // both ends.
    let foot = sub(p, [n[0] * dot(p, n), n[1] * dot(p, n), n[2] * dot(p, n)]);
    let within = angle(foot, a) + angle(foot, b) <= angle(a, b) + 1e-9;
    if within && norm(foot) > 0.0 {
        dot(p, n).abs().clamp(0.0, 1.0).asin().to_degrees()
    } else {
        ends
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances() {
        let (a, b) = ([0.0, 0.0, 0.0], [10.0, 0.0, 0.0]);
        assert!((off_segment([5.0, 0.3, 0.0], a, b, None) - 0.3).abs() < 1e-12);
        assert!((off_segment([12.0, 0.0, 0.0], a, b, None) - 2.0).abs() < 1e-12);
        // An arc of radius 10 about the origin.
        let c = Some(([0.0, 0.0, 0.0], 2));
        let (s, e) = ([10.0, 0.0, 0.0], [0.0, 10.0, 0.0]);
        assert!(
            (off_segment([7.0, 7.0, 0.0], s, e, c) - (98f64.sqrt() - 10.0).abs()).abs() < 1e-12
        );
        let (x, y) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!(off_arc([h, h, 0.0], x, y) < 1e-9);
        let t = 1f64.to_radians();
        let p = [h * t.cos(), h * t.cos(), t.sin()];
        assert!((off_arc(p, x, y) - 1.0).abs() < 1e-9);
        assert!((off_arc([-1.0, 0.0, 0.0], x, y) - 90.0).abs() < 1e-9);
    }
}
