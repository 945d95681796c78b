//! svgir-metrics: image-quality metrics as the standard evaluations compute them (SPEC 8).
//!
//! - [`psnr`](mod@psnr): PSNR on \[0,1\] images, optionally over a mask.
//! - [`ssim`](mod@ssim): SSIM, 3DGS/2DGS variant (zero-padded, also the training loss, with its gradient in
//!   [`ssim_backward`]) and TensoIR's `rgb_ssim` (valid filtering, clipped variances).
//! - [`lpips`]: LPIPS v0.1 with VGG16 / AlexNet, weights from safetensors bytes.
//! - [`geometry`]: normal mean angular error, albedo per-channel median scale.
//! - [`ImageMetrics`] / [`evaluate_pair`]: PSNR + SSIM + LPIPS of one rendered view, for `svgir eval`.
//!
//! Kernels are generic over [`Float`] (f32/f64) where a gradient must be checked in f64.
//! No I/O, no printing.

#![warn(missing_docs)]
// The lane kernels (AVX2 / AVX-512) and their helpers are compiled for x86-64 only; on other
// targets the generic kernels run and those helpers go unused. Dead code is still caught by the
// x86-64 build, which CI lints.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_variables, unused_mut))]

pub mod error;
pub mod geometry;
pub mod lpips;
pub mod psnr;
pub mod ssim;
pub mod ssim_backward;

pub use error::{MetricsError, Result};
pub use geometry::{apply_albedo_scale, normal_error_map, AlbedoScale, NormalMae};
#[cfg(feature = "bench")]
pub use lpips::bench_table;
pub use lpips::{Lpips, LpipsDistance, Net};
pub use psnr::{mse, mse_to_psnr, psnr};
pub use ssim::{ssim, ssim_image, Shape, SsimVariant};
pub use ssim_backward::ssim_with_grad;
pub use svgir_core::Float;

use serde::{Deserialize, Serialize};
use svgir_core::Image;

/// The three image metrics of one view (`lpips` is `None` when no LPIPS model was given).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageMetrics {
    /// Peak signal-to-noise ratio in dB (peak 1).
    pub psnr: f64,
    /// Mean SSIM over the map and the channels, in [-1, 1].
    pub ssim: f64,
    /// LPIPS distance (lower is better), `None` without an LPIPS model.
    pub lpips: Option<f64>,
}

impl ImageMetrics {
    /// Mean of each metric over views (LPIPS only if every view has it); `None` for no views.
    pub fn mean(all: &[ImageMetrics]) -> Option<ImageMetrics> {
        if all.is_empty() {
            return None;
        }
        let n = all.len() as f64;
        let lpips = all.iter().map(|m| m.lpips).sum::<Option<f64>>().map(|s| s / n);
        Some(ImageMetrics {
            psnr: all.iter().map(|m| m.psnr).sum::<f64>() / n,
            ssim: all.iter().map(|m| m.ssim).sum::<f64>() / n,
            lpips,
        })
    }
}

/// PSNR / SSIM / LPIPS of `pred` against `gt` (RGB, or RGBA whose alpha is dropped), as SPEC 8
/// evaluates a view: both clamped to \[0,1\]; with `mask` (one GT alpha per pixel) both are first
/// composited on black by it (`rgb * mask`), then every metric runs on the full image.
pub fn evaluate_pair(
    pred: &Image,
    gt: &Image,
    mask: Option<&[f32]>,
    ssim_variant: SsimVariant,
    lpips: Option<&Lpips>,
) -> Result<ImageMetrics> {
    if (pred.width, pred.height) != (gt.width, gt.height) {
        return Err(MetricsError::ShapeMismatch(format!(
            "{}x{} vs {}x{}",
            pred.width, pred.height, gt.width, gt.height
        )));
    }
    let (a, b) = (prepare(pred, mask)?, prepare(gt, mask)?);
    let shape = Shape::new(pred.width as usize, pred.height as usize, 3);
    let lpips = match lpips {
        Some(model) => Some(model.distance(&a, &b)?.total as f64),
        None => None,
    };
    Ok(ImageMetrics {
        psnr: psnr(&a.data, &b.data, 3, None)?,
        ssim: ssim(&a.data, &b.data, shape, ssim_variant)? as f64,
        lpips,
    })
}

/// RGB clamped to [0,1], multiplied by the mask if given.
fn prepare(img: &Image, mask: Option<&[f32]>) -> Result<Image> {
    let c = img.channels as usize;
    if c != 3 && c != 4 {
        return Err(MetricsError::ShapeMismatch(format!("expected RGB or RGBA, got {c} channels")));
    }
    if let Some(m) = mask {
        error::check_eq("mask vs pixel count", m.len(), img.pixel_count())?;
    }
    let mut data = Vec::with_capacity(img.pixel_count() * 3);
    for (i, px) in img.data.chunks_exact(c).enumerate() {
        let w = mask.map_or(1.0, |m| m[i]);
        data.extend(px[..3].iter().map(|&v| v.clamp(0.0, 1.0) * w));
    }
    Ok(Image::from_data(img.width, img.height, 3, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evaluate_pair_composites_and_clamps() {
        let (w, h) = (16u32, 12u32);
        let n = (w * h) as usize;
        let gt = Image::from_data(w, h, 3, (0..n * 3).map(|i| (i % 7) as f32 / 7.0).collect());
        // Prediction: GT plus out-of-range values and junk in the masked-out half.
        let mask: Vec<f32> = (0..n).map(|i| if i % (w as usize) < 8 { 1.0 } else { 0.0 }).collect();
        let mut pred = gt.clone();
        for (i, px) in pred.data.chunks_exact_mut(3).enumerate() {
            if mask[i] == 0.0 {
                px.copy_from_slice(&[0.9, 0.1, 0.5]);
            }
        }
        pred.data[0] = 1.7; // clamps to 1, gt[0] = 0 -> error 1 on one value
        let m = evaluate_pair(&pred, &gt, Some(&mask), SsimVariant::GaussianSplatting, None).unwrap();
        let want_psnr = -10.0 * (1.0 / (n * 3) as f64).log10();
        assert!((m.psnr - want_psnr).abs() < 1e-6, "{} {want_psnr}", m.psnr);
        assert!(m.ssim < 1.0 && m.ssim > 0.9, "{}", m.ssim);
        assert!(m.lpips.is_none());
        let unmasked = evaluate_pair(&pred, &gt, None, SsimVariant::TensoIR, None).unwrap();
        assert!(unmasked.psnr < m.psnr);
        let mean = ImageMetrics::mean(&[m, unmasked]).unwrap();
        assert!((mean.psnr - 0.5 * (m.psnr + unmasked.psnr)).abs() < 1e-9);
        assert!(evaluate_pair(&pred, &Image::new(3, 3, 3), None, SsimVariant::TensoIR, None).is_err());
    }

    #[test]
    fn metrics_serialise() {
        let m = ImageMetrics { psnr: 30.5, ssim: 0.95, lpips: Some(0.05) };
        let s = serde_json::to_string(&m).unwrap();
        assert_eq!(serde_json::from_str::<ImageMetrics>(&s).unwrap(), m);
    }
}
