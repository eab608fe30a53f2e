//! What `expand-subprograms` needs of the G-code frontend, as an interface: passes do
//! not depend on the frontends, so the pipeline hands the pass a [`Relower`] over the
//! G-code lowerer (the pipeline's `gcode_relower`) in [`crate::passes::Context`].

use serde::{Deserialize, Serialize};

use crate::diag::Diagnostic;
use crate::ir::{Block, Modal, Span};

/// The frontend options bodies are lowered with: the `[input]` table of the pass, with
/// the fields and defaults of the G-code frontend's options (`tests/subprograms.rs`
/// keeps them equal).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Input {
    /// `G4 P` counts milliseconds (RepRapFirmware, Marlin, Fanuc) rather than seconds
    /// (LinuxCNC).
    pub dwell_p_milliseconds: bool,
    /// Largest difference between an arc's start and end radius, mm, below which the
    /// arc is accepted (a relative 0.1 % of the radius is also allowed).
    pub arc_tolerance: f64,
    /// An arc whose end is off its circle by more than the tolerance is an error; when
    /// false it is a warning and the arc is kept as written.
    pub strict_arcs: bool,
    /// Longest line accepted, bytes; a longer line is an error and is skipped.
    pub max_line_len: usize,
}

impl Default for Input {
    fn default() -> Self {
        Input {
            dwell_p_milliseconds: true,
            arc_tolerance: 0.01,
            strict_arcs: true,
            max_line_len: 1 << 20,
        }
    }
}

/// Makes the G-code lowerer for frontend options `input`; `Err` when the frontend does
/// not take them. The pipeline fills [`crate::passes::Context::relower`] with one.
pub type Relower = fn(input: &Input) -> Result<Box<dyn Lowering>, Diagnostic>;

/// The G-code lowerer, for subprogram bodies.
pub trait Lowering: Send {
    /// The state at the start of a program.
    fn start(&self) -> Modal;
    /// A lowerer for the lines of a body, starting in `state`; the calls in the body
    /// clobber nothing (the pass expands them).
    fn body(&self, state: Modal) -> Box<dyn BodyLowerer + '_>;
    /// Reads an o-word call line (`o100 call`, `o<name> call [1] [2]`); `None` when the
    /// line is not one.
    fn oword_call(&self, text: &str) -> Option<OwordCall>;
}

/// Lowers the lines of one body in order.
pub trait BodyLowerer {
    /// Lowers one line, putting its blocks in `out` and its diagnostics in `diags`.
    fn line(&mut self, text: &str, span: Span, out: &mut Vec<Block>, diags: &mut Vec<Diagnostic>);
    /// The state the next line is lowered in.
    fn state(&self) -> Modal;
    /// Puts the lowerer into `state` (after an expanded call).
    fn set_state(&mut self, state: Modal);
}

/// An o-word call line, as far as the pass needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct OwordCall {
    /// The label, lower case, leading zeros of a number removed (`100`, `<name>`); `None`
    /// when it is an expression (`o[#2 * 10]`).
    pub label: Option<String>,
    /// No arguments and a plain label: the call can be expanded.
    pub simple: bool,
    /// Byte range of the label and the keyword in the line, for diagnostics.
    pub at: (usize, usize),
}
