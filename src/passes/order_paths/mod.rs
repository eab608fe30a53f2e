//! `order-paths`: reorders cut groups (plunge ... retract) between barriers to shorten the pen-up travel: nearest neighbour, then 2-opt and Or-opt; open paths may be reversed.
//!
//! The seed 001 HPGL2NC converter cut the figures of an EAGLE plot nearest-first
//! ("nearest-figure path ordering"). This pass does the same on any IR, and then improves
//! the order: a cut group is picked nearest-first from where the tool is, then 2-opt
//! (reversing a run of groups that may all be cut backwards) and Or-opt (moving one group
//! elsewhere, possibly reversed) moves are applied while they shorten the travel, within
//! a bounded number of sweeps over neighbour lists. A note reports the travel before and after. The pass **never
//! lengthens the travel**: when the optimised order is not shorter than the input's, the
//! segment is written exactly as it came in.
//!
//! # Cut groups and travel
//! - The tool **cuts** when Z is below `cut_z` (default 0, the work surface of the
//!   `pcb-mill` preset and of pcb2gcode). A **cut group** begins with the Z-only moves
//!   (the approach `G0 Z0.1`), dwells and comments that follow the last XY travel move,
//!   continues with the plunge below `cut_z` and every block after it (cuts, arcs,
//!   dwells, comments, rapid Z moves inside the group), and ends with the first move that
//!   brings Z back to `cut_z` or above (the retract). Its start is the XY where it is
//!   entered, its end the XY where it retracts. A drilled hole is a group whose start is
//!   its end.
//! - **Travel** is everything between groups: rapid and linear moves with the tool at or
//!   above `cut_z`. These moves are not kept: the pass writes its own travel from one
//!   group's retract to the next group's start — up to the travel height if needed, one
//!   XY rapid, down to the height the input entered the group at. The travel height is
//!   the highest of the previous group's retract height, the next group's entry height
//!   and every height the input moved in XY at between groups in the segment, so the
//!   tool never travels lower than the input did. Comments on or between travel moves go
//!   with the next group (they usually name it); comments after the last group stay at
//!   the end.
//! - **Travel length** is the XY distance of the travel moves (Z moves are not counted):
//!   the input's, measured on its moves, and the output's. The note gives both.
//!
//! # Reversal
//! A group is cut backwards when that shortens travel (and `reverse = true`) only if it
//! is an open path at one depth: its moves between the first and the last XY move are
//! all `G1` lines at the depth it plunged to, with nothing but comments between them.
//! Its plunge then happens at the far end and its retract at the near end; every line
//! keeps its feed, source line and comments. Groups with arcs, with Z changes while
//! cutting (ramps, step-downs, helical holes), with dwells inside or with words riding on
//! the moves are never reversed (only moved). A closed path (start = end) or a hole needs
//! no reversal and is never rewritten.
//!
//! # Barriers
//! Groups are never moved across a **barrier**; the groups between two barriers form a
//! segment that is ordered on its own. Barriers are: commands (`T2 M6`, `M3`, `M5`,
//! `M2`, `M8`, `G28`, probing ...), dwells between groups (`G4`), G92-family offsets,
//! lines passed through as text (parameters, control flow, subprograms), arcs and moves
//! carrying extra words at travel height, machine-frame (`G53`) moves, moves from or to a
//! position that is not known, and moves that change an axis other than X, Y and Z
//! between groups. A segment whose groups change other axes is not reordered.
//!
//! After the last group of a segment the tool travels back to where the input had it
//! before the barrier, so the barrier (a G92 declares the current position!) and the
//! moves after it see the same position and later travel cannot grow. The one exception:
//! when only barriers that do not depend on the position (spindle, tool change, dwell,
//! comments) and then the program end (`M2`, `M30`) or the end of the input follow, and
//! the input made no travel after its last group, the segment ends where its last group
//! does (only Z is restored).
//!
//! A barrier inside a cut group (an `M` code while cutting) ends the segment: the groups
//! before it are ordered with the interrupted group last, which is written unchanged
//! with the rest of it up to its retract; a warning says so.
//!
//! # Options
//! - `cut_z` (mm, default 0): the tool cuts below this height.
//! - `reverse` (default true): allow cutting open paths backwards.
//! - `two_opt` (default true): improve the nearest-neighbour order with 2-opt and Or-opt
//!   moves. With false the order is nearest neighbour only (the seed's method).
//! - `max_sweeps` (default 50): at most this many improvement sweeps per segment.
//! - `neighbours` (default 12): the improvement moves of a group look at the groups
//!   whose ends are among this many nearest ends of its own (each sweep costs
//!   `O(groups x neighbours)` evaluations, so large boards stay fast; the nearest
//!   neighbour step is exact).
//! - `max_groups` (default 20000): a segment holding this many groups is ordered and
//!   written, and a new one begins: this bounds the memory.
//!
//! # Memory
//! This pass buffers by nature: it holds **every block of one segment** — the cut groups
//! between two barriers and the travel between them — until the barrier (or the end of
//! the input, or `max_groups` groups) arrives. For an HPGL plot, where the spindle starts
//! before the first cut and stops after the last, that is the whole pattern of one tool;
//! at a few hundred bytes a block, a 100 000-line board is some tens of MB. Barriers and
//! blocks outside segments stream.
//!
//! # Seed bugs kept out
//! The seed's converter had two bugs in this very search: it skipped the last figure of
//! its list (`for (i = 1; i < fig_count; i++)`, so a figure was left uncut), and a figure
//! whose start had the same X as the previous figure's end was travelled with the pen up
//! instead of cut. Here every group is written exactly once with all of its cut moves, and
//! travel is only ever written between groups (tests/order_paths.rs checks both).

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

mod emit;
mod nearest;
mod tour;

use emit::position_before;

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Axis, AxisSet, Block, BlockKind, Joints, Motion, MotionKind, Target};

/// Options of `order-paths`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// The tool cuts below this Z (mm).
    pub cut_z: f64,
    /// Allow cutting open single-depth line paths backwards.
    pub reverse: bool,
    /// Improve the nearest-neighbour order with 2-opt and Or-opt moves.
    pub two_opt: bool,
    /// Largest number of improvement sweeps per segment.
    pub max_sweeps: u32,
    /// Nearest group ends each improvement move looks at.
    pub neighbours: u32,
    /// A segment with this many groups is written and a new one begins.
    pub max_groups: u32,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            cut_z: 0.0,
            reverse: true,
            two_opt: true,
            max_sweeps: 50,
            neighbours: 12,
            max_groups: 20000,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "order-paths",
    summary: "reorder cut groups (plunge..retract) between barriers to shorten travel: nearest neighbour, 2-opt, open paths reversed (seed 001); buffers one segment",
    build: |t, _ctx| Ok(Box::new(OrderPaths::new(super::options(t)?)?)),
    defaults: || super::to_toml(&Options::default()),
};

/// Positions closer than this (mm) are the same.
const EPS: f64 = 1e-9;

/// One cut group of a segment, as indices into the segment's blocks.
#[derive(Debug, Clone)]
struct Group {
    /// Travel and comment blocks between the previous group and this one.
    lead: std::ops::Range<usize>,
    /// The group's own blocks (prefix, plunge, cuts, retract).
    blocks: std::ops::Range<usize>,
    /// Where the tool is when the group begins (its start XY, at the entry height).
    before: Joints,
    /// Where the tool is after the retract.
    exit: Joints,
    /// Start and end XY of the cut path.
    start: Point2<f64>,
    end: Point2<f64>,
    /// May be cut backwards.
    reversible: bool,
}

impl Group {
    fn closed(&self) -> bool {
        (self.start - self.end).norm() <= EPS
    }
}

/// How a segment ends.
#[derive(Debug, Clone, Copy, PartialEq)]
enum End {
    /// The next block does not care where the tool is in XY.
    Free,
    /// The next block needs the tool where the input had it.
    Fixed,
    /// The last group was interrupted by a barrier: it stays last and unchanged.
    Pinned,
}

/// What the pass is doing.
#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    /// Between groups (the tool is at or above `cut_z`).
    Travel,
    /// Inside a group that began at this index of the segment.
    Cutting { first: usize },
    /// Blocks pass through until the tool is above `cut_z` again (a group cut by a
    /// barrier, or a position that is not known).
    Passing,
}

/// The blocks of one segment.
#[derive(Debug, Default)]
struct Segment {
    /// Where the tool was when the segment's first block came.
    start: Option<Joints>,
    blocks: Vec<Block>,
    groups: Vec<Group>,
    /// Index where the travel after the last group begins.
    pending: usize,
    /// Index after the last XY travel move since the last group, and the position there.
    arrive: Option<(usize, Joints)>,
    /// XY length of the input's travel moves.
    travel: f64,
    /// Highest Z the input moved in XY at between groups.
    height: f64,
    /// A group changes an axis other than X, Y, Z.
    other_axes: bool,
}

impl Segment {
    fn new() -> Segment {
        Segment {
            height: f64::NEG_INFINITY,
            ..Segment::default()
        }
    }
}

/// The `order-paths` pass.
pub struct OrderPaths {
    opt: Options,
    state: State,
    /// The tool position after the last block taken in (input order within the segment,
    /// output order after a flush).
    track: crate::ir::Tracker,
    seg: Segment,
    /// Barriers that do not care where the tool is (`M5`, `T2 M6`, `G4`, comments) after
    /// a segment with groups: whether the segment may end anywhere depends on what comes
    /// after them (a program end: yes; a move: no, the tool returns to where the input
    /// had it, so later travel is not lengthened).
    held: Vec<Block>,
    // Run totals for the note.
    before: f64,
    after: f64,
    groups: usize,
    reordered: usize,
    kept: usize,
    reversed: usize,
    interrupted: usize,
    warned: bool,
}

fn xy(j: &Joints) -> Point2<f64> {
    Point2::new(j.values[0], j.values[1])
}

fn xyz_known(j: &Joints) -> bool {
    j.known.intersection(AxisSet::XYZ) == AxisSet::XYZ
}

/// The axes other than X, Y, Z are the same (known and values).
fn others_equal(a: &Joints, b: &Joints) -> bool {
    let others = AxisSet::ALL.difference(AxisSet::XYZ);
    a.known.intersection(others) == b.known.intersection(others)
        && a.known
            .intersection(others)
            .iter()
            .all(|ax| a.values[ax.index()] == b.values[ax.index()])
}

impl OrderPaths {
    /// The pass with `options`.
    pub fn new(opt: Options) -> Result<OrderPaths, Diagnostic> {
        if !opt.cut_z.is_finite() {
            return Err(Diagnostic::settings("cut_z must be a number"));
        }
        if opt.max_groups < 2 {
            return Err(Diagnostic::settings("max_groups must be at least 2"));
        }
        Ok(OrderPaths {
            opt,
            state: State::Travel,
            track: crate::ir::Tracker::default(),
            seg: Segment::new(),
            held: Vec::new(),
            before: 0.0,
            after: 0.0,
            groups: 0,
            reordered: 0,
            kept: 0,
            reversed: 0,
            interrupted: 0,
            warned: false,
        })
    }

    /// The joint target of a motion that may take part in a segment: absolute joints,
    /// program frame, X Y Z known before and after.
    fn clean_target(&self, m: &Motion) -> Option<Joints> {
        let Target::Joints(t) = m.target else {
            return None;
        };
        (!m.machine_frame && xyz_known(self.track.pos()) && xyz_known(&t)).then_some(t)
    }

    fn take(&mut self, block: Block) {
        if self.seg.start.is_none() {
            self.seg.start = Some(*self.track.pos());
        }
        self.track.update(&block);
        self.seg.blocks.push(block);
    }

    /// Emits a block that is not part of a segment.
    fn pass_on(&mut self, block: Block, out: &mut Output<'_>) {
        self.track.update(&block);
        out.push(block);
        if self.state == State::Travel && !self.above() {
            self.state = State::Passing;
        }
    }

    /// The tool is known to be at or above `cut_z`.
    fn above(&self) -> bool {
        self.track
            .pos()
            .get(Axis::Z)
            .is_some_and(|z| z >= self.opt.cut_z)
    }

    fn barrier(&mut self, block: Block, end: End, out: &mut Output<'_>) {
        self.flush(end, out);
        self.pass_on(block, out);
    }

    /// Whether `block` needs the tool where the input had it.
    fn position_bound(block: &Block) -> bool {
        match &block.kind {
            BlockKind::Command(c) => c.modes.is_some() || !c.clobbers.is_empty(),
            BlockKind::Dwell { .. } | BlockKind::Comment => false,
            _ => true,
        }
    }

    /// `M2` / `M30`: nothing moves after it.
    fn program_end(block: &Block) -> bool {
        matches!(&block.kind, BlockKind::Command(c) if c.ends_program())
    }

    /// Writes the held barriers after the segment, which ends `end`.
    fn release(&mut self, end: End, out: &mut Output<'_>) {
        self.flush(end, out);
        for b in std::mem::take(&mut self.held) {
            self.pass_on(b, out);
        }
    }

    /// A group's blocks from `first` are complete (the last is the retract, or the group
    /// is interrupted).
    fn close_group(&mut self, first: usize) {
        let seg = &mut self.seg;
        let lead = seg.pending..first;
        let before = match seg.arrive {
            Some((_, j)) => j,
            // No XY travel since the last group: the group starts where that one ended.
            None => seg
                .groups
                .last()
                .map(|g| g.exit)
                .or(seg.start)
                .unwrap_or(*self.track.pos()),
        };
        let blocks = &seg.blocks[first..];
        // Walk the group: XY of each move, first and last XY-changing move.
        let mut p = before;
        let mut first_xy = None;
        let mut last_xy = None;
        let mut other_axes = false;
        for (k, b) in blocks.iter().enumerate() {
            if let BlockKind::Motion(m) = &b.kind
                && let Some(t) = m.target.joints()
            {
                if (xy(t) - xy(&p)).norm() > 0.0 {
                    first_xy.get_or_insert(k);
                    last_xy = Some(k);
                }
                other_axes |= !others_equal(&p, t);
                p = *t;
            }
        }
        let exit = p;
        let start = xy(&before);
        let end = xy(&exit);
        let mut reversible = self.opt.reverse && !other_axes;
        if let (Some(f), Some(l)) = (first_xy, last_xy) {
            // The depth the body cuts at: the position before its first XY move.
            let z0 = position_before(blocks, f, before).values[2];
            for b in &blocks[f..=l] {
                match &b.kind {
                    BlockKind::Comment => {}
                    BlockKind::Motion(m) => {
                        let flat = m
                            .target
                            .joints()
                            .is_some_and(|t| (t.values[2] - z0).abs() <= EPS);
                        if !(flat && m.kind == MotionKind::Linear && m.extra.is_empty()) {
                            reversible = false;
                        }
                    }
                    _ => reversible = false,
                }
            }
        }
        seg.other_axes |= other_axes;
        seg.groups.push(Group {
            lead,
            blocks: first..seg.blocks.len(),
            before,
            exit,
            start,
            end,
            reversible,
        });
        seg.pending = seg.blocks.len();
        seg.arrive = None;
    }
}

impl OrderPaths {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        if !self.held.is_empty() {
            if Self::program_end(&block) {
                self.release(End::Free, out);
                return self.pass_on(block, out);
            }
            if !Self::position_bound(&block) {
                self.held.push(block);
                return;
            }
            self.release(End::Fixed, out);
        }
        match self.state {
            State::Passing => self.passing(block, out),
            State::Cutting { first } => self.cutting(block, first, out),
            State::Travel => self.travelling(block, out),
        }
    }

    /// Outside cut segments: blocks pass on; a move that ends above `cut_z` starts a
    /// travel.
    fn passing(&mut self, block: Block, out: &mut Output<'_>) {
        let ends = matches!(block.kind, BlockKind::Motion(_));
        self.track.update(&block);
        out.push(block);
        if ends && self.above() {
            self.state = State::Travel;
        }
    }

    /// Inside a cut group (from block `first` of the segment).
    fn cutting(&mut self, block: Block, first: usize, out: &mut Output<'_>) {
        let ok = match &block.kind {
            BlockKind::Motion(m) => self.clean_target(m),
            BlockKind::Comment | BlockKind::Dwell { .. } => Some(*self.track.pos()),
            _ => None,
        };
        let Some(t) = ok else {
            // A barrier inside a group: the group stays last and unchanged.
            self.interrupted += 1;
            if !self.warned {
                self.warned = true;
                out.diag(
                    Diagnostic::warning(
                        "order-paths::interrupted",
                        "a cut group is interrupted by a line that cannot be moved; the groups before it are ordered with this one last, and it is cut as written (first of possibly several)",
                    )
                    .at_span(block.span)
                    .with_help("commands, offsets and text lines are barriers: put them between cut groups (tool up) to let the groups around them be ordered"),
                );
            }
            self.close_group(first);
            self.flush(End::Pinned, out);
            self.state = State::Passing;
            self.pass_on(block, out);
            if self.above() {
                self.state = State::Travel;
            }
            return;
        };
        let retract = matches!(block.kind, BlockKind::Motion(_)) && t.values[2] >= self.opt.cut_z;
        self.take(block);
        if retract {
            self.close_group(first);
            self.state = State::Travel;
            if self.seg.groups.len() >= self.opt.max_groups as usize {
                self.flush(End::Free, out);
            }
        }
    }

    /// Travelling above `cut_z` between cut groups.
    fn travelling(&mut self, block: Block, out: &mut Output<'_>) {
        match &block.kind {
            BlockKind::Comment => self.take(block),
            BlockKind::Motion(m) => {
                let Some(t) = self.clean_target(m) else {
                    return self.barrier(block, End::Fixed, out);
                };
                if !others_equal(self.track.pos(), &t) {
                    return self.barrier(block, End::Fixed, out);
                }
                if t.values[2] < self.opt.cut_z {
                    // The plunge: the group takes the moves after the last XY travel.
                    let first = match self.seg.arrive {
                        Some((i, _)) => i,
                        None => self.seg.pending,
                    };
                    self.take(block);
                    self.state = State::Cutting { first };
                    return;
                }
                if !(matches!(m.kind, MotionKind::Rapid | MotionKind::Linear) && m.extra.is_empty())
                {
                    return self.barrier(block, End::Fixed, out);
                }
                let d = (xy(&t) - xy(self.track.pos())).norm();
                if d > 0.0 {
                    self.seg.travel += d;
                    self.seg.height = self
                        .seg
                        .height
                        .max(t.values[2])
                        .max(self.track.pos().values[2]);
                }
                self.take(block);
                if d > 0.0 {
                    self.seg.arrive = Some((self.seg.blocks.len(), *self.track.pos()));
                }
            }
            _ if Self::program_end(&block) => self.barrier(block, End::Free, out),
            _ if Self::position_bound(&block) => self.barrier(block, End::Fixed, out),
            // Where the segment may end is decided by what follows.
            _ if !self.seg.groups.is_empty() => self.held.push(block),
            _ => self.barrier(block, End::Free, out),
        }
    }
}

impl Pass for OrderPaths {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        if let State::Cutting { first } = self.state {
            // The input ends inside a group: it stays last, unchanged.
            self.close_group(first);
            self.flush(End::Pinned, out);
        } else {
            self.release(End::Free, out);
        }
        if self.groups == 0 {
            out.diag(Diagnostic::note(
                "order-paths::travel",
                format!(
                    "order-paths: no cut group (no move below Z{}) to order",
                    self.opt.cut_z
                ),
            ));
            return;
        }
        let pct = if self.before > 0.0 {
            100.0 * (self.before - self.after) / self.before
        } else {
            0.0
        };
        let counted =
            |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
        let mut msg = format!(
            "order-paths: travel {:.1} mm -> {:.1} mm ({pct:.1} % shorter), {} in {} ({} reordered, {} kept as written), {} reversed",
            self.before,
            self.after,
            counted(self.groups, "cut group", "cut groups"),
            counted(self.reordered + self.kept, "segment", "segments"),
            self.reordered,
            self.kept,
            self.reversed
        );
        if self.interrupted > 0 {
            msg.push_str(&format!(", {} interrupted by a barrier", self.interrupted));
        }
        out.diag(Diagnostic::note("order-paths::travel", msg));
    }
}
