//! The scalar type the kernels are generic over (`f32` for training, `f64` for the finite-difference
//! oracle), plus the few 3-vector helpers the kernels need on plain arrays.
//!
//! Every kernel in this crate is written once over [`Real`]; the `f64` instantiation is what the
//! tests check against central differences, the `f32` one is what training runs.

use glam::{DQuat, DVec2, DVec3, Quat, Vec2, Vec3};
use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};
/// The branch-free exponential the f32 kernels use (defined beside core's `Float`, which the
/// material activations share).
pub use svgir_core::float::exp_f32;
use svgir_core::ShCoeffs;

/// A floating-point scalar (`f32` or `f64`), with the glam types gradients are returned in.
pub trait Real:
    Copy
    + Send
    + Sync
    + Debug
    + Default
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + 'static
{
    /// Gradient vector types (`Vec2`/`Vec3`/`Quat`/`ShCoeffs` for `f32`).
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
    /// A constant, rounded from `f64`.
    fn c(x: f64) -> Self;
    /// Converts from `f32` (exact).
    fn from_f32(x: f32) -> Self;
    /// Converts to `f64` (exact).
    fn to_f64(self) -> f64;
    /// Converts to `f32` (rounding for `f64`).
    fn to_f32(self) -> f32;
    /// `e^self`.
    fn exp(self) -> Self;
    /// `exp` for the per-pixel Gaussian falloff: inlined polynomial in `f32` (relative error
    /// below 3e-7 on [-87, 88]), `std` in `f64`.
    fn exp_fast(self) -> Self;
    /// `self * a + b` with one rounding (the SIMD kernels' FMA, bit for bit).
    fn mul_add(self, a: Self, b: Self) -> Self;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// The smaller of the two (`self` when they are equal or `o` is NaN).
    #[inline]
    fn min(self, o: Self) -> Self {
        if o < self {
            o
        } else {
            self
        }
    }
    /// The larger of the two (`self` when they are equal or `o` is NaN).
    #[inline]
    fn max(self, o: Self) -> Self {
        if o > self {
            o
        } else {
            self
        }
    }
    /// Packs two scalars into [`Real::V2`].
    fn v2(a: [Self; 2]) -> Self::V2;
    /// Packs three scalars into [`Real::V3`].
    fn v3(a: [Self; 3]) -> Self::V3;
    /// Packs `x, y, z, w` into [`Real::Q`].
    fn quat(a: [Self; 4]) -> Self::Q;
    /// Packs SH coefficients `[k][channel]` into [`Real::Sh`].
    fn sh(a: &[[Self; 3]; 16]) -> Self::Sh;
    /// Real SH basis (3DGS convention) of a unit direction; `f32` calls `svgir_core::sh::basis`.
    fn sh_basis(degree: u32, d: [Self; 3], out: &mut [Self; 16]);
    /// Its Jacobian w.r.t. the direction components; `f32` calls `svgir_core::sh::basis_grad`.
    fn sh_basis_grad(degree: u32, d: [Self; 3], out: &mut [[Self; 3]; 16]);
}

impl Real for f32 {
    type V2 = Vec2;
    type V3 = Vec3;
    type Q = Quat;
    type Sh = ShCoeffs;
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    #[inline(always)]
    fn c(x: f64) -> Self {
        x as f32
    }
    #[inline(always)]
    fn from_f32(x: f32) -> Self {
        x
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn exp(self) -> Self {
        f32::exp(self)
    }
    #[inline(always)]
    fn exp_fast(self) -> Self {
        exp_f32(self)
    }
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        f32::mul_add(self, a, b)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f32::abs(self)
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
        svgir_core::sh::basis(degree, Vec3::from_array(d), out);
    }
    fn sh_basis_grad(degree: u32, d: [f32; 3], out: &mut [[f32; 3]; 16]) {
        let mut g = [Vec3::ZERO; 16];
        svgir_core::sh::basis_grad(degree, Vec3::from_array(d), &mut g);
        for k in 0..16 {
            out[k] = g[k].to_array();
        }
    }
}

impl Real for f64 {
    type V2 = DVec2;
    type V3 = DVec3;
    type Q = DQuat;
    type Sh = [[f64; 3]; 16];
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    #[inline(always)]
    fn c(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn from_f32(x: f32) -> Self {
        x as f64
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline(always)]
    fn exp(self) -> Self {
        f64::exp(self)
    }
    #[inline(always)]
    fn exp_fast(self) -> Self {
        f64::exp(self)
    }
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        f64::mul_add(self, a, b)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f64::abs(self)
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
        sh_basis_f64(degree, d, out);
    }
    fn sh_basis_grad(degree: u32, d: [f64; 3], out: &mut [[f64; 3]; 16]) {
        sh_basis_grad_f64(degree, d, out);
    }
}

/// `f64` twin of `svgir_core::sh::basis`, only for the finite-difference oracle (core's is `f32`);
/// a test asserts the two agree.
pub(crate) fn sh_basis_f64(degree: u32, d: [f64; 3], out: &mut [f64; 16]) {
    use svgir_core::sh::{SH_C0, SH_C1, SH_C2, SH_C3};
    let c = |v: f32| v as f64;
    let [x, y, z] = d;
    out[0] = c(SH_C0);
    if degree < 1 {
        return;
    }
    out[1] = -c(SH_C1) * y;
    out[2] = c(SH_C1) * z;
    out[3] = -c(SH_C1) * x;
    if degree < 2 {
        return;
    }
    let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
    out[4] = c(SH_C2[0]) * xy;
    out[5] = c(SH_C2[1]) * yz;
    out[6] = c(SH_C2[2]) * (2.0 * zz - xx - yy);
    out[7] = c(SH_C2[3]) * xz;
    out[8] = c(SH_C2[4]) * (xx - yy);
    if degree < 3 {
        return;
    }
    out[9] = c(SH_C3[0]) * y * (3.0 * xx - yy);
    out[10] = c(SH_C3[1]) * xy * z;
    out[11] = c(SH_C3[2]) * y * (4.0 * zz - xx - yy);
    out[12] = c(SH_C3[3]) * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    out[13] = c(SH_C3[4]) * x * (4.0 * zz - xx - yy);
    out[14] = c(SH_C3[5]) * z * (xx - yy);
    out[15] = c(SH_C3[6]) * x * (xx - 3.0 * yy);
}

/// `f64` twin of `svgir_core::sh::basis_grad` (see [`sh_basis_f64`]).
pub(crate) fn sh_basis_grad_f64(degree: u32, d: [f64; 3], out: &mut [[f64; 3]; 16]) {
    use svgir_core::sh::{SH_C1, SH_C2, SH_C3};
    let c = |v: f32| v as f64;
    let [x, y, z] = d;
    let s = |k: f64, v: [f64; 3]| [k * v[0], k * v[1], k * v[2]];
    out[0] = [0.0; 3];
    if degree < 1 {
        return;
    }
    out[1] = [0.0, -c(SH_C1), 0.0];
    out[2] = [0.0, 0.0, c(SH_C1)];
    out[3] = [-c(SH_C1), 0.0, 0.0];
    if degree < 2 {
        return;
    }
    out[4] = s(c(SH_C2[0]), [y, x, 0.0]);
    out[5] = s(c(SH_C2[1]), [0.0, z, y]);
    out[6] = s(c(SH_C2[2]), [-2.0 * x, -2.0 * y, 4.0 * z]);
    out[7] = s(c(SH_C2[3]), [z, 0.0, x]);
    out[8] = s(c(SH_C2[4]), [2.0 * x, -2.0 * y, 0.0]);
    if degree < 3 {
        return;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    out[9] = s(c(SH_C3[0]), [6.0 * x * y, 3.0 * xx - 3.0 * yy, 0.0]);
    out[10] = s(c(SH_C3[1]), [y * z, x * z, x * y]);
    out[11] = s(c(SH_C3[2]), [-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z]);
    out[12] = s(c(SH_C3[3]), [-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy]);
    out[13] = s(c(SH_C3[4]), [4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z]);
    out[14] = s(c(SH_C3[5]), [2.0 * x * z, -2.0 * y * z, xx - yy]);
    out[15] = s(c(SH_C3[6]), [3.0 * xx - 3.0 * yy, -6.0 * x * y, 0.0]);
}

#[inline(always)]
pub(crate) fn dot3<F: Real>(a: [F; 3], b: [F; 3]) -> F {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
pub(crate) fn cross3<F: Real>(a: [F; 3], b: [F; 3]) -> [F; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[inline(always)]
pub(crate) fn sub3<F: Real>(a: [F; 3], b: [F; 3]) -> [F; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `m * v` for a row-major 3x3 matrix.
#[inline(always)]
pub(crate) fn matvec<F: Real>(m: &[[F; 3]; 3], v: [F; 3]) -> [F; 3] {
    [dot3(m[0], v), dot3(m[1], v), dot3(m[2], v)]
}

/// `m^T * v` for a row-major 3x3 matrix.
#[inline(always)]
pub(crate) fn matvec_t<F: Real>(m: &[[F; 3]; 3], v: [F; 3]) -> [F; 3] {
    let mut r = [F::ZERO; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[j] += m[i][j] * v[i];
        }
    }
    r
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
}
