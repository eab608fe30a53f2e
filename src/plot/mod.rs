//! Plots of a compiled program as SVG: joint values ([`JointPlot`]) and speeds ([`SpeedPlot`]) over time, and the tool path ([`toolpath::ToolpathPlot`]).
//!
//! Both are [`Backend`]s: put one at the end of a pipeline. [`JointPlot`] records every
//! joint motion with a constant-velocity time (the NIST feed rule, inverse time for G93
//! blocks, an assumed rapid speed) and [`JointPlot::svg`] draws one panel per axis over a
//! shared time axis. [`SpeedPlot`] times the program with the motion-time model
//! ([`crate::motion`]) and draws the tool's linear speed, the axes' speeds and the screw
//! speed.

pub mod toolpath;

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
            let unit = if axis.is_rotary() { "deg" } else { "mm" };
            let label = format!("{} ({unit})", axis.letter());
            let frame = Panel {
                left: LEFT,
                width: WIDTH,
                y0,
                h: PANEL - 30.0,
            };
            frame.draw(&mut s, &label, (lo, hi), &points, t_end);
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
                let (j, next) = joints_after(&self.last, block, m)?;
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
                self.axes = self.axes.union(j.known);
                self.last = next;
                self.record(next);
            }
            BlockKind::Dwell { seconds } => self.seconds += seconds.max(0.0),
            BlockKind::Command(c) => self.last.forget(c.clobbers),
            BlockKind::Verbatim(v) => v.follow(&mut self.last),
            _ => {}
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<(), Diagnostic> {
        Ok(())
    }
}

/// A motion's joint target and the position after it (`last` with the target's known
/// axes set); a tool pose (CL input without `ik`) is the error `plot::pose`.
fn joints_after<'b>(
    last: &Joints,
    block: &Block,
    m: &'b crate::ir::Motion,
) -> Result<(&'b Joints, Joints), Diagnostic> {
    let Target::Joints(j) = &m.target else {
        return Err(Diagnostic::error(
            "plot::pose",
            "a tool pose reached the plot; run the `ik` pass first (use a preset with a machine)",
        )
        .at_span(block.span));
    };
    let mut next = *last;
    for a in j.known.iter() {
        next.set(a, j.values[a.index()]);
    }
    Ok((j, next))
}

/// The (r, θ) axes of a preset's output when its blocks end up in polar joints: the
/// preset has a `[polar]` table and no `polar-ik` pass with `kinematics = "controller"`
/// (which keeps XY for firmware that does the polar kinematics itself).
pub fn polar_axes(preset: &crate::preset::Preset) -> Option<(Axis, Axis)> {
    let polar = preset.polar.as_ref()?;
    let keeps_xy = preset.passes.iter().any(|p| {
        p.name == "polar-ik"
            && p.options.get("kinematics").and_then(|v| v.as_str()) == Some("controller")
    });
    (!keeps_xy).then_some((polar.r_axis, polar.theta_axis))
}

/// What a timed item of the speed plot stands for.
#[derive(Debug, Clone, Copy)]
enum Item {
    Move(Joints, Joints),
    Rpm(f64),
    Other,
}

/// One sample of [`SpeedPlot`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedSample {
    /// Seconds from the program start.
    pub t: f64,
    /// The tool's linear speed, mm/s (for a polar machine the Cartesian speed of the tip).
    pub v: f64,
    /// Each axis' speed, mm/s or deg/s, by [`Axis::index`].
    pub axes: [f64; crate::ir::AXIS_COUNT],
    /// The screw speed in force (`M3 S`/`M4 S`, 0 after `M5`), rev/min.
    pub rpm: f64,
}

/// The screw speed a command sets: `M3 S<rpm>`/`M4 S<rpm>` (the rate the `extrude-rate`
/// pass emits), `M5` stops it.
fn screw_rpm(text: &str) -> Option<f64> {
    let mut m = None;
    let mut speed = None;
    for w in text.split_whitespace() {
        let (letter, value) = w.split_at(w.chars().next().map_or(0, char::len_utf8));
        let value = value.parse::<f64>().ok().filter(|v| v.is_finite());
        match (letter, value) {
            ("M" | "m", Some(v)) if [3.0, 4.0, 5.0].contains(&v) => m = Some(v),
            ("S" | "s", Some(v)) => speed = Some(v),
            _ => {}
        }
    }
    match m? {
        5.0 => Some(0.0),
        _ => speed,
    }
}

/// The tool's linear speed over time under the motion-time model ([`crate::motion`]),
/// as SVG: tool speed, each moving axis' speed and, when the program sets one, the screw
/// speed.
///
/// With a polar machine (`polar = Some((r_axis, theta_axis))`) the tool speed is the
/// Cartesian speed of the tip, `v = sqrt(ṙ² + r² θ̇²)`, sampled inside every phase of every
/// block: under the trapezoid model ṙ and θ̇ are trapezoids (they are the joint speeds)
/// while v is not, which is the seed's appendix figure (seed 002, Figure 2).
///
/// ```
/// use ncpost::back::Backend;
/// use ncpost::front::gcode::{parse_str, Options};
/// use ncpost::machine::{Controller, PerAxis};
/// use ncpost::motion::{Model, Timing};
/// use ncpost::plot::SpeedPlot;
/// let mut c = Controller::default();
/// c.acceleration = PerAxis { x: Some(200.0), y: Some(200.0), ..PerAxis::default() };
/// let model = Model::new(&c).with_timing(Timing::Trapezoid);
/// let program = parse_str("G0 X0 Y0\nG1 X30 Y40 F3000\n", &Options::default()).unwrap();
/// let mut plot = SpeedPlot::new(model, None);
/// let mut diags = Vec::new();
/// for b in &program.blocks {
///     plot.write_block(b, &mut diags).unwrap();
/// }
/// plot.finish().unwrap();
/// let top = plot.samples().iter().map(|s| s.v).fold(0.0, f64::max);
/// assert!((top - 50.0).abs() < 1e-9); // 3000 mm/min
/// assert!(plot.svg().contains(">v (mm/s)<"));
/// ```
pub struct SpeedPlot {
    planner: crate::motion::Planner<Item>,
    polar: Option<(Axis, Axis)>,
    last: Joints,
    rpm: f64,
    has_rpm: bool,
    samples: Vec<SpeedSample>,
    stride: u64,
    seen: u64,
    axes: AxisSet,
    /// Points sampled inside each phase of a polar move.
    per_phase: usize,
    /// Screw speed templates besides `M3`/`M4`/`M5`: the text before and after `{rpm}`.
    screw_templates: Vec<(String, String)>,
    /// Commands that stop the screw besides `M5`.
    stop_commands: Vec<String>,
}

impl SpeedPlot {
    /// A speed plot timing with `model`; `polar` names the (r, θ) axes of a polar machine.
    pub fn new(model: crate::motion::Model, polar: Option<(Axis, Axis)>) -> Self {
        SpeedPlot {
            planner: crate::motion::Planner::new(model),
            polar,
            last: Joints::default(),
            rpm: 0.0,
            has_rpm: false,
            samples: Vec::new(),
            stride: 1,
            seen: 0,
            axes: AxisSet::EMPTY,
            per_phase: 16,
            screw_templates: Vec::new(),
            stop_commands: Vec::new(),
        }
    }

    /// Also reads screw speeds from commands written with `template` (`{rpm}` marks the
    /// number, as in the `extrude-rate` pass's `command`), and `stop` as a screw stop.
    ///
    /// ```
    /// use ncpost::back::Backend;
    /// use ncpost::front::gcode::{parse_str, Options};
    /// use ncpost::plot::SpeedPlot;
    /// let p = parse_str("M106 P2 S40\nG1 X10 F600\nM107 P2\n", &Options::default()).unwrap();
    /// let mut plot = SpeedPlot::new(Default::default(), None)
    ///     .with_screw_command("M106 P2 S{rpm}", Some("M107 P2"));
    /// for b in &p.blocks {
    ///     plot.write_block(b, &mut Vec::new()).unwrap();
    /// }
    /// plot.finish().unwrap();
    /// assert!(plot.samples().iter().any(|s| s.rpm == 40.0));
    /// assert!(plot.svg().contains("screw (rpm)"));
    /// ```
    pub fn with_screw_command(mut self, template: &str, stop: Option<&str>) -> Self {
        if let Some((before, after)) = template.split_once("{rpm}") {
            self.screw_templates
                .push((before.trim().to_string(), after.trim().to_string()));
        }
        if let Some(stop) = stop.filter(|s| !s.trim().is_empty()) {
            self.stop_commands.push(stop.trim().to_string());
        }
        self
    }

    /// The screw speed `text` sets under the configured templates, if any.
    fn template_rpm(&self, text: &str) -> Option<f64> {
        let text = text.trim();
        if self.stop_commands.iter().any(|s| s == text) {
            return Some(0.0);
        }
        self.screw_templates.iter().find_map(|(before, after)| {
            let rest = text.strip_prefix(before.as_str())?;
            let number = rest.strip_suffix(after.as_str())?;
            number.trim().parse::<f64>().ok().filter(|v| v.is_finite())
        })
    }

    /// The plot for a preset: the controller of its `[polar]` table (with its r and θ
    /// axes, see [`polar_axes`]) or `[machine]` table, `timing` overriding the controller's, rapids at
    /// `rapid_feed` mm/min.
    pub fn for_preset(
        preset: &crate::preset::Preset,
        timing: Option<crate::motion::Timing>,
        rapid_feed: f64,
    ) -> Self {
        let model = crate::motion::Model::for_machines(
            preset.polar.as_ref(),
            preset.machine.as_ref(),
            preset.backend_flavour(),
            timing,
            None,
        )
        .with_rapid_feed(rapid_feed);
        let mut plot = SpeedPlot::new(model, polar_axes(preset));
        // The screw commands the preset's `extrude-rate` writes.
        for spec in preset.passes.iter().filter(|p| p.name == "extrude-rate") {
            let get = |k: &str| spec.options.get(k).and_then(|v| v.as_str());
            let template = get("command")
                .map(str::to_string)
                .or_else(|| preset.polar.as_ref().map(|p| p.screw.rpm_command.clone()));
            if let Some(t) = template {
                plot = plot.with_screw_command(&t, get("stop_command"));
            }
        }
        plot
    }

    /// The samples so far (complete after [`Backend::finish`]); thinned on long programs.
    pub fn samples(&self) -> &[SpeedSample] {
        &self.samples
    }

    /// Total program time, seconds (complete after [`Backend::finish`]).
    pub fn seconds(&self) -> f64 {
        self.planner.time()
    }

    fn record(&mut self, s: SpeedSample) {
        self.seen += 1;
        if !self.seen.is_multiple_of(self.stride) {
            return;
        }
        self.samples.push(s);
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

    fn drain(&mut self) {
        while let Some(timed) = self.planner.pop() {
            match timed.payload {
                Item::Rpm(r) => {
                    self.rpm = r;
                    self.record(SpeedSample {
                        t: timed.start,
                        v: self.samples.last().map_or(0.0, |s| s.v),
                        axes: self
                            .samples
                            .last()
                            .map_or([0.0; crate::ir::AXIS_COUNT], |s| s.axes),
                        rpm: r,
                    });
                }
                Item::Other => {
                    if timed.dwell > 0.0 {
                        for t in [timed.start, timed.end()] {
                            self.record(SpeedSample {
                                t,
                                v: 0.0,
                                axes: [0.0; crate::ir::AXIS_COUNT],
                                rpm: self.rpm,
                            });
                        }
                    }
                }
                Item::Move(from, to) => {
                    let Some((seg, prof)) = timed.motion else {
                        continue;
                    };
                    if !seg.moves() {
                        continue;
                    }
                    let mut times = Vec::new();
                    let ph = prof.phases();
                    for w in ph.windows(2) {
                        if w[1] <= w[0] && !times.is_empty() {
                            continue;
                        }
                        // Cartesian speeds are linear within a phase; polar ones are not.
                        let n = if self.polar.is_some() {
                            self.per_phase
                        } else {
                            1
                        };
                        for i in 0..n {
                            times.push(w[0] + (w[1] - w[0]) * i as f64 / n as f64);
                        }
                    }
                    times.push(ph[3]);
                    for t in times {
                        let along = prof.speed_at(t) / seg.length;
                        let v = match self.polar {
                            Some((r, th)) => crate::motion::tool_speed(&prof, &from, &to, t, |j| {
                                crate::motion::polar_point(j, r, th)
                            }),
                            None => {
                                let d = &seg.delta;
                                along * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
                            }
                        };
                        self.record(SpeedSample {
                            t: timed.start + t,
                            v,
                            axes: std::array::from_fn(|k| along * seg.delta[k]),
                            rpm: self.rpm,
                        });
                    }
                }
            }
        }
    }

    /// The SVG picture: tool speed, each moving axis' speed and the screw speed, stacked
    /// over a shared time axis.
    pub fn svg(&self) -> String {
        let mut panels: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
        let title = match self.polar {
            Some((r, th)) => format!(
                "tool speed of a polar machine (r = {}, θ = {}): v = sqrt(ṙ² + r² θ̇²)",
                r.letter(),
                th.letter()
            ),
            None => "tool speed".to_string(),
        };
        panels.push((
            "v (mm/s)".into(),
            self.samples.iter().map(|s| (s.t, s.v)).collect(),
        ));
        for axis in self.axes.iter() {
            let unit = match self.polar {
                Some((_, th)) if axis == th => "deg/s",
                _ if axis.is_rotary() => "deg/s",
                _ => "mm/s",
            };
            let name = match self.polar {
                Some((r, _)) if axis == r => format!("{} = ṙ ({unit})", axis.letter()),
                Some((_, th)) if axis == th => format!("{} = θ̇ ({unit})", axis.letter()),
                _ => format!("{} speed ({unit})", axis.letter()),
            };
            panels.push((
                name,
                self.samples
                    .iter()
                    .map(|s| (s.t, s.axes[axis.index()]))
                    .collect(),
            ));
        }
        if self.has_rpm {
            panels.push((
                "screw (rpm)".into(),
                self.samples.iter().map(|s| (s.t, s.rpm)).collect(),
            ));
        }
        stacked_svg(&title, self.seconds(), &panels)
    }
}

/// Where one panel of a stacked time plot lies: its frame from `left` over `width`, `h`
/// high from `y0`.
struct Panel {
    left: f64,
    width: f64,
    y0: f64,
    h: f64,
}

impl Panel {
    /// The frame, the label at the left, the range `lo..hi` as ticks, and the line through
    /// `points` (time, value) for a time axis ending at `t_end` seconds.
    fn draw(
        &self,
        s: &mut String,
        label: &str,
        (lo, hi): (f64, f64),
        points: &[(f64, f64)],
        t_end: f64,
    ) {
        let Panel { left, width, y0, h } = *self;
        let _ = writeln!(
            s,
            "<rect x=\"{left}\" y=\"{y0:.1}\" width=\"{width}\" height=\"{h:.1}\" fill=\"none\" stroke=\"#999\"/>"
        );
        let _ = writeln!(s, "<text x=\"5\" y=\"{:.1}\">{label}</text>", y0 + h / 2.0);
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\" font-size=\"10\">{hi:.3}</text>\
             <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\" font-size=\"10\">{lo:.3}</text>",
            left - 4.0,
            y0 + 10.0,
            left - 4.0,
            y0 + h
        );
        let mut path = String::new();
        for (i, (t, v)) in points.iter().enumerate() {
            let x = left + width * t / t_end;
            let y = y0 + h - h * (v - lo) / (hi - lo);
            let _ = write!(path, "{}{x:.2},{y:.2}", if i == 0 { "" } else { " " });
        }
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"#1f5fbf\" stroke-width=\"1\" points=\"{path}\"/>"
        );
    }
}

/// Panels of (time, value) lines stacked over one time axis.
fn stacked_svg(title: &str, seconds: f64, panels: &[(String, Vec<(f64, f64)>)]) -> String {
    const WIDTH: f64 = 900.0;
    const PANEL: f64 = 140.0;
    const LEFT: f64 = 110.0;
    const TOP: f64 = 30.0;
    let height = TOP + PANEL * panels.len().max(1) as f64 + 40.0;
    let t_end = seconds.max(1e-9);
    let total_w = WIDTH + LEFT + 20.0;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{total_w}\" height=\"{height:.0}\" \
         viewBox=\"0 0 {total_w} {height:.0}\" font-family=\"sans-serif\" font-size=\"12\">"
    );
    let _ = writeln!(s, "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>");
    let _ = writeln!(s, "<text x=\"{LEFT}\" y=\"18\">{title}</text>");
    for (row, (name, points)) in panels.iter().enumerate() {
        let y0 = TOP + PANEL * row as f64;
        let h = PANEL - 30.0;
        let (lo, hi) = points
            .iter()
            .fold((0.0f64, f64::NEG_INFINITY), |(lo, hi), (_, v)| {
                (lo.min(*v), hi.max(*v))
            });
        let hi = if hi.is_finite() && hi > lo {
            hi
        } else {
            lo + 1.0
        };
        let frame = Panel {
            left: LEFT,
            width: WIDTH,
            y0,
            h,
        };
        frame.draw(&mut s, name, (lo, hi), points, t_end);
    }
    let _ = writeln!(
        s,
        "<text x=\"{LEFT}\" y=\"{:.1}\">time 0 .. {seconds:.3} s</text>",
        height - 12.0
    );
    s.push_str("</svg>\n");
    s
}

impl Backend for SpeedPlot {
    fn write_block(
        &mut self,
        block: &Block,
        _diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        match &block.kind {
            BlockKind::Motion(m) => {
                let (_, mut next) = joints_after(&self.last, block, m)?;
                if let Some(seg) = self.planner.model().motion(&self.last, m) {
                    for a in Axis::ALL {
                        if seg.delta[a.index()] != 0.0 && a != Axis::E {
                            self.axes.insert(a);
                        }
                    }
                    self.planner.push_move(seg, Item::Move(self.last, next));
                }
                if m.machine_frame {
                    next.forget(m.written);
                }
                self.last = next;
            }
            BlockKind::Dwell { seconds } => self.planner.push_stop(*seconds, Item::Other),
            BlockKind::Command(c) => {
                if let Some(r) = screw_rpm(&c.text).or_else(|| self.template_rpm(&c.text)) {
                    self.has_rpm = true;
                    self.planner.push_other(Item::Rpm(r));
                }
                if !c.clobbers.is_empty() {
                    self.last.forget(c.clobbers);
                    self.planner.push_stop(0.0, Item::Other);
                }
            }
            BlockKind::Verbatim(v) => {
                v.follow(&mut self.last);
                self.planner.push_stop(0.0, Item::Other);
            }
            _ => {}
        }
        self.drain();
        Ok(())
    }

    fn finish(&mut self) -> Result<(), Diagnostic> {
        self.planner.finish();
        self.drain();
        Ok(())
    }
}
