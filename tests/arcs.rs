//! `linearize-arcs` geometry, checked independently of `motion::arc`: property tests over
//! random G2/G3 arcs written as G-code text (G17, G18, G19; I J K and R forms, negative R
//! for more than half a turn; full circles; helical; `P` turns) that every output vertex
//! lies on the arc (radius and helix axis interpolated by the swept angle) within 1e-9 mm,
//! that the chords sweep exactly the arc's angle, that every chord's sagitta is within the
//! tolerance, and that the last vertex is the target exactly; the same checks and
//! snapshots on corpus files with arcs (printrun_arc_test.gcode,
//! gcodenom_g2_box_nibble_clockwise.gcode, linuxcnc_arcspiral.ngc).

use std::f64::consts::{PI, TAU};

use ncpost::diag::Diagnostic;
use ncpost::front::gcode::{Options, parse_str};
use ncpost::ir::{Arc, Axis, Block, BlockKind, Joints, MotionKind, Plane, Target};
use ncpost::passes::{self, Context, Output};
use proptest::prelude::*;

/// The frontend's blocks and the blocks after `linearize-arcs` with `tolerance`.
fn linearize(src: &str, tolerance: f64) -> (Vec<Block>, Vec<Block>, Vec<Diagnostic>) {
    // printrun_arc_test.gcode has an arc off its circle: kept as written (the opt-in), so
    // that its chords can be checked.
    let options = Options {
        strict_arcs: false,
        ..Options::default()
    };
    let program = parse_str(src, &options).expect("parses");
    let mut table = toml::Table::new();
    table.insert("tolerance".into(), toml::Value::Float(tolerance));
    let mut pass = passes::build("linearize-arcs", &table, &Context::default()).expect("builds");
    let mut out = Vec::new();
    let mut diags = program.diagnostics.clone();
    for b in program.blocks.iter().cloned() {
        pass.run(&mut vec![b], &mut Output::new(&mut out, &mut diags));
    }
    pass.finish(&mut Output::new(&mut out, &mut diags));
    (program.blocks, out, diags)
}

/// One arc of the input with the chords that replaced it.
struct Cut {
    from: Joints,
    to: Joints,
    arc: Arc,
    line: u32,
    vertices: Vec<Joints>,
}

/// Pairs every input arc with its output chords (same span, in order); arcs from an
/// unknown start (passed on as arcs) are left out.
fn cuts(input: &[Block], output: &[Block]) -> Vec<Cut> {
    let mut pos = Joints::default();
    let mut result = Vec::new();
    let mut k = 0;
    for b in input {
        let BlockKind::Motion(m) = &b.kind else {
            // Commands and text may move the machine to unknown places.
            if let BlockKind::Command(c) = &b.kind {
                pos.forget(c.clobbers);
            }
            if let BlockKind::Verbatim(v) = &b.kind {
                pos.forget(v.clobbers);
            }
            while k < output.len() && output[k].span == b.span {
                k += 1;
            }
            continue;
        };
        let Target::Joints(to) = &m.target else {
            panic!("pose")
        };
        let mut vertices = Vec::new();
        while k < output.len() && output[k].span == b.span {
            if let BlockKind::Motion(o) = &output[k].kind
                && let (MotionKind::Linear, Target::Joints(j)) = (o.kind, &o.target)
            {
                vertices.push(*j);
            }
            k += 1;
        }
        if let MotionKind::Arc(arc) = m.kind {
            let (u, v, _) = arc.plane.axes();
            let known = |j: &Joints| j.get(u).is_some() && j.get(v).is_some();
            if known(&pos) && known(to) {
                result.push(Cut {
                    from: pos,
                    to: *to,
                    arc,
                    line: b.span.line,
                    vertices,
                });
            }
        }
        pos = *to;
    }
    result
}

/// What the checks measured for one arc.
#[derive(Debug, Default)]
struct Measured {
    /// Largest distance of a vertex from the arc (radius and helix axis), mm.
    off_arc: f64,
    /// Largest sagitta of a chord, mm.
    sagitta: f64,
    chords: usize,
    /// Swept angle, rad (signed).
    sweep: f64,
}

/// Checks one cut arc; panics with `what` on a failure.
fn check(cut: &Cut, tol: f64, what: &str) -> Measured {
    let (u, v, n) = cut.arc.plane.axes();
    let c = [cut.arc.center[u.index()], cut.arc.center[v.index()]];
    let g = |j: &Joints, a: Axis| j.get(a).unwrap_or_else(|| panic!("{what}: {a:?} unknown"));
    let polar = |j: &Joints| {
        let (du, dv) = (g(j, u) - c[0], g(j, v) - c[1]);
        (du.hypot(dv), dv.atan2(du))
    };
    let (r0, a0) = polar(&cut.from);
    let (r1, a1) = polar(&cut.to);
    // The arc's sweep from its definition: clockwise negative; equal angles a full turn.
    let mut base = if cut.arc.clockwise { a0 - a1 } else { a1 - a0 }.rem_euclid(TAU);
    if base < 1e-12 {
        base = TAU;
    }
    let total = base + TAU * f64::from(cut.arc.extra_turns);
    let sweep = if cut.arc.clockwise { -total } else { total };
    let n0 = cut.from.get(n);
    let n1 = cut.to.get(n);
    assert!(!cut.vertices.is_empty(), "{what}: no chords");
    // The last vertex is the target exactly.
    let last = cut.vertices[cut.vertices.len() - 1];
    for a in Axis::ALL {
        assert_eq!(
            last.get(a).map(f64::to_bits),
            cut.to.get(a).map(f64::to_bits),
            "{what}: end point {a:?}"
        );
    }
    let mut m = Measured {
        chords: cut.vertices.len(),
        sweep,
        ..Measured::default()
    };
    let mut prev = (r0, 0.0f64, a0);
    for (i, p) in cut.vertices.iter().enumerate() {
        let (r, a) = polar(p);
        // Unwrap in the arc's direction: every chord turns by at most half a turn.
        let step = if cut.arc.clockwise {
            -(prev.2 - a).rem_euclid(TAU)
        } else {
            (a - prev.2).rem_euclid(TAU)
        };
        let swept = prev.1 + step;
        assert!(
            step.abs() <= PI + 1e-9,
            "{what}: chord {i} turns {step} rad"
        );
        let t = swept / sweep;
        assert!(
            (-1e-9..=1.0 + 1e-9).contains(&t),
            "{what}: vertex {i} at t = {t}"
        );
        // On the arc: radius linear in the angle (a circle when r0 = r1), helix axis too.
        let r_expected = r0 + (r1 - r0) * t;
        let mut off = (r - r_expected).abs();
        if let (Some(a0n), Some(b0n)) = (n0, n1) {
            let z = g(p, n);
            off = off.max((z - (a0n + (b0n - a0n) * t)).abs());
        }
        m.off_arc = m.off_arc.max(off);
        assert!(off <= 1e-9, "{what}: vertex {i} is {off} mm off the arc");
        // Sagitta of the chord from the previous vertex: the circle of the larger
        // radius over the chord's angle, and the arc's point at the middle angle.
        let s = r.max(prev.0) * (1.0 - (step.abs() / 2.0).cos());
        let tm = (prev.1 + swept) / 2.0 / sweep;
        let am = a0 + (prev.1 + swept) / 2.0;
        let rm = r0 + (r1 - r0) * tm;
        let mid = [c[0] + rm * am.cos(), c[1] + rm * am.sin()];
        let pa = [c[0] + prev.0 * prev.2.cos(), c[1] + prev.0 * prev.2.sin()];
        let pb = [g(p, u), g(p, v)];
        let d = dist_to_segment(mid, pa, pb);
        m.sagitta = m.sagitta.max(s).max(d);
        assert!(
            s <= tol * (1.0 + 1e-9) + 1e-12,
            "{what}: chord {i} sagitta {s} > {tol}"
        );
        assert!(
            d <= tol * (1.0 + 1e-6) + 1e-9,
            "{what}: chord {i} midpoint {d} mm from the chord > {tol} (s {s}, step {step}, r {r} r0 {r0} r1 {r1}, a0 {a0} a1 {a1} sweep {sweep} pa {pa:?} pb {pb:?} mid {mid:?})"
        );
        prev = (r, swept, a);
    }
    assert!(
        (prev.1 - sweep).abs() <= 1e-9 * sweep.abs().max(1.0),
        "{what}: the chords sweep {} rad, the arc {sweep}",
        prev.1
    );
    m
}

fn dist_to_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
}

/// A random arc as G-code text.
#[derive(Debug, Clone)]
struct ArcCase {
    plane: Plane,
    clockwise: bool,
    centre: [f64; 2],
    radius: f64,
    start_angle: f64,
    /// In (0, 2π]; 2π is a full circle.
    sweep: f64,
    helix: f64,
    normal_start: f64,
    turns: u32,
    r_form: bool,
    tolerance: f64,
}

fn fmt(v: f64) -> String {
    format!("{v:.6}")
}

impl ArcCase {
    fn gcode(&self) -> String {
        let (u, v, n) = self.plane.axes();
        let p = |angle: f64| {
            [
                self.centre[0] + self.radius * angle.cos(),
                self.centre[1] + self.radius * angle.sin(),
            ]
        };
        let s = p(self.start_angle);
        let dir = if self.clockwise { -1.0 } else { 1.0 };
        let full = self.sweep >= TAU;
        let e = if full {
            s
        } else {
            p(self.start_angle + dir * self.sweep)
        };
        let letter = |a: Axis| a.letter();
        let mut t = format!(
            "G21 G90 {}\nG0 {}{} {}{} {}{}\n",
            self.plane.gcode(),
            letter(u),
            fmt(s[0]),
            letter(v),
            fmt(s[1]),
            letter(n),
            fmt(self.normal_start)
        );
        // Start and end as printed (the frontend reads these numbers).
        let sp = [
            fmt(s[0]).parse::<f64>().unwrap(),
            fmt(s[1]).parse::<f64>().unwrap(),
        ];
        t.push_str(&format!(
            "G{} {}{} {}{} {}{}",
            if self.clockwise { 2 } else { 3 },
            letter(u),
            if full { fmt(sp[0]) } else { fmt(e[0]) },
            letter(v),
            if full { fmt(sp[1]) } else { fmt(e[1]) },
            letter(n),
            fmt(self.normal_start + self.helix)
        ));
        if self.r_form {
            let r = if self.sweep > PI {
                -self.radius
            } else {
                self.radius
            };
            t.push_str(&format!(" R{}", fmt(r)));
        } else {
            let off = |a: Axis| match a {
                Axis::X => 'I',
                Axis::Y => 'J',
                _ => 'K',
            };
            t.push_str(&format!(
                " {}{} {}{}",
                off(u),
                fmt(self.centre[0] - sp[0]),
                off(v),
                fmt(self.centre[1] - sp[1])
            ));
            if self.turns > 0 {
                t.push_str(&format!(" P{}", self.turns + 1));
            }
        }
        t.push_str(" F300\n");
        t
    }
}

fn arc_case() -> impl Strategy<Value = ArcCase> {
    (
        prop_oneof![Just(Plane::XY), Just(Plane::ZX), Just(Plane::YZ)],
        any::<bool>(),
        (-50.0..50.0f64, -50.0..50.0f64),
        -2.0..2.0f64, // log10 radius: 0.01 .. 100 mm
        0.0..TAU,
        prop_oneof![0.05..(PI - 0.05), (PI + 0.05)..(TAU - 0.05), Just(TAU)],
        prop_oneof![Just(0.0), -5.0..5.0f64],
        -10.0..10.0f64,
        0u32..3,
        any::<bool>(),
        prop_oneof![Just(0.002), Just(0.0005), Just(0.01), Just(0.1)],
    )
        .prop_map(
            |(plane, clockwise, c, lr, a0, sweep, helix, n0, turns, r_form, tolerance)| {
                let r_form = r_form && sweep < TAU; // R cannot name a full circle
                ArcCase {
                    plane,
                    clockwise,
                    centre: [c.0, c.1],
                    radius: 10f64.powf(lr),
                    start_angle: a0,
                    sweep,
                    helix,
                    normal_start: n0,
                    turns: if r_form { 0 } else { turns },
                    r_form,
                    tolerance,
                }
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn random_arcs_are_cut_on_the_arc_within_tolerance(case in arc_case()) {
        let src = case.gcode();
        let (input, output, diags) = linearize(&src, case.tolerance);
        prop_assert!(diags.iter().all(|d| !d.is_error()), "{src}\n{diags:?}");
        let cuts = cuts(&input, &output);
        prop_assert_eq!(cuts.len(), 1, "{}", src);
        let cut = &cuts[0];
        let (u, v, _) = cut.arc.plane.axes();
        prop_assert_eq!(cut.arc.plane, case.plane);
        // The frontend's centre: start + IJK, or at distance |R| from both ends.
        if case.r_form {
            let d = |j: &Joints| (j.get(u).unwrap() - cut.arc.center[u.index()])
                .hypot(j.get(v).unwrap() - cut.arc.center[v.index()]);
            let r: f64 = fmt(case.radius).parse().unwrap();
            prop_assert!((d(&cut.from) - r).abs() < 1e-9 * r.max(1.0), "{src}");
            prop_assert!((d(&cut.to) - r).abs() < 1e-9 * r.max(1.0), "{src}");
        }
        let m = check(cut, case.tolerance, &src);
        let expected = case.sweep + TAU * f64::from(case.turns);
        // The sweep read back from the printed numbers is the generated one (to the
        // rounding of six decimals), negative R giving more than half a turn.
        if case.r_form {
            // The centre from R moves with the rounding near half a turn: the branch
            // (short or long way) is what R's sign decides.
            prop_assert_eq!(m.sweep.abs() > PI, case.sweep > PI, "{}", src);
            prop_assert!((m.sweep.abs() - expected).abs() < 0.05, "{src}: sweep {}", m.sweep);
        } else if case.sweep >= TAU {
            prop_assert!((m.sweep.abs() - expected).abs() < 1e-12, "{src}: sweep {}", m.sweep);
        } else {
            let slack = 5e-6 / case.radius;
            prop_assert!((m.sweep.abs() - expected).abs() < slack,
                "{src}: sweep {} expected {expected}", m.sweep);
        }
        prop_assert_eq!(m.sweep < 0.0, case.clockwise);
        // Not wastefully many chords: one fewer would break the half-turn limit or the
        // tolerance for the circle of the larger radius (plus, for the slight spiral the
        // six printed decimals make, the radius change's chord error
        // |k| h² sqrt(4 + h²) / 2, k the radius change per radian).
        let r = cut.vertices.len();
        if r > 1 {
            let d = |j: &Joints| (j.get(u).unwrap() - cut.arc.center[u.index()])
                .hypot(j.get(v).unwrap() - cut.arc.center[v.index()]);
            let rmax = d(&cut.from).max(d(&cut.to));
            let k = (d(&cut.to) - d(&cut.from)).abs() / m.sweep.abs();
            let half = m.sweep.abs() / (2.0 * (r - 1) as f64);
            let h = half.min(PI / 2.0);
            let bound = rmax * (1.0 - h.cos()) + k * h * h * (4.0 + h * h).sqrt() / 2.0;
            prop_assert!(bound > case.tolerance || half > PI / 2.0 - 1e-12,
                "{src}: {r} chords, {} would do", r - 1);
        }
    }
}

fn corpus(name: &str) -> String {
    let path = format!(
        "{}/../shared/corpus/gcode/{name}",
        env!("CARGO_MANIFEST_DIR")
    );
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

#[test]
fn corpus_files_with_arcs() {
    for (name, lines) in [
        ("printrun_arc_test.gcode", 40),
        ("gcodenom_g2_box_nibble_clockwise.gcode", 60),
        ("linuxcnc_arcspiral.ngc", 60),
    ] {
        let mut src = corpus(name);
        if name == "printrun_arc_test.gcode" {
            // `G28` homes a printer to X0 Y0 Z0, which the frontend does not assume (it
            // treats the position as unknown and would pass every arc on as an arc):
            // say so after the homing line.
            src = src.replacen("G28 ; home\n", "G28 ; home\nG0 X0 Y0 Z0\n", 1);
        }
        let tol = 0.002;
        let (input, output, diags) = linearize(&src, tol);
        let cuts = cuts(&input, &output);
        assert!(!cuts.is_empty(), "{name}");
        let mut worst = Measured::default();
        let mut chords = 0;
        for cut in &cuts {
            let m = check(cut, tol, &format!("{name}:{}", cut.line));
            worst.off_arc = worst.off_arc.max(m.off_arc);
            worst.sagitta = worst.sagitta.max(m.sagitta);
            chords += m.chords;
        }
        assert!(worst.off_arc <= 1e-9 && worst.sagitta <= tol * (1.0 + 1e-6));
        let arcs_left = output
            .iter()
            .filter(
                |b| matches!(&b.kind, BlockKind::Motion(m) if matches!(m.kind, MotionKind::Arc(_))),
            )
            .count();
        let text = ncpost::back::gcode::write_string(&output, &Default::default()).expect("prints");
        let head: Vec<&str> = text.lines().take(lines).collect();
        let report = format!(
            "arcs cut: {}\nchords: {chords}\narcs passed on (unknown start): {arcs_left}\nlargest vertex distance from the arc < 1e-9: {}\nlargest chord sagitta <= {tol}: {}\n== diagnostics\n{}\n== first {lines} lines\n{}\n",
            cuts.len(),
            worst.off_arc < 1e-9,
            worst.sagitta <= tol * (1.0 + 1e-6),
            diags
                .iter()
                .map(|d| d.render(name, false))
                .collect::<Vec<_>>()
                .join("\n"),
            head.join("\n")
        );
        insta::assert_snapshot!(format!("corpus_{name}"), report);
    }
}

#[test]
fn quarter_circle_numbers() {
    // G3 from (10, 0) about the origin to (0, 10) at 0.01 mm: r (1 - cos(π/4n)) <= 0.01
    // needs n = 18 chords (π/4n <= acos(0.999) = 0.044725; n = 17 gives 0.01067).
    let (input, output, _) = linearize("G0 X10 Y0 Z0\nG3 X0 Y10 I-10 J0 F100\n", 0.01);
    let cuts = cuts(&input, &output);
    assert_eq!(cuts[0].vertices.len(), 18);
    let s18 = 10.0 * (1.0 - (PI / 4.0 / 18.0).cos());
    let s17 = 10.0 * (1.0 - (PI / 4.0 / 17.0).cos());
    assert!(s18 <= 0.01 && s17 > 0.01);
    let m = check(&cuts[0], 0.01, "quarter");
    assert!((m.sweep - PI / 2.0).abs() < 1e-12);
    // Vertex k at angle kπ/36.
    for (k, p) in cuts[0].vertices.iter().enumerate() {
        let a = (k + 1) as f64 * PI / 36.0;
        assert!((p.get(Axis::X).unwrap() - 10.0 * a.cos()).abs() < 1e-12);
        assert!((p.get(Axis::Y).unwrap() - 10.0 * a.sin()).abs() < 1e-12);
    }
}

#[test]
fn negative_r_takes_the_long_way() {
    // From (10, 0) to (0, 10) with R10: centre (0, 0), a quarter turn; R-10: centre
    // (10, 10), three quarters.
    for (r, centre, sweep) in [
        ("10", [0.0, 0.0], PI / 2.0),
        ("-10", [10.0, 10.0], 1.5 * PI),
    ] {
        let (input, output, _) = linearize(&format!("G0 X10 Y0 Z0\nG3 X0 Y10 R{r} F100\n"), 0.002);
        let cuts = cuts(&input, &output);
        assert!((cuts[0].arc.center[0] - centre[0]).abs() < 1e-12, "R{r}");
        assert!((cuts[0].arc.center[1] - centre[1]).abs() < 1e-12, "R{r}");
        let m = check(&cuts[0], 0.002, "R");
        assert!((m.sweep - sweep).abs() < 1e-12, "R{r}: {}", m.sweep);
    }
}

#[test]
fn full_helical_circle_in_g18() {
    // G18: u = Z, v = X, normal Y. A full circle of radius 5 descending 2 mm.
    let (input, output, _) = linearize("G18\nG0 X0 Y0 Z5\nG2 X0 Y-2 Z5 I0 K-5 F100\n", 0.002);
    let cuts = cuts(&input, &output);
    let m = check(&cuts[0], 0.002, "g18");
    assert!((m.sweep + TAU).abs() < 1e-12);
    // Y halfway down at half the turn.
    let half = &cuts[0].vertices[cuts[0].vertices.len() / 2 - 1];
    let n = cuts[0].vertices.len();
    let t = (n / 2) as f64 / n as f64;
    assert!((half.get(Axis::Y).unwrap() + 2.0 * t).abs() < 1e-12);
}
