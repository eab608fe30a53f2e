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

/// Lines a line-based frontend read, for the check that an input holds something.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LineCounts {
    /// Lines read.
    pub lines: u64,
    /// A line held more than blanks.
    pub saw_text: bool,
    /// Lines refused before lowering (too long, not UTF-8).
    pub bad_lines: u64,
}

impl LineCounts {
    /// The error `code` for an input with nothing in it (`None` when it has a line of
    /// text or a refused line, which has its own error); `unit` is what it should hold.
    ///
    /// ```
    /// use ncpost::front::LineCounts;
    /// let blank = LineCounts { lines: 3, saw_text: false, bad_lines: 0 };
    /// let d = blank.empty_error("gcode::empty", "G-code line or comment").unwrap();
    /// assert_eq!(d.message, "the input has only blank lines");
    /// assert!(LineCounts { saw_text: true, ..blank }.empty_error("gcode::empty", "").is_none());
    /// ```
    pub fn empty_error(&self, code: &'static str, unit: &str) -> Option<Diagnostic> {
        if self.lines > 0 && (self.saw_text || self.bad_lines > 0) {
            return None;
        }
        let what = if self.lines == 0 {
            "the input is empty"
        } else {
            "the input has only blank lines"
        };
        Some(
            Diagnostic::error(code, what)
                .with_help(format!("give a file with at least one {unit}")),
        )
    }
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

/// A line's bytes without its terminator (`None` when it is over the limit) and its span,
/// from [`LineReader::next_line_bytes`].
pub type LineBytes<'a> = (Option<&'a [u8]>, Span);

/// Reads lines with bounded memory: a line over `max_len` bytes is skipped, not buffered.
///
/// A UTF-8 byte-order mark at the start of the input (Windows editors write one) is
/// skipped, for every frontend: it is no part of the first line, whose first statement
/// (`UNITS/INCHES`, `G20`) would otherwise not be recognised. The first line's span
/// starts after it.
///
/// ```
/// use ncpost::front::{LineReader, RawLine};
/// let mut r = LineReader::new(&b"\xEF\xBB\xBFUNITS/INCHES\n"[..], 100);
/// let (line, span) = r.next_line().unwrap().unwrap();
/// assert!(matches!(line, RawLine::Text("UNITS/INCHES")));
/// assert_eq!(span.offset, 3);
/// ```
pub struct LineReader<R> {
    inner: R,
    buf: Vec<u8>,
    max_len: usize,
    offset: u64,
    line: u32,
    /// Bytes of the last line, read in place from `inner`'s buffer, still to consume.
    pending: usize,
    /// The start of the input was looked at for a byte-order mark.
    bom_checked: bool,
}

/// The UTF-8 byte-order mark.
const BOM: &[u8] = b"\xEF\xBB\xBF";

/// The length of the line whose `\n` is at `chunk[newline]`, as a line is counted: without
/// the `\n` and a `\r` before it.
pub(crate) fn content_len(chunk: &[u8], newline: usize) -> usize {
    if newline > 0 && chunk[newline - 1] == b'\r' {
        newline - 1
    } else {
        newline
    }
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
            pending: 0,
            bom_checked: false,
        }
    }

    /// Skips a byte-order mark at the start of the input (once, before the first line).
    /// A reader whose first read gives fewer than three bytes keeps the mark.
    fn skip_bom(&mut self) -> io::Result<()> {
        if self.bom_checked {
            return Ok(());
        }
        self.bom_checked = true;
        let starts = loop {
            match self.inner.fill_buf() {
                Ok(chunk) => break chunk.starts_with(BOM),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        };
        if starts {
            self.inner.consume(BOM.len());
            self.offset += BOM.len() as u64;
        }
        Ok(())
    }

    /// Bytes consumed so far.
    pub fn bytes_read(&self) -> u64 {
        self.offset
    }

    /// The next line and its span, or `None` at the end of input.
    pub fn next_line(&mut self) -> io::Result<Option<(RawLine<'_>, Span)>> {
        Ok(self.next_line_bytes()?.map(|(bytes, span)| {
            let raw = match bytes {
                Some(bytes) => decode(bytes),
                None => RawLine::TooLong,
            };
            (raw, span)
        }))
    }

    /// The input buffered after the lines read so far (empty at the end), with the byte
    /// offset and the number of the line before it (0 at the start): for a reader that
    /// can take whole lines from the buffer itself and then [`LineReader::skip_lines`]
    /// them, without the search for each line's end.
    pub fn buffered(&mut self) -> io::Result<(&[u8], (u64, u32))> {
        self.skip_bom()?;
        if self.pending > 0 {
            self.inner.consume(self.pending);
            self.pending = 0;
        }
        loop {
            match self.inner.fill_buf() {
                Ok(_) => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        }
        // The buffer is filled: this second call reads nothing.
        Ok((self.inner.fill_buf()?, (self.offset, self.line)))
    }

    /// Skips `bytes` bytes of [`LineReader::buffered`]: `lines` whole lines, each with its
    /// `\n`, which the caller read.
    pub fn skip_lines(&mut self, bytes: usize, lines: u32) {
        self.pending = bytes;
        self.offset += bytes as u64;
        self.line += lines;
    }

    /// [`LineReader::next_line`] before the UTF-8 check: the line's bytes, or `None` for
    /// a line over the limit. For a reader that can take some lines as bytes (all ASCII
    /// when it takes them) and check the others with [`decode`].
    pub fn next_line_bytes(&mut self) -> io::Result<Option<LineBytes<'_>>> {
        self.skip_bom()?;
        if self.pending > 0 {
            self.inner.consume(self.pending);
            self.pending = 0;
        }
        // Most lines lie whole in the reader's buffer: they are read in place (consumed
        // at the next call) instead of being copied out.
        let found = loop {
            match self.inner.fill_buf() {
                Ok(chunk) => {
                    break memchr::memchr(b'\n', chunk).map(|i| (i + 1, content_len(chunk, i)));
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        };
        if let Some((taken, content)) = found
            && content <= self.max_len
        {
            // The buffer still holds the line (nothing was consumed): no read happens.
            let chunk = self.inner.fill_buf()?;
            let bytes = &chunk[..content];
            self.pending = taken;
            self.line += 1;
            let span = Span {
                offset: self.offset,
                len: content as u32,
                line: self.line,
            };
            self.offset += taken as u64;
            return Ok(Some((Some(bytes), span)));
        }
        let start = self.offset;
        let Some((content, too_long)) = self.copy_line()? else {
            return Ok(None);
        };
        self.line += 1;
        let span = Span {
            offset: start,
            len: content.min(u32::MAX as usize) as u32,
            line: self.line,
        };
        if too_long {
            return Ok(Some((None, span)));
        }
        Ok(Some((Some(&self.buf[..content]), span)))
    }

    /// Reads a line that does not lie whole in the reader's buffer into `buf`, up to the
    /// limit: its content length (without the terminator) and whether it is over the
    /// limit; `None` at the end of input.
    fn copy_line(&mut self) -> io::Result<Option<(usize, bool)>> {
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
        let total = (self.offset - start) as usize;
        let terminator = match (newline, before_newline) {
            (true, b'\r') => 2,
            (true, _) => 1,
            (false, _) => 0,
        };
        let content = total - terminator.min(total);
        Ok(Some((content, too_long || content > self.max_len)))
    }
}

/// A line's bytes as text, or why they are not.
pub fn decode(bytes: &[u8]) -> RawLine<'_> {
    match std::str::from_utf8(bytes) {
        Ok(text) => RawLine::Text(text),
        Err(e) => RawLine::NotUtf8 {
            valid_up_to: e.valid_up_to(),
            lossy: String::from_utf8_lossy(bytes).into_owned(),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::{LineReader, RawLine};
    use std::io::BufReader;

    /// Every line of `bytes` as (kind, text or lossy text, offset, len, line), read
    /// through a buffer of `capacity` bytes.
    fn read_all(bytes: &[u8], capacity: usize, max_len: usize) -> Vec<(u8, String, u64, u32, u32)> {
        let mut r = LineReader::new(BufReader::with_capacity(capacity, bytes), max_len);
        let mut out = Vec::new();
        while let Some((raw, span)) = r.next_line().expect("read") {
            let (kind, text) = match raw {
                RawLine::Text(t) => (0, t.to_string()),
                RawLine::TooLong => (1, String::new()),
                RawLine::NotUtf8 { valid_up_to, lossy } => (2, format!("{valid_up_to}:{lossy}")),
            };
            out.push((kind, text, span.offset, span.len, span.line));
        }
        assert_eq!(r.bytes_read(), bytes.len() as u64);
        out
    }

    /// The same, computed directly from the bytes.
    fn reference(bytes: &[u8], max_len: usize) -> Vec<(u8, String, u64, u32, u32)> {
        let mut out = Vec::new();
        let mut offset = 0u64;
        let mut rest = bytes;
        let mut line = 0;
        while !rest.is_empty() {
            line += 1;
            let (raw, next) = match rest.iter().position(|&b| b == b'\n') {
                Some(i) => (&rest[..i], &rest[i + 1..]),
                None => (rest, &rest[rest.len()..]),
            };
            let consumed = (rest.len() - next.len()) as u64;
            let had_newline = consumed as usize > raw.len();
            let content = if had_newline && raw.last() == Some(&b'\r') {
                &raw[..raw.len() - 1]
            } else {
                raw
            };
            let entry = if content.len() > max_len {
                (1, String::new())
            } else {
                match std::str::from_utf8(content) {
                    Ok(t) => (0, t.to_string()),
                    Err(e) => (
                        2,
                        format!("{}:{}", e.valid_up_to(), String::from_utf8_lossy(content)),
                    ),
                }
            };
            out.push((entry.0, entry.1, offset, content.len() as u32, line));
            offset += consumed;
            rest = next;
        }
        out
    }

    /// A byte-order mark is skipped at the start of the input only; offsets count it.
    #[test]
    fn bom_at_the_start_only() {
        let bytes = b"\xEF\xBB\xBFG20\n\xEF\xBB\xBFG1\n";
        let lines = read_all(bytes, 64, 100);
        assert_eq!(lines[0], (0, "G20".to_string(), 3, 3, 1));
        assert_eq!(lines[1], (0, "\u{feff}G1".to_string(), 7, 5, 2));
    }

    proptest::proptest! {
        /// Lines read in place and lines copied across buffer refills give the same lines,
        /// spans and kinds as splitting the bytes at `\n`.
        #[test]
        fn lines_are_the_same_whatever_the_buffer(
            bytes in proptest::collection::vec(
                proptest::sample::select(vec![b'a', b'G', b'1', b' ', b'\n', b'\r', 0xff, 0xc3, 0xa9]),
                0..200,
            ),
            capacity in proptest::sample::select(vec![1usize, 2, 3, 7, 16, 64, 1 << 16]),
            max_len in proptest::sample::select(vec![0usize, 1, 5, 40, 1 << 20]),
        ) {
            proptest::prop_assert_eq!(read_all(&bytes, capacity, max_len), reference(&bytes, max_len));
        }
    }
}
