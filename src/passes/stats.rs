//! `stats`: time (with the motion-time model), path lengths, extruded amount, bounding boxes and counts.
//!
//! The time comes from [`crate::motion`]: the controller of the preset's `[polar]` or
//! `[machine]` table (feed rule, `max_feed`, `acceleration`, `jerk`, `timing`), or the
//! default controller (NIST rule, no limits) without one; option `controller` replaces it. The run-wide `--timing` beats
//! the pass option `timing`, which beats the controller's. As a pass it reports at the end
//! as a note on standard error (first line `stats: ...`); `ncpost stats` prints
//! [`Stats::table`] on standard output instead ([`Stats`] is also a [`Backend`]).
//!
//! Lengths are XYZ lengths of the joint values as the IR holds them (arcs by their
//! helical length), or of the tool's Cartesian path on a polar machine
//! ([`Stats::with_polar`], which `ncpost stats` uses for `[polar]` presets); the extruded amount is the sum of the positive E steps, retraction
//! the sum of the negative ones. Bounding boxes are over the XYZ targets of all moves and
//! over the two ends of the moves that extrude; an arc adds the points where it bulges
//! furthest along its plane's axes (a full circle its whole square).

use serde::{Deserialize, Serialize};

use super::{Check, Context, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, Joints, MotionKind, Target, Tracker};
use crate::motion::arc::ArcPath;
use crate::motion::{self, Model, Planner, Timing};

/// Options of `stats`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Speed assumed for rapids, mm/min (capped by the axes' `max_feed`).
    pub rapid_feed: f64,
    /// Timing model (`constant-velocity`, `trapezoid`); default: the controller's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timing: Option<Timing>,
    /// The controller to time with (a `[controller]`-like table: `feed_rule`, `max_feed`,
    /// `acceleration`, `jerk`, `lookahead`, ...), for presets without a machine (a 3D
    /// printer's M203/M201/M566); default: the preset's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub controller: Option<crate::machine::Controller>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            rapid_feed: motion::DEFAULT_RAPID_FEED,
            timing: None,
            controller: None,
        }
    }
}

/// An axis-aligned box over X, Y, Z: per axis (min, max), `None` for an axis never known.
pub type Bounds = [Option<(f64, f64)>; 3];

/// Totals collected by `stats`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Totals {
    /// Blocks seen.
    pub blocks: u64,
    /// Rapid, linear and arc moves.
    pub moves: [u64; 3],
    /// Moves that extrude (E increases).
    pub extruding_moves: u64,
    /// Rapid length, mm (XYZ).
    pub rapid_mm: f64,
    /// Feed (G1/G2/G3) length, mm (XYZ).
    pub feed_mm: f64,
    /// XYZ length of the moves that extrude, mm.
    pub extruding_mm: f64,
    /// Sum of the positive E steps, mm of filament (or the slicer's E unit).
    pub extruded: f64,
    /// Sum of the negative E steps (retraction), as a positive number.
    pub retracted: f64,
    /// Program time under the model, seconds (moves and dwells).
    pub seconds: f64,
    /// Of which dwells, seconds.
    pub dwell_seconds: f64,
    /// Bounding box of all XYZ targets.
    pub bounds: Bounds,
    /// Bounding box of the moves that extrude.
    pub extruded_bounds: Bounds,
    /// Blocks passed through as text.
    pub verbatim: u64,
    /// Comments.
    pub comments: u64,
}

/// The `stats` pass.
pub struct Stats {
    planner: Planner<()>,
    track: Tracker,
    finished: bool,
    polar: Option<(Axis, Axis)>,
    /// What has been counted so far (`seconds` is complete after the end).
    pub totals: Totals,
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "stats",
    // The summary stays as `ncpost passes` has always listed it (tests/cli.rs snapshots it).
    summary: "report path lengths, a time estimate, the bounding box and block counts",
    build: |t, ctx| {
        Ok(Box::new(super::Lint(Stats::from_context(
            &super::options(t)?,
            ctx,
        ))))
    },
    defaults: || super::to_toml(&Options::default()),
};

fn grow(bounds: &mut Bounds, p: [Option<f64>; 3]) {
    for (b, v) in bounds.iter_mut().zip(p) {
        if let Some(v) = v {
            *b = Some(b.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))));
        }
    }
}

/// The points of an arc where it reaches furthest along its plane's axes, both ways: the
/// quarter-turn angles (0°, 90°, 180°, 270° from the centre) its sweep passes. Of each,
/// the first and the last pass are enough: the radius changes linearly along the arc, so
/// it is largest at one of them.
fn arc_extremes(path: &ArcPath) -> Vec<Joints> {
    let total = path.sweep.abs();
    if !(total.is_finite() && total > 0.0) {
        return Vec::new();
    }
    let tau = std::f64::consts::TAU;
    let dir = path.sweep.signum();
    let mut points = Vec::new();
    for q in 0..4 {
        let angle = f64::from(q) * std::f64::consts::FRAC_PI_2;
        // Angle travelled from the start to the first pass of this direction.
        let first = (dir * (angle - path.start_angle)).rem_euclid(tau);
        if first > total {
            continue;
        }
        let last = first + tau * ((total - first) / tau).floor();
        points.push(path.point(first / total));
        points.push(path.point(last / total));
    }
    points
}

fn bounds_text(b: &Bounds, sep: &str) -> Option<String> {
    if b.iter().all(Option::is_none) {
        return None;
    }
    let parts: Vec<String> = ["X", "Y", "Z"]
        .iter()
        .zip(b)
        .map(|(n, r)| match r {
            Some((lo, hi)) => format!("{n} {lo:.3}..{hi:.3}"),
            None => format!("{n} -"),
        })
        .collect();
    Some(parts.join(sep))
}

impl Stats {
    /// A `stats` pass with `options` and the default controller.
    pub fn new(options: Options) -> Self {
        Stats::from_context(&options, &Context::default())
    }

    /// A `stats` pass with `options`, timing with the context's controller.
    pub fn from_context(options: &Options, ctx: &Context<'_>) -> Self {
        let model = match &options.controller {
            Some(c) => {
                let timing = motion::resolve_timing(ctx.timing, options.timing, c.timing);
                Model::new(c).with_timing(timing)
            }
            None => Model::for_machines(
                ctx.polar,
                ctx.machine,
                ctx.flavour,
                ctx.timing,
                options.timing,
            ),
        }
        .with_rapid_feed(options.rapid_feed);
        Stats::with_model(model)
    }

    /// A `stats` pass timing with `model`.
    pub fn with_model(model: Model) -> Self {
        Stats {
            planner: Planner::new(model),
            track: Tracker::default(),
            finished: false,
            polar: None,
            totals: Totals::default(),
        }
    }

    /// Counts lengths and bounds on the tool's Cartesian path of a polar machine whose
    /// blocks carry r on `r_axis` and θ (degrees) on `theta_axis`: each move's length is
    /// the chord between its mapped ends (the `polar-ik` output is densified so the chords
    /// follow the path within its tolerance).
    pub fn with_polar(mut self, r_axis: Axis, theta_axis: Axis) -> Self {
        self.polar = Some((r_axis, theta_axis));
        self
    }

    /// The tool point of `j`: X, Y, Z as known (mapped from r, θ on a polar machine).
    fn point(&self, j: &Joints) -> [Option<f64>; 3] {
        match self.polar {
            Some((r, th)) if j.known.contains(r) && j.known.contains(th) => {
                let p = motion::polar_point(j, r, th);
                [Some(p.x), Some(p.y), j.get(Axis::Z)]
            }
            Some(_) => [None, None, j.get(Axis::Z)],
            None => [j.get(Axis::X), j.get(Axis::Y), j.get(Axis::Z)],
        }
    }

    /// The timing model in use.
    pub fn timing(&self) -> Timing {
        self.planner.model().timing
    }

    /// Counts one block (the pipeline's `stats` backend feeds it every block that
    /// reaches the end).
    pub fn count(&mut self, block: &Block) {
        let (from, to) = match &block.kind {
            BlockKind::Motion(m) => match &m.target {
                Target::Joints(end) => (self.point(self.track.pos()), self.point(end)),
                Target::Pose(_) => ([None; 3], [None; 3]),
            },
            _ => ([None; 3], [None; 3]),
        };
        let t = &mut self.totals;
        t.blocks += 1;
        t.comments += block.comments.len() as u64;
        match &block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(end) = &m.target else {
                    return;
                };
                let length = match m.kind {
                    MotionKind::Arc(arc) if self.polar.is_none() => {
                        motion::arc_length(self.track.pos(), end, &arc)
                    }
                    _ => {
                        let d: f64 = (0..3)
                            .filter_map(|k| Some((to[k]? - from[k]?).powi(2)))
                            .sum();
                        d.sqrt()
                    }
                };
                match m.kind {
                    MotionKind::Rapid => {
                        t.moves[0] += 1;
                        t.rapid_mm += length;
                    }
                    MotionKind::Linear => {
                        t.moves[1] += 1;
                        t.feed_mm += length;
                    }
                    MotionKind::Arc(_) => {
                        t.moves[2] += 1;
                        t.feed_mm += length;
                    }
                }
                let de = match (self.track.pos().get(Axis::E), end.get(Axis::E)) {
                    (Some(a), Some(b)) => b - a,
                    _ => 0.0,
                };
                if de > 0.0 {
                    t.extruded += de;
                    t.extruding_moves += 1;
                    t.extruding_mm += length;
                    grow(&mut t.extruded_bounds, from);
                    grow(&mut t.extruded_bounds, to);
                } else {
                    t.retracted -= de;
                }
                grow(&mut t.bounds, to);
                if let MotionKind::Arc(arc) = m.kind
                    && self.polar.is_none()
                    && let Some(path) = ArcPath::new(self.track.pos(), end, &arc)
                {
                    for p in arc_extremes(&path) {
                        let p = [p.get(Axis::X), p.get(Axis::Y), p.get(Axis::Z)];
                        grow(&mut t.bounds, p);
                        if de > 0.0 {
                            grow(&mut t.extruded_bounds, p);
                        }
                    }
                }
                if let Some(seg) = self.planner.model().motion(self.track.pos(), m) {
                    self.planner.push_move(seg, ());
                }
                self.track.motion(m);
            }
            BlockKind::Dwell { seconds } => {
                t.dwell_seconds += seconds.max(0.0);
                self.planner.push_stop(*seconds, ());
            }
            BlockKind::Verbatim(v) => {
                t.verbatim += 1;
                self.track.verbatim(v);
                self.planner.push_stop(0.0, ());
            }
            BlockKind::Command(c) if !c.clobbers.is_empty() => {
                self.track.forget(c.clobbers);
                self.planner.push_stop(0.0, ());
            }
            _ => {}
        }
        // Only the total time is needed: timed items are dropped as they are finished.
        while self.planner.pop().is_some() {}
    }

    /// Ends the program: plans the moves still queued and completes the time.
    pub fn end(&mut self) {
        if !self.finished {
            self.planner.finish();
            while self.planner.pop().is_some() {}
            self.finished = true;
        }
        self.totals.seconds = self.planner.time();
    }

    fn timing_name(&self) -> &'static str {
        match self.timing() {
            Timing::ConstantVelocity => "constant velocity",
            Timing::Trapezoid => "trapezoid",
        }
    }

    /// The report text (a note on standard error when run as a pass).
    pub fn report(&self) -> String {
        let t = &self.totals;
        let mut s = format!(
            "stats: {} blocks; moves: {} rapid, {} linear, {} arc; {} comments; {} passed through as text\n\
             path: {:.3} mm feed, {:.3} mm rapid; extruded {:.5} ({:.5} retracted); time {:.1} s ({})",
            t.blocks,
            t.moves[0],
            t.moves[1],
            t.moves[2],
            t.comments,
            t.verbatim,
            t.feed_mm,
            t.rapid_mm,
            t.extruded,
            t.retracted,
            t.seconds,
            self.timing_name(),
        );
        for (name, b) in [("bounds", t.bounds), ("extruded bounds", t.extruded_bounds)] {
            if let Some(text) = bounds_text(&b, ", ") {
                s.push_str(&format!("\n{name}: {text}"));
            }
        }
        s
    }

    /// The table `ncpost stats` prints.
    pub fn table(&self) -> String {
        let t = &self.totals;
        let hms = {
            let s = t.seconds.max(0.0).round() as u64;
            format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
        };
        let mut rows: Vec<(String, String)> = vec![
            (
                "time".into(),
                format!("{:.1} s ({hms}, {})", t.seconds, self.timing_name()),
            ),
            ("dwell".into(), format!("{:.1} s", t.dwell_seconds)),
            ("feed length".into(), format!("{:.3} mm", t.feed_mm)),
            ("rapid length".into(), format!("{:.3} mm", t.rapid_mm)),
            (
                "extruding length".into(),
                format!("{:.3} mm in {} moves", t.extruding_mm, t.extruding_moves),
            ),
            ("extruded".into(), format!("{:.5}", t.extruded)),
            ("retracted".into(), format!("{:.5}", t.retracted)),
            (
                "net extruded".into(),
                format!("{:.5}", t.extruded - t.retracted),
            ),
        ];
        for (name, b) in [("bounds", t.bounds), ("extruded bounds", t.extruded_bounds)] {
            let v = bounds_text(&b, "  ").unwrap_or_else(|| "-".into());
            rows.push((name.into(), v));
        }
        rows.push(("blocks".into(), t.blocks.to_string()));
        rows.push((
            "moves".into(),
            format!(
                "{} rapid, {} linear, {} arc",
                t.moves[0], t.moves[1], t.moves[2]
            ),
        ));
        rows.push(("comments".into(), t.comments.to_string()));
        rows.push(("passed as text".into(), t.verbatim.to_string()));
        let mut s = String::new();
        for (k, v) in rows {
            s.push_str(&format!("{k:<17} {v}\n"));
        }
        s
    }
}

impl Check for Stats {
    fn check(&mut self, blocks: &[Block], _diags: &mut Vec<Diagnostic>) {
        for block in blocks {
            self.count(block);
        }
    }

    fn finish(&mut self, diags: &mut Vec<Diagnostic>) {
        self.end();
        diags.push(Diagnostic::note("stats::report", self.report()));
    }
}
