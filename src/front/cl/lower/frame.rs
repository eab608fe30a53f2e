//! The statements that name a coordinate frame or a spline: NX `MSYS` (applied to the
//! points under `msys = "apply"`), and NX `NURBS/`, `KNOT/`, `CNTRL/` (gathered, then cut
//! into pieces by [`spline`](crate::front::cl::spline)).

use nalgebra::{Matrix3, Point3, Unit, Vector3};

use super::{Args, Lowerer, comment};
use crate::diag::Diagnostic;
use crate::front::cl::motion::unit;
use crate::front::cl::options::Msys;
use crate::front::cl::source::Statement;
use crate::front::cl::spline::{MAX_RECORDS, Pending, Run};
use crate::ir::{self, Block};

/// A machine coordinate system: `p_part = origin + rot · p_mcs` (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Frame {
    pub origin: Vector3<f64>,
    pub rot: Matrix3<f64>,
}

impl Frame {
    pub fn point(&self, p: Point3<f64>) -> Point3<f64> {
        Point3::from(self.origin + self.rot * p.coords)
    }

    pub fn vector(&self, v: Vector3<f64>) -> Vector3<f64> {
        self.rot * v
    }
}

/// Largest difference from the identity taken as the identity (NX writes 7 decimals).
const IDENTITY_SLACK: f64 = 1e-6;

impl Lowerer {
    /// A point written in the program's frame, in the part frame: the applied `MSYS`.
    pub(super) fn to_part(&self, p: Point3<f64>) -> Point3<f64> {
        self.frame.map_or(p, |f| f.point(p))
    }

    /// A direction written in the program's frame, in the part frame.
    pub(super) fn dir_to_part(&self, v: Vector3<f64>) -> Vector3<f64> {
        self.frame.map_or(v, |f| f.vector(v))
    }

    /// Marks the pass-through block of a frame statement (the last in `out`) for the
    /// passes: the frame rotates the points but was not applied.
    pub(super) fn note_frame(out: &mut [Block]) {
        if let Some(b) = out.last_mut() {
            b.comments.push(comment(ir::FRAME_NOT_APPLIED));
        }
    }

    /// `MSYS/x,y,z,i1,j1,k1,i2,j2,k2`: the MCS origin and its X and Y axes in NX's
    /// absolute frame. Applied under `msys = "apply"` (the tool axis becomes the MCS Z
    /// axis, as NX's fixed-axis operations use it); otherwise one warning when it is not
    /// the identity, and a note for the passes when it rotates.
    pub(super) fn msys(
        &mut self,
        a: &Args<'_>,
        out: &mut [Block],
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let frame = match self.read_msys(a) {
            Ok(f) => f,
            Err(d) if self.options.msys == Msys::Apply => return Err(d),
            Err(_) => {
                diags.push(
                    a.error_all(Diagnostic::warning(
                        "cl::msys-not-applied",
                        "this MSYS is not understood; it is passed through and not applied",
                    ))
                    .with_help("NX writes MSYS/x,y,z,i1,j1,k1,i2,j2,k2"),
                );
                return Ok(());
            }
        };
        let z = Unit::new_unchecked(frame.rot.column(2).into_owned());
        let rotates = (frame.rot - Matrix3::identity()).amax() > IDENTITY_SLACK;
        let moves = frame.origin.amax() > IDENTITY_SLACK;
        if self.options.msys == Msys::Apply {
            self.frame = Some(frame);
            self.axis = z;
            return Ok(());
        }
        if rotates {
            Self::note_frame(out);
        }
        if (rotates || moves) && !self.warned_msys {
            self.warned_msys = true;
            diags.push(
                a.error_all(Diagnostic::warning(
                    "cl::msys-not-applied",
                    "the points are used in the MCS this MSYS names, as NX's postprocessors \
                     print them: the MSYS origin and rotation are not applied",
                ))
                .with_label("not applied")
                .with_help(
                    "this is right when the machine's work offset is the MCS origin; set \
                     `[cl_input] msys = \"apply\"` to move the points into NX's absolute \
                     frame instead",
                ),
            );
        }
        Ok(())
    }

    /// The frame of an `MSYS` statement.
    fn read_msys(&self, a: &Args<'_>) -> Result<Frame, Diagnostic> {
        a.arity("MSYS", &[9], "x,y,z,i1,j1,k1,i2,j2,k2")?;
        let v = a.numbers()?;
        let bad = |what: &str| {
            a.error_all(
                Diagnostic::error("cl::bad-value", format!("the MSYS {what}"))
                    .with_label("here")
                    .with_help(
                        "MSYS gives the origin, then the X and Y axes of the MCS as unit \
                         vectors at right angles",
                    ),
            )
        };
        let x =
            unit(Vector3::new(v[3], v[4], v[5])).ok_or_else(|| bad("X axis is a zero vector"))?;
        let y =
            unit(Vector3::new(v[6], v[7], v[8])).ok_or_else(|| bad("Y axis is a zero vector"))?;
        if x.dot(&y).abs() > 1e-4 {
            return Err(bad("X and Y axes are not at right angles"));
        }
        let z = x.cross(&y).normalize();
        let y = z.cross(&x);
        Ok(Frame {
            origin: Vector3::new(v[0], v[1], v[2]) * self.scale,
            rot: Matrix3::from_columns(&[x.into_inner(), y, z]),
        })
    }

    /// `NURBS/[DEGREE,d | ORDER,k]`, `KNOT/u1[,u2...]`, `CNTRL/x,y,z[,w][,i,j,k]`.
    pub(super) fn nurbs_record(&mut self, major: &str, a: &Args<'_>) -> Result<(), Diagnostic> {
        if major == "NURBS" {
            let degree = nurbs_degree(a)?;
            self.nurbs = Some(Pending::new(a.stmt.span, degree));
            return Ok(());
        }
        let Some(pending) = self.nurbs.as_mut() else {
            return Err(a.error_all(
                Diagnostic::error("cl::nurbs", format!("{major}/ outside a NURBS"))
                    .with_label("no NURBS/ before it")
                    .with_help("KNOT/ and CNTRL/ records follow a NURBS/ record"),
            ));
        };
        let result = if major == "KNOT" {
            read_knots(a, pending)
        } else {
            let (scale, frame) = (self.scale, self.frame);
            read_control(a, pending, scale, frame)
        };
        if result.is_err() {
            pending.broken = true;
        }
        result
    }

    /// Whether `stmt` ends the spline being read (any statement but its records); the
    /// spline's pieces are then planned and handed out before `stmt` is lowered. `false`
    /// when nothing is to be handed out (no spline, or it is an error).
    pub(in crate::front::cl) fn closes_spline(
        &mut self,
        stmt: &Statement,
        diags: &mut Vec<Diagnostic>,
    ) -> bool {
        if self.nurbs.is_none() || self.triplet.is_some() {
            return false;
        }
        let code = stmt.code.trim_start();
        let word = code
            .split(|c: char| !c.is_ascii_alphanumeric())
            .next()
            .unwrap_or("");
        if code.is_empty()
            || word.eq_ignore_ascii_case("KNOT")
            || word.eq_ignore_ascii_case("CNTRL")
        {
            return false;
        }
        self.end_spline(diags)
    }

    /// Plans the spline being read, if any; `true` when pieces are to be handed out.
    pub(super) fn end_spline(&mut self, diags: &mut Vec<Diagnostic>) -> bool {
        let Some(pending) = self.nurbs.take() else {
            return false;
        };
        if pending.broken {
            return false;
        }
        match Run::new(
            pending,
            self.pos,
            self.axis,
            self.feed,
            &self.options,
            diags,
        ) {
            Ok(run) => {
                let (tip, axis) = run.end();
                self.pos = Some(tip);
                self.axis = axis;
                self.spline = Some(run);
                true
            }
            Err(d) => {
                diags.push(d);
                false
            }
        }
    }
}

/// The degree a `NURBS/` record names, if any.
fn nurbs_degree(a: &Args<'_>) -> Result<Option<usize>, Diagnostic> {
    let bad = || {
        a.error_all(
            Diagnostic::error("cl::nurbs", "NURBS/ takes nothing, DEGREE,d or ORDER,k")
                .with_label("not understood")
                .with_help(
                    "the degree follows from the counts of KNOT/ and CNTRL/ values; write \
                     NURBS/ alone, or NURBS/DEGREE,3",
                ),
        )
    };
    match a.list {
        [] => Ok(None),
        [w, n] => {
            let v = a.number(n)?;
            if !(v.fract() == 0.0 && (1.0..=30.0).contains(&v)) {
                return Err(bad());
            }
            match a.word(w).as_deref() {
                Some("DEGREE") => Ok(Some(v as usize)),
                Some("ORDER") if v >= 2.0 => Ok(Some(v as usize - 1)),
                _ => Err(bad()),
            }
        }
        _ => Err(bad()),
    }
}

fn read_knots(a: &Args<'_>, pending: &mut Pending) -> Result<(), Diagnostic> {
    if a.list.is_empty() {
        return Err(a.error_all(
            Diagnostic::error("cl::arity", "KNOT/ without a value")
                .with_help("write KNOT/u or KNOT/u1,u2,..."),
        ));
    }
    for x in a.list {
        pending.knots.push(a.number(x)?);
    }
    if pending.knots.len() > MAX_RECORDS {
        return Err(a.error_all(Diagnostic::error(
            "cl::nurbs",
            format!("the NURBS has more than {MAX_RECORDS} knots"),
        )));
    }
    Ok(())
}

fn read_control(
    a: &Args<'_>,
    pending: &mut Pending,
    scale: f64,
    frame: Option<Frame>,
) -> Result<(), Diagnostic> {
    a.arity("CNTRL", &[3, 4, 6, 7], "x,y,z[,w][,i,j,k]")?;
    let v = a.numbers()?;
    let weighted = v.len() == 4 || v.len() == 7;
    let w = if weighted { v[3] } else { 1.0 };
    if w <= 0.0 {
        let x = &a.list[3];
        return Err(a.stmt.locate(
            Diagnostic::error("cl::nurbs", "a NURBS weight must be positive")
                .with_label("weight")
                .with_help("CNTRL/x,y,z,w: the fourth value is the weight"),
            x.start,
            x.end,
        ));
    }
    let with_axis = v.len() >= 6;
    if pending.with_axis.is_some_and(|had| had != with_axis) {
        return Err(a.error_all(
            Diagnostic::error(
                "cl::nurbs",
                "some CNTRL/ records of this NURBS give a tool axis and some do not",
            )
            .with_help("give every control point a tool axis, or none"),
        ));
    }
    pending.with_axis = Some(with_axis);
    let axis = if with_axis {
        let o = if weighted { 4 } else { 3 };
        let d = Vector3::new(v[o], v[o + 1], v[o + 2]);
        let d = frame.map_or(d, |f| f.vector(d));
        Some(unit(d).ok_or_else(|| {
            a.error_all(
                Diagnostic::error("cl::zero-axis", "the tool axis i,j,k is a zero vector")
                    .with_help("give a tool axis with a non-zero length, e.g. 0,0,1"),
            )
        })?)
    } else {
        None
    };
    let p = Point3::new(v[0], v[1], v[2]) * scale;
    let p = frame.map_or(p, |f| f.point(p));
    pending.push_point(p, w, axis);
    if pending.points.len() > MAX_RECORDS {
        return Err(a.error_all(Diagnostic::error(
            "cl::nurbs",
            format!("the NURBS has more than {MAX_RECORDS} control points"),
        )));
    }
    Ok(())
}
