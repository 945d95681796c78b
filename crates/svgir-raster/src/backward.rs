//! Backward of [`crate::forward`]: per tile, back to front, then a per-Gaussian reduction and the
//! preprocess backward.
//!
//! Per pixel, with `w_i = alpha_i T_i`, every output but the background term is linear in the
//! weights: `sum_i w_i q_i`. Collecting `g_i = dL/dw_i = gC.c_i + gO + gD z_i + gN.n_i + gE.f_i +
//! gDist (A m_i^2 - 2 m_i M1 + M2)` (the last from `Dist = sum_{j<i} w_i w_j (m_i - m_j)^2`, with
//! the final `A = 1 - T_N`, `M1`, `M2`), the chain through `w(alpha)` is
//! `dL/dalpha_i = T_i g_i - (sum_{j>i} g_j w_j + T_N gC.bg) / (1 - alpha_i)`, evaluated back to
//! front with a running suffix sum, and `T_i = T_{i+1} / (1 - alpha_i)` recovered from the saved
//! final T (as 3DGS).
//!
//! Work split: one rayon task per tile, the heaviest tiles first (`heaviest_first`),
//! Gaussian-outer (in reverse list order) and pixel-inner as in the forward; gradients go to a per-entry buffer (one slot per (Gaussian,
//! tile) pair, owned by that tile), then each Gaussian sums its entries in a fixed order. No
//! atomics, no racy `+=`, bit-reproducible for a given input (SPEC 9.4, 9.9). An entry that
//! composited nothing in the forward (zero saved weight: faint everywhere, or behind pixels that
//! had already finished) has no gradient and is passed by before its pixels are listed.
//!
//! With [`crate::RasterConfig::geometry`] off, `gD` and `gN` are read as zero whatever is passed
//! (the SIMD kernels then skip their terms). With [`crate::RasterConfig::geometry_grads`] off,
//! the SIMD kernels compute only the opacity, colour and feature sums; either path then returns
//! zero geometry gradients.

use crate::forward::{background_at, heaviest_first, split_lens, FeatView};
use crate::interp::{normalised_coord, weight_grads, weights, MAX_VERTICES};
use crate::phases::Stopwatch;
use crate::preprocess::Cam;
use crate::preprocess::{assume_init, uninit_vec, Splat};
use crate::preprocess_backward::{gaussian_backward, opacity_logit_grad, GradSlots, ParamGrad, SplatGradSum};
use crate::preprocess_backward_simd::{gaussian_backward_block, Inputs, BLOCK};
use crate::splat::{
    eval_row, hit_from_row, intersect_backward, plane_setup, row_offsets, row_setup, RowEval, SplatGrad,
};
use crate::tiles::{prefetch, EntryBox, TileBins, TileRec};
use crate::{
    BackgroundOf, ColorSourceOf, ForwardStateOf, GaussianParams, GradsOf, OutputGradsOf, RasterConfig, RenderInputOf,
    RenderOutputOf,
};
use rayon::prelude::*;
use std::mem::MaybeUninit;
use svgir_core::par::{filled, zeroed};
use svgir_core::Float;

// Per-entry gradient slot layout.
pub(crate) const OFF_H: usize = 0;
pub(crate) const OFF_C: usize = 9;
pub(crate) const OFF_OP: usize = 11;
pub(crate) const OFF_N: usize = 12;
pub(crate) const OFF_COL: usize = 15;

/// Per-pixel upstream gradients and saved state of one tile (one record per pixel, as the
/// forward's accumulator: one cache line per pixel visit).
#[derive(Clone, Copy, Debug, Default)]
struct PixB<F> {
    /// Transmittance before the current entry (walked back from the final T).
    t: F,
    /// Running suffix sum `sum_{j>i} g_j w_j + T_N gC.bg`.
    acc: F,
    gc: [F; 3],
    gn: [F; 3],
    go: F,
    gd: F,
    gdist: F,
    /// Final `A = 1 - T_N` and distortion moments.
    a: F,
    m1: F,
    m2: F,
    ncon: u32,
}

/// Backward in scalar type `F` (see [`crate::backward()`] for the f32 entry point).
pub fn backward_generic<F: Float, P: GaussianParams<F> + ?Sized>(
    input: &RenderInputOf<F, P>,
    cfg: &RasterConfig,
    state: &ForwardStateOf<F>,
    _out: &RenderOutputOf<F>,
    grads: &OutputGradsOf<F>,
) -> GradsOf<F> {
    let mut sw = Stopwatch::start();
    let cam = Cam::<F>::new(input.camera);
    let (w, h) = (cam.width, cam.height);
    let n = input.surfels.count();
    let bins = &state.proj.bins;
    let cf = FeatView::colors(&input.colors, &state.proj.sh_colors);
    let ef = FeatView::extra(&input.extra);
    let ce = ef.channels;
    let off_ext = OFF_COL + cf.vertices * 3;
    let dim = off_ext + ef.vertices * ce;

    // The tile kernels zero the slots as they fill them (`backward_tile`): zeroed here, in one
    // pass over the whole buffer, the slots were out of the cache by the time the kernels read
    // them back (`+=`) -- cache misses on every entry (docs/performance.md).
    let n_slots = bins.ids.len() * dim;
    assert!(
        bins.ranges.iter().map(|r| (r[1] - r[0]) as usize).sum::<usize>() == bins.ids.len(),
        "tile ranges do not cover the entries"
    );
    let mut entry_grads = uninit_vec::<F>(n_slots);
    sw.lap("buffers");
    {
        // One task per tile (its entries are a contiguous run of `entry_grads`), as uneven in
        // cost as the forward's tiles: heaviest first, one at a time to whichever thread is
        // free (`heaviest_first`).
        let elens = bins.ranges.iter().map(|r| (r[1] - r[0]) as usize * dim);
        let tiles: Vec<(usize, &mut [MaybeUninit<F>])> =
            split_lens(&mut entry_grads, elens).into_iter().enumerate().collect();
        let ctx = Ctx {
            bins,
            recs: &state.proj.recs,
            state,
            cf: &cf,
            ef: &ef,
            grads,
            bg: &input.background,
            cfg,
            w,
            h,
            dim,
            off_ext,
        };
        let tiles = heaviest_first(tiles, |(t, _)| bins.entry_count(*t));
        tiles.par_bridge().for_each_init(
            || Scratch::new(bins.tile as usize, ce),
            |scr, (t, eg)| {
                backward_tile(&ctx, t, eg, scr);
            },
        );
    }
    // SAFETY: the tile ranges cover every entry (asserted above), and every tile task writes
    // each of its slots (`backward_tile`).
    let entry_grads = unsafe { assume_init(entry_grads) };

    sw.lap("tiles");
    // Per-Gaussian reduction in entry order, then the preprocess backward.
    let sh_mode = matches!(input.colors, ColorSourceOf::Sh);
    // Each Gaussian's entry slots, columns `lo..hi`, summed in entry order into its row (of
    // `width` values, the first `hi - lo` written) of `out`. A pass of its own: the slots of one
    // Gaussian are scattered over the tiles (cache misses), and this small loop keeps many loads
    // in flight, where the per-Gaussian backward would stall on each; the slots of the Gaussian
    // `AHEAD` places on are prefetched, since the hardware prefetcher cannot guess them.
    const AHEAD: usize = 8;
    const CHUNK: usize = 1024;
    let reduce = |out: &mut [F], width: usize, lo: usize, hi: usize| {
        let prefetch_slots = |g: usize| {
            if g < n {
                let (a, b) = (bins.entry_offsets[g] as usize, bins.entry_offsets[g + 1] as usize);
                for &e in &bins.entries[a..b] {
                    // Both ends of the slot (it may span two cache lines).
                    let slot = &entry_grads[e as usize * dim..(e as usize + 1) * dim];
                    prefetch::<false, _>(slot.as_ptr());
                    prefetch::<false, _>(&slot[dim - 1]);
                }
            }
        };
        out.par_chunks_mut(CHUNK * width).enumerate().for_each(|(c, rows)| {
            let g0 = c * CHUNK;
            for g in g0..(g0 + AHEAD).min(n) {
                prefetch_slots(g);
            }
            for (j, row) in rows.chunks_exact_mut(width).enumerate() {
                let g = g0 + j;
                prefetch_slots(g + AHEAD);
                let (a, b) = (bins.entry_offsets[g] as usize, bins.entry_offsets[g + 1] as usize);
                for &e in &bins.entries[a..b] {
                    let slot = &entry_grads[e as usize * dim..(e as usize + 1) * dim];
                    for (o, v) in row.iter_mut().zip(&slot[lo..hi]) {
                        *o += *v;
                    }
                }
            }
        });
    };
    if !cfg.geometry_grads && !sh_mode {
        // Frozen geometry and colours from feature tables (stage 2's PBR pass): the per-Gaussian
        // backward is only the opacity's sigmoid, so one reduce reads each entry slot once for
        // the opacity and every feature column (the same sums, in the same order, as below).
        let width = dim - OFF_OP;
        let mut rows = filled(n * width, F::ZERO);
        reduce(&mut rows, width, OFF_OP, dim);
        sw.lap("reduce");
        let (nc, ne) = (cf.vertices * 3, if input.extra.is_some() { ef.vertices * ce } else { 0 });
        let (oc, oe) = (OFF_COL - OFF_OP, off_ext - OFF_OP);
        let mut v_opacity_logits = filled(n, F::ZERO);
        let mut v_color_features = filled(n * nc, F::ZERO);
        let mut v_extra = filled(n * ne, F::ZERO);
        v_opacity_logits.par_iter_mut().zip(rows.par_chunks_exact(width)).zip(&state.proj.splats).for_each(
            |((v, r), sp)| {
                if sp.visible() {
                    *v = opacity_logit_grad(r[0], sp.opacity);
                }
            },
        );
        sw.lap("gaussians");
        v_color_features
            .par_chunks_exact_mut(nc)
            .zip(rows.par_chunks_exact(width))
            .for_each(|(v, r)| v.copy_from_slice(&r[oc..oc + nc]));
        if ne > 0 {
            v_extra
                .par_chunks_exact_mut(ne)
                .zip(rows.par_chunks_exact(width))
                .for_each(|(v, r)| v.copy_from_slice(&r[oe..oe + ne]));
        }
        let v_background = background_grad(&input.background, grads.color, &state.final_t);
        sw.lap("features");
        return GradsOf {
            v_positions: zeroed(n),
            v_rotations: zeroed(n),
            v_log_scales: zeroed(n),
            v_opacity_logits,
            v_sh: zeroed(n),
            v_color_features,
            v_extra,
            v_background,
            v_mean2d_norm: filled(n, F::ZERO),
            phases: sw.finish(),
        };
    }
    let hi = if sh_mode { OFF_COL + 3 } else { OFF_COL };
    let mut sums = filled(n * (OFF_COL + 3), F::ZERO);
    reduce(&mut sums, OFF_COL + 3, 0, hi);
    let (sums, _) = sums.as_chunks::<{ OFF_COL + 3 }>();
    sw.lap("reduce");
    let mut v_positions = uninit_vec::<F::V3>(n);
    let mut v_rotations = uninit_vec::<F::Q>(n);
    let mut v_log_scales = uninit_vec::<F::V2>(n);
    let mut v_opacity_logits = uninit_vec::<F>(n);
    let mut v_sh = uninit_vec::<F::Sh>(n);
    let mut v_mean2d_norm = uninit_vec::<F>(n);
    // Eight Gaussians per block: the SIMD path runs them in lanes, the scalar one by one.
    let path = if crate::simd::is_f32::<F>() { cfg.simd.resolve() } else { crate::Simd::Scalar };
    v_positions
        .par_chunks_mut(BLOCK)
        .zip(v_rotations.par_chunks_mut(BLOCK))
        .zip(v_log_scales.par_chunks_mut(BLOCK))
        .zip(v_opacity_logits.par_chunks_mut(BLOCK))
        .zip(v_sh.par_chunks_mut(BLOCK))
        .zip(v_mean2d_norm.par_chunks_mut(BLOCK))
        .enumerate()
        .with_min_len(32)
        .for_each_init(
            Inputs::new,
            |x, (b, (((((position, rotation), log_scale), opacity_logit), sh), mean2d_norm))| {
                let mut out = GradSlots::<F> { position, rotation, log_scale, opacity_logit, sh, mean2d_norm };
                let (g0, m) = (b * BLOCK, out.len());
                let splats = &state.proj.splats[g0..g0 + m];
                if path != crate::Simd::Scalar {
                    x.fill(input.surfels, splats, &sums[g0..g0 + m], sh_mode, g0);
                    // SAFETY: `path` is only a SIMD one when `F` is `f32` (above), so these are the
                    // same types.
                    let (cam32, splats32, out32) = unsafe {
                        (
                            &*(&cam as *const Cam<F> as *const Cam<f32>),
                            &*(splats as *const [Splat<F>] as *const [Splat<f32>]),
                            &mut *(&mut out as *mut GradSlots<F> as *mut GradSlots<f32>),
                        )
                    };
                    if gaussian_backward_block(path, x, cam32, splats32, out32) {
                        return;
                    }
                }
                for (l, splat) in splats.iter().enumerate() {
                    if !splat.visible() {
                        out.put(l, &ParamGrad::default(), false);
                        continue;
                    }
                    let g = g0 + l;
                    let acc = &sums[g];
                    let mut sg = SplatGradSum::<F>::default();
                    sg.h.copy_from_slice(&acc[OFF_H..OFF_H + 9]);
                    sg.center.copy_from_slice(&acc[OFF_C..OFF_C + 2]);
                    sg.opacity = acc[OFF_OP];
                    sg.normal.copy_from_slice(&acc[OFF_N..OFF_N + 3]);
                    sg.color.copy_from_slice(&acc[OFF_COL..OFF_COL + 3]);
                    out.put(l, &gaussian_backward(input.surfels, &cam, splat, &sg, sh_mode, g), sh_mode);
                }
            },
        );
    // SAFETY: every block wrote each of its slots once (`GradSlots::put`, or the lane kernel's
    // stores, which also cover every slot).
    let (mut v_positions, mut v_rotations, mut v_log_scales, v_opacity_logits, v_sh, mut v_mean2d_norm) = unsafe {
        (
            assume_init(v_positions),
            assume_init(v_rotations),
            assume_init(v_log_scales),
            assume_init(v_opacity_logits),
            assume_init(v_sh),
            assume_init(v_mean2d_norm),
        )
    };

    if !cfg.geometry_grads {
        // Frozen geometry: the tile kernels left the H, centre and normal sums at zero, but the
        // SH colour's view direction still reaches the position; the contract is zeros.
        let z = F::ZERO;
        v_positions.par_iter_mut().for_each(|v| *v = F::v3([z; 3]));
        v_rotations.par_iter_mut().for_each(|v| *v = F::quat([z; 4]));
        v_log_scales.par_iter_mut().for_each(|v| *v = F::v2([z; 2]));
        v_mean2d_norm.par_iter_mut().for_each(|v| *v = z);
    }
    sw.lap("gaussians");
    let feature_grads = |fv: &FeatView<F>, lo: usize| -> Vec<F> {
        let len = fv.vertices * fv.channels;
        let mut v = filled(n * len, F::ZERO);
        if len > 0 {
            reduce(&mut v, len, lo, lo + len);
        }
        v
    };
    let v_color_features = if sh_mode { Vec::new() } else { feature_grads(&cf, OFF_COL) };
    let v_extra = if input.extra.is_some() { feature_grads(&ef, off_ext) } else { Vec::new() };

    let v_background = background_grad(&input.background, grads.color, &state.final_t);
    sw.lap("features");
    GradsOf {
        v_positions,
        v_rotations,
        v_log_scales,
        v_opacity_logits,
        v_sh,
        v_color_features,
        v_extra,
        v_background,
        v_mean2d_norm,
        phases: sw.finish(),
    }
}

/// The background's gradient: `C = ... + T_N bg`.
fn background_grad<F: Float>(bg: &BackgroundOf<F>, gc: Option<&[F]>, final_t: &[F]) -> Vec<F> {
    let npx = final_t.len();
    match (bg, gc) {
        (BackgroundOf::Color(_), None) => vec![F::ZERO; 3],
        (BackgroundOf::Image(_), None) => vec![F::ZERO; npx * 3],
        (BackgroundOf::Color(_), Some(gc)) => {
            // Chunks of pixels in parallel, their sums added in order: the same value at any
            // thread count.
            const PX: usize = 4096;
            let sums: Vec<[F; 3]> = final_t
                .par_chunks(PX)
                .zip(gc.par_chunks(3 * PX))
                .map(|(t, g)| {
                    let mut s = [F::ZERO; 3];
                    for (tp, gp) in t.iter().zip(g.chunks_exact(3)) {
                        for ch in 0..3 {
                            s[ch] += *tp * gp[ch];
                        }
                    }
                    s
                })
                .collect();
            let mut s = [F::ZERO; 3];
            for part in sums {
                for ch in 0..3 {
                    s[ch] += part[ch];
                }
            }
            s.to_vec()
        }
        (BackgroundOf::Image(_), Some(gc)) => {
            let mut v = filled(npx * 3, F::ZERO);
            v.par_chunks_mut(3).zip(gc.par_chunks(3)).zip(final_t).with_min_len(1024).for_each(|((o, g), t)| {
                for ch in 0..3 {
                    o[ch] = *t * g[ch];
                }
            });
            v
        }
    }
}

pub(crate) struct Ctx<'a, F: Float> {
    pub(crate) bins: &'a TileBins,
    pub(crate) recs: &'a [TileRec<F>],
    pub(crate) state: &'a ForwardStateOf<F>,
    pub(crate) cf: &'a FeatView<'a, F>,
    pub(crate) ef: &'a FeatView<'a, F>,
    pub(crate) grads: &'a OutputGradsOf<'a, F>,
    pub(crate) bg: &'a BackgroundOf<'a, F>,
    pub(crate) cfg: &'a RasterConfig,
    pub(crate) w: u32,
    pub(crate) h: u32,
    pub(crate) dim: usize,
    pub(crate) off_ext: usize,
}

/// Per-task buffers of the tile kernel, reused from tile to tile.
struct Scratch<F> {
    px: Vec<PixB<F>>,
    ge_px: Vec<F>,
    ext: Vec<F>,
    ev: Box<RowEval<F>>,
    /// Pixels by decreasing number of composited entries.
    by_ncon: Vec<(u32, u32)>,
    /// Per tile row, the columns that composited the current entry (they only join as the walk
    /// goes back to front).
    row_act: Vec<u64>,
    /// The SIMD kernel's per-pixel arrays ([`crate::backward_simd`]).
    lanes: Vec<f32>,
    /// The SIMD kernel's lane groups of the current entry.
    groups: crate::lane_groups::Groups,
}

impl<F: Float> Scratch<F> {
    fn new(tile: usize, ce: usize) -> Self {
        let tp = tile * tile;
        Self {
            px: vec![PixB::default(); tp],
            ge_px: vec![F::ZERO; tp * ce],
            ext: vec![F::ZERO; ce],
            ev: Box::default(),
            by_ncon: Vec::with_capacity(tp),
            row_act: vec![0; tile],
            lanes: Vec::new(),
            groups: crate::lane_groups::Groups::new(tile),
        }
    }
}

/// Dispatches to the kernel specialised for which optional paths are live (each is a branch
/// per composited pixel otherwise). Writes every slot of `eg`: the SIMD kernels zero each
/// entry's slot as they reach it (in cache), the scalar ones the whole tile's first.
fn backward_tile<F: Float>(ctx: &Ctx<F>, t: usize, eg: &mut [MaybeUninit<F>], scr: &mut Scratch<F>) {
    let ci = ctx.cf.vertices > 1;
    let ex = ctx.ef.channels > 0;
    let dist = ctx.cfg.distortion && ctx.grads.distortion.is_some();
    if crate::simd::is_f32::<F>() {
        // SAFETY: `F` is `f32` (checked above), so these are the same types.
        let (ctx32, eg32, lanes) = unsafe {
            (
                &*(ctx as *const Ctx<F> as *const Ctx<f32>),
                &mut *(eg as *mut [MaybeUninit<F>] as *mut [MaybeUninit<f32>]),
                &mut scr.lanes,
            )
        };
        let path = ctx.cfg.simd.resolve();
        if crate::backward_simd::backward_tile_simd(
            path,
            dist,
            ctx32,
            t,
            eg32,
            lanes,
            &mut scr.by_ncon,
            &mut scr.row_act,
            &mut scr.groups,
        ) {
            return;
        }
    }
    eg.fill(MaybeUninit::new(F::ZERO));
    // SAFETY: every element was written just above, and `MaybeUninit<F>` has `F`'s layout.
    let eg = unsafe { &mut *(eg as *mut [MaybeUninit<F>] as *mut [F]) };
    match (ci, ex, dist) {
        (false, false, false) => backward_tile_k::<F, false, false, false>(ctx, t, eg, scr),
        (false, false, true) => backward_tile_k::<F, false, false, true>(ctx, t, eg, scr),
        (false, true, false) => backward_tile_k::<F, false, true, false>(ctx, t, eg, scr),
        (false, true, true) => backward_tile_k::<F, false, true, true>(ctx, t, eg, scr),
        (true, false, false) => backward_tile_k::<F, true, false, false>(ctx, t, eg, scr),
        (true, false, true) => backward_tile_k::<F, true, false, true>(ctx, t, eg, scr),
        (true, true, false) => backward_tile_k::<F, true, true, false>(ctx, t, eg, scr),
        (true, true, true) => backward_tile_k::<F, true, true, true>(ctx, t, eg, scr),
    }
}

/// One tile; `eg` holds its entries' gradient slots. `CI`: colours interpolated from several
/// vertices; `EX`: extra feature channels; `DIST`: the distortion output has a gradient.
#[inline(never)]
fn backward_tile_k<F: Float, const CI: bool, const EX: bool, const DIST: bool>(
    ctx: &Ctx<F>,
    t: usize,
    eg: &mut [F],
    scr: &mut Scratch<F>,
) {
    let bins = ctx.bins;
    let (cf, ef) = (ctx.cf, ctx.ef);
    let ce = ef.channels;
    let dim = ctx.dim;
    let near = F::from_f32(ctx.cfg.near);
    let far = F::from_f32(ctx.cfg.far);
    let geom = ctx.cfg.geometry;
    let normals = geom && ctx.cfg.normals;
    let half = F::c(0.5);
    let two = F::c(2.0);
    // 2DGS's distortion depth m = far / (far - near) (1 - near / z) (as [`distortion_depth`]).
    let m_scale = far / (far - near);
    let wu = ctx.w as usize;
    let tile = bins.tile as usize;
    let Scratch { px, ge_px, ext, ev, by_ncon, row_act, .. } = scr;
    let g = ctx.grads;
    let st = ctx.state;
    let (mut wc, mut wcu, mut wcv) = ([F::ZERO; MAX_VERTICES], [F::ZERO; MAX_VERTICES], [F::ZERO; MAX_VERTICES]);
    let (mut we, mut weu, mut wev) = ([F::ZERO; MAX_VERTICES], [F::ZERO; MAX_VERTICES], [F::ZERO; MAX_VERTICES]);
    let mut col = [F::ZERO; 3];
    let offs = row_offsets::<F>();
    // Whether any feature is interpolated (else no gradient flows through u~, v~).
    let interp = CI || (EX && ef.vertices > 1);
    let tr = bins.tile_rect(t, ctx.w, ctx.h);
    let [r0, _] = bins.ranges[t];
    let e_tile0 = r0 as usize;
    let (tx0, ty0) = (tr[0] as usize, tr[2] as usize);
    // Load per-pixel state and upstream gradients.
    let mut max_n = 0u32;
    by_ncon.clear();
    row_act.fill(0);
    for y in tr[2] as usize..tr[3] as usize {
        for x in tr[0] as usize..tr[1] as usize {
            let li = (y - ty0) * tile + (x - tx0);
            let p = y * wu + x;
            let tn = st.final_t[p];
            let nc = st.n_contrib[p];
            max_n = max_n.max(nc);
            if nc > 0 {
                by_ncon.push((nc, ((y - ty0) * 64 + (x - tx0)) as u32));
            }
            let gc = g.color.map_or([F::ZERO; 3], |v| [v[p * 3], v[p * 3 + 1], v[p * 3 + 2]]);
            let b = background_at(ctx.bg, p);
            px[li] = PixB {
                t: tn,
                acc: tn * (gc[0] * b[0] + gc[1] * b[1] + gc[2] * b[2]),
                gc,
                // Without the geometry outputs their gradients are ignored (read as zero).
                gn: g.normal.filter(|_| normals).map_or([F::ZERO; 3], |v| [v[p * 3], v[p * 3 + 1], v[p * 3 + 2]]),
                go: g.alpha.map_or(F::ZERO, |v| v[p]),
                gd: g.depth.filter(|_| geom).map_or(F::ZERO, |v| v[p]),
                gdist: if DIST { g.distortion.map_or(F::ZERO, |v| v[p]) } else { F::ZERO },
                a: F::ONE - tn,
                m1: st.moment1[p],
                m2: st.moment2[p],
                ncon: nc,
            };
            for ch in 0..ce {
                ge_px[li * ce + ch] = g.extra.map_or(F::ZERO, |v| v[p * ce + ch]);
            }
        }
    }
    by_ncon.sort_unstable_by_key(|a| std::cmp::Reverse(a.0));
    let mut next_act = 0;
    for e in (r0 as usize..r0 as usize + max_n as usize).rev() {
        let local = (e - r0 as usize) as u32;
        while let Some(&(nc, rc)) = by_ncon.get(next_act) {
            if nc <= local {
                break;
            }
            row_act[rc as usize / 64] |= 1u64 << (rc % 64);
            next_act += 1;
        }
        // An entry that composited no pixel has no gradient (its pixels' transmittance passed
        // it unchanged): nothing to list.
        if st.entry_weight[e] == F::ZERO {
            continue;
        }
        let sp = &ctx.recs[e];
        let gid = sp.id as usize;
        let bx = EntryBox::new(sp, &tr);
        let plane = plane_setup(&sp.h);
        let slot = &mut eg[(e - e_tile0) * dim..(e - e_tile0 + 1) * dim];
        let mut sg = SplatGrad::<F>::default();
        let mut v_n = [F::ZERO; 3];
        // Colour gradient of a one-vertex colour, summed here rather than in the slot.
        let mut v_col = [F::ZERO; 3];
        for y in bx.rows.clone() {
            // Only pixels that composited this entry.
            let Some((yf, xa, xb)) = bx.row_span::<F>(&sp.conic, y, row_act[y - ty0]) else { continue };
            let row = (y - ty0) * tile;
            let rs = row_setup(&plane, yf);
            eval_row(&sp.h, sp.center, sp.opacity, &rs, yf, xa, xb - xa, near, &offs, ev);
            let xa_f = F::c(xa as f64) + half;
            for x in xa..xb {
                let i = x - xa;
                let li = row + (x - tx0);
                let p = &mut px[li];
                if local >= p.ncon || ev.alpha[i] == F::ZERO {
                    continue;
                }
                let xf = xa_f + offs[i];
                let hit = hit_from_row(sp.center, sp.opacity, ev, i, xf, yf);
                // One reciprocal for both divisions by (1 - alpha_i).
                let inv_one_m = F::ONE / (F::ONE - hit.alpha);
                let ti = p.t * inv_one_m;
                p.t = ti;
                let wgt = hit.alpha * ti;
                let (ut, dut, vt, dvt) = if interp {
                    let (ut, dut) = normalised_coord(hit.u);
                    let (vt, dvt) = normalised_coord(hit.v);
                    (ut, dut, vt, dvt)
                } else {
                    (F::ZERO, F::ZERO, F::ZERO, F::ZERO)
                };
                let gc = p.gc;
                let gn = p.gn;
                if CI {
                    weights(cf.vertices, ut, vt, &mut wc);
                    weight_grads(cf.vertices, ut, vt, &mut wcu, &mut wcv);
                    cf.eval(gid, &wc, &mut col);
                } else {
                    col = sp.color;
                }
                // Distortion depth m(z) and dm/dz, only when the distortion has a gradient.
                let (m, dm_dz) = if DIST {
                    let inv_z = F::ONE / hit.z;
                    (m_scale * (F::ONE - near * inv_z), m_scale * near * inv_z * inv_z)
                } else {
                    (F::ZERO, F::ZERO)
                };
                let mut gw = gc[0] * col[0]
                    + gc[1] * col[1]
                    + gc[2] * col[2]
                    + p.go
                    + p.gd * hit.z
                    + gn[0] * sp.normal[0]
                    + gn[1] * sp.normal[1]
                    + gn[2] * sp.normal[2];
                if DIST {
                    gw += p.gdist * (p.a * m * m - two * m * p.m1 + p.m2);
                }
                // d/du~, d/dv~ of sum_ch g_ch f_ch(u~, v~), times w.
                let (mut gut, mut gvt) = (F::ZERO, F::ZERO);
                if CI {
                    for vtx in 0..cf.vertices {
                        let row = &cf.data[(gid * cf.vertices + vtx) * 3..(gid * cf.vertices + vtx + 1) * 3];
                        let dot = gc[0] * row[0] + gc[1] * row[1] + gc[2] * row[2];
                        let cw = wgt * wc[vtx];
                        for ch in 0..3 {
                            slot[OFF_COL + vtx * 3 + ch] += cw * gc[ch];
                        }
                        gut += wcu[vtx] * dot;
                        gvt += wcv[vtx] * dot;
                    }
                } else {
                    for ch in 0..3 {
                        v_col[ch] += wgt * gc[ch];
                    }
                }
                if EX {
                    if ef.vertices > 1 {
                        weights(ef.vertices, ut, vt, &mut we);
                        weight_grads(ef.vertices, ut, vt, &mut weu, &mut wev);
                    } else {
                        we[0] = F::ONE;
                    }
                    ef.eval(gid, &we, ext);
                    let ge = &ge_px[li * ce..(li + 1) * ce];
                    for ch in 0..ce {
                        gw += ge[ch] * ext[ch];
                    }
                    let l = ef.lerped;
                    for vtx in 0..ef.vertices {
                        let base = (gid * ef.vertices + vtx) * ce;
                        let row = &ef.data[base..base + l];
                        let cw = wgt * we[vtx];
                        let mut dot = F::ZERO;
                        for ch in 0..l {
                            slot[ctx.off_ext + vtx * ce + ch] += cw * ge[ch];
                            dot += ge[ch] * row[ch];
                        }
                        if ef.vertices > 1 {
                            gut += weu[vtx] * dot;
                            gvt += wev[vtx] * dot;
                        }
                    }
                    // Uniform channels: one value, its gradient at vertex 0, and no (u, v) term
                    // (the constant does not move with the hit).
                    for ch in l..ce {
                        slot[ctx.off_ext + ch] += wgt * ge[ch];
                    }
                }
                let v_alpha = ti * gw - p.acc * inv_one_m;
                p.acc += gw * wgt;
                for ch in 0..3 {
                    v_n[ch] += wgt * gn[ch];
                }
                // Depth: D = sum w z; distortion: dDist/dm_i = 2 w_i (m_i A - M1).
                let mut v_z = wgt * p.gd;
                if DIST {
                    v_z += p.gdist * two * wgt * (m * p.a - p.m1) * dm_dz;
                }
                let (v_u, v_v) = if interp { (wgt * gut * dut, wgt * gvt * dvt) } else { (F::ZERO, F::ZERO) };
                intersect_backward(&hit, &sp.h, sp.center, sp.opacity, xf, yf, v_alpha, v_z, v_u, v_v, &mut sg);
            }
        }
        if !CI {
            for ch in 0..3 {
                slot[OFF_COL + ch] += v_col[ch];
            }
        }
        let v_h = sg.h_grad(&sp.h);
        for j in 0..9 {
            slot[OFF_H + j] += v_h[j];
        }
        slot[OFF_C] += sg.center[0];
        slot[OFF_C + 1] += sg.center[1];
        slot[OFF_OP] += sg.opacity;
        for j in 0..3 {
            slot[OFF_N + j] += v_n[j];
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::fixtures::{random_scene, Problem};
    use crate::simd::Simd;
    use crate::{backward, render, Grads, RasterConfig};

    fn bits(g: &Grads) -> Vec<Vec<u32>> {
        let b = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<u32>>();
        vec![
            b(g.v_positions.iter().flat_map(|v| v.to_array()).collect()),
            b(g.v_rotations.iter().flat_map(|v| v.to_array()).collect()),
            b(g.v_log_scales.iter().flat_map(|v| v.to_array()).collect()),
            b(g.v_opacity_logits.clone()),
            b(g.v_sh.iter().flat_map(|c| c.0.iter().flatten().copied()).collect()),
            b(g.v_background.clone()),
            b(g.v_mean2d_norm.clone()),
        ]
    }

    /// 30k random surfels at 64 x 64, every other one nearly opaque (opacity logit 6), so that
    /// pixels finish after a few layers.
    fn half_opaque() -> Problem {
        let mut surfels = random_scene(30_000, 11);
        for o in surfels.opacity_logits.iter_mut().step_by(2) {
            *o = 6.0;
        }
        Problem::with_surfels(surfels, 64)
    }

    /// Passing by the entries that composited nothing in the forward changes no gradient bit, on
    /// every path: the same backward with no entry marked empty gives the same gradients. Every
    /// other Gaussian is made nearly opaque, so pixels finish after a few layers and many entries
    /// further back in a tile find none of their pixels still open.
    #[test]
    fn entries_that_composited_nothing_are_passed_by_without_a_bit_changed() {
        let p = half_opaque();
        let (input, grads) = (p.input(), p.grads());
        for path in Simd::available() {
            let cfg = RasterConfig { simd: path, distortion: true, ..Default::default() };
            let (out, mut st) = render(&input, &cfg);
            let empty = st.entry_weight.iter().filter(|&&w| w == 0.0).count();
            assert!(
                empty * 4 > st.entry_weight.len(),
                "{}: only {empty} of {} entries composited nothing",
                path.name(),
                st.entry_weight.len()
            );
            let passed_by = bits(&backward(&input, &cfg, &st, &out, &grads));
            st.entry_weight.fill(1.0);
            let listed = bits(&backward(&input, &cfg, &st, &out, &grads));
            assert!(passed_by[3].iter().any(|&b| f32::from_bits(b) != 0.0), "{}: no opacity gradient", path.name());
            for (k, (a, b)) in passed_by.iter().zip(&listed).enumerate() {
                let differ = a.iter().zip(b).filter(|(x, y)| x != y).count();
                assert_eq!(differ, 0, "{}: gradient array {k} differs in {differ} of {} values", path.name(), a.len());
            }
        }
    }

    /// The SIMD backward on the forward's kept lane groups gives the gradients of the same
    /// backward listing each entry itself from the pixels that composited it (after a render
    /// with `for_backward` off, which keeps none and gives the same images): the lanes are the
    /// same, only their grouping, and so the order of the per-lane sums, may differ. Both are
    /// held to the scalar kernel's gradients: the kept groups may be off by no more than four
    /// times what the own listing is (plus 1e-5 of the largest gradient). The sums cancel
    /// heavily here, which is why the bound follows the paths' spread and not the gradients'
    /// size. Half the Gaussians are nearly opaque, so many pixels stop at an entry the forward
    /// had listed them for; a backward that kept them (`n_contrib` not tested) is off by 10^4
    /// to 10^7 times the spread.
    #[test]
    fn kept_lane_groups_give_the_gradients_of_the_backwards_own_listing() {
        let p = half_opaque();
        let (input, grads) = (p.input(), p.grads());
        let paths: Vec<Simd> = Simd::available().into_iter().filter(|&s| s != Simd::Scalar).collect();
        if paths.is_empty() {
            eprintln!("no SIMD path on this CPU: kept lane groups not checked");
        }
        let scalar_cfg = RasterConfig { simd: Simd::Scalar, distortion: true, ..Default::default() };
        let (sout, sst) = render(&input, &scalar_cfg);
        assert_eq!(sst.group_lanes, 0, "the scalar forward kept lane groups");
        let scalar = bits(&backward(&input, &scalar_cfg, &sst, &sout, &grads));
        let f = |v: &u32| f32::from_bits(*v);
        let off = |a: &[u32], b: &[u32]| a.iter().zip(b).map(|(x, y)| (f(x) - f(y)).abs()).fold(0.0f32, f32::max);
        for path in paths {
            let cfg = RasterConfig { simd: path, ..scalar_cfg };
            let (out, st) = render(&input, &cfg);
            assert!(st.group_lanes > 0 && !st.tile_groups.is_empty(), "{}: the forward kept no groups", path.name());
            let kept = bits(&backward(&input, &cfg, &st, &out, &grads));
            // A render no backward was announced for keeps none; its backward lists itself.
            let (out_own, own) = render(&input, &RasterConfig { for_backward: false, ..cfg });
            assert_eq!(own.group_lanes, 0, "{}: kept groups without a backward to follow", path.name());
            assert!(
                out_own.color == out.color && out_own.accum_weight == out.accum_weight,
                "{}: images differ",
                path.name()
            );
            let listed = bits(&backward(&input, &cfg, &own, &out_own, &grads));
            for (k, s) in scalar.iter().enumerate() {
                let scale = s.iter().map(|v| f(v).abs()).fold(0.0f32, f32::max);
                assert!(k >= 5 || scale > 0.0, "gradient array {k} is all zero");
                let (e_kept, e_own) = (off(&kept[k], s), off(&listed[k], s));
                assert!(
                    e_kept <= 4.0 * e_own + 1e-5 * scale,
                    "{}: gradient array {k} is {e_kept:e} from the scalar kernel's on kept groups, {e_own:e} on its \
                     own listing (largest gradient {scale:e})",
                    path.name()
                );
            }
        }
    }
}
