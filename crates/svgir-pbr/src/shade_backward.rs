//! Backward of [`crate::shade()`]: given `v_color = dL/dc_i^m` (N x M x 3), the gradients with
//! respect to the activated vertex albedo, roughness and unit shading normals, the environment
//! radiance texels and rho (a [`PbrGrads`]). V, L and the directions are frozen (SPEC 5, 6).
//!
//! With C = 2pi/K, per (i, k) with incoming light `Lin = V clamp(L_env) + L_ind`, per vertex m with
//! `cos = n_m.w_k > 0`, `f_c = a_c/pi + S` and upstream g = v_color[i, m]:
//! `dL/da_c = C g_c E_c / pi` (E_c = sum_k cos Lin_c), `dL/dr += C cos dS/dr sum_c g_c Lin_c`,
//! `dL/dn += C [cos dS/dn sum_c g_c Lin_c + w_k sum_c g_c f_c Lin_c]`,
//! `dL/dLin_c = C sum_m g_c f_c cos`; with `Diffuse::Layered` (`f_c = t a_c/pi + S`,
//! `t = 1 - E(n.v, r)`) dL/da_c carries the factor t, and `C q dt/dr`, `C q dt/d(n.v) w_o` with
//! `q = sum_c g_c a_c E_c/pi` join dL/dr and dL/dn. dL/dLin reaches the env texels through `V` and the four
//! bilinear taps (unless the clamp is active) and rho through `L_{i,k}`.
//!
//! Reductions without races (SPEC 9.4): rayon runs over fixed blocks of Gaussians; a block owns
//! its Gaussians' material gradients outright and sums its env / rho gradients into a private
//! partial, and the partials are added in block order. The block size depends only on N, so the
//! result is bit-identical for any thread count.

use crate::grads::PbrGrads;
#[cfg(target_arch = "x86_64")]
use crate::shade::{as_f32_inputs, as_f32_mut, lane_kernels};
use crate::shade::{
    check_sides, gaussian, samples, side_of, FibTable, Frame, Gaussian, LaneScratch, ShadeInputs, SideRef,
};
use crate::{expect_len, PbrError};
use rayon::prelude::*;
use svgir_core::par::add_parts_in_order;
#[cfg(target_arch = "x86_64")]
use svgir_core::simd::Simd;
use svgir_shading::float::dot;
use svgir_shading::split::{half, spec_grad};
use svgir_shading::{Float, MAX_VERTICES};
use svgir_trace::DirectionCache;

/// Gaussians per reduction block: at most ~64 partial env maps, at least 256 Gaussians a block.
fn block_size(n: usize) -> usize {
    n.div_ceil(64).max(256)
}

/// Accumulate Gaussian i's gradients: materials into its own slices, env / rho into partials.
fn backward_gaussian<F: Float>(
    inp: &ShadeInputs<F>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    i: usize,
    g: &[F],
    v_alb: &mut [F],
    v_rough: &mut [F],
    v_nrm: &mut [F],
    v_env: &mut [[F; 3]],
    v_rho: &mut F,
) {
    let m = inp.mats.m;
    let Gaussian { vx, wo, lb, dw } = gaussian(inp, i);
    let frame = Frame::new(inp.mb.normals[i], inp.mb.xi[i]);
    let scale = F::from_f64(std::f64::consts::TAU / inp.mb.k as f64);
    let inv_pi = F::from_f64(std::f64::consts::FRAC_1_PI);
    let mut gm = [[F::ZERO; 3]; MAX_VERTICES];
    for mm in 0..m {
        gm[mm] = [g[mm * 3], g[mm * 3 + 1], g[mm * 3 + 2]];
    }
    let mut e = [[F::ZERO; 3]; MAX_VERTICES];
    let mut vr = [F::ZERO; MAX_VERTICES];
    let mut vn = [[F::ZERO; 3]; MAX_VERTICES];
    for s in samples(inp, table, cache, &frame, i) {
        let hv = half(wo, s.dir);
        let lin = [0, 1, 2].map(|c| s.direct[c] + s.ind[c]);
        let mut v_lin = [F::ZERO; 3];
        for mm in 0..m {
            let cos = dot(vx.n[mm], s.dir);
            if cos <= F::ZERO {
                continue;
            }
            let sg = spec_grad(&lb[mm], &hv, wo, s.dir, cos);
            let mut sum_gl = F::ZERO;
            let mut sum_glf = F::ZERO;
            for c in 0..3 {
                let f = vx.a[mm][c] * inv_pi * dw[mm].value + sg.value;
                let gl = gm[mm][c] * lin[c];
                e[mm][c] += cos * lin[c];
                sum_gl += gl;
                sum_glf += gl * f;
                v_lin[c] += gm[mm][c] * f * cos;
            }
            vr[mm] += cos * sg.v_r * sum_gl;
            for d in 0..3 {
                vn[mm][d] += cos * sg.v_n[d] * sum_gl + s.dir[d] * sum_glf;
            }
        }
        light_grads(s.vis, s.live, &s.taps, s.traced, v_lin, scale, v_env, v_rho);
    }
    for mm in 0..m {
        // Layered diffuse: `q = sum_c g_c a_c/pi E_c` times dt/dr and dt/d(n.v) w_o.
        let q = (0..3).fold(F::ZERO, |acc, c| acc + gm[mm][c] * vx.a[mm][c] * inv_pi * e[mm][c]);
        for c in 0..3 {
            v_alb[mm * 3 + c] = scale * gm[mm][c] * e[mm][c] * inv_pi * dw[mm].value;
            v_nrm[mm * 3 + c] = scale * (vn[mm][c] + q * dw[mm].v_mu * wo[c]);
        }
        v_rough[mm] = scale * (vr[mm] + q * dw[mm].v_r);
    }
}

/// Gradients of `sum v_color . c` (the colours of [`crate::shade()`] with the same inputs).
pub fn shade_backward<F: Float>(inp: &ShadeInputs<F>, v_color: &[F]) -> Result<PbrGrads<F>, PbrError> {
    shade_backward_cached(inp, None, v_color)
}

/// [`shade_backward`] with the env lookups taken from `cache` (see
/// [`crate::shade::shade_into_cached`]); bit-identical to the uncached result.
pub fn shade_backward_cached<F: Float>(
    inp: &ShadeInputs<F>,
    cache: Option<&DirectionCache>,
    v_color: &[F],
) -> Result<PbrGrads<F>, PbrError> {
    let mut grads = PbrGrads::zeros(inp.mb.len(), inp.mats.m, inp.env.len());
    shade_sides_backward_cached(&[(inp, cache)], v_color, &mut grads)?;
    Ok(grads)
}

/// [`shade_backward_cached`] over the sides of [`crate::shade::shade_sides_into_cached`] in one
/// pass, added into `grads` (sized for the sides' N, M and map; the trainer passes the other
/// terms' gradients, which saves a buffer and a pass to add it): each Gaussian's gradients come
/// from the first side whose `visible` holds it, those of the second side (the back, shaded with
/// negated normals) with the normal gradient negated (`d/dn_m = -d/d(-n_m)`). The env and rho
/// gradients of both sides share each block's partial.
pub(crate) fn shade_sides_backward_cached<F: Float>(
    sides: &[SideRef<F>],
    v_color: &[F],
    grads: &mut PbrGrads<F>,
) -> Result<(), PbrError> {
    check_sides(sides)?;
    let inp0 = sides[0].0;
    let n = inp0.mb.len();
    let m = inp0.mats.m;
    expect_len("v_color", v_color.len(), n * m * 3)?;
    let texels = inp0.env.len();
    expect_len("albedo gradients", grads.v_albedo.len(), n * m * 3)?;
    expect_len("roughness gradients", grads.v_roughness.len(), n * m)?;
    expect_len("normal gradients", grads.v_normals.len(), n * m * 3)?;
    expect_len("environment gradients", grads.v_env.len(), texels)?;
    if n == 0 {
        return Ok(());
    }
    let block = block_size(n);
    let tables: Vec<FibTable> = sides.iter().map(|(inp, _)| inp.mb.table()).collect();
    #[cfg(target_arch = "x86_64")]
    let lanes: Vec<Simd> = sides.iter().map(|(inp, _)| lane_kernels::<F>(inp.params.simd)).collect();
    let partials: Vec<Option<(Vec<[F; 3]>, F)>> = grads
        .v_albedo
        .par_chunks_mut(block * m * 3)
        .zip(grads.v_roughness.par_chunks_mut(block * m))
        .zip(grads.v_normals.par_chunks_mut(block * m * 3))
        .enumerate()
        .map(|(bi, ((alb, rough), nrm))| {
            let i0 = bi * block;
            let mut part: Option<(Vec<[F; 3]>, F)> = None;
            let mut rows = LaneScratch::default();
            for li in 0..rough.len() / m {
                let i = i0 + li;
                let g = &v_color[i * m * 3..(i + 1) * m * 3];
                // Unshaded Gaussians and those no pixel saw have no gradient.
                let Some((side, &(inp, cache))) = side_of(sides, i) else { continue };
                if g.iter().all(|&x| x == F::ZERO) {
                    continue;
                }
                let (v_env, v_rho) = part.get_or_insert_with(|| (vec![[F::ZERO; 3]; texels], F::ZERO));
                // The kernels write Gaussian i's material gradients here; they are added below.
                let mut own = [[F::ZERO; 3 * MAX_VERTICES], [F::ZERO; 3 * MAX_VERTICES], [F::ZERO; 3 * MAX_VERTICES]];
                let [own_alb, own_rough, own_nrm] = &mut own;
                let (alb_out, rough_out, nrm_out) = (
                    &mut alb[li * m * 3..(li + 1) * m * 3],
                    &mut rough[li * m..(li + 1) * m],
                    &mut nrm[li * m * 3..(li + 1) * m * 3],
                );
                let (alb, rough, nrm) = (&mut own_alb[..m * 3], &mut own_rough[..m], &mut own_nrm[..m * 3]);
                let table = &tables[side];
                // Set where a lane kernel ran (x86-64 only).
                #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
                let mut done = false;
                #[cfg(target_arch = "x86_64")]
                if lanes[side] != Simd::Scalar {
                    // SAFETY: `lane_kernels` checked that `F` is `f32` and that the CPU has the
                    // path's features.
                    unsafe {
                        let g = std::slice::from_raw_parts(g.as_ptr() as *const f32, g.len());
                        let v_rho = &mut *(v_rho as *mut F as *mut f32);
                        let kernel = match lanes[side] {
                            Simd::Avx512 => crate::shade_simd::backward_gaussian_avx512,
                            _ => crate::shade_simd::backward_gaussian_avx2,
                        };
                        kernel(
                            as_f32_inputs(inp),
                            table,
                            cache,
                            &mut rows,
                            i,
                            g,
                            as_f32_mut(alb),
                            as_f32_mut(rough),
                            as_f32_mut(nrm),
                            as_f32_mut(v_env),
                            v_rho,
                        );
                    }
                    done = true;
                }
                if !done {
                    let _ = &mut rows;
                    backward_gaussian(inp, table, cache, i, g, alb, rough, nrm, v_env, v_rho);
                }
                alb_out.iter_mut().zip(alb.iter()).for_each(|(o, x)| *o += *x);
                rough_out.iter_mut().zip(rough.iter()).for_each(|(o, x)| *o += *x);
                if side > 0 {
                    // The back side shades with -n_m.
                    nrm_out.iter_mut().zip(nrm.iter()).for_each(|(o, x)| *o -= *x);
                } else {
                    nrm_out.iter_mut().zip(nrm.iter()).for_each(|(o, x)| *o += *x);
                }
            }
            part
        })
        .collect();
    let (v_envs, v_rhos): (Vec<Vec<[F; 3]>>, Vec<F>) = partials.into_iter().flatten().unzip();
    add_parts_in_order(&mut grads.v_env, &v_envs, |acc, x| {
        for c in 0..3 {
            acc[c] += x[c];
        }
    });
    for v_rho in v_rhos {
        grads.v_rho += v_rho;
    }
    Ok(())
}

/// One sample's share of the light gradients (SPEC 4): `dL/dLin` (`v_lin`, per channel) times
/// V to the four env taps of the channels inside the clamp, and times the traced radiance to
/// rho. The scalar and the lane kernels both call it, sample by sample in the scalar order.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn light_grads<F: Float>(
    vis: F,
    live: [bool; 3],
    taps: &svgir_core::envmap::Taps,
    traced: [F; 3],
    v_lin: [F; 3],
    scale: F,
    v_env: &mut [[F; 3]],
    v_rho: &mut F,
) {
    if vis > F::ZERO {
        for c in 0..3 {
            if live[c] {
                let gv = scale * vis * v_lin[c];
                for t in 0..4 {
                    v_env[taps.index[t] as usize][c] += F::from_f32(taps.weight[t]) * gv;
                }
            }
        }
    }
    *v_rho += scale * (v_lin[0] * traced[0] + v_lin[1] * traced[1] + v_lin[2] * traced[2]);
}
