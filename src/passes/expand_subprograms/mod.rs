//! `expand-subprograms`: inlines Fanuc `M98 P<n> L<count>` / `O<n> ... M99` subprograms and
//! LinuxCNC `o<n> call` / `o<n> sub ... o<n> endsub` subroutines without arguments.
//!
//! # What it does
//! Each call is replaced by its subprogram body, lowered to IR exactly as the G-code
//! frontend lowers the main program, in the caller's state at the call: units (G20/G21),
//! distance mode (G90/G91), M82/M83, plane, motion mode, feed and feed mode, G92 offsets
//! and the current position. `L<count>` repeats the body (each repetition starts where the
//! last one left the machine, so a G91 body steps on). Bodies may call further
//! subprograms, nested up to `max_depth` levels (a call from the main program is level 1).
//! Definitions that are expanded everywhere are left out of the output; a program with no
//! call left is plain G-code that any controller runs (Grbl, for instance).
//!
//! Fanuc program numbers are numbers: `M98 P0002` calls `O2` or `O0002` (a second
//! definition of the same number is a warning and the first one wins, as LinuxCNC does).
//! Subprograms may stand anywhere after the main program (usually after `M30`), the
//! LinuxCNC subroutines anywhere in the file.
//!
//! RepRapFirmware's `M98 P"homeall.g"` (a quoted file name) runs a macro file from the
//! controller's SD card: it is no subprogram of this file and passes through unchanged,
//! without starting the buffering below. The pipeline runs this pass by default for
//! Grbl and RepRapFirmware, neither of which has numbered subprograms inside one file.
//!
//! # Errors (pointing at the call's line and column)
//! - `subprograms::missing`: the called program is not defined in the file.
//! - `subprograms::recursion`: a program calls itself, directly or through others.
//! - `subprograms::depth`: calls nest deeper than `max_depth` (default 10).
//! - `subprograms::count`: `L` is not a whole number from 0 to `max_count` (default
//!   9999, Fanuc's range). `L0` skips the call, as LinuxCNC does, with the note
//!   `subprograms::skipped` (the program must still exist).
//! - `subprograms::size`: the expansion would produce more than `max_blocks` blocks. The
//!   blocks a call makes (its body's blocks times its repeat count, nested calls
//!   counted the same way) are counted before it is expanded, so a nest of large
//!   repeat counts is refused at its call line without being built.
//! - `subprograms::modes`: a subprogram called from the main program leaves units,
//!   extruder mode or feed mode different from those it was called in. The frontend read
//!   the lines after the call in the old ones, so their meaning would be wrong; end the
//!   subprogram in the modes it started in. Reported only when a line after the call,
//!   before the next call, depends on those modes (a move, a G92, a line passed through
//!   in its modes): `M98 P1 L3` followed by `M30` alone is fine, whatever modes O1
//!   leaves. (Calls inside bodies are exact: the lines after them are lowered here, in
//!   the modes the call left.) A different plane is a warning. The distance and motion
//!   modes a body leaves are followed instead, as LinuxCNC and Fanuc keep them after
//!   `M99`: the frontend copies the lines after a call that move (or set modes) before
//!   restating both G90/G91 and G0/G1/G2/G3 (or a cycle), and this pass reads them
//!   again in the modes the body left (a bare `X5` after a G91 body moves 5 on; after a
//!   body that left a canned cycle it drills, the series going on, with its initial
//!   level, across the call). A line it cannot read again is this error at the line (a
//!   bare `X5` after a body that left `G2` is an arc without a centre). A G91 body
//!   followed by a command with coordinates (`G28 X0`) before any move is this error at
//!   the call.
//! - `subprograms::no-m99`: a Fanuc subprogram runs to the end of the file.
//! - `subprograms::return`: `o<n> return` (an early return) cannot be inlined.
//!
//! # Warnings; calls that pass through
//! A call with arguments (`o100 call [1] [2]`), an expression (`o[#2*10] call`,
//! `M98 P[#1]`) or inside o-word control flow (`o1 if ...`) cannot be expanded without
//! evaluating the program: it passes through unchanged with the warning
//! `subprograms::not-expanded`, and the definitions it may reach stay in the output.
//! The G-code frontend, which cannot know that this pass follows it, warns that o-word
//! calls and subroutines and Fanuc subprograms pass through unchanged
//! (`gcode::control-flow`, `gcode::subprogram`); the pass takes those warnings back on
//! the lines it handles, so only what it really leaves in the output is warned about.
//! `M99` in the main program (an endless loop on the controller) passes through with
//! `subprograms::main-m99`. An unused definition is left out with `subprograms::unused`.
//!
//! # How (and what is buffered)
//! The frontend reads the main program once, streaming; it cannot know the bodies (Fanuc
//! puts them after `M30`). It records on every call the modes in force
//! ([`crate::ir::Command::modes`], [`crate::ir::Verbatim::modes`]) and treats positions and
//! the modal feed as unknown after the call. This pass streams blocks unchanged until the
//! first block that has to do with subprograms (a call, `M99`, a body or a definition);
//! from there on it **buffers every block to the end of the input** (a program with
//! subprograms is held in memory once; programs without them stream). At the end it
//! collects the definitions and replays the buffer: a call is replaced by its body, lowered
//! with the frontend's own lowerer (reached through [`lower::Lowering`], which the pipeline
//! provides) started in the caller's state; the state the body leaves becomes the state after the call, and the
//! blocks after it are completed from it: axes the frontend left unknown get their known
//! values, moves without a feed of their own get the feed the body left in force, and if
//! the body changed G92 offsets, the following targets and offsets are corrected by the
//! difference (`target = frontend target + frontend offset - real offset`).
//!
//! The caller's motion mode, feed and feed mode are taken from the last move before the
//! call (an `F` or `G93` on a line of its own right before the call is not seen; give it
//! on a move or in the body); `G90.1` arc centres are not carried into bodies.
//! A move after a call that is relative from a position the frontend did not know passes
//! through as written (the frontend's `gcode::relative-unknown` warning).
//!
//! # Options
//! - `max_depth` (10): deepest nesting of calls.
//! - `max_count` (9999): largest `L` repeat count.
//! - `max_blocks` (10000000): most blocks the expansion may produce.
//! - `packed_count` (false): read `M98 P50010` (no `L`, more than 4 digits) as 5 times
//!   `O0010`, the Fanuc 0i/16i packed form. Off by default because LinuxCNC reads it as
//!   program 50010; a missing program whose packed reading exists says so in its help.
//! - `[input]`: the G-code frontend options the bodies are lowered with (the pipeline
//!   fills in the preset's `gcode_input`).

mod calls;
mod defs;
mod expand;
pub mod lower;
mod main;
mod size;

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Block, BlockKind, Span};
use calls::main_call;
use defs::{collect_definitions, subprogram_related};
use expand::{Expander, Site};
use lower::{Lowering, Relower};
use main::MainState;

/// Options of `expand-subprograms`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Deepest nesting of calls (a call from the main program is level 1).
    pub max_depth: u32,
    /// Largest `L` repeat count.
    pub max_count: u32,
    /// Most blocks the expansion may produce.
    pub max_blocks: u64,
    /// Read `M98 P<count><4-digit program>` (no `L`) as the Fanuc packed form.
    pub packed_count: bool,
    /// Frontend options the bodies are lowered with: the fields of `[gcode_input]`, over
    /// the preset's `[gcode_input]` (the pipeline fills them in).
    pub input: toml::Table,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_depth: 10,
            max_count: 9999,
            max_blocks: 10_000_000,
            packed_count: false,
            input: toml::Table::new(),
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "expand-subprograms",
    summary: "inline Fanuc M98/M99 subprograms (L repeats, nested) and LinuxCNC o-word subroutines",
    build: |t, ctx| {
        Ok(Box::new(ExpandSubprograms::new(
            super::options(t)?,
            ctx.relower,
        )?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// A program name: Fanuc numbers and o-word labels are separate name spaces.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum Key {
    Fanuc(u32),
    Oword(String),
}

impl Key {
    fn name(&self) -> String {
        match self {
            Key::Fanuc(n) => format!("O{n}"),
            Key::Oword(l) => format!("o{l}"),
        }
    }
}

/// A subprogram definition.
#[derive(Debug)]
struct Def {
    /// Body lines (Fanuc: the `M99` word removed from the last one) and their spans.
    lines: Vec<(String, Span)>,
    /// Indices of the blocks of the definition in the buffer (header to end).
    blocks: std::ops::Range<usize>,
    /// An `o<n> return` line in the body, if any: (text, span, byte range).
    early_return: Option<(String, Span, (usize, usize))>,
}

/// What a call line asks for.
#[derive(Debug)]
enum Call {
    /// Expand `key` `count` times.
    Expand {
        key: Key,
        count: u32,
        at: (usize, usize),
    },
    /// Cannot be expanded: passes through with this warning; may reach these programs.
    Opaque { warning: Diagnostic, reach: Reach },
    /// A bad call (count, missing P): an error.
    Bad(Diagnostic),
}

/// The definitions a call that passes through may reach.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum Reach {
    One(Key),
    AllFanuc,
    AllOword,
}

/// The `expand-subprograms` pass.
pub struct ExpandSubprograms {
    options: Options,
    /// The G-code lowerer bodies are lowered with.
    lowering: Box<dyn Lowering>,
    /// The main program's state, as the blocks so far leave it.
    main: MainState,
    /// Set at the first block that has to do with subprograms.
    buffering: bool,
    /// The last call from the main program is one this pass expands: the lines the
    /// frontend copied after it (warned [`AFTER_CALL`]) are read again here.
    expanding: bool,
    buffer: Vec<Block>,
}

impl ExpandSubprograms {
    /// A pass with `options`, lowering bodies with the lowerer `relower` makes (the
    /// pipeline's is its `gcode_relower`).
    pub fn new(options: Options, relower: Option<Relower>) -> Result<Self, Diagnostic> {
        if options.max_depth == 0 {
            return Err(Diagnostic::settings("max_depth must be at least 1"));
        }
        if options.max_count == 0 {
            return Err(Diagnostic::settings("max_count must be at least 1"));
        }
        let Some(relower) = relower else {
            return Err(Diagnostic::settings(
                "expand-subprograms needs the G-code lowerer, which the pipeline provides",
            ));
        };
        let lowering = relower(&options.input)?;
        Ok(ExpandSubprograms {
            main: MainState::new(lowering.start()),
            lowering,
            options,
            buffering: false,
            expanding: false,
            buffer: Vec::new(),
        })
    }
}

impl ExpandSubprograms {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        if !self.buffering && subprogram_related(&block) {
            self.buffering = true;
        }
        if self.buffering {
            self.buffer.push(block);
        } else {
            if let Some(b) = self.main.block(block, &*self.lowering, out.diags) {
                out.push(b);
            }
        }
    }
}

/// The frontend's warnings that a subprogram, an o-word call or definition passes through
/// unchanged: true without this pass, and taken back by it on the lines it handles.
const FRONTEND_NOTICES: [&str; 2] = ["gcode::subprogram", "gcode::control-flow"];

/// Takes back the frontend's warnings ([`FRONTEND_NOTICES`]) on the lines of `blocks` this
/// pass handles (calls, definitions): the frontend cannot know that the pass follows.
/// What the pass cannot expand it reports itself (`subprograms::not-expanded`).
fn take_back_notices(blocks: &[Block], diags: &mut Vec<Diagnostic>) {
    if !diags.iter().any(|d| FRONTEND_NOTICES.contains(&d.code)) {
        return;
    }
    let handled: std::collections::HashSet<u32> = blocks
        .iter()
        .filter(|b| subprogram_related(b))
        .map(|b| b.span.line)
        .collect();
    diags.retain(|d| {
        !(FRONTEND_NOTICES.contains(&d.code)
            && d.location
                .as_ref()
                .is_some_and(|l| handled.contains(&l.line)))
    });
}

/// The frontend's warning on a line it copied after a call because the call left its
/// distance or motion mode unknown: true without this pass, taken back on the lines after
/// a call it expands (it reads them again in the modes the body left).
const AFTER_CALL: &str = "gcode::after-call";

impl ExpandSubprograms {
    /// Takes back the frontend's [`AFTER_CALL`] warnings on the lines of `blocks` that
    /// follow a call this pass expands, and remembers those lines: one it cannot read
    /// again is an error then.
    fn take_back_after_call(&mut self, blocks: &[Block], diags: &mut Vec<Diagnostic>) {
        let mut lines = Vec::new();
        for b in blocks {
            if subprogram_related(b) {
                match main_call(b, &self.options, &*self.lowering) {
                    Some((Call::Expand { .. }, _)) => self.expanding = true,
                    Some(_) => self.expanding = false,
                    None => {}
                }
            } else if self.expanding && matches!(b.kind, BlockKind::Verbatim(_)) {
                lines.push(b.span.line);
            }
        }
        if lines.is_empty() {
            return;
        }
        diags.retain(|d| {
            let line = d.location.as_ref().map(|l| l.line);
            let taken = d.code == AFTER_CALL && line.is_some_and(|l| lines.contains(&l));
            if let Some(l) = line.filter(|_| taken) {
                self.main.reread.insert(l);
            }
            !taken
        });
    }
}

impl Pass for ExpandSubprograms {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        take_back_notices(blocks, out.diags);
        self.take_back_after_call(blocks, out.diags);
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        let blocks = std::mem::take(&mut self.buffer);
        if blocks.is_empty() {
            return;
        }
        let mut diags = Vec::new();
        let (defs, owner) = collect_definitions(&blocks, &mut diags);
        let mut ex = Expander::new(&defs, &self.options, &*self.lowering);
        for d in diags {
            ex.report(d);
        }
        let (expanded, def_at) = replay(&mut self.main, &blocks, &owner, &mut ex);
        ex.put_out(&blocks, expanded, &def_at, out);
    }
}

/// The buffered main program with its calls expanded, and the places (in it) where the
/// definitions stood.
fn replay(
    main: &mut MainState,
    blocks: &[Block],
    owner: &[Option<Key>],
    ex: &mut Expander<'_>,
) -> (Vec<Block>, Vec<(usize, Key)>) {
    let mut expanded: Vec<Block> = Vec::new();
    let mut def_at: Vec<(usize, Key)> = Vec::new();
    let mut i = 0;
    while i < blocks.len() {
        if let Some(key) = &owner[i] {
            let range = ex.defs[key].blocks.clone();
            // The frontend passed the definition through, forgetting the positions.
            if range.start == i {
                def_at.push((expanded.len(), key.clone()));
                main.pass_over(&blocks[range.clone()]);
                i = range.end;
            } else {
                // A duplicate definition's blocks: left out (warned about).
                main.pass_over(&blocks[i..=i]);
                i += 1;
            }
            continue;
        }
        let block = blocks[i].clone();
        i += 1;
        match main_call(&block, ex.options, ex.lowering) {
            Some((Call::Expand { key, count, at }, text)) => {
                let start = main.call_state(&block);
                let site = Site {
                    text,
                    line: block.span.line,
                    at,
                };
                let mut stack = Vec::new();
                match ex.call(&key, count, start, 1, &mut stack, &site, &mut expanded) {
                    Ok(end) => {
                        let depends = read_in_modes(blocks, owner, i, ex);
                        ex.check_modes(&key, &start, &end, &site, depends);
                        main.after_call(end);
                    }
                    Err(()) => {
                        main.opaque_call();
                        expanded.push(block);
                    }
                }
            }
            Some((Call::Opaque { warning, reach }, _)) => {
                ex.report(warning);
                ex.reached.insert(reach);
                main.opaque_call();
                expanded.extend(main.block(block, ex.lowering, &mut ex.diags));
            }
            Some((Call::Bad(d), _)) => {
                ex.report(d);
                expanded.push(block);
            }
            None => expanded.extend(main.block(block, ex.lowering, &mut ex.diags)),
        }
    }
    (expanded, def_at)
}

/// What the lines of the main program after a call (from `blocks[from]` up to its next
/// call, or its end) take from the modes the frontend read them in.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Depends {
    /// A line depends on the units, the extruder or the feed mode: a move, a G92, a line
    /// passed through with the modes it was written in (parameter assignments aside), a
    /// command with coordinates.
    pub units: bool,
    /// A command with coordinates (`G28 X0`) before the first move depends on the
    /// distance mode. (The frontend copies the moves that do not restate the distance
    /// and motion modes after a call with no modes of their own, and this pass reads them
    /// again in the modes the body left. A line with parameters or expressions keeps the
    /// modes the frontend read it in: not checked.)
    pub distance: bool,
}

/// What the lines after a call take from the modes the frontend read them in: only then
/// does a body that changed modes break them (`M98 P1` followed by `M30` alone does not).
fn read_in_modes(
    blocks: &[Block],
    owner: &[Option<Key>],
    from: usize,
    ex: &Expander<'_>,
) -> Depends {
    let mut d = Depends::default();
    let mut moved = false;
    for (block, own) in blocks.iter().zip(owner).skip(from) {
        if own.is_some() || main_call(block, ex.options, ex.lowering).is_some() {
            break;
        }
        let (units, distance) = match &block.kind {
            BlockKind::Motion(_) => {
                moved = true;
                (true, false)
            }
            BlockKind::Offset(_) => (true, false),
            BlockKind::Command(c) => (c.modes.is_some(), c.modes.is_some()),
            BlockKind::Verbatim(v) => {
                (v.modes.is_some() && !main::only_assignments(&v.text), false)
            }
            BlockKind::Dwell { .. } | BlockKind::Comment => (false, false),
        };
        d.units |= units;
        d.distance |= distance && !moved;
    }
    d
}
