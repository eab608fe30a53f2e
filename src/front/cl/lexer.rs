//! Logos lexer for one APT CL statement (continuation lines already joined, `$$`
//! comments already removed).
//!
//! The lexer never fails: characters it has no token for become [`Tok::Other`], which the
//! grammar rejects with the character's position.

use logos::Logos;

/// One token of a CL statement. Slices borrow from the statement text.
#[derive(Logos, Debug, Clone, Copy, PartialEq, Eq)]
#[logos(skip r"[ \t\r\x0c\x0b]+")]
pub enum Tok<'a> {
    /// A major or minor word: letters, digits, `_` and `-`, starting with a letter or `_`
    /// (`GOTO`, `END-OF-PATH`, `CSI_SET_FLUTE_LENGTH`), or digits followed by a letter
    /// (`1STPECK`).
    #[regex(r"[A-Za-z_][A-Za-z0-9_\-]*", |lex| lex.slice())]
    #[regex(r"[0-9]+[A-Za-z_][A-Za-z0-9_\-]*", |lex| lex.slice(), priority = 1)]
    Word(&'a str),
    /// A number: sign, digits with an optional point, optional exponent (`-.5`,
    /// `5.0000000`, `1.E-3`).
    #[regex(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?", |lex| lex.slice(), priority = 5)]
    Number(&'a str),
    /// `/` after the major word.
    #[token("/")]
    Slash,
    /// `,` between arguments.
    #[token(",")]
    Comma,
    /// Any other character.
    Other(&'a str),
}

/// A token with its byte range in the statement.
pub type Spanned<'a> = (usize, Tok<'a>, usize);

/// Splits `text` into `out`, which is cleared first.
///
/// ```
/// use ncpost::front::cl::lexer::{lex, Tok};
/// let mut toks = Vec::new();
/// lex("GOTO / 1.E-3, -.5", &mut toks);
/// assert_eq!(toks[0].1, Tok::Word("GOTO"));
/// assert_eq!(toks[2].1, Tok::Number("1.E-3"));
/// assert_eq!(toks[4].1, Tok::Number("-.5"));
/// ```
pub fn lex<'a>(text: &'a str, out: &mut Vec<Spanned<'a>>) {
    out.clear();
    out.extend(tokens(text));
}

/// The tokens of `text`, one by one, as [`lex`] gives them.
///
/// ```
/// use ncpost::front::cl::lexer::{tokens, Tok};
/// let mut toks = tokens("GOTO/1");
/// assert_eq!(toks.next(), Some((0, Tok::Word("GOTO"), 4)));
/// assert_eq!(toks.nth(1), Some((5, Tok::Number("1"), 6)));
/// ```
pub fn tokens(text: &str) -> impl Iterator<Item = Spanned<'_>> {
    let mut lexer = Tok::lexer(text);
    std::iter::from_fn(move || {
        let tok = lexer.next()?;
        let span = lexer.span();
        let tok = tok.unwrap_or_else(|()| Tok::Other(lexer.slice()));
        Some((span.start, tok, span.end))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toks(s: &str) -> Vec<Tok<'_>> {
        let mut v = Vec::new();
        lex(s, &mut v);
        v.into_iter().map(|t| t.1).collect()
    }

    #[test]
    fn numbers_in_every_spelling() {
        assert_eq!(
            toks("5.0000000,.9625,-0.5,1.E-3,+2,7e2"),
            vec![
                Tok::Number("5.0000000"),
                Tok::Comma,
                Tok::Number(".9625"),
                Tok::Comma,
                Tok::Number("-0.5"),
                Tok::Comma,
                Tok::Number("1.E-3"),
                Tok::Comma,
                Tok::Number("+2"),
                Tok::Comma,
                Tok::Number("7e2"),
            ]
        );
    }

    #[test]
    fn words_with_digits_and_dashes() {
        assert_eq!(
            toks("END-OF-PATH 1STPECK MILL_0.120RAD"),
            vec![
                Tok::Word("END-OF-PATH"),
                Tok::Word("1STPECK"),
                Tok::Word("MILL_0"),
                Tok::Number(".120"),
                Tok::Word("RAD"),
            ]
        );
    }

    #[test]
    fn other_characters() {
        assert_eq!(
            toks("A=(1)"),
            vec![
                Tok::Word("A"),
                Tok::Other("="),
                Tok::Other("("),
                Tok::Number("1"),
                Tok::Other(")"),
            ]
        );
    }
}
