//! The threaded run: the stages of a pipeline (the G-code frontend's lowering half, the
//! passes, the backend, the output) shared by two threads as they go, by the [`Schedule`].
//!
//! The backend prints each batch into the batch's own text, and the output stage hands
//! that text to the writer, which also feeds `--verify`'s readback. As one stage, printing
//! and reading back were the slowest stage by far (the E-moc pipeline: 1.35 s of 3.3 s of
//! CPU in the readback alone), and the other thread waited for it.

use std::io::Write;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::schedule::{Batch, Schedule, Task};
use super::{Stages, Summary, dump_blocks, finish_pass, run_pass, verify};
use crate::back::Backend;
use crate::diag::Diagnostic;
use crate::front::{self, Frontend};
use crate::ir::Block;
use crate::passes::Pass;

impl Stages {
    /// The passes and `backend` as the stages of one run, each stage with the IR dump of
    /// its input when the dump point is there.
    pub(super) fn relay<'a>(
        &'a mut self,
        backend: Box<dyn Backend + Send + 'a>,
        spool: Spool,
        output: &'a mut (dyn Write + Send),
        mut tap: Option<verify::TapPoint>,
    ) -> Relay<'a> {
        let dump_at = self.dump_at;
        let mut dump = self.dump.as_mut();
        let count = self.passes.len();
        let mut dump_before = |i: usize| {
            if dump_at == Some(i) {
                dump.take()
            } else {
                None
            }
        };
        let passes: Vec<Mutex<PassStage<'_>>> = self
            .passes
            .iter_mut()
            .enumerate()
            .map(|(i, pass)| {
                let dump = dump_before(i);
                let tap = tap.take_if(|t| t.at == i);
                Mutex::new(PassStage { pass, dump, tap })
            })
            .collect();
        let writer = Mutex::new(WriterStage {
            backend,
            spool,
            dump: dump_before(count),
            written: 0,
            tap,
        });
        Relay {
            max_repeats: self.max_repeats,
            schedule: Schedule::new(count + 2),
            lowering: None,
            blocks_in: AtomicU64::new(0),
            spare_lexed: Mutex::new(Vec::new()),
            passes,
            writer,
            output: Mutex::new(output),
            failed: AtomicBool::new(false),
            reports: Mutex::new(Vec::new()),
            spare: Mutex::new(Vec::new()),
            spare_text: Mutex::new(Vec::new()),
        }
    }
}

/// Blocks the frontend reads per batch. Passes that cut moves into pieces (polar-ik,
/// densify, extrude-rate's screw steps) grow every batch in flight several times over, so
/// the batch size sets the streaming runs' memory: at 1024 the polar printer with
/// verification peaked at 20.3 MiB and the E-moc pipeline at 17.8, at 256 they peak at
/// 11.8 and 12.5 MiB with the same CPU time within the noise (identity on 100 MB 0.91,
/// polar on 10 MB 1.03 of the CPU seconds at 1024; whole-process medians of 5, 2 cores).
const BATCH: usize = 256;

/// A batch a pass made longer than this is cut into pieces of [`BATCH`] blocks (see
/// `Relay::cut`).
const CUT_OVER: usize = 4 * BATCH;

/// Blocks a kept buffer has room for. At one batch, every batch a pass cuts into pieces
/// (the polar printer makes about three and a half blocks of each line) grew its buffer
/// anew through fresh pages: 96,000 minor page faults on 10 MB of polar input and a
/// fifth of the run's CPU time in the kernel; at two batches 38,000, and peak RSS
/// 13.7 MiB. Room for `CUT_OVER` takes them to 9,000 but the peak to 15.4 MiB, at the
/// 16 MB floor.
const KEPT: usize = 2 * BATCH;

/// Emptied batch buffers kept for reuse (a buffer grows to what the passes make of a
/// batch once, not on every batch).
const SPARE_BATCHES: usize = 4;

/// A pass as a stage of a [`Relay`], with the IR dump of its input when the dump point
/// is there.
struct PassStage<'a> {
    pass: &'a mut Box<dyn Pass>,
    dump: Option<&'a mut Box<dyn Write + Send>>,
    /// The programmed path of `--verify` is this stage's input.
    tap: Option<verify::TapPoint>,
}

/// The printed text of the batch the backend is writing: the backend's writer, emptied
/// into the batch after each batch.
#[derive(Clone, Default)]
pub(super) struct Spool(Arc<Mutex<Vec<u8>>>);

impl Spool {
    /// Swaps the text printed so far with `text` (an emptied buffer, kept for reuse).
    fn take_into(&self, text: &mut Vec<u8>) {
        let mut printed = self.0.lock().unwrap_or_else(|p| p.into_inner());
        std::mem::swap(&mut *printed, text);
    }
}

impl Write for Spool {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let mut printed = self.0.lock().unwrap_or_else(|p| p.into_inner());
        printed.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The backend as the stage before the output of a [`Relay`].
struct WriterStage<'a> {
    backend: Box<dyn Backend + Send + 'a>,
    /// What the backend writes to.
    spool: Spool,
    dump: Option<&'a mut Box<dyn Write + Send>>,
    /// Blocks handed to the backend.
    written: u64,
    /// The programmed path of `--verify` is the backend's input (no machine pass).
    tap: Option<verify::TapPoint>,
}

/// One stage of a [`Relay`].
enum Step<'r, 'a> {
    Lower(&'r Mutex<front::gcode::Lowering>),
    Pass(&'r Mutex<PassStage<'a>>),
    /// The backend prints the batch into its text.
    Print,
    /// The text goes to the writer (and the readback).
    Output,
}

/// What a run reads: blocks from a frontend, or G-code lines whose lowering is a stage of
/// its own, so that reading and lowering run on different threads.
pub(super) enum Reading<'f> {
    /// A frontend's blocks.
    Blocks(&'f mut dyn Frontend),
    /// G-code lines, and their lowering.
    Lines(
        &'f mut dyn front::gcode::ReadLines,
        Box<front::gcode::Lowering>,
    ),
}

/// How a threaded run ended.
pub(super) struct Ended {
    /// A stage panicked: the output is incomplete.
    pub(super) aborted: bool,
    /// Blocks handed to the backend.
    pub(super) written: u64,
    /// The output could not be written.
    pub(super) failed: bool,
}

/// What the reading thread holds of a [`Reading`].
enum Reader<'f> {
    Blocks(&'f mut dyn Frontend),
    Lines(&'f mut dyn front::gcode::ReadLines),
}

impl Reader<'_> {
    fn bytes_read(&self) -> u64 {
        match self {
            Reader::Blocks(front) => front.bytes_read(),
            Reader::Lines(lines) => lines.bytes_read(),
        }
    }
}

/// What the two threads of [`Pipeline::run_threaded`] share. The schedule gives a stage
/// to one thread at a time, so its lock is never waited for.
pub(super) struct Relay<'a> {
    /// As [`Stages::max_repeats`].
    max_repeats: u64,
    schedule: Schedule,
    /// The G-code frontend's lowering half, as the first stage: the reading thread only
    /// reads and tokenises lines.
    lowering: Option<Mutex<front::gcode::Lowering>>,
    /// Blocks the frontend made.
    blocks_in: AtomicU64,
    /// Emptied line batches kept for reuse.
    spare_lexed: Mutex<Vec<front::gcode::Lexed>>,
    passes: Vec<Mutex<PassStage<'a>>>,
    writer: Mutex<WriterStage<'a>>,
    /// The last stage: where the printed text goes (and `--verify` reads it).
    output: Mutex<&'a mut (dyn Write + Send)>,
    /// The output cannot be written: reading stops, passes skip their work.
    failed: AtomicBool,
    /// Each written batch's diagnostics, in input order, for the reading thread.
    reports: Mutex<Vec<Vec<Diagnostic>>>,
    spare: Mutex<Vec<Vec<Block>>>,
    /// Emptied text buffers kept for reuse.
    spare_text: Mutex<Vec<Vec<u8>>>,
}

impl<'a> Relay<'a> {
    /// Runs the whole input through the stages on this thread and one more: this one
    /// reads the frontend whenever the schedule asks for input, both run whichever stage
    /// is due. `deliver` gets each written batch's diagnostics, in input order.
    pub(super) fn drive(
        mut self,
        reading: Reading<'_>,
        progress: &mut Option<Box<dyn FnMut(u64)>>,
        summary: &mut Summary,
        deliver: &mut dyn FnMut(Vec<Vec<Diagnostic>>, &mut Summary),
    ) -> Ended {
        let mut reader = match reading {
            Reading::Blocks(front) => Reader::Blocks(front),
            Reading::Lines(lines, lowering) => {
                // The lowering half is a stage of its own, before the passes.
                self.lowering = Some(Mutex::new(*lowering));
                self.schedule = Schedule::new(self.passes.len() + 3);
                Reader::Lines(lines)
            }
        };
        self.run(&mut reader, progress, summary, deliver);
        Ended {
            aborted: self.schedule.aborted(),
            written: self
                .writer
                .into_inner()
                .unwrap_or_else(|p| p.into_inner())
                .written,
            failed: self.failed.into_inner(),
        }
    }

    /// [`Relay::drive`] once the stages are set.
    fn run(
        &self,
        reader: &mut Reader<'_>,
        progress: &mut Option<Box<dyn FnMut(u64)>>,
        summary: &mut Summary,
        deliver: &mut dyn FnMut(Vec<Vec<Diagnostic>>, &mut Summary),
    ) {
        std::thread::scope(|scope| {
            let worker = scope.spawn(|| {
                let mut next = Vec::with_capacity(BATCH);
                while let Some(task) = self.schedule.next(false) {
                    if let Task::Stage(k, batch) = task {
                        self.stage_caught(k, batch, &mut next);
                    }
                }
            });
            let mut next = Vec::with_capacity(BATCH);
            let mut seq = 0u64;
            let mut lines_read = 0u64;
            while let Some(task) = self.schedule.next(true) {
                match task {
                    Task::Read if self.failed.load(Ordering::Acquire) => {
                        // Nothing more can be written: stop reading.
                        self.schedule.read_done(None);
                    }
                    Task::Read => {
                        let batch = self.read(reader, seq, &mut lines_read);
                        if lines_read >= 1 << 14 {
                            lines_read = 0;
                            if let Some(p) = progress.as_mut() {
                                p(reader.bytes_read());
                            }
                        }
                        self.schedule.read_done(Some(batch));
                        seq += 1;
                    }
                    Task::Stage(k, batch) => self.stage_caught(k, batch, &mut next),
                }
                deliver(self.take_reports(), summary);
            }
            if worker.join().is_err() {
                self.schedule.abort();
            }
        });
        summary.blocks_in = self.blocks_in.load(Ordering::Acquire);
        deliver(self.take_reports(), summary);
    }

    /// The next batch from `reader`: blocks, or lines for the lowering stage; `count`
    /// grows by what was read (blocks or lines), for progress reports.
    fn read(&self, reader: &mut Reader<'_>, seq: u64, count: &mut u64) -> Batch {
        let mut blocks = self.spare_batch();
        let mut diags = Vec::new();
        let mut lexed = front::gcode::Lexed::new();
        let end = match reader {
            Reader::Blocks(front) => {
                front.next_batch(&mut blocks, BATCH, &mut diags);
                self.blocks_in
                    .fetch_add(blocks.len() as u64, Ordering::AcqRel);
                *count += blocks.len() as u64;
                blocks.is_empty()
            }
            Reader::Lines(lines) => {
                if let Some(spare) = self.spare_lexed.lock().ok().and_then(|mut s| s.pop()) {
                    lexed = spare;
                }
                lines.read(&mut lexed, BATCH);
                *count += lexed.len() as u64;
                lexed.is_end()
            }
        };
        let text = self
            .spare_text
            .lock()
            .ok()
            .and_then(|mut s| s.pop())
            .unwrap_or_default();
        Batch {
            seq,
            lexed,
            blocks,
            text,
            diags,
            end,
        }
    }

    /// The lowering stage: the batch's lines become its blocks.
    fn lower(&self, lowering: &Mutex<front::gcode::Lowering>, batch: &mut Batch) {
        let mut lowering = lowering.lock().unwrap_or_else(|p| p.into_inner());
        if !self.failed.load(Ordering::Acquire) {
            lowering.lower(&batch.lexed, &mut batch.blocks, &mut batch.diags);
            self.blocks_in
                .fetch_add(batch.blocks.len() as u64, Ordering::AcqRel);
        }
        let mut lexed = std::mem::take(&mut batch.lexed);
        lexed.clear();
        if let Ok(mut spare) = self.spare_lexed.lock()
            && spare.len() < SPARE_BATCHES
        {
            spare.push(lexed);
        }
    }

    /// Runs stage `k` (a pass, or after the last pass the backend, then the output) on
    /// `batch` and hands the batch on.
    fn stage(&self, k: usize, mut batch: Batch, next: &mut Vec<Block>) {
        let mut more = Vec::new();
        match self.step(k) {
            Step::Lower(lowering) => self.lower(lowering, &mut batch),
            Step::Pass(stage) => {
                let mut stage = stage.lock().unwrap_or_else(|p| p.into_inner());
                self.pass_stage(&mut stage, &mut batch, next);
                more = self.cut(&mut batch);
            }
            Step::Print => {
                let mut w = self.writer.lock().unwrap_or_else(|p| p.into_inner());
                self.write(&mut w, &mut batch);
            }
            Step::Output => {
                let mut out = self.output.lock().unwrap_or_else(|p| p.into_inner());
                self.output(&mut **out, &mut batch);
            }
        }
        if let Some(mut done) = self.schedule.stage_done(k, batch, more) {
            done.text.clear();
            if let Ok(mut spare) = self.spare_text.lock()
                && spare.len() < SPARE_BATCHES
            {
                spare.push(std::mem::take(&mut done.text));
            }
            done.blocks.clear();
            // A pass that cuts moves into many pieces (polar-ik, densify) grows a batch
            // far beyond what the frontend reads; a kept buffer goes back to `KEPT` so
            // that memory stays bounded by the batch size, not by the longest expansion.
            done.blocks.shrink_to(KEPT);
            if let Ok(mut spare) = self.spare.lock()
                && spare.len() < SPARE_BATCHES
            {
                spare.push(done.blocks);
            }
        }
    }

    /// What stage `k` is: the lowering (when the run reads G-code lines), the passes, the
    /// backend, the output.
    fn step(&self, k: usize) -> Step<'_, 'a> {
        let k = match &self.lowering {
            Some(lowering) if k == 0 => return Step::Lower(lowering),
            Some(_) => k - 1,
            None => k,
        };
        match self.passes.get(k) {
            Some(stage) => Step::Pass(stage),
            None if k == self.passes.len() => Step::Print,
            None => Step::Output,
        }
    }

    /// Cuts a batch that a pass made much longer than [`BATCH`] (the IK look-ahead hands
    /// on up to 4096 poses at once, polar-ik makes several pieces of each move) into
    /// pieces of `BATCH` blocks, returned after the shortened `batch`: the next stages
    /// then share the pieces between the threads. As one batch, the E-moc pipeline's later
    /// stages (densify, feed, the backend, the readback) ran on one thread at a time
    /// while the other waited for the look-ahead.
    fn cut(&self, batch: &mut Batch) -> Vec<Batch> {
        if batch.blocks.len() <= CUT_OVER {
            return Vec::new();
        }
        let mut pieces: Vec<Batch> = Vec::new();
        for (i, block) in batch.blocks.drain(BATCH..).enumerate() {
            if i % BATCH == 0 {
                pieces.push(Batch {
                    seq: batch.seq,
                    lexed: front::gcode::Lexed::new(),
                    blocks: self.spare_batch(),
                    text: Vec::new(),
                    diags: Vec::new(),
                    end: false,
                });
            }
            if let Some(piece) = pieces.last_mut() {
                piece.blocks.push(block);
            }
        }
        // The input's end, and the diagnostics a later stage adds at the end, go with the
        // last piece.
        if let Some(last) = pieces.last_mut() {
            last.end = std::mem::take(&mut batch.end);
        }
        pieces
    }

    fn pass_stage(&self, stage: &mut PassStage<'_>, batch: &mut Batch, next: &mut Vec<Block>) {
        if let Some(d) = stage.dump.as_mut() {
            dump_blocks(d, &batch.blocks);
        }
        if let Some(t) = stage.tap.as_mut() {
            t.record(&batch.blocks);
        }
        if self.failed.load(Ordering::Acquire) {
            batch.blocks.clear();
            return;
        }
        run_pass(
            stage.pass,
            &mut batch.blocks,
            next,
            &mut batch.diags,
            self.max_repeats,
        );
        // The scratch buffer keeps `KEPT`, as the spare buffers do.
        next.shrink_to(KEPT);
        if batch.end {
            // What the pass still holds goes on after this batch's blocks.
            finish_pass(
                stage.pass,
                &mut batch.blocks,
                &mut batch.diags,
                self.max_repeats,
            );
        }
    }

    fn write(&self, w: &mut WriterStage<'_>, batch: &mut Batch) {
        if let Some(d) = w.dump.as_mut() {
            dump_blocks(d, &batch.blocks);
        }
        if let Some(t) = w.tap.as_mut() {
            t.record(&batch.blocks);
        }
        // Set by the first write error (a full disk, a closed pipe): nothing more is written.
        if !self.failed.load(Ordering::Acquire) {
            w.written += batch.blocks.len() as u64;
            if w.backend
                .write_batch(&batch.blocks, &mut batch.diags)
                .is_err()
            {
                self.failed.store(true, Ordering::Release);
                self.schedule.stop_reading();
            } else if batch.end
                && let Err(d) = w.backend.finish()
            {
                batch.diags.push(d);
            }
        }
        w.spool.take_into(&mut batch.text);
    }

    /// The output stage: the batch's text goes to `out`, and its diagnostics to the
    /// reports (still in input order: one batch at a time).
    fn output(&self, out: &mut (dyn Write + Send), batch: &mut Batch) {
        if !self.failed.load(Ordering::Acquire)
            && let Err(e) = out.write_all(&batch.text)
        {
            batch.diags.push(crate::back::io_error(e));
            self.failed.store(true, Ordering::Release);
            self.schedule.stop_reading();
        }
        if !batch.diags.is_empty()
            && let Ok(mut r) = self.reports.lock()
        {
            r.push(std::mem::take(&mut batch.diags));
        }
    }

    /// [`Relay::stage`], stopping the whole run if a pass or the backend panics (the
    /// other thread would otherwise wait for this batch forever).
    fn stage_caught(&self, k: usize, batch: Batch, next: &mut Vec<Block>) {
        let ran =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.stage(k, batch, next)));
        if ran.is_err() {
            self.schedule.abort();
        }
    }

    fn take_reports(&self) -> Vec<Vec<Diagnostic>> {
        self.reports
            .lock()
            .map(|mut r| std::mem::take(&mut *r))
            .unwrap_or_default()
    }

    /// An empty buffer for the next batch.
    fn spare_batch(&self) -> Vec<Block> {
        self.spare
            .lock()
            .ok()
            .and_then(|mut s| s.pop())
            .unwrap_or_else(|| Vec::with_capacity(BATCH))
    }
}
