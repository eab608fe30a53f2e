//! The comparison of the printed program, as [`Reader`](super::Reader) reads it, with the
//! programmed path ([`Vertex`]es): printed blocks are matched to programmed vertices in
//! order. A printed end whose tool pose lands on programmed vertex `j` closes segment `j`;
//! every sample of the printed moves before it must lie within the tolerances of segment
//! `j`, and the printed time between the two hits is that segment's time.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use super::path::{Kinematics, Pose, Vertex, angle, line_param, off_arc, off_segment};
use super::reader::{Event, Move};
use super::{Figures, Tolerances};
use crate::ir::{AXIS_COUNT, Axis, Feed, FeedMode, Joints, MotionKind};
use crate::machine::polar::Polar;
use crate::motion::arc::ArcPath;
use crate::motion::{Model, lerp};
use nalgebra::{Point3, distance};

/// The programmed vertices on their way from the tap to the checker.
pub type Queue = Arc<Mutex<VecDeque<Vertex>>>;

/// Below this tip travel, mm, a programmed segment is a reorientation (no feed time).
const ZERO_TIP: f64 = 1e-6;

/// Samples of a printed move that leaves its straight line (a rotary or θ turns).
const CURVE_SAMPLES: usize = 4;

/// Valve commands kept for matching to their extrusion starts and ends.
const RECENT_COMMANDS: usize = 8;

/// Takes the time in `times` nearest `t`.
fn nearest(times: &mut VecDeque<f64>, t: f64) -> Option<f64> {
    let k =
        (0..times.len()).min_by(|&a, &b| (times[a] - t).abs().total_cmp(&(times[b] - t).abs()))?;
    times.remove(k)
}

/// Samples of a printed arc.
const ARC_SAMPLES: usize = 16;

/// The polar printer's screw and valve, as the material and valve figures need them.
#[derive(Debug, Clone, Copy)]
struct Screw {
    e_per_rev: f64,
    open_delay: f64,
    close_delay: f64,
}

/// The valve as the controller drives it: commands take effect after the valve's delay.
#[derive(Debug, Default)]
struct Valve {
    /// Open now (at the checker's clock).
    open: bool,
    /// Changes still to come: (seconds, open), in time order.
    changes: VecDeque<(f64, bool)>,
    /// When the recent open commands not matched to an extrusion start take effect.
    opens: VecDeque<f64>,
    /// When the recent close commands not matched to an extrusion end take effect.
    closes: VecDeque<f64>,
    /// An extrusion start (seconds) waiting for its open command.
    start: Option<(f64, u64, u32)>,
    /// An extrusion end waiting for its close command.
    end: Option<(f64, u64, u32)>,
    /// Screw speed, rev/min.
    rpm: f64,
}

/// Compares a printed program with its programmed path, one event at a time.
pub struct Checker {
    kin: Kinematics,
    /// The tool axis can turn (a 5-axis machine): its deviation is measured.
    turns_tool: bool,
    model: Model,
    tol: Tolerances,
    limits: [Option<(f64, f64)>; AXIS_COUNT],
    screw: Option<Screw>,
    shared: Queue,
    queue: VecDeque<Vertex>,
    /// The programmed vertex last reached.
    prev: Option<Vertex>,
    /// The printed pose last computed and its joints.
    last: Option<(Joints, Pose)>,
    clock: f64,
    /// Of the segment being traced: printed seconds, the seconds at the programmed feed
    /// and at the slowest feed the machine's limits may ask for (both under the axes'
    /// caps), the tip's length and the material.
    seg: [f64; 5],
    /// When the previous segment was reached (where an extrusion ends).
    seg_start: f64,
    /// When the first printed move of this segment began (where an extrusion starts).
    seg_first: Option<f64>,
    /// How far along the segment (its path parameter, 0 to 1) the last printed move of
    /// it ended.
    seg_t: f64,
    /// A feed move of the current segment was printed.
    seg_fed: bool,
    /// An extrusion start waiting for the printed path to pass this share of its
    /// segment (the E before it restores a retraction).
    deferred: Option<f64>,
    /// A move of this segment started where the controller did not know the position.
    blind: bool,
    /// The segment being traced deposits material.
    extruding: bool,
    valve: Valve,
    figures: Figures,
}

impl Checker {
    /// A checker for printed joints through `kin`, timed by `model`, taking the
    /// programmed vertices from `queue`.
    pub fn new(
        kin: Kinematics,
        model: &Model,
        tol: Tolerances,
        polar: Option<&Polar>,
        queue: Queue,
    ) -> Checker {
        let mut limits = [None; AXIS_COUNT];
        match (&kin, polar) {
            (Kinematics::Machine(m), _) => {
                for a in Axis::ALL {
                    limits[a.index()] = m.limits(a);
                }
            }
            (_, Some(p)) => limits[p.r_axis.index()] = Some((p.r_min(), p.r_max)),
            _ => {}
        }
        Checker {
            turns_tool: matches!(kin, Kinematics::Machine(_)),
            kin,
            model: model
                .clone()
                .with_timing(crate::motion::Timing::ConstantVelocity),
            tol,
            limits,
            screw: polar.map(|p| Screw {
                e_per_rev: p.screw.e_per_rev,
                open_delay: p.valve.open_delay_s,
                close_delay: p.valve.close_delay_s,
            }),
            shared: queue,
            queue: VecDeque::new(),
            prev: None,
            last: None,
            clock: 0.0,
            seg: [0.0; 5],
            seg_start: 0.0,
            seg_first: None,
            seg_t: 0.0,
            seg_fed: false,
            deferred: None,
            blind: false,
            extruding: false,
            valve: Valve::default(),
            figures: Figures::default(),
        }
    }

    /// Takes one event of printed line `line`.
    pub fn event(&mut self, event: &Event, line: u64) {
        match event {
            Event::Move(m) => self.on_move(m, line),
            Event::Dwell(s) => self.advance(*s),
            Event::Valve(open) => self.on_valve(*open, line),
            Event::Screw(rpm) => self.valve.rpm = *rpm,
            Event::Lost(_) => {
                self.prev = None;
                self.last = None;
            }
        }
    }

    /// The figures after the last event: programmed vertices never reached and open
    /// valve business count.
    pub fn finish(mut self) -> Figures {
        self.refill();
        if let Some(v) = self.queue.front() {
            self.unmatched(v.line);
            self.figures.unmatched += self.queue.len() as u64 - 1;
        }
        if let Some((_, line, source)) = self.valve.start.take().or(self.valve.end.take()) {
            self.figures.valve.note(f64::INFINITY, line, source);
        }
        self.figures.seconds = self.clock;
        self.figures
    }

    /// Moves the clock on by `seconds`, depositing what the screw and valve let through.
    fn advance(&mut self, seconds: f64) {
        let end = self.clock + seconds.max(0.0);
        if let Some(s) = self.screw {
            let v = &mut self.valve;
            let mut t = self.clock;
            let mut open_s = 0.0;
            while let Some(&(at, open)) = v.changes.front() {
                if at > end {
                    break;
                }
                if v.open {
                    open_s += (at - t).max(0.0);
                }
                t = t.max(at);
                v.open = open;
                v.changes.pop_front();
            }
            if v.open {
                open_s += end - t;
            }
            let material = open_s * v.rpm * s.e_per_rev / 60.0;
            self.seg[4] += material;
            self.figures.material_printed += material;
        }
        self.clock = end;
    }

    fn on_valve(&mut self, open: bool, line: u64) {
        let Some(s) = self.screw else { return };
        let at = self.clock + if open { s.open_delay } else { s.close_delay };
        let v = &mut self.valve;
        let k = v
            .changes
            .iter()
            .rposition(|c| c.0 <= at)
            .map_or(0, |k| k + 1);
        v.changes.insert(k, (at, open));
        let (waiting, own) = if open {
            (v.start.take(), &mut v.opens)
        } else {
            (v.end.take(), &mut v.closes)
        };
        match waiting {
            Some((t, _, source)) => self.figures.valve.note((at - t).abs(), line, source),
            None => {
                // The look-ahead issues a command a whole delay ahead, which may be
                // several extrusions ahead on short ones; a few are kept to match.
                if own.len() >= RECENT_COMMANDS {
                    own.pop_front();
                }
                own.push_back(at);
            }
        }
    }

    /// The programmed vertex the printed path heads for.
    fn target(&mut self, k: usize) -> Option<Vertex> {
        if self.queue.len() <= k {
            self.refill();
        }
        self.queue.get(k).cloned()
    }

    fn refill(&mut self) {
        if let Ok(mut q) = self.shared.lock() {
            self.queue.extend(q.drain(..));
        }
    }

    fn pose(&mut self, j: &Joints) -> Pose {
        match &self.last {
            Some((at, pose)) if at == j => *pose,
            _ => self.kin.printed(j),
        }
    }

    /// Whether a printed pose in the programmed frame reaches `v` (a machine-frame
    /// vertex is reached only by a printed `G53` move).
    fn hits(&self, pose: &Pose, v: &Vertex) -> bool {
        !v.machine
            && off_known(&pose.0, v) <= self.tol.hit_tip()
            && angle(&pose.1, &v.axis) <= self.tol.hit_axis()
    }

    /// A programmed vertex the printed program never reaches.
    fn unmatched(&mut self, source: u32) {
        if self.figures.unmatched == 0 {
            self.figures.unmatched_line = source;
        }
        self.figures.unmatched += 1;
    }

    /// A printed `G53` move: it reaches the programmed `G53` move it heads for, in the
    /// machine frame, and takes its time; where the controller then is in the
    /// programmed frame is not traced (the programmed path starts afresh after it).
    fn on_machine_move(&mut self, m: &Move, line: u64) {
        self.advance(m.seconds);
        self.last = None;
        if self.target(0).is_some_and(|t| t.machine) {
            self.seg = [0.0; 5];
            self.blind = true;
            self.close(line);
        }
    }

    fn on_move(&mut self, m: &Move, line: u64) {
        self.margins(&m.to, line);
        if m.machine {
            self.on_machine_move(m, line);
            return;
        }
        let start = self.pose(&m.from);
        let end = self.kin.printed(&m.to);
        self.last = Some((m.to, end));
        // A programmed segment of no length is not printed: step over it.
        while let (Some(p), Some(t)) = (self.prev.as_ref().map(|p| (p.tip, p.axis)), self.target(0))
        {
            // (A full circle ends where it starts, but it is printed.)
            if self.hits(&end, &t) || !self.hits(&p, &t) || t.arc.is_some() || t.machine {
                break;
            }
            self.close(line);
        }
        let Some(target) = self.target(0) else {
            self.advance(m.seconds);
            return;
        };
        if self.seg_first.is_none() {
            self.begin(&target, line);
        }
        // A move from a position the controller does not know takes no time it can tell.
        self.blind |= !m
            .from
            .known
            .union(m.to.known)
            .difference(m.from.known)
            .is_empty();
        let (path, t) = self.sample(m, [start, end], &target, line);
        if self
            .deferred
            .is_some_and(|share| t > share || self.hits(&end, &target))
        {
            // The retraction is restored within this printed block: the screw's speed is
            // one per block, so the material flows from the block's start.
            self.deferred = None;
            self.extrusion_start(line, target.line);
        }
        self.advance(m.seconds);
        let length = match (&target.arc, &self.prev) {
            // A programmed arc's time is its own length's, however its pieces cut it.
            (Some(arc), Some(_)) if !target.rapid => {
                let run = std::mem::replace(&mut self.seg_t, t);
                arc.stretch(run, t).1
            }
            // The programmed time of a 5-axis segment is its straight line at the
            // programmed feed, and the pieces' ends lie on that line: each piece counts
            // its chord. The joint-linear path between them bulges off the line within
            // the tip tolerance (checked in `sample`); its extra length, up to a few per
            // cent on short pieces with the whole tolerance's sag, is no time the program
            // asked for.
            _ if self.turns_tool && m.arc.is_none() => distance(&start.0, &end.0),
            _ => path,
        };
        self.seg[0] += m.seconds;
        self.seg[3] += length;
        self.seg_fed |= !m.rapid;
        if target.feed > 0.0
            && !target.rapid
            && m.rapid
            && !self.seg_fed
            && distance(&start.0, &end.0) <= self.tol.hit_tip()
        {
            // A rapid that turns the tool with the tip still (within the printed digits)
            // before a cutting segment's first feed move (the free rotary's swing `ik`
            // makes at the rapid before a cut leaving a singular pose): the controller's
            // G0 time, which the programmed feed does not govern. Inside the cut, a tip
            // standing still is a time error (it dwells in the material).
            self.seg[1] += m.seconds;
            self.seg[2] += m.seconds;
        } else if target.feed > 0.0 && !target.rapid {
            let feed = target.feed / 60.0;
            let capped = feed.min(self.kin.speed_cap(&m.from, &m.to));
            let cap_time = self.cap_time(m);
            self.seg[1] += (length / feed).max(cap_time);
            self.seg[2] += (length / capped).max(cap_time);
        }
        let complete = self.kin.complete(&m.to);
        if (complete && self.hits(&end, &target)) || (!complete && target.partial()) {
            self.close(line);
        } else if complete && self.target(1).is_some_and(|next| self.hits(&end, &next)) {
            // Vertex `j` was missed: how far its segment ended from it counts (unless
            // the controller did not know where it was), and the printed path goes on
            // with the next one.
            if target.machine {
                self.unmatched(target.line);
            } else if !(target.partial() || target.fresh || self.blind) {
                self.figures
                    .tip
                    .note(distance(&start.0, &target.tip), line, target.line);
            }
            self.close(line);
            self.close(line);
        }
    }

    /// Samples the printed move `m` against the segment leading to `target`; returns
    /// the printed tip's path length and how far along the segment the move ends (its
    /// path parameter; 0 when neither its arc nor an extrusion start waits for it).
    fn sample(
        &mut self,
        m: &Move,
        [start, end]: [Pose; 2],
        target: &Vertex,
        line: u64,
    ) -> (f64, f64) {
        let check = !(target.rapid || target.fresh || m.rapid || self.blind) && self.prev.is_some();
        let a = self.prev.as_ref().map_or(start, |p| (p.tip, p.axis));
        let arc = m.arc.and_then(|arc| ArcPath::new(&m.from, &m.to, &arc));
        let n = if arc.is_some() {
            ARC_SAMPLES
        } else if self.kin.curves(&m.from, &m.to) {
            CURVE_SAMPLES
        } else {
            1
        };
        let mut length = 0.0;
        let mut last = start.0;
        for k in 1..=n {
            let f = k as f64 / n as f64;
            let pose = match &arc {
                Some(path) => self.kin.printed(&path.point(f)),
                None if k == n => end,
                None => self.kin.printed(&lerp(&m.from, &m.to, f)),
            };
            length += distance(&last, &pose.0);
            last = pose.0;
            if check {
                let [p, from] = [pose.0, a.0].map(|q| on_known(q, target));
                let tip = off_segment(&p, &from, &target.tip, target.arc.as_deref());
                self.figures.tip.note(tip, line, target.line);
                if self.turns_tool {
                    let axis = off_arc(&pose.1, &a.1, &target.axis);
                    self.figures.axis.note(axis, line, target.line);
                }
            }
        }
        let t = match &target.arc {
            _ if self.hits(&end, target) => 1.0,
            Some(arc) => arc.param(&end.0, self.seg_t),
            None if self.deferred.is_some() => line_param(&end.0, &a.0, &target.tip),
            None => 0.0,
        };
        (length, t)
    }

    /// Seconds the controller needs for `m` at its axes' caps alone (0 without caps).
    fn cap_time(&self, m: &Move) -> f64 {
        let feed = Feed {
            mode: FeedMode::PerMinute,
            rate: Some(1e12),
        };
        let seg = self
            .model
            .between(&m.from, &m.to, MotionKind::Linear, &feed);
        if seg.moves() {
            seg.length / seg.v_max
        } else {
            0.0
        }
    }

    /// The printed path has reached the target vertex: its segment's figures.
    fn close(&mut self, line: u64) {
        let Some(v) = self.queue.pop_front() else {
            return;
        };
        let [printed, fast, slow, length, material] = std::mem::take(&mut self.seg);
        self.seg_t = 0.0;
        self.seg_fed = false;
        if self.deferred.take().is_some() {
            self.extrusion_start(line, v.line);
        }
        let blind = std::mem::take(&mut self.blind);
        let traced = !v.fresh && self.prev.is_some() && !blind;
        if traced && !v.rapid && v.feed > 0.0 && length > ZERO_TIP && fast > 0.0 {
            // Faster than the programmed feed, or slower than the limits ask for.
            let error = if printed < fast {
                (fast - printed) / fast
            } else {
                (printed - slow).max(0.0) / slow
            };
            self.figures.time.note(error, line, v.line);
        }
        if self.screw.is_some() {
            self.figures.material_programmed += v.material;
            if v.material > 1e-9 {
                self.figures.material_block.note(
                    (material - v.material).abs() / v.material,
                    line,
                    v.line,
                );
            }
        }
        self.figures.segments += 1;
        self.seg_start = self.clock;
        self.seg_first = None;
        self.prev = Some(v);
    }

    /// The first printed move of the segment to `target` begins: an extrusion starts
    /// here, or the one before ended when the previous segment was reached.
    fn begin(&mut self, target: &Vertex, line: u64) {
        self.seg_first = Some(self.clock);
        if self.screw.is_none() {
            return;
        }
        // Segments of no length are stepped over: the state is the last traced one's.
        let was = std::mem::replace(&mut self.extruding, target.material > 1e-9);
        let is = self.extruding;
        if is && !was && target.restore > 0.0 && self.prev.is_some() {
            self.deferred = Some(target.restore);
        } else if is && !was {
            self.extrusion_start(line, target.line);
        } else if was && !is {
            self.extrusion_end(line, target.line);
        }
    }

    fn extrusion_start(&mut self, line: u64, source: u32) {
        let t = self.clock;
        let v = &mut self.valve;
        v.end = None;
        match nearest(&mut v.opens, t) {
            Some(at) => self.figures.valve.note((at - t).abs(), line, source),
            // Kept open across the gap: nothing to time.
            None if v.open && v.changes.iter().all(|c| c.1) => {}
            None => v.start = Some((t, line, source)),
        }
    }

    fn extrusion_end(&mut self, line: u64, source: u32) {
        let t = self.seg_start;
        let v = &mut self.valve;
        v.start = None;
        match nearest(&mut v.closes, t) {
            Some(at) => self.figures.valve.note((at - t).abs(), line, source),
            None => v.end = Some((t, line, source)),
        }
    }

    fn margins(&mut self, j: &Joints, line: u64) {
        for a in j.known.iter() {
            if let (Some((lo, hi)), Some(v)) = (self.limits[a.index()], j.get(a)) {
                let margin = (v - lo).min(hi - v);
                if self.figures.margin.is_none_or(|(m, _, _)| margin < m) {
                    self.figures.margin = Some((margin, a.letter(), line));
                }
            }
        }
    }
}

/// Distance of the printed tip `p` from vertex `v` along the axes `v` knows.
fn off_known(p: &Point3<f64>, v: &Vertex) -> f64 {
    distance(&on_known(*p, v), &v.tip)
}

/// The printed point `p` where vertex `v` knows its axes, and at `v`'s own coordinate
/// (0) where it does not: where the program lost an axis (homing, a line it copied as
/// written) and the printed program knows it again (an arc's end named it), only the
/// axes both know are compared.
fn on_known(mut p: Point3<f64>, v: &Vertex) -> Point3<f64> {
    for (k, a) in [Axis::X, Axis::Y, Axis::Z].into_iter().enumerate() {
        if !v.known.contains(a) {
            p[k] = v.tip[k];
        }
    }
    p
}
