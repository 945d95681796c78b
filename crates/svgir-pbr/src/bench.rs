//! Timing table for `svgir bench pbr`: vertex shading forward and forward + backward at N = 10k
//! and 100k Gaussians, M = 4, K = 64, on a synthetic micro-buffer (no tracing needed), all
//! Gaussians visible, traced indirect on, 32 x 64 environment. One row per (N, thread count),
//! each thread count in its own rayon pool; the median of a few repetitions is reported. The
//! `cached` rows use a [`DirectionCache`] (built once, its build time reported separately), as
//! stage 2 does.

use crate::fixtures::Problem;
use crate::shade::{shade_into_cached, ShadeInputs, ShadeOutput, ShadeParams};
use crate::shade_backward::shade_backward_cached;
use std::fmt::Write;
use std::time::Instant;
use svgir_core::simd::Simd;
use svgir_trace::DirectionCache;

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
