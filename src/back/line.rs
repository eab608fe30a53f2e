//! The text being printed: the current line after the finished lines not yet written.

use std::io::Write;

use crate::num::print::{self as number, put_number};

/// The line being printed, after the finished lines not yet handed to the writer: bytes
/// that are always ASCII or whole UTF-8 characters (only `char`s, `str`s and numbers go
/// in). Finished lines go to the writer after each block written alone, after each
/// batch, and whenever they fill [`Line::CHUNK`]: one `write_all` and one copy per line
/// cost more than the printing of a short line.
pub(super) struct Line {
    /// Initialized beyond `end`, so that a number is built in place (see
    /// [`put_number`]) without growing the vector for every word.
    bytes: Vec<u8>,
    /// Where the current line starts in `bytes`.
    start: usize,
    /// Where the current line ends in `bytes`.
    end: usize,
}

impl Line {
    /// How many finished bytes are kept before they are written.
    pub(super) const CHUNK: usize = 1 << 16;

    pub(super) fn new() -> Line {
        Line {
            bytes: vec![0; Self::CHUNK + 1024],
            start: 0,
            end: 0,
        }
    }
    /// `bytes[end..end + n]`, grown when the line needs it.
    pub(super) fn room(&mut self, n: usize) -> &mut [u8] {
        if self.end + n > self.bytes.len() {
            self.bytes.resize(self.end + n + 1024, 0);
        }
        &mut self.bytes[self.end..self.end + n]
    }
    pub(super) fn push(&mut self, c: char) {
        self.push_str(c.encode_utf8(&mut [0; 4]));
    }
    pub(super) fn push_str(&mut self, s: &str) {
        self.room(s.len()).copy_from_slice(s.as_bytes());
        self.end += s.len();
    }
    /// Appends the word `letter` `units * 10^-decimals`, after a space unless the line
    /// is empty.
    pub(super) fn push_word(&mut self, letter: u8, units: i64, decimals: u8, trim: bool) {
        debug_assert!(letter.is_ascii());
        let spaced = !self.is_empty();
        let room = self.room(number::ROOM);
        let len = if spaced {
            put_number(room, [b' ', letter], 2, units, decimals, trim)
        } else {
            put_number(room, [letter, 0], 1, units, decimals, trim)
        };
        self.end += len;
    }
    pub(super) fn is_empty(&self) -> bool {
        self.end == self.start
    }
    /// Drops the current line.
    pub(super) fn clear(&mut self) {
        self.end = self.start;
    }
    /// Inserts `s` at byte `at` of the current line.
    pub(super) fn insert_str(&mut self, at: usize, s: &str) {
        let at = self.start + at;
        self.room(s.len());
        self.bytes.copy_within(at..self.end, at + s.len());
        self.bytes[at..at + s.len()].copy_from_slice(s.as_bytes());
        self.end += s.len();
    }
    /// The current line.
    pub(super) fn as_bytes(&self) -> &[u8] {
        &self.bytes[self.start..self.end]
    }
    /// The current line as text (for messages).
    pub(super) fn text(&self) -> std::borrow::Cow<'_, str> {
        String::from_utf8_lossy(self.as_bytes())
    }
    /// Ends the current line with a newline; writes the finished lines to `out` once
    /// they fill a chunk.
    pub(super) fn finish(&mut self, out: &mut impl Write) -> std::io::Result<()> {
        self.push_str("\n");
        self.start = self.end;
        if self.start >= Self::CHUNK {
            self.write_finished(out)?;
        }
        Ok(())
    }
    /// Writes the finished lines to `out` (the current line stays).
    pub(super) fn write_finished(&mut self, out: &mut impl Write) -> std::io::Result<()> {
        out.write_all(&self.bytes[..self.start])?;
        self.bytes.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines built word by word, with an insertion at the front and a line longer than
    /// the spare room, come out whole and in order across many chunk writes.
    #[test]
    fn lines_survive_the_chunked_writes() {
        let mut line = Line::new();
        let mut out = Vec::new();
        let mut want = String::new();
        let long = "x".repeat(3000);
        for i in 0..20_000i64 {
            line.push_word(b'X', i * 7 - 5000, 3, true);
            line.push_word(b'F', i, 0, false);
            let mut text = format!("X{} F{i}", number_text(i * 7 - 5000, 3));
            if i % 97 == 0 {
                line.insert_str(0, "N1 ");
                text.insert_str(0, "N1 ");
            }
            if i % 1001 == 0 {
                line.push(' ');
                line.push_str(&long);
                text.push(' ');
                text.push_str(&long);
            }
            if i % 13 == 0 {
                // A line dropped before it ends leaves nothing behind.
                line.push_str("dropped");
                line.clear();
                continue;
            }
            if i % 5000 == 1 {
                // The finished lines go out; the one being built stays.
                line.write_finished(&mut out)
                    .expect("a Vec takes every write");
            }
            assert_eq!(line.as_bytes(), text.as_bytes());
            line.finish(&mut out).expect("a Vec takes every write");
            want.push_str(&text);
            want.push('\n');
        }
        line.write_finished(&mut out)
            .expect("a Vec takes every write");
        assert!(want.len() > 4 * Line::CHUNK);
        assert_eq!(String::from_utf8(out).expect("ASCII"), want);
    }

    fn number_text(units: i64, decimals: u8) -> String {
        let mut s = String::new();
        number::write_units(&mut s, units, decimals, true);
        s
    }
}
