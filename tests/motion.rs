//! The motion-time model: durations under each feed rule, trapezoid profiles, junctions, look-ahead, stats and speed plots.

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::Point3;
use ncpost::back::Backend;
use ncpost::front::gcode::{Options, parse_str};
use ncpost::ir::{Axis, Joints};
use ncpost::machine::{Controller, FeedRule, PerAxis};
use ncpost::motion::{Model, Planner, Profile, Segment, Timed, Timing};
use ncpost::plot::SpeedPlot;
use proptest::prelude::*;

fn joints(values: &[(Axis, f64)]) -> Joints {
    let mut j = Joints::default();
    for &(a, v) in values {
        j.set(a, v);
    }
    j
}

fn xy(x: f64, y: f64) -> Joints {
    joints(&[(Axis::X, x), (Axis::Y, y), (Axis::Z, 0.0), (Axis::E, 0.0)])
}

/// Runs G-code through a planner of `model` and returns every timed item.
fn timed(model: &Model, gcode: &str) -> Vec<Timed<()>> {
    let program = parse_str(gcode, &Options::default()).expect("parses");
    let mut planner = Planner::new(model.clone());
    let mut last = Joints::default();
    let mut out = Vec::new();
    for b in &program.blocks {
        match &b.kind {
            ncpost::ir::BlockKind::Motion(m) => {
                if let Some(seg) = model.motion(&last, m) {
                    planner.push_move(seg, ());
                }
                if let Some(j) = m.target.joints() {
                    for a in j.known.iter() {
                        last.set(a, j.values[a.index()]);
                    }
                }
            }
            ncpost::ir::BlockKind::Dwell { seconds } => planner.push_stop(*seconds, ()),
            _ => {}
        }
        while let Some(t) = planner.pop() {
            out.push(t);
        }
    }
    planner.finish();
    while let Some(t) = planner.pop() {
        out.push(t);
    }
    out
}

fn total(model: &Model, gcode: &str) -> f64 {
    timed(model, gcode).last().map_or(0.0, |t| t.end())
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * (1.0 + b.abs())
}

fn controller(rule: FeedRule) -> Controller {
    Controller {
        feed_rule: rule,
        min_speed: Some(0.0),
        ..Controller::default()
    }
}

// ------------------------------------------------------------ constant velocity

#[test]
fn nist_rule_durations() {
    let m = Model::new(&controller(FeedRule::Nist));
    // 3-4-5 in XY while C turns 90 deg: F applies to the 5 mm: 0.5 s at 600 mm/min.
    let t = total(&m, "G0 X0 Y0 Z0 C0\nG1 X3 Y4 C90 F600\n");
    let rapid = 0.0; // the rapid goes nowhere from the unknown start
    assert!(close(t, rapid + 0.5, 1e-12), "{t}");
    // Only the rotary moves: F is deg/min: 90 deg at 1800 deg/min = 3 s.
    let t = total(&m, "G0 X0 Y0 Z0 C0\nG1 C90 F1800\n");
    assert!(close(t, 3.0, 1e-12), "{t}");
    // Only E moves (a retraction): F applies to E: 5 mm at 300 mm/min = 1 s.
    let t = total(&m, "G0 X0 Y0 Z0\nG1 E-5 F300\n");
    assert!(close(t, 1.0, 1e-12), "{t}");
    // E does not count when X moves: 10 mm at 600 mm/min = 1 s.
    let t = total(&m, "G0 X0 Y0 Z0\nG1 X10 E50 F600\n");
    assert!(close(t, 1.0, 1e-12), "{t}");
    // A quarter circle of radius 10 at 600 mm/min: 5 pi mm / 10 mm/s.
    let t = total(&m, "G0 X10 Y0 Z0\nG3 X0 Y10 I-10 J0 F600\n");
    assert!(close(t, std::f64::consts::PI / 2.0, 1e-12), "{t}");
}

#[test]
fn euclidean_and_inverse_time_durations() {
    let m = Model::new(&controller(FeedRule::Euclidean));
    // sqrt(3² + 4² + 12²) = 13 (mm and degrees mixed) at 780/min = 1 s.
    let t = total(&m, "G0 X0 Y0 Z0 C0\nG1 X3 Y4 C12 F780\n");
    assert!(close(t, 1.0, 1e-12), "{t}");
    // G93: every move takes 1/F minutes, whatever the rule: F2 = 30 s.
    for rule in [FeedRule::Nist, FeedRule::Euclidean, FeedRule::InverseTime] {
        let m = Model::new(&controller(rule));
        let t = total(&m, "G0 X0 Y0 Z0 C0\nG93 G1 X3 Y4 C12 F2\n");
        assert!(close(t, 30.0, 1e-12), "{rule:?}: {t}");
    }
}

#[test]
fn axis_caps_min_speed_and_rapids() {
    let mut c = controller(FeedRule::Nist);
    c.max_feed = PerAxis {
        x: Some(3000.0),
        ..PerAxis::default()
    };
    let m = Model::new(&c);
    // X may do 50 mm/s: 100 mm at a programmed 6000 mm/min takes 2 s, not 1 s.
    let t = total(&m, "G0 X0 Y0 Z0\nG1 X100 F6000\n");
    assert!(close(t, 2.0, 1e-12), "{t}");
    // The diagonal: X's share is 0.6 of the speed, so the speed is capped at 50/0.6.
    let t = total(&m, "G0 X0 Y0 Z0\nG1 X60 Y80 F6000\n");
    assert!(close(t, 100.0 / (50.0 / 0.6), 1e-12), "{t}");
    // Rapids run at the rapid feed, capped the same way.
    let m2 = m.clone().with_rapid_feed(1200.0);
    let t = total(&m2, "G0 X0 Y0 Z0\nG0 Y20\n");
    assert!(close(t, 1.0, 1e-12), "{t}");
    // The controller's minimum speed: F1 runs at 30 mm/min.
    let mut c = controller(FeedRule::Nist);
    c.min_speed = Some(30.0);
    let t = total(&Model::new(&c), "G0 X0 Y0 Z0\nG1 X10 F1\n");
    assert!(close(t, 20.0, 1e-12), "{t}");
}

// ------------------------------------------------------------ trapezoid

fn accel_model(ax: f64, ay: f64) -> Model {
    let mut c = controller(FeedRule::Nist);
    c.acceleration = PerAxis {
        x: Some(ax),
        y: Some(ay),
        ..PerAxis::default()
    };
    c.timing = Timing::Trapezoid;
    Model::new(&c)
}

#[test]
fn long_move_accelerates_cruises_and_decelerates() {
    let m = accel_model(100.0, 100.0);
    // d = 100 mm, v = 10 mm/s, a = 100 mm/s²: d/v + v/a.
    let items = timed(&m, "G0 X0 Y0 Z0\nG1 X100 F600\n");
    let t = items.last().map(|t| t.end()).unwrap_or(0.0);
    assert!(close(t, 100.0 / 10.0 + 10.0 / 100.0, 1e-12), "{t}");
    let p = items.iter().rev().find_map(|t| t.motion).unwrap().1;
    assert!(close(p.t_accel, 0.1, 1e-12) && close(p.t_decel, 0.1, 1e-12));
    assert_eq!((p.v_entry, p.v_peak, p.v_exit), (0.0, 10.0, 0.0));
}

#[test]
fn short_move_is_triangular() {
    let m = accel_model(100.0, 100.0);
    // 1 mm cannot reach 100 mm/s (needs 100 mm): peak sqrt(a d), time 2 sqrt(d / a).
    let items = timed(&m, "G0 X0 Y0 Z0\nG1 X1 F6000\n");
    let p = items.iter().rev().find_map(|t| t.motion).unwrap().1;
    assert!(close(p.v_peak, 10.0, 1e-12), "{p:?}");
    assert_eq!(p.t_cruise, 0.0);
    assert!(close(p.duration(), 2.0 * (1.0f64 / 100.0).sqrt(), 1e-12));
}

#[test]
fn acceleration_is_limited_per_axis() {
    // u = (0.6, 0.8): X allows 100/0.6, Y allows 400/0.8 = 500; X limits.
    let m = accel_model(100.0, 400.0);
    let items = timed(&m, "G0 X0 Y0 Z0\nG1 X3 Y4 F60000\n");
    let (seg, p) = items.iter().rev().find_map(|t| t.motion).unwrap();
    assert!(close(seg.accel, 100.0 / 0.6, 1e-12), "{seg:?}");
    // 5 mm, triangular: 2 sqrt(d / a).
    assert!(close(
        p.duration(),
        2.0 * (5.0 / (100.0 / 0.6f64)).sqrt(),
        1e-12
    ));
}

#[test]
fn junctions_follow_the_jerk_rule() {
    // Collinear blocks run through: the same time as one 100 mm block.
    let m = accel_model(100.0, 100.0);
    let t = total(&m, "G0 X0 Y0 Z0\nG1 X50 F600\nG1 X100\n");
    assert!(close(t, 10.1, 1e-12), "{t}");
    // A right-angle corner without jerk allowance stops: twice a 50 mm block.
    let t = total(&m, "G0 X0 Y0 Z0\nG1 X50 F600\nG1 Y50\n");
    assert!(close(t, 2.0 * 5.1, 1e-12), "{t}");
    // With 300 mm/min (5 mm/s) per axis, the corner is taken at 5 mm/s (each axis
    // changes its speed by 5): per block 0.1 s up, 0.05 s down, 49.125 mm at 10 mm/s.
    let mut c = controller(FeedRule::Nist);
    c.acceleration = PerAxis {
        x: Some(100.0),
        y: Some(100.0),
        ..PerAxis::default()
    };
    c.jerk = PerAxis {
        x: Some(300.0),
        y: Some(300.0),
        ..PerAxis::default()
    };
    c.timing = Timing::Trapezoid;
    let m = Model::new(&c);
    let items = timed(&m, "G0 X0 Y0 Z0\nG1 X50 F600\nG1 Y50\n");
    let moves: Vec<Profile> = items
        .iter()
        .filter_map(|t| t.motion.filter(|(s, _)| s.moves()).map(|m| m.1))
        .collect();
    assert_eq!(moves.len(), 2);
    assert!(close(moves[0].v_exit, 5.0, 1e-12) && close(moves[1].v_entry, 5.0, 1e-12));
    let per_block = 0.1 + 0.05 + (50.0 - 0.5 - 0.375) / 10.0;
    let t = items.last().unwrap().end();
    assert!(close(t, 2.0 * per_block, 1e-12), "{t}");
    // The extruder is not jerk-limited: a change of extrusion per mm at a collinear
    // junction does not slow the machine down.
    let m = accel_model(100.0, 100.0);
    let t = total(&m, "G0 X0 Y0 Z0\nG1 X50 E1 F600\nG1 X100 E3\n");
    assert!(close(t, 10.1, 1e-12), "{t}");
    // A dwell stops the machine even between collinear blocks.
    let m = accel_model(100.0, 100.0);
    let t = total(&m, "G0 X0 Y0 Z0\nG1 X50 F600\nG4 P0\nG1 X100\n");
    assert!(close(t, 2.0 * 5.1, 1e-12), "{t}");
}

#[test]
fn lookahead_is_bounded() {
    // 200 collinear 1 mm blocks at 100 mm/s with 100 mm/s²: a block is planned knowing
    // the N blocks after it and must be able to stop at their end, at most N + 1 mm
    // ahead of its start, so it never exceeds sqrt(2 a (N + 1)).
    let mut g = String::from("G0 X0 Y0 Z0\nG1 F6000\n");
    for i in 1..=200 {
        g.push_str(&format!("G1 X{i}\n"));
    }
    let peak = |n: usize| {
        let m = accel_model(100.0, 100.0).with_lookahead(n);
        timed(&m, &g)
            .iter()
            .filter_map(|t| t.motion.map(|m| m.1.v_peak))
            .fold(0.0, f64::max)
    };
    for n in [1usize, 4, 16] {
        let bound = (2.0 * 100.0 * (n + 1) as f64).sqrt();
        assert!(peak(n) <= bound + 1e-9, "{n}: {} > {bound}", peak(n));
    }
    assert!(peak(64) > (2.0f64 * 100.0 * 17.0).sqrt() + 1.0);
    // And memory: after each push at most N moves wait in the planner.
    let m = accel_model(100.0, 100.0).with_lookahead(8);
    let mut planner = Planner::new(m.clone());
    let (mut pushed, mut popped) = (0usize, 0usize);
    for i in 0..200 {
        let seg = m.linear(&xy(i as f64, 0.0), &xy(i as f64 + 1.0, 0.0), 6000.0);
        planner.push_move(seg, ());
        pushed += 1;
        while planner.pop().is_some() {
            popped += 1;
        }
        assert!(pushed - popped <= 8, "{pushed} pushed, {popped} out");
    }
    // A longer window is never slower.
    let t8 = total(&accel_model(100.0, 100.0).with_lookahead(8), &g);
    let t64 = total(&accel_model(100.0, 100.0).with_lookahead(64), &g);
    assert!(t64 <= t8 + 1e-12, "{t64} > {t8}");
}

#[test]
fn splitting_a_move_at_a_time_keeps_the_timing() {
    // The valve pass's operation: find the point of a move at a given time, split there.
    let mut c = controller(FeedRule::Nist);
    c.acceleration = PerAxis {
        x: Some(200.0),
        y: Some(200.0),
        ..PerAxis::default()
    };
    c.jerk = PerAxis {
        x: Some(300.0),
        y: Some(300.0),
        ..PerAxis::default()
    };
    let pts = [xy(0.0, 0.0), xy(40.0, 0.0), xy(40.0, 30.0), xy(0.0, 30.0)];
    for timing in [Timing::ConstantVelocity, Timing::Trapezoid] {
        let m = Model::new(&c).with_timing(timing);
        let plan = |path: &[Joints]| {
            let mut planner = Planner::new(m.clone());
            for w in path.windows(2) {
                planner.push_move(m.linear(&w[0], &w[1], 3000.0), ());
            }
            planner.finish();
            std::iter::from_fn(|| planner.pop()).collect::<Vec<_>>()
        };
        let whole = plan(&pts);
        // 0.3 s before the third move starts, inside the second move.
        let at = whole[2].start - 0.3;
        let f = whole[1]
            .fraction_at_time(at)
            .expect("inside the second move");
        assert!(close(whole[1].time_at_fraction(f), at, 1e-9));
        let mid = ncpost::motion::lerp(&pts[1], &pts[2], f);
        let split = plan(&[pts[0], pts[1], mid, pts[2], pts[3]]);
        assert_eq!(split.len(), 4);
        assert!(
            close(split[2].start, at, 1e-9),
            "{timing:?}: {} vs {at}",
            split[2].start
        );
        assert!(close(split[2].end(), whole[1].end(), 1e-9));
        assert!(close(split[3].end(), whole[2].end(), 1e-9), "{timing:?}");
    }
}

fn program(points: &[(f64, f64, f64)]) -> String {
    let mut g = String::from("G0 X0 Y0 Z0\n");
    for (x, y, f) in points {
        g.push_str(&format!("G1 X{x:.3} Y{y:.3} F{f:.1}\n"));
    }
    g
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn trapezoid_is_never_faster_than_constant_velocity(
        points in prop::collection::vec((-100.0f64..100.0, -100.0f64..100.0, 60.0f64..12000.0), 1..30),
        jerk in 0.0f64..1200.0,
        lookahead in 1usize..20,
    ) {
        let g = program(&points);
        let mut c = controller(FeedRule::Nist);
        c.acceleration = PerAxis { x: Some(500.0), y: Some(800.0), ..PerAxis::default() };
        c.jerk = PerAxis { x: Some(jerk), y: Some(jerk), ..PerAxis::default() };
        c.lookahead = lookahead;
        let cv = total(&Model::new(&c).with_timing(Timing::ConstantVelocity), &g);
        let tr = total(&Model::new(&c).with_timing(Timing::Trapezoid), &g);
        prop_assert!(tr >= cv - 1e-9, "trapezoid {} < constant velocity {}", tr, cv);
        // Without any acceleration limit the trapezoid model is the constant-velocity one.
        c.acceleration = PerAxis::default();
        let tr = total(&Model::new(&c).with_timing(Timing::Trapezoid), &g);
        prop_assert!((tr - cv).abs() <= 1e-9 * (1.0 + cv), "{} vs {}", tr, cv);
    }

    #[test]
    fn time_and_fraction_invert_each_other(
        length in 0.01f64..500.0,
        v_max in 0.5f64..200.0,
        accel in 1.0f64..5000.0,
        v0 in 0.0f64..1.0,
        v1 in 0.0f64..1.0,
        f in 0.0f64..=1.0,
    ) {
        let seg = Segment { delta: [0.0; 10], length, v_max, accel };
        // Feasible entry and exit speeds, as the planner gives them.
        let reach = (2.0 * accel * length).sqrt();
        let v0 = v0 * v_max.min(reach);
        let v1 = v1 * v_max.min((v0 * v0 + 2.0 * accel * length).sqrt());
        let p = Profile::new(&seg, v0, v1);
        let t = p.time_at_fraction(f);
        prop_assert!(t >= 0.0 && t <= p.duration() + 1e-12);
        prop_assert!((p.fraction_at(t) - f).abs() < 1e-9, "f {} -> t {} -> {}", f, t, p.fraction_at(t));
        let t2 = f * p.duration();
        prop_assert!((p.time_at_fraction(p.fraction_at(t2)) - t2).abs() < 1e-6 * (1.0 + p.duration()));
        // The distance covered is the integral of the speed: the end is the length.
        prop_assert!((p.distance_at(p.duration()) - length).abs() < 1e-6 * (1.0 + length));
    }
}

// ------------------------------------------------------------ polar: the seed's appendix

/// A polar machine: r on X, θ on Y (deg), Euclidean rule, trapezoid with per-axis limits.
fn polar_plot() -> SpeedPlot {
    let mut c = controller(FeedRule::Euclidean);
    c.acceleration = PerAxis {
        x: Some(100.0),
        y: Some(100.0),
        ..PerAxis::default()
    };
    c.timing = Timing::Trapezoid;
    SpeedPlot::new(Model::new(&c), Some((Axis::X, Axis::Y)))
}

#[test]
fn polar_linear_speed_is_not_trapezoidal_while_joint_speeds_are() {
    let mut plot = polar_plot();
    // r 20 -> 100 mm while θ turns 0 -> 90 deg, one joint-linear block.
    let program = parse_str("G0 X20 Y0\nG1 X100 Y90 F3000\n", &Options::default()).unwrap();
    let mut diags = Vec::new();
    for b in &program.blocks {
        plot.write_block(b, &mut diags).unwrap();
    }
    plot.finish().unwrap();
    let s: Vec<_> = plot
        .samples()
        .iter()
        .filter(|s| s.t > 0.0 || s.v > 0.0)
        .copied()
        .collect();
    assert!(s.len() > 20, "{}", s.len());
    // ṙ and θ̇ are trapezoids: proportional to each other at every instant (the joints
    // move along one line), rising linearly, flat, falling linearly.
    let (dr, dth) = (80.0, 90.0);
    for x in &s {
        let (rdot, thdot) = (x.axes[0], x.axes[1]);
        assert!((rdot * dth - thdot * dr).abs() < 1e-9, "{x:?}");
    }
    let top = s.iter().map(|x| x.axes[0]).fold(0.0, f64::max);
    let cruise: Vec<_> = s
        .iter()
        .filter(|x| (x.axes[0] - top).abs() < 1e-12)
        .collect();
    assert!(cruise.len() > 5);
    // v = sqrt(ṙ² + r² θ̇²) with r from the joint position at that time.
    let t0 = cruise[0].t;
    let t1 = cruise[cruise.len() - 1].t;
    assert!(t1 > t0);
    // ...and during the cruise, where ṙ and θ̇ are constant, v grows with r: not a
    // trapezoid (the seed's Figure 2).
    let v_first = cruise[0].v;
    let v_last = cruise[cruise.len() - 1].v;
    assert!(v_last > 1.5 * v_first, "{v_first} .. {v_last}");
    for x in &cruise {
        let thdot = x.axes[1].to_radians();
        // r at time t: fraction of the joint path done.
        let r_lo = 20.0;
        let r_hi = 100.0;
        let r_from_v = ((x.v * x.v - x.axes[0] * x.axes[0]).max(0.0)).sqrt() / thdot;
        assert!(
            r_from_v > r_lo - 1e-6 && r_from_v < r_hi + 1e-6,
            "{x:?} r {r_from_v}"
        );
    }
    // Strictly increasing over the cruise (r grows monotonically).
    assert!(cruise.windows(2).all(|w| w[1].v >= w[0].v - 1e-9));
    let svg = plot.svg();
    assert!(svg.contains("X = ṙ (mm/s)") && svg.contains("Y = θ̇ (deg/s)"));
    assert!(svg.contains("v = sqrt(ṙ² + r² θ̇²)"));
}

#[test]
fn polar_tool_speed_matches_the_formula() {
    // One block at constant velocity: v = (s'/L) sqrt(Δr² + r² Δθ²) exactly.
    let from = joints(&[(Axis::X, 10.0), (Axis::Y, 0.0)]);
    let to = joints(&[(Axis::X, 50.0), (Axis::Y, 120.0)]);
    let m = Model::new(&controller(FeedRule::Euclidean));
    let seg = m.linear(&from, &to, 6000.0);
    let p = Profile::new(&seg, 0.0, 0.0);
    for k in 0..=10 {
        let t = p.duration() * k as f64 / 10.0;
        let f = p.fraction_at(t);
        let r = 10.0 + 40.0 * f;
        let sdot = p.speed_at(t) / seg.length;
        let expect = sdot * (40.0f64.powi(2) + (r * 120.0f64.to_radians()).powi(2)).sqrt();
        let v = ncpost::motion::tool_speed(&p, &from, &to, t, |j| {
            ncpost::motion::polar_point(j, Axis::X, Axis::Y)
        });
        assert!(close(v, expect, 1e-6), "{t}: {v} vs {expect}");
    }
    // A Cartesian map gives the XY speed.
    let v = ncpost::motion::tool_speed(&p, &from, &to, 0.1, |j| Point3::new(j.values[0], 0.0, 0.0));
    assert!(close(v, 40.0 / p.duration(), 1e-6));
}

#[test]
fn stats_of_a_polar_program_are_cartesian() {
    // A quarter circle of radius 10 as 90 one-degree joint moves (r on X, θ on Y), then
    // a radial move out to r = 20 at θ = 90: the tool path is 5 pi + 10 mm long.
    let mut g = String::from("G0 X10 Y0\nG1 F600\n");
    for k in 1..=90 {
        g.push_str(&format!("G1 Y{k} E{}\n", k as f64 * 0.01));
    }
    g.push_str("G1 X20\n");
    let program = parse_str(&g, &Options::default()).unwrap();
    let model = Model::new(&controller(FeedRule::Euclidean));
    let mut stats = ncpost::passes::stats::Stats::with_model(model).with_polar(Axis::X, Axis::Y);
    let mut diags = Vec::new();
    for b in &program.blocks {
        stats.write_block(b, &mut diags).unwrap();
    }
    Backend::finish(&mut stats).unwrap();
    let t = &stats.totals;
    let arc = 10.0 * std::f64::consts::FRAC_PI_2;
    // Chords of one degree are shorter than the arc by 1 - sinc: 13 ppm.
    assert!(close(t.feed_mm, arc + 10.0, 2e-5), "{}", t.feed_mm);
    assert!(close(t.extruding_mm, arc, 2e-5), "{}", t.extruding_mm);
    let [x, y, z] = t.bounds;
    let (x, y) = (x.unwrap(), y.unwrap());
    assert!(close(x.0, 0.0, 1e-9) && close(x.1, 10.0, 1e-9), "{x:?}");
    assert!(close(y.0, 0.0, 1e-9) && close(y.1, 20.0, 1e-9), "{y:?}");
    assert_eq!(z, None);
    // Time: Euclidean joint distance (1 deg + ... + 10 mm) at 10 units/s.
    assert!(
        close(t.seconds, (90.0 + 10.0) / 10.0, 1e-12),
        "{}",
        t.seconds
    );
    assert!(stats.table().contains("Z -"));
}

// ------------------------------------------------------------ command line

fn ncpost() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ncpost"))
}

fn corpus(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/gcode")
        .join(name)
}

/// A Prusa MINI-like printer (its firmware's M203/M201/M566 defaults) for `ncpost stats`.
const MINI: &str = r#"
description = "Prusa MINI-like printer: speeds, accelerations and jerk for the time estimate"
[[passes]]
name = "stats"
[passes.options.controller]
max_feed = { X = 10800.0, Y = 10800.0, Z = 720.0 }
acceleration = { X = 1250.0, Y = 1250.0, Z = 200.0 }
jerk = { X = 480.0, Y = 480.0, Z = 120.0 }
"#;

fn stats_of(timing: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let preset = dir.path().join("mini.toml");
    std::fs::write(&preset, MINI).unwrap();
    let out = ncpost()
        .args(["stats", "--timing", timing, "--config"])
        .arg(&preset)
        .arg(corpus("gcodenom_mini_cube_a_prusaslicer.gcode"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The preset's stats pass feeds the table; it does not report on its own.
    assert!(
        out.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn stats_table_on_a_sliced_file() {
    let cv = stats_of("constant-velocity");
    let tr = stats_of("trapezoid");
    insta::assert_snapshot!("stats_cube_constant_velocity", cv);
    insta::assert_snapshot!("stats_cube_trapezoid", tr);
    let secs = |s: &str| -> f64 {
        let line = s.lines().find(|l| l.starts_with("time")).unwrap();
        line.split_whitespace().nth(1).unwrap().parse().unwrap()
    };
    // PrusaSlicer estimates 32 min 6 s for this file (its own planner, the same machine
    // limits): the trapezoid model agrees within 1 %, constant velocity is 5 % short.
    let prusa = 32.0 * 60.0 + 6.0;
    assert!(close(secs(&tr), prusa, 0.01), "{}", secs(&tr));
    assert!(secs(&cv) < 0.96 * prusa, "{}", secs(&cv));
}

#[test]
fn run_timing_reaches_the_stats_pass() {
    let file = corpus("gcodenom_mini_cube_a_prusaslicer.gcode");
    let dir = tempfile::tempdir().unwrap();
    let preset = dir.path().join("mini.toml");
    std::fs::write(&preset, MINI).unwrap();
    let run = |timing: &str| {
        let out = ncpost()
            .args(["run", "--timing", timing, "--config"])
            .arg(&preset)
            .arg(&file)
            .arg("-o")
            .arg(dir.path().join("out.gcode"))
            .output()
            .unwrap();
        assert!(out.status.success());
        String::from_utf8(out.stderr).unwrap()
    };
    assert!(run("trapezoid").contains("(trapezoid)"));
    assert!(run("constant-velocity").contains("(constant velocity)"));
    let out = ncpost()
        .args(["run", "--timing", "sideways", "x.gcode"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn plot_speed_writes_an_svg() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in.gcode");
    std::fs::write(
        &input,
        "G0 X0 Y0 Z0\nM3 S40\nG1 X30 Y40 F3000\nM3 S80\nG1 X0\nM5\n",
    )
    .unwrap();
    let svg = dir.path().join("speed.svg");
    let out = ncpost()
        .args(["plot", "--speed", "--timing", "trapezoid"])
        .arg(&input)
        .arg("-o")
        .arg(&svg)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.starts_with("<svg") && text.trim_end().ends_with("</svg>"));
    for label in [
        ">v (mm/s)<",
        ">X speed (mm/s)<",
        ">Y speed (mm/s)<",
        ">screw (rpm)<",
    ] {
        assert!(text.contains(label), "{label}");
    }
    // The total time: 50 mm then 30 mm at 50 mm/s, no acceleration limit: 1.6 s.
    assert!(text.contains("time 0 .. 1.600 s"), "{text}");
}
