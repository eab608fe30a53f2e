//! The whole pipeline on arbitrary bytes: the G-code frontend, the preset's passes
//! (`verify`) and each backend (plain G-code, RepRapFirmware, the IR dump); and the APT CL
//! frontend through every 5-axis machine preset (ik, unwrap-rotary, densify, feed,
//! limits), writing into a sink. Any input may be rejected with diagnostics; none may
//! panic.
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use ncpost::pipeline::{Pipeline, Source};
use ncpost::preset::{Emit, Preset};

fn machine_presets() -> &'static [Preset] {
    static PRESETS: OnceLock<Vec<Preset>> = OnceLock::new();
    PRESETS.get_or_init(|| {
        ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"]
            .iter()
            .map(|n| Preset::builtin(n).expect("built-in machine preset"))
            .collect()
    })
}

fn presets() -> &'static [Preset] {
    static PRESETS: OnceLock<Vec<Preset>> = OnceLock::new();
    PRESETS.get_or_init(|| {
        let default = Preset::builtin("default").expect("built-in preset `default`");
        let mut rrf = default.clone();
        rrf.emit = Emit::Rrf;
        let mut ir = default.clone();
        ir.emit = Emit::Ir;
        vec![default, rrf, ir]
    })
}

/// Runs `data` as `source` through `preset`, checking every error has a line.
fn check(preset: &Preset, source: Source, data: &[u8]) {
    let mut pipeline = Pipeline::builder()
        .preset(preset.clone())
        .build()
        .expect("the built-in preset builds");
    let mut errors = 0u64;
    let summary = pipeline
        .run_source(source, data, std::io::sink(), &mut |d| {
            if d.is_error() {
                errors += 1;
                assert!(
                    d.code == "gcode::empty"
                        || d.code == "cl::empty"
                        || d.code.starts_with("io::")
                        || d.location.as_ref().is_some_and(|l| l.line >= 1),
                    "error without a line: {d}"
                );
            }
        })
        .expect("writing to a sink cannot fail");
    assert_eq!(summary.errors, errors);
}

fuzz_target!(|data: &[u8]| {
    for preset in machine_presets() {
        check(preset, Source::Cl, data);
    }
    for preset in presets() {
        let mut pipeline = Pipeline::builder()
            .preset(preset.clone())
            .build()
            .expect("the built-in preset builds");
        let mut errors = 0u64;
        let summary = pipeline
            .run_gcode(data, std::io::sink(), &mut |d| {
                if d.is_error() {
                    errors += 1;
                    // Every input error points at a line, except an empty input and
                    // I/O failures.
                    assert!(
                        d.code == "gcode::empty"
                            || d.code.starts_with("io::")
                            || d.location.as_ref().is_some_and(|l| l.line >= 1),
                        "error without a line: {d}"
                    );
                }
            })
            .expect("writing to a sink cannot fail");
        assert_eq!(summary.errors, errors);
    }
});
