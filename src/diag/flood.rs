//! Floods: one diagnostic repeated thousands of times (an unreachable orientation on
//! every block of a 5-axis file, a feed mode the controller lacks on every move).
//!
//! [`Flood`] is the one cap. Per code and severity the first `limit` diagnostics are shown
//! in full; the rest are counted in a [`Tally`] (how many, on which lines, and the worst
//! when they carry a [`Diagnostic::magnitude`]), and one summary per code follows at the
//! end of the run. The pipeline applies it where a pass reports
//! (the passes' output, per batch), so that one block that gives a million warnings
//! is not stored a million times, and where the batches' diagnostics are reported, across
//! the whole run. Both use the same limit, so the first holds back only what the second
//! would hide as well, and the counts stay exact: a hidden diagnostic still counts as an
//! error or a warning of the run.

use std::collections::HashMap;

use super::{Diagnostic, Location, Severity};

/// Diagnostics per code shown in full unless the run says otherwise (`--max-repeats`).
pub const DEFAULT_LIMIT: u64 = 5;

/// Lines of hidden diagnostics a summary names one by one (then their range).
const LINES_NAMED: usize = 3;

/// The diagnostics of one code that were not shown one by one.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Tally {
    /// How many.
    pub count: u64,
    /// The first few of their lines, in input order.
    pub lines: Vec<u32>,
    /// The lowest and the highest of their lines.
    pub line_range: Option<(u32, u32)>,
    /// The one with the largest magnitude, when they carry one.
    pub worst: Option<Worst>,
}

/// The worst of the hidden diagnostics of a code.
#[derive(Debug, Clone, PartialEq)]
pub struct Worst {
    /// Its magnitude (in the diagnostic's own unit).
    pub magnitude: f32,
    /// Its line, if it has one.
    pub line: Option<u32>,
    /// Its message.
    pub message: String,
}

impl Tally {
    /// Counts `d` (all that `d` stands for, when it carries a tally itself).
    pub fn add(&mut self, d: &Diagnostic) {
        if let Some(t) = &d.repeats {
            self.merge(t);
            return;
        }
        self.count += 1;
        let line = d.location.as_ref().map(|l| l.line);
        if let Some(l) = line {
            self.note_lines(&[l], (l, l));
        }
        if let Some(m) = d.magnitude {
            self.note_worst(Worst {
                magnitude: m,
                line,
                message: d.message.clone(),
            });
        }
    }

    /// Adds the counts of `other`, which follows these in the input.
    pub fn merge(&mut self, other: &Tally) {
        self.count += other.count;
        if let Some(range) = other.line_range {
            self.note_lines(&other.lines, range);
        }
        if let Some(w) = &other.worst {
            self.note_worst(w.clone());
        }
    }

    fn note_lines(&mut self, lines: &[u32], (lo, hi): (u32, u32)) {
        for &l in lines {
            // Many from one block (the chords of one arc) name its line once.
            if self.lines.len() < LINES_NAMED && self.lines.last() != Some(&l) {
                self.lines.push(l);
            }
        }
        self.line_range = Some(match self.line_range {
            Some((a, b)) => (a.min(lo), b.max(hi)),
            None => (lo, hi),
        });
    }

    fn note_worst(&mut self, w: Worst) {
        if self
            .worst
            .as_ref()
            .is_none_or(|old| w.magnitude > old.magnitude)
        {
            self.worst = Some(w);
        }
    }

    /// The lines in words: `lines 4, 9, 12, … (4..9050 in all)`, `line 7`.
    fn lines_text(&self) -> String {
        match self.line_range {
            None => "no line".into(),
            Some((lo, hi)) if lo == hi => format!("line {lo}"),
            Some((lo, hi)) => {
                let named: Vec<String> = self.lines.iter().map(u32::to_string).collect();
                if self.lines.len() < LINES_NAMED {
                    // Every line was named: none was left out for room.
                    format!("lines {}", named.join(", "))
                } else {
                    format!("lines {}, … ({lo}..{hi} in all)", named.join(", "))
                }
            }
        }
    }
}

/// The cap on repeated diagnostics (see the module documentation).
///
/// ```
/// use ncpost::diag::{Diagnostic, Flood};
/// let mut flood = Flood::new(2);
/// let shown: Vec<_> = (1..=5)
///     .filter_map(|line| flood.admit(Diagnostic::error("x::y", "bad").at_line(line, "G1", 1, 1)))
///     .collect();
/// assert_eq!(shown.len(), 2);
/// let summary = flood.summaries();
/// assert_eq!(summary[0].repeats.as_ref().unwrap().count, 3);
/// assert!(summary[0].message.contains("lines 3, 4, 5, … (3..5 in all)"));
/// ```
#[derive(Debug, Default)]
pub struct Flood {
    /// Shown in full per code and severity; 0 shows everything.
    limit: u64,
    shown: HashMap<(&'static str, Severity), u64>,
    /// One tally-carrying diagnostic per code and severity, in the order they first
    /// overflowed.
    hidden: Vec<Diagnostic>,
    /// Where [`Flood::push`] keeps the carrier of each code in its vector.
    carriers: HashMap<(&'static str, Severity), usize>,
}

impl Flood {
    /// A cap showing `limit` diagnostics of each code in full (0: all of them).
    pub fn new(limit: u64) -> Self {
        Flood {
            limit,
            ..Flood::default()
        }
    }

    /// Whether `d` is shown in full (counting it if so).
    fn shows(&mut self, d: &Diagnostic) -> bool {
        if d.repeats.is_some() {
            return false;
        }
        if self.limit == 0 || d.sums_up {
            return true;
        }
        let n = self.shown.entry((d.code, d.severity)).or_default();
        *n += 1;
        *n <= self.limit
    }

    /// Takes `d`: gives it back when it is to be shown in full, else counts it for its
    /// code's summary.
    pub fn admit(&mut self, d: Diagnostic) -> Option<Diagnostic> {
        if self.shows(&d) {
            return Some(d);
        }
        let key = (d.code, d.severity);
        match self.hidden.iter_mut().find(|h| (h.code, h.severity) == key) {
            Some(h) => fold(h, &d),
            None => self.hidden.push(carrier(&d)),
        }
        None
    }

    /// Puts `d` into `into` when it is to be shown in full; otherwise counts it in the
    /// one diagnostic of its code in `into` that carries the hidden ones' [`Tally`]
    /// (where a pass reports: the pipeline's [`Flood::admit`] then takes that tally in).
    pub fn push(&mut self, d: Diagnostic, into: &mut Vec<Diagnostic>) {
        if self.shows(&d) {
            into.push(d);
            return;
        }
        let key = (d.code, d.severity);
        if let Some(&i) = self.carriers.get(&key)
            && let Some(h) = into.get_mut(i)
            && (h.code, h.severity) == key
            && h.repeats.is_some()
        {
            fold(h, &d);
            return;
        }
        self.carriers.insert(key, into.len());
        into.push(carrier(&d));
    }

    /// One summary per code that had diagnostics hidden, in the order they first were;
    /// each carries its [`Tally`] and is never capped itself.
    pub fn summaries(&mut self) -> Vec<Diagnostic> {
        let hidden = std::mem::take(&mut self.hidden);
        hidden
            .into_iter()
            .filter_map(|h| {
                let shown = self
                    .shown
                    .get(&(h.code, h.severity))
                    .map_or(0, |&n| n.min(self.limit));
                summary(h, shown)
            })
            .collect()
    }
}

/// Counts `d` into `carrier`'s tally.
fn fold(carrier: &mut Diagnostic, d: &Diagnostic) {
    if let Some(t) = &mut carrier.repeats {
        t.add(d);
    }
}

/// A diagnostic of `d`'s code that stands for `d` and the ones counted into it after.
fn carrier(d: &Diagnostic) -> Diagnostic {
    let mut tally = Tally::default();
    tally.add(d);
    let mut c = Diagnostic::new(d.severity, d.code, String::new()).of_kind(d.kind);
    c.repeats = Some(Box::new(tally));
    c
}

/// The end-of-run summary of a carrier whose code had `shown` diagnostics shown in full.
fn summary(mut h: Diagnostic, shown: u64) -> Option<Diagnostic> {
    let t = h.repeats.as_deref()?.clone();
    let plural = if t.count == 1 { "" } else { "s" };
    let kind = match h.severity {
        Severity::Error => "error",
        Severity::Warning => "warning",
        Severity::Note => "note",
    };
    let mut message = format!(
        "{} more `{}` {kind}{plural} not shown ({} in all, the first {shown} above), on {}",
        t.count,
        h.code,
        t.count + shown,
        t.lines_text()
    );
    match &t.worst {
        Some(w) => {
            message.push_str(&format!("; the worst of them: {}", w.message));
            if let Some(line) = w.line {
                message.push_str(&format!(" (line {line})"));
                h.location = Some(Box::new(Location {
                    line,
                    column: 1,
                    len: 1,
                    source_line: String::new(),
                    cut: 0,
                }));
            }
        }
        None => message.push_str("; they carry no magnitude, so no worst case is named"),
    }
    h.message = message;
    h.help = Some(format!(
        "the count of {kind}s includes them all; --max-repeats 0 shows every one"
    ));
    h.sums_up = true;
    Some(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn over(line: u32, by: f64) -> Diagnostic {
        Diagnostic::error("limits::range", format!("X past its limit by {by} mm"))
            .at_line(line, "G1 X1", 1, 1)
            .with_magnitude(by)
    }

    /// The summary names the worst hidden one, in its own words, at its line.
    #[test]
    fn the_worst_is_named_at_its_line() {
        let mut flood = Flood::new(2);
        let bys = [1.0, 9.0, 2.0, 7.5, 3.0, 0.5];
        let shown = (0..bys.len())
            .filter_map(|i| flood.admit(over(i as u32 + 10, bys[i])))
            .count();
        assert_eq!(shown, 2);
        let s = flood.summaries();
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].location.as_ref().map(|l| l.line), Some(13));
        assert!(
            s[0].message.starts_with("4 more `limits::range` errors not shown (6 in all, the first 2 above), on lines 12, 13, 14, … (12..15 in all); the worst of them: X past its limit by 7.5 mm (line 13)"),
            "{}",
            s[0].message
        );
        assert!(s[0].sums_up);
    }

    /// Counting where a pass reports (per batch, into carriers) and then across the run
    /// shows and sums up exactly what counting across the run alone does.
    #[test]
    fn counting_per_batch_first_changes_nothing() {
        let all: Vec<Diagnostic> = (0..40).map(|i| over(i + 1, f64::from(i % 7))).collect();
        let mut direct = Flood::new(3);
        let shown_direct: Vec<Diagnostic> = all
            .iter()
            .cloned()
            .filter_map(|d| direct.admit(d))
            .collect();
        let mut run = Flood::new(3);
        let mut shown = Vec::new();
        for batch in all.chunks(6) {
            let mut stored = Vec::new();
            let mut output = Flood::new(3);
            for d in batch {
                output.push(d.clone(), &mut stored);
            }
            assert!(stored.len() <= 4, "three in full and one carrier");
            shown.extend(stored.into_iter().filter_map(|d| run.admit(d)));
        }
        assert_eq!(shown, shown_direct);
        assert_eq!(run.summaries(), direct.summaries());
    }
}
