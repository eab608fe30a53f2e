//! NX NURBS motion and NX `MSYS`, through the CLI and the printed text.
//!
//! - `tests/fixtures/cl/nx_nurbs.cl`: an NX CLSF layout with a rational cubic NURBS
//!   (written for ncpost; no public NX file with NURBS output was found). The printed
//!   G-code is read back and every point is checked against the curve evaluated here
//!   independently (Cox–de Boor basis functions, not the frontend's de Boor algorithm),
//!   and every chord against dense samples of the curve.
//! - `tests/fixtures/cl/nx_variable_axis.cl`: ../shared/corpus/cl/mech491_APT_Variable_Axis.txt
//!   lines 1-40 (real NX output, MSYS origin 3,3,0 in).
//! - `tests/fixtures/cl/nx_msys_rotated.cl`: the same path rewritten in an MCS with Z
//!   pointing down.

use std::path::PathBuf;
use std::process::{Command, Output};

const MM: f64 = 25.4;

fn ncpost(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ncpost"))
        .args(args)
        .output()
        .expect("run ncpost")
}

/// Compiles `path` under `preset`, listing the IR after the frontend on standard error.
fn dump_front(preset: &str, path: &str) -> Output {
    ncpost(&["run", "--preset", preset, "--dump-after", "front", path])
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A file in the test's scratch directory.
fn scratch(name: &str, text: &str) -> String {
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    std::fs::write(&path, text).expect("write scratch file");
    path.to_string_lossy().into_owned()
}

/// The trunnion-bc preset with `[cl_input] msys = "apply"`.
fn apply_preset() -> String {
    let base = std::fs::read_to_string("passes/trunnion-bc.toml").expect("preset");
    scratch(
        "trunnion-bc-msys-apply.toml",
        &format!("{base}\n[cl_input]\nmsys = \"apply\"\n"),
    )
}

/// X, Y, Z after every printed motion line (modal values), read from the G-code text.
fn printed_points(text: &str) -> Vec<[f64; 3]> {
    let mut pos = [f64::NAN; 3];
    let mut out = Vec::new();
    for line in text.lines() {
        let code = line.split(';').next().unwrap_or("");
        let words: Vec<&str> = code.split_whitespace().collect();
        if !words.iter().any(|w| *w == "G0" || *w == "G1")
            && !words.first().is_some_and(|w| "XYZ".contains(&w[..1]))
        {
            continue;
        }
        let mut moved = false;
        for w in &words {
            let i = match w.as_bytes()[0] {
                b'X' => 0,
                b'Y' => 1,
                b'Z' => 2,
                _ => continue,
            };
            pos[i] = w[1..].parse().expect("number");
            moved = true;
        }
        if moved {
            out.push(pos);
        }
    }
    out
}

/// Tips and axes of the pose motions in a `--dump-after front` listing.
fn dumped_poses(text: &str) -> Vec<([f64; 3], [f64; 3])> {
    let three = |s: &str, key: &str| -> [f64; 3] {
        let start = s.find(key).expect(key) + key.len();
        let end = start + s[start..].find(')').expect(")");
        let v: Vec<f64> = s[start..end]
            .split(',')
            .map(|x| x.trim().parse().expect("number"))
            .collect();
        [v[0], v[1], v[2]]
    };
    text.lines()
        .filter(|l| l.contains("tip=("))
        .map(|l| (three(l, "tip=("), three(l, "axis=(")))
        .collect()
}

/// The GOTO points of a CL file, as written.
fn written_gotos(path: &str) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .expect("fixture")
        .lines()
        .filter_map(|l| l.strip_prefix("GOTO/"))
        .map(|l| l.split(',').map(|x| x.trim().parse().unwrap()).collect())
        .collect()
}

/// The fixture's NURBS: degree 3, knots, control points (x, y, z, w).
fn fixture_curve() -> (usize, Vec<f64>, Vec<[f64; 4]>) {
    let knots = vec![0.0, 0.0, 0.0, 0.0, 0.25, 0.5, 0.5, 1.0, 1.0, 1.0, 1.0];
    let pts = vec![
        [-231.0, 0.0, 0.0, 1.0],
        [-171.0, 0.0, 40.0, 2.0],
        [-81.0, 30.0, 40.0, 1.0],
        [19.0, -20.0, 40.0, 1.0],
        [99.0, 0.0, 40.0, 0.5],
        [169.0, 10.0, 20.0, 1.0],
        [231.0, 0.0, 0.0, 1.0],
    ];
    (3, knots, pts)
}

/// The B-spline basis function N(i, p) at `u` (Cox–de Boor recursion; the last span is
/// closed at the end of the domain).
fn basis(i: usize, p: usize, u: f64, k: &[f64]) -> f64 {
    if p == 0 {
        let end = *k.last().unwrap();
        let last_span = k[i + 1] == end && k[i] < end;
        return if (k[i] <= u && u < k[i + 1]) || (last_span && u == end) {
            1.0
        } else {
            0.0
        };
    }
    let mut v = 0.0;
    if k[i + p] > k[i] {
        v += (u - k[i]) / (k[i + p] - k[i]) * basis(i, p - 1, u, k);
    }
    if k[i + p + 1] > k[i + 1] {
        v += (k[i + p + 1] - u) / (k[i + p + 1] - k[i + 1]) * basis(i + 1, p - 1, u, k);
    }
    v
}

fn curve_at(u: f64, (p, k, pts): &(usize, Vec<f64>, Vec<[f64; 4]>)) -> [f64; 3] {
    let (mut num, mut den) = ([0.0; 3], 0.0);
    for (i, c) in pts.iter().enumerate() {
        let b = basis(i, *p, u, k) * c[3];
        for d in 0..3 {
            num[d] += b * c[d];
        }
        den += b;
    }
    num.map(|x| x / den)
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Distance from `q` to the segment `a`–`b`.
fn to_segment(q: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let aq = [q[0] - a[0], q[1] - a[1], q[2] - a[2]];
    let len2 = ab.iter().map(|x| x * x).sum::<f64>();
    let t = if len2 > 0.0 {
        (ab.iter().zip(aq).map(|(x, y)| x * y).sum::<f64>() / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    dist(q, [a[0] + t * ab[0], a[1] + t * ab[1], a[2] + t * ab[2]])
}

/// Printed numbers have 4 decimals: half a unit of the last digit in each coordinate.
const PRINT: f64 = 1e-4;

#[test]
fn nurbs_pieces_lie_on_the_curve_and_chords_within_tolerance() {
    let o = ncpost(&[
        "run",
        "--preset",
        "trunnion-bc",
        "tests/fixtures/cl/nx_nurbs.cl",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("NURBS"), "{}", stderr(&o));
    let text = String::from_utf8(o.stdout).unwrap();
    assert!(
        text.lines().any(|l| l.contains("B0 C0")),
        "vertical tool: B0 C0"
    );
    let pts = printed_points(&text);
    // The rapid to Z50, the plunge to the spline start, the pieces, the GOTO to the
    // spline end (no move) and the GOTO beyond it.
    let start = pts
        .iter()
        .position(|p| p == &[-231.0, 0.0, 0.0])
        .expect("start");
    let end = pts
        .iter()
        .position(|p| p == &[231.0, 0.0, 0.0])
        .expect("end");
    let pieces = &pts[start..=end];
    assert!(pieces.len() > 20, "{} pieces", pieces.len());
    assert_eq!(pts.last().unwrap(), &[239.0, 0.0, 0.0]);

    let curve = fixture_curve();
    let n = 40_000;
    let samples: Vec<[f64; 3]> = (0..=n)
        .map(|i| curve_at(i as f64 / n as f64, &curve))
        .collect();
    let top = samples.iter().map(|s| s[2]).fold(f64::MIN, f64::max);
    assert!(top > 25.0, "the curve rises {top} mm");
    let printed_top = pieces.iter().map(|s| s[2]).fold(f64::MIN, f64::max);
    assert!(
        (printed_top - top).abs() < 0.01,
        "printed top {printed_top}, curve top {top}"
    );

    // Every printed point is on the curve: near a sample, measured to the sample polyline.
    let mut at = Vec::new();
    let mut from = 0;
    for q in pieces {
        let j = (from..=n)
            .min_by(|&a, &b| dist(*q, samples[a]).total_cmp(&dist(*q, samples[b])))
            .unwrap();
        let lo = j.saturating_sub(1);
        let hi = (j + 1).min(n);
        let d =
            to_segment(*q, samples[lo], samples[j]).min(to_segment(*q, samples[j], samples[hi]));
        assert!(d <= 2.0 * PRINT, "{q:?} is {d} mm off the curve");
        at.push(j);
        from = j;
    }
    // Every chord is within arc_tolerance (0.001 mm) of the curve between its ends.
    for (w, q) in at.windows(2).zip(pieces.windows(2)) {
        assert!(w[0] <= w[1], "pieces go along the curve");
        // The samples strictly between the ones nearest the ends lie between the ends.
        for s in &samples[(w[0] + 1).min(w[1])..w[1]] {
            let d = to_segment(*s, q[0], q[1]);
            assert!(
                d <= 0.001 + 2.0 * PRINT,
                "chord {q:?} is {d} mm from the curve"
            );
        }
    }
}

#[test]
fn nurbs_control_points_with_tool_axes_turn_the_tool() {
    // A quadratic whose middle control point tilts the tool 30 deg about Y.
    let (s, c) = (30f64.to_radians().sin(), 30f64.to_radians().cos());
    let cl = format!(
        "UNITS/MM\nFEDRAT/MMPM,300\nGOTO/0,0,0\nNURBS/ORDER,3\nKNOT/0,0,0,1,1,1\n\
         CNTRL/0,0,0,0,0,1\nCNTRL/50,0,20,{s},0,{c}\nCNTRL/100,0,0,0,0,1\nGOTO/100,0,0\n"
    );
    let path = scratch("nurbs_axes.cl", &cl);
    let o = dump_front("trunnion-bc", &path);
    assert!(o.status.success(), "{}", stderr(&o));
    let poses = dumped_poses(&stderr(&o));
    assert!(poses.len() > 10);
    let mid = poses
        .iter()
        .min_by(|a, b| (a.0[0] - 50.0).abs().total_cmp(&(b.0[0] - 50.0).abs()))
        .unwrap();
    // At u = 1/2 the basis is 1/4, 1/2, 1/4: the axis is (s/2, 0, 1/2 + c/2), made unit.
    let (ex, ez) = (0.5 * s, 0.5 + 0.5 * c);
    let norm = (ex * ex + ez * ez).sqrt();
    assert!((mid.0[0] - 50.0).abs() < 2.0);
    assert!((mid.1[0] - ex / norm).abs() < 0.01, "{mid:?}");
    assert!((mid.1[2] - ez / norm).abs() < 0.01, "{mid:?}");
    // The output is 5-axis: B turns.
    let text = String::from_utf8(o.stdout).unwrap();
    assert!(
        text.lines().any(|l| l.contains(" B") && !l.contains("B0 ")),
        "{text}"
    );
}

#[test]
fn nurbs_that_cannot_be_evaluated_is_an_error_at_its_line() {
    let cases = [
        (
            "decreasing knots",
            "NURBS/\nKNOT/0,0,0,0.6,0.4,1,1,1\nCNTRL/0,0,0\nCNTRL/1,1,0\nCNTRL/2,1,0\nCNTRL/3,0,0\nCNTRL/4,0,0\n",
            4,
        ),
        (
            "too few control points",
            "NURBS/\nKNOT/0,0,0,0,1,1,1,1\nCNTRL/0,0,0\nCNTRL/1,1,0\n",
            4,
        ),
        (
            "degree mismatch",
            "NURBS/DEGREE,2\nKNOT/0,0,0,0,1,1,1,1\nCNTRL/0,0,0\nCNTRL/1,1,0\nCNTRL/2,1,0\nCNTRL/3,0,0\n",
            4,
        ),
        ("no control points", "NURBS/\nKNOT/0,0,1,1\n", 4),
        ("no knots", "NURBS/\nCNTRL/0,0,0\nCNTRL/1,0,0\n", 4),
        ("knot outside a NURBS", "KNOT/0,0,1,1\n", 4),
        (
            "zero weight",
            "NURBS/\nKNOT/0,0,1,1\nCNTRL/0,0,0,1\nCNTRL/1,0,0,0\n",
            7,
        ),
    ];
    for (i, (what, records, line)) in cases.into_iter().enumerate() {
        let cl = format!("UNITS/MM\nFEDRAT/MMPM,300\nGOTO/0,0,0\n{records}GOTO/50,0,0\n");
        let name = format!("nurbs_bad_{i}.cl");
        let path = scratch(&name, &cl);
        let o = ncpost(&["run", "--preset", "trunnion-bc", &path]);
        let err = stderr(&o);
        assert!(!o.status.success(), "{what}: exit 0\n{err}");
        assert!(err.contains("cl::nurbs"), "{what}: {err}");
        assert!(
            err.contains(&format!("{name}:{line}")),
            "{what}: no line {line}\n{err}"
        );
        assert!(err.contains("help:"), "{what}: {err}");
    }
}

#[test]
fn msys_is_ignored_by_default_like_nx_posts_with_one_warning() {
    let path = "tests/fixtures/cl/nx_variable_axis.cl";
    let o = dump_front("trunnion-bc", path);
    let err = stderr(&o);
    assert_eq!(err.matches("cl::msys-not-applied").count(), 1, "{err}");
    let poses = dumped_poses(&err);
    let raw = written_gotos(path);
    assert_eq!(poses.len(), raw.len());
    for ((tip, _), g) in poses.iter().zip(&raw) {
        for d in 0..3 {
            assert!((tip[d] - g[d] * MM).abs() < 2.0 * PRINT, "{tip:?} vs {g:?}");
        }
    }
}

#[test]
fn msys_applied_moves_points_by_its_origin() {
    let path = "tests/fixtures/cl/nx_variable_axis.cl";
    let preset = apply_preset();
    let o = dump_front(&preset, path);
    let err = stderr(&o);
    assert!(!err.contains("cl::msys-not-applied"), "{err}");
    let poses = dumped_poses(&err);
    let raw = written_gotos(path);
    assert_eq!(poses.len(), raw.len());
    let origin = [3.0, 3.0, 0.0];
    for ((tip, _), g) in poses.iter().zip(&raw) {
        for d in 0..3 {
            assert!(
                (tip[d] - (origin[d] + g[d]) * MM).abs() < 2.0 * PRINT,
                "{tip:?} vs {g:?}"
            );
        }
    }
}

#[test]
fn rotated_msys_applied_is_the_matrix_transform_and_ignored_names_itself_in_ik_help() {
    let rotated = "tests/fixtures/cl/nx_msys_rotated.cl";
    // Ignored: the tool axes point down in the part frame, out of the trunnion's reach,
    // and the help names the MSYS line.
    let o = ncpost(&["run", "--preset", "trunnion-bc", rotated]);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert!(err.contains("ik::unreachable"), "{err}");
    assert!(
        err.contains("line 4 sets a rotated coordinate frame"),
        "{err}"
    );
    assert!(err.contains("msys = \"apply\""), "{err}");

    // Applied: p = origin + R p_mcs, a = R a_mcs with R = (X, Y, X × Y) of the MSYS.
    let preset = apply_preset();
    let o = dump_front(&preset, rotated);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    let poses = dumped_poses(&err);
    let raw = written_gotos(rotated);
    let (origin, x, y) = ([3.0, 3.0, 4.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]);
    let z = [
        x[1] * y[2] - x[2] * y[1],
        x[2] * y[0] - x[0] * y[2],
        x[0] * y[1] - x[1] * y[0],
    ];
    let rot =
        |v: &[f64]| -> [f64; 3] { [0, 1, 2].map(|d| x[d] * v[0] + y[d] * v[1] + z[d] * v[2]) };
    let mut axis = [0.0; 3];
    for ((tip, a), g) in poses.iter().zip(&raw) {
        let p = rot(&g[..3]);
        if g.len() == 6 {
            axis = rot(&g[3..]);
        }
        for d in 0..3 {
            assert!(
                (tip[d] - (origin[d] + p[d]) * MM).abs() < 2.0 * PRINT,
                "{tip:?} vs {g:?}"
            );
            assert!((a[d] - axis[d]).abs() < 2e-6, "{a:?} vs {axis:?}");
        }
    }
    // And that is the real file's path in NX's absolute frame (its MSYS origin 3,3,0 in).
    let real = written_gotos("tests/fixtures/cl/nx_variable_axis.cl");
    for ((tip, _), g) in poses.iter().zip(&real) {
        for d in 0..3 {
            let want = ([3.0, 3.0, 0.0][d] + g[d]) * MM;
            assert!((tip[d] - want).abs() < 0.01, "{tip:?} vs {g:?}");
        }
    }
}
