//! Reading the input: what each block is to the valve timing (move, dwell, line of
//! unknown time...), the extrusion runs it starts and ends, and handing out the blocks
//! whose timing can no longer change.

use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, Joints, Motion, Span, Target};
use crate::motion::Segment;

use super::window::{Item, Kind, MoveData, cv_duration};
use super::{HOLD_MARGIN_S, Output, ValveLookahead};
use crate::passes::extrude_rate::material;

impl ValveLookahead {
    /// The joints as the controller reads them: each known axis rounded to the backend's
    /// decimals (with the G92 offsets the backend adds).
    pub(super) fn printed(&self, j: &Joints) -> Joints {
        crate::ir::as_printed(self.track.decimals, j, &self.track.offsets, None)
    }

    /// The segment of motion `m` between printed joints, at its printed feed.
    pub(super) fn segment(&self, m: &Motion, p_from: &Joints, p_to: &Joints) -> Segment {
        let printed_feed = |f: f64| {
            self.track
                .decimals
                .and_then(|d| d.printed_feed(f))
                .unwrap_or(f)
        };
        let feed = crate::ir::Feed {
            mode: m.feed.mode,
            rate: m.feed.rate.map(printed_feed),
        };
        self.clock.model.between(p_from, p_to, m.kind, &feed)
    }

    /// What an input block is in the window (its kind, and whether it extrudes),
    /// tracking position and retraction.
    pub(super) fn classify(&mut self, block: &Block, out: &mut Output<'_>) -> (Kind, bool) {
        match &block.kind {
            BlockKind::Motion(m) => self.classify_move(m, block, out),
            BlockKind::Dwell { seconds } => (
                Kind::Dwell {
                    seconds: *seconds,
                    owner: None,
                },
                false,
            ),
            BlockKind::Command(c) if !c.clobbers.is_empty() => {
                self.track.pos.forget(c.clobbers);
                (Kind::Barrier, false)
            }
            BlockKind::Verbatim(v) => {
                self.track.pos.forget(v.clobbers);
                (Kind::Barrier, false)
            }
            BlockKind::Offset(o) => {
                self.track.offsets = o.offsets;
                (Kind::Other, false)
            }
            _ => (Kind::Other, false),
        }
    }

    /// [`Self::classify`] for a motion block `m`.
    fn classify_move(&mut self, m: &Motion, block: &Block, out: &mut Output<'_>) -> (Kind, bool) {
        let Target::Joints(to) = &m.target else {
            self.track.pos.forget(m.written);
            let span = block.span;
            self.warn.unknown.hit(out, || {
                Diagnostic::warning(
                    "valve-lookahead::unknown-time",
                    "a move to a tool pose has no known time here: valve commands are not moved across it",
                )
                .at_span(span)
                .with_help("run valve-lookahead after inverse kinematics")
            });
            return (Kind::Barrier, false);
        };
        if m.machine_frame {
            self.track.pos.forget(m.written);
            return (Kind::Barrier, false);
        }
        let from = self.track.pos;
        let next = from.updated_by(to);
        let de = match (from.get(Axis::E), next.get(Axis::E)) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        };
        let e_only = de != 0.0
            && Axis::ALL.iter().all(|&a| {
                a == Axis::E
                    || match (from.get(a), next.get(a)) {
                        (Some(p), Some(q)) => p == q,
                        _ => true,
                    }
            });
        let p_from = self.printed(&from);
        let p_to = self.printed(&next);
        self.track.pos = next;
        let material = material(&mut self.track.pending, de);
        if e_only && self.track.e_untimed {
            let kind = if material > 0.0 {
                Kind::Barrier
            } else {
                Kind::Other
            };
            return (kind, material > 0.0);
        }
        let seg = self.segment(m, &p_from, &p_to);
        let extruding = material > 0.0 && seg.moves();
        let data = MoveData {
            from,
            to: next,
            p_from,
            p_to,
            seg,
        };
        (Kind::Move(Box::new(data)), extruding)
    }
    /// Adds an input block of `kind` to the window and starts or ends runs and their
    /// events.
    pub(super) fn push(&mut self, block: Block, kind: Kind, extruding: bool, out: &mut Output<'_>) {
        let cv = match &kind {
            Kind::Move(m) if m.seg.moves() => m.seg.length / m.seg.v_max,
            Kind::Dwell { seconds, .. } => *seconds,
            _ => 0.0,
        };
        let barrier = matches!(kind, Kind::Barrier);
        let breaks = barrier || cv > 0.0;
        let id = self.fresh();
        let span = block.span;
        let (start, dur) = if self.clock.window == 0 && !self.clock.dirty {
            // Constant velocity: the new block's time follows from the last one's.
            (
                self.queue
                    .items
                    .back()
                    .map_or(self.clock.base_time, Item::end),
                cv_duration(&kind),
            )
        } else {
            self.clock.dirty = true;
            (0.0, 0.0)
        };
        let mut item = Item::new(kind, block, extruding, (id, id));
        item.start = start;
        item.dur = dur;
        self.queue.items.push_back(item);
        if extruding {
            self.extrudes(id, span, barrier, out);
        } else if breaks {
            self.breaks(barrier, cv, out);
        }
        if self.queue.items.len() >= self.queue.next_check {
            self.release(false, out);
            self.queue.next_check = self.queue.items.len() + (self.queue.items.len() / 2).max(32);
        }
    }

    /// An extruding item (`id` its identity) came in: it starts a run (an open), or
    /// continues one (bridging a short gap).
    fn extrudes(&mut self, id: u64, span: Span, barrier: bool, out: &mut Output<'_>) {
        if !self.run.active {
            if self.run.close_pending && !barrier {
                self.ensure_timed();
                let gap = match self.run.end.and_then(|e| self.find_end(e)) {
                    Some(e) => {
                        self.queue.items[self.queue.items.len() - 1].start
                            - self.queue.items[e].end()
                    }
                    None => f64::INFINITY,
                };
                // No motion time between (an untimed prime and its moves): one run.
                if gap <= 1e-12 || gap < self.valve.keep_open_gap {
                    self.run.close_pending = false;
                    self.run.active = true;
                } else {
                    self.close_run(out);
                }
            } else if self.run.close_pending {
                self.close_run(out);
            }
            if !self.run.active {
                self.run.active = true;
                self.event(true, id, span, out);
            }
        }
        self.run.end = Some(id);
        self.run.span = span;
        if barrier {
            // An untimed prime: its end is a line of unknown time.
            self.run.active = false;
            self.run.close_pending = true;
            self.run.gap_cv = 0.0;
        }
    }

    /// A non-extruding item that takes time (`cv` seconds at constant velocity) or
    /// stops the machine came in: it ends a run, or lengthens the gap after one.
    fn breaks(&mut self, barrier: bool, cv: f64, out: &mut Output<'_>) {
        if self.run.active {
            self.run.active = false;
            self.run.close_pending = true;
            self.run.gap_cv = 0.0;
        }
        if self.run.close_pending {
            self.run.gap_cv += cv;
            if barrier || self.run.gap_cv >= self.valve.keep_open_gap {
                self.close_run(out);
            }
        }
    }

    /// Hands out the items whose timing and commands can no longer change (all of them
    /// at the end).
    pub(super) fn release(&mut self, all: bool, out: &mut Output<'_>) {
        self.settle(out);
        self.ensure_timed();
        let n = self.queue.items.len();
        let count = if all { n } else { self.settled_count() };
        let forced = if !all && n - count > self.queue.max_lookahead {
            n - self.queue.max_lookahead * 3 / 4
        } else {
            count
        };
        if forced > count {
            let span = self.queue.items[0].block.span;
            let max = self.queue.max_lookahead;
            self.warn.windowed.hit(out, || {
                Diagnostic::warning(
                    "valve-lookahead::window",
                    format!("more than max_lookahead = {max} blocks fall within the valve delays here: older blocks are passed on and valve commands cannot go before them"),
                )
                .at_span(span)
                .with_help("raise max_lookahead")
            });
        }
        self.check(forced, out);
        let forced = forced.min(self.queue.items.len());
        if forced == 0 {
            return;
        }
        // The window's new start: the time and planner state after the last item out
        // (the last stop or moving move among them decides the state).
        self.clock.base_time = self.queue.items[forced - 1].end();
        if let Some(it) = self
            .queue
            .items
            .range(..forced)
            .rev()
            .find(|it| it.is_stop() || it.moving().is_some())
        {
            self.clock.base_last = match &it.kind {
                Kind::Move(m) => Some((m.seg, it.speeds.1)),
                _ => None,
            };
        }
        for it in self.queue.items.drain(..forced) {
            if let Kind::Marker(id) = it.kind {
                self.queue.events.remove(&id);
            }
            out.push(it.block);
        }
    }

    /// How many items, from the window's start, have a timing that can no longer
    /// change and no valve command still to come before them.
    fn settled_count(&self) -> usize {
        let n = self.queue.items.len();
        // The last item whose timing is final: `window + 1` moves or a stop after it.
        let mut moves_after = 0usize;
        let mut h = None;
        for i in (0..n).rev() {
            if self.queue.items[i].is_stop() || moves_after > self.clock.window {
                h = Some(i);
                break;
            }
            if self.queue.items[i].moving().is_some() {
                moves_after += 1;
            }
        }
        let mut limit = match h {
            _ if self.clock.window == 0 && n > 0 => self.queue.items[n - 1].end() - self.queue.hold,
            Some(h) => self.queue.items[h].start - self.queue.hold,
            None => f64::NEG_INFINITY,
        };
        if self.run.close_pending
            && let Some(e) = self.run.end.and_then(|e| self.find_end(e))
        {
            limit = limit.min(self.queue.items[e].end() - self.valve.close_delay - HOLD_MARGIN_S);
        }
        let mut q = 0usize;
        while q < n && self.queue.items[q].end() <= limit {
            q += 1;
        }
        // Keep the moves whose look-ahead reaches past the limit.
        let mut k = q;
        let mut seen = 0usize;
        while k > 0 && seen < self.clock.window + 2 {
            k -= 1;
            if self.queue.items[k].moving().is_some() {
                seen += 1;
            }
        }
        if self.clock.window == 0 { q } else { k }
    }
}
