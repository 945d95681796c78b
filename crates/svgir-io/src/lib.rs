//! svgir-io: everything svgir reads and writes.
//!
//! - [`image_io`]: PNG / JPEG / HDR / EXR <-> [`svgir_core::Image`].
//! - [`envmap_io`]: equirectangular HDR files <-> [`svgir_core::EnvMap`].
//! - [`load_dataset`]: NeRF/Blender ([`nerf`]), TensoIR ([`tensoir`]), COLMAP ([`colmap`]) and
//!   nerfstudio `transforms.json` ([`transforms`]) layouts -> [`svgir_core::Dataset`], with
//!   foreground masks ([`mask`]) and [`dataset_summary`] for `svgir info`.
//! - [`ply`]: Gaussians in the 3DGS PLY layout, plain point clouds.
//!
//! Every error is an [`IoError`] naming the file and the problem; no input makes these
//! functions panic (fuzzed in `tests/fuzz.rs`).

#![warn(missing_docs)]

pub mod camera_model;
pub mod colmap;
pub mod envmap_io;
pub mod error;
pub mod exif;
pub mod image_io;
pub mod load;
pub mod mask;
pub mod nerf;
pub mod ply;
pub mod ply_format;
pub mod summary;
pub mod tensoir;
pub mod transforms;

pub use envmap_io::{read_envmap, write_envmap_hdr};
pub use error::{ErrorKind, IoError, Result};
pub use image_io::{read_image, write_exr, write_hdr, write_png};
pub use load::{detect_layout, load_dataset, Layout, LoadOptions};
pub use ply::{read_gaussians_ply, read_points_ply, write_gaussians_ply, write_points_ply};
pub use summary::dataset_summary;
