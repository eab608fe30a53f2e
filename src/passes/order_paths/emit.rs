//! Writing an ordered segment: travels between the groups, reversed groups, and the
//! way back to where the input left the tool.

use super::tour::{Order, Problem};
use super::{EPS, End, OrderPaths, Segment, State, xy, xyz_known};
use nalgebra::Point2;

use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind, Span, Target,
};
use crate::passes::Output;

impl OrderPaths {
    /// Orders and writes the segment.
    pub(super) fn flush(&mut self, end: End, out: &mut Output<'_>) {
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
        let (order, _work) = problem.solve(&self.opt);
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
        let blocks = &seg.blocks;
        let mut visit = order.clone();
        if pinned {
            visit.push((n, false));
        }
        let mut cur = self.visit(&seg, visit, start, out);
        if pinned {
            self.track.set_pos(cur);
            self.state = State::Passing;
            return;
        }
        // The tail: comments after the last group, then back to where the input was.
        let tail = seg.pending..blocks.len();
        let span = blocks.last().map(|b| b.span).unwrap_or_default();
        let feed = first_feed(&blocks[seg.groups[n - 1].blocks.clone()]);
        put_comments(&blocks[tail], out);
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

    /// Writes the groups of `seg` in the order `visit`, each after a travel from where
    /// the last one left the tool, starting at `start`; returns where the last one ends.
    fn visit(
        &mut self,
        seg: &Segment,
        visit: Order,
        start: Joints,
        out: &mut Output<'_>,
    ) -> Joints {
        let blocks = &seg.blocks;
        let mut cur = start;
        for (gi, rev) in visit {
            let g = &seg.groups[gi];
            put_comments(&blocks[g.lead.clone()], out);
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
        cur
    }
}

/// The comments of `blocks`, on lines of their own (the blocks stay where they were).
fn put_comments(blocks: &[Block], out: &mut Output<'_>) {
    for b in blocks {
        if !b.comments.is_empty() {
            let mut c = Block::new(b.span, BlockKind::Comment);
            c.comments = b.comments.clone();
            out.push(c);
        }
    }
}

/// The position before `blocks[k]`, walking from `from` at `blocks[0]`.
pub(super) fn position_before(blocks: &[Block], k: usize, from: Joints) -> Joints {
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
