//! Frontends: source text to IR blocks, one statement at a time.

pub mod cl;
pub mod gcode;
pub mod hpgl;

use std::io::{self, BufRead};

use crate::diag::Diagnostic;
use crate::ir::{Block, Span};

/// A source of IR blocks. Frontends read lazily, so memory does not grow with the input.
pub trait Frontend {
    /// The next block, or `None` at the end. Diagnostics found on the way (warnings and
    /// recovered errors) are pushed to `diags`; after an error the frontend goes on with
    /// the next line so one run reports every bad line.
    fn next_block(&mut self, diags: &mut Vec<Diagnostic>) -> Option<Block>;

    /// Appends blocks to `out` until it holds about `max` or the input ends (a line may
    /// give several blocks); appends nothing only at the end. Lets a pipeline take blocks
    /// in batches without moving each one through `next_block`.
    fn next_batch(&mut self, out: &mut Vec<Block>, max: usize, diags: &mut Vec<Diagnostic>) {
        while out.len() < max {
            match self.next_block(diags) {
                Some(b) => out.push(b),
                None => break,
            }
        }
    }

    /// Bytes consumed so far (for progress reports).
    fn bytes_read(&self) -> u64;
}

/// A line as read: its text, or why it has none.
#[derive(Debug)]
pub enum RawLine<'a> {
    /// A UTF-8 line without its terminator (`\n` or `\r\n`).
    Text(&'a str),
    /// The line is longer than the limit; its bytes were skipped.
    TooLong,
    /// The line is not UTF-8; `valid_up_to` bytes are, and `lossy` shows it.
    NotUtf8 {
        /// Bytes before the first bad one.
        valid_up_to: usize,
        /// The line with bad bytes replaced.
        lossy: String,
    },
}

/// Reads lines with bounded memory: a line over `max_len` bytes is skipped, not buffered.
pub struct LineReader<R> {
    inner: R,
    buf: Vec<u8>,
    max_len: usize,
    offset: u64,
    line: u32,
}

impl<R: BufRead> LineReader<R> {
    /// Wraps `inner`; lines longer than `max_len` bytes are reported as [`RawLine::TooLong`].
    pub fn new(inner: R, max_len: usize) -> Self {
        LineReader {
            inner,
            buf: Vec::new(),
            max_len,
            offset: 0,
            line: 0,
        }
    }

    /// Bytes consumed so far.
    pub fn bytes_read(&self) -> u64 {
        self.offset
    }

    /// The next line and its span, or `None` at the end of input.
    pub fn next_line(&mut self) -> io::Result<Option<(RawLine<'_>, Span)>> {
        self.buf.clear();
        let start = self.offset;
        let mut too_long = false;
        let mut consumed_any = false;
        let mut newline = false;
        // The byte before the newline, to tell `\r\n` from `\n` when the line was skipped.
        let mut last = 0u8;
        let mut before_newline = 0u8;
        loop {
            let chunk = match self.inner.fill_buf() {
                Ok(c) => c,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            };
            if chunk.is_empty() {
                break;
            }
            consumed_any = true;
            let (take, done) = match memchr::memchr(b'\n', chunk) {
                Some(i) => {
                    before_newline = if i > 0 { chunk[i - 1] } else { last };
                    (i + 1, true)
                }
                None => (chunk.len(), false),
            };
            if take > 0 {
                last = chunk[take - 1];
            }
            // Two more bytes than the limit leave room for `\r\n`; the exact check is below.
            if !too_long {
                if self.buf.len() + take > self.max_len + 2 {
                    too_long = true;
                    self.buf.clear();
                } else {
                    self.buf.extend_from_slice(&chunk[..take]);
                }
            }
            self.inner.consume(take);
            self.offset += take as u64;
            if done {
                newline = true;
                break;
            }
        }
        if !consumed_any {
            return Ok(None);
        }
        self.line += 1;
        let total = (self.offset - start) as usize;
        let terminator = match (newline, before_newline) {
            (true, b'\r') => 2,
            (true, _) => 1,
            (false, _) => 0,
        };
        let content = total - terminator.min(total);
        if too_long || content > self.max_len {
            let span = Span {
                offset: start,
                len: content.min(u32::MAX as usize) as u32,
                line: self.line,
            };
            return Ok(Some((RawLine::TooLong, span)));
        }
        let end = content;
        let bytes = &self.buf[..end];
        let span = Span {
            offset: start,
            len: end as u32,
            line: self.line,
        };
        Ok(Some(match std::str::from_utf8(bytes) {
            Ok(text) => (RawLine::Text(text), span),
            Err(e) => (
                RawLine::NotUtf8 {
                    valid_up_to: e.valid_up_to(),
                    lossy: String::from_utf8_lossy(bytes).into_owned(),
                },
                span,
            ),
        }))
    }
}
