//! Gaussian-vertex interpolation weights inside one surfel (SPEC 3, SPEC 9.1) and their
//! derivatives w.r.t. the normalised tangent coordinates (u~, v~).
//!
//! Vertex order (shared with the shading crate; SPEC 9.1 "one vertex order"): u~ varies fastest.
//! - M = 1: constant.
//! - M = 2: vertices at u~ = 0, 1 (v~ = 1/2); weights `1-u~, u~`.
//! - M = 4: corners (0,0), (1,0), (0,1), (1,1); bilinear.
//! - M = 6: 3 x 2 grid, vertex `m = 3*j + i` at (u~, v~) = (i/2, j); quadratic Lagrange in u~
//!   (`l0 = 2(u-1/2)(u-1), l1 = -4u(u-1), l2 = 2u(u-1/2)`) times linear in v~.
//!
//! Pure per-pixel arithmetic: no allocation, nothing saved for backward (recomputed).

#![allow(unsafe_op_in_unsafe_fn)]

use crate::simd::Lanes;
use svgir_core::Float;

/// Largest supported vertex count.
pub const MAX_VERTICES: usize = 6;

/// Whether `m` is a supported vertex count.
pub fn supported_vertices(m: usize) -> bool {
    matches!(m, 1 | 2 | 4 | 6)
}

/// Normalised tangent coordinate from a sigma-unit one (SPEC 3: `u~ = clamp(0.5 + 0.5 u, 0.001,
/// 0.999)`), and `d u~ / d u` (0 where the clamp is active: the exact derivative).
#[inline(always)]
pub fn normalised_coord<F: Float>(u: F) -> (F, F) {
    let t = F::c(0.5) + F::c(0.5) * u;
    if t < F::c(0.001) {
        (F::c(0.001), F::ZERO)
    } else if t > F::c(0.999) {
        (F::c(0.999), F::ZERO)
    } else {
        (t, F::c(0.5))
    }
}

/// Weights `w[m]` at (u~, v~) for `m < vertices`.
#[inline(always)]
pub fn weights<F: Float>(vertices: usize, u: F, v: F, w: &mut [F; MAX_VERTICES]) {
    let one = F::ONE;
    match vertices {
        2 => {
            w[0] = one - u;
            w[1] = u;
        }
        4 => {
            w[0] = (one - u) * (one - v);
            w[1] = u * (one - v);
            w[2] = (one - u) * v;
            w[3] = u * v;
        }
        6 => {
            let l = lagrange(u);
            for i in 0..3 {
                w[i] = l[i] * (one - v);
                w[3 + i] = l[i] * v;
            }
        }
        _ => w[0] = one,
    }
}

/// Derivatives `du[m] = d w_m / d u~`, `dv[m] = d w_m / d v~`.
#[inline(always)]
pub fn weight_grads<F: Float>(vertices: usize, u: F, v: F, du: &mut [F; MAX_VERTICES], dv: &mut [F; MAX_VERTICES]) {
    let one = F::ONE;
    match vertices {
        2 => {
            du[0] = -one;
            du[1] = one;
            dv[0] = F::ZERO;
            dv[1] = F::ZERO;
        }
        4 => {
            du[0] = -(one - v);
            du[1] = one - v;
            du[2] = -v;
            du[3] = v;
            dv[0] = -(one - u);
            dv[1] = -u;
            dv[2] = one - u;
            dv[3] = u;
        }
        6 => {
            let l = lagrange(u);
            let dl = lagrange_grad(u);
            for i in 0..3 {
                du[i] = dl[i] * (one - v);
                du[3 + i] = dl[i] * v;
                dv[i] = -l[i];
                dv[3 + i] = l[i];
            }
        }
        _ => {
            du[0] = F::ZERO;
            dv[0] = F::ZERO;
        }
    }
}

#[inline(always)]
fn lagrange<F: Float>(u: F) -> [F; 3] {
    let h = F::c(0.5);
    let one = F::ONE;
    [F::c(2.0) * (u - h) * (u - one), F::c(-4.0) * u * (u - one), F::c(2.0) * u * (u - h)]
}

#[inline(always)]
fn lagrange_grad<F: Float>(u: F) -> [F; 3] {
    [F::c(4.0) * u - F::c(3.0), F::c(4.0) - F::c(8.0) * u, F::c(4.0) * u - F::ONE]
}

/// [`normalised_coord`] per lane (same operations, so the same bits): `(u~, d u~ / d u)`.
///
/// # Safety
/// The CPU has the features of `S`.
#[inline(always)]
pub(crate) unsafe fn normalised_coord_lanes<S: Lanes>(u: S) -> (S, S) {
    let sp = |v: f32| S::splat(v);
    let t = sp(0.5).add(sp(0.5).mul(u));
    let c = t.max(sp(0.001)).min(sp(0.999));
    // Inside the clamp: 0.5.
    (c, S::select(S::and(t.ge(sp(0.001)), t.le(sp(0.999))), sp(0.5), sp(0.0)))
}

/// [`weights`] per lane (same operations, same bits).
///
/// # Safety
/// The CPU has the features of `S`.
#[inline(always)]
pub(crate) unsafe fn weights_lanes<S: Lanes>(vertices: usize, u: S, v: S) -> [S; MAX_VERTICES] {
    let one = S::splat(1.0);
    let mut w = [S::splat(0.0); MAX_VERTICES];
    match vertices {
        2 => {
            w[0] = one.sub(u);
            w[1] = u;
        }
        4 => {
            w[0] = one.sub(u).mul(one.sub(v));
            w[1] = u.mul(one.sub(v));
            w[2] = one.sub(u).mul(v);
            w[3] = u.mul(v);
        }
        6 => {
            let l = lagrange_lanes(u);
            for i in 0..3 {
                w[i] = l[i].mul(one.sub(v));
                w[3 + i] = l[i].mul(v);
            }
        }
        _ => w[0] = one,
    }
    w
}

/// [`weight_grads`] per lane (same operations, same bits): `(d w / d u~, d w / d v~)`.
///
/// # Safety
/// The CPU has the features of `S`.
#[inline(always)]
pub(crate) unsafe fn weight_grads_lanes<S: Lanes>(
    vertices: usize,
    u: S,
    v: S,
) -> ([S; MAX_VERTICES], [S; MAX_VERTICES]) {
    let (zero, one) = (S::splat(0.0), S::splat(1.0));
    let (mut du, mut dv) = ([zero; MAX_VERTICES], [zero; MAX_VERTICES]);
    match vertices {
        2 => {
            du[0] = zero.sub(one);
            du[1] = one;
        }
        4 => {
            du[0] = zero.sub(one.sub(v));
            du[1] = one.sub(v);
            du[2] = zero.sub(v);
            du[3] = v;
            dv[0] = zero.sub(one.sub(u));
            dv[1] = zero.sub(u);
            dv[2] = one.sub(u);
            dv[3] = u;
        }
        6 => {
            let l = lagrange_lanes(u);
            let sp = |x: f32| S::splat(x);
            let dl = [sp(4.0).mul(u).sub(sp(3.0)), sp(4.0).sub(sp(8.0).mul(u)), sp(4.0).mul(u).sub(one)];
            for i in 0..3 {
                du[i] = dl[i].mul(one.sub(v));
                du[3 + i] = dl[i].mul(v);
                dv[i] = zero.sub(l[i]);
                dv[3 + i] = l[i];
            }
        }
        _ => {}
    }
    (du, dv)
}

#[inline(always)]
unsafe fn lagrange_lanes<S: Lanes>(u: S) -> [S; 3] {
    let sp = |x: f32| S::splat(x);
    let (h, one) = (sp(0.5), sp(1.0));
    [sp(2.0).mul(u.sub(h)).mul(u.sub(one)), sp(-4.0).mul(u).mul(u.sub(one)), sp(2.0).mul(u).mul(u.sub(h))]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partition_of_unity_interpolation_and_grads() {
        for &m in &[1usize, 2, 4, 6] {
            for &(u, v) in &[(0.2f64, 0.7f64), (0.5, 0.5), (0.9, 0.1)] {
                let mut w = [0.0; MAX_VERTICES];
                weights(m, u, v, &mut w);
                let s: f64 = w[..m].iter().sum();
                assert!((s - 1.0).abs() < 1e-12, "M={m}");
                let (mut du, mut dv) = ([0.0; MAX_VERTICES], [0.0; MAX_VERTICES]);
                weight_grads(m, u, v, &mut du, &mut dv);
                let h = 1e-6;
                let (mut wp, mut wm) = ([0.0; MAX_VERTICES], [0.0; MAX_VERTICES]);
                weights(m, u + h, v, &mut wp);
                weights(m, u - h, v, &mut wm);
                for k in 0..m {
                    assert!(((wp[k] - wm[k]) / (2.0 * h) - du[k]).abs() < 1e-6, "M={m} du {k}");
                }
                weights(m, u, v + h, &mut wp);
                weights(m, u, v - h, &mut wm);
                for k in 0..m {
                    assert!(((wp[k] - wm[k]) / (2.0 * h) - dv[k]).abs() < 1e-6, "M={m} dv {k}");
                }
            }
        }
        // Interpolating: at vertex (i/2, j) of the M=6 grid only that vertex has weight 1.
        for j in 0..2 {
            for i in 0..3 {
                let mut w = [0.0; MAX_VERTICES];
                weights(6, i as f64 * 0.5, j as f64, &mut w);
                for k in 0..6 {
                    let want = if k == 3 * j + i { 1.0 } else { 0.0 };
                    assert!((w[k] - want).abs() < 1e-12);
                }
            }
        }
    }
}
