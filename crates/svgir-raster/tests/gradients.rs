//! Every gradient of the real (tiled) backward, instantiated in f64, against central finite
//! differences of the dense f64 reference renderer, for a loss that weights every output.

mod common;

use common::*;
use svgir_core::Rng;
use svgir_raster::reference::render_reference;
use svgir_raster::{
    backward, backward_generic, render, render_generic, BackgroundOf, ColorSourceOf, FeaturesOf, GradsOf, OutputGrads,
    RasterConfig, RenderInput, RenderInputOf,
};

struct Case {
    seed: u64,
    /// Colour vertices; 0 = SH.
    color_m: usize,
    extra: Option<(usize, usize)>,
    /// The extra table's uniform channels ([`FeaturesOf::uniform`]).
    uniform: usize,
    bg_image: bool,
}

struct Checker {
    checked: usize,
    skipped: usize,
    /// Checks whose gradient is not negligible (so the comparison could fail).
    nonzero: usize,
    worst: f64,
}

impl Checker {
    /// Compares `analytic` with central differences of `f` at steps h and h/2; a pair of estimates
    /// that disagree means a pixel crossed a cut-off inside the step (a true discontinuity of the
    /// renderer), and the parameter is skipped and counted.
    fn check(&mut self, what: &str, analytic: f64, mut f: impl FnMut(f64) -> f64) {
        let h = 1e-6;
        let fd1 = (f(h) - f(-h)) / (2.0 * h);
        let fd2 = (f(h / 2.0) - f(-h / 2.0)) / h;
        let scale = 1e-6 + 1e-5 * fd1.abs().max(analytic.abs());
        if (fd1 - fd2).abs() > scale {
            self.skipped += 1;
            return;
        }
        let err = (analytic - fd1).abs();
        self.worst = self.worst.max(err / (1e-3 + fd1.abs()));
        assert!(err <= scale, "{what}: analytic {analytic:.9e} vs finite difference {fd1:.9e}");
        self.checked += 1;
        self.nonzero += (fd1.abs() > 1e-4) as usize;
    }
}

fn run_case(case: &Case) -> (usize, usize, usize, f64) {
    let (w, h) = (32u32, 32u32);
    let npx = (w * h) as usize;
    let cam = test_camera(w, h);
    let surfels = small_scene(case.seed, 5);
    let n = surfels.len();
    let mut params = P64::from_surfels(&surfels);
    let mut rng = Rng::new(case.seed + 7);
    let cm = case.color_m.max(1);
    let mut colf = random_vec(&mut rng, n * cm * 3, 0.0, 1.0);
    let (me, ce) = case.extra.unwrap_or((1, 0));
    let mut extf = random_vec(&mut rng, n * me * ce, -1.0, 1.0);
    let mut bg = random_vec(&mut rng, if case.bg_image { npx * 3 } else { 3 }, 0.0, 1.0);
    let lw = LossWeights::new(case.seed, npx, ce);
    let cfg = RasterConfig::default();

    macro_rules! input {
        ($p:expr, $colf:expr, $extf:expr, $bg:expr) => {
            RenderInputOf {
                surfels: $p,
                camera: &cam,
                colors: if case.color_m == 0 {
                    ColorSourceOf::Sh
                } else {
                    ColorSourceOf::Features(FeaturesOf { data: $colf, vertices: cm, channels: 3, uniform: 0 })
                },
                extra: case.extra.map(|_| FeaturesOf {
                    data: $extf,
                    vertices: me,
                    channels: ce,
                    uniform: case.uniform,
                }),
                background: if case.bg_image {
                    BackgroundOf::Image($bg)
                } else {
                    BackgroundOf::Color([$bg[0], $bg[1], $bg[2]])
                },
            }
        };
    }
    let (out, state) = render_generic(&input!(&params, &colf, &extf, &bg), &cfg);
    let g: GradsOf<f64> = backward_generic(&input!(&params, &colf, &extf, &bg), &cfg, &state, &out, &lw.grads());
    assert!(out.alpha.iter().any(|&a| a > 0.5));

    let mut ck = Checker { checked: 0, skipped: 0, nonzero: 0, worst: 0.0 };
    for i in 0..n {
        for j in 0..P64::PER {
            let sh_param = j >= 10;
            if sh_param && case.color_m != 0 {
                continue;
            }
            let analytic = match j {
                0..3 => g.v_positions[i][j],
                3..7 => g.v_rotations[i].to_array()[j - 3],
                7..9 => g.v_log_scales[i][j - 7],
                9 => g.v_opacity_logits[i],
                _ => g.v_sh[i][(j - 10) / 3][(j - 10) % 3],
            };
            let x0 = *params.param_mut(i, j);
            let what = format!("seed {} Gaussian {i} {}", case.seed, P64::param_name(j));
            let mut f = |d: f64| {
                *params.param_mut(i, j) = x0 + d;
                let l = lw.loss(&render_reference(&input!(&params, &colf, &extf, &bg), &cfg));
                *params.param_mut(i, j) = x0;
                l
            };
            ck.check(&what, analytic, &mut f);
        }
        if case.color_m != 0 {
            assert!(g.v_sh[i].iter().flatten().all(|&v| v == 0.0));
        }
    }
    if case.color_m != 0 {
        for k in 0..colf.len() {
            let x0 = colf[k];
            let a = g.v_color_features[k];
            ck.check(&format!("seed {} colour feature {k}", case.seed), a, |d| {
                colf[k] = x0 + d;
                let l = lw.loss(&render_reference(&input!(&params, &colf, &extf, &bg), &cfg));
                colf[k] = x0;
                l
            });
        }
    }
    for k in 0..extf.len() {
        let x0 = extf[k];
        let a = g.v_extra[k];
        ck.check(&format!("seed {} extra feature {k}", case.seed), a, |d| {
            extf[k] = x0 + d;
            let l = lw.loss(&render_reference(&input!(&params, &colf, &extf, &bg), &cfg));
            extf[k] = x0;
            l
        });
    }
    // Background: every value for a colour, a sample of pixels for an image.
    let bg_idx: Vec<usize> = if case.bg_image { (0..bg.len()).step_by(37).collect() } else { (0..3).collect() };
    for k in bg_idx {
        let x0 = bg[k];
        let a = g.v_background[k];
        ck.check(&format!("seed {} background {k}", case.seed), a, |d| {
            bg[k] = x0 + d;
            let l = lw.loss(&render_reference(&input!(&params, &colf, &extf, &bg), &cfg));
            bg[k] = x0;
            l
        });
    }
    (ck.checked, ck.skipped, ck.nonzero, ck.worst)
}

fn report(case: &Case) {
    let (checked, skipped, nonzero, worst) = run_case(case);
    eprintln!(
        "seed {} colour M={} extra {:?} uniform {}: {checked} gradients checked ({nonzero} non-negligible), {skipped} skipped at cut-offs, worst rel err {worst:.2e}",
        case.seed, case.color_m, case.extra, case.uniform
    );
    assert!(checked > 100);
    assert!(nonzero * 2 > checked, "most checked gradients should be non-negligible");
    assert!(skipped * 50 <= checked, "too many discontinuous parameters: {skipped}");
}

#[test]
fn gradients_sh_colour() {
    report(&Case { seed: 1, color_m: 0, extra: None, uniform: 0, bg_image: false });
    report(&Case { seed: 2, color_m: 0, extra: Some((4, 2)), uniform: 0, bg_image: true });
}

#[test]
fn gradients_colour_features_m1_m2() {
    report(&Case { seed: 3, color_m: 1, extra: Some((4, 2)), uniform: 0, bg_image: true });
    report(&Case { seed: 4, color_m: 2, extra: Some((6, 1)), uniform: 0, bg_image: false });
}

#[test]
fn gradients_colour_features_m4_m6() {
    report(&Case { seed: 5, color_m: 4, extra: Some((1, 3)), uniform: 0, bg_image: false });
    report(&Case { seed: 6, color_m: 6, extra: Some((2, 2)), uniform: 0, bg_image: true });
    // Interpolated colour without extra channels (its own specialised kernel).
    report(&Case { seed: 7, color_m: 4, extra: None, uniform: 0, bg_image: false });
    // Extra channels partly uniform over the vertices (stage 2's SH colour in the PBR pass).
    report(&Case { seed: 8, color_m: 4, extra: Some((4, 3)), uniform: 2, bg_image: true });
}

/// The f32 instantiation (what training runs) agrees with the f64 one.
#[test]
fn f32_backward_agrees_with_f64() {
    let (w, h) = (32u32, 32u32);
    let npx = (w * h) as usize;
    let cam = test_camera(w, h);
    let surfels = small_scene(9, 12);
    let lw = LossWeights::new(9, npx, 0);
    let cfg = RasterConfig::default();
    let input = RenderInput {
        surfels: &surfels,
        camera: &cam,
        colors: ColorSourceOf::Sh,
        extra: None,
        background: BackgroundOf::Color([0.3, 0.3, 0.3]),
    };
    let (out, st) = render(&input, &cfg);
    let f = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    let (gc, ga, gd, gn, gdist) = (f(&lw.color), f(&lw.alpha), f(&lw.depth), f(&lw.normal), f(&lw.distortion));
    let og = OutputGrads {
        color: Some(&gc),
        alpha: Some(&ga),
        depth: Some(&gd),
        normal: Some(&gn),
        distortion: Some(&gdist),
        extra: None,
    };
    let g32 = backward(&input, &cfg, &st, &out, &og);
    let p = P64::from_surfels(&surfels);
    let input64 = RenderInputOf {
        surfels: &p,
        camera: &cam,
        colors: ColorSourceOf::Sh,
        extra: None,
        background: BackgroundOf::Color([0.3, 0.3, 0.3]),
    };
    let (out64, st64) = render_generic(&input64, &cfg);
    let g64 = backward_generic(&input64, &cfg, &st64, &out64, &lw.grads());
    let rel = |a: &[f64], b: &[f64]| {
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
        max_diff(a, b) / scale
    };
    let pos32: Vec<f64> = g32.v_positions.iter().flat_map(|v| v.to_array()).map(|x| x as f64).collect();
    let pos64: Vec<f64> = g64.v_positions.iter().flat_map(|v| v.to_array()).collect();
    assert!(rel(&pos32, &pos64) < 1e-2, "positions {}", rel(&pos32, &pos64));
    let r32: Vec<f64> = g32.v_rotations.iter().flat_map(|v| v.to_array()).map(|x| x as f64).collect();
    let r64: Vec<f64> = g64.v_rotations.iter().flat_map(|v| v.to_array()).collect();
    assert!(rel(&r32, &r64) < 1e-2, "rotations {}", rel(&r32, &r64));
    let o32: Vec<f64> = g32.v_opacity_logits.iter().map(|&x| x as f64).collect();
    assert!(rel(&o32, &g64.v_opacity_logits) < 1e-2);
    let m32: Vec<f64> = g32.v_mean2d_norm.iter().map(|&x| x as f64).collect();
    assert!(rel(&m32, &g64.v_mean2d_norm) < 1e-2);
    assert!(g64.v_mean2d_norm.iter().any(|&v| v > 0.0));
}

/// With the distortion switched off, every other output and the gradients of a loss without a
/// distortion term are exactly those of the full render; the distortion output is 0.
#[test]
fn distortion_off_changes_nothing_else() {
    let (w, h) = (40u32, 36u32);
    let npx = (w * h) as usize;
    let cam = test_camera(w, h);
    let surfels = small_scene(4, 16);
    let lw = LossWeights::new(4, npx, 0);
    let p = P64::from_surfels(&surfels);
    let input = RenderInputOf {
        surfels: &p,
        camera: &cam,
        colors: ColorSourceOf::Sh,
        extra: None,
        background: BackgroundOf::Color([0.3, 0.6, 0.1]),
    };
    let on = RasterConfig::default();
    let off = RasterConfig { distortion: false, ..on };
    let (out_on, st_on) = render_generic(&input, &on);
    let (out_off, st_off) = render_generic(&input, &off);
    assert_eq!(out_on.color, out_off.color);
    assert_eq!(out_on.depth, out_off.depth);
    assert_eq!(out_on.normal, out_off.normal);
    assert_eq!(out_on.alpha, out_off.alpha);
    assert!(out_on.distortion.iter().any(|&d| d > 0.0));
    assert!(out_off.distortion.iter().all(|&d| d == 0.0));
    // No distortion gradient on one side; a (to be ignored) one on the other.
    let mut g_none = lw.grads();
    g_none.distortion = None;
    let a = backward_generic(&input, &on, &st_on, &out_on, &g_none);
    let b = backward_generic(&input, &off, &st_off, &out_off, &lw.grads());
    assert_eq!(a.v_positions, b.v_positions);
    assert_eq!(a.v_rotations, b.v_rotations);
    assert_eq!(a.v_log_scales, b.v_log_scales);
    assert_eq!(a.v_opacity_logits, b.v_opacity_logits);
    assert_eq!(a.v_sh, b.v_sh);
}

/// `sh_colors_backward` turns per-Gaussian colour gradients into the SH rows the SH render's own
/// backward gives: the colour gradients come from rendering the same colours as one-vertex
/// features (whose backward returns them per Gaussian), the rows from the SH render's backward.
#[test]
fn sh_colors_backward_gives_the_sh_renders_own_rows() {
    let (w, h) = (40u32, 36u32);
    let npx = (w * h) as usize;
    let cam = test_camera(w, h);
    let surfels = small_scene(7, 16);
    let lw = LossWeights::new(7, npx, 0);
    let gc: Vec<f32> = lw.color.iter().map(|&x| x as f32).collect();
    let cfg = RasterConfig { geometry_grads: false, ..RasterConfig::default() };
    let bg = BackgroundOf::Color([0.3, 0.6, 0.1]);
    let sh_input =
        RenderInput { surfels: &surfels, camera: &cam, colors: ColorSourceOf::Sh, extra: None, background: bg };
    let (sh_out, sh_st) = render(&sh_input, &cfg);
    let og = OutputGrads { color: Some(&gc), ..Default::default() };
    let want = backward(&sh_input, &cfg, &sh_st, &sh_out, &og).v_sh;

    let colours: Vec<f32> = sh_st.sh_colors().iter().flatten().copied().collect();
    let feat_input = RenderInput {
        colors: ColorSourceOf::Features(FeaturesOf { data: &colours, vertices: 1, channels: 3, uniform: 0 }),
        ..sh_input
    };
    let (feat_out, feat_st) = render(&feat_input, &cfg);
    assert_eq!(feat_out.color, sh_out.color, "the same colours composite to the same image");
    let per_gaussian = backward(&feat_input, &cfg, &feat_st, &feat_out, &og).v_color_features;
    let v_colors: Vec<[f32; 3]> = per_gaussian.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let got = svgir_raster::sh_colors_backward(&sh_input, &sh_st.projected(), &v_colors).expect("an SH render");

    let flat = |v: &[svgir_core::ShCoeffs]| v.iter().flat_map(|c| c.0.iter().flatten().map(|&x| x as f64)).collect();
    let (got, want): (Vec<f64>, Vec<f64>) = (flat(&got), flat(&want));
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(scale > 1e-3, "the loss reaches the SH rows");
    let nonzero = want.iter().filter(|v| v.abs() > 1e-6 * scale).count();
    assert!(nonzero > 16 * 3, "{nonzero} non-zero SH gradients");
    assert!(max_diff(&got, &want) <= 1e-5 * scale, "{} of {scale}", max_diff(&got, &want));
    // A clamped channel passes nothing, in both.
    let clamped = sh_st.sh_colors().iter().flatten().filter(|&&c| c == 0.0).count();
    assert!(clamped > 0, "the scene has clamped channels");

    assert!(matches!(
        svgir_raster::sh_colors_backward(&feat_input, &feat_st.projected(), &v_colors),
        Err(svgir_raster::RasterError::NotSh)
    ));
}

/// Uniform extra channels ([`FeaturesOf::uniform`]) render what interpolating the same value at
/// every vertex renders (the weights sum to one), and their gradients, all at vertex 0, are the
/// sums over the vertices of the interpolated table's; the other channels keep theirs. On every
/// path of this CPU, with frozen geometry as stage 2's PBR pass runs.
#[test]
fn uniform_channels_match_interpolating_a_constant() {
    let (w, h) = (48u32, 40u32);
    let npx = (w * h) as usize;
    let cam = test_camera(w, h);
    let surfels = small_scene(9, 24);
    let n = surfels.len();
    let (m, ce, un) = (4usize, 5usize, 2usize);
    let mut rng = Rng::new(9);
    let colf: Vec<f32> = random_vec(&mut rng, n * m * 3, 0.0, 1.0).iter().map(|&x| x as f32).collect();
    let mut extf: Vec<f32> = random_vec(&mut rng, n * m * ce, -1.0, 1.0).iter().map(|&x| x as f32).collect();
    for g in 0..n {
        for v in 1..m {
            for c in ce - un..ce {
                extf[(g * m + v) * ce + c] = extf[g * m * ce + c];
            }
        }
    }
    let lw = LossWeights::new(9, npx, ce);
    let to32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    let (gc, ga, ge) = (to32(&lw.color), to32(&lw.alpha), to32(&lw.extra));
    let og = OutputGrads { color: Some(&gc), alpha: Some(&ga), extra: Some(&ge), ..Default::default() };
    for simd in svgir_raster::simd::Simd::available() {
        let cfg = RasterConfig { geometry_grads: false, simd, ..RasterConfig::default() };
        let run = |uniform: usize| {
            let input = RenderInput {
                surfels: &surfels,
                camera: &cam,
                colors: ColorSourceOf::Features(FeaturesOf { data: &colf, vertices: m, channels: 3, uniform: 0 }),
                extra: Some(FeaturesOf { data: &extf, vertices: m, channels: ce, uniform }),
                background: BackgroundOf::Color([0.3, 0.6, 0.1]),
            };
            let (out, st) = render(&input, &cfg);
            let g = backward(&input, &cfg, &st, &out, &og);
            (out, g)
        };
        let ((out_l, g_l), (out_u, g_u)) = (run(0), run(un));
        let name = simd.name();
        assert_eq!(out_u.color, out_l.color, "{name}: the colours do not change");
        let f = |v: &[f32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<f64>>();
        assert!(max_diff(&f(&out_u.extra), &f(&out_l.extra)) <= 1e-5, "{name}: the extra image");
        let scale = g_l.v_extra.iter().fold(0.0f32, |a, v| a.max(v.abs()));
        assert!(scale > 1e-3, "{name}: the loss reaches the extra table");
        for g in 0..n {
            for c in 0..ce {
                let at = |gr: &[f32], v: usize| gr[(g * m + v) * ce + c];
                if c < ce - un {
                    for v in 0..m {
                        let (a, b) = (at(&g_u.v_extra, v), at(&g_l.v_extra, v));
                        assert!((a - b).abs() <= 1e-5 * scale, "{name}: Gaussian {g} vertex {v} channel {c}");
                    }
                } else {
                    let sum: f32 = (0..m).map(|v| at(&g_l.v_extra, v)).sum();
                    let got = at(&g_u.v_extra, 0);
                    assert!((got - sum).abs() <= 1e-5 * scale, "{name}: Gaussian {g} channel {c}: {got} vs {sum}");
                    assert!((1..m).all(|v| at(&g_u.v_extra, v) == 0.0), "{name}: Gaussian {g} channel {c}");
                }
            }
        }
        let diff = max_diff(&f(&g_u.v_opacity_logits), &f(&g_l.v_opacity_logits));
        assert!(diff <= 1e-5 * f64::from(scale.max(1.0)), "{name}: opacity gradients differ by {diff}");
    }
}

/// A feature table with more uniform channels than channels, or colours with any, is refused.
#[test]
fn uniform_channels_are_checked() {
    let cam = test_camera(8, 8);
    let surfels = small_scene(3, 2);
    let n = surfels.len();
    let (c, e) = (vec![0.5f32; n * 4 * 3], vec![0.5f32; n * 4 * 2]);
    let colors = ColorSourceOf::Features(FeaturesOf { data: &c, vertices: 4, channels: 3, uniform: 0 });
    let base =
        RenderInput { surfels: &surfels, camera: &cam, colors, extra: None, background: BackgroundOf::Color([0.0; 3]) };
    let cfg = RasterConfig::default();
    let extra = |uniform| Some(FeaturesOf { data: &e, vertices: 4, channels: 2, uniform });
    assert!(svgir_raster::check_input(&RenderInput { extra: extra(2), ..base }, &cfg).is_ok());
    assert!(matches!(
        svgir_raster::check_input(&RenderInput { extra: extra(3), ..base }, &cfg),
        Err(svgir_raster::RasterError::Uniform { uniform: 3, channels: 2, .. })
    ));
    let colors = ColorSourceOf::Features(FeaturesOf { data: &c, vertices: 4, channels: 3, uniform: 1 });
    assert!(matches!(
        svgir_raster::check_input(&RenderInput { colors, ..base }, &cfg),
        Err(svgir_raster::RasterError::Uniform { uniform: 1, .. })
    ));
}
