//! Minimum s-t cut on an image grid: the binary labelling that minimises per-pixel costs plus
//! costs between 8-neighbours with different labels, found as a maximum flow with the
//! Boykov-Kolmogorov algorithm (PAMI 26(9), 2004), the solver GrabCut-style segmentation uses.
//!
//! Written by hand: no maintained Rust crate offers a max-flow for image grids, and a
//! general-graph Edmonds-Karp (the oracle in the tests) is orders of magnitude slower on them.
//!
//! Work: one thread. Two search trees grow from the terminals (S: the source, the label "1";
//! T: the sink) through edges with residual capacity; where they touch, the path is augmented by
//! its bottleneck, saturated tree edges leave orphans, and orphans are re-attached to their tree
//! (the neighbour nearest its terminal) or freed. It ends when the trees cannot grow; the S tree
//! is then the set of pixels reachable from the source, the minimum cut's source side.

use std::collections::VecDeque;

/// The 8 neighbours, ordered so that the opposite of direction `k` is `7 - k`.
const DIRS: [(i32, i32); 8] = [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)];
const TERMINAL: u8 = 8;
const ORPHAN: u8 = 9;
const FREE: u8 = 0;
const S: u8 = 1;
const T: u8 = 2;

/// A capacity that no finite cut pays: the terminal link of a pixel whose label is fixed.
pub const HARD: f32 = 1e20;

/// The flow network of a `width` x `height` grid: terminal links and 8-neighbour edges.
pub struct GridGraph {
    width: usize,
    height: usize,
    /// Terminal residual of each pixel: > 0 from the source, < 0 to the sink.
    terminal: Vec<f32>,
    /// Residual capacity from pixel `i` to its neighbour in direction `k`, at `8 i + k`.
    cap: Vec<f32>,
    /// Flow that both terminal links of a pixel carry (it crosses every cut).
    constant: f64,
}

/// The minimum cut: each pixel's side, and the cut's cost (= the maximum flow).
pub struct Cut {
    /// `true` on the source side (label 1).
    pub source_side: Vec<bool>,
    /// Total capacity of the cut edges.
    pub cost: f64,
}

impl GridGraph {
    /// A grid with no capacities.
    pub fn new(width: usize, height: usize) -> Self {
        let n = width * height;
        Self { width, height, terminal: vec![0.0; n], cap: vec![0.0; 8 * n], constant: 0.0 }
    }

    /// Pixel `i` pays `to_sink` if it ends on the sink side (label 0) and `to_source` if on the
    /// source side: the capacities of its source and sink links. Both must be >= 0.
    pub fn add_terminal(&mut self, i: usize, to_sink: f32, to_source: f32) {
        // Only the difference matters to the cut; the common part crosses every cut.
        let common = to_sink.min(to_source);
        self.constant += common as f64;
        self.terminal[i] += to_sink - to_source;
    }

    /// The neighbour of pixel `i` in direction `k`, if inside the grid.
    pub fn neighbour(&self, i: usize, k: usize) -> Option<usize> {
        let (dx, dy) = DIRS[k];
        let x = (i % self.width) as i32 + dx;
        let y = (i / self.width) as i32 + dy;
        (x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height)
            .then(|| y as usize * self.width + x as usize)
    }

    /// Capacity `forward` from pixel `i` to its neighbour in direction `k` (paid when `i` is on
    /// the source side and the neighbour is not), `backward` the other way. Adds to what is there.
    pub fn add_edge(&mut self, i: usize, k: usize, forward: f32, backward: f32) {
        let j = self.neighbour(i, k).expect("edge leaves the grid");
        self.cap[8 * i + k] += forward;
        self.cap[8 * j + 7 - k] += backward;
    }

    /// The maximum flow, and with it the minimum cut.
    pub fn solve(mut self) -> Cut {
        let n = self.width * self.height;
        let mut tree = vec![FREE; n];
        let mut parent = vec![TERMINAL; n];
        let mut stamp = vec![0u32; n];
        let mut dist = vec![0u32; n];
        let mut in_queue = vec![false; n];
        let mut active = VecDeque::new();
        for i in 0..n {
            if self.terminal[i] != 0.0 {
                tree[i] = if self.terminal[i] > 0.0 { S } else { T };
                dist[i] = 1;
                active.push_back(i);
                in_queue[i] = true;
            }
        }
        let mut flow = self.constant;
        let mut time = 0u32;
        let mut orphans = VecDeque::new();
        loop {
            // Grow: the first active pixel whose tree reaches the other one gives a path.
            let mut path = None;
            while let Some(&i) = active.front() {
                if tree[i] != FREE {
                    for k in 0..8 {
                        let Some(j) = self.neighbour(i, k) else { continue };
                        // i would be j's parent, j -> i its direction.
                        if !self.tree_edge_open(tree[i], i, j, 7 - k) {
                            continue;
                        }
                        if tree[j] == FREE {
                            tree[j] = tree[i];
                            parent[j] = (7 - k) as u8;
                            stamp[j] = stamp[i];
                            dist[j] = dist[i] + 1;
                            if !in_queue[j] {
                                in_queue[j] = true;
                                active.push_back(j);
                            }
                        } else if tree[j] != tree[i] {
                            path = Some(if tree[i] == S { (i, j, k) } else { (j, i, 7 - k) });
                            break;
                        }
                    }
                }
                if path.is_some() {
                    break;
                }
                active.pop_front();
                in_queue[i] = false;
            }
            let Some((s_end, t_end, k_mid)) = path else { break };
            time += 1;
            flow += self.augment(s_end, t_end, k_mid, &mut parent, &mut orphans);
            // Adopt: each orphan takes the valid same-tree neighbour nearest its terminal.
            while let Some(o) = orphans.pop_front() {
                let side = tree[o];
                let mut best: Option<(usize, u32)> = None;
                for k in 0..8 {
                    let Some(j) = self.neighbour(o, k) else { continue };
                    if tree[j] != side || !self.tree_edge_open(side, j, o, k) {
                        continue;
                    }
                    if let Some(d) = self.depth(j, time, &parent, &mut stamp, &mut dist) {
                        if best.is_none_or(|(_, bd)| d < bd) {
                            best = Some((k, d));
                        }
                    }
                }
                if let Some((k, d)) = best {
                    parent[o] = k as u8;
                    stamp[o] = time;
                    dist[o] = d + 1;
                    continue;
                }
                tree[o] = FREE;
                for k in 0..8 {
                    let Some(j) = self.neighbour(o, k) else { continue };
                    if tree[j] != side {
                        continue;
                    }
                    if self.tree_edge_open(side, j, o, k) && !in_queue[j] {
                        in_queue[j] = true;
                        active.push_back(j);
                    }
                    if parent[j] == (7 - k) as u8 {
                        parent[j] = ORPHAN;
                        orphans.push_back(j);
                    }
                }
            }
        }
        Cut { source_side: tree.iter().map(|&t| t == S).collect(), cost: flow }
    }

    /// Whether `j` (in tree `side`, the neighbour of `o` in direction `k`) may be `o`'s parent:
    /// in S the edge j -> o has residual, in T the edge o -> j.
    fn tree_edge_open(&self, side: u8, j: usize, o: usize, k: usize) -> bool {
        if side == S {
            self.cap[8 * j + 7 - k] > 0.0
        } else {
            self.cap[8 * o + k] > 0.0
        }
    }

    /// Steps from `j` to its terminal, or `None` if its chain ends at an orphan; stamps the
    /// pixels on a valid chain with `time` and their distance, so later walks stop there.
    fn depth(&self, j: usize, time: u32, parent: &[u8], stamp: &mut [u32], dist: &mut [u32]) -> Option<u32> {
        let mut d = 0;
        let mut m = j;
        loop {
            if stamp[m] == time {
                d += dist[m];
                break;
            }
            match parent[m] {
                TERMINAL => {
                    stamp[m] = time;
                    dist[m] = 1;
                    d += 1;
                    break;
                }
                ORPHAN => return None,
                k => {
                    d += 1;
                    m = self.neighbour(m, k as usize).expect("parent inside the grid");
                }
            }
        }
        let (mut m, mut dm) = (j, d);
        while stamp[m] != time {
            stamp[m] = time;
            dist[m] = dm;
            dm -= 1;
            m = self.neighbour(m, parent[m] as usize).expect("parent inside the grid");
        }
        Some(d)
    }

    /// Push the bottleneck along source -> ... -> s_end -> t_end -> ... -> sink; saturated
    /// tree links make orphans. Returns the flow pushed.
    fn augment(
        &mut self,
        s_end: usize,
        t_end: usize,
        k_mid: usize,
        parent: &mut [u8],
        orphans: &mut VecDeque<usize>,
    ) -> f64 {
        let mut f = self.cap[8 * s_end + k_mid];
        let mut c = s_end;
        while parent[c] != TERMINAL {
            let k = parent[c] as usize;
            let p = self.neighbour(c, k).expect("parent inside the grid");
            f = f.min(self.cap[8 * p + 7 - k]);
            c = p;
        }
        f = f.min(self.terminal[c]);
        let mut c = t_end;
        while parent[c] != TERMINAL {
            let k = parent[c] as usize;
            f = f.min(self.cap[8 * c + k]);
            c = self.neighbour(c, k).expect("parent inside the grid");
        }
        f = f.min(-self.terminal[c]);

        self.cap[8 * s_end + k_mid] -= f;
        self.cap[8 * t_end + 7 - k_mid] += f;
        let mut c = s_end;
        while parent[c] != TERMINAL {
            let k = parent[c] as usize;
            let p = self.neighbour(c, k).expect("parent inside the grid");
            self.cap[8 * p + 7 - k] -= f;
            self.cap[8 * c + k] += f;
            if self.cap[8 * p + 7 - k] <= 0.0 {
                parent[c] = ORPHAN;
                orphans.push_back(c);
            }
            c = p;
        }
        self.terminal[c] -= f;
        if self.terminal[c] <= 0.0 {
            parent[c] = ORPHAN;
            orphans.push_back(c);
        }
        let mut c = t_end;
        while parent[c] != TERMINAL {
            let k = parent[c] as usize;
            let p = self.neighbour(c, k).expect("parent inside the grid");
            self.cap[8 * c + k] -= f;
            self.cap[8 * p + 7 - k] += f;
            if self.cap[8 * c + k] <= 0.0 {
                parent[c] = ORPHAN;
                orphans.push_back(c);
            }
            c = p;
        }
        self.terminal[c] += f;
        if self.terminal[c] >= 0.0 {
            parent[c] = ORPHAN;
            orphans.push_back(c);
        }
        f as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;

    /// The oracle: Edmonds-Karp (shortest augmenting paths by BFS) on a dense capacity matrix.
    fn edmonds_karp(cap: &mut [Vec<f64>], s: usize, t: usize) -> f64 {
        let n = cap.len();
        let mut flow = 0.0;
        loop {
            let mut prev = vec![usize::MAX; n];
            prev[s] = s;
            let mut q = VecDeque::from([s]);
            while let Some(u) = q.pop_front() {
                for v in 0..n {
                    if prev[v] == usize::MAX && cap[u][v] > 1e-12 {
                        prev[v] = u;
                        q.push_back(v);
                    }
                }
            }
            if prev[t] == usize::MAX {
                return flow;
            }
            let mut f = f64::INFINITY;
            let mut v = t;
            while v != s {
                f = f.min(cap[prev[v]][v]);
                v = prev[v];
            }
            let mut v = t;
            while v != s {
                cap[prev[v]][v] -= f;
                cap[v][prev[v]] += f;
                v = prev[v];
            }
            flow += f;
        }
    }

    #[test]
    fn max_flow_and_cut_agree_with_edmonds_karp_on_random_grids() {
        let mut rng = Rng::new(5);
        for case in 0..60 {
            let (w, h) = (2 + rng.below(6), 2 + rng.below(6));
            let n = w * h;
            let mut g = GridGraph::new(w, h);
            let mut dense = vec![vec![0.0f64; n + 2]; n + 2];
            let (src, snk) = (n, n + 1);
            for i in 0..n {
                // Integer-valued capacities keep the f32 sums exact.
                let (a, b) = (rng.below(6) as f32, rng.below(6) as f32);
                let hard = rng.below(10);
                let (a, b) = match hard {
                    0 => (HARD, b),
                    1 => (a, HARD),
                    _ => (a, b),
                };
                g.add_terminal(i, a, b);
                dense[src][i] += a as f64;
                dense[i][snk] += b as f64;
            }
            for i in 0..n {
                for k in 0..8 {
                    if let Some(j) = g.neighbour(i, k) {
                        if k < 4 {
                            let (f, b) = (rng.below(5) as f32, rng.below(5) as f32);
                            g.add_edge(i, k, f, b);
                            dense[i][j] += f as f64;
                            dense[j][i] += b as f64;
                        }
                    }
                }
            }
            let original = dense.clone();
            let want = edmonds_karp(&mut dense, src, snk);
            let cut = g.solve();
            if want >= HARD as f64 {
                continue; // both sides fixed through one pixel: no finite cut
            }
            assert!((cut.cost - want).abs() <= 1e-6 * want.max(1.0), "case {case}: flow {} != {want}", cut.cost);
            // The labelling is a cut of that cost, so it is a minimum cut.
            let side = |u: usize| {
                if u == src {
                    true
                } else if u == snk {
                    false
                } else {
                    cut.source_side[u]
                }
            };
            let mut cost = 0.0;
            for u in 0..n + 2 {
                for v in 0..n + 2 {
                    if side(u) && !side(v) {
                        cost += original[u][v];
                    }
                }
            }
            assert!((cost - want).abs() <= 1e-6 * want.max(1.0), "case {case}: cut {cost} != flow {want}");
        }
    }

    #[test]
    fn a_smooth_edge_follows_the_contrast_not_the_noisy_costs() {
        // Left half prefers 1, right half 0, with a sharp colour edge at x = 10; noise flips a
        // few pixels' preference, and the pairwise terms must smooth them away.
        let (w, h) = (20, 12);
        let mut g = GridGraph::new(w, h);
        let mut rng = Rng::new(1);
        for i in 0..w * h {
            let x = i % w;
            let mut pref = if x < 10 { 1.0 } else { -1.0 };
            if rng.below(8) == 0 {
                pref = -pref;
            }
            if pref > 0.0 {
                g.add_terminal(i, 1.0, 0.0)
            } else {
                g.add_terminal(i, 0.0, 1.0)
            }
            for k in [4, 6] {
                if let Some(j) = g.neighbour(i, k) {
                    let across = (x < 10) != (j % w < 10);
                    let c = if across { 0.05 } else { 2.0 };
                    g.add_edge(i, k, c, c);
                }
            }
        }
        let cut = g.solve();
        for i in 0..w * h {
            assert_eq!(cut.source_side[i], i % w < 10, "pixel {i}");
        }
    }
}
