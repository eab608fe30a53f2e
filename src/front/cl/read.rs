//! The one reader of a CL statement: tokens to major words and arguments.
//!
//! The logos lexer ([`super::lexer`]) splits a statement (continuation lines joined, `$$`
//! comments removed, text statements such as `PPRINT` set aside) into tokens, and this
//! reader checks them against the statement grammar
//!
//! ```text
//! statement := word+ [ "/" [ arg ("," arg)* ] ]     (GOTO/1,2,3   TOOL PATH/X,TOOL,Y)
//!            | number ("," number)*                 (a further point after GOTO)
//! arg       := (word | number)+
//! ```
//!
//! An argument of one number or one word is a value; several pieces are text
//! (`MILL_0.120RAD`). What the arguments mean is the lowering's business.
//!
//! The grammar is regular: nothing nests, so a parser generator adds nothing and the
//! tokens are read by a small state machine, in one pass, as the lexer hands them out.
//! Every statement of a CL file takes this path, plain `GOTO`s included. The same grammar
//! in LALRPOP (`grammar/cldata.lalrpop`) is kept as the tests' oracle: this reader accepts
//! what it accepts, and rejects the rest at the same token.

use super::ast::{Arg, ArgKind, Statement as Syntax};
use super::lexer::{Tok, tokens};
use super::source::Statement;
use crate::diag::Diagnostic;

/// Where a statement stops following the grammar: the token that does not fit (`None` at
/// the end of the statement) and its byte range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Unexpected<'a> {
    pub start: usize,
    pub end: usize,
    pub token: Option<Tok<'a>>,
}

/// Where the reader is in the grammar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum At {
    /// Nothing read yet.
    Start,
    /// In the major words.
    Major,
    /// After the `/`.
    Slash,
    /// In an argument.
    Arg,
    /// After a `,` between arguments.
    Comma,
    /// After a number of a line of bare numbers.
    Bare,
    /// After a `,` between bare numbers.
    BareComma,
}

/// Reads the statement `code`: its major words and `/`, and its arguments into `args`
/// (cleared first); or the first token that does not fit the grammar.
pub(super) fn statement<'a>(code: &'a str, args: &mut Vec<Arg>) -> Result<Syntax, Unexpected<'a>> {
    args.clear();
    let mut at = At::Start;
    let mut major = None;
    let mut slash = None;
    let mut arg = Arg {
        start: 0,
        end: 0,
        kind: ArgKind::Number,
    };
    // The end of the last token: where the statement ends for an error at its end.
    let mut last = 0;
    for (start, tok, end) in tokens(code) {
        let piece = match tok {
            Tok::Word(_) => Some(ArgKind::Word),
            Tok::Number(_) => Some(ArgKind::Number),
            _ => None,
        };
        at = match (at, tok, piece) {
            (At::Start, Tok::Word(_), _) => {
                major = Some((start, end));
                At::Major
            }
            (At::Major, Tok::Word(_), _) => {
                major = major.map(|(s, _)| (s, end));
                At::Major
            }
            (At::Major, Tok::Slash, _) => {
                slash = Some(start);
                At::Slash
            }
            (At::Slash | At::Comma, _, Some(kind)) => {
                arg = Arg { start, end, kind };
                At::Arg
            }
            (At::Arg, _, Some(_)) => {
                arg.end = end;
                arg.kind = ArgKind::Text;
                At::Arg
            }
            (At::Arg, Tok::Comma, _) => {
                args.push(arg);
                At::Comma
            }
            (At::Start | At::BareComma, Tok::Number(_), _) => {
                arg = Arg {
                    start,
                    end,
                    kind: ArgKind::Number,
                };
                At::Bare
            }
            (At::Bare, Tok::Comma, _) => {
                args.push(arg);
                At::BareComma
            }
            _ => {
                return Err(Unexpected {
                    start,
                    end,
                    token: Some(tok),
                });
            }
        };
        last = end;
    }
    match at {
        At::Start | At::Comma | At::BareComma => Err(Unexpected {
            start: last,
            end: last + 1,
            token: None,
        }),
        At::Arg | At::Bare => {
            args.push(arg);
            Ok(Syntax { major, slash })
        }
        At::Major | At::Slash => Ok(Syntax { major, slash }),
    }
}

/// The leading words of `code` (before `/` or anything else), upper-case, single spaces.
pub(super) fn major_words(code: &str) -> String {
    let mut out = String::new();
    for (_, tok, _) in tokens(code) {
        match tok {
            Tok::Word(w) => {
                if !out.is_empty() {
                    out.push(' ');
                }
                out.push_str(&w.to_ascii_uppercase());
            }
            _ => break,
        }
    }
    out
}

/// The error for a statement that does not follow the grammar.
pub(super) fn syntax_error(stmt: &Statement, at: Unexpected<'_>) -> Diagnostic {
    let what = match at.token {
        Some(Tok::Word(w)) => format!("word `{}`", crate::num::range::shown(w)),
        Some(Tok::Number(n)) => format!("number `{}`", crate::num::range::shown(n)),
        Some(Tok::Slash) => "`/`".into(),
        Some(Tok::Comma) => "`,`".into(),
        Some(Tok::Other(o)) => format!("`{}`", crate::num::range::shown(o)),
        None => "the end of the statement".into(),
    };
    stmt.locate(
        Diagnostic::error("cl::syntax", format!("unexpected {what}"))
            .with_label("not allowed here")
            .with_help("a statement is MAJOR/value,value,...; values are numbers or words"),
        at.start,
        at.end,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    lalrpop_util::lalrpop_mod!(
        #[allow(clippy::all, missing_docs, unused)]
        grammar,
        "/cldata.rs"
    );

    /// What the LALRPOP grammar makes of `code`: the syntax and arguments, or where it
    /// stops.
    fn oracle(code: &str) -> Result<(Syntax, Vec<Arg>), Unexpected<'_>> {
        use lalrpop_util::ParseError as P;
        let mut args = Vec::new();
        match grammar::StatementParser::new().parse(&mut args, tokens(code).map(Ok::<_, ()>)) {
            Ok(s) => Ok((s, args)),
            Err(
                P::UnrecognizedToken {
                    token: (start, t, end),
                    ..
                }
                | P::ExtraToken {
                    token: (start, t, end),
                },
            ) => Err(Unexpected {
                start,
                end,
                token: Some(t),
            }),
            Err(P::UnrecognizedEof { location, .. }) => Err(Unexpected {
                start: location,
                end: location + 1,
                token: None,
            }),
            Err(e) => panic!("{e:?}"),
        }
    }

    fn same(code: &str) -> Result<(), proptest::test_runner::TestCaseError> {
        let mut args = Vec::new();
        let got = statement(code, &mut args).map(|s| (s, args));
        proptest::prop_assert_eq!(got, oracle(code), "{:?}", code);
        Ok(())
    }

    #[test]
    fn statements_read_as_the_grammar_reads_them() {
        for code in [
            "GOTO/1,2,3",
            "GOTO / 1.E-3, -.5 ,7",
            "TOOL PATH/X,TOOL,Y",
            "RAPID",
            "RAPID/",
            "1.5,2,3",
            "CUTTER/MILL_0.120RAD,12 MM",
            "GOTO/1,,2",
            "GOTO/1,",
            "GOTO 1,2,3",
            "GOTO//1",
            "1 2",
            "1,",
            "1,X",
            "A=(1)",
            "/",
            ",",
            "=",
            "GOTO/1,2,3;",
        ] {
            same(code).unwrap();
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 4096, ..Default::default() })]

        /// Any sequence of words, numbers, separators and other characters.
        #[test]
        fn soup_reads_as_the_grammar_reads_it(
            pieces in proptest::collection::vec(
                proptest::sample::select(vec![
                    "GOTO", "TOOL", "x", "1STPECK", "1.5", "-.5", "7e2", "/", ",", " ", "=", "(",
                ]),
                0..12,
            ),
        ) {
            same(&pieces.concat())?;
        }
    }
}
