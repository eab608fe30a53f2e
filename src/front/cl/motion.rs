//! The pieces every CL statement builds its motions from: the length unit, unit vectors
//! (tool axes, circle axes), the motion block to a pose, and the `CIRCLE`/`MOVARC` that
//! waits for the `GOTO` ending it. The lowering, the arcs and the drilling cycles all use
//! them; this module uses none of those.

use nalgebra::{Point3, Unit, Vector3};

use crate::diag::Diagnostic;
use crate::ir::{AxisSet, Block, BlockKind, Feed, Motion, MotionKind, Pose, Span, Target};

/// Millimetres per inch (`UNITS/INCHES`, `IPM`, `IPR`).
pub(super) const MM_PER_INCH: f64 = 25.4;

/// A `CIRCLE` or `MOVARC` waiting for the motion that ends it.
#[derive(Debug, Clone)]
pub(super) struct Circle {
    /// Centre, mm.
    pub centre: Point3<f64>,
    /// The arc runs counter-clockwise about this axis (right-hand rule).
    pub normal: Unit<Vector3<f64>>,
    /// Radius, mm, when the statement gives one.
    pub radius: Option<f64>,
    /// Full turns written with `TIMES`.
    pub turns: Option<u32>,
    /// Whole sweep in degrees written with `ANGLE`.
    pub angle: Option<f64>,
    /// The statement's first line.
    pub line: u32,
    /// The warning for a CIRCLE that no GOTO ends, pointing at it.
    pub unused: Diagnostic,
}

/// The unit vector along `v`, or `None` for a zero (or not finite) vector.
///
/// `v` is scaled by its largest magnitude `m` first, so no square overflows or
/// underflows, then divided by its norm: [`Unit::new_normalize`]'s steps. With `m` finite
/// every scaled component that is a number lies in [-1, 1] and one is ±1, so the norm
/// lies in [1, √3] and every quotient is finite, unless a component is NaN (the maximum
/// passes over a NaN first component): then the norm is NaN. Testing the norm is testing
/// the three quotients.
pub(super) fn unit(v: Vector3<f64>) -> Option<Unit<Vector3<f64>>> {
    let m = v.amax();
    if !(m.is_finite() && m > 1e-12) {
        return None;
    }
    let mut u = v / m;
    let n = u.norm();
    if n.is_nan() {
        return None;
    }
    u.unscale_mut(n);
    Some(Unit::new_unchecked(u))
}

/// A motion block to a pose.
pub(super) fn motion_block(
    span: Span,
    kind: MotionKind,
    tip: Point3<f64>,
    axis: Unit<Vector3<f64>>,
    feed: Feed,
) -> Block {
    Block::new(
        span,
        BlockKind::Motion(Motion {
            kind,
            target: Target::Pose(Pose::new(tip, axis)),
            feed,
            written: AxisSet::XYZ,
            machine_frame: false,
            extra: String::new(),
        }),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_vectors_have_no_direction() {
        assert!(unit(Vector3::zeros()).is_none());
        assert!(unit(Vector3::new(f64::NAN, 0.0, 1.0)).is_none());
        assert!(unit(Vector3::new(1e-300, 0.0, 0.0)).is_none());
        let u = unit(Vector3::new(1e-9, 0.0, 0.0)).unwrap();
        assert!((u.norm() - 1.0).abs() < 1e-12);
        let u = unit(Vector3::new(1e300, 1e300, 0.0)).unwrap();
        assert!((u.norm() - 1.0).abs() < 1e-12);
    }

    /// [`unit`] as it was written first: the reference for its bits.
    fn unit_reference(v: Vector3<f64>) -> Option<Unit<Vector3<f64>>> {
        let m = v.amax();
        if !(m.is_finite() && m > 1e-12) {
            return None;
        }
        let u = Unit::new_normalize(v / m);
        u.iter().all(|c| c.is_finite()).then_some(u)
    }

    fn same_unit(v: Vector3<f64>) -> Result<(), proptest::test_runner::TestCaseError> {
        let bits = |u: Option<Unit<Vector3<f64>>>| u.map(|u| u.map(f64::to_bits));
        proptest::prop_assert_eq!(bits(unit(v)), bits(unit_reference(v)), "{:?}", v);
        Ok(())
    }

    /// A component as CL files and worse inputs have them: printed unit-vector parts,
    /// zeros of both signs, tiny, huge and not finite values, and any bits.
    fn component() -> impl proptest::strategy::Strategy<Value = f64> {
        use proptest::prelude::*;
        prop_oneof![
            (-1.0f64..1.0, 0usize..12).prop_map(|(c, d)| format!("{c:.d$}").parse().unwrap()),
            -1.0f64..1.0,
            -1e6f64..1e6,
            -1e-10f64..1e-10,
            proptest::sample::select(vec![
                0.0,
                -0.0,
                1.0,
                -1.0,
                0.5,
                1e-12,
                -1e-12,
                1.000000000001e-12,
                f64::MIN_POSITIVE,
                5e-324,
                f64::MAX,
                -f64::MAX,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NAN,
            ]),
            any::<u64>().prop_map(f64::from_bits),
        ]
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 20_000, ..Default::default() })]

        /// Bit for bit the first [`unit`], `None` included.
        #[test]
        fn unit_is_the_reference_bit_for_bit(x in component(), y in component(), z in component()) {
            same_unit(Vector3::new(x, y, z))?;
        }

        /// Printed unit vectors (the tool axes of 5-axis CL files), their sign flips and
        /// permutations.
        #[test]
        fn printed_axes_are_the_reference_bit_for_bit(
            a in -std::f64::consts::PI..std::f64::consts::PI,
            b in 0.0..std::f64::consts::PI,
            d in 3usize..12,
        ) {
            let p = |c: f64| -> f64 { format!("{c:.d$}").parse().unwrap() };
            let (x, y, z) = (p(b.sin() * a.cos()), p(b.sin() * a.sin()), p(b.cos()));
            for v in [[x, y, z], [y, z, x], [z, x, y], [-x, y, -z], [x, -y, z]] {
                same_unit(Vector3::from(v))?;
            }
        }
    }
}
