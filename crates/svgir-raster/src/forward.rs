//! Forward compositing (SPEC 1, Eqn 3): preprocess, bin, then per tile front to back.
//!
//! Work split: one rayon task per run of consecutive tiles (`tile_runs`, several per thread,
//! since tiles differ tenfold in cost), the heaviest runs first (`heaviest_first`); a tile
//! writes its own pixels of every output image (a run in each of its rows, through
//! [`Disjoint`]) and its own range of tile-list entries.
//! Inside a tile the loop is Gaussian-outer, pixel-inner over the Gaussian's box clipped to the
//! tile, so a Gaussian costs only the pixels it can touch. Each box row is first evaluated
//! branch-free into a small buffer ([`crate::splat::eval_row`], vectorisable), then composited
//! pixel by pixel into one tile-local accumulator record per pixel, copied to the output images
//! at the end of the tile. The tile stops when every pixel has hit the transmittance floor.
//! Per-Gaussian data is read from per-entry copies ([`crate::tiles::TileRec`]) so the loop
//! streams through memory.
//!
//! Saved for backward ([`ForwardStateOf`]): splats, SH colours, tile lists, per pixel the final T,
//! the number of tile-list entries up to the last composited one, and the distortion moments
//! `M1 = sum w m`, `M2 = sum w m^2`. Per-Gaussian accumulated weights are summed per entry and then
//! reduced per Gaussian in entry order (deterministic); the per-entry sums are saved too, and an
//! entry whose sum is zero composited nothing, so the backward passes it by.
//!
//! With [`crate::RasterConfig::geometry`] off, the normal, depth and median-depth accumulators
//! are skipped (those outputs stay 0) and everything else keeps its bits.

use crate::interp::{normalised_coord, weights, MAX_VERTICES};
use crate::lane_groups::{EntryGroups, GroupSlot};
use crate::phases::Stopwatch;
use crate::preprocess::{preprocess, Cam, Splat};
use crate::splat::{eval_row, plane_setup, row_offsets, row_setup, RowEval};
use crate::tiles::{bin, columns_mask, gather_records, EntryBox, TileBins, TileRec};
use crate::{
    BackgroundOf, ColorSourceOf, ForwardStateOf, GaussianParams, Projection, RasterConfig, RenderInputOf,
    RenderOutputOf,
};
use rayon::prelude::*;
use std::ops::Range;
use std::sync::Arc;
use svgir_core::par::{filled, Disjoint};
use svgir_core::Float;

/// A feature table seen by the kernels: `data[(g * vertices + m) * channels + c]`.
#[derive(Clone, Copy, Debug)]
pub struct FeatView<'a, F> {
    /// Values, `[gaussian][vertex][channel]`.
    pub data: &'a [F],
    /// Vertices per Gaussian.
    pub vertices: usize,
    /// Channels per vertex (0 for an absent table).
    pub channels: usize,
    /// The first `lerped` channels are interpolated over the vertices; the rest hold one value
    /// per Gaussian, read at vertex 0 ([`crate::FeaturesOf::uniform`]). `channels` with one
    /// vertex.
    pub lerped: usize,
}

impl<'a, F: Float> FeatView<'a, F> {
    /// The colour table: SH colours (one vertex) or the given features.
    pub fn colors(colors: &ColorSourceOf<'a, F>, sh_colors: &'a [[F; 3]]) -> Self {
        match colors {
            ColorSourceOf::Sh => Self { data: sh_colors.as_flattened(), vertices: 1, channels: 3, lerped: 3 },
            ColorSourceOf::Features(f) => Self { data: f.data, vertices: f.vertices, channels: 3, lerped: 3 },
        }
    }

    /// The extra-feature table; empty (0 channels) without extra features.
    pub fn extra(extra: &Option<crate::FeaturesOf<'a, F>>) -> Self {
        match extra {
            Some(f) => Self {
                data: f.data,
                vertices: f.vertices,
                channels: f.channels,
                lerped: if f.vertices > 1 { f.channels - f.uniform } else { f.channels },
            },
            None => Self { data: &[], vertices: 1, channels: 0, lerped: 0 },
        }
    }

    /// Hints the cache lines of Gaussian `g`'s rows. The tile kernels read the rows in entry
    /// order, which is at random over the table, and `perf` found them waiting on those loads
    /// (docs/performance.md), so they hint the entry a few places ahead.
    #[inline(always)]
    pub(crate) fn prefetch(&self, g: usize) {
        let bytes = self.vertices * self.channels * std::mem::size_of::<F>();
        if bytes == 0 {
            return;
        }
        let start = self.data.as_ptr().wrapping_add(g * self.vertices * self.channels) as usize;
        let mut line = start & !63;
        while line < start + bytes {
            crate::tiles::prefetch::<false, _>(line as *const u8);
            line += 64;
        }
    }

    /// Feature channel values of Gaussian `g` at interpolation weights `w`, into `out[..channels]`.
    #[inline(always)]
    pub fn eval(&self, g: usize, w: &[F; MAX_VERTICES], out: &mut [F]) {
        let c = self.channels;
        let base = g * self.vertices * c;
        if self.vertices == 1 {
            out[..c].copy_from_slice(&self.data[base..base + c]);
            return;
        }
        // The first vertex's product, then the others' by FMA in vertex order (what the SIMD
        // kernels compute lane by lane); the uniform channels as vertex 0 holds them.
        let l = self.lerped;
        for ch in 0..l {
            out[ch] = w[0] * self.data[base + ch];
        }
        out[l..c].copy_from_slice(&self.data[base + l..base + c]);
        for m in 1..self.vertices {
            let row = &self.data[base + m * c..base + m * c + l];
            for ch in 0..l {
                out[ch] = w[m].mul_add(row[ch], out[ch]);
            }
        }
    }
}

/// Interpolation weights at a hit (u, v) for `vertices` (1: `[1, ..]`).
#[inline(always)]
pub(crate) fn hit_weights<F: Float>(vertices: usize, u: F, v: F, w: &mut [F; MAX_VERTICES]) {
    if vertices > 1 {
        let (ut, _) = normalised_coord(u);
        let (vt, _) = normalised_coord(v);
        weights(vertices, ut, vt, w);
    } else {
        w[0] = F::ONE;
    }
}

/// 2DGS's depth mapping for the distortion loss.
#[inline(always)]
pub(crate) fn distortion_depth<F: Float>(z: F, near: F, far: F) -> F {
    far / (far - near) * (F::ONE - near / z)
}

/// Background colour of pixel `pix`.
#[inline(always)]
pub(crate) fn background_at<F: Float>(bg: &BackgroundOf<F>, pix: usize) -> [F; 3] {
    match bg {
        BackgroundOf::Color(c) => *c,
        BackgroundOf::Image(b) => [b[pix * 3], b[pix * 3 + 1], b[pix * 3 + 2]],
    }
}

/// Every per-pixel output and the per-entry weight sums, written by the tile tasks at once:
/// each tile writes its own pixels (a run in each of its rows) and its own tile-list entries.
pub(crate) struct Outputs<'a, F> {
    color: Disjoint<'a, F>,
    alpha: Disjoint<'a, F>,
    depth: Disjoint<'a, F>,
    median: Disjoint<'a, F>,
    normal: Disjoint<'a, F>,
    dist: Disjoint<'a, F>,
    extra: Disjoint<'a, F>,
    final_t: Disjoint<'a, F>,
    n_contrib: Disjoint<'a, u32>,
    m1: Disjoint<'a, F>,
    m2: Disjoint<'a, F>,
    /// Per tile-list entry: sum of w.
    pub(crate) wsum: Disjoint<'a, F>,
    /// Per tile, the SIMD kernel's lane groups ([`ForwardStateOf::tile_groups`]), and per
    /// entry where its groups lie.
    pub(crate) tile_groups: Disjoint<'a, Vec<GroupSlot>>,
    pub(crate) entry_groups: Disjoint<'a, EntryGroups>,
}

/// One run of pixels (part of an image row) in every per-pixel output.
pub(crate) struct RowOut<'a, F> {
    pub(crate) color: &'a mut [F],
    pub(crate) alpha: &'a mut [F],
    pub(crate) depth: &'a mut [F],
    pub(crate) median: &'a mut [F],
    pub(crate) normal: &'a mut [F],
    pub(crate) dist: &'a mut [F],
    pub(crate) extra: &'a mut [F],
    pub(crate) final_t: &'a mut [F],
    pub(crate) n_contrib: &'a mut [u32],
    pub(crate) m1: &'a mut [F],
    pub(crate) m2: &'a mut [F],
}

impl<'a, F> Outputs<'a, F> {
    /// Pixels `start..start + len` (row-major pixel indices) of every output; `ce` extra
    /// channels per pixel.
    ///
    /// # Safety
    /// No other task holds any of these pixels meanwhile (a tile's own pixels, one row at a
    /// time).
    pub(crate) unsafe fn row(&self, start: usize, len: usize, ce: usize) -> RowOut<'a, F> {
        // SAFETY: the caller's contract, for each output.
        unsafe {
            RowOut {
                color: self.color.seg(3 * start, 3 * len),
                alpha: self.alpha.seg(start, len),
                depth: self.depth.seg(start, len),
                median: self.median.seg(start, len),
                normal: self.normal.seg(3 * start, 3 * len),
                dist: self.dist.seg(start, len),
                extra: self.extra.seg(ce * start, ce * len),
                final_t: self.final_t.seg(start, len),
                n_contrib: self.n_contrib.seg(start, len),
                m1: self.m1.seg(start, len),
                m2: self.m2.seg(start, len),
            }
        }
    }
}

/// The forward's tasks: runs of consecutive tiles, about [`TASKS_PER_THREAD`] per worker. A
/// tile's cost follows how many entries it holds and how soon its pixels saturate, which varies
/// tenfold over an object's image, so the tasks are smaller than an even share.
pub(crate) fn tile_runs(ntiles: usize, threads: usize) -> Vec<Range<usize>> {
    let per = ntiles.div_ceil(TASKS_PER_THREAD * threads.max(1)).max(1);
    (0..ntiles).step_by(per).map(|a| a..(a + per).min(ntiles)).collect()
}

/// Forward tasks per worker thread (see [`tile_runs`]).
const TASKS_PER_THREAD: usize = 8;

/// `tasks` ordered by descending `cost` (ties in their given order), for a `par_bridge`, which
/// hands them out one at a time to whichever thread is free. A tile's cost follows its entry
/// count, and the heavy tiles of an object in the middle of the view sit next to each other:
/// split by rayon's default halving, one thread could be left with a run of them while the other
/// waited; taken heaviest first, the pass ends on light tasks. On one thread the given order is
/// kept (neighbouring tiles share Gaussians, which are then still in cache). Only the order in
/// which the tasks run changes, not what any of them computes.
pub(crate) fn heaviest_first<T>(tasks: Vec<T>, cost: impl Fn(&T) -> usize) -> std::vec::IntoIter<T> {
    if rayon::current_num_threads() < 2 {
        return tasks.into_iter();
    }
    let mut keyed: Vec<(usize, T)> = tasks.into_iter().map(|t| (cost(&t), t)).collect();
    keyed.sort_by_key(|(c, _)| std::cmp::Reverse(*c));
    keyed.into_iter().map(|(_, t)| t).collect::<Vec<T>>().into_iter()
}

/// Splits `v` into consecutive chunks of the given lengths.
pub(crate) fn split_lens<T>(mut v: &mut [T], lens: impl Iterator<Item = usize>) -> Vec<&mut [T]> {
    let mut out = Vec::new();
    for n in lens {
        let (a, b) = std::mem::take(&mut v).split_at_mut(n);
        out.push(a);
        v = b;
    }
    out
}

/// Renders in scalar type `F` (see [`crate::render`] for the f32 entry point).
pub fn render_generic<F: Float, P: GaussianParams<F> + ?Sized>(
    input: &RenderInputOf<F, P>,
    cfg: &RasterConfig,
) -> (RenderOutputOf<F>, ForwardStateOf<F>) {
    let mut sw = Stopwatch::start();
    let proj = project_timed(input, cfg, &mut sw);
    render_projected(input, cfg, Arc::new(proj), sw)
}

/// The projection of [`render_generic`] alone (see [`crate::try_project`]).
pub(crate) fn project<F: Float, P: GaussianParams<F> + ?Sized>(
    input: &RenderInputOf<F, P>,
    cfg: &RasterConfig,
) -> Projection<F> {
    project_timed(input, cfg, &mut Stopwatch::start())
}

fn project_timed<F: Float, P: GaussianParams<F> + ?Sized>(
    input: &RenderInputOf<F, P>,
    cfg: &RasterConfig,
    sw: &mut Stopwatch,
) -> Projection<F> {
    let cam = Cam::<F>::new(input.camera);
    let (splats, sh_colors) = preprocess(input.surfels, &cam, &input.colors, cfg);
    sw.lap("preprocess");
    let bins = bin(&splats, cam.width, cam.height, cfg.tile);
    sw.lap("bin");
    let cf = FeatView::colors(&input.colors, &sh_colors);
    let recs = gather_records(&bins, &splats, (cf.vertices == 1).then_some(cf.data));
    sw.lap("records");
    Projection { splats, sh_colors, recs, bins, camera: Some(*input.camera), near: cfg.near }
}

/// Per Gaussian, its screen radius when it is in view, else 0 ([`RenderOutputOf::max_radius`]).
pub(crate) fn max_radius<F: Float>(splats: &[Splat<F>]) -> Vec<f32> {
    splats.par_iter().with_min_len(4096).map(|s| if s.visible() { s.radius } else { 0.0 }).collect()
}

/// The tile passes of [`render_generic`] over a projection already made (by this render or an
/// earlier one of the same Gaussians and camera, [`crate::try_render_reusing`]).
pub(crate) fn render_projected<F: Float, P: GaussianParams<F> + ?Sized>(
    input: &RenderInputOf<F, P>,
    cfg: &RasterConfig,
    proj: Arc<Projection<F>>,
    mut sw: Stopwatch,
) -> (RenderOutputOf<F>, ForwardStateOf<F>) {
    let (w, h) = (input.camera.width(), input.camera.height());
    let npx = w as usize * h as usize;
    let (splats, bins, recs) = (&proj.splats, &proj.bins, &proj.recs);
    let cf = FeatView::colors(&input.colors, &proj.sh_colors);
    let ef = FeatView::extra(&input.extra);
    let ce = ef.channels;

    let mut out = RenderOutputOf::<F> {
        width: w,
        height: h,
        color: filled(npx * 3, F::ZERO),
        alpha: filled(npx, F::ZERO),
        depth: filled(npx, F::ZERO),
        median_depth: filled(npx, F::ZERO),
        normal: filled(npx * 3, F::ZERO),
        distortion: filled(npx, F::ZERO),
        extra: filled(npx * ce, F::ZERO),
        extra_channels: ce,
        accum_weight: Vec::new(),
        max_radius: max_radius(splats),
    };
    let mut final_t = filled(npx, F::ONE);
    let mut n_contrib = filled(npx, 0u32);
    let mut m1 = filled(npx, F::ZERO);
    let mut m2 = filled(npx, F::ZERO);
    let mut wsum = filled(bins.ids.len(), F::ZERO);
    // The SIMD kernels (f32) keep their lane groups when a backward follows (`for_backward`);
    // otherwise, and for the scalar kernels, these stay empty.
    let keep = cfg.for_backward && crate::simd::is_f32::<F>();
    let group_lanes = if keep { crate::forward_simd::group_lanes(cfg.simd.resolve()) } else { 0 };
    let mut tile_groups = vec![Vec::new(); if group_lanes > 0 { bins.ranges.len() } else { 0 }];
    let mut entry_groups = filled(if group_lanes > 0 { bins.ids.len() } else { 0 }, EntryGroups::default());

    {
        let outs = Outputs {
            color: Disjoint::new(&mut out.color),
            alpha: Disjoint::new(&mut out.alpha),
            depth: Disjoint::new(&mut out.depth),
            median: Disjoint::new(&mut out.median_depth),
            normal: Disjoint::new(&mut out.normal),
            dist: Disjoint::new(&mut out.distortion),
            extra: Disjoint::new(&mut out.extra),
            final_t: Disjoint::new(&mut final_t),
            n_contrib: Disjoint::new(&mut n_contrib),
            m1: Disjoint::new(&mut m1),
            m2: Disjoint::new(&mut m2),
            wsum: Disjoint::new(&mut wsum),
            tile_groups: Disjoint::new(&mut tile_groups),
            entry_groups: Disjoint::new(&mut entry_groups),
        };
        sw.lap("buffers");
        let runs = tile_runs(bins.ranges.len(), rayon::current_num_threads());
        heaviest_first(runs, |run| run.clone().map(|t| bins.entry_count(t)).sum()).par_bridge().for_each(|run| {
            render_tiles(&outs, run, bins, recs, &cf, &ef, &input.background, cfg, w, h);
        });
    }
    sw.lap("tiles");

    out.accum_weight = (0..splats.len())
        .into_par_iter()
        .with_min_len(4096)
        .map(|g| {
            let (a, b) = (bins.entry_offsets[g] as usize, bins.entry_offsets[g + 1] as usize);
            let mut s = F::ZERO;
            for &e in &bins.entries[a..b] {
                s += wsum[e as usize];
            }
            s
        })
        .collect();
    sw.lap("reduce");
    let state = ForwardStateOf {
        proj,
        final_t,
        n_contrib,
        moment1: m1,
        moment2: m2,
        entry_weight: wsum,
        tile_groups,
        entry_groups,
        group_lanes,
        phases: sw.finish(),
    };
    (out, state)
}

/// Per-pixel accumulators of one tile (one record per pixel: one cache line, one bounds check).
#[derive(Clone, Copy, Debug, Default)]
struct PixAcc<F> {
    t: F,
    color: [F; 3],
    normal: [F; 3],
    depth: F,
    dist: F,
    m1: F,
    m2: F,
    median: F,
    ncon: u32,
    done: bool,
}

/// Dispatches to the kernel specialised for which optional paths are live (each is a branch per
/// composited pixel otherwise): interpolated colours, extra channels, distortion.
#[allow(clippy::too_many_arguments)]
fn render_tiles<F: Float>(
    o: &Outputs<F>,
    run: Range<usize>,
    bins: &TileBins,
    recs: &[TileRec<F>],
    cf: &FeatView<F>,
    ef: &FeatView<F>,
    bg: &BackgroundOf<F>,
    cfg: &RasterConfig,
    w: u32,
    h: u32,
) {
    let ci = cf.vertices > 1;
    let ex = ef.channels > 0;
    if crate::simd::is_f32::<F>() {
        // SAFETY: `F` is `f32` (checked above), so these are the same types.
        let (o32, recs32, cf32, ef32, bg32) = unsafe {
            (
                &*(o as *const Outputs<F> as *const Outputs<f32>),
                &*(recs as *const [TileRec<F>] as *const [TileRec<f32>]),
                &*(cf as *const FeatView<F> as *const FeatView<f32>),
                &*(ef as *const FeatView<F> as *const FeatView<f32>),
                &*(bg as *const BackgroundOf<F> as *const BackgroundOf<f32>),
            )
        };
        let path = cfg.simd.resolve();
        if crate::forward_simd::render_tiles_simd(path, o32, run.clone(), bins, recs32, cf32, ef32, bg32, cfg, w, h) {
            return;
        }
    }
    macro_rules! go {
        ($ci:literal, $ex:literal, $d:literal) => {
            render_tiles_k::<F, $ci, $ex, $d>(o, run, bins, recs, cf, ef, bg, cfg, w, h)
        };
    }
    match (ci, ex, cfg.distortion) {
        (false, false, false) => go!(false, false, false),
        (false, false, true) => go!(false, false, true),
        (false, true, false) => go!(false, true, false),
        (false, true, true) => go!(false, true, true),
        (true, false, false) => go!(true, false, false),
        (true, false, true) => go!(true, false, true),
        (true, true, false) => go!(true, true, false),
        (true, true, true) => go!(true, true, true),
    }
}

/// A run of tiles; see [`render_tiles`] for the const parameters.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn render_tiles_k<F: Float, const CI: bool, const EX: bool, const DIST: bool>(
    o: &Outputs<F>,
    run: Range<usize>,
    bins: &TileBins,
    recs: &[TileRec<F>],
    cf: &FeatView<F>,
    ef: &FeatView<F>,
    bg: &BackgroundOf<F>,
    cfg: &RasterConfig,
    w: u32,
    h: u32,
) {
    let near = F::from_f32(cfg.near);
    let far = F::from_f32(cfg.far);
    let m_scale = far / (far - near);
    let t_stop = F::from_f32(cfg.t_stop);
    let half = F::c(0.5);
    let geom = cfg.geometry;
    let normals = geom && cfg.normals;
    let two = F::c(2.0);
    let wu = w as usize;
    let ce = ef.channels;
    let tile = bins.tile as usize;
    let mut acc = vec![PixAcc::<F>::default(); tile * tile];
    let mut acc_extra = vec![F::ZERO; tile * tile * ce];
    let mut row_live = vec![0u64; tile];
    let mut wc = [F::ZERO; MAX_VERTICES];
    let mut we = [F::ZERO; MAX_VERTICES];
    let mut col = [F::ZERO; 3];
    let mut ext = vec![F::ZERO; ce];
    let mut ev = Box::<RowEval<F>>::default();
    let offs = row_offsets::<F>();
    /// The fields of a hit the forward needs.
    struct Hit<F> {
        u: F,
        v: F,
        z: F,
        alpha: F,
    }
    for t in run {
        let tr = bins.tile_rect(t, w, h);
        let [r0, r1] = bins.ranges[t];
        let (tx0, ty0) = (tr[0] as usize, tr[2] as usize);
        // SAFETY (every `seg` of this tile): tile `t` alone owns its entries and its pixels.
        let wsum = unsafe { o.wsum.seg(r0 as usize, (r1 - r0) as usize) };
        acc.fill(PixAcc { t: F::ONE, ..Default::default() });
        acc_extra.fill(F::ZERO);
        let mut remaining = (tr[1] - tr[0]) as usize * (tr[3] - tr[2]) as usize;
        // Pixels not yet done, one bit per column per row of the tile: each row's evaluation is
        // narrowed to its live pixels (a saturated row is skipped whole).
        row_live.fill(columns_mask(0, (tr[1] - tr[0]) as usize));
        for e in r0 as usize..r1 as usize {
            if remaining == 0 {
                break;
            }
            let s = &recs[e];
            let g = s.id as usize;
            let bx = EntryBox::new(s, &tr);
            let plane = plane_setup(&s.h);
            let local = (e - r0 as usize + 1) as u32;
            let mut ws = F::ZERO;
            for y in bx.rows.clone() {
                let Some((yf, xa, xb)) = bx.row_span::<F>(&s.conic, y, row_live[y - ty0]) else { continue };
                let row = (y - ty0) * tile;
                let rs = row_setup(&plane, yf);
                eval_row(&s.h, s.center, s.opacity, &rs, yf, xa, xb - xa, near, &offs, &mut ev);
                for x in xa..xb {
                    let i = x - xa;
                    let li = row + (x - tx0);
                    let a = &mut acc[li];
                    if a.done || ev.alpha[i] == F::ZERO {
                        continue;
                    }
                    let hit = Hit { u: ev.u[i], v: ev.v[i], z: ev.z[i], alpha: ev.alpha[i] };
                    let tcur = a.t;
                    let test = tcur * (F::ONE - hit.alpha);
                    if test < t_stop {
                        a.done = true;
                        remaining -= 1;
                        row_live[y - ty0] &= !(1u64 << (x - tx0));
                        continue;
                    }
                    let wgt = hit.alpha * tcur;
                    if CI {
                        hit_weights(cf.vertices, hit.u, hit.v, &mut wc);
                        cf.eval(g, &wc, &mut col);
                    } else {
                        col = s.color;
                    }
                    for ch in 0..3 {
                        // Colours from feature tables by FMA, as the SIMD kernels.
                        a.color[ch] = if CI { wgt.mul_add(col[ch], a.color[ch]) } else { a.color[ch] + wgt * col[ch] };
                    }
                    if normals {
                        for ch in 0..3 {
                            a.normal[ch] += wgt * s.normal[ch];
                        }
                    }
                    if geom {
                        a.depth += wgt * hit.z;
                        if tcur > half {
                            a.median = hit.z;
                        }
                    }
                    if DIST {
                        // 2DGS running-sum distortion: w_i (m_i^2 A_i + M2 - 2 m_i M1), A_i = 1 - T_i.
                        let m = m_scale * (F::ONE - near / hit.z);
                        a.dist += (m * m * (F::ONE - tcur) + a.m2 - two * m * a.m1) * wgt;
                        a.m1 += m * wgt;
                        a.m2 += m * m * wgt;
                    }
                    a.t = test;
                    a.ncon = local;
                    ws += wgt;
                    if EX {
                        hit_weights(ef.vertices, hit.u, hit.v, &mut we);
                        ef.eval(g, &we, &mut ext);
                        let dst = &mut acc_extra[li * ce..(li + 1) * ce];
                        for ch in 0..ce {
                            dst[ch] = wgt.mul_add(ext[ch], dst[ch]);
                        }
                    }
                }
            }
            wsum[e - r0 as usize] = ws;
        }
        let wt = (tr[1] - tr[0]) as usize;
        for y in tr[2] as usize..tr[3] as usize {
            let b0 = y * wu + tx0;
            let r = unsafe { o.row(b0, wt, ce) };
            for i in 0..wt {
                let li = (y - ty0) * tile + i;
                let a = &acc[li];
                let tn = a.t;
                let c = background_at(bg, b0 + i);
                for ch in 0..3 {
                    r.color[i * 3 + ch] = a.color[ch] + tn * c[ch];
                    r.normal[i * 3 + ch] = a.normal[ch];
                }
                r.alpha[i] = F::ONE - tn;
                r.depth[i] = a.depth;
                r.median[i] = a.median;
                r.dist[i] = a.dist;
                r.final_t[i] = tn;
                r.n_contrib[i] = a.ncon;
                r.m1[i] = a.m1;
                r.m2[i] = a.m2;
                r.extra[i * ce..(i + 1) * ce].copy_from_slice(&acc_extra[li * ce..(li + 1) * ce]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::heaviest_first;

    /// Several threads get the tasks by descending cost, equal costs in their given order; one
    /// thread gets them as given.
    #[test]
    fn heaviest_first_orders_by_cost_on_several_threads_only() {
        let tasks = vec![(0, 3), (1, 9), (2, 3), (3, 0), (4, 9), (5, 5)];
        let order = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| heaviest_first(tasks.clone(), |&(_, c)| c).map(|(i, _)| i).collect::<Vec<_>>())
        };
        assert_eq!(order(2), [1, 4, 5, 0, 2, 3]);
        assert_eq!(order(1), [0, 1, 2, 3, 4, 5]);
    }
}
