//! Emitting moves: each straight XY move (and each chord of an arc) becomes the pieces
//! [`plan`] cuts, in r and θ, with the feeds that keep the programmed speed.

use nalgebra::Vector2;

use crate::diag::Diagnostic;
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind, Target,
};

use super::geometry::{MAX_ARC_CHORDS, Piece, PolarPoint, arc_points, plan};
use super::{ORIGIN_EPS, Output, PolarIk};

/// A straight input move's lengths and programmed speed, for timing its pieces.
struct Line {
    p0: Vector2<f64>,
    p1: Vector2<f64>,
    /// XY length, mm.
    xy_len: f64,
    /// XYZ length, mm.
    cart_len: f64,
    /// The programmed XYZ speed, mm/s (`None`: a rapid or no feed).
    speed: Option<f64>,
    /// How far the polar path may stray from this line, mm.
    tolerance: f64,
}

/// The share of the tolerance each of the two cuts of an arc that goes the way of chords
/// gets (another plane, or passing the table's centre; see `arcs` for the others): the
/// chords stray from the arc and the polar path from the chords, so each gets half, and
/// the polar path stays within the whole tolerance of the arc.
const ARC_SHARE: f64 = 0.5;

impl PolarIk {
    /// The chords of an arc from the position to `to`, or, when it needs more than
    /// [`MAX_ARC_CHORDS`], an error at its line (the arc is dropped and the position
    /// moves to its end).
    fn chords_or_error(
        &mut self,
        block: &Block,
        to: &Joints,
        arc: &crate::ir::Arc,
        tolerance: f64,
        out: &mut Output<'_>,
    ) -> Option<Vec<Joints>> {
        match arc_points(self.track.pos(), to, arc, tolerance) {
            Ok(points) => Some(points),
            Err(needed) => {
                out.diag(
                    Diagnostic::error(
                        "polar-ik::chords",
                        format!(
                            "this arc needs {needed} chords to stay within {tolerance} mm; \
                             polar-ik makes at most {MAX_ARC_CHORDS} of one arc"
                        ),
                    )
                    .at_span(block.span)
                    .with_label("too long an arc")
                    .with_help(
                        "check the arc's centre offsets and P turns (a radius of kilometres \
                         is most likely a typo), or raise polar-ik's tolerance",
                    ),
                );
                self.track.set_pos(*to);
                None
            }
        }
    }

    /// `kinematics = "controller"`: arcs become chords, everything else passes.
    pub(super) fn run_controller(&mut self, block: Block, out: &mut Output<'_>) {
        if let BlockKind::Motion(m) = &block.kind
            && let (MotionKind::Arc(arc), &Target::Joints(to)) = (m.kind, &m.target)
        {
            let (a1, a2, _) = arc.plane.axes();
            let from = *self.track.pos();
            if from.known.contains(a1) && from.known.contains(a2) {
                let Some(points) = self.chords_or_error(&block, &to, &arc, self.tolerance, out)
                else {
                    return;
                };
                let n = points.len();
                let total = arc_length(&from, &points);
                let mut prev = from;
                for (i, p) in points.into_iter().enumerate() {
                    let mut piece = m.clone();
                    piece.kind = MotionKind::Linear;
                    piece.target = Target::Joints(p);
                    piece.feed = split_time_feed(&m.feed, &prev, &p, total);
                    prev = p;
                    let mut b = Block::new(block.span, BlockKind::Motion(piece));
                    if i + 1 == n {
                        b.comments.clone_from(&block.comments);
                    }
                    out.push(b);
                }
                self.track.set_pos(to);
                return;
            }
        }
        self.track.update(&block);
        out.push(block);
    }

    /// A motion block (`block` holds its span and comments, `m` the motion).
    pub(super) fn run_motion(&mut self, block: Block, m: Motion, out: &mut Output<'_>) {
        let Target::Joints(to) = m.target else {
            out.diag(
                Diagnostic::error(
                    "polar-ik::pose",
                    "polar-ik needs machine positions (G-code input), not tool poses",
                )
                .at_span(block.span),
            );
            out.push(block);
            return;
        };
        if m.machine_frame {
            self.machine_frame_move(block, m, out);
            return;
        }
        let Some(p1) = self.xy(&to) else {
            self.move_without_xy(block, m, &to, out);
            return;
        };
        let from = *self.track.pos();
        let (Some(_), Some(node)) = (self.xy(&from), self.node) else {
            self.first_point(block, m, &to, p1, out);
            return;
        };
        if let MotionKind::Arc(arc) = m.kind
            && let Some(shape) = self.direct_arc(&from, &to, &arc)
        {
            self.node = Some(self.arc_move(&block, &m, &shape, node, out));
            self.track.set_pos(to);
            return;
        }
        let chords;
        let points: &[Joints] = match m.kind {
            MotionKind::Arc(arc) => {
                let tolerance = ARC_SHARE * self.tolerance;
                let Some(points) = self.chords_or_error(&block, &to, &arc, tolerance, out) else {
                    return;
                };
                chords = points;
                &chords
            }
            _ => std::slice::from_ref(&to),
        };
        // An inverse-time feed's time is shared by length over the chords.
        let total = arc_length(&from, points);
        let n = points.len();
        let mut start = from;
        let mut node = node;
        for (i, p) in points.iter().enumerate() {
            let last = i + 1 == n;
            node = self.line(&block, &m, (&start, p), node, total, last, out);
            start = *p;
        }
        self.track.set_pos(to);
        self.node = Some(node);
    }

    /// A G53 move: passed on as written (X, Y renamed r, θ), the position unknown after.
    fn machine_frame_move(&mut self, block: Block, mut m: Motion, out: &mut Output<'_>) {
        out.diag(
            Diagnostic::warning(
                "polar-ik::machine-frame",
                "a G53 move is passed on as written; r and θ are unknown after it",
            )
            .at_span(block.span),
        );
        self.track.motion(&m);
        self.node = None;
        m.written = self.map_axes(m.written);
        if let Some(j) = m.target.joints_mut() {
            j.known = self.map_axes(j.known);
        }
        out.push(Block {
            kind: BlockKind::Motion(m),
            ..block
        });
    }

    /// A move to `to` where X and Y are not both known: it keeps its other axes.
    fn move_without_xy(&mut self, block: Block, mut m: Motion, to: &Joints, out: &mut Output<'_>) {
        let partial = to.known.contains(Axis::X) || to.known.contains(Axis::Y);
        if partial {
            out.diag(
                Diagnostic::error(
                    "polar-ik::partial-xy",
                    "only one of X and Y is known here, so r and θ cannot be computed (home both axes first)",
                )
                .at_span(block.span),
            );
        }
        if let Some(j) = m.target.joints_mut() {
            j.forget(AxisSet::from_iter([Axis::X, Axis::Y]));
        }
        m.written = m.written.difference(AxisSet::from_iter([Axis::X, Axis::Y]));
        self.track.set_pos(*to);
        self.node = None;
        out.push(Block {
            kind: BlockKind::Motion(m),
            ..block
        });
    }

    /// A move to `to` (XY `p1`) with no start known: the point on its own, θ from atan2
    /// except at the centre.
    fn first_point(
        &mut self,
        block: Block,
        mut m: Motion,
        to: &Joints,
        p1: Vector2<f64>,
        out: &mut Output<'_>,
    ) {
        let theta = if p1.norm() <= ORIGIN_EPS {
            0.0
        } else {
            p1.y.atan2(p1.x)
        };
        let p = PolarPoint {
            r: p1.norm(),
            theta,
        };
        m.kind = match m.kind {
            MotionKind::Arc(_) => MotionKind::Linear,
            k => k,
        };
        m.target = Target::Joints(self.emitted(to, &p));
        m.written = self.map_axes(m.written);
        self.check_reach(&p, block.span, out);
        self.track.set_pos(*to);
        self.node = Some(p);
        out.push(Block {
            kind: BlockKind::Motion(m),
            ..block
        });
    }

    /// Emits one straight input move between `ends`, from polar position `node`;
    /// returns the polar position it ends at. `total` is the whole input move's length
    /// (for an inverse-time feed), `last` whether this is its last straight part (which
    /// takes the block's comments).
    #[allow(clippy::too_many_arguments)]
    fn line(
        &mut self,
        block: &Block,
        m: &Motion,
        ends: (&Joints, &Joints),
        node: PolarPoint,
        total: f64,
        last: bool,
        out: &mut Output<'_>,
    ) -> PolarPoint {
        let (from, to) = ends;
        let (Some(p0), Some(p1)) = (self.xy(from), self.xy(to)) else {
            return node;
        };
        let rapid = m.kind == MotionKind::Rapid;
        let dz = match (from.get(Axis::Z), to.get(Axis::Z)) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        };
        let xy_len = (p1 - p0).norm();
        // The programmed XY(Z) speed, mm/s, or the programmed time of this piece.
        let speed = match (m.feed.mode, m.feed.rate) {
            (FeedMode::PerMinute, Some(f)) if f > 0.0 && !rapid => Some(f / 60.0),
            (FeedMode::InverseTime, Some(f)) if f > 0.0 && total > 0.0 => Some(total / (60.0 / f)),
            _ => None,
        };
        let line = Line {
            p0,
            p1,
            xy_len,
            cart_len: xy_len.hypot(dz),
            speed,
            tolerance: match m.kind {
                MotionKind::Arc(_) => ARC_SHARE * self.tolerance,
                _ => self.tolerance,
            },
        };
        let pieces = self.pieces_of(&line, node, rapid, block, out);
        let xy = AxisSet::from_iter([Axis::X, Axis::Y]);
        let mut written = m.written.difference(xy);
        if xy_len > 0.0 || !m.written.intersection(xy).is_empty() {
            written.insert(self.polar.r_axis);
            written.insert(self.polar.theta_axis);
        }
        let mut prev_s = 0.0;
        let mut prev_node = node;
        let mut prev_joints = self.emitted(from, &node);
        let count = pieces.len();
        for (i, piece) in pieces.iter().enumerate() {
            self.check_reach(&piece.to, block.span, out);
            let joints = self.piece_joints(from, to, piece.s, &piece.to);
            let feed = if rapid {
                m.feed
            } else {
                let seconds = self.piece_seconds(&line, piece, prev_s, &prev_node);
                self.feed_for(&m.feed, &prev_joints, &joints, seconds)
            };
            let motion = Motion {
                kind: if rapid {
                    MotionKind::Rapid
                } else {
                    MotionKind::Linear
                },
                target: Target::Joints(joints),
                feed,
                written,
                machine_frame: m.machine_frame,
                extra: m.extra.clone(),
            };
            let mut b = Block::new(block.span, BlockKind::Motion(motion));
            // The block's comments go on the last piece of the move.
            if last && i + 1 == count {
                b.comments.clone_from(&block.comments);
            }
            out.push(b);
            prev_s = piece.s;
            prev_node = piece.to;
            prev_joints = joints;
        }
        prev_node
    }

    /// The pieces of `line` from polar position `node`, within tolerance and split where
    /// the near-centre speed cap starts (a rapid that is not densified is one piece).
    fn pieces_of(
        &self,
        line: &Line,
        node: PolarPoint,
        rapid: bool,
        block: &Block,
        out: &mut Output<'_>,
    ) -> Vec<Piece> {
        let xy_speed = line.speed.map(|v| {
            if line.cart_len > 0.0 {
                v * line.xy_len / line.cart_len
            } else {
                v
            }
        });
        let cap_radius = match xy_speed {
            Some(v) if self.options.speed_cap && self.cap_rate > 0.0 => Some(v / self.cap_rate),
            _ => None,
        };
        // A rapid that is not densified is one piece: no tolerance holds it back.
        let (tolerance, max_depth, cap_radius) = if rapid && !self.options.rapids {
            (f64::INFINITY, 0, None)
        } else {
            (line.tolerance, self.options.max_depth, cap_radius)
        };
        let mut pieces = Vec::new();
        let deep = plan(
            line.p0,
            line.p1,
            node,
            self.policy,
            tolerance,
            max_depth,
            cap_radius,
            &mut pieces,
        );
        if deep {
            self.warn_depth(block, out);
        }
        pieces
    }

    /// The warning for a move that keeps a piece beyond tolerance (`max_depth`).
    pub(super) fn warn_depth(&self, block: &Block, out: &mut Output<'_>) {
        out.diag(
            Diagnostic::warning(
                "polar-ik::depth",
                format!(
                    "a piece of this move stays beyond tolerance: pieces would have to be shorter than 2^-{} of the move",
                    self.options.max_depth
                ),
            )
            .at_span(block.span),
        );
    }

    /// Seconds the piece `piece` of `line` (after parameter `prev_s`, polar position
    /// `prev_node`) takes: a turn on the spot at ω_max, else its length at the
    /// programmed speed, slowed by the near-centre cap where θ turns.
    fn piece_seconds(
        &self,
        line: &Line,
        piece: &Piece,
        prev_s: f64,
        prev_node: &PolarPoint,
    ) -> f64 {
        if piece.rotate {
            return (piece.to.theta - prev_node.theta).abs() / self.polar.omega_max.to_radians();
        }
        let len = (piece.s - prev_s) * line.cart_len;
        let piece_xy = (piece.s - prev_s) * line.xy_len;
        let Some(v) = line.speed else {
            return 0.0;
        };
        let mut t = len / v;
        if self.options.speed_cap && self.turns(prev_node, &piece.to) {
            let a = line.p0 + (line.p1 - line.p0) * prev_s;
            let b = line.p0 + (line.p1 - line.p0) * piece.s;
            let d = segment_distance(&a, &b);
            let cap = d * self.cap_rate;
            if cap > 0.0 {
                t = t.max(piece_xy / cap);
            }
        }
        t
    }
}

/// The summed XY(Z) length of the chords from `from` through `points`.
fn arc_length(from: &Joints, points: &[Joints]) -> f64 {
    let mut prev = from.xyz();
    let mut total = 0.0;
    for p in points {
        total += (p.xyz() - prev).norm();
        prev = p.xyz();
    }
    total
}

/// The feed of one chord of a split G93 move (the time is shared by length); a per-minute
/// feed stays.
fn split_time_feed(feed: &Feed, a: &Joints, b: &Joints, total: f64) -> Feed {
    match (feed.mode, feed.rate) {
        (FeedMode::InverseTime, Some(f)) if total > 0.0 => {
            let frac = (b.xyz() - a.xyz()).norm() / total;
            Feed {
                mode: FeedMode::InverseTime,
                rate: Some(if frac > 0.0 { f / frac } else { f }),
            }
        }
        _ => *feed,
    }
}

/// Distance from the centre to the segment `a`–`b`.
pub(super) fn segment_distance(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let d = b - a;
    let len2 = d.norm_squared();
    if len2 == 0.0 {
        return a.norm();
    }
    let s = (-a.dot(&d) / len2).clamp(0.0, 1.0);
    (a + d * s).norm()
}
