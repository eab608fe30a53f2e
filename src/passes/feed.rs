//! `feed`: the F that makes the controller take the programmed time for each joint move.
//!
//! The programmed F of CL data is the tool-tip speed in the part frame (mm/min). The
//! controller does not know the tip: it reads F under its own rule over the joint deltas
//! (machine `controller.feed_rule`, or option `mode`):
//! - `nist` (RepRapFirmware, LinuxCNC G94; RS274NGC 2.1.2.5): F is the XYZ speed when any
//!   of X, Y, Z moves, otherwise the rotary speed in degrees per minute;
//! - `inverse-time` (G93): the move takes 1/F minutes;
//! - `euclidean`: F is the speed over all five joint deltas.
//!
//! For a move whose tip travels `L` at the programmed `F`, the time is `t = L / F` and the
//! emitted F is the rule's distance over `t`. Everything is computed from the numbers the
//! controller will read: each joint value rounded as the backend prints it (with the G92
//! offsets in force), both for `L` (forward kinematics of the rounded joints) and for the
//! controller's distance. The IR joint values themselves are left exact. A printed rotary
//! value is a whole number of units, so the sines and cosines of the kinematics come from
//! the tables of [`RotaryGrid`] rather than libm (which stays for values off the grid).
//!
//! A move that turns the tool about a fixed tip has no tip speed; it turns at
//! `reorient_feed` degrees per minute (over the two rotary deltas) instead.
//!
//! Warnings (each shown once with its place, then counted at the end): `feed::min-speed`
//! when the controller's speed for the block (in G93: the NIST distance over the block's
//! time) is below `controller.min_speed`, so the block would run faster than programmed; `feed::max-speed` when an axis would exceed
//! its `max_feed`, so the controller slows the block down; `feed::precision` when the
//! printed F is more than 0.1 % off. A cutting move without a feed rate is the error
//! `feed::missing`. Rapids, arcs, G53 moves, feeds not in mm/min and moves from or to a
//! position with an unknown machine axis pass unchanged.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::{Context, Output, Pass, PassInfo};
use crate::back::Decimals;
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, AxisSet, Block, BlockKind, FeedMode, Joints, MotionKind, Span, Target,
};
use crate::machine::grid::RotaryGrid;
use crate::machine::{FeedRule, Machine, Mount, RotaryLetter};
use crate::num::print::{from_units, to_units};

/// Options of `feed`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// How the controller reads F (`nist`, `inverse-time`, `euclidean`); default: the
    /// machine's `controller.feed_rule`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mode: Option<FeedRule>,
    /// Rotary speed of a pure reorientation (the tip stands still), degrees per minute.
    pub reorient_feed: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            mode: None,
            reorient_feed: 1000.0,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "feed",
    summary: "set each joint move's F (G94 under the controller's rule, or G93) so it takes the programmed tool-tip time",
    build: |t, ctx| {
        let machine = ctx.require_machine("feed")?;
        Ok(Box::new(Feed::new(
            machine.clone(),
            super::options(t)?,
            ctx,
        )?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// Below this tip travel (mm) a move is a pure reorientation.
const ZERO_TIP: f64 = 1e-6;

/// Largest relative error of a printed F.
const FEED_PRECISION: f64 = 1e-3;

/// From this many units of its decimals on, a printed F is within [`FEED_PRECISION`]
/// without a division to show it: rounding to a whole unit moves it by at most half a unit,
/// 5e-4 of it, and the floating-point steps of the check add a few ulps.
const SURE_UNITS: f64 = 1000.0;

/// The tip of a machine with both rotaries on the table, from the sines and cosines in
/// registers: [`Machine::tip_with`] takes its rotations and joints through memory, and the
/// narrow stores that build them, read back wide, stalled every read.
///
/// Each turn is written out about its coordinate axis: the products [`Machine::tip_with`]
/// makes with the matrix's zeros and ones only add signed zeros, so every value is equal
/// to its (a zero may differ in sign, which the tip's only use, the length of a
/// difference of tips, cannot see), the other products and sums being the same in the
/// same order.
#[derive(Debug, Clone, Copy)]
struct TableTable {
    about: [RotaryLetter; 2],
    pivots: [[f64; 3]; 2],
}

impl TableTable {
    fn new(machine: &Machine) -> Option<TableTable> {
        let [r0, r1] = [machine.rotary.first()?, machine.rotary.get(1)?];
        (r0.on == Mount::Table && r1.on == Mount::Table).then_some(TableTable {
            about: [r0.axis, r1.axis],
            pivots: [r0.pivot, r1.pivot],
        })
    }

    /// The tool tip at `xyz` with the rotaries' sines and cosines `sc` (listing order):
    /// undo the base rotary, then the one it carries.
    #[inline(always)]
    fn tip(&self, xyz: [f64; 3], sc: [(f64, f64); 2]) -> Point3<f64> {
        let [p0, p1] = self.pivots;
        let d = [xyz[0] - p0[0], xyz[1] - p0[1], xyz[2] - p0[2]];
        let t = self.about[0].turn_back(sc[0].0, sc[0].1, d);
        let q = [
            t[0] + p0[0] - p1[0],
            t[1] + p0[1] - p1[1],
            t[2] + p0[2] - p1[2],
        ];
        let u = self.about[1].turn_back(sc[1].0, sc[1].1, q);
        Point3::new(u[0] + p1[0], u[1] + p1[1], u[2] + p1[2])
    }
}

/// A warning shown once with its place and counted for the end of the run.
#[derive(Debug, Default)]
struct Counted {
    count: u64,
}

impl Counted {
    fn hit(&mut self, diags: &mut Vec<Diagnostic>, make: impl FnOnce() -> Diagnostic) {
        if self.count == 0 {
            diags.push(make());
        }
        self.count += 1;
    }
}

/// A position as the controller reads it.
#[derive(Debug, Clone, Copy)]
struct Read {
    /// The five machine axes in the program frame after printing (what the controller
    /// moves between).
    printed: [f64; 5],
    /// The tool tip of the printed position (part frame).
    tip: Point3<f64>,
}

/// The `feed` pass.
pub struct Feed {
    machine: Machine,
    rule: FeedRule,
    reorient_feed: f64,
    decimals: Option<Decimals>,
    axes: [Axis; 5],
    /// `axes` as a set, to check that a position knows all five at once.
    five: AxisSet,
    /// [`Axis::index`] of each of `axes`.
    index: [usize; 5],
    /// The printed decimals of each of `axes`, when the backend prints at all.
    places: Option<[u8; 5]>,
    /// The rotaries on the grid of their printed decimals, when the backend prints them
    /// with few enough for the tables.
    grid: Option<RotaryGrid>,
    /// The G92 offset of each rotary in whole units of the grid; `None` when it is not
    /// on the grid (the joint value then is not either, and libm turns it).
    offset_units: [Option<i64>; 2],
    /// Each of `axes`' `max_feed` (infinite when it has none) and the speed above which
    /// it warns (a little over it, so that a move at exactly the limit does not; infinite
    /// again, so that the test needs no branch on whether there is one).
    max_feed: [(f64, f64); 5],
    /// `10^decimals.feed`: a printed F is a whole number of `1 / feed_scale`.
    feed_scale: f64,
    /// Where the next move starts.
    prev: Joints,
    /// `prev` as read, when already computed under the offsets in force (between
    /// batches: within one, [`Feed::run_batch`] carries it in a local).
    prev_read: Option<Read>,
    /// Both rotaries on the table: the tip is worked out by [`TableTable::tip`].
    table_table: Option<TableTable>,
    /// A printed F of at least this many units is surely within [`FEED_PRECISION`]
    /// (infinite when the backend prints F with more decimals than [`to_units`] scales).
    sure_units: f64,
    /// The scale [`to_units`] takes F's units with, `10^min(decimals.feed, 9)`.
    units_scale: f64,
    offsets: [f64; AXIS_COUNT],
    /// The last rate emitted (for moves of zero length).
    last_rate: Option<f64>,
    missing: Counted,
    min_speed: Counted,
    max_speed: Counted,
    precision: Counted,
}

impl Feed {
    /// A `feed` pass for `machine`; `context.decimals` is the backend's precision.
    pub fn new(machine: Machine, options: Options, context: &Context<'_>) -> Result<Feed, String> {
        machine.check()?;
        if !(options.reorient_feed.is_finite() && options.reorient_feed > 0.0) {
            return Err("reorient_feed must be a positive number of degrees per minute".into());
        }
        let [r0, r1] = machine.rotary_axes();
        let axes = [Axis::X, Axis::Y, Axis::Z, r0, r1];
        let max_feed = axes.map(|a| match machine.controller.max_feed.get(a) {
            Some(max) => (max, max * (1.0 + 1e-9)),
            None => (f64::INFINITY, f64::INFINITY),
        });
        let table_table = TableTable::new(&machine);
        let mut feed = Feed {
            rule: options.mode.unwrap_or(machine.controller.feed_rule),
            grid: context
                .decimals
                .and_then(|d| RotaryGrid::new(&machine, d.rotary)),
            machine,
            reorient_feed: options.reorient_feed,
            decimals: context.decimals,
            places: context.decimals.map(|d| axes.map(|a| d.axis(a))),
            max_feed,
            feed_scale: context.decimals.map_or(1.0, |d| 10f64.powi(d.feed as i32)),
            axes,
            five: axes.into_iter().collect(),
            index: axes.map(Axis::index),
            offset_units: [None; 2],
            prev: Joints::default(),
            prev_read: None,
            table_table,
            sure_units: match context.decimals {
                Some(d) if d.feed <= 9 => SURE_UNITS,
                _ => f64::INFINITY,
            },
            units_scale: context
                .decimals
                .map_or(1.0, |d| 10f64.powi(i32::from(d.feed.min(9)))),
            offsets: [0.0; AXIS_COUNT],
            last_rate: None,
            missing: Counted::default(),
            min_speed: Counted::default(),
            max_speed: Counted::default(),
            precision: Counted::default(),
        };
        feed.set_offsets([0.0; AXIS_COUNT]);
        Ok(feed)
    }

    /// Puts `offsets` (the G92 offsets) in force.
    fn set_offsets(&mut self, offsets: [f64; AXIS_COUNT]) {
        self.offsets = offsets;
        self.offset_units = std::array::from_fn(|i| {
            let grid = self.grid.as_ref()?.grid();
            grid.units(offsets[self.index[3 + i]])
        });
    }

    /// The five axes of `j` as the controller reads them; `None` if one is unknown or
    /// cannot be printed.
    // Inlined always: returned through memory, the reading came back with wide loads
    // of what narrow stores had just written (a stall on every move).
    #[inline(always)]
    fn read(&self, j: &Joints) -> Option<Read> {
        if j.known.intersection(self.five) != self.five {
            return None;
        }
        let mut printed = [0.0; 5];
        let mut ir = [0.0; 5];
        // What each axis prints as, in units of its decimals.
        let mut units = [0; 5];
        for k in 0..5 {
            let i = self.index[k];
            let (v, off) = (j.values[i], self.offsets[i]);
            printed[k] = match self.places {
                Some(places) => {
                    units[k] = to_units(v + off, places[k])?;
                    from_units(units[k], places[k])
                }
                None => v + off,
            };
            ir[k] = printed[k] - off;
        }
        let sc = [
            self.sin_cos(0, ir[3], units[3]),
            self.sin_cos(1, ir[4], units[4]),
        ];
        // Only the tip: the tool axis would be computed and normalised for nothing.
        let xyz = [ir[0], ir[1], ir[2]];
        let tip = match &self.table_table {
            Some(tt) => tt.tip(xyz, sc),
            None => self.chain_tip(xyz, sc),
        };
        Some(Read { printed, tip })
    }

    /// [`Feed::read`]'s tip on a machine with a rotary on the head, by the machine's
    /// chains.
    #[inline(never)]
    fn chain_tip(&self, xyz: [f64; 3], sc: [(f64, f64); 2]) -> Point3<f64> {
        let rot = [
            self.machine.rotation_by(0, sc[0].0, sc[0].1),
            self.machine.rotation_by(1, sc[1].0, sc[1].1),
        ];
        self.machine.tip_with(&xyz, &rot)
    }

    /// [`Feed::read`] out of line, for the rare move whose start was not read before.
    #[inline(never)]
    fn read_start(&self) -> Option<Read> {
        self.read(&self.prev)
    }

    /// Sine and cosine of rotary `i`'s physical angle at joint value `deg`, printed as
    /// `units` (with the offset in force): from the grid's tables when the joint value
    /// lies on it.
    #[inline(always)]
    fn sin_cos(&self, i: usize, deg: f64, units: i64) -> (f64, f64) {
        if let (Some(grid), Some(offset)) = (&self.grid, self.offset_units[i])
            && let Some(sc) = grid.sin_cos(i, units - offset)
        {
            return sc;
        }
        self.libm_sin_cos(i, deg)
    }

    /// [`Feed::sin_cos`] off the grid (out of line: it is rare, and the libm call would
    /// make every read save its registers).
    #[cold]
    #[inline(never)]
    fn libm_sin_cos(&self, i: usize, deg: f64) -> (f64, f64) {
        self.machine.physical(i, deg).sin_cos()
    }

    /// The tool tip of the exact joint values `j`, which [`Feed::read`] could read.
    fn exact_tip(&self, j: &Joints) -> Point3<f64> {
        let v = self.index.map(|i| j.values[i]);
        let rot = self.machine.rotations([v[3], v[4]]);
        self.machine.tip_with(&[v[0], v[1], v[2]], &rot)
    }

    /// The new feed of a linear move from `prev` to `end` at programmed tip speed `rate`;
    /// `a` and `b` are `prev` and `end` as read (the exact joints are only needed when
    /// the printed tips are close, to tell a reorientation from a short move).
    // Inlined always, its warnings out of line: the readings stay in registers.
    #[inline(always)]
    fn feed_for(
        &mut self,
        span: Span,
        (a, b): (&Read, &Read),
        end: &Joints,
        rate: f64,
        diags: &mut Vec<Diagnostic>,
    ) -> (FeedMode, f64) {
        let mode = match self.rule {
            FeedRule::InverseTime => FeedMode::InverseTime,
            _ => FeedMode::PerMinute,
        };
        let delta: [f64; 5] = std::array::from_fn(|k| b.printed[k] - a.printed[k]);
        let dxyz = (delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]).sqrt();
        // Only a move without XYZ travel, a reorientation or the Euclidean rule needs it.
        let drot = || delta[3].hypot(delta[4]);
        // `hypot` is zero exactly when both rotary deltas are.
        if dxyz == 0.0 && delta[3] == 0.0 && delta[4] == 0.0 {
            // The controller skips a move that goes nowhere; any valid F will do.
            let f = self.last_rate.unwrap_or(rate);
            return (mode, f);
        }
        let length = (b.tip - a.tip).norm();
        // Rounding moves a tip by well under this, so a longer printed move is no
        // reorientation and the exact tips need not be computed.
        let exact = if length > 0.01 {
            length
        } else {
            self.exact_length(end)
        };
        let minutes = if exact.min(length) <= ZERO_TIP {
            drot() / self.reorient_feed
        } else {
            length / rate
        };
        // Rounding can leave a reorientation without rotary travel: the move is then a
        // few units of XYZ correction, run at the programmed speed.
        let minutes = if minutes > 0.0 { minutes } else { dxyz / rate };
        let nist = if dxyz > 0.0 { dxyz } else { drot() };
        // Divided once: the NIST speed is both F and the speed checked against the
        // minimum (the compiler divided twice).
        let nist_speed = nist / minutes;
        let mut f = match self.rule {
            FeedRule::Nist => nist_speed,
            FeedRule::InverseTime => 1.0 / minutes,
            FeedRule::Euclidean => dxyz.hypot(drot()) / minutes,
        };
        let speed = match self.rule {
            FeedRule::Euclidean => f,
            _ => nist_speed,
        };
        if speed < self.machine.controller.min_speed {
            self.warn_min_speed(span, speed, diags);
        }
        // Counted, not branched on: on the 1M-point benchmark two moves in three have an
        // axis over its max_feed, in no pattern a predictor learns, and each mispredicted
        // branch waited for the whole chain of the feed. (An axis without a max_feed has an
        // infinite limit, which no speed exceeds.)
        let v: [f64; 5] = std::array::from_fn(|k| delta[k].abs() / minutes);
        let over: u64 = (0..5).map(|k| u64::from(v[k] > self.max_feed[k].1)).sum();
        // `&`, not `&&`: one branch, taken once in a run.
        if (over > 0) & (self.max_speed.count == 0) {
            self.warn_max_speed(span, &v, diags);
        }
        self.max_speed.count += over;
        if let Some(d) = self.decimals
            && let Some(units) = to_units(f, d.feed)
        {
            // Enough units are within the precision (see SURE_UNITS): no division for the
            // printed value and its error on the path to the next move.
            // (`f` times the scale of `to_units` is finite, as `to_units` took it.)
            if f * self.units_scale < self.sure_units {
                f = self.check_precision(span, f, units, d.feed, diags);
            }
        }
        self.last_rate = Some(f);
        (mode, f)
    }

    /// The length between the tips of the exact joint values of `prev` and `end`.
    #[cold]
    #[inline(never)]
    fn exact_length(&self, end: &Joints) -> f64 {
        (self.exact_tip(end) - self.exact_tip(&self.prev)).norm()
    }

    /// The check of a printed F of `units` against `f`, which it may replace (F0 is no
    /// feed at all; the slowest printable one is the nearest).
    #[inline(never)]
    fn check_precision(
        &mut self,
        span: Span,
        f: f64,
        units: i64,
        places: u8,
        diags: &mut Vec<Diagnostic>,
    ) -> f64 {
        let scale = self.feed_scale;
        let printed = if units == 0 {
            1.0 / scale
        } else {
            units as f64 / scale
        };
        let error = (printed - f).abs() / f;
        if error > FEED_PRECISION {
            let wanted = f;
            self.precision.hit(diags, || {
                Diagnostic::warning(
                    "feed::precision",
                    format!(
                        "F {wanted:.6} prints as {printed} at {places} decimals, {:.2} % off: the move takes the wrong time",
                        100.0 * error
                    ),
                )
                .at_span(span)
                .with_help("print F with more decimals (the backend's `decimals.feed`)")
            });
        }
        if units == 0 { printed } else { f }
    }

    /// `feed::min-speed` for a move at `speed`.
    #[cold]
    #[inline(never)]
    fn warn_min_speed(&mut self, span: Span, speed: f64, diags: &mut Vec<Diagnostic>) {
        let min = self.machine.controller.min_speed;
        self.min_speed.hit(diags, || {
            Diagnostic::warning(
                "feed::min-speed",
                format!(
                    "this move needs {speed:.3}/min, below the controller's minimum speed of {min}: it will run faster than programmed"
                ),
            )
            .at_span(span)
            .with_help("lower the controller's minimum speed (RepRapFirmware: M203 I) and `controller.min_speed`, or raise the programmed feed")
        });
    }

    /// `feed::max-speed`, shown once, for the first of `axes` whose speed in `v` is over
    /// its max_feed.
    #[cold]
    #[inline(never)]
    fn warn_max_speed(&self, span: Span, v: &[f64; 5], diags: &mut Vec<Diagnostic>) {
        let Some(k) = (0..5).find(|&k| v[k] > self.max_feed[k].1) else {
            return;
        };
        let (axis, max, v) = (self.axes[k], self.max_feed[k].0, v[k]);
        diags.push(
            Diagnostic::warning(
                "feed::max-speed",
                format!(
                    "{} would move at {v:.1}/min, above its max_feed of {max}: the controller slows the move down, so it takes longer than programmed",
                    axis.letter()
                ),
            )
            .at_span(span)
            .with_help("lower the programmed feed here; near a singular orientation a short tip move needs a large rotary turn"),
        );
    }
}

impl Pass for Feed {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        // Every block keeps its place: only feeds change.
        let mut prev_read = self.prev_read;
        for block in blocks.iter_mut() {
            prev_read = self.step(block, prev_read, out.diags);
        }
        self.prev_read = prev_read;
        out.pass_on(blocks);
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        let summary = |c: &Counted, code: &'static str, what: &str| {
            (c.count > 1).then(|| Diagnostic::warning(code, format!("{} {what} in all", c.count)))
        };
        // The first missing feed is an error already; the count is for information.
        if self.missing.count > 1 {
            out.diag(Diagnostic::note(
                "feed::missing",
                format!(
                    "{} cutting moves in all have no feed rate",
                    self.missing.count
                ),
            ));
        }
        let notes = [
            summary(
                &self.min_speed,
                "feed::min-speed",
                "moves below the controller's minimum speed",
            ),
            summary(
                &self.max_speed,
                "feed::max-speed",
                "moves above an axis' max_feed",
            ),
            summary(
                &self.precision,
                "feed::precision",
                "feeds printed more than 0.1 % off",
            ),
        ];
        for d in notes.into_iter().flatten() {
            out.diag(d);
        }
    }
}

impl Feed {
    /// Sets the F of a cutting move in place and follows the position: the reading of the
    /// position before `block` passed in and the one after it returned.
    #[inline(always)]
    fn step(
        &mut self,
        block: &mut Block,
        prev_read: Option<Read>,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<Read> {
        let span = block.span;
        let mut next_read = None;
        match &mut block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(end) = &m.target else {
                    // A pose this late means the joints are not known.
                    self.prev = Joints::default();
                    return None;
                };
                if matches!(m.kind, MotionKind::Linear)
                    && !m.machine_frame
                    && m.feed.mode == FeedMode::PerMinute
                {
                    match m.feed.rate {
                        Some(rate) if rate.is_finite() && rate > 0.0 => {
                            let a = prev_read.or_else(|| self.read_start());
                            let b = self.read(end);
                            if let (Some(a), Some(b)) = (a, b) {
                                let (mode, f) = self.feed_for(span, (&a, &b), end, rate, diags);
                                m.feed.mode = mode;
                                m.feed.rate = Some(f);
                            }
                            // The next move starts here: read once.
                            next_read = b;
                        }
                        _ => self.warn_missing(span, diags),
                    }
                }
                self.prev = *end;
                if m.machine_frame {
                    self.prev.forget(m.written);
                    next_read = None;
                }
            }
            BlockKind::Offset(o) => {
                self.set_offsets(o.offsets);
                for a in o.declared.known.iter() {
                    if self.prev.get(a).is_none() {
                        self.prev
                            .set(a, o.declared.values[a.index()] - o.offsets[a.index()]);
                    }
                }
            }
            BlockKind::Command(c) => {
                self.prev.forget(c.clobbers);
                // A command that moves no axis leaves the reading as it is.
                if c.clobbers.is_empty() {
                    next_read = prev_read;
                }
            }
            BlockKind::Verbatim(v) => {
                self.prev.forget(v.clobbers);
                if v.clobbers.is_empty() {
                    next_read = prev_read;
                }
            }
            // Neither moves nor changes the frame.
            BlockKind::Dwell { .. } | BlockKind::Comment => next_read = prev_read,
        }
        next_read
    }

    /// `feed::missing` for a cutting move without a feed rate.
    #[cold]
    #[inline(never)]
    fn warn_missing(&mut self, span: Span, diags: &mut Vec<Diagnostic>) {
        self.missing.hit(diags, || {
            Diagnostic::error("feed::missing", "a cutting move without a feed rate")
                .at_span(span)
                .with_help("give FEDRAT (or F) before the first cutting move")
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::num::print::printed;
    use crate::preset::Preset;
    use proptest::prelude::*;

    const PRESETS: [&str; 4] = ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"];

    fn feed(preset: usize, zero_offsets: [f64; 2], rotary_decimals: u8) -> Feed {
        let mut m = Preset::builtin(PRESETS[preset])
            .and_then(|p| p.machine)
            .expect("a machine");
        for (r, z) in m.rotary.iter_mut().zip(zero_offsets) {
            r.zero_offset = z;
        }
        let decimals = Decimals {
            linear: 4,
            rotary: rotary_decimals,
            extruder: 5,
            feed: 2,
        };
        let ctx = Context {
            machine: Some(&m),
            decimals: Some(decimals),
            ..Context::default()
        };
        Feed::new(m.clone(), Options::default(), &ctx).expect("a feed pass")
    }

    /// The tip `read` should find: `Machine::forward` (libm) of the joints as printed,
    /// with the offsets taken off again, and the printed values.
    fn forward_of_printed(f: &Feed, j: &Joints) -> (Point3<f64>, [f64; 5]) {
        let places = f.places.expect("printed");
        let p: [f64; 5] = std::array::from_fn(|k| {
            let i = f.index[k];
            printed(j.values[i] + f.offsets[i], places[k]).expect("fits")
        });
        let v: [f64; 5] = std::array::from_fn(|k| p[k] - f.offsets[f.index[k]]);
        (f.machine.forward(&[v[0], v[1], v[2]], [v[3], v[4]]).tip, p)
    }

    fn joints(f: &Feed, v: [f64; 5]) -> Joints {
        let mut j = Joints::default();
        for (a, v) in f.axes.iter().zip(v) {
            j.set(*a, v);
        }
        j
    }

    /// An offset on the grid of four decimals, or (for `on_grid` false) most likely not.
    fn offset(v: f64, on_grid: bool) -> f64 {
        if on_grid { (v * 1e4).round() / 1e4 } else { v }
    }

    /// Reads `v` under `offsets` and checks it against [`forward_of_printed`] within
    /// `bound` mm; with `table` set, both rotaries must come from the tables.
    fn check_read(
        f: &mut Feed,
        v: [f64; 5],
        offsets: [f64; 5],
        table: bool,
        bound: f64,
    ) -> Result<(), TestCaseError> {
        let mut all = [0.0; AXIS_COUNT];
        for k in 0..5 {
            all[f.index[k]] = offsets[k];
        }
        f.set_offsets(all);
        let on_grid = f.offset_units.map(|u| f.grid.is_some() && u.is_some());
        prop_assert!(!table || on_grid == [true; 2]);
        let table = on_grid.contains(&true);
        let j = joints(f, v);
        let read = f.read(&j).expect("readable");
        let (tip, p) = forward_of_printed(f, &j);
        prop_assert_eq!(read.printed.map(f64::to_bits), p.map(f64::to_bits));
        let off = (read.tip - tip).norm();
        if table {
            prop_assert!(
                off <= bound,
                "{:e} mm off: {:?} against {:?}",
                off,
                read.tip,
                tip
            );
        } else {
            // Off the grid it is the same libm computation.
            prop_assert_eq!(
                read.tip.coords.map(f64::to_bits),
                tip.coords.map(f64::to_bits)
            );
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// The tips of the tables' sines and cosines are those of libm's to 1e-12 mm, on
        /// every layout, with G92 offsets and calibration offsets on the grid or off it.
        #[test]
        fn read_tips_are_forward_of_the_printed_joints(
            preset in 0..PRESETS.len(),
            xyz in proptest::array::uniform3(-100.0f64..100.0),
            angles in proptest::array::uniform2(-400.0f64..400.0),
            offsets in proptest::array::uniform5(-30.0f64..30.0),
            zero in proptest::array::uniform2(-5.0f64..5.0),
            (offsets_on_grid, zero_on_grid) in (proptest::bool::weighted(0.8), proptest::bool::ANY),
            decimals in 2u8..=5,
        ) {
            let zero = zero.map(|z| offset(z, zero_on_grid));
            let mut f = feed(preset, zero, decimals);
            let offsets = offsets.map(|o| offset(o, offsets_on_grid));
            let table = decimals == 4 && offsets_on_grid;
            let v = [xyz[0], xyz[1], xyz[2], angles[0], angles[1]];
            check_read(&mut f, v, offsets, table, 1e-12)?;
            // Without offsets, the grid is used whenever it can be.
            check_read(&mut f, v, [0.0; 5], decimals <= 4, 1e-12)?;
        }

        /// The written-out table-table tip is `Machine::tip_with`'s, value for value (a
        /// zero may differ in sign only), on quarter turns too, where sines and cosines
        /// are exactly zero.
        #[test]
        fn table_table_tip_is_tip_with(
            preset in 0..PRESETS.len(),
            xyz in proptest::array::uniform3(-300.0f64..300.0),
            angles in proptest::array::uniform2(-400.0f64..400.0),
            quarters in proptest::array::uniform2(-5i32..5),
            (on_quarters, zero_xyz) in (proptest::bool::ANY, proptest::bool::weighted(0.2)),
        ) {
            let f = feed(preset, [0.0; 2], 4);
            let Some(tt) = f.table_table else {
                return Ok(());
            };
            let angles = if on_quarters { quarters.map(|q| f64::from(q) * 90.0) } else { angles };
            let xyz = if zero_xyz { [0.0, -0.0, xyz[2]] } else { xyz };
            let sc = [0, 1].map(|i| f.machine.physical(i, angles[i]).sin_cos());
            let rot = [0, 1].map(|i| f.machine.rotation_by(i, sc[i].0, sc[i].1));
            let want = f.machine.tip_with(&xyz, &rot);
            let got = tt.tip(xyz, sc);
            prop_assert!(got == want, "{:?} against {:?}", got, want);
        }

        /// Many turns out (C = 49773.1203 degrees), libm's own argument is rounded by up to
        /// 2.2e-16 of the angle in radians, three times: that bounds the difference.
        #[test]
        fn read_tips_many_turns_out(
            preset in 0..PRESETS.len(),
            xyz in proptest::array::uniform3(-100.0f64..100.0),
            angles in proptest::array::uniform2(-60_000.0f64..60_000.0),
        ) {
            let mut f = feed(preset, [0.0; 2], 4);
            let v = [xyz[0], xyz[1], xyz[2], angles[0], angles[1]];
            let radians = (angles[0].abs() + angles[1].abs()).to_radians();
            // A generous 600 mm from the axes.
            let bound = 1e-12 + 600.0 * 3.0 * 2.3e-16 * radians;
            check_read(&mut f, v, [0.0; 5], true, bound)?;
        }
    }

    #[test]
    fn the_example_turn() {
        let mut f = feed(0, [0.0; 2], 4);
        let v = [12.5, -40.25, 7.0, 33.3333, 49773.1203];
        check_read(&mut f, v, [0.0; 5], true, 1e-10).unwrap();
        check_read(&mut f, v, [0.0, 0.0, 0.0, 0.5, -720.0], true, 1e-10).unwrap();
        // A on the grid, C off it.
        check_read(&mut f, v, [0.0, 0.0, 0.0, 0.5, 1e-7], false, 1e-10).unwrap();
        assert_eq!(f.offset_units, [Some(5000), None]);
    }
}
