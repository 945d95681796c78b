//! Radiance consistency: pair selection on hand-made micro-buffers, the L1 core in f64, and the
//! whole loss (selection -> gather -> L1 -> materials / env / rho) against an f64 evaluation of
//! Eqn 13 written straight from the SPEC, differentiated by finite differences, on a traced scene.

use glam::Vec3;
use svgir_core::{EnvMap, Rng};
use svgir_pbr::fixtures::synthetic_materials;
use svgir_pbr::{
    activate, env_radiance, l1_loss, mirror_pick, radiance_consistency, radiance_consistency_backward,
    radiance_consistency_with_grad, select_pairs, ConsistencyInputs, EnvLight, SvgMaterials,
};
use svgir_shading::float::dot;
use svgir_shading::{ggx, vertex_weights, Diffuse};
use svgir_trace::pack::unorm16;
use svgir_trace::scenes::object_scene;
use svgir_trace::{Bvh, GatherParams, MicroBuffer, TraceParams, NO_HIT};

/// The bit patterns of a run of f32s.
fn bits<'a>(v: impl Iterator<Item = &'a f32>) -> Vec<u32> {
    v.map(|x| x.to_bits()).collect()
}

#[test]
fn picks_the_occluded_direction_nearest_the_mirror() {
    let k = 32;
    let mut mb = MicroBuffer {
        k,
        normals: vec![Vec3::Z],
        xi: vec![0.3],
        vis: vec![unorm16(1.0); k],
        radiance: vec![[0; 3]; k],
        first_hit: vec![NO_HIT; k],
        uv: vec![[0; 2]; k],
        interleave: Default::default(),
    };
    // View ray coming down at 45 degrees along +x: the mirror direction is (1, 0, 1)/sqrt2.
    let view = Vec3::new(1.0, 0.0, -1.0).normalize();
    assert_eq!(mirror_pick(&mb, 0, view), None, "nothing occluded");
    let r = Vec3::new(1.0, 0.0, 1.0).normalize();
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| mb.direction(0, b).dot(r).total_cmp(&mb.direction(0, a).dot(r)));
    let (best, second, behind) = (order[0], order[1], order[k - 1]);
    assert!(mb.direction(0, behind).dot(r) < 0.0);
    // Occluded but not hit: not eligible. Occluded with a hit behind the mirror lobe: score < 0.
    mb.vis[best] = unorm16(0.0);
    mb.first_hit[behind] = 0;
    mb.vis[behind] = unorm16(0.0);
    assert_eq!(mirror_pick(&mb, 0, view), None);
    mb.first_hit[second] = 0;
    mb.vis[second] = unorm16(0.0);
    assert_eq!(mirror_pick(&mb, 0, view), Some(second as u32));
    mb.first_hit[best] = 0;
    assert_eq!(mirror_pick(&mb, 0, view), Some(best as u32));
    // (1 - V) weighs in: a barely-occluded best loses to a fully occluded second.
    mb.vis[best] = unorm16(0.95);
    assert_eq!(mirror_pick(&mb, 0, view), Some(second as u32));
    let pairs = select_pairs(&mb, &[Vec3::ZERO], Vec3::new(-1.0, 0.0, 1.0), &[true]);
    assert_eq!(pairs, vec![(0, second as u32)]);
    assert!(select_pairs(&mb, &[Vec3::ZERO], Vec3::new(-1.0, 0.0, 1.0), &[false]).is_empty());
}

#[test]
fn l1_core_gradients_f64() {
    let mut rng = Rng::new(2);
    let l1b: Vec<[f64; 3]> = (0..7).map(|_| [0, 1, 2].map(|_| rng.uniform_f64())).collect();
    let traced: Vec<[f64; 3]> = (0..7).map(|_| [0, 1, 2].map(|_| rng.uniform_f64())).collect();
    let rho = 0.9;
    let (loss, v_l1b, v_rho) = l1_loss(&l1b, &traced, rho);
    let want: f64 = (0..7)
        .flat_map(|i| (0..3).map(move |c| (i, c)))
        .map(|(i, c)| (l1b[i][c] - rho * traced[i][c]).abs())
        .sum::<f64>()
        / 21.0;
    assert!((loss - want).abs() < 1e-15);
    let h = 1e-7;
    let fd = (l1_loss(&l1b, &traced, rho + h).0 - l1_loss(&l1b, &traced, rho - h).0) / (2.0 * h);
    assert!((fd - v_rho).abs() < 1e-8);
    for i in 0..7 {
        for c in 0..3 {
            let mut p = l1b.clone();
            p[i][c] += h;
            let mut q = l1b.clone();
            q[i][c] -= h;
            let fd = (l1_loss(&p, &traced, rho).0 - l1_loss(&q, &traced, rho).0) / (2.0 * h);
            assert!((fd - v_l1b[i][c]).abs() < 1e-8);
        }
    }
    assert_eq!(l1_loss::<f64>(&[], &[], 1.0).0, 0.0);
}

/// Eqn 13 for one (j, k) in f64, term by term.
#[allow(clippy::too_many_arguments)]
fn l1b_naive(
    mb: &MicroBuffer,
    m: usize,
    albedo: &[f64],
    rough: &[f64],
    normals: &[f64],
    geom: &EnvMap,
    env: &[[f64; 3]],
    env_max: f64,
    diffuse: Diffuse,
    j: usize,
    k: usize,
) -> [f64; 3] {
    let Some(h) = mb.hit(j, k) else { return [0.0; 3] };
    let h = h as usize;
    let uv = mb.uv(j, k);
    let w = vertex_weights(m, uv[0] as f64, uv[1] as f64);
    let v = (-mb.direction(j, k)).to_array().map(|x| x as f64);
    let mut acc = [0.0; 3];
    for s in (0..mb.k).filter(|&s| mb.escaped(h, s)) {
        let d = mb.direction(h, s);
        let l = d.to_array().map(|x| x as f64);
        let taps = geom.taps(d);
        let mut light = [0.0; 3];
        for t in 0..4 {
            for c in 0..3 {
                light[c] += taps.weight[t] as f64 * env[taps.index[t] as usize][c];
            }
        }
        let light = light.map(|x| x.clamp(0.0, env_max));
        for mm in 0..m {
            let b = (h * m + mm) * 3;
            let n = [normals[b], normals[b + 1], normals[b + 2]];
            let f = ggx(n, v, l, [albedo[b], albedo[b + 1], albedo[b + 2]], rough[h * m + mm], diffuse);
            let cos = dot(n, l).max(1e-6);
            for c in 0..3 {
                acc[c] += w[mm] * f[c] * cos * light[c];
            }
        }
    }
    acc.map(|x| x * std::f64::consts::TAU / mb.k as f64)
}

#[test]
fn whole_loss_gradients_match_finite_differences() {
    for (m, seed, diffuse) in
        [(4usize, 1u64, Diffuse::Added), (1, 2, Diffuse::Layered), (6, 3, Diffuse::Added), (2, 4, Diffuse::Layered)]
    {
        let surfels = object_scene(300, seed);
        let k = 8;
        let mb = MicroBuffer::trace(&Bvh::build(&surfels), &surfels, k, seed, &TraceParams::default()).unwrap();
        let n = surfels.len();
        let cam = Vec3::new(2.0, -1.5, 1.2);
        let visible: Vec<bool> = (0..n).map(|i| i % 5 != 2).collect();
        let mut mats = synthetic_materials(n, m, seed);
        for x in mats.normal_offset.iter_mut() {
            *x *= 2.0;
        }
        let light = EnvLight::new(4, seed).unwrap();
        let env_max = 3.5f32; // some lookups are clamped
        let params = GatherParams { env_max, lights: None, diffuse, cache: None, ..Default::default() };
        let rho = 0.8f32;
        let normals = mb.normals.clone();

        // Production path, f32.
        let act = mats.activated(&normals).unwrap();
        let env = light.radiance();
        let inp = ConsistencyInputs {
            mb: &mb,
            positions: &surfels.positions,
            camera_center: cam,
            visible: &visible,
            mats: act.view(),
            env: &env,
            rho,
            params,
        };
        let fwd = radiance_consistency(&inp).unwrap();
        assert!(fwd.pairs.len() > 40, "M={m}: only {} pairs", fwd.pairs.len());
        assert!(fwd.pairs.iter().all(|&(j, _)| visible[j as usize]));
        let grads = radiance_consistency_backward(&inp, &fwd, 1.0).unwrap();
        let raw = mats.backward(&normals, &grads.v_albedo, &grads.v_roughness, &grads.v_normals).unwrap();
        let v_param = light.backward(&grads.v_env).unwrap();

        // Oracle, f64, for the same (frozen) pairs.
        let f64v = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
        let param64: Vec<[f64; 3]> = light.param.iter().map(|t| t.map(|x| x as f64)).collect();
        let loss64 = |a: &[f64], r: &[f64], d: &[f64], p: &[[f64; 3]], rho: f64| -> f64 {
            let act = activate(m, a, r, d, &normals).unwrap();
            let rad = env_radiance(p);
            let l1b: Vec<[f64; 3]> = fwd
                .pairs
                .iter()
                .map(|&(j, kk)| {
                    let (albedo, rough, nrm) = (&act.albedo, &act.roughness, &act.normals);
                    l1b_naive(&mb, m, albedo, rough, nrm, &env, &rad, env_max as f64, diffuse, j as usize, kk as usize)
                })
                .collect();
            let traced: Vec<[f64; 3]> = fwd.traced.iter().map(|t| t.map(|x| x as f64)).collect();
            l1_loss(&l1b, &traced, rho).0
        };
        let (mut a, mut r, mut d) = (f64v(&mats.albedo_raw), f64v(&mats.roughness_raw), f64v(&mats.normal_offset));
        let base = loss64(&a, &r, &d, &param64, rho as f64);
        assert!((base - fwd.loss as f64).abs() < 1e-4 * (1.0 + base), "M={m}: loss {} vs f64 {base}", fwd.loss);
        {
            let act64 = activate(m, &a, &r, &d, &normals).unwrap();
            let rad = env_radiance(&param64);
            for (i, &(j, kk)) in fwd.pairs.iter().enumerate() {
                let want = l1b_naive(
                    &mb,
                    m,
                    &act64.albedo,
                    &act64.roughness,
                    &act64.normals,
                    &env,
                    &rad,
                    env_max as f64,
                    diffuse,
                    j as usize,
                    kk as usize,
                );
                for c in 0..3 {
                    assert!((fwd.l1b[i][c] as f64 - want[c]).abs() <= 1e-4 * (1.0 + want[c]), "M={m} pair {i}");
                }
            }
        }

        // Finite differences on a sample of the non-zero gradients (f32 analytic, f64 oracle).
        let h = 1e-5;
        let mut rng = Rng::new(seed);
        let check = |what: &str, all: &[f32], i: usize, fd: f64| {
            let scale = all.iter().fold(0f32, |s, x| s.max(x.abs())) as f64;
            let an = all[i] as f64;
            assert!((fd - an).abs() <= 2e-3 * fd.abs() + 1e-3 * scale, "M={m} {what}[{i}]: fd {fd} vs {an}");
        };
        let pick = |v: &[f32], rng: &mut Rng| -> Vec<usize> {
            let nz: Vec<usize> = (0..v.len()).filter(|&i| v[i] != 0.0).collect();
            assert!(nz.len() >= 6, "M={m}: only {} non-zero gradients", nz.len());
            (0..8).map(|_| nz[rng.below(nz.len())]).collect()
        };
        for i in pick(&raw.v_albedo_raw, &mut rng) {
            let x = a[i];
            a[i] = x + h;
            let p = loss64(&a, &r, &d, &param64, rho as f64);
            a[i] = x - h;
            let q = loss64(&a, &r, &d, &param64, rho as f64);
            a[i] = x;
            check("albedo_raw", &raw.v_albedo_raw, i, (p - q) / (2.0 * h));
        }
        for i in pick(&raw.v_roughness_raw, &mut rng) {
            let x = r[i];
            r[i] = x + h;
            let p = loss64(&a, &r, &d, &param64, rho as f64);
            r[i] = x - h;
            let q = loss64(&a, &r, &d, &param64, rho as f64);
            r[i] = x;
            check("roughness_raw", &raw.v_roughness_raw, i, (p - q) / (2.0 * h));
        }
        for i in pick(&raw.v_normal_offset, &mut rng) {
            let x = d[i];
            d[i] = x + h;
            let p = loss64(&a, &r, &d, &param64, rho as f64);
            d[i] = x - h;
            let q = loss64(&a, &r, &d, &param64, rho as f64);
            d[i] = x;
            check("normal_offset", &raw.v_normal_offset, i, (p - q) / (2.0 * h));
        }
        let flat: Vec<f32> = v_param.iter().flatten().copied().collect();
        for i in pick(&flat, &mut rng) {
            let mut p = param64.clone();
            p[i / 3][i % 3] += h;
            let lp = loss64(&a, &r, &d, &p, rho as f64);
            p[i / 3][i % 3] -= 2.0 * h;
            let lm = loss64(&a, &r, &d, &p, rho as f64);
            check("env_param", &flat, i, (lp - lm) / (2.0 * h));
        }
        let fd =
            (loss64(&a, &r, &d, &param64, rho as f64 + h) - loss64(&a, &r, &d, &param64, rho as f64 - h)) / (2.0 * h);
        check("rho", &[grads.v_rho], 0, fd);
        assert!(grads.v_rho != 0.0);

        // Only hit Gaussians receive material gradients; v_loss scales everything.
        let hit: Vec<bool> = {
            let mut hit = vec![false; n];
            for &(j, kk) in &fwd.pairs {
                hit[mb.hit(j as usize, kk as usize).unwrap() as usize] = true;
            }
            hit
        };
        for i in 0..n {
            if !hit[i] {
                assert!(grads.v_albedo[i * m * 3..(i + 1) * m * 3].iter().all(|&x| x == 0.0));
            }
        }
        let g2 = radiance_consistency_backward(&inp, &fwd, 0.5).unwrap();
        assert!((g2.v_rho - 0.5 * grads.v_rho).abs() <= 1e-6 * grads.v_rho.abs());

        // The one-pass forward and backward give the two calls' values and gradients, bit for bit.
        for (v_loss, want) in [(1.0, &grads), (0.5, &g2)] {
            let (c, g) = radiance_consistency_with_grad(&inp, v_loss).unwrap();
            assert_eq!(c.pairs, fwd.pairs);
            assert_eq!(c.loss.to_bits(), fwd.loss.to_bits());
            assert_eq!(bits(c.l1b.iter().flatten()), bits(fwd.l1b.iter().flatten()));
            assert_eq!(bits(c.traced.iter().flatten()), bits(fwd.traced.iter().flatten()));
            for (got, exp) in
                [(&g.v_albedo, &want.v_albedo), (&g.v_roughness, &want.v_roughness), (&g.v_normals, &want.v_normals)]
            {
                assert_eq!(bits(got.iter()), bits(exp.iter()), "M={m}, v_loss {v_loss}");
            }
            assert_eq!(bits(g.v_env.iter().flatten()), bits(want.v_env.iter().flatten()));
            assert_eq!(g.v_rho.to_bits(), want.v_rho.to_bits());
        }
        let _ = SvgMaterials::new(1, m).unwrap();
    }
}
