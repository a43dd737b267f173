//! Boykov–Kolmogorov max-flow specialised for 4-connected grids.
//!
//! Graph-cut fusion solves one grid max-flow per alpha-expansion move, so this is the inner loop of
//! the labelling. A general adjacency-list graph spends most of its time chasing arc pointers; on a
//! grid the neighbours are implicit (±1, ±width), so each node is a single 32-byte record holding
//! its four residual arc capacities together with all search state. The algorithm itself follows
//! Kolmogorov's maxflow-v3: two search trees grown breadth-first from a FIFO of active nodes,
//! augmentation along the path found, then orphan adoption with the timestamp/distance heuristic.
//! Everything is iterative, so arbitrarily long tree paths cannot overflow the stack.
//!
//! An expansion move often gives capacity to a small part of the grid (the pixels that may take
//! its label), so the solver keeps a list of the nodes given capacity since the last reset and
//! initialises, searches and clears only those: a move costs what it touches, not the grid.

use std::collections::VecDeque;

// Arc directions; `d ^ 1` is the opposite direction, so the reverse of node p's arc `d` is the
// neighbour's arc `d ^ 1`.
const RIGHT: u8 = 0;
const LEFT: u8 = 1;
const DOWN: u8 = 2;
const UP: u8 = 3;
/// Parent code of a tree root: the node hangs directly off its terminal.
const TERMINAL: u8 = 4;
/// Parent code of a node whose tree arc was just saturated and that awaits adoption.
const ORPHAN: u8 = 5;

/// Bit of `Node::nbrs` (above the four direction bits) set once the node is in `touched`.
const TOUCHED: u8 = 1 << 4;

const FREE: u8 = 0;
const SOURCE: u8 = 1;
const SINK: u8 = 2;

/// One grid node. Kept to 32 bytes and aligned so a node never straddles a cache line: tree
/// growth and adoption touch every field of each neighbour they visit.
#[derive(Clone, Copy, Default)]
#[repr(C, align(32))]
struct Node {
    /// Residual capacity of the arc to the neighbour in each direction; always 0 towards a
    /// missing neighbour, which lets the source-tree growth skip the bounds test.
    cap: [i32; 4],
    /// Net terminal residual: positive is capacity from the source, negative to the sink. A single
    /// value suffices because flow through both terminals at once is settled up front.
    tr: i32,
    /// Time at which `dist` was last verified to be this node's distance to its terminal.
    ts: u32,
    dist: u32,
    /// Direction of the tree parent, `TERMINAL` or `ORPHAN`; stale while the node is free.
    parent: u8,
    tree: u8,
    /// Bit `d` is set when the neighbour in direction `d` exists; `TOUCHED` when the node has
    /// been given capacity since the last reset.
    nbrs: u8,
    /// In the active queue (or being processed), so it must not be queued again.
    active: bool,
}

/// Boykov–Kolmogorov max-flow on a 4-connected `width`×`height` grid; node index = y * width + x.
#[derive(Default)]
pub struct GridMaxflow {
    width: usize,
    height: usize,
    nodes: Vec<Node>,
    /// Index offset to the neighbour in each direction; negative ones wrap, use `wrapping_add`.
    step: [usize; 4],
    flow: i64,
    time: u32,
    active: VecDeque<u32>,
    orphans: Vec<u32>,
    /// Nodes given capacity since the last reset, in first-touch order; every other node has
    /// no capacity, is free and is never reached by the search.
    touched: Vec<u32>,
}

impl GridMaxflow {
    pub fn new() -> Self {
        Self::default()
    }

    /// Clears and sizes for a width×height grid with every capacity zero; keeps allocations for
    /// reuse. On a grid of the same size only the nodes touched since the last reset are cleared.
    pub fn reset(&mut self, width: usize, height: usize) {
        let n = width
            .checked_mul(height)
            .expect("grid size overflows usize");
        // Node ids are stored as u32 in the queues and distances are u32.
        assert!(
            n < u32::MAX as usize,
            "grid of {width}x{height} is too large"
        );
        self.flow = 0;
        self.time = 0;
        self.active.clear();
        self.orphans.clear();
        if (width, height) == (self.width, self.height) && self.nodes.len() == n {
            for &i in &self.touched {
                let node = &mut self.nodes[i as usize];
                *node = Node {
                    nbrs: node.nbrs & !TOUCHED,
                    ..Node::default()
                };
            }
            self.touched.clear();
            return;
        }
        self.width = width;
        self.height = height;
        self.step = [1, 1usize.wrapping_neg(), width, width.wrapping_neg()];
        self.touched.clear();
        self.nodes.clear();
        self.nodes.reserve(n);
        for y in 0..height {
            let mut vertical = 0;
            if y + 1 < height {
                vertical |= 1 << DOWN;
            }
            if y > 0 {
                vertical |= 1 << UP;
            }
            for x in 0..width {
                let mut nbrs = vertical;
                if x + 1 < width {
                    nbrs |= 1 << RIGHT;
                }
                if x > 0 {
                    nbrs |= 1 << LEFT;
                }
                self.nodes.push(Node {
                    nbrs,
                    ..Node::default()
                });
            }
        }
    }

    /// Records that `node` has capacity, so the search and the next reset visit it.
    #[inline]
    fn touch(&mut self, node: usize) {
        let n = &mut self.nodes[node];
        if n.nbrs & TOUCHED == 0 {
            n.nbrs |= TOUCHED;
            self.touched.push(node as u32);
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Adds terminal capacities: `source` is paid when the node ends on the sink side of the cut,
    /// `sink` when it ends on the source side. Both >= 0. May be called several times per node
    /// (accumulates).
    pub fn add_tweights(&mut self, node: usize, source: i32, sink: i32) {
        assert!(source >= 0 && sink >= 0, "negative terminal capacity");
        self.touch(node);
        let node = &mut self.nodes[node];
        let delta = i64::from(node.tr);
        let source = i64::from(source) + delta.max(0);
        let sink = i64::from(sink) + (-delta).max(0);
        // Whichever side the node ends on, min(source, sink) is paid: it is flow that goes straight
        // source -> node -> sink and never has to be searched for.
        self.flow += source.min(sink);
        node.tr = i32::try_from(source - sink).expect("terminal capacity overflows i32");
    }

    /// Adds capacity to the edge between `node` (x,y) and its right neighbour (x+1,y): `fwd` is
    /// node→right (paid when node is on the source side and right on the sink side), `rev` is
    /// right→node. Both >= 0. Accumulates.
    pub fn add_right(&mut self, node: usize, fwd: i32, rev: i32) {
        self.add_edge(node, RIGHT, fwd, rev);
    }

    /// Same as [`Self::add_right`] for the down neighbour (x, y+1).
    pub fn add_down(&mut self, node: usize, fwd: i32, rev: i32) {
        self.add_edge(node, DOWN, fwd, rev);
    }

    fn add_edge(&mut self, p: usize, d: u8, fwd: i32, rev: i32) {
        assert!(fwd >= 0 && rev >= 0, "negative edge capacity");
        assert!(
            self.nodes[p].nbrs & (1 << d) != 0,
            "node {p} has no neighbour in direction {d}"
        );
        let q = p.wrapping_add(self.step[d as usize]);
        self.touch(p);
        self.touch(q);
        let fwd = i64::from(self.nodes[p].cap[d as usize]) + i64::from(fwd);
        let rev = i64::from(self.nodes[q].cap[(d ^ 1) as usize]) + i64::from(rev);
        // Augmentation can move an edge's whole capacity to either direction, so the pair's sum
        // must fit; checking it here keeps the search loops free of overflow tests.
        assert!(
            fwd + rev <= i64::from(i32::MAX),
            "edge capacity overflows i32"
        );
        self.nodes[p].cap[d as usize] = fwd as i32;
        self.nodes[q].cap[(d ^ 1) as usize] = rev as i32;
    }

    /// Runs the max-flow and returns the flow value (= min cut cost, including the constant part
    /// that add_tweights cancels when both source and sink capacity are given to one node).
    ///
    /// Works on the residual graph, so capacities may be added afterwards and the call repeated.
    pub fn maxflow(&mut self) -> i64 {
        self.init_trees();
        // The node that found the last augmenting path is scanned again before the queue moves
        // on: it usually has more paths to offer.
        let mut current: Option<usize> = None;
        loop {
            if let Some(i) = current {
                self.nodes[i].active = false;
                if self.nodes[i].tree == FREE {
                    current = None;
                }
            }
            let i = match current {
                Some(i) => i,
                None => match self.next_active() {
                    Some(i) => i,
                    None => break,
                },
            };
            let bridge = if self.nodes[i].tree == SOURCE {
                self.grow::<false>(i)
            } else {
                self.grow::<true>(i)
            };
            current = bridge.map(|(p, d)| {
                // Marked active so adoption does not queue it while it is still being processed.
                self.nodes[i].active = true;
                self.advance_time();
                self.augment(p, d);
                self.adopt();
                i
            });
        }
        self.flow
    }

    /// After maxflow: true when the node is on the sink side of a minimum cut
    /// (i.e. it can still reach the sink in the residual graph).
    ///
    /// That is the smallest sink side of all minimum cuts: ties go to the source side, so a caller
    /// that treats the sink side as "change" (an expansion move) only changes what strictly lowers
    /// the cost, and its iterations terminate.
    pub fn in_sink(&self, node: usize) -> bool {
        // At termination the sink tree is closed under residual arcs into it, so it is exactly the
        // set that can reach the sink; free nodes cannot.
        self.nodes[node].tree == SINK
    }

    fn init_trees(&mut self) {
        self.active.clear();
        self.orphans.clear();
        self.time = 0;
        for &i in &self.touched {
            let n = &mut self.nodes[i as usize];
            n.ts = 0;
            n.dist = 1;
            n.parent = TERMINAL;
            n.active = n.tr != 0;
            n.tree = match n.tr.signum() {
                1 => SOURCE,
                -1 => SINK,
                _ => FREE,
            };
            if n.active {
                self.active.push_back(i);
            }
        }
    }

    fn next_active(&mut self) -> Option<usize> {
        while let Some(i) = self.active.pop_front() {
            let n = &mut self.nodes[i as usize];
            n.active = false;
            // Nodes freed by adoption since they were queued stay in the queue; skip them.
            if n.tree != FREE {
                return Some(i as usize);
            }
        }
        None
    }

    fn advance_time(&mut self) {
        if self.time == u32::MAX {
            // Timestamps only validate cached distances, so forgetting them all is safe.
            for n in &mut self.nodes {
                n.ts = 0;
            }
            self.time = 0;
        }
        self.time += 1;
    }

    /// Grows the tree of node `i` (`SINK_TREE` says which) into free neighbours. Returns the
    /// arc `(p, d)` from the source tree to the sink tree if one is found.
    fn grow<const SINK_TREE: bool>(&mut self, i: usize) -> Option<(usize, u8)> {
        let tree = if SINK_TREE { SINK } else { SOURCE };
        let Node {
            cap,
            ts,
            dist,
            nbrs,
            ..
        } = self.nodes[i];
        for d in 0..4u8 {
            // A source tree grows along arcs out of i, a sink tree along arcs into i.
            if !SINK_TREE && cap[d as usize] <= 0 || SINK_TREE && nbrs & (1 << d) == 0 {
                continue;
            }
            let j = i.wrapping_add(self.step[d as usize]);
            let nj = &mut self.nodes[j];
            if SINK_TREE && nj.cap[(d ^ 1) as usize] <= 0 {
                continue;
            }
            if nj.tree == FREE {
                nj.tree = tree;
                nj.parent = d ^ 1;
                nj.ts = ts;
                nj.dist = dist + 1;
                if !nj.active {
                    nj.active = true;
                    self.active.push_back(j as u32);
                }
            } else if nj.tree != tree {
                return Some(if SINK_TREE { (j, d ^ 1) } else { (i, d) });
            } else if nj.ts <= ts && nj.dist > dist {
                // Re-hang j under i when that is shorter: short trees make augmenting
                // paths and origin checks cheap.
                nj.parent = d ^ 1;
                nj.ts = ts;
                nj.dist = dist + 1;
            }
        }
        None
    }

    /// Pushes the bottleneck flow along source root → p → q → sink root, where `q` is `p`'s
    /// neighbour in direction `d`, and records the nodes whose tree link saturated as orphans.
    fn augment(&mut self, p: usize, d: u8) {
        let step = self.step;
        let q = p.wrapping_add(step[d as usize]);

        let mut b = self.nodes[p].cap[d as usize];
        let mut i = p;
        loop {
            let n = &self.nodes[i];
            if n.parent == TERMINAL {
                b = b.min(n.tr);
                break;
            }
            let j = i.wrapping_add(step[n.parent as usize]);
            b = b.min(self.nodes[j].cap[(n.parent ^ 1) as usize]);
            i = j;
        }
        i = q;
        loop {
            let n = &self.nodes[i];
            if n.parent == TERMINAL {
                b = b.min(-n.tr);
                break;
            }
            b = b.min(n.cap[n.parent as usize]);
            i = i.wrapping_add(step[n.parent as usize]);
        }

        self.nodes[p].cap[d as usize] -= b;
        self.nodes[q].cap[(d ^ 1) as usize] += b;

        i = p;
        loop {
            let pd = self.nodes[i].parent;
            if pd == TERMINAL {
                self.nodes[i].tr -= b;
                if self.nodes[i].tr == 0 {
                    self.make_orphan(i);
                }
                break;
            }
            let j = i.wrapping_add(step[pd as usize]);
            self.nodes[i].cap[pd as usize] += b;
            let c = &mut self.nodes[j].cap[(pd ^ 1) as usize];
            *c -= b;
            if *c == 0 {
                self.make_orphan(i);
            }
            i = j;
        }
        i = q;
        loop {
            let pd = self.nodes[i].parent;
            if pd == TERMINAL {
                self.nodes[i].tr += b;
                if self.nodes[i].tr == 0 {
                    self.make_orphan(i);
                }
                break;
            }
            let j = i.wrapping_add(step[pd as usize]);
            self.nodes[j].cap[(pd ^ 1) as usize] += b;
            let c = &mut self.nodes[i].cap[pd as usize];
            *c -= b;
            if *c == 0 {
                self.make_orphan(i);
            }
            i = j;
        }
        self.flow += i64::from(b);
    }

    fn make_orphan(&mut self, i: usize) {
        self.nodes[i].parent = ORPHAN;
        self.orphans.push(i as u32);
    }

    /// Processes orphans first-in first-out, including those created on the way.
    fn adopt(&mut self) {
        let mut k = 0;
        while let Some(&i) = self.orphans.get(k) {
            k += 1;
            let i = i as usize;
            if self.nodes[i].tree == SINK {
                self.adopt_orphan::<true>(i);
            } else {
                self.adopt_orphan::<false>(i);
            }
        }
        self.orphans.clear();
    }

    /// Finds orphan `i` a new parent in its own tree, preferring the one closest to the
    /// terminal; failing that frees it and orphans its children.
    fn adopt_orphan<const SINK_TREE: bool>(&mut self, i: usize) {
        let tree = if SINK_TREE { SINK } else { SOURCE };
        let Node { cap, nbrs, .. } = self.nodes[i];
        let step = self.step;
        // A source-tree parent must reach i through a residual arc j→i, a sink-tree one through
        // i→j.
        let linked = |nj: &Node, d: u8| {
            if SINK_TREE {
                cap[d as usize] > 0
            } else {
                nj.cap[(d ^ 1) as usize] > 0
            }
        };

        let mut best = None;
        let mut best_dist = u32::MAX;
        for d in 0..4u8 {
            if nbrs & (1 << d) == 0 {
                continue;
            }
            let j = i.wrapping_add(step[d as usize]);
            let nj = &self.nodes[j];
            if nj.tree != tree || !linked(nj, d) {
                continue;
            }
            if let Some(dist) = self.origin_dist(j) {
                if dist < best_dist {
                    best = Some(d);
                    best_dist = dist;
                }
            }
        }
        if let Some(d) = best {
            let time = self.time;
            let n = &mut self.nodes[i];
            n.parent = d;
            n.ts = time;
            n.dist = best_dist + 1;
            return;
        }

        self.nodes[i].tree = FREE;
        for d in 0..4u8 {
            if nbrs & (1 << d) == 0 {
                continue;
            }
            let j = i.wrapping_add(step[d as usize]);
            let nj = &mut self.nodes[j];
            if nj.tree != tree {
                continue;
            }
            // j may now be able to grow into i again.
            if linked(nj, d) && !nj.active {
                nj.active = true;
                self.active.push_back(j as u32);
            }
            if nj.parent == d ^ 1 {
                nj.parent = ORPHAN;
                self.orphans.push(j as u32);
            }
        }
    }

    /// Distance from `j` to its terminal along tree links, or `None` when the path runs into an
    /// orphan. Caches the distances along the path under the current time stamp so later checks
    /// in the same adoption round stop early.
    fn origin_dist(&mut self, j: usize) -> Option<u32> {
        let time = self.time;
        let step = self.step;
        let mut k = j;
        let mut dist = 0u32;
        loop {
            let nk = &mut self.nodes[k];
            if nk.ts == time {
                dist += nk.dist;
                break;
            }
            dist += 1;
            match nk.parent {
                TERMINAL => {
                    nk.ts = time;
                    nk.dist = 1;
                    break;
                }
                ORPHAN => return None,
                pd => k = k.wrapping_add(step[pd as usize]),
            }
        }
        let mut k = j;
        let mut d = dist;
        loop {
            let nk = &mut self.nodes[k];
            if nk.ts == time {
                break;
            }
            nk.ts = time;
            nk.dist = d;
            d -= 1;
            k = k.wrapping_add(step[nk.parent as usize]);
        }
        Some(dist)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct XorShift(u64);

    impl XorShift {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }

        /// Uniform in `0..=max`.
        fn upto(&mut self, max: i32) -> i32 {
            (self.next() % (max as u64 + 1)) as i32
        }
    }

    /// Original (accumulated) capacities of a problem, kept to check the solver against.
    #[derive(Clone)]
    struct Problem {
        width: usize,
        height: usize,
        source: Vec<i64>,
        sink: Vec<i64>,
        /// `(fwd, rev)` of the edge to the right / down neighbour.
        right: Vec<(i64, i64)>,
        down: Vec<(i64, i64)>,
        /// Calls in the order they are to be made: (kind, node, a, b) with kind 0 = tweights,
        /// 1 = right, 2 = down.
        calls: Vec<(u8, usize, i32, i32)>,
    }

    impl Problem {
        fn new(width: usize, height: usize) -> Self {
            let n = width * height;
            Problem {
                width,
                height,
                source: vec![0; n],
                sink: vec![0; n],
                right: vec![(0, 0); n],
                down: vec![(0, 0); n],
                calls: Vec::new(),
            }
        }

        fn tweights(&mut self, p: usize, s: i32, t: i32) {
            self.source[p] += i64::from(s);
            self.sink[p] += i64::from(t);
            self.calls.push((0, p, s, t));
        }

        fn right(&mut self, p: usize, f: i32, r: i32) {
            self.right[p].0 += i64::from(f);
            self.right[p].1 += i64::from(r);
            self.calls.push((1, p, f, r));
        }

        fn down(&mut self, p: usize, f: i32, r: i32) {
            self.down[p].0 += i64::from(f);
            self.down[p].1 += i64::from(r);
            self.calls.push((2, p, f, r));
        }

        fn load(&self, g: &mut GridMaxflow) {
            g.reset(self.width, self.height);
            for &(kind, p, a, b) in &self.calls {
                match kind {
                    0 => g.add_tweights(p, a, b),
                    1 => g.add_right(p, a, b),
                    _ => g.add_down(p, a, b),
                }
            }
        }

        /// Cost of the cut where `in_sink(p)` says which side node p is on.
        fn cut_cost(&self, in_sink: impl Fn(usize) -> bool) -> i64 {
            let w = self.width;
            let mut cost = 0;
            for p in 0..self.width * self.height {
                let sp = in_sink(p);
                cost += if sp { self.source[p] } else { self.sink[p] };
                let (x, y) = (p % w, p / w);
                if x + 1 < w {
                    let sq = in_sink(p + 1);
                    cost += match (sp, sq) {
                        (false, true) => self.right[p].0,
                        (true, false) => self.right[p].1,
                        _ => 0,
                    };
                }
                if y + 1 < self.height {
                    let sq = in_sink(p + w);
                    cost += match (sp, sq) {
                        (false, true) => self.down[p].0,
                        (true, false) => self.down[p].1,
                        _ => 0,
                    };
                }
            }
            cost
        }

        fn brute_force_min_cut(&self) -> i64 {
            let n = self.width * self.height;
            (0u32..1 << n)
                .map(|mask| self.cut_cost(|p| mask >> p & 1 != 0))
                .min()
                .unwrap()
        }
    }

    fn random_problem(rng: &mut XorShift, width: usize, height: usize, max: i32) -> Problem {
        let mut pb = Problem::new(width, height);
        let n = width * height;
        // Zeros are common on purpose: they create free nodes and saturated arcs.
        let cap = |rng: &mut XorShift| {
            if rng.upto(3) == 0 {
                0
            } else {
                rng.upto(max)
            }
        };
        for _ in 0..1 + rng.upto(1) {
            for p in 0..n {
                let (s, t) = (cap(rng), cap(rng));
                pb.tweights(p, s, t);
                if p % width + 1 < width {
                    let (f, r) = (cap(rng), cap(rng));
                    pb.right(p, f, r);
                }
                if p / width + 1 < height {
                    let (f, r) = (cap(rng), cap(rng));
                    pb.down(p, f, r);
                }
            }
        }
        pb
    }

    /// Checks that the solver's residual graph holds a feasible flow of value `flow` and that
    /// the reported segmentation is a cut of the same cost, which proves both optimal. Also
    /// checks that the sink side is exactly the set that can reach the sink.
    fn check_certificate(pb: &Problem, g: &GridMaxflow, flow: i64) {
        let (w, h) = (pb.width, pb.height);
        let n = w * h;
        let mut out = vec![0i64; n];
        let mut value_in = 0;
        let mut value_out = 0;
        for p in 0..n {
            let node = &g.nodes[p];
            let (x, y) = (p % w, p / w);
            let net = pb.source[p] - pb.sink[p];
            let tr = i64::from(node.tr);
            assert!(
                (0..=net).contains(&tr) || (net..=0).contains(&tr),
                "terminal residual {tr} outside 0..={net} at {p}"
            );
            value_in += pb.source[p].min(pb.sink[p]) + (net - tr).max(0);
            value_out += pb.source[p].min(pb.sink[p]) + (tr - net).max(0);
            out[p] += net - tr;
            let mut edge = |d: u8, q: usize, (f, r): (i64, i64)| {
                let res_f = i64::from(node.cap[d as usize]);
                let res_r = i64::from(g.nodes[q].cap[(d ^ 1) as usize]);
                assert!(res_f >= 0 && res_r >= 0, "negative residual at {p}");
                assert_eq!(res_f + res_r, f + r, "edge capacity not conserved at {p}");
                out[p] -= f - res_f;
                out[q] += f - res_f;
            };
            if x + 1 < w {
                edge(RIGHT, p + 1, pb.right[p]);
            } else {
                assert_eq!(node.cap[RIGHT as usize], 0);
            }
            if y + 1 < h {
                edge(DOWN, p + w, pb.down[p]);
            } else {
                assert_eq!(node.cap[DOWN as usize], 0);
            }
            if x == 0 {
                assert_eq!(node.cap[LEFT as usize], 0);
            }
            if y == 0 {
                assert_eq!(node.cap[UP as usize], 0);
            }
        }
        assert!(out.iter().all(|&e| e == 0), "flow not conserved");
        assert_eq!(value_in, flow, "returned flow differs from the flow found");
        assert_eq!(
            value_out, flow,
            "flow out of source differs from flow into sink"
        );
        assert_eq!(
            pb.cut_cost(|p| g.in_sink(p)),
            flow,
            "segmentation is not a min cut"
        );

        // Search backwards from the sink along residual arcs.
        let mut reaches_sink = vec![false; n];
        let mut stack: Vec<usize> = (0..n).filter(|&p| g.nodes[p].tr < 0).collect();
        for &p in &stack {
            reaches_sink[p] = true;
        }
        while let Some(q) = stack.pop() {
            for d in 0..4u8 {
                if g.nodes[q].nbrs & (1 << d) == 0 {
                    continue;
                }
                let p = q.wrapping_add(g.step[d as usize]);
                if g.nodes[p].cap[(d ^ 1) as usize] > 0 && !reaches_sink[p] {
                    reaches_sink[p] = true;
                    stack.push(p);
                }
            }
        }
        for (p, &r) in reaches_sink.iter().enumerate() {
            assert_eq!(g.in_sink(p), r, "in_sink({p}) disagrees with reachability");
        }
    }

    fn solve(pb: &Problem) -> (i64, Vec<bool>) {
        let mut g = GridMaxflow::new();
        pb.load(&mut g);
        let flow = g.maxflow();
        check_certificate(pb, &g, flow);
        (
            flow,
            (0..pb.width * pb.height).map(|p| g.in_sink(p)).collect(),
        )
    }

    #[test]
    fn matches_brute_force_on_small_grids() {
        let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
        for round in 0..1500 {
            let width = 1 + rng.upto(3) as usize;
            let height = 1 + rng.upto(3) as usize;
            let max = [1, 10, 1000, 1 << 24][round % 4];
            let pb = random_problem(&mut rng, width, height, max);
            let (flow, _) = solve(&pb);
            assert_eq!(
                flow,
                pb.brute_force_min_cut(),
                "round {round}: {width}x{height}, max {max}"
            );
        }
    }

    #[test]
    fn reuse_after_reset_matches_fresh_solver() {
        let mut rng = XorShift(12345);
        let mut g = GridMaxflow::new();
        for (w, h) in [(4, 4), (7, 3), (1, 9), (12, 10), (3, 3), (16, 16)] {
            let pb = random_problem(&mut rng, w, h, 100);
            pb.load(&mut g);
            assert_eq!((g.width(), g.height()), (w, h));
            let flow = g.maxflow();
            check_certificate(&pb, &g, flow);
            let (fresh_flow, fresh_seg) = solve(&pb);
            assert_eq!(flow, fresh_flow);
            let seg: Vec<bool> = (0..w * h).map(|p| g.in_sink(p)).collect();
            assert_eq!(seg, fresh_seg);
        }
    }

    /// A problem on a few scattered nodes of a grid whose every node was used before: the reset
    /// clears only what the last problem touched, and the search must not wander into the rest.
    #[test]
    fn sparse_problem_after_dense_one_on_the_same_grid() {
        let mut rng = XorShift(4242);
        let mut g = GridMaxflow::new();
        for _ in 0..10 {
            random_problem(&mut rng, 12, 9, 100).load(&mut g);
            g.maxflow();
            let mut pb = Problem::new(12, 9);
            for p in (0..12 * 9).filter(|p| p % 7 < 2) {
                pb.tweights(p, rng.upto(50), rng.upto(50));
                if p % 12 + 1 < 12 && (p + 1) % 7 < 2 {
                    let (f, r) = (rng.upto(30), rng.upto(30));
                    pb.right(p, f, r);
                }
            }
            pb.load(&mut g);
            assert!(g.touched.len() < 12 * 9 / 2);
            let flow = g.maxflow();
            check_certificate(&pb, &g, flow);
            assert_eq!(flow, solve(&pb).0);
        }
    }

    #[test]
    fn capacities_added_after_maxflow() {
        let mut rng = XorShift(99);
        for _ in 0..20 {
            let pb = random_problem(&mut rng, 9, 7, 1000);
            let (full_flow, full_seg) = solve(&pb);
            let (first, second) = pb.calls.split_at(pb.calls.len() / 2);
            let mut g = GridMaxflow::new();
            Problem {
                calls: first.to_vec(),
                ..pb.clone()
            }
            .load(&mut g);
            g.maxflow();
            for &(kind, p, a, b) in second {
                match kind {
                    0 => g.add_tweights(p, a, b),
                    1 => g.add_right(p, a, b),
                    _ => g.add_down(p, a, b),
                }
            }
            // The flow found may now use both terminals of a node, which check_certificate
            // does not model; a cut of the optimal cost is certificate enough.
            assert_eq!(g.maxflow(), full_flow);
            assert_eq!(pb.cut_cost(|p| g.in_sink(p)), full_flow);
            assert_eq!(
                (0..9 * 7).map(|p| g.in_sink(p)).collect::<Vec<_>>(),
                full_seg
            );
        }
    }

    #[test]
    #[should_panic(expected = "no neighbour")]
    fn edge_off_the_grid_panics() {
        let mut g = GridMaxflow::new();
        g.reset(3, 2);
        g.add_right(2, 1, 1);
    }

    #[test]
    fn single_node() {
        let mut g = GridMaxflow::new();
        g.reset(1, 1);
        g.add_tweights(0, 5, 3);
        assert_eq!(g.maxflow(), 3);
        assert!(!g.in_sink(0));
        g.reset(1, 1);
        g.add_tweights(0, 2, 7);
        g.add_tweights(0, 0, 1);
        assert_eq!(g.maxflow(), 2);
        assert!(g.in_sink(0));
        // A tie stays on the source side.
        g.reset(1, 1);
        g.add_tweights(0, 4, 4);
        assert_eq!(g.maxflow(), 4);
        assert!(!g.in_sink(0));
    }

    /// A chain source → 0 → ... → n-1 → sink with one weak link, laid out as a row or a column.
    fn chain(n: usize, vertical: bool) {
        let weak = (n - 1) / 2;
        let mut pb = if vertical {
            Problem::new(1, n)
        } else {
            Problem::new(n, 1)
        };
        pb.tweights(0, 100, 0);
        pb.tweights(n - 1, 0, 100);
        for p in 0..n - 1 {
            let f = if p == weak { 7 } else { 50 };
            if vertical {
                pb.down(p, f, 1);
            } else {
                pb.right(p, f, 1);
            }
        }
        let (flow, seg) = solve(&pb);
        assert_eq!(flow, 7);
        for (p, &s) in seg.iter().enumerate() {
            assert_eq!(s, p > weak, "node {p}");
        }
    }

    #[test]
    fn row_and_column_grids() {
        for n in [2, 3, 10, 5000] {
            chain(n, false);
            chain(n, true);
        }
    }

    #[test]
    fn empty_grid() {
        let mut g = GridMaxflow::new();
        g.reset(0, 5);
        assert_eq!(g.maxflow(), 0);
    }

    /// Noisy two-region image with contrast-sensitive smoothing, like a fusion labelling move.
    fn segmentation_problem(width: usize, height: usize, seed: u64) -> Problem {
        let mut rng = XorShift(seed);
        let mut img = vec![0i32; width * height];
        for (p, v) in img.iter_mut().enumerate() {
            let (x, y) = ((p % width) as f64, (p / width) as f64);
            let inside = (x * 0.11).sin() + (y * 0.07).cos() + (0.05 * (x + y)).sin() > 0.4;
            let noise: i32 = (0..3).map(|_| rng.upto(80) - 40).sum();
            *v = if inside { 90 } else { 160 } + noise;
        }
        let mut pb = Problem::new(width, height);
        for p in 0..width * height {
            let i = img[p];
            pb.tweights(p, (i - 90).pow(2) / 8, (i - 160).pow(2) / 8);
            let weight = |q: usize| {
                let d = f64::from(img[p] - img[q]);
                (400.0 * (-d * d / 3200.0).exp()) as i32
            };
            if p % width + 1 < width {
                let c = weight(p + 1);
                pb.right(p, c, c);
            }
            if p / width + 1 < height {
                let c = weight(p + width);
                pb.down(p, c, c);
            }
        }
        pb
    }

    #[test]
    fn segmentation_64x64_is_certified_min_cut() {
        for seed in [1, 2, 3] {
            let pb = segmentation_problem(64, 64, seed);
            let (flow, seg) = solve(&pb);
            assert!(flow > 0);
            // Both labels must occur, or the test exercises nothing.
            assert!(seg.iter().any(|&s| s) && seg.iter().any(|&s| !s));
        }
    }
}
