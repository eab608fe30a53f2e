//! The triplet format: a point line, a tool axis line and a hexadecimal motion code
//! line per move.

use nalgebra::{Point3, Unit, Vector3};

use super::Lowerer;
use crate::diag::Diagnostic;
use crate::front::cl::motion::{motion_block, unit};
use crate::front::cl::source::Statement;
use crate::ir::{Block, MotionKind, Span};

/// State of the triplet format: what the next line is.
#[derive(Debug, Clone, Copy)]
pub(super) enum Triplet {
    Point,
    Axis {
        point: Point3<f64>,
        span: Span,
    },
    Code {
        point: Point3<f64>,
        axis: Unit<Vector3<f64>>,
        span: Span,
    },
}

impl Lowerer {
    /// Lowers one line of the triplet format.
    pub(super) fn triplet_line(
        &mut self,
        stmt: &Statement,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let code = stmt.code.trim();
        if code.is_empty() {
            return;
        }
        let state = self.triplet.unwrap_or(Triplet::Point);
        let next = match state {
            Triplet::Point => numbers(stmt).and_then(|p| {
                let p = p * self.scale;
                if p.iter().all(|c| c.is_finite()) {
                    Ok(Triplet::Axis {
                        point: Point3::from(p),
                        span: stmt.span,
                    })
                } else {
                    Err(stmt.locate_all(Diagnostic::error(
                        "cl::bad-number",
                        "the point is out of range",
                    )))
                }
            }),
            Triplet::Axis { point, span } => numbers(stmt).and_then(|v| {
                unit(v)
                    .map(|axis| Triplet::Code { point, axis, span })
                    .ok_or_else(|| {
                        stmt.locate_all(
                            Diagnostic::error("cl::zero-axis", "the tool axis is a zero vector")
                                .with_label("zero vector")
                                .with_help("give a tool axis with a non-zero length, e.g. 0 0 1"),
                        )
                    })
            }),
            Triplet::Code { point, axis, span } => {
                self.triplet_code(stmt, code, (point, axis, span), out)
            }
        };
        match next {
            Ok(s) => self.triplet = Some(s),
            Err(d) => {
                diags.push(d);
                self.triplet = Some(Triplet::Point);
            }
        }
    }

    /// The motion code line that ends a triplet: the move to its point.
    fn triplet_code(
        &mut self,
        stmt: &Statement,
        code: &str,
        (point, axis, span): (Point3<f64>, Unit<Vector3<f64>>, Span),
        out: &mut Vec<Block>,
    ) -> Result<Triplet, Diagnostic> {
        if (1..=4).contains(&code.len()) && code.bytes().all(|b| b.is_ascii_hexdigit()) {
            let kind = if code.eq_ignore_ascii_case("7f") {
                MotionKind::Rapid
            } else {
                MotionKind::Linear
            };
            let end = stmt.span.offset + u64::from(stmt.span.len);
            let span = Span {
                len: end.saturating_sub(span.offset).min(u64::from(u32::MAX)) as u32,
                ..span
            };
            out.push(motion_block(span, kind, point, axis, self.feed));
            self.pos = Some(point);
            self.axis = axis;
            Ok(Triplet::Point)
        } else {
            Err(stmt.locate_all(
                Diagnostic::error(
                    "cl::triplet",
                    format!(
                        "expected a motion code such as `7f` or `80`, found `{}`",
                        crate::num::range::shown(code)
                    ),
                )
                .with_label("not a motion code")
                .with_help("the third line of a triplet is the hexadecimal motion code (7f rapid)"),
            ))
        }
    }
}

/// The three numbers of a triplet's point or tool axis line (blanks or commas between).
fn numbers(stmt: &Statement) -> Result<Vector3<f64>, Diagnostic> {
    let mut v = Vec::with_capacity(3);
    let mut offset = 0;
    for field in stmt
        .code
        .split(|c: char| c.is_ascii_whitespace() || c == ',')
    {
        let start = offset;
        offset += field.len() + 1;
        if field.is_empty() {
            continue;
        }
        match crate::num::parse_decimal(field) {
            Some(x)
                if crate::num::range::in_range(x)
                    && field
                        .bytes()
                        .all(|b| b.is_ascii_digit() || b"+-.eE".contains(&b)) =>
            {
                v.push(x)
            }
            _ => {
                return Err(stmt.locate(
                    Diagnostic::error(
                        "cl::bad-number",
                        format!(
                            "expected a number, found `{}`",
                            crate::num::range::shown(field)
                        ),
                    )
                    .with_label("not a number or out of range")
                    .with_help(format!(
                        "a triplet's first two lines hold three numbers each, at most {:e} in size",
                        crate::num::range::MAX_MAGNITUDE
                    )),
                    start,
                    start + field.len(),
                ));
            }
        }
    }
    if v.len() != 3 {
        return Err(stmt.locate_all(
            Diagnostic::error(
                "cl::triplet",
                format!("expected three numbers, found {}", v.len()),
            )
            .with_label("here")
            .with_help("a triplet is a point line, a tool axis line and a motion code line"),
        ));
    }
    Ok(Vector3::new(v[0], v[1], v[2]))
}
