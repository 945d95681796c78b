//! Test and benchmark inputs for vertex shading: synthetic micro-buffers, positions and
//! materials from fixed seeds, and a [`Problem`] (N Gaussians, M vertices, K directions) that the
//! tests, the divan bench (`benches/shade.rs`) and `svgir bench pbr` share. No I/O, no timing.

use crate::env::{EnvLight, ENV_HEIGHT};
use crate::material::{ActivatedMaterials, SvgMaterials};
use crate::shade::{Indirect, ShadeInputs, ShadeParams};
use crate::PbrError;
use glam::Vec3;
use svgir_core::{EnvMap, Rng};
use svgir_shading::gaussian_xi;
use svgir_trace::pack::{f16_from_f32, unorm16};
use svgir_trace::{MicroBuffer, NO_HIT};

/// A random micro-buffer of `n` Gaussians x `k` directions with a plausible mix of samples:
/// ~40% escaped (V = 1, no hit), ~40% blocked (V = 0, hit), ~20% partly visible; traced
/// radiance in [0, 2). Normals random; positions for it come from [`synthetic_positions`].
pub fn synthetic_microbuffer(n: usize, k: usize, seed: u64) -> MicroBuffer {
    let mut rng = Rng::new(seed);
    let normals: Vec<Vec3> =
        (0..n).map(|_| Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize_or(Vec3::Z)).collect();
    let xi = (0..n).map(|j| gaussian_xi(seed, j)).collect();
    let mut vis = Vec::with_capacity(n * k);
    let mut radiance = Vec::with_capacity(n * k);
    let mut first_hit = Vec::with_capacity(n * k);
    let mut uv = Vec::with_capacity(n * k);
    for _ in 0..n * k {
        let u = rng.uniform();
        let (v, hit) = if u < 0.4 {
            (1.0, NO_HIT)
        } else if u < 0.8 {
            (0.0, rng.below(n) as u32)
        } else {
            (rng.range(0.2, 1.0), rng.below(n) as u32)
        };
        vis.push(unorm16(v));
        let l = if hit == NO_HIT { [0.0; 3] } else { [rng.range(0.0, 2.0), rng.range(0.0, 2.0), rng.range(0.0, 2.0)] };
        radiance.push(l.map(f16_from_f32));
        first_hit.push(hit);
        uv.push([unorm16(rng.range(0.001, 0.999)), unorm16(rng.range(0.001, 0.999))]);
    }
    MicroBuffer { k, normals, xi, vis, radiance, first_hit, uv, interleave: Default::default() }
}

/// Positions 2-4 units from a camera at the origin, each Gaussian seen from its normal's side
/// at a random angle (`w_o = normalize(n + 0.6 noise)`).
pub fn synthetic_positions(mb: &MicroBuffer, seed: u64) -> Vec<Vec3> {
    let mut rng = Rng::new(seed ^ 0x5eed);
    mb.normals
        .iter()
        .map(|&n| {
            let wo = (n + 0.6 * Vec3::new(rng.normal(), rng.normal(), rng.normal())).normalize_or(n);
            -wo * rng.range(2.0, 4.0)
        })
        .collect()
}

/// Random raw materials (albedo, roughness spread over their ranges, small normal offsets).
pub fn synthetic_materials(n: usize, m: usize, seed: u64) -> SvgMaterials {
    let mut rng = Rng::new(seed ^ 0xa1b);
    SvgMaterials {
        m,
        albedo_raw: (0..n * m * 3).map(|_| rng.normal()).collect(),
        roughness_raw: (0..n * m).map(|_| rng.normal()).collect(),
        normal_offset: (0..n * m * 3).map(|_| 0.2 * rng.normal()).collect(),
    }
}

/// A synthetic shading problem: N Gaussians, M vertices, K directions, all visible, traced
/// indirect, 32 x 64 environment, and a random upstream gradient. Shared by the table below, the
/// divan bench and the profiling example.
pub struct Problem {
    /// Synthetic micro-buffers: N Gaussians x K traced directions.
    pub mb: MicroBuffer,
    /// Gaussian centres, N.
    pub positions: Vec<Vec3>,
    /// Random activated vertex materials, N x M.
    pub mats: ActivatedMaterials,
    /// The environment radiance (32 x 64) from a seeded [`EnvLight`].
    pub env: EnvMap,
    /// All true: every Gaussian is shaded.
    pub visible: Vec<bool>,
    /// Random upstream gradient on the shaded colour, N x M x 3.
    pub v_color: Vec<f32>,
}

impl Problem {
    /// Build the problem for N Gaussians, M vertices and K directions from fixed seeds.
    pub fn new(n: usize, m: usize, k: usize) -> Result<Self, PbrError> {
        let mb = synthetic_microbuffer(n, k, 1);
        let positions = synthetic_positions(&mb, 1);
        let mats = synthetic_materials(n, m, 1).activated(&mb.normals)?;
        let env = EnvLight::new(ENV_HEIGHT, 3)?.radiance();
        let mut rng = Rng::new(7);
        let v_color = (0..n * m * 3).map(|_| rng.normal()).collect();
        Ok(Self { mb, positions, mats, env, visible: vec![true; n], v_color })
    }

    /// The problem as shading inputs (camera at the origin, traced indirect, default parameters).
    pub fn inputs(&self) -> ShadeInputs<'_, f32> {
        ShadeInputs {
            mb: &self.mb,
            positions: &self.positions,
            camera_center: Vec3::ZERO,
            visible: &self.visible,
            mats: self.mats.view(),
            env_geom: &self.env,
            env: &self.env.data,
            indirect: Indirect::Traced { rho: 1.0 },
            params: ShadeParams::default(),
            lights: None,
        }
    }
}
