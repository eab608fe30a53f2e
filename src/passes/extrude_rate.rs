//! `extrude-rate`: screw speed (or E) per block from the tool speed the controller really produces, so material per mm of path stays the slicer's.
//!
//! # Why
//! A slicer writes E for a Cartesian printer: `ΔE` per move, at the speed F it asks for.
//! On the polar printer of seed 002 the extruder is a screw turned by a speed command,
//! and after `polar-ik` the controller moves r and θ, so the only thing that counts for
//! the material is how long the controller takes for each block. This pass computes that
//! time with the shared motion-time model ([`crate::motion`]: the controller's feed rule,
//! `min_speed`, `max_feed`, and constant-velocity or trapezoid timing, the run-wide
//! `--timing` first, then the option `timing`, then the controller's), on the numbers the
//! controller will read (positions and F rounded to the backend's decimals), and turns the
//! slicer's `ΔE` of the block into a screw speed:
//!
//! `rpm = ΔE / e_per_rev / (t / 60)` (`t` = the block's motion time, seconds).
//!
//! A command is issued per block and takes effect at the block boundary, so the block's
//! whole motion time is what counts. Under trapezoid timing the speed varies within a
//! block while the screw speed cannot: the rate is the block's average (the material of
//! the block is right; within the block it runs a little thin while accelerating and
//! thick while decelerating).
//!
//! # Modes
//! - `mode = "screw-rpm"` (default; the `polar-printer` preset uses it): E words are
//!   dropped from every move (and from `G92`; a bare `G92 E0` line disappears) and
//!   `command` (default: the `[polar.screw]` `rpm_command`, else `M3 S{rpm}`; `{rpm}` is
//!   replaced by the speed at `rpm_decimals` places) is inserted before a block whose
//!   rate differs from the rate in force by more than `threshold` (relative, default
//!   0.005 = 0.5 %). The rate in force is always the printed number, so the material the
//!   controller produces is `rpm × t × e_per_rev` within the threshold.
//! - `mode = "e-axis"`: for extruders that are firmware axes. E stays, but the E of each
//!   source move is shared out over the blocks it was split into (by `polar-ik`,
//!   `valve-lookahead`, arcs to chords) in proportion to each block's Cartesian length, so
//!   material per mm is the slicer's on every piece; blocks that do not move the tool in
//!   Cartesian space (a rotation on the spot at the centre) get none. `polar-ik` already
//!   interpolates the E of a line by its XY parameter, which is the same distribution, so
//!   after it this mode leaves lines as they are (it is not applied twice: the sharing is
//!   idempotent); an arc's chords get E by the arc's parameter there, which this mode
//!   evens out to per chord millimetre (a change below 1 % on tiny arcs). Within one
//!   joint-linear piece the firmware moves E in step with r and θ, while the tool's speed
//!   along the piece varies a little: densification keeps that variation small. Pieces are
//!   grouped by their source line (at most 65536 per group; a longer run is shared out in
//!   parts, each keeping its own total). Travel, retraction and G92 are left alone.
//! - `mode = "constant-flow"` (seed problem 4.1): the screw runs at one speed (`rpm`,
//!   default the screw's `max_rpm`) and the feed of each extruding block is set so the
//!   controller takes `t = ΔE / e_per_rev / rpm × 60` for it (F = rule distance / t, or
//!   `60 / t` under G93). The speed is limited to what the controller and table allow:
//!   the axes' `max_feed` (the controller would clamp it anyway) and, on a polar frame, the
//!   near-centre cap of `polar-ik` (`v ≤ d · min(ω_max, 1.24 √α_max)`, `d` the distance
//!   of the block from the centre). Where a limit (or `min_speed`) changes the time, the
//!   printed F is the one the controller really runs at, the block's screw speed follows
//!   the exact rule for that block instead (so material per mm stays right; the screw
//!   only ever slows for the cap and `max_feed`) and a warning says how often that
//!   happened. Travel keeps its feed. Choose `rpm` so the stage can follow it: on a part
//!   around the table centre many blocks meet the near-centre cap.
//!   Exact under constant-velocity timing; under trapezoid timing the acceleration
//!   phases make blocks longer than `t`, and the rate is again the block average.
//!
//! # Rules
//! `rule = "exact"` (default) is the formula above. `rule = "seed"` is the seed's ad-hoc
//! rule for comparison, `SNW = γ · F · r · ΔE / √(Δx² + Δy²)`, with F the block's printed
//! feed, r the mean radius of its two ends and Δx, Δy its Cartesian chord; `gamma`
//! defaults to `π / (180 · e_per_rev)`, the value that makes it exact for a turn about
//! the centre on this controller (F = Euclidean joint speed with θ in degrees, where
//! `F ≈ (180/π) · 60 v / r`). It is then right for tangential motion only: a radial move
//! gets `r · π / 180` times the material it needs (a fraction near the centre, too much
//! beyond 57.3 mm), and mixed moves near the centre are off by tens of per cent
//! (`tests/extrude_rate.rs` measures it). Blocks with no XY chord use the exact rule.
//! The seed rule goes with `mode = "screw-rpm"` only, and `limit = "slow-feed"` does not
//! apply to it (its rate does not depend on the block's time).
//!
//! # Retraction, travel and priming (screw modes)
//! A screw cannot run backwards. A move that does not extrude (travel, Z moves, moves
//! with negative ΔE such as a slicer's wipe) runs with the screw stopped (`stop_command`,
//! default `command` at 0 rpm). An E-only retraction is left out (a comment saying so
//! takes its place) and its amount is remembered; the E the slicer then pushes back
//! (E-only "unretract" or the start of the next extruding move) restores that amount
//! first and only the rest is extruded (the material never left the screw). An E-only
//! move that extrudes more than the pending retraction (a prime) becomes a dwell (`G4`,
//! whole milliseconds) at the screw speed that gives the rest in the E-only move's own
//! time (longer at `max_rpm`), with a comment. So the screw delivers
//! exactly the slicer's extruded E minus the retraction still pending at the end.
//! A block that moves but takes no time (rounded to nothing) carries its material to the
//! next extruding block. The screw is stopped at the end of the program if it runs.
//!
//! # Limits
//! `max_rpm` (default the screw's): with `limit = "warn"` (default) a faster rate is
//! printed as computed and warned about (the first block, then a count at the end); with
//! `limit = "slow-feed"` such a block's feed is lowered (before the look-ahead plans it)
//! until the rate is `max_rpm` (F rounded down to the printed precision, so the rate never
//! comes out above it), so material per mm stays right at a lower speed (exact under
//! constant velocity; under trapezoid timing the block gets longer still, so the rate is
//! below `max_rpm`). A non-zero rate below `min_rpm` (the screw's) is warned about too.
//!
//! # Accuracy
//! Per block, the material the controller makes is `rpm × t × e_per_rev` with the rate in
//! force: within `threshold` of the slicer's ΔE plus the rounding of the printed rate
//! (`rpm_decimals`, default 3). On the PrusaSlicer MINI cube centred on the table
//! (`tests/extrude_rate.rs`, re-parsing the printed program and timing it with the same
//! model) the total is within 0.02 % and the worst block longer than 1 mm within 0.5 %,
//! under both timings; the seed rule on the same file extrudes 22 % too little overall and
//! about half the material within 3 mm of the centre.
//!
//! # Where it goes, memory
//! After `polar-ik` (and `valve-lookahead`, which needs E), before `verify`: the
//! `polar-printer` preset runs `polar-ik, valve-lookahead, extrude-rate, verify`. Under
//! trapezoid timing the screw modes hold the controller's look-ahead window
//! (`lookahead` moves) to know each block's time; under constant velocity nothing is
//! held. `e-axis` holds the pieces of one source move.
//!
//! # Frame
//! Cartesian lengths (seed rule, e-axis sharing, constant-flow near-centre cap) use the
//! tool point of the joints: `frame = "auto"` (default) reads r, θ from the `[polar]`
//! axes when the preset has a polar machine, else X, Y; set `frame = "cartesian"` after
//! `polar-ik` with `kinematics = "controller"` (XY kept).

use std::collections::VecDeque;
use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use super::{Context, Output, Pass, PassInfo};
use crate::back::Decimals;
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, Block, BlockKind, Command, Comment, CommentStyle, FeedMode, Joints,
    MotionKind, Span, Target, Text,
};
use crate::machine::FeedRule;
use crate::motion::{self, Model, Planner, Segment, Timed, Timing};
use crate::num::print::{printed, write_fixed};

/// What the pass produces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// A screw speed command per rate change; E dropped.
    #[default]
    ScrewRpm,
    /// E kept, shared out over split moves by Cartesian length.
    EAxis,
    /// The screw at one speed, the feed steered to match.
    ConstantFlow,
}

/// How the screw speed follows the motion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Rule {
    /// `ΔE / e_per_rev / minutes` of the block's motion time.
    #[default]
    Exact,
    /// The seed's `γ F r ΔE / √(Δx² + Δy²)`.
    Seed,
}

/// What happens above `max_rpm`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Limit {
    /// Print the rate and warn.
    #[default]
    Warn,
    /// Lower the block's feed until the rate is `max_rpm`.
    SlowFeed,
}

/// Which joints hold the tool point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Frame {
    /// Polar when the preset has a `[polar]` machine, else Cartesian.
    #[default]
    Auto,
    /// r and θ on the `[polar]` axes.
    Polar,
    /// X and Y.
    Cartesian,
}

/// Options of `extrude-rate`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// `screw-rpm`, `e-axis` or `constant-flow`.
    pub mode: Mode,
    /// `exact` or `seed` (screw modes).
    pub rule: Rule,
    /// γ of the seed rule; default `π / (180 · e_per_rev)`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gamma: Option<f64>,
    /// The screw speed command, with `{rpm}`; default the screw's `rpm_command`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub command: Option<String>,
    /// The command that stops the screw; default `command` at 0.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stop_command: Option<String>,
    /// Relative change of the rate below which no new command is issued.
    pub threshold: f64,
    /// Digits after the decimal point of the printed rate.
    pub rpm_decimals: u8,
    /// The slicer's E per screw revolution; default the screw's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub e_per_rev: Option<f64>,
    /// Highest screw speed, rev/min; default the screw's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_rpm: Option<f64>,
    /// `warn` or `slow-feed` above `max_rpm`.
    pub limit: Limit,
    /// The constant screw speed of `constant-flow`, rev/min; default `max_rpm`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rpm: Option<f64>,
    /// Timing model; default the controller's (the run's `--timing` wins).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timing: Option<Timing>,
    /// Speed of rapids, mm/min.
    pub rapid_feed: f64,
    /// Where the tool point is read from.
    pub frame: Frame,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            mode: Mode::ScrewRpm,
            rule: Rule::Exact,
            gamma: None,
            command: None,
            stop_command: None,
            threshold: 0.005,
            rpm_decimals: 3,
            e_per_rev: None,
            max_rpm: None,
            limit: Limit::Warn,
            rpm: None,
            timing: None,
            rapid_feed: motion::DEFAULT_RAPID_FEED,
            frame: Frame::Auto,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "extrude-rate",
    summary: "screw speed (M3 S) or E per block from the controller's real motion time, so material per mm is the slicer's; seed rule, constant-flow feed steering",
    build: |t, ctx| Ok(Box::new(ExtrudeRate::new(super::options(t)?, ctx)?)),
    defaults: || super::to_toml(&Options::default()),
};

/// E amounts below this (E units) are float dust from summing printed steps, not
/// material.
const E_EPS: f64 = 1e-9;

/// Largest group of pieces of one source move shared out at once in `e-axis` mode.
const MAX_GROUP: usize = 65536;

/// What a queued item is, for the screw.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    /// Passed on, no change of the screw.
    Pass,
    /// A move that does not extrude: the screw stops.
    Travel,
    /// A move that extrudes `material` (E units); `seed` is the seed rule's rate.
    Extrude { material: f64, seed: Option<f64> },
    /// A dwell that extrudes `material`.
    Prime { material: f64 },
}

struct Item {
    block: Block,
    role: Role,
}

/// The motion planner with the blocks beside it: the planner keeps only the roles, the
/// blocks wait here in the same order (it hands items back in the order they came), so
/// each block is moved in and out once.
struct Queue {
    planner: Planner<Role>,
    blocks: VecDeque<Block>,
}

// Inlined so a block is written straight into the queue, not copied through the call
// (a block is over 200 bytes; callgrind: 0.9 % of the polar pipeline).
impl Queue {
    #[inline(always)]
    fn push_move(&mut self, seg: Segment, item: Item) {
        self.blocks.push_back(item.block);
        self.planner.push_move(seg, item.role);
    }

    #[inline(always)]
    fn push_other(&mut self, item: Item) {
        self.blocks.push_back(item.block);
        self.planner.push_other(item.role);
    }

    #[inline(always)]
    fn push_stop(&mut self, dwell: f64, item: Item) {
        self.blocks.push_back(item.block);
        self.planner.push_stop(dwell, item.role);
    }

    fn finish(&mut self) {
        self.planner.finish();
    }

    /// The next item whose timing is final, and its block.
    #[inline(always)]
    fn pop(&mut self) -> Option<(Timed<Role>, Block)> {
        let timed = self.planner.pop()?;
        let block = self.blocks.pop_front()?;
        Some((timed, block))
    }
}

/// A warning counted over the run: the first place and how often.
#[derive(Default)]
struct Tally {
    count: u64,
}

impl Tally {
    fn hit(&mut self, out: &mut Output<'_>, diag: impl FnOnce() -> Diagnostic) {
        if self.count == 0 {
            out.diag(diag());
        }
        self.count += 1;
    }
}

/// The `extrude-rate` pass.
pub struct ExtrudeRate {
    options: Options,
    model: Model,
    decimals: Option<Decimals>,
    polar_axes: Option<(Axis, Axis)>,
    e_per_rev: f64,
    max_rpm: f64,
    min_rpm: f64,
    gamma: f64,
    flow_rpm: f64,
    /// Near-centre cap rate (1/s) of the polar table, 0 without one.
    cap_rate: f64,
    /// The rpm command template split at its `{rpm}` placeholders (at least two parts).
    command: Vec<String>,
    stop_command: Option<String>,
    /// Where [`ExtrudeRate::command_text`] writes (kept for its allocation).
    text_buffer: String,
    /// Position as the input has it (E included).
    pos: Joints,
    /// G92 offsets in force (program = IR + offset).
    offsets: [f64; AXIS_COUNT],
    /// The last move's end as the input has it and as the controller reads it.
    p_cache: Option<(Joints, Joints)>,
    /// Retracted E the screw never pulled back.
    pending: f64,
    /// Material of blocks that took no time, for the next extruding block.
    carry: f64,
    /// The printed rate in force (`None`: not known yet).
    held: Option<f64>,
    queue: Queue,
    last_span: Span,
    over_max: Tally,
    under_min: Tally,
    slowed: Tally,
    limited: Tally,
    /// `e-axis`: the pieces of the current source move and the position before them.
    group: Vec<Block>,
    group_start: Joints,
}

impl ExtrudeRate {
    /// The pass with `options` in `ctx` (screw settings from `[polar.screw]`, timing from
    /// the controller).
    pub fn new(options: Options, ctx: &Context<'_>) -> Result<ExtrudeRate, Diagnostic> {
        let screw = ctx.polar.map(|p| p.screw.clone()).unwrap_or_default();
        let e_per_rev = options.e_per_rev.unwrap_or(screw.e_per_rev);
        let max_rpm = options.max_rpm.unwrap_or(screw.max_rpm);
        let positive = |v: f64, what: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(Diagnostic::settings(format!(
                    "{what} must be a positive number (got {v})"
                )))
            }
        };
        positive(e_per_rev, "e_per_rev")?;
        positive(max_rpm, "max_rpm")?;
        if !(options.threshold.is_finite() && (0.0..1.0).contains(&options.threshold)) {
            return Err(Diagnostic::settings(
                "threshold must be a number from 0 to below 1",
            ));
        }
        if options.rule == Rule::Seed && options.mode != Mode::ScrewRpm {
            return Err(Diagnostic::settings(
                "rule = \"seed\" sets screw speeds: it needs mode = \"screw-rpm\"",
            ));
        }
        if options.rpm_decimals > 6 {
            return Err(Diagnostic::settings("rpm_decimals must be at most 6"));
        }
        let gamma = options
            .gamma
            .unwrap_or(std::f64::consts::PI / (180.0 * e_per_rev));
        positive(gamma, "gamma")?;
        let flow_rpm = options.rpm.unwrap_or(max_rpm);
        positive(flow_rpm, "rpm")?;
        let command = options
            .command
            .clone()
            .unwrap_or_else(|| screw.rpm_command.clone());
        if !command.contains("{rpm}") {
            return Err(Diagnostic::settings(format!(
                "command `{command}` must contain {{rpm}}"
            )));
        }
        for c in [Some(&command), options.stop_command.as_ref()]
            .into_iter()
            .flatten()
        {
            if c.trim().is_empty() || c.contains('\n') {
                return Err(Diagnostic::settings("commands must be one non-empty line"));
            }
        }
        let polar_axes = match (options.frame, ctx.polar) {
            (Frame::Cartesian, _) | (Frame::Auto, None) => None,
            (Frame::Auto | Frame::Polar, Some(p)) => Some((p.r_axis, p.theta_axis)),
            (Frame::Polar, None) => {
                return Err(Diagnostic::settings(
                    "frame = \"polar\" needs a preset with a [polar] machine",
                ));
            }
        };
        let cap_rate = match (polar_axes, ctx.polar) {
            (Some(_), Some(p)) => p
                .omega_max
                .to_radians()
                .min(1.2408 * p.alpha_max.to_radians().sqrt()),
            _ => 0.0,
        };
        let model = Model::for_machines(ctx.polar, ctx.machine, ctx.timing, options.timing)
            .with_rapid_feed(options.rapid_feed);
        Ok(ExtrudeRate {
            model: model.clone(),
            decimals: ctx.decimals,
            polar_axes,
            e_per_rev,
            max_rpm,
            min_rpm: screw.min_rpm,
            gamma,
            flow_rpm,
            cap_rate,
            command: command.split("{rpm}").map(str::to_owned).collect(),
            stop_command: options.stop_command.clone(),
            text_buffer: String::new(),
            pos: Joints::default(),
            offsets: [0.0; AXIS_COUNT],
            p_cache: None,
            pending: 0.0,
            carry: 0.0,
            held: None,
            queue: Queue {
                planner: Planner::new(model),
                blocks: VecDeque::new(),
            },
            last_span: Span::default(),
            over_max: Tally::default(),
            under_min: Tally::default(),
            slowed: Tally::default(),
            limited: Tally::default(),
            group: Vec::new(),
            group_start: Joints::default(),
            options,
        })
    }

    /// The joints as the controller reads them: each known axis but E rounded to the
    /// backend's decimals (offsets included), E forgotten (the screw modes print none).
    fn printed(&self, j: &Joints) -> Joints {
        self.printed_reusing(j, None)
    }

    /// [`Self::printed`], taking unchanged axes' printed values from `seen` (see
    /// [`Decimals::printed_joints`]).
    fn printed_reusing(&self, j: &Joints, seen: Option<&(Joints, Joints)>) -> Joints {
        let mut p = *j;
        p.forget(crate::ir::AxisSet::from_iter([Axis::E]));
        match self.decimals {
            Some(d) => d.printed_joints(&p, &self.offsets, seen),
            None => p,
        }
    }

    fn printed_feed(&self, f: f64) -> f64 {
        self.decimals.and_then(|d| printed(f, d.feed)).unwrap_or(f)
    }

    /// The largest printable feed not above `f` (a slowed block must not come out
    /// faster than `max_rpm` allows by rounding).
    fn printed_feed_down(&self, f: f64) -> f64 {
        match self.decimals {
            Some(d) => {
                let scale = 10f64.powi(d.feed as i32);
                let down = (f * scale).floor() / scale;
                if down > 0.0 { down } else { f }
            }
            None => f,
        }
    }

    fn printed_rpm(&self, rpm: f64) -> f64 {
        let d = self.options.rpm_decimals;
        printed(rpm, d).unwrap_or(rpm)
    }

    /// The Cartesian tool point of a joint vector (`None` if it is not known).
    fn point(&self, j: &Joints) -> Option<nalgebra::Point3<f64>> {
        match self.polar_axes {
            Some((r, th)) => {
                (j.known.contains(r) && j.known.contains(th)).then(|| motion::polar_point(j, r, th))
            }
            None => Some(nalgebra::Point3::new(
                j.get(Axis::X)?,
                j.get(Axis::Y)?,
                j.get(Axis::Z).unwrap_or(0.0),
            )),
        }
    }

    fn radius(&self, j: &Joints) -> Option<f64> {
        match self.polar_axes {
            Some((r, _)) => j.get(r).map(f64::abs),
            None => Some(j.get(Axis::X)?.hypot(j.get(Axis::Y)?)),
        }
    }

    fn command_text(&mut self, rpm: f64) -> Text {
        if rpm == 0.0
            && let Some(stop) = &self.stop_command
        {
            return Text::from(stop);
        }
        // The template's parts with the number between them, written in a buffer kept
        // from call to call: this runs for every rate change, and the usual command
        // (`M3 S19.053`) then needs no allocation at all (see `Text`).
        let text = &mut self.text_buffer;
        text.clear();
        let mut number: Option<std::ops::Range<usize>> = None;
        for (i, part) in self.command.iter().enumerate() {
            if i > 0 {
                match &number {
                    Some(r) => text.extend_from_within(r.clone()),
                    None => {
                        let start = text.len();
                        if !write_fixed(text, rpm, self.options.rpm_decimals, true) {
                            let _ = write!(text, "{rpm}");
                        }
                        number = Some(start..text.len());
                    }
                }
            }
            text.push_str(part);
        }
        Text::from(text.as_str())
    }

    /// Sets the screw to `rpm` (printed), issuing a command when it changes by more than
    /// the threshold.
    fn set_rate(&mut self, rpm: f64, span: Span, out: &mut Output<'_>) {
        let rpm = self.printed_rpm(rpm.max(0.0));
        let keep = match self.held {
            Some(0.0) => rpm == 0.0,
            Some(h) => rpm > 0.0 && (rpm - h).abs() <= self.options.threshold * h,
            None => false,
        };
        if keep {
            return;
        }
        self.held = Some(rpm);
        out.push(Block::new(
            span,
            BlockKind::Command(Command {
                text: self.command_text(rpm),
                modes: None,
                clobbers: crate::ir::AxisSet::EMPTY,
            }),
        ));
    }

    fn check_rpm(&mut self, rpm: f64, span: Span, out: &mut Output<'_>) {
        let max = self.max_rpm;
        if rpm > max * (1.0 + 1e-6) {
            self.over_max.hit(out, || {
                Diagnostic::warning(
                    "extrude-rate::max-rpm",
                    format!("the screw would need {rpm:.3} rpm here, above max_rpm {max}"),
                )
                .at_span(span)
                .with_help("set limit = \"slow-feed\" to lower the feed where the screw is too slow, or slow the print in the slicer")
            });
        } else if rpm > 0.0 && rpm < self.min_rpm {
            let min = self.min_rpm;
            self.under_min.hit(out, || {
                Diagnostic::warning(
                    "extrude-rate::min-rpm",
                    format!("the screw would turn at {rpm:.3} rpm here, below min_rpm {min}"),
                )
                .at_span(span)
                .with_help("raise the feed of slow extrusions, or lower min_rpm if the screw extrudes steadily there")
            });
        }
    }

    /// Sets the feed of `block` (a move from `from` to `to`, printed joints) so the
    /// controller takes `seconds` for it under constant velocity, capped by the axes'
    /// `max_feed` and the polar near-centre cap; returns the new segment and whether a
    /// limit cut it.
    fn steer(
        &self,
        block: &mut Block,
        from: &Joints,
        to: &Joints,
        seconds: f64,
    ) -> Option<(Segment, bool)> {
        let BlockKind::Motion(m) = &mut block.kind else {
            return None;
        };
        let (Some(a), Some(b)) = (self.point(from), self.point(to)) else {
            return None;
        };
        let mut seconds = seconds;
        let mut limited = false;
        // The near-centre cap on the XY speed (only where θ turns).
        if let Some((_, th)) = self.polar_axes
            && self.cap_rate > 0.0
            && from.get(th) != to.get(th)
        {
            let d = segment_distance(a.x, a.y, b.x, b.y);
            let xy = (b.x - a.x).hypot(b.y - a.y);
            if d * self.cap_rate > 0.0 && xy / (d * self.cap_rate) > seconds {
                seconds = xy / (d * self.cap_rate);
                limited = true;
            }
        }
        let seg = self.model.between(from, to, m.kind, &m.feed);
        if seg.length <= 0.0 || seconds <= 0.0 {
            return None;
        }
        let (mode, rate) = match (self.model.rule, m.feed.mode) {
            (FeedRule::InverseTime, _) | (_, FeedMode::InverseTime) => {
                (FeedMode::InverseTime, 60.0 / seconds)
            }
            _ => (FeedMode::PerMinute, seg.length / seconds * 60.0),
        };
        let rate = if self.options.mode == Mode::ConstantFlow {
            self.printed_feed(rate)
        } else {
            self.printed_feed_down(rate)
        };
        if rate <= 0.0 {
            return None;
        }
        m.feed.mode = mode;
        m.feed.rate = Some(rate);
        let seg = self.model.between(from, to, m.kind, &m.feed);
        let wanted = match mode {
            FeedMode::InverseTime => seg.length * rate / 60.0,
            _ => rate / 60.0,
        };
        if (seg.v_max - wanted).abs() > 1e-9 * wanted.max(1.0) {
            // The controller's min_speed or an axis' max_feed wins: print the feed it
            // will really run at.
            limited = true;
            let real = match mode {
                FeedMode::InverseTime => seg.v_max / seg.length * 60.0,
                _ => seg.v_max * 60.0,
            };
            m.feed.rate = Some(self.printed_feed(real));
            return Some((self.model.between(from, to, m.kind, &m.feed), limited));
        }
        Some((seg, limited))
    }

    fn run_screw(&mut self, mut block: Block, out: &mut Output<'_>) {
        self.last_span = block.span;
        match &mut block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(to) = m.target else {
                    self.queue.push_other(Item {
                        block,
                        role: Role::Pass,
                    });
                    return;
                };
                let from = self.pos;
                let de = match (from.get(Axis::E), to.get(Axis::E)) {
                    (Some(a), Some(b)) => b - a,
                    _ => 0.0,
                };
                let mut next = self.pos.updated_by(&to);
                if m.machine_frame {
                    next.forget(m.written);
                }
                // The last block's printed end is this one's start (most of the time).
                let p_from = match self.p_cache {
                    Some((j, p)) if j.same_known(&from) => p,
                    _ => self.printed(&from),
                };
                let p_to = self.printed_reusing(
                    if m.machine_frame { &to } else { &next },
                    self.p_cache.as_ref(),
                );
                crate::back::remember_printed(&mut self.p_cache, next, p_to);
                self.pos = next;
                // Drop E from the move.
                if let Some(j) = m.target.joints_mut() {
                    j.forget(crate::ir::AxisSet::from_iter([Axis::E]));
                }
                m.written.remove(Axis::E);
                if let Some(f) = m.feed.rate {
                    m.feed.rate = Some(self.printed_feed(f));
                }
                let mut seg = self.model.between(&p_from, &p_to, m.kind, &m.feed);
                let moves = seg.length > 0.0 && !m.written.is_empty();
                // Material: what the slicer pushes beyond the retraction still pending.
                let material = if de < 0.0 {
                    self.pending -= de;
                    0.0
                } else {
                    let restored = de.min(self.pending);
                    self.pending -= restored;
                    // Sums of printed E steps leave float dust: below it is nothing.
                    if self.pending < E_EPS {
                        self.pending = 0.0;
                    }
                    if de - restored < E_EPS {
                        0.0
                    } else {
                        de - restored
                    }
                };
                if !moves && de != 0.0 {
                    // An E-only move.
                    let rate = m.feed.rate.unwrap_or(0.0);
                    let rapid = m.kind == MotionKind::Rapid;
                    let comments = std::mem::take(&mut block.comments);
                    if material > 0.0 {
                        // A prime: a dwell with the screw turning, in the move's time.
                        let mut seconds = if rate > 0.0 && !rapid {
                            de / (rate / 60.0).max(self.model.min_speed)
                        } else {
                            de / self.model.rapid_speed
                        };
                        let rpm = material / self.e_per_rev / (seconds / 60.0);
                        if rpm > self.max_rpm {
                            seconds = material / self.e_per_rev / self.max_rpm * 60.0;
                        }
                        // Whole milliseconds (the dwell's printed precision), never shorter.
                        let seconds = ((seconds * 1000.0 - 1e-6).ceil() / 1000.0).max(0.001);
                        let mut b = Block::new(block.span, BlockKind::Dwell { seconds });
                        b.comments = comments;
                        b.comments.push(Comment {
                            text: format!("prime E{material:.5}: the screw runs during this dwell"),
                            style: CommentStyle::Semicolon,
                        });
                        self.queue.push_stop(
                            seconds,
                            Item {
                                block: b,
                                role: Role::Prime { material },
                            },
                        );
                    } else {
                        let text = if de < 0.0 {
                            format!("retraction E{de:.5} left out: the screw cannot turn backwards")
                        } else {
                            format!("E{de:.5} left out: it restores the retraction")
                        };
                        let mut b = Block::new(block.span, BlockKind::Comment);
                        b.comments = comments;
                        b.comments.push(Comment {
                            text,
                            style: CommentStyle::Semicolon,
                        });
                        self.queue.push_other(Item {
                            block: b,
                            role: Role::Pass,
                        });
                    }
                    return;
                }
                if !moves {
                    self.queue.push_move(
                        seg,
                        Item {
                            block,
                            role: Role::Pass,
                        },
                    );
                    return;
                }
                if material <= 0.0 {
                    self.queue.push_move(
                        seg,
                        Item {
                            block,
                            role: Role::Travel,
                        },
                    );
                    return;
                }
                // An extruding move: steer its feed where the mode asks for it.
                let cv_seconds = if seg.moves() {
                    seg.length / seg.v_max
                } else {
                    0.0
                };
                let flow_seconds = material / self.e_per_rev / self.flow_rpm * 60.0;
                let target = match self.options.mode {
                    Mode::ConstantFlow => Some(flow_seconds),
                    _ if self.options.limit == Limit::SlowFeed
                        && self.options.rule == Rule::Exact
                        && cv_seconds > 0.0
                        && material / self.e_per_rev / (cv_seconds / 60.0) > self.max_rpm =>
                    {
                        Some(material / self.e_per_rev / self.max_rpm * 60.0)
                    }
                    _ => None,
                };
                if let Some(t) = target
                    && m.kind != MotionKind::Rapid
                    && let Some((s, limited)) = self.steer(&mut block, &p_from, &p_to, t)
                {
                    seg = s;
                    let span = block.span;
                    if self.options.mode == Mode::ConstantFlow {
                        if limited {
                            self.limited.hit(out, || {
                                Diagnostic::warning(
                                    "extrude-rate::flow-limited",
                                    "the feed for constant flow is above the machine's limits here: the feed is clamped and the screw slows for this block",
                                )
                                .at_span(span)
                                .with_help("lower `rpm` so the stage can follow it")
                            });
                        }
                    } else {
                        self.slowed.hit(out, || {
                            Diagnostic::warning(
                                "extrude-rate::slowed",
                                "the feed is lowered here so the screw stays within max_rpm",
                            )
                            .at_span(span)
                        });
                    }
                }
                let seed = match self.options.rule {
                    Rule::Exact => None,
                    Rule::Seed => {
                        let f = match &block.kind {
                            BlockKind::Motion(m) if m.feed.mode == FeedMode::PerMinute => {
                                m.feed.rate
                            }
                            _ => None,
                        };
                        match (
                            f,
                            self.point(&p_from),
                            self.point(&p_to),
                            self.radius(&p_from),
                            self.radius(&p_to),
                        ) {
                            (Some(f), Some(a), Some(b), Some(ra), Some(rb)) => {
                                let l = (b.x - a.x).hypot(b.y - a.y);
                                (l > 0.0).then(|| self.gamma * f * (ra + rb) / 2.0 * material / l)
                            }
                            _ => None,
                        }
                    }
                };
                self.queue.push_move(
                    seg,
                    Item {
                        block,
                        role: Role::Extrude { material, seed },
                    },
                );
            }
            BlockKind::Dwell { seconds } => {
                let s = *seconds;
                self.queue.push_stop(
                    s,
                    Item {
                        block,
                        role: Role::Pass,
                    },
                );
            }
            BlockKind::Offset(o) => {
                self.offsets = o.offsets;
                self.p_cache = None;
                let named_e = o.declared.known.contains(Axis::E);
                o.declared.forget(crate::ir::AxisSet::from_iter([Axis::E]));
                o.offsets[Axis::E.index()] = 0.0;
                if named_e && o.declared.known.is_empty() && o.code == crate::ir::OffsetCode::Set {
                    // `G92 E0`: nothing left to declare (a bare G92 would zero every axis).
                    if block.comments.is_empty() {
                        return;
                    }
                    block.kind = BlockKind::Comment;
                }
                self.queue.push_other(Item {
                    block,
                    role: Role::Pass,
                });
            }
            BlockKind::Command(c) if !c.clobbers.is_empty() => {
                self.pos.forget(c.clobbers);
                self.queue.push_stop(
                    0.0,
                    Item {
                        block,
                        role: Role::Pass,
                    },
                );
            }
            BlockKind::Verbatim(v) => {
                self.pos.forget(v.clobbers);
                self.queue.push_stop(
                    0.0,
                    Item {
                        block,
                        role: Role::Pass,
                    },
                );
            }
            _ => self.queue.push_other(Item {
                block,
                role: Role::Pass,
            }),
        }
    }

    /// Emits the planned items, with the screw commands before them.
    fn drain(&mut self, out: &mut Output<'_>) {
        while let Some((t, block)) = self.queue.pop() {
            self.emit(t, block, out);
        }
    }

    fn emit(&mut self, t: Timed<Role>, block: Block, out: &mut Output<'_>) {
        let seconds = t.duration();
        let role = t.payload;
        let span = block.span;
        match role {
            Role::Pass => {}
            Role::Travel => self.set_rate(0.0, span, out),
            Role::Extrude { material, seed } => {
                let material = material + self.carry;
                if seconds > 0.0 {
                    self.carry = 0.0;
                    let exact = material / self.e_per_rev / (seconds / 60.0);
                    let rpm = seed.unwrap_or(exact);
                    self.check_rpm(rpm, span, out);
                    self.set_rate(rpm, span, out);
                } else {
                    self.carry = material;
                }
            }
            Role::Prime { material } => {
                if seconds > 0.0 {
                    let rpm = material / self.e_per_rev / (seconds / 60.0);
                    self.check_rpm(rpm, span, out);
                    self.set_rate(rpm, span, out);
                }
            }
        }
        out.push(block);
    }

    fn run_e_axis(&mut self, block: Block, out: &mut Output<'_>) {
        let piece = match &block.kind {
            BlockKind::Motion(m) => !m.machine_frame && m.target.joints().is_some(),
            _ => false,
        };
        if !piece
            || self.group.first().is_some_and(|b| b.span != block.span)
            || self.group.len() >= MAX_GROUP
        {
            self.flush_group(out);
        }
        if !piece {
            if let BlockKind::Motion(m) = &block.kind {
                match m.target.joints() {
                    Some(j) => {
                        for a in j.known.iter() {
                            self.pos.set(a, j.values[a.index()]);
                        }
                        if m.machine_frame {
                            self.pos.forget(m.written);
                        }
                    }
                    None => self.pos.forget(m.written),
                }
            }
            match &block.kind {
                BlockKind::Command(c) => self.pos.forget(c.clobbers),
                BlockKind::Verbatim(v) => self.pos.forget(v.clobbers),
                _ => {}
            }
            out.push(block);
            return;
        }
        if self.group.is_empty() {
            self.group_start = self.pos;
        }
        if let Some(j) = block_joints(&block) {
            for a in j.known.iter() {
                self.pos.set(a, j.values[a.index()]);
            }
        }
        self.group.push(block);
    }

    /// Shares the E of the grouped pieces out by their Cartesian lengths.
    fn flush_group(&mut self, out: &mut Output<'_>) {
        if self.group.is_empty() {
            return;
        }
        let mut group = std::mem::take(&mut self.group);
        let e0 = self.group_start.get(Axis::E);
        let mut prev = self.group_start;
        let mut lengths = Vec::with_capacity(group.len());
        let mut ok = e0.is_some();
        for b in &group {
            let Some(j) = block_joints(b) else {
                ok = false;
                break;
            };
            let mut to = prev;
            for a in j.known.iter() {
                to.set(a, j.values[a.index()]);
            }
            if !j.known.contains(Axis::E) {
                ok = false;
            }
            let len = match (self.point(&prev), self.point(&to)) {
                (Some(a), Some(b)) => (b - a).norm(),
                _ => {
                    ok = false;
                    0.0
                }
            };
            lengths.push(len);
            prev = to;
        }
        let total: f64 = lengths.iter().sum();
        if let (true, Some(e0), Some(e1)) = (ok && total > 0.0, e0, prev.get(Axis::E)) {
            let de = e1 - e0;
            let mut cum = 0.0;
            let n = group.len();
            for (i, (b, len)) in group.iter_mut().zip(&lengths).enumerate() {
                cum += len;
                let e = if i + 1 == n {
                    e1
                } else {
                    e0 + de * cum / total
                };
                if let BlockKind::Motion(m) = &mut b.kind
                    && let Some(j) = m.target.joints_mut()
                {
                    j.set(Axis::E, e);
                }
            }
        }
        for b in group.drain(..) {
            out.push(b);
        }
        self.group = group;
    }
}

/// The joint target of a motion block.
fn block_joints(b: &Block) -> Option<&Joints> {
    match &b.kind {
        BlockKind::Motion(m) => m.target.joints(),
        _ => None,
    }
}

/// Distance from the origin to the segment (ax, ay)–(bx, by).
fn segment_distance(ax: f64, ay: f64, bx: f64, by: f64) -> f64 {
    let (dx, dy) = (bx - ax, by - ay);
    let len2 = dx * dx + dy * dy;
    if len2 == 0.0 {
        return ax.hypot(ay);
    }
    let s = (-(ax * dx + ay * dy) / len2).clamp(0.0, 1.0);
    (ax + dx * s).hypot(ay + dy * s)
}

impl ExtrudeRate {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        match self.options.mode {
            Mode::EAxis => self.run_e_axis(block, out),
            Mode::ScrewRpm | Mode::ConstantFlow => {
                self.run_screw(block, out);
                self.drain(out);
            }
        }
    }
}

impl Pass for ExtrudeRate {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        if self.options.mode == Mode::EAxis {
            self.flush_group(out);
            return;
        }
        self.queue.finish();
        self.drain(out);
        if self.held.is_some_and(|h| h > 0.0) {
            self.set_rate(0.0, self.last_span, out);
        }
        for (tally, what) in [
            (&self.over_max, "blocks needed more than max_rpm"),
            (&self.under_min, "blocks ran the screw below min_rpm"),
            (&self.slowed, "blocks were slowed for max_rpm"),
            (
                &self.limited,
                "blocks could not keep the constant flow (feed limits)",
            ),
        ] {
            if tally.count > 1 {
                out.diag(Diagnostic::warning(
                    "extrude-rate::count",
                    format!("extrude-rate: {} {what}", tally.count),
                ));
            }
        }
    }
}
