//! What G and M codes do: their modal groups, the axes a command leaves unknown, and the
//! commands that pass through as text.

use super::words::{Code, Word, parse_code, split_word};
use super::{Lowerer, MotionMode, Small};
use crate::front::gcode::lexer::{Spanned, Tok, lex_line};
use crate::ir::{Axis, AxisSet, Block, BlockKind, Command, Plane, Span, WrittenModes};

/// Which G-code modal group a code belongs to, for the conflict check.
pub(super) fn g_group(code: Code) -> Option<&'static str> {
    Some(match code {
        (80, 0) => "canned cycle cancel",
        (0 | 1 | 2 | 3 | 33 | 73 | 74 | 76 | 81..=89, 0) | (5, _) | (38, _) | (33, 1) => "motion",
        (17..=19, _) => "plane",
        (20 | 21, 0) => "units",
        (90 | 91, 0) => "distance",
        (90 | 91, 1) => "arc distance",
        (93..=95, 0) => "feed mode",
        (54..=59, _) => "coordinate system",
        (40..=42, _) => "cutter compensation",
        (43 | 49, _) => "tool length offset",
        (4 | 10 | 28 | 30 | 53 | 92, _) => "non-modal",
        _ => return None,
    })
}

/// Modal G codes that neither move nor take axis words.
pub(super) fn g_known_modal(code: Code) -> bool {
    matches!(
        code,
        (17..=21 | 40..=42 | 49 | 54..=59 | 61 | 64 | 80 | 90 | 91 | 93..=99, _) | (43, 0)
    )
}

/// G codes that take axis words without moving along them as a G1 would: homing, probing,
/// setting offsets, direct moves. They pass through as commands.
pub(super) fn g_uses_axes(code: Code) -> bool {
    matches!(
        code,
        (6 | 10 | 28 | 29 | 30 | 31 | 52 | 161 | 162, _) | (38, _) | (43, 4 | 5)
    )
}

/// Axes whose position is unknown after a pass-through command, judged from its codes.
pub(super) fn clobbers(g: &[Code], m: &[Code], named: AxisSet) -> AxisSet {
    let mut set = AxisSet::EMPTY;
    for &code in g {
        match code {
            // Homing and parking: the named axes, or all.
            (28 | 30 | 161 | 162 | 6 | 29, 0) => {
                let mut all = AxisSet::ALL;
                all.remove(Axis::E);
                set = set.union(if named.is_empty() { all } else { named })
            }
            // Probing stops somewhere along the named axes.
            (31, 0) | (38, _) => set = set.union(named),
            // Modal settings that do not move.
            (
                0..=4 | 17..=21 | 40..=43 | 49 | 53 | 54..=59 | 61 | 64 | 80 | 90 | 91 | 93..=99,
                _,
            )
            | (10 | 28 | 30, 1) => {}
            // Probing, macros, coordinate rotation and anything unknown may move or
            // re-define coordinates.
            _ => set = AxisSet::ALL,
        }
    }
    for &code in m {
        if matches!(code, (98 | 99, 0)) {
            set = AxisSet::ALL;
        }
    }
    set
}

/// Whether a line has a G code that works in the selected plane (arcs, canned cycles).
pub(super) fn uses_plane(text: &str) -> bool {
    let mut toks = Vec::new();
    lex_line(text, &mut toks);
    toks.iter().any(|t| match t.1 {
        Tok::Word(w) => {
            let (l, n) = split_word(w);
            l == 'G' && matches!(parse_code(n), Some((2 | 3 | 73 | 76 | 81..=89, 0)))
        }
        _ => false,
    })
}

/// Whether a line has M99, the end of a Fanuc subprogram.
pub(super) fn contains_m99(text: &str) -> bool {
    let mut toks = Vec::new();
    lex_line(text, &mut toks);
    toks.iter().any(|t| match t.1 {
        Tok::Word(w) => {
            let (l, n) = split_word(w);
            l == 'M' && parse_code(n) == Some((99, 0))
        }
        _ => false,
    })
}

impl Lowerer {
    /// Applies modal words of a line that is otherwise passed through, so that following
    /// plain lines are read in the modes the controller will be in.
    /// Returns whether the line has such words (whatever the modes were before, so the
    /// answer depends on the line alone).
    pub(super) fn apply_plain_modes(&mut self, toks: &[Spanned<'_>]) -> bool {
        let mut any = false;
        for t in toks {
            if let Tok::Word(w) = t.1 {
                let (letter, number) = split_word(w);
                let Some(code) = parse_code(number) else {
                    continue;
                };
                match (letter, code) {
                    ('G', (90, 0)) => self.relative = false,
                    ('G', (91, 0)) => self.relative = true,
                    ('G', (20, 0)) => self.inch = true,
                    ('G', (21, 0)) => self.inch = false,
                    ('G', (17, 0)) => self.plane = Plane::XY,
                    ('G', (18, 0)) => self.plane = Plane::ZX,
                    ('G', (19, 0)) => self.plane = Plane::YZ,
                    ('M', (82, 0)) => self.relative_e = false,
                    ('M', (83, 0)) => self.relative_e = true,
                    _ => continue,
                }
                any = true;
            }
        }
        self.motion = MotionMode::None;
        any
    }

    /// Axes left unknown by a command passed through as text.
    pub(super) fn command_clobbers(&self, toks: &[Spanned<'_>]) -> AxisSet {
        let mut g: Small<Code> = Small::new();
        let mut m: Small<Code> = Small::new();
        let mut named = AxisSet::EMPTY;
        for t in toks {
            if let Tok::Word(w) | Tok::Letter(w) = t.1 {
                let (letter, number) = split_word(w);
                match letter {
                    'G' => g.extend(parse_code(number)),
                    'M' => m.extend(parse_code(number)),
                    l => {
                        if let Some(a) = Axis::from_letter(l) {
                            named.insert(a);
                        }
                    }
                }
            }
        }
        clobbers(&g, &m, named)
    }

    /// A command the IR does not model, written from its words.
    pub(super) fn command(
        &mut self,
        span: Span,
        words: &[Word<'_>],
        g: &[Code],
        m: &[Code],
        named: AxisSet,
        with_axes: bool,
    ) -> Block {
        let mut text = String::new();
        for w in words {
            if !text.is_empty() {
                text.push(' ');
            }
            text.push(w.letter);
            text.push_str(w.number());
        }
        // A Fanuc call: the subprogram may move anything and set its own F. Expanded
        // inline (a body lowered for `expand-subprograms`), it changes nothing here.
        let call = m.contains(&(98, 0));
        let clob = if call && self.calls_inline {
            AxisSet::EMPTY
        } else {
            clobbers(g, m, named)
        };
        self.pos.forget(clob);
        if call && !self.calls_inline {
            self.feed = None;
            // A subprogram of this file (not a RepRapFirmware macro file `P"file.g"`)
            // returns in the modes its body left.
            if !text.contains('"') {
                self.after_call = super::after_call::ALL;
            }
        }
        let modes = if call {
            // The modes the body starts in (E: M83 alone, not G91).
            Some(self.call_modes())
        } else {
            with_axes.then(|| WrittenModes {
                relative_e: self.relative_e && named.contains(Axis::E),
                ..self.modes()
            })
        };
        Block::new(
            span,
            BlockKind::Command(Command {
                text: text.into(),
                modes,
                clobbers: clob,
            }),
        )
    }
}
