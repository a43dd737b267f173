//! α-expansion (Boykov, Veksler, Zabih) over a label grid with some pixels held fixed.
//!
//! Callers solve a window as its own small grid with a ring of fixed pixels around it, so windows
//! that do not overlap can be solved in parallel from one snapshot of the labels.

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

/// The grid being labelled: its size, the current labels and which pixels may change.
pub struct Grid<'a> {
    pub width: usize,
    pub height: usize,
    pub labels: &'a [u8],
    /// `None`: every pixel may change.
    pub free: Option<&'a [bool]>,
}

/// The 4-connected neighbours of pixel `p` of a `w`×`h` grid.
pub fn neighbours(w: usize, h: usize, p: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (p % w, p / w);
    [
        (x + 1 < w).then(|| p + 1),
        (y + 1 < h).then(|| p + w),
        (x > 0).then(|| p - 1),
        (y > 0).then(|| p - w),
    ]
    .into_iter()
    .flatten()
}

/// An expansion move to try: a label and the free pixels allowed to take it.
pub struct Move {
    pub label: u8,
    pub pixels: Vec<u32>,
}

/// Runs cycles of `moves` until a cycle changes nothing or `max_cycles` is reached; returns the
/// new labels. Pixels that are not free keep their labels and act as fixed boundary conditions
/// for their free neighbours.
///
/// A pixel that takes a move's label lets its free neighbours take that label too, so a seam can
/// move wherever the label spreads, not only over the pixels first allowed. A move is skipped when
/// none of its pixels nor their neighbours changed since it last changed nothing: its graph would
/// be the same, and so would its answer.
pub fn expand(
    grid: &Grid,
    mut moves: Vec<Move>,
    costs: &impl Costs,
    max_cycles: usize,
    solver: &mut GridMaxflow,
) -> Vec<u8> {
    let (w, h) = (grid.width, grid.height);
    let n = w * h;
    let mut cur = grid.labels.to_vec();
    let free = |p: usize| grid.free.is_none_or(|f| f[p]);
    // allowed[k * n + p]: pixel p may take move k's label.
    let mut allowed = vec![false; moves.len() * n];
    for (k, m) in moves.iter().enumerate() {
        for &p in &m.pixels {
            debug_assert!(free(p as usize), "pixel {p} is fixed");
            allowed[k * n + p as usize] = true;
        }
    }
    // Move counts: when each pixel last changed, when each move last changed nothing (0: never).
    let mut step = 0u32;
    let mut changed_at = vec![0u32; n];
    let mut failed_at = vec![0u32; moves.len()];
    let neighbours = |p: usize| neighbours(w, h, p);
    let mut terminal = vec![0i64; n];
    for _ in 0..max_cycles {
        let mut cycle_changed = false;
        for (k, m) in moves.iter_mut().enumerate() {
            let since = failed_at[k];
            let unchanged = |p: usize| changed_at[p] < since;
            if since > 0
                && m.pixels.iter().all(|&p| {
                    let p = p as usize;
                    unchanged(p) && neighbours(p).all(unchanged)
                })
            {
                continue;
            }
            step += 1;
            let allowed = &mut allowed[k * n..(k + 1) * n];
            let taken = run_move(grid, m, allowed, &mut cur, &mut terminal, costs, solver);
            if taken.is_empty() {
                failed_at[k] = step;
                continue;
            }
            cycle_changed = true;
            for p in taken {
                changed_at[p as usize] = step;
                for q in neighbours(p as usize) {
                    if free(q) && !allowed[q] {
                        allowed[q] = true;
                        m.pixels.push(q as u32);
                    }
                }
            }
        }
        if !cycle_changed {
            break;
        }
    }
    cur
}

/// One α-expansion move: every pixel of `m` either keeps its label or takes `m.label`,
/// whichever minimises the energy (exactly, by a minimum cut). Returns the pixels that took it.
///
/// Each pixel's terminal capacity is summed in `terminal` (all zero, and left so) and given to
/// the graph once: a pixel collects up to six terms, and adding each to the graph as it came
/// was a twentieth of the whole fuse's instructions on a flats stack. The graph is the same, so
/// is its cut.
fn run_move(
    grid: &Grid,
    m: &Move,
    allowed: &[bool],
    cur: &mut [u8],
    terminal: &mut [i64],
    costs: &impl Costs,
    g: &mut GridMaxflow,
) -> Vec<u32> {
    let alpha = m.label;
    let (w, h) = (grid.width, grid.height);
    let var = |i: usize, cur: &[u8]| allowed[i] && cur[i] != alpha;
    if !m.pixels.iter().any(|&i| cur[i as usize] != alpha) {
        return Vec::new();
    }
    g.reset(w, h);
    // Terms of "p takes α" (a constant is dropped).
    let mut add = |p: usize, cost0: i32, cost1: i32| terminal[p] += i64::from(cost1 - cost0);
    for &p in &m.pixels {
        let p = p as usize;
        let lp = cur[p];
        if lp == alpha {
            continue;
        }
        let (x, y) = (p % w, p / w);
        add(p, costs.unary(p, lp), costs.unary(p, alpha));
        // (neighbour exists, q, right/down edge)
        let nbrs = [
            (x + 1 < w, p + 1, Some(true)),
            (y + 1 < h, p + w, Some(false)),
            (x > 0, p.wrapping_sub(1), None),
            (y > 0, p.wrapping_sub(w), None),
        ];
        for (exists, q, forward) in nbrs {
            if !exists {
                continue;
            }
            let lq = cur[q];
            if var(q, cur) {
                // Both variable: the edge is added once, from its left/top end.
                if let Some(right) = forward {
                    // E(xp, xq) = A + (C-A)xp + (D-C)xq + (B+C-A-D)(1-xp)xq, D = 0. Where both
                    // hold one label (most edges), A = 0 and C = B by symmetry.
                    let b = costs.pairwise(p, q, lp, alpha);
                    let (a, c) = if lp == lq {
                        (0, b)
                    } else {
                        (
                            costs.pairwise(p, q, lp, lq),
                            costs.pairwise(p, q, alpha, lq),
                        )
                    };
                    add(p, 0, c - a);
                    add(q, 0, -c);
                    let cap = (b + c - a).max(0);
                    if right {
                        g.add_right(p, cap, 0);
                    } else {
                        g.add_down(p, cap, 0);
                    }
                }
            } else {
                add(
                    p,
                    costs.pairwise(p, q, lp, lq),
                    costs.pairwise(p, q, alpha, lq),
                );
            }
        }
    }
    for &p in &m.pixels {
        let t = std::mem::take(&mut terminal[p as usize]);
        if t != 0 {
            let t = i32::try_from(t).expect("terminal capacity overflows i32");
            g.add_tweights(p as usize, t.max(0), (-t).max(0));
        }
    }
    g.maxflow();
    let mut taken = Vec::new();
    for &p in &m.pixels {
        if cur[p as usize] != alpha && g.in_sink(p as usize) {
            cur[p as usize] = alpha;
            taken.push(p);
        }
    }
    taken
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

    /// Moves that let every free pixel take every label of `labels`.
    fn every_pixel(grid: &Grid, labels: &[u8]) -> Vec<Move> {
        let free: Vec<u32> = (0..(grid.width * grid.height) as u32)
            .filter(|&p| grid.free.is_none_or(|f| f[p as usize]))
            .collect();
        labels
            .iter()
            .map(|&label| Move {
                label,
                pixels: free.clone(),
            })
            .collect()
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
                    let next = expand(&grid, every_pixel(&grid, &[a]), &c, 1, &mut solver);
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
    fn fixed_pixels_keep_their_labels() {
        let mut rng = Rng(77);
        let (w, h, n) = (9, 7, 4);
        let c = random_problem(&mut rng, w, h, n);
        let labels: Vec<u8> = (0..w * h).map(|_| rng.below(n as u64) as u8).collect();
        let free: Vec<bool> = (0..w * h).map(|i| i % 3 != 0).collect();
        let grid = Grid {
            width: w,
            height: h,
            labels: &labels,
            free: Some(&free),
        };
        let cands: Vec<u8> = (0..n as u8).collect();
        let out = expand(
            &grid,
            every_pixel(&grid, &cands),
            &c,
            5,
            &mut GridMaxflow::new(),
        );
        for p in 0..w * h {
            if !free[p] {
                assert_eq!(out[p], labels[p]);
            }
        }
        assert_ne!(
            out, labels,
            "some free pixel should move on a random problem"
        );
        assert!(energy(w, h, &out, &c) < energy(w, h, &labels, &c));
    }

    /// Skipped moves are the ones that would change nothing: after enough cycles no move over
    /// every pixel lowers the energy any more.
    #[test]
    fn skipping_moves_still_reaches_a_local_minimum() {
        let mut rng = Rng(31337);
        let mut solver = GridMaxflow::new();
        for _ in 0..10 {
            let (w, h, n) = (12, 10, 5);
            let c = random_problem(&mut rng, w, h, n);
            let labels: Vec<u8> = (0..w * h).map(|_| rng.below(n as u64) as u8).collect();
            let grid = Grid {
                width: w,
                height: h,
                labels: &labels,
                free: None,
            };
            let cands: Vec<u8> = (0..n as u8).collect();
            let out = expand(&grid, every_pixel(&grid, &cands), &c, 100, &mut solver);
            let e = energy(w, h, &out, &c);
            assert!(e < energy(w, h, &labels, &c));
            for &a in &cands {
                let done = Grid {
                    labels: &out,
                    ..grid
                };
                let again = expand(&done, every_pixel(&done, &[a]), &c, 1, &mut solver);
                assert_eq!(again, out, "a move on {a} still changes the labels");
            }
        }
    }

    /// A label offered to a few pixels reaches others only by spreading from them: every pixel
    /// that takes it is joined to an offered pixel through pixels that took it.
    #[test]
    fn a_label_spreads_only_from_the_pixels_offered_it() {
        let mut rng = Rng(2024);
        let mut spread = false;
        for _ in 0..20 {
            let (w, h, n) = (10, 8, 4);
            let mut c = random_problem(&mut rng, w, h, n);
            // Label 3 is cheap everywhere, so it would win every pixel if offered everywhere.
            for u in &mut c.unary {
                u[3] = 0;
            }
            let labels: Vec<u8> = (0..w * h).map(|_| rng.below(3) as u8).collect();
            let grid = Grid {
                width: w,
                height: h,
                labels: &labels,
                free: None,
            };
            let offered: Vec<u32> = vec![(w * (h / 2) + w / 2) as u32];
            let moves = vec![Move {
                label: 3,
                pixels: offered.clone(),
            }];
            let out = expand(&grid, moves, &c, 5, &mut GridMaxflow::new());
            // Flood from the offered pixels through pixels labelled 3.
            let mut reached = vec![false; w * h];
            let mut stack: Vec<usize> = offered
                .iter()
                .map(|&p| p as usize)
                .filter(|&p| out[p] == 3)
                .collect();
            while let Some(p) = stack.pop() {
                if std::mem::replace(&mut reached[p], true) {
                    continue;
                }
                stack.extend(neighbours(w, h, p).filter(|&q| out[q] == 3));
            }
            for p in 0..w * h {
                assert!(out[p] != 3 || reached[p], "pixel {p} took 3 unconnected");
            }
            spread |= out.iter().filter(|&&l| l == 3).count() > 1;
        }
        assert!(
            spread,
            "the cheap label never spread past the pixel offered it"
        );
    }
}
