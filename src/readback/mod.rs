//! The readback: a second reading of the PRINTED program, the way the target controller
//! reads it, and its comparison with the programmed path (`ncpost run --verify`, issue 20).
//!
//! ncpost's passes compute with their own model of the machine. The readback does not
//! trust it: [`Reader`] re-reads the emitted text with its own modal state (it shares
//! only the word lexer and the decimal reader with the G-code frontend) and times every
//! block as the controller does (the flavour's `G0` rule, the minimum speed, the per-axis
//! caps); [`Checker`] maps the printed joints back through the one kinematic chain
//! (`machine` forward kinematics, or the polar arm) and compares them with the programmed
//! path, the IR as it was before the machine passes ([`Tap`]).
//!
//! Once per run it gives [`Figures`]: the worst tip deviation from the programmed path,
//! the worst tool-axis deviation, the worst block time error against the programmed feed,
//! the worst valve lead error, the material error per file and worst per block (polar),
//! and the smallest limit margin, each with the line of the printed program (and the
//! source line). [`Figures::diagnostics`] makes of them one note and an error for each
//! violated tolerance.
//!
//! The reading streams: the checker holds the programmed vertices between the tap and
//! the printed text (a few batches) and nothing of the printed text but its current line.

mod check;
mod path;
mod reader;

pub use check::{Checker, Queue};
pub use path::{Kinematics, Tap, Vertex};
pub use reader::{Event, Move, Reader};

use serde::{Deserialize, Serialize};

use crate::diag::Diagnostic;
use crate::motion::{Model, Planner};

/// The `[verify]` section of a preset: tolerance overrides of `ncpost run --verify`.
/// Unset tolerances come from the passes' own options.
///
/// ```
/// let s: ncpost::readback::Settings = toml::from_str("time = 0.02").unwrap();
/// assert_eq!(s.time, 0.02);
/// assert_eq!(s.valve_lead, 0.001);
/// assert_eq!(s.tip, None);
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Settings {
    /// Whether runs with this preset verify by default (`--verify`/`--no-verify` win);
    /// unset: when the preset has a `[machine]` or `[polar]` table.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub enabled: Option<bool>,
    /// Largest tip deviation, mm; unset: the `densify` pass's `tip_tolerance` (5-axis)
    /// or the `polar-ik` pass's `tolerance`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tip: Option<f64>,
    /// Largest tool-axis deviation, degrees; unset: `densify`'s `axis_tolerance`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub axis: Option<f64>,
    /// Largest block time error, relative to the programmed time.
    pub time: f64,
    /// Largest valve lead error, seconds.
    pub valve_lead: f64,
    /// Largest material error of the whole file, relative.
    pub material_file: f64,
    /// Largest material error of one block, relative.
    pub material_block: f64,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            enabled: None,
            tip: None,
            axis: None,
            time: 0.01,
            valve_lead: 0.001,
            material_file: 0.005,
            material_block: 0.01,
        }
    }
}

/// The tolerances one run checks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerances {
    /// Tip deviation, mm.
    pub tip: f64,
    /// Tool-axis deviation, degrees.
    pub axis: f64,
    /// Block time error, relative.
    pub time: f64,
    /// Valve lead error, seconds.
    pub valve_lead: f64,
    /// Material error per file, relative.
    pub material_file: f64,
    /// Material error per block, relative.
    pub material_block: f64,
}

impl Tolerances {
    /// The tolerances of `settings`, with `tip` and `axis` for what it leaves unset.
    pub fn new(settings: &Settings, tip: f64, axis: f64) -> Tolerances {
        Tolerances {
            tip: settings.tip.unwrap_or(tip),
            axis: settings.axis.unwrap_or(axis),
            time: settings.time,
            valve_lead: settings.valve_lead,
            material_file: settings.material_file,
            material_block: settings.material_block,
        }
    }

    /// How close a printed end must come to a programmed vertex to reach it, mm: a
    /// quarter of the tip tolerance (the printed digits are far finer).
    fn hit_tip(&self) -> f64 {
        self.tip / 4.0
    }

    /// As [`Tolerances::hit_tip`] for the tool axis, degrees.
    fn hit_axis(&self) -> f64 {
        self.axis / 4.0
    }
}

/// The worst value of a figure and where it was.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Worst {
    /// The value (0 when nothing was measured).
    pub value: f64,
    /// Line of the printed program (0: none).
    pub line: u64,
    /// Source line of the programmed block (0: unknown).
    pub source: u32,
}

impl Worst {
    fn note(&mut self, value: f64, line: u64, source: u32) {
        if value > self.value || (value.is_nan() && !self.value.is_nan()) {
            *self = Worst {
                value,
                line,
                source,
            };
        }
    }

    fn place(&self) -> String {
        match (self.line, self.source) {
            (0, _) => String::new(),
            (l, 0) => format!(" (output line {l})"),
            (l, s) => format!(" (output line {l}, input line {s})"),
        }
    }
}

/// What the readback found in one run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Figures {
    /// Tip deviation from the programmed path, mm.
    pub tip: Worst,
    /// Tool-axis deviation from the programmed axis path, degrees.
    pub axis: Worst,
    /// Block time error against the programmed feed, relative.
    pub time: Worst,
    /// Valve lead error, seconds (infinite: a valve command is missing).
    pub valve: Worst,
    /// Material error of one block, relative.
    pub material_block: Worst,
    /// Material the programmed path deposits, E units.
    pub material_programmed: f64,
    /// Material the printed program deposits, E units.
    pub material_printed: f64,
    /// Smallest limit margin: mm or degrees, the axis letter, the printed line.
    pub margin: Option<(f64, char, u64)>,
    /// Programmed segments the printed path traced.
    pub segments: u64,
    /// Programmed vertices the printed path never reached.
    pub unmatched: u64,
    /// Source line of the first of them.
    pub unmatched_line: u32,
    /// Seconds the printed program takes on the controller.
    pub seconds: f64,
}

impl Figures {
    /// The material error of the whole file, relative (0 without material).
    pub fn material_file(&self) -> f64 {
        if self.material_programmed > 0.0 {
            (self.material_printed - self.material_programmed).abs() / self.material_programmed
        } else if self.material_printed > 0.0 {
            f64::INFINITY
        } else {
            0.0
        }
    }

    /// One note with every figure, then an error for each tolerance it violates.
    /// `polar` adds the valve and material figures.
    pub fn diagnostics(&self, tol: &Tolerances, polar: bool) -> Vec<Diagnostic> {
        let mut parts = vec![
            format!(
                "tip {:.4} mm{} (tolerance {} mm)",
                self.tip.value,
                self.tip.place(),
                tol.tip
            ),
            format!(
                "tool axis {:.4}°{} (tolerance {}°)",
                self.axis.value,
                self.axis.place(),
                tol.axis
            ),
            format!(
                "time {:.3} %{} (tolerance {} %)",
                self.time.value * 100.0,
                self.time.place(),
                tol.time * 100.0
            ),
        ];
        if polar {
            parts.push(format!(
                "valve lead {:.1} ms{} (tolerance {} ms)",
                self.valve.value * 1000.0,
                self.valve.place(),
                tol.valve_lead * 1000.0
            ));
            parts.push(format!(
                "material {:.3} % per file ({:.5} of {:.5}), {:.3} % per block{} (tolerances {} %, {} %)",
                self.material_file() * 100.0,
                self.material_printed,
                self.material_programmed,
                self.material_block.value * 100.0,
                self.material_block.place(),
                tol.material_file * 100.0,
                tol.material_block * 100.0
            ));
        }
        if let Some((m, axis, line)) = self.margin {
            parts.push(format!("limit margin {m:.4} ({axis}, output line {line})"));
        }
        let mut out = vec![Diagnostic::note(
            "verify::report",
            format!(
                "verify: {} segments, {:.1} s on the controller; {}",
                self.segments,
                self.seconds,
                parts.join("; ")
            ),
        )];
        self.violations(tol, polar, &mut out);
        out
    }

    fn violations(&self, tol: &Tolerances, polar: bool, out: &mut Vec<Diagnostic>) {
        let over = |w: &Worst, limit: f64| !within(w.value, limit);
        let mut fail = |code: &'static str, what: String, help: &str| {
            out.push(Diagnostic::error(code, what).with_help(help.to_string()));
        };
        if over(&self.tip, tol.tip) {
            fail(
                "verify::tip",
                format!(
                    "the printed tip leaves the programmed path by {:.4} mm{}, beyond the tolerance {} mm",
                    self.tip.value,
                    self.tip.place(),
                    tol.tip
                ),
                "the machine passes' output does not hold their tolerance on the printed numbers; tighten the pass (densify tip_tolerance, polar-ik tolerance) or set [verify] tip",
            );
        }
        if over(&self.axis, tol.axis) {
            fail(
                "verify::axis",
                format!(
                    "the printed tool axis leaves the programmed one by {:.4}°{}, beyond the tolerance {}°",
                    self.axis.value,
                    self.axis.place(),
                    tol.axis
                ),
                "tighten densify's axis_tolerance, or set [verify] axis",
            );
        }
        if over(&self.time, tol.time) {
            fail(
                "verify::time",
                format!(
                    "a block takes {:.2} % more or less time on the controller than its programmed feed gives{}, beyond {} %",
                    self.time.value * 100.0,
                    self.time.place(),
                    tol.time * 100.0
                ),
                "the printed F, the controller's minimum speed or its G0 rule do not give the programmed time; check [machine.controller] / [polar.controller] (min_speed, max_feed, flavour)",
            );
        }
        if polar && over(&self.valve, tol.valve_lead) {
            fail(
                "verify::valve",
                format!(
                    "a valve command takes effect {:.1} ms away from its extrusion start or end{}, beyond {} ms",
                    self.valve.value * 1000.0,
                    self.valve.place(),
                    tol.valve_lead * 1000.0
                ),
                "the valve look-ahead timed its commands with another motion time than the controller's; check the controller's caps and G0 rule",
            );
        }
        if polar && !within(self.material_file(), tol.material_file) {
            fail(
                "verify::material",
                format!(
                    "the printed program deposits {:.5} where {:.5} was programmed ({:.2} %), beyond {} %",
                    self.material_printed,
                    self.material_programmed,
                    self.material_file() * 100.0,
                    tol.material_file * 100.0
                ),
                "the screw speeds were computed with another motion time than the controller's",
            );
        }
        if polar && over(&self.material_block, tol.material_block) {
            fail(
                "verify::material-block",
                format!(
                    "a block deposits {:.2} % more or less than programmed{}, beyond {} %",
                    self.material_block.value * 100.0,
                    self.material_block.place(),
                    tol.material_block * 100.0
                ),
                "the screw speeds were computed with another motion time than the controller's",
            );
        }
        if let Some((m, axis, line)) = self.margin.filter(|m| m.0 < 0.0) {
            fail(
                "verify::limit",
                format!("{axis} is {:.4} beyond its limit (output line {line})", -m),
                "the printed program leaves the machine's travel; move the part or change the limits",
            );
        }
        if self.unmatched > 0 {
            fail(
                "verify::unmatched",
                format!(
                    "the printed program never reaches {} programmed point{} (the first from input line {})",
                    self.unmatched,
                    if self.unmatched == 1 { "" } else { "s" },
                    self.unmatched_line
                ),
                "the printed path ends early or leaves the programmed one",
            );
        }
    }
}

/// Whether `value` is within `limit` (a value that is not a number is not).
fn within(value: f64, limit: f64) -> bool {
    value <= limit * (1.0 + 1e-9)
}

/// Reads the printed text as it is written (bytes, split into lines here) and checks it.
pub struct Verifier {
    reader: Reader,
    checker: Checker,
    tol: Tolerances,
    polar: bool,
    /// Under trapezoid timing, the planner that times the printed moves with their
    /// neighbours (each event with its output line) before the checker sees them.
    planner: Option<Planner<(Event, u64)>>,
    partial: Vec<u8>,
    line: u64,
}

impl Verifier {
    /// A verifier of the text `reader` reads against `checker`'s programmed path.
    pub fn new(reader: Reader, checker: Checker, tol: Tolerances, polar: bool) -> Verifier {
        Verifier {
            reader,
            checker,
            tol,
            polar,
            planner: None,
            partial: Vec::new(),
            line: 0,
        }
    }

    /// The same verifier timing the printed program as `model`'s look-ahead planner does
    /// (trapezoid timing: each move accelerates and brakes within what its neighbours
    /// allow, and stops at dwells and homing). Valve leads and material are judged on
    /// those times; block times are reported but not judged, since the programmed feed
    /// gives no block time once the machine accelerates.
    pub fn with_planner(mut self, model: Model) -> Verifier {
        self.planner = Some(Planner::new(model));
        self
    }

    /// Takes printed bytes.
    pub fn bytes(&mut self, buf: &[u8]) {
        let Some(last) = memchr::memrchr(b'\n', buf) else {
            self.partial.extend_from_slice(buf);
            return;
        };
        // The whole lines, the last without its newline.
        let mut whole = &buf[..last];
        if !self.partial.is_empty() {
            let end = memchr::memchr(b'\n', whole).unwrap_or(whole.len());
            let mut first = std::mem::take(&mut self.partial);
            first.extend_from_slice(&whole[..end]);
            self.take_line(&first);
            first.clear();
            self.partial = first;
            whole = whole.get(end + 1..).unwrap_or_default();
            if end == last {
                self.partial.extend_from_slice(&buf[last + 1..]);
                return;
            }
        }
        // The backend prints UTF-8: one check for all the lines, not one a line.
        match std::str::from_utf8(whole) {
            Ok(text) => text.split('\n').for_each(|line| self.take_text(line)),
            Err(_) => whole
                .split(|&b| b == b'\n')
                .for_each(|line| self.take_line(line)),
        }
        self.partial.extend_from_slice(&buf[last + 1..]);
    }

    fn take_line(&mut self, bytes: &[u8]) {
        self.take_text(&String::from_utf8_lossy(bytes));
    }

    fn take_text(&mut self, text: &str) {
        self.line += 1;
        let Some(e) = self.reader.line(text) else {
            return;
        };
        let Some(planner) = self.planner.as_mut() else {
            self.checker.event(&e, self.line);
            return;
        };
        let item = (e, self.line);
        match e {
            Event::Move(m) => planner.push_move(m.segment, item),
            Event::Dwell(seconds) => planner.push_stop(seconds, item),
            // Homing ends with the machine at rest.
            Event::Lost(_) => planner.push_stop(0.0, item),
            Event::Valve(_) | Event::Screw(_) => planner.push_other(item),
        }
        Self::check_planned(planner, &mut self.checker);
    }

    /// Hands the moves whose planned times are final to the checker, with those times.
    fn check_planned(planner: &mut Planner<(Event, u64)>, checker: &mut Checker) {
        while let Some(timed) = planner.pop() {
            let (mut e, line) = timed.payload;
            if let Event::Move(m) = &mut e {
                m.seconds = timed.motion.map_or(0.0, |(_, p)| p.duration());
            }
            checker.event(&e, line);
        }
    }

    /// The report: one note, and an error for each violated tolerance.
    pub fn finish(mut self) -> (Figures, Vec<Diagnostic>) {
        if !self.partial.is_empty() {
            let rest = std::mem::take(&mut self.partial);
            self.take_line(&rest);
        }
        let mut tol = self.tol;
        if let Some(planner) = self.planner.as_mut() {
            planner.finish();
            Self::check_planned(planner, &mut self.checker);
            tol.time = f64::INFINITY;
        }
        let figures = self.checker.finish();
        let diags = figures.diagnostics(&tol, self.polar);
        (figures, diags)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ir::{Axis, AxisSet};
    use crate::machine::{Controller, Flavour};
    use crate::motion::Model;
    use std::collections::VecDeque;
    use std::sync::{Arc, Mutex};

    fn vertex(x: f64, feed: f64, line: u32) -> Vertex {
        Vertex {
            tip: nalgebra::Point3::new(x, 0.0, 0.0),
            axis: nalgebra::Vector3::z(),
            feed,
            rapid: feed == 0.0,
            fresh: line == 1,
            material: 0.0,
            arc: None,
            restore: 0.0,
            machine: false,
            known: AxisSet::XYZ,
            line,
        }
    }

    /// A verifier of `G0 X0`, a cut to X10 at F600, then to X20 at F600, in LinuxCNC's
    /// reading.
    fn verifier() -> Verifier {
        let queue: Queue = Arc::new(Mutex::new(VecDeque::from([
            vertex(0.0, 0.0, 1),
            vertex(10.0, 600.0, 2),
            vertex(20.0, 600.0, 3),
        ])));
        let c = Controller {
            flavour: Some(Flavour::Linuxcnc),
            min_speed: Some(0.0),
            ..Controller::default()
        };
        let model = Model::new(&c);
        let tol = Tolerances::new(&Settings::default(), 0.01, 0.05);
        let reader = Reader::new(model.clone(), c.flavour, None);
        let checker = Checker::new(Kinematics::Cartesian, &model, tol, None, queue);
        Verifier::new(reader, checker, tol, false)
    }

    /// A program printed at half the programmed feed on its first cut and 0.02 mm off the
    /// line on its second.
    const WRONG: &[u8] = b"G0 X0 Y0 Z0\nG1 X10 F300\nG1 X15 Y0.02 F600\nG1 X20 Y0";

    /// A cut printed at half its programmed feed, and a printed point 0.02 mm off the
    /// line: both figures, with their lines, and an error each.
    #[test]
    fn figures_of_a_wrong_program() {
        let mut v = verifier();
        v.bytes(WRONG);
        let (f, diags) = v.finish();
        assert!((f.time.value - 1.0).abs() < 1e-9, "{f:?}");
        assert_eq!((f.time.line, f.time.source), (2, 2));
        assert!((f.tip.value - 0.02).abs() < 1e-9, "{f:?}");
        assert_eq!((f.tip.line, f.tip.source), (3, 3));
        assert_eq!(f.segments, 3);
        let codes: Vec<_> = diags.iter().map(|d| d.code).collect();
        assert_eq!(codes, ["verify::report", "verify::tip", "verify::time"]);
        assert!(Axis::X.index() == 0);
    }

    /// The printed text arrives in writes of any length, cut anywhere (inside a line, at
    /// a newline, several lines at once, a bad UTF-8 byte): the lines read are the same.
    #[test]
    fn lines_cut_anywhere_read_the_same() {
        let mut whole = verifier();
        whole.bytes(WRONG);
        let (expected, _) = whole.finish();
        for size in 1..WRONG.len() {
            let mut v = verifier();
            WRONG.chunks(size).for_each(|c| v.bytes(c));
            let (f, _) = v.finish();
            assert_eq!(f, expected, "writes of {size} bytes");
        }
        let mut bad = WRONG.to_vec();
        bad.splice(0..0, b"; \xff\n".iter().copied());
        let mut v = verifier();
        v.bytes(&bad);
        assert_eq!(v.line, 4, "the comment line, then three whole lines");
        let (f, _) = v.finish();
        assert_eq!((f.tip.line, f.segments), (4, 3));
    }
}
