//! Per-photo affine colour correction for captures whose photos differ in exposure or white
//! balance (phones): the loss compares the corrected render with photo `i` instead of the render,
//! so the Gaussians learn one consistent radiance and each photo's deviation goes into its own
//! 3x3 matrix and offset (12 numbers, starting at the identity). Test views have no correction.
//!
//! The correction acts on the object, not on the background it is composited over: a render
//! `c = f + bg (1 - a)` (premultiplied colour `f`, opacity `a`) becomes `A f + b a + bg (1 - a)`.
//! A masked photo shows the background colour itself where the object is not, so a correction
//! applied to the whole composite would be pulled back to the identity by every background pixel.
//! Where the render is opaque the two forms agree.
//!
//! Forward is per pixel. Backward returns `v_c = A^T v_out`, `v_a = v_out . (A bg + b - bg)` and
//! the parameter gradient summed over pixels; it saves nothing. Each photo has its own Adam
//! state, so a photo's correction moves only on the iterations that see it. Stage 2 applies each
//! photo's learned correction unchanged (`stage2::objective`) to its PBR and SH images.

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

/// The object's part of composited pixel `px` of opacity `a` over `bg`: `px - bg (1 - a)`.
fn object<F: Float>(px: &[F], a: F, bg: [F; 3]) -> [F; 3] {
    [0, 1, 2].map(|c| px[c] - bg[c] * (F::ONE - a))
}

/// Applies `p` to the object in interleaved RGB `color`, composited with opacity `alpha` (one
/// per pixel) over `bg`.
pub fn apply<F: Float>(p: &[F; PARAMS], color: &[F], alpha: &[F], bg: [F; 3]) -> Vec<F> {
    let mut out = Vec::with_capacity(color.len());
    for (px, &a) in color.chunks_exact(3).zip(alpha) {
        let f = object(px, a, bg);
        for c in 0..3 {
            out.push(p[3 * c] * f[0] + p[3 * c + 1] * f[1] + p[3 * c + 2] * f[2] + p[9 + c] * a + bg[c] * (F::ONE - a));
        }
    }
    out
}

/// The gradients of [`apply`] from `v_out`.
pub struct CorrectionGrads<F> {
    /// Per colour entry.
    pub v_color: Vec<F>,
    /// Per pixel.
    pub v_alpha: Vec<F>,
    /// Of the 12 parameters, summed over the pixels.
    pub v_params: [F; PARAMS],
}

/// Gradients of [`apply`] (same inputs) from `v_out`.
pub fn apply_backward<F: Float>(
    p: &[F; PARAMS],
    color: &[F],
    alpha: &[F],
    bg: [F; 3],
    v_out: &[F],
) -> CorrectionGrads<F> {
    let mut v_color = Vec::with_capacity(color.len());
    let mut v_alpha = Vec::with_capacity(alpha.len());
    let mut v_p = [F::ZERO; PARAMS];
    // d out_c / d a = (A bg)_c + b_c - bg_c, the same for every pixel.
    let da: [F; 3] =
        [0, 1, 2].map(|c| p[3 * c] * bg[0] + p[3 * c + 1] * bg[1] + p[3 * c + 2] * bg[2] + p[9 + c] - bg[c]);
    for ((px, &a), g) in color.chunks_exact(3).zip(alpha).zip(v_out.chunks_exact(3)) {
        for k in 0..3 {
            v_color.push(p[k] * g[0] + p[3 + k] * g[1] + p[6 + k] * g[2]);
        }
        v_alpha.push(g[0] * da[0] + g[1] * da[1] + g[2] * da[2]);
        let f = object(px, a, bg);
        for c in 0..3 {
            for k in 0..3 {
                v_p[3 * c + k] += g[c] * f[k];
            }
            v_p[9 + c] += g[c] * a;
        }
    }
    CorrectionGrads { v_color, v_alpha, v_params: v_p }
}

/// The correction that best maps `color` (composited with opacity `alpha` over `bg`) to `photo`
/// over the pixels where `region` holds, by least squares: [`apply`]'s form is linear in its
/// 12 numbers, one 4x4 normal system per output channel (features: the object's colour and the
/// opacity), solved in f64. A small ridge towards the identity keeps a flat or empty region
/// solvable. Held-out photos of a capture with varying exposure are scored through it (fitted on
/// one half, measured on the other, as NeRF-W's protocol does).
pub fn fit(color: &[f32], alpha: &[f32], bg: [f32; 3], photo: &[f32], region: impl Fn(usize) -> bool) -> [f32; PARAMS] {
    const RIDGE: f64 = 1e-6;
    let mut ata = glam::DMat4::ZERO;
    let mut atb = [glam::DVec4::ZERO; 3];
    let mut count = 0.0f64;
    for (i, ((px, &a), y)) in color.chunks_exact(3).zip(alpha).zip(photo.chunks_exact(3)).enumerate() {
        if !region(i) {
            continue;
        }
        let f = object(px, a, bg).map(f64::from);
        let x = glam::DVec4::new(f[0], f[1], f[2], a as f64);
        ata += glam::DMat4::from_cols(x * x.x, x * x.y, x * x.z, x * x.w);
        for c in 0..3 {
            // The target of `A f + b a`: the photo less the background's share.
            atb[c] += x * (y[c] as f64 - bg[c] as f64 * (1.0 - a as f64));
        }
        count += 1.0;
    }
    let ridge = RIDGE * count.max(1.0);
    let inv = (ata + glam::DMat4::from_diagonal(glam::DVec4::splat(ridge))).inverse();
    let mut p = [0.0f32; PARAMS];
    for c in 0..3 {
        // Ridge towards the identity row (A's row c = e_c, b_c = 0).
        let mut prior = glam::DVec4::ZERO;
        prior[c] = ridge;
        let row = inv * (atb[c] + prior);
        for k in 0..3 {
            p[3 * c + k] = row[k] as f32;
        }
        p[9 + c] = row.w as f32;
    }
    p
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

    /// f64 finite differences of `sum(w * apply(p, c, a))` against every gradient.
    #[test]
    fn backward_matches_finite_differences() {
        let mut rng = Rng::new(3);
        let n = 5;
        let color: Vec<f64> = (0..3 * n).map(|_| rng.uniform() as f64).collect();
        let alpha: Vec<f64> = (0..n).map(|_| rng.uniform() as f64).collect();
        let bg = [0.3, 0.8, 0.1];
        let w: Vec<f64> = (0..3 * n).map(|_| rng.normal() as f64).collect();
        let mut p: [f64; PARAMS] = identity();
        for v in p.iter_mut() {
            *v += 0.2 * rng.normal() as f64;
        }
        let loss = |p: &[f64; PARAMS], c: &[f64], a: &[f64]| {
            apply(p, c, a, bg).iter().zip(&w).map(|(x, y)| x * y).sum::<f64>()
        };
        let g = apply_backward(&p, &color, &alpha, bg, &w);
        let h = 1e-6;
        let fd = |f: &dyn Fn(f64) -> f64| (f(h) - f(-h)) / (2.0 * h);
        let shifted = |v: &[f64], i: usize, d: f64| {
            let mut v = v.to_vec();
            v[i] += d;
            v
        };
        for k in 0..PARAMS {
            let d = fd(&|d| {
                let mut q = p;
                q[k] += d;
                loss(&q, &color, &alpha)
            });
            assert!((d - g.v_params[k]).abs() < 1e-7, "param {k}: fd {d} vs {}", g.v_params[k]);
        }
        for i in 0..3 * n {
            let d = fd(&|d| loss(&p, &shifted(&color, i, d), &alpha));
            assert!((d - g.v_color[i]).abs() < 1e-7, "colour {i}: fd {d} vs {}", g.v_color[i]);
        }
        for i in 0..n {
            let d = fd(&|d| loss(&p, &color, &shifted(&alpha, i, d)));
            assert!((d - g.v_alpha[i]).abs() < 1e-7, "alpha {i}: fd {d} vs {}", g.v_alpha[i]);
        }
    }

    /// The fit recovers a known correction from the left half of an image (object and background
    /// pixels, soft edges), and on an empty region stays the identity.
    #[test]
    fn fit_recovers_a_known_correction() {
        let mut rng = Rng::new(9);
        let (w, h) = (16, 8);
        let bg = [0.3f32, 0.6, 0.2];
        let alpha: Vec<f32> = (0..w * h).map(|i| [1.0, 0.0, 0.4, 1.0][i % 4]).collect();
        let color: Vec<f32> = (0..w * h * 3)
            .map(|i| {
                let a = alpha[i / 3];
                rng.uniform() * a + bg[i % 3] * (1.0 - a)
            })
            .collect();
        let truth = [1.2, 0.1, -0.05, 0.02, 0.8, 0.07, -0.03, 0.05, 0.95, 0.04, -0.02, 0.06];
        let photo = apply(&truth, &color, &alpha, bg);
        let p = fit(&color, &alpha, bg, &photo, |i| i % w < w / 2);
        let err = p.iter().zip(&truth).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(err < 1e-4, "fitted {p:?}, true {truth:?}");
        let empty = fit(&color, &alpha, bg, &photo, |_| false);
        assert!(empty.iter().zip(&identity::<f32>()).all(|(a, b)| (a - b).abs() < 1e-6), "{empty:?}");
    }

    /// The identity changes nothing; the background (opacity 0) is never corrected; a gain of the
    /// object is learned even where most pixels are background, as in a masked photo.
    #[test]
    fn identity_is_a_no_op_the_background_stays_and_a_gain_is_learned() {
        let bg = [0.25f32, 0.5, 0.75];
        // Two object pixels, then four of background.
        let alpha = [1.0f32, 0.6, 0.0, 0.0, 0.0, 0.0];
        let straight = [0.1f32, 0.5, 0.9, 0.3, 0.2, 0.7];
        let composite = |s: &[f32]| -> Vec<f32> {
            (0..alpha.len() * 3)
                .map(|i| {
                    let (a, c) = (alpha[i / 3], i % 3);
                    s.get(i).copied().unwrap_or(0.0) * a + bg[c] * (1.0 - a)
                })
                .collect()
        };
        let c = composite(&straight);
        let out = apply(&identity(), &c, &alpha, bg);
        assert!(out.iter().zip(&c).all(|(a, b)| (a - b).abs() < 1e-6), "{out:?} vs {c:?}");
        let mut p = identity();
        p[0] = 2.0;
        p[10] = 0.3;
        let out = apply(&p, &c, &alpha, bg);
        assert!(out[6..].iter().zip(&c[6..]).all(|(a, b)| (a - b).abs() < 1e-6), "background moved: {out:?}");
        // Photo = the object at 0.8 x: the correction learns the gain from the L2 gradient.
        let mut ex = ExposureCorrection::new(1);
        let target = composite(&straight.map(|x| 0.8 * x));
        for _ in 0..3000 {
            let out = apply(&ex.params[0], &c, &alpha, bg);
            let v_out: Vec<f32> = out.iter().zip(&target).map(|(a, b)| 2.0 * (a - b)).collect();
            let g = apply_backward(&ex.params[0], &c, &alpha, bg, &v_out);
            ex.step(0, &g.v_params);
        }
        let out = apply(&ex.params[0], &c, &alpha, bg);
        let err = out.iter().zip(&target).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(err < 5e-3, "max error {err}");
    }
}
