//! The IR text dump as a backend (`--emit ir`).

use std::io::Write;

use super::{Backend, io_error};
use crate::diag::Diagnostic;
use crate::ir::{Block, dump};

/// Writes the IR text dump of each block.
pub struct Writer<W: Write> {
    out: W,
    line: String,
}

impl<W: Write> Writer<W> {
    /// A dump writer.
    pub fn new(out: W) -> Self {
        Writer {
            out,
            line: String::new(),
        }
    }
}

impl<W: Write> Backend for Writer<W> {
    fn write_block(
        &mut self,
        block: &Block,
        _diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        self.line.clear();
        dump::write_block(&mut self.line, block);
        self.line.push('\n');
        self.out.write_all(self.line.as_bytes()).map_err(io_error)
    }
    fn finish(&mut self) -> Result<(), Diagnostic> {
        self.out.flush().map_err(io_error)
    }
}
