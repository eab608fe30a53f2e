//! The APT CL frontend (`ncpost::front::cl`).
//!
//! 1. One test per file of `../shared/corpus/cl/`: it parses without errors, the IR
//!    verifier accepts every block, counts of motions, arc pieces and commands match
//!    the file, and an insta snapshot holds the diagnostics and the IR dump of its first
//!    60 blocks.
//! 2. Statement tests on small inputs: feeds, units, RAPID, MULTAX/TLAXIS, `$`
//!    continuation spans, arcs checked geometrically (every point on the circle, every
//!    chord within the tolerance), GODLTA, drilling cycles, the triplet format.
//! 3. Diagnostics: fixtures in `tests/fixtures/cl/` with bad and doubtful statements,
//!    rendered plain and snapshotted, with line and column asserted for each.
//! 4. Properties: no byte string and no soup of CL fragments makes the frontend panic.

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{Point3, Vector3};
use ncpost::diag::{Diagnostic, Severity};
use ncpost::front::Frontend;
use ncpost::front::cl::{Options, Parser, Program, Units, parse_str};
use ncpost::ir::{Block, BlockKind, FeedMode, Motion, MotionKind, Pose, Span, Target, dump};
use ncpost::valid::Verifier;
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------

fn corpus_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/cl")
}

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cl")
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

/// Parses `src`, asserting there is no error.
#[track_caller]
fn ok(src: &str) -> Program {
    ok_with(src, &Options::default())
}

#[track_caller]
fn ok_with(src: &str, options: &Options) -> Program {
    match parse_str(src, options) {
        Ok(p) => p,
        Err(d) => panic!(
            "unexpected errors:\n{}",
            d.iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join("\n")
        ),
    }
}

/// Parses `src`, asserting there is an error; returns every diagnostic.
#[track_caller]
fn errors(src: &str) -> Vec<Diagnostic> {
    match parse_str(src, &Options::default()) {
        Ok(p) => panic!("expected errors, got blocks {:?}", p.blocks),
        Err(d) => d,
    }
}

fn motion(b: &Block) -> Option<&Motion> {
    match &b.kind {
        BlockKind::Motion(m) => Some(m),
        _ => None,
    }
}

fn pose(m: &Motion) -> &Pose {
    match &m.target {
        Target::Pose(p) => p,
        Target::Joints(_) => panic!("a CL motion has a joint target"),
    }
}

fn motions(p: &Program) -> Vec<&Motion> {
    p.blocks.iter().filter_map(motion).collect()
}

fn tips(p: &Program) -> Vec<Point3<f64>> {
    motions(p).iter().map(|m| pose(m).tip).collect()
}

fn commands(p: &Program) -> Vec<&str> {
    p.blocks
        .iter()
        .filter_map(|b| match &b.kind {
            BlockKind::Command(c) => Some(c.text.as_str()),
            _ => None,
        })
        .collect()
}

#[track_caller]
fn close(a: Point3<f64>, b: Point3<f64>, tol: f64) {
    assert!((a - b).norm() <= tol, "{a:?} is not within {tol} of {b:?}");
}

fn dump_blocks(blocks: &[Block]) -> String {
    let mut s = String::new();
    for b in blocks {
        dump::write_block(&mut s, b);
        s.push('\n');
    }
    s
}

/// Asserts severity, code, line and column of `d`.
#[track_caller]
fn expect(d: &Diagnostic, severity: Severity, code: &str, line: u32, column: u32) {
    assert_eq!(d.severity, severity, "severity of {d}");
    assert_eq!(d.code, code, "code of {d}");
    let loc = d
        .location
        .as_ref()
        .unwrap_or_else(|| panic!("no location: {d}"));
    assert_eq!((loc.line, loc.column), (line, column), "line:column of {d}");
}

fn render_all(file: &str, diags: &[Diagnostic]) -> String {
    diags
        .iter()
        .map(|d| d.render(file, false))
        .collect::<Vec<_>>()
        .join("\n")
}

// ---------------------------------------------------------------------------------------
// Part 1: the corpus
// ---------------------------------------------------------------------------------------

/// What a corpus file must give.
struct Expect {
    /// Rapid and linear motions.
    rapid: usize,
    linear: usize,
    /// CIRCLE statements, all lowered to arcs.
    arcs: usize,
    /// Motions of the GOTOs that end arcs.
    arc_pieces: usize,
    /// Commands (spindle, coolant, tool, stop).
    commands: usize,
}

/// Parses a corpus file, checks it and snapshots its start; returns the program.
fn corpus(name: &str, expect: Expect) -> Program {
    let path = corpus_dir().join(name);
    let src = read(&path);
    let program = ok(&src);
    let mut verifier = Verifier;
    for b in &program.blocks {
        if let Err(e) = verifier.check(b) {
            panic!(
                "{name}: block of line {} breaks an invariant: {e}",
                b.span.line
            );
        }
        let end = b.span.offset as usize + b.span.len as usize;
        assert!(end <= src.len(), "{name}: span past the end of the input");
    }
    // The GOTO after each CIRCLE ends an arc.
    let lines: Vec<&str> = src.lines().collect();
    let mut arc_ends = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        if l.starts_with("CIRCLE") {
            let end = (i + 1..lines.len())
                .find(|&k| lines[k].starts_with("GOTO"))
                .unwrap();
            arc_ends.push(end as u32 + 1);
        }
    }
    let ms = motions(&program);
    let rapid = ms.iter().filter(|m| m.kind == MotionKind::Rapid).count();
    let linear = ms.iter().filter(|m| m.kind == MotionKind::Linear).count();
    let mut arc_pieces = 0;
    for line in &arc_ends {
        let n = program
            .blocks
            .iter()
            .filter(|b| b.span.line == *line && motion(b).is_some())
            .count();
        assert!(
            n >= 1,
            "{name}: the arc ending on line {line} has no motion"
        );
        arc_pieces += n;
    }
    assert!(
        program
            .diagnostics
            .iter()
            .all(|d| d.code != "cl::arc-radius"),
        "{name}: an arc fell back to a straight move"
    );
    let found = (
        rapid,
        linear,
        arc_ends.len(),
        arc_pieces,
        commands(&program).len(),
    );
    assert_eq!(
        found,
        (
            expect.rapid,
            expect.linear,
            expect.arcs,
            expect.arc_pieces,
            expect.commands
        ),
        "{name}: (rapid, linear, arcs, arc pieces, commands)"
    );
    let mut snap = String::new();
    let _ = writeln!(
        snap,
        "{name}: {} blocks, {rapid} rapid, {linear} linear, {} arcs in {arc_pieces} pieces, {} commands",
        program.blocks.len(),
        found.2,
        found.4
    );
    snap.push_str("-- diagnostics\n");
    for d in &program.diagnostics {
        let _ = writeln!(snap, "{d}");
    }
    snap.push_str("-- first 60 blocks\n");
    let n = program.blocks.len().min(60);
    snap.push_str(&dump_blocks(&program.blocks[..n]));
    insta::assert_snapshot!(name.replace('.', "_"), snap);
    program
}

/// ../shared/corpus/cl/aptpp_boss.apt — APT++ (CAMWorks) 3+2 axis milling: 1026 six-value
/// CIRCLEs (radius from the start point), RAPID/, CUTCOM, tilted CSYS.
#[test]
fn corpus_aptpp_boss() {
    let p = corpus(
        "aptpp_boss.apt",
        Expect {
            rapid: 775,
            linear: 36366,
            arcs: 1026,
            arc_pieces: 28353,
            commands: 17,
        },
    );
    assert!(p.diagnostics.iter().all(|d| !d.code.contains("arc")));
}

/// ../shared/corpus/cl/aptpp_interface_glue.apt — APT++ with a DEEP2 pecking cycle over
/// six holes and 50 six-value CIRCLEs.
#[test]
fn corpus_aptpp_interface_glue() {
    let p = corpus(
        "aptpp_interface_glue.apt",
        Expect {
            rapid: 125,
            linear: 10996,
            arcs: 50,
            arc_pieces: 4735,
            commands: 13,
        },
    );
    // The first hole: peck to 5, 7, ... 15 and the full depth 15.261 below the point.
    let bottom = tips(&p).iter().map(|t| t.z).fold(f64::INFINITY, f64::min);
    assert!(bottom <= -6.761364 - 15.261 + 1e-9);
}

/// ../shared/corpus/cl/aptpp_shimemcunha.apt — APT++ face milling with a tilted tool axis
/// and CSYS, drilling cycles, 28 CIRCLEs.
#[test]
fn corpus_aptpp_shimemcunha() {
    let p = corpus(
        "aptpp_shimemcunha.apt",
        Expect {
            rapid: 29,
            linear: 1418,
            arcs: 28,
            arc_pieces: 1383,
            commands: 15,
        },
    );
    let first = pose(motions(&p)[0]);
    assert!(
        (first.axis.into_inner() - Vector3::new(0.005061, 0.0, 0.999987).normalize()).norm() < 1e-9
    );
}

/// ../shared/corpus/cl/aptpp_telemecanique_tilt_support1.apt — APT++ with a tool axis
/// tilted 10 degrees (6-value GOTOs), DRILL and DEEP2 cycles along the tilted axis.
#[test]
fn corpus_aptpp_telemecanique_tilt_support1() {
    corpus(
        "aptpp_telemecanique_tilt_support1.apt",
        Expect {
            rapid: 58,
            linear: 154,
            arcs: 0,
            arc_pieces: 0,
            commands: 10,
        },
    );
}

/// ../shared/corpus/cl/igesio_apt.cl — plain APT sample: MULTAX/ON, LOADTL, SPINDL,
/// COOLNT, FEDRAT/300,MMPM, RAPID, a 7-value CIRCLE, PPRINT, DELAY, FINI.
#[test]
fn corpus_igesio_apt() {
    let p = corpus(
        "igesio_apt.cl",
        Expect {
            rapid: 1,
            linear: 59,
            arcs: 1,
            arc_pieces: 56,
            commands: 4,
        },
    );
    assert_eq!(commands(&p), vec!["T1", "M3 S5000", "M8", "M2"]);
    assert!(
        p.blocks
            .iter()
            .any(|b| matches!(b.kind, BlockKind::Dwell { seconds } if seconds == 0.5))
    );
    // The quarter circle from (10,0,0) about (10,10,0) to (20,10,0) runs counter-clockwise.
    let t = tips(&p);
    let arc: Vec<_> = t[3..t.len() - 1].to_vec();
    for q in &arc {
        assert!(((q - Point3::new(10.0, 10.0, 0.0)).norm() - 10.0).abs() < 1e-9);
        assert!(q.x >= 10.0 - 1e-9 && q.y <= 10.0 + 1e-9);
    }
    close(*arc.last().unwrap(), Point3::new(20.0, 10.0, 0.0), 0.0);
}

/// ../shared/corpus/cl/igesio_triplet.cl — the triplet format (point, axis, motion code
/// `7f` rapid / `80` feed), recognised by content; an axis `0 0 2` is normalised.
#[test]
fn corpus_igesio_triplet() {
    let p = corpus(
        "igesio_triplet.cl",
        Expect {
            rapid: 2,
            linear: 2,
            arcs: 0,
            arc_pieces: 0,
            commands: 0,
        },
    );
    let ms = motions(&p);
    close(pose(ms[3]).tip, Point3::new(20.0, 0.0, 0.0), 0.0);
    assert_eq!(pose(ms[3]).axis.into_inner(), Vector3::z());
    assert_eq!(p.blocks[3].span.line, 11);
}

/// ../shared/corpus/cl/mech491_APT_Project2.txt — NX CLSF information listing (header
/// and trailer lines), inch data without a UNITS statement (FEDRAT/IPM), 11-value
/// CIRCLEs including helices with TIMES, inline `$$` comments after GOTO.
#[test]
fn corpus_mech491_project2() {
    let p = corpus(
        "mech491_APT_Project2.txt",
        Expect {
            rapid: 98,
            linear: 18001,
            arcs: 146,
            arc_pieces: 7660,
            commands: 4,
        },
    );
    let codes: Vec<_> = p.diagnostics.iter().map(|d| d.code).collect();
    assert_eq!(codes, vec!["cl::units-inferred"]);
    // GOTO/2.3600,2.2749,3.5300 in inches.
    close(
        pose(motions(&p)[0]).tip,
        Point3::new(59.944, 57.78246, 89.662),
        1e-9,
    );
    // `GOTO/1.9949,0.1148,1.4399 $$ 1.9949,0.0707,1.3611` keeps its comment.
    assert!(p.blocks.iter().any(
        |b| b.span.line == 5342 && b.comments.iter().any(|c| c.text == " 1.9949,0.0707,1.3611")
    ));
}

/// ../shared/corpus/cl/mech491_APT_Variable_Axis.txt — NX variable-axis path: 6-value
/// GOTOs whose tool axis stays in force for the 3-value ones after them.
#[test]
fn corpus_mech491_variable_axis() {
    let p = corpus(
        "mech491_APT_Variable_Axis.txt",
        Expect {
            rapid: 3,
            linear: 345,
            arcs: 0,
            arc_pieces: 0,
            commands: 0,
        },
    );
    let ms = motions(&p);
    // Line 13, `GOTO/-3.5785,-3.0021,1.3002`, keeps the axis of line 10.
    assert_eq!(pose(ms[1]).axis, pose(ms[0]).axis);
    assert!((pose(ms[0]).axis.x + 0.3778015 / 0.99999).abs() < 1e-4);
}

/// ../shared/corpus/cl/mech491_APT_Zig_Zag_Smoothed.txt — NX face milling in mm
/// (FEDRAT/MMPM,250), 35 smoothing CIRCLEs given clockwise about their axis.
#[test]
fn corpus_mech491_zig_zag_smoothed() {
    let p = corpus(
        "mech491_APT_Zig_Zag_Smoothed.txt",
        Expect {
            rapid: 3,
            linear: 1001,
            arcs: 35,
            arc_pieces: 964,
            commands: 1,
        },
    );
    // Every smoothing arc leaves along the line that follows it: the NX axis is clockwise.
    let ms = motions(&p);
    let line_of = |i: usize| {
        p.blocks
            .iter()
            .filter(|b| motion(b).is_some())
            .nth(i)
            .unwrap()
            .span
            .line
    };
    let mut arcs = 0;
    for i in 1..ms.len() - 1 {
        if line_of(i) == line_of(i - 1) && line_of(i + 1) != line_of(i) {
            let (a, b, c) = (pose(ms[i - 1]).tip, pose(ms[i]).tip, pose(ms[i + 1]).tip);
            let into = (b - a).normalize();
            let out = (c - b).normalize();
            if (c - b).norm() > 0.5 {
                arcs += 1;
                assert!(
                    into.dot(&out) > 0.99,
                    "arc ending on line {} turns away",
                    line_of(i)
                );
            }
        }
    }
    assert!(arcs > 20);
}

/// ../shared/corpus/cl/mech491_APT_code.txt — NX contour with a variable tool axis, inch.
#[test]
fn corpus_mech491_code() {
    corpus(
        "mech491_APT_code.txt",
        Expect {
            rapid: 4,
            linear: 321,
            arcs: 0,
            arc_pieces: 0,
            commands: 1,
        },
    );
}

// ---------------------------------------------------------------------------------------
// Part 2: statements
// ---------------------------------------------------------------------------------------

#[test]
fn fedrat_in_either_order_and_every_unit() {
    let p = ok("FROM/0,0,0\n\
                FEDRAT/300,MMPM\nGOTO/1,0,0\n\
                FEDRAT/MMPM,400\nGOTO/2,0,0\n\
                FEDRAT/10,IPM\nGOTO/3,0,0\n\
                FEDRAT/IPM,10\nGOTO/4,0,0\n\
                FEDRAT/0.1,MMPR\nGOTO/5,0,0\n\
                FEDRAT/IPR,0.01\nGOTO/6,0,0\n\
                FEDRAT/500\nGOTO/7,0,0\n\
                FEDRAT / 250 , MMPM\nGOTO/8,0,0\n");
    let feeds: Vec<_> = motions(&p)[1..]
        .iter()
        .map(|m| (m.feed.mode, m.feed.rate.unwrap()))
        .collect();
    let pm = FeedMode::PerMinute;
    let pr = FeedMode::PerRevolution;
    let expected = [
        (pm, 300.0),
        (pm, 400.0),
        (pm, 254.0),
        (pm, 254.0),
        (pr, 0.1),
        (pr, 0.254),
        // Without a unit: the program's length unit, the last mode.
        (pr, 500.0),
        (pm, 250.0),
    ];
    for (f, e) in feeds.iter().zip(expected) {
        assert_eq!(f.0, e.0);
        assert!((f.1 - e.1).abs() < 1e-9, "{f:?} != {e:?}");
    }
    // Before any FEDRAT there is no rate.
    assert_eq!(motions(&p)[0].feed.rate, None);
}

#[test]
fn units_inches_convert_every_length() {
    let p = ok("UNITS/INCHES\n\
                FROM/1,2,3\n\
                GODLTA/1,0,0\n\
                FEDRAT/10\n\
                CIRCLE/0,2,3,0,0,1,2\n\
                GOTO/0,4,3\n");
    let t = tips(&p);
    close(t[0], Point3::new(25.4, 50.8, 76.2), 1e-12);
    close(t[1], Point3::new(50.8, 50.8, 76.2), 1e-12);
    close(*t.last().unwrap(), Point3::new(0.0, 101.6, 76.2), 1e-12);
    // The arc's radius is 2 inches: every piece lies on it, no radius warning.
    for q in &t[2..] {
        assert!(((q - Point3::new(0.0, 50.8, 76.2)).norm() - 50.8).abs() < 1e-9);
    }
    assert!(p.diagnostics.is_empty(), "{:?}", p.diagnostics);
    assert_eq!(motions(&p)[2].feed.rate, Some(254.0));
    // UNIT/MM and METRIC switch back; INCHES alone switches to inches.
    let p = ok("INCHES\nGOTO/1,0,0\nUNIT/MM\nGOTO/1,0,0\nINCHES\nMETRIC\nGOTO/2,0,0\n");
    let xs: Vec<f64> = tips(&p).iter().map(|t| t.x).collect();
    assert_eq!(xs, vec![25.4, 1.0, 2.0]);
    // An explicit unit option wins over a feed clue.
    let options = Options {
        units: Units::Mm,
        ..Options::default()
    };
    let p = ok_with("GOTO/1,0,0\nFEDRAT/IPM,10\n", &options);
    assert_eq!(tips(&p)[0].x, 1.0);
    assert!(p.diagnostics.is_empty());
    let options = Options {
        units: Units::Inch,
        ..Options::default()
    };
    assert_eq!(tips(&ok_with("GOTO/1,0,0\n", &options))[0].x, 25.4);
}

#[test]
fn feed_in_inches_without_units_statement_means_inch_data() {
    let p = ok("$$ NX listing\nRAPID\nGOTO/1,0,0\nFEDRAT/IPM,10.0000\nGOTO/2,0,0\n");
    assert_eq!(tips(&p)[0].x, 25.4);
    let d = &p.diagnostics[0];
    assert_eq!(d.code, "cl::units-inferred");
    assert_eq!(d.location.as_ref().unwrap().line, 4);
    // A feed in mm says mm, without a warning.
    let p = ok("GOTO/1,0,0\nFEDRAT/MMPM,250\n");
    assert_eq!(tips(&p)[0].x, 1.0);
    assert!(p.diagnostics.is_empty());
}

#[test]
fn rapid_applies_to_the_next_motion_only() {
    let p = ok(
        "FEDRAT/100\nGOTO/0,0,0\nRAPID\nGOTO/1,0,0\nGOTO/2,0,0\nRAPID/\nGOTO/3,0,0\nGOTO/4,0,0\n",
    );
    let kinds: Vec<_> = motions(&p).iter().map(|m| m.kind).collect();
    use MotionKind::{Linear, Rapid};
    assert_eq!(kinds, vec![Linear, Rapid, Linear, Rapid, Linear]);
    // FROM is the start point: a rapid move, and RAPID before it is used up.
    let p = ok("RAPID\nFROM/0,0,0\nGOTO/1,0,0\n");
    let kinds: Vec<_> = motions(&p).iter().map(|m| m.kind).collect();
    assert_eq!(kinds, vec![Rapid, Linear]);
}

#[test]
fn multax_off_with_tlaxis() {
    let p = ok(
        "MULTAX/OFF\nTLAXIS/0,1,1\nGOTO/0,0,0\nGOTO/1,0,0,1,0,0\nGOTO/2,0,0,0,0,1\nGOTO/3,0,0\n",
    );
    let axes: Vec<_> = motions(&p)
        .iter()
        .map(|m| pose(m).axis.into_inner())
        .collect();
    let s = 0.5f64.sqrt();
    assert!((axes[0] - Vector3::new(0.0, s, s)).norm() < 1e-12);
    assert_eq!(axes[1], Vector3::x());
    assert_eq!(axes[2], Vector3::z());
    assert_eq!(axes[3], Vector3::z());
    // One warning for all tool axes under MULTAX/OFF, at the first one's i,j,k.
    assert_eq!(p.diagnostics.len(), 1);
    expect(
        &p.diagnostics[0],
        Severity::Warning,
        "cl::multax-off",
        4,
        12,
    );
    // MULTAX and MULTAX/ON: no warning; the axis is modal.
    let p = ok("MULTAX\nGOTO/0,0,0,0,0,2\nMULTAX/ON\nGOTO/1,0,0,0,-1,0\nGOTO/1,1,0\n");
    assert!(p.diagnostics.is_empty());
    let axes: Vec<_> = motions(&p)
        .iter()
        .map(|m| pose(m).axis.into_inner())
        .collect();
    assert_eq!(axes, vec![Vector3::z(), -Vector3::y(), -Vector3::y()]);
}

#[test]
fn continuation_joins_lines_and_spans_them() {
    let src = "GOTO/1,$\n   2,$ $$ middle\n3\nGOTO / 4 , 5 , 6\n";
    let p = ok(src);
    let b = &p.blocks[0];
    assert_eq!(
        b.span,
        Span {
            offset: 0,
            len: (src.find("\nGOTO /").unwrap()) as u32,
            line: 1
        }
    );
    close(
        pose(motion(b).unwrap()).tip,
        Point3::new(1.0, 2.0, 3.0),
        0.0,
    );
    assert_eq!(b.comments[0].text, " middle");
    assert_eq!(p.blocks[1].span.line, 4);
    // An error on a continuation line points at that line.
    let d = errors("GOTO/1,$\n  2,y\n");
    expect(&d[0], Severity::Error, "cl::bad-number", 2, 5);
}

#[test]
fn goto_number_spellings() {
    let p = ok("GOTO/-.5,1.E-3,5.0000000\nGOTO / +2 , 7e1 , -0\n");
    close(tips(&p)[0], Point3::new(-0.5, 0.001, 5.0), 0.0);
    close(tips(&p)[1], Point3::new(2.0, 70.0, 0.0), 0.0);
}

#[test]
fn godlta_moves_relative_to_the_last_point() {
    let p = ok("FROM/1,2,3\nGODLTA/1,1,1\nTLAXIS/0,0,1\nGODLTA/-2\nGODLTA/0,0,0,1,0,0\nGODLTA/3\n");
    let t = tips(&p);
    close(t[1], Point3::new(2.0, 3.0, 4.0), 1e-12);
    close(t[2], Point3::new(2.0, 3.0, 2.0), 1e-12);
    close(t[3], Point3::new(2.0, 3.0, 2.0), 1e-12);
    // The single value goes along the tool axis now in force.
    close(t[4], Point3::new(5.0, 3.0, 2.0), 1e-12);
    let d = errors("GODLTA/1,0,0\n");
    expect(&d[0], Severity::Error, "cl::no-start", 1, 8);
}

/// The pieces of the arc statement: the start point and the motion targets after it.
fn arc_points(src: &str, options: &Options) -> (Vec<Point3<f64>>, Program) {
    let p = ok_with(src, options);
    (tips(&p), p)
}

/// Checks that `points` (the first is the arc start) lie on the circle of `centre`,
/// `normal`, `radius` within 1e-9, that every chord's sagitta is within `tol`, and
/// returns the signed angles (about `normal`) swept piece by piece.
#[track_caller]
fn check_on_circle(
    points: &[Point3<f64>],
    centre: Point3<f64>,
    normal: Vector3<f64>,
    radius: f64,
    tol: f64,
) -> Vec<f64> {
    let n = normal.normalize();
    let radial = |p: &Point3<f64>| {
        let v = p - centre;
        v - n * v.dot(&n)
    };
    let mut steps = Vec::new();
    for w in points.windows(2) {
        let (a, b) = (radial(&w[0]), radial(&w[1]));
        for r in [a, b] {
            assert!(
                (r.norm() - radius).abs() < 1e-9,
                "point off the circle by {}",
                r.norm() - radius
            );
        }
        // Sagitta of the chord: radius minus the distance of the chord's middle.
        let sagitta = radius - ((a + b) / 2.0).norm();
        assert!(sagitta <= tol + 1e-12, "chord sagitta {sagitta} over {tol}");
        steps.push(a.cross(&b).dot(&n).atan2(a.dot(&b)));
    }
    steps
}

#[test]
fn circle_counter_clockwise_about_its_axis_within_the_chord_tolerance() {
    let options = Options::default();
    // APT 7 values: centre, axis +Z, radius; a quarter circle counter-clockwise.
    let (pts, p) = arc_points(
        "FROM/10,0,0\nCIRCLE/0,0,0,0,0,1,10\nGOTO/0,10,0\n",
        &options,
    );
    let steps = check_on_circle(
        &pts,
        Point3::origin(),
        Vector3::z(),
        10.0,
        options.arc_tolerance,
    );
    assert!(steps.iter().all(|s| *s > 0.0));
    assert!((steps.iter().sum::<f64>() - FRAC_PI_2).abs() < 1e-9);
    close(*pts.last().unwrap(), Point3::new(0.0, 10.0, 0.0), 0.0);
    // Every piece has the GOTO's span; the CIRCLE gives no block of its own.
    assert!(p.blocks[1..].iter().all(|b| b.span.line == 3));
    // The least number of pieces: one fewer would break the tolerance.
    let n = steps.len() as f64;
    assert!(10.0 * (1.0 - (FRAC_PI_2 / (n - 1.0) / 2.0).cos()) > options.arc_tolerance);

    // Axis -Z: clockwise seen from +Z, the long way round (270 degrees).
    let (pts, _) = arc_points(
        "FROM/10,0,0\nCIRCLE/0,0,0,0,0,-1,10\nGOTO/0,10,0\n",
        &options,
    );
    let steps = check_on_circle(
        &pts,
        Point3::origin(),
        Vector3::z(),
        10.0,
        options.arc_tolerance,
    );
    assert!(steps.iter().all(|s| *s < 0.0));
    assert!((steps.iter().sum::<f64>() + 3.0 * FRAC_PI_2).abs() < 1e-9);

    // A coarser tolerance, a tilted plane (axis along X).
    let coarse = Options {
        arc_tolerance: 0.05,
        ..Options::default()
    };
    let (pts, _) = arc_points("FROM/0,5,0\nCIRCLE/0,0,0,1,0,0,5\nGOTO/0,-5,0\n", &coarse);
    let steps = check_on_circle(&pts, Point3::origin(), Vector3::x(), 5.0, 0.05);
    assert!((steps.iter().sum::<f64>() - PI).abs() < 1e-9);
    // Counter-clockwise about +X goes from +Y through +Z.
    assert!(pts[pts.len() / 2].z > 4.9);
}

#[test]
fn nx_circle_is_clockwise_about_its_axis() {
    let options = Options::default();
    // NX: centre, axis, radius, tolerance, ratio, tool diameter, corner radius.
    let src = "UNITS/MM\nFROM/-2.5,0,0\nCIRCLE/0,0,0,0,0,-1,2.5,0.06,0.5,10,0\nGOTO/0,-2.5,0\n";
    let (pts, p) = arc_points(src, &options);
    let steps = check_on_circle(
        &pts,
        Point3::origin(),
        Vector3::z(),
        2.5,
        options.arc_tolerance,
    );
    // Axis -Z in NX: counter-clockwise seen from +Z, a quarter turn.
    assert!(steps.iter().all(|s| *s > 0.0));
    assert!((steps.iter().sum::<f64>() - FRAC_PI_2).abs() < 1e-9);
    assert!(p.diagnostics.is_empty());
}

#[test]
fn six_value_circle_takes_its_radius_from_the_start_point() {
    let options = Options::default();
    // A full circle: the GOTO repeats the start point.
    let (pts, _) = arc_points(
        "FROM/41.5,75,0\nCIRCLE/37.5,75.,0,0,0,1.\nGOTO/41.5,75.,0\n",
        &options,
    );
    let steps = check_on_circle(
        &pts,
        Point3::new(37.5, 75.0, 0.0),
        Vector3::z(),
        4.0,
        options.arc_tolerance,
    );
    assert!((steps.iter().sum::<f64>() - TAU).abs() < 1e-9);
}

#[test]
fn helix_with_times_and_changing_tool_axis() {
    let options = Options {
        arc_tolerance: 0.01,
        ..Options::default()
    };
    // Two extra turns and a quarter, falling 9 mm; the tool axis turns from Z to X.
    let src =
        "MULTAX\nFROM/5,0,9,0,0,1\nCIRCLE/0,0,0,0,0,1,5,0.01,0.5,6,0,TIMES,2\nGOTO/0,-5,0,1,0,0\n";
    let p = ok_with(src, &options);
    let t = tips(&p);
    // NX form: clockwise about +Z, a quarter plus two turns.
    let steps = check_on_circle(&t, Point3::origin(), Vector3::z(), 5.0, 0.01);
    let total: f64 = steps.iter().sum();
    assert!((total + 2.0 * TAU + FRAC_PI_2).abs() < 1e-9, "{total}");
    // Height falls in proportion to the angle.
    for (i, q) in t.iter().enumerate().skip(1) {
        let swept: f64 = -steps[..i].iter().sum::<f64>();
        assert!((q.z - (9.0 - 9.0 * swept / (2.0 * TAU + FRAC_PI_2))).abs() < 1e-9);
    }
    let ms = motions(&p);
    let axes: Vec<_> = ms.iter().map(|m| pose(m).axis).collect();
    assert_eq!(axes.last().unwrap().into_inner(), Vector3::x());
    let mid = axes[axes.len() / 2];
    assert!((mid.norm() - 1.0).abs() < 1e-12 && mid.x > 0.5 && mid.z > 0.5);
}

#[test]
fn movarc_forms() {
    let options = Options::default();
    let (pts, p) = arc_points(
        "FROM/1,0,0\nMOVARC/0,0,0,0,0,1,1,ANGLE,450\nGOTO/0,1,0\n",
        &options,
    );
    let steps = check_on_circle(
        &pts,
        Point3::origin(),
        Vector3::z(),
        1.0,
        options.arc_tolerance,
    );
    assert!((steps.iter().sum::<f64>() - (TAU + FRAC_PI_2)).abs() < 1e-9);
    assert!(p.diagnostics.is_empty());
    let (pts, _) = arc_points(
        "FROM/1,0,0\nMOVARC/CENTER,0,0,0,AXIS,0,0,-1,RADIUS,1\nGOTO/0,1,0\n",
        &options,
    );
    let steps = check_on_circle(
        &pts,
        Point3::origin(),
        Vector3::z(),
        1.0,
        options.arc_tolerance,
    );
    assert!((steps.iter().sum::<f64>() + 3.0 * FRAC_PI_2).abs() < 1e-9);
}

#[test]
fn creo_helical_orbits_with_continued_circle_statements() {
    let path = fixture_dir().join("creo_helix.cl");
    let p = ok(&read(&path));
    let t = tips(&p);
    // Two full orbits of radius 0.198 in, each rising 1/24 in.
    let r = 0.198 * 25.4;
    let orbit: Vec<_> = t
        .iter()
        .filter(|q| q.x < 8.198 * 25.4 - 1e-9 || (q.y.abs() > 1e-9))
        .collect();
    assert!(orbit.len() > 100);
    for q in &orbit[..orbit.len() - 1] {
        let d = ((q.x - 8.0 * 25.4).powi(2) + q.y.powi(2)).sqrt();
        assert!((d - r).abs() < 1e-9);
    }
    close(
        t[t.len() - 1],
        Point3::new(8.0 * 25.4, 0.0, -0.541667 * 25.4),
        1e-9,
    );
    // The continued CIRCLE's `$$` comment travels with its first arc piece.
    assert!(
        p.blocks
            .iter()
            .any(|b| b.comments.iter().any(|c| c.text == " 1ST ORBIT"))
    );
    assert!(p.diagnostics.is_empty(), "{:?}", p.diagnostics);
}

#[test]
fn nx_helix_excerpt() {
    let path = fixture_dir().join("nx_helix.cl");
    let p = ok(&read(&path));
    let codes: Vec<_> = p.diagnostics.iter().map(|d| d.code).collect();
    assert_eq!(codes, vec!["cl::units-inferred"]);
    // The TIMES,7 helix: seven turns and the part from start to end.
    let helix: Vec<_> = p.blocks.iter().filter(|b| b.span.line == 18).collect();
    let start = Point3::new(2.0763, 3.9939, 2.1335) * 25.4;
    let mut points = vec![start];
    points.extend(helix.iter().map(|b| pose(motion(b).unwrap()).tip));
    let axis = Vector3::new(0.0, -0.9922779, -0.1240347);
    let centre = Point3::new(1.9949, 3.6307, 1.9391) * 25.4;
    let n = axis.normalize();
    let mut total = 0.0;
    for w in points.windows(2) {
        let ra = (w[0] - centre) - n * (w[0] - centre).dot(&n);
        let rb = (w[1] - centre) - n * (w[1] - centre).dot(&n);
        total += ra.cross(&rb).dot(&n).atan2(ra.dot(&rb));
    }
    // Clockwise about the NX axis.
    let turns = -total / TAU;
    assert!((turns - (7.0 + 331.16 / 360.0)).abs() < 1e-3, "{turns}");
}

#[test]
fn drilling_cycle_on_a_tilted_axis() {
    let path = fixture_dir().join("tilt_drill.cl");
    let p = ok(&read(&path));
    let t = Vector3::new(-0.173648, 0.0, 0.984808).normalize();
    let hole = Point3::new(15.756924, 10.0, -6.156343);
    // The DRILL cycle at line 16: from the retract point (the GOTO before), rapid to
    // RAPTO 3, feed to FEDTO 2.75344, rapid back to RTRCTO 10.
    let at16: Vec<_> = p
        .blocks
        .iter()
        .filter(|b| b.span.line == 16)
        .map(|b| motion(b).unwrap())
        .collect();
    assert_eq!(at16.len(), 3);
    close(pose(at16[0]).tip, hole + t * 3.0, 1e-9);
    assert_eq!(at16[0].kind, MotionKind::Rapid);
    close(pose(at16[1]).tip, hole - t * 2.75344, 1e-9);
    assert_eq!(at16[1].kind, MotionKind::Linear);
    assert_eq!(at16[1].feed.rate, Some(731.52));
    close(pose(at16[2]).tip, hole + t * 10.0, 1e-9);
    // The DEEP2 cycle at line 36: pecks at 5, 7, 9 and the full depth 10.1.
    let feeds: Vec<f64> = p
        .blocks
        .iter()
        .filter(|b| b.span.line == 36)
        .filter_map(motion)
        .filter(|m| m.kind == MotionKind::Linear)
        .map(|m| -(pose(m).tip - hole).dot(&t))
        .collect();
    let expected = [5.0, 7.0, 9.0, 10.1];
    assert_eq!(feeds.len(), expected.len());
    for (f, e) in feeds.iter().zip(expected) {
        assert!((f - e).abs() < 1e-9, "{feeds:?}");
    }
    // The modal feed is not changed by the cycle's feed.
    let after = p
        .blocks
        .iter()
        .filter(|b| b.span.line == 20)
        .find_map(motion)
        .unwrap();
    assert_eq!(after.kind, MotionKind::Rapid);
}

#[test]
fn drilling_cycle_from_the_corpus_with_six_holes() {
    let path = fixture_dir().join("glue_deep2.cl");
    let p = ok(&read(&path));
    for line in 19..=24 {
        let n = p.blocks.iter().filter(|b| b.span.line == line).count();
        // Rapid to the clearance plane (not for the first hole: the tool is there) and
        // to RAPTO, 6 pecks with 3 motions, the last feed, the retract.
        let to_clearance = usize::from(line > 19);
        assert_eq!(n, to_clearance + 1 + 6 * 3 + 1 + 1, "hole on line {line}");
    }
    // The first hole starts at the clearance plane already: no move there.
    let first = p
        .blocks
        .iter()
        .find(|b| b.span.line == 19)
        .and_then(motion)
        .unwrap();
    close(
        pose(first).tip,
        Point3::new(67.5, 107.5, -6.761364 + 3.0),
        1e-9,
    );
}

#[test]
fn commands_and_passed_through_statements() {
    let p = ok("PARTNO TEST PART\n\
                LOADTL/3\nLOAD/TOOL,4,ADJUST,4\n\
                SPINDL/12000,RPM,CLW\nSPINDL/OFF\nSPINDL/ON\nSPINDL/RPM,800,CCLW\n\
                COOLNT/FLOOD\nCOOLNT/MIST\nCOOLNT/OFF\n\
                DELAY/2.5\nPPRINT hello, world / again\n\
                TOOL PATH/X,TOOL,Y\nEND-OF-PATH\nPAINT/COLOR,3\nEND\nFINI\n");
    assert_eq!(
        commands(&p),
        vec![
            "T3",
            "T4",
            "M3 S12000",
            "M5",
            "M3 S12000",
            "M4 S800",
            "M8",
            "M7",
            "M9",
            "M0",
            "M2"
        ]
    );
    let t4 = p.blocks.iter().find(|b| b.span.line == 3).unwrap();
    assert_eq!(t4.comments[0].text, " LOAD/TOOL,4,ADJUST,4");
    let texts: Vec<_> = p
        .blocks
        .iter()
        .filter(|b| b.kind == BlockKind::Comment)
        .map(|b| b.comments[0].text.as_str())
        .collect();
    assert_eq!(
        texts,
        vec![
            " PARTNO TEST PART",
            " hello, world / again",
            " TOOL PATH/X,TOOL,Y",
            " END-OF-PATH",
            " PAINT/COLOR,3"
        ]
    );
    assert!(p.diagnostics.is_empty(), "{:?}", p.diagnostics);
    assert!(
        p.blocks
            .iter()
            .any(|b| b.kind == BlockKind::Dwell { seconds: 2.5 })
    );
    // END and FINI codes are options; empty passes them as comments.
    let options = Options {
        end_command: "M226".into(),
        fini_command: String::new(),
        ..Options::default()
    };
    let p = ok_with("END\nFINI\n", &options);
    assert_eq!(commands(&p), vec!["M226"]);
    assert_eq!(p.blocks[1].comments[0].text, " FINI");
}

#[test]
fn nx_listing_header_lines_are_comments() {
    let src = "\nInformation listing created by\tphill\nDate\t18-Dec-2021 21:07:42\n\
               Current work part\tC:\\part.prt\nNode name\tlaptop\n\nGOTO/0,0,0\n\
               Tool Path Listing has 3 lines.\n";
    let p = ok(src);
    assert!(p.diagnostics.is_empty(), "{:?}", p.diagnostics);
    assert_eq!(p.blocks.len(), 6);
}

#[test]
fn triplet_format_is_recognised_by_content() {
    let p = ok("1 2 3\n0 0 5\n7F\n4 5 6\n0 1 0\n80\n");
    let ms = motions(&p);
    assert_eq!(ms[0].kind, MotionKind::Rapid);
    assert_eq!(ms[1].kind, MotionKind::Linear);
    assert_eq!(pose(ms[1]).axis.into_inner(), Vector3::y());
    assert_eq!(
        p.blocks[1].span,
        Span {
            offset: 15,
            len: 14,
            line: 4
        }
    );
    // A broken triplet is an error at its line; the next one is read.
    let d = errors("1 2 3\n0 0 1\n7f\n1 2\n");
    expect(&d[0], Severity::Error, "cl::triplet", 4, 1);
}

#[test]
fn unknown_statement_passes_through_with_a_warning() {
    let p = ok("FROM/0,0,0\nWIBBLE/1,(2)\nGOTO/1,0,0\n");
    expect(
        &p.diagnostics[0],
        Severity::Warning,
        "cl::unknown-statement",
        2,
        1,
    );
    assert_eq!(p.blocks[1].comments[0].text, " WIBBLE/1,(2)");
    assert_eq!(p.blocks.len(), 3);
}

#[test]
fn streaming_hands_out_arc_pieces_in_small_batches() {
    let src = "FROM/100,0,0\nCIRCLE/0,0,0,0,0,1,100\nGOTO/100,0,0\nGOTO/0,0,0\n";
    let whole = ok(src);
    let mut parser = Parser::new(src.as_bytes(), Options::default());
    let mut diags = Vec::new();
    let mut out = Vec::new();
    loop {
        let before = out.len();
        parser.next_batch(&mut out, before + 7, &mut diags);
        assert!(out.len() <= before + 7 || out.len() == before);
        if out.len() == before {
            break;
        }
    }
    assert_eq!(out, whole.blocks);
    assert!(out.len() > 500);
    assert!(parser.bytes_read() == src.len() as u64);
}

// ---------------------------------------------------------------------------------------
// Part 3: diagnostics
// ---------------------------------------------------------------------------------------

#[test]
fn fixtures_cite_their_origin() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR"));
    for e in std::fs::read_dir(fixture_dir()).unwrap() {
        let path = e.unwrap().path();
        let text = read(&path);
        let first = text.lines().next().unwrap_or("");
        if let Some(rest) = first.strip_prefix("$$ origin: ") {
            let file = rest.split_whitespace().next().unwrap();
            if corpus_dir().is_dir() {
                assert!(
                    corpus.join(file).is_file(),
                    "{}: {file} does not exist",
                    path.display()
                );
            }
        } else {
            assert!(
                first.starts_with("$$ written for ncpost: "),
                "{}: the first line names no origin",
                path.display()
            );
        }
    }
}

#[test]
fn bad_statements_each_reported_with_line_and_column() {
    let name = "bad_statements.cl";
    let d = errors(&read(&fixture_dir().join(name)));
    insta::assert_snapshot!("bad_statements", render_all(name, &d));
    let e = Severity::Error;
    let expected: &[(&str, u32, u32)] = &[
        ("cl::arity", 4, 6),
        ("cl::bad-number", 5, 10),
        ("cl::zero-axis", 6, 12),
        ("cl::bad-value", 7, 8),
        ("cl::feed-unit", 8, 12),
        ("cl::bad-value", 9, 20),
        ("cl::syntax", 10, 12),
        ("cl::bad-value", 11, 8),
        ("cl::bad-value", 12, 8),
        ("cl::bad-number", 13, 6),
        ("cl::zero-axis", 14, 8),
        ("cl::bad-number", 16, 5),
        ("cl::bad-value", 17, 7),
    ];
    assert_eq!(d.len(), expected.len(), "{}", render_all(name, &d));
    for (d, (code, line, column)) in d.iter().zip(expected) {
        expect(d, e, code, *line, *column);
    }
    // Reading went on: the last GOTO is lowered (the streaming parser shows it).
    let src = read(&fixture_dir().join(name));
    let mut parser = Parser::new(src.as_bytes(), Options::default());
    let mut diags = Vec::new();
    let mut last = None;
    while let Some(b) = parser.next_block(&mut diags) {
        if motion(&b).is_some() {
            last = Some(b);
        }
    }
    assert_eq!(last.unwrap().span.line, 18);
}

#[test]
fn warnings_fixture() {
    let name = "warnings.cl";
    let p = ok(&read(&fixture_dir().join(name)));
    insta::assert_snapshot!("warnings", render_all(name, &p.diagnostics));
    let w = Severity::Warning;
    let expected: &[(&str, u32, u32)] = &[
        ("cl::arc-radius", 6, 1),
        ("cl::multax-off", 7, 13),
        ("cl::csys-not-applied", 9, 6),
        ("cl::cutcom", 10, 8),
        ("cl::cycle-unsupported", 11, 7),
        ("cl::unsupported", 14, 8),
        ("cl::unknown-statement", 15, 1),
        ("cl::circle-without-end", 16, 1),
    ];
    assert_eq!(
        p.diagnostics.len(),
        expected.len(),
        "{}",
        render_all(name, &p.diagnostics)
    );
    for (d, (code, line, column)) in p.diagnostics.iter().zip(expected) {
        expect(d, w, code, *line, *column);
    }
    // The arc that does not fit its radius is a straight move; the GOTO inside the
    // unsupported cycle moves to its point.
    let t = tips(&p);
    close(t[1], Point3::new(0.0, 10.0, 0.0), 0.0);
    close(t[4], Point3::new(5.0, 5.0, 0.0), 0.0);
}

#[test]
fn empty_input_is_an_error() {
    for src in ["", "\n\n  \n"] {
        let d = errors(src);
        assert_eq!(d[0].code, "cl::empty");
    }
}

/// Past the lines the frontend looks at first, plain `GOTO/` lines are lowered straight
/// from the reader's bytes: a bad byte there is still reported where it is, and the
/// lines around it still lowered.
#[test]
fn bad_bytes_in_goto_lines_after_the_first_look() {
    let mut src = b"UNITS/MM\n".to_vec();
    for _ in 0..5000 {
        src.extend_from_slice(b"GOTO/1,2,3\n");
    }
    src.extend_from_slice(b"GOTO/1,2,3\xff\nGOTO/1,\xc3\xa9,3\nGOTO/4,5,6\n");
    let mut parser = Parser::new(&src[..], Options::default());
    let mut diags = Vec::new();
    let mut blocks = Vec::new();
    while let Some(b) = parser.next_block(&mut diags) {
        blocks.push(b);
    }
    assert_eq!(blocks.len(), 5001);
    assert_eq!(diags.len(), 2, "{diags:?}");
    expect(&diags[0], Severity::Error, "cl::not-utf8", 5002, 11);
    // Valid UTF-8 that is not a number: the grammar's message, at the bad character.
    assert_eq!(diags[1].severity, Severity::Error);
    assert_eq!(diags[1].location.as_ref().map(|l| l.line), Some(5003));
}

#[test]
fn bad_bytes_and_long_lines() {
    let mut parser = Parser::new(
        &b"GOTO/1,2,3\n\xff\xfeGOTO\nGOTO/1,2,3\n"[..],
        Options::default(),
    );
    let mut diags = Vec::new();
    let mut n = 0;
    while parser.next_block(&mut diags).is_some() {
        n += 1;
    }
    assert_eq!(n, 2);
    expect(&diags[0], Severity::Error, "cl::not-utf8", 2, 1);
    let options = Options {
        max_line_len: 16,
        ..Options::default()
    };
    let src = format!("GOTO/1,2,3\nPPRINT {}\nGOTO/1,$\n2,$\n3\n", "x".repeat(40));
    let d = match parse_str(&src, &options) {
        Err(d) => d,
        Ok(_) => panic!("expected errors"),
    };
    assert_eq!(d[0].code, "cl::line-too-long");
    assert_eq!(d[0].location.as_ref().unwrap().line, 2);
}

#[test]
fn edge_inputs_do_not_panic() {
    for input in [
        "Information listing createdéé\n",
        "Tool Path Listing haé\n",
        "FEDRATé/IPM\nGOTO/1,2,3\n",
        "FEDRAé\n",
        "GOTO/1,2,$",
        "$",
        "$$",
        "CIRCLE/0,0,0,0,0,1,1,TIMES,10000\n",
        "FROM/1,0,0\nCIRCLE/0,0,0,0,0,1,1E300\nGOTO/1,0,0\n",
        "FROM/1E300,0,0\nCIRCLE/0,0,0,0,0,1\nGOTO/-1E300,0,0\n",
        "FROM/0,0,0\nCYCLE/DEEP,FEDTO,1E300,1STPECK,1E-300,SUBPECK,1E-300\nGOTO/0,0,0\n",
        "UNITS/INCHES\nGOTO/1E307,0,0\n",
        "0 0 1\n0 0 0\n7f\n",
        "0 0 1\n0 0 1\nzz\n",
        "FROM/0.7E308,0,0\nCIRCLE/-1E308,0,0,0,0,1\nGOTO/0.7E308,0,0\n",
        "FROM/0,0,0\nCYCLE/DRILL,FEDTO,1E308\nGOTO/-1E308,0,-1E308\n",
    ] {
        run(input.as_bytes()).unwrap_or_else(|e| panic!("{e}\ninput: {input:?}"));
    }
}

// ---------------------------------------------------------------------------------------
// Part 4: properties
// ---------------------------------------------------------------------------------------

/// Runs `bytes` through the streaming parser; checks the blocks and diagnostics.
fn run(bytes: &[u8]) -> Result<(), String> {
    let options = Options {
        arc_tolerance: 0.05,
        ..Options::default()
    };
    let mut parser = Parser::new(bytes, options);
    let mut diags = Vec::new();
    let mut verifier = Verifier;
    let lines = bytes.split(|&b| b == b'\n').count() as u32;
    let mut count = 0usize;
    while let Some(b) = parser.next_block(&mut diags) {
        verifier
            .check(&b)
            .map_err(|e| format!("invariant: {e} in {b:?}"))?;
        count += 1;
        if count > 2_000_000 {
            return Err("too many blocks".into());
        }
    }
    for d in &diags {
        let _ = d.render("input.cl", false);
        let _ = d.to_json("input.cl");
        if d.is_error() && d.code != "cl::empty" && !d.code.starts_with("io::") {
            match &d.location {
                Some(l) if l.line >= 1 && l.line <= lines.max(1) => {}
                _ => return Err(format!("error without a valid line: {d}")),
            }
        }
    }
    Ok(())
}

fn fragment() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("GOTO/".to_string()),
        Just("FROM/".to_string()),
        Just("GODLTA/".to_string()),
        Just("CIRCLE/".to_string()),
        Just("MOVARC/".to_string()),
        Just("CYCLE/DEEP2,FEDTO,".to_string()),
        Just("CYCLE/OFF".to_string()),
        Just("FEDRAT/".to_string()),
        Just("SPINDL/".to_string()),
        Just("TLAXIS/".to_string()),
        Just("MULTAX/OFF".to_string()),
        Just("UNITS/INCHES".to_string()),
        Just("RAPID".to_string()),
        Just("TIMES".to_string()),
        Just("1STPECK".to_string()),
        Just("IPM".to_string()),
        Just("$".to_string()),
        Just("$$".to_string()),
        Just(",".to_string()),
        Just("/".to_string()),
        Just("\n".to_string()),
        Just("\r\n".to_string()),
        Just(" ".to_string()),
        Just("7f\n".to_string()),
        Just("0 0 1\n".to_string()),
        (-1e6f64..1e6).prop_map(|v| format!("{v}")),
        (-3i32..3).prop_map(|v| v.to_string()),
        Just("1E308".to_string()),
        Just("-.5".to_string()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_do_not_panic(input in proptest::collection::vec(any::<u8>(), 0..512)) {
        run(&input).map_err(|e| TestCaseError::fail(format!("{e}\ninput: {:?}", String::from_utf8_lossy(&input))))?;
    }

    #[test]
    fn cl_fragment_soup_does_not_panic(parts in proptest::collection::vec(fragment(), 0..80)) {
        let input = parts.concat();
        run(input.as_bytes()).map_err(|e| TestCaseError::fail(format!("{e}\ninput: {input:?}")))?;
    }
}

/// A number as CAM systems spell it: sign, digits, point, exponent, or too many digits
/// for the fast reader.
fn spelled_number() -> impl Strategy<Value = String> {
    prop_oneof![
        (-1000.0f64..1000.0, 0usize..9).prop_map(|(v, d)| format!("{v:.d$}")),
        (-1.0f64..1.0).prop_map(|v| format!("{v}")),
        (0u32..1000).prop_map(|v| format!("{v}.")),
        (0u32..1000).prop_map(|v| format!("+.{v}")),
        (-9.0f64..9.0).prop_map(|v| format!("{v:.3}E-2")),
        Just("123456789012345678".to_string()),
        Just("1.5.2".to_string()),
        Just("-".to_string()),
        Just(String::new()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// `GOTO/` with plain numbers takes the one-pass reader; `GOTO /` takes the grammar.
    /// Both give the same blocks and the same diagnostics, whatever the spelling, and so
    /// do the one-pass reader's two ways in: lines taken whole from the reader's buffer
    /// (one buffer holds the input) and lines built into statements first (a buffer too
    /// small for any line). Values are compared by their bits (`{:?}` of every block).
    #[test]
    fn plain_goto_reads_as_the_grammar_does(
        values in proptest::collection::vec(spelled_number(), 1..8),
        pad in proptest::collection::vec(prop_oneof![Just(""), Just(" "), Just("\t"), Just("  ")], 16),
        crlf in any::<bool>(),
    ) {
        let mut list = String::new();
        for (i, v) in values.iter().enumerate() {
            if i > 0 {
                list.push(',');
            }
            list.push_str(pad[2 * i % 16]);
            list.push_str(v);
            list.push_str(pad[(2 * i + 1) % 16]);
        }
        let end = if crlf { "\r\n" } else { "\n" };
        // UNITS, MULTAX and FEDRAT end the look at the start of the input: the GOTOs after
        // them come from the reader, where the one-pass reader takes them.
        let source = |head: &str| {
            format!("UNITS/MM\nMULTAX/ON\nFEDRAT/100\n{head}{list}{end}{head}1,2,3{end}{head}{list}{end}")
        };
        let program = |src: &str, capacity: usize| {
            let reader = std::io::BufReader::with_capacity(capacity, src.as_bytes());
            let mut parser = Parser::new(reader, Options::default());
            let mut diags = Vec::new();
            let mut blocks = Vec::new();
            while let Some(b) = parser.next_block(&mut diags) {
                blocks.push(b);
            }
            (blocks, diags)
        };
        let fast = source("GOTO/");
        let (blocks, diags) = program(&fast, 1 << 16);
        let (split_blocks, split_diags) = program(&fast, 1);
        let render = |d: &[Diagnostic]| d.iter().map(|d| d.render("in.cl", false)).collect::<Vec<_>>();
        prop_assert_eq!(format!("{blocks:?}"), format!("{split_blocks:?}"), "list {:?}", list);
        prop_assert_eq!(render(&diags), render(&split_diags), "list {:?}", list);
        let (full_blocks, full_diags) = program(&source("GOTO /"), 1 << 16);
        let said = |d: &[Diagnostic]| d.iter().map(|d| (d.code, d.message.clone())).collect::<Vec<_>>();
        prop_assert_eq!(said(&diags), said(&full_diags), "list {:?}", list);
        if !diags.iter().any(Diagnostic::is_error) {
            let kinds = |b: &[Block]| format!("{:?}", b.iter().map(|b| &b.kind).collect::<Vec<_>>());
            prop_assert_eq!(kinds(&blocks), kinds(&full_blocks), "list {:?}", list);
        }
    }
}
