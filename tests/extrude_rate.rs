//! The `extrude-rate` pass: material per block and per file from the printed output under the motion-time model (exact vs seed rule, both timings), the threshold, retraction/prime handling, e-axis conservation, constant-flow feeds, snapshots and the screw curve of `plot --speed`.

use ncpost::back::Backend;
use ncpost::diag::{Diagnostic, Severity};
use ncpost::front::gcode::{Options as GcodeOptions, parse_str};
use ncpost::ir::{Axis, Block, BlockKind, Joints, MotionKind, Target};
use ncpost::machine::polar::Polar;
use ncpost::motion::{Model, Planner, Timing, polar_point};
use ncpost::passes::{self, Context, Output};
use ncpost::pipeline::Pipeline;
use ncpost::preset::Preset;

const CUBE: &str = include_str!("fixtures/extrude_rate/gcodenom_mini_cube_a_prusaslicer.gcode");

/// The polar-printer preset with polar-ik centred at `center` and extrude-rate `options`.
fn preset(center: [f64; 2], options: &[(&str, toml::Value)]) -> Preset {
    let mut p = Preset::builtin("polar-printer").expect("preset");
    for spec in &mut p.passes {
        if spec.name == "polar-ik" {
            spec.options.insert(
                "center".into(),
                toml::Value::Array(vec![center[0].into(), center[1].into()]),
            );
        }
        if spec.name == "extrude-rate" {
            for (k, v) in options {
                spec.options.insert((*k).into(), v.clone());
            }
        }
    }
    assert!(p.passes.iter().any(|s| s.name == "extrude-rate"));
    p
}

fn compile(src: &str, preset: &Preset, timing: Option<Timing>) -> (String, Vec<Diagnostic>) {
    let mut b = Pipeline::builder().preset(preset.clone());
    if let Some(t) = timing {
        b = b.timing(t);
    }
    let mut pipeline = b.build().expect("pipeline");
    let mut out = Vec::new();
    let mut diags = Vec::new();
    let summary = pipeline
        .run_gcode(src.as_bytes(), &mut out, &mut |d| diags.push(d))
        .expect("run");
    assert_eq!(summary.errors, 0, "{diags:?}");
    (String::from_utf8(out).expect("utf8"), diags)
}

/// The screw speed a printed command sets (`M3 S<rpm>`).
fn rpm_of(text: &str) -> Option<f64> {
    let mut words = text.split_whitespace();
    if words.next()? != "M3" {
        return None;
    }
    words.find_map(|w| w.strip_prefix('S')?.parse().ok())
}

/// One timed item of the printed program.
#[derive(Debug, Clone)]
struct Piece {
    /// Cartesian tool point at its end (table frame).
    end: Option<[f64; 3]>,
    /// Seconds.
    seconds: f64,
    /// Screw speed in force, rev/min.
    rpm: f64,
    /// Whether it is a move.
    motion: bool,
}

/// Re-parses the printed program and times it with the polar controller's model:
/// every move and dwell with the screw speed in force.
fn timed_output(text: &str, polar: &Polar, timing: Timing) -> Vec<Piece> {
    let program = parse_str(text, &GcodeOptions::default()).expect("output parses");
    let model = Model::new(&polar.controller).with_timing(timing);
    let mut planner: Planner<Option<(Option<[f64; 3]>, f64)>> = Planner::new(model.clone());
    let mut pos = Joints::default();
    let mut rpm = 0.0;
    let mut pieces = Vec::new();
    let mut drain = |planner: &mut Planner<_>, pieces: &mut Vec<Piece>| {
        while let Some(t) = planner.pop() {
            if let Some((end, rpm)) = t.payload {
                pieces.push(Piece {
                    end,
                    seconds: t.duration(),
                    rpm,
                    motion: t.motion.is_some(),
                });
            }
        }
    };
    for b in &program.blocks {
        match &b.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(to) = m.target else {
                    panic!("pose in output")
                };
                assert!(
                    !m.written.contains(Axis::E),
                    "E left in the output, line {}",
                    b.span.line
                );
                let mut next = pos;
                for a in to.known.iter() {
                    next.set(a, to.values[a.index()]);
                }
                let seg = model.motion(&pos, m).expect("joints");
                let end =
                    (next.known.contains(Axis::X) && next.known.contains(Axis::Y)).then(|| {
                        let p = polar_point(&next, polar.r_axis, polar.theta_axis);
                        [p.x, p.y, p.z]
                    });
                planner.push_move(seg, Some((end, rpm)));
                pos = next;
            }
            BlockKind::Dwell { seconds } => planner.push_stop(*seconds, Some((None, rpm))),
            BlockKind::Command(c) => {
                if let Some(r) = rpm_of(&c.text) {
                    rpm = r;
                }
                if c.clobbers.is_empty() {
                    planner.push_other(None);
                } else {
                    pos.forget(c.clobbers);
                    planner.push_stop(0.0, None);
                }
            }
            BlockKind::Verbatim(v) => {
                pos.forget(v.clobbers);
                planner.push_stop(0.0, None);
            }
            _ => planner.push_other(None),
        }
        drain(&mut planner, &mut pieces);
    }
    planner.finish();
    drain(&mut planner, &mut pieces);
    pieces
}

/// One input move: its end (centred), ΔE, XY length and mid radius.
#[derive(Debug, Clone)]
struct InputMove {
    line: u32,
    end: [f64; 3],
    de: f64,
    length: f64,
    radius: f64,
    /// Moves the tool (not an E-only move).
    moves: bool,
}

fn input_moves(src: &str, center: [f64; 2]) -> Vec<InputMove> {
    let program = parse_str(src, &GcodeOptions::default()).expect("input parses");
    let mut pos = Joints::default();
    let mut moves = Vec::new();
    for b in &program.blocks {
        if let BlockKind::Motion(m) = &b.kind
            && let Target::Joints(to) = m.target
        {
            assert!(
                !matches!(m.kind, MotionKind::Arc(_)),
                "fixture without arcs"
            );
            let mut next = pos;
            for a in to.known.iter() {
                next.set(a, to.values[a.index()]);
            }
            let de = match (pos.get(Axis::E), next.get(Axis::E)) {
                (Some(a), Some(b)) => b - a,
                _ => 0.0,
            };
            if let (Some(x), Some(y), Some(x0), Some(y0)) = (
                next.get(Axis::X),
                next.get(Axis::Y),
                pos.get(Axis::X),
                pos.get(Axis::Y),
            ) {
                let z = next.get(Axis::Z).unwrap_or(0.0);
                let z0 = pos.get(Axis::Z).unwrap_or(0.0);
                let length = (x - x0).hypot(y - y0);
                let mid = [(x + x0) / 2.0 - center[0], (y + y0) / 2.0 - center[1]];
                moves.push(InputMove {
                    line: b.span.line,
                    end: [x - center[0], y - center[1], z],
                    de,
                    length,
                    radius: mid[0].hypot(mid[1]),
                    moves: length > 0.0 || z != z0,
                });
            }
            pos = next;
        }
    }
    moves
}

/// For every input move that moves the tool: (input move, screw material over the
/// printed pieces it became). Dwells (primes) go to the move after them.
fn material_per_move(
    input: &[InputMove],
    pieces: &[Piece],
    e_per_rev: f64,
) -> Vec<(InputMove, f64)> {
    let close = |a: &[f64; 3], b: &[f64; 3]| {
        (a[0] - b[0]).hypot(a[1] - b[1]) < 2e-3 && (a[2] - b[2]).abs() < 2e-3
    };
    let mut it = pieces.iter().peekable();
    // Skip the printed moves before the first input move with both ends known.
    let mut out = Vec::new();
    let mut started = false;
    for mv in input.iter().filter(|m| m.moves) {
        let mut material = 0.0;
        if !started {
            // The first input move with X and Y known: its printed end.
            for p in it.by_ref() {
                if p.end.is_some_and(|e| close(&e, &mv.end)) {
                    break;
                }
            }
            started = true;
            out.push((mv.clone(), 0.0));
            continue;
        }
        let mut matched = false;
        while let Some(p) = it.next() {
            material += p.rpm / 60.0 * p.seconds * e_per_rev;
            if p.motion && p.end.is_some_and(|e| close(&e, &mv.end)) {
                // Zero-time pieces at the same point (F-only lines) belong here too.
                while let Some(q) = it.peek() {
                    if q.motion && q.seconds == 0.0 && q.end.is_some_and(|e| close(&e, &mv.end)) {
                        it.next();
                    } else {
                        break;
                    }
                }
                matched = true;
                break;
            }
        }
        assert!(matched, "input line {} has no printed end", mv.line);
        out.push((mv.clone(), material));
    }
    out
}

struct Report {
    total_expected: f64,
    total_got: f64,
    /// Worst relative error over extruding moves longer than 1 mm.
    worst: f64,
    worst_line: u32,
    /// Per extruding move > 1 mm: (radius, relative error).
    errors: Vec<(f64, f64)>,
    travel_material: f64,
}

fn report(src: &str, center: [f64; 2], preset: &Preset, timing: Timing) -> Report {
    let (text, _) = compile(src, preset, Some(timing));
    let polar = preset.polar.clone().expect("polar");
    let pieces = timed_output(&text, &polar, timing);
    let input = input_moves(src, center);
    let per_move = material_per_move(&input, &pieces, polar.screw.e_per_rev);
    let mut r = Report {
        total_expected: 0.0,
        total_got: 0.0,
        worst: 0.0,
        worst_line: 0,
        errors: Vec::new(),
        travel_material: 0.0,
    };
    for (mv, got) in per_move {
        if mv.de > 0.0 {
            r.total_expected += mv.de;
            r.total_got += got;
            if mv.length > 1.0 {
                let e = got / mv.de - 1.0;
                r.errors.push((mv.radius, e));
                if e.abs() > r.worst {
                    r.worst = e.abs();
                    r.worst_line = mv.line;
                }
            }
        } else {
            r.travel_material += got;
        }
    }
    r
}

const CENTER: [f64; 2] = [90.0, 90.0];

#[test]
fn exact_rule_keeps_the_slicers_material_on_a_real_file() {
    let p = preset(CENTER, &[]);
    let r = report(CUBE, CENTER, &p, Timing::ConstantVelocity);
    let total = r.total_got / r.total_expected - 1.0;
    eprintln!(
        "exact: expected {:.4}, got {:.4} ({:+.4} %), worst block {:.4} % (line {}), travel {:.6}",
        r.total_expected,
        r.total_got,
        total * 100.0,
        r.worst * 100.0,
        r.worst_line,
        r.travel_material
    );
    assert!(r.total_expected > 100.0, "the cube extrudes");
    assert!(total.abs() < 0.005, "total off by {:.4} %", total * 100.0);
    assert!(
        r.worst < 0.01,
        "block at line {} off by {:.3} %",
        r.worst_line,
        r.worst * 100.0
    );
    assert_eq!(r.travel_material, 0.0, "the screw turns during travel");
}
