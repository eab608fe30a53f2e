//! The `ik`, `unwrap-rotary` and `limits` passes: solution choice (continuity, preference,
//! limits), singularities, unreachable poses and flips on the E-moc X5, FK(joints) = pose
//! on every preset, continuous C, G92 re-basing through the RepRapFirmware backend, limit
//! errors; before/after snapshots.

use nalgebra::{Point3, Unit, Vector3};
use ncpost::back::{Backend, rrf};
use ncpost::diag::{Diagnostic, Severity};
use ncpost::ir::{
    Axis, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind, OffsetCode, Pose, Span,
    Target, dump,
};
use ncpost::machine::{Machine, ToolPose};
use ncpost::passes::{self, Context};
use ncpost::preset::Preset;
use proptest::prelude::*;

mod common;

const PRESETS: [&str; 4] = ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"];

fn preset(name: &str) -> Preset {
    let text = std::fs::read_to_string(format!("passes/{name}.toml")).expect("preset file");
    Preset::from_toml(&text).expect("preset")
}

fn machine(name: &str) -> Machine {
    preset(name).machine.expect("machine")
}

fn span(line: u32) -> Span {
    Span {
        offset: line as u64 * 10,
        len: 5,
        line,
    }
}

fn feed() -> Feed {
    Feed {
        mode: FeedMode::PerMinute,
        rate: Some(800.0),
    }
}

/// The E-moc X5's tool axis in the part frame for joint values A, C (degrees).
fn emoc_axis(a: f64, c: f64) -> Unit<Vector3<f64>> {
    let (sa, ca) = a.to_radians().sin_cos();
    let (sc, cc) = c.to_radians().sin_cos();
    Unit::new_normalize(Vector3::new(sa * sc, -sa * cc, ca))
}

/// The tool axis tilted `deg` from vertical towards -Y (positive) or +Y (negative): the
/// YZ plane.
fn yz_axis(deg: f64) -> Unit<Vector3<f64>> {
    let (s, c) = deg.to_radians().sin_cos();
    Unit::new_normalize(Vector3::new(0.0, -s, c))
}

fn pose_block(line: u32, kind: MotionKind, tip: [f64; 3], axis: Unit<Vector3<f64>>) -> Block {
    Block::new(
        span(line),
        BlockKind::Motion(Motion {
            kind,
            target: Target::Pose(Pose::new(Point3::from(tip), axis)),
            feed: feed(),
            written: ncpost::ir::AxisSet::XYZ,
            machine_frame: false,
            extra: String::new(),
        }),
    )
}

fn joint_block(line: u32, kind: MotionKind, values: &[(Axis, f64)]) -> Block {
    let mut j = Joints::default();
    for &(a, v) in values {
        j.set(a, v);
    }
    Block::new(
        span(line),
        BlockKind::Motion(Motion {
            kind,
            target: Target::Joints(j),
            feed: feed(),
            written: j.known,
            machine_frame: false,
            extra: String::new(),
        }),
    )
}

fn run(
    name: &str,
    options: &str,
    m: Option<&Machine>,
    blocks: Vec<Block>,
) -> (Vec<Block>, Vec<Diagnostic>) {
    let opts: toml::Table = toml::from_str(options).expect("options");
    let ctx = Context {
        machine: m,
        decimals: None,
        ..Context::default()
    };
    common::run_pass(name, &opts, &ctx, blocks)
}

fn motion(b: &Block) -> &Motion {
    match &b.kind {
        BlockKind::Motion(m) => m,
        other => panic!("not a motion: {other:?}"),
    }
}

fn joints_of(b: &Block) -> Joints {
    *motion(b).target.joints().expect("joint target")
}

fn five(m: &Machine, j: &Joints) -> ([f64; 3], [f64; 2]) {
    let [r0, r1] = m.rotary_axes();
    let v = |a: Axis| j.get(a).expect("known axis");
    ([v(Axis::X), v(Axis::Y), v(Axis::Z)], [v(r0), v(r1)])
}

fn fk(m: &Machine, j: &Joints) -> ToolPose {
    let (xyz, a) = five(m, j);
    m.forward(&xyz, a)
}

/// The angle between two unit vectors, degrees (atan2: exact for tiny angles, unlike acos).
fn axis_angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.cross(b).norm().atan2(a.dot(b)).to_degrees()
}

/// A joint block putting the E-moc X5's tip on `tip` with the rotaries at A, C.
fn emoc_joints(line: u32, m: &Machine, tip: [f64; 3], a: f64, c: f64) -> Block {
    let xyz = m.linear(&Point3::from(tip), [a, c]);
    joint_block(
        line,
        MotionKind::Linear,
        &[
            (Axis::X, xyz[0]),
            (Axis::Y, xyz[1]),
            (Axis::Z, xyz[2]),
            (Axis::A, a),
            (Axis::C, c),
        ],
    )
}

fn ac(j: &Joints) -> (f64, f64) {
    (j.get(Axis::A).expect("A"), j.get(Axis::C).expect("C"))
}

fn codes(diags: &[Diagnostic]) -> Vec<&'static str> {
    diags.iter().map(|d| d.code).collect()
}

fn dump_all(blocks: &[Block]) -> String {
    let mut s = String::new();
    for b in blocks {
        dump::write_block(&mut s, b);
        s.push('\n');
    }
    s
}

// ---------------------------------------------------------------- ik

#[test]
fn ik_keeps_c_through_vertical_and_a_changes_sign() {
    let m = machine("emoc-x5");
    let tilts: Vec<f64> = (0..=12).map(|k| 30.0 - 5.0 * k as f64).collect();
    let blocks = tilts
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            pose_block(
                i as u32 + 1,
                MotionKind::Linear,
                [0.0, 10.0 * i as f64, 20.0],
                yz_axis(t),
            )
        })
        .collect();
    let (out, diags) = run("ik", "", Some(&m), blocks);
    assert!(diags.is_empty(), "{diags:?}");
    assert_eq!(out.len(), tilts.len());
    for (b, &t) in out.iter().zip(&tilts) {
        let j = joints_of(b);
        let (a, c) = ac(&j);
        assert!(c.abs() < 1e-9, "C stays 0, got {c} at tilt {t}");
        assert!((a - t).abs() < 1e-9, "A = {a}, tilt {t}");
        let pose = fk(&m, &j);
        assert!(axis_angle_deg(&pose.axis, &yz_axis(t)) < 1e-9);
    }
    let first = ac(&joints_of(&out[0])).0;
    let last = ac(&joints_of(&out[out.len() - 1])).0;
    assert!(first > 0.0 && last < 0.0);
}

/// Axes a pose carries besides the tip and the tool axis (an extruder, a secondary
/// linear) come out as joints beside the five the kinematics computes; a pose cannot
/// override X, Y, Z or the rotaries that way.
#[test]
fn ik_keeps_the_axes_a_pose_carries_besides_the_tool() {
    let m = machine("emoc-x5");
    let mut block = pose_block(1, MotionKind::Linear, [1.0, 2.0, 3.0], yz_axis(20.0));
    let mut extra = Joints::default();
    extra.set(Axis::E, 4.5);
    extra.set(Axis::X, 99.0);
    if let BlockKind::Motion(Motion {
        target: Target::Pose(p),
        ..
    }) = &mut block.kind
    {
        p.extra_axes = Some(Box::new(extra));
    }
    let (out, diags) = run("ik", "", Some(&m), vec![block]);
    assert!(diags.is_empty(), "{diags:?}");
    let j = joints_of(&out[0]);
    assert_eq!(j.get(Axis::E), Some(4.5));
    let pose = fk(&m, &j);
    assert!(
        (pose.tip - Point3::new(1.0, 2.0, 3.0)).norm() < 1e-9,
        "{pose:?}"
    );
}

#[test]
fn ik_first_block_takes_the_preferred_sign() {
    let m = machine("emoc-x5");
    let axis = emoc_axis(-40.0, 30.0); // also (40, 210)
    let (out, _) = run(
        "ik",
        "",
        Some(&m),
        vec![pose_block(1, MotionKind::Rapid, [5.0, 5.0, 30.0], axis)],
    );
    let (a, c) = ac(&joints_of(&out[0]));
    assert!((a - 40.0).abs() < 1e-9, "prefer = positive: A = {a}");
    assert!((c - -150.0).abs() < 1e-9, "C = {c}");

    let mut neg = m.clone();
    neg.rotary[0].prefer = ncpost::machine::Prefer::Negative;
    let (out, _) = run(
        "ik",
        "",
        Some(&neg),
        vec![pose_block(1, MotionKind::Rapid, [5.0, 5.0, 30.0], axis)],
    );
    let (a, c) = ac(&joints_of(&out[0]));
    assert!((a - -40.0).abs() < 1e-9 && (c - 30.0).abs() < 1e-9);
}

#[test]
fn ik_limits_force_the_positive_solution_beyond_90() {
    let m = machine("emoc-x5");
    // A machine preferring negative A still gets A = +100: -100 is below -90.
    let mut neg = m.clone();
    neg.rotary[0].prefer = ncpost::machine::Prefer::Negative;
    let (out, diags) = run(
        "ik",
        "",
        Some(&neg),
        vec![pose_block(
            1,
            MotionKind::Rapid,
            [0.0, 0.0, 10.0],
            yz_axis(100.0),
        )],
    );
    assert!(diags.is_empty());
    let (a, _) = ac(&joints_of(&out[0]));
    assert!((a - 100.0).abs() < 1e-9, "A = {a}");

    // Continuity would keep the negative branch (A -60 -> -100), which is out of range:
    // a rapid takes the other solution.
    let (out, diags) = run(
        "ik",
        "",
        Some(&m),
        vec![
            emoc_joints(1, &m, [0.0, 0.0, 10.0], -60.0, 0.0),
            pose_block(
                2,
                MotionKind::Rapid,
                [0.0, 0.0, 10.0],
                emoc_axis(-100.0, 0.0),
            ),
        ],
    );
    assert!(diags.is_empty(), "{diags:?}");
    assert_eq!(ac(&joints_of(&out[0])), (-60.0, 0.0));
    let (a, c) = ac(&joints_of(&out[1]));
    assert!((a - 100.0).abs() < 1e-9 && (c.abs() - 180.0).abs() < 1e-9);
    for (b, want) in out
        .iter()
        .zip([emoc_axis(-60.0, 0.0), emoc_axis(-100.0, 0.0)])
    {
        assert!(axis_angle_deg(&fk(&m, &joints_of(b)).axis, &want) < 1e-9);
    }
}

#[test]
fn ik_holds_c_at_the_singularity_and_warns_on_the_swing() {
    let m = machine("emoc-x5");
    let blocks = vec![
        pose_block(
            1,
            MotionKind::Linear,
            [0.0, 0.0, 5.0],
            emoc_axis(30.0, 45.0),
        ),
        pose_block(2, MotionKind::Linear, [1.0, 0.0, 5.0], emoc_axis(0.0, 0.0)),
        // 0.005 deg off vertical, at another azimuth: still inside the 0.01 deg cone.
        pose_block(
            3,
            MotionKind::Linear,
            [2.0, 0.0, 5.0],
            emoc_axis(0.005, 170.0),
        ),
        // Out of the cone at C = 120: C swings 75 degrees while cutting.
        pose_block(
            4,
            MotionKind::Linear,
            [3.0, 0.0, 5.0],
            emoc_axis(5.0, 120.0),
        ),
        // Through vertical again, leaving with a small C change: no warning.
        pose_block(5, MotionKind::Linear, [4.0, 0.0, 5.0], emoc_axis(0.0, 0.0)),
        pose_block(
            6,
            MotionKind::Linear,
            [5.0, 0.0, 5.0],
            emoc_axis(5.0, 125.0),
        ),
    ];
    let (all, diags) = run("ik", "", Some(&m), blocks);
    // The swing leaving the cone is spread over pieces before line 4's own block; each
    // line's last block is the one at its pose.
    let out: Vec<Block> = (1..=6)
        .filter_map(|line| all.iter().rev().find(|b| b.span.line == line).cloned())
        .collect();
    assert_eq!(out.len(), 6);
    let j: Vec<(f64, f64)> = out.iter().map(|b| ac(&joints_of(b))).collect();
    assert!((j[0].0 - 30.0).abs() < 1e-9 && (j[0].1 - 45.0).abs() < 1e-9);
    assert!(
        j[1].0.abs() < 1e-9 && (j[1].1 - 45.0).abs() < 1e-12,
        "{:?}",
        j[1]
    );
    assert!(
        (j[2].1 - 45.0).abs() < 1e-12,
        "held within the cone: {:?}",
        j[2]
    );
    assert!(j[2].0.abs() < 0.006);
    assert!(
        (j[3].1 - 120.0).abs() < 1e-9 && (j[3].0 - 5.0).abs() < 1e-9,
        "{:?}",
        j
    );
    assert!((j[4].1 - 120.0).abs() < 1e-12);
    assert!((j[5].1 - 125.0).abs() < 1e-9);
    assert_eq!(codes(&diags), vec!["ik::singular-swing"]);
    let d = &diags[0];
    assert_eq!(d.severity, Severity::Warning);
    assert_eq!(d.location.as_ref().map(|l| l.line), Some(4));
    assert!(d.message.contains("C turns 75.000 deg"), "{}", d.message);
    // The tip is exact even where the orientation is held.
    for (b, x) in out.iter().zip(0..) {
        let p = fk(&m, &joints_of(b));
        assert!((p.tip - Point3::new(x as f64, 0.0, 5.0)).norm() < 1e-9);
    }
}

#[test]
fn ik_unreachable_is_an_error_at_each_line_and_the_block_is_dropped() {
    let m = machine("emoc-x5");
    let blocks = vec![
        pose_block(1, MotionKind::Rapid, [0.0, 0.0, 50.0], emoc_axis(20.0, 0.0)),
        pose_block(
            2,
            MotionKind::Linear,
            [0.0, 0.0, 40.0],
            emoc_axis(145.0, 30.0),
        ),
        pose_block(
            3,
            MotionKind::Linear,
            [0.0, 0.0, 40.0],
            emoc_axis(150.0, 60.0),
        ),
        pose_block(
            4,
            MotionKind::Linear,
            [0.0, 0.0, 40.0],
            emoc_axis(25.0, 0.0),
        ),
    ];
    let (out, diags) = run("ik", "", Some(&m), blocks);
    assert_eq!(codes(&diags), vec!["ik::unreachable", "ik::unreachable"]);
    let lines: Vec<u32> = out.iter().map(|b| b.span.line).collect();
    assert_eq!(lines, vec![1, 4]);
    assert_eq!(diags[0].location.as_ref().map(|l| l.line), Some(2));
    assert!(
        diags[0].message.contains("10.000 deg from the nearest"),
        "{}",
        diags[0].message
    );
    assert!(diags[1].message.contains("15.000 deg from the nearest"));
    assert!(diags[0].help.is_some());
}

/// A cutting move that continues the negative-A branch past -90: the other solution is
/// 180 degrees of C away.
fn flip_program(m: &Machine) -> Vec<Block> {
    vec![
        emoc_joints(1, m, [0.0, 10.0, 30.0], -70.0, 0.0),
        pose_block(
            2,
            MotionKind::Linear,
            [0.0, 12.0, 30.0],
            emoc_axis(-85.0, 0.0),
        ),
        pose_block(
            3,
            MotionKind::Linear,
            [0.0, 14.0, 30.0],
            emoc_axis(-95.0, 0.0),
        ),
    ]
}

#[test]
fn ik_flip_is_an_error_by_default() {
    let m = machine("emoc-x5");
    let (out, diags) = run("ik", "", Some(&m), flip_program(&m));
    assert_eq!(codes(&diags), vec!["ik::flip"]);
    let d = &diags[0];
    assert_eq!(d.location.as_ref().map(|l| l.line), Some(3));
    assert!(
        d.message.contains("A would be -95.000 deg"),
        "{}",
        d.message
    );
    assert_eq!(
        d.help.as_deref(),
        Some(
            "set `on_flip = \"retract\"` in the preset's ik options to retract, rotate and re-engage"
        )
    );
    assert_eq!(out.len(), 3);
}

#[test]
fn ik_flip_retracts_rotates_and_plunges() {
    let m = machine("emoc-x5");
    let (out, diags) = run(
        "ik",
        "on_flip = \"retract\"\nretract_distance = 15.0\nclearance = 150.0",
        Some(&m),
        flip_program(&m),
    );
    assert_eq!(codes(&diags), vec!["ik::retract"]);
    assert_eq!(diags[0].severity, Severity::Warning);
    assert_eq!(out.len(), 8);
    assert!(out[2..].iter().all(|b| b.span.line == 3));
    let kinds: Vec<MotionKind> = out.iter().map(|b| motion(b).kind).collect();
    use MotionKind::{Linear, Rapid};
    assert_eq!(kinds[2..], [Linear, Rapid, Rapid, Rapid, Rapid, Linear]);
    let j: Vec<Joints> = out.iter().map(joints_of).collect();
    let xyz = |k: usize| [Axis::X, Axis::Y, Axis::Z].map(|a| j[k].get(a).expect("known"));
    let before = fk(&m, &j[1]);
    let retract = fk(&m, &j[2]);
    let new_axis = emoc_axis(-95.0, 0.0);
    let new_tip = Point3::new(0.0, 14.0, 30.0);
    // (a) straight up the old tool axis, orientation unchanged.
    assert!((retract.tip - (before.tip + before.axis.into_inner() * 15.0)).norm() < 1e-9);
    assert!(axis_angle_deg(&retract.axis, &before.axis) < 1e-9);
    assert_eq!(ac(&j[2]), ac(&j[1]));
    // (b) Z alone up to the clearance.
    assert_eq!(ac(&j[3]), ac(&j[2]));
    assert_eq!(xyz(3)[..2], xyz(2)[..2]);
    assert_eq!(xyz(3)[2], 150.0);
    // (c) the rotaries alone turn, to the other solution.
    assert_eq!(xyz(4), xyz(3));
    let (a, c) = ac(&j[4]);
    assert!((a - 95.0).abs() < 1e-9 && (c.abs() - 180.0).abs() < 1e-9);
    // (d) across at the clearance to the new point's X and Y.
    assert_eq!(ac(&j[5]), (a, c));
    assert_eq!(xyz(5)[2], 150.0);
    assert_eq!(xyz(5)[..2], xyz(6)[..2]);
    // (e) down to 15 mm above the new point along the new tool axis.
    let lowered = fk(&m, &j[6]);
    assert!((lowered.tip - (new_tip + new_axis.into_inner() * 15.0)).norm() < 1e-9);
    assert!(axis_angle_deg(&lowered.axis, &new_axis) < 1e-9);
    // (f) the block's move plunges down the new tool axis onto the target, at its feed.
    let plunge = fk(&m, &j[7]);
    assert!((plunge.tip - new_tip).norm() < 1e-9);
    assert!(axis_angle_deg(&plunge.axis, &new_axis) < 1e-9);
    assert_eq!(ac(&j[7]), (a, c));
    assert_eq!(motion(&out[7]).feed, feed());
    assert_eq!(motion(&out[2]).feed, feed());
}

#[test]
fn ik_flip_without_a_safe_height_is_not_retracted() {
    // No clearance and no Z travel (the preset's would be the safe height): turning the
    // table at the retract point could sweep
    // the part into the tool, so the flip stays an error that says what is missing.
    let mut m = machine("emoc-x5");
    m.linear = None;
    let (_, diags) = run("ik", "on_flip = \"retract\"", Some(&m), flip_program(&m));
    assert_eq!(codes(&diags), vec!["ik::flip"]);
    assert!(
        diags[0]
            .help
            .as_deref()
            .is_some_and(|h| h.contains("clearance")),
        "{:?}",
        diags[0].help
    );
}

#[test]
fn ik_passes_joints_through_and_forgets_clobbered_axes() {
    let m = machine("emoc-x5");
    let blocks = vec![
        joint_block(
            1,
            MotionKind::Rapid,
            &[
                (Axis::X, 0.0),
                (Axis::Y, 0.0),
                (Axis::Z, 50.0),
                (Axis::A, -30.0),
                (Axis::C, 720.0),
            ],
        ),
        // Continuity from C = 720: the solution (-30, 720 + 10) wins over (30, 190).
        pose_block(
            2,
            MotionKind::Linear,
            [0.0, 0.0, 20.0],
            emoc_axis(-30.0, 10.0),
        ),
        Block::new(
            span(3),
            BlockKind::Command(ncpost::ir::Command {
                text: "G28".into(),
                modes: None,
                clobbers: ncpost::ir::AxisSet::ALL,
            }),
        ),
        // Nothing known: the preferred sign decides again.
        pose_block(
            4,
            MotionKind::Rapid,
            [0.0, 0.0, 20.0],
            emoc_axis(-30.0, 10.0),
        ),
    ];
    let (out, diags) = run("ik", "", Some(&m), blocks);
    assert!(diags.is_empty());
    assert_eq!(ac(&joints_of(&out[0])), (-30.0, 720.0));
    let (a, c) = ac(&joints_of(&out[1]));
    assert!(
        (a + 30.0).abs() < 1e-9 && (c - 730.0).abs() < 1e-9,
        "{a} {c}"
    );
    let (a, c) = ac(&joints_of(&out[3]));
    assert!(
        (a - 30.0).abs() < 1e-9 && (c + 170.0).abs() < 1e-9,
        "{a} {c}"
    );
    let w = motion(&out[1]).written;
    assert!(
        [Axis::X, Axis::Y, Axis::Z, Axis::A, Axis::C]
            .iter()
            .all(|&x| w.contains(x))
    );
}

#[test]
fn ik_needs_a_machine_and_rejects_unknown_options() {
    let ctx = Context::default();
    assert!(passes::build("ik", &toml::Table::new(), &ctx).is_err());
    let m = machine("emoc-x5");
    let ctx = Context {
        machine: Some(&m),
        decimals: None,
        ..Context::default()
    };
    let bogus: toml::Table = toml::from_str("cone = 1.0").unwrap();
    assert!(passes::build("ik", &bogus, &ctx).is_err());
    let bad: toml::Table = toml::from_str("on_flip = \"ignore\"").unwrap();
    assert!(passes::build("ik", &bad, &ctx).is_err());
}

fn unit_from(theta: f64, phi: f64) -> Unit<Vector3<f64>> {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    Unit::new_normalize(Vector3::new(st * cp, st * sp, ct))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// On every preset: FK(joints) reproduces each pose (tip always, axis within 1e-9 outside
    /// the singularity cone), and every rotary value is within its limits.
    #[test]
    fn ik_fk_of_joints_is_the_pose(
        preset_index in 0usize..4,
        steps in prop::collection::vec(
            ((-150.0f64..150.0, -150.0f64..150.0, -50.0f64..150.0),
             0.0f64..std::f64::consts::PI, -std::f64::consts::PI..std::f64::consts::PI,
             any::<bool>()),
            1..25),
    ) {
        let m = machine(PRESETS[preset_index]);
        let poses: Vec<(Point3<f64>, Unit<Vector3<f64>>)> = steps
            .iter()
            .map(|&((x, y, z), th, ph, _)| (Point3::new(x, y, z), unit_from(th, ph)))
            .collect();
        let blocks = steps
            .iter()
            .zip(&poses)
            .enumerate()
            .map(|(i, (s, p))| {
                let kind = if s.3 { MotionKind::Rapid } else { MotionKind::Linear };
                pose_block(i as u32 + 1, kind, p.0.coords.into(), p.1)
            })
            .collect();
        let (out, diags) = run("ik", "", Some(&m), blocks);
        let unreachable: Vec<u32> = diags
            .iter()
            .filter(|d| d.code == "ik::unreachable")
            .filter_map(|d| d.location.as_ref().map(|l| l.line))
            .collect();
        for (i, (tip, axis)) in poses.iter().enumerate() {
            let line = i as u32 + 1;
            let last = out.iter().rev().find(|b| b.span.line == line);
            let Some(b) = last else {
                prop_assert!(unreachable.contains(&line));
                continue;
            };
            let j = joints_of(b);
            let got = fk(&m, &j);
            prop_assert!((got.tip - tip).norm() < 1e-9, "tip {:?} vs {:?}", got.tip, tip);
            let err = axis_angle_deg(&got.axis, axis);
            if m.singularity_distance(*axis) >= 0.01 {
                prop_assert!(err < 1e-9 * 57.3, "axis off by {err} deg");
            } else {
                prop_assert!(err < 0.02, "held axis off by {err} deg");
            }
            for a in m.rotary_axes() {
                if let Some((lo, hi)) = m.limits(a) {
                    let v = j.get(a).unwrap();
                    prop_assert!(v >= lo - 1e-9 && v <= hi + 1e-9, "{a:?} = {v}");
                }
            }
        }
    }
}

// ---------------------------------------------------------------- unwrap-rotary

fn wrap180(d: f64) -> f64 {
    let mut d = d % 360.0;
    if d <= -180.0 {
        d += 360.0;
    } else if d > 180.0 {
        d -= 360.0;
    }
    d
}

fn c_block(line: u32, kind: MotionKind, x: f64, c: f64) -> Block {
    joint_block(line, kind, &[(Axis::X, x), (Axis::C, c)])
}

#[test]
fn unwrap_ten_turns_of_c() {
    let blocks: Vec<Block> = (0..=360)
        .map(|k| {
            c_block(
                k + 1,
                MotionKind::Linear,
                k as f64,
                wrap180(10.0 * k as f64),
            )
        })
        .collect();
    for m in [None, Some(machine("emoc-x5"))] {
        let (out, diags) = run("unwrap-rotary", "", m.as_ref(), blocks.clone());
        assert!(diags.is_empty());
        for (k, b) in out.iter().enumerate() {
            let c = joints_of(b).get(Axis::C).unwrap();
            assert!((c - 10.0 * k as f64).abs() < 1e-9, "block {k}: C = {c}");
        }
        // Idempotent.
        let (again, _) = run("unwrap-rotary", "", m.as_ref(), out.clone());
        assert_eq!(again, out);
    }
}

#[test]
fn unwrap_wraps_limited_axes_into_range_and_other_axes_by_option() {
    let m = machine("emoc-x5");
    let (out, _) = run(
        "unwrap-rotary",
        "",
        Some(&m),
        vec![
            joint_block(1, MotionKind::Rapid, &[(Axis::A, 300.0), (Axis::C, 0.0)]),
            joint_block(2, MotionKind::Rapid, &[(Axis::A, 100.0), (Axis::C, 0.0)]),
            // No turn of -200 is in -90..135: left for `limits` to report.
            joint_block(3, MotionKind::Rapid, &[(Axis::A, -200.0), (Axis::C, 0.0)]),
        ],
    );
    let a: Vec<f64> = out
        .iter()
        .map(|b| joints_of(b).get(Axis::A).unwrap())
        .collect();
    assert_eq!(a, vec![-60.0, 100.0, -200.0]);

    // Without a machine, `axes` names the cyclic ones.
    let blocks = vec![
        joint_block(1, MotionKind::Linear, &[(Axis::A, 170.0), (Axis::B, 170.0)]),
        joint_block(
            2,
            MotionKind::Linear,
            &[(Axis::A, -170.0), (Axis::B, -170.0)],
        ),
    ];
    let (out, _) = run("unwrap-rotary", "axes = [\"B\"]", None, blocks);
    let j = joints_of(&out[1]);
    assert_eq!(
        (j.get(Axis::A), j.get(Axis::B)),
        (Some(-170.0), Some(190.0))
    );
    let ctx = Context::default();
    let bad: toml::Table = toml::from_str("axes = [\"X\"]").unwrap();
    assert!(passes::build("unwrap-rotary", &bad, &ctx).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    /// Wrapped angles whose true steps are below 180 degrees come out with the true steps.
    #[test]
    fn unwrap_recovers_the_true_steps(
        start in -180.0f64..180.0,
        steps in prop::collection::vec(-179.0f64..179.0, 1..80),
    ) {
        let mut truth = vec![start];
        for s in &steps {
            let last = truth[truth.len() - 1];
            truth.push(last + s);
        }
        let blocks = truth
            .iter()
            .enumerate()
            .map(|(i, &c)| c_block(i as u32 + 1, MotionKind::Linear, 0.0, wrap180(c)))
            .collect();
        let (out, _) = run("unwrap-rotary", "", None, blocks);
        let got: Vec<f64> = out.iter().map(|b| joints_of(b).get(Axis::C).unwrap()).collect();
        for k in 1..got.len() {
            prop_assert!(((got[k] - got[k - 1]) - (truth[k] - truth[k - 1])).abs() < 1e-9);
        }
    }
}

/// Prints `blocks` with the RepRapFirmware backend.
fn rrf_text(blocks: &[Block]) -> String {
    let mut text = Vec::new();
    let mut diags = Vec::new();
    {
        let mut w = rrf::Writer::new(&mut text, &rrf::Options::default());
        for b in blocks {
            w.write_block(b, &mut diags).expect("writes");
        }
        w.finish().expect("finishes");
    }
    assert!(diags.is_empty(), "{diags:?}");
    String::from_utf8(text).expect("utf-8")
}

/// Runs the text on a model controller (G92 declares the current position, moves go to
/// the printed value): the physical C after each move line, and the printed C values.
fn controller_c(text: &str) -> (Vec<f64>, Vec<f64>, usize) {
    let mut user = None::<f64>;
    let mut phys = 0.0;
    let mut after_moves = Vec::new();
    let mut printed = Vec::new();
    let mut g92 = 0;
    for line in text.lines() {
        let words: Vec<&str> = line
            .split(';')
            .next()
            .unwrap_or("")
            .split_whitespace()
            .collect();
        let c = words
            .iter()
            .find_map(|w| w.strip_prefix('C'))
            .map(|v| v.parse::<f64>().expect("number"));
        match words.first().copied() {
            Some("G92") => {
                user = c.or(user);
                g92 += 1;
                printed.extend(c);
            }
            Some("G0" | "G1") => {
                if let Some(v) = c {
                    phys += user.map_or(0.0, |u| v - u);
                    if user.is_none() {
                        phys = v;
                    }
                    user = Some(v);
                    printed.push(v);
                }
                after_moves.push(phys);
            }
            _ => {}
        }
    }
    (after_moves, printed, g92)
}

#[test]
fn rebase_prints_g92_and_keeps_printed_c_small() {
    let m = machine("emoc-x5");
    // Five turns of C in 30 degree steps, wrapped as the seed's post writes them, with a
    // rapid every sixth block.
    let blocks: Vec<Block> = (0..=60)
        .map(|k| {
            let kind = if k % 6 == 5 {
                MotionKind::Rapid
            } else {
                MotionKind::Linear
            };
            c_block(k + 1, kind, k as f64, wrap180(30.0 * k as f64))
        })
        .collect();
    let (out, diags) = run(
        "unwrap-rotary",
        "rebase = true\nrebase_above = 180.0",
        Some(&m),
        blocks,
    );
    assert!(diags.is_empty());
    // The IR stays continuous.
    let ir_c: Vec<f64> = out
        .iter()
        .filter_map(|b| match &b.kind {
            BlockKind::Motion(mo) => mo.target.joints().and_then(|j| j.get(Axis::C)),
            _ => None,
        })
        .collect();
    for (k, c) in ir_c.iter().enumerate() {
        assert!((c - 30.0 * k as f64).abs() < 1e-9);
    }
    // Every G92 comes right before a rapid, with the rapid's span.
    for (i, b) in out.iter().enumerate() {
        if let BlockKind::Offset(o) = &b.kind {
            assert_eq!(o.code, OffsetCode::Set);
            let next = &out[i + 1];
            assert_eq!(motion(next).kind, MotionKind::Rapid);
            assert_eq!(next.span, b.span);
            let d = o.declared.get(Axis::C).unwrap();
            assert!(d > -180.0 && d <= 180.0);
        }
    }
    let text = rrf_text(&out);
    let (phys, printed, g92) = controller_c(&text);
    assert!(g92 >= 3, "{text}");
    // The controller moves C exactly as the continuous IR says.
    assert_eq!(phys.len(), ir_c.len());
    for (p, c) in phys.iter().zip(&ir_c) {
        assert!((p - c).abs() < 1e-3, "controller at {p}, IR {c}\n{text}");
    }
    assert!(printed.iter().all(|v| v.abs() <= 360.0), "{text}");
    // Without re-basing the printed value grows.
    let (plain, _) = run(
        "unwrap-rotary",
        "",
        Some(&m),
        out.iter()
            .filter(|b| !matches!(b.kind, BlockKind::Offset(_)))
            .cloned()
            .collect(),
    );
    let (_, printed, g92) = controller_c(&rrf_text(&plain));
    assert_eq!(g92, 0);
    assert!(printed.iter().any(|v| *v >= 1800.0));
}

#[test]
fn rebase_agrees_with_upstream_g92() {
    // G-code from the seed's hand post: C wrapped, a G92 C10 in the middle.
    let program = "G0 X0 C0\nG1 X1 C120 F500\nG1 C-120\nG1 C0\nG92 C10\nG1 C130\nG1 C-110\nG0 C10\nG1 C130\nG0 C-110\n";
    let parsed =
        ncpost::front::gcode::parse_str(program, &ncpost::front::gcode::Options::default())
            .expect("parses");
    let (out, diags) = run(
        "unwrap-rotary",
        "rebase = true\nrebase_above = 180.0",
        None,
        parsed.blocks.clone(),
    );
    assert!(diags.is_empty(), "{diags:?}");
    let text = rrf_text(&out);
    let (phys, _, g92) = controller_c(&text);
    assert!(g92 >= 2, "{text}");
    // Each step turns 120 degrees forward on the controller.
    let steps: Vec<f64> = phys.windows(2).map(|w| w[1] - w[0]).collect();
    assert_eq!(steps.len(), 8, "{text}");
    for s in &steps {
        assert!((s - 120.0).abs() < 1e-3, "{steps:?}\n{text}");
    }
}

#[test]
fn float32_warning_once_without_rebase() {
    let blocks: Vec<Block> = (0..=700)
        .map(|k| c_block(k + 1, MotionKind::Linear, 0.0, wrap180(170.0 * k as f64)))
        .collect();
    let (_, diags) = run("unwrap-rotary", "", None, blocks);
    assert_eq!(codes(&diags), vec!["unwrap::float32"]);
}

// ---------------------------------------------------------------- limits

#[test]
fn limits_reports_line_axis_and_value() {
    let m = machine("emoc-x5");
    let blocks = vec![
        joint_block(
            7,
            MotionKind::Linear,
            &[
                (Axis::X, 200.0),
                (Axis::Y, 0.0),
                (Axis::Z, 0.0),
                (Axis::A, 140.0),
                (Axis::C, 5000.0),
            ],
        ),
        joint_block(
            8,
            MotionKind::Linear,
            &[(Axis::X, 180.0000005), (Axis::A, 135.0)],
        ),
    ];
    let (out, diags) = run("limits", "", Some(&m), blocks);
    assert_eq!(out.len(), 2);
    assert_eq!(codes(&diags), vec!["limits::range", "limits::range"]);
    assert!(
        diags
            .iter()
            .all(|d| d.location.as_ref().map(|l| l.line) == Some(7))
    );
    assert!(
        diags[0].message.contains("X = 200.0000 mm"),
        "{}",
        diags[0].message
    );
    assert!(diags[0].message.contains("-180..180"));
    assert!(diags[1].message.contains("A = 140.0000 deg"));
    let (_, diags) = run(
        "limits",
        "tolerance = 0.0",
        Some(&m),
        vec![joint_block(
            8,
            MotionKind::Linear,
            &[(Axis::X, 180.0000005)],
        )],
    );
    assert_eq!(diags.len(), 1);
    assert!(passes::build("limits", &toml::Table::new(), &Context::default()).is_err());
}

// ---------------------------------------------------------------- snapshots

/// A short 5-axis cut on the E-moc X5: approach, a tilt through vertical, around the part.
fn snapshot_poses() -> Vec<Block> {
    vec![
        pose_block(
            1,
            MotionKind::Rapid,
            [0.0, -30.0, 60.0],
            emoc_axis(20.0, 0.0),
        ),
        pose_block(
            2,
            MotionKind::Linear,
            [0.0, -30.0, 10.0],
            emoc_axis(20.0, 0.0),
        ),
        pose_block(
            3,
            MotionKind::Linear,
            [0.0, -15.0, 10.0],
            emoc_axis(10.0, 0.0),
        ),
        pose_block(4, MotionKind::Linear, [0.0, 0.0, 10.0], emoc_axis(0.0, 0.0)),
        pose_block(
            5,
            MotionKind::Linear,
            [0.0, 15.0, 10.0],
            emoc_axis(-10.0, 0.0),
        ),
        pose_block(
            6,
            MotionKind::Linear,
            [15.0, 15.0, 10.0],
            emoc_axis(-30.0, 60.0),
        ),
        pose_block(
            7,
            MotionKind::Linear,
            [15.0, -15.0, 10.0],
            emoc_axis(-30.0, 150.0),
        ),
        pose_block(
            8,
            MotionKind::Linear,
            [-15.0, -15.0, 10.0],
            emoc_axis(-30.0, 240.0),
        ),
        pose_block(
            9,
            MotionKind::Rapid,
            [-15.0, -15.0, 60.0],
            emoc_axis(-30.0, 240.0),
        ),
    ]
}

#[test]
fn snapshot_ik() {
    let m = machine("emoc-x5");
    let before = snapshot_poses();
    let (after, diags) = run("ik", "", Some(&m), before.clone());
    assert!(diags.is_empty());
    insta::assert_snapshot!(format!(
        "before:\n{}after:\n{}",
        dump_all(&before),
        dump_all(&after)
    ));
}

#[test]
fn snapshot_unwrap_rotary() {
    let m = machine("emoc-x5");
    // Joints as the seed's hand post prints them: C in -180..180, around the part twice.
    let mut before = Vec::new();
    for k in 0..12u32 {
        let c = wrap180(75.0 * k as f64);
        let kind = if k % 4 == 3 {
            MotionKind::Rapid
        } else {
            MotionKind::Linear
        };
        before.push(joint_block(
            k + 1,
            kind,
            &[
                (Axis::X, k as f64),
                (Axis::Y, 0.0),
                (Axis::Z, 10.0),
                (Axis::A, 30.0),
                (Axis::C, c),
            ],
        ));
    }
    let (after, diags) = run(
        "unwrap-rotary",
        "rebase = true\nrebase_above = 360.0",
        Some(&m),
        before.clone(),
    );
    assert!(diags.is_empty());
    assert!(after.iter().any(|b| matches!(b.kind, BlockKind::Offset(_))));
    insta::assert_snapshot!(format!(
        "before:\n{}after:\n{}rrf:\n{}",
        dump_all(&before),
        dump_all(&after),
        rrf_text(&after)
    ));
}

#[test]
fn snapshot_diagnostics() {
    let m = machine("emoc-x5");
    let mut program = vec![pose_block(
        1,
        MotionKind::Rapid,
        [0.0, 0.0, 50.0],
        emoc_axis(20.0, 0.0),
    )];
    program.push(pose_block(
        2,
        MotionKind::Linear,
        [0.0, 0.0, 40.0],
        emoc_axis(145.0, 30.0),
    ));
    let (_, unreachable) = run("ik", "", Some(&m), program);
    let (_, flip) = run("ik", "", Some(&m), flip_program(&m));
    let (_, limits) = run(
        "limits",
        "",
        Some(&m),
        vec![joint_block(
            4,
            MotionKind::Linear,
            &[
                (Axis::X, 0.0),
                (Axis::Y, -150.0),
                (Axis::Z, 0.0),
                (Axis::A, -95.0),
                (Axis::C, 0.0),
            ],
        )],
    );
    let mut text = String::new();
    for d in unreachable.iter().chain(&flip).chain(&limits) {
        text.push_str(&d.render("part.cl", false));
        text.push('\n');
    }
    insta::assert_snapshot!(text);
}

#[test]
fn limits_sums_up_long_runs_of_blocks_past_a_limit() {
    let m = machine("emoc-x5");
    // 25 blocks below Z's minimum (-60), the worst at line 112; 3 above X's maximum.
    let mut blocks = Vec::new();
    for i in 0..25u32 {
        let z = if i == 12 { -63.5 } else { -61.0 };
        blocks.push(joint_block(100 + i, MotionKind::Linear, &[(Axis::Z, z)]));
    }
    for i in 0..3u32 {
        blocks.push(joint_block(
            200 + i,
            MotionKind::Linear,
            &[(Axis::X, 190.0)],
        ));
    }
    let (out, diags) = run("limits", "max_reported = 10", Some(&m), blocks.clone());
    assert_eq!(out.len(), 28);
    assert!(diags.iter().all(|d| d.code == "limits::range"));
    // 10 Z errors one by one, 3 X errors, and one summary of Z's 25.
    assert_eq!(diags.len(), 14, "{diags:#?}");
    let summary = diags.last().expect("summary");
    assert!(
        summary
            .message
            .contains("on 25 blocks in all (lines 100..124)")
            && summary.message.contains("by 3.5000 mm at worst"),
        "{}",
        summary.message
    );
    assert_eq!(summary.location.as_ref().map(|l| l.line), Some(112));
    // max_reported = 0 (the default): every block, each with its excess, for the run's
    // repeat cap to sum up.
    let (_, diags) = run("limits", "", Some(&m), blocks);
    assert_eq!(diags.len(), 28);
    let worst = diags
        .iter()
        .filter(|d| d.message.starts_with("Z ="))
        .filter_map(|d| d.magnitude)
        .fold(0.0f32, f32::max);
    assert!((worst - 3.5).abs() < 1e-4, "{worst}");
}
