//! The pieces `densify` (5-axis presets) and `polar-ik` (polar-printer) cut moves into:
//! read back from the printed program, the controller's joint-linear path between every
//! two printed positions stays within the tolerance of the programmed move, and the
//! pieces are about as long as the tolerance allows (as few as it allows: a piece that is
//! not the last of its move comes close to the tolerance).

use nalgebra::{Point3, Vector2};
use ncpost::diag::Severity;
use ncpost::ir::Axis;
use ncpost::machine::{Machine, ToolPose};
use ncpost::pipeline::{Pipeline, Source};
use ncpost::preset::Preset;

mod common;
use common::geometry::{
    angle_to_arc, arc_distance, distance_to_segment, segment_distance_xy, unit,
};

const PRESETS: [&str; 4] = ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"];

/// Runs `preset` on `input`; the printed program. Errors fail the test.
fn compile(preset: &Preset, source: Source, input: &str) -> String {
    let mut p = Pipeline::builder()
        .preset(preset.clone())
        .build()
        .expect("preset builds");
    let mut out = Vec::new();
    let mut errors = Vec::new();
    p.run_source(source, input.as_bytes(), &mut out, &mut |d| {
        if d.severity == Severity::Error {
            errors.push(d);
        }
    })
    .expect("runs");
    assert!(errors.is_empty(), "{errors:?}");
    String::from_utf8(out).expect("utf-8")
}

/// The positions the controller moves through, read from the printed text: for every
/// G0/G1, the values of `letters` before and after it (G92 frames taken off), and whether
/// it was a G1.
fn printed_moves(text: &str, letters: &[char]) -> Vec<(Vec<f64>, Vec<f64>, bool)> {
    let mut pos: Vec<Option<f64>> = vec![None; letters.len()];
    let mut offsets = vec![0.0; letters.len()];
    let mut moves = Vec::new();
    for line in text.lines() {
        let code = line.split(';').next().unwrap_or("");
        let words: Vec<(char, f64)> = code
            .split_whitespace()
            .filter_map(|w| {
                let mut c = w.chars();
                let l = c.next()?;
                Some((l, c.as_str().parse::<f64>().ok()?))
            })
            .collect();
        let g = |n: f64| words.iter().any(|&(c, v)| c == 'G' && v == n);
        let before = pos.clone();
        for &(l, v) in &words {
            if let Some(k) = letters.iter().position(|&c| c == l) {
                if g(92.0) {
                    // The position stays; the program frame moves.
                    offsets[k] = before[k].map_or(0.0, |b| v - b);
                    pos[k] = Some(v - offsets[k]);
                } else {
                    pos[k] = Some(v - offsets[k]);
                }
            }
        }
        if (g(0.0) || g(1.0)) && before.iter().chain(&pos).all(Option::is_some) {
            let v = |p: &[Option<f64>]| p.iter().map(|x| x.unwrap_or(0.0)).collect();
            moves.push((v(&before), v(&pos), g(1.0)));
        }
    }
    moves
}

/// Sweeps of the tool axis along lines, as CL data, with their poses.
fn cl_program() -> (String, Vec<ToolPose>) {
    let mut text = String::from("PARTNO/PIECES\nUNITS/MM\nMULTAX/ON\nRAPID\n");
    let mut poses = Vec::new();
    let p0 = Point3::new(-30.0, -20.0, 10.0);
    let p1 = Point3::new(35.0, 25.0, 25.0);
    for k in 0..=10 {
        let s = f64::from(k) / 10.0;
        let tip = p0 + (p1 - p0) * s;
        let axis = unit(15.0 + 20.0 * s, 30.0 + 60.0 * s);
        text.push_str(&format!(
            "GOTO/{:.6},{:.6},{:.6},{:.9},{:.9},{:.9}\n",
            tip.x, tip.y, tip.z, axis.x, axis.y, axis.z
        ));
        if k == 0 {
            text.push_str("FEDRAT/MMPM,1000\n");
        }
        poses.push(ToolPose { tip, axis });
    }
    text.push_str("FINI\n");
    (text, poses)
}

/// The worst (tip mm, axis degrees) deviation of the joint-linear path between printed
/// positions `a` and `b` from the programmed segment `p0`–`p1`.
fn five_axis_deviation(
    m: &Machine,
    a: &[f64],
    b: &[f64],
    p0: &ToolPose,
    p1: &ToolPose,
) -> (f64, f64) {
    let mut worst = (0.0f64, 0.0f64);
    for k in 0..=200 {
        let s = f64::from(k) / 200.0;
        let l = |i: usize| a[i] + (b[i] - a[i]) * s;
        let pose = m.forward(&[l(0), l(1), l(2)], [l(3), l(4)]);
        worst.0 = worst
            .0
            .max(distance_to_segment(&pose.tip, &p0.tip, &p1.tip));
        worst.1 = worst.1.max(angle_to_arc(&pose.axis, &p0.axis, &p1.axis));
    }
    worst
}

/// On every 5-axis preset, read from the printed text: every piece stays within
/// `tip_tolerance` and `axis_tolerance` of its programmed CL segment, and every piece but
/// the last of its move reaches most of a tolerance (the longest pieces that fit).
#[test]
fn densify_pieces_hold_the_tolerance_as_printed_and_are_long() {
    let (cl, poses) = cl_program();
    for name in PRESETS {
        let preset = Preset::builtin(name).expect("preset");
        let m = preset.machine.clone().expect("machine");
        let [r0, r1] = m.rotary_axes();
        let letters = ['X', 'Y', 'Z', r0.letter(), r1.letter()];
        let text = compile(&preset, Source::Cl, &cl);
        let moves = printed_moves(&text, &letters);
        let fk = |v: &[f64]| m.forward(&[v[0], v[1], v[2]], [v[3], v[4]]);
        let mut seg = 1;
        let (mut pieces, mut long, mut split_moves) = (Vec::new(), 0, 0);
        for (a, b, cut) in moves.iter().filter(|mv| mv.2) {
            assert!(*cut);
            assert!(seg < poses.len(), "{name}: more moves than programmed");
            let (tip, axis) = five_axis_deviation(&m, a, b, &poses[seg - 1], &poses[seg]);
            assert!(tip <= 0.01 + 1e-9, "{name}: tip {tip} mm off");
            assert!(axis <= 0.05 + 1e-9, "{name}: axis {axis} degrees off");
            pieces.push((tip / 0.01).max(axis / 0.05));
            let end = fk(b);
            if (end.tip - poses[seg].tip).norm() < 2e-3 && end.axis.angle(&poses[seg].axis) < 1e-3 {
                // The move's last piece: the others must be long (come close to a
                // tolerance, in tip or axis).
                if pieces.len() > 1 {
                    split_moves += 1;
                }
                // (The last two share what is left of the move evenly.)
                let n = pieces.len().saturating_sub(2);
                assert!(
                    pieces[..n].iter().all(|&d| d > 0.8),
                    "{name}: segment {seg}: {pieces:?}"
                );
                long += n;
                pieces.clear();
                seg += 1;
            }
        }
        assert_eq!(seg, poses.len(), "{name}: every programmed move ends");
        assert!(
            split_moves >= 5 && long >= 5,
            "{name}: the moves were split ({split_moves}, {long})"
        );
    }
}

/// A programmed XY path of the polar test: a line or an arc (centre, radius, start
/// angle, signed sweep).
enum Path {
    Line(Vector2<f64>, Vector2<f64>),
    Arc(Vector2<f64>, f64, f64, f64),
}

impl Path {
    fn end(&self) -> Vector2<f64> {
        match self {
            Path::Line(_, b) => *b,
            Path::Arc(c, r, start, sweep) => {
                c + Vector2::new((start + sweep).cos(), (start + sweep).sin()) * *r
            }
        }
    }

    fn distance(&self, p: &Vector2<f64>) -> f64 {
        match self {
            Path::Line(a, b) => segment_distance_xy(p, a, b),
            Path::Arc(c, r, start, sweep) => arc_distance(p, c, *r, *start, *sweep),
        }
    }
}

/// Lines and arcs around and across the centre region, as G-code, with their paths.
fn polar_program() -> (String, Vec<Path>) {
    let mut text = String::from("G21\nG90\nG0 X40 Y0 F6000\n");
    let mut paths = vec![Path::Line(Vector2::new(40.0, 0.0), Vector2::new(40.0, 0.0))];
    let mut at = Vector2::new(40.0, 0.0);
    let line =
        |text: &mut String, paths: &mut Vec<Path>, at: &mut Vector2<f64>, to: Vector2<f64>| {
            text.push_str(&format!("G1 X{:.6} Y{:.6} F1800\n", to.x, to.y));
            paths.push(Path::Line(*at, to));
            *at = to;
        };
    line(&mut text, &mut paths, &mut at, Vector2::new(-30.0, 25.0));
    line(&mut text, &mut paths, &mut at, Vector2::new(-5.0, -45.0));
    line(&mut text, &mut paths, &mut at, Vector2::new(25.0, 3.0));
    // Arcs: about a centre off the table's axis, clockwise and counter-clockwise, one
    // enclosing the table's centre.
    for (c, ccw, sweep) in [
        (Vector2::new(4.0, 0.0), true, 4.0),
        (Vector2::new(30.0, 20.0), false, 2.0),
        (Vector2::new(-20.0, 10.0), true, 1.5),
    ] {
        let v = at - c;
        let (r, start) = (v.norm(), v.y.atan2(v.x));
        let sweep = if ccw { sweep } else { -sweep };
        let end = c + Vector2::new((start + sweep).cos(), (start + sweep).sin()) * r;
        text.push_str(&format!(
            "G{} X{:.6} Y{:.6} I{:.6} J{:.6} F1800\n",
            if ccw { 3 } else { 2 },
            end.x,
            end.y,
            c.x - at.x,
            c.y - at.y
        ));
        paths.push(Path::Arc(c, r, start, sweep));
        at = end;
    }
    (text, paths)
}

/// On the polar printer, read from the printed r and θ: every piece of every line and arc
/// stays within the tolerance of the programmed line or arc itself (arcs spend the
/// tolerance once), and the pieces are long (without the near-centre speed cap, whose
/// splits are for the feed).
#[test]
fn polar_pieces_hold_the_tolerance_as_printed_and_are_long() {
    let mut preset = Preset::builtin("polar-printer").expect("preset");
    check_polar(&preset, false);
    for p in &mut preset.passes {
        if p.name == "polar-ik" {
            p.options.insert("speed_cap".into(), false.into());
        }
    }
    check_polar(&preset, true);
}

fn check_polar(preset: &Preset, lengths: bool) {
    let polar = preset.polar.clone().expect("[polar]");
    let letters = [polar.r_axis.letter(), polar.theta_axis.letter()];
    assert_eq!(polar.r_axis, Axis::X);
    let (program, paths) = polar_program();
    let text = compile(preset, Source::Gcode, &program);
    let xy = |v: &[f64]| {
        let th = v[1].to_radians();
        Vector2::new(v[0] * th.cos(), v[0] * th.sin())
    };
    let mut k = 1;
    let (mut pieces, mut long, mut arcs_split) = (Vec::new(), 0, 0);
    for (a, b, _) in printed_moves(&text, &letters) {
        assert!(k < paths.len(), "more moves than programmed");
        let mut worst: f64 = 0.0;
        for s in 0..=200 {
            let s = f64::from(s) / 200.0;
            let p = xy(&[a[0] + (b[0] - a[0]) * s, a[1] + (b[1] - a[1]) * s]);
            worst = worst.max(paths[k].distance(&p));
        }
        assert!(worst <= 0.01 + 1e-9, "path {k}: {worst} mm off");
        // An arc's piece turns at most 20° about the arc's centre (polar-ik's MAX_TURN,
        // shared evenly over the arc): such a piece is as long as it may be.
        let turn = match &paths[k] {
            Path::Arc(c, ..) => (xy(&a) - c).angle(&(xy(&b) - c)),
            Path::Line(..) => 0.0,
        };
        pieces.push(if turn > 0.29 { 1.0 } else { worst / 0.01 });
        if (xy(&b) - paths[k].end()).norm() < 2e-3 {
            // All but the last two pieces of a move are long (the last two of a line
            // share what is left evenly).
            let n = pieces.len().saturating_sub(2);
            assert!(
                !lengths || pieces[..n].iter().all(|&d| d > 0.75),
                "path {k}: {pieces:?}"
            );
            long += n;
            if matches!(paths[k], Path::Arc(..)) && pieces.len() > 2 {
                arcs_split += 1;
            }
            pieces.clear();
            k += 1;
        }
    }
    assert_eq!(k, paths.len(), "every programmed move ends");
    assert!(long > 50 && arcs_split == 3, "{long} {arcs_split}");
    assert!(text.contains("G1 X"), "{text}");
}
