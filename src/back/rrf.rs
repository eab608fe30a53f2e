//! RepRapFirmware 3.x backend (Duet 3, CNC mode).
//!
//! Differences from plain G-code: `;` comments by default (CNC mode accepts one `( )`
//! pair per line), `G4 P` dwells in milliseconds, G93 only when the firmware is 3.5 or newer,
//! and codes RepRapFirmware lacks (G40-G43, G49, G80-G89, M6-M9 without macros) are
//! written as comments with a warning unless configured otherwise.

use std::io::Write;

use serde::{Deserialize, Serialize};

use super::{CommentOutput, Decimals, Emitter, Extrusion, Flavor, Format};
use crate::diag::Diagnostic;
use crate::ir::Block;

/// What to do with a command RepRapFirmware does not implement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Unsupported {
    /// Write it as a comment and warn.
    Comment,
    /// Write it anyway (your `sys/` macros implement it).
    Keep,
    /// Stop with an error.
    Error,
}

/// RepRapFirmware backend options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Digits after the decimal point.
    pub decimals: Decimals,
    /// Drop trailing zeros (`X10` rather than `X10.000`).
    pub trim_zeros: bool,
    /// Comment style.
    pub comments: CommentOutput,
    /// Number the lines (`N1`, `N2`, ...).
    pub line_numbers: bool,
    /// Append `*` checksums (for serial or USB streaming).
    pub checksums: bool,
    /// Leave out a repeated G0/G1/G2/G3.
    pub modal_motion: bool,
    /// How E is written.
    pub extrusion: Extrusion,
    /// The firmware is 3.5 or newer and accepts inverse time feed (G93).
    pub inverse_time: bool,
    /// What to do with codes the firmware lacks.
    pub unsupported: Unsupported,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            decimals: Decimals::default(),
            trim_zeros: true,
            comments: CommentOutput::Semicolon,
            line_numbers: false,
            checksums: false,
            modal_motion: false,
            extrusion: Extrusion::Relative,
            inverse_time: false,
            unsupported: Unsupported::Comment,
        }
    }
}

/// Streams RepRapFirmware G-code to `out`.
///
/// ```
/// use ncpost::back::{Backend, rrf};
/// use ncpost::front::gcode::{parse_str, Options};
/// let program = parse_str("G0 X10 Y5 ; go\n", &Options::default()).unwrap();
/// let mut text = Vec::new();
/// let mut diags = Vec::new();
/// let mut writer = rrf::Writer::new(&mut text, &rrf::Options::default());
/// for b in &program.blocks {
///     writer.write_block(b, &mut diags).unwrap();
/// }
/// writer.finish().unwrap();
/// drop(writer);
/// assert_eq!(String::from_utf8(text).unwrap(), "G21 G90\nG0 X10 Y5 ; go\n");
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
            checksums: options.checksums,
            modal_motion: options.modal_motion,
            extrusion: options.extrusion,
            // `G4 P` in milliseconds keeps the number of the (Fanuc/Marlin/RRF) source.
            dwell_milliseconds: true,
            feed_on_rapids: false,
        };
        let flavor = Flavor::Rrf {
            inverse_time: options.inverse_time,
            unsupported: options.unsupported,
        };
        Writer(Emitter::new(out, flavor, fmt))
    }

    /// The same writer for a controller that runs `G0` at the modal F (RepRapFirmware
    /// in FDM mode): rapids carry the F they were timed at.
    pub fn with_feed_on_rapids(mut self, on: bool) -> Self {
        self.0.fmt.feed_on_rapids = on;
        self
    }
}

super::writer_backend!(Writer);

/// Prints `blocks` as RepRapFirmware G-code.
pub fn write_string(blocks: &[Block], options: &Options) -> Result<String, Vec<Diagnostic>> {
    let mut out = Vec::new();
    super::write_all(&mut Writer::new(&mut out, options), blocks)?;
    Ok(String::from_utf8_lossy(&out).into_owned())
}

/// Whether a word is a G or M code RepRapFirmware lacks (or, for G31, gives another
/// meaning: it sets the Z probe instead of probing).
fn unsupported(word: &str) -> bool {
    let mut chars = word.chars();
    let letter = chars.next().map(|c| c.to_ascii_uppercase());
    let Some(n) = crate::num::parse_decimal(chars.as_str()) else {
        return false;
    };
    if n.fract() != 0.0 {
        return false;
    }
    match letter {
        Some(l) if l.is_ascii() => unsupported_code(l as u8, n as u32),
        _ => false,
    }
}

/// Whether a command has a code RepRapFirmware lacks, that is whether
/// [`split_unsupported`] would remove anything.
///
/// ```
/// # use ncpost::back::rrf::any_unsupported;
/// assert!(any_unsupported("T1 M06"));
/// assert!(!any_unsupported("M3 S1000"));
/// ```
pub fn any_unsupported(text: &str) -> bool {
    if !text.is_ascii() {
        return text
            .split_whitespace()
            .any(|w| starts_command(w) && unsupported(w));
    }
    // Bytes for the usual ASCII line (every backend line of an rpm or valve command
    // comes here); the same words as `split_whitespace` gives for ASCII.
    text.as_bytes()
        .split(|b| matches!(b, b' ' | b'\t' | b'\n' | 0x0B | 0x0C | b'\r'))
        .any(|w| {
            let Some((&letter, number)) = w.split_first() else {
                return false;
            };
            if !matches!(letter, b'G' | b'g' | b'M' | b'm' | b'T' | b't') {
                return false;
            }
            if !number.is_empty() && number.len() <= 9 && number.iter().all(u8::is_ascii_digit) {
                let n = number
                    .iter()
                    .fold(0u32, |n, d| n * 10 + u32::from(d - b'0'));
                return unsupported_code(letter.to_ascii_uppercase(), n);
            }
            std::str::from_utf8(w).is_ok_and(unsupported)
        })
}

fn unsupported_code(letter: u8, n: u32) -> bool {
    match letter {
        b'G' => matches!(n, 31 | 40..=43 | 49 | 80..=89),
        b'M' => matches!(n, 6..=9),
        _ => false,
    }
}

fn starts_command(word: &str) -> bool {
    word.starts_with(['G', 'g', 'M', 'm', 'T', 't'])
}

/// Splits a command into the words RepRapFirmware runs and the unsupported codes with
/// their parameters (the words after them up to the next G, M or T word).
///
/// ```
/// # use ncpost::back::rrf::split_unsupported;
/// assert_eq!(split_unsupported("T1 M06"), ("T1".to_string(), "M06".to_string()));
/// assert_eq!(split_unsupported("G43 H1"), (String::new(), "G43 H1".to_string()));
/// assert_eq!(split_unsupported("M3 S1000"), ("M3 S1000".to_string(), String::new()));
/// ```
pub fn split_unsupported(text: &str) -> (String, String) {
    let mut kept = Vec::new();
    let mut removed = Vec::new();
    let mut dropping = false;
    for w in text.split_whitespace() {
        if starts_command(w) {
            dropping = unsupported(w);
        }
        if dropping {
            removed.push(w);
        } else {
            kept.push(w);
        }
    }
    (kept.join(" "), removed.join(" "))
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The allocation-free check agrees with the split on command-like word soup,
        /// ASCII or not.
        #[test]
        fn any_unsupported_agrees_with_the_split(
            words in proptest::collection::vec(
                "[GMTgmtSXP]{1}(-?[0-9]{0,3}(\\.[0-9]{0,2})?)|é|\u{0085}|\u{000B}",
                0..6,
            ),
            seps in proptest::collection::vec("[ \t\u{000B}\u{000C}\u{00A0}]{1,2}", 6),
        ) {
            let mut text = String::new();
            for (w, s) in words.iter().zip(&seps) {
                text.push_str(w);
                text.push_str(s);
            }
            let removes = !split_unsupported(&text).1.is_empty();
            proptest::prop_assert_eq!(any_unsupported(&text), removes, "{:?}", text);
        }
    }

    #[test]
    fn finds_the_codes_rrf_lacks() {
        for (text, expected) in [
            ("M3 S1000", false),
            ("M6 T1", true),
            ("T1 m06", true),
            ("G43 H1", true),
            ("G43.1 Z2", false),
            ("G31", true),
            ("G1 X5 G80", true),
            ("M", false),
        ] {
            assert_eq!(any_unsupported(text), expected, "{text}");
        }
    }
}
