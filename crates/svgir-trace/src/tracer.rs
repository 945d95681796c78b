//! Where micro-buffers are traced: [`CpuTracer`] marches this crate's BVH with rayon; a device
//! backend (svgir-gpu's `GpuTracer`) runs the same march in its kernels. Stage 2 and relighting
//! take a `&dyn MicroTracer`, so the choice of device is made once, by the front end, and
//! the crates below it never depend on a GPU crate.

use crate::bvh::Bvh;
use crate::gather::{GatherParams, HitSide, VertexMaterials};
use crate::microbuffer::MicroBuffer;
use crate::traverse::TraceParams;
use crate::TraceError;
use glam::Vec3;
use svgir_core::{EnvMap, Surfels};

/// What a micro-buffer trace is asked for (SPEC 5): K directions about one axis per Gaussian,
/// the seed of their azimuth offsets, the march's rules, and whether to trace radiance too.
#[derive(Clone, Debug)]
pub struct TraceRequest<'a> {
    /// Hemisphere axis per Gaussian: its normal, or `-n` for the back sides (two-sided
    /// shading). Moved into the micro-buffer.
    pub axes: Vec<Vec3>,
    /// Directions per Gaussian.
    pub k: usize,
    /// Fixes the per-Gaussian azimuth offsets (`svgir_shading::gaussian_xi`).
    pub seed: u64,
    /// The march's rules.
    pub params: &'a TraceParams,
    /// Trace the radiance L (stage 2's buffers), or the visibility alone (L = 0; relighting's,
    /// whose indirect light is the one-bounce gather under the new map).
    pub radiance: bool,
}

/// A backend that fills micro-buffers (SPEC 5).
pub trait MicroTracer: Send + Sync {
    /// A short name for logs: "cpu", or the adapter.
    fn name(&self) -> String;

    /// The micro-buffers `req` asks for, of every Gaussian of `surfels`, through `bvh` (built
    /// over the same surfels): [`MicroBuffer::traced`].
    fn trace(&self, bvh: &Bvh, surfels: &Surfels, req: TraceRequest) -> Result<MicroBuffer, TraceError>;

    /// For each of `dirs`, the visibility (u16 unorm) from every Gaussian of `surfels` through
    /// `bvh`: the visibility march from its centre, 0 where the direction is below its
    /// hemisphere about `normals` (the directional lights' columns, `crate::BrightLights`).
    fn visibility_columns(
        &self,
        bvh: &Bvh,
        surfels: &Surfels,
        normals: &[Vec3],
        dirs: &[Vec3],
        p: &TraceParams,
    ) -> Result<Vec<Vec<u16>>, TraceError>;

    /// Eqn 13 for every ray of `mb` ([`crate::gather_all`]; the CPU's unless a backend has its own).
    fn gather_all(
        &self,
        mb: &MicroBuffer,
        mats: &VertexMaterials<f32>,
        env: &EnvMap,
        p: &GatherParams,
    ) -> Result<Vec<[f32; 3]>, TraceError> {
        crate::gather_all(mb, mats, env, p)
    }

    /// Two-sided shading's Eqn 13 ([`crate::gather_two_sided`]; the CPU's unless a backend has
    /// its own).
    fn gather_two_sided(
        &self,
        rays: &MicroBuffer,
        front: HitSide,
        back: HitSide,
        env: &EnvMap,
        p: &GatherParams,
    ) -> Result<Vec<[f32; 3]>, TraceError> {
        crate::gather_two_sided(rays, front, back, env, p)
    }
}

/// The CPU march ([`MicroBuffer::trace_about`] on the BVH).
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuTracer;

impl MicroTracer for CpuTracer {
    fn name(&self) -> String {
        "cpu".into()
    }

    fn trace(&self, bvh: &Bvh, surfels: &Surfels, req: TraceRequest) -> Result<MicroBuffer, TraceError> {
        MicroBuffer::traced(bvh, surfels, req)
    }

    fn visibility_columns(
        &self,
        bvh: &Bvh,
        surfels: &Surfels,
        normals: &[Vec3],
        dirs: &[Vec3],
        p: &TraceParams,
    ) -> Result<Vec<Vec<u16>>, TraceError> {
        crate::bright::ColumnTracer::columns(bvh, surfels, normals, dirs, p)
    }
}
