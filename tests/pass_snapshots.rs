//! Before/after IR text of every 5-axis pass on small real CL inputs (one snapshot per
//! fixture and machine): the frontend's output, then the IR after `ik`, `unwrap-rotary`,
//! `densify`, `feed` and `limits`, then the printed output and the diagnostics.
//!
//! Fixtures (first line of each cites its origin):
//! - `tests/fixtures/cl/nx_chamfer_5axis.cl`: ../shared/corpus/cl/mech491_APT_code.txt
//! - `tests/fixtures/cl/nx_variable_axis.cl`: ../shared/corpus/cl/mech491_APT_Variable_Axis.txt
//! - `../shared/corpus/cl/igesio_apt.cl` (whole file)

use ncpost::back::{self, Backend};
use ncpost::front::cl;
use ncpost::ir::{Block, dump};
use ncpost::passes::{self, Context, Output};
use ncpost::preset::{Emit, Preset};

fn dump_all(blocks: &[Block]) -> String {
    let mut s = String::new();
    for b in blocks {
        dump::write_block(&mut s, b);
        s.push('\n');
    }
    s
}

/// Runs the preset's passes one by one, recording the IR after each.
fn stages(path: &str, preset_name: &str) -> String {
    let text = std::fs::read_to_string(path).expect("fixture");
    let preset = Preset::builtin(preset_name).expect("preset");
    let machine = preset.machine.clone().expect("machine");
    let program = cl::parse_str(&text, &preset.cl_input).expect("parses");
    let mut report = format!("== front ({path})\n{}", dump_all(&program.blocks));
    let decimals = match preset.emit {
        Emit::Rrf => Some(preset.rrf.decimals),
        Emit::Gcode => Some(preset.gcode.decimals),
        Emit::Grbl => Some(preset.grbl.decimals),
        Emit::Ir => None,
    };
    let ctx = Context {
        machine: Some(&machine),
        decimals,
        ..Context::default()
    };
    let mut blocks = program.blocks;
    let mut diags = program.diagnostics;
    for spec in &preset.passes {
        let mut pass = passes::build(&spec.name, &spec.options, &ctx).expect("pass builds");
        let mut next = Vec::new();
        for b in blocks {
            pass.run(&mut vec![b], &mut Output::new(&mut next, &mut diags));
        }
        pass.finish(&mut Output::new(&mut next, &mut diags));
        blocks = next;
        if spec.name != "verify" {
            report.push_str(&format!("== after {}\n{}", spec.name, dump_all(&blocks)));
        }
    }
    let mut out = Vec::new();
    {
        let mut writer: Box<dyn Backend> = match preset.emit {
            Emit::Rrf => Box::new(back::rrf::Writer::new(&mut out, &preset.rrf)),
            _ => Box::new(back::gcode::Writer::new(&mut out, &preset.gcode)),
        };
        for b in &blocks {
            if let Err(d) = writer.write_block(b, &mut diags) {
                diags.push(d);
            }
        }
        writer.finish().expect("finish");
    }
    report.push_str(&format!(
        "== output\n{}",
        String::from_utf8(out).expect("utf-8")
    ));
    report.push_str("== diagnostics\n");
    for d in &diags {
        report.push_str(&d.render(path, false));
        report.push('\n');
    }
    report
}

#[test]
fn nx_chamfer_5axis_on_emoc_x5() {
    insta::assert_snapshot!(stages("tests/fixtures/cl/nx_chamfer_5axis.cl", "emoc-x5"));
}

#[test]
fn nx_variable_axis_on_trunnion_bc() {
    insta::assert_snapshot!(stages(
        "tests/fixtures/cl/nx_variable_axis.cl",
        "trunnion-bc"
    ));
}

#[test]
fn nx_variable_axis_on_head_table() {
    insta::assert_snapshot!(stages(
        "tests/fixtures/cl/nx_variable_axis.cl",
        "head-table"
    ));
}

#[test]
fn igesio_apt_on_head_head_ab() {
    insta::assert_snapshot!(stages("../shared/corpus/cl/igesio_apt.cl", "head-head-ab"));
}
