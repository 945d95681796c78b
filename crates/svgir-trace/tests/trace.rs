//! The BVH traversal against the brute-force reference, and analytic transmittance cases.

use glam::{Quat, Vec2, Vec3};
use svgir_core::{surfel::logit, Rng, ShCoeffs, Surfels};
use svgir_trace::scenes::{object_scene, random_scene};
use svgir_trace::{
    march, march_visibility, BruteForce, Bvh, Hit, HitSource, MicroBuffer, Ray, TraceParams, NO_HIT, NO_ID,
};

fn random_ray(rng: &mut Rng, s: &Surfels) -> Ray {
    let dir = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    if rng.uniform() < 0.5 {
        let j = rng.below(s.len());
        Ray { origin: s.positions[j], dir, t_start: 0.0, ignore: j as u32 }
    } else {
        let o = Vec3::new(rng.range(-1.2, 1.2), rng.range(-1.2, 1.2), rng.range(-1.2, 1.2));
        Ray { origin: o, dir, t_start: rng.range(0.0, 0.3), ignore: NO_ID }
    }
}

fn collect<S: HitSource>(src: &S, ray: &Ray, p: &TraceParams) -> Vec<Hit> {
    let mut v = Vec::new();
    src.for_each_hit(ray, p, |h| {
        v.push(*h);
        true
    });
    v
}

fn param_sets() -> Vec<TraceParams> {
    let d = TraceParams::default();
    vec![
        d,
        TraceParams { eps: 0.0, ..d },
        TraceParams { eps: 0.01, eps_scale: 1.0, t_max: 1.5, ..d },
        TraceParams { eps: 0.0, t_max: 0.4, t_stop: 0.05, ..d },
        TraceParams { cull_backfaces: true, t_min_scale: 0.0, ..d },
    ]
}

#[test]
fn bvh_hits_equal_brute_force() {
    let mut total_hits = 0;
    let mut multi = 0;
    for (n, seed) in [(300usize, 1u64), (3000, 2)] {
        let s = random_scene(n, seed);
        let bvh = Bvh::build(&s);
        let bf = BruteForce::new(&s);
        let mut rng = Rng::new(seed + 100);
        for p in param_sets() {
            for _ in 0..400 {
                let ray = random_ray(&mut rng, &s);
                let a = collect(&bvh, &ray, &p);
                let b = collect(&bf, &ray, &p);
                assert_eq!(a, b, "hit lists differ for {ray:?} {p:?}");
                total_hits += a.len();
                multi += (a.len() > 16) as usize;
                assert!(a.windows(2).all(|w| (w[0].t, w[0].id) < (w[1].t, w[1].id)));
                assert_eq!(bvh.first_hit(&ray, &p), bf.first_hit(&ray, &p));
                let ma = march(&bvh, &s.sh, 3, &ray, &p);
                let mb = march(&bf, &s.sh, 3, &ray, &p);
                assert_eq!(ma, mb);
            }
        }
    }
    // The comparison must have exercised long hit lists (buffer restarts), not just misses.
    assert!(total_hits > 5000 && multi > 20, "weak test: {total_hits} hits, {multi} rays with > 16");
}

#[test]
fn micro_buffers_equal_brute_force_and_are_thread_independent() {
    let s = object_scene(1500, 3);
    let bvh = Bvh::build(&s);
    let bf = BruteForce::new(&s);
    let p = TraceParams::default();
    let a = MicroBuffer::trace(&bvh, &s, 16, 9, &p).unwrap();
    let b = MicroBuffer::trace(&bf, &s, 16, 9, &p).unwrap();
    assert_eq!(a, b);
    let c = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| MicroBuffer::trace(&bvh, &s, 16, 9, &p).unwrap());
    assert_eq!(a, c);
    // Non-trivial content: both hits and escapes, partial visibilities.
    let hits = a.first_hit.iter().filter(|&&h| h != NO_HIT).count();
    assert!(hits > 500 && hits < a.first_hit.len() - 500, "{hits} of {}", a.first_hit.len());
    // Decoded values match a direct march of the same ray.
    let mut rng = Rng::new(4);
    for _ in 0..200 {
        let (j, k) = (rng.below(s.len()), rng.below(16));
        let ray = Ray::from_gaussian(&s, j, a.direction(j, k), &p);
        let r = march(&bvh, &s.sh, s.sh_degree, &ray, &p);
        assert!((a.visibility(j, k) - r.visibility).abs() < 1e-4);
        let l = a.radiance(j, k);
        for c in 0..3 {
            assert!((l[c] - r.radiance[c]).abs() <= 1e-3 * r.radiance[c] + 1e-6);
        }
        assert_eq!(a.hit(j, k), r.first.map(|h| h.id));
        if let Some(h) = r.first {
            let uv = h.uv_normalised();
            assert!((a.uv(j, k)[0] - uv[0]).abs() < 2e-5 && (a.uv(j, k)[1] - uv[1]).abs() < 2e-5);
        }
    }
}

/// The visibility-only march stops once V is certain to be 0, yet reports the full march's V and
/// first hit to the bit; it must also stop earlier than the full march on a good share of rays.
#[test]
fn visibility_march_equals_the_full_march() {
    let s = object_scene(3000, 7);
    let bvh = Bvh::build(&s);
    let mut rng = Rng::new(8);
    let (mut rays, mut zero, mut cut_short) = (0, 0, 0);
    let params = param_sets().into_iter().chain([
        TraceParams { visibility_alpha_gain: 3.0, ..TraceParams::default() },
        TraceParams { v_cut: 0.5, ..TraceParams::default() },
        TraceParams { v_cut: 0.0, ..TraceParams::default() },
    ]);
    for p in params {
        for _ in 0..400 {
            let j = rng.below(s.len());
            let dir = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
            let ray = Ray::from_gaussian(&s, j, dir, &p);
            let full = march(&bvh, &s.sh, s.sh_degree, &ray, &p);
            let o = march_visibility(&bvh, &ray, &p);
            assert_eq!(o.visibility.to_bits(), full.visibility.to_bits(), "{ray:?} {p:?}");
            assert_eq!(o.first, full.first);
            let mut consumed = 0;
            let mut tv = 1.0f32;
            bvh.for_each_hit(&ray, &p, |h| {
                consumed += 1;
                tv *= 1.0 - (h.alpha * p.visibility_alpha_gain).min(0.99);
                tv >= p.v_cut
            });
            rays += 1;
            zero += (full.visibility == 0.0) as usize;
            cut_short += (consumed < full.hits) as usize;
        }
    }
    assert!(
        zero > rays / 10 && cut_short > rays / 20,
        "weak test: {rays} rays, {zero} with V = 0, {cut_short} cut short"
    );
}

/// Relighting's micro-buffers: V, I and U as the full trace's, L not traced.
#[test]
fn occlusion_micro_buffers_equal_the_full_ones_but_radiance() {
    let s = object_scene(1500, 3);
    let bvh = Bvh::build(&s);
    let p = TraceParams::default();
    let axes: Vec<Vec3> = (0..s.len()).map(|j| s.normal(j)).collect();
    let full = MicroBuffer::trace(&bvh, &s, 16, 9, &p).unwrap();
    let occ = MicroBuffer::trace_occlusion_about(&bvh, &s, axes, 16, 9, &p).unwrap();
    assert_eq!((&occ.vis, &occ.first_hit, &occ.uv), (&full.vis, &full.first_hit, &full.uv));
    assert_eq!((&occ.normals, &occ.xi, occ.k), (&full.normals, &full.xi, full.k));
    assert!(occ.radiance.iter().all(|l| *l == [0; 3]));
    assert!(full.radiance.iter().any(|l| *l != [0; 3]));
}

/// The back side of every Gaussian (two-sided shading): K directions over the hemisphere of -n,
/// each sample the march of its ray from the Gaussian's own disk; on a closed shell one side looks
/// out and the other in; bad axes are rejected.
#[test]
fn back_micro_buffers_trace_the_other_hemisphere() {
    let s = object_scene(1200, 5);
    let bvh = Bvh::build(&s);
    let p = TraceParams::default();
    let front = MicroBuffer::trace(&bvh, &s, 16, 9, &p).unwrap();
    let back_axes: Vec<Vec3> = front.normals.iter().map(|n| -*n).collect();
    let back = MicroBuffer::trace_about(&bvh, &s, back_axes.clone(), 16, 9, &p).unwrap();
    assert_eq!((back.normals.clone(), back.xi.clone()), (back_axes, front.xi.clone()));
    let mut rng = Rng::new(8);
    for _ in 0..300 {
        let (j, k) = (rng.below(s.len()), rng.below(16));
        let d = back.direction(j, k);
        assert!(d.dot(front.normals[j]) < 0.0, "j={j} k={k}: {d} is not behind {}", front.normals[j]);
        let r = march(&bvh, &s.sh, s.sh_degree, &Ray::from_gaussian(&s, j, d, &p), &p);
        assert!((back.visibility(j, k) - r.visibility).abs() < 1e-4);
        assert_eq!(back.hit(j, k), r.first.map(|h| h.id));
    }
    let mean_vis = |mb: &MicroBuffer| mb.vis.iter().map(|&v| v as f64).sum::<f64>() / mb.vis.len() as f64 / 65535.0;
    // One side of the object's shell looks out, the other in.
    let (vb, vf) = (mean_vis(&back), mean_vis(&front));
    assert!((vb - vf).abs() > 0.2, "{vb} vs {vf}");
    // Axes for the first Gaussians only are rays from those (the rest are surroundings); more
    // axes than Gaussians are refused.
    assert!(MicroBuffer::trace_about(&bvh, &s, vec![Vec3::Z; s.len() + 1], 16, 9, &p).is_err());
    let mut nan = front.normals.clone();
    nan[0] = Vec3::NAN;
    assert!(MicroBuffer::trace_about(&bvh, &s, nan, 16, 9, &p).is_err());
}

/// Disks facing -z stacked along the z axis, one ray up through their centres.
fn stack(opacities: &[f32], spacing: f32) -> Surfels {
    let mut s = Surfels::with_capacity(opacities.len(), 0);
    for (i, &o) in opacities.iter().enumerate() {
        let rgb = [0.1 * i as f32, 0.2, 0.9 - 0.1 * i as f32];
        s.push(
            Vec3::new(0.0, 0.0, 1.0 + spacing * i as f32),
            Quat::from_rotation_x(std::f32::consts::PI),
            Vec2::splat(0.1f32.ln()),
            logit(o),
            ShCoeffs::from_rgb(rgb),
        );
    }
    s
}

#[test]
fn stack_of_disks_gives_product_transmittance() {
    let ops = [0.3f32, 0.5, 0.2, 0.7, 0.4];
    let s = stack(&ops, 0.1);
    let bvh = Bvh::build(&s);
    let ray = Ray { origin: Vec3::ZERO, dir: Vec3::Z, t_start: 0.0, ignore: NO_ID };
    let p = TraceParams { t_stop: 1e-6, v_cut: 0.0, ..TraceParams::default() };
    let r = march(&bvh, &s.sh, 0, &ray, &p);
    let mut t = 1.0f32;
    let mut l = [0.0f32; 3];
    for (i, &o) in ops.iter().enumerate() {
        let c = [0.1 * i as f32, 0.2, 0.9 - 0.1 * i as f32];
        for ch in 0..3 {
            l[ch] += c[ch] * o * t;
        }
        t *= 1.0 - o;
    }
    assert_eq!(r.hits, 5);
    assert!((r.transmittance - t).abs() < 1e-5, "{} vs {t}", r.transmittance);
    for ch in 0..3 {
        assert!((r.radiance[ch] - l[ch]).abs() < 1e-4);
    }
    assert_eq!(r.first.unwrap().id, 0);
    // Linear radiance: each hit's sRGB colour is decoded before it is weighted (not the sum).
    let rl = march(&bvh, &s.sh, 0, &ray, &TraceParams { linear_radiance: true, ..p });
    let mut t = 1.0f32;
    let mut ll = [0.0f32; 3];
    for (i, &o) in ops.iter().enumerate() {
        let c = [0.1 * i as f32, 0.2, 0.9 - 0.1 * i as f32].map(svgir_core::color::srgb_to_linear);
        for ch in 0..3 {
            ll[ch] += c[ch] * o * t;
        }
        t *= 1.0 - o;
    }
    assert_eq!(rl.transmittance, r.transmittance);
    for ch in 0..3 {
        assert!((rl.radiance[ch] - ll[ch]).abs() < 1e-5, "{:?} vs {ll:?}", rl.radiance);
        assert!(rl.radiance[ch] < r.radiance[ch]);
    }
    // V cut: T = 0.084 < 0.2 -> V = 0 under the default parameters.
    assert_eq!(march(&bvh, &s.sh, 0, &ray, &TraceParams::default()).visibility, 0.0);
    // Visibility opacity gain: V is the product of (1 - min(0.99, g o)); radiance and T unchanged.
    let rg = march(&bvh, &s.sh, 0, &ray, &TraceParams { visibility_alpha_gain: 1.5, ..p });
    let tv: f32 = ops.iter().map(|o| 1.0 - (1.5 * o).min(0.99)).product();
    assert!((rg.visibility - tv).abs() < 1e-6, "{} vs {tv}", rg.visibility);
    assert_eq!((rg.transmittance, rg.radiance), (r.transmittance, r.radiance));
    // Continuation offset: with spacing 0.03 < eps = 0.05, hits 0, 2, 4 are taken (1 and 3 skipped).
    let s2 = stack(&ops, 0.03);
    let r2 = march(&Bvh::build(&s2), &s2.sh, 0, &ray, &p);
    assert_eq!(r2.hits, 3);
    assert!((r2.transmittance - 0.7 * 0.8 * 0.6).abs() < 1e-5);
    // Early stop at T < 1e-3: opaque (0.99) disks stop after two.
    let s3 = stack(&[0.999, 0.999, 0.999], 0.1);
    let r3 = march(&Bvh::build(&s3), &s3.sh, 0, &ray, &TraceParams::default());
    assert_eq!(r3.hits, 2);
    // t_max cuts the range.
    let r4 = march(&bvh, &s.sh, 0, &ray, &TraceParams { t_max: 1.25, ..p });
    assert_eq!(r4.hits, 3);
}

/// `radiance_sh_degree` caps the SH degree of the traced radiance: 0 gives each hit's mean
/// (DC) colour in every direction, a cap at or above the model's degree changes nothing.
#[test]
fn radiance_sh_degree_caps_the_traced_colour() {
    let mut s = stack(&[0.6, 0.5], 0.1);
    s.sh_degree = 3;
    let mut rng = svgir_core::Rng::new(7);
    for c in &mut s.sh {
        for k in 1..16 {
            for ch in 0..3 {
                c.0[k][ch] = 0.2 * (rng.uniform() - 0.5);
            }
        }
    }
    let bvh = Bvh::build(&s);
    let p = TraceParams { t_stop: 1e-6, v_cut: 0.0, ..TraceParams::default() };
    let dc = |d: Vec3| {
        let ray = Ray { origin: Vec3::new(0.0, 0.0, -1.0), dir: d.normalize(), t_start: 0.0, ignore: NO_ID };
        let full = march(&bvh, &s.sh, 3, &ray, &p).radiance;
        let capped = march(&bvh, &s.sh, 3, &ray, &TraceParams { radiance_sh_degree: 0, ..p }).radiance;
        let as_zero = march(&bvh, &s.sh, 0, &ray, &p).radiance;
        let as_four = march(&bvh, &s.sh, 3, &ray, &TraceParams { radiance_sh_degree: 4, ..p }).radiance;
        assert_eq!(capped, as_zero);
        assert_eq!(as_four, full);
        (full, capped)
    };
    let (fa, ca) = dc(Vec3::new(0.05, 0.0, 1.0));
    // The same distance from the disks' centres (so the same alphas), another azimuth.
    let (fb, cb) = dc(Vec3::new(0.0, 0.05, 1.0));
    assert_ne!(fa, fb, "the full SH colour depends on the direction");
    for ch in 0..3 {
        assert!((ca[ch] - cb[ch]).abs() < 1e-6, "DC alone does not: {ca:?} vs {cb:?}");
    }
}

#[test]
fn coincident_hits_are_ordered_by_id() {
    let mut s = stack(&[0.5, 0.5], 0.0);
    s.push(Vec3::new(0.0, 0.0, 0.5), Quat::IDENTITY, Vec2::splat(0.1f32.ln()), 0.0, ShCoeffs::default());
    // Ids 0, 1 coincide at t = 1; id 2 sits at t = 0.5.
    let bvh = Bvh::build(&s);
    let ray = Ray { origin: Vec3::ZERO, dir: Vec3::Z, t_start: 0.0, ignore: NO_ID };
    let all = collect(&bvh, &ray, &TraceParams { eps: 0.0, ..TraceParams::default() });
    assert_eq!(all.iter().map(|h| h.id).collect::<Vec<_>>(), vec![2, 0, 1]);
    assert_eq!(all[1].t, all[2].t);
    // With an offset the second coincident disk is skipped.
    let some = collect(&bvh, &ray, &TraceParams::default());
    assert_eq!(some.iter().map(|h| h.id).collect::<Vec<_>>(), vec![2, 0]);
}

/// A closed cube of opaque surfels around a probe surfel: every direction is blocked.
#[test]
fn closed_box_blocks_everything_from_inside() {
    let h = 0.05f32; // grid spacing; sigma = 2h so every point is well covered (alpha >= 0.93)
    let mut s = Surfels::with_capacity(3000, 0);
    s.push(
        Vec3::new(0.05, -0.03, 0.02),
        Quat::from_rotation_y(0.3),
        Vec2::splat(0.01f32.ln()),
        0.0,
        ShCoeffs::default(),
    );
    let faces: [(Vec3, Quat); 6] = [
        (Vec3::Z, Quat::IDENTITY),
        (-Vec3::Z, Quat::from_rotation_x(std::f32::consts::PI)),
        (Vec3::X, Quat::from_rotation_y(std::f32::consts::FRAC_PI_2)),
        (-Vec3::X, Quat::from_rotation_y(-std::f32::consts::FRAC_PI_2)),
        (Vec3::Y, Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2)),
        (-Vec3::Y, Quat::from_rotation_x(std::f32::consts::FRAC_PI_2)),
    ];
    let m = (1.0 / h) as i32;
    for (nrm, q) in faces {
        let (tu, tv) = (q * Vec3::X, q * Vec3::Y);
        assert!(((q * Vec3::Z) - nrm).length() < 1e-6);
        for a in -m / 2..=m / 2 {
            for b in -m / 2..=m / 2 {
                let p = 0.5 * nrm + h * (a as f32 * tu + b as f32 * tv);
                s.push(p, q, Vec2::splat((2.0 * h).ln()), logit(0.99), ShCoeffs::from_rgb([0.5; 3]));
            }
        }
    }
    let bvh = Bvh::build(&s);
    // With the SPEC's continuation offset a ray may first touch a wall surfel at the faint rim of
    // its support and then skip the strong coplanar ones within eps, so V need not reach 0 -- but
    // every direction is hit. With eps = 0 all coplanar layers composite and V = 0 everywhere.
    let mb = MicroBuffer::trace(&bvh, &s, 64, 1, &TraceParams::default()).unwrap();
    assert!((0..64).all(|k| mb.hit(0, k).is_some()));
    let p = TraceParams { eps: 0.0, ..TraceParams::default() };
    let mb = MicroBuffer::trace(&bvh, &s, 64, 1, &p).unwrap();
    for k in 0..64 {
        assert_eq!(mb.visibility(0, k), 0.0, "direction {k} sees out: {}", mb.direction(0, k));
        assert!(mb.hit(0, k).is_some());
        let l = mb.radiance(0, k);
        assert!((l[0] - 0.5).abs() < 0.01, "opaque grey wall radiance {l:?}");
    }
    // Remove the +z face: upward directions now escape with V = 1.
    let keep: Vec<bool> = (0..s.len()).map(|i| i == 0 || s.positions[i].z < 0.49).collect();
    s.retain(&keep);
    let mb = MicroBuffer::trace(&Bvh::build(&s), &s, 64, 1, &p).unwrap();
    let open = (0..64).filter(|&k| mb.hit(0, k).is_none()).count();
    assert!(open > 5, "{open}");
    for k in (0..64).filter(|&k| mb.hit(0, k).is_none()) {
        assert_eq!(mb.visibility(0, k), 1.0);
        assert!(mb.direction(0, k).z > 0.0);
    }
}

#[test]
fn rejects_bad_input() {
    let mut s = random_scene(10, 1);
    let bvh = Bvh::build(&s);
    assert!(MicroBuffer::trace(&bvh, &s, 0, 1, &TraceParams::default()).is_err());
    s.positions[3].x = f32::NAN;
    assert!(MicroBuffer::trace(&bvh, &s, 8, 1, &TraceParams::default()).is_err());
    // An empty scene traces fine: nothing is hit.
    let e = Surfels::default();
    assert!(MicroBuffer::trace(&Bvh::build(&e), &e, 8, 1, &TraceParams::default()).unwrap().is_empty());
}
