//! Vertex shading: f64 finite-difference checks of every gradient (materials through their
//! activations, env parameters through softplus, rho), a naive f32 reference, the closed-form
//! Lambertian case, and thread-count determinism.

use glam::Vec3;
use svgir_core::{EnvMap, Rng};
use svgir_pbr::fixtures::{synthetic_materials, synthetic_microbuffer, synthetic_positions};
use svgir_pbr::{
    activate, activate_backward, env_radiance, env_radiance_backward, negated, shade, shade_backward,
    shade_backward_cached, shade_into_cached, shade_sides_backward, shade_sides_into, split_by_side, DirectionCache,
    EnvLight, Indirect, MaterialGrads, PbrGrads, ShadeInputs, ShadeOutput, ShadeParams, Side,
};
use svgir_shading::{ggx, Diffuse};
use svgir_trace::{brightest_texels, BrightLights, MicroBuffer, VertexMaterials};

#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Off,
    Traced,
    Given,
}

struct Case {
    mb: MicroBuffer,
    positions: Vec<Vec3>,
    visible: Vec<bool>,
    geom: EnvMap,
    given: Vec<[f32; 3]>,
    // f64 parameters
    albedo: Vec<f64>,
    rough: Vec<f64>,
    offset: Vec<f64>,
    env: Vec<[f64; 3]>,
    rho: f64,
    g: Vec<f64>,
    lights: Option<BrightLights>,
}

/// Directional lights at the `count` brightest texels of `geom`, with random visibility (a
/// quarter of the (Gaussian, light) pairs occluded).
fn random_lights(geom: &EnvMap, n: usize, count: usize, seed: u64) -> Option<BrightLights> {
    let mut rng = Rng::new(seed);
    let texels = brightest_texels(geom, count);
    let cols: Vec<Vec<f32>> = texels
        .iter()
        .map(|_| (0..n).map(|_| if rng.uniform() < 0.25 { 0.0 } else { rng.range(0.3, 1.0) }).collect())
        .collect();
    (count > 0).then(|| BrightLights::from_visibility(geom, &texels, &cols).unwrap())
}

fn case(n: usize, m: usize, k: usize, seed: u64) -> Case {
    let mb = synthetic_microbuffer(n, k, seed);
    let positions = synthetic_positions(&mb, seed);
    let mut rng = Rng::new(seed + 100);
    let visible = (0..n).map(|i| i != 1).collect();
    let light = EnvLight::new(4, seed).unwrap();
    let geom = light.radiance();
    let given = (0..n * k).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
    let mats = synthetic_materials(n, m, seed);
    let f = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
    Case {
        positions,
        visible,
        given,
        albedo: f(&mats.albedo_raw),
        rough: f(&mats.roughness_raw),
        offset: f(&mats.normal_offset).iter().map(|x| 2.0 * x).collect(),
        env: light.param.iter().map(|t| t.map(|x| x as f64)).collect(),
        rho: 0.7,
        g: (0..n * m * 3).map(|_| rng.normal() as f64).collect(),
        geom,
        mb,
        lights: None,
    }
}

fn field(c: &mut Case, p: usize, i: usize) -> &mut f64 {
    match p {
        0 => &mut c.albedo[i],
        1 => &mut c.rough[i],
        _ => &mut c.offset[i],
    }
}

/// `sum g . colour` in f64, from raw parameters.
fn loss(c: &Case, m: usize, mode: Mode, params: ShadeParams, env: &[[f64; 3]], rho: f64, raw: [&[f64]; 3]) -> f64 {
    let act = activate(m, raw[0], raw[1], raw[2], &c.mb.normals).unwrap();
    let rad = env_radiance(env);
    let out = shade(&inputs(c, &act.view(), mode, params, &rad, rho)).unwrap();
    out.color.iter().zip(&c.g).map(|(a, b)| a * b).sum()
}

fn inputs<'a>(
    c: &'a Case,
    mats: &VertexMaterials<'a, f64>,
    mode: Mode,
    params: ShadeParams,
    env: &'a [[f64; 3]],
    rho: f64,
) -> ShadeInputs<'a, f64> {
    ShadeInputs {
        mb: &c.mb,
        positions: &c.positions,
        camera_center: Vec3::ZERO,
        visible: &c.visible,
        mats: *mats,
        env_geom: &c.geom,
        env,
        indirect: match mode {
            Mode::Off => Indirect::Off,
            Mode::Traced => Indirect::Traced { rho },
            Mode::Given => Indirect::Given(&c.given),
        },
        params,
        lights: c.lights.as_ref(),
    }
}

/// Shading gradients chained through the activations to `c`'s raw material parameters.
fn raw_grads(c: &Case, m: usize, g: &PbrGrads<f64>) -> MaterialGrads<f64> {
    activate_backward(m, &c.albedo, &c.rough, &c.offset, &c.mb.normals, &g.v_albedo, &g.v_roughness, &g.v_normals)
        .unwrap()
}

#[test]
fn gradients_match_finite_differences_f64() {
    let configs = [
        (1usize, Mode::Traced, true, 64.0f32, 0usize, Diffuse::Added),
        (2, Mode::Off, true, 3.0, 0, Diffuse::Layered),
        (4, Mode::Traced, true, 3.0, 0, Diffuse::Added),
        (4, Mode::Given, false, 64.0, 0, Diffuse::Layered),
        (6, Mode::Traced, false, 3.5, 0, Diffuse::Added),
        (4, Mode::Traced, true, 3.0, 3, Diffuse::Layered),
        (2, Mode::Off, false, 64.0, 4, Diffuse::Added),
    ];
    for (ci, &(m, mode, visibility, env_max, lights, diffuse)) in configs.iter().enumerate() {
        let params = ShadeParams { visibility, env_max, diffuse, ..ShadeParams::default() };
        let mut c = case(5, m, 8, 10 + ci as u64);
        c.lights = random_lights(&c.geom, 5, lights, ci as u64);
        let act = activate(m, &c.albedo, &c.rough, &c.offset, &c.mb.normals).unwrap();
        let rad = env_radiance(&c.env);
        let grads = shade_backward(&inputs(&c, &act.view(), mode, params, &rad, c.rho), &c.g).unwrap();
        let raw_g = raw_grads(&c, m, &grads);
        let v_param = env_radiance_backward(&c.env, &grads.v_env);
        let h = 1e-6;
        let tag = format!("M={m} {mode:?} V={visibility} env_max={env_max} lights={lights}");
        let check = |what: &str, i: usize, fd: f64, an: f64| {
            assert!((fd - an).abs() <= 2e-7 * (1.0 + fd.abs()), "{tag} {what}[{i}]: fd {fd} vs analytic {an}");
        };
        let mut nonzero = [0usize; 5];
        for p in 0..3 {
            let n = [c.albedo.len(), c.rough.len(), c.offset.len()][p];
            for i in 0..n {
                let an = [&raw_g.v_albedo_raw, &raw_g.v_roughness_raw, &raw_g.v_normal_offset][p][i];
                let x = *field(&mut c, p, i);
                *field(&mut c, p, i) = x + h;
                let lp = loss(&c, m, mode, params, &c.env, c.rho, [&c.albedo, &c.rough, &c.offset]);
                *field(&mut c, p, i) = x - h;
                let lm = loss(&c, m, mode, params, &c.env, c.rho, [&c.albedo, &c.rough, &c.offset]);
                *field(&mut c, p, i) = x;
                check(["albedo_raw", "roughness_raw", "normal_offset"][p], i, (lp - lm) / (2.0 * h), an);
                nonzero[p] += (an != 0.0) as usize;
            }
        }
        let mut env = c.env.clone();
        for t in 0..env.len() {
            for ch in 0..3 {
                let x = env[t][ch];
                env[t][ch] = x + h;
                let lp = loss(&c, m, mode, params, &env, c.rho, [&c.albedo, &c.rough, &c.offset]);
                env[t][ch] = x - h;
                let lm = loss(&c, m, mode, params, &env, c.rho, [&c.albedo, &c.rough, &c.offset]);
                env[t][ch] = x;
                check("env_param", t * 3 + ch, (lp - lm) / (2.0 * h), v_param[t][ch]);
                nonzero[3] += (v_param[t][ch] != 0.0) as usize;
            }
        }
        let lp = loss(&c, m, mode, params, &c.env, c.rho + h, [&c.albedo, &c.rough, &c.offset]);
        let lm = loss(&c, m, mode, params, &c.env, c.rho - h, [&c.albedo, &c.rough, &c.offset]);
        check("rho", 0, (lp - lm) / (2.0 * h), grads.v_rho);
        nonzero[4] = (grads.v_rho != 0.0) as usize;
        // The checks must have had something to check.
        assert!(nonzero[0] >= 4 * m * 3 && nonzero[1] >= 4 * m && nonzero[2] >= 4 * m * 3, "{tag}: {nonzero:?}");
        assert!(nonzero[3] > 20, "{tag}: env gradients {nonzero:?}");
        assert_eq!(nonzero[4], (mode == Mode::Traced) as usize, "{tag}");
        // The Gaussian not in `visible` is neither shaded nor given gradients.
        let out = shade(&inputs(&c, &act.view(), mode, params, &rad, c.rho)).unwrap();
        assert!(out.color[m * 3..2 * m * 3].iter().all(|&x| x == 0.0));
        assert!(grads.v_albedo[m * 3..2 * m * 3].iter().all(|&x| x == 0.0));
        assert!(out.color.iter().all(|x| x.is_finite()) && out.color.iter().any(|&x| x > 0.0));
        for i in 0..out.color.len() {
            assert!((out.direct[i] + out.indirect[i] - out.color[i]).abs() <= 1e-12 * (1.0 + out.color[i].abs()));
        }
        if mode == Mode::Off {
            assert!(out.indirect.iter().all(|&x| x == 0.0));
        }
    }
}

/// The kernel (factored diffuse, shared per-direction work) against the rendering equation
/// evaluated term by term with the public BRDF and `EnvMap::lookup`, in f32.
#[test]
fn matches_naive_rendering_equation_f32() {
    let (n, m, k) = (60usize, 4usize, 16usize);
    let mb = synthetic_microbuffer(n, k, 3);
    let positions = synthetic_positions(&mb, 3);
    let act = synthetic_materials(n, m, 3).activated(&mb.normals).unwrap();
    let env = EnvLight::new(8, 3).unwrap().radiance();
    let visible: Vec<bool> = (0..n).map(|i| i % 7 != 3).collect();
    let mut rng = Rng::new(5);
    let given: Vec<[f32; 3]> = (0..n * k).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
    let lit = random_lights(&env, n, 6, 9).unwrap();
    // The K-sample part sees the light texels as black.
    let mut sampled = env.clone();
    lit.texels.iter().for_each(|&t| sampled.data[t as usize] = [0.0; 3]);
    for (mode, visibility, env_max, with_lights, diffuse) in [
        (Mode::Traced, true, 64.0f32, false, Diffuse::Added),
        (Mode::Off, false, 64.0, false, Diffuse::Layered),
        (Mode::Given, true, 3.0, false, Diffuse::Added),
        (Mode::Traced, true, 3.0, true, Diffuse::Layered),
        (Mode::Off, false, 64.0, true, Diffuse::Added),
    ] {
        let rho = 0.8f32;
        let lights = with_lights.then_some(&lit);
        let inp = ShadeInputs {
            mb: &mb,
            positions: &positions,
            camera_center: Vec3::ZERO,
            visible: &visible,
            mats: act.view(),
            env_geom: &env,
            env: &env.data,
            indirect: match mode {
                Mode::Off => Indirect::Off,
                Mode::Traced => Indirect::Traced { rho },
                Mode::Given => Indirect::Given(&given),
            },
            params: ShadeParams { visibility, env_max, diffuse, ..ShadeParams::default() },
            lights,
        };
        let out = shade(&inp).unwrap();
        for i in 0..n {
            let wo = (-positions[i]).normalize();
            for mm in 0..m {
                let b = (i * m + mm) * 3;
                let nm = Vec3::new(act.normals[b], act.normals[b + 1], act.normals[b + 2]);
                let a = [act.albedo[b], act.albedo[b + 1], act.albedo[b + 2]];
                let mut want = [0.0f64; 3];
                for kk in 0..k {
                    let d = mb.direction(i, kk);
                    let v = if visibility { mb.visibility(i, kk) } else { 1.0 };
                    let le = if with_lights { &sampled } else { &env }.lookup(d).map(|x| x.clamp(0.0, env_max));
                    let ind = match mode {
                        Mode::Off => [0.0; 3],
                        Mode::Traced => mb.radiance(i, kk).map(|x| rho * x),
                        Mode::Given => given[i * k + kk],
                    };
                    let f = ggx(nm.to_array(), wo.to_array(), d.to_array(), a, act.roughness[i * m + mm], diffuse);
                    let cos = nm.dot(d).max(0.0);
                    for c in 0..3 {
                        want[c] += (f[c] * (v * le[c] + ind[c]) * cos) as f64 * std::f64::consts::TAU / k as f64;
                    }
                }
                // Directional lights: unclamped texel radiance times its solid angle.
                for (b, &t) in lights.iter().flat_map(|l| l.texels.iter().enumerate()) {
                    let d = lit.dirs[b];
                    let v = match visibility {
                        true => lit.visibility(i, b),
                        false => (mb.normals[i].dot(d) > 0.0) as u8 as f32,
                    };
                    let f = ggx(nm.to_array(), wo.to_array(), d.to_array(), a, act.roughness[i * m + mm], diffuse);
                    let cos = nm.dot(d).max(0.0);
                    for c in 0..3 {
                        want[c] += (f[c] * v * env.data[t as usize][c] * cos * lit.solid_angle[b]) as f64;
                    }
                }
                for c in 0..3 {
                    let got = out.color[b + c] as f64;
                    let want = if visible[i] { want[c] } else { 0.0 };
                    assert!(
                        (got - want).abs() <= 1e-4 * (1.0 + want.abs()),
                        "{mode:?} lights={with_lights} i={i} m={mm}: {got} vs {want}"
                    );
                }
            }
        }
    }
}

/// A white Lambertian vertex (diffuse part only: albedo 1, with the specular part removed by
/// subtracting an albedo-0 render) under a constant environment with V = 1 returns about the
/// environment radiance: 2pi/K sum_k cos_k / pi ~ 1. The Fibonacci set's 10-degree floor on the
/// elevation biases the estimate up by ~sin^2(10deg) = 3% at any K; we allow [0.98, 1.06].
#[test]
fn white_lambertian_under_constant_light_returns_the_light() {
    for &k in &[64usize, 384] {
        let n = 20;
        let mb = synthetic_microbuffer(n, k, 8);
        let positions = synthetic_positions(&mb, 8);
        let m = 1;
        let normals: Vec<f32> = mb.normals.iter().flat_map(|v| v.to_array()).collect();
        let rough = vec![0.7f32; n];
        let white = vec![1.0f32; n * 3];
        let black = vec![0.0f32; n * 3];
        let env = EnvMap::constant(16, 8, [2.0, 1.0, 0.5]);
        let visible = vec![true; n];
        let render = |albedo: &[f32]| {
            let inp = ShadeInputs {
                mb: &mb,
                positions: &positions,
                camera_center: Vec3::ZERO,
                visible: &visible,
                mats: VertexMaterials { m, albedo, roughness: &rough, normals: &normals },
                env_geom: &env,
                env: &env.data,
                indirect: Indirect::Off,
                params: ShadeParams { visibility: false, env_max: 64.0, ..ShadeParams::default() },
                lights: None,
            };
            shade(&inp).unwrap().color
        };
        let (w, b) = (render(&white), render(&black));
        for i in 0..n {
            for (c, want) in [2.0f32, 1.0, 0.5].into_iter().enumerate() {
                let ratio = (w[i * 3 + c] - b[i * 3 + c]) / want;
                assert!((0.98..1.06).contains(&ratio), "K={k} i={i} c={c}: diffuse/L = {ratio}");
            }
        }
    }
}

#[test]
fn backward_is_identical_for_any_thread_count_and_bad_input_errors() {
    let (n, m, k) = (2000usize, 4usize, 16usize);
    let mb = synthetic_microbuffer(n, k, 4);
    let positions = synthetic_positions(&mb, 4);
    let act = synthetic_materials(n, m, 4).activated(&mb.normals).unwrap();
    let env = EnvLight::new(8, 4).unwrap().radiance();
    let visible = vec![true; n];
    let inp = ShadeInputs {
        mb: &mb,
        positions: &positions,
        camera_center: Vec3::ZERO,
        visible: &visible,
        mats: act.view(),
        env_geom: &env,
        env: &env.data,
        indirect: Indirect::Traced { rho: 1.0 },
        params: ShadeParams::default(),
        lights: None,
    };
    let mut rng = Rng::new(1);
    let g: Vec<f32> = (0..n * m * 3).map(|_| rng.normal()).collect();
    let run = |t: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| (shade(&inp).unwrap(), shade_backward(&inp, &g).unwrap()))
    };
    let (f1, b1) = run(1);
    let (f3, b3) = run(3);
    assert_eq!(f1, f3);
    assert_eq!(b1, b3);
    assert!(b1.v_env.iter().flatten().any(|&x| x != 0.0) && b1.v_rho != 0.0);
    // Bad input is an error, not a panic.
    assert!(shade(&ShadeInputs { visible: &visible[1..], ..inp }).is_err());
    assert!(shade(&ShadeInputs { env: &env.data[1..], ..inp }).is_err());
    assert!(shade(&ShadeInputs { indirect: Indirect::Given(&[[0.0; 3]; 4]), ..inp }).is_err());
    assert!(shade_backward(&inp, &g[1..]).is_err());
}

/// The direction cache changes nothing: forward and backward are bit-identical to the uncached
/// path in every indirect mode, with and without visibility, in f32 and f64; a cache built for
/// another micro-buffer or map size is rejected.
#[test]
fn direction_cache_is_bit_identical_and_checked() {
    let (n, m, k) = (300usize, 2usize, 24usize);
    let c = case(n, m, k, 6);
    let cache = DirectionCache::new(&c.mb, &c.geom).unwrap();
    let act = synthetic_materials(n, m, 6).activated(&c.mb.normals).unwrap();
    let act64 = activate(m, &c.albedo, &c.rough, &c.offset, &c.mb.normals).unwrap();
    let env64 = env_radiance(&c.env);
    let mut rng = Rng::new(2);
    let g: Vec<f32> = (0..n * m * 3).map(|_| rng.normal()).collect();
    for mode in [Mode::Off, Mode::Traced, Mode::Given] {
        for params in [
            ShadeParams::default(),
            ShadeParams { visibility: false, env_max: 1.5, diffuse: Diffuse::Layered, ..ShadeParams::default() },
        ] {
            let inp = ShadeInputs {
                mb: &c.mb,
                positions: &c.positions,
                camera_center: Vec3::ZERO,
                visible: &c.visible,
                mats: act.view(),
                env_geom: &c.geom,
                env: &c.geom.data,
                indirect: match mode {
                    Mode::Off => Indirect::Off,
                    Mode::Traced => Indirect::Traced { rho: 0.6 },
                    Mode::Given => Indirect::Given(&c.given),
                },
                params,
                lights: None,
            };
            let mut out = ShadeOutput::new();
            shade_into_cached(&inp, Some(&cache), &mut out).unwrap();
            assert_eq!(out, shade(&inp).unwrap(), "{mode:?} {params:?}");
            let b = shade_backward_cached(&inp, Some(&cache), &g).unwrap();
            assert_eq!(b, shade_backward(&inp, &g).unwrap(), "{mode:?} {params:?}");
            assert!(b.v_env.iter().flatten().any(|&x| x != 0.0) || !params.visibility);
            let inp64 = inputs(&c, &act64.view(), mode, params, &env64, c.rho);
            let mut out64 = ShadeOutput::new();
            shade_into_cached(&inp64, Some(&cache), &mut out64).unwrap();
            assert_eq!(out64, shade(&inp64).unwrap());
            let g64: Vec<f64> = g.iter().map(|&x| x as f64).collect();
            assert_eq!(
                shade_backward_cached(&inp64, Some(&cache), &g64).unwrap(),
                shade_backward(&inp64, &g64).unwrap()
            );
        }
    }
    let inp = inputs(&c, &act64.view(), Mode::Traced, ShadeParams::default(), &env64, c.rho);
    let other = case(n, m, k, 7);
    let stale = DirectionCache::new(&other.mb, &c.geom).unwrap();
    assert!(shade_into_cached(&inp, Some(&stale), &mut ShadeOutput::new()).is_err());
    assert!(shade_backward_cached(&inp, Some(&stale), &c.g).is_err());
    let resized = DirectionCache::new(&c.mb, &EnvMap::constant(16, 8, [1.0; 3])).unwrap();
    assert!(shade_into_cached(&inp, Some(&resized), &mut ShadeOutput::new()).is_err());
}

/// Two-sided shading: every gradient against f64 finite differences with a mix of Gaussians seen
/// from the front and from the back, and a Gaussian seen from its back shades exactly as the
/// flipped Gaussian (normal and offsets negated, the back micro-buffer as its own) seen from its
/// front.
#[test]
fn two_sided_gradients_match_finite_differences_f64_and_flip_the_surfel() {
    let (n, m, k) = (6, 4, 8);
    for (ci, (mode, lights)) in [(Mode::Traced, 0usize), (Mode::Given, 3)].into_iter().enumerate() {
        let params = ShadeParams { diffuse: Diffuse::Layered, ..ShadeParams::default() };
        let mut c = case(n, m, k, 40 + ci as u64);
        c.lights = random_lights(&c.geom, n, lights, 7 + ci as u64);
        // Gaussians 2 and 5 are seen from behind.
        for i in [2, 5] {
            c.positions[i] = -c.positions[i];
        }
        let mut back_mb = synthetic_microbuffer(n, k, 90 + ci as u64);
        back_mb.normals = c.mb.normals.iter().map(|a| -*a).collect();
        let back_lights = random_lights(&c.geom, n, lights, 17 + ci as u64);
        let (front_vis, back_vis) = split_by_side(&c.mb.normals, &c.positions, Vec3::ZERO, &c.visible);
        assert_eq!(back_vis, (0..n).map(|i| i == 2 || i == 5).collect::<Vec<_>>());
        let sides = |c: &Case, act: &VertexMaterials<'_, f64>, env: &[[f64; 3]], rho: f64| -> Vec<f64> {
            let back_n = negated(act.normals);
            let front = Side {
                inputs: ShadeInputs { visible: &front_vis, ..inputs(c, act, mode, params, env, rho) },
                cache: None,
            };
            let mut bi = inputs(c, act, mode, params, env, rho);
            bi = ShadeInputs {
                mb: &back_mb,
                visible: &back_vis,
                lights: back_lights.as_ref(),
                mats: VertexMaterials { normals: &back_n, ..*act },
                ..bi
            };
            let mut out = ShadeOutput::new();
            shade_sides_into(&front, Some(&Side { inputs: bi, cache: None }), &mut out).unwrap();
            out.color
        };
        let loss2 = |c: &Case, env: &[[f64; 3]], rho: f64, raw: [&[f64]; 3]| -> f64 {
            let act = activate(m, raw[0], raw[1], raw[2], &c.mb.normals).unwrap();
            sides(c, &act.view(), &env_radiance(env), rho).iter().zip(&c.g).map(|(a, b)| a * b).sum()
        };
        let act = activate(m, &c.albedo, &c.rough, &c.offset, &c.mb.normals).unwrap();
        let rad = env_radiance(&c.env);
        let back_n = negated(act.normals.as_slice());
        let view = act.view();
        let front = Side {
            inputs: ShadeInputs { visible: &front_vis, ..inputs(&c, &view, mode, params, &rad, c.rho) },
            cache: None,
        };
        let bi = ShadeInputs {
            mb: &back_mb,
            visible: &back_vis,
            lights: back_lights.as_ref(),
            mats: VertexMaterials { normals: &back_n, ..view },
            ..inputs(&c, &view, mode, params, &rad, c.rho)
        };
        let grads = shade_sides_backward(&front, Some(&Side { inputs: bi, cache: None }), &c.g).unwrap();
        let raw_g = raw_grads(&c, m, &grads);
        let v_param = env_radiance_backward(&c.env, &grads.v_env);
        let h = 1e-6;
        let check = |what: &str, i: usize, fd: f64, an: f64| {
            assert!((fd - an).abs() <= 2e-7 * (1.0 + fd.abs()), "{mode:?} {what}[{i}]: fd {fd} vs analytic {an}");
        };
        let mut back_nonzero = 0;
        for p in 0..3 {
            let len = [c.albedo.len(), c.rough.len(), c.offset.len()][p];
            for i in 0..len {
                let an = [&raw_g.v_albedo_raw, &raw_g.v_roughness_raw, &raw_g.v_normal_offset][p][i];
                let x = *field(&mut c, p, i);
                *field(&mut c, p, i) = x + h;
                let lp = loss2(&c, &c.env, c.rho, [&c.albedo, &c.rough, &c.offset]);
                *field(&mut c, p, i) = x - h;
                let lm = loss2(&c, &c.env, c.rho, [&c.albedo, &c.rough, &c.offset]);
                *field(&mut c, p, i) = x;
                check(["albedo_raw", "roughness_raw", "normal_offset"][p], i, (lp - lm) / (2.0 * h), an);
                let gaussian = i / ([3, 1, 3][p] * m);
                back_nonzero += (back_vis[gaussian] && an != 0.0) as usize;
            }
        }
        assert!(back_nonzero >= 2 * m * 5, "{mode:?}: back-side gradients {back_nonzero}");
        let mut env = c.env.clone();
        for t in 0..env.len() {
            for ch in 0..3 {
                let x = env[t][ch];
                env[t][ch] = x + h;
                let lp = loss2(&c, &env, c.rho, [&c.albedo, &c.rough, &c.offset]);
                env[t][ch] = x - h;
                let lm = loss2(&c, &env, c.rho, [&c.albedo, &c.rough, &c.offset]);
                env[t][ch] = x;
                check("env_param", 3 * t + ch, (lp - lm) / (2.0 * h), v_param[t][ch]);
            }
        }
        let lp = loss2(&c, &c.env, c.rho + h, [&c.albedo, &c.rough, &c.offset]);
        let lm = loss2(&c, &c.env, c.rho - h, [&c.albedo, &c.rough, &c.offset]);
        check("rho", 0, (lp - lm) / (2.0 * h), grads.v_rho);

        // The flipped model: normals and offsets negated, the back micro-buffer and lights its own.
        let two = sides(&c, &view, &rad, c.rho);
        let neg_offset: Vec<f64> = c.offset.iter().map(|x| -x).collect();
        let flipped = activate(m, &c.albedo, &c.rough, &neg_offset, &back_mb.normals).unwrap();
        let mut fc = case(n, m, k, 40 + ci as u64);
        fc.positions = c.positions.clone();
        fc.mb = back_mb.clone();
        fc.lights = back_lights.clone();
        let fv = flipped.view();
        let one = shade(&ShadeInputs { visible: &back_vis, ..inputs(&fc, &fv, mode, params, &rad, c.rho) }).unwrap();
        for i in [2, 5] {
            for x in i * m * 3..(i + 1) * m * 3 {
                assert!((two[x] - one.color[x]).abs() <= 1e-12 * (1.0 + one.color[x].abs()), "{mode:?} [{x}]");
            }
        }
        assert!(two[2 * m * 3..3 * m * 3].iter().any(|&x| x > 0.0));
    }
}

/// Interleaved direction subsets (`MicroBuffer::interleaved`): the mean of the `stride`
/// subsets' colours and gradients is the full K-direction result (SPEC 4's sum regrouped, the
/// directional lights carried whole by each subset), in f64 with the generic kernels and in f32
/// with the lane kernels; each subset alone differs from it.
#[test]
fn interleaved_subsets_average_to_the_full_sum() {
    let (n, m, k, stride) = (60usize, 4usize, 48usize, 4usize);
    let mut c = case(n, m, k, 21);
    c.lights = random_lights(&c.geom, n, 3, 5);
    let cache = DirectionCache::new(&c.mb, &c.geom).unwrap();
    let subs: Vec<(MicroBuffer, DirectionCache)> = (0..stride)
        .map(|p| {
            let sub = c.mb.interleaved(stride, p).unwrap();
            let sub_cache = cache.interleaved(&sub).unwrap();
            (sub, sub_cache)
        })
        .collect();
    let act64 = activate(m, &c.albedo, &c.rough, &c.offset, &c.mb.normals).unwrap();
    let env64 = env_radiance(&c.env);
    let act32 = synthetic_materials(n, m, 21).activated(&c.mb.normals).unwrap();
    let flat = |g: &PbrGrads<f64>| {
        [g.v_albedo.clone(), g.v_roughness.clone(), g.v_normals.clone(), g.v_env.concat(), vec![g.v_rho]]
    };
    let flat32 = |g: &PbrGrads<f32>| {
        flat(&PbrGrads {
            v_albedo: g.v_albedo.iter().map(|&x| x as f64).collect(),
            v_roughness: g.v_roughness.iter().map(|&x| x as f64).collect(),
            v_normals: g.v_normals.iter().map(|&x| x as f64).collect(),
            v_env: g.v_env.iter().map(|t| t.map(|x| x as f64)).collect(),
            v_rho: g.v_rho as f64,
        })
    };
    let close = |a: &[f64], b: &[f64], tol: f64, what: &str| {
        let scale = b.iter().fold(1e-12f64, |s, x| s.max(x.abs()));
        let err = a.iter().zip(b).fold(0.0f64, |e, (x, y)| e.max((x - y).abs()));
        assert!(err <= tol * scale, "{what}: max error {err:e} against max {scale:e}");
        err / scale
    };
    // One subset's share of the means: its colours and gradients over the stride.
    let add_share =
        |mean: &mut [f64], mean_g: &mut [Vec<f64>; 5], colour: &mut dyn Iterator<Item = f64>, g: &[Vec<f64>; 5]| {
            mean.iter_mut().zip(colour).for_each(|(a, b)| *a += b / stride as f64);
            mean_g.iter_mut().zip(g).for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(x, y)| *x += y / stride as f64));
        };
    let g32: Vec<f32> = c.g.iter().map(|&x| x as f32).collect();
    for mode in [Mode::Traced, Mode::Off] {
        for params in [
            ShadeParams::default(),
            ShadeParams { visibility: false, env_max: 1.5, diffuse: Diffuse::Layered, ..ShadeParams::default() },
        ] {
            // f64, generic kernels.
            let full_in = inputs(&c, &act64.view(), mode, params, &env64, c.rho);
            let full = shade(&full_in).unwrap();
            let full_g = flat(&shade_backward_cached(&full_in, Some(&cache), &c.g).unwrap());
            let mut mean = vec![0.0f64; full.color.len()];
            let mut mean_g = full_g.clone().map(|v| vec![0.0f64; v.len()]);
            for (sub, sub_cache) in &subs {
                let sub_in = ShadeInputs { mb: sub, ..full_in };
                let mut out = ShadeOutput::new();
                shade_into_cached(&sub_in, Some(sub_cache), &mut out).unwrap();
                assert_eq!(out, shade(&sub_in).unwrap(), "the cache keeps the bits");
                let own = close(&out.color, &full.color, 1.0, "one subset");
                assert!(own > 1e-4, "{mode:?}: one subset alone equals the full sum ({own:e})");
                let g = flat(&shade_backward_cached(&sub_in, Some(sub_cache), &c.g).unwrap());
                add_share(&mut mean, &mut mean_g, &mut out.color.iter().copied(), &g);
            }
            close(&mean, &full.color, 1e-12, "f64 colour");
            for (j, (a, b)) in mean_g.iter().zip(&full_g).enumerate() {
                close(a, b, 1e-11, &format!("f64 gradient {j} {mode:?} {params:?}"));
            }
            // f32, the lane kernels where the CPU has them.
            let in32 = ShadeInputs {
                mb: &c.mb,
                positions: &c.positions,
                camera_center: Vec3::ZERO,
                visible: &c.visible,
                mats: act32.view(),
                env_geom: &c.geom,
                env: &c.geom.data,
                indirect: if mode == Mode::Traced { Indirect::Traced { rho: 0.7 } } else { Indirect::Off },
                params,
                lights: c.lights.as_ref(),
            };
            let mut full32 = ShadeOutput::colour_only();
            shade_into_cached(&in32, Some(&cache), &mut full32).unwrap();
            let full32_g = flat32(&shade_backward_cached(&in32, Some(&cache), &g32).unwrap());
            let mut mean = vec![0.0f64; full32.color.len()];
            let mut mean_g = full32_g.clone().map(|v| vec![0.0f64; v.len()]);
            for (sub, sub_cache) in &subs {
                let sub_in = ShadeInputs { mb: sub, ..in32 };
                let mut out = ShadeOutput::colour_only();
                shade_into_cached(&sub_in, Some(sub_cache), &mut out).unwrap();
                let g = flat32(&shade_backward_cached(&sub_in, Some(sub_cache), &g32).unwrap());
                add_share(&mut mean, &mut mean_g, &mut out.color.iter().map(|&x| x as f64), &g);
            }
            let full32_c: Vec<f64> = full32.color.iter().map(|&x| x as f64).collect();
            close(&mean, &full32_c, 2e-6, "f32 colour");
            for (j, (a, b)) in mean_g.iter().zip(&full32_g).enumerate() {
                close(a, b, 2e-5, &format!("f32 gradient {j} {mode:?} {params:?}"));
            }
        }
    }
}
