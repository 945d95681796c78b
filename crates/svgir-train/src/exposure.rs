//! Per-photo affine colour correction for captures whose photos differ in exposure or white
//! balance (phones): the loss compares `A_i c + b_i` with photo `i` instead of the render `c`,
//! so the Gaussians learn one consistent radiance and each photo's deviation goes into its own
//! 3x3 matrix and offset (12 numbers, starting at the identity). Test views have no correction.
//!
//! Forward is per pixel: `out_c = sum_k A[c][k] in_k + b_c`. Backward returns `v_in = A^T v_out`
//! and the parameter gradient summed over pixels; it saves nothing. Each photo has its own Adam
//! state, so a photo's correction moves only on the iterations that see it.

use crate::adam::AdamGroup;
use svgir_core::Float;

/// Parameters per photo: a row-major 3x3 matrix, then the offset.
pub const PARAMS: usize = 12;

/// The identity correction.
pub fn identity<F: Float>() -> [F; PARAMS] {
    let mut p = [F::ZERO; PARAMS];
    p[0] = F::ONE;
    p[4] = F::ONE;
    p[8] = F::ONE;
    p
}

/// Applies `p` to interleaved RGB `color`.
pub fn apply<F: Float>(p: &[F; PARAMS], color: &[F]) -> Vec<F> {
    let mut out = Vec::with_capacity(color.len());
    for px in color.chunks_exact(3) {
        for c in 0..3 {
            out.push(p[3 * c] * px[0] + p[3 * c + 1] * px[1] + p[3 * c + 2] * px[2] + p[9 + c]);
        }
    }
    out
}

/// Gradients of [`apply`]: `(v_color, v_params)` from `v_out`.
pub fn apply_backward<F: Float>(p: &[F; PARAMS], color: &[F], v_out: &[F]) -> (Vec<F>, [F; PARAMS]) {
    let mut v_color = Vec::with_capacity(color.len());
    let mut v_p = [F::ZERO; PARAMS];
    for (px, g) in color.chunks_exact(3).zip(v_out.chunks_exact(3)) {
        for k in 0..3 {
            v_color.push(p[k] * g[0] + p[3 + k] * g[1] + p[6 + k] * g[2]);
        }
        for c in 0..3 {
            for k in 0..3 {
                v_p[3 * c + k] += g[c] * px[k];
            }
            v_p[9 + c] += g[c];
        }
    }
    (v_color, v_p)
}

/// Every training photo's correction and its optimiser state.
#[derive(Clone, Debug)]
pub struct ExposureCorrection {
    /// Per photo: a row-major 3x3 matrix A then the offset b.
    pub params: Vec<[f32; PARAMS]>,
    /// One Adam group per photo, so a correction moves only when its photo is seen.
    pub adam: Vec<AdamGroup>,
}

/// Learning rate of the corrections (a photo seen 350 times can move its gain by ~0.3).
pub const LR: f32 = 1e-3;

impl ExposureCorrection {
    /// Identity corrections with fresh Adam state for `photos` training photos.
    pub fn new(photos: usize) -> Self {
        Self {
            params: vec![identity(); photos],
            adam: (0..photos).map(|_| AdamGroup::new("exposure", LR, PARAMS, 1)).collect(),
        }
    }

    /// One Adam step of photo `i`'s correction.
    pub fn step(&mut self, i: usize, grad: &[f32; PARAMS]) {
        self.adam[i].step(&mut self.params[i], grad);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;

    /// f64 finite differences of `sum(w * apply(p, c))` against both gradients.
    #[test]
    fn backward_matches_finite_differences() {
        let mut rng = Rng::new(3);
        let n = 5 * 3;
        let color: Vec<f64> = (0..n).map(|_| rng.uniform() as f64).collect();
        let w: Vec<f64> = (0..n).map(|_| rng.normal() as f64).collect();
        let mut p: [f64; PARAMS] = identity();
        for v in p.iter_mut() {
            *v += 0.2 * rng.normal() as f64;
        }
        let loss = |p: &[f64; PARAMS], c: &[f64]| apply(p, c).iter().zip(&w).map(|(a, b)| a * b).sum::<f64>();
        let (v_color, v_p) = apply_backward(&p, &color, &w);
        let h = 1e-6;
        for k in 0..PARAMS {
            let (mut a, mut b) = (p, p);
            a[k] += h;
            b[k] -= h;
            let fd = (loss(&a, &color) - loss(&b, &color)) / (2.0 * h);
            assert!((fd - v_p[k]).abs() < 1e-7, "param {k}: fd {fd} vs {}", v_p[k]);
        }
        for i in 0..n {
            let (mut a, mut b) = (color.clone(), color.clone());
            a[i] += h;
            b[i] -= h;
            let fd = (loss(&p, &a) - loss(&p, &b)) / (2.0 * h);
            assert!((fd - v_color[i]).abs() < 1e-7, "colour {i}: fd {fd} vs {}", v_color[i]);
        }
    }

    #[test]
    fn identity_is_a_no_op_and_a_gain_is_learned() {
        let c = vec![0.1f32, 0.5, 0.9, 0.3, 0.2, 0.7];
        assert_eq!(apply(&identity(), &c), c);
        // Photo = 0.8 x render: the correction learns the gain from the L2 gradient.
        let mut ex = ExposureCorrection::new(1);
        let target: Vec<f32> = c.iter().map(|x| 0.8 * x).collect();
        for _ in 0..3000 {
            let out = apply(&ex.params[0], &c);
            let v_out: Vec<f32> = out.iter().zip(&target).map(|(a, b)| 2.0 * (a - b)).collect();
            let (_, g) = apply_backward(&ex.params[0], &c, &v_out);
            ex.step(0, &g);
        }
        let out = apply(&ex.params[0], &c);
        let err = out.iter().zip(&target).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(err < 5e-3, "max error {err}");
    }
}
