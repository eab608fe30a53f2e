//! [`Modal`]: the modal state a line of G-code is read in.

use super::{AXIS_COUNT, FeedMode, Joints, Plane};

/// The motion mode in force (modal group 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionMode {
    /// No motion mode yet (program start, or after a line that was not evaluated).
    None,
    /// G0.
    Rapid,
    /// G1.
    Linear,
    /// G2 (clockwise) or G3.
    Arc {
        /// G2.
        clockwise: bool,
    },
    /// A mode the IR does not model (canned cycles, splines, threading).
    Unsupported,
}

/// Everything the meaning of a line of G-code depends on: the modes in force, the
/// position and the G92 frame. A subprogram body starts in the state of its call and
/// leaves one behind (`expand-subprograms` lowers bodies from it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Modal {
    /// Motion mode in force (G0/G1/G2/G3).
    pub motion: MotionMode,
    /// Arc plane.
    pub plane: Plane,
    /// G20.
    pub inch: bool,
    /// G91.
    pub relative: bool,
    /// M83 (E relative; G91 moves E relatively too).
    pub relative_e: bool,
    /// G90.1.
    pub arc_center_absolute: bool,
    /// G93/G94/G95.
    pub feed_mode: FeedMode,
    /// Modal feed, mm/min (or the mode's unit).
    pub feed: Option<f64>,
    /// Position, IR frame.
    pub pos: Joints,
    /// G92 offsets (program = IR + offset).
    pub offsets: [f64; AXIS_COUNT],
    /// Offsets suspended by G92.2.
    pub suspended: Option<[f64; AXIS_COUNT]>,
}
