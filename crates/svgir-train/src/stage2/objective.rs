//! Stage 2's assembled per-pixel objective (SPEC 6, Eqn 15), mirroring stage 1's
//! [`crate::losses::objective`]: from the rasteriser's outputs of one view (the PBR pass with its
//! extra channels, and the SH pass) to the loss's per-pixel terms and the gradients handed to the
//! rasteriser's backward. The PBR image divides the composited radiance by the opacity and
//! composites it over the background (SPEC 3, [`crate::composite`]); L1 + D-SSIM on it and on the
//! SH image; edge-aware smoothness of the splatted albedo and roughness (Eqn 17) and, our
//! addition, of the shading normals; the shading-normal / depth-normal loss (Eqn 18).
//! The per-Gaussian terms (L_rc, |dN|^2, env TV) stay in `Stage2::step`.
//!
//! Also here: the extra channels each Gaussian vertex is splatted with ([`extra_features`]), with
//! the shading normal flipped to face the camera, and their adjoint ([`extra_features_backward`]).
//! One module so that the whole sum can be checked against finite differences
//! (`tests/objective_stage2.rs`), not only its parts.

use super::config::Stage2Weights;
use crate::composite::pbr_composite_keep;
use crate::exposure;
use crate::losses::depth_normal::depth_normal_loss;
use crate::losses::l1::l1_loss;
use crate::losses::smoothness::{depth_guide, edge_aware_smoothness_with, EdgeWeights, BACKGROUND_GUIDE};
use crate::losses::CHUNK;
use glam::Vec3;
use rayon::prelude::*;
use svgir_core::par::filled;
use svgir_core::Camera;
use svgir_pbr::{faces, ActivatedMaterials};

/// Extra channels rasterised with the PBR image: albedo (3), roughness (1), shading normal (3).
pub const EXTRA_CHANNELS: usize = 7;
/// Opacity floor when turning composited sums into per-pixel values (SPEC 3).
pub const MIN_OPACITY: f32 = crate::composite::MIN_OPACITY as f32;
/// Depth guide of the normal smoothness: neighbours 1% apart in depth weigh e^-1. A pixel spans
/// ~0.3% of the depth on our 256-px scenes at normal incidence, ~1.5% at 80 degrees.
pub const NORMAL_SMOOTHING_SHARPNESS: f32 = 100.0;

/// +1 or -1 per Gaussian: whether its oriented normal faces the camera at `center`. Splatted
/// normals are flipped to face the camera, as the rasteriser does for geometric normals (SPEC 1),
/// so the normal buffer and Eqn 18 compare like with like.
pub fn facing(normals: &[Vec3], positions: &[Vec3], center: Vec3) -> Vec<f32> {
    normals.iter().zip(positions).map(|(n, p)| if faces(*n, *p, center) { 1.0 } else { -1.0 }).collect()
}

/// Per-vertex extra channels (albedo, roughness, camera-facing shading normal); `facing` per
/// Gaussian ([`facing`]), `act.m` vertices each.
pub fn extra_features(act: &ActivatedMaterials, facing: &[f32]) -> Vec<f32> {
    let mut out = filled(act.roughness.len() * EXTRA_CHANNELS, 0.0f32);
    write_extra_features(act, facing, &mut out, EXTRA_CHANNELS);
    out
}

/// [`extra_features`] into the first [`EXTRA_CHANNELS`] of every `stride` values of `out` (one
/// run per vertex), leaving the rest as they are.
pub(crate) fn write_extra_features(act: &ActivatedMaterials, facing: &[f32], out: &mut [f32], stride: usize) {
    let m = act.m;
    out.par_chunks_exact_mut(stride).enumerate().with_min_len(CHUNK).for_each(|(v, e)| {
        e[..3].copy_from_slice(&act.albedo[3 * v..3 * v + 3]);
        e[3] = act.roughness[v];
        for c in 0..3 {
            e[4 + c] = act.normals[3 * v + c] * facing[v / m];
        }
    });
}

/// Adjoint of [`extra_features`]: accumulates the gradient of the per-vertex extra channels
/// (`v_extra`, as the rasteriser's backward returns it, `channels` per vertex of which the first
/// [`EXTRA_CHANNELS`] are read) into the vertices' albedo, roughness and (unflipped) shading
/// normals.
pub fn extra_features_backward(
    v_extra: &[f32],
    channels: usize,
    m: usize,
    facing: &[f32],
    v_albedo: &mut [f32],
    v_roughness: &mut [f32],
    v_normals: &mut [f32],
) {
    let nv = v_extra.len() / channels;
    assert!(
        v_albedo.len() == 3 * nv && v_roughness.len() == nv && v_normals.len() == 3 * nv,
        "extra_features_backward: {nv} vertices of extra gradients for {} roughness gradients",
        v_roughness.len()
    );
    (v_albedo.par_chunks_exact_mut(3), v_roughness.par_iter_mut(), v_normals.par_chunks_exact_mut(3))
        .into_par_iter()
        .zip(v_extra.par_chunks_exact(channels))
        .enumerate()
        .with_min_len(CHUNK)
        .for_each(|(v, ((a, r, n), e))| {
            for c in 0..3 {
                a[c] += e[c];
                n[c] += facing[v / m] * e[4 + c];
            }
            *r += e[3];
        });
}

/// What the objective reads of one view besides the renders.
pub struct Stage2Target<'a> {
    /// Photo RGB over `background`, `H*W*3`.
    pub rgb: &'a [f32],
    /// The coverage the PBR image is blended by: the photo's alpha (`Coverage::Photo`), or
    /// `None` for the render's own opacity (SPEC 3).
    pub cover: Option<&'a [f32]>,
    /// Background colour (RGB in [0, 1]) the photo and the SH pass are composited over.
    pub background: [f32; 3],
    /// The photo's colour correction learned in stage 1 (`exposure`), applied to both images
    /// before they are compared with the photo, as stage 1 applied it to its render; `None`
    /// for none.
    pub correction: Option<&'a [f32; exposure::PARAMS]>,
}

/// The render outputs the objective depends on.
pub struct Stage2Outputs<'a> {
    /// PBR pass: composited linear radiance `sum w c` (black background), `H*W*3`.
    pub color: &'a [f32],
    /// Rendered opacity per pixel.
    pub alpha: &'a [f32],
    /// Un-normalised `sum w z` as the rasteriser outputs it.
    pub depth: &'a [f32],
    /// `sum w f` of the [`EXTRA_CHANNELS`] per pixel.
    pub extra: &'a [f32],
    /// SH pass, composited over the background, `H*W*3`.
    pub sh_color: &'a [f32],
}

/// Loss value, the PBR image, and `d loss / d output` per pixel.
pub struct Stage2Objective {
    /// The per-pixel part of Eqn 15 (no L_rc, |dN|^2 or env TV).
    pub loss: f32,
    /// The PBR image compared with the photo (with the photo's correction applied).
    pub image: Vec<f32>,
    /// The SH image compared with the photo (with the photo's correction applied).
    pub sh_image: Vec<f32>,
    /// dL / d PBR colour, `H*W*3`.
    pub v_color: Vec<f32>,
    /// dL / d opacity per pixel.
    pub v_alpha: Vec<f32>,
    /// dL / d un-normalised depth per pixel.
    pub v_depth: Vec<f32>,
    /// dL / d extra channels, [`EXTRA_CHANNELS`] per pixel.
    pub v_extra: Vec<f32>,
    /// dL / d SH colour, `H*W*3`.
    pub v_sh_color: Vec<f32>,
}

/// Eqn 15's per-pixel terms and their output gradients. The material buffers are divided by the
/// opacity with the opacity detached, as are the depth guide of the normal smoothness and the
/// opacity factor of Eqn 18 ([`depth_normal_loss`]).
pub fn stage2_objective(
    wts: &Stage2Weights,
    out: &Stage2Outputs,
    target: &Stage2Target,
    cam: &Camera,
) -> Stage2Objective {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let npix = w * h;
    let gt = target.rgb;
    let (cover, bg) = (target.cover, target.background);

    // SPEC 3: the PBR image, then Eqn 15's photometric terms on it and on the SH image (side
    // by side: at 256 x 256 neither fills many cores alone).
    let shape = svgir_metrics::Shape::new(w, h, 3);
    // The photo's correction (stage 1's `exposure`) maps each image's object to the photo's
    // colours; `m` is the image's coverage (the PBR image's blend, the SH image's opacity). Its
    // gradients return through A^T and into the coverage. The correction itself stays as stage 1
    // left it.
    let photo = |x: Vec<f32>, m: &[f32]| {
        let corrected = target.correction.map(|p| exposure::apply(p, &x, m, bg));
        let y = corrected.as_deref().unwrap_or(&x);
        let mut v_y = filled(npix * 3, 0.0f32);
        let l1 = l1_loss(y, gt, wts.l1, &mut v_y);
        let (ssim, g) = svgir_metrics::ssim_with_grad(y, gt, shape).expect("same shape");
        v_y.par_iter_mut().zip(&g).with_min_len(CHUNK).for_each(|(v, g)| *v -= wts.ssim * g);
        let loss = wts.l1 * l1 + wts.ssim * (1.0 - ssim);
        match target.correction {
            Some(p) => {
                let g = exposure::apply_backward(p, &x, m, bg, &v_y);
                (loss, g.v_color, corrected.unwrap_or_default(), Some(g.v_alpha))
            }
            None => (loss, v_y, x, None),
        }
    };
    let (image, composite) = pbr_composite_keep(out.color, out.alpha, cover, bg);
    let ((loss_pbr, v_image, image, v_cover), (loss_sh, v_sh_color, sh_image, v_sh_alpha)) =
        rayon::join(|| photo(image, cover.unwrap_or(out.alpha)), || photo(out.sh_color.to_vec(), out.alpha));
    let mut loss = loss_pbr;
    loss += loss_sh;

    let (v_color, mut v_alpha) = composite.backward(&v_image);
    // The corrections' coverage gradients: the PBR image's only where its own opacity blends it.
    let live_cover = v_cover.filter(|_| cover.is_none());
    for v_m in [live_cover, v_sh_alpha].into_iter().flatten() {
        v_alpha.par_iter_mut().zip(&v_m).with_min_len(CHUNK).for_each(|(v, m)| *v += m);
    }

    // Material buffers (opacity detached in the division) with edge-aware smoothness
    // (Eqn 17) against the photo, and the shading-normal / depth-normal loss (Eqn 18).
    let mut v_extra = filled(npix * EXTRA_CHANNELS, 0.0f32);
    let ex = out.extra;
    let mut alb = filled(npix * 3, 0.0f32);
    let mut rough = filled(npix, 0.0f32);
    let mut nsum = filled(npix * 3, 0.0f32);
    (alb.par_chunks_exact_mut(3), rough.par_iter_mut(), nsum.par_chunks_exact_mut(3))
        .into_par_iter()
        .zip(ex.par_chunks_exact(EXTRA_CHANNELS).zip(out.alpha))
        .with_min_len(CHUNK)
        .for_each(|((a, r, n), (e, &o))| {
            let inv = 1.0 / o.max(MIN_OPACITY);
            for c in 0..3 {
                a[c] = e[c] * inv;
                n[c] = e[4 + c];
            }
            *r = e[3] * inv;
        });
    let mut v_alb = filled(npix * 3, 0.0f32);
    let mut v_rough = filled(npix, 0.0f32);
    let photo_edges = EdgeWeights::new(gt, 3, w, h);
    loss += wts.smooth_albedo * edge_aware_smoothness_with(&alb, 3, &photo_edges, wts.smooth_albedo, &mut v_alb);
    loss +=
        wts.smooth_roughness * edge_aware_smoothness_with(&rough, 1, &photo_edges, wts.smooth_roughness, &mut v_rough);
    let mut v_nrm = filled(npix * 3, 0.0f32);
    if wts.smooth_normal > 0.0 {
        let guide = depth_guide(out.depth, out.alpha, NORMAL_SMOOTHING_SHARPNESS);
        let nrm: Vec<f32> = (0..npix * 3)
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|i| if guide[i / 3] == BACKGROUND_GUIDE { 0.0 } else { nsum[i] / out.alpha[i / 3] })
            .collect();
        let depth_edges = EdgeWeights::new(&guide, 1, w, h);
        loss += wts.smooth_normal * edge_aware_smoothness_with(&nrm, 3, &depth_edges, wts.smooth_normal, &mut v_nrm);
    }
    let (ln, g_n) = depth_normal_loss(out.depth, out.alpha, &nsum, cam);
    loss += wts.normal * ln;
    v_extra.par_chunks_exact_mut(EXTRA_CHANNELS).zip(&mut v_alpha).enumerate().with_min_len(CHUNK).for_each(
        |(p, (ve, va))| {
            let inv = 1.0 / out.alpha[p].max(MIN_OPACITY);
            for c in 0..3 {
                ve[c] = v_alb[3 * p + c] * inv;
                ve[4 + c] = wts.normal * g_n.v_normal[3 * p + c] + v_nrm[3 * p + c] * inv;
            }
            ve[3] = v_rough[p] * inv;
            *va += wts.normal * g_n.v_opacity[p];
        },
    );
    let v_depth: Vec<f32> = g_n.v_depth_sum.par_iter().with_min_len(CHUNK).map(|g| wts.normal * g).collect();
    Stage2Objective { loss, image, sh_image, v_color, v_alpha, v_depth, v_extra, v_sh_color }
}
