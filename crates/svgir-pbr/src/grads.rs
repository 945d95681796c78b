//! The gradient bundle of the stage-2 shading terms, with respect to the *activated* quantities:
//! vertex albedo, roughness and unit shading normals (laid out like
//! `svgir_trace::VertexMaterials`), environment radiance texels (like `EnvMap::data`, before the
//! [0, 64] clamp) and the indirect scale rho. [`crate::material`] and [`crate::env`] chain them to
//! the raw parameters. Shading and the consistency loss return the same bundle so the trainer can
//! sum them before chaining once.

use rayon::prelude::*;
use svgir_core::par::filled;
use svgir_shading::Float;

/// Gradients of a stage-2 shading loss with respect to the activated materials, light and rho.
#[derive(Clone, Debug, PartialEq)]
pub struct PbrGrads<F = f32> {
    /// dL / d albedo per vertex and channel, N x M x 3.
    pub v_albedo: Vec<F>,
    /// dL / d roughness per vertex, N x M.
    pub v_roughness: Vec<F>,
    /// dL / d unit shading normal per vertex, N x M x 3.
    pub v_normals: Vec<F>,
    /// dL / d environment radiance per texel (before the clamp), row-major like `EnvMap::data`.
    pub v_env: Vec<[F; 3]>,
    /// dL / d rho, the indirect scale.
    pub v_rho: F,
}

impl<F: Float> PbrGrads<F> {
    /// All-zero gradients for N Gaussians with M vertices and `env_texels` texels.
    pub fn zeros(n: usize, m: usize, env_texels: usize) -> Self {
        Self {
            v_albedo: filled(n * m * 3, F::ZERO),
            v_roughness: filled(n * m, F::ZERO),
            v_normals: filled(n * m * 3, F::ZERO),
            v_env: vec![[F::ZERO; 3]; env_texels],
            v_rho: F::ZERO,
        }
    }

    /// `self += scale * other`; the shapes must match (returns false, changing nothing, if not).
    pub fn add_scaled(&mut self, other: &Self, scale: F) -> bool {
        if self.v_albedo.len() != other.v_albedo.len()
            || self.v_roughness.len() != other.v_roughness.len()
            || self.v_normals.len() != other.v_normals.len()
            || self.v_env.len() != other.v_env.len()
        {
            return false;
        }
        let pairs = [
            (&mut self.v_albedo, &other.v_albedo),
            (&mut self.v_roughness, &other.v_roughness),
            (&mut self.v_normals, &other.v_normals),
        ];
        for (a, b) in pairs {
            a.par_iter_mut().zip(b).with_min_len(4096).for_each(|(x, y)| *x += scale * *y);
        }
        for (x, y) in self.v_env.iter_mut().zip(&other.v_env) {
            for c in 0..3 {
                x[c] += scale * y[c];
            }
        }
        self.v_rho += scale * other.v_rho;
        true
    }
}
