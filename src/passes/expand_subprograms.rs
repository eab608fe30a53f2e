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
//! # Errors (pointing at the call's line and column)
//! - `subprograms::missing`: the called program is not defined in the file.
//! - `subprograms::recursion`: a program calls itself, directly or through others.
//! - `subprograms::depth`: calls nest deeper than `max_depth` (default 10).
//! - `subprograms::count`: `L` is not a whole number from 1 to `max_count` (default
//!   9999, Fanuc's range). `L0` is an error too (LinuxCNC skips the call; remove the line).
//! - `subprograms::size`: the expansion would produce more than `max_blocks` blocks.
//! - `subprograms::modes`: a subprogram called from the main program leaves units,
//!   distance mode, extruder mode or feed mode different from those it was called in. The
//!   frontend read the lines after the call in the old modes, so their meaning would be
//!   wrong; end the subprogram in the modes it started in. (Calls inside bodies are
//!   exact: the lines after them are lowered here, in the modes the call left.) A
//!   different plane is a warning.
//! - `subprograms::no-m99`: a Fanuc subprogram runs to the end of the file.
//! - `subprograms::return`: `o<n> return` (an early return) cannot be inlined.
//!
//! # Warnings; calls that pass through
//! A call with arguments (`o100 call [1] [2]`), an expression (`o[#2*10] call`,
//! `M98 P[#1]`) or inside o-word control flow (`o1 if ...`) cannot be expanded without
//! evaluating the program: it passes through unchanged with the warning
//! `subprograms::not-expanded`, and the definitions it may reach stay in the output.
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
//! with the frontend's own lowerer (`front::gcode::Lowerer`, crate-internal) started in the
//! caller's state; the state the body leaves becomes the state after the call, and the
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

use std::collections::{HashMap, HashSet};

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::front::gcode::{LowerState, Lowerer, MotionMode, Options as InputOptions, oword_call};
use crate::ir::{AXIS_COUNT, Axis, Block, BlockKind, MotionKind, OffsetCode, Span, Target};
use crate::num::lexer::{Tok, tokens};

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
    /// Frontend options the bodies are lowered with.
    pub input: InputOptions,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_depth: 10,
            max_count: 9999,
            max_blocks: 10_000_000,
            packed_count: false,
            input: InputOptions::default(),
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "expand-subprograms",
    summary: "inline Fanuc M98/M99 subprograms (L repeats, nested) and LinuxCNC o-word subroutines",
    build: |t, _ctx| Ok(Box::new(ExpandSubprograms::new(super::options(t)?)?)),
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
    /// The main program's state, as the blocks so far leave it.
    track: Tracker,
    /// Set at the first block that has to do with subprograms.
    buffering: bool,
    buffer: Vec<Block>,
}

impl ExpandSubprograms {
    /// A pass with `options`.
    pub fn new(options: Options) -> Result<Self, Diagnostic> {
        if options.max_depth == 0 {
            return Err(Diagnostic::settings("max_depth must be at least 1"));
        }
        if options.max_count == 0 {
            return Err(Diagnostic::settings("max_count must be at least 1"));
        }
        Ok(ExpandSubprograms {
            track: Tracker::new(&options.input),
            options,
            buffering: false,
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
            let b = self.track.block(block, out.diags);
            out.push(b);
        }
    }
}

impl Pass for ExpandSubprograms {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
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
        let mut ex = Expander {
            defs: &defs,
            options: &self.options,
            reached: HashSet::new(),
            used: HashSet::new(),
            seen: HashSet::new(),
            produced: 0,
            diags: Vec::new(),
            failed: false,
        };
        for d in diags {
            ex.report(d);
        }
        // Expanded stream, with the places where definitions stood.
        let mut expanded: Vec<Block> = Vec::new();
        let mut def_at: Vec<(usize, Key)> = Vec::new();
        let mut i = 0;
        while i < blocks.len() {
            if let Some(key) = &owner[i] {
                let range = defs[key].blocks.clone();
                if range.start == i {
                    def_at.push((expanded.len(), key.clone()));
                    i = range.end;
                } else {
                    // A duplicate definition's blocks: left out (warned about).
                    i += 1;
                }
                continue;
            }
            let block = blocks[i].clone();
            i += 1;
            match main_call(&block, &self.options) {
                Some((Call::Expand { key, count, at }, text)) => {
                    let start = self.track.call_state(&block);
                    let site = Site {
                        text,
                        line: block.span.line,
                        at,
                    };
                    let mut stack = Vec::new();
                    match ex.call(&key, count, start, 1, &mut stack, &site, &mut expanded) {
                        Ok(end) => {
                            ex.check_modes(&key, &start, &end, &site);
                            self.track.after_call(end);
                        }
                        Err(()) => expanded.push(block),
                    }
                }
                Some((Call::Opaque { warning, reach }, _)) => {
                    ex.report(warning);
                    ex.reached.insert(reach);
                    expanded.push(self.track.block(block, &mut ex.diags));
                }
                Some((Call::Bad(d), _)) => {
                    ex.report(d);
                    expanded.push(block);
                }
                None => expanded.push(self.track.block(block, &mut ex.diags)),
            }
        }
        // Definitions a call that passed through may reach stay where they were.
        let keep = |key: &Key| {
            ex.reached.contains(&Reach::One(key.clone()))
                || match key {
                    Key::Fanuc(_) => ex.reached.contains(&Reach::AllFanuc),
                    Key::Oword(_) => ex.reached.contains(&Reach::AllOword),
                }
        };
        let mut next = def_at.iter().peekable();
        for (n, b) in expanded.into_iter().enumerate() {
            while let Some((at, key)) = next.peek() {
                if *at != n {
                    break;
                }
                emit_definition(
                    &blocks,
                    &defs,
                    key,
                    keep(key),
                    ex.used.contains(key),
                    &mut ex.diags,
                    out,
                );
                next.next();
            }
            out.push(b);
        }
        for (_, key) in next {
            emit_definition(
                &blocks,
                &defs,
                key,
                keep(key),
                ex.used.contains(key),
                &mut ex.diags,
                out,
            );
        }
        for d in ex.diags {
            out.diag(d);
        }
    }
}

/// Puts a definition's blocks back in the output when a call that passed through may need
/// it; otherwise leaves it out (with a warning when nothing called it).
fn emit_definition(
    blocks: &[Block],
    defs: &HashMap<Key, Def>,
    key: &Key,
    keep: bool,
    used: bool,
    diags: &mut Vec<Diagnostic>,
    out: &mut Output<'_>,
) {
    let def = &defs[key];
    if keep {
        for b in &blocks[def.blocks.clone()] {
            out.push(b.clone());
        }
    } else if !used {
        let header = &blocks[def.blocks.start];
        diags.push(
            Diagnostic::warning(
                "subprograms::unused",
                format!("subprogram {} is never called; it is left out", key.name()),
            )
            .at_span(header.span)
            .with_help("remove it from the program, or call it"),
        );
    }
}

/// A call's place, for diagnostics.
struct Site {
    text: String,
    line: u32,
    at: (usize, usize),
}

impl Site {
    fn point(&self, d: Diagnostic) -> Diagnostic {
        d.at_bytes(self.line, &self.text, self.at.0, self.at.1)
    }
}

/// Expands calls recursively.
struct Expander<'a> {
    defs: &'a HashMap<Key, Def>,
    options: &'a Options,
    /// Definitions calls that pass through may reach.
    reached: HashSet<Reach>,
    /// Programs expanded at least once.
    used: HashSet<Key>,
    /// Diagnostics already reported (a body repeated 625 times warns once).
    seen: HashSet<(&'static str, u32, u32, String)>,
    produced: u64,
    diags: Vec<Diagnostic>,
    /// `max_blocks` was exceeded: stop producing.
    failed: bool,
}

impl Expander<'_> {
    fn report(&mut self, d: Diagnostic) {
        let loc = d.location.as_ref().map_or((0, 0), |l| (l.line, l.column));
        if self.seen.insert((d.code, loc.0, loc.1, d.message.clone())) {
            self.diags.push(d);
        }
    }

    /// Expands `key` `count` times starting in `state`; returns the state it leaves.
    #[allow(clippy::too_many_arguments)]
    fn call(
        &mut self,
        key: &Key,
        count: u32,
        state: LowerState,
        depth: u32,
        stack: &mut Vec<Key>,
        site: &Site,
        out: &mut Vec<Block>,
    ) -> Result<LowerState, ()> {
        let Some(def) = self.defs.get(key) else {
            let mut help = match key {
                Key::Fanuc(n) => {
                    format!("define it after the main program: a line `O{n}`, its body, then `M99`")
                }
                Key::Oword(l) => {
                    format!("define it with `o{l} sub` ... `o{l} endsub` in the same file")
                }
            };
            if let Key::Fanuc(n) = key
                && !self.options.packed_count
                && *n >= 10_000
                && self.defs.contains_key(&Key::Fanuc(n % 10_000))
            {
                help.push_str(&format!(
                    "; or, if P{n} means {} times O{}, set the pass option packed_count = true",
                    n / 10_000,
                    n % 10_000
                ));
            }
            self.report(
                site.point(
                    Diagnostic::error(
                        "subprograms::missing",
                        format!("subprogram {} is not defined in this program", key.name()),
                    )
                    .with_label("called here")
                    .with_help(help),
                ),
            );
            return Err(());
        };
        if stack.contains(key) {
            let mut chain: Vec<String> = stack.iter().map(Key::name).collect();
            chain.push(key.name());
            self.report(site.point(
                Diagnostic::error(
                    "subprograms::recursion",
                    format!("subprogram {} calls itself: {}", key.name(), chain.join(" -> ")),
                )
                .with_label("recursive call")
                .with_help("a subprogram cannot be inlined into itself; end the recursion with a loop count (L) instead"),
            ));
            return Err(());
        }
        if depth > self.options.max_depth {
            self.report(site.point(
                Diagnostic::error(
                    "subprograms::depth",
                    format!(
                        "calls nest {depth} levels deep here; the limit is {}",
                        self.options.max_depth
                    ),
                )
                .with_label("one level too many")
                .with_help("controllers allow 10 levels (Fanuc, LinuxCNC); flatten the calls, or raise the pass option max_depth"),
            ));
            return Err(());
        }
        if let Some((text, span, (s, e))) = &def.early_return {
            self.report(
                Diagnostic::error(
                    "subprograms::return",
                    format!("{} returns early; the call cannot be inlined", key.name()),
                )
                .at_bytes(span.line, text, *s, *e)
                .with_label("early return")
                .with_help("restructure the subroutine so it ends at its endsub, or leave it to the controller (remove the pass)"),
            );
            return Err(());
        }
        self.used.insert(key.clone());
        stack.push(key.clone());
        let mut low = Lowerer::for_body(self.options.input.clone(), state);
        for _ in 0..count {
            for (text, span) in &def.lines {
                let mut blocks = Vec::new();
                let mut d = Vec::new();
                low.line(text, *span, &mut blocks, &mut d);
                for d in d {
                    self.report(d);
                }
                for b in blocks {
                    if self.failed {
                        return Err(());
                    }
                    match body_call(&b, text, self.options) {
                        Some(Call::Expand { key, count, at }) => {
                            let inner = Site {
                                text: text.clone(),
                                line: span.line,
                                at,
                            };
                            let end =
                                self.call(&key, count, low.state(), depth + 1, stack, &inner, out)?;
                            low.set_state(end);
                        }
                        Some(Call::Opaque { warning, reach }) => {
                            self.report(warning);
                            self.reached.insert(reach);
                            out.push(b);
                        }
                        Some(Call::Bad(d)) => {
                            self.report(d);
                            return Err(());
                        }
                        None => {
                            self.produced += 1;
                            if self.produced > self.options.max_blocks {
                                self.failed = true;
                                self.report(site.point(
                                    Diagnostic::error(
                                        "subprograms::size",
                                        format!(
                                            "the expansion produces more than {} blocks",
                                            self.options.max_blocks
                                        ),
                                    )
                                    .with_label("in this call")
                                    .with_help("check the repeat counts; raise the pass option max_blocks if the program is meant to be this long"),
                                ));
                                return Err(());
                            }
                            out.push(b);
                        }
                    }
                }
            }
        }
        stack.pop();
        Ok(low.state())
    }

    /// After a call from the main program: the lines after it were read in the modes
    /// before it, so the body must leave those modes in force.
    fn check_modes(&mut self, key: &Key, start: &LowerState, end: &LowerState, site: &Site) {
        let mut changed = Vec::new();
        if start.inch != end.inch {
            changed.push(if end.inch { "G20 (inches)" } else { "G21 (mm)" });
        }
        if start.relative != end.relative {
            changed.push(if end.relative { "G91" } else { "G90" });
        }
        if start.relative_e != end.relative_e {
            changed.push(if end.relative_e { "M83" } else { "M82" });
        }
        if start.feed_mode != end.feed_mode {
            changed.push(match end.feed_mode {
                crate::ir::FeedMode::InverseTime => "G93",
                crate::ir::FeedMode::PerMinute => "G94",
                crate::ir::FeedMode::PerRevolution => "G95",
            });
        }
        if !changed.is_empty() {
            self.report(site.point(
                Diagnostic::error(
                    "subprograms::modes",
                    format!(
                        "{} returns with {} in force, but the lines after this call were read in the modes it was called in",
                        key.name(),
                        changed.join(", ")
                    ),
                )
                .with_label("modes differ after this call")
                .with_help(format!(
                    "end {} in the modes it starts in (restore them before its M99 / endsub)",
                    key.name()
                )),
            ));
        } else if start.plane != end.plane {
            self.report(
                site.point(
                    Diagnostic::warning(
                        "subprograms::modes",
                        format!(
                            "{} returns in plane {}, but the arcs after this call were read in {}",
                            key.name(),
                            end.plane.gcode(),
                            start.plane.gcode()
                        ),
                    )
                    .with_label("plane differs after this call")
                    .with_help("restore the plane before the end of the subprogram"),
                ),
            );
        }
    }
}

/// Tracks the main program's state through the blocks the frontend lowered, and completes
/// the blocks after a call from what the call left.
struct Tracker {
    state: LowerState,
    /// The offsets the frontend used (it does not see G92 inside bodies).
    front_offsets: [f64; AXIS_COUNT],
    /// A call has been expanded: the frontend's positions may be less than known.
    after_call: bool,
    input: InputOptions,
}

impl Tracker {
    fn new(input: &InputOptions) -> Self {
        Tracker {
            state: Lowerer::new(input.clone()).state(),
            front_offsets: [0.0; AXIS_COUNT],
            after_call: false,
            input: input.clone(),
        }
    }

    /// A line the frontend passed through because a position was unknown after a call
    /// (a relative move, an arc), lowered again now that the position is known; `None`
    /// when it still cannot be lowered to moves alone.
    fn relower(&self, block: &Block) -> Option<(Block, LowerState)> {
        let BlockKind::Verbatim(v) = &block.kind else {
            return None;
        };
        let m = v.modes?;
        if v.reason != crate::ir::VerbatimReason::Unevaluated {
            return None;
        }
        let mut state = self.state;
        state.inch = m.inch;
        state.relative = m.relative;
        if crate::num::lexer::has_word(&v.text, 'E') {
            state.relative_e = m.relative_e;
        }
        if let Some(p) = m.plane {
            state.plane = p;
        }
        let mut low = Lowerer::for_body(self.input.clone(), state);
        let (mut out, mut diags) = (Vec::new(), Vec::new());
        low.line(&v.text, block.span, &mut out, &mut diags);
        let moves_only =
            !out.is_empty() && out.iter().all(|b| matches!(b.kind, BlockKind::Motion(_)));
        (diags.is_empty() && moves_only && out.len() == 1).then(|| (out.remove(0), low.state()))
    }

    /// The state a call's body starts in: what the blocks left, with the modes the frontend
    /// recorded on the call.
    fn call_state(&self, call: &Block) -> LowerState {
        let mut s = self.state;
        let modes = match &call.kind {
            BlockKind::Command(c) => c.modes,
            BlockKind::Verbatim(v) => v.modes,
            _ => None,
        };
        if let Some(m) = modes {
            s.inch = m.inch;
            s.relative = m.relative;
            s.relative_e = m.relative_e;
            if let Some(p) = m.plane {
                s.plane = p;
            }
        }
        s
    }

    fn after_call(&mut self, end: LowerState) {
        self.state = end;
        self.after_call = true;
    }

    /// Updates the state with `block` and returns it completed.
    fn block(&mut self, mut block: Block, diags: &mut Vec<Diagnostic>) -> Block {
        if self.after_call
            && let Some((lowered, state)) = self.relower(&block)
        {
            self.state = state;
            return lowered;
        }
        let corr: [f64; AXIS_COUNT] =
            std::array::from_fn(|i| self.front_offsets[i] - self.state.offsets[i]);
        match &mut block.kind {
            BlockKind::Motion(m) => {
                if let Target::Joints(t) = &mut m.target {
                    for a in Axis::ALL {
                        let i = a.index();
                        if m.machine_frame && m.written.contains(a) {
                            continue;
                        }
                        match t.get(a) {
                            Some(v) => t.values[i] = v + corr[i],
                            None => {
                                if let Some(v) = self.state.pos.get(a) {
                                    t.set(a, v);
                                }
                            }
                        }
                    }
                    self.state.pos = *t;
                    if m.machine_frame {
                        self.state.pos.forget(m.written);
                    }
                }
                if let MotionKind::Arc(arc) = &mut m.kind {
                    for (k, c) in arc.center.iter_mut().enumerate() {
                        *c += corr[k];
                    }
                }
                if m.feed.rate.is_none() && m.feed.mode == self.state.feed_mode {
                    m.feed.rate = self.state.feed;
                }
                self.state.feed = m.feed.rate;
                self.state.feed_mode = m.feed.mode;
                self.state.motion = match m.kind {
                    MotionKind::Rapid => MotionMode::Rapid,
                    MotionKind::Linear => MotionMode::Linear,
                    MotionKind::Arc(a) => MotionMode::Arc {
                        clockwise: a.clockwise,
                    },
                };
            }
            BlockKind::Offset(o) => {
                self.front_offsets = o.offsets;
                let s = &mut self.state;
                match o.code {
                    OffsetCode::Set => {
                        for a in o.declared.known.iter() {
                            let v = o.declared.values[a.index()];
                            match s.pos.get(a) {
                                Some(p) => s.offsets[a.index()] = v - p,
                                None => {
                                    s.offsets[a.index()] = 0.0;
                                    s.pos.set(a, v);
                                }
                            }
                        }
                    }
                    OffsetCode::Clear => {
                        s.offsets = [0.0; AXIS_COUNT];
                        s.suspended = None;
                    }
                    OffsetCode::Suspend => {
                        s.suspended = Some(s.offsets);
                        s.offsets = [0.0; AXIS_COUNT];
                    }
                    OffsetCode::Restore => {
                        if let Some(o) = s.suspended.take() {
                            s.offsets = o;
                        }
                    }
                }
                o.offsets = s.offsets;
            }
            BlockKind::Command(c) => {
                self.state.pos.forget(c.clobbers);
                if has_code(&c.text, 'M', 99.0) {
                    diags.push(
                        Diagnostic::warning(
                            "subprograms::main-m99",
                            "M99 in the main program: the controller restarts the program here (an endless loop)",
                        )
                        .at_span(block.span)
                        .with_help("it passes through unchanged and is not expanded; end the program with M30 or M2 instead if it should stop"),
                    );
                }
            }
            BlockKind::Verbatim(v) => {
                self.state.pos.forget(v.clobbers);
                if v.modes.is_some() && v.reason == crate::ir::VerbatimReason::Unevaluated {
                    // As the frontend: a line it could not evaluate leaves the motion mode
                    // unknown, unless it names one.
                    self.state.motion = motion_of(&v.text).unwrap_or(MotionMode::None);
                }
            }
            BlockKind::Dwell { .. } | BlockKind::Comment => {}
        }
        block
    }
}

/// The motion mode a line's G words select, if any.
fn motion_of(text: &str) -> Option<MotionMode> {
    let mut mode = None;
    for (_, t, _) in tokens(text) {
        if let Tok::Word(w) = t
            && w.starts_with(['G', 'g'])
            && let Some(n) = crate::num::parse_decimal(w[1..].trim_start())
        {
            mode = match n {
                0.0 => Some(MotionMode::Rapid),
                1.0 => Some(MotionMode::Linear),
                2.0 => Some(MotionMode::Arc { clockwise: true }),
                3.0 => Some(MotionMode::Arc { clockwise: false }),
                80.0 => Some(MotionMode::None),
                n if (73.0..=89.0).contains(&n) || n == 33.0 || (38.0..39.0).contains(&n) => {
                    Some(MotionMode::Unsupported)
                }
                _ => mode,
            };
        }
    }
    mode
}

/// Whether a line has the word `letter``value` (`M98`, `M99`).
fn has_code(text: &str, letter: char, value: f64) -> bool {
    word_positions(text, letter)
        .iter()
        .any(|(_, _, n)| n.as_deref().and_then(crate::num::parse_decimal) == Some(value))
}

/// The words with `letter` in a line: byte range and number text (`None` for a bare
/// letter followed by an expression, `P[...]`).
fn word_positions(text: &str, letter: char) -> Vec<(usize, usize, Option<String>)> {
    let mut v = Vec::new();
    for (s, t, e) in tokens(text) {
        match t {
            Tok::Word(w) if w.as_bytes()[0].eq_ignore_ascii_case(&(letter as u8)) => {
                v.push((s, e, Some(w[1..].trim_start().to_string())))
            }
            Tok::Letter(w) if w.as_bytes()[0].eq_ignore_ascii_case(&(letter as u8)) => {
                v.push((s, e, None))
            }
            _ => {}
        }
    }
    v
}

/// The o-word keyword and label of a line (`o100 sub` is ("100", "sub")).
fn oword_line(text: &str) -> Option<(String, String)> {
    let toks: Vec<_> = tokens(text).collect();
    let first = toks.first()?;
    let starts_o = matches!(first.1, Tok::Word(w) | Tok::Letter(w) if w.starts_with(['o', 'O']));
    if !starts_o {
        return None;
    }
    // The first identifier that is an o-word keyword (`o<name> sub`: not `name`).
    const KEYWORDS: &[&str] = &[
        "sub",
        "endsub",
        "call",
        "return",
        "if",
        "elseif",
        "else",
        "endif",
        "while",
        "endwhile",
        "do",
        "repeat",
        "endrepeat",
        "break",
        "continue",
    ];
    let (ks, kw, _) = toks.iter().skip(1).find_map(|&(s, t, e)| match t {
        Tok::Ident(w) if KEYWORDS.iter().any(|k| k.eq_ignore_ascii_case(w)) => Some((s, w, e)),
        _ => None,
    })?;
    let raw = text[first.0 + 1..ks].trim();
    Some((normalise_label(raw), kw.to_ascii_lowercase()))
}

/// `0100` and `100` are the same o-word number; names are case-insensitive.
fn normalise_label(raw: &str) -> String {
    if !raw.is_empty() && raw.bytes().all(|b| b.is_ascii_digit()) {
        let t = raw.trim_start_matches('0');
        if t.is_empty() { "0".into() } else { t.into() }
    } else {
        raw.to_ascii_lowercase()
    }
}

/// Whether a block starts the part of the program this pass has to buffer.
fn subprogram_related(block: &Block) -> bool {
    match &block.kind {
        BlockKind::Command(c) => has_code(&c.text, 'M', 98.0) || has_code(&c.text, 'M', 99.0),
        BlockKind::Verbatim(v) => {
            v.reason == crate::ir::VerbatimReason::Subprogram
                || has_code(&v.text, 'M', 98.0)
                || has_code(&v.text, 'M', 99.0)
                || oword_line(&v.text).is_some_and(|(_, kw)| {
                    matches!(kw.as_str(), "sub" | "endsub" | "call" | "return")
                })
        }
        _ => false,
    }
}

/// Finds the definitions in the buffered blocks. Returns them and, per block, the
/// definition it belongs to.
fn collect_definitions(
    blocks: &[Block],
    diags: &mut Vec<Diagnostic>,
) -> (HashMap<Key, Def>, Vec<Option<Key>>) {
    let mut defs: HashMap<Key, Def> = HashMap::new();
    let mut owner: Vec<Option<Key>> = vec![None; blocks.len()];
    let mut i = 0;
    while i < blocks.len() {
        let BlockKind::Verbatim(v) = &blocks[i].kind else {
            i += 1;
            continue;
        };
        let start = i;
        let header_span = blocks[i].span;
        let mut lines = Vec::new();
        let mut early_return = None;
        let key;
        if v.reason == crate::ir::VerbatimReason::Subprogram {
            // Fanuc: `O<n>` ... the line with M99.
            let number = word_positions(&v.text, 'O')
                .first()
                .and_then(|(_, _, n)| n.as_deref().and_then(|n| n.parse::<u32>().ok()));
            let Some(n) = number else {
                i += 1;
                continue;
            };
            key = Key::Fanuc(n);
            let mut j = i;
            let mut closed = has_code(&v.text, 'M', 99.0);
            while !closed {
                j += 1;
                let Some(BlockKind::Verbatim(b)) = blocks.get(j).map(|b| &b.kind) else {
                    break;
                };
                if b.reason != crate::ir::VerbatimReason::Subprogram {
                    break;
                }
                if has_code(&b.text, 'M', 99.0) {
                    closed = true;
                    lines.push((strip_m99(&b.text), blocks[j].span));
                } else {
                    lines.push((b.text.clone(), blocks[j].span));
                }
            }
            if !closed {
                diags.push(
                    Diagnostic::error(
                        "subprograms::no-m99",
                        format!("subprogram {} has no M99", key.name()),
                    )
                    .at_bytes(header_span.line, &v.text, 0, v.text.len())
                    .with_label("starts here and runs to the end")
                    .with_help("end the subprogram with M99"),
                );
                j = j.min(blocks.len() - 1);
                if !matches!(&blocks[j].kind, BlockKind::Verbatim(b) if b.reason == crate::ir::VerbatimReason::Subprogram)
                {
                    j -= 1;
                }
            }
            i = j + 1;
        } else if let Some((label, kw)) = oword_line(&v.text)
            && kw == "sub"
        {
            key = Key::Oword(label.clone());
            let mut j = i + 1;
            let mut closed = false;
            while j < blocks.len() {
                if let BlockKind::Verbatim(b) = &blocks[j].kind {
                    match oword_line(&b.text) {
                        Some((l, k)) if k == "endsub" && l == label => {
                            closed = true;
                            break;
                        }
                        Some((l, k)) if k == "return" && l == label => {
                            let end = b.text.trim_end().len();
                            early_return.get_or_insert((b.text.clone(), blocks[j].span, (0, end)));
                        }
                        _ => {}
                    }
                    lines.push((b.text.clone(), blocks[j].span));
                } else {
                    // The frontend passes every line inside a sub through as text.
                    break;
                }
                j += 1;
            }
            if !closed {
                // The frontend warns about the open o-word; nothing to expand.
                i += 1;
                continue;
            }
            i = j + 1;
        } else {
            i += 1;
            continue;
        }
        if defs.contains_key(&key) {
            diags.push(
                Diagnostic::warning(
                    "subprograms::duplicate",
                    format!(
                        "{} is defined a second time; the first definition is used",
                        key.name()
                    ),
                )
                .at_span(header_span)
                .with_help(
                    "program numbers are numbers (O0002 is O2); give each subprogram its own",
                ),
            );
            for o in owner.iter_mut().take(i).skip(start) {
                *o = Some(key.clone());
            }
            continue;
        }
        for o in owner.iter_mut().take(i).skip(start) {
            *o = Some(key.clone());
        }
        defs.insert(
            key,
            Def {
                lines,
                blocks: start..i,
                early_return,
            },
        );
    }
    (defs, owner)
}

/// The line without its M99 word.
fn strip_m99(text: &str) -> String {
    let mut s = text.to_string();
    for (a, b, n) in word_positions(text, 'M').into_iter().rev() {
        if n.as_deref().and_then(crate::num::parse_decimal) == Some(99.0) {
            s.replace_range(a..b, &" ".repeat(b - a));
        }
    }
    s
}

/// A call in the main program: the call and the text its columns refer to.
fn main_call(block: &Block, options: &Options) -> Option<(Call, String)> {
    let text = match &block.kind {
        BlockKind::Command(c) => c.text.as_str(),
        BlockKind::Verbatim(v) if v.reason != crate::ir::VerbatimReason::Subprogram => {
            v.text.as_str()
        }
        _ => return None,
    };
    let call = classify(block, text, options)?;
    Some((call, text.to_owned()))
}

/// A call in a body line `text`, lowered to `block`.
fn body_call(block: &Block, text: &str, options: &Options) -> Option<Call> {
    match &block.kind {
        BlockKind::Command(_) | BlockKind::Verbatim(_) => classify(block, text, options),
        _ => None,
    }
}

/// Reads the call in `text` (the line of `block`), if it is one.
fn classify(block: &Block, text: &str, options: &Options) -> Option<Call> {
    let line = block.span.line;
    let inside_flow = match &block.kind {
        BlockKind::Verbatim(v) => v.modes.is_none(),
        _ => false,
    };
    let not_expanded = |msg: String, (s, e): (usize, usize), help: &str| {
        Diagnostic::warning("subprograms::not-expanded", msg)
            .at_bytes(line, text, s, e)
            .with_label("passes through unchanged")
            .with_help(help.to_string())
    };
    if let Some(c) = oword_call(text) {
        let reach = match &c.label {
            Some(l) => Reach::One(Key::Oword(l.clone())),
            None => Reach::AllOword,
        };
        if inside_flow {
            return Some(Call::Opaque {
                warning: not_expanded(
                    "a call inside o-word control flow is not expanded".into(),
                    c.at,
                    "the condition or loop around it is evaluated by the controller; the subroutine stays in the output",
                ),
                reach,
            });
        }
        if !c.simple {
            let what = if c.label.is_none() {
                "a call to a computed subroutine number is not expanded"
            } else {
                "a call with arguments is not expanded"
            };
            return Some(Call::Opaque {
                warning: not_expanded(
                    what.into(),
                    (c.at.0, text.trim_end().len()),
                    "parameters and expressions are not evaluated; the call and its subroutine stay in the output for the controller",
                ),
                reach,
            });
        }
        let label = c.label.unwrap_or_default();
        return Some(Call::Expand {
            key: Key::Oword(label),
            count: 1,
            at: c.at,
        });
    }
    let m98 = word_positions(text, 'M')
        .into_iter()
        .find(|(_, _, n)| n.as_deref().and_then(crate::num::parse_decimal) == Some(98.0))?;
    let m98_at = (m98.0, m98.1);
    let expression = tokens(text).any(|t| matches!(t.1, Tok::Other(c) if "#[]".contains(c)));
    if expression || inside_flow {
        let msg = if expression {
            "a call with an expression (parameters) is not expanded"
        } else {
            "a call inside o-word control flow is not expanded"
        };
        return Some(Call::Opaque {
            warning: not_expanded(
                msg.into(),
                (m98_at.0, text.trim_end().len()),
                "the controller evaluates it; the subprograms stay in the output",
            ),
            reach: Reach::AllFanuc,
        });
    }
    let bad = |msg: String, (s, e): (usize, usize), label: &str, help: &str| {
        Call::Bad(
            Diagnostic::error("subprograms::count", msg)
                .at_bytes(line, text, s, e)
                .with_label(label.to_string())
                .with_help(help.to_string()),
        )
    };
    let Some((ps, pe, Some(p))) = word_positions(text, 'P').into_iter().next() else {
        return Some(Call::Bad(
            Diagnostic::error("subprograms::call", "M98 without a program number P")
                .at_bytes(line, text, m98_at.0, m98_at.1)
                .with_label("which program?")
                .with_help("write the program number after P: `M98 P10`"),
        ));
    };
    let digits = p.trim_start_matches('+');
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || digits.len() > 9 {
        return Some(Call::Bad(
            Diagnostic::error(
                "subprograms::call",
                format!("`P{p}` is not a program number"),
            )
            .at_bytes(line, text, ps, pe)
            .with_label("not a whole number")
            .with_help("program numbers are whole numbers from 0 to 99999999"),
        ));
    }
    let number: u32 = digits.parse().ok()?;
    let l = word_positions(text, 'L').into_iter().next();
    let (program, count, count_at) = match l {
        Some((ls, le, Some(lv))) => {
            let v = crate::num::parse_decimal(&lv).unwrap_or(f64::NAN);
            let max = options.max_count;
            if !(v.fract() == 0.0 && v >= 1.0 && v <= max as f64) {
                let why = if v.fract() != 0.0 || !v.is_finite() {
                    "not a whole number"
                } else if v < 1.0 {
                    "runs the subprogram no time"
                } else {
                    "too many repetitions"
                };
                return Some(bad(
                    format!("repeat count `L{lv}` must be a whole number from 1 to {max}"),
                    (ls, le),
                    why,
                    "L counts how many times the subprogram runs (L1 or no L: once); remove the call to run it no time",
                ));
            }
            (number, v as u32, (m98_at.0, le))
        }
        Some((ls, le, None)) => {
            return Some(bad(
                "`L` has no number".into(),
                (ls, le),
                "needs a count",
                "write the repeat count after L: `L5`",
            ));
        }
        None if options.packed_count && digits.len() > 4 => {
            let count = number / 10_000;
            if count > options.max_count {
                return Some(bad(
                    format!(
                        "packed repeat count {count} in `P{p}` is above {}",
                        options.max_count
                    ),
                    (ps, pe),
                    "too many repetitions",
                    "the digits before the last four count the repetitions",
                ));
            }
            (number % 10_000, count.max(1), (m98_at.0, pe))
        }
        None => (number, 1, (m98_at.0, pe)),
    };
    Some(Call::Expand {
        key: Key::Fanuc(program),
        count,
        at: count_at,
    })
}
