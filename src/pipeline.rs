//! The pipeline: frontend → passes → backend, block by block.

mod relay;
mod schedule;
mod verify;

pub use verify::by_default as verify_by_default;

use std::io::{BufRead, Write};

use crate::back::{self, Backend};
use crate::diag::{Diagnostic, Flood, Severity};
use crate::front::{self, Frontend};
use crate::ir::{Block, dump};
use crate::machine::RapidRule;
use crate::passes::{self, Output, Pass};
use crate::preset::{Emit, PassSpec, Preset};
use relay::{Ended, Reading};

/// An input language.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// G-code (ISO, LinuxCNC, RepRapFirmware dialects).
    Gcode,
    /// APT CL data (and NX CLSF listings).
    Cl,
    /// HPGL pen plots (EAGLE, KiCad, plotter files).
    Hpgl,
}

/// Counts of a finished run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Summary {
    /// Blocks the frontend produced.
    pub blocks_in: u64,
    /// Blocks the backend received.
    pub blocks_out: u64,
    /// Errors reported.
    pub errors: u64,
    /// Warnings reported.
    pub warnings: u64,
}

/// Builds a [`Pipeline`] from a preset, extra passes and overrides.
///
/// ```
/// use ncpost::pipeline::Pipeline;
/// use ncpost::preset::Emit;
/// let mut pipeline = Pipeline::builder()
///     .preset_name("duet-cnc").unwrap()
///     .pass("stats", toml::Table::new())
///     .emit(Emit::Rrf)
///     .build()
///     .unwrap();
/// let mut out = Vec::new();
/// let mut notes = Vec::new();
/// let summary = pipeline
///     .run_gcode("G0 X1\nG1 X2 F600\n".as_bytes(), &mut out, &mut |d| notes.push(d))
///     .unwrap();
/// assert_eq!(summary.errors, 0);
/// assert_eq!(String::from_utf8(out).unwrap(), "G21 G90\nG0 X1\nG94\nG1 X2 F600\n");
/// assert!(notes[0].message.starts_with("stats:"));
/// ```
#[derive(Default)]
pub struct Builder {
    preset: Preset,
    dump_after: Option<String>,
    dump: Option<Box<dyn Write + Send>>,
    timing: Option<crate::motion::Timing>,
    max_repeats: Option<u64>,
    verify: Option<bool>,
}

/// A configured pipeline, ready to run.
pub struct Pipeline {
    preset: Preset,
    stages: Stages,
    progress: Option<Box<dyn FnMut(u64)>>,
    /// Notes from building the pipeline, reported when it runs.
    notes: Vec<Diagnostic>,
    /// Read the printed program back and check it ([`Builder::verify`]).
    verify: verify::Mode,
}

/// The passes and the IR dump point: everything between frontend and backend.
struct Stages {
    passes: Vec<Box<dyn Pass>>,
    /// Diagnostics of one code shown in full before the rest are only counted
    /// ([`Flood`]; 0: all of them).
    max_repeats: u64,
    /// Dump point: 0 after the frontend, i + 1 after pass i.
    dump_at: Option<usize>,
    dump: Option<Box<dyn Write + Send>>,
}

impl Builder {
    /// Starts from `preset`.
    pub fn preset(mut self, preset: Preset) -> Self {
        self.preset = preset;
        self
    }

    /// Starts from a built-in preset or a preset file.
    pub fn preset_name(self, name: &str) -> Result<Self, Diagnostic> {
        Ok(self.preset(Preset::load(name)?))
    }

    /// Adds pass `name`; if the preset already has it, sets its options instead.
    pub fn pass(mut self, name: &str, options: toml::Table) -> Self {
        match self.preset.passes.iter_mut().find(|p| p.name == name) {
            Some(p) => p.options.extend(options),
            None => self.preset.passes.push(PassSpec {
                name: name.to_string(),
                options,
            }),
        }
        self
    }

    /// Sets the output format.
    pub fn emit(mut self, emit: Emit) -> Self {
        self.preset.emit = emit;
        self
    }

    /// Writes the IR dump after pass `name` (or `front`, after the frontend) to `out`.
    pub fn dump_after(mut self, name: &str, out: Box<dyn Write + Send>) -> Self {
        self.dump_after = Some(name.to_string());
        self.dump = Some(out);
        self
    }

    /// Overrides the timing model of every pass that uses the motion model
    /// (`--timing`).
    pub fn timing(mut self, timing: crate::motion::Timing) -> Self {
        self.timing = Some(timing);
        self
    }

    /// Shows `n` diagnostics of each code in full and sums up the rest in one summary
    /// per code at the end, without storing them (0, the default, shows every one; the
    /// command line uses [`crate::diag::DEFAULT_LIMIT`]).
    pub fn max_repeats(mut self, n: u64) -> Self {
        self.max_repeats = Some(n);
        self
    }

    /// Reads the printed program back as the controller reads it and checks it against
    /// the programmed path (`--verify`, see [`crate::readback`]); a violated tolerance is
    /// an error of the run. Unset: as the preset's `[verify] enabled` says, else off (the
    /// command line turns it on for presets with a `[machine]` or `[polar]` table:
    /// [`verify_by_default`]).
    pub fn verify(mut self, on: bool) -> Self {
        self.verify = Some(on);
        self
    }

    /// The preset as configured so far.
    pub fn preset_ref(&self) -> &Preset {
        &self.preset
    }

    /// Builds the passes; fails on an unknown pass, bad options or dump point.
    ///
    /// Grbl has no subprograms, and RepRapFirmware none inside one file (its `M98 P"file"`
    /// runs a macro file, which passes through): with `emit = grbl` or `rrf`,
    /// `expand-subprograms` is put first when the preset lacks it (for Grbl the run starts
    /// with a note saying so).
    pub fn build(mut self) -> Result<Pipeline, Diagnostic> {
        let mut notes = Vec::new();
        if matches!(self.preset.emit, Emit::Rrf | Emit::Grbl)
            && !self
                .preset
                .passes
                .iter()
                .any(|p| p.name == "expand-subprograms")
        {
            self.preset.passes.insert(
                0,
                PassSpec {
                    name: "expand-subprograms".into(),
                    options: toml::Table::new(),
                },
            );
            notes.extend((self.preset.emit == Emit::Grbl).then(|| Diagnostic::note(
                "grbl::expand-subprograms",
                "Grbl has no subprograms: expand-subprograms runs first (it was not in the pipeline)",
            )));
        }
        // Neither RepRapFirmware nor Grbl has canned cycles: drill them as moves, after
        // subprograms (whose bodies may hold them) are expanded.
        if matches!(self.preset.emit, Emit::Rrf | Emit::Grbl)
            && !self.preset.passes.iter().any(|p| p.name == "expand-cycles")
        {
            let at = self
                .preset
                .passes
                .iter()
                .position(|p| p.name == "expand-subprograms");
            let spec = PassSpec {
                name: "expand-cycles".into(),
                options: toml::Table::new(),
            };
            self.preset.passes.insert(at.map_or(0, |i| i + 1), spec);
        }
        self.preset.resolve_flavours();
        if let Some(m) = &self.preset.machine {
            m.check()
                .map_err(|e| Diagnostic::settings(format!("[machine]: {}", e.message)))?;
        }
        let context = passes::Context {
            machine: self.preset.machine.as_ref(),
            polar: self.preset.polar.as_ref(),
            decimals: match self.preset.emit {
                Emit::Rrf => Some(self.preset.rrf.decimals),
                Emit::Gcode => Some(self.preset.gcode.decimals),
                Emit::Grbl => Some(self.preset.grbl.decimals),
                Emit::Ir => None,
            },
            flavour: self.preset.backend_flavour(),
            timing: self.timing,
            relower: Some(gcode_relower),
        };
        let mut passes = Vec::new();
        for spec in &self.preset.passes {
            let mut options = spec.options.clone();
            // expand-subprograms lowers subprogram bodies with the frontend's options; its
            // own `input` table changes some of them.
            if spec.name == "expand-subprograms"
                && let Ok(toml::Value::Table(mut input)) =
                    toml::Value::try_from(&self.preset.gcode_input)
            {
                if let Some(toml::Value::Table(own)) = options.get("input") {
                    input.extend(own.clone());
                }
                options.insert("input".into(), toml::Value::Table(input));
            }
            passes.push(passes::build(&spec.name, &options, &context)?);
        }
        let dump_at = self.dump_point()?;
        Ok(Pipeline {
            verify: verify::mode(self.verify, &self.preset, self.timing),
            preset: self.preset,
            stages: Stages {
                passes,
                max_repeats: self.max_repeats.unwrap_or(0),
                dump_at,
                dump: self.dump,
            },
            progress: None,
            notes,
        })
    }
}

impl Builder {
    /// The dump point: 0 after the frontend, i + 1 after pass i.
    fn dump_point(&self) -> Result<Option<usize>, Diagnostic> {
        let Some(n) = &self.dump_after else {
            return Ok(None);
        };
        if n == "front" {
            return Ok(Some(0));
        }
        let at = self.preset.passes.iter().position(|p| p.name == *n);
        at.map(|i| Some(i + 1)).ok_or_else(|| {
            Diagnostic::settings(format!("--dump-after {n}: the pipeline has no pass `{n}` (use `front` for the frontend's output)"))
        })
    }
}

impl Pipeline {
    /// A builder starting from the default (empty) preset.
    pub fn builder() -> Builder {
        Builder::default()
    }

    /// The preset this pipeline was built from.
    pub fn preset(&self) -> &Preset {
        &self.preset
    }

    /// Calls `f` with the number of input bytes read, now and then during a run.
    pub fn on_progress(&mut self, f: Box<dyn FnMut(u64)>) {
        self.progress = Some(f);
    }

    /// Reads G-code from `input` and writes the preset's output format to `output`.
    /// Diagnostics go to `on_diag` in input order, a batch of blocks at a time as each
    /// batch is written (within a batch: the frontend's, then each pass's, then the
    /// backend's). `Err` only for I/O failures of the writer; input errors are counted in
    /// the summary. With [`Builder::max_repeats`] only the first few of each code come one
    /// by one, and one summary per code with the rest comes last (the counts in the
    /// summary include every one).
    ///
    /// Two threads share the work: this one reads the input while few batches are on
    /// their way; otherwise both run the passes and the backend on whichever batch waits
    /// at a free stage, each stage taking its batches in input order. At most a few
    /// batches are on their way at once, so memory stays bounded.
    pub fn run_gcode(
        &mut self,
        input: impl BufRead,
        output: impl Write + Send,
        on_diag: &mut dyn FnMut(Diagnostic),
    ) -> Result<Summary, Diagnostic> {
        self.run_source(Source::Gcode, input, output, on_diag)
    }

    /// Reads `input` in the language `source` and writes the preset's output format to
    /// `output`; otherwise as [`Pipeline::run_gcode`].
    pub fn run_source(
        &mut self,
        source: Source,
        input: impl BufRead,
        output: impl Write + Send,
        on_diag: &mut dyn FnMut(Diagnostic),
    ) -> Result<Summary, Diagnostic> {
        match source {
            Source::Gcode => {
                let parser = front::gcode::Parser::new(input, self.preset.gcode_input.clone());
                let (mut lines, lowering) = parser.into_halves();
                self.run_relay(
                    Reading::Lines(&mut lines, Box::new(lowering)),
                    output,
                    on_diag,
                )
            }
            Source::Cl => {
                let mut front = front::cl::Parser::new(input, self.preset.cl_input.clone());
                self.run_threaded(&mut front, output, on_diag)
            }
            Source::Hpgl => {
                let mut front = front::hpgl::Parser::new(input, self.preset.hpgl_input.clone());
                self.run_threaded(&mut front, output, on_diag)
            }
        }
    }

    /// Runs `front` through the passes and the preset's backend into `output` on two
    /// threads that share the passes and the backend as they go (see [`relay`]).
    pub fn run_threaded(
        &mut self,
        front: &mut dyn Frontend,
        output: impl Write + Send,
        on_diag: &mut dyn FnMut(Diagnostic),
    ) -> Result<Summary, Diagnostic> {
        self.run_relay(Reading::Blocks(front), output, on_diag)
    }

    /// [`Pipeline::run_threaded`] for what the reading thread reads.
    fn run_relay(
        &mut self,
        reading: Reading<'_>,
        output: impl Write + Send,
        on_diag: &mut dyn FnMut(Diagnostic),
    ) -> Result<Summary, Diagnostic> {
        let mut summary = Summary::default();
        let mut flood = Flood::new(self.stages.max_repeats);
        if !self.notes.is_empty() {
            let mut notes = self.notes.clone();
            report(&mut notes, on_diag, &mut summary, &mut flood);
        }
        let out = std::io::BufWriter::with_capacity(1 << 16, output);
        let (tap, mut tee) = verify::start(&self.verify, &self.preset, out);
        // The backend prints into a spool that the output stage empties into `tee`.
        let spool = relay::Spool::default();
        let mut printer = spool.clone();
        let backend = backend_for(&self.preset, &mut printer);
        let progress = &mut self.progress;
        let mut io_error = None;
        let mut deliver = |reports: Vec<Vec<Diagnostic>>, summary: &mut Summary| {
            let mut rest = Vec::new();
            for d in reports.into_iter().flatten() {
                if back::is_io_error(&d) && io_error.is_none() {
                    summary.errors += 1;
                    io_error = Some(d);
                } else {
                    rest.push(d);
                }
            }
            report(&mut rest, on_diag, summary, &mut flood);
        };
        let Ended {
            aborted,
            written,
            failed,
        } = self.stages.relay(backend, spool, &mut tee, tap).drive(
            reading,
            progress,
            &mut summary,
            &mut deliver,
        );
        summary.blocks_out = written;
        if let Some(d) = &mut self.stages.dump {
            let _ = d.flush();
        }
        // The readback of a run that failed already would only repeat its errors.
        let (readback, mut out) = tee.finish();
        if !aborted && !failed && summary.errors == 0 {
            deliver(vec![readback], &mut summary);
        }
        if aborted {
            deliver(
                vec![vec![
                    Diagnostic::error(
                        "back::panic",
                        "a pass or the backend stopped unexpectedly: the output is incomplete",
                    )
                    .with_help("this is a bug in ncpost; please report it with the input"),
                ]],
                &mut summary,
            );
        } else if !failed && let Err(e) = out.flush() {
            deliver(vec![vec![back::io_error(e)]], &mut summary);
        }
        for d in flood.summaries() {
            on_diag(d);
        }
        match io_error {
            Some(d) => Err(d),
            None => Ok(summary),
        }
    }

    /// Reads `input` in the language `source` and runs it through the passes into `back`,
    /// on this thread (for backends that are not writers, such as plots).
    pub fn run_into(
        &mut self,
        source: Source,
        input: impl BufRead,
        back: &mut dyn Backend,
        on_diag: &mut dyn FnMut(Diagnostic),
    ) -> Summary {
        match source {
            Source::Gcode => {
                let mut front = front::gcode::Parser::new(input, self.preset.gcode_input.clone());
                self.run(&mut front, back, on_diag)
            }
            Source::Cl => {
                let mut front = front::cl::Parser::new(input, self.preset.cl_input.clone());
                self.run(&mut front, back, on_diag)
            }
            Source::Hpgl => {
                let mut front = front::hpgl::Parser::new(input, self.preset.hpgl_input.clone());
                self.run(&mut front, back, on_diag)
            }
        }
    }

    /// Runs `front` through the passes into `back`, on this thread.
    pub fn run(
        &mut self,
        front: &mut dyn Frontend,
        back: &mut dyn Backend,
        on_diag: &mut dyn FnMut(Diagnostic),
    ) -> Summary {
        let mut summary = Summary::default();
        let mut flood = Flood::new(self.stages.max_repeats);
        let mut diags = Vec::new();
        let mut written = 0u64;
        let mut deliver = |blocks: &mut Vec<Block>, diags: &mut Vec<Diagnostic>| {
            written += blocks.len() as u64;
            let _ = back.write_batch(blocks, diags);
            blocks.clear();
        };
        let mut cur = Vec::new();
        let mut next = Vec::new();
        let mut counter = 0u64;
        while let Some(block) = front.next_block(&mut diags) {
            summary.blocks_in += 1;
            cur.push(block);
            self.stages
                .whole()
                .flow(0, &mut cur, &mut next, &mut diags, &mut deliver);
            if !diags.is_empty() {
                report(&mut diags, on_diag, &mut summary, &mut flood);
            }
            counter += 1;
            if counter >= 1 << 14 {
                counter = 0;
                if let Some(p) = &mut self.progress {
                    p(front.bytes_read());
                }
            }
        }
        self.stages.whole().finish(&mut diags, &mut deliver);
        summary.blocks_out = written;
        if let Err(d) = back.finish() {
            diags.push(d);
        }
        report(&mut diags, on_diag, &mut summary, &mut flood);
        for d in flood.summaries() {
            on_diag(d);
        }
        summary
    }
}

/// The preset's backend, writing to `out`.
fn backend_for<'a>(
    preset: &'a Preset,
    out: &'a mut (impl Write + Send),
) -> Box<dyn Backend + Send + 'a> {
    match preset.emit {
        Emit::Rrf => Box::new(
            back::rrf::Writer::new(out, &preset.rrf).with_feed_on_rapids(feed_on_rapids(preset)),
        ),
        Emit::Gcode => Box::new(back::gcode::Writer::new(out, &preset.gcode)),
        Emit::Grbl => Box::new(back::grbl::Writer::new(out, &preset.grbl)),
        Emit::Ir => Box::new(back::ir::Writer::new(out)),
    }
}

/// Whether the controller runs `G0` at the modal F (an FDM firmware): then every rapid
/// is printed with the F it was timed at.
fn feed_on_rapids(preset: &Preset) -> bool {
    preset
        .controller()
        .is_some_and(|c| c.rapid_rule() == RapidRule::ModalFeed)
}

impl Stages {
    /// All passes as one part.
    fn whole(&mut self) -> Part<'_> {
        Part {
            max_repeats: self.max_repeats,
            passes: &mut self.passes,
            dump_at: self.dump_at,
            dump: self.dump.as_mut(),
        }
    }
}

/// Runs `pass` on the blocks in `cur`, leaving what it passes on in `cur` (`next` is
/// scratch; a pass that keeps the batch hands the same vector back).
fn run_pass(
    pass: &mut Box<dyn Pass>,
    cur: &mut Vec<Block>,
    next: &mut Vec<Block>,
    diags: &mut Vec<Diagnostic>,
    max_repeats: u64,
) {
    next.clear();
    pass.run(cur, &mut Output::with_limit(next, diags, max_repeats));
    std::mem::swap(cur, next);
}

/// Lets `pass` release what it holds into `blocks` after the last batch. What it reports
/// then sums up the run (as `limits` sums up the blocks past a limit it did not report
/// one by one), so the cap on repeated diagnostics leaves it whole.
fn finish_pass(
    pass: &mut Box<dyn Pass>,
    blocks: &mut Vec<Block>,
    diags: &mut Vec<Diagnostic>,
    max_repeats: u64,
) {
    let before = diags.len();
    pass.finish(&mut Output::with_limit(blocks, diags, max_repeats));
    for d in &mut diags[before..] {
        d.sums_up = true;
    }
}

/// Writes `blocks` as IR text to the dump.
fn dump_blocks(out: &mut Box<dyn Write + Send>, blocks: &[Block]) {
    let mut s = String::new();
    for b in blocks {
        dump::write_block(&mut s, b);
        s.push('\n');
    }
    let _ = out.write_all(s.as_bytes());
}

/// The passes with the dump point, for the single-threaded [`Pipeline::run`].
struct Part<'a> {
    /// As [`Stages::max_repeats`].
    max_repeats: u64,
    passes: &'a mut [Box<dyn Pass>],
    /// Dump point (0 after the frontend, i + 1 after pass i).
    dump_at: Option<usize>,
    dump: Option<&'a mut Box<dyn Write + Send>>,
}

impl Part<'_> {
    /// Sends the blocks in `cur` through this part's passes `from..` (local index) and on
    /// to `deliver`.
    fn flow(
        &mut self,
        from: usize,
        cur: &mut Vec<Block>,
        next: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
        deliver: &mut dyn FnMut(&mut Vec<Block>, &mut Vec<Diagnostic>),
    ) {
        if self.dump_at == Some(from) {
            self.dump_blocks(cur);
        }
        for i in from..self.passes.len() {
            run_pass(&mut self.passes[i], cur, next, diags, self.max_repeats);
            if self.dump_at == Some(i + 1) {
                self.dump_blocks(cur);
            }
        }
        deliver(cur, diags);
    }

    /// Lets every pass release what it holds, in order, through the passes after it.
    fn finish(
        &mut self,
        diags: &mut Vec<Diagnostic>,
        deliver: &mut dyn FnMut(&mut Vec<Block>, &mut Vec<Diagnostic>),
    ) {
        let mut cur = Vec::new();
        let mut next = Vec::new();
        for i in 0..self.passes.len() {
            cur.clear();
            finish_pass(&mut self.passes[i], &mut cur, diags, self.max_repeats);
            self.flow(i + 1, &mut cur, &mut next, diags, deliver);
        }
        if let Some(d) = &mut self.dump {
            let _ = d.flush();
        }
    }

    fn dump_blocks(&mut self, blocks: &[Block]) {
        if let Some(out) = &mut self.dump {
            dump_blocks(out, blocks);
        }
    }
}

/// Counts `diags` into `summary` (each for every diagnostic it stands for) and hands
/// them to `on_diag`, but for what `flood` holds back to sum up at the end of the run.
fn report(
    diags: &mut Vec<Diagnostic>,
    on_diag: &mut dyn FnMut(Diagnostic),
    summary: &mut Summary,
    flood: &mut Flood,
) {
    for d in diags.drain(..) {
        let n = d.repeats.as_ref().map_or(1, |t| t.count);
        match d.severity {
            Severity::Error => summary.errors += n,
            Severity::Warning => summary.warnings += n,
            Severity::Note => {}
        }
        if let Some(d) = flood.admit(d) {
            on_diag(d);
        }
    }
}

/// Compiles G-code text with a preset and returns the output text, or every diagnostic
/// if there was an error.
///
/// ```
/// let preset = ncpost::preset::Preset::builtin("default").unwrap();
/// let out = ncpost::pipeline::compile_str("G0 X0\nG91\nG0 X1\nG0 X1\n", &preset).unwrap();
/// assert_eq!(out, "G21 G90\nG0 X0\nG0 X1\nG0 X2\n");
/// ```
pub fn compile_str(src: &str, preset: &Preset) -> Result<String, Vec<Diagnostic>> {
    let mut pipeline = Pipeline::builder()
        .preset(preset.clone())
        .build()
        .map_err(|e| vec![e])?;
    let mut diags = Vec::new();
    let mut out = Vec::new();
    let summary = pipeline
        .run_gcode(src.as_bytes(), &mut out, &mut |d| diags.push(d))
        .map_err(|d| vec![d])?;
    if summary.errors > 0 {
        return Err(diags);
    }
    Ok(String::from_utf8_lossy(&out).into_owned())
}
/// The G-code lowerer for `expand-subprograms`, made for the frontend options in the
/// table `input`: the [`passes::Context::relower`] of every pipeline (passes do not
/// depend on the frontends; this adapter is where they meet).
///
/// ```
/// let lowering = ncpost::pipeline::gcode_relower(&toml::Table::new()).unwrap();
/// assert!(lowering.oword_call("o100 call").is_some());
/// let bad: toml::Table = toml::from_str("dwell_p_seconds = true").unwrap();
/// assert!(ncpost::pipeline::gcode_relower(&bad).is_err());
/// ```
pub fn gcode_relower(
    input: &toml::Table,
) -> Result<Box<dyn passes::expand_subprograms::lower::Lowering>, Diagnostic> {
    let options: front::gcode::Options =
        toml::Value::Table(input.clone())
            .try_into()
            .map_err(|e: toml::de::Error| {
                Diagnostic::settings(format!("expand-subprograms input: {}", e.message()))
            })?;
    Ok(Box::new(GcodeLowering(options)))
}

/// [`gcode_relower`]'s lowerer: the G-code frontend's, with its options.
struct GcodeLowering(front::gcode::Options);

/// A body being lowered by the G-code frontend.
struct GcodeBody(front::gcode::Lowerer);

impl passes::expand_subprograms::lower::Lowering for GcodeLowering {
    fn start(&self) -> crate::ir::Modal {
        front::gcode::Lowerer::new(self.0.clone()).state()
    }
    fn body(
        &self,
        state: crate::ir::Modal,
    ) -> Box<dyn passes::expand_subprograms::lower::BodyLowerer + '_> {
        Box::new(GcodeBody(front::gcode::Lowerer::for_body(
            self.0.clone(),
            state,
        )))
    }
    fn oword_call(&self, text: &str) -> Option<passes::expand_subprograms::lower::OwordCall> {
        front::gcode::oword_call(text).map(|c| passes::expand_subprograms::lower::OwordCall {
            label: c.label,
            simple: c.simple,
            at: c.at,
        })
    }
}

impl passes::expand_subprograms::lower::BodyLowerer for GcodeBody {
    fn line(
        &mut self,
        text: &str,
        span: crate::ir::Span,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        self.0.line(text, span, out, diags);
    }
    fn state(&self) -> crate::ir::Modal {
        self.0.state()
    }
    fn set_state(&mut self, state: crate::ir::Modal) {
        self.0.set_state(state);
    }
}

/// As a backend, `stats` counts what reaches the end of a pipeline (`ncpost stats`).
impl Backend for passes::stats::Stats {
    fn write_block(
        &mut self,
        block: &Block,
        _diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        self.count(block);
        Ok(())
    }

    fn finish(&mut self) -> Result<(), Diagnostic> {
        self.end();
        Ok(())
    }
}
