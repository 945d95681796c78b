//! Shared helpers of the integration tests: f64 surfel parameters, small scenes, random losses.
#![allow(dead_code)]

use glam::{Quat, Vec2, Vec3};
use svgir_core::{Camera, Rng, ShCoeffs, Surfels};
use svgir_raster::fixtures::look_at_camera;
use svgir_raster::{GaussianParams, OutputGradsOf, RenderOutputOf};

/// Raw surfel parameters in f64 (so finite differences can use tiny steps).
#[derive(Clone, Debug)]
pub struct P64 {
    pub pos: Vec<[f64; 3]>,
    pub rot: Vec<[f64; 4]>,
    pub ls: Vec<[f64; 2]>,
    pub logit: Vec<f64>,
    pub sh: Vec<[[f64; 3]; 16]>,
    pub deg: u32,
}

impl GaussianParams<f64> for P64 {
    fn count(&self) -> usize {
        self.pos.len()
    }
    fn sh_degree(&self) -> u32 {
        self.deg
    }
    fn position(&self, i: usize) -> [f64; 3] {
        self.pos[i]
    }
    fn rotation(&self, i: usize) -> [f64; 4] {
        self.rot[i]
    }
    fn log_scale(&self, i: usize) -> [f64; 2] {
        self.ls[i]
    }
    fn opacity_logit(&self, i: usize) -> f64 {
        self.logit[i]
    }
    fn sh(&self, i: usize, k: usize, ch: usize) -> f64 {
        self.sh[i][k][ch]
    }
}

impl P64 {
    pub fn from_surfels(s: &Surfels) -> Self {
        let f = |v: f32| v as f64;
        Self {
            pos: s.positions.iter().map(|p| p.to_array().map(f)).collect(),
            rot: s.rotations.iter().map(|q| q.to_array().map(f)).collect(),
            ls: s.log_scales.iter().map(|q| q.to_array().map(f)).collect(),
            logit: s.opacity_logits.iter().map(|&v| f(v)).collect(),
            sh: s.sh.iter().map(|c| c.0.map(|r| r.map(f))).collect(),
            deg: s.sh_degree,
        }
    }

    /// Number of scalar parameters per Gaussian: 3 + 4 + 2 + 1 + 48.
    pub const PER: usize = 58;

    pub fn param_mut(&mut self, i: usize, j: usize) -> &mut f64 {
        match j {
            0..3 => &mut self.pos[i][j],
            3..7 => &mut self.rot[i][j - 3],
            7..9 => &mut self.ls[i][j - 7],
            9 => &mut self.logit[i],
            _ => &mut self.sh[i][(j - 10) / 3][(j - 10) % 3],
        }
    }

    pub fn param_name(j: usize) -> String {
        match j {
            0..3 => format!("position[{j}]"),
            3..7 => format!("rotation[{}]", j - 3),
            7..9 => format!("log_scale[{}]", j - 7),
            9 => "opacity_logit".into(),
            _ => format!("sh[{}][{}]", (j - 10) / 3, (j - 10) % 3),
        }
    }
}

pub fn test_camera(w: u32, h: u32) -> Camera {
    look_at_camera(Vec3::new(2.2, -1.6, 1.1).normalize() * 3.0, 0.8, w, h)
}

fn random_sh(rng: &mut Rng) -> ShCoeffs {
    let mut c = ShCoeffs::from_rgb([rng.uniform(), rng.uniform(), rng.uniform()]);
    for k in 1..16 {
        for ch in 0..3 {
            c.0[k][ch] = 0.2 * rng.normal();
        }
    }
    c
}

/// A small scene seen by [`test_camera`]: overlapping surfels near the origin, one at a grazing
/// angle to the view, one whose centre is behind the near plane, one large and translucent.
pub fn small_scene(seed: u64, n: usize) -> Surfels {
    let mut rng = Rng::new(seed);
    let cam = test_camera(8, 8);
    let mut s = Surfels::with_capacity(n + 3, 3);
    for _ in 0..n {
        let p = Vec3::new(rng.normal(), rng.normal(), rng.normal()) * 0.35;
        let q = Quat::from_xyzw(rng.normal(), rng.normal(), rng.normal(), rng.normal()) * rng.range(0.5, 2.0);
        let ls = Vec2::new(rng.range(-2.0, -0.9), rng.range(-2.0, -0.9));
        s.push(p, q, ls, rng.range(-1.5, 2.5), random_sh(&mut rng));
    }
    // Grazing: normal almost perpendicular to the viewing direction.
    let view = (Vec3::new(0.1, 0.1, 0.0) - cam.center()).normalize();
    let side = view.cross(Vec3::Z).normalize();
    let nrm = (side + 0.12 * view).normalize();
    let q = Quat::from_rotation_arc(Vec3::Z, nrm) * Quat::from_rotation_z(0.4);
    s.push(Vec3::new(0.1, 0.1, 0.0), q, Vec2::new(-1.2, -1.6), 1.0, random_sh(&mut rng));
    // Behind the near plane (centre 0.1 in front of the camera).
    let p = cam.center() + cam.forward() * 0.1;
    s.push(p, Quat::from_rotation_x(0.3), Vec2::new(-1.0, -1.0), 1.0, random_sh(&mut rng));
    // Large, translucent, in front of the others.
    let p = cam.center() * 0.3;
    let q = Quat::from_rotation_arc(Vec3::Z, -cam.forward()) * Quat::from_rotation_z(0.7);
    s.push(p, q, Vec2::new(-0.8, -1.3), -0.8, random_sh(&mut rng));
    s
}

/// Random per-pixel weights for every output: the loss is `sum weights * outputs`.
pub struct LossWeights {
    pub color: Vec<f64>,
    pub alpha: Vec<f64>,
    pub depth: Vec<f64>,
    pub normal: Vec<f64>,
    pub distortion: Vec<f64>,
    pub extra: Vec<f64>,
}

impl LossWeights {
    pub fn new(seed: u64, npx: usize, extra_channels: usize) -> Self {
        let mut rng = Rng::new(seed ^ 0x1234);
        let mut v = |n: usize, s: f64| (0..n).map(|_| s * (rng.uniform_f64() * 2.0 - 1.0)).collect::<Vec<f64>>();
        Self {
            color: v(npx * 3, 1.0),
            alpha: v(npx, 1.0),
            depth: v(npx, 0.3),
            normal: v(npx * 3, 1.0),
            distortion: v(npx, 30.0),
            extra: v(npx * extra_channels, 1.0),
        }
    }

    pub fn loss(&self, o: &RenderOutputOf<f64>) -> f64 {
        let d = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        d(&self.color, &o.color)
            + d(&self.alpha, &o.alpha)
            + d(&self.depth, &o.depth)
            + d(&self.normal, &o.normal)
            + d(&self.distortion, &o.distortion)
            + d(&self.extra, &o.extra)
    }

    pub fn grads(&self) -> OutputGradsOf<'_, f64> {
        OutputGradsOf {
            color: Some(&self.color),
            alpha: Some(&self.alpha),
            depth: Some(&self.depth),
            normal: Some(&self.normal),
            distortion: Some(&self.distortion),
            extra: if self.extra.is_empty() { None } else { Some(&self.extra) },
        }
    }
}

/// Largest |a - b| over two buffers.
pub fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).fold(0.0, |m, (x, y)| m.max((x - y).abs()))
}

pub fn random_vec(rng: &mut Rng, n: usize, lo: f64, hi: f64) -> Vec<f64> {
    (0..n).map(|_| lo + (hi - lo) * rng.uniform_f64()).collect()
}
