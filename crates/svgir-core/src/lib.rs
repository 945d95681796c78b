//! svgir-core: the types every other svgir crate shares.
//!
//! Conventions (used everywhere in svgir):
//! - World space is right-handed; the synthetic scenes use Blender's frame (+Z up).
//! - Camera space is OpenCV's: +x right, +y down, +z forward (looking along +z).
//! - Pixel (i, j) covers the square [i, i+1) x [j, j+1); its centre is (i + 0.5, j + 0.5).
//!   A camera-space point (X, Y, Z) lands at `(fx X/Z + cx, fy Y/Z + cy)`.
//! - Images are row-major, interleaved channels, `f32`, linear unless a name says sRGB.
//!
//! This crate does no I/O and prints nothing.

#![warn(missing_docs)]

pub mod camera;
pub mod color;
pub mod dataset;
pub mod envmap;
pub mod float;
pub mod image;
pub mod morton;
pub mod par;
pub mod rng;
pub mod sh;
pub mod simd;
pub mod surfel;

pub use camera::{Camera, CameraError, Intrinsics};
pub use dataset::{Dataset, LightInfo, MaskSource, PointCloud, View};
pub use envmap::EnvMap;
pub use float::Float;
pub use image::Image;
pub use rng::Rng;
pub use sh::ShCoeffs;
pub use surfel::Surfels;
