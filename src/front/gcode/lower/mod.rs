//! Lowering of G-code lines to IR blocks, with the modal state of the controller.

use nalgebra::Vector3;
use smallvec::SmallVec;

/// Per-line scratch lists live on the stack.
type Small<T> = SmallVec<[T; 8]>;

use super::Options;
use super::ast::{Item, Line};
use super::lexer::{Spanned, Tok, lex_line};
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Arc, Axis, AxisSet, Block, BlockKind, Command, Comment, CommentStyle, Feed,
    FeedMode, Joints, Motion, MotionKind, OffsetChange, OffsetCode, Plane, Span, Target, Verbatim,
    VerbatimReason, WrittenModes,
};
use crate::num::{parse_decimal, scan_decimal};

const MM_PER_INCH: f64 = 25.4;

/// RepRapFirmware meta-command keywords that start a line.
const META_KEYWORDS: &[&str] = &[
    "if", "elif", "else", "while", "break", "continue", "abort", "var", "global", "set", "echo",
    "skip",
];
/// Meta keywords that open an indented block.
const META_BLOCK_KEYWORDS: &[&str] = &["if", "elif", "else", "while"];

/// The motion mode in force (modal group 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum MotionMode {
    /// No motion mode yet (program start, or after a line that was not evaluated).
    None,
    /// G0.
    Rapid,
    /// G1.
    Linear,
    /// G2 (clockwise) or G3.
    Arc {
        /// G2.
        clockwise: bool,
    },
    /// A mode the IR does not model (canned cycles, splines, threading).
    Unsupported,
}

/// A G or M code as (major, minor): `G38.2` is (38, 2), `G1` is (1, 0).
type Code = (u32, u32);

fn parse_code(number: &str) -> Option<Code> {
    // Most codes are one or two plain digits (`G1`, `M104`, `G90` have no point).
    match *number.as_bytes() {
        [a] if a.is_ascii_digit() => Some(((a - b'0') as u32, 0)),
        [a, b] if a.is_ascii_digit() && b.is_ascii_digit() => {
            Some((((a - b'0') * 10 + (b - b'0')) as u32, 0))
        }
        _ => parse_code_general(number),
    }
}

/// [`parse_code`] for any number: sign, point, trailing zeros of the minor part.
fn parse_code_general(number: &str) -> Option<Code> {
    let number = number.strip_prefix('+').unwrap_or(number);
    let (major, minor) = match number.split_once('.') {
        Some((a, b)) => (a, b.trim_end_matches('0')),
        None => (number, ""),
    };
    let major = if major.is_empty() {
        0
    } else {
        major.parse().ok()?
    };
    let minor = if minor.is_empty() {
        0
    } else {
        minor.parse().ok()?
    };
    Some((major, minor))
}

/// A word of a plain block.
#[derive(Debug, Clone, Copy)]
struct Word<'a> {
    letter: char,
    value: f64,
    start: usize,
    end: usize,
    /// The source slice, for pass-through text.
    text: &'a str,
}

impl<'a> Word<'a> {
    /// The number as written.
    fn number(&self) -> &'a str {
        number_slice(self.text)
    }
}

/// The first word of each letter (but G, M and N) of a block, as indices into its words:
/// a few bytes per line instead of an array of words.
#[derive(Clone, Copy)]
struct Slots<'w, 'a> {
    words: &'w [Word<'a>],
    index: [u32; 26],
}

impl<'w, 'a> Slots<'w, 'a> {
    const NONE: u32 = u32::MAX;

    /// Whether the block has a word with `letter` (upper case).
    fn has(&self, letter: char) -> bool {
        let slot = (letter as u8).wrapping_sub(b'A') as usize;
        self.index.get(slot).is_some_and(|&i| i != Self::NONE)
    }

    /// Whether the block has a centre word (I, J, K or R).
    fn has_centre(&self) -> bool {
        ['I', 'J', 'K', 'R'].into_iter().any(|l| self.has(l))
    }

    /// The word with `letter` (upper case), if the block has one.
    fn get(&self, letter: char) -> Option<Word<'a>> {
        let slot = (letter as u8).wrapping_sub(b'A') as usize;
        match self.index.get(slot) {
            Some(&i) if i != Self::NONE => Some(self.words[i as usize]),
            _ => None,
        }
    }

    /// The word of `axis`, if the block has one.
    fn axis(&self, axis: Axis) -> Option<Word<'a>> {
        self.get(axis.letter())
    }
}

/// Which G-code modal group a code belongs to, for the conflict check.
fn g_group(code: Code) -> Option<&'static str> {
    Some(match code {
        (80, 0) => "canned cycle cancel",
        (0 | 1 | 2 | 3 | 33 | 73 | 76 | 81..=89, 0) | (5, _) | (38, _) | (33, 1) => "motion",
        (17..=19, _) => "plane",
        (20 | 21, 0) => "units",
        (90 | 91, 0) => "distance",
        (90 | 91, 1) => "arc distance",
        (93..=95, 0) => "feed mode",
        (54..=59, _) => "coordinate system",
        (40..=42, _) => "cutter compensation",
        (43 | 49, _) => "tool length offset",
        (4 | 10 | 28 | 30 | 53 | 92, _) => "non-modal",
        _ => return None,
    })
}

/// Modal G codes that neither move nor take axis words.
fn g_known_modal(code: Code) -> bool {
    matches!(
        code,
        (17..=21 | 40..=42 | 49 | 54..=59 | 61 | 64 | 80 | 90 | 91 | 93..=99, _) | (43, 0)
    )
}

/// G codes that take axis words without moving along them as a G1 would: homing, probing,
/// setting offsets, direct moves. They pass through as commands.
fn g_uses_axes(code: Code) -> bool {
    matches!(
        code,
        (6 | 10 | 28 | 29 | 30 | 31 | 52 | 161 | 162, _) | (38, _) | (43, 4 | 5)
    )
}

/// Axes whose position is unknown after a pass-through command, judged from its codes.
fn clobbers(g: &[Code], m: &[Code], named: AxisSet) -> AxisSet {
    let mut set = AxisSet::EMPTY;
    for &code in g {
        match code {
            // Homing and parking: the named axes, or all.
            (28 | 30 | 161 | 162 | 6 | 29, 0) => {
                let mut all = AxisSet::ALL;
                all.remove(Axis::E);
                set = set.union(if named.is_empty() { all } else { named })
            }
            // Probing stops somewhere along the named axes.
            (31, 0) | (38, _) => set = set.union(named),
            // Modal settings that do not move.
            (
                0..=4 | 17..=21 | 40..=43 | 49 | 53 | 54..=59 | 61 | 64 | 80 | 90 | 91 | 93..=99,
                _,
            )
            | (10 | 28 | 30, 1) => {}
            // Probing, macros, coordinate rotation and anything unknown may move or
            // re-define coordinates.
            _ => set = AxisSet::ALL,
        }
    }
    for &code in m {
        if matches!(code, (98 | 99, 0)) {
            set = AxisSet::ALL;
        }
    }
    set
}

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
    /// Lines of the commonest shape go through [`Lowerer::fast_move`] (off only in the
    /// tests that compare it with the general path).
    fast_lane: bool,
    /// A non-blank line has been seen.
    saw_text: bool,
    /// A block of the main program has been seen.
    program_started: bool,
    /// Lowering a subprogram body for `expand-subprograms`: calls (M98, simple o-calls)
    /// are expanded by the caller, so they change no position or feed here.
    calls_inline: bool,
}

/// The lowering state a subprogram body starts from and leaves behind: everything a
/// line's meaning depends on (crate-internal API for the `expand-subprograms` pass).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LowerState {
    /// Motion mode in force (G0/G1/G2/G3).
    pub motion: MotionMode,
    /// Arc plane.
    pub plane: Plane,
    /// G20.
    pub inch: bool,
    /// G91.
    pub relative: bool,
    /// M83 (E relative; G91 moves E relatively too).
    pub relative_e: bool,
    /// G90.1.
    pub arc_center_absolute: bool,
    /// G93/G94/G95.
    pub feed_mode: FeedMode,
    /// Modal feed, mm/min (or the mode's unit).
    pub feed: Option<f64>,
    /// Position, IR frame.
    pub pos: Joints,
    /// G92 offsets (program = IR + offset).
    pub offsets: [f64; AXIS_COUNT],
    /// Offsets suspended by G92.2.
    pub suspended: Option<[f64; AXIS_COUNT]>,
}

impl Lowerer {
    pub(crate) fn new(options: Options) -> Self {
        Lowerer {
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
            fast_lane: true,
            saw_text: false,
            program_started: false,
            calls_inline: false,
        }
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
                modes.relative_e &= super::lexer::has_word(text, 'E');
                if matches!(
                    self.motion,
                    MotionMode::Arc { .. } | MotionMode::Unsupported
                ) || uses_plane(text)
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
            }),
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
        // A byte-order mark at the start of the file is not part of the program.
        let text = if span.line == 1 {
            text.strip_prefix('\u{feff}').unwrap_or(text)
        } else {
            text
        };
        // Most lines start with a visible ASCII character: then they are not blank and
        // have no indentation, and neither needs a (Unicode-aware) trim.
        let starts_visible = text.as_bytes().first().is_some_and(u8::is_ascii_graphic);
        if !starts_visible && text.trim().is_empty() {
            return;
        }
        self.saw_text = true;
        // Control characters never belong in G-code: most likely a binary file.
        // A quick scan without an early exit (so it vectorises) finds no such byte in
        // almost every line; only then is the position looked for.
        let suspicious = text
            .bytes()
            .fold(false, |seen, b| seen | (b < 0x20) | (b == 0x7f));
        if suspicious
            && let Some(at) = text
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
        let indent = if starts_visible {
            0
        } else {
            text.len() - text.trim_start().len()
        };

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
            if contains_m99(text) {
                self.in_subprogram = false;
            }
            return;
        }
        if self.fast_lane
            && starts_visible
            && self.oword_stack.is_empty()
            && self.fast_move(text, span, out, diags)
        {
            return;
        }

        // The token buffer is kept from line to line (a new one would be allocated or,
        // on the stack, copied on every line).
        let mut toks = recycle(std::mem::take(&mut self.toks));
        let plain = super::lexer::lex_plain(text, &mut toks);
        if !plain {
            toks.clear();
            toks.extend(super::lexer::tokens(text));
        }
        self.tokens(text, span, indent, &toks, plain, out, diags);
        self.toks = recycle(toks);
    }

    /// Lowers a line from its tokens (the rest of [`Lowerer::line`]). `plain`: the hand
    /// lexer took the line, so its tokens are words and comments only, which is neither
    /// an o-word statement nor anything [`Lowerer::unplain`] sets aside (both checked in
    /// debug builds).
    #[allow(clippy::too_many_arguments)]
    fn tokens(
        &mut self,
        text: &str,
        span: Span,
        indent: usize,
        toks: &[Spanned<'_>],
        plain: bool,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let line_no = span.line;
        debug_assert!(
            !plain
                || (oword_keyword(toks).is_none()
                    && self.unplain(text, line_no, toks, &mut Vec::new()).is_none()),
            "{text:?}"
        );
        if let Some(Tok::Ident(word)) = toks.first().map(|t| t.1) {
            let lower = word.to_ascii_lowercase();
            if META_KEYWORDS.contains(&lower.as_str()) {
                if META_BLOCK_KEYWORDS.contains(&lower.as_str()) {
                    self.meta_indent = Some(indent);
                }
                diags.push(
                    Diagnostic::warning(
                        "gcode::meta-command",
                        format!("RepRapFirmware meta command `{lower}` is not evaluated"),
                    )
                    .at_bytes(line_no, text, toks[0].0, toks[0].2)
                    .with_label("passes through unchanged")
                    .with_help(
                        "the line (and the block indented below it) is copied as written; \
                         positions after it are treated as unknown",
                    ),
                );
                out.push(self.pass_through(text, span, VerbatimReason::ControlFlow));
                return;
            }
        }

        if !plain && let Some(kw) = oword_keyword(toks) {
            self.oword(text, span, toks, kw, out, diags);
            return;
        }
        if !self.oword_stack.is_empty() {
            out.push(self.pass_through(text, span, VerbatimReason::ControlFlow));
            return;
        }

        // Fanuc program numbers: at the top a label, after the main program a subprogram.
        if let Some(&(s, Tok::Word(w), e)) = toks.first()
            && w.starts_with(['O', 'o'])
        {
            if self.program_started {
                self.in_subprogram = !contains_m99(text);
                diags.push(
                    Diagnostic::warning(
                        "gcode::subprogram",
                        format!(
                            "subprogram {} passes through unchanged",
                            w.to_ascii_uppercase()
                        ),
                    )
                    .at_bytes(line_no, text, s, e)
                    .with_label("body copied as written up to its M99")
                    .with_help(
                        "the expand-subprograms pass inlines M98 calls when it is available",
                    ),
                );
                out.push(self.pass_through(text, span, VerbatimReason::Subprogram));
            } else {
                out.push(self.verbatim(
                    text,
                    span,
                    VerbatimReason::Delimiter,
                    AxisSet::EMPTY,
                    Placement::Inside,
                ));
            }
            return;
        }

        if !plain && let Some(reason) = self.unplain(text, line_no, toks, diags) {
            match reason {
                Unplain::Command => {
                    self.program_started = true;
                    let clob = self.command_clobbers(toks);
                    self.pos.forget(clob);
                    let mut block = Block::new(
                        span,
                        BlockKind::Command(Command {
                            text: strip_line_number_and_comments(text).into(),
                            modes: None,
                            clobbers: clob,
                        }),
                    );
                    block.comments = comments_of(text, toks);
                    out.push(block);
                }
                Unplain::Unevaluated => {
                    let keeps_modes = !self.apply_plain_modes(toks);
                    out.push(self.verbatim(
                        text,
                        span,
                        VerbatimReason::Unevaluated,
                        AxisSet::ALL,
                        Placement::TopLevel { keeps_modes },
                    ));
                }
                Unplain::Error => {}
            }
            return;
        }

        let mut items = std::mem::take(&mut self.items);
        items.clear();
        let parsed = super::parse_tokens(toks, &mut items);
        let parsed = match parsed {
            Ok(l) => l,
            Err(err) => {
                diags.push(parse_error(line_no, text, err));
                return;
            }
        };
        self.block(text, span, parsed, &items, out, diags);
        self.items = items;
    }

    /// Handles an o-word line (LinuxCNC control flow).
    fn oword(
        &mut self,
        text: &str,
        span: Span,
        toks: &[Spanned<'_>],
        keyword: &str,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let label = oword_label(text, toks);
        let kw = keyword.to_ascii_lowercase();
        let top_level = self.oword_stack.is_empty();
        // Nothing may be inserted between the lines of a control-flow construct.
        let placement = Placement::Inside;
        match kw.as_str() {
            "sub" | "if" | "repeat" | "do" => self.oword_stack.push((label, kw.clone())),
            "while" => {
                let closes_do = self
                    .oword_stack
                    .last()
                    .is_some_and(|(l, k)| *l == label && k == "do");
                if closes_do {
                    self.oword_stack.pop();
                } else {
                    self.oword_stack.push((label, kw.clone()));
                }
            }
            "endsub" | "endif" | "endwhile" | "endrepeat" => {
                self.oword_stack.pop();
            }
            _ => {}
        }
        if top_level {
            diags.push(
                Diagnostic::warning(
                    "gcode::control-flow",
                    format!("o-word `{kw}` is not evaluated"),
                )
                .at_bytes(
                    span.line,
                    text,
                    toks[0].0,
                    toks.last().map_or(toks[0].2, |t| t.2),
                )
                .with_label("passes through unchanged")
                .with_help(
                    "o-word subroutines, loops and conditions are copied as written, with \
                     their bodies; positions after them are treated as unknown",
                ),
            );
        }
        // A call at the top level records the modes its body starts in. A simple call
        // (no arguments) inside a body being expanded clobbers nothing: the caller
        // expands it.
        let is_call = kw == "call";
        let inline =
            is_call && top_level && self.calls_inline && oword_call(text).is_some_and(|c| c.simple);
        let clob = if inline { AxisSet::EMPTY } else { AxisSet::ALL };
        let mut block = self.verbatim(text, span, VerbatimReason::ControlFlow, clob, placement);
        if is_call && top_level {
            if let BlockKind::Verbatim(v) = &mut block.kind {
                v.modes = Some(self.call_modes());
            }
            if !self.calls_inline {
                self.feed = None;
            }
        }
        out.push(block);
    }

    /// Decides whether a line is outside the plain block grammar; reports why.
    fn unplain(
        &mut self,
        text: &str,
        line_no: u32,
        toks: &[Spanned<'_>],
        diags: &mut Vec<Diagnostic>,
    ) -> Option<Unplain> {
        // A checksum ends the line; anything but a comment after it is an error.
        let has_expression = toks
            .iter()
            .any(|t| matches!(t.1, Tok::Other(c) if "#[]{}=<>@^".contains(c)));
        if !has_expression
            && let Some(i) = toks.iter().position(|t| matches!(t.1, Tok::Checksum(_)))
            && let Some(&(s, _, e)) = toks[i + 1..]
                .iter()
                .find(|t| !matches!(t.1, Tok::LineComment(_) | Tok::Comment(_)))
        {
            let (cs, ce) = (toks[i].0, toks[i].2);
            diags.push(
                Diagnostic::error("gcode::checksum-position", format!("checksum `{}` must end the line", &text[cs..ce]))
                    .at_bytes(line_no, text, cs, ce)
                    .with_label("followed by more words")
                    .with_help(format!("move `{}` (and everything after it) before the checksum, or remove the checksum", &text[s..e])),
            );
            return Some(Unplain::Error);
        }
        let mut expression = None;
        let mut odd = None;
        for (i, &(s, tok, e)) in toks.iter().enumerate() {
            match tok {
                Tok::Other(c) if "#[]{}=<>@^".contains(c) => {
                    expression.get_or_insert((s, e));
                }
                Tok::Other(_) | Tok::Ident(_) | Tok::Number(_) => {
                    odd.get_or_insert((s, e, tok));
                }
                Tok::Slash(_) if i > 0 => {
                    odd.get_or_insert((s, e, tok));
                }
                Tok::OpenComment(_) if i > 0 => {}
                _ => {}
            }
        }
        let first_letter = toks.iter().find_map(|t| match t.1 {
            Tok::Word(w) | Tok::Letter(w) => w.chars().next().map(|c| c.to_ascii_uppercase()),
            _ => None,
        });
        let command_line = matches!(first_letter, Some('M' | 'T'));
        let has_string = toks.iter().any(|t| matches!(t.1, Tok::Str(_)));
        if expression.is_none() && odd.is_none() && (!has_string || command_line) {
            return if has_string {
                Some(Unplain::Command)
            } else {
                None
            };
        }
        // NaN and infinity are never numbers in G-code, whatever the dialect: `XNaN`,
        // `X-inf`, `X nan`.
        for &(_, tok, e) in toks {
            let Tok::Ident(w) = tok else { continue };
            let lower = w.to_ascii_lowercase();
            let name = ["infinity", "nan", "inf"]
                .into_iter()
                .find(|n| lower.ends_with(n) && lower.len() <= n.len() + 1);
            if let Some(name) = name {
                let at = e - name.len();
                diags.push(
                    Diagnostic::error(
                        "gcode::not-a-number",
                        format!("`{}` is not a number G-code accepts", &text[at..e]),
                    )
                    .at_bytes(line_no, text, at, e)
                    .with_label("not a finite number")
                    .with_help("give the word a finite decimal value"),
                );
                return Some(Unplain::Error);
            }
        }

        if command_line && expression.is_none() {
            return Some(Unplain::Command);
        }
        let (s, e) = expression.unwrap_or_else(|| odd.map(|o| (o.0, o.1)).unwrap_or((0, 0)));
        diags.push(
            Diagnostic::warning(
                "gcode::unevaluated",
                "line is not plain G-code: parameters, expressions or dialect syntax are not evaluated",
            )
            .at_bytes(line_no, text, s, e)
            .with_label("not evaluated")
            .with_help("the line is copied as written; positions after it are treated as unknown"),
        );
        Some(Unplain::Unevaluated)
    }

    /// Applies modal words of a line that is otherwise passed through, so that following
    /// plain lines are read in the modes the controller will be in.
    /// Returns whether the line has such words (whatever the modes were before, so the
    /// answer depends on the line alone).
    fn apply_plain_modes(&mut self, toks: &[Spanned<'_>]) -> bool {
        let mut any = false;
        for t in toks {
            if let Tok::Word(w) = t.1 {
                let (letter, number) = split_word(w);
                let Some(code) = parse_code(number) else {
                    continue;
                };
                match (letter, code) {
                    ('G', (90, 0)) => self.relative = false,
                    ('G', (91, 0)) => self.relative = true,
                    ('G', (20, 0)) => self.inch = true,
                    ('G', (21, 0)) => self.inch = false,
                    ('G', (17, 0)) => self.plane = Plane::XY,
                    ('G', (18, 0)) => self.plane = Plane::ZX,
                    ('G', (19, 0)) => self.plane = Plane::YZ,
                    ('M', (82, 0)) => self.relative_e = false,
                    ('M', (83, 0)) => self.relative_e = true,
                    _ => continue,
                }
                any = true;
            }
        }
        self.motion = MotionMode::None;
        any
    }

    fn command_clobbers(&self, toks: &[Spanned<'_>]) -> AxisSet {
        let mut g: Small<Code> = Small::new();
        let mut m: Small<Code> = Small::new();
        let mut named = AxisSet::EMPTY;
        for t in toks {
            if let Tok::Word(w) | Tok::Letter(w) = t.1 {
                let (letter, number) = split_word(w);
                match letter {
                    'G' => g.extend(parse_code(number)),
                    'M' => m.extend(parse_code(number)),
                    l => {
                        if let Some(a) = Axis::from_letter(l) {
                            named.insert(a);
                        }
                    }
                }
            }
        }
        clobbers(&g, &m, named)
    }

    /// Lowers a plain block.
    /// Puts the words, bare letters and comments of a parsed line `into` the caller's
    /// lists, after the checks that need no modal state (checksum, number range, exponent
    /// typos, unterminated comments). Returns whether the line holds a `%`; `None` once an
    /// error is reported.
    fn collect<'a>(
        text: &'a str,
        line_no: u32,
        line: &Line,
        items: &[Item],
        into: Collected<'_, 'a>,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<bool> {
        let Collected {
            words,
            bare,
            comments,
        } = into;
        let err = |code: &'static str, msg: String, s: usize, e: usize| {
            Diagnostic::error(code, msg).at_bytes(line_no, text, s, e)
        };

        if let Some((at, cs_end)) = line.checksum {
            let cs = &text[at..cs_end];
            let expected: u32 = text.as_bytes()[..at]
                .iter()
                .fold(0u32, |a, b| a ^ *b as u32);
            let given: Option<u32> = cs[1..].parse().ok();
            if given != Some(expected) {
                diags.push(
                    err(
                        "gcode::checksum",
                        format!(
                            "checksum {} does not match the line (expected *{expected})",
                            cs
                        ),
                        at,
                        at + cs.len(),
                    )
                    .with_label("wrong checksum")
                    .with_help("the line was changed or corrupted after its checksum was computed"),
                );
                return None;
            }
        }

        let mut percent = false;
        for item in items {
            match *item {
                Item::Word(s, e) => {
                    let w = &text[s..e];
                    let (letter, number) = split_word(w);
                    let value = parse_decimal(number).unwrap_or(f64::NAN);
                    if !value.is_finite() || value.abs() > 1e12 {
                        diags.push(
                            err(
                                "gcode::number-range",
                                format!("`{w}`: the number is out of range"),
                                s,
                                s + w.len(),
                            )
                            .with_label("too large")
                            .with_help("G-code values must be finite and below 1e12"),
                        );
                        return None;
                    }
                    // `X1e400` reads as X1 then E400: almost surely an exponent typo.
                    if letter == 'E'
                        && w.starts_with('e')
                        && let Some(prev) = words.last()
                        && prev.end == s
                    {
                        diags.push(
                            err(
                                "gcode::exponent",
                                format!(
                                    "`{}{w}` looks like a number in exponent notation, which G-code does not have",
                                    prev.text
                                ),
                                prev.start,
                                s + w.len(),
                            )
                            .with_label("read as two words")
                            .with_help(
                                "write the value in plain decimals; for an extruder word, \
                                 put a space before it or write it in capitals",
                            ),
                        );
                        return None;
                    }
                    words.push(Word {
                        letter,
                        value,
                        start: s,
                        end: s + w.len(),
                        text: w,
                    });
                }
                Item::Letter(s, e) => bare.push((s, &text[s..e])),
                Item::Comment(s, e) => comments.push(Comment {
                    text: text[s + 1..e - 1].to_string(),
                    style: CommentStyle::Paren,
                }),
                Item::Str(s, _) => {
                    diags.push(err(
                        "gcode::string",
                        "a quoted string needs an M command".into(),
                        s,
                        s + 1,
                    ));
                    return None;
                }
                Item::Percent(_) => percent = true,
            }
        }
        if let Some((at, tail_end)) = line.tail {
            let c = &text[at..tail_end];
            if let Some(rest) = c.strip_prefix(';') {
                comments.push(Comment {
                    text: rest.to_string(),
                    style: CommentStyle::Semicolon,
                });
            } else if words.is_empty() && bare.is_empty() {
                diags.push(
                    Diagnostic::warning("gcode::unterminated-comment", "comment is not closed")
                        .at_bytes(line_no, text, at, text.len())
                        .with_label("runs to the end of the line")
                        .with_help("add `)`; it is kept as a comment"),
                );
                comments.push(Comment {
                    text: c[1..].to_string(),
                    style: CommentStyle::Paren,
                });
            } else {
                diags.push(
                    err(
                        "gcode::unterminated-comment",
                        "comment is not closed".into(),
                        at,
                        text.len(),
                    )
                    .with_label("`(` without `)`")
                    .with_help("close the comment with `)` (comments do not span lines)"),
                );
                return None;
            }
        }

        Some(percent)
    }

    fn block(
        &mut self,
        text: &str,
        span: Span,
        line: Line,
        items: &[Item],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let line_no = span.line;
        let err = |code: &'static str, msg: String, s: usize, e: usize| {
            Diagnostic::error(code, msg).at_bytes(line_no, text, s, e)
        };

        // Filled in place (a returned SmallVec would be copied).
        let mut words: Small<Word<'_>> = Small::new();
        let mut bare: Small<(usize, &str)> = Small::new();
        let mut comments = Vec::new();
        let Some(percent) = Self::collect(
            text,
            line_no,
            &line,
            items,
            Collected {
                words: &mut words,
                bare: &mut bare,
                comments: &mut comments,
            },
            diags,
        ) else {
            return;
        };
        if !percent
            && !line.block_delete
            && bare.is_empty()
            && self.plain_move(text, span, &words, &mut comments, out, diags)
        {
            return;
        }
        if percent {
            if !words.is_empty() {
                diags.push(err(
                    "gcode::percent",
                    "`%` must stand alone on its line".into(),
                    0,
                    text.len(),
                ));
                return;
            }
            out.push(self.verbatim(
                text,
                span,
                VerbatimReason::Delimiter,
                AxisSet::EMPTY,
                Placement::Inside,
            ));
            return;
        }

        if line.block_delete {
            let named_here: AxisSet = words
                .iter()
                .filter_map(|w| Axis::from_letter(w.letter))
                .collect();
            diags.push(
                Diagnostic::warning("gcode::block-delete", "block delete `/` line is not evaluated")
                    .at_bytes(line_no, text, 0, 1)
                    .with_label("optional block")
                    .with_help("the controller may skip it; it is copied as written and positions after it are unknown"),
            );
            out.push(self.verbatim(
                text,
                span,
                VerbatimReason::ControlFlow,
                named_here,
                Placement::TopLevel { keeps_modes: true },
            ));
            return;
        }

        // Sort the words.
        let mut g_codes: Small<(Code, Word<'_>)> = Small::new();
        let mut m_codes: Small<(Code, Word<'_>)> = Small::new();
        let mut index = [Slots::NONE; 26];
        let mut rest: Small<Word<'_>> = Small::new();
        for (wi, w) in words.iter().enumerate() {
            match w.letter {
                'G' | 'M' => {
                    let Some(code) = parse_code(w.number()) else {
                        diags.push(err(
                            "gcode::code",
                            format!("`{}` is not a valid code", w.text),
                            w.start,
                            w.end,
                        ));
                        return;
                    };
                    if w.letter == 'G' {
                        g_codes.push((code, *w));
                    } else {
                        m_codes.push((code, *w));
                    }
                }
                'N' => {}
                l => {
                    let slot = &mut index[(l as u8 - b'A') as usize];
                    if *slot != Slots::NONE
                        && (Axis::from_letter(l).is_some()
                            || matches!(l, 'F' | 'I' | 'J' | 'K' | 'R' | 'S'))
                    {
                        let prev = words[*slot as usize];
                        diags.push(
                            err(
                                "gcode::duplicate-word",
                                format!("the word `{l}` appears twice in one block"),
                                w.start,
                                w.end,
                            )
                            .with_label(format!("second `{l}`; the first is `{}`", prev.text))
                            .with_help(
                                "a block may give each letter once; split it into two blocks",
                            ),
                        );
                        return;
                    }
                    if *slot == Slots::NONE {
                        *slot = wi as u32;
                    }
                    if Axis::from_letter(l).is_none()
                        && !matches!(l, 'F' | 'I' | 'J' | 'K' | 'R' | 'P')
                    {
                        rest.push(*w);
                    }
                }
            }
        }
        let slots = Slots {
            words: &words,
            index,
        };
        // Modal group conflicts.
        for (i, (code, w)) in g_codes.iter().enumerate() {
            if let Some(group) = g_group(*code)
                && group != "non-modal"
                && let Some((_, first)) = g_codes[..i]
                    .iter()
                    .find(|(c, _)| g_group(*c) == Some(group))
            {
                diags.push(
                    err(
                        "gcode::modal-conflict",
                        format!(
                            "`{}` and `{}` are both in the {group} group",
                            first.text, w.text
                        ),
                        w.start,
                        w.end,
                    )
                    .with_label("conflicts with an earlier code")
                    .with_help("a block may hold one code of each modal group"),
                );
                return;
            }
        }
        let named: AxisSet = Axis::ALL
            .into_iter()
            .filter(|a| slots.has(a.letter()))
            .collect();

        // Modal settings, in RS274 execution order.
        let mut motion_here = None;
        let mut unsupported_here = false;
        let mut dwell = false;
        let mut offset_code = None;
        let mut machine_frame = false;
        let mut axis_user = false;
        let mut other_g: Small<Word<'_>> = Small::new();
        let mut g_list: Small<Code> = Small::new();
        for (code, w) in &g_codes {
            g_list.push(*code);
            match *code {
                (0, 0) => motion_here = Some(MotionMode::Rapid),
                (1, 0) => motion_here = Some(MotionMode::Linear),
                (2, 0) => motion_here = Some(MotionMode::Arc { clockwise: true }),
                (3, 0) => motion_here = Some(MotionMode::Arc { clockwise: false }),
                // G80 cancels a canned cycle; Mach3 programs also write it beside G0.
                (80, 0) => {
                    if self.motion == MotionMode::Unsupported && motion_here.is_none() {
                        motion_here = Some(MotionMode::None);
                    }
                }
                (17, 0) => self.plane = Plane::XY,
                (18, 0) => self.plane = Plane::ZX,
                (19, 0) => self.plane = Plane::YZ,
                (20, 0) => self.inch = true,
                (21, 0) => self.inch = false,
                (90, 0) => self.relative = false,
                (91, 0) => self.relative = true,
                (90, 1) => self.arc_center_absolute = true,
                (91, 1) => self.arc_center_absolute = false,
                (93, 0) => self.feed_mode = FeedMode::InverseTime,
                (94, 0) => self.feed_mode = FeedMode::PerMinute,
                (95, 0) => self.feed_mode = FeedMode::PerRevolution,
                (4, 0) => dwell = true,
                (53, 0) => machine_frame = true,
                (92, minor @ 0..=3) => {
                    offset_code = Some(match minor {
                        0 => OffsetCode::Set,
                        1 => OffsetCode::Clear,
                        2 => OffsetCode::Suspend,
                        _ => OffsetCode::Restore,
                    })
                }
                c if g_group(c) == Some("motion") => {
                    unsupported_here = true;
                    other_g.push(*w);
                }
                c if g_uses_axes(c) => {
                    axis_user = true;
                    other_g.push(*w);
                }
                c => {
                    // A code the IR does not know may move or redefine coordinates
                    // (G68.2, G65, G6600): its axis words are its own, not a move.
                    if !g_known_modal(c) && motion_here.is_none() {
                        axis_user = true;
                    }
                    other_g.push(*w)
                }
            }
        }
        for (code, _) in &m_codes {
            match *code {
                (82, 0) => self.relative_e = false,
                (83, 0) => self.relative_e = true,
                // Standard machine M codes never take axis words; on any other M code
                // (M92, M201, M203, M584, ...) axis letters are its parameters.
                (0..=9 | 30 | 48..=53 | 60..=68, _) => {}
                _ if motion_here.is_none() => axis_user = true,
                _ => {}
            }
        }
        if unsupported_here {
            self.motion = MotionMode::Unsupported;
        } else if let Some(m) = motion_here {
            self.motion = m;
        }
        // Per-line lists are filled in place: collecting a SmallVec moves (copies) it.
        let mut m_list: Small<Code> = Small::new();
        m_list.extend(m_codes.iter().map(|(c, _)| *c));
        // M82/M83 are resolved here; the backend puts its own extruder mode before E moves.
        let mut passthrough_m: Small<Word<'_>> = Small::new();
        passthrough_m.extend(
            m_codes
                .iter()
                .filter(|(c, _)| !matches!(c, (82 | 83, 0)))
                .map(|(_, w)| *w),
        );
        // F applies to this block and after; in G93 it is per block.
        let mut feed_written = false;
        if let Some(f) = slots.get('F')
            && !dwell
        {
            if f.value < 0.0 {
                diags.push(
                    err(
                        "gcode::feed",
                        format!("negative feed `{}`", f.text),
                        f.start,
                        f.end,
                    )
                    .with_label("below zero")
                    .with_help("F is a speed and must not be negative"),
                );
                return;
            }
            self.feed = Some(f.value * self.feed_scale());
            feed_written = true;
        }

        // Blocks go straight to `out`; the line's comments go on the first of them.
        let first = out.len();
        let blocks = &mut *out;
        // Pass-through command words (everything the IR does not model).
        let mut command_words: Small<Word<'_>> = Small::new();
        {
            let v = &mut command_words;
            v.extend(
                other_g
                    .iter()
                    .chain(passthrough_m.iter())
                    .chain(rest.iter())
                    .copied(),
            );
            let arc_here =
                matches!(motion_here, Some(MotionMode::Arc { .. })) && slots.has_centre();
            let becomes_motion =
                !axis_user && offset_code.is_none() && (!named.is_empty() || arc_here);
            if !dwell && !becomes_motion {
                // The command's own parameters stay with it (`G54.1 P2`, `M98 P1 L2`).
                for l in ['I', 'J', 'K', 'R', 'P'] {
                    if let Some(w) = slots.get(l) {
                        v.push(w);
                    }
                }
            }
            v.sort_by_key(|w| w.start);
        }

        if let Some(code) = offset_code {
            let declared = self.apply_offset(code, &slots, named, line_no, text, diags);
            if !command_words.is_empty() {
                blocks.push(self.command(span, &command_words, &g_list, &m_list, named, false));
            }
            blocks.push(Block::new(
                span,
                BlockKind::Offset(OffsetChange {
                    code,
                    declared,
                    offsets: self.offsets,
                }),
            ));
        } else if dwell {
            let seconds = self.dwell_seconds(&slots);
            match seconds {
                Some(seconds) => blocks.push(Block::new(span, BlockKind::Dwell { seconds })),
                None => {
                    // Dialect dwells (`G4 F0.25`, bare `G4`) pass through as written.
                    let mut words: Small<Word<'_>> =
                        words.iter().filter(|w| w.letter != 'N').copied().collect();
                    words.sort_by_key(|w| w.start);
                    blocks.push(self.command(
                        span,
                        &words,
                        &g_list,
                        &m_list,
                        AxisSet::EMPTY,
                        false,
                    ));
                }
            }
        } else if axis_user {
            let mut words = command_words.clone();
            words.extend(named.iter().filter_map(|a| slots.axis(a)));
            // A probe's or homing command's feed is its own (and stays modal).
            words.extend(slots.get('F'));
            words.sort_by_key(|w| w.start);
            // Bare letters name axes too (`G28 X Z` homes X and Z).
            let bare_axes: AxisSet = bare
                .iter()
                .filter_map(|(_, l)| l.chars().next().and_then(Axis::from_letter))
                .collect();
            // Only G codes take coordinates in the current units and distance mode; an M code's
            // axis words are settings (`M201 X2500`, `M563 X3`).
            let coordinates = !other_g.is_empty() && !named.is_empty();
            let mut cmd = self.command(
                span,
                &words,
                &g_list,
                &m_list,
                named.union(bare_axes),
                coordinates,
            );
            if !bare.is_empty()
                && let BlockKind::Command(c) = &mut cmd.kind
            {
                // `G28 X Z`, `G6 B20 R`: bare letters are arguments; keep the words as written.
                c.text = strip_line_number_and_comments(text).into();
            }
            blocks.push(cmd);
        } else if !named.is_empty()
            || (motion_here.is_some() && !bare.is_empty())
            || (matches!(motion_here, Some(MotionMode::Arc { .. })) && slots.has_centre())
        {
            if let Some(&(s, l)) = bare.first() {
                diags.push(letter_error(line_no, text, s, l));
                return;
            }
            match self.motion {
                MotionMode::Unsupported => {
                    diags.push(
                        Diagnostic::warning(
                            "gcode::unsupported-motion",
                            "motion mode is not modelled (canned cycle, spline, probing or threading)",
                        )
                        .at_bytes(line_no, text, 0, text.len())
                        .with_label("passes through unchanged")
                        .with_help("the block is copied as written; positions after it are treated as unknown"),
                    );
                    blocks.push(self.verbatim(
                        text,
                        span,
                        VerbatimReason::Unevaluated,
                        AxisSet::ALL,
                        Placement::TopLevel { keeps_modes: true },
                    ));
                }
                MotionMode::None => {
                    let w = named.iter().find_map(|a| slots.axis(a));
                    let (s, e) = w.map_or((0, text.len()), |w| (w.start, w.end));
                    diags.push(
                        err(
                            "gcode::no-motion-mode",
                            "axis words with no motion mode in force".into(),
                            s,
                            e,
                        )
                        .with_label("where should this go?")
                        .with_help("start the block with G0 or G1"),
                    );
                    return;
                }
                mode => {
                    // Words other than the move's (M, T, S, unknown letters) ride along on its line.
                    let mut extra: Small<&str> = Small::new();
                    extra.extend(command_words.iter().map(|w| w.text));
                    let moved = self.motion_block(
                        text,
                        span,
                        mode,
                        &slots,
                        named,
                        machine_frame,
                        feed_written,
                        &extra,
                        blocks,
                        diags,
                    );
                    if moved.is_none() {
                        return;
                    }
                }
            }
        } else if let Some(&(s, l)) = bare.first() {
            if passthrough_m.is_empty() && other_g.is_empty() {
                diags.push(letter_error(line_no, text, s, l));
                return;
            }
            // `M84 X Y`, `G28 X Y`: letters are the command's arguments.
            let mut v = command_words.clone();
            v.sort_by_key(|w| w.start);
            let mut cmd = self.command(span, &v, &g_list, &m_list, AxisSet::EMPTY, false);
            if let BlockKind::Command(c) = &mut cmd.kind {
                c.text = strip_line_number_and_comments(text).into();
            }
            blocks.push(cmd);
        } else if !command_words.is_empty() {
            blocks.push(self.command(
                span,
                &command_words,
                &g_list,
                &m_list,
                AxisSet::EMPTY,
                false,
            ));
        }

        if out.len() == first {
            if comments.is_empty() {
                return;
            }
            out.push(Block::new(span, BlockKind::Comment));
        } else {
            self.program_started = true;
        }
        // A line passed through as text keeps its comments in the text.
        if !matches!(out[first].kind, BlockKind::Verbatim(_)) {
            out[first].comments = comments;
        }
    }

    /// The common case, classified cheaply: a G0/G1 move (written or modal) whose words
    /// are only axes, F and N, each once. Lowered by [`Lowerer::motion_block`] like any
    /// move; returns `false`, having changed nothing, for any other line, which then takes
    /// the general path (with its diagnostics).
    fn plain_move(
        &mut self,
        text: &str,
        span: Span,
        words: &[Word<'_>],
        comments: &mut Vec<Comment>,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> bool {
        let mut index = [Slots::NONE; 26];
        let mut mode = None;
        let mut named = AxisSet::EMPTY;
        for (i, w) in words.iter().enumerate() {
            match w.letter {
                'N' => {}
                'G' => match (mode, parse_code(w.number())) {
                    (None, Some((0, 0))) => mode = Some(MotionMode::Rapid),
                    (None, Some((1, 0))) => mode = Some(MotionMode::Linear),
                    _ => return false,
                },
                l => {
                    let axis = Axis::from_letter(l);
                    if axis.is_none() && l != 'F' {
                        return false;
                    }
                    let slot = &mut index[(l as u8 - b'A') as usize];
                    if *slot != Slots::NONE {
                        return false;
                    }
                    *slot = i as u32;
                    if let Some(a) = axis {
                        named.insert(a);
                    }
                }
            }
        }
        let mode = mode.unwrap_or(self.motion);
        if named.is_empty()
            || !matches!(mode, MotionMode::Rapid | MotionMode::Linear)
            || self.feed_mode == FeedMode::InverseTime
        {
            return false;
        }
        let slots = Slots { words, index };
        let feed = slots.get('F');
        if feed.is_some_and(|f| f.value < 0.0) {
            return false;
        }
        // From here on the line is lowered exactly as the general path would.
        self.motion = mode;
        if let Some(f) = feed {
            self.feed = Some(f.value * self.feed_scale());
        }
        let first = out.len();
        let lowered = self.motion_block(
            text,
            span,
            mode,
            &slots,
            named,
            false,
            feed.is_some(),
            &[],
            out,
            diags,
        );
        if lowered.is_some() && out.len() > first {
            self.program_started = true;
            if !matches!(out[first].kind, BlockKind::Verbatim(_)) {
                out[first].comments = std::mem::take(comments);
            }
        }
        true
    }

    /// The commonest lines of a file (`G1 X93.189 Y98.172 E.1642 ; note`: upper-case G,
    /// X, Y, Z, E and F words with plain decimals, separated by blanks, and at most a `;`
    /// comment; or a `;` comment alone) read in one scan of the bytes and lowered by
    /// [`Lowerer::plain_move`], without the lexer, the line grammar and the word
    /// collection. `false` (nothing done) for any other line, which then takes the
    /// general path; for the lines it takes, the blocks and diagnostics are those of the
    /// general path (tested on every corpus line and on generated ones).
    fn fast_move(
        &mut self,
        text: &str,
        span: Span,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> bool {
        let b = text.as_bytes();
        let mut words: Small<Word<'_>> = Small::new();
        let mut comment = None;
        let mut i = 0;
        while i < b.len() {
            match b[i] {
                b' ' | b'\t' | b'\r' => i += 1,
                b';' => {
                    comment = Some(i);
                    break;
                }
                c @ (b'G' | b'X' | b'Y' | b'Z' | b'E' | b'F') => {
                    // A word needs a blank (or the start) before it: `X1E5` is two
                    // words the general path checks.
                    if i > 0 && !matches!(b[i - 1], b' ' | b'\t') {
                        return false;
                    }
                    let start = i;
                    let Some((value, j)) = scan_decimal(b, i + 1) else {
                        return false;
                    };
                    if j < b.len() && !matches!(b[j], b' ' | b'\t' | b'\r' | b';') {
                        return false;
                    }
                    let w = &text[start..j];
                    if !value.is_finite() || value.abs() > 1e12 {
                        return false;
                    }
                    words.push(Word {
                        letter: c as char,
                        value,
                        start,
                        end: j,
                        text: w,
                    });
                    i = j;
                }
                _ => return false,
            }
        }
        let mut comments = Vec::new();
        if let Some(at) = comment {
            comments.push(Comment {
                text: text[at + 1..].to_string(),
                style: CommentStyle::Semicolon,
            });
        }
        if words.is_empty() {
            // A comment line (`;TYPE:Perimeter`): what the general path makes of it.
            if comments.is_empty() {
                return false;
            }
            let mut block = Block::new(span, BlockKind::Comment);
            block.comments = comments;
            out.push(block);
            return true;
        }
        self.plain_move(text, span, &words, &mut comments, out, diags)
    }

    /// Applies a G92-family code to the offsets and returns the values G92 declares.
    fn apply_offset(
        &mut self,
        code: OffsetCode,
        slots: &Slots<'_, '_>,
        named: AxisSet,
        line_no: u32,
        text: &str,
        diags: &mut Vec<Diagnostic>,
    ) -> Joints {
        let mut declared = Joints::default();
        match code {
            OffsetCode::Set => {
                if named.is_empty() {
                    // RepRapFirmware and Marlin: G92 with no axes does nothing useful.
                    diags.push(
                        Diagnostic::warning(
                            "gcode::g92-empty",
                            "G92 without axis words changes nothing",
                        )
                        .at_bytes(line_no, text, 0, text.len()),
                    );
                }
                for a in named.iter() {
                    let Some(w) = slots.axis(a) else { continue };
                    let v = w.value * self.unit(a);
                    declared.set(a, v);
                    match self.pos.get(a) {
                        Some(p) => self.offsets[a.index()] = v - p,
                        None => {
                            self.offsets[a.index()] = 0.0;
                            self.pos.set(a, v);
                        }
                    }
                }
            }
            OffsetCode::Clear => {
                self.offsets = [0.0; AXIS_COUNT];
                self.suspended = None;
            }
            OffsetCode::Suspend => {
                self.suspended = Some(self.offsets);
                self.offsets = [0.0; AXIS_COUNT];
            }
            OffsetCode::Restore => {
                if let Some(s) = self.suspended.take() {
                    self.offsets = s;
                }
            }
        }
        declared
    }

    /// The length of a G4 dwell, seconds, when the block gives it in a form the IR knows.
    fn dwell_seconds(&self, slots: &Slots<'_, '_>) -> Option<f64> {
        let seconds = match (slots.get('P'), slots.get('S'), slots.axis(Axis::X)) {
            (Some(p), None, None) => {
                if self.options.dwell_p_milliseconds {
                    p.value / 1000.0
                } else {
                    p.value
                }
            }
            (None, Some(s), None) | (None, None, Some(s)) => s.value,
            _ => return None,
        };
        (seconds >= 0.0).then_some(seconds)
    }

    /// Millimetres per unit of F: inches per minute convert, inverse time does not.
    fn feed_scale(&self) -> f64 {
        if self.inch && self.feed_mode != FeedMode::InverseTime {
            MM_PER_INCH
        } else {
            1.0
        }
    }

    fn unit(&self, axis: Axis) -> f64 {
        if self.inch && !axis.is_rotary() {
            MM_PER_INCH
        } else {
            1.0
        }
    }

    fn command(
        &mut self,
        span: Span,
        words: &[Word<'_>],
        g: &[Code],
        m: &[Code],
        named: AxisSet,
        with_axes: bool,
    ) -> Block {
        let mut text = String::new();
        for w in words {
            if !text.is_empty() {
                text.push(' ');
            }
            text.push(w.letter);
            text.push_str(w.number());
        }
        // A Fanuc call: the subprogram may move anything and set its own F. Expanded
        // inline (a body lowered for `expand-subprograms`), it changes nothing here.
        let call = m.contains(&(98, 0));
        let clob = if call && self.calls_inline {
            AxisSet::EMPTY
        } else {
            clobbers(g, m, named)
        };
        self.pos.forget(clob);
        if call && !self.calls_inline {
            self.feed = None;
        }
        let modes = if call {
            // The modes the body starts in (E: M83 alone, not G91).
            Some(self.call_modes())
        } else {
            with_axes.then(|| WrittenModes {
                relative_e: self.relative_e && named.contains(Axis::E),
                ..self.modes()
            })
        };
        Block::new(
            span,
            BlockKind::Command(Command {
                text: text.into(),
                modes,
                clobbers: clob,
            }),
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn motion_block(
        &mut self,
        text: &str,
        span: Span,
        mode: MotionMode,
        slots: &Slots<'_, '_>,
        named: AxisSet,
        machine_frame: bool,
        feed_written: bool,
        extra: &[&str],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<()> {
        let line_no = span.line;
        let param = |l: char| slots.get(l);
        let start = self.pos;
        // A relative move from an unknown position cannot be made absolute: it travels as
        // written, in the modes it was written in, and its axes stay unknown.
        let relative = |a: Axis| {
            if a == Axis::E {
                self.relative || self.relative_e
            } else {
                self.relative
            }
        };
        if !machine_frame
            && let Some(a) = named
                .iter()
                .find(|&a| relative(a) && start.get(a).is_none())
        {
            diags.push(
                Diagnostic::warning(
                    "gcode::relative-unknown",
                    format!("relative move of {} from a position that is not known here", a.letter()),
                )
                .at_bytes(line_no, text, 0, text.len())
                .with_label("passes through unchanged")
                .with_help(format!(
                    "it is copied as written (in G91); move {} to an absolute position first to have it resolved",
                    a.letter()
                )),
            );
            let b = self.verbatim(
                text,
                span,
                VerbatimReason::Unevaluated,
                named,
                Placement::TopLevel { keeps_modes: true },
            );
            out.push(b);
            return Some(());
        }
        let mut target = self.pos;
        for a in named.iter() {
            let Some(w) = slots.axis(a) else { continue };
            let v = w.value * self.unit(a);
            let rel = if a == Axis::E {
                self.relative || self.relative_e
            } else {
                self.relative
            };
            let value = if machine_frame {
                v
            } else if rel {
                start.values[a.index()] + v
            } else {
                v - self.offsets[a.index()]
            };
            target.set(a, value);
        }
        let mut extra_turns = 0;
        let kind = match mode {
            MotionMode::Rapid => MotionKind::Rapid,
            MotionMode::Linear => MotionKind::Linear,
            MotionMode::Arc { clockwise } => {
                let (u, v, _) = self.plane.axes();
                // An arc without its centre (or with two) is wrong wherever it starts.
                let letters = plane_offset_letters(self.plane);
                let has_offsets = slots.has(letters.0) || slots.has(letters.1);
                if has_offsets == slots.has('R') {
                    let msg = if has_offsets {
                        "arc has both a radius (R) and centre offsets"
                    } else {
                        "arc has neither a radius (R) nor centre offsets"
                    };
                    let help = if has_offsets {
                        "give either R or the centre offsets, not both".to_string()
                    } else {
                        format!(
                            "add {} and {} (centre relative to the start) or R",
                            letters.0, letters.1
                        )
                    };
                    diags.push(
                        Diagnostic::error("gcode::arc", msg)
                            .at_bytes(line_no, text, 0, text.len())
                            .with_label("this arc")
                            .with_help(help),
                    );
                    return None;
                }
                if start.get(u).is_none() || start.get(v).is_none() {
                    diags.push(
                        Diagnostic::warning("gcode::arc-unknown-start", "arc starts from a position that is not known here")
                            .at_bytes(line_no, text, 0, text.len())
                            .with_label("passes through unchanged")
                            .with_help(format!(
                                "its centre depends on the start; move {} and {} to absolute positions before the arc",
                                u.letter(),
                                v.letter()
                            )),
                    );
                    let b = self.verbatim(
                        text,
                        span,
                        VerbatimReason::Unevaluated,
                        AxisSet::ALL,
                        Placement::TopLevel { keeps_modes: true },
                    );
                    out.push(b);
                    return Some(());
                }
                let start = self.pos;
                let s2 = [start.values[u.index()], start.values[v.index()]];
                let e2 = [target.values[u.index()], target.values[v.index()]];
                let offset_letters = plane_offset_letters(self.plane);
                let off_u = param(offset_letters.0);
                let off_v = param(offset_letters.1);
                let off_n = param(offset_letters.2);
                let r = param('R');
                if let Some(p) = param('P') {
                    if p.value < 1.0 || p.value.fract() != 0.0 {
                        diags.push(
                            Diagnostic::error("gcode::arc-turns", format!("`{}`: P must be a whole number of turns, 1 or more", p.text))
                                .at_bytes(line_no, text, p.start, p.end)
                                .with_label("not a whole number of turns")
                                .with_help("P counts full turns of the arc: P1 is a plain arc, P2 adds one more turn"),
                        );
                        return None;
                    }
                    extra_turns = p.value as u32 - 1;
                }
                let arc_err = |msg: String, help: &str| {
                    Diagnostic::error("gcode::arc", msg)
                        .at_bytes(line_no, text, 0, text.len())
                        .with_label("this arc")
                        .with_help(help.to_string())
                };
                if let Some(w) = off_n {
                    diags.push(
                        Diagnostic::error(
                            "gcode::arc",
                            format!(
                                "`{}` is not used by an arc in the {} plane",
                                w.text,
                                self.plane.gcode()
                            ),
                        )
                        .at_bytes(line_no, text, w.start, w.end)
                        .with_help(format!(
                            "in {} the centre offsets are {} and {}",
                            self.plane.gcode(),
                            offset_letters.0,
                            offset_letters.1
                        )),
                    );
                    return None;
                }
                let unit = if self.inch { MM_PER_INCH } else { 1.0 };
                let centre2 = match (off_u.is_some() || off_v.is_some(), r) {
                    // Checked above: exactly one of the two forms.
                    (true, Some(_)) | (false, None) => return None,
                    (true, None) => {
                        let du = off_u.map_or(0.0, |w| w.value * unit);
                        let dv = off_v.map_or(0.0, |w| w.value * unit);
                        let c = if self.arc_center_absolute {
                            [du - self.offsets[u.index()], dv - self.offsets[v.index()]]
                        } else {
                            [s2[0] + du, s2[1] + dv]
                        };
                        let r0 = ((s2[0] - c[0]).powi(2) + (s2[1] - c[1]).powi(2)).sqrt();
                        let r1 = ((e2[0] - c[0]).powi(2) + (e2[1] - c[1]).powi(2)).sqrt();
                        let tol = self.options.arc_tolerance.max(1e-3 * r0.max(r1));
                        if (r0 - r1).abs() > tol {
                            let msg = format!(
                                "arc radius does not fit its end points: {r0:.4} mm at the start, {r1:.4} mm at the end"
                            );
                            if self.options.strict_arcs {
                                diags.push(arc_err(
                                    msg,
                                    "check the end point and the centre offsets; they must be equidistant from the centre",
                                ));
                                return None;
                            }
                            diags.push(
                                Diagnostic::warning("gcode::arc-radius", msg)
                                    .at_bytes(line_no, text, 0, text.len())
                                    .with_label("kept as written")
                                    .with_help(
                                        "the centre is kept where the offsets put it; controllers may reject \
                                         the arc or move in a spiral (set strict_arcs to make this an error)",
                                    ),
                            );
                        }
                        if r0 == 0.0 {
                            diags.push(arc_err(
                                "arc centre is at its start point".into(),
                                "the centre offsets must not all be 0",
                            ));
                            return None;
                        }
                        c
                    }
                    (false, Some(rw)) => {
                        let radius = rw.value * unit;
                        let d = ((e2[0] - s2[0]).powi(2) + (e2[1] - s2[1]).powi(2)).sqrt();
                        if d < 1e-9 {
                            diags.push(arc_err(
                                "an R arc cannot end where it starts".into(),
                                "a full circle needs centre offsets instead of R",
                            ));
                            return None;
                        }
                        let half = d / 2.0;
                        let tol = self.options.arc_tolerance.max(1e-3 * radius.abs());
                        if radius == 0.0 {
                            diags.push(arc_err(
                                "arc radius R0 is not a circle".into(),
                                "give the arc's radius",
                            ));
                            return None;
                        }
                        if half > radius.abs() + tol {
                            let msg = format!(
                                "arc radius {:.4} mm does not fit its end points, which are {:.4} mm apart",
                                radius.abs(),
                                d
                            );
                            let help = "the radius must be at least half the distance between start and end";
                            if self.options.strict_arcs {
                                diags.push(arc_err(msg, help));
                                return None;
                            }
                            diags.push(
                                Diagnostic::warning("gcode::arc-radius", msg)
                                    .at_bytes(line_no, text, 0, text.len())
                                    .with_label("made a half circle")
                                    .with_help(format!(
                                        "{help}; it is kept as a half circle through both points, as Mach3 \
                                         does (set strict_arcs to make this an error)"
                                    )),
                            );
                        }
                        let h = (radius * radius - half * half).max(0.0).sqrt();
                        let mid = [(s2[0] + e2[0]) / 2.0, (s2[1] + e2[1]) / 2.0];
                        let dir = [(e2[0] - s2[0]) / d, (e2[1] - s2[1]) / d];
                        // Right of the chord for G2 with R > 0, left for G3; flipped by R < 0.
                        let right = [dir[1], -dir[0]];
                        let sign = if clockwise == (radius > 0.0) {
                            1.0
                        } else {
                            -1.0
                        };
                        [mid[0] + sign * h * right[0], mid[1] + sign * h * right[1]]
                    }
                };
                let mut center = Vector3::zeros();
                center[u.index()] = centre2[0];
                center[v.index()] = centre2[1];
                MotionKind::Arc(Arc {
                    clockwise,
                    plane: self.plane,
                    center,
                    extra_turns,
                })
            }
            MotionMode::None | MotionMode::Unsupported => return None,
        };
        if self.feed_mode == FeedMode::InverseTime
            && !matches!(kind, MotionKind::Rapid)
            && !feed_written
        {
            diags.push(
                Diagnostic::error(
                    "gcode::inverse-time-feed",
                    "in inverse time mode (G93) every feed move needs F",
                )
                .at_bytes(line_no, text, 0, text.len())
                .with_label("no F on this move")
                .with_help("add F (1/minutes for this block) or switch to G94"),
            );
            return None;
        }
        let mut extra_text = String::new();
        for (i, w) in extra.iter().enumerate() {
            if i > 0 {
                extra_text.push(' ');
            }
            extra_text.push_str(&normalise_word(w));
        }
        if !matches!(kind, MotionKind::Arc(_)) {
            // I, J, K, R, P on a line move belong to the controller (tool vectors, ...).
            for l in ['I', 'J', 'K', 'R', 'P'] {
                if let Some(w) = param(l) {
                    if !extra_text.is_empty() {
                        extra_text.push(' ');
                    }
                    extra_text.push_str(&normalise_word(w.text));
                }
            }
        }
        let motion = Motion {
            kind,
            target: Target::Joints(target),
            feed: Feed {
                mode: self.feed_mode,
                rate: self.feed,
            },
            written: named,
            machine_frame,
            extra: extra_text,
        };
        self.pos = target;
        if machine_frame {
            self.pos.forget(named);
        }
        // Pushed here rather than returned: a returned block is one more copy per line.
        out.push(Block::new(span, BlockKind::Motion(motion)));
        Some(())
    }
}

/// Where [`Lowerer::collect`] puts what it takes from a parsed line.
struct Collected<'b, 'a> {
    words: &'b mut Small<Word<'a>>,
    bare: &'b mut Small<(usize, &'a str)>,
    comments: &'b mut Vec<Comment>,
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

/// Classification of a line outside the plain grammar.
enum Unplain {
    /// A command whose arguments are not plain words (`M587 S"net"`, `M563 D0:1`).
    Command,
    /// Parameters, expressions or dialect statements.
    Unevaluated,
    /// An error was reported.
    Error,
}

fn plane_offset_letters(plane: Plane) -> (char, char, char) {
    match plane {
        Plane::XY => ('I', 'J', 'K'),
        Plane::ZX => ('K', 'I', 'J'),
        Plane::YZ => ('J', 'K', 'I'),
    }
}

/// An empty token vector of another lifetime, keeping `v`'s allocation (collecting an
/// emptied vector into one of the same layout reuses its memory).
fn recycle<'b>(mut v: Vec<Spanned<'_>>) -> Vec<Spanned<'b>> {
    v.clear();
    v.into_iter()
        .map(|_| unreachable!("the vector is empty"))
        .collect()
}

/// Letter (upper case) and number (without blanks) of a word token.
///
/// The lexer's word pattern allows blanks only between the letter and the number
/// (`G 1`), so the number is one slice.
fn split_word(w: &str) -> (char, &str) {
    let letter = w.as_bytes().first().copied().unwrap_or(b' ');
    (letter.to_ascii_uppercase() as char, number_slice(w))
}

/// The number part of a word token.
fn number_slice(w: &str) -> &str {
    let rest = w.get(1..).unwrap_or("");
    // Blanks after the letter are rare: look at one byte before trimming.
    if matches!(rest.as_bytes().first(), Some(b' ' | b'\t')) {
        rest.trim_start_matches([' ', '\t'])
    } else {
        rest
    }
}

fn normalise_word(w: &str) -> String {
    let (letter, number) = split_word(w);
    let mut s = String::with_capacity(w.len());
    s.push(letter);
    s.push_str(number);
    s
}

fn letter_error(line_no: u32, text: &str, s: usize, l: &str) -> Diagnostic {
    Diagnostic::error(
        "gcode::letter-without-number",
        format!("letter `{l}` has no number"),
    )
    .at_bytes(line_no, text, s, s + l.len())
    .with_label("needs a value")
    .with_help(format!(
        "write a value after it (for example `{}0`) or remove it",
        l.to_ascii_uppercase()
    ))
}

/// Whether a line has a G code that works in the selected plane (arcs, canned cycles).
fn uses_plane(text: &str) -> bool {
    let mut toks = Vec::new();
    lex_line(text, &mut toks);
    toks.iter().any(|t| match t.1 {
        Tok::Word(w) => {
            let (l, n) = split_word(w);
            l == 'G' && matches!(parse_code(n), Some((2 | 3 | 73 | 76 | 81..=89, 0)))
        }
        _ => false,
    })
}

fn contains_m99(text: &str) -> bool {
    let mut toks = Vec::new();
    lex_line(text, &mut toks);
    toks.iter().any(|t| match t.1 {
        Tok::Word(w) => {
            let (l, n) = split_word(w);
            l == 'M' && parse_code(n) == Some((99, 0))
        }
        _ => false,
    })
}

/// The o-word keyword of a LinuxCNC control line (`o100 sub`, `o<x> if [..]`).
fn oword_keyword<'a>(toks: &[Spanned<'a>]) -> Option<&'a str> {
    const KEYWORDS: &[&str] = &[
        "sub",
        "endsub",
        "call",
        "return",
        "if",
        "elseif",
        "else",
        "endif",
        "while",
        "endwhile",
        "do",
        "repeat",
        "endrepeat",
        "break",
        "continue",
    ];
    let first = toks.first()?.1;
    let starts_o = match first {
        Tok::Word(w) | Tok::Letter(w) => w.starts_with(['o', 'O']),
        _ => false,
    };
    if !starts_o {
        return None;
    }
    toks.iter().skip(1).find_map(|t| match t.1 {
        Tok::Ident(w) if KEYWORDS.iter().any(|k| k.eq_ignore_ascii_case(w)) => Some(w),
        _ => None,
    })
}

/// An o-word call line (`o100 call`, `o<name> call [1] [2]`), as far as the
/// `expand-subprograms` pass needs it (crate-internal).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct OwordCall {
    /// The label, lower case, leading zeros of a number removed (`100`, `<name>`); `None`
    /// when it is an expression (`o[#2 * 10]`).
    pub label: Option<String>,
    /// No arguments and a plain label: the call can be expanded.
    pub simple: bool,
    /// Byte range of the label and the keyword in the line, for diagnostics.
    pub at: (usize, usize),
}

/// Reads an o-word call line; `None` when the line is not one.
pub(crate) fn oword_call(text: &str) -> Option<OwordCall> {
    let toks: Vec<Spanned<'_>> = super::lexer::tokens(text).collect();
    let kw = oword_keyword(&toks)?;
    if !kw.eq_ignore_ascii_case("call") {
        return None;
    }
    let kw_at = toks
        .iter()
        .position(|t| matches!(t.1, Tok::Ident(w) if w.eq_ignore_ascii_case("call")))?;
    let raw = text[toks[0].0 + 1..toks[kw_at].0].trim();
    let label = if let Some(digits) = raw
        .strip_prefix(['+'])
        .or(Some(raw))
        .filter(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
    {
        Some(digits.trim_start_matches('0').to_string())
            .map(|d| if d.is_empty() { "0".to_string() } else { d })
    } else if raw.starts_with('<') && raw.ends_with('>') && !raw.contains(['[', '#']) {
        Some(raw.to_ascii_lowercase())
    } else {
        None
    };
    let args = toks[kw_at + 1..].iter().any(|t| {
        !matches!(
            t.1,
            Tok::Comment(_) | Tok::LineComment(_) | Tok::OpenComment(_)
        )
    });
    Some(OwordCall {
        simple: label.is_some() && !args,
        label,
        at: (toks[0].0, toks[kw_at].2),
    })
}

/// The label of an o-word line: the text between `o` and the keyword.
fn oword_label(text: &str, toks: &[Spanned<'_>]) -> String {
    let end = toks
        .iter()
        .skip(1)
        .find(|t| matches!(t.1, Tok::Ident(_)))
        .map_or(text.len(), |t| t.0);
    text[toks[0].0 + 1..end].trim().to_ascii_lowercase()
}

/// The comments of a line passed through as a command, without their delimiters.
fn comments_of(text: &str, toks: &[Spanned<'_>]) -> Vec<Comment> {
    toks.iter()
        .filter_map(|&(s, t, e)| match t {
            Tok::Comment(_) => Some(Comment {
                text: text[s + 1..e - 1].to_string(),
                style: CommentStyle::Paren,
            }),
            Tok::OpenComment(_) => Some(Comment {
                text: text[s + 1..e].to_string(),
                style: CommentStyle::Paren,
            }),
            Tok::LineComment(_) => Some(Comment {
                text: text[s + 1..e].to_string(),
                style: CommentStyle::Semicolon,
            }),
            _ => None,
        })
        .collect()
}

/// The words of a line as written, without line number, checksum and comments. Words
/// that touch in the source still touch (`S"net"` must not become `S "net"`).
fn strip_line_number_and_comments(text: &str) -> String {
    let mut toks = Vec::new();
    lex_line(text, &mut toks);
    let mut out = String::new();
    let mut last_end = None;
    for (s, t, e) in toks {
        match t {
            Tok::Comment(_) | Tok::LineComment(_) | Tok::OpenComment(_) | Tok::Checksum(_) => {}
            Tok::Word(w) if w.starts_with(['N', 'n']) && last_end.is_none() => {}
            _ => {
                if last_end.is_some_and(|end| end < s) {
                    out.push(' ');
                }
                out.push_str(&text[s..e]);
                last_end = Some(e);
            }
        }
    }
    out
}

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

fn parse_error(
    line_no: u32,
    text: &str,
    err: lalrpop_util::ParseError<usize, Tok<'_>, ()>,
) -> Diagnostic {
    use lalrpop_util::ParseError as P;
    let (s, e, what) = match err {
        P::UnrecognizedToken {
            token: (s, t, e), ..
        }
        | P::ExtraToken { token: (s, t, e) } => (s, e, describe(t)),
        P::InvalidToken { location } => (location, location + 1, "this".to_string()),
        P::UnrecognizedEof { location, .. } => (location, location, "the end of the line".into()),
        P::User { .. } => (0, text.len(), "the line".into()),
    };
    Diagnostic::error("gcode::syntax", format!("unexpected {what}"))
        .at_bytes(line_no, text, s, e)
        .with_label("not allowed here")
        .with_help("block delete `/` starts a line; a checksum `*NN` and a `;` comment end it")
}

fn describe(t: Tok<'_>) -> String {
    match t {
        Tok::Checksum(c) => format!("checksum `{c}`"),
        Tok::Slash(s) => format!("block delete `{s}`"),
        Tok::Word(w) | Tok::Letter(w) | Tok::Ident(w) | Tok::Number(w) | Tok::Other(w) => {
            format!("`{w}`")
        }
        Tok::Comment(c) | Tok::OpenComment(c) | Tok::LineComment(c) | Tok::Str(c) => {
            format!("`{c}`")
        }
        Tok::Percent => "`%`".into(),
        Tok::OpenParen => "`(`".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::{Spanned, number_slice, parse_code, parse_code_general, recycle};
    use crate::ir::Span;

    /// Lowers `text` line by line, with or without the fast lane: blocks and diagnostics.
    fn lower_all(text: &str, fast: bool) -> String {
        let mut low = super::Lowerer::new(super::Options::default());
        low.fast_lane = fast;
        let (mut out, mut diags) = (Vec::new(), Vec::new());
        let mut offset = 0u64;
        for (k, raw) in text.split('\n').enumerate() {
            let line = raw.strip_suffix('\r').unwrap_or(raw);
            let span = Span {
                offset,
                len: line.len() as u32,
                line: k as u32 + 1,
            };
            offset += raw.len() as u64 + 1;
            low.line(line, span, &mut out, &mut diags);
        }
        low.finish(&mut diags);
        format!("{out:#?}\n{diags:#?}")
    }

    #[test]
    fn fast_lane_equals_the_general_path_on_the_corpus() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gcode");
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .expect("corpus")
            .map(|e| e.expect("entry").path())
            .collect();
        files.sort();
        let (mut fast_lines, mut candidates) = (0usize, 0usize);
        for path in files {
            let bytes = std::fs::read(&path).expect("read");
            let text = String::from_utf8_lossy(&bytes);
            assert_eq!(
                lower_all(&text, true),
                lower_all(&text, false),
                "{}",
                path.display()
            );
            // The fast lane does take the commonest lines.
            let mut low = super::Lowerer::new(super::Options::default());
            let (mut out, mut diags) = (Vec::new(), Vec::new());
            for line in text.lines().filter(|l| l.starts_with("G1 X")) {
                candidates += 1;
                if low.fast_move(line, Span::default(), &mut out, &mut diags) {
                    fast_lines += 1;
                }
            }
        }
        assert!(
            fast_lines * 10 > candidates * 9,
            "{fast_lines} of {candidates} `G1 X` lines took the fast lane"
        );
    }

    #[test]
    fn fast_lane_edge_cases() {
        for text in [
            "G1 X1 Y2 E.5 F1200 ; move",
            "G1 X1.;c\nG1 X.5\nG1 X+.5 Y-1.\nG0 X1E5\nG1 X1 E5",
            "G1 X1e5\nG1 X1 e5\nG1 x1\nG1 X1 X2\nG1 X-\nG1 X\nG1 X1 *12",
            "G91\nG1 X1 Y1\nG90\nG20\nG1 X1 F10\nG21\nG93\nG1 X1 F2",
            "G1 X1e400\nG1 X9999999999999\nG1 F-5 X1\nG1 F0 X1\nG2 X1 Y1 I1\nG1 X1 (c)",
            "M83\nG1 E1\nG1 E-1\nM82\nG92 E0\nG1 X1 E1\nG1  X2\t Y3  \r",
            "G0\nG1\nG1 Z\nG4 X1\nG1 G0 X1\nG1 X1 N5\nN5 G1 X1\n/G1 X1\nG1 X1 %",
        ] {
            assert_eq!(lower_all(text, true), lower_all(text, false), "{text:?}");
        }
    }

    proptest::proptest! {
        /// Generated programs of words the fast lane reads and near misses: the same
        /// blocks and diagnostics either way.
        #[test]
        fn fast_lane_equals_the_general_path(
            lines in proptest::collection::vec(
                (
                    proptest::collection::vec(
                        (
                            proptest::sample::select(vec!["G", "X", "Y", "Z", "E", "F", "x", "e", "M", "N", "I", "J", "R"]),
                            proptest::sample::select(vec![
                                "0", "1", "2", "3", "4", "17", "20", "21", "82", "83", "90", "91", "92", "93", "94",
                                "1.5", "-2.25", ".5", "-.5", "+3", "1.", "-", "", "12.3456", "1e5", "99999999999999",
                                "-0", "-0.0", "123456789012345", "1234567890.12345", "0.1234567890123456",
                                "12345678901234567", "0.30000000000000004", "007.50",
                            ]),
                            proptest::sample::select(vec![" ", "  ", "\t", ""]),
                        ),
                        0..6,
                    ),
                    proptest::sample::select(vec!["", " ; note", ";x", " (c)", " *5"]),
                ),
                1..12,
            )
        ) {
            let mut text = String::new();
            for (words, tail) in &lines {
                for (letter, number, sep) in words {
                    text.push_str(letter);
                    text.push_str(number);
                    text.push_str(sep);
                }
                text.push_str(tail);
                text.push('\n');
            }
            proptest::prop_assert_eq!(lower_all(&text, true), lower_all(&text, false), "{:?}", text);
        }
    }

    #[test]
    fn arc_without_centre_is_an_error_from_an_unknown_start() {
        let diags = crate::front::gcode::parse_str("G2 X1\n", &Default::default()).unwrap_err();
        assert_eq!(diags.len(), 1, "{diags:?}");
        assert_eq!(diags[0].code, "gcode::arc");
    }

    /// The one- and two-digit shortcut of `parse_code` gives what the general parser gives.
    #[test]
    fn code_shortcut_matches_the_general_parser() {
        let mut cases: Vec<String> = (0..1000).map(|i| i.to_string()).collect();
        cases.extend((0..100).map(|i| format!("{i:02}")));
        cases.extend(
            [
                "", "+1", "-1", "1.", "38.2", "38.20", "0.1", "a", "1a", " 1", "٣",
            ]
            .map(String::from),
        );
        for c in &cases {
            assert_eq!(parse_code(c), parse_code_general(c), "{c:?}");
        }
        assert_eq!(parse_code("07"), Some((7, 0)));
        assert_eq!(parse_code("38.2"), Some((38, 2)));
        assert_eq!(number_slice("G 01"), "01");
        assert_eq!(number_slice("X-1"), "-1");
    }

    /// The token buffer keeps its memory from line to line.
    #[test]
    fn recycled_token_buffer_keeps_its_allocation() {
        let line = String::from("G1 X1 Y2");
        let mut v: Vec<Spanned<'_>> = Vec::with_capacity(32);
        v.extend(super::super::lexer::tokens(&line));
        assert_eq!(v.len(), 3);
        let at = v.as_ptr() as usize;
        let w: Vec<Spanned<'static>> = recycle(v);
        assert!(w.is_empty());
        assert_eq!((w.as_ptr() as usize, w.capacity()), (at, 32));
    }
}
