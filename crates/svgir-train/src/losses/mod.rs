//! Training losses with hand-written gradients. Each returns the loss value and accumulates
//! `weight * d loss / d input` so the rasterizer's backward receives per-pixel output gradients.
//! SSIM lives in `svgir-metrics`.

pub mod depth_normal;
pub mod l1;
pub mod mask;
pub mod objective;
pub mod opacity;
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

/// Mean squared difference of `a` (clamped to [0, 1] when `clamp`) and `b`, in f64, for the
/// logged PSNR: chunks in parallel, chunk sums added in order (the same value at any thread
/// count).
pub(crate) fn mse(a: &[f32], b: &[f32], clamp: bool) -> f64 {
    assert_eq!(a.len(), b.len());
    let sums: Vec<f64> = a
        .par_chunks(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .map(|(xs, ys)| {
            xs.iter()
                .zip(ys)
                .map(|(&x, &y)| {
                    let x = if clamp { x.clamp(0.0, 1.0) } else { x };
                    f64::from(x - y).powi(2)
                })
                .sum::<f64>()
        })
        .collect();
    sums.iter().sum::<f64>() / a.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mse_is_the_mean_of_squares_at_any_thread_count() {
        // Several chunks and a partial one; values outside [0, 1] for the clamp.
        let n = 3 * CHUNK + 123;
        let a: Vec<f32> = (0..n).map(|i| ((i * 7919) % 1000) as f32 / 800.0 - 0.1).collect();
        let b: Vec<f32> = (0..n).map(|i| ((i * 104_729) % 1000) as f32 / 1000.0).collect();
        let slow = |clamp: bool| {
            let s: f64 =
                a.iter().zip(&b).map(|(&x, &y)| f64::from(if clamp { x.clamp(0.0, 1.0) } else { x } - y).powi(2)).sum();
            s / n as f64
        };
        for clamp in [false, true] {
            let want = slow(clamp);
            let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| mse(&a, &b, clamp));
            let five = rayon::ThreadPoolBuilder::new().num_threads(5).build().unwrap().install(|| mse(&a, &b, clamp));
            assert_eq!(one.to_bits(), five.to_bits(), "clamp {clamp}");
            assert!((one - want).abs() <= 1e-12 * want, "clamp {clamp}: {one} vs {want}");
        }
        assert!(slow(true) < slow(false), "the clamp must change something");
        assert_eq!(mse(&[], &[], true), 0.0);
    }
}
