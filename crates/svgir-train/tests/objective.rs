//! Finite-difference checks of stage 1's assembled per-pixel objective (SPEC 2),
//! `losses::objective::stage1_objective`, the function the trainer calls: every output gradient
//! it hands the rasteriser (colour, opacity, depth, normal, distortion) against the loss it
//! returns, with every term on (L1 + D-SSIM, mask, entropy, depth-normal mid-ramp, distortion).
//!
//! The production code is f32, so two checks complement each other:
//! - central differences of the production loss itself, per entry on a sample and along random
//!   directions (a sum over all entries, the most robust check), at tolerances set by f32
//!   rounding of the loss;
//! - central differences of an f64 mirror of the assembly, written here from SPEC 2's formulas
//!   with the f64 variants of the pieces (`svgir_metrics::ssim::<f64>`, `normal_from_depth`),
//!   at a tight tolerance; the mirror's value must equal the production loss.
//!
//! The opacity factor of the depth-normal loss is detached (SPEC 1: "alpha-masked, detached
//! alpha"), so its gradient is not part of `v_alpha`: the mirror takes that factor as a separate
//! input, and the production loss's difference quotient in opacity is compared with `v_alpha`
//! plus the detached part (the mirror's derivative in that separate input).

mod common;

use glam::{Mat4, Vec3};
use svgir_core::{Camera, Intrinsics, Rng};
use svgir_metrics::{Shape, SsimVariant};
use svgir_train::config::LossWeights;
use svgir_train::losses::depth_normal::normal_from_depth;
use svgir_train::losses::mask::dilated_mask;
use svgir_train::losses::objective::{stage1_objective, Objective, ObjectiveInput, ObjectiveTarget};

const W: usize = 12;
const H: usize = 10;
const NPIX: usize = W * H;
/// Entry ranges of the flat input vector, and the finite-difference step of each for the f32
/// production loss: L1's kink is >= 0.05 away from every colour; opacity and depth steps are
/// relative to the pixel's opacity (see `Scene::step`); the loss is linear in the normal and the
/// distortion, so large steps cost no truncation error there.
const BLOCKS: [(&str, usize, usize, f64); 5] = [
    ("color", 0, 3 * NPIX, 4e-3),
    ("alpha", 3 * NPIX, NPIX, 2e-3),
    ("depth", 4 * NPIX, NPIX, 2e-3),
    ("normal", 5 * NPIX, 3 * NPIX, 0.3),
    ("distortion", 8 * NPIX, NPIX, 0.1),
];
const N_IN: usize = 9 * NPIX;
const ALPHA: std::ops::Range<usize> = 3 * NPIX..4 * NPIX;

fn camera() -> Camera {
    let eye = Vec3::new(0.3, -2.5, 1.0);
    let back = eye.normalize();
    let right = Vec3::Z.cross(back).normalize();
    let up = back.cross(right);
    let c2w = Mat4::from_cols(right.extend(0.0), up.extend(0.0), back.extend(0.0), eye.extend(1.0));
    Camera::from_blender_c2w(c2w, Intrinsics::from_fov_x(0.8, W as u32, H as u32)).unwrap()
}

/// One view: the photo, the settings, and the render outputs flattened into `x` (see `BLOCKS`).
struct Scene {
    cam: Camera,
    w: LossWeights,
    t_frac: f32,
    use_mask: bool,
    rgb: Vec<f32>,
    gt_alpha: Vec<f32>,
    dilated: Vec<bool>,
    x: Vec<f32>,
}

/// Plausible render outputs: opacity in (0.05, 0.95), a slanted surface 2.3-2.6 away with a
/// little noise (`sum w z = O * z`), composited normals `O * n` near the view axis, small positive
/// distortion, and a photo whose colours differ from the render's by 0.05-0.3 either way.
fn scene(seed: u64, use_mask: bool) -> Scene {
    let cam = camera();
    let mut rng = Rng::new(seed);
    let mut u = |lo: f32, hi: f32| lo + (hi - lo) * rng.uniform();
    let alpha: Vec<f32> = (0..NPIX).map(|_| u(0.05, 0.95)).collect();
    let color: Vec<f32> = (0..3 * NPIX).map(|_| u(0.05, 0.95)).collect();
    let rgb: Vec<f32> = color.iter().map(|&c| if c > 0.5 { c - u(0.05, 0.3) } else { c + u(0.05, 0.3) }).collect();
    let depth: Vec<f32> = (0..NPIX)
        .map(|p| alpha[p] * (2.3 + 0.02 * (p % W) as f32 + 0.01 * (p / W) as f32 + u(-0.005, 0.005)))
        .collect();
    let view = -cam.forward();
    let normal: Vec<f32> = (0..NPIX)
        .flat_map(|p| {
            let n = (view + 0.3 * Vec3::new(u(-1.0, 1.0), u(-1.0, 1.0), u(-1.0, 1.0))).normalize() * alpha[p];
            n.to_array()
        })
        .collect();
    let distortion: Vec<f32> = (0..NPIX).map(|_| u(0.0, 0.02)).collect();
    // Photo alpha: an opaque block, a soft rim, and empty elsewhere; dilated by 2 so that some
    // pixels lie outside the dilated mask (the mask loss) and some inside.
    let gt_alpha: Vec<f32> = (0..NPIX)
        .map(|p| {
            let (x, y) = (p % W, p / W);
            if (4..8).contains(&x) && (3..7).contains(&y) {
                1.0
            } else if (3..9).contains(&x) && (2..8).contains(&y) {
                0.4
            } else {
                0.0
            }
        })
        .collect();
    let dilated = dilated_mask(&gt_alpha, W, H, 2);
    assert!(dilated.iter().any(|d| !d) && dilated.iter().any(|d| *d));
    // Every weight on and distinct (SPEC 2's, with SSIM 0.2, mask 0.03 and a distortion term).
    let mut w = LossWeights::default();
    (w.l1, w.ssim, w.mask, w.normal_start, w.normal_ramp, w.entropy, w.distortion) =
        (0.9, 0.2, 0.03, 0.01, 0.02, 0.1, 10.0);
    let x = [color, alpha, depth, normal, distortion].concat();
    assert_eq!(x.len(), N_IN);
    Scene { cam, w, t_frac: 0.4, use_mask, rgb, gt_alpha, dilated, x }
}

impl Scene {
    fn prod(&self, x: &[f32]) -> Objective {
        let b = |i: usize| &x[BLOCKS[i].1..BLOCKS[i].1 + BLOCKS[i].2];
        let input = ObjectiveInput { color: b(0), alpha: b(1), depth: b(2), normal: b(3), distortion: b(4) };
        let target = ObjectiveTarget { rgb: &self.rgb, alpha: &self.gt_alpha, dilated: &self.dilated };
        stage1_objective(&self.w, self.t_frac, self.use_mask, &input, &target, &self.cam)
    }

    /// The production gradients, flattened like `x`.
    fn prod_grad(&self) -> Vec<f64> {
        let o = self.prod(&self.x);
        let v_dist = o.v_distortion.expect("distortion weight > 0");
        [o.v_color, o.v_alpha, o.v_depth, o.v_normal, v_dist].concat().into_iter().map(f64::from).collect()
    }

    /// SPEC 2's loss in f64; `o_mask` is the detached opacity factor of the depth-normal loss.
    fn mirror(&self, x: &[f64], o_mask: &[f64]) -> f64 {
        let b = |i: usize| &x[BLOCKS[i].1..BLOCKS[i].1 + BLOCKS[i].2];
        let (color, alpha, depth, normal, dist) = (b(0), b(1), b(2), b(3), b(4));
        let w = &self.w;
        let wd = |v: f32| v as f64;
        let rgb: Vec<f64> = self.rgb.iter().map(|&v| v as f64).collect();
        let n = NPIX as f64;
        // 0.9 L1 + 0.1 (1 - SSIM), here with the test's weights.
        let l1 = color.iter().zip(&rgb).map(|(a, b)| (a - b).abs()).sum::<f64>() / (3 * NPIX) as f64;
        let ssim = svgir_metrics::ssim(color, &rgb, Shape::new(W, H, 3), SsimVariant::GaussianSplatting).unwrap();
        let mut loss = wd(w.l1) * l1 + wd(w.ssim) * (1.0 - ssim);
        if self.use_mask {
            // Mean opacity outside the dilated mask, and the binary entropy of opacity vs alpha.
            let mask = alpha.iter().zip(&self.dilated).filter(|(_, d)| !**d).map(|(o, _)| o).sum::<f64>() / n;
            let ent = alpha
                .iter()
                .zip(&self.gt_alpha)
                .map(|(&o, &m)| -(m as f64 * o.ln() + (1.0 - m as f64) * (1.0 - o).ln()))
                .sum::<f64>()
                / n;
            loss += wd(w.mask) * mask + wd(w.entropy) * ent;
        }
        // Depth-normal: mean(1 - N . N_D * O_detached), N_D from the expected depth S / O.
        let d: Vec<f64> = depth.iter().zip(alpha).map(|(s, o)| s / o.max(1e-4)).collect();
        let nd = normal_from_depth(&d, &self.cam);
        let dn = (0..NPIX)
            .map(|p| {
                1.0 - (normal[3 * p] * nd[p].x + normal[3 * p + 1] * nd[p].y + normal[3 * p + 2] * nd[p].z) * o_mask[p]
            })
            .sum::<f64>()
            / n;
        let w_dn = wd(w.normal_start) + wd(w.normal_ramp) * self.t_frac as f64;
        loss += w_dn * dn;
        // 2DGS distortion: lambda * mean over pixels.
        loss + wd(w.distortion) * dist.iter().sum::<f64>() / n
    }

    fn x64(&self) -> Vec<f64> {
        self.x.iter().map(|&v| v as f64).collect()
    }

    /// d mirror / d x_i for the live inputs (opacity factor held), central differences.
    fn mirror_fd(&self, i: usize) -> f64 {
        let (x, o) = (self.x64(), self.x64()[ALPHA].to_vec());
        let h = 1e-6;
        let (mut xp, mut xm) = (x.clone(), x);
        xp[i] += h;
        xm[i] -= h;
        (self.mirror(&xp, &o) - self.mirror(&xm, &o)) / (2.0 * h)
    }

    /// The detached part: d mirror / d (opacity factor of pixel p), per pixel.
    fn detached(&self) -> Vec<f64> {
        let (x, o) = (self.x64(), self.x64()[ALPHA].to_vec());
        let h = 1e-6;
        (0..NPIX)
            .map(|p| {
                let (mut op, mut om) = (o.clone(), o.clone());
                op[p] += h;
                om[p] -= h;
                (self.mirror(&x, &op) - self.mirror(&x, &om)) / (2.0 * h)
            })
            .collect()
    }

    /// Production gradient plus the detached part: what the production loss's slope should be.
    fn total_slope(&self) -> Vec<f64> {
        let mut g = self.prod_grad();
        for (p, c) in self.detached().into_iter().enumerate() {
            g[ALPHA.start + p] += c;
        }
        g
    }

    /// The finite-difference step of entry `i` of block `(start, h)`: opacity and depth (`O z`)
    /// steps scale with the pixel's opacity, where the expected depth `S / O` and the entropy
    /// curve most.
    fn step(&self, i: usize, start: usize, h: f64) -> f64 {
        match start {
            s if s == ALPHA.start => h * self.x[i] as f64,
            s if s == BLOCKS[2].1 => h * self.x[ALPHA.start + i - s] as f64,
            _ => h,
        }
    }

    /// Central difference of the f32 production loss along `dir` scaled by each block's step;
    /// returns (loss change, predicted change from `slope`, rounding bound of the change).
    fn prod_directional(&self, dir: &[f64], slope: &[f64]) -> (f64, f64, f64) {
        let (mut xp, mut xm) = (self.x.clone(), self.x.clone());
        for &(_, start, len, h) in &BLOCKS {
            for i in start..start + len {
                let h = self.step(i, start, h);
                xp[i] = (self.x[i] as f64 + h * dir[i]) as f32;
                xm[i] = (self.x[i] as f64 - h * dir[i]) as f32;
            }
        }
        let (lp, lm) = (self.prod(&xp).loss as f64, self.prod(&xm).loss as f64);
        // The steps actually taken, after rounding to f32.
        let want: f64 = (0..N_IN).map(|i| slope[i] * (xp[i] as f64 - xm[i] as f64)).sum();
        (lp - lm, want, 8.0 * f32::EPSILON as f64 * lp.abs().max(lm.abs()))
    }
}

/// The production loss equals the f64 mirror, and each production gradient matches the mirror's
/// central differences, every entry of every output.
#[test]
fn stage1_gradients_match_finite_differences_of_an_f64_mirror() {
    for use_mask in [true, false] {
        let s = scene(1, use_mask);
        let prod = s.prod(&s.x);
        let x = s.x64();
        let mirror = s.mirror(&x, &x[ALPHA]);
        assert!((prod.loss as f64 - mirror).abs() < 1e-6 * mirror.abs(), "loss {} vs mirror {mirror}", prod.loss);
        let g = s.prod_grad();
        for &(name, start, len, _) in &BLOCKS {
            let fd: Vec<f64> = (start..start + len).map(|i| s.mirror_fd(i)).collect();
            common::check_block_against_mirror(&format!("mask {use_mask} {name}"), &g[start..start + len], &fd);
        }
    }
}

/// Central differences of the f32 production loss itself: per entry on a sample of every output,
/// and along random directions through all of them and through each output alone.
#[test]
fn stage1_gradients_match_finite_differences_of_the_production_loss() {
    let mut s = scene(2, true);
    // A heavier depth-normal term than SPEC 2's 0.01-0.02, so that its slope in the depth stands
    // well above the f32 rounding of the loss.
    s.w.normal_start = 0.3;
    s.w.normal_ramp = 0.5;
    let slope = s.total_slope();
    let loss = s.prod(&s.x).loss as f64;
    let mut rng = Rng::new(7);
    for &(name, start, len, h) in &BLOCKS {
        // Each output's 6 steepest entries, which the f32 loss resolves best, and 6 at random.
        let at = |x: &[f32]| s.prod(x).loss as f64;
        common::check_sampled_entries(name, (start, len), &s.x, &slope, loss, &mut rng, |i| s.step(i, start, h), at);
    }
    for trial in 0..4 {
        let dir: Vec<f64> = (0..N_IN).map(|_| 2.0 * rng.uniform_f64() - 1.0).collect();
        let (got, want, noise) = s.prod_directional(&dir, &slope);
        assert!((got - want).abs() <= 1e-3 * want.abs() + noise, "all outputs, trial {trial}: {got:e} vs {want:e}");
        // Through each output alone, downhill in every entry (so that the change is resolved).
        for &(name, start, len, _) in &BLOCKS {
            let one: Vec<f64> = (0..N_IN)
                .map(|i| if (start..start + len).contains(&i) { dir[i].abs() * slope[i].signum() } else { 0.0 })
                .collect();
            let (got, want, noise) = s.prod_directional(&one, &slope);
            assert!(
                want.abs() > 10.0 * noise,
                "{name}: the check must resolve the slope ({want:e} vs noise {noise:e})"
            );
            assert!((got - want).abs() <= 3e-3 * want.abs() + noise, "{name}, trial {trial}: {got:e} vs {want:e}");
        }
    }
}

/// The distortion term is `lambda * mean over pixels` (2DGS): each pixel's gradient is
/// `lambda / npix`, not `lambda`, and it is absent when the weight is 0.
#[test]
fn stage1_distortion_gradient_is_the_weight_over_the_pixel_count() {
    let mut s = scene(3, true);
    let g = s.prod(&s.x).v_distortion.unwrap();
    let want = s.w.distortion / NPIX as f32;
    assert!(g.iter().all(|&v| (v - want).abs() <= 1e-6 * want), "{} vs {want}", g[0]);
    s.w.distortion = 0.0;
    assert!(s.prod(&s.x).v_distortion.is_none());
}
