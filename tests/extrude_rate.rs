//! The `extrude-rate` pass: material per block and per file from the printed output under the motion-time model (exact vs seed rule, both timings), the threshold, retraction/prime handling, e-axis conservation, constant-flow feeds, snapshots and the screw curve of `plot --speed`.

use ncpost::diag::{Diagnostic, Severity};
use ncpost::front::gcode::{Options as GcodeOptions, parse_str};
use ncpost::ir::{Axis, Block, BlockKind, Joints, MotionKind, Target};
use ncpost::machine::polar::Polar;
use ncpost::motion::{Model, Planner, Timing, polar_point};
use ncpost::passes::{self, Context};
use ncpost::pipeline::Pipeline;
use ncpost::preset::Preset;

mod common;

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

/// Compiles `src` (memoised: several tests compile the cube with the same preset).
fn compile(src: &str, preset: &Preset, timing: Option<Timing>) -> (String, Vec<Diagnostic>) {
    use std::collections::HashMap;
    use std::sync::{Mutex, OnceLock};
    type Cache = Mutex<HashMap<String, (String, Vec<Diagnostic>)>>;
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let key = format!(
        "{timing:?}\n{}\n{}",
        toml::to_string(preset).expect("preset toml"),
        src
    );
    let cache = CACHE.get_or_init(Default::default);
    if let Some(hit) = cache.lock().expect("cache").get(&key) {
        return hit.clone();
    }
    let result = compile_uncached(src, preset, timing);
    cache.lock().expect("cache").insert(key, result.clone());
    result
}

fn compile_uncached(
    src: &str,
    preset: &Preset,
    timing: Option<Timing>,
) -> (String, Vec<Diagnostic>) {
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
    let drain = |planner: &mut Planner<_>, pieces: &mut Vec<Piece>| {
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
    let moving: Vec<&InputMove> = input.iter().filter(|m| m.moves).collect();
    for (k, &mv) in moving.iter().enumerate() {
        // The next input move ends elsewhere: pieces still ending here are this move's.
        let next_elsewhere = moving.get(k + 1).is_none_or(|n| !close(&n.end, &mv.end));
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
                // Later pieces that still end at this point belong here too: F-only
                // lines, and the tail of a move split within the print precision of
                // its end (a valve command just before a stop).
                while let Some(q) = it.peek() {
                    let here = q.end.is_some_and(|e| close(&e, &mv.end));
                    if q.motion && here && (q.seconds == 0.0 || next_elsewhere) {
                        material += q.rpm / 60.0 * q.seconds * e_per_rev;
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

/// Per radius band: (from, to, blocks, mean relative error, worst relative error).
fn bands(r: &Report) -> Vec<(f64, f64, usize, f64, f64)> {
    let mut out = Vec::new();
    for (lo, hi) in [(0.0, 3.0), (3.0, 6.0), (6.0, 10.0), (10.0, 20.0)] {
        let errs: Vec<f64> = r
            .errors
            .iter()
            .filter(|(rad, _)| *rad >= lo && *rad < hi)
            .map(|(_, e)| *e)
            .collect();
        let mean = errs.iter().sum::<f64>() / errs.len().max(1) as f64;
        let worst = errs.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        out.push((lo, hi, errs.len(), mean, worst));
    }
    out
}

#[test]
fn seed_rule_is_wrong_near_the_centre() {
    // The same file, the same machine: only the rule differs.
    let exact = report(CUBE, CENTER, &preset(CENTER, &[]), Timing::ConstantVelocity);
    let seed = report(
        CUBE,
        CENTER,
        &preset(CENTER, &[("rule", "seed".into())]),
        Timing::ConstantVelocity,
    );
    for (name, r) in [("exact", &exact), ("seed", &seed)] {
        eprintln!(
            "{name}: total {:+.3} %, worst block {:.2} %",
            (r.total_got / r.total_expected - 1.0) * 100.0,
            r.worst * 100.0
        );
        for (lo, hi, n, mean, worst) in bands(r) {
            eprintln!(
                "  r {lo:>4}..{hi:<4} mm: {n:>5} blocks, mean {:+8.3} %, worst {:8.3} %",
                mean * 100.0,
                worst * 100.0
            );
        }
    }
    let e = bands(&exact);
    let s = bands(&seed);
    // Every band has blocks; the exact rule is right in all of them.
    for (lo, _, n, mean, worst) in &e {
        assert!(*n > 0, "no blocks from r = {lo}");
        assert!(
            mean.abs() < 0.001 && *worst < 0.01,
            "exact rule off from r = {lo}"
        );
    }
    // The seed rule starves the print, worst at the centre: about half the material
    // within 3 mm of it (moves there are mostly radial in joint space, where
    // F·r undercounts the speed by r·π/180), and worse there than further out.
    let seed_total = seed.total_got / seed.total_expected - 1.0;
    assert!(
        seed_total < -0.10,
        "seed total {:+.2} %",
        seed_total * 100.0
    );
    assert!(
        s[0].3 < -0.40,
        "seed mean within 3 mm: {:+.2} %",
        s[0].3 * 100.0
    );
    assert!(
        s[0].3 < s[1].3 && s[1].3 < s[2].3,
        "the seed error grows towards the centre"
    );
    assert!(
        s[0].4 > 0.5,
        "some block near the centre gets less than half"
    );
}

#[test]
fn trapezoid_timing_keeps_the_material_of_its_own_model() {
    let p = preset(CENTER, &[]);
    let r = report(CUBE, CENTER, &p, Timing::Trapezoid);
    let total = r.total_got / r.total_expected - 1.0;
    eprintln!(
        "trapezoid: total {:+.4} %, worst block {:.4} % (line {})",
        total * 100.0,
        r.worst * 100.0,
        r.worst_line
    );
    assert!(total.abs() < 0.005, "total off by {:.4} %", total * 100.0);
    assert!(
        r.worst < 0.01,
        "block at line {} off by {:.3} %",
        r.worst_line,
        r.worst * 100.0
    );
    assert_eq!(r.travel_material, 0.0);
    // Trapezoid blocks take longer than constant-velocity ones: the rates differ.
    let cv = compile(CUBE, &p, Some(Timing::ConstantVelocity)).0;
    let tz = compile(CUBE, &p, Some(Timing::Trapezoid)).0;
    let rates = |t: &str| {
        t.lines()
            .filter_map(rpm_of)
            .filter(|r| *r > 0.0)
            .sum::<f64>()
    };
    assert!(
        rates(&tz) < rates(&cv) * 0.99,
        "trapezoid rates are not lower"
    );
}

/// A preset of `extrude-rate` alone (`options` as TOML lines) on the default controller
/// (NIST rule, constant velocity, min 30 mm/min), plain G-code out.
fn alone(options: &str, src: &str) -> (String, Vec<Diagnostic>) {
    let text = format!(
        "emit = \"gcode\"\n[[passes]]\nname = \"extrude-rate\"\n[passes.options]\n{options}\n"
    );
    let p = Preset::from_toml(&text).expect("preset");
    compile(src, &p, None)
}

fn lines(text: &str) -> Vec<&str> {
    text.lines().filter(|l| !l.starts_with("G21")).collect()
}

#[test]
fn threshold_keeps_the_rate_until_it_changes_by_more_than_half_a_percent() {
    let src = "G90 M82\nG92 E0\nG1 X0 Y0 F600\n\
               G1 X10 E1\n\
               G1 X20 E2.0045\n\
               G1 X30 E3.0105\n\
               G1 X40 E4.0155\n\
               G1 X50 E5.0\n";
    let (out, diags) = alone("e_per_rev = 1.0", src);
    assert!(diags.iter().all(|d| d.severity != Severity::Error));
    // 10 mm at 600 mm/min is 1 s: 1 E per second is 60 rpm. 60.27 (+0.45 %) stays,
    // 60.36 (+0.6 %) is new, 60.30 (-0.1 % from 60.36) stays, 59.07 (-2.1 %) is new.
    assert_eq!(
        lines(&out),
        [
            "G1 X0 Y0 F600",
            "M3 S60",
            "G1 X10",
            "G1 X20",
            "M3 S60.36",
            "G1 X30",
            "G1 X40",
            "M3 S59.07",
            "G1 X50",
            "M3 S0",
        ]
    );
    // threshold = 0 prints every change.
    let (out, _) = alone("e_per_rev = 1.0\nthreshold = 0.0", src);
    assert_eq!(out.lines().filter(|l| l.starts_with("M3")).count(), 6);
}

#[test]
fn retraction_is_left_out_and_a_prime_becomes_a_dwell() {
    let src = "M83\nG1 X0 Y0 F600\n\
               G1 X10 E1\n\
               G1 E-1 F1800\n\
               G0 X20\n\
               G1 E1 F1800\n\
               G1 X30 E1 F600\n\
               G1 E-0.5 F1800\n\
               G1 E1 F1800\n\
               G92 E0\n\
               G1 X40 E1 F600\n";
    let (out, diags) = alone("e_per_rev = 2.0\nmax_rpm = 100.0", src);
    assert!(
        diags.iter().all(|d| d.severity != Severity::Error),
        "{diags:?}"
    );
    // 1 E per second with 2 E per revolution: 30 rpm. The retraction is a comment, the
    // travel stops the screw, the unretraction restores it (comment). The second
    // unretraction pushes 0.5 more than was pulled back: a prime of 0.5 E in the move's
    // own time (1 E at 30 mm/s: 1/30 s) would need 450 rpm, above max_rpm 100, so the
    // dwell is 0.5 / 2 / 100 min = 0.15 s at 100 rpm.
    assert_eq!(
        lines(&out),
        [
            "G1 X0 Y0 F600",
            "M3 S30",
            "G1 X10",
            ";retraction E-1.00000 left out: the screw cannot turn backwards",
            "M3 S0",
            "G0 X20",
            ";E1.00000 left out: it restores the retraction",
            "M3 S30",
            // F1800 of the dropped E-only moves never reaches the controller.
            "G1 X30",
            ";retraction E-0.50000 left out: the screw cannot turn backwards",
            "M3 S100",
            "G4 P150 ;prime E0.50000: the screw runs during this dwell",
            "M3 S30",
            "G1 X40",
            "M3 S0",
        ]
    );
    // No E word and no G92 E0 reaches the controller.
    assert!(
        out.lines()
            .all(|l| !l.split(';').next().unwrap_or("").contains('E')),
        "{out}"
    );
}

const LAYER: &str = include_str!("fixtures/polar/prusaslicer_mini_layer1.gcode");

/// Runs the passes `specs` (name, options TOML) over `src` in process, with the preset's
/// polar machine.
fn run_passes(specs: &[(&str, &str)], polar: &Polar, input: Vec<Block>) -> Vec<Block> {
    let ctx = Context {
        polar: Some(polar),
        ..Context::default()
    };
    let mut blocks = input;
    for (name, options) in specs {
        let opts: toml::Table = toml::from_str(options).expect("options");
        let (out, diags) = common::run_pass(name, &opts, &ctx, blocks);
        assert!(
            diags.iter().all(|d| d.severity != Severity::Error),
            "{diags:?}"
        );
        blocks = out;
    }
    blocks
}

fn polar_machine() -> Polar {
    Preset::builtin("polar-printer")
        .expect("preset")
        .polar
        .expect("[polar]")
}

/// (span line, ΔE, Cartesian length) of every move, from the previous known position.
fn e_steps(blocks: &[Block], polar: Option<&Polar>) -> Vec<(u32, f64, f64)> {
    let mut pos = Joints::default();
    let mut out = Vec::new();
    for b in blocks {
        if let BlockKind::Motion(m) = &b.kind
            && let Target::Joints(to) = m.target
        {
            let mut next = pos;
            for a in to.known.iter() {
                next.set(a, to.values[a.index()]);
            }
            let point = |j: &Joints| match polar {
                Some(p) => polar_point(j, p.r_axis, p.theta_axis),
                None => j.xyz(),
            };
            if let (Some(e0), Some(e1)) = (pos.get(Axis::E), next.get(Axis::E)) {
                out.push((b.span.line, e1 - e0, (point(&next) - point(&pos)).norm()));
            }
            pos = next;
        }
    }
    out
}

#[test]
fn e_axis_mode_shares_e_by_cartesian_length_and_conserves_it() {
    let polar = polar_machine();
    let input = parse_str(LAYER, &GcodeOptions::default())
        .expect("parse")
        .blocks;
    let ik = "center = [100.0, 90.0]";
    let after_ik = run_passes(&[("polar-ik", ik)], &polar, input.clone());
    let shared = run_passes(
        &[("extrude-rate", "mode = \"e-axis\"")],
        &polar,
        after_ik.clone(),
    );
    let steps = e_steps(&shared, Some(&polar));
    // Conservation: the E of every source line is the slicer's.
    let by_line = |steps: &[(u32, f64, f64)]| {
        let mut m = std::collections::BTreeMap::<u32, f64>::new();
        for (l, de, _) in steps {
            *m.entry(*l).or_default() += de;
        }
        m
    };
    let want = by_line(&e_steps(&input, None));
    let got = by_line(&steps);
    assert_eq!(want.len(), got.len());
    for (line, de) in &want {
        assert!(
            (got[line] - de).abs() < 1e-9,
            "line {line}: {} vs {de}",
            got[line]
        );
    }
    // Material per mm is the same on every piece of a source move.
    let mut pieces = 0;
    for w in steps.windows(2) {
        let ((l0, e0, d0), (l1, e1, d1)) = (w[0], w[1]);
        if l0 == l1 && d0 > 1e-3 && d1 > 1e-3 && e0 > 0.0 {
            pieces += 1;
            assert!((e0 / d0 - e1 / d1).abs() < 1e-9 * (e0 / d0), "line {l0}");
        }
    }
    assert!(
        pieces > 100,
        "the layer is densified ({pieces} piece pairs)"
    );
    // polar-ik already shares the E of a line this way: on lines the pass changes
    // nothing. It shares an arc's E over its chords by the arc's parameter; the pass
    // makes it per chord millimetre, a change of well under 1 % (tiny arcs of this layer).
    let arcs: std::collections::HashSet<u32> = input
        .iter()
        .filter(|b| matches!(&b.kind, BlockKind::Motion(m) if matches!(m.kind, MotionKind::Arc(_))))
        .map(|b| b.span.line)
        .collect();
    assert_eq!(e_steps(&after_ik, Some(&polar)).len(), steps.len());
    for (a, b) in e_steps(&after_ik, Some(&polar)).iter().zip(&steps) {
        let tol = if arcs.contains(&a.0) { 1e-2 } else { 1e-9 };
        assert!(
            (a.1 - b.1).abs() <= tol * a.1.abs() + 1e-12,
            "line {}: {a:?} vs {b:?}",
            a.0
        );
    }
    let twice = run_passes(
        &[("extrude-rate", "mode = \"e-axis\"")],
        &polar,
        shared.clone(),
    );
    assert_eq!(twice, shared);
}

#[test]
fn e_axis_mode_reshares_an_uneven_split() {
    // One source line split into 1 mm and 3 mm with E shared 50/50: the pass makes it
    // 25/75 (material per mm), the total stays, other lines are untouched.
    let polar = polar_machine();
    let mut input = parse_str(
        "M82\nG1 X0 Y0 E0 F600\nG1 X1 Y0 E0.5\nG1 X4 Y0 E1\nG1 X4 Y4 E2\n",
        &GcodeOptions::default(),
    )
    .expect("parse")
    .blocks;
    let moves: Vec<usize> = (0..input.len())
        .filter(|&i| matches!(input[i].kind, BlockKind::Motion(_)))
        .collect();
    let span = input[moves[1]].span;
    input[moves[2]].span = span; // the two pieces come from one line
    let out = run_passes(
        &[("extrude-rate", "mode = \"e-axis\"\nframe = \"cartesian\"")],
        &polar,
        input,
    );
    let e: Vec<f64> = out
        .iter()
        .filter_map(|b| match &b.kind {
            BlockKind::Motion(m) => m.target.joints().and_then(|j| j.get(Axis::E)),
            _ => None,
        })
        .collect();
    assert_eq!(e.len(), 4);
    assert!(
        (e[1] - 0.25).abs() < 1e-12 && e[2] == 1.0 && e[3] == 2.0,
        "{e:?}"
    );
}

#[test]
fn constant_flow_steers_the_feed() {
    let src = "M83\nG1 X0 Y0 F600\nG1 X10 E1\nG1 X30 E1\nG0 X40\nG1 X41 E2 F600\n";
    let options = "mode = \"constant-flow\"\nrpm = 30.0\ne_per_rev = 1.0";
    // For RepRapFirmware, whose minimum speed is 30 mm/min (LinuxCNC has none: there the
    // last block runs at the 15 mm/min it needs).
    let text = format!(
        "emit = \"rrf\"\n[[passes]]\nname = \"extrude-rate\"\n[passes.options]\n{options}\n"
    );
    let (out, diags) = compile(src, &Preset::from_toml(&text).expect("preset"), None);
    // 30 rpm × 1 E/rev = 0.5 E/s: 1 E takes 2 s, so 10 mm at 300 mm/min and 20 mm at
    // 600. The last block would need 2 E in 4 s over 1 mm, 15 mm/min, below the
    // controller's 30 mm/min: it runs at 30 (2 s) and the screw doubles for it.
    assert_eq!(
        lines(&out),
        [
            "G1 X0 Y0 F600",
            "M3 S30",
            "G1 X10 F300",
            "G1 X30 F600",
            "M3 S0",
            "G0 X40",
            "M3 S60",
            "G1 X41 F30",
            "M3 S0",
        ]
    );
    assert!(
        diags.iter().any(|d| d.code == "extrude-rate::flow-limited"),
        "{diags:?}"
    );
}

#[test]
fn constant_flow_keeps_the_material_and_the_screw_steady_on_a_real_file() {
    let p = preset(
        CENTER,
        &[("mode", "constant-flow".into()), ("rpm", 5.0.into())],
    );
    let r = report(CUBE, CENTER, &p, Timing::ConstantVelocity);
    let total = r.total_got / r.total_expected - 1.0;
    assert!(total.abs() < 0.005, "total off by {:.4} %", total * 100.0);
    assert!(
        r.worst < 0.01,
        "block at line {} off by {:.3} %",
        r.worst_line,
        r.worst * 100.0
    );
    let (flow, _) = compile(CUBE, &p, None);
    let (rpm, _) = compile(CUBE, &preset(CENTER, &[]), None);
    let changes = |t: &str| {
        t.lines()
            .filter(|l| rpm_of(l).is_some_and(|r| r > 0.0))
            .count()
    };
    let rates: Vec<f64> = flow
        .lines()
        .filter_map(rpm_of)
        .filter(|r| *r > 0.0)
        .collect();
    let at_rpm = rates
        .iter()
        .filter(|r| (**r - 5.0).abs() <= 0.005 * 5.0)
        .count();
    eprintln!(
        "screw starts/changes: constant-flow {} ({at_rpm} at 5 rpm), screw-rpm {}",
        changes(&flow),
        changes(&rpm)
    );
    // The cube sits on the table centre, where the near-centre cap and the table's
    // max_feed hold the stage back: there (and only there) the screw slows below the
    // constant speed; it never runs faster. Elsewhere it runs at 5 rpm, and the program
    // changes the screw an order of magnitude less often than following the feed.
    assert!(
        rates.iter().all(|r| *r <= 5.0 * 1.005),
        "a rate above the constant"
    );
    assert!(at_rpm > 400);
    assert!(changes(&flow) * 10 < changes(&rpm));
}

#[test]
fn max_rpm_warns_or_slows_the_feed() {
    let src = "M83\nG1 X0 Y0 F600\nG1 X10 E1\nG1 X20 E0.25\n";
    // 1 E in 1 s is 60 rpm, above max_rpm 30.
    let (out, diags) = alone("e_per_rev = 1.0\nmax_rpm = 30.0", src);
    assert_eq!(
        lines(&out),
        [
            "G1 X0 Y0 F600",
            "M3 S60",
            "G1 X10",
            "M3 S15",
            "G1 X20",
            "M3 S0"
        ]
    );
    let warn: Vec<_> = diags
        .iter()
        .filter(|d| d.code == "extrude-rate::max-rpm")
        .collect();
    assert_eq!(warn.len(), 1);
    assert_eq!(warn[0].location.as_ref().map(|l| l.line), Some(3));
    // slow-feed: the block takes 2 s (F300) and the screw turns at 30 rpm; the next
    // block keeps its own feed.
    let (out, diags) = alone(
        "e_per_rev = 1.0\nmax_rpm = 30.0\nlimit = \"slow-feed\"",
        src,
    );
    assert_eq!(
        lines(&out),
        [
            "G1 X0 Y0 F600",
            "M3 S30",
            "G1 X10 F300",
            "M3 S15",
            "G1 X20 F600",
            "M3 S0"
        ]
    );
    assert!(diags.iter().any(|d| d.code == "extrude-rate::slowed"));
    assert!(
        diags.iter().all(|d| d.code != "extrude-rate::max-rpm"),
        "{diags:?}"
    );
}

#[test]
fn seed_rule_is_exact_for_a_turn_about_the_centre() {
    // A circle of radius 20 about the table centre at 10 mm/s with 0.1 E/mm: 1 E/s,
    // 60 rpm. The default gamma calibrates the seed rule on exactly this motion.
    let src = "M83\nG0 X20 Y0 Z0.2\nG2 X20 Y0 I-20 J0 E12.56637 F600\n";
    for rule in ["exact", "seed"] {
        let (out, _) = compile(src, &preset([0.0, 0.0], &[("rule", rule.into())]), None);
        let rates: Vec<f64> = out
            .lines()
            .filter_map(rpm_of)
            .filter(|r| *r > 0.0)
            .collect();
        assert!(!rates.is_empty());
        for r in rates {
            assert!((r - 60.0).abs() < 0.6, "{rule}: {r} rpm");
        }
    }
}

#[test]
fn bad_options_are_errors() {
    let polar = polar_machine();
    let ctx = Context {
        polar: Some(&polar),
        ..Context::default()
    };
    for bad in [
        "bogus = 1",
        "mode = \"pump\"",
        "rule = \"guess\"",
        "threshold = -0.1",
        "threshold = 1.0",
        "e_per_rev = 0.0",
        "max_rpm = -5.0",
        "rpm = 0.0",
        "gamma = -1.0",
        "command = \"M3 S100\"",
        "stop_command = \"\"",
        "rpm_decimals = 9",
        "limit = \"ignore\"",
        "timing = \"instant\"",
        "rule = \"seed\"\nmode = \"constant-flow\"",
        "rule = \"seed\"\nmode = \"e-axis\"",
    ] {
        let t: toml::Table = toml::from_str(bad).expect("toml");
        assert!(passes::build("extrude-rate", &t, &ctx).is_err(), "{bad}");
    }
    let t: toml::Table = toml::from_str("frame = \"polar\"").expect("toml");
    assert!(passes::build("extrude-rate", &t, &Context::default()).is_err());
    assert!(passes::build("extrude-rate", &toml::Table::new(), &Context::default()).is_ok());
}

/// A small print near the table centre: a line past the centre, a retraction, travel,
/// an unretraction with a prime, a Z move, absolute E with G92.
const SMALL: &str = "; hand-written for tests/extrude_rate.rs\n\
G21 G90\n\
M82\n\
G92 E0\n\
G0 X-6 Y1 Z0.2\n\
G1 X6 Y1 E0.6 F1200\n\
G1 X6 Y6 E0.85\n\
G1 E0.05 F2400\n\
G0 X-6 Y6\n\
G1 E0.9 F2400\n\
G1 X-6 Y-6 E1.5 F600\n\
G92 E0\n\
G1 Z0.4 F600\n\
G1 X6 Y-6 E0.6 F1800\n";

#[test]
fn snapshots_before_and_after() {
    for (name, options) in [
        ("screw_rpm", vec![]),
        ("seed_rule", vec![("rule", toml::Value::from("seed"))]),
        (
            "constant_flow",
            vec![("mode", "constant-flow".into()), ("rpm", 30.0.into())],
        ),
    ] {
        // The pass's own before/after: the preset without the valve's commands (their
        // snapshots are in tests/valve.rs).
        let mut p = preset([0.0, 0.0], &options);
        p.passes.retain(|spec| spec.name != "valve-lookahead");
        let (out, diags) = compile(SMALL, &p, None);
        let warnings: Vec<String> = diags
            .iter()
            .filter(|d| d.severity == Severity::Warning)
            .map(|d| {
                format!(
                    "{} (line {:?})",
                    d.message,
                    d.location.as_ref().map(|l| l.line)
                )
            })
            .collect();
        insta::assert_snapshot!(
            name,
            format!(
                "before:\n{SMALL}\nafter:\n{out}\nwarnings:\n{}\n",
                warnings.join("\n")
            )
        );
    }
}

#[test]
fn plot_speed_draws_the_screw_rate() {
    use ncpost::plot::SpeedPlot;
    let svg = |p: &Preset| {
        let mut pipeline = Pipeline::builder()
            .preset(p.clone())
            .build()
            .expect("pipeline");
        let mut plot = SpeedPlot::for_preset(pipeline.preset(), None, 3000.0);
        let summary = pipeline.run_into(
            ncpost::pipeline::Source::Gcode,
            SMALL.as_bytes(),
            &mut plot,
            &mut |_| {},
        );
        assert_eq!(summary.errors, 0);
        let rpm: Vec<f64> = plot.samples().iter().map(|s| s.rpm).collect();
        (plot.svg(), rpm)
    };
    let with = preset([0.0, 0.0], &[]);
    let (text, rpm) = svg(&with);
    assert!(text.contains("screw (rpm)"), "no screw series");
    // The curve holds the rates the program sets: 0 on travel, up to the fastest command.
    let (out, _) = compile(SMALL, &with, None);
    let top = out.lines().filter_map(rpm_of).fold(0.0, f64::max);
    assert!(top > 0.0);
    assert!(rpm.iter().any(|r| (*r - top).abs() < 1e-9));
    assert!(rpm.contains(&0.0));
    let mut without = with.clone();
    without.passes.retain(|p| p.name != "extrude-rate");
    assert!(!svg(&without).0.contains("screw (rpm)"));
    // A custom command template is read back too.
    let custom = preset(
        [0.0, 0.0],
        &[
            ("command", "M106 P2 S{rpm}".into()),
            ("stop_command", "M107 P2".into()),
        ],
    );
    let (out, _) = compile(SMALL, &custom, None);
    assert!(out.contains("M106 P2 S") && out.contains("M107 P2") && !out.contains("M3 "));
    let (text, rpm) = svg(&custom);
    assert!(text.contains("screw (rpm)"));
    assert!(rpm.iter().any(|r| (*r - top).abs() < 1e-9));
}

/// Screw material of a printed program on the default controller (X, Y Cartesian):
/// Σ rpm × time × e_per_rev over moves and dwells.
fn screw_material(text: &str, e_per_rev: f64) -> f64 {
    let program = parse_str(text, &GcodeOptions::default()).expect("output parses");
    let model = Model::default();
    let mut planner: Planner<f64> = Planner::new(model.clone());
    let mut pos = Joints::default();
    let mut rpm = 0.0;
    let mut total = 0.0;
    for b in &program.blocks {
        match &b.kind {
            BlockKind::Motion(m) => {
                let Target::Joints(to) = m.target else {
                    panic!("pose")
                };
                let mut next = pos;
                for a in to.known.iter() {
                    next.set(a, to.values[a.index()]);
                }
                planner.push_move(model.motion(&pos, m).expect("joints"), rpm);
                pos = next;
            }
            BlockKind::Dwell { seconds } => planner.push_stop(*seconds, rpm),
            BlockKind::Command(c) => {
                if let Some(r) = rpm_of(&c.text) {
                    rpm = r;
                }
            }
            _ => {}
        }
        while let Some(t) = planner.pop() {
            total += t.payload / 60.0 * t.duration() * e_per_rev;
        }
    }
    planner.finish();
    while let Some(t) = planner.pop() {
        total += t.payload / 60.0 * t.duration() * e_per_rev;
    }
    total
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]

    /// Whatever the mix of moves, travel, retractions and primes: with no threshold the
    /// screw delivers the slicer's E pushed beyond its retractions, exactly (up to the
    /// printed precision).
    #[test]
    fn screw_material_is_conserved(
        steps in proptest::collection::vec(
            (0u8..4, -20i32..20, -20i32..20, 1u32..60, 1i32..40),
            1..30,
        )
    ) {
        let mut src = String::from("M83\nG1 X0 Y0 F1200\n");
        let mut expected = 0.0;
        let mut pending = 0.0f64;
        for (kind, x, y, f, e) in steps {
            let (x, y, f, e) = (x as f64 / 2.0, y as f64 / 2.0, f as f64 * 100.0, e as f64 / 20.0);
            let de = match kind {
                0 => { src.push_str(&format!("G1 X{x} Y{y} E{e} F{f}\n")); e }
                1 => { src.push_str(&format!("G0 X{x} Y{y}\n")); 0.0 }
                2 => { src.push_str(&format!("G1 E-{e} F{f}\n")); -e }
                _ => { src.push_str(&format!("G1 E{e} F{f}\n")); e }
            };
            if de < 0.0 {
                pending -= de;
            } else {
                let restored = de.min(pending);
                pending -= restored;
                expected += de - restored;
            }
        }
        let (out, diags) = alone(
            "e_per_rev = 0.5\nthreshold = 0.0\nrpm_decimals = 6\nmax_rpm = 1000000.0",
            &src,
        );
        proptest::prop_assert!(diags.iter().all(|d| d.severity != Severity::Error));
        let got = screw_material(&out, 0.5);
        proptest::prop_assert!(
            (got - expected).abs() <= 1e-4 * expected.max(1.0),
            "{got} vs {expected}\n{src}\n{out}"
        );
    }
}
