//! Forward and forward+backward timings of the rasterizer on the benchmark scenes of
//! `svgir_raster::bench` (SH degree 3, all auxiliary outputs). Run with
//! `cargo bench -p svgir-raster`; thread count is rayon's default (RAYON_NUM_THREADS).

use svgir_raster::fixtures::Problem;
use svgir_raster::{backward, render, RasterConfig};

fn main() {
    divan::main();
}

const CASES: &[(usize, u32)] = &[(10_000, 256), (100_000, 400), (300_000, 800)];

#[divan::bench(args = CASES, sample_count = 5, sample_size = 1)]
fn forward(bencher: divan::Bencher, case: &(usize, u32)) {
    let problem = Problem::new(case.0, case.1);
    let (input, cfg) = (problem.input(), RasterConfig::default());
    bencher.bench_local(|| render(&input, &cfg));
}

#[divan::bench(args = CASES, sample_count = 5, sample_size = 1)]
fn forward_backward(bencher: divan::Bencher, case: &(usize, u32)) {
    let problem = Problem::new(case.0, case.1);
    let (input, grads, cfg) = (problem.input(), problem.grads(), RasterConfig::default());
    bencher.bench_local(|| {
        let (out, st) = render(&input, &cfg);
        backward(&input, &cfg, &st, &out, &grads)
    });
}
