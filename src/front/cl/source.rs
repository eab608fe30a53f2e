//! From lines to statements: `$` continuation, `$$` comments, and a bounded look at the
//! start of the input (the triplet format, the length unit of files that do not name it).

use std::collections::VecDeque;
use std::io::BufRead;

use crate::diag::Diagnostic;
use crate::front::LineCounts;
use crate::front::{LineReader, RawLine};
use crate::ir::Span;

/// Lines looked at, at most, before the first statement is lowered.
const PROBE_LINES: usize = 4096;
/// Bytes looked at, at most, before the first statement is lowered.
const PROBE_BYTES: usize = 1 << 20;

/// What the look at the start of the input found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct Probe {
    /// The input is in the triplet format (point line, axis line, motion code line).
    pub triplet: bool,
    /// The first clue to the length unit: a `UNITS` statement (`None` inside) or the
    /// first feed with a unit word (`Some(true)` for `IPM`/`IPR`), with its line.
    pub unit_clue: Option<(Option<bool>, u32)>,
}

/// One line of a statement: where its text is in `src` and its code in `code`.
#[derive(Debug, Clone, Copy)]
struct Segment {
    line: u32,
    src_start: usize,
    src_end: usize,
    code_start: usize,
    code_end: usize,
}

/// One statement: its lines joined, without `$` continuation marks and `$$` comments.
#[derive(Debug, Default)]
pub(super) struct Statement {
    /// The code, lines joined by a space.
    pub code: String,
    /// The `$$` comments, text after the `$$`, in order.
    pub comments: Vec<String>,
    /// The whole source lines, one after another.
    src: String,
    segments: Vec<Segment>,
    /// The lines the statement covers (`line` is the first).
    pub span: Span,
    /// The last line ends with `$` but the input ended.
    pub open_at_end: bool,
}

impl Statement {
    fn clear(&mut self) {
        self.code.clear();
        self.comments.clear();
        self.src.clear();
        self.segments.clear();
        self.span = Span::default();
        self.open_at_end = false;
    }

    /// Points `d` at the bytes `start..end` of [`Statement::code`], on the source line
    /// they come from.
    pub fn locate(&self, d: Diagnostic, start: usize, end: usize) -> Diagnostic {
        let seg = self
            .segments
            .iter()
            .rev()
            .find(|s| s.code_start <= start && s.code_end > s.code_start)
            .or(self.segments.first());
        match seg {
            Some(s) => {
                let text = &self.src[s.src_start..s.src_end];
                let width = s.code_end - s.code_start;
                let from = start.saturating_sub(s.code_start).min(width);
                let to = end.min(s.code_end).saturating_sub(s.code_start).max(from);
                let to = if to == from { from + 1 } else { to };
                d.at_bytes(s.line, text, from, to)
            }
            None => d.at_span(self.span),
        }
    }

    /// Points `d` at the statement's code on its first line.
    pub fn locate_all(&self, d: Diagnostic) -> Diagnostic {
        let end = self.segments.first().map_or(0, |s| s.code_end);
        let lead = self.code[..end].len() - self.code[..end].trim_start().len();
        let code_end = self.code[..end].trim_end().len();
        self.locate(d, lead, code_end.max(lead + 1))
    }

    /// Appends one line; returns whether the line ends with a `$` continuation mark.
    fn push_line(&mut self, text: &str, span: Span, join: bool) -> bool {
        let (code, comment) = match comment_start(text) {
            Some(i) => (&text[..i], Some(&text[i + 2..])),
            None => (text, None),
        };
        let (code, continues) = match code.trim_end().strip_suffix('$') {
            Some(c) if join => (c, true),
            _ => (code, false),
        };
        if self.segments.is_empty() {
            self.span = span;
        } else {
            let end = span.offset + u64::from(span.len);
            self.span.len = end
                .saturating_sub(self.span.offset)
                .min(u64::from(u32::MAX)) as u32;
            if !code.trim().is_empty() {
                self.code.push(' ');
            }
        }
        let src_start = self.src.len();
        self.src.push_str(text);
        let code_start = self.code.len();
        self.code.push_str(code);
        self.segments.push(Segment {
            line: span.line,
            src_start,
            src_end: self.src.len(),
            code_start,
            code_end: self.code.len(),
        });
        if let Some(c) = comment {
            self.comments.push(c.trim_end().to_string());
        }
        continues
    }
}

/// A line held during the look at the start of the input.
#[derive(Debug)]
enum Held {
    Text(String),
    TooLong,
    NotUtf8 { valid_up_to: usize, lossy: String },
}

/// Reads statements from lines.
pub(super) struct Source<R> {
    reader: LineReader<R>,
    held: VecDeque<(Held, Span)>,
    probed: Option<Probe>,
    max_line_len: usize,
    /// What was read so far.
    pub counts: LineCounts,
    /// A statement is open: its last line ended with `$`.
    open: bool,
    done: bool,
}

impl<R: BufRead> Source<R> {
    pub fn new(reader: R, max_line_len: usize) -> Self {
        Source {
            reader: LineReader::new(reader, max_line_len),
            held: VecDeque::new(),
            probed: None,
            max_line_len,
            counts: LineCounts::default(),
            open: false,
            done: false,
        }
    }

    /// Ends the input after a read error, reported as `io::read`.
    fn read_failed(&mut self, e: &std::io::Error, diags: &mut Vec<Diagnostic>) {
        self.done = true;
        diags.push(Diagnostic::io(
            "io::read",
            format!("cannot read the input: {e}"),
        ));
    }

    pub fn bytes_read(&self) -> u64 {
        self.reader.bytes_read()
    }

    /// Looks at the start of the input (once, holding at most a bounded number of lines)
    /// and says what it found.
    pub fn probe(&mut self, diags: &mut Vec<Diagnostic>) -> Probe {
        if let Some(p) = self.probed {
            return p;
        }
        let mut probe = Probe::default();
        let mut bytes = 0usize;
        // The first three lines with code decide the triplet format.
        let mut shapes: Vec<Shape> = Vec::with_capacity(3);
        while self.held.len() < PROBE_LINES && bytes < PROBE_BYTES {
            let (held, span) = match self.reader.next_line() {
                Ok(Some((RawLine::Text(t), span))) => (Held::Text(t.to_string()), span),
                Ok(Some((RawLine::TooLong, span))) => (Held::TooLong, span),
                Ok(Some((RawLine::NotUtf8 { valid_up_to, lossy }, span))) => {
                    (Held::NotUtf8 { valid_up_to, lossy }, span)
                }
                Ok(None) => break,
                Err(e) => {
                    self.read_failed(&e, diags);
                    break;
                }
            };
            bytes += span.len as usize + 1;
            if let Held::Text(t) = &held {
                let code = t.split("$$").next().unwrap_or("").trim();
                if !code.is_empty() && shapes.len() < 3 {
                    shapes.push(Shape::of(code));
                }
                if probe.unit_clue.is_none() {
                    probe.unit_clue = unit_clue(code).map(|c| (c, span.line));
                }
            }
            self.held.push_back((held, span));
            if probe.unit_clue.is_some() && shapes.len() >= 3 {
                break;
            }
        }
        probe.triplet = matches!(shapes.as_slice(), [Shape::Three, Shape::Three, Shape::Hex]);
        self.probed = Some(probe);
        probe
    }

    /// Reads the next statement into `stmt`; false at the end of the input. When `join`
    /// is false (the triplet format) every line is a statement of its own.
    pub fn next_statement(
        &mut self,
        stmt: &mut Statement,
        join: bool,
        diags: &mut Vec<Diagnostic>,
    ) -> bool {
        stmt.clear();
        self.open = false;
        loop {
            let complete = if let Some((held, span)) = self.held.pop_front() {
                let raw = match held {
                    Held::Text(ref t) => RawLine::Text(t),
                    Held::TooLong => RawLine::TooLong,
                    Held::NotUtf8 { valid_up_to, lossy } => RawLine::NotUtf8 { valid_up_to, lossy },
                };
                take_line(
                    &mut self.counts,
                    &mut self.open,
                    raw,
                    span,
                    stmt,
                    join,
                    self.max_line_len,
                    diags,
                )
            } else if self.done {
                break;
            } else {
                match self.reader.next_line() {
                    Ok(Some((raw, span))) => take_line(
                        &mut self.counts,
                        &mut self.open,
                        raw,
                        span,
                        stmt,
                        join,
                        self.max_line_len,
                        diags,
                    ),
                    Ok(None) => {
                        self.done = true;
                        false
                    }
                    Err(e) => {
                        self.read_failed(&e, diags);
                        false
                    }
                }
            };
            if complete {
                return true;
            }
        }
        if stmt.segments.is_empty() {
            return false;
        }
        stmt.open_at_end = self.open;
        true
    }
}

/// Adds one line to the statement being read; returns whether the statement is complete.
#[allow(clippy::too_many_arguments)]
fn take_line(
    counts: &mut LineCounts,
    open: &mut bool,
    raw: RawLine<'_>,
    span: Span,
    stmt: &mut Statement,
    join: bool,
    max_line_len: usize,
    diags: &mut Vec<Diagnostic>,
) -> bool {
    counts.lines += 1;
    let text = match raw {
        RawLine::Text(t) => t,
        RawLine::TooLong => {
            counts.bad_lines += 1;
            diags.push(
                Diagnostic::error(
                    "cl::line-too-long",
                    format!(
                        "line {} is {} bytes long, over the limit of {max_line_len} bytes",
                        span.line, span.len
                    ),
                )
                .at_span(span)
                .with_help(
                    "this is not CL data; check that the file is not binary or missing its \
                     line breaks",
                ),
            );
            return false;
        }
        RawLine::NotUtf8 { valid_up_to, lossy } => {
            counts.bad_lines += 1;
            let column = lossy
                .char_indices()
                .take_while(|(i, _)| *i < valid_up_to)
                .count() as u32
                + 1;
            diags.push(
                Diagnostic::error("cl::not-utf8", "the line is not valid UTF-8 text")
                    .at_line(span.line, &lossy, column, 1)
                    .with_label("this byte")
                    .with_help(
                        "CL data is text; check that the file is not binary or in another \
                         encoding (save it as UTF-8)",
                    ),
            );
            return false;
        }
    };
    let blank = text.trim().is_empty();
    if !blank {
        counts.saw_text = true;
    }
    if stmt.segments.is_empty() && blank {
        return false;
    }
    // The joined statement is held in memory: keep it within the line limit.
    if *open && stmt.src.len() + text.len() > max_line_len {
        diags.push(
            Diagnostic::error(
                "cl::statement-too-long",
                format!("the statement continued with `$` is over {max_line_len} bytes long"),
            )
            .at_span(span)
            .with_help("end the statement: the last line of a statement has no `$` at its end"),
        );
        *open = false;
        return true;
    }
    let continues = stmt.push_line(text, span, join);
    let code_blank = text[..comment_start(text).unwrap_or(text.len())]
        .trim()
        .is_empty();
    // A blank or comment-only line inside a continued statement keeps it open.
    *open = continues || (*open && code_blank);
    !*open
}

/// Where a `$$` comment starts in `text` (a single `$` at the end of the code is a
/// continuation mark, not a comment).
fn comment_start(text: &str) -> Option<usize> {
    let bytes = text.as_bytes();
    memchr::memchr_iter(b'$', bytes).find(|&i| bytes.get(i + 1) == Some(&b'$'))
}

/// How a line looks, for telling the triplet format from APT statements.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Shape {
    /// Three numbers separated by blanks.
    Three,
    /// One hexadecimal motion code (`7f`, `80`).
    Hex,
    Other,
}

impl Shape {
    fn of(code: &str) -> Shape {
        let mut fields = code.split_ascii_whitespace();
        let first = fields.next().unwrap_or("");
        if fields.clone().next().is_none()
            && (1..=4).contains(&first.len())
            && first.bytes().all(|b| b.is_ascii_hexdigit())
        {
            return Shape::Hex;
        }
        let numbers = code
            .split_ascii_whitespace()
            .take(4)
            .filter(|f| crate::num::parse_decimal(f).is_some_and(f64::is_finite))
            .count();
        if numbers == 3 && code.split_ascii_whitespace().count() == 3 {
            Shape::Three
        } else {
            Shape::Other
        }
    }
}

/// The unit a line says the file is in: `Some(None)` for a `UNITS` statement (the
/// lowering reads it), `Some(Some(inches))` for a feed with a unit word.
fn unit_clue(code: &str) -> Option<Option<bool>> {
    let upper_start = |word: &str| {
        code.get(..word.len())
            .is_some_and(|c| c.eq_ignore_ascii_case(word))
    };
    let major_end = code.find('/').unwrap_or(code.len());
    let major = code[..major_end].trim();
    if ["UNITS", "UNIT", "INCHES", "METRIC"]
        .iter()
        .any(|w| major.eq_ignore_ascii_case(w))
    {
        return Some(None);
    }
    if upper_start("FEDRAT") {
        for word in code[major_end.min(code.len())..]
            .split(|c: char| c == ',' || c == '/' || c.is_ascii_whitespace())
        {
            if word.eq_ignore_ascii_case("IPM") || word.eq_ignore_ascii_case("IPR") {
                return Some(Some(true));
            }
            if word.eq_ignore_ascii_case("MMPM") || word.eq_ignore_ascii_case("MMPR") {
                return Some(Some(false));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn statements(src: &str) -> Vec<(String, Vec<String>, Span, bool)> {
        let mut source = Source::new(src.as_bytes(), 1 << 20);
        let mut diags = Vec::new();
        source.probe(&mut diags);
        let mut stmt = Statement::default();
        let mut out = Vec::new();
        while source.next_statement(&mut stmt, true, &mut diags) {
            out.push((
                stmt.code.clone(),
                stmt.comments.clone(),
                stmt.span,
                stmt.open_at_end,
            ));
        }
        assert!(diags.is_empty(), "{diags:?}");
        out
    }

    #[test]
    fn continuation_joins_lines_and_keeps_comments() {
        let s = statements("GOTO/1,$\n  2,$ $$ half\n3\nFINI\n");
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].0, "GOTO/1,   2, 3");
        assert_eq!(s[0].1, vec![" half".to_string()]);
        assert_eq!(
            s[0].2,
            Span {
                offset: 0,
                len: 24,
                line: 1
            }
        );
        assert_eq!(s[1].0, "FINI");
        assert_eq!(s[1].2.line, 4);
    }

    #[test]
    fn comment_lines_inside_a_continuation_keep_it_open() {
        let s = statements("GOTO/1,$\n$$ note\n\n2,3\n");
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].0, "GOTO/1, 2,3");
    }

    #[test]
    fn open_statement_at_the_end() {
        let s = statements("GOTO/1,2,$");
        assert_eq!(s.len(), 1);
        assert!(s[0].3);
    }

    #[test]
    fn blank_lines_are_skipped() {
        let s = statements("\n\nRAPID\r\n\n");
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].2.line, 3);
    }

    #[test]
    fn triplet_and_units_are_probed() {
        let mut d = Vec::new();
        let p = Source::new("0 0 1\n0 0 1\n7f\n".as_bytes(), 100).probe(&mut d);
        assert!(p.triplet);
        let p = Source::new("GOTO/1,2,3\nFEDRAT/IPM,10\n".as_bytes(), 100).probe(&mut d);
        assert!(!p.triplet);
        assert_eq!(p.unit_clue, Some((Some(true), 2)));
        let p = Source::new("UNITS/MM\nFEDRAT/IPM,10\n".as_bytes(), 100).probe(&mut d);
        assert_eq!(p.unit_clue, Some((None, 1)));
    }
}
