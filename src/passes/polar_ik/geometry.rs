//! The geometry of `polar-ik`: inverse kinematics of a point on a straight XY move, the
//! error bound of a joint-linear piece, and cutting a move into pieces within tolerance.

use nalgebra::Vector2;
use smallvec::SmallVec;

use crate::ir::{Arc, Joints};
use crate::machine::polar::OriginPolicy;
use crate::motion::arc::ArcPath;

use super::ORIGIN_EPS;

/// A polar joint position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolarPoint {
    /// Arm radius, mm (negative past the centre under `signed-radius`).
    pub r: f64,
    /// Table angle, radians, continuous.
    pub theta: f64,
}

impl PolarPoint {
    /// The XY point the nozzle is at (forward kinematics).
    pub fn xy(&self) -> Vector2<f64> {
        Vector2::new(self.r * self.theta.cos(), self.r * self.theta.sin())
    }
}

/// One emitted piece of a move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Piece {
    /// The XY parameter (0 at the move's start, 1 at its end) the piece ends at.
    pub s: f64,
    /// The joint position it ends at.
    pub to: PolarPoint,
    /// A turn of the table on the spot at the centre (no XY motion).
    pub rotate: bool,
}

/// The bound `|Δθ| √((max(|r_a|, |r_b|) Δθ)² + (2 Δr)²) / 8` of the distance between the
/// joint-linear path from `a` to `b` and the chord between their XY points.
///
/// ```
/// use ncpost::passes::polar_ik::{error_bound, PolarPoint};
/// let a = PolarPoint { r: 100.0, theta: 0.0 };
/// let b = PolarPoint { r: 100.0, theta: 0.01 };
/// // an arc of radius 100 over 0.01 rad: sagitta 100 (1 - cos 0.005) = 0.00125 mm
/// assert!((error_bound(&a, &b) - 0.00125).abs() < 1e-6);
/// ```
pub fn error_bound(a: &PolarPoint, b: &PolarPoint) -> f64 {
    let dt = b.theta - a.theta;
    let dr = b.r - a.r;
    let turn = a.r.abs().max(b.r.abs()) * dt;
    dt.abs() * (turn * turn + 4.0 * dr * dr).sqrt() / 8.0
}

/// The signed angle from `a` to `b`, in `(−π, π]`.
pub(super) fn angle_between(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    (a.x * b.y - a.y * b.x).atan2(a.dot(b))
}

/// The whole turn of `angle` nearest to `reference` (radians).
fn nearest_turn(angle: f64, reference: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    angle + tau * crate::machine::angle::round((reference - angle) / tau)
}

/// Plans one straight XY move from `p0` (where the machine is at `start`) to `p1`: the
/// pieces to emit, in order, the last ending at `s = 1`, into `pieces` (cleared first, so a
/// caller keeps one buffer for every move).
///
/// `cap_radius`, when given, is the distance from the centre inside which the speed cap
/// lowers the feed: the move is also split where it crosses that circle. Returns true when
/// a piece would have had to be shorter than `2^-max_depth` of the move.
///
/// ```
/// use nalgebra::Vector2;
/// use ncpost::machine::polar::OriginPolicy;
/// use ncpost::passes::polar_ik::{plan, PolarPoint};
/// let start = PolarPoint { r: 10.0, theta: 0.0 };
/// let mut pieces = Vec::new();
/// plan(Vector2::new(10.0, 0.0), Vector2::new(-10.0, 0.0), start,
///     OriginPolicy::SignedRadius, 0.01, 24, None, &mut pieces);
/// assert_eq!(pieces.len(), 1);
/// assert_eq!(pieces[0].to, PolarPoint { r: -10.0, theta: 0.0 });
/// ```
#[allow(clippy::too_many_arguments)]
pub fn plan(
    p0: Vector2<f64>,
    p1: Vector2<f64>,
    start: PolarPoint,
    policy: OriginPolicy,
    tolerance: f64,
    max_depth: u32,
    cap_radius: Option<f64>,
    pieces: &mut Vec<Piece>,
) -> bool {
    let d = p1 - p0;
    let len2 = d.norm_squared();
    pieces.clear();
    let piece = |s: f64, to: PolarPoint| Piece {
        s,
        to,
        rotate: false,
    };
    if len2.sqrt() <= ORIGIN_EPS {
        pieces.push(piece(1.0, start));
        return false;
    }
    if p0.norm() <= ORIGIN_EPS {
        leave_centre(p1, start, policy, pieces);
        return false;
    }
    if p1.norm() <= ORIGIN_EPS {
        // Arriving at the centre: radial, θ kept.
        pieces.push(piece(
            1.0,
            PolarPoint {
                r: 0.0,
                theta: start.theta,
            },
        ));
        return false;
    }
    let s_close = -p0.dot(&d) / len2;
    let line_dist = (p0.x * d.y - p0.y * d.x).abs() / len2.sqrt();
    if line_dist <= ORIGIN_EPS && s_close > 0.0 && s_close < 1.0 {
        through_centre(p0, p1, s_close, start, policy, pieces);
        return false;
    }
    // The general case: the line misses the centre, so it subtends less than 180°.
    let sign = if start.r < 0.0 { -1.0 } else { 1.0 };
    let at = |s: f64| {
        let p = p0 + d * s;
        PolarPoint {
            r: sign * p.norm(),
            theta: start.theta + angle_between(&p0, &p),
        }
    };
    let mut splits: SmallVec<[f64; 4]> = SmallVec::new();
    splits.push(0.0);
    if let Some(rc) = cap_radius {
        // |p0 + s d|² = rc²
        let b = p0.dot(&d);
        let c = p0.norm_squared() - rc * rc;
        let disc = b * b - len2 * c;
        if disc > 0.0 {
            let root = disc.sqrt();
            for s in [(-b - root) / len2, (-b + root) / len2] {
                if s > 1e-9 && s < 1.0 - 1e-9 {
                    splits.push(s);
                }
            }
        }
    }
    splits.push(1.0);
    let mut deep = false;
    let mut a = start;
    for w in splits.windows(2) {
        let b = at(w[1]);
        refine(
            &at,
            (w[0], a),
            (w[1], b),
            tolerance,
            max_depth,
            pieces,
            &mut deep,
        );
        a = b;
    }
    deep
}

/// A move leaving the centre for `p1`: radial, so one piece; only θ may have to turn
/// first (on the spot), to the nearer of the two ways under `signed-radius`.
fn leave_centre(
    p1: Vector2<f64>,
    start: PolarPoint,
    policy: OriginPolicy,
    pieces: &mut Vec<Piece>,
) {
    let phi = p1.y.atan2(p1.x);
    let plus = nearest_turn(phi, start.theta);
    let mut out = PolarPoint {
        r: p1.norm(),
        theta: plus,
    };
    if policy == OriginPolicy::SignedRadius {
        let minus = nearest_turn(phi + std::f64::consts::PI, start.theta);
        if (minus - start.theta).abs() < (plus - start.theta).abs() {
            out = PolarPoint {
                r: -p1.norm(),
                theta: minus,
            };
        }
    }
    if (out.theta - start.theta).abs() > 1e-12 {
        pieces.push(Piece {
            s: 0.0,
            to: PolarPoint {
                r: 0.0,
                theta: out.theta,
            },
            rotate: true,
        });
    }
    pieces.push(Piece {
        s: 1.0,
        to: out,
        rotate: false,
    });
}

/// A move from `p0` to `p1` through the centre (at parameter `s_close`): under
/// `signed-radius` the arm passes the centre on one radial piece; under
/// `rotate-in-place` it stops there while the table turns half a turn.
fn through_centre(
    p0: Vector2<f64>,
    p1: Vector2<f64>,
    s_close: f64,
    start: PolarPoint,
    policy: OriginPolicy,
    pieces: &mut Vec<Piece>,
) {
    let u0 = p0 / p0.norm();
    let sign = if start.r < 0.0 { -1.0 } else { 1.0 };
    match policy {
        OriginPolicy::SignedRadius => pieces.push(Piece {
            s: 1.0,
            to: PolarPoint {
                r: sign * p1.dot(&u0),
                theta: start.theta,
            },
            rotate: false,
        }),
        OriginPolicy::RotateInPlace => {
            let turned = if start.theta > 0.0 {
                start.theta - std::f64::consts::PI
            } else {
                start.theta + std::f64::consts::PI
            };
            let centre = |theta| PolarPoint { r: 0.0, theta };
            pieces.push(Piece {
                s: s_close,
                to: centre(start.theta),
                rotate: false,
            });
            pieces.push(Piece {
                s: s_close,
                to: centre(turned),
                rotate: true,
            });
            pieces.push(Piece {
                s: 1.0,
                to: PolarPoint {
                    r: p1.norm(),
                    theta: turned,
                },
                rotate: false,
            });
        }
    }
}

/// Accept a piece once its bound is this close to the tolerance: the bound grows about
/// with the square of the length, so the piece is within about 5 % of the longest.
const GOOD_ENOUGH: f64 = 0.9;

/// Regula-falsi tries per piece before falling back to halving.
const TRIES: usize = 6;

/// Cuts the stretch `a`–`b` of a move (parameters and polar points) into pieces whose
/// [`error_bound`] is within `tolerance`, each about as long as it may be (see the module
/// documentation). A piece shorter than `2^-max_depth` of the stretch stops the cutting:
/// the rest stays one piece and `deep` is set.
fn refine(
    at: &dyn Fn(f64) -> PolarPoint,
    a: (f64, PolarPoint),
    b: (f64, PolarPoint),
    tolerance: f64,
    max_depth: u32,
    pieces: &mut Vec<Piece>,
    deep: &mut bool,
) {
    let min_step = (b.0 - a.0) * 0.5f64.powi(max_depth as i32);
    let piece = |(s, to): (f64, PolarPoint)| Piece {
        s,
        to,
        rotate: false,
    };
    let mut cur = a;
    loop {
        let bound = error_bound(&cur.1, &b.1);
        if bound <= tolerance {
            pieces.push(piece(b));
            return;
        }
        if bound <= 4.0 * tolerance {
            // About two pieces' worth left: halves, rather than the longest piece and a
            // sliver after it.
            let sm = 0.5 * (cur.0 + b.0);
            let m = (sm, at(sm));
            if error_bound(&cur.1, &m.1) <= tolerance && error_bound(&m.1, &b.1) <= tolerance {
                pieces.push(piece(m));
                pieces.push(piece(b));
                return;
            }
        }
        let next = match longest_fit(at, cur, b.0, bound, tolerance) {
            Ok(fit) => fit,
            Err(over) => {
                // Not found in a few tries: halve until a piece fits or is too short.
                let mut s = over;
                loop {
                    s = 0.5 * (cur.0 + s);
                    let p = at(s);
                    if error_bound(&cur.1, &p) <= tolerance || s - cur.0 < min_step {
                        break (s, p);
                    }
                }
            }
        };
        if next.0 - cur.0 < min_step {
            // Too short to go on: keep the rest as one piece, beyond tolerance.
            *deep = true;
            pieces.push(piece(b));
            return;
        }
        pieces.push(piece(next));
        cur = next;
    }
}

/// The longest piece from `cur` towards parameter `end` (whose bound is `bound`) found
/// within `tolerance`, or, when none was found in [`TRIES`] tries, the shortest
/// parameter found beyond it.
///
/// Regula falsi on √bound − √tolerance (about linear in the piece's length) between the
/// longest piece found within tolerance and the shortest beyond it, Illinois-style: a
/// bracket end kept twice has its weight halved.
fn longest_fit(
    at: &dyn Fn(f64) -> PolarPoint,
    cur: (f64, PolarPoint),
    end: f64,
    bound: f64,
    tolerance: f64,
) -> Result<(f64, PolarPoint), f64> {
    let root = tolerance.sqrt();
    let mut fits: Option<(f64, PolarPoint)> = None;
    let mut low = (cur.0, 0.0);
    let mut over = (end, bound.sqrt());
    let mut side = 0i8;
    for _ in 0..TRIES {
        let t = (root - low.1) / (over.1 - low.1);
        let s = low.0 + (over.0 - low.0) * t;
        // Rounding can put the guess on a bracket end: halve then.
        let s = if s > low.0 && s < over.0 {
            s
        } else {
            0.5 * (low.0 + over.0)
        };
        let p = at(s);
        let e = error_bound(&cur.1, &p);
        if e <= tolerance {
            fits = Some((s, p));
            if e >= GOOD_ENOUGH * tolerance {
                break;
            }
            low = (s, e.sqrt());
            if side == -1 {
                over.1 = root + 0.5 * (over.1 - root);
            }
            side = -1;
        } else {
            over = (s, e.sqrt());
            if side == 1 {
                low.1 = root - 0.5 * (root - low.1);
            }
            side = 1;
        }
    }
    fits.ok_or(over.0)
}

/// Most chords one arc may become: beyond it (a radius of kilometres, thousands of `P`
/// turns) the arc is an error rather than millions of blocks held in memory.
pub const MAX_ARC_CHORDS: usize = 100_000;

/// Cuts an arc from `from` to `to` into chords within `tolerance`: the points after the
/// start, the last being `to` exactly. Other axes move in proportion to the angle swept.
/// `Err` with the count needed when that is more than [`MAX_ARC_CHORDS`].
///
/// ```
/// use ncpost::ir::{Arc, Axis, Joints, Plane};
/// use nalgebra::Vector3;
/// let mut a = Joints::default();
/// a.set(Axis::X, 10.0);
/// a.set(Axis::Y, 0.0);
/// let mut b = a;
/// b.set(Axis::X, -10.0);
/// let arc = Arc { clockwise: false, plane: Plane::XY, center: Vector3::zeros(), extra_turns: 0 };
/// let pts = ncpost::passes::polar_ik::arc_points(&a, &b, &arc, 0.01).unwrap();
/// assert_eq!(pts.last(), Some(&b));
/// assert!(pts.iter().all(|p| p.get(Axis::Y).unwrap() >= 0.0)); // counter-clockwise: over +Y
/// ```
pub fn arc_points(
    from: &Joints,
    to: &Joints,
    arc: &Arc,
    tolerance: f64,
) -> Result<Vec<Joints>, usize> {
    match ArcPath::new(from, to, arc) {
        Some(path) => match path.chord_count(tolerance) {
            n if n > MAX_ARC_CHORDS => Err(n),
            n => Ok(path.points(n).collect()),
        },
        None => Ok(vec![*to]),
    }
}

/// Joints at `t` of the way from `a` to `b` (axes known in `b`; those unknown in `a` take
/// `b`'s value): at `t = 1` exactly `b`, so a move's last piece ends on the programmed
/// point.
pub(super) fn lerp(a: &Joints, b: &Joints, t: f64) -> Joints {
    let mut j = *b;
    for axis in b.known.iter() {
        if let Some(va) = a.get(axis) {
            let vb = b.values[axis.index()];
            j.values[axis.index()] = if t >= 1.0 { vb } else { va + (vb - va) * t };
        }
    }
    j
}
