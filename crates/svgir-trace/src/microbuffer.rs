//! Micro-buffers (SPEC 5): for every Gaussian j and each of its K Fibonacci hemisphere directions
//! w_k, the result of marching a ray from the centre p_j along w_k (ignoring j's own disk):
//! visibility V (T_final, 0 below 0.2), traced radiance L (clamped to [0, 10]), first-hit index I
//! and first-hit tangent coordinates U = (u~, v~) (SPEC 3 / 9.1).
//!
//! Layout, structure of arrays indexed `j * K + k`, 16 bytes per sample:
//! - directions: not stored. They are `hemisphere_dir(n_j, k, K, xi_j)` (svgir-shading) from the
//!   stored geometric normal and per-Gaussian `xi_j = gaussian_xi(seed, j)` (8 + 4 bytes per
//!   *Gaussian*), which saves 12 bytes per sample and guarantees the shading and gather see the
//!   same directions as the tracer.
//! - V: u16 unorm (2 B; step 1.5e-5, far below the Monte-Carlo noise of K = 64).
//! - L: 3 x IEEE f16 (6 B; relative error <= 2^-11 over [6e-5, 10]).
//! - I: u32, [`NO_HIT`] = none (4 B).
//! - U: 2 x u16 unorm (4 B; step 1.5e-5 on [0.001, 0.999]). When I is [`SURROUNDINGS_HIT`], U
//!   holds instead which of the surroundings the ray ended on (its index's low and high 16 bits):
//!   no gather reads that hit's coordinates, and relighting needs its colour and normal.
//!
//! So 300k Gaussians x K = 64 take 307 MB (x K = 384: 1.8 GB; relighting may fill per chunk).
//! Separate arrays let each consumer stream only what it reads (shading: V, L; gather: I, U).
//! Relighting's buffers ([`MicroBuffer::trace_occlusion_about`]) skip L: their rays march for V
//! and the first hit alone, and L stays 0.
//!
//! Work split: rayon over Gaussians (each task owns its K contiguous samples in every array), so
//! the fill is race-free and, the march being deterministic, bit-identical for any thread count.

use crate::pack::{f16_from_f32, f16_to_f32, from_unorm16, unorm16};
use crate::tracer::TraceRequest;
use crate::traverse::{march, march_visibility, HitSource, Ray, TraceParams};
use crate::TraceError;
use glam::Vec3;
use rayon::prelude::*;
use svgir_core::Surfels;
use svgir_shading::hemisphere::FibTable;
use svgir_shading::{gaussian_xi, hemisphere_dir};

/// First-hit index meaning "the ray escaped".
pub const NO_HIT: u32 = u32::MAX;

/// First-hit index meaning "the ray hit the surroundings": a Gaussian traced as an occluder
/// (and a source of traced radiance) that has no micro-buffer or material of its own, such as
/// the rest of a captured scene around the object (issue 75, SPEC 5: the micro-buffers see
/// every Gaussian). V and L are as traced; no bounce is gathered off it, and it is no escape.
pub const SURROUNDINGS_HIT: u32 = u32::MAX - 1;

/// Micro-buffers of all Gaussians (SPEC 5): K traced directions each, samples indexed `j * K + k`.
#[derive(Clone, Debug, PartialEq)]
pub struct MicroBuffer {
    /// Directions per Gaussian (K).
    pub k: usize,
    /// Geometric normal per Gaussian (the hemisphere axis).
    pub normals: Vec<Vec3>,
    /// Azimuth offset per Gaussian.
    pub xi: Vec<f32>,
    /// Visibility V per sample, u16 unorm.
    pub vis: Vec<u16>,
    /// Traced radiance L per sample, 3 x IEEE f16 bits.
    pub radiance: Vec<[u16; 3]>,
    /// First-hit Gaussian per sample, [`NO_HIT`] when the ray escaped.
    pub first_hit: Vec<u32>,
    /// First-hit tangent coordinates (u~, v~) per sample, 2 x u16 unorm.
    pub uv: Vec<[u16; 2]>,
    /// Which Fibonacci directions the K samples are: all of them, or one interleaved subset of
    /// a larger set ([`MicroBuffer::interleaved`]).
    pub interleave: Interleave,
}

/// Sample k of a micro-buffer is direction `phase + stride * k` of the `stride * K` Fibonacci
/// directions (SPEC 4). `stride = 1, phase = 0` (the default): the K directions themselves.
///
/// Stage 2 may shade one of the `stride` subsets per iteration in turn: each is spread over the
/// whole hemisphere, weighs `2pi / (K / stride)` per sample, and the mean of the `stride`
/// subsets' estimates is the full K-direction sum of SPEC 4 (`svgir_pbr` tests this).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Interleave {
    /// Subsets the full set is cut into.
    pub stride: usize,
    /// Which subset, `0..stride`.
    pub phase: usize,
}

impl Default for Interleave {
    fn default() -> Self {
        Self { stride: 1, phase: 0 }
    }
}

impl Interleave {
    /// Where the samples of this subset, `k` per Gaussian for `n` Gaussians, sit in the whole
    /// set's arrays of `stride * k` samples per Gaussian, in the subset's order.
    pub fn whole_indices(self, n: usize, k: usize) -> impl Iterator<Item = usize> {
        let whole = k * self.stride;
        (0..n).flat_map(move |j| (0..k).map(move |s| j * whole + self.phase + self.stride * s))
    }
}

/// A traced hit on Gaussian `id` at packed (u~, v~) as a micro-buffer of the first `sources`
/// Gaussians records it (I, U): its own index and coordinates, or [`SURROUNDINGS_HIT`] and the
/// surroundings' index `id - sources` split into 16-bit halves. Every tracer maps its hits so.
pub fn recorded_hit(id: u32, uv: [u16; 2], sources: usize) -> (u32, [u16; 2]) {
    match id.checked_sub(sources as u32) {
        Some(s) if id != NO_HIT => (SURROUNDINGS_HIT, [(s & 0xffff) as u16, (s >> 16) as u16]),
        _ => (id, uv),
    }
}

impl MicroBuffer {
    /// Bytes per (Gaussian, direction) sample.
    pub const BYTES_PER_SAMPLE: usize = 2 + 6 + 4 + 4;

    /// Trace K directions for every Gaussian through `src` (normally the [`crate::Bvh`] of the
    /// same surfels). `seed` fixes the per-Gaussian azimuth offsets.
    pub fn trace<S: HitSource>(
        src: &S,
        surfels: &Surfels,
        k: usize,
        seed: u64,
        p: &TraceParams,
    ) -> Result<Self, TraceError> {
        let normals = (0..surfels.len()).map(|j| surfels.normal(j)).collect();
        Self::trace_about(src, surfels, normals, k, seed, p)
    }

    /// [`MicroBuffer::trace`] over the hemispheres of the given axes (one per Gaussian) instead
    /// of the surfels' normals; `-n` gives each Gaussian's back side (two-sided shading). The
    /// rays still start from, and ignore, the Gaussian's own disk, and the hits' (u~, v~) are
    /// in the hit Gaussians' own frames.
    pub fn trace_about<S: HitSource>(
        src: &S,
        surfels: &Surfels,
        normals: Vec<Vec3>,
        k: usize,
        seed: u64,
        p: &TraceParams,
    ) -> Result<Self, TraceError> {
        Self::traced(src, surfels, TraceRequest { axes: normals, k, seed, params: p, radiance: true })
    }

    /// [`Self::trace_about`] without the traced radiance: V, I and U to the bit (each ray is
    /// [`march_visibility`], which also stops once V is certain to be 0), L left at 0. For
    /// relighting, whose indirect light is the one-bounce gather under the new map (SPEC 7)
    /// and never reads L.
    pub fn trace_occlusion_about<S: HitSource>(
        src: &S,
        surfels: &Surfels,
        normals: Vec<Vec3>,
        k: usize,
        seed: u64,
        p: &TraceParams,
    ) -> Result<Self, TraceError> {
        Self::traced(src, surfels, TraceRequest { axes: normals, k, seed, params: p, radiance: false })
    }

    /// The micro-buffers `req` asks for, traced through `src` on the CPU (rayon over Gaussians):
    /// rays from the first `req.axes.len()` Gaussians of `surfels`; hits on the others (the
    /// surroundings) are recorded as [`SURROUNDINGS_HIT`] with their index ([`recorded_hit`]).
    pub fn traced<S: HitSource>(src: &S, surfels: &Surfels, req: TraceRequest) -> Result<Self, TraceError> {
        let TraceRequest { axes: normals, k, seed, params: p, radiance: with_radiance } = req;
        Self::check_inputs(surfels, &normals, k)?;
        let n = normals.len();
        let xi: Vec<f32> = (0..n).map(|j| gaussian_xi(seed, j)).collect();
        let mut vis = vec![0u16; n * k];
        let mut radiance = vec![[0u16; 3]; n * k];
        let mut first_hit = vec![NO_HIT; n * k];
        let mut uv = vec![[0u16; 2]; n * k];
        vis.par_chunks_mut(k)
            .zip(radiance.par_chunks_mut(k))
            .zip(first_hit.par_chunks_mut(k))
            .zip(uv.par_chunks_mut(k))
            .enumerate()
            .for_each(|(j, (((v, l), i), u))| {
                let ray0 = Ray::from_gaussian(surfels, j, Vec3::Z, p);
                for kk in 0..k {
                    let ray = Ray { dir: hemisphere_dir(normals[j], kk, k, xi[j]), ..ray0 };
                    let (visibility, first) = if with_radiance {
                        let r = march(src, &surfels.sh, surfels.sh_degree, &ray, p);
                        l[kk] = r.radiance.map(f16_from_f32);
                        (r.visibility, r.first)
                    } else {
                        let o = march_visibility(src, &ray, p);
                        (o.visibility, o.first)
                    };
                    v[kk] = unorm16(visibility);
                    if let Some(h) = first {
                        (i[kk], u[kk]) = recorded_hit(h.id, h.uv_normalised().map(unorm16), n);
                    }
                }
            });
        Ok(Self { k, normals, xi, vis, radiance, first_hit, uv, interleave: Interleave::default() })
    }

    /// What every tracer of micro-buffers (this crate's, a device's) requires of its inputs:
    /// valid surfels, one finite hemisphere axis per ray source (the first `normals.len()`
    /// Gaussians; the rest are surroundings), K > 0 and indices that fit u32.
    pub fn check_inputs(surfels: &Surfels, normals: &[Vec3], k: usize) -> Result<(), TraceError> {
        surfels.check().map_err(TraceError::InvalidSurfels)?;
        if normals.len() > surfels.len() || normals.iter().any(|n| !n.is_finite()) {
            return Err(TraceError::InvalidParameter(format!(
                "{} hemisphere axes for {} Gaussians, or not finite",
                normals.len(),
                surfels.len()
            )));
        }
        if k == 0 {
            return Err(TraceError::InvalidParameter("K must be positive".into()));
        }
        if surfels.len() >= SURROUNDINGS_HIT as usize {
            return Err(TraceError::InvalidParameter("too many Gaussians for u32 indices".into()));
        }
        Ok(())
    }

    /// The samples of directions `phase, phase + stride, ..` (copied): a micro-buffer of
    /// `K / stride` directions that shade, gather and cache like any other. `self` must hold a
    /// whole set whose K `stride` divides.
    pub fn interleaved(&self, stride: usize, phase: usize) -> Result<Self, TraceError> {
        if self.interleave != Interleave::default() {
            return Err(TraceError::InvalidParameter("micro-buffer is already an interleaved subset".into()));
        }
        if stride == 0 || phase >= stride || !self.k.is_multiple_of(stride) {
            return Err(TraceError::InvalidParameter(format!(
                "interleaved subset {phase} of {stride}: the stride must divide K = {} and the phase be below it",
                self.k
            )));
        }
        let interleave = Interleave { stride, phase };
        let k = self.k / stride;
        let rows = || interleave.whole_indices(self.len(), k);
        Ok(Self {
            k,
            normals: self.normals.clone(),
            xi: self.xi.clone(),
            vis: rows().map(|s| self.vis[s]).collect(),
            radiance: rows().map(|s| self.radiance[s]).collect(),
            first_hit: rows().map(|s| self.first_hit[s]).collect(),
            uv: rows().map(|s| self.uv[s]).collect(),
            interleave,
        })
    }

    /// The Fibonacci table of this buffer's K samples (its interleaved rows for a subset).
    pub fn table(&self) -> FibTable {
        FibTable::interleaved(self.k * self.interleave.stride, self.interleave.stride, self.interleave.phase)
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.normals.len()
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.normals.is_empty()
    }

    /// Unit world direction w_k of sample (j, k), recomputed from the normal and xi (SPEC 5).
    pub fn direction(&self, j: usize, k: usize) -> Vec3 {
        let Interleave { stride, phase } = self.interleave;
        hemisphere_dir(self.normals[j], phase + stride * k, self.k * stride, self.xi[j])
    }

    /// Visibility V of sample (j, k) in [0, 1].
    pub fn visibility(&self, j: usize, k: usize) -> f32 {
        from_unorm16(self.vis[j * self.k + k])
    }

    /// Traced linear radiance L of sample (j, k), in [0, 10].
    pub fn radiance(&self, j: usize, k: usize) -> [f32; 3] {
        self.radiance[j * self.k + k].map(f16_to_f32)
    }

    /// First-hit Gaussian of this buffer, `None` if the ray escaped or hit the surroundings.
    pub fn hit(&self, j: usize, k: usize) -> Option<u32> {
        let h = self.first_hit[j * self.k + k];
        (h < SURROUNDINGS_HIT).then_some(h)
    }

    /// True when sample (j, k)'s ray hit nothing: the environment lights it (Eqn 13's escapes).
    pub fn escaped(&self, j: usize, k: usize) -> bool {
        self.first_hit[j * self.k + k] == NO_HIT
    }

    /// Which of the surroundings sample (j, k)'s ray ended on (its index among them), if any.
    pub fn surroundings_hit(&self, j: usize, k: usize) -> Option<u32> {
        let i = j * self.k + k;
        let [lo, hi] = self.uv[i];
        (self.first_hit[i] == SURROUNDINGS_HIT).then_some(u32::from(lo) | u32::from(hi) << 16)
    }

    /// Samples whose ray hit the surroundings ([`SURROUNDINGS_HIT`]).
    pub fn surroundings_hits(&self) -> usize {
        self.first_hit.iter().filter(|&&h| h == SURROUNDINGS_HIT).count()
    }

    /// First-hit (u~, v~); meaningless when there is no hit or it is on the surroundings.
    pub fn uv(&self, j: usize, k: usize) -> [f32; 2] {
        self.uv[j * self.k + k].map(from_unorm16)
    }

    /// Bytes held by the samples and the per-Gaussian normals and offsets.
    pub fn memory_bytes(&self) -> usize {
        self.vis.len() * Self::BYTES_PER_SAMPLE + self.len() * 16
    }
}
