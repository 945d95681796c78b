//! Mean absolute error over all pixels and channels, and its (sub)gradient.

/// Returns mean |a - b| and writes d/da into `v_a` (scaled by `weight`, accumulated).
pub fn l1_loss(a: &[f32], b: &[f32], weight: f32, v_a: &mut [f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let n = a.len() as f32;
    let sum = super::chunked_sum(a, v_a, |i, x, g| {
        let d = x - b[i];
        *g += weight * d.signum() * (d != 0.0) as u8 as f32 / n;
        d.abs() as f64
    });
    (sum / n as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_and_gradient() {
        let a = [0.5, 0.2, 0.9, 0.1];
        let b = [0.1, 0.2, 1.0, 0.4];
        let mut g = [0.0; 4];
        let v = l1_loss(&a, &b, 2.0, &mut g);
        assert!((v - (0.4 + 0.0 + 0.1 + 0.3) / 4.0).abs() < 1e-6);
        assert_eq!(g, [0.5, 0.0, -0.5, -0.5]);
    }
}
