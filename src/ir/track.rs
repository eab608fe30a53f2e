//! [`Tracker`]: the position and the G92 frame, followed through a block stream.
//!
//! Every pass that needs to know where the machine is before a block, and the backend,
//! follow the stream with one `Tracker` so that they agree on what a block does to the
//! position. The rules are those of a controller (LinuxCNC, RepRapFirmware, Grbl):
//!
//! - a move in the program frame ends at its target, which names every axis the
//!   position knows after it (invariant 2); an axis the target leaves out is unknown;
//! - a G53 move (machine frame) moves only the axes it writes, to machine coordinates:
//!   in the program frame those axes are unknown afterwards (the work offset is the
//!   controller's), and every other axis stays where it was. The target's values of the
//!   other axes are not used: a pass before may have moved the program (mirror,
//!   transform, heightmap) and left a G53 block as written;
//! - a move to a tool pose (before inverse kinematics) leaves the axes it writes unknown
//!   as joint values;
//! - a command or a line passed through as text makes the axes it clobbers unknown
//!   (homing, probing, macro calls, unevaluated lines); a canned cycle the frontend
//!   resolved then leaves them where its last hole retracted ([`Verbatim::ends_at`]);
//! - a G92-family change puts its offsets in force; G92 on an axis whose position is
//!   not known makes it known at the declared value (the controller takes the declared
//!   value as the position there, as the frontend does).
//!
//! ```
//! use ncpost::front::gcode::{parse_str, Options};
//! use ncpost::ir::{Axis, Tracker};
//! let p = parse_str("G0 X1 Y2\nG53 G0 Z0\nG92 Z5\n", &Options::default()).unwrap();
//! let mut t = Tracker::default();
//! let steps: Vec<_> = p.blocks.iter().map(|b| t.update(b)).collect();
//! assert_eq!(t.pos().get(Axis::X), Some(1.0));
//! assert_eq!(t.pos().get(Axis::Z), Some(5.0));
//! assert!(steps[2].declared.contains(Axis::Z));
//! ```

use super::{
    AXIS_COUNT, AxisSet, Block, BlockKind, Joints, Motion, OffsetChange, OffsetCode, Target,
    Verbatim,
};

/// The position (IR frame) and the G92 offsets in force after the blocks seen so far.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Tracker {
    pos: Joints,
    offsets: [f64; AXIS_COUNT],
}

/// What one block did to the tracked position.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Step {
    /// Axes known before the block and unknown after it.
    pub forgotten: AxisSet,
    /// Axes a G92 made known (they were unknown before it).
    pub declared: AxisSet,
}

impl Tracker {
    /// A tracker at `pos`, with no offsets.
    pub fn at(pos: Joints) -> Tracker {
        Tracker {
            pos,
            offsets: [0.0; AXIS_COUNT],
        }
    }

    /// The position after the blocks seen so far (IR frame: without G92 offsets).
    pub fn pos(&self) -> &Joints {
        &self.pos
    }

    /// The G92 offsets in force (program = IR + offset), per axis.
    pub fn offsets(&self) -> &[f64; AXIS_COUNT] {
        &self.offsets
    }

    /// Puts the position at `pos`: for a pass that replaced a block by others (an arc by
    /// its chords) and knows where they end.
    pub fn set_pos(&mut self, pos: Joints) {
        self.pos = pos;
    }

    /// Makes `axes` unknown.
    pub fn forget(&mut self, axes: AxisSet) {
        self.pos.forget(axes);
    }

    /// Follows `block` (see the module documentation for the rules).
    pub fn update(&mut self, block: &Block) -> Step {
        let before = self.pos.known;
        let mut declared = AxisSet::EMPTY;
        match &block.kind {
            BlockKind::Motion(m) => self.motion(m),
            BlockKind::Command(c) => self.pos.forget(c.clobbers),
            BlockKind::Verbatim(v) => self.verbatim(v),
            BlockKind::Offset(o) => declared = self.offset(o),
            BlockKind::Dwell { .. } | BlockKind::Comment => {}
        }
        Step {
            forgotten: before.difference(self.pos.known),
            declared,
        }
    }

    /// Follows a line passed through as text: [`Tracker::update`] for a caller that holds
    /// the line only.
    pub fn verbatim(&mut self, v: &Verbatim) {
        v.follow(&mut self.pos);
    }

    /// Follows a move: [`Tracker::update`] for a caller that holds the motion only.
    pub fn motion(&mut self, m: &Motion) {
        match &m.target {
            Target::Joints(j) if !m.machine_frame => self.pos = *j,
            _ => self.pos.forget(m.written),
        }
    }

    /// Follows a G92-family change: [`Tracker::update`] for a caller that holds the
    /// change only. Returns the axes a G92 made known.
    pub fn offset(&mut self, o: &OffsetChange) -> AxisSet {
        self.offsets = o.offsets;
        if o.code != OffsetCode::Set {
            return AxisSet::EMPTY;
        }
        let declared = o.declared.known.difference(self.pos.known);
        for a in declared.iter() {
            let i = a.index();
            self.pos.set(a, o.declared.values[i] - o.offsets[i]);
        }
        declared
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ir::{Axis, Feed, FeedMode, Motion, MotionKind, Span};

    fn joints(values: &[(Axis, f64)]) -> Joints {
        let mut j = Joints::default();
        for &(a, v) in values {
            j.set(a, v);
        }
        j
    }

    fn motion(target: Joints, written: &[Axis], machine_frame: bool) -> Block {
        Block::new(
            Span::default(),
            BlockKind::Motion(Motion {
                kind: MotionKind::Rapid,
                target: Target::Joints(target),
                feed: Feed {
                    mode: FeedMode::PerMinute,
                    rate: None,
                },
                written: written.iter().copied().collect(),
                machine_frame,
                extra: String::new(),
            }),
        )
    }

    /// G53 moves only the axes it writes: they become unknown, the others keep their
    /// tracked values even when the block's target says otherwise.
    #[test]
    fn g53_forgets_its_axes_and_keeps_the_others() {
        let mut t = Tracker::at(joints(&[(Axis::X, 1.0), (Axis::Y, 2.0), (Axis::Z, 3.0)]));
        let stale = joints(&[(Axis::X, 9.0), (Axis::Z, 0.0)]);
        let step = t.update(&motion(stale, &[Axis::Z], true));
        assert_eq!(step.forgotten, [Axis::Z].into_iter().collect());
        assert_eq!(*t.pos(), joints(&[(Axis::X, 1.0), (Axis::Y, 2.0)]));
    }

    /// A program-frame move ends at its target.
    #[test]
    fn moves_end_at_their_target() {
        let mut t = Tracker::at(joints(&[(Axis::X, 1.0), (Axis::E, 0.0)]));
        let to = joints(&[(Axis::X, 4.0), (Axis::Y, 2.0)]);
        let step = t.update(&motion(to, &[Axis::X, Axis::Y], false));
        assert_eq!(*t.pos(), to);
        assert_eq!(step.forgotten, [Axis::E].into_iter().collect());
    }
}
