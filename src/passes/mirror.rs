//! `mirror`: the solder-side mirror of seed 001: X becomes `shift - X` (or Y), by default shifted by the program's largest X so the board stays in positive X.
//!
//! The seed's HPGL2NC made the solder side of a single-sided board by turning the
//! drawing over about the Y axis ("X times -1") and shifting it by the largest X of the
//! unmirrored drawing, which it detected itself after the first version made the user
//! type it in. This pass does the same on any IR: every coordinate `a` of the chosen
//! axis becomes `shift - a`, so the drawing's extent `[min, max]` becomes
//! `[shift - max, shift - min]`; with the default shift (the largest value) the board
//! keeps its size, touches the same edge and stays in positive coordinates.
//!
//! # Options
//! - `axis` (`"x"` default, or `"y"`): the axis that changes sign.
//! - `shift` (mm, optional): the value the axis is mirrored to `shift - a`. Without it
//!   the pass uses the largest value the program reaches on the axis: the end points of
//!   every move (rapids included) and the extreme points of arcs that pass them.
//!
//! # Memory
//! Without `shift` the largest value is known only at the end of the program, so the
//! pass **buffers the whole program** (every block, a few hundred bytes each: a 100 000
//! line board is some tens of MB) and writes it out at the end. Give `shift` (for
//! example the board width from the CAD program, or the value the first run reports as
//! a note) to stream with constant memory.
//!
//! # Behaviour
//! - Arcs: the centre is mirrored too, and an arc whose plane contains the axis (G17 and
//!   G18 for X; G17 and G19 for Y) turns the other way (G2 and G3 swap); a G19 arc
//!   (G18 for Y) keeps its direction. Tool poses (CL input) mirror the tip and the tool
//!   axis.
//! - G92 offsets: the program-frame values a G92 declares are mirrored, and the offsets
//!   change sign, so printed coordinates (IR + offset) are mirrored as well.
//! - Machine-frame moves (G53), commands with coordinates (`G28 X..`, `G38.2 X..`) and
//!   text lines naming the axis cannot be mirrored here: they pass on unchanged with a
//!   warning.
//! - A note reports the shift used.

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, MotionKind, OffsetCode, Target};
use crate::motion::arc::ArcPath;

/// The axis `mirror` changes the sign of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MirrorAxis {
    /// X (the seed's solder side).
    #[default]
    X,
    /// Y.
    Y,
}

/// Options of `mirror`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// The mirrored axis.
    pub axis: MirrorAxis,
    /// `a` becomes `shift - a`; without it, the largest value of the program (buffered).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shift: Option<f64>,
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "mirror",
    summary: "mirror X (or Y) to shift - X, shifted by the program's largest X by default (seed's solder side)",
    build: |t, _ctx| Ok(Box::new(Mirror::new(super::options(t)?)?)),
    defaults: || super::to_toml(&Options::default()),
};

/// The `mirror` pass.
pub struct Mirror {
    axis: Axis,
    shift: Option<f64>,
    /// Blocks held until the end (no `shift` given).
    held: Vec<Block>,
    /// The largest value seen on the axis.
    max: f64,
    /// The IR position before the current block (for arc extents).
    track: crate::ir::Tracker,
    warned: bool,
}

impl Mirror {
    /// The pass with `options` (a given shift must be finite).
    pub fn new(options: Options) -> Result<Mirror, Diagnostic> {
        if options.shift.is_some_and(|s| !s.is_finite()) {
            return Err(Diagnostic::settings("shift must be a number"));
        }
        Ok(Mirror {
            axis: match options.axis {
                MirrorAxis::X => Axis::X,
                MirrorAxis::Y => Axis::Y,
            },
            shift: options.shift,
            held: Vec::new(),
            max: f64::NEG_INFINITY,
            track: crate::ir::Tracker::default(),
            warned: false,
        })
    }

    /// Raises `max` to the block's largest value on the axis.
    fn observe(&mut self, block: &Block) {
        let a = self.axis;
        if let BlockKind::Motion(m) = &block.kind
            && !m.machine_frame
        {
            let v = match &m.target {
                Target::Joints(j) => j.get(a),
                Target::Pose(p) => Some(p.tip[a.index()]),
            };
            if let Some(v) = v {
                self.max = self.max.max(v);
            }
            if let (MotionKind::Arc(arc), Target::Joints(to)) = (m.kind, &m.target)
                && let Some(path) = ArcPath::new(self.track.pos(), to, &arc)
            {
                // The angle (in the plane) where the axis is largest.
                let target = if path.u == a {
                    Some(0.0)
                } else if path.v == a {
                    Some(std::f64::consts::FRAC_PI_2)
                } else {
                    None
                };
                if let Some(t) = target {
                    let tau = std::f64::consts::TAU;
                    let from_start = if path.sweep >= 0.0 {
                        (t - path.start_angle).rem_euclid(tau)
                    } else {
                        (path.start_angle - t).rem_euclid(tau)
                    };
                    if from_start <= path.sweep.abs() {
                        let c = if path.u == a {
                            path.centre[0]
                        } else {
                            path.centre[1]
                        };
                        self.max = self.max.max(c + path.max_radius());
                    }
                }
            }
        }
        self.track.update(block);
    }

    /// Mirrors one block to `shift - a`.
    fn mirror(&mut self, mut block: Block, shift: f64, out: &mut Output<'_>) {
        let a = self.axis;
        let i = a.index();
        let letter = a.letter();
        let mut unmirrored = None;
        match &mut block.kind {
            BlockKind::Motion(m) if m.machine_frame && m.written.contains(a) => {
                unmirrored = Some("a machine-frame (G53) move");
            }
            BlockKind::Motion(m) if m.machine_frame => {}
            BlockKind::Motion(m) => {
                match &mut m.target {
                    Target::Joints(j) => {
                        if j.known.contains(a) {
                            j.values[i] = shift - j.values[i];
                        }
                    }
                    Target::Pose(p) => {
                        p.tip[i] = shift - p.tip[i];
                        let mut axis = p.axis.into_inner();
                        axis[i] = -axis[i];
                        p.axis = nalgebra::Unit::new_normalize(axis);
                        if let Some(extra) = p.extra_axes.as_deref_mut()
                            && extra.known.contains(a)
                        {
                            extra.values[i] = shift - extra.values[i];
                        }
                    }
                }
                if let MotionKind::Arc(arc) = &mut m.kind {
                    arc.center[i] = shift - arc.center[i];
                    let (u, v, _) = arc.plane.axes();
                    if u == a || v == a {
                        arc.clockwise = !arc.clockwise;
                    }
                }
            }
            BlockKind::Offset(o) => {
                if o.code == OffsetCode::Set && o.declared.known.contains(a) {
                    o.declared.values[i] = shift - o.declared.values[i];
                }
                o.offsets[i] = -o.offsets[i];
            }
            BlockKind::Command(c)
                if c.modes.is_some() && c.text.to_ascii_uppercase().contains(letter) =>
            {
                unmirrored = Some("a command with coordinates");
            }
            BlockKind::Verbatim(v) if v.text.to_ascii_uppercase().contains(letter) => {
                unmirrored = Some("a line passed through as text");
            }
            _ => {}
        }
        if let Some(what) = unmirrored
            && !self.warned
        {
            self.warned = true;
            out.diag(
                Diagnostic::warning(
                    "mirror::unmirrored",
                    format!("{what} names {letter} and is not mirrored (first of possibly several)"),
                )
                .at_span(block.span)
                .with_help("resolve it first (`normalize`, `expand-subprograms`) or check the result by hand"),
            );
        }
        out.push(block);
    }
}

impl Mirror {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        match self.shift {
            Some(s) => self.mirror(block, s, out),
            None => {
                self.observe(&block);
                self.held.push(block);
            }
        }
    }
}

impl Pass for Mirror {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        let shift = match self.shift {
            Some(s) => s,
            None if self.max.is_finite() => self.max,
            None => 0.0,
        };
        out.diag(Diagnostic::note(
            "mirror::shift",
            format!(
                "mirror: {l} became {shift} - {l} (shift {shift}{how})",
                l = self.axis.letter(),
                how = if self.shift.is_some() {
                    ", given"
                } else {
                    ", the program's largest value"
                }
            ),
        ));
        for b in std::mem::take(&mut self.held) {
            self.mirror(b, shift, out);
        }
    }
}
