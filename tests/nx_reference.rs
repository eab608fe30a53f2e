//! ../shared/corpus/cl/mech491_APT_Variable_Axis.txt against
//! ../shared/corpus/gcode/mech491_PostProcessed_Variable_Axis.nc: the same CL data posted by
//! Siemens NX for a Haas UMC-750 (a B -35..120 / C table-table trunnion, like our
//! `trunnion-bc` preset). The Haas runs it with TCP (G234), so its X/Y/Z are part
//! coordinates; its B and C are what our `ik` must find for the same tool axes: the same
//! angles, or the other solution of the pair (-B, C + 180).

use ncpost::back::Backend;
use ncpost::diag::Diagnostic;
use ncpost::ir::{Axis, Block, BlockKind, Target};
use ncpost::pipeline::{Pipeline, Source};
use ncpost::preset::{PassSpec, Preset};

#[derive(Default)]
struct Collect(Vec<(f64, f64)>);

impl Backend for Collect {
    fn write_block(&mut self, block: &Block, _: &mut Vec<Diagnostic>) -> Result<(), Diagnostic> {
        if let BlockKind::Motion(m) = &block.kind
            && let Target::Joints(j) = &m.target
        {
            self.0
                .push((j.get(Axis::B).unwrap(), j.get(Axis::C).unwrap()));
        }
        Ok(())
    }
    fn finish(&mut self) -> Result<(), Diagnostic> {
        Ok(())
    }
}

/// (B, C) in force at each NX motion line after TCP is switched on.
fn nx_angles(text: &str) -> Vec<(f64, f64)> {
    let (mut b, mut c) = (f64::NAN, f64::NAN);
    let mut tcp = false;
    let mut out = Vec::new();
    for line in text.lines() {
        // Program lines are numbered; the rest is the header and comments.
        let code = line.split('(').next().unwrap_or("");
        if !code.starts_with('N') {
            continue;
        }
        let words: Vec<&str> = code.split_whitespace().collect();
        if words.iter().any(|w| *w == "G53" || *w == "G28") {
            continue;
        }
        let mut moved = false;
        for w in &words {
            let value = || w[1..].parse::<f64>().expect("number");
            match w.as_bytes()[0] {
                b'B' => b = value(),
                b'C' => c = value(),
                b'X' | b'Y' | b'Z' => moved = true,
                b'G' if *w == "G234" => tcp = true,
                b'G' if *w == "G255" => tcp = false,
                _ => {}
            }
        }
        if tcp && moved {
            out.push((b, c));
        }
    }
    out
}

fn wrap(d: f64) -> f64 {
    (d + 540.0).rem_euclid(360.0) - 180.0
}

#[test]
fn trunnion_bc_finds_the_angles_nx_posted_for_a_haas_umc750() {
    let cl = std::fs::read_to_string("../shared/corpus/cl/mech491_APT_Variable_Axis.txt").unwrap();
    let nx =
        std::fs::read_to_string("../shared/corpus/gcode/mech491_PostProcessed_Variable_Axis.nc")
            .unwrap();
    let mut preset =
        Preset::from_toml(&std::fs::read_to_string("passes/trunnion-bc.toml").unwrap()).unwrap();
    preset.passes = ["ik", "unwrap-rotary"]
        .iter()
        .map(|n| PassSpec {
            name: n.to_string(),
            options: toml::Table::new(),
        })
        .collect();
    let mut pipeline = Pipeline::builder().preset(preset).build().unwrap();
    let mut ours = Collect::default();
    let mut diags = Vec::new();
    let summary = pipeline.run_into(Source::Cl, cl.as_bytes(), &mut ours, &mut |d| diags.push(d));
    assert_eq!(summary.errors, 0, "{diags:#?}");
    let theirs = nx_angles(&nx);
    assert_eq!(ours.0.len(), theirs.len(), "motion counts");
    assert!(theirs.len() > 300);
    let mut switches = 0;
    let mut last: Option<(bool, f64)> = None;
    for (k, (&(b, c), &(nb, nc))) in ours.0.iter().zip(&theirs).enumerate() {
        let same = (b - nb).abs() < 2e-3 && wrap(c - nc).abs() < 2e-3;
        let other = (b + nb).abs() < 2e-3 && wrap(c - nc - 180.0).abs() < 2e-3;
        assert!(same || other, "motion {k}: ours B{b} C{c}, NX B{nb} C{nc}");
        // Where the tool axis passes close by vertical, NX's post lets B cross zero (the
        // axis through vertical, up to 0.3 deg off the programmed one) while ncpost keeps
        // B's sign and swings C with the axis's azimuth, holding the axis tolerance. The
        // two then continue on opposite branches: a switch only between two motions
        // within 2 deg of vertical, never back and forth elsewhere.
        if let Some((was_same, prev_b)) = last
            && was_same != same
        {
            assert!(
                prev_b.abs() < 2.0 && nb.abs() < 2.0,
                "motion {k}: branch switch away from vertical (B{prev_b} -> B{nb})"
            );
            switches += 1;
        }
        last = Some((same, nb));
    }
    assert!(switches <= 2, "{switches} branch switches against NX");
}
