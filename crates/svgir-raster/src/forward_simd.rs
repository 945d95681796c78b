//! The forward tile kernel ([`crate::forward`]) vectorised across the pixels of a row, for f32
//! (one colour per Gaussian as in stage 1 and the SH renders, or colours and extra channels
//! interpolated from a surfel's vertices as in stage 2's PBR render), compiled for AVX2 and
//! AVX-512 and chosen at run time ([`crate::simd`]).
//!
//! Same work split and order as the scalar kernel: per run of tiles, per tile front to back,
//! per Gaussian the rows of its box narrowed by the row chord and the live-pixel masks. A row
//! segment is processed `N` pixels at a time, and two segments of at most `N/2` pixels on
//! different rows share one lane group ([`crate::lane_groups::Group`]): the ray-splat evaluation ([`eval_lanes`], the
//! arithmetic of [`crate::splat::eval_row`] lane by lane) and the compositing, with the per-pixel
//! accumulators of the tile kept as one array per quantity so that `N` neighbouring pixels are
//! one load. Skipped, finished and outside pixels are masked, never branched on. Every per-pixel
//! value is computed with the scalar kernel's operations in its order (FMA exactly where the
//! scalar kernel calls `mul_add`: the interpolation and accumulation of feature tables), so the
//! images are bit-identical to the scalar path; only the per-Gaussian weight sums are summed
//! lane-wise.

// The lane methods and kernels are `unsafe fn`s with one contract -- the CPU has the features
// of the path that runs them (checked once by `Simd::resolve`), every pointer stays inside
// its tile buffer and every output segment is the tile's own -- so the operations inside need
// no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]

use crate::forward::{background_at, FeatView, Outputs};
use crate::interp::{normalised_coord_lanes, weights_lanes, MAX_VERTICES};
use crate::lane_groups::{Group, Groups};
use crate::simd::Lanes;
use crate::splat::plane_setup;
use crate::tiles::{columns_mask, TileBins, TileRec};
use crate::{BackgroundOf, RasterConfig};
use std::marker::PhantomData;
use std::ops::Range;

/// One lane group's evaluation; `alpha == 0` marks a skipped pixel.
#[derive(Clone, Copy)]
pub(crate) struct Eval<S: Lanes> {
    pub alpha: S,
    pub u: S,
    pub v: S,
    pub z: S,
    pub g: S,
    pub inv_pz: S,
    /// `rho3 <= rho2`: the Gaussian, not the filter, decided rho.
    pub use3d: S::M,
}

/// The per-row inputs of a lane group, per lane: the hit-plane setup ([`crate::splat::RowSetup`]) and the
/// row centre y of the row each lane lies on.
pub(crate) struct RowLanes<S> {
    pub a: [S; 3],
    pub b: [S; 3],
    pub y: S,
}

/// An entry's hit-plane constants ([`crate::splat::PlaneSetup`]) broadcast to lanes, from which
/// each lane group forms its rows' setups.
pub(crate) struct PlaneLanes<S> {
    a: [S; 3],
    bw: [S; 3],
    b0: [S; 3],
}

impl<S: Lanes> PlaneLanes<S> {
    #[inline(always)]
    pub(crate) unsafe fn new(rec: &TileRec<f32>) -> Self {
        let p = plane_setup(&rec.h);
        let sp = |v: [f32; 3]| [S::splat(v[0]), S::splat(v[1]), S::splat(v[2])];
        Self { a: sp(p.a), bw: sp(p.bw), b0: sp(p.b0) }
    }

    /// [`crate::splat::row_setup`] on the rows with centres `y`, lane by lane (the same
    /// operations, so the same bits).
    #[inline(always)]
    pub(crate) unsafe fn rows(&self, y: S) -> RowLanes<S> {
        let b = |j: usize| y.mul(self.bw[j]).sub(self.b0[j]);
        RowLanes { a: self.a, b: [b(0), b(1), b(2)], y }
    }
}

/// [`crate::splat::eval_row`]'s per-pixel arithmetic at pixel centres `x` on the rows `r` (same
/// operations, same order, so the same bits).
#[inline(always)]
pub(crate) unsafe fn eval_lanes<S: Lanes>(rec: &TileRec<f32>, r: &RowLanes<S>, x: S, near: f32) -> Eval<S> {
    let [ev] = eval_lanes_k(rec, [r], [x], near);
    ev
}

/// [`eval_lanes`] for `K` lane groups at once, each step taken for all of them before the next:
/// one group's steps form a long chain of dependent operations (a division, the exponential),
/// and side by side the chains of several groups overlap. Per group, the same operations.
#[inline(always)]
pub(crate) unsafe fn eval_lanes_k<S: Lanes, const K: usize>(
    rec: &TileRec<f32>,
    r: [&RowLanes<S>; K],
    x: [S; K],
    near: f32,
) -> [Eval<S>; K] {
    // Plain loops over the K groups: closures (`map`, `from_fn`) are compiled without the
    // kernel's CPU features and their lane operations stay calls.
    let sp = |v: f32| S::splat(v);
    let z0 = sp(0.0);
    let (mut pz, mut inv_pz, mut u, mut v) = ([z0; K], [z0; K], [z0; K], [z0; K]);
    let (mut rho3, mut rho2, mut rho, mut z, mut g) = ([z0; K], [z0; K], [z0; K], [z0; K], [z0; K]);
    let mut px = [z0; K];
    for i in 0..K {
        px[i] = x[i].mul(r[i].a[0]).sub(r[i].b[0]);
        pz[i] = x[i].mul(r[i].a[2]).sub(r[i].b[2]);
    }
    for i in 0..K {
        inv_pz[i] = sp(1.0).div(pz[i]);
    }
    for i in 0..K {
        let py = x[i].mul(r[i].a[1]).sub(r[i].b[1]);
        u[i] = px[i].mul(inv_pz[i]);
        v[i] = py.mul(inv_pz[i]);
        rho3[i] = u[i].mul(u[i]).add(v[i].mul(v[i]));
        let dx = sp(rec.center[0]).sub(x[i]);
        let dy = sp(rec.center[1]).sub(r[i].y);
        rho2[i] = sp(2.0).mul(dx.mul(dx).add(dy.mul(dy)));
        // `rho3 <= rho2 ? rho3 : rho2`; equal values have the same bits (both sums of squares).
        rho[i] = rho2[i].min(rho3[i]);
        z[i] = u[i].mul(sp(rec.h[6])).add(v[i].mul(sp(rec.h[7]))).add(sp(rec.h[8]));
        g[i] = sp(-0.5).mul(rho[i]);
    }
    let g = svgir_core::simd::exp_fast_k(g);
    let mut out = [Eval { alpha: z0, u: z0, v: z0, z: z0, g: z0, inv_pz: z0, use3d: z0.lt(z0) }; K];
    for i in 0..K {
        let alpha = sp(rec.opacity).mul(g[i]).min(sp(0.99));
        let valid = S::and(
            S::and(pz[i].ne(sp(0.0)), rho[i].le(sp(9.0))),
            S::and(z[i].ge(sp(near)), alpha.ge(sp((1.0f64 / 255.0) as f32))),
        );
        out[i] = Eval {
            alpha: S::select(valid, alpha, sp(0.0)),
            u: u[i],
            v: v[i],
            z: z[i],
            g: g[i],
            inv_pz: inv_pz[i],
            use3d: rho3[i].le(rho2[i]),
        };
    }
    out
}

// The tile's per-pixel accumulators, one array of `stride * tile` each.
const T: usize = 0;
const COL: usize = 1;
const NRM: usize = 4;
const DEP: usize = 7;
const DST: usize = 8;
const M1: usize = 9;
const M2: usize = 10;
const MED: usize = 11;
const NCON: usize = 12;
const ARRAYS: usize = 13;

/// How many entries ahead the tile kernels hint the feature rows ([`FeatView::prefetch`]).
pub(crate) const FEAT_AHEAD: usize = 4;

/// Hints Gaussian `g`'s rows of the tables the tile kernels read: the colour table where colours
/// are interpolated (one colour per Gaussian comes with its record), and the extra table.
#[inline(always)]
pub(crate) fn prefetch_rows(cf: &FeatView<f32>, ef: &FeatView<f32>, g: usize) {
    if cf.vertices > 1 {
        cf.prefetch(g);
    }
    ef.prefetch(g);
}

/// One Gaussian's row of a feature table, `[m * channels + c]`, broadcast to lanes where it is
/// used. (Broadcasting the whole row into a buffer per entry cost more than the groups' reads:
/// most entries have two or three groups.)
pub(crate) struct FeatLanes<'a, S> {
    row: &'a [f32],
    lanes: PhantomData<S>,
}

impl<'a, S: Lanes> FeatLanes<'a, S> {
    pub(crate) fn new() -> Self {
        Self { row: &[], lanes: PhantomData }
    }

    /// Points at Gaussian `g`'s row of `f`.
    #[inline(always)]
    pub(crate) fn load(&mut self, f: &FeatView<'a, f32>, g: usize) {
        let n = f.vertices * f.channels;
        self.row = &f.data[g * n..(g + 1) * n];
    }

    /// Value `i` of the row (`m * channels + c`), broadcast.
    ///
    /// # Safety
    /// The lanes' CPU features are present and `i` lies in the row.
    #[inline(always)]
    pub(crate) unsafe fn at(&self, i: usize) -> S {
        debug_assert!(i < self.row.len());
        S::splat(*self.row.get_unchecked(i))
    }

    /// Channel `c` at vertex weights `w` (`FeatView::eval`'s operations: one vertex and the
    /// uniform channels are copied, the others are the first vertex's product plus the others'
    /// by FMA, in vertex order).
    #[inline(always)]
    pub(crate) unsafe fn eval(&self, f: &FeatView<f32>, w: &[S; MAX_VERTICES], c: usize) -> S {
        self.eval_n(f, w, c, f.vertices)
    }

    /// [`Self::eval`] with the table's vertex count `nv` passed in (a constant in the callers
    /// that know it, so the loop unrolls: the backward's groups on stage 2's PBR pass).
    #[inline(always)]
    pub(crate) unsafe fn eval_n(&self, f: &FeatView<f32>, w: &[S; MAX_VERTICES], c: usize, nv: usize) -> S {
        debug_assert_eq!(nv, f.vertices);
        let ch = f.channels;
        if nv == 1 || c >= f.lerped {
            return self.at(c);
        }
        let mut out = w[0].mul(self.at(c));
        for m in 1..nv {
            out = w[m].mul_add(self.at(m * ch + c), out);
        }
        out
    }
}

/// The vertex weights of a feature table at normalised hit coordinates (one vertex: unused).
#[inline(always)]
pub(crate) unsafe fn feat_weights<S: Lanes>(f: &FeatView<f32>, ut: S, vt: S) -> [S; MAX_VERTICES] {
    feat_weights_n(f.vertices, ut, vt)
}

/// [`feat_weights`] for a table of `nv` vertices (a constant where the caller knows it).
#[inline(always)]
pub(crate) unsafe fn feat_weights_n<S: Lanes>(nv: usize, ut: S, vt: S) -> [S; MAX_VERTICES] {
    if nv > 1 {
        weights_lanes(nv, ut, vt)
    } else {
        [S::splat(1.0); MAX_VERTICES]
    }
}

/// What the compositing of one entry's groups reads: the tile arrays and the entry's values.
struct Composite<'a, S: Lanes> {
    /// The tile's accumulators, `np` floats per array (see the constants above).
    base: *mut f32,
    np: usize,
    s: &'a TileRec<f32>,
    plane: PlaneLanes<S>,
    near: f32,
    m_scale: f32,
    t_stop: f32,
    /// Per-Gaussian colour and normal, broadcast.
    col1: [S; 3],
    nrm: [S; 3],
    /// The entry's 1-based index in the tile (what `n_contrib` records).
    local: S,
    /// Accumulate normal, depth and median depth ([`crate::RasterConfig::geometry`]).
    geom: bool,
    /// Accumulate the normal ([`crate::RasterConfig::normals`], with `geom`).
    normals: bool,
    cf: &'a FeatView<'a, f32>,
    ef: &'a FeatView<'a, f32>,
    colv: &'a FeatLanes<'a, S>,
    extv: &'a FeatLanes<'a, S>,
}

impl<S: Lanes> Composite<'_, S> {
    /// The entry's evaluation on group `gr` ([`eval_lanes`]).
    #[inline(always)]
    unsafe fn eval<const PACKED: bool>(&self, gr: &Group) -> Eval<S> {
        eval_lanes::<S>(self.s, &self.plane.rows(gr.y::<S, PACKED>()), gr.x::<S, PACKED>(), self.near)
    }

    /// The entry's evaluations on two groups side by side ([`eval_lanes_k`]).
    #[inline(always)]
    unsafe fn eval2<const PACKED: bool>(&self, g0: &Group, g1: &Group) -> [Eval<S>; 2] {
        let (r0, r1) = (self.plane.rows(g0.y::<S, PACKED>()), self.plane.rows(g1.y::<S, PACKED>()));
        eval_lanes_k::<S, 2>(self.s, [&r0, &r1], [g0.x::<S, PACKED>(), g1.x::<S, PACKED>()], self.near)
    }

    /// Composites group `gr`, evaluated as `ev`, into the tile arrays; returns the lanes that
    /// stopped (transmittance fell under `t_stop`) and adds the composited weights to `ws`.
    #[inline(always)]
    unsafe fn group<const DIST: bool, const FEAT: bool, const PACKED: bool>(
        &self,
        gr: &Group,
        ev: Eval<S>,
        ws: &mut S,
    ) -> u32 {
        let sp = |v: f32| S::splat(v);
        let a = |k: usize| self.base.add(k * self.np);
        let (ld, add, set) = (
            |k: usize| gr.load::<S, PACKED>(a(k)),
            |k: usize, m: S::M, d: S| gr.add_masked::<S, PACKED>(a(k), m, d),
            |k: usize, m: S::M, d: S| gr.set_masked::<S, PACKED>(a(k), m, d),
        );
        let fma = |k: usize, m: S::M, x: S, y: S| gr.fma_masked::<S, PACKED>(a(k), m, x, y);
        let (cf, ef) = (self.cf, self.ef);
        let (ci, ce) = (cf.vertices > 1, ef.channels);
        let interp = ci || (ce > 0 && ef.vertices > 1);
        let live = S::and(S::from_bits(gr.lb), ev.alpha.ne(sp(0.0)));
        let tcur = ld(T);
        let test = tcur.mul(sp(1.0).sub(ev.alpha));
        let stop = S::and(live, test.lt(sp(self.t_stop)));
        let comp = S::andnot(live, stop);
        let wgt = ev.alpha.mul(tcur);
        let (ut, vt) = if FEAT && interp {
            (normalised_coord_lanes(ev.u).0, normalised_coord_lanes(ev.v).0)
        } else {
            (sp(0.0), sp(0.0))
        };
        let col = if FEAT && ci {
            let wc = weights_lanes(cf.vertices, ut, vt);
            [self.colv.eval(cf, &wc, 0), self.colv.eval(cf, &wc, 1), self.colv.eval(cf, &wc, 2)]
        } else {
            self.col1
        };
        // Feature tables (stage 2's PBR pass) accumulate by FMA, as the scalar kernel does for
        // them; one colour per Gaussian keeps the product and the sum (stage 1's bits).
        if FEAT && ce > 0 {
            let we = feat_weights(ef, ut, vt);
            for ch in 0..ce {
                fma(ARRAYS + ch, comp, wgt, self.extv.eval(ef, &we, ch));
            }
        }
        for ch in 0..3 {
            if FEAT && ci {
                fma(COL + ch, comp, wgt, col[ch]);
            } else {
                add(COL + ch, comp, wgt.mul(col[ch]));
            }
        }
        if self.normals {
            for ch in 0..3 {
                add(NRM + ch, comp, wgt.mul(self.nrm[ch]));
            }
        }
        if self.geom {
            add(DEP, comp, wgt.mul(ev.z));
            set(MED, S::and(comp, tcur.gt(sp(0.5))), ev.z);
        }
        if DIST {
            // As the scalar kernel: w_i (m_i^2 A_i + M2 - 2 m_i M1), A_i = 1 - T_i.
            let m = sp(self.m_scale).mul(sp(1.0).sub(sp(self.near).div(ev.z)));
            let (m1, m2) = (ld(M1), ld(M2));
            let d = m.mul(m).mul(sp(1.0).sub(tcur)).add(m2).sub(sp(2.0).mul(m).mul(m1)).mul(wgt);
            add(DST, comp, d);
            gr.store::<S, PACKED>(a(M1), S::select(comp, m1.add(m.mul(wgt)), m1));
            gr.store::<S, PACKED>(a(M2), S::select(comp, m2.add(m.mul(m).mul(wgt)), m2));
        }
        set(T, comp, test);
        set(NCON, comp, self.local);
        *ws = ws.add(S::select(comp, wgt, sp(0.0)));
        S::bits(stop)
    }
}

/// A run of tiles, `S::N` pixels at a time (see the module docs). `FEAT`: the colours or
/// extra channels come from the feature tables `cf` / `ef` (interpolated over vertices).
/// `PAIRS`: evaluate an entry's groups two at a time where it has no feature tables.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn tiles<S: Lanes, const DIST: bool, const FEAT: bool, const PAIRS: bool>(
    o: &Outputs<f32>,
    run: Range<usize>,
    bins: &TileBins,
    recs: &[TileRec<f32>],
    cf: &FeatView<f32>,
    ef: &FeatView<f32>,
    bg: &BackgroundOf<f32>,
    cfg: &RasterConfig,
    w: u32,
    h: u32,
) {
    let sp = |v: f32| S::splat(v);
    let wu = w as usize;
    let tile = bins.tile as usize;
    // Row stride: a full lane group from any column of the tile stays in its row.
    let stride = tile + S::N;
    let np = stride * tile;
    let ce = ef.channels;
    let ci = cf.vertices > 1;
    let mut buf = vec![0f32; np * (ARRAYS + ce)];
    let (mut colv, mut extv) = (FeatLanes::<S>::new(), FeatLanes::<S>::new());
    let mut row_live = vec![0u64; tile];
    let mut groups = Groups::new(tile);
    let keep = !o.tile_groups.is_empty();
    let mut scratch = Vec::new();
    for t in run {
        let tr = bins.tile_rect(t, w, h);
        let [r0, r1] = bins.ranges[t];
        let (tx0, ty0) = (tr[0] as usize, tr[2] as usize);
        // The tile's first pixel centre, from which its groups' centres are formed.
        let origin = [(tx0 as f64 + 0.5) as f32, (ty0 as f64 + 0.5) as f32];
        // SAFETY (every `seg` of this tile): tile `t` alone owns its entries and its pixels.
        let wsum = unsafe { o.wsum.seg(r0 as usize, (r1 - r0) as usize) };
        // The groups are listed into the tile's kept vector when a backward follows, else into
        // `scratch`, one entry at a time.
        let mut kept = keep.then(|| unsafe { &mut o.tile_groups.seg(t, 1)[0] });
        let mut kept_at = keep.then(|| unsafe { o.entry_groups.seg(r0 as usize, (r1 - r0) as usize) });
        if let Some(k) = kept.as_deref_mut() {
            // Four or five groups per entry on the random 400 x 400 scene; more grow the vector.
            k.reserve(6 * (r1 - r0) as usize);
        }
        buf[..np].fill(1.0);
        buf[np..].fill(0.0);
        let mut remaining = (tr[1] - tr[0]) as usize * (tr[3] - tr[2]) as usize;
        row_live.fill(columns_mask(0, (tr[1] - tr[0]) as usize));
        for e in r0 as usize..r1 as usize {
            if remaining == 0 {
                break;
            }
            let s = &recs[e];
            if FEAT {
                if let Some(next) = recs[..r1 as usize].get(e + FEAT_AHEAD) {
                    prefetch_rows(cf, ef, next.id as usize);
                }
            }
            // Boxes whose pixels have all finished (common behind opaque surfaces, while the
            // tile's other pixels are still open) are passed by.
            let out = match kept.as_deref_mut() {
                Some(k) => k,
                None => {
                    scratch.clear();
                    &mut scratch
                }
            };
            let Some(at) = groups.list::<S>(s, &tr, &row_live, out) else {
                continue;
            };
            if let Some(ka) = kept_at.as_deref_mut() {
                ka[e - r0 as usize] = at;
            }
            if FEAT {
                if ci {
                    colv.load(cf, s.id as usize);
                }
                if ce > 0 {
                    extv.load(ef, s.id as usize);
                }
            }
            let k = Composite {
                base: buf.as_mut_ptr(),
                np,
                s,
                plane: PlaneLanes::new(s),
                near: cfg.near,
                m_scale: cfg.far / (cfg.far - cfg.near),
                t_stop: cfg.t_stop,
                col1: s.color.map(sp),
                nrm: s.normal.map(sp),
                local: sp((e - r0 as usize + 1) as f32),
                geom: cfg.geometry,
                normals: cfg.geometry && cfg.normals,
                cf,
                ef,
                colv: &colv,
                extv: &extv,
            };
            let mut ws = sp(0.0);
            // Branch-free: a group without stopping lanes clears nothing.
            let (wide, packed) = at.split(kept.as_deref().unwrap_or(&scratch));
            // With `PAIRS` and no feature tables, groups in pairs, evaluated side by side
            // ([`eval_lanes_k`]), then composited in order; else one at a time (chunks of
            // `usize::MAX` leave every group to the remainder's loop).
            macro_rules! run {
                ($list:expr, $packed:literal) => {
                    let mut pairs = $list.chunks_exact(if PAIRS && !FEAT { 2 } else { usize::MAX });
                    for p in &mut pairs {
                        let (g0, g1) = (p[0].group(origin, stride), p[1].group(origin, stride));
                        let [e0, e1] = k.eval2::<$packed>(&g0, &g1);
                        for (gr, ev) in [(&g0, e0), (&g1, e1)] {
                            let sb = k.group::<DIST, FEAT, $packed>(gr, ev, &mut ws);
                            gr.clear::<$packed>(&mut row_live, sb, S::N);
                            remaining -= sb.count_ones() as usize;
                        }
                    }
                    for gr in pairs.remainder().iter().map(|g| g.group(origin, stride)) {
                        let sb = k.group::<DIST, FEAT, $packed>(&gr, k.eval::<$packed>(&gr), &mut ws);
                        gr.clear::<$packed>(&mut row_live, sb, S::N);
                        remaining -= sb.count_ones() as usize;
                    }
                };
            }
            run!(wide, false);
            run!(packed, true);
            wsum[e - r0 as usize] = ws.hsum();
        }
        // The tile's rows out to the images, a row of each array at a time (slice copies and
        // loops the compiler vectorises; per pixel, the same values as the scalar kernel's).
        let wt = (tr[1] - tr[0]) as usize;
        for y in tr[2] as usize..tr[3] as usize {
            let l0 = (y - ty0) * stride;
            let b0 = y * wu + tx0;
            let row = |k: usize| &buf[k * np + l0..k * np + l0 + wt];
            let t = row(T);
            let r = o.row(b0, wt, ce);
            r.final_t.copy_from_slice(t);
            r.alpha.iter_mut().zip(t).for_each(|(a, tn)| *a = 1.0 - tn);
            r.depth.copy_from_slice(row(DEP));
            r.median.copy_from_slice(row(MED));
            r.dist.copy_from_slice(row(DST));
            r.m1.copy_from_slice(row(M1));
            r.m2.copy_from_slice(row(M2));
            r.n_contrib.iter_mut().zip(row(NCON)).for_each(|(n, v)| *n = *v as u32);
            let (col, nrm) = ([row(COL), row(COL + 1), row(COL + 2)], [row(NRM), row(NRM + 1), row(NRM + 2)]);
            for (i, (c_out, n_out)) in r.color.chunks_exact_mut(3).zip(r.normal.chunks_exact_mut(3)).enumerate() {
                let c = background_at(bg, b0 + i);
                for ch in 0..3 {
                    c_out[ch] = col[ch][i] + t[i] * c[ch];
                    n_out[ch] = nrm[ch][i];
                }
            }
            for ch in 0..ce {
                r.extra.iter_mut().skip(ch).step_by(ce).zip(row(ARRAYS + ch)).for_each(|(e, v)| *e = *v);
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn tiles_avx2<const DIST: bool, const FEAT: bool>(
    o: &Outputs<f32>,
    run: Range<usize>,
    bins: &TileBins,
    recs: &[TileRec<f32>],
    cf: &FeatView<f32>,
    ef: &FeatView<f32>,
    bg: &BackgroundOf<f32>,
    cfg: &RasterConfig,
    w: u32,
    h: u32,
) {
    // Pairs of groups side by side: the forward tiles took 8-10% less on the random 400 x 400
    // scene (no less in stage 2's PBR pass, so `tiles` pairs them only without feature tables).
    tiles::<crate::simd::F8, DIST, FEAT, true>(o, run, bins, recs, cf, ef, bg, cfg, w, h)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn tiles_avx512<const DIST: bool, const FEAT: bool>(
    o: &Outputs<f32>,
    run: Range<usize>,
    bins: &TileBins,
    recs: &[TileRec<f32>],
    cf: &FeatView<f32>,
    ef: &FeatView<f32>,
    bg: &BackgroundOf<f32>,
    cfg: &RasterConfig,
    w: u32,
    h: u32,
) {
    // No pairs: no gain on the random scene, and stage 2's PBR pass took 10-15% more with them.
    tiles::<crate::simd::F8k, DIST, FEAT, false>(o, run, bins, recs, cf, ef, bg, cfg, w, h)
}

/// The width of the lane groups that the SIMD path `path` (already resolved) runs and keeps
/// for the backward ([`crate::ForwardStateOf::tile_groups`]); 0 for the scalar path.
pub(crate) fn group_lanes(path: crate::simd::Simd) -> usize {
    #[cfg(target_arch = "x86_64")]
    {
        use crate::simd::{Lanes, Simd};
        match path {
            Simd::Avx2 => crate::simd::F8::N,
            Simd::Avx512 => crate::simd::F8k::N,
            _ => 0,
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = path;
        0
    }
}

/// Runs the tiles `run` on the SIMD path `path` (already resolved); false when `path` is
/// scalar (the caller runs the generic kernel). Each tile's lane groups are kept in `o`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn render_tiles_simd(
    path: crate::simd::Simd,
    o: &Outputs<f32>,
    run: Range<usize>,
    bins: &TileBins,
    recs: &[TileRec<f32>],
    cf: &FeatView<f32>,
    ef: &FeatView<f32>,
    bg: &BackgroundOf<f32>,
    cfg: &RasterConfig,
    w: u32,
    h: u32,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        use crate::simd::Simd;
        let feat = cf.vertices > 1 || ef.channels > 0;
        macro_rules! go {
            ($f:ident, $d:literal, $e:literal) => {
                $f::<$d, $e>(o, run, bins, recs, cf, ef, bg, cfg, w, h)
            };
        }
        // SAFETY: `resolve` only returns a path whose features the CPU has.
        unsafe {
            match (path, cfg.distortion, feat) {
                (Simd::Avx2, false, false) => go!(tiles_avx2, false, false),
                (Simd::Avx2, true, false) => go!(tiles_avx2, true, false),
                (Simd::Avx2, false, true) => go!(tiles_avx2, false, true),
                (Simd::Avx2, true, true) => go!(tiles_avx2, true, true),
                (Simd::Avx512, false, false) => go!(tiles_avx512, false, false),
                (Simd::Avx512, true, false) => go!(tiles_avx512, true, false),
                (Simd::Avx512, false, true) => go!(tiles_avx512, false, true),
                (Simd::Avx512, true, true) => go!(tiles_avx512, true, true),
                _ => return false,
            }
        }
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (path, o, run, bins, recs, cf, ef, bg, cfg, w, h);
        false
    }
}
