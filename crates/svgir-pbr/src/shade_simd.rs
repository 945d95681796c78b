//! f32 lane kernels of the vertex shading ([`crate::shade()`]) and its backward
//! ([`crate::shade_backward()`]), run where the CPU has AVX2 (`svgir_core::simd`). Where it has
//! AVX-512F+VL the same 8-lane code is compiled a second time over `F8k` (compares into mask
//! registers, 32 vector registers): the same bits, 5-7% faster forward and backward on an Intel
//! Xeon VM (docs/performance.md).
//!
//! The generic kernels loop sample by sample and, inside, vertex by vertex, skipping the
//! directions below each vertex's horizon: an unpredictable branch around a GGX evaluation with
//! a division. Here each Gaussian's samples are first written out as structure-of-arrays rows
//! ([`SampleRows`]: direction, half vector, Fresnel, direct and indirect light; the scalar
//! per-sample code of `shade.rs`, once per Gaussian), padded to a multiple of [`W`] lanes with
//! samples that carry nothing. Then, vertex by vertex, the (vertex, direction) work runs over
//! [`W`] samples at a time in AVX2 lanes (`svgir_core::simd::F8`) without a branch: the horizon
//! test becomes a select. [`spec_lanes`] and [`spec_grad_lanes`] are `split::spec` and
//! `spec_grad` written over lanes, operation for operation in the same order and without FMA,
//! so each lane computes the scalar value bit for bit. (Written as plain per-lane loops, the
//! compiler left this code scalar.)
//!
//! What differs from the scalar oracle: the sums over directions (E, P, and in the backward the
//! roughness and normal gradients) are summed lane-wise and then across lanes, so they differ by
//! rounding; per-sample quantities (the light gradient `v_lin`, summed over vertices in vertex
//! order, and hence the env-map and rho gradients) are evaluated in the scalar order. Asked for
//! the colour alone (`ShadeOutput::colour_only`, training), the forward sums each sample's direct
//! and indirect light once and keeps one E and one P per channel instead of two. The tests
//! (`tests/shade_simd.rs`) hold both to the generic f32 kernels and to f64.
//!
//! Work split: as the scalar kernels (rayon over Gaussians forward, over fixed blocks backward);
//! one `SampleRows` scratch per rayon task. Nothing is saved for backward.

// The kernels are `unsafe fn`s with one contract -- the CPU has AVX2 (checked by the caller
// through `Simd::resolve`) -- so the operations inside need no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]

use crate::sample_lanes::{samples8, samples_tail, serves, Samples8, LANES};
use crate::shade::{for_light_samples, gaussian, samples, FibTable, Frame, Sample, ShadeInputs};
use crate::shade_backward::light_grads;
use svgir_core::simd::{F8k, Lanes, F8};
use svgir_shading::split::Lobe;
use svgir_shading::split_lanes::{cdot, dot_l, lobe_l, spec_grad_lanes, spec_lanes, LobeL};
use svgir_shading::tri;
use svgir_shading::F0;
use svgir_trace::DirectionCache;

/// Lanes per step of the (vertex, direction) loops: one AVX2 register of f32.
pub(crate) const W: usize = 8;

/// One Gaussian's samples as rows of lanes, padded to a multiple of [`W`] with zero direction,
/// light and Fresnel.
#[derive(Default)]
pub(crate) struct SampleRows {
    dir: [Vec<f32>; 3],
    h: [Vec<f32>; 3],
    fr: Vec<f32>,
    direct: [Vec<f32>; 3],
    ind: [Vec<f32>; 3],
    /// Backward only: the samples themselves (visibility, clamp, taps, traced radiance) for the
    /// env-map and rho gradients -- the lane blocks as they came, then the rest one by one --
    /// and `dL/dLin` per sample and channel.
    kept8: Vec<Samples8>,
    kept: Vec<Sample<f32>>,
    v_lin: [Vec<f32>; 3],
    /// The backward's and the colour-only forward's `direct + ind` per sample and channel.
    lin: [Vec<f32>; 3],
}

impl SampleRows {
    /// Gaussian i's samples (those `shade::samples` yields, in its order) with their half
    /// vectors towards `wo`; `keep` also stores the samples for the backward, `summed` forms
    /// `lin`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn fill(
        &mut self,
        inp: &ShadeInputs<f32>,
        table: &FibTable,
        cache: Option<&DirectionCache>,
        i: usize,
        wo: [f32; 3],
        keep: bool,
        summed: bool,
    ) {
        let frame = Frame::new(inp.mb.normals[i], inp.mb.xi[i]);
        self.kept.clear();
        self.kept8.clear();
        for v in self.rows_mut() {
            v.clear();
        }
        match cache.filter(|_| serves(inp)) {
            Some(c) => {
                // The K directions eight at a time in lanes (`sample_lanes`, the scalar values
                // bit for bit; a tail of fewer than eight in padded lanes), the lights as the
                // scalar code.
                let k = inp.mb.k;
                // Rows appended to (cleared above, their capacity kept from Gaussian to Gaussian).
                for k0 in (0..k).step_by(LANES) {
                    // SAFETY: the caller of the `_avx2` kernels checked that the CPU has AVX2;
                    // 1 <= lanes <= 8, k0 + lanes <= K and `serves` holds.
                    let s8 = unsafe {
                        match k - k0 {
                            LANES.. => samples8(inp, table, c, &frame, i, k0),
                            lanes => samples_tail(inp, table, c, &frame, i, k0, lanes),
                        }
                    };
                    s8.write_rows(&mut self.dir, &mut self.direct, &mut self.ind);
                    if keep {
                        self.kept8.push(s8);
                    }
                }
                for_light_samples(inp, i, |s| self.push(s, keep));
            }
            None => {
                for s in samples(inp, table, cache, &frame, i) {
                    self.push(s, keep);
                }
            }
        }
        // Padding: a zero direction has cos = 0, so the select drops it.
        let padded = self.dir[0].len().next_multiple_of(W);
        for v in self.rows_mut() {
            v.resize(padded, 0.0);
        }
        // Half vectors and Fresnel towards `wo`, lane by lane.
        for j in 0..padded / F8::N {
            // SAFETY: the caller of the `_avx2` kernels checked that the CPU has AVX2.
            unsafe { self.half_lanes::<F8>(wo, j) };
        }
        if keep {
            for v in &mut self.v_lin {
                v.clear();
                v.resize(padded, 0.0);
            }
        }
        if summed {
            for c in 0..3 {
                let lin = &mut self.lin[c];
                lin.clear();
                lin.extend(self.direct[c].iter().zip(&self.ind[c]).map(|(d, i)| d + i));
            }
        }
    }

    /// Appends one sample's direction and light to the rows.
    #[inline(always)]
    fn push_rows(&mut self, dir: [f32; 3], direct: [f32; 3], ind: [f32; 3]) {
        for c in 0..3 {
            self.dir[c].push(dir[c]);
            self.direct[c].push(direct[c]);
            self.ind[c].push(ind[c]);
        }
    }

    /// Appends sample `s` to the rows, and to `kept` for the backward when `keep`.
    #[inline(always)]
    fn push(&mut self, s: Sample<f32>, keep: bool) {
        self.push_rows(s.dir, s.direct, s.ind);
        if keep {
            self.kept.push(s);
        }
    }

    /// `split::half` for lanes `j`: the same operations, except that 2^x is
    /// `exp_fast(x ln 2)` (relative difference ~1e-7) instead of libm's `exp2f`.
    #[inline(always)]
    unsafe fn half_lanes<L: Lanes>(&mut self, wo: [f32; 3], j: usize) {
        let s = L::splat;
        let d = tri!(c => load::<L>(&self.dir[c], j));
        let h = tri!(c => s(wo[c]).add(d[c]));
        let len = h[0].mul(h[0]).add(h[1].mul(h[1])).add(h[2].mul(h[2])).sqrt();
        let floor = s(1e-12);
        let len = L::select(len.gt(floor), len, floor);
        let h = tri!(c => h[c].div(len));
        let vh = cdot(dot_l(wo, &h));
        let x = s(-5.55473).mul(vh).sub(s(6.98316)).mul(vh);
        let fr = s(F0 as f32).add(s(1.0 - F0 as f32).mul(x.mul(s(std::f32::consts::LN_2)).exp_fast()));
        for c in 0..3 {
            h[c].store(self.h[c].as_mut_ptr().add(j * L::N));
        }
        fr.store(self.fr.as_mut_ptr().add(j * L::N));
    }

    fn rows_mut(&mut self) -> impl Iterator<Item = &mut Vec<f32>> {
        let [a, b, c] = &mut self.dir;
        let [d, e, f] = &mut self.h;
        let [g, h, i] = &mut self.direct;
        let [j, k, l] = &mut self.ind;
        [a, b, c, d, e, f, g, h, i, j, k, l, &mut self.fr].into_iter()
    }
}

/// Lanes `[j*W, (j+1)*W)` of a row.
#[inline(always)]
unsafe fn load<L: Lanes>(row: &[f32], j: usize) -> L {
    debug_assert!((j + 1) * L::N <= row.len());
    L::load(row.as_ptr().add(j * L::N))
}

/// The lane weights of block `j` of the samples for a vertex with lobe `lb`: `max(0, n.l)`
/// and the specular term times it, 0 below the horizon (the scalar kernel's test, as a select).
#[inline(always)]
unsafe fn block_weights<L: Lanes>(rows: &SampleRows, lb: &Lobe<f32>, ll: &LobeL<L>, j: usize) -> (L, L) {
    let zero = L::splat(0.0);
    let d = tri!(c => load::<L>(&rows.dir[c], j));
    let h = tri!(c => load::<L>(&rows.h[c], j));
    let cos = dot_l(lb.n, &d);
    let sc = spec_lanes(ll, dot_l(lb.n, &h), load(&rows.fr, j), cos).mul(cos);
    let live = cos.gt(zero);
    (L::select(live, cos, zero), L::select(live, sc, zero))
}

/// The forward of Gaussian i into its M x 3 slices (as `shade::shade_gaussian`); `parts`: also
/// its direct and indirect parts, else the colour alone from each sample's summed light.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn shade_gaussian<L: Lanes>(
    inp: &ShadeInputs<f32>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    rows: &mut SampleRows,
    i: usize,
    color: &mut [f32],
    parts: Option<(&mut [f32], &mut [f32])>,
) {
    let m = inp.mats.m;
    let g = gaussian(inp, i);
    rows.fill(inp, table, cache, i, g.wo, false, parts.is_none());
    let scale = (std::f64::consts::TAU / inp.mb.k as f64) as f32;
    let inv_pi = std::f64::consts::FRAC_1_PI as f32;
    let zero = L::splat(0.0);
    let chunks = rows.fr.len() / L::N;
    let Some((direct, indirect)) = parts else {
        // E and P of the summed light per channel, lane-wise.
        for mm in 0..m {
            let ll = lobe_l::<L>(&g.lb[mm]);
            let (mut e, mut p) = ([zero; 3], [zero; 3]);
            for j in 0..chunks {
                let (cw, sw) = block_weights(rows, &g.lb[mm], &ll, j);
                for c in 0..3 {
                    let lin = load::<L>(&rows.lin[c], j);
                    e[c] = e[c].add(cw.mul(lin));
                    p[c] = p[c].add(sw.mul(lin));
                }
            }
            for c in 0..3 {
                let kd = g.vx.a[mm][c] * inv_pi * g.dw[mm].value;
                color[mm * 3 + c] = scale * (kd * e[c].hsum() + p[c].hsum());
            }
        }
        return;
    };
    for mm in 0..m {
        let ll = lobe_l::<L>(&g.lb[mm]);
        // E and P (see `shade.rs`), direct and indirect, per channel, lane-wise.
        let (mut e_d, mut e_i, mut p_d, mut p_i) = ([zero; 3], [zero; 3], [zero; 3], [zero; 3]);
        for j in 0..chunks {
            let (cw, sw) = block_weights(rows, &g.lb[mm], &ll, j);
            for c in 0..3 {
                let (dl, il) = (load::<L>(&rows.direct[c], j), load::<L>(&rows.ind[c], j));
                e_d[c] = e_d[c].add(cw.mul(dl));
                e_i[c] = e_i[c].add(cw.mul(il));
                p_d[c] = p_d[c].add(sw.mul(dl));
                p_i[c] = p_i[c].add(sw.mul(il));
            }
        }
        for c in 0..3 {
            let kd = g.vx.a[mm][c] * inv_pi * g.dw[mm].value;
            let d = scale * (kd * e_d[c].hsum() + p_d[c].hsum());
            let ind = scale * (kd * e_i[c].hsum() + p_i[c].hsum());
            direct[mm * 3 + c] = d;
            indirect[mm * 3 + c] = ind;
            color[mm * 3 + c] = d + ind;
        }
    }
}

/// The backward of Gaussian i (as `shade_backward::backward_gaussian`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn backward_gaussian<L: Lanes>(
    inp: &ShadeInputs<f32>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    rows: &mut SampleRows,
    i: usize,
    g: &[f32],
    v_alb: &mut [f32],
    v_rough: &mut [f32],
    v_nrm: &mut [f32],
    v_env: &mut [[f32; 3]],
    v_rho: &mut f32,
) {
    let m = inp.mats.m;
    let ga = gaussian(inp, i);
    let wo = ga.wo;
    rows.fill(inp, table, cache, i, wo, true, true);
    let scale = (std::f64::consts::TAU / inp.mb.k as f64) as f32;
    let inv_pi = std::f64::consts::FRAC_1_PI as f32;
    let zero = L::splat(0.0);
    let chunks = rows.fr.len() / L::N;
    for mm in 0..m {
        let lb = &ga.lb[mm];
        let ll = lobe_l::<L>(lb);
        let gm = [g[mm * 3], g[mm * 3 + 1], g[mm * 3 + 2]];
        let a = ga.vx.a[mm];
        let dw = ga.dw[mm];
        // The diffuse part of f_c, a_c / pi t (scalar order).
        let kd = tri!(c => L::splat(a[c] * inv_pi * dw.value));
        let (mut e, mut vr, mut vn) = ([zero; 3], zero, [zero; 3]);
        for j in 0..chunks {
            let d = tri!(c => load::<L>(&rows.dir[c], j));
            let h = tri!(c => load::<L>(&rows.h[c], j));
            let cos = dot_l(lb.n, &d);
            let live = cos.gt(zero);
            let sg = spec_grad_lanes(lb, &ll, &h, load(&rows.fr, j), wo, &d, cos);
            let (mut sum_gl, mut sum_glf) = (zero, zero);
            for c in 0..3 {
                let lin = load::<L>(&rows.lin[c], j);
                let f = kd[c].add(sg.value);
                let gl = L::splat(gm[c]).mul(lin);
                sum_gl = sum_gl.add(gl);
                sum_glf = sum_glf.add(gl.mul(f));
                let p = rows.v_lin[c].as_mut_ptr().add(j * L::N);
                L::load(p).add(L::select(live, L::splat(gm[c]).mul(f).mul(cos), zero)).store(p);
                e[c] = e[c].add(L::select(live, cos.mul(lin), zero));
            }
            vr = vr.add(L::select(live, cos.mul(sg.v_r).mul(sum_gl), zero));
            for k in 0..3 {
                let x = cos.mul(sg.v_n[k]).mul(sum_gl).add(d[k].mul(sum_glf));
                vn[k] = vn[k].add(L::select(live, x, zero));
            }
        }
        let e = tri!(c => e[c].hsum());
        let q = (0..3).fold(0.0, |acc, c| acc + gm[c] * a[c] * inv_pi * e[c]);
        for c in 0..3 {
            v_alb[mm * 3 + c] = scale * gm[c] * e[c] * inv_pi * dw.value;
            v_nrm[mm * 3 + c] = scale * (vn[c].hsum() + q * dw.v_mu * wo[c]);
        }
        v_rough[mm] = scale * (vr.hsum() + q * dw.v_r);
    }
    // The light gradient per sample, to the env texels and rho (scalar, in sample order).
    let mut k = 0;
    for b in &rows.kept8 {
        k = b.light_grads(&rows.v_lin, k, scale, v_env, v_rho);
    }
    for s in &rows.kept {
        let v_lin = [rows.v_lin[0][k], rows.v_lin[1][k], rows.v_lin[2][k]];
        light_grads(s.vis, s.live, &s.taps, s.traced, v_lin, scale, v_env, v_rho);
        k += 1;
    }
}

/// [`shade_gaussian`] compiled for AVX2.
///
/// # Safety
/// The CPU has AVX2.
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn shade_gaussian_avx2(
    inp: &ShadeInputs<f32>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    rows: &mut SampleRows,
    i: usize,
    color: &mut [f32],
    parts: Option<(&mut [f32], &mut [f32])>,
) {
    shade_gaussian::<F8>(inp, table, cache, rows, i, color, parts)
}

/// [`backward_gaussian`] compiled for AVX2.
///
/// # Safety
/// The CPU has AVX2.
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn backward_gaussian_avx2(
    inp: &ShadeInputs<f32>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    rows: &mut SampleRows,
    i: usize,
    g: &[f32],
    v_alb: &mut [f32],
    v_rough: &mut [f32],
    v_nrm: &mut [f32],
    v_env: &mut [[f32; 3]],
    v_rho: &mut f32,
) {
    backward_gaussian::<F8>(inp, table, cache, rows, i, g, v_alb, v_rough, v_nrm, v_env, v_rho)
}

/// [`shade_gaussian`] compiled for AVX-512F+VL: the same 8 lanes with compares into mask
/// registers and 32 vector registers (as the rasteriser's AVX-512 path).
///
/// # Safety
/// The CPU has AVX-512F and AVX-512VL.
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn shade_gaussian_avx512(
    inp: &ShadeInputs<f32>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    rows: &mut SampleRows,
    i: usize,
    color: &mut [f32],
    parts: Option<(&mut [f32], &mut [f32])>,
) {
    shade_gaussian::<F8k>(inp, table, cache, rows, i, color, parts)
}

/// [`backward_gaussian`] compiled for AVX-512F+VL (see [`shade_gaussian_avx512`]).
///
/// # Safety
/// The CPU has AVX-512F and AVX-512VL.
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn backward_gaussian_avx512(
    inp: &ShadeInputs<f32>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    rows: &mut SampleRows,
    i: usize,
    g: &[f32],
    v_alb: &mut [f32],
    v_rough: &mut [f32],
    v_nrm: &mut [f32],
    v_env: &mut [[f32; 3]],
    v_rho: &mut f32,
) {
    backward_gaussian::<F8k>(inp, table, cache, rows, i, g, v_alb, v_rough, v_nrm, v_env, v_rho)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;
    use svgir_shading::split::{half, lobe, spec, spec_grad, HalfVec};

    fn unit(rng: &mut Rng) -> [f32; 3] {
        let v = [rng.normal(), rng.normal(), rng.normal()];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / l)
    }

    /// `spec_lanes` and `spec_grad_lanes` are `spec` and `spec_grad` lane by lane, bit for bit
    /// (including back-facing and clamped directions); `half_lanes` is `half` up to the exp.
    #[test]
    fn lane_specular_is_the_scalar_one() {
        if !std::is_x86_feature_detected!("avx2") {
            eprintln!("SKIPPED: this CPU has no AVX2, so the shading lane kernels cannot run here");
            return;
        }
        // SAFETY: AVX2 checked above.
        unsafe { check_lanes() }
    }

    #[target_feature(enable = "avx2")]
    unsafe fn check_lanes() {
        let mut rng = Rng::new(5);
        let mut rows = SampleRows::default();
        for case in 0..400 {
            let (n, v) = (unit(&mut rng), unit(&mut rng));
            let r = rng.range(0.02, 1.0);
            let lb = lobe(n, v, r);
            let ls: Vec<[f32; 3]> = (0..W).map(|_| unit(&mut rng)).collect();
            for c in 0..3 {
                rows.dir[c] = ls.iter().map(|l| l[c]).collect();
                rows.h[c] = vec![0.0; W];
            }
            rows.fr = vec![0.0; W];
            rows.half_lanes::<F8>(v, 0);
            let d = tri!(c => load::<F8>(&rows.dir[c], 0));
            let h = tri!(c => load::<F8>(&rows.h[c], 0));
            let fr = load::<F8>(&rows.fr, 0);
            let ll = lobe_l::<F8>(&lb);
            let nl = dot_l(n, &d);
            let mut got = [[0f32; W]; 6];
            spec_lanes(&ll, dot_l(n, &h), fr, nl).store(got[0].as_mut_ptr());
            let sg = spec_grad_lanes(&lb, &ll, &h, fr, v, &d, nl);
            sg.value.store(got[1].as_mut_ptr());
            sg.v_r.store(got[2].as_mut_ptr());
            for k in 0..3 {
                sg.v_n[k].store(got[3 + k].as_mut_ptr());
            }
            for (j, l) in ls.iter().enumerate() {
                let want_h = half(v, *l);
                for c in 0..3 {
                    assert_eq!(rows.h[c][j].to_bits(), want_h.h[c].to_bits(), "case {case} lane {j} h{c}");
                }
                let fr_err = (rows.fr[j] - want_h.fr).abs() / want_h.fr;
                assert!(fr_err <= 1e-6, "case {case} lane {j}: Fresnel {} vs {}", rows.fr[j], want_h.fr);
                // The scalar functions on the lane's own Fresnel, so the rest compares exactly.
                let hv = HalfVec { h: want_h.h, fr: rows.fr[j] };
                let nl = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
                let want = spec_grad(&lb, &hv, v, *l, nl);
                let wants = [spec(&lb, &hv, nl), want.value, want.v_r, want.v_n[0], want.v_n[1], want.v_n[2]];
                for (q, w) in wants.iter().enumerate() {
                    assert_eq!(
                        got[q][j].to_bits(),
                        w.to_bits(),
                        "case {case} lane {j} quantity {q}: {} vs {w}",
                        got[q][j]
                    );
                }
            }
        }
    }
}
