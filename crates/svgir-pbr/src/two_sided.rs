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
//! Work split: one call of the one-sided kernels per side. Each call skips the other side's
//! Gaussians through `visible`, so the outputs add; so do the gradients, the back's normal
//! gradient negated. Nothing is saved for backward.

use crate::grads::PbrGrads;
use crate::shade::{shade_into_cached, ShadeInputs, ShadeOutput};
use crate::shade_backward::shade_backward_cached;
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

/// Shade the front side and the back side (into `scratch`, which holds it between calls), then
/// add the back side's output. The two sides run side by side: each is a parallel loop over
/// all Gaussians that shades few of them on the back side, and neither fills many cores alone.
pub fn shade_sides_into<F: Float>(
    front: &Side<F>,
    back: Option<&Side<F>>,
    out: &mut ShadeOutput<F>,
    scratch: &mut ShadeOutput<F>,
) -> Result<(), PbrError> {
    let Some(back) = back else { return shade_into_cached(&front.inputs, front.cache, out) };
    let (f, b) = rayon::join(
        || shade_into_cached(&front.inputs, front.cache, out),
        || shade_into_cached(&back.inputs, back.cache, scratch),
    );
    f?;
    b?;
    if scratch.color.len() != out.color.len() {
        return Err(PbrError::SizeMismatch {
            what: "back-side shading",
            got: scratch.color.len(),
            want: out.color.len(),
        });
    }
    for (o, s) in
        [(&mut out.color, &scratch.color), (&mut out.direct, &scratch.direct), (&mut out.indirect, &scratch.indirect)]
    {
        o.par_iter_mut().zip(s).with_min_len(4096).for_each(|(a, b)| *a += *b);
    }
    Ok(())
}

/// Gradients of [`shade_sides_into`]'s colour for upstream `v_color`, with respect to the
/// front-side (un-negated) shading normals and the shared materials, light and rho.
pub fn shade_sides_backward<F: Float>(
    front: &Side<F>,
    back: Option<&Side<F>>,
    v_color: &[F],
) -> Result<PbrGrads<F>, PbrError> {
    let Some(back) = back else { return shade_backward_cached(&front.inputs, front.cache, v_color) };
    // Side by side, as the forward.
    let (g, b) = rayon::join(
        || shade_backward_cached(&front.inputs, front.cache, v_color),
        || shade_backward_cached(&back.inputs, back.cache, v_color),
    );
    let (mut g, mut b) = (g?, b?);
    // The back side shades with -n_m: d/dn_m = -d/d(-n_m).
    b.v_normals.par_iter_mut().with_min_len(4096).for_each(|x| *x = -*x);
    if !g.add_scaled(&b, F::ONE) {
        return Err(PbrError::InvalidParameter("front and back shading have different sizes".into()));
    }
    Ok(g)
}
