//! End-to-end stage-2 tests on a real scene, downscaled: material/light fitting raises the PBR
//! image's PSNR on test views, and a resumed run continues bit-identically, with and without
//! directional lights and the sun gathered into one of them.

mod common;

use std::path::PathBuf;
use svgir_core::{Dataset, Rng, Surfels};
use svgir_io::{load_dataset, LoadOptions};
use svgir_pbr::{ColourProjector, EnvActivation};
use svgir_train::stage2::{Coverage, GreyLight, ShadeSets, Stage2Weights};
use svgir_train::{checkpoint, init, BackgroundMode, Stage1, Stage1Config, Stage2, Stage2Config};

fn scene() -> Option<Dataset> {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/synthetic/bowl_fruit_128"));
    if !root.exists() {
        common::missing_data(&root.display().to_string());
        return None;
    }
    let opts = LoadOptions { resolution: Some(48), downscale: None, load_test: true, max_views: Some(12), masks: None };
    Some(load_dataset(&root, &opts).expect("scene loads"))
}

/// A quick stage-1 model, then a small stage-2 set-up (K = 16).
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

fn pbr_psnr(t: &Stage2, ds: &Dataset) -> f32 {
    let env = t.env.radiance();
    let mut sum = 0.0;
    for v in &ds.test {
        let r = t.render_pbr(&v.camera, [0.0; 3], &env, [1.0; 3]).unwrap();
        let gt = svgir_train::stage1::target_rgb(&v.image, [0.0; 3]);
        let mse = r.image.iter().zip(&gt).map(|(a, b)| ((a.clamp(0.0, 1.0) - b) as f64).powi(2)).sum::<f64>()
            / gt.len() as f64;
        sum += svgir_train::stage1::psnr_of_mse(mse);
    }
    sum / ds.test.len() as f32
}

/// The test views' mean PBR colour over their photos' mean, on the object (photo alpha > 0.5).
fn brightness(t: &Stage2, ds: &Dataset) -> f64 {
    let env = t.env.radiance();
    let (mut ours, mut theirs) = (0.0f64, 0.0f64);
    for v in &ds.test {
        let r = t.render_pbr(&v.camera, [0.0; 3], &env, [1.0; 3]).unwrap();
        for (px, c) in v.image.data.chunks_exact(4).zip(r.image.chunks_exact(3)) {
            if px[3] > 0.5 {
                ours += c.iter().map(|&x| x as f64).sum::<f64>();
                theirs += px[..3].iter().map(|&x| x as f64).sum::<f64>();
            }
        }
    }
    ours / theirs
}

#[test]
fn stage2_raises_pbr_psnr_and_resumes_bit_identically() {
    let Some(ds) = scene() else { return };
    let surfels = stage1(&ds);
    let spec = Stage2Config { iterations: 120, directions: 16, ..Stage2Config::default() };
    // Directional lights, re-selected before and after the checkpoint (iterations 80 and 120),
    // the sun gathered into one texel before it (iteration 60) and its direction searched before
    // and after it (60, 110: the checkpoint carries a sun off its texel centre), in the run and
    // its resumption; with the normal smoothness (our addition) on, the PBR image blended by
    // the photos' alpha, and two-sided shading (back sides saved in the checkpoint).
    let lit = Stage2Config {
        iterations: 130,
        two_sided: true,
        pbr_coverage: Coverage::Photo,
        weights: Stage2Weights { smooth_normal: 0.1, ..Stage2Weights::default() },
        lights: 8,
        lights_every: 40,
        env_activation: EnvActivation::Exp,
        sun_at: 60,
        sun_search_views: 3,
        sun_search_every: 50,
        // Spaced-out searches: the schedule (next search at 110) must come back with the checkpoint.
        sun_search_settled_deg: 1e-3,
        // Faint Gaussians composite their SH colour instead of being shaded, and each view's
        // shaded set comes from its last render: the sets must come back with the checkpoint.
        shade_min_weight: 0.01,
        shade_sets: ShadeSets::LastVisit,
        ..spec.clone()
    };
    // Four of the 16 directions per iteration, each subset in turn, on both sides and with
    // lights, then all 16 from iteration 111 with the gradients on two of them, each half of the
    // shaded subset in turn: the subsets are derived again on loading (at 100), and the turn
    // continues.
    let subsets = Stage2Config {
        shade_directions: Some(4),
        shade_directions_until: 110,
        gradient_directions: Some(2),
        two_sided: true,
        lights: 4,
        sun_at: 60,
        ..spec.clone()
    };
    for cfg in [spec.clone(), lit, subsets] {
        let t = Stage2::new(cfg, surfels.clone(), &ds).expect("stage 2 set-up");
        let stride = t.config.shade_stride().unwrap();
        assert_eq!(t.subsets.len(), if stride > 1 { stride } else { 0 });
        let grad_stride = t.config.gradient_stride().unwrap();
        assert_eq!(t.grad_subsets.len(), if grad_stride != stride { grad_stride } else { 0 });
        if let Some(b) = &t.back {
            assert_eq!((b.subsets.len(), b.grad_subsets.len()), (t.subsets.len(), t.grad_subsets.len()));
        }
        run_and_resume(&ds, t);
    }
    // Past `shade_directions_until` an iteration shades every direction: the same loss, to the
    // bit, as a run without subsets; inside it, another.
    let loss_at_11 = |shade_directions, shade_directions_until| {
        let cfg = Stage2Config { shade_directions, shade_directions_until, ..spec.clone() };
        let mut t = Stage2::new(cfg, surfels.clone(), &ds).unwrap();
        t.iteration = 10;
        t.step(&ds).unwrap().loss.to_bits()
    };
    // A view's first render takes its shaded set from its own SH pass: the first iteration of a
    // run with sets from the last visit is the exact one, to the bit.
    let first_loss = |shade_sets| {
        let cfg = Stage2Config { shade_sets, shade_min_weight: 0.01, ..spec.clone() };
        let mut t = Stage2::new(cfg, surfels.clone(), &ds).unwrap();
        t.step(&ds).unwrap().loss.to_bits()
    };
    assert_eq!(first_loss(ShadeSets::LastVisit), first_loss(ShadeSets::ThisRender), "a view's first render");
    let all = loss_at_11(None, 0);
    assert_eq!(loss_at_11(Some(4), 10), all, "iteration 11 comes after the subsets");
    assert_ne!(loss_at_11(Some(4), 11), all, "iteration 11 shades a subset");
    // With the gradients on subsets, iteration 11 renders every direction (the loss of the run
    // without subsets) and steps with a subset's gradients (iteration 12 differs).
    let losses_11_12 = |gradient_directions| {
        let cfg =
            Stage2Config { shade_directions: Some(4), shade_directions_until: 10, gradient_directions, ..spec.clone() };
        let mut t = Stage2::new(cfg, surfels.clone(), &ds).unwrap();
        t.iteration = 10;
        let a = t.step(&ds).unwrap().loss.to_bits();
        (a, t.step(&ds).unwrap().loss.to_bits())
    };
    let (exact, subset, half) = (losses_11_12(None), losses_11_12(Some(4)), losses_11_12(Some(2)));
    assert_eq!((exact.0, subset.0, half.0), (all, all, all), "iteration 11 renders every direction");
    assert_ne!(subset.1, exact.1, "iteration 11 stepped with a subset's gradients");
    assert_ne!(half.1, subset.1, "iteration 11 stepped with half a subset's gradients");
    let bad = Stage2Config { shade_directions: Some(5), ..Stage2Config::default() };
    assert!(bad.shade_stride().is_err(), "5 does not divide 64");
    // The gradients' subsets must lie inside the shaded ones.
    let grads = |shade_directions, gradient_directions| {
        Stage2Config { shade_directions, gradient_directions, ..Stage2Config::default() }.gradient_stride()
    };
    assert_eq!(grads(Some(16), Some(8)), Ok(8));
    assert_eq!(grads(None, None), Ok(1));
    assert!(grads(Some(16), Some(32)).is_err(), "32 of the 16 shaded");
    assert!(grads(Some(16), Some(6)).is_err(), "6 does not divide 16");
}

/// `materials_from`: the light warm-up holds albedo, roughness and normal offsets at their initial
/// values while the light trains, then releases them all; `env_lr_after_warm_up` 0 then freezes
/// the light.
#[test]
fn light_warm_up_holds_the_materials_then_releases_them() {
    let Some(ds) = scene() else { return };
    let cfg = Stage2Config {
        iterations: 20,
        directions: 16,
        materials_from: 10,
        env_lr_after_warm_up: 0.0,
        ..Stage2Config::default()
    };
    let mut t = Stage2::new(cfg, stage1(&ds), &ds).expect("stage 2 set-up");
    let (m0, e0) = (t.materials.clone(), t.env.clone());
    for _ in 0..10 {
        t.step(&ds).unwrap();
    }
    assert_eq!(t.materials, m0, "materials held during the warm-up");
    assert_ne!(t.env, e0, "the light trains during the warm-up");
    let e10 = t.env.clone();
    t.step(&ds).unwrap();
    assert_eq!(t.env, e10, "light frozen after the warm-up");
    assert_ne!(t.materials.albedo_raw, m0.albedo_raw);
    assert_ne!(t.materials.roughness_raw, m0.roughness_raw);
    assert_ne!(t.materials.normal_offset, m0.normal_offset);
}

/// `GreyLight::WarmUp`: the learned light stays grey (equal channels per texel, including the
/// random start) while the materials are held, and takes colour once they are released;
/// `GreyLight::Always` keeps it grey, or with `light_colour_degree` its colour smooth.
#[test]
fn grey_light_holds_during_the_warm_up_or_always() {
    let Some(ds) = scene() else { return };
    let cfg = Stage2Config {
        iterations: 20,
        directions: 16,
        materials_from: 10,
        grey_light: GreyLight::WarmUp,
        ..Stage2Config::default()
    };
    let mut t = Stage2::new(cfg.clone(), stage1(&ds), &ds).expect("stage 2 set-up");
    let grey = |t: &Stage2| t.env.param.iter().all(|p| p[0] == p[1] && p[1] == p[2]);
    assert!(!grey(&t), "SPEC 4's random start is coloured");
    let e0 = t.env.clone();
    for _ in 0..10 {
        t.step(&ds).unwrap();
        assert!(grey(&t), "grey during the warm-up (iteration {})", t.iteration);
    }
    assert_ne!(t.env, e0, "the light trains during the warm-up");
    for _ in 0..10 {
        t.step(&ds).unwrap();
    }
    assert!(!grey(&t), "the light takes colour after the warm-up");

    let mut t = Stage2::new(Stage2Config { grey_light: GreyLight::Always, ..cfg.clone() }, stage1(&ds), &ds).unwrap();
    let e0 = t.env.clone();
    for _ in 0..20 {
        t.step(&ds).unwrap();
    }
    assert!(grey(&t) && t.env != e0, "always grey, and trained");

    // With a colour degree the light keeps a smooth colour: not grey, and already in the span.
    let smooth = Stage2Config { grey_light: GreyLight::Always, light_colour_degree: Some(1), ..cfg };
    let mut t = Stage2::new(smooth, stage1(&ds), &ds).unwrap();
    for _ in 0..20 {
        t.step(&ds).unwrap();
    }
    assert!(!grey(&t), "a degree-1 colour is kept");
    let mut p = t.env.param.clone();
    ColourProjector::new(t.env.width, t.env.height, Some(1)).unwrap().apply(&mut p).unwrap();
    let off =
        p.iter().zip(&t.env.param).flat_map(|(a, b)| (0..3).map(move |c| (a[c] - b[c]).abs())).fold(0.0, f32::max);
    assert!(off < 1e-4, "the trained light's colour lies within SH degree 1 (off by {off})");
}

fn run_and_resume(ds: &Dataset, mut t: Stage2) {
    let tag = format!("lights={} shade_directions={:?}", t.config.lights, t.config.shade_directions);
    let start = pbr_psnr(&t, ds);
    for _ in 0..100 {
        t.step(ds).unwrap();
    }
    let mid = pbr_psnr(&t, ds);
    eprintln!("stage-2 test ({tag}) PBR PSNR {start:.2} -> {mid:.2} dB");
    assert!(mid > start + 2.0, "{tag}: PBR PSNR {start:.2} -> {mid:.2}");
    assert_eq!(t.lights.len(), t.config.lights, "{tag}");
    if t.config.sun_search_views > 0 {
        let grid = svgir_core::EnvMap::constant(t.env.width, t.env.height, [0.0; 3]);
        let off_centre = (0..t.lights.len()).any(|b| {
            let tx = t.lights.texels[b];
            t.lights.dirs[b].dot(grid.texel_dir(tx / grid.width, tx % grid.width).normalize()) < 0.99999
        });
        assert!(off_centre, "{tag}: the searched sun should sit off its texel centre");
    }

    let path = std::env::temp_dir().join(format!("svgir_resume2_{}.bin", std::process::id()));
    checkpoint::save_stage2(&t, &path).unwrap();
    let mut u = checkpoint::load_stage2(&path).unwrap();
    std::fs::remove_file(&path).ok();
    assert!(u.mb == t.mb, "{tag}: restored micro-buffers differ");
    assert!(u.surroundings == t.surroundings, "{tag}: restored surroundings differ");
    assert!(u.lights == t.lights, "{tag}: restored lights differ");
    assert_eq!(u.sun_schedule, t.sun_schedule, "{tag}: restored sun schedule differs");
    let sets = |s: &Stage2| (0..ds.train.len()).map(|v| s.view_set(v).map(<[u64]>::to_vec)).collect::<Vec<_>>();
    assert_eq!(sets(&u), sets(&t), "{tag}: restored shaded sets differ");
    let with_sets = sets(&t).iter().filter(|s| s.is_some()).count();
    assert_eq!(with_sets > 0, t.config.shade_sets == ShadeSets::LastVisit, "{tag}: {with_sets} views with sets");
    let back = |s: &Stage2| s.back.as_ref().map(|b| (b.mb.clone(), b.lights.clone()));
    assert_eq!(back(&t).is_some(), t.config.two_sided, "{tag}");
    assert!(back(&u) == back(&t), "{tag}: restored back sides differ");
    if let Some(b) = &t.back {
        assert_eq!(b.lights.dirs, t.lights.dirs, "{tag}: back-side lights follow the front's");
    }
    while !t.is_done() {
        let a = t.step(ds).unwrap();
        let b = u.step(ds).unwrap();
        assert_eq!(a.loss.to_bits(), b.loss.to_bits(), "{tag}: iteration {}", a.iteration);
    }
    assert_eq!(t.materials, u.materials);
    assert_eq!(t.env, u.env);
    assert_eq!(t.rho.to_bits(), u.rho.to_bits());
}

/// Relighting's directional lights only split the light integral into an exact part (the
/// brightest texels, traced) and the K-sample part (the rest of the map): on a smooth map that K
/// samples resolve, 32 lights + K = 64 must agree with K = 1024 and no lights in the mean, and
/// within 2.5 times K = 64 alone in RMSE. A double-counted or dropped light texel (the 32
/// brightest hold ~11% of this map's power) or a wrong solid angle breaks it. (On a smooth map the
/// split does not reduce the noise: the hole it leaves has sharp edges. It pays off on compact
/// lamps and suns. The ratio is a ratio of two noisy errors: with one stage-1 model it was 1.59
/// one-sided and 1.68 two-sided, with a model whose rasteriser rounded differently 1.60 and 2.04,
/// the split's error the same (0.0032 / 0.0031) and K = 64's lower (0.0019 / 0.0015).) One-sided
/// and two-sided.
#[test]
fn relight_lights_conserve_the_light_integral() {
    let Some(ds) = scene() else { return };
    let surfels = stage1(&ds);
    for two_sided in [false, true] {
        let cfg = Stage2Config { iterations: 1, directions: 16, two_sided, ..Stage2Config::default() };
        relight_split_matches_dense_sampling(&ds, &Stage2::new(cfg, surfels.clone(), &ds).expect("stage 2 set-up"));
    }
}

fn relight_split_matches_dense_sampling(ds: &Dataset, s2: &Stage2) {
    use svgir_core::EnvMap;
    use svgir_train::relight::{RelightSampling, Relighter};
    // A broad warm lobe over a dim blue sky: smooth, so dense sampling is a good reference.
    let mut env = EnvMap::constant(64, 32, [0.2, 0.3, 0.5]);
    let lobe = glam::Vec3::new(0.5, -0.3, 0.8).normalize();
    for r in 0..env.height {
        for c in 0..env.width {
            let w = (env.texel_dir(r, c).dot(lobe) - 1.0).exp2().powi(8) * 6.0;
            let t = &mut env.data[(r * env.width + c) as usize];
            *t = [t[0] + w, t[1] + 0.8 * w, t[2] + 0.5 * w];
        }
    }
    let render = |directions, lights| {
        let rl = Relighter::new(s2, RelightSampling { directions, lights, bounces: 0 }).unwrap();
        let lit = rl.prepare(s2, env.clone()).unwrap();
        ds.test
            .iter()
            .take(3)
            .flat_map(|v| rl.render(s2, &v.camera, [0.0; 3], &lit, [1.0; 3]).unwrap().image)
            .collect::<Vec<f32>>()
    };
    let rmse = |a: &[f32], b: &[f32]| {
        (a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
    };
    let reference = render(1024, 0);
    let split = render(64, 32);
    let sampled = render(64, 0);
    let (e_split, e_sampled) = (rmse(&split, &reference), rmse(&sampled, &reference));
    let mean = |a: &[f32]| a.iter().map(|x| *x as f64).sum::<f64>() / a.len() as f64;
    eprintln!(
        "relight (two-sided: {}) vs K=1024: 32 lights + K=64 rmse {e_split:.4}, K=64 alone {e_sampled:.4}; means {:.4} {:.4}",
        s2.config.two_sided,
        mean(&split),
        mean(&reference)
    );
    assert!((mean(&split) / mean(&reference) - 1.0).abs() < 0.02, "the split changes the image's mean");
    assert!(e_split < 2.5 * e_sampled && e_split < 0.01, "split error {e_split} (K = 64 alone: {e_sampled})");
}

/// The sun direction search (`stage2::sun_search`) finds a sun that sits off the texel grid:
/// photos rendered by the model itself under a sun 3 degrees off a texel centre, the sun then
/// displaced by 10 degrees (28 with the first search's cone scan), and the search must bring it
/// back within 1.5 degrees.
#[test]
fn sun_search_recovers_a_displaced_sun() {
    use glam::Vec3;
    use svgir_core::{EnvMap, Image};
    use svgir_pbr::EnvLight;
    let Some(ds) = scene() else { return };
    let cfg = Stage2Config {
        iterations: 1,
        directions: 16,
        lights: 4,
        env_activation: EnvActivation::Exp,
        sun_at: 1,
        sun_search_views: 6,
        ..Stage2Config::default()
    };
    let mut s2 = Stage2::new(cfg, stage1(&ds), &ds).expect("stage 2 set-up");
    let mut env = EnvMap::constant(64, 32, [0.3, 0.35, 0.4]);
    let sun_texel = 8 * 64 + 20;
    env.data[sun_texel as usize] = [400.0, 380.0, 350.0];
    s2.env = EnvLight::from_radiance(&env).unwrap().with_activation(EnvActivation::Exp).unwrap();
    s2.set_lights(&svgir_trace::brightest_texels(&env, 4)).unwrap();
    let b = s2.sun_light().unwrap();
    assert_eq!(s2.lights.texels[b], sun_texel);
    let centre = s2.lights.dirs[b];
    let (t1, t2) = svgir_shading::tangent_frame(centre);
    let truth = (centre + 3f32.to_radians().tan() * t1).normalize();
    s2.move_light(b, truth).unwrap();
    let mut photos = ds.clone();
    for v in photos.train.iter_mut() {
        let r = s2.render_pbr(&v.camera, [0.0; 3], &env, [1.0; 3]).unwrap();
        v.image = Image::from_data(r.width, r.height, 3, r.image);
    }
    let deg = |a: Vec3| a.dot(truth).clamp(-1.0, 1.0).acos().to_degrees();
    // 10 degrees off: the compass alone; 28 degrees off: the first search's cone scan first.
    for (off, cone) in [(10f32, 0.0f32), (28.0, 30.0)] {
        let start = (truth + off.to_radians().tan() * (0.6 * t1 + 0.8 * t2)).normalize();
        s2.move_light(b, start).unwrap();
        s2.config.sun_search_cone_deg = cone;
        s2.iteration = s2.config.sun_at;
        let found = s2.search_sun(&photos).unwrap().expect("a sun to search");
        eprintln!("sun search (cone {cone}): {found:?}; {:.2} deg from the truth", deg(s2.lights.dirs[b]));
        assert_eq!(s2.lights.dirs[b].to_array(), found.to);
        assert!(found.loss_after < found.loss_before);
        let err = deg(s2.lights.dirs[b]);
        assert!(err < 1.5, "cone {cone}: {err:.2} deg from the true sun (started {:.2})", deg(start));
    }
}

/// Stage 1's per-photo colour corrections (`--exposure`) carry into stage 2: on training photos
/// darkened by their own gains (0.55-0.95, the test views untouched), stage 2 given each photo's
/// gain as its correction learns the light and materials of the undarkened scene, as a run on
/// the true photos does; without the corrections it learns a darker scene.
#[test]
fn stage2_applies_stage_1s_photo_corrections() {
    let Some(ds) = scene() else { return };
    let surfels = stage1(&ds);
    let mut dark = ds.clone();
    let gains: Vec<f32> = (0..ds.train.len()).map(|i| 0.55 + 0.4 * ((i * 7) % 10) as f32 / 9.0).collect();
    for (v, g) in dark.train.iter_mut().zip(&gains) {
        // Straight sRGB colour scaled, alpha kept: the object darker, its outline the same.
        v.image.data.chunks_exact_mut(4).for_each(|px| px[..3].iter_mut().for_each(|c| *c *= g));
    }
    let corrections: Vec<[f32; 12]> = gains
        .iter()
        .map(|&g| {
            let mut p = svgir_train::exposure::identity();
            [0, 4, 8].iter().for_each(|&k| p[k] = g);
            p
        })
        .collect();
    let cfg = Stage2Config { iterations: 300, directions: 16, ..Stage2Config::default() };
    let run = |data: &Dataset, corrections: Option<&[[f32; 12]]>| {
        let mut t = Stage2::new(cfg.clone(), surfels.clone(), data).expect("stage 2 set-up");
        t.photo_corrections = corrections.map(<[_]>::to_vec).unwrap_or_default();
        while !t.is_done() {
            t.step(data).unwrap();
        }
        (pbr_psnr(&t, &ds), brightness(&t, &ds))
    };
    let (truth, b_truth) = run(&ds, None);
    let (corrected, b_corrected) = run(&dark, Some(&corrections));
    let (uncorrected, b_uncorrected) = run(&dark, None);
    eprintln!("test PBR PSNR: true photos {truth:.2}, darkened and corrected {corrected:.2}, uncorrected {uncorrected:.2} dB; brightness {b_truth:.3} {b_corrected:.3} {b_uncorrected:.3}");
    // Measured at 300 iterations: 18.84 / 18.76 / 17.91 dB, brightness 0.872 / 0.871 / 0.642
    // (the mean gain is 0.75).
    assert!((corrected - truth).abs() < 0.2, "corrected {corrected:.2} vs {truth:.2}");
    assert!(uncorrected < truth - 0.5, "uncorrected {uncorrected:.2} vs {truth:.2}");
    assert!((b_corrected / b_truth - 1.0).abs() < 0.01, "brightness {b_corrected:.3} vs {b_truth:.3}");
    assert!(b_uncorrected / b_truth < 0.8, "brightness {b_uncorrected:.3} vs {b_truth:.3}");
    // A correction per photo or none: a stale list is an error, not a silent mismatch.
    let mut t = Stage2::new(cfg.clone(), surfels.clone(), &dark).unwrap();
    t.photo_corrections = corrections[1..].to_vec();
    assert!(t.step(&dark).is_err());
    // They come back with the checkpoint (a resumed run compares as the run did).
    t.photo_corrections = corrections.clone();
    let path = std::env::temp_dir().join(format!("svgir_corrections_{}.bin", std::process::id()));
    checkpoint::save_stage2(&t, &path).unwrap();
    let u = checkpoint::load_stage2(&path).unwrap();
    std::fs::remove_file(&path).ok();
    assert_eq!(u.photo_corrections, corrections);
}

/// A ball of small opaque Gaussians (radius 0.3, normals outward) at `c`.
fn ball_at(c: glam::Vec3, n: usize) -> Surfels {
    let mut b = Surfels::with_capacity(n, 3);
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let (r, a) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
        let d = glam::Vec3::new(r * a.cos(), r * a.sin(), z);
        let q = glam::Quat::from_rotation_arc(glam::Vec3::Z, d);
        b.push(c + 0.3 * d, q, glam::Vec2::splat(0.02f32.ln()), 4.0, svgir_core::ShCoeffs::from_rgb([0.6; 3]));
    }
    b
}

/// A floor of opaque grey Gaussians at height `z`, `half` wide each way about `c`. Their
/// heights are spread over a few mm, as a trained floor's are: a ray consumes one disk per
/// continuation offset, so an exactly flat floor would be a single faint layer to it.
fn floor_at(c: glam::Vec3, z: f32, half: f32, step: f32) -> Surfels {
    let mut f = Surfels::with_capacity(0, 3);
    let n = (half / step) as i32;
    let mut rng = Rng::new(9);
    for ix in -n..=n {
        for iy in -n..=n {
            let dz = rng.range(-0.004, 0.004);
            let p = glam::Vec3::new(c.x + ix as f32 * step, c.y + iy as f32 * step, z + dz);
            let sh = svgir_core::ShCoeffs::from_rgb([0.5; 3]);
            f.push(p, glam::Quat::IDENTITY, glam::Vec2::splat((0.7 * step).ln()), 4.0, sh);
        }
    }
    f
}

/// Surroundings (issue 75 item 3): a floor under a ball occludes its lower hemispheres in the
/// micro-buffers, the relighting trace and the lights' columns, and its hits are no Gaussian of
/// the model; on a trained model the floor comes back with the checkpoint, which resumes
/// bit-identically.
#[test]
fn surroundings_occlude_every_trace_and_resume() {
    let Some(ds) = scene() else { return };
    let surfels = stage1(&ds);
    let (c, _) = svgir_train::surroundings::object_extent(&surfels).unwrap();
    let ball = ball_at(c, 1500);
    let floor = floor_at(c, c.z - 0.31, 1.5, 0.04);
    let cfg = Stage2Config {
        iterations: 140,
        directions: 16,
        two_sided: true,
        lights: 2,
        lights_every: 40,
        ..Stage2Config::default()
    };
    let kernels = svgir_train::stage2::Kernels::cpu;
    let alone = Stage2::new(cfg.clone(), ball.clone(), &ds).unwrap();
    let around = Stage2::new_around(cfg.clone(), ball.clone(), floor.clone(), &ds, kernels()).unwrap();
    assert_eq!(around.surfels, alone.surfels);
    assert_eq!(around.surroundings, floor);
    // Mean visibility of the directions pointing down, without and with the floor.
    let down_v = |mb: &svgir_trace::MicroBuffer| {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for j in 0..mb.len() {
            for k in 0..mb.k {
                if mb.direction(j, k).z < -0.5 {
                    sum += mb.visibility(j, k) as f64;
                    n += 1;
                }
            }
        }
        assert!(n > 1000, "weak test: {n} downward samples");
        sum / n as f64
    };
    let (v_alone, v_around) = (down_v(&alone.mb), down_v(&around.mb));
    let on = around.mb.surroundings_hits();
    eprintln!("downward visibility {v_alone:.3} alone, {v_around:.3} on the floor; {on} rays end on it");
    // Measured: 0.864 alone (the ball's own rim), 0.090 on the floor.
    assert!(v_alone > 0.8 && v_around < 0.15, "downward visibility {v_alone:.3} -> {v_around:.3}");
    assert_eq!(alone.mb.surroundings_hits(), 0);
    assert!((0..around.mb.len()).all(|j| (0..16).all(|k| around.mb.hit(j, k).is_none_or(|h| (h as usize) < 1500))));
    // Relighting's own trace (another K) goes through the floor too.
    use svgir_train::relight::{RelightSampling, Relighter};
    let sampling = RelightSampling { directions: 24, lights: 2, bounces: 0 };
    let rl = Relighter::new(&around, sampling).unwrap();
    let (r_alone, r_around) = (down_v(&Relighter::new(&alone, sampling).unwrap().mb), down_v(&rl.mb));
    eprintln!("relighting's downward visibility {r_alone:.3} alone, {r_around:.3} on the floor");
    assert!(r_alone > 0.8 && r_around < 0.15, "relighting: {r_alone:.3} -> {r_around:.3}");
    // Relit under a sky (light from above only), the floor's top throws light up onto the ball;
    // under a map lit from below only that side is dark: the bounce is the side the rays meet.
    let half_lit = |above: bool| {
        let mut m = svgir_core::EnvMap::constant(64, 32, [0.0; 3]);
        for (t, texel) in m.data.iter_mut().enumerate() {
            if (t / 64 < 16) == above {
                *texel = [2.0; 3];
            }
        }
        m
    };
    let from_floor = |above: bool| {
        let light = rl.prepare(&around, half_lit(above)).unwrap();
        let one_bounce = light.one_bounce.unwrap();
        let (mut sum, mut n) = (0.0f64, 0usize);
        for j in 0..rl.mb.len() {
            for k in (0..rl.mb.k).filter(|&k| rl.mb.surroundings_hit(j, k).is_some()) {
                sum += one_bounce[j * rl.mb.k + k][0] as f64;
                n += 1;
            }
        }
        assert!(n > 1000, "weak test: {n} rays on the floor");
        sum / n as f64
    };
    let (sky, ground) = (from_floor(true), from_floor(false));
    eprintln!("light off the floor: {sky:.4} under a sky, {ground:.5} lit from below");
    // Measured: 0.1267 under the sky, 0.00022 lit from below.
    assert!(sky > 0.1 && ground < 0.005 * sky, "light off the floor: {sky} under a sky, {ground} lit from below");
    // The trained model on its floor: the checkpoint keeps the floor and resumes bit for bit.
    let floor = floor_at(c, c.z - 0.6, 1.5, 0.04);
    run_and_resume(&ds, Stage2::new_around(cfg, surfels, floor, &ds, kernels()).unwrap());
}
