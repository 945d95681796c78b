//! Finite-difference checks of stage 2's assembled per-pixel objective (SPEC 6, Eqn 15),
//! `stage2::objective::stage2_objective`, the function `Stage2::step` calls: every output gradient
//! it hands the rasteriser (PBR colour and opacity through the division by opacity and the
//! composite over the background, depth, the extra channels albedo / roughness / shading normal,
//! the SH colour) against the loss it returns, with every per-pixel term on (L1 + D-SSIM on both
//! images, albedo / roughness / normal smoothness, Eqn 18), blended by the render's opacity
//! (SPEC 3) and by a photo's alpha. And the extra channels' normal flip: the loss as a function
//! of the vertices' materials through `extra_features`, a linear stand-in for the rasteriser's
//! splatting (which is linear in the features) and back through `extra_features_backward`.
//!
//! As in `tests/objective.rs`: central differences of the f32 production loss (sampled entries,
//! directional derivatives) and of an f64 mirror written here from SPEC 3 / 6's formulas, whose
//! value must equal the production loss. Detached by design (`stage2_objective`'s note): the
//! opacity dividing the material buffers and the shading normals, the depth guide of the normal
//! smoothness, and the opacity factor of Eqn 18. The mirror takes those as separate inputs
//! (`det`); the production loss's slope is the gradient plus the mirror's slope in them.

mod common;

use glam::{Mat3, Mat4, Vec3};
use svgir_core::color::linear_to_srgb;
use svgir_core::{Camera, Intrinsics, Rng};
use svgir_metrics::{Shape, SsimVariant};
use svgir_pbr::ActivatedMaterials;
use svgir_train::composite::pbr_composite;
use svgir_train::losses::depth_normal::normal_from_depth;
use svgir_train::losses::smoothness::{edge_aware_smoothness, BACKGROUND_GUIDE};
use svgir_train::stage2::objective::{
    extra_features, extra_features_backward, facing, stage2_objective, Stage2Objective, Stage2Outputs, Stage2Target,
    EXTRA_CHANNELS as EC, NORMAL_SMOOTHING_SHARPNESS,
};
use svgir_train::stage2::Stage2Weights;

const W: usize = 12;
const H: usize = 10;
const N: usize = W * H;
/// Entry ranges of the flat input vector and the f32 finite-difference step of each; `true`: the
/// step scales with the pixel's opacity (the division by opacity magnifies it by 1 / O).
const BLOCKS: [(&str, usize, usize, f64, bool); 5] = [
    ("color", 0, 3 * N, 4e-3, true),
    ("alpha", 3 * N, N, 2e-3, true),
    ("depth", 4 * N, N, 2e-3, true),
    ("extra", 5 * N, EC * N, 4e-3, true),
    ("sh", (5 + EC) * N, 3 * N, 4e-3, false),
];
const N_IN: usize = (8 + EC) * N;
const ALPHA: usize = 3 * N;
const DEPTH: usize = 4 * N;
const EXTRA: usize = 5 * N;

fn camera() -> Camera {
    let eye = Vec3::new(0.3, -2.5, 1.0);
    let back = eye.normalize();
    let right = Vec3::Z.cross(back).normalize();
    let up = back.cross(right);
    let c2w = Mat4::from_cols(right.extend(0.0), up.extend(0.0), back.extend(0.0), eye.extend(1.0));
    Camera::from_blender_c2w(c2w, Intrinsics::from_fov_x(0.8, W as u32, H as u32)).unwrap()
}

struct Scene {
    cam: Camera,
    w: Stage2Weights,
    rgb: Vec<f32>,
    cover: Option<Vec<f32>>,
    bg: [f32; 3],
    /// The photo's colour correction (stage 1's `exposure`), if any.
    correction: Option<[f32; 12]>,
    x: Vec<f32>,
}

fn u(rng: &mut Rng, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * rng.uniform()
}

/// A unit vector near the view axis, times `scale`.
fn near_view(rng: &mut Rng, cam: &Camera, scale: f32) -> [f32; 3] {
    let jitter = Vec3::new(u(rng, -1.0, 1.0), u(rng, -1.0, 1.0), u(rng, -1.0, 1.0));
    ((-cam.forward() + 0.3 * jitter).normalize() * scale).to_array()
}

/// Plausible render outputs: opacity in (0.05, 0.95) but >= 0.08 from the normal smoothness's
/// 0.5 threshold, straight linear colour 0.02-1.2 (above the sRGB knee), a slanted surface
/// 2.3-2.6 away, straight albedo / roughness in their activation ranges (SPEC 3), shading normals
/// near the view axis; photo 0.05-0.3 away from the PBR image, SH image 0.05-0.3 away from it.
fn scene(seed: u64, photo_cover: bool, corrected: bool) -> Scene {
    let cam = camera();
    let mut rng = Rng::new(seed);
    let r = &mut rng;
    let alpha: Vec<f32> = (0..N).map(|_| if r.uniform() < 0.5 { u(r, 0.05, 0.42) } else { u(r, 0.58, 0.95) }).collect();
    let color: Vec<f32> = (0..3 * N).map(|i| alpha[i / 3] * u(r, 0.02, 1.2)).collect();
    let depth: Vec<f32> = (0..N)
        .map(|p| alpha[p] * (2.3 + 0.02 * (p % W) as f32 + 0.01 * (p / W) as f32 + u(r, -0.002, 0.002)))
        .collect();
    let mut extra = Vec::with_capacity(EC * N);
    for &a in &alpha {
        extra.extend([u(r, 0.03, 0.8), u(r, 0.03, 0.8), u(r, 0.03, 0.8), u(r, 0.09, 0.99)].map(|v| a * v));
        extra.extend(near_view(r, &cam, a));
    }
    // Photo alpha: opaque, empty and soft pixels.
    let cover = photo_cover.then(|| (0..N).map(|p| [1.0, 0.0, 0.7, 1.0, 0.3][p % 5]).collect::<Vec<f32>>());
    let bg = [0.2, 0.5, 0.8];
    let image = pbr_composite(&color, &alpha, cover.as_deref(), bg);
    // A gain, a colour cast and an offset, as phone photos give (its own stream: the scenes
    // without one stay as they were).
    let correction = corrected.then(|| {
        let mut c = Rng::new(seed + 100);
        let mut p = [1.1, 0.08, -0.05, 0.03, 0.9, 0.06, -0.04, 0.1, 1.05, 0.02, -0.03, 0.05];
        p.iter_mut().for_each(|v| *v += u(&mut c, -0.02, 0.02));
        p
    });
    // The images the loss compares (corrected, with the PBR image's coverage and the SH image's
    // opacity) are 0.05-0.3 from the photo, away from L1's kink; the SH image is the one whose
    // corrected form lies there.
    let m = cover.clone().unwrap_or_else(|| alpha.clone());
    let away = |r: &mut Rng, v: f32| if v > 0.5 { v - u(r, 0.05, 0.3) } else { v + u(r, 0.05, 0.3) };
    let rgb: Vec<f32> = correct(correction, &image, &m, bg).iter().map(|&v| away(r, v)).collect();
    let sh_seen: Vec<f32> = rgb.iter().map(|&v| away(r, v)).collect();
    let sh = uncorrect(correction, &sh_seen, &alpha, bg);
    // SPEC 6's weights, made distinct from each other (a swapped weight shows), with the normal
    // smoothness (our addition) on.
    let w = Stage2Weights {
        ssim: 0.2,
        normal: 0.03,
        smooth_roughness: 0.07,
        smooth_normal: 0.13,
        ..Stage2Weights::default()
    };
    assert!([w.l1, w.ssim, w.normal, w.smooth_albedo, w.smooth_roughness, w.smooth_normal].iter().all(|v| *v > 0.0));
    let x = [color, alpha, depth, extra, sh].concat();
    assert_eq!(x.len(), N_IN);
    Scene { cam, w, rgb, cover, bg, correction, x }
}

/// `img` (coverage `m` over `bg`) through correction `p`, as `svgir_train::exposure::apply`.
fn correct(p: Option<[f32; 12]>, img: &[f32], m: &[f32], bg: [f32; 3]) -> Vec<f32> {
    match p {
        Some(p) => svgir_train::exposure::apply(&p, img, m, bg),
        None => img.to_vec(),
    }
}

/// The image whose corrected form is `seen`: `A^-1 (seen - b m - bg (1 - m)) + bg (1 - m)`.
fn uncorrect(p: Option<[f32; 12]>, seen: &[f32], m: &[f32], bg: [f32; 3]) -> Vec<f32> {
    let Some(p) = p else { return seen.to_vec() };
    let inv = Mat3::from_cols_array(&p[..9].try_into().unwrap()).transpose().inverse();
    let (b, bg) = (Vec3::new(p[9], p[10], p[11]), Vec3::from(bg));
    seen.chunks_exact(3)
        .zip(m)
        .flat_map(|(c, &m)| (inv * (Vec3::from_slice(c) - b * m - bg * (1.0 - m)) + bg * (1.0 - m)).to_array())
        .collect()
}

impl Scene {
    fn prod(&self, x: &[f32]) -> Stage2Objective {
        let b = |i: usize| &x[BLOCKS[i].1..BLOCKS[i].1 + BLOCKS[i].2];
        let out = Stage2Outputs { color: b(0), alpha: b(1), depth: b(2), extra: b(3), sh_color: b(4) };
        let target = Stage2Target {
            rgb: &self.rgb,
            cover: self.cover.as_deref(),
            background: self.bg,
            correction: self.correction.as_ref(),
        };
        stage2_objective(&self.w, &out, &target, &self.cam)
    }

    fn prod_grad(&self, x: &[f32]) -> Vec<f64> {
        let o = self.prod(x);
        [o.v_color, o.v_alpha, o.v_depth, o.v_extra, o.v_sh_color].concat().into_iter().map(f64::from).collect()
    }

    fn x64(&self) -> Vec<f64> {
        self.x.iter().map(|&v| v as f64).collect()
    }

    /// The detached inputs at `x`: opacity, then depth.
    fn det_of(x: &[f64]) -> Vec<f64> {
        x[ALPHA..DEPTH + N].to_vec()
    }

    /// The PBR image in f64 (SPEC 3): `srgb(C / max(O, 1e-5)) * m + bg * (1 - m)`.
    fn image(&self, color: &[f64], alpha: &[f64]) -> Vec<f64> {
        (0..3 * N)
            .map(|i| {
                let p = i / 3;
                let m = self.cover.as_ref().map_or(alpha[p], |c| c[p] as f64);
                linear_to_srgb(color[i] / alpha[p].max(1e-5)) * m + self.bg[i % 3] as f64 * (1.0 - m)
            })
            .collect()
    }

    /// `img`, composited with coverage `m` over the background, through the photo's correction:
    /// `A (img - bg (1 - m)) + b m + bg (1 - m)` per pixel.
    fn corrected(&self, img: &[f64], m: &[f64]) -> Vec<f64> {
        let Some(p) = self.correction else { return img.to_vec() };
        let p = p.map(f64::from);
        let bg = self.bg.map(f64::from);
        img.chunks_exact(3)
            .zip(m)
            .flat_map(|(c, &m)| {
                let f = [0, 1, 2].map(|k| c[k] - bg[k] * (1.0 - m));
                [0, 1, 2].map(|r| {
                    p[3 * r] * f[0] + p[3 * r + 1] * f[1] + p[3 * r + 2] * f[2] + p[9 + r] * m + bg[r] * (1.0 - m)
                })
            })
            .collect()
    }

    /// The PBR image's coverage: the photo's alpha, or the render's opacity `alpha`.
    fn coverage(&self, alpha: &[f64]) -> Vec<f64> {
        self.cover.as_ref().map_or(alpha.to_vec(), |c| c.iter().map(|&v| v as f64).collect())
    }

    /// Eqn 15's per-pixel terms in f64; `det`: the detached opacity and depth (see the note).
    fn mirror(&self, x: &[f64], det: &[f64]) -> f64 {
        let b = |i: usize| &x[BLOCKS[i].1..BLOCKS[i].1 + BLOCKS[i].2];
        let (color, alpha, depth, extra, sh) = (b(0), b(1), b(2), b(3), b(4));
        let (alpha_d, depth_d) = det.split_at(N);
        let wd = |v: f32| v as f64;
        let w = &self.w;
        let gt: Vec<f64> = self.rgb.iter().map(|&v| v as f64).collect();
        let photometric = |img: &[f64], m: &[f64]| {
            let img = &self.corrected(img, m)[..];
            let l1 = img.iter().zip(&gt).map(|(a, b)| (a - b).abs()).sum::<f64>() / (3 * N) as f64;
            let ssim = svgir_metrics::ssim(img, &gt, Shape::new(W, H, 3), SsimVariant::GaussianSplatting).unwrap();
            wd(w.l1) * l1 + wd(w.ssim) * (1.0 - ssim)
        };
        let mut loss = photometric(&self.image(color, alpha), &self.coverage(alpha)) + photometric(sh, alpha);
        // Eqn 17 on the straight albedo and roughness (opacity detached), guided by the photo.
        let straight =
            |c: usize, p: usize| if c < 4 { extra[EC * p + c] / alpha_d[p].max(1e-5) } else { extra[EC * p + c] };
        let alb: Vec<f64> = (0..3 * N).map(|i| straight(i % 3, i / 3)).collect();
        let rough: Vec<f64> = (0..N).map(|p| straight(3, p)).collect();
        let smooth = |a: &[f64], ca: usize, g: &[f64], cg: usize| {
            edge_aware_smoothness(a, ca, g, cg, W, H, 1.0, &mut vec![0.0; a.len()])
        };
        loss += wd(w.smooth_albedo) * smooth(&alb, 3, &gt, 3) + wd(w.smooth_roughness) * smooth(&rough, 1, &gt, 3);
        // Normal smoothness over the depth guide `k ln(S / O)` where O > 0.5 (all detached).
        let guide: Vec<f64> = (0..N)
            .map(|p| {
                let (s, o) = (depth_d[p], alpha_d[p]);
                if o > 0.5 {
                    NORMAL_SMOOTHING_SHARPNESS as f64 * (s / o).max(1e-6).ln()
                } else {
                    BACKGROUND_GUIDE as f64
                }
            })
            .collect();
        let nsum: Vec<f64> = (0..3 * N).map(|i| straight(4 + i % 3, i / 3)).collect();
        let nrm: Vec<f64> =
            (0..3 * N).map(|i| if alpha_d[i / 3] > 0.5 { nsum[i] / alpha_d[i / 3] } else { 0.0 }).collect();
        loss += wd(w.smooth_normal) * smooth(&nrm, 3, &guide, 1);
        // Eqn 18: mean(1 - N . N_D * O_detached), N_D from the expected depth S / O.
        let d: Vec<f64> = depth.iter().zip(alpha).map(|(s, o)| s / o.max(1e-4)).collect();
        let nd = normal_from_depth(&d, &self.cam);
        let dot = |p: usize| nsum[3 * p] * nd[p].x + nsum[3 * p + 1] * nd[p].y + nsum[3 * p + 2] * nd[p].z;
        loss + wd(w.normal) * (0..N).map(|p| 1.0 - dot(p) * alpha_d[p]).sum::<f64>() / N as f64
    }

    /// Central difference of the mirror in entry `i` of `x` (live) or of `det` (detached).
    fn mirror_fd(&self, i: usize, detached: bool) -> f64 {
        let x = self.x64();
        let det = Self::det_of(&x);
        let h = 1e-6;
        let shift = |v: &[f64], s: f64| {
            let mut v = v.to_vec();
            v[i] += s;
            v
        };
        if detached {
            (self.mirror(&x, &shift(&det, h)) - self.mirror(&x, &shift(&det, -h))) / (2.0 * h)
        } else {
            (self.mirror(&shift(&x, h), &det) - self.mirror(&shift(&x, -h), &det)) / (2.0 * h)
        }
    }

    /// Production gradient plus the detached parts: the production loss's slope.
    fn total_slope(&self) -> Vec<f64> {
        let mut g = self.prod_grad(&self.x);
        for i in 0..2 * N {
            g[ALPHA + i] += self.mirror_fd(i, true);
        }
        g
    }

    /// The f32 step of entry `i` in block `(start, h, scaled)`.
    fn step(&self, i: usize, start: usize, h: f64, scaled: bool) -> f64 {
        let pixel = match start {
            0 => (i - start) / 3,
            EXTRA => (i - start) / EC,
            _ if start < EXTRA => i - start,
            _ => 0,
        };
        if scaled {
            h * self.x[ALPHA + pixel] as f64
        } else {
            h
        }
    }

    /// Central difference of the f32 production loss along `dir` (scaled by half the steps: the
    /// third-order terms add up over all entries): (loss change, change predicted by `slope`
    /// over the steps actually taken, rounding bound).
    fn prod_directional(&self, dir: &[f64], slope: &[f64]) -> (f64, f64, f64) {
        let (mut xp, mut xm) = (self.x.clone(), self.x.clone());
        for &(_, start, len, h, scaled) in &BLOCKS {
            for i in start..start + len {
                let h = 0.5 * self.step(i, start, h, scaled) * dir[i];
                xp[i] = (self.x[i] as f64 + h) as f32;
                xm[i] = (self.x[i] as f64 - h) as f32;
            }
        }
        let (lp, lm) = (self.prod(&xp).loss as f64, self.prod(&xm).loss as f64);
        let want: f64 = (0..N_IN).map(|i| slope[i] * (xp[i] as f64 - xm[i] as f64)).sum();
        (lp - lm, want, 8.0 * f32::EPSILON as f64 * lp.abs().max(lm.abs()))
    }
}

/// The production loss and image equal the f64 mirror's, and every production gradient matches
/// the mirror's central differences, under both coverages.
#[test]
fn stage2_gradients_match_finite_differences_of_an_f64_mirror() {
    for (photo_cover, corrected) in [(false, false), (true, false), (false, true), (true, true)] {
        let s = scene(1, photo_cover, corrected);
        let prod = s.prod(&s.x);
        let x = s.x64();
        let mirror = s.mirror(&x, &Scene::det_of(&x));
        assert!((prod.loss as f64 - mirror).abs() < 1e-6 * mirror, "loss {} vs mirror {mirror}", prod.loss);
        let alpha = &x[ALPHA..DEPTH];
        let image = s.corrected(&s.image(&x[..3 * N], alpha), &s.coverage(alpha));
        assert!(prod.image.iter().zip(&image).all(|(a, b)| (*a as f64 - b).abs() < 1e-6));
        let g = s.prod_grad(&s.x);
        for &(name, start, len, _, _) in &BLOCKS {
            let fd: Vec<f64> = (start..start + len).map(|i| s.mirror_fd(i, false)).collect();
            let what = format!("photo cover {photo_cover} corrected {corrected} {name}");
            common::check_block_against_mirror(&what, &g[start..start + len], &fd);
        }
    }
}

/// Central differences of the f32 production loss: per entry (each output's steepest entries
/// and a random sample) and along random directions through all outputs and each alone.
#[test]
fn stage2_gradients_match_finite_differences_of_the_production_loss() {
    for (photo_cover, corrected) in [(false, false), (true, false), (false, true), (true, true)] {
        let mut s = scene(2, photo_cover, corrected);
        // A heavier Eqn 18 than SPEC 6's 0.02, so that the depth's slope stands above f32 rounding.
        s.w.normal = 0.5;
        let slope = s.total_slope();
        let loss = s.prod(&s.x).loss as f64;
        let mut rng = Rng::new(7);
        for &(name, start, len, h, scaled) in &BLOCKS {
            let what = format!("photo cover {photo_cover} corrected {corrected} {name}");
            let at = |x: &[f32]| s.prod(x).loss as f64;
            let step = |i| s.step(i, start, h, scaled);
            common::check_sampled_entries(&what, (start, len), &s.x, &slope, loss, &mut rng, step, at);
        }
        for trial in 0..3 {
            let dir: Vec<f64> = (0..N_IN).map(|_| 2.0 * rng.uniform_f64() - 1.0).collect();
            let (got, want, noise) = s.prod_directional(&dir, &slope);
            assert!((got - want).abs() <= 1e-3 * want.abs() + noise, "all, trial {trial}: {got:e} vs {want:e}");
            for &(name, start, len, _, _) in &BLOCKS {
                let one: Vec<f64> = (0..N_IN)
                    .map(|i| if (start..start + len).contains(&i) { dir[i].abs() * slope[i].signum() } else { 0.0 })
                    .collect();
                let (got, want, noise) = s.prod_directional(&one, &slope);
                assert!(want.abs() > 10.0 * noise, "{name}: the check must resolve the slope ({want:e}, {noise:e})");
                assert!((got - want).abs() <= 3e-3 * want.abs() + noise, "{name}, trial {trial}: {got:e} vs {want:e}");
            }
        }
    }
}

/// Gaussians with `M` vertices each, their vertex materials, and a linear stand-in for the
/// rasteriser's splatting of vertex features (`sum_v w_pv f_v`, linear in the features as the
/// rasteriser is): each pixel covers 3 vertices with weights summing to its opacity.
struct Splat {
    fac: Vec<f32>,
    /// Per vertex: albedo (3), roughness, shading normal (3), as `ActivatedMaterials` lays out.
    albedo: Vec<f32>,
    roughness: Vec<f32>,
    normals: Vec<f32>,
    cover: Vec<Vec<(usize, f64)>>,
}

const M: usize = 2;
const GAUSSIANS: usize = 8;
const NV: usize = M * GAUSSIANS;

fn splat_scene(s: &Scene, seed: u64) -> Splat {
    let mut rng = Rng::new(seed);
    let r = &mut rng;
    let positions: Vec<Vec3> =
        (0..GAUSSIANS).map(|_| Vec3::new(u(r, -0.5, 0.5), u(r, -0.5, 0.5), u(r, -0.5, 0.5))).collect();
    let normals: Vec<Vec3> =
        (0..GAUSSIANS).map(|_| Vec3::new(r.normal(), r.normal(), r.normal()).normalize()).collect();
    let fac = facing(&normals, &positions, s.cam.center());
    assert!(fac.contains(&1.0) && fac.contains(&-1.0), "both sides: {fac:?}");
    // The flipped normal faces the camera (SPEC 1's double-sided normals).
    for ((n, p), f) in normals.iter().zip(&positions).zip(&fac) {
        assert!((*n * *f).dot(s.cam.center() - *p) >= 0.0);
    }
    let jitter = |r: &mut Rng| Vec3::new(u(r, -0.2, 0.2), u(r, -0.2, 0.2), u(r, -0.2, 0.2));
    let vertex_normals: Vec<f32> = (0..NV).flat_map(|v| (normals[v / M] + jitter(r)).normalize().to_array()).collect();
    let cover = (0..N)
        .map(|p| {
            let raw: Vec<(usize, f64)> = (0..3).map(|_| (r.below(NV), u(r, 0.2, 1.0) as f64)).collect();
            let sum: f64 = raw.iter().map(|(_, w)| w).sum();
            raw.into_iter().map(|(v, w)| (v, w / sum * s.x[ALPHA + p] as f64)).collect()
        })
        .collect();
    Splat {
        fac,
        albedo: (0..3 * NV).map(|_| u(r, 0.03, 0.8)).collect(),
        roughness: (0..NV).map(|_| u(r, 0.09, 0.99)).collect(),
        normals: vertex_normals,
        cover,
    }
}

impl Splat {
    /// The vertex materials as one vector: albedo, roughness, normals.
    fn materials(&self) -> Vec<f64> {
        self.albedo.iter().chain(&self.roughness).chain(&self.normals).map(|&v| v as f64).collect()
    }

    /// The extra channels of every vertex in f64: the shading normal flipped to face the camera.
    fn features(&self, mat: &[f64]) -> Vec<f64> {
        let (albedo, rest) = mat.split_at(3 * NV);
        let (roughness, normals) = rest.split_at(NV);
        (0..NV)
            .flat_map(|v| {
                let f = self.fac[v / M] as f64;
                let n = [0, 1, 2].map(|c| f * normals[3 * v + c]);
                [albedo[3 * v], albedo[3 * v + 1], albedo[3 * v + 2], roughness[v], n[0], n[1], n[2]]
            })
            .collect()
    }

    fn splat(&self, feat: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; N * EC];
        for (p, cov) in self.cover.iter().enumerate() {
            for &(v, w) in cov {
                (0..EC).for_each(|c| out[EC * p + c] += w * feat[EC * v + c]);
            }
        }
        out
    }

    fn splat_adjoint(&self, v_pix: &[f32]) -> Vec<f32> {
        let mut out = vec![0.0f64; NV * EC];
        for (p, cov) in self.cover.iter().enumerate() {
            for &(v, w) in cov {
                (0..EC).for_each(|c| out[EC * v + c] += w * v_pix[EC * p + c] as f64);
            }
        }
        out.into_iter().map(|v| v as f32).collect()
    }

    /// `x` with its extra channels splatted from `mat`.
    fn with_extra(&self, x: &[f64], mat: &[f64]) -> Vec<f64> {
        let mut x = x.to_vec();
        x[EXTRA..EXTRA + EC * N].copy_from_slice(&self.splat(&self.features(mat)));
        x
    }
}

/// The normal flip: the loss as a function of the vertices' albedo, roughness and (unflipped)
/// shading normals, through `extra_features`, the splatting and `stage2_objective`, back through
/// the splatting's adjoint and `extra_features_backward`, against central differences of the f64
/// mirror; on Gaussians seen from both sides.
#[test]
fn stage2_vertex_material_gradients_through_the_normal_flip_match_finite_differences() {
    let mut s = scene(3, false, false);
    let sp = splat_scene(&s, 5);
    let mat = sp.materials();
    let act = ActivatedMaterials {
        m: M,
        albedo: sp.albedo.clone(),
        roughness: sp.roughness.clone(),
        normals: sp.normals.clone(),
    };
    let feat = extra_features(&act, &sp.fac);
    assert_eq!(feat, sp.features(&mat).into_iter().map(|v| v as f32).collect::<Vec<_>>());
    s.x = sp.with_extra(&s.x64(), &mat).into_iter().map(|v| v as f32).collect();
    let obj = s.prod(&s.x);
    let v_vertex = sp.splat_adjoint(&obj.v_extra);
    let (mut v_alb, mut v_rough, mut v_nrm) = (vec![0.0; 3 * NV], vec![0.0; NV], vec![0.0; 3 * NV]);
    extra_features_backward(&v_vertex, EC, M, &sp.fac, &mut v_alb, &mut v_rough, &mut v_nrm);
    let g: Vec<f64> = v_alb.iter().chain(&v_rough).chain(&v_nrm).map(|&v| v as f64).collect();

    let x = s.x64();
    let det = Scene::det_of(&x);
    let h = 1e-6;
    for (name, start, len) in [("albedo", 0, 3 * NV), ("roughness", 3 * NV, NV), ("normal", 4 * NV, 3 * NV)] {
        let fd: Vec<f64> = (start..start + len)
            .map(|i| {
                let (mut mp, mut mm) = (mat.clone(), mat.clone());
                mp[i] += h;
                mm[i] -= h;
                (s.mirror(&sp.with_extra(&x, &mp), &det) - s.mirror(&sp.with_extra(&x, &mm), &det)) / (2.0 * h)
            })
            .collect();
        let scale = fd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 0.0, "{name}: the loss must depend on it");
        for (k, f) in fd.iter().enumerate() {
            let a = g[start + k];
            assert!(
                (a - f).abs() <= 2e-5 * f.abs() + 2e-6 * scale,
                "{name}[{k}] (facing {}): production {a:e} vs f64 difference {f:e} (max {scale:e})",
                sp.fac[k / (len / NV) / M]
            );
        }
        if name == "normal" {
            // Gaussians seen from behind carry real weight in the check.
            let back = (0..len).filter(|k| sp.fac[k / 3 / M] < 0.0).map(|k| fd[k].abs()).fold(0.0, f64::max);
            assert!(back > 0.1 * scale, "back-facing normals' slope {back:e} vs {scale:e}");
        }
    }

    // The f32 production path itself, downhill along the gradient in all vertex materials.
    let prod_loss = |mat: &[f32]| {
        let (albedo, rest) = mat.split_at(3 * NV);
        let (roughness, normals) = rest.split_at(NV);
        let act = ActivatedMaterials {
            m: M,
            albedo: albedo.to_vec(),
            roughness: roughness.to_vec(),
            normals: normals.to_vec(),
        };
        let pix = sp.splat(&extra_features(&act, &sp.fac).into_iter().map(f64::from).collect::<Vec<_>>());
        let mut x = s.x.clone();
        x[EXTRA..EXTRA + EC * N].iter_mut().zip(&pix).for_each(|(d, v)| *d = *v as f32);
        s.prod(&x).loss as f64
    };
    let mut rng = Rng::new(9);
    let (mut mp, mut mm): (Vec<f32>, Vec<f32>) = (vec![], vec![]);
    for (i, m) in mat.iter().enumerate() {
        let d = 2e-3 * (0.5 + 0.5 * rng.uniform_f64()) * g[i].signum();
        mp.push((m + d) as f32);
        mm.push((m - d) as f32);
    }
    let (lp, lm) = (prod_loss(&mp), prod_loss(&mm));
    let want: f64 = (0..mat.len()).map(|i| g[i] * (mp[i] as f64 - mm[i] as f64)).sum();
    let noise = 8.0 * f32::EPSILON as f64 * lp.abs().max(lm.abs());
    assert!(want > 10.0 * noise, "the check must resolve the slope ({want:e}, {noise:e})");
    assert!((lp - lm - want).abs() <= 3e-3 * want + noise, "f32 production: {:e} vs {want:e}", lp - lm);
}

/// `extra_features_backward` is the adjoint of `extra_features` (which is linear in the
/// materials): `<F(a), u> = <a, F^T(u)>` for random materials and output gradients.
#[test]
fn extra_features_backward_is_the_adjoint_of_extra_features() {
    let s = scene(4, false, false);
    let sp = splat_scene(&s, 6);
    let mut rng = Rng::new(8);
    let act = ActivatedMaterials {
        m: M,
        albedo: sp.albedo.clone(),
        roughness: sp.roughness.clone(),
        normals: sp.normals.clone(),
    };
    let out = extra_features(&act, &sp.fac);
    let v: Vec<f32> = (0..NV * EC).map(|_| rng.normal()).collect();
    let (mut va, mut vr, mut vn) = (vec![0.0; 3 * NV], vec![0.0; NV], vec![0.0; 3 * NV]);
    extra_features_backward(&v, EC, M, &sp.fac, &mut va, &mut vr, &mut vn);
    let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum::<f64>();
    let lhs = dot(&out, &v);
    let rhs = dot(&act.albedo, &va) + dot(&act.roughness, &vr) + dot(&act.normals, &vn);
    assert!((lhs - rhs).abs() < 1e-9 * lhs.abs().max(1.0), "{lhs} vs {rhs}");
    // Accumulates: a second call doubles the gradients.
    let once = vn.clone();
    extra_features_backward(&v, EC, M, &sp.fac, &mut va, &mut vr, &mut vn);
    assert!(vn.iter().zip(&once).all(|(b, a)| *b == 2.0 * a));
}
