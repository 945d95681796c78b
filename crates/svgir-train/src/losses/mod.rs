//! Training losses with hand-written gradients. Each returns the loss value and accumulates
//! `weight * d loss / d input` so the rasterizer's backward receives per-pixel output gradients.
//! SSIM lives in `svgir-metrics`.

pub mod depth_normal;
pub mod l1;
pub mod mask;
pub mod objective;
pub mod smoothness;
