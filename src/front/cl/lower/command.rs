//! Feeds, units and the statements that become machine commands: `FEDRAT`, `UNITS`,
//! `SPINDL`, `COOLNT`, `LOADTL`, `DELAY`, `END`/`FINI`/`STOP`/`OPSTOP`, `CYCLE`.

use super::{Args, Lowerer, command, comment};
use crate::diag::Diagnostic;
use crate::front::cl::ast::ArgKind;
use crate::front::cl::cycle;
use crate::front::cl::motion::MM_PER_INCH;
use crate::front::cl::source::Statement;
use crate::ir::{Block, BlockKind, Feed, FeedMode};

/// A number as a G-code word value: at most 4 decimals, no trailing zeros.
pub(super) fn format_number(v: f64) -> String {
    let mut s = format!("{v:.4}");
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    if s == "-0" { "0".to_string() } else { s }
}

impl Lowerer {
    pub(super) fn fedrat(&mut self, a: &Args<'_>) -> Result<(), Diagnostic> {
        let mut rate = None;
        let mut unit: Option<(f64, FeedMode)> = None;
        for x in a.list {
            if x.kind == ArgKind::Number {
                if rate.is_some() {
                    return Err(a.stmt.locate(
                        Diagnostic::error("cl::arity", "FEDRAT takes one rate")
                            .with_label("second number")
                            .with_help("write FEDRAT/f or FEDRAT/f,MMPM (or IPM, MMPR, IPR)"),
                        x.start,
                        x.end,
                    ));
                }
                rate = Some((a.number(x)?, x));
                continue;
            }
            let w = a.text(x).to_ascii_uppercase();
            unit = Some(match w.as_str() {
                "MMPM" => (1.0, FeedMode::PerMinute),
                "IPM" => (MM_PER_INCH, FeedMode::PerMinute),
                "MMPR" => (1.0, FeedMode::PerRevolution),
                "IPR" => (MM_PER_INCH, FeedMode::PerRevolution),
                "PERMIN" => (self.scale, FeedMode::PerMinute),
                "PERREV" => (self.scale, FeedMode::PerRevolution),
                _ => {
                    return Err(a.stmt.locate(
                        Diagnostic::error(
                            "cl::feed-unit",
                            format!("unknown feed unit `{}`", crate::num::range::shown(&w)),
                        )
                        .with_label("not a feed unit")
                        .with_help("use MMPM, IPM, MMPR or IPR"),
                        x.start,
                        x.end,
                    ));
                }
            });
        }
        let Some((r, arg)) = rate else {
            return Err(a.error_all(
                Diagnostic::error("cl::arity", "FEDRAT needs a rate")
                    .with_help("write FEDRAT/f or FEDRAT/f,MMPM (or IPM, MMPR, IPR)"),
            ));
        };
        if r < 0.0 {
            return Err(a.stmt.locate(
                Diagnostic::error("cl::bad-value", "the feed rate is negative")
                    .with_label("negative")
                    .with_help("a feed rate is a speed: give a positive number"),
                arg.start,
                arg.end,
            ));
        }
        let (factor, mode) = unit.unwrap_or((self.scale, self.feed.mode));
        let rate = r * factor;
        if !rate.is_finite() {
            return Err(a.stmt.locate(
                Diagnostic::error("cl::bad-number", "the feed rate is out of range")
                    .with_label("too large"),
                arg.start,
                arg.end,
            ));
        }
        self.feed = Feed {
            mode,
            rate: Some(rate),
        };
        Ok(())
    }

    pub(super) fn units(&mut self, a: &Args<'_>, major: &str) -> Result<(), Diagnostic> {
        let word = match a.list {
            [x] => a.word(x),
            _ => None,
        };
        self.scale = match word.as_deref() {
            Some("INCHES" | "INCH" | "IN") => MM_PER_INCH,
            Some("MM" | "MILLIMETERS" | "MILLIMETRES" | "METRIC") => 1.0,
            Some("CM" | "CENTIMETERS" | "CENTIMETRES") => 10.0,
            _ => {
                return Err(a.error_all(
                    Diagnostic::error("cl::bad-value", format!("{major} takes MM or INCHES"))
                        .with_label("here")
                        .with_help(format!("write {major}/MM or {major}/INCHES")),
                ));
            }
        };
        Ok(())
    }

    pub(super) fn spindle(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        out: &mut Vec<Block>,
    ) -> Result<(), Diagnostic> {
        let mut rpm = None;
        let mut on = false;
        let mut off = false;
        let mut ccw = None;
        let mut i = 0;
        while i < a.list.len() {
            let x = &a.list[i];
            if x.kind == ArgKind::Number {
                if rpm.is_none() {
                    rpm = Some((a.number(x)?, x));
                }
                i += 1;
                continue;
            }
            match a.text(x).to_ascii_uppercase().as_str() {
                "ON" => on = true,
                "OFF" => off = true,
                "CLW" => ccw = Some(false),
                "CCLW" => ccw = Some(true),
                "RPM" => {}
                // A value that is not the speed.
                "RANGE" | "MAXRPM" => i += 1,
                "SFM" | "SMM" => {
                    return Err(a.error_all(
                        Diagnostic::warning(
                            "cl::unsupported",
                            "constant surface speed cannot be expressed as a spindle speed",
                        )
                        .with_help("passed through as a comment; give the speed in RPM"),
                    ));
                }
                w => {
                    return Err(stmt.locate(
                        Diagnostic::error(
                            "cl::bad-value",
                            format!("unknown SPINDL word `{}`", crate::num::range::shown(w)),
                        )
                        .with_label("not understood")
                        .with_help("write SPINDL/rpm,CLW (or CCLW), SPINDL/ON or SPINDL/OFF"),
                        x.start,
                        x.end,
                    ));
                }
            }
            i += 1;
        }
        if off {
            out.push(Block::new(stmt.span, command("M5")));
            return Ok(());
        }
        if let Some((r, x)) = rpm {
            if r < 0.0 {
                return Err(stmt.locate(
                    Diagnostic::error("cl::bad-value", "the spindle speed is negative")
                        .with_label("negative")
                        .with_help(
                            "give the speed as a positive number and the direction as CLW or CCLW",
                        ),
                    x.start,
                    x.end,
                ));
            }
            self.spindle_rpm = Some(r);
        } else if !on && ccw.is_none() {
            return Err(a.error_all(
                Diagnostic::error("cl::arity", "SPINDL needs a speed, ON or OFF")
                    .with_help("write SPINDL/rpm,CLW (or CCLW), SPINDL/ON or SPINDL/OFF"),
            ));
        }
        if let Some(d) = ccw {
            self.spindle_ccw = d;
        }
        let mut text = String::from(if self.spindle_ccw { "M4" } else { "M3" });
        if let Some(r) = self.spindle_rpm {
            text.push_str(" S");
            text.push_str(&format_number(r));
        }
        out.push(Block::new(stmt.span, command(text)));
        Ok(())
    }

    pub(super) fn coolant(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        out: &mut Vec<Block>,
    ) -> Result<(), Diagnostic> {
        let words: Vec<String> = a.list.iter().filter_map(|x| a.word(x)).collect();
        let has = |w: &str| words.iter().any(|x| x == w);
        let code = if has("OFF") {
            "M9"
        } else if has("MIST") || has("AIR") {
            "M7"
        } else if has("ON") || has("FLOOD") || has("THRU") {
            "M8"
        } else {
            return Err(a.error_all(
                Diagnostic::warning("cl::unsupported", "COOLNT mode not understood")
                    .with_help("passed through as a comment; use COOLNT/ON, FLOOD, MIST or OFF"),
            ));
        };
        out.push(Block::new(stmt.span, command(code)));
        Ok(())
    }

    pub(super) fn load_tool(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        at: usize,
        out: &mut Vec<Block>,
    ) -> Result<(), Diagnostic> {
        let Some(x) = a.list.get(at) else {
            return Err(a.error_all(
                Diagnostic::error("cl::arity", "the tool number is missing")
                    .with_help("write LOADTL/n or LOAD/TOOL,n"),
            ));
        };
        let n = a.number(x)?;
        if !(n >= 0.0 && n.fract() == 0.0 && n < 1e9) {
            return Err(stmt.locate(
                Diagnostic::error("cl::bad-value", "the tool number is not a whole number")
                    .with_label("tool number")
                    .with_help("tool numbers are whole numbers from 0"),
                x.start,
                x.end,
            ));
        }
        let mut b = Block::new(stmt.span, command(format!("T{}", n as u64)));
        if a.list.len() > at + 1 {
            b.comments.push(comment(format!(" {}", stmt.code.trim())));
        }
        out.push(b);
        Ok(())
    }

    pub(super) fn delay(
        &mut self,
        stmt: &Statement,
        a: &Args<'_>,
        out: &mut Vec<Block>,
    ) -> Result<(), Diagnostic> {
        let (value, revolutions) = match a.list {
            [x] => (x, false),
            [w, x] if a.word(w).as_deref() == Some("REV") => (x, true),
            _ => {
                return Err(a.error_all(
                    Diagnostic::error("cl::arity", "DELAY takes one time in seconds")
                        .with_label("here")
                        .with_help("write DELAY/s or DELAY/REV,n"),
                ));
            }
        };
        let v = a.number(value)?;
        if v < 0.0 {
            return Err(stmt.locate(
                Diagnostic::error("cl::bad-value", "the delay is negative")
                    .with_label("negative")
                    .with_help("a delay is a time: give a positive number of seconds"),
                value.start,
                value.end,
            ));
        }
        let seconds = if revolutions {
            match self.spindle_rpm {
                Some(rpm) if rpm > 0.0 => v * 60.0 / rpm,
                _ => {
                    return Err(a.error_all(
                        Diagnostic::warning(
                            "cl::unsupported",
                            "DELAY/REV needs a known spindle speed",
                        )
                        .with_help("passed through as a comment; give the delay in seconds"),
                    ));
                }
            }
        } else {
            v
        };
        out.push(Block::new(stmt.span, BlockKind::Dwell { seconds }));
        Ok(())
    }

    pub(super) fn stop(&mut self, stmt: &Statement, code: String, out: &mut Vec<Block>) {
        if code.trim().is_empty() {
            self.pass_through(stmt, out);
        } else {
            out.push(Block::new(stmt.span, command(code.trim())));
        }
    }

    pub(super) fn cycle(&mut self, a: &Args<'_>) -> Result<(), Diagnostic> {
        match cycle::parse(a.stmt, a.list, self.scale) {
            Ok(cycle::Parsed::Off) => self.cycle.stop(),
            Ok(cycle::Parsed::Keep) => {}
            Ok(cycle::Parsed::On) => self.cycle.resume(),
            Ok(cycle::Parsed::Cycle(c)) => self.cycle = cycle::State::On(c),
            Err(d) => {
                // An unsupported cycle: the motions inside stay plain moves.
                self.cycle = cycle::State::Off;
                return Err(d);
            }
        }
        Ok(())
    }

    /// `CUTCOM/LEFT` or `RIGHT`: the points stay the tool position (one warning).
    pub(super) fn cutcom(&mut self, a: &Args<'_>, diags: &mut Vec<Diagnostic>) {
        let side = a.list.first().and_then(|x| a.word(x));
        if matches!(side.as_deref(), Some("LEFT" | "RIGHT")) && !self.warned_cutcom {
            self.warned_cutcom = true;
            diags.push(
                a.error_all(Diagnostic::warning(
                    "cl::cutcom",
                    "cutter compensation is not applied: the CL points are taken as \
                     the tool position",
                ))
                .with_help(
                    "CL data from CAM is normally already offset by the tool radius; \
                     check the CAM setting if the controller was meant to offset it",
                ),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    pub(super) fn numbers_print_short() {
        assert_eq!(format_number(12000.0), "12000");
        assert_eq!(format_number(2.5), "2.5");
        assert_eq!(format_number(-0.00001), "0");
        assert_eq!(format_number(1.23456), "1.2346");
    }
}
