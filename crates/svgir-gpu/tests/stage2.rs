//! Stage 2 with its tracing, shading and feature raster on the GPU (lavapipe in CI) against the same
//! CPU, on the shipped scene at small size: SPEC 8's novel views, albedo and relighting within
//! 0.02 dB (issue 76 asks for 0.3), runs resumed across devices within the same, and the same
//! model evaluated by both devices' kernels within 0.002 dB.

mod common;

use svgir_core::{Dataset, Rng, Surfels};
use svgir_io::{load_dataset, LoadOptions};
use svgir_train::relight::RelightSampling;
use svgir_train::{checkpoint, init, BackgroundMode, Kernels, Stage1, Stage1Config, Stage2, Stage2Config};

fn scene() -> Dataset {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/bowl_fruit_128");
    let opts = LoadOptions { resolution: Some(48), downscale: None, load_test: true, max_views: Some(12), masks: None };
    load_dataset(std::path::Path::new(root), &opts).expect("the shipped scene loads")
}

/// A quick stage-1 model on the CPU.
fn stage1(ds: &Dataset) -> Surfels {
    let mut cfg = Stage1Config::default().scaled_to(300);
    cfg.background = BackgroundMode::Black;
    cfg.densify.max_gaussians = 3000;
    let mut rng = Rng::new(0);
    let pts = init::random_box_points(3000, 1.3, &mut rng);
    let mut s1 = Stage1::new(cfg, init::surfels_from_points(&pts, 3, &mut rng), ds);
    while !s1.is_done() {
        s1.step(ds);
    }
    s1.surfels
}

/// The evaluation sink that keeps nothing.
struct Discard;

impl svgir_eval::spec8::EvalSink for Discard {
    fn picture(&mut self, _: &str, _: svgir_core::Image) -> anyhow::Result<()> {
        Ok(())
    }
    fn progress(&mut self, _: &str) {}
}

/// SPEC 8's (novel views, albedo, relighting) PSNR of `s2`, relit at K = 64 with 8 lights.
fn metrics(s2: &Stage2, ds: &Dataset) -> [f64; 3] {
    let sampling = RelightSampling { directions: 64, lights: 8, bounces: 0 };
    let e = svgir_eval::spec8::evaluate(s2, ds, None, 0, sampling, &[], &mut Discard).expect("evaluation");
    let psnr = |v: &serde_json::Value| v["psnr"].as_f64().unwrap_or_else(|| panic!("no PSNR in {e}"));
    [psnr(&e["nvs"]), psnr(&e["albedo"]), psnr(&e["relight"]["mean"])]
}

fn run(s2: &mut Stage2, ds: &Dataset, until: u64) {
    while s2.iteration < until {
        s2.step(ds).expect("stage-2 step");
    }
}

#[test]
fn a_short_stage2_run_on_the_gpu_lands_where_the_cpu_run_does_and_resumes_across_devices() {
    let Some(gpu) = common::gpu() else { return };
    let on_gpu = Kernels {
        tracer: std::sync::Arc::new(svgir_gpu::GpuTracer::new(gpu.clone())),
        shader: std::sync::Arc::new(svgir_gpu::GpuShader::new(gpu.clone())),
        raster: std::sync::Arc::new(svgir_gpu::GpuFeatureRaster::new(gpu)),
    };
    let ds = scene();
    let surfels = stage1(&ds);
    // Two-sided, with directional lights: every path of the GPU shading is taken.
    let cfg = Stage2Config { iterations: 120, directions: 16, two_sided: true, lights: 4, ..Stage2Config::default() };
    let mut cpu = Stage2::new_on(cfg.clone(), surfels.clone(), &ds, Kernels::cpu()).unwrap();
    let mut gpu = Stage2::new_on(cfg.clone(), surfels.clone(), &ds, on_gpu.clone()).unwrap();
    run(&mut cpu, &ds, 60);
    run(&mut gpu, &ds, 60);
    // Resumed half-way on the other device, through a checkpoint file.
    let path = std::env::temp_dir().join(format!("svgir-gpu-stage2-{}.bin", std::process::id()));
    let resumed = |from: &Stage2, kernels: &Kernels| {
        checkpoint::save_stage2(from, &path).unwrap();
        let mut s2 = checkpoint::load_stage2(&path).unwrap();
        s2.kernels = kernels.clone();
        run(&mut s2, &ds, 120);
        s2
    };
    let gpu_then_cpu = resumed(&gpu, &Kernels::cpu());
    let cpu_then_gpu = resumed(&cpu, &on_gpu);
    let _ = std::fs::remove_file(&path);
    run(&mut cpu, &ds, 120);
    run(&mut gpu, &ds, 120);

    let want = metrics(&cpu, &ds);
    eprintln!("CPU run: novel views {:.6} dB, albedo {:.6}, relighting {:.6}", want[0], want[1], want[2]);
    // The GPU's kernels ran: its micro-buffers are its own (a few hits on a boundary differ).
    assert!(gpu.kernels.name().contains(&on_gpu.name()) && on_gpu.name() != "cpu");
    let differ = gpu.mb.vis.iter().zip(&cpu.mb.vis).filter(|(a, b)| a != b).count();
    eprintln!("micro-buffer samples whose visibility differs: {differ} of {}", cpu.mb.vis.len());
    for (name, s2) in [("GPU", &gpu), ("GPU -> CPU", &gpu_then_cpu), ("CPU -> GPU", &cpu_then_gpu)] {
        let got = metrics(s2, &ds);
        eprintln!("{name} run: novel views {:.6} dB, albedo {:.6}, relighting {:.6}", got[0], got[1], got[2]);
        for (what, (g, w)) in ["novel views", "albedo", "relighting"].iter().zip(got.iter().zip(&want)) {
            // Issue 76 asks for 0.3 dB; the runs differ by 1e-5 dB on lavapipe (the micro-buffers
            // by a few boundary hits, the shading by rounding).
            assert!((g - w).abs() <= 0.02, "{name} {what}: {g:.4} dB against the CPU's {w:.4}");
        }
    }
    // The CPU's model evaluated with the GPU's kernels (relighting traced and every render
    // shaded there): the same pictures up to rounding.
    let mut cpu_on_gpu = cpu;
    let cpu_metrics = want;
    cpu_on_gpu.kernels = on_gpu;
    let got = metrics(&cpu_on_gpu, &ds);
    for (what, (g, w)) in ["novel views", "albedo", "relighting"].iter().zip(got.iter().zip(&cpu_metrics)) {
        eprintln!("CPU model, GPU kernels: {what} {g:.4} dB against {w:.4}");
        assert!((g - w).abs() <= 0.002, "{what}: {g:.4} dB on the GPU's kernels against the CPU's {w:.4}");
    }
}
