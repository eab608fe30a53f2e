//! The HPGL frontend (`ncpost::front::hpgl`) end to end with the `pcb-mill` preset.
//!
//! 1. One test per file of `../shared/corpus/hpgl/` (read from there; HPGL has no
//!    comment syntax every reader accepts, so the fixtures are not copied; the origin of
//!    each file is in `../shared/corpus/SOURCES.md`): no errors, the number of plunges
//!    in the G-code equals the number of pen-down strokes counted from the raw HPGL by an
//!    independent reader below, every cut vertex is the HPGL point / 40 (after IP/SC) in
//!    order, every output block passes the IR verifier, and an insta snapshot holds the
//!    head and tail of the output and the warnings.
//! 2. `hpgl2gcode_basic.hpgl` visits the XY points of a peer's expected output
//!    (`../shared/corpus/gcode/hpgl2gcode_basic_expected.gcode`).
//! 3. Semantics on small inputs: drill marks, circles, arcs, tool changes, relative
//!    moves, scaling, polygon mode, options from the preset, `mirror` giving the exact
//!    mirror image of the output.
//! 4. Diagnostics for bad HPGL (plain rendering snapshotted, line and column asserted),
//!    and a property test: no byte soup of HPGL fragments makes the frontend panic.

use std::path::{Path, PathBuf};

use ncpost::diag::Diagnostic;
use ncpost::front::Frontend;
use ncpost::front::hpgl::{Options, Parser, parse_str};
use ncpost::pipeline::{Pipeline, Source};
use ncpost::preset::Preset;
use ncpost::valid::Verifier;
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------

fn corpus(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/hpgl")
        .join(name)
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

/// Runs `src` through `preset` plus `passes` (`name:k=v` specs); the output text and
/// every diagnostic.
fn compile_with(src: &str, preset: Preset, passes: &[&str]) -> (String, Vec<Diagnostic>) {
    let mut b = Pipeline::builder().preset(preset);
    for spec in passes {
        let (name, table) = ncpost::passes::parse_spec(spec).unwrap();
        b = b.pass(&name, table);
    }
    let mut pipeline = b.build().unwrap();
    let mut out = Vec::new();
    let mut diags = Vec::new();
    pipeline
        .run_source(Source::Hpgl, src.as_bytes(), &mut out, &mut |d| {
            diags.push(d)
        })
        .unwrap();
    (String::from_utf8(out).unwrap(), diags)
}

fn pcb() -> Preset {
    Preset::builtin("pcb-mill").unwrap()
}

/// Compiles with the pcb-mill preset and asserts there is no error.
#[track_caller]
fn compile(src: &str) -> String {
    compile_passes(src, &[])
}

#[track_caller]
fn compile_passes(src: &str, passes: &[&str]) -> String {
    let (out, diags) = compile_with(src, pcb(), passes);
    let errors: Vec<String> = diags
        .iter()
        .filter(|d| d.is_error())
        .map(|d| d.to_string())
        .collect();
    assert!(errors.is_empty(), "errors: {errors:#?}");
    out
}

/// Every diagnostic of the frontend alone.
fn front_diags(src: &str) -> Vec<Diagnostic> {
    match parse_str(src, &Options::default()) {
        Ok(p) => p.diagnostics,
        Err(d) => d,
    }
}

fn render_all(file: &str, diags: &[Diagnostic]) -> String {
    diags
        .iter()
        .map(|d| d.render(file, false))
        .collect::<Vec<_>>()
        .join("\n")
}

// ---------------------------------------------------------------------------------------
// A reader of the G-code output: positions, plunges and cut vertices.
// ---------------------------------------------------------------------------------------

#[derive(Debug, Default)]
struct Run {
    /// G1 moves from Z >= 0 to Z < 0.
    plunges: usize,
    /// Plunges deeper than the cut depth (holes).
    holes: usize,
    /// XY after every move that changes X or Y with the tool below Z0, in order.
    cuts: Vec<(f64, f64)>,
    /// XY of every line that names X or Y.
    points: Vec<(f64, f64)>,
    /// Arcs: (clockwise, centre, radius at start, radius at end).
    arcs: Vec<(bool, (f64, f64), f64, f64)>,
    /// Commands other than moves (`M3 S4600`, `T1 M6`, ...), in order.
    commands: Vec<String>,
}

fn word(line: &str, letter: char) -> Option<f64> {
    line.split_whitespace()
        .find(|w| w.starts_with(letter))
        .and_then(|w| w[1..].parse().ok())
}

fn simulate(gcode: &str) -> Run {
    let mut run = Run::default();
    let (mut x, mut y, mut z) = (f64::NAN, f64::NAN, f64::NAN);
    let mut motion = "G0";
    for line in gcode.lines() {
        let line = line.split(';').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        for w in line.split_whitespace() {
            if matches!(w, "G0" | "G1" | "G2" | "G3") {
                motion = match w {
                    "G0" => "G0",
                    "G1" => "G1",
                    "G2" => "G2",
                    _ => "G3",
                };
            }
        }
        let nx = word(line, 'X');
        let ny = word(line, 'Y');
        let nz = word(line, 'Z');
        if nx.is_none() && ny.is_none() && nz.is_none() {
            if !line.starts_with('G') {
                run.commands.push(line.to_string());
            }
            continue;
        }
        let (sx, sy) = (x, y);
        x = nx.unwrap_or(x);
        y = ny.unwrap_or(y);
        if let Some(nz) = nz {
            if motion == "G1" && z >= 0.0 && nz < 0.0 {
                run.plunges += 1;
                if nz < -0.1 {
                    run.holes += 1;
                }
            }
            z = nz;
        }
        if nx.is_some() || ny.is_some() {
            run.points.push((x, y));
            if z < 0.0 {
                run.cuts.push((x, y));
            }
        }
        if motion == "G2" || motion == "G3" {
            let (i, j) = (
                word(line, 'I').unwrap_or(0.0),
                word(line, 'J').unwrap_or(0.0),
            );
            let c = (sx + i, sy + j);
            let r0 = (sx - c.0).hypot(sy - c.1);
            let r1 = (x - c.0).hypot(y - c.1);
            run.arcs.push((motion == "G2", c, r0, r1));
        }
    }
    run
}

// ---------------------------------------------------------------------------------------
// An independent reading of the HPGL: strokes and pen-down vertices.
// ---------------------------------------------------------------------------------------

#[derive(Debug, Default)]
struct Reference {
    /// Pen-down strokes (each becomes one plunge: a cut or a hole).
    strokes: usize,
    /// Strokes that never moved (drill marks).
    marks: usize,
    /// Pen-down points in mm, in order, where the pen moved.
    vertices: Vec<(f64, f64)>,
}

/// Splits HPGL into (mnemonic, numbers), the simple way: two letters, then everything up
/// to the next letter or `;`.
fn commands(src: &str) -> Vec<(String, Vec<f64>)> {
    let b = src.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if !b[i].is_ascii_alphabetic() {
            i += 1;
            continue;
        }
        let name = src[i..i + 2].to_ascii_uppercase();
        i += 2;
        let start = i;
        while i < b.len() && !b[i].is_ascii_alphabetic() && b[i] != b';' {
            i += 1;
        }
        let nums = src[start..i]
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<f64>().unwrap())
            .collect();
        out.push((name, nums));
    }
    out
}

fn reference(src: &str) -> Reference {
    let mut r = Reference::default();
    let (mut x, mut y) = (0.0f64, 0.0f64);
    let mut down = false;
    let mut moved = false;
    let mut abs = true;
    let mut ip: Option<[f64; 4]> = None;
    // plotter = user * f + o
    let mut scale: Option<[f64; 4]> = None;
    let mut sc: Option<Vec<f64>> = None;
    let mut polygon: Option<((f64, f64), bool)> = None;
    let to_mm = |p: (f64, f64)| (p.0 / 40.0, p.1 / 40.0);

    fn lift(
        r: &mut Reference,
        down: &mut bool,
        moved: &mut bool,
        polygon: &mut Option<((f64, f64), bool)>,
        pos: &mut (f64, f64),
    ) {
        if let Some((start, true)) = *polygon
            && *down
            && *pos != start
        {
            r.vertices.push((start.0 / 40.0, start.1 / 40.0));
            *pos = start;
        }
        if *down {
            r.strokes += 1;
            if !*moved {
                r.marks += 1;
            }
        }
        *down = false;
        *moved = false;
    }

    for (name, n) in commands(src) {
        let mut pos = (x, y);
        match name.as_str() {
            "IN" => {
                lift(&mut r, &mut down, &mut moved, &mut polygon, &mut pos);
                abs = true;
                ip = None;
                sc = None;
                scale = None;
                polygon = None;
            }
            "SP" => lift(&mut r, &mut down, &mut moved, &mut polygon, &mut pos),
            "IP" => {
                ip = Some([n[0], n[1], n[2], n[3]]);
            }
            "SC" => sc = Some(n.clone()),
            "PM" => {
                if n.first().copied().unwrap_or(0.0) == 0.0 {
                    polygon = Some((pos, false));
                } else {
                    // Close the subpolygon (pen down), leave the mode.
                    if let Some((start, true)) = polygon
                        && down
                        && pos != start
                    {
                        r.vertices.push(to_mm(start));
                        pos = start;
                    }
                    polygon = None;
                }
            }
            "PU" | "PD" | "PA" | "PR" => {
                if name == "PU" {
                    lift(&mut r, &mut down, &mut moved, &mut polygon, &mut pos);
                }
                if name == "PD" {
                    down = true;
                }
                if name == "PA" {
                    abs = true;
                }
                if name == "PR" {
                    abs = false;
                }
                for p in n.chunks(2) {
                    let q = match (abs, scale) {
                        (true, Some(s)) => (p[0] * s[0] + s[2], p[1] * s[1] + s[3]),
                        (true, None) => (p[0], p[1]),
                        (false, Some(s)) => (pos.0 + p[0] * s[0], pos.1 + p[1] * s[1]),
                        (false, None) => (pos.0 + p[0], pos.1 + p[1]),
                    };
                    if down && q != pos {
                        r.vertices.push(to_mm(q));
                        moved = true;
                        if let Some((_, cut)) = &mut polygon {
                            *cut = true;
                        }
                    }
                    pos = q;
                }
                if name == "PU"
                    && let Some((start, cut)) = &mut polygon
                {
                    *start = pos;
                    *cut = false;
                }
            }
            "AA" => {
                // Only full circles occur in the corpus: the end is the start.
                assert_eq!(n[2].abs() % 360.0, 0.0, "partial AA in the corpus");
                if down {
                    moved = true;
                }
            }
            _ => {}
        }
        if let (Some([p1x, p1y, p2x, p2y]), Some(s)) = (ip, &sc)
            && scale.is_none()
        {
            // SC type 0 (the corpus has no other).
            let fx = (p2x - p1x) / (s[1] - s[0]);
            let fy = (p2y - p1y) / (s[3] - s[2]);
            scale = Some([fx, fy, p1x - s[0] * fx, p1y - s[2] * fy]);
        }
        (x, y) = pos;
    }
    let mut pos = (x, y);
    lift(&mut r, &mut down, &mut moved, &mut polygon, &mut pos);
    r
}

fn dedup(v: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for &p in v {
        if out.last() != Some(&p) {
            out.push(p);
        }
    }
    out
}

// ---------------------------------------------------------------------------------------
// 1. Corpus
// ---------------------------------------------------------------------------------------

fn check_corpus(file: &str) {
    let src = read(&corpus(file));
    let (out, diags) = compile_with(&src, pcb(), &[]);
    let errors: Vec<String> = diags
        .iter()
        .filter(|d| d.is_error())
        .map(|d| d.to_string())
        .collect();
    assert!(errors.is_empty(), "{file}: {errors:#?}");

    // Every block of the frontend passes the verifier.
    let mut parser = Parser::new(src.as_bytes(), pcb().hpgl_input);
    let mut fd = Vec::new();
    let mut verifier = Verifier;
    while let Some(b) = parser.next_block(&mut fd) {
        verifier
            .check(&b)
            .unwrap_or_else(|e| panic!("{file}: {e}: {b:?}"));
    }

    let run = simulate(&out);
    let reference = reference(&src);
    assert!(reference.strokes > 0, "{file}: no strokes");
    assert_eq!(run.plunges, reference.strokes, "{file}: plunges vs strokes");
    assert_eq!(run.holes, reference.marks, "{file}: holes vs drill marks");
    let cuts = dedup(&run.cuts);
    let want = dedup(&reference.vertices);
    assert_eq!(cuts.len(), want.len(), "{file}: cut vertices");
    for (k, (a, b)) in cuts.iter().zip(&want).enumerate() {
        // Printed at 4 decimals.
        assert!(
            (a.0 - b.0).abs() <= 5.001e-5 && (a.1 - b.1).abs() <= 5.001e-5,
            "{file}: vertex {k}: output {a:?}, HPGL/40 {b:?}"
        );
    }
    // Cutting happens at the cut depth only; holes at the drill depth; travel at Z1.
    for line in out.lines() {
        if let Some(z) = word(line, 'Z') {
            assert!([1.0, 0.1, -0.06, -1.55].contains(&z), "{file}: {line}");
        }
    }

    let lines: Vec<&str> = out.lines().collect();
    let head = lines.len().min(80);
    let tail = lines.len().saturating_sub(12).max(head);
    let mut snap = format!(
        "{} lines, {} plunges ({} holes), {} cut vertices, {} arcs\n",
        lines.len(),
        run.plunges,
        run.holes,
        cuts.len(),
        run.arcs.len()
    );
    for d in &diags {
        snap.push_str(&format!("{d}\n"));
    }
    snap.push_str("----\n");
    snap.push_str(&lines[..head].join("\n"));
    if tail > head {
        snap.push_str(&format!("\n... {} lines ...\n", tail - head));
        snap.push_str(&lines[tail..].join("\n"));
    }
    insta::assert_snapshot!(file.replace('.', "_"), snap);
}

#[test]
fn corpus_chiplotle_bird() {
    check_corpus("chiplotle_bird.hpgl");
}

#[test]
fn corpus_chiplotle_foal() {
    check_corpus("chiplotle_foal.hpgl");
}

#[test]
fn corpus_chiplotle_import_test() {
    check_corpus("chiplotle_import_test.hpgl");
}

#[test]
fn corpus_gcodeplot_star() {
    check_corpus("gcodeplot_star.plt");
}

#[test]
fn corpus_gcodeplot_test() {
    check_corpus("gcodeplot_test.hpgl");
}

#[test]
fn corpus_hpgl2gcode_basic() {
    check_corpus("hpgl2gcode_basic.hpgl");
}

#[test]
fn corpus_hpgl2gcode_test() {
    check_corpus("hpgl2gcode_test.hpgl");
}

/// The peer (geoffd123/Hpgl2Gcode) turns `PU; PA 40,80; PD; PA 40,80;` into moves to
/// X1 Y2: the same XY points (here a drilled hole, as the pen never moves).
#[test]
fn hpgl2gcode_basic_matches_the_peer_coordinates() {
    let expected = read(
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/corpus/gcode/hpgl2gcode_basic_expected.gcode"),
    );
    let ours = simulate(&compile(&read(&corpus("hpgl2gcode_basic.hpgl"))));
    let theirs = simulate(&expected);
    assert!(!theirs.points.is_empty());
    assert_eq!(dedup(&ours.points), dedup(&theirs.points));
    assert_eq!(ours.points, [(1.0, 2.0)]);
    assert_eq!(ours.holes, 1);
}

// ---------------------------------------------------------------------------------------
// 3. Semantics
// ---------------------------------------------------------------------------------------

#[test]
fn a_stroke_is_plunge_cut_retract_at_the_seed_values() {
    let out = compile("IN;SP1;PU400,800;PD800,800,800,1200;PU;");
    assert_eq!(
        out,
        "G21 G90\nG0 Z1\nT1 M6\nG0 X10 Y20\nM3 S4600\nG0 Z0.1\nG94\nG1 Z-0.06 F20\n\
         G1 X20 F70\nG1 Y30\nG0 Z1\nM5\nM2\n"
    );
}

#[test]
fn drill_marks_become_holes() {
    // Pen down and up at one point (also with a zero-length move), then a real stroke.
    let out = compile("PU400,400;PD;PU;PA800,400;PD800,400;PU;PD1200,400;PU;");
    let run = simulate(&out);
    assert_eq!(run.plunges, 3);
    assert_eq!(run.holes, 2);
    assert!(out.contains("G0 X10 Y10\nM3 S4600\nG0 Z0.1\nG94\nG1 Z-1.55 F20\nG0 Z1\n"));
    assert!(out.contains("G0 X20\nG0 Z0.1\nG1 Z-1.55\nG0 Z1\n"));
    assert_eq!(dedup(&run.cuts), [(30.0, 10.0)]);
}

/// The seed's two path bugs (2006-11-20 and -21), as far as they concern the
/// frontend: a figure that starts at the X where the previous one ended is cut, not
/// travelled; the last figure is cut even without a final `PU`.
#[test]
fn seed_bugs_the_same_x_figure_and_the_last_figure_are_cut() {
    // The seed's figure ends at X21.336 Y16.3068 and the next starts at X21.8186: here
    // both at X 10 mm, as in the bug.
    let run = simulate(&compile(
        "PU0,0;PD400,400;PU;PU400,800;PD400,1200;PU;PU0,0;PD0,400",
    ));
    assert_eq!(run.plunges, 3);
    assert_eq!(run.cuts, [(10.0, 10.0), (10.0, 30.0), (0.0, 10.0)]);
    // The program still ends lifted, with the spindle off.
    let out = compile("PU0,0;PD0,400");
    assert!(out.ends_with("G1 Y10 F70\nG0 Z1\nM5\nM2\n"), "{out}");
}

#[test]
fn pen_up_moves_merge_into_one_travel() {
    let run = simulate(&compile("PU0,0,400,0,400,400;PU800,800;PD0,800;PU;"));
    assert_eq!(run.points.first(), Some(&(20.0, 20.0)));
}

#[test]
fn relative_moves_and_several_pairs() {
    let run = simulate(&compile("PA400,400;PR;PD400,0,0,400,-400,0,0,-400;PU;"));
    assert_eq!(
        run.cuts,
        [(20.0, 10.0), (20.0, 20.0), (10.0, 20.0), (10.0, 10.0)]
    );
    assert_eq!(run.plunges, 1);
}

#[test]
fn circles_are_cut_as_full_arcs_and_return_to_the_centre() {
    let out = compile("PU400,400;CI200;PU800,400;");
    let run = simulate(&out);
    assert_eq!(run.plunges, 1);
    assert!(out.contains("G0 X15 Y10\n"), "{out}");
    assert_eq!(run.arcs.len(), 1);
    let (cw, c, r0, r1) = run.arcs[0];
    assert!(!cw);
    assert_eq!(c, (10.0, 10.0));
    assert!((r0 - 5.0).abs() < 1e-9 && (r1 - 5.0).abs() < 1e-9);
    // Negative radius: starts at 180 degrees.
    let out = compile("PU400,400;CI-200;");
    assert!(out.contains("G0 X5 Y10\n"), "{out}");
    assert!(out.contains("G3 X5 Y10 I5 J0"), "{out}");
}

#[test]
fn arcs_with_the_pen_down_cut_and_with_it_up_travel() {
    // Quarter turn counter-clockwise about (0,0) from (400,0) to (0,400), then clockwise
    // back.
    let out = compile("PU400,0;PD;AA0,0,90;AR0,-400,-90;PU;AA0,0,90;");
    let run = simulate(&out);
    assert_eq!(run.arcs.len(), 2);
    assert!(!run.arcs[0].0 && run.arcs[1].0);
    for (_, c, r0, r1) in &run.arcs {
        assert_eq!(*c, (0.0, 0.0));
        assert!((r0 - 10.0).abs() < 1e-4 && (r1 - 10.0).abs() < 1e-4);
    }
    assert_eq!(dedup(&run.cuts), [(0.0, 10.0), (10.0, 0.0)]);
    // The pen-up arc is a travel to its end.
    assert_eq!(run.points.last(), Some(&(0.0, 10.0)));
}

#[test]
fn pens_are_tools_and_the_spindle_follows() {
    let run = simulate(&compile(
        "SP1;PD0,0,40,0;PU;SP1;PD80,0;PU;SP2;PU400,0;PD;PU;SP0;",
    ));
    assert_eq!(
        run.commands,
        ["T1 M6", "M3 S4600", "M5", "T2 M6", "M3 S4600", "M5", "M2"]
    );
    assert_eq!(run.plunges, 3);
}

#[test]
fn scaling_maps_user_units_onto_p1_p2() {
    // Type 0: 0..100 onto 0..4000 plotter units (0..100 mm).
    let run = simulate(&compile(
        "IP0,0,4000,4000;SC0,100,0,100;PU10,10;PD20,10;PU;",
    ));
    assert_eq!(run.cuts, [(20.0, 10.0)]);
    // Type 2: point factor 2 plotter units per user unit, user 0 at P1 = 400.
    let run = simulate(&compile("IP400,400,800,800;SC0,2,0,2,2;PU0,0;PD20,0;PU;"));
    assert_eq!(run.points, [(10.0, 10.0), (11.0, 10.0)]);
    // Type 1 (isotropic): X 0..100 and Y 0..50 onto 4000 x 4000: factor 40 on both,
    // Y centred (50 % left/bottom): user y 0 at 1000.
    let run = simulate(&compile(
        "IP0,0,4000,4000;SC0,100,0,50,1;PU0,0;PD100,50;PU;",
    ));
    assert_eq!(run.points, [(0.0, 25.0), (100.0, 75.0)]);
    // Relative moves scale without the offset.
    let run = simulate(&compile(
        "IP0,0,4000,4000;SC0,100,0,100;PU10,10;PR;PD10,0;PU;",
    ));
    assert_eq!(run.cuts, [(20.0, 10.0)]);
    // SC without IP is not applied, with a warning.
    let d = front_diags("SC0,100,0,100;PU40,40;");
    assert_eq!(d[0].code, "hpgl::scale-without-ip");
}

#[test]
fn polygon_mode_cuts_each_edge_once_and_closes() {
    let src = "PA0,0;PM0;PD400,0,400,400;PU;PM2;EP;FP;";
    let run = simulate(&compile(src));
    assert_eq!(run.cuts, [(10.0, 0.0), (10.0, 10.0), (0.0, 0.0)]);
    assert_eq!(run.plunges, 1);
    assert_eq!(reference(src).vertices, run.cuts);
}

#[test]
fn labels_and_other_commands_become_comments() {
    let (out, diags) = compile_with("LBHello;world\u{3}CO\"note\";RO90;PU0,0;", pcb(), &[]);
    assert!(out.contains("HPGL label: Hello;world"), "{out}");
    assert!(out.contains("note"), "{out}");
    assert!(out.contains("HPGL RO90"), "{out}");
    let codes: Vec<&str> = diags.iter().map(|d| d.code).collect();
    assert_eq!(codes, ["hpgl::label", "hpgl::ignored"]);
}

#[test]
fn options_come_from_the_preset() {
    let mut p = pcb();
    p.hpgl_input.cut_depth = 0.1;
    p.hpgl_input.cut_feed = 120.0;
    p.hpgl_input.spindle_rpm = 0.0;
    p.hpgl_input.tool_change = String::new();
    p.hpgl_input.units_per_mm = 1016.0 / 25.4;
    let (out, d) = compile_with("SP3;PU0,0;PD1016,0;PU;", p.clone(), &[]);
    assert!(d.is_empty(), "{d:?}");
    assert!(out.contains("G1 Z-0.1 F20\nG1 X25.4 F120\n"), "{out}");
    assert!(!out.contains("M3") && !out.contains("T3"), "{out}");
    assert!(out.contains(";pen 3"), "{out}");
    // Bad options are an error before anything is read.
    p.hpgl_input.approach_z = 5.0;
    let (_, d) = compile_with("PU0,0;", p, &[]);
    assert_eq!(d[0].code, "hpgl::options");
    assert!(d[0].is_error());
    // Unknown keys in the preset are refused.
    assert!(Preset::from_toml("[hpgl_input]\ncut_deep = 1\n").is_err());
}

/// `mirror` (no options: buffered, shifted by the largest X of the program) turns the
/// output into its exact mirror image: every printed point (x, y) becomes (maxX - x, y)
/// and every arc turns the other way about the mirrored centre.
#[test]
fn mirrored_output_is_the_exact_mirror_image() {
    for file in [
        "hpgl2gcode_test.hpgl",
        "chiplotle_foal.hpgl",
        "gcodeplot_star.plt",
    ] {
        let src = read(&corpus(file));
        let plain = simulate(&compile(&src));
        let mirrored = simulate(&compile_passes(&src, &["mirror"]));
        // The largest X the tool reaches: points, and full circles' right-hand sides
        // (the corpus arcs are full circles).
        let max_x = plain
            .points
            .iter()
            .map(|p| p.0)
            .chain(plain.arcs.iter().map(|a| a.1.0 + a.2))
            .fold(f64::NEG_INFINITY, f64::max);
        assert_eq!(plain.points.len(), mirrored.points.len(), "{file}");
        for (a, b) in plain.points.iter().zip(&mirrored.points) {
            assert!(
                ((max_x - a.0) - b.0).abs() < 1e-9 && a.1 == b.1,
                "{file}: {a:?} mirrored to {b:?} (max X {max_x})"
            );
        }
        assert_eq!(plain.plunges, mirrored.plunges);
        assert_eq!(plain.arcs.len(), mirrored.arcs.len());
        for (a, b) in plain.arcs.iter().zip(&mirrored.arcs) {
            assert_eq!(a.0, !b.0, "{file}: arc direction");
            assert!(((max_x - a.1.0) - b.1.0).abs() < 1e-9 && a.1.1 == b.1.1);
        }
        // The board stays in positive X.
        assert!(mirrored.points.iter().all(|p| p.0 >= 0.0), "{file}");
    }
}

// ---------------------------------------------------------------------------------------
// 4. Diagnostics
// ---------------------------------------------------------------------------------------

#[test]
fn bad_hpgl_diagnostics() {
    let src = "IN;SP1;\nPA 10,20,30;\nPD1,,2;PU 4.5.6,7;\nQ;PA1e3,4;\n\u{7}\u{7}PU;SP-1;\nCI;AA1,2;IP1,2,3;\nPA\"x\",1;";
    let d = front_diags(src);
    let at: Vec<(&str, u32, u32)> = d
        .iter()
        .map(|d| {
            let l = d.location.as_ref().unwrap();
            (d.code, l.line, l.column)
        })
        .collect();
    assert_eq!(
        at,
        [
            ("hpgl::odd-coordinates", 2, 10),
            ("hpgl::bad-parameter", 3, 5),
            ("hpgl::bad-parameter", 3, 11),
            ("hpgl::mnemonic", 4, 1),
            // `e` ends `PA1` (odd) and is a one-letter command.
            ("hpgl::odd-coordinates", 4, 5),
            ("hpgl::mnemonic", 4, 6),
            ("hpgl::unexpected", 5, 1),
            ("hpgl::pen", 5, 8),
            ("hpgl::parameters", 6, 1),
            ("hpgl::parameters", 6, 4),
            ("hpgl::parameters", 6, 10),
            ("hpgl::bad-parameter", 7, 3),
        ]
    );
    assert!(d.iter().all(Diagnostic::is_error));
    insta::assert_snapshot!("bad_hpgl", render_all("bad.hpgl", &d));
}

#[test]
fn empty_input_and_long_lines() {
    let d = front_diags("");
    assert_eq!(d[0].code, "hpgl::empty");
    // A bad number far into a one-line file: the column is exact, the snippet cut.
    let mut src = "PD1,1;".repeat(2000);
    src.push_str("PD1,2.3.4;");
    let d = front_diags(&format!("PU0,0;{src}"));
    let l = d[0].location.as_ref().unwrap();
    assert_eq!((l.line, l.column), (1, 6 + 12000 + 5));
    assert!(l.source_line.len() <= 160);
    insta::assert_snapshot!("long_line", render_all("long.plt", &d));
}

#[test]
fn too_long_commands_are_skipped() {
    let o = Options {
        max_command_len: 64,
        ..Options::default()
    };
    let src = format!("PU0,0;PD{};PD40,0;PU;", "1,1,".repeat(40) + "1,1");
    let err = parse_str(&src, &o).unwrap_err();
    assert_eq!(err[0].code, "hpgl::too-long");
    assert_eq!(err.len(), 1);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn no_input_panics(parts in proptest::collection::vec(
        prop_oneof![
            Just("PU".to_string()), Just("PD".to_string()), Just("PA".to_string()),
            Just("PR".to_string()), Just("CI".to_string()), Just("AA".to_string()),
            Just("AR".to_string()), Just("SP".to_string()), Just("SC".to_string()),
            Just("IP".to_string()), Just("PM".to_string()), Just("LB".to_string()),
            Just("DT".to_string()), Just("IN".to_string()), Just(";".to_string()),
            Just(",".to_string()), Just("\n".to_string()), Just("\"".to_string()),
            Just("\u{3}".to_string()), Just("-".to_string()), Just(".".to_string()),
            (-5000i32..5000).prop_map(|v| v.to_string()),
            "[ -~]{0,3}",
        ],
        0..60,
    )) {
        let src = parts.concat();
        let mut parser = Parser::new(src.as_bytes(), Options::default());
        let mut diags = Vec::new();
        let mut verifier = Verifier;
        while let Some(b) = parser.next_block(&mut diags) {
            prop_assert!(verifier.check(&b).is_ok(), "{:?}", b);
        }
        for d in &diags {
            prop_assert!(d.location.is_some() || d.code == "hpgl::empty", "{}", d);
        }
    }
}
