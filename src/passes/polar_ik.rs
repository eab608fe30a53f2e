//! `polar-ik`: Cartesian XY to turntable angle θ and arm radius r, densified so the
//! controller's joint-linear path follows the programmed line.
//!
//! # What the controller does
//! The polar printer's controller (seed 002) interpolates r and θ linearly, like a plain
//! Cartesian firmware with r on one axis and θ in degrees on another. Between two emitted
//! blocks `(r_a, θ_a) → (r_b, θ_b)` the nozzle follows `q(u) = r(u) (cos θ(u), sin θ(u))`
//! with `r(u) = r_a + u Δr`, `θ(u) = θ_a + u Δθ`, `u ∈ [0, 1]`: a spiral, not the straight
//! XY line the slicer wrote.
//!
//! # The error bound and densification
//! Differentiating twice, `q'' = 2 Δr Δθ e_θ − r Δθ² e_r`; `e_r` and `e_θ` are
//! orthonormal, so `|q''| ≤ |Δθ| √((max(|r_a|, |r_b|) Δθ)² + (2 Δr)²)` (θ in radians). A
//! curve whose second derivative is bounded by `M` stays within `M / 8` of its chord;
//! every emitted node is the exact inverse kinematics of a point on the programmed line, so
//! the chord lies on the line and the whole joint-linear piece is within
//! `|Δθ| √((r Δθ)² + (2 Δr)²) / 8` of it. On short pieces the bound is at most about 6 %
//! above the true distance (what it overstates is the part of `q''` along the chord;
//! `tests/polar.rs` checks 10 %); the sum `r Δθ² + 2 |Δr Δθ|` first used here overstated
//! it by up to 41 %, and gave 10 % more output lines on the bench print. A move
//! is cut into pieces that each satisfy `bound ≤ tolerance` (0.01 mm by default), each
//! piece as long as the bound allows: from the last node, a few regula-falsi steps on
//! `√bound` (about linear in the piece's length) find where the bound reaches 90–100 % of
//! the tolerance, and the last two pieces share what is left evenly. Near the centre, where
//! θ turns fastest, pieces are short; away from it they are long. This gives within a few
//! per cent of the fewest pieces the bound allows (halving at midpoints, as first built,
//! gave up to twice as many; every piece is work for the passes after it and for the
//! controller). A piece shorter than `2^-max_depth` of the move stops the cutting (then a
//! warning). The bound is a proof, not an estimate; `tests/polar.rs` also samples the
//! joint-linear path of every emitted piece and measures the true deviation.
//!
//! # θ continuity
//! Every point of a move takes its angle relative to the move's start,
//! `θ(s) = θ_0 + ∠(P_0, P(s))` with the signed angle in `(−180°, 180°]`, so θ is
//! continuous (no wrap to `±180`) over the whole program; a straight line that misses the
//! centre subtends less than 180° from it, so no piece turns by 180° or more. After homing
//! or another command that makes X or Y unknown, the next point starts afresh from
//! `atan2(y, x)`.
//!
//! # The centre (r = 0)
//! A point at exactly r = 0 never takes its angle from `atan2(0, 0)`: a move ending there
//! keeps its θ (the arm runs radially in), a move starting there takes the direction of
//! the move (a rotation on the spot first, at `omega_max`, when θ has to change), and a
//! first point at the centre with no θ known yet takes θ = 0. A line through the centre
//! follows the `origin` policy (default: the machine's, `signed-radius` when `negative_r`,
//! else `rotate-in-place`):
//! - `signed-radius`: θ stays, r passes through zero to negative values (no rotation);
//!   the sign of r then stays until the next line through the centre;
//! - `rotate-in-place`: the arm stops at the centre, the table turns by 180° on the spot
//!   (towards θ = 0 on a tie, so θ stays bounded), the arm goes on.
//!
//! # Feeds
//! F on every emitted motion is what the controller needs to move the piece at the
//! programmed XY(Z) speed under its feed rule (`[polar.controller] feed_rule`): with the
//! Euclidean rule `F_out = joint distance / (Cartesian length / F_prog)`, joint distance
//! being `√(Δr² + Δθ_deg² + Δz²)`; under `nist` only X/Y/Z letters count while any of
//! them moves; `inverse-time` writes G93 `F = 1 / minutes`.
//! Near the centre a line forces the table to turn fast: a line passing the centre at
//! distance `d` at speed `v` turns at `ω = v / d` at its closest approach, and its angular
//! acceleration peaks at `(3√3 / 8) v² / d²` (at `vt = d/√3`). So the XY speed is capped at
//! `v ≤ d · min(ω_max, 1.2408 √α_max)` (`1.2408 = √(8 / (3√3))`, ω in rad/s, α in rad/s²,
//! both from the `[polar]` table's deg/s and deg/s²). The cap applies only inside the
//! circle where it is lower than the programmed speed: the move is split where it crosses
//! that circle, and only the pieces inside it (each at its own distance `d`, the closest
//! of the piece) get a lower F; radial pieces (θ not changing) are never capped. Rapids
//! keep their feed (the controller's rapid speed).
//!
//! # Other axes and blocks
//! Z, E and every other axis are interpolated along each split move in proportion to its
//! XY parameter (equal to the length fraction), the last piece ending at the exact target,
//! so the total E is unchanged. Arcs (G2/G3, any plane, helical, extra turns) are first
//! cut into chords within `tolerance` of the arc; the polar path is then within
//! `tolerance` of the chords. `center` is the input XY point that sits on the table's
//! axis. G92 offsets on X or Y are dropped with a warning (the table centre is the
//! origin); commands that make X or Y unknown make r and θ unknown.
//!
//! `kinematics = "controller"` is for firmware that does polar kinematics itself
//! (RepRapFirmware `M669 K7`, Klipper `kinematics: polar`, Marlin `POLAR`): XY are kept and
//! only arcs are cut into chords, so later passes (extrusion rate, valve timing) see straight
//! segments.

use nalgebra::Vector2;
use serde::{Deserialize, Serialize};
use smallvec::SmallVec;

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Arc, Axis, AxisSet, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind,
    Span, Target,
};
use crate::machine::FeedRule;
use crate::machine::polar::{OriginPolicy, Polar};

/// Who does the polar kinematics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Kinematics {
    /// This pass: XY become r and θ, densified.
    #[default]
    Post,
    /// The firmware (`M669 K7`, Klipper, Marlin `POLAR`): XY stay, arcs become chords.
    Controller,
}

/// Options of `polar-ik`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Largest distance of the joint-linear path from the programmed XY line (and of arc
    /// chords from their arc), mm.
    pub tolerance: f64,
    /// The policy at the centre; unset: the `[polar]` table's.
    pub origin: Option<OriginPolicy>,
    /// `post` (this pass computes r, θ) or `controller` (the firmware does).
    pub kinematics: Kinematics,
    /// The input XY point on the table's axis, mm.
    pub center: [f64; 2],
    /// Cap the XY speed near the centre by the table's ω_max and α_max.
    pub speed_cap: bool,
    /// Densify rapids too, so travel follows its straight line.
    pub rapids: bool,
    /// Shortest piece as `2^-max_depth` of its move; where pieces would have to be shorter
    /// the rest of the move stays one piece, with a warning.
    pub max_depth: u32,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            tolerance: 0.01,
            origin: None,
            kinematics: Kinematics::Post,
            center: [0.0, 0.0],
            speed_cap: true,
            rapids: true,
            max_depth: 24,
        }
    }
}

impl Options {
    fn check(&self) -> Result<(), Diagnostic> {
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(Diagnostic::settings(
                "tolerance must be a positive number of millimetres",
            ));
        }
        if !self.center.iter().all(|c| c.is_finite()) {
            return Err(Diagnostic::settings("center must be two finite numbers"));
        }
        if self.max_depth > 40 {
            return Err(Diagnostic::settings("max_depth must be at most 40"));
        }
        Ok(())
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "polar-ik",
    summary: "Cartesian XY to polar r/theta (continuous), densified within tolerance, origin policy and near-centre speed cap",
    build: |t, ctx| {
        let options: Options = super::options(t)?;
        let polar = match (ctx.polar, options.kinematics) {
            (Some(p), _) => p.clone(),
            (None, Kinematics::Controller) => Polar::default(),
            (None, Kinematics::Post) => {
                return Err(Diagnostic::settings(
                    "pass `polar-ik` needs a polar machine: use a preset with a [polar] table (for example --preset polar-printer)",
                ));
            }
        };
        Ok(Box::new(PolarIk::new(polar, options)?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// Closer than this to the centre (mm) a point is at the centre.
const ORIGIN_EPS: f64 = 1e-9;

/// `√(8 / (3√3))`: the peak angular acceleration of a line passed at speed v and distance
/// d is `(3√3 / 8) v² / d²`, so `α ≤ α_max` means `v ≤ 1.2408 d √α_max`.
pub const ALPHA_FACTOR: f64 = 1.240_806_478_802_799_6;

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
fn angle_between(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
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
    if len2.sqrt() <= ORIGIN_EPS {
        pieces.push(Piece {
            s: 1.0,
            to: start,
            rotate: false,
        });
        return false;
    }
    if p0.norm() <= ORIGIN_EPS {
        // Leaving the centre: radial, so one piece; only θ may have to turn first.
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
        return false;
    }
    if p1.norm() <= ORIGIN_EPS {
        // Arriving at the centre: radial, θ kept.
        pieces.push(Piece {
            s: 1.0,
            to: PolarPoint {
                r: 0.0,
                theta: start.theta,
            },
            rotate: false,
        });
        return false;
    }
    let s_close = -p0.dot(&d) / len2;
    let line_dist = (p0.x * d.y - p0.y * d.x).abs() / len2.sqrt();
    if line_dist <= ORIGIN_EPS && s_close > 0.0 && s_close < 1.0 {
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
                pieces.push(Piece {
                    s: s_close,
                    to: PolarPoint {
                        r: 0.0,
                        theta: start.theta,
                    },
                    rotate: false,
                });
                pieces.push(Piece {
                    s: s_close,
                    to: PolarPoint {
                        r: 0.0,
                        theta: turned,
                    },
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
    let mut cur = a;
    loop {
        let bound = error_bound(&cur.1, &b.1);
        if bound <= tolerance {
            pieces.push(Piece {
                s: b.0,
                to: b.1,
                rotate: false,
            });
            return;
        }
        if bound <= 4.0 * tolerance {
            // About two pieces' worth left: halves, rather than the longest piece and a
            // sliver after it.
            let sm = 0.5 * (cur.0 + b.0);
            let m = (sm, at(sm));
            if error_bound(&cur.1, &m.1) <= tolerance && error_bound(&m.1, &b.1) <= tolerance {
                for (s, to) in [m, b] {
                    pieces.push(Piece {
                        s,
                        to,
                        rotate: false,
                    });
                }
                return;
            }
        }
        // Regula falsi on √bound − √tolerance (about linear in the piece's length)
        // between the longest piece found within tolerance and the shortest beyond it,
        // Illinois-style: a bracket end kept twice has its weight halved.
        let root = tolerance.sqrt();
        let mut fits: Option<(f64, PolarPoint)> = None;
        let mut low = (cur.0, 0.0);
        let mut over = (b.0, bound.sqrt());
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
        let next = match fits {
            Some(f) => f,
            None => {
                // Not found in a few tries: halve until a piece fits or is too short.
                let mut s = over.0;
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
            pieces.push(Piece {
                s: b.0,
                to: b.1,
                rotate: false,
            });
            return;
        }
        pieces.push(Piece {
            s: next.0,
            to: next.1,
            rotate: false,
        });
        cur = next;
    }
}

/// Cuts an arc from `from` to `to` into chords within `tolerance`: the points after the
/// start, the last being `to` exactly. Other axes move in proportion to the angle swept.
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
/// let pts = ncpost::passes::polar_ik::arc_points(&a, &b, &arc, 0.01);
/// assert_eq!(pts.last(), Some(&b));
/// assert!(pts.iter().all(|p| p.get(Axis::Y).unwrap() >= 0.0)); // counter-clockwise: over +Y
/// ```
pub fn arc_points(from: &Joints, to: &Joints, arc: &Arc, tolerance: f64) -> Vec<Joints> {
    match crate::motion::arc::ArcPath::new(from, to, arc) {
        Some(path) => path.chords(tolerance),
        None => vec![*to],
    }
}

/// Joints at `t` of the way from `a` to `b` (axes known in `b`; those unknown in `a` take
/// `b`'s value).
#[cfg(test)]
fn lerp(a: &Joints, b: &Joints, t: f64) -> Joints {
    let mut j = *b;
    for axis in b.known.iter() {
        if let Some(va) = a.get(axis) {
            let vb = b.values[axis.index()];
            j.values[axis.index()] = if t >= 1.0 { vb } else { va + (vb - va) * t };
        }
    }
    j
}

/// The `polar-ik` pass.
pub struct PolarIk {
    polar: Polar,
    options: Options,
    policy: OriginPolicy,
    /// The last input target (IR frame).
    pos: Joints,
    /// The machine's polar position after the last emitted move, if known.
    node: Option<PolarPoint>,
    /// `min(ω_max, 1.24 √α_max)`, 1/s.
    cap_rate: f64,
    /// The pieces of the move being emitted (kept to reuse its allocation).
    pieces: Vec<Piece>,
}

impl PolarIk {
    /// The pass for `polar` with `options`.
    pub fn new(polar: Polar, options: Options) -> Result<PolarIk, Diagnostic> {
        options.check()?;
        let mut checked = polar.clone();
        if let Some(origin) = options.origin {
            checked.origin = Some(origin);
        }
        if options.kinematics == Kinematics::Post {
            checked.check()?;
        }
        let omega = polar.omega_max.to_radians();
        let alpha = polar.alpha_max.to_radians();
        Ok(PolarIk {
            policy: checked.origin_policy(),
            cap_rate: omega.min(ALPHA_FACTOR * alpha.sqrt()),
            polar,
            options,
            pos: Joints::default(),
            node: None,
            pieces: Vec::new(),
        })
    }

    fn xy(&self, j: &Joints) -> Option<Vector2<f64>> {
        Some(Vector2::new(
            j.get(Axis::X)? - self.options.center[0],
            j.get(Axis::Y)? - self.options.center[1],
        ))
    }

    /// Input joints with X/Y replaced by r and θ (degrees).
    fn emitted(&self, j: &Joints, p: &PolarPoint) -> Joints {
        let mut out = *j;
        self.to_polar(&mut out, p);
        out
    }

    /// The joints of a piece ending at `t` of the way from `from` to `to`, at polar point
    /// `p`: the other axes interpolated (those unknown in `from` take `to`'s value), r and
    /// θ set. One select per axis and no branch, so that the block the joints go into
    /// copies them from whole stores (a copy of values written one by one at varying
    /// indices waits on store forwarding). The same values as `lerp` then
    /// [`Self::to_polar`], which the tests check.
    fn piece_joints(&self, from: &Joints, to: &Joints, t: f64, p: &PolarPoint) -> Joints {
        let both = from.known.intersection(to.known);
        let (r_axis, theta_axis) = (self.polar.r_axis, self.polar.theta_axis);
        let theta = p.theta.to_degrees();
        let mut values = [0.0; AXIS_COUNT];
        for (k, v) in values.iter_mut().enumerate() {
            let axis = Axis::ALL[k];
            let (va, vb) = (from.values[k], to.values[k]);
            let mixed = if t >= 1.0 { vb } else { va + (vb - va) * t };
            let moved = if both.contains(axis) { mixed } else { vb };
            let planar = if matches!(axis, Axis::X | Axis::Y) {
                0.0
            } else {
                moved
            };
            let radial = if axis == r_axis { p.r } else { planar };
            *v = if axis == theta_axis { theta } else { radial };
        }
        let mut known = to.known.difference(AxisSet::from_iter([Axis::X, Axis::Y]));
        known.insert(r_axis);
        known.insert(theta_axis);
        Joints { values, known }
    }

    /// Puts r and θ (degrees) in place of X and Y, in place.
    fn to_polar(&self, j: &mut Joints, p: &PolarPoint) {
        j.forget(AxisSet::from_iter([Axis::X, Axis::Y]));
        j.set(self.polar.r_axis, p.r);
        j.set(self.polar.theta_axis, p.theta.to_degrees());
    }

    fn map_axes(&self, set: AxisSet) -> AxisSet {
        let xy = AxisSet::from_iter([Axis::X, Axis::Y]);
        if set.intersection(xy).is_empty() {
            return set;
        }
        let mut out = set.difference(xy);
        out.insert(self.polar.r_axis);
        out.insert(self.polar.theta_axis);
        out
    }

    /// The controller's distance for F between two emitted joint vectors.
    fn joint_distance(&self, a: &Joints, b: &Joints) -> f64 {
        // Axes known at both ends, in index order (unknown ones add nothing): this runs
        // for every piece.
        let both = a.known.intersection(b.known);
        let norm = |axes: AxisSet| {
            let mut sum = 0.0;
            for x in both.intersection(axes).iter() {
                let d = b.values[x.index()] - a.values[x.index()];
                sum += d * d;
            }
            f64::sqrt(sum)
        };
        match self.polar.controller.feed_rule {
            FeedRule::Nist => {
                let xyz = norm(AxisSet::XYZ);
                if xyz > 0.0 {
                    xyz
                } else {
                    norm(AxisSet::from_iter([Axis::A, Axis::B, Axis::C]))
                }
            }
            FeedRule::Euclidean | FeedRule::InverseTime => {
                norm(AxisSet::ALL.difference(AxisSet::from_iter([Axis::E])))
            }
        }
    }

    /// The feed that makes the controller take `seconds` from `a` to `b`.
    fn feed_for(&self, feed: &Feed, a: &Joints, b: &Joints, seconds: f64) -> Feed {
        if !(seconds > 0.0 && seconds.is_finite()) {
            return *feed;
        }
        if self.polar.controller.feed_rule == FeedRule::InverseTime {
            return Feed {
                mode: FeedMode::InverseTime,
                rate: Some(60.0 / seconds),
            };
        }
        let dist = self.joint_distance(a, b);
        if dist <= 0.0 {
            return *feed;
        }
        Feed {
            mode: FeedMode::PerMinute,
            rate: Some(dist / seconds * 60.0),
        }
    }

    fn run_controller(&mut self, block: Block, out: &mut Output<'_>) {
        if let BlockKind::Motion(m) = &block.kind
            && let (MotionKind::Arc(arc), &Target::Joints(to)) = (m.kind, &m.target)
        {
            let (a1, a2, _) = arc.plane.axes();
            if self.pos.known.contains(a1) && self.pos.known.contains(a2) {
                let points = arc_points(&self.pos, &to, &arc, self.options.tolerance);
                let n = points.len();
                let total = arc_length(&self.pos, &points);
                let mut prev = self.pos;
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
                self.pos = to;
                return;
            }
        }
        self.track(&block);
        out.push(block);
    }

    /// Follows the input position through a block that is passed on unchanged.
    fn track(&mut self, block: &Block) {
        match &block.kind {
            BlockKind::Motion(m) => match m.target.joints() {
                Some(j) if !m.machine_frame => self.pos = *j,
                _ => self.pos.forget(m.written),
            },
            BlockKind::Command(c) => self.pos.forget(c.clobbers),
            BlockKind::Verbatim(v) => self.pos.forget(v.clobbers),
            _ => {}
        }
        if self.xy(&self.pos).is_none() {
            self.node = None;
        }
    }

    fn run_motion(&mut self, block: Block, m: Motion, out: &mut Output<'_>) {
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
            out.diag(
                Diagnostic::warning(
                    "polar-ik::machine-frame",
                    "a G53 move is passed on as written; r and θ are unknown after it",
                )
                .at_span(block.span),
            );
            self.pos.forget(m.written);
            self.node = None;
            let mut m = m;
            m.written = self.map_axes(m.written);
            if let Some(j) = m.target.joints_mut() {
                j.known = self.map_axes(j.known);
            }
            out.push(Block {
                kind: BlockKind::Motion(m),
                ..block
            });
            return;
        }
        let Some(p1) = self.xy(&to) else {
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
            let mut m = m;
            if let Some(j) = m.target.joints_mut() {
                j.forget(AxisSet::from_iter([Axis::X, Axis::Y]));
            }
            m.written = m.written.difference(AxisSet::from_iter([Axis::X, Axis::Y]));
            self.pos = to;
            self.node = None;
            out.push(Block {
                kind: BlockKind::Motion(m),
                ..block
            });
            return;
        };
        let from = self.pos;
        let (Some(_), Some(node)) = (self.xy(&from), self.node) else {
            // No start known: the point on its own, θ from atan2 except at the centre.
            let theta = if p1.norm() <= ORIGIN_EPS {
                0.0
            } else {
                p1.y.atan2(p1.x)
            };
            let p = PolarPoint {
                r: p1.norm(),
                theta,
            };
            let mut m = m;
            m.kind = match m.kind {
                MotionKind::Arc(_) => MotionKind::Linear,
                k => k,
            };
            m.target = Target::Joints(self.emitted(&to, &p));
            m.written = self.map_axes(m.written);
            self.check_reach(&p, block.span, out);
            self.pos = to;
            self.node = Some(p);
            out.push(Block {
                kind: BlockKind::Motion(m),
                ..block
            });
            return;
        };
        let chords;
        let points: &[Joints] = match m.kind {
            MotionKind::Arc(arc) => {
                chords = arc_points(&from, &to, &arc, self.options.tolerance);
                &chords
            }
            _ => std::slice::from_ref(&to),
        };
        // Only an inverse-time feed needs the whole move's length (a `sqrt` per move).
        let total = if m.feed.mode == FeedMode::InverseTime {
            arc_length(&from, points)
        } else {
            0.0
        };
        let n = points.len();
        let mut start = from;
        let mut node = node;
        for (i, p) in points.iter().enumerate() {
            let last = i + 1 == n;
            node = self.line(&block, &m, &start, p, node, total, last, out);
            start = *p;
        }
        self.pos = to;
        self.node = Some(node);
    }

    /// Emits one straight input move from `from` to `to`; returns the polar position it
    /// ends at.
    #[allow(clippy::too_many_arguments)]
    fn line(
        &mut self,
        block: &Block,
        m: &Motion,
        from: &Joints,
        to: &Joints,
        node: PolarPoint,
        total: f64,
        last: bool,
        out: &mut Output<'_>,
    ) -> PolarPoint {
        let (Some(p0), Some(p1)) = (self.xy(from), self.xy(to)) else {
            return node;
        };
        let rapid = m.kind == MotionKind::Rapid;
        let dz = match (from.get(Axis::Z), to.get(Axis::Z)) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        };
        let xy_len = (p1 - p0).norm();
        // `hypot(x, 0)` is `|x|` exactly: no libm call for the usual move in a layer.
        let cart_len = if dz == 0.0 { xy_len } else { xy_len.hypot(dz) };
        // The programmed XY(Z) speed, mm/s, or the programmed time of this piece.
        let speed = match (m.feed.mode, m.feed.rate) {
            (FeedMode::PerMinute, Some(f)) if f > 0.0 && !rapid => Some(f / 60.0),
            (FeedMode::InverseTime, Some(f)) if f > 0.0 && total > 0.0 => Some(total / (60.0 / f)),
            _ => None,
        };
        let xy_speed = speed.map(|v| {
            if cart_len > 0.0 {
                v * xy_len / cart_len
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
            (self.options.tolerance, self.options.max_depth, cap_radius)
        };
        let mut pieces = std::mem::take(&mut self.pieces);
        let deep = plan(
            p0,
            p1,
            node,
            self.policy,
            tolerance,
            max_depth,
            cap_radius,
            &mut pieces,
        );
        if deep {
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
                let seconds = if piece.rotate {
                    (piece.to.theta - prev_node.theta).abs() / self.polar.omega_max.to_radians()
                } else {
                    let len = (piece.s - prev_s) * cart_len;
                    let piece_xy = (piece.s - prev_s) * xy_len;
                    match speed {
                        Some(v) => {
                            let mut t = len / v;
                            if self.options.speed_cap && piece.to.theta != prev_node.theta {
                                let a = p0 + (p1 - p0) * prev_s;
                                let b = p0 + (p1 - p0) * piece.s;
                                let d = segment_distance(&a, &b);
                                let cap = d * self.cap_rate;
                                if cap > 0.0 {
                                    t = t.max(piece_xy / cap);
                                }
                            }
                            t
                        }
                        None => 0.0,
                    }
                };
                self.feed_for(&m.feed, &prev_joints, &joints, seconds)
            };
            // Built in one expression where it is pushed: the block is written in its
            // slot, not built on the stack and copied (a copy of freshly written fields
            // stalls on store forwarding).
            out.push(Block {
                span: block.span,
                kind: BlockKind::Motion(Motion {
                    kind: if rapid {
                        MotionKind::Rapid
                    } else {
                        MotionKind::Linear
                    },
                    target: Target::Joints(joints),
                    feed,
                    written,
                    machine_frame: m.machine_frame,
                    extra: if m.extra.is_empty() {
                        String::new()
                    } else {
                        m.extra.clone()
                    },
                }),
                comments: Vec::new(),
            });
            // The comments go on the last piece where it lies: a vector made beforehand
            // would be copied in as one 16-byte load of two 8-byte stores, a stall.
            if last
                && i + 1 == count
                && let Some(b) = out.blocks.last_mut()
            {
                b.comments.clone_from(&block.comments);
            }
            prev_s = piece.s;
            prev_node = piece.to;
            prev_joints = joints;
        }
        self.pieces = pieces;
        prev_node
    }

    fn check_reach(&self, p: &PolarPoint, span: Span, out: &mut Output<'_>) {
        let eps = 1e-9;
        if p.r > self.polar.r_max + eps || p.r < self.polar.r_min() - eps {
            out.diag(
                Diagnostic::warning(
                    "polar-ik::reach",
                    format!(
                        "r = {:.3} mm is outside the arm's range {:.3}..{:.3}",
                        p.r,
                        self.polar.r_min(),
                        self.polar.r_max
                    ),
                )
                .at_span(span),
            );
        }
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
fn segment_distance(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let d = b - a;
    let len2 = d.norm_squared();
    if len2 == 0.0 {
        return a.norm();
    }
    let s = (-a.dot(&d) / len2).clamp(0.0, 1.0);
    (a + d * s).norm()
}

impl PolarIk {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        if self.options.kinematics == Kinematics::Controller {
            self.run_controller(block, out);
            return;
        }
        match block.kind {
            BlockKind::Motion(m) => {
                let block = Block {
                    kind: BlockKind::Comment,
                    ..block
                };
                self.run_motion(block, m, out);
            }
            BlockKind::Offset(mut o) => {
                let xy = AxisSet::from_iter([Axis::X, Axis::Y]);
                let named_xy = !o.declared.known.intersection(xy).is_empty()
                    || o.offsets[Axis::X.index()] != 0.0
                    || o.offsets[Axis::Y.index()] != 0.0;
                if named_xy {
                    out.diag(
                        Diagnostic::warning(
                            "polar-ik::offset",
                            "G92 offsets on X and Y are dropped: the table centre is the polar origin",
                        )
                        .at_span(block.span),
                    );
                    o.declared.forget(xy);
                    for a in [Axis::X, Axis::Y, self.polar.r_axis, self.polar.theta_axis] {
                        o.offsets[a.index()] = 0.0;
                    }
                    if o.declared.known.is_empty() && o.code == crate::ir::OffsetCode::Set {
                        // A bare G92 would zero every axis: leave the line out.
                        return;
                    }
                }
                out.push(Block {
                    kind: BlockKind::Offset(o),
                    ..block
                });
            }
            BlockKind::Command(mut c) => {
                self.pos.forget(c.clobbers);
                if self.xy(&self.pos).is_none() {
                    self.node = None;
                }
                c.clobbers = self.map_axes(c.clobbers);
                out.push(Block {
                    kind: BlockKind::Command(c),
                    ..block
                });
            }
            BlockKind::Verbatim(mut v) => {
                self.pos.forget(v.clobbers);
                if self.xy(&self.pos).is_none() {
                    self.node = None;
                }
                v.clobbers = self.map_axes(v.clobbers);
                out.push(Block {
                    kind: BlockKind::Verbatim(v),
                    ..block
                });
            }
            kind => out.push(Block { kind, ..block }),
        }
    }
}

impl Pass for PolarIk {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// A piece's joints are those of interpolating the move and then setting r and θ,
        /// bit for bit, whatever axes either end knows.
        #[test]
        fn piece_joints_are_lerp_then_to_polar(
            from_values in proptest::array::uniform10(-500.0f64..500.0),
            to_values in proptest::array::uniform10(-500.0f64..500.0),
            from_known in 0u16..1024,
            to_known in 0u16..1024,
            t in proptest::sample::select(vec![0.0, 0.25, 0.5, 0.999, 1.0]),
            r in -150.0f64..150.0,
            theta in -20.0f64..20.0,
        ) {
            let joints = |values: [f64; AXIS_COUNT], known: u16| {
                let mut j = Joints::default();
                for (k, &v) in values.iter().enumerate() {
                    if known & (1 << k) != 0 {
                        j.set(Axis::ALL[k], v);
                    }
                }
                j
            };
            let from = joints(from_values, from_known);
            let to = joints(to_values, to_known);
            let ik = PolarIk::new(Polar::default(), Options::default()).unwrap();
            let p = PolarPoint { r, theta };
            let mut expected = lerp(&from, &to, t);
            ik.to_polar(&mut expected, &p);
            let got = ik.piece_joints(&from, &to, t, &p);
            proptest::prop_assert_eq!(got.known, expected.known);
            for k in 0..AXIS_COUNT {
                proptest::prop_assert_eq!(got.values[k].to_bits(), expected.values[k].to_bits(), "axis {}", k);
            }
        }
    }
}
