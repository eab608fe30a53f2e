//! Using ncpost as a library: compile a G-code file for a Duet 3 with a `stats` report.
//!
//! `cargo run --example library -- [INPUT]` (default: the bundled `examples/rrf_cnc_job.gcode`).

use std::fs::File;
use std::io::{BufReader, stdout};

use ncpost::Pipeline;
use ncpost::diag::Severity;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let input = std::env::args().nth(1).unwrap_or_else(|| {
        concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rrf_cnc_job.gcode").to_string()
    });
    let mut pipeline = Pipeline::builder()
        .preset_name("duet-cnc")?
        .pass("stats", toml::Table::new())
        .build()?;
    let reader = BufReader::new(File::open(&input)?);
    let mut errors = 0;
    let summary = pipeline.run_gcode(reader, stdout(), &mut |d| {
        if d.severity == Severity::Error {
            errors += 1;
        }
        eprintln!("{d}");
    })?;
    eprintln!(
        "{} blocks in, {} blocks out, {} warnings, {errors} errors",
        summary.blocks_in, summary.blocks_out, summary.warnings
    );
    if errors > 0 {
        std::process::exit(1);
    }
    Ok(())
}
