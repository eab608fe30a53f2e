//! Syntax of one plain G-code line, as [`parse_tokens`](super::parse_tokens) reads it. Items are byte
//! ranges of the line, so the buffers holding them are reused from line to line.

/// One element of a block: its byte range `start..end` in the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Item {
    /// A letter and its number, as written (`G01`, `x-.5`).
    Word(usize, usize),
    /// A letter with no number (`G28 X Y`).
    Letter(usize, usize),
    /// A closed `( )` comment, with its parentheses.
    Comment(usize, usize),
    /// A quoted string, with its quotes.
    Str(usize, usize),
    /// A `%` tape delimiter (its offset).
    Percent(usize),
}

/// A parsed line: block delete, checksum and trailing comment; the items in order are
/// in the buffer given to the parser.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Line {
    /// The line starts with `/`.
    pub block_delete: bool,
    /// `*NN`: its byte range.
    pub checksum: Option<(usize, usize)>,
    /// A `;` comment, or an unterminated `(` comment, that ends the line: its byte range.
    pub tail: Option<(usize, usize)>,
}
