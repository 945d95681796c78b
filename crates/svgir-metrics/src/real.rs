//! `Real`: the float operations the metric kernels need, so the same code runs in f32 (training,
//! evaluation) and f64 (finite-difference checks of hand-written gradients). It is the shared
//! [`svgir_core::Float`] plus summation and `max`/`min` under the names the kernels use.

use std::iter::Sum;
use svgir_core::Float;

/// A float type the metric kernels run in: f32 for evaluation and training, f64 for gradient checks.
pub trait Real: Float + Default + Sum {
    /// The larger of two values (`Float::maxf`).
    #[inline]
    fn max(self, other: Self) -> Self {
        self.maxf(other)
    }

    /// The smaller of two values (`Float::minf`).
    #[inline]
    fn min(self, other: Self) -> Self {
        self.minf(other)
    }
}

impl Real for f32 {}
impl Real for f64 {}
