//! The two-thread pipeline (`Pipeline::run_gcode` and friends, see `pipeline::relay`)
//! against the same pipeline on one thread (`Pipeline::run_into`): the same bytes and the
//! same diagnostics in the same order, on inputs of many batches (the polar printer on
//! a real sliced file with warnings from the frontend and several passes, the E-moc X5
//! on generated CL data); a failing output stops the run with one error, without
//! reading the whole input.

use ncpost::diag::Diagnostic;
use ncpost::pipeline::{Pipeline, Source};
use ncpost::preset::Preset;

/// The PrusaSlicer cube of the corpus (26,288 lines: 26 batches), with a parameter line
/// now and then so that the frontend warns in several batches.
fn cube_with_parameter_lines() -> String {
    let src = include_str!("fixtures/extrude_rate/gcodenom_mini_cube_a_prusaslicer.gcode");
    let mut out = String::new();
    for (i, line) in src.lines().enumerate() {
        if i % 4000 == 2000 {
            out.push_str("#100=1\n");
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// Each code's diagnostics in order: every stage reports in input order, however the
/// stages' reports interleave (one thread runs a block through every pass before the
/// next block; two threads run a batch of blocks through a pass at a time).
fn by_code(diags: &[Diagnostic]) -> std::collections::BTreeMap<&str, Vec<&Diagnostic>> {
    let mut m: std::collections::BTreeMap<&str, Vec<&Diagnostic>> = Default::default();
    for d in diags {
        m.entry(d.code).or_default().push(d);
    }
    m
}

fn polar_preset() -> Preset {
    let mut p = Preset::builtin("polar-printer").expect("preset");
    for spec in &mut p.passes {
        if spec.name == "polar-ik" {
            spec.options.insert(
                "center".into(),
                toml::Value::Array(vec![90.0.into(), 90.0.into()]),
            );
        }
    }
    p
}

/// (code, line) of each diagnostic, in order, for messages.
fn keys(diags: &[Diagnostic]) -> Vec<(&str, Option<u32>)> {
    diags
        .iter()
        .map(|d| (d.code, d.location.as_ref().map(|l| l.line)))
        .collect()
}

/// Runs `input` on two threads and on one, checks that both write the same bytes and
/// report the same diagnostics (each code's in the same order), and returns the output
/// and diagnostics of the two-thread run.
fn both_ways(preset: &Preset, source: Source, input: &str) -> (Vec<u8>, Vec<Diagnostic>) {
    let build = || {
        Pipeline::builder()
            .preset(preset.clone())
            .build()
            .expect("pipeline")
    };
    let mut threaded_out = Vec::new();
    let mut threaded_diags = Vec::new();
    build()
        .run_source(source, input.as_bytes(), &mut threaded_out, &mut |d| {
            threaded_diags.push(d)
        })
        .expect("writes");
    let mut single_out = Vec::new();
    let mut single_diags = Vec::new();
    {
        let mut back = ncpost::back::rrf::Writer::new(&mut single_out, &preset.rrf);
        build().run_into(source, input.as_bytes(), &mut back, &mut |d| {
            single_diags.push(d)
        });
    }
    assert!(threaded_out == single_out, "the outputs differ");
    assert!(
        by_code(&threaded_diags) == by_code(&single_diags),
        "{:?}\n{:?}",
        keys(&threaded_diags),
        keys(&single_diags)
    );
    (threaded_out, threaded_diags)
}

#[test]
fn the_polar_printer_on_two_threads_writes_what_one_thread_writes() {
    let input = cube_with_parameter_lines();
    let (t_out, t_diags) = both_ways(&polar_preset(), Source::Gcode, &input);
    assert!(t_out.len() > 500_000, "{} bytes", t_out.len());
    // Warnings from the frontend in several batches and from passes, in input order
    // within each stage.
    let lines = |code: &str| -> Vec<u32> {
        t_diags
            .iter()
            .filter(|d| d.code.starts_with(code))
            .filter_map(|d| d.location.as_ref().map(|l| l.line))
            .collect()
    };
    let unknown = lines("gcode::unevaluated");
    assert!(unknown.len() >= 3, "{:?}", keys(&t_diags));
    assert!(unknown.windows(2).all(|w| w[0] < w[1]), "{unknown:?}");
    assert!(!lines("valve-lookahead::").is_empty());
    assert!(!lines("extrude-rate::").is_empty());
}

#[test]
fn the_e_moc_on_two_threads_writes_what_one_thread_writes() {
    let mut cl = String::from(
        "PARTNO/THREADS\nUNITS/MM\nMULTAX/ON\nRAPID\nGOTO/40,0,60,0,0,1\nFEDRAT/MMPM,1200.0\n",
    );
    // A spiral with a tool axis that turns: 5,000 points, five batches.
    for i in 0..5000 {
        let t = f64::from(i) * 0.01;
        let (s, c) = t.sin_cos();
        let tilt = 0.3 + 0.2 * (t * 0.7).sin();
        let (ts, tc) = tilt.sin_cos();
        cl.push_str(&format!(
            "GOTO/{:.6},{:.6},{:.6},{:.9},{:.9},{:.9}\n",
            40.0 * c,
            40.0 * s,
            40.0 - 0.001 * f64::from(i),
            ts * c,
            ts * s,
            tc
        ));
    }
    let preset = Preset::builtin("emoc-x5").expect("preset");
    let (out, _) = both_ways(&preset, Source::Cl, &cl);
    assert!(out.len() > 100_000, "{} bytes", out.len());
}

/// Accepts `limit` bytes, then fails like a full disk.
struct FullDisk {
    limit: usize,
    written: usize,
}

impl std::io::Write for FullDisk {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.written + buf.len() > self.limit {
            return Err(std::io::Error::other("no space left on device"));
        }
        self.written += buf.len();
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[test]
fn a_failing_output_stops_the_run_with_one_error() {
    let input =
        include_str!("fixtures/extrude_rate/gcodenom_mini_cube_a_prusaslicer.gcode").repeat(4);
    let mut pipeline = Pipeline::builder()
        .preset(polar_preset())
        .build()
        .expect("pipeline");
    let mut diags = Vec::new();
    let out = FullDisk {
        limit: 200_000,
        written: 0,
    };
    let err = pipeline
        .run_gcode(input.as_bytes(), out, &mut |d| diags.push(d))
        .expect_err("the output fails");
    assert_eq!(err.code, "io::write");
    assert!(
        !diags.iter().any(|d| d.code == "io::write"),
        "the write error is the result, not also a diagnostic"
    );
}
