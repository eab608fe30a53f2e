//! Printing a move: the axis words the controller needs, the arc's centre offsets, the
//! feed, and what the controller knows afterwards.

use super::{Emitter, Extrusion, Flavor, too_large};
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Arc, Axis, AxisSet, Block, FeedMode, Joints, Motion, MotionKind, Plane, Target,
};
use crate::num::print::{from_units, to_units};

/// The axis words of a move: `units[i]` for the axes in `named`.
struct Words {
    units: [i64; AXIS_COUNT],
    named: AxisSet,
    /// Relative extrusion: where the printed numbers put E (print units, IR frame).
    e_target: Option<i64>,
    /// Relative extrusion from an unknown E: this move says where E goes, in M82.
    e_absolute_once: bool,
}

impl<W: std::io::Write> Emitter<W> {
    pub(super) fn motion(&mut self, block: &Block, motion: &Motion) -> Result<(), Diagnostic> {
        let target = match &motion.target {
            Target::Joints(j) => j,
            Target::Pose(_) => {
                return Err(Diagnostic::error(
                    "back::pose",
                    "a tool pose reached the backend, which prints joint values",
                )
                .at_span(block.span)
                .with_help("add the `ik` pass to the pipeline for CL input"));
            }
        };
        // The axis words first: the mode line depends on whether E is printed.
        let mut words = self.axis_words(motion, target, block)?;
        let relative = self.fmt.extrusion == Extrusion::Relative;
        if let Flavor::Grbl(_) = self.flavor {
            grbl_motion_check(&mut words, motion, target, self.track.pos(), block)?;
        }
        let e_mode = words
            .named
            .contains(Axis::E)
            .then_some(relative && !words.e_absolute_once && !motion.machine_frame);
        self.ensure_modes(motion, e_mode, block)?;

        let code = match motion.kind {
            MotionKind::Rapid => "G0",
            MotionKind::Linear => "G1",
            MotionKind::Arc(a) if a.clockwise => "G2",
            MotionKind::Arc(_) => "G3",
        };
        if motion.machine_frame {
            self.text("G53");
        }
        if !self.fmt.modal_motion || self.modes.motion != Some(code) || motion.machine_frame {
            self.text(code);
        }
        self.modes.motion = Some(code);
        for a in words.named.iter() {
            let i = a.index();
            self.word_units(a.letter(), words.units[i], self.axis_decimals[i]);
        }
        if let MotionKind::Arc(arc) = motion.kind {
            self.arc_words(&arc, block)?;
        }
        self.feed_word(motion, block)?;
        if !motion.extra.is_empty() {
            self.text(&motion.extra);
        }
        self.end_line(&block.comments, true)?;
        self.after_motion(motion, &words);
        Ok(())
    }

    /// The axis words of a move to `target`: the axes whose printed value changes (all
    /// the written ones for G53), E relative or absolute as the output extrudes, an arc's
    /// end point in its plane, and a move that changes nothing keeps the axes it named.
    fn axis_words(
        &self,
        motion: &Motion,
        target: &Joints,
        block: &Block,
    ) -> Result<Words, Diagnostic> {
        let mut w = Words {
            units: [0; AXIS_COUNT],
            named: AxisSet::EMPTY,
            e_target: None,
            e_absolute_once: false,
        };
        let machine_frame = motion.machine_frame;
        let relative = self.fmt.extrusion == Extrusion::Relative;
        // A machine-frame (G53) move names only its own axes.
        let axes = if machine_frame {
            target.known.intersection(motion.written)
        } else {
            target.known
        };
        // E is the last axis: dealt with after the others, a number that does not fit is
        // reported in axis order.
        let e_apart = relative && !machine_frame && axes.contains(Axis::E);
        let plain = if e_apart {
            axes.difference(AxisSet::from_iter([Axis::E]))
        } else {
            axes
        };
        for a in plain.iter() {
            let i = a.index();
            let v = target.values[i];
            let prog = if machine_frame {
                v
            } else {
                v + self.track.offsets()[i]
            };
            let u = to_units(prog, self.axis_decimals[i])
                .ok_or_else(|| too_large(a.letter(), prog, block))?;
            if self.printed[i] != Some(u) || machine_frame {
                w.units[i] = u;
                w.named.insert(a);
            }
        }
        if e_apart {
            self.relative_e_word(target, block, &mut w)?;
        }
        let any = !w.named.is_empty();
        let is_arc = matches!(motion.kind, MotionKind::Arc(_));
        if let MotionKind::Arc(arc) = motion.kind {
            // An arc names its end point in the plane, even when it ends where it starts.
            let (u, v, _) = arc.plane.axes();
            for a in [u, v] {
                if !w.named.contains(a)
                    && let Some(val) = target.get(a)
                {
                    let prog = val + self.track.offsets()[a.index()];
                    w.units[a.index()] = to_units(prog, self.axis_decimals[a.index()])
                        .ok_or_else(|| too_large(a.letter(), prog, block))?;
                    w.named.insert(a);
                }
            }
        }
        if !any && !is_arc {
            // A move that changes nothing keeps the axes it named.
            for a in motion.written.iter() {
                if a == Axis::E && relative {
                    w.units[a.index()] = 0;
                    w.named.insert(a);
                    continue;
                }
                if let Some(v) = target.get(a) {
                    let prog = v + self.track.offsets()[a.index()];
                    if let Some(u) = to_units(prog, self.axis_decimals[a.index()]) {
                        w.units[a.index()] = u;
                        w.named.insert(a);
                    }
                }
            }
        }
        Ok(w)
    }

    /// The E word of relative extrusion: the distance from where the printed numbers put
    /// E, or, when the controller's E is not known, where E goes (in M82).
    fn relative_e_word(
        &self,
        target: &Joints,
        block: &Block,
        w: &mut Words,
    ) -> Result<(), Diagnostic> {
        let i = Axis::E.index();
        let v = target.values[i];
        let d = self.axis_decimals[i];
        let u = to_units(v, d).ok_or_else(|| too_large('E', v, block))?;
        w.e_target = Some(u);
        let base = match (self.e_units, self.track.pos().get(Axis::E)) {
            (Some(b), _) => Some(b),
            (None, Some(p)) => to_units(p, d),
            (None, None) => None,
        };
        match base {
            Some(base) if u != base => {
                w.units[i] = u - base;
                w.named.insert(Axis::E);
            }
            Some(_) => {}
            None => {
                let prog = v + self.track.offsets()[i];
                w.units[i] = to_units(prog, d).ok_or_else(|| too_large('E', prog, block))?;
                w.e_absolute_once = true;
                w.named.insert(Axis::E);
            }
        }
        Ok(())
    }

    /// The centre offsets of an arc (and `P` for extra turns).
    fn arc_words(&mut self, arc: &Arc, block: &Block) -> Result<(), Diagnostic> {
        let (u, v, _) = arc.plane.axes();
        let letters = match arc.plane {
            Plane::XY => ('I', 'J'),
            Plane::ZX => ('K', 'I'),
            Plane::YZ => ('J', 'K'),
        };
        // The controller starts the arc where the last printed numbers put it, so the
        // centre offsets are taken from those, not from the unrounded position.
        let d = self.fmt.decimals.linear;
        let scale = 10f64.powi(d as i32);
        let printed_start = |a: Axis, me: &Self| {
            me.printed[a.index()]
                .map(|units| units as f64 / scale - me.track.offsets()[a.index()])
                .or(me.track.pos().get(a))
        };
        let (Some(su), Some(sv)) = (printed_start(u, self), printed_start(v, self)) else {
            return Err(Diagnostic::error(
                "back::arc-start",
                "an arc starts from a position that is not known",
            )
            .at_span(block.span)
            .with_help("move to an absolute position before the arc"));
        };
        // I/J/K, printed in the order I, J, K.
        let mut offs = [
            (letters.0, arc.center[u.index()] - su),
            (letters.1, arc.center[v.index()] - sv),
        ];
        offs.sort_by_key(|o| o.0);
        for (l, val) in offs {
            self.word(l, val, d, block)?;
        }
        if arc.extra_turns > 0 {
            self.text(&format!("P{}", arc.extra_turns + 1));
        }
        Ok(())
    }

    /// F is modal and matters to feed moves, and to rapids on a controller that runs
    /// them at the modal F: printed there, when it changes (and on every inverse-time
    /// move).
    fn feed_word(&mut self, motion: &Motion, block: &Block) -> Result<(), Diagnostic> {
        let rapid = matches!(motion.kind, MotionKind::Rapid);
        if let Some(rate) = motion.feed.rate.filter(|_| {
            !rapid || (self.fmt.feed_on_rapids && motion.feed.mode == FeedMode::PerMinute)
        }) {
            // A slow F gets the decimals that keep it within the feed resolution.
            let places = self.fmt.decimals.feed_decimals(rate);
            let fu = to_units(rate, places).ok_or_else(|| too_large('F', rate, block))?;
            let must = motion.feed.mode == FeedMode::InverseTime
                && !matches!(motion.kind, MotionKind::Rapid);
            let value = from_units(fu, places);
            if self.modes.feed != Some(value) || must {
                self.word_units('F', fu, places);
                self.modes.feed = Some(value);
            }
        }
        Ok(())
    }

    /// What the controller knows after the printed move.
    fn after_motion(&mut self, motion: &Motion, words: &Words) {
        let mut kept = words.named;
        if self.fmt.extrusion == Extrusion::Relative {
            // The printed numbers put E exactly here.
            if words.e_target.is_some() {
                self.e_units = words.e_target;
            }
            kept = kept.difference(AxisSet::from_iter([Axis::E]));
        }
        for a in kept.iter() {
            self.printed[a.index()] = Some(words.units[a.index()]);
        }
        self.track.motion(motion);
        if motion.machine_frame {
            for a in motion.written.iter() {
                self.printed[a.index()] = None;
            }
        }
    }
}

/// Grbl drives X, Y and Z only, and rejects `P` on an arc.
///
/// Only the axes beyond XYZ that this move writes or changes are an error. An axis that is
/// named only because the controller's position on it is not established (an earlier
/// move to it was rejected here) is left out of the words: Grbl has no such axis, the
/// earlier move's error already says so, and naming it again would blame a move such as
/// `G0 X1 Y1` for axes it does not move.
fn grbl_motion_check(
    words: &mut Words,
    motion: &Motion,
    target: &Joints,
    from: &Joints,
    block: &Block,
) -> Result<(), Diagnostic> {
    let beyond = words.named.difference(AxisSet::XYZ);
    let moved: AxisSet = beyond
        .iter()
        .filter(|&a| {
            motion.written.contains(a)
                || matches!((from.get(a), target.get(a)), (Some(f), Some(t)) if f != t)
        })
        .collect();
    words.named = words.named.difference(beyond.difference(moved));
    let others: String = moved.iter().map(|a| a.letter()).collect();
    if !others.is_empty() {
        return Err(Diagnostic::error(
            "grbl::axis",
            format!("Grbl drives X, Y and Z only; this move also moves {others}"),
        )
        .at_span(block.span)
        .with_help("emit for a controller with these axes (--emit rrf or gcode), or remove them"));
    }
    if let MotionKind::Arc(arc) = motion.kind
        && arc.extra_turns > 0
    {
        return Err(Diagnostic::error(
            "grbl::arc-turns",
            format!(
                "this arc makes {} full turns more than Grbl's G2/G3 can (Grbl rejects P on an arc)",
                arc.extra_turns
            ),
        )
        .at_span(block.span)
        .with_help("add --pass linearize-arcs, which cuts the turns into straight moves"));
    }
    Ok(())
}
