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

/// [`linear_to_srgb_with_grad`] in f32 without a call: `c^(1/2.4)` as
/// `exp_f32(ln_f32(c) / 2.4)`, within 1e-6 of libm's f64 value relative (tested), branch-free
/// so that a loop over many channels vectorises. For the PBR image in training, where libm's
/// `powf` was the largest part of the composite; the generic function stays the oracle.
/// NaN stays NaN and +inf gives `(inf, 0)`, as in the generic function.
#[inline(always)]
pub fn linear_to_srgb_with_grad_fast(c: f32) -> (f32, f32) {
    use crate::float::{exp_f32, ln_f32};
    const KNEE: f32 = 0.003_130_8;
    // The power branch on a clamped argument (NaN stays NaN through `clamp`).
    let cp = c.clamp(KNEE, f32::MAX);
    let p = exp_f32(ln_f32(cp) * (1.0 / 2.4));
    let (mut v, mut g) = (1.055 * p - 0.055, (1.055 / 2.4) * p / cp);
    if c <= KNEE {
        (v, g) = (12.92 * c, 12.92);
    }
    if c <= 0.0 {
        (v, g) = (0.0, 0.0);
    }
    if c == f32::INFINITY {
        (v, g) = (c, 0.0);
    }
    if c.is_nan() {
        (v, g) = (c, c);
    }
    (v, g)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_tone_agrees_with_libm() {
        let mut worst = [0.0f64; 2];
        for i in 0..=200_000 {
            let c = 10.0f64.powf(-6.0 + 10.0 * i as f64 / 200_000.0) as f32;
            let (v, g) = linear_to_srgb_with_grad_fast(c);
            let (wv, wg) = linear_to_srgb_with_grad(c as f64);
            worst[0] = worst[0].max((v as f64 - wv).abs() / wv);
            worst[1] = worst[1].max((g as f64 - wg).abs() / wg);
        }
        assert!(worst[0] < 1e-6 && worst[1] < 1e-6, "worst relative errors {worst:?}");
        for c in [0.0f32, -0.0, -1.0, -f32::INFINITY, 0.003_130_8, f32::MIN_POSITIVE] {
            let (v, g) = linear_to_srgb_with_grad_fast(c);
            // Against the f32 instance, which takes the same branch at the knee (its f32 value
            // lies just above the f64 knee, where the slope jumps).
            let (wv, wg) = linear_to_srgb_with_grad(c);
            assert!((v - wv).abs() <= 1e-6 * wv.abs() && (g - wg).abs() <= 1e-6 * wg.abs(), "{c}");
        }
        assert_eq!(linear_to_srgb_with_grad_fast(f32::INFINITY), (f32::INFINITY, 0.0));
        let (v, g) = linear_to_srgb_with_grad_fast(f32::NAN);
        assert!(v.is_nan() && g.is_nan());
    }

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
