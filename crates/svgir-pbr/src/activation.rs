//! Scalar activations of the stage-2 parameters (SPEC 3, 4): sigmoid for albedo and roughness,
//! softplus for the environment map. Generic over [`Float`] so that f64 runs the same code as the
//! reference of the gradient tests.

use svgir_shading::Float;

/// Logistic sigmoid, evaluated without overflow for either sign of `x`: `1 / (1 + e^-x)` for
/// `x >= 0`, `e^x / (1 + e^x)` below. Both are `num / (1 + e^-|x|)`, so the sign selects only the
/// numerator, without a branch (the signs of trained parameters are mixed, and a mispredicted
/// branch cost as much as the `exp`). The exponential is [`Float::exp_fast`].
#[inline(always)]
pub fn sigmoid<F: Float>(x: F) -> F {
    let e = (-x.abs()).exp_fast();
    let num = if x >= F::ZERO { F::ONE } else { e };
    num / (F::ONE + e)
}

/// `ln(1 + e^x)` as `max(x, 0) + ln(1 + e^-|x|)`: no overflow for large x. Its derivative is
/// [`sigmoid`].
#[inline]
pub fn softplus<F: Float>(x: F) -> F {
    x.maxf(F::ZERO) + (F::ONE + (-x.abs()).exp()).ln()
}

/// Inverse of softplus for y > 0: `y + ln(1 - e^-y)`.
#[inline]
pub fn softplus_inv<F: Float>(y: F) -> F {
    y + (F::ONE - (-y).exp()).ln()
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::float::exp_f32;

    /// The two-branch form the selected numerator replaces (with the same exponential).
    fn sigmoid_branches(x: f32) -> f32 {
        if x >= 0.0 {
            1.0 / (1.0 + exp_f32(-x))
        } else {
            let e = exp_f32(x);
            e / (1.0 + e)
        }
    }

    #[test]
    fn sigmoid_has_the_two_branch_forms_bits() {
        let mut xs = vec![0.0f32, -0.0, 1e-30, -1e-30, 88.0, -88.0, 104.0, -104.0, 1e30, -1e30];
        xs.extend((-4000..=4000).map(|i| i as f32 * 0.0137));
        for x in xs {
            assert_eq!(sigmoid(x).to_bits(), sigmoid_branches(x).to_bits(), "sigmoid({x})");
        }
        assert!(sigmoid(f32::NAN).is_nan());
    }

    #[test]
    fn activations_are_stable_and_consistent() {
        for &x in &[-800.0f64, -30.0, -2.0, 0.0, 0.7, 30.0, 800.0] {
            let s = sigmoid(x);
            assert!((0.0..=1.0).contains(&s) && s.is_finite());
            let sp = softplus(x);
            assert!(sp.is_finite() && sp >= 0.0 && sp >= x);
            let h = 1e-6;
            if x.abs() < 100.0 {
                let fd = (softplus(x + h) - softplus(x - h)) / (2.0 * h);
                assert!((fd - s).abs() < 1e-8, "x={x}: {fd} vs {s}");
                let fd = (sigmoid(x + h) - sigmoid(x - h)) / (2.0 * h);
                assert!((fd - s * (1.0 - s)).abs() < 1e-8);
            }
        }
        for &y in &[1e-3f64, 0.5, 2.0, 40.0] {
            assert!((softplus(softplus_inv(y)) - y).abs() < 1e-9 * (1.0 + y));
        }
        assert!((sigmoid(0.3f32) - sigmoid(0.3f64) as f32).abs() < 1e-7);
    }
}
