//! Passes: IR blocks in, IR blocks out, one block at a time.
//!
//! Every pass lives in its own file, has a kebab-case name, an options struct
//! (serde, `deny_unknown_fields`) and a one-line summary, and is listed in [`REGISTRY`],
//! which is also where the command line gets its list of valid names.

pub mod backlash;
pub mod densify;
pub mod expand_cycles;
pub mod expand_subprograms;
pub mod extrude_rate;
pub mod feed;
pub mod heightmap;
pub mod ik;
pub mod limits;
pub mod linearize_arcs;
pub mod machine_settings;
pub mod mirror;
pub mod normalize;
pub mod order_paths;
pub mod polar_ik;
pub mod stats;
pub mod transform;
pub mod unwrap_rotary;
pub mod valve_lookahead;
pub mod verify;

use serde::de::DeserializeOwned;

use crate::diag::Diagnostic;
use crate::ir::Block;
use crate::machine::Machine;
use crate::num::print::Decimals;

/// What a pass may know about the pipeline it runs in besides its own options.
#[derive(Debug, Clone, Copy, Default)]
pub struct Context<'a> {
    /// The preset's machine, if it defines one.
    pub machine: Option<&'a Machine>,
    /// The preset's polar machine, if it defines one.
    pub polar: Option<&'a crate::machine::polar::Polar>,
    /// The precision the backend prints with (`None` for the IR dump), so a pass can
    /// compute with the numbers the controller will see.
    pub decimals: Option<Decimals>,
    /// The firmware the backend prints for, which times the program when the preset has
    /// no machine of its own (the preset's backend flavour).
    pub flavour: Option<crate::machine::Flavour>,
    /// The run-wide timing model (`--timing`), overriding the controller's and the
    /// passes' own (see [`crate::motion::resolve_timing`]).
    pub timing: Option<crate::motion::Timing>,
    /// Makes the G-code lowerer `expand-subprograms` lowers subprogram bodies with: the
    /// program that runs the passes supplies it, since passes do not depend on the
    /// frontends.
    pub relower: Option<expand_subprograms::lower::Relower>,
}

impl<'a> Context<'a> {
    /// The motion-time model a timing pass uses: the run's controller (polar, else
    /// machine), the timing by precedence (`--timing`, then the pass's `timing`), and
    /// rapids at `rapid_feed` mm/min where the controller's rule leaves their speed open.
    pub fn model(
        &self,
        timing: Option<crate::motion::Timing>,
        rapid_feed: f64,
    ) -> Result<crate::motion::Model, Diagnostic> {
        if !(rapid_feed.is_finite() && rapid_feed > 0.0) {
            return Err(Diagnostic::settings("rapid_feed must be a positive number"));
        }
        Ok(crate::motion::Model::for_machines(
            self.polar,
            self.machine,
            self.flavour,
            self.timing,
            timing,
        )
        .with_rapid_feed(rapid_feed))
    }

    /// The machine, or the error a pass that needs one reports.
    pub fn require_machine(&self, pass: &str) -> Result<&'a Machine, Diagnostic> {
        self.machine.ok_or_else(|| {
            Diagnostic::settings(format!(
                "pass `{pass}` needs a machine: use a preset with a [machine] table (for example --preset emoc-x5)"
            ))
        })
    }
}

/// Where a pass puts its output.
///
/// Diagnostics reported through [`Output::diag`] go through the cap on repeated
/// diagnostics ([`crate::diag::Flood`]): past its limit a code's diagnostics are counted,
/// not stored, so a block that a pass cuts into a million pieces with a warning each
/// holds one counter instead of a million warnings.
pub struct Output<'a> {
    pub(crate) blocks: &'a mut Vec<Block>,
    pub(crate) diags: &'a mut Vec<Diagnostic>,
    flood: crate::diag::Flood,
}

impl<'a> Output<'a> {
    /// An output writing to `blocks` and `diags`, storing every diagnostic (the pipeline
    /// uses [`Output::with_limit`]).
    pub fn new(blocks: &'a mut Vec<Block>, diags: &'a mut Vec<Diagnostic>) -> Self {
        Output::with_limit(blocks, diags, 0)
    }
    /// An output writing to `blocks` and `diags`, storing `limit` diagnostics of each code
    /// in full and counting the rest (0: storing all).
    pub fn with_limit(
        blocks: &'a mut Vec<Block>,
        diags: &'a mut Vec<Diagnostic>,
        limit: u64,
    ) -> Self {
        Output {
            blocks,
            diags,
            flood: crate::diag::Flood::new(limit),
        }
    }
    /// Passes a block on.
    pub fn push(&mut self, block: Block) {
        self.blocks.push(block);
    }
    /// Passes a whole batch on, leaving `blocks` empty.
    pub fn pass_on(&mut self, blocks: &mut Vec<Block>) {
        if self.blocks.is_empty() {
            std::mem::swap(blocks, self.blocks);
        } else {
            self.blocks.append(blocks);
        }
    }
    /// Reports a diagnostic (stored in full, or counted past the limit of its code).
    pub fn diag(&mut self, diag: Diagnostic) {
        self.flood.push(diag, self.diags);
    }
}

/// A transformation over the block stream.
///
/// The pipeline hands a pass the blocks of the input in batches, in order, and calls
/// [`Pass::finish`] once after the last one. A pass moves or edits the blocks of a batch
/// into `out` (all of them, or what it makes of them) and may hold back a bounded number
/// for look-ahead, which it must release by `finish`. Passes are `Send`: the pipeline's
/// two threads take turns running them.
///
/// A pass that only reads blocks is a [`Check`], wrapped in [`Lint`].
///
/// ```
/// use ncpost::ir::{Block, BlockKind, Span};
/// use ncpost::passes::{Output, Pass};
///
/// /// Drops comment blocks.
/// struct NoComments;
/// impl Pass for NoComments {
///     fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
///         blocks.retain(|b| !matches!(b.kind, BlockKind::Comment));
///         out.pass_on(blocks);
///     }
/// }
///
/// let mut batch = vec![Block::new(Span::default(), BlockKind::Comment)];
/// let (mut blocks, mut diags) = (Vec::new(), Vec::new());
/// NoComments.run(&mut batch, &mut Output::new(&mut blocks, &mut diags));
/// assert!(blocks.is_empty() && batch.is_empty());
/// ```
pub trait Pass: Send {
    /// Takes every block of `blocks`, in order, and puts what comes of them into `out`;
    /// `blocks` is left empty.
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>);
    /// Called once after the last batch: releases held blocks and reports summaries.
    fn finish(&mut self, _out: &mut Output<'_>) {}
}

/// A read-only check over the block stream: it reports diagnostics and never changes a
/// block. [`Lint`] makes it a [`Pass`].
pub trait Check: Send {
    /// Looks at one batch of blocks, in order.
    fn check(&mut self, blocks: &[Block], diags: &mut Vec<Diagnostic>);
    /// Called once after the last batch, for summaries.
    fn finish(&mut self, _diags: &mut Vec<Diagnostic>) {}
}

/// A [`Check`] run as a [`Pass`]: the blocks go on as they are.
pub struct Lint<C>(pub C);

impl<C: Check> Pass for Lint<C> {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        self.0.check(blocks, out.diags);
        out.pass_on(blocks);
    }
    fn finish(&mut self, out: &mut Output<'_>) {
        self.0.finish(out.diags);
    }
}

/// [`Pass::run`] for a pass that changes most blocks where they lie, one block in and the
/// same block out: `edit` changes a block in place and returns true, or returns false and
/// leaves it (and the pass) untouched; that block and the rest of the batch then go one by
/// one through `each`, which may put out any number of blocks for each.
pub fn edit_in_place<P: ?Sized>(
    pass: &mut P,
    blocks: &mut Vec<Block>,
    out: &mut Output<'_>,
    mut edit: impl FnMut(&mut P, &mut Block, &mut Vec<Diagnostic>) -> bool,
    mut each: impl FnMut(&mut P, Block, &mut Output<'_>),
) {
    let mut edited = 0;
    while let Some(block) = blocks.get_mut(edited) {
        if !edit(pass, block, out.diags) {
            break;
        }
        edited += 1;
    }
    if edited == blocks.len() {
        out.pass_on(blocks);
        return;
    }
    out.blocks.extend(blocks.drain(..edited));
    for block in blocks.drain(..) {
        each(pass, block, out);
    }
}

/// Builds a pass from its options table and the pipeline context.
pub type BuildFn = fn(&toml::Table, &Context<'_>) -> Result<Box<dyn Pass>, Diagnostic>;

/// What the registry knows about a pass.
pub struct PassInfo {
    /// Kebab-case name used in presets and on the command line.
    pub name: &'static str,
    /// One-line description.
    pub summary: &'static str,
    /// Builds the pass from its options table and the pipeline context.
    pub build: BuildFn,
    /// The default options, as TOML.
    pub defaults: fn() -> String,
}

/// Every pass, in the order `ncpost passes` lists them.
pub const REGISTRY: &[PassInfo] = &[
    verify::INFO,
    stats::INFO,
    ik::INFO,
    unwrap_rotary::INFO,
    densify::INFO,
    feed::INFO,
    limits::INFO,
    polar_ik::INFO,
    extrude_rate::INFO,
    valve_lookahead::INFO,
    machine_settings::INFO,
    linearize_arcs::INFO,
    normalize::INFO,
    heightmap::INFO,
    backlash::INFO,
    expand_subprograms::INFO,
    expand_cycles::INFO,
    mirror::INFO,
    order_paths::INFO,
    transform::INFO,
];

/// The registry entry for `name`.
pub fn lookup(name: &str) -> Option<&'static PassInfo> {
    REGISTRY.iter().find(|p| p.name == name)
}

/// Builds pass `name` with `options`.
///
/// ```
/// let opts: toml::Table = toml::from_str("rapid_feed = 5000.0").unwrap();
/// let ctx = ncpost::passes::Context::default();
/// assert!(ncpost::passes::build("stats", &opts, &ctx).is_ok());
/// assert!(ncpost::passes::build("stats", &toml::from_str("bogus = 1").unwrap(), &ctx).is_err());
/// ```
pub fn build(
    name: &str,
    options: &toml::Table,
    context: &Context<'_>,
) -> Result<Box<dyn Pass>, Diagnostic> {
    let info = lookup(name).ok_or_else(|| {
        let names: Vec<&str> = REGISTRY.iter().map(|p| p.name).collect();
        Diagnostic::settings(format!(
            "unknown pass `{name}`; the passes are: {}",
            names.join(", ")
        ))
    })?;
    (info.build)(options, context).map_err(|mut d| {
        d.message = format!("options of pass `{name}`: {}", d.message);
        d
    })
}

/// Deserialises a pass's options struct from a table.
pub fn options<T: DeserializeOwned>(table: &toml::Table) -> Result<T, Diagnostic> {
    toml::Value::Table(table.clone())
        .try_into()
        .map_err(|e: toml::de::Error| Diagnostic::settings(e.message()))
}

/// TOML text of a value (for `ncpost passes` and presets).
pub fn to_toml<T: serde::Serialize>(value: &T) -> String {
    toml::to_string(value).unwrap_or_default()
}

/// The syntax of a command-line pass spec, for error messages.
pub const SPEC_SYNTAX: &str = "--pass NAME:key=value,key=[a,b],key=\"text\"";

/// Parses a command-line pass spec `NAME[:key=value,...]` into the name and a table.
/// Values are TOML literals (`1.5`, `true`, `"text"`, `[105, 53]`); a bare word is taken
/// as a string. Commas inside brackets or quotes belong to the value.
///
/// ```
/// let (name, t) = ncpost::passes::parse_spec("stats:rapid_feed=6000,label=x").unwrap();
/// assert_eq!(name, "stats");
/// assert_eq!(t["rapid_feed"].as_integer(), Some(6000));
/// assert_eq!(t["label"].as_str(), Some("x"));
/// let (_, t) = ncpost::passes::parse_spec("polar-ik:center=[105,53],note=\"a,b\"").unwrap();
/// assert_eq!(t["center"].as_array().map(|a| a.len()), Some(2));
/// assert_eq!(t["note"].as_str(), Some("a,b"));
/// ```
pub fn parse_spec(spec: &str) -> Result<(String, toml::Table), Diagnostic> {
    let (name, rest) = spec.split_once(':').unwrap_or((spec, ""));
    let name = name.trim();
    if name.is_empty() {
        return Err(Diagnostic::settings(format!(
            "`{spec}` has no pass name; write {SPEC_SYNTAX}"
        )));
    }
    let mut table = toml::Table::new();
    for pair in split_options(rest)?
        .into_iter()
        .filter(|p| !p.trim().is_empty())
    {
        let (key, value) = pair.split_once('=').ok_or_else(|| {
            Diagnostic::settings(format!(
                "`{pair}` in `{spec}` is not key=value; write {SPEC_SYNTAX}"
            ))
        })?;
        let key = key.trim();
        let value = value.trim();
        let parsed = toml::from_str::<toml::Table>(&format!("v = {value}"))
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or_else(|| toml::Value::String(value.to_string()));
        table.insert(key.to_string(), parsed);
    }
    Ok((name.to_string(), table))
}

/// Splits the options of a pass spec at the commas outside brackets and quotes.
fn split_options(rest: &str) -> Result<Vec<&str>, Diagnostic> {
    let mut parts = Vec::new();
    let mut depth = 0usize;
    let mut quote = None;
    let mut start = 0;
    for (i, c) in rest.char_indices() {
        match (quote, c) {
            (Some(q), _) if c == q => quote = None,
            (Some(_), _) => {}
            (None, '"' | '\'') => quote = Some(c),
            (None, '[' | '{') => depth += 1,
            (None, ']' | '}') => depth = depth.saturating_sub(1),
            (None, ',') if depth == 0 => {
                parts.push(&rest[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    if quote.is_some() || depth > 0 {
        let what = if quote.is_some() {
            "a quote"
        } else {
            "a bracket"
        };
        return Err(Diagnostic::settings(format!(
            "`{rest}` leaves {what} open; write {SPEC_SYNTAX}"
        )));
    }
    parts.push(&rest[start..]);
    Ok(parts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ir::{BlockKind, Span};

    /// Numbers each block it sees in its span's length; a block on a line divisible by
    /// three is refused in place and gets a comment block put before it.
    struct Numbering {
        seen: u32,
    }

    impl Numbering {
        fn edit(&mut self, block: &mut Block) -> bool {
            if block.span.line.is_multiple_of(3) {
                return false;
            }
            self.seen += 1;
            block.span.len = self.seen;
            true
        }

        fn each(&mut self, mut block: Block, out: &mut Output<'_>) {
            if block.span.line.is_multiple_of(3) {
                out.push(Block::new(Span::default(), BlockKind::Comment));
                self.seen += 1;
                block.span.len = self.seen;
            } else {
                self.edit(&mut block);
            }
            out.push(block);
        }
    }

    impl Pass for Numbering {
        fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
            edit_in_place(self, blocks, out, |p, b, _| p.edit(b), Self::each);
        }
    }

    fn lines(lines: &[u32]) -> Vec<Block> {
        lines
            .iter()
            .map(|&line| {
                let span = Span {
                    line,
                    ..Span::default()
                };
                Block::new(span, BlockKind::Comment)
            })
            .collect()
    }

    #[test]
    fn editing_in_place_gives_what_each_block_gives() {
        for case in [
            &[1, 2, 4][..],
            &[1, 3, 4, 6, 7],
            &[3, 1, 2],
            &[],
            &[2, 1, 3],
        ] {
            let (mut by_block, mut diags) = (Vec::new(), Vec::new());
            let mut pass = Numbering { seen: 0 };
            for b in lines(case) {
                pass.each(b, &mut Output::new(&mut by_block, &mut diags));
            }
            let mut pass = Numbering { seen: 0 };
            let mut blocks = lines(case);
            let mut edited = Vec::new();
            pass.run(&mut blocks, &mut Output::new(&mut edited, &mut diags));
            assert_eq!(edited, by_block, "{case:?}");
            assert!(blocks.is_empty());
        }
        // Blocks already in the output stay first.
        let mut pass = Numbering { seen: 0 };
        let mut out = lines(&[9]);
        let mut diags = Vec::new();
        pass.run(&mut lines(&[1, 2]), &mut Output::new(&mut out, &mut diags));
        let got: Vec<(u32, u32)> = out.iter().map(|b| (b.span.line, b.span.len)).collect();
        assert_eq!(got, [(9, 0), (1, 1), (2, 2)]);
    }
}
