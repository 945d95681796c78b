//! Training losses with hand-written gradients. Each returns the loss value and accumulates
//! `weight * d loss / d input` so the rasterizer's backward receives per-pixel output gradients.
//! SSIM lives in `svgir-metrics`.

pub mod depth_normal;
pub mod l1;
pub mod mask;
pub mod objective;
pub mod smoothness;

use rayon::prelude::*;

/// Pixels (or per-pixel values) per rayon task of the per-pixel loss loops ([`chunked_sum`],
/// the composite, the objectives): a 256-pixel-wide image's 16 rows.
pub(crate) const CHUNK: usize = 4096;

/// `sum_i f(i, x[i], &mut g[i])`, chunks of pixels in parallel; the chunk sums are added in
/// order, so the value does not depend on the thread count.
pub(crate) fn chunked_sum(x: &[f32], g: &mut [f32], f: impl Fn(usize, f32, &mut f32) -> f64 + Sync) -> f64 {
    assert_eq!(x.len(), g.len());
    let sums: Vec<f64> = x
        .par_chunks(CHUNK)
        .zip(g.par_chunks_mut(CHUNK))
        .enumerate()
        .map(|(c, (xs, gs))| xs.iter().zip(gs).enumerate().map(|(j, (&x, g))| f(c * CHUNK + j, x, g)).sum())
        .collect();
    sums.iter().sum()
}
