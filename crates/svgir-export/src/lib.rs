//! svgir-export: relightable assets from a trained model, for other tools.
//!
//! The mesh path follows 2DGS's extraction: render depth from the training cameras, fuse it into
//! a truncated signed distance field ([`tsdf`]), extract the zero level set with surface nets
//! ([`isosurface`], the `fast-surface-nets` crate), keep the largest connected components and
//! simplify with `meshopt` ([`mesh`]), lay the triangles out in a texture atlas ([`atlas`]),
//! and bake the stage-2 materials of the Gaussians into base colour, metallic-roughness and a
//! tangent-space normal map ([`bake`]). [`gltf`] assembles a glTF 2.0 binary (`gltf-json`),
//! [`splats`] the 3DGS viewer PLY columns and a `KHR_gaussian_splatting` glTF, and
//! [`chamfer`] measures geometry against a reference mesh.
//!
//! Everything here is maths on memory except [`files`], which reads reference meshes and writes
//! finished byte buffers atomically (temp file + rename; a set of files is all written or none).

#![warn(missing_docs)]

pub mod atlas;
pub mod bake;
pub mod chamfer;
pub mod files;
pub mod gltf;
pub mod isosurface;
pub mod mesh;
pub mod splats;
pub mod tsdf;

pub use atlas::{build_atlas, AtlasMesh};
pub use bake::{bake_textures, BakedTextures, GaussianField};
pub use mesh::Mesh;
pub use tsdf::{fuse, DepthView, TsdfGrid, TsdfParams};

/// Why an export cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The mesh has no triangles or no area left (e.g. an empty model or a bad iso-level).
    #[error("degenerate mesh: {0}")]
    Degenerate(String),
    /// An input is inconsistent (lengths, non-finite values, bad settings).
    #[error("invalid input: {0}")]
    Invalid(String),
    /// Encoding a file's bytes failed.
    #[error("encoding {what}: {detail}")]
    Encode {
        /// The file kind being encoded (e.g. "GLB", "PNG").
        what: &'static str,
        /// The encoder's message.
        detail: String,
    },
    /// Reading or writing a file failed.
    #[error("{path}: {detail}")]
    File {
        /// The file that failed.
        path: String,
        /// What went wrong.
        detail: String,
    },
}
