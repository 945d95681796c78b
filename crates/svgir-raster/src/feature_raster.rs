//! Where a feature render runs: stage 2's PBR pass and its evaluation renders composite
//! per-vertex feature tables over Gaussians whose geometry is frozen (SPEC 6). [`CpuFeatureRaster`]
//! is this crate's kernels ([`crate::try_render_reusing`], [`crate::backward()`]); a device
//! backend (svgir-gpu's `GpuFeatureRaster`) composites the same tables in its own kernels. The
//! trainer takes a `&dyn FeatureRaster`, so the device is chosen once, by the front end, and the
//! crates below it never depend on a GPU crate (as `svgir_pbr::VertexShader` does for the
//! shading).

use crate::{Grads, OutputGrads, Projected, RasterConfig, RasterError, RenderInput, RenderOutput};

/// What a backend's render keeps for its backward (the CPU's [`crate::ForwardState`], or a
/// device's buffers).
pub type PassState = Box<dyn std::any::Any + Send + Sync>;

/// A feature render's gradients.
#[derive(Clone, Debug)]
pub struct PassGrads {
    /// As [`crate::backward()`] returns them with `RasterConfig::geometry_grads` off: the
    /// opacity logits', the colour and extra tables', the background's; the geometry's zero.
    pub grads: Grads,
    /// Per Gaussian, the weight `alpha T` it composited over the view
    /// ([`RenderOutput::accum_weight`] on the CPU; a device sums it in its backward).
    pub accum_weight: Vec<f32>,
}

/// A backend that renders feature tables and their gradients for frozen geometry.
pub trait FeatureRaster: Send + Sync {
    /// A short name for logs: "cpu", or the adapter.
    fn name(&self) -> String;

    /// Renders `input` (colours from a feature table) with `cfg`; `prior` is a projection of
    /// the same Gaussians by the same camera (a backend may reuse it). The output's
    /// `accum_weight` may be empty: [`PassGrads::accum_weight`] holds it.
    fn render(
        &self,
        input: &RenderInput,
        cfg: &RasterConfig,
        prior: &Projected,
    ) -> Result<(RenderOutput, PassState), RasterError>;

    /// The gradients of a loss with output gradients `grads` for the render that made `state`
    /// and `out` from `input`. The geometry's gradients are zero whatever `cfg` says.
    fn backward(
        &self,
        input: &RenderInput,
        cfg: &RasterConfig,
        state: &PassState,
        out: &RenderOutput,
        grads: &OutputGrads,
    ) -> Result<PassGrads, RasterError>;
}

/// The CPU kernels.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuFeatureRaster;

impl FeatureRaster for CpuFeatureRaster {
    fn name(&self) -> String {
        "cpu".into()
    }

    /// Reuses `prior` when it can ([`crate::try_render_reusing`]: colours from several
    /// vertices), else renders its own projection (one vertex per Gaussian).
    fn render(
        &self,
        input: &RenderInput,
        cfg: &RasterConfig,
        prior: &Projected,
    ) -> Result<(RenderOutput, PassState), RasterError> {
        let (out, state) = match crate::try_render_reusing(input, cfg, prior) {
            Ok(r) => r,
            Err(RasterError::Reuse) => crate::try_render(input, cfg)?,
            Err(e) => return Err(e),
        };
        Ok((out, Box::new(state)))
    }

    fn backward(
        &self,
        input: &RenderInput,
        cfg: &RasterConfig,
        state: &PassState,
        out: &RenderOutput,
        grads: &OutputGrads,
    ) -> Result<PassGrads, RasterError> {
        let state = state.downcast_ref::<crate::ForwardState>().ok_or(RasterError::State)?;
        let cfg = RasterConfig { geometry_grads: false, ..*cfg };
        let grads = crate::backward(input, &cfg, state, out, grads);
        Ok(PassGrads { grads, accum_weight: out.accum_weight.clone() })
    }
}
