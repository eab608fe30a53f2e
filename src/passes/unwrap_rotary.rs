//! `unwrap-rotary`: cyclic rotaries turn continuously, limited ones wrap into their range; optional G92 re-basing.
//!
//! A cyclic axis (the machine's cyclic rotaries; without a machine, the axes in `axes`)
//! takes in every joint move the value `v + 360 k` nearest its previous value, so a C
//! written in -180..180 (the seed's hand post) never turns the long way round. A limited
//! rotary whose value is outside `[min, max]` while a whole turn of it is inside takes that
//! turn (nearest its previous value). Already continuous input comes out unchanged.
//!
//! # Re-basing
//! RepRapFirmware keeps positions as 32-bit floats and never reduces a rotary modulo 360,
//! so a C that has turned many times loses precision. With `rebase = true`, before a rapid
//! whose printed value of a cyclic axis exceeds `rebase_above` in size, the pass inserts
//! `G92 C<c>` declaring the current position wrapped into (-180, 180]: an
//! [`OffsetChange`] whose offsets change that axis by whole turns. The IR stays continuous
//! (invariant 2); the backend prints IR + offset. Offsets from upstream G92 blocks are
//! tracked and rewritten so they agree with the unwrapped values and earlier re-basing.
//! A printed value beyond 8192 degrees gets the warning `unwrap::float32`.

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, Block, BlockKind, Joints, MotionKind, OffsetChange, OffsetCode, Span, Target,
};
use crate::machine::angle::{LIMIT_SLACK, near_turn, turn_within, wrap180};

/// Options of `unwrap-rotary`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Without a machine: the rotary axes (letters A, B, C) to treat as cyclic. With a
    /// machine its own rotaries are used and this is ignored.
    pub axes: Vec<String>,
    /// Insert `G92` before rapids to keep printed cyclic values small.
    pub rebase: bool,
    /// Re-base when a rapid's printed value of a cyclic axis is larger than this, degrees
    /// (at least 180).
    pub rebase_above: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            axes: vec!["C".into()],
            rebase: false,
            rebase_above: 360.0,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "unwrap-rotary",
    summary: "continuous cyclic rotaries (nearest whole turn to the previous value), limited rotaries wrapped into range, optional G92 re-basing at rapids",
    build: |t, ctx| {
        let options: Options = super::options(t)?;
        let rules = match ctx.machine {
            Some(m) => m
                .rotary
                .iter()
                .map(|r| {
                    let axis = r.axis.axis();
                    match m.limits(axis) {
                        Some((lo, hi)) => (axis, Rule::Limited(lo, hi)),
                        None => (axis, Rule::Cyclic),
                    }
                })
                .collect(),
            None => options
                .axes
                .iter()
                .map(|s| {
                    let mut chars = s.trim().chars();
                    match (chars.next().and_then(Axis::from_letter), chars.next()) {
                        (Some(a), None) if a.is_rotary() => Ok((a, Rule::Cyclic)),
                        _ => Err(Diagnostic::settings(format!(
                            "`{s}` in axes is not a rotary axis letter (A, B or C)"
                        ))),
                    }
                })
                .collect::<Result<Vec<_>, Diagnostic>>()?,
        };
        Ok(Box::new(UnwrapRotary::new(rules, options)?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// Above this size (degrees) a printed value loses precision as a 32-bit float: from
/// 2^13 on, one float step is 2^-10 deg (0.001 deg, 2.6 um at 150 mm from the axis), more
/// than the 4 decimals the machine presets print.
const FLOAT32_LIMIT: f64 = 8192.0;

/// How an axis is treated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rule {
    /// Any whole turn is the same position: take the one nearest the previous value.
    Cyclic,
    /// Limited to `[min, max]`: wrap into it by whole turns when outside.
    Limited(f64, f64),
}

/// The `unwrap-rotary` pass.
pub struct UnwrapRotary {
    rules: Vec<(Axis, Rule)>,
    options: Options,
    /// Unwrapped IR values after the last block.
    prev: Joints,
    /// The offsets the backend will print with (program = IR + offset).
    offsets: [f64; AXIS_COUNT],
    /// Offsets saved by G92.2.
    suspended: Option<[f64; AXIS_COUNT]>,
    warned_float32: bool,
}

impl UnwrapRotary {
    /// An `unwrap-rotary` pass treating each axis of `rules` as it says.
    pub fn new(rules: Vec<(Axis, Rule)>, options: Options) -> Result<UnwrapRotary, Diagnostic> {
        if !(options.rebase_above.is_finite() && options.rebase_above >= 180.0) {
            return Err(Diagnostic::settings(
                "rebase_above must be at least 180 degrees",
            ));
        }
        Ok(UnwrapRotary {
            rules,
            options,
            prev: Joints::default(),
            offsets: [0.0; AXIS_COUNT],
            suspended: None,
            warned_float32: false,
        })
    }

    /// The value `v` of `axis` takes under `rule`.
    fn unwrap(&self, axis: Axis, rule: Rule, v: f64) -> f64 {
        let prev = self.prev.get(axis);
        match rule {
            Rule::Cyclic => prev.map_or(v, |p| near_turn(v, p)),
            Rule::Limited(lo, hi) => {
                if (lo - LIMIT_SLACK..=hi + LIMIT_SLACK).contains(&v) {
                    return v;
                }
                // Out of range on every turn: `limits` reports it.
                turn_within(v, lo, hi, prev).unwrap_or(v)
            }
        }
    }

    /// Unwraps the axes of `j` (all, or those not in `skip`).
    fn unwrap_joints(&mut self, j: &mut Joints, skip: crate::ir::AxisSet) {
        for &(axis, rule) in &self.rules {
            if skip.contains(axis) {
                continue;
            }
            if let Some(v) = j.get(axis) {
                let u = self.unwrap(axis, rule, v);
                j.set(axis, u);
                self.prev.set(axis, u);
            }
        }
    }

    /// The G92 that re-bases the cyclic axes before a rapid to `target`, if one is due.
    /// `before` is the position the G92 is printed at.
    fn rebase(&mut self, before: &Joints, target: &Joints) -> Option<OffsetChange> {
        let mut declared = Joints::default();
        let mut offsets = self.offsets;
        for &(axis, rule) in &self.rules {
            if rule != Rule::Cyclic {
                continue;
            }
            let (Some(t), Some(cur)) = (target.get(axis), before.get(axis)) else {
                continue;
            };
            let i = axis.index();
            if (t + offsets[i]).abs() <= self.options.rebase_above {
                continue;
            }
            // Whole turns only, so the printed numbers shift by exact multiples of 360.
            let printed = cur + offsets[i];
            let turns = ((printed - wrap180(printed)) / 360.0).round();
            if turns == 0.0 {
                continue;
            }
            offsets[i] -= 360.0 * turns;
            declared.set(axis, cur + offsets[i]);
        }
        if declared.known.is_empty() {
            return None;
        }
        self.offsets = offsets;
        Some(OffsetChange {
            code: OffsetCode::Set,
            declared,
            offsets,
        })
    }

    /// Takes an upstream G92-family block into account and makes its offsets agree with
    /// the unwrapped values.
    fn offset(&mut self, change: &mut OffsetChange) {
        let ours = self.offsets;
        match change.code {
            OffsetCode::Set => {
                let mut next = change.offsets;
                for &(axis, _) in &self.rules {
                    let i = axis.index();
                    match (change.declared.get(axis), self.prev.get(axis)) {
                        (Some(d), Some(p)) => next[i] = d - p,
                        (Some(d), None) => self.prev.set(axis, d - next[i]),
                        (None, _) => next[i] = ours[i],
                    }
                }
                self.offsets = next;
            }
            OffsetCode::Clear => {
                self.offsets = change.offsets;
                self.suspended = None;
            }
            OffsetCode::Suspend => {
                self.suspended = Some(ours);
                self.offsets = change.offsets;
            }
            OffsetCode::Restore => {
                if let Some(s) = self.suspended.take() {
                    self.offsets = s;
                }
            }
        }
        change.offsets = self.offsets;
    }

    fn check_float32(&mut self, j: &Joints, span: Span, diags: &mut Vec<Diagnostic>) {
        if self.warned_float32 {
            return;
        }
        for &(axis, rule) in &self.rules {
            if rule != Rule::Cyclic {
                continue;
            }
            let Some(v) = j.get(axis) else { continue };
            let printed = v + self.offsets[axis.index()];
            if printed.abs() > FLOAT32_LIMIT {
                self.warned_float32 = true;
                let help = if self.options.rebase {
                    "re-basing happens at rapids only: add a rapid (a safe point) between the turns"
                } else {
                    "set `rebase = true` in the unwrap-rotary options to re-base the axis with G92 at rapids"
                };
                diags.push(
                    Diagnostic::warning(
                        "unwrap::float32",
                        format!(
                            "{} reaches {printed:.3} deg; RepRapFirmware keeps positions as 32-bit floats, which step by {:.5} deg there",
                            axis.letter(),
                            2f64.powi(printed.abs().log2().floor() as i32 - 23)
                        ),
                    )
                    .at_span(span)
                    .with_help(help),
                );
                return;
            }
        }
    }
}

impl Pass for UnwrapRotary {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        let edit = |pass: &mut Self, block: &mut Block, diags: &mut Vec<Diagnostic>| {
            // A rapid may need a G92 before it, which only `each` can add.
            let may_rebase = pass.options.rebase
                && matches!(&block.kind, BlockKind::Motion(m)
                    if matches!(m.kind, MotionKind::Rapid) && !m.machine_frame);
            if may_rebase {
                return false;
            }
            let rebase = pass.apply(block, diags);
            debug_assert!(rebase.is_none(), "only a rapid is re-based");
            true
        };
        let each = |pass: &mut Self, mut block: Block, out: &mut Output<'_>| {
            if let Some(change) = pass.apply(&mut block, out.diags) {
                out.push(Block::new(block.span, BlockKind::Offset(change)));
            }
            out.push(block);
        };
        super::edit_in_place(self, blocks, out, edit, each);
    }
}

impl UnwrapRotary {
    /// Unwraps `block` in place; returns the G92 re-basing that must go before it.
    fn apply(&mut self, block: &mut Block, diags: &mut Vec<Diagnostic>) -> Option<OffsetChange> {
        let mut rebase = None;
        match &mut block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(j) = &mut m.target else {
                    return None;
                };
                // A G53 move's written axes are machine coordinates, unknown afterwards.
                let skip = if m.machine_frame {
                    m.written
                } else {
                    crate::ir::AxisSet::EMPTY
                };
                let before = self.prev;
                self.unwrap_joints(j, skip);
                self.prev.forget(skip);
                // Re-basing happens at rapids, where the controller may jump the axis.
                if self.options.rebase && matches!(m.kind, MotionKind::Rapid) && !m.machine_frame {
                    rebase = self.rebase(&before, j);
                }
                self.check_float32(j, block.span, diags);
            }
            BlockKind::Offset(change) => self.offset(change),
            BlockKind::Command(c) => self.prev.forget(c.clobbers),
            BlockKind::Verbatim(v) => v.follow(&mut self.prev),
            _ => {}
        }
        rebase
    }
}
