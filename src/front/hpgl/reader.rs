//! HPGL command reader: bytes to commands (mnemonic + parameters), with positions.
//!
//! HPGL has no lines: a command is two letters followed by parameters (numbers, or
//! quoted strings in HP-GL/2), separated by commas and/or blanks, and ends at `;`, at
//! the next letter (the next command's mnemonic) or at the end of the input. Line
//! breaks and blanks between commands and between parameters are allowed, so real
//! files with and without terminators, one command per line or everything on one
//! line, all read the same. `LB` (label) text runs to the label terminator (ETX,
//! byte 3, or the one `DT` sets) and may hold any byte, `;` included; a label the input
//! ends inside is an error (`hpgl::open-label`), not a plot that silently stops there.
//! A UTF-8 byte-order mark at the start is skipped; one anywhere else is an error that
//! says BOM. Parameters beyond [`crate::num::range::MAX_MAGNITUDE`] are errors.
//!
//! Memory is bounded: a command longer than the limit is an error and its bytes are
//! skipped, not buffered.

use std::io::{self, BufRead};

use crate::diag::{Diagnostic, Location};
use crate::ir::Span;

/// A parameter as written.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Value {
    /// A number.
    Num(f64),
    /// A quoted string (without the quotes).
    Str(String),
}

/// A parameter and where it is in the command text.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Param {
    /// Its value.
    pub value: Value,
    /// Byte range in [`Command::text`].
    pub start: usize,
    /// End of the byte range.
    pub end: usize,
}

/// One command.
#[derive(Debug, Clone, Default)]
pub(super) struct Command {
    /// Upper-case mnemonic.
    pub mnemonic: [u8; 2],
    /// The command as written, from its first letter up to (not including) its
    /// terminator (for `LB`, the label terminator).
    pub text: Vec<u8>,
    /// Parsed parameters (empty for `LB`, `DT`).
    pub params: Vec<Param>,
    /// Where it starts; `len` covers the text.
    pub span: Span,
    /// 1-based column (characters) of its first letter on `span.line`.
    pub column: u32,
}

impl Command {
    /// The mnemonic as text.
    pub fn name(&self) -> &str {
        std::str::from_utf8(&self.mnemonic).unwrap_or("??")
    }

    /// The numbers of the parameters; the first string parameter is an error.
    pub fn numbers(&self) -> Result<Vec<f64>, Diagnostic> {
        self.params
            .iter()
            .map(|p| match p.value {
                Value::Num(v) => Ok(v),
                Value::Str(_) => Err(self
                    .diag_at(
                        Diagnostic::error(
                            "hpgl::bad-parameter",
                            format!("{} takes numbers, not a string", self.name()),
                        ),
                        p.start,
                        p.end,
                    )
                    .with_help("remove the quoted text")),
            })
            .collect()
    }

    /// Points `diag` at bytes `start..end` of the command text: the line and column
    /// are those in the input, the snippet is the command's text on that line.
    pub fn diag_at(&self, diag: Diagnostic, start: usize, end: usize) -> Diagnostic {
        let start = start.min(self.text.len());
        let end = end.clamp(start, self.text.len());
        // The line of the mark: the command may run over several lines.
        let before = &self.text[..start];
        let newlines = before.iter().filter(|&&b| b == b'\n').count() as u32;
        let line_start = before
            .iter()
            .rposition(|&b| b == b'\n')
            .map_or(0, |i| i + 1);
        let line_end = self.text[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(self.text.len(), |i| start + i);
        let first_col = if newlines == 0 { self.column } else { 1 };
        let seg = &self.text[line_start..line_end];
        let lossy = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
        let prefix_chars = lossy(&self.text[line_start..start]).chars().count() as u32;
        let mark_chars = lossy(&self.text[start..end.min(line_end)]).chars().count() as u32;
        let column = first_col + prefix_chars;
        let mut text: String = lossy(seg)
            .chars()
            .map(|c| {
                if c.is_control() && c != '\t' {
                    '\u{fffd}'
                } else {
                    c
                }
            })
            .collect();
        let mut cut = first_col - 1;
        // Keep the snippet readable around the mark.
        const MAX: u32 = 160;
        let count = text.chars().count() as u32;
        if count > MAX {
            let skip = prefix_chars.saturating_sub(MAX / 2).min(count - MAX);
            text = text
                .chars()
                .skip(skip as usize)
                .take(MAX as usize)
                .collect();
            cut += skip;
        }
        let mut d = diag;
        d.location = Some(Box::new(Location {
            line: self.span.line + newlines,
            column,
            len: mark_chars.max(1),
            source_line: text,
            cut,
        }));
        d
    }

    /// Points `diag` at the whole command (its mnemonic when it is long).
    pub fn diag(&self, diag: Diagnostic) -> Diagnostic {
        let end = if self.text.len() > 40 {
            2
        } else {
            self.text.len()
        };
        self.diag_at(diag, 0, end)
    }
}

/// Reads commands from a byte stream.
pub(super) struct Reader<R> {
    inner: R,
    max_len: usize,
    offset: u64,
    line: u32,
    column: u32,
    /// Label terminator (`DT`).
    label_end: u8,
    /// The last byte read was a bad one (so a run of them gives one error).
    in_garbage: bool,
    /// I/O error already reported.
    failed: bool,
    /// The last `LB` ran to the end of the input without its terminator.
    open_label: bool,
}

impl<R: BufRead> Reader<R> {
    /// A reader over `inner`; commands over `max_len` bytes are errors.
    pub fn new(inner: R, max_len: usize) -> Self {
        Reader {
            inner,
            max_len,
            offset: 0,
            line: 1,
            column: 1,
            label_end: 3,
            in_garbage: false,
            failed: false,
            open_label: false,
        }
    }

    /// Bytes consumed so far.
    pub fn bytes_read(&self) -> u64 {
        self.offset
    }

    fn peek(&mut self) -> io::Result<Option<u8>> {
        loop {
            match self.inner.fill_buf() {
                Ok(b) => return Ok(b.first().copied()),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        }
    }

    /// The input goes on with a UTF-8 byte-order mark (all of it in the buffer).
    fn at_bom(&mut self) -> io::Result<bool> {
        loop {
            match self.inner.fill_buf() {
                Ok(b) => return Ok(b.starts_with(&BOM)),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        }
    }

    fn bump(&mut self, b: u8) {
        self.inner.consume(1);
        self.offset += 1;
        if b == b'\n' {
            self.line += 1;
            self.column = 1;
        } else if b & 0xC0 != 0x80 {
            // Columns count characters: UTF-8 continuation bytes do not start one.
            self.column += 1;
        }
    }

    fn io_error(&mut self, e: io::Error, diags: &mut Vec<Diagnostic>) -> Option<Command> {
        if !self.failed {
            self.failed = true;
            diags.push(
                Diagnostic::io("io::read", format!("cannot read the input: {e}"))
                    .with_help("check the file and the device it is on"),
            );
        }
        None
    }

    /// The next command, or `None` at the end of the input. Malformed bytes between
    /// commands are errors pushed to `diags`; reading goes on after them.
    pub fn next_command(&mut self, diags: &mut Vec<Diagnostic>) -> Option<Command> {
        loop {
            if let Some(c) = self.try_command(diags) {
                return c;
            }
        }
    }

    /// One attempt: `None` after a malformed command (reported; try again),
    /// `Some(None)` at the end.
    fn try_command(&mut self, diags: &mut Vec<Diagnostic>) -> Option<Option<Command>> {
        if self.failed {
            return Some(None);
        }
        // A byte-order mark, which Windows editors put at the start of a text file, is
        // not part of the plot.
        if self.offset == 0 {
            match self.at_bom() {
                Ok(true) => {
                    self.inner.consume(BOM.len());
                    self.offset += BOM.len() as u64;
                }
                Ok(false) => {}
                Err(e) => return Some(self.io_error(e, diags)),
            }
        }
        // Between commands: blanks, line breaks, stray terminators.
        let first = loop {
            let b = match self.peek() {
                Ok(Some(b)) => b,
                Ok(None) => return Some(None),
                Err(e) => return Some(self.io_error(e, diags)),
            };
            if b.is_ascii_alphabetic() {
                self.in_garbage = false;
                break b;
            }
            let (line, column) = (self.line, self.column);
            if b == BOM[0] && matches!(self.at_bom(), Ok(true)) {
                // Files joined together carry a mark each: one error for the whole mark.
                self.inner.consume(BOM.len());
                self.offset += BOM.len() as u64;
                self.column += 1;
                self.in_garbage = false;
                diags.push(bom_inside(line, column));
                continue;
            }
            self.bump(b);
            if matches!(b, b' ' | b'\t' | b'\r' | b'\n' | b';' | 0 | 0x0C | 0x1A) {
                // NUL padding, form feed and Ctrl-Z (DOS end of file) appear in real
                // plotter files between commands.
                self.in_garbage = false;
                continue;
            }
            if !self.in_garbage {
                self.in_garbage = true;
                diags.push(unexpected(b, line, column));
            }
        };
        let mut cmd = Command {
            span: Span {
                offset: self.offset,
                len: 0,
                line: self.line,
            },
            column: self.column,
            ..Command::default()
        };
        self.bump(first);
        cmd.text.push(first);
        let second = match self.peek() {
            Ok(b) => b,
            Err(e) => return Some(self.io_error(e, diags)),
        };
        match second {
            Some(b) if b.is_ascii_alphabetic() => {
                self.bump(b);
                cmd.text.push(b);
                cmd.mnemonic = [first.to_ascii_uppercase(), b.to_ascii_uppercase()];
            }
            _ => {
                diags.push(
                    cmd.diag_at(
                        Diagnostic::error(
                            "hpgl::mnemonic",
                            format!("`{}` alone is not a command", first as char),
                        ),
                        0,
                        1,
                    )
                    .with_label("a command is two letters")
                    .with_help("write the whole command, such as `PU` or `PD`"),
                );
                self.in_garbage = true;
                return None;
            }
        }
        let too_long = match &cmd.mnemonic {
            b"LB" => self.read_label(&mut cmd),
            b"DT" => self.read_dt(&mut cmd),
            _ => self.read_params(&mut cmd),
        };
        let too_long = match too_long {
            Ok(t) => t,
            Err(e) => return Some(self.io_error(e, diags)),
        };
        self.finish(cmd, too_long, diags)
    }

    /// The command read: its span, the error when it was too long, its parameters.
    fn finish(
        &mut self,
        mut cmd: Command,
        too_long: bool,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<Option<Command>> {
        cmd.span.len = (self.offset - cmd.span.offset).min(u32::MAX as u64) as u32;
        if std::mem::take(&mut self.open_label) {
            diags.push(self.unterminated_label(&cmd));
            return None;
        }
        if too_long {
            diags.push(
                cmd.diag_at(
                    Diagnostic::error(
                        "hpgl::too-long",
                        format!(
                            "this {} command is longer than {} bytes; it is skipped",
                            cmd.name(),
                            self.max_len
                        ),
                    ),
                    0,
                    2,
                )
                .with_help("split it into several commands, or raise the frontend option `max_command_len`"),
            );
            return None;
        }
        if !matches!(&cmd.mnemonic, b"LB" | b"DT") {
            let text = std::mem::take(&mut cmd.text);
            match parse_params(&text, &mut cmd.params) {
                Ok(()) => cmd.text = text,
                Err((start, end, msg, help)) => {
                    cmd.text = text;
                    diags.push(cmd.diag_at(
                        Diagnostic::error("hpgl::bad-parameter", msg).with_help(help),
                        start,
                        end,
                    ));
                    return None;
                }
            }
        }
        Some(Some(cmd))
    }

    /// The error for an `LB` whose terminator never comes.
    fn unterminated_label(&self, cmd: &Command) -> Diagnostic {
        let terminator = if self.label_end == 3 {
            "ETX (byte 0x03)".to_string()
        } else if self.label_end.is_ascii_graphic() {
            format!("`{}` (set by DT)", self.label_end as char)
        } else {
            format!("byte 0x{:02X} (set by DT)", self.label_end)
        };
        cmd.diag_at(
            Diagnostic::error(
                "hpgl::open-label",
                format!(
                    "this label is not terminated: no {terminator} before the end of the input, so it would swallow every command after it"
                ),
            ),
            0,
            2,
        )
        .with_label("label starts here")
        .with_help(format!(
            "end the label text with {terminator}; if the file was edited as text, the terminator may have been lost"
        ))
    }

    /// Parameters: up to `;` (consumed), the next letter or the end. Returns whether
    /// the command was too long (its bytes then skipped).
    fn read_params(&mut self, cmd: &mut Command) -> io::Result<bool> {
        let mut quoted = false;
        let mut too_long = false;
        while let Some(b) = self.peek()? {
            if !quoted {
                if b == b';' {
                    self.bump(b);
                    break;
                }
                if b.is_ascii_alphabetic() {
                    break;
                }
            }
            if b == b'"' {
                quoted = !quoted;
            }
            self.bump(b);
            if cmd.text.len() >= self.max_len {
                too_long = true;
            } else {
                cmd.text.push(b);
            }
        }
        // Trailing blanks and line breaks belong to no command.
        while cmd.text.last().is_some_and(|b| b.is_ascii_whitespace()) {
            cmd.text.pop();
        }
        Ok(too_long)
    }

    /// `LB` text up to the label terminator. A label the input ends inside is an
    /// error: its text would hold the rest of the file, every command after it lost.
    fn read_label(&mut self, cmd: &mut Command) -> io::Result<bool> {
        let mut too_long = false;
        while let Some(b) = self.peek()? {
            self.bump(b);
            if b == self.label_end {
                return Ok(too_long);
            }
            if cmd.text.len() >= self.max_len {
                too_long = true;
            } else {
                cmd.text.push(b);
            }
        }
        self.open_label = true;
        Ok(too_long)
    }

    /// `DT t[,mode];`: the byte after `DT` is the new label terminator (`;` or the end:
    /// back to ETX).
    fn read_dt(&mut self, cmd: &mut Command) -> io::Result<bool> {
        match self.peek()? {
            None => self.label_end = 3,
            Some(b';') => {
                self.bump(b';');
                self.label_end = 3;
                return Ok(false);
            }
            Some(b) => {
                self.bump(b);
                cmd.text.push(b);
                self.label_end = b;
            }
        }
        // An optional `,mode`.
        while let Some(b) = self.peek()? {
            if b == b';' {
                self.bump(b);
                break;
            }
            if !(b == b',' || b.is_ascii_digit() || b == b' ') {
                break;
            }
            self.bump(b);
            cmd.text.push(b);
        }
        Ok(false)
    }
}

/// The UTF-8 byte-order mark.
const BOM: [u8; 3] = [0xEF, 0xBB, 0xBF];

/// The error for a byte-order mark after the start of the input.
fn bom_inside(line: u32, column: u32) -> Diagnostic {
    let mut d = Diagnostic::error(
        "hpgl::unexpected",
        "a UTF-8 byte-order mark (BOM) where a command (two letters) should start",
    )
    .with_help("a BOM belongs only at the very start of a file (it is skipped there); remove it, as when files were joined together");
    d.location = Some(Box::new(Location {
        line,
        column,
        len: 1,
        source_line: "\u{fffd}".to_string(),
        cut: column - 1,
    }));
    d
}

/// The error for a byte `b` at `line`, `column` where a command should start.
fn unexpected(b: u8, line: u32, column: u32) -> Diagnostic {
    let shown = if b.is_ascii_graphic() {
        format!("`{}`", b as char)
    } else {
        format!("byte 0x{b:02X}")
    };
    let mut d = Diagnostic::error(
        "hpgl::unexpected",
        format!("{shown} where a command (two letters) should start"),
    )
    .with_help("HPGL commands are two letters and parameters, such as `PA100,200;`");
    d.location = Some(Box::new(Location {
        line,
        column,
        len: 1,
        source_line: if b.is_ascii_graphic() {
            (b as char).to_string()
        } else {
            "\u{fffd}".to_string()
        },
        cut: column - 1,
    }));
    d
}

/// Splits the text after the mnemonic into numbers and strings. `Err` gives the byte
/// range, message and help of the first bad parameter.
fn parse_params(
    text: &[u8],
    out: &mut Vec<Param>,
) -> Result<(), (usize, usize, String, &'static str)> {
    let mut i = 2;
    // Whether a comma was seen since the last parameter (for empty ones).
    let mut comma = false;
    let n = text.len();
    while i < n {
        let b = text[i];
        if b.is_ascii_whitespace() {
            i += 1;
            continue;
        }
        if b == b',' {
            if comma || out.is_empty() {
                return Err((
                    i,
                    i + 1,
                    "empty parameter".into(),
                    "remove the extra comma or write the missing number",
                ));
            }
            comma = true;
            i += 1;
            continue;
        }
        let start = i;
        if b == b'"' {
            let close = text[i + 1..].iter().position(|&c| c == b'"');
            let Some(close) = close else {
                return Err((
                    i,
                    n,
                    "unterminated string".into(),
                    "close the string with `\"`",
                ));
            };
            let s = String::from_utf8_lossy(&text[i + 1..i + 1 + close]).into_owned();
            i += close + 2;
            out.push(Param {
                value: Value::Str(s),
                start,
                end: i,
            });
            comma = false;
            continue;
        }
        // A number: sign, digits, point, digits; the token runs to the next separator,
        // for the message.
        let mut end = i;
        while end < n && !(text[end] == b',' || text[end].is_ascii_whitespace()) {
            end += 1;
        }
        let token = String::from_utf8_lossy(&text[start..end]);
        let shown = crate::num::range::shown(&token);
        let v = match crate::num::scan_decimal(text, start) {
            Some((v, e)) if e == end => v,
            _ => {
                return Err((
                    start,
                    end,
                    format!("`{shown}` is not a number"),
                    "parameters are numbers such as `120`, `-3.5` or `+.25`, separated by commas",
                ));
            }
        };
        if !crate::num::range::in_range(v) {
            return Err((
                start,
                end,
                format!("`{shown}` is too large"),
                "parameters are at most 1e12 in size (plotter coordinates are at most about 1e9)",
            ));
        }
        out.push(Param {
            value: Value::Num(v),
            start,
            end,
        });
        comma = false;
        i = end;
    }
    if comma {
        let at = text.iter().rposition(|&b| b == b',').unwrap_or(n);
        return Err((
            at,
            at + 1,
            "a comma with no parameter after it".into(),
            "remove the trailing comma or write the missing number",
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all(src: &str) -> (Vec<Command>, Vec<Diagnostic>) {
        let mut r = Reader::new(src.as_bytes(), 1 << 20);
        let mut d = Vec::new();
        let mut v = Vec::new();
        while let Some(c) = r.next_command(&mut d) {
            v.push(c);
        }
        (v, d)
    }

    fn nums(c: &Command) -> Vec<f64> {
        c.numbers().unwrap()
    }

    #[test]
    fn terminators_and_blanks() {
        let (c, d) = all("IN;PU3580,8870;PD 1 , 2\n3,4\nPA-1.5,+.5 pu");
        assert!(d.is_empty(), "{d:?}");
        let names: Vec<&str> = c.iter().map(|c| c.name()).collect();
        assert_eq!(names, ["IN", "PU", "PD", "PA", "PU"]);
        assert_eq!(nums(&c[1]), [3580.0, 8870.0]);
        assert_eq!(nums(&c[2]), [1.0, 2.0, 3.0, 4.0]);
        assert_eq!(nums(&c[3]), [-1.5, 0.5]);
        assert_eq!(c[3].span.line, 3);
        assert_eq!(c[4].column, 12);
    }

    #[test]
    fn labels_hold_semicolons() {
        let (c, d) = all("LBa;b\u{3}PU1,2;DT#;LBxy#PD;");
        assert!(d.is_empty(), "{d:?}");
        assert_eq!(c[0].text, b"LBa;b");
        assert_eq!(nums(&c[1]), [1.0, 2.0]);
        assert_eq!(c[3].text, b"LBxy");
        assert_eq!(c[4].name(), "PD");
    }

    #[test]
    fn errors_have_columns() {
        let (c, d) = all("PA1,,2;PU1;\nPA 3.4.5,4;PD;\n 7 PU;");
        assert_eq!(
            c.iter().map(|c| c.name()).collect::<Vec<_>>(),
            ["PU", "PD", "PU"]
        );
        let at: Vec<(u32, u32)> = d
            .iter()
            .map(|d| {
                let l = d.location.as_ref().unwrap();
                (l.line, l.column)
            })
            .collect();
        assert_eq!(at, [(1, 5), (2, 4), (3, 2)]);
    }
}
