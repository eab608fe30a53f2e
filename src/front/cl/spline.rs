//! NX NURBS motion (`NURBS/`, `KNOT/`, `CNTRL/`) cut into straight pieces in the part
//! frame.
//!
//! NX writes a spline of a contouring operation as one `NURBS/` record, the knot vector
//! in `KNOT/` records and the control points in `CNTRL/` records, instead of the `GOTO`s
//! it would write otherwise. The records are gathered until the next other statement;
//! then the curve is checked (the knot count is the control point count plus the order,
//! the knots never decrease, every weight is positive), evaluated with de Boor's
//! algorithm (rational when weights are given) and cut into pieces whose chords stay
//! within [`Options::arc_tolerance`] of the curve: each candidate chord is checked
//! against the curve at seven points inside it, and halved until it fits. Control
//! points that carry a tool axis give the axis along the curve (blended with the same
//! basis, then made unit length); otherwise the tool axis in force holds.
//!
//! A spline the frontend cannot evaluate is an error at its `NURBS/` line, never a
//! straight move.

use nalgebra::{Point3, Unit, Vector3};

use super::motion::{motion_block, unit};
use super::options::Options;
use crate::diag::Diagnostic;
use crate::ir::{Block, Comment, Feed, MotionKind, Span};

/// Most pieces one spline is cut into; a spline needing more is an error.
pub(super) const MAX_SEGMENTS: usize = 100_000;

/// Most control points (and knots) one spline may have.
pub(super) const MAX_RECORDS: usize = 100_000;

/// Points inside a candidate chord at which the curve is measured.
const PROBES: usize = 7;

/// Halvings of one knot span before a chord is taken as it is (a span 2^-40 of its length
/// is far below any machine's resolution).
const MAX_DEPTH: u32 = 40;

/// A control point: homogeneous position `w·x, w·y, w·z, w` and `w·i, w·j, w·k`.
type Homogeneous = [f64; 7];

/// The records of a spline being read.
#[derive(Debug, Clone)]
pub(super) struct Pending {
    /// The `NURBS/` statement: where errors point and the span of the pieces.
    pub span: Span,
    /// The degree written on `NURBS/` (from `DEGREE,d` or `ORDER,k`), if any.
    pub degree: Option<usize>,
    pub knots: Vec<f64>,
    /// Control points, mm, in the part frame.
    pub points: Vec<Homogeneous>,
    /// Whether the control points carry tool axes (all or none).
    pub with_axis: Option<bool>,
    /// A record was malformed (already reported): the spline is not cut.
    pub broken: bool,
}

impl Pending {
    /// The records of the spline whose `NURBS/` statement is at `span`.
    pub fn new(span: Span, degree: Option<usize>) -> Pending {
        Pending {
            span,
            degree,
            knots: Vec::new(),
            points: Vec::new(),
            with_axis: None,
            broken: false,
        }
    }

    /// Adds a control point at `p` (mm) with weight `w` and, maybe, tool axis `axis`.
    pub fn push_point(&mut self, p: Point3<f64>, w: f64, axis: Option<Unit<Vector3<f64>>>) {
        let a = axis.map_or([0.0; 3], |a| [a.x, a.y, a.z]);
        self.points
            .push([w * p.x, w * p.y, w * p.z, w, w * a[0], w * a[1], w * a[2]]);
    }

    fn error(&self, what: String, help: &str) -> Diagnostic {
        Diagnostic::error("cl::nurbs", what)
            .at_span(self.span)
            .with_label("this spline")
            .with_help(help.to_string())
    }

    /// The curve, checked.
    fn curve(self) -> Result<Curve, Diagnostic> {
        let n = self.points.len();
        let m = self.knots.len();
        if n == 0 || m == 0 {
            let missing = if n == 0 { "CNTRL/" } else { "KNOT/" };
            return Err(self.error(
                format!(
                    "the NURBS on line {} has no {missing} records",
                    self.span.line
                ),
                "a NURBS/ record is followed by its KNOT/ (knot vector) and CNTRL/ (control \
                 point) records; re-output the operation from the CAM",
            ));
        }
        let Some(p) = m.checked_sub(n + 1).filter(|&p| p >= 1) else {
            return Err(self.error(
                format!(
                    "the NURBS on line {} has {m} knots for {n} control points; a spline of \
                     degree p needs control points + p + 1 knots (p at least 1)",
                    self.span.line
                ),
                "too few knots or too many control points: the records are incomplete",
            ));
        };
        if n < p + 1 {
            return Err(self.error(
                format!(
                    "the NURBS on line {} has {n} control points and {m} knots: degree {p}, \
                     which needs at least {} control points",
                    self.span.line,
                    p + 1
                ),
                "too few CNTRL/ records for the knot vector: the records are incomplete",
            ));
        }
        if let Some(d) = self.degree
            && d != p
        {
            return Err(self.error(
                format!(
                    "the NURBS on line {} says degree {d}, but its {m} knots and {n} control \
                     points make degree {p}",
                    self.span.line
                ),
                "the knot count must be the control point count + degree + 1",
            ));
        }
        if let Some(i) = self.knots.windows(2).position(|k| k[1] < k[0]) {
            return Err(self.error(
                format!(
                    "knot {} of the NURBS on line {} ({}) is smaller than the one before ({})",
                    i + 2,
                    self.span.line,
                    self.knots[i + 1],
                    self.knots[i]
                ),
                "a knot vector never decreases; the KNOT/ records are out of order",
            ));
        }
        let (u0, u1) = (self.knots[p], self.knots[n]);
        if u1 <= u0 {
            return Err(self.error(
                format!(
                    "the NURBS on line {} has no length: its knots are all equal",
                    self.span.line
                ),
                "the knots from the (degree+1)-th to the (control points)-th must span a range",
            ));
        }
        let inner = &self.knots[1..m - 1];
        let mut run = 1;
        for k in inner.windows(2) {
            run = if k[1] == k[0] { run + 1 } else { 1 };
            if run > p && k[0] > u0 && k[0] < u1 {
                return Err(self.error(
                    format!(
                        "the NURBS on line {} repeats the inner knot {} more than {p} times, \
                         which breaks the curve apart",
                        self.span.line, k[0]
                    ),
                    "an inner knot may repeat at most degree times; re-output the operation",
                ));
            }
        }
        Ok(Curve {
            p,
            knots: self.knots,
            points: self.points,
            with_axis: self.with_axis == Some(true),
        })
    }
}

/// A checked B-spline (rational when weights differ).
#[derive(Debug, Clone)]
struct Curve {
    p: usize,
    knots: Vec<f64>,
    points: Vec<Homogeneous>,
    with_axis: bool,
}

impl Curve {
    fn domain(&self) -> (f64, f64) {
        (self.knots[self.p], self.knots[self.points.len()])
    }

    /// The knot span `k` (`knots[k] <= u < knots[k + 1]`, the last non-empty one at the
    /// end of the domain).
    fn span(&self, u: f64) -> usize {
        let n = self.points.len();
        let (lo, hi) = (self.p, n - 1);
        if u >= self.knots[n] {
            let mut k = hi;
            while k > lo && self.knots[k] >= self.knots[k + 1] {
                k -= 1;
            }
            return k;
        }
        // The first knot above u, within knots[p + 1 ..= n].
        let above = self.knots[lo + 1..=n].partition_point(|&k| k <= u);
        (lo + above).clamp(lo, hi)
    }

    /// The point (mm) and, when the control points carry them, the tool axis at `u`.
    fn at(&self, u: f64) -> (Point3<f64>, Option<Unit<Vector3<f64>>>) {
        let p = self.p;
        let k = self.span(u);
        let mut d: Vec<Homogeneous> = self.points[k - p..=k].to_vec();
        for r in 1..=p {
            for j in (r..=p).rev() {
                let i = j + k - p;
                let alpha = (u - self.knots[i]) / (self.knots[i + p + 1 - r] - self.knots[i]);
                let prev = d[j - 1];
                for (x, y) in d[j].iter_mut().zip(prev) {
                    *x = (1.0 - alpha) * y + alpha * *x;
                }
            }
        }
        let h = d[p];
        let tip = Point3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]);
        let axis = if self.with_axis {
            unit(Vector3::new(h[4], h[5], h[6]))
        } else {
            None
        };
        (tip, axis)
    }

    /// The parameters of the piece ends from `u0` on, every chord within `tol` of the
    /// curve; `None` when more than [`MAX_SEGMENTS`] are needed.
    fn plan(&self, tol: f64) -> Option<Vec<f64>> {
        let (u0, u1) = self.domain();
        let mut params = vec![u0];
        let n = self.points.len();
        for k in self.p..n {
            let (a, b) = (self.knots[k].max(u0), self.knots[k + 1].min(u1));
            if b <= a {
                continue;
            }
            // Intervals still to check, the leftmost on top.
            let mut stack = vec![(a, b, 0u32)];
            while let Some((a, b, depth)) = stack.pop() {
                if depth < MAX_DEPTH && self.deviation(a, b) > tol {
                    let m = 0.5 * (a + b);
                    stack.push((m, b, depth + 1));
                    stack.push((a, m, depth + 1));
                    continue;
                }
                params.push(b);
                if params.len() > MAX_SEGMENTS + 1 {
                    return None;
                }
            }
        }
        Some(params)
    }

    /// The largest distance of the curve between `a` and `b`, measured at [`PROBES`]
    /// points, from the chord between its ends.
    fn deviation(&self, a: f64, b: f64) -> f64 {
        let (pa, _) = self.at(a);
        let (pb, _) = self.at(b);
        let chord = pb - pa;
        let len2 = chord.norm_squared();
        (1..=PROBES)
            .map(|i| {
                let u = a + (b - a) * i as f64 / (PROBES + 1) as f64;
                let q = self.at(u).0 - pa;
                let t = if len2 > 0.0 {
                    (q.dot(&chord) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                (q - chord * t).norm()
            })
            .fold(0.0, f64::max)
    }
}

/// A spline being cut into pieces.
#[derive(Debug, Clone)]
pub(super) struct Run {
    curve: Curve,
    params: Vec<f64>,
    next: usize,
    axis: Unit<Vector3<f64>>,
    feed: Feed,
    span: Span,
    /// Comments for the first piece.
    pub comments: Vec<Comment>,
}

impl Run {
    /// Plans the pieces of `pending`, the tool at `pos` with `axis` in force and `feed`.
    /// Warns when the curve starts away from the tool (the tool then moves there
    /// straight first).
    pub fn new(
        pending: Pending,
        pos: Option<Point3<f64>>,
        axis: Unit<Vector3<f64>>,
        feed: Feed,
        options: &Options,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<Run, Diagnostic> {
        let span = pending.span;
        let curve = pending.curve()?;
        if curve.points.iter().flatten().any(|c| !c.is_finite())
            || curve.knots.iter().any(|k| !k.is_finite())
        {
            return Err(
                Diagnostic::error("cl::nurbs", "the NURBS values are out of range")
                    .at_span(span)
                    .with_help("CL values must be finite numbers"),
            );
        }
        let tol = options.arc_tolerance.max(1e-6);
        let params = curve.plan(tol).ok_or_else(|| {
            Diagnostic::error(
                "cl::nurbs",
                format!(
                    "the NURBS on line {} needs more than {MAX_SEGMENTS} straight pieces \
                     within arc_tolerance = {tol} mm",
                    span.line
                ),
            )
            .at_span(span)
            .with_help("raise cl_input.arc_tolerance, or split the operation in the CAM")
        })?;
        let (start, _) = curve.at(params[0]);
        let gap = pos.map_or(f64::INFINITY, |p| (p - start).norm());
        if pos.is_some() && gap > tol {
            diags.push(
                Diagnostic::warning(
                    "cl::nurbs-start",
                    format!(
                        "the NURBS on line {} starts {gap:.4} mm away from the tool; it moves \
                         there in a straight line first",
                        span.line
                    ),
                )
                .at_span(span)
                .with_help("a NURBS usually starts where the last motion ended; check the records"),
            );
        }
        Ok(Run {
            curve,
            params,
            next: if gap > 1e-9 { 0 } else { 1 },
            axis,
            feed,
            span,
            comments: Vec::new(),
        })
    }

    /// Whether every piece has been handed out.
    pub fn done(&self) -> bool {
        self.next >= self.params.len()
    }

    /// The pose at the end of the spline.
    pub fn end(&self) -> (Point3<f64>, Unit<Vector3<f64>>) {
        let (tip, axis) = self.curve.at(self.curve.domain().1);
        (tip, axis.unwrap_or(self.axis))
    }

    /// Appends up to `max` pieces.
    pub fn emit(&mut self, out: &mut Vec<Block>, max: usize) {
        for _ in 0..max {
            if self.done() {
                break;
            }
            let (tip, axis) = self.curve.at(self.params[self.next]);
            let mut b = motion_block(
                self.span,
                MotionKind::Linear,
                tip,
                axis.unwrap_or(self.axis),
                self.feed,
            );
            if self.next <= 1 {
                b.comments.append(&mut self.comments);
            }
            out.push(b);
            self.next += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pending(knots: &[f64], pts: &[[f64; 4]]) -> Pending {
        let mut p = Pending::new(Span::default(), None);
        p.knots = knots.to_vec();
        for q in pts {
            p.push_point(Point3::new(q[0], q[1], q[2]), q[3], None);
        }
        p
    }

    /// A quarter circle as a rational quadratic: every point on the curve is at radius 1.
    #[test]
    fn rational_quarter_circle() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let c = pending(
            &[0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
            &[
                [1.0, 0.0, 0.0, 1.0],
                [1.0, 1.0, 0.0, h],
                [0.0, 1.0, 0.0, 1.0],
            ],
        )
        .curve()
        .unwrap();
        assert_eq!(c.p, 2);
        for i in 0..=100 {
            let (p, _) = c.at(i as f64 / 100.0);
            assert!((p.coords.norm() - 1.0).abs() < 1e-12, "{p}");
        }
        let params = c.plan(0.001).unwrap();
        // A chord of angle θ on the unit circle sags 1 - cos(θ/2).
        for w in params.windows(2) {
            let (a, b) = (c.at(w[0]).0, c.at(w[1]).0);
            let sag = 1.0 - (0.5 * (a - b).norm()).asin().cos();
            assert!(sag <= 0.001 + 1e-9);
        }
    }

    #[test]
    fn bad_records_are_errors() {
        let pts = [
            [0.0, 0.0, 0.0, 1.0],
            [1.0, 1.0, 0.0, 1.0],
            [2.0, 0.0, 0.0, 1.0],
        ];
        assert!(pending(&[0.0, 0.0, 1.0, 1.0], &pts).curve().is_err());
        assert!(
            pending(&[0.0, 0.0, 1.0, 0.5, 1.0, 1.0], &pts)
                .curve()
                .is_err()
        );
        assert!(pending(&[1.0; 6], &pts).curve().is_err());
        let mut d = pending(&[0.0, 0.0, 0.0, 1.0, 1.0, 1.0], &pts);
        d.degree = Some(3);
        assert!(d.curve().is_err());
    }
}
