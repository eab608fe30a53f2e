//! A plain block: its words sorted by modal group, the modal settings applied in RS274
//! execution order, and the block lowered to a move, an offset, a dwell or a command.

use super::codes::{g_group, g_known_modal, g_uses_axes};
use super::dialect::strip_line_number_and_comments;
use super::motion::Move;
use super::words::{Code, Collected, Slots, Word, collect, letter_error, parse_code};
use super::{Lowerer, MotionMode, Placement, Small};
use crate::diag::Diagnostic;
use crate::front::gcode::ast::{Item, Line};
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, FeedMode, OffsetChange, OffsetCode, Plane, Span,
    VerbatimReason,
};

/// A block's words sorted by letter: G and M codes, and the words that pass through on a
/// command (the first word of each other letter is in the block's [`Slots`]).
struct Sorted {
    g: Small<(Code, WordAt)>,
    m: Small<(Code, WordAt)>,
    /// Words of letters that are neither axes nor arc or command parameters (S, T, ...).
    rest: Small<WordAt>,
}

/// A word of the block, by its place in the block's words.
type WordAt = u32;

/// What a block's G and M codes ask for, beyond the modes they set.
#[derive(Default)]
struct Effects {
    /// A motion mode written in the block (G0-G3, or G80 ending a canned cycle).
    motion: Option<MotionMode>,
    /// A motion code the IR does not model (canned cycles, splines, probing).
    unsupported: bool,
    /// G4.
    dwell: bool,
    /// G92, G92.1, G92.2, G92.3.
    offset: Option<OffsetCode>,
    /// G53.
    machine_frame: bool,
    /// The block's axis words are a command's parameters, not a move.
    axis_user: bool,
    /// G codes that pass through on a command.
    other_g: Small<WordAt>,
    /// All G codes of the block.
    g_list: Small<Code>,
}

/// Everything a block's lowering decides on, once its modal settings are applied.
struct Parts<'w, 'a> {
    text: &'a str,
    span: Span,
    words: &'w [Word<'a>],
    bare: &'w [(usize, &'a str)],
    slots: Slots<'w, 'a>,
    named: AxisSet,
    fx: Effects,
    m_list: Small<Code>,
    /// M codes that pass through (all but M82/M83, which the lowering resolves).
    passthrough_m: Small<WordAt>,
    /// The words of the command the block holds beside (or instead of) a move, in line
    /// order.
    command_words: Small<WordAt>,
    feed_written: bool,
}

impl Lowerer {
    /// Lowers a plain block to `out`.
    pub(super) fn block(
        &mut self,
        text: &str,
        span: Span,
        line: Line,
        items: &[Item],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let line_no = span.line;
        let mut collected = Collected::default();
        if collect(text, line_no, &line, items, &mut collected, diags).is_none() {
            return;
        }
        let Collected {
            words,
            bare,
            comments,
            percent,
        } = &mut collected;
        if *percent {
            if !words.is_empty() {
                diags.push(
                    Diagnostic::error("gcode::percent", "`%` must stand alone on its line")
                        .at_bytes(line_no, text, 0, text.len()),
                );
                return;
            }
            out.push(self.delimiter(text, span));
            return;
        }
        if line.block_delete {
            out.push(self.block_delete(text, span, words, diags));
            return;
        }
        let mut parts = Parts {
            text,
            span,
            words,
            bare,
            slots: Slots {
                words,
                index: [Slots::NONE; 26],
            },
            named: AxisSet::EMPTY,
            fx: Effects::default(),
            m_list: Small::new(),
            passthrough_m: Small::new(),
            command_words: Small::new(),
            feed_written: false,
        };
        if self.resolve(&mut parts, diags).is_none() {
            return;
        }
        if self.after_call != 0
            && let Some(placement) = self.read_after_call(&parts)
        {
            self.program_started = true;
            diags.push(after_call_warning(text, line_no));
            let clobbers = if parts.named.is_empty() {
                AxisSet::EMPTY
            } else {
                AxisSet::ALL
            };
            out.push(self.verbatim(text, span, VerbatimReason::Unevaluated, clobbers, placement));
            return;
        }
        let first = out.len();
        if self.lower_parts(&parts, out, diags).is_none() {
            return;
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
        if !comments.is_empty() && !matches!(out[first].kind, BlockKind::Verbatim(_)) {
            out[first].comments = std::mem::take(comments);
        }
    }

    /// A `/` line: the controller may skip it, so it is copied as written and the axes
    /// it names become unknown.
    fn block_delete(
        &mut self,
        text: &str,
        span: Span,
        words: &[Word<'_>],
        diags: &mut Vec<Diagnostic>,
    ) -> Block {
        let named_here: AxisSet = words
            .iter()
            .filter_map(|w| Axis::from_letter(w.letter))
            .collect();
        diags.push(
            Diagnostic::warning("gcode::block-delete", "block delete `/` line is not evaluated")
                .at_bytes(span.line, text, 0, 1)
                .with_label("optional block")
                .with_help("the controller may skip it; it is copied as written and positions after it are unknown"),
        );
        self.verbatim(
            text,
            span,
            VerbatimReason::ControlFlow,
            named_here,
            Placement::TopLevel { keeps_modes: true },
        )
    }

    /// Sorts a block's words, applies its modal settings and its feed, and gathers what
    /// its lowering needs; `None` once an error is reported.
    fn resolve(&mut self, p: &mut Parts<'_, '_>, diags: &mut Vec<Diagnostic>) -> Option<()> {
        let (text, line_no) = (p.text, p.span.line);
        let mut sorted = Sorted {
            g: Small::new(),
            m: Small::new(),
            rest: Small::new(),
        };
        sort_words(text, line_no, p.words, &mut sorted, &mut p.slots, diags)?;
        if let Some(d) = modal_conflict(text, line_no, p.words, &sorted.g) {
            diags.push(d);
            return None;
        }
        p.named = Axis::ALL
            .into_iter()
            .filter(|a| p.slots.has(a.letter()))
            .collect();
        self.apply_g_codes(&sorted.g, &mut p.fx);
        self.follow_cycle_codes(&sorted.g);
        self.apply_m_codes(&sorted.m, &mut p.fx);
        if p.fx.unsupported {
            self.motion = MotionMode::Unsupported;
        } else if let Some(m) = p.fx.motion {
            self.motion = m;
        }
        p.m_list.extend(sorted.m.iter().map(|(c, _)| *c));
        // M82/M83 are resolved here; the backend puts its own extruder mode before E moves.
        p.passthrough_m.extend(
            sorted
                .m
                .iter()
                .filter(|(c, _)| !matches!(c, (82 | 83, 0)))
                .map(|&(_, w)| w),
        );
        p.feed_written = self.apply_feed(text, line_no, &p.slots, &p.fx, diags)?;
        p.command_words = command_words(p, &sorted.rest);
        Some(())
    }

    /// After a call the frontend does not expand, the distance and motion modes are
    /// whatever the subprogram left (LinuxCNC and Fanuc keep modal state across `M99`).
    /// Clears the modes the line restates; `Some` when the line must be copied as
    /// written: a move while one of them is still unknown, or a line that sets modes
    /// while the distance mode is. The controller reads it in the modes the body left,
    /// and `expand-subprograms`, which knows them, reads it again. It carries the modes
    /// it was written in only once the distance mode is known again (the backend then
    /// puts them first). G92, dwells and commands with axis words are lowered as before.
    fn read_after_call(&mut self, p: &Parts<'_, '_>) -> Option<Placement> {
        use super::after_call::{DISTANCE, MOTION};
        if p.fx.g_list.iter().any(|c| matches!(c, (90 | 91, 0))) {
            self.after_call &= !DISTANCE;
        }
        if p.fx.motion.is_some() || p.fx.unsupported {
            self.after_call &= !MOTION;
        }
        let call = p.m_list.iter().any(|c| matches!(c, (98 | 99, 0)));
        if self.after_call == 0 || call || p.fx.offset.is_some() || p.fx.dwell || p.fx.axis_user {
            return None;
        }
        let distance_known = self.after_call & DISTANCE == 0;
        let copied = if p.named.is_empty() {
            !p.fx.g_list.is_empty() && !distance_known
        } else {
            true
        };
        copied.then_some(if distance_known {
            Placement::TopLevel { keeps_modes: false }
        } else {
            Placement::Inside
        })
    }

    /// Applies the block's G codes to the modal state, in RS274 execution order, and
    /// returns what else they ask for.
    fn apply_g_codes(&mut self, g_codes: &[(Code, WordAt)], fx: &mut Effects) {
        for &(code, w) in g_codes {
            fx.g_list.push(code);
            match code {
                (0, 0) => fx.motion = Some(MotionMode::Rapid),
                (1, 0) => fx.motion = Some(MotionMode::Linear),
                (2, 0) => fx.motion = Some(MotionMode::Arc { clockwise: true }),
                (3, 0) => fx.motion = Some(MotionMode::Arc { clockwise: false }),
                // G80 cancels a canned cycle; Mach3 programs also write it beside G0.
                // Ending a cycle it is printed, so a controller with cycles leaves them
                // (`expand-cycles` drops it for controllers without).
                (80, 0) => {
                    if self.motion == MotionMode::Unsupported {
                        fx.other_g.push(w);
                        if fx.motion.is_none() {
                            fx.motion = Some(MotionMode::None);
                        }
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
                (4, 0) => fx.dwell = true,
                (53, 0) => fx.machine_frame = true,
                (92, minor @ 0..=3) => {
                    fx.offset = Some(match minor {
                        0 => OffsetCode::Set,
                        1 => OffsetCode::Clear,
                        2 => OffsetCode::Suspend,
                        _ => OffsetCode::Restore,
                    })
                }
                c if g_group(c) == Some("motion") => {
                    fx.unsupported = true;
                    fx.other_g.push(w);
                }
                c if g_uses_axes(c) => {
                    fx.axis_user = true;
                    fx.other_g.push(w);
                }
                c => {
                    // A code the IR does not know may move or redefine coordinates
                    // (G68.2, G65, G6600): its axis words are its own, not a move.
                    if !g_known_modal(c) && fx.motion.is_none() {
                        fx.axis_user = true;
                    }
                    fx.other_g.push(w)
                }
            }
        }
    }

    /// Applies the block's M codes to the modal state (M82/M83).
    fn apply_m_codes(&mut self, m_codes: &[(Code, WordAt)], fx: &mut Effects) {
        for (code, _) in m_codes {
            match *code {
                (82, 0) => self.relative_e = false,
                (83, 0) => self.relative_e = true,
                // Standard machine M codes never take axis words; on any other M code
                // (M92, M201, M203, M584, ...) axis letters are its parameters.
                (0..=9 | 30 | 48..=53 | 60..=68, _) => {}
                _ if fx.motion.is_none() => fx.axis_user = true,
                _ => {}
            }
        }
    }

    /// F applies to this block and after (in G93 it is per block); a dwell's F is its
    /// own. Returns whether the block sets the feed; `None` on a negative feed.
    fn apply_feed(
        &mut self,
        text: &str,
        line_no: u32,
        slots: &Slots<'_, '_>,
        fx: &Effects,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<bool> {
        let Some(f) = slots.get('F') else {
            return Some(false);
        };
        if fx.dwell {
            return Some(false);
        }
        if f.value < 0.0 {
            diags.push(
                Diagnostic::error("gcode::feed", format!("negative feed `{}`", f.text))
                    .at_bytes(line_no, text, f.start, f.end)
                    .with_label("below zero")
                    .with_help("F is a speed and must not be negative"),
            );
            return None;
        }
        self.feed = Some(f.value * self.feed_scale());
        Some(true)
    }

    /// Lowers a resolved block to `out`; `None` once an error is reported.
    fn lower_parts(
        &mut self,
        p: &Parts<'_, '_>,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<()> {
        let (text, span, line_no) = (p.text, p.span, p.span.line);
        let is_move = !p.named.is_empty()
            || (p.fx.motion.is_some() && !p.bare.is_empty())
            || (matches!(p.fx.motion, Some(MotionMode::Arc { .. })) && p.slots.has_centre());
        if let Some(code) = p.fx.offset {
            let declared = self.apply_offset(code, &p.slots, p.named, line_no, text, diags);
            if !p.command_words.is_empty() {
                out.push(self.command_of(p, &p.command_words, p.named, false));
            }
            out.push(Block::new(
                span,
                BlockKind::Offset(OffsetChange {
                    code,
                    declared,
                    offsets: self.offsets,
                }),
            ));
        } else if p.fx.dwell {
            out.push(self.dwell(p));
        } else if p.fx.axis_user {
            out.push(self.axis_command(p));
        } else if is_move {
            if let Some(&(s, l)) = p.bare.first() {
                diags.push(letter_error(line_no, text, s, l));
                return None;
            }
            self.lower_move(p, out, diags)?;
        } else if let Some(&(s, l)) = p.bare.first() {
            if p.passthrough_m.is_empty() && p.fx.other_g.is_empty() {
                diags.push(letter_error(line_no, text, s, l));
                return None;
            }
            // `M84 X Y`, `G28 X Y`: letters are the command's arguments.
            let mut cmd = self.command_of(p, &p.command_words, AxisSet::EMPTY, false);
            if let BlockKind::Command(c) = &mut cmd.kind {
                c.text = strip_line_number_and_comments(text).into();
            }
            out.push(cmd);
        } else if !p.command_words.is_empty() {
            out.push(self.command_of(p, &p.command_words, AxisSet::EMPTY, false));
        }
        Some(())
    }

    /// [`Lowerer::command`] with the block's codes.
    fn command_of(
        &mut self,
        p: &Parts<'_, '_>,
        words: &[WordAt],
        named: AxisSet,
        with_axes: bool,
    ) -> Block {
        let words: Small<Word<'_>> = words.iter().map(|&at| p.words[at as usize]).collect();
        self.command(p.span, &words, &p.fx.g_list, &p.m_list, named, with_axes)
    }

    /// G4: a dwell block, or the words as written for a dialect's dwell (`G4 F0.25`,
    /// bare `G4`).
    fn dwell(&mut self, p: &Parts<'_, '_>) -> Block {
        match self.dwell_seconds(&p.slots) {
            Some(seconds) => Block::new(p.span, BlockKind::Dwell { seconds }),
            None => {
                let words: Small<WordAt> = (0..p.words.len() as WordAt)
                    .filter(|&at| p.words[at as usize].letter != 'N')
                    .collect();
                self.command_of(p, &words, AxisSet::EMPTY, false)
            }
        }
    }

    /// A command whose axis words are its parameters (homing, probing, M201 X2500).
    fn axis_command(&mut self, p: &Parts<'_, '_>) -> Block {
        let mut words = p.command_words.clone();
        words.extend(p.named.iter().filter_map(|a| p.slots.at(a.letter())));
        // A probe's or homing command's feed is its own (and stays modal).
        words.extend(p.slots.at('F'));
        // Words sit in the block in line order.
        words.sort_unstable();
        // Bare letters name axes too (`G28 X Z` homes X and Z).
        let bare_axes: AxisSet = p
            .bare
            .iter()
            .filter_map(|(_, l)| l.chars().next().and_then(Axis::from_letter))
            .collect();
        // Only G codes take coordinates in the current units and distance mode; an M
        // code's axis words are settings (`M201 X2500`, `M563 X3`).
        let coordinates = !p.fx.other_g.is_empty() && !p.named.is_empty();
        let mut cmd = self.command_of(p, &words, p.named.union(bare_axes), coordinates);
        if !p.bare.is_empty()
            && let BlockKind::Command(c) = &mut cmd.kind
        {
            // `G28 X Z`, `G6 B20 R`: bare letters are arguments; keep the words as written.
            c.text = strip_line_number_and_comments(p.text).into();
        }
        cmd
    }

    /// A block with axis words in the motion mode in force.
    fn lower_move(
        &mut self,
        p: &Parts<'_, '_>,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<()> {
        let (text, span, line_no) = (p.text, p.span, p.span.line);
        match self.motion {
            MotionMode::Unsupported if self.in_cycle() => {
                out.push(self.cycle_block(text, span, &p.slots, diags));
                Some(())
            }
            MotionMode::Unsupported => {
                diags.push(
                    Diagnostic::warning(
                        "gcode::unsupported-motion",
                        "motion mode is not modelled (canned cycle, spline, probing or threading)",
                    )
                    .at_bytes(line_no, text, 0, text.len())
                    .with_label("passes through unchanged")
                    .with_help(
                        "the block is copied as written; positions after it are treated as unknown",
                    ),
                );
                out.push(self.verbatim(
                    text,
                    span,
                    VerbatimReason::Unevaluated,
                    AxisSet::ALL,
                    Placement::TopLevel { keeps_modes: true },
                ));
                Some(())
            }
            MotionMode::None => {
                let w = p.named.iter().find_map(|a| p.slots.axis(a));
                let (s, e) = w.map_or((0, text.len()), |w| (w.start, w.end));
                diags.push(
                    Diagnostic::error(
                        "gcode::no-motion-mode",
                        "axis words with no motion mode in force",
                    )
                    .at_bytes(line_no, text, s, e)
                    .with_label("where should this go?")
                    .with_help("start the block with G0 or G1"),
                );
                None
            }
            mode => {
                // Words other than the move's (M, T, S, unknown letters) ride along on its line.
                let extra: Small<&str> = p
                    .command_words
                    .iter()
                    .map(|&at| p.words[at as usize].text)
                    .collect();
                let mv = Move {
                    mode,
                    slots: &p.slots,
                    named: p.named,
                    machine_frame: p.fx.machine_frame,
                    feed_written: p.feed_written,
                    extra: &extra,
                };
                self.motion_block(text, span, &mv, out, diags)
            }
        }
    }
}

/// The warning on a line copied as written after a call: its modes are the body's.
fn after_call_warning(text: &str, line_no: u32) -> Diagnostic {
    Diagnostic::warning(
        AFTER_CALL,
        "this line moves in the distance or motion mode the subprogram called before it left",
    )
    .at_bytes(line_no, text, 0, text.trim_end().len())
    .with_label("copied as written")
    .with_help("the controller reads it in the modes the subprogram returned in; write G90 or G91 and G0 or G1 on it (or before it) to have it read here, or let expand-subprograms read it")
}

/// The code of [`after_call_warning`]: `expand-subprograms` takes it back on the lines it
/// reads again.
const AFTER_CALL: &str = "gcode::after-call";

/// Sorts a block's words by letter; `None` once an error is reported (a G or M word that
/// is not a code, a letter given twice).
fn sort_words(
    text: &str,
    line_no: u32,
    words: &[Word<'_>],
    sorted: &mut Sorted,
    slots: &mut Slots<'_, '_>,
    diags: &mut Vec<Diagnostic>,
) -> Option<()> {
    for (wi, w) in words.iter().enumerate() {
        match w.letter {
            'G' | 'M' => {
                let Some(code) = parse_code(w.number()) else {
                    diags.push(
                        Diagnostic::error(
                            "gcode::code",
                            format!("`{}` is not a valid code", w.text),
                        )
                        .at_bytes(line_no, text, w.start, w.end),
                    );
                    return None;
                };
                if w.letter == 'G' {
                    sorted.g.push((code, wi as WordAt));
                } else {
                    sorted.m.push((code, wi as WordAt));
                }
            }
            'N' => {}
            l => {
                let slot = &mut slots.index[(l as u8 - b'A') as usize];
                if *slot != Slots::NONE
                    && (Axis::from_letter(l).is_some()
                        || matches!(l, 'F' | 'I' | 'J' | 'K' | 'R' | 'S'))
                {
                    let prev = words[*slot as usize];
                    diags.push(
                        Diagnostic::error(
                            "gcode::duplicate-word",
                            format!("the word `{l}` appears twice in one block"),
                        )
                        .at_bytes(line_no, text, w.start, w.end)
                        .with_label(format!("second `{l}`; the first is `{}`", prev.text))
                        .with_help("a block may give each letter once; split it into two blocks"),
                    );
                    return None;
                }
                if *slot == Slots::NONE {
                    *slot = wi as u32;
                }
                if Axis::from_letter(l).is_none() && !matches!(l, 'F' | 'I' | 'J' | 'K' | 'R' | 'P')
                {
                    sorted.rest.push(wi as WordAt);
                }
            }
        }
    }
    Some(())
}

/// Two G codes of one modal group in a block.
fn modal_conflict(
    text: &str,
    line_no: u32,
    words: &[Word<'_>],
    g_codes: &[(Code, WordAt)],
) -> Option<Diagnostic> {
    for (i, &(code, at)) in g_codes.iter().enumerate() {
        let w = words[at as usize];
        if let Some(group) = g_group(code)
            && group != "non-modal"
            && let Some(&(_, first)) = g_codes[..i]
                .iter()
                .find(|(c, _)| g_group(*c) == Some(group))
        {
            let first = words[first as usize];
            return Some(
                Diagnostic::error(
                    "gcode::modal-conflict",
                    format!(
                        "`{}` and `{}` are both in the {group} group",
                        first.text, w.text
                    ),
                )
                .at_bytes(line_no, text, w.start, w.end)
                .with_label("conflicts with an earlier code")
                .with_help("a block may hold one code of each modal group"),
            );
        }
    }
    None
}

/// The words of the command a block holds, in line order: G and M codes the IR does not
/// model and the other letters; with the command's own parameters (`G54.1 P2`,
/// `M98 P1 L2`) unless the block is a move or a dwell.
fn command_words(p: &Parts<'_, '_>, rest: &[WordAt]) -> Small<WordAt> {
    let mut v: Small<WordAt> = Small::new();
    v.extend(
        p.fx.other_g
            .iter()
            .chain(p.passthrough_m.iter())
            .chain(rest.iter())
            .copied(),
    );
    let arc_here = matches!(p.fx.motion, Some(MotionMode::Arc { .. })) && p.slots.has_centre();
    let becomes_motion =
        !p.fx.axis_user && p.fx.offset.is_none() && (!p.named.is_empty() || arc_here);
    if !p.fx.dwell && !becomes_motion {
        for l in ['I', 'J', 'K', 'R', 'P'] {
            if let Some(at) = p.slots.at(l) {
                v.push(at);
            }
        }
    }
    // Words sit in the block in line order.
    if v.len() > 1 {
        v.sort_unstable();
    }
    v
}
