//! `ncpost run --verify`: the readback of the printed program (issue 20). Each test runs
//! the binary, reads the report it gives (the `verify::report` note, the errors) and, where
//! the run succeeds, re-reads the printed text itself. The failing runs are made wrong on
//! purpose (a pass told a wrong valve delay, a densify tolerance loosened past the
//! verification's, a controller that cannot run the programmed feed): each must exit 1
//! and leave no output file.

use std::path::Path;
use std::process::{Command, Output};

use tempfile::TempDir;

fn ncpost(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ncpost"))
        .args(args)
        .output()
        .expect("run ncpost")
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write a test file");
    p.display().to_string()
}

/// The number after `label` in the report note.
fn figure(report: &str, label: &str) -> f64 {
    let at = report
        .find(label)
        .unwrap_or_else(|| panic!("{label} in {report}"))
        + label.len();
    let rest = report[at..].trim_start();
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-'))
        .unwrap_or(rest.len());
    rest[..end]
        .parse()
        .unwrap_or_else(|_| panic!("{label} {rest}"))
}

fn report(stderr: &str) -> &str {
    stderr
        .lines()
        .find(|l| l.starts_with("verify:"))
        .unwrap_or_else(|| panic!("no report in {stderr}"))
}

/// The travel program (defect 1): every travel carries the F it was timed at, so
/// the valve leads are exact on the controller, and the material is exact.
const TRAVELS: &str =
    "G21\nG90\nM82\nG0 X10 Y0 F6000\nG1 X20 Y0 E0.4 F1200\nG0 X40 Y0 F6000\nG1 X50 Y0 E0.8 F1200\n";

#[test]
fn polar_travels_verify_clean() {
    let dir = TempDir::new().expect("temporary directory");
    let input = write(dir.path(), "travel.gcode", TRAVELS);
    let out = dir.path().join("travel.out");
    let o = ncpost(&[
        "run",
        "--preset",
        "polar-printer",
        &input,
        "-o",
        &out.display().to_string(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let r = report(&stderr);
    assert!(figure(r, "valve lead") < 1.0, "{r}");
    assert!(figure(r, "material") < 0.5, "{r}");
    assert!(figure(r, "time") < 1.0, "{r}");
    assert!(figure(r, "tip") <= 0.01, "{r}");
    // The printed text itself: every G0 carries an F (an FDM firmware runs G0 at the
    // modal F), and the arm ends at r = 50 on θ = 0.
    let text = std::fs::read_to_string(&out).expect("output written");
    assert!(
        text.lines()
            .filter(|l| l.starts_with("G0"))
            .all(|l| l.contains('F'))
    );
    let last = text
        .lines()
        .rev()
        .find(|l| l.starts_with("G1"))
        .expect("a G1");
    assert!(last.contains("X50"), "{last}");
}

/// A valve-lookahead told a longer open delay than the valve has leads by 100 ms too much:
/// the readback sees it, the run fails and writes nothing; `--no-verify` lets it through.
#[test]
fn wrong_valve_delay_fails() {
    let dir = TempDir::new().expect("temporary directory");
    let input = write(dir.path(), "travel.gcode", TRAVELS);
    let out = dir.path().join("travel.out");
    let out_s = out.display().to_string();
    let args = [
        "run",
        "--preset",
        "polar-printer",
        "--pass",
        "valve-lookahead:open_delay_s=0.3",
        &input,
        "-o",
        &out_s,
    ];
    let o = ncpost(&args);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("verify::valve"), "{stderr}");
    assert!(
        (figure(report(&stderr), "valve lead") - 100.0).abs() < 1.0,
        "{stderr}"
    );
    assert!(!out.exists());
    let mut args = args.to_vec();
    args.push("--no-verify");
    let o = ncpost(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!String::from_utf8_lossy(&o.stderr).contains("verify:"));
    assert!(out.exists());
}

/// A tilting cut on the fork head: densify loosened to 2 mm while `[verify] tip` stays
/// 0.01 mm. The joint-linear path sags far from the programmed line.
#[test]
fn loosened_densify_fails() {
    let dir = TempDir::new().expect("temporary directory");
    let cl = "UNITS/MM\nMULTAX/ON\nRAPID\nGOTO/0,0,10,0,0,1\nFEDRAT/MMPM,600\nGOTO/0,0,0,0,0,1\nGOTO/40,0,0,0.5,0,0.866025403784\n";
    let input = write(dir.path(), "tilt.cl", cl);
    let preset = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/passes/head-head-ab.toml"
    ))
    .expect("built-in preset");
    let config = write(
        dir.path(),
        "loose.toml",
        &format!("{preset}\n[verify]\ntip = 0.01\naxis = 0.05\n"),
    );
    let out = dir.path().join("tilt.nc");
    let out_s = out.display().to_string();
    let good = ncpost(&["run", "--config", &config, &input, "-o", &out_s]);
    let stderr = String::from_utf8_lossy(&good.stderr);
    assert!(good.status.success(), "{stderr}");
    assert!(figure(report(&stderr), "tip") <= 0.01, "{stderr}");
    std::fs::remove_file(&out).expect("remove");
    let bad = ncpost(&[
        "run",
        "--config",
        &config,
        "--pass",
        "densify:tip_tolerance=2,axis_tolerance=45",
        &input,
        "-o",
        &out_s,
    ]);
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("verify::tip"), "{stderr}");
    assert!(figure(report(&stderr), "tip") > 0.01, "{stderr}");
    assert!(!out.exists());
}

/// A controller whose minimum speed is above the programmed feed runs the cut faster
/// than programmed: a time error, reported with the line, in JSON too.
#[test]
fn minimum_speed_above_the_feed_fails_in_json() {
    let dir = TempDir::new().expect("temporary directory");
    let cl = "UNITS/MM\nMULTAX/ON\nRAPID\nGOTO/0,0,10,0,0,1\nFEDRAT/MMPM,60\nGOTO/0,0,0,0,0,1\nGOTO/10,0,0,0,0,1\n";
    let input = write(dir.path(), "slow.cl", cl);
    let preset = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/passes/head-head-ab.toml"
    ))
    .expect("built-in preset")
    .replace("min_speed = 0.0", "min_speed = 120.0");
    let config = write(dir.path(), "slow.toml", &preset);
    let o = ncpost(&[
        "run",
        "--config",
        &config,
        &input,
        "--message-format",
        "json",
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    let codes: Vec<String> = stderr
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v["code"].as_str().map(str::to_string))
        .collect();
    assert!(codes.iter().any(|c| c == "verify::report"), "{stderr}");
    assert!(codes.iter().any(|c| c == "verify::time"), "{stderr}");
    // Twice as fast: half the time, a 50 % error.
    let note = stderr
        .lines()
        .find(|l| l.contains("verify::report"))
        .expect("report");
    let v: serde_json::Value = serde_json::from_str(note).expect("json");
    let msg = v["message"].as_str().expect("message");
    assert!((figure(msg, "time") - 50.0).abs() < 0.1, "{msg}");
}

/// Presets without a machine do not verify unless asked.
#[test]
fn plain_presets_do_not_verify_by_default() {
    let dir = TempDir::new().expect("temporary directory");
    let input = write(dir.path(), "p.gcode", "G0 X1\nG1 X2 F600\n");
    let o = ncpost(&["run", &input]);
    assert!(o.status.success());
    assert!(!String::from_utf8_lossy(&o.stderr).contains("verify:"));
    let o = ncpost(&["run", "--verify", &input]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(report(&stderr).contains("time 0.000 %"), "{stderr}");
}

fn corpus(kind: &str, name: &str) -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus")
        .join(kind)
        .join(name);
    assert!(p.is_file(), "the shared corpus is missing: {}", p.display());
    p.display().to_string()
}

/// The four 5-axis presets on real CL data: every figure within its tolerance.
#[test]
fn five_axis_presets_verify_clean_on_corpus_cl() {
    let input = corpus("cl", "aptpp_shimemcunha.apt");
    for preset in ["trunnion-bc", "head-table", "head-head-ab", "emoc-x5"] {
        let o = ncpost(&["run", "--preset", preset, &input, "-o", "-"]);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{preset}: {stderr}");
        let r = report(&stderr);
        assert!(figure(r, "tip") <= 0.01, "{preset}: {r}");
        assert!(figure(r, "tool axis") <= 0.05, "{preset}: {r}");
        assert!(figure(r, "time") <= 1.0, "{preset}: {r}");
        assert!(figure(r, "limit margin") >= 0.0, "{preset}: {r}");
        assert!(figure(r, "verify:") > 1000.0, "{preset}: {r}");
    }
}

/// The polar printer on a real Cura print, centred on the table: leads, material and
/// times within their tolerances.
#[test]
fn polar_printer_verifies_a_corpus_slicer_file() {
    let dir = TempDir::new().expect("temporary directory");
    let input = corpus("gcode", "lhalb_cura_EVT_v4.gcode");
    let preset = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/passes/polar-printer.toml"
    ))
    .expect("built-in preset")
    .replace("center = [0.0, 0.0]", "center = [50.0, 45.0]")
    .replace("r_max = 150.0", "r_max = 300.0");
    let config = write(dir.path(), "centred.toml", &preset);
    let o = ncpost(&["run", "--config", &config, &input, "-o", "-"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let r = report(&stderr);
    assert!(figure(r, "valve lead") <= 1.0, "{r}");
    assert!(figure(r, "material") <= 0.5, "{r}");
    assert!(figure(r, "per file (") > 5000.0, "{r}");
    assert!(figure(r, "time") <= 1.0, "{r}");
}
