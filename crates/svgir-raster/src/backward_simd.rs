//! The backward tile kernel ([`crate::backward`]) vectorised across the pixels of a row, for
//! f32 (one colour per Gaussian, or colours and extra channels interpolated from a surfel's
//! vertices), compiled for AVX2 and AVX-512 and chosen at run time ([`crate::simd`]).
//!
//! Same work split and order as the scalar kernel: per tile, entries back to front, per entry the
//! rows of its box narrowed by the row chord and the pixels that composited it; `N` pixels at a
//! time, with the tile's per-pixel state and upstream gradients as one array per quantity. The
//! per-pixel chain (transmittance walk, suffix sum, `dL/dalpha`, the hit's gradient) is the
//! scalar arithmetic lane by lane; the per-Gaussian sums (`dL/dp` moments, centre, opacity,
//! normal, colour) are kept per lane and reduced once per entry, so they differ from the scalar
//! path's pixel-order sums by rounding only. Without geometry gradients
//! ([`crate::RasterConfig::geometry_grads`], the `GEO` parameter) the chain stops at `dL/dalpha`:
//! only the opacity, colour and feature sums are kept, with the same bits.

// The kernels are `unsafe fn`s with one contract -- the CPU has the features of the path that
// runs them (checked once by `Simd::resolve`) and every pointer stays inside its tile buffer --
// so the operations inside need no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]

use crate::backward::{Ctx, OFF_C, OFF_COL, OFF_H, OFF_N, OFF_OP};
use crate::forward::background_at;
use crate::forward::FeatView;
use crate::forward_simd::{eval_lanes, feat_weights_n, prefetch_rows, FeatLanes, PlaneLanes, FEAT_AHEAD};
use crate::interp::{normalised_coord_lanes, weight_grads_lanes, weights_lanes, MAX_VERTICES};
use crate::lane_groups::{Group, Groups};
use crate::simd::{Lanes, Simd};
use crate::splat::SplatGrad;
use crate::tiles::TileRec;
use std::mem::MaybeUninit;

// Per-pixel arrays of the tile, `stride * tile` each.
const T: usize = 0;
const ACC: usize = 1;
const GC: usize = 2;
const GN: usize = 5;
const GO: usize = 8;
const GD: usize = 9;
const GDIST: usize = 10;
const A: usize = 11;
const M1: usize = 12;
const M2: usize = 13;
const NCON: usize = 14;
const ARRAYS: usize = 15;

/// Per-lane sums of one entry.
#[derive(Clone, Copy)]
struct Sums<S: Lanes> {
    h_depth: [S; 3],
    center: [S; 2],
    opacity: S,
    gp: [S; 3],
    gp_x: [S; 3],
    gp_y: [S; 3],
    v_n: [S; 3],
    v_col: [S; 3],
}

/// `*acc += m ? d : 0` (masked lanes may hold NaN, so they are selected away, not multiplied).
#[inline(always)]
unsafe fn acc<S: Lanes>(a: &mut S, m: S::M, d: S) {
    *a = a.add(S::select(m, d, S::splat(0.0)));
}

impl<S: Lanes> Sums<S> {
    #[inline(always)]
    unsafe fn zero() -> Self {
        let z = S::splat(0.0);
        Self {
            h_depth: [z; 3],
            center: [z; 2],
            opacity: z,
            gp: [z; 3],
            gp_x: [z; 3],
            gp_y: [z; 3],
            v_n: [z; 3],
            v_col: [z; 3],
        }
    }
}

/// `out[k] += v[k].hsum()` for every k, eight sums at a time ([`Lanes::hsum8`], the same bits).
#[inline(always)]
unsafe fn add_hsums<S: Lanes>(v: &[S], out: &mut [f32]) {
    let mut chunks = v.chunks_exact(8);
    let mut k = 0;
    for c in &mut chunks {
        let c: &[S; 8] = c.try_into().expect("chunks of eight");
        let s = S::hsum8(c);
        for (o, x) in out[k..k + 8].iter_mut().zip(s) {
            *o += x;
        }
        k += 8;
    }
    for (o, f) in out[k..].iter_mut().zip(chunks.remainder()) {
        *o += f.hsum();
    }
}

#[inline(always)]
unsafe fn hsum3<S: Lanes>(v: &[S; 3]) -> [f32; 3] {
    [v[0].hsum(), v[1].hsum(), v[2].hsum()]
}

/// What the backward of one entry's groups reads: the tile arrays and the entry's values.
struct Entry<'a, S: Lanes> {
    /// The tile's per-pixel arrays, `np` floats each (see the constants above).
    base: *mut f32,
    np: usize,
    s: &'a TileRec<f32>,
    plane: PlaneLanes<S>,
    near: f32,
    m_scale: f32,
    /// Interpolated colour gradients in the feature sums (`M x 3`, or 0 for one colour).
    n_col: usize,
    /// Per-Gaussian colour and normal, broadcast.
    col1: [S; 3],
    nrm: [S; 3],
    cf: &'a FeatView<'a, f32>,
    ef: &'a FeatView<'a, f32>,
    colv: &'a FeatLanes<'a, S>,
    extv: &'a FeatLanes<'a, S>,
    /// Carry the normal and depth gradients ([`crate::RasterConfig::geometry`]).
    geom: bool,
    /// Carry the normal gradient ([`crate::RasterConfig::normals`], with `geom`).
    normals: bool,
    /// The entry's 0-based index in the tile: a pixel composited it when its `n_contrib`
    /// exceeds it.
    local: S,
    /// Both feature tables have four vertices (or the extra one no channel): the groups run
    /// with the vertex count a constant, so their vertex loops unroll (stage 2's PBR pass).
    v4: bool,
}

/// `fsum[k] = a * b` (an entry's first group) or `fsum[k] = fma(a, b, fsum[k])`, without a
/// bounds check.
///
/// # Safety
/// `k < fsum.len()`, and the lanes' CPU features are present.
#[inline(always)]
unsafe fn feat_acc<S: Lanes, const FIRST: bool>(fsum: &mut [S], k: usize, a: S, b: S) {
    debug_assert!(k < fsum.len());
    let f = fsum.get_unchecked_mut(k);
    *f = if FIRST { a.mul(b) } else { a.mul_add(b, *f) };
}

impl<S: Lanes> Entry<'_, S> {
    /// [`Self::group`] for the entry's next group: the first (`first` set, then cleared) stores
    /// the feature sums.
    #[inline(always)]
    unsafe fn next_group<const DIST: bool, const FEAT: bool, const GEO: bool, const PACKED: bool>(
        &self,
        gr: &Group,
        sm: &mut Sums<S>,
        fsum: &mut [S],
        first: &mut bool,
    ) -> bool {
        match (std::mem::take(first), FEAT && self.v4) {
            (true, true) => self.group::<DIST, FEAT, GEO, PACKED, true, 4>(gr, sm, fsum),
            (true, false) => self.group::<DIST, FEAT, GEO, PACKED, true, 0>(gr, sm, fsum),
            (false, true) => self.group::<DIST, FEAT, GEO, PACKED, false, 4>(gr, sm, fsum),
            (false, false) => self.group::<DIST, FEAT, GEO, PACKED, false, 0>(gr, sm, fsum),
        }
    }

    /// Runs group `gr` back to front through the tile arrays, adding its per-lane gradient sums
    /// to `sm` and the feature sums to `fsum`; false when no lane of it composited the entry
    /// (then it changed nothing: every update is masked, so the loop needs no branch).
    /// `FIRST`: the entry's first group, which stores its feature sums instead of adding them,
    /// so that `fsum` needs no zeroing per entry. `a * b` is `fma(a, b, 0)` but for the sign of
    /// an exact zero, which the entry's slots (zeroed, then added to) do not keep. `V`: the
    /// feature tables' vertex count when it is a constant ([`Entry::v4`]), else 0 (read from
    /// the tables); the operations are the same either way.
    #[inline(always)]
    unsafe fn group<
        const DIST: bool,
        const FEAT: bool,
        const GEO: bool,
        const PACKED: bool,
        const FIRST: bool,
        const V: usize,
    >(
        &self,
        gr: &Group,
        sm: &mut Sums<S>,
        fsum: &mut [S],
    ) -> bool {
        let sp = |v: f32| S::splat(v);
        let zero = sp(0.0);
        let (s, near, m_scale, n_col) = (self.s, self.near, self.m_scale, self.n_col);
        let (cf, ef, colv, extv, col1, nrm) = (self.cf, self.ef, self.colv, self.extv, self.col1, self.nrm);
        let (ce, ci) = (ef.channels, cf.vertices > 1);
        let interp = ci || (ce > 0 && ef.vertices > 1);
        // The tables' vertex counts, constants when `V` is set.
        let (cvn, evn) = if V > 0 { (V, V) } else { (cf.vertices, ef.vertices) };
        let arr = |k: usize| self.base.add(k * self.np);
        let (h6, h7) = (sp(s.h[6]), sp(s.h[7]));
        let (o, c0v) = (sp(s.opacity), sp(s.center[0]));
        let x = gr.x::<S, PACKED>();
        let rows = self.plane.rows(gr.y::<S, PACKED>());
        let ev = eval_lanes::<S>(s, &rows, x, near);
        let ld = |k: usize| gr.load::<S, PACKED>(arr(k));
        // The forward's groups hold the pixels still open when it reached the entry; the
        // pixel that stopped at it, and any whose last composited entry lies before it, drop
        // out here (with the backward's own listing the test holds on every listed lane).
        let m = S::and(S::and(S::from_bits(gr.lb), ev.alpha.ne(zero)), ld(NCON).gt(self.local));
        let yv = rows.y;
        let dy = sp(s.center[1]).sub(yv);
        let inv_one_m = sp(1.0).div(sp(1.0).sub(ev.alpha));
        let tcur = ld(T);
        let ti = tcur.mul(inv_one_m);
        gr.store::<S, PACKED>(arr(T), S::select(m, ti, tcur));
        let wgt = ev.alpha.mul(ti);
        let gc = [ld(GC), ld(GC + 1), ld(GC + 2)];
        // Geometry off: the normal and depth gradients are zero, so their terms are skipped
        // (adding exact zeros changes no bit but a zero's sign).
        let (geom, normals) = (self.geom, self.normals);
        let gn = if normals { [ld(GN), ld(GN + 1), ld(GN + 2)] } else { [zero; 3] };
        let gd = if geom { ld(GD) } else { zero };
        // Interpolation weights and their derivatives at the hit (features only). The
        // derivatives, and every sum below that only feeds the hit's (u, v) and depth, reach
        // positions, rotations and scales alone: skipped without `GEO`.
        let (ut, dut, vt, dvt) = if FEAT && interp {
            let (ut, dut) = normalised_coord_lanes(ev.u);
            let (vt, dvt) = normalised_coord_lanes(ev.v);
            (ut, dut, vt, dvt)
        } else {
            (zero, zero, zero, zero)
        };
        let (mut gut, mut gvt) = (zero, zero);
        let wgt_m = S::select(m, wgt, zero);
        let col = if FEAT && ci {
            let wc = weights_lanes(cvn, ut, vt);
            for vtx in 0..cvn {
                let cw = wgt_m.mul(wc[vtx]);
                for ch in 0..3 {
                    // SAFETY: `fsum` holds the colour table's `M x 3` sums first.
                    feat_acc::<S, FIRST>(fsum, vtx * 3 + ch, cw, gc[ch]);
                }
            }
            if GEO {
                let (wcu, wcv) = weight_grads_lanes(cvn, ut, vt);
                for vtx in 0..cvn {
                    let r = [0, 1, 2].map(|ch| colv.at(vtx * 3 + ch));
                    let dot = gc[0].mul(r[0]).add(gc[1].mul(r[1])).add(gc[2].mul(r[2]));
                    gut = wcu[vtx].mul_add(dot, gut);
                    gvt = wcv[vtx].mul_add(dot, gvt);
                }
            }
            [colv.eval_n(cf, &wc, 0, cvn), colv.eval_n(cf, &wc, 1, cvn), colv.eval_n(cf, &wc, 2, cvn)]
        } else {
            col1
        };
        // dL/dw as a tree of sums (a chain of eight adds was on the critical path).
        let g_col = gc[0].mul(col[0]).add(gc[1].mul(col[1])).add(gc[2].mul(col[2]));
        let mut gw = if normals {
            let g_nrm = gn[0].mul(nrm[0]).add(gn[1].mul(nrm[1])).add(gn[2].mul(nrm[2]));
            g_col.add(g_nrm).add(ld(GO).add(gd.mul(ev.z)))
        } else if geom {
            g_col.add(ld(GO).add(gd.mul(ev.z)))
        } else {
            g_col.add(ld(GO))
        };
        if FEAT && ce > 0 {
            let we = feat_weights_n(evn, ut, vt);
            let (weu, wev) = if GEO && evn > 1 {
                weight_grads_lanes(evn, ut, vt)
            } else {
                ([zero; MAX_VERTICES], [zero; MAX_VERTICES])
            };
            let mut g_ext = zero;
            for ch in 0..ce {
                g_ext = ld(ARRAYS + ch).mul_add(extv.eval_n(ef, &we, ch, evn), g_ext);
            }
            gw = gw.add(g_ext);
            let l = ef.lerped;
            // Channel by channel, each channel's gradient loaded once for the vertices (each
            // sum still gets one FMA per group, and each vertex's dot its channels in order).
            let (mut cw, mut dot) = ([zero; MAX_VERTICES], [zero; MAX_VERTICES]);
            for vtx in 0..evn {
                cw[vtx] = wgt_m.mul(we[vtx]);
            }
            for ch in 0..l {
                let ge = ld(ARRAYS + ch);
                for vtx in 0..evn {
                    // SAFETY: the extra table's `M x lerped` sums follow the colour's.
                    feat_acc::<S, FIRST>(fsum, n_col + vtx * l + ch, cw[vtx], ge);
                    if GEO {
                        dot[vtx] = ge.mul_add(extv.at(vtx * ce + ch), dot[vtx]);
                    }
                }
            }
            if GEO && evn > 1 {
                for vtx in 0..evn {
                    gut = weu[vtx].mul_add(dot[vtx], gut);
                    gvt = wev[vtx].mul_add(dot[vtx], gvt);
                }
            }
            // Uniform channels (`FeatView::lerped`): one sum each, after the vertices' (see
            // `fsum`), no (u, v) term.
            for ch in l..ce {
                // SAFETY: one sum per uniform channel after the vertices' (see `fsum`).
                feat_acc::<S, FIRST>(fsum, n_col + evn * l + ch - l, wgt_m, ld(ARRAYS + ch));
            }
        }
        let mut v_z = if GEO && geom { wgt.mul(gd) } else { zero };
        if DIST {
            let inv_z = sp(1.0).div(ev.z);
            let mz = sp(m_scale).mul(sp(1.0).sub(sp(near).mul(inv_z)));
            let (a, m1, m2, gdist) = (ld(A), ld(M1), ld(M2), ld(GDIST));
            gw = gw.add(gdist.mul(a.mul(mz).mul(mz).sub(sp(2.0).mul(mz).mul(m1)).add(m2)));
            if GEO {
                let dm_dz = sp(m_scale).mul(sp(near)).mul(inv_z).mul(inv_z);
                v_z = v_z.add(gdist.mul(sp(2.0)).mul(wgt).mul(mz.mul(a).sub(m1)).mul(dm_dz));
            }
        }
        // Upstream gradients are finite, so one masked weight serves all these sums.
        for ch in 0..3 {
            if !(FEAT && ci) {
                // One colour per Gaussian (interpolated colours are summed per vertex above).
                sm.v_col[ch] = wgt_m.mul_add(gc[ch], sm.v_col[ch]);
            }
            if GEO && normals {
                sm.v_n[ch] = wgt_m.mul_add(gn[ch], sm.v_n[ch]);
            }
        }
        let pacc = ld(ACC);
        let v_alpha = ti.mul(gw).sub(pacc.mul(inv_one_m));
        gr.store::<S, PACKED>(arr(ACC), S::select(m, pacc.add(gw.mul(wgt)), pacc));
        let free = S::andnot(m, o.mul(ev.g).gt(sp(0.99)));
        acc(&mut sm.opacity, free, v_alpha.mul(ev.g));
        if !GEO {
            return S::bits(m) != 0;
        }
        // The hit's backward ([`crate::splat::intersect_backward`]); the (u, v) input is the
        // interpolation's, `w d(sum_ch g_ch f_ch)/du~ du~/du`.
        let (mut gu, mut gv) = if FEAT && interp {
            (wgt.mul(gut).mul(dut).add(v_z.mul(h6)), wgt.mul(gvt).mul(dvt).add(v_z.mul(h7)))
        } else if geom || DIST {
            (v_z.mul(h6), v_z.mul(h7))
        } else {
            (zero, zero)
        };
        if geom || DIST {
            acc(&mut sm.h_depth[0], m, v_z.mul(ev.u));
            acc(&mut sm.h_depth[1], m, v_z.mul(ev.v));
            acc(&mut sm.h_depth[2], m, v_z);
        }
        let v_rho = sp(-0.5).mul(v_alpha).mul(o).mul(ev.g);
        let on3d = S::and(free, ev.use3d);
        gu = S::select(on3d, gu.add(sp(2.0).mul(v_rho).mul(ev.u)), gu);
        gv = S::select(on3d, gv.add(sp(2.0).mul(v_rho).mul(ev.v)), gv);
        let on2d = S::andnot(free, ev.use3d);
        let v4 = sp(4.0).mul(v_rho);
        acc(&mut sm.center[0], on2d, v4.mul(c0v.sub(x)));
        acc(&mut sm.center[1], on2d, v4.mul(dy));
        let inv = ev.inv_pz;
        let gp = [gu.mul(inv), gv.mul(inv), zero.sub(gu.mul(ev.u).add(gv.mul(ev.v))).mul(inv)];
        for j in 0..3 {
            // Masked once; x and y are finite pixel centres.
            let gpm = S::select(m, gp[j], zero);
            sm.gp[j] = sm.gp[j].add(gpm);
            sm.gp_x[j] = x.mul_add(gpm, sm.gp_x[j]);
            sm.gp_y[j] = yv.mul_add(gpm, sm.gp_y[j]);
        }
        S::bits(m) != 0
    }
}

/// One tile (see the module docs); `eg` holds its entries' gradient slots. `FEAT`: colours or
/// extra channels come from the feature tables (interpolated over vertices).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn tile_k<S: Lanes, const DIST: bool, const FEAT: bool, const GEO: bool>(
    ctx: &Ctx<f32>,
    t: usize,
    eg: &mut [MaybeUninit<f32>],
    buf: &mut Vec<f32>,
    by_ncon: &mut Vec<(u32, u32)>,
    row_act: &mut [u64],
    groups: &mut Groups,
) {
    let sp = |v: f32| S::splat(v);
    let bins = ctx.bins;
    let dim = ctx.dim;
    let near = ctx.cfg.near;
    let far = ctx.cfg.far;
    let geom = ctx.cfg.geometry;
    let normals = geom && ctx.cfg.normals;
    let m_scale = far / (far - near);
    let wu = ctx.w as usize;
    let tile = bins.tile as usize;
    let stride = tile + S::N;
    let np = stride * tile;
    let (cf, ef) = (ctx.cf, ctx.ef);
    let ce = ef.channels;
    let ci = cf.vertices > 1;
    buf.resize(np * (ARRAYS + ce), 0.0);
    let base = buf.as_mut_ptr();
    let arr = |k: usize| base.add(k * np);
    let g = ctx.grads;
    let st = ctx.state;
    let tr = bins.tile_rect(t, ctx.w, ctx.h);
    let [r0, _] = bins.ranges[t];
    let e_tile0 = r0 as usize;
    let (tx0, ty0) = (tr[0] as usize, tr[2] as usize);
    // The tile's first pixel centre, from which its groups' centres are formed.
    let origin = [(tx0 as f64 + 0.5) as f32, (ty0 as f64 + 0.5) as f32];
    // The forward's lane groups, when it kept them at this width; else each entry is listed
    // here, from the pixels that composited it.
    let kept = st.group_lanes == S::N;
    let mut max_n = 0u32;
    by_ncon.clear();
    row_act.fill(0);
    for y in tr[2] as usize..tr[3] as usize {
        for x in tr[0] as usize..tr[1] as usize {
            let li = (y - ty0) * stride + (x - tx0);
            let p = y * wu + x;
            let tn = st.final_t[p];
            let nc = st.n_contrib[p];
            max_n = max_n.max(nc);
            if nc > 0 && !kept {
                by_ncon.push((nc, ((y - ty0) * 64 + (x - tx0)) as u32));
            }
            let gc = g.color.map_or([0.0; 3], |v| [v[p * 3], v[p * 3 + 1], v[p * 3 + 2]]);
            // Without the geometry outputs their gradients are ignored (read as zero).
            let gn = g.normal.filter(|_| normals).map_or([0.0; 3], |v| [v[p * 3], v[p * 3 + 1], v[p * 3 + 2]]);
            let b = background_at(ctx.bg, p);
            let set = |k: usize, v: f32| *arr(k).add(li) = v;
            set(T, tn);
            set(ACC, tn * (gc[0] * b[0] + gc[1] * b[1] + gc[2] * b[2]));
            for ch in 0..3 {
                set(GC + ch, gc[ch]);
                set(GN + ch, gn[ch]);
            }
            set(GO, g.alpha.map_or(0.0, |v| v[p]));
            set(GD, g.depth.filter(|_| geom).map_or(0.0, |v| v[p]));
            set(GDIST, if DIST { g.distortion.map_or(0.0, |v| v[p]) } else { 0.0 });
            set(A, 1.0 - tn);
            set(M1, st.moment1[p]);
            set(M2, st.moment2[p]);
            set(NCON, nc as f32);
            for ch in 0..ce {
                set(ARRAYS + ch, g.extra.map_or(0.0, |v| v[p * ce + ch]));
            }
        }
    }
    // Per-entry feature rows (broadcast where read) and per-lane sums of their gradients: the colour
    // table's `M x 3` (interpolated colours only), then the extra table's `M x ce`.
    let (mut colv, mut extv) = (FeatLanes::<S>::new(), FeatLanes::<S>::new());
    let zero = sp(0.0);
    let n_col = if ci { cf.vertices * 3 } else { 0 };
    // The extra table's sums: `M x lerped`, vertex-major, then one per uniform channel (whose
    // gradient goes to vertex 0); with no uniform channel, the slots' own layout.
    let l = ef.lerped;
    let n_ext = ef.vertices * l + ce - l;
    let mut fsum = vec![zero; n_col + n_ext];
    // The groups' vertex loops run with a constant count where both tables have four vertices.
    let v4 = cf.vertices == 4 && (ce == 0 || ef.vertices == 4);
    let mut ext_sums = vec![0f32; if l < ce { n_ext } else { 0 }];
    by_ncon.sort_unstable_by_key(|a| std::cmp::Reverse(a.0));
    let mut next_act = 0;
    // The slots are zeroed as the entries are reached, so that the sums below add into cached
    // lines; the entries behind every pixel's last contributor are never reached.
    let zero_slots = |eg: &mut [MaybeUninit<f32>], a: usize, b: usize| {
        eg[(a - e_tile0) * dim..(b - e_tile0) * dim].fill(MaybeUninit::new(0.0));
    };
    let e_end = r0 as usize + max_n as usize;
    zero_slots(eg, e_end, bins.ranges[t][1] as usize);
    for e in (r0 as usize..e_end).rev() {
        zero_slots(eg, e, e + 1);
        let local = (e - r0 as usize) as u32;
        while let Some(&(nc, rc)) = by_ncon.get(next_act) {
            if nc <= local {
                break;
            }
            row_act[rc as usize / 64] |= 1u64 << (rc % 64);
            next_act += 1;
        }
        // As the scalar kernel: an entry that composited nothing is passed by unlisted.
        if st.entry_weight[e] == 0.0 {
            continue;
        }
        let s = &ctx.recs[e];
        if FEAT {
            // Entries run back to front: the one `FEAT_AHEAD` places nearer the front is hinted.
            if let Some(next) = e.checked_sub(FEAT_AHEAD).filter(|&n| n >= r0 as usize) {
                prefetch_rows(cf, ef, ctx.recs[next].id as usize);
            }
            if ci {
                colv.load(cf, s.id as usize);
            }
            if ce > 0 {
                extv.load(ef, s.id as usize);
            }
        }
        let k = Entry {
            base,
            np,
            s,
            plane: PlaneLanes::new(s),
            near,
            m_scale,
            n_col,
            col1: s.color.map(sp),
            nrm: s.normal.map(sp),
            cf,
            ef,
            colv: &colv,
            extv: &extv,
            geom,
            normals,
            local: sp(local as f32),
            v4,
        };
        let mut sm = Sums::<S>::zero();
        // The first group stores the feature sums (see `Entry::group`); with no group at all
        // `any` stays false and `fsum` is not read.
        let (mut any, mut first) = (false, FEAT);
        let listed = if kept {
            Some(st.entry_groups[e].split(&st.tile_groups[t]))
        } else {
            groups.list_here::<S>(s, &tr, row_act)
        };
        let (wide, packed) = listed.unwrap_or_default();
        for gr in wide.iter().map(|g| g.group(origin, stride)) {
            any |= k.next_group::<DIST, FEAT, GEO, false>(&gr, &mut sm, &mut fsum, &mut first);
        }
        for gr in packed.iter().map(|g| g.group(origin, stride)) {
            any |= k.next_group::<DIST, FEAT, GEO, true>(&gr, &mut sm, &mut fsum, &mut first);
        }
        if !any {
            continue;
        }
        let slot = &mut eg[(e - e_tile0) * dim..(e - e_tile0 + 1) * dim];
        // SAFETY: zeroed at the top of this iteration; `MaybeUninit<f32>` has `f32`'s layout.
        let slot = &mut *(slot as *mut [MaybeUninit<f32>] as *mut [f32]);
        if FEAT && ci {
            add_hsums(&fsum[..n_col], &mut slot[OFF_COL..OFF_COL + n_col]);
        }
        if FEAT {
            let ext = &mut slot[ctx.off_ext..ctx.off_ext + ef.vertices * ce];
            if l == ce {
                add_hsums(&fsum[n_col..], ext);
            } else {
                ext_sums.fill(0.0);
                add_hsums(&fsum[n_col..], &mut ext_sums);
                let (lerped, uniform) = ext_sums.split_at(ef.vertices * l);
                for (row, sums) in ext.chunks_exact_mut(ce).zip(lerped.chunks_exact(l.max(1))) {
                    row[..l].iter_mut().zip(sums).for_each(|(o, x)| *o += x);
                }
                ext[l..ce].iter_mut().zip(uniform).for_each(|(o, x)| *o += x);
            }
        }
        let one_colour = !(FEAT && ci);
        if !GEO {
            if one_colour {
                let v_col = hsum3(&sm.v_col);
                for ch in 0..3 {
                    slot[OFF_COL + ch] += v_col[ch];
                }
            }
            slot[OFF_OP] += sm.opacity.hsum();
            // The geometry slots stay zero (`crate::RasterConfig::geometry_grads`).
            continue;
        }
        // The entry's per-lane sums eight at a time ([`Lanes::hsum8`]: the bits of one by one).
        let z = sp(0.0);
        let col = if one_colour { sm.v_col } else { [z; 3] };
        let (n, hd, c, g) = (&sm.v_n, &sm.h_depth, &sm.center, &sm.gp);
        let a = S::hsum8(&[n[0], n[1], n[2], hd[0], hd[1], hd[2], c[0], c[1]]);
        let (gx, gy) = (&sm.gp_x, &sm.gp_y);
        let b = S::hsum8(&[sm.opacity, g[0], g[1], g[2], gx[0], gx[1], gx[2], gy[0]]);
        let d = S::hsum8(&[gy[1], gy[2], col[0], col[1], col[2], z, z, z]);
        if one_colour {
            for ch in 0..3 {
                slot[OFF_COL + ch] += d[2 + ch];
            }
        }
        slot[OFF_OP] += b[0];
        let sg = SplatGrad::from_sums(
            [a[3], a[4], a[5]],
            [a[6], a[7]],
            b[0],
            [b[1], b[2], b[3]],
            [b[4], b[5], b[6]],
            [b[7], d[0], d[1]],
        );
        let v_h = sg.h_grad(&s.h);
        for j in 0..9 {
            slot[OFF_H + j] += v_h[j];
        }
        slot[OFF_C] += sg.center[0];
        slot[OFF_C + 1] += sg.center[1];
        for j in 0..3 {
            slot[OFF_N + j] += a[j];
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn tile_avx2<const DIST: bool, const FEAT: bool, const GEO: bool>(
    ctx: &Ctx<f32>,
    t: usize,
    eg: &mut [MaybeUninit<f32>],
    buf: &mut Vec<f32>,
    by_ncon: &mut Vec<(u32, u32)>,
    row_act: &mut [u64],
    groups: &mut Groups,
) {
    tile_k::<crate::simd::F8, DIST, FEAT, GEO>(ctx, t, eg, buf, by_ncon, row_act, groups)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
unsafe fn tile_avx512<const DIST: bool, const FEAT: bool, const GEO: bool>(
    ctx: &Ctx<f32>,
    t: usize,
    eg: &mut [MaybeUninit<f32>],
    buf: &mut Vec<f32>,
    by_ncon: &mut Vec<(u32, u32)>,
    row_act: &mut [u64],
    groups: &mut Groups,
) {
    tile_k::<crate::simd::F8k, DIST, FEAT, GEO>(ctx, t, eg, buf, by_ncon, row_act, groups)
}

/// Runs tile `t` on the SIMD path `path` (already resolved); false when `path` is scalar (the
/// caller runs the generic kernel). `dist`: the distortion output has a gradient.
#[allow(clippy::too_many_arguments)]
pub(crate) fn backward_tile_simd(
    path: Simd,
    dist: bool,
    ctx: &Ctx<f32>,
    t: usize,
    eg: &mut [MaybeUninit<f32>],
    buf: &mut Vec<f32>,
    by_ncon: &mut Vec<(u32, u32)>,
    row_act: &mut [u64],
    groups: &mut Groups,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        let feat = ctx.cf.vertices > 1 || ctx.ef.channels > 0;
        let geo = ctx.cfg.geometry_grads;
        macro_rules! go {
            ($f:ident, $d:literal, $e:literal) => {
                if geo {
                    $f::<$d, $e, true>(ctx, t, eg, buf, by_ncon, row_act, groups)
                } else {
                    $f::<$d, $e, false>(ctx, t, eg, buf, by_ncon, row_act, groups)
                }
            };
        }
        // SAFETY: `resolve` only returns a path whose features the CPU has.
        unsafe {
            match (path, dist, feat) {
                (Simd::Avx2, false, false) => go!(tile_avx2, false, false),
                (Simd::Avx2, true, false) => go!(tile_avx2, true, false),
                (Simd::Avx2, false, true) => go!(tile_avx2, false, true),
                (Simd::Avx2, true, true) => go!(tile_avx2, true, true),
                (Simd::Avx512, false, false) => go!(tile_avx512, false, false),
                (Simd::Avx512, true, false) => go!(tile_avx512, true, false),
                (Simd::Avx512, false, true) => go!(tile_avx512, false, true),
                (Simd::Avx512, true, true) => go!(tile_avx512, true, true),
                _ => return false,
            }
        }
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (path, dist, ctx, t, eg, buf, by_ncon, row_act, groups);
        false
    }
}
