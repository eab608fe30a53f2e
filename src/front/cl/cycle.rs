//! Drilling cycles: `CYCLE/DRILL|FACE|DEEP|DEEP2|BRKCHP|REAM|BORE,...` up to `CYCLE/OFF`.
//!
//! Each `GOTO` inside a cycle gives the hole's top point P; the tool axis T points out of
//! the hole. Distances are measured from P along T (APT `CYCLE` with minor words, as
//! written by APT++/CAMWorks: the `GOTO` before the cycle is P + RTRCTO·T):
//!
//! - `FEDTO d` (or `DEPTH d`, or the first plain number): the depth, to P − d·T;
//! - `RAPTO r` (or the second plain number, ISO 4343's clearance): the feed starts at
//!   P + r·T;
//! - `RTRCTO c`: the retract height P + c·T (without it, the tool retracts to P + r·T);
//! - `MMPM f`, `IPM f`, `MMPR f`, `IPR f`: the cycle's feed (otherwise the feed in force);
//! - `DWELL s`: seconds at the bottom;
//! - `1STPECK p`, `SUBPECK q` (or `STEP q`): peck depths for `DEEP*` (full retract to
//!   P + r·T between pecks) and `BRKCHP` (chip break: back off by the peck clearance).
//!
//! The motions of one hole: rapid to P + c·T, rapid to P + r·T, feed to the depth (in
//! pecks), dwell, and back to P + c·T (`REAM` and `BORE` feed out to P + r·T first).
//! `CYCLE/INIT` does nothing, `CYCLE/ON` resumes the last cycle. Other cycle types
//! (tapping, threading, ...) are not lowered: a warning, and the `GOTO`s inside move to
//! the written points.

use nalgebra::{Point3, Unit, Vector3};

use super::ast::{Arg, ArgKind};
use super::motion::{MM_PER_INCH, motion_block};
use super::options::Options;
use super::source::Statement;
use crate::diag::Diagnostic;
use crate::ir::{Block, BlockKind, Feed, FeedMode, MotionKind};

/// Moves shorter than this (mm) are left out: the tool is there already (the CL rounds
/// the retract point it writes before a cycle).
const SAME_POINT: f64 = 1e-4;

/// Most pecks per hole; a cycle that needs more is drilled in one feed.
const MAX_PECKS: usize = 10_000;

/// How a cycle drills.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// Feed in, rapid out.
    Drill,
    /// Pecks with a full retract between them.
    Deep,
    /// Pecks with a short back-off between them.
    ChipBreak,
    /// Feed in, feed out.
    FeedOut,
}

/// A drilling cycle's parameters, lengths in mm.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Cycle {
    kind: Kind,
    depth: f64,
    rapto: f64,
    rtrcto: Option<f64>,
    dwell: f64,
    first_peck: Option<f64>,
    sub_peck: Option<f64>,
    feed: Option<Feed>,
}

/// Whether a cycle is active.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum State {
    /// No cycle; `last` is resumed by `CYCLE/ON`.
    Off,
    /// Lowering `GOTO`s as holes.
    On(Cycle),
    /// Off, remembering the cycle for `CYCLE/ON`.
    Suspended(Cycle),
}

impl State {
    /// The active cycle.
    pub fn active(&self) -> Option<&Cycle> {
        match self {
            State::On(c) => Some(c),
            _ => None,
        }
    }

    /// `CYCLE/OFF`: keeps the cycle for `CYCLE/ON`.
    pub fn stop(&mut self) {
        if let State::On(c) = std::mem::replace(self, State::Off) {
            *self = State::Suspended(c);
        }
    }

    /// `CYCLE/ON`: the last cycle again.
    pub fn resume(&mut self) {
        if let State::Suspended(c) = std::mem::replace(self, State::Off) {
            *self = State::On(c);
        }
    }
}

/// What a `CYCLE` statement says.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Parsed {
    /// `CYCLE/OFF`.
    Off,
    /// `CYCLE/ON`.
    On,
    /// `CYCLE/INIT` and the like: nothing changes.
    Keep,
    /// A drilling cycle.
    Cycle(Cycle),
}

/// Reads a `CYCLE` statement's arguments; `Err` is an error, or a warning when the cycle
/// cannot be lowered (it then passes through as a comment).
pub(super) fn parse(stmt: &Statement, args: &[Arg], scale: f64) -> Result<Parsed, Diagnostic> {
    let Some(first) = args.first() else {
        let (s, e) = all(stmt, args);
        return Err(stmt.locate(
            Diagnostic::error("cl::arity", "CYCLE needs a cycle type")
                .with_label("here")
                .with_help("write CYCLE/DRILL,FEDTO,d,... or CYCLE/OFF"),
            s,
            e,
        ));
    };
    let name = text(stmt, first).to_ascii_uppercase();
    let kind = match name.as_str() {
        "OFF" => return Ok(Parsed::Off),
        "ON" => return Ok(Parsed::On),
        "INIT" | "NOMORE" => return Ok(Parsed::Keep),
        "DRILL" | "FACE" | "SPOT" => Kind::Drill,
        "DEEP" | "DEEP2" => Kind::Deep,
        "BRKCHP" => Kind::ChipBreak,
        "REAM" | "BORE" => Kind::FeedOut,
        _ => {
            return Err(unsupported(
                stmt,
                args,
                format!("CYCLE/{name} is not a drilling cycle ncpost lowers"),
            ));
        }
    };
    let w = written(stmt, args)?;
    let Some(depth) = w.depth else {
        return Err(unsupported(
            stmt,
            args,
            format!("CYCLE/{name} gives no depth (FEDTO)"),
        ));
    };
    let lengths = [Some(depth), w.rapto, w.rtrcto, w.first_peck, w.sub_peck];
    if lengths.iter().flatten().any(|v| *v < 0.0) || w.dwell < 0.0 {
        let (s, e) = all(stmt, args);
        return Err(stmt.locate(
            Diagnostic::error("cl::bad-value", "a CYCLE depth, height or time is negative")
                .with_label("here")
                .with_help(
                    "depths are measured into the hole and heights out of it, both positive",
                ),
            s,
            e,
        ));
    }
    let feed = match w.feed {
        Some((v, factor, mode)) => {
            if v < 0.0 {
                let (s, e) = all(stmt, args);
                return Err(stmt.locate(
                    Diagnostic::error("cl::bad-value", "the cycle feed is negative")
                        .with_label("here"),
                    s,
                    e,
                ));
            }
            Some(Feed {
                mode,
                rate: Some(v * factor),
            })
        }
        None => None,
    };
    let scaled = |v: f64| v * scale;
    let cycle = Cycle {
        kind,
        depth: scaled(depth),
        rapto: scaled(w.rapto.unwrap_or(0.0)),
        rtrcto: w.rtrcto.map(scaled),
        dwell: w.dwell,
        first_peck: w.first_peck.map(scaled),
        sub_peck: w.sub_peck.map(scaled),
        feed,
    };
    let values = [cycle.depth, cycle.rapto, cycle.rtrcto.unwrap_or(0.0)];
    if !values.iter().all(|v| v.is_finite()) {
        let (s, e) = all(stmt, args);
        return Err(stmt.locate(
            Diagnostic::error("cl::bad-number", "a CYCLE value is out of range").with_label("here"),
            s,
            e,
        ));
    }
    Ok(Parsed::Cycle(cycle))
}

/// The values a `CYCLE` writes, as written (in the program's length unit).
struct Written {
    depth: Option<f64>,
    rapto: Option<f64>,
    rtrcto: Option<f64>,
    dwell: f64,
    first_peck: Option<f64>,
    sub_peck: Option<f64>,
    /// Rate, mm per inch or 1, per minute or revolution.
    feed: Option<(f64, f64, FeedMode)>,
}

/// Reads the values after the cycle type: plain numbers (depth, clearance) and the values
/// after minor words.
fn written(stmt: &Statement, args: &[Arg]) -> Result<Written, Diagnostic> {
    let mut w = Written {
        depth: None,
        rapto: None,
        rtrcto: None,
        dwell: 0.0,
        first_peck: None,
        sub_peck: None,
        feed: None,
    };
    let mut positional = 0;
    let mut i = 1;
    while i < args.len() {
        let a = &args[i];
        let number = |k: usize| -> Result<f64, Diagnostic> {
            let Some(x) = args.get(k).filter(|x| x.kind == ArgKind::Number) else {
                let at = args.get(k).unwrap_or(a);
                return Err(stmt.locate(
                    Diagnostic::error(
                        "cl::bad-number",
                        format!(
                            "`{}` needs a number after it",
                            crate::num::range::shown(text(stmt, a))
                        ),
                    )
                    .with_label("number expected")
                    .with_help("write the keyword and then its value, e.g. FEDTO,5"),
                    at.start,
                    at.end,
                ));
            };
            match crate::num::parse_decimal(text(stmt, x)) {
                Some(v) if crate::num::range::in_range(v) => Ok(v),
                _ => Err(stmt.locate(
                    Diagnostic::error(
                        "cl::bad-number",
                        format!(
                            "`{}` is out of range",
                            crate::num::range::shown(text(stmt, x))
                        ),
                    )
                    .with_label("too large")
                    .with_help(format!(
                        "CL values must be finite and at most {:e} in size",
                        crate::num::range::MAX_MAGNITUDE
                    )),
                    x.start,
                    x.end,
                )),
            }
        };
        if a.kind == ArgKind::Number {
            let v = number(i)?;
            match positional {
                0 if w.depth.is_none() => w.depth = Some(v),
                _ if w.rapto.is_none() => w.rapto = Some(v),
                _ => {
                    return Err(unsupported(
                        stmt,
                        args,
                        "the CYCLE has more values than ncpost reads".into(),
                    ));
                }
            }
            positional += 1;
            i += 1;
            continue;
        }
        let word = text(stmt, a).to_ascii_uppercase();
        let v = number(i + 1)?;
        match word.as_str() {
            "FEDTO" | "DEPTH" => w.depth = Some(v),
            "RAPTO" => w.rapto = Some(v),
            "RTRCTO" => w.rtrcto = Some(v),
            "DWELL" => w.dwell = v,
            "1STPECK" => w.first_peck = Some(v),
            "SUBPECK" | "STEP" => w.sub_peck = Some(v),
            "MMPM" => w.feed = Some((v, 1.0, FeedMode::PerMinute)),
            "IPM" => w.feed = Some((v, MM_PER_INCH, FeedMode::PerMinute)),
            "MMPR" => w.feed = Some((v, 1.0, FeedMode::PerRevolution)),
            "IPR" => w.feed = Some((v, MM_PER_INCH, FeedMode::PerRevolution)),
            _ => {
                return Err(unsupported(
                    stmt,
                    args,
                    format!(
                        "the CYCLE word `{}` is not understood",
                        crate::num::range::shown(&word)
                    ),
                ));
            }
        }
        i += 2;
    }
    Ok(w)
}

/// The bytes of an argument.
fn text<'a>(stmt: &'a Statement, a: &Arg) -> &'a str {
    &stmt.code[a.start..a.end]
}

/// The byte range of all arguments (of the statement when there are none).
fn all(stmt: &Statement, args: &[Arg]) -> (usize, usize) {
    let (s, e) = match (args.first(), args.last()) {
        (Some(f), Some(l)) => (f.start, l.end),
        _ => (0, stmt.code.trim_end().len()),
    };
    (s, e.max(s + 1))
}

/// The warning for a cycle that is not lowered.
fn unsupported(stmt: &Statement, args: &[Arg], why: String) -> Diagnostic {
    let (s, e) = all(stmt, args);
    stmt.locate(Diagnostic::warning("cl::cycle-unsupported", why), s, e)
        .with_label("not lowered")
        .with_help(
            "passed through as a comment; the GOTOs up to CYCLE/OFF move to the written \
             points",
        )
}

impl Cycle {
    /// Appends the motions of the hole at `p` (tool axis `axis`), starting from `from`;
    /// returns where the tool ends.
    #[allow(clippy::too_many_arguments)]
    pub fn expand(
        &self,
        stmt: &Statement,
        p: Point3<f64>,
        axis: Unit<Vector3<f64>>,
        from: Option<Point3<f64>>,
        feed_in_force: Feed,
        options: &Options,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Point3<f64> {
        let t = axis.into_inner();
        let at = |d: f64| p + t * d;
        let clear = at(self.rtrcto.unwrap_or(self.rapto));
        let r = at(self.rapto);
        let feed = self.feed.unwrap_or(feed_in_force);
        let mut here = from;
        let mut out_of_range = false;
        let mut go = |kind: MotionKind, to: Point3<f64>, out: &mut Vec<Block>| {
            if !to.iter().all(|v| v.is_finite()) {
                out_of_range = true;
                return;
            }
            if here.is_some_and(|h| (h - to).norm() < SAME_POINT) {
                return;
            }
            out.push(motion_block(stmt.span, kind, to, axis, feed));
            here = Some(to);
        };
        go(MotionKind::Rapid, clear, out);
        go(MotionKind::Rapid, r, out);
        // Peck depths, measured from P.
        let mut pecks = Vec::new();
        if matches!(self.kind, Kind::Deep | Kind::ChipBreak)
            && let Some(first) = self.first_peck.filter(|f| *f > 0.0)
        {
            let step = self.sub_peck.filter(|s| *s > 0.0).unwrap_or(first);
            let mut d = first;
            while d < self.depth && pecks.len() < MAX_PECKS {
                pecks.push(d);
                d += step;
            }
            if pecks.len() >= MAX_PECKS {
                diags.push(
                    stmt.locate_all(Diagnostic::warning(
                        "cl::cycle-pecks",
                        format!("the cycle needs over {MAX_PECKS} pecks; the hole is drilled in one feed"),
                    ))
                    .with_help("check the CYCLE peck depths"),
                );
                pecks.clear();
            }
        }
        let back_off = options.peck_clearance.max(0.0).min(self.rapto.max(0.0));
        for d in pecks {
            go(MotionKind::Linear, at(-d), out);
            match self.kind {
                Kind::Deep => {
                    go(MotionKind::Rapid, r, out);
                    go(MotionKind::Rapid, at(back_off - d), out);
                }
                _ => go(MotionKind::Rapid, at(back_off - d), out),
            }
        }
        go(MotionKind::Linear, at(-self.depth), out);
        if self.dwell > 0.0 {
            out.push(Block::new(
                stmt.span,
                BlockKind::Dwell {
                    seconds: self.dwell,
                },
            ));
        }
        if self.kind == Kind::FeedOut {
            go(MotionKind::Linear, r, out);
        }
        go(MotionKind::Rapid, clear, out);
        if out_of_range {
            diags.push(
                stmt.locate_all(Diagnostic::error(
                    "cl::bad-number",
                    "the drilling cycle reaches points out of range here",
                ))
                .with_help("check the CYCLE depth and heights and the point"),
            );
        }
        here.unwrap_or(p)
    }
}
