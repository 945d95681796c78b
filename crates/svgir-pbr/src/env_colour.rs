//! Holding the learned light's colour smooth (our option; docs/method.md, "Where svgir differs").
//!
//! Each texel's parameter `p_c` (per channel c) splits into a grey part, the channel mean `m`,
//! and a colour part `q_c = p_c - m` (under `EnvActivation::Exp` a log-chroma: the ratios between
//! channels). [`ColourProjector`] keeps the grey part as it is and replaces each channel's colour
//! part by its least-squares fit in real spherical harmonics up to a degree: the light can still
//! be bright or dark texel by texel (a sun, a window), but its colour varies only slowly over the
//! sphere (blue sky over green ground, not an orange glow round the sun). With no degree it
//! removes the colour (a grey light).
//!
//! Why: under a single light the albedo and the light's colour are ambiguous region by region;
//! on cup_and_ball the free light grows a localised orange glow that the albedo then offsets.
//!
//! The fit is unweighted (every texel counts once), so the projector is symmetric and
//! idempotent: applied to the parameters it enforces the constraint, applied to their gradient
//! it gives the steepest descent within it. 2048 texels and at most 16 coefficients: sequential.

use crate::PbrError;
use svgir_core::sh;
use svgir_core::EnvMap;

/// Orthogonal projection of per-texel RGB parameters onto "any grey part, colour part in SH
/// up to `degree`" (or "grey" with no degree).
#[derive(Clone, Debug)]
pub struct ColourProjector {
    /// Texels of the map (`width x height`).
    texels: usize,
    /// SH coefficients kept per channel (0: grey).
    coeffs: usize,
    /// Basis value per texel and coefficient, row-major `texels x coeffs`.
    basis: Vec<f64>,
    /// Inverse Gram matrix `(B^T B)^-1`, `coeffs x coeffs`.
    gram_inv: Vec<f64>,
}

impl ColourProjector {
    /// For a `width` x `height` map in `EnvMap`'s texel layout; `degree` at most 3, `None` for
    /// a grey light.
    pub fn new(width: u32, height: u32, degree: Option<u32>) -> Result<Self, PbrError> {
        if width < 2 || height < 2 {
            return Err(PbrError::InvalidParameter(format!("environment {width}x{height}")));
        }
        let coeffs = match degree {
            None => 0,
            Some(d) if d <= 3 => sh::num_coeffs(d),
            Some(d) => return Err(PbrError::InvalidParameter(format!("light colour SH degree {d} (at most 3)"))),
        };
        let grid = EnvMap::constant(width, height, [0.0; 3]);
        let mut basis = Vec::with_capacity((width * height) as usize * coeffs);
        let mut b = [0f32; 16];
        for row in 0..height {
            for col in 0..width {
                sh::basis(degree.unwrap_or(0), grid.texel_dir(row, col), &mut b);
                basis.extend(b[..coeffs].iter().map(|&x| x as f64));
            }
        }
        let mut gram = vec![0f64; coeffs * coeffs];
        if coeffs > 0 {
            for t in basis.chunks_exact(coeffs) {
                for i in 0..coeffs {
                    for j in 0..coeffs {
                        gram[i * coeffs + j] += t[i] * t[j];
                    }
                }
            }
        }
        let gram_inv = invert(&gram, coeffs)
            .ok_or_else(|| PbrError::InvalidParameter(format!("SH degree {degree:?} on a {width}x{height} map")))?;
        Ok(Self { texels: (width * height) as usize, coeffs, basis, gram_inv })
    }

    /// Project `texels` (parameters or their gradient, one per texel) in place.
    pub fn apply(&self, texels: &mut [[f32; 3]]) -> Result<(), PbrError> {
        let n = self.coeffs;
        crate::expect_len("light texels", texels.len(), self.texels)?;
        let mean = |t: &[f32; 3]| (t[0] as f64 + t[1] as f64 + t[2] as f64) / 3.0;
        // B^T q per channel, then a = (B^T B)^-1 B^T q.
        let mut rhs = vec![[0f64; 3]; n];
        if n > 0 {
            for (t, b) in texels.iter().zip(self.basis.chunks_exact(n)) {
                let m = mean(t);
                for (r, &bk) in rhs.iter_mut().zip(b) {
                    (0..3).for_each(|c| r[c] += bk * (t[c] as f64 - m));
                }
            }
        }
        let a: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                let row = &self.gram_inv[i * n..(i + 1) * n];
                [0, 1, 2].map(|c| row.iter().zip(&rhs).map(|(g, r)| g * r[c]).sum())
            })
            .collect();
        for (k, t) in texels.iter_mut().enumerate() {
            let m = mean(t);
            let b = &self.basis[k * n..(k + 1) * n];
            *t = [0, 1, 2].map(|c| (m + b.iter().zip(&a).map(|(bk, ak)| bk * ak[c]).sum::<f64>()) as f32);
        }
        Ok(())
    }
}

/// Inverse of an `n x n` symmetric positive-definite matrix (Gauss-Jordan with partial
/// pivoting, f64); `None` if singular.
fn invert(m: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut a = m.to_vec();
    let mut inv: Vec<f64> = (0..n * n).map(|k| if k / n == k % n { 1.0 } else { 0.0 }).collect();
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if a[piv * n + col].abs() < 1e-12 {
            return None;
        }
        for k in 0..n {
            a.swap(col * n + k, piv * n + k);
            inv.swap(col * n + k, piv * n + k);
        }
        let d = a[col * n + col];
        for k in 0..n {
            a[col * n + k] /= d;
            inv[col * n + k] /= d;
        }
        for r in (0..n).filter(|&r| r != col) {
            let f = a[r * n + col];
            for k in 0..n {
                a[r * n + k] -= f * a[col * n + k];
                inv[r * n + k] -= f * inv[col * n + k];
            }
        }
    }
    Some(inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;

    fn random(texels: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = Rng::new(seed);
        (0..texels).map(|_| [rng.uniform() * 4.0 - 2.0, rng.uniform() * 4.0 - 2.0, rng.uniform() * 4.0 - 2.0]).collect()
    }

    fn dot(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
        a.iter().zip(b).map(|(x, y)| (0..3).map(|c| x[c] as f64 * y[c] as f64).sum::<f64>()).sum()
    }

    /// Largest absolute difference over texels and channels.
    fn max_diff(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
        a.iter().zip(b).flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).abs())).fold(0.0, f32::max)
    }

    #[test]
    fn grey_keeps_the_channel_mean() {
        let p = ColourProjector::new(16, 8, None).unwrap();
        let mut x = random(128, 1);
        let before = x.clone();
        p.apply(&mut x).unwrap();
        for (a, b) in x.iter().zip(&before) {
            assert!(a[0] == a[1] && a[1] == a[2]);
            assert!((a[0] - (b[0] + b[1] + b[2]) / 3.0).abs() < 1e-5);
        }
    }

    /// Idempotent and symmetric (an orthogonal projection), for every degree.
    #[test]
    fn is_an_orthogonal_projection() {
        for degree in [None, Some(0), Some(1), Some(2), Some(3)] {
            let p = ColourProjector::new(16, 8, degree).unwrap();
            let (x, y) = (random(128, 2), random(128, 3));
            let (mut px, mut py) = (x.clone(), y.clone());
            p.apply(&mut px).unwrap();
            p.apply(&mut py).unwrap();
            let mut ppx = px.clone();
            p.apply(&mut ppx).unwrap();
            let err = max_diff(&ppx, &px);
            assert!(err < 1e-4, "{degree:?}: P(Px) != Px by {err}");
            let (a, b) = (dot(&px, &y), dot(&x, &py));
            assert!((a - b).abs() < 1e-3 * a.abs().max(1.0), "{degree:?}: <Px,y> {a} vs <x,Py> {b}");
            // The projection removes something from random data, and more with a lower degree.
            assert!(dot(&px, &px) < dot(&x, &x));
        }
    }

    /// A colour that varies as a degree-1 harmonic (e.g. bluer towards the zenith) passes
    /// unchanged at degree >= 1 with any per-texel brightness; one texel's colour spike is
    /// spread out.
    #[test]
    fn keeps_a_smooth_colour_and_spreads_a_spike() {
        let (w, h) = (32u32, 16u32);
        let grid = EnvMap::constant(w, h, [0.0; 3]);
        let mut rng = Rng::new(4);
        let mut x = Vec::new();
        for row in 0..h {
            for col in 0..w {
                let z = grid.texel_dir(row, col).z;
                let lum = rng.uniform() * 6.0 - 3.0;
                x.push([lum - 0.3 * z, lum, lum + 0.3 * z]);
            }
        }
        for degree in 1..=3 {
            let mut px = x.clone();
            ColourProjector::new(w, h, Some(degree)).unwrap().apply(&mut px).unwrap();
            let err = max_diff(&px, &x);
            assert!(err < 1e-4, "degree {degree}: smooth colour changed by {err}");
        }
        let mut spike = vec![[1.0f32; 3]; (w * h) as usize];
        spike[5 * w as usize + 7] = [3.0, 1.0, 1.0];
        ColourProjector::new(w, h, Some(2)).unwrap().apply(&mut spike).unwrap();
        let s = spike[5 * w as usize + 7];
        assert!((s[0] + s[1] + s[2] - 5.0).abs() < 1e-4, "brightness kept: {s:?}");
        assert!(s[0] - s[1] < 0.2, "spike's colour spread out: {s:?}");
    }

    #[test]
    fn rejects_bad_sizes() {
        assert!(ColourProjector::new(16, 8, Some(4)).is_err());
        assert!(ColourProjector::new(1, 8, None).is_err());
        let p = ColourProjector::new(16, 8, Some(1)).unwrap();
        assert!(p.apply(&mut [[0.0; 3]; 10]).is_err());
    }
}
