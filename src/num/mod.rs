//! Numbers and words as NC programs write them: the bottom layer, below the IR.
//!
//! Every layer reads and prints numbers through this module: frontends read programs,
//! passes and backends re-read the G-code text that the IR carries through unevaluated
//! (commands, verbatim lines) and print positions, feeds and times. One reader and one
//! printer for all of them means a number reads back as it was printed.
//!
//! - [`decimal`]: reading a decimal number exactly (`-1.25`, `.5`, `3.`);
//! - [`lexer`]: the tokens of one line of G-code (words, comments, strings);
//! - [`print`]: fixed-precision printing and the print quantization (`to_units`, `printed`);
//! - [`range`]: the largest value a program may write, and long tokens cut for messages.

pub mod decimal;
pub mod lexer;
pub mod print;
pub mod range;

pub use decimal::{parse_decimal, scan_decimal};
