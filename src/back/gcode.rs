//! Plain ISO / LinuxCNC G-code backend.

use std::io::Write;

use serde::{Deserialize, Serialize};

use super::{CommentOutput, Decimals, Emitter, Extrusion, Flavor, Format};
use crate::diag::Diagnostic;
use crate::ir::Block;

/// Plain G-code backend options.
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
    /// Append `*` checksums.
    pub checksums: bool,
    /// Leave out a repeated G0/G1/G2/G3.
    pub modal_motion: bool,
    /// How E is written.
    pub extrusion: Extrusion,
    /// `G4 P` in milliseconds (Fanuc, Marlin; the frontend's default reading, so the
    /// number is kept) rather than seconds (LinuxCNC). Unset: what the preset's
    /// controller reads (its flavour's dwell unit: seconds for `linuxcnc`, the default
    /// flavour of a `gcode` preset with a `[machine]`), else milliseconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dwell_milliseconds: Option<bool>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            decimals: Decimals::default(),
            trim_zeros: true,
            comments: CommentOutput::AsInput,
            line_numbers: false,
            checksums: false,
            modal_motion: false,
            extrusion: Extrusion::Relative,
            dwell_milliseconds: None,
        }
    }
}

/// Streams plain G-code to `out`.
///
/// ```
/// use ncpost::back::gcode;
/// use ncpost::front::gcode::{parse_str, Options};
/// let program = parse_str("G20\nG1 X1 F10 (inch)\n", &Options::default()).unwrap();
/// let text = gcode::write_string(&program.blocks, &gcode::Options::default()).unwrap();
/// assert_eq!(text, "G21 G90 G94\nG1 X25.4 F254 (inch)\n");
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
            dwell_milliseconds: options.dwell_milliseconds.unwrap_or(true),
            feed_on_rapids: false,
        };
        Writer(Emitter::new(out, Flavor::Plain, fmt))
    }
}

super::writer_backend!(Writer);

/// Prints `blocks` as plain G-code.
pub fn write_string(blocks: &[Block], options: &Options) -> Result<String, Vec<Diagnostic>> {
    let mut out = Vec::new();
    super::write_all(&mut Writer::new(&mut out, options), blocks)?;
    Ok(String::from_utf8_lossy(&out).into_owned())
}
