//! Lines outside the plain block grammar: LinuxCNC o-word control flow, RepRapFirmware
//! meta commands, parameters and expressions. They pass through as text, with a warning,
//! and the positions they may change become unknown.

use super::codes::contains_m99;
use super::{Lowerer, Placement, Unplain};
use crate::diag::Diagnostic;
use crate::front::gcode::lexer::{Spanned, Tok, lex_line};
use crate::ir::{AxisSet, Block, BlockKind, Command, Comment, CommentStyle, Span, VerbatimReason};
use crate::num::lexer::Assigned;

use crate::num::lexer::RRF_META_KEYWORDS as META_KEYWORDS;
/// Meta keywords that open an indented block.
const META_BLOCK_KEYWORDS: &[&str] = &["if", "elif", "else", "while"];

impl Lowerer {
    /// Handles an o-word line (LinuxCNC control flow).
    pub(super) fn oword(
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
        self.follow_sub(&label, top_level, &kw);
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
                let label = oword_call(text).and_then(|c| c.label);
                // Modes an earlier call left unknown stay so until restated.
                self.after_call |= self
                    .sub_modes
                    .iter()
                    .find(|(l, _)| Some(l) == label.as_ref())
                    .map_or(super::after_call::ALL, |&(_, bits)| bits);
            }
        }
        out.push(block);
    }

    /// Follows the o-word subroutines defined at the top level: which of the modes a
    /// call leaves unknown ([`super::after_call`]) their lines may change. A call inside
    /// one may change any.
    fn follow_sub(&mut self, label: &str, top_level: bool, kw: &str) {
        match kw {
            "sub" if top_level => {
                self.reading_sub = normal_label(label).map(|l| (l, 0));
            }
            "endsub" if self.oword_stack.len() == 1 => {
                if let Some(sub) = self.reading_sub.take() {
                    self.sub_modes.push(sub);
                }
            }
            "call" => {
                if let Some((_, bits)) = &mut self.reading_sub {
                    *bits = super::after_call::ALL;
                }
            }
            _ => {}
        }
    }

    /// Decides whether a line is outside the plain block grammar; reports why.
    pub(super) fn unplain(
        &mut self,
        text: &str,
        line_no: u32,
        toks: &[Spanned<'_>],
        diags: &mut Vec<Diagnostic>,
    ) -> Option<Unplain> {
        // Words, letters and comments alone are the plain block grammar.
        if toks.iter().all(|t| {
            matches!(
                t.1,
                Tok::Word(_) | Tok::Letter(_) | Tok::Comment(_) | Tok::LineComment(_)
            )
        }) {
            return None;
        }
        if let Some(d) = misplaced_checksum(text, line_no, toks) {
            diags.push(d);
            return Some(Unplain::Error);
        }
        let mut expression = None;
        let mut odd = None;
        for (i, &(s, tok, e)) in toks.iter().enumerate() {
            match tok {
                Tok::Other(c) if is_expression_char(c) => {
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
        let assignment = expression.and_then(|_| self.assignment_clobbers(toks));
        let help = match assignment {
            None => "the line is copied as written; positions after it are treated as unknown".to_string(),
            Some(c) if c.is_empty() => "the line is copied as written; it only sets parameters, which move nothing: positions after it stay known".to_string(),
            Some(c) => format!(
                "the line is copied as written; it sets a system parameter that holds an offset, after which {} {} unknown",
                axis_names(c),
                if c.iter().count() == 1 { "is" } else { "are" }
            ),
        };
        diags.push(
            Diagnostic::warning(
                "gcode::unevaluated",
                "line is not plain G-code: parameters, expressions or dialect syntax are not evaluated",
            )
            .at_bytes(line_no, text, s, e)
            .with_label("not evaluated")
            .with_help(help),
        );
        Some(assignment.map_or(Unplain::Unevaluated, Unplain::Assignment))
    }

    /// A RepRapFirmware meta command (`if`, `while`, `var`, `echo`...) passes through,
    /// with the block indented below it; `false` when the line is not one.
    pub(super) fn meta_command(
        &mut self,
        text: &str,
        span: Span,
        indent: usize,
        toks: &[Spanned<'_>],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> bool {
        let Some(Tok::Ident(word)) = toks.first().map(|t| t.1) else {
            return false;
        };
        let lower = word.to_ascii_lowercase();
        if !META_KEYWORDS.contains(&lower.as_str()) {
            return false;
        }
        if META_BLOCK_KEYWORDS.contains(&lower.as_str()) {
            self.meta_indent = Some(indent);
        }
        diags.push(
            Diagnostic::warning(
                "gcode::meta-command",
                format!("RepRapFirmware meta command `{lower}` is not evaluated"),
            )
            .at_bytes(span.line, text, toks[0].0, toks[0].2)
            .with_label("passes through unchanged")
            .with_help(
                "the line (and the block indented below it) is copied as written; \
                 positions after it are treated as unknown",
            ),
        );
        out.push(self.pass_through(text, span, VerbatimReason::ControlFlow));
        true
    }

    /// A Fanuc program number (`O1000`): at the top a label, after the main program the
    /// start of a subprogram, whose body passes through up to its M99. `false` when the
    /// line is not one.
    pub(super) fn program_number(
        &mut self,
        text: &str,
        span: Span,
        toks: &[Spanned<'_>],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> bool {
        let Some(&(s, Tok::Word(w), e)) = toks.first() else {
            return false;
        };
        if !w.starts_with(['O', 'o']) {
            return false;
        }
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
                .at_bytes(span.line, text, s, e)
                .with_label("body copied as written up to its M99")
                .with_help("the expand-subprograms pass inlines M98 calls when it is available"),
            );
            out.push(self.pass_through(text, span, VerbatimReason::Subprogram));
        } else {
            out.push(self.delimiter(text, span));
        }
        true
    }

    /// Lowers a line that [`Lowerer::unplain`] set aside: a command with arguments that
    /// are not plain words, or a line passed through as written.
    /// Prusa firmware's `G80` is mesh bed levelling (its `X Y W H` words are the probed
    /// area), not a canned-cycle cancel: under the `prusa` dialect it passes as a command,
    /// after which the head's position is unknown (it probed the bed). `false` when the
    /// line is not one.
    pub(super) fn prusa_mesh_levelling(
        &mut self,
        text: &str,
        span: Span,
        toks: &[Spanned<'_>],
        out: &mut Vec<Block>,
    ) -> bool {
        if self.dialect != crate::ir::Dialect::Prusa {
            return false;
        }
        // The command word: the first word but a line number.
        let first = toks.iter().find_map(|t| match t.1 {
            Tok::Word(w) if !w.as_bytes()[0].eq_ignore_ascii_case(&b'N') => Some(w),
            _ => None,
        });
        let is_g80 = first.is_some_and(|w| {
            w.as_bytes()[0].eq_ignore_ascii_case(&b'G')
                && super::words::parse_code(super::words::number_slice(w)) == Some((80, 0))
        });
        if !is_g80 {
            return false;
        }
        out.push(self.command_as_written(text, span, toks, AxisSet::ALL));
        true
    }

    /// A line passed on as a command with its words as written, after which `clobbers`
    /// are unknown.
    fn command_as_written(
        &mut self,
        text: &str,
        span: Span,
        toks: &[Spanned<'_>],
        clobbers: AxisSet,
    ) -> Block {
        self.program_started = true;
        self.pos.forget(clobbers);
        let mut block = Block::new(
            span,
            BlockKind::Command(Command {
                text: strip_line_number_and_comments(text).into(),
                modes: None,
                clobbers,
            }),
        );
        block.comments = comments_of(text, toks);
        block
    }

    pub(super) fn lower_unplain(
        &mut self,
        text: &str,
        span: Span,
        toks: &[Spanned<'_>],
        reason: Unplain,
        out: &mut Vec<Block>,
    ) {
        match reason {
            Unplain::Command => {
                let clob = self.command_clobbers(toks);
                out.push(self.command_as_written(text, span, toks, clob));
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
            Unplain::Assignment(clobbers) => {
                // It names no mode and no motion: the modes and the canned cycle in force
                // stay, as on the controller.
                out.push(self.verbatim(
                    text,
                    span,
                    VerbatimReason::Unevaluated,
                    clobbers,
                    Placement::TopLevel { keeps_modes: true },
                ));
            }
            Unplain::Error => {}
        }
    }

    /// For a line that only sets parameters (`#1 = [#1 + 1]`), the axes whose position it
    /// can change; `None` for any other line.
    ///
    /// A parameter moves nothing; only the system parameters that hold offsets change
    /// what the program's coordinates mean, and so where the tool is in them (LinuxCNC,
    /// "Numbered Parameters" in the G-code overview): the G92 offsets `#5211`–`#5219`
    /// (one axis each, X Y Z A B C U V W) and their switch `#5210`, the coordinate
    /// system number `#5220`, the G54–G59.3 offsets `#5221`–`#5390` (20 per system: one
    /// axis each, then the XY rotation R), the tool offsets `#5401`–`#5409`. The stored
    /// G28/G30 positions (`#5161`–`#5189`) matter only to a later G28/G30, after which
    /// the axes are unknown anyway; `#5420`–`#5428` (the current position) are read-only.
    /// Any other parameter above 5000, and a computed parameter number, may be any of
    /// these: every axis. Under the `fanuc` dialect every variable from 1000 up is a
    /// system variable (tool offsets `#2001`…, work offsets `#5201`…, `#7001`…): every
    /// axis. Named parameters are the program's own (the named system ones are read-only).
    fn assignment_clobbers(&self, toks: &[Spanned<'_>]) -> Option<AxisSet> {
        let mut clobbers = AxisSet::EMPTY;
        let fanuc = self.dialect == crate::ir::Dialect::Fanuc;
        let only = crate::num::lexer::parameter_assignments(toks, |a| {
            let n = match a {
                Assigned::Number(n) => crate::num::parse_decimal(n).unwrap_or(f64::INFINITY),
                Assigned::Named => return,
                Assigned::Computed => f64::INFINITY,
            };
            clobbers = clobbers.union(system_parameter_axes(n, fanuc));
        });
        only.then_some(clobbers)
    }
}

/// The axes whose position in program coordinates a parameter `n` can change (see
/// [`Lowerer::assignment_clobbers`]).
fn system_parameter_axes(n: f64, fanuc: bool) -> AxisSet {
    // X Y Z A B C U V W: the order of LinuxCNC's per-axis parameters and of `Axis::ALL`.
    let axis = |k: u32| {
        let mut set = AxisSet::EMPTY;
        set.insert(crate::ir::Axis::ALL[k as usize]);
        set
    };
    if n.fract() != 0.0 || (fanuc && n >= 1000.0) {
        return AxisSet::ALL;
    }
    let n = n as u32;
    match n {
        0..=5000 | 5161..=5169 | 5181..=5189 | 5420..=5428 => AxisSet::EMPTY,
        5211..=5219 => axis(n - 5211),
        5401..=5409 => axis(n - 5401),
        5221..=5390 => match (n - 5221) % 20 {
            k @ 0..=8 => axis(k),
            // The rotation of the XY plane.
            9 => axis(0).union(axis(1)),
            _ => AxisSet::ALL,
        },
        _ => AxisSet::ALL,
    }
}

/// `X Y` for a set of axes.
fn axis_names(set: AxisSet) -> String {
    set.iter()
        .map(|a| a.letter().to_string())
        .collect::<Vec<_>>()
        .join(" ")
}

/// The o-word keyword of a LinuxCNC control line (`o100 sub`, `o<x> if [..]`).
pub(super) fn oword_keyword<'a>(toks: &[Spanned<'a>]) -> Option<&'a str> {
    match crate::num::lexer::oword_keyword(toks)?.1 {
        Tok::Ident(w) => Some(w),
        _ => None,
    }
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

/// An o-word label as calls and definitions name it: a number without leading zeros,
/// or a `<name>` in lower case; `None` for an expression.
fn normal_label(raw: &str) -> Option<String> {
    if let Some(digits) = raw
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
    }
}

/// The modes a line of a subroutine may change, as [`super::after_call`] bits: G90/G91,
/// a motion code (G0-G3, G33, G38.x, the cycles, G80), and anything from a `G` with an
/// expression, a macro call (`G65`) or a subprogram call (`M98`).
pub(super) fn modes_set(toks: &[Spanned<'_>]) -> u8 {
    use super::after_call::{ALL, DISTANCE, MOTION};
    let mut bits = 0;
    for &(_, t, _) in toks {
        let (letter, number) = match t {
            Tok::Word(w) => (w.as_bytes()[0].to_ascii_uppercase(), w[1..].trim_start()),
            Tok::Letter(w) if w.eq_ignore_ascii_case("G") => return ALL,
            _ => continue,
        };
        let n = crate::num::parse_decimal(number);
        bits |= match (letter, n) {
            (b'G', Some(n)) if n == 90.0 || n == 91.0 => DISTANCE,
            (b'G', Some(65.0)) => ALL,
            (b'G', Some(n))
                if (n <= 3.0 && n.fract() == 0.0)
                    || (33.0..34.0).contains(&n)
                    || (38.0..39.0).contains(&n)
                    || (73.0..=89.0).contains(&n) =>
            {
                MOTION
            }
            (b'G', None) => ALL,
            (b'M', Some(98.0)) => ALL,
            _ => 0,
        };
    }
    bits
}

/// Reads an o-word call line; `None` when the line is not one.
pub(crate) fn oword_call(text: &str) -> Option<OwordCall> {
    let toks: Vec<Spanned<'_>> = crate::front::gcode::lexer::tokens(text).collect();
    let kw = oword_keyword(&toks)?;
    if !kw.eq_ignore_ascii_case("call") {
        return None;
    }
    let kw_at = toks
        .iter()
        .position(|t| matches!(t.1, Tok::Ident(w) if w.eq_ignore_ascii_case("call")))?;
    let raw = text[toks[0].0 + 1..toks[kw_at].0].trim();
    let label = normal_label(raw);
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
pub(super) fn oword_label(text: &str, toks: &[Spanned<'_>]) -> String {
    let end = toks
        .iter()
        .skip(1)
        .find(|t| matches!(t.1, Tok::Ident(_)))
        .map_or(text.len(), |t| t.0);
    text[toks[0].0 + 1..end].trim().to_ascii_lowercase()
}

/// The comments of a line passed through as a command, without their delimiters.
pub(super) fn comments_of(text: &str, toks: &[Spanned<'_>]) -> Vec<Comment> {
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
pub(super) fn strip_line_number_and_comments(text: &str) -> String {
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

/// A checksum ends the line: the error for anything but a comment after it (on a line
/// without expressions, where `*` may be a product).
fn misplaced_checksum(text: &str, line_no: u32, toks: &[Spanned<'_>]) -> Option<Diagnostic> {
    let has_expression = toks
        .iter()
        .any(|t| matches!(t.1, Tok::Other(c) if is_expression_char(c)));
    if has_expression {
        return None;
    }
    let i = toks.iter().position(|t| matches!(t.1, Tok::Checksum(_)))?;
    let &(s, _, e) = toks[i + 1..]
        .iter()
        .find(|t| !matches!(t.1, Tok::LineComment(_) | Tok::Comment(_)))?;
    let (cs, ce) = (toks[i].0, toks[i].2);
    Some(
        Diagnostic::error(
            "gcode::checksum-position",
            format!("checksum `{}` must end the line", &text[cs..ce]),
        )
        .at_bytes(line_no, text, cs, ce)
        .with_label("followed by more words")
        .with_help(format!(
            "move `{}` (and everything after it) before the checksum, or remove the checksum",
            &text[s..e]
        )),
    )
}

/// Whether a character the lexer has no token for belongs to expression syntax:
/// parameters (`#`), expressions (`[ ]`), RepRapFirmware `{ }` and comparisons.
fn is_expression_char(c: &str) -> bool {
    matches!(
        c.as_bytes(),
        [b'#' | b'[' | b']' | b'{' | b'}' | b'=' | b'<' | b'>' | b'@' | b'^']
    )
}

#[cfg(test)]
mod tests {
    use super::system_parameter_axes;
    use crate::ir::{Axis, AxisSet};

    fn axes(list: &[Axis]) -> AxisSet {
        let mut s = AxisSet::EMPTY;
        for &a in list {
            s.insert(a);
        }
        s
    }

    /// LinuxCNC's numbered parameters: what each offset parameter can change.
    #[test]
    fn system_parameters_forget_the_axes_of_their_offsets() {
        assert_eq!(system_parameter_axes(1.0, false), AxisSet::EMPTY);
        assert_eq!(system_parameter_axes(5000.0, false), AxisSet::EMPTY);
        assert_eq!(system_parameter_axes(5161.0, false), AxisSet::EMPTY); // G28 X
        assert_eq!(system_parameter_axes(5211.0, false), axes(&[Axis::X])); // G92 X
        assert_eq!(system_parameter_axes(5219.0, false), axes(&[Axis::W])); // G92 W
        assert_eq!(system_parameter_axes(5210.0, false), AxisSet::ALL); // G92 on/off
        assert_eq!(system_parameter_axes(5223.0, false), axes(&[Axis::Z])); // G54 Z
        assert_eq!(system_parameter_axes(5242.0, false), axes(&[Axis::Y])); // G55 Y
        assert_eq!(
            system_parameter_axes(5230.0, false), // G54 R
            axes(&[Axis::X, Axis::Y])
        );
        assert_eq!(system_parameter_axes(5403.0, false), axes(&[Axis::Z])); // tool Z
        assert_eq!(system_parameter_axes(5422.0, false), AxisSet::EMPTY); // read-only
        assert_eq!(system_parameter_axes(5600.0, false), AxisSet::ALL);
        // Fanuc macro B: #2001 is a tool offset.
        assert_eq!(system_parameter_axes(2001.0, false), AxisSet::EMPTY);
        assert_eq!(system_parameter_axes(2001.0, true), AxisSet::ALL);
        assert_eq!(system_parameter_axes(1.5, false), AxisSet::ALL);
    }
}
