//! The `heightmap` pass, checked against a bilinear surface computed here from the
//! parsed grid: on every ../shared/corpus/heightmap/*.csv (RepRapFirmware) and on a
//! synthetic tilted and warped map on an uneven grid (x,y,z CSV and bCNC `.probe`),
//! every output vertex's Z is the programmed Z (interpolated along the original move)
//! plus bilinear(x, y) within 1e-6 mm and lies on the programmed XY segment; the
//! midpoint of every output segment is within the tolerance of the compensated path; no
//! output segment crosses a grid line; rapids and plunges are compensated; clamp mode
//! extends the edge heights; the outside-the-grid error has a plain diagnostic snapshot;
//! the three file formats of one surface give the same output; probe-program output
//! snapshots for rrf and grbl. The RRF maps are read from ../shared/corpus/heightmap (the
//! format has no comment line to carry an origin).

use std::fmt::Write as _;
use std::path::PathBuf;

use ncpost::diag::Diagnostic;
use ncpost::front::gcode::{Options, parse_str};
use ncpost::heightmap::{HeightMap, ProbeEmit, ProbeOptions, probe_program};
use ncpost::ir::{Axis, Block, BlockKind, Joints, MotionKind, Target};
use ncpost::passes::{self, Context, Output};
use proptest::prelude::*;

fn corpus_maps() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/heightmap");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("corpus")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .collect();
    v.sort();
    assert_eq!(v.len(), 4);
    v
}

/// The surface, computed here: find the cell by scanning the grid lines, then the
/// bilinear formula in the cell's own coordinates; outside, `None` unless `clamp`.
struct Surface {
    xs: Vec<f64>,
    ys: Vec<f64>,
    z: Vec<f64>,
}

impl Surface {
    fn of(map: &HeightMap) -> Surface {
        Surface {
            xs: map.xs.clone(),
            ys: map.ys.clone(),
            z: map.z.iter().map(|h| h.expect("probed")).collect(),
        }
    }

    fn at(&self, x: f64, y: f64, clamp: bool) -> Option<f64> {
        let (x0, x1) = (self.xs[0], *self.xs.last().unwrap());
        let (y0, y1) = (self.ys[0], *self.ys.last().unwrap());
        if !clamp && (x < x0 || x > x1 || y < y0 || y > y1) {
            return None;
        }
        let (x, y) = (x.clamp(x0, x1), y.clamp(y0, y1));
        let i = (0..self.xs.len() - 1)
            .find(|&i| x <= self.xs[i + 1])
            .unwrap();
        let j = (0..self.ys.len() - 1)
            .find(|&j| y <= self.ys[j + 1])
            .unwrap();
        let u = (x - self.xs[i]) / (self.xs[i + 1] - self.xs[i]);
        let v = (y - self.ys[j]) / (self.ys[j + 1] - self.ys[j]);
        let n = self.xs.len();
        let h = |a: usize, b: usize| self.z[(j + b) * n + i + a];
        Some(
            h(0, 0) * (1.0 - u) * (1.0 - v)
                + h(1, 0) * u * (1.0 - v)
                + h(0, 1) * (1.0 - u) * v
                + h(1, 1) * u * v,
        )
    }
}

/// Frontend, then `heightmap` with `options` (TOML): input blocks, output blocks,
/// diagnostics.
fn compensate(src: &str, options: &str) -> (Vec<Block>, Vec<Block>, Vec<Diagnostic>) {
    let program = parse_str(src, &Options::default()).expect("parses");
    let table: toml::Table = toml::from_str(options).expect("options");
    let mut pass = passes::build("heightmap", &table, &Context::default()).expect("builds");
    let mut out = Vec::new();
    let mut diags = program.diagnostics.clone();
    for b in program.blocks.iter().cloned() {
        pass.run(&mut vec![b], &mut Output::new(&mut out, &mut diags));
    }
    pass.finish(&mut Output::new(&mut out, &mut diags));
    (program.blocks, out, diags)
}

fn xyz(j: &Joints) -> [f64; 3] {
    [
        j.get(Axis::X).expect("X"),
        j.get(Axis::Y).expect("Y"),
        j.get(Axis::Z).expect("Z"),
    ]
}

/// What the checks measured.
#[derive(Debug, Default)]
struct Stats {
    moves: usize,
    rapids: usize,
    segments: usize,
    worst_vertex: f64,
    worst_midpoint: f64,
}

/// Checks the output of every move against the programmed move and the surface.
fn check(
    input: &[Block],
    output: &[Block],
    surface: &Surface,
    tol: f64,
    clamp: bool,
    name: &str,
) -> Stats {
    let mut stats = Stats::default();
    let mut pos: Option<[f64; 3]> = None;
    let mut k = 0;
    for b in input {
        let mut pieces = Vec::new();
        while k < output.len() && output[k].span == b.span {
            pieces.push(&output[k]);
            k += 1;
        }
        let BlockKind::Motion(m) = &b.kind else {
            continue;
        };
        let Target::Joints(to) = &m.target else {
            panic!("pose")
        };
        let end = xyz(to);
        let rapid = matches!(m.kind, MotionKind::Rapid);
        let what = format!("{name}: line {}", b.span.line);
        let verts: Vec<[f64; 3]> = pieces
            .iter()
            .map(|p| match &p.kind {
                BlockKind::Motion(o) => {
                    assert_eq!(o.kind, m.kind, "{what}: the pieces keep the motion");
                    xyz(o.target.joints().expect("joints"))
                }
                _ => panic!("{what}: a piece is not a move"),
            })
            .collect();
        assert!(!verts.is_empty(), "{what}: no output");
        stats.moves += 1;
        if rapid {
            stats.rapids += 1;
        }
        let Some(start) = pos else {
            // From an unknown start only the end point is compensated.
            assert_eq!(verts.len(), 1);
            let h = surface.at(end[0], end[1], clamp).expect("inside");
            assert!((verts[0][2] - end[2] - h).abs() <= 1e-6, "{what}");
            pos = Some(end);
            continue;
        };
        let d = [end[0] - start[0], end[1] - start[1]];
        let len2 = d[0] * d[0] + d[1] * d[1];
        // The parameter along the move of a point (by XY; a Z-only move has one piece).
        let t_of = |p: [f64; 3]| {
            if len2 == 0.0 {
                1.0
            } else {
                ((p[0] - start[0]) * d[0] + (p[1] - start[1]) * d[1]) / len2
            }
        };
        let programmed = |t: f64| start[2] + (end[2] - start[2]) * t;
        let mut prev = {
            let h = surface.at(start[0], start[1], clamp).expect("start inside");
            [start[0], start[1], start[2] + h]
        };
        let mut prev_t = 0.0;
        for (i, v) in verts.iter().enumerate() {
            let t = t_of(*v);
            assert!(
                t > prev_t - 1e-12 && t <= 1.0 + 1e-12,
                "{what}: vertex {i} at t = {t}"
            );
            // On the programmed XY segment.
            let (px, py) = (start[0] + d[0] * t, start[1] + d[1] * t);
            assert!(
                (px - v[0]).abs() < 1e-9 && (py - v[1]).abs() < 1e-9,
                "{what}: vertex {i} off the move"
            );
            // Z = programmed Z + surface.
            let h = surface.at(v[0], v[1], clamp).expect("inside");
            let err = (v[2] - programmed(t) - h).abs();
            stats.worst_vertex = stats.worst_vertex.max(err);
            assert!(err <= 1e-6, "{what}: vertex {i} Z off by {err}");
            // The segment's midpoint against the compensated path there.
            let mid = [
                (prev[0] + v[0]) / 2.0,
                (prev[1] + v[1]) / 2.0,
                (prev[2] + v[2]) / 2.0,
            ];
            let tm = (prev_t + t) / 2.0;
            let hm = surface.at(mid[0], mid[1], clamp).expect("inside");
            let dev = (mid[2] - programmed(tm) - hm).abs();
            stats.worst_midpoint = stats.worst_midpoint.max(dev);
            assert!(
                dev <= tol + 1e-9,
                "{what}: segment {i} midpoint {dev} > {tol}"
            );
            // No grid line strictly inside the segment.
            for (lines, a, b) in [(&surface.xs, prev[0], v[0]), (&surface.ys, prev[1], v[1])] {
                let (lo, hi) = (a.min(b), a.max(b));
                for &g in lines.iter() {
                    assert!(
                        !(g > lo + 1e-9 && g < hi - 1e-9),
                        "{what}: segment {i} crosses the grid line {g}"
                    );
                }
            }
            stats.segments += 1;
            prev = *v;
            prev_t = t;
        }
        // The last vertex is the target plus the surface, X and Y exact.
        let last = verts[verts.len() - 1];
        assert_eq!((last[0], last[1]), (end[0], end[1]), "{what}");
        pos = Some(end);
    }
    stats
}

/// A program over `[x0, x1] x [y0, y1]`: rapids, plunges, diagonal cuts, cuts along and
/// across grid lines, moves ending on grid lines, ramps, and pseudo-random moves.
fn program(area: [f64; 4], lines: (&[f64], &[f64]), seed: u64) -> String {
    let [x0, y0, x1, y1] = area;
    let mut s = String::from("G21 G90\n");
    let _ = writeln!(s, "G0 X{x0:.4} Y{y0:.4} Z2");
    let _ = writeln!(s, "G1 Z-0.06 F20");
    let _ = writeln!(s, "G1 X{x1:.4} Y{y1:.4} F70");
    let _ = writeln!(s, "G0 Z2");
    let _ = writeln!(s, "G0 X{x0:.4} Y{y1:.4} Z0.5");
    let _ = writeln!(s, "G1 X{x1:.4} Y{y0:.4} Z-0.1 F70");
    // Along a grid line and ending on grid lines.
    let (gx, gy) = (lines.0[1], lines.1[1]);
    let _ = writeln!(s, "G1 X{gx} Y{y0:.4}");
    let _ = writeln!(s, "G1 X{gx} Y{y1:.4}");
    let _ = writeln!(s, "G1 X{x0:.4} Y{gy}");
    let _ = writeln!(s, "G1 X{x1:.4} Y{gy} Z-0.05");
    let _ = writeln!(s, "G0 Z3");
    let mut state = seed;
    let mut rnd = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for k in 0..40 {
        let x = x0 + (x1 - x0) * rnd();
        let y = y0 + (y1 - y0) * rnd();
        let z = -0.2 + 0.4 * rnd();
        let code = if k % 5 == 0 { "G0" } else { "G1" };
        let _ = writeln!(s, "{code} X{x:.4} Y{y:.4} Z{z:.4} F300");
    }
    s
}

#[test]
fn corpus_rrf_maps() {
    for path in corpus_maps() {
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let text = std::fs::read_to_string(&path).unwrap();
        let map = HeightMap::parse(&text).expect("parses");
        // The grid against the file's own numbers: the third line names min, spacing and
        // count (in either label order); the rows are the heights, from the first Y up.
        let labels: Vec<&str> = text.lines().nth(1).unwrap().split(',').collect();
        let values: Vec<&str> = text.lines().nth(2).unwrap().split(',').collect();
        let get = |names: &[&str]| -> f64 {
            let i = labels
                .iter()
                .position(|l| names.contains(&l.trim()))
                .unwrap();
            values[i].trim().parse().unwrap()
        };
        let (xmin, xsp, xn) = (
            get(&["xmin", "min0"]),
            get(&["xspacing", "spacing0"]),
            get(&["xnum", "num0"]),
        );
        let (ymin, ysp, yn) = (
            get(&["ymin", "min1"]),
            get(&["yspacing", "spacing1"]),
            get(&["ynum", "num1"]),
        );
        assert_eq!(map.xs.len(), xn as usize);
        assert_eq!(map.ys.len(), yn as usize);
        for (i, &x) in map.xs.iter().enumerate() {
            assert!((x - (xmin + i as f64 * xsp)).abs() < 1e-9);
        }
        for (j, &y) in map.ys.iter().enumerate() {
            assert!((y - (ymin + j as f64 * ysp)).abs() < 1e-9);
        }
        let rows: Vec<Vec<f64>> = text
            .lines()
            .skip(3)
            .filter(|l| !l.trim().is_empty())
            .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
            .collect();
        for (j, row) in rows.iter().enumerate() {
            for (i, &h) in row.iter().enumerate() {
                assert_eq!(map.node(i, j), Some(h), "{name} node {i},{j}");
            }
        }
        let surface = Surface::of(&map);
        let area = [
            map.xs[0] + 1.0,
            map.ys[0] + 1.0,
            *map.xs.last().unwrap() - 1.0,
            *map.ys.last().unwrap() - 1.0,
        ];
        let src = program(area, (&map.xs, &map.ys), 7);
        for tol in [0.001, 0.0001] {
            let options = format!("map = {:?}\ntolerance = {tol}\n", path.to_str().unwrap());
            let (input, output, diags) = compensate(&src, &options);
            assert!(diags.iter().all(|d| !d.is_error()), "{name}: {diags:?}");
            let stats = check(&input, &output, &surface, tol, false, &name);
            assert!(
                stats.rapids > 5 && stats.segments > stats.moves,
                "{name}: {stats:?}"
            );
        }
    }
}

/// The synthetic board: tilted 0.3 mm over 60 mm in X, warped by up to 0.087 mm (the
/// seed's measured warp) in a saddle and a bump, on an uneven grid (2 to 10 mm pitch).
fn synthetic_points() -> (Vec<f64>, Vec<f64>, Vec<[f64; 3]>) {
    let xs = vec![0.0, 2.0, 7.0, 15.0, 25.0, 35.0, 42.0, 50.0, 60.0];
    let ys = vec![0.0, 5.0, 10.0, 12.5, 20.0, 30.0, 40.0];
    let h = |x: f64, y: f64| {
        0.005 * x - 0.002 * y
            + 0.087 * ((x / 60.0 - 0.5) * (y / 40.0 - 0.5)) * 4.0
            + 0.03 * (-((x - 30.0).powi(2) + (y - 20.0).powi(2)) / 100.0).exp()
    };
    let mut pts = Vec::new();
    for &y in &ys {
        for &x in &xs {
            pts.push([x, y, (h(x, y) * 1e6).round() / 1e6]);
        }
    }
    (xs, ys, pts)
}

fn write_temp(dir: &tempfile::TempDir, name: &str, text: &str) -> String {
    let p = dir.path().join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

/// The synthetic map as x,y,z CSV (shuffled rows, a header and comments) and as bCNC.
fn synthetic_files(dir: &tempfile::TempDir) -> (String, String) {
    let (xs, ys, pts) = synthetic_points();
    let mut csv = String::from("# synthetic tilted and warped board (tests/heightmap.rs)\nx,y,z\n");
    // Row order does not matter for plain CSV: write the columns backwards.
    for p in pts.iter().rev() {
        let _ = writeln!(csv, "{},{},{}", p[0], p[1], p[2]);
    }
    let mut bcnc = format!(
        "{} {} {}\n{} {} {}\n-1 1 10\n",
        xs[0],
        xs[xs.len() - 1],
        xs.len(),
        ys[0],
        ys[ys.len() - 1],
        ys.len()
    );
    for (j, _) in ys.iter().enumerate() {
        for p in &pts[j * xs.len()..(j + 1) * xs.len()] {
            let _ = writeln!(bcnc, "{} {} {}", p[0], p[1], p[2]);
        }
        bcnc.push('\n');
    }
    (
        write_temp(dir, "board.csv", &csv),
        write_temp(dir, "board.probe", &bcnc),
    )
}

#[test]
fn synthetic_map_in_csv_and_bcnc() {
    let dir = tempfile::tempdir().unwrap();
    let (csv, bcnc) = synthetic_files(&dir);
    let (xs, ys, pts) = synthetic_points();
    let surface = Surface {
        xs: xs.clone(),
        ys: ys.clone(),
        z: pts.iter().map(|p| p[2]).collect(),
    };
    let src = program([0.0, 0.0, 60.0, 40.0], (&xs, &ys), 11);
    let mut outputs = Vec::new();
    for (file, format) in [
        (&csv, "csv"),
        (&bcnc, "bcnc"),
        (&csv, "auto"),
        (&bcnc, "auto"),
    ] {
        let options = format!("map = {file:?}\nformat = {format:?}\n");
        let (input, output, diags) = compensate(&src, &options);
        assert!(diags.iter().all(|d| !d.is_error()), "{format}: {diags:?}");
        let stats = check(&input, &output, &surface, 0.001, false, format);
        assert!(
            stats.worst_midpoint <= 0.001 && stats.segments > 100,
            "{stats:?}"
        );
        outputs.push(output);
    }
    // One surface, one output, whatever the file format.
    assert!(outputs.windows(2).all(|w| w[0] == w[1]));
}

#[test]
fn tolerance_splits_inside_cells() {
    // One cell, a saddle (h = 0.4 u v over 10 x 10 mm): the diagonal from corner to
    // corner has h = 0.4 t², deviating from its chord by 0.1 at the middle; at 0.001 it
    // needs ceil(sqrt(0.1 / 0.001)) = 10 equal pieces.
    let dir = tempfile::tempdir().unwrap();
    let map = write_temp(&dir, "saddle.csv", "0,0,0\n10,0,0\n0,10,0\n10,10,0.4\n");
    let (input, output, _) = compensate(
        "G0 X0 Y0 Z0\nG1 X10 Y10 F100\n",
        &format!("map = {map:?}\ntolerance = 0.001\n"),
    );
    let surface = Surface {
        xs: vec![0.0, 10.0],
        ys: vec![0.0, 10.0],
        z: vec![0.0, 0.0, 0.0, 0.4],
    };
    let stats = check(&input, &output, &surface, 0.001, false, "saddle");
    assert_eq!(output.len(), 1 + 10);
    // Equal pieces: the largest midpoint deviation is 0.1 / 100.
    assert!((stats.worst_midpoint - 0.001).abs() < 1e-12, "{stats:?}");
    // A move along an edge of the cell is straight on the surface: not cut.
    let (_, output, _) = compensate(
        "G0 X0 Y0 Z0\nG1 X10 Y0 F100\n",
        &format!("map = {map:?}\ntolerance = 0.001\n"),
    );
    assert_eq!(output.len(), 2);
}

#[test]
fn rapids_and_plunges_are_compensated() {
    let dir = tempfile::tempdir().unwrap();
    let map = write_temp(&dir, "tilt.csv", "0,0,0\n10,0,0.1\n0,10,0\n10,10,0.1\n");
    let (_, output, _) = compensate(
        "G0 X0 Y0 Z1\nG0 X10 Z1\nG1 Z-0.06 F20\n",
        &format!("map = {map:?}\n"),
    );
    let zs: Vec<(MotionKind, [f64; 3])> = output
        .iter()
        .filter_map(|b| match &b.kind {
            BlockKind::Motion(m) => Some((m.kind, xyz(m.target.joints().unwrap()))),
            _ => None,
        })
        .collect();
    assert_eq!(
        zs.len(),
        3,
        "a plane: no splitting, a plunge is shifted not cut"
    );
    assert_eq!(zs[1].0, MotionKind::Rapid);
    assert!((zs[1].1[2] - 1.1).abs() < 1e-12);
    assert!((zs[2].1[2] - 0.04).abs() < 1e-12);
}

fn render_all(file: &str, diags: &[Diagnostic]) -> String {
    diags
        .iter()
        .map(|d| d.render(file, false))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn outside_the_grid_is_an_error_or_clamped() {
    let path = corpus_maps()[0].clone(); // blvcube 3x3: X, Y 20..215
    let src = "G0 X30 Y30 Z1\nG1 X10 Y30 Z-0.1 F100\nG1 X30 Y250\n";
    let (_, _, diags) = compensate(src, &format!("map = {:?}\n", path.to_str().unwrap()));
    let errors: Vec<Diagnostic> = diags.iter().filter(|d| d.is_error()).cloned().collect();
    assert_eq!(errors.len(), 2, "{errors:?}");
    assert!(errors.iter().all(|d| d.code == "heightmap::outside"));
    insta::assert_snapshot!("outside", render_all("job.nc", &errors));

    // Clamped: the edge heights extend outward.
    let map = HeightMap::parse(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let surface = Surface::of(&map);
    let (input, output, diags) = compensate(
        src,
        &format!("map = {:?}\noutside = \"clamp\"\n", path.to_str().unwrap()),
    );
    assert!(diags.iter().all(|d| !d.is_error()), "{diags:?}");
    let stats = check(&input, &output, &surface, 0.001, true, "clamp");
    assert!(stats.segments >= 3);
    // X10 Y30 is the height at X20 Y30.
    let h = surface.at(20.0, 30.0, false).unwrap();
    let z = output
        .iter()
        .find_map(|b| match &b.kind {
            BlockKind::Motion(m) => {
                let p = xyz(m.target.joints().unwrap());
                (p[0] == 10.0 && p[1] == 30.0).then_some(p[2])
            }
            _ => None,
        })
        .unwrap();
    assert!((z - (-0.1 + h)).abs() < 1e-12);
}

#[test]
fn unprobed_points() {
    // RepRapFirmware writes a bare `0` for a point it did not probe.
    let dir = tempfile::tempdir().unwrap();
    let text = "RepRapFirmware height map file v2 generated at 2024-01-01 00:00\nxmin,xmax,ymin,ymax,radius,xspacing,yspacing,xnum,ynum\n0.00,20.00,0.00,20.00,-1.00,10.00,10.00,3,3\n 0.010, 0.020, 0\n 0.000, 0.010, 0.020\n 0.010, 0.020, 0.030\n";
    let map = write_temp(&dir, "heightmap.csv", text);
    let src = "G0 X1 Y1 Z1\nG1 X19 Y1 F100\n";
    let (_, _, diags) = compensate(src, &format!("map = {map:?}\n"));
    assert!(
        diags.iter().any(|d| d.code == "heightmap::unprobed"),
        "{diags:?}"
    );
    let (_, output, diags) = compensate(src, &format!("map = {map:?}\nunprobed = \"nearest\"\n"));
    assert!(diags.iter().all(|d| !d.is_error()), "{diags:?}");
    // X20 Y0 takes 0.020 from X10 Y0 (nearest; X20 Y10 is as near but later in row order).
    let last = output.last().unwrap();
    let BlockKind::Motion(m) = &last.kind else {
        panic!()
    };
    let p = xyz(m.target.joints().unwrap());
    // At X19 Y1: u = 0.9, v = 0.1 over h00 = 0.02, h10 = 0.02, h01 = 0.01, h11 = 0.02.
    let expected = 0.02 * 0.1 * 0.9 + 0.02 * 0.9 * 0.9 + 0.01 * 0.1 * 0.1 + 0.02 * 0.9 * 0.1;
    assert!(
        (p[2] - 1.0 - expected).abs() < 1e-12,
        "{} vs {expected}",
        p[2] - 1.0
    );
}

#[test]
fn arcs_need_linearize_arcs_first() {
    let path = corpus_maps()[0].clone();
    let (_, _, diags) = compensate(
        "G0 X50 Y50 Z0\nG2 X60 Y50 I5 J0 F100\n",
        &format!("map = {:?}\n", path.to_str().unwrap()),
    );
    assert!(
        diags
            .iter()
            .any(|d| d.code == "heightmap::arc" && d.is_error())
    );
}

#[test]
fn probe_programs() {
    for (emit, name) in [(ProbeEmit::Rrf, "rrf"), (ProbeEmit::Grbl, "grbl")] {
        let o = ProbeOptions {
            area: [0.0, 0.0, 20.0, 12.0],
            pitch: 5.0,
            emit,
            safe_z: 2.0,
            depth: -1.0,
            feed: 20.0,
        };
        let text = probe_program(&o).unwrap();
        // 5 x 4 points: X 0..20, Y 0..15 (the last line moved out to cover 12).
        match emit {
            ProbeEmit::Rrf => assert!(text.contains("M557 X0:20 Y0:15 P5:4\nG29 S0\n")),
            ProbeEmit::Grbl => {
                assert_eq!(text.matches("G38.2 Z-1 F20").count(), 20);
                for line in text.lines() {
                    let code = line.split('(').next().unwrap();
                    let (_, removed) =
                        ncpost::back::grbl::split_unsupported(code, &Default::default());
                    assert!(removed.is_empty(), "Grbl lacks `{removed}`");
                    assert!(ncpost::back::grbl::counted_length(line) <= 79);
                }
            }
        }
        insta::assert_snapshot!(format!("probe_program_{name}"), text);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Random moves over the synthetic board at random tolerances.
    #[test]
    fn random_moves_on_the_synthetic_board(
        moves in proptest::collection::vec((0.0..60.0f64, 0.0..40.0f64, -0.3..0.3f64, any::<bool>()), 1..30),
        tol in prop_oneof![Just(0.001), Just(0.0002), Just(0.01)],
    ) {
        let dir = tempfile::tempdir().unwrap();
        let (csv, _) = synthetic_files(&dir);
        let (xs, ys, pts) = synthetic_points();
        let surface = Surface { xs, ys, z: pts.iter().map(|p| p[2]).collect() };
        let mut src = String::from("G0 X30 Y20 Z1\n");
        for (x, y, z, rapid) in &moves {
            let _ = writeln!(src, "{} X{x:.5} Y{y:.5} Z{z:.5} F200", if *rapid { "G0" } else { "G1" });
        }
        let (input, output, diags) = compensate(&src, &format!("map = {csv:?}\ntolerance = {tol}\n"));
        prop_assert!(diags.iter().all(|d| !d.is_error()), "{diags:?}");
        check(&input, &output, &surface, tol, false, &src);
    }
}
