//! The backward tile kernel ([`crate::backward`]) vectorised across the pixels of a row, for
//! f32 with one colour per Gaussian and no extra channels, compiled for AVX2 and AVX-512 and
//! chosen at run time ([`crate::simd`]).
//!
//! Same work split and order as the scalar kernel: per tile, entries back to front, per entry the
//! rows of its box narrowed by the row chord and the pixels that composited it; `N` pixels at a
//! time, with the tile's per-pixel state and upstream gradients as one array per quantity. The
//! per-pixel chain (transmittance walk, suffix sum, `dL/dalpha`, the hit's gradient) is the
//! scalar arithmetic lane by lane; the per-Gaussian sums (`dL/dp` moments, centre, opacity,
//! normal, colour) are kept per lane and reduced once per entry, so they differ from the scalar
//! path's pixel-order sums by rounding only.

// The kernels are `unsafe fn`s with one contract -- the CPU has the features of the path that
// runs them (checked once by `Simd::resolve`) and every pointer stays inside its tile buffer --
// so the operations inside need no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]

use crate::backward::{Ctx, OFF_C, OFF_COL, OFF_H, OFF_N, OFF_OP};
use crate::forward::background_at;
use crate::forward_simd::{eval_lanes, list_groups, Group};
use crate::simd::{Lanes, Simd};
use crate::splat::SplatGrad;

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

#[inline(always)]
unsafe fn hsum3<S: Lanes>(v: &[S; 3]) -> [f32; 3] {
    [v[0].hsum(), v[1].hsum(), v[2].hsum()]
}

/// One tile (see the module docs); `eg` holds its entries' gradient slots.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn tile_k<S: Lanes, const DIST: bool>(
    ctx: &Ctx<f32>,
    t: usize,
    eg: &mut [f32],
    buf: &mut Vec<f32>,
    by_ncon: &mut Vec<(u32, u32)>,
    row_act: &mut [u64],
    groups: &mut Vec<Group>,
) {
    let sp = |v: f32| S::splat(v);
    let bins = ctx.bins;
    let dim = ctx.dim;
    let near = ctx.cfg.near;
    let far = ctx.cfg.far;
    let m_scale = far / (far - near);
    let wu = ctx.w as usize;
    let tile = bins.tile as usize;
    let stride = tile + S::N;
    let np = stride * tile;
    buf.resize(np * ARRAYS, 0.0);
    let base = buf.as_mut_ptr();
    let arr = |k: usize| base.add(k * np);
    let g = ctx.grads;
    let st = ctx.state;
    let tr = bins.tile_rect(t, ctx.w, ctx.h);
    let [r0, _] = bins.ranges[t];
    let e_tile0 = r0 as usize;
    let (tx0, ty0) = (tr[0] as usize, tr[2] as usize);
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
            if nc > 0 {
                by_ncon.push((nc, ((y - ty0) * 64 + (x - tx0)) as u32));
            }
            let gc = g.color.map_or([0.0; 3], |v| [v[p * 3], v[p * 3 + 1], v[p * 3 + 2]]);
            let gn = g.normal.map_or([0.0; 3], |v| [v[p * 3], v[p * 3 + 1], v[p * 3 + 2]]);
            let b = background_at(ctx.bg, p);
            let set = |k: usize, v: f32| *arr(k).add(li) = v;
            set(T, tn);
            set(ACC, tn * (gc[0] * b[0] + gc[1] * b[1] + gc[2] * b[2]));
            for ch in 0..3 {
                set(GC + ch, gc[ch]);
                set(GN + ch, gn[ch]);
            }
            set(GO, g.alpha.map_or(0.0, |v| v[p]));
            set(GD, g.depth.map_or(0.0, |v| v[p]));
            set(GDIST, if DIST { g.distortion.map_or(0.0, |v| v[p]) } else { 0.0 });
            set(A, 1.0 - tn);
            set(M1, st.moment1[p]);
            set(M2, st.moment2[p]);
            set(NCON, nc as f32);
        }
    }
    by_ncon.sort_unstable_by_key(|a| std::cmp::Reverse(a.0));
    let mut next_act = 0;
    let zero = sp(0.0);
    for e in (r0 as usize..r0 as usize + max_n as usize).rev() {
        let local = (e - r0 as usize) as u32;
        while let Some(&(nc, rc)) = by_ncon.get(next_act) {
            if nc <= local {
                break;
            }
            row_act[rc as usize / 64] |= 1u64 << (rc % 64);
            next_act += 1;
        }
        let s = &ctx.recs[e];
        let col = s.color.map(sp);
        let nrm = s.normal.map(sp);
        let (h6, h7) = (sp(s.h[6]), sp(s.h[7]));
        let (o, c0v) = (sp(s.opacity), sp(s.center[0]));
        let mut sm = Sums::<S> {
            h_depth: [zero; 3],
            center: [zero; 2],
            opacity: zero,
            gp: [zero; 3],
            gp_x: [zero; 3],
            gp_y: [zero; 3],
            v_n: [zero; 3],
            v_col: [zero; 3],
        };
        list_groups(s, &tr, row_act, S::N, groups);
        let mut any = false;
        for gr in groups.iter() {
            let x = sp(gr.xs).add(S::iota().add(sp(gr.off)));
            let ev = eval_lanes::<S>(s, &gr.rs, x, gr.yf, near);
            let m = S::and(S::from_bits(gr.lb), ev.alpha.ne(zero));
            // Branch-free: a group without live lanes adds nothing (every update is masked).
            any |= S::bits(m) != 0;
            let i = gr.ry as usize * stride + gr.c0 as usize;
            let yv = sp(gr.yf);
            let dy = sp(s.center[1] - gr.yf);
            let ld = |k: usize| S::load(arr(k).add(i));
            let inv_one_m = sp(1.0).div(sp(1.0).sub(ev.alpha));
            let tcur = ld(T);
            let ti = tcur.mul(inv_one_m);
            S::select(m, ti, tcur).store(arr(T).add(i));
            let wgt = ev.alpha.mul(ti);
            let gc = [ld(GC), ld(GC + 1), ld(GC + 2)];
            let gn = [ld(GN), ld(GN + 1), ld(GN + 2)];
            let gd = ld(GD);
            // dL/dw as a tree of sums (a chain of eight adds was on the critical path).
            let g_col = gc[0].mul(col[0]).add(gc[1].mul(col[1])).add(gc[2].mul(col[2]));
            let g_nrm = gn[0].mul(nrm[0]).add(gn[1].mul(nrm[1])).add(gn[2].mul(nrm[2]));
            let mut gw = g_col.add(g_nrm).add(ld(GO).add(gd.mul(ev.z)));
            let mut v_z = wgt.mul(gd);
            if DIST {
                let inv_z = sp(1.0).div(ev.z);
                let mz = sp(m_scale).mul(sp(1.0).sub(sp(near).mul(inv_z)));
                let dm_dz = sp(m_scale).mul(sp(near)).mul(inv_z).mul(inv_z);
                let (a, m1, m2, gdist) = (ld(A), ld(M1), ld(M2), ld(GDIST));
                gw = gw.add(gdist.mul(a.mul(mz).mul(mz).sub(sp(2.0).mul(mz).mul(m1)).add(m2)));
                v_z = v_z.add(gdist.mul(sp(2.0)).mul(wgt).mul(mz.mul(a).sub(m1)).mul(dm_dz));
            }
            // Upstream gradients are finite, so one masked weight serves all six sums.
            let wgt_m = S::select(m, wgt, zero);
            for ch in 0..3 {
                sm.v_col[ch] = wgt_m.mul_add(gc[ch], sm.v_col[ch]);
                sm.v_n[ch] = wgt_m.mul_add(gn[ch], sm.v_n[ch]);
            }
            let pacc = ld(ACC);
            let v_alpha = ti.mul(gw).sub(pacc.mul(inv_one_m));
            S::select(m, pacc.add(gw.mul(wgt)), pacc).store(arr(ACC).add(i));
            // The hit's backward ([`crate::splat::intersect_backward`]) with no (u, v) input.
            let mut gu = v_z.mul(h6);
            let mut gv = v_z.mul(h7);
            acc(&mut sm.h_depth[0], m, v_z.mul(ev.u));
            acc(&mut sm.h_depth[1], m, v_z.mul(ev.v));
            acc(&mut sm.h_depth[2], m, v_z);
            let free = S::andnot(m, o.mul(ev.g).gt(sp(0.99)));
            acc(&mut sm.opacity, free, v_alpha.mul(ev.g));
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
        }
        if !any {
            continue;
        }
        let slot = &mut eg[(e - e_tile0) * dim..(e - e_tile0 + 1) * dim];
        let v_col = hsum3(&sm.v_col);
        let v_n = hsum3(&sm.v_n);
        for ch in 0..3 {
            slot[OFF_COL + ch] += v_col[ch];
        }
        let sg = SplatGrad::from_sums(
            hsum3(&sm.h_depth),
            [sm.center[0].hsum(), sm.center[1].hsum()],
            sm.opacity.hsum(),
            hsum3(&sm.gp),
            hsum3(&sm.gp_x),
            hsum3(&sm.gp_y),
        );
        let v_h = sg.h_grad(&s.h);
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

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn tile_avx2<const DIST: bool>(
    ctx: &Ctx<f32>,
    t: usize,
    eg: &mut [f32],
    buf: &mut Vec<f32>,
    by_ncon: &mut Vec<(u32, u32)>,
    row_act: &mut [u64],
    groups: &mut Vec<Group>,
) {
    tile_k::<crate::simd::F8, DIST>(ctx, t, eg, buf, by_ncon, row_act, groups)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn tile_avx512<const DIST: bool>(
    ctx: &Ctx<f32>,
    t: usize,
    eg: &mut [f32],
    buf: &mut Vec<f32>,
    by_ncon: &mut Vec<(u32, u32)>,
    row_act: &mut [u64],
    groups: &mut Vec<Group>,
) {
    tile_k::<crate::simd::F16, DIST>(ctx, t, eg, buf, by_ncon, row_act, groups)
}

/// Runs tile `t` on the SIMD path `path` (already resolved); false when `path` is scalar (the
/// caller runs the generic kernel). `dist`: the distortion output has a gradient.
#[allow(clippy::too_many_arguments)]
pub(crate) fn backward_tile_simd(
    path: Simd,
    dist: bool,
    ctx: &Ctx<f32>,
    t: usize,
    eg: &mut [f32],
    buf: &mut Vec<f32>,
    by_ncon: &mut Vec<(u32, u32)>,
    row_act: &mut [u64],
    groups: &mut Vec<Group>,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: `resolve` only returns a path whose features the CPU has.
        unsafe {
            match (path, dist) {
                (Simd::Avx2, false) => tile_avx2::<false>(ctx, t, eg, buf, by_ncon, row_act, groups),
                (Simd::Avx2, true) => tile_avx2::<true>(ctx, t, eg, buf, by_ncon, row_act, groups),
                (Simd::Avx512, false) => tile_avx512::<false>(ctx, t, eg, buf, by_ncon, row_act, groups),
                (Simd::Avx512, true) => tile_avx512::<true>(ctx, t, eg, buf, by_ncon, row_act, groups),
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
