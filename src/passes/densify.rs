//! `densify`: split joint moves until the joint-linear path follows the programmed CL segment.
//!
//! A controller without tool-centre-point control interpolates the joints linearly, so
//! between two blocks the tool tip follows `FK(lerp(j0, j1, s))`, not the programmed
//! straight line, and the tool axis does not turn along the great circle. This pass checks
//! that path against the programmed segment (tip on the straight line from `FK(j0).tip` to
//! `FK(j1).tip`, axis on the great-circle arc from `FK(j0).axis` to `FK(j1).axis`) and
//! splits a move at its programmed midpoint until every piece is within tolerance.
//!
//! # Why the check cannot miss a bump
//! The check is not a plain sampling. For the tip `p(s)` of the joint-linear path, an upper
//! bound `M` of `|p''(s)|` over the whole move follows from the joint deltas and the
//! machine's geometry (each rotary stage turning at `ω` rad per unit `s` about an axis at
//! distance `ρ` adds `ω²ρ + 2ωV` to the bound, `V` being the bound of the speed entering
//! it). Between two samples `a < b` the path differs from its chord by at most
//! `M (b - a)² / 8`, and the distance to the (convex) programmed segment is at most the
//! larger of its values at the chord's ends, so on `[a, b]` the tip deviation is at most
//! `max(d(a), d(b)) + M (b - a)² / 8`. The tool axis is handled the same way with the cone
//! spanned by the arc (convex, as the arc is at most 180°): the sine of the angle to the
//! arc is that cone's distance, and `|axis''| <= (ω0 + ω1)²`. The check bisects an
//! interval only while this bound exceeds the tolerance, so a move within tolerance is
//! proven so (usually with no sample at all for short CL steps), and a move is split as
//! soon as one sample is out of tolerance.
//!
//! # How a move is split
//! At the programmed midpoint: the tip halfway along the line, the axis halfway along the
//! arc, solved by inverse kinematics with the orientation and whole turns nearest the
//! interpolated rotary values, so the pieces stay on the branch the move is on (at a
//! singular orientation the free rotary takes its interpolated value). A move that starts
//! or ends at a singular orientation whose free rotary sits at another value than the
//! other end needs (`ik` held the previous angle there) first turns that rotary on the
//! spot, as halving could never take that swing out of the pieces next to the end. Every
//! piece is a copy of the move (span, feed, extra words) with its own target; the last
//! one is the original block with its comments. After `max_depth` halvings a piece stays
//! as it is and the move gets the warning `densify::depth`.
//!
//! Only linear moves (and rapids with `rapids = true`) from a position with all five
//! machine axes known are checked; commands and lines that clobber axes make the next
//! move start from an unknown position.

use std::cell::OnceCell;

use nalgebra::{Point3, Unit, Vector3};
use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, Joints, Motion, MotionKind, Span, Target};
use crate::machine::angle::near_turn;
use crate::machine::{Machine, PathEnd, ToolPose};

/// Options of `densify`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Largest distance of the tool tip from the programmed straight line, mm.
    pub tip_tolerance: f64,
    /// Largest angle between the tool axis and the programmed great-circle arc, degrees.
    pub axis_tolerance: f64,
    /// Most halvings of one move (at most `2^max_depth` pieces); beyond it the piece is
    /// kept as it is, with a warning.
    pub max_depth: u32,
    /// Split rapids too (by default a rapid's path is not checked).
    pub rapids: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            tip_tolerance: 0.01,
            axis_tolerance: 0.05,
            max_depth: 16,
            rapids: false,
        }
    }
}

impl Options {
    fn check(&self) -> Result<(), Diagnostic> {
        let problem = if !(self.tip_tolerance.is_finite() && self.tip_tolerance > 0.0) {
            "tip_tolerance must be a positive number of millimetres"
        } else if !(self.axis_tolerance.is_finite()
            && self.axis_tolerance > 0.0
            && self.axis_tolerance < 90.0)
        {
            "axis_tolerance must be between 0 and 90 degrees"
        } else if self.max_depth > 30 {
            "max_depth must be at most 30"
        } else {
            return Ok(());
        };
        Err(Diagnostic::settings(problem))
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "densify",
    summary: "split joint moves until the joint-linear path stays within tolerance of the programmed tip line and tool-axis arc",
    build: |t, ctx| {
        let machine = ctx.require_machine("densify")?;
        Ok(Box::new(Densify::new(machine.clone(), super::options(t)?)?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// Closer than this to a singular orientation (degrees) the free rotary is held at its
/// interpolated value instead of taking the inverse kinematics' arbitrary choice.
const SINGULAR_DEG: f64 = 1e-6;

/// Bisection levels of one check before a move is treated as out of tolerance; only a
/// deviation within rounding of the tolerance gets that deep.
const CHECK_LEVELS: u8 = 20;

/// A joint position with its five machine axes and tool pose.
#[derive(Debug, Clone)]
struct Node {
    joints: Joints,
    /// The five machine axes, with what the curvature bounds need of this end (worked
    /// out once per node, not once per move end).
    at: PathEnd,
    /// Worked out on first use ([`Densify::pose`]): a move that passes the whole-move
    /// test never needs its ends' poses.
    pose: OnceCell<ToolPose>,
}

/// The programmed straight line of the tool tip.
struct Segment {
    start: Point3<f64>,
    dir: Vector3<f64>,
    len: f64,
}

impl Segment {
    fn new(a: &Point3<f64>, b: &Point3<f64>) -> Segment {
        let d = b - a;
        let len = d.norm();
        Segment {
            start: *a,
            dir: if len > 0.0 { d / len } else { Vector3::zeros() },
            len,
        }
    }

    fn distance(&self, p: &Point3<f64>) -> f64 {
        let v = p - self.start;
        let t = v.dot(&self.dir).clamp(0.0, self.len);
        (v - self.dir * t).norm()
    }
}

/// The programmed great-circle arc of the tool axis, in the frame `e1` (start), `e2`
/// (towards the end, in the arc's plane), `n` (normal).
struct AxisArc {
    e1: Vector3<f64>,
    e2: Vector3<f64>,
    n: Vector3<f64>,
    end: Vector3<f64>,
    /// Arc angle, radians (0 when start and end coincide).
    phi: f64,
}

impl AxisArc {
    /// `mid` gives a point of the joint-linear path to pick the plane when the ends are
    /// antiparallel (any great circle joins them; the one the machine sweeps is meant).
    fn new(
        u0: &Unit<Vector3<f64>>,
        u1: &Unit<Vector3<f64>>,
        mid: impl FnOnce() -> Vector3<f64>,
    ) -> AxisArc {
        let e1 = u0.into_inner();
        let end = u1.into_inner();
        let cos = e1.dot(&end);
        let perp = end - e1 * cos;
        let sin = perp.norm();
        let (e2, phi) = if sin > 1e-12 {
            (perp / sin, sin.atan2(cos))
        } else if cos > 0.0 {
            (any_perpendicular(&e1), 0.0)
        } else {
            let m = mid();
            let p = m - e1 * e1.dot(&m);
            let e2 = if p.norm() > 1e-9 {
                p.normalize()
            } else {
                any_perpendicular(&e1)
            };
            (e2, std::f64::consts::PI)
        };
        AxisArc {
            e1,
            e2,
            n: e1.cross(&e2),
            end,
            phi,
        }
    }

    /// The point at fraction `t` of the arc.
    fn slerp(&self, t: f64) -> Unit<Vector3<f64>> {
        let (s, c) = (t * self.phi).sin_cos();
        Unit::new_normalize(self.e1 * c + self.e2 * s)
    }

    /// The angle (radians) from `a` to the nearest point of the arc, and the distance of
    /// `a` from the cone the arc spans (the sine of that angle while it is below 90°).
    fn deviation(&self, a: &Vector3<f64>) -> (f64, f64) {
        let x = a.dot(&self.e1);
        let y = a.dot(&self.e2);
        let z = a.dot(&self.n);
        if self.phi > 0.0 {
            let alpha = y.atan2(x);
            if (0.0..=self.phi).contains(&alpha) {
                return (z.abs().atan2(x.hypot(y)), z.abs());
            }
        }
        let end = |u: &Vector3<f64>| {
            let c = a.dot(u);
            let s = a.cross(u).norm();
            (s.atan2(c), if c >= 0.0 { s } else { 1.0 })
        };
        let (t0, d0) = end(&self.e1);
        let (t1, d1) = end(&self.end);
        (t0.min(t1), d0.min(d1))
    }
}

fn any_perpendicular(v: &Vector3<f64>) -> Vector3<f64> {
    let helper = if v.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    v.cross(&helper).normalize()
}

/// The `densify` pass.
pub struct Densify {
    machine: Machine,
    options: Options,
    axes: [Axis; 2],
    axis_tol: f64,
    sin_axis_tol: f64,
    /// The last emitted position.
    prev: Joints,
    /// Its five machine axes and pose (when all are known) sit in `nodes[prev_slot]`; a
    /// move's end is built in the other slot, which then becomes the previous one, so a
    /// node is never moved.
    nodes: [Option<Node>; 2],
    prev_slot: usize,
}

impl Densify {
    /// A `densify` pass for `machine`.
    pub fn new(machine: Machine, options: Options) -> Result<Densify, Diagnostic> {
        options.check()?;
        machine.check()?;
        let axis_tol = options.axis_tolerance.to_radians();
        Ok(Densify {
            axes: machine.rotary_axes(),
            machine,
            axis_tol,
            sin_axis_tol: axis_tol.sin(),
            options,
            prev: Joints::default(),
            nodes: [None, None],
            prev_slot: 0,
        })
    }

    /// The five machine axes of `joints`, when all are known.
    fn five_axes(&self, joints: &Joints) -> Option<([f64; 3], [f64; 2])> {
        let xyz = [
            joints.get(Axis::X)?,
            joints.get(Axis::Y)?,
            joints.get(Axis::Z)?,
        ];
        let angles = [joints.get(self.axes[0])?, joints.get(self.axes[1])?];
        Some((xyz, angles))
    }

    #[cfg(test)]
    fn node(&self, joints: &Joints) -> Option<Node> {
        let (xyz, angles) = self.five_axes(joints)?;
        Some(self.node_at(*joints, xyz, angles))
    }

    /// Puts the node of `joints` (none when an axis is unknown) in `nodes[slot]`.
    fn set_node(&mut self, slot: usize, joints: &Joints) {
        self.nodes[slot] = self
            .five_axes(joints)
            .map(|(xyz, angles)| self.node_at(*joints, xyz, angles));
    }

    /// The node of `joints`, whose five machine axes are `xyz` and `angles`.
    fn node_at(&self, joints: Joints, xyz: [f64; 3], angles: [f64; 2]) -> Node {
        Node {
            joints,
            at: self.machine.path_end(xyz, angles),
            pose: OnceCell::new(),
        }
    }

    /// The tool pose of `node`.
    fn pose<'n>(&self, node: &'n Node) -> &'n ToolPose {
        node.pose
            .get_or_init(|| self.machine.forward_at(node.at.xyz, &node.at.turns))
    }

    fn remember(&mut self, joints: Joints) {
        self.prev = joints;
        self.set_node(self.prev_slot, &joints);
    }

    fn forget(&mut self, axes: crate::ir::AxisSet) {
        if !axes.is_empty() {
            let mut j = self.prev;
            j.forget(axes);
            self.remember(j);
        }
    }

    /// The pose of the joint-linear path at `s`.
    fn path_pose(&self, a: &Node, b: &Node, s: f64) -> ToolPose {
        let l = |p: f64, q: f64| p + (q - p) * s;
        self.machine.forward(
            &[
                l(a.at.xyz[0], b.at.xyz[0]),
                l(a.at.xyz[1], b.at.xyz[1]),
                l(a.at.xyz[2], b.at.xyz[2]),
            ],
            [
                l(a.at.angles[0], b.at.angles[0]),
                l(a.at.angles[1], b.at.angles[1]),
            ],
        )
    }

    fn arc(&self, a: &Node, b: &Node) -> AxisArc {
        AxisArc::new(&self.pose(a).axis, &self.pose(b).axis, || {
            self.path_pose(a, b, 0.5).axis.into_inner()
        })
    }

    /// Whether the joint-linear path from `a` to `b` stays within tolerance of the
    /// programmed segment (see the module documentation for why this is a proof).
    fn within(&self, a: &Node, b: &Node) -> bool {
        let tol = self.options.tip_tolerance;
        let (tip_accel, axis_accel) = self.machine.path_bounds(&a.at, &b.at);
        // The loop's first test, on the whole move (both ends on the programmed path):
        // most CL steps pass it, and then need neither the segment nor the arc.
        let whole = 1.0 / 8.0;
        if tip_accel * whole <= tol && axis_accel * whole <= self.sin_axis_tol {
            return true;
        }
        let seg = Segment::new(&self.pose(a).tip, &self.pose(b).tip);
        let arc = self.arc(a, b);
        // (start, end, tip deviation at both, axis cone distance at both, level)
        let mut stack =
            [(0.0f64, 1.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64, 0u8); CHECK_LEVELS as usize + 2];
        let mut len = 1;
        while len > 0 {
            len -= 1;
            let (s0, s1, t0, t1, c0, c1, level) = stack[len];
            let q = (s1 - s0) * (s1 - s0) / 8.0;
            if t0.max(t1) + tip_accel * q <= tol && c0.max(c1) + axis_accel * q <= self.sin_axis_tol
            {
                continue;
            }
            if level >= CHECK_LEVELS {
                return false;
            }
            let sm = 0.5 * (s0 + s1);
            let pose = self.path_pose(a, b, sm);
            let tm = seg.distance(&pose.tip);
            let (angle, cm) = arc.deviation(&pose.axis);
            if tm > tol || angle > self.axis_tol {
                return false;
            }
            stack[len] = (sm, s1, tm, t1, cm, c1, level + 1);
            stack[len + 1] = (s0, sm, t0, tm, c0, cm, level + 1);
            len += 2;
        }
        true
    }

    /// The orientation for `axis` nearest the interpolated rotary values `target`.
    fn orientation(&self, axis: Unit<Vector3<f64>>, target: [f64; 2]) -> [f64; 2] {
        let m = &self.machine;
        let sols = m.inverse(axis);
        let singular = sols.iter().any(|o| o.free.is_some())
            || (!sols.is_empty() && m.singularity_distance(axis) < SINGULAR_DEG);
        if singular {
            let k = m.singular_rotary(axis);
            let o = m.hold(axis, k, target[k]);
            return [
                near_turn(o.angles[0], target[0]),
                near_turn(o.angles[1], target[1]),
            ];
        }
        let mut best: Option<([f64; 2], f64)> = None;
        for o in &sols {
            let a = [
                near_turn(o.angles[0], target[0]),
                near_turn(o.angles[1], target[1]),
            ];
            let cost = (a[0] - target[0]).powi(2) + (a[1] - target[1]).powi(2);
            if best.is_none_or(|(_, c)| cost < c) {
                best = Some((a, cost));
            }
        }
        // Out of the axis pair's reach (cannot happen between two reachable poses on
        // the machines modelled): keep the interpolated angles, the tip stays exact.
        best.map_or(target, |(a, _)| a)
    }

    /// The position at the programmed midpoint between `a` and `b`.
    fn midpoint(&self, a: &Node, b: &Node) -> Node {
        let (ta, tb) = (self.pose(a).tip, self.pose(b).tip);
        let tip = ta + (tb - ta) * 0.5;
        let axis = self.arc(a, b).slerp(0.5);
        let target = [
            0.5 * (a.at.angles[0] + b.at.angles[0]),
            0.5 * (a.at.angles[1] + b.at.angles[1]),
        ];
        let angles = self.orientation(axis, target);
        let xyz = self.machine.linear(&tip, angles);
        let mut joints = b.joints;
        for ax in b.joints.known.iter() {
            match a.joints.get(ax) {
                Some(v) => joints.values[ax.index()] = 0.5 * (v + b.joints.values[ax.index()]),
                None => joints.forget(std::iter::once(ax).collect()),
            }
        }
        joints.set(Axis::X, xyz[0]);
        joints.set(Axis::Y, xyz[1]);
        joints.set(Axis::Z, xyz[2]);
        joints.set(self.axes[0], angles[0]);
        joints.set(self.axes[1], angles[1]);
        self.node_at(joints, xyz, angles)
    }

    /// Emits the pieces from `a` to `b` (the last one only when `last` is false: the
    /// caller emits the original block there). `depth` halvings made so far.
    #[allow(clippy::too_many_arguments)]
    fn refine(
        &self,
        motion: &Motion,
        span: Span,
        a: &Node,
        b: &Node,
        depth: u32,
        last: bool,
        hit_limit: &mut bool,
        out: &mut Output<'_>,
    ) {
        let ok = self.within(a, b);
        if ok || depth >= self.options.max_depth {
            *hit_limit |= !ok;
            if !last {
                let mut piece = motion.clone();
                piece.target = Target::Joints(b.joints);
                out.push(Block::new(span, BlockKind::Motion(piece)));
            }
            return;
        }
        let m = self
            .turn_on_the_spot(a, b)
            .unwrap_or_else(|| self.midpoint(a, b));
        self.refine(motion, span, a, &m, depth + 1, false, hit_limit, out);
        self.refine(motion, span, &m, b, depth + 1, last, hit_limit, out);
    }

    /// At a singular end the free rotary's value is arbitrary, and the other end's branch
    /// may need another one (`ik` held the previous angle there). Halving cannot fix that:
    /// every piece next to the singular end would still swing the free rotary. So it turns
    /// first (or last), on the spot: the node at the singular end's pose with the free
    /// rotary at the other end's value.
    fn turn_on_the_spot(&self, a: &Node, b: &Node) -> Option<Node> {
        let (pa, pb) = (self.pose(a), self.pose(b));
        let same_pose = (pa.tip - pb.tip).norm() <= 1e-9 && pa.axis.dot(&pb.axis) >= 1.0 - 1e-15;
        if same_pose {
            return None;
        }
        for (end, other) in [(a, b), (b, a)] {
            let end_pose = self.pose(end);
            let axis = end_pose.axis;
            if self.machine.singularity_distance(axis) >= SINGULAR_DEG {
                continue;
            }
            let k = self.machine.singular_rotary(axis);
            let want = other.at.angles[k];
            if (end.at.angles[k] - want).abs() <= 1e-9 {
                continue;
            }
            let held = self.machine.hold(axis, k, want).angles;
            let mut angles = end.at.angles;
            angles[k] = want;
            angles[1 - k] = near_turn(held[1 - k], end.at.angles[1 - k]);
            let xyz = self.machine.linear(&end_pose.tip, angles);
            let mut joints = end.joints;
            joints.set(Axis::X, xyz[0]);
            joints.set(Axis::Y, xyz[1]);
            joints.set(Axis::Z, xyz[2]);
            joints.set(self.axes[0], angles[0]);
            joints.set(self.axes[1], angles[1]);
            return Some(self.node_at(joints, xyz, angles));
        }
        None
    }
}

impl Pass for Densify {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        // Most moves stay within tolerance and pass unchanged, where they lie.
        super::edit_in_place(
            self,
            blocks,
            out,
            |pass, block, _| pass.advance(block),
            |pass, block, out| {
                if !pass.advance(&block) {
                    pass.split(&block, out);
                }
                out.push(block);
            },
        );
    }
}

impl Densify {
    /// Follows the position through `block`, which passes unchanged; `false` (nothing
    /// followed) when it is a move off the programmed path, for [`Densify::split`].
    fn advance(&mut self, block: &Block) -> bool {
        match &block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(end) = &m.target else {
                    // A pose this late means the joints are not known.
                    self.remember(Joints::default());
                    return true;
                };
                let end_slot = 1 - self.prev_slot;
                // Built in the free slot: the previous node stays until the move is done.
                self.set_node(end_slot, end);
                if self.checked(m)
                    && let (Some(a), Some(b)) = (&self.nodes[self.prev_slot], &self.nodes[end_slot])
                    && !self.within(a, b)
                {
                    return false;
                }
                self.moved_to(m, end, end_slot);
            }
            BlockKind::Command(c) => self.forget(c.clobbers),
            BlockKind::Verbatim(v) => self.forget(v.clobbers),
            _ => {}
        }
        true
    }

    /// Whether `densify` checks motion `m` against the programmed path.
    fn checked(&self, m: &Motion) -> bool {
        let by_kind = match m.kind {
            MotionKind::Linear => true,
            MotionKind::Rapid => self.options.rapids,
            MotionKind::Arc(_) => false,
        };
        by_kind && !m.machine_frame
    }

    /// The position is now `end` of motion `m`, whose node is in `nodes[end_slot]`.
    fn moved_to(&mut self, m: &Motion, end: &Joints, end_slot: usize) {
        self.prev = *end;
        self.prev_slot = end_slot;
        if m.machine_frame {
            self.forget(m.written);
        }
    }

    /// Emits the pieces before the move `block`, which [`Densify::advance`] found off the
    /// programmed path (its end node built), and follows the position to its end.
    fn split(&mut self, block: &Block, out: &mut Output<'_>) {
        let BlockKind::Motion(m) = &block.kind else {
            return;
        };
        let Target::Joints(end) = &m.target else {
            return;
        };
        let end_slot = 1 - self.prev_slot;
        if let (Some(a), Some(b)) = (&self.nodes[self.prev_slot], &self.nodes[end_slot]) {
            let mut hit_limit = false;
            if self.options.max_depth == 0 {
                hit_limit = true;
            } else {
                let mid = self
                    .turn_on_the_spot(a, b)
                    .unwrap_or_else(|| self.midpoint(a, b));
                self.refine(m, block.span, a, &mid, 1, false, &mut hit_limit, out);
                self.refine(m, block.span, &mid, b, 1, true, &mut hit_limit, out);
            }
            if hit_limit {
                out.diag(
                    Diagnostic::warning(
                        "densify::depth",
                        format!(
                            "the move is still off the programmed path after {} halvings",
                            self.options.max_depth
                        ),
                    )
                    .at_span(block.span)
                    .with_help(
                        "the rotaries swing far for this move (a singularity or a branch change?); raise max_depth or the tolerances, or check the ik choices",
                    ),
                );
            }
        }
        self.moved_to(m, end, end_slot);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::builtin as machine;

    fn node(d: &Densify, xyz: [f64; 3], angles: [f64; 2]) -> Node {
        let mut j = Joints::default();
        j.set(Axis::X, xyz[0]);
        j.set(Axis::Y, xyz[1]);
        j.set(Axis::Z, xyz[2]);
        j.set(d.axes[0], angles[0]);
        j.set(d.axes[1], angles[1]);
        d.node(&j).expect("five axes")
    }

    /// The machine's bound holds for the real curvature of the joint-linear path.
    #[test]
    fn curvature_bound_holds() {
        for name in ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"] {
            let d = Densify::new(machine(name), Options::default()).expect("pass");
            let a = node(&d, [10.0, -20.0, 30.0], [20.0, -40.0]);
            let b = node(&d, [-35.0, 5.0, 12.0], [-15.0, 75.0]);
            let (tip_bound, axis_bound) = d.machine.path_bounds(&a.at, &b.at);
            let h = 1e-3;
            let mut worst: f64 = 0.0;
            let mut worst_axis: f64 = 0.0;
            for k in 1..999 {
                let s = k as f64 * h;
                let p = |s| d.path_pose(&a, &b, s);
                let acc =
                    (p(s + h).tip.coords - 2.0 * p(s).tip.coords + p(s - h).tip.coords) / (h * h);
                let acc_axis = (p(s + h).axis.into_inner() - 2.0 * p(s).axis.into_inner()
                    + p(s - h).axis.into_inner())
                    / (h * h);
                worst = worst.max(acc.norm());
                worst_axis = worst_axis.max(acc_axis.norm());
            }
            assert!(worst <= tip_bound * 1.0001, "{name}: {worst} > {tip_bound}");
            assert!(worst_axis <= axis_bound * 1.0001, "{name}");
            // Not uselessly loose either.
            assert!(tip_bound < 20.0 * worst, "{name}: {tip_bound} vs {worst}");
            assert_eq!(d.machine.path_bounds(&a.at, &a.at).1, 0.0);
        }
    }

    #[test]
    fn arc_deviation() {
        let z = Vector3::z_axis();
        let x = Vector3::x_axis();
        let arc = AxisArc::new(&z, &x, || unreachable!());
        let mid = arc.slerp(0.5);
        assert!((mid.x - mid.z).abs() < 1e-15 && mid.y == 0.0);
        let (a, _) = arc.deviation(&Vector3::new(1.0, 0.01, 1.0).normalize());
        assert!((a - (0.01f64 / 2f64.sqrt()).atan()).abs() < 1e-12);
        // Beyond the end: the angle to the end point.
        let (a, _) = arc.deviation(&Vector3::new(1.0, 0.0, -0.1).normalize());
        assert!((a - 0.1f64.atan()).abs() < 1e-12);
        // Antiparallel ends: the plane of the path's midpoint.
        let arc = AxisArc::new(&z, &-z, Vector3::y);
        assert!((arc.slerp(0.5).into_inner() - Vector3::y()).norm() < 1e-12);
        // Equal ends.
        let arc = AxisArc::new(&z, &z, || unreachable!());
        assert_eq!(arc.slerp(0.5), z);
        let (a, c) = arc.deviation(&Vector3::new(0.1, 0.0, 1.0).normalize());
        assert!((a - 0.1f64.atan()).abs() < 1e-12 && (c - a.sin()).abs() < 1e-12);
    }
}
