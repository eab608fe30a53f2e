//! The main program's state between calls: what the frontend could not know after a
//! call (positions, the modal feed, G92 offsets a body changed) is completed here.

use super::defs::has_code;
use super::lower::Lowering;
use crate::diag::Diagnostic;
use crate::ir::{
    AXIS_COUNT, Axis, Block, BlockKind, Dialect, Modal, Motion, MotionKind, MotionMode,
    OffsetChange, OffsetCode, Target, Tracker, VerbatimReason,
};
use crate::num::lexer::{Tok, tokens};

/// Follows the main program's state through the blocks the frontend lowered, and
/// completes the blocks after a call from what the call left.
pub(super) struct MainState {
    state: Modal,
    /// The offsets the frontend used (it does not see G92 inside bodies).
    front_offsets: [f64; AXIS_COUNT],
    /// A call has been expanded: the frontend's positions may be less than known.
    after_call: bool,
    /// The last call from the main program was expanded: the lines the frontend copied
    /// because that call left their modes unknown are read in the modes its body left.
    body_modes: bool,
    /// The lines the frontend copied after a call this pass expands (their warning taken
    /// back): each must be read again.
    pub reread: std::collections::HashSet<u32>,
    /// A line of the program proper has been read (the header, where the frontend
    /// learns the dialect under `auto`, is over).
    started: bool,
}

impl MainState {
    /// The state at the program start, `start`.
    pub fn new(start: Modal) -> Self {
        MainState {
            state: start,
            front_offsets: [0.0; AXIS_COUNT],
            after_call: false,
            body_modes: false,
            reread: std::collections::HashSet::new(),
            started: false,
        }
    }

    /// Follows what the frontend learns from the header and the retract-mode codes:
    /// the dialect (`auto`: named in a comment before the program proper) and `G98`/`G99`,
    /// which the bodies are lowered in.
    fn follow_reading(&mut self, block: &Block) {
        if !self.started && self.state.dialect == Dialect::Auto {
            let named = match &block.kind {
                BlockKind::Verbatim(v) => Dialect::named_in(&v.text),
                _ => None,
            };
            let named = named.or_else(|| {
                block
                    .comments
                    .iter()
                    .find_map(|c| Dialect::named_in(&format!("({})", c.text)))
            });
            if let Some(d) = named {
                self.state.read_in(d);
            }
        }
        let text = match &block.kind {
            BlockKind::Command(c) => c.text.as_str(),
            BlockKind::Verbatim(v) => v.text.as_str(),
            BlockKind::Motion(m) => m.extra.as_str(),
            BlockKind::Comment => return,
            _ => "",
        };
        let delimiter =
            matches!(&block.kind, BlockKind::Verbatim(v) if v.reason == VerbatimReason::Delimiter);
        self.started |= !delimiter;
        for (_, t, _) in tokens(text) {
            if let Tok::Word(w) = t
                && w.starts_with(['G', 'g'])
            {
                match crate::num::parse_decimal(w[1..].trim_start()) {
                    Some(98.0) => self.state.retract_to_initial = true,
                    Some(99.0) => self.state.retract_to_initial = false,
                    _ => {}
                }
            }
        }
    }

    /// A line the frontend passed through because a position was unknown after a call
    /// (a relative move, an arc), or because a call left its modes unknown (it has no
    /// modes of its own then: it is read in the modes the body left), lowered again now
    /// that they are known (no block for a line that only sets modes); `None` when it
    /// still cannot be lowered to moves alone.
    fn relower(&self, block: &Block, lowering: &dyn Lowering) -> Option<(Option<Block>, Modal)> {
        let BlockKind::Verbatim(v) = &block.kind else {
            return None;
        };
        if v.reason != crate::ir::VerbatimReason::Unevaluated {
            return None;
        }
        let mut state = self.state;
        match v.modes {
            Some(m) => {
                state.inch = m.inch;
                state.relative = m.relative;
                if crate::num::lexer::has_word(&v.text, 'E') {
                    state.relative_e = m.relative_e;
                }
                if let Some(p) = m.plane {
                    state.plane = p;
                }
            }
            None if self.body_modes => {}
            None => return None,
        }
        let mut low = lowering.body(state);
        let (mut out, mut diags) = (Vec::new(), Vec::new());
        low.line(&v.text, block.span, &mut out, &mut diags);
        if !diags.is_empty() || out.len() > 1 {
            return None;
        }
        let Some(lowered) = out.pop() else {
            return Some((None, low.state()));
        };
        let plain = match &lowered.kind {
            BlockKind::Motion(_) | BlockKind::Comment | BlockKind::Dwell { .. } => true,
            BlockKind::Command(c) => c.clobbers.is_empty(),
            // A canned cycle the body left in force, drilled where the line says.
            BlockKind::Verbatim(v) => v.ends_at().is_some() && v.modes.is_some(),
            BlockKind::Offset(_) => false,
        };
        plain.then(|| (Some(lowered), low.state()))
    }

    /// Follows the blocks of a definition, which are left out of the output, as the
    /// frontend did: the positions its lines clobber are unknown after them (the
    /// completion after a call restores only what the call made unknown).
    pub fn pass_over(&mut self, blocks: &[Block]) {
        for b in blocks {
            if let BlockKind::Verbatim(v) = &b.kind {
                self.state.pos.forget(v.clobbers);
            }
        }
    }

    /// The state a call's body starts in: what the blocks left, with the modes the frontend
    /// recorded on the call.
    pub fn call_state(&self, call: &Block) -> Modal {
        let mut s = self.state;
        let modes = match &call.kind {
            BlockKind::Command(c) => c.modes,
            BlockKind::Verbatim(v) => v.modes,
            _ => None,
        };
        if let Some(m) = modes {
            s.inch = m.inch;
            s.relative = m.relative;
            s.relative_e = m.relative_e;
            if let Some(p) = m.plane {
                s.plane = p;
            }
        }
        s
    }

    /// The state a call from the main program left.
    pub fn after_call(&mut self, end: Modal) {
        self.state = end;
        self.after_call = true;
        self.body_modes = true;
    }

    /// A call from the main program passes through: the controller runs it, so the lines
    /// after it stay as written.
    pub fn opaque_call(&mut self) {
        self.body_modes = false;
        // Lines the frontend copied because the motion mode is unknown stay as written.
        self.state.motion = MotionMode::None;
    }

    /// Updates the state with `block` and returns it completed (`None` for a line that
    /// only set modes, read again).
    pub fn block(
        &mut self,
        mut block: Block,
        lowering: &dyn Lowering,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<Block> {
        self.follow_reading(&block);
        if self.after_call {
            if let Some((lowered, state)) = self.relower(&block, lowering) {
                self.state = state;
                return lowered;
            }
            if self.body_modes
                && let BlockKind::Verbatim(v) = &block.kind
                && self.reread.contains(&block.span.line)
            {
                diags.push(
                    Diagnostic::error(
                        "subprograms::modes",
                        "this line is read in the distance or motion mode the subprogram called before it left, and cannot be read again here",
                    )
                    .at_bytes(block.span.line, &v.text, 0, v.text.trim_end().len())
                    .with_label("depends on the modes the subprogram left")
                    .with_help("write the distance and motion modes it moves in on the line (`G90 G1 X1`), or the words the mode the subprogram left needs (an arc's centre)"),
                );
            }
        }
        let corr: [f64; AXIS_COUNT] =
            std::array::from_fn(|i| self.front_offsets[i] - self.state.offsets[i]);
        match &mut block.kind {
            BlockKind::Motion(m) => self.motion(m, &corr),
            BlockKind::Offset(o) => self.offset(o),
            BlockKind::Command(c) => {
                self.state.pos.forget(c.clobbers);
                if has_code(&c.text, 'M', 99.0) {
                    diags.push(
                        Diagnostic::warning(
                            "subprograms::main-m99",
                            "M99 in the main program: the controller restarts the program here (an endless loop)",
                        )
                        .at_span(block.span)
                        .with_help("it passes through unchanged and is not expanded; end the program with M30 or M2 instead if it should stop"),
                    );
                }
            }
            BlockKind::Verbatim(v) => {
                v.follow(&mut self.state.pos);
                if v.modes.is_some()
                    && v.reason == crate::ir::VerbatimReason::Unevaluated
                    && !only_assignments(&v.text)
                {
                    // As the frontend: a line it could not evaluate leaves the motion mode
                    // unknown, unless it names one; parameter assignments keep it.
                    self.state.motion = motion_of(&v.text).unwrap_or(MotionMode::None);
                }
            }
            BlockKind::Dwell { .. } | BlockKind::Comment => {}
        }
        Some(block)
    }

    /// Completes a move from the state (known axes, G92 correction, modal feed) and
    /// follows it.
    fn motion(&mut self, m: &mut Motion, corr: &[f64; AXIS_COUNT]) {
        if let Target::Joints(t) = &mut m.target {
            for a in Axis::ALL {
                let i = a.index();
                if m.machine_frame && m.written.contains(a) {
                    continue;
                }
                match t.get(a) {
                    Some(v) => t.values[i] = v + corr[i],
                    None => {
                        if let Some(v) = self.state.pos.get(a) {
                            t.set(a, v);
                        }
                    }
                }
            }
            // The IR's rule for where the move leaves the machine.
            let mut track = Tracker::at(self.state.pos);
            track.motion(m);
            self.state.pos = *track.pos();
        }
        if let MotionKind::Arc(arc) = &mut m.kind {
            for (k, c) in arc.center.iter_mut().enumerate() {
                *c += corr[k];
            }
        }
        if m.feed.rate.is_none() && m.feed.mode == self.state.feed_mode {
            m.feed.rate = self.state.feed;
        }
        self.state.feed = m.feed.rate;
        self.state.feed_mode = m.feed.mode;
        self.state.motion = match m.kind {
            MotionKind::Rapid => MotionMode::Rapid,
            MotionKind::Linear => MotionMode::Linear,
            MotionKind::Arc(a) => MotionMode::Arc {
                clockwise: a.clockwise,
            },
        };
    }

    /// Follows a G92-family change as the frontend lowers it, and gives it the offsets
    /// really in force.
    fn offset(&mut self, o: &mut OffsetChange) {
        self.front_offsets = o.offsets;
        let s = &mut self.state;
        match o.code {
            OffsetCode::Set => {
                for a in o.declared.known.iter() {
                    let v = o.declared.values[a.index()];
                    match s.pos.get(a) {
                        Some(p) => s.offsets[a.index()] = v - p,
                        None => {
                            s.offsets[a.index()] = 0.0;
                            s.pos.set(a, v);
                        }
                    }
                }
            }
            OffsetCode::Clear => {
                s.offsets = [0.0; AXIS_COUNT];
                s.suspended = None;
            }
            OffsetCode::Suspend => {
                s.suspended = Some(s.offsets);
                s.offsets = [0.0; AXIS_COUNT];
            }
            OffsetCode::Restore => {
                if let Some(o) = s.suspended.take() {
                    s.offsets = o;
                }
            }
        }
        o.offsets = s.offsets;
    }
}

/// Whether a line only sets parameters (`#1 = [#1 + 1]`).
pub(super) fn only_assignments(text: &str) -> bool {
    let toks: Vec<_> = tokens(text).collect();
    crate::num::lexer::parameter_assignments(&toks, |_| {})
}

/// The motion mode a line's G words select, if any.
fn motion_of(text: &str) -> Option<MotionMode> {
    let mut mode = None;
    for (_, t, _) in tokens(text) {
        if let Tok::Word(w) = t
            && w.starts_with(['G', 'g'])
            && let Some(n) = crate::num::parse_decimal(w[1..].trim_start())
        {
            mode = match n {
                0.0 => Some(MotionMode::Rapid),
                1.0 => Some(MotionMode::Linear),
                2.0 => Some(MotionMode::Arc { clockwise: true }),
                3.0 => Some(MotionMode::Arc { clockwise: false }),
                80.0 => Some(MotionMode::None),
                n if (73.0..=89.0).contains(&n) || n == 33.0 || (38.0..39.0).contains(&n) => {
                    Some(MotionMode::Unsupported)
                }
                _ => mode,
            };
        }
    }
    mode
}
