//! The printed program read line by line the way the controller reads it: its own modal
//! state (G0–G3, G90/G91, G20/G21, G93/G94, G17–G19, modal F, M82/M83), dwells in the
//! flavour's unit, the polar printer's valve and screw commands, and every move timed by
//! the controller's rules ([`Model`] at constant velocity: the flavour's `G0` rule, the
//! minimum speed, the per-axis caps).

use crate::ir::{Arc, Axis, AxisSet, Feed, FeedMode, Joints, MotionKind, Plane};
use crate::machine::polar::Polar;
use crate::machine::{DwellUnit, Flavour};
use crate::motion::{Model, Segment};
use crate::num::lexer::{Tok, tokens};
use crate::num::parse_decimal;

/// What one printed line does, as far as the verification needs it.
// Returned for each printed line and taken at once, never stored: boxing the move would
// cost an allocation per block.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// A move, with the seconds the controller takes for it.
    Move(Move),
    /// A dwell, seconds.
    Dwell(f64),
    /// The valve command: `true` opens, `false` closes.
    Valve(bool),
    /// The screw's speed command, rev/min.
    Screw(f64),
    /// The axes whose position the controller no longer knows from the program (homing).
    Lost(AxisSet),
}

/// One printed move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Move {
    /// Joints before it.
    pub from: Joints,
    /// Joints after it.
    pub to: Joints,
    /// `G0`.
    pub rapid: bool,
    /// The arc of a `G2`/`G3` (absolute centre).
    pub arc: Option<Arc>,
    /// A `G53` move: its words are machine coordinates.
    pub machine: bool,
    /// Seconds the controller takes (at constant velocity; a trapezoid-timed readback
    /// plans `segment` with its neighbours instead).
    pub seconds: f64,
    /// The controller's segment of the move: its length under the feed rule, top speed
    /// and acceleration.
    pub segment: Segment,
}

/// A machine command of the polar printer, as words (upper case, blanks dropped).
fn command_key(text: &str) -> String {
    text.chars()
        .filter(|c| !c.is_whitespace())
        .map(|c| c.to_ascii_uppercase())
        .collect()
}

/// What follows `key` in `code` when `code`, read as a [`command_key`], starts with it
/// (`M42 p0 s1` starts with `M42P0S1`): the rest of the line, as written. The line is
/// compared as it stands, so that the moves that make up most of a print (`G1 ...`)
/// differ at their first letter and cost nothing more.
fn after_key<'a>(code: &'a str, key: &str) -> Option<&'a str> {
    let mut want = key.chars();
    let mut next = want.next();
    for (i, c) in code.char_indices() {
        if c.is_whitespace() {
            continue;
        }
        match next {
            None => return Some(&code[i..]),
            Some(k) if k == c.to_ascii_uppercase() => next = want.next(),
            Some(_) => return None,
        }
    }
    next.is_none().then_some("")
}

/// Reads printed lines and keeps the controller's state.
#[derive(Debug, Clone)]
pub struct Reader {
    model: Model,
    /// What `G4 P` counts on the controller (seconds without a flavour).
    dwell_unit: DwellUnit,
    pos: Joints,
    absolute: bool,
    relative_e: bool,
    inch: bool,
    inverse_time: bool,
    feed: Option<f64>,
    /// 0, 1, 2, 3: the modal motion.
    motion: u8,
    plane: Plane,
    valve_open: String,
    valve_close: String,
    /// The screw command up to its `{rpm}` (upper case, no blanks).
    screw: String,
}

impl Reader {
    /// A reader for a controller timed by `model` on `flavour`, knowing the commands of
    /// `polar` when there is one. Each move's `seconds` is its constant-velocity time;
    /// its `segment` carries the accelerations when `model` is trapezoid-timed.
    pub fn new(model: Model, flavour: Option<Flavour>, polar: Option<&Polar>) -> Reader {
        let (valve_open, valve_close, screw) = match polar {
            Some(p) => (
                command_key(&p.valve.open_command),
                command_key(&p.valve.close_command),
                command_key(p.screw.rpm_command.split("{rpm}").next().unwrap_or("")),
            ),
            None => (String::new(), String::new(), String::new()),
        };
        Reader {
            model,
            dwell_unit: flavour.map_or(DwellUnit::Seconds, Flavour::dwell),
            pos: Joints::default(),
            absolute: true,
            relative_e: false,
            inch: false,
            inverse_time: false,
            feed: None,
            motion: 0,
            plane: Plane::XY,
            valve_open,
            valve_close,
            screw,
        }
    }

    /// The position after the lines read so far.
    pub fn pos(&self) -> &Joints {
        &self.pos
    }

    /// Reads one line (without its terminator).
    pub fn line(&mut self, line: &str) -> Option<Event> {
        let code = line.split(';').next().unwrap_or("");
        if !self.valve_open.is_empty()
            && let Some(e) = self.polar_command(code)
        {
            return Some(e);
        }
        let mut words = Words::default();
        for (_, tok, _) in tokens(code) {
            if let Tok::Word(w) = tok {
                self.word(w, &mut words);
            }
        }
        self.apply(words)
    }

    fn polar_command(&self, code: &str) -> Option<Event> {
        let whole = |key: &str| after_key(code, key).is_some_and(|rest| rest.trim().is_empty());
        if whole(&self.valve_open) {
            return Some(Event::Valve(true));
        }
        if whole(&self.valve_close) {
            return Some(Event::Valve(false));
        }
        if self.screw.is_empty() {
            return None;
        }
        let rpm = after_key(code, &self.screw)?;
        parse_decimal(&command_key(rpm)).map(Event::Screw)
    }

    /// Notes one word of a line.
    fn word(&mut self, w: &str, words: &mut Words) {
        let letter = w.as_bytes()[0].to_ascii_uppercase();
        let Some(value) = parse_decimal(w[1..].trim_start()) else {
            return;
        };
        match letter {
            b'G' => match (value * 10.0).round() as i64 {
                0 => words.motion = Some(0),
                10 => words.motion = Some(1),
                20 => words.motion = Some(2),
                30 => words.motion = Some(3),
                40 => words.dwell = true,
                170 => self.plane = Plane::XY,
                180 => self.plane = Plane::ZX,
                190 => self.plane = Plane::YZ,
                200 => self.inch = true,
                210 => self.inch = false,
                // Homing, bed probing (RepRapFirmware's and Prusa's G29 take X Y as an
                // area), going to a stored position, direct moves: where they end is the
                // controller's business, not the written numbers'.
                60 | 280 | 290 | 300 | 1610 | 1620 => words.home = true,
                // Probing (G31, G38.x) stops somewhere along the named axes; offsets set
                // with G10 or G52 move the frame of the named axes.
                100 | 310 | 380..=389 | 520 => words.probe = true,
                530 => words.machine = true,
                900 => self.absolute = true,
                910 => self.absolute = false,
                920 => words.set = true,
                930 => self.inverse_time = true,
                940 => self.inverse_time = false,
                _ => {}
            },
            b'M' => match value as i64 {
                82 => self.relative_e = false,
                83 => self.relative_e = true,
                _ => {}
            },
            b'F' => words.f = Some(value),
            b'P' => words.p = Some(value),
            b'S' => words.s = Some(value),
            b'I' => words.ijk[0] = Some(value),
            b'J' => words.ijk[1] = Some(value),
            b'K' => words.ijk[2] = Some(value),
            _ => {
                if let Some(axis) = Axis::from_letter(letter as char) {
                    words.axes[axis.index()] = Some(value);
                    words.any_axis = true;
                }
            }
        }
    }

    fn apply(&mut self, w: Words) -> Option<Event> {
        let scale = if self.inch { 25.4 } else { 1.0 };
        if let Some(f) = w.f {
            self.feed = Some(if self.inverse_time { f } else { f * scale });
        }
        if w.dwell {
            let seconds = match (w.p, w.s) {
                (Some(p), _) => self.dwell_unit.seconds(p),
                (None, Some(s)) => s,
                _ => 0.0,
            };
            return Some(Event::Dwell(seconds));
        }
        if w.home || w.probe {
            let mut lost = AxisSet::default();
            for a in Axis::ALL {
                if w.axes[a.index()].is_some() || (w.home && !w.any_axis) {
                    lost.insert(a);
                }
            }
            self.pos.forget(lost);
            return Some(Event::Lost(lost));
        }
        if let Some(m) = w.motion {
            self.motion = m;
        }
        if w.set || w.machine {
            // G92 declares the position; G53 moves in machine coordinates, which the
            // reader takes as they are written (it knows no work offsets): both leave the
            // written axes where the controller says.
            let from = self.pos;
            for a in Axis::ALL {
                if let Some(v) = w.axes[a.index()] {
                    self.pos.set(
                        a,
                        if a.is_rotary() || a == Axis::E {
                            v
                        } else {
                            v * scale
                        },
                    );
                }
            }
            if w.set || !w.any_axis {
                return None;
            }
            let mut m = self.timed(from, self.pos, &w, scale);
            m.machine = true;
            return Some(Event::Move(m));
        }
        if !w.any_axis {
            return None;
        }
        let from = self.pos;
        let mut to = from;
        for a in Axis::ALL {
            let Some(v) = w.axes[a.index()] else { continue };
            let v = if a.is_rotary() || a == Axis::E {
                v
            } else {
                v * scale
            };
            let relative = if a == Axis::E {
                self.relative_e || !self.absolute
            } else {
                !self.absolute
            };
            let base = from.get(a).unwrap_or(0.0);
            to.set(a, if relative { base + v } else { v });
        }
        self.pos = to;
        Some(Event::Move(self.timed(from, to, &w, scale)))
    }

    fn timed(&self, from: Joints, to: Joints, w: &Words, scale: f64) -> Move {
        let arc = match self.motion {
            2 | 3 => {
                let mut center = nalgebra::Vector3::zeros();
                let ijk = [w.ijk[0], w.ijk[1], w.ijk[2]];
                for (k, a) in [Axis::X, Axis::Y, Axis::Z].into_iter().enumerate() {
                    center[k] = from.get(a).unwrap_or(0.0) + ijk[k].unwrap_or(0.0) * scale;
                }
                Some(Arc {
                    clockwise: self.motion == 2,
                    plane: self.plane,
                    center,
                    extra_turns: 0,
                })
            }
            _ => None,
        };
        let kind = match (self.motion, arc) {
            (0, _) => MotionKind::Rapid,
            (_, Some(a)) => MotionKind::Arc(a),
            _ => MotionKind::Linear,
        };
        let feed = Feed {
            mode: if self.inverse_time {
                FeedMode::InverseTime
            } else {
                FeedMode::PerMinute
            },
            rate: self.feed,
        };
        let seg = self.model.between(&from, &to, kind, &feed);
        let seconds = if seg.moves() {
            seg.length / seg.v_max
        } else {
            0.0
        };
        Move {
            from,
            to,
            rapid: self.motion == 0,
            arc,
            machine: false,
            seconds,
            segment: seg,
        }
    }
}

/// The words of one line.
#[derive(Debug, Default, Clone, Copy)]
struct Words {
    motion: Option<u8>,
    dwell: bool,
    home: bool,
    /// A probing or offset code: the named axes end where the controller says.
    probe: bool,
    set: bool,
    machine: bool,
    any_axis: bool,
    f: Option<f64>,
    p: Option<f64>,
    s: Option<f64>,
    ijk: [Option<f64>; 3],
    axes: [Option<f64>; crate::ir::AXIS_COUNT],
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::Controller;

    fn reader(flavour: Flavour) -> Reader {
        let c = Controller {
            flavour: Some(flavour),
            min_speed: Some(0.0),
            ..Controller::default()
        };
        Reader::new(Model::new(&c), Some(flavour), None)
    }

    fn seconds(r: &mut Reader, line: &str) -> f64 {
        match r.line(line) {
            Some(Event::Move(m)) => m.seconds,
            Some(Event::Dwell(s)) => s,
            e => panic!("{line}: {e:?}"),
        }
    }

    /// A G0 without F runs at the modal F of the last G1 on an FDM firmware.
    #[test]
    fn rapid_at_modal_feed_on_fdm() {
        let mut r = reader(Flavour::RrfFdm);
        r.line("G0 X0 Y0");
        assert!((seconds(&mut r, "G1 X10 F600") - 1.0).abs() < 1e-12);
        assert!((seconds(&mut r, "G0 X30") - 2.0).abs() < 1e-12);
    }

    /// Relative moves, inches and dwell units per flavour.
    #[test]
    fn modes_and_dwells() {
        let mut r = reader(Flavour::RrfCnc);
        r.line("G0 X0");
        r.line("G91 G20");
        assert!((seconds(&mut r, "G1 X1 F60") - 1.0).abs() < 1e-12);
        assert!((r.pos().get(Axis::X).unwrap() - 25.4).abs() < 1e-12);
        assert!((seconds(&mut r, "G4 P250") - 0.25).abs() < 1e-12);
        let mut g = reader(Flavour::Grbl);
        assert!((seconds(&mut g, "G4 P0.5") - 0.5).abs() < 1e-12);
    }

    /// A bed-probing `G29` with an area in X and Y (PrusaSlicer's Core One start code)
    /// and a `G38.2` probe are no moves to their numbers: the named axes are lost.
    #[test]
    fn probing_codes_with_axis_words_are_no_moves() {
        let mut r = reader(Flavour::RrfFdm);
        r.line("G0 X0 Y0 Z5");
        let lost = |e: Option<Event>| match e {
            Some(Event::Lost(set)) => set,
            e => panic!("{e:?}"),
        };
        let set = lost(r.line("G29 P9 X208 Y-2.5 W32 H4"));
        assert!(set.contains(Axis::X) && set.contains(Axis::Y) && !set.contains(Axis::Z));
        assert_eq!(r.pos().get(Axis::X), None);
        let set = lost(r.line("G38.2 Z-10 F50"));
        assert!(set.contains(Axis::Z) && !set.contains(Axis::X));
        assert!(lost(r.line("G29")).contains(Axis::Z));
    }

    /// The polar printer's commands are recognised as written in the preset.
    #[test]
    fn polar_commands() {
        let p = Polar::default();
        let mut r = Reader::new(Model::default(), Some(Flavour::RrfFdm), Some(&p));
        assert_eq!(r.line("M42 P0 S1 ; open"), Some(Event::Valve(true)));
        assert_eq!(r.line("m42 p0 s0"), Some(Event::Valve(false)));
        assert_eq!(r.line("M3 S48.5"), Some(Event::Screw(48.5)));
        assert_eq!(r.line(" m3  s 48.5 "), Some(Event::Screw(48.5)));
        // Another pin's value, or the command's start alone, is no valve command.
        assert_eq!(r.line("M42 P0 S10"), None);
        assert_eq!(r.line("M42 P0"), None);
        assert_eq!(r.line(""), None);
    }
}
