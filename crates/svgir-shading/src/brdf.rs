//! Cook-Torrance GGX BRDF exactly as SPEC 4, with hand-written gradients.
//!
//! `f = a/pi + F*D*G / (4 (n.l)(n.v))`, `alpha = r^2`, `D = alpha^2 / (pi ((n.h)^2 (alpha^2-1)+1)^2)`,
//! `G = G1(n.v) G1(n.l)`, `G1(x) = x / (x(1-k)+k)`, `k = (r+1)^2/8`,
//! `F = F0 + (1-F0) 2^((-5.55473 (v.h) - 6.98316)(v.h))`, F0 = 0.04, every dot product clamped to
//! [1e-6, 1]. The specular part is grey (F0 has no colour), so `f_c = a_c/pi + S` with one scalar S.
//! We evaluate S as `F D g(n.v) g(n.l) / 4` with `g(x) = G1(x)/x = 1/(x(1-k)+k)`: algebraically
//! identical (x >= 1e-6 > 0) and it avoids dividing two tiny numbers at grazing angles.
//!
//! Gradients: `d f_c / d a_c = 1/pi` (constant), and [`ggx_specular_grad`] returns dS/dr and dS/dn
//! with respect to the *unit* normal passed in (callers chain through their normalisation). Where
//! a clamp is active its derivative is zero. `v` and `l` are treated as constants.

use crate::float::{dot, Float};
use crate::layering::Diffuse;
use std::f64::consts::PI;

/// Normal-incidence Fresnel reflectance of the dielectric-only model (no metallic; SPEC 3-4).
pub const F0: f64 = 0.04;
/// Lower clamp of every dot product (SPEC 4).
pub const DOT_EPS: f64 = 1e-6;

/// Value and gradients of the specular term S.
#[derive(Clone, Copy, Debug)]
pub struct SpecularGrad<F> {
    /// The specular term S itself.
    pub value: F,
    /// dS / d roughness.
    pub v_roughness: F,
    /// dS / d n (unit normal, as passed).
    pub v_normal: [F; 3],
}

#[inline]
fn half_vector<F: Float>(v: [F; 3], l: [F; 3]) -> [F; 3] {
    let h = [v[0] + l[0], v[1] + l[1], v[2] + l[2]];
    let len = dot(h, h).sqrt().maxf(F::from_f64(1e-12));
    [h[0] / len, h[1] / len, h[2] / len]
}

/// Clamped dot product and whether the clamp is inactive (derivative passes).
#[inline]
fn cdot<F: Float>(a: [F; 3], b: [F; 3]) -> (F, bool) {
    let x = dot(a, b);
    let lo = F::from_f64(DOT_EPS);
    (x.clampf(lo, F::ONE), x > lo && x < F::ONE)
}

#[inline]
fn fresnel<F: Float>(vh: F) -> F {
    let f0 = F::from_f64(F0);
    f0 + (F::ONE - f0) * ((F::from_f64(-5.55473) * vh - F::from_f64(6.98316)) * vh).exp2()
}

/// Specular term S(n, v, l; r); `n`, `v` (towards the viewer) and `l` (towards the light) unit.
#[inline]
pub fn ggx_specular<F: Float>(n: [F; 3], v: [F; 3], l: [F; 3], r: F) -> F {
    let h = half_vector(v, l);
    let (nl, _) = cdot(n, l);
    let (nv, _) = cdot(n, v);
    let (nh, _) = cdot(n, h);
    let (vh, _) = cdot(v, h);
    let a = r * r;
    let a2 = a * a;
    let q = nh * nh * (a2 - F::ONE) + F::ONE;
    let d = a2 / (F::from_f64(PI) * q * q);
    let k = (r + F::ONE) * (r + F::ONE) / F::from_f64(8.0);
    let gv = F::ONE / (nv * (F::ONE - k) + k);
    let gl = F::ONE / (nl * (F::ONE - k) + k);
    fresnel(vh) * d * gv * gl / F::from_f64(4.0)
}

/// Full BRDF value per channel: `t albedo/pi + S`, with t = 1 for SPEC 4's [`Diffuse::Added`]
/// and `1 - E(n.v, r)` for [`Diffuse::Layered`].
#[inline]
pub fn ggx<F: Float>(n: [F; 3], v: [F; 3], l: [F; 3], albedo: [F; 3], r: F, diffuse: Diffuse) -> [F; 3] {
    let s = ggx_specular(n, v, l, r);
    let kd = F::from_f64(1.0 / PI) * diffuse.weight(dot(n, v), r).value;
    albedo.map(|a| a * kd + s)
}

/// S together with dS/dr and dS/dn.
#[inline]
pub fn ggx_specular_grad<F: Float>(n: [F; 3], v: [F; 3], l: [F; 3], r: F) -> SpecularGrad<F> {
    let h = half_vector(v, l);
    let (nl, nl_on) = cdot(n, l);
    let (nv, nv_on) = cdot(n, v);
    let (nh, nh_on) = cdot(n, h);
    let (vh, _) = cdot(v, h);
    let pi = F::from_f64(PI);
    let a = r * r;
    let a2 = a * a;
    let q = nh * nh * (a2 - F::ONE) + F::ONE;
    let d = a2 / (pi * q * q);
    let k = (r + F::ONE) * (r + F::ONE) / F::from_f64(8.0);
    let gv = F::ONE / (nv * (F::ONE - k) + k);
    let gl = F::ONE / (nl * (F::ONE - k) + k);
    let fr = fresnel(vh);
    let quarter = F::from_f64(0.25);
    let value = fr * d * gv * gl * quarter;

    // Roughness: through alpha^2 = r^4 in D and through k in both g terms.
    let dd_da2 = (q - F::from_f64(2.0) * a2 * nh * nh) / (pi * q * q * q);
    let dd_dr = dd_da2 * F::from_f64(4.0) * r * r * r;
    let dk_dr = (r + F::ONE) * quarter;
    let dgv_dk = -(F::ONE - nv) * gv * gv;
    let dgl_dk = -(F::ONE - nl) * gl * gl;
    let v_roughness = fr * quarter * (dd_dr * gv * gl + d * (dgv_dk * gl + gv * dgl_dk) * dk_dr);

    // Normal: through n.h (D), n.v and n.l (g terms); zero where a clamp is active.
    let zero = F::ZERO;
    let ds_dnh = if nh_on {
        fr * quarter * gv * gl * (-F::from_f64(4.0) * a2 * nh * (a2 - F::ONE) / (pi * q * q * q))
    } else {
        zero
    };
    let ds_dnv = if nv_on { fr * d * gl * quarter * (-(F::ONE - k) * gv * gv) } else { zero };
    let ds_dnl = if nl_on { fr * d * gv * quarter * (-(F::ONE - k) * gl * gl) } else { zero };
    let v_normal = [0, 1, 2].map(|i| ds_dnh * h[i] + ds_dnv * v[i] + ds_dnl * l[i]);
    SpecularGrad { value, v_roughness, v_normal }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use svgir_core::Rng;

    /// A random unit vector (shared by the shading crate's tests).
    pub(crate) fn unit(rng: &mut Rng) -> [f64; 3] {
        let v = [rng.normal() as f64, rng.normal() as f64, rng.normal() as f64];
        let l = dot(v, v).sqrt();
        v.map(|x| x / l)
    }

    /// A unit vector in the upper hemisphere of `n`.
    fn upper(rng: &mut Rng, n: [f64; 3]) -> [f64; 3] {
        loop {
            let d = unit(rng);
            if dot(d, n) > 0.05 {
                return d;
            }
        }
    }

    #[test]
    fn f32_and_f64_agree_and_value_is_textbook() {
        // Normal incidence, v = l = n: D = 1/(pi alpha^2), F = F0 + (1-F0) 2^(-12.53789), g = 1.
        let n = [0.0, 0.0, 1.0f64];
        let r = 0.5f64;
        let s = ggx_specular(n, n, n, r);
        let alpha = r * r;
        let want = (F0 + (1.0 - F0) * (-12.53789f64).exp2()) / (PI * alpha * alpha) / 4.0;
        assert!((s - want).abs() < 1e-12 * want.max(1.0), "{s} vs {want}");
        let mut rng = Rng::new(3);
        for _ in 0..100 {
            let n = unit(&mut rng);
            let (v, l) = (upper(&mut rng, n), upper(&mut rng, n));
            let r = rng.range(0.09, 0.99) as f64;
            let a = ggx_specular(n, v, l, r);
            let b = ggx_specular(n.map(|x| x as f32), v.map(|x| x as f32), l.map(|x| x as f32), r as f32) as f64;
            assert!((a - b).abs() <= 1e-4 * a.abs().max(1.0), "{a} vs {b}");
        }
    }

    #[test]
    fn gradients_match_finite_differences_f64() {
        let mut rng = Rng::new(11);
        let h = 1e-6;
        for case in 0..300 {
            let n = unit(&mut rng);
            let (v, l) = (upper(&mut rng, n), upper(&mut rng, n));
            let r = rng.range(0.09, 0.99) as f64;
            let g = ggx_specular_grad(n, v, l, r);
            assert!((g.value - ggx_specular(n, v, l, r)).abs() < 1e-14 * g.value.max(1.0));
            let fd = (ggx_specular(n, v, l, r + h) - ggx_specular(n, v, l, r - h)) / (2.0 * h);
            let tol = 1e-5 * (1.0 + fd.abs());
            assert!((fd - g.v_roughness).abs() < tol, "case {case} dr: fd {fd} vs {}", g.v_roughness);
            for i in 0..3 {
                let (mut np, mut nm) = (n, n);
                np[i] += h;
                nm[i] -= h;
                let fd = (ggx_specular(np, v, l, r) - ggx_specular(nm, v, l, r)) / (2.0 * h);
                let tol = 1e-5 * (1.0 + fd.abs());
                assert!((fd - g.v_normal[i]).abs() < tol, "case {case} dn{i}: fd {fd} vs {}", g.v_normal[i]);
            }
        }
        // Albedo: f_c = a_c/pi + S, so df_c/da_c = 1/pi exactly.
        let n = [0.0, 0.6, 0.8];
        let f1 = ggx(n, n, n, [0.3, 0.4, 0.5], 0.5f64, Diffuse::Added);
        let f2 = ggx(n, n, n, [0.3 + 1e-3, 0.4, 0.5], 0.5f64, Diffuse::Added);
        assert!(((f2[0] - f1[0]) / 1e-3 - 1.0 / PI).abs() < 1e-9 && f2[1] == f1[1]);
    }

    /// White-furnace-style sanity: with albedo 1 the Lambertian part integrates to exactly 1, and
    /// the grey specular lobe's directional albedo `int S cos dl` lies in (0, 1) (Smith-Schlick G
    /// loses energy, it never creates it). The SPEC's BRDF simply adds the two lobes, so their sum
    /// can exceed 1 by the specular albedo; that is the model, not a bug, and is asserted as such.
    #[test]
    fn directional_albedo_is_bounded() {
        let n = [0.0, 0.0, 1.0f64];
        let (nt, np) = (400, 400);
        for &r in &[0.09f64, 0.3, 0.6, 0.99] {
            for &theta_v in &[0.0f64, 0.5, 1.0, 1.4] {
                let v = [theta_v.sin(), 0.0, theta_v.cos()];
                let (mut spec, mut total) = (0.0, 0.0);
                for (l, dl) in crate::quadrature::stratified_hemisphere(nt, np) {
                    let w = l[2] * dl;
                    spec += ggx_specular(n, v, l, r) * w;
                    total += ggx(n, v, l, [1.0; 3], r, Diffuse::Added)[0] * w;
                }
                let diffuse = total - spec;
                assert!((diffuse - 1.0).abs() < 1e-4, "r={r} theta={theta_v}: diffuse albedo {diffuse}");
                assert!(spec > 0.0 && spec < 1.0, "r={r} theta={theta_v}: specular albedo {spec}");
            }
        }
    }
}
