//! Bounding-volume hierarchy over surfel disks (SPEC 5), built with a binned SAH.
//!
//! Build: every disk gets its exact (slightly padded) AABB; a node's primitives are binned by
//! centroid into 16 bins along each of the three axes, the split with the lowest SAH cost
//! `1 + (A_l N_l + A_r N_r) / A` is taken, and a leaf is made when it is cheaper than splitting
//! and holds at most [`MAX_LEAF`] disks (or when all centroids coincide and few disks remain;
//! otherwise coincident centroids are split at the median). Subtrees larger than
//! [`PAR_THRESHOLD`] disks build their two children in parallel (`rayon::join`), each into its own
//! node vector, which are then appended with their child indices shifted.
//!
//! Layout: a flat depth-first array of 32-byte `#[repr(C)]` `Pod` nodes (a GPU can read it as is).
//! An interior node's left child is the next node and `offset` is the right child; a leaf has
//! `count > 0` disks starting at `offset` in [`Bvh::disks`], which holds the prepared disks in
//! leaf order so a leaf reads one contiguous run of cache lines.

use crate::hit::{disks_of, Disk};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use svgir_core::Surfels;

/// Most disks a leaf holds.
pub const MAX_LEAF: usize = 4;
/// Number of centroid bins of the binned SAH split search.
pub const BINS: usize = 16;
/// Subtrees with more disks than this build their children in parallel.
pub const PAR_THRESHOLD: usize = 8192;
/// Past this depth splits fall back to the median, so traversal stacks stay bounded.
pub const MAX_DEPTH: u32 = 48;
/// Relative padding of primitive boxes (see `Disk::bounds`).
pub const BOX_PAD_REL: f32 = 1e-5;

/// One BVH node, 32 bytes: bounding box plus child offset or leaf range.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Node {
    /// Lower corner of the node's box, world units.
    pub lo: [f32; 3],
    /// Interior: index of the right child. Leaf: first disk in `Bvh::disks`.
    pub offset: u32,
    /// Upper corner of the node's box, world units.
    pub hi: [f32; 3],
    /// 0 for interior nodes, else the number of disks in the leaf.
    pub count: u32,
}

impl Node {
    /// True for a leaf (it holds disks, not children).
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }
}

/// Bounding volume hierarchy over the surfel disks; node 0 is the root.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// Nodes in depth-first order; an interior node's left child follows it.
    pub nodes: Vec<Node>,
    /// Prepared disks in leaf order; `disks[i].id` is the Gaussian index.
    pub disks: Vec<Disk>,
    /// max(s_u, s_v) per Gaussian (Gaussian order), for scale-aware offsets.
    pub max_scales: Vec<f32>,
}

#[derive(Clone, Copy)]
struct Aabb {
    lo: Vec3,
    hi: Vec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb { lo: Vec3::splat(f32::INFINITY), hi: Vec3::splat(f32::NEG_INFINITY) };
    fn grow(&mut self, o: &Aabb) {
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
    }
    fn grow_point(&mut self, p: Vec3) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }
    fn area(&self) -> f32 {
        let d = (self.hi - self.lo).max(Vec3::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
}

struct Ctx {
    boxes: Vec<Aabb>,
    centroids: Vec<Vec3>,
}

enum Split {
    Leaf,
    /// Partition by centroid bin along `axis`: bins < `bin` go left.
    Bin {
        axis: usize,
        bin: usize,
        lo: f32,
        scale: f32,
    },
    Median,
}

#[inline]
fn bin_of(c: f32, lo: f32, scale: f32) -> usize {
    (((c - lo) * scale) as usize).min(BINS - 1)
}

impl Bvh {
    /// Build over all surfels. An empty input gives an empty tree (every ray misses).
    pub fn build(s: &Surfels) -> Self {
        let n = s.len();
        let all = disks_of(s);
        if n == 0 {
            return Self::default();
        }
        let boxes: Vec<Aabb> = (0..n)
            .map(|i| {
                let (lo, hi) = Disk::bounds(s, i, BOX_PAD_REL);
                Aabb { lo, hi }
            })
            .collect();
        let centroids = boxes.iter().map(|b| 0.5 * (b.lo + b.hi)).collect();
        let ctx = Ctx { boxes, centroids };
        let mut idx: Vec<u32> = (0..n as u32).collect();
        let mut nodes = Vec::with_capacity(2 * n / MAX_LEAF + 1);
        build_rec(&ctx, &mut idx, 0, 0, &mut nodes);
        let disks = idx.iter().map(|&i| all[i as usize]).collect();
        let max_scales = all.iter().map(|d| d.max_scale).collect();
        Self { nodes, disks, max_scales }
    }

    /// Depth of the tree: 0 when empty, 1 for a lone leaf.
    pub fn depth(&self) -> usize {
        fn rec(nodes: &[Node], i: usize) -> usize {
            let nd = &nodes[i];
            if nd.is_leaf() {
                1
            } else {
                1 + rec(nodes, i + 1).max(rec(nodes, nd.offset as usize))
            }
        }
        if self.nodes.is_empty() {
            0
        } else {
            rec(&self.nodes, 0)
        }
    }
}

fn build_rec(ctx: &Ctx, idx: &mut [u32], first: u32, depth: u32, out: &mut Vec<Node>) {
    let mut bounds = Aabb::EMPTY;
    let mut cb = Aabb::EMPTY;
    for &i in idx.iter() {
        bounds.grow(&ctx.boxes[i as usize]);
        cb.grow_point(ctx.centroids[i as usize]);
    }
    let me = out.len();
    out.push(Node { lo: bounds.lo.to_array(), offset: first, hi: bounds.hi.to_array(), count: idx.len() as u32 });
    let mid = match choose_split(ctx, idx, &bounds, &cb, depth) {
        Split::Leaf => return,
        Split::Median => idx.len() / 2,
        Split::Bin { axis, bin, lo, scale } => {
            let m = partition(idx, |i| bin_of(ctx.centroids[i as usize][axis], lo, scale) < bin);
            if m == 0 || m == idx.len() {
                idx.len() / 2
            } else {
                m
            }
        }
    };
    out[me].count = 0;
    let parallel = idx.len() > PAR_THRESHOLD;
    let (l, r) = idx.split_at_mut(mid);
    if parallel {
        let (mut lv, mut rv) = rayon::join(
            || {
                let mut v = Vec::new();
                build_rec(ctx, l, first, depth + 1, &mut v);
                v
            },
            || {
                let mut v = Vec::new();
                build_rec(ctx, r, first + mid as u32, depth + 1, &mut v);
                v
            },
        );
        let lbase = out.len() as u32;
        shift(&mut lv, lbase);
        out.extend_from_slice(&lv);
        let rbase = out.len() as u32;
        shift(&mut rv, rbase);
        out.extend_from_slice(&rv);
        out[me].offset = rbase;
    } else {
        build_rec(ctx, l, first, depth + 1, out);
        out[me].offset = out.len() as u32;
        build_rec(ctx, r, first + mid as u32, depth + 1, out);
    }
}

/// Interior nodes of a subtree built on its own store child indices relative to its start.
fn shift(nodes: &mut [Node], base: u32) {
    for nd in nodes.iter_mut().filter(|n| !n.is_leaf()) {
        nd.offset += base;
    }
}

fn choose_split(ctx: &Ctx, idx: &[u32], bounds: &Aabb, cb: &Aabb, depth: u32) -> Split {
    let n = idx.len();
    if n <= 1 {
        return Split::Leaf;
    }
    if depth >= MAX_DEPTH {
        return if n <= MAX_LEAF { Split::Leaf } else { Split::Median };
    }
    let ext = cb.hi - cb.lo;
    let mut best: Option<(f32, usize, usize)> = None;
    for axis in 0..3 {
        if ext[axis].is_nan() || ext[axis] <= 0.0 {
            continue;
        }
        let scale = BINS as f32 / ext[axis];
        let mut bb = [Aabb::EMPTY; BINS];
        let mut cnt = [0usize; BINS];
        for &i in idx {
            let b = bin_of(ctx.centroids[i as usize][axis], cb.lo[axis], scale);
            cnt[b] += 1;
            bb[b].grow(&ctx.boxes[i as usize]);
        }
        // Sweep: right-side areas/counts, then left-to-right evaluation of split planes 1..BINS.
        let mut right_area = [0.0f32; BINS];
        let mut right_cnt = [0usize; BINS];
        let mut acc = Aabb::EMPTY;
        let mut c = 0;
        for b in (1..BINS).rev() {
            acc.grow(&bb[b]);
            c += cnt[b];
            right_area[b] = acc.area();
            right_cnt[b] = c;
        }
        let mut acc = Aabb::EMPTY;
        let mut c = 0;
        for b in 1..BINS {
            acc.grow(&bb[b - 1]);
            c += cnt[b - 1];
            if c == 0 || right_cnt[b] == 0 {
                continue;
            }
            let cost = acc.area() * c as f32 + right_area[b] * right_cnt[b] as f32;
            if best.is_none_or(|(bc, _, _)| cost < bc) {
                best = Some((cost, axis, b));
            }
        }
    }
    let area = bounds.area();
    match best {
        None => {
            // All centroids coincide: nothing to separate them by.
            if n <= MAX_LEAF {
                Split::Leaf
            } else {
                Split::Median
            }
        }
        Some((cost, axis, bin)) => {
            let split_cost = if area > 0.0 { 1.0 + cost / area } else { 1.0 + n as f32 };
            if n <= MAX_LEAF && n as f32 <= split_cost {
                Split::Leaf
            } else {
                Split::Bin { axis, bin, lo: cb.lo[axis], scale: BINS as f32 / ext[axis] }
            }
        }
    }
}

/// In-place partition; returns the number of elements for which `pred` holds (moved to the front).
fn partition(v: &mut [u32], pred: impl Fn(u32) -> bool) -> usize {
    let mut i = 0;
    for j in 0..v.len() {
        if pred(v[j]) {
            v.swap(i, j);
            i += 1;
        }
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::random_scene;

    #[test]
    fn node_is_32_bytes() {
        assert_eq!(std::mem::size_of::<Node>(), 32);
        assert_eq!(std::mem::size_of::<Disk>(), 64);
    }

    #[test]
    fn invariants_hold() {
        for (n, seed) in [(1usize, 1u64), (2, 2), (7, 3), (500, 4), (20000, 5)] {
            let s = random_scene(n, seed);
            let bvh = Bvh::build(&s);
            let mut seen = vec![0u32; n];
            let mut stack = vec![0usize];
            let mut reached = 0;
            while let Some(i) = stack.pop() {
                reached += 1;
                let nd = bvh.nodes[i];
                let (lo, hi) = (Vec3::from_array(nd.lo), Vec3::from_array(nd.hi));
                if nd.is_leaf() {
                    assert!(nd.count as usize <= MAX_LEAF.max(1) || n <= MAX_LEAF);
                    for d in &bvh.disks[nd.offset as usize..(nd.offset + nd.count) as usize] {
                        seen[d.id as usize] += 1;
                        let (blo, bhi) = Disk::bounds(&s, d.id as usize, BOX_PAD_REL);
                        assert!(blo.cmpge(lo).all() && bhi.cmple(hi).all(), "disk outside its leaf");
                    }
                } else {
                    for c in [i + 1, nd.offset as usize] {
                        let ch = bvh.nodes[c];
                        assert!(Vec3::from_array(ch.lo).cmpge(lo).all() && Vec3::from_array(ch.hi).cmple(hi).all());
                        stack.push(c);
                    }
                }
            }
            assert_eq!(reached, bvh.nodes.len(), "every node reachable exactly once");
            assert!(seen.iter().all(|&c| c == 1), "every primitive in exactly one leaf");
            assert!(bvh.depth() <= MAX_DEPTH as usize + 2);
        }
        // Coincident centres (a degenerate but legal input).
        let mut s = random_scene(100, 9);
        let p0 = s.positions[0];
        s.positions.iter_mut().for_each(|p| *p = p0);
        let bvh = Bvh::build(&s);
        assert_eq!(bvh.disks.len(), 100);
        assert!(Bvh::build(&Surfels::default()).nodes.is_empty());
    }

    #[test]
    fn parallel_build_is_deterministic() {
        let s = random_scene(30000, 11);
        let a = Bvh::build(&s);
        let b = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| Bvh::build(&s));
        assert_eq!(a.nodes, b.nodes);
        assert_eq!(a.disks, b.disks);
    }
}
