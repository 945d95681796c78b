//! The per-vertex colour of the viewer (the page's vertex shader computes the same):
//!
//! `c_m = k_d a_m / pi * max(0, sum_j L_j T_{m,j}) + s * P(R_m, r_m) * E * vis_m`, `E = (F0 A + B)(r_m, n.v)`
//!
//! with `L_j` the light's SH coefficients ([`crate::light::project_sh`]), `T` the vertex's
//! transfer ([`crate::model`]; per channel when it holds the one-bounce term), `P` the prefiltered map at the mirror direction
//! `R_m = 2 (n_m . v) n_m - v`, `v = normalize(cam - p_i)` per Gaussian as SPEC 3, `(A, B)` the
//! split-sum fit ([`crate::light::env_brdf`]), F0 = 0.04 (SPEC 3), `s` the light strength and
//! `vis_m` the vertex's cosine-weighted visibility (a scalar specular occlusion); `k_d` is 1, or
//! `1 - E` for a model trained with the layered diffuse (svgir-shading's `Diffuse::Layered`
//! with its tabulated directional albedo replaced by the same split-sum fit).

use crate::light::{env_brdf, lookup_prefiltered};
use crate::model::{ViewModel, MAT_FLOATS, VERTICES};
use glam::Vec3;

/// What the page shows per pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewMode {
    /// The relit image (sRGB).
    Rgb,
    /// Albedo (sRGB-encoded for display).
    Albedo,
    /// Roughness (grey).
    Roughness,
    /// Shading normal, `0.5 + 0.5 n` (world).
    Normal,
    /// Cosine-weighted visibility (grey).
    Visibility,
}

impl ViewMode {
    /// The page's name of the mode.
    pub fn name(self) -> &'static str {
        match self {
            Self::Rgb => "rgb",
            Self::Albedo => "albedo",
            Self::Roughness => "roughness",
            Self::Normal => "normal",
            Self::Visibility => "visibility",
        }
    }

    /// Parses a page name.
    pub fn parse(s: &str) -> Option<Self> {
        [Self::Rgb, Self::Albedo, Self::Roughness, Self::Normal, Self::Visibility].into_iter().find(|m| m.name() == s)
    }

    /// Whether the composited value is sRGB-encoded for display.
    pub fn srgb(self) -> bool {
        matches!(self, Self::Rgb | Self::Albedo)
    }
}

/// The light as the shading uses it.
pub struct Light<'a> {
    /// SH coefficients of the rotated light, strength included (`(degree + 1)^2`).
    pub sh: &'a [[f32; 3]],
    /// Prefiltered chain ([`crate::light::prefilter`]) of the unrotated, unscaled map.
    pub chain: &'a [[f32; 3]],
    /// Map width in texels (2 x height).
    pub width: u32,
    /// Map height in texels.
    pub height: u32,
    /// Rotation about +Z (radians).
    pub angle: f32,
    /// Radiance scale.
    pub strength: f32,
}

/// The M = 4 vertex colours of surfel `i` seen from `cam`. A two-sided model shades a surfel
/// seen from behind (`n . (cam - p) < 0`, svgir-pbr's `faces`) with its back-side transfer,
/// visibility and negated normals.
pub fn shade_surfel(model: &ViewModel, i: usize, cam: Vec3, light: &Light, mode: ViewMode) -> [[f32; 3]; VERTICES] {
    let g = &model.geom[i * crate::model::GEOM_FLOATS..];
    let p = Vec3::new(g[0], g[1], g[2]);
    let back = model.two_sided && Vec3::new(g[12], g[13], g[14]).dot(cam - p) < 0.0;
    let v = (cam - p).normalize();
    let c = model.coeffs();
    let pv = model.per_vertex();
    let mut out = [[0.0f32; 3]; VERTICES];
    for (m, o) in out.iter_mut().enumerate() {
        let q = i * VERTICES + m;
        let mt = &model.mats[q * MAT_FLOATS..(q + 1) * MAT_FLOATS];
        let (albedo, rough) = ([mt[0], mt[1], mt[2]], mt[3]);
        let (n, vis) =
            if back { (-Vec3::new(mt[4], mt[5], mt[6]), mt[8]) } else { (Vec3::new(mt[4], mt[5], mt[6]), mt[7]) };
        *o = match mode {
            ViewMode::Albedo => albedo,
            ViewMode::Roughness => [rough; 3],
            ViewMode::Normal => [0.5 + 0.5 * n.x, 0.5 + 0.5 * n.y, 0.5 + 0.5 * n.z],
            ViewMode::Visibility => [vis; 3],
            ViewMode::Rgb => {
                let tq = if back { model.n * VERTICES + q } else { q };
                let t = &model.transfer[tq * pv..(tq + 1) * pv];
                let mut irr = [0.0f32; 3];
                for ch in 0..3 {
                    let tc = if model.channels == 3 { &t[ch * c..(ch + 1) * c] } else { &t[..c] };
                    for j in 0..c {
                        irr[ch] += light.sh[j][ch] * tc[j];
                    }
                }
                let nv_raw = n.dot(v);
                let nv = nv_raw.clamp(1e-6, 1.0);
                let r = 2.0 * nv_raw * n - v;
                let pre = lookup_prefiltered(light.chain, light.width, light.height, r, rough, light.angle);
                let (a, b) = env_brdf(rough, nv);
                let e = 0.04 * a + b;
                let kd = if model.layered { 1.0 - e } else { 1.0 };
                let spec = e * vis * light.strength;
                [0, 1, 2].map(|ch| kd * albedo[ch] / std::f32::consts::PI * irr[ch].max(0.0) + pre[ch] * spec)
            }
        };
    }
    out
}
