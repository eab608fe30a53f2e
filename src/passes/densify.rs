//! `densify`: split joint moves until the joint-linear path follows the programmed CL segment.
//!
//! A controller without tool-centre-point control interpolates the joints linearly, so
//! between two blocks the tool tip follows `FK(lerp(j0, j1, s))`, not the programmed
//! straight line, and the tool axis does not turn along the great circle. This pass checks
//! that path against the programmed segment (tip on the straight line from `FK(j0).tip` to
//! `FK(j1).tip`, axis on the great-circle arc from `FK(j0).axis` to `FK(j1).axis`) and
//! cuts a move that strays into as few pieces as the tolerances allow.
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
//! Into the longest pieces within tolerance, one after the other: from the start of the
//! move (or of the piece before) the end of the next piece is searched along the
//! programmed move, from the previous piece's length (or, for the first, from the
//! curvature bound), doubling while the piece fits and then bisecting, until the piece's
//! end is within 2 % of the longest that fits. Every piece end is a point of the programmed
//! move: the tip at that fraction of the line, the axis at that fraction of the arc,
//! solved by inverse kinematics with the orientation and whole turns nearest the
//! interpolated rotary values, so the pieces stay on the branch the move is on (at a
//! singular orientation the free rotary takes its interpolated value). Controllers plan a
//! limited number of blocks a second, so every piece more than needed is a stutter:
//! halving at midpoints, as first built, gave about 1.4 times the fewest pieces (each
//! piece between a quarter and the whole of the allowed deviation); this gives within a
//! few per cent of them (`scripts/bench-pieces.sh`, BENCHMARKS.md). A move that starts
//! or ends at a singular orientation whose free rotary sits at another value than the
//! other end needs (`ik` held the previous angle there) first turns that rotary on the
//! spot, as no cut could take that swing out of the pieces next to the end. Every
//! piece is a copy of the move (span, feed, extra words) with its own target; the last
//! one is the original block with its comments. Where no piece of at least `2^-max_depth`
//! of the move fits, a piece of that length is kept as it is and the move gets the warning
//! `densify::depth`.
//!
//! # The printed numbers
//! The tolerances hold on the positions as printed: the backend rounds every axis to half
//! a unit of its last decimal (`ctx.decimals`), which moves the tip by up to `√3` times
//! the linear rounding plus each rotary's own rounding at the piece's ends (radians, 0 for
//! an angle that prints exactly) times the tip's distance from that rotary's axis, and
//! turns the tool axis by up to twice the rotary rounding. The check gets the tolerances
//! less those amounts; tolerances finer than the printed decimals can hold are a settings
//! error. Far from a rotary axis (a part metres away, or a wild CL point) the rounding of
//! an angle alone can exceed the tip tolerance, and no cut helps: from there the move is
//! left whole with the warning `densify::rounding`, rather than cut into `2^max_depth`
//! useless blocks.
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
use crate::num::print::{self, Decimals};

/// Options of `densify`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Largest distance of the tool tip from the programmed straight line, mm.
    pub tip_tolerance: f64,
    /// Largest angle between the tool axis and the programmed great-circle arc, degrees.
    pub axis_tolerance: f64,
    /// The shortest piece is `2^-max_depth` of its move (so at most `2^max_depth` pieces);
    /// where a shorter one would be needed, a piece of that length is kept as it is, with
    /// a warning.
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
        let pass = Densify::new(machine.clone(), super::options(t)?)?;
        Ok(Box::new(pass.printed_with(ctx.decimals)?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// Closer than this to a singular orientation (degrees) the free rotary is held at its
/// interpolated value instead of taking the inverse kinematics' arbitrary choice.
const SINGULAR_DEG: f64 = 1e-6;

/// Bisection levels of one check before a move is treated as out of tolerance; only a
/// deviation within rounding of the tolerance gets that deep.
const CHECK_LEVELS: u8 = 20;

/// How close to the longest piece within tolerance the search for a piece's end gets, as
/// a share of the piece's length: a piece is at most 2 % shorter than it could be.
const PRECISION: f64 = 0.02;

/// Why `densify` left a piece of a move out of tolerance, the worse last.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd)]
enum Shortfall {
    /// A piece would have to be shorter than `2^-max_depth` of the move.
    Depth,
    /// The print rounding of the rotaries alone moves the tip this far (mm), beyond the
    /// tolerance, however short the piece.
    Rounding(f64),
}

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
    /// How far each rotary's printed value lies from its value here, radians (0 when
    /// the backend does not print).
    rotary_rounding: [f64; 2],
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

/// The end of the longest piece within tolerance from parameter `s0` of a move (whose
/// end, at 1, is known to be beyond tolerance from `s0`): `probe(s)` gives the piece's end
/// at `s` when the piece from `s0` to it fits. The search starts at `s0 + step`, doubles
/// the piece while it fits and then bisects, until the end found is within [`PRECISION`]
/// of the piece's length from the shortest end known not to fit. `None` when no piece
/// of at least `min_step` fits. `densify` and `polar-ik` (on arcs) cut moves with it.
pub(crate) fn longest_piece<N>(
    s0: f64,
    step: f64,
    min_step: f64,
    mut probe: impl FnMut(f64) -> Option<N>,
) -> Option<(f64, N)> {
    let rest = 1.0 - s0;
    let mut hi = 1.0;
    let mut lo: Option<(f64, N)> = None;
    let mut s = (s0 + step.max(min_step)).min(s0 + 0.5 * rest);
    // Each round halves the bracket or doubles the piece: 64 rounds reach the last bit.
    for _ in 0..64 {
        if let Some(n) = probe(s) {
            let done = hi - s <= (s - s0) * PRECISION;
            lo = Some((s, n));
            if done {
                break;
            }
            s = (s0 + 2.0 * (s - s0)).min(0.5 * (s + hi));
        } else {
            hi = s;
            let base = lo.as_ref().map_or(s0, |l| l.0);
            if hi - s0 < min_step || (lo.is_some() && hi - base <= (base - s0) * PRECISION) {
                break;
            }
            s = 0.5 * (base + hi);
        }
    }
    lo.filter(|(s, _)| s - s0 >= min_step)
}

/// Puts out a copy of `motion` (span, feed, extra words) ending at `node`.
fn piece(motion: &Motion, span: Span, node: &Node, out: &mut Output<'_>) {
    let mut p = motion.clone();
    p.target = Target::Joints(node.joints);
    out.push(Block::new(span, BlockKind::Motion(p)));
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
    /// The axis tolerance left after the print rounding of the rotaries, radians.
    axis_tol: f64,
    sin_axis_tol: f64,
    /// How far a printed value may lie from the computed one: half a unit of the last
    /// printed decimal of a linear axis (mm) and of a rotary (radians); 0 unprinted.
    rounding: [f64; 2],
    /// The decimals the rotaries are printed with, when the backend prints.
    rotary_places: Option<u8>,
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
            rounding: [0.0; 2],
            rotary_places: None,
            options,
            prev: Joints::default(),
            nodes: [None, None],
            prev_slot: 0,
        })
    }

    /// The same pass for a backend that prints with `decimals`: the tolerances hold on
    /// the printed positions, which the rounding moves by up to half a unit of the last
    /// decimal in each axis. An error when a tolerance is finer than that can hold.
    pub fn printed_with(mut self, decimals: Option<Decimals>) -> Result<Densify, Diagnostic> {
        let Some(d) = decimals else {
            return Ok(self);
        };
        let half = |places: u8| 0.5 * 10f64.powi(-i32::from(places));
        self.rounding = [half(d.linear), half(d.rotary).to_radians()];
        self.rotary_places = Some(d.rotary);
        // Each rotary turns the tool axis by up to its rounding.
        self.axis_tol = self.options.axis_tolerance.to_radians() - 2.0 * self.rounding[1];
        self.sin_axis_tol = self.axis_tol.sin();
        if self.axis_tol <= 0.0 || self.options.tip_tolerance <= self.rounding[0] * 3f64.sqrt() {
            return Err(Diagnostic::settings(format!(
                "densify tolerances ({} mm, {} degrees) are finer than the printed positions \
                 ({} and {} decimals) can hold: raise them or print more decimals",
                self.options.tip_tolerance, self.options.axis_tolerance, d.linear, d.rotary
            )));
        }
        Ok(self)
    }

    /// How far the print rounding may move the tool tip on the joint-linear path from
    /// `a` to `b`, mm. The rounding of each end is interpolated along the path like the
    /// joints, so it is within the larger end's everywhere: X, Y, Z move the tip by up to
    /// `√3` times half their last unit (not their own rounding: `feed:hold_units` may
    /// print a neighbour's value), and a rotary printed `δ` off moves it by `δ` times its
    /// distance from that rotary's axis, which along the piece stays below the larger of
    /// the ends' distances plus how far the piece goes. A rotary printed exactly (a whole
    /// angle, say) costs nothing however far the tip is from its axis.
    fn print_error(&self, a: &Node, b: &Node) -> f64 {
        let [lin, rot] = self.rounding;
        if rot == 0.0 && lin == 0.0 {
            return 0.0;
        }
        let reach = |i: usize| a.at.reach[i].max(b.at.reach[i]);
        let travel = (Vector3::from(b.at.xyz) - Vector3::from(a.at.xyz)).norm()
            + (0..2)
                .map(|i| (b.at.angles[i] - a.at.angles[i]).abs().to_radians() * reach(i))
                .sum::<f64>();
        let rotary = (0..2)
            .map(|i| a.rotary_rounding[i].max(b.rotary_rounding[i]) * (reach(i) + travel))
            .sum::<f64>();
        lin * 3f64.sqrt() + rotary
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
        let rounding = |deg: f64| {
            self.rotary_places
                .map_or(0.0, |places| match print::printed(deg, places) {
                    Some(p) => (p - deg).abs().to_radians(),
                    // Beyond what prints: the backend reports it; count half a unit.
                    None => self.rounding[1],
                })
        };
        Node {
            joints,
            at: self.machine.path_end(xyz, angles),
            pose: OnceCell::new(),
            rotary_rounding: [rounding(angles[0]), rounding(angles[1])],
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
        let tol = self.options.tip_tolerance - self.print_error(a, b);
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

    /// Whether the rotary values `angles` are within the rotaries' travel.
    fn in_travel(&self, angles: [f64; 2]) -> bool {
        (0..2).all(|k| {
            self.machine
                .limits(self.axes[k])
                .is_none_or(|(lo, hi)| (lo - 1e-9..=hi + 1e-9).contains(&angles[k]))
        })
    }

    /// The orientation for `axis` nearest the interpolated rotary values `target` (within
    /// the rotaries' travel where a solution is, when `keep_travel`).
    fn orientation(
        &self,
        axis: Unit<Vector3<f64>>,
        target: [f64; 2],
        keep_travel: bool,
    ) -> [f64; 2] {
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
            let mut cost = (a[0] - target[0]).powi(2) + (a[1] - target[1]).powi(2);
            // A solution past a rotary's travel only where there is no other: the pieces
            // of a move within travel (that `ik` took across a branch change, say) must
            // not leave the machine's range.
            if keep_travel && !self.in_travel(a) {
                cost += 1e12;
            }
            if best.is_none_or(|(_, c)| cost < c) {
                best = Some((a, cost));
            }
        }
        // Out of the axis pair's reach (cannot happen between two reachable poses on
        // the machines modelled): keep the interpolated angles, the tip stays exact.
        best.map_or(target, |(a, _)| a)
    }

    /// The position at fraction `s` of the programmed move from `a` to `b` (whose
    /// tool-axis arc is `arc`): the tip on the line, the axis on the arc, the rotaries
    /// nearest their values interpolated from `from` (the piece's start, at its fraction,
    /// so the pieces follow the branch the path is on even where the rotaries swing
    /// unevenly, near a singular orientation) to `b`, and every other axis interpolated.
    fn node_on(&self, a: &Node, b: &Node, arc: &AxisArc, s: f64, from: &(f64, Node)) -> Node {
        let (ta, tb) = (self.pose(a).tip, self.pose(b).tip);
        let tip = ta + (tb - ta) * s;
        let axis = arc.slerp(s);
        let l = |p: f64, q: f64| p + (q - p) * s;
        let u = if from.0 < 1.0 {
            (s - from.0) / (1.0 - from.0)
        } else {
            1.0
        };
        let lf = |k: usize| from.1.at.angles[k] + (b.at.angles[k] - from.1.at.angles[k]) * u;
        let target = [lf(0), lf(1)];
        let keep_travel = self.in_travel(a.at.angles) && self.in_travel(b.at.angles);
        let angles = self.orientation(axis, target, keep_travel);
        let xyz = self.machine.linear(&tip, angles);
        let mut joints = b.joints;
        for ax in b.joints.known.iter() {
            match a.joints.get(ax) {
                Some(v) => joints.values[ax.index()] = l(v, b.joints.values[ax.index()]),
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

    /// Emits the pieces of the move from `a` to `b` but its last (the caller puts out
    /// the original block there); why a piece had to stay out of tolerance, if one did.
    fn split_move(
        &self,
        motion: &Motion,
        span: Span,
        a: &Node,
        b: &Node,
        out: &mut Output<'_>,
    ) -> Option<Shortfall> {
        match self.turn_on_the_spot(a, b) {
            Some(m) => {
                let first = self.cut(motion, span, a, &m, out);
                piece(motion, span, &m, out);
                let second = self.cut(motion, span, &m, b, out);
                // The worse of the two halves (`None` is the least).
                if second > first { second } else { first }
            }
            None => self.cut(motion, span, a, b, out),
        }
    }

    /// Cuts the programmed move from `a` to `b` into the longest pieces within tolerance
    /// and puts out every piece of `motion` but the last (ending at `b`); says why a piece
    /// had to stay out of tolerance: shorter than `2^-max_depth` of the move, or the print
    /// rounding alone beyond the tolerance (then the rest of the move stays whole, as no
    /// cut can help: it would only print up to `2^max_depth` useless blocks).
    fn cut(
        &self,
        motion: &Motion,
        span: Span,
        a: &Node,
        b: &Node,
        out: &mut Output<'_>,
    ) -> Option<Shortfall> {
        let arc = self.arc(a, b);
        let min_step = 0.5f64.powi(self.options.max_depth as i32);
        let mut shortfall = None;
        let mut cur = (0.0, a.clone());
        let mut last_len: Option<f64> = None;
        let mut fits_rest = self.within(a, b);
        while !fits_rest {
            let floor = self.print_error(&cur.1, &cur.1);
            if floor >= self.options.tip_tolerance {
                return Some(Shortfall::Rounding(floor));
            }
            let (s, node, fits) = self.longest(a, b, &arc, &cur, last_len, min_step);
            if !fits {
                shortfall = Some(Shortfall::Depth);
            }
            if s >= 1.0 {
                break;
            }
            fits_rest = self.within(&node, b);
            if fits_rest && fits {
                // The last two pieces share the rest evenly, rather than the longest
                // piece and a sliver after it.
                let even = self.node_on(a, b, &arc, 0.5 * (cur.0 + 1.0), &cur);
                if self.within(&cur.1, &even) && self.within(&even, b) {
                    piece(motion, span, &even, out);
                    break;
                }
            }
            piece(motion, span, &node, out);
            last_len = Some(s - cur.0);
            cur = (s, node);
        }
        shortfall
    }

    /// The longest piece from `cur` (at fraction `cur.0` of the move from `a` to `b`)
    /// within tolerance ([`longest_piece`]): its end's fraction and node, and true; or,
    /// when no piece of at least `min_step` fits, the piece of `min_step` and false. The
    /// search starts from the previous piece's length `guess` (pieces along one move
    /// change length slowly) or else from the curvature bound.
    fn longest(
        &self,
        a: &Node,
        b: &Node,
        arc: &AxisArc,
        cur: &(f64, Node),
        guess: Option<f64>,
        min_step: f64,
    ) -> (f64, Node, bool) {
        let s0 = cur.0;
        let step = guess.unwrap_or_else(|| {
            // The bound of a piece grows with the square of its length; it overstates
            // the deviation, so this is about the shortest fitting length.
            let (tip, axis) = self.machine.path_bounds(&cur.1.at, &b.at);
            let ratio =
                (tip / (8.0 * self.options.tip_tolerance)).max(axis / (8.0 * self.sin_axis_tol));
            (1.0 - s0) / ratio.sqrt().max(1.0)
        });
        let probe = |s: f64| {
            let n = self.node_on(a, b, arc, s, cur);
            self.within(&cur.1, &n).then_some(n)
        };
        match longest_piece(s0, step, min_step, probe) {
            Some((s, n)) => (s, n, true),
            None => {
                let s = (s0 + min_step).min(1.0);
                let n = if s >= 1.0 {
                    b.clone()
                } else {
                    self.node_on(a, b, arc, s, cur)
                };
                (s, n, false)
            }
        }
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
            let shortfall = if self.options.max_depth == 0 {
                Some(Shortfall::Depth)
            } else {
                self.split_move(m, block.span, a, b, out)
            };
            if let Some(why) = shortfall {
                out.diag(self.shortfall_warning(why).at_span(block.span));
            }
        }
        self.moved_to(m, end, end_slot);
    }

    fn shortfall_warning(&self, why: Shortfall) -> Diagnostic {
        match why {
            Shortfall::Depth => Diagnostic::warning(
                "densify::depth",
                format!(
                    "a piece of this move stays off the programmed path: pieces would have to \
                     be shorter than 2^-{} of the move",
                    self.options.max_depth
                ),
            )
            .with_help(
                "the rotaries swing far for this move (a singularity or a branch change?); \
                 raise max_depth or the tolerances, or check the ik choices",
            ),
            Shortfall::Rounding(floor) => Diagnostic::warning(
                "densify::rounding",
                format!(
                    "the printed rotary positions alone put the tool tip up to {floor:.4} mm off \
                     here, beyond tip_tolerance {} mm: the tip is far from a rotary axis, where \
                     the last printed decimal of an angle is a long way; the rest of the move is \
                     not cut",
                    self.options.tip_tolerance
                ),
            )
            .with_help(
                "bring the work closer to the rotary axes, print more rotary decimals, or raise \
                 tip_tolerance",
            ),
        }
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
