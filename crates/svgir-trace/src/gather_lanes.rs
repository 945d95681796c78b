//! The one-bounce gather's per-ray shading ([`crate::gather::shade_pair`], SPEC 5 Eqn 13) and its
//! backward ([`crate::gather_backward::backward_pair`]) over [`W`] escape directions at a time
//! in AVX2 lanes (`svgir_core::simd::F8`), for f32 where the CPU has AVX2.
//!
//! The hit Gaussian's escape list is kept as structure-of-arrays rows ([`EscapeRows`]: direction
//! and clamped env radiance), padded to a multiple of [`W`] with directions that carry no light.
//! Per ray, the per-vertex set-up is the scalar kernels' ([`crate::gather::RaySetup`]); then,
//! per chunk of [`W`] escapes, the half vector and Fresnel ([`half_lanes`]) and, vertex by
//! vertex, the split GGX term and its gradient (`svgir_shading::split_lanes`, the scalar
//! formulas lane by lane).
//!
//! What differs from the scalar oracle: the Fresnel's `exp2` is the lanes' polynomial (a few
//! ulp), and the sums over escapes (the radiance, and in the backward the albedo, roughness and
//! normal gradients) are summed lane-wise and then across lanes. The light gradient of each
//! escape (summed over vertices in vertex order) is stored per lane and routed to the env taps
//! in the scalar loop's order. The test `f32_paths_agree_with_naive_formula_and_each_other`
//! (`gather_backward.rs`) holds every path to the scalar kernels.
//!
//! Work split and saved state: none of its own; the callers in `gather` and `gather_backward`
//! decide both.

// The lane kernels are `unsafe fn`s with one contract -- the CPU has AVX2 (checked by the caller
// through `Simd::resolve`) -- so the operations inside need no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]

use crate::gather::{Escapes, RaySetup, VertexMaterials};
use crate::microbuffer::MicroBuffer;
use svgir_core::simd::{is_f32, Lanes, Simd};
use svgir_shading::split_lanes::{dot_l, half_lanes, lobe_l, spec_grad_lanes, spec_lanes, LobeL};
use svgir_shading::{tri, Diffuse, DOT_EPS, MAX_VERTICES};

/// Escapes per lane step: one AVX2 register of f32.
pub(crate) const W: usize = 8;

/// An escape list as rows of lanes: unit directions and clamped env radiance per channel,
/// padded to a multiple of [`W`] with the direction +z and no light.
#[derive(Clone, Debug, Default)]
pub(crate) struct EscapeRows {
    pub dir: [Vec<f32>; 3],
    pub light: [Vec<f32>; 3],
    /// Real (unpadded) escapes.
    pub len: usize,
}

impl EscapeRows {
    pub fn clear(&mut self) {
        for r in self.dir.iter_mut().chain(self.light.iter_mut()) {
            r.clear();
        }
        self.len = 0;
    }

    pub fn push(&mut self, d: [f32; 3], light: [f32; 3]) {
        for c in 0..3 {
            self.dir[c].push(d[c]);
            self.light[c].push(light[c]);
        }
        self.len += 1;
    }

    /// Pad to whole lane steps with escapes that carry nothing (finite in every formula).
    pub fn pad(&mut self) {
        while !self.dir[0].len().is_multiple_of(W) {
            for (c, d) in [0.0, 0.0, 1.0].into_iter().enumerate() {
                self.dir[c].push(d);
                self.light[c].push(0.0);
            }
        }
    }

    fn steps(&self) -> usize {
        self.dir[0].len() / W
    }
}

/// Whether the lane kernels run for scalar type `F` under `simd`: f32 on an x86-64 CPU with AVX2
/// (the AVX-512 path runs the same 8-lane code).
pub(crate) fn lane_kernels<F: 'static>(simd: Simd) -> bool {
    cfg!(target_arch = "x86_64") && is_f32::<F>() && simd.resolve() != Simd::Scalar
}

/// Lanes `[j*W, (j+1)*W)` of a row.
#[inline(always)]
unsafe fn load<L: Lanes>(row: &[f32], j: usize) -> L {
    debug_assert!((j + 1) * L::N <= row.len());
    L::load(row.as_ptr().add(j * L::N))
}

/// `max(x, DOT_EPS)` per lane (`maxf`), and whether `x > DOT_EPS`.
#[inline(always)]
unsafe fn clamp_cos<L: Lanes>(x: L) -> (L, L::M) {
    let eps = L::splat(DOT_EPS as f32);
    let live = x.gt(eps);
    (L::select(live, x, eps), live)
}

/// The ray's lobes broadcast to lanes (a loop, not `array::map`: see `svgir_shading::tri`).
#[inline(always)]
unsafe fn lane_lobes<L: Lanes>(ray: &RaySetup<f32>, m: usize) -> [LobeL<L>; MAX_VERTICES] {
    let mut out = [lobe_l(&ray.lobes[0]); MAX_VERTICES];
    for mm in 1..m {
        out[mm] = lobe_l(&ray.lobes[mm]);
    }
    out
}

/// Eqn 13 for ray (j, k) of `mb` off its hit Gaussian `esc.h`, whose escapes `rows` holds.
#[inline(always)]
unsafe fn shade_pair_lanes<L: Lanes>(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    esc: &Escapes<f32>,
    diffuse: Diffuse,
    j: usize,
    k: usize,
) -> [f32; 3] {
    let rows = &esc.rows;
    let m = mats.m;
    let ray = RaySetup::new(mb, mats, diffuse, esc.h as usize, j, k);
    let inv_pi = std::f64::consts::FRAC_1_PI as f32;
    // The diffuse term `t a/pi` per vertex (independent of the escape direction).
    let mut kd = [[0.0f32; 3]; MAX_VERTICES];
    for mm in 0..m {
        let t = inv_pi * ray.dw[mm].value;
        kd[mm] = [ray.a[mm][0] * t, ray.a[mm][1] * t, ray.a[mm][2] * t];
    }
    let ll = lane_lobes::<L>(&ray, m);
    let zero = L::splat(0.0);
    let mut acc = [zero; 3];
    for step in 0..rows.steps() {
        let l: [L; 3] = tri!(i => load(&rows.dir[i], step));
        let (hh, fr) = half_lanes(ray.v, &l);
        let mut f_cos = [zero; 3];
        for mm in 0..m {
            let nl = dot_l(ray.n[mm], &l);
            let s = spec_lanes(&ll[mm], dot_l(ray.n[mm], &hh), fr, nl);
            let cw = clamp_cos(nl).0.mul(L::splat(ray.w[mm]));
            f_cos = tri!(c => f_cos[c].add(L::splat(kd[mm][c]).add(s).mul(cw)));
        }
        acc = tri!(c => acc[c].add(f_cos[c].mul(load(&rows.light[c], step))));
    }
    let scale = (std::f64::consts::TAU / mb.k as f64) as f32;
    tri!(c => acc[c].hsum() * scale)
}

/// [`crate::gather::shade_pair`] in AVX2 lanes.
///
/// # Safety
/// The CPU has AVX2 and FMA ([`lane_kernels`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn shade_pair_avx2(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    esc: &Escapes<f32>,
    diffuse: Diffuse,
    j: usize,
    k: usize,
) -> [f32; 3] {
    shade_pair_lanes::<svgir_core::simd::F8>(mb, mats, esc, diffuse, j, k)
}

/// The backward of one ray, adding into its hit Gaussian's slices (`alb`: M x 3, `rough`: M,
/// `nrm`: M x 3) and the env texels, as [`crate::gather_backward::backward_pair`].
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn backward_pair_lanes<L: Lanes>(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    esc: &Escapes<f32>,
    diffuse: Diffuse,
    (j, k): (usize, usize),
    g: [f32; 3],
    alb: &mut [f32],
    rough: &mut [f32],
    nrm: &mut [f32],
    v_env: &mut [[f32; 3]],
    v_light_rows: &mut [Vec<f32>; 3],
) {
    let rows = &esc.rows;
    let m = mats.m;
    let ray = RaySetup::new(mb, mats, diffuse, esc.h as usize, j, k);
    let v = ray.v;
    let cscale = (std::f64::consts::TAU / mb.k as f64) as f32;
    let inv_pi = std::f64::consts::FRAC_1_PI as f32;
    let ll = lane_lobes::<L>(&ray, m);
    let s = L::splat;
    let zero = s(0.0);
    // Per vertex, summed over escapes lane-wise: dL/da (3), dL/dr, dL/dn (3) and q, the factor of
    // the diffuse weight's derivatives (`gather_backward`'s module note).
    let mut v_a = [[zero; 3]; MAX_VERTICES];
    let mut v_r = [zero; MAX_VERTICES];
    let mut v_n = [[zero; 3]; MAX_VERTICES];
    let mut q = [zero; MAX_VERTICES];
    for r in v_light_rows.iter_mut() {
        r.clear();
        r.resize(rows.dir[0].len(), 0.0);
    }
    for step in 0..rows.steps() {
        let l: [L; 3] = tri!(i => load(&rows.dir[i], step));
        let light: [L; 3] = tri!(c => load(&rows.light[c], step));
        let (hh, fr) = half_lanes(v, &l);
        let mut v_light = [zero; 3];
        for mm in 0..m {
            let ndl = dot_l(ray.n[mm], &l);
            let sg = spec_grad_lanes(&ray.lobes[mm], &ll[mm], &hh, fr, v, &l, ndl);
            let (cos, cos_live) = clamp_cos(ndl);
            let gw = cscale * ray.w[mm];
            let kd = inv_pi * ray.dw[mm].value;
            let mut sum_gl = zero;
            let mut sum_glf = zero;
            for c in 0..3 {
                let f = s(ray.a[mm][c] * kd).add(sg.value);
                let gl = s(g[c] * gw).mul(light[c]);
                let gl_cos = gl.mul(cos);
                v_a[mm][c] = v_a[mm][c].add(gl_cos.mul(s(kd)));
                q[mm] = q[mm].add(gl_cos.mul(s(ray.a[mm][c] * inv_pi)));
                sum_gl = sum_gl.add(gl);
                sum_glf = sum_glf.add(gl.mul(f));
                v_light[c] = v_light[c].add(s(g[c] * gw).mul(f).mul(cos));
            }
            let sum_gl_cos = sum_gl.mul(cos);
            v_r[mm] = v_r[mm].add(sum_gl_cos.mul(sg.v_r));
            let glf = L::select(cos_live, sum_glf, zero);
            v_n[mm] = tri!(i => v_n[mm][i].add(sum_gl_cos.mul(sg.v_n[i]).add(glf.mul(l[i]))));
        }
        for c in 0..3 {
            v_light[c].store(v_light_rows[c].as_mut_ptr().add(step * W));
        }
    }
    for mm in 0..m {
        let qm = q[mm].hsum();
        for c in 0..3 {
            alb[mm * 3 + c] += v_a[mm][c].hsum();
        }
        rough[mm] += v_r[mm].hsum() + qm * ray.dw[mm].v_r;
        for i in 0..3 {
            nrm[mm * 3 + i] += v_n[mm][i].hsum() + qm * ray.dw[mm].v_mu * v[i];
        }
    }
    // Each real escape's light gradient to its bilinear taps, in the scalar loop's order.
    for e in 0..rows.len {
        let taps = &esc.taps[e];
        for c in 0..3 {
            if esc.live[e][c] {
                let vl = v_light_rows[c][e];
                for t in 0..4 {
                    v_env[taps.index[t] as usize][c] += taps.weight[t] * vl;
                }
            }
        }
    }
}

/// [`crate::gather_backward::backward_pair`] in AVX2 lanes; `v_light_rows` is scratch.
///
/// # Safety
/// The CPU has AVX2 and FMA ([`lane_kernels`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn backward_pair_avx2(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    esc: &Escapes<f32>,
    diffuse: Diffuse,
    jk: (usize, usize),
    g: [f32; 3],
    alb: &mut [f32],
    rough: &mut [f32],
    nrm: &mut [f32],
    v_env: &mut [[f32; 3]],
    v_light_rows: &mut [Vec<f32>; 3],
) {
    backward_pair_lanes::<svgir_core::simd::F8>(mb, mats, esc, diffuse, jk, g, alb, rough, nrm, v_env, v_light_rows)
}
