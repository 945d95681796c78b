//! End-to-end stage-1 tests on a real scene, downscaled: training improves test PSNR, and a
//! resumed run continues bit-identically.

mod common;

use std::path::PathBuf;
use svgir_core::{Dataset, Rng};
use svgir_io::{load_dataset, LoadOptions};
use svgir_train::{checkpoint, init, BackgroundMode, Stage1, Stage1Config};

fn scene() -> Option<Dataset> {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/synthetic/bowl_fruit_128"));
    if !root.exists() {
        common::missing_data(&root.display().to_string());
        return None;
    }
    let opts = LoadOptions { resolution: Some(64), downscale: None, load_test: true, max_views: Some(16), masks: None };
    Some(load_dataset(&root, &opts).expect("scene loads"))
}

fn trainer(ds: &Dataset, iterations: u64) -> Stage1 {
    let mut cfg = Stage1Config::default().scaled_to(iterations);
    cfg.background = BackgroundMode::Black;
    cfg.init_points = 4000;
    let mut rng = Rng::new(cfg.seed);
    let pts = init::random_box_points(cfg.init_points, cfg.init_half_extent, &mut rng);
    let s = init::surfels_from_points(&pts, cfg.max_sh_degree, &mut rng);
    Stage1::new(cfg, s, ds)
}

fn test_psnr(t: &Stage1, ds: &Dataset) -> f32 {
    let mut sum = 0.0;
    for v in &ds.test {
        let out = t.render_view(&v.camera, [0.0; 3]);
        let gt = svgir_train::stage1::target_rgb(&v.image, [0.0; 3]);
        let mse = out.color.iter().zip(&gt).map(|(a, b)| ((a.clamp(0.0, 1.0) - b) as f64).powi(2)).sum::<f64>()
            / gt.len() as f64;
        sum += svgir_train::stage1::psnr_of_mse(mse);
    }
    sum / ds.test.len() as f32
}

#[test]
fn training_raises_test_psnr_well_above_its_start() {
    let Some(ds) = scene() else { return };
    let mut t = trainer(&ds, 400);
    let start = test_psnr(&t, &ds);
    while !t.is_done() {
        t.step(&ds);
    }
    let end = test_psnr(&t, &ds);
    eprintln!("test PSNR {start:.2} -> {end:.2} dB, {} Gaussians", t.surfels.len());
    assert!(end > start + 6.0 && end > 20.0, "test PSNR {start:.2} -> {end:.2}");
}

#[test]
fn resume_continues_bit_identically() {
    let Some(ds) = scene() else { return };
    let mut a = trainer(&ds, 60);
    for _ in 0..30 {
        a.step(&ds);
    }
    let path = std::env::temp_dir().join(format!("svgir_resume_{}.bin", std::process::id()));
    checkpoint::save(&a, &path).unwrap();
    let mut b = checkpoint::load(&path, &ds).unwrap();
    std::fs::remove_file(&path).ok();
    while !a.is_done() {
        let sa = a.step(&ds);
        let sb = b.step(&ds);
        assert_eq!(sa.loss.to_bits(), sb.loss.to_bits(), "iteration {}", sa.iteration);
    }
    assert_eq!(a.surfels, b.surfels);
    assert_eq!(a.groups, b.groups);
}
