//! Backends: IR blocks to text, written as they arrive.
//!
//! [`rrf`] (RepRapFirmware 3.x, CNC mode), [`gcode`] (plain ISO/LinuxCNC) and [`grbl`]
//! (Grbl 1.1, the plain emitter restricted to Grbl's words) share one emitter that prints absolute millimetre coordinates at fixed precision and elides modal
//! words (motion code, feed, plane, units, distance mode) and unchanged axes. [`ir`] prints
//! the IR text dump.

mod command;
mod emit;
pub mod gcode;
pub mod grbl;
pub mod ir;
mod line;
mod motion;
pub mod rrf;

use std::io::Write;

use serde::{Deserialize, Serialize};

use crate::diag::Diagnostic;
use crate::ir::{AXIS_COUNT, Block, FeedMode, Plane, Tracker};
pub use crate::num::print::{Decimals, remember_printed};

/// Writing stopped because the output cannot be written (a full disk, a closed pipe); the
/// diagnostic that says so is in the list of the call that stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputLost;

/// A sink for IR blocks.
pub trait Backend {
    /// Writes one block. An `Err` is a diagnostic about the block (an IR the backend
    /// cannot express) or an I/O failure.
    fn write_block(&mut self, block: &Block, diags: &mut Vec<Diagnostic>)
    -> Result<(), Diagnostic>;
    /// Writes `blocks` in order, adding every diagnostic to `diags`; stops at an I/O
    /// failure, when nothing more can be written. By default one [`Backend::write_block`]
    /// after the other; a backend may hand the batch's text to its writer in one piece
    /// (where [`Backend::write_block`] hands each block's text over as it returns).
    fn write_batch(
        &mut self,
        blocks: &[Block],
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), OutputLost> {
        each_block(blocks, diags, |b, d| self.write_block(b, d))
    }
    /// Flushes the output at the end of the program.
    fn finish(&mut self) -> Result<(), Diagnostic>;
}

/// How comments are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CommentOutput {
    /// As in the source: `( )` or `;`.
    AsInput,
    /// Always `;`.
    Semicolon,
    /// Always `( )` (a comment containing parentheses falls back to `;`).
    Paren,
    /// Comments are dropped (smallest output for controllers with little memory).
    Strip,
}

/// How the extruder axis is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Extrusion {
    /// M83: each move's E is its own length; rounding never accumulates.
    Relative,
    /// M82: E is a running position.
    Absolute,
}

/// Settings both G-code backends share.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Format {
    pub decimals: Decimals,
    pub trim_zeros: bool,
    pub comments: CommentOutput,
    pub line_numbers: bool,
    pub checksums: bool,
    pub modal_motion: bool,
    pub extrusion: Extrusion,
    pub dwell_milliseconds: bool,
    /// The controller runs `G0` at the modal F (an FDM firmware): F is printed on
    /// rapids too, so each runs at the F it was timed at.
    pub feed_on_rapids: bool,
}

/// Which controller the text is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Flavor {
    Rrf {
        inverse_time: bool,
        unsupported: rrf::Unsupported,
    },
    Plain,
    Grbl(grbl::Settings),
}

/// What the controller is known to be in after what has been printed. `None` means
/// unknown (program start, or after a line passed through as text).
#[derive(Debug, Clone, Default)]
struct Modes {
    metric: Option<bool>,
    absolute: Option<bool>,
    plane: Option<Plane>,
    feed_mode: Option<FeedMode>,
    /// The modal F as the controller read it.
    feed: Option<f64>,
    motion: Option<&'static str>,
    e_relative: Option<bool>,
}

use line::Line;

/// The shared G-code emitter.
pub(crate) struct Emitter<W: Write> {
    out: W,
    flavor: Flavor,
    fmt: Format,
    line: Line,
    number: u64,
    modes: Modes,
    /// Last printed program-frame value per axis, in print units.
    printed: [Option<i64>; AXIS_COUNT],
    /// IR-frame position after the last block, and the G92 offsets printing adds.
    track: Tracker,
    /// Running E in print units (IR frame), for relative extrusion.
    e_units: Option<i64>,
    /// The span of the block being printed (for line-length errors).
    span: crate::ir::Span,
    /// Grbl: inside a subprogram or control-flow run already reported (its further
    /// lines are not reported one by one).
    grbl_quiet: bool,
    /// `fmt.decimals.axis(a)` for every axis, looked up by index.
    axis_decimals: [u8; AXIS_COUNT],
}

pub(crate) fn io_error(e: std::io::Error) -> Diagnostic {
    Diagnostic::io("io::write", format!("cannot write the output: {e}"))
}

/// Whether `d` says the output could not be written.
pub(crate) fn is_io_error(d: &Diagnostic) -> bool {
    d.kind == crate::diag::Kind::Io
}

impl<W: Write> Backend for Emitter<W> {
    fn write_block(
        &mut self,
        block: &Block,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let written = self.block(block, diags);
        // The block's text is the writer's when this returns (a program streamed to a
        // controller line by line sees it now).
        let handed = self.hand_out();
        written.and(handed)
    }
    fn write_batch(
        &mut self,
        blocks: &[Block],
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), OutputLost> {
        let written = each_block(blocks, diags, |b, d| self.block(b, d));
        // The whole batch's text in one write; what was printed before a failure stands.
        match self.hand_out() {
            Err(e) if written.is_ok() => {
                diags.push(e);
                Err(OutputLost)
            }
            _ => written,
        }
    }
    fn finish(&mut self) -> Result<(), Diagnostic> {
        self.flush()
    }
}

/// Implements [`Backend`] for a flavour's `Writer`, a newtype over [`Emitter`].
macro_rules! writer_backend {
    ($writer:ident) => {
        impl<W: std::io::Write> $crate::back::Backend for $writer<W> {
            fn write_block(
                &mut self,
                block: &$crate::ir::Block,
                diags: &mut Vec<$crate::diag::Diagnostic>,
            ) -> Result<(), $crate::diag::Diagnostic> {
                $crate::back::Backend::write_block(&mut self.0, block, diags)
            }
            fn write_batch(
                &mut self,
                blocks: &[$crate::ir::Block],
                diags: &mut Vec<$crate::diag::Diagnostic>,
            ) -> Result<(), $crate::back::OutputLost> {
                self.0.write_batch(blocks, diags)
            }
            fn finish(&mut self) -> Result<(), $crate::diag::Diagnostic> {
                self.0.flush()
            }
        }
    };
}
use writer_backend;

/// Writes all `blocks` to `backend` and finishes it; returns every diagnostic, in order.
///
/// ```
/// use ncpost::back::{gcode, write_blocks};
/// use ncpost::front::gcode::{parse_str, Options};
/// let program = parse_str("G0 X1\n", &Options::default()).unwrap();
/// let mut text = Vec::new();
/// let diags = write_blocks(&mut gcode::Writer::new(&mut text, &gcode::Options::default()), &program.blocks);
/// assert!(diags.is_empty());
/// ```
pub fn write_blocks(backend: &mut dyn Backend, blocks: &[Block]) -> Vec<Diagnostic> {
    let mut diags = Vec::new();
    let _ = backend.write_batch(blocks, &mut diags);
    if let Err(d) = backend.finish() {
        diags.push(d);
    }
    diags
}

/// Writes each block with `write`, adding its diagnostics to `diags`; `Err` after an
/// I/O failure.
pub(crate) fn each_block(
    blocks: &[Block],
    diags: &mut Vec<Diagnostic>,
    mut write: impl FnMut(&Block, &mut Vec<Diagnostic>) -> Result<(), Diagnostic>,
) -> Result<(), OutputLost> {
    for b in blocks {
        if let Err(d) = write(b, diags) {
            // The output cannot be written (a full disk, a closed pipe): nothing after
            // this block can be either, so writing stops with one error.
            let io = is_io_error(&d);
            diags.push(d);
            if io {
                return Err(OutputLost);
            }
        }
    }
    Ok(())
}

/// Like [`write_blocks`], but `Err` with every diagnostic when any is an error.
pub(crate) fn write_all(
    backend: &mut dyn Backend,
    blocks: &[Block],
) -> Result<(), Vec<Diagnostic>> {
    let diags = write_blocks(backend, blocks);
    if diags.iter().any(Diagnostic::is_error) {
        Err(diags)
    } else {
        Ok(())
    }
}

/// The error for a value that does not fit the configured precision.
fn too_large(letter: char, value: f64, block: &Block) -> Diagnostic {
    Diagnostic::error(
        "back::number",
        format!("{letter} = {value} cannot be printed at the configured precision"),
    )
    .at_span(block.span)
    .with_help("the value is not finite or too large; check the transformations before the backend")
}
