//! Binning of visible Gaussians into screen tiles, each tile's list sorted front to back by
//! (centre depth, id) -- never depth alone, so ties are deterministic (SPEC 1, 9.9).
//!
//! Work split: one parallel radix sort of the visible Gaussians by a unique u64 key, then a
//! counting sort into tiles, chunk-parallel over the sorted keys (so every tile list comes out
//! sorted).
//! Saved for backward: the whole [`TileBins`], including for each Gaussian the positions of its
//! entries in the flat list, which lets per-entry gradients be reduced per Gaussian in a fixed
//! order without atomics or racy `+=` (SPEC 9.4). The tile kernels read a copy of each
//! Gaussian's hot data per entry ([`TileRec`], gathered in parallel after binning) so that they
//! stream through memory instead of chasing Gaussian ids.

use crate::preprocess::Splat;
use rayon::prelude::*;
use svgir_core::par::Disjoint;
use svgir_core::Float;

/// The sort key: depth (as f32, whose bit pattern orders positive values) then id.
#[inline]
pub fn sort_key<F: Float>(depth: F, id: u32) -> u64 {
    let d = depth.to_f32().max(0.0);
    ((d.to_bits() as u64) << 32) | id as u64
}

/// What the tile kernels read for one (tile, Gaussian) entry.
#[derive(Clone, Copy, Debug, Default)]
pub struct TileRec<F> {
    /// Rows `T_u, T_v, T_w` of H, row-major.
    pub h: [F; 9],
    /// Projected centre, pixels.
    pub center: [F; 2],
    /// Opacity `o` (after the sigmoid).
    pub opacity: F,
    /// World normal flipped to face the camera.
    pub normal: [F; 3],
    /// The colour when the colour source has one vertex (SH or constant features).
    pub color: [F; 3],
    /// The splat's pixel box `[x0, x1, y0, y1]`, ends exclusive.
    pub rect: [u32; 4],
    /// The splat's per-row chords (culling bound, [`crate::splat::RowConic`]).
    pub conic: crate::splat::RowConic,
    /// The Gaussian's index.
    pub id: u32,
}

/// Per-entry records for `bins.ids` (colour from `colors` when it has one vertex per Gaussian).
///
/// Scattered Gaussian by Gaussian through `bins.entries` rather than gathered entry by entry:
/// the splats are then read in order and the records written at their positions, independent
/// stores the core overlaps, where the gather's reads of splats in tile order missed the cache
/// one after another (400x400 / 100k, 2 threads: 10.1 -> 7.5 ms; docs/performance.md).
pub fn gather_records<F: Float>(bins: &TileBins, splats: &[Splat<F>], colors: Option<&[F]>) -> Vec<TileRec<F>> {
    let n = bins.ids.len();
    // `bin` lays out `entries` as a permutation of `0..n` split by `entry_offsets`.
    assert!(
        bins.entries.len() == n
            && bins.entry_offsets.len() == splats.len() + 1
            && bins.entry_offsets.last().is_some_and(|&e| e as usize == n),
        "tile bins do not match the splats"
    );
    let mut recs: Vec<TileRec<F>> = Vec::with_capacity(n);
    let out = SharedSlice(recs.as_mut_ptr());
    // The slots of the Gaussian `AHEAD` places on are prefetched for writing: they are scattered
    // over the tiles, so the hardware prefetcher cannot guess them.
    const AHEAD: usize = 8;
    let prefetch_slots = |g: usize| {
        if g < splats.len() {
            let (a, b) = (bins.entry_offsets[g] as usize, bins.entry_offsets[g + 1] as usize);
            for &pos in &bins.entries[a..b] {
                let p = out.at(pos as usize);
                prefetch::<true, _>(p);
                prefetch::<true, _>((p as *const u8).wrapping_add(std::mem::size_of::<TileRec<F>>() - 1));
            }
        }
    };
    splats.par_iter().enumerate().with_min_len(1024).for_each(|(g, s)| {
        prefetch_slots(g + AHEAD);
        let (a, b) = (bins.entry_offsets[g] as usize, bins.entry_offsets[g + 1] as usize);
        if a == b {
            return;
        }
        let color = colors.map_or([F::ZERO; 3], |c| {
            let i = g * 3;
            [c[i], c[i + 1], c[i + 2]]
        });
        let rec = TileRec {
            h: s.h,
            center: s.center,
            opacity: s.opacity,
            normal: s.normal,
            color,
            rect: s.rect,
            conic: s.conic,
            id: g as u32,
        };
        for &pos in &bins.entries[a..b] {
            // SAFETY: `entries` holds every position below `n` exactly once (`bin`), so the
            // writes are disjoint and in bounds.
            unsafe { out.write(pos as usize, rec) };
        }
    });
    // SAFETY: every one of the `n` slots was written above.
    unsafe { recs.set_len(n) };
    recs
}

/// Tile lists in one flat array.
#[derive(Clone, Debug, Default)]
pub struct TileBins {
    /// Tile side in pixels.
    pub tile: u32,
    /// Number of tile columns (tiles across the width).
    pub tiles_x: u32,
    /// Number of tile rows (tiles down the height).
    pub tiles_y: u32,
    /// Per tile (row-major), the range of `ids`.
    pub ranges: Vec<[u32; 2]>,
    /// Gaussian ids, tile by tile, each tile front to back.
    pub ids: Vec<u32>,
    /// Gaussian g's entries are `entries[entry_offsets[g]..entry_offsets[g + 1]]` (positions in
    /// `ids`, in tile order).
    pub entry_offsets: Vec<u32>,
    /// Positions in `ids` of each Gaussian's entries, grouped by Gaussian (see `entry_offsets`).
    pub entries: Vec<u32>,
}

impl TileBins {
    /// Entries (Gaussians) binned to tile `t`.
    pub fn entry_count(&self, t: usize) -> usize {
        let [a, b] = self.ranges[t];
        (b - a) as usize
    }

    /// Pixel rectangle `[x0, x1, y0, y1]` of tile `t`.
    pub fn tile_rect(&self, t: usize, width: u32, height: u32) -> [u32; 4] {
        let tx = t as u32 % self.tiles_x;
        let ty = t as u32 / self.tiles_x;
        let x0 = tx * self.tile;
        let y0 = ty * self.tile;
        [x0, (x0 + self.tile).min(width), y0, (y0 + self.tile).min(height)]
    }

    /// Range of `ids` covered by tile row `ty`.
    pub fn row_range(&self, ty: u32) -> [u32; 2] {
        let a = (ty * self.tiles_x) as usize;
        let b = a + self.tiles_x as usize - 1;
        [self.ranges[a][0], self.ranges[b][1]]
    }
}

#[inline]
fn tile_span(s: &[u32; 4], tile: u32) -> [u32; 4] {
    [s[0] / tile, (s[1] - 1) / tile + 1, s[2] / tile, (s[3] - 1) / tile + 1]
}

/// Bins the visible splats into `tile`-pixel tiles of a `width` x `height` image.
pub fn bin<F: Float>(splats: &[Splat<F>], width: u32, height: u32, tile: u32) -> TileBins {
    let tiles_x = width.div_ceil(tile);
    let tiles_y = height.div_ceil(tile);
    let ntiles = (tiles_x * tiles_y) as usize;
    // Tile spans and depths in compact arrays, in one pass over the (large) splats: the sort
    // keys are built from them, and the fill below reads the spans in depth order, i.e. randomly.
    let (spans, depths): (Vec<[u32; 4]>, Vec<F>) = splats
        .par_iter()
        .with_min_len(4096)
        .map(|s| if s.visible() { (tile_span(&s.rect, tile), s.depth) } else { ([0; 4], F::ZERO) })
        .unzip();
    // A span is empty exactly when the splat is culled (its box is empty).
    let keys: Vec<u64> = (0..splats.len())
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&i| spans[i][0] < spans[i][1])
        .map(|i| sort_key(depths[i], i as u32))
        .collect();
    // The keys are built in id order, so a stable sort on the depth half gives (depth, id) order.
    let keys = radix_sort_high(keys);
    let mut entry_offsets = vec![0u32; splats.len() + 1];
    for (g, r) in spans.iter().enumerate() {
        entry_offsets[g + 1] = entry_offsets[g] + (r[1] - r[0]) * (r[3] - r[2]);
    }
    // A parallel counting sort: the depth-sorted keys are cut into chunks; each chunk counts its
    // entries per tile, the counts give every (chunk, tile) its first slot, and the chunks fill
    // their slots at once. Chunks are in key order, so each tile list comes out in key order,
    // the same lists as one sequential fill.
    let chunk = keys.len().div_ceil(4 * rayon::current_num_threads()).max(4096);
    const AHEAD: usize = 8;
    let chunk_counts: Vec<Vec<u32>> = keys
        .par_chunks(chunk)
        .map(|ks| {
            let mut c = vec![0u32; ntiles];
            for (i, &key) in ks.iter().enumerate() {
                // The keys are in depth order, so their spans are read at random: prefetched.
                if let Some(&k) = ks.get(i + AHEAD) {
                    prefetch::<false, _>(&spans[(k & 0xffff_ffff) as usize]);
                }
                let r = spans[(key & 0xffff_ffff) as usize];
                for ty in r[2]..r[3] {
                    for tx in r[0]..r[1] {
                        c[(ty * tiles_x + tx) as usize] += 1;
                    }
                }
            }
            c
        })
        .collect();
    let mut ranges = Vec::with_capacity(ntiles);
    let mut cursors: Vec<Vec<u32>> = vec![vec![0; ntiles]; chunk_counts.len()];
    let mut acc = 0u32;
    for t in 0..ntiles {
        let start = acc;
        for (c, counts) in chunk_counts.iter().enumerate() {
            cursors[c][t] = acc;
            acc += counts[t];
        }
        ranges.push([start, acc]);
    }
    let total = acc as usize;
    let mut ids = svgir_core::par::filled(total, 0u32);
    let mut entries = svgir_core::par::filled(total, 0u32);
    {
        let (ids_p, entries_p) = (SharedSlice(ids.as_mut_ptr()), SharedSlice(entries.as_mut_ptr()));
        keys.par_chunks(chunk).zip(cursors.par_iter_mut()).for_each(|(ks, cursor)| {
            for (i, &key) in ks.iter().enumerate() {
                if let Some(&k) = ks.get(i + AHEAD) {
                    let g = (k & 0xffff_ffff) as usize;
                    prefetch::<false, _>(&spans[g]);
                    prefetch::<false, _>(&entry_offsets[g]);
                }
                let g = (key & 0xffff_ffff) as usize;
                let r = spans[g];
                let mut e = entry_offsets[g] as usize;
                for ty in r[2]..r[3] {
                    for tx in r[0]..r[1] {
                        let t = (ty * tiles_x + tx) as usize;
                        let pos = cursor[t];
                        cursor[t] += 1;
                        // SAFETY: every (chunk, tile) owns the slots from its cursor start up
                        // to its count, and each Gaussian owns its entry range, so no two
                        // writes hit the same index; all indices are below `total`.
                        unsafe {
                            ids_p.write(pos as usize, g as u32);
                            entries_p.write(e, pos);
                        }
                        e += 1;
                    }
                }
            }
        });
    }
    TileBins { tile, tiles_x, tiles_y, ranges, ids, entry_offsets, entries }
}

/// Stable LSD radix sort of `keys` by their upper 32 bits (8 bits a pass; a pass whose byte is
/// the same in every key is skipped). Ties keep their order, so keys built in id order come out
/// sorted by the whole key. Several times faster than a comparison sort of 100k keys.
///
/// Each pass runs on the rayon workers: the keys are cut into chunks, each chunk counts its
/// bytes, the counts give every (chunk, byte) its own run of the output (byte-major, chunks in
/// order, which keeps the sort stable), and the chunks scatter into their runs at once. Below
/// `RADIX_CHUNK` keys there is one chunk, the serial sort.
pub fn radix_sort_high(mut keys: Vec<u64>) -> Vec<u64> {
    let n = keys.len();
    let chunk = n.div_ceil(2 * rayon::current_num_threads()).max(RADIX_CHUNK);
    let mut tmp = svgir_core::par::filled(n, 0u64);
    for pass in 0..4 {
        let shift = 32 + 8 * pass;
        let byte = |k: u64| (k >> shift) as usize & 255;
        let counts: Vec<[u32; 256]> = keys
            .par_chunks(chunk)
            .map(|ks| {
                let mut c = [0u32; 256];
                for &k in ks {
                    c[byte(k)] += 1;
                }
                c
            })
            .collect();
        // Where each (chunk, byte) run starts: all smaller bytes first, then earlier chunks.
        let mut starts = vec![[0u32; 256]; counts.len()];
        let mut acc = 0u32;
        let mut skip = false;
        for b in 0..256 {
            let before = acc;
            for (c, cnt) in counts.iter().enumerate() {
                starts[c][b] = acc;
                acc += cnt[b];
            }
            skip |= (acc - before) as usize == n;
        }
        if skip {
            continue;
        }
        let out = Disjoint::new(&mut tmp);
        keys.par_chunks(chunk).zip(&starts).zip(&counts).for_each(|((ks, start), cnt)| {
            // SAFETY: the runs of different (chunk, byte) pairs do not overlap, and together
            // they tile `0..n`.
            let mut runs: Vec<&mut [u64]> =
                (0..256).map(|b| unsafe { out.seg(start[b] as usize, cnt[b] as usize) }).collect();
            let mut next = [0usize; 256];
            for &k in ks {
                let b = byte(k);
                runs[b][next[b]] = k;
                next[b] += 1;
            }
        });
        std::mem::swap(&mut keys, &mut tmp);
    }
    keys
}

/// Keys per chunk of the parallel radix sort, at least (smaller sorts run on one thread, where
/// waking the workers would cost more than it saves).
const RADIX_CHUNK: usize = 1 << 14;

/// A hint to fetch the cache line at `p`, for writing when `WRITE` (x86-64; nothing elsewhere).
#[inline(always)]
pub(crate) fn prefetch<const WRITE: bool, T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch never faults, whatever the address.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_ET0, _MM_HINT_T0};
        if WRITE {
            _mm_prefetch::<_MM_HINT_ET0>(p as *const i8)
        } else {
            _mm_prefetch::<_MM_HINT_T0>(p as *const i8)
        }
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// A pointer that parallel tasks write through at indices they own alone.
struct SharedSlice<T>(*mut T);
// SAFETY: only used for writes at disjoint indices (see `bin` and `gather_records`).
unsafe impl<T: Send> Send for SharedSlice<T> {}
unsafe impl<T: Send> Sync for SharedSlice<T> {}

impl<T> Clone for SharedSlice<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for SharedSlice<T> {}

impl<T> SharedSlice<T> {
    /// The address of index `i` (for prefetching; not dereferenced).
    fn at(self, i: usize) -> *const T {
        self.0.wrapping_add(i)
    }

    /// # Safety
    /// `i` is in bounds and no other task reads or writes index `i` meanwhile.
    unsafe fn write(self, i: usize, v: T) {
        // SAFETY: the caller's contract.
        unsafe { self.0.add(i).write(v) }
    }
}

/// One tile entry's box clipped to its tile, and the per-row culling every tile kernel (scalar
/// and SIMD, forward and backward) starts a row with.
pub(crate) struct EntryBox {
    /// Pixel columns `[x0, x1)` of the box inside the tile.
    x0: usize,
    x1: usize,
    /// Pixel rows of the box inside the tile.
    pub rows: std::ops::Range<usize>,
    /// The projected centre in f32, as the row chords take it.
    c32: [f32; 2],
    /// The tile's first column.
    tx0: usize,
}

impl EntryBox {
    /// The box of entry `s` inside the tile with pixel rectangle `tr`.
    #[inline(always)]
    pub(crate) fn new<F: Float>(s: &TileRec<F>, tr: &[u32; 4]) -> Self {
        Self {
            x0: s.rect[0].max(tr[0]) as usize,
            x1: s.rect[1].min(tr[1]) as usize,
            rows: s.rect[2].max(tr[2]) as usize..s.rect[3].min(tr[3]) as usize,
            c32: [s.center[0].to_f32(), s.center[1].to_f32()],
            tx0: tr[0] as usize,
        }
    }

    /// Row `y`'s centre and its pixels `[xa, xb)`: the box row narrowed by the row chord of
    /// `conic`, then trimmed to the tile columns set in `live`; `None` when nothing is left.
    #[inline(always)]
    pub(crate) fn row_span<F: Float>(
        &self,
        conic: &crate::splat::RowConic,
        y: usize,
        live: u64,
    ) -> Option<(F, usize, usize)> {
        if live == 0 {
            return None;
        }
        let yf = F::c(y as f64) + F::c(0.5);
        let (xa, xb) = conic.span(self.c32, yf.to_f32(), self.x0, self.x1);
        let (xa, xb) = live_span(live, self.tx0, xa, xb)?;
        Some((yf, xa, xb))
    }

    /// [`EntryBox::row_span`]'s pixels `[xa, xb)` from the chord's pixels computed elsewhere
    /// (`None`: unbounded, the whole box row), without branches: `xa == xb` (at the tile's
    /// first column) when nothing is left.
    #[inline(always)]
    pub(crate) fn live_span_or_empty(&self, chord: Option<(usize, usize)>, live: u64) -> (usize, usize) {
        let (xa, xb) = chord.unwrap_or((self.x0, self.x1));
        live_span_or_empty(live, self.tx0, xa, xb)
    }

    /// Whether any pixel of the box is set in `live` (per tile row, its live columns; the tile's
    /// first row is `ty0`). A box with none has nothing left to composite in this tile.
    #[inline(always)]
    pub(crate) fn any_live(&self, live: &[u64], ty0: usize) -> bool {
        let cols = columns_mask(self.x0 - self.tx0, self.x1.max(self.x0) - self.tx0);
        let rows = self.rows.start - ty0..self.rows.end.max(self.rows.start) - ty0;
        live[rows].iter().any(|&l| l & cols != 0)
    }

    /// The box's columns `[x0, x1)` inside the tile.
    #[inline(always)]
    pub(crate) fn columns(&self) -> (usize, usize) {
        (self.x0, self.x1)
    }

    /// The projected centre in f32, as the row chords take it.
    #[inline(always)]
    pub(crate) fn center(&self) -> [f32; 2] {
        self.c32
    }
}

/// Bit mask of tile columns `[lo, hi)` (`lo <= hi <= 64`), for per-row sets of live pixels.
#[inline(always)]
pub(crate) fn columns_mask(lo: usize, hi: usize) -> u64 {
    debug_assert!(lo <= hi && hi <= 64);
    // Through u128 so that n = 64 needs no branch.
    let below = |n: usize| ((1u128 << n) - 1) as u64;
    below(hi) & !below(lo)
}

/// Narrows the row segment `[xa, xb)` (absolute columns; the tile starts at `x0`) to the span of
/// the pixels set in `live`; `None` when none is.
#[inline(always)]
pub(crate) fn live_span(live: u64, x0: usize, xa: usize, xb: usize) -> Option<(usize, usize)> {
    let (a, b) = live_span_or_empty(live, x0, xa, xb);
    (a < b).then_some((a, b))
}

/// [`live_span`] without a branch: the empty span `[x0, x0)` when no pixel is set.
#[inline(always)]
pub(crate) fn live_span_or_empty(live: u64, x0: usize, xa: usize, xb: usize) -> (usize, usize) {
    let m = live & columns_mask(xa - x0, xb - x0);
    // m == 0: 64 trailing and leading zeros, so `a = x0 + 64 > b = x0` and the min is x0.
    let b = x0 + 64 - m.leading_zeros() as usize;
    ((x0 + m.trailing_zeros() as usize).min(b), b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scattered records are the obvious gather: entry e holds Gaussian `ids[e]`'s splat.
    #[test]
    fn scattered_records_match_the_gather() {
        use crate::preprocess::{preprocess, Cam};
        let p = crate::fixtures::Problem::new(3000, 96);
        let input = p.input();
        let cfg = crate::RasterConfig::default();
        let cam = Cam::<f32>::new(input.camera);
        let (splats, _) = preprocess(input.surfels, &cam, &input.colors, &cfg);
        let bins = bin(&splats, cam.width, cam.height, cfg.tile);
        assert!(bins.ids.len() > 3000, "too few entries: {}", bins.ids.len());
        let colors: Vec<f32> = (0..splats.len() * 3).map(|i| i as f32 * 0.25).collect();
        let got = gather_records(&bins, &splats, Some(&colors));
        assert_eq!(got.len(), bins.ids.len());
        for (rec, &g) in got.iter().zip(&bins.ids) {
            let (s, g) = (&splats[g as usize], g as usize);
            let want = TileRec {
                h: s.h,
                center: s.center,
                opacity: s.opacity,
                normal: s.normal,
                color: [colors[3 * g], colors[3 * g + 1], colors[3 * g + 2]],
                rect: s.rect,
                conic: s.conic,
                id: g as u32,
            };
            assert_eq!(format!("{rec:?}"), format!("{want:?}"));
        }
    }

    #[test]
    fn radix_sort_matches_the_comparison_sort() {
        let mut rng = svgir_core::Rng::new(3);
        // Depths with many ties (few distinct values) and ids in order, as `bin` builds them.
        let keys: Vec<u64> = (0..20_000u32).map(|i| sort_key((rng.uniform() * 50.0).floor() * 0.37 + 0.2, i)).collect();
        let mut want = keys.clone();
        want.sort_unstable();
        assert_eq!(radix_sort_high(keys), want);
        assert!(radix_sort_high(Vec::new()).is_empty());
        // Several chunks on four threads and many ties: the chunked passes must keep the order
        // of equal depths (ids in order, as `bin` builds them).
        let keys: Vec<u64> = (0..5 * RADIX_CHUNK as u32 + 17)
            .map(|i| sort_key((rng.uniform() * 3000.0).floor() * 1.7 + 0.5, i))
            .collect();
        let mut want = keys.clone();
        want.sort_unstable();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
        assert_eq!(pool.install(|| radix_sort_high(keys)), want);
    }

    #[test]
    fn live_span_trims_to_set_bits() {
        assert_eq!(columns_mask(0, 64), u64::MAX);
        assert_eq!(columns_mask(3, 3), 0);
        assert_eq!(columns_mask(2, 5), 0b11100);
        let live = 0b0110_0100u64;
        assert_eq!(live_span(live, 16, 16, 32), Some((18, 23)));
        assert_eq!(live_span(live, 16, 19, 21), None);
        assert_eq!(live_span(live, 16, 22, 24), Some((22, 23)));
        assert_eq!(live_span(u64::MAX, 0, 60, 64), Some((60, 64)));
        assert_eq!(live_span_or_empty(live, 16, 19, 21), (16, 16));
    }
}
