//! svgir-pbr: the physically-based shading of SVG-IR stage 2.
//!
//! - [`material`]: spatially-varying Gaussian materials, M vertices per surfel (SPEC 3).
//! - [`env`](mod@env): the learnable lat-long environment light (SPEC 4).
//! - [`env_colour`]: holding that light grey or its colour smooth (our option).
//! - [`shade`](mod@shade) / [`shade_backward`](mod@shade_backward): the per-vertex rendering
//!   equation with visibility and indirect light from the micro-buffers (SPEC 4, 5) and its
//!   gradients.
//! - [`two_sided`]: shading each Gaussian on the side its camera sees (our option).
//! - [`shader`]: where the shading runs (the CPU kernels, or a device backend's).
//! - [`DirectionCache`] (from `svgir_trace`): the frozen micro-buffer directions' env-map
//!   lookups, computed once per stage 2 (`shade_into_cached` / `shade_backward_cached`;
//!   bit-identical, ~8 B / sample).
//! - [`consistency`]: the radiance consistency loss (SPEC 6, Eqn 14/16; 9.3, 9.6).
//! - [`grads`]: the gradient bundle shared by shading and consistency.
//! - [`activation`]: sigmoid / softplus, generic so the f64 instantiation is the test oracle.
//! - [`bench`](mod@bench): the timing table behind `svgir bench`.
//!
//! A stage-2 step, in order: `act = materials.activated(&mb.normals)`, `env = light.radiance()`;
//! `shade_into(&ShadeInputs { mats: act.view(), env_geom: &env, env: &env.data,
//! indirect: Indirect::Traced { rho }, .. }, &mut out)`; splat `out.color` (rasteriser);
//! `g = shade_backward(&inputs, &v_color)`; `rc = radiance_consistency(..)`, `g.add_scaled(
//! &radiance_consistency_backward(.., &rc, 1.0)?, 0.05)`; then `materials.backward(&mb.normals,
//! &g.v_albedo, &g.v_roughness, &g.v_normals)` and `light.backward(&g.v_env)` give the raw
//! gradients, `g.v_rho` the one of rho.
//!
//! Kernels are generic over `svgir_shading::Float` (f32 in production, f64 in the gradient
//! checks). This crate does no I/O and prints nothing.

#![warn(missing_docs)]
// The lane kernels (AVX2 / AVX-512) and their helpers are compiled for x86-64 only; on other
// targets the generic kernels run and those helpers go unused. Dead code is still caught by the
// x86-64 build, which CI lints.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code, unused_variables, unused_mut))]

pub mod activation;
/// Timing tables for `svgir bench` (feature `bench`).
#[cfg(feature = "bench")]
pub mod bench;
pub mod consistency;
pub mod env;
pub mod env_colour;
pub mod fixtures;
pub mod grads;
pub mod material;
#[cfg(target_arch = "x86_64")]
mod sample_lanes;
pub mod shade;
pub mod shade_backward;
#[cfg(target_arch = "x86_64")]
mod shade_simd;
pub mod shader;
pub mod two_sided;

pub use consistency::{
    check_inputs, l1_loss, mirror_pick, pbr_grads, radiance_consistency, radiance_consistency_backward,
    radiance_consistency_with_grad, select_pairs, traced_of, Consistency, ConsistencyInputs,
};
pub use env::{env_radiance, env_radiance_backward, EnvActivation, EnvLight, ENV_HEIGHT};
pub use env_colour::ColourProjector;
pub use grads::PbrGrads;
pub use material::{activate, activate_backward, ActivatedMaterials, MaterialGrads, SvgMaterials};
pub use shade::{shade, shade_into, shade_into_cached, Indirect, ShadeInputs, ShadeOutput, ShadeParams, ENV_MAX};
pub use shade_backward::{shade_backward, shade_backward_cached};
pub use shader::{check_sides, expect_sizes, CpuShader, VertexShader};
pub use svgir_core::Float;
pub use svgir_trace::DirectionCache;
pub use two_sided::{
    faces, negated, shade_sides_backward, shade_sides_backward_into, shade_sides_into, split_by_side, Side,
};

/// Everything the stage-2 shading can reject: bad parameters, mismatched array sizes, tracer errors.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PbrError {
    /// A parameter out of its domain (e.g. M not in {1, 2, 4, 6}, K = 0); the message says which.
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
    /// An error of the tracer (micro-buffers, gather).
    #[error(transparent)]
    Trace(#[from] svgir_trace::TraceError),
    /// A device backend failed (the GPU's error, in words).
    #[error("device: {0}")]
    Device(String),
}

/// `Err(SizeMismatch)` unless `got == want`.
pub(crate) fn expect_len(what: &'static str, got: usize, want: usize) -> Result<(), PbrError> {
    if got == want {
        Ok(())
    } else {
        Err(PbrError::SizeMismatch { what, got, want })
    }
}
