//! Corpus tests (issue 2).
//!
//! 1. One snapshot test per fixture in `tests/fixtures/gcode/`: each fixture is a whole,
//!    unmodified file of the shared corpus with one `; origin: ...` line added at the top.
//!    The snapshot holds the frontend diagnostics, the IR dump, the plain G-code and the
//!    RepRapFirmware output, with section headers.
//! 2. The done-when check over every file of `../shared/corpus/gcode/`:
//!    `ncpost run --emit gcode` succeeds, its output re-parses without errors, moves
//!    through the same absolute positions (and arc centres) within the print precision
//!    and keeps every comment; lines the IR does not evaluate pass through unchanged;
//!    dwells keep their length; the real binary gives the library's output.
//!
//! Checks that fail because of bugs in `src/` keep asserting the correct behaviour.
//! Snapshots that record wrong output say so in their header (`KNOWN BUG`).

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use ncpost::back::{Backend, gcode as plain, rrf};
use ncpost::diag::Diagnostic;
use ncpost::front::Frontend;
use ncpost::front::gcode::{Options, Parser, parse_str};
use ncpost::ir::{
    Axis, AxisSet, Block, BlockKind, Joints, MotionKind, Plane, Target, VerbatimReason, dump,
};
use ncpost::num::lexer::{Tok, lex_line};
use ncpost::pipeline::compile_str;
use ncpost::preset::Preset;
use ncpost::valid::Verifier;

// ---------------------------------------------------------------------------------------
// Part 1: fixture snapshots
// ---------------------------------------------------------------------------------------

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/gcode")
}

fn render_all(out: &mut String, diags: &[Diagnostic], file: &str) {
    if diags.is_empty() {
        out.push_str("(none)\n");
    }
    for d in diags {
        out.push_str(d.render(file, false).trim_end());
        out.push('\n');
    }
}

/// Runs `blocks` through a backend, collecting its warnings and errors.
fn emit(blocks: &[Block], backend: &mut dyn Backend) -> Vec<Diagnostic> {
    ncpost::back::write_blocks(backend, blocks)
}

/// One backend's section: its diagnostics and its text.
fn backend_section(
    out: &mut String,
    title: &str,
    file: &str,
    text: Vec<u8>,
    diags: &[Diagnostic],
    via_write_string: Result<String, Vec<Diagnostic>>,
) {
    let text = String::from_utf8(text).expect("backend output is UTF-8");
    // The streaming writer and the `write_string` convenience must agree.
    match &via_write_string {
        Ok(s) => assert_eq!(s, &text, "{title}: write_string differs from the Writer"),
        Err(_) => assert!(
            diags.iter().any(Diagnostic::is_error),
            "{title}: write_string failed but the Writer reported no error"
        ),
    }
    let _ = writeln!(out, "\n=== {title}: diagnostics ===");
    render_all(out, diags, file);
    let _ = writeln!(out, "\n=== {title}: output ===");
    out.push_str(&text);
}

/// The combined snapshot text of one fixture.
fn fixture_report(file: &str) -> String {
    let path = fixture_dir().join(file);
    let bytes =
        std::fs::read(&path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let mut parser = Parser::new(&bytes[..], Options::default());
    let mut diags = Vec::new();
    let mut blocks = Vec::new();
    while let Some(b) = parser.next_block(&mut diags) {
        blocks.push(b);
    }
    let mut verifier = Verifier;
    for b in &blocks {
        if let Err(e) = verifier.check(b) {
            panic!("{file}:{}: IR invariant broken: {e}", b.span.line);
        }
    }
    // The fixture's first line is its origin comment, kept as a comment block.
    let first = blocks.first().expect("fixture has blocks");
    assert!(
        matches!(first.kind, BlockKind::Comment)
            && first.comments.len() == 1
            && first.comments[0].text.starts_with(" origin: "),
        "{file}: first block is not the origin comment: {first:?}"
    );

    let mut out = String::new();
    let _ = writeln!(out, "=== frontend: diagnostics ===");
    render_all(&mut out, &diags, file);
    let _ = writeln!(out, "\n=== ir ===");
    out.push_str(&dump::to_string(&blocks));

    let mut text = Vec::new();
    let back_diags = emit(
        &blocks,
        &mut plain::Writer::new(&mut text, &plain::Options::default()),
    );
    let ws = plain::write_string(&blocks, &plain::Options::default());
    backend_section(&mut out, "gcode", file, text, &back_diags, ws);

    let mut text = Vec::new();
    let back_diags = emit(
        &blocks,
        &mut rrf::Writer::new(&mut text, &rrf::Options::default()),
    );
    let ws = rrf::write_string(&blocks, &rrf::Options::default());
    backend_section(&mut out, "rrf", file, text, &back_diags, ws);
    out
}

/// The fixture's first line (its origin), for the snapshot's description.
fn origin_line(file: &str) -> String {
    let text = std::fs::read(fixture_dir().join(file)).expect("fixture exists");
    let first = text.split(|&b| b == b'\n').next().unwrap_or_default();
    String::from_utf8_lossy(first).trim_end().to_string()
}

/// Snapshots one fixture (named after the calling test). With `known_bug`, the snapshot
/// records current behaviour that is wrong; the note goes into the snapshot header.
macro_rules! snapshot_fixture {
    ($file:literal) => {
        snapshot_fixture!($file, known_bug = "")
    };
    ($file:literal, known_bug = $bug:literal) => {{
        let mut description = origin_line($file);
        if !$bug.is_empty() {
            description.push_str("\nKNOWN BUG (snapshot shows current, wrong output): ");
            description.push_str($bug);
        }
        insta::with_settings!({
            description => description,
            omit_expression => true,
        }, {
            insta::assert_snapshot!(fixture_report($file));
        });
    }};
}

#[test]
fn linuxcnc_tort() {
    // origin: LinuxCNC/linuxcnc nc_files/tort.ngc @ 5c41560e (GPL-2.0)
    snapshot_fixture!("linuxcnc_tort.ngc");
}

#[test]
fn millenniumos_rrf_cnc_example() {
    // origin: MillenniumMachines/MillenniumOS example.gcode @ de639ec8 (GPL-3.0)
    snapshot_fixture!("millenniumos_rrf_cnc_example.gcode");
}

#[test]
fn millenniumos_g6508_1_meta_macro() {
    // origin: MillenniumMachines/MillenniumOS macro/movement/G6508.1.g @ de639ec8 (GPL-3.0)
    snapshot_fixture!("millenniumos_G6508.1.g");
}

#[test]
fn gcoders_mach3_plasma() {
    // origin: Michael-F-Bryan/gcode-rs tests/data/_mach3_plasma.gcode @ d6edb2a6 (MIT OR Apache-2.0)
    snapshot_fixture!("gcoders_mach3_plasma.gcode");
}

#[test]
fn gcoders_helman_program_2_g41() {
    // origin: Michael-F-Bryan/gcode-rs tests/data/program_2.gcode @ d6edb2a6 (MIT OR Apache-2.0)
    snapshot_fixture!("gcoders_helman_program_2_g41.gcode");
}

#[test]
fn igesio_codes() {
    // origin: YayoiHabami/IGESio tests/test_data/machines/nc/codes.nc @ 3e87a91a (MIT)
    snapshot_fixture!("igesio_codes.nc");
}

#[test]
fn linuxcnc_m98m99_01_basics() {
    // origin: LinuxCNC/linuxcnc tests/interp/m98m99/01-basics/test.ngc @ 5c41560e (GPL-2.0)
    snapshot_fixture!("linuxcnc_m98m99_01_basics.ngc");
}

#[test]
fn lhalb_sinumerik_pathcode() {
    // origin: lhalb/cura_g-code_converter data/PATHCODE.MPF @ b1913f31 (MIT)
    snapshot_fixture!("lhalb_sinumerik_PATHCODE.MPF");
}

#[test]
fn gcoders_gcode_lexer_samples() {
    // origin: Michael-F-Bryan/gcode-rs tests/data/_gcodeLexer_samples.ngc @ d6edb2a6 (MIT OR Apache-2.0)
    snapshot_fixture!("gcoders_gcodeLexer_samples.ngc");
}

#[test]
fn sameer_edge_cases() {
    // origin: sameer/g-code lib/tests/edge_cases.gcode @ 81035b12 (MIT OR Apache-2.0)
    snapshot_fixture!("sameer_edge_cases.gcode");
}

#[test]
fn gcoders_reprap_25000_cnc() {
    // origin: Michael-F-Bryan/gcode-rs tests/data/reprap_cnc.gcode @ d6edb2a6 (MIT OR Apache-2.0)
    snapshot_fixture!("gcoders_reprap_25000_cnc.gcode");
}

#[test]
fn printrun_pause_restore_rel_e() {
    // origin: kliment/Printrun testfiles/pause-restore-rel-e.gcode @ ecd260f1 (GPL-3.0)
    snapshot_fixture!("printrun_pause_restore_rel_e.gcode");
}

#[test]
fn printrun_pcb_milling_comment() {
    // origin: kliment/Printrun testfiles/PCB-milling-and-(comment).gcode @ ecd260f1 (GPL-3.0)
    snapshot_fixture!("printrun_pcb_milling_comment.gcode");
}

#[test]
fn mech491_zig_zag_smoothed() {
    // origin: userFour/MECH491-postprocessor PostProcessed_Zig_Zag_Smoothed.txt @ 22c4fbbd (CC0-1.0)
    snapshot_fixture!("mech491_PostProcessed_Zig_Zag_Smoothed.nc");
}

#[test]
fn printrun_arc_test() {
    // origin: kliment/Printrun testfiles/arc_test.gcode @ ecd260f1 (GPL-3.0)
    snapshot_fixture!("printrun_arc_test.gcode");
}

#[test]
fn gcodenom_g2_box_nibble_clockwise() {
    // origin: martinfrances107/gcode-nom assets/g2_box_nibble_clockwise.gcode @ ddef00e8 (MIT)
    snapshot_fixture!("gcodenom_g2_box_nibble_clockwise.gcode");
}

#[test]
fn sameer_vandy_logo_svg2gcode() {
    // origin: sameer/g-code lib/tests/vandy_commodores_logo.gcode @ 81035b12 (MIT OR Apache-2.0)
    snapshot_fixture!("sameer_vandy_logo_svg2gcode.gcode");
}

#[test]
fn gcoders_program_3_tweakie() {
    // origin: Michael-F-Bryan/gcode-rs tests/data/_program_3.gcode @ d6edb2a6 (MIT OR Apache-2.0)
    snapshot_fixture!("gcoders_program_3_tweakie.gcode");
}

/// Every fixture file has a test above (and so a snapshot), and every fixture starts with
/// its origin.
#[test]
fn every_fixture_has_a_snapshot_and_an_origin() {
    let snapshots = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/snapshots");
    let source = include_str!("corpus.rs");
    for entry in std::fs::read_dir(fixture_dir()).expect("fixture directory") {
        let name = entry.unwrap().file_name().to_string_lossy().into_owned();
        assert!(
            origin_line(&name).starts_with("; origin: "),
            "{name}: the first line must cite the origin"
        );
        assert!(
            source.contains(&format!("\"{name}\"")),
            "{name}: no snapshot test"
        );
    }
    let pending: Vec<_> = std::fs::read_dir(&snapshots)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with("corpus__") && !n.ends_with(".snap"))
                .collect()
        })
        .unwrap_or_default();
    assert!(pending.is_empty(), "unreviewed snapshots: {pending:?}");
}

// ---------------------------------------------------------------------------------------
// Part 2: the done-when check over the whole corpus
// ---------------------------------------------------------------------------------------

/// Lines with these warnings are passed through unevaluated, so positions after them
/// cannot be compared.
const SKIP_POSITIONS: &[&str] = &[
    "gcode::unevaluated",
    "gcode::meta-command",
    "gcode::control-flow",
    "gcode::subprogram",
    "gcode::unsupported-motion",
    "gcode::arc-unknown-start",
    "gcode::block-delete",
];

fn corpus_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gcode");
    assert!(
        dir.is_dir(),
        "the shared corpus is missing: {} is not a directory (CI must check it out at \
         ../shared/corpus relative to the repository root)",
        dir.display()
    );
    dir
}

/// One corpus file and what the library made of it.
struct Checked {
    name: String,
    input: Result<String, String>,
    /// `compile_str` with the `default` preset.
    output: Result<String, Vec<Diagnostic>>,
}

fn preset() -> Preset {
    Preset::builtin("default").expect("built-in preset `default`")
}

/// Mach3 programs with arcs off their circle (a plasma R arc too short for its chord, a
/// centre off by more than the tolerance): Mach3 cuts them, LinuxCNC, Grbl and
/// RepRapFirmware stop there. By default they are refused; they compile with the opt-in
/// `gcode_input.strict_arcs = false`.
const OFF_CIRCLE_ARCS: &[&str] = &[
    "gcoders_helman_program_2_g41.gcode",
    "gcoders_mach3_plasma.gcode",
];

/// The preset a corpus file is compiled with: the default, with the opt-in for the files
/// of [`OFF_CIRCLE_ARCS`].
fn preset_for(name: &str) -> Preset {
    let mut preset = preset();
    if OFF_CIRCLE_ARCS.contains(&name) {
        preset.gcode_input.strict_arcs = false;
    }
    preset
}

#[test]
fn off_circle_arcs_are_refused_by_default_at_their_lines() {
    for name in OFF_CIRCLE_ARCS {
        let src = std::fs::read_to_string(corpus_dir().join(name)).expect("corpus file");
        let diags = compile_str(&src, &preset()).expect_err("refused by default");
        let errors: Vec<&Diagnostic> = diags.iter().filter(|d| d.is_error()).collect();
        assert!(!errors.is_empty(), "{name}");
        for e in errors {
            assert_eq!(e.code, "gcode::arc", "{name}: {e}");
            assert!(
                e.help
                    .as_deref()
                    .is_some_and(|h| h.contains("strict_arcs = false"))
            );
        }
    }
}

fn corpus() -> &'static [Checked] {
    static CORPUS: OnceLock<Vec<Checked>> = OnceLock::new();
    CORPUS.get_or_init(|| {
        let mut paths: Vec<PathBuf> = std::fs::read_dir(corpus_dir())
            .expect("read the corpus directory")
            .map(|e| e.expect("directory entry").path())
            .filter(|p| p.is_file())
            .collect();
        paths.sort();
        assert!(!paths.is_empty(), "the corpus directory holds no files");
        paths
            .into_iter()
            .map(|p| {
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                let preset = preset_for(&name);
                let input = std::fs::read(&p)
                    .map_err(|e| e.to_string())
                    .and_then(|b| String::from_utf8(b).map_err(|e| e.to_string()));
                let output = match &input {
                    Ok(src) => compile_str(src, &preset),
                    Err(e) => Err(vec![Diagnostic::error("test::read", e.clone())]),
                };
                Checked {
                    name,
                    input,
                    output,
                }
            })
            .collect()
    })
}

fn render(diags: &[Diagnostic], file: &str) -> String {
    let mut s = String::new();
    render_all(&mut s, diags, file);
    s
}

/// Panics with every failure at once, so one run shows the whole list.
fn report(what: &str, failures: Vec<String>) {
    if !failures.is_empty() {
        panic!(
            "{what}: {} failure(s)\n\n{}",
            failures.len(),
            failures.join("\n")
        );
    }
}

#[test]
fn corpus_compiles_with_emit_gcode() {
    let mut failures = Vec::new();
    for c in corpus() {
        if let Err(diags) = &c.output {
            const SHOWN: usize = 3;
            let errors: Vec<Diagnostic> = diags.iter().filter(|d| d.is_error()).cloned().collect();
            let more = match errors.len() {
                n if n > SHOWN => format!("... {n} errors in all\n"),
                _ => String::new(),
            };
            let shown = &errors[..errors.len().min(SHOWN)];
            failures.push(format!("--- {}\n{}{more}", c.name, render(shown, &c.name)));
        }
    }
    report("ncpost run --emit gcode failed", failures);
}

#[test]
fn corpus_output_reparses_without_errors() {
    let mut failures = Vec::new();
    for c in corpus() {
        let Ok(out) = &c.output else { continue };
        if let Err(diags) = parse_str(out, &preset_for(&c.name).gcode_input) {
            let errors: Vec<Diagnostic> = diags.iter().filter(|d| d.is_error()).cloned().collect();
            failures.push(format!(
                "--- {} (emitted G-code)\n{}",
                c.name,
                render(&errors, &format!("{}.out", c.name))
            ));
        }
    }
    report("emitted G-code does not re-parse", failures);
}

/// A motion as the IR describes it, for comparison.
#[derive(Debug, Clone, Copy)]
struct Move {
    line: u32,
    kind: &'static str,
    joints: Joints,
    arc: Option<(Plane, [f64; 2], u32)>,
}

fn moves(blocks: &[Block]) -> Vec<Move> {
    blocks
        .iter()
        .filter_map(|b| {
            let BlockKind::Motion(m) = &b.kind else {
                return None;
            };
            let Target::Joints(joints) = m.target else {
                panic!("line {}: G-code input lowered to a pose", b.span.line)
            };
            let (kind, arc) = match m.kind {
                MotionKind::Rapid => ("G0", None),
                MotionKind::Linear => ("G1", None),
                MotionKind::Arc(a) => {
                    let (u, v, _) = a.plane.axes();
                    let centre = [a.center[u.index()], a.center[v.index()]];
                    (
                        if a.clockwise { "G2" } else { "G3" },
                        Some((a.plane, centre, a.extra_turns)),
                    )
                }
            };
            Some(Move {
                line: b.span.line,
                kind,
                joints,
                arc,
            })
        })
        .collect()
}

/// Half a unit of the last printed digit, plus float noise.
fn tolerance(axis: Axis, value: f64) -> f64 {
    let half_unit = if axis == Axis::E { 0.000_005 } else { 0.000_5 };
    half_unit * (1.0 + 1e-9) + 1e-9 * value.abs().max(1.0)
}

fn axes_text(set: AxisSet) -> String {
    set.iter().map(Axis::letter).collect()
}

/// Differences between an input move and the re-parsed output move, if any.
fn compare(a: &Move, b: &Move) -> Option<String> {
    let mut diffs = Vec::new();
    if a.kind != b.kind {
        diffs.push(format!("motion {} became {}", a.kind, b.kind));
    }
    if a.joints.known != b.joints.known {
        diffs.push(format!(
            "known axes {} became {}",
            axes_text(a.joints.known),
            axes_text(b.joints.known)
        ));
    }
    for axis in a.joints.known.intersection(b.joints.known).iter() {
        let (x, y) = (a.joints.values[axis.index()], b.joints.values[axis.index()]);
        if (x - y).abs() > tolerance(axis, x) {
            diffs.push(format!(
                "{}: {x:.6} became {y:.6} (off by {:.6})",
                axis.letter(),
                (x - y).abs()
            ));
        }
    }
    match (a.arc, b.arc) {
        (Some((pa, ca, ta)), Some((pb, cb, tb))) => {
            if pa != pb {
                diffs.push(format!("arc plane {} became {}", pa.gcode(), pb.gcode()));
            } else {
                let (u, v, _) = pa.axes();
                for (i, axis) in [u, v].into_iter().enumerate() {
                    if (ca[i] - cb[i]).abs() > tolerance(axis, ca[i]) {
                        diffs.push(format!(
                            "arc centre {}: {:.6} became {:.6} (off by {:.6})",
                            axis.letter(),
                            ca[i],
                            cb[i],
                            (ca[i] - cb[i]).abs()
                        ));
                    }
                }
            }
            if ta != tb {
                diffs.push(format!("arc extra turns {ta} became {tb}"));
            }
        }
        (None, None) => {}
        _ => {} // reported as a motion-kind difference
    }
    (!diffs.is_empty()).then(|| diffs.join("; "))
}

fn nth_line(text: &str, line: u32) -> &str {
    text.lines()
        .nth(line.saturating_sub(1) as usize)
        .unwrap_or("")
}

/// A corpus file whose compiled output reads back without errors, with both read into IR.
/// Files that fail to compile or to read back are reported by their own tests.
struct Reread {
    file: &'static Checked,
    src: &'static str,
    out: &'static str,
    input: ncpost::front::gcode::Program,
    output: ncpost::front::gcode::Program,
}

fn reread() -> impl Iterator<Item = Reread> {
    corpus().iter().filter_map(move |file| {
        let (Ok(src), Ok(out)) = (&file.input, &file.output) else {
            return None;
        };
        let options = preset_for(&file.name).gcode_input;
        let output = parse_str(out, &options).ok()?;
        let input = parse_str(src, &options).expect("input parsed before");
        Some(Reread {
            file,
            src,
            out,
            input,
            output,
        })
    })
}

#[test]
fn corpus_output_moves_through_the_same_positions() {
    const SHOWN: usize = 6;
    let mut failures = Vec::new();
    let mut skipped = Vec::new();
    let mut compared = 0;
    for Reread {
        file: c,
        src,
        out,
        input,
        output,
    } in reread()
    {
        let codes: BTreeSet<&str> = input
            .diagnostics
            .iter()
            .map(|d| d.code)
            .filter(|code| SKIP_POSITIONS.contains(code))
            .collect();
        if !codes.is_empty() {
            skipped.push(format!("{} ({})", c.name, Vec::from_iter(codes).join(", ")));
            continue;
        }
        compared += 1;
        let (a, b) = (moves(&input.blocks), moves(&output.blocks));
        let mut lines = Vec::new();
        if a.len() != b.len() {
            lines.push(format!(
                "  {} moves in the input, {} in the output (moves are compared pairwise, so \
                 after the first missing one every pair differs)",
                a.len(),
                b.len()
            ));
        }
        let mut bad = 0;
        for (x, y) in a.iter().zip(&b) {
            if let Some(diff) = compare(x, y) {
                bad += 1;
                if bad <= SHOWN {
                    lines.push(format!(
                        "  input line {} `{}` -> output line {} `{}`: {diff}",
                        x.line,
                        nth_line(src, x.line).trim(),
                        y.line,
                        nth_line(out, y.line)
                    ));
                }
            }
        }
        if bad > SHOWN {
            lines.push(format!("  ... {} differing moves in all", bad));
        }
        if !lines.is_empty() {
            failures.push(format!("--- {}\n{}", c.name, lines.join("\n")));
        }
    }
    println!(
        "position check: {compared} file(s) compared, {} skipped:",
        skipped.len()
    );
    for s in &skipped {
        println!("  skipped {s}");
    }
    assert!(compared > 0, "no corpus file was position-checked");
    report(
        "emitted G-code does not move through the input's positions",
        failures,
    );
}

/// Comments in the IR, in order: those on blocks plus those inside lines passed through
/// as text (and inside command text, where commands with quoted strings or odd arguments
/// keep theirs). Each with the line it is on.
fn comments(blocks: &[Block]) -> Vec<(u32, String)> {
    let mut toks = Vec::new();
    let mut out = Vec::new();
    for b in blocks {
        let text = match &b.kind {
            BlockKind::Verbatim(v) => Some(v.text.as_str()),
            BlockKind::Command(c) => Some(c.text.as_str()),
            _ => None,
        };
        if let Some(text) = text {
            lex_line(text, &mut toks);
            for t in &toks {
                if let Tok::Comment(c) | Tok::LineComment(c) | Tok::OpenComment(c) = t.1 {
                    out.push((b.span.line, c.to_string()));
                }
            }
        }
        for c in &b.comments {
            out.push((b.span.line, c.text.clone()));
        }
    }
    out
}

#[test]
fn corpus_output_keeps_every_comment() {
    let mut failures = Vec::new();
    for Reread {
        file: c,
        src,
        out,
        input,
        output,
    } in reread()
    {
        let (a, b) = (comments(&input.blocks), comments(&output.blocks));
        if a.len() != b.len() {
            // Comments may change style (`( )` to `;`), so compare the text only where
            // it helps to find the first extra or missing one.
            let norm = |s: &str| {
                s.trim_start_matches([';', '('])
                    .trim_end_matches(')')
                    .trim()
                    .to_string()
            };
            let first = a
                .iter()
                .zip(&b)
                .position(|(x, y)| norm(&x.1) != norm(&y.1))
                .unwrap_or(a.len().min(b.len()));
            let show = |v: &[(u32, String)], text: &str| {
                v.get(first)
                    .map(|(l, c)| format!("line {l} `{}` (comment {c:?})", nth_line(text, *l)))
                    .unwrap_or_else(|| "the end".into())
            };
            failures.push(format!(
                "--- {}: {} comments in the input, {} in the output; first difference: \
                 input {} / output {}",
                c.name,
                a.len(),
                b.len(),
                show(&a, src),
                show(&b, out),
            ));
        }
    }
    report("emitted G-code does not keep the comments", failures);
}

/// Lines the IR does not evaluate (parameters, expressions, meta commands, control flow,
/// subprogram bodies, tape delimiters) appear in the output exactly as written, in order;
/// every unevaluated line has a warning pointing at it.
#[test]
fn corpus_unevaluated_lines_pass_through_unchanged() {
    const SHOWN: usize = 4;
    let mut failures = Vec::new();
    for c in corpus() {
        let (Ok(src), Ok(out)) = (&c.input, &c.output) else {
            continue;
        };
        let input = parse_str(src, &preset_for(&c.name).gcode_input).expect("input parsed before");
        let warned: BTreeSet<u32> = input
            .diagnostics
            .iter()
            .filter_map(|d| d.location.as_ref().map(|l| l.line))
            .collect();
        let out_lines: Vec<&str> = out.lines().collect();
        let mut next = 0;
        let mut problems = Vec::new();
        for b in &input.blocks {
            let BlockKind::Verbatim(v) = &b.kind else {
                continue;
            };
            if v.reason == VerbatimReason::Unevaluated && !warned.contains(&b.span.line) {
                problems.push(format!(
                    "  line {} `{}` is not evaluated but has no warning",
                    b.span.line, v.text
                ));
            }
            match out_lines[next..].iter().position(|l| *l == v.text) {
                Some(i) => next += i + 1,
                None => {
                    let near = out_lines[next..]
                        .iter()
                        .find(|l| l.contains(v.text.as_str()))
                        .map_or(String::from("nothing similar"), |l| format!("`{l}`"));
                    problems.push(format!(
                        "  line {} `{}` is not in the output as written (found {near})",
                        b.span.line, v.text
                    ));
                }
            }
        }
        if !problems.is_empty() {
            let n = problems.len();
            problems.truncate(SHOWN);
            if n > SHOWN {
                problems.push(format!("  ... {n} problems in all"));
            }
            failures.push(format!("--- {}\n{}", c.name, problems.join("\n")));
        }
    }
    report("unevaluated lines do not pass through unchanged", failures);
}

/// Dwell blocks, in order, in seconds.
fn dwells(blocks: &[Block]) -> Vec<(u32, f64)> {
    blocks
        .iter()
        .filter_map(|b| match b.kind {
            BlockKind::Dwell { seconds } => Some((b.span.line, seconds)),
            _ => None,
        })
        .collect()
}

/// The emitted dwells last as long as the input's when ncpost reads its own output back
/// (milliseconds are printed with 3 decimals).
#[test]
fn corpus_output_keeps_dwell_times() {
    const SHOWN: usize = 4;
    let mut failures = Vec::new();
    for Reread {
        file: c,
        src,
        out,
        input,
        output,
    } in reread()
    {
        let (a, b) = (dwells(&input.blocks), dwells(&output.blocks));
        let mut problems = Vec::new();
        if a.len() != b.len() {
            problems.push(format!(
                "  {} dwells in the input, {} in the output",
                a.len(),
                b.len()
            ));
        }
        for ((la, sa), (lb, sb)) in a.iter().zip(&b) {
            if (sa - sb).abs() > 0.000_5 * (1.0 + 1e-9) + 1e-9 {
                problems.push(format!(
                    "  input line {la} `{}` ({sa} s) -> output line {lb} `{}` ({sb} s)",
                    nth_line(src, *la).trim(),
                    nth_line(out, *lb)
                ));
            }
        }
        if !problems.is_empty() {
            let n = problems.len();
            problems.truncate(SHOWN);
            if n > SHOWN {
                problems.push(format!("  ... {n} problems in all"));
            }
            failures.push(format!("--- {}\n{}", c.name, problems.join("\n")));
        }
    }
    report(
        "emitted dwells do not last as long as the input's",
        failures,
    );
}

/// The real binary, on a few varied files (inch, arcs in three planes, G92, RepRapFirmware
/// meta commands, relative extrusion, CRLF): exit code 0 and the library's output.
#[test]
fn corpus_binary_run_emit_gcode() {
    const FILES: &[&str] = &[
        "linuxcnc_tort.ngc",
        "gcoders_mach3_plasma.gcode",
        "gcoders_reprap_25000_cnc.gcode",
        "millenniumos_G6508.1.g",
        "gcodenom_mini_cube_a_prusaslicer.gcode",
        "gcoders_program_3_tweakie.gcode",
        "lhalb_sinumerik_mainprog.MPF",
    ];
    let dir = corpus_dir();
    let tmp = tempfile::tempdir().expect("temporary directory");
    let mut failures = Vec::new();
    for (i, name) in FILES.iter().enumerate() {
        let input = dir.join(name);
        let src = std::fs::read_to_string(&input).expect("corpus file");
        let expected = match compile_str(&src, &preset_for(name)) {
            Ok(s) => s,
            Err(_) => {
                failures.push(format!("--- {name}: compile_str failed"));
                continue;
            }
        };
        // Alternate between standard output and `-o FILE`.
        let out_file = tmp.path().join(format!("{i}.gcode"));
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_ncpost"));
        cmd.args(["run", "--emit", "gcode", "--quiet"]).arg(&input);
        if OFF_CIRCLE_ARCS.contains(name) {
            let config = tmp.path().join(format!("{i}.toml"));
            let toml = "emit = \"gcode\"\n[[passes]]\nname = \"verify\"\n\
                        [gcode_input]\nstrict_arcs = false\n";
            std::fs::write(&config, toml).expect("write the preset");
            cmd.arg("--config").arg(&config);
        }
        if i % 2 == 1 {
            cmd.arg("-o").arg(&out_file);
        }
        let result = cmd.output().expect("run ncpost");
        if !result.status.success() {
            failures.push(format!(
                "--- {name}: exit status {}\n{}",
                result.status,
                String::from_utf8_lossy(&result.stderr)
            ));
            continue;
        }
        let got = if i % 2 == 1 {
            std::fs::read_to_string(&out_file).expect("output file written")
        } else {
            String::from_utf8(result.stdout).expect("UTF-8 output")
        };
        if got != expected {
            failures.push(format!(
                "--- {name}: the binary's output differs from compile_str"
            ));
        }
    }
    report("ncpost run --emit gcode (binary)", failures);
}
