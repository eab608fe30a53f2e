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

// ---- The readback's own reading of polar programs (arcs, G53, primes): each printed
// program ncpost writes is accepted, and the same text made wrong is rejected. The
// programmed path is tapped from the frontend's IR as `--verify` taps it before the
// machine passes, and the text goes through the same reader and checker.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use ncpost::front::gcode::{Options, parse_str};
use ncpost::motion::Model;
use ncpost::pipeline::compile_str;
use ncpost::preset::Preset;
use ncpost::readback::{
    Checker, Figures, Kinematics, Queue, Reader, Settings, Tap, Tolerances, Verifier,
};

/// The polar printer preset with `polar-ik` centred at `center`.
fn polar_preset(center: [f64; 2]) -> Preset {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/passes/polar-printer.toml"
    ))
    .expect("built-in preset")
    .replace(
        "center = [0.0, 0.0]",
        &format!("center = [{:?}, {:?}]", center[0], center[1]),
    );
    Preset::from_toml(&text).expect("the preset parses")
}

/// Re-reads `printed` against the programmed path of the G-code `source` on `preset`'s
/// polar printer (centred at `center`): the figures and the codes of the violations.
fn verify_text(
    preset: &Preset,
    center: [f64; 2],
    source: &str,
    printed: &str,
) -> (Figures, Vec<&'static str>) {
    let polar = preset.polar.as_ref().expect("a polar preset");
    let kin = Kinematics::Polar {
        r: polar.r_axis,
        theta: polar.theta_axis,
        center,
        table: [polar.omega_max.to_radians(), polar.alpha_max.to_radians()],
    };
    let controller = preset.controller().cloned().unwrap_or_default();
    read_back(kin, &controller, Some(polar), source, printed)
}

/// `printed` read back against `source` through `kin` on `controller` (a polar printer's
/// valve and screw when `polar` is given): the figures and the error codes.
fn read_back(
    kin: Kinematics,
    controller: &ncpost::machine::Controller,
    polar: Option<&ncpost::machine::polar::Polar>,
    source: &str,
    printed: &str,
) -> (Figures, Vec<&'static str>) {
    let program = parse_str(source, &Options::default()).expect("the source parses");
    let mut vertices = VecDeque::new();
    Tap::new(kin.clone()).record(&program.blocks, &mut vertices);
    let queue: Queue = Arc::new(Mutex::new(vertices));
    let model = Model::new(controller);
    let tol = Tolerances::new(&Settings::default(), 0.01, 0.05);
    let reader = Reader::new(model.clone(), controller.flavour, polar);
    let checker = Checker::new(kin, &model, tol, polar, queue);
    let mut v = Verifier::new(reader, checker, tol, polar.is_some());
    v.bytes(printed.as_bytes());
    let (figures, diags) = v.finish();
    let codes = diags
        .iter()
        .map(|d| d.code)
        .filter(|&c| c != "verify::report")
        .collect();
    (figures, codes)
}

/// The polar printer's table centre in the tests' programs.
const CENTER: [f64; 2] = [0.0, 0.0];

/// The printed program of `source` on the polar printer, which its readback accepts:
/// the preset, the text and the figures.
fn accepted(source: &str) -> (Preset, String, Figures) {
    let preset = polar_preset(CENTER);
    let text = compile_str(source, &preset).unwrap_or_else(|d| panic!("{d:?}"));
    let (f, codes) = verify_text(&preset, CENTER, source, &text);
    assert!(codes.is_empty(), "{codes:?} {f:?}\n{text}");
    assert_eq!(f.unmatched, 0, "{f:?}");
    (preset, text, f)
}

/// Rewrites the word `letter` of printed line `k` (0-based) by `f`.
fn edit_word(text: &str, k: usize, letter: char, f: impl Fn(f64) -> f64) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    lines[k] = lines[k]
        .split_whitespace()
        .map(
            |w| match w.strip_prefix(letter).and_then(|v| v.parse::<f64>().ok()) {
                Some(v) => format!("{letter}{:.4}", f(v)),
                None => w.to_string(),
            },
        )
        .collect::<Vec<_>>()
        .join(" ");
    lines.join("\n") + "\n"
}

/// The printed G1 lines' indices.
fn g1_lines(text: &str) -> Vec<usize> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.starts_with("G1 "))
        .map(|(k, _)| k)
        .collect()
}

/// An arc whose end lies 0.012 mm inside its start's circle (within the controllers'
/// arc tolerance, so the frontend keeps it): the controller and `polar-ik` move it as a
/// spiral (the radius going linearly with the angle), and so does the printed program.
/// Measured against the start's circle it would be 0.012 mm off at its end; against the
/// spiral it is within the tolerance. One printed point moved 0.05 mm outwards on the
/// arm (r larger) leaves the spiral and is rejected, at its line.
#[test]
fn polar_spiral_arc_is_measured_against_the_spiral() {
    let source = "G21\nG90\nG0 X55 Y10 F6000\nG3 X25.012 Y10 I-15 J0 F1200\n";
    let (preset, text, f) = accepted(source);
    assert!(f.tip.value <= 0.01 && f.time.value <= 0.01, "{f:?}");
    let g1 = g1_lines(&text);
    assert!(g1.len() > 6, "the arc is printed in pieces:\n{text}");
    let wrong = edit_word(&text, g1[g1.len() / 2], 'X', |r| r + 0.05);
    let (f, codes) = verify_text(&preset, CENTER, source, &wrong);
    assert!(codes.contains(&"verify::tip"), "{codes:?} {f:?}");
    assert_eq!(f.tip.line as usize, g1[g1.len() / 2] + 1, "{f:?}");
}

/// A small arc (radius 0.1 mm, a half turn): its pieces' chords (45° each within the
/// 0.01 mm tolerance) are 2.5 % shorter than the arc, and the printed feeds give the arc's length its programmed
/// time. Printed 5 % faster, it is rejected.
#[test]
fn polar_arc_time_is_the_arc_length_at_the_feed() {
    let source = "G21\nG90\nG0 X60.1 Y20 F6000\nG2 X59.9 Y20 I-0.1 J0 F600\nG0 X70 Y20 F6000\n";
    let (preset, text, f) = accepted(source);
    assert!(f.time.value < 0.002, "{f:?}");
    let mut wrong = text.clone();
    for k in g1_lines(&text) {
        if text.lines().nth(k).is_some_and(|l| l.contains(" F")) {
            wrong = edit_word(&wrong, k, 'F', |f| f * 1.05);
        }
    }
    let (f, codes) = verify_text(&preset, CENTER, source, &wrong);
    assert!(codes.contains(&"verify::time"), "{codes:?} {f:?}\n{wrong}");
    assert!(f.time.value > 0.04, "{f:?}");
}

/// A final `G53 G0 Z0` (tool up in the machine frame) is printed as written and read as
/// a move in the machine frame that reaches its programmed move; without it the
/// programmed move is never reached.
#[test]
fn polar_machine_frame_move_is_matched() {
    let source = "G21\nG90\nG0 X10 Y0 Z5 F6000\nG1 X20 Y0 Z0.2 F1200\nG1 X30 Y5\nG53 G0 Z0\n";
    let (preset, text, _) = accepted(source);
    assert!(text.contains("G53 G0 Z0"), "{text}");
    let wrong: String = text
        .lines()
        .filter(|l| !l.starts_with("G53"))
        .map(|l| format!("{l}\n"))
        .collect();
    let (f, codes) = verify_text(&preset, CENTER, source, &wrong);
    assert!(codes.contains(&"verify::unmatched"), "{codes:?} {f:?}");
    assert_eq!((f.unmatched, f.unmatched_line), (1, 6), "{f:?}");
}

/// A retraction, a travel, and a long move that first pushes the retracted E back and
/// then prints: the material starts to flow in the printed block where the restoring
/// ends, and the valve opens its delay ahead of that. The open command moved to the
/// move's start (as if the whole move printed) is rejected.
#[test]
fn polar_prime_after_a_retraction_starts_where_the_restore_ends() {
    let source = "G21\nG90\nM83\nG0 X10 Y30 F6000\nG1 X30 Y30 E0.8 F1200\nG1 E-2 F2400\nG0 X40 Y30 F6000\nG1 X100 Y30 E4 F1200\nG0 X110 Y30 F6000\n";
    let (preset, text, f) = accepted(source);
    // The valve opens its delay ahead of the block where the restore ends.
    assert!(f.valve.value <= 0.001, "{f:?}");
    assert!(f.material_block.value <= 0.01, "{f:?}");
    // The open command of the prime, moved to just before the prime's first piece (the
    // first G1 after the travel's last G0).
    let lines: Vec<&str> = text.lines().collect();
    let open = lines
        .iter()
        .rposition(|l| l.starts_with("M42 P0 S1"))
        .expect("an open command");
    let first = lines[..open]
        .iter()
        .rposition(|l| l.starts_with("G0 "))
        .expect("the travel to the prime")
        + 2;
    assert!(lines[first - 1].starts_with("G1 "), "{text}");
    assert!(open > first + 2, "the open lies within the prime:\n{text}");
    let mut moved: Vec<&str> = lines.clone();
    let cmd = moved.remove(open);
    moved.insert(first - 1, cmd);
    let wrong = moved.join("\n") + "\n";
    let (f, codes) = verify_text(&preset, CENTER, source, &wrong);
    assert!(codes.contains(&"verify::valve"), "{codes:?} {f:?}\n{wrong}");
    assert!(f.valve.value > 0.05, "{f:?}");
}

/// A preset without a machine is read as its backend's firmware reads it. A drill plunge
/// at F20 (the pcb-mill preset's `plunge_feed`) runs at F20 on LinuxCNC and on Grbl, so
/// the plain and Grbl outputs verify clean; RepRapFirmware raises it to its 30 mm/min
/// minimum speed, so the same program for `duet-cnc` takes a third less time than
/// programmed and fails.
#[test]
fn presets_without_a_machine_are_read_as_their_backend_firmware() {
    let dir = TempDir::new().expect("temporary directory");
    let plunge = "G21 G90\nG0 Z1\nG0 X1 Y2\nG0 Z0.1\nG1 Z-1.55 F20\nG0 Z1\n";
    let input = write(dir.path(), "plunge.ngc", plunge);
    let hpgl = write(
        dir.path(),
        "drill.hpgl",
        "IN;\nPU;\nPA 40,80;\nPD;\nPA 40,80;\nPU;\n",
    );
    let out = dir.path().join("out.ngc").display().to_string();
    for args in [
        vec!["--preset", "pcb-mill", hpgl.as_str()],
        vec!["--preset", "default", input.as_str()],
        vec!["--emit", "grbl", input.as_str()],
    ] {
        let o = ncpost(&[&["run", "--verify", "-o", &out][..], &args[..]].concat());
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{args:?}: {stderr}");
        assert!(figure(report(&stderr), "time") < 1.0, "{args:?}: {stderr}");
        let printed = std::fs::read_to_string(&out).expect("the output");
        assert!(printed.contains("Z-1.55 F20"), "{printed}");
    }
    let o = ncpost(&[
        "run", "--verify", "--preset", "duet-cnc", "-o", &out, &input,
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("verify::time"), "{stderr}");
    assert!(
        (figure(report(&stderr), "time") - 33.33).abs() < 0.01,
        "{stderr}"
    );
}

/// `printed` read back against `source` on a LinuxCNC mill (Cartesian, no machine).
fn verify_cartesian(source: &str, printed: &str) -> (Figures, Vec<&'static str>) {
    let controller = ncpost::machine::Controller::of(Some(ncpost::machine::Flavour::Linuxcnc));
    read_back(Kinematics::Cartesian, &controller, None, source, printed)
}

/// After homing, arcs from a start the program does not know are copied as written; the
/// printed arcs name X, Y and Z, so the controller knows where it is again while the
/// program knows only the axes its next moves name (printrun's arc test). Those moves are
/// reached on the axes the program knows, and a cut after lines copied as written is
/// compared on them alone (igesio's block-delete line, then a relative move from it: the
/// printed Y is 10, the program's unknown). A printed move off a known axis still fails.
#[test]
fn moves_after_lines_copied_as_written_are_compared_on_the_axes_the_program_knows() {
    let source = "G28\nG0 Z10\nG90 G21\nG2 X15 Y20 I30 J40 Z20 F8000\nG0 X5\nG0 Y5\n\
                  G1 X20 Y5 Z0 F300\n/ G1 X99\nG91 G1 X5 Y5\nG90 G1 X25\nG1 X30\n";
    let dir = TempDir::new().expect("temporary directory");
    let input = write(dir.path(), "arcs.gcode", source);
    let out = dir.path().join("arcs.out").display().to_string();
    let o = ncpost(&["run", "--verify", "-o", &out, &input]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let printed = std::fs::read_to_string(&out).expect("the output");
    let (f, codes) = verify_cartesian(source, &printed);
    assert!(codes.is_empty(), "{codes:?} {f:?}\n{printed}");
    assert_eq!(f.unmatched, 0, "{f:?}");
    // The printed program's travel to X5 goes to X6: the program knows X there.
    let wrong = printed.replace("G0 X5\n", "G0 X6\n");
    assert_ne!(wrong, printed, "{printed}");
    let (f, codes) = verify_cartesian(source, &wrong);
    assert!(!codes.is_empty(), "{f:?}\n{wrong}");
    // After the block-delete line and the relative move from where it left X, the
    // program knows X and Z again but not Y; the cut to X30 strays 0.5 mm in Z.
    let wrong = printed.replace("G1 X30\n", "G1 X27.5 Z0.5\nG1 X30 Z0\n");
    assert_ne!(wrong, printed, "{printed}");
    let (f, codes) = verify_cartesian(source, &wrong);
    assert!(codes.contains(&"verify::tip"), "{codes:?} {f:?}\n{wrong}");
}

/// Under trapezoid timing the printed moves are timed with their neighbours, as the
/// valve look-ahead timed them: the travels' leads and the material are judged and exact
/// (the open command lands where the travel, braking into the extrusion, is its delay
/// away from it), and a valve told a wrong delay fails by that difference. Block times
/// are reported but not judged: the programmed feed gives none once the machine
/// accelerates.
#[test]
fn trapezoid_timing_judges_valve_leads_and_material_on_the_planned_times() {
    let dir = TempDir::new().expect("temporary directory");
    let input = write(dir.path(), "travel.gcode", TRAVELS);
    let out = dir.path().join("travel.out").display().to_string();
    let run = |extra: &[&str]| {
        let args = [
            &["run", "--preset", "polar-printer", "--timing", "trapezoid"][..],
            extra,
        ]
        .concat();
        ncpost(&[&args[..], &[input.as_str(), "-o", out.as_str()][..]].concat())
    };
    let o = run(&[]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let r = report(&stderr);
    assert!(figure(r, "valve lead") < 1.0, "{r}");
    assert!(figure(r, "material") < 0.5, "{r}");
    assert!(r.contains("(tolerance inf %)"), "{r}");
    let o = run(&["--pass", "valve-lookahead:open_delay_s=0.3"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("verify::valve"), "{stderr}");
    assert!(figure(report(&stderr), "valve lead") > 50.0, "{stderr}");
}
