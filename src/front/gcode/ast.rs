//! Syntax of one plain G-code line, as the LALRPOP grammar builds it.

/// One element of a block, with its byte offset in the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Item<'a> {
    /// A letter and its number, as written (`G01`, `x-.5`).
    Word(usize, &'a str),
    /// A letter with no number (`G28 X Y`).
    Letter(usize, &'a str),
    /// A closed `( )` comment, with its parentheses.
    Comment(usize, &'a str),
    /// A quoted string, with its quotes.
    Str(usize, &'a str),
    /// A `%` tape delimiter.
    Percent(usize),
}

/// A parsed line: block delete, items in order, checksum and trailing comment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Line<'a> {
    /// The line starts with `/`.
    pub block_delete: bool,
    /// Words, comments and strings in source order.
    pub items: Vec<Item<'a>>,
    /// `*NN` with its offset.
    pub checksum: Option<(usize, &'a str)>,
    /// A `;` comment, or an unterminated `(` comment, that ends the line.
    pub tail: Option<(usize, &'a str)>,
}
