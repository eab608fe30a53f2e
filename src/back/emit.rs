//! The emitter's words, lines, comments and modes, and the blocks other than moves
//! and pass-through text.

use std::io::Write;

use super::{CommentOutput, Emitter, Flavor, Format, Line, Modes, grbl, io_error, too_large};
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, Block, BlockKind, Comment, CommentStyle, FeedMode, Joints, Motion,
    MotionKind, OffsetChange, Tracker,
};
use crate::num::print::to_units;

impl<W: Write> Emitter<W> {
    pub(crate) fn new(out: W, flavor: Flavor, fmt: Format) -> Self {
        Emitter {
            out,
            flavor,
            line: Line::new(),
            number: 0,
            modes: Modes::default(),
            printed: [None; AXIS_COUNT],
            // Like the frontend, the extruder's logical position starts at 0.
            track: Tracker::at({
                let mut p = Joints::default();
                p.set(Axis::E, 0.0);
                p
            }),
            e_units: Some(0),
            span: crate::ir::Span::default(),
            grbl_quiet: false,
            axis_decimals: Axis::ALL.map(|a| fmt.decimals.axis(a)),
            fmt,
        }
    }

    pub(super) fn word(
        &mut self,
        letter: char,
        value: f64,
        decimals: u8,
        block: &Block,
    ) -> Result<(), Diagnostic> {
        let units = to_units(value, decimals).ok_or_else(|| too_large(letter, value, block))?;
        self.word_units(letter, units, decimals);
        Ok(())
    }

    /// `letter` is a word letter (an axis, `F`, `I`/`J`/`K`, `P`): always ASCII.
    pub(super) fn word_units(&mut self, letter: char, units: i64, decimals: u8) {
        debug_assert!(letter.is_ascii(), "word letter {letter:?}");
        self.line
            .push_word(letter as u8, units, decimals, self.fmt.trim_zeros);
    }

    pub(super) fn space(&mut self) {
        if !self.line.is_empty() {
            self.line.push(' ');
        }
    }

    pub(super) fn text(&mut self, s: &str) {
        self.space();
        self.line.push_str(s);
    }

    /// Ends the current line, adding line number and checksum when configured, then
    /// the comments.
    pub(super) fn end_line(
        &mut self,
        comments: &[Comment],
        numbered: bool,
    ) -> Result<(), Diagnostic> {
        // Most lines have no comment, number, checksum or length limit: those end with
        // the newline alone, without the comment bookkeeping below.
        if comments.is_empty()
            && !(numbered && (self.fmt.line_numbers || self.fmt.checksums))
            && !matches!(self.flavor, Flavor::Grbl(_))
        {
            if !self.line.is_empty() {
                self.line.finish(&mut self.out).map_err(io_error)?;
            }
            return Ok(());
        }
        let mut comments = comments;
        if self.fmt.comments == CommentOutput::Strip {
            comments = &[];
        }
        let body_empty = self.line.is_empty();
        if !body_empty {
            if numbered && self.fmt.line_numbers {
                self.number += 1;
                let prefix = format!("N{} ", self.number);
                self.line.insert_str(0, &prefix);
            }
            if numbered && self.fmt.checksums {
                let cs = self.line.as_bytes().iter().fold(0u8, |a, b| a ^ b);
                self.line.push('*');
                self.line.push_str(itoa::Buffer::new().format(cs));
            }
        }
        // A checksummed line carries no comment; one `;` comment per line at most.
        let mut own_lines: &[Comment] = &[];
        let inline_allowed = !(numbered && self.fmt.checksums) || body_empty;
        if inline_allowed {
            let mut used_semicolon = false;
            for (i, c) in comments.iter().enumerate() {
                let style = self.comment_style(c);
                if used_semicolon {
                    own_lines = &comments[i..];
                    break;
                }
                if style == CommentStyle::Semicolon
                    && self.fmt.comments == CommentOutput::Semicolon
                    && i + 1 < comments.len()
                {
                    // Only the last inline comment may be a `;` comment.
                    self.push_comment(c, style);
                    own_lines = &comments[i + 1..];
                    break;
                }
                self.push_comment(c, style);
                used_semicolon = style == CommentStyle::Semicolon;
            }
        } else {
            own_lines = comments;
        }
        if !self.line.is_empty() {
            if let Flavor::Grbl(_) = self.flavor {
                let n = grbl::counted_length(&self.line.text());
                if n > grbl::LINE_LIMIT {
                    let text = self.line.text().into_owned();
                    self.line.clear();
                    return Err(Diagnostic::error(
                        "grbl::line-length",
                        format!(
                            "`{text}` is {n} characters for Grbl (spaces and comments not counted); Grbl holds at most {} and skips a longer line (error:11)",
                            grbl::LINE_LIMIT
                        ),
                    )
                    .at_span(self.span)
                    .with_help("shorten the line: fewer `decimals`, no `line_numbers`, or split the command"));
                }
            }
            self.line.finish(&mut self.out).map_err(io_error)?;
        }
        for c in own_lines {
            let style = self.comment_style(c);
            self.push_comment(c, style);
            self.line.finish(&mut self.out).map_err(io_error)?;
        }
        Ok(())
    }

    pub(super) fn comment_style(&self, c: &Comment) -> CommentStyle {
        let wanted = match self.fmt.comments {
            CommentOutput::AsInput | CommentOutput::Strip => c.style,
            CommentOutput::Semicolon => CommentStyle::Semicolon,
            CommentOutput::Paren => CommentStyle::Paren,
        };
        if wanted == CommentStyle::Paren && !balanced(&c.text) {
            CommentStyle::Semicolon
        } else {
            wanted
        }
    }

    pub(super) fn push_comment(&mut self, c: &Comment, style: CommentStyle) {
        if !self.line.is_empty() {
            self.line.push(' ');
        }
        match style {
            CommentStyle::Paren => {
                self.line.push('(');
                self.line.push_str(&c.text);
                self.line.push(')');
            }
            CommentStyle::Semicolon => {
                self.line.push(';');
                self.line.push_str(&c.text);
            }
        }
    }

    /// Prints the mode words the controller needs before a move, on their own line.
    pub(super) fn ensure_modes(
        &mut self,
        motion: &Motion,
        e_mode: Option<bool>,
        block: &Block,
    ) -> Result<(), Diagnostic> {
        // The extruder mode goes on its own line, first: read back, it is a command of its
        // own, and printing it first keeps the text a fixpoint of parse and print.
        if let Some(relative) = e_mode
            && self.modes.e_relative != Some(relative)
        {
            self.line.push_str(if relative { "M83" } else { "M82" });
            self.end_line(&[], true)?;
            self.modes.e_relative = Some(relative);
        }
        let mut setup = String::new();
        if self.modes.metric != Some(true) {
            setup.push_str("G21 ");
            self.modes.metric = Some(true);
        }
        if self.modes.absolute != Some(true) {
            setup.push_str("G90 ");
            self.modes.absolute = Some(true);
        }
        if !matches!(motion.kind, MotionKind::Rapid)
            && self.modes.feed_mode != Some(motion.feed.mode)
        {
            if let (
                Flavor::Rrf {
                    inverse_time: false,
                    ..
                },
                FeedMode::InverseTime,
            ) = (self.flavor, motion.feed.mode)
            {
                return Err(Diagnostic::error(
                    "rrf::inverse-time",
                    "inverse time feed (G93) needs RepRapFirmware 3.5 or newer",
                )
                .at_span(block.span)
                .with_help(
                    "set `inverse_time = true` in the rrf backend options if the firmware is 3.5+",
                ));
            }
            if let (Flavor::Grbl(g), FeedMode::InverseTime) = (self.flavor, motion.feed.mode)
                && !g.allow_g93
            {
                return Err(Diagnostic::error(
                    "grbl::inverse-time",
                    "inverse time feed (G93) is not allowed for this Grbl output",
                )
                .at_span(block.span)
                .with_help(
                    "Grbl 1.1 runs G93: set `allow_g93 = true` in the [grbl] options if these inverse-time feeds were computed for this machine; otherwise leave out the pass that made them (feed with `mode = \"g93\"`)",
                ));
            }
            if let (Flavor::Grbl(_), FeedMode::PerRevolution) = (self.flavor, motion.feed.mode) {
                return Err(Diagnostic::error(
                    "grbl::feed-per-rev",
                    "Grbl has no feed per revolution (G95)",
                )
                .at_span(block.span)
                .with_help("convert the feeds to mm/min for this spindle speed"));
            }
            if let (Flavor::Rrf { .. }, FeedMode::PerRevolution) = (self.flavor, motion.feed.mode) {
                return Err(Diagnostic::error(
                    "rrf::feed-per-rev",
                    "RepRapFirmware has no feed per revolution (G95)",
                )
                .at_span(block.span)
                .with_help("convert the feeds to mm/min for this spindle speed"));
            }
            setup.push_str(match motion.feed.mode {
                FeedMode::PerMinute => "G94 ",
                FeedMode::InverseTime => "G93 ",
                FeedMode::PerRevolution => "G95 ",
            });
            self.modes.feed_mode = Some(motion.feed.mode);
            self.modes.feed = None;
        }
        if let MotionKind::Arc(arc) = motion.kind
            && self.modes.plane != Some(arc.plane)
        {
            setup.push_str(arc.plane.gcode());
            setup.push(' ');
            self.modes.plane = Some(arc.plane);
        }

        if !setup.is_empty() {
            self.line.push_str(setup.trim_end());
            self.end_line(&[], true)?;
        }
        Ok(())
    }

    pub(super) fn offset(
        &mut self,
        block: &Block,
        change: &OffsetChange,
    ) -> Result<(), Diagnostic> {
        if let Flavor::Grbl(_) = self.flavor
            && matches!(
                change.code,
                crate::ir::OffsetCode::Suspend | crate::ir::OffsetCode::Restore
            )
        {
            return Err(Diagnostic::error(
                "grbl::offset",
                format!(
                    "Grbl has no {} (it knows G92 and G92.1)",
                    change.code.gcode()
                ),
            )
            .at_span(block.span)
            .with_help("add the `normalize` pass, which folds G92 offsets into the coordinates"));
        }
        // The declared values are millimetres.
        if !change.declared.known.is_empty() && self.modes.metric != Some(true) {
            self.text("G21");
            self.modes.metric = Some(true);
        }
        self.text(change.code.gcode());
        for a in change.declared.known.iter() {
            let v = change.declared.values[a.index()];
            self.word(a.letter(), v, self.axis_decimals[a.index()], block)?;
        }
        self.end_line(&block.comments, true)?;
        let declared = self.track.offset(change);
        let (pos, offsets) = (*self.track.pos(), *self.track.offsets());
        for a in Axis::ALL {
            let i = a.index();
            self.printed[i] = if declared.contains(a) {
                to_units(change.declared.values[i], self.axis_decimals[i])
            } else {
                pos.get(a)
                    .and_then(|v| to_units(v + offsets[i], self.axis_decimals[i]))
            };
        }
        if declared.contains(Axis::E) {
            self.e_units = pos
                .get(Axis::E)
                .and_then(|v| to_units(v, self.fmt.decimals.extruder));
        }
        Ok(())
    }

    pub(super) fn forget(&mut self, axes: crate::ir::AxisSet) {
        for a in axes.iter() {
            self.printed[a.index()] = None;
            if a == Axis::E {
                self.e_units = None;
            }
        }
        self.track.forget(axes);
    }

    pub(crate) fn block(
        &mut self,
        block: &Block,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        self.span = block.span;
        if !matches!(&block.kind, BlockKind::Verbatim(v) if matches!(v.reason, crate::ir::VerbatimReason::Subprogram | crate::ir::VerbatimReason::ControlFlow))
        {
            self.grbl_quiet = false;
        }
        match &block.kind {
            BlockKind::Motion(m) => self.motion(block, m),
            BlockKind::Dwell { seconds } => {
                self.text("G4");
                if self.fmt.dwell_milliseconds {
                    // RepRapFirmware, Marlin and Fanuc read `G4 P` as whole milliseconds:
                    // a fraction would be cut off (or refused) by the controller.
                    self.word('P', seconds * 1000.0, 0, block)?;
                } else {
                    self.word('P', *seconds, 3, block)?;
                }
                self.end_line(&block.comments, true)
            }
            BlockKind::Offset(o) => self.offset(block, o),
            BlockKind::Command(c) => self.command(block, c, diags),
            BlockKind::Verbatim(v) => self.verbatim(block, v, diags),
            BlockKind::Comment => self.end_line(&block.comments, false),
        }
    }

    /// Hands the finished lines to the writer.
    pub(crate) fn hand_out(&mut self) -> Result<(), Diagnostic> {
        self.line.write_finished(&mut self.out).map_err(io_error)
    }

    pub(crate) fn flush(&mut self) -> Result<(), Diagnostic> {
        self.hand_out()?;
        self.out.flush().map_err(io_error)
    }
}

/// Whether a comment can be written in parentheses.
fn balanced(text: &str) -> bool {
    !text.contains(['(', ')'])
}
