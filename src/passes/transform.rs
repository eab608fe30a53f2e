//! `transform`: scale, rotate about Z and translate the program in XY (arcs stay arcs), streaming.
//!
//! Places a drawing on the stock: every XY point `p` becomes
//!
//! ```text
//! p' = origin + R(rotate) · scale · (p - origin) + (dx, dy)
//! ```
//!
//! with `R` the counter-clockwise rotation about Z by `rotate` degrees. Z moves by
//! `dz` and is not scaled (cutting depths stay what the program says).
//!
//! # Options
//! Scalars, so they can be given on the command line
//! (`--pass transform:rotate=90,dx=50`):
//! - `dx`, `dy`, `dz` (mm, default `0`): the translation.
//! - `rotate` (degrees about Z, counter-clockwise seen from +Z, default `0`).
//! - `origin_x`, `origin_y` (mm, default `0`): the fixed point of rotation and scale.
//! - `scale` (default `1`, not 0): the same factor on X and Y. A negative factor is a
//!   half turn, not a mirror (use `mirror` for that).
//!
//! # Behaviour
//! - G17 arcs: the centre is transformed like a point; the radius scales by `|scale|`;
//!   the direction is kept. G18/G19 arcs are exact only when neither rotation nor
//!   scaling touches their plane: under a rotation other than a multiple of 360° or a
//!   scale other than 1 they are an error (`transform::arc-plane`: put
//!   `linearize-arcs` first); a pure translation moves them.
//! - Tool poses (CL input) rotate their tool axis with the tip.
//! - A rotation needs both X and Y of a target: a move whose X or Y is unknown (before
//!   the first XY move) is an error when the rotation is not a multiple of 360°.
//! - G92 offsets rotate and scale with the points (printed = IR + offset stays the
//!   transformed program position); a G92 that declares only one of X and Y under a
//!   rotation is an error.
//! - Machine-frame moves (G53) and commands with coordinates (`G28 X..`) pass on
//!   unchanged with a warning.
//!
//! # Memory
//! None beyond the block at hand.

use nalgebra::{Matrix2, Vector2};
use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, Joints, MotionKind, OffsetCode, Plane, Target};

/// Options of `transform`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Translation in X, mm, applied last.
    pub dx: f64,
    /// Translation in Y, mm.
    pub dy: f64,
    /// Translation in Z, mm.
    pub dz: f64,
    /// Rotation about Z, degrees, counter-clockwise.
    pub rotate: f64,
    /// X of the fixed point of rotation and scale, mm.
    pub origin_x: f64,
    /// Y of the fixed point of rotation and scale, mm.
    pub origin_y: f64,
    /// Uniform XY scale factor.
    pub scale: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            dx: 0.0,
            dy: 0.0,
            dz: 0.0,
            rotate: 0.0,
            origin_x: 0.0,
            origin_y: 0.0,
            scale: 1.0,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "transform",
    summary: "scale (uniform), rotate about Z and translate XY(Z); arcs stay arcs",
    build: |t, _ctx| Ok(Box::new(Transform::new(super::options(t)?)?)),
    defaults: || super::to_toml(&Options::default()),
};

/// The `transform` pass.
pub struct Transform {
    /// `scale · R`.
    m: Matrix2<f64>,
    origin: Vector2<f64>,
    translate: [f64; 3],
    /// Rotation or scale present (XY must be known together).
    linear: bool,
    /// Only the rotation (for tool axes).
    rot: Matrix2<f64>,
    warned: bool,
}

impl Transform {
    /// The pass with `options` (finite numbers, scale not 0).
    pub fn new(o: Options) -> Result<Transform, Diagnostic> {
        let finite = [o.dx, o.dy, o.dz, o.rotate, o.origin_x, o.origin_y, o.scale]
            .iter()
            .all(|v| v.is_finite());
        if !finite {
            return Err(Diagnostic::settings(
                "dx, dy, dz, rotate, origin_x, origin_y and scale must be numbers",
            ));
        }
        if o.scale == 0.0 {
            return Err(Diagnostic::settings("scale must not be 0"));
        }
        // Exact values for quarter turns, so 90° maps grid points onto grid points.
        let turns = o.rotate.rem_euclid(360.0);
        let (s, c) = match turns {
            0.0 => (0.0, 1.0),
            90.0 => (1.0, 0.0),
            180.0 => (0.0, -1.0),
            270.0 => (-1.0, 0.0),
            _ => o.rotate.to_radians().sin_cos(),
        };
        let rot = Matrix2::new(c, -s, s, c);
        Ok(Transform {
            m: rot * o.scale,
            origin: Vector2::new(o.origin_x, o.origin_y),
            translate: [o.dx, o.dy, o.dz],
            linear: turns != 0.0 || o.scale != 1.0,
            rot,
            warned: false,
        })
    }

    fn point(&self, p: Vector2<f64>) -> Vector2<f64> {
        self.origin
            + self.m * (p - self.origin)
            + Vector2::new(self.translate[0], self.translate[1])
    }

    /// Transforms the XY(Z) of `j` in place; `Err` when a rotation needs an unknown axis.
    fn joints(&self, j: &mut Joints) -> Result<(), &'static str> {
        let (x, y) = (j.get(Axis::X), j.get(Axis::Y));
        match (x, y) {
            (Some(x), Some(y)) => {
                let p = self.point(Vector2::new(x, y));
                j.values[0] = p.x;
                j.values[1] = p.y;
            }
            (None, None) => {}
            _ if self.linear => {
                return Err("X or Y of this move is not known, so it cannot be rotated or scaled");
            }
            (Some(x), None) => j.values[0] = x + self.translate[0],
            (None, Some(y)) => j.values[1] = y + self.translate[1],
        }
        if j.known.contains(Axis::Z) {
            j.values[2] += self.translate[2];
        }
        Ok(())
    }

    fn error(
        &self,
        block: &Block,
        code: &'static str,
        msg: &str,
        help: &str,
        out: &mut Output<'_>,
    ) {
        out.diag(
            Diagnostic::error(code, msg.to_string())
                .at_span(block.span)
                .with_help(help.to_string()),
        );
    }
}

impl Transform {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, mut block: Block, out: &mut Output<'_>) {
        let mut problem: Option<(&'static str, &'static str, &'static str)> = None;
        let mut unchanged = false;
        match &mut block.kind {
            BlockKind::Motion(m) if m.machine_frame => unchanged = true,
            BlockKind::Motion(m) => {
                if let MotionKind::Arc(arc) = &mut m.kind {
                    if arc.plane != Plane::XY && self.linear {
                        problem = Some((
                            "transform::arc-plane",
                            "a G18/G19 arc cannot be rotated about Z or scaled and stay an arc",
                            "put `linearize-arcs` before `transform`",
                        ));
                    } else {
                        let c = self.point(Vector2::new(arc.center[0], arc.center[1]));
                        arc.center[0] = c.x;
                        arc.center[1] = c.y;
                        arc.center[2] += self.translate[2];
                    }
                }
                let r = match &mut m.target {
                    Target::Joints(j) => self.joints(j),
                    Target::Pose(p) => {
                        let q = self.point(Vector2::new(p.tip.x, p.tip.y));
                        p.tip.x = q.x;
                        p.tip.y = q.y;
                        p.tip.z += self.translate[2];
                        let a = p.axis.into_inner();
                        let r = self.rot * Vector2::new(a.x, a.y);
                        p.axis =
                            nalgebra::Unit::new_normalize(nalgebra::Vector3::new(r.x, r.y, a.z));
                        Ok(())
                    }
                };
                if let Err(msg) = r {
                    problem = Some((
                        "transform::unknown-axis",
                        msg,
                        "move to an absolute X and Y position first",
                    ));
                }
            }
            BlockKind::Offset(o) => {
                // printed = IR + offset: the offset is a displacement.
                let d = self.m * Vector2::new(o.offsets[0], o.offsets[1]);
                o.offsets[0] = d.x;
                o.offsets[1] = d.y;
                if o.code == OffsetCode::Set {
                    let r = self.joints(&mut o.declared);
                    if r.is_err() {
                        problem = Some((
                            "transform::g92",
                            "a G92 that declares only one of X and Y cannot be rotated or scaled",
                            "declare X and Y together, or put `normalize` before `transform`",
                        ));
                    }
                }
            }
            BlockKind::Command(c) => {
                unchanged =
                    c.modes.is_some() && c.text.to_ascii_uppercase().contains(['X', 'Y', 'Z']);
            }
            BlockKind::Verbatim(v) => {
                unchanged = v.text.to_ascii_uppercase().contains(['X', 'Y', 'Z']);
            }
            _ => {}
        }
        if let Some((code, msg, help)) = problem {
            self.error(&block, code, msg, help, out);
        }
        if unchanged && !self.warned {
            self.warned = true;
            out.diag(
                Diagnostic::warning(
                    "transform::untransformed",
                    "this line has coordinates the pass cannot transform; it passes on unchanged (first of possibly several)",
                )
                .at_span(block.span)
                .with_help("resolve it first (`normalize`, `expand-subprograms`) or check the result by hand"),
            );
        }
        out.push(block);
    }
}

impl Pass for Transform {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }
}
