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
//! (`G4`, whole microseconds) for the remainder is inserted right before the run's first
//! extruding move, with a warning (the first, then a count). A close that cannot be
//! early enough (a run shorter than `close_delay_s` right after a line of unknown time)
//! goes as early as it can, with a warning.
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

use std::collections::{HashMap, VecDeque};

use serde::{Deserialize, Serialize};

use super::{Context, Output, Pass, PassInfo};
use crate::back::Decimals;
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, AxisSet, Block, BlockKind, Command, Comment, CommentStyle, FeedMode, Joints,
    Motion, MotionKind, Span, Target,
};
use crate::motion::arc::ArcPath;
use crate::motion::{self, Model, Profile, Segment, Timing};
use crate::num::print::printed;

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

/// A split closer than this (seconds) to a block's end goes to the end instead.
const SPLIT_EPS: f64 = 5e-5;
/// Parts of a split move that move the tool less than this (mm)...
const MIN_PART_MM: f64 = 0.002;
/// ...and take less than this (seconds) are not made.
const SNAP_S: f64 = 5e-4;
/// Placements are moved until their time is this close to the delay, seconds.
const SETTLE_TOL: f64 = 1e-4;
/// A placement further off than this after settling is warned about, seconds.
const WARN_TOL: f64 = 1e-3;
/// Rounds of re-placement per settling.
const SETTLE_ROUNDS: usize = 12;
/// Extra seconds of motion the window holds.
const HOLD_MARGIN_S: f64 = 0.05;
/// E amounts below this are float dust, not material.
const E_EPS: f64 = 1e-9;

/// A move held in the window: its IR ends and the printed ends the controller reads.
#[derive(Debug, Clone)]
struct MoveData {
    from: Joints,
    to: Joints,
    p_from: Joints,
    p_to: Joints,
    seg: Segment,
}

#[derive(Debug, Clone)]
enum Kind {
    /// A move with its segment.
    Move(Box<MoveData>),
    /// A dwell: stops the machine, takes `seconds`; `owner` is the event that inserted it.
    Dwell { seconds: f64, owner: Option<u64> },
    /// A line of unknown time: stops the machine; nothing moves across it.
    Barrier,
    /// No time, no stop.
    Other,
    /// The valve command of event `id`.
    Marker(u64),
}

/// What the window knows of a held block (the block itself is in
/// `ValveLookahead::blocks`, at the same index).
#[derive(Debug, Clone)]
struct Item {
    kind: Kind,
    extruding: bool,
    /// Identity of the item's start (kept by the first part when it is split).
    start_id: u64,
    /// Identity of the item's end (kept by the last part).
    end_id: u64,
    start: f64,
    dur: f64,
    /// Entry and exit speed of a move as timed.
    speeds: (f64, f64),
}

impl Item {
    fn end(&self) -> f64 {
        self.start + self.dur
    }
    fn moving(&self) -> Option<&Segment> {
        match &self.kind {
            Kind::Move(m) if m.seg.moves() => Some(&m.seg),
            _ => None,
        }
    }
    fn is_stop(&self) -> bool {
        matches!(self.kind, Kind::Dwell { .. } | Kind::Barrier)
    }
}

/// Seconds an item takes at constant velocity (a dwell its time).
fn cv_duration(kind: &Kind) -> f64 {
    match kind {
        Kind::Move(m) if m.seg.moves() => m.seg.length / m.seg.v_max,
        Kind::Dwell { seconds, .. } => seconds.max(0.0),
        _ => 0.0,
    }
}

/// A valve command to place.
#[derive(Debug, Clone)]
struct Event {
    open: bool,
    /// Open: the start id of the run's first item; close: the end id of its last.
    target: u64,
    delay: f64,
    /// Correction of the wanted time found by settling.
    corr: f64,
    /// The previous correction and the error it gave.
    last: Option<(f64, f64)>,
    /// The item this event split, and the ids of the two parts' inner ends.
    original: Option<(Item, Block, u64, u64)>,
    /// Placed at the earliest allowed point, short of its delay.
    clamped: bool,
    span: Span,
}

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

/// Most spare move boxes kept (a window's worth is enough).
const SPARE_BOXES: usize = 1024;

/// The `valve-lookahead` pass.
pub struct ValveLookahead {
    model: Model,
    window: usize,
    open_delay: f64,
    close_delay: f64,
    open_command: String,
    close_command: String,
    keep_open_gap: f64,
    max_lookahead: usize,
    e_untimed: bool,
    decimals: Option<Decimals>,
    /// The `[polar]` machine's (r, θ) axes, for tool distances.
    polar_axes: Option<(Axis, Axis)>,
    hold: f64,
    /// Position as the input has it.
    pos: Joints,
    offsets: [f64; AXIS_COUNT],
    /// The last move's end and its printed form.
    p_cache: Option<(Joints, Joints)>,
    /// Retracted E not yet pushed back.
    pending: f64,
    /// The window: what is known of each held block, and the blocks, index by index
    /// (always the same length: change them through `insert_item` and `remove_item`).
    /// Kept apart so that taking a block in and passing it on copies the block alone,
    /// not the block inside its item; the window's work only needs the blocks to split
    /// a move.
    items: VecDeque<Item>,
    blocks: VecDeque<Block>,
    events: HashMap<u64, Event>,
    next_id: u64,
    /// Time and planner state at the window's start.
    base_time: f64,
    base_last: Option<(Segment, f64)>,
    dirty: bool,
    scratch_moving: Vec<usize>,
    scratch_stops: Vec<usize>,
    /// Boxes of moves passed on, for the next moves (a box per move otherwise): the
    /// boxes themselves are the point, so `vec_box` does not apply.
    #[allow(clippy::vec_box)]
    spare: Vec<Box<MoveData>>,
    /// Settling re-places a command: no warnings again.
    replacing: bool,
    next_check: usize,
    /// Inside a run.
    in_run: bool,
    /// End id of the last extruding item of the current or last run.
    run_end: Option<u64>,
    run_span: Span,
    /// A run ended and its close waits to see whether the gap is bridged.
    close_pending: bool,
    /// Lower bound (constant-velocity time) of the gap since the run ended.
    gap_cv: f64,
    dwelled: Tally,
    late: Tally,
    short_run: Tally,
    windowed: Tally,
    unsettled: Tally,
    unknown: Tally,
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
        if !(options.rapid_feed.is_finite() && options.rapid_feed > 0.0) {
            return Err(Diagnostic::settings("rapid_feed must be a positive number"));
        }
        let model = Model::for_machines(ctx.polar, ctx.machine, ctx.timing, options.timing)
            .with_rapid_feed(options.rapid_feed);
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
            model,
            window,
            open_delay,
            close_delay,
            open_command,
            close_command,
            keep_open_gap: options.keep_open_gap_s,
            max_lookahead: options.max_lookahead,
            e_untimed,
            decimals: ctx.decimals,
            polar_axes: ctx.polar.map(|p| (p.r_axis, p.theta_axis)),
            hold: 2.0 * open_delay.max(close_delay) + HOLD_MARGIN_S,
            pos: Joints::default(),
            offsets: [0.0; AXIS_COUNT],
            p_cache: None,
            pending: 0.0,
            items: VecDeque::new(),
            blocks: VecDeque::new(),
            events: HashMap::new(),
            next_id: 1,
            base_time: 0.0,
            base_last: None,
            dirty: false,
            scratch_moving: Vec::new(),
            scratch_stops: Vec::new(),
            spare: Vec::new(),
            replacing: false,
            next_check: 32,
            in_run: false,
            run_end: None,
            run_span: Span::default(),
            close_pending: false,
            gap_cv: 0.0,
            dwelled: Tally::default(),
            late: Tally::default(),
            short_run: Tally::default(),
            windowed: Tally::default(),
            unsettled: Tally::default(),
            unknown: Tally::default(),
        })
    }

    fn fresh(&mut self) -> u64 {
        self.next_id += 1;
        self.next_id
    }

    /// The joints as the controller reads them: each known axis rounded to the backend's
    /// decimals (with the G92 offsets the backend adds).
    fn printed(&self, j: &Joints) -> Joints {
        self.printed_reusing(j, None)
    }

    /// [`Self::printed`], taking unchanged axes' printed values from `seen` (see
    /// [`Decimals::printed_joints`]).
    fn printed_reusing(&self, j: &Joints, seen: Option<&(Joints, Joints)>) -> Joints {
        match self.decimals {
            Some(d) => d.printed_joints(j, &self.offsets, seen),
            None => *j,
        }
    }

    /// How far the tool moves between two joint vectors, mm: through the `[polar]`
    /// machine's r and θ when there is one, else X, Y, Z (and the other joints).
    fn tool_distance(&self, a: &Joints, b: &Joints) -> f64 {
        let mut d2 = 0.0;
        if let Some((r, th)) = self.polar_axes
            && a.known.contains(r)
            && a.known.contains(th)
        {
            d2 += (motion::polar_point(b, r, th) - motion::polar_point(a, r, th)).norm_squared();
            for ax in Axis::ALL {
                if ax != r && ax != th && ax != Axis::Z && ax != Axis::E {
                    d2 += (b.values[ax.index()] - a.values[ax.index()]).powi(2);
                }
            }
            return d2.sqrt();
        }
        for ax in Axis::ALL {
            if ax != Axis::E {
                d2 += (b.values[ax.index()] - a.values[ax.index()]).powi(2);
            }
        }
        d2.sqrt()
    }

    fn printed_feed(&self, f: f64) -> f64 {
        self.decimals.and_then(|d| printed(f, d.feed)).unwrap_or(f)
    }

    /// The segment of motion `m` between printed joints, at its printed feed.
    fn segment(&self, m: &Motion, p_from: &Joints, p_to: &Joints) -> Segment {
        let feed = crate::ir::Feed {
            mode: m.feed.mode,
            rate: m.feed.rate.map(|f| self.printed_feed(f)),
        };
        self.model.between(p_from, p_to, m.kind, &feed)
    }

    /// A move's data in a box, reusing a spare one (written field by field: a whole
    /// `MoveData` built first and then moved in stalls on the copy).
    fn boxed(
        &mut self,
        from: Joints,
        to: Joints,
        p_from: Joints,
        p_to: Joints,
        seg: Segment,
    ) -> Box<MoveData> {
        match self.spare.pop() {
            Some(mut b) => {
                b.from = from;
                b.to = to;
                b.p_from = p_from;
                b.p_to = p_to;
                b.seg = seg;
                b
            }
            None => Box::new(MoveData {
                from,
                to,
                p_from,
                p_to,
                seg,
            }),
        }
    }

    fn item(&mut self, kind: Kind, extruding: bool) -> Item {
        let id = self.fresh();
        Item {
            kind,
            extruding,
            start_id: id,
            end_id: id,
            start: 0.0,
            dur: 0.0,
            speeds: (0.0, 0.0),
        }
    }

    /// What an input block is in the window (its kind, and whether it extrudes),
    /// tracking position and retraction.
    fn classify(&mut self, block: &Block, out: &mut Output<'_>) -> (Kind, bool) {
        match &block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(to) = &m.target else {
                    self.pos.forget(m.written);
                    self.p_cache = None;
                    let span = block.span;
                    self.unknown.hit(out, || {
                        Diagnostic::warning(
                            "valve-lookahead::unknown-time",
                            "a move to a tool pose has no known time here: valve commands are not moved across it",
                        )
                        .at_span(span)
                        .with_help("run valve-lookahead after inverse kinematics")
                    });
                    return (Kind::Barrier, false);
                };
                if m.machine_frame {
                    self.pos.forget(m.written);
                    self.p_cache = None;
                    return (Kind::Barrier, false);
                }
                let from = self.pos;
                let next = from.updated_by(to);
                let de = match (from.get(Axis::E), next.get(Axis::E)) {
                    (Some(a), Some(b)) => b - a,
                    _ => 0.0,
                };
                let e_only = de != 0.0
                    && Axis::ALL.iter().all(|&a| {
                        a == Axis::E
                            || match (from.get(a), next.get(a)) {
                                (Some(p), Some(q)) => p == q,
                                _ => true,
                            }
                    });
                let p_from = match self.p_cache {
                    Some((j, p)) if j.same_known(&from) => p,
                    _ => self.printed(&from),
                };
                let p_to = self.printed_reusing(&next, self.p_cache.as_ref());
                crate::back::remember_printed(&mut self.p_cache, next, p_to);
                self.pos = next;
                let material = if de < 0.0 {
                    self.pending -= de;
                    0.0
                } else {
                    let restored = de.min(self.pending);
                    self.pending -= restored;
                    if self.pending < E_EPS {
                        self.pending = 0.0;
                    }
                    if de - restored < E_EPS {
                        0.0
                    } else {
                        de - restored
                    }
                };
                if e_only && self.e_untimed {
                    let kind = if material > 0.0 {
                        Kind::Barrier
                    } else {
                        Kind::Other
                    };
                    return (kind, material > 0.0);
                }
                let seg = self.segment(m, &p_from, &p_to);
                let extruding = material > 0.0 && seg.moves();
                (
                    Kind::Move(self.boxed(from, next, p_from, p_to, seg)),
                    extruding,
                )
            }
            BlockKind::Dwell { seconds } => (
                Kind::Dwell {
                    seconds: *seconds,
                    owner: None,
                },
                false,
            ),
            BlockKind::Command(c) if !c.clobbers.is_empty() => {
                self.pos.forget(c.clobbers);
                self.p_cache = None;
                (Kind::Barrier, false)
            }
            BlockKind::Verbatim(v) => {
                self.pos.forget(v.clobbers);
                self.p_cache = None;
                (Kind::Barrier, false)
            }
            BlockKind::Offset(o) => {
                self.offsets = o.offsets;
                self.p_cache = None;
                (Kind::Other, false)
            }
            _ => (Kind::Other, false),
        }
    }

    /// Recomputes the time of every held item from the state at the window's start, as
    /// the controller's planner ([`motion::Planner`]) would: each move knows the
    /// `lookahead` moves after it up to the next stop, and must be able to stop at the
    /// end of what it knows.
    fn retime(&mut self) {
        self.dirty = false;
        if self.window == 0 {
            // Constant velocity: every block's time is its own.
            let mut time = self.base_time;
            for it in self.items.iter_mut() {
                it.start = time;
                it.dur = cv_duration(&it.kind);
                time = it.end();
            }
            return;
        }
        let n = self.items.len();
        let mut last = self.base_last;
        // Moving moves by position, and for each item the index of the next stop.
        let mut moving = std::mem::take(&mut self.scratch_moving);
        let mut next_stop = std::mem::take(&mut self.scratch_stops);
        moving.clear();
        next_stop.clear();
        moving.extend(
            self.items
                .iter()
                .enumerate()
                .filter(|(_, it)| it.moving().is_some())
                .map(|(i, _)| i),
        );
        next_stop.resize(n + 1, n);
        for i in (0..n).rev() {
            next_stop[i] = if self.items[i].is_stop() {
                i
            } else {
                next_stop[i + 1]
            };
        }
        let mut time = self.base_time;
        let mut k = 0usize;
        for (i, &stop) in next_stop.iter().enumerate().take(n) {
            let seg = match &self.items[i].kind {
                Kind::Move(m) if m.seg.moves() => Some(m.seg),
                Kind::Dwell { .. } | Kind::Barrier => {
                    last = None;
                    None
                }
                _ => None,
            };
            let (dur, speeds) = match seg {
                None => (cv_duration(&self.items[i].kind), (0.0, 0.0)),
                Some(seg) => {
                    // This move is moving[k]; its window ends at the next stop.
                    let mut end = k;
                    while end + 1 < moving.len() && end < k + self.window && moving[end + 1] < stop
                    {
                        end += 1;
                    }
                    let seg_of = |idx: usize| match &self.items[moving[idx]].kind {
                        Kind::Move(m) => m.seg,
                        _ => seg,
                    };
                    let mut exit = 0.0f64;
                    for j in (k + 1..=end).rev() {
                        let s = seg_of(j);
                        exit = (exit * exit + 2.0 * s.accel * s.length)
                            .sqrt()
                            .min(s.v_max)
                            .min(self.model.junction(&seg_of(j - 1), &s));
                    }
                    let entry = match &last {
                        Some((prev, v)) => v.min(self.model.junction(prev, &seg)),
                        None => 0.0,
                    };
                    let exit = exit.min((entry * entry + 2.0 * seg.accel * seg.length).sqrt());
                    let p = Profile::new(&seg, entry, exit);
                    last = Some((seg, p.v_exit));
                    k += 1;
                    (p.duration(), (p.v_entry, p.v_exit))
                }
            };
            let it = &mut self.items[i];
            it.start = time;
            it.dur = dur;
            it.speeds = speeds;
            time = it.end();
        }
        self.scratch_moving = moving;
        self.scratch_stops = next_stop;
    }

    /// The speed profile of a held move as last timed.
    fn profile_of(&self, it: &Item) -> Option<Profile> {
        let Kind::Move(m) = &it.kind else {
            return None;
        };
        let mut seg = m.seg;
        if self.window == 0 {
            seg.accel = f64::INFINITY;
        }
        Some(Profile::new(&seg, it.speeds.0, it.speeds.1))
    }

    fn ensure_timed(&mut self) {
        if self.dirty {
            self.retime();
        }
    }

    fn find_start(&self, id: u64) -> Option<usize> {
        self.items.iter().position(|it| it.start_id == id)
    }

    fn find_end(&self, id: u64) -> Option<usize> {
        self.items.iter().rposition(|it| it.end_id == id)
    }

    fn find_marker(&self, id: u64) -> Option<usize> {
        self.items
            .iter()
            .position(|it| matches!(it.kind, Kind::Marker(m) if m == id))
    }

    /// The target's index (where a zero-delay command would go) and time.
    fn target_of(&self, ev: &Event) -> Option<(usize, f64)> {
        if ev.open {
            let i = self.find_start(ev.target)?;
            Some((i, self.items[i].start))
        } else {
            let i = self.find_end(ev.target)?;
            Some((i + 1, self.items[i].end()))
        }
    }

    /// Splits item `i` `dt` seconds into it; returns the end id of the first part and
    /// the start id of the second.
    fn split(&mut self, i: usize, dt: f64) -> Option<(u64, u64)> {
        let it = &self.items[i];
        let (first, second) = match &it.kind {
            Kind::Move(m) => {
                let prof = self.profile_of(it)?;
                let f = prof.fraction_at(dt);
                if !(f > 1e-9 && f < 1.0 - 1e-9) {
                    return None;
                }
                let BlockKind::Motion(motion) = &self.blocks[i].kind else {
                    return None;
                };
                let mid = match motion.kind {
                    MotionKind::Arc(a) if a.extra_turns == 0 => {
                        ArcPath::new(&m.from, &m.to, &a)?.point(f)
                    }
                    MotionKind::Arc(_) => return None,
                    _ => motion::lerp(&m.from, &m.to, f),
                };
                let p_mid = self.printed(&mid);
                if p_mid == m.p_from || p_mid == m.p_to {
                    return None;
                }
                // No sliver blocks (below a stepper's resolution) where that costs less
                // than SNAP_S: the command goes to the block's end instead.
                if (self.tool_distance(&m.p_from, &p_mid) < MIN_PART_MM && dt < SNAP_S)
                    || (self.tool_distance(&p_mid, &m.p_to) < MIN_PART_MM && it.dur - dt < SNAP_S)
                {
                    return None;
                }
                let mut ma = motion.clone();
                ma.target = Target::Joints(mid);
                let mut mb = motion.clone();
                if motion.feed.mode == FeedMode::InverseTime
                    && let Some(rate) = motion.feed.rate
                {
                    // Each part keeps its share of the move's time.
                    ma.feed.rate = Some(rate / f);
                    mb.feed.rate = Some(rate / (1.0 - f));
                }
                let seg_a = self.segment(&ma, &m.p_from, &p_mid);
                let seg_b = self.segment(&mb, &p_mid, &m.p_to);
                let mut ba = self.blocks[i].clone();
                ba.kind = BlockKind::Motion(ma);
                let mut bb = self.blocks[i].clone();
                bb.kind = BlockKind::Motion(mb);
                bb.comments.clear();
                let da = MoveData {
                    from: m.from,
                    to: mid,
                    p_from: m.p_from,
                    p_to: p_mid,
                    seg: seg_a,
                };
                let db = MoveData {
                    from: mid,
                    to: m.to,
                    p_from: p_mid,
                    p_to: m.p_to,
                    seg: seg_b,
                };
                (
                    (ba, Kind::Move(Box::new(da))),
                    (bb, Kind::Move(Box::new(db))),
                )
            }
            Kind::Dwell { seconds, owner } => {
                let owner = *owner;
                let a = (dt * 1e6).round() / 1e6;
                let b = ((seconds - a) * 1e6).round() / 1e6;
                if a <= 0.0 || b <= 0.0 {
                    return None;
                }
                let mut ba = self.blocks[i].clone();
                ba.kind = BlockKind::Dwell { seconds: a };
                let mut bb = self.blocks[i].clone();
                bb.kind = BlockKind::Dwell { seconds: b };
                bb.comments.clear();
                (
                    (ba, Kind::Dwell { seconds: a, owner }),
                    (bb, Kind::Dwell { seconds: b, owner }),
                )
            }
            _ => return None,
        };
        let (start_id, end_id, extruding) = (it.start_id, it.end_id, it.extruding);
        let (mid_end, mid_start) = (self.fresh(), self.fresh());
        let a = Item {
            kind: first.1,
            extruding,
            start_id,
            end_id: mid_end,
            start: 0.0,
            dur: 0.0,
            speeds: (0.0, 0.0),
        };
        let b = Item {
            kind: second.1,
            extruding,
            start_id: mid_start,
            end_id,
            start: 0.0,
            dur: 0.0,
            speeds: (0.0, 0.0),
        };
        self.items[i] = a;
        self.blocks[i] = first.0;
        self.insert_item(i + 1, b, second.0);
        self.dirty = true;
        Some((mid_end, mid_start))
    }

    /// The command item of event `id`, and its block.
    fn marker(&mut self, ev: &Event, id: u64) -> (Item, Block) {
        let text: &str = if ev.open {
            &self.open_command
        } else {
            &self.close_command
        };
        let block = Block::new(
            ev.span,
            BlockKind::Command(Command {
                text: text.into(),
                modes: None,
                clobbers: AxisSet::EMPTY,
            }),
        );
        (self.item(Kind::Marker(id), false), block)
    }

    /// Inserts `item` and its `block` at `i` in the window.
    fn insert_item(&mut self, i: usize, item: Item, block: Block) {
        self.items.insert(i, item);
        self.blocks.insert(i, block);
    }

    /// Takes item `i` and its block out of the window.
    fn remove_item(&mut self, i: usize) {
        self.items.remove(i);
        self.blocks.remove(i);
    }

    /// Places event `id`'s command (and an open's dwell) by the current timing.
    fn place(&mut self, id: u64, out: &mut Output<'_>) {
        self.ensure_timed();
        let Some(ev) = self.events.get(&id).cloned() else {
            return;
        };
        let Some((b, t_target)) = self.target_of(&ev) else {
            // The target left the window (forced release): the command goes at its start.
            let (marker, block) = self.marker(&ev, id);
            self.insert_item(0, marker, block);
            self.dirty = true;
            if let Some(e) = self.events.get_mut(&id) {
                e.clamped = true;
            }
            return;
        };
        let desired = t_target - ev.delay - ev.corr;
        let mut lower = b;
        while lower > 0 {
            let it = &self.items[lower - 1];
            if matches!(it.kind, Kind::Marker(_) | Kind::Barrier) {
                break;
            }
            lower -= 1;
        }
        let mut pos = lower;
        let mut clamped = true;
        let mut original = None;
        for i in (lower..b).rev() {
            let it = &self.items[i];
            if it.start > desired + 1e-12 {
                continue;
            }
            clamped = false;
            let end = it.end();
            if desired >= end - SPLIT_EPS {
                pos = i + 1;
            } else if desired - it.start <= SPLIT_EPS {
                pos = i;
            } else {
                let (saved, saved_block) = (it.clone(), self.blocks[i].clone());
                match self.split(i, desired - it.start) {
                    Some((ea, sb)) => {
                        original = Some((saved, saved_block, ea, sb));
                        pos = i + 1;
                    }
                    None => {
                        let it = &self.items[i];
                        pos = if desired - it.start < it.end() - desired {
                            i
                        } else {
                            i + 1
                        };
                    }
                }
            }
            break;
        }
        if clamped {
            // As late as the same time allows (after comments, modes, moves of no length).
            while pos < b
                && self.items[pos].dur == 0.0
                && matches!(self.items[pos].kind, Kind::Other | Kind::Move(_))
            {
                pos += 1;
            }
        }
        let (marker, block) = self.marker(&ev, id);
        self.insert_item(pos, marker, block);
        self.dirty = true;
        if let Some(e) = self.events.get_mut(&id) {
            e.original = original;
            e.clamped = clamped;
        }
        if !clamped {
            return;
        }
        self.ensure_timed();
        let (Some(m), Some((ti, tt))) = (self.find_marker(id), self.target_of(&ev)) else {
            return;
        };
        let gap = tt - self.items[m].start;
        let short = ev.delay - gap;
        // An open that already has its dwell (placed again after the close before it
        // moved) lengthens or shortens it.
        if ev.open
            && let Some(d) = self.owned_dwell(id)
            && let Kind::Dwell { seconds, .. } = self.items[d].kind
        {
            self.set_dwell(d, id, seconds + short);
            return;
        }
        if short <= SETTLE_TOL / 2.0 {
            return;
        }
        if ev.open {
            let seconds = (short * 1e6).round() / 1e6;
            let mut dwell = Block::new(ev.span, BlockKind::Dwell { seconds });
            dwell.comments.push(Comment {
                text: "valve: waiting for the open delay".into(),
                style: CommentStyle::Semicolon,
            });
            let item = self.item(
                Kind::Dwell {
                    seconds,
                    owner: Some(id),
                },
                false,
            );
            self.insert_item(ti, item, dwell);
            self.dirty = true;
            let span = ev.span;
            if self.replacing {
                return;
            }
            self.dwelled.hit(out, || {
                Diagnostic::warning(
                    "valve-lookahead::dwell",
                    format!(
                        "only {gap:.4} s of motion before this extrusion start for an open delay of {:.4} s: dwelling {seconds:.4} s",
                        ev.delay
                    ),
                )
                .at_span(span)
                .with_help("lengthen the travel before the start, or set keep_open_gap_s to keep the valve open across short gaps")
            });
        } else if !self.replacing {
            let span = ev.span;
            let lead = ev.delay;
            let own_open = lower > 0
                && matches!(self.items[lower - 1].kind, Kind::Marker(o) if self.events.get(&o).is_some_and(|e| e.open));
            if own_open {
                self.short_run.hit(out, || {
                    Diagnostic::warning(
                        "valve-lookahead::short-run",
                        format!("this extrusion run is too short for the valve delays: the close follows the open at once ({gap:.4} s before the run ends instead of {lead:.4} s)"),
                    )
                    .at_span(span)
                })
            } else {
                self.late.hit(out, || {
                    Diagnostic::warning(
                        "valve-lookahead::late-close",
                        format!("the close command can only come {gap:.4} s before this extrusion ends, not {lead:.4} s"),
                    )
                    .at_span(span)
                    .with_help("a line of unknown time, the previous valve command or the look-ahead window's start is in the way")
                })
            }
        }
    }

    /// The last dwell event `id` inserted.
    fn owned_dwell(&self, id: u64) -> Option<usize> {
        self.items
            .iter()
            .rposition(|it| matches!(it.kind, Kind::Dwell { owner: Some(o), .. } if o == id))
    }

    /// Sets dwell `d` of event `id` to `seconds` (whole microseconds), or removes it.
    fn set_dwell(&mut self, d: usize, id: u64, seconds: f64) {
        let seconds = (seconds * 1e6).round() / 1e6;
        if seconds > 0.0 {
            self.items[d].kind = Kind::Dwell {
                seconds,
                owner: Some(id),
            };
            self.blocks[d].kind = BlockKind::Dwell { seconds };
        } else {
            self.remove_item(d);
        }
        self.dirty = true;
    }

    /// Takes event `id`'s command and dwell out again and merges its split.
    fn undo(&mut self, id: u64) {
        while let Some(d) = self
            .items
            .iter()
            .rposition(|it| matches!(it.kind, Kind::Dwell { owner: Some(o), .. } if o == id))
        {
            self.remove_item(d);
        }
        self.undo_marker(id);
    }

    /// Takes event `id`'s command out again and merges its split.
    fn undo_marker(&mut self, id: u64) {
        if let Some(m) = self.find_marker(id) {
            self.remove_item(m);
        }
        if let Some((mut orig, mut orig_block, ea, sb)) =
            self.events.get_mut(&id).and_then(|e| e.original.take())
            && let Some(a) = self.find_end(ea)
            && a + 1 < self.items.len()
            && self.items[a + 1].start_id == sb
        {
            // A dwell may have been lengthened or shortened since: merge what is there.
            if let (
                Kind::Dwell { seconds: sa, .. },
                Kind::Dwell { seconds: sb, .. },
                Kind::Dwell { owner, .. },
            ) = (&self.items[a].kind, &self.items[a + 1].kind, &orig.kind)
            {
                let seconds = ((sa + sb) * 1e6).round() / 1e6;
                orig.kind = Kind::Dwell {
                    seconds,
                    owner: *owner,
                };
                orig_block.kind = BlockKind::Dwell { seconds };
            }
            self.items[a] = orig;
            self.blocks[a] = orig_block;
            self.remove_item(a + 1);
        }
        self.dirty = true;
    }

    /// How far event `id`'s command is off its delay, seconds, when it is further off
    /// than the settling tolerance and can be moved.
    fn error_of(&mut self, id: u64) -> Option<f64> {
        self.ensure_timed();
        let ev = self.events.get(&id)?;
        let (_, tt) = self.target_of(ev)?;
        let m = self.find_marker(id)?;
        let error = (tt - self.items[m].start) - ev.delay;
        let stuck = ev.clamped && !ev.open && error < 0.0;
        (error.abs() > SETTLE_TOL && !stuck).then_some(error)
    }

    /// Moves every held command until its time to its target is the delay.
    fn settle(&mut self, out: &mut Output<'_>) {
        for _ in 0..SETTLE_ROUNDS {
            let ids: Vec<u64> = self
                .items
                .iter()
                .filter_map(|it| match it.kind {
                    Kind::Marker(id) => Some(id),
                    _ => None,
                })
                .collect();
            let mut changed = false;
            for id in ids {
                let Some(error) = self.error_of(id) else {
                    continue;
                };
                changed = true;
                self.fix(id, error, out);
            }
            if !changed {
                return;
            }
        }
    }

    /// Moves event `id`'s command (or changes its dwell) by `error` seconds.
    fn fix(&mut self, id: u64, error: f64, out: &mut Output<'_>) {
        // An open's own dwell takes the error first.
        if let Some(d) = self.owned_dwell(id)
            && let Kind::Dwell { seconds, .. } = self.items[d].kind
            && seconds - error > 0.0
        {
            self.set_dwell(d, id, seconds - error);
            return;
        }
        // Later commands placed before this one's target (an open that follows a close
        // at once) are taken out and placed again after it, so the order holds.
        let boundary = self
            .events
            .get(&id)
            .and_then(|ev| self.target_of(ev))
            .map_or(0, |(b, _)| b);
        let later: Vec<u64> = self
            .items
            .iter()
            .take(boundary)
            .filter_map(|it| match it.kind {
                Kind::Marker(l) if l > id => Some(l),
                _ => None,
            })
            .collect();
        for &l in &later {
            self.undo_marker(l);
        }
        self.undo(id);
        if let Some(e) = self.events.get_mut(&id) {
            // Secant step on error(corr): a split can add a corner (the printed split
            // point is rounded), so the command's time does not move 1:1 with the wish.
            let slope = match e.last {
                Some((c1, e1)) if (e.corr - c1).abs() > 1e-9 => (error - e1) / (e.corr - c1),
                _ => 1.0,
            };
            let slope = if slope.is_finite() && (0.2..=20.0).contains(&slope) {
                slope
            } else {
                1.0
            };
            e.last = Some((e.corr, error));
            e.corr -= error / slope;
        }
        // Re-placing repeats no warning.
        self.replacing = true;
        self.place(id, out);
        for l in later {
            self.place(l, out);
        }
        self.replacing = false;
    }

    /// Creates and places an event.
    fn event(&mut self, open: bool, target: u64, span: Span, out: &mut Output<'_>) {
        let id = self.fresh();
        let delay = if open {
            self.open_delay
        } else {
            self.close_delay
        };
        self.events.insert(
            id,
            Event {
                open,
                target,
                delay,
                corr: 0.0,
                last: None,
                original: None,
                clamped: false,
                span,
            },
        );
        self.place(id, out);
    }

    fn close_run(&mut self, out: &mut Output<'_>) {
        if let Some(end) = self.run_end.take() {
            let span = self.run_span;
            self.event(false, end, span, out);
        }
        self.close_pending = false;
        self.in_run = false;
    }

    /// Adds an input block of `kind` to the window and starts or ends runs and their
    /// events. Inlined into its one caller, so the block does not stop in this call's
    /// arguments.
    #[inline(always)]
    fn push(&mut self, block: Block, kind: Kind, extruding: bool, out: &mut Output<'_>) {
        let cv = match &kind {
            Kind::Move(m) if m.seg.moves() => m.seg.length / m.seg.v_max,
            Kind::Dwell { seconds, .. } => *seconds,
            _ => 0.0,
        };
        let barrier = matches!(kind, Kind::Barrier);
        let breaks = barrier || cv > 0.0;
        let id = self.fresh();
        let (start_id, end_id, span) = (id, id, block.span);
        let (start, dur) = if self.window == 0 && !self.dirty {
            // Constant velocity: the new block's time follows from the last one's.
            (
                self.items.back().map_or(self.base_time, Item::end),
                cv_duration(&kind),
            )
        } else {
            self.dirty = true;
            (0.0, 0.0)
        };
        self.blocks.push_back(block);
        self.items.push_back(Item {
            kind,
            extruding,
            start_id,
            end_id,
            start,
            dur,
            speeds: (0.0, 0.0),
        });
        if extruding {
            if !self.in_run {
                if self.close_pending && !barrier {
                    self.ensure_timed();
                    let gap = match self.run_end.and_then(|e| self.find_end(e)) {
                        Some(e) => self.items[self.items.len() - 1].start - self.items[e].end(),
                        None => f64::INFINITY,
                    };
                    // No motion time between (an untimed prime and its moves): one run.
                    if gap <= 1e-12 || gap < self.keep_open_gap {
                        self.close_pending = false;
                        self.in_run = true;
                    } else {
                        self.close_run(out);
                    }
                } else if self.close_pending {
                    self.close_run(out);
                }
                if !self.in_run {
                    self.in_run = true;
                    self.event(true, start_id, span, out);
                }
            }
            self.run_end = Some(end_id);
            self.run_span = span;
            if barrier {
                // An untimed prime: its end is a line of unknown time.
                self.in_run = false;
                self.close_pending = true;
                self.gap_cv = 0.0;
            }
        } else if breaks {
            if self.in_run {
                self.in_run = false;
                self.close_pending = true;
                self.gap_cv = 0.0;
            }
            if self.close_pending {
                self.gap_cv += cv;
                if barrier || self.gap_cv >= self.keep_open_gap {
                    self.close_run(out);
                }
            }
        }
        if self.items.len() >= self.next_check {
            self.release(false, out);
            self.next_check = self.items.len() + (self.items.len() / 2).max(32);
        }
    }

    /// Hands out the items whose timing and commands can no longer change (all of them
    /// at the end).
    fn release(&mut self, all: bool, out: &mut Output<'_>) {
        self.settle(out);
        self.ensure_timed();
        let n = self.items.len();
        let count = if all {
            n
        } else {
            // The last item whose timing is final: `window + 1` moves or a stop after it.
            let mut moves_after = 0usize;
            let mut h = None;
            for i in (0..n).rev() {
                if self.items[i].is_stop() || moves_after > self.window {
                    h = Some(i);
                    break;
                }
                if self.items[i].moving().is_some() {
                    moves_after += 1;
                }
            }
            let mut limit = match h {
                _ if self.window == 0 && n > 0 => self.items[n - 1].end() - self.hold,
                Some(h) => self.items[h].start - self.hold,
                None => f64::NEG_INFINITY,
            };
            if self.close_pending
                && let Some(e) = self.run_end.and_then(|e| self.find_end(e))
            {
                limit = limit.min(self.items[e].end() - self.close_delay - HOLD_MARGIN_S);
            }
            let mut q = 0usize;
            while q < n && self.items[q].end() <= limit {
                q += 1;
            }
            // Keep the moves whose look-ahead reaches past the limit.
            let mut k = q;
            let mut seen = 0usize;
            while k > 0 && seen < self.window + 2 {
                k -= 1;
                if self.items[k].moving().is_some() {
                    seen += 1;
                }
            }
            if self.window == 0 { q } else { k }
        };
        let forced = if !all && n - count > self.max_lookahead {
            n - self.max_lookahead * 3 / 4
        } else {
            count
        };
        if forced > count {
            let span = self.blocks[0].span;
            let max = self.max_lookahead;
            self.windowed.hit(out, || {
                Diagnostic::warning(
                    "valve-lookahead::window",
                    format!("more than max_lookahead = {max} blocks fall within the valve delays here: older blocks are passed on and valve commands cannot go before them"),
                )
                .at_span(span)
                .with_help("raise max_lookahead")
            });
        }
        self.check(forced, out);
        let forced = forced.min(self.items.len());
        if forced == 0 {
            return;
        }
        // The window's new start: the time and planner state after the last item out
        // (the last stop or moving move among them decides the state).
        self.base_time = self.items[forced - 1].end();
        if let Some(it) = self
            .items
            .range(..forced)
            .rev()
            .find(|it| it.is_stop() || it.moving().is_some())
        {
            self.base_last = match &it.kind {
                Kind::Move(m) => Some((m.seg, it.speeds.1)),
                _ => None,
            };
        }
        debug_assert_eq!(self.items.len(), self.blocks.len());
        out.blocks.extend(self.blocks.drain(..forced));
        for it in self.items.drain(..forced) {
            if let Kind::Marker(id) = it.kind {
                self.events.remove(&id);
            }
            if let Kind::Move(b) = it.kind
                && self.spare.len() < SPARE_BOXES
            {
                self.spare.push(b);
            }
        }
    }

    /// Checks the commands among the first `count` items one last time before they
    /// leave.
    fn check(&mut self, count: usize, out: &mut Output<'_>) {
        self.ensure_timed();
        for (i, it) in self.items.iter().enumerate().take(count) {
            let Kind::Marker(id) = it.kind else { continue };
            let Some(ev) = self.events.get(&id) else {
                continue;
            };
            let Some((_, tt)) = self.target_of(ev) else {
                continue;
            };
            let error = (tt - self.items[i].start) - ev.delay;
            if (ev.open || !ev.clamped) && error.abs() > WARN_TOL {
                let span = ev.span;
                self.unsettled.hit(out, || {
                    Diagnostic::warning(
                        "valve-lookahead::off",
                        format!("this valve command comes {:.4} s before its extrusion event instead of {:.4} s", error + ev.delay, ev.delay),
                    )
                    .at_span(span)
                });
            }
        }
    }
}

impl ValveLookahead {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        let (kind, extruding) = self.classify(&block, out);
        self.push(block, kind, extruding, out);
    }
}

impl Pass for ValveLookahead {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        if self.in_run || self.close_pending {
            self.close_run(out);
        }
        self.release(true, out);
        for (tally, what) in [
            (
                &self.dwelled,
                "extrusion starts needed a dwell for the open delay",
            ),
            (&self.late, "close commands could not come early enough"),
            (
                &self.short_run,
                "extrusion runs were shorter than the valve delays allow",
            ),
            (
                &self.unsettled,
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
