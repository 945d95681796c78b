//! Stage 1's assembled per-pixel objective (SPEC 2): L1 + D-SSIM on colour, mask and entropy on
//! opacity, depth-normal consistency, and 2DGS depth distortion, with the gradients it hands
//! the rasterizer's backward. One function so that the whole sum can be checked against finite
//! differences (`tests/objective.rs`), not only its parts.

use super::{depth_normal::depth_normal_loss, l1::l1_loss, mask};
use crate::config::LossWeights;
use rayon::prelude::*;
use svgir_core::par::filled;
use svgir_core::Camera;

/// What the objective reads of one view besides the render.
pub struct ObjectiveTarget<'a> {
    /// Photo RGB over the render's background, `H*W*3`.
    pub rgb: &'a [f32],
    /// Photo alpha, `H*W` (1 for photos without a mask).
    pub alpha: &'a [f32],
    /// 9x9-dilated mask (SPEC 2's mask loss).
    pub dilated: &'a [bool],
}

/// The render outputs the objective depends on.
pub struct ObjectiveInput<'a> {
    /// Rendered RGB over the background, `H*W*3`.
    pub color: &'a [f32],
    /// Rendered opacity per pixel.
    pub alpha: &'a [f32],
    /// Un-normalised `sum w z` as the rasterizer outputs it.
    pub depth: &'a [f32],
    /// Composited (unnormalised) world normal, `H*W*3`.
    pub normal: &'a [f32],
    /// 2DGS depth distortion per pixel.
    pub distortion: &'a [f32],
}

/// Loss value, its parts, and `d loss / d output` per pixel.
pub struct Objective {
    /// Total weighted loss.
    pub loss: f32,
    /// Mean absolute colour error (unweighted).
    pub l1: f32,
    /// SSIM of render and photo (unweighted; the loss uses 1 - SSIM).
    pub ssim: f32,
    /// dL / d colour, `H*W*3`.
    pub v_color: Vec<f32>,
    /// dL / d opacity per pixel.
    pub v_alpha: Vec<f32>,
    /// dL / d un-normalised depth per pixel.
    pub v_depth: Vec<f32>,
    /// dL / d normal, `H*W*3`.
    pub v_normal: Vec<f32>,
    /// `None` when the distortion weight is 0 (the rasterizer then skips its output).
    pub v_distortion: Option<Vec<f32>>,
}

/// The weight of SPEC 2's depth-normal term at training progress `t_frac` (it ramps linearly).
pub fn depth_normal_weight(w: &LossWeights, t_frac: f32) -> f32 {
    w.normal_start + w.normal_ramp * t_frac.clamp(0.0, 1.0)
}

/// SPEC 2's loss at training progress `t_frac` in [0, 1] (the depth-normal weight ramps with it).
/// `use_mask` switches the mask and entropy losses on (datasets with a meaningful alpha).
pub fn stage1_objective(
    w: &LossWeights,
    t_frac: f32,
    use_mask: bool,
    out: &ObjectiveInput,
    target: &ObjectiveTarget,
    camera: &Camera,
) -> Objective {
    let (width, height) = (camera.width() as usize, camera.height() as usize);
    let npix = width * height;
    let mut v_color = filled(npix * 3, 0.0f32);
    let l1 = l1_loss(out.color, target.rgb, w.l1, &mut v_color);
    let (ssim, v_ssim) =
        svgir_metrics::ssim_with_grad(out.color, target.rgb, svgir_metrics::Shape::new(width, height, 3))
            .expect("render and target have the same shape");
    // The loss term is weight * (1 - SSIM).
    v_color.par_iter_mut().zip(&v_ssim).with_min_len(super::CHUNK).for_each(|(g, s)| *g -= w.ssim * s);
    let mut loss = w.l1 * l1 + w.ssim * (1.0 - ssim);
    let mut v_alpha = filled(npix, 0.0f32);
    if use_mask {
        loss += w.mask * mask::mask_loss(out.alpha, target.dilated, w.mask, &mut v_alpha);
        loss += w.entropy * mask::entropy_loss(out.alpha, target.alpha, w.entropy, &mut v_alpha);
    }
    let w_dn = depth_normal_weight(w, t_frac);
    let (v_depth, v_normal) = if w_dn == 0.0 {
        // A switched-off term costs nothing (it is the loss phase's second largest).
        (filled(npix, 0.0), filled(3 * npix, 0.0))
    } else {
        let (dn, g_dn) = depth_normal_loss(out.depth, out.alpha, out.normal, camera);
        loss += w_dn * dn;
        for (a, g) in v_alpha.iter_mut().zip(&g_dn.v_opacity) {
            *a += w_dn * g;
        }
        (g_dn.v_depth_sum.iter().map(|g| w_dn * g).collect(), g_dn.v_normal.iter().map(|g| w_dn * g).collect())
    };
    // 2DGS: lambda_dist * mean over pixels, so each pixel's gradient is lambda / npix.
    let v_distortion = (w.distortion > 0.0).then(|| {
        loss += w.distortion * out.distortion.iter().map(|&d| d as f64).sum::<f64>() as f32 / npix as f32;
        vec![w.distortion / npix as f32; npix]
    });
    Objective { loss, l1, ssim, v_color, v_alpha, v_depth, v_normal, v_distortion }
}
