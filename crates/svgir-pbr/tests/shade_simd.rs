//! The AVX2 lane kernels of the vertex shading against the generic ones: in f32 both ways, and
//! both against the f64 oracle, forward (colour, direct, indirect) and backward (materials, env
//! texels, rho), over vertex counts, indirect modes, clamps, layered diffuse, directional
//! lights, and K not a multiple of the lane width.

use glam::Vec3;
use svgir_core::simd::Simd;
use svgir_core::{EnvMap, Rng};
use svgir_pbr::fixtures::{synthetic_materials, synthetic_microbuffer, synthetic_positions};
use svgir_pbr::{
    shade_backward_cached, shade_into_cached, DirectionCache, EnvLight, Indirect, PbrGrads, ShadeInputs, ShadeOutput,
    ShadeParams,
};
use svgir_shading::Diffuse;
use svgir_trace::{brightest_texels, BrightLights, MicroBuffer};

struct Case {
    mb: MicroBuffer,
    positions: Vec<Vec3>,
    visible: Vec<bool>,
    env: EnvMap,
    env64: Vec<[f64; 3]>,
    given: Vec<[f32; 3]>,
    albedo: Vec<f32>,
    rough: Vec<f32>,
    normals: Vec<f32>,
    lights: Option<BrightLights>,
    v_color: Vec<f32>,
}

fn case(n: usize, m: usize, k: usize, lights: usize, seed: u64) -> Case {
    let mb = synthetic_microbuffer(n, k, seed);
    let positions = synthetic_positions(&mb, seed);
    let env = EnvLight::new(8, seed).unwrap().radiance();
    let act = synthetic_materials(n, m, seed).activated(&mb.normals).unwrap();
    let mut rng = Rng::new(seed + 1);
    let given: Vec<[f32; 3]> = (0..n * k).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
    let lights = (lights > 0).then(|| {
        let texels = brightest_texels(&env, lights);
        let cols: Vec<Vec<f32>> = texels
            .iter()
            .map(|_| (0..n).map(|_| if rng.uniform() < 0.25 { 0.0 } else { rng.range(0.3, 1.0) }).collect())
            .collect();
        BrightLights::from_visibility(&env, &texels, &cols).unwrap()
    });
    Case {
        visible: (0..n).map(|i| i % 7 != 3).collect(),
        env64: env.data.iter().map(|t| t.map(f64::from)).collect(),
        given,
        albedo: act.albedo.clone(),
        rough: act.roughness.clone(),
        normals: act.normals.clone(),
        v_color: (0..n * m * 3).map(|i| if i % 11 == 5 { 0.0 } else { rng.normal() }).collect(),
        lights,
        positions,
        env,
        mb,
    }
}

#[derive(Clone, Copy, Debug)]
enum Mode {
    Off,
    Traced,
    Given,
}

#[allow(clippy::too_many_arguments)]
fn inputs<'a, F>(
    c: &'a Case,
    m: usize,
    mats: (&'a [F], &'a [F], &'a [F]),
    env: &'a [[F; 3]],
    given: &'a [[f32; 3]],
    mode: Mode,
    rho: F,
    params: ShadeParams,
) -> ShadeInputs<'a, F> {
    ShadeInputs {
        mb: &c.mb,
        positions: &c.positions,
        camera_center: Vec3::new(0.3, -2.5, 1.2),
        visible: &c.visible,
        mats: svgir_trace::VertexMaterials { m, albedo: mats.0, roughness: mats.1, normals: mats.2 },
        env_geom: &c.env,
        env,
        indirect: match mode {
            Mode::Off => Indirect::Off,
            Mode::Traced => Indirect::Traced { rho },
            Mode::Given => Indirect::Given(given),
        },
        params,
        lights: c.lights.as_ref(),
    }
}

/// Largest |a - b| over the largest |b| (0 when both are all zero).
fn rel_err(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f64, |s, x| s.max(x.abs()));
    let diff = a.iter().zip(b).fold(0.0f64, |s, (x, y)| s.max((x - y).abs()));
    if scale == 0.0 {
        diff
    } else {
        diff / scale
    }
}

fn grads_flat<F: Copy + Into<f64>>(g: &PbrGrads<F>) -> [Vec<f64>; 4] {
    let f = |v: &[F]| v.iter().map(|&x| x.into()).collect::<Vec<f64>>();
    let env: Vec<f64> = g.v_env.iter().flat_map(|t| t.map(|x| x.into())).collect();
    let mut env_rho = env;
    env_rho.push(g.v_rho.into());
    [f(&g.v_albedo), f(&g.v_roughness), f(&g.v_normals), env_rho]
}

#[test]
fn lane_kernels_match_the_scalar_ones_and_f64() {
    if svgir_core::simd::best_available() == Simd::Scalar {
        eprintln!("SKIPPED: this CPU has no AVX2, so the shading lane kernels cannot run here");
        return;
    }
    let configs = [
        // (M, K, lights, mode, visibility, env_max, diffuse)
        (4usize, 64usize, 0usize, Mode::Traced, true, 64.0f32, Diffuse::Layered),
        (4, 64, 4, Mode::Traced, true, 64.0, Diffuse::Layered),
        (1, 13, 0, Mode::Off, true, 64.0, Diffuse::Added),
        (2, 37, 3, Mode::Given, false, 64.0, Diffuse::Added),
        (6, 64, 2, Mode::Traced, true, 0.8, Diffuse::Layered),
        (4, 8, 0, Mode::Given, true, 64.0, Diffuse::Added),
        // Stage 2's gradient subsets: four directions, fewer than a lane block.
        (4, 4, 4, Mode::Traced, true, 64.0, Diffuse::Layered),
    ];
    let mut lane_differs = false;
    let mut checked_avx512 = false;
    for (ci, &(m, k, lights, mode, visibility, env_max, diffuse)) in configs.iter().enumerate() {
        let c = case(97, m, k, lights, 40 + ci as u64);
        let cache = DirectionCache::new(&c.mb, &c.env).unwrap();
        let p = |simd| ShadeParams { visibility, env_max, diffuse, simd };
        let mats32 = (&c.albedo[..], &c.rough[..], &c.normals[..]);
        let run32 = |simd| {
            let inp = inputs(&c, m, mats32, &c.env.data, &c.given, mode, 0.7f32, p(simd));
            let mut out = ShadeOutput::new();
            shade_into_cached(&inp, Some(&cache), &mut out).unwrap();
            let g = shade_backward_cached(&inp, Some(&cache), &c.v_color).unwrap();
            (out, g)
        };
        let (scalar, g_scalar) = run32(Simd::Scalar);
        let (lane, g_lane) = run32(Simd::Avx2);
        // The AVX-512 kernels are the AVX2 ones with mask registers: the same operations on the
        // same 8 lanes, so the same bits.
        if Simd::available().contains(&Simd::Avx512) {
            let (wide, g_wide) = run32(Simd::Avx512);
            assert_eq!(wide, lane, "config {ci}: AVX-512 forward vs AVX2");
            assert_eq!(g_wide, g_lane, "config {ci}: AVX-512 backward vs AVX2");
            checked_avx512 = true;
        }
        // The colour alone (`ShadeOutput::colour_only`): the scalar kernel gives its split colour
        // bit for bit, the lane kernel sums each sample's light first (rounding only), and the
        // parts stay empty.
        let colour_only = |simd| {
            let inp = inputs(&c, m, mats32, &c.env.data, &c.given, mode, 0.7f32, p(simd));
            let mut out = ShadeOutput::colour_only();
            shade_into_cached(&inp, Some(&cache), &mut out).unwrap();
            assert!(out.direct.is_empty() && out.indirect.is_empty(), "config {ci}");
            out.color
        };
        assert_eq!(colour_only(Simd::Scalar), scalar.color, "config {ci}: scalar colour-only");

        let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
        let summed = colour_only(Simd::Avx2);
        assert!(rel_err(&f(&summed), &f(&lane.color)) <= 5e-6, "config {ci}: lane colour-only vs split");
        let (a64, r64, n64) = (f(&c.albedo), f(&c.rough), f(&c.normals));
        let inp64 = inputs(&c, m, (&a64[..], &r64[..], &n64[..]), &c.env64, &c.given, mode, 0.7f64, p(Simd::Scalar));
        let mut oracle = ShadeOutput::new();
        shade_into_cached(&inp64, Some(&cache), &mut oracle).unwrap();
        let v64 = f(&c.v_color);
        let g_oracle = shade_backward_cached(&inp64, Some(&cache), &v64).unwrap();

        let outs = |o: &ShadeOutput<f32>| [f(&o.color), f(&o.direct), f(&o.indirect)];
        let want = [oracle.color.clone(), oracle.direct.clone(), oracle.indirect.clone()];
        for (name, ((s, l), w)) in
            ["colour", "direct", "indirect"].iter().zip(outs(&scalar).iter().zip(&outs(&lane)).zip(&want))
        {
            let (es, el) = (rel_err(s, w), rel_err(l, w));
            assert!(el <= 2e-6 + 4.0 * es, "config {ci} {name}: lane error {el:.2e}, scalar error {es:.2e}");
            assert!(rel_err(l, s) <= 5e-6, "config {ci} {name}: lane vs scalar {:.2e}", rel_err(l, s));
            lane_differs |= s != l;
        }
        let gs = grads_flat(&g_scalar);
        let gl = grads_flat(&g_lane);
        let go = grads_flat(&g_oracle);
        for (name, ((s, l), w)) in ["albedo", "roughness", "normal", "env+rho"].iter().zip(gs.iter().zip(&gl).zip(&go))
        {
            let (es, el) = (rel_err(s, w), rel_err(l, w));
            assert!(el <= 5e-6 + 4.0 * es, "config {ci} v_{name}: lane error {el:.2e}, scalar error {es:.2e}");
            lane_differs |= s != l;
        }
        // Gaussians the rasteriser did not see stay zero on both paths.
        for (i, vis) in c.visible.iter().enumerate() {
            if !vis {
                assert!(lane.color[i * m * 3..(i + 1) * m * 3].iter().all(|&x| x == 0.0), "config {ci} Gaussian {i}");
            }
        }
    }
    // The sums over directions are summed lane-wise, so somewhere the rounding differs: proof
    // that the lane kernels, not the scalar fallback, produced `lane`.
    assert!(lane_differs, "the lane path gave bit-identical results everywhere: did it run?");
    if !checked_avx512 {
        eprintln!("SKIPPED (part): this CPU has no AVX-512F+VL, so the AVX-512 shading kernels were not compared");
    }
}

#[test]
fn lane_backward_is_deterministic_across_thread_counts() {
    if svgir_core::simd::best_available() == Simd::Scalar {
        eprintln!("SKIPPED: this CPU has no AVX2, so the shading lane kernels cannot run here");
        return;
    }
    let c = case(3000, 4, 64, 2, 9);
    let cache = DirectionCache::new(&c.mb, &c.env).unwrap();
    let params = ShadeParams { simd: Simd::Avx2, ..ShadeParams::default() };
    let inp = inputs(&c, 4, (&c.albedo, &c.rough, &c.normals), &c.env.data, &c.given, Mode::Traced, 0.5f32, params);
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut out = ShadeOutput::new();
            shade_into_cached(&inp, Some(&cache), &mut out).unwrap();
            (out, shade_backward_cached(&inp, Some(&cache), &c.v_color).unwrap())
        })
    };
    let (o1, g1) = run(1);
    let (o2, g2) = run(2);
    assert_eq!(o1, o2);
    assert_eq!(g1, g2);
}
