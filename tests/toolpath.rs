//! `ncpost plot --toolpath` (`ncpost::plot::toolpath`): the drawn tip path against the
//! programs it comes from.
//!
//! 1. A hand-written G-code program: cut vertices, arc points on their circle (1e-9 mm),
//!    plunges, lengths, travel, and an insta snapshot of the SVG.
//! 2. Every corpus HPGL board through `pcb-mill`: as many plunges as the printed G-code
//!    has (counted from the text by a reader below) and every cut vertex of the text
//!    drawn.
//! 3. The bundled E-moc X5 job (`examples/emoc_taper_boss.cl`): forward kinematics of the
//!    emitted joints puts every CL point on the drawing within 1e-6 mm, in order.
//! 4. The first layer of a real print through the polar printer: every slicer vertex,
//!    moved to the table centre, on the drawing within 1e-6 mm.
//! 5. A long program: the vertex count stays bounded, corners stay, every kept vertex is
//!    on the programmed path.
//! 6. The command line writes the SVG.

use std::path::Path;

use nalgebra::Point3;
use ncpost::Pipeline;
use ncpost::pipeline::Source;
use ncpost::plot::toolpath::{Frame, MAX_POINTS, ToolpathPlot};
use ncpost::preset::Preset;

/// Runs `src` through `preset` into a toolpath plot.
fn plot(src: &str, source: Source, preset: Preset) -> ToolpathPlot {
    let frame = Frame::for_preset(&preset);
    let mut pipeline = Pipeline::builder()
        .preset(preset)
        .build()
        .expect("pipeline");
    let mut plot = ToolpathPlot::new(frame);
    let summary = pipeline.run_into(source, src.as_bytes(), &mut plot, &mut |_| {});
    assert_eq!(summary.errors, 0);
    plot
}

fn vertices(plot: &ToolpathPlot) -> Vec<Point3<f64>> {
    plot.runs()
        .iter()
        .flat_map(|r| r.points.iter().copied())
        .collect()
}

/// Whether `wanted` appear among `got` in order, each within `tol` (XY and Z).
fn in_order(wanted: &[Point3<f64>], got: &[Point3<f64>], tol: f64) -> Result<(), String> {
    let mut it = got.iter();
    for (k, w) in wanted.iter().enumerate() {
        if !it.any(|g| (g - w).norm() <= tol) {
            return Err(format!("point {k} {w:?} is not drawn (in order)"));
        }
    }
    Ok(())
}

const SQUARE: &str = "; hand-written for tests/toolpath.rs\n\
G21 G90\n\
G0 Z1\n\
G0 X0 Y0\n\
G1 Z-0.1 F20\n\
G1 X10 F70\n\
G3 X20 Y10 I0 J10\n\
G1 Y20\n\
G0 Z1\n\
G0 X0 Y20\n\
G1 Z-0.1 F20\n\
G1 Y10 F70\n\
G0 Z1\n\
M2\n";

#[test]
fn hand_written_program_with_an_arc() {
    let p = plot(SQUARE, Source::Gcode, Preset::default());
    assert_eq!(p.plunges().len(), 2);
    assert_eq!(
        p.plunges()
            .iter()
            .map(|q| (q.x, q.y, q.z))
            .collect::<Vec<_>>(),
        vec![(0.0, 0.0, -0.1), (0.0, 20.0, -0.1)]
    );
    let cuts: Vec<_> = p.runs().iter().filter(|r| !r.travel).collect();
    assert_eq!(cuts.len(), 2);
    // The first cut: plunge, line, quarter circle about (10, 10), line.
    let first = &cuts[0].points;
    assert_eq!(first[0], Point3::new(0.0, 0.0, 1.0));
    assert_eq!(first[1], Point3::new(0.0, 0.0, -0.1));
    assert_eq!(first[2], Point3::new(10.0, 0.0, -0.1));
    let arc: Vec<_> = first[3..first.len() - 1].to_vec();
    assert!(
        arc.len() >= 4,
        "a quarter circle in pieces of 5 deg or less"
    );
    for q in &arc {
        let r = (q.x - 10.0).hypot(q.y - 10.0);
        assert!(
            (r - 10.0).abs() < 1e-9,
            "{q:?} off the circle by {}",
            r - 10.0
        );
        assert!(
            q.x >= 10.0 - 1e-12 && q.y <= 10.0 + 1e-12,
            "{q:?} on the wrong quarter"
        );
    }
    assert_eq!(first.last(), Some(&Point3::new(20.0, 20.0, -0.1)));
    let quarter = std::f64::consts::FRAC_PI_2 * 10.0;
    let chords = {
        let mut l = 0.0;
        for w in first[2..first.len() - 1].windows(2) {
            l += (w[1] - w[0]).norm();
        }
        l
    };
    assert!(
        chords < quarter && quarter - chords < 0.02,
        "arc chords {chords}"
    );
    // Plunges 1.1 + 1.1, lines 10 + 10 + 10, the arc by its chords.
    let expected = 2.2 + 30.0 + chords;
    assert!(
        (p.cut_length() - expected).abs() < 1e-9,
        "{}",
        p.cut_length()
    );
    // Travel: up 1.1, across 28.28..., and up again (the first rapids start unknown).
    let across = 20.0f64.hypot(0.0);
    assert!((p.travel_length() - (1.1 + across + 1.1)).abs() < 1e-9);
    insta::assert_snapshot!("square_svg", p.svg());
}

/// Plunges in printed G-code: feed moves that lower Z (to below zero) without X or Y.
fn plunges_in_text(text: &str) -> usize {
    let mut z: Option<f64> = None;
    let mut count = 0;
    for line in text.lines() {
        let words: Vec<&str> = line
            .split(';')
            .next()
            .unwrap_or("")
            .split_whitespace()
            .collect();
        let is_g1 = words.first().is_some_and(|w| *w == "G1" || *w == "G01");
        let mut new_z = None;
        let mut xy = false;
        for w in &words {
            match w.as_bytes().first() {
                Some(b'Z') => new_z = w[1..].parse::<f64>().ok(),
                Some(b'X' | b'Y') => xy = true,
                _ => {}
            }
        }
        if let Some(nz) = new_z {
            if is_g1 && !xy && z.is_some_and(|old| nz < old) && nz < 0.0 {
                count += 1;
            }
            z = Some(nz);
        }
    }
    count
}

#[test]
fn every_corpus_hpgl_board_plunges_as_its_gcode_does() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/hpgl");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("corpus")
        .map(|e| e.expect("entry").path())
        .collect();
    files.sort();
    assert!(files.len() >= 5);
    for path in files {
        let src = std::fs::read_to_string(&path).expect("read");
        let preset = Preset::builtin("pcb-mill").expect("preset");
        let p = plot(&src, Source::Hpgl, preset.clone());
        let text = {
            let mut pipeline = Pipeline::builder()
                .preset(preset)
                .build()
                .expect("pipeline");
            let mut out = Vec::new();
            pipeline
                .run_source(Source::Hpgl, src.as_bytes(), &mut out, &mut |_| {})
                .expect("run");
            String::from_utf8(out).expect("utf-8")
        };
        // Both counts from a board that does plunge (not two zeros).
        assert!(!p.plunges().is_empty(), "{}", path.display());
        assert_eq!(
            p.plunges().len(),
            plunges_in_text(&text),
            "{}",
            path.display()
        );
        assert!(p.cut_length() > 0.0, "{}", path.display());
        // Every XY vertex of the text is drawn.
        let drawn = vertices(&p);
        let mut pos = [f64::NAN; 2];
        for line in text.lines().filter(|l| l.starts_with("G")) {
            for w in line.split_whitespace() {
                match w.as_bytes()[0] {
                    b'X' => pos[0] = w[1..].parse().expect("x"),
                    b'Y' => pos[1] = w[1..].parse().expect("y"),
                    _ => {}
                }
            }
            if pos.iter().all(|v| v.is_finite()) {
                assert!(
                    drawn
                        .iter()
                        .any(|d| (d.x - pos[0]).abs() < 1e-4 && (d.y - pos[1]).abs() < 1e-4),
                    "{}: {pos:?} not drawn",
                    path.display()
                );
            }
        }
    }
}

#[test]
fn emoc_x5_tip_in_the_part_frame_reproduces_the_cl_points() {
    let src = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/emoc_taper_boss.cl"),
    )
    .expect("example");
    let cl: Vec<Point3<f64>> = src
        .lines()
        .filter_map(|l| l.strip_prefix("GOTO/"))
        .map(|rest| {
            let v: Vec<f64> = rest
                .split(',')
                .take(3)
                .map(|t| t.trim().parse().expect("number"))
                .collect();
            Point3::new(v[0], v[1], v[2])
        })
        .collect();
    assert!(cl.len() > 100);
    let p = plot(
        &src,
        Source::Cl,
        Preset::builtin("emoc-x5").expect("preset"),
    );
    let drawn = vertices(&p);
    assert!(drawn.len() < MAX_POINTS);
    in_order(&cl, &drawn, 1e-6).expect("CL points drawn");
    // The drawing is in the part frame: the boss's wall stays at radius <= 45 mm,
    // while the machine's X and Y (the table turned under the tool) are not the CL's.
    assert!(drawn.iter().all(|q| q.x.hypot(q.y) <= 45.0 + 1e-6));
}

#[test]
fn polar_printer_first_layer_matches_the_slicer_path() {
    let full = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/corpus/gcode/gcodenom_mini_cube_a_prusaslicer.gcode"),
    )
    .expect("corpus");
    // Up to the end of the first layer.
    let first = full.find(";LAYER_CHANGE").expect("first layer");
    let cut = first
        + 1
        + full[first + 1..]
            .find(";LAYER_CHANGE")
            .expect("second layer");
    let src = &full[..cut];
    let mut preset = Preset::builtin("polar-printer").expect("preset");
    for spec in &mut preset.passes {
        if spec.name == "polar-ik" {
            spec.options.insert(
                "center".into(),
                toml::Value::Array(vec![90.0.into(), 90.0.into()]),
            );
        }
    }
    let p = plot(src, Source::Gcode, preset);
    let drawn = vertices(&p);
    // The slicer's vertices (after the first one with X and Y known), moved to the centre.
    let mut pos = [f64::NAN; 2];
    let mut wanted = Vec::new();
    for line in src
        .lines()
        .filter(|l| l.starts_with("G1 ") || l.starts_with("G0 "))
    {
        let mut moved = false;
        for w in line.split(';').next().unwrap_or("").split_whitespace() {
            match w.as_bytes()[0] {
                b'X' => {
                    pos[0] = w[1..].parse().expect("x");
                    moved = true;
                }
                b'Y' => {
                    pos[1] = w[1..].parse().expect("y");
                    moved = true;
                }
                _ => {}
            }
        }
        if moved && pos.iter().all(|v| v.is_finite()) {
            wanted.push([pos[0] - 90.0, pos[1] - 90.0]);
        }
    }
    assert!(wanted.len() > 100);
    let mut it = drawn.iter();
    for (k, w) in wanted.iter().enumerate() {
        assert!(
            it.any(|d| (d.x - w[0]).hypot(d.y - w[1]) < 1e-6),
            "slicer vertex {k} {w:?} not drawn in order"
        );
    }
    assert!(p.cut_length() > 100.0 && p.travel_length() > 0.0);
}

#[test]
fn long_programs_stay_bounded_and_keep_their_corners() {
    // 200 squares of 400 collinear 0.01 mm steps a side: 320,000 moves, more vertices
    // than the plot keeps.
    let mut src = String::from("; generated by tests/toolpath.rs\nG21 G90\nG0 X0 Y0 Z0\n");
    let side = 400;
    for k in 0..200 {
        let z = -0.01 * k as f64;
        src.push_str(&format!("G1 Z{z:.2} F100\n"));
        for i in 1..=side {
            src.push_str(&format!("G1 X{:.2} Y0\n", i as f64 * 0.01));
        }
        for i in 1..=side {
            src.push_str(&format!("G1 X4 Y{:.2}\n", i as f64 * 0.01));
        }
        for i in 1..=side {
            src.push_str(&format!("G1 X{:.2} Y4\n", 4.0 - i as f64 * 0.01));
        }
        for i in 1..=side {
            src.push_str(&format!("G1 X0 Y{:.2}\n", 4.0 - i as f64 * 0.01));
        }
    }
    let p = plot(&src, Source::Gcode, Preset::default());
    let drawn = vertices(&p);
    assert!(drawn.len() <= MAX_POINTS, "{} vertices", drawn.len());
    // The SVG leaves out what a quarter pixel cannot show: the collinear steps.
    let svg = p.svg();
    let drawn_in_svg = svg.matches(',').count();
    assert!(
        drawn_in_svg < 2000,
        "collinear steps were not simplified: {drawn_in_svg}"
    );
    for corner in [[4.0, 0.0], [4.0, 4.0], [0.0, 4.0]] {
        assert!(
            drawn
                .iter()
                .any(|d| (d.x - corner[0]).abs() < 1e-9 && (d.y - corner[1]).abs() < 1e-9),
            "corner {corner:?} lost"
        );
    }
    for d in &drawn {
        let on_edge = [d.x, d.y, 4.0 - d.x, 4.0 - d.y]
            .iter()
            .any(|e| e.abs() < 1e-9);
        assert!(on_edge, "{d:?} is not on the programmed square");
    }
    assert!(
        (p.cut_length() - (200.0 * 16.0 + 1.99)).abs() < 1e-6,
        "{}",
        p.cut_length()
    );
}

#[test]
fn command_line_writes_the_svg() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("board.svg");
    let input =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/hpgl/gcodeplot_star.plt");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_ncpost"))
        .args(["plot", "--toolpath", "--preset", "pcb-mill", "-q", "-o"])
        .arg(&out)
        .arg(&input)
        .status()
        .expect("run");
    assert!(status.success());
    let svg = std::fs::read_to_string(&out).expect("svg written");
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    assert!(svg.contains("plunges (rings)") && svg.contains("<polyline"));
    // --toolpath and --speed are one or the other.
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_ncpost"))
        .args(["plot", "--toolpath", "--speed", "-q"])
        .arg(&input)
        .stderr(std::process::Stdio::null())
        .status()
        .expect("run");
    assert_eq!(status.code(), Some(2));
}
