//! Arcs in the XY plane cut straight into polar pieces: every piece end is a point of the
//! arc, and each piece is the longest whose joint-linear path stays within the tolerance
//! of the arc itself, so the tolerance is spent once (cutting the arc into chords first and
//! then holding the polar path to the chords spends it twice, and gave about 1.9 times the
//! pieces needed).
//!
//! # The check
//! The arc (a circle, or the spiral of an arc whose end lies off the start's circle) is
//! `ρ(φ) = r0 + k (φ - φ0)` about its centre `c`. For a point `q` of the joint-linear path
//! the gap `g(q) = |q - c| - ρ(angle of q - c)` is the distance along the radius to the
//! arc, so the distance to the arc is at most `|g|`. Along the piece, with `w = q(u) - c`,
//! `|g''| <= |q''| (1 + |k|/ρ) + |q'|² (1/ρ + 2|k|/ρ²)`, `ρ` the least `|w|` (the
//! chord's distance from `c` less how far the path strays from its chord), and `|q'|`,
//! `|q''|` bounded from the joint deltas as for lines. Between two samples `a < b` the gap
//! is then within `max(|g(a)|, |g(b)|) + |g''| (b - a)² / 8`; the check samples the
//! middle of an interval only while that exceeds the tolerance, so it proves a piece
//! within tolerance and rejects it as soon as one sample is beyond. A piece whose whole
//! bound (its chord's deviation plus the arc's sagitta over it) is within tolerance needs
//! no sample. A piece turns at most 20° about the arc's centre ([`MAX_TURN`]), or as far
//! as a chord of half the tolerance on arcs of a few tenths of a millimetre.

use nalgebra::Vector2;

use crate::ir::{Arc, Axis, AxisSet, Block, BlockKind, FeedMode, Joints, Motion, MotionKind};
use crate::ir::{Plane, Target};
use crate::motion::arc::ArcPath;
use crate::passes::Output;
use crate::passes::densify::longest_piece;

use super::geometry::{Piece, PolarPoint, angle_between};
use super::moves::segment_distance;
use super::{MAX_ARC_CHORDS, PolarIk};

/// The most a piece turns about the arc's centre, radians (20°), unless the chords of half
/// the tolerance (how such arcs were cut before) turn further: a piece runs from one end
/// of its stretch of the arc to the other (a whole circle's ends coincide, and a piece
/// standing still would be "on the arc"), and its path is within 0.5 % of its chord's
/// length, which the passes after it count material and time by. Only arcs about the
/// table's centre have longer pieces within tolerance; arcs of a few tenths of a
/// millimetre get their chords' turn (up to half a turn).
const MAX_TURN: f64 = 0.35;

/// Bisection levels of one check before a piece is treated as beyond tolerance; only a
/// gap within rounding of the tolerance gets that deep.
const CHECK_LEVELS: u8 = 20;

/// An XY arc in the table's frame.
pub(super) struct ArcShape {
    /// The arc as the frontend resolved it (IR frame), for the other axes.
    pub path: ArcPath,
    /// The arc's centre relative to the table's centre, mm.
    centre: Vector2<f64>,
    /// Radius change per radian of the signed sweep, mm.
    k: f64,
    /// The least distance of the arc from the table's centre, mm (at least the margin).
    clearance: f64,
    /// The most a piece turns about the arc's centre, radians ([`MAX_TURN`]).
    max_turn: f64,
}

impl ArcShape {
    /// The shape of `path` (an XY arc) with the table's centre at `table` (IR frame), cut
    /// within `tolerance`; `None` when the arc may come within `margin` of the table's
    /// centre, where θ is undefined (such arcs go the way of chords, which handles the
    /// centre).
    pub fn new(path: ArcPath, table: [f64; 2], margin: f64, tolerance: f64) -> Option<ArcShape> {
        let centre = Vector2::new(path.centre[0] - table[0], path.centre[1] - table[1]);
        let (lo, hi) = (path.r0.min(path.r1), path.r0.max(path.r1));
        let d = centre.norm();
        if d >= lo - margin && d <= hi + margin {
            return None;
        }
        let clearance = if d > hi { d - hi } else { lo - d };
        let k = if path.sweep == 0.0 {
            0.0
        } else {
            (path.r1 - path.r0) / path.sweep
        };
        // The turn of a chord of half the tolerance (NaN, so half a turn, when the arc
        // is within that of its centre).
        let chord = 2.0 * (1.0 - 0.5 * tolerance / path.max_radius()).acos();
        let max_turn = if chord.is_nan() {
            std::f64::consts::PI
        } else {
            chord.clamp(MAX_TURN, std::f64::consts::PI)
        };
        // Whole pieces of the arc: where the turn is what limits them, they are equal.
        let sweep = path.sweep.abs();
        let max_turn = if sweep > 0.0 {
            sweep / (sweep / max_turn).ceil()
        } else {
            max_turn
        };
        Some(ArcShape {
            path,
            centre,
            k,
            clearance,
            max_turn,
        })
    }

    /// The XY point at parameter `t` (table frame).
    pub fn xy(&self, t: f64) -> Vector2<f64> {
        let phi = self.path.start_angle + self.path.sweep * t;
        let (s, c) = phi.sin_cos();
        self.centre + Vector2::new(c, s) * self.path.radius_at(t)
    }

    /// The greatest distance of the arc between parameters `t0` and `t1` from its chord
    /// (see [`ArcPath::sagitta`]).
    pub fn sagitta(&self, t0: f64, t1: f64) -> f64 {
        let half = (0.5 * self.path.sweep.abs() * (t1 - t0)).min(std::f64::consts::FRAC_PI_2);
        let r = self.path.radius_at(t0).max(self.path.radius_at(t1));
        let k = self.k.abs();
        r * (1.0 - half.cos()) + k * half * half * (4.0 + half * half).sqrt() / 2.0
    }

    /// Whether the joint-linear path between the piece ends `a` and `b` (parameters and
    /// polar points on the arc) stays within `tol` of the arc (module documentation).
    pub fn fits(&self, a: &(f64, PolarPoint), b: &(f64, PolarPoint), tol: f64) -> bool {
        if (b.0 - a.0).abs() * self.path.sweep.abs() > self.max_turn * (1.0 + 1e-9) {
            return false;
        }
        let (pa, pb) = (a.1, b.1);
        let (dr, dth) = (pb.r - pa.r, pb.theta - pa.theta);
        let turn = pa.r.abs().max(pb.r.abs()) * dth;
        let accel = dth.abs() * (turn * turn + 4.0 * dr * dr).sqrt();
        let strays = accel / 8.0;
        if strays + self.sagitta(a.0, b.0) <= tol {
            return true;
        }
        let (xa, xb) = (pa.xy(), pb.xy());
        let rho = segment_distance(&(xa - self.centre), &(xb - self.centre)) - strays;
        if rho <= 0.0 {
            return false;
        }
        let k = self.k.abs();
        let speed2 = dr * dr + turn * turn;
        let bound = accel * (1.0 + k / rho) + speed2 * (1.0 / rho + 2.0 * k / (rho * rho));
        let phi_a = self.path.start_angle + self.path.sweep * a.0;
        let wa = xa - self.centre;
        let gap = |u: f64| {
            let p = PolarPoint {
                r: pa.r + dr * u,
                theta: pa.theta + dth * u,
            };
            let w = p.xy() - self.centre;
            let phi = phi_a + angle_between(&wa, &w);
            w.norm() - (self.path.r0 + self.k * (phi - self.path.start_angle))
        };
        // (start, end, |gap| at both, level)
        let mut stack = [(0.0f64, 1.0f64, 0.0f64, 0.0f64, 0u8); CHECK_LEVELS as usize + 2];
        stack[0] = (0.0, 1.0, gap(0.0).abs(), gap(1.0).abs(), 0);
        let mut len = 1;
        while len > 0 {
            len -= 1;
            let (u0, u1, g0, g1, level) = stack[len];
            if g0.max(g1) + bound * (u1 - u0) * (u1 - u0) / 8.0 <= tol {
                continue;
            }
            if level >= CHECK_LEVELS {
                return false;
            }
            let um = 0.5 * (u0 + u1);
            let gm = gap(um).abs();
            if gm > tol {
                return false;
            }
            stack[len] = (um, u1, gm, g1, level + 1);
            stack[len + 1] = (u0, um, g0, gm, level + 1);
            len += 2;
        }
        true
    }
}

/// Plans the arc `shape` from polar position `start` into pieces within `tolerance`,
/// each as long as it may be, also split at the parameters `splits` (ascending, inside
/// `(0, 1)`: where the near-centre speed cap starts). Returns true when a piece would
/// have had to be shorter than `2^-max_depth` of the arc (the piece of that length is
/// kept, beyond tolerance).
pub(super) fn plan_arc(
    shape: &ArcShape,
    start: PolarPoint,
    tolerance: f64,
    max_depth: u32,
    splits: &[f64],
    pieces: &mut Vec<Piece>,
) -> bool {
    pieces.clear();
    let sign = if start.r < 0.0 { -1.0 } else { 1.0 };
    // θ of a later point from the one before, continuous: summed over steps that each
    // turn less than a quarter turn about the table's centre (the arc turns about it at
    // most at its speed over its least distance from it).
    let rate = shape.path.max_radius() * shape.path.sweep.abs() / shape.clearance;
    let at = |from: &(f64, PolarPoint), t: f64| {
        let steps = ((t - from.0).abs() * rate / 1.5).ceil().max(1.0);
        let mut theta = from.1.theta;
        let mut prev = shape.xy(from.0);
        for k in 1..=steps as usize {
            let p = shape.xy(from.0 + (t - from.0) * k as f64 / steps);
            theta += angle_between(&prev, &p);
            prev = p;
        }
        PolarPoint {
            r: sign * prev.norm(),
            theta,
        }
    };
    let min_step = 0.5f64.powi(max_depth as i32);
    let mut deep = false;
    let mut cur = (0.0, start);
    let mut guess: Option<f64> = None;
    for &end in splits.iter().chain(std::iter::once(&1.0)) {
        loop {
            let last = (end, at(&cur, end));
            if shape.fits(&cur, &last, tolerance) {
                pieces.push(piece(last));
                cur = last;
                break;
            }
            // The longest turn a piece may make, when it fits: then no search.
            let turn_end = cur.0 + shape.max_turn / shape.path.sweep.abs();
            if turn_end < end {
                let next = (turn_end, at(&cur, turn_end));
                if shape.fits(&cur, &next, tolerance) {
                    guess = Some(turn_end - cur.0);
                    pieces.push(piece(next));
                    cur = next;
                    continue;
                }
            }
            // The search runs over the stretch up to `end`, scaled to [0, 1].
            let span = end - cur.0;
            // The first guess: where the arc's own sagitta reaches the tolerance.
            let first =
                2.0 * (2.0 * tolerance / shape.path.max_radius()).sqrt() / shape.path.sweep.abs();
            let step = guess.unwrap_or(first).min(span) / span;
            let probe = |x: f64| {
                let next = (cur.0 + x * span, at(&cur, cur.0 + x * span));
                shape.fits(&cur, &next, tolerance).then_some(next)
            };
            let next = match longest_piece(0.0, step, min_step / span, probe) {
                Some((_, next)) => next,
                None => {
                    deep = true;
                    let t = (cur.0 + min_step).min(end);
                    (t, at(&cur, t))
                }
            };
            guess = Some(next.0 - cur.0);
            pieces.push(piece(next));
            cur = next;
            if cur.0 >= end {
                break;
            }
        }
    }
    deep
}

fn piece((s, to): (f64, PolarPoint)) -> Piece {
    Piece {
        s,
        to,
        rotate: false,
    }
}

/// The share of the arc's material laid down by the end of each piece: by the pieces'
/// straight XYZ lengths, which the nozzle follows within the tolerance, so every piece
/// gets the same material per millimetre (the pieces turn by different angles).
fn material_shares(path: &ArcPath, pieces: &[Piece]) -> Vec<f64> {
    let mut prev = path.from.xyz();
    let mut sums = Vec::with_capacity(pieces.len());
    let mut total = 0.0;
    for p in pieces {
        let at = path.point(p.s).xyz();
        total += (at - prev).norm();
        sums.push(total);
        prev = at;
    }
    if total > 0.0 {
        sums.iter_mut().for_each(|s| *s /= total);
    } else {
        sums = pieces.iter().map(|p| p.s).collect();
    }
    sums
}

/// The parameters in `(0, 1)`, ascending, where the arc crosses the circle of radius
/// `radius` about the table's centre (at its mean radius for a spiral).
pub(super) fn crossings(shape: &ArcShape, radius: f64) -> Vec<f64> {
    let c = shape.centre;
    let r = 0.5 * (shape.path.r0 + shape.path.r1);
    let d = c.norm();
    let mut out = Vec::new();
    if d == 0.0 || r == 0.0 {
        return out;
    }
    // |c + r e(φ)|² = radius²  ⇔  cos(φ - φc) = (radius² - d² - r²) / (2 r d)
    let cos = (radius * radius - d * d - r * r) / (2.0 * r * d);
    if !(-1.0..=1.0).contains(&cos) {
        return out;
    }
    let phi_c = c.y.atan2(c.x);
    let (sweep, start) = (shape.path.sweep, shape.path.start_angle);
    let tau = std::f64::consts::TAU;
    for psi in [phi_c + cos.acos(), phi_c - cos.acos()] {
        // Every turn of the arc that passes angle ψ.
        let first = (psi - start) / tau;
        let (lo, hi) = if sweep > 0.0 {
            (0.0, sweep / tau)
        } else {
            (sweep / tau, 0.0)
        };
        let mut n = (lo - first).ceil();
        while first + n <= hi {
            let t = (first + n) * tau / sweep;
            if t > 1e-9 && t < 1.0 - 1e-9 {
                out.push(t);
            }
            n += 1.0;
        }
    }
    out.sort_by(f64::total_cmp);
    out
}

impl PolarIk {
    /// The shape of an XY arc from `from` to `to` that is cut straight into polar pieces,
    /// or `None` for one that goes the way of chords (another plane, near the table's
    /// centre, or too long an arc, which is an error there).
    pub(super) fn direct_arc(&self, from: &Joints, to: &Joints, arc: &Arc) -> Option<ArcShape> {
        if arc.plane != Plane::XY {
            return None;
        }
        let path = ArcPath::new(from, to, arc)?;
        if path.chord_count(self.tolerance) > MAX_ARC_CHORDS {
            return None;
        }
        ArcShape::new(path, self.options.center, 1e-3, self.tolerance)
    }

    /// Emits an XY arc, from polar position `node`, as pieces on the arc (module
    /// documentation); returns the polar position it ends at. Z, E and the other axes move
    /// in proportion to the angle swept; the block's comments go on the last piece.
    pub(super) fn arc_move(
        &mut self,
        block: &Block,
        m: &Motion,
        shape: &ArcShape,
        node: PolarPoint,
        out: &mut Output<'_>,
    ) -> PolarPoint {
        let path = &shape.path;
        let total = path.length();
        let xy_len = path.stretch(0.0, 1.0).0;
        // The programmed speed along the arc, mm/s (or the programmed time's).
        let speed = match (m.feed.mode, m.feed.rate) {
            (FeedMode::PerMinute, Some(f)) if f > 0.0 => Some(f / 60.0),
            (FeedMode::InverseTime, Some(f)) if f > 0.0 && total > 0.0 => Some(total / (60.0 / f)),
            _ => None,
        };
        let splits = match speed {
            Some(v) if self.options.speed_cap && self.cap_rate > 0.0 && total > 0.0 => {
                crossings(shape, v * xy_len / total / self.cap_rate)
            }
            _ => Vec::new(),
        };
        let mut pieces = Vec::new();
        let deep = plan_arc(
            shape,
            node,
            self.tolerance,
            self.options.max_depth,
            &splits,
            &mut pieces,
        );
        if deep {
            self.warn_depth(block, out);
        }
        let xy = AxisSet::from_iter([Axis::X, Axis::Y]);
        let mut written = m.written.difference(xy);
        written.insert(self.polar.r_axis);
        written.insert(self.polar.theta_axis);
        let (mut prev_t, mut prev_node) = (0.0, node);
        let mut prev_joints = self.emitted(&path.from, &node);
        let count = pieces.len();
        let shares = material_shares(path, &pieces);
        for (i, piece) in pieces.iter().enumerate() {
            self.check_reach(&piece.to, block.span, out);
            let mut joints = path.point(piece.s);
            if let (Some(e0), Some(e1)) = (path.from.get(Axis::E), path.to.get(Axis::E))
                && i + 1 < count
            {
                joints.set(Axis::E, e0 + (e1 - e0) * shares[i]);
            }
            self.to_polar(&mut joints, &piece.to);
            let seconds = speed.map_or(0.0, |v| {
                let (piece_xy, len) = path.stretch(prev_t, piece.s);
                let mut t = len / v;
                if self.options.speed_cap && self.turns(&prev_node, &piece.to) {
                    // The piece's closest approach to the centre: its chord's, less
                    // how far the arc bulges from the chord.
                    let d = segment_distance(&prev_node.xy(), &piece.to.xy())
                        - shape.sagitta(prev_t, piece.s);
                    let cap = d * self.cap_rate;
                    if cap > 0.0 {
                        t = t.max(piece_xy / cap);
                    }
                }
                t
            });
            let motion = Motion {
                kind: MotionKind::Linear,
                target: Target::Joints(joints),
                feed: self.feed_for(&m.feed, &prev_joints, &joints, seconds),
                written,
                machine_frame: m.machine_frame,
                extra: m.extra.clone(),
            };
            let mut b = Block::new(block.span, BlockKind::Motion(motion));
            if i + 1 == count {
                b.comments.clone_from(&block.comments);
            }
            out.push(b);
            (prev_t, prev_node, prev_joints) = (piece.s, piece.to, joints);
        }
        prev_node
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn shape(from: [f64; 2], to: [f64; 2], centre: [f64; 2], clockwise: bool) -> ArcShape {
        let j = |p: [f64; 2]| {
            let mut j = Joints::default();
            j.set(Axis::X, p[0]);
            j.set(Axis::Y, p[1]);
            j
        };
        let arc = Arc {
            clockwise,
            plane: Plane::XY,
            center: Vector3::new(centre[0], centre[1], 0.0),
            extra_turns: 0,
        };
        let path = ArcPath::new(&j(from), &j(to), &arc).expect("arc");
        ArcShape::new(path, [0.0, 0.0], 1e-3, 0.01).expect("clear of the centre")
    }

    /// Where a full circle about (10, 0) crosses the circle of radius 8 about the centre.
    #[test]
    fn crossings_lie_on_the_circle() {
        let s = shape([5.0, 0.0], [5.0, 0.0], [10.0, 0.0], false);
        let t = crossings(&s, 8.0);
        assert_eq!(t.len(), 2, "{t:?}");
        for t in &t {
            assert!((s.xy(*t).norm() - 8.0).abs() < 1e-9);
        }
        assert!(crossings(&s, 2.0).is_empty());
    }

    /// About the table's centre an arc is exact in r and θ: a piece of up to its most
    /// turn fits. Off the centre the same sweep strays far, and a short piece fits.
    #[test]
    fn fits_measures_the_gap_to_the_arc() {
        let (s, c) = 0.5f64.sin_cos();
        let about = shape([20.0, 0.0], [20.0 * c, 20.0 * s], [0.0, 0.0], false);
        let at = |t: f64| {
            (
                t,
                PolarPoint {
                    r: 20.0,
                    theta: 0.5 * t,
                },
            )
        };
        // (The 0.5 rad arc turns 0.25 rad a piece at most: two equal pieces.)
        assert!(about.fits(&at(0.0), &at(0.5), 0.01));
        assert!(!about.fits(&at(0.0), &at(0.6), 0.01));
        let off = shape([30.0, 0.0], [20.0, 10.0], [20.0, 0.0], false);
        let node = |t: f64| {
            let p = off.xy(t);
            (
                t,
                PolarPoint {
                    r: p.norm(),
                    theta: p.y.atan2(p.x),
                },
            )
        };
        assert!(!off.fits(&node(0.0), &node(1.0), 0.01));
        assert!(off.fits(&node(0.0), &node(0.02), 0.01));
        // The proof agrees with sampling: the longest fitting piece strays close to the
        // tolerance.
        let mut lo = 0.02;
        let mut hi = 1.0;
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if off.fits(&node(0.0), &node(mid), 0.01) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let (pa, pb) = (node(0.0).1, node(lo).1);
        let worst = (0..=400)
            .map(|k| {
                let u = f64::from(k) / 400.0;
                let p = PolarPoint {
                    r: pa.r + (pb.r - pa.r) * u,
                    theta: pa.theta + (pb.theta - pa.theta) * u,
                };
                ((p.xy() - Vector2::new(20.0, 0.0)).norm() - 10.0).abs()
            })
            .fold(0.0, f64::max);
        assert!(worst <= 0.01 && worst > 0.009, "{worst}");
    }
}
