//! The ordering problem of one segment and its solver: nearest neighbour, then 2-opt
//! and or-opt improvement.

use nalgebra::Point2;

use super::{EPS, Options};

/// The ordering problem of one segment: groups as (start, end) pairs, a fixed origin
/// and an optional fixed finish.
pub(super) struct Problem {
    pub starts: Vec<Point2<f64>>,
    pub ends: Vec<Point2<f64>>,
    /// The group may be entered at its end (reversible, or closed).
    pub flippable: Vec<bool>,
    pub origin: Point2<f64>,
    pub finish: Option<Point2<f64>>,
}

/// A visiting order: group index and whether it is entered at its end.
pub(super) type Order = Vec<(usize, bool)>;

impl Problem {
    fn entry(&self, (g, r): (usize, bool)) -> Point2<f64> {
        if r { self.ends[g] } else { self.starts[g] }
    }
    fn exit(&self, (g, r): (usize, bool)) -> Point2<f64> {
        if r { self.starts[g] } else { self.ends[g] }
    }
    /// Endpoint `e` (2g = start, 2g+1 = end).
    fn point(&self, e: usize) -> Point2<f64> {
        if e.is_multiple_of(2) {
            self.starts[e / 2]
        } else {
            self.ends[e / 2]
        }
    }

    /// The XY travel of `order`: origin to the first group, between groups, the last
    /// group to the finish.
    pub fn cost(&self, order: &Order) -> f64 {
        let mut at = self.origin;
        let mut sum = 0.0;
        for &v in order {
            sum += (self.entry(v) - at).norm();
            at = self.exit(v);
        }
        if let Some(f) = self.finish {
            sum += (f - at).norm();
        }
        sum
    }

    /// Nearest neighbour, then bounded 2-opt / Or-opt.
    pub fn solve(&self, opt: &Options) -> Order {
        let n = self.starts.len();
        if n == 0 {
            return Vec::new();
        }
        let k = (opt.neighbours as usize).clamp(1, 2 * n);
        let near = self.neighbours(k);
        let mut order = self.nearest_neighbour(&near);
        if opt.two_opt && n > 1 {
            Improver::new(self, &near, &mut order).run(opt.max_sweeps);
        }
        order
    }

    /// For every endpoint, the `k` nearest endpoints of other groups, nearest first
    /// (ties by index), found by scanning outwards in X order.
    fn neighbours(&self, k: usize) -> Vec<Vec<usize>> {
        let m = 2 * self.starts.len();
        let mut by_x: Vec<usize> = (0..m).collect();
        by_x.sort_by(|&a, &b| {
            let (pa, pb) = (self.point(a), self.point(b));
            pa.x.total_cmp(&pb.x)
                .then(pa.y.total_cmp(&pb.y))
                .then(a.cmp(&b))
        });
        let mut rank = vec![0; m];
        for (r, &e) in by_x.iter().enumerate() {
            rank[e] = r;
        }
        let mut lists = Vec::with_capacity(m);
        for (e, &r) in rank.iter().enumerate() {
            let p = self.point(e);
            let mut best: Vec<(f64, usize)> = Vec::with_capacity(k + 1);
            let consider = |c: usize, best: &mut Vec<(f64, usize)>| {
                if c / 2 == e / 2 {
                    return;
                }
                let d = (self.point(c) - p).norm_squared();
                if best.len() == k && (d, c) >= best[k - 1] {
                    return;
                }
                let at = best.partition_point(|&x| x < (d, c));
                best.insert(at, (d, c));
                best.truncate(k);
            };
            // Leftwards and rightwards while the X gap can still beat the k-th best.
            for &c in by_x[..r].iter().rev() {
                let dx = p.x - self.point(c).x;
                if best.len() == k && dx * dx > best[k - 1].0 {
                    break;
                }
                consider(c, &mut best);
            }
            for &c in &by_x[r + 1..] {
                let dx = self.point(c).x - p.x;
                if best.len() == k && dx * dx > best[k - 1].0 {
                    break;
                }
                consider(c, &mut best);
            }
            lists.push(best.into_iter().map(|(_, c)| c).collect());
        }
        lists
    }

    /// Greedy: from the origin, always the nearest group not yet cut (either end when it
    /// may be entered there). Exact: the neighbour list, else a scan of all groups.
    fn nearest_neighbour(&self, near: &[Vec<usize>]) -> Order {
        let n = self.starts.len();
        let mut done = vec![false; n];
        let mut order = Vec::with_capacity(n);
        let mut at = self.origin;
        let mut from: Option<usize> = None;
        let usable = |e: usize, done: &[bool]| {
            !done[e / 2] && (e.is_multiple_of(2) || self.flippable[e / 2])
        };
        // Every group is taken, including the last one of the list (seed bug 1).
        for _ in 0..n {
            let listed = from.and_then(|e| near[e].iter().copied().find(|&c| usable(c, &done)));
            let pick = match listed {
                Some(c) => c,
                None => {
                    let mut best: Option<(f64, usize)> = None;
                    for c in 0..2 * n {
                        if !usable(c, &done) {
                            continue;
                        }
                        let d = (self.point(c) - at).norm_squared();
                        if best.is_none_or(|b| (d, c) < b) {
                            best = Some((d, c));
                        }
                    }
                    match best {
                        Some((_, c)) => c,
                        None => break,
                    }
                }
            };
            let v = (pick / 2, pick % 2 == 1);
            done[v.0] = true;
            order.push(v);
            at = self.exit(v);
            // The exit endpoint's index.
            from = Some(2 * v.0 + usize::from(!v.1));
        }
        order
    }
}

/// 2-opt and Or-opt over neighbour lists, first improvement, bounded sweeps.
struct Improver<'a> {
    p: &'a Problem,
    near: &'a [Vec<usize>],
    order: &'a mut Order,
    /// Position of each group in `order`.
    pos: Vec<usize>,
    /// `fixed[i]`: number of groups that cannot be flipped in `order[..i]`.
    fixed: Vec<usize>,
}

impl<'a> Improver<'a> {
    fn new(p: &'a Problem, near: &'a [Vec<usize>], order: &'a mut Order) -> Self {
        let mut s = Improver {
            p,
            near,
            order,
            pos: Vec::new(),
            fixed: Vec::new(),
        };
        s.reindex();
        s
    }

    fn reindex(&mut self) {
        let n = self.order.len();
        self.pos = vec![0; n];
        self.fixed = Vec::with_capacity(n + 1);
        self.fixed.push(0);
        for (i, &(g, _)) in self.order.iter().enumerate() {
            self.pos[g] = i;
            let last = self.fixed[i];
            self.fixed.push(last + usize::from(!self.p.flippable[g]));
        }
    }

    fn prev_exit(&self, i: usize) -> Point2<f64> {
        if i == 0 {
            self.p.origin
        } else {
            self.p.exit(self.order[i - 1])
        }
    }
    fn next_entry(&self, i: usize) -> Option<Point2<f64>> {
        if i + 1 < self.order.len() {
            Some(self.p.entry(self.order[i + 1]))
        } else {
            self.p.finish
        }
    }

    fn run(&mut self, max_sweeps: u32) {
        for _ in 0..max_sweeps {
            let a = self.two_opt_sweep();
            let b = self.or_opt_sweep();
            if !a && !b {
                break;
            }
        }
    }

    fn two_opt_sweep(&mut self) -> bool {
        let n = self.order.len();
        let mut improved = false;
        for i in 0..n {
            let cands: Vec<usize> = if i == 0 {
                (0..n).collect()
            } else {
                let (g, r) = self.order[i - 1];
                let exit_e = 2 * g + usize::from(!r);
                self.near[exit_e].iter().map(|&e| e / 2).collect()
            };
            for h in cands {
                let j = self.pos[h];
                if j < i || self.fixed[j + 1] != self.fixed[i] {
                    continue;
                }
                let pe = self.prev_exit(i);
                let ei = self.p.entry(self.order[i]);
                let xj = self.p.exit(self.order[j]);
                let delta = match self.next_entry(j) {
                    Some(nx) => {
                        (pe - xj).norm() + (ei - nx).norm() - (pe - ei).norm() - (xj - nx).norm()
                    }
                    None => (pe - xj).norm() - (pe - ei).norm(),
                };
                if delta < -EPS {
                    self.order[i..=j].reverse();
                    for v in &mut self.order[i..=j] {
                        v.1 = !v.1;
                    }
                    self.reindex();
                    improved = true;
                }
            }
        }
        improved
    }

    fn or_opt_sweep(&mut self) -> bool {
        let n = self.order.len();
        let mut improved = false;
        for g in 0..n {
            let k = self.pos[g];
            let cur = self.order[k];
            let a = self.prev_exit(k);
            let b = self.next_entry(k);
            let d = |x: Point2<f64>, y: Option<Point2<f64>>| y.map_or(0.0, |y| (x - y).norm());
            let removal = (self.p.entry(cur) - a).norm() + d(self.p.exit(cur), b) - d(a, b);
            let orients: &[bool] = if self.p.flippable[g] {
                &[false, true]
            } else {
                &[cur.1]
            };
            let mut best: Option<(f64, usize, bool)> = None;
            let mut cands: Vec<usize> = self.near[2 * g]
                .iter()
                .chain(&self.near[2 * g + 1])
                .map(|&e| e / 2)
                .collect();
            cands.sort_unstable();
            cands.dedup();
            for h in cands {
                let m = self.pos[h];
                // Insert after h (between h and what follows it once g is out), or before.
                for after in [true, false] {
                    let (x, y) = if after {
                        let y = if m + 1 == k { b } else { self.next_entry(m) };
                        (self.p.exit(self.order[m]), y)
                    } else {
                        let x = if m == k + 1 { a } else { self.prev_exit(m) };
                        (x, Some(self.p.entry(self.order[m])))
                    };
                    for &r in orients {
                        let v = (g, r);
                        let insert = (self.p.entry(v) - x).norm() + d(self.p.exit(v), y) - d(x, y);
                        let delta = insert - removal;
                        if delta < -EPS && best.is_none_or(|bb| delta < bb.0) {
                            // Index in the order without g.
                            let at = if after { m + 1 } else { m };
                            let at = if m > k { at - 1 } else { at };
                            best = Some((delta, at, r));
                        }
                    }
                }
            }
            if let Some((_, at, r)) = best {
                self.order.remove(k);
                self.order.insert(at, (g, r));
                self.reindex();
                improved = true;
            }
        }
        improved
    }
}
