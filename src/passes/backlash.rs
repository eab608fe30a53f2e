//! `backlash`: per-axis backlash compensation in software: a take-up move on every direction reversal, later coordinates shifted by the slack (for controllers without M425).
//!
//! The home-made PCB mill of seed 001 lost 160 µm on every reversal of X and Y before a
//! mechanical fix, 20 µm after, and its own software compensated that per axis. Grbl and
//! such home-made controllers cannot do it themselves; RepRapFirmware and Marlin can
//! (`M425`), and there the firmware's compensation is better (it knows the real step
//! direction, also for jogging and homing): use `M425` there, not this pass.
//!
//! # Options
//! Scalars, so they can be given on the command line
//! (`--pass backlash:x=0.16,y=0.16`):
//! - `x`, `y`, `z` (mm, default `0`): the slack of each axis (the lost motion measured
//!   when the axis reverses). At least one must be `> 0`; none may be negative.
//! - `feed` (mm/min, default: none): the feed of the take-up move inserted before a
//!   reversing feed move. Without it the take-up runs at the reversing move's own feed
//!   (the same F; under G93 inverse time the same speed, F scaled by the move's length
//!   over the take-up's length). A take-up before a rapid is always a rapid.
//! - `start` (`"first-move"`, default): what the pass assumes about the slack where it
//!   knows nothing (program start, after homing or probing). `"first-move"`: the first
//!   move of the axis from a known position finds the slack already taken up in its own
//!   direction (as after a touch-off or a positioning move approached from that side),
//!   so it gets no take-up. `"positive"` / `"negative"`: the slack is taken up in that
//!   direction (as after homing towards a switch on that side; a homing cycle that pulls
//!   off the switch reverses it): a first move the other way gets a take-up.
//!
//! # Method
//! For every compensated axis the pass keeps the direction it last moved in and an offset
//! `o`; the machine is sent `p + o`, with `p` the programmed (IR) position. The offset
//! starts at `0` and, at every reversal, moves by the slack `b` in the new direction
//! (`o += b` when the axis turns to positive, `o -= b` when it turns to negative), so it
//! alternates between `0` and `+b` (first direction negative) or `0` and `-b` (first
//! direction positive). Convention: with `o = 0` the work coordinates are true with the
//! slack taken up in the axis's first direction, which is how the work origin was set.
//!
//! When a move reverses one or more axes, a take-up move comes first: from the current
//! machine position it moves only the reversing axes, each by its `b` in the new
//! direction; the table does not move during it (the motor crosses the slack). The
//! reversing move itself then starts with the slack taken up, and the table follows the
//! programmed path exactly. An axis's direction changes only on moves that move it by
//! more than 1e-6 mm; smaller components (rounding noise) neither reverse nor establish a
//! direction.
//!
//! # Where the physical path differs from the program
//! - At every reversal the tool stands still at the corner while the take-up runs (for a
//!   0.16 mm slack at F70, about 0.14 s). For a spindle that is harmless; for a laser it
//!   would burn a dot, so set a fast `feed` or use `M425` firmware.
//! - The controller's coordinates (its display, its soft limits) are the motor's: up to
//!   `b` beyond the program's extent on the side the axis last moved away from.
//! - The model is the ideal one (the table does not move while the slack is crossed):
//!   a real slack smaller than `b` moves the tool by the difference during the take-up.
//!
//! # Other blocks
//! - A `G92` declares the motor's position: its declared values get the axis's current
//!   offset, so the controller's new frame keeps the work coordinates true and the
//!   direction state carries on (a G92 does not move the machine). `G92.1`..`G92.3` pass
//!   on unchanged.
//! - Homing, probing, lines passed through as text and G53 moves make axes unknown: for
//!   those axes the offset goes back to `0` and the direction is unknown again (`start`
//!   decides at their next move from a known position). A G53 move passes on unchanged.
//! - A move from an unknown position (the first positioning move) cannot tell its
//!   direction: it is sent to `p + o` and establishes nothing.
//! - Arcs: an arc can reverse an axis in mid-arc (at a quadrant point), which a take-up
//!   before the block cannot compensate. An arc in a plane with a compensated axis (or
//!   helical along one) is the error `backlash::arc`: put `linearize-arcs` before
//!   `backlash`. Arcs that touch no compensated axis pass on.
//! - Tool poses (CL input before `ik`) are the error `backlash::pose`.
//!
//! # Order of passes
//! `backlash` compensates the path the machine is finally sent, so it runs after every
//! pass that moves points: `linearize-arcs`, `heightmap` (whose Z corrections reverse Z
//! often: give `z` only if Z has measurable slack), `mirror`, `transform`, `normalize`.
//!
//! # Report
//! The note `backlash::take-ups` gives the number of take-up moves per compensated axis
//! (a take-up that moves two axes counts for both).
//!
//! # Memory
//! None beyond the block at hand.

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind, OffsetCode, Target,
};

/// Axis components of a move at most this long (mm) neither reverse nor set a direction.
pub const EPS: f64 = 1e-6;

/// The axes the pass compensates, in option order.
const AXES: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

/// What the pass assumes about the slack where the direction is not known.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Start {
    /// The first move from a known position finds the slack taken up in its direction.
    #[default]
    FirstMove,
    /// The slack is taken up in the positive direction.
    Positive,
    /// The slack is taken up in the negative direction.
    Negative,
}

/// Options of `backlash`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Slack of X, mm.
    pub x: f64,
    /// Slack of Y, mm.
    pub y: f64,
    /// Slack of Z, mm.
    pub z: f64,
    /// Feed of take-up moves before feed moves, mm/min (default: the move's own).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub feed: Option<f64>,
    /// The assumption where the direction is not known.
    pub start: Start,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            feed: None,
            start: Start::FirstMove,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "backlash",
    summary: "per-axis backlash compensation: a take-up move on each direction reversal, later coordinates shifted by the slack (for controllers without M425)",
    build: |t, _ctx| Ok(Box::new(Backlash::new(super::options(t)?)?)),
    defaults: || super::to_toml(&Options::default()),
};

/// Direction state of one compensated axis.
#[derive(Debug, Clone, Copy, Default)]
struct AxisState {
    /// The slack, mm.
    amount: f64,
    /// Last direction moved: +1, -1, or 0 for not known.
    dir: i8,
    /// Machine minus programmed position, mm.
    offset: f64,
    /// Take-up moves inserted.
    take_ups: u64,
}

/// The `backlash` pass.
pub struct Backlash {
    axes: [AxisState; 3],
    feed: Option<f64>,
    start: Start,
    /// Programmed (IR) position after the last block.
    track: crate::ir::Tracker,
}

impl Backlash {
    /// The pass with `options`: amounts finite and `>= 0`, at least one `> 0`; a `feed`
    /// finite and `> 0`.
    pub fn new(options: Options) -> Result<Backlash, Diagnostic> {
        let amounts = [options.x, options.y, options.z];
        for (a, v) in AXES.iter().zip(amounts) {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Diagnostic::settings(format!(
                    "{} = {v}: the backlash must be a number of mm >= 0",
                    a.letter().to_ascii_lowercase()
                )));
            }
        }
        if amounts.iter().all(|&v| v == 0.0) {
            return Err(Diagnostic::settings(
                "every backlash amount is 0: give the slack per axis in mm, for example --pass backlash:x=0.02,y=0.02",
            ));
        }
        if let Some(f) = options.feed
            && !(f.is_finite() && f > 0.0)
        {
            return Err(Diagnostic::settings(format!(
                "feed = {f}: the take-up feed must be a number of mm/min > 0"
            )));
        }
        let mut axes = [AxisState::default(); 3];
        for (s, v) in axes.iter_mut().zip(amounts) {
            s.amount = v;
        }
        Ok(Backlash {
            axes,
            feed: options.feed,
            start: options.start,
            track: crate::ir::Tracker::default(),
        })
    }

    /// Take-up moves inserted so far, per axis (X, Y, Z).
    pub fn take_ups(&self) -> [u64; 3] {
        [
            self.axes[0].take_ups,
            self.axes[1].take_ups,
            self.axes[2].take_ups,
        ]
    }

    /// Forgets direction and offset of the compensated axes in `axes`.
    fn reset(&mut self, axes: AxisSet) {
        for (s, a) in self.axes.iter_mut().zip(AXES) {
            if axes.contains(a) {
                s.dir = 0;
                s.offset = 0.0;
            }
        }
    }

    /// Adds the offsets to the compensated axes of `j` that are known.
    fn shift(&self, j: &mut Joints) {
        for (s, a) in self.axes.iter().zip(AXES) {
            if j.known.contains(a) {
                j.values[a.index()] += s.offset;
            }
        }
    }

    fn error(&mut self, out: &mut Output<'_>, make: impl FnOnce() -> Diagnostic) {
        // The pipeline caps repeated diagnostics and counts every one.
        out.diag(make());
    }

    /// Whether the arc moves a compensated axis (in its plane or along its normal).
    fn arc_compensated(&self, arc: &crate::ir::Arc, to: &Joints) -> bool {
        let (u, v, n) = arc.plane.axes();
        self.axes.iter().zip(AXES).any(|(s, a)| {
            s.amount > 0.0
                && (a == u
                    || a == v
                    || (a == n
                        && match (self.track.pos().get(n), to.get(n)) {
                            (Some(p), Some(q)) => (q - p).abs() > EPS,
                            _ => true,
                        }))
        })
    }

    /// A straight move (or rapid) to `to`: the take-up, if any, then the shifted move.
    fn straight(&mut self, block: Block, mut m: Motion, to: Joints, out: &mut Output<'_>) {
        let from = *self.track.pos();
        let mut reversing = AxisSet::EMPTY;
        for (i, a) in AXES.into_iter().enumerate() {
            let s = &mut self.axes[i];
            if s.amount == 0.0 {
                continue;
            }
            let (Some(p), Some(q)) = (from.get(a), to.get(a)) else {
                continue;
            };
            let d = q - p;
            if d.abs() <= EPS {
                continue;
            }
            let sign: i8 = if d > 0.0 { 1 } else { -1 };
            if s.dir == 0 {
                s.dir = match self.start {
                    Start::FirstMove => sign,
                    Start::Positive => 1,
                    Start::Negative => -1,
                };
            }
            if s.dir != sign {
                reversing.insert(a);
            }
        }
        if !reversing.is_empty() {
            // The take-up starts where the machine is: the start with the old offsets.
            let mut take_up = from;
            self.shift(&mut take_up);
            for (i, a) in AXES.into_iter().enumerate() {
                if reversing.contains(a) {
                    let s = &mut self.axes[i];
                    s.dir = -s.dir;
                    s.offset += f64::from(s.dir) * s.amount;
                    s.take_ups += 1;
                    take_up.values[a.index()] += f64::from(s.dir) * s.amount;
                }
            }
            let feed = match (m.kind, self.feed) {
                (MotionKind::Rapid, _) => m.feed,
                (_, Some(rate)) => Feed {
                    mode: FeedMode::PerMinute,
                    rate: Some(rate),
                },
                (_, None) if m.feed.mode == FeedMode::InverseTime => {
                    // Same speed as the move: the time scales with the length.
                    let len = linear_length(&from, &to);
                    let tl = reversing
                        .iter()
                        .map(|a| self.axes[a.index()].amount.powi(2))
                        .sum::<f64>()
                        .sqrt();
                    Feed {
                        mode: FeedMode::InverseTime,
                        rate: m.feed.rate.map(|f| f * len / tl),
                    }
                }
                (_, None) => m.feed,
            };
            out.push(Block::new(
                block.span,
                BlockKind::Motion(Motion {
                    kind: match m.kind {
                        MotionKind::Rapid => MotionKind::Rapid,
                        _ => MotionKind::Linear,
                    },
                    target: Target::Joints(take_up),
                    feed,
                    written: reversing,
                    machine_frame: false,
                    extra: String::new(),
                }),
            ));
            m.written = m.written.union(reversing);
        }
        self.track.set_pos(to);
        let mut sent = to;
        self.shift(&mut sent);
        m.target = Target::Joints(sent);
        out.push(Block {
            span: block.span,
            kind: BlockKind::Motion(m),
            comments: block.comments,
        });
    }
}

/// Length of the move over the linear axes (X, Y, Z, U, V, W) known at both ends, mm.
fn linear_length(from: &Joints, to: &Joints) -> f64 {
    [Axis::X, Axis::Y, Axis::Z, Axis::U, Axis::V, Axis::W]
        .iter()
        .filter_map(|&a| Some((to.get(a)? - from.get(a)?).powi(2)))
        .sum::<f64>()
        .sqrt()
}

impl Backlash {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, mut block: Block, out: &mut Output<'_>) {
        match &mut block.kind {
            BlockKind::Motion(m) if m.machine_frame => self.reset(m.written),
            BlockKind::Motion(m) => {
                let Target::Joints(to) = m.target else {
                    self.error(out, || {
                        Diagnostic::error(
                            "backlash::pose",
                            "backlash compensates machine axes; this move is a tool pose",
                        )
                        .at_span(block.span)
                        .with_help("put backlash after ik")
                    });
                    out.push(block);
                    return;
                };
                // Axes that became unknown lose their state.
                self.reset(self.track.pos().known.difference(to.known));
                if let MotionKind::Arc(arc) = &mut m.kind {
                    if self.arc_compensated(arc, &to) {
                        self.error(out, || {
                            Diagnostic::error(
                                "backlash::arc",
                                "an arc can reverse an axis in mid-arc, which a take-up before it cannot compensate",
                            )
                            .at_span(block.span)
                            .with_help("put linearize-arcs before backlash: --pass linearize-arcs --pass backlash:x=..,y=..")
                        });
                    }
                    // The arc keeps the offsets (exact when none of its axes is compensated).
                    let (u, v, n) = arc.plane.axes();
                    for a in [u, v, n] {
                        if let Some(s) = AXES.iter().position(|&c| c == a) {
                            arc.center[a.index()] += self.axes[s].offset;
                        }
                    }
                    let mut sent = to;
                    self.shift(&mut sent);
                    m.target = Target::Joints(sent);
                    self.track.set_pos(to);
                    out.push(block);
                    return;
                }
                let m = m.clone();
                self.straight(block, m, to, out);
                return;
            }
            BlockKind::Offset(o) if o.code == OffsetCode::Set => {
                for (s, a) in self.axes.iter().zip(AXES) {
                    if o.declared.known.contains(a) && self.track.pos().get(a).is_some() {
                        // The controller is told where the motor is.
                        o.declared.values[a.index()] += s.offset;
                    }
                }
            }
            BlockKind::Command(c) => self.reset(c.clobbers),
            BlockKind::Verbatim(v) => self.reset(v.clobbers),
            _ => {}
        }
        // The programmed position, as every pass keeps it (the adjusted G92 values only
        // change axes whose position was known, which it leaves alone).
        self.track.update(&block);
        out.push(block);
    }
}

impl Pass for Backlash {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        let parts: Vec<String> = self
            .axes
            .iter()
            .zip(AXES)
            .filter(|(s, _)| s.amount > 0.0)
            .map(|(s, a)| format!("{} {} ({} mm)", a.letter(), s.take_ups, s.amount))
            .collect();
        out.diag(Diagnostic::note(
            "backlash::take-ups",
            format!("backlash: take-up moves inserted: {}", parts.join(", ")),
        ));
    }
}
