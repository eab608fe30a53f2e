//! Peer benchmark: parse a whole G-code file with the `gcode` crate 0.7
//! (`gcode::parse`, its simplest full-parse API) and print counts so the
//! work is not optimised away. Parse-only: no interpretation, no output.
//!
//! Used by `scripts/bench-peers.sh`.
//! Usage: peer_gcode_crate FILE

use std::process::ExitCode;

fn main() -> ExitCode {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: peer_gcode_crate FILE");
        return ExitCode::from(2);
    };
    let src = match std::fs::read_to_string(&path) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("peer_gcode_crate: cannot read {path}: {e}");
            return ExitCode::from(1);
        }
    };

    match gcode::parse(&src) {
        Ok(program) => {
            let mut blocks = 0usize;
            let mut codes = 0usize;
            let mut words = 0usize;
            let mut comments = 0usize;
            for block in &program.blocks {
                blocks += 1;
                comments += block.comments.len();
                words += block.word_addresses.len();
                for code in &block.codes {
                    codes += 1;
                    words += 1 + match code {
                        gcode::Code::General(g) => g.args.len(),
                        gcode::Code::Miscellaneous(m) => m.args.len(),
                        gcode::Code::ToolChange(t) => t.args.len(),
                        _ => 0,
                    };
                }
            }
            println!(
                "gcode-crate 0.7: bytes={} blocks={blocks} codes={codes} words={words} comments={comments}",
                src.len()
            );
            ExitCode::SUCCESS
        }
        Err(diags) => {
            // gcode 0.7 drops the AST when any diagnostic is emitted; the
            // whole input was still parsed, so report and succeed.
            let all = diags.into_inner();
            let first = all.first().map(|d| d.to_string()).unwrap_or_default();
            println!(
                "gcode-crate 0.7: bytes={} diagnostics={} (first: {first})",
                src.len(),
                all.len()
            );
            ExitCode::SUCCESS
        }
    }
}
