//! Arcs (G2/G3): the centre from I/J/K offsets or from R, checked against the end point
//! within the arc tolerance, and full turns from P.

use nalgebra::Vector3;

use super::words::Slots;
use super::{Lowerer, MM_PER_INCH};
use crate::diag::Diagnostic;
use crate::ir::{Arc, Joints, Plane};

/// The centre-offset letters of a plane: the two in the plane, then the one across it.
fn plane_offset_letters(plane: Plane) -> (char, char, char) {
    match plane {
        Plane::XY => ('I', 'J', 'K'),
        Plane::ZX => ('K', 'I', 'J'),
        Plane::YZ => ('J', 'K', 'I'),
    }
}

/// An error on an arc block as a whole.
fn arc_err(line_no: u32, text: &str, msg: String, help: &str) -> Diagnostic {
    Diagnostic::error("gcode::arc", msg)
        .at_bytes(line_no, text, 0, text.len())
        .with_label("this arc")
        .with_help(help.to_string())
}

/// The error for an arc off its circle: the controller would stop the job at it.
fn off_circle_err(line_no: u32, text: &str, msg: String, help: &str) -> Diagnostic {
    arc_err(
        line_no,
        text,
        msg,
        &format!(
            "{help}; LinuxCNC and Grbl refuse such an arc and stop the job there (set \
             gcode_input.strict_arcs = false to keep it as written, for a controller \
             that cuts it anyway, as RepRapFirmware and Mach3 do)"
        ),
    )
}

/// An arc's start and end in its plane, and the block it is written on.
struct Chord<'t> {
    start: [f64; 2],
    end: [f64; 2],
    line_no: u32,
    text: &'t str,
}

impl Lowerer {
    /// An arc needs its centre given one way: R, or the offsets in its plane. Without
    /// either (or with both) it is wrong wherever it starts.
    pub(super) fn check_arc_form(
        &self,
        text: &str,
        line_no: u32,
        slots: &Slots<'_, '_>,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<()> {
        let letters = plane_offset_letters(self.plane);
        let has_offsets = slots.has(letters.0) || slots.has(letters.1);
        if has_offsets != slots.has('R') {
            return Some(());
        }
        let msg = if has_offsets {
            "arc has both a radius (R) and centre offsets"
        } else {
            "arc has neither a radius (R) nor centre offsets"
        };
        let help = if has_offsets {
            "give either R or the centre offsets, not both".to_string()
        } else {
            format!(
                "add {} and {} (centre relative to the start) or R",
                letters.0, letters.1
            )
        };
        diags.push(
            Diagnostic::error("gcode::arc", msg)
                .at_bytes(line_no, text, 0, text.len())
                .with_label("this arc")
                .with_help(help),
        );
        None
    }

    /// Whether the arc's start is known in its plane; warns when it is not (the centre
    /// depends on the start, so the block passes through as written).
    pub(super) fn arc_start_known(
        &self,
        text: &str,
        line_no: u32,
        diags: &mut Vec<Diagnostic>,
    ) -> bool {
        let (u, v, _) = self.plane.axes();
        if self.pos.get(u).is_some() && self.pos.get(v).is_some() {
            return true;
        }
        diags.push(
            Diagnostic::warning("gcode::arc-unknown-start", "arc starts from a position that is not known here")
                .at_bytes(line_no, text, 0, text.len())
                .with_label("passes through unchanged")
                .with_help(format!(
                    "its centre depends on the start; move {} and {} to absolute positions before the arc",
                    u.letter(),
                    v.letter()
                )),
        );
        false
    }

    /// The arc from the current position to `target`; `None` once an error is reported.
    pub(super) fn arc(
        &self,
        text: &str,
        line_no: u32,
        clockwise: bool,
        slots: &Slots<'_, '_>,
        target: &Joints,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<Arc> {
        let (u, v, _) = self.plane.axes();
        let start = self.pos;
        let chord = Chord {
            start: [start.values[u.index()], start.values[v.index()]],
            end: [target.values[u.index()], target.values[v.index()]],
            line_no,
            text,
        };
        let letters = plane_offset_letters(self.plane);
        let mut extra_turns = 0;
        if let Some(p) = slots.get('P') {
            if p.value < 1.0 || p.value.fract() != 0.0 {
                diags.push(
                    Diagnostic::error(
                        "gcode::arc-turns",
                        format!("`{}`: P must be a whole number of turns, 1 or more", p.text),
                    )
                    .at_bytes(line_no, text, p.start, p.end)
                    .with_label("not a whole number of turns")
                    .with_help(
                        "P counts full turns of the arc: P1 is a plain arc, P2 adds one more turn",
                    ),
                );
                return None;
            }
            extra_turns = p.value as u32 - 1;
        }
        if let Some(w) = slots.get(letters.2) {
            diags.push(
                Diagnostic::error(
                    "gcode::arc",
                    format!(
                        "`{}` is not used by an arc in the {} plane",
                        w.text,
                        self.plane.gcode()
                    ),
                )
                .at_bytes(line_no, text, w.start, w.end)
                .with_help(format!(
                    "in {} the centre offsets are {} and {}",
                    self.plane.gcode(),
                    letters.0,
                    letters.1
                )),
            );
            return None;
        }
        let unit = if self.inch { MM_PER_INCH } else { 1.0 };
        let (off_u, off_v) = (slots.get(letters.0), slots.get(letters.1));
        let centre2 = match (off_u.is_some() || off_v.is_some(), slots.get('R')) {
            // Checked by `check_arc_form`: exactly one of the two forms.
            (true, Some(_)) | (false, None) => return None,
            (true, None) => {
                let du = off_u.map_or(0.0, |w| w.value * unit);
                let dv = off_v.map_or(0.0, |w| w.value * unit);
                let c = if self.arc_center_absolute {
                    [du - self.offsets[u.index()], dv - self.offsets[v.index()]]
                } else {
                    [chord.start[0] + du, chord.start[1] + dv]
                };
                self.check_centre(&chord, c, diags)?
            }
            (false, Some(rw)) => {
                self.centre_from_radius(&chord, clockwise, rw.value * unit, diags)?
            }
        };
        let mut center = Vector3::zeros();
        center[u.index()] = centre2[0];
        center[v.index()] = centre2[1];
        Some(Arc {
            clockwise,
            plane: self.plane,
            center,
            extra_turns,
        })
    }

    /// A centre given by offsets must be as far from the end as from the start, within
    /// the arc tolerance (or 0.1 % of the radius); outside it the arc is refused, or with
    /// `strict_arcs = false` kept as written with a warning.
    fn check_centre(
        &self,
        chord: &Chord<'_>,
        c: [f64; 2],
        diags: &mut Vec<Diagnostic>,
    ) -> Option<[f64; 2]> {
        let (s2, e2) = (chord.start, chord.end);
        let (line_no, text) = (chord.line_no, chord.text);
        let r0 = ((s2[0] - c[0]).powi(2) + (s2[1] - c[1]).powi(2)).sqrt();
        let r1 = ((e2[0] - c[0]).powi(2) + (e2[1] - c[1]).powi(2)).sqrt();
        let tol = self.options.arc_tolerance.max(1e-3 * r0.max(r1));
        if (r0 - r1).abs() > tol {
            let msg = format!(
                "arc radius does not fit its end points: {r0:.4} mm at the start, {r1:.4} mm at the end"
            );
            if self.options.strict_arcs {
                diags.push(off_circle_err(
                    line_no,
                    text,
                    msg,
                    "check the end point and the centre offsets; they must be equidistant from the centre",
                ));
                return None;
            }
            diags.push(
                Diagnostic::warning("gcode::arc-radius", msg)
                    .at_bytes(line_no, text, 0, text.len())
                    .with_label("kept as written")
                    .with_help(
                        "the centre is kept where the offsets put it; controllers may reject \
                         the arc or move in a spiral (strict_arcs = false keeps it)",
                    ),
            );
        }
        if r0 == 0.0 {
            diags.push(arc_err(
                line_no,
                text,
                "arc centre is at its start point".into(),
                "the centre offsets must not all be 0",
            ));
            return None;
        }
        Some(c)
    }

    /// The centre of an R arc: right of the chord for G2 with R > 0, left for G3, and
    /// the other side for R < 0 (the arc over half a turn). A radius too short for the
    /// chord is an error, or with `strict_arcs = false` a half circle, as Mach3 makes
    /// it, with a warning.
    fn centre_from_radius(
        &self,
        chord: &Chord<'_>,
        clockwise: bool,
        radius: f64,
        diags: &mut Vec<Diagnostic>,
    ) -> Option<[f64; 2]> {
        let (s2, e2) = (chord.start, chord.end);
        let (line_no, text) = (chord.line_no, chord.text);
        let d = ((e2[0] - s2[0]).powi(2) + (e2[1] - s2[1]).powi(2)).sqrt();
        if d < 1e-9 {
            diags.push(arc_err(
                line_no,
                text,
                "an R arc cannot end where it starts".into(),
                "a full circle needs centre offsets instead of R",
            ));
            return None;
        }
        let half = d / 2.0;
        let tol = self.options.arc_tolerance.max(1e-3 * radius.abs());
        if radius == 0.0 {
            diags.push(arc_err(
                line_no,
                text,
                "arc radius R0 is not a circle".into(),
                "give the arc's radius",
            ));
            return None;
        }
        if half > radius.abs() + tol {
            let msg = format!(
                "arc radius {:.4} mm does not fit its end points, which are {:.4} mm apart",
                radius.abs(),
                d
            );
            let help = "the radius must be at least half the distance between start and end";
            if self.options.strict_arcs {
                diags.push(off_circle_err(line_no, text, msg, help));
                return None;
            }
            diags.push(
                Diagnostic::warning("gcode::arc-radius", msg)
                    .at_bytes(line_no, text, 0, text.len())
                    .with_label("made a half circle")
                    .with_help(format!(
                        "{help}; it is kept as a half circle through both points, as Mach3 \
                         does (strict_arcs = false keeps it)"
                    )),
            );
        }
        let h = (radius * radius - half * half).max(0.0).sqrt();
        let mid = [(s2[0] + e2[0]) / 2.0, (s2[1] + e2[1]) / 2.0];
        let dir = [(e2[0] - s2[0]) / d, (e2[1] - s2[1]) / d];
        let right = [dir[1], -dir[0]];
        let sign = if clockwise == (radius > 0.0) {
            1.0
        } else {
            -1.0
        };
        Some([mid[0] + sign * h * right[0], mid[1] + sign * h * right[1]])
    }
}
