//! Tiled forward against the dense reference, symmetry and SH checks.

mod common;

use common::*;
use glam::Quat;
use svgir_core::Rng;
use svgir_raster::preprocess::{sh_color, Cam};
use svgir_raster::reference::render_reference;
use svgir_raster::{
    render, render_generic, BackgroundOf, ColorSource, ColorSourceOf, FeaturesOf, RasterConfig, RenderInput,
    RenderInputOf, RenderOutputOf,
};

fn compare(a: &RenderOutputOf<f64>, b: &RenderOutputOf<f64>, tol: f64, what: &str) {
    let fields: [(&str, &[f64], &[f64]); 9] = [
        ("color", &a.color, &b.color),
        ("alpha", &a.alpha, &b.alpha),
        ("depth", &a.depth, &b.depth),
        ("median_depth", &a.median_depth, &b.median_depth),
        ("normal", &a.normal, &b.normal),
        ("distortion", &a.distortion, &b.distortion),
        ("extra", &a.extra, &b.extra),
        ("accum_weight", &a.accum_weight, &b.accum_weight),
        (
            "max_radius",
            &a.max_radius.iter().map(|&v| v as f64).collect::<Vec<_>>(),
            &b.max_radius.iter().map(|&v| v as f64).collect::<Vec<_>>(),
        ),
    ];
    for (name, x, y) in fields {
        let d = max_diff(x, y);
        assert!(d <= tol, "{what}: {name} differs by {d}");
    }
}

#[test]
fn tiled_matches_dense_reference() {
    for seed in 0..6u64 {
        // Non-multiple-of-16 sizes exercise partial tiles; several tile sizes.
        let (w, h) = (40 + seed as u32 * 3, 29 + seed as u32 * 5);
        let cam = test_camera(w, h);
        let surfels = small_scene(seed, 20 + 10 * seed as usize);
        let p = P64::from_surfels(&surfels);
        let n = surfels.len();
        let mut rng = Rng::new(seed + 100);
        let npx = (w * h) as usize;
        let bg_img = random_vec(&mut rng, npx * 3, 0.0, 1.0);
        let m = [1usize, 2, 4, 6][seed as usize % 4];
        let me = [6usize, 4, 1, 2][seed as usize % 4];
        let colf = random_vec(&mut rng, n * m * 3, 0.0, 1.0);
        let extf = random_vec(&mut rng, n * me * 2, -1.0, 1.0);
        let tile = [16u32, 8, 5, 16, 32, 7][seed as usize];
        let cfg = RasterConfig { tile, ..Default::default() };
        for variant in 0..2 {
            let input = RenderInputOf {
                surfels: &p,
                camera: &cam,
                colors: if variant == 0 {
                    ColorSourceOf::Sh
                } else {
                    ColorSourceOf::Features(FeaturesOf { data: &colf, vertices: m, channels: 3, uniform: 0 })
                },
                extra: (variant == 1).then_some(FeaturesOf { data: &extf, vertices: me, channels: 2, uniform: 0 }),
                background: if variant == 0 {
                    BackgroundOf::Color([0.2, 0.5, 0.9])
                } else {
                    BackgroundOf::Image(&bg_img)
                },
            };
            let (tiled, state) = render_generic(&input, &cfg);
            let dense = render_reference(&input, &cfg);
            compare(&tiled, &dense, 1e-12, &format!("seed {seed} variant {variant}"));
            assert!(state.num_tile_entries() > 0);
            // Something is actually drawn and the scene has a culled Gaussian.
            assert!(tiled.alpha.iter().any(|&a| a > 0.5), "seed {seed}: nothing opaque rendered");
            assert!(tiled.max_radius.contains(&0.0), "near-plane Gaussian should be culled");
            assert!(tiled.distortion.iter().any(|&d| d > 0.0));
        }
    }
}

#[test]
fn f32_render_matches_f64_reference() {
    let (w, h) = (48, 40);
    let cam = test_camera(w, h);
    let surfels = small_scene(11, 40);
    let cfg = RasterConfig::default();
    let input = RenderInput {
        surfels: &surfels,
        camera: &cam,
        colors: ColorSource::Sh,
        extra: None,
        background: BackgroundOf::Color([0.1, 0.2, 0.3]),
    };
    let (out, _) = render(&input, &cfg);
    let p = P64::from_surfels(&surfels);
    let input64 = RenderInputOf {
        surfels: &p,
        camera: &cam,
        colors: ColorSourceOf::Sh,
        extra: None,
        background: BackgroundOf::Color([0.1, 0.2, 0.3]),
    };
    let dense = render_reference(&input64, &cfg);
    let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
    // f32 vs f64 can differ where a pixel sits on a cut-off; count, don't demand none.
    let bad = f(&out.color).iter().zip(&dense.color).filter(|(a, b)| (*a - *b).abs() > 1e-3).count();
    assert!(bad <= 3, "{bad} colour values differ by > 1e-3 between f32 and f64");
    let mean_err =
        f(&out.color).iter().zip(&dense.color).map(|(a, b)| (a - b).abs()).sum::<f64>() / dense.color.len() as f64;
    assert!(mean_err < 1e-5, "mean f32 error {mean_err}");
}

#[test]
fn rotating_by_pi_about_the_normal_changes_nothing() {
    let (w, h) = (40, 36);
    let cam = test_camera(w, h);
    let mut surfels = small_scene(3, 25);
    let cfg = RasterConfig::default();
    let input = RenderInput {
        surfels: &surfels,
        camera: &cam,
        colors: ColorSource::Sh,
        extra: None,
        background: BackgroundOf::Color([0.0; 3]),
    };
    let (a, _) = render(&input, &cfg);
    for q in surfels.rotations.iter_mut() {
        *q *= Quat::from_rotation_z(std::f32::consts::PI);
    }
    let input = RenderInput {
        surfels: &surfels,
        camera: &cam,
        colors: ColorSource::Sh,
        extra: None,
        background: BackgroundOf::Color([0.0; 3]),
    };
    let (b, _) = render(&input, &cfg);
    let d = a.color.iter().zip(&b.color).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(d < 1e-4, "colour changed by {d}");
    let d = a.depth.iter().zip(&b.depth).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(d < 1e-4, "depth changed by {d}");
    assert!(a.alpha.iter().any(|&v| v > 0.3));
}

#[test]
fn sh_colour_matches_core_eval() {
    let cam = test_camera(16, 16);
    let surfels = small_scene(5, 10);
    let c = Cam::<f32>::new(&cam);
    let mut nonzero = 0;
    for i in 0..surfels.len() {
        let (rgb, clamped) = sh_color(&surfels, &c, i);
        let dir = (surfels.positions[i] - cam.center()).normalize();
        let want = surfels.sh[i].eval(surfels.sh_degree, dir);
        for ch in 0..3 {
            assert!((rgb[ch] - want[ch].max(0.0)).abs() < 1e-5, "Gaussian {i} channel {ch}");
            assert_eq!(clamped & (1 << ch) != 0, want[ch] < 0.0);
            nonzero += (rgb[ch] > 0.0) as usize;
        }
    }
    assert!(nonzero > 10);
}

#[test]
fn rejects_bad_inputs() {
    let cam = test_camera(8, 8);
    let surfels = small_scene(1, 3);
    let bad = vec![0.0f32; 5];
    let input = RenderInput {
        surfels: &surfels,
        camera: &cam,
        colors: ColorSource::Features(FeaturesOf { data: &bad, vertices: 4, channels: 3, uniform: 0 }),
        extra: None,
        background: BackgroundOf::Color([0.0; 3]),
    };
    assert!(svgir_raster::try_render(&input, &RasterConfig::default()).is_err());
    let ok = vec![0.0f32; surfels.len() * 3 * 3];
    let input = RenderInput {
        colors: ColorSource::Features(FeaturesOf { data: &ok, vertices: 3, channels: 3, uniform: 0 }),
        ..input
    };
    assert!(svgir_raster::try_render(&input, &RasterConfig::default()).is_err());
}

/// The oracle's per-pixel weights add up to its alpha, and to its accumulated weight per Gaussian
/// when every pixel is listed; none of them zero. (They come in the sort key's order, by centre
/// depth; a tilted splat's intersection depth may be out of that order.)
#[test]
fn layer_weights_sum_to_the_oracles_alpha() {
    use svgir_raster::fixtures::Problem;
    use svgir_raster::reference::layer_weights;
    let prob = Problem::new(300, 24);
    let input = prob.input();
    let cfg = RasterConfig::default();
    let dense = render_reference(&input, &cfg);
    let pixels: Vec<(u32, u32)> = (0..24).flat_map(|y| (0..24).map(move |x| (x, y))).collect();
    let layers = layer_weights(&input, &cfg, &pixels);
    let mut acc = vec![0.0f64; prob.surfels.len()];
    let mut stacked = 0;
    for (k, l) in layers.iter().enumerate() {
        let sum: f32 = l.iter().map(|h| h.weight).sum();
        assert!((sum - dense.alpha[k]).abs() < 1e-5, "pixel {k}: {sum} vs alpha {}", dense.alpha[k]);
        assert!(l.iter().all(|h| h.weight > 0.0));
        for h in l {
            acc[h.gaussian as usize] += h.weight as f64;
        }
        stacked += (l.len() > 1) as usize;
    }
    assert!(stacked > 100, "the scene stacks splats: {stacked} pixels with two or more");
    for (g, (&a, &b)) in acc.iter().zip(&dense.accum_weight).enumerate() {
        assert!((a - b as f64).abs() < 1e-4, "Gaussian {g}: {a} vs {b}");
    }
}
