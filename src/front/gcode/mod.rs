//! G-code frontend: RS274/NGC, Fanuc, RepRapFirmware and Marlin dialects.
//!
//! Plain blocks are lowered to IR with modal state resolved. Lines the IR cannot evaluate
//! (parameters, expressions, control flow, RepRapFirmware meta commands, subprogram
//! bodies) travel as [`Verbatim`](crate::ir::Verbatim) text with a warning, and the
//! positions they may change become unknown.
//!
//! A line is split into tokens by the logos lexer ([`lexer`]) and its block structure
//! (block delete, items, checksum, end-of-line comment) read by [`parse_tokens`]. That
//! grammar is regular, one optional part after another with nothing nested, so it is read
//! in one scan of the tokens: a LALRPOP parser, as the CL frontend uses for its
//! statements, would add a generated automaton and nothing else.

pub mod ast;
pub use crate::num::lexer;
pub mod lines;
pub use lines::{Lexed, Lines, Lowering, ReadLines};
pub(crate) use lower::{Lowerer, oword_call};
mod lower;

use std::io::BufRead;

use serde::{Deserialize, Serialize};

use crate::diag::Diagnostic;
use crate::front::Frontend;
use crate::ir::Block;

/// Frontend options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// `G4 P` counts milliseconds (RepRapFirmware, Marlin, Fanuc) rather than seconds
    /// (LinuxCNC).
    pub dwell_p_milliseconds: bool,
    /// Largest difference between an arc's start and end radius, mm, below which the
    /// arc is accepted (a relative 0.1 % of the radius is also allowed).
    pub arc_tolerance: f64,
    /// An arc whose end is off its circle by more than the tolerance is an error (the
    /// default: LinuxCNC and Grbl refuse such an arc and stop the job there); when false
    /// it is a warning and the arc is kept as written (an opt-in for controllers that cut
    /// it anyway: RepRapFirmware, Mach3).
    pub strict_arcs: bool,
    /// Longest line accepted, bytes; a longer line is an error and is skipped.
    pub max_line_len: usize,
    /// The dialect (`auto`: from the header comments).
    pub dialect: crate::ir::Dialect,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            dwell_p_milliseconds: true,
            arc_tolerance: 0.01,
            strict_arcs: true,
            max_line_len: 1 << 20,
            dialect: crate::ir::Dialect::Auto,
        }
    }
}

/// Streaming G-code frontend over any buffered reader: the two halves of [`lines`] on
/// one thread.
///
/// ```
/// use ncpost::front::{Frontend, gcode::{Parser, Options}};
/// let mut parser = Parser::new("G0 X1\nG1 X2 F100\n".as_bytes(), Options::default());
/// let mut diags = Vec::new();
/// let mut count = 0;
/// while let Some(_block) = parser.next_block(&mut diags) {
///     count += 1;
/// }
/// assert_eq!(count, 2);
/// assert!(diags.is_empty());
/// ```
pub struct Parser<R> {
    lines: Lines<R>,
    lowering: Lowering,
    lexed: Lexed,
    /// Blocks lowered but not yet handed out by `next_block`, in reverse order.
    pending: Vec<Block>,
    done: bool,
}

impl<R: BufRead> Parser<R> {
    /// A parser reading from `reader`.
    pub fn new(reader: R, options: Options) -> Self {
        Parser {
            lines: Lines::new(reader, options.max_line_len),
            lowering: Lowering::new(options),
            lexed: Lexed::new(),
            pending: Vec::new(),
            done: false,
        }
    }

    /// The parser's two halves, to run on different threads.
    pub fn into_halves(self) -> (Lines<R>, Lowering) {
        (self.lines, self.lowering)
    }

    /// Reads lines until `out` holds at least `want` blocks or the input ends.
    fn read_into(&mut self, out: &mut Vec<Block>, want: usize, diags: &mut Vec<Diagnostic>) {
        while out.len() < want && !self.done {
            self.lines.read(&mut self.lexed, want - out.len());
            self.lowering.lower(&self.lexed, out, diags);
            self.done = self.lexed.is_end();
        }
    }
}

impl<R: BufRead> Frontend for Parser<R> {
    fn next_block(&mut self, diags: &mut Vec<Diagnostic>) -> Option<Block> {
        if self.pending.is_empty() {
            let mut blocks = std::mem::take(&mut self.pending);
            self.read_into(&mut blocks, 1, diags);
            blocks.reverse();
            self.pending = blocks;
        }
        self.pending.pop()
    }

    fn next_batch(&mut self, out: &mut Vec<Block>, max: usize, diags: &mut Vec<Diagnostic>) {
        while let Some(b) = self.pending.pop() {
            out.push(b);
        }
        self.read_into(out, max, diags);
    }

    fn bytes_read(&self) -> u64 {
        self.lines.bytes_read()
    }
}

/// Lexes and parses one plain line into its syntax tree, without lowering; `None` when
/// the line is not in the plain block grammar (expressions, dialect statements) or has a
/// syntax error. `items` receives the line's items (cleared first). For tools and
/// benchmarks that want the syntax only.
///
/// ```
/// let (mut toks, mut items) = (Vec::new(), Vec::new());
/// let line = ncpost::front::gcode::parse_line("N10 G1 X2 ; cut", &mut toks, &mut items).unwrap();
/// assert_eq!(items.len(), 3);
/// assert_eq!(line.tail, Some((10, 15)));
/// ```
pub fn parse_line<'a>(
    line: &'a str,
    toks: &mut Vec<lexer::Spanned<'a>>,
    items: &mut Vec<ast::Item>,
) -> Option<ast::Line> {
    lexer::lex_line(line, toks);
    items.clear();
    if toks.iter().any(|t| {
        matches!(
            t.1,
            lexer::Tok::Other(_) | lexer::Tok::Ident(_) | lexer::Tok::Number(_)
        )
    }) {
        return None;
    }
    parse_tokens(toks, items).ok()
}

/// Reads the block structure of a line from its tokens:
///
/// ```text
/// line := ["/" [n]] item* [checksum] [tail comment]
/// item := word | letter | (comment) | "string" | %
/// ```
///
/// The items go to `items` (cleared first, and reused from line to line by the caller).
/// On a token the grammar does not allow where it stands, that token is the error (the
/// caller reports "unexpected ..." at it); `items` then holds the items before it.
///
/// The grammar is regular, one optional part after another, so it is read in one scan
/// of the tokens rather than by a generated parser (LALRPOP would add a table-driven
/// automaton and nothing else: there is no nesting to parse).
///
/// ```
/// use ncpost::front::gcode::{lexer::{lex_line, Tok}, parse_tokens};
/// let (mut toks, mut items) = (Vec::new(), Vec::new());
/// lex_line("/ G1 X2 *71 ; cut", &mut toks);
/// let line = parse_tokens(&toks, &mut items).unwrap();
/// assert!(line.block_delete);
/// assert_eq!((items.len(), line.checksum, line.tail), (2, Some((8, 11)), Some((12, 17))));
/// lex_line("G1 *71 X2", &mut toks);
/// assert_eq!(parse_tokens(&toks, &mut items), Err((7, Tok::Word("X2"), 9)));
/// ```
pub fn parse_tokens<'a>(
    toks: &[lexer::Spanned<'a>],
    items: &mut Vec<ast::Item>,
) -> Result<ast::Line, lexer::Spanned<'a>> {
    use ast::Item;
    use lexer::Tok;
    items.clear();
    let mut rest = toks;
    let block_delete = matches!(rest.first(), Some((_, Tok::Slash(_), _)));
    if block_delete {
        rest = &rest[1..];
    }
    while let Some(&(l, tok, r)) = rest.first() {
        items.push(match tok {
            Tok::Word(_) => Item::Word(l, r),
            Tok::Letter(_) => Item::Letter(l, r),
            Tok::Comment(_) => Item::Comment(l, r),
            Tok::Str(_) => Item::Str(l, r),
            Tok::Percent => Item::Percent(l),
            _ => break,
        });
        rest = &rest[1..];
    }
    let mut checksum = None;
    if let Some(&(l, Tok::Checksum(_), r)) = rest.first() {
        checksum = Some((l, r));
        rest = &rest[1..];
    }
    let mut tail = None;
    if let Some(&(l, Tok::LineComment(_) | Tok::OpenComment(_), r)) = rest.first() {
        tail = Some((l, r));
        rest = &rest[1..];
    }
    match rest.first() {
        Some(&unexpected) => Err(unexpected),
        None => Ok(ast::Line {
            block_delete,
            checksum,
            tail,
        }),
    }
}

/// A whole program parsed from a string.
#[derive(Debug, Clone, PartialEq)]
pub struct Program {
    /// The blocks in order.
    pub blocks: Vec<Block>,
    /// Warnings (and, in an `Err`, errors) in source order.
    pub diagnostics: Vec<Diagnostic>,
}

/// Parses and lowers a whole G-code program held in memory.
///
/// Returns `Err` with every diagnostic when any of them is an error.
///
/// ```
/// use ncpost::front::gcode::{parse_str, Options};
/// let program = parse_str("G21 G90\nG0 X10 Y5\n", &Options::default()).unwrap();
/// assert_eq!(program.blocks.len(), 1);
/// assert!(parse_str("G1 X1 X2\n", &Options::default()).is_err());
/// ```
pub fn parse_str(src: &str, options: &Options) -> Result<Program, Vec<Diagnostic>> {
    let mut parser = Parser::new(src.as_bytes(), options.clone());
    let mut blocks = Vec::new();
    let mut diagnostics = Vec::new();
    while let Some(b) = parser.next_block(&mut diagnostics) {
        blocks.push(b);
    }
    if diagnostics.iter().any(Diagnostic::is_error) {
        Err(diagnostics)
    } else {
        Ok(Program {
            blocks,
            diagnostics,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::lexer::{Tok, lex_line};
    use super::*;

    /// The line grammar's answer for `line`: the line and its items, or the token where
    /// the line leaves the grammar.
    fn read(line: &str) -> Result<(ast::Line, Vec<ast::Item>), (usize, Tok<'_>, usize)> {
        let mut toks = Vec::new();
        lex_line(line, &mut toks);
        let mut items = vec![ast::Item::Percent(99)]; // must be cleared
        parse_tokens(&toks, &mut items).map(|l| (l, items))
    }

    #[test]
    fn each_optional_part_in_its_place() {
        use ast::Item;
        let line = |block_delete, checksum, tail| ast::Line {
            block_delete,
            checksum,
            tail,
        };
        assert_eq!(read(""), Ok((line(false, None, None), vec![])));
        assert_eq!(read("/"), Ok((line(true, None, None), vec![])));
        assert_eq!(
            read("/2 G1"),
            Ok((line(true, None, None), vec![Item::Word(3, 5)]))
        );
        assert_eq!(read("*12"), Ok((line(false, Some((0, 3)), None), vec![])));
        assert_eq!(
            read("G1 *12 ; c"),
            Ok((
                line(false, Some((3, 6)), Some((7, 10))),
                vec![Item::Word(0, 2)]
            ))
        );
        assert_eq!(
            read("% G1 X (c) \"s\" *1"),
            Ok((
                line(false, Some((15, 17)), None),
                vec![
                    Item::Percent(0),
                    Item::Word(2, 4),
                    Item::Letter(5, 6),
                    Item::Comment(7, 10),
                    Item::Str(11, 14)
                ]
            ))
        );
        assert_eq!(
            read("G1 X1 ( open"),
            Ok((
                line(false, None, Some((6, 12))),
                vec![Item::Word(0, 2), Item::Word(3, 5)]
            ))
        );
        assert_eq!(
            read("; only"),
            Ok((line(false, None, Some((0, 6))), vec![]))
        );
    }

    #[test]
    fn the_first_token_out_of_place_is_the_error() {
        assert_eq!(read("G1 / X2").map(|_| ()), Err((3, Tok::Slash("/"), 4)));
        assert_eq!(
            read("*12 *13").map(|_| ()),
            Err((4, Tok::Checksum("*13"), 7))
        );
        assert_eq!(read("G1 ; c *12").map(|_| ()).ok(), Some(()));
        assert_eq!(read("G1 (a) *12 (b").map(|_| ()).ok(), Some(()));
        assert_eq!(
            read("G1 *12 (b)").map(|_| ()),
            Err((7, Tok::Comment("(b)"), 10))
        );
        assert_eq!(read("#1=2").map(|_| ()), Err((0, Tok::Other("#"), 1)));
        assert_eq!(read("G1 X[1+2]").map(|_| ()), Err((4, Tok::Other("["), 5)));
    }
}
