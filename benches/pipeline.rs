//! Criterion benchmarks of the G-code pipeline, stage by stage, in bytes of input per second.
//!
//! Groups (each over the same real corpus files, read at run time from
//! `../shared/corpus/gcode/` next to the repository):
//!
//! - `lex`: [`lex_line`] over every line (logos tokens into one reused `Vec`);
//! - `parse`: [`parse_line`] over every line (lex + the line grammar);
//! - `lower`: the whole frontend, [`Parser`] producing IR blocks (line reader, lex,
//!   grammar and lowering with modal state);
//! - `emit`: the plain G-code [`Writer`] over blocks parsed once before timing, into a
//!   reused `Vec<u8>`; throughput is still counted in *input* bytes, so it compares
//!   with the other stages;
//! - `pipeline`: [`Pipeline`] with the built-in `default` preset (the `verify` pass,
//!   plain G-code out) via `run_gcode` into `std::io::sink()`: what
//!   `ncpost run --emit gcode` does, minus process start-up and file I/O.
//!
//! Run with `cargo bench --bench pipeline` (`-- lex` etc. to pick a group);
//! `cargo bench --bench pipeline -- --test` runs every benchmark once as a smoke test.
//! See BENCHMARKS.md for the figures.

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{
    BenchmarkGroup, Criterion, Throughput, criterion_group, criterion_main, measurement::WallTime,
};
use ncpost::back::Backend;
use ncpost::back::gcode::{Options as WriterOptions, Writer};
use ncpost::front::Frontend;
use ncpost::front::gcode::ast::Item;
use ncpost::front::gcode::{Options as FrontOptions, Parser, parse_line};
use ncpost::ir::Block;
use ncpost::num::lexer::{Spanned, lex_line};
use ncpost::pipeline::Pipeline;

/// The corpus files: a 3D print, a PCB milling job and an arc-heavy print.
const FILES: &[&str] = &[
    "gcodenom_mini_cube_a_prusaslicer.gcode",
    "pcb2gcode_d1minigsr_front.ngc",
    "printrun_testgeometry_prusaslicer_arcs.gcode",
];

struct Input {
    name: &'static str,
    text: String,
    /// Lines without terminators (`\n`, `\r\n`), as the frontend's line reader gives them.
    lines: Vec<&'static str>,
    /// The frontend's blocks, for the emitter group.
    blocks: Vec<Block>,
}

fn corpus_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gcode")
}

fn load() -> Vec<Input> {
    let dir = corpus_dir();
    FILES
        .iter()
        .map(|&name| {
            let path = dir.join(name);
            let text = std::fs::read_to_string(&path)
                .unwrap_or_else(|e| panic!("cannot read corpus file {}: {e}", path.display()));
            // The benchmark process is short-lived: leaking one copy gives `'static` lines
            // that outlive every borrow of the token vectors.
            let leaked: &'static str = Box::leak(text.clone().into_boxed_str());
            let lines = leaked.lines().collect();
            let blocks = front_blocks(&text);
            assert!(
                !blocks.is_empty(),
                "{name}: the frontend produced no blocks"
            );
            Input {
                name,
                text,
                lines,
                blocks,
            }
        })
        .collect()
}

fn front_blocks(text: &str) -> Vec<Block> {
    let mut parser = Parser::new(text.as_bytes(), FrontOptions::default());
    let mut diags = Vec::new();
    let mut blocks = Vec::new();
    while let Some(b) = parser.next_block(&mut diags) {
        blocks.push(b);
        diags.clear();
    }
    blocks
}

fn configure(group: &mut BenchmarkGroup<'_, WallTime>, input: &Input) {
    group.throughput(Throughput::Bytes(input.text.len() as u64));
    group.sample_size(10);
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
}

fn bench_lex(c: &mut Criterion, inputs: &[Input]) {
    let mut group = c.benchmark_group("lex");
    for input in inputs {
        configure(&mut group, input);
        group.bench_function(input.name, |b| {
            let mut toks: Vec<Spanned<'static>> = Vec::with_capacity(64);
            b.iter(|| {
                let mut n = 0usize;
                for &line in &input.lines {
                    lex_line(line, &mut toks);
                    n += toks.len();
                }
                black_box(n)
            })
        });
    }
    group.finish();
}

fn bench_parse(c: &mut Criterion, inputs: &[Input]) {
    let mut group = c.benchmark_group("parse");
    for input in inputs {
        configure(&mut group, input);
        group.bench_function(input.name, |b| {
            let mut toks: Vec<Spanned<'static>> = Vec::with_capacity(64);
            let mut items: Vec<Item> = Vec::with_capacity(64);
            b.iter(|| {
                let mut n = 0usize;
                for &line in &input.lines {
                    if let Some(parsed) = parse_line(line, &mut toks, &mut items) {
                        n += items.len() + usize::from(parsed.tail.is_some());
                    }
                }
                black_box(n)
            })
        });
    }
    group.finish();
}

fn bench_lower(c: &mut Criterion, inputs: &[Input]) {
    let mut group = c.benchmark_group("lower");
    for input in inputs {
        configure(&mut group, input);
        group.bench_function(input.name, |b| {
            let mut diags = Vec::new();
            b.iter(|| {
                let mut parser = Parser::new(input.text.as_bytes(), FrontOptions::default());
                let mut n = 0usize;
                while let Some(block) = parser.next_block(&mut diags) {
                    black_box(&block);
                    n += 1;
                    diags.clear();
                }
                n
            })
        });
    }
    group.finish();
}

fn bench_emit(c: &mut Criterion, inputs: &[Input]) {
    let mut group = c.benchmark_group("emit");
    let options = WriterOptions::default();
    for input in inputs {
        configure(&mut group, input);
        group.bench_function(input.name, |b| {
            let mut out: Vec<u8> = Vec::with_capacity(2 * input.text.len());
            let mut diags = Vec::new();
            b.iter(|| {
                out.clear();
                {
                    let mut writer = Writer::new(&mut out, &options);
                    for block in &input.blocks {
                        if let Err(d) = writer.write_block(block, &mut diags) {
                            diags.push(d);
                        }
                    }
                    writer.finish().expect("writing into a Vec cannot fail");
                }
                diags.clear();
                black_box(out.len())
            })
        });
    }
    group.finish();
}

fn bench_pipeline(c: &mut Criterion, inputs: &[Input]) {
    let mut group = c.benchmark_group("pipeline");
    for input in inputs {
        configure(&mut group, input);
        group.bench_function(input.name, |b| {
            let mut pipeline = Pipeline::builder()
                .preset_name("default")
                .expect("built-in preset")
                .build()
                .expect("default preset builds");
            b.iter(|| {
                let summary = pipeline
                    .run_gcode(input.text.as_bytes(), std::io::sink(), &mut |d| {
                        black_box(d);
                    })
                    .expect("writing to a sink cannot fail");
                black_box(summary.blocks_out)
            })
        });
    }
    group.finish();
}

fn benches(c: &mut Criterion) {
    let inputs = load();
    bench_lex(c, &inputs);
    bench_parse(c, &inputs);
    bench_lower(c, &inputs);
    bench_emit(c, &inputs);
    bench_pipeline(c, &inputs);
}

criterion_group!(pipeline, benches);
criterion_main!(pipeline);
