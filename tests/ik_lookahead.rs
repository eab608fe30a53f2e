//! `ik`'s look-ahead and singular swings (issue 20, defects 7 and 8), checked on the printed
//! program: the G-code is re-read here (modal axis words, G92 re-basing, F), mapped through
//! the machine's forward kinematics and compared with the programmed CL points.

use nalgebra::{Point3, Unit, Vector3};
use ncpost::diag::Diagnostic;
use ncpost::machine::Machine;
use ncpost::pipeline::{Pipeline, Source};
use proptest::prelude::*;

#[allow(dead_code)]
#[path = "common/geometry.rs"]
mod geometry;
use geometry::{AXIS_TOL_DEG, TIP_TOL, angle_to_arc, distance_to_segment};

const PRESETS: [&str; 4] = ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"];

/// A programmed CL point: tip, unit tool axis, rapid or the feed (mm/min) to it.
#[derive(Debug, Clone, Copy)]
struct ClPoint {
    tip: Point3<f64>,
    axis: Unit<Vector3<f64>>,
    rapid: bool,
    feed: f64,
}

fn cl_text(points: &[ClPoint]) -> String {
    let mut s = String::from("UNITS/MM\nMULTAX/ON\n");
    let mut feed = None;
    for p in points {
        if p.rapid {
            s.push_str("RAPID\n");
        } else if feed != Some(p.feed) {
            s.push_str(&format!("FEDRAT/MMPM,{}\n", p.feed));
            feed = Some(p.feed);
        }
        s.push_str(&format!(
            "GOTO/{:.9},{:.9},{:.9},{:.12},{:.12},{:.12}\n",
            p.tip.x, p.tip.y, p.tip.z, p.axis.x, p.axis.y, p.axis.z
        ));
    }
    s
}

/// One printed motion: rapid, X Y Z and both rotaries (IR frame, G92 undone), F.
#[derive(Debug, Clone, Copy)]
struct Printed {
    rapid: bool,
    j: [f64; 5],
    f: f64,
    line: usize,
}

/// Reads the printed G0/G1 lines the way the controller does: modal words, G92 re-basing.
fn read_printed(text: &str, letters: [char; 5]) -> Vec<Printed> {
    let mut pos = [f64::NAN; 5];
    let mut offset = [0.0; 5];
    let (mut feed, mut rapid) = (f64::NAN, true);
    let mut out = Vec::new();
    for (line, raw) in text.lines().enumerate() {
        let code = raw.split(';').next().unwrap_or("").trim();
        let words: Vec<&str> = code.split_whitespace().collect();
        let value = |w: &str| w[1..].parse::<f64>().expect("a number");
        let axis = |w: &str| letters.iter().position(|c| w.starts_with(*c));
        if words.contains(&"G92") {
            for w in &words {
                if let Some(k) = axis(w) {
                    offset[k] = value(w) - pos[k];
                }
            }
            continue;
        }
        let mut motion = false;
        for w in &words {
            match *w {
                "G0" => (rapid, motion) = (true, true),
                "G1" => (rapid, motion) = (false, true),
                _ => {}
            }
        }
        for w in &words {
            if let Some(k) = axis(w) {
                pos[k] = value(w) - offset[k];
                motion = true;
            } else if w.starts_with('F') {
                feed = value(w);
            }
        }
        if motion
            && !words
                .iter()
                .any(|w| w.starts_with('M') || w.starts_with('T'))
        {
            out.push(Printed {
                rapid,
                j: pos,
                f: feed,
                line: line + 1,
            });
        }
    }
    out
}

struct Run {
    text: String,
    diags: Vec<Diagnostic>,
    machine: Machine,
}

fn compile(preset: &str, cl: &str) -> Run {
    compile_with(preset, cl, false)
}

/// [`compile`], with the readback of the printed program on when `readback` says.
fn compile_with(preset: &str, cl: &str, readback: bool) -> Run {
    let mut p = Pipeline::builder()
        .preset_name(preset)
        .expect("preset")
        .verify(readback)
        .build()
        .expect("pipeline");
    let machine = p.preset().machine.clone().expect("a 5-axis preset");
    let mut out = Vec::new();
    let mut diags = Vec::new();
    p.run_source(Source::Cl, cl.as_bytes(), &mut out, &mut |d| diags.push(d))
        .expect("writes");
    Run {
        text: String::from_utf8(out).expect("utf-8"),
        diags,
        machine,
    }
}

fn letters(m: &Machine) -> [char; 5] {
    let [a, b] = m.rotary_axes();
    ['X', 'Y', 'Z', a.letter(), b.letter()]
}

fn fk(m: &Machine, j: &[f64; 5]) -> (Point3<f64>, Unit<Vector3<f64>>) {
    let p = m.forward(&[j[0], j[1], j[2]], [j[3], j[4]]);
    (p.tip, p.axis)
}

/// Checks the printed program of `points` on `run`: every CL point reached in order (FK of
/// the printed numbers within 1e-3 mm, 1e-3 deg); between them the joint-linear path within
/// the tip and axis tolerances, no cutting block with the tip standing still, and each
/// block's time under the printed F (NIST rule) within 1 % of tip length / programmed F.
/// Returns the worst tip deviation from the programmed lines, mm.
fn check_printed(name: &str, run: &Run, points: &[ClPoint]) -> f64 {
    let m = &run.machine;
    let printed = read_printed(&run.text, letters(m));
    let mut hits = Vec::new();
    for p in &printed {
        let k = hits.len();
        if k < points.len() && (fk(m, &p.j).0 - points[k].tip).norm() < 1e-3 {
            let e = fk(m, &p.j).1.angle(&points[k].axis).to_degrees();
            assert!(e < 1e-3, "{name}: CL point {k} axis off by {e} deg");
            hits.push(p);
        }
    }
    assert_eq!(
        hits.len(),
        points.len(),
        "{name}: CL points reached\n{}",
        run.text
    );
    let index = |p: &Printed| printed.iter().position(|q| q.line == p.line).expect("line");
    let mut worst = 0.0f64;
    for seg in 1..points.len() {
        let (a, b) = (&points[seg - 1], &points[seg]);
        if b.rapid {
            continue;
        }
        let (i0, i1) = (index(hits[seg - 1]), index(hits[seg]));
        for w in i0..i1 {
            let (p0, p1) = (&printed[w], &printed[w + 1]);
            assert!(!p1.rapid, "{name}: a rapid inside the cut to point {seg}");
            worst = worst.max(check_block(name, m, (p0, p1), (a, b)));
        }
    }
    worst
}

/// One printed cutting block `p0 → p1` inside the programmed segment `a → b`; returns its
/// worst tip deviation, mm.
fn check_block(
    name: &str,
    m: &Machine,
    (p0, p1): (&Printed, &Printed),
    (a, b): (&ClPoint, &ClPoint),
) -> f64 {
    let line = p1.line;
    let mut worst = 0.0f64;
    for s in 0..=100 {
        let s = f64::from(s) / 100.0;
        let j: [f64; 5] = std::array::from_fn(|q| p0.j[q] + (p1.j[q] - p0.j[q]) * s);
        let (tip, axis) = fk(m, &j);
        let d = distance_to_segment(&tip, &a.tip, &b.tip);
        assert!(
            d <= TIP_TOL + 1e-4,
            "{name}: line {line}: tip {d} mm off the line"
        );
        worst = worst.max(d);
        let e = angle_to_arc(&axis, &a.axis, &b.axis);
        assert!(
            e <= AXIS_TOL_DEG + 1e-3,
            "{name}: line {line}: axis {e} deg off"
        );
    }
    let tip_len = (fk(m, &p1.j).0 - fk(m, &p0.j).0).norm();
    assert!(
        tip_len > 1e-4,
        "{name}: line {line}: the tip stands still in a cut"
    );
    let d = |r: std::ops::Range<usize>| r.map(|q| (p1.j[q] - p0.j[q]).powi(2)).sum::<f64>().sqrt();
    let (dxyz, drot) = (d(0..3), d(3..5));
    let minutes = if dxyz > 0.0 { dxyz / p1.f } else { drot / p1.f };
    let programmed = tip_len / b.feed;
    let rel = (minutes - programmed).abs() / programmed;
    assert!(
        rel < 0.01 || (minutes - programmed).abs() < 2e-6,
        "{name}: line {line}: {minutes} min printed vs {programmed} min programmed"
    );
    worst
}

fn no_errors(run: &Run) {
    assert!(
        !run.diags.iter().any(Diagnostic::is_error),
        "{:?}",
        run.diags
    );
}

fn codes(run: &Run) -> Vec<&str> {
    run.diags.iter().map(|d| d.code).collect()
}

fn pt(tip: [f64; 3], axis: Unit<Vector3<f64>>, rapid: bool) -> ClPoint {
    ClPoint {
        tip: Point3::from(tip),
        axis,
        rapid,
        feed: 900.0,
    }
}

/// Defect 7: a cut through exactly the singular direction (the reproduction on
/// `head-head-ab`, turned to each preset's singular direction) keeps the tip moving at the
/// programmed feed, on the line.
#[test]
fn a_cut_through_the_singular_direction_keeps_the_tip_moving() {
    for name in PRESETS {
        // (singular direction, the tilt direction, the sideways one)
        let (u, e1, e2) = if name == "head-head-ab" {
            (Vector3::x(), Vector3::z(), Vector3::y())
        } else {
            (Vector3::z(), Vector3::x(), Vector3::y())
        };
        let (c, t, side) = (0.999981564859, 0.006070645402, 0.000131172843);
        let before = Unit::new_normalize(u * c + e2 * side + e1 * t);
        let after = Unit::new_normalize(u * c + e2 * side - e1 * t);
        let points = [
            pt([-9.047619048, -13.571428571, 4.107142857], before, true),
            pt(
                [-8.571428571, -12.857142857, 4.285714286],
                Unit::new_normalize(u),
                false,
            ),
            pt([-8.095238095, -12.142857143, 4.464285714], after, false),
        ];
        let run = compile(name, &cl_text(&points));
        assert!(
            !run.diags.iter().any(Diagnostic::is_error),
            "{name}: {:?}",
            run.diags
        );
        let worst = check_printed(name, &run, &points);
        // The figure for a spread swing, with the printed decimals' rounding.
        assert!(
            worst < 0.003,
            "{name}: the tip strays {worst} mm\n{}",
            run.text
        );
        eprintln!("{name}: worst tip deviation {worst:.5} mm");
    }
}

/// The tool axis tilted `deg` degrees from Z towards +X.
fn tilt(deg: f64) -> Unit<Vector3<f64>> {
    let r = deg.to_radians();
    Unit::new_normalize(Vector3::new(r.sin(), 0.0, r.cos()))
}

/// A trunnion cut from a rapid at `start` degrees towards +X through Z to 40 degrees
/// towards -X (CL lines 4 to 7).
fn through_z(start: f64) -> Vec<ClPoint> {
    vec![
        pt([0.0, 0.0, 50.0], tilt(start), true),
        pt([5.0, 0.0, 50.0], tilt(10.0), false),
        pt([10.0, 0.0, 50.0], tilt(-10.0), false),
        pt([15.0, 0.0, 50.0], tilt(-40.0), false),
    ]
}

/// Tool axes (part frame) of the machine at rotary values `r`.
fn axis_at(m: &Machine, r: [f64; 2]) -> Unit<Vector3<f64>> {
    m.forward(&[0.0; 3], r).axis
}

fn machine(name: &str) -> Machine {
    Pipeline::builder()
        .preset_name(name)
        .expect("preset")
        .build()
        .expect("pipeline")
        .preset()
        .machine
        .clone()
        .expect("machine")
}

/// Defect 8, first example: on the trunnion a cut tilts towards +X, through Z, and on
/// past B -35 towards -X. Only the branch starting at B -30 C180 stays within B's range;
/// the look-ahead takes it at the rapid, so there is no flip.
#[test]
fn trunnion_reorientation_through_z_then_past_b_minus_35_needs_no_flip() {
    let mut points = through_z(30.0);
    points.push(pt([20.0, 0.0, 50.0], tilt(-40.0), false));
    let run = compile("trunnion-bc", &cl_text(&points));
    no_errors(&run);
    check_printed("trunnion", &run, &points);
    for p in read_printed(&run.text, letters(&run.machine)) {
        assert!(
            (-35.0..=120.0).contains(&p.j[3]),
            "B{} out of range",
            p.j[3]
        );
    }
}

/// A head-head path from rotary values `r0` in `steps` steps of `dr` each, the tip moving
/// along X; the first point is a rapid.
fn head_head_path(m: &Machine, r0: [f64; 2], dr: [f64; 2], steps: usize) -> Vec<ClPoint> {
    (0..=steps)
        .map(|i| {
            let k = i as f64;
            let r = [r0[0] + dr[0] * k, r0[1] + dr[1] * k];
            pt([k * 2.0, 10.0, 0.0], axis_at(m, r), i == 0)
        })
        .collect()
}

/// Defect 8, second example: at a head-head start both branches (A80 B80 and A-100 B100)
/// are reachable and A > 0 is preferred, but the cut then needs A up to 115 on that
/// branch, past its limit: the look-ahead starts on A < 0.
#[test]
fn head_head_start_chooses_a_below_zero_when_the_path_needs_it() {
    let m = machine("head-head-ab");
    let points = head_head_path(&m, [80.0, 80.0], [5.0, 0.0], 7);
    let run = compile("head-head-ab", &cl_text(&points));
    no_errors(&run);
    let printed = read_printed(&run.text, letters(&m));
    assert!(
        printed[0].j[3] < 0.0,
        "starts at A{}\n{}",
        printed[0].j[3],
        run.text
    );
    check_printed("head-head start", &run, &points);
}

/// A flip two cuts need is made at the rapid between them: the first cut needs A > 0
/// (A from 80 down to 60; its twin would pass A -110), the second A < 0.
#[test]
fn an_unavoidable_flip_is_made_at_the_rapid() {
    let m = machine("head-head-ab");
    let mut points = head_head_path(&m, [80.0, 80.0], [-5.0, 0.0], 4);
    let mut second = head_head_path(&m, [80.0, 80.0], [5.0, 0.0], 7);
    for p in &mut second {
        p.tip.y += 20.0;
    }
    points.extend(second);
    let run = compile("head-head-ab", &cl_text(&points));
    no_errors(&run);
    let printed = read_printed(&run.text, letters(&m));
    for w in printed.windows(2) {
        let jump = (w[1].j[3] - w[0].j[3])
            .abs()
            .max((w[1].j[4] - w[0].j[4]).abs());
        assert!(
            w[1].rapid || jump < 30.0,
            "line {}: turns {jump} deg cutting",
            w[1].line
        );
    }
    check_printed("flip at the rapid", &run, &points);
}

/// A cut that needs both branches (B +40 to -40 through Z on the trunnion: B40 C0 ends at
/// B -40, and B-40 C180 starts there) flips: `ik::flip`, naming what stops each branch.
#[test]
fn a_flip_no_branch_avoids_is_an_error_that_says_why() {
    let points = through_z(40.0);
    let run = compile("trunnion-bc", &cl_text(&points));
    let flip = run
        .diags
        .iter()
        .find(|d| d.code == "ik::flip")
        .unwrap_or_else(|| panic!("{:?}", codes(&run)));
    let text = flip.message.clone();
    assert!(text.contains("no flip-free choice"), "{text}");
    assert!(
        text.contains("B would be -40.000 deg, outside -35..120"),
        "{text}"
    );
    assert!(text.contains("at line 4"), "{text}");
}

/// A random walk of the rotaries inside their limits (`steps` of at most 4 degrees, some
/// starting a new cut after a rapid anywhere), as CL points through the machine's FK: a
/// program that can run without a flip.
fn feasible(m: &Machine, start: [f64; 2], steps: &[(bool, f64, f64)]) -> Vec<ClPoint> {
    let limits = |i: usize| m.limits(m.rotary_axes()[i]);
    let range = |i: usize| limits(i).map_or((-180.0, 180.0), |(lo, hi)| (lo + 1.0, hi - 1.0));
    let clamp = |i: usize, v: f64| match limits(i) {
        Some((lo, hi)) => v.clamp(lo + 1.0, hi - 1.0),
        None => v,
    };
    let at = |f: f64, i: usize| range(i).0 + (range(i).1 - range(i).0) * f;
    let mut r = [at(start[0], 0), at(start[1], 1)];
    let mut out = Vec::new();
    for (k, &(rapid, d0, d1)) in steps.iter().enumerate() {
        if rapid {
            r = [at(d0.abs() / 4.0, 0), at(d1.abs() / 4.0, 1)];
        } else if k > 0 {
            r = [clamp(0, r[0] + d0), clamp(1, r[1] + d1)];
        }
        let x = k as f64 * 0.7 - 20.0;
        out.push(pt(
            [x, 5.0 + (k as f64 * 0.3).sin(), 10.0],
            axis_at(m, r),
            rapid || k == 0,
        ));
    }
    out
}

/// A rapid to a pose 0.0095° from head-head-ab's singular direction (inside the cone, A
/// free and held at -109), then a cut whose nearer branch from the held A lies outside
/// A's limits (-183.8) and whose other one is 105° away: the swing is made at the rapid,
/// as G0 pieces with the tip still, and the cut runs flip-free at its programmed time,
/// as the readback of the printed program (verification on) finds (the case proptest
/// found; before, `ik::flip` though a flip-free choice existed).
#[test]
fn a_rapid_to_a_held_singular_pose_swings_there_for_the_cut_after_it() {
    let m = machine("head-head-ab");
    let steps = [
        (true, 0.0, 2.552948493085217),
        (true, 1.9296344579453435, 3.6512010865529168),
        (false, 0.0, -3.8941335664948533),
    ];
    let points = feasible(&m, [0.0, 0.0], &steps);
    let run = compile_with("head-head-ab", &cl_text(&points), true);
    no_errors(&run);
    let text = &run.text;
    let printed = read_printed(text, letters(&m));
    // The swing: G0 pieces of at most 1°, the tip still.
    let swing: Vec<_> = printed
        .windows(2)
        .filter(|w| (w[1].j[3] - w[0].j[3]).abs() > 1e-6)
        .collect();
    assert!(swing.len() > 100, "{text}");
    for w in &swing {
        assert!(w[1].rapid, "line {}: A turns in a cutting block", w[1].line);
        assert!((w[1].j[3] - w[0].j[3]).abs() <= 1.0 + 1e-6);
        assert!((fk(&m, &w[1].j).0 - fk(&m, &w[0].j).0).norm() < 1e-3);
    }
    // Every CL point reached: the held one within the singularity cone (0.01°), the cut's
    // end exactly.
    let mut k = 0;
    for q in &printed {
        let (tip, axis) = fk(&m, &q.j);
        if k < points.len() && (tip - points[k].tip).norm() < 1e-3 {
            assert!(axis.angle(&points[k].axis).to_degrees() < 0.01, "point {k}");
            k += 1;
        }
    }
    assert_eq!(k, points.len(), "{text}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Every feasible generated program compiles without `ik::flip` on every preset, and
    /// its printed program reaches every CL point.
    #[test]
    fn feasible_programs_compile_without_a_flip(
        preset in 0usize..4,
        start in (0.0f64..1.0, 0.0f64..1.0),
        steps in prop::collection::vec(
            (prop::bool::weighted(0.08), -4.0f64..4.0, -4.0f64..4.0), 2..60),
    ) {
        let name = PRESETS[preset];
        let m = machine(name);
        let points = feasible(&m, [start.0, start.1], &steps);
        let run = compile(name, &cl_text(&points));
        let c = codes(&run);
        prop_assert!(!c.contains(&"ik::flip") && !c.contains(&"ik::unreachable"), "{name}: {:?}", run.diags);
        let printed = read_printed(&run.text, letters(&m));
        let pts = &points;
        let mut k = 0;
        for p in &printed {
            if k < pts.len() && (fk(&m, &p.j).0 - pts[k].tip).norm() < 1e-3 {
                k += 1;
            }
        }
        prop_assert_eq!(k, pts.len(), "{}: CL points reached\n{}", name, run.text);
    }
}
