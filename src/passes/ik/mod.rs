//! `ik`: tool poses to joint values for two-rotary machines (limits, look-ahead, preference).
//!
//! Every motion with a [`Target::Pose`] becomes a [`Target::Joints`] with X, Y, Z and both
//! rotaries set. The rotary values come from the closed-form inverse kinematics
//! ([`Machine::inverse`], up to two orientations, the branches), each angle taken at the
//! whole turn that suits it: nearest the previous value of a cyclic axis, inside
//! `[min, max]` (nearest the previous value) for a limited one. X, Y, Z follow from
//! [`Machine::linear_at`], with the rotaries' sines and cosines those of the solution
//! ([`crate::machine::Solutions::sin_cos`]; from the degrees for a held rotary), so
//! FK(joints) reproduces the pose exactly outside the singularity cone.
//!
//! # Look-ahead
//! The branch of each pose is not chosen greedily: the poses wait in a window that reaches
//! the next rapid (at most 4096 poses, or 8192 blocks with those between them: a bounded
//! look-ahead that keeps the pass streaming), and dynamic programming over both branches
//! of every pose picks the sequence with the fewest flips, then the least rotary travel
//! (largest change per move, then both changes), then the machine's preferred sign (first
//! rotary with a `prefer`) at the window's start. Branches a limited rotary cannot reach are left out. A long
//! cutting move is followed along its tool-axis path (`Ik::walked_from`), so a turn
//! never swaps branches through the singularity. A rapid starts a new window: the rotaries
//! may turn freely there, so a flip the cut after it would need is made at the rapid. A
//! command or line that clobbers axes, a joint move or an offset ends the window (the
//! position the next pose starts from changes); after a clobber the next pose is chosen
//! by preference again.
//!
//! # Singularities
//! Within `singularity_cone` degrees of an orientation where one rotary stops mattering
//! (a cradle's C table when the tool stands vertical), that rotary keeps its previous
//! value and the other one turns the tool ([`Machine::hold`]). Leaving the cone in a
//! cutting move may need a swing of the held rotary: it is spread over the start of the
//! move (`Ik::spread_swing`) in pieces along the programmed line, the tool axis leaning
//! at most 0.02 degrees (`swing::SWING_LEAN`) off the programmed one meanwhile, so the tip keeps
//! moving at the programmed feed instead of standing in the material while the rotary
//! turns. A swing above `singular_jump` gets the warning `ik::singular-swing`.
//!
//! # Unreachable poses and flips
//! A pose no orientation reaches within the limits is the error `ik::unreachable`; the
//! block is dropped and the pass goes on, so every such line is reported. When no
//! sequence of branches within the limits avoids it, a cutting move must flip to the
//! other solution; with a rotary change above `max_cutting_jump` that would drag the tool
//! through the part, so it is the error `ik::flip`, whose message says why no flip-free
//! choice exists (from each branch at the window's start, the line where a limit stops
//! it), or with `on_flip = "retract"` a retract along the tool axis (a linear move at the
//! block's feed: the tool may still be in the material), a rapid turning the rotaries
//! above the new point and a linear plunge onto it, with the warning `ik::retract`.
//!
//! Joint moves, commands, comments and offset blocks pass through, in order. An arc to a
//! pose is the error `ik::arc` (the CL frontend cuts arcs into lines).

use nalgebra::{Point3, Unit, Vector3};
use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Joints, Motion, MotionKind, Span, Target, Tracker,
};
use crate::machine::angle::{LIMIT_SLACK, near_turn, turn_within};
use crate::machine::{Machine, Orientation, Prefer, Turns};

mod flip;
mod swing;
#[cfg(test)]
mod tests;
mod window;

/// What `ik` does where the path must flip to the other solution in a cutting move.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OnFlip {
    /// Report the error `ik::flip`.
    #[default]
    Error,
    /// Retract along the tool axis, turn the rotaries, plunge back (warning `ik::retract`).
    Retract,
}

/// Options of `ik`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Within this angle (degrees) of a singular orientation the free rotary keeps its
    /// previous value.
    pub singularity_cone: f64,
    /// A swing of the held rotary larger than this (degrees) when the path leaves the
    /// singularity cone in a cutting move is reported (`ik::singular-swing`).
    pub singular_jump: f64,
    /// What to do when the path must flip to the other solution in a cutting move.
    pub on_flip: OnFlip,
    /// How far (mm, along the tool axis) a flip retracts before turning.
    pub retract_distance: f64,
    /// Largest rotary change (degrees) a cutting move may make to reach the other
    /// solution before it counts as a flip. The default, 90, lets any move that stays on
    /// its branch through, while a branch change (about 180 degrees of the cyclic axis)
    /// is caught.
    pub max_cutting_jump: f64,
    /// The machine Z (mm, the frame the joints are in) a flip lifts to before the
    /// rotaries turn: high enough that the part and its fixture clear the tool while
    /// the table or head swings. Without it, the top of the machine's Z travel; without
    /// either, a flip cannot be retracted safely and stays the error `ik::flip`.
    pub clearance: Option<f64>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            singularity_cone: 0.01,
            singular_jump: 10.0,
            on_flip: OnFlip::Error,
            retract_distance: 20.0,
            max_cutting_jump: 90.0,
            clearance: None,
        }
    }
}

impl Options {
    fn check(&self) -> Result<(), Diagnostic> {
        let problem = if !(self.singularity_cone.is_finite()
            && (0.0..90.0).contains(&self.singularity_cone))
        {
            "singularity_cone must be at least 0 and below 90 degrees"
        } else if !(self.singular_jump.is_finite() && self.singular_jump >= 0.0) {
            "singular_jump must be a number of degrees >= 0"
        } else if !(self.retract_distance.is_finite() && self.retract_distance > 0.0) {
            "retract_distance must be a positive number of millimetres"
        } else if !(self.max_cutting_jump.is_finite() && self.max_cutting_jump > 0.0) {
            "max_cutting_jump must be a positive number of degrees"
        } else if self.clearance.is_some_and(|c| !c.is_finite()) {
            "clearance must be a number of millimetres"
        } else {
            return Ok(());
        };
        Err(Diagnostic::settings(problem))
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "ik",
    summary: "tool poses to joint values: both closed-form solutions, chosen by limits, continuity and preferred sign; singularities held, unreachable poses and flips reported",
    build: |t, ctx| {
        let machine = ctx.require_machine("ik")?;
        Ok(Box::new(Ik::new(machine.clone(), super::options(t)?)?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// Largest tool-axis turn (degrees) compared by end points alone; longer cutting moves are
/// followed along their path (see `Ik::walked_from`).
const WALK_STEP: f64 = 2.0;

/// A walk's steps are at most this fraction of the tool axis's distance from the singular
/// direction (see `Ik::walk`), and a move counts as passing it when its turn is more than
/// this fraction of its ends' distance (`Ik::passes_singular`).
const WALK_RATIO: f64 = 4.0;

/// The shortest step of a walk, degrees: a move passing closer than half this to the
/// singular direction may be walked through it (the tool axis that far off the arc).
const MIN_WALK_STEP: f64 = 0.01;

/// Most steps of one walk: a half turn in steps of [`WALK_STEP`] takes 90, the approach to
/// and the way away from the singular direction some 40.
const MAX_WALK_STEPS: usize = 4096;

/// Costs closer than this (degrees) are a tie, decided by the preferred sign.
const TIE: f64 = 1e-9;

/// The rotary values chosen for a pose.
#[derive(Debug, Clone, Copy)]
struct Choice {
    /// Joint values of the two rotaries, listing order.
    angles: [f64; 2],
    /// The rotary held at its previous value (singularity).
    held: Option<usize>,
    /// The path flips to the other solution: the rotaries the continuous solution would
    /// need (out of limits) and the largest change of the chosen one, degrees.
    flip: Option<([f64; 2], f64)>,
    /// The sine and cosine of both rotaries' physical angles when they come from the
    /// solution ([`crate::machine::Solutions::sin_cos`]; a whole turn keeps them); `None`
    /// for a held rotary.
    trig: Option<Turns>,
}

/// One orientation at the turns that suit the previous joints ([`Ik::candidate`]).
#[derive(Debug, Clone, Copy)]
struct Candidate {
    /// The turns nearest the previous values, ignoring the limits, and their cost.
    unlimited: [f64; 2],
    unlimited_cost: (f64, f64),
    /// The turns inside the limits and their cost; `None` when a rotary cannot reach.
    limited: Option<([f64; 2], (f64, f64))>,
}

/// The `ik` pass.
pub struct Ik {
    machine: Machine,
    options: Options,
    axes: [Axis; 2],
    /// The joints after the last emitted block.
    prev: Joints,
    /// The rotary held at a singularity by the last pose block.
    held: Option<usize>,
    /// The line of that block when it was a rapid: a swing the next cut needs is made
    /// there, before the tool enters the material (`Ik::spread_swing`).
    held_rapid: Option<Span>,
    /// The rotary values and tool axis of the last pose block.
    last_axis: Option<([f64; 2], Unit<Vector3<f64>>)>,
    /// cos(singularity_cone).
    cone_cos: f64,
    /// The cosine of an axis turn surely below [`WALK_STEP`].
    within_step_cos: f64,
    /// The rotaries' limits (`None`: cyclic), listing order.
    limits: [Option<(f64, f64)>; 2],
    /// The line of the first statement that set a rotated frame the frontend did not
    /// apply ([`crate::ir::FRAME_NOT_APPLIED`]): named in the help of unreachable poses.
    frame_note: Option<u32>,
    /// The poses waiting for the look-ahead to choose their branches, with the blocks
    /// between them ([`window::Window`]).
    window: window::Window,
    /// The pieces of a swing being spread (`Ik::spread_swing`), kept between blocks so
    /// that spreading allocates nothing.
    swing_buf: Vec<(Point3<f64>, [f64; 2])>,
}

impl Ik {
    /// An `ik` pass for `machine`.
    pub fn new(machine: Machine, options: Options) -> Result<Ik, Diagnostic> {
        options.check()?;
        machine.check()?;
        let axes = machine.rotary_axes();
        let cone_cos = options.singularity_cone.to_radians().cos();
        let limits = axes.map(|a| machine.limits(a));
        Ok(Ik {
            machine,
            options,
            axes,
            prev: Joints::default(),
            held: None,
            held_rapid: None,
            last_axis: None,
            cone_cos,
            within_step_cos: (WALK_STEP * (1.0 - 1e-6)).to_radians().cos(),
            limits,
            frame_note: None,
            window: window::Window::default(),
            swing_buf: Vec::new(),
        })
    }

    fn prev_angles(&self) -> [Option<f64>; 2] {
        [self.prev.get(self.axes[0]), self.prev.get(self.axes[1])]
    }

    /// Rotary `i` at `v + 360 k` inside its limits, nearest `prev` (nearest `v` without
    /// one); `None` when no turn of `v` is inside.
    fn in_limits(&self, i: usize, v: f64, prev: Option<f64>) -> Option<f64> {
        match self.limits[i] {
            None => Some(prev.map_or(v, |p| near_turn(v, p))),
            Some((lo, hi)) => turn_within(v, lo, hi, prev),
        }
    }

    /// Rotary `i` at the turn of `v` nearest `prev` ignoring the limits (`v` itself
    /// without a previous value), and [`Ik::in_limits`] of it.
    fn turns(&self, i: usize, v: f64, prev: Option<f64>) -> (f64, Option<f64>) {
        (
            prev.map_or(v, |p| near_turn(v, p)),
            self.in_limits(i, v, prev),
        )
    }

    /// How far `angles` is from the previous joints (known rotaries only): the largest
    /// change, then the sum of both (so of two orientations with the same largest change
    /// the one that moves the other rotary less wins).
    fn cost(&self, angles: [f64; 2], prev: [Option<f64>; 2]) -> (f64, f64) {
        let (mut largest, mut sum) = (0.0f64, 0.0);
        for (a, p) in angles.into_iter().zip(prev) {
            if let Some(p) = p {
                let d = (a - p).abs();
                largest = largest.max(d);
                sum += d;
            }
        }
        (largest, sum)
    }

    /// Orientation `o` taken at the turns that suit it for `prev` ([`Ik::turns`]): the
    /// angles ignoring the limits and their [`Ik::cost`], and the angles inside the limits
    /// with theirs when both rotaries reach.
    fn candidate(&self, o: &Orientation, prev: [Option<f64>; 2]) -> Candidate {
        let (u0, l0) = self.turns(0, o.angles[0], prev[0]);
        let (u1, l1) = self.turns(1, o.angles[1], prev[1]);
        let unlimited = [u0, u1];
        let limited = match (l0, l1) {
            (Some(a0), Some(a1)) => Some(([a0, a1], self.cost([a0, a1], prev))),
            _ => None,
        };
        Candidate {
            unlimited,
            unlimited_cost: self.cost(unlimited, prev),
            limited,
        }
    }

    /// Whether cost `a` is clearly below cost `b`; `None` on a tie.
    fn less(a: (f64, f64), b: (f64, f64)) -> Option<bool> {
        if (a.0 - b.0).abs() > TIE {
            Some(a.0 < b.0)
        } else if (a.1 - b.1).abs() > TIE {
            Some(a.1 < b.1)
        } else {
            None
        }
    }

    /// Whether `angles` has the sign the machine prefers (first rotary with a preference).
    fn preferred(&self, angles: [f64; 2]) -> bool {
        for (i, r) in self.machine.rotary.iter().enumerate() {
            match r.prefer {
                Prefer::Positive => return angles[i] >= -LIMIT_SLACK,
                Prefer::Negative => return angles[i] <= LIMIT_SLACK,
                Prefer::None => {}
            }
        }
        false
    }

    /// The rotary values reached by following the tool axis from orientation `from` (at
    /// rotary values `prev`) to `axis` along the great circle (the path densify makes the
    /// tool take), taking the nearest solution at each step ([`Ik::walk`]). Comparing end
    /// points alone can pick the other branch when a move turns the axis far: from A20
    /// C240 to a 70 deg tilt, A-70 C160 is "nearer" than A70 C340, but getting there
    /// swings the tool through vertical, off the programmed path. So it can when a short
    /// move passes close by the singular direction: the free rotary sweeps the angle the
    /// move subtends there, up to half a turn, and past a quarter turn the other branch's
    /// ends look nearer (a B head over a C table passing 0.3 deg from vertical: C sweeps
    /// 136 deg along the move, while B-1.5 C-44 at its end is "nearer" than B1.5 C136).
    fn walked_from(
        &self,
        from: Unit<Vector3<f64>>,
        axis: Unit<Vector3<f64>>,
        prev: [Option<f64>; 2],
    ) -> [Option<f64>; 2] {
        let [Some(p0), Some(p1)] = prev else {
            return prev;
        };
        // Most blocks turn the axis far less than a step: tell that from the cosine (the
        // one `angle` takes the arccosine of) against a cone a little narrower than a step,
        // so that acos rounding cannot matter. Both are unit vectors: their dot product is
        // the cosine, to a rounding far inside the cone's margin.
        let dot = from.dot(&axis);
        if dot >= 1.0 || (dot >= self.within_step_cos && !self.passes_singular(from, axis, dot)) {
            return prev;
        }
        match self.walk(from, axis, [p0, p1]) {
            Some([a0, a1]) => [Some(a0), Some(a1)],
            None => prev,
        }
    }

    /// Whether the turn from tool axis `from` to `axis` (`dot` the cosine between them)
    /// may come close enough to the singular direction that the free rotary sweeps far
    /// along it. The free rotary turns by the angle the move subtends at the singular
    /// direction, at most the turn over the sine of the nearest distance to it along the
    /// way, and that distance is at least the ends' nearer one less half the turn: a turn
    /// at most a quarter of both ends' distances sweeps at most 17 degrees, and the
    /// nearest ends are then those the move reaches. Without trigonometry: the squared
    /// turn is at most 2.002 (1 - dot) below 2 degrees, the squared distance at least its
    /// squared sine.
    fn passes_singular(
        &self,
        from: Unit<Vector3<f64>>,
        axis: Unit<Vector3<f64>>,
        dot: f64,
    ) -> bool {
        let turn2 = 2.002 * (1.0 - dot);
        let sin2 = |a: Unit<Vector3<f64>>| {
            let c = self.machine.singularity_cos(a);
            1.0 - c * c
        };
        // A start held inside the singularity cone has its free rotary where the path
        // before left it, not where the tool axis points: walking from there would follow
        // a branch chosen by that held value, so the end's nearest solution decides.
        if self.machine.singularity_cos(from) > self.cone_cos {
            return false;
        }
        WALK_RATIO * WALK_RATIO * turn2 > sin2(from).min(sin2(axis))
    }

    /// The tool axis the last emitted pose asked for, unless the rotaries moved since
    /// (then the one they point); `None` when a rotary is unknown.
    fn committed_axis(&self) -> Option<Unit<Vector3<f64>>> {
        let [Some(p0), Some(p1)] = self.prev_angles() else {
            return None;
        };
        Some(match self.last_axis {
            Some((angles, axis)) if angles == [p0, p1] => axis,
            _ => self.machine.forward(&[0.0; 3], [p0, p1]).axis,
        })
    }

    /// [`Ik::walked_from`] from tool axis `from` at rotary values `[p0, p1]` to `axis`: the
    /// values reached, or `None` to keep `[p0, p1]` (axes nearly opposite: no one great
    /// circle joins them). The steps are at most [`WALK_STEP`] and at most a
    /// [`WALK_RATIO`]th of the distance from the singular direction, so the free rotary
    /// turns at most some 17 degrees a step and the nearest solution stays on the branch;
    /// within [`MIN_WALK_STEP`] of it a step may pass it (the tool axis tilts through the
    /// singular direction, at most that far off the programmed arc), and within the
    /// singularity cone the free rotary is held ([`Ik::continuous`]), as `ik` holds it.
    fn walk(
        &self,
        from: Unit<Vector3<f64>>,
        axis: Unit<Vector3<f64>>,
        [p0, p1]: [f64; 2],
    ) -> Option<[f64; 2]> {
        let turn = from.angle(&axis);
        if turn <= 0.0 || turn > (180.0 - WALK_STEP).to_radians() {
            return None;
        }
        let (max_step, min_step) = (WALK_STEP.to_radians(), MIN_WALK_STEP.to_radians());
        let mut cur = [p0, p1];
        let mut t = 0.0;
        let mut at = from;
        // From a start held in the singularity cone the first step is a whole one: the
        // held free rotary says nothing about the branch, and fine steps where the path
        // leaves the cone would follow its azimuth there instead of the move's end.
        let held = self.machine.singularity_cos(from) > self.cone_cos;
        for _ in 0..MAX_WALK_STEPS {
            let c = self.machine.singularity_cos(at);
            let distance = (1.0 - c * c).max(0.0).sqrt();
            let step = if held && t == 0.0 {
                max_step
            } else {
                (distance / WALK_RATIO).clamp(min_step, max_step)
            };
            t = (t + step / turn).min(1.0);
            at = if t >= 1.0 {
                axis
            } else {
                from.try_slerp(&axis, t, 1e-12)?
            };
            cur = self.continuous(at, cur);
            if t >= 1.0 {
                return Some(cur);
            }
        }
        None
    }

    /// How far (degrees) `axis` is from the nearest orientation the rotaries reach within
    /// their limits; `None` when the machine has no limited rotary to measure against.
    fn miss_angle(&self, axis: Unit<Vector3<f64>>) -> Option<f64> {
        let mut best: Option<f64> = None;
        for i in 0..2 {
            let Some((lo, hi)) = self.machine.limits(self.axes[i]) else {
                continue;
            };
            for bound in [lo, hi] {
                let o = self.machine.hold(axis, i, bound);
                let j = 1 - i;
                let others: Vec<f64> = match self.in_limits(j, o.angles[j], None) {
                    Some(v) => vec![v],
                    None => match self.machine.limits(self.axes[j]) {
                        Some((l, h)) => vec![l, h],
                        None => vec![o.angles[j]],
                    },
                };
                for v in others {
                    let mut angles = [0.0; 2];
                    angles[i] = bound;
                    angles[j] = v;
                    let reached = self.machine.forward(&[0.0; 3], angles).axis;
                    let deg = reached.dot(&axis).clamp(-1.0, 1.0).acos().to_degrees();
                    if best.is_none_or(|b| deg < b) {
                        best = Some(deg);
                    }
                }
            }
        }
        best
    }

    /// The rotaries' ranges, for messages: `A -90..135 deg, C unlimited`.
    fn ranges(&self) -> String {
        let parts: Vec<String> = (0..2)
            .map(|i| match self.machine.limits(self.axes[i]) {
                Some((lo, hi)) => format!("{} {lo}..{hi} deg", self.axes[i].letter()),
                None => format!("{} unlimited", self.axes[i].letter()),
            })
            .collect();
        parts.join(", ")
    }

    /// The joint vector for the rotaries at `angles` with the tip on `tip`, carrying the
    /// other known axes (those of `extra` but X, Y, Z and the rotaries, else the previous
    /// joints'); `trig`, when known, is the sine and cosine of both rotaries' physical
    /// angles (the chain then needs no sin_cos of the degrees).
    fn joints_at(
        &self,
        tip: &nalgebra::Point3<f64>,
        angles: [f64; 2],
        trig: Option<Turns>,
        extra: &Joints,
    ) -> Joints {
        let xyz = match trig {
            Some(turns) => self.machine.linear_at(tip, &turns),
            None => self.machine.linear(tip, angles),
        };
        let mut values = self.prev.values;
        for a in extra.known.iter() {
            values[a.index()] = extra.values[a.index()];
        }
        values[..3].copy_from_slice(&xyz);
        values[self.axes[0].index()] = angles[0];
        values[self.axes[1].index()] = angles[1];
        Joints {
            values,
            known: self.prev.known.union(extra.known).union(self.written()),
        }
    }

    fn written(&self) -> AxisSet {
        let mut w = AxisSet::XYZ;
        w.insert(self.axes[0]);
        w.insert(self.axes[1]);
        w
    }

    /// The previous X, Y, Z and rotaries, when all five are known.
    fn prev_five(&self) -> Option<([f64; 3], [f64; 2])> {
        let p = &self.prev;
        Some((
            [p.get(Axis::X)?, p.get(Axis::Y)?, p.get(Axis::Z)?],
            [p.get(self.axes[0])?, p.get(self.axes[1])?],
        ))
    }

    /// The rotary that swings by more than `singular_jump` as a cutting move leaves the
    /// singularity with `choice`, and by how much (degrees): the `ik::singular-swing` case.
    fn singular_swing(&self, choice: &Choice, cutting: bool) -> Option<(usize, f64)> {
        if choice.held.is_some() || !cutting {
            return None;
        }
        let k = self.held?;
        let swing = (choice.angles[k] - self.prev.get(self.axes[k])?).abs();
        (swing > self.options.singular_jump).then_some((k, swing))
    }

    /// Makes pose motion `m` the joints of `choice` (which the look-ahead chose
    /// for its pose), carrying the pose's other axes, and takes them as the previous joints.
    fn apply(&mut self, m: &mut Motion, choice: &Choice) {
        let Target::Pose(pose) = &m.target else {
            return;
        };
        let target = self.joints_at(&pose.tip, choice.angles, choice.trig, pose.extra());
        self.last_axis = Some((choice.angles, pose.axis));
        m.target = Target::Joints(target);
        self.prev = target;
        m.written = m.written.union(self.written());
        self.held = choice.held;
    }

    /// What a block other than a pose motion tells the pass about the axes: the one
    /// position tracker of the IR ([`Tracker`]) follows it.
    fn track(&mut self, block: &Block) {
        if self.frame_note.is_none() && crate::ir::frame_not_applied(block) {
            self.frame_note = Some(block.span.line);
        }
        let mut tracker = Tracker::at(self.prev);
        tracker.update(block);
        self.prev = *tracker.pos();
        if let BlockKind::Motion(m) = &block.kind
            && let Target::Joints(_) = &m.target
        {
            // Joint moves from elsewhere end any hold at a singularity.
            self.held = None;
            self.held_rapid = None;
        }
    }

    /// Turns the pose motion `block` into joints with the rotaries of `choice` (what the
    /// look-ahead chose for it) and puts it out, with the diagnostics and extra blocks it
    /// needs: a spread singular swing, a flip (`no_flip_free` says why no flip-free choice
    /// exists).
    fn emit(
        &mut self,
        mut block: Block,
        choice: &Choice,
        no_flip_free: Option<&str>,
        out: &mut Output<'_>,
    ) {
        let span = block.span;
        let BlockKind::Motion(m) = &mut block.kind else {
            return;
        };
        let cutting = !matches!(m.kind, MotionKind::Rapid);
        let swing = self.singular_swing(choice, cutting);
        let mut at_rapid = false;
        if cutting && choice.flip.is_none() {
            at_rapid = self.spread_swing(span, m, choice, out);
        }
        if let Some((k, swing)) = swing.filter(|_| !at_rapid) {
            out.diag(
                Diagnostic::warning(
                    "ik::singular-swing",
                    format!(
                        "leaving the singular orientation, {} turns {swing:.3} deg in one cutting move",
                        self.axes[k].letter()
                    ),
                )
                .at_span(span)
                .with_help(format!(
                    "the swing is spread over the start of the move so the tip keeps the programmed line and feed, the tool axis leaning up to {} deg off the programmed one meanwhile; keep the tool axis further from the singular direction in the CAM to avoid it",
                    swing::SWING_LEAN
                )),
            );
        }
        if let Some(flip) = choice.flip {
            self.flip(span, m, choice, flip, no_flip_free, out);
        }
        self.apply(m, choice);
        self.held_rapid = (choice.held.is_some() && !cutting).then_some(span);
        out.push(block);
    }

    /// `ik::unreachable` for tool axis `a`.
    fn unreachable(&self, a: Unit<Vector3<f64>>) -> Diagnostic {
        let miss_deg = self.miss_angle(a);
        let miss = match miss_deg {
            Some(d) => format!(", {d:.3} deg from the nearest orientation they reach"),
            None => String::new(),
        };
        let d = Diagnostic::error(
            "ik::unreachable",
            format!(
                "tool axis ({:.6}, {:.6}, {:.6}) is out of reach of the rotaries ({}){miss}",
                a.x,
                a.y,
                a.z,
                self.ranges()
            ),
        )
        .with_help(match self.frame_note {
            Some(line) => format!(
                "line {line} sets a rotated coordinate frame (MSYS or CSYS) that was not applied to the points; if the CAM wrote the tool axes in that frame, set `[cl_input] msys = \"apply\"` (NX MSYS) or output the path in the base frame; otherwise tilt the tool axis less in the CAM, or fixture the part so the path is within the rotaries' limits; the block is left out"
            ),
            None => "tilt the tool axis less in the CAM, or fixture the part so the path is within the rotaries' limits; the block is left out".into(),
        });
        // How far out of reach, for naming the worst of many.
        match miss_deg {
            Some(deg) => d.with_magnitude(deg),
            None => d,
        }
    }
}

impl Pass for Ik {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        self.flush(out);
    }
}

impl Ik {
    /// One block of the input: a pose joins the look-ahead window; anything else waits in
    /// it in order, or, when it changes what the next pose starts from, lets the window's
    /// choice go out first.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        if let BlockKind::Motion(m) = &block.kind
            && let Target::Pose(pose) = &m.target
        {
            let cutting = match m.kind {
                MotionKind::Arc(_) => {
                    self.flush(out);
                    out.diag(
                        Diagnostic::error(
                            "ik::arc",
                            "a circular move to a tool pose cannot be turned into joint values",
                        )
                        .at_span(block.span)
                        .with_help("cut the arc into straight moves before `ik` (the CL frontend does this for CIRCLE)"),
                    );
                    return;
                }
                MotionKind::Rapid => false,
                MotionKind::Linear => true,
            };
            // The rotaries turn freely at a rapid: the window before it is decided.
            if !cutting {
                self.flush(out);
            }
            self.look(pose.axis, cutting, block.span, out);
            self.window.pending.push(block);
            if self.window.full() {
                self.flush(out);
            }
            return;
        }
        if self.window.is_empty() {
            self.track(&block);
            out.push(block);
        } else if window::keeps_position(&block) {
            self.window.pending.push(block);
            if self.window.full() {
                self.flush(out);
            }
        } else {
            self.flush(out);
            self.track(&block);
            out.push(block);
        }
    }
}
