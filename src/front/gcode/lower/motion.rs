//! Moves: the target of a G0/G1/G2/G3 block in the IR frame (units, distance mode, G92
//! offsets, G53), and the block's feed; also G92 offsets and G4 dwells.

use super::words::Slots;
use super::{Lowerer, MM_PER_INCH, MotionMode, Placement};
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, AxisSet, Block, BlockKind, Feed, FeedMode, Joints, Motion, MotionKind,
    OffsetCode, Span, Target, VerbatimReason,
};

/// A move as the block writes it, before it is resolved against the modal state.
pub(super) struct Move<'s, 'w, 'a> {
    /// The motion mode in force for the block.
    pub mode: MotionMode,
    /// The block's words by letter.
    pub slots: &'s Slots<'w, 'a>,
    /// The axes the block names.
    pub named: AxisSet,
    /// G53: the coordinates are machine coordinates.
    pub machine_frame: bool,
    /// The block gives F.
    pub feed_written: bool,
    /// Words of the line that ride along with the move (M, T, S, unknown letters).
    pub extra: &'s [&'a str],
}

impl Lowerer {
    /// Lowers a move to `out`: a motion block, or the line as written when its start is
    /// not known. `None` once an error is reported.
    pub(super) fn motion_block(
        &mut self,
        text: &str,
        span: Span,
        mv: &Move<'_, '_, '_>,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<()> {
        let line_no = span.line;
        let named = mv.named;
        if self.relative_from_unknown(text, span, mv, out, diags) {
            return Some(());
        }
        let target = self.target(mv.slots, named, mv.machine_frame);
        let kind = match mv.mode {
            MotionMode::Rapid => MotionKind::Rapid,
            MotionMode::Linear => MotionKind::Linear,
            MotionMode::Arc { clockwise } => {
                self.check_arc_form(text, line_no, mv.slots, diags)?;
                if !self.arc_start_known(text, line_no, diags) {
                    let b = self.verbatim(
                        text,
                        span,
                        VerbatimReason::Unevaluated,
                        AxisSet::ALL,
                        Placement::TopLevel { keeps_modes: true },
                    );
                    out.push(b);
                    return Some(());
                }
                match self.arc(text, line_no, clockwise, mv.slots, &target, diags) {
                    Some(arc) => MotionKind::Arc(arc),
                    None => {
                        // The block is refused, but its end point is as written: the
                        // blocks after it start there, and report their own errors only.
                        self.pos = target;
                        return None;
                    }
                }
            }
            MotionMode::None | MotionMode::Unsupported => return None,
        };
        if self.feed_mode == FeedMode::InverseTime
            && !matches!(kind, MotionKind::Rapid)
            && !mv.feed_written
        {
            diags.push(
                Diagnostic::error(
                    "gcode::inverse-time-feed",
                    "in inverse time mode (G93) every feed move needs F",
                )
                .at_bytes(line_no, text, 0, text.len())
                .with_label("no F on this move")
                .with_help("add F (1/minutes for this block) or switch to G94"),
            );
            return None;
        }
        let extra = extra_text(mv, &kind);
        let motion = Motion {
            kind,
            target: Target::Joints(target),
            feed: Feed {
                mode: self.feed_mode,
                rate: self.feed,
            },
            written: named,
            machine_frame: mv.machine_frame,
            extra,
        };
        self.pos = target;
        if mv.machine_frame {
            self.pos.forget(named);
        }
        out.push(Block::new(span, BlockKind::Motion(motion)));
        Some(())
    }

    /// A relative move from an unknown position cannot be made absolute: it travels as
    /// written, in the modes it was written in, and its axes stay unknown. `true` when
    /// the move is one.
    fn relative_from_unknown(
        &mut self,
        text: &str,
        span: Span,
        mv: &Move<'_, '_, '_>,
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) -> bool {
        if mv.machine_frame {
            return false;
        }
        let Some(a) = mv
            .named
            .iter()
            .find(|&a| self.is_relative(a) && self.pos.get(a).is_none())
        else {
            return false;
        };
        diags.push(
            Diagnostic::warning(
                "gcode::relative-unknown",
                format!("relative move of {} from a position that is not known here", a.letter()),
            )
            .at_bytes(span.line, text, 0, text.len())
            .with_label("passes through unchanged")
            .with_help(format!(
                "it is copied as written (in G91); move {} to an absolute position first to have it resolved",
                a.letter()
            )),
        );
        let b = self.verbatim(
            text,
            span,
            VerbatimReason::Unevaluated,
            mv.named,
            Placement::TopLevel { keeps_modes: true },
        );
        out.push(b);
        true
    }

    /// Whether `axis` moves relatively: G91, and for E also M83.
    fn is_relative(&self, axis: Axis) -> bool {
        if axis == Axis::E {
            self.relative || self.relative_e
        } else {
            self.relative
        }
    }

    /// Where the named axes go, IR frame: machine coordinates under G53, added to the
    /// start when relative, less the G92 offset when absolute.
    fn target(&self, slots: &Slots<'_, '_>, named: AxisSet, machine_frame: bool) -> Joints {
        let start = self.pos;
        let mut target = self.pos;
        for a in named.iter() {
            let Some(w) = slots.axis(a) else { continue };
            let v = w.value * self.unit(a);
            let value = if machine_frame {
                v
            } else if self.is_relative(a) {
                start.values[a.index()] + v
            } else {
                v - self.offsets[a.index()]
            };
            target.set(a, value);
        }
        target
    }

    /// Applies a G92-family code to the offsets and returns the values G92 declares.
    pub(super) fn apply_offset(
        &mut self,
        code: OffsetCode,
        slots: &Slots<'_, '_>,
        named: AxisSet,
        line_no: u32,
        text: &str,
        diags: &mut Vec<Diagnostic>,
    ) -> Joints {
        let mut declared = Joints::default();
        match code {
            OffsetCode::Set => {
                if named.is_empty() {
                    // RepRapFirmware and Marlin: G92 with no axes does nothing useful.
                    diags.push(
                        Diagnostic::warning(
                            "gcode::g92-empty",
                            "G92 without axis words changes nothing",
                        )
                        .at_bytes(line_no, text, 0, text.len()),
                    );
                }
                for a in named.iter() {
                    let Some(w) = slots.axis(a) else { continue };
                    let v = w.value * self.unit(a);
                    declared.set(a, v);
                    match self.pos.get(a) {
                        Some(p) => self.offsets[a.index()] = v - p,
                        None => {
                            self.offsets[a.index()] = 0.0;
                            self.pos.set(a, v);
                        }
                    }
                }
            }
            OffsetCode::Clear => {
                self.offsets = [0.0; AXIS_COUNT];
                self.suspended = None;
            }
            OffsetCode::Suspend => {
                self.suspended = Some(self.offsets);
                self.offsets = [0.0; AXIS_COUNT];
            }
            OffsetCode::Restore => {
                if let Some(s) = self.suspended.take() {
                    self.offsets = s;
                }
            }
        }
        declared
    }

    /// The length of a G4 dwell, seconds, when the block gives it in a form the IR knows.
    pub(super) fn dwell_seconds(&self, slots: &Slots<'_, '_>) -> Option<f64> {
        let seconds = match (slots.get('P'), slots.get('S'), slots.axis(Axis::X)) {
            (Some(p), None, None) => self.p_seconds(p.value),
            (None, Some(s), None) | (None, None, Some(s)) => s.value,
            _ => return None,
        };
        (seconds >= 0.0).then_some(seconds)
    }

    /// A dwell's P (`G4 P`, and the P of a canned cycle) in seconds: the cycle's P counts
    /// as `G4 P` does on every controller (LinuxCNC: seconds for both, G-code reference
    /// "G4 ... P seconds to dwell" and "G82 ... Dwell for the P number of seconds"; Fanuc:
    /// milliseconds for both, `G04 P1000` and `G82 ... P1000` dwell one second), so one
    /// option, `dwell_p_milliseconds`, says which. The dialect does not set it: the
    /// `gcode` backend prints milliseconds unless `gcode.dwell_milliseconds = false`, and
    /// a LinuxCNC program read in seconds would then come out 1000 times longer.
    pub(super) fn p_seconds(&self, p: f64) -> f64 {
        if self.options.dwell_p_milliseconds {
            p / 1000.0
        } else {
            p
        }
    }

    /// Millimetres per unit of F: inches per minute convert, inverse time does not.
    pub(super) fn feed_scale(&self) -> f64 {
        if self.inch && self.feed_mode != FeedMode::InverseTime {
            MM_PER_INCH
        } else {
            1.0
        }
    }

    /// Millimetres per unit of a linear axis word (rotary axes are in degrees).
    pub(super) fn unit(&self, axis: Axis) -> f64 {
        if self.inch && !axis.is_rotary() {
            MM_PER_INCH
        } else {
            1.0
        }
    }
}

/// The words of a move line that the controller reads beside the move: the line's other
/// words, and I, J, K, R, P on a straight move (tool vectors and the like).
fn extra_text(mv: &Move<'_, '_, '_>, kind: &MotionKind) -> String {
    let mut text = String::new();
    for (i, w) in mv.extra.iter().enumerate() {
        if i > 0 {
            text.push(' ');
        }
        text.push_str(&super::words::normalise_word(w));
    }
    if !matches!(kind, MotionKind::Arc(_)) {
        for l in ['I', 'J', 'K', 'R', 'P'] {
            if let Some(w) = mv.slots.get(l) {
                if !text.is_empty() {
                    text.push(' ');
                }
                text.push_str(&super::words::normalise_word(w.text));
            }
        }
    }
    text
}
