//! Energy-conserving diffuse layering, an option beside SPEC 4's BRDF (docs/method.md, "Where svgir
//! differs from SPEC").
//!
//! SPEC 4 adds the lobes: `f = a/pi + S`. Cycles' Principled BSDF, which renders the synthetic
//! ground truth, puts the diffuse base *under* the dielectric specular layer and dims it by the
//! energy that layer reflects: `f = (1 - E(n.v, r)) a/pi + S`, with `E(mu, r) = int S(n, v, l)
//! (n.l) dl` the directional albedo of the specular lobe (4-18% at F0 = 0.04, rising towards
//! grazing views). Without it our shading of the *true* materials is a few percent too bright,
//! and the evaluation (SPEC 8), which rescales the albedo to the ground truth before relighting,
//! keeps that excess. [`Diffuse::Layered`] uses the albedo of our own lobe (`ggx_specular`:
//! Schlick-type Fresnel, Smith-Schlick G), so the model stays self-consistent.
//!
//! E is tabulated once (lazily, in f64) on a `MU_NODES x R_NODES` grid over (n.v, r) in [0, 1]^2
//! by stratified GGX importance sampling, and looked up bilinearly; the derivatives are the
//! bilinear cell's, so gradient checks agree with finite differences inside a cell.

use crate::brdf::{ggx_specular, DOT_EPS};
use crate::float::Float;
use std::f64::consts::PI;
use std::sync::OnceLock;

/// How the diffuse lobe combines with the specular one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Diffuse {
    /// SPEC 4: `a/pi + S`.
    #[default]
    Added,
    /// Cycles-like: `(1 - E(n.v, r)) a/pi + S`.
    Layered,
}

/// Grid nodes along n.v and along the roughness.
pub const MU_NODES: usize = 65;
/// Number of roughness grid nodes over [0, 1] (see [`MU_NODES`]).
pub const R_NODES: usize = 33;
/// The r = 0 column is integrated at this roughness (SPEC 4's lobe degenerates at r = 0).
const R_FLOOR: f64 = 0.01;
/// Stratified samples per axis when integrating one node.
const SAMPLES_PER_AXIS: usize = 96;

/// The diffuse weight `t = 1 - E` (or 1) and its derivatives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiffuseWeight<F> {
    /// The weight t itself.
    pub value: F,
    /// dt / d(n.v); zero where n.v is clamped.
    pub v_mu: F,
    /// dt / dr; zero outside [0, 1].
    pub v_r: F,
}

impl Diffuse {
    /// Weight of `a/pi` for `nv = n.v` (unclamped) and roughness `r`.
    #[inline]
    pub fn weight<F: Float>(self, nv: F, r: F) -> DiffuseWeight<F> {
        match self {
            Diffuse::Added => DiffuseWeight { value: F::ONE, v_mu: F::ZERO, v_r: F::ZERO },
            Diffuse::Layered => {
                let e = specular_albedo(nv, r);
                DiffuseWeight { value: F::ONE - e.value, v_mu: -e.v_mu, v_r: -e.v_r }
            }
        }
    }
}

/// E(mu, r) by bilinear lookup, with its derivatives (same layout as [`DiffuseWeight`]).
pub fn specular_albedo<F: Float>(nv: F, r: F) -> DiffuseWeight<F> {
    let table = table();
    let lo = F::from_f64(DOT_EPS);
    let mu_live = nv > lo && nv < F::ONE;
    let r_live = r > F::ZERO && r < F::ONE;
    let x = nv.clampf(lo, F::ONE) * F::from_f64((MU_NODES - 1) as f64);
    let y = r.clampf(F::ZERO, F::ONE) * F::from_f64((R_NODES - 1) as f64);
    let (i, fx) = cell(x, MU_NODES);
    let (j, fy) = cell(y, R_NODES);
    let at = |i: usize, j: usize| F::from_f64(table[i * R_NODES + j]);
    let (e00, e01, e10, e11) = (at(i, j), at(i, j + 1), at(i + 1, j), at(i + 1, j + 1));
    let ex0 = e00 + (e10 - e00) * fx;
    let ex1 = e01 + (e11 - e01) * fx;
    let value = ex0 + (ex1 - ex0) * fy;
    let dx = (e10 - e00) + ((e11 - e01) - (e10 - e00)) * fy;
    let dy = ex1 - ex0;
    let zero = F::ZERO;
    DiffuseWeight {
        value,
        v_mu: if mu_live { dx * F::from_f64((MU_NODES - 1) as f64) } else { zero },
        v_r: if r_live { dy * F::from_f64((R_NODES - 1) as f64) } else { zero },
    }
}

/// Cell index (so that index + 1 is a node) and the fraction inside it, for x in [0, nodes-1].
/// The cast truncates, which is the floor for x >= 0 (and NaN casts to 0 either way); `floor`
/// itself is a libm call on baseline x86-64, about a sixth of a Gaussian's shading set-up.
#[inline]
fn cell<F: Float>(x: F, nodes: usize) -> (usize, F) {
    let i = (x.to_f64() as usize).min(nodes - 2);
    (i, x - F::from_f64(i as f64))
}

/// The table of E(mu, r) that [`specular_albedo`] interpolates, `MU_NODES` x `R_NODES`,
/// row-major in mu (for a device kernel that interpolates it the same way).
pub fn specular_albedo_table() -> &'static [f64] {
    table()
}

fn table() -> &'static [f64] {
    static TABLE: OnceLock<Vec<f64>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = vec![0.0; MU_NODES * R_NODES];
        for i in 0..MU_NODES {
            let mu = (i as f64 / (MU_NODES - 1) as f64).max(DOT_EPS);
            for j in 0..R_NODES {
                let r = (j as f64 / (R_NODES - 1) as f64).max(R_FLOOR);
                t[i * R_NODES + j] = integrate(mu, r);
            }
        }
        t
    })
}

/// `int S(n, v, l) (n.l) dl` for n = z, v at n.v = mu: GGX half-vector importance sampling,
/// pdf(l) = D (n.h) / (4 v.h), on a stratified grid.
fn integrate(mu: f64, r: f64) -> f64 {
    let n = [0.0, 0.0, 1.0];
    let v = [(1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu];
    let a2 = r.powi(4);
    let s = SAMPLES_PER_AXIS;
    let mut sum = 0.0;
    for iu in 0..s {
        let u1 = (iu as f64 + 0.5) / s as f64;
        let cos2 = (1.0 - u1) / (1.0 + (a2 - 1.0) * u1);
        let (ch, sh) = (cos2.sqrt(), (1.0 - cos2).max(0.0).sqrt());
        for ip in 0..s {
            let phi = 2.0 * PI * (ip as f64 + 0.5) / s as f64;
            let h = [sh * phi.cos(), sh * phi.sin(), ch];
            let vh = v[0] * h[0] + v[2] * h[2];
            if vh <= 0.0 {
                continue;
            }
            let l = [2.0 * vh * h[0] - v[0], 2.0 * vh * h[1] - v[1], 2.0 * vh * h[2] - v[2]];
            if l[2] <= 0.0 {
                continue;
            }
            let q = cos2 * (a2 - 1.0) + 1.0;
            let pdf = a2 / (PI * q * q) * ch / (4.0 * vh);
            sum += ggx_specular(n, v, l, r) * l[2] / pdf;
        }
    }
    sum / (s * s) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;

    /// Brute force: a dense stratified grid over the hemisphere in (cos theta, phi).
    fn brute(mu: f64, r: f64) -> f64 {
        let n = [0.0, 0.0, 1.0];
        let v = [(1.0 - mu * mu).sqrt(), 0.0, mu];
        crate::quadrature::stratified_hemisphere(1500, 600).map(|(l, w)| ggx_specular(n, v, l, r) * l[2] * w).sum()
    }

    #[test]
    fn table_matches_brute_force_integration() {
        // Nodes and points between nodes, away from the r -> 0 spike (which brute force cannot resolve).
        for &(mu, r) in &[(1.0, 0.5), (0.5, 0.25), (0.2, 0.75), (0.83, 0.41), (0.07, 0.6), (0.31, 0.97), (0.6, 0.3)] {
            let got = specular_albedo(mu, r).value;
            let want = brute(mu, r);
            assert!((got - want).abs() < 0.004 + 0.03 * want, "mu={mu} r={r}: table {got}, brute force {want}");
            assert!(got > 0.0 && got < 1.0);
        }
    }

    #[test]
    fn layered_weight_is_a_fraction_and_added_is_one() {
        let mut rng = Rng::new(5);
        for _ in 0..500 {
            let (nv, r) = (rng.uniform() as f64 * 1.2 - 0.1, rng.uniform() as f64);
            let t = Diffuse::Layered.weight(nv, r);
            assert!(t.value > 0.5 && t.value < 1.0, "nv={nv} r={r}: {t:?}");
            assert_eq!(Diffuse::Added.weight(nv, r), DiffuseWeight { value: 1.0, v_mu: 0.0, v_r: 0.0 });
        }
        // At normal view the specular layer reflects about F0.
        let e = specular_albedo(1.0f64, 0.5).value;
        assert!((0.03..0.06).contains(&e), "{e}");
        // Grazing views of a smooth surface reflect more (Fresnel; at n.v -> 0 Smith-Schlick
        // masking takes it back to 0).
        assert!(specular_albedo(0.2f64, 0.2).value > 2.0 * specular_albedo(1.0f64, 0.2).value);
    }

    #[test]
    fn derivatives_match_finite_differences_f64() {
        let mut rng = Rng::new(9);
        let h = 1e-7;
        for _ in 0..300 {
            let (nv, r) = (0.02 + 0.96 * rng.uniform() as f64, 0.02 + 0.96 * rng.uniform() as f64);
            let w = Diffuse::Layered.weight(nv, r);
            // Stay inside the cell: skip points within h of a grid line.
            let near = |x: f64, nodes: usize| {
                let s = x * (nodes - 1) as f64;
                (s - s.round()).abs() < 1e-5
            };
            if near(nv, MU_NODES) || near(r, R_NODES) {
                continue;
            }
            let fd_mu =
                (Diffuse::Layered.weight(nv + h, r).value - Diffuse::Layered.weight(nv - h, r).value) / (2.0 * h);
            let fd_r =
                (Diffuse::Layered.weight(nv, r + h).value - Diffuse::Layered.weight(nv, r - h).value) / (2.0 * h);
            assert!((fd_mu - w.v_mu).abs() < 1e-6 * (1.0 + fd_mu.abs()), "mu: fd {fd_mu}, analytic {}", w.v_mu);
            assert!((fd_r - w.v_r).abs() < 1e-6 * (1.0 + fd_r.abs()), "r: fd {fd_r}, analytic {}", w.v_r);
        }
        // Clamped n.v (back-facing view) passes no gradient.
        assert_eq!(Diffuse::Layered.weight(-0.3f64, 0.5).v_mu, 0.0);
    }
}
