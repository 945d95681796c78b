//! The few 3-vector helpers the rasterizer's kernels need on plain `[F; 3]` arrays, in any
//! [`Float`] (`f32` for training, `f64` for the finite-difference checks and the reference).

use svgir_core::Float;

#[inline(always)]
pub(crate) fn dot3<F: Float>(a: [F; 3], b: [F; 3]) -> F {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
pub(crate) fn cross3<F: Float>(a: [F; 3], b: [F; 3]) -> [F; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[inline(always)]
pub(crate) fn sub3<F: Float>(a: [F; 3], b: [F; 3]) -> [F; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `m * v` for a row-major 3x3 matrix.
#[inline(always)]
pub(crate) fn matvec<F: Float>(m: &[[F; 3]; 3], v: [F; 3]) -> [F; 3] {
    [dot3(m[0], v), dot3(m[1], v), dot3(m[2], v)]
}

/// `m^T * v` for a row-major 3x3 matrix.
#[inline(always)]
pub(crate) fn matvec_t<F: Float>(m: &[[F; 3]; 3], v: [F; 3]) -> [F; 3] {
    let mut r = [F::ZERO; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[j] += m[i][j] * v[i];
        }
    }
    r
}
