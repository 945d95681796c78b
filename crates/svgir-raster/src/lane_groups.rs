//! The lane groups of one (tile, Gaussian) entry, which the SIMD tile kernels
//! ([`crate::forward_simd`], [`crate::backward_simd`]) run through: the pixels of the Gaussian's
//! box in the tile, narrowed by the row chords and the live pixels, cut into row pieces of at
//! most `N` pixels and placed in wide or packed groups ([`Group`]).
//!
//! Work split: one entry at a time, inside the tile kernel's task. Per block of `N` box rows in
//! lanes: the rows' chords and their pixel spans; then per row, without branches, the live span
//! and its pieces, written as [`GroupSlot`]s. The forward keeps its groups for the backward
//! ([`crate::ForwardStateOf::tile_groups`]), which lists an entry itself only when the forward
//! kept none at its width (then from the pixels that composited the entry).

// The lane methods are `unsafe fn`s with one contract -- the CPU has the features of the path
// that runs them (checked once by `Simd::resolve`) and every pointer stays inside its buffer --
// so the operations inside need no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]

use crate::simd::Lanes;
use crate::tiles::{EntryBox, TileRec};

/// One lane group of a (tile, Gaussian) entry: pixels of the Gaussian's box, narrowed by the
/// row chords and the live pixels, in one of two shapes. A *wide* group is up to `N` consecutive
/// pixels of one row. A *packed* group is two halves of up to `N/2` consecutive pixels each, on
/// two different rows: most splats of a trained scene cover row segments of one to four pixels,
/// and packing two of them fills the lanes that a wide group would leave idle (on the bench's
/// random 100k-surfel scene at 400x400, before early stopping, 8-lane groups fill 49% of their
/// lanes with wide groups alone and 68% with packing; docs/performance.md).
///
/// An entry's groups are listed first ([`Groups::list`]) and then run through a branch-free lane
/// loop, so the out-of-order core overlaps the long dependency chains of neighbouring groups
/// instead of stalling on a mispredicted branch between them.
#[derive(Clone, Copy, Default)]
pub(crate) struct Group {
    /// Each half's row centre y.
    pub yf: [f32; 2],
    /// Centre x of each half's first pixel.
    pub x0: [f32; 2],
    /// Index of each half's first pixel in the tile arrays (`row * stride + column`).
    pub at: [u32; 2],
    /// Each half's row in the tile.
    pub ry: [u16; 2],
    /// Each half's first column in the tile.
    pub c0: [u16; 2],
    /// Live lanes.
    pub lb: u32,
}

impl Group {
    /// The lanes' pixel-centre x.
    #[inline(always)]
    pub(crate) unsafe fn x<S: Lanes, const PACKED: bool>(&self) -> S {
        if PACKED {
            S::halves(self.x0[0], self.x0[1]).add(S::iota2())
        } else {
            S::splat(self.x0[0]).add(S::iota())
        }
    }

    /// The lanes' row centre y.
    #[inline(always)]
    pub(crate) unsafe fn y<S: Lanes, const PACKED: bool>(&self) -> S {
        if PACKED {
            S::halves(self.yf[0], self.yf[1])
        } else {
            S::splat(self.yf[0])
        }
    }

    /// The lanes of tile array `p`.
    #[inline(always)]
    pub(crate) unsafe fn load<S: Lanes, const PACKED: bool>(&self, p: *const f32) -> S {
        if PACKED {
            S::load2(p.add(self.at[0] as usize), p.add(self.at[1] as usize))
        } else {
            S::load(p.add(self.at[0] as usize))
        }
    }

    /// Stores `v` to the lanes of tile array `p`.
    #[inline(always)]
    pub(crate) unsafe fn store<S: Lanes, const PACKED: bool>(&self, p: *mut f32, v: S) {
        if PACKED {
            v.store2(p.add(self.at[0] as usize), p.add(self.at[1] as usize))
        } else {
            v.store(p.add(self.at[0] as usize))
        }
    }

    /// `*p += d` on the lanes of `m`.
    #[inline(always)]
    pub(crate) unsafe fn add_masked<S: Lanes, const PACKED: bool>(&self, p: *mut f32, m: S::M, d: S) {
        let v = self.load::<S, PACKED>(p);
        self.store::<S, PACKED>(p, S::select(m, v.add(d), v));
    }

    /// `*p = a * b + *p` with one rounding (FMA) on the lanes of `m`.
    #[inline(always)]
    pub(crate) unsafe fn fma_masked<S: Lanes, const PACKED: bool>(&self, p: *mut f32, m: S::M, a: S, b: S) {
        let v = self.load::<S, PACKED>(p);
        self.store::<S, PACKED>(p, S::select(m, a.mul_add(b, v), v));
    }

    /// `*p = d` on the lanes of `m`.
    #[inline(always)]
    pub(crate) unsafe fn set_masked<S: Lanes, const PACKED: bool>(&self, p: *mut f32, m: S::M, d: S) {
        if PACKED {
            d.store2_where(m, p.add(self.at[0] as usize), p.add(self.at[1] as usize))
        } else {
            d.store_where(m, p.add(self.at[0] as usize))
        }
    }

    /// Clears the lanes set in `bits` from the per-row column masks `rows`.
    #[inline(always)]
    pub(crate) fn clear<const PACKED: bool>(&self, rows: &mut [u64], bits: u32, n: usize) {
        if PACKED {
            let h = n / 2;
            let lo = bits & ((1u32 << h) - 1);
            rows[self.ry[0] as usize] &= !((lo as u64) << self.c0[0]);
            rows[self.ry[1] as usize] &= !(((bits >> h) as u64) << self.c0[1]);
        } else {
            rows[self.ry[0] as usize] &= !((bits as u64) << self.c0[0]);
        }
    }
}

/// A listed group ([`Groups::list`]) in six bytes, as the forward keeps it for the backward:
/// the row and first column of each half in the tile (tiles are at most 64 pixels a side: the
/// row masks are `u64`; both halves of a wide group are the same), and the live lanes.
/// [`GroupSlot::group`] builds the [`Group`] that runs. (Packed into four bytes, the backward
/// ran slower.)
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GroupSlot {
    ry: [u8; 2],
    c0: [u8; 2],
    lb: u16,
}

/// Where an entry's kept groups lie in its tile's [`GroupSlot`]s: `wide` wide groups from
/// `start`, then `packed` packed ones. An entry the forward did not list keeps none.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EntryGroups {
    pub(crate) start: u32,
    pub(crate) wide: u16,
    pub(crate) packed: u16,
}

impl GroupSlot {
    /// The group in the tile whose first pixel centre is `origin` (`x + 0.5, y + 0.5`), its rows
    /// `stride` apart. The centres are exact: integers and halves below 2^22.
    #[inline(always)]
    pub(crate) fn group(&self, origin: [f32; 2], stride: usize) -> Group {
        let (ry, c0) = (self.ry.map(usize::from), self.c0.map(usize::from));
        Group {
            yf: self.ry.map(|r| origin[1] + f32::from(r)),
            x0: self.c0.map(|c| origin[0] + f32::from(c)),
            at: [0, 1].map(|i| (ry[i] * stride + c0[i]) as u32),
            ry: ry.map(|r| r as u16),
            c0: c0.map(|c| c as u16),
            lb: u32::from(self.lb),
        }
    }
}

/// Lists the lane groups of one entry at a time ([`Groups::list`]), into a vector of
/// [`GroupSlot`]s that the caller keeps (the forward, for the backward) or that the lister owns
/// ([`Groups::list_here`]: the backward's own listing).
pub(crate) struct Groups {
    /// Short row pieces (at most `n/2` pixels), to be paired.
    short: Vec<GroupSlot>,
    /// The lister's own groups ([`Groups::list_here`]).
    own: Vec<GroupSlot>,
    /// The row chords' pixels `[xa, xb)` of the entry's box rows ([`chord_pixels_lanes`]).
    xa: Vec<i32>,
    xb: Vec<i32>,
}

impl EntryGroups {
    /// The entry's wide and packed groups in `slots` (its tile's).
    #[inline(always)]
    pub(crate) fn split<'a>(&self, slots: &'a [GroupSlot]) -> (&'a [GroupSlot], &'a [GroupSlot]) {
        slots[self.start as usize..][..self.wide as usize + self.packed as usize].split_at(self.wide as usize)
    }
}

impl Groups {
    /// Lists for tiles of side up to `tile`.
    pub(crate) fn new(tile: usize) -> Self {
        // Chords are stored a whole lane group at a time.
        let len = tile + MAX_LANES;
        Self { short: Vec::new(), own: Vec::new(), xa: vec![0; len], xb: vec![0; len] }
    }

    /// [`Groups::list`] into the lister's own vector, replacing the last entry's groups; the
    /// wide and the packed groups, or `None` when no pixel of the box is live.
    #[inline(always)]
    pub(crate) unsafe fn list_here<S: Lanes>(
        &mut self,
        s: &TileRec<f32>,
        tr: &[u32; 4],
        live: &[u64],
    ) -> Option<(&[GroupSlot], &[GroupSlot])> {
        let mut own = std::mem::take(&mut self.own);
        own.clear();
        let at = self.list::<S>(s, tr, live, &mut own);
        self.own = own;
        at.map(|at| at.split(&self.own))
    }
}

/// The widest lane type.
const MAX_LANES: usize = 16;

/// [`crate::splat::RowConic::chord`] for the rows with centres `y`, lane by lane (the same
/// operations; where the scalar code branches, the lanes select).
#[inline(always)]
unsafe fn chord_lanes<S: Lanes>(conic: &crate::splat::RowConic, c: [f32; 2], y: S) -> (S, S) {
    let sp = |v: f32| S::splat(v);
    let (k, disk_r2) = conic.coefficients();
    let t = y.sub(sp(c[1]));
    let bh = sp(k[0]).add(t.mul(sp(k[1])));
    let ch = sp(k[2]).add(t.mul(sp(k[3]).add(t.mul(sp(k[4])))));
    let disc = bh.mul(bh).sub(ch);
    let e2 = sp(disk_r2).sub(t.mul(t));
    // The square roots of negative lanes are NaN and selected away.
    let (has, sq) = (disc.ge(sp(0.0)), disc.sqrt());
    let mid = sp(c[0]).sub(bh);
    let lo = S::select(has, mid.sub(sq), sp(f32::INFINITY));
    let hi = S::select(has, mid.add(sq), sp(f32::NEG_INFINITY));
    let (hasd, e) = (e2.ge(sp(0.0)), e2.sqrt());
    let (a, b) = (sp(c[0]).sub(e), sp(c[0]).add(e));
    // f32::min / max: the other operand when it is smaller / larger (a NaN never is).
    let lo = S::select(S::and(hasd, a.lt(lo)), a, lo);
    let hi = S::select(S::and(hasd, b.gt(hi)), b, hi);
    (lo, hi)
}

/// [`crate::splat::chord_pixels`] lane by lane, for the box columns `[x0, x1)`: the same
/// operations in f32, whose integers are exact here (below 2^24), then truncated to i32; a chord
/// that misses the row gives the empty span `[x0, x0)`.
#[inline(always)]
unsafe fn chord_pixels_lanes<S: Lanes>(lo: S, hi: S, x0: usize, x1: usize) -> (S, S) {
    let (fx0, fx1) = (S::splat(x0 as f32), S::splat(x1 as f32));
    // `floor_clamped`: f32::max then f32::min (a NaN clamps to the low end), then truncation.
    let clamp = |v: S| fx1.min(fx0.max(v)).trunc();
    let one = S::splat(1.0);
    let a = lo.sub(S::splat(1.5));
    let t = clamp(a);
    let lo_px = S::select(t.lt(a), t.add(one), t).min(fx1);
    let hi_px = clamp(hi.add(S::splat(0.5))).add(one).min(fx1);
    let hi_px = hi_px.max(lo_px);
    let full = lo.le(hi);
    (S::select(full, lo_px, fx0), S::select(full, hi_px, fx0))
}

impl Groups {
    /// Lists the `n`-lane groups of entry `s` clipped to the tile with pixel rectangle `tr`,
    /// where `live[row]` marks the tile's live columns, and appends them to `out`: the wide groups, then the packed ones. The row pieces of at most
    /// `n/2` pixels are paired in order into packed groups; an odd one out is the last wide one.
    ///
    /// Listing was a third of the tile kernels' time, so it is kept lean: the chord pixels of
    /// `N` rows at a time in lanes, then per row no branch (an empty row gives one empty piece,
    /// written and not counted; a piece is written to both lists and counted in the one it
    /// belongs to; only a row longer than `n` pixels loops).
    ///
    /// Returns `None`, with nothing appended, when no pixel of the box is live: nothing is left
    /// for the entry in this tile (in the forward, boxes behind pixels that have all finished).
    #[inline(always)]
    pub(crate) unsafe fn list<S: Lanes>(
        &mut self,
        s: &TileRec<f32>,
        tr: &[u32; 4],
        live: &[u64],
        out: &mut Vec<GroupSlot>,
    ) -> Option<EntryGroups> {
        let n = S::N;
        const { assert!(S::N <= 16, "a group's live lanes are sixteen bits of its slot") };
        let (tx0, ty0) = (tr[0] as usize, tr[2] as usize);
        let bx = EntryBox::new(s, tr);
        if !bx.any_live(live, ty0) {
            return None;
        }
        let rows = bx.rows.clone();
        let bounded = s.conic.bounded();
        if bounded {
            // The row chords and their pixels, N rows at a time (the scalar operations lane by
            // lane).
            let (x0, x1) = bx.columns();
            let mut y = rows.start;
            while y < rows.end {
                let yl = S::splat((y as f64 + 0.5) as f32).add(S::iota());
                let (lo, hi) = chord_lanes(&s.conic, bx.center(), yl);
                let (xa, xb) = chord_pixels_lanes(lo, hi, x0, x1);
                let i = y - rows.start;
                xa.store_i32(self.xa.as_mut_ptr().add(i));
                xb.store_i32(self.xb.as_mut_ptr().add(i));
                y += S::N;
            }
        }
        // At most one piece per `n` columns of the tile on every row, and one per empty row.
        let cap = rows.len() * ((tr[1] - tr[0]) as usize / n + 2);
        let start = out.len();
        out.reserve(cap + 1);
        self.short.clear();
        self.short.reserve(cap);
        let (wide, short) = (out.as_mut_ptr().add(start), self.short.as_mut_ptr());
        let (mut nw, mut ns) = (0usize, 0usize);
        for y in rows.clone() {
            let ry = y - ty0;
            let lv = live[ry];
            let i = y - rows.start;
            let chord = bounded.then(|| (self.xa[i] as usize, self.xb[i] as usize));
            // `[xa, xb)`: the live span, empty (`xa == xb`) when the row has none.
            let (xa, xb) = bx.live_span_or_empty(chord, lv);
            let mut k = xa;
            loop {
                let (c0, lanes) = (k - tx0, (xb - k).min(n));
                let lb = (lv >> c0) as u32 & ((1u64 << lanes) - 1) as u32;
                let piece = GroupSlot { ry: [ry as u8; 2], c0: [c0 as u8; 2], lb: lb as u16 };
                // SAFETY: at most `cap` pieces are written (see above), within the reserves.
                wide.add(nw).write(piece);
                short.add(ns).write(piece);
                let (is_short, some) = (lanes <= n / 2, lb != 0);
                nw += (some && !is_short) as usize;
                ns += (some && is_short) as usize;
                k += n;
                if k >= xb {
                    break;
                }
            }
        }
        // SAFETY: the first `nw` / `ns` slots were written above.
        out.set_len(start + nw);
        self.short.set_len(ns);
        // Short pieces in pairs, in order; an odd one out is a wide group.
        if ns % 2 == 1 {
            out.push(self.short[ns - 1]);
        }
        let h = n / 2;
        out.extend(self.short.chunks_exact(2).map(|p| GroupSlot {
            ry: [p[0].ry[0], p[1].ry[0]],
            c0: [p[0].c0[0], p[1].c0[0]],
            lb: p[0].lb | (p[1].lb << h),
        }));
        Some(EntryGroups { start: start as u32, wide: (nw + ns % 2) as u16, packed: (ns / 2) as u16 })
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::fixtures::Problem;
    use crate::preprocess::{preprocess, Cam};
    use crate::simd::F8;
    use crate::tiles::{bin, gather_records};
    use crate::RasterConfig;
    use svgir_core::rng::Rng;

    /// Every pixel the scalar kernels visit (box rows narrowed by the chord and the live masks)
    /// lies in exactly one lane group, at the right x, y and tile index; and small
    /// splats do produce packed groups.
    #[test]
    fn groups_cover_the_scalar_spans_once() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: lane groups not checked");
            return;
        }
        let p = Problem::new(3000, 96);
        let input = p.input();
        let cfg = RasterConfig::default();
        let cam = Cam::<f32>::new(input.camera);
        let (splats, _) = preprocess(input.surfels, &cam, &input.colors, &cfg);
        let bins = bin(&splats, cam.width, cam.height, cfg.tile);
        let recs = gather_records(&bins, &splats, None);
        let tile = cfg.tile as usize;
        let stride = tile + 8;
        let mut groups = Groups::new(tile);
        let mut rng = Rng::new(5);
        let (mut packed, mut pixels) = (0, 0);
        for t in 0..bins.ranges.len() {
            let tr = bins.tile_rect(t, cam.width, cam.height);
            let [r0, r1] = bins.ranges[t];
            for s in &recs[r0 as usize..r1 as usize] {
                // Random live columns (three in four), one row in eight dead.
                let live: Vec<u64> = (0..tile)
                    .map(|_| if rng.next_u64().is_multiple_of(8) { 0 } else { rng.next_u64() | rng.next_u64() })
                    .collect();
                let mut want = std::collections::BTreeSet::new();
                let bx = EntryBox::new(s, &tr);
                for y in bx.rows.clone() {
                    let ry = y - tr[2] as usize;
                    if let Some((_, xa, xb)) = bx.row_span::<f32>(&s.conic, y, live[ry]) {
                        for x in xa..xb {
                            if live[ry] >> (x - tr[0] as usize) & 1 == 1 {
                                want.insert((y, x));
                            }
                        }
                    }
                }
                // Listed after the groups of earlier entries (three here), as the forward keeps
                // a tile's groups.
                let mut kept = vec![GroupSlot::default(); 3];
                let at = unsafe { groups.list::<F8>(s, &tr, &live, &mut kept) };
                let origin = [tr[0] as f32 + 0.5, tr[2] as f32 + 0.5];
                let (wide, packed_groups) = match at {
                    Some(at) => {
                        assert_eq!(at.start, 3);
                        assert_eq!(kept.len(), 3 + at.wide as usize + at.packed as usize);
                        at.split(&kept)
                    }
                    None => (&[][..], &[][..]),
                };
                let mut got = std::collections::BTreeSet::new();
                let mut lanes = |g: &Group, is_packed: bool| {
                    let (mut xs, mut ys) = ([0f32; 8], [0f32; 8]);
                    unsafe {
                        let x = if is_packed { g.x::<F8, true>() } else { g.x::<F8, false>() };
                        x.store(xs.as_mut_ptr());
                        let y = if is_packed { g.y::<F8, true>() } else { g.y::<F8, false>() };
                        y.store(ys.as_mut_ptr());
                    }
                    for l in 0..8 {
                        if g.lb >> l & 1 == 0 {
                            continue;
                        }
                        let (h, col) = if is_packed { (l / 4, l % 4) } else { (0, l) };
                        let (ry, c) = (g.ry[h] as usize, g.c0[h] as usize + col);
                        let (y, x) = (ry + tr[2] as usize, c + tr[0] as usize);
                        assert_eq!(g.at[h] as usize + col, ry * stride + c, "tile index");
                        assert_eq!(xs[l], x as f32 + 0.5, "pixel centre");
                        assert_eq!(ys[l], y as f32 + 0.5, "row centre");
                        assert!(got.insert((y, x)), "pixel ({x}, {y}) in two groups");
                    }
                };
                for g in wide.iter().map(|g| g.group(origin, stride)) {
                    lanes(&g, false);
                }
                for g in packed_groups.iter().map(|g| g.group(origin, stride)) {
                    assert_ne!(g.ry[0], g.ry[1], "a packed group's halves share a row");
                    lanes(&g, true);
                }
                packed += packed_groups.len();
                pixels += want.len();
                assert_eq!(got, want, "entry {} of tile {t}", s.id);
            }
        }
        assert!(pixels > 10_000 && packed > 1000, "too few pixels ({pixels}) or packed groups ({packed})");
    }

    /// The chord pixels in lanes are the scalar ones, row by row, empty chords and NaN included.
    #[test]
    fn chord_pixels_lanes_are_the_scalar_ones() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: lane chord pixels not checked");
            return;
        }
        let mut rng = Rng::new(7);
        let special = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -3.0, 0.0, 0.5, 31.5, 64.0, 1e9];
        let mut value = |k: usize| {
            if k.is_multiple_of(5) {
                special[k / 5 % special.len()]
            } else {
                rng.uniform() * 80.0 - 10.0
            }
        };
        let mut nonempty = 0;
        for round in 0..4000 {
            let lo: [f32; 8] = std::array::from_fn(|l| value(round * 8 + l));
            let hi: [f32; 8] = std::array::from_fn(|l| value(round * 3 + l + 1));
            let x0 = round % 40;
            let x1 = x0 + round * 7 % 33;
            let (mut xa, mut xb) = ([0i32; 8], [0i32; 8]);
            unsafe {
                let (a, b) = chord_pixels_lanes(F8::load(lo.as_ptr()), F8::load(hi.as_ptr()), x0, x1);
                a.store_i32(xa.as_mut_ptr());
                b.store_i32(xb.as_mut_ptr());
            }
            for l in 0..8 {
                let want = crate::splat::chord_pixels(lo[l], hi[l], x0, x1);
                let got = (xa[l] as usize, xb[l] as usize);
                let what = format!("lo {} hi {} x0 {x0} x1 {x1}: {got:?} vs {want:?}", lo[l], hi[l]);
                if want.0 == want.1 {
                    // Empty: any empty span inside the box will do.
                    assert!(got.0 == got.1 && (x0..=x1).contains(&got.0), "{what}");
                } else {
                    assert_eq!(got, want, "{what}");
                    nonempty += 1;
                }
            }
        }
        assert!(nonempty > 10_000, "only {nonempty} non-empty chords");
    }
}
