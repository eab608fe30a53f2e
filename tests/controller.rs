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
