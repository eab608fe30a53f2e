//! The look-ahead of `ik`: both branches of every pose in a window reaching the next rapid,
//! chosen together by dynamic programming.
//!
//! Each pose has at most two cells, one per branch (or, inside the singularity cone, one
//! per branch of the pose before it, with the free rotary held at that branch's value).
//! A cell keeps the best way to reach it from the window's start: its score (flips, then
//! rotary travel, then the preferred sign at the start) and the cell of the pose before
//! it. When the window ends, the best cell of the last pose is followed back, and the
//! blocks go out with the branches found. The work per pose is a fixed handful of
//! inverse-kinematics solutions and comparisons; the window's buffers are kept between
//! windows, so a pose allocates nothing once they have grown.

use std::fmt::Write as _;

use nalgebra::{Unit, Vector3};

use super::{Choice, Ik, TIE};
use crate::ir::{Block, BlockKind, Span, Target};
use crate::machine::Turns;
use crate::machine::angle::near_turn;
use crate::passes::Output;

/// Most poses the look-ahead holds: a cut longer than this without a rapid is decided in
/// windows of this many poses, each continuing from the choice of the one before. It
/// bounds the memory (the poses, their blocks and the comments between them) and the delay
/// before the first block of a window goes out.
pub const MAX_WINDOW: usize = 4096;

/// Totals of rotary travel closer than this (degrees) are a tie, decided by the
/// preferred sign: the twin branches of a path travel the same, up to rounding.
const TOTAL_TIE: f64 = 1e-6;

/// How good a way to a cell is; lower is better, in this order.
#[derive(Debug, Clone, Copy)]
struct Score {
    /// Cutting moves that flip to the other solution.
    flips: u32,
    /// The sum over the moves of the largest rotary change, degrees.
    largest: f64,
    /// The sum over the moves of both rotary changes, degrees.
    sum: f64,
    /// Whether the branch at the window's start has the preferred sign (better).
    preferred: bool,
}

impl Score {
    /// Whether `self` is clearly better than `other`.
    fn better(&self, other: &Score) -> bool {
        if self.flips != other.flips {
            return self.flips < other.flips;
        }
        if (self.largest - other.largest).abs() > TOTAL_TIE {
            return self.largest < other.largest;
        }
        if (self.sum - other.sum).abs() > TOTAL_TIE {
            return self.sum < other.sum;
        }
        self.preferred && !other.preferred
    }
}

/// One branch of a pose and the best way to it.
#[derive(Debug, Clone, Copy)]
struct Cell {
    choice: Choice,
    /// The cell of the previous live pose this one is reached from; `None` at the start.
    from: Option<u8>,
    score: Score,
}

/// A pose of the window.
#[derive(Debug, Clone, Copy)]
struct Point {
    axis: Unit<Vector3<f64>>,
    cutting: bool,
    line: u32,
    /// Both branches; none when the pose is out of reach (`ik::unreachable`).
    cells: [Option<Cell>; 2],
    /// The previous pose with a cell.
    prev_live: Option<usize>,
    /// The cell the window chose.
    chosen: Option<u8>,
}

/// The poses waiting for their branches and the blocks among them, in order.
#[derive(Debug, Default)]
pub struct Window {
    /// Every block since the window started, poses and the blocks between them.
    pub pending: Vec<Block>,
    points: Vec<Point>,
    last_live: Option<usize>,
}

impl Window {
    /// Whether nothing waits.
    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }

    /// Whether the window holds [`MAX_WINDOW`] poses, or twice as many blocks (comments
    /// and commands between the poses count too, so memory stays bounded).
    pub fn full(&self) -> bool {
        self.points.len() >= MAX_WINDOW || self.pending.len() >= 2 * MAX_WINDOW
    }
}

/// Whether `block` (not a pose) leaves the position the next pose starts from as it is, so
/// it may wait in the window: comments, dwells, commands that clobber no axis.
pub fn keeps_position(block: &Block) -> bool {
    if crate::ir::frame_not_applied(block) {
        return false;
    }
    match &block.kind {
        BlockKind::Comment | BlockKind::Dwell { .. } => true,
        BlockKind::Command(c) => c.clobbers.is_empty(),
        BlockKind::Verbatim(v) => v.clobbers.is_empty(),
        BlockKind::Motion(_) | BlockKind::Offset(_) => false,
    }
}

/// A branch within the limits: its rotary values, their cost from the walked values and
/// the sines and cosines of the solution.
type Reached = ([f64; 2], (f64, f64), Turns);

/// Where a way into a new pose comes from: a cell of the pose before, or the joints the
/// window starts from.
#[derive(Clone, Copy)]
struct From {
    angles: [Option<f64>; 2],
    axis: Option<Unit<Vector3<f64>>>,
    score: Option<Score>,
    cell: Option<u8>,
    /// The rotary a rapid left held at a singular pose: the swing the next cut needs of it
    /// is made at that rapid (`Ik::spread_swing`), so it is no flip of the cut.
    swings_at_rapid: Option<usize>,
}

impl Ik {
    /// Adds the pose with tool axis `axis` (at `span`) to the window: the best way to each
    /// of its branches from those of the pose before. A pose no branch reaches is reported
    /// at once (`ik::unreachable`), as the block is read: its block will be left out.
    pub(super) fn look(
        &mut self,
        axis: Unit<Vector3<f64>>,
        cutting: bool,
        span: Span,
        out: &mut Output<'_>,
    ) {
        let line = span.line;
        let froms: [Option<From>; 2] = match self.window.last_live {
            Some(i) => {
                let p = &self.window.points[i];
                [0, 1].map(|c| {
                    p.cells[c].map(|cell| From {
                        angles: cell.choice.angles.map(Some),
                        axis: Some(p.axis),
                        score: Some(cell.score),
                        cell: Some(c as u8),
                        swings_at_rapid: cell.choice.held.filter(|_| !p.cutting),
                    })
                })
            }
            None => [
                Some(From {
                    angles: self.prev_angles(),
                    axis: self.committed_axis(),
                    score: None,
                    cell: None,
                    swings_at_rapid: self.held.filter(|_| self.held_rapid.is_some()),
                }),
                None,
            ],
        };
        let solutions = self.machine.inverse(axis);
        let free = solutions.iter().find_map(|o| o.free);
        let singular = (free.is_some() || solutions.singularity_cos > self.cone_cos)
            .then(|| free.unwrap_or_else(|| self.machine.singular_rotary(axis)));
        let mut cells: [Option<Cell>; 2] = [None, None];
        for (slot, from) in froms.iter().enumerate() {
            let Some(from) = from else { continue };
            let walked = match (cutting, from.axis) {
                (true, Some(prev_axis)) => self.walked_from(prev_axis, axis, from.angles),
                _ => from.angles,
            };
            let held = singular.and_then(|k| self.held_choice(axis, k, walked));
            if let Some(choice) = held {
                self.offer(&mut cells, slot, choice, walked, from);
                continue;
            }
            let mut actual = from.angles;
            if let Some(k) = from.swings_at_rapid {
                actual[k] = None;
            }
            for (k, mut choice) in self.branches(&solutions, cutting, walked, actual) {
                // A singular pose with the free rotary unknown before it (the program's
                // first): its value is as arbitrary as a held one, and the move leaving
                // the singularity treats it so (`Ik::spread_swing`).
                if singular.is_some_and(|f| walked[f].is_none()) {
                    choice.held = singular;
                }
                self.offer(&mut cells, k, choice, walked, from);
            }
        }
        let index = self.window.points.len();
        let live = cells.iter().any(Option::is_some);
        self.window.points.push(Point {
            axis,
            cutting,
            line,
            cells,
            prev_live: self.window.last_live,
            chosen: None,
        });
        if live {
            self.window.last_live = Some(index);
        } else {
            out.diag(self.unreachable(axis).at_span(span));
        }
    }

    /// Inside the singularity cone with rotary `k` free: `k` held at its walked value and
    /// the other one turning the tool, when that one is within its limits.
    fn held_choice(
        &self,
        axis: Unit<Vector3<f64>>,
        k: usize,
        walked: [Option<f64>; 2],
    ) -> Option<Choice> {
        let pk = walked[k]?;
        let o = self.machine.hold(axis, k, pk);
        let j = 1 - k;
        let v = self.in_limits(j, o.angles[j], walked[j])?;
        let mut angles = [0.0; 2];
        angles[k] = pk;
        angles[j] = v;
        Some(Choice {
            angles,
            held: Some(k),
            flip: None,
            trig: None,
        })
    }

    /// Both branches of `solutions` within the limits, at the turns that suit `walked`
    /// (the rotaries the move would reach continuing its path), each marked as a flip when
    /// a cutting move reaches it only by leaving a nearer branch that is out of limits and
    /// turns a rotary more than `max_cutting_jump` from `actual`; while the nearer branch
    /// is within the limits, such a branch is not offered.
    fn branches(
        &self,
        solutions: &crate::machine::Solutions,
        cutting: bool,
        walked: [Option<f64>; 2],
        actual: [Option<f64>; 2],
    ) -> impl Iterator<Item = (usize, Choice)> {
        let mut nearest: Option<([f64; 2], (f64, f64))> = None;
        let mut found: [Option<Reached>; 2] = [None, None];
        for (k, o) in solutions.iter().enumerate() {
            let c = self.candidate(o, walked);
            if nearest.is_none_or(|(_, nc)| Self::less(c.unlimited_cost, nc) == Some(true)) {
                nearest = Some((c.unlimited, c.unlimited_cost));
            }
            found[k] = c
                .limited
                .map(|(angles, cost)| (angles, cost, solutions.sin_cos(k)));
        }
        let known = walked.iter().all(Option::is_some);
        let max_jump = self.options.max_cutting_jump;
        let jumps = found.map(|f| f.map(|(angles, _, _)| self.cost(angles, actual).0));
        let near_reachable = nearest.is_some_and(|(near, _)| self.outside(near).is_none());
        (0..2).filter_map(move |k| {
            let (angles, cost, trig) = found[k]?;
            let (near, near_cost) = nearest?;
            let jump = jumps[k]?;
            let flip = (cutting && known && near_cost.0 < cost.0 - TIE && jump > max_jump)
                .then_some((near, jump));
            // A flip is made only where the path leaves the reach of its branch: while
            // that branch goes on, leaving it in the cut is no choice at all.
            if flip.is_some() && near_reachable {
                return None;
            }
            Some((
                k,
                Choice {
                    angles,
                    held: None,
                    flip,
                    trig: Some(trig),
                },
            ))
        })
    }

    /// Takes `choice` into `cells[slot]` when the way to it from `from` is better than the
    /// one there.
    fn offer(
        &self,
        cells: &mut [Option<Cell>; 2],
        slot: usize,
        choice: Choice,
        walked: [Option<f64>; 2],
        from: &From,
    ) {
        let (largest, sum) = self.cost(choice.angles, walked);
        let flip = u32::from(choice.flip.is_some());
        let score = match from.score {
            Some(s) => Score {
                flips: s.flips + flip,
                largest: s.largest + largest,
                sum: s.sum + sum,
                preferred: s.preferred,
            },
            None => Score {
                flips: flip,
                largest,
                sum,
                preferred: self.preferred(choice.angles),
            },
        };
        if cells[slot].is_none_or(|c| score.better(&c.score)) {
            cells[slot] = Some(Cell {
                choice,
                from: from.cell,
                score,
            });
        }
    }

    /// Chooses the branches of the window's poses and puts its blocks out, in order.
    pub(super) fn flush(&mut self, out: &mut Output<'_>) {
        if self.window.is_empty() {
            return;
        }
        self.choose_back();
        let mut points = std::mem::take(&mut self.window.points);
        let mut pending = std::mem::take(&mut self.window.pending);
        let flips = points
            .iter()
            .any(|p| chosen(p).is_some_and(|c| c.flip.is_some()));
        let why = flips.then(|| self.no_flip_free(&points));
        let mut next = points.iter();
        for block in pending.drain(..) {
            let is_pose =
                matches!(&block.kind, BlockKind::Motion(m) if matches!(m.target, Target::Pose(_)));
            if !is_pose {
                self.track(&block);
                out.push(block);
                continue;
            }
            let Some(point) = next.next() else {
                continue;
            };
            // Out of reach: reported when it was read, and left out.
            if let Some(choice) = chosen(point) {
                self.emit(block, &choice, why.as_deref(), out);
            }
        }
        points.clear();
        self.window.points = points;
        self.window.pending = pending;
        self.window.last_live = None;
    }

    /// Marks the chosen cell of every live pose: the best of the last one, and the way
    /// back from it (on a tie, the cell with the preferred sign, then the first).
    fn choose_back(&mut self) {
        let Some(last) = self.window.last_live else {
            return;
        };
        let cells = self.window.points[last].cells;
        let mut best: Option<(usize, Score)> = None;
        for (k, cell) in cells.iter().enumerate() {
            let Some(cell) = cell else { continue };
            let better = match best {
                None => true,
                Some((b, s)) => {
                    cell.score.better(&s)
                        || (!s.better(&cell.score)
                            && self.preferred(cell.choice.angles)
                            && cells[b].is_some_and(|c| !self.preferred(c.choice.angles)))
                }
            };
            if better {
                best = Some((k, cell.score));
            }
        }
        let Some((mut k, _)) = best else { return };
        let points = &mut self.window.points;
        let mut i = last;
        loop {
            points[i].chosen = Some(k as u8);
            let from = points[i].cells[k].and_then(|c| c.from);
            match (points[i].prev_live, from) {
                (Some(p), Some(f)) => {
                    i = p;
                    k = usize::from(f);
                }
                _ => break,
            }
        }
    }

    /// Why no flip-free choice exists in the window of `points`: from each branch of its
    /// first pose, followed continuously, the first limit it leaves and where.
    fn no_flip_free(&self, points: &[Point]) -> String {
        let Some(first) = points
            .iter()
            .position(|p| p.cells.iter().any(Option::is_some))
        else {
            return String::new();
        };
        let start = &points[first];
        let near = start
            .cells
            .iter()
            .flatten()
            .next()
            .map(|c| c.choice.angles.map(Some))
            .unwrap_or([None; 2]);
        let mut text = String::new();
        for o in &self.machine.inverse(start.axis) {
            // Each rotary inside its range where a turn of it is, so that the message
            // names the rotary that cannot reach.
            let unlimited = self.candidate(o, near).unlimited;
            let from = [0, 1].map(|i| {
                self.in_limits(i, o.angles[i], near[i])
                    .unwrap_or(unlimited[i])
            });
            if !text.is_empty() {
                text.push_str("; ");
            }
            let _ = write!(text, "from {} at line {}, ", self.show(from), start.line);
            if let Some(why) = self.outside(from) {
                let _ = write!(text, "{why} there");
                continue;
            }
            let continues = start.cells.iter().flatten().any(|c| {
                c.choice.flip.is_none()
                    && (0..2).all(|i| {
                        let d = (c.choice.angles[i] - from[i]).rem_euclid(360.0);
                        d.min(360.0 - d) < 1e-6
                    })
            });
            if start.cutting && !continues {
                text.push_str("a flip away from the joints before it");
                continue;
            }
            match self.blocked(from, start.axis, &points[first + 1..]) {
                Some((line, why)) => {
                    let _ = write!(text, "{why} at line {line}");
                }
                None => text.push_str("the path stays within the limits"),
            }
        }
        let _ = write!(
            text,
            " (the look-ahead starts at line {}, {}, and reaches at most {MAX_WINDOW} poses)",
            start.line,
            if start.cutting {
                "inside a cut whose branch was chosen before"
            } else {
                "a rapid"
            }
        );
        text
    }

    /// Following the branch at `angles` (tool axis `axis`) through `points` without a
    /// flip: the line and the limit where it first leaves the rotaries' range.
    fn blocked(
        &self,
        mut angles: [f64; 2],
        mut axis: Unit<Vector3<f64>>,
        points: &[Point],
    ) -> Option<(u32, String)> {
        for p in points
            .iter()
            .filter(|p| p.cells.iter().any(Option::is_some))
        {
            let cur = angles.map(Some);
            let walked = if p.cutting {
                self.walked_from(axis, p.axis, cur)
            } else {
                cur
            };
            let w = [
                walked[0].unwrap_or(angles[0]),
                walked[1].unwrap_or(angles[1]),
            ];
            angles = self.continuous(p.axis, w);
            axis = p.axis;
            if let Some(why) = self.outside(angles) {
                return Some((p.line, why));
            }
        }
        None
    }

    /// The rotaries pointing the tool along `axis` nearest `walked`, limits ignored (the
    /// free rotary held inside the singularity cone).
    pub(super) fn continuous(&self, axis: Unit<Vector3<f64>>, walked: [f64; 2]) -> [f64; 2] {
        let solutions = self.machine.inverse(axis);
        let free = solutions.iter().find_map(|o| o.free);
        if free.is_some() || solutions.singularity_cos > self.cone_cos {
            let k = free.unwrap_or_else(|| self.machine.singular_rotary(axis));
            let o = self.machine.hold(axis, k, walked[k]);
            let mut a = walked;
            a[1 - k] = near_turn(o.angles[1 - k], walked[1 - k]);
            return a;
        }
        let mut best: Option<([f64; 2], (f64, f64))> = None;
        for o in &solutions {
            let c = self.candidate(o, walked.map(Some));
            if best.is_none_or(|(_, bc)| Self::less(c.unlimited_cost, bc) == Some(true)) {
                best = Some((c.unlimited, c.unlimited_cost));
            }
        }
        best.map_or(walked, |(a, _)| a)
    }

    /// Rotary values for messages: `B30.000 C180.000`.
    fn show(&self, angles: [f64; 2]) -> String {
        format!(
            "{}{:.3} {}{:.3}",
            self.axes[0].letter(),
            angles[0],
            self.axes[1].letter(),
            angles[1]
        )
    }
}

/// The choice the window made for `point`; `None` when it is out of reach.
fn chosen(point: &Point) -> Option<Choice> {
    point
        .chosen
        .and_then(|k| point.cells[usize::from(k)])
        .map(|c| c.choice)
}
