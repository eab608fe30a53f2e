//! Flips of `ik`: the error, or the retract that turns the rotaries clear of the part.

use super::{Choice, Ik, OnFlip, TIE};
use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, Joints, Motion, MotionKind, Span, Target};
use crate::machine::angle::LIMIT_SLACK;
use crate::passes::Output;

impl Ik {
    /// Which rotary of `angles` is outside its limits, for messages:
    /// `B would be -40.000 deg, outside -35..120`; `None` when both are inside.
    pub(super) fn outside(&self, angles: [f64; 2]) -> Option<String> {
        (0..2).find_map(|i| {
            let (lo, hi) = self.machine.limits(self.axes[i])?;
            let v = angles[i];
            (v < lo - LIMIT_SLACK || v > hi + LIMIT_SLACK).then(|| {
                format!(
                    "{} would be {v:.3} deg, outside {lo}..{hi}",
                    self.axes[i].letter()
                )
            })
        })
    }

    /// Pose motion `m` needs the rotaries to flip to the other solution, `jump` degrees
    /// away from the previous joints, while the continuing one (`continuous`) is out of
    /// limits: with `on_flip = "retract"` and a known position, the retract and the turn
    /// go out before the block; otherwise the error `ik::flip`.
    pub(super) fn flip(
        &self,
        span: Span,
        m: &Motion,
        choice: &Choice,
        (continuous, jump): ([f64; 2], f64),
        no_flip_free: Option<&str>,
        out: &mut Output<'_>,
    ) {
        let Target::Pose(pose) = &m.target else {
            return;
        };
        let out_of_range = self
            .outside(continuous)
            .unwrap_or_else(|| "the continuous solution is out of limits".into());
        let safe_z = self
            .options
            .clearance
            .or_else(|| self.machine.limits(Axis::Z).map(|(_, hi)| hi));
        let (OnFlip::Retract, Some(start), Some(safe_z)) =
            (self.options.on_flip, self.prev_five(), safe_z)
        else {
            let help = if self.options.on_flip != OnFlip::Retract {
                "set `on_flip = \"retract\"` in the preset's ik options to retract, rotate and re-engage".to_string()
            } else if self.prev_five().is_none() {
                "the position before this block is not known, so there is nothing to retract from; move to a known pose first".to_string()
            } else {
                "no safe height to turn the rotaries at: set the ik option `clearance` (machine Z, mm) or the machine's Z travel".to_string()
            };
            out.diag(
                Diagnostic::error(
                    "ik::flip",
                    format!(
                        "the path leaves the rotaries' reach on its current solution ({out_of_range}); the other solution is {jump:.3} deg away, too far for a cutting move{}",
                        no_flip_free.map_or(String::new(), |why| format!("; no flip-free choice exists: {why}"))
                    ),
                )
                .at_span(span)
                .with_help(help),
            );
            return;
        };
        let flip = Flip {
            start,
            choice,
            safe_z,
            why: out_of_range,
            jump,
        };
        self.retract_turn_plunge(span, m, pose, &flip, out);
    }

    /// The moves of a flip, before the block's own move plunges onto its target: out of
    /// the cut along the old tool axis (at the block's feed: the tool may be in the
    /// material), straight up to the safe height, the rotaries turned with the linear
    /// axes still, across to the new point's X and Y, and down to `retract_distance`
    /// above it along the new tool axis. What a real post does; nothing here checks the
    /// tool against the part or the fixture, which the safe height must clear.
    fn retract_turn_plunge(
        &self,
        span: Span,
        m: &Motion,
        pose: &crate::ir::Pose,
        flip: &Flip<'_>,
        out: &mut Output<'_>,
    ) {
        let (xyz0, angles0) = flip.start;
        let d = self.options.retract_distance;
        let from = self.machine.forward(&xyz0, angles0);
        let up = from.tip + from.axis.into_inner() * d;
        let above = pose.tip + pose.axis.into_inner() * d;
        let retract = self.joints_at(&up, angles0, None, &Joints::NONE);
        let lowered = self.joints_at(&above, flip.choice.angles, flip.choice.trig, &Joints::NONE);
        let mut lifted = retract;
        let z = retract.get(Axis::Z).unwrap_or(flip.safe_z).max(flip.safe_z);
        lifted.set(Axis::Z, z);
        let mut turned = lifted;
        for a in self.axes {
            if let Some(v) = lowered.get(a) {
                turned.set(a, v);
            }
        }
        let mut across = turned;
        for a in [Axis::X, Axis::Y] {
            if let Some(v) = lowered.get(a) {
                across.set(a, v);
            }
        }
        let step = |kind: MotionKind, target: Joints| {
            Block::new(
                span,
                BlockKind::Motion(Motion {
                    kind,
                    target: Target::Joints(target),
                    feed: m.feed,
                    written: self.written(),
                    machine_frame: false,
                    extra: String::new(),
                }),
            )
        };
        out.push(step(MotionKind::Linear, retract));
        for target in [lifted, turned, across, lowered] {
            out.push(step(MotionKind::Rapid, target));
        }
        out.diag(
            Diagnostic::warning(
                "ik::retract",
                format!(
                    "the rotaries flip to the other solution ({}): retracting {d} mm along the tool axis, lifting to Z{z:.3}, turning {} by up to {:.3} deg with X, Y and Z still, and plunging back at the block's feed",
                    flip.why,
                    self.ranges_moved(angles0, flip.choice.angles),
                    flip.jump
                ),
            )
            .at_span(span),
        );
    }

    /// The letters of the rotaries that change between `a` and `b`: `A and C`.
    fn ranges_moved(&self, a: [f64; 2], b: [f64; 2]) -> String {
        let moved: Vec<String> = (0..2)
            .filter(|&i| (a[i] - b[i]).abs() > TIE)
            .map(|i| self.axes[i].letter().to_string())
            .collect();
        if moved.is_empty() {
            "the rotaries".into()
        } else {
            moved.join(" and ")
        }
    }
}

/// A flip the pass retracts for: the joints it starts from, the solution it turns to,
/// the safe height and why (for the warning).
struct Flip<'c> {
    start: ([f64; 3], [f64; 2]),
    choice: &'c Choice,
    safe_z: f64,
    why: String,
    jump: f64,
}
