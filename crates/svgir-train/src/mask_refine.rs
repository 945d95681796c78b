//! Mask edges that follow the photo. The 3D estimate ([`crate::foreground`]) puts a mask in the
//! right place with the reconstruction's blur at its edge; this refines it per photo as GrabCut
//! does (Rother et al. 2004), seeded by the estimate instead of a user's rectangle:
//!
//! 1. A band of half-width `band` around the estimate's edge is uncertain; pixels farther inside
//!    or outside keep their label.
//! 2. A colour model of each side ([`ColourModel`]) is fitted to the fixed pixels near the band.
//! 3. Each band pixel pays -ln p(colour | side) - `prior` ln(share or 1 - share), the estimate's
//!    own soft vote; neighbours with different labels pay `smoothness` exp(-beta |dc|^2) / dist,
//!    cheap across colour edges (beta from the band's mean contrast).
//! 4. The minimum cut ([`crate::grid_cut`]) is the new mask; the models are refitted to it and
//!    the cut repeated `iterations` times.

use crate::colour_model::ColourModel;
use crate::grid_cut::{GridGraph, HARD};
use serde::{Deserialize, Serialize};
use svgir_core::Rng;

/// Settings of the per-photo refinement.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RefineConfig {
    /// Half-width of the uncertain band, as a share of the image diagonal.
    pub band: f32,
    /// The band is at least this many pixels wide on each side.
    pub min_band_px: f32,
    /// Gaussians per colour model.
    pub components: usize,
    /// Weight of the contrast-sensitive smoothness (GrabCut's gamma, for colours in [0, 255]
    /// and unit weight on the colour term).
    pub smoothness: f32,
    /// Weight of the 3D estimate's share as a prior.
    pub prior: f32,
    /// Fit-and-cut rounds.
    pub iterations: usize,
    /// Colours drawn to fit each model.
    pub max_samples: usize,
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            band: 0.03,
            min_band_px: 2.0,
            components: 5,
            smoothness: 50.0,
            prior: 3.0,
            iterations: 2,
            max_samples: 20_000,
        }
    }
}

/// A refined mask.
pub struct Refinement {
    /// `true` on the object.
    pub mask: Vec<bool>,
    /// Pixels whose label differs from the estimate's.
    pub changed: usize,
    /// Pixels in the uncertain band.
    pub band: usize,
}

/// Refine the estimate `share` (the object's share of each pixel, 0.5 the threshold) of one
/// `width` x `height` photo (`channels` interleaved values per pixel, RGB first).
pub fn refine(
    photo: &[f32],
    channels: usize,
    share: &[f32],
    width: usize,
    height: usize,
    cfg: &RefineConfig,
    rng: &mut Rng,
) -> Refinement {
    let n = width * height;
    let estimate: Vec<bool> = share.iter().map(|&s| s >= 0.5).collect();
    let unchanged = |estimate: Vec<bool>| Refinement { mask: estimate, changed: 0, band: 0 };
    let objects = estimate.iter().filter(|&&m| m).count();
    if objects == 0 || objects == n {
        return unchanged(estimate);
    }
    let colour = |i: usize| [photo[i * channels], photo[i * channels + 1], photo[i * channels + 2]];
    let diagonal = ((width * width + height * height) as f32).sqrt();
    let band = (cfg.band * diagonal).max(cfg.min_band_px);
    let edge_distance = distance_to_other_label(&estimate, width, height);
    let uncertain: Vec<bool> = edge_distance.iter().map(|&d| d <= band).collect();
    // The colour models see the fixed pixels within a few band widths: the colours that meet
    // at this object's edge, not the far corners of the room.
    let near: Vec<bool> = edge_distance.iter().map(|&d| d <= 5.0 * band).collect();
    let band_pixels = uncertain.iter().filter(|&&u| u).count();

    // beta: 1 / (2 <|dc|^2>) over the band's neighbour pairs (GrabCut).
    let (mut sum, mut pairs) = (0.0f64, 0usize);
    for_each_pair(width, height, |i, j, _| {
        if uncertain[i] || uncertain[j] {
            sum += colour_distance2(colour(i), colour(j)) as f64;
            pairs += 1;
        }
    });
    let beta = if sum > 0.0 { pairs as f64 / (2.0 * sum) } else { 0.0 };
    // Colours in [0, 1]: the colour term's scale differs from GrabCut's [0, 255] by a constant
    // per side that cancels; gamma keeps its meaning.
    let mut mask = estimate.clone();
    for _ in 0..cfg.iterations.max(1) {
        let fit = |side: bool, fixed_only: bool, rng: &mut Rng| {
            let colours: Vec<[f32; 3]> =
                (0..n).filter(|&i| near[i] && mask[i] == side && !(fixed_only && uncertain[i])).map(colour).collect();
            ColourModel::fit(&colours, cfg.components, cfg.max_samples, rng)
        };
        let first = mask == estimate;
        let (Some(fg), Some(bg)) = (fit(true, first, rng), fit(false, first, rng)) else {
            return unchanged(estimate);
        };
        let mut graph = GridGraph::new(width, height);
        for i in 0..n {
            if !uncertain[i] {
                if estimate[i] {
                    graph.add_terminal(i, HARD, 0.0);
                } else {
                    graph.add_terminal(i, 0.0, HARD);
                }
                continue;
            }
            let p = share[i].clamp(0.05, 0.95) as f64;
            let c = colour(i);
            let on = fg.neg_log_likelihood(c) - cfg.prior as f64 * p.ln();
            let off = bg.neg_log_likelihood(c) - cfg.prior as f64 * (1.0 - p).ln();
            let m = on.min(off);
            graph.add_terminal(i, (off - m) as f32, (on - m) as f32);
        }
        for_each_pair(width, height, |i, j, k| {
            if uncertain[i] || uncertain[j] {
                let dist = if k == 4 || k == 6 { 1.0 } else { std::f64::consts::SQRT_2 };
                let w = cfg.smoothness as f64 / dist * (-beta * colour_distance2(colour(i), colour(j)) as f64).exp();
                graph.add_edge(i, k, w as f32, w as f32);
            }
        });
        mask = graph.solve().source_side;
    }
    let changed = mask.iter().zip(&estimate).filter(|(a, b)| a != b).count();
    Refinement { mask, changed, band: band_pixels }
}

fn colour_distance2(a: [f32; 3], b: [f32; 3]) -> f32 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// Each unordered 8-neighbour pair once: `(i, j, k)` with `j` the neighbour of `i` in direction
/// `k` of [`GridGraph`]'s order (2: up-right, 4: right, 6: down, 7: down-right).
fn for_each_pair(width: usize, height: usize, mut f: impl FnMut(usize, usize, usize)) {
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            if x + 1 < width {
                f(i, i + 1, 4);
                if y > 0 {
                    f(i, i - width + 1, 2);
                }
                if y + 1 < height {
                    f(i, i + width + 1, 7);
                }
            }
            if y + 1 < height {
                f(i, i + width, 6);
            }
        }
    }
}

/// Distance from each pixel to the nearest pixel with the other label (chamfer 1 / sqrt 2, two
/// passes): 1 next to the edge.
fn distance_to_other_label(mask: &[bool], width: usize, height: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; mask.len()];
    for label in [true, false] {
        let mut d: Vec<f32> = mask.iter().map(|&m| if m == label { f32::INFINITY } else { 0.0 }).collect();
        let s2 = std::f32::consts::SQRT_2;
        let at = |x: isize, y: isize| -> Option<usize> {
            (x >= 0 && y >= 0 && (x as usize) < width && (y as usize) < height).then(|| y as usize * width + x as usize)
        };
        for y in 0..height as isize {
            for x in 0..width as isize {
                let i = at(x, y).unwrap();
                for (dx, dy, c) in [(-1, 0, 1.0), (0, -1, 1.0), (-1, -1, s2), (1, -1, s2)] {
                    if let Some(j) = at(x + dx, y + dy) {
                        d[i] = d[i].min(d[j] + c);
                    }
                }
            }
        }
        for y in (0..height as isize).rev() {
            for x in (0..width as isize).rev() {
                let i = at(x, y).unwrap();
                for (dx, dy, c) in [(1, 0, 1.0), (0, 1, 1.0), (1, 1, s2), (-1, 1, s2)] {
                    if let Some(j) = at(x + dx, y + dy) {
                        d[i] = d[i].min(d[j] + c);
                    }
                }
            }
        }
        for (o, (&m, &v)) in out.iter_mut().zip(mask.iter().zip(&d)) {
            if m == label {
                *o = v;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A photo of a textured disc on a textured background, and a blurred, shifted,
    /// eroded estimate of it: the refinement must recover the disc's true edge.
    #[test]
    fn a_blurred_offset_estimate_snaps_to_the_object_edge() {
        let (w, h) = (128, 112);
        let (cx, cy, r) = (66.0f32, 56.0f32, 32.0f32);
        let mut rng = Rng::new(9);
        let mut photo = vec![0.0f32; w * h * 3];
        let mut truth = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let inside = ((x as f32 - cx).powi(2) + (y as f32 - cy).powi(2)).sqrt() < r;
                truth[i] = inside;
                // Object: orange with darker stripes; background: grey-blue checker; noise.
                let c = if inside {
                    if (x / 6) % 2 == 0 {
                        [0.85, 0.45, 0.1]
                    } else {
                        [0.6, 0.3, 0.05]
                    }
                } else if ((x / 10) + (y / 10)) % 2 == 0 {
                    [0.3, 0.35, 0.5]
                } else {
                    [0.7, 0.72, 0.75]
                };
                for ch in 0..3 {
                    photo[i * 3 + ch] = (c[ch] + 0.02 * rng.normal()).clamp(0.0, 1.0);
                }
            }
        }
        // The estimate: the disc 2 px smaller and 1.5 px off, with a 3 px soft ramp.
        let share: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let d = ((x - cx - 1.5).powi(2) + (y - cy).powi(2)).sqrt() - (r - 2.0);
                (0.5 - d / 3.0).clamp(0.0, 1.0)
            })
            .collect();
        let iou = |m: &[bool]| {
            let inter = m.iter().zip(&truth).filter(|(a, b)| **a && **b).count() as f64;
            let union = m.iter().zip(&truth).filter(|(a, b)| **a || **b).count() as f64;
            inter / union
        };
        let before: Vec<bool> = share.iter().map(|&s| s >= 0.5).collect();
        let out = refine(&photo, 3, &share, w, h, &RefineConfig::default(), &mut Rng::new(0));
        let (a, b) = (iou(&before), iou(&out.mask));
        assert!(a < 0.9, "the estimate is off: {a}");
        eprintln!("estimate IoU {a:.4}, refined {b:.4}, changed {} of band {}", out.changed, out.band);
        assert!(b > 0.995, "refined IoU {b} (estimate {a})");
        assert!(out.changed > 0 && out.band > out.changed);
    }

    #[test]
    fn an_empty_or_full_estimate_is_left_alone() {
        let photo = vec![0.5f32; 16 * 3];
        for s in [0.0, 1.0] {
            let out = refine(&photo, 3, &[s; 16], 4, 4, &RefineConfig::default(), &mut Rng::new(0));
            assert!(out.mask.iter().all(|&m| m == (s > 0.5)));
            assert_eq!(out.changed, 0);
        }
    }

    #[test]
    fn chamfer_distance_counts_steps_to_the_other_label() {
        let mut m = vec![false; 7 * 7];
        m[3 * 7 + 3] = true;
        let d = distance_to_other_label(&m, 7, 7);
        assert_eq!(d[3 * 7 + 3], 1.0);
        assert_eq!(d[3 * 7 + 5], 2.0);
        assert!((d[5 * 7 + 5] - 2.0 * std::f32::consts::SQRT_2).abs() < 1e-6);
    }
}
