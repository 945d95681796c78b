//! Timing table for `svgir bench pbr`: vertex shading forward and forward + backward at N = 10k
//! and 100k Gaussians, M = 4, K = 64, on a synthetic micro-buffer (no tracing needed), all
//! Gaussians visible, traced indirect on, 32 x 64 environment. One row per (N, thread count),
//! each thread count in its own rayon pool; the median of a few repetitions is reported. The
//! `cached` rows use a [`DirectionCache`] (built once, its build time reported separately), as
//! stage 2 does.

use crate::env::{EnvLight, ENV_HEIGHT};
use crate::material::{ActivatedMaterials, SvgMaterials};
use crate::shade::{shade_into_cached, Indirect, ShadeInputs, ShadeOutput, ShadeParams};
use crate::shade_backward::shade_backward_cached;
use crate::PbrError;
use glam::Vec3;
use std::fmt::Write;
use std::time::Instant;
use svgir_core::simd::Simd;
use svgir_core::{EnvMap, Rng};
use svgir_shading::gaussian_xi;
use svgir_trace::pack::{f16_from_f32, unorm16};
use svgir_trace::DirectionCache;
use svgir_trace::{MicroBuffer, NO_HIT};

/// A random micro-buffer of `n` Gaussians x `k` directions with a plausible mix of samples:
/// ~40% escaped (V = 1, no hit), ~40% blocked (V = 0, hit), ~20% partly visible; traced
/// radiance in [0, 2). Normals random; positions for it come from [`synthetic_positions`].
pub fn synthetic_microbuffer(n: usize, k: usize, seed: u64) -> MicroBuffer {
    let mut rng = Rng::new(seed);
    let normals: Vec<Vec3> =
        (0..n).map(|_| Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize_or(Vec3::Z)).collect();
    let xi = (0..n).map(|j| gaussian_xi(seed, j)).collect();
    let mut vis = Vec::with_capacity(n * k);
    let mut radiance = Vec::with_capacity(n * k);
    let mut first_hit = Vec::with_capacity(n * k);
    let mut uv = Vec::with_capacity(n * k);
    for _ in 0..n * k {
        let u = rng.uniform();
        let (v, hit) = if u < 0.4 {
            (1.0, NO_HIT)
        } else if u < 0.8 {
            (0.0, rng.below(n) as u32)
        } else {
            (rng.range(0.2, 1.0), rng.below(n) as u32)
        };
        vis.push(unorm16(v));
        let l = if hit == NO_HIT { [0.0; 3] } else { [rng.range(0.0, 2.0), rng.range(0.0, 2.0), rng.range(0.0, 2.0)] };
        radiance.push(l.map(f16_from_f32));
        first_hit.push(hit);
        uv.push([unorm16(rng.range(0.001, 0.999)), unorm16(rng.range(0.001, 0.999))]);
    }
    MicroBuffer { k, normals, xi, vis, radiance, first_hit, uv, interleave: Default::default() }
}

/// Positions 2-4 units from a camera at the origin, each Gaussian seen from its normal's side
/// at a random angle (`w_o = normalize(n + 0.6 noise)`).
pub fn synthetic_positions(mb: &MicroBuffer, seed: u64) -> Vec<Vec3> {
    let mut rng = Rng::new(seed ^ 0x5eed);
    mb.normals
        .iter()
        .map(|&n| {
            let wo = (n + 0.6 * Vec3::new(rng.normal(), rng.normal(), rng.normal())).normalize_or(n);
            -wo * rng.range(2.0, 4.0)
        })
        .collect()
}

/// Random raw materials (albedo, roughness spread over their ranges, small normal offsets).
pub fn synthetic_materials(n: usize, m: usize, seed: u64) -> SvgMaterials {
    let mut rng = Rng::new(seed ^ 0xa1b);
    SvgMaterials {
        m,
        albedo_raw: (0..n * m * 3).map(|_| rng.normal()).collect(),
        roughness_raw: (0..n * m).map(|_| rng.normal()).collect(),
        normal_offset: (0..n * m * 3).map(|_| 0.2 * rng.normal()).collect(),
    }
}

fn median_ms(mut f: impl FnMut(), reps: usize) -> f64 {
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(|a, b| a.total_cmp(b));
    t[t.len() / 2]
}

/// A synthetic shading problem: N Gaussians, M vertices, K directions, all visible, traced
/// indirect, 32 x 64 environment, and a random upstream gradient. Shared by the table below, the
/// divan bench and the profiling example.
pub struct Problem {
    /// Synthetic micro-buffers: N Gaussians x K traced directions.
    pub mb: MicroBuffer,
    /// Gaussian centres, N.
    pub positions: Vec<Vec3>,
    /// Random activated vertex materials, N x M.
    pub mats: ActivatedMaterials,
    /// The environment radiance (32 x 64) from a seeded [`EnvLight`].
    pub env: EnvMap,
    /// All true: every Gaussian is shaded.
    pub visible: Vec<bool>,
    /// Random upstream gradient on the shaded colour, N x M x 3.
    pub v_color: Vec<f32>,
}

impl Problem {
    /// Build the problem for N Gaussians, M vertices and K directions from fixed seeds.
    pub fn new(n: usize, m: usize, k: usize) -> Result<Self, PbrError> {
        let mb = synthetic_microbuffer(n, k, 1);
        let positions = synthetic_positions(&mb, 1);
        let mats = synthetic_materials(n, m, 1).activated(&mb.normals)?;
        let env = EnvLight::new(ENV_HEIGHT, 3)?.radiance();
        let mut rng = Rng::new(7);
        let v_color = (0..n * m * 3).map(|_| rng.normal()).collect();
        Ok(Self { mb, positions, mats, env, visible: vec![true; n], v_color })
    }

    /// The problem as shading inputs (camera at the origin, traced indirect, default parameters).
    pub fn inputs(&self) -> ShadeInputs<'_, f32> {
        ShadeInputs {
            mb: &self.mb,
            positions: &self.positions,
            camera_center: Vec3::ZERO,
            visible: &self.visible,
            mats: self.mats.view(),
            env_geom: &self.env,
            env: &self.env.data,
            indirect: Indirect::Traced { rho: 1.0 },
            params: ShadeParams::default(),
            lights: None,
        }
    }
}

/// One row per (N, thread count) for the given sizes, with M = 4 and K directions.
pub fn bench_table_sizes(threads: usize, sizes: &[usize], k: usize) -> String {
    let m = 4usize;
    let mut out = String::new();
    let _ = writeln!(out, "svgir-pbr: vertex shading, M = {m}, K = {k}, all visible, traced indirect, env 32x64");
    let _ = writeln!(
        out,
        "{:>8} {:>7} {:>7} {:>7} {:>10} {:>11} {:>14}",
        "N", "threads", "cache", "path", "fwd ms", "fwd+bwd ms", "Msample/s fwd"
    );
    // The scalar oracle and the lane kernels (`shade_simd`) this CPU has.
    let paths = Simd::available();
    let mut counts = vec![1usize];
    if threads > 1 {
        counts.push(threads);
    }
    for &n in sizes {
        let problem = match Problem::new(n, m, k) {
            Ok(p) => p,
            Err(e) => return format!("{out}error: {e}\n"),
        };
        let (base, v_color, mb, env) = (problem.inputs(), &problem.v_color, &problem.mb, &problem.env);
        let reps = if n > 50_000 { 3 } else { 5 };
        let start = Instant::now();
        let cache = match DirectionCache::new(mb, env) {
            Ok(c) => c,
            Err(e) => return format!("{out}error: {e}\n"),
        };
        let build_ms = start.elapsed().as_secs_f64() * 1e3;
        for &t in &counts {
            let pool = match rayon::ThreadPoolBuilder::new().num_threads(t).build() {
                Ok(pool) => pool,
                Err(e) => return format!("{out}error: {e}\n"),
            };
            for (cached, &path) in [None, Some(&cache)].into_iter().flat_map(|c| paths.iter().map(move |p| (c, p))) {
                let inp = ShadeInputs { params: ShadeParams { simd: path, ..base.params }, ..base };
                let mut buf = ShadeOutput::new();
                let (fwd, both) = pool.install(|| {
                    let fwd = median_ms(
                        || {
                            let _ = shade_into_cached(&inp, cached, &mut buf);
                        },
                        reps,
                    );
                    let both = median_ms(
                        || {
                            let _ = shade_into_cached(&inp, cached, &mut buf);
                            let _ = std::hint::black_box(shade_backward_cached(&inp, cached, v_color));
                        },
                        reps,
                    );
                    (fwd, both)
                });
                let rate = (n * k * m) as f64 / (fwd * 1e-3) / 1e6;
                let tag = if cached.is_some() { "yes" } else { "no" };
                let name = path.name();
                let _ = writeln!(out, "{n:>8} {t:>7} {tag:>7} {name:>7} {fwd:>10.1} {both:>11.1} {rate:>14.1}");
            }
        }
        let _ = writeln!(
            out,
            "{n:>8} direction cache: built in {build_ms:.1} ms ({} threads), {:.1} MB",
            rayon::current_num_threads(),
            cache.memory_bytes() as f64 / 1e6
        );
    }
    out
}

/// The table for N = 10k and 100k with SPEC's K = 64, then 100k with K = 4, the directions of
/// stage 2's gradient subsets, fewer than a lane block (what `svgir bench` prints).
pub fn bench_table(threads: usize) -> String {
    bench_table_sizes(threads, &[10_000, 100_000], 64) + &bench_table_sizes(threads, &[100_000], 4)
}
