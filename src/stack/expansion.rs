//! α-expansion (Boykov, Veksler, Zabih) over windows of a label grid.
//!
//! A window is solved on its own with the pixels around it held fixed, so windows that do not
//! overlap can be solved in parallel from one snapshot of the labels.

use super::maxflow::GridMaxflow;

/// Energy terms of a 4-connected labelling problem, in integer units so each move is exact.
pub trait Costs: Sync {
    /// Cost of giving pixel `p` (index into the whole grid) label `l`.
    fn unary(&self, p: usize, l: u8) -> i32;
    /// Cost of neighbours `p`, `q` taking labels `lp`, `lq`. Must be a metric (zero when the labels
    /// are equal, symmetric, triangle inequality) for expansion moves to be optimal.
    fn pairwise(&self, p: usize, q: usize, lp: u8, lq: u8) -> i32;
}

/// Total energy of a labelling of a `width`×`height` grid.
pub fn energy(width: usize, height: usize, labels: &[u8], c: &impl Costs) -> i64 {
    let mut e = 0i64;
    for y in 0..height {
        for x in 0..width {
            let p = y * width + x;
            e += c.unary(p, labels[p]) as i64;
            if x + 1 < width {
                e += c.pairwise(p, p + 1, labels[p], labels[p + 1]) as i64;
            }
            if y + 1 < height {
                e += c.pairwise(p, p + width, labels[p], labels[p + width]) as i64;
            }
        }
    }
    e
}

/// A rectangle of the grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    pub x0: usize,
    pub y0: usize,
    pub w: usize,
    pub h: usize,
}

/// The grid being labelled: its size, the current labels and which pixels may change.
pub struct Grid<'a> {
    pub width: usize,
    pub height: usize,
    pub labels: &'a [u8],
    /// `None`: every pixel may change.
    pub free: Option<&'a [bool]>,
}

impl Grid<'_> {
    fn is_free(&self, p: usize) -> bool {
        self.free.is_none_or(|f| f[p])
    }
}

/// Adds `cost1 - cost0` for "takes α" as terminal capacities (a constant is dropped).
#[inline]
fn add_unary(g: &mut GridMaxflow, i: usize, cost0: i32, cost1: i32) {
    let d = cost1 - cost0;
    if d > 0 {
        g.add_tweights(i, d, 0);
    } else {
        g.add_tweights(i, 0, -d);
    }
}

/// Runs expansion cycles over `candidates` inside `win` until a cycle changes nothing or
/// `max_cycles` is reached; returns the window's new labels (row-major, `win.w`×`win.h`).
pub fn expand_window(
    grid: &Grid,
    win: Window,
    candidates: &[u8],
    costs: &impl Costs,
    max_cycles: usize,
    solver: &mut GridMaxflow,
) -> Vec<u8> {
    let gw = grid.width;
    let mut cur: Vec<u8> = (0..win.h)
        .flat_map(|y| {
            let s = (win.y0 + y) * gw + win.x0;
            grid.labels[s..s + win.w].iter().copied()
        })
        .collect();
    let free: Vec<bool> = (0..win.w * win.h)
        .map(|i| grid.is_free((win.y0 + i / win.w) * gw + win.x0 + i % win.w))
        .collect();
    // Sparse windows (a band around seams) visit only their free pixels.
    let free_idx: Vec<u32> = (0..free.len() as u32)
        .filter(|&i| free[i as usize])
        .collect();
    for _ in 0..max_cycles {
        let mut changed = false;
        for &alpha in candidates {
            let m = Move {
                grid,
                win,
                free: &free,
                free_idx: &free_idx,
                alpha,
            };
            changed |= m.run(&mut cur, costs, solver);
        }
        if !changed {
            break;
        }
    }
    cur
}

/// One α-expansion move: every free pixel either keeps its label or takes `alpha`, whichever
/// minimises the energy (exactly, by a minimum cut).
struct Move<'a> {
    grid: &'a Grid<'a>,
    win: Window,
    free: &'a [bool],
    free_idx: &'a [u32],
    alpha: u8,
}

impl Move<'_> {
    /// Returns whether any label changed.
    fn run(&self, cur: &mut [u8], costs: &impl Costs, g: &mut GridMaxflow) -> bool {
        let (win, alpha) = (self.win, self.alpha);
        let (gw, gh) = (self.grid.width, self.grid.height);
        let var = |i: usize, cur: &[u8]| self.free[i] && cur[i] != alpha;
        if !self.free_idx.iter().any(|&i| cur[i as usize] != alpha) {
            return false;
        }
        g.reset(win.w, win.h);
        for &i in self.free_idx {
            let i = i as usize;
            let lp = cur[i];
            if lp == alpha {
                continue;
            }
            let (lx, ly) = (i % win.w, i / win.w);
            let (x, y) = (win.x0 + lx, win.y0 + ly);
            let p = y * gw + x;
            add_unary(g, i, costs.unary(p, lp), costs.unary(p, alpha));
            // (neighbour exists, global q, local index if inside the window, right/down edge)
            let nbrs = [
                (
                    x + 1 < gw,
                    p + 1,
                    (lx + 1 < win.w).then(|| i + 1),
                    Some(true),
                ),
                (
                    y + 1 < gh,
                    p + gw,
                    (ly + 1 < win.h).then(|| i + win.w),
                    Some(false),
                ),
                (
                    x > 0,
                    p.wrapping_sub(1),
                    (lx > 0).then(|| i.wrapping_sub(1)),
                    None,
                ),
                (
                    y > 0,
                    p.wrapping_sub(gw),
                    (ly > 0).then(|| i.wrapping_sub(win.w)),
                    None,
                ),
            ];
            for (exists, q, j, forward) in nbrs {
                if !exists {
                    continue;
                }
                let lq = j.map_or(self.grid.labels[q], |j| cur[j]);
                match j.filter(|&j| var(j, cur)) {
                    // Both free: the edge is added once, from its left/top end.
                    Some(j) => {
                        if let Some(right) = forward {
                            // E(xp, xq) = A + (C-A)xp + (D-C)xq + (B+C-A-D)(1-xp)xq, D = 0.
                            let a = costs.pairwise(p, q, lp, lq);
                            let b = costs.pairwise(p, q, lp, alpha);
                            let c = costs.pairwise(p, q, alpha, lq);
                            add_unary(g, i, 0, c - a);
                            add_unary(g, j, 0, -c);
                            let cap = (b + c - a).max(0);
                            if right {
                                g.add_right(i, cap, 0);
                            } else {
                                g.add_down(i, cap, 0);
                            }
                        }
                    }
                    None => add_unary(
                        g,
                        i,
                        costs.pairwise(p, q, lp, lq),
                        costs.pairwise(p, q, alpha, lq),
                    ),
                }
            }
        }
        g.maxflow();
        let mut changed = false;
        for &i in self.free_idx {
            let i = i as usize;
            if cur[i] != alpha && g.in_sink(i) {
                cur[i] = alpha;
                changed = true;
            }
        }
        changed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }
        fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }
    }

    /// Random unaries; truncated-linear plus Potts pairwise weighted per edge (a metric).
    struct RandomCosts {
        width: usize,
        unary: Vec<Vec<i32>>,
        weight: Vec<i32>,
    }
    impl Costs for RandomCosts {
        fn unary(&self, p: usize, l: u8) -> i32 {
            self.unary[p][l as usize]
        }
        fn pairwise(&self, p: usize, q: usize, lp: u8, lq: u8) -> i32 {
            let _ = self.width;
            let w = self.weight[p.min(q)];
            if lp == lq {
                0
            } else {
                w * (3 + (lp as i32 - lq as i32).abs().min(4))
            }
        }
    }

    fn random_problem(rng: &mut Rng, w: usize, h: usize, n: usize) -> RandomCosts {
        RandomCosts {
            width: w,
            unary: (0..w * h)
                .map(|_| (0..n).map(|_| rng.below(100) as i32).collect())
                .collect(),
            weight: (0..w * h).map(|_| rng.below(12) as i32).collect(),
        }
    }

    #[test]
    fn moves_never_raise_energy_and_beat_brute_force_bound() {
        let mut rng = Rng(0x9e3779b97f4a7c15);
        let mut solver = GridMaxflow::new();
        for trial in 0..60 {
            let (w, h, n) = (
                1 + rng.below(4) as usize,
                1 + rng.below(3) as usize,
                2 + rng.below(3) as usize,
            );
            let c = random_problem(&mut rng, w, h, n);
            let mut labels: Vec<u8> = (0..w * h).map(|_| rng.below(n as u64) as u8).collect();
            let win = Window { x0: 0, y0: 0, w, h };
            let cands: Vec<u8> = (0..n as u8).collect();
            let mut e = energy(w, h, &labels, &c);
            for _ in 0..3 {
                for &a in &cands {
                    let grid = Grid {
                        width: w,
                        height: h,
                        labels: &labels,
                        free: None,
                    };
                    let next = expand_window(&grid, win, &[a], &c, 1, &mut solver);
                    let e2 = energy(w, h, &next, &c);
                    assert!(e2 <= e, "trial {trial}: move on {a} raised {e} to {e2}");
                    // The move is optimal: no labelling reachable by one α-move is cheaper.
                    let free: Vec<usize> = (0..w * h).filter(|&i| labels[i] != a).collect();
                    for mask in 0..1u32 << free.len() {
                        let mut t = labels.clone();
                        for (k, &i) in free.iter().enumerate() {
                            if mask >> k & 1 == 1 {
                                t[i] = a;
                            }
                        }
                        assert!(
                            energy(w, h, &t, &c) >= e2,
                            "trial {trial}: move not optimal"
                        );
                    }
                    labels = next;
                    e = e2;
                }
            }
            // Expansion's local minimum is within 2·max/min pairwise ratio of the optimum, and never
            // worse than the best constant labelling.
            let best_const = (0..n as u8)
                .map(|l| energy(w, h, &vec![l; w * h], &c))
                .min()
                .unwrap();
            assert!(e <= best_const);
        }
    }

    #[test]
    fn fixed_pixels_and_windows_keep_outside_labels() {
        let mut rng = Rng(77);
        let (w, h, n) = (9, 7, 4);
        let c = random_problem(&mut rng, w, h, n);
        let labels: Vec<u8> = (0..w * h).map(|_| rng.below(n as u64) as u8).collect();
        let free: Vec<bool> = (0..w * h).map(|i| i % 3 != 0).collect();
        let win = Window {
            x0: 2,
            y0: 1,
            w: 5,
            h: 4,
        };
        let grid = Grid {
            width: w,
            height: h,
            labels: &labels,
            free: Some(&free),
        };
        let cands: Vec<u8> = (0..n as u8).collect();
        let out = expand_window(&grid, win, &cands, &c, 5, &mut GridMaxflow::new());
        let mut merged = labels.clone();
        for y in 0..win.h {
            for x in 0..win.w {
                let p = (win.y0 + y) * w + win.x0 + x;
                if !free[p] {
                    assert_eq!(out[y * win.w + x], labels[p]);
                }
                merged[p] = out[y * win.w + x];
            }
        }
        assert!(energy(w, h, &merged, &c) <= energy(w, h, &labels, &c));
    }
}
