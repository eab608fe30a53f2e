//! No input makes the pipeline panic.
//!
//! Random bytes (invalid UTF-8, NUL, `\r`, very long tokens) and "token soup" (random
//! sequences of plausible G-code fragments) go through the whole pipeline with the
//! `default` and `duet-cnc` presets and the IR dump (`--emit ir`). A run may succeed
//! or fail with diagnostics, but:
//! - it does not panic, and neither does rendering its diagnostics;
//! - every error has a location with line ≥ 1 (within the input), except
//!   `gcode::empty` and `io::*` errors;
//! - the summary counts the errors it reported;
//! - no error says the frontend broke an IR invariant (`ir::invariant`) or handed the
//!   backend something it cannot print from any input (`back::pose`,
//!   `back::arc-start`).

use ncpost::Diagnostic;
use ncpost::pipeline::{Pipeline, compile_str};
use ncpost::preset::{Emit, Preset};
use proptest::prelude::*;
use proptest::test_runner::Config as ProptestConfig;

fn presets() -> Vec<(&'static str, Preset)> {
    let default = Preset::builtin("default").unwrap();
    let duet = Preset::builtin("duet-cnc").unwrap();
    let mut ir = default.clone();
    ir.emit = Emit::Ir;
    vec![
        ("default", default),
        ("duet-cnc", duet),
        ("default --emit ir", ir),
    ]
}

/// Lines of `input` as the frontend counts them (a final line without `\n` counts).
fn line_count(input: &[u8]) -> usize {
    let newlines = input.iter().filter(|&&b| b == b'\n').count();
    newlines + usize::from(!input.ends_with(b"\n") && !input.is_empty())
}

/// Checks one diagnostic against the contract above; `Err` says what is wrong.
fn check_diag(d: &Diagnostic, lines: usize) -> Result<(), String> {
    // Rendering must not panic either (the CLI renders every diagnostic).
    let _ = d.render("input.gcode", false);
    let _ = d.render("input.gcode", true);
    let _ = d.to_json("input.gcode");
    let _ = d.to_string();
    if !d.is_error() {
        return Ok(());
    }
    if matches!(d.code, "ir::invariant" | "back::pose" | "back::arc-start") {
        return Err(format!("internal error reported as a diagnostic: {d}"));
    }
    if d.code == "gcode::empty" || d.code.starts_with("io::") {
        return Ok(());
    }
    match &d.location {
        None => Err(format!("error without a location: {d}")),
        Some(l) if l.line == 0 => Err(format!("error at line 0: {d}")),
        Some(l) if l.line as usize > lines.max(1) => Err(format!(
            "error at line {} of a {lines}-line input: {d}",
            l.line
        )),
        Some(l) if l.column == 0 => Err(format!("error at column 0: {d}")),
        Some(_) => Ok(()),
    }
}

/// Runs `input` through every preset with [`Pipeline::run_gcode`].
fn run_bytes(input: &[u8]) -> Result<(), String> {
    let lines = line_count(input);
    for (name, preset) in presets() {
        let mut pipeline = Pipeline::builder()
            .preset(preset)
            .build()
            .map_err(|e| format!("{name}: {e}"))?;
        let mut diags = Vec::new();
        let mut out = Vec::new();
        let summary = pipeline
            .run_gcode(input, &mut out, &mut |d| diags.push(d))
            .map_err(|d| format!("{name}: writing to memory failed: {d}"))?;
        let errors = diags.iter().filter(|d| d.is_error()).count() as u64;
        if summary.errors != errors {
            return Err(format!(
                "{name}: summary counts {} errors, {errors} were reported",
                summary.errors
            ));
        }
        for d in &diags {
            check_diag(d, lines).map_err(|e| format!("{name}: {e}"))?;
        }
    }
    Ok(())
}

/// Runs text through [`compile_str`], the per-line syntax API and the byte pipeline.
fn run_text(input: &str) -> Result<(), String> {
    let lines = line_count(input.as_bytes());
    for (name, preset) in presets() {
        if let Err(diags) = compile_str(input, &preset) {
            if !diags.iter().any(Diagnostic::is_error) {
                return Err(format!("{name}: compile_str failed without an error"));
            }
            for d in &diags {
                check_diag(d, lines).map_err(|e| format!("{name}: {e}"))?;
            }
        }
    }
    let (mut toks, mut items) = (Vec::new(), Vec::new());
    for line in input.lines() {
        let _ = ncpost::front::gcode::parse_line(line, &mut toks, &mut items);
    }
    run_bytes(input.as_bytes())
}

// ---------------------------------------------------------------------------------------
// Random bytes
// ---------------------------------------------------------------------------------------

/// Pieces of byte input: anything, line ends, NUL, bytes that are never UTF-8,
/// truncated multi-byte sequences, and very long tokens.
fn byte_chunk() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        6 => prop::collection::vec(any::<u8>(), 0..48),
        3 => prop::sample::select(vec![
            &b"\n"[..], b"\r\n", b"\r", b"\0", b"\xff", b"\xfe", b"\xc3", b"\xe2\x82",
            b"\xf0\x9f\x98", b"\xed\xa0\x80", b"\xef\xbb\xbf", b"\x0b", b"\x0c", b"\t",
        ])
        .prop_map(|b| b.to_vec()),
        4 => "[ -~]{0,24}".prop_map(String::into_bytes),
        1 => (prop::sample::select(vec!["X", "G", "E", "(", ";", "\"", "abc", "#", "N"]),
              prop::sample::select(vec!["9", "0", "1.", "a", " ", "(", "e"]),
              100usize..6000)
            .prop_map(|(head, rep, n)| {
                let mut s = head.to_string();
                s.push_str(&rep.repeat(n));
                s.into_bytes()
            }),
    ]
}

fn bytes_input() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(byte_chunk(), 0..16).prop_map(|chunks| chunks.concat())
}

// ---------------------------------------------------------------------------------------
// Token soup
// ---------------------------------------------------------------------------------------

const FRAGMENTS: &[&str] = &[
    // Words and letters.
    "G",
    "M",
    "T",
    "S",
    "F",
    "X",
    "Y",
    "Z",
    "A",
    "B",
    "C",
    "E",
    "I",
    "J",
    "K",
    "R",
    "P",
    "L",
    "N",
    "O",
    "Q",
    "H",
    "D",
    "U",
    "V",
    "W",
    "x",
    "e",
    "g",
    "G0",
    "G1",
    "G2",
    "G3",
    "G4",
    "G00",
    "G01",
    "G02",
    "G03",
    "G04",
    "G17",
    "G18",
    "G19",
    "G20",
    "G21",
    "G28",
    "G38.2",
    "G43.4",
    "G53",
    "G54",
    "G80",
    "G81",
    "G90",
    "G91",
    "G90.1",
    "G91.1",
    "G92",
    "G92.1",
    "G92.2",
    "G92.3",
    "G93",
    "G94",
    "G95",
    "G6",
    "G10 L20 P1",
    "M3",
    "M5",
    "M6",
    "M82",
    "M83",
    "M98",
    "M99",
    "M30",
    "M587",
    "T1",
    "S1000",
    "F100",
    "F0",
    "P2",
    "P0.5",
    "R5",
    "R-5",
    "R0",
    "I5 J0",
    "J5 K0",
    "K5 I0",
    "E0.5",
    "E-1",
    "X10",
    "Y-5",
    "Z.5",
    "A90",
    "C360",
    "O100",
    // Numbers.
    "0",
    "-0",
    "+1",
    "1.",
    ".5",
    "-.5",
    "1.2.3",
    "..",
    ".",
    "-",
    "+",
    "1e400",
    "1E5",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "Infinity",
    "99999999999999",
    "0.000000001",
    "1e",
    "007",
    // Comments, strings, checksums, delimiters, block delete.
    "(",
    ")",
    "()",
    "(a (b) c)",
    "(unterminated",
    ";",
    "; comment",
    "*",
    "*12",
    "*255",
    "%",
    "/",
    "/2",
    "\"",
    "\"\"",
    "\"a;b\"",
    "\"(x)\"",
    "'",
    // Parameters and expressions.
    "#1",
    "#<x>",
    "#<_y>",
    "=",
    "#1=2",
    "[",
    "]",
    "[#1+2]",
    "{",
    "}",
    "{var.x}",
    "<",
    ">",
    "@",
    "^",
    "$",
    "&",
    "\\",
    "!",
    "?",
    ",",
    ":",
    // Control flow.
    "o100 sub",
    "o100 endsub",
    "o100 call",
    "o100 if [1]",
    "o100 endif",
    "o<s> while [1]",
    "o<s> endwhile",
    "o1 do",
    "o1 while [0]",
    "o2 repeat [3]",
    "o2 endrepeat",
    "if",
    "elif",
    "else",
    "while",
    "endwhile",
    "var x = 1",
    "global g = 2",
    "set var.x = 3",
    "echo",
    "abort",
    "break",
    "M98 P100 L2",
    "O200",
    // Blanks and line ends.
    " ",
    "  ",
    "\t",
    "\n",
    "\n",
    "\n",
    "\r\n",
    "\r",
    "\0",
    "\u{feff}",
    "é",
    "°",
];

fn soup_piece() -> impl Strategy<Value = String> {
    prop_oneof![
        8 => prop::sample::select(FRAGMENTS).prop_map(str::to_string),
        2 => (
            prop::sample::select(vec!["X", "Y", "Z", "I", "J", "K", "R", "E", "F", "P", "S", "G", "M", "A", "C"]),
            -100_000i64..100_000,
            0u32..4,
        )
            .prop_map(|(l, v, d)| format!("{l}{}", v as f64 / 10f64.powi(d as i32))),
        1 => "[a-zA-Z]{2,8}",
        1 => (1usize..=8).prop_map(|n| " ".repeat(n)),
    ]
}

fn soup_input() -> impl Strategy<Value = String> {
    prop::collection::vec((soup_piece(), any::<bool>()), 0..80).prop_map(|pieces| {
        let mut s = String::new();
        for (p, space) in pieces {
            s.push_str(&p);
            if space {
                s.push(' ');
            }
        }
        s
    })
}

/// Plausible programs: lines of a few fragments each, so more lines reach the lowering
/// (modal state, arcs, offsets) rather than failing in the lexer.
fn soup_program() -> impl Strategy<Value = String> {
    let line = prop::collection::vec(soup_piece(), 0..8).prop_map(|p| p.join(" "));
    prop::collection::vec(line, 1..30).prop_map(|lines| lines.join("\n"))
}

/// 200 cases per property by default (the file runs in about 10 s in debug);
/// `NCPOST_NO_PANIC_CASES` for a longer search.
fn config() -> ProptestConfig {
    ProptestConfig {
        cases: std::env::var("NCPOST_NO_PANIC_CASES").map_or(200, |v| v.parse().expect("a number")),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn random_bytes_do_not_panic(input in bytes_input()) {
        run_bytes(&input).map_err(|e| TestCaseError::fail(format!("{e}\ninput: {:?}", String::from_utf8_lossy(&input))))?;
    }

    #[test]
    fn token_soup_does_not_panic(input in soup_input()) {
        run_text(&input).map_err(|e| TestCaseError::fail(format!("{e}\ninput: {input:?}")))?;
    }

    #[test]
    fn token_soup_programs_do_not_panic(input in soup_program()) {
        run_text(&input).map_err(|e| TestCaseError::fail(format!("{e}\ninput: {input:?}")))?;
    }
}

// ---------------------------------------------------------------------------------------
// Fixed inputs
// ---------------------------------------------------------------------------------------

fn assert_no_panic(input: &[u8]) {
    if let Err(e) = run_bytes(input) {
        panic!(
            "{e}\ninput: {:?}",
            String::from_utf8_lossy(&input[..input.len().min(200)])
        );
    }
    if let Ok(text) = std::str::from_utf8(input)
        && let Err(e) = run_text(text)
    {
        panic!("{e}\ninput: {:?}", &text[..text.len().min(200)]);
    }
}

#[test]
fn edge_inputs_do_not_panic() {
    let cases: &[&[u8]] = &[
        b"",
        b"\n",
        b"\r",
        b"\r\n\r\n",
        b"\0",
        b"\xff\xfe\xfd",
        b"G1 X1\xff\n",
        b"\xef\xbb\xbfG0 X1\n",
        b"G1 X1 X2\n",
        b"G1 X1e400\n",
        b"G1 XNaN\n",
        b"G2 X1 Y1\n",
        b"G0 X0 Y0\nG2 X10 Y0 I5 R5\n",
        b"G0 X0 Y0\nG2 X10 Y0 R0\n",
        b"G0 X0 Y0\nG2 X0 Y0 R5\n",
        b"G0 X0 Y0\nG2 X100 Y0 R1\n",
        b"G0 X0 Y0\nG2 X0 Y0 I0 J0\n",
        b"G0 X0 Y0\nG2 X10 Y0 I5 J0 P0\n",
        b"G0 X0 Y0\nG2 X10 Y0 I5 J0 P4294967296\n",
        b"G93\nG1 X1\n",
        b"G1 X99999999999 E99999999999 F99999999999\n",
        b"G91\nG1 X999999999999\nG1 X999999999999\nG1 X999999999999\n",
        b"G92 X999999999999\nG1 X-999999999999\n",
        b"G20\nG1 X999999999999 F999999999999\n",
        b"G4 P-1\nG4 S1 P1\nG4\n",
        b"o100 sub\nG1 X1\n",
        b"if true\n  G1 X1\n",
        b"O100\nM99\nO200\n",
        b"G1 X1 ; \xe2\x82\n",
        b"(\n)\n((((\n",
        b"*\n*1\nG1 X1*999999999999999999999\n",
        b"%\n%\n%",
        b"/\n/G1\n//\n",
        b"M587 S\"\n",
        b"G53\nG53 G0\nG53 X1 Y1\n",
    ];
    for c in cases {
        assert_no_panic(c);
    }
}

/// Lines far longer than anything real: a long number, a long comment, and a line over
/// the frontend's 1 MiB limit.
#[test]
fn long_lines_do_not_panic() {
    let mut long_number = b"G1 X".to_vec();
    long_number.extend(std::iter::repeat_n(b'9', 100_000));
    long_number.push(b'\n');
    assert_no_panic(&long_number);

    let mut long_comment = b"G1 X1 (".to_vec();
    long_comment.extend(std::iter::repeat_n(b'x', 100_000));
    long_comment.extend_from_slice(b")\nG1 X2\n");
    assert_no_panic(&long_comment);

    // Over the line limit, then a good line: the error and the recovery.
    let mut over = std::iter::repeat_n(b'G', (1 << 20) + 10).collect::<Vec<u8>>();
    over.extend_from_slice(b"\nG0 X1\n");
    assert!(run_bytes(&over).is_ok());
}

/// Many lines, to reach the pipeline's progress and buffering paths.
#[test]
fn many_lines_do_not_panic() {
    let mut s = String::new();
    for i in 0..20_000 {
        s.push_str(&format!("G1 X{} Y{} E{}\n", i % 97, i % 13, i));
    }
    assert_no_panic(s.as_bytes());
}
