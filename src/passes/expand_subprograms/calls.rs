//! Reading call lines: Fanuc `M98 P<n> L<count>` and LinuxCNC `o<n> call`.

use super::defs::{file_call, word_positions};
use super::lower::{Lowering, OwordCall};
use super::{Call, Key, Options, Reach};
use crate::diag::Diagnostic;
use crate::ir::{Block, BlockKind};
use crate::num::lexer::{Tok, tokens};

/// A call in the main program: the call and the text its columns refer to.
pub(super) fn main_call(
    block: &Block,
    options: &Options,
    lowering: &dyn Lowering,
) -> Option<(Call, String)> {
    let text = match &block.kind {
        BlockKind::Command(c) => c.text.as_str(),
        BlockKind::Verbatim(v) if v.reason != crate::ir::VerbatimReason::Subprogram => {
            v.text.as_str()
        }
        _ => return None,
    };
    let call = classify(block, text, options, lowering)?;
    Some((call, text.to_owned()))
}

/// A call in a body line `text`, lowered to `block`.
pub(super) fn body_call(
    block: &Block,
    text: &str,
    options: &Options,
    lowering: &dyn Lowering,
) -> Option<Call> {
    match &block.kind {
        BlockKind::Command(_) | BlockKind::Verbatim(_) => classify(block, text, options, lowering),
        _ => None,
    }
}

/// Reads the call in `text` (the line of `block`), if it is one.
fn classify(block: &Block, text: &str, options: &Options, lowering: &dyn Lowering) -> Option<Call> {
    let line = block.span.line;
    let inside_flow = match &block.kind {
        BlockKind::Verbatim(v) => v.modes.is_none(),
        _ => false,
    };
    match lowering.oword_call(text) {
        Some(c) => Some(oword(c, line, text, inside_flow)),
        None => fanuc(line, text, options, inside_flow),
    }
}

/// The warning for a call that passes through unchanged.
fn not_expanded(
    line: u32,
    text: &str,
    msg: String,
    (s, e): (usize, usize),
    help: &str,
) -> Diagnostic {
    Diagnostic::warning("subprograms::not-expanded", msg)
        .at_bytes(line, text, s, e)
        .with_label("passes through unchanged")
        .with_help(help.to_string())
}

/// An o-word call line `text` (line `line`).
fn oword(c: OwordCall, line: u32, text: &str, inside_flow: bool) -> Call {
    let not_expanded = |msg, at, help| not_expanded(line, text, msg, at, help);
    let reach = match &c.label {
        Some(l) => Reach::One(Key::Oword(l.clone())),
        None => Reach::AllOword,
    };
    if inside_flow {
        return Call::Opaque {
            warning: not_expanded(
                "a call inside o-word control flow is not expanded".into(),
                c.at,
                "the condition or loop around it is evaluated by the controller; the subroutine stays in the output",
            ),
            reach,
        };
    }
    if !c.simple {
        let what = if c.label.is_none() {
            "a call to a computed subroutine number is not expanded"
        } else {
            "a call with arguments is not expanded"
        };
        return Call::Opaque {
            warning: not_expanded(
                what.into(),
                (c.at.0, text.trim_end().len()),
                "parameters and expressions are not evaluated; the call and its subroutine stay in the output for the controller",
            ),
            reach,
        };
    }
    let label = c.label.unwrap_or_default();
    Call::Expand {
        key: Key::Oword(label),
        count: 1,
        at: c.at,
    }
}

/// A Fanuc `M98` call line `text` (line `line`), if it is one (a RepRapFirmware macro
/// call `M98 P"file.g"` is not: it runs a file on the controller).
fn fanuc(line: u32, text: &str, options: &Options, inside_flow: bool) -> Option<Call> {
    let not_expanded = |msg, at, help| not_expanded(line, text, msg, at, help);
    if file_call(text) {
        return None;
    }
    let m98 = word_positions(text, 'M')
        .into_iter()
        .find(|(_, _, n)| n.as_deref().and_then(crate::num::parse_decimal) == Some(98.0))?;
    let m98_at = (m98.0, m98.1);
    let expression = tokens(text).any(|t| matches!(t.1, Tok::Other(c) if "#[]".contains(c)));
    if expression || inside_flow {
        let msg = if expression {
            "a call with an expression (parameters) is not expanded"
        } else {
            "a call inside o-word control flow is not expanded"
        };
        return Some(Call::Opaque {
            warning: not_expanded(
                msg.into(),
                (m98_at.0, text.trim_end().len()),
                "the controller evaluates it; the subprograms stay in the output",
            ),
            reach: Reach::AllFanuc,
        });
    }
    let Some((ps, pe, Some(p))) = word_positions(text, 'P').into_iter().next() else {
        return Some(Call::Bad(
            Diagnostic::error("subprograms::call", "M98 without a program number P")
                .at_bytes(line, text, m98_at.0, m98_at.1)
                .with_label("which program?")
                .with_help("write the program number after P: `M98 P10`"),
        ));
    };
    let digits = p.trim_start_matches('+');
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || digits.len() > 9 {
        return Some(Call::Bad(
            Diagnostic::error(
                "subprograms::call",
                format!("`P{p}` is not a program number"),
            )
            .at_bytes(line, text, ps, pe)
            .with_label("not a whole number")
            .with_help("program numbers are whole numbers from 0 to 99999999"),
        ));
    }
    let number: u32 = digits.parse().ok()?;
    let (program, count, count_at) =
        match repeat(line, text, options, (number, digits, &p), (ps, pe), m98_at)? {
            Ok(r) => r,
            Err(bad) => return Some(bad),
        };
    Some(Call::Expand {
        key: Key::Fanuc(program),
        count,
        at: count_at,
    })
}

/// A Fanuc call's program, repeat count and the byte range that says so.
type Repeat = (u32, u32, (usize, usize));

/// The program a Fanuc call runs, how many times, and the byte range of the call that
/// says so: from `L`, or from a packed `P` (when the option says so); `Some(Err)` for
/// a bad count.
fn repeat(
    line: u32,
    text: &str,
    options: &Options,
    (number, digits, p): (u32, &str, &str),
    (ps, pe): (usize, usize),
    m98_at: (usize, usize),
) -> Option<Result<Repeat, Call>> {
    let bad = |msg: String, (s, e): (usize, usize), label: &str, help: &str| {
        Call::Bad(
            Diagnostic::error("subprograms::count", msg)
                .at_bytes(line, text, s, e)
                .with_label(label.to_string())
                .with_help(help.to_string()),
        )
    };
    let l = word_positions(text, 'L').into_iter().next();
    Some(match l {
        Some((ls, le, Some(lv))) => {
            let v = crate::num::parse_decimal(&lv).unwrap_or(f64::NAN);
            let max = options.max_count;
            // `L0` runs the subprogram no time: LinuxCNC skips the call (the expansion
            // is empty, with a note).
            if !(v.fract() == 0.0 && v >= 0.0 && v <= max as f64) {
                let why = if v.fract() != 0.0 || !v.is_finite() {
                    "not a whole number"
                } else if v < 0.0 {
                    "a negative count"
                } else {
                    "too many repetitions"
                };
                return Some(Err(bad(
                    format!("repeat count `L{lv}` must be a whole number from 0 to {max}"),
                    (ls, le),
                    why,
                    "L counts how many times the subprogram runs (L1 or no L: once; L0: the call is skipped)",
                )));
            }
            Ok((number, v as u32, (m98_at.0, le)))
        }
        Some((ls, le, None)) => {
            return Some(Err(bad(
                "`L` has no number".into(),
                (ls, le),
                "needs a count",
                "write the repeat count after L: `L5`",
            )));
        }
        None if options.packed_count && digits.len() > 4 => {
            let count = number / 10_000;
            if count > options.max_count {
                return Some(Err(bad(
                    format!(
                        "packed repeat count {count} in `P{p}` is above {}",
                        options.max_count
                    ),
                    (ps, pe),
                    "too many repetitions",
                    "the digits before the last four count the repetitions",
                )));
            }
            Ok((number % 10_000, count.max(1), (m98_at.0, pe)))
        }
        None => Ok((number, 1, (m98_at.0, pe))),
    })
}
