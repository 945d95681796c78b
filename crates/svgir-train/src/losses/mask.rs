//! Opacity losses for RGBA data (SPEC 2): the mask loss penalises opacity outside the 9x9-dilated
//! ground-truth mask, and the entropy loss is the binary cross-entropy of the rendered opacity
//! against the ground-truth alpha, which pushes opacity to 0 or 1 where the photo says so.
//! Work split: chunks of pixels in parallel, each summing its own part of the mean.

use super::chunked_sum;

/// 9x9 (radius 4) dilation of `alpha > 0.5`, separable max filter.
pub fn dilated_mask(alpha: &[f32], width: usize, height: usize, radius: usize) -> Vec<bool> {
    let on: Vec<bool> = alpha.iter().map(|&a| a > 0.5).collect();
    let mut tmp = vec![false; on.len()];
    for y in 0..height {
        for x in 0..width {
            let (x0, x1) = (x.saturating_sub(radius), (x + radius).min(width - 1));
            tmp[y * width + x] = (x0..=x1).any(|i| on[y * width + i]);
        }
    }
    let mut out = vec![false; on.len()];
    for y in 0..height {
        let (y0, y1) = (y.saturating_sub(radius), (y + radius).min(height - 1));
        for x in 0..width {
            out[y * width + x] = (y0..=y1).any(|j| tmp[j * width + x]);
        }
    }
    out
}

/// Mean opacity outside the dilated mask; accumulates `weight * d/d opacity` into `v_opacity`.
pub fn mask_loss(opacity: &[f32], dilated: &[bool], weight: f32, v_opacity: &mut [f32]) -> f32 {
    let n = opacity.len() as f32;
    let sum = chunked_sum(opacity, v_opacity, |i, o, g| {
        if dilated[i] {
            0.0
        } else {
            *g += weight / n;
            o as f64
        }
    });
    (sum / n as f64) as f32
}

/// Mean binary cross-entropy of opacity against the ground-truth alpha.
pub fn entropy_loss(opacity: &[f32], gt_alpha: &[f32], weight: f32, v_opacity: &mut [f32]) -> f32 {
    let n = opacity.len() as f32;
    let sum = chunked_sum(opacity, v_opacity, |i, o, g| {
        let o = o.clamp(1e-6, 1.0 - 1e-6) as f64;
        let m = gt_alpha[i] as f64;
        *g += weight * ((o - m) / (o * (1.0 - o)) / n as f64) as f32;
        -(m * o.ln() + (1.0 - m) * (1.0 - o).ln())
    });
    (sum / n as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_grows_by_radius() {
        let (w, h) = (12, 10);
        let mut a = vec![0.0; w * h];
        a[5 * w + 6] = 1.0;
        let d = dilated_mask(&a, w, h, 4);
        assert!(d[5 * w + 2] && d[w + 10] && d[9 * w + 6]);
        assert!(!d[5 * w + 1] && !d[6]);
        assert_eq!(d.iter().filter(|x| **x).count(), 9 * 9);
    }

    #[test]
    fn entropy_gradient_matches_finite_differences() {
        let o = [0.3f32, 0.8, 0.55];
        let m = [0.0f32, 1.0, 0.4];
        let mut g = [0.0; 3];
        entropy_loss(&o, &m, 1.0, &mut g);
        for i in 0..3 {
            let h = 1e-3;
            let (mut op, mut om) = (o, o);
            op[i] += h;
            om[i] -= h;
            let fd =
                (entropy_loss(&op, &m, 1.0, &mut [0.0; 3]) - entropy_loss(&om, &m, 1.0, &mut [0.0; 3])) / (2.0 * h);
            assert!((fd - g[i]).abs() < 2e-3 * g[i].abs().max(1.0), "{i}: {fd} vs {}", g[i]);
        }
    }
}
