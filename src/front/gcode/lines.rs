//! The G-code frontend in two halves: [`Lines`] reads lines and their tokens, which needs
//! no modal state, and [`Lowering`] gives them their meaning, in input order. A pipeline
//! runs the halves on different threads: in a pipeline with few passes, reading and
//! tokenising a line takes about as long as working out what it does, so one thread
//! doing both would hold up the whole run (`BENCHMARKS.md` has the figure).
//!
//! A batch of lines travels as a [`Lexed`]: the lines' text in one buffer and each
//! token as its [`Kind`] and byte range, so it borrows nothing and can cross threads.

use std::io::BufRead;
use std::ops::Range;

use super::Options;
use super::lexer::{self, Kind, Spanned};
use super::lower::{self, Lowerer};
use crate::diag::Diagnostic;
use crate::front::{LineCounts, LineReader, RawLine, content_len};
use crate::ir::{Block, Span};

/// Lines read and tokenised, waiting to be lowered.
#[derive(Debug, Default)]
pub struct Lexed {
    /// The text of the lines, one after another.
    text: String,
    lines: Vec<Entry>,
    /// Each token as (start, end, kind), the range relative to its line.
    toks: Vec<(u32, u32, Kind)>,
    /// The input ends after these lines (or could not be read further).
    end: bool,
}

/// One line of a [`Lexed`] batch.
#[derive(Debug)]
struct Entry {
    span: Span,
    what: Line,
}

/// What was read for a line.
#[derive(Debug)]
enum Line {
    /// UTF-8 text (its range in [`Lexed::text`]) and its tokens' range.
    Text {
        text: Range<usize>,
        toks: Range<usize>,
    },
    /// Over the length limit: its bytes were skipped.
    TooLong,
    /// Not UTF-8: `valid_up_to` bytes are; the lossy text's range.
    NotUtf8 {
        valid_up_to: usize,
        lossy: Range<usize>,
    },
    /// The input could not be read here: the message.
    ReadError(String),
}

impl Lexed {
    /// An empty batch.
    pub fn new() -> Lexed {
        Lexed::default()
    }

    /// Lines in the batch.
    pub fn len(&self) -> usize {
        self.lines.len()
    }

    /// Whether the batch holds no line.
    pub fn is_empty(&self) -> bool {
        self.lines.is_empty()
    }

    /// Whether the input ends after this batch.
    pub fn is_end(&self) -> bool {
        self.end
    }

    /// Empties the batch, keeping its memory for the next one.
    pub fn clear(&mut self) {
        self.text.clear();
        self.lines.clear();
        self.toks.clear();
        self.end = false;
    }

    fn push_text(&mut self, text: &str, span: Span) {
        let start = self.text.len();
        self.text.push_str(text);
        self.push_line(start..self.text.len(), span);
    }

    /// Adds the line whose text is already at `text` in the buffer, with its tokens.
    fn push_line(&mut self, text: Range<usize>, span: Span) {
        let first_tok = self.toks.len();
        self.toks.extend(
            lexer::tokens(&self.text[text.clone()])
                .map(|(s, tok, e)| (s as u32, e as u32, tok.kind())),
        );
        let toks = first_tok..self.toks.len();
        self.lines.push(Entry {
            span,
            what: Line::Text { text, toks },
        });
    }
}

/// The reading half: lines from a buffered reader, tokenised into [`Lexed`] batches.
pub struct Lines<R> {
    reader: LineReader<R>,
    /// Longest line accepted, bytes.
    max_len: usize,
    done: bool,
}

impl<R: BufRead> Lines<R> {
    /// Lines of `reader`, a line over `max_line_len` bytes being refused.
    pub fn new(reader: R, max_line_len: usize) -> Lines<R> {
        Lines {
            reader: LineReader::new(reader, max_line_len),
            max_len: max_line_len,
            done: false,
        }
    }

    /// Fills `into` (emptied first) with up to `max` lines; marks it as the end when the
    /// input is done.
    pub fn read(&mut self, into: &mut Lexed, max: usize) {
        into.clear();
        while into.len() < max.max(1) && !self.done {
            if self.take_whole_lines(into, max) {
                continue;
            }
            let (raw, span) = match self.reader.next_line() {
                Ok(Some(line)) => line,
                Ok(None) => {
                    self.done = true;
                    break;
                }
                Err(e) => {
                    self.done = true;
                    let what = Line::ReadError(format!("cannot read the input: {e}"));
                    let span = Span::default();
                    into.lines.push(Entry { span, what });
                    break;
                }
            };
            match raw {
                RawLine::Text(text) => into.push_text(text, span),
                RawLine::TooLong => into.lines.push(Entry {
                    span,
                    what: Line::TooLong,
                }),
                RawLine::NotUtf8 { valid_up_to, lossy } => {
                    let start = into.text.len();
                    into.text.push_str(&lossy);
                    let lossy = start..into.text.len();
                    let what = Line::NotUtf8 { valid_up_to, lossy };
                    into.lines.push(Entry { span, what });
                }
            }
        }
        into.end = self.done;
    }

    /// Bytes read so far.
    pub fn bytes_read(&self) -> u64 {
        self.reader.bytes_read()
    }

    /// Takes the lines that lie whole in the reader's buffer (up to `max` lines in
    /// `into`) at once: one copy of their bytes and one UTF-8 check for all. False when
    /// not one line could be taken so: the next line then goes alone, by
    /// [`LineReader::next_line`] (a line over the limit or across the buffer's end, the
    /// last line without its newline, a line that is not UTF-8, a read error).
    fn take_whole_lines(&mut self, into: &mut Lexed, max: usize) -> bool {
        let max_len = self.max_len;
        let Ok((chunk, (offset, line))) = self.reader.buffered() else {
            return false;
        };
        let want = max.saturating_sub(into.len());
        // The byte after each whole line's newline, and its content length.
        let (mut end, mut count) = (0, 0);
        for nl in memchr::memchr_iter(b'\n', chunk).take(want) {
            if content_len(chunk, nl) - end > max_len {
                break;
            }
            end = nl + 1;
            count += 1;
        }
        let text = match std::str::from_utf8(&chunk[..end]) {
            Ok(text) => text,
            Err(e) => {
                // Only the lines before the first bad byte.
                let valid = &chunk[..e.valid_up_to()];
                end = memchr::memrchr(b'\n', valid).map_or(0, |i| i + 1);
                count = memchr::memchr_iter(b'\n', &chunk[..end]).count();
                // Whole lines of valid UTF-8: the check cannot fail.
                std::str::from_utf8(&chunk[..end]).unwrap_or_default()
            }
        };
        if count == 0 {
            return false;
        }
        let base = into.text.len();
        into.text.push_str(text);
        let (mut start, mut offset, mut line) = (0, offset, line);
        for nl in memchr::memchr_iter(b'\n', &chunk[..end]) {
            let content = content_len(chunk, nl) - start;
            line += 1;
            let span = Span {
                offset,
                len: content as u32,
                line,
            };
            into.push_line(base + start..base + start + content, span);
            offset += (nl + 1 - start) as u64;
            start = nl + 1;
        }
        self.reader.skip_lines(end, count as u32);
        true
    }
}

/// The reading half as a pipeline holds it, whatever it reads from.
pub trait ReadLines {
    /// As [`Lines::read`].
    fn read(&mut self, into: &mut Lexed, max: usize);
    /// As [`Lines::bytes_read`].
    fn bytes_read(&self) -> u64;
}

impl<R: BufRead> ReadLines for Lines<R> {
    fn read(&mut self, into: &mut Lexed, max: usize) {
        Lines::read(self, into, max)
    }

    fn bytes_read(&self) -> u64 {
        Lines::bytes_read(self)
    }
}

/// The lowering half: the modal state of the program, given [`Lexed`] batches in input
/// order.
pub struct Lowering {
    lower: Lowerer,
    max_line_len: usize,
    lines: u64,
    /// Lines refused before lowering (too long, not UTF-8).
    bad_lines: u64,
    /// The input could not be read to its end: no end-of-program checks.
    read_failed: bool,
    /// The tokens of the line being lowered (the buffer is kept from line to line).
    toks: Vec<Spanned<'static>>,
}

impl Lowering {
    /// A program's lowering, under `options`.
    pub fn new(options: Options) -> Lowering {
        Lowering {
            max_line_len: options.max_line_len,
            lower: Lowerer::new(options),
            lines: 0,
            bad_lines: 0,
            read_failed: false,
            toks: Vec::with_capacity(32),
        }
    }

    /// Lowers the lines of `lexed` into `out`; after the input's last batch, reports an
    /// empty input and what the program left open.
    pub fn lower(&mut self, lexed: &Lexed, out: &mut Vec<Block>, diags: &mut Vec<Diagnostic>) {
        for entry in &lexed.lines {
            self.line(lexed, entry, out, diags);
        }
        if lexed.end && !self.read_failed {
            self.finish(diags);
        }
    }

    fn line(
        &mut self,
        lexed: &Lexed,
        entry: &Entry,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let span = entry.span;
        match &entry.what {
            Line::Text { text, toks } => {
                self.lines += 1;
                let text = &lexed.text[text.clone()];
                let mut buf = lower::recycle(std::mem::take(&mut self.toks));
                buf.extend(lexed.toks[toks.clone()].iter().map(|&(s, e, kind)| {
                    let (s, e) = (s as usize, e as usize);
                    (s, kind.with_text(&text[s..e]), e)
                }));
                self.lower.lexed_line(text, span, &buf, out, diags);
                self.toks = lower::recycle(buf);
            }
            Line::TooLong => {
                self.lines += 1;
                self.bad_lines += 1;
                diags.push(too_long(span, self.max_line_len));
            }
            Line::NotUtf8 { valid_up_to, lossy } => {
                self.lines += 1;
                self.bad_lines += 1;
                diags.push(lower::not_utf8(
                    span,
                    *valid_up_to,
                    &lexed.text[lossy.clone()],
                ));
            }
            Line::ReadError(message) => {
                self.read_failed = true;
                diags.push(Diagnostic::io("io::read", message.clone()));
            }
        }
    }

    /// The end of the input: an input with no G-code is an error; the lowerer reports
    /// what the program left open.
    fn finish(&mut self, diags: &mut Vec<Diagnostic>) {
        let counts = LineCounts {
            lines: self.lines,
            saw_text: self.lower.saw_text(),
            bad_lines: self.bad_lines,
        };
        diags.extend(counts.empty_error("gcode::empty", "G-code line or comment"));
        self.lower.finish(diags);
    }
}

/// The error for a line over the length limit.
fn too_long(span: Span, limit: usize) -> Diagnostic {
    Diagnostic::error(
        "gcode::line-too-long",
        format!(
            "line {} is {} bytes long, over the limit of {limit} bytes",
            span.line, span.len
        ),
    )
    .at_span(span)
    .with_help(
        "this is not G-code a controller accepts; check that the file is not binary or \
         missing its line breaks",
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::strategy::Strategy;

    /// What [`LineReader::next_line`] gives, line by line, in the form a batch holds.
    fn one_by_one(bytes: &[u8], cap: usize, max_len: usize) -> Vec<(Span, String)> {
        let mut r = LineReader::new(std::io::BufReader::with_capacity(cap, bytes), max_len);
        let mut out = Vec::new();
        while let Ok(Some((raw, span))) = r.next_line() {
            let text = match raw {
                RawLine::Text(t) => format!("text {t}"),
                RawLine::TooLong => "too long".to_string(),
                RawLine::NotUtf8 { valid_up_to, lossy } => format!("bad {valid_up_to} {lossy}"),
            };
            out.push((span, text));
        }
        out
    }

    /// What [`Lines::read`] batches hold, in the same form, and the tokens of each text
    /// line against the lexer's.
    fn batched(bytes: &[u8], cap: usize, max_len: usize, batch: usize) -> Vec<(Span, String)> {
        let mut lines = Lines::new(std::io::BufReader::with_capacity(cap, bytes), max_len);
        let mut lexed = Lexed::new();
        let mut out = Vec::new();
        loop {
            lines.read(&mut lexed, batch);
            for e in &lexed.lines {
                let text = match &e.what {
                    Line::Text { text, toks } => {
                        let t = &lexed.text[text.clone()];
                        let ours: Vec<_> = lexed.toks[toks.clone()]
                            .iter()
                            .map(|&(s, e, k)| {
                                (
                                    s as usize,
                                    k.with_text(&t[s as usize..e as usize]),
                                    e as usize,
                                )
                            })
                            .collect();
                        assert_eq!(ours, lexer::tokens(t).collect::<Vec<_>>());
                        format!("text {t}")
                    }
                    Line::TooLong => "too long".to_string(),
                    Line::NotUtf8 { valid_up_to, lossy } => {
                        format!("bad {valid_up_to} {}", &lexed.text[lossy.clone()])
                    }
                    Line::ReadError(m) => format!("error {m}"),
                };
                out.push((e.span, text));
            }
            if lexed.is_end() {
                return out;
            }
        }
    }

    proptest::proptest! {
        /// Lines taken whole from the reader's buffer, many at once, are the lines the
        /// reader gives one by one, with the same spans: whatever the buffer size, line
        /// ends, byte-order mark, over-long lines and bytes that are not UTF-8.
        #[test]
        fn batches_hold_the_lines_one_by_one_reading_gives(
            parts in proptest::collection::vec(
                proptest::prop_oneof![
                    proptest::string::string_regex("[G01XYZ. ;(a)-]{0,12}").expect("regex").prop_map(String::into_bytes),
                    proptest::strategy::Just(b"\r\n".to_vec()),
                    proptest::strategy::Just(b"\n".to_vec()),
                    proptest::strategy::Just(vec![0xff, b'G']),
                    proptest::strategy::Just("é".as_bytes().to_vec()),
                ],
                0..40,
            ),
            bom in proptest::bool::ANY,
            cap in 8usize..64,
            max_len in 4usize..30,
            batch in 1usize..6,
        ) {
            let mut bytes = if bom { b"\xEF\xBB\xBF".to_vec() } else { Vec::new() };
            bytes.extend(parts.concat());
            proptest::prop_assert_eq!(
                batched(&bytes, cap, max_len, batch),
                one_by_one(&bytes, cap, max_len)
            );
        }
    }
}
