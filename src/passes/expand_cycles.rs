//! `expand-cycles`: drill the canned cycles (`G73`, `G81`–`G83`, `G85`, `G89`) as G0/G1/G4
//! moves, for controllers that have no cycles (RepRapFirmware, Grbl).
//!
//! The G-code frontend keeps each cycle line as written ([`Verbatim`]) and resolves it
//! ([`CycleLine`]): its holes, R plane, bottom and retract level with LinuxCNC's semantics
//! (see [`crate::ir::cycle`]). This pass drills each hole as LinuxCNC does
//! (`interp_cycles.cc`, G-code reference "G80-G89 Canned Cycles"):
//!
//! 1. If the tool is below the R plane, rapid Z up to R (once per line).
//! 2. Rapid X Y to the hole at that height, then rapid Z down to R.
//! 3. The cycle's own motion:
//!    - `G81`: feed to Z;
//!    - `G82`: feed to Z, dwell P;
//!    - `G83`: peck: feed down by Q, rapid out to R, rapid back down to `peck_clearance`
//!      above the last depth, until Z is reached;
//!    - `G73`: chip break: feed down by Q, rapid up `chip_break_retract`, until Z;
//!    - `G85`: feed to Z, feed out to R, then rapid to the retract level;
//!    - `G89`: feed to Z, dwell P, feed out to the retract level.
//! 4. Retract (rapid unless said otherwise) to R under `G99`, under `G98` to the initial
//!    level (the Z before the first cycle of the series, or R when that is lower).
//!
//! `G80`, `G98` and `G99` are dropped: the cycle no longer exists on the controller.
//!
//! # Errors
//! Tapping (`G84`, `G74`) and the boring cycles that stop or orient the spindle (`G86`–`G88`,
//! `G76`) need the controller's cycle, and are errors at their line, as is a cycle line the
//! frontend could not resolve (an unknown start position, a missing R, Z, Q or P, a plane
//! other than G17, parameters or expressions, a cycle inside control flow). The line then
//! passes through as written.
//!
//! # Options
//! - `chip_break_retract` (mm, default `0.254`, LinuxCNC's 0.010 in): G73's retract.
//! - `peck_clearance` (mm, default `0.254`): how far above the last peck G83 stops its
//!   rapid back down.
//!
//! The dwell's unit is the frontend's (`gcode_input.dwell_p_milliseconds` and the
//! dialect): the frontend reads P.

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::cycle::{CannedCycle, CycleLine};
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Command, Joints, Motion, MotionKind, Span, Target, Tracker,
    Verbatim, VerbatimReason,
};
use crate::num::lexer::{Tok, tokens};
use crate::num::parse_decimal;

/// Options of `expand-cycles`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// G73's retract between pecks, mm.
    pub chip_break_retract: f64,
    /// How far above the last peck G83's rapid back down stops, mm.
    pub peck_clearance: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
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

/// The `expand-cycles` pass.
pub struct ExpandCycles {
    options: Options,
    track: Tracker,
    /// A canned cycle is in force: a line with axis words that the frontend did not
    /// resolve (inside control flow, a subprogram body called in the middle of a series)
    /// drills a hole this pass cannot place.
    in_cycle: bool,
}

/// The Z axis alone: what the strokes into and out of a hole write.
fn z_only() -> AxisSet {
    [Axis::Z].into_iter().collect()
}

/// Cycles this pass cannot drill as moves, with why.
fn unexpandable(code: u32) -> Option<&'static str> {
    Some(match code {
        74 | 84 => "tapping needs the controller to reverse the spindle in step with Z",
        86 => "G86 stops the spindle at the bottom",
        87 => "G87 back-boring stops and orients the spindle",
        88 => "G88 waits for a manual retract",
        76 => "G76 needs the controller's spindle orientation or synchronisation",
        _ => return None,
    })
}

/// The G numbers (× 10, rounded: G73 is 730) of the words of `text`.
fn g_codes(text: &str) -> impl Iterator<Item = u32> + '_ {
    tokens(text).filter_map(|(_, t, _)| match t {
        Tok::Word(w) if w.starts_with(['G', 'g']) => {
            parse_decimal(w[1..].trim_start()).map(|v| (v * 10.0).round() as u32)
        }
        _ => None,
    })
}

/// Whether `text` has an X, Y or Z word (comments aside).
fn has_axis_word(text: &str) -> bool {
    tokens(text).any(|(_, t, _)| {
        matches!(t, Tok::Word(w) | Tok::Letter(w)
            if matches!(w.as_bytes()[0].to_ascii_uppercase(), b'X' | b'Y' | b'Z'))
    })
}

/// Whether G code `g` (× 10) is a canned cycle's.
fn is_cycle(g: u32) -> bool {
    matches!(g, 730 | 740 | 760 | 810..=890) && g.is_multiple_of(10)
}

/// `words` without the cycle codes (G80, G98, G99 and the cycles).
fn without_cycle_codes(words: &str) -> String {
    let rest: Vec<&str> = words
        .split_whitespace()
        .filter(|w| {
            let g = w
                .strip_prefix(['G', 'g'])
                .and_then(parse_decimal)
                .map(|v| (v * 10.0).round() as u32);
            !g.is_some_and(|g| matches!(g, 800 | 980 | 990) || is_cycle(g))
        })
        .collect();
    rest.join(" ")
}

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
            in_cycle: false,
        })
    }

    /// One block of the input: puts out what becomes of it.
    /// A move, a comment, a dwell or an offset, changed where it lies: a move ends the
    /// cycle in force, and a G80 written beside it (Mach3 style) leaves its line. False
    /// for commands and verbatim lines, where cycle codes and holes are.
    fn edit(&mut self, block: &mut Block) -> bool {
        match &mut block.kind {
            BlockKind::Command(_) | BlockKind::Verbatim(_) => return false,
            BlockKind::Motion(m) => {
                self.in_cycle = false;
                if !m.extra.is_empty() {
                    let kept = without_cycle_codes(&m.extra);
                    if kept.split_whitespace().count() != m.extra.split_whitespace().count() {
                        m.extra = kept;
                    }
                }
            }
            _ => {}
        }
        self.track.update(block);
        true
    }

    fn block(&mut self, mut block: Block, out: &mut Output<'_>) {
        if self.edit(&mut block) {
            out.push(block);
            return;
        }
        match &mut block.kind {
            BlockKind::Command(c) => {
                let printed = self.command(c);
                // Only cycle codes were on the line: its comments stay, as a comment line.
                if !printed && block.comments.is_empty() {
                    return;
                }
                if !printed {
                    block.kind = BlockKind::Comment;
                }
            }
            BlockKind::Verbatim(v) => {
                let v = v.clone();
                if self.verbatim(&v, &mut block, out) {
                    return;
                }
            }
            _ => {}
        }
        self.track.update(&block);
        out.push(block);
    }

    /// Takes the cycle codes (`G98`, `G99`, `G80`, a cycle code with no hole) out of a
    /// command; false when nothing is left to print.
    fn command(&mut self, c: &mut Command) -> bool {
        let codes: Vec<u32> = g_codes(&c.text).collect();
        self.follow_codes(&codes);
        if !codes
            .iter()
            .any(|&g| matches!(g, 800 | 980 | 990) || is_cycle(g))
        {
            return true;
        }
        c.text = without_cycle_codes(&c.text).into();
        !c.text.is_empty()
    }

    /// A line passed through as text: drills it when it is a resolved cycle (true: its
    /// moves are out), reports it when it is a cycle that cannot be drilled.
    fn verbatim(&mut self, v: &Verbatim, block: &mut Block, out: &mut Output<'_>) -> bool {
        let span = block.span;
        let whole = (0, v.text.len());
        let codes: Vec<u32> = g_codes(&v.text).collect();
        let was_in_cycle = self.in_cycle;
        self.follow_codes(&codes);
        self.in_cycle |= v.cycle.is_some();
        let cycle = match &v.cycle {
            Some(CycleLine::Resolved(c)) => c,
            Some(CycleLine::Unresolved(p)) => {
                Self::error(out, v, span, p.at, p.message.clone(), p.help);
                return false;
            }
            None => {
                let moves = has_axis_word(&v.text);
                if codes.iter().any(|&g| is_cycle(g)) || (was_in_cycle && self.in_cycle && moves) {
                    let help = match v.reason {
                        VerbatimReason::Subprogram => {
                            "expand the subprograms first (--pass expand-subprograms), or write the holes out"
                        }
                        VerbatimReason::ControlFlow => {
                            "write the holes out of the control flow, or leave the cycle to a controller that has it (--emit gcode)"
                        }
                        _ => {
                            "write the holes as plain numbers, start the cycle in the subprogram that lists its holes (expand-subprograms cannot carry a cycle into a call), or write the holes out"
                        }
                    };
                    Self::error(
                        out,
                        v,
                        span,
                        whole,
                        "a canned-cycle line the frontend could not follow (inside control flow or a subprogram body, or with words it could not evaluate) cannot be drilled as moves".into(),
                        help,
                    );
                }
                return false;
            }
        };
        if let Some(why) = unexpandable(cycle.code) {
            let msg = format!("G{} cannot be drilled as G0/G1 moves: {why}", cycle.code);
            Self::error(
                out,
                v,
                span,
                whole,
                msg,
                "leave this cycle to a controller that has it (--emit gcode), or write its moves out in the CAM",
            );
            return false;
        }
        let Some(start) = self.start(cycle) else {
            Self::error(
                out,
                v,
                span,
                whole,
                "the Z position before the canned cycle is not known".into(),
                "move Z to a known height (G0 Z..) before the cycle",
            );
            return false;
        };
        let moves = self.plan(cycle, start);
        let mut comments = Some(std::mem::take(&mut block.comments));
        for kind in moves {
            let mut b = Block::new(span, kind);
            if let Some(c) = comments.take() {
                b.comments = c;
            }
            self.track.update(&b);
            out.push(b);
        }
        if let Some(c) = comments.filter(|c| !c.is_empty()) {
            // K0: no hole; the line's comments stay.
            let mut b = Block::new(span, BlockKind::Comment);
            b.comments = c;
            out.push(b);
        }
        true
    }

    /// Follows the motion codes of a line: a cycle code starts a cycle, `G80` or another
    /// motion code ends it.
    fn follow_codes(&mut self, codes: &[u32]) {
        for &g in codes {
            if is_cycle(g) {
                self.in_cycle = true;
            } else if matches!(g, 0..=30 | 50..=59 | 330..=339 | 380..=389 | 800) {
                self.in_cycle = false;
            }
        }
    }

    /// Where the tool is before the cycle: Z must be known (X and Y may be unknown when
    /// the line writes them in G90: the first rapid goes to the hole).
    fn start(&self, cycle: &CannedCycle) -> Option<Joints> {
        let pos = *self.track.pos();
        (pos.get(Axis::Z).is_some() || cycle.holes.is_empty()).then_some(pos)
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
        // The frontend's warning on the line says less.
        out.diags.retain(|d| {
            !(matches!(d.code, "gcode::cycle" | "gcode::unsupported-motion")
                && d.location.as_ref().is_some_and(|l| l.line == span.line))
        });
        out.diag(
            Diagnostic::error("expand-cycles::cycle", msg)
                .at_bytes(span.line, &v.text, at.0, at.1)
                .with_label("passed through as written")
                .with_help(help.to_string()),
        );
    }

    /// The blocks that drill the holes of `cycle` from `start`.
    fn plan(&self, cycle: &CannedCycle, start: Joints) -> Vec<BlockKind> {
        let mut at = start;
        let mut blocks = Vec::new();
        if cycle.holes.is_empty() {
            return blocks;
        }
        // Preliminary: up to R if below it, once.
        if at.get(Axis::Z).is_some_and(|z| z < cycle.r) {
            at.set(Axis::Z, cycle.r);
            blocks.push(self.go(cycle, MotionKind::Rapid, at, z_only()));
        }
        for &[x, y] in &cycle.holes {
            let mut moved = AxisSet::EMPTY;
            for (a, v) in [(Axis::X, x), (Axis::Y, y)] {
                if at.get(a) != Some(v) {
                    at.set(a, v);
                    moved.insert(a);
                }
            }
            if !moved.is_empty() {
                blocks.push(self.go(cycle, MotionKind::Rapid, at, moved));
            }
            self.hole(cycle, &mut at, &mut blocks);
        }
        blocks
    }

    /// The moves of one hole from the R-plane approach to the retract; `at` is where the
    /// tool is.
    fn hole(&self, cycle: &CannedCycle, at: &mut Joints, blocks: &mut Vec<BlockKind>) {
        let (r, bottom, clear) = (cycle.r, cycle.bottom, cycle.clear);
        if at.get(Axis::Z) != Some(r) {
            self.z_to(cycle, MotionKind::Rapid, r, at, blocks);
        }
        match (cycle.code, cycle.q) {
            (73 | 83, Some(q)) => {
                // LinuxCNC: feed down by Q from R; G83 rapids out to R and back down to
                // `peck_clearance` above the last depth, G73 rapids up `chip_break_retract`.
                let mut depth = r;
                while depth > bottom {
                    let next = (depth - q).max(bottom);
                    if depth < r && cycle.code == 83 {
                        let near = (depth + self.options.peck_clearance).min(r);
                        self.z_to(cycle, MotionKind::Rapid, near, at, blocks);
                    }
                    self.z_to(cycle, MotionKind::Linear, next, at, blocks);
                    depth = next;
                    if depth > bottom {
                        let up = if cycle.code == 83 {
                            r
                        } else {
                            (depth + self.options.chip_break_retract).min(r)
                        };
                        self.z_to(cycle, MotionKind::Rapid, up, at, blocks);
                    }
                }
            }
            _ => self.z_to(cycle, MotionKind::Linear, bottom, at, blocks),
        }
        if let (82 | 89, Some(seconds)) = (cycle.code, cycle.dwell) {
            blocks.push(BlockKind::Dwell { seconds });
        }
        match cycle.code {
            // LinuxCNC's G85 feeds out to R only, then rapids to the retract level.
            85 => {
                self.z_to(cycle, MotionKind::Linear, r, at, blocks);
                if clear != r {
                    self.z_to(cycle, MotionKind::Rapid, clear, at, blocks);
                }
            }
            89 => self.z_to(cycle, MotionKind::Linear, clear, at, blocks),
            _ => self.z_to(cycle, MotionKind::Rapid, clear, at, blocks),
        }
    }

    /// A Z move to `z`.
    fn z_to(
        &self,
        cycle: &CannedCycle,
        kind: MotionKind,
        z: f64,
        at: &mut Joints,
        blocks: &mut Vec<BlockKind>,
    ) {
        at.set(Axis::Z, z);
        blocks.push(self.go(cycle, kind, *at, z_only()));
    }

    /// A move to `to` naming `written`, at the cycle's feed.
    fn go(&self, cycle: &CannedCycle, kind: MotionKind, to: Joints, written: AxisSet) -> BlockKind {
        // The cycle's moves are in the program frame and carry no other words.
        BlockKind::Motion(Motion {
            kind,
            target: Target::Joints(to),
            feed: cycle.feed,
            written,
            machine_frame: false,
            extra: String::new(),
        })
    }
}

impl Pass for ExpandCycles {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        // Moves and comments, most of a program and all of CL data, stay where they lie.
        super::edit_in_place(self, blocks, out, |p, b, _| p.edit(b), Self::block);
    }
}
