//! Adam over stage 1's five groups at a trained lego's size (217.7k Gaussians, 59 floats each):
//! the vectorised update against the per-float oracle. `cargo bench -p svgir-train --bench adam`.

use svgir_core::Rng;
use svgir_train::adam::AdamGroup;

fn main() {
    println!("cpu: {}, threads: {}", svgir_core::simd::cpu_features(), rayon::current_num_threads());
    divan::main();
}

const ROWS: usize = 217_700;

/// The stage-1 groups (position, rotation, log-scale, opacity, SH with DC at 20x the rest's rate).
fn groups() -> Vec<(AdamGroup, Vec<f32>, Vec<f32>)> {
    let mut rng = Rng::new(1);
    [3usize, 4, 2, 1, 48]
        .iter()
        .map(|&stride| {
            let mut g = AdamGroup::new("x", 1e-3, stride, ROWS);
            if stride == 48 {
                g = g.with_lr_scale((0..48).map(|c| if c < 3 { 1.0 } else { 0.05 }).collect());
            }
            let p = (0..ROWS * stride).map(|_| rng.normal()).collect();
            let grad = (0..ROWS * stride).map(|_| 1e-3 * rng.normal()).collect();
            (g, p, grad)
        })
        .collect()
}

#[divan::bench(sample_count = 20)]
fn step(bencher: divan::Bencher) {
    let mut gs = groups();
    bencher.bench_local(|| {
        for (g, p, grad) in gs.iter_mut() {
            g.step(p, grad);
        }
    });
}

#[divan::bench(sample_count = 20)]
fn step_reference(bencher: divan::Bencher) {
    let mut gs = groups();
    bencher.bench_local(|| {
        for (g, p, grad) in gs.iter_mut() {
            g.step_reference(p, grad);
        }
    });
}
