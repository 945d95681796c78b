//! What the GPU tests share: the adapter they run on, and the rasterizer tests' checks (`oracle`).

use svgir_gpu::Gpu;

pub mod oracle;

/// The adapter `SVGIR_GPU_ADAPTER` names, else Mesa's lavapipe; `None` (the test prints
/// SKIPPED) without one, a panic under `SVGIR_REQUIRE_GPU=1` (as `.ci/run` sets).
pub fn gpu() -> Option<Gpu> {
    let name = std::env::var(svgir_gpu::ADAPTER_ENV).unwrap_or_else(|_| "llvmpipe".into());
    match svgir_gpu::open_named(Some(&name)) {
        Ok(g) => {
            eprintln!("GPU tests on {}", g.report);
            Some(g)
        }
        Err(e) => {
            if std::env::var("SVGIR_REQUIRE_GPU").is_ok_and(|v| v == "1") {
                panic!("SVGIR_REQUIRE_GPU=1 and no GPU adapter: {e}");
            }
            eprintln!("SKIPPED: no GPU adapter ({e})");
            None
        }
    }
}
