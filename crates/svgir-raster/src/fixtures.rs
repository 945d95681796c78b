//! Test and benchmark inputs: random surfel scenes shaped like a trained object, look-at
//! cameras, and a [`Problem`] (scene, camera, upstream gradients) that the tests, the divan
//! bench (`benches/raster.rs`), the GPU tests and `svgir bench` share. No I/O, no timing.
//!
//! Scene: `n` surfels on and near a unit sphere (an "object"), oriented roughly tangent to it,
//! sizes of a trained object scene (sigma ~ 0.006 with log-normal spread), opacity logits in
//! [-1, 3], SH degree 3 with small random higher bands; the camera sits 3.2 units away with a
//! 40-degree field of view.

use crate::{Background, ColorSource, OutputGrads, RenderInput};
use glam::{Mat4, Quat, Vec2, Vec3};
use svgir_core::{sh, Camera, Intrinsics, Rng, ShCoeffs, Surfels};

/// A look-at camera at `eye` towards the origin (Blender axes, +Z up), `width` x `height`.
pub fn look_at_camera(eye: Vec3, fov_x: f32, width: u32, height: u32) -> Camera {
    let back = eye.normalize();
    let right = Vec3::Z.cross(back).normalize();
    let up = back.cross(right);
    let c2w = Mat4::from_cols(right.extend(0.0), up.extend(0.0), back.extend(0.0), eye.extend(1.0));
    Camera::from_blender_c2w(c2w, Intrinsics::from_fov_x(fov_x, width, height)).expect("look-at camera is rigid")
}

/// The benchmark camera.
pub fn bench_camera(width: u32, height: u32) -> Camera {
    look_at_camera(Vec3::new(2.4, -1.8, 1.2).normalize() * 3.2, 0.7, width, height)
}

/// A benchmark problem: the scene, the camera, and a uniform upstream gradient on colour,
/// opacity, depth, normal and distortion (so every backward path runs). Shared by the table
/// below, the divan bench and the profiling example.
pub struct Problem {
    /// The Gaussians.
    pub surfels: Surfels,
    /// The camera rendered from.
    pub camera: Camera,
    g3: Vec<f32>,
    g1: Vec<f32>,
}

impl Problem {
    /// `n` random Gaussians (seed 7) seen by the benchmark camera at `res x res`.
    pub fn new(n: usize, res: u32) -> Self {
        Self::with_surfels(random_scene(n, 7), res)
    }

    /// Given Gaussians seen by the benchmark camera at `res x res`.
    pub fn with_surfels(surfels: Surfels, res: u32) -> Self {
        Self::with_camera(surfels, bench_camera(res, res))
    }

    /// Given Gaussians and camera.
    pub fn with_camera(surfels: Surfels, camera: Camera) -> Self {
        let npx = camera.intrinsics.width as usize * camera.intrinsics.height as usize;
        Self { surfels, camera, g3: vec![1e-3; npx * 3], g1: vec![1e-3; npx] }
    }

    /// Render input: SH colours, black background, no extra features.
    pub fn input(&self) -> RenderInput<'_> {
        RenderInput {
            surfels: &self.surfels,
            camera: &self.camera,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color([0.0; 3]),
        }
    }

    /// Upstream gradients: `1e-3` on colour, alpha, depth, normal and distortion.
    pub fn grads(&self) -> OutputGrads<'_> {
        OutputGrads {
            color: Some(&self.g3),
            alpha: Some(&self.g1),
            depth: Some(&self.g1),
            normal: Some(&self.g3),
            distortion: Some(&self.g1),
            extra: None,
        }
    }
}

/// `n` random surfels shaped like a trained object scene (see the module docs).
pub fn random_scene(n: usize, seed: u64) -> Surfels {
    let mut rng = Rng::new(seed);
    let mut s = Surfels::with_capacity(n, 3);
    for _ in 0..n {
        let d = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize_or(Vec3::Z);
        let p = d * (1.0 + 0.02 * rng.normal());
        // Rotation taking +Z to roughly the sphere normal, with a random twist.
        let nrm = (d + 0.2 * Vec3::new(rng.normal(), rng.normal(), rng.normal())).normalize_or(Vec3::Z);
        let q = Quat::from_rotation_arc(Vec3::Z, nrm) * Quat::from_rotation_z(rng.range(0.0, std::f32::consts::TAU));
        let ls = Vec2::new((0.006f32).ln() + 0.5 * rng.normal(), (0.006f32).ln() + 0.5 * rng.normal());
        let mut c = ShCoeffs::from_rgb([rng.uniform(), rng.uniform(), rng.uniform()]);
        for k in 1..sh::num_coeffs(3) {
            for ch in 0..3 {
                c.0[k][ch] = 0.05 * rng.normal();
            }
        }
        s.push(p, q, ls, rng.range(-1.0, 3.0), c);
    }
    s
}
