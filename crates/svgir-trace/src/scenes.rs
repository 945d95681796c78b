//! Synthetic surfel scenes for tests and benchmarks (deterministic from a seed).

use crate::traverse::{Ray, TraceParams};
use glam::{Quat, Vec2, Vec3};
use svgir_core::{surfel::logit, Rng, ShCoeffs, Surfels};
use svgir_shading::hemisphere_dir;

fn random_sh(rng: &mut Rng) -> ShCoeffs {
    let mut sh = ShCoeffs::from_rgb([rng.uniform(), rng.uniform(), rng.uniform()]);
    for k in 1..16 {
        for c in 0..3 {
            sh.0[k][c] = 0.1 * rng.normal();
        }
    }
    sh
}

/// `n` randomly oriented disks in [-1, 1]^3, sized so that a ray crosses a handful of them;
/// random opacities (many low), degree-3 SH. Good for exercising ordering and transmittance.
pub fn random_scene(n: usize, seed: u64) -> Surfels {
    let mut rng = Rng::new(seed);
    let mut s = Surfels::with_capacity(n, 3);
    let base = 0.9 / (n.max(1) as f32).cbrt();
    for _ in 0..n {
        let p = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
        let q = Quat::from_xyzw(rng.normal(), rng.normal(), rng.normal(), rng.normal()) * 1.7;
        let ls = Vec2::new((base * rng.range(0.5, 1.5)).ln(), (base * rng.range(0.5, 1.5)).ln());
        s.push(p, q, ls, rng.normal() * 2.0, random_sh(&mut rng));
    }
    s
}

/// `n` surfels sized like a trained object: 60% on a sphere (radius 0.5 centred at z = 0.35),
/// 40% on the surface of a box below it ([-0.6, 0.6]^2 x [-0.9, -0.3]); normals follow the
/// surface (with a little noise), 3-sigma radii of ~1.5-3.6 times the mean spacing (about
/// 0.005-0.03 at 10k-300k), opacities mostly high.
pub fn object_scene(n: usize, seed: u64) -> Surfels {
    let mut rng = Rng::new(seed);
    let mut s = Surfels::with_capacity(n, 3);
    let sphere_area = 4.0 * std::f32::consts::PI * 0.25;
    let box_area = 2.0 * (1.2 * 1.2) + 4.0 * (1.2 * 0.6);
    let spacing = ((sphere_area + box_area) / n.max(1) as f32).sqrt();
    for i in 0..n {
        let (p, nrm) = if i % 5 < 3 {
            let d = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize_or(Vec3::Z);
            (Vec3::new(0.0, 0.0, 0.35) + 0.5 * d, d)
        } else {
            // Pick a face proportionally to area: top/bottom 1.44 each, sides 0.72 each.
            let f = rng.uniform() * box_area;
            let (a, b) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            if f < 1.44 {
                (Vec3::new(0.6 * a, 0.6 * b, -0.3), Vec3::Z)
            } else if f < 2.88 {
                (Vec3::new(0.6 * a, 0.6 * b, -0.9), -Vec3::Z)
            } else {
                let side = ((f - 2.88) / 0.72) as usize;
                let z = -0.6 + 0.3 * b;
                match side {
                    0 => (Vec3::new(0.6, 0.6 * a, z), Vec3::X),
                    1 => (Vec3::new(-0.6, 0.6 * a, z), -Vec3::X),
                    2 => (Vec3::new(0.6 * a, 0.6, z), Vec3::Y),
                    _ => (Vec3::new(0.6 * a, -0.6, z), -Vec3::Y),
                }
            }
        };
        let nrm = (nrm + 0.05 * Vec3::new(rng.normal(), rng.normal(), rng.normal())).normalize();
        let spin = Quat::from_rotation_z(rng.range(0.0, std::f32::consts::TAU));
        let q = Quat::from_rotation_arc(Vec3::Z, nrm) * spin;
        let ls = Vec2::new((spacing * rng.range(0.5, 1.2)).ln(), (spacing * rng.range(0.5, 1.2)).ln());
        let o = if rng.uniform() < 0.8 { logit(rng.range(0.85, 0.99)) } else { logit(rng.range(0.05, 0.85)) };
        s.push(p, q, ls, o, random_sh(&mut rng));
    }
    s
}

/// Rays per throughput measurement.
pub const RAYS: usize = 200_000;

/// The benchmark rays: `RAYS` micro-buffer rays from random Gaussians along random Fibonacci directions.
pub fn rays_for(s: &Surfels, p: &TraceParams, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    (0..RAYS)
        .map(|_| {
            let j = rng.below(s.len());
            let d = hemisphere_dir(s.normal(j), rng.below(64), 64, rng.range(0.0, std::f32::consts::TAU));
            Ray::from_gaussian(s, j, d, p)
        })
        .collect()
}
