//! The pipeline: frontend → passes → backend, block by block.

use std::io::{BufRead, Write};

use crate::back::{self, Backend};
use crate::diag::{Diagnostic, Severity};
use crate::front::{self, Frontend};
use crate::ir::{Block, dump};
use crate::passes::{self, Output, Pass};
use crate::preset::{Emit, PassSpec, Preset};

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
}

/// A configured pipeline, ready to run.
pub struct Pipeline {
    preset: Preset,
    stages: Stages,
    progress: Option<Box<dyn FnMut(u64)>>,
    /// Notes from building the pipeline, reported when it runs.
    notes: Vec<Diagnostic>,
}

/// The passes and the IR dump point: everything between frontend and backend.
struct Stages {
    passes: Vec<Box<dyn Pass>>,
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
    pub fn preset_name(self, name: &str) -> Result<Self, String> {
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

    /// The preset as configured so far.
    pub fn preset_ref(&self) -> &Preset {
        &self.preset
    }

    /// Builds the passes; fails on an unknown pass, bad options or dump point.
    ///
    /// Grbl has no subprograms: with `emit = grbl`, `expand-subprograms` is put first
    /// when the preset lacks it, and the run starts with a note saying so.
    pub fn build(mut self) -> Result<Pipeline, String> {
        let mut notes = Vec::new();
        if self.preset.emit == Emit::Grbl
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
            notes.push(Diagnostic::note(
                "grbl::expand-subprograms",
                "Grbl has no subprograms: expand-subprograms runs first (it was not in the pipeline)",
            ));
        }
        if let Some(m) = &self.preset.machine {
            m.check().map_err(|e| format!("[machine]: {e}"))?;
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
            timing: self.timing,
        };
        let mut passes = Vec::new();
        for spec in &self.preset.passes {
            let mut options = spec.options.clone();
            // expand-subprograms lowers subprogram bodies with the frontend's options.
            if spec.name == "expand-subprograms"
                && !options.contains_key("input")
                && let Ok(toml::Value::Table(t)) = toml::Value::try_from(&self.preset.gcode_input)
            {
                options.insert("input".into(), toml::Value::Table(t));
            }
            passes.push(passes::build(&spec.name, &options, &context)?);
        }
        let dump_at = match &self.dump_after {
            None => None,
            Some(n) if n == "front" => Some(0),
            Some(n) => Some(
                self.preset
                    .passes
                    .iter()
                    .position(|p| p.name == *n)
                    .map(|i| i + 1)
                    .ok_or_else(|| {
                        format!("--dump-after {n}: the pipeline has no pass `{n}` (use `front` for the frontend's output)")
                    })?,
            ),
        };
        Ok(Pipeline {
            preset: self.preset,
            stages: Stages {
                passes,
                dump_at,
                dump: self.dump,
            },
            progress: None,
            notes,
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
    /// Frontend diagnostics go to `on_diag` as they occur, those of the passes and the
    /// backend at the end. `Err` only for I/O failures of the writer; input errors are
    /// counted in the summary.
    ///
    /// Two threads share the work: this one reads and lowers the input; a second one runs
    /// the passes and the backend. Batches of blocks go between them through a bounded
    /// channel, so memory stays bounded.
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
                let mut front = front::gcode::Parser::new(input, self.preset.gcode_input.clone());
                self.run_threaded(&mut front, output, on_diag)
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

    /// Runs `front` through the passes and the preset's backend into `output`, with the
    /// passes and the backend on a second thread.
    pub fn run_threaded(
        &mut self,
        front: &mut dyn Frontend,
        output: impl Write + Send,
        on_diag: &mut dyn FnMut(Diagnostic),
    ) -> Result<Summary, Diagnostic> {
        const BATCH: usize = 1024;
        let mut summary = Summary::default();
        if !self.notes.is_empty() {
            let mut notes = self.notes.clone();
            report(&mut notes, on_diag, &mut summary);
        }
        let preset = &self.preset;
        let share = self.stages.front_share();
        let (mut front_part, mut back_part) = self.stages.split(share);
        let progress = &mut self.progress;
        let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<Block>>(2);
        // Emptied batches go back to the frontend: a batch's buffer grows to what the
        // passes make of it once, not on every batch.
        let (recycle_tx, recycle) = std::sync::mpsc::sync_channel::<Vec<Block>>(4);
        let (blocks_out, back_diags) = std::thread::scope(|scope| {
            let worker = scope.spawn(move || {
                let mut out = std::io::BufWriter::with_capacity(1 << 16, output);
                let mut diags = Vec::new();
                let mut written = 0u64;
                // Set by the first write error (a full disk, a closed pipe): nothing more
                // is written, and the frontend stops at its next batch.
                let failed = std::cell::Cell::new(false);
                {
                    let mut backend: Box<dyn Backend + '_> = match preset.emit {
                        Emit::Rrf => Box::new(back::rrf::Writer::new(&mut out, &preset.rrf)),
                        Emit::Gcode => Box::new(back::gcode::Writer::new(&mut out, &preset.gcode)),
                        Emit::Grbl => Box::new(back::grbl::Writer::new(&mut out, &preset.grbl)),
                        Emit::Ir => Box::new(back::ir::Writer::new(&mut out)),
                    };
                    let mut deliver = |blocks: &mut Vec<Block>, diags: &mut Vec<Diagnostic>| {
                        if !failed.get() {
                            written += blocks.len() as u64;
                            let ok = back::write_each(backend.as_mut(), blocks, diags);
                            failed.set(ok.is_err());
                        }
                        blocks.clear();
                    };
                    let mut next = Vec::with_capacity(BATCH);
                    for mut batch in rx.iter() {
                        back_part.flow(0, &mut batch, &mut next, &mut diags, &mut deliver);
                        if failed.get() {
                            break;
                        }
                        batch.clear();
                        // A full or closed channel just drops the buffer.
                        let _ = recycle_tx.try_send(batch);
                    }
                    // A closed channel stops the frontend.
                    drop(rx);
                    if !failed.get() {
                        back_part.finish(&mut diags, &mut deliver);
                        if let Err(d) = backend.finish() {
                            diags.push(d);
                        }
                    }
                }
                if !failed.get()
                    && let Err(e) = out.flush()
                {
                    diags.push(back::io_error(e));
                }
                (written, diags)
            });
            let mut diags = Vec::new();
            let mut counter = 0u64;
            let mut next = Vec::with_capacity(BATCH);
            // What the frontend's share of the passes produced, ready to send.
            let mut ready: Vec<Block> = Vec::with_capacity(BATCH);
            let mut open = true;
            let mut batch = Vec::with_capacity(BATCH);
            loop {
                batch.clear();
                front.next_batch(&mut batch, BATCH, &mut diags);
                let end = batch.is_empty();
                summary.blocks_in += batch.len() as u64;
                counter += batch.len() as u64;
                {
                    // Taking the whole batch when nothing is waiting saves copying it
                    // (the usual case: the G-code pipeline has no passes on this side).
                    let mut send = |blocks: &mut Vec<Block>, _: &mut Vec<Diagnostic>| {
                        if ready.is_empty() {
                            std::mem::swap(&mut ready, blocks);
                        } else {
                            ready.append(blocks);
                        }
                    };
                    if end {
                        front_part.finish(&mut diags, &mut send);
                    } else {
                        front_part.flow(0, &mut batch, &mut next, &mut diags, &mut send);
                    }
                }
                if !diags.is_empty() {
                    report(&mut diags, on_diag, &mut summary);
                }
                if counter >= 1 << 14 {
                    counter = 0;
                    if let Some(p) = progress.as_mut() {
                        p(front.bytes_read());
                    }
                }
                let empty = recycle
                    .try_recv()
                    .unwrap_or_else(|_| Vec::with_capacity(BATCH));
                let out = std::mem::replace(&mut ready, empty);
                // A closed channel means the worker stopped; its error comes at join.
                if !out.is_empty() && open && tx.send(out).is_err() {
                    open = false;
                }
                if end || !open {
                    break;
                }
            }
            drop(tx);
            worker.join().unwrap_or_else(|_| {
                (
                    0,
                    vec![Diagnostic::error(
                        "back::panic",
                        "the backend stopped unexpectedly",
                    )],
                )
            })
        });
        summary.blocks_out = blocks_out;
        let mut io_error = None;
        for d in back_diags {
            if back::is_io_error(&d) && io_error.is_none() {
                summary.errors += 1;
                io_error = Some(d);
            } else {
                report(&mut vec![d], on_diag, &mut summary);
            }
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
        let mut diags = Vec::new();
        let mut written = 0u64;
        let mut deliver = |blocks: &mut Vec<Block>, diags: &mut Vec<Diagnostic>| {
            written += blocks.len() as u64;
            let _ = back::write_each(back, blocks, diags);
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
                report(&mut diags, on_diag, &mut summary);
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
        report(&mut diags, on_diag, &mut summary);
        summary
    }
}

impl Stages {
    /// All passes as one part.
    fn whole(&mut self) -> Part<'_> {
        Part {
            passes: &mut self.passes,
            first: 0,
            dump_at: self.dump_at,
            dump: self.dump.as_mut(),
            last: true,
        }
    }

    /// Passes `..k` and `k..` as two parts, for two threads. The dump point goes to the
    /// part it falls in (a dump between the parts is written by the second).
    fn split(&mut self, k: usize) -> (Part<'_>, Part<'_>) {
        let (a, b) = self.passes.split_at_mut(k);
        let (dump_a, dump_b) = match self.dump_at {
            Some(p) if p < k => (self.dump.as_mut(), None),
            _ => (None, self.dump.as_mut()),
        };
        (
            Part {
                passes: a,
                first: 0,
                dump_at: self.dump_at.filter(|p| *p < k),
                dump: dump_a,
                last: false,
            },
            Part {
                passes: b,
                first: k,
                dump_at: self.dump_at.filter(|p| *p >= k),
                dump: dump_b,
                last: true,
            },
        )
    }

    /// How many leading passes run beside the frontend in [`Pipeline::run_threaded`]:
    /// those up to and including the last of [`FRONT_THREAD_PASSES`], so the frontend
    /// thread (reading, lowering, kinematics) and the writer thread (densify, feed,
    /// extrusion rate, checks, printing) carry similar loads; none without them, where
    /// reading is the heavy part.
    fn front_share(&self) -> usize {
        self.passes
            .iter()
            .rposition(|p| FRONT_THREAD_PASSES.contains(&p.name()))
            .map_or(0, |i| i + 1)
    }
}

/// Passes whose work balances the frontend's: the two threads of a run split after the
/// last of them. Measured on the E-moc pipeline (`ik`: 1.65 s -> 1.4 s on 1M GOTO
/// points) and the polar printer (`polar-ik` and `valve-lookahead`: 1.14 s -> 0.65 s on
/// 10 MB of print G-code, where everything had run on the writer thread).
const FRONT_THREAD_PASSES: &[&str] = &["ik", "polar-ik", "valve-lookahead"];

/// A run of consecutive passes with the dump point that falls among them.
struct Part<'a> {
    passes: &'a mut [Box<dyn Pass>],
    /// Index of `passes[0]` in the whole pipeline.
    first: usize,
    /// Dump point (0 after the frontend, i + 1 after pass i), if it is in this part.
    dump_at: Option<usize>,
    dump: Option<&'a mut Box<dyn Write + Send>>,
    /// The last part also dumps after its last pass.
    last: bool,
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
        if self.dump_at == Some(self.first + from) {
            self.dump_blocks(cur);
        }
        for i in from..self.passes.len() {
            let pass = &mut self.passes[i];
            // A pass that only reads the blocks looks at them where they lie.
            if !pass.observe(cur, diags) {
                next.clear();
                pass.run_batch(cur, &mut Output::new(next, diags));
                std::mem::swap(cur, next);
            }
            let at = self.first + i + 1;
            if self.dump_at == Some(at) && (self.last || i + 1 < self.passes.len()) {
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
            self.passes[i].finish(&mut Output::new(&mut cur, diags));
            self.flow(i + 1, &mut cur, &mut next, diags, deliver);
        }
        if let Some(d) = &mut self.dump {
            let _ = d.flush();
        }
    }

    fn dump_blocks(&mut self, blocks: &[Block]) {
        if let Some(out) = &mut self.dump {
            let mut s = String::new();
            for b in blocks {
                dump::write_block(&mut s, b);
                s.push('\n');
            }
            let _ = out.write_all(s.as_bytes());
        }
    }
}

fn report(diags: &mut Vec<Diagnostic>, on_diag: &mut dyn FnMut(Diagnostic), summary: &mut Summary) {
    for d in diags.drain(..) {
        match d.severity {
            Severity::Error => summary.errors += 1,
            Severity::Warning => summary.warnings += 1,
            Severity::Note => {}
        }
        on_diag(d);
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
        .map_err(|e| vec![Diagnostic::error("pipeline::config", e)])?;
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
