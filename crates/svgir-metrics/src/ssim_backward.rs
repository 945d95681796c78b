//! Gradient of the 3DGS/2DGS SSIM (zero padding 5, same-size map; `ssim.rs`) with respect to the
//! first image, for the training loss `1 - SSIM` (SPEC 2 / 6 use it in the photometric loss).
//!
//! With moments mu1 = G*x, mu2 = G*y, e11 = G*x^2, e12 = G*xy (G the zero-padded Gaussian
//! blur) and per-pixel S = A1 A2 / (B1 B2), A1 = 2 mu1 mu2 + C1, A2 = 2 (e12 - mu1 mu2) + C2,
//! B1 = mu1^2 + mu2^2 + C1, B2 = (e11 - mu1^2) + (e22 - mu2^2) + C2:
//!   dS/dmu1 = S (2 mu2/A1 - 2 mu2/A2 - 2 mu1/B1 + 2 mu1/B2),  dS/de11 = -S/B2,  dS/de12 = 2 S/A2.
//! The blur is symmetric with zero padding, so its adjoint is the same blur: the three per-pixel
//! partials (scaled by 1/N of the mean) are blurred once more, and
//!   v_x = G*(dS/dmu1) + 2 x G*(dS/de11) + y G*(dS/de12).
//! Work split: channels in turn, rows in parallel inside the blurs. Moments are recomputed, not saved.

use rayon::prelude::*;

use crate::error::Result;
use crate::ssim::{moments, sized, BlurBuffers, Shape, SsimVariant, C1, C2};
use svgir_core::Float;

/// 3DGS SSIM of `a` against `b` and its gradient `v_a` (d SSIM / d a, same layout as `a`).
pub fn ssim_with_grad<T: Float>(a: &[T], b: &[T], shape: Shape) -> Result<(T, Vec<T>)> {
    shape.check(a, b, SsimVariant::GaussianSplatting)?;
    let n = shape.channels;
    let inv_count = T::from_f64(1.0 / a.len() as f64);
    let two = T::from_f64(2.0);
    let mut total = 0.0f64;
    let mut v_a = svgir_core::par::filled(a.len(), T::ZERO);
    let (mut fwd, mut bwd) = (BlurBuffers::default(), BlurBuffers::default());
    let mut row_sums: Vec<f64> = Vec::new();
    for c in 0..n {
        let (w, h) = moments(a, b, shape, c, true, &mut fwd);
        let m = &fwd.out;
        let np = w * h;
        // Three stacked planes: dS/dmu1, dS/de11, dS/de12, each already scaled by 1/N; and each
        // row's SSIM sum (the map value is `a1 a2 / (b1 b2)`, as `ssim_from_moments` forms it).
        sized(&mut bwd.src, 3 * np);
        let (p_mu, rest) = bwd.src.split_at_mut(np);
        let (p_e11, p_e12) = rest.split_at_mut(np);
        row_sums.resize(h, 0.0);
        p_mu.par_chunks_mut(w)
            .zip(p_e11.par_chunks_mut(w))
            .zip(p_e12.par_chunks_mut(w))
            .zip(row_sums.par_iter_mut())
            .enumerate()
            .for_each(|(y, (((r_mu, r_e11), r_e12), row_sum))| {
                let plane = |q: usize| &m[q * np + y * w..q * np + (y + 1) * w];
                let moments = [plane(0), plane(1), plane(2), plane(3), plane(4)];
                *row_sum = map_row(moments, inv_count, [r_mu, r_e11, r_e12]);
            });
        // Rows summed in order: the value does not depend on the thread count.
        total += row_sums.iter().sum::<f64>();
        bwd.blur(3, w, h, true);
        let back = &bwd.out;
        let (q_mu, q_e11, q_e12) = (&back[..np], &back[np..2 * np], &back[2 * np..]);
        // A row per task (a pixel per task spent more on rayon than on the sum).
        v_a.par_chunks_mut(w * n).zip(a.par_chunks(w * n)).zip(b.par_chunks(w * n)).enumerate().for_each(
            |(y, ((va, pa), pb))| {
                for (x, ((va, pa), pb)) in
                    va.chunks_exact_mut(n).zip(pa.chunks_exact(n)).zip(pb.chunks_exact(n)).enumerate()
                {
                    let i = y * w + x;
                    va[c] = q_mu[i] + two * pa[c] * q_e11[i] + pb[c] * q_e12[i];
                }
            },
        );
    }
    Ok((T::from_f64(total / a.len() as f64), v_a))
}

/// One row of the SSIM map from its five moments (mu1, mu2, e11, e22, e12, as the rows of
/// [`moments`]' planes): the partials dS/dmu1, dS/de11, dS/de12 into `out` (scaled by
/// `inv_count`), and the row's map sum in pixel order (f64).
fn map_row<T: Float>(moments: [&[T]; 5], inv_count: T, out: [&mut [T]; 3]) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if crate::ssim::wide() {
        // SAFETY: `wide` found AVX2 on this CPU.
        return unsafe { map_row_avx2(moments, inv_count, out) };
    }
    map_row_body(moments, inv_count, out)
}

/// [`map_row`] compiled for AVX2 (the same operations in the same order).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn map_row_avx2<T: Float>(moments: [&[T]; 5], inv_count: T, out: [&mut [T]; 3]) -> f64 {
    map_row_body(moments, inv_count, out)
}

/// Pixels per block of [`map_row_body`]: the map values of a block are formed in a loop without a
/// carried dependency (so it vectorises) and then added to the row's sum one by one.
const MAP_BLOCK: usize = 64;

#[inline(always)]
fn map_row_body<T: Float>(moments: [&[T]; 5], inv_count: T, out: [&mut [T]; 3]) -> f64 {
    let (two, c1, c2) = (T::from_f64(2.0), T::from_f64(C1), T::from_f64(C2));
    let [p_mu1, p_mu2, p_e11, p_e22, p_e12] = moments;
    let [r_mu, r_e11, r_e12] = out;
    let w = r_mu.len();
    let mut sum = 0.0f64;
    let mut s_map = [T::ZERO; MAP_BLOCK];
    for x0 in (0..w).step_by(MAP_BLOCK) {
        let n = MAP_BLOCK.min(w - x0);
        for i in 0..n {
            let x = x0 + i;
            let (mu1, mu2) = (p_mu1[x], p_mu2[x]);
            let a1 = two * mu1 * mu2 + c1;
            let a2 = two * (p_e12[x] - mu1 * mu2) + c2;
            let b1 = mu1 * mu1 + mu2 * mu2 + c1;
            let b2 = (p_e11[x] - mu1 * mu1) + (p_e22[x] - mu2 * mu2) + c2;
            let sm = (a1 * a2) / (b1 * b2);
            s_map[i] = sm;
            let s = sm * inv_count;
            r_mu[x] = s * (two * mu2 / a1 - two * mu2 / a2 - two * mu1 / b1 + two * mu1 / b2);
            r_e11[x] = -s / b2;
            r_e12[x] = two * s / a2;
        }
        for &sm in &s_map[..n] {
            sum += sm.to_f64();
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ssim::ssim;
    use crate::ssim::tests::random_image;
    use svgir_core::Rng;

    #[test]
    fn gradient_matches_finite_differences_f64() {
        let mut rng = Rng::new(11);
        for (w, h, ch) in [(13, 12, 2), (7, 9, 3)] {
            let s = Shape::new(w, h, ch);
            let a = random_image(&mut rng, w * h * ch);
            let b: Vec<f64> = a.iter().map(|&x| 0.6 * x + 0.4 * rng.uniform_f64()).collect();
            let (val, grad) = ssim_with_grad(&a, &b, s).unwrap();
            let direct = ssim(&a, &b, s, SsimVariant::GaussianSplatting).unwrap();
            assert!((val - direct).abs() < 1e-14);
            let eps = 1e-6;
            let mut max_g = 0.0f64;
            for i in 0..a.len() {
                let mut ap = a.clone();
                ap[i] += eps;
                let mut am = a.clone();
                am[i] -= eps;
                let fp = ssim(&ap, &b, s, SsimVariant::GaussianSplatting).unwrap();
                let fm = ssim(&am, &b, s, SsimVariant::GaussianSplatting).unwrap();
                let fd = (fp - fm) / (2.0 * eps);
                max_g = max_g.max(fd.abs());
                assert!((fd - grad[i]).abs() < 1e-7 + 1e-5 * fd.abs(), "{w}x{h}x{ch} i={i}: fd {fd} vs {}", grad[i]);
            }
            assert!(max_g > 1e-3, "gradient should not be trivially zero: {max_g}");
        }
    }

    /// The AVX2 builds of the row loops give the baseline build's floats, bit for bit: the
    /// blur taps (`ssim::taps`, through the moments and the backward blur) and the map rows, in
    /// f32 and f64, on rows longer and shorter than a block.
    #[test]
    fn wide_row_loops_give_the_baseline_bits() {
        if !crate::ssim::wide() {
            eprintln!("no AVX2 on this CPU (or SVGIR_SIMD=scalar): the AVX2 row loops are not checked");
            return;
        }
        #[cfg(target_arch = "x86_64")]
        {
            let mut rng = Rng::new(17);
            for w in [5usize, 64, 131] {
                let m64: Vec<f64> =
                    (0..5 * w).map(|i| if i < 2 * w { rng.uniform_f64() } else { 0.6 * rng.uniform_f64() }).collect();
                let m32: Vec<f32> = m64.iter().map(|&x| x as f32).collect();
                fn rows<T: Float>(m: &[T], w: usize, wide: bool) -> (f64, Vec<T>) {
                    let mut r = vec![T::ZERO; 3 * w];
                    let (a, rest) = r.split_at_mut(w);
                    let (b, c) = rest.split_at_mut(w);
                    let inv = T::from_f64(1.0 / 7.0);
                    // SAFETY: `wide` found AVX2 above.
                    let moments = [0, 1, 2, 3, 4].map(|q| &m[q * w..(q + 1) * w]);
                    let sum = if wide {
                        unsafe { map_row_avx2(moments, inv, [a, b, c]) }
                    } else {
                        map_row_body(moments, inv, [a, b, c])
                    };
                    (sum, r)
                }
                let bits64 = |v: (f64, Vec<f64>)| (v.0.to_bits(), v.1.iter().map(|x| x.to_bits()).collect::<Vec<_>>());
                let bits32 = |v: (f64, Vec<f32>)| (v.0.to_bits(), v.1.iter().map(|x| x.to_bits()).collect::<Vec<_>>());
                assert_eq!(bits64(rows(&m64, w, true)), bits64(rows(&m64, w, false)), "f64 map row, width {w}");
                assert_eq!(bits32(rows(&m32, w, true)), bits32(rows(&m32, w, false)), "f32 map row, width {w}");
                let g = crate::ssim::gaussian_window::<f32>();
                let src: Vec<f32> = (0..11 * (w + 10)).map(|_| rng.uniform()).collect();
                for stride in [1, w + 10] {
                    let (mut o1, mut o2) = (vec![0f32; w], vec![0f32; w]);
                    // SAFETY: as above.
                    unsafe { crate::ssim::taps_avx2(&src, stride, &mut o1, &g) };
                    crate::ssim::taps_body(&src, stride, &mut o2, &g);
                    assert_eq!(
                        o1.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                        o2.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                        "taps, width {w}, stride {stride}"
                    );
                }
            }
        }
    }

    #[test]
    fn f32_gradient_tracks_f64() {
        let mut rng = Rng::new(5);
        let s = Shape::new(20, 16, 3);
        let a = random_image(&mut rng, 20 * 16 * 3);
        let b = random_image(&mut rng, 20 * 16 * 3);
        let (_, g64) = ssim_with_grad(&a, &b, s).unwrap();
        let to32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<_>>();
        let (_, g32) = ssim_with_grad(&to32(&a), &to32(&b), s).unwrap();
        let scale = g64.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        for (x, y) in g32.iter().zip(&g64) {
            assert!((*x as f64 - y).abs() < 1e-3 * scale, "{x} vs {y}");
        }
    }
}
