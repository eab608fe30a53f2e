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
//! them moves; `inverse-time` writes G93 `F = 1 / minutes`. The distance and the length
//! are those of the printed joints (see [`PolarIk::printed_with`]): the controller moves
//! between the printed numbers, so a piece whose θ change rounds away is a pure r move.
//! Near the centre a line forces the table to turn fast: a line passing the centre at
//! distance `d` at speed `v` turns at `ω = v / d` at its closest approach, and its angular
//! acceleration peaks at `(3√3 / 8) v² / d²` (at `vt = d/√3`). So the XY speed is capped at
//! `v ≤ d · min(ω_max, 1.2408 √α_max)` (`1.2408 = √(8 / (3√3))`, ω in rad/s, α in rad/s²,
//! both from the `[polar]` table's deg/s and deg/s²). The cap applies only inside the
//! circle where it is lower than the programmed speed: the move is split where it crosses
//! that circle, and only the pieces inside it (each at its own distance `d`, the closest
//! of the piece) get a lower F; radial pieces (θ not changing as printed) are never
//! capped. Rapids keep their feed (the controller's rapid speed).
//!
//! # Other axes and blocks
//! Z, E and every other axis are interpolated along each split move in proportion to its
//! XY parameter (equal to the length fraction), the last piece ending at the exact target,
//! so the total E is unchanged. Arcs in the XY plane (G17; helical, spirals and extra
//! turns too) are cut straight into polar pieces whose ends lie on the arc, each the
//! longest whose joint-linear path stays within `tolerance` of the arc itself (`arcs`:
//! a proof by a bound of the radial gap's second derivative with samples, then doubling
//! and bisection on the piece's end). Arcs in another plane, and the rare arc that
//! passes within 0.001 mm of the table's centre (where θ is undefined), are first cut
//! into chords within half the `tolerance`, the polar path then held within the other
//! half of the chords. `center` is the input XY point that sits on the table's axis.
//! G92 offsets on X or Y are dropped with a warning (the table centre is the origin);
//! commands that make X or Y unknown make r and θ unknown. The input position is followed
//! with [`crate::ir::Tracker`], as in every pass: a G92 that declares an unknown axis (E0
//! at the start of a print) makes it known, so the next move's pieces share its E.
//!
//! # The printed numbers
//! The tolerance holds on r and θ as printed: the backend rounds them to half a unit of
//! their last decimal, which moves the nozzle by up to the r rounding plus `r_max` times
//! the θ rounding in radians (0.00018 mm at the preset's 4 decimals), so the pieces get
//! the tolerance less that.
//!
//! `kinematics = "controller"` is for firmware that does polar kinematics itself
//! (RepRapFirmware `M669 K7`, Klipper `kinematics: polar`, Marlin `POLAR`): XY are kept and
//! only arcs are cut into chords, so later passes (extrusion rate, valve timing) see straight
//! segments.

mod arcs;
mod geometry;
mod moves;

use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Axis, AxisSet, Block, BlockKind, Feed, FeedMode, Joints, Span, Tracker};
use crate::machine::FeedRule;
use crate::machine::polar::{OriginPolicy, Polar};
use crate::num::print::{Decimals, to_units};

pub use geometry::{MAX_ARC_CHORDS, Piece, PolarPoint, arc_points, error_bound, plan};

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
        Ok(Box::new(
            PolarIk::new(polar, options)?.printed_with(ctx.decimals)?,
        ))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// Closer than this to the centre (mm) a point is at the centre.
const ORIGIN_EPS: f64 = 1e-9;

/// `√(8 / (3√3))`: the peak angular acceleration of a line passed at speed v and distance
/// d is `(3√3 / 8) v² / d²`, so `α ≤ α_max` means `v ≤ 1.2408 d √α_max`.
pub const ALPHA_FACTOR: f64 = 1.240_806_478_802_799_6;

/// The `polar-ik` pass.
pub struct PolarIk {
    polar: Polar,
    options: Options,
    policy: OriginPolicy,
    /// The input position (IR frame), followed as every pass follows it.
    track: Tracker,
    /// The machine's polar position after the last emitted move, if known.
    node: Option<PolarPoint>,
    /// `min(ω_max, 1.24 √α_max)`, 1/s.
    cap_rate: f64,
    /// The tolerance the pieces get: what the print rounding of their ends leaves.
    tolerance: f64,
    /// The backend's decimals, when it prints: the controller moves between the printed
    /// joints, so F is computed from their deltas.
    decimals: Option<Decimals>,
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
            tolerance: options.tolerance,
            polar,
            options,
            track: Tracker::default(),
            node: None,
            decimals: None,
        })
    }

    /// The same pass for a backend that prints with `decimals`: the tolerance holds on
    /// the printed positions. Printing rounds r and θ by up to half a unit of their last
    /// decimal, which moves the nozzle by up to the r rounding plus `r_max` times the θ
    /// rounding (radians), all along a piece (the rounding of its ends is interpolated
    /// like the joints); under `kinematics = "controller"` X, Y and Z are printed, by up to
    /// `√3` times their rounding. The pieces get the tolerance less that; an error when
    /// nothing is left.
    pub fn printed_with(mut self, decimals: Option<Decimals>) -> Result<PolarIk, Diagnostic> {
        self.decimals = decimals;
        let Some(d) = decimals else {
            return Ok(self);
        };
        let half = |axis: Axis| 0.5 * 10f64.powi(-i32::from(d.axis(axis)));
        let rounding = match self.options.kinematics {
            Kinematics::Post => {
                half(self.polar.r_axis)
                    + self.polar.r_max * half(self.polar.theta_axis).to_radians()
            }
            Kinematics::Controller => {
                half(Axis::X).max(half(Axis::Y)).max(half(Axis::Z)) * 3f64.sqrt()
            }
        };
        self.tolerance = self.options.tolerance - rounding;
        if self.tolerance <= 0.0 {
            return Err(Diagnostic::settings(format!(
                "polar-ik tolerance {} mm is finer than the printed positions can hold \
                 ({rounding:.6} mm): raise the tolerance or print more decimals",
                self.options.tolerance
            )));
        }
        Ok(self)
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
    /// θ set.
    fn piece_joints(&self, from: &Joints, to: &Joints, t: f64, p: &PolarPoint) -> Joints {
        let mut j = geometry::lerp(from, to, t);
        self.to_polar(&mut j, p);
        j
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
        // Axes unknown at either end add nothing.
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

    /// The joints as the controller reads them: each known axis rounded to the backend's
    /// decimals with the G92 offsets in force (X and Y have none here: they are dropped).
    fn printed(&self, j: &Joints) -> Joints {
        crate::ir::as_printed(self.decimals, j, self.track.offsets(), None)
    }

    /// The feed that makes the controller run the piece from `a` to `b` (emitted joints,
    /// `seconds` at the programmed speed along the exact piece) at the programmed speed.
    ///
    /// The controller moves between the printed joints, not the exact ones: a short piece
    /// whose θ change rounds away is a pure r move (`G1 X1.4931` without its Y), so F is
    /// the printed joint distance over the time. That time is the programmed speed along
    /// the printed piece: the nozzle goes where the printed numbers put it, so a piece
    /// whose printed ends are 15 % closer than the exact ones (a 0.0002 mm slicer move)
    /// takes 15 % less time, at the programmed speed; on pieces longer than a few hundred
    /// print units the two lengths agree within the F resolution. A piece whose printed
    /// joints do not change goes nowhere on the controller and takes no time there: its
    /// printed length is zero, so no programmed time is lost (it keeps the programmed F).
    fn feed_for(&self, feed: &Feed, a: &Joints, b: &Joints, seconds: f64) -> Feed {
        if !(seconds > 0.0 && seconds.is_finite()) {
            return *feed;
        }
        let (pa, pb) = (self.printed(a), self.printed(b));
        let seconds = seconds * self.printed_share(a, b, &pa, &pb);
        if seconds <= 0.0 {
            return *feed;
        }
        if self.polar.controller.feed_rule == FeedRule::InverseTime {
            return Feed {
                mode: FeedMode::InverseTime,
                rate: Some(60.0 / seconds),
            };
        }
        let dist = self.joint_distance(&pa, &pb);
        if dist <= 0.0 {
            return *feed;
        }
        Feed {
            mode: FeedMode::PerMinute,
            rate: Some(dist / seconds * 60.0),
        }
    }

    /// Whether the table turns between polar points `a` and `b` on the controller: their
    /// printed θ differ. A piece whose θ change rounds away is a pure r move there, which
    /// the near-centre speed cap (a limit on the table's turning) does not slow.
    fn turns(&self, a: &PolarPoint, b: &PolarPoint) -> bool {
        if a.theta == b.theta {
            return false;
        }
        let Some(d) = self.decimals else {
            return true;
        };
        let places = d.axis(self.polar.theta_axis);
        let offset = self.track.offsets()[self.polar.theta_axis.index()];
        to_units(a.theta.to_degrees() + offset, places)
            != to_units(b.theta.to_degrees() + offset, places)
    }

    /// The nozzle's straight travel between the printed joints `pa`, `pb` over that
    /// between the exact ones `a`, `b` (1 when the exact ends coincide: a turn on the
    /// spot, or a move of Z alone through the centre, is timed by its joints).
    fn printed_share(&self, a: &Joints, b: &Joints, pa: &Joints, pb: &Joints) -> f64 {
        if self.decimals.is_none() || self.options.kinematics == Kinematics::Controller {
            return 1.0;
        }
        let (r, th) = (self.polar.r_axis, self.polar.theta_axis);
        let tip = |j: &Joints| crate::motion::polar_point(j, r, th);
        let exact = (tip(b) - tip(a)).norm();
        if exact <= 0.0 {
            return 1.0;
        }
        (tip(pb) - tip(pa)).norm() / exact
    }

    /// A line (homing, a macro...) makes `clobbers` unknown: the position forgets them;
    /// returns them as the output names them (r and θ for X and Y).
    fn clobbered(&mut self, clobbers: AxisSet) -> AxisSet {
        self.track.forget(clobbers);
        if self.xy(self.track.pos()).is_none() {
            self.node = None;
        }
        self.map_axes(clobbers)
    }

    /// An error when `p` is outside the arm's reach: the machine cannot go there (the
    /// arm would hit its end stop), as a 5-axis move past a rotary's limit cannot.
    fn check_reach(&self, p: &PolarPoint, span: Span, out: &mut Output<'_>) {
        let eps = 1e-9;
        if p.r > self.polar.r_max + eps || p.r < self.polar.r_min() - eps {
            out.diag(
                Diagnostic::error(
                    "polar-ik::reach",
                    format!(
                        "r = {:.3} mm is outside the arm's range {:.3}..{:.3}",
                        p.r,
                        self.polar.r_min(),
                        self.polar.r_max
                    ),
                )
                .at_span(span)
                .with_label("out of the arm's reach")
                .with_help(
                    "move the part towards the table's centre (polar-ik `center` is the bed \
                     point over the table's axis), or check [polar] r_max",
                )
                // How far past the range, for naming the worst of many.
                .with_magnitude((p.r - self.polar.r_max).max(self.polar.r_min() - p.r)),
            );
        }
    }
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
                // The controller knows an axis a G92 declares (E0 at the start of a
                // print): the pieces of the next move interpolate it from there.
                self.track.offset(&o);
                out.push(Block {
                    kind: BlockKind::Offset(o),
                    ..block
                });
            }
            BlockKind::Command(mut c) => {
                c.clobbers = self.clobbered(c.clobbers);
                out.push(Block {
                    kind: BlockKind::Command(c),
                    ..block
                });
            }
            BlockKind::Verbatim(mut v) => {
                v.clobbers = self.clobbered(v.clobbers);
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
