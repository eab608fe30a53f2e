//! The look-ahead window: what is known of each held block, its timing by the
//! controller's planner, and splitting a held move or dwell at a point in time.

use crate::ir::{Block, BlockKind, FeedMode, Joints, MotionKind, Target};
use crate::motion::arc::ArcPath;
use crate::motion::{self, Profile, Segment};

use super::ValveLookahead;

/// A move held in the window: its IR ends and the printed ends the controller reads.
#[derive(Debug, Clone)]
pub(super) struct MoveData {
    pub(super) from: Joints,
    pub(super) to: Joints,
    pub(super) p_from: Joints,
    pub(super) p_to: Joints,
    pub(super) seg: Segment,
}

/// What a held block is to the valve timing.
#[derive(Debug, Clone)]
pub(super) enum Kind {
    /// A move with its segment.
    Move(Box<MoveData>),
    /// A dwell: stops the machine, takes `seconds`; `owner` is the event that inserted it.
    Dwell { seconds: f64, owner: Option<u64> },
    /// A line of unknown time: stops the machine; nothing moves across it.
    Barrier,
    /// No time, no stop.
    Other,
    /// The valve command of event `id`.
    Marker(u64),
}

/// A held block and what the window knows of it.
#[derive(Debug, Clone)]
pub(super) struct Item {
    pub(super) kind: Kind,
    pub(super) block: Block,
    pub(super) extruding: bool,
    /// Identity of the item's start (kept by the first part when it is split).
    pub(super) start_id: u64,
    /// Identity of the item's end (kept by the last part).
    pub(super) end_id: u64,
    pub(super) start: f64,
    pub(super) dur: f64,
    /// Entry and exit speed of a move as timed.
    pub(super) speeds: (f64, f64),
}

impl Item {
    /// An untimed item of `kind` for `block`, starting and ending at `start_id`/`end_id`.
    pub(super) fn new(kind: Kind, block: Block, extruding: bool, ids: (u64, u64)) -> Item {
        Item {
            kind,
            block,
            extruding,
            start_id: ids.0,
            end_id: ids.1,
            start: 0.0,
            dur: 0.0,
            speeds: (0.0, 0.0),
        }
    }
    pub(super) fn end(&self) -> f64 {
        self.start + self.dur
    }
    pub(super) fn moving(&self) -> Option<&Segment> {
        match &self.kind {
            Kind::Move(m) if m.seg.moves() => Some(&m.seg),
            _ => None,
        }
    }
    pub(super) fn is_stop(&self) -> bool {
        matches!(self.kind, Kind::Dwell { .. } | Kind::Barrier)
    }
}

/// Seconds an item takes at constant velocity (a dwell its time).
pub(super) fn cv_duration(kind: &Kind) -> f64 {
    match kind {
        Kind::Move(m) if m.seg.moves() => m.seg.length / m.seg.v_max,
        Kind::Dwell { seconds, .. } => seconds.max(0.0),
        _ => 0.0,
    }
}

/// What a dwell carries in the IR, when nothing prints it: whole microseconds.
const IR_DWELL_STEP: f64 = 1e-6;

/// Rounds seconds to whole microseconds (a dwell a command splits keeps them).
pub(super) fn micros(seconds: f64) -> f64 {
    (seconds * 1e6).round() / 1e6
}

/// What a printed dwell carries, seconds: every backend prints `G4` in whole
/// milliseconds (RepRapFirmware, Marlin, Fanuc `P` in ms; Grbl, LinuxCNC `P` in seconds
/// at 3 decimals), and the controller waits just that long.
pub(super) const PRINTED_DWELL_STEP: f64 = 1e-3;

impl ValveLookahead {
    /// The resolution of the dwells this pass inserts or splits: whole milliseconds when
    /// a backend prints them, whole microseconds in the IR.
    pub(super) fn dwell_step(&self) -> f64 {
        if self.track.decimals.is_some() {
            PRINTED_DWELL_STEP
        } else {
            IR_DWELL_STEP
        }
    }

    /// `seconds` to the nearest printable dwell.
    pub(super) fn dwell_nearest(&self, seconds: f64) -> f64 {
        let step = self.dwell_step();
        (seconds / step).round() * step
    }

    /// `seconds` up to the next printable dwell: a wait for the valve must not come out
    /// shorter than the valve needs (`G4 P83` for 83.4 ms starts the run 0.4 ms before
    /// the valve is open, and a short first block then lacks a third of its material).
    /// A hair over a whole step (float noise) stays on it.
    pub(super) fn dwell_up(&self, seconds: f64) -> f64 {
        let step = self.dwell_step();
        (seconds / step - 1e-6).ceil() * step
    }

    /// `seconds` down to the previous printable dwell (a hair under a whole step stays
    /// on it).
    pub(super) fn dwell_down(&self, seconds: f64) -> f64 {
        let step = self.dwell_step();
        (seconds / step + 1e-6).floor() * step
    }
}

impl ValveLookahead {
    pub(super) fn fresh(&mut self) -> u64 {
        self.queue.next_id += 1;
        self.queue.next_id
    }

    /// A new item with its own identity.
    pub(super) fn item(&mut self, kind: Kind, block: Block, extruding: bool) -> Item {
        let id = self.fresh();
        Item::new(kind, block, extruding, (id, id))
    }

    /// Recomputes the time of every held item from the state at the window's start, as
    /// the controller's planner ([`motion::Planner`]) would: each move knows the
    /// `lookahead` moves after it up to the next stop, and must be able to stop at the
    /// end of what it knows.
    pub(super) fn retime(&mut self) {
        self.clock.dirty = false;
        if self.clock.window == 0 {
            // Constant velocity: every block's time is its own.
            let mut time = self.clock.base_time;
            for it in self.queue.items.iter_mut() {
                it.start = time;
                it.dur = cv_duration(&it.kind);
                time = it.end();
            }
            return;
        }
        let items = &self.queue.items;
        let n = items.len();
        // The moving moves' segments in order, and for each item the index of the next
        // stop.
        let moving: Vec<(usize, Segment)> = items
            .iter()
            .enumerate()
            .filter_map(|(i, it)| it.moving().map(|s| (i, *s)))
            .collect();
        let mut next_stop = vec![n; n + 1];
        for i in (0..n).rev() {
            next_stop[i] = if items[i].is_stop() {
                i
            } else {
                next_stop[i + 1]
            };
        }
        let mut last = self.clock.base_last;
        let mut time = self.clock.base_time;
        let mut k = 0usize;
        for (i, &stop) in next_stop.iter().enumerate().take(n) {
            let (dur, speeds) = match self.queue.items[i].moving() {
                Some(&seg) => {
                    let p = self.plan_move(&moving, k, stop, last, &seg);
                    last = Some((seg, p.v_exit));
                    k += 1;
                    (p.duration(), (p.v_entry, p.v_exit))
                }
                None => {
                    if self.queue.items[i].is_stop() {
                        last = None;
                    }
                    (cv_duration(&self.queue.items[i].kind), (0.0, 0.0))
                }
            };
            let it = &mut self.queue.items[i];
            it.start = time;
            it.dur = dur;
            it.speeds = speeds;
            time = it.end();
        }
    }

    /// The profile of `seg`, the `k`th moving move, entered after `last` (the previous
    /// move and its exit speed; `None` from a stop): it must be able to stop at the end
    /// of the `window` moves it sees before the next stop (item index `stop`).
    fn plan_move(
        &self,
        moving: &[(usize, Segment)],
        k: usize,
        stop: usize,
        last: Option<(Segment, f64)>,
        seg: &Segment,
    ) -> Profile {
        let model = &self.clock.model;
        let mut end = k;
        while end + 1 < moving.len() && end < k + self.clock.window && moving[end + 1].0 < stop {
            end += 1;
        }
        let mut exit = 0.0f64;
        for j in (k + 1..=end).rev() {
            let s = moving[j].1;
            exit = (exit * exit + 2.0 * s.accel * s.length)
                .sqrt()
                .min(s.v_max)
                .min(model.junction(&moving[j - 1].1, &s));
        }
        let entry = match &last {
            Some((prev, v)) => v.min(model.junction(prev, seg)),
            None => 0.0,
        };
        let exit = exit.min((entry * entry + 2.0 * seg.accel * seg.length).sqrt());
        Profile::new(seg, entry, exit)
    }

    /// The speed profile of a held move as last timed.
    pub(super) fn profile_of(&self, it: &Item) -> Option<Profile> {
        let Kind::Move(m) = &it.kind else {
            return None;
        };
        let mut seg = m.seg;
        if self.clock.window == 0 {
            seg.accel = f64::INFINITY;
        }
        Some(Profile::new(&seg, it.speeds.0, it.speeds.1))
    }

    /// Splits item `i` `dt` seconds into it; returns the end id of the first part and
    /// the start id of the second. A valve's wait splits on whole printed steps, towards
    /// the safe side of the command: `early` (an open: the valve is open before the
    /// material comes) or late (a close: the flow stops after the material ends).
    pub(super) fn split(&mut self, i: usize, dt: f64, early: bool) -> Option<(u64, u64)> {
        let it = &self.queue.items[i];
        let (first, second) = match &it.kind {
            Kind::Move(m) => self.split_move(it, m, dt)?,
            Kind::Dwell { seconds, owner } => {
                let owner = *owner;
                // A valve's wait is on the printed dwells' grid, and so are its parts (each
                // is printed on its own).
                let a = match owner {
                    Some(_) if early => self.dwell_down(dt),
                    Some(_) => self.dwell_up(dt),
                    None => micros(dt),
                };
                let b = match owner {
                    Some(_) => self.dwell_nearest(seconds - a),
                    None => micros(seconds - a),
                };
                if a <= 0.0 || b <= 0.0 {
                    return None;
                }
                let mut ba = it.block.clone();
                ba.kind = BlockKind::Dwell { seconds: a };
                let mut bb = it.block.clone();
                bb.kind = BlockKind::Dwell { seconds: b };
                bb.comments.clear();
                (
                    (ba, Kind::Dwell { seconds: a, owner }),
                    (bb, Kind::Dwell { seconds: b, owner }),
                )
            }
            _ => return None,
        };
        let (start_id, end_id, extruding) = (it.start_id, it.end_id, it.extruding);
        let (mid_end, mid_start) = (self.fresh(), self.fresh());
        self.queue.items[i] = Item::new(first.1, first.0, extruding, (start_id, mid_end));
        let b = Item::new(second.1, second.0, extruding, (mid_start, end_id));
        self.queue.items.insert(i + 1, b);
        self.clock.dirty = true;
        Some((mid_end, mid_start))
    }

    /// The two parts of held move `it` (data `m`) split `dt` seconds into it, or `None`
    /// where it is not split: an arc with extra turns, a split point that prints as one
    /// of the ends, or a sliver part.
    fn split_move(
        &self,
        it: &Item,
        m: &MoveData,
        dt: f64,
    ) -> Option<((Block, Kind), (Block, Kind))> {
        let prof = self.profile_of(it)?;
        let f = prof.fraction_at(dt);
        if !(f > 1e-9 && f < 1.0 - 1e-9) {
            return None;
        }
        let BlockKind::Motion(motion) = &it.block.kind else {
            return None;
        };
        let mid = match motion.kind {
            MotionKind::Arc(a) if a.extra_turns == 0 => ArcPath::new(&m.from, &m.to, &a)?.point(f),
            MotionKind::Arc(_) => return None,
            _ => motion::lerp(&m.from, &m.to, f),
        };
        let p_mid = self.printed(&mid);
        if p_mid == m.p_from || p_mid == m.p_to {
            return None;
        }
        let mut ma = motion.clone();
        ma.target = Target::Joints(mid);
        let mut mb = motion.clone();
        if motion.feed.mode == FeedMode::InverseTime
            && let Some(rate) = motion.feed.rate
        {
            // Each part keeps its share of the move's time.
            ma.feed.rate = Some(rate / f);
            mb.feed.rate = Some(rate / (1.0 - f));
        }
        let da = MoveData {
            from: m.from,
            to: mid,
            p_from: m.p_from,
            p_to: p_mid,
            seg: self.segment(&ma, &m.p_from, &p_mid),
        };
        let db = MoveData {
            from: mid,
            to: m.to,
            p_from: p_mid,
            p_to: m.p_to,
            seg: self.segment(&mb, &p_mid, &m.p_to),
        };
        let mut ba = it.block.clone();
        ba.kind = BlockKind::Motion(ma);
        let mut bb = it.block.clone();
        bb.kind = BlockKind::Motion(mb);
        bb.comments.clear();
        Some((
            (ba, Kind::Move(Box::new(da))),
            (bb, Kind::Move(Box::new(db))),
        ))
    }
}
