//! `CIRCLE`/`MOVARC` arcs cut into straight pieces in the part frame.
//!
//! The arc starts at the current point and ends at the point of the next `GOTO`. The
//! start and end are measured from the circle's axis (the line through the centre along
//! the axis vector): their distances from it are the start and end radius, their
//! heights along it the start and end height. Pieces follow a circle (a helix when the
//! heights differ, a slight spiral when the radii differ within the tolerance), so the
//! first piece starts and the last one ends exactly at the written points. The sweep is
//! counter-clockwise about the (direction-corrected) axis, from the start to the end
//! angle, plus the full turns written with `TIMES` (or implied by `ANGLE`). The tool
//! axis turns from the start to the end axis along a great circle (slerp).

use std::f64::consts::TAU;

use nalgebra::{Point3, Unit, Vector3};

use super::motion::{Circle, motion_block};
use super::options::Options;
use super::source::Statement;
use crate::diag::Diagnostic;
use crate::ir::{Block, Comment, Feed, MotionKind, Span};

/// Most pieces one arc is cut into; beyond it the chord error exceeds the tolerance (with
/// a warning).
pub(super) const MAX_SEGMENTS: u32 = 100_000;

/// Radial distance below which start and end are the same point (a full circle).
const SAME_POINT: f64 = 1e-7;

/// An arc being cut into pieces.
#[derive(Debug, Clone)]
pub(super) struct Run {
    centre: Point3<f64>,
    normal: Vector3<f64>,
    /// Unit vector from the axis towards the start point.
    u: Vector3<f64>,
    /// `normal × u`.
    v: Vector3<f64>,
    r0: f64,
    r1: f64,
    h0: f64,
    h1: f64,
    sweep: f64,
    segments: u32,
    next: u32,
    a0: Unit<Vector3<f64>>,
    a1: Unit<Vector3<f64>>,
    end: Point3<f64>,
    kind: MotionKind,
    feed: Feed,
    span: Span,
    /// Comments for the first piece.
    pub comments: Vec<Comment>,
}

impl Run {
    /// Plans the arc of `circle` from `start` to `end`; `Err` is a warning, and the
    /// motion is then a straight move.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        circle: &Circle,
        start: Point3<f64>,
        end: Point3<f64>,
        a0: Unit<Vector3<f64>>,
        a1: Unit<Vector3<f64>>,
        kind: MotionKind,
        feed: Feed,
        stmt: &Statement,
        options: &Options,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<Run, Diagnostic> {
        let n = circle.normal.into_inner();
        let s = start - circle.centre;
        let e = end - circle.centre;
        let (h0, h1) = (s.dot(&n), e.dot(&n));
        let rs = s - n * h0;
        let re = e - n * h1;
        let (r0, r1) = (rs.norm(), re.norm());
        let nominal = circle.radius.unwrap_or(r0);
        let tolerance = options.radius_tolerance.max(0.0) + 1e-3 * nominal;
        let off = match circle.radius {
            Some(r) => (r0 - r).abs().max((r1 - r).abs()),
            None => (r1 - r0).abs(),
        };
        let warn = |what: String| {
            stmt.locate_all(Diagnostic::warning("cl::arc-radius", what))
                .with_label("arc end point")
                .with_help("moved in a straight line to the point; check the CIRCLE values")
        };
        if off.is_nan() || off > tolerance {
            return Err(warn(format!(
                "the arc of the CIRCLE on line {} does not fit its points: start and end are \
                 {:.4} mm and {:.4} mm from its axis, radius {:.4} mm",
                circle.line, r0, r1, nominal
            )));
        }
        if !(r0 > SAME_POINT && r1 > SAME_POINT) {
            return Err(warn(format!(
                "the arc of the CIRCLE on line {} has a point on its axis",
                circle.line
            )));
        }
        let extent = circle.centre.coords.amax() + r0.max(r1) + h0.abs().max(h1.abs());
        if !(extent.is_finite() && extent < 1e300) {
            return Err(warn(format!(
                "the arc of the CIRCLE on line {} is out of range",
                circle.line
            )));
        }
        let u = rs / r0;
        let v = n.cross(&u);
        let sweep = sweep(circle, (u, v), re, (r0, r1), stmt, diags).ok_or_else(|| {
            warn(format!(
                "the arc of the CIRCLE on line {} has no length",
                circle.line
            ))
        })?;
        let segments = pieces(circle, sweep, r0.max(r1), stmt, options, diags);
        Ok(Run {
            centre: circle.centre,
            normal: n,
            u,
            v,
            r0,
            r1,
            h0,
            h1,
            sweep,
            segments,
            next: 1,
            a0,
            a1,
            end,
            kind,
            feed,
            span: stmt.span,
            comments: Vec::new(),
        })
    }

    /// Whether every piece has been handed out.
    pub fn done(&self) -> bool {
        self.next > self.segments
    }

    /// Appends up to `max` pieces.
    pub fn emit(&mut self, out: &mut Vec<Block>, max: usize) {
        for _ in 0..max {
            if self.done() {
                break;
            }
            let k = self.next;
            self.next += 1;
            let (tip, axis) = if k == self.segments {
                (self.end, self.a1)
            } else {
                let t = f64::from(k) / f64::from(self.segments);
                let angle = self.sweep * t;
                let r = self.r0 + (self.r1 - self.r0) * t;
                let h = self.h0 + (self.h1 - self.h0) * t;
                let p = self.centre
                    + self.normal * h
                    + (self.u * angle.cos() + self.v * angle.sin()) * r;
                (p, slerp(self.a0, self.a1, t))
            };
            let mut b = motion_block(self.span, self.kind, tip, axis, self.feed);
            if k == 1 {
                b.comments = std::mem::take(&mut self.comments);
            }
            out.push(b);
        }
    }
}

/// The angle the arc sweeps about the circle's axis (`u` towards the start, `v` a quarter
/// turn on), from the start to `re`, the end's offset from the axis: the partial turn plus
/// the full turns written with `TIMES` or implied by `ANGLE`; `None` when it has no length.
fn sweep(
    circle: &Circle,
    (u, v): (Vector3<f64>, Vector3<f64>),
    re: Vector3<f64>,
    (r0, r1): (f64, f64),
    stmt: &Statement,
    diags: &mut Vec<Diagnostic>,
) -> Option<f64> {
    let mut partial = re.dot(&v).atan2(re.dot(&u));
    if partial < 0.0 {
        partial += TAU;
    }
    let coincident = (re / r1 - u).norm() * r0.max(r1) < SAME_POINT;
    if coincident {
        // The same point: a full circle, unless TIMES or ANGLE count the turns.
        partial = if circle.turns.is_some() || circle.angle.is_some() {
            0.0
        } else {
            TAU
        };
    }
    let mut turns = f64::from(circle.turns.unwrap_or(0));
    if let Some(angle) = circle.angle {
        let whole = angle.abs().to_radians();
        let k = ((whole - partial) / TAU).round().max(0.0);
        if ((partial + k * TAU) - whole).abs() > 1f64.to_radians() {
            diags.push(
                stmt.locate_all(Diagnostic::warning(
                    "cl::arc-angle",
                    format!(
                        "the ANGLE of the arc on line {} ({angle} degrees) does not reach \
                         its end point ({:.4} degrees)",
                        circle.line,
                        partial.to_degrees()
                    ),
                ))
                .with_help("the arc ends at the GOTO point; ANGLE only counts full turns"),
            );
        }
        turns = turns.max(k.min(10_000.0));
    }
    let sweep = partial + turns * TAU;
    (sweep > 0.0).then_some(sweep)
}

/// How many straight pieces an arc of `sweep` radians on `radius` needs for the chord
/// tolerance (at most [`MAX_SEGMENTS`], with a warning).
fn pieces(
    circle: &Circle,
    sweep: f64,
    radius: f64,
    stmt: &Statement,
    options: &Options,
    diags: &mut Vec<Diagnostic>,
) -> u32 {
    // A piece of angle `step` on radius R deviates from the arc by its sagitta
    // 2 R sin²(step/4).
    let tol = options.arc_tolerance;
    let step = if tol > 0.0 && tol < 2.0 * radius {
        (4.0 * (tol / (2.0 * radius)).sqrt().asin()).min(std::f64::consts::FRAC_PI_2)
    } else {
        std::f64::consts::FRAC_PI_2
    };
    let needed = (sweep / step).ceil();
    if needed > f64::from(MAX_SEGMENTS) {
        diags.push(
            stmt.locate_all(Diagnostic::warning(
                "cl::arc-pieces",
                format!(
                    "the arc of the CIRCLE on line {} needs {needed:.0} pieces for the \
                     chord tolerance; it is cut into {MAX_SEGMENTS}",
                    circle.line
                ),
            ))
            .with_help("raise `arc_tolerance` or check the CIRCLE radius and TIMES"),
        );
        MAX_SEGMENTS
    } else {
        (needed as u32).max(1)
    }
}

/// The unit vector a fraction `t` of the way from `a` to `b` along the great circle;
/// for opposite vectors, about an axis perpendicular to `a`.
pub(super) fn slerp(a: Unit<Vector3<f64>>, b: Unit<Vector3<f64>>, t: f64) -> Unit<Vector3<f64>> {
    let cos = a.dot(&b).clamp(-1.0, 1.0);
    let perp = b.into_inner() - a.into_inner() * cos;
    let sin = perp.norm();
    let angle = sin.atan2(cos);
    if angle < 1e-12 {
        return a;
    }
    let w = if sin > 1e-9 {
        perp / sin
    } else {
        // Opposite: any perpendicular will do.
        let helper = if a.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        a.cross(&helper).normalize()
    };
    Unit::new_normalize(a.into_inner() * (angle * t).cos() + w * (angle * t).sin())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slerp_ends_and_middle() {
        let a = Vector3::z_axis();
        let b = Vector3::x_axis();
        assert!((slerp(a, b, 0.0).into_inner() - a.into_inner()).norm() < 1e-12);
        assert!((slerp(a, b, 1.0).into_inner() - b.into_inner()).norm() < 1e-12);
        let m = slerp(a, b, 0.5);
        assert!((m.x - m.z).abs() < 1e-12 && m.y.abs() < 1e-12);
        let o = slerp(a, -a, 0.5);
        assert!(o.z.abs() < 1e-12);
    }
}
