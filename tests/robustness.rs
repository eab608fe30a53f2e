//! Robustness (issue 21, item 11): byte-order marks, numbers out of range, an HPGL label
//! that never ends, memory bombs in `linearize-arcs` and `expand-subprograms`, temporary
//! output files on signals. Every test runs the CLI and re-reads what it printed.

use std::path::Path;
use std::process::{Command, Output, Stdio};

fn ncpost() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ncpost"))
}

/// Runs `ncpost run ARGS FILE` on `input` written to `name` in a new directory.
fn run(name: &str, input: &[u8], args: &[&str]) -> Output {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join(name);
    std::fs::write(&path, input).expect("write input");
    ncpost()
        .arg("run")
        .args(args)
        .arg(&path)
        .stdin(Stdio::null())
        .output()
        .expect("cannot start ncpost")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The run failed with exit 1 and its messages say every one of `needles`; returns them.
fn fails_with(out: &Output, needles: &[&str]) -> String {
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "no `{n}` in: {stderr}");
    }
    stderr
}

/// The value of word `letter` in a printed line (`G1 X25.4 Y50.8` → X: 25.4).
fn word(line: &str, letter: char) -> Option<f64> {
    line.split_whitespace()
        .find(|w| w.starts_with(letter))
        .and_then(|w| w[1..].parse().ok())
}

/// The X and Y of every printed move, carried modally.
fn xy_of_moves(out: &str) -> Vec<(f64, f64)> {
    let (mut x, mut y) = (f64::NAN, f64::NAN);
    let mut v = Vec::new();
    for line in out.lines() {
        let is_move = line
            .split_whitespace()
            .any(|w| matches!(w, "G0" | "G1" | "G00" | "G01"));
        if let Some(nx) = word(line, 'X') {
            x = nx;
        }
        if let Some(ny) = word(line, 'Y') {
            y = ny;
        }
        if is_move && (word(line, 'X').is_some() || word(line, 'Y').is_some()) {
            v.push((x, y));
        }
    }
    v
}

const BOM: &[u8] = b"\xEF\xBB\xBF";

/// A CL file in inches with a byte-order mark: `UNITS/INCHES` is read, and the printed
/// positions are 25.4 times the programmed ones.
#[test]
fn cl_with_bom_keeps_its_units() {
    let cl = b"UNITS/INCHES\nFEDRAT/10,IPM\nGOTO/1,2,0\nGOTO/2,2,0\n";
    let with_bom = [BOM, cl].concat();
    let out = run("part.cls", &with_bom, &["--preset", "emoc-x5"]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(!text(&out.stderr).contains("cl::unknown-statement"));
    let moves = xy_of_moves(&stdout);
    assert_eq!(moves, [(25.4, 50.8), (50.8, 50.8)], "{stdout}");
    // The same as the file without the mark.
    let plain = run("part.cls", cl, &["--preset", "emoc-x5"]);
    assert_eq!(text(&plain.stdout), stdout);
}

/// An HPGL plot with a byte-order mark reads as without it; a mark inside the file is
/// one error that says BOM.
#[test]
fn hpgl_bom() {
    let plot = b"IN;PU400,400;PD800,400,800,800;PU;\n";
    let plain = run("a.hpgl", plot, &["--preset", "pcb-mill"]);
    let marked = run("a.hpgl", &[BOM, plot].concat(), &["--preset", "pcb-mill"]);
    assert!(marked.status.success(), "{}", text(&marked.stderr));
    assert_eq!(text(&marked.stdout), text(&plain.stdout));
    assert!(xy_of_moves(&text(&marked.stdout)).contains(&(20.0, 20.0)));

    let inside = [&plot[..13], BOM, &plot[13..]].concat();
    let out = run("b.hpgl", &inside, &["--preset", "pcb-mill"]);
    let stderr = text(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("BOM"), "{stderr}");
    assert_eq!(stderr.matches("error:").count(), 1, "{stderr}");
}

/// An `LB` label without its terminator is an error at the `LB`, naming the terminator,
/// not a silent end of the plot.
#[test]
fn hpgl_unterminated_label() {
    let out = run(
        "l.hpgl",
        b"IN;PU100,100;LBhello\nPD200,200;PU;\n",
        &["--preset", "pcb-mill"],
    );
    fails_with(&out, &["not terminated", "ETX", "l.hpgl:1:14"]);

    let out = run(
        "l.hpgl",
        b"IN;DT#;PU100,100;LBhello\x03PD200,200;PU;\n",
        &["--preset", "pcb-mill"],
    );
    let stderr = text(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("`#` (set by DT)"), "{stderr}");

    // Terminated labels still read, and the commands after them too.
    let out = run(
        "l.hpgl",
        b"IN;PU100,100;LBhello\x03PU400,400;PD800,400;PU;\n",
        &["--preset", "pcb-mill"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(xy_of_moves(&text(&out.stdout)).contains(&(20.0, 10.0)));
}

/// `GOTO/1e308` is one error at the number; a number of a million digits is not echoed
/// whole.
#[test]
fn cl_numbers_out_of_range() {
    let out = run(
        "big.cls",
        b"FEDRAT/100\nGOTO/1e308,0,0\nGOTO/1,2,3\n",
        &["--preset", "emoc-x5"],
    );
    let stderr = fails_with(&out, &["big.cls:2:6", "out of range"]);
    assert_eq!(stderr.matches("error:").count(), 1, "{stderr}");
    // The good move after it is still compiled.
    let moves = xy_of_moves(&text(&out.stdout));
    assert_eq!(moves, [(1.0, 2.0)]);

    let huge = format!("FEDRAT/100\nGOTO/1{},0,0\n", "9".repeat(1_000_000));
    let out = run("huge.cls", huge.as_bytes(), &["--preset", "emoc-x5"]);
    let stderr = text(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.len() < 4000, "{} bytes of messages", stderr.len());
    assert!(stderr.contains("9999…` is out of range"), "{stderr}");
}

/// HPGL: a parameter over 1e12 is one short error.
#[test]
fn hpgl_numbers_out_of_range() {
    let plot = format!("IN;PU1{},0;PD10,10;PU;\n", "9".repeat(100_000));
    let out = run("huge.hpgl", plot.as_bytes(), &["--preset", "pcb-mill"]);
    let stderr = text(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.len() < 4000, "{} bytes of messages", stderr.len());
    assert_eq!(stderr.matches("error:").count(), 1, "{stderr}");
    assert!(stderr.contains("…` is too large"), "{stderr}");
    let out = run(
        "big.hpgl",
        b"IN;PU2000000000000,0;\n",
        &["--preset", "pcb-mill"],
    );
    assert!(text(&out.stderr).contains("is too large"));
}

/// A million turns is an error at the arc's line, not a decagon; a few turns are cut
/// within the tolerance (every chord's middle re-read from the output is within
/// 0.002 mm of the circle).
#[test]
fn linearize_arcs_past_its_cap() {
    let out = run(
        "turns.ngc",
        b"G21 G90\nG0 X10 Y0\nG2 X10 Y0 I-10 J0 P1000000 F1000\nG1 X0\n",
        &["--emit", "gcode", "--pass", "linearize-arcs"],
    );
    fails_with(
        &out,
        &["linearize-arcs::chords", "turns.ngc:3", "max_chords"],
    );

    let out = run(
        "turns.ngc",
        b"G21 G90\nG0 X10 Y0\nG2 X10 Y0 I-10 J0 P3 F1000\n",
        &["--emit", "gcode", "--pass", "linearize-arcs"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let pts = xy_of_moves(&text(&out.stdout));
    assert!(pts.len() > 100, "{} points", pts.len());
    let r = |(x, y): (f64, f64)| (x * x + y * y).sqrt();
    for w in pts.windows(2) {
        let mid = ((w[0].0 + w[1].0) / 2.0, (w[0].1 + w[1].1) / 2.0);
        // Printed with 3 decimals: 0.001 mm of rounding on top of the tolerance.
        assert!((r(w[1]) - 10.0).abs() < 0.001, "{:?}", w[1]);
        assert!(
            10.0 - r(mid) <= 0.002 + 0.0015,
            "sag {} at {mid:?}",
            10.0 - r(mid)
        );
    }
}

/// Nested `L3000` repeats are refused at the call line before any block is built.
#[test]
fn expand_subprograms_counts_first() {
    let program = b"G21 G90\nG0 X0 Y0 Z5\nM98 P100 L3000\nM30\nO100\nM98 P200 L3000\nM99\nO200\nG91 G1 X0.001 F100\nG1 X-0.001\nG90\nM99\n";
    let started = std::time::Instant::now();
    let out = run(
        "nest.ngc",
        program,
        &["--emit", "gcode", "--pass", "expand-subprograms"],
    );
    let stderr = fails_with(
        &out,
        &["subprograms::size", "nest.ngc:3:1", "18000000 blocks"],
    );
    assert!(!stderr.contains("never called"), "{stderr}");
    // 18 million blocks were never made.
    assert!(started.elapsed().as_secs() < 20);

    // Under the limit the same nest is expanded: 3 x 2 x 3 moves.
    let small = b"G21 G90\nG0 X0 Y0 Z5\nM98 P100 L3\nM30\nO100\nM98 P200 L2\nM99\nO200\nG91 G1 X1 F100\nG1 X-1\nG90\nM99\n";
    let out = run(
        "nest.ngc",
        small,
        &["--emit", "gcode", "--pass", "expand-subprograms"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let xs: Vec<f64> = xy_of_moves(&text(&out.stdout))
        .iter()
        .map(|p| p.0)
        .collect();
    assert_eq!(xs.len(), 1 + 12, "{xs:?}");
    assert!(xs[1..].chunks(2).all(|c| c == [1.0, 0.0]), "{xs:?}");
}

/// Calls the pass inlines are not said to pass through unchanged (issue 21, 9b); a call
/// it cannot expand still is.
#[test]
fn expanded_calls_are_not_said_to_pass_through() {
    let oword = b"G21 G90\nG0 X0 Y0 Z5\no100 call\nG0 X1\nM30\no100 sub\nG1 X5 F100\no100 endsub\n";
    let out = run("o.ngc", oword, &["--pass", "expand-subprograms"]);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("passes through unchanged"), "{stderr}");
    assert!(!stderr.contains("not evaluated"), "{stderr}");
    let xs: Vec<f64> = xy_of_moves(&text(&out.stdout))
        .iter()
        .map(|p| p.0)
        .collect();
    assert_eq!(xs, [0.0, 5.0, 1.0]);

    let fanuc = b"G21 G90\nG0 X0 Y0 Z5\nM98 P100 L2\nG0 X1\nM30\nO100\nG91 G1 X5 F100\nG90\nM99\n";
    let out = run("f.ngc", fanuc, &["--pass", "expand-subprograms"]);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("gcode::subprogram"), "{stderr}");
    let xs: Vec<f64> = xy_of_moves(&text(&out.stdout))
        .iter()
        .map(|p| p.0)
        .collect();
    assert_eq!(xs, [0.0, 5.0, 10.0, 1.0]);

    // Without the pass the frontend's warning stays; a call with arguments is still
    // reported by the pass.
    let out = run("o.ngc", oword, &[]);
    assert!(text(&out.stderr).contains("passes through unchanged"));
    let args = b"G21 G90\nG0 X0 Y0 Z5\no100 call [1]\nM30\no100 sub\nG1 X5 F100\no100 endsub\n";
    let out = run("a.ngc", args, &["--pass", "expand-subprograms"]);
    assert!(text(&out.stderr).contains("subprograms::not-expanded"));
}

/// The hidden temporary files in `dir`.
fn temp_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .expect("read dir")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".ncpost-"))
        .collect()
}

/// SIGTERM, SIGINT, SIGHUP and SIGABRT while the output is written: the process ends
/// by the signal and leaves no temporary file.
#[cfg(unix)]
#[test]
fn signals_remove_the_temporary_file() {
    use std::fmt::Write as _;
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().expect("temporary directory");
    let mut program = String::from("G21 G90\n");
    for i in 0..400_000 {
        let _ = writeln!(program, "G1 X{}.5 Y{}.25 F1000", i % 100, i % 77);
    }
    let input = dir.path().join("big.ngc");
    std::fs::write(&input, program).expect("write input");
    for (name, sig) in [("TERM", 15), ("INT", 2), ("HUP", 1), ("ABRT", 6)] {
        let mut child = ncpost()
            .args(["run", "--emit", "gcode", "-o"])
            .arg(dir.path().join("out.ngc"))
            .arg(&input)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("cannot start ncpost");
        // The run has started writing when its temporary file is there.
        let started = std::time::Instant::now();
        while temp_files(dir.path()).is_empty() {
            assert!(
                started.elapsed().as_secs() < 30,
                "no temporary file appeared"
            );
            assert!(
                child.try_wait().expect("wait").is_none(),
                "ended before SIG{name}"
            );
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        let killed = Command::new("kill")
            .arg(format!("-{name}"))
            .arg(child.id().to_string())
            .status()
            .expect("kill");
        assert!(killed.success());
        let status = child.wait().expect("wait");
        assert_eq!(status.signal(), Some(sig), "SIG{name}: {status:?}");
        assert!(!status.success());
        assert_eq!(
            temp_files(dir.path()),
            Vec::<String>::new(),
            "after SIG{name}"
        );
        assert!(!dir.path().join("out.ngc").exists(), "after SIG{name}");
    }
}

/// One arc of a 100 km radius and 600 turns through the polar printer: an error at its
/// line, not millions of chords held in memory (issue 21, item 11).
#[test]
fn a_huge_polar_arc_is_an_error_at_its_line() {
    let preset = ncpost::preset::Preset::builtin("polar-printer").expect("preset");
    let src = "G0 X10 Y0\nG2 X10 Y0 I100000 J0 P600 F1000\n";
    let diags = ncpost::pipeline::compile_str(src, &preset).expect_err("refused");
    let err = diags
        .iter()
        .find(|d| d.code == "polar-ik::chords")
        .expect("polar-ik::chords");
    assert_eq!(err.location.as_ref().map(|l| l.line), Some(2));
}
