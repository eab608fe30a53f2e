//! The statements that move the tool or set its axis: `GOTO`, `FROM`, `GODLTA` and the
//! further points after a `GOTO`, `CIRCLE`/`MOVARC`, `TLAXIS`, `MULTAX`, `CSYS`.

use nalgebra::{Point3, Unit, Vector3};

use super::{Args, Lowerer};
use crate::diag::Diagnostic;
use crate::front::cl::arc;
use crate::front::cl::ast::ArgKind;
use crate::front::cl::motion::{Circle, motion_block, unit};
use crate::front::cl::source::Statement;
use crate::ir::{Block, MotionKind};

/// How a point statement moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Point {
    /// `GOTO`: to the point.
    Absolute,
    /// `FROM`: the start point, at rapid.
    Start,
    /// `GODLTA`: by the offset.
    Delta,
}

fn unused_circle(stmt: &Statement, major: &str) -> Diagnostic {
    stmt.locate_all(Diagnostic::warning(
        "cl::circle-without-end",
        format!("no GOTO ends this {major}; it was ignored"),
    ))
    .with_label("no end point")
    .with_help(format!(
        "an arc ends at the point of the GOTO right after its {major}"
    ))
}

impl Lowerer {
    /// `GOTO`, `FROM`, `GODLTA` and a further point after a `GOTO`: a move to the point,
    /// the end of a pending arc, or a hole of the drilling cycle in force.
    pub(super) fn goto(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        what: Point,
        major: &str,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        match what {
            Point::Delta => a.arity(major, &[1, 3, 6], "dx,dy,dz[,i,j,k] or d")?,
            _ => a.arity(major, &[3, 6], "x,y,z[,i,j,k]")?,
        }
        let mut v = [0.0; 6];
        for (slot, x) in v.iter_mut().zip(a.list) {
            *slot = a.number(x)?;
        }
        let start_axis = self.axis;
        let axis = if a.list.len() == 6 {
            self.point_axis(a, &v, major, diags)?
        } else {
            self.axis
        };
        let tip = if what == Point::Delta {
            let Some(pos) = self.pos else {
                return Err(a.error_all(
                    Diagnostic::error(
                        "cl::no-start",
                        "GODLTA moves relative to the current point, which is not known yet",
                    )
                    .with_help("give an absolute point first (FROM/x,y,z or GOTO/x,y,z)"),
                ));
            };
            if a.list.len() == 1 {
                pos + axis.into_inner() * (v[0] * self.scale)
            } else {
                pos + self.dir_to_part(Vector3::new(v[0], v[1], v[2]) * self.scale)
            }
        } else {
            self.to_part(Point3::new(v[0], v[1], v[2]) * self.scale)
        };
        if !tip.iter().all(|c| c.is_finite()) {
            return Err(a.error_all(
                Diagnostic::error("cl::bad-number", "the point is out of range")
                    .with_help("CL values must be finite numbers"),
            ));
        }
        self.axis = axis;
        let rapid = std::mem::replace(&mut self.rapid_next, false);
        let kind = if rapid || what == Point::Start {
            MotionKind::Rapid
        } else {
            MotionKind::Linear
        };
        self.move_to(stmt, what, tip, (start_axis, axis), kind, out, diags);
        Ok(())
    }

    /// The tool axis `i,j,k` of a point statement (values 3 to 5 of `v`), with the one
    /// warning when `MULTAX/OFF` is in force.
    fn point_axis(
        &mut self,
        a: &Args<'_>,
        v: &[f64; 6],
        major: &str,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<Unit<Vector3<f64>>, Diagnostic> {
        let (s, e) = (a.list[3].start, a.list[5].end);
        let axis = unit(self.dir_to_part(Vector3::new(v[3], v[4], v[5]))).ok_or_else(|| {
            a.stmt.locate(
                Diagnostic::error("cl::zero-axis", "the tool axis i,j,k is a zero vector")
                    .with_label("zero vector")
                    .with_help("give a tool axis with a non-zero length, e.g. 0,0,1"),
                s,
                e,
            )
        })?;
        if self.multax == Some(false) && !self.warned_multax {
            self.warned_multax = true;
            diags.push(
                a.stmt
                    .locate(
                        Diagnostic::warning(
                            "cl::multax-off",
                            format!("{major} gives a tool axis under MULTAX/OFF"),
                        ),
                        s,
                        e,
                    )
                    .with_label("tool axis")
                    .with_help("the tool axis is used; write MULTAX/ON before 5-axis motion"),
            );
        }
        Ok(axis)
    }

    /// Moves to `tip`, the tool axis turning from `axes.0` to `axes.1`: the holes of the
    /// drilling cycle in force, the pieces of a pending arc, or one straight move.
    #[allow(clippy::too_many_arguments)]
    fn move_to(
        &mut self,
        stmt: &Statement,
        what: Point,
        tip: Point3<f64>,
        (start_axis, axis): (Unit<Vector3<f64>>, Unit<Vector3<f64>>),
        kind: MotionKind,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let circle = self.circle.take();
        if what == Point::Start {
            if let Some(c) = circle {
                diags.push(c.unused);
            }
        } else if what == Point::Absolute
            && let Some(cy) = self.cycle.active()
        {
            if let Some(c) = circle {
                diags.push(c.unused);
            }
            let cy = cy.clone();
            self.pos = Some(cy.expand(
                stmt,
                tip,
                axis,
                self.pos,
                self.feed,
                &self.options,
                out,
                diags,
            ));
            return;
        } else if let Some(c) = circle
            && let Some(start) = self.pos
        {
            match arc::Run::new(
                &c,
                start,
                tip,
                start_axis,
                axis,
                kind,
                self.feed,
                stmt,
                &self.options,
                diags,
            ) {
                Ok(run) => {
                    self.arc = Some(run);
                    self.pos = Some(tip);
                    return;
                }
                Err(d) => diags.push(d),
            }
        }
        out.push(motion_block(stmt.span, kind, tip, axis, self.feed));
        self.pos = Some(tip);
    }

    /// `CIRCLE`/`MOVARC`: the arc that the next `GOTO` ends.
    pub(super) fn circle(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        major: &str,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let mut w = circle_words(a, major)?;
        let left_handed = circle_form(&mut w, a, major)?;
        let Written {
            centre,
            normal,
            radius,
            radius_at,
            turns,
            angle,
            ..
        } = w;
        let (Some(c), Some((nv, ns, ne))) = (centre, normal) else {
            return Ok(());
        };
        let mut normal = unit(self.dir_to_part(nv)).ok_or_else(|| {
            stmt.locate(
                Diagnostic::error(
                    "cl::zero-axis",
                    format!("the {major} axis i,j,k is a zero vector"),
                )
                .with_label("zero vector")
                .with_help("give the circle's axis, e.g. 0,0,1 for counter-clockwise in XY"),
                ns,
                ne.max(ns + 1),
            )
        })?;
        if left_handed {
            normal = -normal;
        }
        if let Some(r) = radius
            && r <= 0.0
        {
            return Err(stmt.locate(
                Diagnostic::error(
                    "cl::bad-value",
                    format!("the {major} radius is not positive"),
                )
                .with_label("radius")
                .with_help("give the radius as a positive length"),
                radius_at.0,
                radius_at.1,
            ));
        }
        let centre = self.to_part(Point3::from(c * self.scale));
        let radius = radius.map(|r| r * self.scale);
        if !centre.iter().all(|v| v.is_finite()) || radius.is_some_and(|r| !r.is_finite()) {
            return Err(a.error_all(Diagnostic::error(
                "cl::bad-number",
                format!("the {major} centre or radius is out of range"),
            )));
        }
        if self.pos.is_none() {
            return Err(a.error_all(
                Diagnostic::error(
                    "cl::no-start",
                    format!("{major} starts at the current point, which is not known yet"),
                )
                .with_help("give a point first (FROM/x,y,z or GOTO/x,y,z)"),
            ));
        }
        if let Some(old) = self.circle.take() {
            diags.push(old.unused);
        }
        self.circle = Some(Circle {
            centre,
            normal,
            radius,
            turns,
            angle,
            line: stmt.span.line,
            unused: unused_circle(stmt, major),
        });
        Ok(())
    }

    pub(super) fn tlaxis(&mut self, a: &Args<'_>) -> Result<(), Diagnostic> {
        if a.list.iter().any(|x| x.kind != ArgKind::Number) {
            return Err(a.error_all(
                Diagnostic::warning(
                    "cl::unsupported",
                    "only TLAXIS/i,j,k is understood; the tool axis is unchanged",
                )
                .with_help("passed through as a comment"),
            ));
        }
        a.arity("TLAXIS", &[3], "i,j,k")?;
        let v = a.numbers()?;
        self.axis = unit(self.dir_to_part(Vector3::new(v[0], v[1], v[2]))).ok_or_else(|| {
            a.error_all(
                Diagnostic::error("cl::zero-axis", "the tool axis i,j,k is a zero vector")
                    .with_label("zero vector")
                    .with_help("give a tool axis with a non-zero length, e.g. 0,0,1"),
            )
        })?;
        Ok(())
    }

    pub(super) fn multax(&mut self, a: &Args<'_>) -> Result<(), Diagnostic> {
        self.multax = match a.list {
            [] => Some(true),
            [x] => match a.word(x).as_deref() {
                Some("ON") => Some(true),
                Some("OFF") => Some(false),
                _ => {
                    return Err(a.error_all(
                        Diagnostic::error("cl::bad-value", "MULTAX takes ON or OFF")
                            .with_label("here")
                            .with_help("write MULTAX/ON or MULTAX/OFF"),
                    ));
                }
            },
            _ => {
                return Err(a.error_all(
                    Diagnostic::error("cl::arity", "MULTAX takes ON or OFF")
                        .with_label("here")
                        .with_help("write MULTAX/ON or MULTAX/OFF"),
                ));
            }
        };
        Ok(())
    }

    /// A CSYS matrix (three rows of rotation and translation) passes through; its Z
    /// column becomes the tool axis (APT++ writes 3-value GOTOs only under a CSYS whose
    /// Z column is +Z, and 6-value ones with the Z column as their axis otherwise). A
    /// CSYS that is not the identity gets a warning: it is not applied to the points; one
    /// that rotates gets a note for the passes on its block (the last in `out`).
    pub(super) fn csys(&mut self, a: &Args<'_>, out: &mut [Block], diags: &mut Vec<Diagnostic>) {
        let Ok(v) = a.numbers() else {
            return;
        };
        let identity = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        if v.len() == 12
            && let Some(z) = unit(Vector3::new(v[2], v[6], v[10]))
        {
            self.axis = z;
        }
        if v.len() == 12 && v.iter().zip(identity).all(|(a, b)| (a - b).abs() < 1e-9) {
            return;
        }
        let rotation = [0, 1, 2, 4, 5, 6, 8, 9, 10];
        if v.len() != 12 || rotation.iter().any(|&i| (v[i] - identity[i]).abs() > 1e-6) {
            Self::note_frame(out);
        }
        diags.push(
            a.error_all(
                Diagnostic::warning(
                    "cl::csys-not-applied",
                    "the CSYS transform is not applied: the points that follow are used as \
                 written, in the part frame",
                )
                .with_label("not applied"),
            )
            .with_help(
                "CAM systems that write CSYS give GOTO points and tool axes in the base frame \
                 already (the tool axes match the CSYS Z column); CSYS only names the working \
                 plane",
            ),
        );
    }
}

/// What a `CIRCLE` or `MOVARC` writes: its plain numbers and its keyword values.
#[derive(Debug, Default)]
struct Written {
    plain: Vec<f64>,
    centre: Option<Vector3<f64>>,
    /// The axis and the byte range it is written in.
    normal: Option<(Vector3<f64>, usize, usize)>,
    radius: Option<f64>,
    radius_at: (usize, usize),
    turns: Option<u32>,
    angle: Option<f64>,
}

/// Reads the arguments of a `CIRCLE` or `MOVARC`: plain numbers, and the values after
/// `TIMES`, `ANGLE`, `RADIUS`, `CENTER` and `AXIS`.
fn circle_words(a: &Args<'_>, major: &str) -> Result<Written, Diagnostic> {
    let mut w = Written {
        plain: Vec::with_capacity(11),
        ..Written::default()
    };
    let mut i = 0;
    let take = |i: &mut usize, n: usize| -> Result<Vec<f64>, Diagnostic> {
        let kw = &a.list[*i];
        let mut v = Vec::with_capacity(n);
        for k in 1..=n {
            match a.list.get(*i + k) {
                Some(x) => v.push(a.number(x)?),
                None => {
                    return Err(a.stmt.locate(
                        Diagnostic::error(
                            "cl::arity",
                            format!(
                                "`{}` needs {n} value{}",
                                a.text(kw),
                                if n == 1 { "" } else { "s" }
                            ),
                        )
                        .with_label("values missing"),
                        kw.start,
                        kw.end,
                    ));
                }
            }
        }
        *i += n;
        Ok(v)
    };
    while i < a.list.len() {
        let x = &a.list[i];
        if x.kind == ArgKind::Number {
            w.plain.push(a.number(x)?);
        } else {
            match a.text(x).to_ascii_uppercase().as_str() {
                "TIMES" => {
                    let v = take(&mut i, 1)?[0];
                    if !(v >= 0.0 && v.fract() == 0.0 && v <= 10_000.0) {
                        return Err(a.stmt.locate(
                            Diagnostic::error(
                                "cl::bad-value",
                                "TIMES takes a whole number of turns from 0 to 10000",
                            )
                            .with_label("here"),
                            x.start,
                            a.list[i].end,
                        ));
                    }
                    w.turns = Some(v as u32);
                }
                "ANGLE" => w.angle = Some(take(&mut i, 1)?[0]),
                "RADIUS" => {
                    w.radius = Some(take(&mut i, 1)?[0]);
                    w.radius_at = (a.list[i].start, a.list[i].end);
                }
                "CENTER" | "CENTRE" => {
                    let v = take(&mut i, 3)?;
                    w.centre = Some(Vector3::new(v[0], v[1], v[2]));
                }
                "AXIS" => {
                    let v = take(&mut i, 3)?;
                    w.normal = Some((Vector3::new(v[0], v[1], v[2]), x.start, a.list[i].end));
                }
                _ => {
                    return Err(a.stmt.locate(
                        Diagnostic::error(
                            "cl::bad-number",
                            format!(
                                "expected a number, found `{}`",
                                crate::num::range::shown(a.text(x))
                            ),
                        )
                        .with_label("not a number")
                        .with_help(format!(
                            "{major} takes the centre, the axis and the radius: \
                             {major}/x,y,z,i,j,k,r"
                        )),
                        x.start,
                        x.end,
                    ));
                }
            }
        }
        i += 1;
    }
    Ok(w)
}

/// Completes `w` from its plain numbers when no keyword gave the centre and axis: 6 values
/// (centre, axis; radius from the start point), 7 (APT), 8 to 11 (NX: tolerance, ratio,
/// tool diameter and corner radius follow). Returns whether the axis is clockwise (NX).
fn circle_form(w: &mut Written, a: &Args<'_>, major: &str) -> Result<bool, Diagnostic> {
    let keyword_form = w.centre.is_some() || w.normal.is_some();
    let mut left_handed = false;
    if keyword_form {
        if !w.plain.is_empty() || w.centre.is_none() || w.normal.is_none() {
            return Err(a.error_all(
                Diagnostic::error(
                    "cl::arity",
                    format!("{major} with keywords takes CENTER,x,y,z,AXIS,i,j,k[,RADIUS,r]"),
                )
                .with_label("here"),
            ));
        }
    } else {
        let n = w.plain.len();
        if !(6..=11).contains(&n) {
            return Err(a.error_all(
                Diagnostic::error(
                    "cl::arity",
                    format!("{major} takes 6, 7 or 11 values, found {n}"),
                )
                .with_label("here")
                .with_help(format!(
                    "write {major}/x,y,z,i,j,k,r (centre, axis, radius)"
                )),
            ));
        }
        // Numbers sit at positions 0..n of the plain list, which follow the
        // arguments in order when no keyword comes first.
        let pos = |k: usize| a.list.iter().filter(|x| x.kind == ArgKind::Number).nth(k);
        w.centre = Some(Vector3::new(w.plain[0], w.plain[1], w.plain[2]));
        let (s, e) = (pos(3).map_or(0, |x| x.start), pos(5).map_or(0, |x| x.end));
        w.normal = Some((Vector3::new(w.plain[3], w.plain[4], w.plain[5]), s, e));
        if n >= 7 {
            w.radius = Some(w.plain[6]);
            w.radius_at = pos(6).map_or((0, 0), |x| (x.start, x.end));
        }
        left_handed = n >= 8 && major == "CIRCLE";
    }
    Ok(left_handed)
}
