//! Floods of repeated diagnostics (issue 21, item 6): every code's diagnostics beyond the
//! first few (`--max-repeats`, default 5) are summed up in one message at the end with the
//! true count, their lines and the worst case, on standard error in human and JSON form;
//! the exit code and the error count still count every one; and a block that gives
//! millions of errors does not store them (the summary's count is exact).
//!
//! Each run goes through the `ncpost` binary and reads what it printed.

use std::process::{Command, Output};

/// `ncpost check --preset PRESET --message-format json EXTRA INPUT`: the JSON messages
/// on standard error, one a line, after asserting the exit code.
fn check_json(preset: &str, extra: &[&str], input: &str, ext: &str, code: i32) -> String {
    let mut args = vec!["check", "--preset", preset, "--message-format", "json"];
    args.extend_from_slice(extra);
    let out = ncpost(&args, input, ext);
    assert_eq!(out.status.code(), Some(code));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn ncpost(args: &[&str], input: &str, ext: &str) -> Output {
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join(format!("in.{ext}"));
    std::fs::write(&path, input).expect("write input");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_ncpost"));
    cmd.args(args).arg(&path);
    cmd.output().expect("runs ncpost")
}

/// One orientation the trunnion cannot reach (the tool pointing up from under the table,
/// 60° past B's -35° limit), repeated `n` times after a reachable start, with a feed.
fn unreachable_cl(n: usize) -> String {
    let mut s = String::from("FEDRAT/1000\nGOTO/0,0,50,0,0,1\n");
    for i in 0..n {
        s.push_str(&format!("GOTO/{},0,10,0,0,-1\n", i % 50));
    }
    s
}

/// The number after `word` in `text` (`19995` of "19995 more").
fn number_before(text: &str, word: &str) -> u64 {
    let at = text
        .find(word)
        .unwrap_or_else(|| panic!("`{word}` in {text}"));
    let digits: String = text[..at]
        .trim_end()
        .chars()
        .rev()
        .take_while(char::is_ascii_digit)
        .collect();
    digits
        .chars()
        .rev()
        .collect::<String>()
        .parse()
        .expect("a count")
}

#[test]
fn twenty_thousand_unreachable_orientations_give_a_few_lines_and_the_true_count() {
    let out = ncpost(
        &["check", "--preset", "trunnion-bc"],
        &unreachable_cl(20_000),
        "cl",
    );
    assert_eq!(out.status.code(), Some(1), "an error is still an error");
    let err = String::from_utf8_lossy(&out.stderr);
    let lines = err.lines().count();
    assert!(lines < 60, "{lines} lines on stderr:\n{err}");
    // Five in full, then one summary with the rest, their lines and the worst of them.
    assert_eq!(err.matches("is out of reach of the").count(), 6, "{err}");
    let flat = err
        .split_whitespace()
        .filter(|w| *w != "|")
        .collect::<Vec<_>>()
        .join(" ");
    assert_eq!(
        number_before(&flat, "more `ik::unreachable` errors"),
        19_995
    );
    assert!(flat.contains("(20000 in all, the first 5 above)"), "{flat}");
    // The first block of the loop is line 3 of the file; the hidden ones start at line 8.
    assert!(
        flat.contains("lines 8, 9, 10, … (8..20002 in all)"),
        "{flat}"
    );
    assert!(flat.contains("the worst of them:"), "{flat}");
    assert!(flat.contains("60.000 deg from the nearest"), "{flat}");
    // The error count is every error, not the ones shown.
    assert!(
        err.trim_end().ends_with("20000 errors, 0 warnings"),
        "{err}"
    );
}

#[test]
fn json_messages_are_capped_too_and_the_summary_carries_the_count() {
    let err = check_json("trunnion-bc", &[], &unreachable_cl(2_000), "cl", 1);
    let messages: Vec<serde_json::Value> = err
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON object a line"))
        .collect();
    assert_eq!(messages.len(), 6, "{err}");
    assert!(messages[..5].iter().all(|m| m["repeats"].is_null()));
    let summary = &messages[5];
    assert_eq!(summary["code"], "ik::unreachable");
    assert_eq!(summary["severity"], "error");
    assert_eq!(summary["repeats"]["count"], 1_995);
    assert_eq!(summary["repeats"]["first_line"], 8);
    assert_eq!(summary["repeats"]["last_line"], 2_002);
    assert_eq!(summary["repeats"]["lines"], serde_json::json!([8, 9, 10]));
}

#[test]
fn max_repeats_sets_how_many_are_shown_and_zero_shows_all() {
    let input = unreachable_cl(30);
    let shown = |extra: &[&str]| {
        check_json("trunnion-bc", extra, &input, "cl", 1)
            .lines()
            .count()
    };
    assert_eq!(shown(&["--max-repeats", "2"]), 3);
    assert_eq!(shown(&["--max-repeats", "0"]), 30);
}

/// One arc of a polar printer far outside the arm's reach, cut into chords each out of
/// reach: the errors of that one block are counted, not stored, and the summary counts
/// every chord (the same count the full list gives).
#[test]
fn one_block_with_thousands_of_errors_is_summed_up_with_the_exact_count() {
    let input = "G0 X10 Y0\nG2 X10 Y0 I100000 J0 F1000\n";
    let run = |extra: &[&str]| check_json("polar-printer", extra, input, "nc", 1);
    let all = run(&["--max-repeats", "0"]);
    let reach_all = all
        .lines()
        .filter(|l| l.contains("polar-ik::reach"))
        .count() as u64;
    assert!(reach_all > 1000, "{reach_all} chords out of reach");
    let capped = run(&[]);
    assert!(capped.lines().count() < 12, "{capped}");
    let summary: serde_json::Value = capped
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .find(|m| m["code"] == "polar-ik::reach" && !m["repeats"].is_null())
        .expect("a summary of the reach errors");
    assert_eq!(summary["repeats"]["count"].as_u64(), Some(reach_all - 5));
    assert_eq!(summary["repeats"]["first_line"], 2);
    assert_eq!(summary["repeats"]["last_line"], 2);
    let message = summary["message"].as_str().expect("message");
    assert!(message.contains("on line 2;"), "{message}");
    // The reach errors carry how far past the arm's range they are: the worst is the
    // chord end farthest out, near r = 100010 + 100000 mm on this circle about X100010.
    let worst = &summary["repeats"]["worst"];
    let r: f64 = worst["message"]
        .as_str()
        .and_then(|m| m.strip_prefix("r = "))
        .and_then(|m| m.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("the worst message names r");
    assert!((r - 200_010.0).abs() < 1.0, "{worst}");
    assert!((worst["magnitude"].as_f64().unwrap_or(0.0) - (r - 150.0)).abs() < 0.1);
    assert!(message.contains("the worst of them: r = "), "{message}");
}
