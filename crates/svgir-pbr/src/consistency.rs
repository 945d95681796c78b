//! Radiance consistency (SPEC 6, Eqn 14/16; 9.3, 9.6): the traced radiance of an occluded
//! direction must match the physically-based one-bounce radiance of the surface it hits.
//!
//! Per visible Gaussian j, with v the unit view ray (camera -> p_j), n the geometric normal and
//! `r_j = v - 2(n.v)n` the mirror direction (9.6), pick `k_j = argmax_k <w_k, r_j> (1 - V_j^k)`
//! over directions that hit a Gaussian. Only strictly positive scores count: a zero score means
//! "not occluded" and a negative one lies behind the mirror lobe, so j is skipped when no
//! direction scores above 0 (no occluded direction with a hit). Ties go to the lowest k. Then
//! `L_rc = mean_{j, c} | L1b_{j,k_j,c} - rho stopgrad(L_{j,k_j,c}) |` with L1b the gather of Eqn 13
//! (`svgir_trace::gather_pairs`, the same shading as the rendering equation, 9.3).
//!
//! Gradients: `sign(d)/(3 count)` on L1b, pushed through `svgir_trace::gather_pairs_backward` to
//! the *hit* Gaussians' albedo, roughness and shading normals and the env radiance texels, and
//! `-sum sign(d) L/(3 count)` to rho. The selection depends only on frozen geometry and V.
//! Work split: rayon over Gaussians for the selection, the gather parallelises over pairs; the
//! forward saves the pairs and both radiances for backward. Training calls
//! [`radiance_consistency_with_grad`], which runs both in one pass over the pairs.

use crate::grads::PbrGrads;
use crate::{expect_len, PbrError};
use glam::Vec3;
use rayon::prelude::*;
use svgir_core::EnvMap;
use svgir_shading::hemisphere::{FibTable, HemiFrame};
use svgir_shading::Float;
use svgir_trace::{
    gather_pairs, gather_pairs_backward, gather_pairs_with_backward, GatherGrads, GatherParams, MicroBuffer,
    VertexMaterials,
};

/// Everything the radiance-consistency loss reads (SPEC 6, Eqn 14/16).
#[derive(Clone, Copy, Debug)]
pub struct ConsistencyInputs<'a> {
    /// Frozen micro-buffers: directions, visibility, hits and traced radiance per Gaussian.
    pub mb: &'a MicroBuffer,
    /// Gaussian centres, N.
    pub positions: &'a [Vec3],
    /// Camera centre in world space; view rays run from it to each Gaussian.
    pub camera_center: Vec3,
    /// Gaussians that take part (the rasteriser's visibility for the current view), N.
    pub visible: &'a [bool],
    /// Activated vertex materials of all Gaussians (the hit Gaussians' are read).
    pub mats: VertexMaterials<'a, f32>,
    /// Environment radiance (clamped to `params.env_max` inside the gather).
    pub env: &'a EnvMap,
    /// Indirect scale rho applied to the traced radiance (SPEC 6).
    pub rho: f32,
    /// Settings of the one-bounce gather that computes L1b (Eqn 13).
    pub params: GatherParams<'a>,
}

/// Forward results, saved for [`radiance_consistency_backward`].
#[derive(Clone, Debug, PartialEq)]
pub struct Consistency {
    /// `L_rc`: mean absolute difference over selected pairs and channels (0 when none is selected).
    pub loss: f32,
    /// Selected (j, k_j).
    pub pairs: Vec<(u32, u32)>,
    /// L1b per pair.
    pub l1b: Vec<[f32; 3]>,
    /// Traced radiance L per pair.
    pub traced: Vec<[f32; 3]>,
}

/// `k_j` for Gaussian j seen along the unit view ray `view` (camera -> p_j), if any.
pub fn mirror_pick(mb: &MicroBuffer, j: usize, view: Vec3) -> Option<u32> {
    mirror_pick_with(mb, &mb.table(), j, view)
}

/// [`mirror_pick`] with the micro-buffer's Fibonacci table built once by the caller. The
/// directions are the table rotated into j's frame (`MicroBuffer::direction` up to f32
/// rounding, without a sine, cosine and remainder each), as the vertex shading uses them.
fn mirror_pick_with(mb: &MicroBuffer, table: &FibTable, j: usize, view: Vec3) -> Option<u32> {
    let n = mb.normals[j];
    let r = view - 2.0 * n.dot(view) * n;
    let frame = HemiFrame::new(n, mb.xi[j]);
    let mut best: Option<(u32, f32)> = None;
    for k in 0..mb.k {
        if mb.hit(j, k).is_none() {
            continue;
        }
        let score = frame.dir(table, k).dot(r) * (1.0 - mb.visibility(j, k));
        if score > 0.0 && best.is_none_or(|(_, b)| score > b) {
            best = Some((k as u32, score));
        }
    }
    best.map(|(k, _)| k)
}

/// The (j, k_j) pairs of all visible Gaussians that have one, in increasing j.
pub fn select_pairs(mb: &MicroBuffer, positions: &[Vec3], camera_center: Vec3, visible: &[bool]) -> Vec<(u32, u32)> {
    let n = mb.len().min(positions.len()).min(visible.len());
    let table = mb.table();
    (0..n)
        .into_par_iter()
        .with_min_len(256)
        .filter_map(|j| {
            if !visible[j] {
                return None;
            }
            let view = (positions[j] - camera_center).normalize_or_zero();
            mirror_pick_with(mb, &table, j, view).map(|k| (j as u32, k))
        })
        .collect()
}

/// The L1 part: `mean |l1b - rho traced|` over pairs and channels, with its gradients w.r.t.
/// each l1b and rho (`sign(0) = 0`). Generic so the tests check it in f64.
pub fn l1_loss<F: Float>(l1b: &[[F; 3]], traced: &[[F; 3]], rho: F) -> (F, Vec<[F; 3]>, F) {
    let count = l1b.len().min(traced.len());
    if count == 0 {
        return (F::ZERO, vec![[F::ZERO; 3]; l1b.len()], F::ZERO);
    }
    let inv = inv_channels::<F>(count);
    let mut loss = F::ZERO;
    let mut v_rho = F::ZERO;
    let mut v_l1b = vec![[F::ZERO; 3]; l1b.len()];
    for i in 0..count {
        for c in 0..3 {
            let d = l1b[i][c] - rho * traced[i][c];
            loss += d.abs();
            let s = sign(d);
            v_l1b[i][c] = s * inv;
            v_rho -= s * inv * traced[i][c];
        }
    }
    (loss * inv, v_l1b, v_rho)
}

/// `1 / (3 count)`, the mean's factor over `count` pairs' channels.
fn inv_channels<F: Float>(count: usize) -> F {
    F::ONE / F::from_f64((3 * count) as f64)
}

/// The traced radiance L of each pair.
pub fn traced_of(mb: &MicroBuffer, pairs: &[(u32, u32)]) -> Vec<[f32; 3]> {
    pairs.iter().map(|&(j, k)| mb.radiance(j as usize, k as usize)).collect()
}

/// The gather's gradients with rho's beside them, each times `v_loss` but the gather's (whose
/// upstream already carries it).
pub fn pbr_grads(g: GatherGrads, v_rho: f32, v_loss: f32) -> PbrGrads {
    PbrGrads {
        v_albedo: g.v_albedo,
        v_roughness: g.v_roughness,
        v_normals: g.v_normals,
        v_env: g.v_env,
        v_rho: v_rho * v_loss,
    }
}

/// +1, -1, or 0 for zero and NaN.
fn sign<F: Float>(d: F) -> F {
    if d > F::ZERO {
        F::ONE
    } else if d < F::ZERO {
        -F::ONE
    } else {
        F::ZERO
    }
}

/// The input checks of every consistency call (the CPU's and a backend's): the materials and
/// the per-Gaussian arrays sized for the micro-buffer's N.
pub fn check_inputs(inp: &ConsistencyInputs) -> Result<(), PbrError> {
    let n = inp.mb.len();
    inp.mats.validate(n)?;
    expect_len("positions", inp.positions.len(), n)?;
    expect_len("visible", inp.visible.len(), n)
}

/// Select the pairs, gather L1b and evaluate `L_rc`.
pub fn radiance_consistency(inp: &ConsistencyInputs) -> Result<Consistency, PbrError> {
    check_inputs(inp)?;
    let pairs = select_pairs(inp.mb, inp.positions, inp.camera_center, inp.visible);
    let l1b = gather_pairs(inp.mb, &inp.mats, inp.env, &inp.params, &pairs)?;
    let traced = traced_of(inp.mb, &pairs);
    let (loss, _, _) = l1_loss(&l1b, &traced, inp.rho);
    Ok(Consistency { loss, pairs, l1b, traced })
}

/// [`radiance_consistency`] and the gradients of `v_loss * L_rc`
/// ([`radiance_consistency_backward`]) in one pass over the pairs: a pair's gradient needs only
/// its own L1b, so its hit's escape list is filled once for both (`gather_pairs_with_backward`).
/// The same values and gradients, bit for bit.
pub fn radiance_consistency_with_grad(
    inp: &ConsistencyInputs,
    v_loss: f32,
) -> Result<(Consistency, PbrGrads), PbrError> {
    check_inputs(inp)?;
    let pairs = select_pairs(inp.mb, inp.positions, inp.camera_center, inp.visible);
    let traced = traced_of(inp.mb, &pairs);
    // `l1_loss`'s gradient per pair, times `v_loss`, in its operations.
    let inv = inv_channels::<f32>(pairs.len());
    let rho = inp.rho;
    let upstream = |i: usize, l1b: [f32; 3]| {
        let t = traced[i];
        [0, 1, 2].map(|c| sign(l1b[c] - rho * t[c]) * inv * v_loss)
    };
    let (l1b, g) = gather_pairs_with_backward(inp.mb, &inp.mats, inp.env, &inp.params, &pairs, upstream)?;
    let (loss, _, v_rho) = l1_loss(&l1b, &traced, rho);
    Ok((Consistency { loss, pairs, l1b, traced }, pbr_grads(g, v_rho, v_loss)))
}

/// Gradients of `v_loss * L_rc` (the same inputs as the forward that produced `fwd`).
pub fn radiance_consistency_backward(
    inp: &ConsistencyInputs,
    fwd: &Consistency,
    v_loss: f32,
) -> Result<PbrGrads, PbrError> {
    check_inputs(inp)?;
    expect_len("saved L1b", fwd.l1b.len(), fwd.pairs.len())?;
    expect_len("saved traced radiance", fwd.traced.len(), fwd.pairs.len())?;
    let (_, mut v_l1b, v_rho) = l1_loss(&fwd.l1b, &fwd.traced, inp.rho);
    for g in v_l1b.iter_mut() {
        *g = g.map(|x| x * v_loss);
    }
    let g = gather_pairs_backward(inp.mb, &inp.mats, inp.env, &inp.params, &fwd.pairs, &v_l1b)?;
    Ok(pbr_grads(g, v_rho, v_loss))
}
