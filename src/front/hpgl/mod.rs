//! HPGL frontend (`--from hpgl`; files `.hpgl`, `.hpg`, `.plt`): pen plots become milling moves.
//!
//! Reads the HPGL that EAGLE (`mill-outlines`, the HPGL CAM driver), KiCad and plotter
//! software write, and turns the pen into a cutter, as the PCB mill of seed 001 did:
//! pen up is a retract to a safe height, pen down a plunge to the cutting depth at the
//! plunge feed, then cutting at the cut feed. Coordinates are plotter units, 40 per mm
//! ([`Options::units_per_mm`]), so `PA400,800` is X10 Y20.
//!
//! # Commands
//!
//! | HPGL | milling program |
//! |---|---|
//! | `PU [x,y,...]` | lift: retract to `safe_z` (`G0`); the points are pen-up travel (consecutive ones merge into one `G0 X Y`) |
//! | `PD [x,y,...]` | pen down: at the first move, `G0` to the point, `G0 Z approach_z`, `G1 Z-cut_depth F plunge_feed`, then `G1 X Y F cut_feed` per point |
//! | `PD` then `PU` without moving (a drill mark) | a hole: `G1 Z-drill_depth F plunge_feed` and back up |
//! | `PA`, `PR` [x,y,...] | absolute / relative mode, and moves in the pen's state |
//! | `SP n` | pen `n` is tool `n`: retract, `M5`, [`Options::tool_change`] (`T{n} M6`); the spindle starts again (`M3 S…`) before the next cut. `SP0` (no pen) stops the spindle |
//! | `CI r[,chord]` | a full circle about the pen (G3, `r` < 0 starts at 180°), always cut, then back to the centre with the pen in its former state |
//! | `AA x,y,a[,chord]`, `AR dx,dy,a[,chord]` | an arc (G3 for `a` > 0, G2 below) about the centre; cut with the pen down, a travel with it up |
//! | `IN` | initialise: pen up, absolute, no scaling |
//! | `IP p1x,p1y[,p2x,p2y]`, `SC ...` | user units: `SC xmin,xmax,ymin,ymax[,type[,left,bottom]]` maps onto P1..P2 (type 0 anisotropic, 1 isotropic, 2 point factor `xmin,fx,ymin,fy`). `SC` without an `IP` is not applied (the default P1/P2 depend on the plotter), with a warning |
//! | `PM0`/`PM1`/`PM2` (polygon mode) | the polygon's edges are cut as they are defined, each subpolygon closed; `EP`/`FP` then add nothing (warning) |
//! | `LT` | solid lines only (a warning for dashed types); `VS` is ignored (feeds come from the options) |
//! | `LB text` | not cut: a comment, with a warning; `DT` sets its terminator |
//! | `CO "text"` | a comment |
//! | page, pen width, fill and text settings (`BP`, `PG`, `WU`, `PW`, `TR`, `LA`, `FT`, `SI`, ...) | a comment |
//! | anything else (`RO`, `DF`, `PE`, ...) | a comment, with one warning per command name |
//!
//! At the end of the input the pen lifts, the last pen-up travel is made, the spindle
//! stops (`M5`) and [`Options::end_command`] (`M2`) ends the program.
//!
//! # Syntax
//!
//! A command is two letters, case-insensitive, then numbers separated by commas or
//! blanks, ended by `;`, by the next command's letters or by the end of the input; line
//! breaks may come anywhere between numbers and commands (so files with and without
//! terminators, one command per line or all on one line, read alike). Bad numbers,
//! empty parameters, odd coordinate counts and stray characters are errors with line
//! and column; reading goes on with the next command so one run reports them all.
//!
//! # Limits
//!
//! - Printer-driver wrappers around HP-GL/2 (PCL/PJL escape sequences such as
//!   `ESC%-12345X`, `@PJL` lines) are not skipped: they are errors. Strip them first.
//! - `PE` (polyline encoded), `RO` (rotate), `DF` and other HP-GL/2 commands are not
//!   interpreted: they pass as comments with a warning, so a plot that relies on them
//!   is cut differently than it would be drawn.
//! - The chord angle of `CI`/`AA`/`AR` is ignored: arcs are exact G2/G3 (use
//!   `linearize-arcs` for chords).
//!
//! # Memory
//!
//! Streaming: one command at a time (at most [`Options::max_command_len`] bytes, so a
//! long `PD` list is fine), one held-back pen-down point and one pending travel.

mod lower;
mod reader;

use std::collections::VecDeque;
use std::io::BufRead;

use serde::{Deserialize, Serialize};

use crate::diag::Diagnostic;
use crate::front::Frontend;
use crate::ir::Block;

pub use crate::front::gcode::Program;

/// Frontend options: how the pen becomes a cutter. The defaults are the seed's PCB
/// mill (seed 001, 2006-12-27 and -29 cutting tables): 0.06 mm deep at F70, plunging
/// at F20, 4600 rpm, 1.55 mm deep holes; `safe_z` 1 and `approach_z` 0.1 are the
/// heights of the seed's own NC code (`G00 Z1` / `G00 Z0.1` / `G01 Z-0.06 F20`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Plotter units per millimetre (HPGL: 40, one unit is 0.025 mm).
    pub units_per_mm: f64,
    /// Cutting depth below Z0 for pen-down strokes, mm (positive).
    pub cut_depth: f64,
    /// Depth below Z0 of the hole a drill mark becomes, mm (positive).
    pub drill_depth: f64,
    /// Height for pen-up travel, mm.
    pub safe_z: f64,
    /// Height the tool drops to rapidly before a plunge, mm (at most `safe_z`).
    pub approach_z: f64,
    /// Feed for plunges and holes, mm/min.
    pub plunge_feed: f64,
    /// Feed for cutting, mm/min.
    pub cut_feed: f64,
    /// Spindle speed for `M3 S…` before the first cut (and after each tool change);
    /// 0 writes no spindle commands.
    pub spindle_rpm: f64,
    /// The command for `SP n` (`{n}` is the pen number); empty writes a comment.
    pub tool_change: String,
    /// The command that ends the program; empty writes none.
    pub end_command: String,
    /// Longest command accepted, bytes; a longer one is an error and is skipped.
    pub max_command_len: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            units_per_mm: 40.0,
            cut_depth: 0.06,
            drill_depth: 1.55,
            safe_z: 1.0,
            approach_z: 0.1,
            plunge_feed: 20.0,
            cut_feed: 70.0,
            spindle_rpm: 4600.0,
            tool_change: "T{n} M6".into(),
            end_command: "M2".into(),
            max_command_len: 1 << 20,
        }
    }
}

impl Options {
    /// Checks the values: positive scale and feeds, depths and heights in order. The
    /// error is `hpgl::options`, reported before anything is read.
    ///
    /// ```
    /// use ncpost::front::hpgl::Options;
    /// assert!(Options::default().check().is_ok());
    /// let bad = Options { units_per_mm: 0.0, ..Options::default() };
    /// assert_eq!(bad.check().unwrap_err().code, "hpgl::options");
    /// ```
    pub fn check(&self) -> Result<(), Diagnostic> {
        self.problem().map_or(Ok(()), |e| {
            Err(
                Diagnostic::error("hpgl::options", format!("HPGL frontend options: {e}"))
                    .with_help("fix [hpgl_input] in the preset"),
            )
        })
    }

    /// What is wrong with the values, if anything.
    fn problem(&self) -> Option<&'static str> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if !pos(self.units_per_mm) {
            return Some("units_per_mm must be a number > 0");
        }
        if !pos(self.plunge_feed) || !pos(self.cut_feed) {
            return Some("plunge_feed and cut_feed must be numbers > 0");
        }
        if !(self.cut_depth.is_finite() && self.drill_depth.is_finite()) {
            return Some("cut_depth and drill_depth must be numbers");
        }
        if !(self.safe_z.is_finite() && self.approach_z.is_finite()) {
            return Some("safe_z and approach_z must be numbers");
        }
        if self.approach_z > self.safe_z {
            return Some("approach_z must not be above safe_z");
        }
        if -self.cut_depth >= self.approach_z || -self.drill_depth >= self.approach_z {
            return Some(
                "the cut (Z = -cut_depth) and hole (Z = -drill_depth) bottoms must be below \
                 approach_z",
            );
        }
        if !(self.spindle_rpm.is_finite() && self.spindle_rpm >= 0.0) {
            return Some("spindle_rpm must be a number >= 0");
        }
        if self.tool_change.contains('\n') || self.end_command.contains('\n') {
            return Some("tool_change and end_command are one line each");
        }
        if self.max_command_len < 16 {
            return Some("max_command_len must be at least 16");
        }
        None
    }
}

/// Streaming HPGL frontend over any buffered reader.
///
/// ```
/// use ncpost::front::{Frontend, hpgl::{Parser, Options}};
/// let src = "IN;SP1;PU400,800;PD800,800;PU;";
/// let mut parser = Parser::new(src.as_bytes(), Options::default());
/// let mut diags = Vec::new();
/// let mut blocks = Vec::new();
/// while let Some(b) = parser.next_block(&mut diags) {
///     blocks.push(b);
/// }
/// assert!(diags.is_empty());
/// let text = ncpost::back::gcode::write_string(&blocks, &Default::default()).unwrap();
/// assert!(text.contains("G0 X10 Y20\n"));
/// assert!(text.contains("G1 Z-0.06 F20\nG1 X20 F70\n"));
/// ```
pub struct Parser<R> {
    reader: reader::Reader<R>,
    lower: lower::Lowerer,
    pending: VecDeque<Block>,
    options_error: Option<Diagnostic>,
    started: bool,
    done: bool,
}

impl<R: BufRead> Parser<R> {
    /// A parser reading from `input`.
    pub fn new(input: R, options: Options) -> Self {
        Parser {
            reader: reader::Reader::new(input, options.max_command_len.max(16)),
            options_error: options.check().err(),
            lower: lower::Lowerer::new(options),
            pending: VecDeque::new(),
            started: false,
            done: false,
        }
    }

    /// Lowers commands until some blocks are pending or the input ends.
    fn fill(&mut self, diags: &mut Vec<Diagnostic>) {
        if !self.started {
            self.started = true;
            if let Some(e) = self.options_error.take() {
                diags.push(e);
                self.done = true;
                return;
            }
        }
        let mut out = Vec::new();
        while out.is_empty() && !self.done {
            match self.reader.next_command(diags) {
                Some(cmd) => self.lower.command(&cmd, &mut out, diags),
                None => {
                    self.done = true;
                    if self.reader.bytes_read() == 0 {
                        diags.push(
                            Diagnostic::error("hpgl::empty", "the input is empty")
                                .with_help("give an HPGL file with at least one command"),
                        );
                    }
                    self.lower.finish(&mut out);
                }
            }
        }
        self.pending.extend(out);
    }
}

impl<R: BufRead> Frontend for Parser<R> {
    fn next_block(&mut self, diags: &mut Vec<Diagnostic>) -> Option<Block> {
        if self.pending.is_empty() {
            self.fill(diags);
        }
        self.pending.pop_front()
    }

    fn bytes_read(&self) -> u64 {
        self.reader.bytes_read()
    }
}

/// Parses and lowers a whole HPGL plot held in memory.
///
/// Returns `Err` with every diagnostic when any of them is an error.
///
/// ```
/// use ncpost::front::hpgl::{parse_str, Options};
/// let program = parse_str("PU0,0;PD40,0;PU;", &Options::default()).unwrap();
/// assert!(program.blocks.len() > 3);
/// assert!(parse_str("PA1,2,3;", &Options::default()).is_err());
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
