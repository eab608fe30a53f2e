//! The screw modes (`screw-rpm`, `constant-flow`): each block is queued in the
//! controller's planner with what it means for the screw, and put out with the screw
//! command its timing asks for.

use std::fmt::Write as _;

use crate::diag::Diagnostic;
use crate::ir::{
    Axis, AxisSet, Block, BlockKind, Command, Comment, CommentStyle, FeedMode, Joints, MotionKind,
    OffsetCode, Span, Target, Text,
};
use crate::machine::{FeedRule, RapidRule};
use crate::motion::{self, Segment, Timed};
use crate::num::print::remember_printed;
use crate::num::print::{printed, write_fixed};

use super::{ExtrudeRate, Item, Limit, Mode, Output, Role, Rule, material};

impl ExtrudeRate {
    /// The joints as the controller reads them: each known axis but E rounded to the
    /// backend's decimals (offsets included), E forgotten (the screw modes print none).
    fn printed(&self, j: &Joints) -> Joints {
        self.printed_reusing(j, None)
    }

    /// [`Self::printed`], taking unchanged axes' printed values from `seen` (see
    /// [`Decimals::printed_joints`]).
    fn printed_reusing(&self, j: &Joints, seen: Option<&(Joints, Joints)>) -> Joints {
        let mut p = *j;
        p.forget(AxisSet::from_iter([Axis::E]));
        crate::ir::as_printed(self.decimals, &p, &self.offsets, seen)
    }

    fn printed_feed(&self, f: f64) -> f64 {
        self.decimals.and_then(|d| d.printed_feed(f)).unwrap_or(f)
    }

    /// The largest printable feed not above `f` (a slowed block must not come out
    /// faster than `max_rpm` allows by rounding).
    fn printed_feed_down(&self, f: f64) -> f64 {
        match self.decimals {
            Some(d) => {
                let scale = 10f64.powi(d.feed as i32);
                let down = (f * scale).floor() / scale;
                if down > 0.0 { down } else { f }
            }
            None => f,
        }
    }

    fn printed_rpm(&self, rpm: f64) -> f64 {
        let d = self.options.rpm_decimals;
        printed(rpm, d).unwrap_or(rpm)
    }

    /// The Cartesian tool point of a joint vector (`None` if it is not known).
    pub(super) fn point(&self, j: &Joints) -> Option<nalgebra::Point3<f64>> {
        match self.polar_axes {
            Some((r, th)) => {
                (j.known.contains(r) && j.known.contains(th)).then(|| motion::polar_point(j, r, th))
            }
            None => Some(nalgebra::Point3::new(
                j.get(Axis::X)?,
                j.get(Axis::Y)?,
                j.get(Axis::Z).unwrap_or(0.0),
            )),
        }
    }

    fn radius(&self, j: &Joints) -> Option<f64> {
        match self.polar_axes {
            Some((r, _)) => j.get(r).map(f64::abs),
            None => Some(j.get(Axis::X)?.hypot(j.get(Axis::Y)?)),
        }
    }

    fn command_text(&self, rpm: f64) -> Text {
        if rpm == 0.0
            && let Some(stop) = &self.stop_command
        {
            return Text::from(stop);
        }
        // The template with the number wherever it says `{rpm}`.
        let mut number = String::new();
        if !write_fixed(&mut number, rpm, self.options.rpm_decimals, true) {
            let _ = write!(number, "{rpm}");
        }
        Text::from(self.command.join(&number).as_str())
    }

    /// Sets the screw to `rpm` (printed), issuing a command when it changes by more than
    /// the threshold.
    pub(super) fn set_rate(&mut self, rpm: f64, span: Span, out: &mut Output<'_>) {
        let rpm = self.printed_rpm(rpm.max(0.0));
        let keep = match self.held {
            Some(0.0) => rpm == 0.0,
            Some(h) => rpm > 0.0 && (rpm - h).abs() <= self.options.threshold * h,
            None => false,
        };
        if keep {
            return;
        }
        self.held = Some(rpm);
        out.push(Block::new(
            span,
            BlockKind::Command(Command {
                text: self.command_text(rpm),
                modes: None,
                clobbers: AxisSet::EMPTY,
            }),
        ));
    }

    fn check_rpm(&mut self, rpm: f64, span: Span, out: &mut Output<'_>) {
        let max = self.max_rpm;
        if rpm > max * (1.0 + 1e-6) {
            self.over_max.hit(out, || {
                Diagnostic::warning(
                    "extrude-rate::max-rpm",
                    format!("the screw would need {rpm:.3} rpm here, above max_rpm {max}"),
                )
                .at_span(span)
                .with_help("set limit = \"slow-feed\" to lower the feed where the screw is too slow, or slow the print in the slicer")
            });
        } else if rpm > 0.0 && rpm < self.min_rpm {
            let min = self.min_rpm;
            self.under_min.hit(out, || {
                Diagnostic::warning(
                    "extrude-rate::min-rpm",
                    format!("the screw would turn at {rpm:.3} rpm here, below min_rpm {min}"),
                )
                .at_span(span)
                .with_help("raise the feed of slow extrusions, or lower min_rpm if the screw extrudes steadily there")
            });
        }
    }

    /// Sets the feed of `block` (a move from `from` to `to`, printed joints) so the
    /// controller takes `seconds` for it under constant velocity, capped by the axes'
    /// `max_feed` and the polar near-centre cap; returns the new segment and whether a
    /// limit cut it.
    fn steer(
        &self,
        block: &mut Block,
        from: &Joints,
        to: &Joints,
        seconds: f64,
    ) -> Option<(Segment, bool)> {
        let BlockKind::Motion(m) = &mut block.kind else {
            return None;
        };
        let (Some(a), Some(b)) = (self.point(from), self.point(to)) else {
            return None;
        };
        let mut seconds = seconds;
        let mut limited = false;
        // The near-centre cap on the XY speed (only where θ turns).
        if let Some((_, th)) = self.polar_axes
            && self.cap_rate > 0.0
            && from.get(th) != to.get(th)
        {
            let d = segment_distance(a.x, a.y, b.x, b.y);
            let xy = (b.x - a.x).hypot(b.y - a.y);
            if d * self.cap_rate > 0.0 && xy / (d * self.cap_rate) > seconds {
                seconds = xy / (d * self.cap_rate);
                limited = true;
            }
        }
        let seg = self.model.between(from, to, m.kind, &m.feed);
        if seg.length <= 0.0 || seconds <= 0.0 {
            return None;
        }
        let (mode, rate) = match (self.model.rule, m.feed.mode) {
            (FeedRule::InverseTime, _) | (_, FeedMode::InverseTime) => {
                (FeedMode::InverseTime, 60.0 / seconds)
            }
            _ => (FeedMode::PerMinute, seg.length / seconds * 60.0),
        };
        let rate = if self.options.mode == Mode::ConstantFlow {
            self.printed_feed(rate)
        } else {
            self.printed_feed_down(rate)
        };
        if rate <= 0.0 {
            return None;
        }
        m.feed.mode = mode;
        m.feed.rate = Some(rate);
        let seg = self.model.between(from, to, m.kind, &m.feed);
        let wanted = match mode {
            FeedMode::InverseTime => seg.length * rate / 60.0,
            _ => rate / 60.0,
        };
        if (seg.v_max - wanted).abs() > 1e-9 * wanted.max(1.0) {
            // The controller's min_speed or an axis' max_feed wins: print the feed it
            // will really run at.
            limited = true;
            let real = match mode {
                FeedMode::InverseTime => seg.v_max / seg.length * 60.0,
                _ => seg.v_max * 60.0,
            };
            m.feed.rate = Some(self.printed_feed(real));
            return Some((self.model.between(from, to, m.kind, &m.feed), limited));
        }
        Some((seg, limited))
    }

    /// A block in the screw modes: queued with its role for the screw.
    pub(super) fn run_screw(&mut self, mut block: Block, out: &mut Output<'_>) {
        self.last_span = block.span;
        let pass = |block| Item {
            block,
            role: Role::Pass,
        };
        match &mut block.kind {
            BlockKind::Motion(_) => self.screw_move(block, out),
            BlockKind::Dwell { seconds } => {
                let s = *seconds;
                self.queue.push_stop(s, pass(block));
            }
            BlockKind::Offset(o) => {
                self.offsets = o.offsets;
                self.p_cache = None;
                let named_e = o.declared.known.contains(Axis::E);
                o.declared.forget(AxisSet::from_iter([Axis::E]));
                o.offsets[Axis::E.index()] = 0.0;
                if named_e && o.declared.known.is_empty() && o.code == OffsetCode::Set {
                    // `G92 E0`: nothing left to declare (a bare G92 would zero every axis).
                    if block.comments.is_empty() {
                        return;
                    }
                    block.kind = BlockKind::Comment;
                }
                self.queue.push_other(pass(block));
            }
            // The screw must not run on in a paused or finished machine: every block
            // before the stop is timed and put out, then the screw stops, then the stop.
            BlockKind::Command(c) if c.stops_machine() => {
                self.queue.finish();
                self.drain(out);
                if self.held.is_some_and(|h| h > 0.0) {
                    self.set_rate(0.0, block.span, out);
                }
                self.pos.forget(c.clobbers);
                self.queue.push_stop(0.0, pass(block));
            }
            BlockKind::Command(c) if !c.clobbers.is_empty() => {
                self.pos.forget(c.clobbers);
                self.queue.push_stop(0.0, pass(block));
            }
            BlockKind::Verbatim(v) => {
                self.pos.forget(v.clobbers);
                self.queue.push_stop(0.0, pass(block));
            }
            _ => self.queue.push_other(pass(block)),
        }
    }

    /// A motion block in the screw modes: E leaves the move, and its material decides
    /// the role (travel, extrusion, or an E-only move that becomes a prime or a comment).
    fn screw_move(&mut self, mut block: Block, out: &mut Output<'_>) {
        let BlockKind::Motion(m) = &mut block.kind else {
            return;
        };
        let Target::Joints(to) = m.target else {
            self.queue.push_other(Item {
                block,
                role: Role::Pass,
            });
            return;
        };
        let from = self.pos;
        let de = match (from.get(Axis::E), to.get(Axis::E)) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        };
        let mut next = self.pos.updated_by(&to);
        if m.machine_frame {
            next.forget(m.written);
        }
        // The last block's printed end is this one's start (most of the time).
        let p_from = match self.p_cache {
            Some((j, p)) if j.same_known(&from) => p,
            _ => self.printed(&from),
        };
        let p_to = self.printed_reusing(
            if m.machine_frame { &to } else { &next },
            self.p_cache.as_ref(),
        );
        remember_printed(&mut self.p_cache, next, p_to);
        self.pos = next;
        // Drop E from the move.
        if let Some(j) = m.target.joints_mut() {
            j.forget(AxisSet::from_iter([Axis::E]));
        }
        m.written.remove(Axis::E);
        if let Some(f) = m.feed.rate {
            m.feed.rate = Some(self.printed_feed(f));
        }
        let seg = self.model.between(&p_from, &p_to, m.kind, &m.feed);
        let moves = seg.length > 0.0 && !m.written.is_empty();
        // Material: what the slicer pushes beyond the retraction still pending.
        let material = material(&mut self.pending, de);
        if !moves && de != 0.0 {
            let rate = m.feed.rate.unwrap_or(0.0);
            let rapid = m.kind == MotionKind::Rapid;
            self.e_only(block, de, material, rate, rapid);
        } else if !moves || material <= 0.0 {
            let role = if moves { Role::Travel } else { Role::Pass };
            self.queue.push_move(seg, Item { block, role });
        } else {
            self.extrusion(block, seg, (&p_from, &p_to), material, out);
        }
    }

    /// An E-only move of `de` (at `rate` mm/min, or a rapid): a prime (a dwell with the
    /// screw turning, in the move's time) when it extrudes `material`, else a comment
    /// (the screw cannot retract).
    fn e_only(&mut self, mut block: Block, de: f64, material: f64, rate: f64, rapid: bool) {
        let comments = std::mem::take(&mut block.comments);
        if material > 0.0 {
            // A rapid runs at the modal F on an FDM firmware, else at the rapid speed.
            let at_feed = !rapid || self.model.rapid == RapidRule::ModalFeed;
            let mut seconds = if rate > 0.0 && at_feed {
                de / (rate / 60.0).max(self.model.min_speed)
            } else {
                de / self.model.rapid_speed
            };
            let rpm = material / self.e_per_rev / (seconds / 60.0);
            if rpm > self.max_rpm {
                seconds = material / self.e_per_rev / self.max_rpm * 60.0;
            }
            // Whole milliseconds (the dwell's printed precision), never shorter.
            let seconds = ((seconds * 1000.0 - 1e-6).ceil() / 1000.0).max(0.001);
            let mut b = Block::new(block.span, BlockKind::Dwell { seconds });
            b.comments = comments;
            b.comments.push(Comment {
                text: format!("prime E{material:.5}: the screw runs during this dwell"),
                style: CommentStyle::Semicolon,
            });
            self.queue.push_stop(
                seconds,
                Item {
                    block: b,
                    role: Role::Prime { material },
                },
            );
        } else {
            let text = if de < 0.0 {
                format!("retraction E{de:.5} left out: the screw cannot turn backwards")
            } else {
                format!("E{de:.5} left out: it restores the retraction")
            };
            let mut b = Block::new(block.span, BlockKind::Comment);
            b.comments = comments;
            b.comments.push(Comment {
                text,
                style: CommentStyle::Semicolon,
            });
            self.queue.push_other(Item {
                block: b,
                role: Role::Pass,
            });
        }
    }

    /// An extruding move (segment `seg` between the printed ends `ends`): its feed is
    /// steered where the mode asks for it (constant flow, or slowed for `max_rpm`).
    fn extrusion(
        &mut self,
        mut block: Block,
        mut seg: Segment,
        ends: (&Joints, &Joints),
        material: f64,
        out: &mut Output<'_>,
    ) {
        let (p_from, p_to) = ends;
        let cv_seconds = if seg.moves() {
            seg.length / seg.v_max
        } else {
            0.0
        };
        let flow_seconds = material / self.e_per_rev / self.flow_rpm * 60.0;
        let target = match self.options.mode {
            Mode::ConstantFlow => Some(flow_seconds),
            _ if self.options.limit == Limit::SlowFeed
                && self.options.rule == Rule::Exact
                && cv_seconds > 0.0
                && material / self.e_per_rev / (cv_seconds / 60.0) > self.max_rpm =>
            {
                Some(material / self.e_per_rev / self.max_rpm * 60.0)
            }
            _ => None,
        };
        let rapid = matches!(&block.kind, BlockKind::Motion(m) if m.kind == MotionKind::Rapid);
        if let Some(t) = target
            && !rapid
            && let Some((s, limited)) = self.steer(&mut block, p_from, p_to, t)
        {
            seg = s;
            self.warn_steered(limited, block.span, out);
        }
        let seed = match self.options.rule {
            Rule::Exact => None,
            Rule::Seed => self.seed_rpm(&block, p_from, p_to, material),
        };
        self.queue.push_move(
            seg,
            Item {
                block,
                role: Role::Extrude { material, seed },
            },
        );
    }

    /// Warns that a steered feed was clamped (constant flow) or lowered (`max_rpm`).
    fn warn_steered(&mut self, limited: bool, span: Span, out: &mut Output<'_>) {
        if self.options.mode == Mode::ConstantFlow {
            if limited {
                self.limited.hit(out, || {
                    Diagnostic::warning(
                        "extrude-rate::flow-limited",
                        "the feed for constant flow is above the machine's limits here: the feed is clamped and the screw slows for this block",
                    )
                    .at_span(span)
                    .with_help("lower `rpm` so the stage can follow it")
                });
            }
        } else {
            self.slowed.hit(out, || {
                Diagnostic::warning(
                    "extrude-rate::slowed",
                    "the feed is lowered here so the screw stays within max_rpm",
                )
                .at_span(span)
            });
        }
    }

    /// The seed's rule for a move from `p_from` to `p_to` extruding `material`:
    /// `gamma · F · mean radius · material / XY length`.
    fn seed_rpm(
        &self,
        block: &Block,
        p_from: &Joints,
        p_to: &Joints,
        material: f64,
    ) -> Option<f64> {
        let f = match &block.kind {
            BlockKind::Motion(m) if m.feed.mode == FeedMode::PerMinute => m.feed.rate,
            _ => None,
        };
        match (
            f,
            self.point(p_from),
            self.point(p_to),
            self.radius(p_from),
            self.radius(p_to),
        ) {
            (Some(f), Some(a), Some(b), Some(ra), Some(rb)) => {
                let l = (b.x - a.x).hypot(b.y - a.y);
                (l > 0.0).then(|| self.gamma * f * (ra + rb) / 2.0 * material / l)
            }
            _ => None,
        }
    }

    /// Emits the planned items, with the screw commands before them.
    pub(super) fn drain(&mut self, out: &mut Output<'_>) {
        while let Some(t) = self.queue.pop() {
            self.emit(t, out);
        }
    }

    /// Puts out a planned block, after the screw command its time asks for.
    fn emit(&mut self, t: Timed<Item>, out: &mut Output<'_>) {
        let seconds = t.duration();
        let Item { block, role } = t.payload;
        let span = block.span;
        match role {
            Role::Pass => {}
            Role::Travel => self.set_rate(0.0, span, out),
            Role::Extrude { material, seed } => {
                let material = material + self.carry;
                if seconds > 0.0 {
                    self.carry = 0.0;
                    let exact = material / self.e_per_rev / (seconds / 60.0);
                    let rpm = seed.unwrap_or(exact);
                    self.check_rpm(rpm, span, out);
                    self.set_rate(rpm, span, out);
                } else {
                    self.carry = material;
                }
            }
            Role::Prime { material } => {
                if seconds > 0.0 {
                    let rpm = material / self.e_per_rev / (seconds / 60.0);
                    self.check_rpm(rpm, span, out);
                    self.set_rate(rpm, span, out);
                }
            }
        }
        out.push(block);
    }
}

/// Distance from the origin to the segment (ax, ay)–(bx, by).
fn segment_distance(ax: f64, ay: f64, bx: f64, by: f64) -> f64 {
    let (dx, dy) = (bx - ax, by - ay);
    let len2 = dx * dx + dy * dy;
    if len2 == 0.0 {
        return ax.hypot(ay);
    }
    let s = (-(ax * dx + ay * dy) / len2).clamp(0.0, 1.0);
    (ax + dx * s).hypot(ay + dy * s)
}
