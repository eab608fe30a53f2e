//! A flip retracted safely (issue 21, item 10), checked on the printed program of the
//! `trunnion-bc` preset: out of the cut along the tool axis, up to the top of Z, the table
//! turned with X, Y and Z still, across, down, and the plunge at a feed.

use ncpost::pipeline::Pipeline;

/// A cut tilting from B 40 towards +X through Z towards -X past B -35: the continuing
/// solution leaves B's range, the other one is 180 degrees of C away, and no branch runs
/// the whole cut (the twin of the start, B -40, is out of range too), so the look-ahead
/// cannot avoid the flip.
const FLIP: &str = "UNITS/MM\nMULTAX/ON\nRAPID\nGOTO/0,0,50,0.6427876,0,0.7660444\n\
FEDRAT/MMPM,500\nGOTO/5,0,50,0.1736482,0,0.9848078\nGOTO/10,0,50,-0.1736482,0,0.9848078\n\
GOTO/15,0,50,-0.6427876,0,0.7660444\nGOTO/20,0,50,-0.6427876,0,0.7660444\n";

fn word(line: &str, letter: char) -> Option<f64> {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(letter)?.parse().ok())
}

#[test]
fn a_flip_lifts_to_the_top_of_z_and_turns_with_the_linear_axes_still() {
    let mut table = toml::Table::new();
    table.insert("on_flip".into(), "retract".into());
    let mut pipeline = Pipeline::builder()
        .preset_name("trunnion-bc")
        .expect("preset")
        .pass("ik", table)
        .build()
        .expect("builds");
    let z_top = pipeline
        .preset()
        .machine
        .as_ref()
        .and_then(|m| m.limits(ncpost::ir::Axis::Z))
        .expect("Z travel")
        .1;
    let mut out = Vec::new();
    let mut diags = Vec::new();
    pipeline
        .run_source(
            ncpost::pipeline::Source::Cl,
            FLIP.as_bytes(),
            &mut out,
            &mut |d| diags.push(d),
        )
        .expect("runs");
    assert!(diags.iter().any(|d| d.code == "ik::retract"), "{diags:?}");
    assert!(!diags.iter().any(|d| d.is_error()), "{diags:?}");
    let text = String::from_utf8(out).expect("text");
    // The controller's modal Z, read line by line.
    let mut z = None;
    let mut turned = false;
    let mut after_turn = Vec::new();
    for line in text.lines() {
        let rotary = word(line, 'B').is_some() || word(line, 'C').is_some();
        let linear = ['X', 'Y', 'Z'].iter().any(|&l| word(line, l).is_some());
        if rotary && !turned && z.is_some_and(|z| z > 100.0) {
            // The turn of the table, after the lift: no linear axis moves with it, and Z
            // is at the top of its travel.
            assert!(!linear && line.starts_with("G0"), "{line}\n{text}");
            assert_eq!(z, Some(z_top), "{text}");
            turned = true;
            continue;
        }
        z = word(line, 'Z').or(z);
        if turned {
            after_turn.push(line.to_string());
        }
    }
    assert!(turned, "{text}");
    // Across at the top, down with a rapid to above the cut, then the plunge is a feed move.
    assert!(after_turn[0].starts_with("G0") && word(&after_turn[0], 'Z').is_none());
    assert!(after_turn[1].starts_with("G0") && word(&after_turn[1], 'Z').is_some());
    assert!(after_turn[2].starts_with("G1"), "{text}");
}
