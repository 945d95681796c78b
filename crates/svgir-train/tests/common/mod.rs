//! Helpers shared by the integration tests.

/// A folder of `../shared/data` that a test needs is missing (`what` names it). With
/// `SVGIR_REQUIRE_DATA=1` (set by `.ci/run`) the test fails; otherwise it prints `SKIPPED` and
/// the caller returns.
#[allow(dead_code)]
pub fn missing_data(what: &str) {
    let msg = format!("{what} not found; this test needs ../shared/data");
    if std::env::var("SVGIR_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!("SVGIR_REQUIRE_DATA=1: {msg}");
    }
    eprintln!("SKIPPED: {msg}");
}

/// Central differences of an f32 loss on a sample of one output's entries, `start..start + len`
/// of the inputs `x`: its 6 steepest entries by `slope` (which the f32 loss resolves best; they
/// must stand above its rounding noise) and 6 at random. `step(i)` is entry `i`'s step and
/// `loss_at` the production loss; each difference must match `slope` to 2% plus the noise of
/// the f32 loss `loss` at that step. `what` names the output in messages.
#[allow(dead_code)]
pub fn check_sampled_entries(
    what: &str,
    (start, len): (usize, usize),
    x: &[f32],
    slope: &[f64],
    loss: f64,
    rng: &mut svgir_core::Rng,
    step: impl Fn(usize) -> f64,
    loss_at: impl Fn(&[f32]) -> f64,
) {
    let mut order: Vec<usize> = (start..start + len).collect();
    order.sort_by(|&a, &b| slope[b].abs().total_cmp(&slope[a].abs()));
    let sample: Vec<usize> = order[..6].iter().copied().chain((0..6).map(|_| start + rng.below(len))).collect();
    for (k, i) in sample.into_iter().enumerate() {
        let h = step(i);
        let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
        xp[i] = (x[i] as f64 + h) as f32;
        xm[i] = (x[i] as f64 - h) as f32;
        let dx = xp[i] as f64 - xm[i] as f64;
        let fd = (loss_at(&xp) - loss_at(&xm)) / dx;
        let noise = 8.0 * f32::EPSILON as f64 * loss / dx;
        if k < 6 {
            assert!(slope[i].abs() > 4.0 * noise, "{what}: the check must resolve the steepest entries");
        }
        assert!(
            (fd - slope[i]).abs() <= 0.02 * slope[i].abs() + noise,
            "{what}[{}]: finite difference {fd:e} vs gradient {:e} (noise {noise:e})",
            i - start,
            slope[i]
        );
    }
}

/// Every entry of one output's gradient `grad` against the f64 mirror's central differences
/// `fd`, to 2e-5 relative plus 2e-6 of the block's largest difference (which must be non-zero:
/// the loss must depend on the output). `what` names the output in messages.
#[allow(dead_code)]
pub fn check_block_against_mirror(what: &str, grad: &[f64], fd: &[f64]) {
    let scale = fd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(scale > 0.0, "{what}: the loss must depend on it");
    for (k, (a, f)) in grad.iter().zip(fd).enumerate() {
        assert!(
            (a - f).abs() <= 2e-5 * f.abs() + 2e-6 * scale,
            "{what}[{k}]: production {a:e} vs f64 finite difference {f:e} (block max {scale:e})"
        );
    }
}
