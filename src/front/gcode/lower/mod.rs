//! Lowering of G-code lines to IR blocks, with the modal state of the controller.
//!
//! Every line takes one path: the logos lexer ([`crate::num::lexer`]), the lines outside
//! the plain block grammar set aside (`dialect`), the block structure read by
//! [`parse_tokens`](super::parse_tokens), the words collected (`words`) and the block
//! lowered with the modal state (`block`, `motion`, `arc`, `codes`).

use smallvec::SmallVec;

use super::Options;
use super::ast::Item;
use super::lexer::Spanned;
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, AxisSet, Block, BlockKind, Dialect, FeedMode, Joints, Plane, Span, Verbatim,
    VerbatimReason, WrittenModes,
};

mod arc;
mod block;
mod codes;
mod cycle;
mod dialect;
mod motion;
mod words;

pub(crate) use dialect::oword_call;

/// Per-line lists of words and codes: a block rarely has more than eight.
type Small<T> = SmallVec<[T; 8]>;

const MM_PER_INCH: f64 = 25.4;

/// The motion mode in force (modal group 1): the IR's, which a subprogram body starts in.
pub(crate) use crate::ir::MotionMode;

/// Lowers lines, keeping the controller's modal state.
pub(crate) struct Lowerer {
    pub(super) options: Options,
    motion: MotionMode,
    plane: Plane,
    inch: bool,
    relative: bool,
    relative_e: bool,
    arc_center_absolute: bool,
    feed_mode: FeedMode,
    feed: Option<f64>,
    /// Current position, IR frame.
    pos: Joints,
    /// G92 offsets: program = IR + offset.
    offsets: [f64; AXIS_COUNT],
    suspended: Option<[f64; AXIS_COUNT]>,
    /// Open o-word blocks: (label, keyword).
    oword_stack: Vec<(String, String)>,
    /// Indentation of an open RepRapFirmware meta block.
    meta_indent: Option<usize>,
    /// Inside a Fanuc subprogram body (until M99).
    in_subprogram: bool,
    /// Item buffer reused for every line.
    items: Vec<Item>,
    /// Token buffer reused for every line (empty between lines).
    toks: Vec<Spanned<'static>>,
    /// A non-blank line has been seen.
    saw_text: bool,
    /// A block of the main program has been seen.
    program_started: bool,
    /// Lowering a subprogram body for `expand-subprograms`: calls (M98, simple o-calls)
    /// are expanded by the caller, so they change no position or feed here.
    calls_inline: bool,
    /// The modes a subprogram called from here may have changed, not restated since
    /// ([`after_call`] bits): lines that depend on them are copied as written.
    after_call: u8,
    /// The modes each o-word subroutine read so far may change ([`after_call`] bits), by
    /// label as [`oword_call`] spells it; the one being read, with its label.
    sub_modes: Vec<(String, u8)>,
    reading_sub: Option<(String, u8)>,
    /// The dialect in force: the option's, or under `auto` the one the header names
    /// (until the program starts).
    dialect: Dialect,
    /// The canned cycle in force, its sticky words and the retract mode.
    cycle: cycle::CycleModal,
}

/// The lowering state a subprogram body starts from and leaves behind: the IR's
/// [`Modal`](crate::ir::Modal) (crate-internal API for the `expand-subprograms` pass).
pub(crate) use crate::ir::Modal as LowerState;

impl Lowerer {
    pub(crate) fn new(options: Options) -> Self {
        let dialect = options.dialect;
        let mut l = Lowerer {
            options,
            motion: MotionMode::None,
            plane: Plane::XY,
            inch: false,
            relative: false,
            relative_e: false,
            arc_center_absolute: false,
            feed_mode: FeedMode::PerMinute,
            feed: None,
            // The extruder's logical position starts at 0 (firmware convention).
            pos: {
                let mut p = Joints::default();
                p.set(Axis::E, 0.0);
                p
            },
            offsets: [0.0; AXIS_COUNT],
            suspended: None,
            oword_stack: Vec::new(),
            meta_indent: None,
            in_subprogram: false,
            items: Vec::with_capacity(32),
            toks: Vec::with_capacity(32),
            saw_text: false,
            program_started: false,
            calls_inline: false,
            after_call: 0,
            sub_modes: Vec::new(),
            reading_sub: None,
            dialect: Dialect::Auto,
            cycle: cycle::CycleModal::default(),
        };
        l.set_dialect(dialect);
        l
    }

    /// Reads the program in `dialect` ([`LowerState::read_in`]).
    fn set_dialect(&mut self, dialect: Dialect) {
        let mut state = self.state();
        state.read_in(dialect);
        self.set_state(state);
    }

    /// A lowerer for the lines of a subprogram body, starting in `state`; its calls
    /// (M98, o-calls without arguments) clobber nothing, as the caller expands them.
    pub(crate) fn for_body(options: Options, state: LowerState) -> Self {
        let mut l = Lowerer::new(options);
        l.calls_inline = true;
        l.set_state(state);
        l
    }

    /// The state the next line is lowered in.
    pub(crate) fn state(&self) -> LowerState {
        LowerState {
            motion: self.motion,
            plane: self.plane,
            inch: self.inch,
            relative: self.relative,
            relative_e: self.relative_e,
            arc_center_absolute: self.arc_center_absolute,
            feed_mode: self.feed_mode,
            feed: self.feed,
            pos: self.pos,
            offsets: self.offsets,
            suspended: self.suspended,
            retract_to_initial: self.cycle.retract_to_initial(),
            cycle: self.cycle.series(),
            dialect: self.dialect,
        }
    }

    /// Puts the lowerer into `state` (after an expanded call).
    pub(crate) fn set_state(&mut self, s: LowerState) {
        self.motion = s.motion;
        self.plane = s.plane;
        self.inch = s.inch;
        self.relative = s.relative;
        self.relative_e = s.relative_e;
        self.arc_center_absolute = s.arc_center_absolute;
        self.feed_mode = s.feed_mode;
        self.feed = s.feed;
        self.pos = s.pos;
        self.offsets = s.offsets;
        self.suspended = s.suspended;
        self.cycle.set_retract_to_initial(s.retract_to_initial);
        self.cycle.set_series(s.cycle);
        self.dialect = s.dialect;
    }

    /// Whether any non-blank line was read.
    pub(super) fn saw_text(&self) -> bool {
        self.saw_text
    }

    pub(super) fn finish(&mut self, diags: &mut Vec<Diagnostic>) {
        if let Some((label, kw)) = self.oword_stack.last() {
            diags.push(
                Diagnostic::warning(
                    "gcode::open-control-flow",
                    format!("o{label} {kw} is not closed at the end of the input"),
                )
                .with_help("every o-word sub/if/while/repeat needs its end word"),
            );
        }
    }

    /// A line as written, passed through: its modes are those in force before it (it
    /// was written in them), and the axes it `clobbers` become unknown.
    fn verbatim(
        &mut self,
        text: &str,
        span: Span,
        reason: VerbatimReason,
        clobbers: AxisSet,
        placement: Placement,
    ) -> Block {
        // The modes are those in force before the line (it was written in them).
        let (modes, keeps_modes) = match placement {
            Placement::Inside => (None, false),
            Placement::TopLevel { keeps_modes } => {
                // The extruder mode matters only to a line that moves E.
                let mut modes = self.modes();
                modes.relative_e &= crate::num::lexer::has_word(text, 'E');
                if matches!(
                    self.motion,
                    MotionMode::Arc { .. } | MotionMode::Unsupported
                ) || codes::uses_plane(text)
                {
                    modes.plane = Some(self.plane);
                }
                (Some(modes), keeps_modes)
            }
        };
        self.pos.forget(clobbers);
        Block::new(
            span,
            BlockKind::Verbatim(Verbatim {
                text: text.to_string(),
                reason,
                clobbers,
                modes,
                keeps_modes,
                cycle: None,
            }),
        )
    }

    /// A tape delimiter or program label (`%`, `O1000`), copied as written; it moves
    /// nothing.
    fn delimiter(&mut self, text: &str, span: Span) -> Block {
        self.verbatim(
            text,
            span,
            VerbatimReason::Delimiter,
            AxisSet::EMPTY,
            Placement::Inside,
        )
    }

    /// A line copied as written inside a construct (control flow, subprogram body) that
    /// may move anything.
    fn pass_through(&mut self, text: &str, span: Span, reason: VerbatimReason) -> Block {
        self.verbatim(text, span, reason, AxisSet::ALL, Placement::Inside)
    }

    /// The modes recorded on a subprogram call: units, distance mode, M83 (alone, not
    /// G91) and the plane, which the subprogram body starts in.
    fn call_modes(&self) -> WrittenModes {
        WrittenModes {
            inch: self.inch,
            relative: self.relative,
            relative_e: self.relative_e,
            plane: Some(self.plane),
        }
    }

    /// The modes a line is written in, for a line that may need them restored.
    fn modes(&self) -> WrittenModes {
        WrittenModes {
            inch: self.inch,
            relative: self.relative,
            // G91 moves E relatively too.
            relative_e: self.relative_e || self.relative,
            plane: None,
        }
    }

    /// Lowers one line; blocks go to `out`, diagnostics to `diags`.
    pub(crate) fn line(
        &mut self,
        text: &str,
        span: Span,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let mut toks = recycle(std::mem::take(&mut self.toks));
        super::lexer::lex_line(text, &mut toks);
        self.lexed_line(text, span, &toks, out, diags);
        self.toks = recycle(toks);
    }

    /// [`Lowerer::line`] for a line already split into `toks`.
    pub(super) fn lexed_line(
        &mut self,
        text: &str,
        span: Span,
        toks: &[Spanned<'_>],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        if text.trim().is_empty() {
            return;
        }
        self.saw_text = true;
        // The slicer's or post processor's header names the dialect.
        if self.dialect == Dialect::Auto
            && !self.program_started
            && let Some(d) = Dialect::named_in(text)
        {
            self.set_dialect(d);
        }
        // Control characters never belong in G-code: most likely a binary file.
        if let Some(at) = text
            .bytes()
            .position(|b| (b < 0x20 && !matches!(b, b'\t' | b'\r' | 0x0b | 0x0c)) || b == 0x7f)
        {
            diags.push(
                Diagnostic::error(
                    "gcode::control-character",
                    format!(
                        "control character 0x{:02x} in the line",
                        text.as_bytes()[at]
                    ),
                )
                .at_bytes(span.line, text, at, at + 1)
                .with_label("not text")
                .with_help("G-code is plain text; check that the file is not binary or corrupted"),
            );
            return;
        }
        let indent = text.len() - text.trim_start().len();

        // A RepRapFirmware meta block: its body is the lines indented deeper.
        if let Some(k) = self.meta_indent {
            if indent > k {
                out.push(self.pass_through(text, span, VerbatimReason::ControlFlow));
                return;
            }
            self.meta_indent = None;
        }
        if self.in_subprogram {
            out.push(self.pass_through(text, span, VerbatimReason::Subprogram));
            if codes::contains_m99(text) {
                self.in_subprogram = false;
            }
            return;
        }
        self.tokens(text, span, indent, toks, out, diags);
    }

    /// Lowers a line from its tokens (the rest of [`Lowerer::line`]).
    fn tokens(
        &mut self,
        text: &str,
        span: Span,
        indent: usize,
        toks: &[Spanned<'_>],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        if self.meta_command(text, span, indent, toks, out, diags) {
            return;
        }
        if let Some(kw) = dialect::oword_keyword(toks) {
            self.oword(text, span, toks, kw, out, diags);
            return;
        }
        if !self.oword_stack.is_empty() {
            if let Some((_, bits)) = &mut self.reading_sub {
                *bits |= dialect::modes_set(toks);
            }
            out.push(self.pass_through(text, span, VerbatimReason::ControlFlow));
            return;
        }
        if self.program_number(text, span, toks, out, diags)
            || self.prusa_mesh_levelling(text, span, toks, out)
        {
            return;
        }
        if let Some(reason) = self.unplain(text, span.line, toks, diags) {
            self.lower_unplain(text, span, toks, reason, out);
            return;
        }
        let mut items = std::mem::take(&mut self.items);
        match super::parse_tokens(toks, &mut items) {
            Ok(parsed) => self.block(text, span, parsed, &items, out, diags),
            Err(unexpected) => diags.push(words::syntax_error(span.line, text, unexpected)),
        }
        self.items = items;
    }
}

/// Where a verbatim line stands.
#[derive(Debug, Clone, Copy)]
enum Placement {
    /// At the top level of the program: the backend may put the controller into the
    /// line's modes before it. `keeps_modes`: the line changes none of them.
    TopLevel { keeps_modes: bool },
    /// Inside a block (control flow, subprogram): nothing may be inserted before it.
    Inside,
}

/// The modes a subprogram may leave changed, as bits of [`Lowerer`]'s `after_call`.
pub(super) mod after_call {
    /// G90/G91.
    pub const DISTANCE: u8 = 1;
    /// The motion mode: G0-G3, or a canned cycle (G81 ...).
    pub const MOTION: u8 = 2;
    /// Both: what a call the frontend does not expand leaves unknown.
    pub const ALL: u8 = DISTANCE | MOTION;
}

/// Classification of a line outside the plain grammar.
enum Unplain {
    /// A command whose arguments are not plain words (`M587 S"net"`, `M563 D0:1`).
    Command,
    /// Parameters, expressions or dialect statements.
    Unevaluated,
    /// Parameter assignments alone (`#1 = [#1 + 1]`): they move nothing; the axes whose
    /// position a system parameter set there can change.
    Assignment(crate::ir::AxisSet),
    /// An error was reported.
    Error,
}

/// An empty token vector of another lifetime, keeping `v`'s allocation (collecting an
/// emptied vector into one of the same layout reuses its memory).
pub(super) fn recycle<'b>(mut v: Vec<Spanned<'_>>) -> Vec<Spanned<'b>> {
    v.clear();
    v.into_iter()
        .map(|_| unreachable!("the vector is empty"))
        .collect()
}

/// The error for a line that is not UTF-8, pointing at its first bad byte.
pub(super) fn not_utf8(span: Span, valid_up_to: usize, lossy: &str) -> Diagnostic {
    let column = lossy
        .char_indices()
        .take_while(|(i, _)| *i < valid_up_to)
        .count() as u32
        + 1;
    Diagnostic::error("gcode::not-utf8", "the line is not valid UTF-8 text")
        .at_line(span.line, lossy, column, 1)
        .with_label("this byte")
        .with_help("G-code is text; check that the file is not binary or in another encoding (save it as UTF-8)")
}

#[cfg(test)]
mod tests {
    use super::{Spanned, recycle};

    #[test]
    fn arc_without_centre_is_an_error_from_an_unknown_start() {
        let diags = crate::front::gcode::parse_str("G2 X1\n", &Default::default()).unwrap_err();
        assert_eq!(diags.len(), 1, "{diags:?}");
        assert_eq!(diags[0].code, "gcode::arc");
    }

    /// The token buffer keeps its memory from line to line.
    #[test]
    fn recycled_token_buffer_keeps_its_allocation() {
        let line = String::from("G1 X1 Y2");
        let mut v: Vec<Spanned<'_>> = Vec::with_capacity(32);
        v.extend(crate::num::lexer::tokens(&line));
        assert_eq!(v.len(), 3);
        let at = v.as_ptr() as usize;
        let w: Vec<Spanned<'static>> = recycle(v);
        assert!(w.is_empty());
        assert_eq!((w.as_ptr() as usize, w.capacity()), (at, 32));
    }
}
