//! Bad-input fixtures: every diagnostic the G-code frontend reports for them, rendered
//! plain (ASCII, no colour, width 80) and snapshotted with insta, plus the severity, code,
//! line and column each one must have.
//!
//! The fixtures live in `tests/fixtures/bad/`; the first line of each is a `;` comment that
//! says what it tests and where it comes from. Inputs that cannot be a small committed file
//! (an empty file, a 10 MB line, random bytes) are generated here.

use std::path::{Path, PathBuf};

use ncpost::diag::{Diagnostic, Severity};
use ncpost::front::Frontend;
use ncpost::front::gcode::{Options, Parser, parse_str};
use ncpost::ir::{Block, BlockKind};

/// Every fixture in `tests/fixtures/bad/`; `fixtures_are_all_tested` keeps it in step with
/// the directory.
const FIXTURES: &[&str] = &[
    "arc_both_ijk_and_r.gcode",
    "arc_fractional_turns.gcode",
    "arc_k_in_g17.gcode",
    "arc_neither_ijk_nor_r.gcode",
    "arc_r_chord_too_long.gcode",
    "arc_radius_mismatch.gcode",
    "binary_png_header.gcode",
    "checksum_mid_line.gcode",
    "checksum_mismatch.gcode",
    "control_characters.gcode",
    "duplicate_axis_word.gcode",
    "exponent_x1e400.gcode",
    "inverse_time_without_f.gcode",
    "letter_without_number.gcode",
    "long_line_column.gcode",
    "many_bad_lines.gcode",
    "modal_conflicts.gcode",
    "nan_spelled_with_sign.gcode",
    "nan_word.gcode",
    "negative_feed.gcode",
    "no_motion_mode.gcode",
    "not_utf8_latin1_comment.gcode",
    "unterminated_comment_after_code.gcode",
    "unterminated_comment_alone.gcode",
];

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/bad")
}

fn read_bytes(name: &str) -> Vec<u8> {
    let path = fixture_dir().join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

fn read_text(name: &str) -> String {
    String::from_utf8(read_bytes(name)).unwrap_or_else(|_| panic!("{name} is not UTF-8"))
}

/// All diagnostics of `src` through `parse_str`; checks that the result is `Err` exactly
/// when there is an error.
fn parse_text(src: &str, options: &Options) -> Vec<Diagnostic> {
    match parse_str(src, options) {
        Ok(p) => {
            assert!(
                !p.diagnostics.iter().any(Diagnostic::is_error),
                "parse_str returned Ok with errors: {:?}",
                p.diagnostics
            );
            p.diagnostics
        }
        Err(diags) => {
            assert!(
                diags.iter().any(Diagnostic::is_error),
                "parse_str returned Err without an error: {diags:?}"
            );
            diags
        }
    }
}

/// Blocks and diagnostics of `bytes` through the streaming parser (any bytes, not only
/// UTF-8).
fn parse_bytes(bytes: &[u8], options: Options) -> (Vec<Block>, Vec<Diagnostic>) {
    let mut parser = Parser::new(bytes, options);
    let mut diags = Vec::new();
    let mut blocks = Vec::new();
    while let Some(b) = parser.next_block(&mut diags) {
        blocks.push(b);
    }
    (blocks, diags)
}

/// Every diagnostic rendered plain, as the snapshots hold them.
fn render_all(file: &str, diags: &[Diagnostic]) -> String {
    diags
        .iter()
        .map(|d| d.render(file, false))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Makes control characters (other than the line feed) visible, for snapshots of
/// binary input; a snapshot file must stay text.
fn visible_controls(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_control() && c != '\n' {
                c.escape_unicode().to_string()
            } else {
                c.to_string()
            }
        })
        .collect()
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

/// Asserts that `diags` holds exactly one diagnostic and returns it.
#[track_caller]
fn only(diags: &[Diagnostic]) -> &Diagnostic {
    assert_eq!(diags.len(), 1, "expected one diagnostic, got {diags:#?}");
    &diags[0]
}

/// Parses a text fixture with default options, snapshots the rendering and returns the
/// diagnostics.
fn check_text(name: &str, snapshot: &str) -> Vec<Diagnostic> {
    check_text_with(name, snapshot, &Options::default())
}

fn check_text_with(name: &str, snapshot: &str, options: &Options) -> Vec<Diagnostic> {
    let diags = parse_text(&read_text(name), options);
    insta::assert_snapshot!(snapshot, render_all(name, &diags));
    diags
}

#[test]
fn fixtures_are_all_tested() {
    let mut on_disk: Vec<String> = std::fs::read_dir(fixture_dir())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    on_disk.sort();
    let mut listed: Vec<String> = FIXTURES.iter().map(|s| s.to_string()).collect();
    listed.sort();
    assert_eq!(on_disk, listed, "tests/fixtures/bad and FIXTURES differ");
}

#[test]
fn fixtures_say_what_they_test_and_where_they_come_from() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    for name in FIXTURES {
        let bytes = read_bytes(name);
        let first = bytes.split(|&b| b == b'\n').next().unwrap();
        let first = std::str::from_utf8(first)
            .unwrap_or_else(|_| panic!("{name}: the first line is not ASCII"));
        assert!(first.is_ascii(), "{name}: the first line is not ASCII");
        assert!(
            first.starts_with("; "),
            "{name}: the first line is not a `;` comment"
        );
        if let Some((_, rest)) = first.split_once("derived from corpus ") {
            let file = rest.split_whitespace().next().unwrap();
            if corpus.is_dir() {
                assert!(
                    corpus.join(file).is_file(),
                    "{name}: corpus file {file} does not exist"
                );
            }
        } else {
            assert!(
                first.ends_with("hand-written for ncpost"),
                "{name}: the first line names no origin"
            );
        }
    }
}

#[test]
fn unterminated_comment_after_code() {
    let diags = check_text(
        "unterminated_comment_after_code.gcode",
        "unterminated_comment_after_code",
    );
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::unterminated-comment", 4, 13);
    assert_eq!(
        d.location.as_ref().unwrap().len,
        "(cut to the edge".len() as u32
    );
}

#[test]
fn unterminated_comment_alone() {
    let name = "unterminated_comment_alone.gcode";
    let diags = check_text(name, "unterminated_comment_alone");
    expect(
        only(&diags),
        Severity::Warning,
        "gcode::unterminated-comment",
        3,
        1,
    );
    // The comment is kept.
    let program = parse_str(&read_text(name), &Options::default()).unwrap();
    assert!(
        program
            .blocks
            .iter()
            .flat_map(|b| &b.comments)
            .any(|c| c.text == "tool 3: 6 mm end mill"),
        "{:#?}",
        program.blocks
    );
}

#[test]
fn letter_without_number() {
    let diags = check_text("letter_without_number.gcode", "letter_without_number");
    expect(
        only(&diags),
        Severity::Error,
        "gcode::letter-without-number",
        3,
        4,
    );
}

#[test]
fn exponent_x1e400() {
    let diags = check_text("exponent_x1e400.gcode", "exponent_x1e400");
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::exponent", 3, 4);
    assert_eq!(d.location.as_ref().unwrap().len, "X1e400".len() as u32);
}

#[test]
fn nan_word() {
    let diags = check_text("nan_word.gcode", "nan_word");
    expect(only(&diags), Severity::Error, "gcode::not-a-number", 3, 5);
}

/// `X-inf`, `X nan` and `Y+NaN` are no more numbers than `XNaN`: each line is an error.
#[test]
fn nan_spelled_with_sign() {
    let diags = check_text("nan_spelled_with_sign.gcode", "nan_spelled_with_sign");
    assert_eq!(diags.len(), 3, "{diags:#?}");
    for (d, line) in diags.iter().zip(3..) {
        assert_eq!(d.severity, Severity::Error, "line {line}: {d}");
        assert_eq!(d.location.as_ref().unwrap().line, line);
    }
}

#[test]
fn duplicate_axis_word() {
    let diags = check_text("duplicate_axis_word.gcode", "duplicate_axis_word");
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::duplicate-word", 5, 22);
    assert_eq!(
        d.label.as_deref(),
        Some("second `X`; the first is `X-141.6`")
    );
}

#[test]
fn arc_neither_ijk_nor_r() {
    let diags = check_text("arc_neither_ijk_nor_r.gcode", "arc_neither_ijk_nor_r");
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::arc", 4, 1);
    assert!(d.message.contains("neither"), "{d}");
}

#[test]
fn arc_both_ijk_and_r() {
    let diags = check_text("arc_both_ijk_and_r.gcode", "arc_both_ijk_and_r");
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::arc", 5, 1);
    assert!(d.message.contains("both"), "{d}");
}

/// The opt-in for controllers that cut an arc off its circle (Mach3).
fn keep_off_circle_arcs() -> Options {
    Options {
        strict_arcs: false,
        ..Default::default()
    }
}

#[test]
fn arc_radius_mismatch_warns_when_kept() {
    let diags = check_text_with(
        "arc_radius_mismatch.gcode",
        "arc_radius_mismatch",
        &keep_off_circle_arcs(),
    );
    let d = only(&diags);
    expect(d, Severity::Warning, "gcode::arc-radius", 4, 1);
    assert!(
        d.message
            .contains("5.0000 mm at the start, 8.0000 mm at the end"),
        "{d}"
    );
}

#[test]
fn arc_radius_mismatch_is_an_error_by_default() {
    let diags = check_text("arc_radius_mismatch.gcode", "arc_radius_mismatch_strict");
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::arc", 4, 1);
    assert!(
        d.message
            .contains("5.0000 mm at the start, 8.0000 mm at the end"),
        "{d}"
    );
}

#[test]
fn arc_r_chord_too_long_warns_when_kept() {
    let diags = check_text_with(
        "arc_r_chord_too_long.gcode",
        "arc_r_chord_too_long",
        &keep_off_circle_arcs(),
    );
    let d = only(&diags);
    expect(d, Severity::Warning, "gcode::arc-radius", 5, 1);
    // g20: R0.5 inch is 12.7 mm.
    assert!(d.message.contains("12.7000 mm"), "{d}");
}

#[test]
fn arc_r_chord_too_long_is_an_error_by_default() {
    let diags = check_text("arc_r_chord_too_long.gcode", "arc_r_chord_too_long_strict");
    expect(only(&diags), Severity::Error, "gcode::arc", 5, 1);
}

#[test]
fn modal_conflicts() {
    let diags = check_text("modal_conflicts.gcode", "modal_conflicts");
    assert_eq!(diags.len(), 3, "{diags:#?}");
    expect(&diags[0], Severity::Error, "gcode::modal-conflict", 2, 4);
    assert!(diags[0].message.contains("motion group"), "{}", diags[0]);
    expect(&diags[1], Severity::Error, "gcode::modal-conflict", 3, 5);
    assert!(diags[1].message.contains("distance group"), "{}", diags[1]);
    expect(&diags[2], Severity::Error, "gcode::modal-conflict", 4, 5);
    assert!(diags[2].message.contains("units group"), "{}", diags[2]);
}

#[test]
fn checksum_mismatch() {
    let diags = check_text("checksum_mismatch.gcode", "checksum_mismatch");
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::checksum", 3, 9);
    assert!(d.message.contains("expected *96"), "{d}");
}

#[test]
fn checksum_mid_line() {
    let diags = check_text("checksum_mid_line.gcode", "checksum_mid_line");
    // The checksum is marked: it must end the line.
    expect(
        only(&diags),
        Severity::Error,
        "gcode::checksum-position",
        3,
        9,
    );
}

#[test]
fn inverse_time_without_f() {
    let diags = check_text("inverse_time_without_f.gcode", "inverse_time_without_f");
    expect(
        only(&diags),
        Severity::Error,
        "gcode::inverse-time-feed",
        4,
        1,
    );
}

#[test]
fn no_motion_mode() {
    let diags = check_text("no_motion_mode.gcode", "no_motion_mode");
    expect(only(&diags), Severity::Error, "gcode::no-motion-mode", 3, 1);
}

#[test]
fn negative_feed() {
    let diags = check_text("negative_feed.gcode", "negative_feed");
    expect(only(&diags), Severity::Error, "gcode::feed", 4, 14);
}

#[test]
fn arc_fractional_turns() {
    let diags = check_text("arc_fractional_turns.gcode", "arc_fractional_turns");
    expect(only(&diags), Severity::Error, "gcode::arc-turns", 3, 16);
}

#[test]
fn arc_k_in_g17() {
    let diags = check_text("arc_k_in_g17.gcode", "arc_k_in_g17");
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::arc", 4, 10);
    assert!(d.message.contains("G17"), "{d}");
}

/// Five bad lines between good ones: one run reports all five, each on its own line, and
/// the good lines still become blocks.
#[test]
fn many_bad_lines_are_all_reported() {
    let name = "many_bad_lines.gcode";
    let diags = check_text(name, "many_bad_lines");
    assert_eq!(diags.len(), 5, "{diags:#?}");
    expect(
        &diags[0],
        Severity::Error,
        "gcode::letter-without-number",
        4,
        4,
    );
    expect(&diags[1], Severity::Error, "gcode::duplicate-word", 6, 7);
    expect(&diags[2], Severity::Error, "gcode::feed", 7, 8);
    expect(&diags[3], Severity::Error, "gcode::modal-conflict", 8, 4);
    expect(&diags[4], Severity::Error, "gcode::arc", 10, 1);
    let (blocks, _) = parse_bytes(&read_bytes(name), Options::default());
    let lines: Vec<u32> = blocks
        .iter()
        .filter(|b| matches!(b.kind, BlockKind::Motion(_)))
        .map(|b| b.span.line)
        .collect();
    assert_eq!(lines, [3, 5, 9, 11]);
}

/// On a line longer than the snippet the renderer shows, the location still gives the
/// real column (it is what `--message-format json` prints).
#[test]
fn long_line_column() {
    let name = "long_line_column.gcode";
    let text = read_text(name);
    let line = text.lines().nth(1).unwrap();
    let real_column = line.find(" X2").unwrap() as u32 + 2;
    assert_eq!(real_column, 250);
    let diags = check_text(name, "long_line_column");
    expect(
        only(&diags),
        Severity::Error,
        "gcode::duplicate-word",
        2,
        real_column,
    );
}

#[test]
fn not_utf8_latin1_comment() {
    let name = "not_utf8_latin1_comment.gcode";
    let (_, diags) = parse_bytes(&read_bytes(name), Options::default());
    insta::assert_snapshot!("not_utf8_latin1_comment", render_all(name, &diags));
    assert_eq!(diags.len(), 2, "{diags:#?}");
    // `G0 X0 Y0 (Fr` is 12 characters.
    expect(&diags[0], Severity::Error, "gcode::not-utf8", 3, 13);
    // `(Ø 6) X` is 7 characters (8 bytes): columns count characters.
    expect(&diags[1], Severity::Error, "gcode::not-utf8", 4, 8);
}

#[test]
fn binary_png_header() {
    let name = "binary_png_header.gcode";
    let (_, diags) = parse_bytes(&read_bytes(name), Options::default());
    let rendered = render_all(name, &diags);
    insta::assert_snapshot!("binary_png_header", visible_controls(&rendered));
    assert!(diags.iter().any(Diagnostic::is_error));
    let errors: Vec<&Diagnostic> = diags.iter().filter(|d| d.is_error()).collect();
    expect(errors[0], Severity::Error, "gcode::not-utf8", 2, 1);
    // Line 3 is the PNG header's 0x1a (SUB): a control character.
    expect(errors[1], Severity::Error, "gcode::control-character", 3, 1);
    // NUL NUL NUL CR I H D R, NUL NUL NUL 0x10, NUL NUL NUL 0x10, 0x08 0x06, NUL NUL NUL,
    // 0x1f: the bad byte 0xf3 is the 23rd.
    expect(errors[2], Severity::Error, "gcode::not-utf8", 4, 23);
    for d in &diags {
        assert!(d.location.is_some(), "no location: {d}");
    }
    // Diagnostics must not copy raw control characters (NUL, ESC, ...) to a terminal.
    assert_eq!(
        rendered,
        visible_controls(&rendered),
        "raw control characters in the rendered diagnostics"
    );
}

/// NUL bytes and an escape sequence in an otherwise textual file are binary garbage, not
/// expression syntax: each is an error, and no raw control character reaches the
/// rendered diagnostics.
#[test]
fn control_characters() {
    let name = "control_characters.gcode";
    let (_, diags) = parse_bytes(&read_bytes(name), Options::default());
    let rendered = render_all(name, &diags);
    insta::assert_snapshot!("control_characters", visible_controls(&rendered));
    assert_eq!(diags.len(), 2, "{diags:#?}");
    expect(&diags[0], Severity::Error, diags[0].code, 3, 7);
    expect(&diags[1], Severity::Error, diags[1].code, 4, 1);
    assert_eq!(
        rendered,
        visible_controls(&rendered),
        "raw control characters in the rendered diagnostics"
    );
}

/// An empty input is an error without a place in the file.
#[test]
fn empty_file() {
    let diags = parse_text("", &Options::default());
    insta::assert_snapshot!("empty_file", render_all("empty.gcode", &diags));
    let d = only(&diags);
    assert_eq!((d.severity, d.code), (Severity::Error, "gcode::empty"));
    assert!(d.location.is_none());
    let (blocks, diags) = parse_bytes(b"", Options::default());
    assert!(blocks.is_empty());
    assert_eq!(only(&diags).code, "gcode::empty");
}

/// A 10 MiB line (no line breaks, as in a file whose newlines were lost) against the
/// default 1 MiB limit: one error on its line, and the lines around it are still read.
#[test]
fn ten_mb_line_is_rejected_and_parsing_goes_on() {
    const LEN: usize = 10 << 20;
    let mut input = b"G0 X0 Y0\nG1 X1 F300".to_vec();
    while input.len() < 9 + LEN {
        input.extend_from_slice(b" Y1");
    }
    input.truncate(9 + LEN);
    input.extend_from_slice(b"\nG1 X2\nG1 X Y3\n");
    assert_eq!(Options::default().max_line_len, 1 << 20);
    let (blocks, diags) = parse_bytes(&input, Options::default());
    insta::assert_snapshot!("ten_mb_line", render_all("ten_mb_line.gcode", &diags));
    assert_eq!(diags.len(), 2, "{diags:#?}");
    let d = &diags[0];
    assert_eq!(
        (d.severity, d.code),
        (Severity::Error, "gcode::line-too-long")
    );
    let loc = d.location.as_ref().unwrap();
    assert_eq!((loc.line, loc.column), (2, 1));
    assert!(d.message.contains("1048576"), "{d}");
    // Recovery: line 3 is a move, line 4 is reported.
    expect(
        &diags[1],
        Severity::Error,
        "gcode::letter-without-number",
        4,
        4,
    );
    let lines: Vec<u32> = blocks.iter().map(|b| b.span.line).collect();
    assert_eq!(lines, [1, 3]);
}

/// The message gives the line's length without its line terminator.
#[test]
fn line_too_long_reports_the_length_of_the_line() {
    const LEN: usize = 10 << 20;
    let mut input = vec![b'G'; 1];
    input.resize(LEN, b'1');
    input.push(b'\n');
    let (_, diags) = parse_bytes(&input, Options::default());
    let d = only(&diags);
    assert_eq!(d.code, "gcode::line-too-long");
    assert!(
        d.message.contains(&format!(" {LEN} bytes long")),
        "a {LEN}-byte line: {d}"
    );
}

/// `max_line_len` is the longest line accepted: with 10, a line of 10 bytes is read and
/// one of 11 is an error, whatever its terminator (`\n`, `\r\n` or the end of input).
#[test]
fn max_line_len_is_exact() {
    let options = Options {
        max_line_len: 10,
        ..Default::default()
    };
    for (input, too_long) in [
        (&b"G1 X123456\n"[..], false),
        (b"G1 X123456\r\n", false),
        (b"G1 X123456", false),
        (b"G1 X1234567\n", true),
        (b"G1 X1234567\r\n", true),
        (b"G1 X1234567", true),
        (b"G1 X12345678", true),
    ] {
        let input = [b"G0 X0\n".as_slice(), input].concat();
        let (_, diags) = parse_bytes(&input, options.clone());
        let reported = diags.iter().any(|d| d.code == "gcode::line-too-long");
        assert_eq!(
            reported,
            too_long,
            "{:?} with max_line_len 10: {diags:#?}",
            String::from_utf8_lossy(&input)
        );
    }
}

/// Random bytes (fixed seed): the input is rejected, every diagnostic has a line, and
/// one run reports many bad lines rather than stopping at the first.
#[test]
fn random_bytes_are_rejected() {
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut bytes = Vec::with_capacity(4096);
    for _ in 0..4096 {
        // xorshift64*
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        bytes.push((state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 56) as u8);
    }
    let (_, diags) = parse_bytes(&bytes, Options::default());
    assert!(diags.iter().any(Diagnostic::is_error), "{diags:#?}");
    for d in &diags {
        assert!(d.location.is_some(), "no location: {d}");
    }
    let lines: std::collections::BTreeSet<u32> = diags
        .iter()
        .filter(|d| d.is_error())
        .map(|d| d.location.as_ref().unwrap().line)
        .collect();
    assert!(lines.len() > 1, "{diags:#?}");
}

/// The rendered header `[file:line:column]` points at the marked text, not at column 1.
#[test]
fn rendered_header_shows_the_real_column() {
    let diags = parse_text("G0 X0 Y0\nG1 X Y10\n", &Options::default());
    let d = only(&diags);
    expect(d, Severity::Error, "gcode::letter-without-number", 2, 4);
    let text = d.render("t.gcode", false);
    assert!(text.contains("[t.gcode:2:4]"), "{text}");
}

/// The plain rendering is ASCII (apart from the quoted source line) and has no colour.
#[test]
fn plain_rendering_is_ascii_without_colour() {
    for name in FIXTURES {
        let (_, diags) = parse_bytes(&read_bytes(name), Options::default());
        for d in &diags {
            let text = d.render(name, false);
            assert!(
                !text.contains('\u{1b}') || name.starts_with("control"),
                "{name}: colour in {text:?}"
            );
            let source = d
                .location
                .as_ref()
                .map(|l| l.source_line.as_str())
                .unwrap_or("");
            for line in text.lines() {
                if !source.is_empty() && line.contains(source) {
                    continue;
                }
                assert!(line.is_ascii(), "{name}: non-ASCII line {line:?}");
                if source.chars().count() < 60 {
                    assert!(
                        line.chars().count() <= 80,
                        "{name}: line over 80 columns {line:?}"
                    );
                }
            }
        }
    }
}
