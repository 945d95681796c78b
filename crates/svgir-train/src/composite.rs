//! The PBR image (SPEC 3): the rasteriser composites linear HDR vertex colours into a sum `C`
//! with opacity `O`; the image compared with the sRGB photo is
//! `I = srgb(C / max(O, eps)) * m + bg * (1 - m)`: divide out the coverage, tone-map after
//! compositing, then blend with the background by a coverage `m`. SPEC 3 takes the render's own
//! `m = O`; [`Coverage::Photo`] takes the photo's alpha, as SPEC 8's evaluation composites the
//! prediction (its straight colour under the ground-truth mask), so that training cannot darken a
//! surface by thinning it over a black background, which the evaluation would then divide out.
//!
//! Per pixel and independent, so forward and backward are plain loops over pixels, split into
//! rows of pixels across threads (each pixel's value does not depend on the split); computed in
//! f64 so the same per-pixel functions are the finite-difference oracle. Training's forward keeps
//! each channel's sRGB value and slope (`pbr_composite_keep`), so its backward needs no `powf`;
//! it computes them with an f32 tone curve that vectorises, within 1e-6 of the oracle's.

/// Opacity floor of the division (SPEC 3).
pub const MIN_OPACITY: f64 = 1e-5;

use crate::losses::CHUNK;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svgir_core::par::filled;

use svgir_core::color::{
    linear_to_srgb as srgb, linear_to_srgb_with_grad as srgb_with_grad, linear_to_srgb_with_grad_fast,
};

/// One pixel's image value; `cover`: the photo's alpha ([`Coverage::Photo`]), `None` for the
/// render's own opacity `o` (SPEC 3).
pub fn composite_px(c: [f64; 3], o: f64, cover: Option<f64>, bg: [f32; 3]) -> [f64; 3] {
    let oc = o.max(MIN_OPACITY);
    let m = cover.unwrap_or(o);
    [0, 1, 2].map(|k| srgb(c[k] / oc) * m + bg[k] as f64 * (1.0 - m))
}

/// [`composite_px`] with each channel's tone value and slope `(srgb(x), srgb'(x))`, in libm's
/// f64: the oracle [`composite_px_backward`] reads them from.
fn composite_px_toned(c: [f64; 3], o: f64, cover: Option<f64>, bg: [f32; 3]) -> ([f64; 3], [Tone; 3]) {
    let oc = o.max(MIN_OPACITY);
    let m = cover.unwrap_or(o);
    let tone = [0, 1, 2].map(|k| srgb_with_grad(c[k] / oc));
    ([0, 1, 2].map(|k| tone[k].0 * m + bg[k] as f64 * (1.0 - m)), tone)
}

/// A channel's `(srgb(x), d srgb / dx)` at its straight colour `x = C / max(O, eps)`.
type Tone = (f64, f64);

/// Gradients of one pixel: `(dL/dC, dL/dO)` given `dL/dI`.
pub fn composite_px_backward(c: [f64; 3], o: f64, cover: Option<f64>, bg: [f32; 3], v_i: [f64; 3]) -> ([f64; 3], f64) {
    composite_px_backward_toned(c, o, cover, bg, v_i, &composite_px_toned(c, o, cover, bg).1)
}

/// [`composite_px_backward`] with the forward's tone values and slopes.
fn composite_px_backward_toned(
    c: [f64; 3],
    o: f64,
    cover: Option<f64>,
    bg: [f32; 3],
    v_i: [f64; 3],
    tone: &[Tone; 3],
) -> ([f64; 3], f64) {
    let oc = o.max(MIN_OPACITY);
    let m = cover.unwrap_or(o);
    let mut v_c = [0.0; 3];
    let mut v_o = 0.0;
    for k in 0..3 {
        let (s, ds) = tone[k];
        if cover.is_none() {
            v_o += v_i[k] * (s - bg[k] as f64);
        }
        let v_lin = v_i[k] * m * ds;
        v_c[k] = v_lin / oc;
        if o > MIN_OPACITY {
            v_o -= v_lin * c[k] / (o * o);
        }
    }
    (v_c, v_o)
}

fn px(v: &[f32], p: usize) -> [f64; 3] {
    [v[3 * p] as f64, v[3 * p + 1] as f64, v[3 * p + 2] as f64]
}

/// Which coverage blends the PBR image with the background in training.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Coverage {
    /// SPEC 3: the render's own opacity.
    #[default]
    Render,
    /// The photo's alpha where the view has one (SPEC 8's evaluation composites so).
    Photo,
}

fn cover_of(cover: Option<&[f32]>, p: usize) -> Option<f64> {
    cover.map(|c| c[p] as f64)
}

/// The whole image (RGB, 3 per pixel); `cover`: one alpha per pixel, or `None` for the render's.
pub fn pbr_composite(color: &[f32], alpha: &[f32], cover: Option<&[f32]>, bg: [f32; 3]) -> Vec<f32> {
    let mut image = filled(alpha.len() * 3, 0.0f32);
    image.par_chunks_mut(3 * CHUNK).enumerate().for_each(|(k, out)| {
        for (i, o) in out.chunks_exact_mut(3).enumerate() {
            let p = k * CHUNK + i;
            let v = composite_px(px(color, p), alpha[p] as f64, cover_of(cover, p), bg);
            o.iter_mut().zip(v).for_each(|(o, v)| *o = v as f32);
        }
    });
    image
}

/// [`pbr_composite`], keeping each channel's tone value and slope for its backward
/// ([`PbrComposite::backward`]), so that the backward needs no `powf`. The tone curve runs in
/// f32 ([`linear_to_srgb_with_grad_fast`], within 1e-6 of libm's relative) over blocks of
/// channels, a loop that vectorises: libm's f64 `powf` was most of the composite's time. The
/// rest is [`composite_px`]'s f64 arithmetic.
pub fn pbr_composite_keep<'a>(
    color: &'a [f32],
    alpha: &'a [f32],
    cover: Option<&'a [f32]>,
    bg: [f32; 3],
) -> (Vec<f32>, PbrComposite<'a>) {
    const BLOCK: usize = 256;
    let mut image = filled(alpha.len() * 3, 0.0f32);
    let mut tone = filled(alpha.len() * 3, (0.0, 0.0));
    image.par_chunks_mut(3 * CHUNK).zip(tone.par_chunks_mut(3 * CHUNK)).enumerate().for_each(|(k, (out, tn))| {
        for (b, (out, tn)) in out.chunks_mut(3 * BLOCK).zip(tn.chunks_mut(3 * BLOCK)).enumerate() {
            let p0 = k * CHUNK + b * BLOCK;
            let n = out.len();
            // The straight colours `C / max(O, eps)` (SPEC 3), then their tone values and slopes.
            let mut x = [0.0f32; 3 * BLOCK];
            for (j, x) in x[..n].iter_mut().enumerate() {
                let p = p0 + j / 3;
                *x = (color[3 * p0 + j] as f64 / (alpha[p] as f64).max(MIN_OPACITY)) as f32;
            }
            let (mut tv, mut tg) = ([0.0f32; 3 * BLOCK], [0.0f32; 3 * BLOCK]);
            for j in 0..n {
                (tv[j], tg[j]) = linear_to_srgb_with_grad_fast(x[j]);
            }
            for (i, (o, t)) in out.chunks_exact_mut(3).zip(tn.chunks_exact_mut(3)).enumerate() {
                let p = p0 + i;
                let m = cover.map_or(alpha[p], |c| c[p]) as f64;
                for c in 0..3 {
                    let (v, g) = (tv[3 * i + c] as f64, tg[3 * i + c] as f64);
                    o[c] = (v * m + bg[c] as f64 * (1.0 - m)) as f32;
                    t[c] = (v, g);
                }
            }
        }
    });
    (image, PbrComposite { color, alpha, cover, bg, tone })
}

/// A composited image's inputs and tone values, for its backward.
pub struct PbrComposite<'a> {
    color: &'a [f32],
    alpha: &'a [f32],
    cover: Option<&'a [f32]>,
    bg: [f32; 3],
    tone: Vec<Tone>,
}

impl PbrComposite<'_> {
    /// `(dL/dC, dL/dO)` for the whole image, the bits of [`pbr_composite_backward`].
    pub fn backward(&self, v_image: &[f32]) -> (Vec<f32>, Vec<f32>) {
        composite_backward(self.color, self.alpha, self.cover, self.bg, v_image, Some(&self.tone))
    }
}

/// `(dL/dC, dL/dO)` for the whole image.
pub fn pbr_composite_backward(
    color: &[f32],
    alpha: &[f32],
    cover: Option<&[f32]>,
    bg: [f32; 3],
    v_image: &[f32],
) -> (Vec<f32>, Vec<f32>) {
    composite_backward(color, alpha, cover, bg, v_image, None)
}

fn composite_backward(
    color: &[f32],
    alpha: &[f32],
    cover: Option<&[f32]>,
    bg: [f32; 3],
    v_image: &[f32],
    tone: Option<&[Tone]>,
) -> (Vec<f32>, Vec<f32>) {
    let mut v_color = filled(color.len(), 0.0);
    let mut v_alpha = filled(alpha.len(), 0.0);
    v_color.par_chunks_mut(3 * CHUNK).zip(v_alpha.par_chunks_mut(CHUNK)).enumerate().for_each(|(k, (vcs, vos))| {
        for (i, (vc_out, vo_out)) in vcs.chunks_exact_mut(3).zip(vos.iter_mut()).enumerate() {
            let p = k * CHUNK + i;
            let (c, o, cv) = (px(color, p), alpha[p] as f64, cover_of(cover, p));
            let v_i = px(v_image, p);
            let (vc, vo) = match tone {
                Some(t) => composite_px_backward_toned(c, o, cv, bg, v_i, &[t[3 * p], t[3 * p + 1], t[3 * p + 2]]),
                None => composite_px_backward(c, o, cv, bg, v_i),
            };
            vc_out.iter_mut().zip(vc).for_each(|(o, v)| *o = v as f32);
            *vo_out = vo as f32;
        }
    });
    (v_color, v_alpha)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;

    #[test]
    fn gradients_match_finite_differences_in_f64() {
        let mut rng = Rng::new(11);
        let bg = [0.2, 0.7, 0.4];
        for case in 0..200 {
            // Coverage from tiny to full, radiance on both sides of the sRGB knee.
            let o = if case % 10 == 0 { 1.0 } else { 0.001 + 0.999 * rng.uniform_f64() };
            // Away from the clamp at 0, where a central difference straddles the kink.
            let c = [0, 1, 2].map(|_| o * (1e-4 + 2.0 * rng.uniform_f64().powi(3)));
            let v_i = [0, 1, 2].map(|_| rng.normal() as f64);
            // Every third case blends by a photo's alpha instead of the render's opacity.
            let cover = (case % 3 == 1).then(|| rng.uniform_f64());
            let loss =
                |c: [f64; 3], o: f64| composite_px(c, o, cover, bg).iter().zip(&v_i).map(|(a, b)| a * b).sum::<f64>();
            let (vc, vo) = composite_px_backward(c, o, cover, bg, v_i);
            let h = 1e-7;
            for k in 0..3 {
                let (mut cp, mut cm) = (c, c);
                cp[k] += h;
                cm[k] -= h;
                let fd = (loss(cp, o) - loss(cm, o)) / (2.0 * h);
                assert!((fd - vc[k]).abs() < 1e-5 * fd.abs().max(1.0), "case {case} C[{k}]: {fd} vs {}", vc[k]);
            }
            if o < 1.0 - 1e-6 {
                let fd = (loss(c, o + h) - loss(c, o - h)) / (2.0 * h);
                assert!((fd - vo).abs() < 1e-5 * fd.abs().max(1.0), "case {case} O: {fd} vs {vo}");
            }
        }
    }

    #[test]
    fn kept_tone_agrees_with_the_plain_image_and_backward() {
        let mut rng = Rng::new(3);
        let n = 3 * CHUNK + 17;
        let alpha: Vec<f32> = (0..n).map(|p| if p % 7 == 0 { 0.0 } else { rng.uniform() }).collect();
        let color: Vec<f32> = (0..3 * n).map(|i| alpha[i / 3] * 2.0 * rng.uniform().powi(3)).collect();
        let v_image: Vec<f32> = (0..3 * n).map(|_| rng.normal()).collect();
        let cover: Vec<f32> = (0..n).map(|_| rng.uniform()).collect();
        let bg = [0.1, 0.5, 0.9];
        // The f32 tone curve is within 1e-6 of libm's, relative; the rest is the same f64. The
        // opacity gradient sums terms of both signs, which can cancel: its errors are measured
        // against the gradients' RMS where that is larger than the value.
        let close = |a: &[f32], b: &[f32], tol: f32, what: &str| {
            let rms = (b.iter().map(|y| y * y).sum::<f32>() / b.len() as f32).sqrt();
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                assert!((x - y).abs() <= tol * y.abs().max(rms), "{what}[{i}]: {x} vs {y}");
            }
        };
        for cv in [None, Some(&cover[..])] {
            let (image, kept) = pbr_composite_keep(&color, &alpha, cv, bg);
            let plain = pbr_composite(&color, &alpha, cv, bg);
            let (vc, vo) = kept.backward(&v_image);
            let (wc, wo) = pbr_composite_backward(&color, &alpha, cv, bg, &v_image);
            close(&image, &plain, 2e-6, "image");
            close(&vc, &wc, 2e-6, "dL/dC");
            close(&vo, &wo, 2e-6, "dL/dO");
            // Empty pixels show exactly the background in both.
            assert!(alpha.iter().zip(image.chunks(3)).all(|(&a, px)| a > 0.0 || cv.is_some() || px == bg));
        }
    }

    #[test]
    fn empty_pixels_show_the_background_and_opaque_ones_the_tone_mapped_colour() {
        let img = pbr_composite(&[0.0, 0.0, 0.0, 0.18, 0.18, 0.18], &[0.0, 1.0], None, [0.1, 0.2, 0.3]);
        assert_eq!(&img[..3], &[0.1, 0.2, 0.3]);
        assert!((img[3] - svgir_core::color::linear_to_srgb(0.18)).abs() < 1e-6);
    }

    #[test]
    fn photo_coverage_ignores_how_thin_the_render_is() {
        // The same straight colour at opacity 0.3 and 1: SPEC 3's image darkens the thin one over
        // black, the photo's coverage does not, and its opacity gradient is only the division's.
        let black = [0.0; 3];
        let thin = pbr_composite(&[0.054, 0.054, 0.054], &[0.3], None, black);
        let full = pbr_composite(&[0.18, 0.18, 0.18], &[1.0], None, black);
        assert!(thin[0] < 0.5 * full[0]);
        let cover = [1.0];
        let thin = pbr_composite(&[0.054, 0.054, 0.054], &[0.3], Some(&cover), black);
        assert!((thin[0] - full[0]).abs() < 1e-5, "{} vs {}", thin[0], full[0]);
        // Scaling C and O together leaves the image, so the gradients are orthogonal to (C, O).
        let (vc, vo) = pbr_composite_backward(&[0.054; 3], &[0.3], Some(&cover), black, &[1.0; 3]);
        let along = vc.iter().map(|g| g * 0.054).sum::<f32>() + vo[0] * 0.3;
        assert!(along.abs() < 1e-5, "{along}");
    }
}
