//! The arguments of a statement as the lowering reads them: numbers, words, and the
//! errors that point at them.

use crate::diag::Diagnostic;
use crate::front::cl::ast::{Arg, ArgKind};
use crate::front::cl::source::Statement;

/// The numbers and words of a statement's arguments.
pub(super) struct Args<'a> {
    pub stmt: &'a Statement,
    pub list: &'a [Arg],
}

impl<'a> Args<'a> {
    pub(super) fn text(&self, a: &Arg) -> &'a str {
        &self.stmt.code[a.start..a.end]
    }

    /// The argument as a number, or an error pointing at it: a number beyond
    /// [`crate::num::range::MAX_MAGNITUDE`] is refused here, once, rather than giving an
    /// error on every move downstream.
    pub(super) fn number(&self, a: &Arg) -> Result<f64, Diagnostic> {
        let text = self.text(a);
        // The token as a message shows it, only when there is a message.
        let shown = || crate::num::range::shown(text);
        if a.kind != ArgKind::Number {
            return Err(self.stmt.locate(
                Diagnostic::error(
                    "cl::bad-number",
                    format!("expected a number, found `{}`", shown()),
                )
                .with_label("not a number")
                .with_help("write a decimal number such as `12.5`, `-.5` or `1.E-3`"),
                a.start,
                a.end,
            ));
        }
        match crate::num::parse_decimal(text) {
            Some(v) if crate::num::range::in_range(v) => Ok(v),
            _ => Err(self.stmt.locate(
                Diagnostic::error("cl::bad-number", format!("`{}` is out of range", shown()))
                    .with_label("too large")
                    .with_help(format!(
                        "CL values must be finite and at most {:e} in size; check the number's exponent and digits",
                        crate::num::range::MAX_MAGNITUDE
                    )),
                a.start,
                a.end,
            )),
        }
    }

    /// Every argument as a number.
    pub(super) fn numbers(&self) -> Result<Vec<f64>, Diagnostic> {
        self.list.iter().map(|a| self.number(a)).collect()
    }

    /// The argument as an upper-case word, if it is one.
    pub(super) fn word(&self, a: &Arg) -> Option<String> {
        (a.kind == ArgKind::Word).then(|| self.text(a).to_ascii_uppercase())
    }

    /// The byte range of all arguments (or of the statement when it has none).
    pub(super) fn range(&self) -> (usize, usize) {
        match (self.list.first(), self.list.last()) {
            (Some(f), Some(l)) => (f.start, l.end),
            _ => (0, self.stmt.code.trim_end().len()),
        }
    }

    pub(super) fn error_all(&self, d: Diagnostic) -> Diagnostic {
        let (s, e) = self.range();
        self.stmt.locate(d, s, e)
    }

    /// An error when the count of arguments is not in `counts`.
    pub(super) fn arity(
        &self,
        major: &str,
        counts: &[usize],
        what: &str,
    ) -> Result<(), Diagnostic> {
        if counts.contains(&self.list.len()) {
            return Ok(());
        }
        Err(self.error_all(
            Diagnostic::error(
                "cl::arity",
                format!(
                    "{major} takes {what}, found {} value{}",
                    self.list.len(),
                    if self.list.len() == 1 { "" } else { "s" }
                ),
            )
            .with_label("here")
            .with_help(format!("write {major}/{what}")),
        ))
    }
}
