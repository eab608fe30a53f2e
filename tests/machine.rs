//! The machine model: the seed's formulas (seeds/000, E-moc X5) against our kinematics,
//! and FK(IK(pose)) = pose for every built-in machine.

use nalgebra::{Point3, Unit, Vector3};
use ncpost::machine::Machine;
use ncpost::preset::Preset;
use proptest::prelude::*;

fn machine(file: &str) -> Machine {
    let text = std::fs::read_to_string(format!("passes/{file}.toml")).unwrap();
    Preset::from_toml(&text).unwrap().machine.unwrap()
}

const PRESETS: [&str; 4] = ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"];

/// The seed's X, Y, Z formulas exactly as printed (degrees in, az = 100 mm).
fn seed_xyz(p: [f64; 3], a_deg: f64, c_deg: f64) -> [f64; 3] {
    let az = 100.0;
    let (sa, ca) = a_deg.to_radians().sin_cos();
    let (sc, cc) = c_deg.to_radians().sin_cos();
    let [px, py, pz] = p;
    let x = (sc * py + cc * px) / (sc * sc + cc * cc);
    let den = (sa * sa + ca * ca) * sc * sc + cc * cc * sa * sa + ca * ca * cc * cc;
    let y = -(-(sa * sc * sc * pz) - cc * cc * sa * pz - ca * cc * py
        + ca * sc * px
        + (sa * sc * sc + cc * cc * sa) * az)
        / den;
    let z = (ca * sc * sc * pz + ca * cc * cc * pz - cc * sa * py
        + sa * sc * px
        + ((sa * sa + ca * ca - ca) * sc * sc + cc * cc * sa * sa + (ca * ca - ca) * cc * cc) * az)
        / den;
    [x, y, z]
}

/// The seed's printed angle formulas: A = acos(Tz), C = sgn(Ty) acos(Ty / |Txy|).
fn seed_angles(t: &Vector3<f64>) -> (f64, f64) {
    let a = t.z.acos().to_degrees();
    let sgn = if t.y >= 0.0 { 1.0 } else { -1.0 };
    let c = sgn * (t.y / (t.x * t.x + t.y * t.y).sqrt()).acos().to_degrees();
    (a, c)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// The seed's X/Y/Z part is our forward kinematics for random (A, C, P).
    #[test]
    fn seed_xyz_is_our_linear_transform(
        a in -90.0f64..135.0, c in -720.0f64..720.0,
        px in -150.0f64..150.0, py in -150.0f64..150.0, pz in -50.0f64..150.0,
    ) {
        let m = machine("emoc-x5");
        let seed = seed_xyz([px, py, pz], a, c);
        let ours = m.linear(&Point3::new(px, py, pz), [a, c]);
        for k in 0..3 {
            prop_assert!(close(seed[k], ours[k], 1e-9), "{seed:?} vs {ours:?}");
        }
        let back = m.forward(&ours, [a, c]);
        prop_assert!((back.tip - Point3::new(px, py, pz)).norm() < 1e-9);
    }

    /// FK(IK(pose)) = pose for every preset and random reachable poses, both solutions.
    #[test]
    fn fk_of_ik_is_the_pose(
        which in 0usize..4, theta in 0.5f64..179.5, phi in -180.0f64..180.0,
        px in -100.0f64..100.0, py in -100.0f64..100.0, pz in -50.0f64..100.0,
    ) {
        let m = machine(PRESETS[which]);
        let (st, ct) = theta.to_radians().sin_cos();
        let (sp, cp) = phi.to_radians().sin_cos();
        let axis = Unit::new_normalize(Vector3::new(st * cp, st * sp, ct));
        let tip = Point3::new(px, py, pz);
        prop_assume!(m.singularity_distance(axis) > 1e-3);
        let sols = m.inverse(axis);
        for s in &sols {
            let xyz = m.linear(&tip, s.angles);
            let pose = m.forward(&xyz, s.angles);
            prop_assert!((pose.tip - tip).norm() < 1e-9, "tip {:?} vs {:?}", pose.tip, tip);
            for k in 0..3 {
                prop_assert!(close(pose.axis[k], axis[k], 1e-9), "{} axis {:?} vs {:?} at {:?}", PRESETS[which], pose.axis, axis, s.angles);
            }
        }
    }
}

/// The printed C formula does not align the tool axis; ours does, for both solutions.
#[test]
fn seed_c_formula_misaligns_the_tool_axis_ours_does_not() {
    let m = machine("emoc-x5");
    let mut seed_worst = 0.0f64;
    for (i, &(tx, ty, tz)) in [
        (0.3, 0.4, 0.866),
        (-0.5, 0.2, 0.84),
        (0.1, -0.7, 0.707),
        (0.6, 0.0, 0.8),
    ]
    .iter()
    .enumerate()
    {
        let axis = Unit::new_normalize(Vector3::new(tx, ty, tz));
        let (a, c) = seed_angles(&axis);
        let seed_pose = m.forward(&[0.0, 0.0, 0.0], [a, c]);
        let err = seed_pose.axis.angle(&axis).to_degrees();
        seed_worst = seed_worst.max(err);
        let sols = m.inverse(axis);
        assert_eq!(sols.len(), 2, "case {i}");
        for s in &sols {
            let pose = m.forward(&[0.0, 0.0, 0.0], s.angles);
            assert!(pose.axis.angle(&axis) < 1e-12, "case {i}: {:?}", s.angles);
        }
        // The consistent pair: A = acos(Tz), C = atan2(Tx, -Ty); and -A, C + 180.
        let c_consistent = tx.atan2(-ty).to_degrees();
        assert!(
            sols.iter()
                .any(|s| close(s.angles[0], a, 1e-9) && close(s.angles[1], c_consistent, 1e-9))
        );
        assert!(sols.iter().any(|s| close(s.angles[0], -a, 1e-9)
            && close(
                ((s.angles[1] - c_consistent - 180.0) % 360.0 + 360.0) % 360.0,
                0.0,
                1e-9
            ) | close(
                ((s.angles[1] - c_consistent - 180.0) % 360.0 + 360.0) % 360.0,
                360.0,
                1e-9
            )));
    }
    assert!(
        seed_worst > 10.0,
        "the printed C formula misaligns by {seed_worst} deg at most"
    );
}

/// Exactly vertical: C is free, A is 0.
#[test]
fn vertical_tool_is_singular() {
    let m = machine("emoc-x5");
    let sols = m.inverse(Vector3::z_axis());
    assert_eq!(sols.len(), 1);
    assert_eq!(sols[0].free, Some(1));
    assert!(sols[0].angles[0].abs() < 1e-12);
    assert_eq!(m.singular_rotary(Vector3::z_axis()), 1);
    let held = m.hold(Vector3::z_axis(), 1, 37.0);
    assert!(held.angles[0].abs() < 1e-12 && held.angles[1] == 37.0);
}

/// `ncpost machine config-g --preset emoc-x5`: drivers, limits, speeds, accelerations.
#[test]
fn config_g_fragment() {
    let m = machine("emoc-x5");
    let text = m.config_g();
    insta::assert_snapshot!(text);
}

/// Calibration offsets (bed.g): the joint value at the true zero. Every solution shifts
/// by exactly the offsets, and FK(IK(pose)) = pose still holds.
#[test]
fn zero_offsets_shift_the_joint_values() {
    let plain = machine("emoc-x5");
    let mut calibrated = plain.clone();
    calibrated.rotary[0].zero_offset = 0.35;
    calibrated.rotary[1].zero_offset = -1.2;
    let tip = Point3::new(12.0, -7.0, 20.0);
    for (tilt, az) in [(30.0f64, 10.0f64), (100.0, -135.0), (5.0, 170.0)] {
        let (st, ct) = tilt.to_radians().sin_cos();
        let (sa, ca) = az.to_radians().sin_cos();
        let axis = Unit::new_normalize(Vector3::new(st * ca, st * sa, ct));
        let a = plain.inverse(axis);
        let b = calibrated.inverse(axis);
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(&b) {
            assert!(close(y.angles[0] - x.angles[0], 0.35, 1e-9));
            let dc = (y.angles[1] - x.angles[1] + 1.2).rem_euclid(360.0);
            assert!(!(1e-9..=360.0 - 1e-9).contains(&dc), "{x:?} {y:?}");
            let xyz = calibrated.linear(&tip, y.angles);
            let pose = calibrated.forward(&xyz, y.angles);
            assert!((pose.tip - tip).norm() < 1e-9);
            assert!(
                (pose.axis.into_inner() - axis.into_inner()).norm() < 1e-9,
                "{tilt} {az} {y:?}"
            );
            // The same physical position: the machine coordinates agree.
            assert!(
                (Vector3::from(xyz) - Vector3::from(plain.linear(&tip, x.angles))).norm() < 1e-9
            );
        }
    }
}
