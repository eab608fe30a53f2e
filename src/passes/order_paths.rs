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

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind, Span, Target,
};

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
        self.track.pos().get(Axis::Z).is_some_and(|z| z >= self.opt.cut_z)
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
        matches!(&block.kind, BlockKind::Command(c)
            if c.text.split_whitespace().any(|w| matches!(w.to_ascii_uppercase().as_str(), "M2" | "M02" | "M30")))
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

    /// Orders and writes the segment.
    fn flush(&mut self, end: End, out: &mut Output<'_>) {
        let seg = std::mem::replace(&mut self.seg, Segment::new());
        if seg.groups.is_empty() || seg.other_axes {
            for b in seg.blocks {
                out.push(b);
            }
            return;
        }
        let Some(start) = seg.start.filter(xyz_known) else {
            for b in seg.blocks {
                out.push(b);
            }
            return;
        };
        let pinned = end == End::Pinned;
        let n = seg.groups.len() - usize::from(pinned);
        let tail_has_travel = seg.arrive.is_some();
        // Where the tool must end in XY, if anywhere.
        let fixed_end: Option<Joints> = match end {
            End::Pinned => Some(seg.groups[n].before),
            End::Fixed => Some(*self.track.pos()),
            End::Free if tail_has_travel => Some(*self.track.pos()),
            End::Free => None,
        };
        let problem = Problem {
            starts: seg.groups[..n].iter().map(|g| g.start).collect(),
            ends: seg.groups[..n].iter().map(|g| g.end).collect(),
            flippable: seg.groups[..n]
                .iter()
                .map(|g| g.reversible || g.closed())
                .collect(),
            origin: xy(&start),
            finish: fixed_end.as_ref().map(xy),
        };
        let order = problem.solve(&self.opt);
        let planned = problem.cost(&order);
        self.groups += seg.groups.len();
        self.before += seg.travel;
        if planned >= seg.travel - EPS {
            // Not shorter: the input as it came.
            self.after += seg.travel;
            self.kept += 1;
            for b in seg.blocks {
                out.push(b);
            }
            if pinned {
                self.state = State::Passing;
            }
            return;
        }
        self.after += planned;
        self.reordered += 1;
        let mut cur = start;
        let blocks = &seg.blocks;
        let emit_comments = |range: std::ops::Range<usize>, out: &mut Output<'_>| {
            for b in &blocks[range] {
                if !b.comments.is_empty() {
                    let mut c = Block::new(b.span, BlockKind::Comment);
                    c.comments = b.comments.clone();
                    out.push(c);
                }
            }
        };
        let mut visit = order.clone();
        if pinned {
            visit.push((n, false));
        }
        for (gi, rev) in visit {
            let g = &seg.groups[gi];
            emit_comments(g.lead.clone(), out);
            let rev = rev && g.reversible && !g.closed();
            let span = blocks[g.blocks.start].span;
            let (before, exit) = if rev {
                let mut b = g.before;
                b.values[0] = g.end.x;
                b.values[1] = g.end.y;
                let mut e = g.exit;
                e.values[0] = g.start.x;
                e.values[1] = g.start.y;
                (b, e)
            } else {
                (g.before, g.exit)
            };
            let feed = first_feed(&blocks[g.blocks.clone()]);
            travel(&cur, &before, seg.height, span, feed, out);
            if rev {
                self.reversed += 1;
                for b in reversed(&blocks[g.blocks.clone()], &g.before) {
                    out.push(b);
                }
            } else {
                for b in &blocks[g.blocks.clone()] {
                    out.push(b.clone());
                }
            }
            cur = exit;
        }
        if pinned {
            self.track.set_pos(cur);
            self.state = State::Passing;
            return;
        }
        // The tail: comments after the last group, then back to where the input was.
        let tail = seg.pending..blocks.len();
        let span = blocks.last().map(|b| b.span).unwrap_or_default();
        let feed = first_feed(&blocks[seg.groups[n - 1].blocks.clone()]);
        emit_comments(tail, out);
        match fixed_end {
            Some(e) => travel(&cur, &e, seg.height, span, feed, out),
            None => {
                // Only the height matters.
                let mut e = cur;
                e.values[2] = self.track.pos().values[2];
                travel(&cur, &e, f64::NEG_INFINITY, span, feed, out);
                cur = e;
            }
        }
        if fixed_end.is_none() {
            self.track.set_pos(cur);
        }
    }
}

/// The position before `blocks[k]`, walking from `from` at `blocks[0]`.
fn position_before(blocks: &[Block], k: usize, from: Joints) -> Joints {
    let mut p = from;
    for b in &blocks[..k] {
        if let BlockKind::Motion(m) = &b.kind
            && let Some(t) = m.target.joints()
        {
            p = *t;
        }
    }
    p
}

/// The feed of the first motion of `blocks` (travel written before a group carries it,
/// so the feed mode stays the group's).
fn first_feed(blocks: &[Block]) -> Feed {
    blocks
        .iter()
        .find_map(|b| match &b.kind {
            BlockKind::Motion(m) => Some(m.feed),
            _ => None,
        })
        .unwrap_or(Feed {
            mode: FeedMode::PerMinute,
            rate: None,
        })
}

fn rapid(span: Span, to: Joints, written: AxisSet, feed: Feed) -> Block {
    Block::new(
        span,
        BlockKind::Motion(Motion {
            kind: MotionKind::Rapid,
            target: Target::Joints(to),
            feed,
            written,
            machine_frame: false,
            extra: String::new(),
        }),
    )
}

/// Rapid travel from `from` to `to`: up to the travel height, across, down.
fn travel(from: &Joints, to: &Joints, height: f64, span: Span, feed: Feed, out: &mut Output<'_>) {
    let h = from.values[2].max(to.values[2]).max(height);
    let z: AxisSet = [Axis::Z].into_iter().collect();
    let mut p = *from;
    if p.values[2] < h {
        p.values[2] = h;
        out.push(rapid(span, p, z, feed));
    }
    if (xy(&p) - xy(to)).norm() > 0.0 {
        p.values[0] = to.values[0];
        p.values[1] = to.values[1];
        out.push(rapid(
            span,
            p,
            [Axis::X, Axis::Y].into_iter().collect(),
            feed,
        ));
    }
    if p.values[2] > to.values[2] {
        p.values[2] = to.values[2];
        out.push(rapid(span, p, z, feed));
    }
}

/// A reversible group cut backwards. `before` is where the group began.
///
/// The prefix (blocks before the first XY move) moves to the far end, the lines run from
/// the last point back to the first, each keeping its feed, span and comments, and the
/// suffix (blocks after the last XY move: dwells, the retract) moves to the near end.
fn reversed(blocks: &[Block], before: &Joints) -> Vec<Block> {
    // Points: the position before each block.
    let mut points = Vec::with_capacity(blocks.len() + 1);
    let mut p = *before;
    let mut first = None;
    let mut last = None;
    for (k, b) in blocks.iter().enumerate() {
        points.push(p);
        if let BlockKind::Motion(m) = &b.kind
            && let Some(t) = m.target.joints()
        {
            if (xy(t) - xy(&p)).norm() > 0.0 {
                first.get_or_insert(k);
                last = Some(k);
            }
            p = *t;
        }
    }
    points.push(p);
    let (Some(f), Some(l)) = (first, last) else {
        return blocks.to_vec();
    };
    let start = xy(&points[f]);
    let end = xy(&points[l + 1]);
    let set_xy = |b: &Block, at: Point2<f64>| {
        let mut b = b.clone();
        if let BlockKind::Motion(m) = &mut b.kind
            && let Some(t) = m.target.joints_mut()
        {
            t.values[0] = at.x;
            t.values[1] = at.y;
        }
        b
    };
    let mut out = Vec::with_capacity(blocks.len());
    out.extend(blocks[..f].iter().map(|b| set_xy(b, end)));
    // The body backwards: a run of comment blocks stays before the line it preceded.
    let mut k = l + 1;
    while k > f {
        // blocks[j..k] is one line and the comment blocks before it.
        let line = (f..k)
            .rev()
            .find(|&j| matches!(blocks[j].kind, BlockKind::Motion(_)))
            .unwrap_or(f);
        let run_start = (f..line)
            .rev()
            .take_while(|&j| matches!(blocks[j].kind, BlockKind::Comment))
            .last()
            .unwrap_or(line);
        out.extend(blocks[run_start..line].iter().cloned());
        let mut b = set_xy(&blocks[line], xy(&points[line]));
        if let BlockKind::Motion(m) = &mut b.kind {
            m.written.insert(Axis::X);
            m.written.insert(Axis::Y);
        }
        out.push(b);
        k = run_start;
    }
    out.extend(blocks[l + 1..].iter().map(|b| set_xy(b, start)));
    out
}

/// The ordering problem of one segment: groups as (start, end) pairs, a fixed origin
/// and an optional fixed finish.
struct Problem {
    starts: Vec<Point2<f64>>,
    ends: Vec<Point2<f64>>,
    /// The group may be entered at its end (reversible, or closed).
    flippable: Vec<bool>,
    origin: Point2<f64>,
    finish: Option<Point2<f64>>,
}

/// A visiting order: group index and whether it is entered at its end.
type Order = Vec<(usize, bool)>;

impl Problem {
    fn entry(&self, (g, r): (usize, bool)) -> Point2<f64> {
        if r { self.ends[g] } else { self.starts[g] }
    }
    fn exit(&self, (g, r): (usize, bool)) -> Point2<f64> {
        if r { self.starts[g] } else { self.ends[g] }
    }
    /// Endpoint `e` (2g = start, 2g+1 = end).
    fn point(&self, e: usize) -> Point2<f64> {
        if e.is_multiple_of(2) {
            self.starts[e / 2]
        } else {
            self.ends[e / 2]
        }
    }

    /// The XY travel of `order`: origin to the first group, between groups, the last
    /// group to the finish.
    fn cost(&self, order: &Order) -> f64 {
        let mut at = self.origin;
        let mut sum = 0.0;
        for &v in order {
            sum += (self.entry(v) - at).norm();
            at = self.exit(v);
        }
        if let Some(f) = self.finish {
            sum += (f - at).norm();
        }
        sum
    }

    /// Nearest neighbour, then bounded 2-opt / Or-opt.
    fn solve(&self, opt: &Options) -> Order {
        let n = self.starts.len();
        if n == 0 {
            return Vec::new();
        }
        let k = (opt.neighbours as usize).clamp(1, 2 * n);
        let near = self.neighbours(k);
        let mut order = self.nearest_neighbour(&near);
        if opt.two_opt && n > 1 {
            Improver::new(self, &near, &mut order).run(opt.max_sweeps);
        }
        order
    }

    /// For every endpoint, the `k` nearest endpoints of other groups, nearest first
    /// (ties by index), found by scanning outwards in X order.
    fn neighbours(&self, k: usize) -> Vec<Vec<usize>> {
        let m = 2 * self.starts.len();
        let mut by_x: Vec<usize> = (0..m).collect();
        by_x.sort_by(|&a, &b| {
            let (pa, pb) = (self.point(a), self.point(b));
            pa.x.total_cmp(&pb.x)
                .then(pa.y.total_cmp(&pb.y))
                .then(a.cmp(&b))
        });
        let mut rank = vec![0; m];
        for (r, &e) in by_x.iter().enumerate() {
            rank[e] = r;
        }
        let mut lists = Vec::with_capacity(m);
        for (e, &r) in rank.iter().enumerate() {
            let p = self.point(e);
            let mut best: Vec<(f64, usize)> = Vec::with_capacity(k + 1);
            let consider = |c: usize, best: &mut Vec<(f64, usize)>| {
                if c / 2 == e / 2 {
                    return;
                }
                let d = (self.point(c) - p).norm_squared();
                if best.len() == k && (d, c) >= best[k - 1] {
                    return;
                }
                let at = best.partition_point(|&x| x < (d, c));
                best.insert(at, (d, c));
                best.truncate(k);
            };
            // Leftwards and rightwards while the X gap can still beat the k-th best.
            for &c in by_x[..r].iter().rev() {
                let dx = p.x - self.point(c).x;
                if best.len() == k && dx * dx > best[k - 1].0 {
                    break;
                }
                consider(c, &mut best);
            }
            for &c in &by_x[r + 1..] {
                let dx = self.point(c).x - p.x;
                if best.len() == k && dx * dx > best[k - 1].0 {
                    break;
                }
                consider(c, &mut best);
            }
            lists.push(best.into_iter().map(|(_, c)| c).collect());
        }
        lists
    }

    /// Greedy: from the origin, always the nearest group not yet cut (either end when it
    /// may be entered there). Exact: the neighbour list, else a scan of all groups.
    fn nearest_neighbour(&self, near: &[Vec<usize>]) -> Order {
        let n = self.starts.len();
        let mut done = vec![false; n];
        let mut order = Vec::with_capacity(n);
        let mut at = self.origin;
        let mut from: Option<usize> = None;
        let usable = |e: usize, done: &[bool]| {
            !done[e / 2] && (e.is_multiple_of(2) || self.flippable[e / 2])
        };
        // Every group is taken, including the last one of the list (seed bug 1).
        for _ in 0..n {
            let listed = from.and_then(|e| near[e].iter().copied().find(|&c| usable(c, &done)));
            let pick = match listed {
                Some(c) => c,
                None => {
                    let mut best: Option<(f64, usize)> = None;
                    for c in 0..2 * n {
                        if !usable(c, &done) {
                            continue;
                        }
                        let d = (self.point(c) - at).norm_squared();
                        if best.is_none_or(|b| (d, c) < b) {
                            best = Some((d, c));
                        }
                    }
                    match best {
                        Some((_, c)) => c,
                        None => break,
                    }
                }
            };
            let v = (pick / 2, pick % 2 == 1);
            done[v.0] = true;
            order.push(v);
            at = self.exit(v);
            // The exit endpoint's index.
            from = Some(2 * v.0 + usize::from(!v.1));
        }
        order
    }
}

/// 2-opt and Or-opt over neighbour lists, first improvement, bounded sweeps.
struct Improver<'a> {
    p: &'a Problem,
    near: &'a [Vec<usize>],
    order: &'a mut Order,
    /// Position of each group in `order`.
    pos: Vec<usize>,
    /// `fixed[i]`: number of groups that cannot be flipped in `order[..i]`.
    fixed: Vec<usize>,
}

impl<'a> Improver<'a> {
    fn new(p: &'a Problem, near: &'a [Vec<usize>], order: &'a mut Order) -> Self {
        let mut s = Improver {
            p,
            near,
            order,
            pos: Vec::new(),
            fixed: Vec::new(),
        };
        s.reindex();
        s
    }

    fn reindex(&mut self) {
        let n = self.order.len();
        self.pos = vec![0; n];
        self.fixed = Vec::with_capacity(n + 1);
        self.fixed.push(0);
        for (i, &(g, _)) in self.order.iter().enumerate() {
            self.pos[g] = i;
            let last = self.fixed[i];
            self.fixed.push(last + usize::from(!self.p.flippable[g]));
        }
    }

    fn prev_exit(&self, i: usize) -> Point2<f64> {
        if i == 0 {
            self.p.origin
        } else {
            self.p.exit(self.order[i - 1])
        }
    }
    fn next_entry(&self, i: usize) -> Option<Point2<f64>> {
        if i + 1 < self.order.len() {
            Some(self.p.entry(self.order[i + 1]))
        } else {
            self.p.finish
        }
    }

    fn run(&mut self, max_sweeps: u32) {
        for _ in 0..max_sweeps {
            let a = self.two_opt_sweep();
            let b = self.or_opt_sweep();
            if !a && !b {
                break;
            }
        }
    }

    fn two_opt_sweep(&mut self) -> bool {
        let n = self.order.len();
        let mut improved = false;
        for i in 0..n {
            let cands: Vec<usize> = if i == 0 {
                (0..n).collect()
            } else {
                let (g, r) = self.order[i - 1];
                let exit_e = 2 * g + usize::from(!r);
                self.near[exit_e].iter().map(|&e| e / 2).collect()
            };
            for h in cands {
                let j = self.pos[h];
                if j < i || self.fixed[j + 1] != self.fixed[i] {
                    continue;
                }
                let pe = self.prev_exit(i);
                let ei = self.p.entry(self.order[i]);
                let xj = self.p.exit(self.order[j]);
                let delta = match self.next_entry(j) {
                    Some(nx) => {
                        (pe - xj).norm() + (ei - nx).norm() - (pe - ei).norm() - (xj - nx).norm()
                    }
                    None => (pe - xj).norm() - (pe - ei).norm(),
                };
                if delta < -EPS {
                    self.order[i..=j].reverse();
                    for v in &mut self.order[i..=j] {
                        v.1 = !v.1;
                    }
                    self.reindex();
                    improved = true;
                }
            }
        }
        improved
    }

    fn or_opt_sweep(&mut self) -> bool {
        let n = self.order.len();
        let mut improved = false;
        for g in 0..n {
            let k = self.pos[g];
            let cur = self.order[k];
            let a = self.prev_exit(k);
            let b = self.next_entry(k);
            let d = |x: Point2<f64>, y: Option<Point2<f64>>| y.map_or(0.0, |y| (x - y).norm());
            let removal = (self.p.entry(cur) - a).norm() + d(self.p.exit(cur), b) - d(a, b);
            let orients: &[bool] = if self.p.flippable[g] {
                &[false, true]
            } else {
                &[cur.1]
            };
            let mut best: Option<(f64, usize, bool)> = None;
            let mut cands: Vec<usize> = self.near[2 * g]
                .iter()
                .chain(&self.near[2 * g + 1])
                .map(|&e| e / 2)
                .collect();
            cands.sort_unstable();
            cands.dedup();
            for h in cands {
                let m = self.pos[h];
                // Insert after h (between h and what follows it once g is out), or before.
                for after in [true, false] {
                    let (x, y) = if after {
                        let y = if m + 1 == k { b } else { self.next_entry(m) };
                        (self.p.exit(self.order[m]), y)
                    } else {
                        let x = if m == k + 1 { a } else { self.prev_exit(m) };
                        (x, Some(self.p.entry(self.order[m])))
                    };
                    for &r in orients {
                        let v = (g, r);
                        let insert = (self.p.entry(v) - x).norm() + d(self.p.exit(v), y) - d(x, y);
                        let delta = insert - removal;
                        if delta < -EPS && best.is_none_or(|bb| delta < bb.0) {
                            // Index in the order without g.
                            let at = if after { m + 1 } else { m };
                            let at = if m > k { at - 1 } else { at };
                            best = Some((delta, at, r));
                        }
                    }
                }
            }
            if let Some((_, at, r)) = best {
                self.order.remove(k);
                self.order.insert(at, (g, r));
                self.reindex();
                improved = true;
            }
        }
        improved
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
            State::Passing => {
                let ends = matches!(block.kind, BlockKind::Motion(_));
                self.track.update(&block);
                out.push(block);
                if ends && self.above() {
                    self.state = State::Travel;
                }
            }
            State::Cutting { first } => {
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
                let retract =
                    matches!(block.kind, BlockKind::Motion(_)) && t.values[2] >= self.opt.cut_z;
                self.take(block);
                if retract {
                    self.close_group(first);
                    self.state = State::Travel;
                    if self.seg.groups.len() >= self.opt.max_groups as usize {
                        self.flush(End::Free, out);
                    }
                }
            }
            State::Travel => match &block.kind {
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
                    if !(matches!(m.kind, MotionKind::Rapid | MotionKind::Linear)
                        && m.extra.is_empty())
                    {
                        return self.barrier(block, End::Fixed, out);
                    }
                    let d = (xy(&t) - xy(self.track.pos())).norm();
                    if d > 0.0 {
                        self.seg.travel += d;
                        self.seg.height = self.seg.height.max(t.values[2]).max(self.track.pos().values[2]);
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
            },
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
