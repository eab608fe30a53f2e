//! Plots: the joint values of a compiled program over time, as SVG.
//!
//! [`JointPlot`] is a [`Backend`]: put it at the end of a pipeline and it records every
//! joint motion with the time the controller takes for it (the same model as `stats`:
//! the NIST feed rule, inverse time for G93 blocks, an assumed rapid speed), then
//! [`JointPlot::svg`] draws one panel per axis over a shared time axis.

use std::fmt::Write;

use crate::back::Backend;
use crate::diag::Diagnostic;
use crate::ir::{Axis, AxisSet, Block, BlockKind, FeedMode, Joints, MotionKind, Target};

/// Keeps at most about this many samples; beyond it every other sample is dropped, which
/// keeps memory bounded on long programs without changing the picture's shape much.
const MAX_SAMPLES: usize = 1 << 16;

/// Records joint positions over time and draws them.
///
/// ```
/// use ncpost::back::Backend;
/// use ncpost::front::gcode::{parse_str, Options};
/// use ncpost::plot::JointPlot;
/// let program = parse_str("G0 X0 A0\nG1 X10 A30 F600\n", &Options::default()).unwrap();
/// let mut plot = JointPlot::new(3000.0);
/// let mut diags = Vec::new();
/// for b in &program.blocks {
///     plot.write_block(b, &mut diags).unwrap();
/// }
/// let svg = plot.svg();
/// assert!(svg.starts_with("<svg") && svg.contains(">X (mm)<") && svg.contains(">A (deg)<"));
/// ```
#[derive(Debug, Clone)]
pub struct JointPlot {
    rapid_feed: f64,
    last: Joints,
    seconds: f64,
    /// (seconds, joints) at the end of each motion.
    samples: Vec<(f64, Joints)>,
    /// Keep one sample in `stride` (grows as samples are thinned).
    stride: u64,
    seen: u64,
    axes: AxisSet,
}

impl JointPlot {
    /// A plot assuming rapids at `rapid_feed` mm/min.
    pub fn new(rapid_feed: f64) -> Self {
        JointPlot {
            rapid_feed,
            last: Joints::default(),
            seconds: 0.0,
            samples: Vec::new(),
            stride: 1,
            seen: 0,
            axes: AxisSet::EMPTY,
        }
    }

    /// Total program time, seconds.
    pub fn seconds(&self) -> f64 {
        self.seconds
    }

    fn record(&mut self, joints: Joints) {
        self.seen += 1;
        if !self.seen.is_multiple_of(self.stride) {
            return;
        }
        self.samples.push((self.seconds, joints));
        if self.samples.len() >= MAX_SAMPLES {
            let mut keep = 0;
            for i in (0..self.samples.len()).step_by(2) {
                self.samples[keep] = self.samples[i];
                keep += 1;
            }
            self.samples.truncate(keep);
            self.stride *= 2;
        }
    }

    /// Minutes the controller takes from `from` to `to` at `feed`.
    fn minutes(from: &Joints, to: &Joints, mode: FeedMode, rate: f64) -> f64 {
        let delta = |axes: &[Axis]| -> f64 {
            axes.iter()
                .filter_map(|&a| Some(to.get(a)? - from.get(a)?))
                .map(|d| d * d)
                .sum::<f64>()
                .sqrt()
        };
        if mode == FeedMode::InverseTime {
            return if rate > 0.0 { 1.0 / rate } else { 0.0 };
        }
        let linear = delta(&[Axis::X, Axis::Y, Axis::Z]);
        let distance = if linear > 0.0 {
            linear
        } else {
            delta(&[Axis::A, Axis::B, Axis::C])
        };
        if rate > 0.0 { distance / rate } else { 0.0 }
    }

    /// The SVG picture: one panel per axis that moved, stacked, time on the horizontal axis.
    pub fn svg(&self) -> String {
        const WIDTH: f64 = 900.0;
        const PANEL: f64 = 140.0;
        const LEFT: f64 = 80.0;
        const TOP: f64 = 20.0;
        let axes: Vec<Axis> = [Axis::X, Axis::Y, Axis::Z, Axis::A, Axis::B, Axis::C]
            .into_iter()
            .filter(|a| self.axes.contains(*a))
            .collect();
        let height = TOP + PANEL * axes.len().max(1) as f64 + 40.0;
        let t_end = self.seconds.max(1e-9);
        let mut s = String::new();
        let _ = writeln!(
            s,
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{height:.0}\" \
             viewBox=\"0 0 {} {height:.0}\" font-family=\"sans-serif\" font-size=\"12\">",
            WIDTH + LEFT + 20.0,
            WIDTH + LEFT + 20.0
        );
        let _ = writeln!(s, "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>");
        for (row, &axis) in axes.iter().enumerate() {
            let y0 = TOP + PANEL * row as f64;
            let points: Vec<(f64, f64)> = self
                .samples
                .iter()
                .filter_map(|(t, j)| j.get(axis).map(|v| (*t, v)))
                .collect();
            let (lo, hi) = points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (_, v)| {
                    (lo.min(*v), hi.max(*v))
                });
            let (lo, hi) = if lo.is_finite() && hi > lo {
                (lo, hi)
            } else if lo.is_finite() {
                (lo - 1.0, lo + 1.0)
            } else {
                (-1.0, 1.0)
            };
            let h = PANEL - 30.0;
            let unit = if axis.is_rotary() { "deg" } else { "mm" };
            let _ = writeln!(
                s,
                "<rect x=\"{LEFT}\" y=\"{y0:.1}\" width=\"{WIDTH}\" height=\"{h:.1}\" fill=\"none\" stroke=\"#999\"/>"
            );
            let _ = writeln!(
                s,
                "<text x=\"5\" y=\"{:.1}\">{} ({unit})</text>",
                y0 + h / 2.0,
                axis.letter()
            );
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\" font-size=\"10\">{hi:.3}</text>\
                 <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\" font-size=\"10\">{lo:.3}</text>",
                LEFT - 4.0,
                y0 + 10.0,
                LEFT - 4.0,
                y0 + h
            );
            let mut path = String::new();
            for (i, (t, v)) in points.iter().enumerate() {
                let x = LEFT + WIDTH * t / t_end;
                let y = y0 + h - h * (v - lo) / (hi - lo);
                let _ = write!(path, "{}{x:.2},{y:.2}", if i == 0 { "" } else { " " });
            }
            let _ = writeln!(
                s,
                "<polyline fill=\"none\" stroke=\"#1f5fbf\" stroke-width=\"1\" points=\"{path}\"/>"
            );
        }
        let _ = writeln!(
            s,
            "<text x=\"{LEFT}\" y=\"{:.1}\">time 0 .. {:.1} s</text>",
            height - 12.0,
            self.seconds
        );
        s.push_str("</svg>\n");
        s
    }
}

impl Backend for JointPlot {
    fn write_block(
        &mut self,
        block: &Block,
        _diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        match &block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(j) = &m.target else {
                    return Err(Diagnostic::error(
                        "plot::pose",
                        "a tool pose reached the plot; run the `ik` pass first (use a preset with a machine)",
                    )
                    .at_span(block.span));
                };
                let rate = match m.kind {
                    MotionKind::Rapid => self.rapid_feed,
                    _ => m.feed.rate.unwrap_or(self.rapid_feed),
                };
                let mode = if m.kind == MotionKind::Rapid {
                    FeedMode::PerMinute
                } else {
                    m.feed.mode
                };
                self.seconds += 60.0 * Self::minutes(&self.last, j, mode, rate);
                let mut next = self.last;
                for a in j.known.iter() {
                    next.set(a, j.values[a.index()]);
                }
                self.axes = self.axes.union(j.known);
                self.last = next;
                self.record(next);
            }
            BlockKind::Dwell { seconds } => self.seconds += seconds.max(0.0),
            BlockKind::Command(c) => self.last.forget(c.clobbers),
            BlockKind::Verbatim(v) => self.last.forget(v.clobbers),
            _ => {}
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<(), Diagnostic> {
        Ok(())
    }
}
