//! The `transform` and `mirror` passes.
//!
//! 1. Properties over random programs of lines and XY arcs: `transform` followed by its
//!    inverse gives back every coordinate and arc centre within 1e-9 mm; arcs stay arcs
//!    of the same direction with the radius times |scale| and their end points on the
//!    transformed circle; rotation keeps distances; `mirror` with a given shift twice
//!    is the identity, and once keeps radii and turns every arc the other way.
//! 2. Exact cases: quarter turns map grid points onto grid points, G92 offsets follow
//!    the points, errors (G18 arcs under rotation, unknown X, bad options) and warnings.
//! 3. Before/after snapshots on a small real PCB milling file
//!    (`../shared/corpus/gcode/printrun_pcb_milling_comment.gcode`, kliment/Printrun,
//!    GPL-3.0, read from the corpus).

mod common;

use std::path::Path;

use nalgebra::Vector3;
use ncpost::back::gcode;
use ncpost::diag::Diagnostic;
use ncpost::front::gcode::{Options as GOptions, parse_str};
use ncpost::ir::{
    Arc, Axis, AxisSet, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind, Plane, Span,
    Target,
};
use ncpost::passes::{self, Context};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------

/// Runs `blocks` through the passes given as `name:k=v` specs.
fn run(blocks: Vec<Block>, specs: &[&str]) -> (Vec<Block>, Vec<Diagnostic>) {
    common::run_passes(blocks, specs)
}

fn span(line: u32) -> Span {
    Span {
        offset: 0,
        len: 1,
        line,
    }
}

fn xyz(x: f64, y: f64, z: f64) -> Joints {
    let mut j = Joints::default();
    j.set(Axis::X, x);
    j.set(Axis::Y, y);
    j.set(Axis::Z, z);
    j
}

fn motion(line: u32, kind: MotionKind, to: Joints) -> Block {
    Block::new(
        span(line),
        BlockKind::Motion(Motion {
            kind,
            target: Target::Joints(to),
            feed: Feed {
                mode: FeedMode::PerMinute,
                rate: Some(100.0),
            },
            written: AxisSet::XYZ,
            machine_frame: false,
            extra: String::new(),
        }),
    )
}

/// A move in a generated program.
#[derive(Debug, Clone)]
enum Step {
    Line(f64, f64, f64),
    /// Arc from the current point: centre offset angle, radius, sweep (rad), clockwise.
    Arc {
        phase: f64,
        radius: f64,
        sweep: f64,
        cw: bool,
        z: f64,
    },
}

fn steps() -> impl Strategy<Value = Vec<Step>> {
    let line = (-200.0..200.0f64, -200.0..200.0f64, -5.0..5.0f64)
        .prop_map(|(x, y, z)| Step::Line(x, y, z));
    let arc = (
        0.0..std::f64::consts::TAU,
        0.1..80.0f64,
        0.05..6.2f64,
        any::<bool>(),
        -5.0..5.0f64,
    )
        .prop_map(|(phase, radius, sweep, cw, z)| Step::Arc {
            phase,
            radius,
            sweep,
            cw,
            z,
        });
    proptest::collection::vec(prop_oneof![line, arc], 1..20)
}

/// The blocks of a generated program, starting with a rapid to (1, 2, 3).
fn program(steps: &[Step]) -> Vec<Block> {
    let mut blocks = vec![motion(1, MotionKind::Rapid, xyz(1.0, 2.0, 3.0))];
    let mut pos = (1.0, 2.0);
    for (k, s) in steps.iter().enumerate() {
        let line = k as u32 + 2;
        match *s {
            Step::Line(x, y, z) => {
                blocks.push(motion(line, MotionKind::Linear, xyz(x, y, z)));
                pos = (x, y);
            }
            Step::Arc {
                phase,
                radius,
                sweep,
                cw,
                z,
            } => {
                // Centre at `radius` from the current point; end after `sweep`.
                let c = (pos.0 - radius * phase.cos(), pos.1 - radius * phase.sin());
                let a = if cw { phase - sweep } else { phase + sweep };
                let end = (c.0 + radius * a.cos(), c.1 + radius * a.sin());
                let arc = Arc {
                    clockwise: cw,
                    plane: Plane::XY,
                    center: Vector3::new(c.0, c.1, 0.0),
                    extra_turns: 0,
                };
                blocks.push(motion(line, MotionKind::Arc(arc), xyz(end.0, end.1, z)));
                pos = end;
            }
        }
    }
    blocks
}

fn target(b: &Block) -> (Joints, MotionKind) {
    match &b.kind {
        BlockKind::Motion(m) => (*m.target.joints().unwrap(), m.kind),
        k => panic!("not a motion: {k:?}"),
    }
}

/// (start, end, centre, clockwise) of every arc, with its start from the previous block.
type ArcEnds = ((f64, f64), (f64, f64), (f64, f64), bool);

fn arcs(blocks: &[Block]) -> Vec<ArcEnds> {
    let mut out = Vec::new();
    let mut pos = (f64::NAN, f64::NAN);
    for b in blocks {
        let (j, kind) = target(b);
        let end = (j.values[0], j.values[1]);
        if let MotionKind::Arc(a) = kind {
            out.push((pos, end, (a.center[0], a.center[1]), a.clockwise));
        }
        pos = end;
    }
    out
}

fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.0 - b.0).hypot(a.1 - b.1)
}

fn gcode_text(src: &str, specs: &[&str]) -> (String, Vec<Diagnostic>) {
    let p = parse_str(src, &GOptions::default()).unwrap();
    let (blocks, diags) = run(p.blocks, specs);
    (
        gcode::write_string(&blocks, &Default::default()).unwrap(),
        diags,
    )
}

// ---------------------------------------------------------------------------------------
// 1. Properties
// ---------------------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn transform_then_inverse_is_the_identity(
        steps in steps(),
        rotate in -720.0..720.0f64,
        scale in prop_oneof![0.05..20.0f64, -20.0..-0.05f64],
        ox in -100.0..100.0f64, oy in -100.0..100.0f64,
        tx in -100.0..100.0f64, ty in -100.0..100.0f64, tz in -10.0..10.0f64,
    ) {
        let blocks = program(&steps);
        let fwd = format!(
            "transform:rotate={rotate},scale={scale},origin_x={ox},origin_y={oy},dx={tx},dy={ty},dz={tz}"
        );
        // Inverse: undo the translation, then the rotation and scale about the origin.
        let back_t = format!("transform:dx={},dy={},dz={}", -tx, -ty, -tz);
        let back_r = format!(
            "transform:rotate={},scale={},origin_x={ox},origin_y={oy}",
            -rotate,
            1.0 / scale
        );
        let (out, diags) = run(blocks.clone(), &[&fwd, &back_t, &back_r]);
        prop_assert!(diags.is_empty(), "{:?}", diags);
        prop_assert_eq!(out.len(), blocks.len());
        for (a, b) in blocks.iter().zip(&out) {
            let ((ja, ka), (jb, kb)) = (target(a), target(b));
            for i in 0..3 {
                prop_assert!((ja.values[i] - jb.values[i]).abs() < 1e-9,
                    "axis {}: {} vs {}", i, ja.values[i], jb.values[i]);
            }
            match (ka, kb) {
                (MotionKind::Arc(x), MotionKind::Arc(y)) => {
                    prop_assert_eq!(x.clockwise, y.clockwise);
                    prop_assert!((x.center - y.center).norm() < 1e-9);
                }
                (x, y) => prop_assert_eq!(x, y),
            }
        }
    }

    #[test]
    fn arcs_stay_arcs_with_the_scaled_radius(
        steps in steps(),
        rotate in -360.0..360.0f64,
        scale in prop_oneof![0.05..20.0f64, -20.0..-0.05f64],
        tx in -100.0..100.0f64, ty in -100.0..100.0f64,
    ) {
        let blocks = program(&steps);
        let spec = format!("transform:rotate={rotate},scale={scale},dx={tx},dy={ty}");
        let (out, _) = run(blocks.clone(), &[&spec]);
        let (before, after) = (arcs(&blocks), arcs(&out));
        prop_assert_eq!(before.len(), after.len());
        for (b, a) in before.iter().zip(&after) {
            // The same direction (a uniform scale, negative or not, is a similarity
            // without reflection).
            prop_assert_eq!(b.3, a.3);
            let r = dist(b.0, b.2) * scale.abs();
            let tol = 1e-9 * (1.0 + r + dist(b.2, (0.0, 0.0)) * scale.abs());
            prop_assert!((dist(a.0, a.2) - r).abs() < tol, "start radius");
            prop_assert!((dist(a.1, a.2) - r).abs() < tol, "end radius");
        }
        // Distances between consecutive points scale by |scale|.
        for w in blocks.windows(2).zip(out.windows(2)) {
            let (p, q) = (target(&w.0[0]).0, target(&w.0[1]).0);
            let (p2, q2) = (target(&w.1[0]).0, target(&w.1[1]).0);
            let d = dist((p.values[0], p.values[1]), (q.values[0], q.values[1]));
            let d2 = dist((p2.values[0], p2.values[1]), (q2.values[0], q2.values[1]));
            prop_assert!((d2 - d * scale.abs()).abs() < 1e-9 * (1.0 + d2));
        }
    }

    #[test]
    fn mirror_twice_is_the_identity_and_once_turns_arcs(
        steps in steps(), shift in -300.0..300.0f64, y_axis in any::<bool>(),
    ) {
        let blocks = program(&steps);
        let axis = if y_axis { "y" } else { "x" };
        let spec = format!("mirror:axis={axis},shift={shift}");
        let (once, _) = run(blocks.clone(), &[&spec]);
        let (twice, _) = run(blocks.clone(), &[&spec, &spec]);
        let i = usize::from(y_axis);
        for ((a, m), t) in blocks.iter().zip(&once).zip(&twice) {
            let ((ja, _), (jm, _), (jt, _)) = (target(a), target(m), target(t));
            prop_assert!((jm.values[i] - (shift - ja.values[i])).abs() < 1e-9);
            prop_assert_eq!(jm.values[1 - i], ja.values[1 - i]);
            for k in 0..3 {
                prop_assert!((jt.values[k] - ja.values[k]).abs() < 1e-9);
            }
        }
        for (b, a) in arcs(&blocks).iter().zip(&arcs(&once)) {
            prop_assert_eq!(b.3, !a.3);
            prop_assert!((dist(b.0, b.2) - dist(a.0, a.2)).abs() < 1e-9);
            prop_assert!((dist(b.1, b.2) - dist(a.1, a.2)).abs() < 1e-9);
        }
    }
}

// ---------------------------------------------------------------------------------------
// 2. Exact cases, errors
// ---------------------------------------------------------------------------------------

#[test]
fn quarter_turns_are_exact() {
    let (text, d) = gcode_text(
        "G0 X10 Y0 Z1\nG1 X10 Y5\nG2 X15 Y10 I5 J0\n",
        &["transform:rotate=90,origin_x=10,dx=1,dz=-1"],
    );
    assert!(d.is_empty(), "{d:?}");
    // (10,0) fixed, (10,5) -> (5,0), (15,10) -> (0,5), centre (15,5) -> (5,5); +1 in X.
    assert_eq!(
        text,
        "G21 G90\nG0 X11 Y0 Z0\nG94\nG1 X6\nG17\nG2 X1 Y5 I0 J5\n"
    );
}

#[test]
fn g92_offsets_follow_the_points() {
    // Printed coordinates are IR + offset: after the transform the printed program is
    // the transformed program.
    let src = "G0 X0 Y0\nG92 X10 Y0\nG1 X20 Y0 F100\n";
    let (text, d) = gcode_text(src, &["transform:rotate=90"]);
    assert!(d.is_empty(), "{d:?}");
    assert_eq!(text, "G21 G90\nG0 X0 Y0\nG92 X0 Y10\nG94\nG1 Y20 F100\n");
}

#[test]
fn errors_and_warnings() {
    let (_, d) = gcode_text(
        "G0 X0 Y0 Z0\nG18 G2 X10 Z0 I5 K0\n",
        &["transform:rotate=30"],
    );
    assert_eq!(d[0].code, "transform::arc-plane");
    assert_eq!(d[0].location.as_ref().unwrap().line, 2);
    // A pure translation moves a G18 arc.
    let (text, d) = gcode_text(
        "G0 X0 Y0 Z0\nG18 G2 X10 Z0 I5 K0\n",
        &["transform:dx=1,dy=2,dz=3"],
    );
    assert!(d.is_empty(), "{d:?}");
    assert!(text.contains("G2 X11 Z3 I5 K0"), "{text}");
    // X known, Y not: cannot rotate.
    let (_, d) = gcode_text("G0 X1\n", &["transform:rotate=45"]);
    assert_eq!(d[0].code, "transform::unknown-axis");
    // But it can be translated.
    let (text, d) = gcode_text("G0 X1\n", &["transform:dx=2"]);
    assert!(d.is_empty() && text.contains("G0 X3"), "{text}");
    // Commands with coordinates pass unchanged, with one warning.
    let (_, d) = gcode_text("G28 X0\nG28 X0\n", &["transform:dx=1"]);
    assert_eq!(d.len(), 1);
    assert_eq!(d[0].code, "transform::untransformed");
    let (_, d) = gcode_text("G28 X0\n", &["mirror:shift=5"]);
    assert_eq!(d[0].code, "mirror::unmirrored");
    // Bad options.
    let ctx = Context::default();
    for bad in [
        "scale = 0.0",
        "rotate = nan",
        "bogus = 1",
        "translate = 1.0",
    ] {
        let t: toml::Table = toml::from_str(bad).unwrap();
        assert!(passes::build("transform", &t, &ctx).is_err(), "{bad}");
    }
    for bad in ["axis = \"z\"", "shift = inf", "bogus = 1"] {
        let t: toml::Table = toml::from_str(bad).unwrap();
        assert!(passes::build("mirror", &t, &ctx).is_err(), "{bad}");
    }
}

// ---------------------------------------------------------------------------------------
// 3. Snapshots
// ---------------------------------------------------------------------------------------

fn pcb_file() -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/gcode/printrun_pcb_milling_comment.gcode");
    std::fs::read_to_string(p).unwrap()
}

#[test]
fn snapshot_transform_pcb_file() {
    let src = pcb_file();
    let (before, _) = gcode_text(&src, &[]);
    let (after, d) = gcode_text(
        &src,
        &["transform:rotate=90,origin_x=10,origin_y=10,scale=2,dx=5"],
    );
    assert!(d.is_empty(), "{d:?}");
    insta::assert_snapshot!(
        "transform_pcb",
        format!("--- before\n{before}--- after rotate=90 origin=(10,10) scale=2 dx=5\n{after}")
    );
}

#[test]
fn snapshot_mirror_pcb_file() {
    let src = pcb_file();
    let (before, _) = gcode_text(&src, &[]);
    let (after, d) = gcode_text(&src, &["mirror"]);
    assert_eq!(d.len(), 1);
    // The shift is the largest X of the file (it has no arcs).
    let max_x = src
        .lines()
        .flat_map(|l| l.split_whitespace())
        .filter_map(|w| w.strip_prefix('X')?.parse::<f64>().ok())
        .fold(f64::NEG_INFINITY, f64::max);
    assert_eq!(max_x, 17.0544);
    assert!(d[0].message.contains("shift 17.0544,"), "{}", d[0].message);
    insta::assert_snapshot!(
        "mirror_pcb",
        format!(
            "--- before\n{before}--- after mirror ({})\n{after}",
            d[0].message
        )
    );
}
