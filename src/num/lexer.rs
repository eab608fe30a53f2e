//! Logos lexer for one line of G-code.
//!
//! The lexer never fails: characters it has no token for become [`Tok::Other`], so the
//! caller can decide whether the line is an expression it passes through or an error.

use logos::Logos;

/// One token of a G-code line. Slices borrow from the line.
#[derive(Logos, Debug, Clone, Copy, PartialEq, Eq)]
#[logos(skip r"[ \t\r\x0c\x0b]+")]
pub enum Tok<'a> {
    /// A letter and its number, e.g. `G1`, `x-.5`, `G 38.2` (RS274 allows blanks inside).
    #[regex(r"[A-Za-z][ \t]*[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)", |lex| lex.slice())]
    Word(&'a str),
    /// A letter with no number after it (`G28 X Y`).
    #[regex(r"[A-Za-z]", |lex| lex.slice())]
    Letter(&'a str),
    /// Two or more letters: a dialect keyword (`if`, `DEF`, `EQ`) or a typo.
    #[regex(r"[A-Za-z][A-Za-z_]+", |lex| lex.slice())]
    Ident(&'a str),
    /// A number with no letter before it.
    #[regex(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)", |lex| lex.slice())]
    Number(&'a str),
    /// A closed parenthesised comment, with its parentheses (nesting allowed).
    Comment(&'a str),
    /// A parenthesised comment that runs to the end of the line.
    OpenComment(&'a str),
    /// `;` and the rest of the line.
    #[regex(r";[^\n]*", |lex| lex.slice(), allow_greedy = true)]
    LineComment(&'a str),
    /// A RepRapFirmware quoted string, `""` standing for one quote.
    #[regex(r#""([^"]|"")*""#, |lex| lex.slice())]
    Str(&'a str),
    /// `*` and the checksum digits.
    #[regex(r"\*[0-9]+", |lex| lex.slice())]
    Checksum(&'a str),
    /// Block delete `/`, optionally with a level digit.
    #[regex(r"/[0-9]?", |lex| lex.slice())]
    Slash(&'a str),
    /// The tape delimiter `%`.
    #[token("%")]
    Percent,
    /// Start of a parenthesised comment; replaced by `Comment` or `OpenComment`.
    #[token("(")]
    OpenParen,
    /// Any other character: expression syntax, parameters, stray punctuation.
    Other(&'a str),
}

/// A token with its byte range in the line.
pub type Spanned<'a> = (usize, Tok<'a>, usize);

/// Splits `line` (without its line terminator) into `out`, which is cleared first.
///
/// ```
/// use ncpost::num::lexer::{lex_line, Tok};
/// let mut toks = Vec::new();
/// lex_line("G1 X10 (move) ; done", &mut toks);
/// assert_eq!(toks[1].1, Tok::Word("X10"));
/// assert_eq!(toks[2].1, Tok::Comment("(move)"));
/// ```
pub fn lex_line<'a>(line: &'a str, out: &mut Vec<Spanned<'a>>) {
    out.clear();
    out.extend(tokens(line));
}

/// The tokens of `line`, lazily (no allocation).
pub fn tokens(line: &str) -> impl Iterator<Item = Spanned<'_>> {
    let mut lex = Tok::lexer(line);
    std::iter::from_fn(move || {
        let tok = lex.next()?;
        let span = lex.span();
        let tok = match tok {
            Ok(Tok::OpenParen) => {
                let rest = lex.remainder();
                match closing_paren(rest) {
                    Some(len) => {
                        lex.bump(len);
                        Tok::Comment(&line[span.start..span.end + len])
                    }
                    None => {
                        lex.bump(rest.len());
                        Tok::OpenComment(&line[span.start..])
                    }
                }
            }
            Ok(tok) => tok,
            Err(()) => Tok::Other(lex.slice()),
        };
        let end = span.start.max(lex.span().end);
        Some((span.start, tok, end))
    })
}

/// A token's kind without its text. A line's tokens kept as kinds and byte ranges need no
/// borrow of the line, so the G-code frontend's reading half can hand a batch of lexed
/// lines to its lowering half on another thread, which rebuilds each [`Tok`] with
/// [`Kind::with_text`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// [`Tok::Word`].
    Word,
    /// [`Tok::Letter`].
    Letter,
    /// [`Tok::Ident`].
    Ident,
    /// [`Tok::Number`].
    Number,
    /// [`Tok::Comment`].
    Comment,
    /// [`Tok::OpenComment`].
    OpenComment,
    /// [`Tok::LineComment`].
    LineComment,
    /// [`Tok::Str`].
    Str,
    /// [`Tok::Checksum`].
    Checksum,
    /// [`Tok::Slash`].
    Slash,
    /// [`Tok::Percent`].
    Percent,
    /// [`Tok::OpenParen`].
    OpenParen,
    /// [`Tok::Other`].
    Other,
}

impl Tok<'_> {
    /// The token's kind.
    pub fn kind(&self) -> Kind {
        match self {
            Tok::Word(_) => Kind::Word,
            Tok::Letter(_) => Kind::Letter,
            Tok::Ident(_) => Kind::Ident,
            Tok::Number(_) => Kind::Number,
            Tok::Comment(_) => Kind::Comment,
            Tok::OpenComment(_) => Kind::OpenComment,
            Tok::LineComment(_) => Kind::LineComment,
            Tok::Str(_) => Kind::Str,
            Tok::Checksum(_) => Kind::Checksum,
            Tok::Slash(_) => Kind::Slash,
            Tok::Percent => Kind::Percent,
            Tok::OpenParen => Kind::OpenParen,
            Tok::Other(_) => Kind::Other,
        }
    }
}

impl Kind {
    /// The token of this kind whose text is `text`: the line's bytes over the token's
    /// range, as [`tokens`] gives every token its own range's text.
    ///
    /// ```
    /// use ncpost::num::lexer::tokens;
    /// let line = "G1 X-.5 (cut) ; end";
    /// for (start, tok, end) in tokens(line) {
    ///     assert_eq!(tok.kind().with_text(&line[start..end]), tok);
    /// }
    /// ```
    pub fn with_text(self, text: &str) -> Tok<'_> {
        match self {
            Kind::Word => Tok::Word(text),
            Kind::Letter => Tok::Letter(text),
            Kind::Ident => Tok::Ident(text),
            Kind::Number => Tok::Number(text),
            Kind::Comment => Tok::Comment(text),
            Kind::OpenComment => Tok::OpenComment(text),
            Kind::LineComment => Tok::LineComment(text),
            Kind::Str => Tok::Str(text),
            Kind::Checksum => Tok::Checksum(text),
            Kind::Slash => Tok::Slash(text),
            Kind::Percent => Tok::Percent,
            Kind::OpenParen => Tok::OpenParen,
            Kind::Other => Tok::Other(text),
        }
    }
}

/// Whether `line` has a word (letter with a number) for `letter`, either case.
///
/// ```
/// use ncpost::num::lexer::has_word;
/// assert!(has_word("G1 X1 e0.5", 'E'));
/// assert!(!has_word("G1 X1 (E5)", 'E'));
/// ```
pub fn has_word(line: &str, letter: char) -> bool {
    tokens(line).any(
        |t| matches!(t.1, Tok::Word(w) if w.as_bytes()[0].eq_ignore_ascii_case(&(letter as u8))),
    )
}

/// The keywords of LinuxCNC o-word control lines (`o100 sub`, `o<x> if [..]`).
const OWORD_KEYWORDS: &[&str] = &[
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

/// The keyword token of an o-word control line, as written, with its place in `toks`:
/// the first o-word keyword after the leading `o` word (in `o<name> sub`, not `name`).
///
/// ```
/// use ncpost::num::lexer::{Tok, oword_keyword, tokens};
/// let toks: Vec<_> = tokens("o<part> SUB").collect();
/// assert_eq!(oword_keyword(&toks).map(|(_, kw, _)| kw), Some(Tok::Ident("SUB")));
/// assert_eq!(oword_keyword(&tokens("G1 X1").collect::<Vec<_>>()), None);
/// ```
pub fn oword_keyword<'a>(toks: &[Spanned<'a>]) -> Option<Spanned<'a>> {
    let first = toks.first()?;
    let starts_o = matches!(first.1, Tok::Word(w) | Tok::Letter(w) if w.starts_with(['o', 'O']));
    if !starts_o {
        return None;
    }
    toks.iter().skip(1).copied().find(|t| {
        matches!(t.1, Tok::Ident(w) if OWORD_KEYWORDS.iter().any(|k| k.eq_ignore_ascii_case(w)))
    })
}

/// RepRapFirmware meta-command keywords that start a line (`if`, `while`, `var`, `echo`,
/// ...): their expressions are written without braces.
pub const RRF_META_KEYWORDS: &[&str] = &[
    "if", "elif", "else", "while", "break", "continue", "abort", "var", "global", "set", "echo",
    "skip",
];

/// Whether `line` is a RepRapFirmware meta command (its first word is one of
/// [`RRF_META_KEYWORDS`]).
///
/// ```
/// use ncpost::num::lexer::is_rrf_meta;
/// assert!(is_rrf_meta("  while iterations < #move.axes"));
/// assert!(!is_rrf_meta("#1 = [#1 + 1]"));
/// ```
pub fn is_rrf_meta(line: &str) -> bool {
    matches!(tokens(line).next(), Some((_, Tok::Ident(w), _))
        if RRF_META_KEYWORDS.iter().any(|k| k.eq_ignore_ascii_case(w)))
}

/// Whether `line` uses RS274/NGC or Fanuc macro syntax that RepRapFirmware does not read:
/// a parameter (`#1`, `#<depth>`) or an expression in brackets (`[#1 + 2]`) outside a
/// RepRapFirmware expression in braces (`{#move.axes}`) and outside quoted strings, or
/// an o-word statement (`o100 while [...]`). A meta command's own expressions (`if
/// #move.axes > 3`) are RepRapFirmware's.
///
/// ```
/// use ncpost::num::lexer::has_ngc_syntax;
/// assert!(has_ngc_syntax("#101 = #5211"));
/// assert!(has_ngc_syntax("M98 P2 L#104"));
/// assert!(has_ngc_syntax("o101 while [#1 lt 5]"));
/// assert!(!has_ngc_syntax("G1 X{move.axes[0].max - 5} F600"));
/// assert!(!has_ngc_syntax("M118 S\"#1 [done]\""));
/// assert!(!has_ngc_syntax("if #move.axes > 3"));
/// ```
pub fn has_ngc_syntax(line: &str) -> bool {
    if is_rrf_meta(line) {
        return false;
    }
    let toks: Vec<Spanned<'_>> = tokens(line).collect();
    if oword_keyword(&toks).is_some() {
        return true;
    }
    let mut depth = 0usize;
    toks.iter().any(|t| match t.1 {
        Tok::Other("{") => {
            depth += 1;
            false
        }
        Tok::Other("}") => {
            depth = depth.saturating_sub(1);
            false
        }
        Tok::Other(o) => depth == 0 && o.starts_with(['#', '[']),
        _ => false,
    })
}

/// Whether `line` does nothing but set parameters ([`parameter_assignments`] of its
/// tokens).
///
/// ```
/// use ncpost::num::lexer::sets_parameters_only;
/// assert!(sets_parameters_only("#1 = [#1 + 1] (count)"));
/// assert!(!sets_parameters_only("G0 X#1"));
/// ```
pub fn sets_parameters_only(line: &str) -> bool {
    let toks: Vec<Spanned<'_>> = tokens(line).collect();
    parameter_assignments(&toks, |_| {})
}

/// The parameter a `#… = value` assignment sets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Assigned<'a> {
    /// A numbered parameter, the number as written (`#5211 = 0`: `"5211"`).
    Number(&'a str),
    /// A named parameter (`#<depth> = 2`).
    Named,
    /// A parameter whose number is computed (`#[#1 + 5000] = 0`, `##1 = 0`).
    Computed,
}

/// Whether a line does nothing but set parameters (RS274/NGC and Fanuc macro B:
/// `#1 = [#1 + 1]`, `N10 #1 = 0 #<x> = #2 (note)`); `each` is called with what each
/// assignment sets, in order (also for the assignments before a part that makes the
/// answer false). A line with any other word (`#1 = 2 G0 X#1`) or syntax is not one.
///
/// ```
/// use ncpost::num::lexer::{Assigned, parameter_assignments, tokens};
/// let toks: Vec<_> = tokens("#1 = [#1 + 1] #<_x> = #2 (step)").collect();
/// let mut set = Vec::new();
/// assert!(parameter_assignments(&toks, |a| set.push(a)));
/// assert_eq!(set, [Assigned::Number("1"), Assigned::Named]);
/// let toks: Vec<_> = tokens("#1 = 2 G0 X#1").collect();
/// assert!(!parameter_assignments(&toks, |_| {}));
/// ```
pub fn parameter_assignments<'a>(toks: &[Spanned<'a>], mut each: impl FnMut(Assigned<'a>)) -> bool {
    let is = |i: usize, c: &str| matches!(toks.get(i), Some((_, Tok::Other(o), _)) if *o == c);
    // Comments do not count; a block-delete slash and a line number may lead.
    let mut i = 0;
    let skip = |mut i: usize| {
        while matches!(
            toks.get(i).map(|t| t.1),
            Some(Tok::Comment(_) | Tok::OpenComment(_) | Tok::LineComment(_))
        ) {
            i += 1;
        }
        i
    };
    i = skip(i);
    if matches!(toks.get(i).map(|t| t.1), Some(Tok::Slash(_))) {
        i = skip(i + 1);
    }
    if matches!(toks.get(i).map(|t| t.1), Some(Tok::Word(w)) if w.starts_with(['N', 'n'])) {
        i = skip(i + 1);
    }
    let mut any = false;
    while i < toks.len() {
        if !is(i, "#") {
            return false;
        }
        let (target, at) = match toks.get(i + 1).map(|t| t.1) {
            Some(Tok::Number(n)) if n.bytes().all(|b| b.is_ascii_digit() || b == b'.') => {
                (Assigned::Number(n), i + 2)
            }
            Some(Tok::Other("<")) => match (i + 2..toks.len()).find(|&k| is(k, ">")) {
                Some(k) => (Assigned::Named, k + 1),
                None => return false,
            },
            _ => match value(toks, i + 1) {
                Some(k) => (Assigned::Computed, k),
                None => return false,
            },
        };
        if !is(at, "=") {
            return false;
        }
        each(target);
        any = true;
        match value(toks, at + 1) {
            Some(k) => i = skip(k),
            None => return false,
        }
    }
    any
}

/// The end of the RS274/NGC real value starting at `toks[i]` (a number, a parameter
/// `#…`, a bracketed expression, a function `SIN[…]`, a sign before one of these).
fn value(toks: &[Spanned<'_>], i: usize) -> Option<usize> {
    match toks.get(i)?.1 {
        Tok::Number(_) => Some(i + 1),
        Tok::Other("#") => match toks.get(i + 1)?.1 {
            Tok::Other("<") => (i + 2..toks.len())
                .find(|&k| toks[k].1 == Tok::Other(">"))
                .map(|k| k + 1),
            _ => value(toks, i + 1),
        },
        Tok::Other("-" | "+") => value(toks, i + 1),
        Tok::Other("[") => bracketed(toks, i),
        Tok::Ident(_) if toks.get(i + 1)?.1 == Tok::Other("[") => bracketed(toks, i + 1),
        _ => None,
    }
}

/// The end of the bracketed expression opening at `toks[i]` (`[`).
fn bracketed(toks: &[Spanned<'_>], i: usize) -> Option<usize> {
    let mut depth = 0usize;
    for (k, t) in toks.iter().enumerate().skip(i) {
        match t.1 {
            Tok::Other("[") => depth += 1,
            Tok::Other("]") => {
                depth -= 1;
                if depth == 0 {
                    return Some(k + 1);
                }
            }
            _ => {}
        }
    }
    None
}

/// Length up to and including the `)` that closes an already opened comment.
fn closing_paren(rest: &str) -> Option<usize> {
    let mut depth = 1usize;
    for (i, b) in rest.bytes().enumerate() {
        match b {
            b'(' => depth += 1,
            b')' => {
                depth -= 1;
                if depth == 0 {
                    return Some(i + 1);
                }
            }
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toks(s: &str) -> Vec<Tok<'_>> {
        let mut v = Vec::new();
        lex_line(s, &mut v);
        v.into_iter().map(|t| t.1).collect()
    }

    #[test]
    fn compact_words_split() {
        assert_eq!(
            toks("G1Y-2X179F2400"),
            vec![
                Tok::Word("G1"),
                Tok::Word("Y-2"),
                Tok::Word("X179"),
                Tok::Word("F2400")
            ]
        );
    }

    #[test]
    fn nested_and_open_comments() {
        assert_eq!(toks("((a) b)"), vec![Tok::Comment("((a) b)")]);
        assert_eq!(
            toks("G0 ( open"),
            vec![Tok::Word("G0"), Tok::OpenComment("( open")]
        );
    }

    #[test]
    fn quoted_string_with_escapes() {
        assert_eq!(
            toks(r#"M587 S"A;""B""#),
            vec![Tok::Word("M587"), Tok::Letter("S"), Tok::Str(r#""A;""B""#)]
        );
    }

    #[test]
    fn word_shapes() {
        assert_eq!(
            toks("G1X-1.5Y+.5E2.F1800 g 38.2"),
            vec![
                Tok::Word("G1"),
                Tok::Word("X-1.5"),
                Tok::Word("Y+.5"),
                Tok::Word("E2."),
                Tok::Word("F1800"),
                Tok::Word("g 38.2")
            ]
        );
        assert_eq!(
            toks("G28 X Y"),
            vec![Tok::Word("G28"), Tok::Letter("X"), Tok::Letter("Y")]
        );
        assert_eq!(
            toks("/G1 *12"),
            vec![Tok::Slash("/"), Tok::Word("G1"), Tok::Checksum("*12")]
        );
    }

    #[test]
    fn unknown_characters_become_other() {
        assert_eq!(
            toks("#1=2"),
            vec![
                Tok::Other("#"),
                Tok::Number("1"),
                Tok::Other("="),
                Tok::Number("2")
            ]
        );
    }

    proptest::proptest! {
        /// A token rebuilt from its kind and its range's text is the token: what the
        /// G-code frontend's two halves rely on to pass lines between threads.
        #[test]
        fn kind_and_range_rebuild_every_token(line in "[ -~]{0,40}") {
            for (start, tok, end) in tokens(&line) {
                proptest::prop_assert_eq!(tok.kind().with_text(&line[start..end]), tok);
            }
        }
    }
}
