//! Syntax of one CL statement, as the LALRPOP grammar builds it. Positions are byte
//! offsets into the statement's code text (continuation lines joined, `$$` comments
//! removed), so the buffers holding them are reused from statement to statement.

/// What one argument between commas is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArgKind {
    /// A single number (`-.5`, `1.E-3`).
    Number,
    /// A single minor word (`MMPM`, `CLW`, `1STPECK`).
    Word,
    /// Several words and numbers (`MILL_0.120RAD`, `12 MM`): text, not a value.
    Text,
}

/// One argument: its byte range `start..end` and kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Arg {
    /// First byte.
    pub start: usize,
    /// One past the last byte.
    pub end: usize,
    /// Number, word or text.
    pub kind: ArgKind,
}

/// A parsed statement; its arguments, in order, are in the buffer given to the parser.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Statement {
    /// The major word(s) (`GOTO`, `TOOL PATH`): their byte range. `None` for a line of
    /// bare numbers (a continuation point after `GOTO`).
    pub major: Option<(usize, usize)>,
    /// Offset of the `/` after the major word, if written.
    pub slash: Option<usize>,
}
