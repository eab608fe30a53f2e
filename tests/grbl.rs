//! The Grbl 1.1 flavour (`--emit grbl`): the seed's `M98 P10 L625` program runs 625
//! plunges with no M98, M99 or O left (expand-subprograms inserted with a note); every
//! output line of the corpus pcb2gcode files passes an independent check of Grbl 1.1's
//! grammar (letters, G/M codes, 79 counted characters, no `%`) and keeps the programmed
//! positions; snapshots of those outputs; errors (G93, extra axes, arc turns, long lines,
//! unexpandable calls, parameters) as plain diagnostic snapshots; options (allow_g93,
//! unsupported = error/keep, m7).

use ncpost::back::grbl;
use ncpost::diag::Diagnostic;
use ncpost::pipeline::Pipeline;
use ncpost::preset::{Emit, Preset};

const SEED: &str =
    "G92 X0 Y0 Z0\nG00 Z1\nM98 P10 L625\nG00 Z0\nM30\nO10\nG00 Z0.1\nG01 Z0.04 F20\nG00 Z1\nM99\n";

/// Runs `src` through `preset` with Grbl output: (text, diagnostics).
fn run(src: &str, preset: Preset) -> (String, Vec<Diagnostic>) {
    let mut pipeline = Pipeline::builder()
        .preset(preset)
        .emit(Emit::Grbl)
        .build()
        .expect("builds");
    let mut out = Vec::new();
    let mut diags = Vec::new();
    pipeline
        .run_gcode(src.as_bytes(), &mut out, &mut |d| diags.push(d))
        .expect("runs");
    (String::from_utf8(out).expect("utf-8"), diags)
}

fn run_toml(src: &str, toml: &str) -> (String, Vec<Diagnostic>) {
    run(src, Preset::from_toml(toml).expect("preset"))
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

/// The part of a line Grbl parses: blanks, `/`, `( )` comments and `;` to the end
/// dropped (Grbl 1.1 `protocol.c`), upper-cased.
fn grbl_view(line: &str) -> String {
    let mut s = String::new();
    let mut paren = false;
    for c in line.chars() {
        if paren {
            paren = c != ')';
            continue;
        }
        match c {
            ';' => break,
            '(' => paren = true,
            '/' => {}
            c if c.is_whitespace() => {}
            c => s.push(c.to_ascii_uppercase()),
        }
    }
    s
}

/// Grbl 1.1's words (`gcode.c`, default build): `Err` names the first word it rejects.
fn grbl_words(view: &str) -> Result<Vec<(char, f64)>, String> {
    let mut words = Vec::new();
    let b = view.as_bytes();
    let mut k = 0;
    while k < b.len() {
        let letter = b[k] as char;
        if !letter.is_ascii_uppercase() {
            return Err(format!("expected a letter at `{}`", &view[k..]));
        }
        k += 1;
        let start = k;
        while k < b.len() && (b[k].is_ascii_digit() || b[k] == b'.' || b[k] == b'-' || b[k] == b'+')
        {
            k += 1;
        }
        let v: f64 = view[start..k]
            .parse()
            .map_err(|_| format!("bad number after {letter} in `{view}`"))?;
        let ok = match letter {
            'G' => [
                0.0, 1.0, 2.0, 3.0, 4.0, 10.0, 17.0, 18.0, 19.0, 20.0, 21.0, 28.0, 28.1, 30.0,
                30.1, 38.2, 38.3, 38.4, 38.5, 40.0, 43.1, 49.0, 53.0, 54.0, 55.0, 56.0, 57.0, 58.0,
                59.0, 61.0, 80.0, 90.0, 91.0, 91.1, 92.0, 92.1, 93.0, 94.0,
            ]
            .iter()
            .any(|g| (g - v).abs() < 1e-9),
            'M' => [0.0, 1.0, 2.0, 30.0, 3.0, 4.0, 5.0, 8.0, 9.0].contains(&v),
            'F' | 'I' | 'J' | 'K' | 'L' | 'N' | 'P' | 'R' | 'S' | 'T' | 'X' | 'Y' | 'Z' => true,
            _ => false,
        };
        if !ok {
            return Err(format!("Grbl 1.1 rejects {letter}{v} in `{view}`"));
        }
        words.push((letter, v));
    }
    Ok(words)
}

/// Checks every line of a Grbl output; returns the moves as (code, X, Y, Z) with the
/// modal position filled in.
fn check_grbl(text: &str) -> Vec<(u32, [f64; 3])> {
    let mut moves = Vec::new();
    let mut pos = [f64::NAN; 3];
    let mut motion = 0;
    for line in text.lines() {
        assert!(!line.trim_start().starts_with('%'), "`%` line: {line}");
        let view = grbl_view(line);
        assert!(
            view.len() <= 79,
            "{} characters for Grbl: {line}",
            view.len()
        );
        let words = grbl_words(&view).unwrap_or_else(|e| panic!("{e}"));
        let mut moved = false;
        let mut non_modal = false;
        for &(l, v) in &words {
            match l {
                'G' if [0.0, 1.0, 2.0, 3.0].contains(&v) => motion = v as u32,
                'G' if [4.0, 10.0, 28.0, 30.0, 53.0, 92.0].contains(&v) => non_modal = true,
                'X' | 'Y' | 'Z' if !non_modal => {
                    pos["XYZ".find(l).unwrap()] = v;
                    moved = true;
                }
                _ => {}
            }
        }
        if moved {
            moves.push((motion, pos));
        }
    }
    moves
}

#[test]
fn seed_program_runs_625_plunges_without_subprograms() {
    let (text, diags) = run(SEED, Preset::default());
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert!(
        diags
            .iter()
            .any(|d| d.code == "grbl::expand-subprograms" && !d.is_error()),
        "the inserted pass is announced: {diags:?}"
    );
    for line in text.lines() {
        let view = grbl_view(line);
        for bad in ["M98", "M99", "O"] {
            assert!(!view.contains(bad), "`{bad}` in `{line}`");
        }
    }
    let moves = check_grbl(&text);
    // G0 Z1, 625 x (G0 Z0.1, G1 Z0.04, G0 Z1), G0 Z0.
    assert_eq!(moves.len(), 1 + 625 * 3 + 1);
    let plunges: Vec<_> = moves.iter().filter(|m| m.0 == 1).collect();
    assert_eq!(plunges.len(), 625);
    for (k, rep) in moves[1..moves.len() - 1].chunks(3).enumerate() {
        let z: Vec<f64> = rep.iter().map(|m| m.1[2]).collect();
        assert_eq!(z, vec![0.1, 0.04, 1.0], "repetition {k}");
        assert_eq!(rep.iter().map(|m| m.0).collect::<Vec<_>>(), vec![0, 1, 0]);
    }
    assert_eq!(moves[moves.len() - 1].1[2], 0.0);
    assert_eq!(text.matches("F20").count(), 1, "modal feed printed once");
    assert!(text.ends_with("M30\n"));
    // The preset that already has the pass: no note, the same text.
    let with = run_toml(SEED, "[[passes]]\nname = \"expand-subprograms\"\n");
    assert!(with.1.iter().all(|d| d.code != "grbl::expand-subprograms"));
    assert_eq!(with.0, text);
}

#[test]
fn plain_gcode_keeps_calls_but_grbl_never_does() {
    // The plain backend without the pass prints the call; Grbl output never does.
    let plain = ncpost::pipeline::compile_str(SEED, &Preset::default()).expect("plain");
    assert!(plain.contains("M98"));
    let (text, _) = run(SEED, Preset::default());
    assert!(!text.contains("M98"));
}

fn corpus(name: &str) -> String {
    let path = format!(
        "{}/../shared/corpus/gcode/{name}",
        env!("CARGO_MANIFEST_DIR")
    );
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// pcb2gcode writes LinuxCNC G-code: `G04 P` is in seconds.
const PCB2GCODE: &str = "[gcode_input]\ndwell_p_milliseconds = false\n";

/// The programmed X, Y, Z of every move of the plain output (same frontend), for
/// comparison with the Grbl output.
fn plain_moves(src: &str) -> Vec<(u32, [f64; 3])> {
    let preset = Preset::from_toml(PCB2GCODE).unwrap();
    let text = ncpost::pipeline::compile_str(src, &preset).expect("plain output");
    let mut pos = [f64::NAN; 3];
    let mut motion = 0;
    let mut moves = Vec::new();
    for line in text.lines() {
        let view = grbl_view(line);
        let mut moved = false;
        let mut non_modal = false;
        let mut k = 0;
        let b = view.as_bytes();
        while k < b.len() {
            let l = b[k] as char;
            k += 1;
            let s = k;
            while k < b.len() && !b[k].is_ascii_alphabetic() {
                k += 1;
            }
            let Ok(v) = view[s..k].parse::<f64>() else {
                continue;
            };
            match l {
                'G' if [0.0, 1.0, 2.0, 3.0].contains(&v) => motion = v as u32,
                'G' if [4.0, 10.0, 28.0, 30.0, 53.0, 92.0].contains(&v) => non_modal = true,
                'X' | 'Y' | 'Z' if !non_modal => {
                    pos["XYZ".find(l).unwrap()] = v;
                    moved = true;
                }
                _ => {}
            }
        }
        if moved {
            moves.push((motion, pos));
        }
    }
    moves
}

#[test]
fn corpus_pcb2gcode_files() {
    for name in [
        "pcb2gcode_d1minigsr_front.ngc",
        "pcb2gcode_easysdr_drill.ngc",
        "pcb2gcode_multivibrator_tiles_milldrill.ngc",
    ] {
        let src = corpus(name);
        let (text, diags) = run_toml(&src, PCB2GCODE);
        assert!(errors(&diags).is_empty(), "{name}: {diags:?}");
        let moves = check_grbl(&text);
        // The same path as the plain backend prints: Grbl output only drops words.
        let plain = plain_moves(&src);
        if let Some(k) = (0..moves.len().max(plain.len())).find(|&k| {
            moves.get(k).map(|m| format!("{m:?}")) != plain.get(k).map(|m| format!("{m:?}"))
        }) {
            panic!(
                "{name}: move {k} differs: grbl {:?}, plain {:?} ({} and {} moves)",
                moves.get(k),
                plain.get(k),
                moves.len(),
                plain.len()
            );
        }
        // Tool changes are commented out with a warning; the M0 pause after them stays.
        let m6 = src.lines().filter(|l| grbl_view(l) == "M6").count();
        let warned = diags
            .iter()
            .filter(|d| d.code == "grbl::unsupported" && d.message.contains("M6"))
            .count();
        assert_eq!(m6, warned, "{name}");
        assert_eq!(
            text.matches("(M6: not supported by Grbl)").count(),
            m6,
            "{name}"
        );
        // pcb2gcode's G04 P1.0 is one second; Grbl's P is seconds too.
        if src.contains("G04 P1.00000") {
            assert!(text.contains("G4 P1\n"), "{name}");
        }
        let head: String = text.lines().take(60).collect::<Vec<_>>().join("\n");
        let report = format!(
            "lines: {}\nmoves: {}\nG1 moves: {}\n== diagnostics\n{}\n== first 60 lines\n{head}\n",
            text.lines().count(),
            moves.len(),
            moves.iter().filter(|m| m.0 == 1).count(),
            render_all(name, &diags)
        );
        insta::assert_snapshot!(format!("corpus_{name}"), report);
    }
}

#[test]
fn pcb2gcode_autoleveller_parameters_are_errors() {
    // pcb2gcode's LinuxCNC autoleveller probes into parameters (#500...) and computes
    // with them: Grbl cannot run that (use --pass heightmap instead).
    let name = "pcb2gcode_al_linuxcnc_back.ngc";
    let (_, diags) = run_toml(&corpus(name), PCB2GCODE);
    let errs = errors(&diags);
    assert!(!errs.is_empty());
    assert!(
        errs.iter()
            .all(|d| d.code == "grbl::unevaluated" || d.code == "grbl::subprogram"),
        "{errs:?}"
    );
    let first: Vec<Diagnostic> = errs.iter().take(3).map(|d| (*d).clone()).collect();
    insta::assert_snapshot!("autoleveller_errors", render_all(name, &first));
}

#[test]
fn unexpandable_call_is_an_error() {
    let name = "linuxcnc_m98m99_14_o_expression_call.ngc";
    let (_, diags) = run(&corpus(name), Preset::default());
    let errs: Vec<Diagnostic> = errors(&diags).into_iter().cloned().collect();
    assert!(
        errs.iter().any(|d| d.code == "grbl::subprogram"),
        "{errs:?}"
    );
    insta::assert_snapshot!("unexpandable_call", render_all(name, &errs));
}

#[test]
fn tape_delimiters_program_numbers_dwell_and_comments() {
    let (text, diags) = run(
        "%\nO1000 (part)\nG0 X1 ; go\nG4 P250\n(note)\nM30\n%\n",
        Preset::default(),
    );
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert_eq!(
        text,
        "(program O1000) (part)\nG21 G90\nG0 X1 ( go)\nG4 P0.25\n(note)\nM30\n"
    );
    check_grbl(&text);
}

#[test]
fn inverse_time_needs_allow_g93() {
    let src = "G0 X0 Y0 Z0\nG93 G1 X10 F2\nG94 G1 X0 F100\n";
    let (_, diags) = run(src, Preset::default());
    let errs: Vec<Diagnostic> = errors(&diags).into_iter().cloned().collect();
    assert_eq!(errs.len(), 1, "{errs:?}");
    assert_eq!(errs[0].code, "grbl::inverse-time");
    insta::assert_snapshot!("inverse_time", render_all("g93.nc", &errs));
    let (text, diags) = run_toml(src, "[grbl]\nallow_g93 = true\n");
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert!(text.contains("G93\nG1 X10 F2\nG94\nG1 X0 F100\n"), "{text}");
    check_grbl(&text);
}

#[test]
fn axes_grbl_lacks_are_errors() {
    let (_, diags) = run("G0 X0 Y0 Z0 A0\nG1 X1 A90 F100\n", Preset::default());
    let errs = errors(&diags);
    assert!(
        !errs.is_empty() && errs.iter().all(|d| d.code == "grbl::axis"),
        "{errs:?}"
    );
    assert!(errs[0].message.contains('A'));
}

#[test]
fn arc_turns_need_linearize_arcs() {
    let src = "G0 X5 Y0 Z0\nG2 X5 Y0 I-5 J0 Z-3 P3 F100\n";
    let (_, diags) = run(src, Preset::default());
    let errs: Vec<Diagnostic> = errors(&diags).into_iter().cloned().collect();
    assert_eq!(errs.len(), 1, "{errs:?}");
    assert_eq!(errs[0].code, "grbl::arc-turns");
    insta::assert_snapshot!("arc_turns", render_all("turns.nc", &errs));
    let (text, diags) = run_toml(src, "[[passes]]\nname = \"linearize-arcs\"\n");
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let moves = check_grbl(&text);
    // Three turns down 3 mm, every vertex on the circle of radius 5 about the origin.
    assert_eq!(moves.last().unwrap().1, [5.0, 0.0, -3.0]);
    for (_, p) in &moves[1..] {
        assert!((p[0].hypot(p[1]) - 5.0).abs() < 2e-3, "{p:?}");
    }
    // A single arc (no P) stays an arc, in any plane.
    let (text, diags) = run(
        "G0 X0 Y0 Z0\nG18\nG2 X10 Z0 I5 K0 F100\n",
        Preset::default(),
    );
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert!(text.contains("G18\nG2 X10 Z0 I5 K0 F100\n"), "{text}");
    check_grbl(&text);
}

#[test]
fn long_lines_are_errors() {
    // 9 decimals: the helix line has more than 79 characters Grbl counts.
    let src = "G0 X-12345.123456789 Y-12345.123456789 Z-1.5\nG2 X-12345.123456789 Y-12334.876543211 Z-123.123456789 I0.123456789 J5.123456789 F1000\n";
    let toml = "[grbl.decimals]\nlinear = 9\nrotary = 3\nextruder = 5\nfeed = 1\n";
    let (_, diags) = run_toml(src, toml);
    let errs: Vec<Diagnostic> = errors(&diags).into_iter().cloned().collect();
    assert_eq!(errs.len(), 1, "{errs:?}");
    assert_eq!(errs[0].code, "grbl::line-length");
    insta::assert_snapshot!("line_length", render_all("long.nc", &errs));
    // Comments and spaces do not count: a long comment is fine.
    let comment = "x".repeat(200);
    let (text, diags) = run(&format!("G0 X1 ({comment})\n"), Preset::default());
    assert!(errors(&diags).is_empty(), "{diags:?}");
    check_grbl(&text);
    assert_eq!(grbl::counted_length(&format!("G0 X1 ({comment})")), 4);
}

#[test]
fn unsupported_codes_comment_error_or_keep() {
    let src = "G0 X0 Y0 Z5\nT2 M6\nM7\nG43 H2\nM3 S1000\nG64 P0.01\nG38.2 Z-2 F20\nM30\n";
    let (text, diags) = run(src, Preset::default());
    assert!(errors(&diags).is_empty(), "{diags:?}");
    let warned: Vec<&str> = diags
        .iter()
        .filter(|d| d.code == "grbl::unsupported")
        .map(|d| d.message.as_str())
        .collect();
    assert_eq!(
        warned,
        vec![
            "`M6` is not supported by Grbl 1.1",
            "`M7` is not supported by Grbl 1.1",
            "`G43 H2` is not supported by Grbl 1.1",
            "`G64 P0.01` is not supported by Grbl 1.1",
        ]
    );
    check_grbl(&text);
    assert!(text.contains("T2 (M6: not supported by Grbl)\n"), "{text}");
    assert!(text.contains("M3 S1000\n"));
    assert!(
        text.contains("(G64 P0.01: not supported by Grbl)\n"),
        "{text}"
    );
    // Probing is Grbl's own: printed as written.
    assert!(text.contains("G38.2 Z-2 F20\n"), "{text}");
    // A canned cycle is drilled as moves (`expand-cycles`, tests/cycles.rs): no G81 or G80
    // reaches Grbl.
    let (text, diags) = run(
        "G0 X0 Y0 Z5\nG81 X1 Y1 Z-1 R1 F50\nG80\n",
        Preset::default(),
    );
    assert!(errors(&diags).is_empty(), "{diags:?}");
    assert!(
        text.contains("G1 Z-1 F50\n") && !text.contains("G8"),
        "{text}"
    );
    // A build with M7.
    let (text, diags) = run_toml(src, "[grbl]\nm7 = true\n");
    assert!(text.contains("\nM7\n"), "{text}");
    assert_eq!(
        diags
            .iter()
            .filter(|d| d.code == "grbl::unsupported")
            .count(),
        3
    );
    // error
    let (_, diags) = run_toml(src, "[grbl]\nunsupported = \"error\"\n");
    assert_eq!(errors(&diags).len(), 4);
    // keep (grblHAL)
    let (text, diags) = run_toml(src, "[grbl]\nunsupported = \"keep\"\n");
    assert!(diags.iter().all(|d| d.code != "grbl::unsupported"));
    assert!(text.contains("T2 M6\n"));
}

#[test]
fn line_numbers_and_offsets() {
    let (text, diags) = run_toml(
        "G92 X10\nG0 X12 Y0 Z1\nG92.1\nG0 X1\n",
        "[grbl]\nline_numbers = true\n",
    );
    assert!(errors(&diags).is_empty(), "{diags:?}");
    check_grbl(&text);
    assert!(text.lines().all(|l| l.starts_with('N')), "{text}");
    let (_, diags) = run("G0 X0\nG92 X5\nG92.2\nG0 X1\n", Preset::default());
    assert!(errors(&diags).iter().any(|d| d.code == "grbl::offset"));
}

#[test]
fn split_unsupported_groups() {
    let o = grbl::Options::default();
    assert_eq!(
        grbl::split_unsupported("G28 G91 Z0", &o),
        ("G28 G91 Z0".to_string(), String::new())
    );
    assert_eq!(
        grbl::split_unsupported("M106 S255", &o),
        (String::new(), "M106 S255".to_string())
    );
    assert_eq!(
        grbl::split_unsupported("G59.1", &o),
        (String::new(), "G59.1".to_string())
    );
    assert_eq!(
        grbl::split_unsupported("G90.1", &o),
        (String::new(), "G90.1".to_string())
    );
    assert_eq!(
        grbl::split_unsupported("G91.1 G17", &o),
        ("G91.1 G17".to_string(), String::new())
    );
}

/// Grbl's own arc check (`gc_execute_line`, error:33): the end's distance from the centre
/// differs from the start's by more than 0.005 mm and 0.1 % of the radius, or by 0.5 mm.
fn grbl_refuses(start: [f64; 2], end: [f64; 2], centre: [f64; 2]) -> bool {
    let r0 = (start[0] - centre[0]).hypot(start[1] - centre[1]);
    let r1 = (end[0] - centre[0]).hypot(end[1] - centre[1]);
    let dr = (r1 - r0).abs();
    dr > 0.5 || (dr > 0.005 && dr > 0.001 * r0)
}

/// Issue 20, defect 9: an arc Grbl would stop on (error:33, the job halts there) is an
/// error at its line and column when the target is Grbl, although it is within the
/// frontend's own 0.01 mm; one just inside Grbl's 0.005 mm is printed, and Grbl's check
/// on the printed numbers passes. RepRapFirmware runs either arc.
#[test]
fn an_arc_grbl_refuses_is_an_error_at_its_line_and_column() {
    let off = "G21 G90\nG0 X0 Y0\nG2 X10.006 Y0 I5 J0 F300\n";
    let (_, diags) = run(off, Preset::default());
    let e = errors(&diags);
    assert_eq!(e.len(), 1, "{}", render_all("off.nc", &diags));
    assert_eq!(e[0].code, "gcode::arc");
    let at = e[0].location.as_ref().expect("a place");
    assert_eq!((at.line, at.column), (3, 1));
    let inside = "G21 G90\nG0 X0 Y0\nG2 X10.004 Y0 I5 J0 F300\n";
    let (text, diags) = run(inside, Preset::default());
    assert!(errors(&diags).is_empty(), "{}", render_all("in.nc", &diags));
    let arc = text.lines().find(|l| l.starts_with("G2")).expect("the arc");
    let w = |c: char| {
        arc.split_whitespace()
            .find_map(|w| w.strip_prefix(c)?.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    assert!(
        !grbl_refuses([0.0, 0.0], [w('X'), w('Y')], [w('I'), w('J')]),
        "{arc}"
    );
    let mut rrf = Pipeline::builder()
        .preset(Preset::default())
        .emit(Emit::Rrf)
        .build()
        .expect("builds");
    let (mut out, mut diags) = (Vec::new(), Vec::new());
    rrf.run_gcode(off.as_bytes(), &mut out, &mut |d| diags.push(d))
        .expect("runs");
    assert!(
        errors(&diags).is_empty(),
        "{}",
        render_all("rrf.nc", &diags)
    );
}
