//! The GPU feature raster (stage 2's PBR pass) against svgir-raster's scalar kernels (the
//! oracle), as raster.rs checks the stage-1 rasterizer: per vertex count (M = 1, 2, 4, 6), with
//! extra channels (some uniform, as stage 2's pass carries the SH colour) and without, the
//! colour and extra images within 1e-5, alpha and depth bit for bit the stage-1 kernel's, and
//! the gradients (opacity logits, colour and extra tables, background,
//! composited weights) within 1e-3 relative; and the inputs it refuses, with errors.

use svgir_core::{Camera, Rng, Surfels};
use svgir_gpu::{GpuFeatureRaster, GpuRaster};

mod common;
use common::gpu;
use common::oracle::{camera, check_grads, close, cpu_cfg, near_cuts, scene};
use svgir_raster::{
    Background, BackgroundOf, ColorSource, ColorSourceOf, Features, FeaturesOf, OutputGrads, OutputGradsOf,
    RasterConfig, RasterError, RenderInput, RenderInputOf,
};

/// Stage 2's settings: no normals or distortion, frozen geometry.
fn pass_cfg() -> RasterConfig {
    RasterConfig { normals: false, distortion: false, geometry_grads: false, ..cpu_cfg() }
}

/// Random tables for `s`: colours (3 a vertex) and `ce` extra channels, `uniform` of them one
/// value a Gaussian.
fn tables(s: &Surfels, m: usize, ce: usize, seed: u64) -> (Vec<f32>, Vec<f32>) {
    let mut rng = Rng::new(seed);
    let n = s.len();
    let colours = (0..n * m * 3).map(|_| rng.uniform()).collect();
    let extra = (0..n * m * ce).map(|_| 2.0 * rng.uniform() - 1.0).collect();
    (colours, extra)
}

fn to64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

struct Case<'a> {
    s: &'a Surfels,
    cam: &'a Camera,
    m: usize,
    ce: usize,
    uniform: usize,
    colours: &'a [f32],
    extra: &'a [f32],
    bg: [f32; 3],
}

impl<'a> Case<'a> {
    fn input(&self) -> RenderInput<'a> {
        RenderInput {
            surfels: self.s,
            camera: self.cam,
            colors: ColorSource::Features(Features { data: self.colours, vertices: self.m, channels: 3, uniform: 0 }),
            extra: (self.ce > 0).then_some(Features {
                data: self.extra,
                vertices: self.m,
                channels: self.ce,
                uniform: self.uniform,
            }),
            background: Background::Color(self.bg),
        }
    }
}

/// The render and its backward for one case on the GPU, the CPU's scalar kernels and in f64.
fn check(g: &svgir_gpu::Gpu, r: &GpuFeatureRaster, r1: &GpuRaster, c: &Case, seed: u64) {
    let cfg = pass_cfg();
    let input = c.input();
    let (c64, e64) = (to64(c.colours), to64(c.extra));
    let input64 = RenderInputOf::<f64, Surfels> {
        surfels: c.s,
        camera: c.cam,
        colors: ColorSourceOf::Features(FeaturesOf { data: &c64, vertices: c.m, channels: 3, uniform: 0 }),
        extra: (c.ce > 0).then_some(FeaturesOf { data: &e64, vertices: c.m, channels: c.ce, uniform: c.uniform }),
        background: BackgroundOf::Color(c.bg.map(f64::from)),
    };
    let (cpu, state) = svgir_raster::render(&input, &cfg);
    let (exact, state64) = svgir_raster::render_generic::<f64, Surfels>(&input64, &cfg);
    let (out, fwd) = r.render(&input, &cfg).unwrap();
    let what = format!("M = {}, {} extra ({} uniform)", c.m, c.ce, c.uniform);
    assert!(cpu.alpha.iter().filter(|&&a| a > 0.5).count() > 10, "{what}: the scene covers too few pixels");
    let cut = near_cuts(c.s, c.cam, &cfg);
    assert!(cut.iter().filter(|&&x| x).count() * 7 < cut.len(), "{what}: more than 15% of the pixels left out");
    // Interpolated values carry the hit's (u, v) too, whose rounding the devices' FMAs round
    // differently and the CPU's distance from f64 does not bound (it is that of the CPU's own
    // rounding): measured up to 1.3e-5 (M = 6), 1.0e-5 (M = 4, 16 channels); one vertex 2e-6.
    let tol = if c.m > 1 { 2e-5 } else { 1e-5 };
    close(&format!("{what}: colour"), &out.color, &cpu.color, &exact.color, &cut, tol);
    // The weights are the stage-1 kernel's (the same projection, binning and compositing
    // rules), which raster.rs checks against the CPU: the same bits.
    let (sh, _) = r1.render(g, c.s, c.cam, c.bg, &cfg).unwrap();
    assert_eq!(out.alpha, sh.alpha, "{what}: alpha differs from the stage-1 kernel's");
    assert_eq!(out.depth, sh.depth, "{what}: depth differs from the stage-1 kernel's");
    assert_eq!(out.median_depth, sh.median_depth, "{what}: median depth differs from the stage-1 kernel's");
    assert_eq!(out.max_radius, sh.max_radius, "{what}: radii differ from the stage-1 kernel's");
    assert_eq!(out.extra_channels, c.ce, "{what}: extra channels");
    if c.ce > 0 {
        close(&format!("{what}: extra"), &out.extra, &cpu.extra, &exact.extra, &cut, tol);
    }

    let npx = (c.cam.width() * c.cam.height()) as usize;
    let mut rng = Rng::new(seed);
    let mut v = |k: usize, amp: f32| (0..k).map(|_| amp * (2.0 * rng.uniform() - 1.0)).collect::<Vec<f32>>();
    let (gc, ga, gd, ge) = (v(npx * 3, 1.0), v(npx, 1.0), v(npx, 0.3), v(npx * c.ce, 1.0));
    let og = OutputGrads {
        color: Some(&gc),
        alpha: Some(&ga),
        depth: Some(&gd),
        extra: (c.ce > 0).then_some(&ge[..]),
        ..Default::default()
    };
    let (gc64, ga64, gd64, ge64) = (to64(&gc), to64(&ga), to64(&gd), to64(&ge));
    let og64 = OutputGradsOf::<f64> {
        color: Some(&gc64),
        alpha: Some(&ga64),
        depth: Some(&gd64),
        extra: (c.ce > 0).then_some(&ge64[..]),
        ..Default::default()
    };
    let want = svgir_raster::backward(&input, &cfg, &state, &cpu, &og);
    let exact_g = svgir_raster::backward_generic::<f64, Surfels>(&input64, &cfg, &state64, &exact, &og64);
    let got = r.backward(&fwd, &og).unwrap();
    let gg = &got.grads;
    // Composited on one device only, and then faintly: a splat on a cut-off at some pixel.
    let (wg, wc) = (&got.accum_weight, &cpu.accum_weight);
    let flipped: Vec<bool> = wg.iter().zip(wc).map(|(a, b)| (*a == 0.0) != (*b == 0.0) && a.max(*b) < 1e-2).collect();
    assert!(flipped.iter().filter(|&&f| f).count() * 50 <= c.s.len(), "{what}: over 2% composited on one device only");
    check_grads(
        &format!("{what}: opacity logits"),
        &gg.v_opacity_logits,
        &want.v_opacity_logits,
        &exact_g.v_opacity_logits,
        &flipped,
    );
    check_grads(
        &format!("{what}: colour table"),
        &gg.v_color_features,
        &want.v_color_features,
        &exact_g.v_color_features,
        &flipped,
    );
    if c.ce > 0 {
        check_grads(&format!("{what}: extra table"), &gg.v_extra, &want.v_extra, &exact_g.v_extra, &flipped);
    } else {
        assert!(gg.v_extra.is_empty(), "{what}: extra gradients without extra channels");
    }
    check_grads(&format!("{what}: background"), &gg.v_background, &want.v_background, &exact_g.v_background, &[false]);
    check_grads(
        &format!("{what}: composited weight"),
        &got.accum_weight,
        &cpu.accum_weight,
        &exact.accum_weight,
        &flipped,
    );
    assert!(gg.v_positions.iter().all(|p| *p == glam::Vec3::ZERO), "{what}: frozen positions have gradients");
    assert_eq!(gg.v_opacity_logits.len(), c.s.len());
}

#[test]
fn features_match_the_scalar_kernels_at_every_vertex_count() {
    let Some(g) = gpu() else { return };
    let (r, r1) = (GpuFeatureRaster::new(g.clone()), GpuRaster::new(&g));
    // Image sizes that cut tiles at both edges; stage 2's extra channels (10, 3 uniform).
    for (k, (m, ce, uniform)) in
        [(1usize, 10usize, 3usize), (2, 10, 3), (4, 10, 3), (6, 10, 3), (6, 0, 0), (4, 16, 0)].into_iter().enumerate()
    {
        let seed = 20 + k as u64;
        let (w, h) = if k % 2 == 0 { (37, 29) } else { (64, 48) };
        let cam = camera(w, h);
        let s = scene(seed, 250, &cam);
        let (colours, extra) = tables(&s, m, ce, seed);
        let c = Case { s: &s, cam: &cam, m, ce, uniform, colours: &colours, extra: &extra, bg: [0.2, 0.5, 0.9] };
        check(&g, &r, &r1, &c, seed);
    }
}

#[test]
fn inputs_the_kernels_cannot_take_are_errors() {
    let Some(g) = gpu() else { return };
    let r = GpuFeatureRaster::new(g.clone());
    let cam = camera(20, 16);
    let s = scene(7, 30, &cam);
    let (colours, extra) = tables(&s, 4, 17, 7);
    let ok = Case {
        s: &s,
        cam: &cam,
        m: 4,
        ce: 10,
        uniform: 3,
        colours: &colours,
        extra: &extra[..s.len() * 40],
        bg: [0.0; 3],
    };
    let base = ok.input();
    let err = |input: &RenderInput, cfg: &RasterConfig| {
        use svgir_raster::FeatureRaster;
        let prior =
            svgir_raster::try_project(&RenderInput { colors: ColorSource::Sh, extra: None, ..*input }, &pass_cfg())
                .unwrap();
        match FeatureRaster::render(&r, input, cfg, &prior) {
            Ok(_) => panic!("rendered an input it cannot take"),
            Err(e) => e,
        }
    };
    // What svgir-raster rejects, with its error.
    let short = Features { data: &colours[1..], vertices: 4, channels: 3, uniform: 0 };
    let bad = RenderInput { colors: ColorSource::Features(short), ..base };
    assert_eq!(err(&bad, &pass_cfg()), svgir_raster::check_input(&bad, &pass_cfg()).unwrap_err());
    // What the GPU kernels do not do.
    let device = |e: RasterError, has: &str| match e {
        RasterError::Device(m) => assert!(m.contains(has), "{m}"),
        e => panic!("expected a device refusal, got {e}"),
    };
    device(err(&base, &RasterConfig { normals: true, ..pass_cfg() }), "normals");
    device(err(&base, &RasterConfig { distortion: true, ..pass_cfg() }), "distortion");
    device(err(&RenderInput { colors: ColorSource::Sh, ..base }, &pass_cfg()), "SH");
    let img = vec![0.0; 20 * 16 * 3];
    device(err(&RenderInput { background: Background::Image(&img), ..base }, &pass_cfg()), "background");
    let two = Features { data: &extra[..s.len() * 20], vertices: 2, channels: 10, uniform: 0 };
    device(err(&RenderInput { extra: Some(two), ..base }, &pass_cfg()), "vertices");
    let wide = Features { data: &extra, vertices: 4, channels: 17, uniform: 0 };
    device(err(&RenderInput { extra: Some(wide), ..base }, &pass_cfg()), "at most 16");
    // And a backward given another backend's state.
    use svgir_raster::FeatureRaster;
    let prior =
        svgir_raster::try_project(&RenderInput { colors: ColorSource::Sh, extra: None, ..base }, &pass_cfg()).unwrap();
    let (out, state) = svgir_raster::CpuFeatureRaster.render(&base, &pass_cfg(), &prior).unwrap();
    let e = FeatureRaster::backward(&r, &base, &pass_cfg(), &state, &out, &OutputGrads::default()).unwrap_err();
    assert_eq!(e, RasterError::State);
}
