//! Lowering of CL statements to IR blocks, with the modal state of the CL program:
//! current point and tool axis, feed, units, `RAPID`, `MULTAX`, a pending `CIRCLE` and an
//! active drilling `CYCLE`.
//!
//! This module holds the state and sends each statement to its lowering by major word:
//! [`point`] for the statements that move or set the tool axis, [`command`] for feeds,
//! units and the machine commands, [`triplet`] for the lines of the triplet format.

mod args;
mod command;
mod frame;
mod point;
mod triplet;

use nalgebra::{Point3, Unit, Vector3};

use super::ast::{Arg, Statement as Syntax};
use super::motion::{Circle, MM_PER_INCH};
use super::options::{Options, Units};
use super::read::{self, major_words, syntax_error};
use super::source::{Probe, Statement};
use super::{arc, cycle, spline};
use crate::diag::Diagnostic;
use crate::ir::{
    AxisSet, Block, BlockKind, Command, Comment, CommentStyle, Feed, FeedMode, Span, Text,
};
use args::Args;
use point::Point;
use triplet::Triplet;

/// Statements that carry information for people or for other postprocessors only; they
/// pass through as comments without a warning.
const INFORMATIONAL: &[&str] = &[
    "TOOL PATH",
    "TLDATA",
    "PAINT",
    "END-OF-PATH",
    "CUTTER",
    "TRNTYP",
    "SELECT",
    "CLRSRF",
    "OPSKIP",
    "SEQNO",
    "MACHIN",
    "CLPRNT",
    "TPRINT",
    "DISPLY",
    "LEADER",
    "REWIND",
];

/// Statements whose argument is free text (`PPRINT any text, even / and ,`).
const TEXT_STATEMENTS: &[&str] = &["PARTNO", "PPRINT", "INSERT", "REMARK"];

/// Lines of an NX "Information listing" header or trailer: the key before a tab.
const LISTING_KEYS: &[&str] = &[
    "Information listing created by",
    "Date",
    "Current work part",
    "Node name",
];

/// Lines of an NX listing that start with these words.
const LISTING_PREFIXES: &[&str] = &[
    "Information listing created by",
    "Tool Path Listing has",
    "Listing created by",
];

/// Lowers statements, keeping the CL program's modal state.
pub(super) struct Lowerer {
    pub(super) options: Options,
    /// Millimetres per length unit of the input.
    scale: f64,
    /// Current tool tip, mm; `None` before the first point.
    pos: Option<Point3<f64>>,
    /// Current tool axis.
    axis: Unit<Vector3<f64>>,
    /// `MULTAX` as written: `None` when the program does not say.
    multax: Option<bool>,
    warned_multax: bool,
    warned_cutcom: bool,
    /// `RAPID` applies to the next motion.
    rapid_next: bool,
    feed: Feed,
    spindle_rpm: Option<f64>,
    spindle_ccw: bool,
    circle: Option<Circle>,
    cycle: cycle::State,
    /// The last statement was a `GOTO` (or a further point after one).
    after_goto: bool,
    /// An arc being cut into straight pieces.
    arc: Option<arc::Run>,
    args: Vec<Arg>,
    /// The major word(s) of the statement being lowered, upper-case (kept to reuse).
    major: String,
    /// Triplet format state, when the input is in it.
    triplet: Option<Triplet>,
    /// The applied NX `MSYS` (`msys = "apply"`).
    frame: Option<frame::Frame>,
    warned_msys: bool,
    /// The records of a NURBS being read.
    nurbs: Option<spline::Pending>,
    /// A NURBS being cut into pieces.
    spline: Option<spline::Run>,
}

fn comment(text: impl Into<String>) -> Comment {
    Comment {
        text: text.into(),
        style: CommentStyle::Semicolon,
    }
}

fn command(text: impl Into<Text>) -> BlockKind {
    BlockKind::Command(Command {
        text: text.into(),
        modes: None,
        clobbers: AxisSet::EMPTY,
    })
}

/// Whether `code` is a line of an NX information listing header or trailer.
fn is_listing_line(code: &str) -> bool {
    let starts = |p: &str| {
        code.get(..p.len())
            .is_some_and(|c| c.eq_ignore_ascii_case(p))
    };
    if LISTING_PREFIXES.iter().any(|p| starts(p)) {
        return true;
    }
    if let Some((key, _)) = code.split_once('\t')
        && LISTING_KEYS
            .iter()
            .any(|k| key.trim().eq_ignore_ascii_case(k))
    {
        return true;
    }
    code.len() >= 3 && code.bytes().all(|b| matches!(b, b'=' | b'-' | b'*' | b' '))
}

/// The leading word of `code` (letters, digits, `_`, `-`), upper-cased.
fn leading_word(code: &str) -> (usize, usize) {
    let start = code.len() - code.trim_start().len();
    let len = code[start..]
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == '-'))
        .unwrap_or(code.len() - start);
    (start, start + len)
}

impl Lowerer {
    pub(super) fn new(options: Options) -> Self {
        Lowerer {
            scale: match options.units {
                Units::Inch => MM_PER_INCH,
                _ => 1.0,
            },
            options,
            pos: None,
            axis: Vector3::z_axis(),
            multax: None,
            warned_multax: false,
            warned_cutcom: false,
            rapid_next: false,
            feed: Feed {
                mode: FeedMode::PerMinute,
                rate: None,
            },
            spindle_rpm: None,
            spindle_ccw: false,
            circle: None,
            cycle: cycle::State::Off,
            after_goto: false,
            arc: None,
            args: Vec::with_capacity(16),
            major: String::new(),
            triplet: None,
            frame: None,
            warned_msys: false,
            nurbs: None,
            spline: None,
        }
    }

    /// Takes what the look at the start of the input found: the format and, when the
    /// options leave it open, the length unit.
    pub(super) fn begin(&mut self, probe: Probe, diags: &mut Vec<Diagnostic>) {
        if probe.triplet {
            self.triplet = Some(Triplet::Point);
            return;
        }
        if self.options.units == Units::Auto
            && let Some((Some(true), line)) = probe.unit_clue
        {
            self.scale = MM_PER_INCH;
            diags.push(
                Diagnostic::warning(
                    "cl::units-inferred",
                    format!(
                        "the program does not name its length unit; lengths are read as \
                         inches because the feed on line {line} is given in inches"
                    ),
                )
                .at_span(Span {
                    offset: 0,
                    len: 0,
                    line,
                })
                .with_help(
                    "write UNITS/INCHES (or UNITS/MM) before the first point, or set the \
                     frontend option `units` to \"mm\" or \"inch\"",
                ),
            );
        }
    }

    /// Whether the input is in the triplet format (no `$` continuation).
    pub(super) fn is_triplet(&self) -> bool {
        self.triplet.is_some()
    }

    /// Whether an arc or a spline is being cut into pieces.
    pub(super) fn expanding(&self) -> bool {
        self.arc.is_some() || self.spline.is_some()
    }

    /// Appends up to `max` (at least one) pieces of the arc or spline being cut.
    pub(super) fn expand(&mut self, out: &mut Vec<Block>, max: usize) {
        if let Some(run) = &mut self.spline {
            run.emit(out, max.max(1));
            if run.done() {
                self.spline = None;
            }
            return;
        }
        if let Some(run) = &mut self.arc {
            run.emit(out, max.max(1));
            if run.done() {
                self.arc = None;
            }
        }
    }

    /// At the end of the input: a spline still being read is planned (its pieces are
    /// handed out by [`Lowerer::expand`]).
    pub(super) fn finish(&mut self, diags: &mut Vec<Diagnostic>) {
        self.end_spline(diags);
        if let Some(c) = self.circle.take() {
            diags.push(c.unused);
        }
        if let Some(Triplet::Axis { span, .. } | Triplet::Code { span, .. }) = self.triplet {
            diags.push(
                Diagnostic::error(
                    "cl::triplet",
                    "the input ends inside a triplet (point, tool axis, motion code)",
                )
                .at_span(span)
                .with_help("every point line needs a tool axis line and a motion code line"),
            );
        }
    }

    /// Lowers one statement, appending its blocks to `out`.
    pub(super) fn statement(
        &mut self,
        stmt: &Statement,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let first = out.len();
        if stmt.open_at_end {
            diags.push(
                stmt.locate_all(Diagnostic::warning(
                    "cl::open-continuation",
                    "the last statement ends with `$` but no line follows",
                ))
                .with_help("remove the `$` at the end of the last line"),
            );
        }
        let started_arc = self.arc.is_none();
        if self.triplet.is_some() {
            self.triplet_line(stmt, out, diags);
        } else {
            self.lower(stmt, out, diags);
        }
        let comments = stmt.comments.iter().map(|c| comment(c.as_str()));
        if out.len() > first {
            let c = &mut out[first].comments;
            c.splice(0..0, comments);
        } else if started_arc && let Some(run) = &mut self.arc {
            run.comments.extend(comments);
        } else if !stmt.comments.is_empty() {
            let mut b = Block::new(stmt.span, BlockKind::Comment);
            b.comments.extend(comments);
            out.push(b);
        }
    }

    fn pass_through(&self, stmt: &Statement, out: &mut Vec<Block>) {
        let text = stmt.code.trim();
        if text.is_empty() {
            return;
        }
        let mut b = Block::new(stmt.span, BlockKind::Comment);
        b.comments.push(comment(format!(" {text}")));
        out.push(b);
    }

    fn lower(&mut self, stmt: &Statement, out: &mut Vec<Block>, diags: &mut Vec<Diagnostic>) {
        let code = stmt.code.as_str();
        if code.trim().is_empty() {
            return;
        }
        if is_listing_line(code.trim()) {
            self.pass_through(stmt, out);
            return;
        }
        let (ws, we) = leading_word(code);
        let word = &code[ws..we];
        if let Some(t) = TEXT_STATEMENTS
            .iter()
            .find(|t| word.eq_ignore_ascii_case(t))
        {
            let rest = code[we..].trim_start();
            let rest = rest.strip_prefix('/').unwrap_or(rest).trim();
            let text = if *t == "PPRINT" || *t == "REMARK" {
                format!(" {rest}")
            } else {
                format!(" {}", code.trim())
            };
            let mut b = Block::new(stmt.span, BlockKind::Comment);
            b.comments.push(comment(text));
            out.push(b);
            self.after_goto = false;
            return;
        }

        let mut args = std::mem::take(&mut self.args);
        let result = match read::statement(code, &mut args) {
            Ok(syntax) => self.dispatch(stmt, syntax, &args, out, diags),
            Err(err) => {
                let major = major_words(code);
                if known_major(&major) {
                    Err(syntax_error(stmt, err))
                } else {
                    Err(unknown(stmt, &major, ws, we))
                }
            }
        };
        self.args = args;
        if let Err(d) = result {
            let keep = !d.is_error();
            if keep {
                self.pass_through(stmt, out);
            }
            diags.push(d);
        }
    }

    fn dispatch(
        &mut self,
        stmt: &Statement,
        syntax: Syntax,
        args: &[Arg],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let a = Args { stmt, list: args };
        let Some((ms, me)) = syntax.major else {
            // A line of bare numbers: a further point after GOTO (Creo point lists).
            if self.after_goto {
                return self.goto(stmt, &a, Point::Absolute, "GOTO", out, diags);
            }
            return Err(a.error_all(
                Diagnostic::error("cl::no-statement", "numbers without a statement word")
                    .with_label("no major word")
                    .with_help("write the statement word first, e.g. GOTO/x,y,z"),
            ));
        };
        let mut major = std::mem::take(&mut self.major);
        normalise_major(&stmt.code[ms..me], &mut major);
        let result = self.by_major(&major, (ms, me), &a, out, diags);
        self.major = major;
        result
    }

    /// Lowers the statement whose major word(s) `major` are at `ms..me` of its code.
    fn by_major(
        &mut self,
        major: &str,
        (ms, me): (usize, usize),
        a: &Args<'_>,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let stmt = a.stmt;
        let was_after_goto = std::mem::replace(&mut self.after_goto, false);
        match major {
            "GOTO" => {
                self.goto(stmt, a, Point::Absolute, "GOTO", out, diags)?;
                self.after_goto = true;
                Ok(())
            }
            "FROM" => self.goto(stmt, a, Point::Start, "FROM", out, diags),
            "GODLTA" => self.goto(stmt, a, Point::Delta, "GODLTA", out, diags),
            "RAPID" => {
                self.rapid_next = true;
                Ok(())
            }
            "FEDRAT" => self.fedrat(a),
            "CIRCLE" | "MOVARC" => self.circle(stmt, a, major, diags),
            "TLAXIS" => self.tlaxis(a),
            "MULTAX" => self.multax(a),
            "UNITS" | "UNIT" => self.units(a, major),
            "INCHES" => {
                self.scale = MM_PER_INCH;
                Ok(())
            }
            "METRIC" => {
                self.scale = 1.0;
                Ok(())
            }
            "SPINDL" => self.spindle(stmt, a, out),
            "COOLNT" => self.coolant(stmt, a, out),
            "LOADTL" => self.load_tool(stmt, a, 0, out),
            "LOAD" => match a.list.first().and_then(|x| a.word(x)).as_deref() {
                Some("TOOL") => self.load_tool(stmt, a, 1, out),
                _ => Err(unknown(stmt, "LOAD", ms, me)),
            },
            "DELAY" => self.delay(stmt, a, out),
            "END" => {
                self.stop(stmt, self.options.end_command.clone(), out);
                Ok(())
            }
            "FINI" => {
                self.stop(stmt, self.options.fini_command.clone(), out);
                Ok(())
            }
            "STOP" => {
                self.stop(stmt, "M0".into(), out);
                Ok(())
            }
            "OPSTOP" => {
                self.stop(stmt, "M1".into(), out);
                Ok(())
            }
            "CYCLE" => self.cycle(a),
            "CSYS" => {
                self.pass_through(stmt, out);
                self.csys(a, out, diags);
                Ok(())
            }
            "MSYS" => {
                self.pass_through(stmt, out);
                self.msys(a, out, diags)
            }
            "NURBS" | "KNOT" | "CNTRL" => self.nurbs_record(major, a),
            "CUTCOM" => {
                self.pass_through(stmt, out);
                self.cutcom(a, diags);
                Ok(())
            }
            m if INFORMATIONAL.contains(&m) => {
                self.after_goto = was_after_goto && m == "PAINT";
                self.pass_through(stmt, out);
                Ok(())
            }
            m => Err(unknown(stmt, m, ms, me)),
        }
    }
}

/// The major word(s) `text` into `out`: upper-case, single spaces.
fn normalise_major(text: &str, out: &mut String) {
    out.clear();
    for w in text.split_ascii_whitespace() {
        if !out.is_empty() {
            out.push(' ');
        }
        out.extend(w.chars().map(|c| c.to_ascii_uppercase()));
    }
}

fn known_major(major: &str) -> bool {
    matches!(
        major,
        "GOTO"
            | "FROM"
            | "GODLTA"
            | "RAPID"
            | "FEDRAT"
            | "CIRCLE"
            | "MOVARC"
            | "TLAXIS"
            | "MULTAX"
            | "UNITS"
            | "UNIT"
            | "INCHES"
            | "METRIC"
            | "SPINDL"
            | "COOLNT"
            | "LOADTL"
            | "LOAD"
            | "DELAY"
            | "END"
            | "FINI"
            | "STOP"
            | "OPSTOP"
            | "CYCLE"
            | "CSYS"
            | "MSYS"
            | "NURBS"
            | "KNOT"
            | "CNTRL"
            | "CUTCOM"
    ) || INFORMATIONAL.contains(&major)
}

fn unknown(stmt: &Statement, major: &str, start: usize, end: usize) -> Diagnostic {
    let shown = if major.is_empty() {
        stmt.code.trim().chars().take(20).collect::<String>()
    } else {
        crate::num::range::shown(major).into_owned()
    };
    stmt.locate(
        Diagnostic::warning(
            "cl::unknown-statement",
            format!("`{shown}` is not a CL statement ncpost knows"),
        )
        .with_label("unknown statement")
        .with_help("passed through as a comment"),
        start,
        end.max(start + 1),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listing_lines() {
        assert!(is_listing_line("Information listing created by\tphill"));
        assert!(is_listing_line("Date\t18-Dec-2021 21:07:42"));
        assert!(is_listing_line("Tool Path Listing has 11294 lines."));
        assert!(is_listing_line("=========="));
        assert!(!is_listing_line("GOTO/1,2,3"));
    }
}
