//! Stage 1's loss and optimiser kernels against the CPU's (svgir_train's `stage1_objective`
//! and `AdamGroup`), and a whole short stage-1 run on the shipped scene on both devices.

mod common;
use common::gpu;

use glam::Vec3;
use svgir_core::{Image, Rng};
use svgir_gpu::testing::{adam_step, stage1_loss, LossInput};
use svgir_raster::fixtures::{look_at_camera, random_scene};
use svgir_raster::{Background, ColorSource, RasterConfig, RenderInput};
use svgir_train::adam::AdamGroup;
use svgir_train::losses::objective::{stage1_objective, ObjectiveInput, ObjectiveTarget};
use svgir_train::stage1::photo_target;
use svgir_train::Stage1Config;

/// Largest |gpu - cpu| over a gradient, as a fraction of the CPU gradient's largest magnitude.
fn rel_err(what: &str, gpu: &[f32], cpu: &[f32]) -> f32 {
    assert_eq!(gpu.len(), cpu.len(), "{what}");
    let scale = cpu.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let worst = gpu.iter().zip(cpu).fold(0.0f32, |m, (g, c)| m.max((g - c).abs()));
    eprintln!("{what}: worst {worst:.3e} of max {scale:.3e}");
    assert!(scale > 0.0, "{what}: the CPU gradient is all zero, the check would be empty");
    worst / scale
}

#[test]
fn loss_matches_the_cpu_objective() {
    let Some(g) = gpu() else { return };
    for (seed, w, h) in [(1u64, 48u32, 40u32), (2, 67, 53)] {
        let cam = look_at_camera(Vec3::new(2.2, -1.6, 1.1).normalize() * 3.0, 0.9, w, h);
        let mut s = random_scene(300, seed);
        s.sh_degree = 1;
        let input = RenderInput {
            surfels: &s,
            camera: &cam,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color([0.2, 0.3, 0.4]),
        };
        let cfg = RasterConfig { distortion: true, ..RasterConfig::default() };
        let (out, _) = svgir_raster::render(&input, &cfg);
        // A photo with a mask that cuts through the render: opaque, transparent and soft.
        let mut rng = Rng::new(seed);
        let npx = (w * h) as usize;
        let data: Vec<f32> = (0..npx)
            .flat_map(|i| {
                let (x, y) = ((i % w as usize) as f32 / w as f32, (i / w as usize) as f32 / h as f32);
                let a = ((0.35 - ((x - 0.5).powi(2) + (y - 0.5).powi(2)).sqrt()) * 8.0).clamp(0.0, 1.0);
                [rng.uniform(), rng.uniform(), rng.uniform(), a]
            })
            .collect();
        let photo = Image::from_data(w, h, 4, data);
        let bg = [0.2, 0.3, 0.4];
        let mut weights = Stage1Config::default().loss;
        weights.mask = 0.1;
        weights.entropy = 0.05;
        weights.normal_start = 0.05;
        weights.normal_ramp = 0.0;
        weights.distortion = 100.0;
        let (alpha, dilated) = photo_target(&photo);
        let gt = photo.composite_over(bg).data;
        let obj = stage1_objective(
            &weights,
            0.5,
            true,
            &ObjectiveInput {
                color: &out.color,
                alpha: &out.alpha,
                depth: &out.depth,
                normal: &out.normal,
                distortion: &out.distortion,
            },
            &ObjectiveTarget { rgb: &gt, alpha: &alpha, dilated: &dilated },
            &cam,
        );
        let li = LossInput {
            color: &out.color,
            alpha: &out.alpha,
            depth: &out.depth,
            normal: &out.normal,
            distortion: &out.distortion,
        };
        let (rec, vout) = stage1_loss(&g, &li, &photo, &cam, bg, &weights, 0.05, true).unwrap();
        let pick = |at: usize, ch: usize| -> Vec<f32> {
            (0..npx).flat_map(|i| vout[i * 9 + at..i * 9 + at + ch].to_vec()).collect()
        };
        eprintln!("loss gpu {:?}, cpu total {} l1 {} ssim {}", rec, obj.loss, obj.l1, obj.ssim);
        assert!((rec[0] - obj.l1).abs() <= 1e-5 * obj.l1, "L1 {} vs {}", rec[0], obj.l1);
        assert!((rec[1] - obj.ssim).abs() <= 1e-5, "SSIM {} vs {}", rec[1], obj.ssim);
        assert!((rec[7] - obj.loss).abs() <= 1e-5 * obj.loss.abs(), "total {} vs {}", rec[7], obj.loss);
        assert!(rel_err("colour", &pick(0, 3), &obj.v_color) < 1e-5);
        assert!(rel_err("alpha", &pick(3, 1), &obj.v_alpha) < 1e-6);
        assert!(rel_err("depth", &pick(4, 1), &obj.v_depth) < 2e-5);
        assert!(rel_err("normal", &pick(5, 3), &obj.v_normal) < 2e-5);
        assert!(rel_err("distortion", &pick(8, 1), obj.v_distortion.as_deref().unwrap()) < 1e-6);
    }
}

#[test]
fn adam_matches_the_cpu_step() {
    let Some(g) = gpu() else { return };
    let mut rng = Rng::new(7);
    let rows = 1000;
    let mut scale = vec![0.05f32; 48];
    scale[..3].fill(1.0);
    // The third case is an opacity group with the binary-opacity term (logits from -6 to 6),
    // whose gradient the CPU adds before its step and the GPU inside it.
    for (stride, lr_scale, binary) in [(3usize, None, 0.0), (48, Some(scale), 0.0), (1, None, 0.3f32)] {
        let mut cpu = AdamGroup::new("g", 1e-3, stride, rows);
        if let Some(s) = lr_scale {
            cpu = cpu.with_lr_scale(s);
        }
        let mut gpu_group = cpu.clone();
        let spread = if binary > 0.0 { 12.0 } else { 1.0 };
        let mut p_cpu: Vec<f32> = (0..rows * stride).map(|_| (rng.uniform() - 0.5) * spread).collect();
        let mut p_gpu = p_cpu.clone();
        for _ in 0..5 {
            let grad: Vec<f32> = (0..rows * stride).map(|_| (rng.uniform() - 0.5) * 1e-2).collect();
            let mut g_cpu = grad.clone();
            if binary > 0.0 {
                svgir_train::losses::opacity::binary_opacity(&p_cpu, binary, &mut g_cpu);
            }
            cpu.step_reference(&mut p_cpu, &g_cpu);
            adam_step(&g, &mut gpu_group, &mut p_gpu, &grad, binary).unwrap();
        }
        assert_eq!(cpu.step, gpu_group.step);
        // sqrt and division are within a few ulps on a GPU (WGSL allows 2.5 ulp for division).
        for (what, a, b) in [("params", &p_gpu, &p_cpu), ("m", &gpu_group.m, &cpu.m), ("v", &gpu_group.v, &cpu.v)] {
            // Relative to each value, but not below a thousandth of the largest: with the
            // binary term a gradient can cancel to near 0, and exp's few ulps remain.
            let floor = 1e-3 * b.iter().fold(1e-3f32, |m, y| m.max(y.abs()));
            let worst = a.iter().zip(b.iter()).map(|(x, y)| (x - y).abs() / y.abs().max(floor)).fold(0.0f32, f32::max);
            eprintln!("adam stride {stride} binary {binary} {what}: worst relative {worst:.2e}");
            // The term's `1 - o` at logit 6 cancels: exp's ulps on the GPU become 4e-5 there.
            let bound = if binary > 0.0 { 1e-4 } else { 1e-5 };
            assert!(worst < bound, "{what}: {worst}");
        }
    }
}

/// Mean PSNR of the surfels' renders of the first `k` test views, rendered on the CPU.
fn test_psnr(t: &svgir_train::Stage1, ds: &svgir_core::Dataset, k: usize) -> f32 {
    let bg = t.config.background.fixed_color().unwrap_or([1.0; 3]);
    let k = k.min(ds.test.len());
    let mut sum = 0.0;
    for i in 0..k {
        let v = &ds.test[i * ds.test.len() / k];
        let out = svgir_train::stage1::render_surfels(&t.surfels, &v.camera, bg, &t.raster);
        let pred: Vec<f32> = out.color.iter().map(|c| c.clamp(0.0, 1.0)).collect();
        let gt = svgir_train::stage1::target_rgb(&v.image, bg);
        sum += svgir_metrics::psnr(&pred, &gt, 3, None).unwrap();
    }
    sum as f32 / k as f32
}

/// A fresh stage-1 run of `iterations` on the shipped scene, as `svgir train` sets it up, but
/// from 3000 random points and with densification every 40 iterations from the 40th to the
/// 160th (lavapipe runs a GPU's kernels on two CPU cores, so the test keeps the work small).
fn fresh_run(ds: &svgir_core::Dataset, iterations: u64) -> svgir_train::Stage1 {
    let pixels = ds.train.iter().map(|v| v.image.pixel_count()).sum();
    let mut cfg = Stage1Config::for_profile(svgir_train::Profile::Object, iterations, pixels);
    cfg.mask_losses_only_with(ds.has_masks());
    cfg.init_points = 3000;
    cfg.densify.from_iter = 40;
    cfg.densify.interval = 40;
    cfg.densify.until_iter = 160;
    cfg.densify.opacity_reset_interval = 120;
    let mut rng = Rng::new(cfg.seed);
    let points = svgir_train::init::random_box_points(cfg.init_points, cfg.init_half_extent, &mut rng);
    let surfels = svgir_train::init::surfels_from_points(&points, cfg.max_sh_degree, &mut rng);
    svgir_train::Stage1::new(cfg, surfels, ds)
}

fn run_cpu(t: &mut svgir_train::Stage1, ds: &svgir_core::Dataset, until: u64) {
    while t.iteration < until {
        t.step(ds);
    }
}

fn run_gpu(t: svgir_train::Stage1, ds: &svgir_core::Dataset, until: u64) -> svgir_train::Stage1 {
    let g = gpu().expect("adapter");
    let mut r = svgir_gpu::GpuStage1::new(t, g, ds).unwrap();
    while r.host.iteration < until {
        r.step(ds, false).unwrap();
    }
    assert_eq!(r.overflows, 0, "renders overflowed the entry buffers");
    r.into_parts().unwrap().0
}

/// Through a checkpoint file, as `--resume` reads it.
fn through_checkpoint(t: &svgir_train::Stage1, ds: &svgir_core::Dataset, name: &str) -> svgir_train::Stage1 {
    let path = std::env::temp_dir().join(format!("svgir-gpu-{name}-{}.bin", std::process::id()));
    svgir_train::checkpoint::save(t, &path).unwrap();
    let back = svgir_train::checkpoint::load(&path, ds).unwrap();
    let _ = std::fs::remove_file(&path);
    back
}

/// The shipped scene with its test views.
fn shipped_scene() -> svgir_core::Dataset {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/bowl_fruit_128");
    let opts = svgir_io::LoadOptions { load_test: true, ..Default::default() };
    svgir_io::load_dataset(root, &opts).unwrap()
}

#[test]
fn a_short_run_on_the_shipped_scene_lands_where_the_cpu_run_does_and_resumes_across_devices() {
    if gpu().is_none() {
        return;
    }
    let ds = shipped_scene();
    let iters = 200;
    let t0 = std::time::Instant::now();
    let mut cpu = fresh_run(&ds, iters);
    run_cpu(&mut cpu, &ds, iters);
    let t1 = std::time::Instant::now();
    let gpu_run = run_gpu(fresh_run(&ds, iters), &ds, iters);
    let t2 = std::time::Instant::now();
    // Half on each device, each way, through a checkpoint.
    let half = iters / 2;
    let first = run_gpu(fresh_run(&ds, iters), &ds, half);
    let mut gpu_then_cpu = through_checkpoint(&first, &ds, "g2c");
    run_cpu(&mut gpu_then_cpu, &ds, iters);
    let mut first = fresh_run(&ds, iters);
    run_cpu(&mut first, &ds, half);
    let cpu_then_gpu = run_gpu(through_checkpoint(&first, &ds, "c2g"), &ds, iters);
    let k = 8;
    let p_cpu = test_psnr(&cpu, &ds, k);
    let results = [("gpu", &gpu_run), ("gpu then cpu", &gpu_then_cpu), ("cpu then gpu", &cpu_then_gpu)];
    eprintln!(
        "cpu {p_cpu:.2} dB ({} Gaussians, {:.1} s); gpu {:.1} s",
        cpu.surfels.len(),
        (t1 - t0).as_secs_f64(),
        (t2 - t1).as_secs_f64()
    );
    for (what, t) in results {
        let p = test_psnr(t, &ds, k);
        eprintln!("{what}: {p:.2} dB, {} Gaussians", t.surfels.len());
        assert_eq!(t.iteration, iters, "{what}");
        assert!((p - p_cpu).abs() <= 0.3, "{what}: {p:.2} dB against the CPU's {p_cpu:.2}");
    }
    // The run learns: far above the initial random box.
    let p0 = test_psnr(&fresh_run(&ds, iters), &ds, k);
    assert!(p_cpu > p0 + 5.0, "the CPU run did not learn: {p0:.2} -> {p_cpu:.2} dB");
}

#[test]
fn one_iteration_gathers_the_cpu_statistics_and_takes_its_step() {
    let Some(g) = gpu() else { return };
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/bowl_fruit_128");
    let ds = svgir_io::load_dataset(root, &svgir_io::LoadOptions::default()).unwrap();
    let mut cpu = fresh_run(&ds, 200);
    cpu.step(&ds);
    let mut gpu_run = svgir_gpu::GpuStage1::new(fresh_run(&ds, 200), g, &ds).unwrap();
    gpu_run.step(&ds, true).unwrap();
    gpu_run.sync().unwrap();
    let (a, b) = (&gpu_run.host.stats, &cpu.stats);
    // A Gaussian whose box ends within rounding of a pixel edge is seen on one device only.
    let both: Vec<usize> = (0..b.denom.len()).filter(|&i| a.denom[i] == b.denom[i]).collect();
    let seen = b.denom.iter().filter(|&&d| d > 0).count();
    let differ = b.denom.len() - both.len();
    eprintln!("seen by the view: {seen}; seen on one device only: {differ}");
    assert!(seen > 1000 && differ * 200 <= seen, "{differ} of {seen}");
    let at = |v: &[f32]| both.iter().map(|&i| v[i]).collect::<Vec<f32>>();
    assert!(rel_err("max radius", &at(&a.max_radius), &at(&b.max_radius)) < 1e-5);
    assert!(rel_err("accumulated weight", &at(&a.accum_weight), &at(&b.accum_weight)) < 1e-4);
    // Sums over a splat's pixels in another order, with cancellation: tests/raster.rs checks
    // these gradients against f64; here the whole iteration's path to them.
    assert!(rel_err("screen gradient", &at(&a.grad_accum), &at(&b.grad_accum)) < 2e-3);
    let pos = |t: &svgir_train::Stage1| -> Vec<f32> { bytemuck::cast_slice(&t.surfels.positions).to_vec() };
    let moved: Vec<f32> = pos(&cpu).iter().zip(&pos(&fresh_run(&ds, 200))).map(|(x, y)| x - y).collect();
    let moved_gpu: Vec<f32> = pos(&gpu_run.host).iter().zip(&pos(&fresh_run(&ds, 200))).map(|(x, y)| x - y).collect();
    // Adam's first step is lr sign(g) where g is not tiny: the steps agree but for the signs of
    // gradients at the rounding level.
    let agree = moved.iter().zip(&moved_gpu).filter(|(a, b)| (*a - *b).abs() <= 1e-3 * a.abs().max(1e-9)).count();
    eprintln!("position steps that agree: {agree} of {}", moved.len());
    assert!(agree as f64 >= 0.99 * moved.len() as f64, "{agree} of {}", moved.len());
}

/// The binary-opacity term on the GPU (added inside the opacity group's Adam step) drives as
/// many surfels under the 1/255 cut as on the CPU, and the run ends without them, as the CPU's
/// does (its final pruning runs on the host, so the GPU run must bring its surfels there).
#[test]
fn the_binary_opacity_term_drives_and_prunes_as_on_the_cpu() {
    if gpu().is_none() {
        return;
    }
    let ds = shipped_scene();
    let iters = 200;
    let run = || {
        let mut t = fresh_run(&ds, iters);
        t.config.loss.opacity_binary = 0.2;
        t
    };
    let invisible =
        |t: &svgir_train::Stage1| (0..t.surfels.len()).filter(|&i| t.surfels.opacity(i) < 1.0 / 255.0).count();
    let mut cpu = run();
    run_cpu(&mut cpu, &ds, iters - 1);
    let (cpu_before, cpu_n) = (invisible(&cpu), cpu.surfels.len());
    run_cpu(&mut cpu, &ds, iters);
    let gpu_run = run_gpu(run(), &ds, iters - 1);
    let (gpu_before, gpu_n) = (invisible(&gpu_run), gpu_run.surfels.len());
    let gpu_run = run_gpu(gpu_run, &ds, iters);
    let (p_cpu, p_gpu) = (test_psnr(&cpu, &ds, 8), test_psnr(&gpu_run, &ds, 8));
    eprintln!(
        "before the last step: cpu {cpu_before} of {cpu_n} invisible, gpu {gpu_before} of {gpu_n}; after: {} / {} \
         surfels, {p_cpu:.2} / {p_gpu:.2} dB",
        cpu.surfels.len(),
        gpu_run.surfels.len()
    );
    // 40 iterations of the term (after densification ends at 160) leave about 11.5% invisible.
    assert!(gpu_before * 10 > gpu_n, "the GPU's term left only {gpu_before} of {gpu_n} invisible");
    let share = |k: usize, n: usize| k as f64 / n as f64;
    assert!(
        (share(gpu_before, gpu_n) - share(cpu_before, cpu_n)).abs() <= 0.01,
        "invisible surfels: gpu {gpu_before} of {gpu_n}, cpu {cpu_before} of {cpu_n}"
    );
    assert_eq!(invisible(&gpu_run), 0);
    assert!(
        gpu_run.surfels.len() + gpu_before * 9 / 10 <= gpu_n,
        "pruned {} of {gpu_before}",
        gpu_n - gpu_run.surfels.len()
    );
    assert!((p_gpu - p_cpu).abs() <= 0.3, "{p_gpu:.2} dB against the CPU's {p_cpu:.2}");
}

/// The shipped scene's training photos each under its own gain and white balance (0.7-1.3 per
/// channel), as a phone's or a photo collection's.
fn exposed_scene() -> svgir_core::Dataset {
    let mut ds = shipped_scene();
    let mut rng = Rng::new(21);
    for v in ds.train.iter_mut() {
        let gain = [rng.range(0.7, 1.3), rng.range(0.7, 1.3), rng.range(0.7, 1.3)];
        let c = v.image.channels as usize;
        for (i, x) in v.image.data.iter_mut().enumerate() {
            if i % c < 3 {
                *x = (*x * gain[i % c]).min(1.0);
            }
        }
    }
    ds
}

/// `--exposure` on the GPU: one iteration takes the CPU's step of the photo's correction (and
/// of the surfels, through `A^T`), and a run up to its first densification, on photos under
/// their own gains, keeps every photo's correction and the test views the CPU's.
#[test]
fn the_exposure_correction_matches_the_cpu() {
    let Some(g) = gpu() else { return };
    let ds = exposed_scene();
    let run = |iters| {
        let mut t = fresh_run(&ds, iters);
        t.config.exposure = true;
        // Corrections away from the identity, so that the colour gradient's A^T matters.
        let mut e = svgir_train::exposure::ExposureCorrection::new(ds.train.len());
        let mut rng = Rng::new(5);
        for p in e.params.iter_mut().flatten() {
            *p += 0.15 * rng.normal();
        }
        t.exposure = Some(e);
        t
    };
    let worst = |a: &svgir_train::Stage1, b: &svgir_train::Stage1| {
        let (a, b) = (a.exposure.as_ref().unwrap(), b.exposure.as_ref().unwrap());
        let d = |x: &[[f32; 12]], y: &[[f32; 12]]| {
            x.iter().flatten().zip(y.iter().flatten()).fold(0.0f32, |m, (p, q)| m.max((p - q).abs()))
        };
        let moments = a.adam.iter().zip(&b.adam).fold(0.0f32, |m, (p, q)| {
            p.m.iter().zip(&q.m).fold(m, |m, (x, y)| m.max((x - y).abs() / y.abs().max(1e-6)))
        });
        (d(&a.params, &b.params), moments)
    };
    // One iteration.
    let mut cpu = run(200);
    let view = cpu.step(&ds).view;
    let mut gpu_run = svgir_gpu::GpuStage1::new(run(200), g.clone(), &ds).unwrap();
    gpu_run.step(&ds, true).unwrap();
    gpu_run.sync().unwrap();
    let (dp, dm) = worst(&gpu_run.host, &cpu);
    let moved = cpu.exposure.as_ref().unwrap().params[view]
        .iter()
        .zip(run(200).exposure.as_ref().unwrap().params[view])
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    // The surfels' gradients come through A^T: the screen gradients as in the iteration
    // without a correction (one_iteration_gathers_the_cpu_statistics_and_takes_its_step).
    let (a, b) = (&gpu_run.host.stats, &cpu.stats);
    let both: Vec<usize> = (0..b.denom.len()).filter(|&i| a.denom[i] == b.denom[i] && b.denom[i] > 0).collect();
    let at = |v: &[f32]| both.iter().map(|&i| v[i]).collect::<Vec<f32>>();
    assert!(both.len() > 1000, "{} Gaussians seen on both", both.len());
    assert!(rel_err("screen gradient", &at(&a.grad_accum), &at(&b.grad_accum)) < 2e-3);
    eprintln!("one iteration (photo {view}): correction moved {moved:.2e}; GPU - CPU: params {dp:.2e}, first moments {dm:.2e} relative");
    assert!(moved > 5e-4, "the correction did not move: {moved}");
    assert!(dp < 1e-8 && dm < 5e-5, "params {dp}, moments {dm}");
    // Up to the first densification (iteration 40), where the two runs' Gaussians part (a box
    // edge within rounding; after it two runs on one device with and without the correction
    // differ by 0.2-0.3 dB at 50-100 iterations, whatever the device): every photo's correction
    // and the test views as the CPU's.
    let iters = 39;
    let mut cpu = run(200);
    run_cpu(&mut cpu, &ds, iters);
    let gpu_run = run_gpu(run(200), &ds, iters);
    let (p_cpu, p_gpu) = (test_psnr(&cpu, &ds, 8), test_psnr(&gpu_run, &ds, 8));
    let (dp, _) = worst(&gpu_run, &cpu);
    eprintln!("{iters} iterations: {p_cpu:.3} / {p_gpu:.3} dB (CPU / GPU); corrections differ by {dp:.3e} at most");
    assert!((p_gpu - p_cpu).abs() <= 0.01, "{p_gpu:.3} against {p_cpu:.3}");
    // 3.6e-6 measured (0.4% of one Adam step of 1e-3): the correction's opacity share reaches
    // the surfels' gradients, which the GPU sums in another order than the CPU.
    assert!(dp < 1e-5, "corrections differ by {dp}");
}
