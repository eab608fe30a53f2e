//! The motion-time model: how long the controller takes for each block, and how fast the tool moves.
//!
//! Every pass and command that needs time (`stats`, `plot --speed`, `extrude-rate`,
//! `valve-lookahead`) uses this one model, built from the machine's [`Controller`]:
//!
//! - **Distance under the feed rule** ([`rule_distance`]): `nist` (RS274NGC 2.1.2.5, as
//!   RepRapFirmware and LinuxCNC in G94) takes the XYZ distance when any of X, Y, Z moves,
//!   else the rotary (A, B, C) distance in degrees, else U, V, W, else E; `euclidean` takes
//!   the distance over every joint but E (E alone when nothing else moves); arcs count
//!   their (helical) length. A G93 block ([`FeedMode::InverseTime`]) takes 1/F minutes
//!   whatever the rule. Axes whose start or end position is unknown count as not moving.
//! - **Speed limits**: the block's speed along its rule distance is F (rapids: the
//!   model's `rapid_feed`, 3000 mm/min unless set), raised to the controller's
//!   `min_speed`, then lowered so that no axis exceeds its `max_feed`.
//! - [`Timing::ConstantVelocity`]: no acceleration; the block takes distance / speed.
//! - [`Timing::Trapezoid`]: each block has a trapezoidal (or triangular) speed profile over
//!   its rule distance. Its acceleration along the path is the smallest `a_k / |u_k|` over
//!   the moving axes `k` with a configured `acceleration` (`u` = joint delta / rule
//!   distance), so no axis accelerates faster than its limit; axes without one are
//!   unlimited, and a block with no limited axis changes speed instantly.
//!
//! # Junctions
//! The speed at the junction of two blocks follows RepRapFirmware's "jerk" rule (`M566`):
//! each axis may change its speed instantly by at most `controller.jerk` (mm/min or
//! deg/min, per axis; an axis of X, Y, Z, A, B, C without a value may not change speed at
//! all). The controller table has no entries for U, V, W and E, so they limit nothing:
//! speed, acceleration nor jerk (an extruder's rate changing between two printing moves
//! does not stop the machine). With block
//! directions `u1`, `u2` (joint delta per unit rule distance) the junction speed `v` is the
//! largest one with `v * |u2_k - u1_k| <= jerk_k` for every axis, and no more than either
//! block's top speed. So two collinear blocks run through at full speed, a corner on
//! axes without a jerk allowance stops, and a machine with large jerk values barely
//! slows. A dwell, a command that makes positions unknown (homing, probing, macros), a
//! line the IR passes through as text and the end of the program stop the machine.
//!
//! # Look-ahead
//! The [`Planner`] plans each motion block knowing the `controller.lookahead` (N,
//! default 16) motion blocks after it, and holds at most N unfinished ones. The oldest
//! block's exit speed is fixed when N more follow it: a backward pass over those blocks
//! assumes the machine must be able to stop at the end of the last (what a firmware with a
//! bounded queue does), a forward pass limits it to what the block can reach from its
//! fixed entry speed. Memory is bounded by the window; a longer window can only make the
//! program faster.
//!
//! ```
//! use ncpost::machine::{Controller, PerAxis};
//! use ncpost::motion::{Model, Planner, Timing};
//! use ncpost::ir::{Axis, Joints};
//! let mut c = Controller::default();
//! c.acceleration = PerAxis { x: Some(100.0), ..PerAxis::default() };
//! let model = Model::new(&c).with_timing(Timing::Trapezoid);
//! let (mut a, mut b) = (Joints::default(), Joints::default());
//! a.set(Axis::X, 0.0);
//! b.set(Axis::X, 100.0);
//! let mut planner = Planner::new(model.clone());
//! planner.push_move(model.linear(&a, &b, 600.0), ()); // 10 mm/s, 100 mm/s²
//! planner.finish();
//! let timed = planner.pop().unwrap();
//! // d/v + v/a: 100/10 + 10/100 seconds.
//! assert!((timed.duration() - 10.1).abs() < 1e-9);
//! ```

pub mod arc;

use std::collections::VecDeque;

use crate::ir::{AXIS_COUNT, Arc, Axis, FeedMode, Joints, Motion, MotionKind, Target};
use crate::machine::polar::Polar;
use crate::machine::{Controller, FeedRule, Flavour, Machine, PerAxis, RapidRule};
use arc::ArcPath;
use nalgebra::Point3;

/// Speed assumed for rapids when nothing else is known, mm/min.
pub const DEFAULT_RAPID_FEED: f64 = 3000.0;

pub use crate::machine::Timing;

/// The timing a pass uses: the run-wide `--timing` wins,
/// then the pass's own `timing` option, then the controller's `timing`.
pub fn resolve_timing(run: Option<Timing>, pass: Option<Timing>, controller: Timing) -> Timing {
    run.or(pass).unwrap_or(controller)
}

fn per_axis(p: &PerAxis, scale: f64) -> [Option<f64>; AXIS_COUNT] {
    std::array::from_fn(|k| {
        p.get(Axis::ALL[k])
            .filter(|v| v.is_finite() && *v > 0.0)
            .map(|v| v * scale)
    })
}

/// The controller's motion facts in the units the model computes with (seconds).
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// How F turns into a distance.
    pub rule: FeedRule,
    /// Constant velocity or trapezoid.
    pub timing: Timing,
    /// The controller's lowest speed, units/s.
    pub min_speed: f64,
    /// Rapid speed along the rule distance, units/s: for every rapid under
    /// [`RapidRule::Fixed`], else where the rule leaves the speed open (no F yet, no
    /// axis cap).
    pub rapid_speed: f64,
    /// How fast the controller runs `G0`.
    pub rapid: RapidRule,
    /// Motion blocks the trapezoid planner looks ahead.
    pub lookahead: usize,
    max_speed: [Option<f64>; AXIS_COUNT],
    accel: [Option<f64>; AXIS_COUNT],
    jerk: [f64; AXIS_COUNT],
}

impl Default for Model {
    fn default() -> Self {
        Model::new(&Controller::default())
    }
}

impl Model {
    /// The model of `controller` (its `timing`, `lookahead` and jerk included).
    pub fn new(controller: &Controller) -> Model {
        let jerk = per_axis(&controller.jerk, 1.0 / 60.0);
        Model {
            rule: controller.feed_rule,
            timing: controller.timing,
            min_speed: controller.min_speed().max(0.0) / 60.0,
            rapid_speed: DEFAULT_RAPID_FEED / 60.0,
            rapid: controller.rapid_rule(),
            lookahead: controller.lookahead.max(1),
            max_speed: per_axis(&controller.max_feed, 1.0 / 60.0),
            accel: per_axis(&controller.acceleration, 1.0),
            // Only X..C can be given; the others (U, V, W, E) are never limited.
            jerk: std::array::from_fn(|k| match Axis::ALL[k] {
                Axis::U | Axis::V | Axis::W | Axis::E => f64::INFINITY,
                _ => jerk[k].unwrap_or(0.0),
            }),
        }
    }

    /// The model a run uses: the polar machine's controller (the screw printer's), else
    /// the machine's, else the default controller of `flavour` (the firmware the backend
    /// prints for); timing by [`resolve_timing`] from the run-wide timing `run` and a
    /// pass's own option `pass`.
    pub fn for_machines(
        polar: Option<&Polar>,
        machine: Option<&Machine>,
        flavour: Option<Flavour>,
        run: Option<Timing>,
        pass: Option<Timing>,
    ) -> Model {
        let controller = polar
            .map(|p| &p.controller)
            .or(machine.map(|m| &m.controller));
        let model = controller
            .map(Model::new)
            .unwrap_or_else(|| Model::new(&Controller::of(flavour)));
        let timing = resolve_timing(run, pass, model.timing);
        model.with_timing(timing)
    }

    /// The same model with another timing.
    pub fn with_timing(mut self, timing: Timing) -> Model {
        self.timing = timing;
        self
    }

    /// The same model with rapids at `feed` mm/min.
    pub fn with_rapid_feed(mut self, feed: f64) -> Model {
        if feed.is_finite() && feed > 0.0 {
            self.rapid_speed = feed / 60.0;
        }
        self
    }

    /// The same model looking ahead `blocks` motion blocks (at least 1).
    pub fn with_lookahead(mut self, blocks: usize) -> Model {
        self.lookahead = blocks.max(1);
        self
    }

    /// A G1 from `from` to `to` at `feed` mm/min.
    pub fn linear(&self, from: &Joints, to: &Joints, feed: f64) -> Segment {
        self.segment_from(from, to, None, Some(Feed::PerMinute(feed)))
    }

    /// The segment of an IR motion starting at `from` (its target must be joints;
    /// a pose target gives `None`). Feed per revolution (G95) has no time without the
    /// spindle speed: such a move, like a feed move without F, runs at the rapid speed.
    pub fn motion(&self, from: &Joints, motion: &Motion) -> Option<Segment> {
        let Target::Joints(to) = &motion.target else {
            return None;
        };
        Some(self.between(from, to, motion.kind, &motion.feed))
    }

    /// The segment of a move of `kind` at `feed` from `from` to `to` ([`Model::motion`]
    /// for a pass that has the ends at hand, such as the printed joints of a move).
    pub fn between(
        &self,
        from: &Joints,
        to: &Joints,
        kind: MotionKind,
        feed: &crate::ir::Feed,
    ) -> Segment {
        let arc = match kind {
            MotionKind::Arc(a) => Some(a),
            _ => None,
        };
        let feed = match (kind, feed.mode, feed.rate) {
            (MotionKind::Rapid, FeedMode::PerMinute, Some(f))
                if self.rapid == RapidRule::ModalFeed && f > 0.0 =>
            {
                Some(Feed::PerMinute(f))
            }
            (MotionKind::Rapid, _, _) if self.rapid == RapidRule::MaxSpeed => Some(Feed::MaxSpeed),
            (MotionKind::Rapid, _, _) => None,
            (_, FeedMode::InverseTime, Some(f)) if f > 0.0 => Some(Feed::InverseTime(f)),
            (_, FeedMode::PerMinute, Some(f)) if f > 0.0 => Some(Feed::PerMinute(f)),
            _ => None,
        };
        self.segment_from(from, to, arc, feed)
    }

    fn segment_from(
        &self,
        from: &Joints,
        to: &Joints,
        arc: Option<Arc>,
        feed: Option<Feed>,
    ) -> Segment {
        // Axes known at both ends move by the difference, the others not at all.
        let both = from.known.intersection(to.known);
        let mut delta = [0.0; AXIS_COUNT];
        for (k, d) in delta.iter_mut().enumerate() {
            if both.contains(Axis::ALL[k]) {
                *d = to.values[k] - from.values[k];
            }
        }
        let arc_len = arc.map(|a| arc_length(from, to, &a));
        let length = rule_distance(self.rule, &delta, arc_len);
        let mut seg = Segment {
            delta,
            length,
            v_max: 0.0,
            accel: f64::INFINITY,
        };
        if length <= 0.0 {
            return seg;
        }
        let mut v = match feed {
            None => self.rapid_speed,
            Some(Feed::PerMinute(f)) => (f / 60.0).max(self.min_speed),
            Some(Feed::InverseTime(f)) => length * f / 60.0,
            // Capped below by the moving axes; uncapped, the run's rapid speed.
            Some(Feed::MaxSpeed) => f64::INFINITY,
        };
        // Constant velocity has no acceleration: the axes' acceleration limits do not
        // apply to it.
        let accelerates = self.timing != Timing::ConstantVelocity;
        for a in both.iter() {
            let k = a.index();
            let d = delta[k];
            // An axis that does not move limits nothing: no division for it.
            if d == 0.0 {
                continue;
            }
            // `m / u < v` needs `m · length < v · |d|`: the divisions only where the cap
            // may be lower (the margin is far beyond rounding, so the result is the same).
            let limits = |m: f64, v: f64| m * length <= v * d.abs() * (1.0 + 1e-9);
            let max_speed = self.max_speed[k].filter(|&m| limits(m, v));
            let accel = self.accel[k].filter(|&a| accelerates && limits(a, seg.accel));
            if max_speed.is_none() && accel.is_none() {
                continue;
            }
            let u = (d / length).abs();
            if u <= 0.0 {
                continue;
            }
            if let Some(m) = max_speed {
                v = v.min(m / u);
            }
            if let Some(a) = accel {
                seg.accel = seg.accel.min(a / u);
            }
        }
        seg.v_max = if v.is_finite() { v } else { self.rapid_speed };
        seg
    }

    /// The largest junction speed between `a` and `b` under the per-axis jerk rule.
    pub fn junction(&self, a: &Segment, b: &Segment) -> f64 {
        let mut v = a.v_max.min(b.v_max);
        if a.length <= 0.0 || b.length <= 0.0 {
            return 0.0;
        }
        for k in 0..AXIS_COUNT {
            let du = (b.delta[k] / b.length - a.delta[k] / a.length).abs();
            if du > 1e-12 {
                v = v.min(self.jerk[k] / du);
            }
        }
        v.max(0.0)
    }
}

#[derive(Debug, Clone, Copy)]
enum Feed {
    PerMinute(f64),
    InverseTime(f64),
    /// A rapid at the axes' caps.
    MaxSpeed,
}

/// The distance the controller applies F to, for joint deltas `delta` (mm, degrees);
/// `arc` is the (helical) XYZ length of an arc, which replaces the XYZ chord.
///
/// ```
/// use ncpost::machine::FeedRule;
/// use ncpost::motion::rule_distance;
/// let mut d = [0.0; 10];
/// d[0] = 3.0; // X
/// d[1] = 4.0; // Y
/// d[5] = 90.0; // C
/// assert_eq!(rule_distance(FeedRule::Nist, &d, None), 5.0);
/// assert!((rule_distance(FeedRule::Euclidean, &d, None) - (25.0f64 + 8100.0).sqrt()).abs() < 1e-12);
/// ```
pub fn rule_distance(rule: FeedRule, delta: &[f64; AXIS_COUNT], arc: Option<f64>) -> f64 {
    let norm = |axes: &[usize]| {
        axes.iter()
            .map(|&k| delta[k] * delta[k])
            .sum::<f64>()
            .sqrt()
    };
    let xyz = arc.unwrap_or_else(|| norm(&[0, 1, 2]));
    let e = delta[Axis::E.index()].abs();
    match rule {
        FeedRule::Euclidean => {
            let rest = norm(&[3, 4, 5, 6, 7, 8]);
            let d = xyz.hypot(rest);
            if d > 0.0 { d } else { e }
        }
        FeedRule::Nist | FeedRule::InverseTime => {
            for d in [xyz, norm(&[3, 4, 5]), norm(&[6, 7, 8])] {
                if d > 0.0 {
                    return d;
                }
            }
            e
        }
    }
}

/// Length of a (helical) arc from `a` to `b`, mm (the chord when the plane's axes are
/// not known).
pub fn arc_length(a: &Joints, b: &Joints, arc: &Arc) -> f64 {
    match ArcPath::new(a, b, arc) {
        Some(path) => path.length(),
        None => [Axis::X, Axis::Y, Axis::Z]
            .iter()
            .filter_map(|&k| Some((b.get(k)? - a.get(k)?).powi(2)))
            .sum::<f64>()
            .sqrt(),
    }
}

/// One motion block as the planner sees it: joint deltas, distance under the feed rule
/// and the limits along it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Joint deltas, mm or degrees, by [`Axis::index`] (0 for unknown axes).
    pub delta: [f64; AXIS_COUNT],
    /// Distance under the feed rule (the path parameter the controller plans along).
    pub length: f64,
    /// Top speed along `length`, units/s (F, the minimum speed and the axes' caps).
    pub v_max: f64,
    /// Acceleration along `length`, units/s² (infinite: instant speed changes).
    pub accel: f64,
}

impl Segment {
    /// Whether the block moves at all (a zero-length block takes no time).
    pub fn moves(&self) -> bool {
        self.length > 0.0 && self.v_max > 0.0
    }
}

/// The speed profile of one block: accelerate, cruise, decelerate.
///
/// Speeds are along the rule distance (mm/s for an XYZ move under NIST). The joints move
/// linearly in the rule distance, so the fraction of the distance covered is also the
/// fraction of the joint interpolation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    /// Rule distance.
    pub length: f64,
    /// Speed at the start.
    pub v_entry: f64,
    /// Highest speed reached (the cruise speed when `t_cruise > 0`).
    pub v_peak: f64,
    /// Speed at the end.
    pub v_exit: f64,
    /// Acceleration and deceleration along the path (infinite: none modelled).
    pub accel: f64,
    /// Seconds accelerating.
    pub t_accel: f64,
    /// Seconds at `v_peak`.
    pub t_cruise: f64,
    /// Seconds decelerating.
    pub t_decel: f64,
}

impl Profile {
    /// The profile of `seg` entered at `v0` and left at `v1` (both clamped to what the
    /// block allows).
    pub fn new(seg: &Segment, v0: f64, v1: f64) -> Profile {
        let l = seg.length;
        if !seg.moves() {
            return Profile {
                length: l.max(0.0),
                v_entry: 0.0,
                v_peak: 0.0,
                v_exit: 0.0,
                accel: f64::INFINITY,
                t_accel: 0.0,
                t_cruise: 0.0,
                t_decel: 0.0,
            };
        }
        let vm = seg.v_max;
        let a = seg.accel;
        if !a.is_finite() {
            return Profile {
                length: l,
                v_entry: vm,
                v_peak: vm,
                v_exit: vm,
                accel: a,
                t_accel: 0.0,
                t_cruise: l / vm,
                t_decel: 0.0,
            };
        }
        let v0 = v0.clamp(0.0, vm);
        let v1 = v1.clamp(0.0, vm);
        let vp = vm
            .min(((2.0 * a * l + v0 * v0 + v1 * v1) / 2.0).sqrt())
            .max(v0)
            .max(v1);
        let da = (vp * vp - v0 * v0) / (2.0 * a);
        let dd = (vp * vp - v1 * v1) / (2.0 * a);
        let dc = (l - da - dd).max(0.0);
        Profile {
            length: l,
            v_entry: v0,
            v_peak: vp,
            v_exit: v1,
            accel: a,
            t_accel: (vp - v0) / a,
            t_cruise: if vp > 0.0 { dc / vp } else { 0.0 },
            t_decel: (vp - v1) / a,
        }
    }

    /// Seconds the block takes.
    pub fn duration(&self) -> f64 {
        self.t_accel + self.t_cruise + self.t_decel
    }

    /// Speed along the rule distance `t` seconds into the block.
    pub fn speed_at(&self, t: f64) -> f64 {
        let t = t.clamp(0.0, self.duration());
        if t < self.t_accel {
            self.v_entry + self.accel * t
        } else if t <= self.t_accel + self.t_cruise {
            self.v_peak
        } else {
            let td = t - self.t_accel - self.t_cruise;
            (self.v_peak - self.accel * td).max(self.v_exit)
        }
    }

    fn accel_distance(&self) -> f64 {
        if self.t_accel > 0.0 {
            (self.v_entry + self.v_peak) / 2.0 * self.t_accel
        } else {
            0.0
        }
    }

    /// Rule distance covered `t` seconds into the block.
    pub fn distance_at(&self, t: f64) -> f64 {
        let t = t.clamp(0.0, self.duration());
        let da = self.accel_distance();
        let s = if t < self.t_accel {
            self.v_entry * t + self.accel * t * t / 2.0
        } else if t <= self.t_accel + self.t_cruise {
            da + self.v_peak * (t - self.t_accel)
        } else {
            let td = t - self.t_accel - self.t_cruise;
            da + self.v_peak * self.t_cruise + self.v_peak * td - self.accel * td * td / 2.0
        };
        s.clamp(0.0, self.length)
    }

    /// Seconds into the block at which rule distance `s` is reached.
    pub fn time_at_distance(&self, s: f64) -> f64 {
        let s = s.clamp(0.0, self.length);
        let da = self.accel_distance();
        let dc = self.v_peak * self.t_cruise;
        if s <= da && self.t_accel > 0.0 {
            let a = self.accel;
            let v0 = self.v_entry;
            // The stable root of v0 t + a t²/2 = s.
            let t = 2.0 * s / (v0 + (v0 * v0 + 2.0 * a * s).sqrt());
            return t.min(self.t_accel);
        }
        if s <= da + dc || self.t_decel <= 0.0 {
            let t = if self.v_peak > 0.0 {
                (s - da) / self.v_peak
            } else {
                0.0
            };
            return self.t_accel + t.clamp(0.0, self.t_cruise);
        }
        let sd = s - da - dc;
        let vp = self.v_peak;
        let root = (vp * vp - 2.0 * self.accel * sd).max(0.0).sqrt();
        let td = if vp + root > 0.0 {
            2.0 * sd / (vp + root)
        } else {
            0.0
        };
        self.t_accel + self.t_cruise + td.min(self.t_decel)
    }

    /// Fraction of the block (of its joint interpolation) done `t` seconds in.
    pub fn fraction_at(&self, t: f64) -> f64 {
        if self.length > 0.0 {
            self.distance_at(t) / self.length
        } else if t > 0.0 {
            1.0
        } else {
            0.0
        }
    }

    /// Seconds into the block at which `fraction` (0..=1) of it is done.
    pub fn time_at_fraction(&self, fraction: f64) -> f64 {
        self.time_at_distance(fraction.clamp(0.0, 1.0) * self.length)
    }

    /// The phase boundaries, seconds from the block's start: 0, end of acceleration,
    /// end of cruise, end.
    pub fn phases(&self) -> [f64; 4] {
        [
            0.0,
            self.t_accel,
            self.t_accel + self.t_cruise,
            self.duration(),
        ]
    }
}

/// Joints a fraction `f` of the way from `from` to `to` (linear interpolation; axes
/// unknown at either end keep `to`'s state).
pub fn lerp(from: &Joints, to: &Joints, f: f64) -> Joints {
    let mut j = *to;
    for a in to.known.iter() {
        if let Some(p) = from.get(a) {
            j.values[a.index()] = p + (to.values[a.index()] - p) * f;
        }
    }
    j
}

/// The tool's speed (units of `map` per second) `t` seconds into a block that moves the
/// joints linearly from `from` to `to` with `profile`, where `map` gives the tool point of
/// a joint vector (for a polar machine: r, θ → x, y). The derivative is a central
/// difference of `map` along the joint interpolation.
///
/// ```
/// use ncpost::ir::{Axis, Joints};
/// use ncpost::motion::{Model, Profile, tool_speed};
/// use nalgebra::Point3;
/// let (mut a, mut b) = (Joints::default(), Joints::default());
/// a.set(Axis::X, 10.0); a.set(Axis::Y, 0.0);   // r = 10 mm, θ = 0
/// b.set(Axis::X, 10.0); b.set(Axis::Y, 90.0);  // quarter turn
/// let model = Model::default();
/// let seg = model.linear(&a, &b, 5400.0);      // 90 deg/s on the table
/// let p = Profile::new(&seg, 0.0, 0.0);
/// let polar = |j: &Joints| { let (r, th) = (j.values[0], j.values[1].to_radians()); Point3::new(r * th.cos(), r * th.sin(), 0.0) };
/// let v = tool_speed(&p, &a, &b, 0.5, polar);
/// assert!((v - 10.0 * std::f64::consts::FRAC_PI_2).abs() < 1e-6); // r θ̇
/// ```
pub fn tool_speed(
    profile: &Profile,
    from: &Joints,
    to: &Joints,
    t: f64,
    map: impl Fn(&Joints) -> Point3<f64>,
) -> f64 {
    if profile.length <= 0.0 {
        return 0.0;
    }
    let f = profile.fraction_at(t);
    let h = 1e-6;
    let (f0, f1) = ((f - h).max(0.0), (f + h).min(1.0));
    if f1 <= f0 {
        return 0.0;
    }
    let dp = (map(&lerp(from, to, f1)) - map(&lerp(from, to, f0))).norm() / (f1 - f0);
    dp * profile.speed_at(t) / profile.length
}

/// A polar machine's tool point: `r_axis` is the radius (mm), `theta_axis` the table angle
/// (degrees); Z is kept.
pub fn polar_point(j: &Joints, r_axis: Axis, theta_axis: Axis) -> Point3<f64> {
    let r = j.values[r_axis.index()];
    let th = j.values[theta_axis.index()].to_radians();
    Point3::new(r * th.cos(), r * th.sin(), j.values[Axis::Z.index()])
}

/// One item of the planned program, with its time.
#[derive(Debug, Clone, PartialEq)]
pub struct Timed<T> {
    /// Seconds from the program start at which it begins.
    pub start: f64,
    /// The motion's segment and profile; `None` for items that are not moves.
    pub motion: Option<(Segment, Profile)>,
    /// Seconds of dwell.
    pub dwell: f64,
    /// What the caller attached.
    pub payload: T,
}

impl<T> Timed<T> {
    /// Seconds the item takes.
    pub fn duration(&self) -> f64 {
        self.motion.map_or(0.0, |(_, p)| p.duration()) + self.dwell
    }
    /// Seconds from the program start at which it ends.
    pub fn end(&self) -> f64 {
        self.start + self.duration()
    }

    /// The fraction of this move done at `time` (seconds from the program start), if
    /// the move runs then: the point to split it at for an event at `time` (a valve
    /// command issued a delay before an extrusion starts). Splitting a move there does
    /// not change the timing: the two parts are collinear, so the junction between them
    /// is taken at full speed (as long as the extra block does not push a stop the
    /// look-ahead must see out of its window).
    ///
    /// ```
    /// use ncpost::ir::{Axis, Joints};
    /// use ncpost::motion::{Model, Planner};
    /// let (mut a, mut b) = (Joints::default(), Joints::default());
    /// a.set(Axis::X, 0.0);
    /// b.set(Axis::X, 10.0);
    /// let model = Model::default();
    /// let mut planner = Planner::new(model.clone());
    /// planner.push_move(model.linear(&a, &b, 600.0), ()); // 1 s
    /// planner.finish();
    /// let item = planner.pop().unwrap();
    /// assert_eq!(item.fraction_at_time(0.25), Some(0.25));
    /// assert_eq!(item.fraction_at_time(2.0), None);
    /// ```
    pub fn fraction_at_time(&self, time: f64) -> Option<f64> {
        let (_, p) = self.motion?;
        let t = time - self.start;
        (t >= 0.0 && t <= p.duration()).then(|| p.fraction_at(t))
    }

    /// Seconds from the program start at which `fraction` of this move is done (the
    /// start time for an item that is not a move).
    pub fn time_at_fraction(&self, fraction: f64) -> f64 {
        self.start
            + self
                .motion
                .map_or(0.0, |(_, p)| p.time_at_fraction(fraction))
    }
}

struct Pending<T> {
    seg: Option<Segment>,
    dwell: f64,
    payload: T,
}

/// Plans speeds over a stream of blocks with bounded look-ahead and hands them back in
/// order, timed.
///
/// Push items with [`Planner::push_move`], [`Planner::push_other`] or
/// [`Planner::push_stop`]; take finished ones with [`Planner::pop`]. Under constant
/// velocity every item is ready at once; under the trapezoid model a move is ready once
/// `lookahead` moves follow it, or at a stop, or after [`Planner::finish`].
pub struct Planner<T> {
    model: Model,
    queue: VecDeque<Pending<T>>,
    moves_queued: usize,
    ready: VecDeque<Timed<T>>,
    time: f64,
    /// Exit speed and segment of the last move handed out, while the machine is moving.
    last: Option<(Segment, f64)>,
}

impl<T> Planner<T> {
    /// An empty planner for `model`.
    pub fn new(model: Model) -> Self {
        Planner {
            model,
            queue: VecDeque::new(),
            moves_queued: 0,
            ready: VecDeque::new(),
            time: 0.0,
            last: None,
        }
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Seconds of program handed out so far (the start time of the next ready item).
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Adds a move.
    pub fn push_move(&mut self, seg: Segment, payload: T) {
        let instant = self.model.timing == Timing::ConstantVelocity || !seg.moves();
        if instant && self.queue.is_empty() {
            // Nothing to plan: constant velocity needs no look-ahead.
            self.hand_out(Some(seg), 0.0, payload, 0.0, 0.0);
            return;
        }
        self.queue.push_back(Pending {
            seg: Some(seg),
            dwell: 0.0,
            payload,
        });
        if seg.moves() {
            self.moves_queued += 1;
        }
        let window = match self.model.timing {
            Timing::ConstantVelocity => 0,
            Timing::Trapezoid => self.model.lookahead,
        };
        while self.moves_queued > window {
            self.release_first_move();
        }
    }

    /// Adds an item that takes no time and does not stop the machine (a comment, an
    /// M-code).
    pub fn push_other(&mut self, payload: T) {
        if self.queue.is_empty() {
            self.hand_out(None, 0.0, payload, 0.0, 0.0);
        } else {
            self.queue.push_back(Pending {
                seg: None,
                dwell: 0.0,
                payload,
            });
        }
    }

    /// Adds an item that stops the machine and then waits `dwell` seconds (a dwell, a
    /// homing command, the end of the program).
    pub fn push_stop(&mut self, dwell: f64, payload: T) {
        self.flush();
        self.last = None;
        self.hand_out(None, dwell.max(0.0), payload, 0.0, 0.0);
    }

    /// Plans everything queued, stopping at the end.
    pub fn finish(&mut self) {
        self.flush();
        self.last = None;
    }

    /// The next item whose timing is final.
    pub fn pop(&mut self) -> Option<Timed<T>> {
        self.ready.pop_front()
    }

    fn flush(&mut self) {
        while self.moves_queued > 0 {
            self.release_first_move();
        }
        while let Some(p) = self.queue.pop_front() {
            self.hand_out(p.seg, p.dwell, p.payload, 0.0, 0.0);
        }
    }

    /// Fixes the exit speed of the first queued move and hands it (and the items before
    /// it) out.
    fn release_first_move(&mut self) {
        let moving: Vec<Segment> = self
            .queue
            .iter()
            .filter_map(|p| p.seg.filter(|s| s.moves()))
            .collect();
        let Some(first) = moving.first().copied() else {
            return;
        };
        // Backward pass: the fastest exit of each move from which the machine can still
        // stop at the end of the window.
        let mut exit = 0.0f64;
        for i in (1..moving.len()).rev() {
            let s = &moving[i];
            let entry = (exit * exit + 2.0 * s.accel * s.length)
                .sqrt()
                .min(s.v_max)
                .min(self.model.junction(&moving[i - 1], s));
            exit = entry;
        }
        let entry = match &self.last {
            Some((prev, v)) => v.min(self.model.junction(prev, &first)),
            None => 0.0,
        };
        // Forward pass for the first move: no faster than it can reach from its entry.
        let exit = exit.min((entry * entry + 2.0 * first.accel * first.length).sqrt());
        while let Some(p) = self.queue.pop_front() {
            let is_first = p.seg.is_some_and(|s| s.moves());
            self.hand_out(p.seg, p.dwell, p.payload, entry, exit);
            if is_first {
                self.moves_queued -= 1;
                break;
            }
        }
    }

    fn hand_out(&mut self, seg: Option<Segment>, dwell: f64, payload: T, v0: f64, v1: f64) {
        let constant = self.model.timing == Timing::ConstantVelocity;
        let motion = seg.map(|mut s| {
            if constant {
                s.accel = f64::INFINITY;
            }
            let p = Profile::new(&s, v0, v1);
            // Junction speeds are the trapezoid planner's: under constant velocity every
            // move starts on its own.
            if !constant && s.moves() {
                self.last = Some((s, p.v_exit));
            }
            (s, p)
        });
        let item = Timed {
            start: self.time,
            motion,
            dwell,
            payload,
        };
        self.time = item.end();
        self.ready.push_back(item);
    }
}
