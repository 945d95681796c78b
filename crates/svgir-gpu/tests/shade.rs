//! The GPU vertex shading against the CPU's scalar kernel (svgir_pbr::shade, itself checked
//! against f64), on lavapipe in CI: colour, direct and indirect parts vertex by vertex, over
//! vertex counts, K, indirect modes, the visibility switch, clamps, layered diffuse,
//! directional lights, interleaved subsets, two sides and batches; and the same refusals.

mod common;

use glam::Vec3;
use svgir_core::{EnvMap, Rng};
use svgir_gpu::GpuShader;
use svgir_pbr::fixtures::{synthetic_materials, synthetic_microbuffer, synthetic_positions};
use svgir_pbr::{negated, shade_sides_into, EnvLight, Indirect, ShadeInputs, ShadeOutput, ShadeParams, Side};
use svgir_shading::Diffuse;
use svgir_trace::{brightest_texels, BrightLights, MicroBuffer, VertexMaterials};

struct Case {
    mb: MicroBuffer,
    back_mb: MicroBuffer,
    positions: Vec<Vec3>,
    front: Vec<bool>,
    back: Vec<bool>,
    env: EnvMap,
    given: Vec<[f32; 3]>,
    albedo: Vec<f32>,
    rough: Vec<f32>,
    normals: Vec<f32>,
    lights: Option<BrightLights>,
    back_lights: Option<BrightLights>,
}

/// The shipped fixtures' random micro-buffers, materials and map; `lights` of the map's
/// brightest texels with random visibility; a seventh of the Gaussians unseen and, for two
/// sides, a third of the rest shaded from behind.
fn case(n: usize, m: usize, k: usize, lights: usize, two_sided: bool, seed: u64) -> Case {
    let mb = synthetic_microbuffer(n, k, seed);
    let mut back_mb = synthetic_microbuffer(n, k, seed + 100);
    back_mb.normals = mb.normals.iter().map(|n| -*n).collect();
    let positions = synthetic_positions(&mb, seed);
    let env = EnvLight::new(8, seed).unwrap().radiance();
    let act = synthetic_materials(n, m, seed).activated(&mb.normals).unwrap();
    let mut rng = Rng::new(seed + 1);
    let given = (0..n * k).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
    let mut random_lights = || {
        (lights > 0).then(|| {
            let texels = brightest_texels(&env, lights);
            let cols: Vec<Vec<f32>> = texels
                .iter()
                .map(|_| (0..n).map(|_| if rng.uniform() < 0.25 { 0.0 } else { rng.range(0.3, 1.0) }).collect())
                .collect();
            BrightLights::from_visibility(&env, &texels, &cols).unwrap()
        })
    };
    let (lights, back_lights) = (random_lights(), random_lights());
    let seen: Vec<bool> = (0..n).map(|i| i % 7 != 3).collect();
    let behind: Vec<bool> = (0..n).map(|i| two_sided && i % 3 == 1).collect();
    Case {
        front: seen.iter().zip(&behind).map(|(s, b)| *s && !b).collect(),
        back: seen.iter().zip(&behind).map(|(s, b)| *s && *b).collect(),
        given,
        albedo: act.albedo.clone(),
        rough: act.roughness.clone(),
        normals: act.normals.clone(),
        lights,
        back_lights,
        positions,
        env,
        mb,
        back_mb,
    }
}

#[derive(Clone, Copy, Debug)]
enum Mode {
    Off,
    Traced,
    Given,
}

/// One side's inputs in F.
#[allow(clippy::too_many_arguments)]
fn inputs<'a, F>(
    c: &'a Case,
    mb: &'a MicroBuffer,
    visible: &'a [bool],
    mats: VertexMaterials<'a, F>,
    env: &'a [[F; 3]],
    mode: Mode,
    rho: F,
    params: ShadeParams,
    lights: Option<&'a BrightLights>,
) -> ShadeInputs<'a, F> {
    ShadeInputs {
        mb,
        positions: &c.positions,
        camera_center: Vec3::new(0.3, -2.5, 1.2),
        visible,
        mats,
        env_geom: &c.env,
        env,
        indirect: match mode {
            Mode::Off => Indirect::Off,
            Mode::Traced => Indirect::Traced { rho },
            Mode::Given => Indirect::Given(&c.given),
        },
        params,
        lights,
    }
}

#[test]
fn gpu_shading_matches_the_cpu_vertex_by_vertex() {
    let Some(gpu) = common::gpu() else { return };
    let mut shader = GpuShader::new(gpu);
    let configs = [
        // (N, M, K, lights, mode, visibility, env_max, diffuse, two-sided, interleave, batch bytes)
        (300usize, 4usize, 64usize, 0usize, Mode::Traced, true, 64.0f32, Diffuse::Added, false, 1usize, 0u64),
        (300, 6, 37, 8, Mode::Given, true, f32::INFINITY, Diffuse::Layered, false, 1, 0),
        (300, 1, 16, 0, Mode::Off, false, 1.5, Diffuse::Added, false, 1, 0),
        (300, 2, 64, 8, Mode::Traced, false, 64.0, Diffuse::Layered, true, 4, 0),
        (500, 4, 64, 4, Mode::Given, true, 64.0, Diffuse::Added, true, 1, 40 * 64 * 28),
    ];
    let mut worst = 0.0f32;
    for (ci, &(n, m, k, lights, mode, visibility, env_max, diffuse, two_sided, stride, batch)) in
        configs.iter().enumerate()
    {
        let mut c = case(n, m, k, lights, two_sided, 40 + ci as u64);
        if stride > 1 {
            c.mb = c.mb.interleaved(stride, 1).unwrap();
            c.back_mb = c.back_mb.interleaved(stride, 2).unwrap();
            c.given.truncate(n * c.mb.k);
        }
        shader.batch_bytes = if batch > 0 { batch } else { svgir_gpu::shade::BATCH_BYTES };
        let params = ShadeParams { visibility, env_max, diffuse, simd: svgir_core::simd::Simd::Scalar };
        let back_normals = negated(&c.normals);
        let mats32 = VertexMaterials { m, albedo: &c.albedo[..], roughness: &c.rough[..], normals: &c.normals[..] };
        let back32 = VertexMaterials { normals: &back_normals[..], ..mats32 };
        let side = |mb, visible, mats, lights| Side {
            inputs: inputs(&c, mb, visible, mats, &c.env.data, mode, 0.7f32, params, lights),
            cache: None,
        };
        let front = side(&c.mb, &c.front[..], mats32, c.lights.as_ref());
        let back = two_sided.then(|| side(&c.back_mb, &c.back[..], back32, c.back_lights.as_ref()));
        let mut cpu = ShadeOutput::new();
        shade_sides_into(&front, back.as_ref(), &mut cpu).unwrap();
        let mut gpu = ShadeOutput::new();
        shader.shade(&front, back.as_ref(), &mut gpu).unwrap();
        let mut gpu_colour = ShadeOutput::colour_only();
        shader.shade(&front, back.as_ref(), &mut gpu_colour).unwrap();
        assert!(gpu_colour.direct.is_empty() && gpu_colour.indirect.is_empty(), "config {ci}");
        assert_eq!(gpu_colour.color, gpu.color, "config {ci}: colour alone vs split");

        // Against the CPU's scalar kernel, vertex by vertex (relative to max(|c|, 1)). The two
        // round each direction differently (the driver fuses multiply-adds), and at a vertex of
        // low roughness a direction near its mirror direction meets GGX's peak, where
        // q = 1 - (n.h)^2 (1 - a^2) cancels: there 1 ulp of direction is 1e-4 of the colour.
        // So: every vertex within 5e-4 (seen: 1.7e-4), at most 1% of the Gaussians with a vertex
        // past 2e-5, and each such vertex of roughness under 0.3.
        let parts = [(&gpu.color, &cpu.color), (&gpu.direct, &cpu.direct), (&gpu.indirect, &cpu.indirect)];
        let mut outliers = std::collections::BTreeSet::new();
        for (name, (g, cp)) in ["colour", "direct", "indirect"].iter().zip(parts) {
            for (i, (&a, &b)) in g.iter().zip(cp.iter()).enumerate() {
                let e = (a - b).abs() / b.abs().max(1.0);
                worst = worst.max(e);
                assert!(e <= 5e-4, "config {ci} {name} {i}: GPU {a}, CPU {b}");
                if e > 2e-5 {
                    let vertex = i / 3;
                    assert!(
                        c.rough[vertex] < 0.3,
                        "config {ci} {name} {i}: GPU {a}, CPU {b} at roughness {}",
                        c.rough[vertex]
                    );
                    outliers.insert(vertex / m);
                }
            }
        }
        eprintln!("config {ci}: {} of {n} Gaussians past 2e-5", outliers.len());

        // The backward against the CPU's, for an upstream gradient with zeros (Gaussians no
        // pixel saw). Each gradient within a bound of its largest entry, about 2.5x the largest
        // difference seen (the same ill-conditioned GGX peaks move roughness and normal entries
        // most: 3.7e-4; albedo 2e-7, env 1.3e-4, rho 3e-6).
        let mut rng = Rng::new(ci as u64 + 5);
        let v_color: Vec<f32> =
            (0..n * m * 3).map(|i| if (i / (m * 3)) % 5 == 2 { 0.0 } else { rng.normal() }).collect();
        let want = svgir_pbr::shade_sides_backward(&front, back.as_ref(), &v_color).unwrap();
        let texels = c.env.data.len();
        let clamped = c.env.data.iter().flatten().filter(|&&x| x > env_max).count();
        eprintln!("config {ci}: {clamped} of {} texel channels over the clamp", texels * 3);
        let mut got = svgir_pbr::PbrGrads::zeros(n, m, c.env.data.len());
        shader.backward(&front, back.as_ref(), &v_color, &mut got).unwrap();
        let env = |g: &svgir_pbr::PbrGrads| g.v_env.iter().flatten().copied().collect::<Vec<f32>>();
        for (name, g, w, bound) in [
            ("v_albedo", got.v_albedo.clone(), want.v_albedo.clone(), 5e-7),
            ("v_roughness", got.v_roughness.clone(), want.v_roughness.clone(), 1e-3),
            ("v_normals", got.v_normals.clone(), want.v_normals.clone(), 1e-3),
            ("v_env", env(&got), env(&want), 3e-4),
            ("v_rho", vec![got.v_rho], vec![want.v_rho], 1e-5),
        ] {
            let scale = w.iter().fold(0.0f32, |a, x| a.max(x.abs()));
            let diff = g.iter().zip(&w).fold(0.0f32, |a, (x, y)| a.max((x - y).abs()));
            eprintln!("config {ci} {name}: largest difference {:.2e} of the largest entry", diff / scale.max(1e-30));
            // rho has a gradient only through traced light.
            let zero_ok = name == "v_rho" && !matches!(mode, Mode::Traced);
            assert!((scale > 0.0 || zero_ok) && diff <= bound * scale, "config {ci} {name}: {diff:.3e} of {scale:.3e}");
        }
        assert!(outliers.len() * 100 <= n, "config {ci}: {} of {n} Gaussians past 2e-5", outliers.len());
        // What neither side shades stays zero, and something was shaded.
        for i in 0..n {
            let px = &gpu.color[i * m * 3..(i + 1) * m * 3];
            if !c.front[i] && !c.back[i] {
                assert!(px.iter().all(|&x| x == 0.0), "config {ci}: unseen Gaussian {i} shaded");
            }
        }
        assert!(gpu.color.iter().filter(|&&x| x > 0.0).count() > n * m, "config {ci}: too little light");
    }
    eprintln!("worst GPU difference from the CPU: {worst:.2e}");
}

#[test]
fn gpu_shading_refuses_what_the_cpu_refuses() {
    let Some(gpu) = common::gpu() else { return };
    let shader = GpuShader::new(gpu);
    let (n, m, k) = (40, 4, 16);
    let c = case(n, m, k, 0, true, 9);
    let mats = VertexMaterials { m, albedo: &c.albedo[..], roughness: &c.rough[..], normals: &c.normals[..] };
    let p = ShadeParams::default();
    let front = Side { inputs: inputs(&c, &c.mb, &c.front, mats, &c.env.data, Mode::Off, 1.0, p, None), cache: None };
    // A Gaussian on both sides, a short visible list, a bad clamp: the CPU's errors, word for word.
    let all = vec![true; n];
    let both = Side { inputs: ShadeInputs { visible: &all, ..front.inputs }, cache: None };
    let short = Side { inputs: ShadeInputs { visible: &all[1..], ..front.inputs }, cache: None };
    let bad = Side { inputs: ShadeInputs { params: ShadeParams { env_max: -1.0, ..p }, ..front.inputs }, cache: None };
    for (what, f, b) in [("both sides", &front, Some(&both)), ("short", &short, None), ("clamp", &bad, None)] {
        let cpu = shade_sides_into(f, b, &mut ShadeOutput::new()).expect_err(what).to_string();
        let gpu = shader.shade(f, b, &mut ShadeOutput::new()).expect_err(what).to_string();
        assert_eq!(gpu, cpu, "{what}");
    }
    // Nothing visible: all zero, no dispatch needed.
    let none = vec![false; n];
    let empty = Side { inputs: ShadeInputs { visible: &none, ..front.inputs }, cache: None };
    let mut out = ShadeOutput::new();
    shader.shade(&empty, None, &mut out).unwrap();
    assert!(out.color.len() == n * m * 3 && out.color.iter().all(|&x| x == 0.0));
}

/// The samples the shader keeps on the GPU across calls (`resident.rs`) shade exactly as the
/// ones each call uploads: forward and backward, bit for bit, over several chunks and both
/// sides; a new micro-buffer, and one changed in place, are shaded with their own samples.
#[test]
fn kept_samples_shade_as_uploaded_ones() {
    let Some(gpu) = common::gpu() else { return };
    let mut kept = GpuShader::new(gpu.clone());
    let mut uploaded = GpuShader::new(gpu).keep_samples(0);
    // 40 Gaussians' samples a chunk: 13 chunks a side.
    kept.batch_bytes = 40 * 64 * 16;
    uploaded.batch_bytes = kept.batch_bytes;
    let (n, m) = (500, 4);
    let mut c = case(n, m, 64, 4, true, 77);
    let params = ShadeParams {
        visibility: true,
        env_max: 64.0,
        diffuse: Diffuse::Layered,
        simd: svgir_core::simd::Simd::Scalar,
    };
    let v_color: Vec<f32> = {
        let mut rng = Rng::new(3);
        (0..n * m * 3).map(|_| rng.normal()).collect()
    };
    // Colour, then the backward's gradients, of both shaders on the case as it is now.
    let run = |c: &Case, shader: &GpuShader| {
        let back_normals = negated(&c.normals);
        let mats = VertexMaterials { m, albedo: &c.albedo[..], roughness: &c.rough[..], normals: &c.normals[..] };
        let back_mats = VertexMaterials { normals: &back_normals[..], ..mats };
        let side = |mb, visible, mats, lights| Side {
            inputs: inputs(c, mb, visible, mats, &c.env.data, Mode::Traced, 0.7f32, params, lights),
            cache: None,
        };
        let front = side(&c.mb, &c.front[..], mats, c.lights.as_ref());
        let back = side(&c.back_mb, &c.back[..], back_mats, c.back_lights.as_ref());
        let mut out = ShadeOutput::new();
        shader.shade(&front, Some(&back), &mut out).unwrap();
        let mut g = svgir_pbr::PbrGrads::zeros(n, m, c.env.data.len());
        shader.backward(&front, Some(&back), &v_color, &mut g).unwrap();
        (out.color, out.direct, out.indirect, g.v_albedo, g.v_roughness, g.v_normals, g.v_env, g.v_rho)
    };
    let want = run(&c, &uploaded);
    assert_eq!(uploaded.kept_samples().0, 0);
    assert!(run(&c, &kept) == want, "first call (uploads and keeps)");
    assert_eq!(kept.kept_samples(), (2, 2 * (n * 64 * 16) as u64));
    assert!(run(&c, &kept) == want, "second call (kept samples)");
    // A new trace.
    c.mb = synthetic_microbuffer(n, 64, 78);
    let want_new = run(&c, &uploaded);
    assert!(want_new != want);
    assert!(run(&c, &kept) == want_new, "a new micro-buffer");
    // The same allocation changed in place: every sample's visibility halved.
    c.mb.vis.iter_mut().for_each(|v| *v /= 2);
    let want_halved = run(&c, &uploaded);
    assert!(want_halved != want_new);
    assert!(run(&c, &kept) == want_halved, "a micro-buffer changed in place");
}
