//! Canned cycles: drilled as G0/G1/G4 moves for RepRapFirmware and Grbl (`expand-cycles`),
//! printed as written, `G80` included, for LinuxCNC (`--emit gcode`).
//!
//! The printed programs are re-read here independently: each G0/G1/G4 line's words are
//! taken from the text and followed in absolute millimetres, and the moves are grouped by
//! hole (a group starts where X or Y moves). Each hole is then checked against what the
//! cycle programs: its X Y, the depth it reaches, the Z of each feed stroke (the pecks),
//! the dwells and the height it retracts to.

mod common;

use std::process::Output;

/// Runs `ncpost run --emit <emit> -` on `program`, with `extra` arguments.
fn run(program: &str, emit: &str, extra: &[&str]) -> Output {
    let mut args = vec!["--emit", emit];
    args.extend_from_slice(extra);
    common::run_stdin(&args, program)
}

/// The printed program of a run that must succeed.
fn succeeded(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    text(out)
}

fn text(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// One step of a printed program: a move (G0 or G1) to X Y Z, or a dwell.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Step {
    Move { rapid: bool, z: f64, f: Option<f64> },
    Dwell(f64),
}

/// The moves made at one X Y: where the tool came over the hole, and what it did there.
#[derive(Debug, Clone, PartialEq)]
struct Hole {
    x: f64,
    y: f64,
    /// The Z the tool moved over the hole at.
    approach_z: f64,
    steps: Vec<Step>,
}

impl Hole {
    fn deepest(&self) -> f64 {
        self.zs().fold(f64::INFINITY, f64::min)
    }
    fn zs(&self) -> impl Iterator<Item = f64> + '_ {
        self.steps.iter().filter_map(|s| match s {
            Step::Move { z, .. } => Some(*z),
            Step::Dwell(_) => None,
        })
    }
    /// The Z the tool is at when it leaves the hole.
    fn retract(&self) -> f64 {
        self.zs().last().unwrap_or(self.approach_z)
    }
    /// The Z each feed (G1) stroke ends at.
    fn feed_ends(&self) -> Vec<f64> {
        self.steps
            .iter()
            .filter_map(|s| match s {
                Step::Move {
                    rapid: false, z, ..
                } => Some(*z),
                _ => None,
            })
            .collect()
    }
    fn dwells(&self) -> Vec<f64> {
        self.steps
            .iter()
            .filter_map(|s| match s {
                Step::Dwell(d) => Some(*d),
                _ => None,
            })
            .collect()
    }
    fn last_feed_rate(&self) -> Option<f64> {
        self.steps.iter().rev().find_map(|s| match s {
            Step::Move { f, .. } => *f,
            _ => None,
        })
    }
}

/// The number after `letter` in the words of `line`.
fn word(line: &str, letter: char) -> Option<f64> {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(letter))
        .map(|v| v.parse().expect("a number"))
}

/// Re-reads a printed RepRapFirmware or Grbl program (absolute mm; G4 P in ms for RRF,
/// seconds for Grbl) into holes. Moves before the first X Y move of a cycle are in the
/// first group.
fn holes(printed: &str, dwell_scale: f64) -> Vec<Hole> {
    let (mut x, mut y, mut z) = (f64::NAN, f64::NAN, f64::NAN);
    let mut feed = None;
    let mut out: Vec<Hole> = Vec::new();
    for line in printed.lines() {
        let line = line.split(';').next().unwrap_or("").trim();
        let first = line.split_whitespace().next().unwrap_or("");
        assert!(
            !line.contains("G91") && !line.contains("G20"),
            "the reader follows G90 G21 only: {line}"
        );
        match first {
            "G0" | "G1" => {
                let (nx, ny) = (word(line, 'X').unwrap_or(x), word(line, 'Y').unwrap_or(y));
                z = word(line, 'Z').unwrap_or(z);
                if let Some(f) = word(line, 'F') {
                    feed = Some(f);
                }
                if nx != x || ny != y {
                    (x, y) = (nx, ny);
                    out.push(Hole {
                        x,
                        y,
                        approach_z: z,
                        steps: Vec::new(),
                    });
                } else if let Some(h) = out.last_mut() {
                    h.steps.push(Step::Move {
                        rapid: first == "G0",
                        z,
                        f: if first == "G1" { feed } else { None },
                    });
                }
            }
            "G4" => {
                let p = word(line, 'P').or(word(line, 'S').map(|s| s * 1000.0));
                let d = p.expect("G4 with P") * dwell_scale;
                out.last_mut()
                    .expect("a dwell over a hole")
                    .steps
                    .push(Step::Dwell(d));
            }
            _ => {}
        }
    }
    out
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-3
}

fn assert_close_all(got: &[f64], want: &[f64], what: &str) {
    assert!(
        got.len() == want.len() && got.iter().zip(want).all(|(a, b)| close(*a, *b)),
        "{what}: got {got:?}, want {want:?}"
    );
}

/// No G73/G8x/G98/G99 word is left in a program drilled as moves.
fn assert_no_cycle_codes(printed: &str) {
    for line in printed.lines() {
        for w in line.split(';').next().unwrap_or("").split_whitespace() {
            let g = w.strip_prefix('G').and_then(|n| n.parse::<f64>().ok());
            assert!(
                !g.is_some_and(|g| g == 73.0
                    || (80.0..=89.0).contains(&g)
                    || g == 98.0
                    || g == 99.0),
                "cycle code left in: {line}"
            );
        }
    }
}

const DRILLS: &str = "\
G21 G90 G17
G0 X0 Y0 Z10
G98 G81 X5 Y5 Z-3 R2 F100
X10
G99 G83 X20 Y5 Z-7 R1 Q3 F120
Y15
G80
G0 X0 Y0 Z20
G98 G82 X1 Y1 Z-1 R2 P500 F90
G73 X30 Y30 Z-2 R1 Q0.8 F60
G85 X40 Y40 Z-4 R1 F50
G89 X50 Y50 Z-5 R1 P250 F40
G80 G0 X0 Y0 (Mach3 writes G80 beside the move)
M30
";

#[test]
fn cycles_are_drilled_as_moves_for_reprapfirmware() {
    let out = run(DRILLS, "rrf", &[]);
    let printed = succeeded(&out);
    assert_no_cycle_codes(&printed);
    let h = holes(&printed, 1.0 / 1000.0);
    // The first group is the start position; then one group per hole, then the park.
    let xy: Vec<(f64, f64)> = h.iter().map(|h| (h.x, h.y)).collect();
    assert_eq!(
        xy,
        [
            (0.0, 0.0),
            (5.0, 5.0),
            (10.0, 5.0),
            (20.0, 5.0),
            (20.0, 15.0),
            (0.0, 0.0),
            (1.0, 1.0),
            (30.0, 30.0),
            (40.0, 40.0),
            (50.0, 50.0),
            (0.0, 0.0)
        ]
    );
    // G81, G98: from Z10 to R2, feed to -3, back to the initial level 10.
    for hole in &h[1..3] {
        assert_eq!(hole.approach_z, 10.0);
        assert_eq!(hole.deepest(), -3.0);
        assert_close_all(&hole.feed_ends(), &[-3.0], "G81 feeds");
        assert_eq!(hole.retract(), 10.0);
        assert_eq!(hole.last_feed_rate(), Some(100.0));
    }
    // G83, G99: pecks of Q3 from R1 to -7, each retracted to R, and back to R.
    assert_eq!(
        h[3].approach_z, 10.0,
        "the first G99 hole is approached at the initial level"
    );
    assert_eq!(h[4].approach_z, 1.0, "G99 leaves the tool at R");
    for hole in &h[3..5] {
        assert_close_all(&hole.feed_ends(), &[-2.0, -5.0, -7.0], "G83 pecks");
        let rapids_up = hole
            .steps
            .iter()
            .filter(|s| matches!(s, Step::Move { rapid: true, z, .. } if *z == 1.0))
            .count();
        assert!(
            rapids_up >= 3,
            "G83 retracts to R between pecks: {:?}",
            hole.steps
        );
        assert_eq!(hole.retract(), 1.0);
        assert_eq!(hole.last_feed_rate(), Some(120.0));
    }
    // G82, G98 from Z20: dwell P500 (ms, as G4 P reads), back to 20.
    assert_eq!(h[6].approach_z, 20.0);
    assert_eq!(h[6].deepest(), -1.0);
    assert_close_all(&h[6].dwells(), &[0.5], "G82 dwell");
    assert_eq!(h[6].retract(), 20.0);
    // G73: chip breaks of 0.254 between pecks of 0.8 down to -2, then back to 20.
    assert_close_all(&h[7].feed_ends(), &[0.2, -0.6, -1.4, -2.0], "G73 pecks");
    let breaks: Vec<f64> = h[7]
        .steps
        .windows(2)
        .filter_map(|w| match w {
            [
                Step::Move {
                    rapid: false, z: a, ..
                },
                Step::Move {
                    rapid: true, z: b, ..
                },
            ] if *b < 1.0 => Some(b - a),
            _ => None,
        })
        .collect();
    assert_close_all(&breaks, &[0.254, 0.254, 0.254], "G73 chip breaks");
    assert_eq!(h[7].retract(), 20.0);
    // G85 feeds in, feeds out to R, then rapids to the retract height (G98: 20), as
    // LinuxCNC's convert_cycle_g85 does.
    assert_close_all(&h[8].feed_ends(), &[-4.0, 1.0], "G85 feeds");
    assert_eq!(h[8].retract(), 20.0);
    // G89: feed in, dwell 0.25 s, feed out.
    assert_close_all(&h[9].feed_ends(), &[-5.0, 20.0], "G89 feeds");
    assert_close_all(&h[9].dwells(), &[0.25], "G89 dwell");
    // Every X Y move is made above the R plane of its hole.
    assert!(h.iter().all(|h| h.approach_z >= 1.0), "{h:?}");
}

#[test]
fn incremental_repeats_in_inches_are_drilled_for_grbl() {
    let program = "\
G20 G90 G17
G0 X0 Y0 Z1
G91 G99 G81 X1 Z-0.5 R-0.5 L3 F5
G90 G80
M30
";
    let out = run(program, "grbl", &[]);
    let printed = succeeded(&out);
    assert_no_cycle_codes(&printed);
    // The reader takes G21 only: Grbl output is in millimetres.
    let h = holes(&printed, 1.0);
    let xs: Vec<f64> = h[1..].iter().map(|h| h.x).collect();
    assert_close_all(&xs, &[25.4, 50.8, 76.2], "L3 holes 1 in apart");
    for hole in &h[1..] {
        // R is 0.5 in below the start (Z1 in), Z 0.5 in below R.
        assert!(close(hole.deepest(), 0.0), "{hole:?}");
        assert!(close(hole.retract(), 12.7), "{hole:?}");
        assert!(
            close(hole.last_feed_rate().unwrap_or(0.0), 127.0),
            "{hole:?}"
        );
    }
    assert!(close(h[1].approach_z, 25.4));
}

#[test]
fn linuxcnc_output_keeps_the_cycles_and_g80() {
    let out = run(DRILLS, "gcode", &[]);
    assert!(out.status.success());
    let printed = text(&out);
    for line in [
        "G98 G81 X5 Y5 Z-3 R2 F100",
        "X10",
        "G99 G83 X20 Y5 Z-7 R1 Q3 F120",
        "G89 X50 Y50 Z-5 R1 P250 F40",
    ] {
        assert!(
            printed.lines().any(|l| l == line),
            "{line} missing:\n{printed}"
        );
    }
    let g80 = |l: &str| l.split_whitespace().any(|w| w == "G80");
    assert_eq!(printed.lines().filter(|l| g80(l)).count(), 2, "{printed}");
}

#[test]
fn tapping_and_missing_words_are_errors_at_their_line() {
    let tap = "G21 G90\nG0 X0 Y0 Z10\nG84 X1 Y1 Z-5 R2 F100\nG80\n";
    let out = run(tap, "rrf", &[]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("G84 cannot be drilled") && err.contains(":3:"),
        "{err}"
    );
    let no_r = "G21 G90\nG0 X0 Y0 Z10\nG81 X1 Y1 Z-5 F100\nG80\n";
    let err = String::from_utf8_lossy(&run(no_r, "rrf", &[]).stderr).into_owned();
    assert!(
        err.contains("no R word") && err.contains(":3:") && err.contains("help"),
        "{err}"
    );
    let unknown_z = "G21 G90\nG28\nG81 X1 Y1 Z-5 R2 F100\nG80\n";
    let err = String::from_utf8_lossy(&run(unknown_z, "rrf", &[]).stderr).into_owned();
    assert!(
        err.contains("Z position before the canned cycle is not known"),
        "{err}"
    );
    let peck = "G21 G90\nG0 X0 Y0 Z10\nG83 X1 Y1 Z-5 R2 F100\nG80\n";
    let err = String::from_utf8_lossy(&run(peck, "rrf", &[]).stderr).into_owned();
    assert!(err.contains("peck depth Q"), "{err}");
}

/// LinuxCNC's own test program (shared corpus, see the fixture's first line): a G81 in
/// a subprogram called three times, with a G91 jog before it. LinuxCNC's expected
/// canonical output (tests/interp/m98m99/01-basics/expected) drills at X1, X2 and X3, to
/// Z-1 from R0.25, and retracts to R0.25 (G99).
#[test]
fn linuxcnc_subprogram_cycle_is_drilled_at_each_call() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/gcode/linuxcnc_m98m99_01_basics.ngc"
    );
    let program = std::fs::read_to_string(path).expect("fixture");
    let out = run(&program, "gcode", &[]);
    assert!(
        text(&out).contains("G90 G99 G81 Z-1.0 R0.25"),
        "kept for LinuxCNC"
    );
    // For RepRapFirmware the body is inlined three times; the jog after each cycle starts
    // where the cycle left the tool.
    let out = run(&program, "rrf", &["--pass", "expand-subprograms"]);
    let printed = succeeded(&out);
    assert_no_cycle_codes(&printed);
    let h = holes(&printed, 1.0 / 1000.0);
    let drilled: Vec<&Hole> = h.iter().filter(|h| !h.feed_ends().is_empty()).collect();
    let xs: Vec<f64> = drilled.iter().map(|h| h.x).collect();
    assert_close_all(&xs, &[1.0, 2.0, 3.0], "holes");
    for hole in drilled {
        assert_eq!(hole.y, 0.0);
        assert_close_all(&hole.feed_ends(), &[-1.0], "depth");
        assert_eq!(hole.retract(), 0.25);
        assert_eq!(hole.last_feed_rate(), Some(40.0));
    }
}

/// Drilled cycle lines carry no "passes through unchanged" warning from the frontend: the
/// pass takes it back on the lines it drills.
#[test]
fn drilled_lines_are_not_said_to_pass_through() {
    let preset = ncpost::preset::Preset::builtin("duet-cnc").expect("preset");
    let mut pipeline = ncpost::pipeline::Pipeline::builder()
        .preset(preset)
        .build()
        .expect("builds");
    let (mut out, mut diags) = (Vec::new(), Vec::new());
    let src = "G0 X0 Y0 Z10\nG81 X1 Y1 Z-1 R2 F100\nX2 Y2\nG80\nG0 Z10\n";
    pipeline
        .run_gcode(src.as_bytes(), &mut out, &mut |d| diags.push(d))
        .expect("runs");
    assert!(
        !diags.iter().any(|d| d.code == "gcode::unsupported-motion"),
        "{diags:?}"
    );
    let text = String::from_utf8(out).expect("text");
    assert!(!text.contains("G81"), "{text}");
}

/// The position after each G0/G1 line of a printed program, X Y Z absolute, following
/// G90/G91 as the controller would (the backends print absolute moves, so G91 is a sign
/// that a move was left unresolved).
fn positions(printed: &str) -> Vec<(String, [f64; 3])> {
    let mut pos = [f64::NAN; 3];
    let mut relative = false;
    let mut out = Vec::new();
    for line in printed.lines() {
        let line = line.split(';').next().unwrap_or("").trim();
        let words: Vec<&str> = line.split_whitespace().collect();
        if words.contains(&"G91") {
            relative = true;
        }
        if words.contains(&"G90") {
            relative = false;
        }
        if !words.iter().any(|w| matches!(*w, "G0" | "G1")) {
            continue;
        }
        for (k, l) in ['X', 'Y', 'Z'].into_iter().enumerate() {
            if let Some(v) = word(line, l) {
                pos[k] = if relative { pos[k] + v } else { v };
            }
        }
        out.push((line.to_string(), pos));
    }
    out
}

/// The moves printed after the last line that drills (the last G1 down a hole): where the
/// program goes once the cycles are done.
fn after_cycles<'a>(
    moves: &'a [(String, [f64; 3])],
    first_after: &str,
) -> &'a [(String, [f64; 3])] {
    let at = moves
        .iter()
        .position(|(l, _)| l == first_after)
        .unwrap_or_else(|| panic!("`{first_after}` not printed: {moves:?}"));
    &moves[at..]
}

fn assert_at(got: [f64; 3], want: [f64; 3], what: &str) {
    assert!(
        got.iter().zip(want).all(|(a, b)| close(*a, b)),
        "{what}: at {got:?}, want {want:?}"
    );
}

/// An absolute (G90) series, then incremental moves: each starts where the last hole
/// retracted to (G99: the R plane), for RepRapFirmware (drilled) and LinuxCNC (kept).
#[test]
fn incremental_moves_after_a_g90_cycle_start_at_the_last_hole() {
    let program = "\
G21 G90 G17
G0 X0 Y0 Z10
G99 G81 X5 Y5 Z-3 R2 F100
X10
G80
G91 G1 Z-1 F50
X5
G90 G0 Z20
M30
";
    let printed = succeeded(&run(program, "rrf", &[]));
    assert_no_cycle_codes(&printed);
    let drilling = printed.split("G1 Z1 F50").next().unwrap_or("");
    let h = holes(drilling, 1.0 / 1000.0);
    let xy: Vec<(f64, f64)> = h[1..3].iter().map(|h| (h.x, h.y)).collect();
    assert_eq!(xy, [(5.0, 5.0), (10.0, 5.0)]);
    for hole in &h[1..3] {
        assert_close_all(&hole.feed_ends(), &[-3.0], "depth");
        assert_eq!(hole.retract(), 2.0, "G99: back to R");
    }
    let moves = positions(&printed);
    assert!(!printed.contains("G91"), "every move resolved:\n{printed}");
    // G91 Z-1 from the R plane of the last hole, then X+5 there, then Z20.
    let after = after_cycles(&moves, "G1 Z1 F50");
    assert_at(after[0].1, [10.0, 5.0, 1.0], "G91 Z-1 after the cycle");
    assert_at(after[1].1, [15.0, 5.0, 1.0], "G91 X5");
    assert_at(after[2].1, [15.0, 5.0, 20.0], "G90 Z20");
    // LinuxCNC keeps the cycle and gets the moves after it in absolute coordinates.
    let printed = succeeded(&run(program, "gcode", &[]));
    assert!(printed.contains("G99 G81 X5 Y5 Z-3 R2 F100") && printed.contains("G80"));
    let moves = positions(&printed);
    let after = moves
        .iter()
        .find(|(l, _)| l.starts_with("G1"))
        .expect("a feed move after the cycle");
    assert!(!after.0.contains("G91"), "{printed}");
    assert_at(after.1, [10.0, 5.0, 1.0], "the first move after the cycle");
}

/// A G91 series (LinuxCNC's example 2 and Fanuc's rule: R from the initial level, Z from
/// R, X Y stepped at each repeat) over several lines, with G99 and then G98.
#[test]
fn g91_series_measures_r_from_the_initial_level_on_every_line() {
    let program = "\
G21 G90 G17
G0 X1 Y2 Z10
G91 G99 G81 X4 Y5 Z-6 R-8 L2 F100
X10 Y0
G98 X0 Y-5
G80
G1 Z-1 F50
G90 G0 X0 Y0
M30
";
    let printed = succeeded(&run(program, "rrf", &[]));
    assert_no_cycle_codes(&printed);
    let drilling = printed.split("G1 Z9 F50").next().unwrap_or("");
    let h = holes(drilling, 1.0 / 1000.0);
    let drilled: Vec<&Hole> = h.iter().filter(|h| !h.feed_ends().is_empty()).collect();
    let xy: Vec<(f64, f64)> = drilled.iter().map(|h| (h.x, h.y)).collect();
    assert_eq!(xy, [(5.0, 7.0), (9.0, 12.0), (19.0, 12.0), (19.0, 7.0)]);
    // Every line: R = 10 - 8 = 2 and bottom = 2 - 6 = -4 (not from the Z the tool is
    // at, which would sink each line 8 mm deeper).
    for hole in &drilled {
        assert_close_all(&hole.feed_ends(), &[-4.0], "depth");
    }
    let retracts: Vec<f64> = drilled.iter().map(|h| h.retract()).collect();
    assert_close_all(
        &retracts,
        &[2.0, 2.0, 2.0, 10.0],
        "G99 to R, then G98 to Z10",
    );
    // After G80, still G91: Z-1 from the initial level the last hole went back to.
    let moves = positions(&printed);
    assert!(!printed.contains("G91"), "every move resolved:\n{printed}");
    let after = after_cycles(&moves, "G1 Z9 F50");
    assert_at(after[0].1, [19.0, 7.0, 9.0], "G91 Z-1 after the cycle");
    assert_at(after[1].1, [0.0, 0.0, 9.0], "G90 X0 Y0");
}

/// G98 returns to the Z before the series began, even after G99 holes of the same series
/// left the tool at R (LinuxCNC G-code reference, "G98, G99": "retract to the position
/// that axis was in just before this series of one or more contiguous canned cycles was
/// started").
#[test]
fn g98_returns_to_the_level_before_the_series() {
    let program = "\
G21 G90 G17
G0 X0 Y0 Z15
G99 G81 X1 Y1 Z-2 R3 F100
G98 X2
G83 X3 Q1
G80
G0 Z30
M30
";
    let printed = succeeded(&run(program, "grbl", &[]));
    let h = holes(printed.split("G0 Z30").next().unwrap_or(""), 1.0);
    let drilled: Vec<&Hole> = h.iter().filter(|h| !h.feed_ends().is_empty()).collect();
    let retracts: Vec<f64> = drilled.iter().map(|h| h.retract()).collect();
    assert_close_all(&retracts, &[3.0, 15.0, 15.0], "G99 to R3, then G98 to Z15");
    // Switching G81 to G83 keeps the series, its R and Z: pecks of 1 from R3 to -2.
    assert_close_all(
        &drilled[2].feed_ends(),
        &[2.0, 1.0, 0.0, -1.0, -2.0],
        "G83 pecks",
    );
}

/// The dwell P of a cycle counts as `G4 P` does, on LinuxCNC (seconds for both, G-code
/// reference, G82: "Dwell for the P number of seconds") and on Fanuc (milliseconds for
/// both): `gcode_input.dwell_p_milliseconds`, `true` by default.
#[test]
fn cycle_dwell_counts_as_g4_p() {
    let body = "G21 G90 G17\nG0 X0 Y0 Z5\nG4 P{P}\nG82 X1 Y1 Z-1 R1 P{P} F100\nG80\nM30\n";
    for (ms, p, seconds) in [(true, "250", 0.25), (false, "0.5", 0.5)] {
        let mut preset = ncpost::preset::Preset::builtin("duet-cnc").expect("preset");
        preset.gcode_input.dwell_p_milliseconds = ms;
        let program = body.replace("{P}", p);
        let printed = ncpost::pipeline::compile_str(&program, &preset).expect("drilled");
        // RepRapFirmware's G4 P counts milliseconds.
        let h = holes(&printed, 1.0 / 1000.0);
        assert_close_all(&h[0].dwells(), &[seconds], "G4 P");
        assert_close_all(&h[1].dwells(), &[seconds], "G82 P");
    }
}

/// The repeat count: L on LinuxCNC (L0 refused, as LinuxCNC does), K on Fanuc (K0 stores
/// the cycle's words and drills nothing).
#[test]
fn l0_is_refused_and_fanuc_k0_drills_nothing() {
    let l0 = "G21 G90\nG0 X0 Y0 Z5\nG91 G81 X1 Z-1 R-4 L0 F100\nG80\n";
    let out = run(l0, "rrf", &[]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("`L0`") && err.contains(":3:"), "{err}");
    let k0 = "(FANUC)\nG21 G90\nG0 X0 Y0 Z5\nG91 G81 X1 Z-1 R-4 K0 F100\nX2 K2\nG80\n";
    let printed = succeeded(&run(k0, "rrf", &[]));
    let h = holes(&printed, 1.0 / 1000.0);
    let xs: Vec<f64> = h
        .iter()
        .filter(|h| !h.feed_ends().is_empty())
        .map(|h| h.x)
        .collect();
    // K0 stored R, Z and the feed; the next line drills twice, 2 apart, from X0.
    assert_close_all(&xs, &[2.0, 4.0], "K2 after K0");
}

/// After homing, a G90 cycle that writes X and Y needs only a known Z: the first rapid goes
/// to the hole, and the moves after the cycle start from it.
#[test]
fn g90_cycle_after_homing_needs_only_z() {
    let program = "G21 G90\nG28\nG0 Z10\nG81 X5 Y5 Z-1 R2 F100\nX8\nG80\nG91 G0 X1\nM30\n";
    let printed = succeeded(&run(program, "rrf", &[]));
    let moves = positions(&printed);
    let last = moves.last().expect("moves");
    assert_eq!(last.0, "G0 X9", "{printed}");
    assert_at(last.1, [9.0, 5.0, 10.0], "G91 X1 after the cycle");
    let drilled: Vec<&(String, [f64; 3])> =
        moves.iter().filter(|(l, _)| l.starts_with("G1")).collect();
    assert_eq!(drilled.len(), 2, "{printed}");
    assert_at(drilled[0].1, [5.0, 5.0, -1.0], "first hole");
    assert_at(drilled[1].1, [8.0, 5.0, -1.0], "second hole");
}

/// A subprogram that leaves a G91 G99 G81 series in force (LinuxCNC keeps modal state
/// across M99, and the series' initial level with it: interp_cycles.cc keeps `cycle_il`
/// until a motion code that is not a cycle): after the call a bare `X1` drills one more
/// hole 1 on, and a restated `G91 G99 G81` line continues the same series, so its R is
/// still measured from the initial level Z0.25 before the first call (EMC handbook,
/// "Canned Cycles": "In incremental distance mode, X, Y, and R values are treated as
/// increments to the current position and Z as an increment from the Z-axis position
/// before the move involving Z"; https://emc.sourceforge.net/Handbook/node66.html).
/// Every hole: R 0.5, bottom -0.5, retract to R. Read back from the printed program, for
/// RepRapFirmware and Grbl.
#[test]
fn a_series_left_by_a_subprogram_continues_after_the_call() {
    let program = "\
G21 G90 G17
G0 X0 Y0 Z0.25
M98 P1 L2
X1
G91 G99 G81 X1 Z-1 R0.25 F40
G90 G80 G0 Z5
M30
O1
G91 G99 G81 X1 Z-1.0 R0.25 F40
M99
";
    for emit in ["rrf", "grbl"] {
        let printed = succeeded(&run(program, emit, &["--pass", "expand-subprograms"]));
        assert_no_cycle_codes(&printed);
        let h = holes(&printed, 1.0);
        let drilled: Vec<&Hole> = h.iter().filter(|h| !h.feed_ends().is_empty()).collect();
        let xs: Vec<f64> = drilled.iter().map(|h| h.x).collect();
        assert_close_all(&xs, &[1.0, 2.0, 3.0, 4.0], emit);
        for hole in drilled {
            assert_eq!(hole.y, 0.0, "{emit}");
            assert_close_all(&hole.feed_ends(), &[-0.5], emit);
            // Fed to the bottom, then back to R (G99); the last hole then goes on to Z5.
            let zs: Vec<f64> = hole.zs().collect();
            assert!(zs.windows(2).any(|w| w == [-0.5, 0.5]), "{emit}: {zs:?}");
            assert_eq!(hole.approach_z, 0.5, "{emit}: over the hole at R");
        }
    }
}
