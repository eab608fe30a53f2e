//! The options of the CL frontend (`[cl_input]` in a preset).

use serde::{Deserialize, Serialize};

/// The length unit of a CL program that does not name one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Units {
    /// Millimetres, unless the first feed with a unit word is in inches (`IPM`, `IPR`).
    #[default]
    Auto,
    /// Millimetres.
    Mm,
    /// Inches.
    Inch,
}

/// What the frontend does with NX `MSYS` (the machine coordinate system the points
/// that follow are written in).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Msys {
    /// Use the points as written, in the MCS: what NX's own postprocessors print (the
    /// MCS origin is the work offset). A rotated or moved MCS gets one warning.
    #[default]
    Ignore,
    /// Move points and tool axes from the MCS into the frame `MSYS` is given in (NX's
    /// absolute coordinate system): `p' = origin + R p`, `a' = R a`.
    Apply,
}

/// Frontend options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// Chord tolerance (mm) for turning CIRCLE/MOVARC arcs and NURBS splines into
    /// straight pieces in the part frame.
    pub arc_tolerance: f64,
    /// Largest distance (mm) of an arc's start or end point from its circle, beyond
    /// which the arc becomes a straight move with a warning (0.1 % of the radius is also
    /// allowed).
    pub radius_tolerance: f64,
    /// Length unit before any `UNITS` statement.
    pub units: Units,
    /// Command for `END` (end of a program section); empty passes it as a comment.
    pub end_command: String,
    /// Command for `FINI` (end of the program); empty passes it as a comment.
    pub fini_command: String,
    /// How far (mm) a pecking drill cycle backs off before the next peck, at most the
    /// cycle's `RAPTO`.
    pub peck_clearance: f64,
    /// Longest line accepted, bytes; a longer line is an error and is skipped. Also the
    /// limit of a statement continued over several lines.
    pub max_line_len: usize,
    /// NX `MSYS`: `ignore` (the default, as NX posts do) or `apply`.
    pub msys: Msys,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            arc_tolerance: 0.001,
            radius_tolerance: 0.01,
            units: Units::Auto,
            end_command: "M0".into(),
            fini_command: "M2".into(),
            peck_clearance: 0.5,
            max_line_len: 1 << 20,
            msys: Msys::Ignore,
        }
    }
}
