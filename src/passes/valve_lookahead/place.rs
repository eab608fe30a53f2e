//! Placing the valve commands: each command goes its delay of motion time before its
//! target (a run's first extruding move, or the end of its last), splitting the move
//! running then, and is moved until the re-timed window agrees (settling).

use crate::diag::Diagnostic;
use crate::ir::{AxisSet, Block, BlockKind, Command, Comment, CommentStyle, Span};

use super::window::{Item, Kind, micros};
use super::{Output, SETTLE_ROUNDS, SETTLE_TOL, SPLIT_EPS, ValveLookahead, WARN_TOL};

/// A change of a command's time that stands for a jump, not a slope, seconds.
const JUMP_S: f64 = 1e-3;

/// A valve command to place.
#[derive(Debug, Clone)]
pub(super) struct Event {
    open: bool,
    /// Open: the start id of the run's first item; close: the end id of its last.
    target: u64,
    delay: f64,
    /// Correction of the wanted time found by settling.
    corr: f64,
    /// The previous correction and the error it gave.
    last: Option<(f64, f64)>,
    /// The item this event split, and the ids of the two parts' inner ends.
    original: Option<(Item, u64, u64)>,
    /// Placed at the earliest allowed point, short of its delay.
    clamped: bool,
    span: Span,
}

/// What settling does with a command off its delay.
enum Step {
    /// Nothing more to move: true when it is as close as it can come, false when its
    /// dwell changed.
    Done(bool),
    /// The command moves; `keep_dwell`: an open keeps its own wait.
    Move { keep_dwell: bool },
}

/// Where a command goes among the held items.
struct Spot {
    /// The index it is inserted at.
    pos: usize,
    /// At the earliest allowed point, short of its delay.
    clamped: bool,
    /// The item split for it, and the ids of the two parts' inner ends.
    original: Option<(Item, u64, u64)>,
}

impl ValveLookahead {
    pub(super) fn ensure_timed(&mut self) {
        if self.clock.dirty {
            self.retime();
        }
    }

    pub(super) fn find_start(&self, id: u64) -> Option<usize> {
        self.queue.items.iter().position(|it| it.start_id == id)
    }

    pub(super) fn find_end(&self, id: u64) -> Option<usize> {
        self.queue.items.iter().rposition(|it| it.end_id == id)
    }

    fn find_marker(&self, id: u64) -> Option<usize> {
        self.queue
            .items
            .iter()
            .position(|it| matches!(it.kind, Kind::Marker(m) if m == id))
    }

    /// The target's index (where a zero-delay command would go) and time.
    fn target_of(&self, ev: &Event) -> Option<(usize, f64)> {
        if ev.open {
            let i = self.find_start(ev.target)?;
            Some((i, self.queue.items[i].start))
        } else {
            let i = self.find_end(ev.target)?;
            Some((i + 1, self.queue.items[i].end()))
        }
    }

    /// The command item of event `id`, with its block.
    fn marker(&mut self, ev: &Event, id: u64) -> Item {
        let text: &str = if ev.open {
            &self.valve.open_command
        } else {
            &self.valve.close_command
        };
        let block = Block::new(
            ev.span,
            BlockKind::Command(Command {
                text: text.into(),
                modes: None,
                clobbers: AxisSet::EMPTY,
            }),
        );
        self.item(Kind::Marker(id), block, false)
    }

    /// Places event `id`'s command (and an open's dwell) by the current timing.
    fn place(&mut self, id: u64, out: &mut Output<'_>) {
        self.ensure_timed();
        let Some(ev) = self.queue.events.get(&id).cloned() else {
            return;
        };
        let Some((b, t_target)) = self.target_of(&ev) else {
            // The target left the window (forced release): the command goes at its start.
            let marker = self.marker(&ev, id);
            self.queue.items.insert(0, marker);
            self.clock.dirty = true;
            if let Some(e) = self.queue.events.get_mut(&id) {
                e.clamped = true;
            }
            return;
        };
        // Commands never move back across the previous command or a line of unknown time.
        let mut lower = b;
        while lower > 0 {
            let it = &self.queue.items[lower - 1];
            if matches!(it.kind, Kind::Marker(_) | Kind::Barrier) {
                break;
            }
            lower -= 1;
        }
        let spot = self.spot(lower, b, t_target - ev.delay - ev.corr, ev.open);
        let marker = self.marker(&ev, id);
        self.queue.items.insert(spot.pos, marker);
        self.clock.dirty = true;
        if let Some(e) = self.queue.events.get_mut(&id) {
            e.original = spot.original;
            e.clamped = spot.clamped;
        }
        if spot.clamped {
            self.short_of_delay(id, &ev, lower, out);
        }
    }

    /// Where a command wanted at time `desired` goes among items `lower..b`: after the
    /// item that ends then, or inside the one running then (split there). Inside a
    /// valve's wait, which the controller times in whole steps, it goes to the step on
    /// its safe side: earlier for an open (`early`), later for a close.
    fn spot(&mut self, lower: usize, b: usize, desired: f64, early: bool) -> Spot {
        let mut spot = Spot {
            pos: lower,
            clamped: true,
            original: None,
        };
        for i in (lower..b).rev() {
            let it = &self.queue.items[i];
            if it.start > desired + 1e-12 {
                continue;
            }
            spot.clamped = false;
            let end = it.end();
            if desired >= end - SPLIT_EPS {
                spot.pos = i + 1;
            } else if desired - it.start <= SPLIT_EPS {
                spot.pos = i;
            } else {
                let saved = it.clone();
                match self.split(i, desired - it.start, early) {
                    Some((ea, sb)) => {
                        spot.original = Some((saved, ea, sb));
                        spot.pos = i + 1;
                    }
                    None if matches!(saved.kind, Kind::Dwell { owner: Some(_), .. }) => {
                        spot.pos = if early { i } else { i + 1 };
                    }
                    None => {
                        let it = &self.queue.items[i];
                        spot.pos = if desired - it.start < it.end() - desired {
                            i
                        } else {
                            i + 1
                        };
                    }
                }
            }
            return spot;
        }
        // As late as the same time allows (after comments, modes, moves of no length).
        while spot.pos < b
            && self.queue.items[spot.pos].dur == 0.0
            && matches!(self.queue.items[spot.pos].kind, Kind::Other | Kind::Move(_))
        {
            spot.pos += 1;
        }
        spot
    }

    /// Event `id`'s command went as early as it can (`lower` is the earliest index)
    /// and may be short of its delay: an open makes up the rest with a dwell, a close
    /// is warned about.
    fn short_of_delay(&mut self, id: u64, ev: &Event, lower: usize, out: &mut Output<'_>) {
        self.ensure_timed();
        let (Some(m), Some((ti, tt))) = (self.find_marker(id), self.target_of(ev)) else {
            return;
        };
        let gap = tt - self.queue.items[m].start;
        let short = ev.delay - gap;
        // An open that already has its dwell (placed again after the close before it
        // moved) lengthens or shortens it.
        if ev.open
            && let Some(d) = self.owned_dwell(id)
            && let Kind::Dwell { seconds, .. } = self.queue.items[d].kind
        {
            self.set_dwell(d, id, seconds + short);
            return;
        }
        if short <= SETTLE_TOL / 2.0 {
            return;
        }
        if ev.open {
            self.open_dwell(id, ev, ti, short, gap, out);
        } else if !self.queue.replacing {
            self.warn_late_close(ev, lower, gap, out);
        }
    }

    /// Inserts the dwell that makes up the `short` seconds an open lacks (`gap` seconds
    /// of motion before its target at `ti`), with a warning.
    fn open_dwell(
        &mut self,
        id: u64,
        ev: &Event,
        ti: usize,
        short: f64,
        gap: f64,
        out: &mut Output<'_>,
    ) {
        let seconds = self.dwell_up(short);
        let mut dwell = Block::new(ev.span, BlockKind::Dwell { seconds });
        dwell.comments.push(Comment {
            text: "valve: waiting for the open delay".into(),
            style: CommentStyle::Semicolon,
        });
        let kind = Kind::Dwell {
            seconds,
            owner: Some(id),
        };
        let item = self.item(kind, dwell, false);
        self.queue.items.insert(ti, item);
        self.clock.dirty = true;
        if self.queue.replacing {
            return;
        }
        let (span, delay) = (ev.span, ev.delay);
        self.warn.dwelled.hit(out, || {
            Diagnostic::warning(
                "valve-lookahead::dwell",
                format!(
                    "only {gap:.4} s of motion before this extrusion start for an open delay of {delay:.4} s: dwelling {seconds:.4} s"
                ),
            )
            .at_span(span)
            .with_help("lengthen the travel before the start, or set keep_open_gap_s to keep the valve open across short gaps")
        });
    }

    /// Warns that a close comes only `gap` seconds before its run ends: right after its
    /// own run's open (a run too short for the delays), or after something in the way.
    fn warn_late_close(&mut self, ev: &Event, lower: usize, gap: f64, out: &mut Output<'_>) {
        let span = ev.span;
        let lead = ev.delay;
        let own_open = lower > 0
            && matches!(self.queue.items[lower - 1].kind, Kind::Marker(o) if self.queue.events.get(&o).is_some_and(|e| e.open));
        if own_open {
            self.warn.short_run.hit(out, || {
                Diagnostic::warning(
                    "valve-lookahead::short-run",
                    format!("this extrusion run is too short for the valve delays: the close follows the open at once ({gap:.4} s before the run ends instead of {lead:.4} s)"),
                )
                .at_span(span)
            })
        } else {
            self.warn.late.hit(out, || {
                Diagnostic::warning(
                    "valve-lookahead::late-close",
                    format!("the close command can only come {gap:.4} s before this extrusion ends, not {lead:.4} s"),
                )
                .at_span(span)
                .with_help("a line of unknown time, the previous valve command or the look-ahead window's start is in the way")
            })
        }
    }

    /// The last dwell event `id` inserted.
    fn owned_dwell(&self, id: u64) -> Option<usize> {
        self.queue
            .items
            .iter()
            .rposition(|it| matches!(it.kind, Kind::Dwell { owner: Some(o), .. } if o == id))
    }

    /// Sets dwell `d` of event `id` to `seconds` (up to a printable dwell: it waits for
    /// the valve), or removes it.
    fn set_dwell(&mut self, d: usize, id: u64, seconds: f64) {
        let seconds = self.dwell_up(seconds);
        if seconds > 0.0 {
            self.queue.items[d].kind = Kind::Dwell {
                seconds,
                owner: Some(id),
            };
            self.queue.items[d].block.kind = BlockKind::Dwell { seconds };
        } else {
            self.queue.items.remove(d);
        }
        self.clock.dirty = true;
    }

    /// Takes event `id`'s command and dwell out again and merges its split.
    fn undo(&mut self, id: u64) {
        while let Some(d) = self
            .queue
            .items
            .iter()
            .rposition(|it| matches!(it.kind, Kind::Dwell { owner: Some(o), .. } if o == id))
        {
            self.queue.items.remove(d);
        }
        self.undo_marker(id);
    }

    /// Takes event `id`'s command out again and merges its split.
    fn undo_marker(&mut self, id: u64) {
        if let Some(m) = self.find_marker(id) {
            self.queue.items.remove(m);
        }
        if let Some((mut orig, ea, sb)) = self
            .queue
            .events
            .get_mut(&id)
            .and_then(|e| e.original.take())
            && let Some(a) = self.find_end(ea)
            && a + 1 < self.queue.items.len()
            && self.queue.items[a + 1].start_id == sb
        {
            // A dwell may have been lengthened or shortened since: merge what is there.
            if let (
                Kind::Dwell { seconds: sa, .. },
                Kind::Dwell { seconds: sb, .. },
                Kind::Dwell { owner, .. },
            ) = (
                &self.queue.items[a].kind,
                &self.queue.items[a + 1].kind,
                &orig.kind,
            ) {
                let seconds = match owner {
                    Some(_) => self.dwell_nearest(sa + sb),
                    None => micros(sa + sb),
                };
                orig.kind = Kind::Dwell {
                    seconds,
                    owner: *owner,
                };
                orig.block.kind = BlockKind::Dwell { seconds };
            }
            self.queue.items[a] = orig;
            self.queue.items.remove(a + 1);
        }
        self.clock.dirty = true;
    }

    /// How far event `id`'s command is off its delay, seconds, when it is further off
    /// than the settling tolerance and can be moved.
    fn error_of(&mut self, id: u64) -> Option<f64> {
        self.ensure_timed();
        let ev = self.queue.events.get(&id)?;
        let (_, tt) = self.target_of(ev)?;
        let m = self.find_marker(id)?;
        let error = (tt - self.queue.items[m].start) - ev.delay;
        let stuck = ev.clamped && !ev.open && error < 0.0;
        (error.abs() > SETTLE_TOL && !stuck).then_some(error)
    }

    /// Moves every held command until its time to its target is the delay.
    pub(super) fn settle(&mut self, out: &mut Output<'_>) {
        // Commands put back at their best placement, which the rounds leave alone.
        let mut settled = Vec::new();
        for _ in 0..SETTLE_ROUNDS {
            let ids: Vec<u64> = self
                .queue
                .items
                .iter()
                .filter_map(|it| match it.kind {
                    Kind::Marker(id) => Some(id),
                    _ => None,
                })
                .collect();
            let mut changed = false;
            for id in ids {
                let Some(error) = self.error_of(id) else {
                    continue;
                };
                // A settled open is left alone unless it has become late: the valve
                // must be open when its run starts.
                let late_open = error < 0.0 && self.queue.events.get(&id).is_some_and(|e| e.open);
                if settled.contains(&id) && !late_open {
                    continue;
                }
                changed = true;
                if self.fix(id, error, out) {
                    settled.push(id);
                }
            }
            if !changed {
                return;
            }
        }
    }

    /// Moves event `id`'s command (or changes its dwell) by `error` seconds.
    /// True when the command went back to the best placement found before (its error
    /// grew after a step): settling it further would circle.
    fn fix(&mut self, id: u64, error: f64, out: &mut Output<'_>) -> bool {
        let keep_dwell = match self.settle_step(id, error) {
            Step::Done(settled) => return settled,
            Step::Move { keep_dwell } => keep_dwell,
        };
        // Every later command is taken out and placed again after this one, in run
        // order, so the order holds and each finds its own lower bound again: an open
        // that follows a close at once lies before the close's target, and a short run's
        // close lies before its own run's start (its open, put back alone, would stop
        // at that close, behind its own run's close, and wait a dwell for its delay).
        // Taken out last placed first, so each merges its own split.
        let mut later: Vec<u64> = self
            .queue
            .items
            .iter()
            .filter_map(|it| match it.kind {
                Kind::Marker(l) if l > id => Some(l),
                _ => None,
            })
            .collect();
        later.sort_unstable();
        for &l in later.iter().rev() {
            self.undo_marker(l);
        }
        if keep_dwell {
            self.undo_marker(id);
        } else {
            self.undo(id);
        }
        let went_back = self.next_correction(id, error, keep_dwell);
        // Re-placing repeats no warning.
        self.queue.replacing = true;
        self.place(id, out);
        for l in later {
            self.place(l, out);
        }
        self.queue.replacing = false;
        went_back
    }

    /// What settling does with event `id`'s command, `error` seconds off its delay.
    fn settle_step(&mut self, id: u64, error: f64) -> Step {
        let Some((open, clamped)) = self.queue.events.get(&id).map(|e| (e.open, e.clamped)) else {
            return Step::Done(true);
        };
        if self.on_wait_step(id, open, error) {
            return Step::Done(true);
        }
        // An open's own dwell takes the error first, in whole printed steps.
        if let Some(d) = open.then(|| self.owned_dwell(id)).flatten()
            && let Kind::Dwell { seconds, .. } = self.queue.items[d].kind
        {
            // Less than a step off: the open moves over the motion before its wait, where
            // it can go to the microsecond (`G4 P83.4` waits 83 ms on RepRapFirmware, so
            // the wait is `G4 P84` and the open comes 0.6 ms later). Early, it moves
            // later only as far as that motion reaches. Under constant velocity only: with
            // acceleration the split point, printed rounded, can add a stop that moves
            // the commands around it (the previous close) by more than it gains.
            let room = self.find_marker(id).filter(|&m| m < d).map_or(0.0, |m| {
                self.queue.items[d].start - self.queue.items[m].start
            });
            let constant_velocity = self.clock.window == 0;
            if constant_velocity
                && error.abs() < self.dwell_step()
                && error < room
                && (error > 0.0 || !clamped)
            {
                return Step::Move { keep_dwell: true };
            }
            if seconds - error > 0.0 {
                // Less than a step early with no motion to move over: as close as the
                // open can come (early, the safe side). Should the commands around it
                // move it late, a later round takes it up again.
                if self.dwell_up(seconds - error) == seconds {
                    return Step::Done(true);
                }
                self.set_dwell(d, id, seconds - error);
                return Step::Done(false);
            }
        }
        Step::Move { keep_dwell: false }
    }

    /// Whether event `id`'s command sits at an edge of a valve's wait, on the side safe
    /// for the material (an open early, a close late) and less than a printed step off
    /// its delay: the controller times the wait in whole steps, so it can come no closer.
    fn on_wait_step(&self, id: u64, open: bool, error: f64) -> bool {
        let Some(m) = self.find_marker(id) else {
            return false;
        };
        let neighbour = match open {
            true if error > 0.0 => m + 1,
            false if error < 0.0 && m > 0 => m - 1,
            _ => return false,
        };
        error.abs() < self.dwell_step()
            && self
                .queue
                .items
                .get(neighbour)
                .is_some_and(|it| matches!(it.kind, Kind::Dwell { owner: Some(_), .. }))
    }

    /// The next correction of event `id`'s wanted time after an `error` (seconds); true
    /// when it goes back to the better one before. `restart`: the command moves off its
    /// earliest point over the motion before its own wait, where the wanted time with
    /// the wait in place is right as it is.
    fn next_correction(&mut self, id: u64, error: f64, restart: bool) -> bool {
        let Some(e) = self.queue.events.get_mut(&id) else {
            return false;
        };
        if restart && e.clamped {
            e.corr = 0.0;
            e.last = None;
            return false;
        }
        // Secant step on error(corr): a split can add a corner (the printed split
        // point is rounded), so the command's time does not move 1:1 with the wish.
        let slope = match e.last {
            Some((c1, e1)) if (e.corr - c1).abs() > 1e-9 => (error - e1) / (e.corr - c1),
            _ => 1.0,
        };
        let slope = if slope.is_finite() && (0.2..=20.0).contains(&slope) {
            slope
        } else {
            1.0
        };
        // The last step crossed the delay within a millisecond and landed further
        // off: a split there snaps to a block's end, so the time jumps over the
        // delay. The better side of the jump is as close as the command can come.
        let back = match e.last {
            Some((c1, e1))
                if e1.signum() != error.signum()
                    && e1.abs() < error.abs()
                    && (e.corr - c1).abs() < JUMP_S =>
            {
                Some(c1)
            }
            _ => None,
        };
        e.last = Some((e.corr, error));
        match back {
            Some(corr) => e.corr = corr,
            None => e.corr -= error / slope,
        }
        back.is_some()
    }
    /// Creates and places an event.
    pub(super) fn event(&mut self, open: bool, target: u64, span: Span, out: &mut Output<'_>) {
        let id = self.fresh();
        let delay = if open {
            self.valve.open_delay
        } else {
            self.valve.close_delay
        };
        self.queue.events.insert(
            id,
            Event {
                open,
                target,
                delay,
                corr: 0.0,
                last: None,
                original: None,
                clamped: false,
                span,
            },
        );
        self.place(id, out);
    }

    pub(super) fn close_run(&mut self, out: &mut Output<'_>) {
        if let Some(end) = self.run.end.take() {
            let span = self.run.span;
            self.event(false, end, span, out);
        }
        self.run.close_pending = false;
        self.run.active = false;
    }

    /// Checks the commands among the first `count` items one last time before they
    /// leave.
    pub(super) fn check(&mut self, count: usize, out: &mut Output<'_>) {
        self.ensure_timed();
        for (i, it) in self.queue.items.iter().enumerate().take(count) {
            let Kind::Marker(id) = it.kind else { continue };
            let Some(ev) = self.queue.events.get(&id) else {
                continue;
            };
            let Some((_, tt)) = self.target_of(ev) else {
                continue;
            };
            let error = (tt - self.queue.items[i].start) - ev.delay;
            if (ev.open || !ev.clamped) && error.abs() > WARN_TOL {
                let span = ev.span;
                self.warn.unsettled.hit(out, || {
                    Diagnostic::warning(
                        "valve-lookahead::off",
                        format!("this valve command comes {:.4} s before its extrusion event instead of {:.4} s", error + ev.delay, ev.delay),
                    )
                    .at_span(span)
                });
            }
        }
    }
}
