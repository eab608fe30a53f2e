//! What `expand-subprograms` needs of the G-code frontend, as an interface: passes do
//! not depend on the frontends, so the pipeline hands the pass a [`Relower`] over the
//! G-code lowerer (the pipeline's `gcode_relower`) in [`crate::passes::Context`].

use crate::diag::Diagnostic;
use crate::ir::{Block, Modal, Span};

/// Makes the G-code lowerer for the frontend options in the table `input` (the G-code
/// frontend's `[gcode_input]` fields; the frontend reads them, so the pass keeps no copy
/// of their names and defaults); `Err` when the frontend does not take them. The
/// pipeline fills [`crate::passes::Context::relower`] with one.
pub type Relower = fn(input: &toml::Table) -> Result<Box<dyn Lowering>, Diagnostic>;

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
