//! Dense brute-force renderer: every visible Gaussian against every pixel, hits sorted per pixel
//! by the same (depth, id) key, composited with the plain formulas of SPEC 1 (distortion as the
//! explicit double sum `sum_{j<i} w_i w_j (m_i - m_j)^2`, not the running sum). Slow and obvious:
//! it is the oracle for the tiled forward and, in `f64`, the function the gradient tests
//! differentiate numerically. Shares only the per-Gaussian preprocess and the per-pixel ray-splat
//! evaluation with the fast path. Sequential; nothing is saved. [`layer_weights`] lists the same
//! composite's per-Gaussian weights at chosen pixels, for statistics of how stacked surfaces are.

use crate::forward::{background_at, distortion_depth, hit_weights, FeatView};
use crate::interp::MAX_VERTICES;
use crate::preprocess::{preprocess, Cam, Splat};
use crate::splat::{intersect, Hit};
use crate::tiles::sort_key;
use crate::{GaussianParams, RasterConfig, RenderInputOf, RenderOutputOf};
use svgir_core::Float;

/// Renders `input` densely (tiny images only: O(pixels x Gaussians)).
pub fn render_reference<F: Float, P: GaussianParams<F> + ?Sized>(
    input: &RenderInputOf<F, P>,
    cfg: &RasterConfig,
) -> RenderOutputOf<F> {
    let cam = Cam::<F>::new(input.camera);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let npx = w * h;
    let (splats, sh_colors) = preprocess(input.surfels, &cam, &input.colors, cfg);
    let cf = FeatView::colors(&input.colors, &sh_colors);
    let ef = FeatView::extra(&input.extra);
    let ce = ef.channels;
    let near = F::from_f32(cfg.near);
    let far = F::from_f32(cfg.far);
    let n = splats.len();
    let mut out = RenderOutputOf::<F> {
        width: w as u32,
        height: h as u32,
        color: vec![F::ZERO; npx * 3],
        alpha: vec![F::ZERO; npx],
        depth: vec![F::ZERO; npx],
        median_depth: vec![F::ZERO; npx],
        normal: vec![F::ZERO; npx * 3],
        distortion: vec![F::ZERO; npx],
        extra: vec![F::ZERO; npx * ce],
        extra_channels: ce,
        accum_weight: vec![F::ZERO; n],
        max_radius: splats.iter().map(|s| if s.visible() { s.radius } else { 0.0 }).collect(),
    };
    let mut hits = Vec::new();
    let mut wv = [F::ZERO; MAX_VERTICES];
    let mut col = [F::ZERO; 3];
    let mut ext = vec![F::ZERO; ce];
    // (w, m) of the Gaussians composited so far at this pixel.
    let mut composited: Vec<(F, F)> = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let (xf, yf) = (F::c(x as f64 + 0.5), F::c(y as f64 + 0.5));
            pixel_hits(&splats, xf, yf, near, &mut hits);
            composited.clear();
            let mut t = F::ONE;
            for &(_, g, hit) in &hits {
                let next = t * (F::ONE - hit.alpha);
                if next < F::from_f32(cfg.t_stop) {
                    break;
                }
                let wgt = hit.alpha * t;
                hit_weights(cf.vertices, hit.u, hit.v, &mut wv);
                cf.eval(g, &wv, &mut col);
                let s = &splats[g];
                for ch in 0..3 {
                    out.color[p * 3 + ch] += wgt * col[ch];
                    out.normal[p * 3 + ch] += wgt * s.normal[ch];
                }
                if ce > 0 {
                    hit_weights(ef.vertices, hit.u, hit.v, &mut wv);
                    ef.eval(g, &wv, &mut ext);
                    for ch in 0..ce {
                        out.extra[p * ce + ch] += wgt * ext[ch];
                    }
                }
                out.depth[p] += wgt * hit.z;
                if t > F::c(0.5) {
                    out.median_depth[p] = hit.z;
                }
                out.accum_weight[g] += wgt;
                composited.push((wgt, distortion_depth(hit.z, near, far)));
                t = next;
            }
            let mut dist = F::ZERO;
            for i in 0..composited.len() {
                for j in 0..i {
                    let (wi, mi) = composited[i];
                    let (wj, mj) = composited[j];
                    dist += wi * wj * (mi - mj) * (mi - mj);
                }
            }
            out.distortion[p] = dist;
            out.alpha[p] = F::ONE - t;
            let b = background_at(&input.background, p);
            for ch in 0..3 {
                out.color[p * 3 + ch] += t * b[ch];
            }
        }
    }
    out
}

/// Every visible splat's hit at pixel position (`x`, `y`), sorted by the (depth, id) key.
fn pixel_hits<F: Float>(splats: &[Splat<F>], x: F, y: F, near: F, hits: &mut Vec<(u64, usize, Hit<F>)>) {
    hits.clear();
    for (g, s) in splats.iter().enumerate() {
        if !s.visible() {
            continue;
        }
        if let Some(hit) = intersect(&s.h, s.center, s.opacity, x, y, near) {
            hits.push((sort_key(s.depth, g as u32), g, hit));
        }
    }
    hits.sort_by_key(|h| h.0);
}

/// One Gaussian's share of a pixel's composite.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerHit<F> {
    /// Index of the Gaussian.
    pub gaussian: u32,
    /// Its weight `alpha_i T_i` (SPEC 1).
    pub weight: F,
    /// Depth of its ray-splat intersection (camera z).
    pub depth: F,
}

/// The composite's weights at each of `pixels` (column, row), in the composite's (centre depth,
/// id) order, cut where
/// [`render_reference`] stops: their sum is that pixel's alpha. O(pixels x Gaussians).
pub fn layer_weights<F: Float, P: GaussianParams<F> + ?Sized>(
    input: &RenderInputOf<F, P>,
    cfg: &RasterConfig,
    pixels: &[(u32, u32)],
) -> Vec<Vec<LayerHit<F>>> {
    let cam = Cam::<F>::new(input.camera);
    let (splats, _) = preprocess(input.surfels, &cam, &input.colors, cfg);
    let near = F::from_f32(cfg.near);
    let mut hits = Vec::new();
    pixels
        .iter()
        .map(|&(x, y)| {
            pixel_hits(&splats, F::c(x as f64 + 0.5), F::c(y as f64 + 0.5), near, &mut hits);
            let mut t = F::ONE;
            let mut out = Vec::new();
            for &(_, g, hit) in &hits {
                let next = t * (F::ONE - hit.alpha);
                if next < F::from_f32(cfg.t_stop) {
                    break;
                }
                out.push(LayerHit { gaussian: g as u32, weight: hit.alpha * t, depth: hit.z });
                t = next;
            }
            out
        })
        .collect()
}
