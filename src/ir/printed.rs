//! Positions as the controller reads them back: joints rounded to the printed decimals.

use super::{AXIS_COUNT, Axis, AxisSet, Joints};
use crate::num::print::{Decimals, printed};

/// The joints as the controller reads them when the backend prints at `decimals`
/// ([`Decimals::printed_joints`]), or `j` itself when nothing is printed (a pass run
/// without a backend, on the exact IR).
pub fn as_printed(
    decimals: Option<Decimals>,
    j: &Joints,
    offsets: &[f64; AXIS_COUNT],
    seen: Option<&(Joints, Joints)>,
) -> Joints {
    match decimals {
        Some(d) => d.printed_joints(j, offsets, seen),
        None => *j,
    }
}

impl Decimals {
    /// Decimals for an axis.
    ///
    /// ```
    /// use ncpost::ir::Axis;
    /// use ncpost::num::print::Decimals;
    /// assert_eq!(Decimals::default().axis(Axis::E), 5);
    /// ```
    pub fn axis(&self, axis: Axis) -> u8 {
        if axis == Axis::E {
            self.extruder
        } else if axis.is_rotary() {
            self.rotary
        } else {
            self.linear
        }
    }

    /// The joints as the controller reads them: each known axis printed at its decimals
    /// with `offsets` (the G92 offsets the backend adds), which are then taken off again.
    /// An axis that `seen` (joints and their printed form) has at the same value takes its
    /// printed value from there: most moves change two or three axes.
    pub fn printed_joints(
        &self,
        j: &Joints,
        offsets: &[f64; AXIS_COUNT],
        seen: Option<&(Joints, Joints)>,
    ) -> Joints {
        let mut p = *j;
        let (reusable, key, printed_seen) = match seen {
            Some((key, printed)) => (key.known.intersection(printed.known), key, printed),
            None => (AxisSet::EMPTY, j, j),
        };
        for a in j.known.iter() {
            let i = a.index();
            if reusable.contains(a) && key.values[i] == j.values[i] {
                p.values[i] = printed_seen.values[i];
            } else if let Some(v) = printed(j.values[i] + offsets[i], self.axis(a)) {
                p.values[i] = v - offsets[i];
            }
        }
        p
    }
}
