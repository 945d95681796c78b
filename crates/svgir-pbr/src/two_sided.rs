//! Two-sided shading (our option; SPEC 4 shades the hemisphere of one normal).
//!
//! A 2D Gaussian has no inherent side: the rasteriser flips each normal to face the camera
//! (SPEC 1), and stage 2 orients every surfel towards the training cameras that see it. A thin
//! wall (a bowl's rim, a saucer) is one layer of surfels seen from both sides, and an outvoted
//! surfel is seen from its back. Shaded over its oriented hemisphere, such a surfel looks into the
//! surface, so it renders dark and its albedo brightens to make up for it.
//!
//! With two sides every Gaussian also has back micro-buffers, traced over the hemisphere of `-n`,
//! and each view shades a Gaussian on the side its camera sees. The front inputs shade the
//! Gaussians that face the camera (`n . (c - p) >= 0`, the test the rasteriser flips normals by).
//! The back inputs shade the others, with the back micro-buffers, their direction cache and light
//! visibility, and the shading normals negated. Materials and light are shared.
//!
//! Work split: one pass of the one-sided kernels over the Gaussians, each shaded (and given its
//! gradients) on the side whose `visible` holds it, the back's normal gradient negated. The
//! sides' sets are disjoint, so this is the sum of two one-sided calls without a second output
//! buffer and a pass to add it. Nothing is saved for backward.

use crate::grads::PbrGrads;
use crate::shade::{shade_sides_into_cached, ShadeInputs, ShadeOutput, SideRef};
use crate::shade_backward::shade_sides_backward_cached;
use crate::PbrError;
use glam::Vec3;
use rayon::prelude::*;
use svgir_shading::Float;
use svgir_trace::DirectionCache;

/// One side's shading: its inputs and the direction cache of its micro-buffers.
#[derive(Clone, Copy, Debug)]
pub struct Side<'a, F> {
    /// `visible` holds the Gaussians this side shades; on the back, `mats.normals` are the
    /// negated shading normals ([`negated`]) and `mb` the back micro-buffers.
    pub inputs: ShadeInputs<'a, F>,
    /// Precomputed per-direction env lookups of `mb` (`None`: computed on the fly).
    pub cache: Option<&'a DirectionCache>,
}

/// Does `camera` see the oriented side of a Gaussian at `position` with `normal`? The test the
/// rasteriser flips normals by: `normal . (camera - position) >= 0`.
#[inline]
pub fn faces(normal: Vec3, position: Vec3, camera: Vec3) -> bool {
    normal.dot(camera - position) >= 0.0
}

/// Which side of each Gaussian `camera` sees: `(front, back)` visibility masks of the Gaussians
/// in `visible`, split by [`faces`].
pub fn split_by_side(normals: &[Vec3], positions: &[Vec3], camera: Vec3, visible: &[bool]) -> (Vec<bool>, Vec<bool>) {
    normals
        .iter()
        .zip(positions)
        .zip(visible)
        .map(|((n, p), &v)| {
            let front = faces(*n, *p, camera);
            (v && front, v && !front)
        })
        .unzip()
}

/// The back side's shading normals: every component negated.
pub fn negated<F: Float>(normals: &[F]) -> Vec<F> {
    normals.par_iter().with_min_len(4096).map(|&x| -x).collect()
}

/// Shade the front side and the back side (if any) into `out`, in one pass over the Gaussians:
/// each is shaded on the side whose `visible` holds it. The sides' visible sets must be
/// disjoint ([`split_by_side`]), else an error.
pub fn shade_sides_into<F: Float>(
    front: &Side<F>,
    back: Option<&Side<F>>,
    out: &mut ShadeOutput<F>,
) -> Result<(), PbrError> {
    shade_sides_into_cached(&sides(front, back)?, out)
}

/// Gradients of [`shade_sides_into`]'s colour for upstream `v_color`, with respect to the
/// front-side (un-negated) shading normals and the shared materials, light and rho.
pub fn shade_sides_backward<F: Float>(
    front: &Side<F>,
    back: Option<&Side<F>>,
    v_color: &[F],
) -> Result<PbrGrads<F>, PbrError> {
    let inp = &front.inputs;
    let mut grads = PbrGrads::zeros(inp.mb.len(), inp.mats.m, inp.env.len());
    shade_sides_backward_into(front, back, v_color, &mut grads)?;
    Ok(grads)
}

/// [`shade_sides_backward`] added into `grads` (sized for the sides' Gaussians, vertices and
/// map, else an error): the trainer's other gradients of the same quantities, without a second
/// buffer and a pass to add it.
pub fn shade_sides_backward_into<F: Float>(
    front: &Side<F>,
    back: Option<&Side<F>>,
    v_color: &[F],
    grads: &mut PbrGrads<F>,
) -> Result<(), PbrError> {
    shade_sides_backward_cached(&sides(front, back)?, v_color, grads)
}

/// The sides the one-pass kernels take: the front, then the back if any. No Gaussian may be
/// shaded on both.
pub(crate) fn sides<'s, F>(
    front: &'s Side<'s, F>,
    back: Option<&'s Side<'s, F>>,
) -> Result<Vec<SideRef<'s, F>>, PbrError> {
    let mut sides = vec![(&front.inputs, front.cache)];
    if let Some(back) = back {
        let (f, b) = (front.inputs.visible, back.inputs.visible);
        if f.len() != b.len() {
            return Err(PbrError::SizeMismatch { what: "back side's visible Gaussians", got: b.len(), want: f.len() });
        }
        if f.par_iter().zip(b).with_min_len(4096).any(|(x, y)| *x && *y) {
            return Err(PbrError::InvalidParameter("a Gaussian is shaded on both sides".into()));
        }
        sides.push((&back.inputs, back.cache));
    }
    Ok(sides)
}
