//! The `ncpost` binary: exit codes, atomic output, standard input and output, presets,
//! passes, dumps and diagnostic formats.
//!
//! Exit codes: 0 success, 1 errors in the input, 2 usage errors. Standard error is not a
//! terminal here, so diagnostics are plain.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use ncpost::pipeline::compile_str;
use ncpost::preset::{Emit, Preset};
use tempfile::TempDir;

/// A small good program: units, distance modes, offsets, arcs, dwell, spindle, comments.
const GOOD: &str = "\
; good program, hand-written for ncpost
G21 G90
G0 X0 Y0 Z5 (safe height)
M3 S12000
G1 Z-1 F300
G1 X20 Y0 F600
G2 X30 Y10 I0 J10
G3 X20 Y20 R10
G91
G1 X-10 Y0
G90
G4 P500
G92 X0 Y0
G1 X5 Y5
G0 Z5
M5
M30
";

/// Several bad lines (and a warning) in one file.
const BAD: &str = "\
; bad program, hand-written for ncpost
G21 G90
G0 X0 Y0
G1 X Y10 F300
(unterminated comment alone
G1 X1 X2
G2 X10 Y0
G1 X5 F-100
";

/// Warnings only: an unterminated comment alone on its line and an unevaluated
/// parameter line.
const WARNINGS_ONLY: &str = "\
; warnings only, hand-written for ncpost
G21 G90
(unterminated comment
#1 = 5
G0 X0 Y0
";

fn ncpost() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ncpost"))
}

/// Runs `ncpost ARGS` in `dir` with `stdin` as standard input.
fn run_in(dir: &Path, args: &[&str], stdin: Option<&[u8]>) -> Output {
    let mut cmd = ncpost();
    cmd.args(args)
        .current_dir(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .stdin(if stdin.is_some() {
            Stdio::piped()
        } else {
            Stdio::null()
        });
    let mut child = cmd.spawn().expect("cannot start ncpost");
    if let Some(bytes) = stdin {
        use std::io::Write;
        let mut pipe = child.stdin.take().unwrap();
        pipe.write_all(bytes).unwrap();
    }
    child.wait_with_output().unwrap()
}

/// A temporary directory holding `files`.
fn dir_with(files: &[(&str, &str)]) -> TempDir {
    let dir = tempfile::tempdir().unwrap();
    for (name, text) in files {
        std::fs::write(dir.path().join(name), text).unwrap();
    }
    dir
}

fn code(out: &Output) -> i32 {
    out.status.code().expect("killed by a signal")
}

fn stdout(out: &Output) -> String {
    String::from_utf8(out.stdout.clone()).unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8(out.stderr.clone()).unwrap()
}

#[track_caller]
fn assert_exit(out: &Output, expected: i32) {
    assert_eq!(
        code(out),
        expected,
        "exit code; stdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Files in `dir` whose names look like the binary's temporary files.
fn temp_files(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with(".ncpost-") || name.ends_with(".tmp")
        })
        .collect()
}

fn preset(name: &str) -> Preset {
    Preset::builtin(name).unwrap()
}

fn library(src: &str, preset: &Preset) -> String {
    compile_str(src, preset).expect("the library rejects the input")
}

fn with_emit(mut p: Preset, emit: Emit) -> Preset {
    p.emit = emit;
    p
}

// ---------------------------------------------------------------- success and output

#[test]
fn good_file_to_output_file_matches_the_library() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let out = run_in(dir.path(), &["run", "in.gcode", "-o", "out.gcode"], None);
    assert_exit(&out, 0);
    assert!(out.stdout.is_empty(), "{}", stdout(&out));
    let written = std::fs::read_to_string(dir.path().join("out.gcode")).unwrap();
    assert_eq!(written, library(GOOD, &preset("default")));
    assert!(!written.is_empty());
    assert!(temp_files(dir.path()).is_empty());
    // The input is untouched.
    assert_eq!(
        std::fs::read_to_string(dir.path().join("in.gcode")).unwrap(),
        GOOD
    );
}

#[test]
fn good_file_to_stdout_matches_the_library() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let expected = library(GOOD, &preset("default"));
    let out = run_in(dir.path(), &["run", "in.gcode"], None);
    assert_exit(&out, 0);
    assert_eq!(stdout(&out), expected);
    let out = run_in(dir.path(), &["run", "in.gcode", "-o", "-"], None);
    assert_exit(&out, 0);
    assert_eq!(stdout(&out), expected);
    assert!(
        !dir.path().join("-").exists(),
        "`-o -` wrote a file named `-`"
    );
}

#[test]
fn stdin_input() {
    let dir = tempfile::tempdir().unwrap();
    let expected = library(GOOD, &preset("default"));
    let out = run_in(dir.path(), &["run", "-"], Some(GOOD.as_bytes()));
    assert_exit(&out, 0);
    assert_eq!(stdout(&out), expected);
    let out = run_in(dir.path(), &["run", "-", "-o", "-"], Some(GOOD.as_bytes()));
    assert_exit(&out, 0);
    assert_eq!(stdout(&out), expected);
    let out = run_in(
        dir.path(),
        &["run", "-", "-o", "out.gcode"],
        Some(GOOD.as_bytes()),
    );
    assert_exit(&out, 0);
    assert_eq!(
        std::fs::read_to_string(dir.path().join("out.gcode")).unwrap(),
        expected
    );
}

#[test]
fn stdin_diagnostics_name_stdin() {
    let dir = tempfile::tempdir().unwrap();
    let out = run_in(
        dir.path(),
        &["check", "--message-format", "json", "-"],
        Some(b"G0 X0\nG1 X1 X2\n"),
    );
    assert_exit(&out, 1);
    let v: serde_json::Value = serde_json::from_str(stderr(&out).lines().next().unwrap()).unwrap();
    assert_eq!(v["file"], "<stdin>");
    assert_eq!(v["line"], 2);
}

#[test]
fn emit_formats_match_the_library() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    for (flag, emit) in [("ir", Emit::Ir), ("rrf", Emit::Rrf), ("gcode", Emit::Gcode)] {
        let out = run_in(dir.path(), &["run", "--emit", flag, "in.gcode"], None);
        assert_exit(&out, 0);
        assert_eq!(
            stdout(&out),
            library(GOOD, &with_emit(preset("default"), emit)),
            "--emit {flag}"
        );
    }
    // The three are different formats.
    let ir = stdout(&run_in(
        dir.path(),
        &["run", "--emit", "ir", "in.gcode"],
        None,
    ));
    let rrf = stdout(&run_in(
        dir.path(),
        &["run", "--emit", "rrf", "in.gcode"],
        None,
    ));
    let gcode = stdout(&run_in(
        dir.path(),
        &["run", "--emit", "gcode", "in.gcode"],
        None,
    ));
    assert_ne!(ir, gcode);
    assert_ne!(ir, rrf);
    let out = run_in(dir.path(), &["run", "--emit", "svg", "in.gcode"], None);
    assert_exit(&out, 2);
}

#[test]
fn preset_duet_cnc_matches_the_library() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let out = run_in(
        dir.path(),
        &["run", "--preset", "duet-cnc", "in.gcode"],
        None,
    );
    assert_exit(&out, 0);
    assert_eq!(stdout(&out), library(GOOD, &preset("duet-cnc")));
    // --emit overrides the preset's format.
    let out = run_in(
        dir.path(),
        &["run", "--preset", "duet-cnc", "--emit", "ir", "in.gcode"],
        None,
    );
    assert_exit(&out, 0);
    assert_eq!(
        stdout(&out),
        library(GOOD, &with_emit(preset("duet-cnc"), Emit::Ir))
    );
}

const CONFIG: &str = "\
description = \"test preset: numbered lines with checksums\"
emit = \"gcode\"

[[passes]]
name = \"verify\"

[gcode]
line_numbers = true
checksums = true
modal_motion = true
";

#[test]
fn config_file_preset() {
    let dir = dir_with(&[("in.gcode", GOOD), ("my.toml", CONFIG)]);
    let expected = library(GOOD, &Preset::from_toml(CONFIG).unwrap());
    assert!(expected.contains("\nN1 G21 G90*"), "{expected}");
    let out = run_in(
        dir.path(),
        &["run", "--config", "my.toml", "in.gcode"],
        None,
    );
    assert_exit(&out, 0);
    assert_eq!(stdout(&out), expected);
    // `--preset FILE` reads a preset file too.
    let out = run_in(
        dir.path(),
        &["run", "--preset", "my.toml", "in.gcode"],
        None,
    );
    assert_exit(&out, 0);
    assert_eq!(stdout(&out), expected);
}

#[test]
fn bad_config_files_are_usage_errors() {
    let dir = dir_with(&[
        ("in.gcode", GOOD),
        ("unknown_field.toml", "bogus = 1\n"),
        ("not_toml.toml", "emit = \n"),
        ("unknown_pass.toml", "[[passes]]\nname = \"no-such-pass\"\n"),
        (
            "bad_pass_option.toml",
            "[[passes]]\nname = \"stats\"\n[passes.options]\nbogus = 1\n",
        ),
    ]);
    for file in [
        "unknown_field.toml",
        "not_toml.toml",
        "unknown_pass.toml",
        "bad_pass_option.toml",
        "missing.toml",
    ] {
        let out = run_in(
            dir.path(),
            &["run", "--config", file, "in.gcode", "-o", "out.gcode"],
            None,
        );
        assert_exit(&out, 2);
        assert!(stderr(&out).contains("error"), "{file}: {}", stderr(&out));
        assert!(!dir.path().join("out.gcode").exists(), "{file}");
    }
    let out = run_in(
        dir.path(),
        &[
            "run",
            "--config",
            "unknown_field.toml",
            "--preset",
            "default",
            "in.gcode",
        ],
        None,
    );
    assert_exit(&out, 2);
}

// ---------------------------------------------------------------- failure and atomicity

#[test]
fn bad_input_exits_1_and_creates_no_output_file() {
    let dir = dir_with(&[("bad.gcode", BAD)]);
    let out = run_in(dir.path(), &["run", "bad.gcode", "-o", "out.gcode"], None);
    assert_exit(&out, 1);
    let err = stderr(&out);
    for code in [
        "gcode::letter-without-number",
        "gcode::duplicate-word",
        "gcode::arc",
        "gcode::feed",
        "gcode::unterminated-comment",
    ] {
        assert!(err.contains(code), "{code} missing from:\n{err}");
    }
    assert!(out.stdout.is_empty());
    assert!(!dir.path().join("out.gcode").exists());
    assert!(
        temp_files(dir.path()).is_empty(),
        "{:?}",
        temp_files(dir.path())
    );
    assert_eq!(
        std::fs::read_to_string(dir.path().join("bad.gcode")).unwrap(),
        BAD
    );
}

#[test]
fn failed_run_leaves_an_existing_output_file_untouched() {
    let old = b"G0 X1 ; the previous good result\n\x00\xff binary tail";
    let dir = dir_with(&[("bad.gcode", BAD)]);
    let target = dir.path().join("out.gcode");
    std::fs::write(&target, old).unwrap();
    let before = std::fs::metadata(&target).unwrap();
    let out = run_in(dir.path(), &["run", "bad.gcode", "-o", "out.gcode"], None);
    assert_exit(&out, 1);
    assert_eq!(std::fs::read(&target).unwrap(), old);
    let after = std::fs::metadata(&target).unwrap();
    assert_eq!(before.modified().unwrap(), after.modified().unwrap());
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        assert_eq!(before.ino(), after.ino(), "the file was replaced");
    }
    assert!(
        temp_files(dir.path()).is_empty(),
        "{:?}",
        temp_files(dir.path())
    );
    // The same from standard input.
    let out = run_in(
        dir.path(),
        &["run", "-", "-o", "out.gcode"],
        Some(BAD.as_bytes()),
    );
    assert_exit(&out, 1);
    assert_eq!(std::fs::read(&target).unwrap(), old);
    assert!(
        temp_files(dir.path()).is_empty(),
        "{:?}",
        temp_files(dir.path())
    );
}

#[test]
fn failed_run_into_another_directory_leaves_no_temp_file() {
    let dir = dir_with(&[("bad.gcode", BAD)]);
    let sub = dir.path().join("out");
    std::fs::create_dir(&sub).unwrap();
    let out = run_in(
        dir.path(),
        &["run", "bad.gcode", "-o", "out/result.gcode"],
        None,
    );
    assert_exit(&out, 1);
    assert_eq!(std::fs::read_dir(&sub).unwrap().count(), 0);
    assert!(temp_files(dir.path()).is_empty());
}

#[test]
fn output_equal_to_input_is_a_usage_error() {
    let dir = dir_with(&[("in.gcode", GOOD), ("bad.gcode", BAD)]);
    std::fs::create_dir(dir.path().join("sub")).unwrap();
    for (input, output) in [
        ("in.gcode", "in.gcode"),
        ("in.gcode", "./in.gcode"),
        ("in.gcode", "sub/../in.gcode"),
        ("bad.gcode", "bad.gcode"),
    ] {
        let before = std::fs::read(dir.path().join(input)).unwrap();
        let out = run_in(dir.path(), &["run", input, "-o", output], None);
        assert_exit(&out, 2);
        assert!(stderr(&out).contains("input"), "{}", stderr(&out));
        assert_eq!(std::fs::read(dir.path().join(input)).unwrap(), before);
        assert!(temp_files(dir.path()).is_empty());
    }
    let abs = dir.path().join("in.gcode");
    let abs = abs.to_str().unwrap();
    let out = run_in(dir.path(), &["run", abs, "-o", "in.gcode"], None);
    assert_exit(&out, 2);
    assert_eq!(std::fs::read_to_string(abs).unwrap(), GOOD);
}

#[cfg(unix)]
#[test]
fn output_through_a_symlink_to_the_input_is_a_usage_error() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    std::os::unix::fs::symlink("in.gcode", dir.path().join("link.gcode")).unwrap();
    let out = run_in(dir.path(), &["run", "in.gcode", "-o", "link.gcode"], None);
    assert_exit(&out, 2);
    assert_eq!(
        std::fs::read_to_string(dir.path().join("in.gcode")).unwrap(),
        GOOD
    );
}

/// The output file gets the permissions any new file in that directory gets (the
/// umask), not the private mode of a temporary file.
#[cfg(unix)]
#[test]
fn output_file_has_ordinary_permissions() {
    use std::os::unix::fs::PermissionsExt;
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let out = run_in(dir.path(), &["run", "in.gcode", "-o", "out.gcode"], None);
    assert_exit(&out, 0);
    std::fs::File::create(dir.path().join("reference")).unwrap();
    let mode = |name: &str| {
        std::fs::metadata(dir.path().join(name))
            .unwrap()
            .permissions()
            .mode()
            & 0o777
    };
    assert_eq!(
        format!("{:o}", mode("out.gcode")),
        format!("{:o}", mode("reference")),
        "mode of the output file"
    );
}

// ---------------------------------------------------------------- usage errors

#[test]
fn usage_errors_exit_2() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let cases: &[(&[&str], &str)] = &[
        (
            &["run", "--pass", "no-such-pass", "in.gcode"],
            "unknown pass",
        ),
        (&["run", "--pass", "stats:bogus=1", "in.gcode"], "bogus"),
        (&["run", "--pass", "verify:bogus=1", "in.gcode"], "bogus"),
        (&["run", "--pass", ":x=1", "in.gcode"], "no pass name"),
        (
            &["run", "--preset", "no-such-preset", "in.gcode"],
            "no-such-preset",
        ),
        (&["run", "missing.gcode"], "missing.gcode"),
        (&["run", "--dump-after", "stats", "in.gcode"], "stats"),
        (
            &["check", "--pass", "no-such-pass", "in.gcode"],
            "unknown pass",
        ),
        (&["check", "missing.gcode"], "missing.gcode"),
        (&["run"], "INPUT"),
        (&["frobnicate"], "frobnicate"),
    ];
    for (args, needle) in cases {
        let mut with_output = args.to_vec();
        if args.first() == Some(&"run") && args.len() > 1 {
            with_output.extend(["-o", "out.gcode"]);
        }
        let out = run_in(dir.path(), &with_output, None);
        assert_exit(&out, 2);
        let err = stderr(&out);
        assert!(err.contains(needle), "{args:?}: `{needle}` not in:\n{err}");
        assert!(out.stdout.is_empty(), "{args:?}: {}", stdout(&out));
        assert!(!dir.path().join("out.gcode").exists(), "{args:?}");
        assert!(temp_files(dir.path()).is_empty(), "{args:?}");
    }
}

/// A directory where a file is expected is a usage error (2), like a missing file, not an
/// error in the input (1).
#[test]
fn directories_instead_of_files_are_usage_errors() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    std::fs::create_dir(dir.path().join("folder")).unwrap();
    let out = run_in(dir.path(), &["run", "folder"], None);
    assert_exit(&out, 2);
    let out = run_in(dir.path(), &["run", "in.gcode", "-o", "folder"], None);
    assert!(dir.path().join("folder").is_dir());
    assert!(temp_files(dir.path()).is_empty());
    assert_exit(&out, 2);
}

#[test]
fn unknown_pass_lists_the_passes() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let out = run_in(dir.path(), &["run", "--pass", "nope", "in.gcode"], None);
    assert_exit(&out, 2);
    let err = stderr(&out);
    for p in ncpost::passes::REGISTRY {
        assert!(err.contains(p.name), "{err}");
    }
}

#[test]
fn hpgl_input_runs_and_cl_needs_a_machine() {
    let dir = dir_with(&[
        ("part.apt", "GOTO/1,2,3\n"),
        ("part.cl", "GOTO/1,2,3\n"),
        ("board.hpgl", "IN;PU0,0;\n"),
        ("board.plt", "IN;PU0,0;\n"),
        ("in.gcode", GOOD),
    ]);
    for (file, frontend, why) in [
        ("part.apt", "APT", "need a machine"),
        ("part.cl", "APT", "need a machine"),
    ] {
        let out = run_in(dir.path(), &["run", file, "-o", "out.gcode"], None);
        assert_exit(&out, 2);
        let err = stderr(&out);
        assert!(err.contains(frontend), "{file}: {err}");
        assert!(err.contains(why), "{file}: {err}");
        assert!(!dir.path().join("out.gcode").exists());
        let out = run_in(dir.path(), &["check", file], None);
        assert_exit(&out, 2);
    }
    // HPGL by extension: the pen-up move to 0,0 at the safe height.
    for file in ["board.hpgl", "board.plt"] {
        let out = run_in(dir.path(), &["run", file], None);
        assert_exit(&out, 0);
        assert_eq!(stdout(&out), "G21 G90\nG0 Z1\nG0 X0 Y0\nM2\n", "{file}");
    }
    // --from overrides the extension: G-code read as HPGL is an input error.
    let out = run_in(dir.path(), &["run", "--from", "hpgl", "in.gcode"], None);
    assert_exit(&out, 1);
    std::fs::copy(dir.path().join("in.gcode"), dir.path().join("prog.apt")).unwrap();
    let out = run_in(dir.path(), &["run", "--from", "gcode", "prog.apt"], None);
    assert_exit(&out, 0);
    assert_eq!(stdout(&out), library(GOOD, &preset("default")));
}

// ---------------------------------------------------------------- passes and dumps

#[test]
fn pass_stats_is_appended_and_reports_on_stderr() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let out = run_in(dir.path(), &["run", "--pass", "stats", "in.gcode"], None);
    assert_exit(&out, 0);
    assert!(stderr(&out).starts_with("stats:"), "{}", stderr(&out));
    // stats does not change the output.
    assert_eq!(stdout(&out), library(GOOD, &preset("default")));
    // Options of an appended pass.
    let out = run_in(
        dir.path(),
        &["run", "--pass", "stats:rapid_feed=6000", "in.gcode"],
        None,
    );
    assert_exit(&out, 0);
    assert!(stderr(&out).contains("stats:"), "{}", stderr(&out));
    // A pass the preset has already: its options are set, it is not added twice.
    let out = run_in(dir.path(), &["run", "--pass", "verify", "in.gcode"], None);
    assert_exit(&out, 0);
    assert!(out.stderr.is_empty(), "{}", stderr(&out));
    // Appended passes can be dumped after.
    let out = run_in(
        dir.path(),
        &[
            "run",
            "--pass",
            "stats",
            "--dump-after",
            "stats",
            "in.gcode",
        ],
        None,
    );
    assert_exit(&out, 0);
    assert!(stderr(&out).contains("stats:"));
}

#[test]
fn dump_after_prints_the_ir_on_stderr() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let ir = library(GOOD, &with_emit(preset("default"), Emit::Ir));
    for point in ["verify", "front"] {
        let out = run_in(
            dir.path(),
            &["run", "--dump-after", point, "in.gcode"],
            None,
        );
        assert_exit(&out, 0);
        // The output is unchanged and the dump goes to standard error.
        assert_eq!(stdout(&out), library(GOOD, &preset("default")), "{point}");
        assert_eq!(stderr(&out), ir, "--dump-after {point}");
    }
    let out = run_in(
        dir.path(),
        &["run", "--dump-after", "no-such-pass", "in.gcode"],
        None,
    );
    assert_exit(&out, 2);
}

// ---------------------------------------------------------------- diagnostics

#[test]
fn plain_stderr_of_a_failing_run() {
    let dir = dir_with(&[("bad.gcode", BAD)]);
    let out = run_in(dir.path(), &["run", "bad.gcode", "-o", "out.gcode"], None);
    assert_exit(&out, 1);
    let err = stderr(&out);
    assert!(!err.contains('\u{1b}'), "colour on a non-terminal: {err:?}");
    insta::assert_snapshot!("failing_run_stderr", err);
}

#[test]
fn json_diagnostics_one_object_per_line() {
    let dir = dir_with(&[("bad.gcode", BAD)]);
    let out = run_in(
        dir.path(),
        &[
            "run",
            "--message-format",
            "json",
            "bad.gcode",
            "-o",
            "out.gcode",
        ],
        None,
    );
    assert_exit(&out, 1);
    let err = stderr(&out);
    let got: Vec<(String, String, u64, u64)> = err
        .lines()
        .map(|l| {
            let v: serde_json::Value =
                serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l:?}"));
            assert!(v.is_object());
            assert_eq!(v["file"], "bad.gcode");
            assert!(v["message"].is_string());
            (
                v["severity"].as_str().unwrap().to_string(),
                v["code"].as_str().unwrap().to_string(),
                v["line"].as_u64().unwrap(),
                v["column"].as_u64().unwrap(),
            )
        })
        .collect();
    let want = [
        ("error", "gcode::letter-without-number", 4, 4),
        ("warning", "gcode::unterminated-comment", 5, 1),
        ("error", "gcode::duplicate-word", 6, 7),
        ("error", "gcode::arc", 7, 1),
        ("error", "gcode::feed", 8, 7),
    ];
    let want: Vec<(String, String, u64, u64)> = want
        .iter()
        .map(|(s, c, l, col)| (s.to_string(), c.to_string(), *l, *col))
        .collect();
    assert_eq!(got, want);
    assert!(!dir.path().join("out.gcode").exists());
}

#[test]
fn json_notes_from_passes() {
    let dir = dir_with(&[("in.gcode", GOOD)]);
    let out = run_in(
        dir.path(),
        &[
            "run",
            "--message-format",
            "json",
            "--pass",
            "stats",
            "in.gcode",
        ],
        None,
    );
    assert_exit(&out, 0);
    for l in stderr(&out).lines() {
        let v: serde_json::Value = serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l:?}"));
        assert_eq!(v["severity"], "note");
        assert_eq!(v["code"], "stats::report", "{l}");
    }
}

#[test]
fn quiet_hides_warnings_but_not_errors() {
    let dir = dir_with(&[("warn.gcode", WARNINGS_ONLY), ("bad.gcode", BAD)]);
    let loud = run_in(dir.path(), &["run", "warn.gcode"], None);
    assert_exit(&loud, 0);
    assert!(stderr(&loud).contains("gcode::unterminated-comment"));
    assert!(stderr(&loud).contains("gcode::unevaluated"));
    let quiet = run_in(dir.path(), &["run", "--quiet", "warn.gcode"], None);
    assert_exit(&quiet, 0);
    assert!(quiet.stderr.is_empty(), "{}", stderr(&quiet));
    assert_eq!(quiet.stdout, loud.stdout);
    // Warnings do not stop the output file.
    let out = run_in(dir.path(), &["run", "warn.gcode", "-o", "warn.out"], None);
    assert_exit(&out, 0);
    assert_eq!(
        std::fs::read(dir.path().join("warn.out")).unwrap(),
        loud.stdout
    );
    let quiet = run_in(
        dir.path(),
        &["check", "-q", "--message-format", "json", "warn.gcode"],
        None,
    );
    assert_exit(&quiet, 0);
    assert!(quiet.stderr.is_empty(), "{}", stderr(&quiet));
    // Errors are still shown, warnings are not.
    let quiet = run_in(
        dir.path(),
        &["run", "--quiet", "bad.gcode", "-o", "o.gcode"],
        None,
    );
    assert_exit(&quiet, 1);
    let err = stderr(&quiet);
    assert!(err.contains("gcode::duplicate-word"), "{err}");
    assert!(!err.contains("gcode::unterminated-comment"), "{err}");
}

#[test]
fn repeated_warnings_are_summed_up_after_five() {
    let mut src = String::from("G21 G90\n");
    for i in 0..15 {
        src.push_str(&format!("#{i} = 1\n"));
    }
    let dir = dir_with(&[("many.gcode", &src)]);
    let out = run_in(dir.path(), &["check", "many.gcode"], None);
    assert_exit(&out, 0);
    let err = stderr(&out);
    // Five in full and the summary, which has the code too.
    assert_eq!(err.matches("gcode::unevaluated\n").count(), 6, "{err}");
    // JSON is capped the same way; --max-repeats 0 shows them all.
    let out = run_in(
        dir.path(),
        &["check", "--message-format", "json", "many.gcode"],
        None,
    );
    let json = stderr(&out);
    assert_eq!(json.lines().count(), 6);
    let summary: serde_json::Value =
        serde_json::from_str(json.lines().last().unwrap_or("")).expect("JSON");
    assert_eq!(
        summary["message"],
        "10 more `gcode::unevaluated` warnings not shown (15 in all, the first 5 above), \
         on lines 7, 8, 9, … (7..16 in all); they carry no magnitude, so no worst case is named"
    );
    let out = run_in(
        dir.path(),
        &[
            "check",
            "--message-format",
            "json",
            "--max-repeats",
            "0",
            "many.gcode",
        ],
        None,
    );
    assert_eq!(stderr(&out).lines().count(), 15);
}

// ---------------------------------------------------------------- check, passes, presets

#[test]
fn check_writes_nothing_to_stdout() {
    let dir = dir_with(&[("in.gcode", GOOD), ("bad.gcode", BAD)]);
    let out = run_in(dir.path(), &["check", "in.gcode"], None);
    assert_exit(&out, 0);
    assert!(out.stdout.is_empty(), "{}", stdout(&out));
    assert!(out.stderr.is_empty(), "{}", stderr(&out));
    let out = run_in(dir.path(), &["check", "bad.gcode"], None);
    assert_exit(&out, 1);
    assert!(out.stdout.is_empty(), "{}", stdout(&out));
    assert!(stderr(&out).contains("gcode::duplicate-word"));
    let out = run_in(dir.path(), &["check", "-"], Some(BAD.as_bytes()));
    assert_exit(&out, 1);
    assert!(out.stdout.is_empty(), "{}", stdout(&out));
    // check writes no files either.
    let mut names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["bad.gcode", "in.gcode"]);
}

#[test]
fn passes_lists_the_registry() {
    let dir = tempfile::tempdir().unwrap();
    let out = run_in(dir.path(), &["passes"], None);
    assert_exit(&out, 0);
    let text = stdout(&out);
    for p in ncpost::passes::REGISTRY {
        assert!(
            text.lines()
                .any(|l| l.starts_with(p.name) && l.contains(p.summary)),
            "{}: {text}",
            p.name
        );
    }
    insta::assert_snapshot!("passes", text);
}

#[test]
fn presets_lists_the_builtins() {
    let dir = tempfile::tempdir().unwrap();
    let out = run_in(dir.path(), &["presets"], None);
    assert_exit(&out, 0);
    let text = stdout(&out);
    for (name, _) in ncpost::preset::BUILTIN {
        let p = preset(name);
        assert!(
            text.lines()
                .any(|l| l.starts_with(name) && l.contains(&p.description)),
            "{name}: {text}"
        );
    }
    insta::assert_snapshot!("presets", text);
}

#[test]
fn version_and_help() {
    let dir = tempfile::tempdir().unwrap();
    let out = run_in(dir.path(), &["--version"], None);
    assert_exit(&out, 0);
    assert!(stdout(&out).contains(env!("CARGO_PKG_VERSION")));
    let out = run_in(dir.path(), &["run", "--help"], None);
    assert_exit(&out, 0);
    for flag in [
        "--preset",
        "--config",
        "--pass",
        "--emit",
        "--dump-after",
        "--quiet",
        "--message-format",
        "--from",
    ] {
        assert!(stdout(&out).contains(flag), "{flag}");
    }
}

/// The E-moc pipeline runs its kinematics beside the frontend (a second thread does the
/// rest): a dump at any point still shows the IR of that point, exactly once.
#[test]
fn dump_after_works_on_both_sides_of_the_thread_split() {
    let cl = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/emoc_taper_boss.cl"),
    )
    .unwrap();
    let dir = dir_with(&[("boss.cl", &cl)]);
    let dump = |pass: &str| {
        let out = run_in(
            dir.path(),
            &[
                "run",
                "--quiet",
                "--preset",
                "emoc-x5",
                "boss.cl",
                "--dump-after",
                pass,
                "-o",
                "out.gcode",
            ],
            None,
        );
        assert_exit(&out, 0);
        stderr(&out)
    };
    let front = dump("front");
    assert!(
        front.contains("tip=(") && !front.contains(" A15.0000"),
        "{front}"
    );
    let ik = dump("ik");
    assert!(
        !ik.contains("tip=(") && ik.contains(" A15.0000 C90.0000"),
        "{ik}"
    );
    assert_eq!(front.lines().count(), ik.lines().count());
    let unwrap = dump("unwrap-rotary");
    assert!(unwrap.contains("G92") || unwrap.lines().count() >= ik.lines().count());
    let densify = dump("densify");
    assert!(densify.lines().count() > ik.lines().count());
    let verify = dump("verify");
    assert!(verify.lines().count() >= densify.lines().count());
}

#[test]
fn machine_config_g_prints_the_fragment_and_needs_a_machine() {
    let dir = dir_with(&[]);
    let out = run_in(
        dir.path(),
        &["machine", "config-g", "--preset", "emoc-x5"],
        None,
    );
    assert_exit(&out, 0);
    let text = stdout(&out);
    for word in [
        "M584 X0.0 Y0.1:0.2 Z0.3",
        "M584 A0.4 C0.5 R1 S1",
        "M208",
        "A-90:135",
        "M203",
        "I6",
        "M201",
    ] {
        assert!(text.contains(word), "{word}: {text}");
    }
    let out = run_in(
        dir.path(),
        &["machine", "config-g", "--preset", "duet-cnc"],
        None,
    );
    assert_exit(&out, 2);
    assert!(stderr(&out).contains("no [machine]"), "{}", stderr(&out));
}

#[test]
fn plot_joints_writes_an_svg_of_each_axis() {
    let cl = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/emoc_taper_boss.cl"),
    )
    .unwrap();
    let dir = dir_with(&[("boss.cl", &cl)]);
    let out = run_in(
        dir.path(),
        &[
            "plot",
            "--joints",
            "--preset",
            "emoc-x5",
            "boss.cl",
            "-o",
            "joints.svg",
        ],
        None,
    );
    assert_exit(&out, 0);
    let svg = std::fs::read_to_string(dir.path().join("joints.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    for label in [">X (mm)<", ">Y (mm)<", ">Z (mm)<", ">A (deg)<", ">C (deg)<"] {
        assert!(svg.contains(label), "{label}");
    }
    assert_eq!(svg.matches("<polyline").count(), 5);
    // CL input without a machine is refused, and nothing is written.
    let out = run_in(
        dir.path(),
        &["plot", "--joints", "boss.cl", "-o", "other.svg"],
        None,
    );
    assert_ne!(out.status.code(), Some(0));
    assert!(!dir.path().join("other.svg").exists());
}

#[cfg(unix)]
#[test]
fn output_to_a_pipe_is_written_in_place_and_stays_a_pipe() {
    use std::os::unix::fs::FileTypeExt;
    let dir = dir_with(&[("good.gcode", GOOD)]);
    let fifo = dir.path().join("out.fifo");
    let made = Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
    assert!(made.success());
    // Renaming a temporary file over the name would replace the pipe (as it would
    // replace /dev/null): the output must go through it instead.
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read_to_string(fifo).expect("read the pipe"))
    };
    let out = run_in(dir.path(), &["run", "good.gcode", "-o", "out.fifo"], None);
    assert_exit(&out, 0);
    // Checked before joining: had the pipe been replaced, the reader would wait forever.
    let kind = std::fs::symlink_metadata(&fifo)
        .expect("still there")
        .file_type();
    assert!(kind.is_fifo(), "the pipe was replaced by a {kind:?}");
    let text = reader.join().expect("reader");
    assert!(text.contains("G1 X20"), "{text}");
    assert!(temp_files(dir.path()).is_empty());
}

#[cfg(unix)]
#[test]
fn output_through_a_symlink_replaces_the_target_and_keeps_the_link() {
    let dir = dir_with(&[("good.gcode", GOOD)]);
    let target = dir.path().join("real.gcode");
    std::fs::write(&target, "old\n").unwrap();
    let link = dir.path().join("link.gcode");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let out = run_in(dir.path(), &["run", "good.gcode", "-o", "link.gcode"], None);
    assert_exit(&out, 0);
    assert!(
        std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink(),
        "the link was replaced by a file"
    );
    let written = std::fs::read_to_string(&target).unwrap();
    assert!(written.contains("G21"), "{written}");
    assert!(temp_files(dir.path()).is_empty());
}

/// Runs ncpost with `args` on the corpus cube (output well over a pipe's buffer), reads
/// 100 bytes of its standard output and closes the pipe (`ncpost ... | head -c 100`).
fn into_closed_pipe(args: &[&str]) -> (Vec<u8>, Output) {
    use std::io::Read;
    let input = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/gcode/gcodenom_mini_cube_a_prusaslicer.gcode");
    let mut child = ncpost()
        .args(args)
        .arg(&input)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = child.stdout.take().unwrap();
    let mut head = vec![0u8; 100];
    stdout.read_exact(&mut head).unwrap();
    drop(stdout);
    (head, child.wait_with_output().unwrap())
}

#[test]
fn a_reader_that_goes_away_ends_the_program_quietly() {
    let (head, out) = into_closed_pipe(&["plot", "--toolpath", "-q"]);
    assert!(head.starts_with(b"<svg"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(out.status.code(), Some(0), "{stderr}");
}

#[test]
fn output_into_a_closed_pipe_is_one_error_not_one_per_block() {
    let (_, out) = into_closed_pipe(&["run", "-q", "-o", "-"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        stderr.matches("cannot write the output").count(),
        1,
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_exit(&out, 1);
}
