//! `limits`: every emitted joint value within the machine's travel and rotary limits, or an error.
//!
//! Each joint move's known axes that have limits ([`Machine::limits`]: the linear travel
//! and the non-cyclic rotaries) are checked, in the IR frame (invariant 2: the frame the
//! machine moves in, without G92 offsets). A value outside the range by more than
//! `tolerance` is the error `limits::range`, one per axis and block, carrying its excess;
//! the run's repeat cap (`--max-repeats`) shows the first few and sums up the rest with
//! the count, the lines and the worst excess, so a part set up 3 mm too low gives a few
//! messages instead of one per block. With `max_reported` > 0 the pass itself reports
//! only that many blocks per axis and side and then one summary per axis and side. G53 moves name machine coordinates,
//! whose range the machine definition does not give; their written axes are not
//! checked.

use serde::{Deserialize, Serialize};

use super::{Check, PassInfo};
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
    /// Blocks reported one by one per axis and side (below the minimum, above the
    /// maximum); the rest are summed up in one error at the end. 0 reports every block.
    pub max_reported: u64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            tolerance: 1e-6,
            // The run's repeat cap (`--max-repeats`) sums up the rest, naming the worst.
            max_reported: 0,
        }
    }
}

/// The blocks past one side of one axis' range.
#[derive(Debug, Clone, Copy)]
struct Overrun {
    axis: Axis,
    /// Above the maximum (else below the minimum).
    high: bool,
    limit: f64,
    count: u64,
    first_line: u32,
    last_line: u32,
    /// The largest excess and where.
    worst: f64,
    worst_span: crate::ir::Span,
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "limits",
    summary: "check every joint value against the machine's linear travel and rotary limits",
    build: |t, ctx| {
        let machine = ctx.require_machine("limits")?;
        Ok(Box::new(super::Lint(Limits::new(
            machine,
            super::options(t)?,
        )?)))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// The `limits` pass.
pub struct Limits {
    /// `(axis, min, max)` of every limited axis.
    ranges: Vec<(Axis, f64, f64)>,
    options: Options,
    overruns: Vec<Overrun>,
}

impl Limits {
    /// A `limits` pass for `machine`.
    pub fn new(machine: &Machine, options: Options) -> Result<Limits, Diagnostic> {
        if !(options.tolerance.is_finite() && options.tolerance >= 0.0) {
            return Err(Diagnostic::settings("tolerance must be a number >= 0"));
        }
        let ranges = Axis::ALL
            .into_iter()
            .filter_map(|a| machine.limits(a).map(|(lo, hi)| (a, lo, hi)))
            .collect();
        Ok(Limits {
            ranges,
            options,
            overruns: Vec::new(),
        })
    }

    /// Checks one block's joints against the ranges: an error for each known value
    /// outside its range (but for axes a G53 move writes in machine coordinates), the
    /// overruns counted.
    fn block(&mut self, block: &Block, diags: &mut Vec<Diagnostic>) {
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
                let high = v > hi;
                let line = block.span.line;
                let k = match self
                    .overruns
                    .iter()
                    .position(|o| o.axis == axis && o.high == high)
                {
                    Some(k) => k,
                    None => {
                        self.overruns.push(Overrun {
                            axis,
                            high,
                            limit: if high { hi } else { lo },
                            count: 0,
                            first_line: line,
                            last_line: line,
                            worst: 0.0,
                            worst_span: block.span,
                        });
                        self.overruns.len() - 1
                    }
                };
                let o = &mut self.overruns[k];
                o.count += 1;
                o.last_line = line;
                if side > o.worst {
                    o.worst = side;
                    o.worst_span = block.span;
                }
                let cap = self.options.max_reported;
                if cap > 0 && o.count > cap {
                    continue;
                }
                diags.push(
                    Diagnostic::error(
                        "limits::range",
                        format!(
                            "{} = {v:.4} {unit} is outside the machine's range {lo}..{hi} {unit} (by {side:.4})",
                            axis.letter()
                        ),
                    )
                    .at_span(block.span)
                    .with_help(help)
                    // The excess, for naming the worst of many.
                    .with_magnitude(side),
                );
            }
        }
    }
}

impl Check for Limits {
    fn check(&mut self, blocks: &[Block], diags: &mut Vec<Diagnostic>) {
        for block in blocks {
            self.block(block, diags);
        }
    }

    fn finish(&mut self, diags: &mut Vec<Diagnostic>) {
        let cap = self.options.max_reported;
        for o in &self.overruns {
            if cap == 0 || o.count <= cap {
                continue;
            }
            let unit = if o.axis.is_rotary() { "deg" } else { "mm" };
            let (side, word) = if o.high {
                ("above", "maximum")
            } else {
                ("below", "minimum")
            };
            diags.push(
                Diagnostic::error(
                    "limits::range",
                    format!(
                        "{} went {side} its {word} {} {unit} on {} blocks in all (lines {}..{}), \
                         by {:.4} {unit} at worst (here); the first {cap} are reported above",
                        o.axis.letter(),
                        o.limit,
                        o.count,
                        o.first_line,
                        o.last_line,
                        o.worst
                    ),
                )
                .at_span(o.worst_span)
                .with_help(
                    "move the part or the work origin by at least the worst excess, or set \
                     limits:max_reported=0 to see every block",
                ),
            );
        }
    }
}
