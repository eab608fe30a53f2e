//! Expanding calls: bodies lowered in the caller's state, recursively, within the
//! limits of the options.

use std::collections::{HashMap, HashSet};

use super::calls::{body_call, main_call};
use super::lower::{BodyLowerer, Lowering};
use super::size::Sizes;
use super::{Call, Def, Key, Options, Reach};
use crate::diag::Diagnostic;
use crate::ir::{Block, Modal};
use crate::passes::Output;

/// Puts a definition's blocks back in the output when a call that passed through may need
/// it; otherwise leaves it out (with a warning when nothing called it).
fn emit_definition(
    blocks: &[Block],
    defs: &HashMap<Key, Def>,
    key: &Key,
    keep: bool,
    used: bool,
    diags: &mut Vec<Diagnostic>,
    out: &mut Output<'_>,
) {
    let def = &defs[key];
    if keep {
        for b in &blocks[def.blocks.clone()] {
            out.push(b.clone());
        }
    } else if !used {
        let header = &blocks[def.blocks.start];
        diags.push(
            Diagnostic::warning(
                "subprograms::unused",
                format!("subprogram {} is never called; it is left out", key.name()),
            )
            .at_span(header.span)
            .with_help("remove it from the program, or call it"),
        );
    }
}

/// A call's place, for diagnostics.
pub(super) struct Site {
    pub text: String,
    pub line: u32,
    pub at: (usize, usize),
}

impl Site {
    fn point(&self, d: Diagnostic) -> Diagnostic {
        d.at_bytes(self.line, &self.text, self.at.0, self.at.1)
    }
}

/// Where a body line stands: its text and line, its nesting and the call from the main
/// program it is part of.
struct Place<'t> {
    text: &'t String,
    line: u32,
    depth: u32,
    site: &'t Site,
}

/// Expands calls recursively.
pub(super) struct Expander<'a> {
    pub defs: &'a HashMap<Key, Def>,
    pub options: &'a Options,
    /// The G-code lowerer bodies are lowered with.
    pub lowering: &'a dyn Lowering,
    /// Definitions calls that pass through may reach.
    pub reached: HashSet<Reach>,
    /// Programs expanded at least once.
    pub used: HashSet<Key>,
    /// Diagnostics already reported (a body repeated 625 times warns once).
    seen: HashSet<(&'static str, u32, u32, String)>,
    produced: u64,
    pub diags: Vec<Diagnostic>,
    /// `max_blocks` was exceeded: stop producing.
    failed: bool,
    /// The blocks one run of each program makes, counted before expanding.
    sizes: Sizes,
}

impl<'a> Expander<'a> {
    /// An expander of the calls to `defs`.
    pub fn new(
        defs: &'a HashMap<Key, Def>,
        options: &'a Options,
        lowering: &'a dyn Lowering,
    ) -> Self {
        Expander {
            defs,
            options,
            lowering,
            reached: HashSet::new(),
            used: HashSet::new(),
            seen: HashSet::new(),
            produced: 0,
            diags: Vec::new(),
            failed: false,
            sizes: Sizes::new(),
        }
    }

    /// Whether definition `key` stays where it was: a call that passed through may reach it.
    fn keeps(&self, key: &Key) -> bool {
        self.reached.contains(&Reach::One(key.clone()))
            || match key {
                Key::Fanuc(_) => self.reached.contains(&Reach::AllFanuc),
                Key::Oword(_) => self.reached.contains(&Reach::AllOword),
            }
    }

    /// Adds what the calls inside kept definitions reach (a kept `o3` whose body calls
    /// `o2`), until nothing more is added: the printed program must not call a subprogram
    /// it left out.
    fn close_reach(&mut self, blocks: &[Block], def_at: &[(usize, Key)]) {
        loop {
            let mut added = false;
            for (_, key) in def_at {
                if !self.keeps(key) {
                    continue;
                }
                for b in &blocks[self.defs[key].blocks.clone()] {
                    let reach = match main_call(b, self.options, self.lowering) {
                        Some((Call::Expand { key, .. }, _)) => Reach::One(key),
                        Some((Call::Opaque { reach, .. }, _)) => reach,
                        _ => continue,
                    };
                    added |= self.reached.insert(reach);
                }
            }
            if !added {
                return;
            }
        }
    }

    /// Puts out the expanded main program, with the definitions a call that passed
    /// through may reach where they stood, and the diagnostics.
    pub(super) fn put_out(
        mut self,
        blocks: &[Block],
        expanded: Vec<Block>,
        def_at: &[(usize, Key)],
        out: &mut Output<'_>,
    ) {
        let defs = self.defs;
        self.close_reach(blocks, def_at);
        let kept: HashSet<&Key> = def_at
            .iter()
            .map(|(_, key)| key)
            .filter(|key| self.keeps(key))
            .collect();
        let used = &self.used;
        let diags = &mut self.diags;
        let mut definition = |key: &Key, out: &mut Output<'_>| {
            let keep = kept.contains(key);
            emit_definition(blocks, defs, key, keep, used.contains(key), diags, out);
        };
        let mut next = def_at.iter().peekable();
        for (n, b) in expanded.into_iter().enumerate() {
            while let Some((_, key)) = next.next_if(|(at, _)| *at == n) {
                definition(key, out);
            }
            out.push(b);
        }
        for (_, key) in next {
            definition(key, out);
        }
        for d in self.diags {
            out.diag(d);
        }
    }

    /// Reports `d` unless the same was reported already.
    pub fn report(&mut self, d: Diagnostic) {
        let loc = d.location.as_ref().map_or((0, 0), |l| (l.line, l.column));
        if self.seen.insert((d.code, loc.0, loc.1, d.message.clone())) {
            self.diags.push(d);
        }
    }

    /// Expands `key` `count` times starting in `state`; returns the state it leaves.
    #[allow(clippy::too_many_arguments)]
    pub fn call(
        &mut self,
        key: &Key,
        count: u32,
        state: Modal,
        depth: u32,
        stack: &mut Vec<Key>,
        site: &Site,
        out: &mut Vec<Block>,
    ) -> Result<Modal, ()> {
        let def = self.callable(key, depth, stack, site)?;
        if count == 0 {
            self.report(
                site.point(Diagnostic::note(
                    "subprograms::skipped",
                    format!(
                        "{} is called to run no time (L0): the call is skipped",
                        key.name()
                    ),
                ))
                .with_label("skipped, as LinuxCNC does")
                .with_help("nothing runs and nothing moves here; remove the call if that is meant"),
            );
        }
        self.fits(key, count, site)?;
        self.used.insert(key.clone());
        stack.push(key.clone());
        let lowering = self.lowering;
        let mut low = lowering.body(state);
        for _ in 0..count {
            for (text, span) in &def.lines {
                let mut blocks = Vec::new();
                let mut d = Vec::new();
                low.line(text, *span, &mut blocks, &mut d);
                for d in d {
                    self.report(d);
                }
                let place = Place {
                    text,
                    line: span.line,
                    depth,
                    site,
                };
                for b in blocks {
                    self.body_block(b, &place, &mut *low, stack, out)?;
                }
            }
        }
        stack.pop();
        Ok(low.state())
    }

    /// `Err` after reporting it when `count` runs of `key` would take the expansion over
    /// `max_blocks`: counted before a block is made.
    fn fits(&mut self, key: &Key, count: u32, site: &Site) -> Result<(), ()> {
        let one = self
            .sizes
            .of(key, self.defs, self.options, self.lowering, &mut Vec::new());
        let expected = one.saturating_mul(u64::from(count));
        if self.produced.saturating_add(expected) <= self.options.max_blocks {
            return Ok(());
        }
        // Called, though refused: not "never called".
        self.used.extend(self.sizes.counted().cloned());
        self.report(site.point(
            Diagnostic::error(
                "subprograms::size",
                format!(
                    "this call would produce about {expected} blocks ({count} x {one} of {}, calls inside counted), more than max_blocks = {}",
                    key.name(),
                    self.options.max_blocks
                ),
            )
            .with_label("too many blocks")
            .with_help("check the repeat counts (L) here and in the subprograms it calls; raise the pass option max_blocks if the program is meant to be this long"),
        ));
        Err(())
    }

    /// The definition `key` calls, or `Err` after reporting why it cannot be expanded
    /// here (missing, recursive, too deep, returning early).
    fn callable(
        &mut self,
        key: &Key,
        depth: u32,
        stack: &[Key],
        site: &Site,
    ) -> Result<&'a Def, ()> {
        let Some(def) = self.defs.get(key) else {
            let mut help = match key {
                Key::Fanuc(n) => {
                    format!("define it after the main program: a line `O{n}`, its body, then `M99`")
                }
                Key::Oword(l) => {
                    format!("define it with `o{l} sub` ... `o{l} endsub` in the same file")
                }
            };
            if let Key::Fanuc(n) = key
                && !self.options.packed_count
                && *n >= 10_000
                && self.defs.contains_key(&Key::Fanuc(n % 10_000))
            {
                help.push_str(&format!(
                    "; or, if P{n} means {} times O{}, set the pass option packed_count = true",
                    n / 10_000,
                    n % 10_000
                ));
            }
            self.report(
                site.point(
                    Diagnostic::error(
                        "subprograms::missing",
                        format!("subprogram {} is not defined in this program", key.name()),
                    )
                    .with_label("called here")
                    .with_help(help),
                ),
            );
            return Err(());
        };
        if stack.contains(key) {
            let mut chain: Vec<String> = stack.iter().map(Key::name).collect();
            chain.push(key.name());
            self.report(site.point(
                Diagnostic::error(
                    "subprograms::recursion",
                    format!("subprogram {} calls itself: {}", key.name(), chain.join(" -> ")),
                )
                .with_label("recursive call")
                .with_help("a subprogram cannot be inlined into itself; end the recursion with a loop count (L) instead"),
            ));
            return Err(());
        }
        if depth > self.options.max_depth {
            self.report(site.point(
                Diagnostic::error(
                    "subprograms::depth",
                    format!(
                        "calls nest {depth} levels deep here; the limit is {}",
                        self.options.max_depth
                    ),
                )
                .with_label("one level too many")
                .with_help("controllers allow 10 levels (Fanuc, LinuxCNC); flatten the calls, or raise the pass option max_depth"),
            ));
            return Err(());
        }
        if let Some((text, span, (s, e))) = &def.early_return {
            self.report(
                Diagnostic::error(
                    "subprograms::return",
                    format!("{} returns early; the call cannot be inlined", key.name()),
                )
                .at_bytes(span.line, text, *s, *e)
                .with_label("early return")
                .with_help("restructure the subroutine so it ends at its endsub, or leave it to the controller (remove the pass)"),
            );
            return Err(());
        }
        Ok(def)
    }

    /// One block of a body line: a call is expanded, anything else is put out.
    fn body_block(
        &mut self,
        b: Block,
        place: &Place<'_>,
        low: &mut dyn BodyLowerer,
        stack: &mut Vec<Key>,
        out: &mut Vec<Block>,
    ) -> Result<(), ()> {
        if self.failed {
            return Err(());
        }
        match body_call(&b, place.text, self.options, self.lowering) {
            Some(Call::Expand { key, count, at }) => {
                let inner = Site {
                    text: place.text.clone(),
                    line: place.line,
                    at,
                };
                let end = self.call(
                    &key,
                    count,
                    low.state(),
                    place.depth + 1,
                    stack,
                    &inner,
                    out,
                )?;
                low.set_state(end);
            }
            Some(Call::Opaque { warning, reach }) => {
                self.report(warning);
                self.reached.insert(reach);
                out.push(b);
            }
            Some(Call::Bad(d)) => {
                self.report(d);
                return Err(());
            }
            None => {
                self.produced += 1;
                if self.produced > self.options.max_blocks {
                    self.failed = true;
                    self.report(place.site.point(
                        Diagnostic::error(
                            "subprograms::size",
                            format!(
                                "the expansion produces more than {} blocks",
                                self.options.max_blocks
                            ),
                        )
                        .with_label("in this call")
                        .with_help("check the repeat counts; raise the pass option max_blocks if the program is meant to be this long"),
                    ));
                    return Err(());
                }
                out.push(b);
            }
        }
        Ok(())
    }

    /// After a call from the main program: the lines after it that the frontend read
    /// in the modes before it (`depends`) need the body to leave those modes in force.
    /// (The moves it could not read, the distance or motion mode unknown after the call,
    /// are read again in the modes the body left.)
    pub fn check_modes(
        &mut self,
        key: &Key,
        start: &Modal,
        end: &Modal,
        site: &Site,
        depends: super::Depends,
    ) {
        let mut changed = Vec::new();
        let units = depends.units;
        if units && start.inch != end.inch {
            changed.push(if end.inch { "G20 (inches)" } else { "G21 (mm)" });
        }
        if depends.distance && start.relative != end.relative {
            changed.push(if end.relative { "G91" } else { "G90" });
        }
        if units && start.relative_e != end.relative_e {
            changed.push(if end.relative_e { "M83" } else { "M82" });
        }
        if units && start.feed_mode != end.feed_mode {
            changed.push(match end.feed_mode {
                crate::ir::FeedMode::InverseTime => "G93",
                crate::ir::FeedMode::PerMinute => "G94",
                crate::ir::FeedMode::PerRevolution => "G95",
            });
        }
        if !changed.is_empty() {
            self.report(site.point(
                Diagnostic::error(
                    "subprograms::modes",
                    format!(
                        "{} returns with {} in force, but the lines after this call were read in the modes it was called in",
                        key.name(),
                        changed.join(", ")
                    ),
                )
                .with_label("modes differ after this call")
                .with_help(format!(
                    "end {} in the modes it starts in (restore them before its M99 / endsub)",
                    key.name()
                )),
            ));
        } else if units && start.plane != end.plane {
            self.report(
                site.point(
                    Diagnostic::warning(
                        "subprograms::modes",
                        format!(
                            "{} returns in plane {}, but the arcs after this call were read in {}",
                            key.name(),
                            end.plane.gcode(),
                            start.plane.gcode()
                        ),
                    )
                    .with_label("plane differs after this call")
                    .with_help("restore the plane before the end of the subprogram"),
                ),
            );
        }
    }
}
