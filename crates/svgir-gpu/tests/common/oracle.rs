//! The scenes, tolerances and cut-off maps the rasterizer tests share (raster.rs, features.rs):
//! each GPU value is checked against the scalar CPU kernels', with the CPU f32 value's own
//! distance from the f64 kernels as the conditioning allowance.

#![allow(dead_code)]

use glam::{Quat, Vec2, Vec3};
use svgir_core::{Camera, Rng, ShCoeffs, Surfels};
use svgir_raster::fixtures::{look_at_camera, random_scene};
use svgir_raster::{RasterConfig, Simd};

/// Random Gaussians on a unit sphere (svgir-raster's bench scene, larger splats) and a few
/// special ones: edge-on to the camera, behind the near plane, huge and faint.
pub fn scene(seed: u64, n: usize, cam: &Camera) -> Surfels {
    let mut s = random_scene(n, seed);
    let mut rng = Rng::new(seed ^ 99);
    for ls in s.log_scales.iter_mut() {
        *ls += Vec2::splat(2.0);
    }
    s.sh_degree = 3;
    // Edge-on: the normal perpendicular to the view ray through the centre.
    let p = Vec3::new(0.05, -0.1, 0.2);
    let view = (p - cam.center()).normalize();
    let side = view.cross(Vec3::Z).normalize();
    s.push(p, Quat::from_rotation_arc(Vec3::Z, side), Vec2::new(-2.0, -2.5), 1.5, ShCoeffs::from_rgb([0.9, 0.2, 0.1]));
    // Nearly edge-on.
    let nrm = (side + 0.05 * view).normalize();
    s.push(
        p * 0.5,
        Quat::from_rotation_arc(Vec3::Z, nrm),
        Vec2::new(-1.5, -2.0),
        2.0,
        ShCoeffs::from_rgb([0.1, 0.8, 0.3]),
    );
    // Behind the near plane.
    s.push(
        cam.center() + cam.forward() * 0.1,
        Quat::from_rotation_x(0.3),
        Vec2::new(-1.0, -1.0),
        1.0,
        ShCoeffs::from_rgb([0.5; 3]),
    );
    // Large and faint, in front.
    let q = Quat::from_rotation_arc(Vec3::Z, -cam.forward());
    s.push(cam.center() * 0.4, q, Vec2::new(-0.8, -1.3), -3.0, ShCoeffs::from_rgb([0.3, 0.3, rng.uniform()]));
    s
}

pub fn camera(w: u32, h: u32) -> Camera {
    look_at_camera(Vec3::new(2.2, -1.6, 1.1).normalize() * 3.0, 0.9, w, h)
}

pub fn cpu_cfg() -> RasterConfig {
    RasterConfig { simd: Simd::Scalar, tile: 16, ..RasterConfig::default() }
}

/// Checks the GPU's f32 values against the scalar CPU kernels' f32 ones, each within `tol`
/// (relative, absolute below 1) plus the CPU f32 value's own error against the f64 kernels: an
/// f32 kernel on any device rounds, and where a value is ill-conditioned (a splat near edge-on,
/// whose hit is a ratio of small cross products) the compilers' fused multiply-adds round it
/// differently. The CPU's distance from f64 measures that conditioning.
///
/// Pixels where some splat sits within a relative 1e-4 of a cut-off (`near_cut`) are left out:
/// there the exact tests are discontinuous, so which side an f32 kernel lands on is rounding.
pub fn close(what: &str, gpu: &[f32], cpu: &[f32], f64_ref: &[f64], near_cut: &[bool], tol: f32) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: lengths");
    let ch = gpu.len() / near_cut.len();
    let mut worst = (0.0f64, 0usize);
    for (i, ((g, c), r)) in gpu.iter().zip(cpu).zip(f64_ref).enumerate() {
        if near_cut[i / ch] {
            continue;
        }
        let own = (*c as f64 - r).abs();
        let err = ((*g - *c).abs() as f64 - own).max(0.0) / (c.abs().max(1.0) as f64);
        // A NaN error is the worst.
        if err > worst.0 || err.is_nan() {
            worst = (err, i);
        }
    }
    let i = worst.1;
    eprintln!(
        "{what}: worst error beyond the CPU's own {:.2e} at {i} (gpu {}, cpu {}, f64 {})",
        worst.0, gpu[i], cpu[i], f64_ref[i]
    );
    assert!(
        worst.0 <= tol as f64,
        "{what}: gpu {} vs cpu {} (f64 {}) at {i} (error {:.2e} > {tol:.0e})",
        gpu[i],
        cpu[i],
        f64_ref[i],
        worst.0
    );
}

/// Per pixel, whether some splat lies within a relative 1e-4 of a cut-off of the exact tests,
/// or its hit is ill-conditioned (see [`close`]).
pub fn near_cuts(s: &Surfels, cam: &Camera, cfg: &RasterConfig) -> Vec<bool> {
    use svgir_raster::preprocess::{project_one, Cam};
    let c64 = Cam::<f64>::new(cam);
    let mut splats: Vec<(f64, usize, svgir_raster::preprocess::Splat<f64>)> =
        (0..s.len()).filter_map(|i| project_one::<f64, Surfels>(s, &c64, cfg, i).map(|sp| (sp.depth, i, sp))).collect();
    splats.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let near = cfg.near as f64;
    let rel = |a: f64, b: f64| (a - b).abs() <= 1e-4 * b.abs().max(1e-30);
    let (w, h) = (cam.width(), cam.height());
    let mut out = vec![false; (w * h) as usize];
    for py in 0..h {
        for px in 0..w {
            let (x, y) = (px as f64 + 0.5, py as f64 + 0.5);
            let mut t = 1.0f64;
            let mut flag = false;
            for (_, _, sp) in &splats {
                let hh = &sp.h;
                let (tu, tv, tw) = ([hh[0], hh[1], hh[2]], [hh[3], hh[4], hh[5]], [hh[6], hh[7], hh[8]]);
                let k = [x * tw[0] - tu[0], x * tw[1] - tu[1], x * tw[2] - tu[2]];
                let l = [y * tw[0] - tv[0], y * tw[1] - tv[1], y * tw[2] - tv[2]];
                let p = [k[1] * l[2] - k[2] * l[1], k[2] * l[0] - k[0] * l[2], k[0] * l[1] - k[1] * l[0]];
                if p[2] == 0.0 {
                    continue;
                }
                let (u, v) = (p[0] / p[2], p[1] / p[2]);
                let (dx, dy) = (sp.center[0] - x, sp.center[1] - y);
                let rho = (u * u + v * v).min(2.0 * (dx * dx + dy * dy));
                let z = u * tw[0] + v * tw[1] + tw[2];
                let a = sp.opacity * (-0.5 * rho).exp();
                flag |= rel(rho, 9.0) || rel(a, 1.0 / 255.0) || rel(z, near) || rel(a, 0.99);
                if rho <= 9.0 && z >= near && a.min(0.99) >= 1.0 / 255.0 {
                    // An ill-conditioned hit: the f32 rounding of the cross product p = k x l
                    // (a few units in the last place of its terms) carried through u = p.x / p.z,
                    // v = p.y / p.z to z. Large for a splat seen nearly edge-on, whose p.z is a
                    // difference of much larger terms, and then beyond 1e-6 in any f32 kernel.
                    let eps = 4.0 * f32::EPSILON as f64;
                    let cz = eps * ((k[0] * l[1]).abs() + (k[1] * l[0]).abs()) / p[2].abs();
                    let eu = eps * ((k[1] * l[2]).abs() + (k[2] * l[1]).abs()) / p[2].abs() + u.abs() * cz;
                    let ev = eps * ((k[2] * l[0]).abs() + (k[0] * l[2]).abs()) / p[2].abs() + v.abs() * cz;
                    flag |= (tw[0] * eu).abs() + (tw[1] * ev).abs() > 1e-6 * z.abs().max(1.0);
                    // The same rounding through rho = u^2 + v^2 to alpha = o exp(-rho / 2).
                    let use3d = u * u + v * v <= 2.0 * (dx * dx + dy * dy);
                    flag |= use3d && a.min(0.99) * (u.abs() * eu + v.abs() * ev) > 1e-6;
                    let next = t * (1.0 - a.min(0.99));
                    flag |= rel(next, cfg.t_stop as f64) || rel(t, 0.5);
                    if next < cfg.t_stop as f64 {
                        break;
                    }
                    t = next;
                }
            }
            out[(py * w + px) as usize] = flag;
        }
    }
    out
}

/// Gradients of `sum weights * outputs` for random weights, per parameter group: each GPU value
/// within 1e-3 of the CPU's, relative to the larger of its own size and a tenth of the group's
/// largest. The floor is there because some gradients are differences of terms of the group's
/// size: a log-scale's, where the filter decides alpha, is zero in exact arithmetic (the ray-plane
/// hit does not move with the scale), and in f32 it is those terms' rounding, which the two
/// devices' different summation orders (per 16-px tile here, per 32-px tile entry there) round
/// differently.
///
/// Gaussians in `skip` are left out: those composited on one device only, at a few pixels
/// where they sit on a cut-off (`flipped`).
///
/// Beyond that, each may differ by its CPU f32 value's own distance from the f64 kernels': a
/// gradient that is a small difference of large per-pixel terms (a log-scale's, say) carries
/// rounding of the size of those terms in any f32 kernel.
pub fn check_grads(what: &str, gpu: &[f32], cpu: &[f32], exact: &[f64], skip: &[bool]) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: lengths");
    let per = gpu.len() / skip.len();
    let scale = cpu.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(scale > 0.0, "{what}: all CPU gradients are zero: nothing is tested");
    let mut worst = (0.0f32, 0usize);
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        if skip[i / per] {
            continue;
        }
        let own = (*c as f64 - exact[i]).abs() as f32;
        let err = ((g - c).abs() - own).max(0.0) / c.abs().max(0.1 * scale);
        if err > worst.0 || err.is_nan() {
            worst = (err, i);
        }
    }
    let i = worst.1;
    eprintln!("{what}: worst relative error {:.2e} at {i} (gpu {}, cpu {}, largest {scale})", worst.0, gpu[i], cpu[i]);
    assert!(worst.0 <= 1e-3, "{what}: gpu {} vs cpu {} at {i}: relative error {:.2e}", gpu[i], cpu[i], worst.0);
}
