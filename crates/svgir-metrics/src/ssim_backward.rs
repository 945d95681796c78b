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
use crate::real::Real;
use crate::ssim::{gather5, moments, sized, BlurBuffers, Shape, SsimVariant, C1, C2};

/// 3DGS SSIM of `a` against `b` and its gradient `v_a` (d SSIM / d a, same layout as `a`).
pub fn ssim_with_grad<T: Real>(a: &[T], b: &[T], shape: Shape) -> Result<(T, Vec<T>)> {
    shape.check(a, b, SsimVariant::GaussianSplatting)?;
    let n = shape.channels;
    let inv_count = T::from_f64(1.0 / a.len() as f64);
    let (two, c1, c2) = (T::from_f64(2.0), T::from_f64(C1), T::from_f64(C2));
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
                let mut sum = 0.0f64;
                for x in 0..w {
                    let p = gather5(m, np, y * w + x);
                    let (mu1, mu2) = (p[0], p[1]);
                    let a1 = two * mu1 * mu2 + c1;
                    let a2 = two * (p[4] - mu1 * mu2) + c2;
                    let b1 = mu1 * mu1 + mu2 * mu2 + c1;
                    let b2 = (p[2] - mu1 * mu1) + (p[3] - mu2 * mu2) + c2;
                    let s_map = (a1 * a2) / (b1 * b2);
                    sum += s_map.to_f64();
                    let s = s_map * inv_count;
                    r_mu[x] = s * (two * mu2 / a1 - two * mu2 / a2 - two * mu1 / b1 + two * mu1 / b2);
                    r_e11[x] = -s / b2;
                    r_e12[x] = two * s / a2;
                }
                *row_sum = sum;
            });
        // Rows summed in order: the value does not depend on the thread count.
        total += row_sums.iter().sum::<f64>();
        bwd.blur(3, w, h, true);
        let back = &bwd.out;
        let (q_mu, q_e11, q_e12) = (&back[..np], &back[np..2 * np], &back[2 * np..]);
        v_a.par_chunks_exact_mut(n).zip(a.par_chunks_exact(n)).zip(b.par_chunks_exact(n)).enumerate().for_each(
            |(i, ((va, pa), pb))| {
                va[c] = q_mu[i] + two * pa[c] * q_e11[i] + pb[c] * q_e12[i];
            },
        );
    }
    Ok((T::from_f64(total / a.len() as f64), v_a))
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
