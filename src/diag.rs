//! The one diagnostic type, its builder methods and its renderings (miette graphical,
//! plain text, JSON).

mod flood;

use std::fmt;

use crate::ir::Span;
pub use flood::{DEFAULT_LIMIT, Flood, Tally, Worst};

/// How bad a diagnostic is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Severity {
    /// A report (statistics, summaries); never a problem.
    Note,
    /// Information the user should see; the run goes on.
    Warning,
    /// The input is wrong; the run fails with exit code 1 and writes no output.
    Error,
}

impl Severity {
    /// `note`, `warning` or `error`.
    pub fn name(self) -> &'static str {
        match self {
            Severity::Note => "note",
            Severity::Warning => "warning",
            Severity::Error => "error",
        }
    }
}

/// What a diagnostic is about, for the code that acts on it; the `code` string is for
/// people and may be more precise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Kind {
    /// The program being compiled: a line, a move, a value.
    #[default]
    Program,
    /// The run's settings: a preset, a machine definition, a pass's options, a
    /// command-line value. Shown without a source line.
    Settings,
    /// Reading the input or writing the output failed; the output is lost.
    Io,
}

/// Where in the source a diagnostic points.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// 1-based line number.
    pub line: u32,
    /// 1-based column, in characters.
    pub column: u32,
    /// Length of the marked text, in characters (at least 1).
    pub len: u32,
    /// The source line, for the snippet: cut to a readable length around the mark, with
    /// control characters shown as U+FFFD.
    pub source_line: String,
    /// Characters cut from the start of the line in `source_line`.
    pub cut: u32,
}

/// A message about the input, with its place, a label for the marked text and help.
///
/// ```
/// use ncpost::diag::{Diagnostic, Severity};
/// let d = Diagnostic::error("gcode::bad-word", "letter without a number")
///     .at_line(3, "G1 X Y10", 4, 1)
///     .with_label("`X` needs a value")
///     .with_help("write X0 or remove the letter");
/// assert_eq!(d.severity, Severity::Error);
/// assert_eq!(d.location.as_ref().unwrap().column, 4);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostic {
    /// Error or warning.
    pub severity: Severity,
    /// What it is about (program, settings, I/O).
    pub kind: Kind,
    /// Stable code, `area::kind`.
    pub code: &'static str,
    /// One-line message.
    pub message: String,
    /// Place in the source, when there is one (boxed: diagnostics travel in `Result`s).
    pub location: Option<Box<Location>>,
    /// Text under the marked span.
    pub label: Option<String>,
    /// What to do about it.
    pub help: Option<String>,
    /// How far off this case is, in the diagnostic's own unit (mm past a limit, degrees
    /// of tilt): among many of one code, the largest is named in their summary. Always
    /// finite; single precision is plenty to rank by and keeps diagnostics small (they
    /// travel in `Result`s).
    pub magnitude: Option<f32>,
    /// For a summary of repeated diagnostics (and, on their way, for the one that stands
    /// for the hidden ones of a batch): how many it stands for, where and the worst. See
    /// [`Flood`].
    pub repeats: Option<Box<Tally>>,
    /// This diagnostic sums others up (a pass's report at the end of the run, a flood
    /// summary): it is never hidden by the cap on repeated diagnostics.
    pub sums_up: bool,
}

// Magnitudes are finite (see `with_magnitude`), so equality is an equivalence.
impl Eq for Diagnostic {}

/// Longest source line kept in a diagnostic; longer lines are cut around the mark.
const SNIPPET_MAX: usize = 160;

impl Diagnostic {
    /// A new error.
    pub fn error(code: &'static str, message: impl Into<String>) -> Self {
        Self::new(Severity::Error, code, message)
    }

    /// A new note (a report, not a problem).
    pub fn note(code: &'static str, message: impl Into<String>) -> Self {
        Self::new(Severity::Note, code, message)
    }

    /// A new warning.
    pub fn warning(code: &'static str, message: impl Into<String>) -> Self {
        Self::new(Severity::Warning, code, message)
    }

    /// An error in the run's settings (preset, machine, pass options), with the code
    /// `pipeline::config`.
    ///
    /// ```
    /// use ncpost::diag::{Diagnostic, Kind};
    /// let d = Diagnostic::settings("unknown pass `foo`");
    /// assert_eq!((d.kind, d.code), (Kind::Settings, "pipeline::config"));
    /// ```
    pub fn settings(message: impl Into<String>) -> Self {
        Self::new(Severity::Error, "pipeline::config", message).of_kind(Kind::Settings)
    }

    /// An error reading the input or writing the output (`io::read`, `io::write`).
    pub fn io(code: &'static str, message: impl Into<String>) -> Self {
        Self::new(Severity::Error, code, message).of_kind(Kind::Io)
    }

    /// Sets what the diagnostic is about.
    pub fn of_kind(mut self, kind: Kind) -> Self {
        self.kind = kind;
        self
    }

    fn new(severity: Severity, code: &'static str, message: impl Into<String>) -> Self {
        Diagnostic {
            severity,
            kind: Kind::Program,
            code,
            message: message.into(),
            location: None,
            label: None,
            help: None,
            magnitude: None,
            repeats: None,
            sums_up: false,
        }
    }

    /// Sets how far off this case is (ignored unless finite; beyond single precision it
    /// is kept as the largest such number), for naming the worst of many.
    ///
    /// ```
    /// use ncpost::diag::Diagnostic;
    /// let d = Diagnostic::warning("polar::reach", "out of reach by 2 mm").with_magnitude(2.0);
    /// assert_eq!(d.magnitude, Some(2.0));
    /// assert_eq!(Diagnostic::warning("a::b", "c").with_magnitude(f64::NAN).magnitude, None);
    /// ```
    pub fn with_magnitude(mut self, magnitude: f64) -> Self {
        self.magnitude = magnitude
            .is_finite()
            .then_some(magnitude.clamp(f64::from(f32::MIN), f64::from(f32::MAX)) as f32);
        self
    }

    /// Points at `len` characters from 1-based `column` of line `line` whose text is
    /// `source_line`.
    pub fn at_line(mut self, line: u32, source_line: &str, column: u32, len: u32) -> Self {
        let column = column.max(1);
        let (text, cut) = snippet(source_line, column as usize);
        self.location = Some(Box::new(Location {
            line,
            column,
            len: len.max(1),
            source_line: text,
            cut: cut as u32,
        }));
        self
    }

    /// Points at a byte range `start..end` of `source_line` (line number `line`).
    pub fn at_bytes(self, line: u32, source_line: &str, start: usize, end: usize) -> Self {
        let start = floor_char(source_line, start.min(source_line.len()));
        let end = floor_char(source_line, end.clamp(start, source_line.len()));
        let column = source_line[..start].chars().count() as u32 + 1;
        let len = source_line[start..end].chars().count() as u32;
        self.at_line(line, source_line, column, len)
    }

    /// Points at a whole block's line (column 1), without a snippet.
    pub fn at_span(mut self, span: Span) -> Self {
        self.location = Some(Box::new(Location {
            line: span.line,
            column: 1,
            len: 1,
            source_line: String::new(),
            cut: 0,
        }));
        self
    }

    /// Sets the label under the marked text.
    pub fn with_label(mut self, label: impl Into<String>) -> Self {
        self.label = Some(label.into());
        self
    }

    /// Sets the help text.
    pub fn with_help(mut self, help: impl Into<String>) -> Self {
        self.help = Some(help.into());
        self
    }

    /// Whether this is an error.
    pub fn is_error(&self) -> bool {
        self.severity == Severity::Error
    }

    /// Renders as text: graphical with colour when `fancy`, otherwise plain ASCII without
    /// colour at width 80 (the form snapshots use). `file` names the input.
    pub fn render(&self, file: &str, fancy: bool) -> String {
        use miette::{GraphicalReportHandler, GraphicalTheme};
        let theme = if fancy {
            GraphicalTheme::unicode()
        } else {
            // Plain text says what it is in words.
            let mut t = GraphicalTheme::none();
            t.characters.error = "error:".into();
            t.characters.warning = "warning:".into();
            t.characters.advice = "note:".into();
            t
        };
        let handler = GraphicalReportHandler::new_themed(theme)
            .with_width(80)
            .with_links(false);
        let report = Report { diag: self, file };
        let mut out = String::new();
        if handler.render_report(&mut out, &report).is_err() {
            out = self.to_string();
        }
        out
    }

    /// One JSON object (no trailing newline), for `--message-format json`.
    pub fn to_json(&self, file: &str) -> String {
        let loc = self.location.as_ref();
        let mut value = serde_json::json!({
            "severity": self.severity.name(),
            "code": self.code,
            "message": self.message,
            "file": file,
            "line": loc.map(|l| l.line),
            "column": loc.map(|l| l.column),
            "label": self.label,
            "help": self.help,
        });
        // A summary of repeated diagnostics says what it stands for.
        if let (Some(t), Some(map)) = (&self.repeats, value.as_object_mut()) {
            map.insert(
                "repeats".into(),
                serde_json::json!({
                    "count": t.count,
                    "lines": t.lines,
                    "first_line": t.line_range.map(|r| r.0),
                    "last_line": t.line_range.map(|r| r.1),
                    "worst": t.worst.as_ref().map(|w| serde_json::json!({
                        "magnitude": w.magnitude,
                        "line": w.line,
                        "message": w.message,
                    })),
                }),
            );
        }
        value.to_string()
    }
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}[{}]", self.severity.name(), self.code)?;
        if let Some(l) = &self.location {
            write!(f, " line {}:{}", l.line, l.column)?;
        }
        write!(f, ": {}", self.message)?;
        if let Some(h) = &self.help {
            write!(f, " (help: {h})")?;
        }
        Ok(())
    }
}

impl std::error::Error for Diagnostic {}

fn floor_char(s: &str, mut i: usize) -> usize {
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// Cuts a long line to a window around `column`; returns the text and the number of
/// characters cut from its start. Control characters become U+FFFD so a snippet never
/// drives the terminal.
fn snippet(line: &str, column: usize) -> (String, usize) {
    let count = line.chars().count();
    let start = if count <= SNIPPET_MAX {
        0
    } else {
        column
            .saturating_sub(SNIPPET_MAX / 2)
            .min(count - SNIPPET_MAX)
    };
    let text: String = line
        .chars()
        .skip(start)
        .take(SNIPPET_MAX)
        .map(|c| {
            if c.is_control() && c != '\t' {
                '\u{fffd}'
            } else {
                c
            }
        })
        .collect();
    (text, start)
}

/// Adapter that lets miette draw one diagnostic with its one-line snippet.
struct Report<'a> {
    diag: &'a Diagnostic,
    file: &'a str,
}

impl fmt::Debug for Report<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.diag, f)
    }
}

impl fmt::Display for Report<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.diag.message)?;
        if let Some(l) = &self.diag.location
            && l.source_line.is_empty()
        {
            write!(f, " ({}:{})", self.file, l.line)?;
        }
        Ok(())
    }
}

impl std::error::Error for Report<'_> {}

impl miette::Diagnostic for Report<'_> {
    fn code<'b>(&'b self) -> Option<Box<dyn fmt::Display + 'b>> {
        Some(Box::new(self.diag.code))
    }

    fn severity(&self) -> Option<miette::Severity> {
        Some(match self.diag.severity {
            Severity::Error => miette::Severity::Error,
            Severity::Warning => miette::Severity::Warning,
            Severity::Note => miette::Severity::Advice,
        })
    }

    fn help<'b>(&'b self) -> Option<Box<dyn fmt::Display + 'b>> {
        self.diag
            .help
            .as_ref()
            .map(|h| Box::new(h) as Box<dyn fmt::Display>)
    }

    fn source_code(&self) -> Option<&dyn miette::SourceCode> {
        match &self.diag.location {
            Some(l) if !l.source_line.is_empty() => Some(self as &dyn miette::SourceCode),
            _ => None,
        }
    }

    fn labels(&self) -> Option<Box<dyn Iterator<Item = miette::LabeledSpan> + '_>> {
        let l = self.diag.location.as_ref()?;
        if l.source_line.is_empty() {
            return None;
        }
        let column = (l.column - l.cut) as usize;
        let start = char_to_byte(&l.source_line, column - 1);
        let end = char_to_byte(&l.source_line, column + l.len as usize - 1);
        let span =
            miette::LabeledSpan::new(self.diag.label.clone(), start, end.saturating_sub(start));
        Some(Box::new(std::iter::once(span)))
    }
}

fn char_to_byte(s: &str, chars: usize) -> usize {
    s.char_indices().nth(chars).map_or(s.len(), |(i, _)| i)
}

impl miette::SourceCode for Report<'_> {
    fn read_span<'b>(
        &'b self,
        span: &miette::SourceSpan,
        _context_lines_before: usize,
        _context_lines_after: usize,
    ) -> Result<Box<dyn miette::SpanContents<'b> + 'b>, miette::MietteError> {
        let l = self
            .diag
            .location
            .as_ref()
            .ok_or(miette::MietteError::OutOfBounds)?;
        if span.offset() > l.source_line.len() {
            return Err(miette::MietteError::OutOfBounds);
        }
        // The column is that of the requested span in the whole line: miette prints it in
        // the `[file:line:column]` header.
        let offset = floor_char(&l.source_line, span.offset());
        let column = l.source_line[..offset].chars().count() + l.cut as usize;
        Ok(Box::new(miette::MietteSpanContents::new_named(
            self.file.to_string(),
            l.source_line.as_bytes(),
            (0, l.source_line.len()).into(),
            l.line.saturating_sub(1) as usize,
            column,
            1,
        )))
    }
}
