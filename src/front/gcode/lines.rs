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
use crate::front::{LineReader, RawLine};
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
        let first_tok = self.toks.len();
        self.toks
            .extend(lexer::tokens(text).map(|(s, tok, e)| (s as u32, e as u32, tok.kind())));
        self.lines.push(Entry {
            span,
            what: Line::Text {
                text: start..self.text.len(),
                toks: first_tok..self.toks.len(),
            },
        });
    }
}

/// The reading half: lines from a buffered reader, tokenised into [`Lexed`] batches.
pub struct Lines<R> {
    reader: LineReader<R>,
    done: bool,
}

impl<R: BufRead> Lines<R> {
    /// Lines of `reader`, a line over `max_line_len` bytes being refused.
    pub fn new(reader: R, max_line_len: usize) -> Lines<R> {
        Lines {
            reader: LineReader::new(reader, max_line_len),
            done: false,
        }
    }

    /// Fills `into` (emptied first) with up to `max` lines; marks it as the end when the
    /// input is done.
    pub fn read(&mut self, into: &mut Lexed, max: usize) {
        into.clear();
        while into.len() < max.max(1) && !self.done {
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
        if self.lines == 0 || (!self.lower.saw_text() && self.bad_lines == 0) {
            let what = if self.lines == 0 {
                "the input is empty"
            } else {
                "the input has only blank lines"
            };
            diags.push(
                Diagnostic::error("gcode::empty", what)
                    .with_help("give a file with at least one G-code line or comment"),
            );
        }
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
