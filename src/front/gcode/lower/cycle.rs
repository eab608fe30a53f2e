//! Canned cycles (`G73`, `G74`, `G81`–`G89`): the line travels as written, resolved to
//! its holes, planes and end position ([`CycleLine`]) so that the position after it is
//! the controller's. The semantics are LinuxCNC's (see [`crate::ir::cycle`]); Fanuc's
//! differ in the repeat word (`K`, or `L` on Haas and the FS15 format).

use super::words::{Code, Slots, Word};
use super::{Lowerer, Placement};
use crate::diag::Diagnostic;
use crate::ir::cycle::{CannedCycle, CycleLine, CycleProblem};
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, CycleSeries, Dialect, Feed, FeedMode, Joints, Plane, Span,
    VerbatimReason,
};

/// The canned cycle in force and its sticky words (LinuxCNC's "sticky" R, Z, Q, P: given
/// once, kept by the lines after until the series ends).
#[derive(Debug, Clone, Copy)]
pub(super) struct CycleModal {
    /// The cycle, its sticky words as written (program units and distance mode) and the
    /// initial level (IR frame): the part a subprogram body carries across its call.
    series: CycleSeries,
    /// `G98` (true) or `G99`: the retract mode, modal across series.
    to_initial: bool,
}

impl Default for CycleModal {
    fn default() -> Self {
        CycleModal {
            series: CycleSeries::default(),
            // Fanuc's power-on mode (the dialect sets LinuxCNC's G99); CAM posts write
            // G98 or G99 with their cycles.
            to_initial: true,
        }
    }
}

impl CycleModal {
    /// `G98` (true) or `G99`.
    pub(super) fn retract_to_initial(&self) -> bool {
        self.to_initial
    }

    /// The series in force, for the state a subprogram body leaves.
    pub(super) fn series(&self) -> CycleSeries {
        self.series
    }

    /// Continues the series `s` (the caller's into a body, the body's after a call).
    pub(super) fn set_series(&mut self, s: CycleSeries) {
        self.series = s;
    }

    /// Sets the retract mode (the dialect's start, or the caller's across a call).
    pub(super) fn set_retract_to_initial(&mut self, to_initial: bool) {
        self.to_initial = to_initial;
    }
}

/// The G numbers of the canned cycles of the XY-plane mill (G76 included: Fanuc's fine
/// boring, LinuxCNC's lathe threading; it is never resolved).
fn is_cycle(code: Code) -> bool {
    matches!(code, (73 | 74 | 76 | 81..=89, 0))
}

/// Where a cycle line leaves X, Y and Z: over its last hole at the retract level (Z
/// unknown after `G88`, whose retract is the operator's), or where it started when it
/// drills no hole (Fanuc's `K0`).
fn end_of(holes: &[[f64; 2]], start: &Joints, clear: f64, code: u32) -> Joints {
    let mut end = Joints::default();
    let Some(&[x, y]) = holes.last() else {
        for a in [Axis::X, Axis::Y, Axis::Z] {
            if let Some(v) = start.get(a) {
                end.set(a, v);
            }
        }
        return end;
    };
    end.set(Axis::X, x);
    end.set(Axis::Y, y);
    if code != 88 {
        end.set(Axis::Z, clear);
    }
    end
}

/// A problem with the whole line.
fn problem(message: impl Into<String>, help: &'static str, at: (usize, usize)) -> CycleProblem {
    CycleProblem {
        message: message.into(),
        help,
        at,
    }
}

impl Lowerer {
    /// Follows the cycle codes of a block: `G98`/`G99` set the retract mode, a cycle code
    /// starts (or switches) the cycle, and `G80` or any other motion code ends the series.
    pub(super) fn follow_cycle_codes(&mut self, g: &[(Code, u32)]) {
        for &(code, _) in g {
            match code {
                (98, 0) => self.cycle.to_initial = true,
                (99, 0) => self.cycle.to_initial = false,
                c if is_cycle(c) => self.cycle.series.code = Some(c.0),
                (80, 0) | (0..=3 | 5 | 33 | 38, _) => {
                    // The series ends: its initial level and sticky words go with it.
                    self.cycle = CycleModal {
                        to_initial: self.cycle.to_initial,
                        ..CycleModal::default()
                    };
                }
                _ => {}
            }
        }
    }

    /// Whether a canned cycle is the motion mode in force.
    pub(super) fn in_cycle(&self) -> bool {
        self.cycle.series.code.is_some()
    }

    /// A line with axis words while a cycle is in force: the line as written, with the
    /// cycle resolved; the position after it is where its last hole retracted.
    pub(super) fn cycle_block(
        &mut self,
        text: &str,
        span: Span,
        slots: &Slots<'_, '_>,
        diags: &mut Vec<Diagnostic>,
    ) -> Block {
        let resolved = self.resolve_cycle(text, slots);
        if let Err(p) = &resolved {
            diags.push(
                Diagnostic::warning(
                    "gcode::cycle",
                    format!("canned cycle not resolved: {}", p.message),
                )
                .at_bytes(span.line, text, p.at.0, p.at.1)
                .with_label("passes through unchanged")
                .with_help(format!("{}; positions after the line are unknown", p.help)),
            );
        }
        let clobbers = if resolved.is_ok() {
            // The cycle moves X, Y and Z only (LinuxCNC refuses rotary words in cycles).
            AxisSet::XYZ
        } else {
            AxisSet::ALL
        };
        let mut block = self.verbatim(
            text,
            span,
            VerbatimReason::Unevaluated,
            clobbers,
            Placement::TopLevel { keeps_modes: true },
        );
        let line = match resolved {
            Ok(c) => {
                for a in c.end.known.iter() {
                    self.pos.set(a, c.end.values[a.index()]);
                }
                CycleLine::Resolved(Box::new(c))
            }
            Err(p) => CycleLine::Unresolved(Box::new(p)),
        };
        if let BlockKind::Verbatim(v) = &mut block.kind {
            v.cycle = Some(line);
        }
        block
    }

    /// Resolves a cycle line: its sticky words, planes, holes and end position.
    fn resolve_cycle(
        &mut self,
        text: &str,
        slots: &Slots<'_, '_>,
    ) -> Result<CannedCycle, CycleProblem> {
        let whole = (0, text.len());
        let code = self.cycle.series.code.unwrap_or(81);
        if code == 76 {
            return Err(problem(
                "G76 is a boring cycle that orients the spindle (Fanuc) or a lathe threading cycle (LinuxCNC)",
                "leave this cycle to a controller that has it, or write its moves out in the CAM",
                whole,
            ));
        }
        if self.plane != Plane::XY {
            return Err(problem(
                "canned cycles are resolved along Z only (G17)",
                "select G17 before the cycle",
                whole,
            ));
        }
        for (letter, slot) in [
            ('R', &mut self.cycle.series.r),
            ('Z', &mut self.cycle.series.z),
            ('Q', &mut self.cycle.series.q),
            ('P', &mut self.cycle.series.p),
        ] {
            if let Some(w) = slots.get(letter) {
                *slot = Some(w.value);
            }
        }
        let repeats = self.repeats(slots)?;
        let scale = self.unit(Axis::Z);
        let [x0, y0, z0] = self.cycle_start(slots, whole)?;
        let (Some(r), Some(z)) = (self.cycle.series.r, self.cycle.series.z) else {
            let missing = if self.cycle.series.r.is_none() {
                "R"
            } else {
                "Z"
            };
            return Err(problem(
                format!("the canned cycle has no {missing} word"),
                "write R (the retract plane) and Z (the hole bottom) on the first line of the cycle",
                whole,
            ));
        };
        // LinuxCNC `cycle_il`: the level before the first cycle of the series.
        let initial = *self.cycle.series.initial.get_or_insert(z0);
        let off_z = self.offsets[Axis::Z.index()];
        let (r_ir, bottom) = if self.relative {
            // G91: R from the initial level, Z from R (LinuxCNC's and Fanuc's rule).
            (initial + r * scale, initial + (r + z) * scale)
        } else {
            (r * scale - off_z, z * scale - off_z)
        };
        if bottom > r_ir {
            let at = slots.get('Z').map_or(whole, |w| (w.start, w.end));
            return Err(problem(
                "the hole bottom Z is above the R plane",
                "write Z below R",
                at,
            ));
        }
        let (q, dwell, feed) = self.cycle_parameters(code, slots, whole)?;
        let clear = if self.cycle.to_initial {
            initial.max(r_ir)
        } else {
            r_ir
        };
        let holes = self.holes(slots, [x0, y0], repeats);
        let values = holes.iter().flatten().chain([&r_ir, &bottom]);
        if !values.into_iter().all(|v| v.is_finite()) {
            return Err(problem(
                "the canned cycle's coordinates are out of range",
                "write the cycle's X Y Z R in the part's range",
                whole,
            ));
        }
        let end = end_of(&holes, &self.pos, clear, code);
        Ok(CannedCycle {
            code,
            r: r_ir,
            bottom,
            clear,
            holes,
            q,
            dwell,
            feed,
            end,
        })
    }

    /// X, Y and Z before a cycle line (IR frame). Z must be known; X and Y too, unless
    /// the line writes them in absolute mode (an unknown one is then 0 here, and never
    /// used: every hole takes the written value).
    fn cycle_start(
        &self,
        slots: &Slots<'_, '_>,
        whole: (usize, usize),
    ) -> Result<[f64; 3], CycleProblem> {
        let pos = &self.pos;
        let needed = |a: Axis| a == Axis::Z || self.relative || slots.axis(a).is_none();
        let unknown: Vec<String> = [Axis::X, Axis::Y, Axis::Z]
            .into_iter()
            .filter(|&a| pos.get(a).is_none() && needed(a))
            .map(|a| a.letter().to_string())
            .collect();
        if unknown.is_empty() {
            let at = |a: Axis| pos.get(a).unwrap_or(0.0);
            return Ok([at(Axis::X), at(Axis::Y), at(Axis::Z)]);
        }
        Err(problem(
            format!(
                "the {} position before the canned cycle is not known",
                unknown.join(" ")
            ),
            "move to a known position (G0 X.. Y.. Z..) before the cycle, or write X and Y on the cycle line in G90",
            whole,
        ))
    }

    /// X and Y of the holes of a line, from `start`: the line's X Y (under `G91` added
    /// again at each repeat; under `G90` the same place each time, as LinuxCNC does).
    fn holes(&self, slots: &Slots<'_, '_>, start: [f64; 2], repeats: u32) -> Vec<[f64; 2]> {
        let mut at = start;
        let mut holes = Vec::with_capacity(repeats as usize);
        for _ in 0..repeats {
            for (i, a) in [Axis::X, Axis::Y].into_iter().enumerate() {
                if let Some(w) = slots.axis(a) {
                    let v = w.value * self.unit(a);
                    at[i] = if self.relative {
                        at[i] + v
                    } else {
                        v - self.offsets[a.index()]
                    };
                }
            }
            holes.push(at);
        }
        holes
    }

    /// The repeat count: `L` (LinuxCNC, Haas), or `K` under the Fanuc dialect.
    fn repeats(&self, slots: &Slots<'_, '_>) -> Result<u32, CycleProblem> {
        let fanuc = self.dialect == Dialect::Fanuc;
        let word: Option<Word<'_>> = match (slots.get('L'), slots.get('K')) {
            (Some(l), Some(k)) if fanuc => {
                return Err(problem(
                    format!("`{}` and `{}` both give the repeat count", l.text, k.text),
                    "give the number of repeats once, with K",
                    (k.start, k.end),
                ));
            }
            (_, Some(k)) if !fanuc => {
                return Err(problem(
                    format!(
                        "`{}`: K is Fanuc's repeat count; LinuxCNC repeats with L",
                        k.text
                    ),
                    "set gcode_input.dialect = \"fanuc\" for a Fanuc program, or write L",
                    (k.start, k.end),
                ));
            }
            (l, k) => k.or(l),
        };
        let Some(w) = word else { return Ok(1) };
        let n = w.value;
        // LinuxCNC refuses L0 ("It is an error if ... an L number is used that does not
        // evaluate to a positive integer"); Fanuc's K0 only stores the cycle's words.
        let least = if fanuc { 0.0 } else { 1.0 };
        if n.fract() != 0.0 || n < least || n > 10_000.0 {
            return Err(problem(
                format!(
                    "`{}` must be a whole number of repeats from {least} to 10000",
                    w.text
                ),
                "write the number of holes to drill at this line's spacing",
                (w.start, w.end),
            ));
        }
        Ok(n as u32)
    }

    /// The peck depth (mm), the dwell (s) and the feed of cycle `code`.
    fn cycle_parameters(
        &self,
        code: u32,
        slots: &Slots<'_, '_>,
        whole: (usize, usize),
    ) -> Result<(Option<f64>, Option<f64>, Feed), CycleProblem> {
        let at = |l: char| slots.get(l).map_or(whole, |w| (w.start, w.end));
        let q = match (code, self.cycle.series.q) {
            (73 | 83, Some(q)) if q > 0.0 => Some(q * self.unit(Axis::Z)),
            (73 | 83, _) => {
                return Err(problem(
                    "a peck cycle needs a peck depth Q > 0",
                    "write Q, the depth of each peck",
                    at('Q'),
                ));
            }
            _ => None,
        };
        let dwell = match (code, self.cycle.series.p) {
            (82 | 86 | 88 | 89 | 74 | 84, Some(p)) if p >= 0.0 => Some(self.p_seconds(p)),
            (82 | 86 | 88 | 89, _) => {
                return Err(problem(
                    "a dwell cycle needs a dwell P >= 0",
                    "write P, the dwell at the bottom",
                    at('P'),
                ));
            }
            _ => None,
        };
        if self.feed_mode == FeedMode::InverseTime || !self.feed.is_some_and(|f| f > 0.0) {
            return Err(problem(
                "the canned cycle has no feed per minute",
                "write F (and G94) on the cycle line",
                at('F'),
            ));
        }
        let feed = Feed {
            mode: self.feed_mode,
            rate: self.feed,
        };
        Ok((q, dwell, feed))
    }
}
