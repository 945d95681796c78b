//! The float abstraction every kernel crate shares (rasterizer, shading, tracing, PBR, metrics),
//! so kernels run in f32 (production) and f64 (gradient checks against finite differences, and
//! the rasterizer's reference kernels) from one source.

use crate::ShCoeffs;
use glam::{DQuat, DVec2, DVec3, Quat, Vec2, Vec3};
use std::fmt::Debug;
use std::iter::Sum;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// The one scalar type every kernel is generic over: `f32` in training and evaluation, `f64`
/// for the finite-difference and reference checks of the same code. Besides arithmetic it
/// carries the glam types the rasterizer returns gradients in, and the SH basis in that
/// precision.
pub trait Float:
    Copy
    + Debug
    + Default
    + PartialOrd
    + Send
    + Sync
    + 'static
    + Sum
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
{
    /// 2-vector gradient type (`Vec2` for `f32`, `DVec2` for `f64`).
    type V2: Copy + Send + Sync + Debug + Default + bytemuck::Zeroable;
    /// 3-vector gradient type (`Vec3` for `f32`, `DVec3` for `f64`).
    type V3: Copy + Send + Sync + Debug + Default + bytemuck::Zeroable;
    /// Quaternion gradient type (`Quat` for `f32`, `DQuat` for `f64`).
    type Q: Copy + Send + Sync + Debug + bytemuck::Zeroable;
    /// SH-coefficient gradient type (`ShCoeffs` for `f32`, `[[f64; 3]; 16]` for `f64`).
    type Sh: Copy + Send + Sync + Debug + bytemuck::Zeroable;

    /// Additive identity.
    const ZERO: Self;
    /// Multiplicative identity.
    const ONE: Self;
    /// Convert from f64 (rounding for f32).
    fn from_f64(x: f64) -> Self;
    /// A constant, rounded from `f64` (`from_f64`, short for the kernels' formulas).
    #[inline(always)]
    fn c(x: f64) -> Self {
        Self::from_f64(x)
    }
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
    /// `e^x` for the hot loops: [`exp_f32`] in `f32` (branch-free, inlinable, relative error
    /// under 3e-7 on [-87, 88]), libm's in `f64` (the checks' reference).
    fn exp_fast(self) -> Self;
    /// Base-2 exponential 2^x.
    fn exp2(self) -> Self;
    /// Natural logarithm.
    fn ln(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// `self` raised to the power `e`.
    fn powf(self, e: Self) -> Self;
    /// `self * a + b` with one rounding (the SIMD kernels' FMA, bit for bit).
    fn mul_add(self, a: Self, b: Self) -> Self;

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

    /// The smaller of the two (`self` when they are equal or `o` is NaN), as the rasterizer's
    /// SIMD lanes compute it.
    #[inline]
    fn min(self, o: Self) -> Self {
        if o < self {
            o
        } else {
            self
        }
    }

    /// The larger of the two (`self` when they are equal or `o` is NaN), as the rasterizer's
    /// SIMD lanes compute it.
    #[inline]
    fn max(self, o: Self) -> Self {
        if o > self {
            o
        } else {
            self
        }
    }

    /// Packs two scalars into [`Float::V2`].
    fn v2(a: [Self; 2]) -> Self::V2;
    /// Packs three scalars into [`Float::V3`].
    fn v3(a: [Self; 3]) -> Self::V3;
    /// Packs `x, y, z, w` into [`Float::Q`].
    fn quat(a: [Self; 4]) -> Self::Q;
    /// Packs SH coefficients `[k][channel]` into [`Float::Sh`].
    fn sh(a: &[[Self; 3]; 16]) -> Self::Sh;
    /// The real SH basis (3DGS convention) of a unit direction ([`crate::sh::basis`]).
    fn sh_basis(degree: u32, d: [Self; 3], out: &mut [Self; 16]);
    /// Its Jacobian w.r.t. the direction components ([`crate::sh::basis_grad`]).
    fn sh_basis_grad(degree: u32, d: [Self; 3], out: &mut [[Self; 3]; 16]);
}

/// The methods whose body is the same call for both types.
macro_rules! common_float {
    ($t:ty) => {
        const ZERO: Self = 0.0;
        const ONE: Self = 1.0;
        #[inline(always)]
        fn from_f64(x: f64) -> Self {
            x as $t
        }
        #[inline(always)]
        fn from_f32(x: f32) -> Self {
            x as $t
        }
        #[inline(always)]
        fn to_f64(self) -> f64 {
            self as f64
        }
        #[inline(always)]
        fn to_f32(self) -> f32 {
            self as f32
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            <$t>::sqrt(self)
        }
        #[inline(always)]
        fn exp(self) -> Self {
            <$t>::exp(self)
        }
        #[inline(always)]
        fn exp2(self) -> Self {
            <$t>::exp2(self)
        }
        #[inline(always)]
        fn ln(self) -> Self {
            <$t>::ln(self)
        }
        #[inline(always)]
        fn abs(self) -> Self {
            <$t>::abs(self)
        }
        #[inline(always)]
        fn powf(self, e: Self) -> Self {
            <$t>::powf(self, e)
        }
        #[inline(always)]
        fn mul_add(self, a: Self, b: Self) -> Self {
            <$t>::mul_add(self, a, b)
        }
    };
}

impl Float for f32 {
    type V2 = Vec2;
    type V3 = Vec3;
    type Q = Quat;
    type Sh = ShCoeffs;
    common_float!(f32);
    #[inline(always)]
    fn exp_fast(self) -> Self {
        exp_f32(self)
    }
    fn v2(a: [f32; 2]) -> Vec2 {
        Vec2::from_array(a)
    }
    fn v3(a: [f32; 3]) -> Vec3 {
        Vec3::from_array(a)
    }
    fn quat(a: [f32; 4]) -> Quat {
        Quat::from_array(a)
    }
    fn sh(a: &[[f32; 3]; 16]) -> ShCoeffs {
        ShCoeffs(*a)
    }
    fn sh_basis(degree: u32, d: [f32; 3], out: &mut [f32; 16]) {
        crate::sh::basis(degree, Vec3::from_array(d), out);
    }
    fn sh_basis_grad(degree: u32, d: [f32; 3], out: &mut [[f32; 3]; 16]) {
        let mut g = [Vec3::ZERO; 16];
        crate::sh::basis_grad(degree, Vec3::from_array(d), &mut g);
        for k in 0..16 {
            out[k] = g[k].to_array();
        }
    }
}

impl Float for f64 {
    type V2 = DVec2;
    type V3 = DVec3;
    type Q = DQuat;
    type Sh = [[f64; 3]; 16];
    common_float!(f64);
    #[inline(always)]
    fn exp_fast(self) -> Self {
        f64::exp(self)
    }
    fn v2(a: [f64; 2]) -> DVec2 {
        DVec2::from_array(a)
    }
    fn v3(a: [f64; 3]) -> DVec3 {
        DVec3::from_array(a)
    }
    fn quat(a: [f64; 4]) -> DQuat {
        DQuat::from_array(a)
    }
    fn sh(a: &[[f64; 3]; 16]) -> [[f64; 3]; 16] {
        *a
    }
    fn sh_basis(degree: u32, d: [f64; 3], out: &mut [f64; 16]) {
        crate::sh::basis_f64(degree, d, out);
    }
    fn sh_basis_grad(degree: u32, d: [f64; 3], out: &mut [[f64; 3]; 16]) {
        crate::sh::basis_grad_f64(degree, d, out);
    }
}

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
    fn f64_sh_twin_matches_core() {
        let d = Vec3::new(0.3, -0.6, 0.74).normalize();
        let dd = [d.x as f64, d.y as f64, d.z as f64];
        let (mut a, mut b) = ([0.0f32; 16], [0.0f64; 16]);
        f32::sh_basis(3, d.to_array(), &mut a);
        f64::sh_basis(3, dd, &mut b);
        let (mut ga, mut gb) = ([[0.0f32; 3]; 16], [[0.0f64; 3]; 16]);
        f32::sh_basis_grad(3, d.to_array(), &mut ga);
        f64::sh_basis_grad(3, dd, &mut gb);
        for k in 0..16 {
            assert!((a[k] as f64 - b[k]).abs() < 1e-6, "basis {k}");
            for j in 0..3 {
                assert!((ga[k][j] as f64 - gb[k][j]).abs() < 1e-5, "grad {k} {j}");
            }
        }
    }

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
