//! The programmed path as the verification compares against it: one [`Vertex`] per
//! programmed motion block (the IR before the machine passes), and the one kinematic chain
//! that maps printed joints back to the tool tip and axis in the programmed frame.

use nalgebra::{Point3, Vector3};

use crate::ir::{Axis, AxisSet, Block, BlockKind, Joints, MotionKind, Target, Tracker};
use crate::machine::Machine;
use crate::motion::arc::ArcPath;
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
pub type Pose = (Point3<f64>, Vector3<f64>);

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
                (pose.tip, pose.axis.into_inner())
            }
            Kinematics::Polar {
                r, theta, center, ..
            } => {
                let p = polar_point(j, *r, *theta);
                let z = j.get(Axis::Z).unwrap_or(0.0);
                (
                    Point3::new(p.x + center[0], p.y + center[1], z),
                    Vector3::z(),
                )
            }
            Kinematics::Cartesian => (xyz(j).into(), Vector3::z()),
        }
    }

    /// The tool pose of programmed joints `j` (before the machine passes): polar input is
    /// Cartesian, a 5-axis joint target goes through the forward kinematics.
    fn programmed(&self, j: &Joints) -> Pose {
        match self {
            Kinematics::Machine(_) => self.printed(j),
            _ => (xyz(j).into(), Vector3::z()),
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
#[derive(Debug, Clone, PartialEq)]
pub struct Vertex {
    /// Tool tip, mm.
    pub tip: Point3<f64>,
    /// Unit tool axis.
    pub axis: Vector3<f64>,
    /// Programmed feed, mm/min (0: a rapid or no feed).
    pub feed: f64,
    /// A rapid: its path is the controller's, only its end is compared.
    pub rapid: bool,
    /// The segment's start is not known (first move, after homing): only its end is
    /// compared.
    pub fresh: bool,
    /// Material the segment deposits (its E increase), slicer E units.
    pub material: f64,
    /// The arc the segment programs: the deviation is measured from it, and its length
    /// is the programmed time's.
    pub arc: Option<std::sync::Arc<ArcPath>>,
    /// The share of the segment's E increase that restores a retraction (0 to 1): the
    /// slicer pushes back what it retracted before any material flows, so the extrusion
    /// starts that far into the segment.
    pub restore: f64,
    /// A `G53` move: its end is in the machine frame, which the programmed frame's
    /// offsets do not reach; it is matched by the printed program's `G53` move.
    pub machine: bool,
    /// Of X, Y and Z, the axes the programmed target knows (all three for a tool pose):
    /// a printed point is compared with it on these (an unknown one counts as 0).
    pub known: AxisSet,
    /// Source line.
    pub line: u32,
}

impl Vertex {
    /// The target leaves X or Y unknown (before homing ends, say): a printed end whose
    /// place in the plane the controller does not know reaches it, and so does one that
    /// agrees with it on the axes it knows.
    pub fn partial(&self) -> bool {
        !(self.known.contains(Axis::X) && self.known.contains(Axis::Y))
    }
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
        let from = *self.tracker.pos();
        let known = from.known;
        let before = from.get(Axis::E);
        let step = self.tracker.update(b);
        let BlockKind::Motion(m) = &b.kind else {
            if !step.forgotten.is_empty() || !step.declared.is_empty() {
                self.fresh = true;
            }
            return None;
        };
        let (tip, axis, e) = match &m.target {
            Target::Pose(p) => (p.tip, p.axis.into_inner(), None),
            Target::Joints(j) => {
                let (tip, axis) = self.kin.programmed(j);
                (tip, axis, j.get(Axis::E))
            }
        };
        let (material, restore) = match (before, e) {
            (Some(a), Some(b)) => {
                let de = b - a;
                // The E that restores the retraction comes first in the move.
                let restore = if de > 0.0 {
                    self.retracted.min(de) / de
                } else {
                    0.0
                };
                let net = de - self.retracted;
                self.retracted = (-net).max(0.0);
                (net.max(0.0), restore)
            }
            _ => (0.0, 0.0),
        };
        let rapid = m.kind == MotionKind::Rapid;
        let arc = match (m.kind, &m.target) {
            (MotionKind::Arc(a), Target::Joints(j)) => {
                ArcPath::new(&from, j, &a).map(std::sync::Arc::new)
            }
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
            restore,
            machine: m.machine_frame,
            known: match &m.target {
                Target::Joints(j) => j.known.intersection(AxisSet::XYZ),
                Target::Pose(_) => AxisSet::XYZ,
            },
            line: b.span.line,
        })
    }
}

/// Distance of `p` from the programmed segment `a → b` (an arc: from its path).
pub fn off_segment(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    arc: Option<&ArcPath>,
) -> f64 {
    if let Some(path) = arc {
        return path.distance(p);
    }
    let t = line_param(p, a, b);
    nalgebra::distance(p, &(a + (b - a) * t))
}

/// The parameter (0 at `a`, 1 at `b`) of the point of the line segment `a → b` nearest
/// `p`.
pub fn line_param(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let d = b - a;
    let len2 = d.norm_squared();
    if len2 > 0.0 {
        ((p - a).dot(&d) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Angle, degrees, between unit vectors.
pub fn angle(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.cross(b).norm().atan2(a.dot(b)).to_degrees()
}

/// Angle, degrees, of the unit vector `p` from the great-circle arc `a → b` (the tool
/// axis the programmed segment sweeps): from the great circle where `p`'s foot on it
/// lies between the ends, else from the nearer end.
pub fn off_arc(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let n = a.cross(b);
    let nn = n.norm();
    if nn >= 1e-12 {
        // The foot of p on the great circle lies on the (shorter) arc when it is turned
        // from a towards b and from itself on towards b, both about the normal a × b.
        let foot = p - n * (p.dot(&n) / (nn * nn));
        if a.cross(&foot).dot(&n) >= 0.0 && foot.cross(b).dot(&n) >= 0.0 && foot.norm() > 0.0 {
            return (p.dot(&n) / nn).abs().clamp(0.0, 1.0).asin().to_degrees();
        }
    }
    // The nearer end: the one with the larger cosine (a and b are both unit).
    angle(p, if p.dot(a) >= p.dot(b) { a } else { b })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distances() {
        let (a, b) = (Point3::origin(), Point3::new(10.0, 0.0, 0.0));
        assert!((off_segment(&Point3::new(5.0, 0.3, 0.0), &a, &b, None) - 0.3).abs() < 1e-12);
        assert!((off_segment(&Point3::new(12.0, 0.0, 0.0), &a, &b, None) - 2.0).abs() < 1e-12);
        // Arcs about the origin in XY, counter-clockwise from (10, 0).
        let path = |end: [f64; 3], extra_turns: u32| {
            let mut from = Joints::default();
            let mut to = Joints::default();
            for (k, axis) in [Axis::X, Axis::Y, Axis::Z].into_iter().enumerate() {
                from.set(axis, [10.0, 0.0, 0.0][k]);
                to.set(axis, end[k]);
            }
            let arc = crate::ir::Arc {
                clockwise: false,
                plane: crate::ir::Plane::XY,
                center: nalgebra::Vector3::zeros(),
                extra_turns,
            };
            ArcPath::new(&from, &to, &arc).expect("plane axes known")
        };
        let (s, e) = (Point3::new(10.0, 0.0, 0.0), Point3::new(0.0, 10.0, 0.0));
        // A quarter circle of radius 10.
        let circle = path([0.0, 10.0, 0.0], 0);
        let c = Some(&circle);
        assert!(
            (off_segment(&Point3::new(7.0, 7.0, 0.0), &s, &e, c) - (98f64.sqrt() - 10.0).abs())
                .abs()
                < 1e-12
        );
        // A spiral from radius 10 to 11 over a quarter turn: 10.5 half way, and the
        // start's circle is 0.5 off there; two turns of it, the point on the second.
        let spiral = path([0.0, 11.0, 0.0], 0);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let mid = Point3::new(10.5 * h, 10.5 * h, 0.0);
        assert!(off_segment(&mid, &s, &Point3::new(0.0, 11.0, 0.0), Some(&spiral)) < 1e-12);
        assert!((off_segment(&mid, &s, &e, c) - 0.5).abs() < 1e-12);
        assert!((spiral.param(&mid, 0.0) - 0.5).abs() < 1e-12);
        // Four whole turns from radius 10 to 14.
        let two = path([14.0, 0.0, 0.0], 3);
        assert!((two.sweep - 4.0 * std::f64::consts::TAU).abs() < 1e-12);
        let second = Point3::new(11.125 * h, 11.125 * h, 0.0);
        assert!(off_segment(&second, &s, &Point3::new(14.0, 0.0, 0.0), Some(&two)) < 1e-12);
        assert!((two.param(&second, 0.4) - 1.125 / 4.0).abs() < 1e-12);
        assert!((circle.stretch(0.0, 1.0).1 - 5.0 * std::f64::consts::PI).abs() < 1e-12);
        let (x, y) = (Vector3::x(), Vector3::y());
        assert!(off_arc(&Vector3::new(h, h, 0.0), &x, &y) < 1e-9);
        let t = 1f64.to_radians();
        let p = Vector3::new(h * t.cos(), h * t.cos(), t.sin());
        assert!((off_arc(&p, &x, &y) - 1.0).abs() < 1e-9);
        assert!((off_arc(&-Vector3::x(), &x, &y) - 90.0).abs() < 1e-9);
    }
}
