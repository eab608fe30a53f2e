//! Lowering of CL statements to IR blocks, with the modal state of the CL program:
//! current point and tool axis, feed, units, `RAPID`, `MULTAX`, a pending `CIRCLE` and an
//! active drilling `CYCLE`.

use nalgebra::{Point3, Unit, Vector3};

use super::ast::{Arg, ArgKind, Statement as Syntax};
use super::lexer::Tok;
use super::source::{Probe, Statement};
use super::{Options, Units, arc, cycle, scan};
use crate::diag::Diagnostic;
use crate::ir::{
    AxisSet, Block, BlockKind, Command, Comment, CommentStyle, Feed, FeedMode, Motion, MotionKind,
    Pose, Span, Target, Text,
};

pub(super) const MM_PER_INCH: f64 = 25.4;

/// Statements that carry information for people or for other postprocessors only; they
/// pass through as comments without a warning.
const INFORMATIONAL: &[&str] = &[
    "TOOL PATH",
    "TLDATA",
    "MSYS",
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

/// A `CIRCLE` or `MOVARC` waiting for the motion that ends it.
#[derive(Debug, Clone)]
pub(super) struct Circle {
    /// Centre, mm.
    pub centre: Point3<f64>,
    /// The arc runs counter-clockwise about this axis (right-hand rule).
    pub normal: Unit<Vector3<f64>>,
    /// Radius, mm, when the statement gives one.
    pub radius: Option<f64>,
    /// Full turns written with `TIMES`.
    pub turns: Option<u32>,
    /// Whole sweep in degrees written with `ANGLE`.
    pub angle: Option<f64>,
    /// The statement's first line.
    pub line: u32,
    /// The warning for a CIRCLE that no GOTO ends, pointing at it.
    pub unused: Diagnostic,
}

/// State of the triplet format: what the next line is.
#[derive(Debug, Clone, Copy)]
enum Triplet {
    Point,
    Axis {
        point: Point3<f64>,
        span: Span,
    },
    Code {
        point: Point3<f64>,
        axis: Unit<Vector3<f64>>,
        span: Span,
    },
}

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
    /// Triplet format state, when the input is in it.
    triplet: Option<Triplet>,
    /// The plain `GOTO/` lines [`Lowerer::plain_gotos`] has read and not yet lowered.
    ahead: Box<[Ahead; READ_AHEAD]>,
}

/// How many plain `GOTO/` lines [`Lowerer::plain_gotos`] reads before it lowers them.
const READ_AHEAD: usize = 32;

/// A plain `GOTO/` line read ahead: its values, then its pose.
#[derive(Debug, Clone, Copy, Default)]
struct Ahead {
    v: [f64; 6],
    n: usize,
    span: Span,
    /// Where the line's `\n` ends in the chunk.
    end: usize,
    /// The tip, then the axis.
    pose: [f64; 6],
}

/// The numbers and words of a statement's arguments.
struct Args<'a> {
    stmt: &'a Statement,
    list: &'a [Arg],
}

impl<'a> Args<'a> {
    fn text(&self, a: &Arg) -> &'a str {
        &self.stmt.code[a.start..a.end]
    }

    /// The argument as a number, or an error pointing at it.
    fn number(&self, a: &Arg) -> Result<f64, Diagnostic> {
        let text = self.text(a);
        if a.kind != ArgKind::Number {
            return Err(self.stmt.locate(
                Diagnostic::error(
                    "cl::bad-number",
                    format!("expected a number, found `{text}`"),
                )
                .with_label("not a number")
                .with_help("write a decimal number such as `12.5`, `-.5` or `1.E-3`"),
                a.start,
                a.end,
            ));
        }
        match crate::num::parse_decimal(text) {
            Some(v) if v.is_finite() => Ok(v),
            _ => Err(self.stmt.locate(
                Diagnostic::error("cl::bad-number", format!("`{text}` is out of range"))
                    .with_label("too large")
                    .with_help("CL values must be finite numbers"),
                a.start,
                a.end,
            )),
        }
    }

    /// Every argument as a number.
    fn numbers(&self) -> Result<Vec<f64>, Diagnostic> {
        self.list.iter().map(|a| self.number(a)).collect()
    }

    /// The argument as an upper-case word, if it is one.
    fn word(&self, a: &Arg) -> Option<String> {
        (a.kind == ArgKind::Word).then(|| self.text(a).to_ascii_uppercase())
    }

    /// The byte range of all arguments (or of the statement when it has none).
    fn range(&self) -> (usize, usize) {
        match (self.list.first(), self.list.last()) {
            (Some(f), Some(l)) => (f.start, l.end),
            _ => (0, self.stmt.code.trim_end().len()),
        }
    }

    fn error_all(&self, d: Diagnostic) -> Diagnostic {
        let (s, e) = self.range();
        self.stmt.locate(d, s, e)
    }

    /// An error when the count of arguments is not in `counts`.
    fn arity(&self, major: &str, counts: &[usize], what: &str) -> Result<(), Diagnostic> {
        if counts.contains(&self.list.len()) {
            return Ok(());
        }
        Err(self.error_all(
            Diagnostic::error(
                "cl::arity",
                format!(
                    "{major} takes {what}, found {} value{}",
                    self.list.len(),
                    if self.list.len() == 1 { "" } else { "s" }
                ),
            )
            .with_label("here")
            .with_help(format!("write {major}/{what}")),
        ))
    }
}

/// The unit vector along `v`, or `None` for a zero (or not finite) vector.
///
/// `v` is scaled by its largest magnitude `m` first, so no square overflows or
/// underflows, then divided by its norm: [`Unit::new_normalize`]'s steps. With `m` finite
/// every scaled component that is a number lies in [-1, 1] and one is ±1, so the norm
/// lies in [1, √3] and every quotient is finite, unless a component is NaN (the maximum
/// passes over a NaN first component): then the norm is NaN. Testing the norm is testing
/// the three quotients.
pub(super) fn unit(v: Vector3<f64>) -> Option<Unit<Vector3<f64>>> {
    let m = v.amax();
    if !(m.is_finite() && m > 1e-12) {
        return None;
    }
    let mut u = v / m;
    let n = u.norm();
    if n.is_nan() {
        return None;
    }
    u.unscale_mut(n);
    Some(Unit::new_unchecked(u))
}

/// The tip and axis of a plain `GOTO/` with the `n` values `v`, the axis in force being
/// `axis` and the length unit `scale` mm; `None` when the grammar path must read it: a
/// wrong count, a zero axis, a point out of range.
#[inline(always)]
fn plain_pose(
    v: &[f64; 6],
    n: usize,
    axis: Unit<Vector3<f64>>,
    scale: f64,
) -> Option<(Point3<f64>, Unit<Vector3<f64>>)> {
    let axis = match n {
        3 => axis,
        6 => unit(Vector3::new(v[3], v[4], v[5]))?,
        _ => return None,
    };
    let tip = Point3::new(v[0], v[1], v[2]) * scale;
    // `c * 0.0` is ±0 for a finite `c` and NaN for the others: one test for all three,
    // without a branch per coordinate.
    (tip.x * 0.0 + tip.y * 0.0 + tip.z * 0.0 == 0.0).then_some((tip, axis))
}

/// A number as a G-code word value: at most 4 decimals, no trailing zeros.
pub(super) fn format_number(v: f64) -> String {
    let mut s = format!("{v:.4}");
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    if s == "-0" { "0".to_string() } else { s }
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

/// A motion block to a pose.
pub(super) fn motion_block(
    span: Span,
    kind: MotionKind,
    tip: Point3<f64>,
    axis: Unit<Vector3<f64>>,
    feed: Feed,
) -> Block {
    Block::new(
        span,
        BlockKind::Motion(Motion {
            kind,
            target: Target::Pose(Pose::new(tip, axis)),
            feed,
            written: AxisSet::XYZ,
            machine_frame: false,
            extra: String::new(),
        }),
    )
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
            triplet: None,
            ahead: Box::new([Ahead::default(); READ_AHEAD]),
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

    /// Whether an arc is being cut into pieces.
    pub(super) fn expanding(&self) -> bool {
        self.arc.is_some()
    }

    /// Appends up to `max` (at least one) pieces of the arc being cut.
    pub(super) fn expand(&mut self, out: &mut Vec<Block>, max: usize) {
        if let Some(run) = &mut self.arc {
            run.emit(out, max.max(1));
            if run.done() {
                self.arc = None;
            }
        }
    }

    /// At the end of the input.
    pub(super) fn finish(&mut self, diags: &mut Vec<Diagnostic>) {
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
        if self.plain_goto(code.as_bytes(), stmt.span, out) {
            return;
        }
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
        args.clear();
        let parsed = super::grammar::StatementParser::new()
            .parse(&mut args, lex_iter(code).map(Ok::<_, ()>));
        let result = match parsed {
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

    /// Lowers the commonest statement, a plain `GOTO/x,y,z[,i,j,k]` with no arc, cycle or
    /// MULTAX/OFF in force, without the grammar: most lines of a 5-axis file are this.
    /// Returns false for anything else, which then takes the full path (and gets its
    /// diagnostics there); both paths give the same block. It refuses blank lines, every
    /// line with a `$` (a value list holds none) and every byte that is not ASCII.
    pub(super) fn plain_goto(&mut self, code: &[u8], span: Span, out: &mut Vec<Block>) -> bool {
        if !self.plain_gotos_allowed() {
            return false;
        }
        let mut v = [0.0f64; 6];
        match scan::goto::<false>(code, &mut v) {
            Some((n, _)) => self.goto_values(&v, n, span, out),
            None => false,
        }
    }

    /// [`Lowerer::plain_goto`] on the lines at the start of buffered input: `chunk` holds
    /// whole lines, each ended by `\n`, then whatever follows; the first starts at byte
    /// `offset` of the input and is line `line + 1`. Lowers lines until one is not a plain
    /// `GOTO/` (or is over the line limit, or is not whole in `chunk`) or `out` holds
    /// `want` blocks; returns the bytes and the lines taken. Reading the lines from the
    /// buffer saves finding each line's end first: the reader finds it.
    ///
    /// The lines go in three steps of up to [`READ_AHEAD`] lines each: their values, then
    /// their poses, then their blocks. A line's reading no longer waits behind the
    /// divisions of the line before (the number's, then the axis's), and `Vec::extend`
    /// writes the blocks where they go in `out`: `push` built each on the stack and
    /// copied it (224 bytes, a `memcpy`).
    pub(super) fn plain_gotos(
        &mut self,
        chunk: &[u8],
        (offset, line): (u64, u32),
        out: &mut Vec<Block>,
        want: usize,
    ) -> (usize, u32) {
        let mut taken = 0;
        let mut lines = 0u32;
        if !self.plain_gotos_allowed() {
            return (0, 0);
        }
        while out.len() < want {
            // Values: nothing changes yet.
            let room = (want - out.len()).min(READ_AHEAD);
            let mut read = 0;
            let mut at = taken;
            let mut whole = true;
            while read < room {
                let a = &mut self.ahead[read];
                let Some(rest) = chunk.get(at..) else {
                    whole = false;
                    break;
                };
                let Some((n, newline)) = scan::goto::<true>(rest, &mut a.v) else {
                    whole = false;
                    break;
                };
                let content = crate::front::content_len(rest, newline);
                if content > self.options.max_line_len {
                    whole = false;
                    break;
                }
                a.n = n;
                a.span = Span {
                    offset: offset + at as u64,
                    len: content as u32,
                    line: line + lines + read as u32 + 1,
                };
                at += newline + 1;
                a.end = at;
                read += 1;
            }
            // Poses, until a line needs the grammar path.
            let mut axis = self.axis;
            let mut posed = 0usize;
            for a in &mut self.ahead[..read] {
                let Some((tip, to)) = plain_pose(&a.v, a.n, axis, self.scale) else {
                    break;
                };
                a.pose = [tip.x, tip.y, tip.z, to.x, to.y, to.z];
                axis = to;
                posed += 1;
            }
            let Some(last) = posed.checked_sub(1).map(|i| self.ahead[i]) else {
                break;
            };
            // Blocks.
            let first = if std::mem::replace(&mut self.rapid_next, false) {
                MotionKind::Rapid
            } else {
                MotionKind::Linear
            };
            let feed = self.feed;
            out.extend(self.ahead[..posed].iter().enumerate().map(|(i, a)| {
                let kind = if i == 0 { first } else { MotionKind::Linear };
                let [x, y, z, i, j, k] = a.pose;
                let tip = Point3::new(x, y, z);
                let axis = Unit::new_unchecked(Vector3::new(i, j, k));
                motion_block(a.span, kind, tip, axis, feed)
            }));
            self.axis = axis;
            self.pos = Some(Point3::new(last.pose[0], last.pose[1], last.pose[2]));
            self.after_goto = true;
            taken = last.end;
            lines += posed as u32;
            if !whole || posed < read {
                break;
            }
        }
        (taken, lines)
    }

    /// No arc, cycle or MULTAX/OFF is in force: a plain `GOTO/` is a move to its point.
    fn plain_gotos_allowed(&self) -> bool {
        self.circle.is_none() && self.multax != Some(false) && self.cycle.active().is_none()
    }

    /// The block of a plain `GOTO/` with the `n` values `v`; false (and nothing changed)
    /// when the grammar path must read it: a wrong count, a zero axis, a point out of range.
    #[inline(always)]
    fn goto_values(&mut self, v: &[f64; 6], n: usize, span: Span, out: &mut Vec<Block>) -> bool {
        let Some((tip, axis)) = plain_pose(v, n, self.axis, self.scale) else {
            return false;
        };
        self.axis = axis;
        let kind = if std::mem::replace(&mut self.rapid_next, false) {
            MotionKind::Rapid
        } else {
            MotionKind::Linear
        };
        out.push(motion_block(span, kind, tip, axis, self.feed));
        self.pos = Some(tip);
        self.after_goto = true;
        true
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
        let major = normalise_major(&stmt.code[ms..me]);
        let was_after_goto = std::mem::replace(&mut self.after_goto, false);
        match major.as_str() {
            "GOTO" => {
                self.goto(stmt, &a, Point::Absolute, "GOTO", out, diags)?;
                self.after_goto = true;
                Ok(())
            }
            "FROM" => self.goto(stmt, &a, Point::Start, "FROM", out, diags),
            "GODLTA" => self.goto(stmt, &a, Point::Delta, "GODLTA", out, diags),
            "RAPID" => {
                self.rapid_next = true;
                Ok(())
            }
            "FEDRAT" => self.fedrat(&a),
            "CIRCLE" | "MOVARC" => self.circle(stmt, &a, &major, diags),
            "TLAXIS" => self.tlaxis(&a),
            "MULTAX" => self.multax(&a),
            "UNITS" | "UNIT" => self.units(&a, &major),
            "INCHES" => {
                self.scale = MM_PER_INCH;
                Ok(())
            }
            "METRIC" => {
                self.scale = 1.0;
                Ok(())
            }
            "SPINDL" => self.spindle(stmt, &a, out),
            "COOLNT" => self.coolant(stmt, &a, out),
            "LOADTL" => self.load_tool(stmt, &a, 0, out),
            "LOAD" => match a.list.first().and_then(|x| a.word(x)).as_deref() {
                Some("TOOL") => self.load_tool(stmt, &a, 1, out),
                _ => Err(unknown(stmt, "LOAD", ms, me)),
            },
            "DELAY" => self.delay(stmt, &a, out),
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
            "CYCLE" => self.cycle(&a),
            "CSYS" => {
                self.pass_through(stmt, out);
                self.csys(&a, diags);
                Ok(())
            }
            "CUTCOM" => {
                self.pass_through(stmt, out);
                let side = a.list.first().and_then(|x| a.word(x));
                if matches!(side.as_deref(), Some("LEFT" | "RIGHT")) && !self.warned_cutcom {
                    self.warned_cutcom = true;
                    diags.push(
                        a.error_all(Diagnostic::warning(
                            "cl::cutcom",
                            "cutter compensation is not applied: the CL points are taken as \
                             the tool position",
                        ))
                        .with_help(
                            "CL data from CAM is normally already offset by the tool radius; \
                             check the CAM setting if the controller was meant to offset it",
                        ),
                    );
                }
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

    fn goto(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        what: Point,
        major: &str,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        match what {
            Point::Delta => a.arity(major, &[1, 3, 6], "dx,dy,dz[,i,j,k] or d")?,
            _ => a.arity(major, &[3, 6], "x,y,z[,i,j,k]")?,
        }
        let v = a.numbers()?;
        let start_axis = self.axis;
        let mut axis = self.axis;
        if v.len() == 6 {
            let (s, e) = (a.list[3].start, a.list[5].end);
            axis = unit(Vector3::new(v[3], v[4], v[5])).ok_or_else(|| {
                stmt.locate(
                    Diagnostic::error("cl::zero-axis", "the tool axis i,j,k is a zero vector")
                        .with_label("zero vector")
                        .with_help("give a tool axis with a non-zero length, e.g. 0,0,1"),
                    s,
                    e,
                )
            })?;
            if self.multax == Some(false) && !self.warned_multax {
                self.warned_multax = true;
                diags.push(
                    stmt.locate(
                        Diagnostic::warning(
                            "cl::multax-off",
                            format!("{major} gives a tool axis under MULTAX/OFF"),
                        ),
                        s,
                        e,
                    )
                    .with_label("tool axis")
                    .with_help("the tool axis is used; write MULTAX/ON before 5-axis motion"),
                );
            }
        }
        let tip = if what == Point::Delta {
            let Some(pos) = self.pos else {
                return Err(a.error_all(
                    Diagnostic::error(
                        "cl::no-start",
                        "GODLTA moves relative to the current point, which is not known yet",
                    )
                    .with_help("give an absolute point first (FROM/x,y,z or GOTO/x,y,z)"),
                ));
            };
            if v.len() == 1 {
                pos + axis.into_inner() * (v[0] * self.scale)
            } else {
                pos + Vector3::new(v[0], v[1], v[2]) * self.scale
            }
        } else {
            Point3::new(v[0], v[1], v[2]) * self.scale
        };
        if !tip.iter().all(|c| c.is_finite()) {
            return Err(a.error_all(
                Diagnostic::error("cl::bad-number", "the point is out of range")
                    .with_help("CL values must be finite numbers"),
            ));
        }
        self.axis = axis;
        let rapid = std::mem::replace(&mut self.rapid_next, false);
        let kind = if rapid || what == Point::Start {
            MotionKind::Rapid
        } else {
            MotionKind::Linear
        };
        let circle = self.circle.take();
        if what == Point::Start {
            if let Some(c) = circle {
                diags.push(c.unused);
            }
        } else if what == Point::Absolute
            && let Some(cy) = self.cycle.active()
        {
            if let Some(c) = circle {
                diags.push(c.unused);
            }
            let cy = cy.clone();
            self.pos = Some(cy.expand(
                stmt,
                tip,
                axis,
                self.pos,
                self.feed,
                &self.options,
                out,
                diags,
            ));
            return Ok(());
        } else if let Some(c) = circle
            && let Some(start) = self.pos
        {
            match arc::Run::new(
                &c,
                start,
                tip,
                start_axis,
                axis,
                kind,
                self.feed,
                stmt,
                &self.options,
                diags,
            ) {
                Ok(run) => {
                    self.arc = Some(run);
                    self.pos = Some(tip);
                    return Ok(());
                }
                Err(d) => diags.push(d),
            }
        }
        out.push(motion_block(stmt.span, kind, tip, axis, self.feed));
        self.pos = Some(tip);
        Ok(())
    }

    fn fedrat(&mut self, a: &Args<'_>) -> Result<(), Diagnostic> {
        let mut rate = None;
        let mut unit: Option<(f64, FeedMode)> = None;
        for x in a.list {
            if x.kind == ArgKind::Number {
                if rate.is_some() {
                    return Err(a.stmt.locate(
                        Diagnostic::error("cl::arity", "FEDRAT takes one rate")
                            .with_label("second number")
                            .with_help("write FEDRAT/f or FEDRAT/f,MMPM (or IPM, MMPR, IPR)"),
                        x.start,
                        x.end,
                    ));
                }
                rate = Some((a.number(x)?, x));
                continue;
            }
            let w = a.text(x).to_ascii_uppercase();
            unit = Some(match w.as_str() {
                "MMPM" => (1.0, FeedMode::PerMinute),
                "IPM" => (MM_PER_INCH, FeedMode::PerMinute),
                "MMPR" => (1.0, FeedMode::PerRevolution),
                "IPR" => (MM_PER_INCH, FeedMode::PerRevolution),
                "PERMIN" => (self.scale, FeedMode::PerMinute),
                "PERREV" => (self.scale, FeedMode::PerRevolution),
                _ => {
                    return Err(a.stmt.locate(
                        Diagnostic::error("cl::feed-unit", format!("unknown feed unit `{w}`"))
                            .with_label("not a feed unit")
                            .with_help("use MMPM, IPM, MMPR or IPR"),
                        x.start,
                        x.end,
                    ));
                }
            });
        }
        let Some((r, arg)) = rate else {
            return Err(a.error_all(
                Diagnostic::error("cl::arity", "FEDRAT needs a rate")
                    .with_help("write FEDRAT/f or FEDRAT/f,MMPM (or IPM, MMPR, IPR)"),
            ));
        };
        if r < 0.0 {
            return Err(a.stmt.locate(
                Diagnostic::error("cl::bad-value", "the feed rate is negative")
                    .with_label("negative")
                    .with_help("a feed rate is a speed: give a positive number"),
                arg.start,
                arg.end,
            ));
        }
        let (factor, mode) = unit.unwrap_or((self.scale, self.feed.mode));
        let rate = r * factor;
        if !rate.is_finite() {
            return Err(a.stmt.locate(
                Diagnostic::error("cl::bad-number", "the feed rate is out of range")
                    .with_label("too large"),
                arg.start,
                arg.end,
            ));
        }
        self.feed = Feed {
            mode,
            rate: Some(rate),
        };
        Ok(())
    }

    fn circle(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        major: &str,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let mut plain = Vec::with_capacity(11);
        let mut centre = None;
        let mut normal = None;
        let mut radius = None;
        let mut radius_at = (0, 0);
        let mut turns = None;
        let mut angle = None;
        let mut i = 0;
        let take = |i: &mut usize, n: usize| -> Result<Vec<f64>, Diagnostic> {
            let kw = &a.list[*i];
            let mut v = Vec::with_capacity(n);
            for k in 1..=n {
                match a.list.get(*i + k) {
                    Some(x) => v.push(a.number(x)?),
                    None => {
                        return Err(a.stmt.locate(
                            Diagnostic::error(
                                "cl::arity",
                                format!(
                                    "`{}` needs {n} value{}",
                                    a.text(kw),
                                    if n == 1 { "" } else { "s" }
                                ),
                            )
                            .with_label("values missing"),
                            kw.start,
                            kw.end,
                        ));
                    }
                }
            }
            *i += n;
            Ok(v)
        };
        while i < a.list.len() {
            let x = &a.list[i];
            if x.kind == ArgKind::Number {
                plain.push(a.number(x)?);
            } else {
                match a.text(x).to_ascii_uppercase().as_str() {
                    "TIMES" => {
                        let v = take(&mut i, 1)?[0];
                        if !(v >= 0.0 && v.fract() == 0.0 && v <= 10_000.0) {
                            return Err(a.stmt.locate(
                                Diagnostic::error(
                                    "cl::bad-value",
                                    "TIMES takes a whole number of turns from 0 to 10000",
                                )
                                .with_label("here"),
                                x.start,
                                a.list[i].end,
                            ));
                        }
                        turns = Some(v as u32);
                    }
                    "ANGLE" => angle = Some(take(&mut i, 1)?[0]),
                    "RADIUS" => {
                        radius = Some(take(&mut i, 1)?[0]);
                        radius_at = (a.list[i].start, a.list[i].end);
                    }
                    "CENTER" | "CENTRE" => {
                        let v = take(&mut i, 3)?;
                        centre = Some(Vector3::new(v[0], v[1], v[2]));
                    }
                    "AXIS" => {
                        let v = take(&mut i, 3)?;
                        normal = Some((Vector3::new(v[0], v[1], v[2]), x.start, a.list[i].end));
                    }
                    _ => {
                        return Err(a.stmt.locate(
                            Diagnostic::error(
                                "cl::bad-number",
                                format!("expected a number, found `{}`", a.text(x)),
                            )
                            .with_label("not a number")
                            .with_help(format!(
                                "{major} takes the centre, the axis and the radius: \
                                 {major}/x,y,z,i,j,k,r"
                            )),
                            x.start,
                            x.end,
                        ));
                    }
                }
            }
            i += 1;
        }
        // Which positional form: 6 (centre, axis; radius from the start point), 7 (APT),
        // 8 to 11 (NX: tolerance, ratio, tool diameter and corner radius follow).
        let keyword_form = centre.is_some() || normal.is_some();
        let mut left_handed = false;
        if keyword_form {
            if !plain.is_empty() || centre.is_none() || normal.is_none() {
                return Err(a.error_all(
                    Diagnostic::error(
                        "cl::arity",
                        format!("{major} with keywords takes CENTER,x,y,z,AXIS,i,j,k[,RADIUS,r]"),
                    )
                    .with_label("here"),
                ));
            }
        } else {
            let n = plain.len();
            if !(6..=11).contains(&n) {
                return Err(a.error_all(
                    Diagnostic::error(
                        "cl::arity",
                        format!("{major} takes 6, 7 or 11 values, found {n}"),
                    )
                    .with_label("here")
                    .with_help(format!(
                        "write {major}/x,y,z,i,j,k,r (centre, axis, radius)"
                    )),
                ));
            }
            // Numbers sit at positions 0..n of the plain list, which follow the
            // arguments in order when no keyword comes first.
            let pos = |k: usize| a.list.iter().filter(|x| x.kind == ArgKind::Number).nth(k);
            centre = Some(Vector3::new(plain[0], plain[1], plain[2]));
            let (s, e) = (pos(3).map_or(0, |x| x.start), pos(5).map_or(0, |x| x.end));
            normal = Some((Vector3::new(plain[3], plain[4], plain[5]), s, e));
            if n >= 7 {
                radius = Some(plain[6]);
                radius_at = pos(6).map_or((0, 0), |x| (x.start, x.end));
            }
            left_handed = n >= 8 && major == "CIRCLE";
        }
        let (Some(c), Some((nv, ns, ne))) = (centre, normal) else {
            return Ok(());
        };
        let mut normal = unit(nv).ok_or_else(|| {
            stmt.locate(
                Diagnostic::error(
                    "cl::zero-axis",
                    format!("the {major} axis i,j,k is a zero vector"),
                )
                .with_label("zero vector")
                .with_help("give the circle's axis, e.g. 0,0,1 for counter-clockwise in XY"),
                ns,
                ne.max(ns + 1),
            )
        })?;
        if left_handed {
            normal = -normal;
        }
        if let Some(r) = radius
            && r <= 0.0
        {
            return Err(stmt.locate(
                Diagnostic::error(
                    "cl::bad-value",
                    format!("the {major} radius is not positive"),
                )
                .with_label("radius")
                .with_help("give the radius as a positive length"),
                radius_at.0,
                radius_at.1,
            ));
        }
        let centre = Point3::from(c * self.scale);
        let radius = radius.map(|r| r * self.scale);
        if !centre.iter().all(|v| v.is_finite()) || radius.is_some_and(|r| !r.is_finite()) {
            return Err(a.error_all(Diagnostic::error(
                "cl::bad-number",
                format!("the {major} centre or radius is out of range"),
            )));
        }
        if self.pos.is_none() {
            return Err(a.error_all(
                Diagnostic::error(
                    "cl::no-start",
                    format!("{major} starts at the current point, which is not known yet"),
                )
                .with_help("give a point first (FROM/x,y,z or GOTO/x,y,z)"),
            ));
        }
        if let Some(old) = self.circle.take() {
            diags.push(old.unused);
        }
        self.circle = Some(Circle {
            centre,
            normal,
            radius,
            turns,
            angle,
            line: stmt.span.line,
            unused: unused_circle(stmt, major),
        });
        Ok(())
    }

    fn tlaxis(&mut self, a: &Args<'_>) -> Result<(), Diagnostic> {
        if a.list.iter().any(|x| x.kind != ArgKind::Number) {
            return Err(a.error_all(
                Diagnostic::warning(
                    "cl::unsupported",
                    "only TLAXIS/i,j,k is understood; the tool axis is unchanged",
                )
                .with_help("passed through as a comment"),
            ));
        }
        a.arity("TLAXIS", &[3], "i,j,k")?;
        let v = a.numbers()?;
        self.axis = unit(Vector3::new(v[0], v[1], v[2])).ok_or_else(|| {
            a.error_all(
                Diagnostic::error("cl::zero-axis", "the tool axis i,j,k is a zero vector")
                    .with_label("zero vector")
                    .with_help("give a tool axis with a non-zero length, e.g. 0,0,1"),
            )
        })?;
        Ok(())
    }

    fn multax(&mut self, a: &Args<'_>) -> Result<(), Diagnostic> {
        self.multax = match a.list {
            [] => Some(true),
            [x] => match a.word(x).as_deref() {
                Some("ON") => Some(true),
                Some("OFF") => Some(false),
                _ => {
                    return Err(a.error_all(
                        Diagnostic::error("cl::bad-value", "MULTAX takes ON or OFF")
                            .with_label("here")
                            .with_help("write MULTAX/ON or MULTAX/OFF"),
                    ));
                }
            },
            _ => {
                return Err(a.error_all(
                    Diagnostic::error("cl::arity", "MULTAX takes ON or OFF")
                        .with_label("here")
                        .with_help("write MULTAX/ON or MULTAX/OFF"),
                ));
            }
        };
        Ok(())
    }

    fn units(&mut self, a: &Args<'_>, major: &str) -> Result<(), Diagnostic> {
        let word = match a.list {
            [x] => a.word(x),
            _ => None,
        };
        self.scale = match word.as_deref() {
            Some("INCHES" | "INCH" | "IN") => MM_PER_INCH,
            Some("MM" | "MILLIMETERS" | "MILLIMETRES" | "METRIC") => 1.0,
            Some("CM" | "CENTIMETERS" | "CENTIMETRES") => 10.0,
            _ => {
                return Err(a.error_all(
                    Diagnostic::error("cl::bad-value", format!("{major} takes MM or INCHES"))
                        .with_label("here")
                        .with_help(format!("write {major}/MM or {major}/INCHES")),
                ));
            }
        };
        Ok(())
    }

    fn spindle(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        out: &mut Vec<Block>,
    ) -> Result<(), Diagnostic> {
        let mut rpm = None;
        let mut on = false;
        let mut off = false;
        let mut ccw = None;
        let mut i = 0;
        while i < a.list.len() {
            let x = &a.list[i];
            if x.kind == ArgKind::Number {
                if rpm.is_none() {
                    rpm = Some((a.number(x)?, x));
                }
                i += 1;
                continue;
            }
            match a.text(x).to_ascii_uppercase().as_str() {
                "ON" => on = true,
                "OFF" => off = true,
                "CLW" => ccw = Some(false),
                "CCLW" => ccw = Some(true),
                "RPM" => {}
                // A value that is not the speed.
                "RANGE" | "MAXRPM" => i += 1,
                "SFM" | "SMM" => {
                    return Err(a.error_all(
                        Diagnostic::warning(
                            "cl::unsupported",
                            "constant surface speed cannot be expressed as a spindle speed",
                        )
                        .with_help("passed through as a comment; give the speed in RPM"),
                    ));
                }
                w => {
                    return Err(stmt.locate(
                        Diagnostic::error("cl::bad-value", format!("unknown SPINDL word `{w}`"))
                            .with_label("not understood")
                            .with_help("write SPINDL/rpm,CLW (or CCLW), SPINDL/ON or SPINDL/OFF"),
                        x.start,
                        x.end,
                    ));
                }
            }
            i += 1;
        }
        if off {
            out.push(Block::new(stmt.span, command("M5")));
            return Ok(());
        }
        if let Some((r, x)) = rpm {
            if r < 0.0 {
                return Err(stmt.locate(
                    Diagnostic::error("cl::bad-value", "the spindle speed is negative")
                        .with_label("negative")
                        .with_help(
                            "give the speed as a positive number and the direction as CLW or CCLW",
                        ),
                    x.start,
                    x.end,
                ));
            }
            self.spindle_rpm = Some(r);
        } else if !on && ccw.is_none() {
            return Err(a.error_all(
                Diagnostic::error("cl::arity", "SPINDL needs a speed, ON or OFF")
                    .with_help("write SPINDL/rpm,CLW (or CCLW), SPINDL/ON or SPINDL/OFF"),
            ));
        }
        if let Some(d) = ccw {
            self.spindle_ccw = d;
        }
        let mut text = String::from(if self.spindle_ccw { "M4" } else { "M3" });
        if let Some(r) = self.spindle_rpm {
            text.push_str(" S");
            text.push_str(&format_number(r));
        }
        out.push(Block::new(stmt.span, command(text)));
        Ok(())
    }

    fn coolant(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        out: &mut Vec<Block>,
    ) -> Result<(), Diagnostic> {
        let words: Vec<String> = a.list.iter().filter_map(|x| a.word(x)).collect();
        let has = |w: &str| words.iter().any(|x| x == w);
        let code = if has("OFF") {
            "M9"
        } else if has("MIST") || has("AIR") {
            "M7"
        } else if has("ON") || has("FLOOD") || has("THRU") {
            "M8"
        } else {
            return Err(a.error_all(
                Diagnostic::warning("cl::unsupported", "COOLNT mode not understood")
                    .with_help("passed through as a comment; use COOLNT/ON, FLOOD, MIST or OFF"),
            ));
        };
        out.push(Block::new(stmt.span, command(code)));
        Ok(())
    }

    fn load_tool(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        at: usize,
        out: &mut Vec<Block>,
    ) -> Result<(), Diagnostic> {
        let Some(x) = a.list.get(at) else {
            return Err(a.error_all(
                Diagnostic::error("cl::arity", "the tool number is missing")
                    .with_help("write LOADTL/n or LOAD/TOOL,n"),
            ));
        };
        let n = a.number(x)?;
        if !(n >= 0.0 && n.fract() == 0.0 && n < 1e9) {
            return Err(stmt.locate(
                Diagnostic::error("cl::bad-value", "the tool number is not a whole number")
                    .with_label("tool number")
                    .with_help("tool numbers are whole numbers from 0"),
                x.start,
                x.end,
            ));
        }
        let mut b = Block::new(stmt.span, command(format!("T{}", n as u64)));
        if a.list.len() > at + 1 {
            b.comments.push(comment(format!(" {}", stmt.code.trim())));
        }
        out.push(b);
        Ok(())
    }

    fn delay(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        out: &mut Vec<Block>,
    ) -> Result<(), Diagnostic> {
        let (value, revolutions) = match a.list {
            [x] => (x, false),
            [w, x] if a.word(w).as_deref() == Some("REV") => (x, true),
            _ => {
                return Err(a.error_all(
                    Diagnostic::error("cl::arity", "DELAY takes one time in seconds")
                        .with_label("here")
                        .with_help("write DELAY/s or DELAY/REV,n"),
                ));
            }
        };
        let v = a.number(value)?;
        if v < 0.0 {
            return Err(stmt.locate(
                Diagnostic::error("cl::bad-value", "the delay is negative")
                    .with_label("negative")
                    .with_help("a delay is a time: give a positive number of seconds"),
                value.start,
                value.end,
            ));
        }
        let seconds = if revolutions {
            match self.spindle_rpm {
                Some(rpm) if rpm > 0.0 => v * 60.0 / rpm,
                _ => {
                    return Err(a.error_all(
                        Diagnostic::warning(
                            "cl::unsupported",
                            "DELAY/REV needs a known spindle speed",
                        )
                        .with_help("passed through as a comment; give the delay in seconds"),
                    ));
                }
            }
        } else {
            v
        };
        out.push(Block::new(stmt.span, BlockKind::Dwell { seconds }));
        Ok(())
    }

    fn stop(&mut self, stmt: &Statement, code: String, out: &mut Vec<Block>) {
        if code.trim().is_empty() {
            self.pass_through(stmt, out);
        } else {
            out.push(Block::new(stmt.span, command(code.trim())));
        }
    }

    fn cycle(&mut self, a: &Args<'_>) -> Result<(), Diagnostic> {
        match cycle::parse(a.stmt, a.list, self.scale) {
            Ok(cycle::Parsed::Off) => self.cycle.stop(),
            Ok(cycle::Parsed::Keep) => {}
            Ok(cycle::Parsed::On) => self.cycle.resume(),
            Ok(cycle::Parsed::Cycle(c)) => self.cycle = cycle::State::On(c),
            Err(d) => {
                // An unsupported cycle: the motions inside stay plain moves.
                self.cycle = cycle::State::Off;
                return Err(d);
            }
        }
        Ok(())
    }

    /// A CSYS matrix (three rows of rotation and translation) passes through; its Z
    /// column becomes the tool axis (APT++ writes 3-value GOTOs only under a CSYS whose
    /// Z column is +Z, and 6-value ones with the Z column as their axis otherwise). A
    /// CSYS that is not the identity gets a warning: it is not applied to the points.
    fn csys(&mut self, a: &Args<'_>, diags: &mut Vec<Diagnostic>) {
        let Ok(v) = a.numbers() else {
            return;
        };
        let identity = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        if v.len() == 12
            && let Some(z) = unit(Vector3::new(v[2], v[6], v[10]))
        {
            self.axis = z;
        }
        if v.len() == 12 && v.iter().zip(identity).all(|(a, b)| (a - b).abs() < 1e-9) {
            return;
        }
        diags.push(
            a.error_all(
                Diagnostic::warning(
                    "cl::csys-not-applied",
                    "the CSYS transform is not applied: the points that follow are used as \
                 written, in the part frame",
                )
                .with_label("not applied"),
            )
            .with_help(
                "CAM systems that write CSYS give GOTO points and tool axes in the base frame \
                 already (the tool axes match the CSYS Z column); CSYS only names the working \
                 plane",
            ),
        );
    }

    fn triplet_line(
        &mut self,
        stmt: &Statement,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let code = stmt.code.trim();
        if code.is_empty() {
            return;
        }
        let state = self.triplet.unwrap_or(Triplet::Point);
        let numbers = || -> Result<Vector3<f64>, Diagnostic> {
            let mut v = Vec::with_capacity(3);
            let mut offset = 0;
            for field in stmt
                .code
                .split(|c: char| c.is_ascii_whitespace() || c == ',')
            {
                let start = offset;
                offset += field.len() + 1;
                if field.is_empty() {
                    continue;
                }
                match field.parse::<f64>() {
                    Ok(x)
                        if x.is_finite()
                            && field
                                .bytes()
                                .all(|b| b.is_ascii_digit() || b"+-.eE".contains(&b)) =>
                    {
                        v.push(x)
                    }
                    _ => {
                        return Err(stmt.locate(
                            Diagnostic::error(
                                "cl::bad-number",
                                format!("expected a number, found `{field}`"),
                            )
                            .with_label("not a number")
                            .with_help("a triplet's first two lines hold three numbers each"),
                            start,
                            start + field.len(),
                        ));
                    }
                }
            }
            if v.len() != 3 {
                return Err(stmt.locate_all(
                    Diagnostic::error(
                        "cl::triplet",
                        format!("expected three numbers, found {}", v.len()),
                    )
                    .with_label("here")
                    .with_help(
                        "a triplet is a point line, a tool axis line and a motion code line",
                    ),
                ));
            }
            Ok(Vector3::new(v[0], v[1], v[2]))
        };
        let next = match state {
            Triplet::Point => numbers().and_then(|p| {
                let p = p * self.scale;
                if p.iter().all(|c| c.is_finite()) {
                    Ok(Triplet::Axis {
                        point: Point3::from(p),
                        span: stmt.span,
                    })
                } else {
                    Err(stmt.locate_all(Diagnostic::error(
                        "cl::bad-number",
                        "the point is out of range",
                    )))
                }
            }),
            Triplet::Axis { point, span } => numbers().and_then(|v| {
                unit(v)
                    .map(|axis| Triplet::Code { point, axis, span })
                    .ok_or_else(|| {
                        stmt.locate_all(
                            Diagnostic::error("cl::zero-axis", "the tool axis is a zero vector")
                                .with_label("zero vector")
                                .with_help("give a tool axis with a non-zero length, e.g. 0 0 1"),
                        )
                    })
            }),
            Triplet::Code { point, axis, span } => {
                if (1..=4).contains(&code.len()) && code.bytes().all(|b| b.is_ascii_hexdigit()) {
                    let kind = if code.eq_ignore_ascii_case("7f") {
                        MotionKind::Rapid
                    } else {
                        MotionKind::Linear
                    };
                    let end = stmt.span.offset + u64::from(stmt.span.len);
                    let span = Span {
                        len: end.saturating_sub(span.offset).min(u64::from(u32::MAX)) as u32,
                        ..span
                    };
                    out.push(motion_block(span, kind, point, axis, self.feed));
                    self.pos = Some(point);
                    self.axis = axis;
                    Ok(Triplet::Point)
                } else {
                    Err(stmt.locate_all(
                        Diagnostic::error(
                            "cl::triplet",
                            format!("expected a motion code such as `7f` or `80`, found `{code}`"),
                        )
                        .with_label("not a motion code")
                        .with_help(
                            "the third line of a triplet is the hexadecimal motion code (7f rapid)",
                        ),
                    ))
                }
            }
        };
        match next {
            Ok(s) => self.triplet = Some(s),
            Err(d) => {
                diags.push(d);
                self.triplet = Some(Triplet::Point);
            }
        }
    }
}

/// How a point statement moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Point {
    /// `GOTO`: to the point.
    Absolute,
    /// `FROM`: the start point, at rapid.
    Start,
    /// `GODLTA`: by the offset.
    Delta,
}

fn unused_circle(stmt: &Statement, major: &str) -> Diagnostic {
    stmt.locate_all(Diagnostic::warning(
        "cl::circle-without-end",
        format!("no GOTO ends this {major}; it was ignored"),
    ))
    .with_label("no end point")
    .with_help(format!(
        "an arc ends at the point of the GOTO right after its {major}"
    ))
}

/// The tokens of `code` for the grammar.
fn lex_iter(code: &str) -> impl Iterator<Item = (usize, Tok<'_>, usize)> {
    use logos::Logos;
    let mut lexer = Tok::lexer(code);
    std::iter::from_fn(move || {
        let tok = lexer.next()?;
        let span = lexer.span();
        let tok = tok.unwrap_or_else(|()| Tok::Other(lexer.slice()));
        Some((span.start, tok, span.end))
    })
}

/// The leading words of `code` (before `/` or anything else), upper-case, single spaces.
fn major_words(code: &str) -> String {
    let mut out = String::new();
    for (_, tok, _) in lex_iter(code) {
        match tok {
            Tok::Word(w) => {
                if !out.is_empty() {
                    out.push(' ');
                }
                out.push_str(&w.to_ascii_uppercase());
            }
            _ => break,
        }
    }
    out
}

fn normalise_major(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for w in text.split_ascii_whitespace() {
        if !out.is_empty() {
            out.push(' ');
        }
        out.push_str(&w.to_ascii_uppercase());
    }
    out
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
            | "CUTCOM"
    ) || INFORMATIONAL.contains(&major)
}

fn unknown(stmt: &Statement, major: &str, start: usize, end: usize) -> Diagnostic {
    let shown = if major.is_empty() {
        stmt.code.trim().chars().take(20).collect::<String>()
    } else {
        major.to_string()
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

fn syntax_error(stmt: &Statement, err: lalrpop_util::ParseError<usize, Tok<'_>, ()>) -> Diagnostic {
    use lalrpop_util::ParseError as P;
    let code = stmt.code.as_str();
    let (s, e, what) = match err {
        P::UnrecognizedToken {
            token: (s, t, e), ..
        }
        | P::ExtraToken { token: (s, t, e) } => (s, e, describe(t)),
        P::InvalidToken { location } => (location, location + 1, "this".to_string()),
        P::UnrecognizedEof { location, .. } => {
            (location, location + 1, "the end of the statement".into())
        }
        P::User { .. } => (0, code.len(), "the statement".into()),
    };
    stmt.locate(
        Diagnostic::error("cl::syntax", format!("unexpected {what}"))
            .with_label("not allowed here")
            .with_help("a statement is MAJOR/value,value,...; values are numbers or words"),
        s,
        e,
    )
}

fn describe(t: Tok<'_>) -> String {
    match t {
        Tok::Word(w) => format!("word `{w}`"),
        Tok::Number(n) => format!("number `{n}`"),
        Tok::Slash => "`/`".into(),
        Tok::Comma => "`,`".into(),
        Tok::Other(o) => format!("`{o}`"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_print_short() {
        assert_eq!(format_number(12000.0), "12000");
        assert_eq!(format_number(2.5), "2.5");
        assert_eq!(format_number(-0.00001), "0");
        assert_eq!(format_number(1.23456), "1.2346");
    }

    #[test]
    fn listing_lines() {
        assert!(is_listing_line("Information listing created by\tphill"));
        assert!(is_listing_line("Date\t18-Dec-2021 21:07:42"));
        assert!(is_listing_line("Tool Path Listing has 11294 lines."));
        assert!(is_listing_line("=========="));
        assert!(!is_listing_line("GOTO/1,2,3"));
    }

    #[test]
    fn zero_vectors_have_no_direction() {
        assert!(unit(Vector3::zeros()).is_none());
        assert!(unit(Vector3::new(f64::NAN, 0.0, 1.0)).is_none());
        assert!(unit(Vector3::new(1e-300, 0.0, 0.0)).is_none());
        let u = unit(Vector3::new(1e-9, 0.0, 0.0)).unwrap();
        assert!((u.norm() - 1.0).abs() < 1e-12);
        let u = unit(Vector3::new(1e300, 1e300, 0.0)).unwrap();
        assert!((u.norm() - 1.0).abs() < 1e-12);
    }

    /// [`unit`] as it was written first: the reference for its bits.
    fn unit_reference(v: Vector3<f64>) -> Option<Unit<Vector3<f64>>> {
        let m = v.amax();
        if !(m.is_finite() && m > 1e-12) {
            return None;
        }
        let u = Unit::new_normalize(v / m);
        u.iter().all(|c| c.is_finite()).then_some(u)
    }

    fn same_unit(v: Vector3<f64>) -> Result<(), proptest::test_runner::TestCaseError> {
        let bits = |u: Option<Unit<Vector3<f64>>>| u.map(|u| u.map(f64::to_bits));
        proptest::prop_assert_eq!(bits(unit(v)), bits(unit_reference(v)), "{:?}", v);
        Ok(())
    }

    /// A component as CL files and worse inputs have them: printed unit-vector parts,
    /// zeros of both signs, tiny, huge and not finite values, and any bits.
    fn component() -> impl proptest::strategy::Strategy<Value = f64> {
        use proptest::prelude::*;
        prop_oneof![
            (-1.0f64..1.0, 0usize..12).prop_map(|(c, d)| format!("{c:.d$}").parse().unwrap()),
            -1.0f64..1.0,
            -1e6f64..1e6,
            -1e-10f64..1e-10,
            proptest::sample::select(vec![
                0.0,
                -0.0,
                1.0,
                -1.0,
                0.5,
                1e-12,
                -1e-12,
                1.000000000001e-12,
                f64::MIN_POSITIVE,
                5e-324,
                f64::MAX,
                -f64::MAX,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NAN,
            ]),
            any::<u64>().prop_map(f64::from_bits),
        ]
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 20_000, ..Default::default() })]

        /// Bit for bit the first [`unit`], `None` included.
        #[test]
        fn unit_is_the_reference_bit_for_bit(x in component(), y in component(), z in component()) {
            same_unit(Vector3::new(x, y, z))?;
        }

        /// Printed unit vectors (the tool axes of 5-axis CL files), their sign flips and
        /// permutations.
        #[test]
        fn printed_axes_are_the_reference_bit_for_bit(
            a in -std::f64::consts::PI..std::f64::consts::PI,
            b in 0.0..std::f64::consts::PI,
            d in 3usize..12,
        ) {
            let p = |c: f64| -> f64 { format!("{c:.d$}").parse().unwrap() };
            let (x, y, z) = (p(b.sin() * a.cos()), p(b.sin() * a.sin()), p(b.cos()));
            for v in [[x, y, z], [y, z, x], [z, x, y], [-x, y, -z], [x, -y, z]] {
                same_unit(Vector3::from(v))?;
            }
        }
    }
}
