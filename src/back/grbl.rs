//! Grbl 1.1 backend: the plain G-code emitter restricted to what Grbl 1.1 parses.
//!
//! Grbl (gnea/grbl 1.1, `gcode.c` and `protocol.c`) accepts a small, fixed set of words.
//! This flavour writes only those, or stops with a diagnostic that points at the source
//! line, because Grbl answers anything else with an `error:` and **skips the line while
//! the job goes on** (a missing move or a missing retract on a running machine):
//!
//! - **G codes**: G0 G1 G2 G3 G4 G10 G17 G18 G19 G20 G21 G28 G28.1 G30 G30.1
//!   G38.2-G38.5 G40 G43.1 G49 G53 G54-G59 G61 G80 G90 G91 G91.1 G92 G92.1 G93 G94.
//!   **M codes**: M0 M1 M2 M30 M3 M4 M5 M8 M9 (M7 and M56 only in builds compiled with
//!   `ENABLE_M7` / `ENABLE_PARKING_OVERRIDE_CONTROL`: set `m7 = true` / `m56 = true`).
//!   **Value words**: F I J K L N P R S T X Y Z. Grbl has no A, B, C or E axis.
//! - A command Grbl lacks (M6, M7, G41, G43 H, G81-G89 canned cycles, G64, M106, ...) is
//!   written as a comment with the warning `grbl::unsupported` (option `unsupported`:
//!   `"comment"`, `"keep"` for a grblHAL or patched build, or `"error"`), like the
//!   RepRapFirmware flavour. The group removed is the code with the words after it up to
//!   the next G, M or T word (`T1 M6` keeps `T1`; Grbl parses T and ignores it).
//! - **Canned cycles, splines, threading** (G73, G76, G81-G89, G5.x, G33): always the
//!   error `grbl::unsupported-motion` (a drilling cycle left out is holes not drilled).
//!   Lines the IR passes as text that are plain words Grbl reads (probing `G38.2`) are
//!   printed as written.
//! - **Subprograms**: Grbl has no `M98`/`M99`, `O` programs or `o` words. The pipeline
//!   runs `expand-subprograms` first whenever the output is Grbl (it inserts the pass
//!   with a note when the preset lacks it). A call or control-flow line left after it (a
//!   call with arguments or an expression, `o100 if`, parameters `#1=...`) is the error
//!   `grbl::subprogram` / `grbl::unevaluated`.
//! - **`%` lines** are left out: Grbl reads `%` as a bad command letter (`error:1`). An
//!   `O1234` program number line becomes a comment.
//! - **G93** (inverse time) is the error `grbl::inverse-time` unless `allow_g93 = true`:
//!   Grbl 1.1 does run G93, but an inverse-time feed is computed for one machine's
//!   kinematics and is only right when the emitted moves are the ones it was computed
//!   for, so it is opt-in. G95 (feed per revolution) is the error `grbl::feed-per-rev`.
//! - **Arcs**: G2/G3 with I J K in G17, G18 and G19 (full circles included). An arc with
//!   extra turns (`P`) is the error `grbl::arc-turns` (Grbl rejects `P` on an arc); put
//!   `linearize-arcs` before the backend.
//! - **G92.2 / G92.3** (suspend and restore offsets) are the error `grbl::offset`.
//! - **Line length**: Grbl drops spaces, comments and `/` as it reads a line and holds at
//!   most 79 characters of the rest (`LINE_BUFFER_SIZE` 80); a longer line is
//!   `error:11` and skipped. A line over [`LINE_LIMIT`] counted characters is the error
//!   `grbl::line-length` (fewer decimals or no line numbers make lines shorter).
//! - **Comments** are written in parentheses by default (Grbl 1.1 also reads `;`, used
//!   for a comment that contains parentheses). **Dwell** `G4 P` is in seconds (Grbl's
//!   unit). No checksums (Grbl has none); `N` line numbers are allowed.

use std::io::Write;

use serde::{Deserialize, Serialize};

use super::{CommentOutput, Decimals, Emitter, Extrusion, Flavor, Format};
use crate::diag::Diagnostic;
use crate::ir::Block;

pub use super::rrf::Unsupported;

/// Most characters Grbl 1.1 holds of one line, spaces and comments not counted
/// (`LINE_BUFFER_SIZE - 1`).
pub const LINE_LIMIT: usize = 79;

/// Grbl backend options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Digits after the decimal point.
    pub decimals: Decimals,
    /// Drop trailing zeros (`X10` rather than `X10.000`).
    pub trim_zeros: bool,
    /// Comment style (`paren` by default; `strip` for the smallest stream).
    pub comments: CommentOutput,
    /// Number the lines (`N1`, `N2`, ...).
    pub line_numbers: bool,
    /// Leave out a repeated G0/G1/G2/G3.
    pub modal_motion: bool,
    /// Write G93 (inverse time feed) moves; otherwise they are an error.
    pub allow_g93: bool,
    /// The Grbl build has `ENABLE_M7` (mist coolant).
    pub m7: bool,
    /// The Grbl build has `ENABLE_PARKING_OVERRIDE_CONTROL` (M56).
    pub m56: bool,
    /// What to do with codes Grbl lacks.
    pub unsupported: Unsupported,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            decimals: Decimals::default(),
            trim_zeros: true,
            comments: CommentOutput::Paren,
            line_numbers: false,
            modal_motion: false,
            allow_g93: false,
            m7: false,
            m56: false,
            unsupported: Unsupported::Comment,
        }
    }
}

/// What the Grbl flavour of the emitter needs to know.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Settings {
    pub allow_g93: bool,
    pub m7: bool,
    pub m56: bool,
    pub unsupported: Unsupported,
}

/// Streams Grbl 1.1 G-code to `out`.
///
/// ```
/// use ncpost::back::grbl;
/// use ncpost::front::gcode::{parse_str, Options};
/// let program = parse_str("%\nG0 X10 Y5 ; go\nG4 P500\nM30\n%\n", &Options::default()).unwrap();
/// let text = grbl::write_string(&program.blocks, &grbl::Options::default()).unwrap();
/// assert_eq!(text, "G21 G90\nG0 X10 Y5 ( go)\nG4 P0.5\nM30\n");
/// ```
pub struct Writer<W: Write>(Emitter<W>);

impl<W: Write> Writer<W> {
    /// A writer with `options`.
    pub fn new(out: W, options: &Options) -> Self {
        let fmt = Format {
            decimals: options.decimals,
            trim_zeros: options.trim_zeros,
            comments: options.comments,
            line_numbers: options.line_numbers,
            checksums: false,
            modal_motion: options.modal_motion,
            extrusion: Extrusion::Relative,
            // Grbl's `G4 P` is in seconds.
            dwell_milliseconds: false,
            feed_on_rapids: false,
        };
        let flavor = Flavor::Grbl(Settings {
            allow_g93: options.allow_g93,
            m7: options.m7,
            m56: options.m56,
            unsupported: options.unsupported,
        });
        Writer(Emitter::new(out, flavor, fmt))
    }
}

super::writer_backend!(Writer);

/// Prints `blocks` as Grbl G-code.
pub fn write_string(blocks: &[Block], options: &Options) -> Result<String, Vec<Diagnostic>> {
    let mut out = Vec::new();
    super::write_all(&mut Writer::new(&mut out, options), blocks)?;
    Ok(String::from_utf8_lossy(&out).into_owned())
}

/// Whether Grbl 1.1 (with `settings`' build options) runs the G or M code `word`.
fn supported_code(word: &str, settings: &Settings) -> bool {
    let mut chars = word.chars();
    let letter = chars.next().map(|c| c.to_ascii_uppercase());
    let Some(n) = crate::num::parse_decimal(chars.as_str()) else {
        return false;
    };
    // Codes as tenths: G38.2 is 382.
    let tenths = (n * 10.0).round();
    if (n * 10.0 - tenths).abs() > 1e-9 || tenths < 0.0 {
        return false;
    }
    let t = tenths as u32;
    match letter {
        Some('G') => {
            matches!(
                t,
                0 | 10
                    | 20
                    | 30
                    | 40
                    | 100
                    | 170
                    | 180
                    | 190
                    | 200
                    | 210
                    | 280
                    | 281
                    | 300
                    | 301
                    | 382
                    ..=385
                        | 400
                        | 431
                        | 490
                        | 530
                        | 540
                        | 550
                        | 560
                        | 570
                        | 580
                        | 590
                        | 610
                        | 800
                        | 900
                        | 910
                        | 911
                        | 920
                        | 921
                        | 930
                        | 940
            )
        }
        Some('M') => match t {
            0 | 10 | 20 | 300 | 30 | 40 | 50 | 80 | 90 => true,
            70 => settings.m7,
            560 => settings.m56,
            _ => false,
        },
        Some('T') => true,
        _ => false,
    }
}

/// Whether Grbl 1.1 reads the value word letter `c`.
fn supported_letter(c: char) -> bool {
    matches!(
        c.to_ascii_uppercase(),
        'F' | 'I' | 'J' | 'K' | 'L' | 'N' | 'P' | 'R' | 'S' | 'T' | 'X' | 'Y' | 'Z' | 'G' | 'M'
    )
}

/// Whether `word` is a subprogram call or return (`M98`, `M99`).
pub(crate) fn is_subprogram_word(word: &str) -> bool {
    let mut chars = word.chars();
    if !matches!(chars.next(), Some('M' | 'm')) {
        return false;
    }
    matches!(
        crate::num::parse_decimal(chars.as_str()),
        Some(n) if n == 98.0 || n == 99.0
    )
}

/// Whether `word` is a motion code Grbl lacks: canned cycles (G73, G76, G81-G89),
/// splines (G5.x), threading (G33.x). Such a line left out would leave cuts out, so it is
/// an error whatever `unsupported` says.
pub(crate) fn is_unsupported_motion(word: &str) -> bool {
    let mut chars = word.chars();
    if !matches!(chars.next(), Some('G' | 'g')) {
        return false;
    }
    match crate::num::parse_decimal(chars.as_str()) {
        Some(n) => {
            let i = n.trunc();
            i == 5.0 || i == 33.0 || i == 73.0 || i == 76.0 || (81.0..=89.0).contains(&i)
        }
        None => false,
    }
}

/// Splits a command into the words Grbl runs and the groups it lacks (a G, M or T code
/// with the words after it up to the next code; a group with a letter Grbl does not read
/// is removed whole).
///
/// ```
/// # use ncpost::back::grbl::{split_unsupported, Options};
/// let o = Options::default();
/// assert_eq!(split_unsupported("T1 M6", &o), ("T1".to_string(), "M6".to_string()));
/// assert_eq!(split_unsupported("G43 H1", &o), (String::new(), "G43 H1".to_string()));
/// assert_eq!(split_unsupported("M3 S1000", &o), ("M3 S1000".to_string(), String::new()));
/// assert_eq!(split_unsupported("G38.2 Z-2 F20", &o), ("G38.2 Z-2 F20".to_string(), String::new()));
/// assert_eq!(split_unsupported("G28 A0", &o), (String::new(), "G28 A0".to_string()));
/// ```
pub fn split_unsupported(text: &str, options: &Options) -> (String, String) {
    let settings = Settings {
        allow_g93: options.allow_g93,
        m7: options.m7,
        m56: options.m56,
        unsupported: options.unsupported,
    };
    split_words(text, &settings)
}

pub(crate) fn split_words(text: &str, settings: &Settings) -> (String, String) {
    let mut groups: Vec<Vec<&str>> = Vec::new();
    for w in text.split_whitespace() {
        let starts_command = w.starts_with(['G', 'g', 'M', 'm', 'T', 't']);
        match groups.last_mut() {
            Some(g) if !starts_command => g.push(w),
            _ => groups.push(vec![w]),
        }
    }
    let mut kept = Vec::new();
    let mut removed = Vec::new();
    for g in groups {
        let head = g[0];
        let code_ok = if head.starts_with(['G', 'g', 'M', 'm', 'T', 't']) {
            supported_code(head, settings)
        } else {
            true
        };
        let letters_ok = g
            .iter()
            .all(|w| w.chars().next().is_some_and(supported_letter));
        if code_ok && letters_ok {
            kept.extend(g);
        } else {
            removed.extend(g);
        }
    }
    (kept.join(" "), removed.join(" "))
}

/// The number of characters Grbl 1.1 keeps of `line`: it drops blanks and control
/// characters, `/`, `( )` comments and everything after `;`.
///
/// ```
/// # use ncpost::back::grbl::counted_length;
/// assert_eq!(counted_length("G1 X10 Y5 (a long comment)"), 7);
/// assert_eq!(counted_length("N10 G0 Z1 ; up"), 7);
/// ```
pub fn counted_length(line: &str) -> usize {
    let mut n = 0;
    let mut paren = false;
    for c in line.chars() {
        if paren {
            if c == ')' {
                paren = false;
            }
            continue;
        }
        match c {
            ';' => break,
            '(' => paren = true,
            '/' => {}
            c if c <= ' ' => {}
            _ => n += 1,
        }
    }
    n
}
