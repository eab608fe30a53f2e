//! The `expand-subprograms` pass: the seed's `M98 P10 L625` program (625 plunges, positions
//! and feeds), every LinuxCNC M98/M99 corpus fixture (expanded G-code and diagnostics,
//! snapshotted), nesting limits, recursion, missing programs and bad counts (diagnostic
//! snapshots, plain rendering), the state carried into and out of bodies (modes, feed,
//! G92 offsets, positions), and a property test: a generated program with calls expands to
//! the same IR as the same program inlined by hand.

mod common;

use std::path::Path;

use ncpost::back::gcode;
use ncpost::diag::Diagnostic;
use ncpost::front::Frontend;
use ncpost::front::gcode::{Options, Parser};
use ncpost::ir::{Axis, Block, BlockKind, MotionKind, Target, dump};
use ncpost::passes::{self, Context, Output};
use proptest::prelude::*;

/// Frontend, then `expand-subprograms` with `options`: blocks and every diagnostic.
fn expand_with(src: &str, options: &str) -> (Vec<Block>, Vec<Diagnostic>) {
    let mut parser = Parser::new(src.as_bytes(), Options::default());
    let mut diags = Vec::new();
    let table: toml::Table = toml::from_str(options).unwrap();
    let ctx = Context {
        relower: Some(ncpost::pipeline::gcode_relower),
        ..Context::default()
    };
    let mut pass = passes::build("expand-subprograms", &table, &ctx).unwrap();
    let mut blocks = Vec::new();
    while let Some(b) = parser.next_block(&mut diags) {
        let mut out = Output::new(&mut blocks, &mut diags);
        pass.run(&mut vec![b], &mut out);
    }
    let mut out = Output::new(&mut blocks, &mut diags);
    pass.finish(&mut out);
    (blocks, diags)
}

fn expand(src: &str) -> (Vec<Block>, Vec<Diagnostic>) {
    expand_with(src, "")
}

/// The frontend alone.
fn lower(src: &str) -> Vec<Block> {
    let mut parser = Parser::new(src.as_bytes(), Options::default());
    let mut diags = Vec::new();
    let mut blocks = Vec::new();
    while let Some(b) = parser.next_block(&mut diags) {
        blocks.push(b);
    }
    blocks
}

fn errors(diags: &[Diagnostic]) -> Vec<&Diagnostic> {
    diags.iter().filter(|d| d.is_error()).collect()
}

fn render_all(file: &str, diags: &[Diagnostic]) -> String {
    diags
        .iter()
        .map(|d| d.render(file, false))
        .collect::<Vec<_>>()
        .join("\n")
}

fn fixture(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/subprograms")
        .join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn motions(blocks: &[Block]) -> Vec<(&ncpost::ir::Motion, &ncpost::ir::Joints)> {
    blocks
        .iter()
        .filter_map(|b| match &b.kind {
            BlockKind::Motion(m) => match &m.target {
                Target::Joints(j) => Some((m, j)),
                Target::Pose(_) => None,
            },
            _ => None,
        })
        .collect()
}

fn is_call_or_body(b: &Block) -> bool {
    match &b.kind {
        BlockKind::Command(c) => c.text.contains("M98") || c.text.contains("M99"),
        BlockKind::Verbatim(v) => v.reason == ncpost::ir::VerbatimReason::Subprogram,
        _ => false,
    }
}

/// Whether a block's text or comments contain `needle`.
fn mentions(b: &Block, needle: &str) -> bool {
    b.comments.iter().any(|c| c.text.contains(needle))
        || matches!(&b.kind, BlockKind::Verbatim(v) if v.text.contains(needle))
}

#[test]
fn seed_program_expands_to_625_plunges() {
    let (blocks, diags) = expand(&fixture("seed_001_z_check.ngc"));
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert!(
        !blocks.iter().any(is_call_or_body),
        "a call or body is left"
    );
    let moves = motions(&blocks);
    // G00 Z1, then 625 x (G00 Z0.1, G01 Z0.04 F20, G00 Z1), then G00 Z0.
    assert_eq!(moves.len(), 1 + 625 * 3 + 1);
    let plunges: Vec<_> = moves
        .iter()
        .filter(|(m, _)| matches!(m.kind, MotionKind::Linear))
        .collect();
    assert_eq!(plunges.len(), 625, "one G01 plunge per repetition");
    for (m, j) in &plunges {
        assert_eq!(j.get(Axis::Z), Some(0.04));
        assert_eq!(m.feed.rate, Some(20.0));
        // G92 X0 Y0 Z0 made X and Y known; the body keeps them.
        assert_eq!((j.get(Axis::X), j.get(Axis::Y)), (Some(0.0), Some(0.0)));
    }
    for (k, (m, j)) in moves[1..moves.len() - 1].iter().enumerate() {
        let z = [0.1, 0.04, 1.0][k % 3];
        assert_eq!(j.get(Axis::Z), Some(z), "move {k}");
        assert_eq!(matches!(m.kind, MotionKind::Rapid), k % 3 != 1);
    }
    // After the call the frontend knew nothing; the pass restored X, Y (and E) and the
    // feed the body left in force.
    let (last_m, last) = moves[moves.len() - 1];
    assert_eq!(last.get(Axis::Z), Some(0.0));
    assert_eq!(
        (last.get(Axis::X), last.get(Axis::Y)),
        (Some(0.0), Some(0.0))
    );
    assert_eq!(last_m.feed.rate, Some(20.0));
    // Spans: body blocks point at the body's lines (9-11 of the fixture).
    assert_eq!(plunges[0].0.kind, MotionKind::Linear);
    let lines: Vec<u32> = blocks
        .iter()
        .filter(|b| matches!(b.kind, BlockKind::Motion(_)))
        .map(|b| b.span.line)
        .collect();
    assert_eq!(&lines[..4], &[4, 9, 10, 11]);
    assert_eq!(lines[lines.len() - 1], 6);
    // The plain output runs no subprogram and plunges 625 times.
    let text = gcode::write_string(&blocks, &gcode::Options::default()).unwrap();
    assert!(
        !text
            .lines()
            .any(|l| l.starts_with("M98") || l.starts_with("M99") || l.starts_with('O')),
        "{text}"
    );
    assert_eq!(
        text.lines().filter(|l| l.starts_with("G1 Z0.04")).count(),
        625
    );
    assert_eq!(text.matches("F20").count(), 1, "F is modal");
}

/// Every LinuxCNC M98/M99 corpus file: the expanded G-code (plain backend) and every
/// diagnostic, one snapshot per fixture.
#[test]
fn corpus_fixtures() {
    for name in [
        "linuxcnc_m98m99_01_basics.ngc",
        "linuxcnc_m98m99_02_variables.ngc",
        "linuxcnc_m98m99_05_loops.ngc",
        "linuxcnc_m98m99_07_nested.ngc",
        "linuxcnc_m98m99_10_P0002.ngc",
        "linuxcnc_m98m99_12_endless_main.ngc",
        "linuxcnc_m98m99_14_o_expression_call.ngc",
        "linuxcnc_interp_test_sub.ngc",
        "seed_001_z_check.ngc",
    ] {
        let src = fixture(name);
        let (blocks, diags) = expand(&src);
        let mut out = Vec::new();
        let back = ncpost::back::write_blocks(
            &mut gcode::Writer::new(&mut out, &gcode::Options::default()),
            &blocks,
        );
        let mut text = String::from_utf8(out).unwrap();
        if name.starts_with("seed") {
            // 625 repetitions: the first and the last are enough to read.
            let lines: Vec<&str> = text.lines().collect();
            text = format!(
                "{}\n... ({} lines)\n{}\n",
                lines[..8].join("\n"),
                lines.len(),
                lines[lines.len() - 4..].join("\n")
            );
        }
        let snap = format!(
            "---- output ----\n{text}---- diagnostics ----\n{}{}",
            render_all(name, &diags),
            render_all(name, &back)
        );
        insta::assert_snapshot!(name.trim_end_matches(".ngc"), snap);
    }
}

#[test]
fn basics_numbers() {
    // 01: three times `G91 G0 X1` from X0, then a canned cycle the IR does not model.
    let (blocks, diags) = expand(&fixture("linuxcnc_m98m99_01_basics.ngc"));
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let xs: Vec<f64> = motions(&blocks)
        .iter()
        .filter_map(|(_, j)| j.get(Axis::X))
        .collect();
    // The file has no G20, so X1 is 1 mm. The first repetition starts at the known X0;
    // the canned cycle leaves the tool over its hole (at R, G99), so the next two
    // relative moves start there: X2 and X3, as in LinuxCNC's expected output.
    assert_eq!(xs, vec![0.0, 1.0, 2.0, 3.0]);
    let verbatim = |needle: &str| {
        blocks
            .iter()
            .filter(|b| matches!(&b.kind, BlockKind::Verbatim(v) if v.text.contains(needle)))
            .count()
    };
    assert_eq!(verbatim("G81"), 3);
    assert_eq!(verbatim("G91 G0 X1"), 0);
}

#[test]
fn nested_calls_multiply() {
    // 07: O2 five times, each calling O1 five times: 25 runs of O1's (PRINT) line.
    let (blocks, diags) = expand(&fixture("linuxcnc_m98m99_07_nested.ngc"));
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let prints = |needle: &str| blocks.iter().filter(|b| mentions(b, needle)).count();
    assert_eq!(prints(">>>> LOOP"), 25);
    assert_eq!(prints("O2 END"), 5);
    assert!(!blocks.iter().any(is_call_or_body));
}

/// A chain O1 -> O2 -> ... -> O`levels`, each body one move.
fn chain(levels: u32) -> String {
    let mut s = String::from("G0 X0 Y0 Z0\nM98 P1\nG0 Z5\nM30\n");
    for n in 1..=levels {
        s.push_str(&format!("O{n}\nG1 X{n} F100\n"));
        if n < levels {
            s.push_str(&format!("M98 P{}\n", n + 1));
        }
        s.push_str("M99\n");
    }
    s
}

#[test]
fn ten_levels_expand_eleven_do_not() {
    let (blocks, diags) = expand(&chain(10));
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let xs: Vec<f64> = motions(&blocks)
        .iter()
        .filter(|(m, _)| matches!(m.kind, MotionKind::Linear))
        .map(|(_, j)| j.get(Axis::X).unwrap())
        .collect();
    assert_eq!(xs, (1..=10).map(f64::from).collect::<Vec<_>>());

    let src = chain(11);
    let (_, diags) = expand(&src);
    let errs = errors(&diags);
    assert_eq!(errs.len(), 1, "{diags:?}");
    assert_eq!(errs[0].code, "subprograms::depth");
    // Points at the innermost call, `M98 P11` in O10's body.
    let loc = errs[0].location.as_ref().unwrap();
    let line = src.lines().nth(loc.line as usize - 1).unwrap();
    assert_eq!(line, "M98 P11");
    assert_eq!(loc.column, 1);
    insta::assert_snapshot!("depth_eleven", render_all("chain11.ngc", &diags));
}

#[test]
fn error_snapshots() {
    let cases = [
        (
            "recursion",
            "G0 X0\nM98 P1\nM30\nO1\nG1 X1 F10\nM98 P2\nM99\nO2\nM98 P1 L2\nM99\n",
            "subprograms::recursion",
            (9, 1),
        ),
        (
            "missing",
            "G0 X0\nM98 P7 L2\nM30\nO1\nG1 X1 F10\nM99\n",
            "subprograms::missing",
            (2, 1),
        ),
        (
            "count_fraction",
            "M98 P1 L2.5\nM30\nO1\nG0 X1\nM99\n",
            "subprograms::count",
            (1, 8),
        ),
        (
            "count_negative",
            "M98 P1 L-3\nM30\nO1\nG0 X1\nM99\n",
            "subprograms::count",
            (1, 8),
        ),
        (
            "count_huge",
            "M98 P1 L100000\nM30\nO1\nG0 X1\nM99\n",
            "subprograms::count",
            (1, 8),
        ),
        (
            "missing_packed_hint",
            "G0 X0\nM98 P30010\nM30\nO10\nG0 X1\nM99\n",
            "subprograms::missing",
            (2, 1),
        ),
        (
            "modes_left_g20",
            "G0 X0\nM98 P1\nG90 G0 X5\nM30\nO1\nG20 G0 X1\nM99\n",
            "subprograms::modes",
            (2, 1),
        ),
        // A bare X after a body that left G2 in force is an arc without a centre.
        (
            "modes_left_arc",
            "G0 X0 Y0 Z1\nM98 P1\nX5\nM30\nO1\nG1 X1 F100\nG2 X2 Y0 I0.5 J0\nM99\n",
            "subprograms::modes",
            (3, 1),
        ),
        (
            "no_m99",
            "G0 X0\nM98 P1\nM30\nO1\nG0 X1\n",
            "subprograms::no-m99",
            (4, 1),
        ),
        (
            "oword_missing",
            "o7 call\nM2\n",
            "subprograms::missing",
            (1, 1),
        ),
    ];
    for (name, src, code, (line, column)) in cases {
        let (_, diags) = expand(src);
        let errs = errors(&diags);
        assert_eq!(errs.len(), 1, "{name}: {diags:?}");
        assert_eq!(errs[0].code, code, "{name}");
        let loc = errs[0].location.as_ref().unwrap();
        assert_eq!((loc.line, loc.column), (line, column), "{name}");
        insta::assert_snapshot!(name, render_all(&format!("{name}.ngc"), &diags));
    }
}

#[test]
fn packed_count_option() {
    let src = "G0 X0\nM98 P30010\nM30\nO10\nG91 G1 X1 F50\nG90\nM99\n";
    let (blocks, diags) = expand_with(src, "packed_count = true");
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let xs: Vec<f64> = motions(&blocks)
        .iter()
        .map(|(_, j)| j.get(Axis::X).unwrap())
        .collect();
    assert_eq!(xs, vec![0.0, 1.0, 2.0, 3.0]);
}

#[test]
fn program_numbers_are_numbers() {
    // 10: P0002 calls the first definition of number 2; the second is a warning.
    let (blocks, diags) = expand(&fixture("linuxcnc_m98m99_10_P0002.ngc"));
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert!(diags.iter().any(|d| d.code == "subprograms::duplicate"));
    assert_eq!(blocks.iter().filter(|b| mentions(b, "got here")).count(), 1);
    assert!(!blocks.iter().any(|b| mentions(b, "should not get here")));
}

#[test]
fn calls_that_cannot_be_expanded_keep_their_definitions() {
    // 14: `O[#2 * 10] call` and `M98 P[expr]`: both pass through, with the subprograms.
    let (blocks, diags) = expand(&fixture("linuxcnc_m98m99_14_o_expression_call.ngc"));
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert_eq!(
        diags
            .iter()
            .filter(|d| d.code == "subprograms::not-expanded")
            .count(),
        2
    );
    let text = gcode::write_string(&blocks, &gcode::Options::default()).unwrap();
    assert!(text.contains("O100 sub") && text.contains("O200"), "{text}");
    // interp_test_sub: calls with arguments; the subroutines stay before them.
    let (blocks, diags) = expand(&fixture("linuxcnc_interp_test_sub.ngc"));
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let text = gcode::write_string(&blocks, &gcode::Options::default()).unwrap();
    let sub = text.find("o100 sub").unwrap();
    let call = text.find("o100 call").unwrap();
    assert!(sub < call, "{text}");
}

#[test]
fn oword_subroutine_expands_in_the_callers_modes() {
    // G20 G91 in force at the calls: the body's X10 is 10 inches, relative, twice; the
    // relative G1 Y1 after the calls (unknown to the frontend) is lowered again here.
    let src = "o<zig> sub\nG1 X10 F3\no<zig> endsub\nG20\nG0 X0 Y0\nG91\no<zig> call\no<zig> call\nG1 Y1\nG90\nM2\n";
    let (blocks, diags) = expand(src);
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let moves = motions(&blocks);
    let xs: Vec<f64> = moves.iter().map(|(_, j)| j.get(Axis::X).unwrap()).collect();
    assert_eq!(xs, vec![0.0, 254.0, 508.0, 508.0]);
    // Feed: F3 in/min from the body is in force after the call.
    assert_eq!(moves[3].0.feed.rate, Some(3.0 * 25.4));
    assert_eq!(moves[3].1.get(Axis::Y), Some(25.4));
}

#[test]
fn g92_inside_a_body_shifts_the_lines_after_the_call() {
    // The body declares X=0 at X=10; the main program's X5 after the call is then X15
    // in the frame the machine moves in.
    let src = "G0 X10 Y0\nM98 P1\nG0 X5\nG0 Y1\nM30\nO1\nG92 X0\nM99\n";
    let (blocks, diags) = expand(src);
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let moves = motions(&blocks);
    let last = moves.last().unwrap().1;
    assert_eq!(last.get(Axis::X), Some(15.0));
    assert_eq!(moves[1].1.get(Axis::X), Some(15.0));
    let text = gcode::write_string(&blocks, &gcode::Options::default()).unwrap();
    assert!(text.contains("G92 X0\nG0 X5\n"), "{text}");
}

#[test]
fn main_m99_is_a_warning_and_passes_through() {
    let (blocks, diags) = expand(&fixture("linuxcnc_m98m99_12_endless_main.ngc"));
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert!(diags.iter().any(|d| d.code == "subprograms::main-m99"));
    // The call to O100 is expanded (its G1 Y-4), the main M99 stays.
    assert!(
        motions(&blocks)
            .iter()
            .any(|(_, j)| j.get(Axis::Y) == Some(-4.0))
    );
    assert!(
        blocks
            .iter()
            .any(|b| matches!(&b.kind, BlockKind::Command(c) if c.text == "M99"))
    );
}

#[test]
fn programs_without_calls_are_unchanged() {
    let src = "G21 G90\nG0 X1 Y2\nG1 Z-1 F100\nG2 X3 Y2 I1 J0\nM30\n";
    let (blocks, diags) = expand(src);
    assert!(diags.is_empty(), "{diags:?}");
    assert_eq!(blocks, lower(src));
}

fn dump_all(blocks: &[Block]) -> Vec<String> {
    blocks
        .iter()
        .map(|b| {
            let mut s = String::new();
            dump::write_block(&mut s, b);
            // Spans differ (body lines vs inlined lines): compare from the colon on.
            s.split_once(": ").map(|x| x.1.to_string()).unwrap_or(s)
        })
        .collect()
}

/// A generated body line: absolute or relative moves, feeds, units and G92.
fn body_line() -> impl Strategy<Value = String> {
    prop_oneof![
        (-50i32..50, -50i32..50).prop_map(|(x, y)| format!("G0 X{x} Y{y}")),
        (-50i32..50, 1u32..500).prop_map(|(z, f)| format!("G1 Z{} F{f}", z as f64 / 10.0)),
        (-9i32..9).prop_map(|x| format!("G91 G1 X{x}\nG90")),
        (-9i32..9).prop_map(|y| format!("G1 Y{y}")),
        (1i32..9).prop_map(|x| format!("G20 G0 X{x}\nG21")),
        Just("G92 X0".to_string()),
        Just("G92.1".to_string()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// A main program calling two subprograms (one also calling the other), with repeat
    /// counts, gives the same IR as the program with every call written out.
    #[test]
    fn expansion_equals_hand_inlining(
        main in prop::collection::vec(body_line(), 0..4),
        tail in prop::collection::vec(body_line(), 0..3),
        o1 in prop::collection::vec(body_line(), 1..4),
        o2 in prop::collection::vec(body_line(), 1..3),
        l1 in 1u32..4,
        l2 in 1u32..3,
    ) {
        let start = "G0 X1 Y2 Z3\n";
        let o1_text = o1.join("\n");
        let o2_text = o2.join("\n");
        let with_calls = format!(
            "{start}{}\nM98 P1 L{l1}\n{}\nM30\nO1\n{o1_text}\nM98 P2 L{l2}\nM99\nO2\n{o2_text}\nM99\n",
            main.join("\n"),
            tail.join("\n"),
        );
        let mut inlined = format!("{start}{}\n", main.join("\n"));
        for _ in 0..l1 {
            inlined.push_str(&o1_text);
            inlined.push('\n');
            for _ in 0..l2 {
                inlined.push_str(&o2_text);
                inlined.push('\n');
            }
        }
        inlined.push_str(&format!("{}\nM30\n", tail.join("\n")));
        let (expanded, diags) = expand(&with_calls);
        prop_assert!(errors(&diags).is_empty(), "{:?}", diags);
        let by_hand = lower(&inlined);
        prop_assert_eq!(dump_all(&expanded), dump_all(&by_hand), "{}", with_calls);
    }
}

/// Bodies are lowered with the preset's `[gcode_input]`, and the pass's `input` table
/// changes single fields of it: `G4 P500` in a body is half a second under the default
/// (milliseconds) and 500 seconds when the pass's input says P counts seconds, and an
/// unknown field is a settings error.
#[test]
fn pass_input_changes_the_frontend_options() {
    let program = "M98 P1000\nM30\nO1000\nG4 P500\nM99\n";
    let dwell = |input: &str| -> Result<String, Vec<ncpost::diag::Diagnostic>> {
        let text = format!(
            "emit = \"ir\"\n[[passes]]\nname = \"expand-subprograms\"\n[passes.options.input]\n{input}\n"
        );
        let preset = ncpost::preset::Preset::from_toml(&text).expect("preset");
        ncpost::pipeline::compile_str(program, &preset)
    };
    let ms = dwell("").expect("compiles");
    assert!(ms.contains("dwell 0.5000s"), "{ms}");
    let s = dwell("dwell_p_milliseconds = false").expect("compiles");
    assert!(s.contains("dwell 500.0000s"), "{s}");
    let bad = dwell("dwell_p_seconds = true").expect_err("unknown field");
    assert!(bad[0].message.contains("dwell_p_seconds"), "{:?}", bad[0]);
}

/// Runs `ncpost run <args> -` (the binary) on `program`: success, printed program, stderr.
fn run_cli(program: &str, args: &[&str]) -> (bool, String, String) {
    let out = common::run_stdin(args, program);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `program` for RepRapFirmware (`--preset duet-cnc`), which must compile without
/// diagnostics of code `quiet`: the printed program and the moves read back from it.
fn for_rrf(program: &str, quiet: &str) -> (String, String, Vec<(bool, [f64; 3])>) {
    let (ok, printed, err) = run_cli(program, &["--preset", "duet-cnc"]);
    assert!(ok, "{err}");
    assert!(!err.contains(quiet), "{err}");
    let moves = reread(&printed, ncpost::machine::Flavour::RrfCnc);
    (printed, err, moves)
}

/// The printed program read back the way `flavour`'s controller reads it (the crate's
/// readback): each move's end X Y Z (NaN where not known) and whether it is a rapid.
fn reread(printed: &str, flavour: ncpost::machine::Flavour) -> Vec<(bool, [f64; 3])> {
    use ncpost::readback::{Event, Reader};
    let mut r = Reader::new(ncpost::motion::Model::default(), Some(flavour), None);
    printed
        .lines()
        .filter_map(|l| match r.line(l) {
            Some(Event::Move(m)) => Some((
                m.rapid,
                [Axis::X, Axis::Y, Axis::Z].map(|a| m.to.get(a).unwrap_or(f64::NAN)),
            )),
            _ => None,
        })
        .collect()
}

/// 01 for RepRapFirmware (`--preset duet-cnc`) and Grbl: `O1` runs three times, each a
/// `G91 G0 X1` step and a `G99 G81` hole drilled to Z-1 from the R plane 0.25 and left at
/// R (G99). The printed program, read back as the controller reads it, goes to X1, X2
/// and X3 at Y0 and drills each to Z-1, as LinuxCNC's expected output does.
#[test]
fn basics_run_for_rrf_and_grbl() {
    use ncpost::machine::Flavour;
    let src = fixture("linuxcnc_m98m99_01_basics.ngc");
    for (args, flavour) in [
        (&["--preset", "duet-cnc"][..], Flavour::RrfCnc),
        (&["--emit", "grbl"][..], Flavour::Grbl),
    ] {
        let (ok, printed, err) = run_cli(&src, args);
        assert!(ok, "{args:?}: {err}");
        assert!(
            !printed.contains("M98") && !printed.contains("M99"),
            "{printed}"
        );
        let mut want = vec![(true, [0.0, 0.0, 0.25])];
        for hole in 1..=3 {
            let x = hole as f64;
            want.push((true, [x, 0.0, 0.25])); // the G91 step, at the initial level
            want.push((false, [x, 0.0, -1.0])); // feed to the depth
            want.push((true, [x, 0.0, 0.25])); // back to R (G99)
        }
        assert_eq!(reread(&printed, flavour), want, "{args:?}:\n{printed}");
    }
}

/// RepRapFirmware's `M98 P"file"` runs a macro file from the SD card: it is no subprogram
/// of the program, so it passes through unchanged for RepRapFirmware, and the moves around
/// it print as programmed.
#[test]
fn rrf_macro_calls_pass_through() {
    let src = "G21 G90\nG0 X0 Y0 Z5\nM98 P\"homeall.g\"\nG0 X10 Y5 Z5\nG1 Z-1 F100\nM98 P\"0:/macros/tool change.g\"\nG0 Z5\nM30\n";
    let (printed, _, moves) = for_rrf(src, "subprograms::");
    let calls: Vec<&str> = printed.lines().filter(|l| l.contains("M98")).collect();
    assert_eq!(
        calls,
        ["M98 P\"homeall.g\"", "M98 P\"0:/macros/tool change.g\""]
    );
    let ends: Vec<[f64; 3]> = moves.iter().map(|m| m.1).collect();
    assert_eq!(
        ends,
        [
            [0.0, 0.0, 5.0],
            [10.0, 5.0, 5.0],
            [10.0, 5.0, -1.0],
            [10.0, 5.0, 5.0]
        ]
    );
    // Grbl runs no files: its backend refuses the call, expand-subprograms does not.
    let (ok, _, err) = run_cli(src, &["--emit", "grbl"]);
    assert!(!ok);
    assert!(!err.contains("subprograms::call"), "{err}");
}

/// Parameter assignments (`#1 = [#1 + 1]`) move nothing: the positions and the modes,
/// the canned cycle in force included, stay known after them, and the relative moves
/// after them print resolved. A G92 offset parameter (`#5212`, Y's) makes Y, and only Y,
/// unknown. Read back as RepRapFirmware reads the printed program.
#[test]
fn parameter_lines_move_nothing_and_forget_nothing() {
    let src = "G21 G90 G0 X1 Y2 Z3\n#1 = [#1 + 1]\nG91 G1 X1 F100\n#<step> = 2 (named)\nG1 Y1\n#5212 = 4\nG1 X1 Z-1\nG1 Y1\nG90 G98 G81 X5 Y5 Z-1 R1\n#2 = 1\nX6\nG80\nM30\n";
    let (printed, err, moves) = for_rrf(src, "subprograms::");
    // Only the relative Y move after `#5212` is unknown (line 8), nothing else.
    assert_eq!(err.matches("gcode::relative-unknown").count(), 1, "{err}");
    assert!(err.contains(":8:"), "{err}");
    let mut want = vec![
        (true, [1.0, 2.0, 3.0]),
        (false, [2.0, 2.0, 3.0]),
        (false, [2.0, 3.0, 3.0]),
        (false, [3.0, 3.0, 2.0]),
        (false, [3.0, 4.0, 2.0]), // `G1 Y1` as written, read relatively by the controller
    ];
    // G98: each hole from the initial level Z2 down to R1, fed to Z-1, back to Z2; the
    // second hole (X6) is the cycle still in force after `#2 = 1`.
    for x in [5.0, 6.0] {
        want.extend([
            (true, [x, 5.0, 2.0]),
            (true, [x, 5.0, 1.0]),
            (false, [x, 5.0, -1.0]),
            (true, [x, 5.0, 2.0]),
        ]);
    }
    assert_eq!(moves, want, "\n{printed}");
}

/// `M98 P1 L0` runs O1 no time: LinuxCNC skips the call, and so does the expansion, with
/// a note; the moves around it print where they were programmed.
#[test]
fn l0_skips_the_call() {
    let src = "G21 G90 G0 X0 Y0 Z5\nM98 P1 L0\nG0 X2\nM98 P1 L2\nG0 Y3\nM30\nO1\nG1 Z-1 F100\nG0 Z5\nM99\n";
    let (printed, err, moves) = for_rrf(src, "subprograms::count");
    assert!(err.contains("O1 is called to run no time (L0)"), "{err}");
    let want = [
        (true, [0.0, 0.0, 5.0]),
        (true, [2.0, 0.0, 5.0]),
        (false, [2.0, 0.0, -1.0]),
        (true, [2.0, 0.0, 5.0]),
        (false, [2.0, 0.0, -1.0]),
        (true, [2.0, 0.0, 5.0]),
        (true, [2.0, 3.0, 5.0]),
    ];
    assert_eq!(moves, want, "\n{printed}");
}

/// A body that returns in G91: the relative body steps on from call to call as on the
/// controller, and a move after the call that does not restate G90 is read in G91.
#[test]
fn modes_left_by_a_body_matter_only_to_lines_that_follow() {
    let src = "G21 G90 G0 X0 Y0 Z5\nM98 P1 L2\n(done)\n#1 = 2\nM98 P1\nM30\nO1\nG91 G0 X1\nG1 Z-1 F100\nG0 Z1\nM99\n";
    let (_, _, moves) = for_rrf(src, "subprograms::modes");
    let mut want = vec![(true, [0.0, 0.0, 5.0])];
    for x in 1..=3 {
        let x = x as f64;
        want.push((true, [x, 0.0, 5.0]));
        want.push((false, [x, 0.0, 4.0]));
        want.push((true, [x, 0.0, 5.0]));
    }
    assert_eq!(moves, want);
    // A move after the call that does not restate G90 is read in G91, as the controller
    // reads it: 5 on from X2, and the next call steps on from X7.
    let (_, _, moves) = for_rrf(&src.replace("(done)", "G0 X5"), "subprograms::modes");
    assert_eq!(moves[..7], want[..7]);
    assert_eq!(
        moves[7..],
        [
            (true, [7.0, 0.0, 5.0]),
            (true, [8.0, 0.0, 5.0]),
            (false, [8.0, 0.0, 4.0]),
            (true, [8.0, 0.0, 5.0]),
        ]
    );
}

/// A subroutine defined between moves is passed over by the frontend, which forgets the
/// positions there; the expansion leaves the definition out and forgets them too, so it
/// never completes a move with an axis the program does not know (an `E0` on a mill, as
/// pcb2gcode_al_linuxcnc_back.ngc got once parameter lines stopped forgetting E).
#[test]
fn a_definition_between_moves_adds_no_axis() {
    // The call with an argument keeps the definition in the output: for LinuxCNC, which
    // runs it (RepRapFirmware has no o-word subroutines: an error there).
    let src = "G21 G90 G0 X0 Y0 Z5\no100 sub\nG0 X1\no100 endsub\n#1 = 2\nG0 Z2\no100 call\nG0 Y3\no100 call [1]\nM30\n";
    let (ok, printed, err) = run_cli(src, &["--emit", "gcode", "--pass", "expand-subprograms"]);
    assert!(ok && !err.contains("subprograms::modes"), "{err}");
    let moves = reread(&printed, ncpost::machine::Flavour::Linuxcnc);
    assert!(
        !printed.contains(" E") && !printed.contains("M82"),
        "{printed}"
    );
    // Read back (the controller runs the definition's lines too): the moves the main
    // program makes end where it put them, the expanded call's X1 and the Y3 after it.
    let ends: Vec<[f64; 3]> = moves.iter().map(|m| m.1).collect();
    assert_eq!(ends.last(), Some(&[1.0, 3.0, 2.0]), "{printed}");
    assert!(printed.lines().any(|l| l == "G0 Z2"), "{printed}");
}

/// A subprogram called only from inside another one that passes through (a loop with a
/// parameter count cannot be expanded) stays in the printed program with it: pcb2gcode's
/// autolevelling probe (`o3` repeats `o2 call` `#104` times) once lost `o2`, and the
/// printed program called a subprogram it no longer had.
#[test]
fn subprograms_reached_from_kept_bodies_stay() {
    let program = "G21 G90\n\
        o2 sub\n  G0 Z0.080\n  G38.2 Z-0.1 F60\no2 endsub\n\
        o3 sub\n  o4 repeat [#104]\n    o2 call\n  o4 endrepeat\no3 endsub\n\
        o9 sub\n  G0 X9\no9 endsub\n\
        #104 = 2\n\
        o5 repeat [6]\n  o3 call\no5 endrepeat\n\
        M2\n";
    // For LinuxCNC, which runs o-word subroutines (RepRapFirmware has none).
    let o = common::run_stdin(
        &["--emit", "gcode", "--pass", "expand-subprograms", "-o", "-"],
        program,
    );
    let printed = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    for needle in ["o2 sub", "o2 endsub", "o2 call", "o3 sub", "o3 call"] {
        assert!(
            printed.contains(needle),
            "{needle} missing:\n{printed}\n{stderr}"
        );
    }
    // A subprogram nothing reaches is still left out, with its warning.
    assert!(!printed.contains("o9 sub"), "{printed}");
    assert!(stderr.contains("subprograms::unused"), "{stderr}");
}

/// The moves a printed program makes as X Y Z ends, `rapid` or fed, split into its
/// holes: each fed stroke's bottom, with the rapid before it (the approach at the R plane)
/// and the rapid after it (the retract).
fn drilled(moves: &[(bool, [f64; 3])]) -> Vec<([f64; 3], [f64; 3], [f64; 3])> {
    let mut holes = Vec::new();
    for (i, m) in moves.iter().enumerate() {
        if !m.0 {
            let before = moves[i - 1];
            let after = moves[i + 1];
            assert!(
                before.0 && after.0,
                "a feed not between rapids at {i}: {moves:?}"
            );
            holes.push((before.1, m.1, after.1));
        }
    }
    holes
}

/// linuxcnc_m98m99_05_loops: O1 is `G91 G99 G81 X1 Z-1.0 R0.25` and returns with G91, G81
/// and G99 in force, as LinuxCNC leaves them; the main program restates `G90 G0` after
/// each call. For RepRapFirmware and Grbl the calls are expanded and the cycle drilled
/// as moves. LinuxCNC's G91 cycle (interp_cycles.cc, `convert_cycle_xy`: under
/// `MODE_INCREMENTAL`, `r = R + initial level` and `cc = r + Z`; G-code reference, G81
/// "Incremental Position" example): from the initial level Z0.25 the R plane is 0.5 and
/// the bottom -0.5, each repetition one X step on. So: ten holes at X1..X10, then after
/// `G90 G0 X0 Y0 Z0.25` and the skipped `L0` call, two more at X1 and X2; every hole fed
/// from R 0.5 to -0.5 and retracted to R (G99). Read back from the printed program.
#[test]
fn loops_follow_the_modes_the_body_leaves() {
    use ncpost::machine::Flavour;
    let src = fixture("linuxcnc_m98m99_05_loops.ngc");
    // Grbl has no parameters: the `#1` counter lines (they feed only the PRINT
    // messages) are left out for it.
    let no_params: String = src
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .map(|l| format!("{l}\n"))
        .collect();
    for (program, args, flavour) in [
        (&src, &["--preset", "duet-cnc"][..], Flavour::RrfCnc),
        (&no_params, &["--emit", "grbl"][..], Flavour::Grbl),
    ] {
        let (ok, printed, err) = run_cli(program, args);
        assert!(ok, "{args:?}: {err}");
        assert!(!err.contains("subprograms::modes"), "{err}");
        // Words of the printed lines, comments aside.
        let words = |w: &str| {
            printed
                .lines()
                .filter(|l| !l.starts_with([';', '(']))
                .any(|l| l.split_whitespace().any(|x| x == w))
        };
        assert!(
            !words("M98") && !words("M99") && !words("O1"),
            "{args:?}:\n{printed}"
        );
        let moves = reread(&printed, flavour);
        let holes = drilled(&moves);
        let xs: Vec<f64> = holes.iter().map(|h| h.1[0]).collect();
        let want: Vec<f64> = (1..=10).chain(1..=2).map(f64::from).collect();
        assert_eq!(xs, want, "{args:?}:\n{printed}");
        for (approach, bottom, retract) in &holes {
            let [x, y, _] = *bottom;
            assert_eq!(*approach, [x, y, 0.5], "{args:?}: R plane");
            assert_eq!(*bottom, [x, 0.0, -0.5], "{args:?}: depth");
            assert_eq!(*retract, [x, y, 0.5], "{args:?}: G99 retract to R");
        }
        // After each call, the `G90 G0 X0 Y0 Z0.25` goes where it says (from X10 after
        // the ten holes); the program ends where the second call leaves it.
        let back: Vec<usize> = (1..moves.len())
            .filter(|&i| moves[i].1 == [0.0, 0.0, 0.25])
            .collect();
        assert!(!back.is_empty(), "{printed}");
        assert_eq!(moves[back[0] - 1].1, [10.0, 0.0, 0.5], "{args:?}");
        assert_eq!(moves.last().unwrap().1, [2.0, 0.0, 0.5], "{args:?}");
    }
}

/// linuxcnc_m98m99_05_loops printed with its calls (`--emit gcode`, no expansion), read
/// as LinuxCNC runs it: each `M98 P1 L<n>` runs O1's lines n times in the same modal
/// state, so the body's G91 is in force after the call. The printed program must put
/// G90 back before the rapid after each call, which then lands at X0 Y0 Z0.25 (read in
/// G91 it went to X10 Z0.75, and a bare `X0 Y0 Z0.25` after the body's G81 drills).
#[test]
fn printed_calls_restate_the_modes_after_them() {
    use ncpost::readback::{Event, Reader};
    let src = fixture("linuxcnc_m98m99_05_loops.ngc");
    let (ok, printed, err) = run_cli(&src, &["--emit", "gcode"]);
    assert!(ok, "{err}");
    let lines: Vec<&str> = printed.lines().collect();
    let o1 = lines
        .iter()
        .position(|l| l.trim() == "O1")
        .expect("O1 printed");
    let m99 = o1 + lines[o1..].iter().position(|l| l.trim() == "M99").unwrap();
    let body = &lines[o1 + 1..m99];
    let mut r = Reader::new(
        ncpost::motion::Model::default(),
        Some(ncpost::machine::Flavour::Linuxcnc),
        None,
    );
    let mut after_call = Vec::new();
    let mut pending = false;
    for line in &lines[..o1] {
        if line.split_whitespace().any(|w| w == "M98") {
            let count = line
                .split_whitespace()
                .find_map(|w| w.strip_prefix('L'))
                .map_or(1, |n| n.parse::<u32>().unwrap());
            for _ in 0..count {
                for b in body {
                    r.line(b);
                }
            }
            pending = true;
            continue;
        }
        if let Some(Event::Move(m)) = r.line(line)
            && std::mem::take(&mut pending)
        {
            after_call.push([Axis::X, Axis::Y, Axis::Z].map(|a| m.to.get(a).unwrap()));
        }
    }
    // The L10 and L0 calls are followed by the rapid; the L2 call by M30.
    assert_eq!(after_call, [[0.0, 0.0, 0.25]; 2], "\n{printed}");
}

/// Only the modes a subroutine's lines can change are unknown after its call: after an
/// o-word subroutine that sets none (a dwell), the next move is read as usual; after one
/// that sets G91, a move that does not restate G90 is copied as written (warned), so the
/// controller reads it in G91. Calls with arguments pass through, so nothing reads
/// these lines again.
#[test]
fn only_the_modes_a_subroutine_sets_are_unknown_after_it() {
    let src = "G21 G90 G0 X0 Y0 Z5\no100 sub\nG4 P1\no100 endsub\no200 sub\nG91\no200 endsub\no100 call [1]\nG0 X5\no200 call [1]\nG0 X2\nG90 G0 X3\nM30\n";
    let (ok, printed, err) = run_cli(src, &["--emit", "gcode"]);
    assert!(ok, "{err}");
    assert_eq!(err.matches("gcode::after-call").count(), 1, "{err}");
    assert!(err.contains(":11:1]"), "{err}");
    let lines: Vec<&str> = printed.lines().collect();
    let at = |l: &str| lines.iter().position(|x| *x == l).unwrap();
    // `G0 X2` as written, with no G90 put before it; `G0 X5` and `G0 X3` in G90.
    assert_eq!(lines[at("G0 X2") - 1], "o200 call [1]", "{printed}");
    for (mv, within) in [("G0 X5", 3), ("G0 X3", 2)] {
        let before = &lines[at(mv) - within..at(mv)];
        assert!(before.iter().any(|l| l.contains("G90")), "{printed}");
    }
}
