//! `stats`: path lengths, time estimate, bounding box and block counts, reported at the end.

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, FeedMode, Joints, MotionKind, Target};

/// Options of `stats`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Speed assumed for rapids, mm/min.
    pub rapid_feed: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options { rapid_feed: 3000.0 }
    }
}

/// Totals collected by `stats`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Totals {
    /// Blocks seen.
    pub blocks: u64,
    /// Rapid, linear and arc moves.
    pub moves: [u64; 3],
    /// Rapid length, mm (XYZ).
    pub rapid_mm: f64,
    /// Feed (G1/G2/G3) length, mm (XYZ).
    pub feed_mm: f64,
    /// Estimated time, seconds (no acceleration).
    pub seconds: f64,
    /// Bounding box of XYZ targets: (min, max).
    pub bounds: Option<([f64; 3], [f64; 3])>,
    /// Blocks passed through as text.
    pub verbatim: u64,
    /// Comments.
    pub comments: u64,
}

/// The `stats` pass.
pub struct Stats {
    options: Options,
    last: Joints,
    /// What has been counted so far.
    pub totals: Totals,
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "stats",
    summary: "report path lengths, a time estimate, the bounding box and block counts",
    build: |t, _| Ok(Box::new(Stats::new(super::options(t)?))),
    defaults: || super::to_toml(&Options::default()),
};

impl Stats {
    /// A `stats` pass with `options`.
    pub fn new(options: Options) -> Self {
        Stats {
            options,
            last: Joints::default(),
            totals: Totals::default(),
        }
    }

    fn count(&mut self, block: &Block) {
        let t = &mut self.totals;
        t.blocks += 1;
        t.comments += block.comments.len() as u64;
        match &block.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(end) = &m.target else {
                    return;
                };
                let length = match m.kind {
                    MotionKind::Arc(arc) => arc_length(&self.last, end, &arc),
                    _ => xyz_distance(&self.last, end),
                };
                match m.kind {
                    MotionKind::Rapid => {
                        t.moves[0] += 1;
                        t.rapid_mm += length;
                        t.seconds += 60.0 * length / self.options.rapid_feed.max(1e-9);
                    }
                    _ => {
                        t.moves[if matches!(m.kind, MotionKind::Linear) {
                            1
                        } else {
                            2
                        }] += 1;
                        t.feed_mm += length;
                        t.seconds += match (m.feed.mode, m.feed.rate) {
                            (FeedMode::InverseTime, Some(f)) if f > 0.0 => 60.0 / f,
                            (FeedMode::PerMinute, Some(f)) if f > 0.0 => 60.0 * length / f,
                            _ => 0.0,
                        };
                    }
                }
                if end.known.contains(Axis::X)
                    && end.known.contains(Axis::Y)
                    && end.known.contains(Axis::Z)
                {
                    let p = [end.values[0], end.values[1], end.values[2]];
                    t.bounds = Some(match t.bounds {
                        None => (p, p),
                        Some((lo, hi)) => (
                            [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                            [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
                        ),
                    });
                }
                self.last = *end;
                if m.machine_frame {
                    self.last.forget(m.written);
                }
            }
            BlockKind::Verbatim(v) => {
                t.verbatim += 1;
                self.last.forget(v.clobbers);
            }
            BlockKind::Command(c) => self.last.forget(c.clobbers),
            _ => {}
        }
    }

    /// The report text.
    pub fn report(&self) -> String {
        let t = &self.totals;
        let mut s = format!(
            "stats: {} blocks; moves: {} rapid, {} linear, {} arc; {} comments; {} passed through as text\n\
             path: {:.3} mm feed, {:.3} mm rapid; estimated time {:.1} s (no acceleration)",
            t.blocks,
            t.moves[0],
            t.moves[1],
            t.moves[2],
            t.comments,
            t.verbatim,
            t.feed_mm,
            t.rapid_mm,
            t.seconds
        );
        if let Some((lo, hi)) = t.bounds {
            s.push_str(&format!(
                "\nbounds: X {:.3}..{:.3}, Y {:.3}..{:.3}, Z {:.3}..{:.3}",
                lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
            ));
        }
        s
    }
}

fn xyz_distance(a: &Joints, b: &Joints) -> f64 {
    let mut sum = 0.0;
    for ax in [Axis::X, Axis::Y, Axis::Z] {
        if let (Some(p), Some(q)) = (a.get(ax), b.get(ax)) {
            sum += (q - p).powi(2);
        }
    }
    sum.sqrt()
}

/// Length of a (helical) arc from `a` to `b`.
fn arc_length(a: &Joints, b: &Joints, arc: &crate::ir::Arc) -> f64 {
    let (u, v, n) = arc.plane.axes();
    let (Some(su), Some(sv), Some(eu), Some(ev)) = (a.get(u), a.get(v), b.get(u), b.get(v)) else {
        return xyz_distance(a, b);
    };
    let (cu, cv) = (arc.center[u.index()], arc.center[v.index()]);
    let r = (su - cu).hypot(sv - cv);
    let a0 = (sv - cv).atan2(su - cu);
    let a1 = (ev - cv).atan2(eu - cu);
    let mut sweep = if arc.clockwise { a0 - a1 } else { a1 - a0 };
    let tau = std::f64::consts::TAU;
    sweep = sweep.rem_euclid(tau);
    if sweep < 1e-12 {
        sweep = tau;
    }
    sweep += tau * arc.extra_turns as f64;
    let dn = match (a.get(n), b.get(n)) {
        (Some(p), Some(q)) => q - p,
        _ => 0.0,
    };
    (r * sweep).hypot(dn)
}

impl Pass for Stats {
    fn name(&self) -> &'static str {
        "stats"
    }

    fn run(&mut self, block: Block, out: &mut Output<'_>) {
        self.count(&block);
        out.push(block);
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        out.diag(Diagnostic::note("stats::report", self.report()));
    }
}
