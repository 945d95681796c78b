//! Which Gaussians a stage-2 view shades: those its SH pass blended with enough weight
//! ([`weighted`]); the faint ones composite a stand-in colour instead ([`stand_in_colours`]).
//! Or, with [`ShadeSets::LastVisit`], those the view's previous render blended with enough
//! weight ([`ViewSets`]), which spares the SH pass its pixels.

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
    visible.iter().zip(accum_weight).map(|(v, w)| *v && shades(*w, min_weight)).collect()
}

/// Whether a Gaussian a render blended with total weight `w` is shaded: `0 < w >= min_weight`
/// ([`weighted`], [`faint`], [`ViewSets::record`]).
#[inline]
fn shades(w: f32, min_weight: f32) -> bool {
    w > 0.0 && w >= min_weight
}

/// The Gaussians of `visible` blended with a total weight below `min_weight`
/// (`Stage2Config::shade_min_weight`), which training does not shade but stands in
/// ([`stand_in_colours`]).
pub(crate) fn faint(visible: &[bool], accum_weight: &[f32], min_weight: f32) -> Vec<bool> {
    visible.iter().zip(accum_weight).map(|(v, w)| *v && *w > 0.0 && !shades(*w, min_weight)).collect()
}

/// Stand-in colours for the Gaussians of `stands_in`, which training does not shade: each vertex
/// takes the colour the SH pass composited for the Gaussian (`sh_colors`, per Gaussian), clamped
/// to [0, 1] and taken from sRGB to linear, the PBR image's space before its encoding. Both
/// images fit the same photos, so the stand-in is close to the shaded colour; it is a constant
/// (no gradients to the materials or the SH). Returns how many Gaussians stand in.
pub(crate) fn stand_in_colours(sh_colors: &[[f32; 3]], stands_in: &[bool], m: usize, color: &mut [f32]) -> usize {
    color
        .par_chunks_exact_mut(m * 3)
        .zip(stands_in.par_iter().zip(sh_colors))
        .with_min_len(1024)
        .map(|(vertices, (s, sh))| {
            if !*s {
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

/// Where a training view's shaded set comes from (`Stage2Config::shade_sets`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ShadeSets {
    /// The view's SH pass of this iteration: the weights it composited (exact).
    #[default]
    ThisRender,
    /// The view's previous training render, when it has one: the Gaussians that render blended
    /// with enough weight. The SH pass then only projects (no pixel), since nothing else of it
    /// is read; a view's first render runs the whole pass. Opacities move little between two
    /// visits of a view (tens of iterations apart), so the sets differ by a few faint Gaussians,
    /// which composite their stand-in colour in place of a shaded one.
    LastVisit,
}

/// Per training view, the Gaussians its last training render blended with a weight of at least
/// the threshold ([`weighted`]'s test), one bit each; saved with the checkpoint so that a
/// resumed run shades the same sets.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct ViewSets {
    /// Per view, `None` until it is rendered; else `ceil(n / 64)` words, bit `g` for Gaussian g.
    sets: Vec<Option<Vec<u64>>>,
}

impl ViewSets {
    /// View `view`'s set, if it was rendered.
    pub(crate) fn get(&self, view: usize) -> Option<&[u64]> {
        self.sets.get(view).and_then(|s| s.as_deref())
    }

    /// Keeps, for view `view`, the Gaussians `accum_weight` shades ([`shades`]).
    pub(crate) fn record(&mut self, view: usize, accum_weight: &[f32], min_weight: f32) {
        if self.sets.len() <= view {
            self.sets.resize(view + 1, None);
        }
        let mut words = vec![0u64; accum_weight.len().div_ceil(64)];
        for (g, w) in accum_weight.iter().enumerate() {
            if shades(*w, min_weight) {
                words[g / 64] |= 1 << (g % 64);
            }
        }
        self.sets[view] = Some(words);
    }

    /// The views that have a set, and all their words in view order (for the checkpoint).
    pub(crate) fn parts(&self) -> (Vec<u32>, Vec<u64>) {
        let mut views = Vec::new();
        let mut words = Vec::new();
        for (v, s) in self.sets.iter().enumerate() {
            if let Some(s) = s {
                views.push(v as u32);
                words.extend_from_slice(s);
            }
        }
        (views, words)
    }

    /// The sets of [`ViewSets::parts`] for `n` Gaussians; None when the words do not fit.
    pub(crate) fn from_parts(views: &[u32], words: &[u64], n: usize) -> Option<Self> {
        let per = n.div_ceil(64);
        if words.len() != views.len() * per {
            return None;
        }
        let mut out = Self::default();
        for (v, w) in views.iter().zip(words.chunks_exact(per.max(1))) {
            let v = *v as usize;
            if out.sets.len() <= v {
                out.sets.resize(v + 1, None);
            }
            out.sets[v] = Some(w.to_vec());
        }
        Some(out)
    }
}

/// Whether Gaussian `g` is in a [`ViewSets`] set.
#[inline]
pub(crate) fn in_set(set: &[u64], g: usize) -> bool {
    set[g / 64] >> (g % 64) & 1 == 1
}

/// The Gaussians of `visible` in `set`.
pub(crate) fn in_set_of(visible: &[bool], set: &[u64]) -> Vec<bool> {
    visible.iter().enumerate().map(|(g, v)| *v && in_set(set, g)).collect()
}

/// The Gaussians of `visible` outside `set`: with sets from a view's last render, every one of
/// them stands in ([`stand_in_colours`]), since its weight now may be above 0.
pub(crate) fn outside_set(visible: &[bool], set: &[u64]) -> Vec<bool> {
    visible.iter().enumerate().map(|(g, v)| *v && !in_set(set, g)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A set keeps exactly the Gaussians `weighted` keeps, survives the checkpoint's parts, and
    /// its stand-ins are the visible Gaussians outside it.
    #[test]
    fn view_sets_keep_what_weighted_keeps() {
        let n = 130;
        let weight: Vec<f32> = (0..n).map(|g| [0.0, 0.004, 0.01, 0.5][g % 4]).collect();
        let visible: Vec<bool> = (0..n).map(|g| g % 7 != 3).collect();
        let mut sets = ViewSets::default();
        assert!(sets.get(2).is_none());
        sets.record(2, &weight, 0.01);
        let set = sets.get(2).expect("recorded");
        assert_eq!(in_set_of(&visible, set), weighted(&visible, &weight, 0.01));
        assert!(sets.get(0).is_none() && sets.get(3).is_none());
        let (views, words) = sets.parts();
        assert_eq!(views, [2]);
        assert_eq!(ViewSets::from_parts(&views, &words, n), Some(sets.clone()));
        assert_eq!(ViewSets::from_parts(&views, &words[1..], n), None);
        let rgb = vec![[0.3, 0.6, 0.9]; n];
        let mut color = vec![7.0; n * 3];
        let stand_ins = stand_in_colours(&rgb, &outside_set(&visible, set), 1, &mut color);
        let outside = (0..n).filter(|&g| visible[g] && !in_set(set, g)).count();
        assert_eq!(stand_ins, outside);
        for g in 0..n {
            assert_eq!(color[3 * g] == 7.0, !visible[g] || in_set(set, g), "Gaussian {g}");
        }
    }

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
        let count = stand_in_colours(&rgb, &faint(&visible, &weight, 0.01), m, &mut color);
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
