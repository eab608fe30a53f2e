//! Backends: IR blocks to text, written as they arrive.
//!
//! [`rrf`] (RepRapFirmware 3.x, CNC mode), [`gcode`] (plain ISO/LinuxCNC) and [`grbl`]
//! (Grbl 1.1, the plain emitter restricted to Grbl's words) share one emitter that prints absolute millimetre coordinates at fixed precision and elides modal
//! words (motion code, feed, plane, units, distance mode) and unchanged axes. [`ir`] prints
//! the IR text dump.

pub mod gcode;
pub mod grbl;
pub mod ir;
pub mod rrf;

use std::io::Write;

use serde::{Deserialize, Serialize};

use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, AxisSet, Block, BlockKind, Comment, CommentStyle, FeedMode, Joints, Motion,
    MotionKind, OffsetChange, Plane, Target, Tracker,
};
use crate::num::print as number;
pub use crate::num::print::{Decimals, remember_printed};
use number::{put_number, to_units};

/// Writing stopped because the output cannot be written (a full disk, a closed pipe); the
/// diagnostic that says so is in the list of the call that stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputLost;

/// A sink for IR blocks.
pub trait Backend {
    /// Writes one block. An `Err` is a diagnostic about the block (an IR the backend
    /// cannot express) or an I/O failure.
    fn write_block(&mut self, block: &Block, diags: &mut Vec<Diagnostic>)
    -> Result<(), Diagnostic>;
    /// Writes `blocks` in order, adding every diagnostic to `diags`; stops at an I/O
    /// failure, when nothing more can be written. By default one [`Backend::write_block`]
    /// after the other; a backend may hand the batch's text to its writer in one piece
    /// (where [`Backend::write_block`] hands each block's text over as it returns).
    fn write_batch(
        &mut self,
        blocks: &[Block],
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), OutputLost> {
        each_block(blocks, diags, |b, d| self.write_block(b, d))
    }
    /// Flushes the output at the end of the program.
    fn finish(&mut self) -> Result<(), Diagnostic>;
}

/// How comments are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CommentOutput {
    /// As in the source: `( )` or `;`.
    AsInput,
    /// Always `;`.
    Semicolon,
    /// Always `( )` (a comment containing parentheses falls back to `;`).
    Paren,
    /// Comments are dropped (smallest output for controllers with little memory).
    Strip,
}

/// How the extruder axis is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Extrusion {
    /// M83: each move's E is its own length; rounding never accumulates.
    Relative,
    /// M82: E is a running position.
    Absolute,
}

/// Settings both G-code backends share.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Format {
    pub decimals: Decimals,
    pub trim_zeros: bool,
    pub comments: CommentOutput,
    pub line_numbers: bool,
    pub checksums: bool,
    pub modal_motion: bool,
    pub extrusion: Extrusion,
    pub dwell_milliseconds: bool,
}

/// Which controller the text is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Flavor {
    Rrf {
        inverse_time: bool,
        unsupported: rrf::Unsupported,
    },
    Plain,
    Grbl(grbl::Settings),
}

/// What the controller is known to be in after what has been printed. `None` means
/// unknown (program start, or after a line passed through as text).
#[derive(Debug, Clone, Default)]
struct Modes {
    metric: Option<bool>,
    absolute: Option<bool>,
    plane: Option<Plane>,
    feed_mode: Option<FeedMode>,
    feed: Option<i64>,
    motion: Option<&'static str>,
    e_relative: Option<bool>,
}

/// The line being printed, after the finished lines not yet handed to the writer: bytes
/// that are always ASCII or whole UTF-8 characters (only `char`s, `str`s and numbers go
/// in). Finished lines go to the writer after each block written alone, after each
/// batch, and whenever they fill [`Line::CHUNK`]: one `write_all` and one copy per line
/// cost more than the printing of a short line.
struct Line {
    /// Initialized beyond `end`, so that a number is built in place (see
    /// [`put_number`]) without growing the vector for every word.
    bytes: Vec<u8>,
    /// Where the current line starts in `bytes`.
    start: usize,
    /// Where the current line ends in `bytes`.
    end: usize,
}

impl Line {
    /// How many finished bytes are kept before they are written.
    const CHUNK: usize = 1 << 16;

    fn new() -> Line {
        Line {
            bytes: vec![0; Self::CHUNK + 1024],
            start: 0,
            end: 0,
        }
    }
    /// `bytes[end..end + n]`, grown when the line needs it.
    fn room(&mut self, n: usize) -> &mut [u8] {
        if self.end + n > self.bytes.len() {
            self.bytes.resize(self.end + n + 1024, 0);
        }
        &mut self.bytes[self.end..self.end + n]
    }
    fn push(&mut self, c: char) {
        self.push_str(c.encode_utf8(&mut [0; 4]));
    }
    fn push_str(&mut self, s: &str) {
        self.room(s.len()).copy_from_slice(s.as_bytes());
        self.end += s.len();
    }
    /// Appends the word `letter` `units * 10^-decimals`, after a space unless the line
    /// is empty.
    fn push_word(&mut self, letter: u8, units: i64, decimals: u8, trim: bool) {
        debug_assert!(letter.is_ascii());
        let spaced = !self.is_empty();
        let room = self.room(number::ROOM);
        let len = if spaced {
            put_number(room, [b' ', letter], 2, units, decimals, trim)
        } else {
            put_number(room, [letter, 0], 1, units, decimals, trim)
        };
        self.end += len;
    }
    fn is_empty(&self) -> bool {
        self.end == self.start
    }
    /// Drops the current line.
    fn clear(&mut self) {
        self.end = self.start;
    }
    /// Inserts `s` at byte `at` of the current line.
    fn insert_str(&mut self, at: usize, s: &str) {
        let at = self.start + at;
        self.room(s.len());
        self.bytes.copy_within(at..self.end, at + s.len());
        self.bytes[at..at + s.len()].copy_from_slice(s.as_bytes());
        self.end += s.len();
    }
    /// The current line.
    fn as_bytes(&self) -> &[u8] {
        &self.bytes[self.start..self.end]
    }
    /// The current line as text (for messages).
    fn text(&self) -> std::borrow::Cow<'_, str> {
        String::from_utf8_lossy(self.as_bytes())
    }
    /// Ends the current line with a newline; writes the finished lines to `out` once
    /// they fill a chunk.
    fn finish(&mut self, out: &mut impl Write) -> std::io::Result<()> {
        self.push_str("\n");
        self.start = self.end;
        if self.start >= Self::CHUNK {
            self.write_finished(out)?;
        }
        Ok(())
    }
    /// Writes the finished lines to `out` (the current line stays).
    fn write_finished(&mut self, out: &mut impl Write) -> std::io::Result<()> {
        out.write_all(&self.bytes[..self.start])?;
        self.bytes.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        Ok(())
    }
}

/// The shared G-code emitter.
pub(crate) struct Emitter<W: Write> {
    out: W,
    flavor: Flavor,
    fmt: Format,
    line: Line,
    number: u64,
    modes: Modes,
    /// Last printed program-frame value per axis, in print units.
    printed: [Option<i64>; AXIS_COUNT],
    /// IR-frame position after the last block, and the G92 offsets printing adds.
    track: Tracker,
    /// Running E in print units (IR frame), for relative extrusion.
    e_units: Option<i64>,
    /// The span of the block being printed (for line-length errors).
    span: crate::ir::Span,
    /// Grbl: inside a subprogram or control-flow run already reported (its further
    /// lines are not reported one by one).
    grbl_quiet: bool,
    /// `fmt.decimals.axis(a)` for every axis, looked up by index.
    axis_decimals: [u8; AXIS_COUNT],
}

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

    fn word(
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
    fn word_units(&mut self, letter: char, units: i64, decimals: u8) {
        debug_assert!(letter.is_ascii(), "word letter {letter:?}");
        self.line
            .push_word(letter as u8, units, decimals, self.fmt.trim_zeros);
    }

    fn space(&mut self) {
        if !self.line.is_empty() {
            self.line.push(' ');
        }
    }

    fn text(&mut self, s: &str) {
        self.space();
        self.line.push_str(s);
    }

    /// Ends the current line, adding line number and checksum when configured, then
    /// the comments.
    fn end_line(&mut self, comments: &[Comment], numbered: bool) -> Result<(), Diagnostic> {
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

    fn comment_style(&self, c: &Comment) -> CommentStyle {
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

    fn push_comment(&mut self, c: &Comment, style: CommentStyle) {
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
    fn ensure_modes(
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

    fn motion(&mut self, block: &Block, motion: &Motion) -> Result<(), Diagnostic> {
        let target = match &motion.target {
            Target::Joints(j) => j,
            Target::Pose(_) => {
                return Err(Diagnostic::error(
                    "back::pose",
                    "a tool pose reached the backend, which prints joint values",
                )
                .at_span(block.span)
                .with_help("add the `ik` pass to the pipeline for CL input"));
            }
        };
        // Work out the axis words first: the mode line depends on whether E is printed.
        // The words are `units[i]` for the axes in `named`: one pass over the known axes,
        // and the printing and bookkeeping loops visit only the named ones.
        let mut units = [0i64; AXIS_COUNT];
        let mut named = AxisSet::EMPTY;
        let mut e_target = None;
        let mut e_absolute_once = false;
        let machine_frame = motion.machine_frame;
        let relative = self.fmt.extrusion == Extrusion::Relative;
        // A machine-frame (G53) move names only its own axes.
        let axes = if machine_frame {
            target.known.intersection(motion.written)
        } else {
            target.known
        };
        // E is the last axis: taking it out of the loop and after it keeps the order in
        // which a number that does not fit is reported.
        let e_apart = relative && !machine_frame && axes.contains(Axis::E);
        let plain = if e_apart {
            axes.difference(AxisSet::from_iter([Axis::E]))
        } else {
            axes
        };
        for a in plain.iter() {
            let i = a.index();
            let v = target.values[i];
            let prog = if machine_frame {
                v
            } else {
                v + self.track.offsets()[i]
            };
            let u = to_units(prog, self.axis_decimals[i])
                .ok_or_else(|| too_large(a.letter(), prog, block))?;
            if self.printed[i] != Some(u) || machine_frame {
                units[i] = u;
                named.insert(a);
            }
        }
        if e_apart {
            let i = Axis::E.index();
            let v = target.values[i];
            let d = self.axis_decimals[i];
            let u = to_units(v, d).ok_or_else(|| too_large('E', v, block))?;
            e_target = Some(u);
            let base = match (self.e_units, self.track.pos().get(Axis::E)) {
                (Some(b), _) => Some(b),
                (None, Some(p)) => to_units(p, d),
                (None, None) => None,
            };
            match base {
                Some(base) if u != base => {
                    units[i] = u - base;
                    named.insert(Axis::E);
                }
                Some(_) => {}
                // The controller's E is not known: this move says where E goes, in M82.
                None => {
                    let prog = v + self.track.offsets()[i];
                    units[i] = to_units(prog, d).ok_or_else(|| too_large('E', prog, block))?;
                    e_absolute_once = true;
                    named.insert(Axis::E);
                }
            }
        }
        let any = !named.is_empty();
        let is_arc = matches!(motion.kind, MotionKind::Arc(_));
        if let MotionKind::Arc(arc) = motion.kind {
            // An arc names its end point in the plane, even when it ends where it starts.
            let (u, v, _) = arc.plane.axes();
            for a in [u, v] {
                if !named.contains(a)
                    && let Some(val) = target.get(a)
                {
                    let prog = val + self.track.offsets()[a.index()];
                    units[a.index()] = to_units(prog, self.axis_decimals[a.index()])
                        .ok_or_else(|| too_large(a.letter(), prog, block))?;
                    named.insert(a);
                }
            }
        }
        if !any && !is_arc {
            // A move that changes nothing keeps the axes it named.
            for a in motion.written.iter() {
                if a == Axis::E && relative {
                    units[a.index()] = 0;
                    named.insert(a);
                    continue;
                }
                if let Some(v) = target.get(a) {
                    let prog = v + self.track.offsets()[a.index()];
                    if let Some(u) = to_units(prog, self.axis_decimals[a.index()]) {
                        units[a.index()] = u;
                        named.insert(a);
                    }
                }
            }
        }
        if let Flavor::Grbl(_) = self.flavor {
            grbl_motion_check(named, motion, block)?;
        }
        let e_mode = named
            .contains(Axis::E)
            .then_some(relative && !e_absolute_once && !machine_frame);
        self.ensure_modes(motion, e_mode, block)?;

        let code = match motion.kind {
            MotionKind::Rapid => "G0",
            MotionKind::Linear => "G1",
            MotionKind::Arc(a) if a.clockwise => "G2",
            MotionKind::Arc(_) => "G3",
        };
        if motion.machine_frame {
            self.text("G53");
        }
        if !self.fmt.modal_motion || self.modes.motion != Some(code) || motion.machine_frame {
            self.text(code);
        }
        self.modes.motion = Some(code);
        for a in named.iter() {
            let i = a.index();
            self.word_units(a.letter(), units[i], self.axis_decimals[i]);
        }
        if let MotionKind::Arc(arc) = motion.kind {
            let (u, v, _) = arc.plane.axes();
            let letters = match arc.plane {
                Plane::XY => ('I', 'J'),
                Plane::ZX => ('K', 'I'),
                Plane::YZ => ('J', 'K'),
            };
            // The controller starts the arc where the last printed numbers put it, so the
            // centre offsets are taken from those, not from the unrounded position.
            let d = self.fmt.decimals.linear;
            let scale = 10f64.powi(d as i32);
            let printed_start = |a: Axis, me: &Self| {
                me.printed[a.index()]
                    .map(|units| units as f64 / scale - me.track.offsets()[a.index()])
                    .or(me.track.pos().get(a))
            };
            let (Some(su), Some(sv)) = (printed_start(u, self), printed_start(v, self)) else {
                return Err(Diagnostic::error(
                    "back::arc-start",
                    "an arc starts from a position that is not known",
                )
                .at_span(block.span)
                .with_help("move to an absolute position before the arc"));
            };
            // I/J/K, printed in the order I, J, K.
            let mut offs = [
                (letters.0, arc.center[u.index()] - su),
                (letters.1, arc.center[v.index()] - sv),
            ];
            offs.sort_by_key(|o| o.0);
            for (l, val) in offs {
                self.word(l, val, d, block)?;
            }
            if arc.extra_turns > 0 {
                self.text(&format!("P{}", arc.extra_turns + 1));
            }
        }
        // F is modal and only matters to feed moves: print it there, when it changes.
        if let Some(rate) = motion
            .feed
            .rate
            .filter(|_| !matches!(motion.kind, MotionKind::Rapid))
        {
            let fu = to_units(rate, self.fmt.decimals.feed)
                .ok_or_else(|| too_large('F', rate, block))?;
            let must = motion.feed.mode == FeedMode::InverseTime
                && !matches!(motion.kind, MotionKind::Rapid);
            if self.modes.feed != Some(fu) || must {
                self.word_units('F', fu, self.fmt.decimals.feed);
                self.modes.feed = Some(fu);
            }
        }
        if !motion.extra.is_empty() {
            self.text(&motion.extra);
        }
        self.end_line(&block.comments, true)?;

        // Bookkeeping.
        let mut kept = named;
        if relative {
            // The printed numbers put E exactly here.
            if e_target.is_some() {
                self.e_units = e_target;
            }
            kept = kept.difference(AxisSet::from_iter([Axis::E]));
        }
        for a in kept.iter() {
            self.printed[a.index()] = Some(units[a.index()]);
        }
        self.track.motion(motion);
        if motion.machine_frame {
            for a in motion.written.iter() {
                self.printed[a.index()] = None;
            }
        }
        Ok(())
    }

    fn offset(&mut self, block: &Block, change: &OffsetChange) -> Result<(), Diagnostic> {
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

    fn forget(&mut self, axes: crate::ir::AxisSet) {
        for a in axes.iter() {
            self.printed[a.index()] = None;
            if a == Axis::E {
                self.e_units = None;
            }
        }
        self.track.forget(axes);
    }

    fn command(
        &mut self,
        block: &Block,
        cmd: &crate::ir::Command,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let mut text = cmd.text.as_str();
        let mut comments = std::borrow::Cow::Borrowed(&block.comments[..]);
        // The words this firmware does not run (the rest of the command kept), with what
        // the policy says about them in its terms; most commands have none and are
        // checked without allocating.
        let split = match self.flavor {
            Flavor::Grbl(g) => {
                if cmd.text.split_whitespace().any(grbl::is_subprogram_word) {
                    return Err(grbl_subprogram(block, &cmd.text));
                }
                let (k, removed) = grbl::split_words(&cmd.text, &g);
                (!removed.is_empty()).then(|| {
                    let wording = Unsupported {
                        code: "grbl::unsupported",
                        firmware: "Grbl 1.1",
                        option: "grbl",
                        keep_help: "for a build that runs it (grblHAL)",
                        note: |removed| Comment {
                            text: format!("{removed}: not supported by Grbl"),
                            style: CommentStyle::Paren,
                        },
                    };
                    (k, removed, g.unsupported, wording)
                })
            }
            // `any_unsupported` holds exactly when the split removes something.
            Flavor::Rrf { unsupported, .. } if rrf::any_unsupported(&cmd.text) => {
                let (k, removed) = rrf::split_unsupported(&cmd.text);
                let wording = Unsupported {
                    code: "rrf::unsupported",
                    firmware: "RepRapFirmware",
                    option: "rrf",
                    keep_help: "if your macros implement it",
                    note: |removed| Comment {
                        text: format!(" {removed} (not supported by RepRapFirmware)"),
                        style: CommentStyle::Semicolon,
                    },
                };
                Some((k, removed, unsupported, wording))
            }
            _ => None,
        };
        let kept;
        if let Some((k, removed, policy, wording)) = split {
            let msg = format!("`{removed}` is not supported by {}", wording.firmware);
            match policy {
                rrf::Unsupported::Error => {
                    return Err(Diagnostic::error(wording.code, msg)
                        .at_span(block.span)
                        .with_help(format!("remove it, or set the {} option `unsupported` to \"comment\" or \"keep\"", wording.option)));
                }
                rrf::Unsupported::Comment => {
                    diags.push(
                        Diagnostic::warning(wording.code, msg)
                            .at_span(block.span)
                            .with_help(format!("it is written as a comment; set the {} option `unsupported = \"keep\"` {}", wording.option, wording.keep_help)),
                    );
                    let mut c = vec![(wording.note)(&removed)];
                    c.extend(block.comments.iter().cloned());
                    comments = std::borrow::Cow::Owned(c);
                    kept = k;
                    text = &kept;
                    if text.is_empty() {
                        return self.end_line(&comments, false);
                    }
                }
                rrf::Unsupported::Keep => {}
            }
        }
        if let Some(modes) = cmd.modes {
            let metric = !modes.inch;
            if self.modes.metric != Some(metric) {
                self.text(if metric { "G21" } else { "G20" });
                self.modes.metric = Some(metric);
            }
            let absolute = !modes.relative;
            if self.modes.absolute != Some(absolute) {
                self.text(if absolute { "G90" } else { "G91" });
                self.modes.absolute = Some(absolute);
            }
            // A subprogram call: its body starts in the caller's plane.
            if let Some(plane) = modes.plane
                && self.modes.plane != Some(plane)
            {
                self.text(plane.gcode());
                self.modes.plane = Some(plane);
            }
        }
        self.text(text);
        self.end_line(&comments, true)?;
        self.forget(cmd.clobbers);
        // M82/M83 pass through; the next E move puts back the output's own mode.
        for w in text.split_whitespace() {
            if let Some(n) = w
                .strip_prefix(['M', 'm'])
                .and_then(crate::num::parse_decimal)
            {
                if n == 82.0 {
                    self.modes.e_relative = Some(false);
                } else if n == 83.0 {
                    self.modes.e_relative = Some(true);
                }
            }
        }
        // A command's F (probing, homing) changes the modal feed.
        if cmd
            .text
            .split_whitespace()
            .any(|w| w.starts_with(['F', 'f']))
        {
            self.modes.feed = None;
        }
        Ok(())
    }

    /// Prints a line as written, first putting the controller into the modes it was
    /// written in (at the top level only).
    fn verbatim(
        &mut self,
        block: &Block,
        v: &crate::ir::Verbatim,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        if let Flavor::Grbl(g) = self.flavor
            && self.grbl_verbatim(block, v, g, diags)?
        {
            return Ok(());
        }
        if v.reason == crate::ir::VerbatimReason::Delimiter {
            self.line.push_str(&v.text);
            return self.end_line(&block.comments, false);
        }
        if let Some(m) = v.modes {
            if self.modes.metric != Some(!m.inch) {
                self.text(if m.inch { "G20" } else { "G21" });
            }
            if self.modes.absolute != Some(!m.relative) {
                self.text(if m.relative { "G91" } else { "G90" });
            }
            // E modes only where this output has used them or the line moves E (LinuxCNC
            // lacks M82/M83).
            if let Some(plane) = m.plane
                && self.modes.plane != Some(plane)
            {
                self.text(plane.gcode());
                self.modes.plane = Some(plane);
            }
            if self.modes.e_relative != Some(m.relative_e)
                && crate::num::lexer::has_word(&v.text, 'E')
            {
                self.text(if m.relative_e { "M83" } else { "M82" });
                self.modes.e_relative = Some(m.relative_e);
            }
            if !self.line.is_empty() {
                self.end_line(&[], true)?;
            }
        }
        self.line.push_str(&v.text);
        self.end_line(&block.comments, false)?;
        self.forget(v.clobbers);
        let kept = v.modes.filter(|_| v.keeps_modes);
        self.modes = Modes {
            metric: kept.map(|m| !m.inch),
            absolute: kept.map(|m| !m.relative),
            // Aligned above when the line moves E; otherwise it is untouched.
            e_relative: kept.and(self.modes.e_relative),
            plane: if v.keeps_modes {
                self.modes.plane
            } else {
                None
            },
            ..Modes::default()
        };
        Ok(())
    }

    /// A line the IR passes as text, for Grbl: `%` is left out, an `O` number becomes a
    /// comment, subprograms, control flow, parameters and expressions are errors, and a
    /// line of plain words the IR does not model (probing, canned cycles) is checked
    /// word by word. `Ok(true)` when the line is dealt with, `Ok(false)` to print it as
    /// written.
    fn grbl_verbatim(
        &mut self,
        block: &Block,
        v: &crate::ir::Verbatim,
        g: grbl::Settings,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<bool, Diagnostic> {
        use crate::ir::VerbatimReason;
        let text = v.text.trim();
        let cut = text.find(['(', ';']).unwrap_or(text.len());
        let (code, rest) = (text[..cut].trim(), text[cut..].trim());
        let body = matches!(
            v.reason,
            VerbatimReason::Subprogram | VerbatimReason::ControlFlow
        );
        if body && (self.grbl_quiet || code.is_empty()) {
            // One error per subprogram or control-flow run; the output fails anyway.
            return Ok(true);
        }
        self.grbl_quiet = body;
        match v.reason {
            VerbatimReason::Delimiter if code.starts_with('%') => {
                self.line.push_str(rest);
                self.end_line(&block.comments, false)?;
                Ok(true)
            }
            VerbatimReason::Delimiter => {
                self.line
                    .push_str(format!("(program {code}) {rest}").trim_end());
                self.end_line(&block.comments, false)?;
                Ok(true)
            }
            VerbatimReason::Subprogram => Err(grbl_subprogram(block, text)),
            _ if code.split_whitespace().any(grbl::is_subprogram_word)
                || code.starts_with(['o', 'O']) =>
            {
                Err(grbl_subprogram(block, code))
            }
            _ if v.reason == VerbatimReason::ControlFlow || code.contains(['#', '[', '<']) => {
                Err(Diagnostic::error(
                    "grbl::unevaluated",
                    format!(
                        "Grbl cannot run `{code}`: it has no parameters, expressions or control flow"
                    ),
                )
                .at_span(block.span)
                .with_help(
                    "write the line with plain numbers, or use a controller that evaluates it (LinuxCNC)",
                ))
            }
            _ => {
                let (_, removed) = grbl::split_words(code, &g);
                if removed.is_empty() || g.unsupported == rrf::Unsupported::Keep {
                    return Ok(false);
                }
                if removed.split_whitespace().any(grbl::is_unsupported_motion) {
                    return Err(Diagnostic::error(
                        "grbl::unsupported-motion",
                        format!("Grbl 1.1 has no canned cycles, splines or threading: `{code}`"),
                    )
                    .at_span(block.span)
                    .with_help("let the CAM write the cycle as G0/G1 moves (Grbl would skip the line and not cut it)"));
                }
                let msg = format!("`{removed}` is not supported by Grbl 1.1");
                if g.unsupported == rrf::Unsupported::Error {
                    return Err(Diagnostic::error("grbl::unsupported", msg)
                        .at_span(block.span)
                        .with_help("remove it, or set the grbl option `unsupported` to \"comment\" or \"keep\""));
                }
                diags.push(
                    Diagnostic::warning("grbl::unsupported", msg)
                        .at_span(block.span)
                        .with_help("the line is written as a comment; set the grbl option `unsupported = \"keep\"` for a build that runs it (grblHAL)"),
                );
                self.line
                    .push_str(format!("({}: not supported by Grbl) {rest}", code.replace(['(', ')'], "")).trim_end());
                self.end_line(&block.comments, false)?;
                self.forget(v.clobbers);
                Ok(true)
            }
        }
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
                let letter = 'P';
                if self.fmt.dwell_milliseconds {
                    self.word(letter, seconds * 1000.0, 3, block)?;
                } else {
                    self.word(letter, *seconds, 3, block)?;
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

/// Grbl has no subprograms: a call, return or body left in the IR.
/// How a firmware's unsupported words are reported and noted.
struct Unsupported {
    code: &'static str,
    firmware: &'static str,
    /// The backend's options table, for the help.
    option: &'static str,
    /// Why one would keep the words anyway.
    keep_help: &'static str,
    /// The comment that takes the removed words' place.
    note: fn(&str) -> Comment,
}

fn grbl_subprogram(block: &Block, text: &str) -> Diagnostic {
    Diagnostic::error(
        "grbl::subprogram",
        format!("Grbl has no subprograms, and `{text}` was not expanded"),
    )
    .at_span(block.span)
    .with_help("expand-subprograms runs before the Grbl backend; it leaves a call with arguments or an expression (see its warning): write the call without them, or inline the body")
}

/// Grbl drives X, Y and Z only, and rejects `P` on an arc.
fn grbl_motion_check(named: AxisSet, motion: &Motion, block: &Block) -> Result<(), Diagnostic> {
    let others: String = named
        .difference(AxisSet::XYZ)
        .iter()
        .map(|a| a.letter())
        .collect();
    if !others.is_empty() {
        return Err(Diagnostic::error(
            "grbl::axis",
            format!("Grbl drives X, Y and Z only; this move also moves {others}"),
        )
        .at_span(block.span)
        .with_help("emit for a controller with these axes (--emit rrf or gcode), or remove them"));
    }
    if let MotionKind::Arc(arc) = motion.kind
        && arc.extra_turns > 0
    {
        return Err(Diagnostic::error(
            "grbl::arc-turns",
            format!(
                "this arc makes {} full turns more than Grbl's G2/G3 can (Grbl rejects P on an arc)",
                arc.extra_turns
            ),
        )
        .at_span(block.span)
        .with_help("add --pass linearize-arcs, which cuts the turns into straight moves"));
    }
    Ok(())
}

fn balanced(text: &str) -> bool {
    !text.contains(['(', ')'])
}

fn too_large(letter: char, value: f64, block: &Block) -> Diagnostic {
    Diagnostic::error(
        "back::number",
        format!("{letter} = {value} cannot be printed at the configured precision"),
    )
    .at_span(block.span)
    .with_help("the value is not finite or too large; check the transformations before the backend")
}

pub(crate) fn io_error(e: std::io::Error) -> Diagnostic {
    Diagnostic::io("io::write", format!("cannot write the output: {e}"))
}

/// Whether `d` says the output could not be written.
pub(crate) fn is_io_error(d: &Diagnostic) -> bool {
    d.kind == crate::diag::Kind::Io
}

impl<W: Write> Backend for Emitter<W> {
    fn write_block(
        &mut self,
        block: &Block,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let written = self.block(block, diags);
        // The block's text is the writer's when this returns (a program streamed to a
        // controller line by line sees it now).
        let handed = self.hand_out();
        written.and(handed)
    }
    fn write_batch(
        &mut self,
        blocks: &[Block],
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), OutputLost> {
        let written = each_block(blocks, diags, |b, d| self.block(b, d));
        // The whole batch's text in one write; what was printed before a failure stands.
        match self.hand_out() {
            Err(e) if written.is_ok() => {
                diags.push(e);
                Err(OutputLost)
            }
            _ => written,
        }
    }
    fn finish(&mut self) -> Result<(), Diagnostic> {
        self.flush()
    }
}

/// Implements [`Backend`] for a flavour's `Writer`, a newtype over [`Emitter`].
macro_rules! writer_backend {
    ($writer:ident) => {
        impl<W: std::io::Write> $crate::back::Backend for $writer<W> {
            fn write_block(
                &mut self,
                block: &$crate::ir::Block,
                diags: &mut Vec<$crate::diag::Diagnostic>,
            ) -> Result<(), $crate::diag::Diagnostic> {
                $crate::back::Backend::write_block(&mut self.0, block, diags)
            }
            fn write_batch(
                &mut self,
                blocks: &[$crate::ir::Block],
                diags: &mut Vec<$crate::diag::Diagnostic>,
            ) -> Result<(), $crate::back::OutputLost> {
                self.0.write_batch(blocks, diags)
            }
            fn finish(&mut self) -> Result<(), $crate::diag::Diagnostic> {
                self.0.flush()
            }
        }
    };
}
use writer_backend;

/// Writes all `blocks` to `backend` and finishes it; returns every diagnostic, in order.
///
/// ```
/// use ncpost::back::{gcode, write_blocks};
/// use ncpost::front::gcode::{parse_str, Options};
/// let program = parse_str("G0 X1\n", &Options::default()).unwrap();
/// let mut text = Vec::new();
/// let diags = write_blocks(&mut gcode::Writer::new(&mut text, &gcode::Options::default()), &program.blocks);
/// assert!(diags.is_empty());
/// ```
pub fn write_blocks(backend: &mut dyn Backend, blocks: &[Block]) -> Vec<Diagnostic> {
    let mut diags = Vec::new();
    let _ = backend.write_batch(blocks, &mut diags);
    if let Err(d) = backend.finish() {
        diags.push(d);
    }
    diags
}

/// Writes each block with `write`, adding its diagnostics to `diags`; `Err` after an
/// I/O failure.
pub(crate) fn each_block(
    blocks: &[Block],
    diags: &mut Vec<Diagnostic>,
    mut write: impl FnMut(&Block, &mut Vec<Diagnostic>) -> Result<(), Diagnostic>,
) -> Result<(), OutputLost> {
    for b in blocks {
        if let Err(d) = write(b, diags) {
            // The output cannot be written (a full disk, a closed pipe): nothing after
            // this block can be either, so writing stops with one error.
            let io = is_io_error(&d);
            diags.push(d);
            if io {
                return Err(OutputLost);
            }
        }
    }
    Ok(())
}

/// Like [`write_blocks`], but `Err` with every diagnostic when any is an error.
pub(crate) fn write_all(
    backend: &mut dyn Backend,
    blocks: &[Block],
) -> Result<(), Vec<Diagnostic>> {
    let diags = write_blocks(backend, blocks);
    if diags.iter().any(Diagnostic::is_error) {
        Err(diags)
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines built word by word, with an insertion at the front and a line longer than
    /// the spare room, come out whole and in order across many chunk writes.
    #[test]
    fn lines_survive_the_chunked_writes() {
        let mut line = Line::new();
        let mut out = Vec::new();
        let mut want = String::new();
        let long = "x".repeat(3000);
        for i in 0..20_000i64 {
            line.push_word(b'X', i * 7 - 5000, 3, true);
            line.push_word(b'F', i, 0, false);
            let mut text = format!("X{} F{i}", number_text(i * 7 - 5000, 3));
            if i % 97 == 0 {
                line.insert_str(0, "N1 ");
                text.insert_str(0, "N1 ");
            }
            if i % 1001 == 0 {
                line.push(' ');
                line.push_str(&long);
                text.push(' ');
                text.push_str(&long);
            }
            if i % 13 == 0 {
                // A line dropped before it ends leaves nothing behind.
                line.push_str("dropped");
                line.clear();
                continue;
            }
            if i % 5000 == 1 {
                // The finished lines go out; the one being built stays.
                line.write_finished(&mut out)
                    .expect("a Vec takes every write");
            }
            assert_eq!(line.as_bytes(), text.as_bytes());
            line.finish(&mut out).expect("a Vec takes every write");
            want.push_str(&text);
            want.push('\n');
        }
        line.write_finished(&mut out)
            .expect("a Vec takes every write");
        assert!(want.len() > 4 * Line::CHUNK);
        assert_eq!(String::from_utf8(out).expect("ASCII"), want);
    }

    fn number_text(units: i64, decimals: u8) -> String {
        let mut s = String::new();
        number::write_units(&mut s, units, decimals, true);
        s
    }
}
