//! Which Gaussians a stage-2 view shades: those its SH pass blended with enough weight
//! ([`weighted`]); the faint ones composite a stand-in colour instead ([`stand_in_colours`]).

use rayon::prelude::*;
use svgir_core::color::srgb_to_linear;

/// The Gaussians a render kept (a positive screen radius: in front of the camera, not culled).
pub(crate) fn visible_of(max_radius: &[f32]) -> Vec<bool> {
    max_radius.iter().map(|r| *r > 0.0).collect()
}

/// The Gaussians of `visible` that a render blended into some pixel with a total weight of at
/// least `min_weight`: `accum_weight` (that render's per-Gaussian sum of w_i) is positive and at
/// least `min_weight`. Every blended Gaussian has a positive weight w_i = alpha_i T_i, so the
/// others' colours are never read (or only times a zero weight) by a render of the same surfels
/// and camera, whatever its colours: with `min_weight` 0, shading only these gives the same
/// image and gradients. On the shipped scene a fifth of the Gaussians in the frustum are hidden.
pub(crate) fn weighted(visible: &[bool], accum_weight: &[f32], min_weight: f32) -> Vec<bool> {
    visible.iter().zip(accum_weight).map(|(v, w)| *v && *w > 0.0 && *w >= min_weight).collect()
}

/// Stand-in colours for the Gaussians of `visible` blended with a total weight below
/// `min_weight` (`Stage2Config::shade_min_weight`), which training does not shade: each vertex
/// takes the colour the SH pass composited for the Gaussian (`sh_colors`, per Gaussian), clamped
/// to [0, 1] and taken from sRGB to linear, the PBR image's space before its encoding. Both
/// images fit the same photos, so the stand-in is close to the shaded colour; it is a constant
/// (no gradients to the materials or the SH). Returns how many Gaussians stand in.
pub(crate) fn stand_in_colours(
    sh_colors: &[[f32; 3]],
    visible: &[bool],
    accum_weight: &[f32],
    min_weight: f32,
    m: usize,
    color: &mut [f32],
) -> usize {
    color
        .par_chunks_exact_mut(m * 3)
        .zip(visible.par_iter().zip(accum_weight).zip(sh_colors))
        .with_min_len(1024)
        .map(|(vertices, ((v, w), sh))| {
            if !(*v && *w > 0.0 && *w < min_weight) {
                return 0;
            }
            let lin = sh.map(|c| srgb_to_linear(c.clamp(0.0, 1.0)));
            for px in vertices.chunks_exact_mut(3) {
                px.copy_from_slice(&lin);
            }
            1
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only the visible Gaussians blended under the threshold stand in, each vertex with the
    /// linearised SH colour; the rest keep their shaded colours, and the shaded set is the
    /// complement among the blended ones.
    #[test]
    fn faint_gaussians_stand_in_with_their_linear_sh_colour() {
        let rgb = [[0.2, 0.5, 0.9], [1.4, 0.0, 0.5], [0.6, 0.6, 0.6], [0.1, 0.2, 0.3], [0.7, 0.1, 0.4]];
        let n = rgb.len();
        let visible = [true, true, true, false, true];
        let weight = [0.004, 0.009, 0.5, 0.001, 0.0];
        let (m, shaded) = (4, 7.0);
        let mut color = vec![shaded; n * m * 3];
        let count = stand_in_colours(&rgb, &visible, &weight, 0.01, m, &mut color);
        assert_eq!(count, 2);
        for i in 0..n {
            let want = if i < 2 { rgb[i].map(|c: f32| srgb_to_linear(c.clamp(0.0, 1.0))) } else { [shaded; 3] };
            for v in 0..m {
                let got = &color[(i * m + v) * 3..(i * m + v) * 3 + 3];
                for c in 0..3 {
                    assert!((got[c] - want[c]).abs() < 1e-5, "Gaussian {i} vertex {v}: {got:?} vs {want:?}");
                }
            }
        }
        assert_eq!(weighted(&visible, &weight, 0.01), [false, false, true, false, false]);
        assert_eq!(weighted(&visible, &weight, 0.0), [true, true, true, false, false]);
    }
}
