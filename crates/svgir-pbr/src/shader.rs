//! Where the vertex shading runs: [`CpuShader`] is this crate's kernels
//! ([`crate::shade_sides_into`], rayon and the lane kernels); a device backend (svgir-gpu's
//! `GpuShader`) evaluates the same sums in its own kernels. Stage 2's renders take a
//! `&dyn VertexShader`, so the device is chosen once, by the front end, and the crates below
//! it never depend on a GPU crate (as `svgir_trace::MicroTracer` does for the tracing).

use crate::shade::{ShadeOutput, SideRef};
use crate::two_sided::Side;
use crate::{Consistency, ConsistencyInputs, PbrError, PbrGrads};

/// A backend that shades every visible Gaussian's vertices (SPEC 4, with SPEC 5's visibility
/// and indirect light), one side or two.
pub trait VertexShader: Send + Sync {
    /// A short name for logs: "cpu", or the adapter.
    fn name(&self) -> String;

    /// [`crate::shade_sides_into`]: each Gaussian shaded on the side whose `visible` holds it
    /// (the sides' sets disjoint), the others 0; `out.split` asks for the direct and indirect
    /// parts too.
    fn shade_sides(&self, front: &Side<f32>, back: Option<&Side<f32>>, out: &mut ShadeOutput) -> Result<(), PbrError>;

    /// [`crate::shade_sides_backward_into`]: the gradients of `sum v_color . c` added into
    /// `grads` (sized for the sides' N, M and map).
    fn shade_sides_backward(
        &self,
        front: &Side<f32>,
        back: Option<&Side<f32>>,
        v_color: &[f32],
        grads: &mut PbrGrads,
    ) -> Result<(), PbrError>;

    /// [`crate::radiance_consistency_with_grad`]: L_rc (SPEC 6, Eqn 14/16) and the gradients of
    /// `v_loss * L_rc` (the CPU's unless a backend has its own).
    fn consistency_with_grad(&self, inp: &ConsistencyInputs, v_loss: f32) -> Result<(Consistency, PbrGrads), PbrError> {
        crate::radiance_consistency_with_grad(inp, v_loss)
    }
}

/// The CPU kernels.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuShader;

impl VertexShader for CpuShader {
    fn name(&self) -> String {
        "cpu".into()
    }

    fn shade_sides(&self, front: &Side<f32>, back: Option<&Side<f32>>, out: &mut ShadeOutput) -> Result<(), PbrError> {
        crate::shade_sides_into(front, back, out)
    }

    fn shade_sides_backward(
        &self,
        front: &Side<f32>,
        back: Option<&Side<f32>>,
        v_color: &[f32],
        grads: &mut PbrGrads,
    ) -> Result<(), PbrError> {
        crate::shade_sides_backward_into(front, back, v_color, grads)
    }
}

/// Every check [`crate::shade_sides_into`] makes before it shades: each side's inputs and
/// cache, the sides' sizes against each other, and that no Gaussian is on both sides. A device
/// backend calls it so that it rejects what the CPU rejects, with the same errors.
pub fn check_sides(front: &Side<f32>, back: Option<&Side<f32>>) -> Result<(), PbrError> {
    let sides: Vec<SideRef<f32>> = crate::two_sided::sides(front, back)?;
    crate::shade::check_sides(&sides)
}

/// `Err(SizeMismatch)` for the first `(what, got, want)` whose sizes differ: the checks of an
/// array's length, with the CPU kernels' messages, for a device backend.
pub fn expect_sizes(sizes: &[(&'static str, usize, usize)]) -> Result<(), PbrError> {
    sizes.iter().try_for_each(|&(what, got, want)| crate::expect_len(what, got, want))
}
