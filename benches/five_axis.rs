//! Criterion benchmarks of the 5-axis (E-moc X5) pipeline on a generated CL program.
//!
//! The input is the spiral of `scripts/gen-cl.py` at 20,000 GOTO points (a tool axis that
//! varies on every point; C winds up over several turns), generated in memory:
//!
//! - `five_axis/front`: the CL frontend alone, bytes to IR blocks;
//! - `five_axis/emoc-x5`: the whole `emoc-x5` preset (ik, unwrap-rotary, densify, feed,
//!   limits, verify, RepRapFirmware output) into `std::io::sink()`;
//! - `kinematics/inverse+linear` and `kinematics/forward`: the machine model alone, per
//!   pose.
//!
//! Run with `cargo bench --bench five_axis`; whole-process figures against the seed's
//! Python post come from `scripts/bench-5axis.sh`. See BENCHMARKS.md.

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::{Point3, Unit, Vector3};
use ncpost::front::Frontend;
use ncpost::front::cl::{Options, Parser};
use ncpost::pipeline::{Pipeline, Source};
use ncpost::preset::Preset;

const POINTS: usize = 20_000;

/// The tip and tool axis of point `i` of `n` (as scripts/gen-cl.py).
fn pose(i: usize, n: usize) -> ([f64; 3], [f64; 3]) {
    let turns = (n / 3600).max(1) as f64;
    let s = i as f64 / n as f64;
    let phi = 2.0 * std::f64::consts::PI * turns * s;
    let r = 40.0 + 5.0 * (7.0 * phi).sin();
    let tilt = (32.5 + 27.5 * (3.0 * phi + 11.0 * s).sin()).to_radians();
    let lean = phi + 0.3 * (5.0 * phi).sin();
    (
        [r * phi.cos(), r * phi.sin(), 40.0 - 30.0 * s],
        [tilt.sin() * lean.cos(), tilt.sin() * lean.sin(), tilt.cos()],
    )
}

fn program(n: usize) -> String {
    let mut s = String::from("PARTNO/BENCH\nUNITS/MM\nMULTAX/ON\nSPINDL/12000,CLW\nRAPID\n");
    s.push_str("GOTO/40,0,60,0,0,1\nFEDRAT/MMPM,1200.0\n");
    for i in 0..n {
        let (p, t) = pose(i, n);
        s.push_str(&format!(
            "GOTO/{:.6},{:.6},{:.6},{:.9},{:.9},{:.9}\n",
            p[0], p[1], p[2], t[0], t[1], t[2]
        ));
    }
    s.push_str("SPINDL/OFF\nFINI\n");
    s
}

fn benches(c: &mut Criterion) {
    let text = program(POINTS);
    let preset = Preset::builtin("emoc-x5").expect("built-in preset");
    let mut group = c.benchmark_group("five_axis");
    group
        .throughput(Throughput::Elements(POINTS as u64))
        .measurement_time(Duration::from_secs(5))
        .sample_size(20);
    group.bench_function("front", |b| {
        b.iter(|| {
            let mut parser = Parser::new(text.as_bytes(), Options::default());
            let mut diags = Vec::new();
            let mut blocks = Vec::with_capacity(1024);
            let mut n = 0;
            loop {
                parser.next_batch(&mut blocks, 1024, &mut diags);
                if blocks.is_empty() {
                    break;
                }
                n += blocks.len();
                blocks.clear();
            }
            black_box(n)
        })
    });
    group.bench_function("emoc-x5", |b| {
        let mut pipeline = Pipeline::builder()
            .preset(preset.clone())
            .build()
            .expect("preset builds");
        b.iter(|| {
            let summary = pipeline
                .run_source(Source::Cl, text.as_bytes(), std::io::sink(), &mut |d| {
                    black_box(d);
                })
                .expect("writing to a sink cannot fail");
            black_box(summary.blocks_out)
        })
    });
    group.finish();

    let machine = preset.machine.clone().expect("machine");
    let poses: Vec<(Point3<f64>, Unit<Vector3<f64>>)> = (0..1000)
        .map(|i| {
            let (p, t) = pose(i * 20, POINTS);
            (Point3::from(p), Unit::new_normalize(Vector3::from(t)))
        })
        .collect();
    let mut group = c.benchmark_group("kinematics");
    group.throughput(Throughput::Elements(poses.len() as u64));
    group.bench_function("inverse+linear", |b| {
        b.iter(|| {
            let mut sum = 0.0;
            for (tip, axis) in &poses {
                for o in machine.inverse(*axis) {
                    sum += machine.linear(tip, o.angles)[0];
                }
            }
            black_box(sum)
        })
    });
    group.bench_function("forward", |b| {
        b.iter(|| {
            let mut sum = 0.0;
            for (tip, _) in &poses {
                sum += machine.forward(&[tip.x, tip.y, tip.z], [30.0, tip.x]).tip.x;
            }
            black_box(sum)
        })
    });
    group.finish();
}

criterion_group!(five_axis, benches);
criterion_main!(five_axis);
