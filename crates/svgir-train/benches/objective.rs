//! The per-pixel objectives at 256 x 256 (the synthetic scenes' training size): stage 2's
//! (Eqn 15: L1 + D-SSIM on the PBR and SH images, the material buffers' smoothness, Eqn 18) and
//! the two kernels stage 1 shares with it (D-SSIM with its gradient, Eqn 18), and the PBR image's
//! composite with its backward.
//! `cargo bench -p svgir-train --bench objective` (add `-- --threads 1` for one thread).

use glam::{Mat4, Vec3};
use svgir_core::{Camera, Intrinsics, Rng};
use svgir_train::losses::depth_normal::depth_normal_loss;
use svgir_train::stage2::objective::{stage2_objective, Stage2Outputs, Stage2Target, EXTRA_CHANNELS as EC};
use svgir_train::stage2::Stage2Weights;

fn main() {
    println!("cpu: {}, threads: {}", svgir_core::simd::cpu_features(), rayon::current_num_threads());
    divan::main();
}

const SIDE: usize = 256;

/// Render outputs of an object on a black background: a quarter of the columns empty, the rest
/// with opacity 0.2-1 and a slanted depth; a random photo and SH image.
struct Frame {
    cam: Camera,
    alpha: Vec<f32>,
    color: Vec<f32>,
    depth: Vec<f32>,
    extra: Vec<f32>,
    sh: Vec<f32>,
    rgb: Vec<f32>,
}

fn frame() -> Frame {
    let n = SIDE * SIDE;
    let eye = Vec3::new(0.3, -2.5, 1.0);
    let back = eye.normalize();
    let right = Vec3::Z.cross(back).normalize();
    let up = back.cross(right);
    let c2w = Mat4::from_cols(right.extend(0.0), up.extend(0.0), back.extend(0.0), eye.extend(1.0));
    let cam = Camera::from_blender_c2w(c2w, Intrinsics::from_fov_x(0.8, SIDE as u32, SIDE as u32)).unwrap();
    let mut r = Rng::new(1);
    let alpha: Vec<f32> = (0..n).map(|p| if p % SIDE < SIDE / 4 { 0.0 } else { 0.2 + 0.8 * r.uniform() }).collect();
    let color = (0..3 * n).map(|i| alpha[i / 3] * r.uniform()).collect();
    let depth = (0..n).map(|p| alpha[p] * (2.3 + 0.001 * (p % SIDE) as f32)).collect();
    let extra = (0..EC * n).map(|i| alpha[i / EC] * r.uniform()).collect();
    let sh = (0..3 * n).map(|_| r.uniform()).collect();
    let rgb = (0..3 * n).map(|_| r.uniform()).collect();
    Frame { cam, alpha, color, depth, extra, sh, rgb }
}

#[divan::bench(sample_count = 20)]
fn stage2(bencher: divan::Bencher) {
    let f = frame();
    let wts = Stage2Weights::default();
    let out = Stage2Outputs { color: &f.color, alpha: &f.alpha, depth: &f.depth, extra: &f.extra, sh_color: &f.sh };
    let target = Stage2Target { rgb: &f.rgb, cover: None, background: [0.0; 3], correction: None };
    bencher.bench(|| stage2_objective(&wts, &out, &target, &f.cam));
}

/// The PBR image's composite (SPEC 3) with its tone values kept, and its backward.
#[divan::bench(sample_count = 50)]
fn composite(bencher: divan::Bencher) {
    let f = frame();
    bencher.bench(|| {
        let (image, kept) = svgir_train::composite::pbr_composite_keep(&f.color, &f.alpha, None, [0.0; 3]);
        (kept.backward(&image), image)
    });
}

#[divan::bench(sample_count = 20)]
fn ssim_with_grad(bencher: divan::Bencher) {
    let f = frame();
    let shape = svgir_metrics::Shape::new(SIDE, SIDE, 3);
    bencher.bench(|| svgir_metrics::ssim_with_grad(&f.sh, &f.rgb, shape).unwrap());
}

#[divan::bench(sample_count = 20)]
fn depth_normal(bencher: divan::Bencher) {
    let f = frame();
    let normals: Vec<f32> = f.extra.chunks_exact(EC).flat_map(|e| [e[4], e[5], e[6]]).collect();
    bencher.bench(|| depth_normal_loss(&f.depth, &f.alpha, &normals, &f.cam));
}
