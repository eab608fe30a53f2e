//! `mode = "e-axis"`: the pieces `polar-ik` cut from one source move share its E by
//! their Cartesian lengths.

use crate::ir::{Axis, Block, BlockKind, Joints};

use super::{ExtrudeRate, MAX_GROUP, Output};

impl ExtrudeRate {
    /// A block in `e-axis` mode: pieces of one source move are grouped, the rest
    /// passes (flushing the group).
    pub(super) fn run_e_axis(&mut self, block: Block, out: &mut Output<'_>) {
        let piece = match &block.kind {
            BlockKind::Motion(m) => !m.machine_frame && m.target.joints().is_some(),
            _ => false,
        };
        if !piece
            || self.group.first().is_some_and(|b| b.span != block.span)
            || self.group.len() >= MAX_GROUP
        {
            self.flush_group(out);
        }
        if !piece {
            if let BlockKind::Motion(m) = &block.kind {
                match m.target.joints() {
                    Some(j) => {
                        for a in j.known.iter() {
                            self.pos.set(a, j.values[a.index()]);
                        }
                        if m.machine_frame {
                            self.pos.forget(m.written);
                        }
                    }
                    None => self.pos.forget(m.written),
                }
            }
            match &block.kind {
                BlockKind::Command(c) => self.pos.forget(c.clobbers),
                BlockKind::Verbatim(v) => self.pos.forget(v.clobbers),
                _ => {}
            }
            out.push(block);
            return;
        }
        if self.group.is_empty() {
            self.group_start = self.pos;
        }
        if let Some(j) = block_joints(&block) {
            for a in j.known.iter() {
                self.pos.set(a, j.values[a.index()]);
            }
        }
        self.group.push(block);
    }

    /// Shares the E of the grouped pieces out by their Cartesian lengths.
    pub(super) fn flush_group(&mut self, out: &mut Output<'_>) {
        if self.group.is_empty() {
            return;
        }
        let mut group = std::mem::take(&mut self.group);
        let e0 = self.group_start.get(Axis::E);
        let mut prev = self.group_start;
        let mut lengths = Vec::with_capacity(group.len());
        let mut ok = e0.is_some();
        for b in &group {
            let Some(j) = block_joints(b) else {
                ok = false;
                break;
            };
            let mut to = prev;
            for a in j.known.iter() {
                to.set(a, j.values[a.index()]);
            }
            if !j.known.contains(Axis::E) {
                ok = false;
            }
            let len = match (self.point(&prev), self.point(&to)) {
                (Some(a), Some(b)) => (b - a).norm(),
                _ => {
                    ok = false;
                    0.0
                }
            };
            lengths.push(len);
            prev = to;
        }
        let total: f64 = lengths.iter().sum();
        if let (true, Some(e0), Some(e1)) = (ok && total > 0.0, e0, prev.get(Axis::E)) {
            let de = e1 - e0;
            let mut cum = 0.0;
            let n = group.len();
            for (i, (b, len)) in group.iter_mut().zip(&lengths).enumerate() {
                cum += len;
                let e = if i + 1 == n {
                    e1
                } else {
                    e0 + de * cum / total
                };
                if let BlockKind::Motion(m) = &mut b.kind
                    && let Some(j) = m.target.joints_mut()
                {
                    j.set(Axis::E, e);
                }
            }
        }
        for b in group.drain(..) {
            out.push(b);
        }
        self.group = group;
    }
}

/// The joint target of a motion block.
fn block_joints(b: &Block) -> Option<&Joints> {
    match &b.kind {
        BlockKind::Motion(m) => m.target.joints(),
        _ => None,
    }
}
