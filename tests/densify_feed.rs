//! The `densify` and `feed` passes: the joint-linear path between emitted blocks stays
//! within tolerance of the programmed CL segment, and the printed feeds make the controller
//! take the programmed tool-tip time.

use std::cell::RefCell;
use std::io::Write;
use std::rc::Rc;

use nalgebra::{Point3, Rotation3, Unit, Vector3};
use ncpost::back::{Backend, Decimals, rrf};
use ncpost::diag::{Diagnostic, Severity};
use ncpost::ir::{
    Axis, AxisSet, Block, BlockKind, Command, Feed, FeedMode, Joints, Motion, MotionKind,
    OffsetChange, OffsetCode, Span, Target, dump,
};
use ncpost::machine::{Machine, ToolPose};
use ncpost::passes::{self, Context};
use ncpost::preset::Preset;
use proptest::prelude::*;

mod common;
use common::geometry::{angle_to_arc, distance_to_segment, unit};

const PRESETS: [&str; 4] = ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"];

fn preset(name: &str) -> Preset {
    let text = std::fs::read_to_string(format!("passes/{name}.toml")).expect("preset file");
    Preset::from_toml(&text).expect("preset")
}

fn machine(name: &str) -> Machine {
    preset(name).machine.expect("machine")
}

fn emoc_decimals() -> Decimals {
    preset("emoc-x5").rrf.decimals
}

fn joints(m: &Machine, xyz: [f64; 3], angles: [f64; 2]) -> Joints {
    let mut j = Joints::default();
    j.set(Axis::X, xyz[0]);
    j.set(Axis::Y, xyz[1]);
    j.set(Axis::Z, xyz[2]);
    let [r0, r1] = m.rotary_axes();
    j.set(r0, angles[0]);
    j.set(r1, angles[1]);
    j
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

fn near_turn(v: f64, target: f64) -> f64 {
    v + 360.0 * ((target - v) / 360.0).round()
}

/// What `ik` + `unwrap-rotary` do for a pose: the solution nearest `prev`.
fn solve(m: &Machine, tip: Point3<f64>, axis: Unit<Vector3<f64>>, prev: [f64; 2]) -> Joints {
    let sols = m.inverse(axis);
    let angles = if sols.iter().any(|s| s.free.is_some()) {
        let k = m.singular_rotary(axis);
        m.hold(axis, k, prev[k]).angles
    } else {
        let mut best = None;
        for s in &sols {
            let a = [
                near_turn(s.angles[0], prev[0]),
                near_turn(s.angles[1], prev[1]),
            ];
            let cost = (a[0] - prev[0]).powi(2) + (a[1] - prev[1]).powi(2);
            if best.is_none_or(|(_, c)| cost < c) {
                best = Some((a, cost));
            }
        }
        best.expect("reachable").0
    };
    joints(m, m.linear(&tip, angles), angles)
}

fn span(line: u32) -> Span {
    Span {
        offset: line as u64 * 10,
        len: 5,
        line,
    }
}

fn motion(line: u32, kind: MotionKind, target: Joints, rate: Option<f64>) -> Block {
    Block::new(
        span(line),
        BlockKind::Motion(Motion {
            kind,
            target: Target::Joints(target),
            feed: Feed {
                mode: FeedMode::PerMinute,
                rate,
            },
            written: target.known,
            machine_frame: false,
            extra: String::new(),
        }),
    )
}

fn run(
    name: &str,
    options: &str,
    m: &Machine,
    decimals: Option<Decimals>,
    blocks: Vec<Block>,
) -> (Vec<Block>, Vec<Diagnostic>) {
    let opts: toml::Table = toml::from_str(options).expect("options");
    let ctx = Context {
        machine: Some(m),
        decimals,
        ..Context::default()
    };
    common::run_pass(name, &opts, &ctx, blocks)
}

fn target(b: &Block) -> Option<Joints> {
    match &b.kind {
        BlockKind::Motion(m) => m.target.joints().copied(),
        _ => None,
    }
}

fn feed_of(b: &Block) -> Feed {
    match &b.kind {
        BlockKind::Motion(m) => m.feed,
        _ => panic!("not a motion"),
    }
}

/// Checks every emitted piece from `start` against the CL segment `cl0`-`cl1`: 200
/// samples of the joint-linear path per piece. Returns the worst (tip, axis) deviation.
fn check_pieces(
    m: &Machine,
    start: &Joints,
    pieces: &[Joints],
    cl0: &ToolPose,
    cl1: &ToolPose,
) -> (f64, f64) {
    let mut worst = (0.0f64, 0.0f64);
    let mut a = *start;
    for b in pieces {
        let (x0, r0) = five(m, &a);
        let (x1, r1) = five(m, b);
        // Every block is on the programmed segment before printing.
        let pb = fk(m, b);
        assert!(distance_to_segment(&pb.tip, &cl0.tip, &cl1.tip) < 1e-6);
        for k in 0..=200 {
            let s = k as f64 / 200.0;
            let l = |p: f64, q: f64| p + (q - p) * s;
            let pose = m.forward(
                &[l(x0[0], x1[0]), l(x0[1], x1[1]), l(x0[2], x1[2])],
                [l(r0[0], r1[0]), l(r0[1], r1[1])],
            );
            worst.0 = worst
                .0
                .max(distance_to_segment(&pose.tip, &cl0.tip, &cl1.tip));
            worst.1 = worst.1.max(angle_to_arc(&pose.axis, &cl0.axis, &cl1.axis));
        }
        a = *b;
    }
    worst
}

/// Runs densify on one move from `j0` to `j1`; returns the pieces and diagnostics.
fn densify_move(
    m: &Machine,
    options: &str,
    j0: Joints,
    j1: Joints,
) -> (Vec<Joints>, Vec<Diagnostic>) {
    let blocks = vec![
        motion(1, MotionKind::Rapid, j0, None),
        motion(2, MotionKind::Linear, j1, Some(500.0)),
    ];
    let (out, diags) = run("densify", options, m, None, blocks);
    assert_eq!(target(&out[0]), Some(j0));
    for b in &out[1..] {
        assert_eq!(b.span, span(2));
        assert_eq!(feed_of(b).rate, Some(500.0));
    }
    (out[1..].iter().filter_map(target).collect(), diags)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(160))]

    /// After densify, the joint-linear path between consecutive emitted blocks stays
    /// within the tolerances of the original CL segment, on every preset, for short and
    /// long moves.
    #[test]
    fn densified_path_follows_the_cl_segment(
        which in 0usize..4,
        theta in 0.0f64..70.0, phi in -180.0f64..180.0,
        px in -80.0f64..80.0, py in -80.0f64..80.0, pz in -20.0f64..80.0,
        len_exp in -2.0f64..2.3, dir_t in 0.0f64..180.0, dir_p in -180.0f64..180.0,
        turn_exp in -2.0f64..1.85, turn_dir in -180.0f64..180.0,
    ) {
        let m = machine(PRESETS[which]);
        let tip0 = Point3::new(px, py, pz);
        let axis0 = unit(theta, phi);
        let tip1 = tip0 + unit(dir_t, dir_p).into_inner() * 10f64.powf(len_exp);
        // Turn the axis by 10^turn_exp degrees about a direction across it.
        let across = axis0.cross(&unit(90.0, turn_dir)).try_normalize(1e-9);
        prop_assume!(across.is_some());
        let rot = Rotation3::from_axis_angle(
            &Unit::new_normalize(across.unwrap_or_else(Vector3::x)),
            10f64.powf(turn_exp).to_radians(),
        );
        let axis1 = Unit::new_normalize(rot * axis0.into_inner());
        // Stay away from singular orientations along the arc (the ik pass's business).
        let min_sing = (0..=50)
            .map(|k| {
                let t = k as f64 / 50.0;
                let v = Unit::new_normalize(axis0.slerp(&axis1, t).into_inner());
                m.singularity_distance(v)
            })
            .fold(f64::INFINITY, f64::min);
        prop_assume!(min_sing > 0.5);
        let sols = m.inverse(axis0);
        prop_assume!(!sols.is_empty());
        let j0 = joints(&m, m.linear(&tip0, sols[0].angles), sols[0].angles);
        // ik on a fine CL sequence along the arc: the branch the path continues on.
        let (_, mut angles) = five(&m, &j0);
        for k in 1..=200 {
            let t = k as f64 / 200.0;
            let v = Unit::new_normalize(axis0.slerp(&axis1, t).into_inner());
            angles = five(&m, &solve(&m, tip0, v, angles)).1;
        }
        let j1 = solve(&m, tip1, axis1, angles);
        let (pieces, diags) = densify_move(&m, "", j0, j1);
        prop_assert!(diags.is_empty(), "{:?}", diags);
        prop_assert_eq!(pieces.last().copied(), Some(j1));
        let cl0 = ToolPose { tip: tip0, axis: axis0 };
        let cl1 = ToolPose { tip: tip1, axis: axis1 };
        let (tip_dev, axis_dev) = check_pieces(&m, &j0, &pieces, &cl0, &cl1);
        prop_assert!(tip_dev <= 0.01 + 1e-9, "{}: tip off by {tip_dev} over {} pieces", PRESETS[which], pieces.len());
        prop_assert!(axis_dev <= 0.05 + 1e-9, "{}: axis off by {axis_dev} deg", PRESETS[which]);
    }
}

/// A move through the singular orientation (tool vertical on the cradle): C is held at
/// its interpolated value there, the path still follows the segment.
#[test]
fn densify_through_the_singularity() {
    let m = machine("emoc-x5");
    let cl0 = m.forward(&[20.0, 10.0, 5.0], [20.0, 30.0]);
    let j0 = joints(&m, [20.0, 10.0, 5.0], [20.0, 30.0]);
    let cl1 = ToolPose {
        tip: cl0.tip + Vector3::new(30.0, -5.0, 2.0),
        axis: m.forward(&[0.0; 3], [-20.0, 30.0]).axis,
    };
    let j1 = joints(&m, m.linear(&cl1.tip, [-20.0, 30.0]), [-20.0, 30.0]);
    let (pieces, diags) = densify_move(&m, "", j0, j1);
    assert!(diags.is_empty(), "{diags:?}");
    assert!(pieces.len() > 4);
    let (tip, axis) = check_pieces(&m, &j0, &pieces, &cl0, &cl1);
    assert!(tip <= 0.01 + 1e-9 && axis <= 0.05 + 1e-9, "{tip} {axis}");
    // C stays on its branch: the pieces never leave 30 deg.
    for p in &pieces {
        assert!((p.get(Axis::C).unwrap() - 30.0).abs() < 1e-9, "{p:?}");
    }
}

/// A move within tolerance is the same block; tighter tolerances split it.
#[test]
fn densify_keeps_short_moves_and_obeys_options() {
    let m = machine("emoc-x5");
    let j0 = joints(&m, [10.0, 0.0, 0.0], [10.0, 0.0]);
    let j1 = joints(&m, [10.2, 0.1, 0.0], [10.2, 0.3]);
    let (pieces, diags) = densify_move(&m, "", j0, j1);
    assert_eq!(pieces, vec![j1]);
    assert!(diags.is_empty());
    let (pieces, _) = densify_move(&m, "tip_tolerance = 1e-6", j0, j1);
    assert!(pieces.len() > 1);
    let (pieces, _) = densify_move(&m, "axis_tolerance = 1e-6", j0, j1);
    assert!(pieces.len() > 1);

    // A long swing with one halving allowed: two pieces and a warning.
    let j2 = joints(&m, [10.0, 0.0, 0.0], [60.0, 120.0]);
    let (pieces, diags) = densify_move(&m, "max_depth = 1", j0, j2);
    assert_eq!(pieces.len(), 2);
    assert_eq!(diags.len(), 1);
    assert_eq!(diags[0].code, "densify::depth");
    assert_eq!(diags[0].location.as_ref().map(|l| l.line), Some(2));

    // Rapids are only split on request.
    let blocks = || {
        vec![
            motion(1, MotionKind::Rapid, j0, None),
            motion(2, MotionKind::Rapid, j2, None),
        ]
    };
    let (out, _) = run("densify", "", &m, None, blocks());
    assert_eq!(out.len(), 2);
    let (out, _) = run("densify", "rapids = true", &m, None, blocks());
    assert!(out.len() > 10);

    // A command that clobbers an axis: the next move starts from an unknown position.
    let homing = Block::new(
        span(2),
        BlockKind::Command(Command {
            text: "G28 Z".into(),
            modes: None,
            clobbers: [Axis::Z].into_iter().collect::<AxisSet>(),
        }),
    );
    let (out, _) = run(
        "densify",
        "",
        &m,
        None,
        vec![
            motion(1, MotionKind::Rapid, j0, None),
            homing,
            motion(3, MotionKind::Linear, j2, Some(100.0)),
        ],
    );
    assert_eq!(out.len(), 3);

    // Bad options are refused.
    let ctx = Context {
        machine: Some(&m),
        decimals: None,
        ..Context::default()
    };
    for bad in ["tip_tolerance = 0.0", "axis_tolerance = 95.0", "bogus = 1"] {
        let t: toml::Table = toml::from_str(bad).unwrap();
        assert!(passes::build("densify", &t, &ctx).is_err(), "{bad}");
    }
    assert!(passes::build("densify", &toml::Table::new(), &Context::default()).is_err());
}

/// A writer whose output can be read while it is alive.
#[derive(Clone, Default)]
struct Shared(Rc<RefCell<Vec<u8>>>);

impl Write for Shared {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.borrow_mut().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// What the controller knows from the printed text: a tiny G-code reader.
#[derive(Default)]
struct Controller {
    pos: [Option<f64>; 5],
    feed: Option<f64>,
    inverse_time: bool,
    offsets: [f64; 5],
}

const LETTERS: [char; 5] = ['X', 'Y', 'Z', 'A', 'C'];

/// One G1 as the controller runs it: start and end (program frame), time in minutes.
struct Run {
    start: [f64; 5],
    end: [f64; 5],
    minutes: f64,
    text: String,
}

impl Controller {
    fn line(&mut self, line: &str) -> Option<Run> {
        let code = line.split(';').next().unwrap_or("");
        let words: Vec<(char, f64)> = code
            .split_whitespace()
            .map(|w| {
                let mut c = w.chars();
                let l = c.next().expect("letter");
                (l, c.as_str().parse::<f64>().expect("number"))
            })
            .collect();
        let has = |l: char, n: f64| words.iter().any(|&(c, v)| c == l && v == n);
        if has('G', 93.0) {
            self.inverse_time = true;
        }
        if has('G', 94.0) {
            self.inverse_time = false;
        }
        if let Some(&(_, f)) = words.iter().find(|w| w.0 == 'F') {
            self.feed = Some(f);
        }
        let start = self.pos;
        for &(l, v) in &words {
            if let Some(k) = LETTERS.iter().position(|&c| c == l) {
                if has('G', 92.0) {
                    // The position stays; the frame moves.
                    let old = self.pos[k].expect("known before G92");
                    self.offsets[k] += v - old;
                }
                self.pos[k] = Some(v);
            }
        }
        if !has('G', 1.0) {
            return None;
        }
        let start: [f64; 5] = std::array::from_fn(|k| start[k].expect("known start"));
        let end: [f64; 5] = std::array::from_fn(|k| self.pos[k].expect("known end"));
        let f = self.feed.expect("a feed");
        let minutes = if self.inverse_time {
            1.0 / f
        } else {
            let d = |r: std::ops::Range<usize>| {
                r.map(|k| (end[k] - start[k]).powi(2)).sum::<f64>().sqrt()
            };
            // NIST RS274NGC 2.1.2.5, as RepRapFirmware does it.
            if d(0..3) > 0.0 {
                d(0..3) / f
            } else {
                d(3..5) / f
            }
        };
        Some(Run {
            start,
            end,
            minutes,
            text: line.to_string(),
        })
    }
}

/// One CL step for the feed test: tip, axis, programmed feed.
struct Step {
    tip: Point3<f64>,
    axis: Unit<Vector3<f64>>,
    feed: f64,
}

/// A pose sequence on the E-moc X5: varying tool axis, short and long moves, a G92
/// offset, a pure reorientation about the tip and a rotary-only move.
fn emoc_program(m: &Machine) -> (Vec<Block>, Vec<Option<Step>>) {
    let mut steps: Vec<Step> = Vec::new();
    let mut push = |tip: Point3<f64>, axis: Unit<Vector3<f64>>, feed: f64| {
        steps.push(Step { tip, axis, feed });
    };
    let p = |x, y, z| Point3::new(x, y, z);
    push(p(0.0, 0.0, 30.0), unit(10.0, 30.0), 0.0);
    push(p(40.0, 10.0, 20.0), unit(25.0, 60.0), 800.0);
    push(p(40.3, 10.1, 20.0), unit(25.5, 61.0), 800.0);
    push(p(-30.0, 45.0, 5.0), unit(40.0, 150.0), 1200.0);
    push(p(-30.0, 45.0, 4.0), unit(40.0, 150.0), 150.0);
    push(p(-29.0, 45.0, 4.0), unit(0.0, 0.0), 300.0);
    push(p(0.05, 0.0, 4.0), unit(5.0, -90.0), 2000.0);
    // On the A axis (machine y = 0, z = 100 at C = 0): a pure reorientation, tip fixed.
    push(p(10.0, 0.0, 100.0), unit(0.0, 0.0), 1000.0);
    push(p(10.0, 0.0, 100.0), unit(30.0, -90.0), 1000.0);
    let mut blocks = Vec::new();
    let mut cl: Vec<Option<Step>> = vec![None];
    let mut prev = [0.0, 0.0];
    for (i, s) in steps.into_iter().enumerate() {
        let j = solve(m, s.tip, s.axis, prev);
        prev = five(m, &j).1;
        let line = cl.len() as u32;
        if i == 0 {
            blocks.push(motion(line, MotionKind::Rapid, j, None));
        } else {
            blocks.push(motion(line, MotionKind::Linear, j, Some(s.feed)));
        }
        cl.push(Some(s));
        if i == 4 {
            // G92: declare X 7 mm further on.
            let mut declared = Joints::default();
            declared.set(Axis::X, j.get(Axis::X).unwrap() + 7.0);
            let mut offsets = [0.0; 10];
            offsets[0] = 7.0;
            blocks.push(Block::new(
                span(cl.len() as u32),
                BlockKind::Offset(OffsetChange {
                    code: OffsetCode::Set,
                    declared,
                    offsets,
                }),
            ));
            cl.push(None);
        }
    }
    // Rotary-only: C turns half a degree with X, Y, Z still, the tip 50 mm off the axis
    // (within tolerance, so densify keeps it whole).
    let last = target(blocks.last().unwrap()).unwrap();
    let (_, a) = five(m, &last);
    let j_start = joints(m, [50.0, 0.0, 10.0], [a[0], a[1]]);
    let j_end = joints(m, [50.0, 0.0, 10.0], [a[0], a[1] + 0.5]);
    for (j, f) in [(j_start, 700.0), (j_end, 600.0)] {
        let pose = fk(m, &j);
        blocks.push(motion(cl.len() as u32, MotionKind::Linear, j, Some(f)));
        cl.push(Some(Step {
            tip: pose.tip,
            axis: pose.axis,
            feed: f,
        }));
    }
    (blocks, cl)
}

/// ik-equivalent joints → densify → feed → rrf text; every G1's time under the NIST
/// rule (or G93), computed from the printed numbers, is the tip length over the
/// programmed feed within 1 %.
fn check_printed_times(feed_options: &str, inverse_time: bool) -> Vec<Run> {
    let m = machine("emoc-x5");
    let decimals = emoc_decimals();
    let (blocks, cl) = emoc_program(&m);
    let (dense, diags) = run("densify", "", &m, None, blocks);
    assert!(diags.is_empty(), "{diags:?}");
    let (fed, diags) = run("feed", feed_options, &m, Some(decimals), dense);
    assert!(
        diags.iter().all(|d| d.severity != Severity::Error),
        "{diags:?}"
    );
    let buf = Shared::default();
    let mut writer = rrf::Writer::new(
        buf.clone(),
        &rrf::Options {
            decimals,
            inverse_time,
            ..rrf::Options::default()
        },
    );
    let mut ctl = Controller::default();
    let mut runs = Vec::new();
    let mut seen = 0;
    let mut wdiags = Vec::new();
    for b in &fed {
        writer.write_block(b, &mut wdiags).expect("printable");
        let text = String::from_utf8(buf.0.borrow().clone()).unwrap();
        let new = &text[seen..];
        seen = text.len();
        for line in new.lines() {
            let Some(r) = ctl.line(line) else { continue };
            let step = cl[b.span.line as usize].as_ref().expect("a CL step");
            let off = ctl.offsets;
            let ir = |v: &[f64; 5]| std::array::from_fn::<f64, 5, _>(|k| v[k] - off[k]);
            let (s, e) = (ir(&r.start), ir(&r.end));
            let tip = |v: [f64; 5]| m.forward(&[v[0], v[1], v[2]], [v[3], v[4]]).tip;
            let length = (tip(e) - tip(s)).norm();
            let rot = (e[3] - s[3]).hypot(e[4] - s[4]);
            let expected = if length < 1e-3 && rot > 0.0 {
                rot / 1000.0
            } else {
                length / step.feed
            };
            let ratio = r.minutes / expected;
            assert!(
                (ratio - 1.0).abs() < 0.01,
                "`{}`: controller takes {} min, programmed {} min",
                r.text,
                r.minutes,
                expected
            );
            runs.push(r);
        }
    }
    assert!(wdiags.is_empty(), "{wdiags:?}");
    let text = String::from_utf8(buf.0.borrow().clone()).unwrap();
    assert_eq!(text.contains("G93"), inverse_time, "{text}");
    runs
}

#[test]
fn printed_feeds_give_the_programmed_time_nist() {
    let runs = check_printed_times("", false);
    assert!(runs.len() > 15, "densify split the long moves");
    // The pure reorientation and the rotary-only move print rotary words only.
    let rotary_only: Vec<&Run> = runs
        .iter()
        .filter(|r| (0..3).all(|k| r.start[k] == r.end[k]))
        .collect();
    assert_eq!(
        rotary_only.len(),
        2,
        "{:?}",
        rotary_only.iter().map(|r| &r.text).collect::<Vec<_>>()
    );
    // A turns about the tip at reorient_feed (F1000, already modal there).
    assert_eq!(rotary_only[0].text, "G1 A30");
    assert!(rotary_only[1].text.starts_with("G1 C"));
}

#[test]
fn printed_feeds_give_the_programmed_time_inverse_time() {
    let runs = check_printed_times("mode = \"inverse-time\"", true);
    assert!(runs.len() > 15);
}

/// Builds a one-move program from `a` to `b` and runs `feed` on it.
fn feed_move(
    m: &Machine,
    options: &str,
    decimals: Option<Decimals>,
    a: Joints,
    b: Joints,
    rate: Option<f64>,
) -> (Feed, Vec<Diagnostic>) {
    let blocks = vec![
        motion(1, MotionKind::Rapid, a, None),
        motion(2, MotionKind::Linear, b, rate),
    ];
    let (out, diags) = run("feed", options, m, decimals, blocks);
    assert_eq!(out.len(), 2);
    assert_eq!(target(&out[1]), Some(b), "joint values stay exact");
    (feed_of(&out[1]), diags)
}

#[test]
fn feed_rules() {
    let m = machine("emoc-x5");
    // A plain XYZ move at A = C = 0: the tip moves with X, Y, Z.
    let a = joints(&m, [0.0, 0.0, 0.0], [0.0, 0.0]);
    let b = joints(&m, [30.0, 40.0, 0.0], [0.0, 0.0]);
    for mode in ["nist", "euclidean"] {
        let (f, diags) = feed_move(&m, &format!("mode = \"{mode}\""), None, a, b, Some(600.0));
        assert_eq!(f.mode, FeedMode::PerMinute);
        assert!((f.rate.unwrap() - 600.0).abs() < 1e-9, "{mode}: {f:?}");
        assert!(diags.is_empty());
    }
    let (f, _) = feed_move(&m, "mode = \"inverse-time\"", None, a, b, Some(600.0));
    assert_eq!(f.mode, FeedMode::InverseTime);
    assert!(
        (f.rate.unwrap() - 12.0).abs() < 1e-9,
        "50 mm at 600 mm/min: 1/12 min"
    );

    // With a rotary turning: the tip travels L (from forward kinematics), the rule's
    // distance over L/F is the feed.
    let c = joints(&m, [32.0, 41.0, -3.0], [4.0, 7.0]);
    let length = (fk(&m, &c).tip - fk(&m, &a).tip).norm();
    let t = length / 500.0;
    let dxyz = (32.0f64 * 32.0 + 41.0 * 41.0 + 9.0).sqrt();
    let all = (dxyz * dxyz + 16.0 + 49.0).sqrt();
    let (f, _) = feed_move(&m, "", None, a, c, Some(500.0));
    assert!((f.rate.unwrap() - dxyz / t).abs() < 1e-6);
    let (f, _) = feed_move(&m, "mode = \"euclidean\"", None, a, c, Some(500.0));
    assert!((f.rate.unwrap() - all / t).abs() < 1e-6);
    let (f, _) = feed_move(&m, "mode = \"inverse-time\"", None, a, c, Some(500.0));
    assert!((f.rate.unwrap() - 1.0 / t).abs() < 1e-6);

    // The machine's rule is the default.
    let mut m2 = m.clone();
    m2.controller.feed_rule = ncpost::machine::FeedRule::InverseTime;
    let (f, _) = feed_move(&m2, "", None, a, b, Some(600.0));
    assert_eq!(f.mode, FeedMode::InverseTime);

    // Rotary only, tip 50 mm from the C axis: degrees over the tip time.
    let r0 = joints(&m, [50.0, 0.0, 0.0], [0.0, 0.0]);
    let r1 = joints(&m, [50.0, 0.0, 0.0], [0.0, 2.0]);
    let chord = 2.0 * 50.0 * 1f64.to_radians().sin();
    let (f, _) = feed_move(&m, "", None, r0, r1, Some(400.0));
    assert!((f.rate.unwrap() - 2.0 / (chord / 400.0)).abs() < 1e-6);

    // A pure reorientation about the tip (on the A axis): reorient_feed.
    let o0 = joints(&m, [10.0, 0.0, 100.0], [0.0, 0.0]);
    let o1 = joints(&m, [10.0, 0.0, 100.0], [30.0, 0.0]);
    assert!((fk(&m, &o1).tip - fk(&m, &o0).tip).norm() < 1e-9);
    let (f, _) = feed_move(&m, "reorient_feed = 720.0", None, o0, o1, Some(400.0));
    assert!((f.rate.unwrap() - 720.0).abs() < 1e-9);
    let (f, _) = feed_move(&m, "mode = \"inverse-time\"", None, o0, o1, Some(400.0));
    assert!((f.rate.unwrap() - 1000.0 / 30.0).abs() < 1e-9);
}

#[test]
fn feed_uses_the_printed_numbers() {
    let m = machine("emoc-x5");
    let d = Decimals {
        linear: 1,
        rotary: 1,
        extruder: 5,
        feed: 3,
    };
    // 10.04 prints as 10.0: the controller moves 10 mm, not 10.04.
    let a = joints(&m, [0.0, 0.0, 0.0], [0.0, 0.0]);
    let b = joints(&m, [10.04, 0.0, 0.0], [0.0, 0.0]);
    let (f, diags) = feed_move(&m, "", Some(d), a, b, Some(100.0));
    assert!((f.rate.unwrap() - 100.0).abs() < 1e-9, "{f:?}");
    assert!(diags.is_empty());
    let (f, _) = feed_move(&m, "mode = \"inverse-time\"", Some(d), a, b, Some(100.0));
    assert!((f.rate.unwrap() - 10.0).abs() < 1e-9, "{f:?}");
}

#[test]
fn feed_warnings_and_errors() {
    let mut m = machine("emoc-x5");
    // RepRapFirmware's default floor (the emoc-x5 preset lowers it with M203 I6).
    m.controller.min_speed = Some(30.0);
    let d = emoc_decimals();
    // X moves 0.01 mm while C swings the tip 0.87 mm: 11 mm/min is below 30.
    let a = joints(&m, [50.0, 0.0, 0.0], [0.0, 0.0]);
    let b = joints(&m, [50.01, 0.0, 0.0], [0.0, 1.0]);
    let (_, diags) = feed_move(&m, "", Some(d), a, b, Some(1000.0));
    let codes: Vec<_> = diags.iter().map(|d| d.code).collect();
    assert_eq!(codes, ["feed::min-speed"]);
    assert_eq!(diags[0].location.as_ref().map(|l| l.line), Some(2));

    // 5000 mm/min along X is over its max_feed of 3000.
    let b = joints(&m, [60.0, 0.0, 0.0], [0.0, 0.0]);
    let (_, diags) = feed_move(&m, "", Some(d), a, b, Some(5000.0));
    let codes: Vec<_> = diags.iter().map(|d| d.code).collect();
    assert_eq!(codes, ["feed::max-speed"]);

    // Inverse time over a long, slow move: 1/F = 3 min, which the 2 feed decimals printed
    // as 0.33 (1 % off), gets the decimals that keep it within 0.1 %.
    let b = joints(&m, [350.0, 0.0, 0.0], [0.0, 0.0]);
    let (f, diags) = feed_move(&m, "mode = \"inverse-time\"", Some(d), a, b, Some(100.0));
    assert!(diags.is_empty(), "{diags:?}");
    let rate = f.rate.expect("a rate");
    let printed = d.printed_feed(rate).expect("printable");
    assert!((printed * 3.0 - 1.0).abs() <= 1e-3, "{printed}");

    // No feed: an error at the move.
    let (f, diags) = feed_move(&m, "", Some(d), a, b, None);
    assert_eq!(f.rate, None);
    assert_eq!(diags.len(), 1);
    assert_eq!(diags[0].code, "feed::missing");
    assert_eq!(diags[0].severity, Severity::Error);
    assert_eq!(diags[0].location.as_ref().map(|l| l.line), Some(2));

    // Counted once, summarised at the end.
    let mut blocks = vec![motion(1, MotionKind::Rapid, a, None)];
    for k in 1..6 {
        let j = joints(&m, [50.0 + k as f64, 0.0, 0.0], [0.0, 0.0]);
        blocks.push(motion(2 + k, MotionKind::Linear, j, Some(10.0)));
    }
    let (_, diags) = run("feed", "", &m, Some(d), blocks);
    let codes: Vec<_> = diags.iter().map(|d| d.code).collect();
    assert_eq!(codes, ["feed::min-speed", "feed::min-speed"]);
    assert!(diags[1].message.starts_with("5 "), "{}", diags[1].message);

    // Rapids and moves from an unknown position pass unchanged.
    let mut unknown = a;
    unknown.forget([Axis::C].into_iter().collect());
    let blocks = vec![
        motion(1, MotionKind::Rapid, unknown, None),
        motion(2, MotionKind::Linear, b, Some(100.0)),
        motion(3, MotionKind::Rapid, a, None),
    ];
    let (out, diags) = run("feed", "", &m, Some(d), blocks.clone());
    assert_eq!(out, blocks);
    assert!(diags.is_empty());

    let ctx = Context {
        machine: Some(&m),
        decimals: None,
        ..Context::default()
    };
    for bad in ["reorient_feed = 0.0", "mode = \"fast\"", "bogus = 1"] {
        let t: toml::Table = toml::from_str(bad).unwrap();
        assert!(passes::build("feed", &t, &ctx).is_err(), "{bad}");
    }
}

/// A move after one to a pose (whose joints `feed` does not know) starts at an unknown
/// position: its feed stays as programmed, not one worked out from the move before the
/// pose.
#[test]
fn feed_forgets_the_position_at_a_pose() {
    let m = machine("emoc-x5");
    let d = emoc_decimals();
    let a = joints(&m, [0.0, 0.0, 0.0], [0.0, 0.0]);
    let b = joints(&m, [10.0, 0.0, 0.0], [0.0, 0.0]);
    let c = joints(&m, [10.0, 20.0, 0.0], [0.0, 30.0]);
    let mut pose = motion(3, MotionKind::Rapid, b, None);
    if let BlockKind::Motion(mo) = &mut pose.kind {
        mo.target = Target::Pose(ncpost::ir::Pose::new(
            Point3::new(50.0, 50.0, 50.0),
            Vector3::z_axis(),
        ));
    }
    let blocks = vec![
        motion(1, MotionKind::Rapid, a, None),
        motion(2, MotionKind::Linear, b, Some(500.0)),
        pose,
        motion(4, MotionKind::Linear, c, Some(500.0)),
    ];
    let (out, diags) = run("feed", "", &m, Some(d), blocks.clone());
    assert!(diags.is_empty(), "{diags:?}");
    assert_eq!(feed_of(&out[1]).rate, Some(500.0), "a plain X move");
    assert_eq!(out[2], blocks[2]);
    assert_eq!(out[3], blocks[3], "from an unknown position the feed stays");
}

/// A tiny E-moc X5 program: a rapid in, a long tilting cut that densify splits, a short
/// cut that it keeps, a tool change in between.
fn tiny_emoc() -> (Machine, Vec<Block>) {
    let m = machine("emoc-x5");
    let j0 = solve(
        &m,
        Point3::new(-10.0, 0.0, 10.0),
        unit(10.0, 0.0),
        [10.0, 90.0],
    );
    let j1 = solve(
        &m,
        Point3::new(10.0, 0.0, 10.0),
        unit(14.0, 0.0),
        [10.0, 90.0],
    );
    let (_, a1) = five(&m, &j1);
    let j2 = solve(&m, Point3::new(10.5, 0.2, 10.0), unit(14.2, 0.5), a1);
    let mut blocks = vec![
        motion(1, MotionKind::Rapid, j0, None),
        motion(2, MotionKind::Linear, j1, Some(600.0)),
        Block::new(
            span(3),
            BlockKind::Command(Command {
                text: "M3 S12000".into(),
                modes: None,
                clobbers: AxisSet::EMPTY,
            }),
        ),
        motion(4, MotionKind::Linear, j2, Some(300.0)),
    ];
    if let BlockKind::Motion(mo) = &mut blocks[1].kind {
        mo.extra = "S12000".into();
    }
    blocks[3].comments.push(ncpost::ir::Comment {
        text: " finish".into(),
        style: ncpost::ir::CommentStyle::Semicolon,
    });
    (m, blocks)
}

#[test]
fn snapshot_densify() {
    let (m, blocks) = tiny_emoc();
    let before = dump::to_string(&blocks);
    let (after, diags) = run("densify", "", &m, None, blocks);
    assert!(diags.is_empty());
    insta::assert_snapshot!(
        "densify",
        format!(
            "--- before\n{before}--- after densify\n{}",
            dump::to_string(&after)
        )
    );
}

#[test]
fn snapshot_feed() {
    let (m, blocks) = tiny_emoc();
    let (dense, _) = run("densify", "", &m, None, blocks);
    let before = dump::to_string(&dense);
    let (after, diags) = run("feed", "", &m, Some(emoc_decimals()), dense);
    assert!(diags.is_empty(), "{diags:?}");
    insta::assert_snapshot!(
        "feed",
        format!(
            "--- before\n{before}--- after feed\n{}",
            dump::to_string(&after)
        )
    );
}

/// Far from the rotary axes the last printed decimal of an angle is a long way for the
/// tip. A rotary that does not move and prints exactly costs nothing: the move stays one
/// block (it was cut into 2^16 pieces). One that prints inexactly so far out that no cut
/// can help gets `densify::rounding`, and the move is not cut into thousands of blocks.
#[test]
fn densify_far_from_the_rotary_axes() {
    let m = machine("emoc-x5");
    let d = Some(emoc_decimals());
    let far = |angles: [f64; 2]| {
        let j0 = joints(&m, [9.3, 4.86, -1.4], angles);
        let j1 = joints(&m, [9.4, 5.6, -20000.0], angles);
        let blocks = vec![
            motion(1, MotionKind::Rapid, j0, None),
            motion(2, MotionKind::Linear, j1, Some(3000.0)),
        ];
        run("densify", "", &m, d, blocks)
    };
    let (out, diags) = far([0.0, 90.0]);
    assert_eq!(out.len(), 2, "{out:?}");
    assert!(diags.is_empty(), "{diags:?}");

    let (out, diags) = far([0.123_456_789, 90.0]);
    let codes: Vec<&str> = diags.iter().map(|d| d.code).collect();
    assert_eq!(codes, ["densify::rounding"]);
    assert!(out.len() < 100, "{} blocks", out.len());
}
