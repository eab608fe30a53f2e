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

mod e_axis;
mod screw;

use serde::{Deserialize, Serialize};

use super::{Context, Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{AXIS_COUNT, Axis, Block, Joints, Span};
use crate::motion::{self, Model, Planner, Timing};
use crate::num::print::Decimals;

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

/// A block queued in the controller's planner, with what it means for the screw.
struct Item {
    block: Block,
    role: Role,
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
    /// The controller's planner, timing the queued blocks.
    queue: Planner<Item>,
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
        let (polar_axes, cap_rate) = polar_frame(&options, ctx)?;
        let model = ctx.model(options.timing, options.rapid_feed)?;
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
            pos: Joints::default(),
            offsets: [0.0; AXIS_COUNT],
            p_cache: None,
            pending: 0.0,
            carry: 0.0,
            held: None,
            queue: Planner::new(model),
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
}

/// The `[polar]` axes the tool point is read from under `frame` (`None`: X, Y), and the
/// near-centre cap rate (1/s) of the polar table, 0 without one.
fn polar_frame(
    options: &Options,
    ctx: &Context<'_>,
) -> Result<(Option<(Axis, Axis)>, f64), Diagnostic> {
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
    Ok((polar_axes, cap_rate))
}

/// The material (E units) a move with E change `de` extrudes, with `pending` the
/// retraction the screw still owes: a retraction (negative `de`) is owed, the E that
/// follows restores it first, and only the E beyond it is material. Sums of printed E
/// steps leave float dust: below [`E_EPS`] is nothing. `valve-lookahead` keeps the same
/// book.
pub(crate) fn material(pending: &mut f64, de: f64) -> f64 {
    if de < 0.0 {
        *pending -= de;
        return 0.0;
    }
    let restored = de.min(*pending);
    *pending -= restored;
    if *pending < E_EPS {
        *pending = 0.0;
    }
    if de - restored < E_EPS {
        0.0
    } else {
        de - restored
    }
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
