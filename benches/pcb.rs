//! Criterion benchmark of PCB height-map compensation, in bytes of input per second.
//!
//! The input is built in memory as `scripts/bench-pcb.sh` builds its 50 MB file, smaller:
//! `COPIES` times the corpus pair `pcb2gcode_d1minigsr_front.ngc` (isolation milling,
//! G1 only, mm) + `linuxcnc_arcspiral.ngc` (999 G2 arcs, R form, inches), each copy
//! shifted in X and Y by `(i mod 4, i / 4 mod 4)` mm (X/Y words rewritten), their `M2`
//! left out. The map is an x,y,z CSV over X, Y -60..90 mm at a 5 mm pitch (tilt and
//! warp), written to a temporary file.
//!
//! Group `pcb`, one input, two pipelines, both `Pipeline::run_gcode` into
//! `std::io::sink()` (the work of `ncpost run` minus process start-up and file I/O):
//! - `identity`: the built-in `default` preset (the `verify` pass, plain G-code out);
//! - `arcs+heightmap`: the same plus `linearize-arcs` and `heightmap:map=...`.
//!
//! Run with `cargo bench --bench pcb` (`-- --test` for a smoke run). See BENCHMARKS.md.

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ncpost::pipeline::Pipeline;

/// Copies of the corpus pair (about 0.5 MB each).
const COPIES: usize = 8;

fn corpus(name: &str) -> String {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/gcode")
        .join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `line` with `dx`, `dy` added to its X and Y words (outside comments).
fn shift_line(line: &str, dx: f64, dy: f64, out: &mut String) {
    let (code, comment) = match line.find('(') {
        Some(i) => line.split_at(i),
        None => (line, ""),
    };
    let b = code.as_bytes();
    let mut k = 0;
    while k < b.len() {
        let c = b[k] as char;
        let prev_letter = k > 0 && (b[k - 1] as char).is_ascii_alphabetic();
        if matches!(c, 'X' | 'x' | 'Y' | 'y') && !prev_letter {
            let start = k + 1;
            let mut end = start;
            while end < b.len() && (b[end].is_ascii_digit() || b[end] == b'.' || b[end] == b'-') {
                end += 1;
            }
            if let Ok(v) = code[start..end].parse::<f64>() {
                let off = if matches!(c, 'X' | 'x') { dx } else { dy };
                out.push(c);
                out.push_str(&format!("{:.6}", v + off));
                k = end;
                continue;
            }
        }
        out.push(c);
        k += 1;
    }
    out.push_str(comment);
    out.push('\n');
}

fn input() -> String {
    let files = [
        (corpus("pcb2gcode_d1minigsr_front.ngc"), 1.0),
        (corpus("linuxcnc_arcspiral.ngc"), 25.4),
    ];
    let mut out = String::new();
    for i in 0..COPIES {
        let (dx, dy) = ((i % 4) as f64, ((i / 4) % 4) as f64);
        for (text, unit) in &files {
            for line in text.lines() {
                let t = line.trim_start();
                if t.eq_ignore_ascii_case("m2") || t.starts_with("M2 ") {
                    continue;
                }
                shift_line(line, dx / unit, dy / unit, &mut out);
            }
        }
    }
    out.push_str("G21\nM30\n");
    out
}

fn map_text() -> String {
    let mut t = String::from("x,y,z\n");
    for j in 0..31 {
        for i in 0..31 {
            let (x, y) = (-60.0 + 5.0 * i as f64, -60.0 + 5.0 * j as f64);
            let h = 0.2 * (x + 60.0) / 150.0 + 0.087 * (x / 40.0).sin() * (y / 55.0).cos();
            t.push_str(&format!("{x},{y},{h:.4}\n"));
        }
    }
    t
}

fn benches(c: &mut Criterion) {
    let text = input();
    let dir = tempfile::tempdir().expect("temp dir");
    let map = dir.path().join("map.csv");
    std::fs::write(&map, map_text()).expect("map");
    let mut options = toml::Table::new();
    options.insert(
        "map".into(),
        toml::Value::String(map.to_string_lossy().into_owned()),
    );
    let build = |compensate: bool| {
        let mut b = Pipeline::builder().preset_name("default").expect("preset");
        if compensate {
            b = b
                .pass("linearize-arcs", toml::Table::new())
                .pass("heightmap", options.clone());
        }
        b.build().expect("pipeline")
    };
    // The compensated run must not fail (every point on the map).
    {
        let mut errors = 0;
        build(true)
            .run_gcode(text.as_bytes(), std::io::sink(), &mut |d| {
                errors += usize::from(d.is_error())
            })
            .expect("runs");
        assert_eq!(errors, 0);
    }
    let mut group = c.benchmark_group("pcb");
    group.throughput(Throughput::Bytes(text.len() as u64));
    group.sample_size(10);
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(5));
    for (name, compensate) in [("identity", false), ("arcs+heightmap", true)] {
        group.bench_function(name, |b| {
            b.iter(|| {
                let mut p = build(compensate);
                let s = p
                    .run_gcode(black_box(text.as_bytes()), std::io::sink(), &mut |_| {})
                    .expect("runs");
                black_box(s)
            })
        });
    }
    group.finish();
}

criterion_group!(pcb, benches);
criterion_main!(pcb);
