//! svgir-trace: ray tracing Gaussian surfels (SPEC 5).
//!
//! - [`bright`]: the brightest env texels as directional lights with traced visibility.
//! - [`bvh`]: binned-SAH BVH over the surfels' 3-sigma disks, flat 32-byte nodes.
//! - [`hit`]: the ray-disk test (plane crossing, 3-sigma ellipse, alpha rules).
//! - [`traverse`]: all hits front to back in (t, id) order and the transmittance march (Eqn 12).
//! - [`microbuffer`]: per-Gaussian K-direction visibility / radiance / first-hit buffers.
//! - [`tracer`]: where micro-buffers are traced (this crate's CPU march, or a device's).
//! - [`gather`] / [`gather_backward`]: the one-bounce indirect term (Eqn 13) and its gradients.
//! - [`reference`](mod@reference): brute-force tracer used by the tests.
//! - [`bench`](mod@bench): the timing table behind `svgir bench trace`.
//!
//! The maths is in `svgir-shading`; this crate does no I/O and prints nothing.

#![warn(missing_docs)]
// The lane kernels (AVX2 / AVX-512) and their helpers are compiled for x86-64 only; on other
// targets the generic kernels run and those helpers go unused. Dead code is still caught by the
// x86-64 build, which CI lints.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_variables, unused_mut))]

/// Timing tables for `svgir bench` (feature `bench`).
#[cfg(feature = "bench")]
pub mod bench;
pub mod bounce;
pub mod bright;
pub mod bvh;
pub mod direction_cache;
pub mod gather;
pub mod gather_backward;
mod gather_lanes;
pub mod hit;
pub mod microbuffer;
pub mod pack;
pub mod reference;
pub mod scenes;
pub mod surroundings_light;
pub mod tracer;
pub mod traverse;

pub use bounce::add_bounces;
pub use bright::{brightest_texels, concentrate_lobe, BrightLights, ColumnTracer, Via};
pub use bvh::{Bvh, Node};
pub use direction_cache::DirectionCache;
pub use gather::{
    gather_all, gather_from, gather_one, gather_pairs, gather_two_sided, GatherParams, HitSide, VertexMaterials,
};
pub use gather_backward::{
    gather_all_backward, gather_one_backward, gather_pairs_backward, gather_pairs_with_backward, GatherGrads,
};
pub use hit::{disks_of, Disk, Hit};
pub use microbuffer::{recorded_hit, Interleave, MicroBuffer, NO_HIT, SURROUNDINGS_HIT};
pub use reference::BruteForce;
pub use surroundings_light::{add_surroundings_light, LearnedIrradiance, SurroundingsGain};
pub use tracer::{CpuTracer, MicroTracer, TraceRequest};
pub use traverse::{hit_colour, march, march_visibility, HitSource, MarchResult, Occlusion, Ray, TraceParams, NO_ID};

/// Everything the tracer can reject: invalid surfels, bad parameters, mismatched array sizes.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TraceError {
    /// The surfels fail `Surfels::check` (array lengths, SH degree, non-finite values); the message says which.
    #[error("invalid surfels: {0}")]
    InvalidSurfels(String),
    /// A parameter out of its domain (e.g. K = 0, M not in {1, 2, 4, 6}).
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// An array has the wrong number of entries.
    #[error("size mismatch: {what} has {got} entries, expected {want}")]
    SizeMismatch {
        /// Which array.
        what: &'static str,
        /// Entries it has.
        got: usize,
        /// Entries it should have.
        want: usize,
    },
    /// A device backend failed (its message names the adapter and the cause).
    #[error("{0}")]
    Device(String),
}
