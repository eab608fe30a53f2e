//! `verify`: checks the IR invariants on every block and stops the run on a violation.

use serde::{Deserialize, Serialize};

use super::{Check, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::Block;
use crate::valid::Verifier;

/// Options of `verify`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {}

/// The `verify` pass.
pub struct Verify {
    verifier: Verifier,
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "verify",
    summary: "check the IR invariants (spans, finite numbers, known axes, unit tool axes)",
    build: |t, _| {
        let _: Options = super::options(t)?;
        Ok(Box::new(super::Lint(Verify { verifier: Verifier })))
    },
    defaults: || super::to_toml(&Options::default()),
};

impl Check for Verify {
    fn check(&mut self, blocks: &[Block], diags: &mut Vec<Diagnostic>) {
        for block in blocks {
            self.block(block, diags);
        }
    }
}

impl Verify {
    fn block(&mut self, block: &Block, diags: &mut Vec<Diagnostic>) {
        if let Err(d) = self.verifier.check(block) {
            diags.push(d);
        }
    }
}
