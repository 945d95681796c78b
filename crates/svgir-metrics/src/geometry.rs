//! Material and geometry metrics of SPEC 8 (TensoIR synthetic protocol):
//! - normal mean angular error: both normals blended with the background normal (0,0,1) by the GT
//!   alpha and renormalised, then `acos(clip(n . n_gt, -1, 1))` in degrees, averaged over all pixels of
//!   all views (background pixels contribute 0);
//! - albedo scale: per channel `s_c = median over the mask of a_gt / a_pred` (linear values, the
//!   prediction clamped to >= 1e-6 as TensoIR does; even counts take the lower middle value, as
//!   `torch.median`), then `clamp(s_c a_pred, 0, 1)` inside the mask.
//!
//! Sequential per-pixel loops with f64 sums: these run once per evaluation on a few views.

use crate::error::{check_eq, MetricsError, Result};

const BACKGROUND_NORMAL: [f32; 3] = [0.0, 0.0, 1.0];
/// A pixel belongs to the albedo mask when its GT alpha exceeds this.
pub const MASK_THRESHOLD: f32 = 0.5;

fn blend_normalise(n: &[f32], a: f32) -> [f64; 3] {
    let v: [f64; 3] = std::array::from_fn(|k| (n[k] * a + BACKGROUND_NORMAL[k] * (1.0 - a)) as f64);
    // torch.nn.functional.normalize: divide by max(|v|, 1e-12).
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-12);
    v.map(|x| x / len)
}

/// Per-pixel angular error in degrees (`pred`, `gt`: 3 values per pixel; `alpha`: GT alpha).
pub fn normal_error_map(pred: &[f32], gt: &[f32], alpha: &[f32]) -> Result<Vec<f32>> {
    check_eq("pred vs gt normals", pred.len(), gt.len())?;
    check_eq("normals vs 3 x alpha", pred.len(), 3 * alpha.len())?;
    Ok(pred
        .chunks_exact(3)
        .zip(gt.chunks_exact(3))
        .zip(alpha)
        .map(|((p, g), &a)| {
            let (p, g) = (blend_normalise(p, a), blend_normalise(g, a));
            let dot = (p[0] * g[0] + p[1] * g[1] + p[2] * g[2]).clamp(-1.0, 1.0);
            dot.acos().to_degrees() as f32
        })
        .collect())
}

/// Normal mean angular error accumulated over views: the mean is over all pixels of all views.
#[derive(Clone, Debug, Default)]
pub struct NormalMae {
    sum_deg: f64,
    pixels: u64,
}

impl NormalMae {
    /// An empty accumulator (no pixels).
    pub fn new() -> Self {
        Self::default()
    }

    /// Add one view: normals `pred`, `gt` (3 per pixel) and GT alpha (1 per pixel), blended with the background normal as in SPEC 8.
    pub fn add_view(&mut self, pred: &[f32], gt: &[f32], alpha: &[f32]) -> Result<()> {
        let errs = normal_error_map(pred, gt, alpha)?;
        self.sum_deg += errs.iter().map(|&e| e as f64).sum::<f64>();
        self.pixels += errs.len() as u64;
        Ok(())
    }

    /// Mean error in degrees, `None` before any pixel was added.
    pub fn mean_deg(&self) -> Option<f64> {
        (self.pixels > 0).then(|| self.sum_deg / self.pixels as f64)
    }

    /// Number of pixels accumulated so far over all views.
    pub fn pixels(&self) -> u64 {
        self.pixels
    }
}

/// Collects `a_gt / a_pred` ratios over the masked pixels of any number of views.
#[derive(Clone, Debug, Default)]
pub struct AlbedoScale {
    ratios: [Vec<f32>; 3],
}

impl AlbedoScale {
    /// An empty accumulator (no ratios).
    pub fn new() -> Self {
        Self::default()
    }

    /// Add one view: `pred`, `gt` RGB (3 per pixel, linear), `mask` one GT alpha per pixel.
    pub fn add_view(&mut self, pred: &[f32], gt: &[f32], mask: &[f32]) -> Result<()> {
        check_eq("pred vs gt albedo", pred.len(), gt.len())?;
        check_eq("albedo vs 3 x mask", pred.len(), 3 * mask.len())?;
        for ((p, g), &m) in pred.chunks_exact(3).zip(gt.chunks_exact(3)).zip(mask) {
            if m > MASK_THRESHOLD {
                for c in 0..3 {
                    self.ratios[c].push(g[c] / p[c].max(1e-6));
                }
            }
        }
        Ok(())
    }

    /// The per-channel medians `s_c`.
    pub fn scale(&self) -> Result<[f32; 3]> {
        if self.ratios[0].is_empty() {
            return Err(MetricsError::EmptyMask);
        }
        let mut out = [0.0; 3];
        for c in 0..3 {
            let mut r = self.ratios[c].clone();
            let mid = (r.len() - 1) / 2;
            let (_, m, _) = r.select_nth_unstable_by(mid, f32::total_cmp);
            out[c] = *m;
        }
        Ok(out)
    }
}

/// `clamp(s_c pred_c, 0, 1)` inside the mask, `background` outside (RGB, 3 per pixel).
pub fn apply_albedo_scale(pred: &[f32], scale: [f32; 3], mask: &[f32], background: [f32; 3]) -> Result<Vec<f32>> {
    check_eq("albedo vs 3 x mask", pred.len(), 3 * mask.len())?;
    let mut out = Vec::with_capacity(pred.len());
    for (p, &m) in pred.chunks_exact(3).zip(mask) {
        for c in 0..3 {
            out.push(if m > MASK_THRESHOLD { (scale[c] * p[c]).clamp(0.0, 1.0) } else { background[c] });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_error_known_angles() {
        // Pixel 0: 90 degrees apart, fully opaque. Pixel 1: background (alpha 0) -> both (0,0,1) -> 0.
        // Pixel 2: half alpha, pred = gt -> 0. Pixel 3: opposite normals at alpha 1 -> 180.
        let pred = [1.0, 0.0, 0.0, 0.3, 0.3, 0.3, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let gt = [0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0];
        let alpha = [1.0, 0.0, 0.5, 1.0];
        let e = normal_error_map(&pred, &gt, &alpha).unwrap();
        assert!(
            (e[0] - 90.0).abs() < 1e-4 && e[1].abs() < 1e-4 && e[2].abs() < 1e-3 && (e[3] - 180.0).abs() < 1e-3,
            "{e:?}"
        );
        // Half alpha: pred (1,0,0) and gt (0,1,0) blend to (.5,0,.5) and (0,.5,.5): 60 degrees.
        let e = normal_error_map(&[1.0, 0.0, 0.0], &[0.0, 1.0, 0.0], &[0.5]).unwrap();
        assert!((e[0] - 60.0).abs() < 1e-3, "{e:?}");
        let mut acc = NormalMae::new();
        acc.add_view(&pred, &gt, &alpha).unwrap();
        acc.add_view(&[1.0, 0.0, 0.0], &[0.0, 1.0, 0.0], &[0.5]).unwrap();
        assert!((acc.mean_deg().unwrap() - (90.0 + 180.0 + 60.0) / 5.0).abs() < 1e-3);
        assert!(acc.add_view(&pred, &gt, &alpha[..3]).is_err());
    }

    #[test]
    fn albedo_scale_recovers_per_channel_factor() {
        // GT = (2, 0.5, 1) x pred on the mask; one outlier pixel must not move the median.
        let mut pred = Vec::new();
        let mut gt = Vec::new();
        let mut mask = Vec::new();
        for i in 0..9 {
            let p = [0.1 + 0.05 * i as f32, 0.2, 0.3 + 0.01 * i as f32];
            pred.extend_from_slice(&p);
            gt.extend_from_slice(&[2.0 * p[0], 0.5 * p[1], p[2]]);
            mask.push(1.0);
        }
        pred.extend_from_slice(&[0.0, 0.0, 0.0]);
        gt.extend_from_slice(&[1.0, 1.0, 1.0]);
        mask.push(1.0);
        // Background pixel: ignored.
        pred.extend_from_slice(&[1.0, 1.0, 1.0]);
        gt.extend_from_slice(&[0.0, 0.0, 0.0]);
        mask.push(0.0);
        let mut acc = AlbedoScale::new();
        acc.add_view(&pred, &gt, &mask).unwrap();
        let s = acc.scale().unwrap();
        assert!((s[0] - 2.0).abs() < 1e-5 && (s[1] - 0.5).abs() < 1e-5 && (s[2] - 1.0).abs() < 1e-5, "{s:?}");
        let out = apply_albedo_scale(&pred, s, &mask, [0.0; 3]).unwrap();
        assert!((out[0] - gt[0]).abs() < 1e-6 && out[30..] == [0.0, 0.0, 0.0]);
        assert!(AlbedoScale::new().scale().is_err());
    }

    #[test]
    fn median_of_even_count_is_lower_middle() {
        let mut acc = AlbedoScale::new();
        acc.add_view(&[1.0; 6], &[1.0, 1.0, 1.0, 3.0, 3.0, 3.0], &[1.0, 1.0]).unwrap();
        assert_eq!(acc.scale().unwrap(), [1.0; 3]);
    }
}
