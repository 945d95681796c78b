//! The loop guard's host side: the kernels `guard_loops` (`shaders/loop_guard.wgsl`) names by
//! bit, which [`Gpu::check`](crate::Gpu::check) reports when a driver has cut their loops short.

/// The kernels `guard_loops` names by bit, in bit order.
pub(crate) const GUARDED: [&str; 9] = [
    "the rasterizer's forward",
    "the rasterizer's backward",
    "the feature raster's forward",
    "the feature raster's backward",
    "the micro-buffer tracer",
    "the radiance gather",
    "the vertex shading",
    "the vertex shading's backward",
    "the radiance-consistency gather",
];

#[cfg(test)]
mod tests {
    use super::GUARDED;
    use crate::buffers::{bind, dispatch, kernel_of, read_back, upload, LOOP_GUARD};

    /// A probe: one invocation runs `n` steps of an LCG (a loop the compiler cannot reduce to a
    /// formula), writes where it got, then calls the guard with bit `bit`.
    const PROBE: &str = "
@group(0) @binding(0) var<storage, read_write> io: array<u32>;
@group(0) @binding(1) var<storage, read_write> status: array<atomic<u32>, 2>;
@compute @workgroup_size(1)
fn main() {
    var x = 1u;
    for (var i = 0u; i < io[0]; i++) {
        x = x * 1664525u + 1013904223u;
    }
    io[2] = x;
    guard_loops(1u << io[1]);
}";

    fn lcg(n: u32) -> u32 {
        (0..n).fold(1u32, |x, _| x.wrapping_mul(1664525).wrapping_add(1013904223))
    }

    /// Runs the probe for `n` steps: whether its loop ran them all, and what `check` says.
    fn probe(g: &crate::Gpu, n: u32, bit: u32) -> (bool, Result<(), crate::GpuError>) {
        let d = &g.device;
        let k = kernel_of(d, "loop guard probe", &[PROBE, LOOP_GUARD]);
        let io = upload(d, "probe io", &[n, bit, 0u32]);
        let mut enc = d.create_command_encoder(&Default::default());
        let b = bind(d, &k, &[&io, &g.status]);
        dispatch(&mut enc, &k, &b, 1);
        g.queue.submit([enc.finish()]);
        let x = read_back::<u32>(d, &g.queue, &[(&io, 3)]).unwrap().remove(0)[2];
        (x == lcg(n), g.check())
    }

    /// A loop within any cap runs through and leaves `check` quiet; one of 100000 iterations
    /// is cut on lavapipe (its cap is 65535), and then `check` fails naming that kernel and no
    /// other. On an adapter without a cap the long loop runs through and `check` stays quiet.
    #[test]
    fn the_guard_reports_a_cut_loop_by_its_kernel() {
        let Some(g) = crate::testing::test_adapter() else { return };
        let (whole, check) = probe(&g, 1000, 4);
        assert!(whole, "a 1000-iteration loop was cut on {}", g.report.name);
        assert!(check.is_ok(), "{check:?}");
        let (whole, check) = probe(&g, 100_000, 4);
        eprintln!("{}: 100000 iterations run through: {whole}; check: {check:?}", g.report.name);
        if whole {
            assert!(check.is_ok(), "the guard fired on a loop that ran through: {check:?}");
            assert_ne!(g.report.device_type, "Cpu", "lavapipe's cap did not cut 100000 iterations");
        } else {
            let e = check.expect_err("a cut loop passed the check").to_string();
            assert!(e.contains(GUARDED[4]), "{e}");
            assert!(GUARDED.iter().enumerate().all(|(i, k)| i == 4 || !e.contains(k)), "{e}");
        }
    }
}
