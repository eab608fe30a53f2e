//! `expand-cycles`: drill the canned cycles (`G73`, `G81`–`G83`, `G85`, `G89`) as G0/G1/G4
//! moves, for controllers that have no cycles (RepRapFirmware, Grbl).
//!
//! The G-code frontend does not model cycles: a cycle line, and each line with axis words
//! while a cycle is in force, travels as a [`Verbatim`] line, and `G80` as a command. This
//! pass re-reads those lines with the one G-code lexer and expands each hole with
//! LinuxCNC's semantics:
//!
//! 1. If the tool is below the R plane, rapid Z up to R (once per block).
//! 2. Rapid X Y to the hole at that clear height, then rapid Z down to R.
//! 3. The cycle's own motion:
//!    - `G81`: feed to Z;
//!    - `G82`: feed to Z, dwell P;
//!    - `G83`: peck: feed down by Q, rapid out to R, rapid back down to `peck_clearance`
//!      above the last depth, until Z is reached;
//!    - `G73`: chip break: feed down by Q, rapid up `chip_break_retract`, until Z;
//!    - `G85`: feed to Z, feed out to the retract height (below);
//!    - `G89`: feed to Z, dwell P, feed out to the retract height.
//! 4. Retract (at feed for G85 and G89, otherwise rapid): to R under `G99`, under `G98` to the initial level (the Z at the start
//!    of the block, or R when that is lower).
//!
//! `L` repeats the hole: under `G91` each repeat moves by the X Y increments again. Under
//! `G91`, R is measured from the Z at the start of the block and Z from R. R, Z, Q, P and
//! the retract mode are modal until `G80` or a G0–G3 motion ends the cycle; `G98` is the
//! retract mode until the program says otherwise. `G80` is dropped: the cycle no longer
//! exists on the controller.
//!
//! # Errors
//! Tapping (`G84`, `G74`) and the boring cycles that stop or orient the spindle (`G86`–`G88`,
//! `G76`) need the controller's cycle, and are errors at their line, as is anything the pass
//! cannot evaluate: a start position that is not known, a missing R or Z, a missing or
//! non-positive Q, parameters or expressions, a plane other than G17. The line then passes
//! through as written.
//!
//! # Options
//! - `dwell_p_milliseconds` (default `true`): P of G82/G89 in milliseconds (Fanuc, Haas,
//!   RepRapFirmware) rather than seconds (LinuxCNC). Inserted by the pipeline, it is
//!   `gcode_input.dwell_p_milliseconds`: the cycle's P counts as `G4 P` does.
//! - `chip_break_retract` (mm, default `0.254`, LinuxCNC's 0.010 in): G73's retract.
//! - `peck_clearance` (mm, default `0.254`): how far above the last peck G83 stops its
//!   rapid back down.

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Command, Feed, FeedMode, Joints, Motion, MotionKind, Plane,
    Span, Target, Tracker, Verbatim,
};
use crate::num::lexer::{Tok, tokens};
use crate::num::parse_decimal;

/// Options of `expand-cycles`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// P of G82/G89 in milliseconds rather than seconds.
    pub dwell_p_milliseconds: bool,
    /// G73's retract between pecks, mm.
    pub chip_break_retract: f64,
    /// How far above the last peck G83's rapid back down stops, mm.
    pub peck_clearance: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            dwell_p_milliseconds: true,
            chip_break_retract: 0.254,
            peck_clearance: 0.254,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "expand-cycles",
    summary: "drill canned cycles (G73, G81-G83, G85, G89, G98/G99, G80) as G0/G1/G4 moves for controllers without cycles",
    build: |t, _ctx| Ok(Box::new(ExpandCycles::new(super::options(t)?)?)),
    defaults: || super::to_toml(&Options::default()),
};

/// The cycle parameters in force (modal until G80), as written (program units).
#[derive(Debug, Clone, Copy, Default)]
struct Cycle {
    /// The cycle's G code (73, 81, ...); `None` when no cycle is in force.
    code: Option<u32>,
    r: Option<f64>,
    z: Option<f64>,
    q: Option<f64>,
    p: Option<f64>,
}

/// The `expand-cycles` pass.
pub struct ExpandCycles {
    options: Options,
    track: Tracker,
    cycle: Cycle,
    /// G98 (true: back to the initial level) or G99 (to R).
    initial_return: bool,
    /// The feed of the last move: the cycle's feed when its line has no F.
    feed: Feed,
}

/// The words of a cycle line.
#[derive(Debug, Default)]
struct Words {
    /// G codes as (number × 10, rounded): G73 is 730.
    g: Vec<u32>,
    /// Values by letter (A = 0), with the byte range of the word.
    values: [Option<(f64, usize, usize)>; 26],
    /// Whether a word was an axis, R or L: the line drills when a cycle is in force.
    drills: bool,
}

impl Words {
    fn get(&self, letter: char) -> Option<f64> {
        self.values[(letter as u8 - b'A') as usize].map(|v| v.0)
    }
    fn has_g(&self, code: u32) -> bool {
        self.g.contains(&(code * 10))
    }
}

/// Why a line cannot be read as a cycle line, with where.
struct Unreadable {
    message: String,
    at: (usize, usize),
    help: &'static str,
}

/// Reads the words of `text`. Letters the cycle does not take are refused.
fn read_words(text: &str) -> Result<Words, Unreadable> {
    let mut words = Words::default();
    for (s, tok, e) in tokens(text) {
        let w = match tok {
            Tok::Word(w) => w,
            Tok::Comment(_) | Tok::OpenComment(_) | Tok::LineComment(_) | Tok::Slash(_) => continue,
            Tok::Checksum(_) | Tok::Percent => continue,
            _ => {
                return Err(Unreadable {
                    message: format!("`{}` cannot be evaluated in a canned cycle", &text[s..e]),
                    at: (s, e),
                    help: "write the cycle's words as plain numbers (no parameters or expressions)",
                });
            }
        };
        let letter = w.as_bytes()[0].to_ascii_uppercase();
        let value = parse_decimal(w[1..].trim_start()).filter(|v| v.is_finite());
        let Some(value) = value else {
            return Err(Unreadable {
                message: format!("`{w}` is not a number"),
                at: (s, e),
                help: "write the value as a decimal number",
            });
        };
        match letter {
            b'G' => words.g.push((value * 10.0).round() as u32),
            b'N' | b'M' | b'S' | b'T' => {
                if letter != b'N' {
                    return Err(Unreadable {
                        message: format!("`{w}` on a canned-cycle line is not expanded"),
                        at: (s, e),
                        help: "put spindle, tool and M codes on a line of their own before the cycle",
                    });
                }
            }
            b'X' | b'Y' | b'Z' | b'R' | b'Q' | b'P' | b'F' | b'L' => {
                words.drills |= matches!(letter, b'X' | b'Y' | b'Z' | b'R' | b'L');
                words.values[(letter - b'A') as usize] = Some((value, s, e));
            }
            _ => {
                return Err(Unreadable {
                    message: format!(
                        "`{w}`: a canned cycle drilled as moves takes X Y Z R Q P F L only"
                    ),
                    at: (s, e),
                    help: "drill along Z in the XY plane (G17), or leave the cycle to a controller that has it (--emit gcode)",
                });
            }
        }
    }
    Ok(words)
}

/// Cycles this pass cannot drill as moves, with why.
fn unexpandable(code: u32) -> Option<&'static str> {
    Some(match code {
        740 | 840 | 841 => "tapping needs the controller to reverse the spindle in step with Z",
        860 => "G86 stops the spindle at the bottom",
        870 => "G87 back-boring stops and orients the spindle",
        880 => "G88 waits for a manual retract",
        760 => "G76 threading needs spindle synchronisation",
        _ => return None,
    })
}

/// `words` without the cycle codes (G80, G98, G99 and the cycles drilled here).
fn without_cycle_codes(words: &str) -> String {
    let rest: Vec<&str> = words
        .split_whitespace()
        .filter(|w| {
            let g = w
                .strip_prefix(['G', 'g'])
                .and_then(parse_decimal)
                .map(|v| (v * 10.0).round() as u32);
            !matches!(g, Some(800 | 980 | 990)) && !g.is_some_and(|g| CYCLES.contains(&g))
        })
        .collect();
    rest.join(" ")
}

/// Cycles this pass drills.
const CYCLES: [u32; 6] = [730, 810, 820, 830, 850, 890];

impl ExpandCycles {
    /// The pass with `options` (the retracts must be numbers ≥ 0).
    pub fn new(options: Options) -> Result<ExpandCycles, Diagnostic> {
        for (name, v) in [
            ("chip_break_retract", options.chip_break_retract),
            ("peck_clearance", options.peck_clearance),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Diagnostic::settings(format!(
                    "{name} must be a number >= 0"
                )));
            }
        }
        Ok(ExpandCycles {
            options,
            track: Tracker::default(),
            cycle: Cycle::default(),
            initial_return: true,
            feed: Feed {
                mode: FeedMode::PerMinute,
                rate: None,
            },
        })
    }

    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, mut block: Block, out: &mut Output<'_>) {
        match &mut block.kind {
            BlockKind::Motion(m) => {
                // A G0-G3 move ends the cycle; the frontend lost the position at the cycle
                // lines, and the axes this move leaves alone are still where they drilled.
                self.cycle.code = None;
                self.feed = m.feed;
                // A G80 written beside the move (Mach3 style) rides on it.
                if !m.extra.is_empty() {
                    let kept = without_cycle_codes(&m.extra);
                    if kept.split_whitespace().count() != m.extra.split_whitespace().count() {
                        m.extra = kept;
                    }
                }
                if let Target::Joints(j) = &mut m.target
                    && !m.machine_frame
                {
                    let pos = *self.track.pos();
                    for a in pos.known.difference(j.known).difference(m.written).iter() {
                        j.set(a, pos.values[a.index()]);
                    }
                }
            }
            BlockKind::Command(c) => {
                let printed = self.command(c);
                if !printed {
                    // Only cycle codes were on the line: its comments stay, as a comment line.
                    if block.comments.is_empty() {
                        return;
                    }
                    block.kind = BlockKind::Comment;
                }
            }
            BlockKind::Verbatim(v) => {
                if let Some(cycle_line) = self.cycle_line(v) {
                    let v = v.clone();
                    if self.expand(&v, cycle_line, &mut block, out) {
                        return;
                    }
                }
            }
            _ => {}
        }
        self.track.update(&block);
        out.push(block);
    }

    /// Follows the cycle codes of a command (`G98`, `G99`, `G80`, a cycle code with no
    /// hole) and takes them out of it; false when nothing is left to print.
    fn command(&mut self, c: &mut Command) -> bool {
        let Ok(words) = read_words(&c.text) else {
            return true;
        };
        let mut cycle_code = false;
        for &g in &words.g {
            match g {
                980 => self.initial_return = true,
                990 => self.initial_return = false,
                800 => self.cycle.code = None,
                g if CYCLES.contains(&g) => {
                    self.start_cycle(g, &words);
                }
                _ => continue,
            }
            cycle_code = true;
        }
        if !cycle_code {
            return true;
        }
        c.text = without_cycle_codes(&c.text).into();
        !c.text.is_empty()
    }

    /// Starts (or switches to) cycle `g`, taking the modal words of `words`.
    fn start_cycle(&mut self, g: u32, words: &Words) {
        if self.cycle.code != Some(g) {
            self.cycle.code = Some(g);
        }
        for (letter, slot) in [
            ('R', &mut self.cycle.r),
            ('Z', &mut self.cycle.z),
            ('Q', &mut self.cycle.q),
            ('P', &mut self.cycle.p),
        ] {
            if let Some(v) = words.get(letter) {
                *slot = Some(v);
            }
        }
    }

    /// Whether `v` is a line this pass must drill: one with a cycle code, or with axis
    /// words while a cycle is in force.
    fn cycle_line(&mut self, v: &Verbatim) -> Option<Result<Words, Unreadable>> {
        let g_codes = tokens(&v.text).filter_map(|(_, t, _)| match t {
            Tok::Word(w) if w.starts_with(['G', 'g']) => {
                parse_decimal(w[1..].trim_start()).map(|v| (v * 10.0).round() as u32)
            }
            _ => None,
        });
        let mut has_cycle_code = false;
        let mut refused = None;
        for g in g_codes {
            has_cycle_code |= CYCLES.contains(&g);
            refused = refused.or(unexpandable(g).map(|why| (g, why)));
            // Another motion (G0-G3, probing, threading) or G80 ends the cycle.
            if matches!(g, 0..=39 | 50..=59 | 330 | 380..=389 | 800) {
                self.cycle.code = None;
            }
        }
        if let Some((g, why)) = refused {
            self.cycle.code = None;
            return Some(Err(Unreadable {
                message: format!(
                    "G{} cannot be drilled as G0/G1 moves: {why}",
                    g as f64 / 10.0
                ),
                at: (0, v.text.len()),
                help: "leave this cycle to a controller that has it (--emit gcode), or write its moves out in the CAM",
            }));
        }
        if has_cycle_code {
            return Some(read_words(&v.text));
        }
        self.cycle.code?;
        let moves = tokens(&v.text).any(|(_, t, _)| {
            matches!(t, Tok::Word(w) | Tok::Letter(w)
                if matches!(w.as_bytes()[0].to_ascii_uppercase(), b'X' | b'Y' | b'Z' | b'R' | b'L'))
        });
        moves.then(|| read_words(&v.text))
    }

    /// Reports an error at the line of `span`.
    fn error(
        out: &mut Output<'_>,
        v: &Verbatim,
        span: Span,
        at: (usize, usize),
        msg: String,
        help: &str,
    ) {
        out.diag(
            Diagnostic::error("expand-cycles::cycle", msg)
                .at_bytes(span.line, &v.text, at.0, at.1)
                .with_label("passed through as written")
                .with_help(help.to_string()),
        );
    }

    /// Drills the holes of the cycle line `v`; false (with an error) when it cannot.
    fn expand(
        &mut self,
        v: &Verbatim,
        words: Result<Words, Unreadable>,
        block: &mut Block,
        out: &mut Output<'_>,
    ) -> bool {
        let span = block.span;
        let whole = (0, v.text.len());
        let words = match words {
            Ok(w) => w,
            Err(u) => {
                Self::error(out, v, span, u.at, u.message, u.help);
                return false;
            }
        };
        for &g in &words.g {
            match g {
                980 => self.initial_return = true,
                990 => self.initial_return = false,
                g if CYCLES.contains(&g) => self.start_cycle(g, &words),
                _ => {}
            }
        }
        if let Some(code) = self.cycle.code
            && words.g.iter().all(|g| !CYCLES.contains(g))
        {
            // A continuation line: its R, Z, Q, P update the cycle in force.
            self.start_cycle(code, &words);
        }
        match self.plan(v, &words) {
            Ok(moves) => {
                let mut comments = Some(std::mem::take(&mut block.comments));
                for kind in moves {
                    let mut b = Block::new(span, kind);
                    if let Some(c) = comments.take() {
                        b.comments = c;
                    }
                    self.track.update(&b);
                    out.push(b);
                }
                // The frontend warned that the line passes through unchanged: it could not
                // know that this pass drills it.
                out.diags.retain(|d| {
                    !(d.code == "gcode::unsupported-motion"
                        && d.location.as_ref().is_some_and(|l| l.line == span.line))
                });
                true
            }
            Err((at, msg, help)) => {
                Self::error(out, v, span, at.unwrap_or(whole), msg, help);
                false
            }
        }
    }
}

/// An error of planning a hole: where on the line (if one word), what, and what to do.
type PlanError = (Option<(usize, usize)>, String, &'static str);

/// Puts `at` over the next hole of the line (absolute X Y, or X Y increments under G91)
/// and returns the axes that moved.
fn next_hole(
    at: &mut Joints,
    words: &Words,
    relative: bool,
    scale: f64,
    off: &[f64; crate::ir::AXIS_COUNT],
) -> Result<AxisSet, PlanError> {
    let mut written = AxisSet::EMPTY;
    for a in [Axis::X, Axis::Y] {
        let Some(&(value, s, e)) = words.values[(a.letter() as u8 - b'A') as usize].as_ref() else {
            if at.get(a).is_none() {
                return Err((
                    None,
                    format!(
                        "the {} position before the canned cycle is not known",
                        a.letter()
                    ),
                    "move X and Y to known positions before the cycle, or write them on the cycle line",
                ));
            }
            continue;
        };
        let v = match (relative, at.get(a)) {
            (false, _) => value * scale - off[a.index()],
            (true, Some(cur)) => cur + value * scale,
            (true, None) => {
                return Err((
                    Some((s, e)),
                    format!(
                        "an incremental {} from a position that is not known",
                        a.letter()
                    ),
                    "move to a known position before the cycle",
                ));
            }
        };
        at.set(a, v);
        written.insert(a);
    }
    Ok(written)
}

impl ExpandCycles {
    /// The blocks that drill the holes of the line with `words`.
    fn plan(&mut self, v: &Verbatim, words: &Words) -> Result<Vec<BlockKind>, PlanError> {
        let (code, scale, relative) = self.frame(v, words)?;
        let word_at = |c: char| words.values[(c as u8 - b'A') as usize].map(|w| (w.1, w.2));
        let (Some(r), Some(z)) = (self.cycle.r, self.cycle.z) else {
            let missing = if self.cycle.r.is_none() { "R" } else { "Z" };
            return Err((
                None,
                format!("the canned cycle has no {missing} word"),
                "write R (the retract plane) and Z (the hole bottom) on the first line of the cycle",
            ));
        };
        let (q, dwell, repeats) = self.parameters(code, scale, words)?;
        let pos = *self.track.pos();
        let off = *self.track.offsets();
        let Some(z0) = pos.get(Axis::Z) else {
            return Err((
                None,
                "the Z position before the canned cycle is not known".into(),
                "move Z to a known height (G0 Z...) before the cycle",
            ));
        };
        // The planes, in the IR frame (program values less the G92 offsets).
        let (r_ir, bottom) = if relative {
            (z0 + r * scale, z0 + r * scale + z * scale)
        } else {
            (
                r * scale - off[Axis::Z.index()],
                z * scale - off[Axis::Z.index()],
            )
        };
        if bottom > r_ir {
            return Err((
                word_at('Z'),
                "the hole bottom Z is above the R plane".into(),
                "write Z below R",
            ));
        }
        let mut at = pos;
        let mut blocks = Vec::new();
        // Preliminary: up to R if below it, once.
        if z0 < r_ir {
            at.set(Axis::Z, r_ir);
            blocks.push(self.go(MotionKind::Rapid, at, [Axis::Z].into_iter().collect()));
        }
        let clear = if self.initial_return {
            z0.max(r_ir)
        } else {
            r_ir
        };
        for _ in 0..repeats {
            let xy_written = next_hole(&mut at, words, relative, scale, &off)?;
            if !xy_written.is_empty() {
                blocks.push(self.go(MotionKind::Rapid, at, xy_written));
            }
            self.hole(code, &mut at, (r_ir, bottom, clear), q, dwell, &mut blocks);
        }
        Ok(blocks)
    }

    /// The cycle in force, the length scale (25.4 under G20) and whether the line is
    /// incremental (G91), from the modes the line was written in and its own codes.
    fn frame(&self, v: &Verbatim, words: &Words) -> Result<(u32, f64, bool), PlanError> {
        let Some(code) = self.cycle.code else {
            return Err((
                None,
                "axis words with no canned cycle in force".into(),
                "start the line with G81 (or another cycle)",
            ));
        };
        let Some(modes) = v.modes else {
            return Err((None, "a canned cycle inside control flow or a subprogram body cannot be drilled as moves".into(), "expand the subprogram first (expand-subprograms), or write the holes out"));
        };
        if modes.plane.is_some_and(|p| p != Plane::XY) {
            return Err((
                None,
                "canned cycles are drilled along Z only (G17)".into(),
                "select G17 before the cycle",
            ));
        }
        let pick = |on: u32, off: u32, mode: bool| {
            if words.has_g(on) {
                true
            } else if words.has_g(off) {
                false
            } else {
                mode
            }
        };
        let inch = pick(200, 210, modes.inch);
        let relative = pick(910, 900, modes.relative);
        Ok((code, if inch { 25.4 } else { 1.0 }, relative))
    }

    /// The peck depth (mm), the dwell (s) and the repeat count of cycle `code`, and the
    /// feed the line sets.
    fn parameters(
        &mut self,
        code: u32,
        scale: f64,
        words: &Words,
    ) -> Result<(Option<f64>, f64, u32), PlanError> {
        let word_at = |c: char| words.values[(c as u8 - b'A') as usize].map(|w| (w.1, w.2));
        let q = match (code, self.cycle.q) {
            (730 | 830, Some(q)) if q > 0.0 => Some(q * scale),
            (730 | 830, _) => {
                return Err((
                    word_at('Q'),
                    "a peck cycle needs a peck depth Q > 0".into(),
                    "write Q, the depth of each peck",
                ));
            }
            _ => None,
        };
        let per_second = if self.options.dwell_p_milliseconds {
            1000.0
        } else {
            1.0
        };
        let dwell = match (code, self.cycle.p) {
            (820 | 890, Some(p)) if p >= 0.0 => p / per_second,
            (820 | 890, _) => {
                return Err((
                    word_at('P'),
                    "a dwell cycle needs a dwell P >= 0".into(),
                    "write P, the dwell at the bottom",
                ));
            }
            _ => 0.0,
        };
        let repeats = match words.get('L') {
            None => 1,
            Some(l) if l >= 0.0 && l.fract() == 0.0 && l <= 10_000.0 => l as u32,
            Some(_) => {
                return Err((
                    word_at('L'),
                    "L must be a whole number of repeats from 0 to 10000".into(),
                    "write L as a count",
                ));
            }
        };
        if let Some(f) = words.get('F') {
            if f.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                return Err((
                    word_at('F'),
                    "the feed must be > 0".into(),
                    "write F, the drilling feed",
                ));
            }
            self.feed.rate = Some(f * scale);
        }
        if self.feed.mode == FeedMode::InverseTime || self.feed.rate.is_none() {
            return Err((
                None,
                "the canned cycle has no feed per minute".into(),
                "write F (and G94) on the cycle line",
            ));
        }
        Ok((q, dwell, repeats))
    }

    /// The moves of one hole from R-plane approach to retract; `at` is where the tool is.
    fn hole(
        &self,
        code: u32,
        at: &mut Joints,
        (r, bottom, clear): (f64, f64, f64),
        q: Option<f64>,
        dwell: f64,
        blocks: &mut Vec<BlockKind>,
    ) {
        let z_only: AxisSet = [Axis::Z].into_iter().collect();
        let z_to = |kind: MotionKind, z: f64, blocks: &mut Vec<BlockKind>, at: &mut Joints| {
            at.set(Axis::Z, z);
            blocks.push(self.go(kind, *at, z_only));
        };
        if at.get(Axis::Z) != Some(r) {
            z_to(MotionKind::Rapid, r, blocks, at);
        }
        match (code, q) {
            (730 | 830, Some(q)) => {
                let mut depth = r;
                while depth > bottom {
                    let next = (depth - q).max(bottom);
                    if depth < r {
                        // Back down near the last depth at rapid (G83) or from the chip
                        // break (G73) at feed.
                        let near = (depth + self.options.peck_clearance).min(r);
                        if code == 830 {
                            z_to(MotionKind::Rapid, near, blocks, at);
                        }
                    }
                    z_to(MotionKind::Linear, next, blocks, at);
                    depth = next;
                    if depth > bottom {
                        let up = if code == 830 {
                            r
                        } else {
                            (depth + self.options.chip_break_retract).min(r)
                        };
                        z_to(MotionKind::Rapid, up, blocks, at);
                    }
                }
            }
            _ => z_to(MotionKind::Linear, bottom, blocks, at),
        }
        if matches!(code, 820 | 890) {
            blocks.push(BlockKind::Dwell { seconds: dwell });
        }
        let out_kind = if matches!(code, 850 | 890) {
            MotionKind::Linear
        } else {
            MotionKind::Rapid
        };
        z_to(out_kind, clear, blocks, at);
    }

    /// A move to `to` naming `written`.
    fn go(&self, kind: MotionKind, to: Joints, written: AxisSet) -> BlockKind {
        // The cycle's moves are in the program frame and carry no other words.
        let (target, feed) = (Target::Joints(to), self.feed);
        let (machine_frame, extra) = (false, String::new());
        BlockKind::Motion(Motion {
            kind,
            target,
            feed,
            written,
            machine_frame,
            extra,
        })
    }
}

impl Pass for ExpandCycles {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }
}
