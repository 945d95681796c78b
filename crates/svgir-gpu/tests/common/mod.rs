//! What the GPU tests share: the adapter they run on, and the rasterizer tests' checks (`oracle`).

use svgir_gpu::Gpu;

pub mod oracle;

/// The adapter the tests run on (`svgir_gpu::testing::test_adapter`).
pub fn gpu() -> Option<Gpu> {
    svgir_gpu::testing::test_adapter()
}
