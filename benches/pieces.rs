//! Pieces against the fewest that hold the tolerance: how many blocks `densify` (the four
//! 5-axis presets) and `polar-ik` (the polar-printer preset) emit on generated programs,
//! against a greedy reference that cuts every programmed move into the longest pieces
//! whose joint-linear path stays within the tolerance, each piece's end found by bisection
//! and each piece checked by dense sampling of the deviation the pass promises (tip from
//! the programmed line and tool axis from its great-circle arc for 5-axis; the XY path
//! from the programmed line or arc for polar).
//!
//! Every controller plans a limited number of blocks per second: a piece more than needed
//! is a stutter on the machine. The counts do not depend on the build, so the command
//! runs a debug build:
//!
//! ```text
//! bash scripts/bench-pieces.sh        # cargo bench --profile dev --bench pieces
//! ```
//!
//! It prints, per program, the pieces emitted, the greedy minimum and their ratio, and the
//! worst deviation of the emitted pieces as printed (joints rounded to the preset's
//! decimals) in units of the tolerance. The near-centre speed cap of `polar-ik` is turned
//! off here: its splits are for the feed, not for the tolerance.

use nalgebra::{Point3, Unit, Vector2, Vector3};
use ncpost::front::gcode::{Options as GcodeOptions, parse_str};
use ncpost::ir::{Axis, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind, Span};
use ncpost::ir::{Target, Tracker};
use ncpost::machine::{Machine, ToolPose};
use ncpost::num::print::{Decimals, printed};
use ncpost::passes::Context;
use ncpost::preset::{Emit, Preset};

#[path = "../tests/common/mod.rs"]
mod common;
use common::geometry::{
    angle_to_arc, arc_distance, distance_to_segment, segment_distance_xy, unit,
};

/// Samples per piece when checking a piece of the reference or of the pass's output.
const SAMPLES: usize = 96;

/// A small deterministic generator (xorshift64*), so every run measures the same programs.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

fn decimals(p: &Preset) -> Decimals {
    match p.emit {
        Emit::Rrf => p.rrf.decimals,
        Emit::Grbl => p.grbl.decimals,
        _ => p.gcode.decimals,
    }
}

/// The preset's options of pass `name`, with `extra` on top.
fn options_of(p: &Preset, name: &str, extra: &str) -> toml::Table {
    let mut t = p
        .passes
        .iter()
        .find(|s| s.name == name)
        .map(|s| s.options.clone())
        .unwrap_or_default();
    let more: toml::Table = toml::from_str(extra).expect("options");
    t.extend(more);
    t
}

/// Runs pass `name` over `blocks` one block at a time (as a stream).
fn run_pass(name: &str, options: &toml::Table, ctx: &Context, blocks: Vec<Block>) -> Vec<Block> {
    common::run_pass(name, options, ctx, blocks).0
}

/// The motion targets of `out`, grouped by the line of the input block they came from.
fn pieces_by_line(out: &[Block]) -> Vec<(u32, Joints)> {
    out.iter()
        .filter_map(|b| match &b.kind {
            BlockKind::Motion(m) => m.target.joints().map(|j| (b.span.line, *j)),
            _ => None,
        })
        .collect()
}

/// `j` as the controller reads it: every known axis rounded to its printed decimals.
fn as_printed(d: &Decimals, j: &Joints) -> Joints {
    let mut p = *j;
    for a in j.known.iter() {
        if let Some(v) = printed(j.values[a.index()], d.axis(a)) {
            p.values[a.index()] = v;
        }
    }
    p
}

/// Greedy longest pieces over `[0, 1]`: from each piece's start the end is the largest
/// parameter (bisection to 1e-5 of the move) for which `fits(start, end)` holds.
fn greedy(fits: &mut dyn FnMut(f64, f64) -> bool) -> usize {
    let mut cur = 0.0;
    let mut count = 0;
    while cur < 1.0 {
        count += 1;
        if fits(cur, 1.0) {
            break;
        }
        let (mut lo, mut hi) = (cur, 1.0);
        while hi - lo > 1e-5 {
            let mid = 0.5 * (lo + hi);
            if fits(cur, mid) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        cur = if lo > cur { lo } else { hi };
    }
    count
}

/// One row of the table.
#[derive(Default, Clone, Copy)]
struct Tally {
    moves: usize,
    emitted: usize,
    greedy: usize,
    /// Worst deviation of the printed output, in tolerances.
    worst: f64,
}

impl Tally {
    fn add(&mut self, o: Tally) {
        self.moves += o.moves;
        self.emitted += o.emitted;
        self.greedy += o.greedy;
        self.worst = self.worst.max(o.worst);
    }
    fn row(&self, name: &str) {
        println!(
            "| {name} | {} | {} | {} | {:.3} | {:.3} |",
            self.moves,
            self.emitted,
            self.greedy,
            self.emitted as f64 / self.greedy as f64,
            self.worst
        );
    }
}

// ---------------------------------------------------------------- 5-axis

struct FiveAxis {
    m: Machine,
    axes: [Axis; 2],
    tip_tol: f64,
    axis_tol: f64,
}

fn near_turn(v: f64, target: f64) -> f64 {
    v + 360.0 * ((target - v) / 360.0).round()
}

impl FiveAxis {
    fn joints(&self, xyz: [f64; 3], angles: [f64; 2]) -> Joints {
        let mut j = Joints::default();
        j.set(Axis::X, xyz[0]);
        j.set(Axis::Y, xyz[1]);
        j.set(Axis::Z, xyz[2]);
        j.set(self.axes[0], angles[0]);
        j.set(self.axes[1], angles[1]);
        j
    }

    fn five(&self, j: &Joints) -> ([f64; 3], [f64; 2]) {
        let v = |a: Axis| j.get(a).expect("known axis");
        (
            [v(Axis::X), v(Axis::Y), v(Axis::Z)],
            [v(self.axes[0]), v(self.axes[1])],
        )
    }

    /// The orientation for `axis` nearest the angles `near` (what `ik` and
    /// `unwrap-rotary` choose along a path).
    fn angles(&self, axis: Unit<Vector3<f64>>, near: [f64; 2]) -> [f64; 2] {
        let sols = self.m.inverse(axis);
        if sols.iter().any(|s| s.free.is_some()) {
            let k = self.m.singular_rotary(axis);
            let a = self.m.hold(axis, k, near[k]).angles;
            return [near_turn(a[0], near[0]), near_turn(a[1], near[1])];
        }
        let mut best: Option<([f64; 2], f64)> = None;
        for s in &sols {
            let a = [
                near_turn(s.angles[0], near[0]),
                near_turn(s.angles[1], near[1]),
            ];
            let cost = (a[0] - near[0]).powi(2) + (a[1] - near[1]).powi(2);
            if best.is_none_or(|(_, c)| cost < c) {
                best = Some((a, cost));
            }
        }
        best.map_or(near, |(a, _)| a)
    }

    /// The worst deviation (in tolerances) of the joint-linear path from `a` to `b` from
    /// the programmed segment `cl0`–`cl1`.
    fn deviation(&self, a: &Joints, b: &Joints, cl0: &ToolPose, cl1: &ToolPose) -> f64 {
        let (x0, r0) = self.five(a);
        let (x1, r1) = self.five(b);
        let mut worst: f64 = 0.0;
        for k in 0..=SAMPLES {
            let s = k as f64 / SAMPLES as f64;
            let l = |p: f64, q: f64| p + (q - p) * s;
            let pose = self.m.forward(
                &[l(x0[0], x1[0]), l(x0[1], x1[1]), l(x0[2], x1[2])],
                [l(r0[0], r1[0]), l(r0[1], r1[1])],
            );
            let tip = distance_to_segment(&pose.tip, &cl0.tip, &cl1.tip) / self.tip_tol;
            let axis = angle_to_arc(&pose.axis, &cl0.axis, &cl1.axis) / self.axis_tol;
            worst = worst.max(tip).max(axis);
        }
        worst
    }

    /// The node at `s` of the programmed move from `a` to `b`.
    fn node(&self, a: &Joints, b: &Joints, cl0: &ToolPose, cl1: &ToolPose, s: f64) -> Joints {
        let tip = cl0.tip + (cl1.tip - cl0.tip) * s;
        let axis = Unit::new_normalize(cl0.axis.slerp(&cl1.axis, s).into_inner());
        let (_, ra) = self.five(a);
        let (_, rb) = self.five(b);
        let near = [ra[0] + (rb[0] - ra[0]) * s, ra[1] + (rb[1] - ra[1]) * s];
        let angles = self.angles(axis, near);
        self.joints(self.m.linear(&tip, angles), angles)
    }

    /// The greedy minimum of pieces for the move from `a` to `b`.
    fn greedy(&self, a: &Joints, b: &Joints) -> usize {
        let cl0 = self.pose(a);
        let cl1 = self.pose(b);
        greedy(&mut |s0, s1| {
            let n0 = if s0 == 0.0 {
                *a
            } else {
                self.node(a, b, &cl0, &cl1, s0)
            };
            let n1 = if s1 == 1.0 {
                *b
            } else {
                self.node(a, b, &cl0, &cl1, s1)
            };
            self.deviation(&n0, &n1, &cl0, &cl1) <= 1.0
        })
    }

    fn pose(&self, j: &Joints) -> ToolPose {
        let (xyz, angles) = self.five(j);
        self.m.forward(&xyz, angles)
    }
}

/// The CL poses of the generated 5-axis programs: `sweep` (the tip along lines while the
/// tool axis sweeps between tilts and azimuths) and `c-arcs` (the tip on circles about
/// the table's axis, tilted outwards, so the C table turns along arcs).
/// Each pose comes with whether the move to it is a rapid (between sweeps and circles).
fn five_axis_programs(rng: &mut Rng) -> Vec<(&'static str, Vec<(ToolPose, bool)>)> {
    let mut sweep = Vec::new();
    for _ in 0..12 {
        let p0 = Point3::new(
            rng.range(-40.0, 40.0),
            rng.range(-40.0, 40.0),
            rng.range(0.0, 30.0),
        );
        let p1 = Point3::new(
            rng.range(-40.0, 40.0),
            rng.range(-40.0, 40.0),
            rng.range(0.0, 30.0),
        );
        let (t0, t1) = (rng.range(10.0, 50.0), rng.range(10.0, 50.0));
        // Azimuth changes that keep each step on its branch (as `ik` would).
        let a0 = rng.range(-180.0, 180.0);
        let a1 = a0 + rng.range(-90.0, 90.0);
        let steps = 12;
        for k in 0..=steps {
            let s = k as f64 / steps as f64;
            let pose = ToolPose {
                tip: p0 + (p1 - p0) * s,
                axis: unit(t0 + (t1 - t0) * s, a0 + (a1 - a0) * s),
            };
            sweep.push((pose, k == 0));
        }
    }
    let mut arcs = Vec::new();
    for _ in 0..8 {
        let r = rng.range(10.0, 60.0);
        let z = rng.range(0.0, 30.0);
        let tilt = rng.range(10.0, 45.0);
        let step = rng.range(4.0, 15.0);
        let start = rng.range(-180.0, 180.0);
        for k in 0..=24 {
            let phi = start + step * k as f64;
            let (s, c) = phi.to_radians().sin_cos();
            let pose = ToolPose {
                tip: Point3::new(r * c, r * s, z),
                axis: unit(tilt, phi),
            };
            arcs.push((pose, k == 0));
        }
    }
    vec![("sweep", sweep), ("c-arcs", arcs)]
}

/// One 5-axis program on one preset.
fn five_axis_run(name: &str, poses: &[(ToolPose, bool)]) -> Tally {
    let preset = Preset::builtin(name).expect("preset");
    let m = preset.machine.clone().expect("machine");
    let options = options_of(&preset, "densify", "");
    let opts: ncpost::passes::densify::Options =
        options.clone().try_into().expect("densify options");
    let fa = FiveAxis {
        axes: m.rotary_axes(),
        m,
        tip_tol: opts.tip_tolerance,
        axis_tol: opts.axis_tolerance,
    };
    let d = decimals(&preset);
    // The joints `ik` and `unwrap-rotary` give: each pose nearest the one before.
    let mut angles = fa.angles(poses[0].0.axis, [0.0, 0.0]);
    let mut blocks = Vec::new();
    let mut targets = Vec::new();
    for (i, (p, rapid)) in poses.iter().enumerate() {
        angles = fa.angles(p.axis, angles);
        let j = fa.joints(fa.m.linear(&p.tip, angles), angles);
        targets.push(j);
        let kind = if *rapid {
            MotionKind::Rapid
        } else {
            MotionKind::Linear
        };
        blocks.push(motion(i as u32 + 1, kind, j));
    }
    let ctx = Context {
        machine: Some(&fa.m),
        decimals: Some(d),
        ..Context::default()
    };
    let out = pieces_by_line(&run_pass("densify", &options, &ctx, blocks));
    let mut t = Tally::default();
    for w in 1..targets.len() {
        let (a, b) = (&targets[w - 1], &targets[w]);
        let (cl0, cl1) = (fa.pose(a), fa.pose(b));
        let line = w as u32 + 1;
        if poses[w].1 {
            continue;
        }
        // A move whose tool axis passes the singular orientation changes branch on the
        // way (the `ik` pass's business, with its own warnings): not a densify figure.
        let near_singular = (0..=32).any(|k| {
            let v =
                Unit::new_normalize(cl0.axis.slerp(&cl1.axis, f64::from(k) / 32.0).into_inner());
            fa.m.singularity_distance(v) < 5.0
        });
        if near_singular {
            continue;
        }
        let mut prev = as_printed(&d, a);
        for (_, j) in out.iter().filter(|(l, _)| *l == line) {
            let j = as_printed(&d, j);
            let dev = fa.deviation(&prev, &j, &cl0, &cl1);
            if dev > 2.0 && std::env::var("PIECES_DEBUG").is_ok() {
                eprintln!(
                    "{name} line {line}: {dev}\n a {:?}\n prev {:?}\n j {:?}\n b {:?}",
                    fa.five(a),
                    fa.five(&prev),
                    fa.five(&j),
                    fa.five(b)
                );
            }
            t.worst = t.worst.max(dev);
            prev = j;
            t.emitted += 1;
        }
        t.greedy += fa.greedy(a, b);
        t.moves += 1;
    }
    t
}

fn motion(line: u32, kind: MotionKind, target: Joints) -> Block {
    Block::new(
        Span {
            offset: u64::from(line) * 10,
            len: 5,
            line,
        },
        BlockKind::Motion(Motion {
            kind,
            target: Target::Joints(target),
            feed: Feed {
                mode: FeedMode::PerMinute,
                rate: Some(1000.0),
            },
            written: target.known,
            machine_frame: false,
            extra: String::new(),
        }),
    )
}

// ---------------------------------------------------------------- polar

/// A programmed XY path of the polar bench: a line or a circular arc.
enum Path {
    Line(Vector2<f64>, Vector2<f64>),
    Arc {
        centre: Vector2<f64>,
        radius: f64,
        start: f64,
        sweep: f64,
    },
}

impl Path {
    fn at(&self, s: f64) -> Vector2<f64> {
        match self {
            Path::Line(a, b) => a + (b - a) * s,
            Path::Arc {
                centre,
                radius,
                start,
                sweep,
            } => on_circle(centre, *radius, start + sweep * s),
        }
    }

    /// Distance from `p` to the path.
    fn distance(&self, p: &Vector2<f64>) -> f64 {
        match self {
            Path::Line(a, b) => segment_distance_xy(p, a, b),
            Path::Arc {
                centre,
                radius,
                start,
                sweep,
            } => arc_distance(p, centre, *radius, *start, *sweep),
        }
    }
}

/// The point at `angle` (radians) of the circle about `centre` of `radius`.
fn on_circle(centre: &Vector2<f64>, radius: f64, angle: f64) -> Vector2<f64> {
    centre + Vector2::new(angle.cos(), angle.sin()) * radius
}

/// The signed angle from `a` to `b`.
fn angle_between(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    (a.x * b.y - a.y * b.x).atan2(a.dot(b))
}

/// The worst distance (in tolerances) of the joint-linear path between polar points
/// `(r, θ rad)` `a` and `b` from `path`.
fn polar_deviation(path: &Path, a: (f64, f64), b: (f64, f64), tol: f64) -> f64 {
    let mut worst: f64 = 0.0;
    for k in 0..=SAMPLES {
        let s = k as f64 / SAMPLES as f64;
        let r = a.0 + (b.0 - a.0) * s;
        let th = a.1 + (b.1 - a.1) * s;
        let p = Vector2::new(r * th.cos(), r * th.sin());
        worst = worst.max(path.distance(&p) / tol);
    }
    worst
}

/// The greedy minimum of polar pieces for `path`, the arm at θ `theta0` (rad) at its start.
fn polar_greedy(path: &Path, theta0: f64, tol: f64) -> usize {
    // θ along the path, continuous, on a fine grid; between grid points by the angle
    // from the grid point (under 180° on so fine a grid).
    let n = 4096;
    let mut grid = Vec::with_capacity(n + 1);
    let mut th = theta0;
    let mut prev = path.at(0.0);
    for k in 0..=n {
        let p = path.at(k as f64 / n as f64);
        th += angle_between(&prev, &p);
        grid.push(th);
        prev = p;
    }
    let node = |s: f64| {
        let k = ((s * n as f64).floor() as usize).min(n);
        let g = path.at(k as f64 / n as f64);
        let p = path.at(s);
        (p.norm(), grid[k] + angle_between(&g, &p))
    };
    greedy(&mut |s0, s1| polar_deviation(path, node(s0), node(s1), tol) <= 1.0)
}

/// The generated polar program: lines and arcs across the centre region, as G-code, with
/// the path of every cutting move by its line number.
fn polar_program(rng: &mut Rng, arcs: bool) -> (String, Vec<(u32, Path)>) {
    let mut text = String::from("G21\nG90\n");
    let mut paths = Vec::new();
    let mut line = 2u32;
    let mut push = |text: &mut String, s: String| {
        text.push_str(&s);
        text.push('\n');
        line += 1;
        line
    };
    for _ in 0..60 {
        let start = Vector2::new(rng.range(-50.0, 50.0), rng.range(-50.0, 50.0));
        push(&mut text, format!("G0 X{:.4} Y{:.4}", start.x, start.y));
        if arcs {
            let radius = rng.range(3.0, 40.0);
            let dir = rng.range(-3.2, 3.2);
            let centre = start + Vector2::new(dir.cos(), dir.sin()) * radius;
            let begin = (start - centre).y.atan2((start - centre).x);
            let sweep = rng.range(0.5, 5.0) * if rng.next() < 0.5 { -1.0 } else { 1.0 };
            let end = on_circle(&centre, radius, begin + sweep);
            let g = if sweep < 0.0 { 2 } else { 3 };
            let (i, j) = ((centre - start).x, (centre - start).y);
            let l = push(
                &mut text,
                format!("G{g} X{:.6} Y{:.6} I{i:.6} J{j:.6} F1200", end.x, end.y),
            );
            paths.push((
                l,
                Path::Arc {
                    centre,
                    radius,
                    start: begin,
                    sweep,
                },
            ));
        } else {
            let mut a = start;
            for _ in 0..4 {
                let b = Vector2::new(rng.range(-50.0, 50.0), rng.range(-50.0, 50.0));
                let l = push(&mut text, format!("G1 X{:.6} Y{:.6} F1200", b.x, b.y));
                paths.push((l, Path::Line(a, b)));
                a = b;
            }
        }
    }
    (text, paths)
}

fn polar_run(rng: &mut Rng, arcs: bool) -> Tally {
    let preset = Preset::builtin("polar-printer").expect("preset");
    let polar = preset.polar.clone().expect("[polar]");
    let options = options_of(&preset, "polar-ik", "speed_cap = false");
    let tol = options
        .get("tolerance")
        .and_then(|v| v.as_float())
        .unwrap_or(0.01);
    let d = decimals(&preset);
    let (text, paths) = polar_program(rng, arcs);
    let input = parse_str(&text, &GcodeOptions::default())
        .expect("parse")
        .blocks;
    let ctx = Context {
        polar: Some(&polar),
        decimals: Some(d),
        ..Context::default()
    };
    let out = run_pass("polar-ik", &options, &ctx, input);
    let (r_ax, t_ax) = (polar.r_axis, polar.theta_axis);
    let mut t = Tally::default();
    // The printed r and θ before each block, followed through the output.
    let mut track = Tracker::default();
    let mut i = 0;
    for (line, path) in &paths {
        while i < out.len() && out[i].span.line < *line {
            track.update(&out[i]);
            i += 1;
        }
        let start = as_printed(&d, track.pos());
        let mut prev = (
            start.get(r_ax).unwrap_or(0.0),
            start.get(t_ax).unwrap_or(0.0).to_radians(),
        );
        let theta0 = prev.1;
        while i < out.len() && out[i].span.line == *line {
            track.update(&out[i]);
            let j = as_printed(&d, track.pos());
            let next = (
                j.get(r_ax).unwrap_or(0.0),
                j.get(t_ax).unwrap_or(0.0).to_radians(),
            );
            t.worst = t.worst.max(polar_deviation(path, prev, next, tol));
            prev = next;
            t.emitted += 1;
            i += 1;
        }
        t.greedy += polar_greedy(path, theta0, tol);
        t.moves += 1;
    }
    t
}

fn main() {
    println!(
        "Pieces emitted against the greedy minimum (dense sampling, {SAMPLES} samples a piece)"
    );
    println!();
    println!(
        "| program | moves | emitted | greedy minimum | ratio | worst printed deviation / tolerance |"
    );
    println!("|---|---|---|---|---|---|");
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let programs = five_axis_programs(&mut rng);
    let mut all5 = Tally::default();
    for name in ["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"] {
        if std::env::var("PIECES_ONLY").is_ok_and(|o| o != name) {
            continue;
        }
        for (kind, poses) in &programs {
            let t = five_axis_run(name, poses);
            t.row(&format!("{name} {kind}"));
            all5.add(t);
        }
    }
    all5.row("**5-axis, all**");
    let mut allp = Tally::default();
    for (kind, arcs) in [("lines", false), ("arcs", true)] {
        let t = polar_run(&mut rng, arcs);
        t.row(&format!("polar-printer {kind}"));
        allp.add(t);
    }
    allp.row("**polar, all**");
}
