//! The GGX specular term S of SPEC 4 (formula and clamps exactly as
//! [`crate::ggx_specular`] / [`crate::ggx_specular_grad`]), split by what it depends on so a
//! shading loop over many light directions does each part once: per vertex ([`Lobe`]: alpha^2, k, g(n.v), all fixed by
//! (n_m, w_o, r_m)) and per (Gaussian, direction) ([`HalfVec`]: half vector and Fresnel, shared
//! by the M vertices because they share w_o and w_k). What remains per (vertex, direction) is two
//! dot products and one division: `S = F a^2 g(n.v) / (4 pi q^2 (n.l (1-k) + k))` with
//! `q = (n.h)^2 (a^2 - 1) + 1`. The tests compare against the shading crate's functions in f64.

use crate::float::dot;
use crate::{Float, DOT_EPS, F0};
use std::f64::consts::PI;

/// The (n, v, r)-dependent part of S for one vertex.
#[derive(Clone, Copy, Debug)]
pub struct Lobe<F> {
    /// Unit shading normal.
    pub n: [F; 3],
    /// Roughness.
    pub r: F,
    /// alpha^2 = r^4.
    pub a2: F,
    /// The Schlick-GGX k = (r + 1)^2 / 8.
    pub k: F,
    /// 1 - k.
    pub omk: F,
    /// Clamped n.v.
    pub nv: F,
    /// Whether the n.v clamp is inactive.
    pub nv_live: bool,
    /// `1 / (n.v (1-k) + k)`.
    pub gv: F,
    /// `a^2 g(n.v) / (4 pi)`.
    pub c0: F,
    /// `a^2 / pi` (D's factor).
    pub d0: F,
    /// `4 r^3 / pi` (dD/dr's factor).
    pub cr: F,
    /// `-4 a^2 (a^2 - 1) / pi` (dD/d(n.h)'s factor).
    pub cn: F,
}

#[inline]
fn cdot<F: Float>(x: F) -> (F, bool) {
    let lo = F::from_f64(DOT_EPS);
    (x.clampf(lo, F::ONE), x > lo && x < F::ONE)
}

/// The lobe of a vertex with unit normal `n`, seen from unit `v`, roughness `r`.
#[inline]
pub fn lobe<F: Float>(n: [F; 3], v: [F; 3], r: F) -> Lobe<F> {
    let (nv, nv_live) = cdot(dot(n, v));
    let a = r * r;
    let a2 = a * a;
    let k = (r + F::ONE) * (r + F::ONE) / F::from_f64(8.0);
    let omk = F::ONE - k;
    let gv = F::ONE / (nv * omk + k);
    let pi = F::from_f64(PI);
    Lobe {
        n,
        r,
        a2,
        k,
        omk,
        nv,
        nv_live,
        gv,
        c0: a2 * gv / F::from_f64(4.0 * PI),
        d0: a2 / pi,
        cr: F::from_f64(4.0) * r * r * r / pi,
        cn: -F::from_f64(4.0) * a2 * (a2 - F::ONE) / pi,
    }
}

/// The (v, l)-dependent part of S.
#[derive(Clone, Copy, Debug)]
pub struct HalfVec<F> {
    /// Unit half vector of v and l.
    pub h: [F; 3],
    /// Fresnel (Schlick, spherical-Gaussian form, SPEC 4).
    pub fr: F,
}

/// The half vector of unit `v` and `l` and its Fresnel term.
#[inline]
pub fn half<F: Float>(v: [F; 3], l: [F; 3]) -> HalfVec<F> {
    let h = [v[0] + l[0], v[1] + l[1], v[2] + l[2]];
    let len = dot(h, h).sqrt().maxf(F::from_f64(1e-12));
    let h = [h[0] / len, h[1] / len, h[2] / len];
    let (vh, _) = cdot(dot(v, h));
    let f0 = F::from_f64(F0);
    let fr = f0 + (F::ONE - f0) * ((F::from_f64(-5.55473) * vh - F::from_f64(6.98316)) * vh).exp2();
    HalfVec { h, fr }
}

/// S for one vertex and light direction; `nl` is the unclamped n.l.
#[inline]
pub fn spec<F: Float>(lb: &Lobe<F>, hv: &HalfVec<F>, nl: F) -> F {
    let (nl, _) = cdot(nl);
    let (nh, _) = cdot(dot(lb.n, hv.h));
    let q = nh * nh * (lb.a2 - F::ONE) + F::ONE;
    hv.fr * lb.c0 / (q * q * (nl * lb.omk + lb.k))
}

/// S, dS/dr and dS/dn (unit normal as passed; zero through active clamps).
#[derive(Clone, Copy, Debug)]
pub struct SpecGrad<F> {
    /// S.
    pub value: F,
    /// dS/dr.
    pub v_r: F,
    /// dS/dn.
    pub v_n: [F; 3],
}

/// S and its gradients for one vertex and light direction `l`; `nl` is the unclamped n.l.
/// One division per (vertex, direction): `1 / (q (n.l (1-k) + k))` gives both `1/q` and the
/// `g(n.l)` term, and the `1/pi` factors are the lobe's (`d0`, `cr`, `cn`). The lane form
/// ([`crate::split_lanes::spec_grad_lanes`]) repeats these operations in this order.
#[inline]
pub fn spec_grad<F: Float>(lb: &Lobe<F>, hv: &HalfVec<F>, v: [F; 3], l: [F; 3], nl: F) -> SpecGrad<F> {
    let (nl, nl_live) = cdot(nl);
    let (nh, nh_live) = cdot(dot(lb.n, hv.h));
    let a2 = lb.a2;
    let q = nh * nh * (a2 - F::ONE) + F::ONE;
    let den = nl * lb.omk + lb.k;
    let t = F::ONE / (q * den);
    let inv_q = den * t;
    let gl = q * t;
    let d = lb.d0 * inv_q * inv_q;
    let gv = lb.gv;
    let fq = hv.fr * F::from_f64(0.25);
    let value = fq * d * gv * gl;
    // Roughness: through alpha^2 = r^4 in D and through k in both g terms.
    let inv_q3 = inv_q * inv_q * inv_q;
    let dd_dr = (q - F::from_f64(2.0) * a2 * nh * nh) * inv_q3 * lb.cr;
    let dk_dr = (lb.r + F::ONE) * F::from_f64(0.25);
    let dgv_dk = -(F::ONE - lb.nv) * gv * gv;
    let dgl_dk = -(F::ONE - nl) * gl * gl;
    let v_r = fq * (dd_dr * gv * gl + d * (dgv_dk * gl + gv * dgl_dk) * dk_dr);
    // Normal: through n.h (D), n.v and n.l (g terms).
    let zero = F::ZERO;
    let ds_dnh = if nh_live { fq * gv * gl * (lb.cn * nh * inv_q3) } else { zero };
    let ds_dnv = if lb.nv_live { -fq * d * gl * lb.omk * gv * gv } else { zero };
    let ds_dnl = if nl_live { -fq * d * gv * lb.omk * gl * gl } else { zero };
    let v_n = [0, 1, 2].map(|i| ds_dnh * hv.h[i] + ds_dnv * v[i] + ds_dnl * l[i]);
    SpecGrad { value, v_r, v_n }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::tests::unit;
    use crate::{ggx_specular, ggx_specular_grad};
    use svgir_core::Rng;

    #[test]
    fn split_form_equals_the_shading_crate() {
        let mut rng = Rng::new(21);
        for case in 0..2000 {
            // Include back-facing v / l so every clamp is exercised.
            let (n, v, l) = (unit(&mut rng), unit(&mut rng), unit(&mut rng));
            let r = rng.range(0.09, 0.99) as f64;
            let lb = lobe(n, v, r);
            let hv = half(v, l);
            let want = ggx_specular(n, v, l, r);
            let got = spec(&lb, &hv, dot(n, l));
            assert!((got - want).abs() <= 1e-12 * want.abs().max(1e-300), "case {case}: {got} vs {want}");
            let g = spec_grad(&lb, &hv, v, l, dot(n, l));
            let w = ggx_specular_grad(n, v, l, r);
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-10 * (a.abs() + b.abs()) + 1e-300;
            assert!(close(g.value, w.value), "case {case}");
            assert!(close(g.v_r, w.v_roughness), "case {case}: {} vs {}", g.v_r, w.v_roughness);
            for i in 0..3 {
                assert!(close(g.v_n[i], w.v_normal[i]), "case {case} n{i}: {} vs {}", g.v_n[i], w.v_normal[i]);
            }
        }
    }
}
