//! Issue 21, items 7, 8 and 9a through the `ncpost` binary: `--pass` options with arrays
//! and quoted text (and the syntax in the error for a malformed one), `ncpost stats`
//! bounds that include the bulge of arcs, and the Grbl backend naming only the axes a
//! move actually moves.

use std::process::{Command, Output};

fn ncpost(args: &[&str], input: &str) -> Output {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("in.nc");
    std::fs::write(&path, input).expect("write input");
    Command::new(env!("CARGO_BIN_EXE_ncpost"))
        .args(args)
        .arg(&path)
        .output()
        .expect("runs ncpost")
}

/// The value of word `letter` on `line` (`X10.5` → 10.5).
fn word(line: &str, letter: char) -> Option<f64> {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(letter)?.parse().ok())
}

#[test]
fn an_array_option_sets_the_polar_centre() {
    // The centre itself is r = 0; 10 mm in +X from it is r = 10 at θ = 0.
    let input = "G0 X105 Y53\nG1 X115 Y53 F1000\n";
    let out = ncpost(
        &[
            "run",
            "--preset",
            "polar-printer",
            "--pass",
            "polar-ik:center=[105,53]",
        ],
        input,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let moves: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("G0 ") || l.starts_with("G1 "))
        .collect();
    let r: Vec<f64> = moves.iter().filter_map(|l| word(l, 'X')).collect();
    assert_eq!(r.first().copied(), Some(0.0), "{text}");
    assert_eq!(r.last().copied(), Some(10.0), "{text}");
    // Without the option the centre is the origin: the same start is far from r = 0.
    let plain = ncpost(&["run", "--preset", "polar-printer"], input);
    let plain = String::from_utf8_lossy(&plain.stdout);
    let first = plain
        .lines()
        .find(|l| l.starts_with("G0 "))
        .and_then(|l| word(l, 'X'));
    assert!(first.is_some_and(|x| x > 100.0), "{plain}");
}

#[test]
fn quoted_text_keeps_its_commas_and_a_malformed_spec_shows_the_syntax() {
    let (_, t) = ncpost::passes::parse_spec("x:a=\"b,c\",d=[1, 2],e='f,g'").expect("parses");
    assert_eq!(t["a"].as_str(), Some("b,c"));
    assert_eq!(t["d"].as_array().map(Vec::len), Some(2));
    assert_eq!(t["e"].as_str(), Some("f,g"));
    for bad in ["polar-ik:center", "polar-ik:center=[105,53"] {
        let out = ncpost(
            &["run", "--preset", "polar-printer", "--pass", bad],
            "G0 X1\n",
        );
        assert_eq!(out.status.code(), Some(2), "{bad}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("--pass NAME:key=value,key=[a,b],key=\"text\""),
            "{bad}: {err}"
        );
    }
}

/// The `bounds` row of `ncpost stats` as (X lo, X hi, Y lo, Y hi).
fn xy_bounds(input: &str) -> (f64, f64, f64, f64) {
    let out = ncpost(&["stats"], input);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let row = text
        .lines()
        .find(|l| l.starts_with("bounds"))
        .unwrap_or_else(|| panic!("{text}"));
    let range = |axis: &str| -> (f64, f64) {
        let at = row.find(&format!("{axis} ")).expect("axis") + 2;
        let field = row[at..].split_whitespace().next().expect("range");
        let (lo, hi) = field.split_once("..").expect("lo..hi");
        (lo.parse().expect("lo"), hi.parse().expect("hi"))
    };
    let (x, y) = (range("X"), range("Y"));
    (x.0, x.1, y.0, y.1)
}

#[test]
fn stats_bounds_take_in_the_bulge_of_arcs() {
    // A full circle about (10, 0) from the origin: its whole square.
    assert_eq!(
        xy_bounds("G0 X0 Y0\nG2 X0 Y0 I10 F100\n"),
        (0.0, 20.0, -10.0, 10.0)
    );
    // Clockwise from (0, 0) to (10, 10) about (10, 0): the quarter through the top-left
    // passes no axis extreme; counter-clockwise the same ends sweep 270°, through the
    // bottom and the right.
    assert_eq!(
        xy_bounds("G0 X0 Y0\nG2 X10 Y10 I10 F100\n"),
        (0.0, 10.0, 0.0, 10.0)
    );
    assert_eq!(
        xy_bounds("G0 X0 Y0\nG3 X10 Y10 I10 F100\n"),
        (0.0, 20.0, -10.0, 10.0)
    );
    // In G18 (Z, X) a half circle from X0 Z0 about X5 bulges in Z only.
    let out = ncpost(&["stats"], "G0 X0 Y0 Z0\nG18 G2 X10 Z0 I5 F100\n");
    let text = String::from_utf8_lossy(&out.stdout);
    let row = text
        .lines()
        .find(|l| l.starts_with("bounds"))
        .expect("bounds");
    assert!(row.contains("X 0.000..10.000"), "{row}");
    assert!(row.contains("Y 0.000..0.000"), "{row}");
    assert!(
        row.contains("Z 0.000..5.000") || row.contains("Z -5.000..0.000"),
        "{row}"
    );
}

#[test]
fn grbl_names_only_the_axes_a_move_moves() {
    // A and C are written on line 1 only; line 3 moves A again.
    let input = "G0 A10 C5\nG0 X1 Y1\nG1 X2 Y2 A20 F100\n";
    let out = ncpost(
        &["run", "--emit", "grbl", "--message-format", "json"],
        input,
    );
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    let axis_errors: Vec<(u64, String)> = err
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|m| m["code"] == "grbl::axis")
        .map(|m| {
            let line = m["line"].as_u64().expect("a line");
            (line, m["message"].as_str().expect("message").to_string())
        })
        .collect();
    let moved: Vec<(u64, &str)> = axis_errors
        .iter()
        .map(|(line, m)| (*line, m.rsplit(' ').next().unwrap_or("")))
        .collect();
    // G0 X1 Y1 on line 2 moves no rotary and is printed.
    assert_eq!(moved, vec![(1, "AC"), (3, "A")], "{err}");
}
