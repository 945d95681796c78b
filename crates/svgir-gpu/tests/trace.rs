//! The GPU micro-buffer march against the CPU's (svgir_trace::traverse), on lavapipe in CI:
//! the same hits in the same (t, id) order for every ray, the same samples once packed, and
//! the CPU's own micro-buffers up to the rounding of the directions.

mod common;

use glam::Vec3;
use svgir_core::Surfels;
use svgir_gpu::trace::{GpuTracer, RecordedRay};
use svgir_trace::pack::{f16_to_f32, from_unorm16};
use svgir_trace::scenes::{object_scene, random_scene};
use svgir_trace::{Bvh, HitSource, MicroBuffer, Ray, TraceParams, TraceRequest, NO_HIT};

/// Hits recorded per ray.
const RECORD: u32 = 48;

/// K directions about every surfel's own normal.
fn request<'a>(s: &Surfels, k: usize, seed: u64, p: &'a TraceParams, radiance: bool) -> TraceRequest<'a> {
    TraceRequest { axes: (0..s.len()).map(|j| s.normal(j)).collect(), k, seed, params: p, radiance }
}

/// The variants of the rules each scene is traced with: the default, scale-aware offsets and a
/// finite range, back-face culling with linear radiance and a low SH degree, and the
/// visibility march (which stops at v_cut) with a visibility gain.
fn variants() -> Vec<(TraceParams, bool)> {
    let d = TraceParams::default();
    vec![
        (d, true),
        (TraceParams { eps_scale: 0.5, eps: 0.01, t_max: 1.5, t_min_scale: 1.0, ..d }, true),
        (TraceParams { cull_backfaces: true, linear_radiance: true, radiance_sh_degree: 1, ..d }, true),
        (TraceParams { visibility_alpha_gain: 2.0, ..d }, false),
    ]
}

/// The hits the CPU march consumes along `ray` (its stop rule: T < t_stop, and for the
/// visibility march also the visibility transmittance below v_cut).
fn cpu_hits(bvh: &Bvh, ray: &Ray, p: &TraceParams, with_radiance: bool) -> Vec<svgir_trace::Hit> {
    let (mut t, mut tv) = (1.0f32, 1.0f32);
    let mut out = Vec::new();
    bvh.for_each_hit(ray, p, |h| {
        out.push(*h);
        t *= 1.0 - h.alpha;
        tv *= 1.0 - (h.alpha * p.visibility_alpha_gain).min(0.99);
        t >= p.t_stop && (with_radiance || tv >= p.v_cut)
    });
    out
}

/// The ray the GPU traced for sample (j, k), rebuilt on the CPU from its recorded direction.
fn ray_of(s: &Surfels, j: usize, rec: &RecordedRay, p: &TraceParams) -> Ray {
    Ray::from_gaussian(s, j, rec.dir, p)
}

#[test]
fn gpu_march_consumes_the_cpu_hits_in_order() {
    let Some(gpu) = common::gpu() else { return };
    let tracer = GpuTracer::new(gpu);
    let k = 16;
    let mut rays = 0usize;
    let mut long = 0usize;
    let mut total = 0usize;
    for (name, s) in [("random", random_scene(1500, 11)), ("object", object_scene(2500, 12))] {
        let bvh = Bvh::build(&s);
        for (vi, (p, with_radiance)) in variants().into_iter().enumerate() {
            let rec = tracer.record(&bvh, &s, request(&s, k, 5, &p, with_radiance), RECORD).expect("GPU trace");
            assert_eq!(rec.len(), s.len() * k);
            let mut bad = Vec::new();
            for (r, g) in rec.iter().enumerate() {
                let j = r / k;
                let cpu = cpu_hits(&bvh, &ray_of(&s, j, g, &p), &p, with_radiance);
                total += cpu.len();
                long += usize::from(cpu.len() > 16);
                let same = cpu.len() == g.hits as usize
                    && cpu.iter().zip(&g.recorded).all(|(c, h)| {
                        c.id == h.id
                            && (c.t - h.t).abs() <= 1e-5 * c.t.abs().max(1.0)
                            && (c.alpha - h.alpha).abs() <= 1e-5 * c.alpha + 1e-7
                            && (c.u - h.u).abs() <= 1e-4
                            && (c.v - h.v).abs() <= 1e-4
                    });
                if !same {
                    bad.push((r, cpu.iter().take(6).map(|h| (h.id, h.t)).collect::<Vec<_>>(), g.clone()));
                }
            }
            rays += rec.len();
            assert!(
                bad.is_empty(),
                "{name} variant {vi}: {} of {} rays differ, first {:?}",
                bad.len(),
                rec.len(),
                bad[0]
            );
        }
    }
    // The comparison must have met long hit lists (k-buffer restarts), not only short ones.
    assert!(total > 50_000 && long > 200, "weak test: {total} hits over {rays} rays, {long} with > 16");
}

#[test]
fn gpu_samples_are_the_cpu_march_of_the_same_rays_packed() {
    let Some(gpu) = common::gpu() else { return };
    let tracer = GpuTracer::new(gpu);
    let (k, seed) = (16, 7);
    let s = object_scene(2500, 21);
    let bvh = Bvh::build(&s);
    for (p, with_radiance) in variants() {
        let normals: Vec<Vec3> = (0..s.len()).map(|j| s.normal(j)).collect();
        let req = TraceRequest { axes: normals, k, seed, params: &p, radiance: with_radiance };
        let mb = tracer.micro_buffer(&bvh, &s, req.clone()).expect("GPU trace");
        let rec = tracer.record(&bvh, &s, req, 1).expect("GPU trace");
        let (mut hits, mut partial) = (0, 0);
        for (r, g) in rec.iter().enumerate() {
            let (j, kk) = (r / k, r % k);
            let ray = ray_of(&s, j, g, &p);
            let (v, l, first) = if with_radiance {
                let m = svgir_trace::march(&bvh, &s.sh, s.sh_degree, &ray, &p);
                (m.visibility, m.radiance, m.first)
            } else {
                let o = svgir_trace::march_visibility(&bvh, &ray, &p);
                (o.visibility, [0.0; 3], o.first)
            };
            assert!((mb.visibility(j, kk) - v).abs() <= 2e-5, "V at {r}: {} vs {v}", mb.visibility(j, kk));
            let lg = mb.radiance(j, kk);
            for c in 0..3 {
                assert!((lg[c] - l[c]).abs() <= 1e-3 * l[c] + 1e-6, "L at {r}: {lg:?} vs {l:?}");
            }
            assert_eq!(mb.hit(j, kk), first.map(|h| h.id), "first hit at {r}");
            if let Some(h) = first {
                hits += 1;
                let uv = h.uv_normalised();
                let ug = mb.uv(j, kk);
                assert!((ug[0] - uv[0]).abs() <= 3e-5 && (ug[1] - uv[1]).abs() <= 3e-5, "uv at {r}");
            }
            partial += usize::from(v > 0.0 && v < 0.99);
        }
        assert!(hits > 2000 && partial > 200, "weak test: {hits} hits, {partial} partial V");
    }
}

#[test]
fn gpu_micro_buffers_match_the_cpu_trace() {
    let Some(gpu) = common::gpu() else { return };
    let tracer = GpuTracer::new(gpu);
    let (k, seed) = (32, 3);
    let s = object_scene(3000, 31);
    let bvh = Bvh::build(&s);
    let p = TraceParams { linear_radiance: true, ..TraceParams::default() };
    let front: Vec<Vec3> = (0..s.len()).map(|j| s.normal(j)).collect();
    // Front, back, and rays from the first 60% alone, the rest being surroundings.
    let sources = s.len() * 3 / 5;
    for axes in [front.clone(), front.iter().map(|n| -*n).collect(), front[..sources].to_vec()] {
        let cpu = MicroBuffer::trace_about(&bvh, &s, axes.clone(), k, seed, &p).unwrap();
        if axes.len() < s.len() {
            let on = cpu.surroundings_hits();
            assert!(on > cpu.first_hit.len() / 20, "weak test: {on} rays on the surroundings");
        }
        let req = TraceRequest { axes: axes.clone(), k, seed, params: &p, radiance: true };
        let g = tracer.micro_buffer(&bvh, &s, req.clone()).expect("GPU trace");
        assert_eq!((g.k, &g.normals, &g.xi, g.interleave), (cpu.k, &cpu.normals, &cpu.xi, cpu.interleave));
        // The directions differ by f32 rounding alone (HemiFrame against hemisphere_dir), so a
        // sample differs only where a hit sits on a boundary of the rules.
        let n = cpu.first_hit.len();
        let same_hit = cpu.first_hit.iter().zip(&g.first_hit).filter(|(a, b)| a == b).count();
        let dv: Vec<f32> = (0..n).map(|i| (from_unorm16(cpu.vis[i]) - from_unorm16(g.vis[i])).abs()).collect();
        let dl: Vec<f32> = (0..n)
            .map(|i| (0..3).map(|c| (f16_to_f32(cpu.radiance[i][c]) - f16_to_f32(g.radiance[i][c])).abs()).sum())
            .collect();
        let far_v = dv.iter().filter(|&&d| d > 1e-3).count();
        let far_l = dl.iter().filter(|&&d| d > 1e-2).count();
        assert!(n - same_hit <= n / 2000, "first hits differ on {} of {n} samples", n - same_hit);
        assert!(far_v <= n / 1000 && far_l <= n / 1000, "V differs on {far_v}, L on {far_l} of {n}");
        assert!(cpu.first_hit.iter().filter(|&&h| h != NO_HIT).count() > n / 10, "weak test: few hits");
        // The occlusion-only trace is the full one without L, to the bit.
        let occ = tracer.micro_buffer(&bvh, &s, TraceRequest { radiance: false, ..req }).expect("GPU trace");
        assert_eq!((&occ.vis, &occ.first_hit, &occ.uv), (&g.vis, &g.first_hit, &g.uv));
        assert!(occ.radiance.iter().all(|l| *l == [0; 3]));
    }
}

#[test]
fn gpu_trace_refuses_what_the_cpu_refuses() {
    let Some(gpu) = common::gpu() else { return };
    let tracer = GpuTracer::new(gpu);
    let s = random_scene(50, 1);
    let bvh = Bvh::build(&s);
    let p = TraceParams::default();
    let req = |n: usize, k: usize| TraceRequest { axes: vec![Vec3::Z; n], k, seed: 1, params: &p, radiance: true };
    assert!(tracer.micro_buffer(&bvh, &s, req(50, 0)).is_err(), "K = 0");
    assert!(tracer.micro_buffer(&bvh, &s, req(51, 8)).is_err(), "axes for 51 of 50");
    let other = Bvh::build(&random_scene(40, 2));
    assert!(tracer.micro_buffer(&other, &s, req(50, 8)).is_err(), "BVH of other surfels");
    let e = Surfels::default();
    let mb = tracer.micro_buffer(&Bvh::build(&e), &e, req(0, 8)).unwrap();
    assert!(mb.is_empty() && mb.vis.is_empty());
}

/// The directional lights' visibility columns (`MicroTracer::visibility_columns`, behind
/// `BrightLights::trace` and `for_normals`) against the CPU's: the same rays, so the same
/// values but where a crossing's rounding moves a hit over a rule's boundary, and the same
/// zeros below every Gaussian's hemisphere (bit-equal on lavapipe).
#[test]
fn gpu_light_columns_match_the_cpu_ones() {
    let Some(gpu) = common::gpu() else { return };
    let tracer = GpuTracer::new(gpu);
    let mut rng = svgir_core::Rng::new(3);
    let dirs: Vec<Vec3> = (0..12).map(|_| Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize()).collect();
    let p = TraceParams::default();
    for (name, s) in [("random", random_scene(1500, 21)), ("object", object_scene(2500, 22))] {
        let bvh = Bvh::build(&s);
        let mut axes: Vec<Vec3> = (0..s.len()).map(|j| s.normal(j)).collect();
        if name == "object" {
            // Columns from the first 60% alone, the rest being surroundings.
            axes.truncate(s.len() * 3 / 5);
        }
        let cpu = svgir_trace::ColumnTracer::columns(&bvh, &s, &axes, &dirs, &p).unwrap();
        assert!(cpu.iter().all(|c| c.len() == axes.len()));
        let gpu = tracer.columns(&bvh, &s, &axes, &dirs, &p).unwrap();
        assert_eq!(gpu.len(), dirs.len());
        let (mut n, mut far, mut shadowed) = (0, 0, 0);
        for (b, (c, g)) in cpu.iter().zip(&gpu).enumerate() {
            for (j, (&x, &y)) in c.iter().zip(g).enumerate() {
                n += 1;
                if axes[j].dot(dirs[b]) <= 0.0 {
                    assert_eq!((x, y), (0, 0), "{name}: light {b} below Gaussian {j}");
                }
                shadowed += usize::from(x < 65535 && axes[j].dot(dirs[b]) > 0.0);
                far +=
                    usize::from(from_unorm16(x) - from_unorm16(y) > 1e-3 || from_unorm16(y) - from_unorm16(x) > 1e-3);
            }
        }
        eprintln!("{name}: {far} of {n} visibilities differ ({shadowed} shadowed)");
        assert!(far <= n / 2000, "{name}: {far} of {n} visibilities differ");
        assert!(shadowed > n / 20, "{name}: weak test, {shadowed} of {n} shadowed");
    }
    assert!(tracer
        .columns(&Bvh::build(&random_scene(10, 1)), &random_scene(10, 1), &[Vec3::Z; 10], &[], &p)
        .unwrap()
        .is_empty());
}
