//! The words of a block: G and M codes, letters with their values, and the checks that
//! need no modal state (checksum, number range, exponent typos, unterminated comments).

use super::Small;
use crate::diag::Diagnostic;
use crate::front::gcode::ast::{Item, Line};
use crate::front::gcode::lexer::Tok;
use crate::ir::{Axis, Comment, CommentStyle};
use crate::num::parse_decimal;
use crate::num::range::{in_range, shown};

/// A G or M code as (major, minor): `G38.2` is (38, 2), `G1` is (1, 0).
pub(super) type Code = (u32, u32);

/// The code a G or M word's number names: sign, point and trailing zeros of the minor
/// part as controllers read them (`G01` is G1, `G38.20` is G38.2).
pub(super) fn parse_code(number: &str) -> Option<Code> {
    let number = number.strip_prefix('+').unwrap_or(number).as_bytes();
    let (major, minor) = match number.iter().position(|&b| b == b'.') {
        Some(dot) => (&number[..dot], trim_zeros(&number[dot + 1..])),
        None => (number, &[][..]),
    };
    Some((code_number(major)?, code_number(minor)?))
}

/// The digits of a code number as an integer (none: 0); `None` for any other character
/// or a number too large for a code.
fn code_number(digits: &[u8]) -> Option<u32> {
    digits.iter().try_fold(0u32, |n, &b| {
        let digit = char::from(b).to_digit(10)?;
        n.checked_mul(10)?.checked_add(digit)
    })
}

/// `digits` without its trailing zeros (`20` of `G38.20` is the 2 of `G38.2`).
fn trim_zeros(digits: &[u8]) -> &[u8] {
    let end = digits.iter().rposition(|&b| b != b'0').map_or(0, |i| i + 1);
    &digits[..end]
}

/// A word of a plain block.
#[derive(Debug, Clone, Copy)]
pub(super) struct Word<'a> {
    /// The letter, upper case.
    pub letter: char,
    /// The number, as written (not yet in the block's units).
    pub value: f64,
    /// Byte range of the word in the line.
    pub start: usize,
    /// End of the byte range.
    pub end: usize,
    /// The source slice, for pass-through text.
    pub text: &'a str,
}

impl<'a> Word<'a> {
    /// The number as written.
    pub fn number(&self) -> &'a str {
        number_slice(self.text)
    }
}

/// The first word of each letter (but G, M and N) of a block, as indices into its words.
#[derive(Clone, Copy)]
pub(super) struct Slots<'w, 'a> {
    pub words: &'w [Word<'a>],
    pub index: [u32; 26],
}

impl<'w, 'a> Slots<'w, 'a> {
    /// An empty slot.
    pub const NONE: u32 = u32::MAX;

    /// Whether the block has a word with `letter` (upper case).
    pub fn has(&self, letter: char) -> bool {
        let slot = (letter as u8).wrapping_sub(b'A') as usize;
        self.index.get(slot).is_some_and(|&i| i != Self::NONE)
    }

    /// Whether the block has a centre word (I, J, K or R).
    pub fn has_centre(&self) -> bool {
        ['I', 'J', 'K', 'R'].into_iter().any(|l| self.has(l))
    }

    /// The word with `letter` (upper case), if the block has one.
    pub fn get(&self, letter: char) -> Option<Word<'a>> {
        self.at(letter).map(|i| self.words[i as usize])
    }

    /// Where the word with `letter` (upper case) sits in the block's words.
    pub fn at(&self, letter: char) -> Option<u32> {
        let slot = (letter as u8).wrapping_sub(b'A') as usize;
        self.index.get(slot).copied().filter(|&i| i != Self::NONE)
    }

    /// The word of `axis`, if the block has one.
    pub fn axis(&self, axis: Axis) -> Option<Word<'a>> {
        self.get(axis.letter())
    }
}

/// What [`collect`] takes from a parsed line.
#[derive(Default)]
pub(super) struct Collected<'a> {
    /// Letters with numbers, in line order.
    pub words: Small<Word<'a>>,
    /// Letters without a number, with their offsets.
    pub bare: Small<(usize, &'a str)>,
    /// The line's comments, without their delimiters.
    pub comments: Vec<Comment>,
    /// The line holds a `%` tape delimiter.
    pub percent: bool,
}

/// The words, bare letters and comments of a parsed line, into `into`, after the checks
/// that need no modal state (checksum, number range, exponent typos, unterminated
/// comments); `None` once an error is reported.
pub(super) fn collect<'a>(
    text: &'a str,
    line_no: u32,
    line: &Line,
    items: &[Item],
    into: &mut Collected<'a>,
    diags: &mut Vec<Diagnostic>,
) -> Option<()> {
    if let Some(checksum) = line.checksum
        && let Err(d) = check_checksum(text, line_no, checksum)
    {
        diags.push(d);
        return None;
    }
    for item in items {
        match *item {
            Item::Word(s, e) => {
                let word = read_word(text, line_no, s, e, into.words.last());
                match word {
                    Ok(w) => into.words.push(w),
                    Err(d) => {
                        diags.push(d);
                        return None;
                    }
                }
            }
            Item::Letter(s, e) => into.bare.push((s, &text[s..e])),
            Item::Comment(s, e) => into.comments.push(Comment {
                text: text[s + 1..e - 1].to_string(),
                style: CommentStyle::Paren,
            }),
            Item::Str(s, _) => {
                diags.push(
                    Diagnostic::error("gcode::string", "a quoted string needs an M command")
                        .at_bytes(line_no, text, s, s + 1),
                );
                return None;
            }
            Item::Percent(_) => into.percent = true,
        }
    }
    if let Some(tail) = line.tail {
        tail_comment(text, line_no, tail, into, diags)?;
    }
    Some(())
}

/// A RepRapFirmware/Marlin checksum `*NN`: the XOR of the bytes before it.
fn check_checksum(
    text: &str,
    line_no: u32,
    (at, cs_end): (usize, usize),
) -> Result<(), Diagnostic> {
    let cs = &text[at..cs_end];
    let expected: u32 = text.as_bytes()[..at]
        .iter()
        .fold(0u32, |a, b| a ^ *b as u32);
    let given: Option<u32> = cs[1..].parse().ok();
    if given == Some(expected) {
        return Ok(());
    }
    Err(Diagnostic::error(
        "gcode::checksum",
        format!("checksum {cs} does not match the line (expected *{expected})"),
    )
    .at_bytes(line_no, text, at, at + cs.len())
    .with_label("wrong checksum")
    .with_help("the line was changed or corrupted after its checksum was computed"))
}

/// The word at `text[s..e]`, checked for its range and for an exponent typo against the
/// word before it.
fn read_word<'a>(
    text: &'a str,
    line_no: u32,
    s: usize,
    e: usize,
    prev: Option<&Word<'a>>,
) -> Result<Word<'a>, Diagnostic> {
    let err = |code: &'static str, msg: String, s: usize, e: usize| {
        Diagnostic::error(code, msg).at_bytes(line_no, text, s, e)
    };
    let w = &text[s..e];
    let (letter, number) = split_word(w);
    let value = parse_decimal(number).unwrap_or(f64::NAN);
    if !in_range(value) {
        return Err(err(
            "gcode::number-range",
            format!("`{}`: the number is out of range", shown(w)),
            s,
            s + w.len(),
        )
        .with_label("too large")
        .with_help("G-code values must be finite and below 1e12"));
    }
    // `X1e400` reads as X1 then E400: almost surely an exponent typo.
    if letter == 'E'
        && w.starts_with('e')
        && let Some(prev) = prev
        && prev.end == s
    {
        return Err(err(
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
        ));
    }
    Ok(Word {
        letter,
        value,
        start: s,
        end: s + w.len(),
        text: w,
    })
}

/// The comment that ends a line: `;` to the end, or a `(` never closed, which is kept as
/// a comment on a line of its own and an error after words.
fn tail_comment(
    text: &str,
    line_no: u32,
    (at, tail_end): (usize, usize),
    into: &mut Collected<'_>,
    diags: &mut Vec<Diagnostic>,
) -> Option<()> {
    let c = &text[at..tail_end];
    if let Some(rest) = c.strip_prefix(';') {
        into.comments.push(Comment {
            text: rest.to_string(),
            style: CommentStyle::Semicolon,
        });
    } else if into.words.is_empty() && into.bare.is_empty() {
        diags.push(
            Diagnostic::warning("gcode::unterminated-comment", "comment is not closed")
                .at_bytes(line_no, text, at, text.len())
                .with_label("runs to the end of the line")
                .with_help("add `)`; it is kept as a comment"),
        );
        into.comments.push(Comment {
            text: c[1..].to_string(),
            style: CommentStyle::Paren,
        });
    } else {
        diags.push(
            Diagnostic::error("gcode::unterminated-comment", "comment is not closed")
                .at_bytes(line_no, text, at, text.len())
                .with_label("`(` without `)`")
                .with_help("close the comment with `)` (comments do not span lines)"),
        );
        return None;
    }
    Some(())
}

/// Letter (upper case) and number (without blanks) of a word token.
///
/// The lexer's word pattern allows blanks only between the letter and the number
/// (`G 1`), so the number is one slice.
pub(super) fn split_word(w: &str) -> (char, &str) {
    let letter = w.as_bytes().first().copied().unwrap_or(b' ');
    (letter.to_ascii_uppercase() as char, number_slice(w))
}

/// The number part of a word token.
pub(super) fn number_slice(w: &str) -> &str {
    w.get(1..).unwrap_or("").trim_start_matches([' ', '\t'])
}

/// A word as the output writes it: letter upper case, no blank before the number.
pub(super) fn normalise_word(w: &str) -> String {
    let (letter, number) = split_word(w);
    let mut s = String::with_capacity(w.len());
    s.push(letter);
    s.push_str(number);
    s
}

/// A letter with no number where the block needs a value.
pub(super) fn letter_error(line_no: u32, text: &str, s: usize, l: &str) -> Diagnostic {
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

/// A token where the line grammar does not allow it.
pub(super) fn syntax_error(
    line_no: u32,
    text: &str,
    (s, t, e): (usize, Tok<'_>, usize),
) -> Diagnostic {
    Diagnostic::error("gcode::syntax", format!("unexpected {}", describe(t)))
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
    use super::{number_slice, parse_code};

    #[test]
    fn codes_as_controllers_read_them() {
        assert_eq!(parse_code("07"), Some((7, 0)));
        assert_eq!(parse_code("1"), Some((1, 0)));
        assert_eq!(parse_code("38.2"), Some((38, 2)));
        assert_eq!(parse_code("38.20"), Some((38, 2)));
        assert_eq!(parse_code("+1"), Some((1, 0)));
        assert_eq!(parse_code("1."), Some((1, 0)));
        assert_eq!(parse_code("-1"), None);
        assert_eq!(parse_code("4294967296"), None);
        assert_eq!(parse_code("38.02"), Some((38, 2)));
        assert_eq!(parse_code(".5"), Some((0, 5)));
        assert_eq!(parse_code(""), Some((0, 0)));
        assert_eq!(number_slice("G 01"), "01");
        assert_eq!(number_slice("X-1"), "-1");
    }
}
