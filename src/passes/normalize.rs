//! `normalize`: absolute millimetres with G92 folded in; the output has no G92, G91 or G20, its coordinates are the ones the machine moves in.
//!
//! # What the IR already does
//! The frontend resolves G90/G91, G20/G21 and G92 (invariant 2 of [`crate::ir`]): every
//! motion target is absolute, in mm, in the *program frame without G92 offsets*. The
//! backend prints G21 G90 before moves and adds the offsets of the last
//! [`OffsetChange`](crate::ir::OffsetChange) back when printing, so that a G92 program
//! prints in its own shifted frame. What remains for this pass is the G92 blocks
//! themselves and the lines the IR carries as words or text.
//!
//! # What folding means
//! The output frame is the IR frame: the frame in force when an axis first became known.
//! - A `G92` that declares an axis whose position has never been known (the seed's
//!   `G92 X0 Y0 Z0` at program start, or `G92 E0` before the first E move) **defines the
//!   output frame** for that axis: the current, unknown, position is its declared value.
//!   The frontend already takes that frame for the IR (offset 0), so the G92 is removed
//!   and replaced by a comment saying so: the operator sets the work origin there (as the
//!   seed's operator zeroes X, Y and Z on the board corner).
//! - A `G92` of axes whose position is known, and `G92.1`, `G92.2`, `G92.3`, are **folded**:
//!   the block is removed (a comment records it) and later coordinates are printed
//!   unshifted, in the frame the machine has been moving in. Example: `G0 X10`, `G92 X0`,
//!   `G1 X5` prints `G0 X10`, `G1 X15`.
//! - A `G92` of an axis that was known and then became unknown (after homing, probing or a
//!   line passed through as text) declares a new frame that cannot be related to the
//!   output frame: error `normalize::g92-unknown`.
//! - Commands with coordinates the controller reads as positions (`G28`, `G30` via points,
//!   `G38.2`..`G38.5` probe targets) are rewritten into absolute mm in the output frame:
//!   inch values (and the command's F) times 25.4, relative values added to the known
//!   position (error `normalize::relative-unknown` when it is not known), G92 offsets
//!   taken off. Any other command with coordinates written in inches, in G91 or under a
//!   G92 offset (`G10 L20`, ...) is the error `normalize::command`.
//! - Lines passed through as text (`G1 X[#1]`, o-word bodies) cannot be rewritten: one with
//!   axis words written in inches, in G91 or under a G92 offset, or one that itself holds
//!   G20, G91 or G92, is the error `normalize::verbatim`; one without axis words is
//!   printed without switching the controller into inches or G91.
//!
//! E is folded like the other axes: after `G92 E0` the extruder's coordinates keep
//! growing (absolute E of the whole program), which is what the machine moves.
//!
//! # Options
//! None (an empty table).
//!
//! # Limits
//! An arc that is the first move after a removed origin-declaring G92 needs its start
//! from a move: the backend reports `back::arc-start` (put `linearize-arcs` first or
//! move before the arc).

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Command, Comment, CommentStyle, OffsetChange, OffsetCode,
    Span, Tracker, Verbatim, WrittenModes,
};

/// Options of `normalize` (none).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "normalize",
    summary: "absolute mm with G92 folded in: no G92, G91 or G20 in the output",
    build: |t, _ctx| {
        let _: Options = super::options(t)?;
        Ok(Box::new(Normalize::default()))
    },
    defaults: || super::to_toml(&Options::default()),
};

const MM_PER_INCH: f64 = 25.4;

/// The `normalize` pass.
#[derive(Debug, Default)]
pub struct Normalize {
    /// The IR position and the G92 offsets in force in the source (program = IR +
    /// offset).
    track: Tracker,
    /// Axes that have been known at some point.
    ever_known: AxisSet,
}

/// One `letter value` word of a command's text.
fn split_word(w: &str) -> Option<(char, &str)> {
    let mut chars = w.chars();
    let letter = chars.next()?.to_ascii_uppercase();
    letter
        .is_ascii_alphabetic()
        .then_some((letter, chars.as_str()))
}

/// The G codes of a line (numbers after `G` outside comments), as written.
fn g_codes(text: &str) -> Vec<f64> {
    let mut codes = Vec::new();
    let bytes = text.as_bytes();
    let mut i = 0;
    let mut depth = 0usize;
    while i < bytes.len() {
        let b = bytes[i];
        match b {
            b'(' => depth += 1,
            b')' => depth = depth.saturating_sub(1),
            b';' if depth == 0 => break,
            b'G' | b'g' if depth == 0 => {
                let start = i + 1;
                let mut end = start;
                while end < bytes.len() && (bytes[end].is_ascii_digit() || bytes[end] == b'.') {
                    end += 1;
                }
                if let Some(v) = text.get(start..end).and_then(crate::num::parse_decimal) {
                    codes.push(v);
                }
                i = end;
                continue;
            }
            _ => {}
        }
        i += 1;
    }
    codes
}

/// Whether a line names any axis word (outside comments).
fn has_axis_word(text: &str) -> bool {
    Axis::ALL
        .iter()
        .any(|a| crate::num::lexer::has_word(text, a.letter()))
}

impl Normalize {
    fn note(block: &mut Block, text: String) {
        block.comments.insert(
            0,
            Comment {
                text: format!(" normalize: {text}"),
                style: CommentStyle::Semicolon,
            },
        );
    }

    fn offset_in_use(&self, text: &str) -> bool {
        Axis::ALL.iter().any(|a| {
            self.track.offsets()[a.index()] != 0.0 && crate::num::lexer::has_word(text, a.letter())
        })
    }

    /// Rewrites the coordinates of a positional command (G28, G30, G38.x) into absolute
    /// mm in the output frame.
    fn rewrite_command(
        &self,
        text: &str,
        modes: WrittenModes,
        span: crate::ir::Span,
    ) -> Result<String, Diagnostic> {
        let unit = if modes.inch { MM_PER_INCH } else { 1.0 };
        let mut words = Vec::new();
        for w in text.split_whitespace() {
            let Some((letter, num)) = split_word(w) else {
                words.push(w.to_string());
                continue;
            };
            let value = crate::num::parse_decimal(num);
            match (Axis::from_letter(letter), value) {
                (Some(axis), Some(v)) => {
                    let scale = if axis.is_rotary() { 1.0 } else { unit };
                    let mm = v * scale;
                    let ir = if modes.relative {
                        match self.track.pos().get(axis) {
                            Some(p) => p + mm,
                            None => {
                                return Err(Diagnostic::error(
                                    "normalize::relative-unknown",
                                    format!(
                                        "`{w}` is relative (G91) but the position of {} is not known here, so it cannot be made absolute",
                                        axis.letter()
                                    ),
                                )
                                .at_span(span)
                                .with_help("move the axis to an absolute position before this line, or leave normalize out"));
                            }
                        }
                    } else {
                        mm - self.track.offsets()[axis.index()]
                    };
                    words.push(format!("{}{}", axis.letter(), fmt_num(ir)));
                }
                (None, Some(v)) if letter == 'F' && modes.inch => {
                    words.push(format!("F{}", fmt_num(v * MM_PER_INCH)));
                }
                _ => words.push(w.to_string()),
            }
        }
        Ok(words.join(" "))
    }
}

/// A number for a rewritten word: up to 6 decimals, no trailing zeros.
fn fmt_num(v: f64) -> String {
    let s = format!("{:.6}", v);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" || s.is_empty() {
        "0".to_string()
    } else {
        s.to_string()
    }
}

impl Normalize {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, mut block: Block, out: &mut Output<'_>) {
        let span = block.span;
        match &mut block.kind {
            BlockKind::Offset(change) => {
                let note = self.offset(change, span, out);
                let comments = std::mem::take(&mut block.comments);
                let mut b = Block {
                    span: block.span,
                    kind: BlockKind::Comment,
                    comments,
                };
                Self::note(&mut b, note);
                out.push(b);
                return;
            }
            BlockKind::Motion(m) => {
                self.track.motion(m);
                self.ever_known = self.ever_known.union(self.track.pos().known);
            }
            BlockKind::Command(cmd) => self.command(cmd, span, out),
            BlockKind::Verbatim(v) => self.verbatim(v, span, out),
            _ => {}
        }
        out.push(block);
    }

    /// Folds a G92-family change into the coordinates; returns the note that takes its
    /// place.
    fn offset(&mut self, change: &OffsetChange, span: Span, out: &mut Output<'_>) -> String {
        let written: Vec<String> = change
            .declared
            .known
            .iter()
            .map(|a| {
                format!(
                    "{}{}",
                    a.letter(),
                    fmt_num(change.declared.values[a.index()])
                )
            })
            .collect();
        let code = change.code;
        let what = if written.is_empty() {
            code.gcode().to_string()
        } else {
            format!("{} {}", code.gcode(), written.join(" "))
        };
        let mut declares = Vec::new();
        if code == OffsetCode::Set {
            for a in change.declared.known.iter() {
                if self.track.pos().get(a).is_some() {
                    continue;
                }
                if self.ever_known.contains(a) {
                    out.diag(
                        Diagnostic::error(
                            "normalize::g92-unknown",
                            format!(
                                "`{what}` declares {} after its position became unknown; the frame it defines cannot be folded into the output's",
                                a.letter()
                            ),
                        )
                        .at_span(span)
                        .with_help("move the axis to an absolute position before the G92 (so it shifts a known frame), or leave normalize out to keep the G92"),
                    );
                }
                declares.push(a);
                self.ever_known.insert(a);
            }
        }
        self.track.offset(change);
        if declares.is_empty() {
            format!("`{what}` folded into the coordinates")
        } else {
            let axes: String = declares.iter().map(|a| a.letter()).collect();
            format!(
                "`{what}` removed: it declares the origin of {axes} here; set the work origin at this position"
            )
        }
    }

    /// Rewrites the coordinates of a positional command (G28, G30, G38.x) into the
    /// output's modes, or reports one it cannot rewrite.
    fn command(&mut self, cmd: &mut Command, span: Span, out: &mut Output<'_>) {
        if let Some(modes) = cmd.modes {
            let odd = modes.inch || modes.relative || self.offset_in_use(&cmd.text);
            if odd {
                let codes = g_codes(&cmd.text);
                let positional = !codes.is_empty()
                    && codes.iter().all(|&c| {
                        c == 28.0
                            || c == 30.0
                            || (c > 38.0 && c < 39.0)
                            || c == 90.0
                            || c == 91.0
                            || c == 20.0
                            || c == 21.0
                    })
                    && codes
                        .iter()
                        .any(|&c| c == 28.0 || c == 30.0 || (c > 38.0 && c < 39.0));
                if !positional {
                    out.diag(
                        Diagnostic::error(
                            "normalize::command",
                            format!(
                                "`{}` has coordinates written in {}; normalize cannot rewrite this command",
                                cmd.text,
                                if modes.inch { "inches" } else if modes.relative { "relative mode (G91)" } else { "a G92-shifted frame" }
                            ),
                        )
                        .at_span(span)
                        .with_help("only G28, G30 and G38.x positions are rewritten; write this line in G21 G90 without G92, or leave normalize out"),
                    );
                } else {
                    match self.rewrite_command(&cmd.text, modes, span) {
                        Ok(t) => {
                            cmd.text = t.into();
                            cmd.modes = Some(WrittenModes {
                                inch: false,
                                relative: false,
                                ..modes
                            });
                        }
                        Err(d) => out.diag(d),
                    }
                }
            }
        }
        self.track.forget(cmd.clobbers);
    }

    /// Puts a line passed through as text into the output's modes, or reports one that
    /// depends on modes normalize removes.
    fn verbatim(&mut self, v: &mut Verbatim, span: Span, out: &mut Output<'_>) {
        let codes = g_codes(&v.text);
        let mode_codes = codes
            .iter()
            .any(|&c| c == 20.0 || c == 91.0 || (92.0..93.0).contains(&c));
        let axes = has_axis_word(&v.text);
        let odd_modes = v.modes.is_some_and(|m| m.inch || m.relative);
        let shifted = self.offset_in_use(&v.text);
        if mode_codes || (axes && (odd_modes || shifted)) {
            out.diag(
                Diagnostic::error(
                    "normalize::verbatim",
                    format!(
                        "`{}` passes through as text and {}; normalize cannot rewrite it",
                        v.text,
                        if mode_codes {
                            "holds G20, G91 or G92"
                        } else if odd_modes {
                            "has axis words in inches or relative mode"
                        } else {
                            "has axis words in a G92-shifted frame"
                        }
                    ),
                )
                .at_span(span)
                .with_help("write the line in G21 G90 with plain numbers (no parameters or expressions), or leave normalize out"),
            );
        } else if let Some(m) = &mut v.modes {
            m.inch = false;
            m.relative = false;
        }
        self.track.verbatim(v);
    }
}

impl Pass for Normalize {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn g_codes_skip_comments() {
        assert_eq!(g_codes("G91 G28 Z0 (G20)"), vec![91.0, 28.0]);
        assert_eq!(g_codes("g38.2 z-1 ; G92"), vec![38.2]);
    }

    #[test]
    fn numbers() {
        assert_eq!(fmt_num(25.4), "25.4");
        assert_eq!(fmt_num(-0.0000001), "0");
        assert_eq!(fmt_num(3.0), "3");
    }
}
