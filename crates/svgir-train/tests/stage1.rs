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

/// After a densification step the Gaussians are in Morton order of their centres, the children
/// included (their Adam moments follow them: `permuted_rows_step_as_before`).
#[test]
fn densification_leaves_the_gaussians_in_morton_order() {
    let Some(ds) = scene() else { return };
    let mut t = trainer(&ds, 60);
    let start = t.surfels.len();
    for _ in 0..30 {
        t.step(&ds);
    }
    let s = &t.surfels;
    assert_ne!(s.len(), start, "no densification ran");
    let (lo, hi) = s.bounds().unwrap();
    let codes: Vec<u32> = s.positions.iter().map(|p| svgir_core::morton::morton_code(*p, lo, hi)).collect();
    assert!(codes.windows(2).all(|w| w[0] <= w[1]), "not in Morton order");
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

/// A checkpoint whose densification statistics do not match its Gaussian count is refused on
/// load, naming the file and the array, instead of panicking on an index when the resumed run
/// next densifies.
#[test]
fn checkpoint_with_mismatched_densify_stats_is_an_error() {
    let Some(ds) = scene() else { return };
    let t = trainer(&ds, 60);
    let n = t.surfels.len();
    let path = std::env::temp_dir().join(format!("svgir_bad_stats_{}.bin", std::process::id()));
    for (name, shorten) in [
        ("grad_accum", (|s| _ = s.grad_accum.pop()) as fn(&mut svgir_train::densify::DensifyStats)),
        ("denom", |s| _ = s.denom.pop()),
        ("max_radius", |s| _ = s.max_radius.pop()),
        ("accum_weight", |s| s.accum_weight.push(0.0)),
    ] {
        let mut bad = trainer(&ds, 60);
        shorten(&mut bad.stats);
        checkpoint::save(&bad, &path).unwrap();
        let err = match checkpoint::load(&path, &ds) {
            Ok(_) => panic!("stats.{name} of the wrong length was accepted"),
            Err(e) => e.to_string(),
        };
        assert!(err.contains(&path.display().to_string()), "{err}");
        assert!(err.contains(&format!("stats.{name}")) && err.contains(&format!("for {n} Gaussians")), "{err}");
    }
    // The same trainer with its statistics intact loads.
    checkpoint::save(&t, &path).unwrap();
    assert!(checkpoint::load(&path, &ds).is_ok());
    std::fs::remove_file(&path).ok();
}

/// `half_res_until`: the first iterations are those of a run on the photos resized to half
/// size (`View::resized`, as `--downscale 2` loads them), the later ones those of a run on the
/// photos themselves, and a run resumed inside the half-size part continues bit-identically.
#[test]
fn half_size_iterations_are_a_half_size_run_then_the_full_one() {
    let Some(ds) = scene() else { return };
    let (iterations, until) = (60, 20);
    let half_size = |mut cfg: Stage1Config| {
        cfg.half_res_until = until;
        cfg
    };
    let with = |ds: &Dataset, f: &dyn Fn(Stage1Config) -> Stage1Config| {
        let t = trainer(ds, iterations);
        Stage1::new(f(t.config.clone()), t.surfels.clone(), ds)
    };
    let mut small = ds.clone();
    for v in &mut small.train {
        let (w, h) = (v.image.width / 2, v.image.height / 2);
        *v = v.clone().resized(w, h);
    }
    assert_eq!(small.train[0].image.width, 32, "the scene loads at 64 px");

    let mut a = with(&ds, &half_size);
    let mut b = with(&small, &|c| c);
    for _ in 0..until {
        let (sa, sb) = (a.step(&ds), b.step(&small));
        assert_eq!(sa.loss.to_bits(), sb.loss.to_bits(), "iteration {}: not the half-size run's", sa.iteration);
    }
    assert_eq!(a.surfels, b.surfels);
    // The half-size run, saved and continued on the full-size photos, is what `a` now does.
    let path = std::env::temp_dir().join(format!("svgir_half_{}.bin", std::process::id()));
    checkpoint::save(&b, &path).unwrap();
    let mut c = checkpoint::load(&path, &ds).unwrap();
    let mut differs = false;
    while !a.is_done() {
        let (sa, sc) = (a.step(&ds), c.step(&ds));
        assert_eq!(sa.loss.to_bits(), sc.loss.to_bits(), "iteration {}: not the full-size run's", sa.iteration);
        differs |= sa.loss.to_bits() != b.step(&small).loss.to_bits();
    }
    assert!(differs, "after the switch the run should leave the half-size photos");
    assert_eq!(a.surfels, c.surfels);

    // Saved inside the half-size part and resumed: the same run.
    let mut d = with(&ds, &half_size);
    for _ in 0..until / 2 {
        d.step(&ds);
    }
    checkpoint::save(&d, &path).unwrap();
    let mut e = checkpoint::load(&path, &ds).unwrap();
    std::fs::remove_file(&path).ok();
    while !d.is_done() {
        let (sd, se) = (d.step(&ds), e.step(&ds));
        assert_eq!(sd.loss.to_bits(), se.loss.to_bits(), "resumed, iteration {}", sd.iteration);
    }
    assert_eq!(d.surfels, a.surfels, "resuming changed the run");
    assert_eq!(d.surfels, e.surfels);
}

/// The binary-opacity term drives surfels to opacity 0 once densification ends, and the run
/// ends without those under the 1/255 cut (which render as nothing), still training well.
#[test]
fn binary_opacity_ends_without_invisible_surfels() {
    let Some(ds) = scene() else { return };
    let mut t = trainer(&ds, 400);
    t.config.loss.opacity_binary = 0.2;
    let invisible = |t: &Stage1| (0..t.surfels.len()).filter(|&i| t.surfels.opacity(i) < 1.0 / 255.0).count();
    while t.iteration + 1 < t.config.iterations {
        t.step(&ds);
    }
    let (before, n) = (invisible(&t), t.surfels.len());
    t.step(&ds);
    assert!(t.is_done());
    let psnr = test_psnr(&t, &ds);
    eprintln!(
        "{before} of {n} surfels invisible before the last step; {} left; test PSNR {psnr:.2} dB",
        t.surfels.len()
    );
    assert!(before * 5 > n * 2, "the term left only {before} of {n} invisible");
    assert_eq!(invisible(&t), 0);
    assert!(t.surfels.len() + before * 9 / 10 <= n, "pruned {} of {before}", n - t.surfels.len());
    assert!(psnr > 20.0, "test PSNR {psnr:.2}");
}
