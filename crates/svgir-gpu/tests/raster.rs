//! The GPU kernels against svgir-raster's scalar kernels (the oracle): scan and sort exactly,
//! tile lists exactly, forward outputs within 1e-5, gradients within 1e-3 relative. Run on
//! whatever adapter `SVGIR_GPU_ADAPTER` names, else Mesa's lavapipe; without one they print
//! SKIPPED, and fail under `SVGIR_REQUIRE_GPU=1` (as `.ci/run` sets).

use glam::{Quat, Vec2, Vec3};
use svgir_core::{Camera, Rng, ShCoeffs, Surfels};
use svgir_gpu::{Gpu, GpuRaster};

mod common;
use common::gpu;
use common::oracle::{camera, check_grads, close, cpu_cfg, near_cuts, scene};
use svgir_raster::{Background, ColorSource, OutputGrads, RasterConfig, RenderInput};

#[test]
fn scan_matches_a_sequential_prefix_sum() {
    let Some(g) = gpu() else { return };
    let mut rng = Rng::new(3);
    for n in [1usize, 255, 1024, 1025, 5000, 1 << 20 | 77] {
        let data: Vec<u32> = (0..n).map(|_| rng.below(9) as u32).collect();
        let mut want = Vec::with_capacity(n);
        let mut run = 0u32;
        for &v in &data {
            want.push(run);
            run += v;
        }
        assert_eq!(svgir_gpu::testing::exclusive_scan(&g, &data).unwrap(), want, "n = {n}");
    }
}

#[test]
fn radix_sort_is_stable_and_matches_the_standard_sort() {
    let Some(g) = gpu() else { return };
    let mut rng = Rng::new(5);
    for (n, bits, range) in
        [(2usize, 32u32, 3u32), (1000, 32, 40), (4097, 32, u32::MAX), (70_000, 12, 4000), (3000, 8, 256)]
    {
        let keys: Vec<u32> =
            (0..n).map(|_| (rng.uniform_f64() * range as f64) as u32 & ((1u64 << bits) - 1) as u32).collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let mut want: Vec<(u32, u32)> = keys.iter().copied().zip(vals.iter().copied()).collect();
        want.sort_by_key(|p| p.0);
        let (k, v) = svgir_gpu::testing::sort_pairs(&g, &keys, &vals, bits).unwrap();
        let got: Vec<(u32, u32)> = k.into_iter().zip(v).collect();
        assert_eq!(got, want, "n = {n}, bits = {bits}");
    }
}

/// Per pixel, whether a splat is within a relative 1e-4 of one of the per-pixel cut-offs in f64
/// (svgir_raster::splat: rho <= 9, alpha >= 1/255, z >= near) or, compositing in (depth, id)
/// order, of the transmittance floor t_stop or of the median depth's T = 0.5, or composites a
/// hit whose depth is ill-conditioned (below).
/// The forward outputs of one scene on both devices.
fn check_forward(g: &Gpu, r: &GpuRaster, s: &Surfels, cam: &Camera, bg: [f32; 3], cfg: &RasterConfig) {
    let input = RenderInput {
        surfels: s,
        camera: cam,
        colors: ColorSource::Sh,
        extra: None,
        background: Background::Color(bg),
    };
    let (cpu, _) = svgir_raster::render(&input, cfg);
    let input64 = svgir_raster::RenderInputOf::<f64, Surfels> {
        surfels: s,
        camera: cam,
        colors: svgir_raster::ColorSourceOf::Sh,
        extra: None,
        background: svgir_raster::BackgroundOf::Color(bg.map(f64::from)),
    };
    let (exact, _) = svgir_raster::render_generic::<f64, Surfels>(&input64, cfg);
    let (out, fwd) = r.render(g, s, cam, bg, cfg).unwrap();
    eprintln!("{} Gaussians, {}x{} px, {} entries", s.len(), cam.width(), cam.height(), fwd.entries);
    assert!(cpu.alpha.iter().filter(|&&a| a > 0.5).count() > 10, "the scene covers too few pixels to test");
    let cut = near_cuts(s, cam, cfg);
    let left_out = cut.iter().filter(|&&c| c).count();
    eprintln!("{left_out} of {} pixels have a splat at a cut-off", cut.len());
    // Random splats on a sphere: those on its silhouette are seen edge-on, ill-conditioned.
    assert!(left_out * 7 < cut.len(), "more than 15% of the pixels are left out");
    close("colour", &out.color, &cpu.color, &exact.color, &cut, 1e-5);
    close("alpha", &out.alpha, &cpu.alpha, &exact.alpha, &cut, 1e-5);
    close("depth", &out.depth, &cpu.depth, &exact.depth, &cut, 1e-5);
    close("median depth", &out.median_depth, &cpu.median_depth, &exact.median_depth, &cut, 1e-5);
    close("normal", &out.normal, &cpu.normal, &exact.normal, &cut, 1e-5);
    close("distortion", &out.distortion, &cpu.distortion, &exact.distortion, &cut, 1e-5);
    let vis_cpu: Vec<f32> = cpu.max_radius.iter().map(|&r| f32::from(r > 0.0)).collect();
    let vis_gpu: Vec<f32> = out.max_radius.iter().map(|&r| f32::from(r > 0.0)).collect();
    assert_eq!(vis_gpu, vis_cpu, "culling differs");
}

#[test]
fn forward_matches_the_scalar_kernels() {
    let Some(g) = gpu() else { return };
    let r = GpuRaster::new(&g);
    // Image sizes that cut tiles at both edges.
    for (seed, n, w, h) in [(1u64, 60usize, 37u32, 29u32), (2, 400, 64, 48), (3, 1000, 83, 71)] {
        let cam = camera(w, h);
        let s = scene(seed, n, &cam);
        check_forward(&g, &r, &s, &cam, [0.2, 0.5, 0.9], &cpu_cfg());
    }
    // Without the optional outputs.
    let cam = camera(40, 33);
    let s = scene(4, 300, &cam);
    let cfg = RasterConfig { distortion: false, geometry: false, ..cpu_cfg() };
    check_forward(&g, &r, &s, &cam, [1.0, 1.0, 1.0], &cfg);
}

#[test]
fn backward_matches_the_scalar_kernels() {
    let Some(g) = gpu() else { return };
    let r = GpuRaster::new(&g);
    for (seed, n, w, h) in [(11u64, 40usize, 37u32, 29u32), (12, 300, 64, 48)] {
        let cam = camera(w, h);
        let s = scene(seed, n, &cam);
        let cfg = cpu_cfg();
        let bg = [0.3, 0.6, 0.1];
        let npx = (w * h) as usize;
        let mut rng = Rng::new(seed);
        let mut v = |k: usize, amp: f32| (0..k).map(|_| amp * (2.0 * rng.uniform() - 1.0)).collect::<Vec<f32>>();
        let (gc, ga, gd, gn, gdist) = (v(npx * 3, 1.0), v(npx, 1.0), v(npx, 0.3), v(npx * 3, 1.0), v(npx, 30.0));
        let og = OutputGrads {
            color: Some(&gc),
            alpha: Some(&ga),
            depth: Some(&gd),
            normal: Some(&gn),
            distortion: Some(&gdist),
            extra: None,
        };
        let input = RenderInput {
            surfels: &s,
            camera: &cam,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color(bg),
        };
        let (cpu_out, state) = svgir_raster::render(&input, &cfg);
        let cpu = svgir_raster::backward(&input, &cfg, &state, &cpu_out, &og);
        let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
        let (gc64, ga64, gd64, gn64, gdist64) = (f(&gc), f(&ga), f(&gd), f(&gn), f(&gdist));
        let og64 = svgir_raster::OutputGradsOf::<f64> {
            color: Some(&gc64),
            alpha: Some(&ga64),
            depth: Some(&gd64),
            normal: Some(&gn64),
            distortion: Some(&gdist64),
            extra: None,
        };
        let input64 = svgir_raster::RenderInputOf::<f64, Surfels> {
            surfels: &s,
            camera: &cam,
            colors: svgir_raster::ColorSourceOf::Sh,
            extra: None,
            background: svgir_raster::BackgroundOf::Color(bg.map(f64::from)),
        };
        let (out64, state64) = svgir_raster::render_generic::<f64, Surfels>(&input64, &cfg);
        let exact = svgir_raster::backward_generic::<f64, Surfels>(&input64, &cfg, &state64, &out64, &og64);
        let flat = |v: &[f64]| v.to_vec();
        let (_, fwd) = r.render(&g, &s, &cam, bg, &cfg).unwrap();
        let got = r.backward(&g, &fwd, &og).unwrap();
        let gg = &got.grads;
        // Composited on one device only, and then faintly: a splat on a cut-off at some pixel.
        let (wg, wc) = (&got.accum_weight, &cpu_out.accum_weight);
        let flipped: Vec<bool> =
            wg.iter().zip(wc).map(|(a, b)| (*a == 0.0) != (*b == 0.0) && a.max(*b) < 1e-2).collect();
        let nf = flipped.iter().filter(|&&f| f).count();
        eprintln!("{nf} of {} Gaussians composited on one device only", s.len());
        assert!(nf * 50 <= s.len(), "more than 2% of the Gaussians composited on one device only");
        check_grads(
            "positions",
            bytemuck::cast_slice(&gg.v_positions),
            bytemuck::cast_slice(&cpu.v_positions),
            &flat(bytemuck::cast_slice(&exact.v_positions)),
            &flipped,
        );
        check_grads(
            "rotations",
            bytemuck::cast_slice(&gg.v_rotations),
            bytemuck::cast_slice(&cpu.v_rotations),
            &flat(bytemuck::cast_slice(&exact.v_rotations)),
            &flipped,
        );
        check_grads(
            "log-scales",
            bytemuck::cast_slice(&gg.v_log_scales),
            bytemuck::cast_slice(&cpu.v_log_scales),
            &flat(bytemuck::cast_slice(&exact.v_log_scales)),
            &flipped,
        );
        check_grads("opacity logits", &gg.v_opacity_logits, &cpu.v_opacity_logits, &exact.v_opacity_logits, &flipped);
        check_grads(
            "SH",
            bytemuck::cast_slice(&gg.v_sh),
            bytemuck::cast_slice(&cpu.v_sh),
            &flat(bytemuck::cast_slice(&exact.v_sh)),
            &flipped,
        );
        check_grads("mean2d norm", &gg.v_mean2d_norm, &cpu.v_mean2d_norm, &exact.v_mean2d_norm, &flipped);
        check_grads("background", &gg.v_background, &cpu.v_background, &exact.v_background, &[false]);
        check_grads("accumulated weight", &got.accum_weight, &cpu_out.accum_weight, &out64.accum_weight, &flipped);
    }
}

#[test]
fn a_driver_error_is_an_error_not_a_panic() {
    let Some(g) = gpu() else { return };
    g.check().expect("a fresh device has no error");
    // A buffer mapped at creation must have a size that is a multiple of 4: wgpu reports it
    // through the device's error handler, which keeps it for `check`.
    let _ = g.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("odd"),
        size: 3,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: true,
    });
    let e = g.check().expect_err("the validation error is kept");
    assert!(e.to_string().contains("llvmpipe") || e.to_string().contains(&g.report.name), "{e}");
}

/// A change of one parameter by a step.
type Perturb = Box<dyn Fn(&mut Surfels, f32)>;

/// A linear functional of every output, `sum w . out`, in f64 from the f32 images.
fn functional(out: &svgir_raster::RenderOutput, w: &[Vec<f32>; 5]) -> f64 {
    let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum::<f64>();
    dot(&out.color, &w[0])
        + dot(&out.alpha, &w[1])
        + dot(&out.depth, &w[2])
        + dot(&out.normal, &w[3])
        + dot(&out.distortion, &w[4])
}

#[test]
fn gradients_match_finite_differences_of_the_gpu_render() {
    let Some(g) = gpu() else { return };
    let r = GpuRaster::new(&g);
    let (w, h) = (32u32, 24u32);
    let cam = camera(w, h);
    let toward = -cam.forward();
    let mut rng = Rng::new(5);
    // Six surfels large enough that their cut-off ellipses and boxes lie outside the image, so
    // the render is smooth in every parameter (no pixel enters or leaves a splat).
    let mut s = Surfels::with_capacity(6, 1);
    for _ in 0..6 {
        let p = Vec3::new(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5) * 0.6;
        let n = (toward + Vec3::new(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5) * 0.6).normalize();
        let q = Quat::from_rotation_arc(Vec3::Z, n) * Quat::from_rotation_z(rng.uniform() * 3.0);
        let ls = Vec2::new(0.9 + 0.3 * rng.uniform(), 0.7 + 0.3 * rng.uniform());
        let mut sh = ShCoeffs::from_rgb([rng.uniform(), rng.uniform(), rng.uniform()]);
        for k in 1..4 {
            sh.0[k] = [0.1 * (rng.uniform() - 0.5), 0.1 * (rng.uniform() - 0.5), 0.1 * (rng.uniform() - 0.5)];
        }
        s.push(p, q, ls, -0.5 + rng.uniform(), sh);
    }
    let cfg = RasterConfig { distortion: true, ..RasterConfig::default() };
    let npx = (w * h) as usize;
    let mut wrng = Rng::new(9);
    let mut weights = |k: usize| (0..k).map(|_| wrng.uniform() - 0.5).collect::<Vec<f32>>();
    let wts = [weights(npx * 3), weights(npx), weights(npx), weights(npx * 3), weights(npx)];
    let (out, fwd) = r.render(&g, &s, &cam, [0.1, 0.2, 0.3], &cfg).unwrap();
    assert!(out.alpha.iter().all(|&a| a > 0.05), "every pixel is covered, so no splat edge is in the image");
    let og = OutputGrads {
        color: Some(&wts[0]),
        alpha: Some(&wts[1]),
        depth: Some(&wts[2]),
        normal: Some(&wts[3]),
        distortion: Some(&wts[4]),
        extra: None,
    };
    let grads = r.backward(&g, &fwd, &og).unwrap().grads;
    let loss = |s: &Surfels| functional(&r.render(&g, s, &cam, [0.1, 0.2, 0.3], &cfg).unwrap().0, &wts);
    let mut pairs: Vec<(String, f64, f64)> = Vec::new();
    for i in 0..s.len() {
        // (name, analytic, perturb by e)
        let mut checks: Vec<(String, f32, Perturb)> = Vec::new();
        for a in 0..3 {
            checks.push((
                format!("position {i}.{a}"),
                grads.v_positions[i][a],
                Box::new(move |s, e| s.positions[i][a] += e),
            ));
        }
        for a in 0..2 {
            checks.push((
                format!("log-scale {i}.{a}"),
                grads.v_log_scales[i][a],
                Box::new(move |s, e| s.log_scales[i][a] += e),
            ));
        }
        let vq = grads.v_rotations[i];
        for (a, v) in [vq.x, vq.y, vq.z, vq.w].into_iter().enumerate() {
            checks.push((
                format!("rotation {i}.{a}"),
                v,
                Box::new(move |s, e| {
                    let q = s.rotations[i];
                    let mut c = [q.x, q.y, q.z, q.w];
                    c[a] += e;
                    s.rotations[i] = Quat::from_xyzw(c[0], c[1], c[2], c[3]);
                }),
            ));
        }
        checks.push((
            format!("opacity {i}"),
            grads.v_opacity_logits[i],
            Box::new(move |s, e| s.opacity_logits[i] += e),
        ));
        for (k, c) in [(0usize, 0usize), (0, 2), (2, 1)] {
            checks.push((format!("sh {i}.{k}.{c}"), grads.v_sh[i].0[k][c], Box::new(move |s, e| s.sh[i].0[k][c] += e)));
        }
        for (name, analytic, perturb) in checks {
            let e = 1e-2f32;
            let (mut sp, mut sm) = (s.clone(), s.clone());
            perturb(&mut sp, e);
            perturb(&mut sm, -e);
            let fd = (loss(&sp) - loss(&sm)) / (2.0 * e as f64);
            pairs.push((name, fd, analytic as f64));
        }
    }
    // Relative, with a floor of a hundredth of the largest partial. The step is large because
    // the f32 renders' rounding of the functional, divided by the step, dominates below it
    // (2e-3: 9e-3 worst; 5e-4: 2e-2); at 1e-2 the worst is 2.3e-3, at 2e-2 the step's own
    // curvature shows (8e-3).
    let scale = pairs.iter().fold(0.0f64, |m, p| m.max(p.2.abs()));
    let mut worst = 0.0f64;
    for (name, fd, analytic) in &pairs {
        let err = (fd - analytic).abs() / analytic.abs().max(0.01 * scale);
        worst = worst.max(err);
        assert!(err < 5e-3, "{name}: finite difference {fd:.6} vs gradient {analytic:.6}");
    }
    eprintln!("finite differences: {} partials, largest {scale:.3}, worst error {worst:.2e}", pairs.len());
}

#[test]
fn tile_lists_are_the_boxes_binned_in_depth_then_id_order() {
    let Some(g) = gpu() else { return };
    let r = GpuRaster::new(&g);
    for (seed, n, w, h) in [(3u64, 700usize, 83u32, 71u32), (4, 2000, 50, 37)] {
        let cam = camera(w, h);
        let mut s = scene(seed, n, &cam);
        // Ties in depth, which the order breaks by id.
        for k in (0..s.len()).step_by(7).skip(1) {
            s.positions[k] = s.positions[k - 1];
        }
        let (_, fwd) = r.render(&g, &s, &cam, [0.0; 3], &cpu_cfg()).unwrap();
        let (rects, depth, lists) = fwd.tile_lists(&g).unwrap();
        let tiles_x = w.div_ceil(svgir_gpu::TILE);
        let mut want = vec![Vec::new(); lists.len()];
        let mut order: Vec<usize> =
            (0..s.len()).filter(|&i| rects[i][0] < rects[i][1] && rects[i][2] < rects[i][3]).collect();
        order.sort_by(|&a, &b| depth[a].total_cmp(&depth[b]).then(a.cmp(&b)));
        for &i in &order {
            let rc = rects[i];
            for ty in rc[2] / svgir_gpu::TILE..(rc[3] - 1) / svgir_gpu::TILE + 1 {
                for tx in rc[0] / svgir_gpu::TILE..(rc[1] - 1) / svgir_gpu::TILE + 1 {
                    want[(ty * tiles_x + tx) as usize].push(i as u32);
                }
            }
        }
        let entries: usize = want.iter().map(Vec::len).sum();
        assert_eq!(entries, fwd.entries as usize, "entry count");
        assert!(entries > 5 * lists.len(), "a test with few entries checks little: {entries}");
        for (t, (got, want)) in lists.iter().zip(&want).enumerate() {
            assert_eq!(got, want, "tile {t}");
        }
    }
}
