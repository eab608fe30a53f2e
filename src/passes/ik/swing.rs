//! Leaving a singular orientation in a cut: the held rotary's swing spread over the start
//! of the move.
//!
//! At a singular orientation (the tool along the free rotary's axis) that rotary's value
//! does not matter, and `ik` holds it. The move leaving it may need another value; turned
//! on the spot, the rotary would swing while the tip stands in the material, and the
//! block would take as long as the swing at the reorientation feed. Instead the swing goes
//! into pieces along the start of the programmed line: the tip on the line at every piece
//! end, the free rotary stepping from the held value to the move's, the other rotary
//! pointing the tool as near the programmed axis as that allows. Near the singular
//! orientation a wrong free rotary tilts the tool little, so the axis leans at most
//! [`SWING_LEAN`] degrees off while the swing lasts, and the tip keeps the programmed
//! feed.
//!
//! When the singular pose was reached by a rapid (a cut starting with the tool along the
//! free rotary's axis, as CAM programs start from vertical), the swing is made there
//! instead, as rapids: the tool turns about its own axis over the start point before it
//! cuts, as a hand-written post positions every axis in the approach. Spread over the cut,
//! a swing of 90 degrees would fit into the first hundredth of a millimetre, and the tool
//! would stand in the material for the seconds the table needs to turn.

use nalgebra::{Point3, Unit, Vector3};

use super::{Choice, Ik};
use crate::ir::{Block, BlockKind, Joints, Motion, MotionKind, Span, Target};
use crate::passes::Output;

/// Largest angle (degrees) the tool axis leans off the programmed one while a swing is
/// spread: well inside `densify`'s default axis tolerance (0.05), which then need not split
/// the pieces for the axis.
pub const SWING_LEAN: f64 = 0.02;

/// Largest swing (degrees) of the free rotary in one piece: a pivot at radius r sags the
/// tip r (1 - cos(swing / 2)) off the line, 0.006 mm for 1 degree at 150 mm, so the tip
/// stays within `densify`'s tip tolerance on the pieces as emitted.
const PIECE_SWING: f64 = 1.0;

/// Swings smaller than this (degrees) are left to the move itself.
const LEAST_SWING: f64 = 1e-6;

/// A swing whose whole move keeps the tip this close (mm) to the line at its middle, and
/// the axis within [`SWING_LEAN`], is left to the move itself: `densify` then passes the
/// move as it is, and the program has no more blocks than it needs.
const MOVE_SAG: f64 = 0.0025;

impl Ik {
    /// Puts out the pieces that spread the free rotary's swing over the start of cutting
    /// move `m` (to the joints of `choice`), when the last pose held it at a singular
    /// orientation and `choice` turns it away; the pass's position follows the pieces.
    /// Nothing is put out when the swing is negligible or a piece would leave the limits.
    /// `true` when the swing was made at the rapid that reached the singular pose instead
    /// ([`Ik::swing_at_rapid`]): the cut then has no swing in it.
    pub(super) fn spread_swing(
        &mut self,
        span: Span,
        m: &Motion,
        choice: &Choice,
        out: &mut Output<'_>,
    ) -> bool {
        let Target::Pose(pose) = &m.target else {
            return false;
        };
        let (Some(k), None) = (self.held, choice.held) else {
            return false;
        };
        let Some((xyz, angles)) = self.prev_five() else {
            return false;
        };
        let (p, q) = (angles[k], choice.angles[k]);
        let swing = (q - p).abs();
        if swing <= LEAST_SWING {
            return false;
        }
        let start = self.machine.forward(&xyz, angles);
        let from_axis = match self.last_axis {
            Some((a, axis)) if a == angles => axis,
            _ => start.axis,
        };
        let turn = from_axis.angle(&pose.axis);
        if turn < 1e-12 {
            return false;
        }
        // A free rotary `d` off tilts an axis `t` from the singular direction by about
        // t d; stepping linearly to the end of the swing at fraction `reach` of the move,
        // the lean is at most reach turn swing / 4.
        let reach = (4.0 * SWING_LEAN.to_radians() / (turn * swing.to_radians())).min(1.0);
        if reach >= 1.0 && self.sag(start.tip, (xyz, angles), pose, choice) <= MOVE_SAG {
            return false;
        }
        if let Some(at) = self.held_rapid
            && self.swing_at_rapid(at, m, k, (p, q), (xyz, angles), out)
        {
            return true;
        }
        let n = (swing / PIECE_SWING).ceil().max(1.0);
        let first = reach / (2.0 * n);
        let ends = Ends {
            tip: (start.tip, pose.tip),
            axis: (from_axis, pose.axis),
        };
        let mut buf = std::mem::take(&mut self.swing_buf);
        buf.clear();
        if self.swing_pieces(&ends, k, (p, q), (first, reach, n as usize), &mut buf) {
            for &(tip, a) in &buf {
                let target = self.joints_at(&tip, a, None, pose.extra());
                let mut piece = m.clone();
                piece.target = Target::Joints(target);
                piece.written = piece.written.union(self.written());
                out.push(Block::new(span, BlockKind::Motion(piece)));
                self.prev = target;
            }
        }
        self.swing_buf = buf;
        false
    }

    /// Puts out the swing of held rotary `k` from `p` to `q` as rapids at the start
    /// `(xyz, angles)` of cutting move `m`, on the line `at` of the rapid that got there:
    /// the tool axis and the tip stay, pieces of at most [`PIECE_SWING`] keep the tip
    /// within a few micrometres of the point between them. `false`, putting out nothing,
    /// when the other rotary would leave its limits.
    fn swing_at_rapid(
        &mut self,
        at: Span,
        m: &Motion,
        k: usize,
        (p, q): (f64, f64),
        (xyz, angles): ([f64; 3], [f64; 2]),
        out: &mut Output<'_>,
    ) -> bool {
        let start = self.machine.forward(&xyz, angles);
        let n = ((q - p).abs() / PIECE_SWING).ceil().max(1.0) as usize;
        let j = 1 - k;
        let mut prev_j = Some(angles[j]);
        let mut buf = std::mem::take(&mut self.swing_buf);
        buf.clear();
        for i in 1..=n {
            let kv = p + (q - p) * i as f64 / n as f64;
            let o = self.machine.hold(start.axis, k, kv);
            let Some(jv) = self.in_limits(j, o.angles[j], prev_j) else {
                self.swing_buf = buf;
                return false;
            };
            prev_j = Some(jv);
            let mut a = [0.0; 2];
            a[k] = kv;
            a[j] = jv;
            buf.push((start.tip, a));
        }
        for &(tip, a) in &buf {
            let target = self.joints_at(&tip, a, None, &Joints::NONE);
            out.push(Block::new(
                at,
                BlockKind::Motion(Motion {
                    kind: MotionKind::Rapid,
                    target: Target::Joints(target),
                    feed: m.feed,
                    written: self.written(),
                    machine_frame: false,
                    extra: String::new(),
                }),
            ));
            self.prev = target;
        }
        self.swing_buf = buf;
        true
    }

    /// How far (mm) the tip is off the programmed line halfway through the move from the
    /// joints `from` (tip `from_tip`) to `pose` at the rotaries of `choice`, the controller
    /// moving the joints linearly.
    fn sag(
        &self,
        from_tip: Point3<f64>,
        (xyz, angles): ([f64; 3], [f64; 2]),
        pose: &crate::ir::Pose,
        choice: &Choice,
    ) -> f64 {
        let to = match choice.trig {
            Some(turns) => self.machine.linear_at(&pose.tip, &turns),
            None => self.machine.linear(&pose.tip, choice.angles),
        };
        let mid = |a: f64, b: f64| (a + b) / 2.0;
        let xyz_mid = [0, 1, 2].map(|i| mid(xyz[i], to[i]));
        let angles_mid = [0, 1].map(|i| mid(angles[i], choice.angles[i]));
        let tip = self.machine.forward(&xyz_mid, angles_mid).tip;
        // Off the programmed line (through both tips), or off the tip when it stays.
        let line = pose.tip - from_tip;
        let off = tip - from_tip;
        match line.try_normalize(1e-12) {
            Some(dir) => off.cross(&dir).norm(),
            None => off.norm(),
        }
    }

    /// The tips and rotaries of the pieces of a swing of rotary `k` from `p` to `q` (see
    /// [`Ik::spread_swing`]): the first at fraction `first` of the move with `k` still at
    /// `p`, then `n` steps to `q` at fraction `reach` (left to the move itself when that
    /// is its end). `false` when the other rotary would leave its limits.
    fn swing_pieces(
        &self,
        ends: &Ends,
        k: usize,
        (p, q): (f64, f64),
        (first, reach, n): (f64, f64, usize),
        buf: &mut Vec<(Point3<f64>, [f64; 2])>,
    ) -> bool {
        let j = 1 - k;
        let mut prev_j = self.prev.get(self.axes[j]);
        for i in 0..=n {
            let t = i as f64 / n as f64;
            let s = first + (reach - first) * t;
            if i == n && reach >= 1.0 {
                break;
            }
            let Some(axis) = ends.axis.0.try_slerp(&ends.axis.1, s, 1e-12) else {
                return false;
            };
            let kv = p + (q - p) * t;
            let o = self.machine.hold(axis, k, kv);
            let Some(jv) = self.in_limits(j, o.angles[j], prev_j) else {
                return false;
            };
            prev_j = Some(jv);
            let mut a = [0.0; 2];
            a[k] = kv;
            a[j] = jv;
            let tip = ends.tip.0 + (ends.tip.1 - ends.tip.0) * s;
            buf.push((tip, a));
        }
        true
    }
}

/// The programmed move a swing is spread over: tips and tool axes at its start and end.
struct Ends {
    tip: (Point3<f64>, Point3<f64>),
    axis: (Unit<Vector3<f64>>, Unit<Vector3<f64>>),
}
