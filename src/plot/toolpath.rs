//! The tool path seen from above (XY), as SVG: cuts solid, rapids and travel dashed, plunges as rings.
//!
//! [`ToolpathPlot`] is a [`Backend`] at the end of a pipeline, so it draws what the
//! controller will be sent, mapped back to where the tool tip goes:
//! - G-code and HPGL without kinematics: the program's X and Y (IR frame, G92 offsets not
//!   added), arcs along their circle;
//! - a preset with a `[machine]`: forward kinematics of the emitted joints, the tip in the
//!   part frame, with moves that turn a rotary sampled along the joint-linear path the
//!   controller interpolates (so a tip that leaves the programmed line shows it);
//! - a polar preset: `(r cos θ, r sin θ)` in the table frame, sampled along the
//!   joint-linear path in `(r, θ)`.
//!
//! A feed move cuts (or prints) unless it is travel: once the program has moved E, a
//! move prints when E grows (slicer G-code travels with G1 and no E); after a screw command
//! (`M3 S<rpm>`, `M5`: the `extrude-rate` output) it prints while the screw turns;
//! otherwise every feed move cuts. A plunge is a cutting move that lowers Z without
//! moving in XY.
//!
//! Memory is bounded: past [`MAX_POINTS`] vertices the runs are simplified
//! (Ramer–Douglas–Peucker in XY, starting at a quarter pixel of the drawing and coarser
//! as needed): the ends of every run, every corner and every plunge stay, so the picture
//! keeps its shape on long programs.

use std::fmt::Write;

use nalgebra::Point3;

use crate::back::Backend;
use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, Joints, MotionKind};
use crate::machine::Machine;
use crate::motion::arc::ArcPath;

/// At most about this many vertices are kept.
pub const MAX_POINTS: usize = 1 << 18;

/// Pieces a move that turns a rotary (or θ) is drawn with.
const JOINT_SAMPLES: usize = 16;

/// Below this (mm) an XY change is none: a plunge moves Z alone.
const SAME_XY: f64 = 1e-9;

/// How joints map to the tool tip.
#[derive(Debug, Clone)]
pub enum Frame {
    /// X, Y and Z are the tip (3-axis machines, printers, plotters).
    Cartesian,
    /// Forward kinematics of a two-rotary machine: the tip in the part frame.
    Machine(Box<Machine>),
    /// A polar machine: `r` and `θ` (degrees) joints, the tip in the table frame.
    Polar {
        /// The radial joint.
        r: Axis,
        /// The turntable joint, degrees.
        theta: Axis,
    },
}

impl Frame {
    /// The frame of a preset's output: its machine's kinematics, its polar joints, or
    /// plain X/Y/Z.
    pub fn for_preset(preset: &crate::preset::Preset) -> Frame {
        if let Some(m) = &preset.machine {
            return Frame::Machine(Box::new(m.clone()));
        }
        match super::polar_axes(preset) {
            Some((r, theta)) => Frame::Polar { r, theta },
            None => Frame::Cartesian,
        }
    }

    /// The tool tip at `j`, when every joint it needs is known.
    pub fn tip(&self, j: &Joints) -> Option<Point3<f64>> {
        match self {
            Frame::Cartesian => Some(Point3::new(
                j.get(Axis::X)?,
                j.get(Axis::Y)?,
                j.get(Axis::Z).unwrap_or(0.0),
            )),
            Frame::Machine(m) => {
                let [a, b] = m.rotary_axes();
                let xyz = [j.get(Axis::X)?, j.get(Axis::Y)?, j.get(Axis::Z)?];
                Some(m.forward(&xyz, [j.get(a)?, j.get(b)?]).tip)
            }
            Frame::Polar { r, theta } => {
                j.get(*r)?;
                j.get(*theta)?;
                Some(crate::motion::polar_point(j, *r, *theta))
            }
        }
    }

    /// Whether the tip moves on a straight line when the joints move linearly from `a`
    /// to `b`.
    fn straight(&self, a: &Joints, b: &Joints) -> bool {
        let same = |axis: Axis| a.get(axis) == b.get(axis);
        match self {
            Frame::Cartesian => true,
            Frame::Machine(m) => m.rotary_axes().into_iter().all(same),
            Frame::Polar { theta, .. } => same(*theta),
        }
    }

    fn label(&self) -> &'static str {
        match self {
            Frame::Cartesian => "program X/Y",
            Frame::Machine(_) => "part frame: forward kinematics of the emitted joints",
            Frame::Polar { .. } => "table frame: r cos θ, r sin θ of the emitted joints",
        }
    }
}

/// A run of vertices drawn one way.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    /// Rapids and travel (feed moves that neither cut nor print), dashed; otherwise
    /// cutting or printing moves, solid.
    pub travel: bool,
    /// Tip positions, mm: the start of the run, then the vertices along it.
    pub points: Vec<Point3<f64>>,
}

/// Records the tool tip's path and draws it from above.
///
/// ```
/// use ncpost::back::Backend;
/// use ncpost::front::gcode::{parse_str, Options};
/// use ncpost::plot::toolpath::{Frame, ToolpathPlot};
/// let program = parse_str("G0 X0 Y0 Z1\nG1 Z-0.1 F20\nG1 X10 F70\nG0 Z1\n", &Options::default()).unwrap();
/// let mut plot = ToolpathPlot::new(Frame::Cartesian);
/// let mut diags = Vec::new();
/// for b in &program.blocks {
///     plot.write_block(b, &mut diags).unwrap();
/// }
/// assert_eq!(plot.plunges().len(), 1);
/// assert!((plot.cut_length() - 11.1).abs() < 1e-12); // the plunge and the cut
/// assert!(plot.svg().contains("1 plunges"));
/// ```
#[derive(Debug, Clone)]
pub struct ToolpathPlot {
    frame: Frame,
    /// The joints before the next block (unknown axes absent).
    last: Joints,
    runs: Vec<Run>,
    plunges: Vec<Point3<f64>>,
    cut_length: f64,
    travel_length: f64,
    /// The screw speed the last screw command set, once one was seen.
    screw: Option<f64>,
    /// Some move has changed E: the program extrudes, and E tells printing from travel.
    extrudes: bool,
    points: usize,
    /// The XY tolerance the runs were last simplified with, mm (0 before any).
    eps: f64,
    /// A new run starts with the next move (the position was unknown, or the kind
    /// changed).
    broken: bool,
}

impl ToolpathPlot {
    /// An empty plot mapping joints to the tip through `frame`.
    pub fn new(frame: Frame) -> Self {
        ToolpathPlot {
            frame,
            last: Joints::default(),
            runs: Vec::new(),
            plunges: Vec::new(),
            cut_length: 0.0,
            travel_length: 0.0,
            screw: None,
            extrudes: false,
            points: 0,
            eps: 0.0,
            broken: true,
        }
    }

    /// The runs recorded so far.
    pub fn runs(&self) -> &[Run] {
        &self.runs
    }

    /// Where the tool went down: cutting moves that lower Z without moving in XY.
    pub fn plunges(&self) -> &[Point3<f64>] {
        &self.plunges
    }

    /// Length of the cutting (printing) moves' tip path, mm (sampled as drawn).
    pub fn cut_length(&self) -> f64 {
        self.cut_length
    }

    /// Length of the rapids' and travel moves' tip path, mm.
    pub fn travel_length(&self) -> f64 {
        self.travel_length
    }

    /// Whether a move from `from` to `to` is travel.
    fn is_travel(&self, from: &Joints, to: &Joints, kind: &MotionKind) -> bool {
        if matches!(kind, MotionKind::Rapid) {
            return true;
        }
        if let (true, Some(a), Some(b)) = (self.extrudes, from.get(Axis::E), to.get(Axis::E)) {
            return b <= a;
        }
        self.screw.is_some_and(|rpm| rpm <= 0.0)
    }

    /// Joint positions along a move from `from` to `to` (the end included, the start
    /// not).
    fn samples(&self, from: &Joints, to: &Joints, kind: &MotionKind) -> Vec<Joints> {
        if let MotionKind::Arc(arc) = kind
            && let Some(path) = ArcPath::new(from, to, arc)
        {
            // One piece per 5 degrees swept, at least 4.
            let n = ((path.sweep.abs().to_degrees() / 5.0).ceil() as usize).clamp(4, 4096);
            return (1..=n).map(|i| path.point(i as f64 / n as f64)).collect();
        }
        let n = if self.frame.straight(from, to) {
            1
        } else {
            JOINT_SAMPLES
        };
        (1..=n)
            .map(|i| {
                let t = i as f64 / n as f64;
                let mut j = *to;
                for axis in to.known.iter() {
                    if let (Some(a), Some(b)) = (from.get(axis), to.get(axis)) {
                        j.values[axis.index()] = if i == n { b } else { a + (b - a) * t };
                    }
                }
                j
            })
            .collect()
    }

    fn add(&mut self, from: &Joints, to: &Joints, kind: &MotionKind) {
        if let (Some(a), Some(b)) = (from.get(Axis::E), to.get(Axis::E))
            && a != b
        {
            self.extrudes = true;
        }
        let travel = self.is_travel(from, to, kind);
        let Some(start) = self.frame.tip(from) else {
            self.broken = true;
            return;
        };
        let tips: Vec<Point3<f64>> = self
            .samples(from, to, kind)
            .iter()
            .filter_map(|j| self.frame.tip(j))
            .collect();
        let Some(end) = tips.last().copied() else {
            self.broken = true;
            return;
        };
        if !travel
            && (end.x - start.x).hypot(end.y - start.y) <= SAME_XY
            && end.z < start.z
            && !matches!(kind, MotionKind::Arc(_))
        {
            self.plunges.push(end);
        }
        let mut length = 0.0;
        let mut prev = start;
        for p in &tips {
            length += (p - prev).norm();
            prev = *p;
        }
        if travel {
            self.travel_length += length;
        } else {
            self.cut_length += length;
        }
        let continues = !self.broken && self.runs.last().is_some_and(|r| r.travel == travel);
        if !continues {
            self.runs.push(Run {
                travel,
                points: vec![start],
            });
            self.points += 1;
        }
        self.broken = false;
        if let Some(run) = self.runs.last_mut() {
            self.points += tips.len();
            run.points.extend(tips);
        }
        if self.points > MAX_POINTS {
            self.thin();
        }
    }

    /// Simplifies every run (Ramer–Douglas–Peucker in XY) with a tolerance that starts at
    /// 1/4000 of the drawing's size (a quarter pixel at its 900 px) and doubles until at
    /// most half of [`MAX_POINTS`] are left: vertices that do not change the picture go,
    /// corners stay.
    fn thin(&mut self) {
        let Some(([x0, y0], [x1, y1])) = self.extent() else {
            return;
        };
        let span = (x1 - x0).max(y1 - y0);
        if span <= 0.0 {
            return;
        }
        // Never finer than the last time: those vertices are gone already.
        self.eps = self.eps.max(span / 4000.0);
        loop {
            self.points = 0;
            for run in &mut self.runs {
                simplify(&mut run.points, self.eps);
                self.points += run.points.len();
            }
            if self.points <= MAX_POINTS / 2 {
                break;
            }
            self.eps *= 2.0;
        }
    }

    /// The smallest and largest X and Y of the drawing, if it has a point.
    fn extent(&self) -> Option<([f64; 2], [f64; 2])> {
        let mut points = self
            .runs
            .iter()
            .flat_map(|r| r.points.iter())
            .chain(self.plunges.iter());
        let first = points.next()?;
        Some(
            points.fold(([first.x, first.y], [first.x, first.y]), |(lo, hi), p| {
                (
                    [lo[0].min(p.x), lo[1].min(p.y)],
                    [hi[0].max(p.x), hi[1].max(p.y)],
                )
            }),
        )
    }

    /// The SVG picture: the path from above, X to the right and Y up, to scale.
    pub fn svg(&self) -> String {
        const SIZE: f64 = 900.0;
        const MARGIN: f64 = 40.0;
        const FOOTER: f64 = 50.0;
        let ([x0, y0], [x1, y1]) = self.extent().unwrap_or(([0.0, 0.0], [1.0, 1.0]));
        let span = (x1 - x0).max(y1 - y0).max(1e-9);
        let scale = SIZE / span;
        let (w, h) = ((x1 - x0) * scale, (y1 - y0) * scale);
        let width = w + 2.0 * MARGIN;
        let height = h + 2.0 * MARGIN + FOOTER;
        let px = |p: &Point3<f64>| (MARGIN + (p.x - x0) * scale, MARGIN + (y1 - p.y) * scale);
        let mut s = String::new();
        let _ = writeln!(
            s,
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width:.0}\" height=\"{height:.0}\" \
             viewBox=\"0 0 {width:.0} {height:.0}\" font-family=\"sans-serif\" font-size=\"12\">"
        );
        let _ = writeln!(s, "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>");
        let _ = writeln!(
            s,
            "<rect x=\"{MARGIN}\" y=\"{MARGIN}\" width=\"{w:.1}\" height=\"{h:.1}\" fill=\"none\" stroke=\"#ddd\"/>"
        );
        for run in &self.runs {
            // What a quarter pixel cannot show is left out of the file.
            let mut points = run.points.clone();
            simplify(&mut points, 0.25 / scale);
            let mut pts = String::new();
            for (i, p) in points.iter().enumerate() {
                let (x, y) = px(p);
                let _ = write!(pts, "{}{x:.2},{y:.2}", if i == 0 { "" } else { " " });
            }
            let style = if run.travel {
                "stroke=\"#999\" stroke-width=\"0.6\" stroke-dasharray=\"4 3\""
            } else {
                "stroke=\"#1f5fbf\" stroke-width=\"1\""
            };
            let _ = writeln!(s, "<polyline fill=\"none\" {style} points=\"{pts}\"/>");
        }
        for p in &self.plunges {
            let (x, y) = px(p);
            let _ = writeln!(
                s,
                "<circle cx=\"{x:.2}\" cy=\"{y:.2}\" r=\"2.5\" fill=\"none\" stroke=\"#c0392b\"/>"
            );
        }
        let _ = writeln!(
            s,
            "<text x=\"{MARGIN}\" y=\"{:.1}\">X {x0:.3} .. {x1:.3} mm, Y {y0:.3} .. {y1:.3} mm ({})</text>",
            height - FOOTER + 5.0,
            self.frame.label()
        );
        let _ = writeln!(
            s,
            "<text x=\"{MARGIN}\" y=\"{:.1}\">cut {:.1} mm (solid), rapid and travel {:.1} mm (dashed), {} plunges (rings)</text>",
            height - FOOTER + 22.0,
            self.cut_length,
            self.travel_length,
            self.plunges.len()
        );
        s.push_str("</svg>\n");
        s
    }
}

impl Backend for ToolpathPlot {
    fn write_block(
        &mut self,
        block: &Block,
        _diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        match &block.kind {
            BlockKind::Motion(m) => {
                let (_, mut next) = super::joints_after(&self.last, block, m)?;
                if m.machine_frame {
                    // G53: the axes it names are unknown in the program frame afterwards.
                    next.forget(m.written);
                    self.broken = true;
                } else {
                    let from = self.last;
                    self.add(&from, &next, &m.kind);
                }
                self.last = next;
            }
            BlockKind::Command(c) => {
                if let Some(rpm) = super::screw_rpm(&c.text) {
                    self.screw = Some(rpm);
                }
                if !c.clobbers.is_empty() {
                    self.last.forget(c.clobbers);
                    self.broken = true;
                }
            }
            BlockKind::Verbatim(v) if !v.clobbers.is_empty() => {
                v.follow(&mut self.last);
                self.broken = true;
            }
            _ => {}
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<(), Diagnostic> {
        Ok(())
    }
}

/// Distance in XY from `p` to the segment `a`-`b`.
fn distance_to_segment(p: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    let (dx, dy) = (b.x - a.x, b.y - a.y);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p.x - a.x) * dx + (p.y - a.y) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p.x - (a.x + t * dx)).hypot(p.y - (a.y + t * dy))
}

/// Ramer–Douglas–Peucker: keeps the vertices without which the polyline would move by
/// more than `eps` in XY; the first and last always stay.
fn simplify(points: &mut Vec<Point3<f64>>, eps: f64) {
    let n = points.len();
    if n < 3 {
        return;
    }
    let mut keep = vec![false; n];
    keep[0] = true;
    keep[n - 1] = true;
    let mut stack = vec![(0usize, n - 1)];
    while let Some((a, b)) = stack.pop() {
        let mut worst = (0.0, 0usize);
        for i in a + 1..b {
            let d = distance_to_segment(&points[i], &points[a], &points[b]);
            if d > worst.0 {
                worst = (d, i);
            }
        }
        if worst.0 > eps {
            keep[worst.1] = true;
            stack.push((a, worst.1));
            stack.push((worst.1, b));
        }
    }
    let mut i = 0;
    points.retain(|_| {
        i += 1;
        keep[i - 1]
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simplify_keeps_corners_and_drops_collinear_points() {
        let p = |x: f64, y: f64| Point3::new(x, y, 0.0);
        let mut square: Vec<Point3<f64>> = (0..=40)
            .map(|i| {
                let t = i as f64 / 10.0;
                match i / 10 {
                    0 => p(t, 0.0),
                    1 => p(1.0, t - 1.0),
                    2 => p(3.0 - t, 1.0),
                    _ => p(0.0, 4.0 - t),
                }
            })
            .collect();
        simplify(&mut square, 1e-9);
        assert_eq!(
            square,
            vec![
                p(0.0, 0.0),
                p(1.0, 0.0),
                p(1.0, 1.0),
                p(0.0, 1.0),
                p(0.0, 0.0)
            ]
        );
        // A bump smaller than the tolerance goes, a larger one stays.
        let mut bump = vec![p(0.0, 0.0), p(1.0, 0.01), p(2.0, 0.0)];
        simplify(&mut bump, 0.02);
        assert_eq!(bump.len(), 2);
        let mut bump = vec![p(0.0, 0.0), p(1.0, 0.01), p(2.0, 0.0)];
        simplify(&mut bump, 0.005);
        assert_eq!(bump.len(), 3);
    }
}
