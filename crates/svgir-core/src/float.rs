//! A minimal float abstraction so kernels run in f32 (production) and f64 (gradient checks
//! against finite differences) from one source. Shared by shading, tracing, PBR and metrics.

use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// The float operations shared kernels need, implemented for f32 and f64.
pub trait Float:
    Copy
    + Debug
    + PartialOrd
    + Send
    + Sync
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
{
    /// Additive identity.
    const ZERO: Self;
    /// Multiplicative identity.
    const ONE: Self;
    /// Convert from f64 (rounding for f32).
    fn from_f64(x: f64) -> Self;
    /// Convert from f32 (exact).
    fn from_f32(x: f32) -> Self;
    /// Convert to f64 (exact).
    fn to_f64(self) -> f64;
    /// Convert to f32 (rounding for f64).
    fn to_f32(self) -> f32;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Natural exponential e^x.
    fn exp(self) -> Self;
    /// Base-2 exponential 2^x.
    fn exp2(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// `self` raised to the power `e`.
    fn powf(self, e: Self) -> Self;

    /// Larger of the two (plain comparison; callers never pass NaN).
    #[inline]
    fn maxf(self, o: Self) -> Self {
        if self > o {
            self
        } else {
            o
        }
    }

    /// Smaller of the two (plain comparison; callers never pass NaN).
    #[inline]
    fn minf(self, o: Self) -> Self {
        if self < o {
            self
        } else {
            o
        }
    }

    /// `self` limited to [lo, hi].
    #[inline]
    fn clampf(self, lo: Self, hi: Self) -> Self {
        self.maxf(lo).minf(hi)
    }
}

macro_rules! impl_float {
    ($t:ty) => {
        impl Float for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            #[inline]
            fn from_f64(x: f64) -> Self {
                x as $t
            }
            #[inline]
            fn from_f32(x: f32) -> Self {
                x as $t
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn to_f32(self) -> f32 {
                self as f32
            }
            #[inline]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline]
            fn exp2(self) -> Self {
                <$t>::exp2(self)
            }
            #[inline]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline]
            fn powf(self, e: Self) -> Self {
                <$t>::powf(self, e)
            }
        }
    };
}

impl_float!(f32);
impl_float!(f64);

/// `exp(x)` as `2^n * p(r)`, `x = n ln2 + r`, `|r| <= ln2 / 2`, `p` the degree-6 Taylor
/// polynomial in Estrin's form; branch-free and inlinable (libm's `expf` is a call on baseline
/// x86-64).
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    // Round-to-nearest via the 1.5 * 2^23 shifter (no SSE4.1 `round` needed).
    let shifter = 12_582_912.0f32;
    let t = x * std::f32::consts::LOG2_E + shifter;
    let n = t - shifter;
    let r = x - n * 0.693_145_75 - n * 1.428_606_8e-6;
    // Estrin's scheme: the chain of dependent operations is five deep where Horner's is twelve,
    // and the tile kernels wait on it (docs/performance.md).
    let (r2, r4) = (r * r, r * r * (r * r));
    let a = 1.0 + r;
    let b = 0.5 + r * (1.0 / 6.0);
    let d = (1.0 / 24.0 + r * (1.0 / 120.0)) + r2 * (1.0 / 720.0);
    let p = (a + r2 * b) + r4 * d;
    // The shifter's low mantissa bits hold n + 2^22: integer ops only (no saturating cast), so
    // the loops calling this vectorise.
    let ni = (t.to_bits() as i32).wrapping_sub(0x4B40_0000);
    let bits = (ni.wrapping_add(127) as u32) << 23;
    p * f32::from_bits(bits)
}

/// `ln(x)` for positive, finite, normal `x` (other inputs give meaningless values: callers
/// clamp): `x = 2^e m` with `m` in `[sqrt(1/2), sqrt(2))`, and `ln m = 2 atanh(t)`,
/// `t = (m - 1) / (m + 1)`, `|t| <= 0.172`, from its odd series to `t^9` (the next term is
/// under 1e-9). Branch-free and inlinable, so the loops calling it vectorise.
#[inline(always)]
pub fn ln_f32(x: f32) -> f32 {
    // Subtracting sqrt(1/2)'s bits moves the binade boundary there: `e` is the exponent of x
    // relative to sqrt(1/2), and the mantissa with that exponent removed is in range.
    let bits = x.to_bits() as i32;
    let e = bits.wrapping_sub(0x3F35_04F3) >> 23;
    let m = f32::from_bits(bits.wrapping_sub(e << 23) as u32);
    let t = (m - 1.0) / (m + 1.0);
    let t2 = t * t;
    let t4 = t2 * t2;
    let series = (1.0 + t2 * (1.0 / 3.0)) + t4 * ((1.0 / 5.0 + t2 * (1.0 / 7.0)) + t4 * (1.0 / 9.0));
    e as f32 * std::f32::consts::LN_2 + 2.0 * t * series
}

/// Small 3-vector helpers on `[F; 3]`.
#[inline]
pub fn dot<F: Float>(a: [F; 3], b: [F; 3]) -> F {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Convert an f32 3-vector to `F`.
#[inline]
pub fn to_f<F: Float>(a: [f32; 3]) -> [F; 3] {
    a.map(F::from_f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_ln_is_accurate() {
        let mut worst = 0.0f64;
        // Every binade from 1e-30 to 1e30, densely, and the binade edges exactly.
        for i in 0..=400_000 {
            let x = (10.0f64.powf(-30.0 + 60.0 * i as f64 / 400_000.0)) as f32;
            let want = (x as f64).ln();
            let got = ln_f32(x) as f64;
            worst = worst.max((got - want).abs() / want.abs().max(1.0));
        }
        for k in -100..100 {
            for x in [2.0f32.powi(k), 2.0f32.powi(k) * std::f32::consts::FRAC_1_SQRT_2] {
                let want = (x as f64).ln();
                worst = worst.max((ln_f32(x) as f64 - want).abs() / want.abs().max(1.0));
            }
        }
        assert!(worst < 2e-7, "worst error {worst}");
        assert_eq!(ln_f32(1.0), 0.0);
    }

    #[test]
    fn fast_exp_is_accurate() {
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            let x = -87.0 + 175.0 * i as f64 / 200_000.0;
            let want = x.exp();
            let got = exp_f32(x as f32) as f64;
            // Compare against exp of the f32-rounded argument.
            let want_r = ((x as f32) as f64).exp();
            worst = worst.max(((got - want_r) / want_r).abs());
            assert!(((got - want) / want).abs() < 1e-5);
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
    }
}
