//! The polar printer: the `polar-printer` preset, the `[polar]` machine definition and the
//! `polar-ik` pass (geometry of the joint-linear path, θ continuity, E, origin policies,
//! the near-centre speed cap).

use std::collections::HashMap;

use nalgebra::Vector2;
use ncpost::diag::{Diagnostic, Severity};
use ncpost::front::gcode::{Options as GcodeOptions, parse_str};
use ncpost::ir::{Axis, Block, BlockKind, FeedMode, Joints, MotionKind, Target, dump};
use ncpost::machine::polar::{OriginPolicy, Polar};
use ncpost::passes::polar_ik::{PolarPoint, arc_points, error_bound, plan};
use ncpost::passes::{self, Context, Output};
use ncpost::preset::Preset;
use proptest::prelude::*;

const TOL: f64 = 0.01;

fn polar(negative_r: bool) -> Polar {
    let mut p = Preset::builtin("polar-printer")
        .expect("preset")
        .polar
        .expect("[polar]");
    p.negative_r = negative_r;
    p
}

fn run_ik(p: &Polar, options: &str, src: &str) -> (Vec<Block>, Vec<Block>, Vec<Diagnostic>) {
    let input = parse_str(src, &GcodeOptions::default())
        .expect("parse")
        .blocks;
    let opts: toml::Table = toml::from_str(options).expect("options");
    let ctx = Context {
        polar: Some(p),
        ..Context::default()
    };
    let mut pass = passes::build("polar-ik", &opts, &ctx).expect("pass");
    let mut out = Vec::new();
    let mut diags = Vec::new();
    {
        let mut o = Output::new(&mut out, &mut diags);
        for b in input.clone() {
            pass.run(&mut vec![b], &mut o);
        }
        pass.finish(&mut o);
    }
    (input, out, diags)
}

fn target(b: &Block) -> Option<Joints> {
    match &b.kind {
        BlockKind::Motion(m) => m.target.joints().copied(),
        _ => None,
    }
}

fn seg_dist(p: Vector2<f64>, a: Vector2<f64>, b: Vector2<f64>) -> f64 {
    let d = b - a;
    let l2 = d.norm_squared();
    if l2 == 0.0 {
        return (p - a).norm();
    }
    let s = ((p - a).dot(&d) / l2).clamp(0.0, 1.0);
    (p - (a + d * s)).norm()
}

/// The programmed XY path of every input motion, by source line: a polyline (an arc as
/// chords within 1e-4 mm).
fn input_paths(input: &[Block]) -> HashMap<u32, Vec<Vector2<f64>>> {
    let mut paths = HashMap::new();
    let mut pos: Option<Joints> = None;
    for b in input {
        if let BlockKind::Motion(m) = &b.kind
            && let Target::Joints(to) = m.target
        {
            if let (Some(from), Some(x1), Some(y1)) = (pos, to.get(Axis::X), to.get(Axis::Y))
                && let (Some(x0), Some(y0)) = (from.get(Axis::X), from.get(Axis::Y))
            {
                let mut pts = vec![Vector2::new(x0, y0)];
                match m.kind {
                    MotionKind::Arc(arc) => {
                        for j in arc_points(&from, &to, &arc, 1e-4).expect("chords") {
                            pts.push(Vector2::new(j.values[0], j.values[1]));
                        }
                    }
                    _ => pts.push(Vector2::new(x1, y1)),
                }
                paths.insert(b.span.line, pts);
            }
            pos = Some(to);
        }
        if let BlockKind::Command(c) = &b.kind
            && !c.clobbers.is_empty()
        {
            pos = None;
        }
    }
    paths
}

fn last_e(blocks: &[Block]) -> Option<f64> {
    blocks.iter().rev().find_map(|b| target(b)?.get(Axis::E))
}

struct Checked {
    out: Vec<Block>,
    /// (r, θ) of every emitted motion, in order.
    nodes: Vec<(f64, f64)>,
    worst: f64,
}

/// Runs `polar-ik` and checks the geometry of the whole output: FK of the joint-linear
/// path between consecutive emitted blocks (sampled) against the input path of the
/// block's source line, θ steps, E total, and the controller's speed and table rate per
/// piece against the programmed speed and ω_max.
fn check(p: &Polar, options: &str, src: &str, center: [f64; 2], path_tol: f64) -> Checked {
    let (input, out, diags) = run_ik(p, options, src);
    assert!(
        diags.iter().all(|d| d.severity != Severity::Error),
        "{diags:?}"
    );
    let paths = input_paths(&input);
    let c = Vector2::new(center[0], center[1]);
    let (ra, ta) = (p.r_axis, p.theta_axis);
    let mut prev: Option<(f64, f64)> = None;
    let mut nodes = Vec::new();
    let mut worst: f64 = 0.0;
    let mut in_feed: HashMap<u32, f64> = HashMap::new();
    for b in &input {
        if let BlockKind::Motion(m) = &b.kind
            && m.kind != MotionKind::Rapid
            && let (FeedMode::PerMinute, Some(f)) = (m.feed.mode, m.feed.rate)
        {
            in_feed.insert(b.span.line, f);
        }
    }
    for b in &out {
        let BlockKind::Motion(m) = &b.kind else {
            if let BlockKind::Command(cmd) = &b.kind
                && !cmd.clobbers.is_empty()
            {
                prev = None;
            }
            continue;
        };
        let j = m.target.joints().expect("joints");
        assert!(!j.known.contains(Axis::X) || ra == Axis::X);
        let (Some(r), Some(t)) = (j.get(ra), j.get(ta)) else {
            continue;
        };
        assert!(r.is_finite() && t.is_finite());
        nodes.push((r, t));
        if let Some((r0, t0)) = prev {
            assert!(
                (t - t0).abs() <= 180.0 + 1e-9,
                "θ jumps {t0} -> {t} at line {}",
                b.span.line
            );
            let path = &paths[&b.span.line];
            for k in 0..=32 {
                let u = k as f64 / 32.0;
                let rr = r0 + (r - r0) * u;
                let tt = (t0 + (t - t0) * u).to_radians();
                let q = c + Vector2::new(rr * tt.cos(), rr * tt.sin());
                let d = path
                    .windows(2)
                    .map(|w| seg_dist(q, w[0], w[1]))
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(d);
                assert!(
                    d <= path_tol,
                    "line {}: joint-linear path {d} mm off the programmed path",
                    b.span.line
                );
            }
            // The controller's time under the Euclidean rule and the resulting speeds.
            if let (Some(f_prog), Some(f)) = (in_feed.get(&b.span.line), m.feed.rate) {
                let q0 = Vector2::new(r0 * t0.to_radians().cos(), r0 * t0.to_radians().sin());
                let q1 = Vector2::new(r * t.to_radians().cos(), r * t.to_radians().sin());
                let joint = (r - r0).hypot(t - t0);
                if joint > 1e-12 {
                    let secs = joint / f * 60.0;
                    let v = (q1 - q0).norm() / secs;
                    assert!(
                        v <= f_prog / 60.0 * (1.0 + 1e-9) + 1e-12,
                        "line {}: XY speed {v} over the programmed {}",
                        b.span.line,
                        f_prog / 60.0
                    );
                    let omega = (t - t0).abs() / secs;
                    assert!(
                        omega <= p.omega_max * (1.0 + 1e-6),
                        "line {}: table at {omega} deg/s",
                        b.span.line
                    );
                }
            }
        }
        prev = Some((r, t));
    }
    assert_eq!(last_e(&out), last_e(&input), "E total changed");
    Checked { out, nodes, worst }
}

#[test]
fn line_exactly_through_the_origin_signed_radius() {
    let src = "G1 X-10 Y-10 F1200\nG1 X10 Y10 E2\n";
    let c = check(&polar(true), "", src, [0.0, 0.0], TOL);
    // No rotation: θ stays, r goes through zero to the other side.
    assert_eq!(c.nodes.len(), 2);
    assert_eq!(c.nodes[0].1, c.nodes[1].1);
    assert!((c.nodes[0].0 + c.nodes[1].0).abs() < 1e-9);
    assert!((c.nodes[1].0.abs() - 200f64.sqrt()).abs() < 1e-9);
}

#[test]
fn line_exactly_through_the_origin_rotate_in_place() {
    let src = "G1 X-10 Y-10 F1200\nG1 X10 Y10 E2\n";
    let c = check(&polar(false), "", src, [0.0, 0.0], TOL);
    // Stop at the centre, turn 180° on the spot, go on; r never negative.
    assert_eq!(c.nodes.len(), 4, "{:?}", c.nodes);
    assert_eq!(c.nodes[1].0, 0.0);
    assert_eq!(c.nodes[2].0, 0.0);
    assert!(((c.nodes[2].1 - c.nodes[1].1).abs() - 180.0).abs() < 1e-9);
    assert!(c.nodes.iter().all(|n| n.0 >= 0.0));
    // Half the E before the centre, none while turning.
    let es: Vec<f64> = c
        .out
        .iter()
        .filter_map(|b| target(b)?.get(Axis::E))
        .collect();
    assert_eq!(es, vec![0.0, 1.0, 1.0, 2.0]);
    // The turn runs at ω_max.
    let BlockKind::Motion(m) = &c.out[2].kind else {
        panic!("motion")
    };
    assert!((m.feed.rate.expect("F") - 180.0 * 60.0).abs() < 1e-6);
}

#[test]
fn origin_policy_option_overrides_the_machine() {
    let src = "G1 X-10 Y-10 F1200\nG1 X10 Y10 E2\n";
    let c = check(
        &polar(true),
        "origin = \"rotate-in-place\"",
        src,
        [0.0, 0.0],
        TOL,
    );
    assert_eq!(c.nodes.len(), 4);
    let p = polar(false);
    let opts: toml::Table = toml::from_str("origin = \"signed-radius\"").expect("toml");
    let ctx = Context {
        polar: Some(&p),
        ..Context::default()
    };
    let err = passes::build("polar-ik", &opts, &ctx).err().expect("error");
    assert!(err.message.contains("negative_r"), "{err}");
}

#[test]
fn line_passing_a_tenth_of_a_millimetre_from_the_origin() {
    for negative in [false, true] {
        let src = "G1 X-10 Y0.1 F1200\nG1 X10 Y0.1 E2\n";
        let c = check(&polar(negative), "", src, [0.0, 0.0], TOL);
        let (t0, t1) = (c.nodes[0].1, c.nodes[c.nodes.len() - 1].1);
        // The table turns by almost half a turn, the short way (clockwise here).
        assert!((t1 - t0 + 180.0).abs() < 1.2, "{t0} -> {t1}");
        assert!(c.worst > 0.0);
    }
}

#[test]
fn move_ending_at_the_origin_keeps_its_angle() {
    let src = "G1 X10 Y5 F1200\nG1 X0 Y0 E1\nG1 X0 Y0 Z1\n";
    let c = check(&polar(false), "", src, [0.0, 0.0], TOL);
    let want = 5f64.atan2(10.0).to_degrees();
    for (r, t) in &c.nodes[1..] {
        assert_eq!(*r, 0.0);
        assert!((t - want).abs() < 1e-9);
    }
}

#[test]
fn move_starting_at_the_origin_turns_first() {
    for negative in [false, true] {
        // From a fresh start at the centre (θ = 0, never atan2(0, 0)), then a corner at it.
        let src = "G1 X0 Y0 F1200\nG1 X5 Y5 E1\nG1 X0 Y0 E1\nG1 X-3 Y-8 E1\n";
        let c = check(&polar(negative), "", src, [0.0, 0.0], TOL);
        assert_eq!(c.nodes[0], (0.0, 0.0));
        // A turn on the spot to 45° (or 225° with negative r: nearer is 45° from 0).
        assert_eq!(c.nodes[1].0, 0.0);
        assert!((c.nodes[1].1 - 45.0).abs() < 1e-9, "{:?}", c.nodes);
        let last = c.nodes[c.nodes.len() - 1];
        let dir = (-8f64).atan2(-3.0).to_degrees();
        if negative {
            // Signed radius: dir + 180 (69.4°) is nearer to 45° than dir (-110.6°): r < 0.
            assert!((last.1 - (dir + 180.0)).abs() < 1e-9, "{last:?}");
            assert!(last.0 < 0.0);
        } else {
            assert!((last.1 - dir).abs() < 1e-9, "{last:?}");
        }
    }
}

#[test]
fn circle_around_the_origin_turns_continuously() {
    // One G2 full circle and one polygon of 72 G1 lines around the centre, twice.
    let mut src = String::from("G1 X20 Y0 F1800\nG2 X20 Y0 I-20 J0 E10\n");
    for k in 1..=144 {
        let a = (k as f64 * 5.0).to_radians();
        src.push_str(&format!(
            "G1 X{:.6} Y{:.6} E0.1\n",
            20.0 * a.cos(),
            20.0 * a.sin()
        ));
    }
    let c = check(&polar(false), "", &src, [0.0, 0.0], 2.0 * TOL + 1e-4);
    let thetas: Vec<f64> = c.nodes.iter().map(|n| n.1).collect();
    let after_arc = thetas
        .iter()
        .position(|t| (t + 360.0).abs() < 1e-6)
        .expect("the G2 ends at -360");
    assert!((thetas[thetas.len() - 1] - 360.0).abs() < 1e-3);
    // About the table's centre the arc is exact in r and θ: a few pieces, each under
    // half a turn.
    assert!(after_arc >= 3, "{after_arc}");
    // A circle off the centre that still contains it: θ wraps once, continuously.
    let mut src = String::from("G1 X35 Y0 F1800\n");
    for k in 1..=72 {
        let a = (k as f64 * 5.0).to_radians();
        src.push_str(&format!(
            "G1 X{:.6} Y{:.6} E0.1\n",
            5.0 + 30.0 * a.cos(),
            30.0 * a.sin()
        ));
    }
    let c = check(&polar(false), "", &src, [0.0, 0.0], TOL);
    assert!((c.nodes[c.nodes.len() - 1].1 - 360.0).abs() < 1e-3);
}

#[test]
fn spiral_from_near_the_centre() {
    let mut src = String::from("G1 X0.5 Y0 F1500\n");
    for k in 1..=360 {
        let phi = (k as f64 * 3.0).to_radians();
        let r = 0.5 + 2.0 * phi;
        src.push_str(&format!(
            "G1 X{:.6} Y{:.6} E0.05\n",
            r * phi.cos(),
            r * phi.sin()
        ));
    }
    let c = check(&polar(false), "", &src, [0.0, 0.0], TOL);
    assert!((c.nodes[c.nodes.len() - 1].1 - 1080.0).abs() < 1e-3);
}

const LAYER: &str = include_str!("fixtures/polar/prusaslicer_mini_layer1.gcode");

#[test]
fn real_sliced_layer() {
    // The parts of the PrusaSlicer layer lie around (101, 100): put the table centre near
    // them and inside the intro line's reach.
    for center in [[100.0, 90.0], [103.0, 107.0]] {
        let opts = format!("center = [{}, {}]", center[0], center[1]);
        let c = check(&polar(false), &opts, LAYER, center, 2.0 * TOL + 1e-4);
        assert!(c.worst > 1e-4, "densification does something here");
        assert!(c.out.len() > 300);
    }
}

#[test]
fn speed_cap_only_near_the_closest_approach() {
    let p = polar(false);
    // 50 mm/s past the centre at 5 mm: capped inside v / c = 50 / min(π, 1.2408 √(2π)).
    let (_, out, _) = run_ik(&p, "", "G1 X-100 Y5 F3000\nG1 X100 Y5 E10\n");
    let c = (180f64.to_radians()).min(1.240_806_478_802_799_6 * 360f64.to_radians().sqrt());
    let r_cap = 50.0 / c;
    let mut prev: Option<(f64, f64)> = None;
    let (mut capped, mut free) = (0, 0);
    for b in &out {
        let BlockKind::Motion(m) = &b.kind else {
            continue;
        };
        let j = m.target.joints().expect("joints");
        let (r, t) = (j.values[0], j.values[1]);
        if let Some((r0, t0)) = prev {
            let q0 = Vector2::new(r0 * t0.to_radians().cos(), r0 * t0.to_radians().sin());
            let q1 = Vector2::new(r * t.to_radians().cos(), r * t.to_radians().sin());
            let secs = (r - r0).hypot(t - t0) / m.feed.rate.expect("F") * 60.0;
            let v = (q1 - q0).norm() / secs;
            let d = seg_dist(Vector2::zeros(), q0, q1);
            if d >= r_cap - 1e-6 {
                assert!((v - 50.0).abs() < 1e-6, "outside the cap circle: {v}");
                free += 1;
            } else {
                assert!(v <= d * c * (1.0 + 1e-9), "inside: {v} at {d}");
                assert!(v < 50.0);
                capped += 1;
            }
        }
        prev = Some((r, t));
    }
    assert!(capped >= 2 && free >= 2, "{capped} capped, {free} free");
    // With the cap off, every piece runs at the programmed speed.
    let (_, out, _) = run_ik(
        &p,
        "speed_cap = false",
        "G1 X-100 Y5 F3000\nG1 X100 Y5 E10\n",
    );
    let slow = out.windows(2).filter(|w| {
        let (Some(a), Some(b)) = (target(&w[0]), target(&w[1])) else {
            return false;
        };
        let BlockKind::Motion(m) = &w[1].kind else {
            return false;
        };
        let (r0, t0, r, t) = (a.values[0], a.values[1], b.values[0], b.values[1]);
        let q0 = Vector2::new(r0 * t0.to_radians().cos(), r0 * t0.to_radians().sin());
        let q1 = Vector2::new(r * t.to_radians().cos(), r * t.to_radians().sin());
        let secs = (r - r0).hypot(t - t0) / m.feed.rate.expect("F") * 60.0;
        ((q1 - q0).norm() / secs - 50.0).abs() > 1e-6
    });
    assert_eq!(slow.count(), 0);
}

#[test]
fn e_total_is_exact_over_the_real_layer_output_text() {
    let mut preset = Preset::builtin("polar-printer").expect("preset");
    let polar_ik = preset.passes.iter_mut().find(|p| p.name == "polar-ik");
    polar_ik.expect("polar-ik").options.insert(
        "center".into(),
        toml::Value::try_from([100.0, 90.0]).expect("toml"),
    );
    // E as an axis: without extrude-rate, which turns E into screw speeds.
    preset.passes.retain(|p| p.name != "extrude-rate");
    let out = ncpost::pipeline::compile_str(LAYER, &preset).expect("compiles");
    let e_sum = |text: &str| -> f64 {
        text.lines()
            .filter(|l| l.starts_with("G1") || l.starts_with("G2") || l.starts_with("G3"))
            .flat_map(|l| l.split(' ').collect::<Vec<_>>())
            .filter_map(|w| w.strip_prefix('E')?.parse::<f64>().ok())
            .sum()
    };
    // The IR's E is absolute from 0 across G92 E0: its last value is the net amount.
    let blocks = parse_str(LAYER, &GcodeOptions::default())
        .expect("parse")
        .blocks;
    let input = last_e(&blocks).expect("E");
    assert!(
        (e_sum(&out) - input).abs() < 2e-5,
        "{} vs {input}",
        e_sum(&out)
    );
    assert!(
        out.lines()
            .all(|l| !l.starts_with("G2 ") && !l.starts_with("G3 "))
    );
}

#[test]
fn controller_kinematics_keeps_xy_and_cuts_arcs() {
    let p = polar(false);
    let src = "M83\nG1 X10 Y0 F1200\nG1 X12 Y3 E1\nG3 X-12 Y3 I-12 J-3 E5\n";
    let (input, out, diags) = run_ik(&p, "kinematics = \"controller\"", src);
    assert!(diags.is_empty());
    assert_eq!(out[..2], input[..2]);
    assert!(out.len() > 10);
    for b in &out[2..] {
        let j = target(b).expect("motion");
        let r = j.values[0].hypot(j.values[1] - 0.0);
        assert!((r - 153f64.sqrt()).abs() < 1e-6, "chord ends on the arc");
        let BlockKind::Motion(m) = &b.kind else {
            panic!()
        };
        assert_eq!(m.kind, MotionKind::Linear);
    }
    assert_eq!(last_e(&out), Some(6.0));
    // Without a [polar] table the controller mode still runs, the post mode does not.
    let t: toml::Table = toml::from_str("kinematics = \"controller\"").expect("toml");
    assert!(passes::build("polar-ik", &t, &Context::default()).is_ok());
    assert!(passes::build("polar-ik", &toml::Table::new(), &Context::default()).is_err());
}

#[test]
fn arcs_become_chords_within_tolerance() {
    let mut a = Joints::default();
    a.set(Axis::X, 30.0);
    a.set(Axis::Y, 0.0);
    a.set(Axis::E, 0.0);
    let mut b = a;
    b.set(Axis::X, 0.0);
    b.set(Axis::Y, 30.0);
    b.set(Axis::E, 3.0);
    let arc = ncpost::ir::Arc {
        clockwise: true,
        plane: ncpost::ir::Plane::XY,
        center: nalgebra::Vector3::zeros(),
        extra_turns: 1,
    };
    let pts = arc_points(&a, &b, &arc, TOL).expect("chords");
    let mut prev = Vector2::new(30.0, 0.0);
    let mut swept = 0.0;
    for p in &pts {
        let q = Vector2::new(p.values[0], p.values[1]);
        assert!((q.norm() - 30.0).abs() < 1e-9);
        let mid = (prev + q) / 2.0;
        assert!(30.0 - mid.norm() <= TOL + 1e-12);
        swept += (prev.x * q.y - prev.y * q.x).atan2(prev.dot(&q));
        prev = q;
    }
    // Clockwise from 0° to 90° plus a whole turn: -270° - 360°.
    assert!((swept.to_degrees() + 630.0).abs() < 1e-6);
    assert_eq!(pts.last(), Some(&b));
}

#[test]
fn bad_options_and_machines_are_errors() {
    let p = polar(false);
    let ctx = Context {
        polar: Some(&p),
        ..Context::default()
    };
    for bad in [
        "bogus = 1",
        "tolerance = 0.0",
        "tolerance = -1.0",
        "origin = \"sideways\"",
        "kinematics = \"magic\"",
        "max_depth = 99",
    ] {
        let t: toml::Table = toml::from_str(bad).expect("toml");
        assert!(passes::build("polar-ik", &t, &ctx).is_err(), "{bad}");
    }
    let mut q = polar(false);
    q.screw.e_per_rev = 0.0;
    assert!(q.check().is_err());
    let mut q = polar(false);
    q.valve.open_delay_s = -0.1;
    assert!(q.check().is_err());
    let mut q = polar(false);
    q.r_axis = Axis::C;
    assert!(q.check().is_err());
    let mut q = polar(false);
    q.omega_max = f64::NAN;
    assert!(q.check().is_err());
    assert!(toml::from_str::<Polar>("bogus = 1").is_err());
}

#[test]
fn preset_loads_and_runs_end_to_end() {
    let preset = Preset::builtin("polar-printer").expect("built-in preset");
    let p = preset.polar.as_ref().expect("[polar]");
    p.check().expect("valid machine");
    assert_eq!(p.origin_policy(), OriginPolicy::RotateInPlace);
    assert_eq!(p.valve.open_command, "M42 P0 S1");
    let names: Vec<&str> = preset.passes.iter().map(|s| s.name.as_str()).collect();
    // The final order is machine-settings, polar-ik, valve-lookahead, extrude-rate,
    // verify.
    let order: Vec<&str> = [
        "machine-settings",
        "polar-ik",
        "valve-lookahead",
        "extrude-rate",
        "verify",
    ]
    .into_iter()
    .filter(|n| names.contains(n))
    .collect();
    assert_eq!(names, order);
    assert_eq!(names.get(1), Some(&"polar-ik"));
    assert!(names.contains(&"extrude-rate"));
    let text = include_str!("../passes/polar-printer.toml");
    assert!(text.matches("# assumption:").count() >= 5);

    // The preset verifies by default; `run_verified` asks for it as well.
    let text = run_verified(
        "square_through_centre.gcode",
        &["--preset", "polar-printer"],
    );
    insta::assert_snapshot!("polar_printer_square_rrf", text);
}

#[test]
fn before_after_snapshot() {
    let src = include_str!("fixtures/polar/square_through_centre.gcode");
    let (input, out, diags) = run_ik(&polar(false), "", src);
    assert!(diags.is_empty(), "{diags:?}");
    let text = format!(
        "before:\n{}\nafter polar-ik:\n{}",
        dump::to_string(&input),
        dump::to_string(&out)
    );
    insta::assert_snapshot!("polar_ik_square", text);
    let (_, out, _) = run_ik(&polar(true), "", src);
    insta::assert_snapshot!("polar_ik_square_signed", dump::to_string(&out));
}

/// The largest distance of the joint-linear path from `a` to `b` from the line `p0`–`p1`.
fn piece_deviation(a: &PolarPoint, b: &PolarPoint, p0: Vector2<f64>, p1: Vector2<f64>) -> f64 {
    (0..=64)
        .map(|k| {
            let u = k as f64 / 64.0;
            let q = PolarPoint {
                r: a.r + (b.r - a.r) * u,
                theta: a.theta + (b.theta - a.theta) * u,
            }
            .xy();
            seg_dist(q, p0, p1)
        })
        .fold(0.0, f64::max)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Every planned piece of a random segment (some through or near the centre) is
    /// within tolerance on its sampled joint-linear path, and ends on the segment.
    #[test]
    fn densification_error_on_random_segments(
        x0 in -80.0..80.0f64, y0 in -80.0..80.0f64,
        x1 in -80.0..80.0f64, y1 in -80.0..80.0f64,
        near in 0usize..4, turns in -3i32..3, signed in any::<bool>(),
    ) {
        let p0 = Vector2::new(x0, y0);
        let mut p1 = Vector2::new(x1, y1);
        match near {
            0 => p1 = -p0 * 0.7,                            // through the centre
            1 => p1 = -p0 + Vector2::new(-p0.y, p0.x).normalize() * 0.2, // 0.1 mm off it
            _ => {}
        }
        let policy = if signed { OriginPolicy::SignedRadius } else { OriginPolicy::RotateInPlace };
        let start = PolarPoint {
            r: p0.norm(),
            theta: p0.y.atan2(p0.x) + f64::from(turns) * std::f64::consts::TAU,
        };
        let mut pieces = Vec::new();
        let deep = plan(p0, p1, start, policy, TOL, 24, Some(5.0), &mut pieces);
        prop_assert!(!deep);
        prop_assert!(pieces.windows(2).all(|w| w[0].s <= w[1].s), "pieces out of order");
        let mut a = start;
        for piece in &pieces {
            prop_assert!(piece_deviation(&a, &piece.to, p0, p1) <= TOL * (1.0 + 1e-9) + 1e-12);
            prop_assert!((piece.to.theta - a.theta).abs() <= std::f64::consts::PI + 1e-12);
            let on_line = seg_dist(piece.to.xy(), p0, p1);
            prop_assert!(on_line < 1e-9, "node {} off the line", on_line);
            a = piece.to;
        }
        prop_assert!((a.xy() - p1).norm() < 1e-9);
    }

    /// Densification is close to the fewest pieces the bound allows: within 10 % (and one
    /// piece) of the greedy cut that makes every piece as long as it can be, found here
    /// by exhaustive bisection. (Halving at midpoints gave up to twice as many.)
    #[test]
    fn densification_is_near_minimal(
        x0 in -80.0..80.0f64, y0 in -80.0..80.0f64,
        x1 in -80.0..80.0f64, y1 in -80.0..80.0f64,
    ) {
        let p0 = Vector2::new(x0, y0);
        let p1 = Vector2::new(x1, y1);
        let d = p1 - p0;
        // Lines through the centre take their own path; these miss it by a margin.
        prop_assume!((p0.x * d.y - p0.y * d.x).abs() / d.norm() > 0.5);
        let start = PolarPoint { r: p0.norm(), theta: p0.y.atan2(p0.x) };
        let at = |s: f64| {
            let p = p0 + d * s;
            PolarPoint { r: p.norm(), theta: start.theta + (p0.x * p.y - p0.y * p.x).atan2(p0.dot(&p)) }
        };
        let mut fewest = 0usize;
        let mut cur = (0.0, start);
        loop {
            fewest += 1;
            if error_bound(&cur.1, &at(1.0)) <= TOL {
                break;
            }
            let (mut lo, mut hi) = (cur.0, 1.0);
            for _ in 0..60 {
                let m = 0.5 * (lo + hi);
                if error_bound(&cur.1, &at(m)) <= TOL { lo = m } else { hi = m }
            }
            cur = (lo, at(lo));
        }
        let mut pieces = Vec::new();
        plan(p0, p1, start, OriginPolicy::RotateInPlace, TOL, 24, None, &mut pieces);
        prop_assert!(
            pieces.len() as f64 <= fewest as f64 * 1.1 + 1.0,
            "{} pieces where {} would do", pieces.len(), fewest
        );
    }

    /// The bound holds: the joint-linear path never leaves its chord by more.
    #[test]
    fn error_bound_holds(r0 in -100.0..100.0f64, r1 in -100.0..100.0f64,
                         t0 in -7.0..7.0f64, dt in -3.0..3.0f64) {
        let a = PolarPoint { r: r0, theta: t0 };
        let b = PolarPoint { r: r1, theta: t0 + dt };
        let dev = piece_deviation(&a, &b, a.xy(), b.xy());
        prop_assert!(dev <= error_bound(&a, &b) * (1.0 + 1e-9) + 1e-9);
    }

    /// The bound is close to the truth on short pieces (where the densified pieces are):
    /// a looser one would cut more pieces than needed.
    #[test]
    fn error_bound_is_tight_on_short_pieces(r0 in 5.0..100.0f64, dr_frac in -0.05..0.05f64,
                                            t0 in -7.0..7.0f64, dt in -0.05..0.05f64) {
        let a = PolarPoint { r: r0, theta: t0 };
        let b = PolarPoint { r: r0 * (1.0 + dr_frac), theta: t0 + dt };
        let bound = error_bound(&a, &b);
        prop_assume!(bound > 1e-6);
        let dev = piece_deviation(&a, &b, a.xy(), b.xy());
        prop_assert!(dev >= 0.9 * bound, "deviation {dev} against the bound {bound}");
    }
}

/// Runs the binary on fixture `name` (in `tests/fixtures/polar/`) with `args` and the
/// verification on; the run must pass it. Returns the printed program.
fn run_verified(name: &str, args: &[&str]) -> String {
    let path = format!("{}/tests/fixtures/polar/{name}", env!("CARGO_MANIFEST_DIR"));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_ncpost"))
        .args(["run", "--verify"])
        .args(args)
        .arg(&path)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{name}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("UTF-8")
}

/// One printed move as the controller runs it.
struct Timed {
    seconds: f64,
    /// The printed tip's path length (the joint-linear spiral, sampled), mm.
    length: f64,
    /// The printed θ changes: the table turns.
    turns: bool,
    /// The distance from the centre to the line of the printed move's ends, mm.
    reach: f64,
}

/// Every printed feed move of `text` re-read by the crate's readback (the controller's
/// own modal state and timing) on polar machine `p`.
fn printed_moves(text: &str, p: &Polar) -> Vec<Timed> {
    use ncpost::motion::{Model, lerp, polar_point};
    use ncpost::readback::{Event, Reader};
    let model = Model::for_machines(Some(p), None, None, None, None);
    let mut reader = Reader::new(model, p.controller.flavour, Some(p));
    let (r, th) = (p.r_axis, p.theta_axis);
    let mut moves = Vec::new();
    for line in text.lines() {
        let Some(Event::Move(m)) = reader.line(line) else {
            continue;
        };
        let known = |j: &Joints| j.known.contains(r) && j.known.contains(th);
        if m.rapid || !known(&m.from) || !known(&m.to) {
            continue;
        }
        let (a, b) = (polar_point(&m.from, r, th), polar_point(&m.to, r, th));
        let mut length = 0.0;
        let mut last = a;
        for k in 1..=16 {
            let q = polar_point(&lerp(&m.from, &m.to, f64::from(k) / 16.0), r, th);
            length += (q - last).xy().norm();
            last = q;
        }
        let d = b - a;
        let chord = d.xy().norm();
        moves.push(Timed {
            seconds: m.seconds,
            length,
            turns: m.from.get(th) != m.to.get(th),
            reach: if chord > 0.0 {
                (a.x * d.y - a.y * d.x).abs() / chord
            } else {
                a.coords.xy().norm()
            },
        });
    }
    moves
}

/// Checks every printed move of `text` against the programmed speed `feed` (mm/min):
/// the controller takes the printed length at that speed, within 1 %, or longer only as
/// far as the near-centre cap asks where the table turns. Returns the printed seconds.
fn check_block_times(text: &str, p: &Polar, feed: f64) -> f64 {
    let v = feed / 60.0;
    let rate = p
        .omega_max
        .to_radians()
        .min(ncpost::passes::polar_ik::ALPHA_FACTOR * p.alpha_max.to_radians().sqrt());
    let mut total = 0.0;
    for m in printed_moves(text, p) {
        total += m.seconds;
        if m.length <= 1e-6 {
            continue;
        }
        let slowest = if m.turns { v.min(m.reach * rate) } else { v };
        let (fast, slow) = (m.length / v, m.length / slowest);
        assert!(
            m.seconds >= fast * 0.99 && m.seconds <= slow * 1.01,
            "a printed move of {:.5} mm takes {:.6} s, programmed {fast:.6}..{slow:.6} s",
            m.length,
            m.seconds
        );
    }
    total
}

/// The programmed XY length of the feed moves of `src` (straight lines only), mm.
fn programmed_length(src: &str) -> f64 {
    let input = parse_str(src, &GcodeOptions::default())
        .expect("parse")
        .blocks;
    let mut last: Option<Vector2<f64>> = None;
    let mut total = 0.0;
    for b in &input {
        if let BlockKind::Motion(m) = &b.kind
            && let Some(j) = m.target.joints()
            && let (Some(x), Some(y)) = (j.get(Axis::X), j.get(Axis::Y))
        {
            let q = Vector2::new(x, y);
            if let (Some(a), MotionKind::Linear) = (last, m.kind) {
                total += (q - a).norm();
            }
            last = Some(q);
        }
    }
    total
}

/// pcb2gcode's 5-decimal moves 1.5 mm from the table's centre (corpus p-pcb, 115 % over
/// the block time before): a piece whose θ change rounds away prints as a pure r move,
/// so its F comes from the printed r alone and the near-centre cap (a limit on the
/// table's turning) does not slow it.
#[test]
fn near_centre_short_moves_run_at_the_programmed_speed() {
    let text = run_verified(
        "near_centre_short_moves.ngc",
        &["--preset", "polar-printer"],
    );
    let p = polar(false);
    let seconds = check_block_times(&text, &p, 600.0);
    // Never faster than the programmed feed over the whole program.
    let src = include_str!("fixtures/polar/near_centre_short_moves.ngc");
    let programmed = programmed_length(src) / 10.0;
    assert!(
        seconds >= programmed * 0.99,
        "{seconds} s for {programmed} s"
    );
    // Rounding leaves some pieces without a θ change: they are in the test.
    assert!(
        text.lines()
            .any(|l| l.starts_with("G1 X") && !l.contains('Y')),
        "{text}"
    );
}

/// svg2gcode's 0.0002 mm closing move (corpus p-sameer, 1.65 % over the block time
/// before): F comes from the printed r/θ deltas, and the whole program takes the
/// programmed length at the programmed speed.
#[test]
fn tiny_closing_move_runs_at_the_programmed_speed() {
    let text = run_verified("tiny_closing_move.gcode", &["--preset", "polar-printer"]);
    let seconds = check_block_times(&text, &polar(false), 300.0);
    let src = include_str!("fixtures/polar/tiny_closing_move.gcode");
    let programmed = programmed_length(src) / 5.0;
    assert!(
        (seconds - programmed).abs() <= 0.01 * programmed,
        "{seconds} s for {programmed} s"
    );
}
