//! svgir's interactive relighting viewer (`svgir view`): a stage-2 model relit in real time in
//! a browser by precomputed radiance transfer (PRT), and a CPU oracle of exactly the page's
//! frame.
//!
//! - [`model`]: per surfel, geometry and M = 4 Gaussian vertices with materials and a transfer
//!   vector (visibility x cosine projected on SH, from the traced micro-buffers).
//! - [`light`]: the light's SH projection (rotated), its GGX-prefiltered chain and lookup, and
//!   the split-sum BRDF fit.
//! - [`shade`]: the per-vertex colour, diffuse from PRT plus prefiltered specular.
//! - [`oracle`]: sort, ray-splat intersection, blending and display as the page does them.
//! - [`mod@page`]: the self-contained HTML file (`web/viewer.html`, `light.js`, `hdr.js`, `viewer.js`).
//!
//! The maths here do no I/O: `svgir view` reads the run and writes the page.

#![warn(missing_docs)]

pub mod light;
pub mod model;
pub mod oracle;
pub mod page;
pub mod shade;

pub use model::{Options, VertexData, ViewError, ViewModel};
pub use oracle::{render, Frame, Orbit, View};
pub use page::{page, PageLight};
pub use shade::{Light, ViewMode};

/// Builds the viewer's model from a stage-2 model and micro-buffers traced over its surfels'
/// normals (e.g. [`svgir_train::relight::Relighter`]'s, K = 384), and over the negated normals
/// for a model trained two-sided; `bounce` adds the diffuse one-bounce term to the transfer.
pub fn model_from_stage2(
    s2: &svgir_train::stage2::Stage2,
    front: &svgir_trace::MicroBuffer,
    back: Option<&svgir_trace::MicroBuffer>,
    degree: u32,
    bounce: bool,
) -> Result<ViewModel, ViewError> {
    let act = s2.materials.activated(&s2.normals).map_err(|e| ViewError::Inconsistent(e.to_string()))?;
    let data = VertexData { albedo: &act.albedo, roughness: &act.roughness, normals: &act.normals };
    let layered = s2.config.diffuse == svgir_shading::Diffuse::Layered;
    ViewModel::build(&s2.surfels, &data, act.m, front, back, model::Options { degree, bounce, layered })
}
