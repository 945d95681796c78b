//! Where micro-buffers are traced: [`CpuTracer`] marches this crate's BVH with rayon; a device
//! backend (svgir-gpu's `GpuTracer`) runs the same march in its kernels. Stage 2 and relighting
//! take a `&dyn MicroTracer`, so the choice of device is made once, by the front end, and
//! the crates below it never depend on a GPU crate.

use crate::bvh::Bvh;
use crate::microbuffer::MicroBuffer;
use crate::traverse::TraceParams;
use crate::TraceError;
use glam::Vec3;
use svgir_core::Surfels;

/// A backend that fills micro-buffers (SPEC 5).
pub trait MicroTracer: Send + Sync {
    /// A short name for logs: "cpu", or the adapter.
    fn name(&self) -> String;

    /// K directions about `normals` (one axis per Gaussian) for every Gaussian of `surfels`,
    /// through `bvh` (built over the same surfels): [`MicroBuffer::trace_about`] with
    /// `with_radiance`, else [`MicroBuffer::trace_occlusion_about`] (L = 0).
    #[allow(clippy::too_many_arguments)]
    fn trace(
        &self,
        bvh: &Bvh,
        surfels: &Surfels,
        normals: Vec<Vec3>,
        k: usize,
        seed: u64,
        p: &TraceParams,
        with_radiance: bool,
    ) -> Result<MicroBuffer, TraceError>;

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
}

/// The CPU march ([`MicroBuffer::trace_about`] on the BVH).
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuTracer;

impl MicroTracer for CpuTracer {
    fn name(&self) -> String {
        "cpu".into()
    }

    fn trace(
        &self,
        bvh: &Bvh,
        surfels: &Surfels,
        normals: Vec<Vec3>,
        k: usize,
        seed: u64,
        p: &TraceParams,
        with_radiance: bool,
    ) -> Result<MicroBuffer, TraceError> {
        if with_radiance {
            MicroBuffer::trace_about(bvh, surfels, normals, k, seed, p)
        } else {
            MicroBuffer::trace_occlusion_about(bvh, surfels, normals, k, seed, p)
        }
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
