//! Backward of the one-bounce gather (SPEC 5, Eqn 13; SPEC 6 radiance consistency): gradients of
//! a loss on L1b with respect to the *hit* Gaussians' vertex albedo, roughness and shading normals
//! and to the environment-map texels.
//!
//! With C = 2pi/K, per escape s of h and vertex m (f_c = a_c/pi + S, cos = max(1e-6, n.l)):
//! `dL/da_mc += g_c C w_m cos L_c / pi`, `dL/dr_m += (sum_c g_c C w_m L_c) cos dS/dr`,
//! `dL/dn_m += (sum_c g_c C w_m L_c)(cos dS/dn) + (sum_c g_c C w_m L_c f_c) [n.l > 1e-6] l`,
//! `dL/dL_c = sum_m g_c C w_m f_c cos`, passed to the four bilinear taps unless the [0, env_max]
//! clamp is active. Normal gradients are with respect to the unit normals passed in.
//! With [`Diffuse::Layered`] the diffuse lobe is `t a_c/pi`, `t = 1 - E(n.v, r)` per vertex:
//! `a_c/pi` above becomes `t a_c/pi`, and `q_m = sum_s sum_c g_c C w_m L_c cos a_c/pi` adds
//! `q_m dt/dr` to dL/dr_m and `q_m dt/d(n.v) v` to dL/dn_m.
//!
//! Reductions without races (SPEC 9.4): the (j, k) entries are bucketed by their hit Gaussian h
//! (a counting sort), and rayon runs over fixed blocks of h. Each block owns its h's slices of the
//! material gradients outright and sums its environment-map gradient into a private partial; the
//! partials are then added in block order. Block size depends only on N, so the result is
//! bit-identical for any thread count. [`gather_pairs_with_backward`] shades each pair's L1b in
//! the same loop, on the escape list its backward fills, when the upstream gradient of a pair
//! depends on its own L1b alone.

use crate::gather::{
    check, check_lights, check_pair_call, check_pairs, shade_f32, Escapes, GatherParams, LightIn, RaySetup,
    VertexMaterials,
};
use crate::gather_lanes::lane_kernels;
use crate::microbuffer::{MicroBuffer, SURROUNDINGS_HIT};
use crate::TraceError;
use rayon::prelude::*;
use svgir_core::par::add_parts_in_order;
use svgir_core::simd::Simd;
use svgir_core::EnvMap;
use svgir_shading::float::dot;
use svgir_shading::split::{half, spec_grad};
use svgir_shading::{Diffuse, Float, DOT_EPS, MAX_VERTICES};

/// Gradients, laid out like [`VertexMaterials`] and `EnvMap::data`.
#[derive(Clone, Debug, PartialEq)]
pub struct GatherGrads<F = f32> {
    /// dL / d albedo, N x M x 3.
    pub v_albedo: Vec<F>,
    /// dL / d roughness, N x M.
    pub v_roughness: Vec<F>,
    /// dL / d unit shading normal, N x M x 3.
    pub v_normals: Vec<F>,
    /// dL / d environment radiance per texel (before the clamp).
    pub v_env: Vec<[F; 3]>,
}

impl<F: Float> GatherGrads<F> {
    /// All-zero gradients for N Gaussians with M vertices and `env_texels` texels.
    pub fn zeros(n: usize, m: usize, env_texels: usize) -> Self {
        Self {
            v_albedo: svgir_core::par::filled(n * m * 3, F::ZERO),
            v_roughness: svgir_core::par::filled(n * m, F::ZERO),
            v_normals: svgir_core::par::filled(n * m * 3, F::ZERO),
            v_env: vec![[F::ZERO; 3]; env_texels],
        }
    }
}

/// Accumulate the gradient of `g . L1b(j, k)` into h's material slices (`alb`, `rough`, `nrm`
/// hold h's M vertices) and into `v_env`.
pub(crate) fn backward_pair<F: Float>(
    mb: &MicroBuffer,
    mats: &VertexMaterials<F>,
    esc: &Escapes<F>,
    diffuse: Diffuse,
    j: usize,
    k: usize,
    g: [F; 3],
    alb: &mut [F],
    rough: &mut [F],
    nrm: &mut [F],
    v_env: &mut [[F; 3]],
) {
    let m = mats.m;
    let ray = RaySetup::new(mb, mats, diffuse, esc.h as usize, j, k);
    let (v, w, dw, lobes) = (ray.v, ray.w, ray.dw, ray.lobes);
    let cscale = F::from_f64(std::f64::consts::TAU / mb.k as f64);
    let inv_pi = F::from_f64(std::f64::consts::FRAC_1_PI);
    let eps = F::from_f64(DOT_EPS);
    // Per vertex, `q = sum_s sum_c g_c C w_m L_c cos a_c/pi`, the factor of dt/dr and dt/dn.
    let mut q = [F::ZERO; MAX_VERTICES];
    for s in 0..esc.dirs.len() {
        let l = esc.dirs[s];
        let light = esc.light[s];
        let mut v_light = [F::ZERO; 3];
        let hv = half(v, l);
        for mm in 0..m {
            let (n, a) = (ray.n[mm], ray.a[mm]);
            let ndl = dot(n, l);
            let sg = spec_grad(&lobes[mm], &hv, v, l, ndl);
            let cos = ndl.maxf(eps);
            let gw = cscale * w[mm];
            let kd = inv_pi * dw[mm].value;
            let mut sum_gl = F::ZERO;
            let mut sum_glf = F::ZERO;
            for c in 0..3 {
                let f = a[c] * kd + sg.value;
                let gl = g[c] * gw * light[c];
                alb[mm * 3 + c] += gl * cos * kd;
                q[mm] += gl * cos * a[c] * inv_pi;
                sum_gl += gl;
                sum_glf += gl * f;
                v_light[c] += g[c] * gw * f * cos;
            }
            rough[mm] += sum_gl * cos * sg.v_r;
            let cos_live = ndl > eps;
            for i in 0..3 {
                let mut d = sum_gl * cos * sg.v_n[i];
                if cos_live {
                    d += sum_glf * l[i];
                }
                nrm[mm * 3 + i] += d;
            }
        }
        let taps = &esc.taps[s];
        for c in 0..3 {
            if esc.live[s][c] {
                for t in 0..4 {
                    v_env[taps.index[t] as usize][c] += F::from_f32(taps.weight[t]) * v_light[c];
                }
            }
        }
    }
    for mm in 0..m {
        rough[mm] += q[mm] * dw[mm].v_r;
        for i in 0..3 {
            nrm[mm * 3 + i] += q[mm] * dw[mm].v_mu * v[i];
        }
    }
}

/// Generic batched backward: `entries` are (flat j*K+k, index into `v_out`); `simd` picks the
/// lane kernels for f32 ([`crate::gather_lanes`]).
pub(crate) fn backward_generic<F: Float>(
    mb: &MicroBuffer,
    mats: &VertexMaterials<F>,
    light: &LightIn<F>,
    entries: impl Iterator<Item = (usize, usize)>,
    v_out: &[[F; 3]],
    simd: Simd,
) -> GatherGrads<F> {
    backward_with(mb, mats, light, entries, simd, |up, _, _, _, _: &mut Vec<()>| v_out[up]).0
}

/// [`backward_generic`] with each entry's upstream gradient from `upstream(up, esc, j, k,
/// records)`, called once per entry after its hit's escape list `esc` is filled, in the
/// backward's own order (by hit Gaussian, blocks in order); what it pushes to `records` comes
/// back in that order.
fn backward_with<F: Float, R: Send>(
    mb: &MicroBuffer,
    mats: &VertexMaterials<F>,
    light: &LightIn<F>,
    entries: impl Iterator<Item = (usize, usize)>,
    simd: Simd,
    upstream: impl Fn(usize, &Escapes<F>, usize, usize, &mut Vec<R>) -> [F; 3] + Sync,
) -> (GatherGrads<F>, Vec<R>) {
    let lanes = lane_kernels::<F>(simd);
    let n = mb.len();
    let m = mats.m;
    let kk = mb.k;
    let texels = light.env.len();
    let mut grads = GatherGrads::zeros(n, m, texels);
    if n == 0 || kk == 0 {
        return (grads, Vec::new());
    }
    // Counting sort of the entries by hit Gaussian.
    let mut start = vec![0usize; n + 1];
    let mut list: Vec<(usize, usize)> = entries.filter(|&(jk, _)| mb.first_hit[jk] < SURROUNDINGS_HIT).collect();
    for &(jk, _) in &list {
        start[mb.first_hit[jk] as usize + 1] += 1;
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut sorted = vec![(0usize, 0usize); list.len()];
    for &(jk, up) in &list {
        let h = mb.first_hit[jk] as usize;
        sorted[fill[h]] = (jk, up);
        fill[h] += 1;
    }
    list.clear();
    let block = (n / 64).max(256);
    // Per block: its partial env-map gradient (None without entries) and its records.
    type Block<F, R> = (Option<Vec<[F; 3]>>, Vec<R>);
    let partials: Vec<Block<F, R>> = grads
        .v_albedo
        .par_chunks_mut(block * m * 3)
        .zip(grads.v_roughness.par_chunks_mut(block * m))
        .zip(grads.v_normals.par_chunks_mut(block * m * 3))
        .enumerate()
        .map(|(bi, ((alb, rough), nrm))| {
            let h0 = bi * block;
            let h1 = (h0 + block).min(n);
            let mut records = Vec::new();
            if start[h0] == start[h1] {
                return (None, records);
            }
            let mut v_env = vec![[F::ZERO; 3]; texels];
            let mut esc = Escapes::new();
            let mut scratch: [Vec<f32>; 3] = Default::default();
            for h in h0..h1 {
                let lh = h - h0;
                for &(jk, up) in &sorted[start[h]..start[h + 1]] {
                    esc.fill(mb, light, h as u32);
                    let g = upstream(up, &esc, jk / kk, jk % kk, &mut records);
                    let (alb, rough, nrm) = (
                        &mut alb[lh * m * 3..(lh + 1) * m * 3],
                        &mut rough[lh * m..(lh + 1) * m],
                        &mut nrm[lh * m * 3..(lh + 1) * m * 3],
                    );
                    #[cfg(target_arch = "x86_64")]
                    if lanes {
                        // SAFETY: `lane_kernels` checked that `F` is `f32` and that the CPU has
                        // AVX2, so every cast below is to the same type.
                        unsafe {
                            crate::gather_lanes::backward_pair_avx2(
                                mb,
                                same(mats),
                                same(&esc),
                                light.diffuse,
                                (jk / kk, jk % kk),
                                *same::<[F; 3], [f32; 3]>(&g),
                                same_mut(alb),
                                same_mut(rough),
                                same_mut(nrm),
                                same_mut(&mut v_env),
                                &mut scratch,
                            );
                        }
                        continue;
                    }
                    backward_pair(mb, mats, &esc, light.diffuse, jk / kk, jk % kk, g, alb, rough, nrm, &mut v_env);
                }
            }
            (Some(v_env), records)
        })
        .collect();
    let mut records = Vec::new();
    let mut parts: Vec<Vec<[F; 3]>> = Vec::new();
    for (part, recs) in partials {
        parts.extend(part);
        records.extend(recs);
    }
    add_parts_in_order(&mut grads.v_env, &parts, |acc, x| {
        for c in 0..3 {
            acc[c] += x[c];
        }
    });
    (grads, records)
}

/// `x` as a `U`.
///
/// # Safety
/// `T` and `U` are the same type up to `F` = `f32` (checked by [`lane_kernels`]).
#[cfg(target_arch = "x86_64")]
unsafe fn same<T, U>(x: &T) -> &U {
    // SAFETY: the caller's contract.
    unsafe { &*(x as *const T as *const U) }
}

/// `x` as a slice of `U`; the contract of [`same`].
#[cfg(target_arch = "x86_64")]
unsafe fn same_mut<T, U>(x: &mut [T]) -> &mut [U] {
    // SAFETY: the caller's contract.
    unsafe { std::slice::from_raw_parts_mut(x.as_mut_ptr() as *mut U, x.len()) }
}

/// Gradients for upstream `v_l1b` on every (j, k) (`j * K + k`, as [`crate::gather_all`] returns).
pub fn gather_all_backward(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    env: &EnvMap,
    p: &GatherParams,
    v_l1b: &[[f32; 3]],
) -> Result<GatherGrads, TraceError> {
    check(mb, mats, env)?;
    if v_l1b.len() != mb.len() * mb.k {
        return Err(TraceError::SizeMismatch { what: "v_l1b", got: v_l1b.len(), want: mb.len() * mb.k });
    }
    check_lights(mb, env, p)?;
    Ok(backward_generic(mb, mats, &LightIn::new(env, p), (0..v_l1b.len()).map(|i| (i, i)), v_l1b, p.simd))
}

/// Gradients for upstream `v_l1b[i]` on the pairs `pairs[i] = (j, k)` (radiance consistency).
pub fn gather_pairs_backward(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    env: &EnvMap,
    p: &GatherParams,
    pairs: &[(u32, u32)],
    v_l1b: &[[f32; 3]],
) -> Result<GatherGrads, TraceError> {
    check_pair_call(mb, mats, env, p, pairs)?;
    if v_l1b.len() != pairs.len() {
        return Err(TraceError::SizeMismatch { what: "v_l1b", got: v_l1b.len(), want: pairs.len() });
    }
    Ok(backward_generic(mb, mats, &LightIn::new(env, p), pair_entries(mb, pairs), v_l1b, p.simd))
}

/// The backward's entries of the pairs: `(j K + k, i)` for pair i = (j, k).
fn pair_entries<'a>(mb: &'a MicroBuffer, pairs: &'a [(u32, u32)]) -> impl Iterator<Item = (usize, usize)> + 'a {
    pairs.iter().enumerate().map(|(i, &(j, k))| (j as usize * mb.k + k as usize, i))
}

/// [`crate::gather_pairs`] and, in the same pass, [`gather_pairs_backward`] with the upstream
/// gradient of pair i given by `v(i, L1b_i)` (radiance consistency, where it depends on the
/// pair's own L1b alone). Each pair's L1b is shaded on its hit's escape list and the gradient
/// runs on the same list, which is filled once for both. Returns L1b per pair (0 for pairs
/// without a hit) and the gradients, with the bits of the two calls.
pub fn gather_pairs_with_backward(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    env: &EnvMap,
    p: &GatherParams,
    pairs: &[(u32, u32)],
    v: impl Fn(usize, [f32; 3]) -> [f32; 3] + Sync,
) -> Result<(Vec<[f32; 3]>, GatherGrads), TraceError> {
    check_pair_call(mb, mats, env, p, pairs)?;
    let light = LightIn::new(env, p);
    let lanes = lane_kernels::<f32>(p.simd);
    let (grads, records) =
        backward_with(mb, mats, &light, pair_entries(mb, pairs), p.simd, |up, esc, j, k, records| {
            let l1b = shade_f32(lanes, mb, mats, esc, light.diffuse, j, k);
            records.push((up, l1b));
            v(up, l1b)
        });
    let mut l1b = vec![[0.0; 3]; pairs.len()];
    for (up, value) in records {
        l1b[up] = value;
    }
    Ok((l1b, grads))
}

/// Add the gradient of `v . L1b(j, k)` into `grads` (sequential; one pair).
pub fn gather_one_backward(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    env: &EnvMap,
    p: &GatherParams,
    j: usize,
    k: usize,
    v: [f32; 3],
    grads: &mut GatherGrads,
) -> Result<(), TraceError> {
    check(mb, mats, env)?;
    check_pairs(mb, [(j, k)])?;
    let (n, m) = (mb.len(), mats.m);
    if grads.v_albedo.len() != n * m * 3 || grads.v_env.len() != env.data.len() {
        return Err(TraceError::SizeMismatch { what: "grads", got: grads.v_albedo.len(), want: n * m * 3 });
    }
    check_lights(mb, env, p)?;
    if let Some(h) = mb.hit(j, k) {
        let mut esc = Escapes::new();
        esc.fill(mb, &LightIn::new(env, p), h);
        let h = h as usize;
        backward_pair(
            mb,
            mats,
            &esc,
            p.diffuse,
            j,
            k,
            v,
            &mut grads.v_albedo[h * m * 3..(h + 1) * m * 3],
            &mut grads.v_roughness[h * m..(h + 1) * m],
            &mut grads.v_normals[h * m * 3..(h + 1) * m * 3],
            &mut grads.v_env,
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bright::{brightest_texels, BrightLights};
    use crate::gather::{gather_all, gather_from, gather_one, gather_one_generic, gather_pairs};
    use crate::scenes::object_scene;
    use crate::{Bvh, TraceParams};
    use glam::Vec3;
    use svgir_core::{Rng, Surfels};
    use svgir_shading::ggx;

    struct Case {
        surfels: Surfels,
        mb: MicroBuffer,
        albedo: Vec<f64>,
        rough: Vec<f64>,
        normals: Vec<f64>,
        env: EnvMap,
        env64: Vec<[f64; 3]>,
        lights: Option<BrightLights>,
        diffuse: Diffuse,
    }

    /// A scene with random materials and map; `lights` of its texels act as directional lights.
    fn case(m: usize, seed: u64, lights: usize) -> Case {
        let surfels = object_scene(400, seed);
        let bvh = Bvh::build(&surfels);
        let mb = MicroBuffer::trace(&bvh, &surfels, 16, seed, &TraceParams::default()).unwrap();
        let mut rng = Rng::new(seed);
        let n = surfels.len();
        let albedo = (0..n * m * 3).map(|_| rng.range(0.03, 0.8) as f64).collect();
        let rough = (0..n * m).map(|_| rng.range(0.09, 0.99) as f64).collect();
        let mut normals = Vec::with_capacity(n * m * 3);
        for i in 0..n {
            for _ in 0..m {
                let d = (surfels.normal(i) + 0.3 * Vec3::new(rng.normal(), rng.normal(), rng.normal())).normalize();
                normals.extend([d.x as f64, d.y as f64, d.z as f64]);
            }
        }
        let mut env = EnvMap::constant(16, 8, [0.0; 3]);
        for t in env.data.iter_mut() {
            *t = [rng.range(0.1, 3.0), rng.range(0.1, 3.0), rng.range(0.1, 3.0)];
        }
        let env64 = env.data.iter().map(|t| t.map(|x| x as f64)).collect();
        let lights = (lights > 0).then(|| {
            let texels = brightest_texels(&env, lights);
            BrightLights::trace(&bvh, &surfels, &mb.normals, &env, &texels, &TraceParams::default(), None).unwrap()
        });
        Case { surfels, mb, albedo, rough, normals, env, env64, lights, diffuse: Diffuse::Added }
    }

    fn light_in<'a>(c: &'a Case, env: &'a [[f64; 3]], env_max: f64) -> LightIn<'a, f64> {
        LightIn { geom: &c.env, env, env_max, lights: c.lights.as_ref(), diffuse: c.diffuse, cache: None }
    }

    fn mats64(c: &Case, m: usize) -> VertexMaterials<'_, f64> {
        VertexMaterials { m, albedo: &c.albedo, roughness: &c.rough, normals: &c.normals }
    }

    /// sum_jk g_jk . L1b_jk in f64.
    fn loss(c: &Case, m: usize, env: &[[f64; 3]], env_max: f64, g: &[[f64; 3]]) -> f64 {
        let mats = mats64(c, m);
        let mut total = 0.0;
        for j in 0..c.mb.len() {
            for k in 0..c.mb.k {
                let l = gather_one_generic(&c.mb, &mats, &light_in(c, env, env_max), j, k);
                total += (0..3).map(|ch| l[ch] * g[j * c.mb.k + k][ch]).sum::<f64>();
            }
        }
        total
    }

    #[test]
    fn gradients_match_finite_differences_f64() {
        use Diffuse::{Added, Layered};
        for (m, seed, lights, diffuse) in
            [(4usize, 1u64, 0usize, Added), (6, 2, 0, Layered), (1, 3, 0, Added), (4, 4, 6, Layered), (2, 5, 3, Added)]
        {
            let mut c = case(m, seed, lights);
            c.diffuse = diffuse;
            let env_max = 2.5; // some bilinear lookups exceed it: exercises the clamp
            let mut rng = Rng::new(seed + 10);
            let g: Vec<[f64; 3]> = (0..c.mb.len() * c.mb.k)
                .map(|_| [rng.normal() as f64, rng.normal() as f64, rng.normal() as f64])
                .collect();
            let env64 = c.env64.clone();
            let grads = backward_generic(
                &c.mb,
                &mats64(&c, m),
                &light_in(&c, &env64, env_max),
                (0..g.len()).map(|i| (i, i)),
                &g,
                Simd::Scalar,
            );
            let h = 1e-6;
            let pick = |v: &[f64], rng: &mut Rng| -> Vec<usize> {
                let nz: Vec<usize> = (0..v.len()).filter(|&i| v[i] != 0.0).collect();
                assert!(nz.len() > 10, "M={m}: only {} non-zero gradients", nz.len());
                (0..8).map(|_| nz[rng.below(nz.len())]).collect()
            };
            let check = |name: &str, i: usize, analytic: f64, plus: f64, minus: f64| {
                let fd = (plus - minus) / (2.0 * h);
                assert!(
                    (fd - analytic).abs() <= 1e-6 * (1.0 + fd.abs()),
                    "M={m} lights={lights} {diffuse:?} {name}[{i}]: fd {fd} vs {analytic}"
                );
            };
            for i in pick(&grads.v_albedo, &mut rng) {
                let x = c.albedo[i];
                c.albedo[i] = x + h;
                let p = loss(&c, m, &env64, env_max, &g);
                c.albedo[i] = x - h;
                let q = loss(&c, m, &env64, env_max, &g);
                c.albedo[i] = x;
                check("albedo", i, grads.v_albedo[i], p, q);
            }
            for i in pick(&grads.v_roughness, &mut rng) {
                let x = c.rough[i];
                c.rough[i] = x + h;
                let p = loss(&c, m, &env64, env_max, &g);
                c.rough[i] = x - h;
                let q = loss(&c, m, &env64, env_max, &g);
                c.rough[i] = x;
                check("roughness", i, grads.v_roughness[i], p, q);
            }
            for i in pick(&grads.v_normals, &mut rng) {
                let x = c.normals[i];
                c.normals[i] = x + h;
                let p = loss(&c, m, &env64, env_max, &g);
                c.normals[i] = x - h;
                let q = loss(&c, m, &env64, env_max, &g);
                c.normals[i] = x;
                check("normal", i, grads.v_normals[i], p, q);
            }
            let flat: Vec<f64> = grads.v_env.iter().flatten().copied().collect();
            let mut clamped_zero = 0;
            for i in pick(&flat, &mut rng) {
                let mut e = env64.clone();
                e[i / 3][i % 3] += h;
                let p = loss(&c, m, &e, env_max, &g);
                e[i / 3][i % 3] -= 2.0 * h;
                let q = loss(&c, m, &e, env_max, &g);
                check("env", i, flat[i], p, q);
            }
            // Every light texel: its gradient comes from the directional path only.
            for &t in c.lights.iter().flat_map(|l| l.texels.iter()) {
                let i = 3 * t as usize + 1;
                let mut e = env64.clone();
                e[i / 3][i % 3] += h;
                let p = loss(&c, m, &e, env_max, &g);
                e[i / 3][i % 3] -= 2.0 * h;
                let q = loss(&c, m, &e, env_max, &g);
                check("light texel", i, flat[i], p, q);
            }
            // Texels whose every lookup is clamped get exactly zero, and FD agrees.
            for i in (0..flat.len()).filter(|&i| flat[i] == 0.0).take(3) {
                let mut e = env64.clone();
                e[i / 3][i % 3] += 1e-4;
                clamped_zero += 1;
                assert!((loss(&c, m, &e, env_max, &g) - loss(&c, m, &env64, env_max, &g)).abs() < 1e-9);
            }
            let _ = clamped_zero;
        }
    }

    /// `gather_from(back, front)` is the back rows of `gather_all` on one buffer stacking the
    /// front rows over the back ones (whose hits index the front rows).
    #[test]
    fn gather_from_back_rays_reflects_off_the_front_sides() {
        let m = 4;
        let c = case(m, 5, 3);
        let n = c.mb.len();
        let back_axes = c.mb.normals.iter().map(|a| -*a).collect();
        let back =
            MicroBuffer::trace_about(&Bvh::build(&c.surfels), &c.surfels, back_axes, 16, 5, &TraceParams::default())
                .unwrap();
        let cat = |a: &MicroBuffer, b: &MicroBuffer| MicroBuffer {
            k: a.k,
            normals: [a.normals.clone(), b.normals.clone()].concat(),
            xi: [a.xi.clone(), b.xi.clone()].concat(),
            vis: [a.vis.clone(), b.vis.clone()].concat(),
            radiance: [a.radiance.clone(), b.radiance.clone()].concat(),
            first_hit: [a.first_hit.clone(), b.first_hit.clone()].concat(),
            uv: [a.uv.clone(), b.uv.clone()].concat(),
            interleave: a.interleave,
        };
        let stacked = cat(&c.mb, &back);
        let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        let (alb, rough, nrm) = (f32s(&c.albedo), f32s(&c.rough), f32s(&c.normals));
        let twice = |v: &[f32]| [v, v].concat();
        let (alb2, rough2, nrm2) = (twice(&alb), twice(&rough), twice(&nrm));
        let mats = VertexMaterials { m, albedo: &alb, roughness: &rough, normals: &nrm };
        let mats2 = VertexMaterials { m, albedo: &alb2, roughness: &rough2, normals: &nrm2 };
        let lights = c.lights.as_ref().unwrap();
        let cols: Vec<Vec<f32>> =
            (0..lights.len()).map(|b| (0..2 * n).map(|j| lights.visibility(j % n, b)).collect()).collect();
        let lights2 = BrightLights::from_visibility(&c.env, &lights.texels, &cols).unwrap();
        let p = GatherParams { lights: Some(lights), diffuse: c.diffuse, ..GatherParams::default() };
        let p2 = GatherParams { lights: Some(&lights2), ..p };
        let got = gather_from(&back, &c.mb, &mats, &c.env, &p).unwrap();
        let want = gather_all(&stacked, &mats2, &c.env, &p2).unwrap();
        assert_eq!(got, want[n * 16..]);
        assert!(got.iter().filter(|l| l[0] > 0.0).count() > 100, "the back rays should hit lit surfaces");
        assert_ne!(got, gather_all(&c.mb, &mats, &c.env, &p).unwrap());
        let short = MicroBuffer::trace(&Bvh::build(&c.surfels), &c.surfels, 8, 5, &TraceParams::default()).unwrap();
        assert!(gather_from(&short, &c.mb, &mats, &c.env, &p).is_err());
    }

    #[test]
    fn f32_paths_agree_with_naive_formula_and_each_other() {
        for (lights, diffuse) in [(0, Diffuse::Added), (5, Diffuse::Layered)] {
            // Every kernel this CPU runs: the scalar one and the lanes of `gather_lanes`.
            for simd in Simd::available() {
                f32_paths_agree(lights, diffuse, simd);
            }
        }
    }

    fn f32_paths_agree(lights: usize, diffuse: Diffuse, simd: Simd) {
        let m = 4;
        let c = case(m, 7, lights);
        let alb: Vec<f32> = c.albedo.iter().map(|&x| x as f32).collect();
        let rough: Vec<f32> = c.rough.iter().map(|&x| x as f32).collect();
        let nrm: Vec<f32> = c.normals.iter().map(|&x| x as f32).collect();
        let mats = VertexMaterials { m, albedo: &alb, roughness: &rough, normals: &nrm };
        let p = GatherParams { lights: c.lights.as_ref(), diffuse, simd, ..GatherParams::default() };
        let all = gather_all(&c.mb, &mats, &c.env, &p).unwrap();
        let scalar = gather_all(&c.mb, &mats, &c.env, &GatherParams { simd: Simd::Scalar, ..p }).unwrap();
        // The K-sample part sees the light texels as black.
        let mut sampled = c.env.clone();
        for &t in c.lights.iter().flat_map(|l| l.texels.iter()) {
            sampled.data[t as usize] = [0.0; 3];
        }
        let (n, kk) = (c.mb.len(), c.mb.k);
        let mut nonzero = 0;
        for j in 0..n {
            for k in 0..kk {
                let got = all[j * kk + k];
                let one = gather_one(&c.mb, &mats, &c.env, &p, j, k).unwrap();
                assert_eq!(scalar[j * kk + k], one, "{simd:?}");
                // The lanes sum the escapes in another order and take Fresnel's exp2 from a
                // polynomial: a few ulp of each term.
                for ch in 0..3 {
                    assert!(
                        (got[ch] - one[ch]).abs() <= 2e-6 * one[ch].abs() + 1e-9,
                        "{simd:?} ({j},{k}): {got:?} vs {one:?}"
                    );
                }
                // Naive Eqn 13 straight from the SPEC text.
                let mut want = [0.0f32; 3];
                if let Some(h) = c.mb.hit(j, k) {
                    let h = h as usize;
                    let uv = c.mb.uv(j, k);
                    let w =
                        [(1.0 - uv[0]) * (1.0 - uv[1]), uv[0] * (1.0 - uv[1]), (1.0 - uv[0]) * uv[1], uv[0] * uv[1]];
                    // (direction, radiance, weight): escaped samples, then directional lights.
                    // h's direction s as the gather computes it (`MicroBuffer::direction` up to
                    // f32 rounding, which near the map's poles moves a lookup by ~1e-4).
                    let frame = svgir_shading::hemisphere::HemiFrame::new(c.mb.normals[h], c.mb.xi[h]);
                    let table = svgir_shading::hemisphere::FibTable::new(kk);
                    let mut incoming: Vec<(Vec3, [f32; 3], f32)> = (0..kk)
                        .filter(|&s| c.mb.escaped(h, s))
                        .map(|s| {
                            let l = frame.dir(&table, s);
                            (l, sampled.lookup(l).map(|x| x.clamp(0.0, 64.0)), std::f32::consts::TAU / kk as f32)
                        })
                        .collect();
                    if let Some(ls) = &c.lights {
                        for (b, &t) in ls.texels.iter().enumerate() {
                            let v = ls.visibility(h, b);
                            incoming.push((ls.dirs[b], c.env.data[t as usize], v * ls.solid_angle[b]));
                        }
                    }
                    for (l, le, weight) in incoming {
                        for mm in 0..4 {
                            let b = (h * 4 + mm) * 3;
                            let nv = [nrm[b], nrm[b + 1], nrm[b + 2]];
                            let f = ggx(
                                nv,
                                (-c.mb.direction(j, k)).to_array(),
                                l.to_array(),
                                [alb[b], alb[b + 1], alb[b + 2]],
                                rough[h * 4 + mm],
                                diffuse,
                            );
                            let cos = Vec3::from_array(nv).dot(l).max(1e-6);
                            for ch in 0..3 {
                                want[ch] += w[mm] * f[ch] * cos * le[ch] * weight;
                            }
                        }
                    }
                    nonzero += (want[0] > 0.0) as usize;
                }
                for ch in 0..3 {
                    assert!(
                        (got[ch] - want[ch]).abs() <= 1e-4 * want[ch].abs() + 1e-6,
                        "({j},{k}): {got:?} vs {want:?}"
                    );
                }
            }
        }
        assert!(nonzero > 100, "{nonzero}");
        let pairs: Vec<(u32, u32)> = (0..n as u32).map(|j| (j, j % kk as u32)).collect();
        let pv = gather_pairs(&c.mb, &mats, &c.env, &p, &pairs).unwrap();
        for (i, &(j, k)) in pairs.iter().enumerate() {
            assert_eq!(pv[i], all[j as usize * kk + k as usize]);
        }
        // Backward: batched pairs == sum of single-pair calls (up to f32 summation order),
        // and the whole-buffer backward is identical on 1 thread and on the default pool.
        let mut rng = Rng::new(3);
        let g: Vec<[f32; 3]> = pairs.iter().map(|_| [rng.normal(), rng.normal(), rng.normal()]).collect();
        let batched = gather_pairs_backward(&c.mb, &mats, &c.env, &p, &pairs, &g).unwrap();
        let mut single = GatherGrads::zeros(n, m, c.env.data.len());
        for (i, &(j, k)) in pairs.iter().enumerate() {
            gather_one_backward(&c.mb, &mats, &c.env, &p, j as usize, k as usize, g[i], &mut single).unwrap();
        }
        for (a, b) in batched
            .v_albedo
            .iter()
            .zip(&single.v_albedo)
            .chain(batched.v_normals.iter().zip(&single.v_normals))
            .chain(batched.v_roughness.iter().zip(&single.v_roughness))
        {
            assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{simd:?}: {a} vs {b}");
        }
        assert!(batched.v_roughness.iter().filter(|x| **x != 0.0).count() > 100, "{simd:?}");
        for (a, b) in batched.v_env.iter().flatten().zip(single.v_env.iter().flatten()) {
            assert!((a - b).abs() <= 1e-4 * (1.0 + b.abs()));
        }
        let gall: Vec<[f32; 3]> = all.iter().map(|_| [rng.normal(), rng.normal(), rng.normal()]).collect();
        let ga = gather_all_backward(&c.mb, &mats, &c.env, &p, &gall).unwrap();
        let gb = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| gather_all_backward(&c.mb, &mats, &c.env, &p, &gall).unwrap());
        assert_eq!(ga, gb);
        // Bad input is an error, not a panic.
        let short = VertexMaterials { m, albedo: &alb[1..], roughness: &rough, normals: &nrm };
        assert!(gather_all(&c.mb, &short, &c.env, &p).is_err());
        assert!(gather_one(&c.mb, &VertexMaterials { m: 3, ..mats }, &c.env, &p, 0, 0).is_err());
        let mut corrupt = c.mb.clone();
        corrupt.first_hit[0] = corrupt.len() as u32;
        assert!(gather_all(&corrupt, &mats, &c.env, &p).is_err());
        let _ = &c.surfels;
    }
}
