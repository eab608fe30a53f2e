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
//! controller's distance. The IR joint values themselves are left exact (but for X, Y, Z
//! held below). A printed rotary value is a whole number of units, so the sines and
//! cosines of the kinematics come from the tables of [`RotaryGrid`] rather than libm
//! (which stays for values off the grid).
//!
//! A move that turns the tool about a fixed tip has no tip speed; it turns at
//! `reorient_feed` degrees per minute (over the two rotary deltas) instead.
//!
//! **X, Y, Z that move only by print rounding.** Where a rotary turns and X, Y, Z stay
//! within `hold_units` print units (default 2) of where they were last printed (a C-table
//! circle, a hemisphere's ring: the tip stands still in the machine frame, and CL data
//! rounded to 4 decimals or the print rounding make it jitter by 0.0001 mm), X, Y, Z are
//! held where they were printed: under the NIST rule F then applies to the rotary
//! distance. Printed as they come, a 0.0001 mm step would carry the whole time, with an F
//! such as 0.0628 mm/min far below any controller's minimum speed, so the controller would
//! run the block many times too fast. Holding moves the tip by at most `hold_units` print
//! units per axis.
//!
//! F is printed with the decimals that keep it within 0.1 % (the backend's
//! `decimals.feed` at least, more for a slow F: `num::print::Decimals::feed_decimals`).
//!
//! Warnings (each shown once with its place, then counted at the end): `feed::min-speed`
//! when the controller's speed for the block (in G93: the NIST distance over the block's
//! time) is still below `controller.min_speed`, so the block runs faster than programmed
//! (the message says how much; the help names where the firmware's minimum is set,
//! `machine::Flavour::min_speed_setting`); `feed::max-speed` when an axis would exceed
//! its `max_feed`, so the controller slows the block down; `feed::precision` when the
//! printed F is more than 0.1 % off. A cutting move without a feed rate is the error
//! `feed::missing`. Rapids, arcs, G53 moves, feeds not in mm/min and moves from or to a
//! position with an unknown machine axis pass unchanged.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::{Context, Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, AxisSet, Block, BlockKind, FeedMode, Joints, MotionKind, Span, Target,
    Tracker,
};
use crate::machine::grid::RotaryGrid;
use crate::machine::{FeedRule, Machine, Turns};
use crate::num::print::{
    Decimals, FEED_MAX_DECIMALS, FEED_RESOLUTION, from_units, printed, to_units,
};

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
    /// X, Y, Z within this many print units of where they were last printed are held
    /// there while a rotary turns (0: never), so that F applies to the rotary distance.
    pub hold_units: u32,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            mode: None,
            reorient_feed: 1000.0,
            hold_units: 2,
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
    hold_units: u32,
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
    /// Each of `axes`' `max_feed` and the speed above which it warns (a little over it, so
    /// that a move at exactly the limit does not); both infinite for an axis without one,
    /// which no speed exceeds.
    max_feed: [(f64, f64); 5],
    /// Where the next move starts.
    prev: Joints,
    /// `prev` as read, when already computed under the offsets in force.
    prev_read: Option<Read>,
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
    pub fn new(
        machine: Machine,
        options: Options,
        context: &Context<'_>,
    ) -> Result<Feed, Diagnostic> {
        machine.check()?;
        if !(options.reorient_feed.is_finite() && options.reorient_feed > 0.0) {
            return Err(Diagnostic::settings(
                "reorient_feed must be a positive number of degrees per minute",
            ));
        }
        let [r0, r1] = machine.rotary_axes();
        let axes = [Axis::X, Axis::Y, Axis::Z, r0, r1];
        let max_feed = axes.map(|a| match machine.controller.max_feed.get(a) {
            Some(max) => (max, max * (1.0 + 1e-9)),
            None => (f64::INFINITY, f64::INFINITY),
        });
        let mut feed = Feed {
            rule: options.mode.unwrap_or(machine.controller.feed_rule),
            grid: context
                .decimals
                .and_then(|d| RotaryGrid::new(&machine, d.rotary)),
            machine,
            reorient_feed: options.reorient_feed,
            hold_units: options.hold_units,
            decimals: context.decimals,
            places: context.decimals.map(|d| axes.map(|a| d.axis(a))),
            max_feed,
            axes,
            five: axes.into_iter().collect(),
            index: axes.map(Axis::index),
            offset_units: [None; 2],
            prev: Joints::default(),
            prev_read: None,
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
        // Only the tip: the tool axis does not enter the time.
        let tip = self.machine.tip_at([ir[0], ir[1], ir[2]], &sc);
        Some(Read { printed, tip })
    }

    /// Sine and cosine of rotary `i`'s physical angle at joint value `deg`, printed as
    /// `units` (with the offset in force): from the grid's tables when the joint value
    /// lies on it, so that the controller's printed angle is turned exactly.
    fn sin_cos(&self, i: usize, deg: f64, units: i64) -> (f64, f64) {
        if let (Some(grid), Some(offset)) = (&self.grid, self.offset_units[i])
            && let Some(sc) = grid.sin_cos(i, units - offset)
        {
            return sc;
        }
        self.machine.physical(i, deg).sin_cos()
    }

    /// The tool tip of the exact joint values `j`, which [`Feed::read`] could read.
    fn exact_tip(&self, j: &Joints) -> Point3<f64> {
        let v = self.index.map(|i| j.values[i]);
        let turns: Turns = self.machine.turns([v[3], v[4]]);
        self.machine.tip_at([v[0], v[1], v[2]], &turns)
    }

    /// The new feed of a linear move from `prev` to `end` at programmed tip speed `rate`;
    /// `a` and `b` are `prev` and `end` as read (the exact joints are only needed when
    /// the printed tips are close, to tell a reorientation from a short move).
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
        // The NIST speed is both F and the speed checked against the minimum.
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
        if speed < self.machine.controller.min_speed() {
            self.warn_min_speed(span, speed, diags);
        }
        // Every axis over its max_feed counts; the first such move is shown.
        let v: [f64; 5] = std::array::from_fn(|k| delta[k].abs() / minutes);
        let over = (0..5).filter(|&k| v[k] > self.max_feed[k].1).count() as u64;
        if over > 0 {
            if self.max_speed.count == 0 {
                self.warn_max_speed(span, &v, diags);
            }
            self.max_speed.count += over;
        }
        if let Some(d) = self.decimals {
            let places = d.feed_decimals(f);
            if let Some(units) = to_units(f, places) {
                f = self.check_precision(span, f, units, places, diags);
            }
        }
        self.last_rate = Some(f);
        (mode, f)
    }

    /// The length between the tips of the exact joint values of `prev` and `end`.
    fn exact_length(&self, end: &Joints) -> f64 {
        (self.exact_tip(end) - self.exact_tip(&self.prev)).norm()
    }

    /// The check of a printed F of `units` against `f`, which it may replace (F0 is no
    /// feed at all; the slowest printable one is the nearest).
    fn check_precision(
        &mut self,
        span: Span,
        f: f64,
        units: i64,
        places: u8,
        diags: &mut Vec<Diagnostic>,
    ) -> f64 {
        let printed = from_units(units.max(1), places);
        let error = (printed - f).abs() / f;
        if error > FEED_RESOLUTION {
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
                .with_help(format!("this F is too slow for the most decimals an F is printed with ({FEED_MAX_DECIMALS}): raise the programmed feed, or use inverse time (`mode = \"inverse-time\"`) where the controller has G93"))
            });
        }
        if units == 0 { printed } else { f }
    }

    /// `feed::min-speed` for a move at `speed`.
    fn warn_min_speed(&mut self, span: Span, speed: f64, diags: &mut Vec<Diagnostic>) {
        let min = self.machine.controller.min_speed();
        let setting = self.machine.controller.min_speed_setting();
        self.min_speed.hit(diags, || {
            Diagnostic::warning(
                "feed::min-speed",
                format!(
                    "this move needs {speed:.4}/min, below the controller's minimum speed of {min}: the controller runs it at {min}, in {:.1} % of the programmed time",
                    100.0 * speed / min
                ),
            )
            .at_span(span)
            .with_help(format!("lower the controller's minimum speed ({setting}) and `controller.min_speed` to {:.4} or less, or raise the programmed feed", speed))
        });
    }

    /// `feed::max-speed`, shown once, for the first of `axes` whose speed in `v` is over
    /// its max_feed.
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
                let Target::Joints(end) = &mut m.target else {
                    // A pose this late: the axes it writes are not known.
                    self.follow(|t| t.motion(m));
                    return None;
                };
                if matches!(m.kind, MotionKind::Linear)
                    && !m.machine_frame
                    && m.feed.mode == FeedMode::PerMinute
                {
                    match m.feed.rate {
                        Some(rate) if rate.is_finite() && rate > 0.0 => {
                            let a = prev_read.or_else(|| self.read(&self.prev));
                            // The exact end tells a reorientation from a short move.
                            let exact = *end;
                            if let Some(a) = &a {
                                self.hold(a, end);
                            }
                            let b = self.read(end);
                            if let (Some(a), Some(b)) = (a, b) {
                                let (mode, f) = self.feed_for(span, (&a, &b), &exact, rate, diags);
                                m.feed.mode = mode;
                                m.feed.rate = Some(f);
                            }
                            // The next move starts here: read once.
                            next_read = b;
                        }
                        _ => self.warn_missing(span, diags),
                    }
                }
                self.follow(|t| t.motion(m));
                if m.machine_frame {
                    next_read = None;
                }
            }
            BlockKind::Offset(o) => {
                self.set_offsets(o.offsets);
                self.follow(|t| {
                    t.offset(o);
                });
            }
            BlockKind::Command(c) => {
                self.follow(|t| t.forget(c.clobbers));
                // A command that moves no axis leaves the reading as it is.
                if c.clobbers.is_empty() {
                    next_read = prev_read;
                }
            }
            BlockKind::Verbatim(v) => {
                self.follow(|t| t.forget(v.clobbers));
                if v.clobbers.is_empty() {
                    next_read = prev_read;
                }
            }
            // Neither moves nor changes the frame.
            BlockKind::Dwell { .. } | BlockKind::Comment => next_read = prev_read,
        }
        next_read
    }

    /// Moves the position the next move starts from as the IR's one position tracker
    /// ([`Tracker`]) says `change` does.
    fn follow(&mut self, change: impl FnOnce(&mut Tracker)) {
        let mut tracker = Tracker::at(self.prev);
        change(&mut tracker);
        self.prev = *tracker.pos();
    }

    /// Holds X, Y and Z of `end` where `a` (the start as printed) has them, when a rotary
    /// turns and each lies within `hold_units` print units of there: they would move only
    /// by rounding, and the NIST rule would give that step the whole time.
    fn hold(&self, a: &Read, end: &mut Joints) {
        let Some(places) = self.places.filter(|_| self.hold_units > 0) else {
            return;
        };
        if end.known.intersection(self.five) != self.five {
            return;
        }
        let moved = |k: usize, v: f64| printed(v + self.offsets[self.index[k]], places[k]);
        let turns = (3..5).any(|k| moved(k, end.values[self.index[k]]) != Some(a.printed[k]));
        let near = (0..3).all(|k| {
            let v = end.values[self.index[k]] + self.offsets[self.index[k]];
            (v - a.printed[k]).abs() <= f64::from(self.hold_units) * from_units(1, places[k])
        });
        if turns && near {
            for k in 0..3 {
                let i = self.index[k];
                if moved(k, end.values[i]) != Some(a.printed[k]) {
                    end.values[i] = a.printed[k] - self.offsets[i];
                }
            }
        }
    }

    /// `feed::missing` for a cutting move without a feed rate.
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
    use proptest::prelude::*;

    const PRESETS: [&str; 4] = ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"];

    fn feed(preset: usize, zero_offsets: [f64; 2], rotary_decimals: u8) -> Feed {
        let mut m = crate::machine::builtin(PRESETS[preset]);
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

    /// X, Y, Z within two print units of where they were printed are held there while a
    /// rotary turns; further off, or without a turn, they are left exact.
    #[test]
    fn hold_keeps_xyz_that_move_only_by_rounding() {
        let f = feed(0, [0.0; 2], 4);
        let a = f
            .read(&joints(&f, [10.0, -17.3648, 31.5192, 10.0, 90.0]))
            .expect("readable");
        let held = |y: f64, c: f64| {
            let mut end = joints(&f, [10.0, y, 31.5192, 10.0, c]);
            f.hold(&a, &mut end);
            end.get(Axis::Y)
        };
        assert_eq!(held(-17.36489, 95.0), Some(-17.3648));
        assert_eq!(held(-17.36499, 95.0), Some(-17.3648));
        assert_eq!(held(-17.3651, 95.0), Some(-17.3651));
        assert_eq!(held(-17.36489, 90.0), Some(-17.36489));
        let mut off = feed(0, [0.0; 2], 4);
        off.hold_units = 0;
        let mut end = joints(&off, [10.0, -17.36489, 31.5192, 10.0, 95.0]);
        off.hold(&a, &mut end);
        assert_eq!(end.get(Axis::Y), Some(-17.36489));
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
