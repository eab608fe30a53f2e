//! APT CL data frontend (`--from cl`; files `.cl`, `.apt`, `.cls`, `.clsf`).
//!
//! Reads cutter-location data as APT postprocessors get it from CAM systems: APT/ISO 4343
//! CL statements, APT++ (CAMWorks) output, NX CLSF listings and the triplet format (a
//! point line, a tool axis line and a hexadecimal motion code per move, recognised by
//! its content). Every motion becomes a [`Pose`](crate::ir::Pose) target: the tool tip
//! in millimetres in the part frame and the unit tool axis.
//!
//! # Statements
//!
//! | CL | IR |
//! |---|---|
//! | `GOTO/x,y,z[,i,j,k]`, a further line `x,y,z` after a `GOTO` | linear move (rapid after `RAPID`) |
//! | `FROM/x,y,z[,i,j,k]` | rapid move (the start point) |
//! | `GODLTA/dx,dy,dz[,i,j,k]`, `GODLTA/d` (along the tool axis) | move relative to the current point |
//! | `RAPID`, `RAPID/` | the next motion only is rapid |
//! | `FEDRAT/f[,unit]`, `FEDRAT/unit,f` | feed of the motions that follow (`MMPM`, `IPM` ×25.4, `MMPR`/`IPR` per revolution; without a unit: the program's length unit and the last mode) |
//! | `TLAXIS/i,j,k`, the `i,j,k` of a point statement | tool axis of this and later motions |
//! | `MULTAX[/ON]`, `MULTAX/OFF` | a tool axis on a point under `MULTAX/OFF` is used, with one warning |
//! | `UNITS/MM`, `UNITS/INCHES` (`UNIT/`, `INCHES`, `METRIC`) | length unit of the values that follow |
//! | `CIRCLE`, `MOVARC` + next `GOTO` | straight pieces along the arc ([`Options::arc_tolerance`]) |
//! | `CYCLE/DRILL,...` (`FACE`, `DEEP`, `DEEP2`, `BRKCHP`, `REAM`, `BORE`) … `CYCLE/OFF` | the holes' motions (see below) |
//! | `SPINDL/rpm[,RPM][,CLW]` (or `CCLW`), `SPINDL/ON`, `SPINDL/OFF` | command `M3 S…` / `M4 S…` / `M5` |
//! | `COOLNT/ON`, `COOLNT/FLOOD`, `COOLNT/MIST`, `COOLNT/OFF` | command `M8` / `M7` / `M9` |
//! | `LOADTL/n[,...]`, `LOAD/TOOL,n[,...]` | command `T<n>` (the statement as a comment when it says more) |
//! | `DELAY/s`, `DELAY/REV,n` | dwell |
//! | `END`, `FINI`, `STOP`, `OPSTOP` | command [`Options::end_command`] (`M0`), [`Options::fini_command`] (`M2`), `M0`, `M1` |
//! | `$$ text`, `PPRINT text` | comment |
//! | `NURBS/[DEGREE,d]`, `KNOT/u,...`, `CNTRL/x,y,z[,w][,i,j,k]` (NX) | straight pieces along the spline ([`Options::arc_tolerance`]) |
//! | `MSYS/x,y,z,i1,j1,k1,i2,j2,k2` (NX) | comment; applied to the points under [`Options::msys`] `apply` |
//! | `PARTNO`, `INSERT`, `CUTTER`, `CUTCOM`, `CSYS`, `TOOL PATH`, `TLDATA`, `PAINT`, `END-OF-PATH`, `TRNTYP`, `SELECT`, NX listing header lines | comment (the statement as written) |
//! | anything else | comment, with a warning |
//!
//! `$` at the end of a line continues the statement on the next line (a `$$` comment may
//! follow the `$`); the block's span covers all its lines. Malformed statements (a bad
//! number, a wrong count of values, a zero axis vector) are errors with line and column,
//! and reading goes on with the next statement.
//!
//! # Reading
//!
//! Lines become statements in `source` (continuation, comments, the look at the start),
//! statements become tokens in [`lexer`] (logos) and major words and arguments in `read`
//! (the statement grammar, in one pass), and `lower` turns them into blocks with the
//! program's modal state. Every statement takes this one path; numbers are read by
//! [`crate::num::parse_decimal`].
//!
//! # Choices
//!
//! - **Units.** With [`Options::units`] `auto`, a program that names no unit before its
//!   first feed with a unit word is read in the unit of that feed (NX CLSF listings in
//!   inches say `FEDRAT/IPM,10` and nothing else), with a warning; otherwise
//!   millimetres. The look ahead is bounded (4096 lines, 1 MiB).
//! - **CIRCLE.** `CIRCLE/x,y,z,i,j,k,r`: centre, axis, radius; the arc runs
//!   counter-clockwise about the axis (right-hand rule), from the current point to the
//!   next `GOTO` point (APT, Creo). `CIRCLE/x,y,z,i,j,k` (six values, APT++/CAMWorks):
//!   the same without the radius, which is the start point's distance from the axis; the
//!   corpus (`aptpp_*.apt`) has arcs whose lines meet them tangentially only with this
//!   reading, and a start equal to the end is a full circle. `CIRCLE/x,y,z,i,j,k,r,t,f,d,e`
//!   (eight to eleven values, NX CLSF: tolerance, in-tolerance ratio, tool diameter and
//!   corner radius follow): NX gives the axis "assuming a clockwise direction", so the arc
//!   runs clockwise about it (every arc of `mech491_APT_*.txt` is tangent to its lines
//!   only so). `,TIMES,n` adds n full turns (helical entries). `MOVARC/x,y,z,i,j,k,r
//!   [,ANGLE,a]` and `MOVARC/CENTER,x,y,z,AXIS,i,j,k[,RADIUS,r]` follow the right-hand
//!   rule; `ANGLE` counts full turns. An arc whose points are off its radius by more than
//!   [`Options::radius_tolerance`] (plus 0.1 %) becomes a straight move with a warning.
//! - **CSYS** is not applied to the points (warning when it is not the identity): in the
//!   corpus the points after a tilted `CSYS` already carry the tilted tool axis in the
//!   base frame. Its Z column becomes the current tool axis: APT++ writes 3-value GOTOs
//!   only under a CSYS whose Z column is +Z (so a drilling operation after a tilted one
//!   is vertical again) and 6-value GOTOs with the Z column as their axis otherwise.
//!   A CSYS that rotates carries the note [`crate::ir::FRAME_NOT_APPLIED`].
//! - **MSYS**: NX writes points and tool axes in the MCS it names. By default they are used
//!   as written, as NX's postprocessors print them (one warning when the MSYS is not the
//!   identity; a rotating one carries the note [`crate::ir::FRAME_NOT_APPLIED`]); with
//!   [`Options::msys`] `apply` they become `origin + R p` and `R a` (R: the MCS axes as
//!   columns) and the tool axis in force becomes the MCS Z axis.
//! - **NURBS**: see the `spline` module: the records up to the next other statement make
//!   one spline, checked, evaluated and cut within [`Options::arc_tolerance`]; one that
//!   cannot be evaluated is an error at its `NURBS/` line.
//! - **CYCLE**: each `GOTO` between a drilling `CYCLE` and `CYCLE/OFF` is the top point
//!   P of a hole, T the tool axis, and the values are distances from P along T (as
//!   APT++ writes them: the `GOTO` before the cycle is P + RTRCTO·T). The hole: rapid to
//!   P + RTRCTO·T (RAPTO when there is no RTRCTO), rapid to P + RAPTO·T, feed to
//!   P − FEDTO·T (at the cycle's `MMPM`/`IPM`/`MMPR`/`IPR` feed, else the feed in force),
//!   `DWELL` seconds, rapid back to P + RTRCTO·T; `REAM` and `BORE` feed out to RAPTO
//!   first. `DEEP`/`DEEP2` peck (`1STPECK`, then `SUBPECK`) with a full retract to RAPTO
//!   and a rapid back to [`Options::peck_clearance`] above the last depth; `BRKCHP` only
//!   backs off by that clearance. Plain numbers after the type are the depth and the
//!   clearance (ISO 4343 `CYCLE/DRILL,d,IPM,f,c`). `CYCLE/INIT` does nothing,
//!   `CYCLE/ON` resumes the last cycle. Other types (tapping, ...) warn and pass through
//!   as comments; the `GOTO`s inside then move to the written points.
//! - **END** is ISO 4343's end of a program section, a program stop: `M0` by default.
//!   **FINI** ends the program: `M2` by default, not `M30`, which RepRapFirmware reads as
//!   "delete file". Both are options.
//! - **CUTCOM** is passed through; the points are the tool position (one warning).

pub mod ast;
pub mod lexer;

mod arc;
mod cycle;
mod lower;
mod motion;
mod options;
mod read;
mod source;
mod spline;

use std::io::BufRead;

use crate::diag::Diagnostic;
use crate::front::Frontend;
use crate::ir::Block;

pub use crate::front::gcode::Program;
pub use options::{Msys, Options, Units};

/// Streaming CL frontend over any buffered reader; memory stays bounded (lines, one
/// statement, a bounded look at the start, arcs handed out piece by piece).
///
/// ```
/// use ncpost::front::{Frontend, cl::{Parser, Options}};
/// let src = "FEDRAT/300,MMPM\nGOTO/0,0,10\nGOTO/10,0,0\n";
/// let mut parser = Parser::new(src.as_bytes(), Options::default());
/// let mut diags = Vec::new();
/// let mut count = 0;
/// while let Some(_block) = parser.next_block(&mut diags) {
///     count += 1;
/// }
/// assert_eq!(count, 2);
/// assert!(diags.is_empty());
/// ```
pub struct Parser<R> {
    source: source::Source<R>,
    lower: lower::Lowerer,
    stmt: source::Statement,
    /// Blocks lowered but not yet handed out by `next_block`, in reverse order.
    pending: Vec<Block>,
    started: bool,
    done: bool,
    /// `stmt` ended a spline and waits until the spline's pieces are handed out.
    held: bool,
}

impl<R: BufRead> Parser<R> {
    /// A parser reading from `input`.
    pub fn new(input: R, options: Options) -> Self {
        Parser {
            source: source::Source::new(input, options.max_line_len),
            lower: lower::Lowerer::new(options),
            stmt: source::Statement::default(),
            pending: Vec::new(),
            started: false,
            done: false,
            held: false,
        }
    }

    /// Reads statements until `out` holds at least `want` blocks or the input ends.
    fn read_into(&mut self, out: &mut Vec<Block>, want: usize, diags: &mut Vec<Diagnostic>) {
        if !self.started {
            self.started = true;
            let probe = self.source.probe(diags);
            self.lower.begin(probe, diags);
        }
        while out.len() < want {
            if self.lower.expanding() {
                self.lower.expand(out, want - out.len());
                continue;
            }
            if std::mem::take(&mut self.held) {
                self.lower.statement(&self.stmt, out, diags);
                continue;
            }
            if self.done {
                break;
            }
            let join = !self.lower.is_triplet();
            if self.source.next_statement(&mut self.stmt, join, diags) {
                // A statement after a NURBS's records comes after its pieces.
                self.held = self.lower.closes_spline(&self.stmt, diags);
                if !self.held {
                    self.lower.statement(&self.stmt, out, diags);
                }
                continue;
            }
            self.done = true;
            let counts = self.source.counts;
            diags.extend(counts.empty_error("cl::empty", "CL statement or comment"));
            self.lower.finish(diags);
        }
    }
}

impl<R: BufRead> Frontend for Parser<R> {
    fn next_block(&mut self, diags: &mut Vec<Diagnostic>) -> Option<Block> {
        if self.pending.is_empty() {
            let mut blocks = std::mem::take(&mut self.pending);
            self.read_into(&mut blocks, 1, diags);
            blocks.reverse();
            self.pending = blocks;
        }
        self.pending.pop()
    }

    fn next_batch(&mut self, out: &mut Vec<Block>, max: usize, diags: &mut Vec<Diagnostic>) {
        while let Some(b) = self.pending.pop() {
            out.push(b);
        }
        self.read_into(out, max, diags);
    }

    fn bytes_read(&self) -> u64 {
        self.source.bytes_read()
    }
}

/// Parses and lowers a whole CL program held in memory.
///
/// Returns `Err` with every diagnostic when any of them is an error.
///
/// ```
/// use ncpost::front::cl::{parse_str, Options};
/// let program = parse_str("UNITS/INCHES\nGOTO/1,0,0\n", &Options::default()).unwrap();
/// assert_eq!(program.blocks.len(), 1);
/// assert!(parse_str("GOTO/1,2\n", &Options::default()).is_err());
/// ```
pub fn parse_str(src: &str, options: &Options) -> Result<Program, Vec<Diagnostic>> {
    let mut parser = Parser::new(src.as_bytes(), options.clone());
    let mut blocks = Vec::new();
    let mut diagnostics = Vec::new();
    while let Some(b) = parser.next_block(&mut diagnostics) {
        blocks.push(b);
    }
    if diagnostics.iter().any(Diagnostic::is_error) {
        Err(diagnostics)
    } else {
        Ok(Program {
            blocks,
            diagnostics,
        })
    }
}
