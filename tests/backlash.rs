//! The `backlash` pass, checked against a physical model written here: a table that
//! lags the motor by the slack (when the motor reverses, the table stands until the
//! slack `b` is crossed; at the first motion after the position became known the slack
//! is already taken up in that motion's direction, the pass's default `start`).
//!
//! 1. Geometry: the pass's output driven through the model puts the table on every
//!    programmed vertex and on the midpoint of every programmed move within 1e-9 mm, the
//!    table stands still during every take-up, and a take-up moves only the reversing
//!    axes by exactly their slack; the uncompensated input through the same model misses
//!    by the slack. On a corpus file without arcs
//!    (`../shared/corpus/gcode/pcb2gcode_d1minigsr_front.ngc`), on one with arcs after
//!    `linearize-arcs` (`pcb2gcode_multivibrator_tiles_milldrill.ngc`), and on random
//!    programs (proptest: rapids, feeds, zero components, homing).
//! 2. Counts: take-up moves per axis = direction reversals per axis, counted here from
//!    the input, and the note reports the same numbers.
//! 3. G92 end to end: the printed text, read back by the frontend, is the pass's output in
//!    the controller's frame (declared values carry the offset).
//! 4. Exact cases by hand (the seed's 0.16 mm), feeds of take-ups (own F, `feed`, G93,
//!    rapids), `start = "positive"`, tiny components, homing reset, arcs (error), bad
//!    options (snapshot), a before/after snapshot with the pcb-mill preset.

mod common;

use std::path::Path;

use ncpost::back::gcode;
use ncpost::diag::Diagnostic;
use ncpost::front::gcode::{Options as GOptions, parse_str};
use ncpost::ir::{Axis, Block, BlockKind, FeedMode, Joints, Motion, MotionKind, Target};
use ncpost::passes::{self, Context};
use ncpost::pipeline::Pipeline;
use ncpost::preset::Preset;
use ncpost::valid::Verifier;
use proptest::prelude::*;

const XYZ: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

// ---------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------

fn parse(src: &str) -> Vec<Block> {
    let p = parse_str(src, &GOptions::default()).expect("parses");
    assert!(
        !p.diagnostics.iter().any(|d| d.is_error()),
        "{:?}",
        p.diagnostics
    );
    p.blocks
}

/// Runs `blocks` through the passes given as `name:k=v` specs.
fn run(blocks: Vec<Block>, specs: &[&str]) -> (Vec<Block>, Vec<Diagnostic>) {
    common::run_passes(blocks, specs)
}

fn corpus(name: &str) -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/gcode")
        .join(name);
    std::fs::read_to_string(p).expect("corpus file")
}

fn motion(b: &Block) -> Option<(&Motion, &Joints)> {
    match &b.kind {
        BlockKind::Motion(m) => match &m.target {
            Target::Joints(j) => Some((m, j)),
            Target::Pose(_) => None,
        },
        _ => None,
    }
}

/// Axes whose position is unknown after a block that is not an ordinary move.
fn clobbers(b: &Block) -> ncpost::ir::AxisSet {
    match &b.kind {
        BlockKind::Command(c) => c.clobbers,
        BlockKind::Verbatim(v) => v.clobbers,
        BlockKind::Motion(m) if m.machine_frame => m.written,
        _ => ncpost::ir::AxisSet::EMPTY,
    }
}

/// One axis of the physical model: motor `m`, table `t`; the gap `m - t` stays in
/// `[lo, lo + b]`, and the table moves only when the motor pushes it at an edge.
#[derive(Debug, Clone, Copy)]
struct Slack {
    b: f64,
    motor: Option<f64>,
    table: f64,
    /// Lower edge of the gap; `None` until the first motion after the position became
    /// known (then the slack is at the edge that motion pushes).
    lo: Option<f64>,
}

impl Slack {
    fn new(b: f64) -> Slack {
        Slack {
            b,
            motor: None,
            table: 0.0,
            lo: None,
        }
    }

    /// The table if the motor went (monotonically) from where it is to `m`.
    fn table_at(&self, m: f64) -> (f64, Option<f64>) {
        let Some(m0) = self.motor else {
            // Positioned from an unknown place: the controller's number is the table's.
            return (m, None);
        };
        let lo = match self.lo {
            Some(lo) => Some(lo),
            None if m > m0 => Some(m0 - self.table - self.b),
            None if m < m0 => Some(m0 - self.table),
            None => None,
        };
        let t = match lo {
            Some(lo) => self.table.clamp(m - lo - self.b, m - lo),
            None => self.table,
        };
        (t, lo)
    }

    fn go(&mut self, m: f64) {
        let (t, lo) = self.table_at(m);
        self.table = t;
        self.lo = lo;
        self.motor = Some(m);
    }

    fn forget(&mut self) {
        self.motor = None;
        self.lo = None;
    }
}

/// The model machine for X, Y, Z.
#[derive(Debug, Clone)]
struct Model {
    axes: [Slack; 3],
}

impl Model {
    fn new(b: [f64; 3]) -> Model {
        Model {
            axes: b.map(Slack::new),
        }
    }

    /// Table positions (X, Y, Z; `None` where unknown).
    fn table(&self) -> [Option<f64>; 3] {
        self.axes.map(|s| s.motor.map(|_| s.table))
    }

    /// Table positions if the motor went to `j` (not applied).
    fn table_if(&self, j: &Joints) -> [Option<f64>; 3] {
        let mut t = [None; 3];
        for (i, a) in XYZ.iter().enumerate() {
            t[i] = j.get(*a).map(|m| self.axes[i].table_at(m).0);
        }
        t
    }

    fn block(&mut self, b: &Block) {
        let gone = clobbers(b);
        for (i, a) in XYZ.iter().enumerate() {
            if gone.contains(*a) {
                self.axes[i].forget();
            }
        }
        if let Some((m, j)) = motion(b)
            && !m.machine_frame
        {
            for (i, a) in XYZ.iter().enumerate() {
                match j.get(*a) {
                    Some(v) => self.axes[i].go(v),
                    None => self.axes[i].forget(),
                }
            }
        }
    }
}

fn lerp(a: &Joints, b: &Joints, s: f64) -> Joints {
    let mut j = *b;
    for ax in b.known.iter() {
        if let Some(va) = a.get(ax) {
            j.values[ax.index()] = va + (b.values[ax.index()] - va) * s;
        }
    }
    j
}

/// What the geometry check measured.
#[derive(Debug, Default)]
struct Check {
    vertices: usize,
    take_ups: [usize; 3],
    worst: f64,
    /// Largest miss of the uncompensated input, per axis.
    miss: [f64; 3],
}

/// Drives `output` through the model with slack `b` and compares the table with the
/// programmed `input`: vertices, midpoints, take-ups. Output blocks are paired with the
/// input block of the same span (the pass keeps spans; a take-up comes first).
fn check(input: &[Block], output: &[Block], b: [f64; 3]) -> Check {
    let mut model = Model::new(b);
    let mut c = Check::default();
    let mut k = 0;
    let mut prog = Joints::default();
    for inb in input {
        let start = k;
        while k < output.len() && output[k].span == inb.span {
            k += 1;
        }
        let group = &output[start..k];
        let Some((m_in, to_in)) = motion(inb).filter(|(m, _)| !m.machine_frame) else {
            match (&inb.kind, group) {
                // A G92 declares the motor's position: only the declared values change.
                (BlockKind::Offset(o), [out]) => {
                    let BlockKind::Offset(p) = &out.kind else {
                        panic!("G92 changed kind")
                    };
                    assert_eq!((o.code, o.offsets), (p.code, p.offsets));
                }
                _ => assert_eq!(group, std::slice::from_ref(inb), "non-motion changed"),
            }
            model.block(inb);
            prog.forget(clobbers(inb));
            continue;
        };
        assert!(
            group.len() == 1 || group.len() == 2,
            "line {}: {} blocks",
            inb.span.line,
            group.len()
        );
        if group.len() == 2 {
            // The take-up: only reversing axes, by exactly their slack; the table stands.
            let (tm, tj) = motion(&group[0]).expect("take-up is a move");
            assert!(group[0].comments.is_empty());
            let before_motor = model.axes.map(|s| s.motor);
            let before = model.table();
            model.block(&group[0]);
            let still = model.table().iter().zip(before).all(|(a, b)| match (a, b) {
                (Some(a), Some(b)) => (a - b).abs() < 1e-12,
                (a, b) => *a == b,
            });
            assert!(
                still,
                "line {}: the table moved in the take-up",
                inb.span.line
            );
            let mut moved = 0;
            for (i, a) in XYZ.iter().enumerate() {
                let d = tj.get(*a).zip(before_motor[i]).map(|(x, y)| x - y);
                match d {
                    Some(d) if d != 0.0 => {
                        assert!((d.abs() - b[i]).abs() < 1e-12, "take-up {d} on {a:?}");
                        assert!(tm.written.contains(*a));
                        c.take_ups[i] += 1;
                        moved += 1;
                    }
                    _ => {}
                }
            }
            assert!(moved > 0, "line {}: empty take-up", inb.span.line);
            assert_eq!(
                matches!(tm.kind, MotionKind::Rapid),
                matches!(m_in.kind, MotionKind::Rapid)
            );
        }
        let last = group.last().expect("a move stays a move");
        assert_eq!(last.comments, inb.comments);
        let (m_out, to_out) = motion(last).expect("move");
        assert_eq!(m_out.kind, m_in.kind);
        // Midpoint of the programmed move.
        let mid_prog = lerp(&prog, to_in, 0.5);
        let mut from_motor = Joints::default();
        for (i, a) in XYZ.iter().enumerate() {
            if let Some(m) = model.axes[i].motor {
                from_motor.set(*a, m);
            }
        }
        let mid_table = model.table_if(&lerp(&from_motor, to_out, 0.5));
        model.block(last);
        let table = model.table();
        for (i, a) in XYZ.iter().enumerate() {
            // Other axes pass through untouched.
            assert_eq!(to_out.known, to_in.known);
            if let Some(p) = to_in.get(*a) {
                let t = table[i].expect("known");
                c.worst = c.worst.max((t - p).abs());
                if prog.get(*a).is_some()
                    && let (Some(mp), Some(mt)) = (mid_prog.get(*a), mid_table[i])
                {
                    c.worst = c.worst.max((mt - mp).abs());
                }
            }
        }
        for a in to_in.known.iter().filter(|a| !XYZ.contains(a)) {
            assert_eq!(to_out.get(a), to_in.get(a));
        }
        c.vertices += 1;
        prog = *to_in;
    }
    assert_eq!(k, output.len(), "output left over");
    c
}

/// Largest distance of the table from the programmed vertices when the input itself
/// drives the model, per axis.
fn uncompensated_miss(input: &[Block], b: [f64; 3]) -> [f64; 3] {
    let mut model = Model::new(b);
    let mut worst = [0.0f64; 3];
    for blk in input {
        model.block(blk);
        if let Some((m, j)) = motion(blk)
            && !m.machine_frame
        {
            let t = model.table();
            for (i, a) in XYZ.iter().enumerate() {
                if let (Some(p), Some(t)) = (j.get(*a), t[i]) {
                    worst[i] = worst[i].max((t - p).abs());
                }
            }
        }
    }
    worst
}

/// Direction reversals per axis of the input, counted from its positions: components of
/// more than 1e-6 mm from a known position; homing forgets.
fn reversals(input: &[Block]) -> [usize; 3] {
    let mut n = [0; 3];
    let mut pos: [Option<f64>; 3] = [None; 3];
    let mut dir = [0i8; 3];
    for b in input {
        let gone = clobbers(b);
        for (i, a) in XYZ.iter().enumerate() {
            if gone.contains(*a) {
                pos[i] = None;
                dir[i] = 0;
            }
        }
        let Some((m, j)) = motion(b) else { continue };
        if m.machine_frame {
            continue;
        }
        for (i, a) in XYZ.iter().enumerate() {
            let q = j.get(*a);
            if let (Some(p), Some(q)) = (pos[i], q) {
                let d = q - p;
                if d.abs() > 1e-6 {
                    let s = if d > 0.0 { 1 } else { -1 };
                    if dir[i] != 0 && dir[i] != s {
                        n[i] += 1;
                    }
                    dir[i] = s;
                }
            }
            if q.is_none() {
                dir[i] = 0;
            }
            pos[i] = q;
        }
    }
    n
}

/// The per-axis numbers of the `backlash::take-ups` note.
fn noted(diags: &[Diagnostic]) -> Vec<(char, usize)> {
    let notes: Vec<&Diagnostic> = diags
        .iter()
        .filter(|d| d.code == "backlash::take-ups")
        .collect();
    assert_eq!(notes.len(), 1, "{diags:?}");
    let text = notes[0]
        .message
        .split_once("inserted: ")
        .expect("numbers")
        .1;
    text.split(", ")
        .map(|part| {
            let mut w = part.split(' ');
            let letter = w.next().and_then(|l| l.chars().next()).expect("axis");
            let n = w.next().and_then(|n| n.parse().ok()).expect("count");
            (letter, n)
        })
        .collect()
}

fn spec(b: [f64; 3]) -> String {
    format!("backlash:x={},y={},z={}", b[0], b[1], b[2])
}

fn verify(blocks: &[Block]) {
    let mut v = Verifier;
    for b in blocks {
        v.check(b).expect("IR invariants");
    }
}

/// The whole geometric and counting check of one input.
fn full_check(input: &[Block], b: [f64; 3]) -> Check {
    // linearize-arcs gives its chords the arc's span: one span per block here, so the
    // check can pair output with input by span.
    let input: Vec<Block> = input
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let mut b = b.clone();
            b.span.line = i as u32 + 1;
            b.span.offset = i as u64;
            b
        })
        .collect();
    let input = &input[..];
    let (output, diags) = run(input.to_vec(), &[&spec(b)]);
    assert!(!diags.iter().any(|d| d.is_error()), "{diags:?}");
    verify(&output);
    let mut c = check(input, &output, b);
    assert!(c.worst < 1e-9, "compensated table misses by {}", c.worst);
    let rev = reversals(input);
    for i in 0..3 {
        let want = if b[i] > 0.0 { rev[i] } else { 0 };
        assert_eq!(c.take_ups[i], want, "axis {i}: take-ups = reversals");
    }
    let expect: Vec<(char, usize)> = XYZ
        .iter()
        .zip(rev)
        .zip(b)
        .filter(|(_, b)| *b > 0.0)
        .map(|((a, n), _)| (a.letter(), n))
        .collect();
    assert_eq!(noted(&diags), expect);
    // Without the pass the same machine misses on every reversing axis, by at most the
    // slack (exactly the slack once a reversed run is longer than it).
    let miss = uncompensated_miss(input, b);
    for i in 0..3 {
        if rev[i] > 0 && b[i] > 0.0 {
            assert!(
                miss[i] > 1e-9 && miss[i] <= b[i] + 1e-9,
                "axis {i}: {} vs {}",
                miss[i],
                b[i]
            );
        }
    }
    c.miss = miss;
    c
}

// ---------------------------------------------------------------------------------------
// 1. Geometry on the corpus
// ---------------------------------------------------------------------------------------

#[test]
fn corpus_pcb2gcode_d1minigsr_front() {
    let input = parse(&corpus("pcb2gcode_d1minigsr_front.ngc"));
    let c = full_check(&input, [0.16, 0.16, 0.02]);
    assert!(c.vertices > 10_000, "{c:?}");
    assert!(c.take_ups.iter().all(|&n| n > 10), "{c:?}");
    assert!(
        c.miss
            .iter()
            .zip([0.16, 0.16, 0.02])
            .all(|(m, b)| (m - b).abs() < 1e-9),
        "{c:?}"
    );
}

#[test]
fn corpus_pcb2gcode_multivibrator_tiles_milldrill_after_linearize_arcs() {
    let src = corpus("pcb2gcode_multivibrator_tiles_milldrill.ngc");
    let (input, d) = run(parse(&src), &["linearize-arcs"]);
    assert!(!d.iter().any(|d| d.is_error()), "{d:?}");
    let c = full_check(&input, [0.02, 0.02, 0.0]);
    assert!(c.take_ups[0] > 100 && c.take_ups[1] > 100, "{c:?}");
    assert_eq!(c.take_ups[2], 0);
    assert!(
        (c.miss[0] - 0.02).abs() < 1e-9 && (c.miss[1] - 0.02).abs() < 1e-9,
        "{c:?}"
    );
    // The arcs themselves are an error without linearize-arcs.
    let (_, d) = run(parse(&src), &["backlash:x=0.02,y=0.02"]);
    assert!(d.iter().any(|d| d.code == "backlash::arc"));
}

// ---------------------------------------------------------------------------------------
// 1. Geometry on random programs
// ---------------------------------------------------------------------------------------

#[derive(Debug, Clone)]
enum Step {
    /// G0/G1 with X, Y, Z in hundredths of a mm (`None`: the word is left out).
    Move(bool, [Option<i32>; 3]),
    /// G28: homing, every axis unknown afterwards.
    Home,
}

fn steps() -> impl Strategy<Value = Vec<Step>> {
    let coord = prop_oneof![Just(None), (-2000i32..2000).prop_map(Some)];
    let step = prop_oneof![
        10 => (any::<bool>(), [coord.clone(), coord.clone(), coord]).prop_map(|(r, c)| Step::Move(r, c)),
        1 => Just(Step::Home),
    ];
    prop::collection::vec(step, 1..60)
}

fn text(steps: &[Step]) -> String {
    let mut s = String::from("G21 G90\nG0 X0 Y0 Z0\n");
    for st in steps {
        match st {
            Step::Move(rapid, c) => {
                s.push_str(if *rapid { "G0" } else { "G1 F300" });
                for (l, v) in ['X', 'Y', 'Z'].iter().zip(c) {
                    if let Some(v) = v {
                        s.push_str(&format!(" {l}{:.2}", f64::from(*v) / 100.0));
                    }
                }
                s.push('\n');
            }
            Step::Home => s.push_str("G28\n"),
        }
    }
    s
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn random_programs_put_the_table_on_the_program(
        prog in steps(),
        b in (0.001f64..0.5, 0.001f64..0.5, prop_oneof![Just(0.0), 0.001f64..0.5]),
    ) {
        let input = parse(&text(&prog));
        full_check(&input, [b.0, b.1, b.2]);
    }
}

// ---------------------------------------------------------------------------------------
// 2. Exact cases
// ---------------------------------------------------------------------------------------

fn targets(blocks: &[Block]) -> Vec<(MotionKind, [f64; 3], Option<f64>, FeedMode)> {
    blocks
        .iter()
        .filter_map(motion)
        .map(|(m, j)| {
            (
                m.kind,
                [j.values[0], j.values[1], j.values[2]],
                m.feed.rate,
                m.feed.mode,
            )
        })
        .collect()
}

fn close(a: [f64; 3], b: [f64; 3]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
}

#[test]
fn seed_slack_by_hand() {
    // X out and back with the seed's 0.16 mm, then Y, then X out again.
    let input = parse("G0 X0 Y0 Z0\nG1 X10 F70\nG1 X0\nG1 Y5\nG1 X10\n");
    let (out, _) = run(input, &["backlash:x=0.16,y=0.16"]);
    let t = targets(&out);
    let want = [
        [0.0, 0.0, 0.0],
        [10.0, 0.0, 0.0],
        [9.84, 0.0, 0.0],  // take-up: X back by the slack, table stands at 10
        [-0.16, 0.0, 0.0], // the return move carries the offset
        [-0.16, 5.0, 0.0], // Y's first move: no take-up
        [0.0, 5.0, 0.0],   // take-up: X forward again, offset back to 0
        [10.0, 5.0, 0.0],
    ];
    assert_eq!(t.len(), want.len(), "{t:?}");
    for (got, want) in t.iter().zip(want) {
        assert!(close(got.1, want), "{got:?} vs {want:?}");
    }
    // Take-ups of feed moves run at the move's own F.
    assert_eq!(t[2].2, Some(70.0));
    assert_eq!(t[2].0, MotionKind::Linear);
}

#[test]
fn take_up_feeds() {
    let src = "G0 X0 Y0\nG1 X10 F300\nG1 X0\nG0 X5\nG0 X1\n";
    // `feed` sets the take-up of feed moves; rapids take up at rapid.
    let (out, _) = run(parse(src), &["backlash:x=0.02,feed=1000"]);
    let t = targets(&out);
    assert_eq!(t.len(), 8, "{t:?}");
    assert_eq!((t[2].0, t[2].2), (MotionKind::Linear, Some(1000.0)));
    assert!(close(t[2].1, [9.98, 0.0, 0.0]));
    assert_eq!(t[3].2, Some(300.0), "the move keeps its F");
    assert!(close(t[3].1, [-0.02, 0.0, 0.0]));
    assert_eq!(t[4].0, MotionKind::Rapid);
    assert!(close(t[4].1, [0.0, 0.0, 0.0]), "{t:?}");
    assert!(close(t[5].1, [5.0, 0.0, 0.0]));
    assert_eq!(t[6].0, MotionKind::Rapid);
    assert!(close(t[6].1, [4.98, 0.0, 0.0]));
    assert!(close(t[7].1, [0.98, 0.0, 0.0]));
    // G93: the take-up has the move's speed: F scaled by length / slack.
    let (out, _) = run(
        parse("G0 X0 Y0\nG93\nG1 X10 F6\nG1 X0 F6\n"),
        &["backlash:x=0.02"],
    );
    let t = targets(&out);
    assert_eq!(t[2].3, FeedMode::InverseTime);
    let f = t[2].2.expect("F");
    assert!((f - 6.0 * 10.0 / 0.02).abs() < 1e-9, "{f}");
}

#[test]
fn start_positive_takes_up_a_first_negative_move() {
    let src = "G0 X5 Y5\nG1 X0 F100\nG1 Y9\n";
    let (out, diags) = run(parse(src), &["backlash:x=0.16,y=0.16,start=\"positive\""]);
    let t = targets(&out);
    assert_eq!(t.len(), 4, "{t:?}");
    assert!(close(t[1].1, [4.84, 5.0, 0.0]));
    assert!(close(t[2].1, [-0.16, 5.0, 0.0]));
    assert!(
        close(t[3].1, [-0.16, 9.0, 0.0]),
        "Y goes positive: no take-up"
    );
    assert_eq!(noted(&diags), vec![('X', 1), ('Y', 0)]);
    // start = "negative": the Y move is the one taken up.
    let (out, _) = run(parse(src), &["backlash:x=0.16,y=0.16,start=negative"]);
    let t = targets(&out);
    assert_eq!(t.len(), 4, "{t:?}");
    assert!(close(t[2].1, [0.0, 5.16, 0.0]));
}

#[test]
fn tiny_components_neither_reverse_nor_set_a_direction() {
    // 0.1 + 0.2 != 0.3 in binary: the "return" of 5.5e-17 mm is noise, not a reversal.
    let input =
        parse("G0 X0 Y0\nG1 X0.3 F100\nG1 X0.1\nG1 X0.30000000000000004\nG1 X0.3 Y1\nG1 X0.5\n");
    let (out, diags) = run(input.clone(), &["backlash:x=0.02"]);
    assert_eq!(noted(&diags), vec![('X', 2)]);
    let c = check(&input, &out, [0.02, 0.0, 0.0]);
    assert_eq!(c.take_ups, [2, 0, 0]);
}

#[test]
fn homing_forgets_the_direction_and_the_offset() {
    let input = parse("G0 X0 Y0\nG1 X10 F100\nG1 X0\nG28\nG0 X3 Y3\nG1 X1\nG1 X2\n");
    let (out, diags) = run(input.clone(), &["backlash:x=0.1"]);
    let t = targets(&out);
    // After G28 the positioning move carries no offset and the next move sets the direction.
    let after: Vec<[f64; 3]> = t.iter().skip(4).map(|t| t.1).collect();
    assert_eq!(after.len(), 4, "{t:?}");
    assert!(close(after[0], [3.0, 3.0, 0.0]));
    assert!(close(after[1], [1.0, 3.0, 0.0]));
    assert!(close(after[2], [1.1, 3.0, 0.0]));
    assert!(close(after[3], [2.1, 3.0, 0.0]));
    assert_eq!(noted(&diags), vec![('X', 2)]);
    let c = check(&input, &out, [0.1, 0.0, 0.0]);
    assert!(c.worst < 1e-9);
}

/// Printed text read back by the frontend: its IR is the controller's frame.
#[test]
fn g92_declares_the_motor_position() {
    let src = "G0 X0 Y0 Z0\nG1 X10 F100\nG1 X4\nG92 X0 Y0\nG1 X-2\nG1 X3 Y2\nG92.1\nG1 X1\n";
    let input = parse(src);
    let (out, diags) = run(input.clone(), &["backlash:x=0.16,y=0.02"]);
    assert!(!diags.iter().any(|d| d.is_error()), "{diags:?}");
    let c = check(&input, &out, [0.16, 0.02, 0.0]);
    assert!(c.worst < 1e-9);
    let printed = gcode::write_string(&out, &Default::default()).expect("prints");
    assert!(printed.contains("G92 X-0.16 Y0"), "{printed}");
    let back = parse(&printed);
    let a: Vec<[f64; 3]> = targets(&out).iter().map(|t| t.1).collect();
    let b: Vec<[f64; 3]> = targets(&back).iter().map(|t| t.1).collect();
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert!(
            x.iter().zip(y).all(|(p, q)| (p - q).abs() < 1e-9),
            "{x:?} vs {y:?}\n{printed}"
        );
    }
}

#[test]
fn arcs_are_an_error_unless_they_touch_no_compensated_axis() {
    let src = "G0 X0 Y0 Z0\nG1 X10 F100\nG2 X20 Y0 I5 J0\n";
    let (_, diags) = run(parse(src), &["backlash:x=0.16,y=0.16"]);
    let errors: Vec<&Diagnostic> = diags.iter().filter(|d| d.is_error()).collect();
    assert_eq!(errors.len(), 1);
    insta::assert_snapshot!("arc_error", errors[0].render("arc.nc", false));
    // Only Z compensated, XY arc without helix: passes on.
    let (out, diags) = run(parse(src), &["backlash:z=0.02"]);
    assert!(!diags.iter().any(|d| d.is_error()), "{diags:?}");
    assert_eq!(out, parse(src));
}

#[test]
fn bad_options() {
    let mut report = String::new();
    for s in [
        "backlash",
        "backlash:x=-0.02",
        "backlash:x=nan",
        "backlash:y=inf",
        "backlash:x=0.02,feed=0",
        "backlash:x=0.02,start=sideways",
        "backlash:x=0.02,a=0.1",
    ] {
        let (name, table) = passes::parse_spec(s).expect("spec");
        let e = passes::build(&name, &table, &Context::default())
            .err()
            .expect("an error");
        report.push_str(&format!("{s}\n  {}\n", e.message));
    }
    insta::assert_snapshot!("bad_options", report);
}

#[test]
fn snapshot_pcb_mill_before_after() {
    // A 4 x 3 mm isolation outline, cut twice around, then a drill position back left.
    let src = "G0 Z1\nG0 X1 Y1\nG1 Z-0.06 F20\nG1 X5 F70\nG1 Y4\nG1 X1\nG1 Y1\nG1 X5 (second pass)\nG0 Z1\nG0 X0.5 Y0.5\nM30\n";
    let compile = |with: bool| {
        let preset = Preset::builtin("pcb-mill").expect("preset");
        let mut b = Pipeline::builder().preset(preset);
        if with {
            let (_, t) = passes::parse_spec("backlash:x=0.16,y=0.16,z=0.02").expect("spec");
            b = b.pass("backlash", t);
        }
        let mut p = b.build().expect("builds");
        let mut out = Vec::new();
        let mut diags = Vec::new();
        p.run_gcode(src.as_bytes(), &mut out, &mut |d| diags.push(d))
            .expect("runs");
        let notes: Vec<String> = diags
            .iter()
            .map(|d| d.render("outline.nc", false))
            .collect();
        (String::from_utf8(out).expect("utf-8"), notes.join("\n"))
    };
    let (before, _) = compile(false);
    let (after, notes) = compile(true);
    insta::assert_snapshot!(
        "pcb_mill",
        format!(
            "--- before\n{before}--- after backlash:x=0.16,y=0.16,z=0.02\n{after}--- diagnostics\n{notes}\n"
        )
    );
}
