//! svgir-diagnose: research diagnostics of the svgir pipeline, one binary each, that compare our
//! surfel pipeline with a scene's ground truth (its mesh, its true light). They are how the
//! deliberate differences in `docs/method.md` were measured; `docs/diagnostics.md` gives each
//! command and what it showed.
//!
//! - `light_visibility`: traced visibility of the brightest texels of a map, per Gaussian.
//! - `microbuffer_stats`: how the traced micro-buffers' visibility is distributed.
//! - `sun_probe`: where the learned light puts its sun against the true one.
//! - `visibility_vs_mesh`: our surfel visibility against rays traced on the true mesh.
//! - `gt_shading`: SPEC 4's shading on the true mesh and materials, against the photos.
//! - `nerf_normals`: a stage-1 run's normals on the NeRF-synthetic test views, where their
//!   clipped normal pass still holds the true normal.
//!
//! Run one with `cargo run --release -p svgir-diagnose --bin NAME -- ARGS`.

#![warn(missing_docs)]

pub mod clipped_normals;
pub mod mesh;
