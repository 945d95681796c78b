//! divan benches of the stage-2 vertex shading: N = 10k Gaussians, M = 4, K = 64 (synthetic
//! micro-buffer, all visible, traced indirect), forward and backward, without and with the
//! direction cache, on the default rayon pool.

use svgir_pbr::fixtures::Problem;
use svgir_pbr::{
    shade, shade_backward, shade_backward_cached, shade_into_cached, DirectionCache, ShadeInputs, ShadeOutput,
};

fn main() {
    divan::main();
}

const N: usize = 10_000;

fn with_inputs<R>(f: impl FnOnce(&ShadeInputs<f32>, &[f32]) -> R) -> R {
    let problem = Problem::new(N, 4, 64).unwrap();
    f(&problem.inputs(), &problem.v_color)
}

#[divan::bench(sample_count = 10)]
fn forward_10k(b: divan::Bencher) {
    with_inputs(|inp, _| b.bench(|| shade(inp).unwrap()));
}

#[divan::bench(sample_count = 10)]
fn backward_10k(b: divan::Bencher) {
    with_inputs(|inp, g| b.bench(|| shade_backward(inp, g).unwrap()));
}

#[divan::bench(sample_count = 10)]
fn forward_10k_cached(b: divan::Bencher) {
    with_inputs(|inp, _| {
        let cache = DirectionCache::new(inp.mb, inp.env_geom).unwrap();
        let mut out = ShadeOutput::new();
        b.bench_local(|| shade_into_cached(inp, Some(&cache), &mut out).unwrap())
    });
}

#[divan::bench(sample_count = 10)]
fn backward_10k_cached(b: divan::Bencher) {
    with_inputs(|inp, g| {
        let cache = DirectionCache::new(inp.mb, inp.env_geom).unwrap();
        b.bench(|| shade_backward_cached(inp, Some(&cache), g).unwrap())
    });
}
