//! Two threads that share the pipeline's stages as they go: whichever thread is free takes
//! the next batch that waits at a free stage, so the work shares itself out, whatever
//! the passes cost.
//!
//! A fixed split of the passes between a reading thread and a writing thread leaves one
//! of them idle whenever the input changes character (travel against extrusion, a flat
//! layer against a curved one): the polar printer's two halves were within 5 % of each
//! other over a whole print, yet each waited for the other about a seventh of the time.
//! Here a stage (a pass, then the backend) runs on one batch at a time, and takes its
//! batches in input order (each stage's inbox is filled in order by the stage before
//! it), so the output, the diagnostics and every pass's state change exactly as on one
//! thread. Only the reading thread reads (the input need not be `Send`); it reads while
//! few batches are on their way, and otherwise works on stages like the other thread.

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex};

use crate::diag::Diagnostic;
use crate::front::gcode::Lexed;
use crate::ir::Block;

/// A batch of blocks on its way through the stages.
pub(super) struct Batch {
    /// Position in the input.
    pub(super) seq: u64,
    /// Lines still to be lowered (G-code, whose lowering is a stage of its own), else
    /// empty.
    pub(super) lexed: Lexed,
    pub(super) blocks: Vec<Block>,
    /// The backend's text for these blocks, on its way to the output (and the readback).
    pub(super) text: Vec<u8>,
    /// Diagnostics about these blocks, from the frontend and each stage in order.
    pub(super) diags: Vec<Diagnostic>,
    /// The input's last batch: every stage finishes after it.
    pub(super) end: bool,
}

/// Work for a thread.
pub(super) enum Task {
    /// Read the next batch (the reading thread only).
    Read,
    /// Run stage `.0` on the batch.
    Stage(usize, Batch),
}

/// The reading thread reads while fewer batches than this are on their way, and works on
/// stages otherwise: reading is never held up (where it is the slowest stage, as in the
/// identity pipeline, it runs all the time), and memory stays bounded (a batch of
/// polar-printer output is about 0.6 MB). Pieces of a cut batch count one each: 12 leave
/// room to read on while the IK look-ahead's 16 pieces are on their way (in a model of
/// the E-moc run's stage times: 1.83 s at 8, 1.61 at 12, 1.60 at 16; peak RSS 14.5 MB at
/// 16 against 11.8 at 8).
const MAX_IN_FLIGHT: usize = 12;

/// Which stage runs which batch next.
pub(super) struct Schedule {
    state: Mutex<State>,
    ready: Condvar,
}

struct State {
    /// Batches waiting for each stage, in input order.
    inbox: Vec<VecDeque<Batch>>,
    /// Stages running a batch now.
    busy: Vec<bool>,
    /// The sequence number each stage took last (checked in debug builds).
    expected: Vec<u64>,
    /// Batches read (or being read) and not yet through the last stage.
    in_flight: usize,
    /// The input is done (or reading stopped).
    read_all: bool,
    /// A thread panicked: everyone stops.
    abort: bool,
}

impl State {
    /// A free stage with a batch waiting: for the reading thread the last one, for the
    /// other the one most batches wait for (of equals, the first). So the other thread
    /// stays with the slowest stage (the one batches queue up for, early or late) while
    /// the reading thread reads and takes the later stages in between. When both took the
    /// last stage first, the slowest stage stood idle whenever one thread was reading and
    /// the other printing: the identity run (reading, lowering, printing) took 1.3 times
    /// the lowering alone. When the other thread took the first stage, the readback at
    /// the end of the E-moc pipeline waited for the reading thread.
    fn runnable(&mut self, reader: bool) -> Option<Task> {
        let free = |k: &usize| !self.busy[*k] && !self.inbox[*k].is_empty();
        let k = if reader {
            (0..self.inbox.len()).rev().find(free)?
        } else {
            // `max_by_key` keeps the last of equals: over the stages reversed, the first.
            (0..self.inbox.len())
                .rev()
                .filter(free)
                .max_by_key(|&k| self.inbox[k].len())?
        };
        let batch = self.inbox[k].pop_front()?;
        // Pieces of one batch share its number (see `Schedule::stage_done`).
        debug_assert!(batch.seq >= self.expected[k], "stage {k} out of order");
        self.expected[k] = batch.seq;
        self.busy[k] = true;
        Some(Task::Stage(k, batch))
    }

    fn read(&mut self) -> Task {
        self.in_flight += 1;
        Task::Read
    }
}

impl Schedule {
    /// A schedule for `stages` stages (the passes, the backend and the output).
    pub(super) fn new(stages: usize) -> Schedule {
        Schedule {
            state: Mutex::new(State {
                inbox: (0..stages).map(|_| VecDeque::new()).collect(),
                busy: vec![false; stages],
                expected: vec![0; stages],
                in_flight: 0,
                read_all: false,
                abort: false,
            }),
            ready: Condvar::new(),
        }
    }

    /// The next task for a thread, waiting for one; `None` when the run is over or
    /// aborted.
    pub(super) fn next(&self, reader: bool) -> Option<Task> {
        let mut s = self.state.lock().ok()?;
        loop {
            if s.abort {
                return None;
            }
            if reader && !s.read_all && s.in_flight < MAX_IN_FLIGHT {
                return Some(s.read());
            }
            if let Some(task) = s.runnable(reader) {
                return Some(task);
            }
            if s.read_all && s.in_flight == 0 {
                return None;
            }
            s = self.ready.wait(s).ok()?;
        }
    }

    /// A [`Task::Read`] is done: `batch` goes to the first stage (`None`: nothing was
    /// read, and no more will be).
    pub(super) fn read_done(&self, batch: Option<Batch>) {
        if let Ok(mut s) = self.state.lock() {
            match batch {
                Some(b) => {
                    s.read_all |= b.end;
                    s.inbox[0].push_back(b);
                }
                None => {
                    s.read_all = true;
                    s.in_flight -= 1;
                }
            }
        }
        self.ready.notify_all();
    }

    /// Stage `k` is done with `batch`, and made `more` batches after it out of it (a
    /// batch cut into pieces, which share its number): they go on to the next stage, or,
    /// after the last, `batch` goes back to the caller (there, `more` is empty).
    pub(super) fn stage_done(&self, k: usize, batch: Batch, more: Vec<Batch>) -> Option<Batch> {
        let mut left = None;
        if let Ok(mut s) = self.state.lock() {
            s.busy[k] = false;
            if k + 1 < s.inbox.len() {
                s.in_flight += more.len();
                s.inbox[k + 1].push_back(batch);
                s.inbox[k + 1].extend(more);
            } else {
                debug_assert!(more.is_empty(), "the last stage makes no pieces");
                s.in_flight -= 1;
                left = Some(batch);
            }
        }
        self.ready.notify_all();
        left
    }

    /// No more reading (the output cannot be written).
    pub(super) fn stop_reading(&self) {
        if let Ok(mut s) = self.state.lock() {
            s.read_all = true;
        }
        self.ready.notify_all();
    }

    /// Stops both threads wherever they are.
    pub(super) fn abort(&self) {
        match self.state.lock() {
            Ok(mut s) => s.abort = true,
            Err(poisoned) => poisoned.into_inner().abort = true,
        }
        self.ready.notify_all();
    }

    /// Whether the run was aborted.
    pub(super) fn aborted(&self) -> bool {
        match self.state.lock() {
            Ok(s) => s.abort,
            Err(_) => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn batch(seq: u64, end: bool) -> Batch {
        Batch {
            seq,
            lexed: Lexed::new(),
            blocks: Vec::new(),
            text: Vec::new(),
            diags: Vec::new(),
            end,
        }
    }

    /// Two threads, one of them reading, take 200 batches through five stages, one of
    /// which cuts some batches into pieces: every stage sees the batches in input order,
    /// one at a time, the pieces after their batch, and the run ends.
    #[test]
    fn every_stage_sees_the_batches_in_order() {
        const STAGES: usize = 5;
        let schedule = Schedule::new(STAGES);
        let seen: Vec<Mutex<Vec<u64>>> = (0..STAGES).map(|_| Mutex::new(Vec::new())).collect();
        let next_seq = Mutex::new(0u64);
        let work = |reader: bool| {
            while let Some(task) = schedule.next(reader) {
                match task {
                    Task::Read => {
                        let mut n = next_seq.lock().expect("not poisoned");
                        let b = batch(*n, *n == 199);
                        *n += 1;
                        schedule.read_done(Some(b));
                    }
                    Task::Stage(k, mut b) => {
                        // One at a time: the lock is never contended.
                        let mut log = seen[k].try_lock().expect("a stage runs one batch");
                        log.push(b.seq);
                        drop(log);
                        std::thread::yield_now();
                        // Stage 1 cuts every third batch in three pieces.
                        let mut more = Vec::new();
                        if k == 1 && b.seq % 3 == 0 {
                            more = vec![batch(b.seq, false), batch(b.seq, b.end)];
                            b.end = false;
                        }
                        schedule.stage_done(k, b, more);
                    }
                }
            }
        };
        std::thread::scope(|s| {
            s.spawn(|| work(false));
            work(true);
        });
        let pieces = |k: usize| -> Vec<u64> {
            (0..200)
                .flat_map(|s| {
                    let n = if k > 1 && s % 3 == 0 { 3 } else { 1 };
                    std::iter::repeat_n(s, n)
                })
                .collect()
        };
        for (k, log) in seen.into_iter().enumerate() {
            assert_eq!(log.into_inner().expect("not poisoned"), pieces(k));
        }
    }

    /// An aborted schedule lets a waiting thread go.
    #[test]
    fn abort_wakes_a_waiter() {
        let schedule = Schedule::new(2);
        std::thread::scope(|s| {
            let waiter = s.spawn(|| schedule.next(false).is_none());
            std::thread::sleep(std::time::Duration::from_millis(20));
            schedule.abort();
            assert!(waiter.join().expect("no panic"));
        });
        assert!(schedule.aborted());
    }
}
