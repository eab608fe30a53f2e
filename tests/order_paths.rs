//! The `order-paths` pass, checked on the printed G-code by a reader of its own (below):
//! cut groups are the moves from a plunge below Z0 to the retract, travel the XY length
//! of the moves made at or above Z0.
//!
//! 1. Real boards: every file of `../shared/corpus/hpgl/` through the `pcb-mill` preset and
//!    the pcb2gcode / PCB files of `../shared/corpus/gcode/` (read from there; origins in
//!    `../shared/corpus/SOURCES.md`): travel never longer than without the pass, every cut
//!    group exactly once with the same cut moves and feeds (reversed only when made of
//!    lines), every output block passes the IR verifier.
//! 2. A shuffled real board (EAGLE `hpgl2gcode_test.hpgl`, groups shuffled with a fixed
//!    seed): at least 30 % shorter travel.
//! 3. The seed's two bugs: the last figure is cut; a figure whose start has the X of the
//!    previous end is cut, not travelled (the seed's own NC code of 2006-11-20).
//! 4. Barriers (tool change, G92), comments inside a group, options, the input order kept
//!    when not longer, a barrier inside a group (warning snapshot), a before/after
//!    snapshot of a small real file, a property test over random groups, a large board.

use std::path::{Path, PathBuf};

use ncpost::diag::Diagnostic;
use ncpost::front::gcode::{Options, parse_str};
use ncpost::ir::Block;
use ncpost::passes::{self, Context, Output};
use ncpost::pipeline::{Pipeline, Source};
use ncpost::preset::Preset;
use ncpost::valid::Verifier;
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------
// Running the pass
// ---------------------------------------------------------------------------------------

fn corpus(dir: &str, name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus")
        .join(dir)
        .join(name)
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

/// G-code through the frontend, then `order-paths` with `options` (TOML) on the IR; the
/// printed input, the printed output, the output blocks and the pass's diagnostics.
fn order_gcode(src: &str, options: &str) -> (String, String, Vec<Block>, Vec<Diagnostic>) {
    let program = parse_str(src, &Options::default()).expect("parses");
    let table: toml::Table = toml::from_str(options).expect("options");
    let mut pass = passes::build("order-paths", &table, &Context::default()).expect("builds");
    let mut out = Vec::new();
    let mut diags = Vec::new();
    for b in program.blocks.iter().cloned() {
        pass.run(&mut vec![b], &mut Output::new(&mut out, &mut diags));
    }
    pass.finish(&mut Output::new(&mut out, &mut diags));
    let mut verifier = Verifier;
    for b in &out {
        verifier
            .check(b)
            .unwrap_or_else(|e| panic!("verifier: {e}: {b:?}"));
    }
    let print = |blocks: &[Block]| {
        ncpost::back::gcode::write_string(blocks, &Default::default()).expect("prints")
    };
    (print(&program.blocks), print(&out), out, diags)
}

/// HPGL through the `pcb-mill` preset plus `passes`: the output text and diagnostics.
fn compile_hpgl(src: &str, passes: &[&str]) -> (String, Vec<Diagnostic>) {
    let mut b = Pipeline::builder().preset(Preset::builtin("pcb-mill").expect("preset"));
    for spec in passes {
        let (name, table) = ncpost::passes::parse_spec(spec).expect("spec");
        b = b.pass(&name, table);
    }
    let mut pipeline = b.build().expect("pipeline");
    let mut out = Vec::new();
    let mut diags = Vec::new();
    pipeline
        .run_source(Source::Hpgl, src.as_bytes(), &mut out, &mut |d| {
            diags.push(d)
        })
        .expect("runs");
    assert!(
        diags.iter().all(|d| !d.is_error()),
        "errors: {:#?}",
        diags.iter().filter(|d| d.is_error()).collect::<Vec<_>>()
    );
    (String::from_utf8(out).expect("utf-8"), diags)
}

fn note(diags: &[Diagnostic]) -> String {
    diags
        .iter()
        .find(|d| d.code == "order-paths::travel")
        .map(|d| d.message.clone())
        .expect("the travel note")
}

// ---------------------------------------------------------------------------------------
// A reader of printed G-code: cut groups and travel
// ---------------------------------------------------------------------------------------

/// A move as the controller sees it, absolute, mm (rounded to 1 um for comparing).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
struct Cut {
    kind: u8,
    from: (i64, i64, i64),
    to: (i64, i64, i64),
    /// Arc centre (absolute), zero for lines.
    centre: (i64, i64),
    feed: i64,
}

/// A move with its numbers, for writing programs again.
#[derive(Debug, Clone, Copy)]
struct Move {
    kind: u8,
    to: [f64; 3],
    ij: (f64, f64),
    feed: f64,
}

#[derive(Debug, Clone, Default)]
struct Group {
    /// Cut moves (XY changes below Z0), in order.
    cuts: Vec<Cut>,
    /// XY where the plunge happens, and the deepest Z (for holes).
    plunge: (i64, i64),
    depth: i64,
    /// Every move from the plunge through the retract, and the XY before the plunge.
    moves: Vec<Move>,
    start: (f64, f64),
    /// Lines of text (comments) seen inside the group.
    comments: Vec<String>,
    /// Index of the group among all groups, and the number of `T` lines before it.
    tools_before: usize,
}

impl Group {
    /// The key a group must keep: its cuts forwards, or backwards when all are lines.
    fn canonical(&self) -> Vec<Cut> {
        if self.cuts.is_empty() {
            return vec![Cut {
                kind: b'H',
                from: (self.plunge.0, self.plunge.1, self.depth),
                to: (self.plunge.0, self.plunge.1, self.depth),
                centre: (0, 0),
                feed: 0,
            }];
        }
        let forward = self.cuts.clone();
        if self.cuts.iter().all(|c| c.kind == b'1') {
            let backward: Vec<Cut> = self
                .cuts
                .iter()
                .rev()
                .map(|c| Cut {
                    from: c.to,
                    to: c.from,
                    ..*c
                })
                .collect();
            forward.min(backward)
        } else {
            forward
        }
    }
}

#[derive(Debug, Default)]
struct Reading {
    groups: Vec<Group>,
    /// XY length of the moves made with the tool at or above Z0.
    travel: f64,
    /// The XYZ before each `G92` line.
    before_g92: Vec<(i64, i64, i64)>,
}

fn um(v: f64) -> i64 {
    (v * 1000.0).round() as i64
}

fn word(words: &[&str], letter: char) -> Option<f64> {
    words
        .iter()
        .find(|w| w.starts_with(letter))
        .and_then(|w| w[1..].parse().ok())
}

fn read_gcode(text: &str) -> Reading {
    let mut r = Reading::default();
    let (mut x, mut y, mut z) = (f64::NAN, f64::NAN, f64::NAN);
    let mut motion = b'0';
    let mut feed = 0.0;
    let mut tools = 0;
    let mut group: Option<Group> = None;
    for line in text.lines() {
        let code = line.split(['(', ';']).next().unwrap_or("").trim();
        if code.is_empty() {
            if let Some(g) = &mut group
                && !line.trim().is_empty()
            {
                g.comments.push(line.trim().to_string());
            }
            continue;
        }
        let words: Vec<&str> = code.split_whitespace().collect();
        if words.iter().any(|w| w.starts_with('T')) {
            tools += 1;
        }
        if words.contains(&"G92") {
            r.before_g92.push((um(x), um(y), um(z)));
            continue;
        }
        for w in &words {
            match *w {
                "G0" => motion = b'0',
                "G1" => motion = b'1',
                "G2" => motion = b'2',
                "G3" => motion = b'3',
                _ => {}
            }
        }
        if let Some(f) = word(&words, 'F') {
            feed = f;
        }
        let (nx, ny, nz) = (word(&words, 'X'), word(&words, 'Y'), word(&words, 'Z'));
        if nx.is_none() && ny.is_none() && nz.is_none() {
            continue;
        }
        let (sx, sy, sz) = (x, y, z);
        x = nx.unwrap_or(x);
        y = ny.unwrap_or(y);
        z = nz.unwrap_or(z);
        let ij = (
            word(&words, 'I').unwrap_or(0.0),
            word(&words, 'J').unwrap_or(0.0),
        );
        let mv = Move {
            kind: motion,
            to: [x, y, z],
            ij,
            feed,
        };
        if sz >= 0.0 && z >= 0.0 {
            let d = (x - sx).hypot(y - sy);
            if d.is_finite() {
                r.travel += d;
            }
            continue;
        }
        if sz >= 0.0 && z < 0.0 {
            group = Some(Group {
                plunge: (um(sx), um(sy)),
                depth: um(z),
                start: (sx, sy),
                tools_before: tools,
                ..Group::default()
            });
        }
        let Some(g) = &mut group else { continue };
        g.moves.push(mv);
        g.depth = g.depth.min(um(z));
        if (x, y) != (sx, sy) && sz < 0.0 && z < 0.0 {
            g.cuts.push(Cut {
                kind: motion,
                from: (um(sx), um(sy), um(sz)),
                to: (um(x), um(y), um(z)),
                centre: if motion == b'2' || motion == b'3' {
                    (um(sx + ij.0), um(sy + ij.1))
                } else {
                    (0, 0)
                },
                feed: um(feed),
            });
        }
        if z >= 0.0 {
            r.groups.extend(group.take());
        }
    }
    r
}

/// Every group of `a` is in `b` exactly once (forwards, or backwards when allowed).
#[track_caller]
fn assert_same_groups(a: &Reading, b: &Reading, what: &str) {
    let mut ka: Vec<Vec<Cut>> = a.groups.iter().map(Group::canonical).collect();
    let mut kb: Vec<Vec<Cut>> = b.groups.iter().map(Group::canonical).collect();
    ka.sort();
    kb.sort();
    assert_eq!(ka.len(), kb.len(), "{what}: number of groups");
    assert!(ka == kb, "{what}: the groups differ");
}

/// A program of `groups` in the given order, every move written in full: travel at Z1,
/// then the group's own moves from the plunge to the retract.
fn write_program(groups: &[&Group]) -> String {
    let mut s = String::from("G21 G90\nG0 Z1\nM3 S4600\n");
    for g in groups {
        s.push_str(&format!("G0 X{:.4} Y{:.4}\n", g.start.0, g.start.1));
        for m in &g.moves {
            let [x, y, z] = m.to;
            match m.kind {
                b'0' => s.push_str(&format!("G0 X{x:.4} Y{y:.4} Z{z:.4}\n")),
                b'1' => s.push_str(&format!("G1 X{x:.4} Y{y:.4} Z{z:.4} F{}\n", m.feed)),
                k => s.push_str(&format!(
                    "G{} X{x:.4} Y{y:.4} Z{z:.4} I{:.4} J{:.4} F{}\n",
                    k as char, m.ij.0, m.ij.1, m.feed
                )),
            }
        }
    }
    s.push_str("M5\nM2\n");
    s
}

/// A fixed-seed generator (xorshift64*), so the shuffle is the same on every run.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

// ---------------------------------------------------------------------------------------
// 1. Real boards
// ---------------------------------------------------------------------------------------

#[track_caller]
fn check_hpgl_board(name: &str) -> (f64, f64) {
    let src = read(&corpus("hpgl", name));
    let (plain, _) = compile_hpgl(&src, &[]);
    let (ordered, diags) = compile_hpgl(&src, &["order-paths", "verify"]);
    let (a, b) = (read_gcode(&plain), read_gcode(&ordered));
    assert!(!a.groups.is_empty(), "{name}: no groups");
    assert_same_groups(&a, &b, name);
    assert!(
        b.travel <= a.travel + 1e-6,
        "{name}: travel {} > {}",
        b.travel,
        a.travel
    );
    note(&diags);
    (a.travel, b.travel)
}

#[test]
fn corpus_chiplotle_bird_hpgl() {
    check_hpgl_board("chiplotle_bird.hpgl");
}

#[test]
fn corpus_chiplotle_foal_hpgl() {
    check_hpgl_board("chiplotle_foal.hpgl");
}

#[test]
fn corpus_chiplotle_import_test_hpgl() {
    check_hpgl_board("chiplotle_import_test.hpgl");
}

#[test]
fn corpus_gcodeplot_star_plt() {
    check_hpgl_board("gcodeplot_star.plt");
}

#[test]
fn corpus_gcodeplot_test_hpgl() {
    check_hpgl_board("gcodeplot_test.hpgl");
}

#[test]
fn corpus_hpgl2gcode_basic_hpgl() {
    check_hpgl_board("hpgl2gcode_basic.hpgl");
}

#[test]
fn corpus_hpgl2gcode_test_hpgl() {
    // EAGLE CAM output of a real board: the order is much shorter.
    let (before, after) = check_hpgl_board("hpgl2gcode_test.hpgl");
    assert!(after < 0.8 * before, "{before} -> {after}");
}

#[track_caller]
fn check_gcode_file(name: &str) {
    let src = read(&corpus("gcode", name));
    let (plain, ordered, _, diags) = order_gcode(&src, "");
    let (a, b) = (read_gcode(&plain), read_gcode(&ordered));
    assert!(!a.groups.is_empty(), "{name}: no groups");
    assert_same_groups(&a, &b, name);
    // Tool changes are barriers: each group keeps the tool it had.
    let mut ta: Vec<(Vec<Cut>, usize)> = a
        .groups
        .iter()
        .map(|g| (g.canonical(), g.tools_before))
        .collect();
    let mut tb: Vec<(Vec<Cut>, usize)> = b
        .groups
        .iter()
        .map(|g| (g.canonical(), g.tools_before))
        .collect();
    ta.sort();
    tb.sort();
    assert!(ta == tb, "{name}: a group changed tool");
    assert!(
        b.travel <= a.travel + 1e-6,
        "{name}: travel {} > {}",
        b.travel,
        a.travel
    );
    note(&diags);
}

#[test]
fn corpus_pcb2gcode_d1minigsr_front() {
    check_gcode_file("pcb2gcode_d1minigsr_front.ngc");
}

#[test]
fn corpus_pcb2gcode_easysdr_drill() {
    // Seven tool changes: holes are ordered within each tool only.
    check_gcode_file("pcb2gcode_easysdr_drill.ngc");
}

#[test]
fn corpus_pcb2gcode_multivibrator_tiles_milldrill() {
    // Helical G2 holes: moved, never reversed.
    check_gcode_file("pcb2gcode_multivibrator_tiles_milldrill.ngc");
}

#[test]
fn corpus_printrun_pcb_milling_comment() {
    check_gcode_file("printrun_pcb_milling_comment.gcode");
}

// ---------------------------------------------------------------------------------------
// 2. A shuffled real board
// ---------------------------------------------------------------------------------------

#[test]
fn shuffled_real_board_travel_at_least_30_percent_shorter() {
    let src = read(&corpus("hpgl", "hpgl2gcode_test.hpgl"));
    let (plain, _) = compile_hpgl(&src, &[]);
    let board = read_gcode(&plain);
    assert!(board.groups.len() > 100, "{}", board.groups.len());
    let mut groups: Vec<&Group> = board.groups.iter().collect();
    let mut rng = Rng(0x5eed_0001);
    for i in (1..groups.len()).rev() {
        groups.swap(i, rng.below(i + 1));
    }
    let shuffled = write_program(&groups);
    let (input, ordered, _, diags) = order_gcode(&shuffled, "");
    let (a, b) = (read_gcode(&input), read_gcode(&ordered));
    assert_same_groups(&board, &a, "shuffled");
    assert_same_groups(&a, &b, "ordered");
    let saved = 1.0 - b.travel / a.travel;
    eprintln!(
        "shuffled board: travel {:.1} mm -> {:.1} mm ({:.1} % shorter); {}",
        a.travel,
        b.travel,
        100.0 * saved,
        note(&diags)
    );
    assert!(saved >= 0.30, "only {:.1} % shorter", 100.0 * saved);
    // Nearest neighbour alone (the seed's method) is already shorter; 2-opt adds to it.
    let (_, nn, _, _) = order_gcode(&shuffled, "two_opt = false");
    let nn = read_gcode(&nn);
    assert_same_groups(&a, &nn, "nearest neighbour");
    assert!(nn.travel < a.travel && b.travel <= nn.travel + 1e-6);
}

// ---------------------------------------------------------------------------------------
// 3. The seed's bugs
// ---------------------------------------------------------------------------------------

/// A program of line figures at depth 0.06 (the seed's heights and feeds), each a list of
/// XY points, in the given order.
fn figures(list: &[&[(f64, f64)]]) -> String {
    let mut s = String::from("G21 G90\nG0 Z1\nG0 X0 Y0\nM3 S4600\n");
    for f in list {
        s.push_str(&format!(
            "G0 X{} Y{}\nG0 Z0.1\nG1 Z-0.06 F20\n",
            f[0].0, f[0].1
        ));
        for p in &f[1..] {
            s.push_str(&format!("G1 X{} Y{} F70\n", p.0, p.1));
        }
        s.push_str("G0 Z1\n");
    }
    s.push_str("M5\nM2\n");
    s
}

#[test]
fn seed_bug_1_the_last_figure_is_always_cut() {
    // The seed's search ran `for (i = 1; i < fig_count; i++)` and never looked at the last
    // figure. Here the last figure of the list is the nearest one to the start and the
    // other figures lead away from it: it must be cut (first), once.
    let src = figures(&[
        &[(50.0, 0.0), (60.0, 0.0)],
        &[(70.0, 0.0), (80.0, 0.0)],
        &[(90.0, 0.0), (100.0, 0.0)],
        &[(1.0, 1.0), (2.0, 2.0)],
    ]);
    for options in ["", "two_opt = false", "reverse = false"] {
        let (input, output, _, _) = order_gcode(&src, options);
        let (a, b) = (read_gcode(&input), read_gcode(&output));
        assert_same_groups(&a, &b, options);
        let last = a.groups.last().expect("groups").canonical();
        let n = b.groups.iter().filter(|g| g.canonical() == last).count();
        assert_eq!(n, 1, "{options}: the last figure is cut {n} times");
        assert_eq!(
            b.groups[0].canonical(),
            last,
            "{options}: it is the nearest"
        );
        assert!(b.travel < a.travel, "{options}");
    }
    // A single figure, and two: nothing is lost at the ends of the list.
    for list in [
        &[&[(5.0, 5.0), (6.0, 5.0)][..]][..],
        &[&[(5.0, 5.0), (6.0, 5.0)][..], &[(1.0, 1.0), (1.0, 2.0)][..]][..],
    ] {
        let (input, output, _, _) = order_gcode(&figures(list), "");
        assert_same_groups(&read_gcode(&input), &read_gcode(&output), "short list");
    }
}

#[test]
fn seed_bug_2_a_figure_starting_at_the_previous_end_x_is_cut() {
    // The seed's own NC code of 2006-11-20 (a track of its ZIP adapter board), as its
    // HPGL2NC wrote it: the second figure starts at X21.8186 and its first cut keeps
    // X21.8186; the seed's bug travelled such a figure with the pen up. Here a third
    // figure starts at the second one's end X, and the figures are listed far-first so
    // that the pass reorders them.
    let seed_a: &[(f64, f64)] = &[
        (16.6116, 2.5908),
        (16.6116, 4.9022),
        (17.1704, 5.4356),
        (17.4498, 5.4356),
        (20.6248, 8.89),
        (20.6248, 13.3604),
        (20.1676, 13.8176),
        (20.1676, 15.8242),
        (20.6502, 16.3068),
        (21.336, 16.3068),
    ];
    let seed_b: &[(f64, f64)] = &[
        (21.8186, 15.8242),
        (21.8186, 13.8176),
        (21.3614, 13.3604),
        (21.3614, 8.6106),
        (21.2598, 8.5344),
        (21.2598, 8.509),
        (18.1864, 5.1816),
        (18.4658, 4.9022),
        (18.4658, 2.5908),
        (17.9324, 2.032),
        (17.1704, 2.032),
        (16.6116, 2.5908),
    ];
    let same_x: &[(f64, f64)] = &[(16.6116, 30.0), (16.6116, 25.0), (10.0, 25.0)];
    let far: &[(f64, f64)] = &[(60.0, 60.0), (61.0, 60.0)];
    let src = figures(&[far, same_x, seed_b, seed_a]);
    for options in ["", "two_opt = false", "reverse = false"] {
        let (input, output, _, _) = order_gcode(&src, options);
        let (a, b) = (read_gcode(&input), read_gcode(&output));
        assert_same_groups(&a, &b, options);
        assert_ne!(
            a.groups.iter().map(Group::canonical).collect::<Vec<_>>(),
            b.groups.iter().map(Group::canonical).collect::<Vec<_>>(),
            "{options}: reordered"
        );
        // Every segment of every figure is a cut (below Z0), none is travel.
        let cut: Vec<Cut> = b.groups.iter().flat_map(|g| g.cuts.clone()).collect();
        for f in [seed_a, seed_b, same_x, far] {
            for w in f.windows(2) {
                let (p, q) = ((um(w[0].0), um(w[0].1)), (um(w[1].0), um(w[1].1)));
                let found = cut.iter().any(|c| {
                    let (f, t) = ((c.from.0, c.from.1), (c.to.0, c.to.1));
                    (f, t) == (p, q) || (f, t) == (q, p)
                });
                assert!(found, "{options}: {w:?} is not cut");
            }
        }
        assert_eq!(b.groups.len(), 4, "{options}: four plunges");
    }
}

// ---------------------------------------------------------------------------------------
// 4. Barriers, comments, options, snapshots
// ---------------------------------------------------------------------------------------

#[test]
fn tool_changes_are_barriers() {
    // Tool 1 cuts far away, tool 2 near the origin: the best tour would mix them.
    let a = figures(&[&[(50.0, 50.0), (51.0, 50.0)], &[(0.0, 1.0), (0.0, 2.0)]]);
    let b = figures(&[&[(50.0, 52.0), (51.0, 52.0)], &[(1.0, 1.0), (1.0, 2.0)]]);
    let src = format!("T1 M6\n{}T2 M6\n{}", a.replace("M2\n", ""), b);
    let (input, output, _, _) = order_gcode(&src, "");
    let (ra, rb) = (read_gcode(&input), read_gcode(&output));
    assert_same_groups(&ra, &rb, "tools");
    for g in &rb.groups {
        let original = ra
            .groups
            .iter()
            .find(|o| o.canonical() == g.canonical())
            .expect("same group");
        assert_eq!(g.tools_before, original.tools_before, "{g:?}");
    }
    assert!(rb.travel < ra.travel);
}

#[test]
fn g92_sees_the_position_the_input_had() {
    let a = figures(&[
        &[(30.0, 0.0), (31.0, 0.0)],
        &[(1.0, 0.0), (2.0, 0.0)],
        &[(20.0, 0.0), (21.0, 0.0)],
    ]);
    let src = a.replace(
        "M5\nM2\n",
        "G92 X0 Y0\nG0 X5 Y5\nG0 Z0.1\nG1 Z-0.1 F20\nG1 X6\nG0 Z1\nM2\n",
    );
    let (input, output, _, _) = order_gcode(&src, "");
    let (ra, rb) = (read_gcode(&input), read_gcode(&output));
    assert_same_groups(&ra, &rb, "g92");
    assert_eq!(ra.before_g92, rb.before_g92);
    assert!(rb.travel < ra.travel);
}

#[test]
fn comments_inside_a_group_travel_with_it() {
    let src = "G21 G90\nG0 Z1\nG0 X0 Y0\nM3\n\
               G0 X40 Y0\nG1 Z-0.1 F20\nG1 X41 F70\n(inside far)\nG1 X42\nG0 Z1\n\
               (before near)\nG0 X1 Y0\nG1 Z-0.1 F20\nG1 X2 F70\n(inside near)\nG1 X3\nG0 Z1\nM5\nM2\n";
    let (input, output, _, _) = order_gcode(src, "");
    let (ra, rb) = (read_gcode(&input), read_gcode(&output));
    assert_same_groups(&ra, &rb, "comments");
    assert_eq!(rb.groups[0].comments, vec!["(inside near)"]);
    assert_eq!(rb.groups[1].comments, vec!["(inside far)"]);
    // The comment between the groups stays in front of the group it preceded.
    let near = output.find("(before near)").expect("kept");
    let plunge_near = output.find("G1 Z-0.1").expect("plunge");
    assert!(near < plunge_near, "{output}");
}

#[test]
fn reverse_false_cuts_every_path_forwards() {
    let src = figures(&[
        &[(10.0, 0.0), (0.0, 0.0)],
        &[(20.0, 1.0), (11.0, 1.0)],
        &[(30.0, 2.0), (21.0, 2.0)],
    ]);
    let (input, output, _, diags) = order_gcode(&src, "reverse = false");
    let (ra, rb) = (read_gcode(&input), read_gcode(&output));
    for g in &rb.groups {
        assert!(ra.groups.iter().any(|o| o.cuts == g.cuts), "{g:?} reversed");
    }
    assert!(note(&diags).ends_with("0 reversed"), "{}", note(&diags));
    // With reversal the zig-zag is cut as a meander: shorter.
    let (_, output2, _, _) = order_gcode(&src, "");
    assert!(read_gcode(&output2).travel < rb.travel.max(ra.travel));
}

#[test]
fn input_order_is_kept_when_it_is_not_longer() {
    let src = figures(&[
        &[(1.0, 0.0), (2.0, 0.0)],
        &[(3.0, 0.0), (4.0, 0.0)],
        &[(5.0, 0.0), (6.0, 0.0)],
    ]);
    let (input, output, _, diags) = order_gcode(&src, "");
    assert_eq!(input, output);
    assert!(
        note(&diags).contains("1 kept as written"),
        "{}",
        note(&diags)
    );
}

#[test]
fn bad_options_are_rejected() {
    for bad in ["cut_z = nan", "max_groups = 1", "bogus = 1"] {
        let table: toml::Table = toml::from_str(bad).expect("toml");
        assert!(
            passes::build("order-paths", &table, &Context::default()).is_err(),
            "{bad}"
        );
    }
}

#[test]
fn a_barrier_inside_a_group_keeps_it_last_and_warns() {
    // M8 (coolant) while cutting: the group around it cannot move.
    let src = "G21 G90\nG0 Z1\nG0 X0 Y0\nM3\n\
               G0 X40 Y0\nG1 Z-0.1 F20\nG1 X41 F70\nG0 Z1\n\
               G0 X1 Y0\nG1 Z-0.1 F20\nG1 X2 F70\nG0 Z1\n\
               G0 X20 Y0\nG1 Z-0.1 F20\nG1 X21 F70\nM8\nG1 X22\nG0 Z1\n\
               G0 X3 Y0\nG1 Z-0.1 F20\nG1 X4 F70\nG0 Z1\nM5\nM2\n";
    let (input, output, _, diags) = order_gcode(src, "");
    let (ra, rb) = (read_gcode(&input), read_gcode(&output));
    assert_same_groups(&ra, &rb, "interrupted");
    assert_eq!(
        rb.groups[2].cuts, ra.groups[2].cuts,
        "the interrupted group is third"
    );
    assert!(rb.travel <= ra.travel);
    let rendered: Vec<String> = diags.iter().map(|d| d.render("m8.ngc", false)).collect();
    insta::assert_snapshot!(
        "interrupted",
        format!("{}\n--- output ---\n{output}", rendered.join("\n"))
    );
}

#[test]
fn snapshot_printrun_pcb_milling_before_after() {
    // ../shared/corpus/gcode/printrun_pcb_milling_comment.gcode (kliment/Printrun
    // testfiles/PCB-milling-and-(comment).gcode): five letters; "p" is cut backwards.
    let src = read(&corpus("gcode", "printrun_pcb_milling_comment.gcode"));
    let (input, output, _, diags) = order_gcode(&src, "");
    let (ra, rb) = (read_gcode(&input), read_gcode(&output));
    assert_same_groups(&ra, &rb, "printrun");
    assert!(rb.travel < ra.travel);
    insta::assert_snapshot!(
        "printrun_pcb_milling",
        format!(
            "--- before ---\n{input}--- after ---\n{output}--- note ---\n{}\n",
            note(&diags)
        )
    );
}

#[test]
fn large_board_of_three_thousand_groups() {
    // 3000 short lines and holes scattered with a fixed seed: bounded work, the same
    // groups, shorter travel.
    let mut rng = Rng(42);
    let mut s = String::from("G21 G90\nG0 Z1\nG0 X0 Y0\nM3\n");
    for k in 0..3000 {
        let x = rng.below(200_000) as f64 / 1000.0;
        let y = rng.below(150_000) as f64 / 1000.0;
        s.push_str(&format!("G0 X{x} Y{y}\nG1 Z-0.1 F20\n"));
        if k % 3 != 0 {
            s.push_str(&format!("G1 X{} Y{} F70\n", x + 1.0, y + 0.5));
        }
        s.push_str("G0 Z1\n");
    }
    s.push_str("M5\nM2\n");
    let t = std::time::Instant::now();
    let (input, output, _, diags) = order_gcode(&s, "");
    eprintln!("3000 groups: {:?}; {}", t.elapsed(), note(&diags));
    let (ra, rb) = (read_gcode(&input), read_gcode(&output));
    assert_same_groups(&ra, &rb, "large");
    assert!(
        rb.travel < 0.3 * ra.travel,
        "{} -> {}",
        ra.travel,
        rb.travel
    );
}

// ---------------------------------------------------------------------------------------
// Property: random groups
// ---------------------------------------------------------------------------------------

/// A random group: a hole, an open polyline, a closed polyline or a half-circle arc, on a
/// 0.5 mm grid (so equal X and equal points happen).
fn group_strategy() -> impl Strategy<Value = String> {
    let pt = (0u32..40, 0u32..40).prop_map(|(x, y)| (f64::from(x) * 0.5, f64::from(y) * 0.5));
    (0u8..4, pt.clone(), prop::collection::vec(pt, 1..5), 1u32..4).prop_map(
        |(kind, start, rest, r)| {
            let (x, y) = start;
            let mut s = format!("G0 X{x} Y{y}\nG0 Z0.5\nG1 Z-0.1 F50\n");
            match kind {
                0 => {}
                1 | 2 => {
                    for (px, py) in &rest {
                        s.push_str(&format!("G1 X{px} Y{py} F300\n"));
                    }
                    if kind == 2 {
                        s.push_str(&format!("G1 X{x} Y{y} F200\n"));
                    }
                }
                _ => {
                    let r = f64::from(r);
                    s.push_str(&format!("G2 X{} Y{y} I{r} J0 F300\n", x + 2.0 * r));
                }
            }
            s.push_str("G0 Z5\n");
            s
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn random_groups_are_a_permutation_and_travel_never_grows(
        groups in prop::collection::vec(group_strategy(), 1..30),
        two_opt in any::<bool>(),
        reverse in any::<bool>(),
    ) {
        let src = format!("G21 G90\nG0 Z5\nG0 X3 Y7\nM3\n{}M5\nG0 X0 Y0\nM2\n", groups.concat());
        let options = format!("two_opt = {two_opt}\nreverse = {reverse}");
        let (input, output, _, _) = order_gcode(&src, &options);
        let (a, b) = (read_gcode(&input), read_gcode(&output));
        let mut ka: Vec<Vec<Cut>> = a.groups.iter().map(Group::canonical).collect();
        let mut kb: Vec<Vec<Cut>> = b.groups.iter().map(Group::canonical).collect();
        ka.sort();
        kb.sort();
        prop_assert_eq!(ka, kb);
        prop_assert!(b.travel <= a.travel + 1e-6, "{} > {}", b.travel, a.travel);
        if !reverse {
            for g in &b.groups {
                prop_assert!(a.groups.iter().any(|o| o.cuts == g.cuts), "reversed: {:?}", g);
            }
        }
    }
}
