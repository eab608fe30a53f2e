//! Finding the subprogram definitions in the buffered program, and the words of a line.

use std::collections::HashMap;

use super::{Def, Key};
use crate::diag::Diagnostic;
use crate::ir::{Block, BlockKind};
use crate::num::lexer::{Tok, oword_keyword, tokens};

/// Whether a line has the word `letter``value` (`M98`, `M99`).
pub(super) fn has_code(text: &str, letter: char, value: f64) -> bool {
    word_positions(text, letter)
        .iter()
        .any(|(_, _, n)| n.as_deref().and_then(crate::num::parse_decimal) == Some(value))
}

/// The words with `letter` in a line: byte range and number text (`None` for a bare
/// letter followed by an expression, `P[...]`).
pub(super) fn word_positions(text: &str, letter: char) -> Vec<(usize, usize, Option<String>)> {
    let mut v = Vec::new();
    for (s, t, e) in tokens(text) {
        match t {
            Tok::Word(w) if w.as_bytes()[0].eq_ignore_ascii_case(&(letter as u8)) => {
                v.push((s, e, Some(w[1..].trim_start().to_string())))
            }
            Tok::Letter(w) if w.as_bytes()[0].eq_ignore_ascii_case(&(letter as u8)) => {
                v.push((s, e, None))
            }
            _ => {}
        }
    }
    v
}

/// Whether a line's `P` is a quoted file name, `M98 P"homeall.g"`: a RepRapFirmware macro
/// call, which runs a file from the controller's SD card. It is no subprogram of this
/// file, so it passes through unchanged (and does not start the buffering).
pub(super) fn file_call(text: &str) -> bool {
    let mut toks = tokens(text).map(|t| t.1).peekable();
    while let Some(t) = toks.next() {
        if matches!(t, Tok::Letter(l) if l.eq_ignore_ascii_case("P"))
            && matches!(toks.peek(), Some(Tok::Str(_)))
        {
            return true;
        }
    }
    false
}

/// Whether a line calls a subprogram of this file or returns from one: `M98` (not a
/// macro file call, [`file_call`]) or `M99`.
fn calls_or_returns(text: &str) -> bool {
    (has_code(text, 'M', 98.0) && !file_call(text)) || has_code(text, 'M', 99.0)
}

/// The o-word keyword and label of a line (`o100 sub` is ("100", "sub")).
fn oword_line(text: &str) -> Option<(String, String)> {
    let toks: Vec<_> = tokens(text).collect();
    let first = toks.first()?;
    let (ks, Tok::Ident(kw), _) = oword_keyword(&toks)? else {
        return None;
    };
    let raw = text[first.0 + 1..ks].trim();
    Some((normalise_label(raw), kw.to_ascii_lowercase()))
}

/// `0100` and `100` are the same o-word number; names are case-insensitive.
fn normalise_label(raw: &str) -> String {
    if !raw.is_empty() && raw.bytes().all(|b| b.is_ascii_digit()) {
        let t = raw.trim_start_matches('0');
        if t.is_empty() { "0".into() } else { t.into() }
    } else {
        raw.to_ascii_lowercase()
    }
}

/// Whether a block starts the part of the program this pass has to buffer.
pub(super) fn subprogram_related(block: &Block) -> bool {
    match &block.kind {
        BlockKind::Command(c) => calls_or_returns(&c.text),
        BlockKind::Verbatim(v) => {
            v.reason == crate::ir::VerbatimReason::Subprogram
                || calls_or_returns(&v.text)
                || oword_line(&v.text).is_some_and(|(_, kw)| {
                    matches!(kw.as_str(), "sub" | "endsub" | "call" | "return")
                })
        }
        _ => false,
    }
}

/// A definition found in the buffer: its name, its body and the blocks it spans.
struct Found {
    key: Key,
    def: Def,
}

/// Finds the definitions in the buffered blocks. Returns them and, per block, the
/// definition it belongs to.
pub(super) fn collect_definitions(
    blocks: &[Block],
    diags: &mut Vec<Diagnostic>,
) -> (HashMap<Key, Def>, Vec<Option<Key>>) {
    let mut defs: HashMap<Key, Def> = HashMap::new();
    let mut owner: Vec<Option<Key>> = vec![None; blocks.len()];
    let mut i = 0;
    while i < blocks.len() {
        let found = match &blocks[i].kind {
            BlockKind::Verbatim(v) if v.reason == crate::ir::VerbatimReason::Subprogram => {
                fanuc_definition(blocks, i, &v.text, diags)
            }
            BlockKind::Verbatim(v) => oword_definition(blocks, i, &v.text),
            _ => None,
        };
        let Some(Found { key, def }) = found else {
            i += 1;
            continue;
        };
        let (start, end) = (def.blocks.start, def.blocks.end);
        i = end;
        for o in owner.iter_mut().take(end).skip(start) {
            *o = Some(key.clone());
        }
        if defs.contains_key(&key) {
            diags.push(
                Diagnostic::warning(
                    "subprograms::duplicate",
                    format!(
                        "{} is defined a second time; the first definition is used",
                        key.name()
                    ),
                )
                .at_span(blocks[start].span)
                .with_help(
                    "program numbers are numbers (O0002 is O2); give each subprogram its own",
                ),
            );
            continue;
        }
        defs.insert(key, def);
    }
    (defs, owner)
}

/// The Fanuc definition `O<n>` ... (the line with M99) whose header, `text`, is block
/// `i`; `None` when the header has no program number.
fn fanuc_definition(
    blocks: &[Block],
    i: usize,
    text: &str,
    diags: &mut Vec<Diagnostic>,
) -> Option<Found> {
    let n = word_positions(text, 'O')
        .first()
        .and_then(|(_, _, n)| n.as_deref().and_then(|n| n.parse::<u32>().ok()))?;
    let key = Key::Fanuc(n);
    let mut lines = Vec::new();
    let mut j = i;
    let mut closed = has_code(text, 'M', 99.0);
    while !closed {
        j += 1;
        let Some(BlockKind::Verbatim(b)) = blocks.get(j).map(|b| &b.kind) else {
            break;
        };
        if b.reason != crate::ir::VerbatimReason::Subprogram {
            break;
        }
        if has_code(&b.text, 'M', 99.0) {
            closed = true;
            lines.push((strip_m99(&b.text), blocks[j].span));
        } else {
            lines.push((b.text.clone(), blocks[j].span));
        }
    }
    if !closed {
        diags.push(
            Diagnostic::error(
                "subprograms::no-m99",
                format!("subprogram {} has no M99", key.name()),
            )
            .at_bytes(blocks[i].span.line, text, 0, text.len())
            .with_label("starts here and runs to the end")
            .with_help("end the subprogram with M99"),
        );
        j = j.min(blocks.len() - 1);
        if !matches!(&blocks[j].kind, BlockKind::Verbatim(b) if b.reason == crate::ir::VerbatimReason::Subprogram)
        {
            j -= 1;
        }
    }
    Some(Found {
        key,
        def: Def {
            lines,
            blocks: i..j + 1,
            early_return: None,
        },
    })
}

/// The o-word definition `o<n> sub` ... `o<n> endsub` whose header, `text`, is block
/// `i`; `None` when `text` is no `sub` line or the definition is not closed (the
/// frontend warns about the open o-word; there is nothing to expand).
fn oword_definition(blocks: &[Block], i: usize, text: &str) -> Option<Found> {
    let (label, kw) = oword_line(text)?;
    if kw != "sub" {
        return None;
    }
    let mut lines = Vec::new();
    let mut early_return = None;
    let mut j = i + 1;
    while j < blocks.len() {
        // The frontend passes every line inside a sub through as text.
        let BlockKind::Verbatim(b) = &blocks[j].kind else {
            return None;
        };
        match oword_line(&b.text) {
            Some((l, k)) if k == "endsub" && l == label => {
                return Some(Found {
                    key: Key::Oword(label),
                    def: Def {
                        lines,
                        blocks: i..j + 1,
                        early_return,
                    },
                });
            }
            Some((l, k)) if k == "return" && l == label => {
                let end = b.text.trim_end().len();
                early_return.get_or_insert((b.text.clone(), blocks[j].span, (0, end)));
            }
            _ => {}
        }
        lines.push((b.text.clone(), blocks[j].span));
        j += 1;
    }
    None
}

/// The line without its M99 word.
fn strip_m99(text: &str) -> String {
    let mut s = text.to_string();
    for (a, b, n) in word_positions(text, 'M').into_iter().rev() {
        if n.as_deref().and_then(crate::num::parse_decimal) == Some(99.0) {
            s.replace_range(a..b, &" ".repeat(b - a));
        }
    }
    s
}
