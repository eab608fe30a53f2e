//! How many blocks a call expands to, counted before any block is made: a nest of
//! `L3000` repeats is refused at its call line instead of being built block by block
//! until `max_blocks` (gigabytes later).

use std::collections::HashMap;

use super::calls::body_call;
use super::lower::Lowering;
use super::{Call, Def, Key, Options};

/// Blocks one run of each definition puts out, with its calls expanded (memoised).
pub(super) struct Sizes {
    known: HashMap<Key, u64>,
}

impl Sizes {
    pub fn new() -> Self {
        Sizes {
            known: HashMap::new(),
        }
    }

    /// The programs counted so far: each was reached from a call.
    pub fn counted(&self) -> impl Iterator<Item = &Key> {
        self.known.keys()
    }

    /// Blocks one run of `key` puts out: its lines lowered once, each block counted, a
    /// call counted as its repeat count times the size of what it calls. A recursive or
    /// missing program counts nothing (its call is an error of its own).
    pub fn of(
        &mut self,
        key: &Key,
        defs: &HashMap<Key, Def>,
        options: &Options,
        lowering: &dyn Lowering,
        visiting: &mut Vec<Key>,
    ) -> u64 {
        if let Some(&n) = self.known.get(key) {
            return n;
        }
        let Some(def) = defs.get(key) else {
            return 0;
        };
        if visiting.contains(key) || visiting.len() as u32 > options.max_depth {
            return 0;
        }
        visiting.push(key.clone());
        let mut low = lowering.body(lowering.start());
        let mut total = 0u64;
        let (mut blocks, mut diags) = (Vec::new(), Vec::new());
        for (text, span) in &def.lines {
            blocks.clear();
            diags.clear();
            low.line(text, *span, &mut blocks, &mut diags);
            for b in &blocks {
                let n = match body_call(b, text, options, lowering) {
                    Some(Call::Expand { key, count, .. }) => u64::from(count)
                        .saturating_mul(self.of(&key, defs, options, lowering, visiting)),
                    Some(Call::Bad(_)) => 0,
                    Some(Call::Opaque { .. }) | None => 1,
                };
                total = total.saturating_add(n);
            }
        }
        visiting.pop();
        self.known.insert(key.clone(), total);
        total
    }
}
