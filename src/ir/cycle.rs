//! Canned drilling cycles (`G73`, `G74`, `G81`–`G89`) as the G-code frontend resolves them.
//!
//! A cycle line travels as [`Verbatim`](super::Verbatim) text, so that a controller with
//! cycles (LinuxCNC, Fanuc) gets it as written. The frontend resolves it as it resolves a
//! move, and attaches the result ([`CycleLine`]): where each hole is, the R plane, the
//! bottom, the level each hole retracts to, and where the tool is after the line. The
//! [`Tracker`](super::Tracker) puts the position there, so the moves after a cycle (G91
//! ones included) start from where the controller left the tool; `expand-cycles` drills
//! the holes as moves for controllers without cycles.
//!
//! The semantics are LinuxCNC's (G-code reference, "G80-G89 Canned Cycles" and "G98, G99";
//! `interp_cycles.cc`), which are also Fanuc's for the cycles ncpost drills:
//! - the initial level is the Z before the first cycle of a series (a series ends at `G80`
//!   or at any motion code that is not a cycle); under `G98` each hole retracts to it, or
//!   to R when it is lower; under `G99` to R;
//! - under `G91`, R is an increment from the initial level and Z an increment from R; X and
//!   Y are increments from the current position, stepped again at each repeat.

use super::{Feed, Joints};

/// A canned-cycle line: resolved, or why it could not be.
#[derive(Debug, Clone, PartialEq)]
pub enum CycleLine {
    /// Its holes and planes are known.
    Resolved(Box<CannedCycle>),
    /// The frontend could not resolve it (an unknown start, a missing word, a parameter);
    /// the positions it moves are unknown after it.
    Unresolved(Box<CycleProblem>),
}

/// A canned-cycle line resolved by the frontend. Heights and hole positions are in the
/// IR frame (millimetres, without G92 offsets).
#[derive(Debug, Clone, PartialEq)]
pub struct CannedCycle {
    /// The cycle's G number: 73, 74, 81 to 89 (76 is never resolved).
    pub code: u32,
    /// The R plane: where each hole starts feeding.
    pub r: f64,
    /// The bottom of the holes.
    pub bottom: f64,
    /// The height each hole retracts to: R under `G99`; under `G98` the initial level, or
    /// R when that is lower.
    pub clear: f64,
    /// X and Y of each hole, in drilling order (empty for Fanuc's `K0`, which only sets
    /// the cycle's words).
    pub holes: Vec<[f64; 2]>,
    /// The peck depth of `G73` and `G83`, mm.
    pub q: Option<f64>,
    /// The dwell at the bottom, seconds (`G82`, `G86`, `G88`, `G89`; optional on
    /// `G74`/`G84`).
    pub dwell: Option<f64>,
    /// The feed of the strokes into and out of the holes.
    pub feed: Feed,
    /// The position after the line: X and Y of the last hole, Z at the retract level (Z
    /// unknown after `G88`, whose retract is manual). Only the axes it knows are set.
    pub end: Joints,
}

/// Why a canned-cycle line could not be resolved, and where on the line.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleProblem {
    /// What is wrong.
    pub message: String,
    /// What to do.
    pub help: &'static str,
    /// Byte range on the line (the whole line when no one word is at fault).
    pub at: (usize, usize),
}

impl CycleLine {
    /// The resolved cycle, if the line is one.
    pub fn resolved(&self) -> Option<&CannedCycle> {
        match self {
            CycleLine::Resolved(c) => Some(c),
            CycleLine::Unresolved(_) => None,
        }
    }
}
