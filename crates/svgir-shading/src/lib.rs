//! svgir-shading: the physically-based shading pieces shared by the rasteriser, the tracer and
//! training (SPEC 3 and 4): the Cook-Torrance GGX BRDF with its gradients (also split per
//! vertex and per light direction, [`split`]), the Fibonacci
//! hemisphere directions and the Gaussian-vertex interpolation weights.
//!
//! Everything is generic over [`Float`] (f32 for speed, f64 so tests can check hand-written
//! gradients against finite differences). No I/O, no printing.

#![warn(missing_docs)]

pub mod brdf;
pub use svgir_core::float;
pub mod hemisphere;
pub mod layering;
#[cfg(test)]
mod quadrature;
pub mod split;
pub mod split_lanes;
pub mod vertex;

pub use brdf::{ggx, ggx_specular, ggx_specular_grad, SpecularGrad, DOT_EPS, F0};
pub use float::Float;
pub use hemisphere::{fibonacci_local, gaussian_xi, hemisphere_dir, tangent_frame, MIN_ELEVATION_SIN};
pub use layering::{Diffuse, DiffuseWeight};
pub use vertex::{vertex_weights, vertex_weights_grad, MAX_VERTICES};
