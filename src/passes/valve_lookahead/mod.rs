//! `valve-lookahead`: valve open/close commands issued a set motion time ahead of each extrusion start and end, splitting moves at the exact point.
//!
//! # Why
//! The screw extruder of seed 002 is closed by a solenoid valve that reacts late (seed
//! §4.3): material flows `open_delay_s` after the open command and stops `close_delay_s`
//! after the close command. So the open command must be issued `open_delay_s` of *motion
//! time* before the first extruding move of a run, and the close command `close_delay_s`
//! before the run's last extruding move ends. This pass looks ahead in the block stream
//! to do that.
//!
//! # What counts as extrusion
//! A move that moves the machine (any axis but E) with a positive ΔE (positions are
//! absolute after M82/M83/G92 resolution, so ΔE is the IR's E difference) beyond the
//! retraction still pending. Retractions and wipes (ΔE < 0) are not extrusion, and the
//! E that the next moves push back restores the pending retraction first (the same book
//! keeping as `extrude-rate`): only the rest is material. An E-only move that extrudes
//! beyond the pending retraction is a *prime* and counts as extrusion too.
//!
//! A *run* is a sequence of extruding moves with no motion time between them (comments,
//! commands, retract/unretract pairs that take no time do not end it). Two runs
//! separated by less than `keep_open_gap_s` seconds of motion become one run (the valve
//! stays open across the gap; 0 = off, the default). A line whose time the model does not
//! know (homing, probing, lines passed through as text, an untimed prime, below) always
//! ends a run.
//!
//! # Time
//! The motion time is the controller's, from the shared motion-time model
//! ([`crate::motion`]): its feed rule, `min_speed`, `max_feed`, and constant-velocity
//! or trapezoid timing (the run-wide `--timing` wins, then the option `timing`, then the
//! controller's) with the controller's junction rule and bounded look-ahead. Positions
//! and feeds are rounded to the backend's printed precision first, so the times are the
//! ones of the program the controller reads. Dwells (G4) take their time and stop the
//! machine.
//!
//! E-only moves (`e_only`): a screw printer's `extrude-rate` pass turns them into
//! comments (retractions and the E that restores them) or a dwell (a prime), so they
//! take no motion time there: `e_only = "untimed"`. With an extruder that is a firmware
//! axis (`extrude-rate` with `mode = "e-axis"`, or none) they are ordinary moves:
//! `e_only = "timed"`. The default `auto` is `untimed` when the preset has a `[polar]`
//! machine (the screw printer) and `timed` otherwise. An untimed prime's duration is
//! chosen later (by `extrude-rate`), so it is a line of unknown time: the run starts at
//! it and no command is moved across it.
//!
//! # Placement
//! For each run, the open command's time is `start − open_delay_s` and the close
//! command's `end − close_delay_s`. The move running at that time is split there: the
//! fraction of the move done at that time (from its speed profile, so the split holds
//! under trapezoid timing too) gives the split point, the E and every other axis
//! interpolated linearly (arcs are split on the arc; an arc with extra full turns is not
//! split and the command goes to its nearer end). A dwell running at that time is split
//! into two dwells. Splitting a move into two collinear parts keeps its time under
//! constant velocity; under trapezoid timing the extra block can change the timing of
//! its neighbours through the controller's look-ahead window, and an inserted dwell stops
//! the machine, so every placement is checked on the emitted blocks (re-timed with the
//! controller's look-ahead, from the exact state at the window's start) and moved until
//! the time from each command to its target is the delay within 0.1 ms (a warning names
//! any command that could not be brought within 1 ms). The split point is printed rounded,
//! so the two parts are not exactly collinear: on a controller without jerk allowances
//! the model stops there, and the placement accounts for that (a secant search on the
//! command's time). A part that would move the tool less than 2 µm in less than 0.5 ms is
//! not made (the command goes to the block's end).
//!
//! # Not enough time before a start
//! A command never moves back across the previous valve command, a line of unknown time,
//! or the start of the look-ahead window. If the motion time available before a run start
//! is shorter than `open_delay_s`, the open command goes as early as it can and a dwell
//! (`G4`) for the remainder is inserted right before the run's first extruding move, with
//! a warning (the first, then a count). When a backend prints, the dwell is timed as the
//! controller waits: whole milliseconds, rounded up so the valve is open when the run
//! starts. Under constant velocity the open then moves the fraction later over the motion
//! before the wait, to its delay; with no motion there (or under trapezoid timing, where
//! a split printed rounded can add a stop) it comes less than a millisecond early. A
//! command that falls into a wait splits it on whole milliseconds too, on the side safe
//! for the material: an open earlier, a close later (up to a millisecond late, never
//! early: an early close starves the run's last block). A close that cannot be early
//! enough (a run shorter than `close_delay_s` right after a line of unknown time) goes
//! as early as it can, with a warning.
//!
//! # Overlapping events (the rule)
//! Commands are issued in run order: close of run k, then open of run k+1, each after
//! the one before it. So:
//! - when the gap between two runs is shorter than `open_delay_s − close_delay_s` (the
//!   open would be due before the previous close), the open follows the close
//!   immediately and a dwell makes up the rest (as above). With `keep_open_gap_s` set, such
//!   short gaps are bridged instead;
//! - when a run is shorter than `close_delay_s − open_delay_s` (its close would be due
//!   before its open), the close follows the open immediately (the flow then lasts
//!   longer than the run), with a warning;
//! - a close due before its own run's start (a run shorter than `close_delay_s`) is
//!   issued before the start: that is the right time.
//!
//! # Look-ahead and memory
//! The pass holds the blocks of the last `2 · max(open_delay_s, close_delay_s) + 0.05 s`
//! of motion (plus `keep_open_gap_s` while a gap may still be bridged, and the
//! controller's `lookahead` moves after them, whose timing can still change), and never
//! more than `max_lookahead` blocks (default 4096): memory does not grow with the input.
//! A travel longer than the window needs nothing more: the open point lies within the
//! last `open_delay_s` before the start, which is inside the window by definition. When
//! the block bound cuts the window shorter (many tiny blocks), older blocks are released
//! as they are; a command that would have to go before them is placed at the window's
//! start (an open then dwells for the rest), and a warning says so.
//!
//! # Options
//! - `open_delay_s`, `close_delay_s`: default the `[polar.valve]` settings (else 0.2 s
//!   and 0.1 s);
//! - `open_command`, `close_command`: default the `[polar.valve]` ones (else
//!   `M42 P0 S1`, `M42 P0 S0`);
//! - `timing`: `constant-velocity` or `trapezoid` (default the controller's);
//! - `keep_open_gap_s` (default 0), `max_lookahead` (blocks, default 4096),
//!   `e_only` (`auto`, `timed`, `untimed`), `rapid_feed` (mm/min, default 3000, as the
//!   other timing passes).
//!
//! # Limits
//! - The pass must see the feeds the controller runs: `extrude-rate` in `screw-rpm` mode
//!   with `limit = "warn"` (the preset) only rounds them; its `constant-flow` mode and
//!   `limit = "slow-feed"` change feeds afterwards, which moves the valve timing.
//! - Inverse-time (G93) moves that are split get each part's F scaled so the parts keep
//!   the move's time.
//! - Tool poses (before inverse kinematics) and G53 moves have no known time here: they
//!   are lines of unknown time.
//! - The valve is assumed closed at the program start and is closed at the end.

mod input;
mod place;
mod window;

use std::collections::{HashMap, VecDeque};

use serde::{Deserialize, Serialize};

use super::{Context, Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{AXIS_COUNT, Block, Joints, Span};
use crate::motion::{self, Model, Segment, Timing};
use crate::num::print::Decimals;

use place::Event;
use window::Item;

/// How E-only moves are timed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EOnly {
    /// `untimed` with a `[polar]` machine (the screw printer), else `timed`.
    #[default]
    Auto,
    /// E-only moves are moves with their motion time (an extruder axis).
    Timed,
    /// E-only moves take no time (a screw: `extrude-rate` makes them comments or dwells).
    Untimed,
}

/// Options of `valve-lookahead`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Seconds from the open command to material flowing; default `[polar.valve]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub open_delay_s: Option<f64>,
    /// Seconds from the close command to the flow stopping; default `[polar.valve]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub close_delay_s: Option<f64>,
    /// The command that opens the valve; default `[polar.valve]`, else `M42 P0 S1`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub open_command: Option<String>,
    /// The command that closes the valve; default `[polar.valve]`, else `M42 P0 S0`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub close_command: Option<String>,
    /// Timing model; default the controller's (the run's `--timing` wins).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timing: Option<Timing>,
    /// Keep the valve open across non-extruding gaps shorter than this, seconds (0: off).
    pub keep_open_gap_s: f64,
    /// Most blocks held for look-ahead.
    pub max_lookahead: usize,
    /// How E-only moves are timed.
    pub e_only: EOnly,
    /// Speed of rapids, mm/min.
    pub rapid_feed: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            open_delay_s: None,
            close_delay_s: None,
            open_command: None,
            close_command: None,
            timing: None,
            keep_open_gap_s: 0.0,
            max_lookahead: 4096,
            e_only: EOnly::Auto,
            rapid_feed: motion::DEFAULT_RAPID_FEED,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "valve-lookahead",
    summary: "valve open/close commands a set motion time before each extrusion start and end, splitting moves at the exact point (dwell when the travel is too short)",
    build: |t, ctx| Ok(Box::new(ValveLookahead::new(super::options(t)?, ctx)?)),
    defaults: || super::to_toml(&Options::default()),
};

/// A split closer than this (seconds) to a block's end goes to the end instead. One
/// microsecond: moving a valve open later than wanted takes material from the first block
/// of the extrusion, and a block of 3 ms loses 1 % of it to 30 µs (the cube print's first
/// 0.018 mm extrusion after a prime lost 3.45 % to a 31.6 µs snap at 50 µs). A split
/// whose point prints the same as an end is not made (`split_move`).
const SPLIT_EPS: f64 = 1e-6;
/// Placements are moved until their time is this close to the delay, seconds.
const SETTLE_TOL: f64 = 1e-4;
/// A placement further off than this after settling is warned about, seconds.
const WARN_TOL: f64 = 1e-3;
/// Rounds of re-placement per settling.
const SETTLE_ROUNDS: usize = 12;
/// Extra seconds of motion the window holds.
const HOLD_MARGIN_S: f64 = 0.05;

/// A warning counted over the run: the first one is reported, then a count.
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

/// The valve: its delays and commands.
struct Valve {
    /// Seconds from the open command to material flowing.
    open_delay: f64,
    /// Seconds from the close command to the flow stopping.
    close_delay: f64,
    open_command: String,
    close_command: String,
    /// Gaps shorter than this (seconds of motion) keep the valve open.
    keep_open_gap: f64,
}

/// The input's position and the screw's material book keeping, and how the controller
/// reads positions.
struct Track {
    /// Position as the input has it.
    pos: Joints,
    /// The G92 offsets the backend adds when it prints positions.
    offsets: [f64; AXIS_COUNT],
    /// Retracted E not yet pushed back.
    pending: f64,
    /// The backend's printed precision (`None`: positions are used as they are).
    decimals: Option<Decimals>,
    /// E-only moves take no motion time (a screw extruder).
    e_untimed: bool,
}

/// The controller's timing of the window.
struct Clock {
    model: Model,
    /// Moves the controller looks ahead (0: constant velocity, every block on its own).
    window: usize,
    /// Time at the window's start.
    base_time: f64,
    /// The planner's state at the window's start: the last move and its exit speed
    /// (`None`: the machine is stopped).
    base_last: Option<(Segment, f64)>,
    /// The held items' times are out of date.
    dirty: bool,
}

/// The look-ahead queue: the held blocks and the valve commands placed among them.
struct Queue {
    /// What is known of each held block, with the block.
    items: VecDeque<Item>,
    /// The valve commands held, by id.
    events: HashMap<u64, Event>,
    /// The last identity handed out (items' ends and events share them).
    next_id: u64,
    /// Most blocks held.
    max_lookahead: usize,
    /// Seconds of motion held behind the last block whose timing is final.
    hold: f64,
    /// Queue length at which the next release is tried.
    next_check: usize,
    /// Settling re-places a command: no warnings again.
    replacing: bool,
}

/// The extrusion run being read.
struct Run {
    /// Inside a run.
    active: bool,
    /// End id of the last extruding item of the current or last run.
    end: Option<u64>,
    span: Span,
    /// A run ended and its close waits to see whether the gap is bridged.
    close_pending: bool,
    /// Lower bound (constant-velocity time) of the gap since the run ended.
    gap_cv: f64,
}

/// The warnings counted over the program.
#[derive(Default)]
struct Warnings {
    dwelled: Tally,
    late: Tally,
    short_run: Tally,
    windowed: Tally,
    unsettled: Tally,
    unknown: Tally,
}

/// The `valve-lookahead` pass.
pub struct ValveLookahead {
    valve: Valve,
    track: Track,
    clock: Clock,
    queue: Queue,
    run: Run,
    warn: Warnings,
}

impl ValveLookahead {
    /// The pass with `options` in `ctx` (valve settings from `[polar.valve]`).
    pub fn new(options: Options, ctx: &Context<'_>) -> Result<ValveLookahead, Diagnostic> {
        let valve = ctx.polar.map(|p| p.valve.clone()).unwrap_or_default();
        let open_delay = options.open_delay_s.unwrap_or(valve.open_delay_s);
        let close_delay = options.close_delay_s.unwrap_or(valve.close_delay_s);
        for (v, what) in [
            (open_delay, "open_delay_s"),
            (close_delay, "close_delay_s"),
            (options.keep_open_gap_s, "keep_open_gap_s"),
        ] {
            if !(v.is_finite() && (0.0..=3600.0).contains(&v)) {
                return Err(Diagnostic::settings(format!(
                    "{what} must be a number of seconds from 0 to 3600 (got {v})"
                )));
            }
        }
        let open_command = options.open_command.clone().unwrap_or(valve.open_command);
        let close_command = options.close_command.clone().unwrap_or(valve.close_command);
        for c in [&open_command, &close_command] {
            if c.trim().is_empty() || c.contains('\n') {
                return Err(Diagnostic::settings(
                    "open_command and close_command must be one non-empty line",
                ));
            }
        }
        if options.max_lookahead < 16 {
            return Err(Diagnostic::settings(
                "max_lookahead must be at least 16 blocks",
            ));
        }
        let model = ctx.model(options.timing, options.rapid_feed)?;
        let window = match model.timing {
            Timing::ConstantVelocity => 0,
            Timing::Trapezoid => model.lookahead,
        };
        let e_untimed = match options.e_only {
            EOnly::Auto => ctx.polar.is_some(),
            EOnly::Timed => false,
            EOnly::Untimed => true,
        };
        Ok(ValveLookahead {
            valve: Valve {
                open_delay,
                close_delay,
                open_command,
                close_command,
                keep_open_gap: options.keep_open_gap_s,
            },
            track: Track {
                pos: Joints::default(),
                offsets: [0.0; AXIS_COUNT],
                pending: 0.0,
                decimals: ctx.decimals,
                e_untimed,
            },
            clock: Clock {
                model,
                window,
                base_time: 0.0,
                base_last: None,
                dirty: false,
            },
            queue: Queue {
                items: VecDeque::new(),
                events: HashMap::new(),
                next_id: 1,
                max_lookahead: options.max_lookahead,
                hold: 2.0 * open_delay.max(close_delay) + HOLD_MARGIN_S,
                next_check: 32,
                replacing: false,
            },
            run: Run {
                active: false,
                end: None,
                span: Span::default(),
                close_pending: false,
                gap_cv: 0.0,
            },
            warn: Warnings::default(),
        })
    }
}

impl Pass for ValveLookahead {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            let (kind, extruding) = self.classify(&block, out);
            self.push(block, kind, extruding, out);
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        if self.run.active || self.run.close_pending {
            self.close_run(out);
        }
        self.release(true, out);
        for (tally, what) in [
            (
                &self.warn.dwelled,
                "extrusion starts needed a dwell for the open delay",
            ),
            (
                &self.warn.late,
                "close commands could not come early enough",
            ),
            (
                &self.warn.short_run,
                "extrusion runs were shorter than the valve delays allow",
            ),
            (
                &self.warn.unsettled,
                "valve commands are more than 1 ms off their delay",
            ),
        ] {
            if tally.count > 1 {
                out.diag(Diagnostic::warning(
                    "valve-lookahead::count",
                    format!("valve-lookahead: {} {what}", tally.count),
                ));
            }
        }
    }
}
