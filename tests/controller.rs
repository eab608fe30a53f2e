//! Controller truth for the polar printer (issue 20, defect 1): the printed program is
//! re-read the way RepRapFirmware reads it, by a reader written here and independent of
//! ncpost's frontend and motion model, and the valve opens and closes its delay ahead of
//! every extrusion start and end, whatever F the travels carry, in FDM mode (`G0` at the
//! modal F) and in CNC mode (`G0` at the `M203` caps).

use ncpost::pipeline::compile_str;
use ncpost::preset::Preset;

const OPEN: &str = "M42 P0 S1";
const CLOSE: &str = "M42 P0 S0";

/// How the firmware runs `G0`.
#[derive(Clone, Copy, Debug)]
enum Mode {
    /// RepRapFirmware in FDM mode: `G0` is `G1`, at the one modal F.
    Fdm,
    /// RepRapFirmware in CNC mode: `G0` at the axes' caps, F ignored.
    Cnc,
}

/// What happens at a moment of the printed program.
#[derive(Debug, PartialEq)]
enum Event {
    Open,
    Close,
    /// The screw starts (`M3 S` > 0) or stops.
    Screw(bool),
}

/// The word `letter` of a line, read as a number.
fn word(line: &str, letter: char) -> Option<f64> {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(letter)?.parse().ok())
}

/// Times the printed program as RepRapFirmware does with the polar-printer preset's
/// controller (constant velocity: r on X at 6000 mm/min, θ on Y at 10800 deg/min, F the
/// Euclidean joint speed, at least 6 mm/min): the moments of the valve and screw events.
fn events(text: &str, mode: Mode) -> Vec<(f64, Event)> {
    let caps = [6000.0 / 60.0, 10800.0 / 60.0];
    // RepRapFirmware starts at F3000 until a line sets F.
    let (mut pos, mut feed, mut clock) = ([0.0f64; 2], 3000.0, 0.0);
    let mut out = Vec::new();
    for line in text.lines() {
        let line = line.split(';').next().unwrap_or("").trim();
        if line == OPEN || line == CLOSE {
            let e = if line == OPEN {
                Event::Open
            } else {
                Event::Close
            };
            out.push((clock, e));
            continue;
        }
        if line.starts_with("M3 ") {
            let rpm = word(line, 'S').expect("M3 S");
            out.push((clock, Event::Screw(rpm > 0.0)));
            continue;
        }
        if line.starts_with("G4") {
            clock += word(line, 'P').expect("G4 P") / 1000.0;
            continue;
        }
        let rapid = line.starts_with("G0");
        if !(rapid || line.starts_with("G1")) {
            continue;
        }
        if let Some(f) = word(line, 'F') {
            feed = f;
        }
        let next = [
            word(line, 'X').unwrap_or(pos[0]),
            word(line, 'Y').unwrap_or(pos[1]),
        ];
        let d = [next[0] - pos[0], next[1] - pos[1]];
        let len = d[0].hypot(d[1]);
        if len > 0.0 {
            // The fastest speed along the move that keeps every axis within its cap.
            let capped = (0..2)
                .filter(|&k| d[k] != 0.0)
                .map(|k| caps[k] * len / d[k].abs())
                .fold(f64::INFINITY, f64::min);
            let speed = match (mode, rapid) {
                (Mode::Cnc, true) => capped,
                _ => (feed / 60.0).max(6.0 / 60.0).min(capped),
            };
            clock += len / speed;
        }
        pos = next;
    }
    out
}

/// The worst difference between each valve event's lead and its delay (open 0.2 s
/// before the screw starts, close 0.1 s before it stops), and the number of runs.
fn worst_lead(events: &[(f64, Event)]) -> (f64, usize) {
    let (mut worst, mut runs, mut opened) = (0.0f64, 0, None);
    let mut closed = None;
    for (t, e) in events {
        match e {
            Event::Open => opened = Some(*t),
            Event::Close => closed = Some(*t),
            Event::Screw(true) => {
                let o = opened.take().expect("opened before the screw starts");
                worst = worst.max((t - o - 0.2).abs());
                runs += 1;
            }
            Event::Screw(false) => {
                if let Some(c) = closed.take() {
                    worst = worst.max((t - c - 0.1).abs());
                }
            }
        }
    }
    (worst, runs)
}

fn preset(mode: Mode) -> Preset {
    let mut p = Preset::builtin("polar-printer").expect("preset");
    let polar = p.polar.as_mut().expect("[polar]");
    polar.controller.flavour = Some(match mode {
        Mode::Fdm => ncpost::machine::Flavour::RrfFdm,
        Mode::Cnc => ncpost::machine::Flavour::RrfCnc,
    });
    p
}

/// Two extrusion runs with travels at `travel` (a word such as `F6000`, or nothing: the
/// modal F of the run before).
fn program(travel: &str) -> String {
    format!(
        "G21\nG90\nM82\nG0 X10 Y0 {travel}\nG1 X20 Y0 E0.4 F1200\nG0 X40 Y0 {travel}\n\
         G1 X50 Y0 E0.8 F1200\nG0 X80 Y0 {travel}\nG1 X100 Y0 E1.6 F900\n"
    )
}

#[test]
fn valve_leads_hold_for_travels_at_any_feed_in_both_modes() {
    for mode in [Mode::Fdm, Mode::Cnc] {
        for travel in ["F6000", "F2400", "F900", "F12000", ""] {
            let out = compile_str(&program(travel), &preset(mode)).expect("compiles");
            let (worst, runs) = worst_lead(&events(&out, mode));
            assert_eq!(runs, 3, "{mode:?} {travel}\n{out}");
            // The firmware reads `G4 P` in whole milliseconds: within half of one.
            assert!(worst <= 5e-4 + 1e-9, "{mode:?} {travel}: {worst} s\n{out}");
        }
    }
}

#[test]
fn fdm_travels_carry_the_feed_they_were_timed_at() {
    let out = compile_str(&program("F6000"), &preset(Mode::Fdm)).expect("compiles");
    // F is one modal value for G0 and G1: each travel after a cut restores F6000 (the
    // cut left it at 1200 or 900).
    let mut feed = None;
    let mut travels = 0;
    for l in out.lines() {
        feed = word(l, 'F').or(feed);
        if l.starts_with("G0 ") {
            assert_eq!(feed, Some(6000.0), "{l}\n{out}");
            travels += 1;
        }
    }
    assert!(travels >= 3, "{out}");
}

/// PrusaSlicer's start code for a Prusa MINI (`M201`, `M203 X180 Y180 Z12 E80` in Marlin's
/// mm/s, `M204`, `M205`, `M221`, `M900`) must not reach the polar printer's firmware,
/// which would cap r at 3 mm/s and θ at 3°/s against the model every pass timed with.
#[test]
fn slicer_machine_settings_become_comments_with_one_warning() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/corpus/gcode/gcodenom_both_prusaslicer_mini.gcode"
    );
    let src = std::fs::read_to_string(path).expect("corpus file");
    let mut preset = preset(Mode::Fdm);
    preset
        .passes
        .iter_mut()
        .find(|p| p.name == "polar-ik")
        .expect("polar-ik")
        .options
        .insert(
            "center".into(),
            toml::Value::try_from([90.0, 90.0]).expect("array"),
        );
    let mut pipeline = ncpost::pipeline::Pipeline::builder()
        .preset(preset)
        .build()
        .expect("builds");
    let (mut out, mut diags) = (Vec::new(), Vec::new());
    pipeline
        .run_gcode(src.as_bytes(), &mut out, &mut |d| diags.push(d))
        .expect("runs");
    let out = String::from_utf8(out).expect("text");
    let settings = [
        "M92", "M201", "M203", "M204", "M205", "M207", "M220", "M221", "M566", "M900",
    ];
    for line in out.lines() {
        let first = line.split_whitespace().next().unwrap_or("");
        assert!(!settings.contains(&first), "{line}");
    }
    assert!(out.contains(";M203 X180 Y180 Z12 E80"), "kept as a comment");
    let warned: Vec<_> = diags
        .iter()
        .filter(|d| d.code == "machine-settings::commented")
        .collect();
    assert_eq!(warned.len(), 1, "{diags:?}");
    assert!(warned[0].message.contains("M203 X180 Y180 Z12 E80"));
    assert!(!diags.iter().any(|d| d.is_error()), "{diags:?}");
}

/// The distance of the printed chords from their arc: the G1 vertices of the printed
/// program, read from the text, with every chord sampled against the exact circle.
fn printed_chord_error(text: &str, centre: [f64; 2], r: f64) -> f64 {
    let mut worst = 0.0f64;
    let mut prev: Option<[f64; 2]> = None;
    let mut pos = [0.0f64; 2];
    for line in text.lines() {
        let (x, y) = (word(line, 'X'), word(line, 'Y'));
        if x.is_none() && y.is_none() {
            continue;
        }
        pos = [x.unwrap_or(pos[0]), y.unwrap_or(pos[1])];
        if line.starts_with("G1") {
            let a = prev.expect("a start before the first chord");
            for k in 0..=64 {
                let t = f64::from(k) / 64.0;
                let p = [a[0] + t * (pos[0] - a[0]), a[1] + t * (pos[1] - a[1])];
                let d = (p[0] - centre[0]).hypot(p[1] - centre[1]);
                worst = worst.max((d - r).abs());
            }
        }
        prev = Some(pos);
    }
    worst
}

/// `linearize-arcs` holds its tolerance on the printed (rounded) vertices, not only on
/// the computed ones (issue 20, defect 10).
#[test]
fn linearized_arcs_hold_the_tolerance_as_printed() {
    let mut preset = Preset::builtin("default").expect("preset");
    preset.passes.insert(
        0,
        ncpost::preset::PassSpec {
            name: "linearize-arcs".into(),
            options: toml::Table::new(),
        },
    );
    for (r, start_angle, sweep) in [
        (0.5f64, 0.3f64, 5.9f64),
        (3.7, 1.1, 2.4),
        (25.4, -0.7, 4.4),
        (120.0, 2.0, 1.3),
        (7.77, 0.0, 6.2),
    ] {
        let centre = [10.123456, -4.567891];
        let at = |a: f64| [centre[0] + r * a.cos(), centre[1] + r * a.sin()];
        let (s, e) = (at(start_angle), at(start_angle + sweep));
        let src = format!(
            "G0 X{:.6} Y{:.6}\nG3 X{:.6} Y{:.6} I{:.6} J{:.6} F300\n",
            s[0],
            s[1],
            e[0],
            e[1],
            centre[0] - s[0],
            centre[1] - s[1]
        );
        let out = compile_str(&src, &preset).expect("compiles");
        assert!(!out.contains("G3"), "{out}");
        let worst = printed_chord_error(&out, centre, r);
        assert!(worst <= 0.002 + 1e-6, "r {r}: {worst} mm\n{out}");
    }
}

/// The height of a 3×3 test map over [0, 20]² (nodes every 10 mm), bilinear in each
/// cell, written independently of ncpost's reader.
fn test_surface(x: f64, y: f64) -> f64 {
    let z = [[0.0, 0.31, -0.12], [0.27, -0.4, 0.05], [-0.2, 0.18, 0.44]];
    let (i, j) = (((x / 10.0) as usize).min(1), ((y / 10.0) as usize).min(1));
    let (u, v) = (x / 10.0 - i as f64, y / 10.0 - j as f64);
    z[j][i] * (1.0 - u) * (1.0 - v)
        + z[j][i + 1] * u * (1.0 - v)
        + z[j + 1][i] * (1.0 - u) * v
        + z[j + 1][i + 1] * u * v
}

/// `heightmap` holds its tolerance on the printed vertices (issue 20, defect 10): every
/// printed piece of a compensated cut, read from the text, stays within 0.001 mm
/// vertically of the programmed Z plus the surface.
#[test]
fn heightmap_holds_the_tolerance_as_printed() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let map = dir.path().join("map.csv");
    let mut csv = String::new();
    for j in 0..3 {
        for i in 0..3 {
            let (x, y) = (10.0 * f64::from(i), 10.0 * f64::from(j));
            csv.push_str(&format!("{x},{y},{}\n", test_surface(x, y)));
        }
    }
    std::fs::write(&map, csv).expect("write the map");
    let mut preset = Preset::builtin("default").expect("preset");
    let mut options = toml::Table::new();
    options.insert("map".into(), map.to_string_lossy().into_owned().into());
    preset.passes.insert(
        0,
        ncpost::preset::PassSpec {
            name: "heightmap".into(),
            options,
        },
    );
    let (a, b, z0, z1) = ([0.5, 0.7], [19.3, 18.1], 0.0, -0.5);
    let src = format!(
        "G0 X{} Y{} Z{z0}\nG1 X{} Y{} Z{z1} F300\n",
        a[0], a[1], b[0], b[1]
    );
    let out = compile_str(&src, &preset).expect("compiles");
    let mut prev: Option<[f64; 3]> = None;
    let mut worst = 0.0f64;
    let mut pieces = 0;
    let mut pos = [0.0f64; 3];
    for line in out.lines() {
        let w = [word(line, 'X'), word(line, 'Y'), word(line, 'Z')];
        if w.iter().all(Option::is_none) {
            continue;
        }
        for k in 0..3 {
            pos[k] = w[k].unwrap_or(pos[k]);
        }
        if let (true, Some(p)) = (line.starts_with("G1"), prev) {
            pieces += 1;
            for k in 0..=32 {
                let t = f64::from(k) / 32.0;
                let q: Vec<f64> = (0..3).map(|i| p[i] + t * (pos[i] - p[i])).collect();
                let d = [b[0] - a[0], b[1] - a[1]];
                let s = ((q[0] - a[0]) * d[0] + (q[1] - a[1]) * d[1]) / (d[0] * d[0] + d[1] * d[1]);
                let want = z0 + s * (z1 - z0) + test_surface(q[0], q[1]);
                worst = worst.max((q[2] - want).abs());
            }
        }
        prev = Some(pos);
    }
    assert!(pieces > 4, "{out}");
    assert!(worst <= 0.001 + 1e-9, "{worst} mm\n{out}");
}

/// A polar arc keeps the whole tolerance (issue 20, defect 3): the printed r/θ program,
/// interpolated joint-linearly as the controller does, stays within 0.01 mm of the
/// programmed arc (plus the printed numbers' rounding, 0.00005 mm and 0.00005° at most).
#[test]
fn polar_arcs_stay_within_the_tolerance_of_the_arc() {
    let src = "G21\nG90\nM83\nG0 X55 Y0 F3000\nG3 X25 Y0 I-15 J0 E2 F1200\n";
    let out = compile_str(src, &preset(Mode::Fdm)).expect("compiles");
    let (centre, radius) = ([40.0, 0.0], 15.0);
    let mut worst = 0.0f64;
    let mut prev: Option<[f64; 2]> = None;
    let mut joints = [0.0f64; 2];
    let mut cutting = false;
    for line in out.lines() {
        let (r, t) = (word(line, 'X'), word(line, 'Y'));
        if line.starts_with("G1") {
            cutting = true;
        }
        if r.is_none() && t.is_none() {
            continue;
        }
        joints = [r.unwrap_or(joints[0]), t.unwrap_or(joints[1])];
        if let (true, Some(p)) = (line.starts_with("G1"), prev) {
            for k in 0..=64 {
                let s = f64::from(k) / 64.0;
                let r = p[0] + s * (joints[0] - p[0]);
                let theta = (p[1] + s * (joints[1] - p[1])).to_radians();
                let xy = [r * theta.cos(), r * theta.sin()];
                let d = (xy[0] - centre[0]).hypot(xy[1] - centre[1]);
                worst = worst.max((d - radius).abs());
            }
        }
        prev = Some(joints);
    }
    assert!(cutting, "{out}");
    assert!(worst <= 0.01 + 2e-4, "{worst} mm\n{out}");
}

/// Compiles CL text with a built-in preset (verification on) and gives the printed
/// program; a run with errors fails the test.
fn compile_cl(preset: Preset, cl: &str) -> String {
    use ncpost::pipeline::{Pipeline, Source};
    let mut p = Pipeline::builder()
        .preset(preset)
        .verify(true)
        .build()
        .expect("pipeline");
    let (mut out, mut diags) = (Vec::new(), Vec::new());
    p.run_source(Source::Cl, cl.as_bytes(), &mut out, &mut |d| diags.push(d))
        .expect("writes");
    assert!(
        diags
            .iter()
            .all(|d| d.severity != ncpost::diag::Severity::Error),
        "{diags:?}"
    );
    String::from_utf8(out).expect("utf-8")
}

/// The dwell of the printed `G4` line, seconds, read as the controller reads `P`: whole
/// milliseconds on RepRapFirmware, seconds on LinuxCNC.
fn printed_dwell(text: &str, p_in_seconds: bool) -> f64 {
    let line = text
        .lines()
        .find(|l| l.starts_with("G4"))
        .unwrap_or_else(|| panic!("no G4 in\n{text}"));
    let p = word(line, 'P').expect("G4 P");
    if p_in_seconds { p } else { p.trunc() / 1000.0 }
}

/// A CL `DELAY/0.5` waits half a second on each 5-axis preset's controller: LinuxCNC
/// (the plain G-code presets' flavour) reads `G4 P` as seconds, so `G4 P500` would wait
/// 500 s there (igesio_apt.cl was printed so); RepRapFirmware reads milliseconds. An
/// explicit `gcode.dwell_milliseconds` still decides.
#[test]
fn a_dwell_waits_its_time_on_each_presets_controller() {
    let cl = "UNITS/MM\nMULTAX/ON\nRAPID\nGOTO/0,0,10,0,0,1\nFEDRAT/MMPM,500\n\
              GOTO/10,0,0,0,0,1\nDELAY/0.5\nGOTO/20,0,0,0,0,1\nFINI\n";
    for (name, seconds) in [
        ("emoc-x5", false),
        ("trunnion-bc", true),
        ("head-table", true),
        ("head-head-ab", true),
    ] {
        let text = compile_cl(Preset::builtin(name).expect("preset"), cl);
        let dwell = printed_dwell(&text, seconds);
        assert!((dwell - 0.5).abs() < 1e-9, "{name}: {dwell} s\n{text}");
    }
    let mut p = Preset::builtin("trunnion-bc").expect("preset");
    p.gcode.dwell_milliseconds = Some(true);
    let text = compile_cl(p, cl);
    assert!(text.contains("G4 P500"), "{text}");
}
