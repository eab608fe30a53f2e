//! Nearest group ends: a 2-d tree over the ends of a segment's groups, for the `k`
//! nearest ends of each end (the improvement moves' neighbour lists) and for the nearest
//! end of a group not yet cut (the nearest-neighbour order), each found in about
//! `log n` steps instead of a scan of the whole board. Ties go to the smaller end index,
//! as a scan in index order would give them.

use nalgebra::Point2;

/// The ends of a segment's groups in a 2-d tree: each node is the median of its range
/// in X or Y (across the range's longer side), with the bounding box and the number of live ends of its
/// range, so that searches skip whole regions, and regions whose groups are all cut.
pub(super) struct Tree {
    points: Vec<Point2<f64>>,
    /// End indices in tree order: the node of range `lo..hi` is at `(lo + hi) / 2`.
    order: Vec<usize>,
    /// Where each end is in `order`.
    slot: Vec<usize>,
    /// Per node: bounding box of its range (min x, min y, max x, max y).
    boxes: Vec<[f64; 4]>,
    /// Per node: live ends in its range.
    live: Vec<u32>,
    /// Per end: still live.
    is_live: Vec<bool>,
    /// Nodes looked at so far (the work the searches did).
    pub visited: u64,
}

/// Squared distance, computed as the rest of the pass computes it.
fn dist2(a: Point2<f64>, b: Point2<f64>) -> f64 {
    (a - b).norm_squared()
}

impl Tree {
    /// A tree over `points` (end `e` is `points[e]`), the ends `live` says live.
    pub fn new(points: Vec<Point2<f64>>, live: impl Fn(usize) -> bool) -> Tree {
        let m = points.len();
        let mut t = Tree {
            order: (0..m).collect(),
            slot: vec![0; m],
            boxes: vec![[0.0; 4]; m],
            live: vec![0; m],
            is_live: (0..m).map(live).collect(),
            points,
            visited: 0,
        };
        t.build(0, m);
        for (s, &e) in t.order.iter().enumerate() {
            t.slot[e] = s;
        }
        t
    }

    /// Builds the range `lo..hi`, split across its longer side (ends on one line, as
    /// the holes of a connector row, are split along it); fills the node's box and live
    /// count.
    fn build(&mut self, lo: usize, hi: usize) {
        if lo >= hi {
            return;
        }
        let mid = (lo + hi) / 2;
        let pts = &self.points;
        let mut bx = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for &e in &self.order[lo..hi] {
            let p = pts[e];
            bx = [
                bx[0].min(p.x),
                bx[1].min(p.y),
                bx[2].max(p.x),
                bx[3].max(p.y),
            ];
        }
        let axis = usize::from(bx[3] - bx[1] > bx[2] - bx[0]);
        self.order[lo..hi].select_nth_unstable_by(mid - lo, |&a, &b| {
            pts[a][axis].total_cmp(&pts[b][axis]).then(a.cmp(&b))
        });
        self.build(lo, mid);
        self.build(mid + 1, hi);
        let mut live = u32::from(self.is_live[self.order[mid]]);
        for child in [(lo, mid), (mid + 1, hi)] {
            if child.0 < child.1 {
                live += self.live[(child.0 + child.1) / 2];
            }
        }
        self.boxes[mid] = bx;
        self.live[mid] = live;
    }

    /// Squared distance from `p` to the box of node `node` (0 inside).
    fn box_dist2(&self, node: usize, p: Point2<f64>) -> f64 {
        let b = self.boxes[node];
        let dx = (b[0] - p.x).max(p.x - b[2]).max(0.0);
        let dy = (b[1] - p.y).max(p.y - b[3]).max(0.0);
        dx * dx + dy * dy
    }

    /// Takes end `e` out of the nearest-live search.
    pub fn remove(&mut self, e: usize) {
        if !std::mem::replace(&mut self.is_live[e], false) {
            return;
        }
        let target = self.slot[e];
        let (mut lo, mut hi) = (0, self.order.len());
        while lo < hi {
            let mid = (lo + hi) / 2;
            self.live[mid] -= 1;
            match target.cmp(&mid) {
                std::cmp::Ordering::Equal => break,
                std::cmp::Ordering::Less => hi = mid,
                std::cmp::Ordering::Greater => lo = mid + 1,
            }
        }
    }

    /// The `k` ends nearest to `p`, nearest first (ties by index), among those `skip`
    /// does not leave out; live or not.
    pub fn nearest_k(
        &mut self,
        p: Point2<f64>,
        k: usize,
        skip: impl Fn(usize) -> bool,
    ) -> Vec<usize> {
        let mut best: Vec<(f64, usize)> = Vec::with_capacity(k + 1);
        if k > 0 {
            self.search(0, self.order.len(), p, k, false, &skip, &mut best);
        }
        best.into_iter().map(|(_, e)| e).collect()
    }

    /// The live end nearest to `p` (ties by index), if any is left.
    pub fn nearest_live(&mut self, p: Point2<f64>) -> Option<usize> {
        let mut best = Vec::with_capacity(2);
        self.search(0, self.order.len(), p, 1, true, &|_| false, &mut best);
        best.first().map(|&(_, e)| e)
    }

    /// Searches node range `lo..hi` for the `k` best (distance, index) pairs in `best`
    /// (kept sorted); only live ends when `live_only`.
    #[allow(clippy::too_many_arguments)]
    fn search(
        &mut self,
        lo: usize,
        hi: usize,
        p: Point2<f64>,
        k: usize,
        live_only: bool,
        skip: &dyn Fn(usize) -> bool,
        best: &mut Vec<(f64, usize)>,
    ) {
        if lo >= hi {
            return;
        }
        let mid = (lo + hi) / 2;
        if live_only && self.live[mid] == 0 {
            return;
        }
        // A box as far as the k-th best can still hold an end of the same distance and
        // a smaller index: only a farther box is skipped.
        if best.len() == k && self.box_dist2(mid, p) > best[k - 1].0 {
            return;
        }
        self.visited += 1;
        let e = self.order[mid];
        if !skip(e) && (!live_only || self.is_live[e]) {
            let d = dist2(self.points[e], p);
            let cand = (d, e);
            if best.len() < k || cand < best[k - 1] {
                let at = best.partition_point(|&x| x < cand);
                best.insert(at, cand);
                best.truncate(k);
            }
        }
        // The side of the split `p` is on first.
        let left = (lo, mid);
        let right = (mid + 1, hi);
        let near_left = if left.0 < left.1 {
            self.box_dist2((left.0 + left.1) / 2, p)
                <= if right.0 < right.1 {
                    self.box_dist2((right.0 + right.1) / 2, p)
                } else {
                    f64::INFINITY
                }
        } else {
            false
        };
        let (a, b) = if near_left {
            (left, right)
        } else {
            (right, left)
        };
        self.search(a.0, a.1, p, k, live_only, skip, best);
        self.search(b.0, b.1, p, k, live_only, skip, best);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tree gives what a scan of all ends in index order gives, ties included.
    #[test]
    fn same_as_a_scan() {
        let mut pts = Vec::new();
        let mut s = 7u64;
        for i in 0..500 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            // Many equal coordinates: ties everywhere.
            let x = ((s >> 33) % 13) as f64;
            let y = if i % 3 == 0 {
                2.0
            } else {
                ((s >> 20) % 11) as f64
            };
            pts.push(Point2::new(x, y));
        }
        let mut t = Tree::new(pts.clone(), |e| e % 5 != 0);
        let scan = |p: Point2<f64>, k: usize, f: &dyn Fn(usize) -> bool| {
            let mut v: Vec<(f64, usize)> = (0..pts.len())
                .filter(|&e| f(e))
                .map(|e| (dist2(pts[e], p), e))
                .collect();
            v.sort_by(|a, b| a.partial_cmp(b).unwrap());
            v.into_iter().take(k).map(|x| x.1).collect::<Vec<_>>()
        };
        for (i, &p) in pts.iter().enumerate().step_by(7) {
            let got = t.nearest_k(p, 12, |e| e / 2 == i / 2);
            assert_eq!(got, scan(p, 12, &|e| e / 2 != i / 2));
        }
        let mut live: Vec<bool> = (0..pts.len()).map(|e| e % 5 != 0).collect();
        for i in 0..pts.len() {
            let p = pts[(i * 37) % pts.len()];
            let want = scan(p, 1, &|e| live[e]).first().copied();
            assert_eq!(t.nearest_live(p), want);
            if let Some(e) = want {
                t.remove(e);
                live[e] = false;
            }
        }
    }
}
