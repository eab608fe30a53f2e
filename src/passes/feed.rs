//! `feed`: the F that makes the controller take the programmed time for each joint move.
//!
//! The programmed F of CL data is the tool-tip speed in the part frame (mm/min). The
//! controller does not know the tip: it reads F under its own rule over the joint deltas
//! (machine `controller.feed_rule`, or option `mode`):
//! - `nist` (RepRapFirmware, LinuxCNC G94; RS274NGC 2.1.2.5): F is the XYZ speed when any
//!   of X, Y, Z moves, otherwise the rotary speed in degrees per minute;
//! - `inverse-time` (G93): the move takes 1/F minutes;
//! - `euclidean`: F is the speed over all five joint deltas.
//!
//! For a move whose tip travels `L` at the programmed `F`, the time is `t = L / F` and the
//! emitted F is the rule's distance over `t`. Everything is computed from the numbers the
//! controller will read: each joint value rounded as the backend prints it (with the G92
//! offsets in force), both for `L` (forward kinematics of the rounded joints) and for the
//! controller's distance. The IR joint values themselves are left exact.
//!
//! A move that turns the tool about a fixed tip has no tip speed; it turns at
//! `reorient_feed` degrees per minute (over the two rotary deltas) instead.
//!
//! Warnings (each shown once with its place, then counted at the end): `feed::min-speed`
//! when the controller's speed for the block (in G93: the NIST distance over the block's
//! time) is below `controller.min_speed`, so the block would run faster than programmed; `feed::max-speed` when an axis would exceed
//! its `max_feed`, so the controller slows the block down; `feed::precision` when the
//! printed F is more than 0.1 % off. A cutting move without a feed rate is the error
//! `feed::missing`. Rapids, arcs, G53 moves, feeds not in mm/min and moves from or to a
//! position with an unknown machine axis pass unchanged.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::{Context, Output, Pass, PassInfo};
use crate::back::Decimals;
use crate::back::number::{self, to_units};
use crate::diag::Diagnostic;
use crate::ir::{AXIS_COUNT, Axis, Block, BlockKind, FeedMode, Joints, MotionKind, Span, Target};
use crate::machine::{FeedRule, Machine};

/// Options of `feed`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// How the controller reads F (`nist`, `inverse-time`, `euclidean`); default: the
    /// machine's `controller.feed_rule`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mode: Option<FeedRule>,
    /// Rotary speed of a pure reorientation (the tip stands still), degrees per minute.
    pub reorient_feed: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            mode: None,
            reorient_feed: 1000.0,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "feed",
    summary: "set each joint move's F (G94 under the controller's rule, or G93) so it takes the programmed tool-tip time",
    build: |t, ctx| {
        let machine = ctx.require_machine("feed")?;
        Ok(Box::new(Feed::new(
            machine.clone(),
            super::options(t)?,
            ctx,
        )?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// Below this tip travel (mm) a move is a pure reorientation.
const ZERO_TIP: f64 = 1e-6;

/// Largest relative error of a printed F.
const FEED_PRECISION: f64 = 1e-3;

/// A warning shown once with its place and counted for the end of the run.
#[derive(Debug, Default)]
struct Counted {
    count: u64,
}

impl Counted {
    fn hit(&mut self, diags: &mut Vec<Diagnostic>, make: impl FnOnce() -> Diagnostic) {
        if self.count == 0 {
            diags.push(make());
        }
        self.count += 1;
    }
}

/// A position as the controller reads it.
#[derive(Debug, Clone, Copy)]
struct Read {
    /// The five machine axes in the program frame after printing (what the controller
    /// moves between).
    printed: [f64; 5],
    /// The tool tip of the printed position (part frame).
    tip: Point3<f64>,
    /// The exact IR position (its tip is only needed to tell a reorientation from a
    /// short move, so it is computed when the printed tips are close).
    exact: [f64; 5],
}

/// The `feed` pass.
pub struct Feed {
    machine: Machine,
    rule: FeedRule,
    reorient_feed: f64,
    decimals: Option<Decimals>,
    axes: [Axis; 5],
    /// The printed decimals of each of `axes`, when the backend prints at all.
    places: Option<[u8; 5]>,
    /// Each of `axes`' `max_feed` and the speed above which it warns (a little over it,
    /// so that a move at exactly the limit does not).
    max_feed: [Option<(f64, f64)>; 5],
    /// `10^decimals.feed`: a printed F is a whole number of `1 / feed_scale`.
    feed_scale: f64,
    prev: Joints,
    /// `prev` as read, when already computed under the offsets in force.
    prev_read: Option<Read>,
    offsets: [f64; AXIS_COUNT],
    /// The last rate emitted (for moves of zero length).
    last_rate: Option<f64>,
    missing: Counted,
    min_speed: Counted,
    max_speed: Counted,
    precision: Counted,
}

impl Feed {
    /// A `feed` pass for `machine`; `context.decimals` is the backend's precision.
    pub fn new(machine: Machine, options: Options, context: &Context<'_>) -> Result<Feed, String> {
        machine.check()?;
        if !(options.reorient_feed.is_finite() && options.reorient_feed > 0.0) {
            return Err("reorient_feed must be a positive number of degrees per minute".into());
        }
        let [r0, r1] = machine.rotary_axes();
        let axes = [Axis::X, Axis::Y, Axis::Z, r0, r1];
        let max_feed = axes.map(|a| {
            let max = machine.controller.max_feed.get(a)?;
            Some((max, max * (1.0 + 1e-9)))
        });
        Ok(Feed {
            rule: options.mode.unwrap_or(machine.controller.feed_rule),
            machine,
            reorient_feed: options.reorient_feed,
            decimals: context.decimals,
            places: context.decimals.map(|d| axes.map(|a| d.axis(a))),
            max_feed,
            feed_scale: context.decimals.map_or(1.0, |d| 10f64.powi(d.feed as i32)),
            axes,
            prev: Joints::default(),
            prev_read: None,
            offsets: [0.0; AXIS_COUNT],
            last_rate: None,
            missing: Counted::default(),
            min_speed: Counted::default(),
            max_speed: Counted::default(),
            precision: Counted::default(),
        })
    }

    /// The five axes of `j` as the controller reads them; `None` if one is unknown or
    /// cannot be printed.
    fn read(&self, j: &Joints) -> Option<Read> {
        let mut printed = [0.0; 5];
        let mut ir = [0.0; 5];
        let mut exact = [0.0; 5];
        for (k, &a) in self.axes.iter().enumerate() {
            let v = j.get(a)?;
            let off = self.offsets[a.index()];
            printed[k] = match self.places {
                Some(places) => number::printed(v + off, places[k])?,
                None => v + off,
            };
            ir[k] = printed[k] - off;
            exact[k] = v;
        }
        Some(Read {
            printed,
            tip: self.tip(&ir),
            exact,
        })
    }

    /// The tool tip of the five axes `v` (in the order of `axes`).
    fn tip(&self, v: &[f64; 5]) -> Point3<f64> {
        self.machine.forward(&[v[0], v[1], v[2]], [v[3], v[4]]).tip
    }

    /// The new feed of a linear move from `prev` to `end` at programmed tip speed `rate`.
    fn feed_for(
        &mut self,
        span: Span,
        a: &Read,
        b: &Read,
        rate: f64,
        diags: &mut Vec<Diagnostic>,
    ) -> (FeedMode, f64) {
        let mode = match self.rule {
            FeedRule::InverseTime => FeedMode::InverseTime,
            _ => FeedMode::PerMinute,
        };
        let delta: [f64; 5] = std::array::from_fn(|k| b.printed[k] - a.printed[k]);
        let dxyz = (delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]).sqrt();
        // Only a move without XYZ travel, a reorientation or the Euclidean rule needs it.
        let drot = || delta[3].hypot(delta[4]);
        // `hypot` is zero exactly when both rotary deltas are.
        if dxyz == 0.0 && delta[3] == 0.0 && delta[4] == 0.0 {
            // The controller skips a move that goes nowhere; any valid F will do.
            let f = self.last_rate.unwrap_or(rate);
            return (mode, f);
        }
        let length = (b.tip - a.tip).norm();
        // Rounding moves a tip by well under this, so a longer printed move is no
        // reorientation and the exact tips need not be computed.
        let exact = if length > 0.01 {
            length
        } else {
            (self.tip(&b.exact) - self.tip(&a.exact)).norm()
        };
        let minutes = if exact.min(length) <= ZERO_TIP {
            drot() / self.reorient_feed
        } else {
            length / rate
        };
        // Rounding can leave a reorientation without rotary travel: the move is then a
        // few units of XYZ correction, run at the programmed speed.
        let minutes = if minutes > 0.0 { minutes } else { dxyz / rate };
        let nist = if dxyz > 0.0 { dxyz } else { drot() };
        let mut f = match self.rule {
            FeedRule::Nist => nist / minutes,
            FeedRule::InverseTime => 1.0 / minutes,
            FeedRule::Euclidean => dxyz.hypot(drot()) / minutes,
        };
        let speed = match self.rule {
            FeedRule::Euclidean => f,
            _ => nist / minutes,
        };
        let min = self.machine.controller.min_speed;
        if speed < min {
            self.min_speed.hit(diags, || {
                Diagnostic::warning(
                    "feed::min-speed",
                    format!(
                        "this move needs {speed:.3}/min, below the controller's minimum speed of {min}: it will run faster than programmed"
                    ),
                )
                .at_span(span)
                .with_help("lower the controller's minimum speed (RepRapFirmware: M203 I) and `controller.min_speed`, or raise the programmed feed")
            });
        }
        for (k, &axis) in self.axes.iter().enumerate() {
            let Some((max, limit)) = self.max_feed[k] else {
                continue;
            };
            let v = delta[k].abs() / minutes;
            if v > limit {
                self.max_speed.hit(diags, || {
                    Diagnostic::warning(
                        "feed::max-speed",
                        format!(
                            "{} would move at {v:.1}/min, above its max_feed of {max}: the controller slows the move down, so it takes longer than programmed",
                            axis.letter()
                        ),
                    )
                    .at_span(span)
                    .with_help("lower the programmed feed here; near a singular orientation a short tip move needs a large rotary turn")
                });
            }
        }
        if let Some(d) = self.decimals {
            let scale = self.feed_scale;
            if let Some(units) = to_units(f, d.feed) {
                let printed = if units == 0 {
                    1.0 / scale
                } else {
                    units as f64 / scale
                };
                let error = (printed - f).abs() / f;
                if error > FEED_PRECISION {
                    let wanted = f;
                    self.precision.hit(diags, || {
                        Diagnostic::warning(
                            "feed::precision",
                            format!(
                                "F {wanted:.6} prints as {printed} at {} decimals, {:.2} % off: the move takes the wrong time",
                                d.feed,
                                100.0 * error
                            ),
                        )
                        .at_span(span)
                        .with_help("print F with more decimals (the backend's `decimals.feed`)")
                    });
                }
                if units == 0 {
                    // F0 is no feed at all; the slowest printable one is the nearest.
                    f = printed;
                }
            }
        }
        self.last_rate = Some(f);
        (mode, f)
    }
}

impl Pass for Feed {
    fn name(&self) -> &'static str {
        "feed"
    }

    fn run(&mut self, mut block: Block, out: &mut Output<'_>) {
        self.apply(&mut block, out.diags);
        out.push(block);
    }

    fn run_batch(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        super::edit_in_place(self, blocks, out, |pass, block, diags| {
            pass.apply(block, diags);
            true
        });
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        let summary = |c: &Counted, code: &'static str, what: &str| {
            (c.count > 1).then(|| Diagnostic::warning(code, format!("{} {what} in all", c.count)))
        };
        // The first missing feed is an error already; the count is for information.
        if self.missing.count > 1 {
            out.diag(Diagnostic::note(
                "feed::missing",
                format!(
                    "{} cutting moves in all have no feed rate",
                    self.missing.count
                ),
            ));
        }
        let notes = [
            summary(
                &self.min_speed,
                "feed::min-speed",
                "moves below the controller's minimum speed",
            ),
            summary(
                &self.max_speed,
                "feed::max-speed",
                "moves above an axis' max_feed",
            ),
            summary(
                &self.precision,
                "feed::precision",
                "feeds printed more than 0.1 % off",
            ),
        ];
        for d in notes.into_iter().flatten() {
            out.diag(d);
        }
    }
}

impl Feed {
    /// Sets the F of a cutting move in place and follows the position.
    fn apply(&mut self, block: &mut Block, diags: &mut Vec<Diagnostic>) {
        let span = block.span;
        let mut next_read = None;
        match &mut block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(end) = m.target else {
                    // A pose this late means the joints are not known.
                    self.prev = Joints::default();
                    return;
                };
                if matches!(m.kind, MotionKind::Linear)
                    && !m.machine_frame
                    && m.feed.mode == FeedMode::PerMinute
                {
                    match m.feed.rate {
                        Some(rate) if rate.is_finite() && rate > 0.0 => {
                            let a = self.prev_read.or_else(|| self.read(&self.prev));
                            let b = self.read(&end);
                            if let (Some(a), Some(b)) = (a, b) {
                                let (mode, f) = self.feed_for(span, &a, &b, rate, diags);
                                m.feed.mode = mode;
                                m.feed.rate = Some(f);
                            }
                            // The next move starts here: read once.
                            next_read = b;
                        }
                        _ => self.missing.hit(diags, || {
                            Diagnostic::error("feed::missing", "a cutting move without a feed rate")
                                .at_span(span)
                                .with_help("give FEDRAT (or F) before the first cutting move")
                        }),
                    }
                }
                self.prev = end;
                if m.machine_frame {
                    self.prev.forget(m.written);
                    next_read = None;
                }
            }
            BlockKind::Offset(o) => {
                self.offsets = o.offsets;
                for a in o.declared.known.iter() {
                    if self.prev.get(a).is_none() {
                        self.prev
                            .set(a, o.declared.values[a.index()] - o.offsets[a.index()]);
                    }
                }
            }
            BlockKind::Command(c) => self.prev.forget(c.clobbers),
            BlockKind::Verbatim(v) => self.prev.forget(v.clobbers),
            // Neither moves nor changes the frame.
            BlockKind::Dwell { .. } | BlockKind::Comment => next_read = self.prev_read,
        }
        self.prev_read = next_read;
    }
}
