//! Helpers shared by the integration tests (`mod common;`).

#[allow(dead_code)]
pub mod geometry;

use std::io::Write;
use std::process::{Command, Stdio};

use ncpost::diag::Diagnostic;
use ncpost::ir::Block;
use ncpost::passes::{self, Context, Output};

/// Runs `blocks` through the passes given as `name:k=v` specs, each with `finish`, in a
/// context without a machine.
#[allow(dead_code)]
pub fn run_passes(blocks: Vec<Block>, specs: &[&str]) -> (Vec<Block>, Vec<Diagnostic>) {
    let mut diags = Vec::new();
    let mut cur = blocks;
    for spec in specs {
        let (name, table) = passes::parse_spec(spec).expect("spec");
        let mut pass = passes::build(&name, &table, &Context::default()).expect("builds");
        let mut next = Vec::new();
        for b in cur {
            pass.run(&mut vec![b], &mut Output::new(&mut next, &mut diags));
        }
        pass.finish(&mut Output::new(&mut next, &mut diags));
        cur = next;
    }
    (cur, diags)
}

/// Runs pass `name` with `options` in `ctx` over `blocks` one block at a time, as a stream,
/// then `finish`.
#[allow(dead_code)]
pub fn run_pass(
    name: &str,
    options: &toml::Table,
    ctx: &Context,
    blocks: Vec<Block>,
) -> (Vec<Block>, Vec<Diagnostic>) {
    let mut pass = passes::build(name, options, ctx).expect("pass");
    let mut out = Vec::new();
    let mut diags = Vec::new();
    {
        let mut o = Output::new(&mut out, &mut diags);
        for b in blocks {
            pass.run(&mut vec![b], &mut o);
        }
        pass.finish(&mut o);
    }
    (out, diags)
}

/// Runs the binary, `ncpost run <args> -`, on `program` given on standard input.
#[allow(dead_code)]
pub fn run_stdin(args: &[&str], program: &str) -> std::process::Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_ncpost"))
        .arg("run")
        .args(args)
        .arg("-")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("ncpost runs");
    let mut stdin = child.stdin.take().expect("stdin");
    stdin
        .write_all(program.as_bytes())
        .expect("program written");
    drop(stdin);
    child.wait_with_output().expect("ncpost ends")
}
