//! The instruction sets of the f32 tile kernels (modules `forward_simd`, `backward_simd`): AVX2
//! (8 lanes) and AVX-512F+VL (the same 8 lanes with compares into mask registers and 32 vector
//! registers; 16 lanes idled more and measured slower, docs/performance.md), each a
//! `#[target_feature]` compilation of one generic kernel over `svgir_core::simd::Lanes`, picked
//! once per call by [`Simd`] (`SVGIR_SIMD`). The generic scalar kernels stay the oracle and the
//! fallback (f64, other architectures, and the colour / feature paths the SIMD kernels do not
//! cover).
//!
//! The lane kernels use no FMA and evaluate every expression in the scalar kernels' order, so the
//! per-pixel evaluation and the forward compositing are bit-identical to the scalar path; only
//! sums over pixels (per-Gaussian gradients and accumulated weights) are summed lane-wise and
//! differ by rounding (tests bound the difference).

pub(crate) use svgir_core::simd::Lanes;
pub use svgir_core::simd::{best_available, cpu_features, is_f32, Simd};
#[cfg(target_arch = "x86_64")]
pub(crate) use svgir_core::simd::{F8k, F8};
