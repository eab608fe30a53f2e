//! `limits`: every emitted joint value within the machine's travel and rotary limits, or an error.
//!
//! Each joint move's known axes that have limits ([`Machine::limits`]: the linear travel
//! and the non-cyclic rotaries) are checked, in the IR frame (invariant 2: the frame the
//! machine moves in, without G92 offsets). A value outside the range by more than
//! `tolerance` is the error `limits::range`, one per axis and block. G53 moves name
//! machine coordinates, whose range the machine definition does not give; their written
//! axes are not checked.

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, Target};
use crate::machine::Machine;

/// Options of `limits`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// How far (mm or degrees) a value may lie outside its range before it is an error,
    /// for rounding at the limits.
    pub tolerance: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options { tolerance: 1e-6 }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "limits",
    summary: "check every joint value against the machine's linear travel and rotary limits",
    build: |t, ctx| {
        let machine = ctx.require_machine("limits")?;
        Ok(Box::new(Limits::new(machine, super::options(t)?)?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// The `limits` pass.
pub struct Limits {
    /// `(axis, min, max)` of every limited axis.
    ranges: Vec<(Axis, f64, f64)>,
    options: Options,
}

impl Limits {
    /// A `limits` pass for `machine`.
    pub fn new(machine: &Machine, options: Options) -> Result<Limits, String> {
        if !(options.tolerance.is_finite() && options.tolerance >= 0.0) {
            return Err("tolerance must be a number >= 0".into());
        }
        let ranges = Axis::ALL
            .into_iter()
            .filter_map(|a| machine.limits(a).map(|(lo, hi)| (a, lo, hi)))
            .collect();
        Ok(Limits { ranges, options })
    }
}

impl Pass for Limits {
    fn name(&self) -> &'static str {
        "limits"
    }

    fn run(&mut self, block: Block, out: &mut Output<'_>) {
        if let BlockKind::Motion(m) = &block.kind
            && let Target::Joints(j) = &m.target
        {
            let tol = self.options.tolerance;
            for &(axis, lo, hi) in &self.ranges {
                if m.machine_frame && m.written.contains(axis) {
                    continue;
                }
                let Some(v) = j.get(axis) else { continue };
                if v >= lo - tol && v <= hi + tol {
                    continue;
                }
                let (unit, help) = if axis.is_rotary() {
                    (
                        "deg",
                        "the rotary would have to turn past its limit here; tilt the tool axis less in the CAM or fixture the part differently",
                    )
                } else {
                    (
                        "mm",
                        "the move is beyond the axis travel; move the part or the work origin (the CL frame is the machine's at zero rotaries), or shorten the tool",
                    )
                };
                let side = if v < lo { lo - v } else { v - hi };
                out.diag(
                    Diagnostic::error(
                        "limits::range",
                        format!(
                            "{} = {v:.4} {unit} is outside the machine's range {lo}..{hi} {unit} (by {side:.4})",
                            axis.letter()
                        ),
                    )
                    .at_span(block.span)
                    .with_help(help),
                );
            }
        }
        out.push(block);
    }
}
