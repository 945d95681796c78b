//! sRGB transfer functions (IEC 61966-2-1), applied per channel.

use crate::float::Float;

/// Decode one sRGB-encoded value in [0, 1] to linear.
#[inline]
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear to sRGB (generic so the f64 finite-difference oracles share it).
#[inline]
pub fn linear_to_srgb<F: Float>(c: F) -> F {
    let c = c.maxf(F::ZERO);
    if c <= F::from_f64(0.0031308) {
        F::from_f64(12.92) * c
    } else {
        F::from_f64(1.055) * c.powf(F::from_f64(1.0 / 2.4)) - F::from_f64(0.055)
    }
}

/// d linear_to_srgb / dc (SPEC 3's tone curve) on its own: the per-function oracle that
/// [`linear_to_srgb_with_grad`], which the PBR image's backward calls, is tested against.
#[inline]
pub fn linear_to_srgb_grad<F: Float>(c: F) -> F {
    if c <= F::ZERO {
        F::ZERO
    } else if c <= F::from_f64(0.0031308) {
        F::from_f64(12.92)
    } else {
        F::from_f64(1.055 / 2.4) * c.powf(F::from_f64(1.0 / 2.4 - 1.0))
    }
}

/// [`linear_to_srgb`] and [`linear_to_srgb_grad`] at once, with one `powf`: above the linear
/// toe the gradient is `1.055 / 2.4 * c^(1/2.4) / c`. (The PBR image's backward needs both per
/// channel, and its f64 `powf` calls were a fifth of stage 2's loss phase at 256 x 256.)
#[inline]
pub fn linear_to_srgb_with_grad<F: Float>(c: F) -> (F, F) {
    if c <= F::ZERO {
        (F::ZERO, F::ZERO)
    } else if c <= F::from_f64(0.0031308) {
        (F::from_f64(12.92) * c, F::from_f64(12.92))
    } else {
        let p = c.powf(F::from_f64(1.0 / 2.4));
        (F::from_f64(1.055) * p - F::from_f64(0.055), F::from_f64(1.055 / 2.4) * p / c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_gradient() {
        for i in 0..=100 {
            let c = i as f32 / 100.0;
            assert!((srgb_to_linear(linear_to_srgb(c)) - c).abs() < 1e-5);
            if c > 0.01 {
                let h = 1e-3;
                let fd = (linear_to_srgb(c + h) - linear_to_srgb(c - h)) / (2.0 * h);
                assert!((fd - linear_to_srgb_grad(c)).abs() < 1e-2 * fd.abs().max(1.0));
            }
        }
    }

    #[test]
    fn value_and_gradient_at_once_agree_with_the_two_functions() {
        for i in -5..=4000 {
            let c = i as f64 * 2.5e-4;
            let (v, g) = linear_to_srgb_with_grad(c);
            assert_eq!(v, linear_to_srgb(c), "value at {c}");
            let g0 = linear_to_srgb_grad(c);
            assert!((g - g0).abs() <= 4.0 * f64::EPSILON * g0.abs(), "gradient at {c}: {g} vs {g0}");
        }
    }
}
