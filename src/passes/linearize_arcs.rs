//! `linearize-arcs`: cut every G2/G3 arc (any plane, helical, full circles, `P` turns) into G1 chords within a tolerance.
//!
//! For controllers or passes that want straight moves only (a Grbl without arcs,
//! `heightmap`, which compensates straight moves). Each arc block becomes `n` G1 blocks
//! with the arc's span; the block's comments go on the last one.
//!
//! # Options
//! - `tolerance` (mm, default `0.002`): the largest distance of the arc from its chords
//!   (the sagitta). The chord count is the smallest `n` with
//!   `r (1 - cos(|sweep| / 2n)) <= tolerance` (`r` the larger of the start and end
//!   radii), each chord over at most half a turn; it is computed and then checked. When
//!   the source's end point is off the circle (a spiral, below) the bound also counts
//!   the chord error of the radius change ([`crate::motion::arc::ArcPath::sagitta`]),
//!   so the path stays within `tolerance` of its chords there too. The tolerance holds
//!   on the printed vertices: the backend rounds each linear coordinate by up to half a
//!   unit of its last decimal (0.0005 mm at 3 decimals), so the chords get what that
//!   rounding leaves (`tolerance - 0.5·10^-d·√2`, `√3` for a helix); a tolerance the
//!   printed decimals cannot hold is a settings error.
//! - `max_chords` (default `100000`, at most 10,000,000): the most chords one arc may
//!   become. An arc that needs more to stay within `tolerance` (a huge radius at a tiny
//!   tolerance, or thousands of `P` turns) is an error at its line, `linearize-arcs::chords`,
//!   and is passed on unchanged: the tolerance is never broken silently, and the chords
//!   of one arc, which the pass holds until the arc is done, stay within a bounded
//!   memory.
//!
//! # Geometry
//! The arc is the one [`crate::motion::arc`] defines and the frontend resolved: G17, G18
//! and G19; `I J K` or `R` (the frontend turns `R` into a centre, a negative `R` being
//! the arc of more than 180°); a full circle when the end point is the start; `P` adds
//! full turns. Chord end points are computed on the arc (`c + r (cos φ, sin φ)` at
//! equal angle steps) and the last is the block's target exactly. The normal axis
//! (helical motion), E and every other known axis move linearly in the angle, so E is
//! shared out by arc length. When the source's end point was off the circle (the
//! frontend warned `gcode::arc-radius`) the radius goes linearly from the start to the
//! end radius, as LinuxCNC moves.
//!
//! # Feed
//! A G94 (or G95) feed is unchanged: the chords are the path at the same speed. Under
//! G93 (inverse time) the block's time is shared equally by its equal chords: each
//! chord's F is the block's F times `n`.
//!
//! # Limits
//! An arc whose start is not known (not produced by the G-code frontend, which passes
//! such lines through as text) and arcs on tool poses are passed on unchanged with a
//! warning. An arc that needs more than `max_chords` chords is an error (see the
//! option).

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Block, BlockKind, FeedMode, MotionKind, Target, Tracker};
use crate::motion::arc::{ArcPath, MAX_CHORDS};

/// Options of `linearize-arcs`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Largest distance of the arc from its chords, mm.
    pub tolerance: f64,
    /// Most chords one arc may become.
    pub max_chords: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            tolerance: 0.002,
            max_chords: 100_000,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "linearize-arcs",
    summary: "cut G2/G3 arcs (all planes, R and IJK, helical, full circles) into G1 chords within a tolerance",
    build: |t, ctx| {
        let pass = LinearizeArcs::new(super::options(t)?)?;
        Ok(Box::new(pass.printed_with(ctx.decimals.map(|d| d.linear))?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// The `linearize-arcs` pass.
pub struct LinearizeArcs {
    options: Options,
    /// How far a printed vertex may lie from the computed one in each linear axis, mm
    /// (half a unit of the last printed decimal; 0 when nothing is printed).
    rounding: f64,
    /// The position after the last block (IR frame).
    track: Tracker,
}

impl LinearizeArcs {
    /// The pass with `options` (the tolerance must be a number > 0).
    pub fn new(options: Options) -> Result<LinearizeArcs, Diagnostic> {
        if !(options.tolerance.is_finite() && options.tolerance > 0.0) {
            return Err(Diagnostic::settings("tolerance must be a number > 0"));
        }
        if !(1..=MAX_CHORDS).contains(&options.max_chords) {
            return Err(Diagnostic::settings(format!(
                "max_chords must be from 1 to {MAX_CHORDS}"
            )));
        }
        Ok(LinearizeArcs {
            options,
            rounding: 0.0,
            track: Tracker::default(),
        })
    }

    /// The same pass for a backend that prints linear axes with `decimals`: the chords
    /// are cut so that the tolerance holds on the printed vertices, which the rounding
    /// moves by up to half a unit of the last decimal in each axis. An error when the
    /// tolerance is finer than the printed numbers can hold.
    pub fn printed_with(mut self, decimals: Option<u8>) -> Result<LinearizeArcs, Diagnostic> {
        let Some(d) = decimals else {
            return Ok(self);
        };
        self.rounding = 0.5 * 10f64.powi(-i32::from(d));
        // A planar arc's vertex moves in two axes; a helix's in three.
        if self.budget(true) <= 0.0 {
            return Err(Diagnostic::settings(format!(
                "linearize-arcs tolerance {} mm is finer than the printed coordinates ({d} \
                 decimals) can hold: raise the tolerance or print more decimals",
                self.options.tolerance
            )));
        }
        Ok(self)
    }

    /// The chords' own share of the tolerance: what the print rounding of their
    /// vertices leaves of it.
    fn budget(&self, helical: bool) -> f64 {
        let axes: f64 = if helical { 3.0 } else { 2.0 };
        self.options.tolerance - self.rounding * axes.sqrt()
    }
}

impl LinearizeArcs {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        let BlockKind::Motion(m) = &block.kind else {
            self.track.update(&block);
            out.push(block);
            return;
        };
        let MotionKind::Arc(arc) = m.kind else {
            self.track.update(&block);
            out.push(block);
            return;
        };
        let path = match &m.target {
            Target::Joints(to) if !m.machine_frame => ArcPath::new(self.track.pos(), to, &arc),
            _ => None,
        };
        let Some(path) = path else {
            out.diag(
                Diagnostic::warning(
                    "linearize-arcs::unknown-start",
                    "this arc is passed on as an arc: its start (or its target) is not a known position",
                )
                .at_span(block.span)
                .with_help("move to absolute positions in the arc's plane before the arc"),
            );
            self.track.update(&block);
            out.push(block);
            return;
        };
        let helical = path.from.get(path.n) != path.to.get(path.n);
        let budget = self.budget(helical);
        let n = path.chord_count(budget);
        // At the count's own cap the tolerance may not hold: then more were needed.
        let capped = n >= MAX_CHORDS && path.sagitta(n) > budget;
        if n > self.options.max_chords || capped {
            out.diag(self.too_many_chords(&block, n, capped));
            self.track.update(&block);
            out.push(block);
            return;
        }
        let mut feed = m.feed;
        if feed.mode == FeedMode::InverseTime {
            feed.rate = feed.rate.map(|f| f * n as f64);
        }
        let mut written = m.written;
        written.insert(path.u);
        written.insert(path.v);
        let Block {
            span,
            kind,
            comments,
        } = block;
        let BlockKind::Motion(m) = kind else {
            return;
        };
        let mut comments = Some(comments);
        for (k, p) in path.points(n).enumerate() {
            let mut piece = m.clone();
            piece.kind = MotionKind::Linear;
            piece.target = Target::Joints(p);
            piece.feed = feed;
            piece.written = written;
            let mut b = Block::new(span, BlockKind::Motion(piece));
            if k + 1 == n {
                b.comments = comments.take().unwrap_or_default();
            }
            out.push(b);
        }
        self.track.set_pos(path.to);
    }
}

impl LinearizeArcs {
    /// The error for an arc that needs `n` chords (more when `capped`), over `max_chords`.
    fn too_many_chords(&self, block: &Block, n: usize, capped: bool) -> Diagnostic {
        let needed = if capped {
            format!("more than {n}")
        } else {
            n.to_string()
        };
        Diagnostic::error(
            "linearize-arcs::chords",
            format!(
                "this arc needs {needed} chords to stay within the tolerance {} mm; linearize-arcs makes at most {} of one arc",
                self.options.tolerance, self.options.max_chords
            ),
        )
        .at_span(block.span)
        .with_help(format!(
            "program fewer turns (P) or a smaller arc; or raise the tolerance, or the cap \
             (`--pass linearize-arcs:max_chords=N`, at most {MAX_CHORDS})"
        ))
    }
}

impl Pass for LinearizeArcs {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }
}
