//! Tracing with surroundings: rays leave only the first Gaussians (the object), the rest (a
//! box under the ball of `object_scene`) occlude and carry radiance. Checked against the trace
//! of every Gaussian: the object's rows must be the same samples, with hits on the
//! surroundings recorded as `SURROUNDINGS_HIT` with their index, and the gather must treat those
//! as neither a bounce nor an escape; relighting adds their captured colour, relit.

use glam::Vec3;
use svgir_core::{EnvMap, Surfels};
use svgir_trace::scenes::object_scene;
use svgir_trace::{
    gather_all, BrightLights, Bvh, GatherParams, MicroBuffer, TraceParams, VertexMaterials, NO_HIT, SURROUNDINGS_HIT,
};

/// The ball's Gaussians first, then the box's.
fn ball_then_box(n: usize) -> (Surfels, usize) {
    let s = object_scene(n, 7);
    let ball: Vec<bool> = (0..n).map(|i| i % 5 < 3).collect();
    let mut order: Vec<usize> = (0..n).filter(|&i| ball[i]).collect();
    let n_ball = order.len();
    order.extend((0..n).filter(|&i| !ball[i]));
    let mut s = s;
    s.reorder(&order);
    (s, n_ball)
}

/// The ball-then-box scene of `n` Gaussians, its BVH, every Gaussian's normal and the trace of
/// all of them at K = `k`: what the object's own trace is compared with.
fn traced_whole(n: usize, k: usize, seed: u64) -> (Surfels, usize, Bvh, Vec<Vec3>, MicroBuffer) {
    let (s, n0) = ball_then_box(n);
    let bvh = Bvh::build(&s);
    let all: Vec<Vec3> = (0..s.len()).map(|j| s.normal(j)).collect();
    let full = MicroBuffer::trace_about(&bvh, &s, all.clone(), k, seed, &TraceParams::default()).unwrap();
    (s, n0, bvh, all, full)
}

#[test]
fn object_rows_equal_the_full_trace_with_surroundings_hits_marked() {
    let k = 32;
    let (s, n0, bvh, all, full) = traced_whole(2500, k, 3);
    let p = TraceParams::default();
    let part = MicroBuffer::trace_about(&bvh, &s, all[..n0].to_vec(), k, 3, &p).unwrap();
    assert_eq!(part.len(), n0);
    let rows = n0 * k;
    assert_eq!(part.vis, full.vis[..rows]);
    assert_eq!(part.radiance, full.radiance[..rows]);
    let mut on_surroundings = 0;
    for (i, (&a, &b)) in part.first_hit.iter().zip(&full.first_hit[..rows]).enumerate() {
        if b != NO_HIT && b as usize >= n0 {
            // The hit's surroundings index in place of its coordinates.
            assert_eq!(a, SURROUNDINGS_HIT, "sample {i}");
            assert_eq!(part.surroundings_hit(i / k, i % k), Some(b - n0 as u32), "sample {i}");
            on_surroundings += 1;
        } else {
            assert_eq!((a, part.uv[i]), (b, full.uv[i]), "sample {i}");
            assert_eq!(part.surroundings_hit(i / k, i % k), None);
        }
    }
    // The ball sits on the box: a good share of its downward rays end there.
    assert!(on_surroundings > rows / 20, "weak test: {on_surroundings} of {rows} rays on the box");
    assert_eq!(part.surroundings_hits(), on_surroundings);
    assert!((0..n0).all(|j| (0..k).all(|kk| part.hit(j, kk).is_none_or(|h| (h as usize) < n0))));

    // The lights' columns: the object's rows of the full columns.
    let geom = EnvMap::constant(32, 16, [0.0; 3]);
    let texels = [3u32, 100, 400];
    let full_l = BrightLights::trace(&bvh, &s, &all, &geom, &texels, &p, None).unwrap();
    let part_l = BrightLights::trace(&bvh, &s, &all[..n0], &geom, &texels, &p, None).unwrap();
    assert_eq!(part_l.len(), texels.len());
    for b in 0..texels.len() {
        for j in 0..n0 {
            assert_eq!(part_l.visibility(j, b), full_l.visibility(j, b), "light {b}, Gaussian {j}");
        }
    }
    assert!(part_l.check(n0, 32, 16).is_ok());
    assert!(BrightLights::trace(&bvh, &s, &[all.clone(), vec![Vec3::Z]].concat(), &geom, &texels, &p, None).is_err());
}

#[test]
fn the_gather_takes_no_bounce_off_the_surroundings_and_sees_no_escape_through_them() {
    let k = 24;
    let (s, n0, bvh, all, full) = traced_whole(2000, k, 5);
    let p = TraceParams::default();
    let part = MicroBuffer::trace_about(&bvh, &s, all[..n0].to_vec(), k, 5, &p).unwrap();
    let n = s.len();
    let albedo: Vec<f32> = (0..n * 3).map(|i| 0.2 + 0.6 * ((i * 37 % 101) as f32 / 101.0)).collect();
    let rough: Vec<f32> = (0..n).map(|i| 0.3 + 0.6 * ((i * 53 % 97) as f32 / 97.0)).collect();
    let normals: Vec<f32> = all.iter().flat_map(|v| v.to_array()).collect();
    let env = EnvMap::constant(32, 16, [1.0, 0.8, 0.6]);
    let gp = GatherParams::default();
    let full_mats = VertexMaterials { m: 1, albedo: &albedo, roughness: &rough, normals: &normals };
    let part_mats =
        VertexMaterials { m: 1, albedo: &albedo[..n0 * 3], roughness: &rough[..n0], normals: &normals[..n0 * 3] };
    let want = gather_all(&full, &full_mats, &env, &gp).unwrap();
    let got = gather_all(&part, &part_mats, &env, &gp).unwrap();
    let (mut off_ball, mut off_box) = (0, 0);
    for i in 0..n0 * k {
        match full.first_hit[i] {
            NO_HIT => assert_eq!(got[i], [0.0; 3]),
            h if (h as usize) < n0 => {
                // The same hit's escapes in both: its rays onto the box are occluded in both.
                assert_eq!(got[i], want[i], "sample {i}");
                off_ball += 1;
            }
            _ => {
                assert_eq!(got[i], [0.0; 3], "sample {i}: no bounce off the surroundings");
                off_box += usize::from(want[i] != [0.0; 3]);
            }
        }
    }
    assert!(off_ball > 100 && off_box > 100, "weak test: {off_ball} / {off_box}");
    // Were the surroundings' hits escapes, the ball's bounce would gain light.
    let mut leaky = part.clone();
    for h in leaky.first_hit.iter_mut().filter(|h| **h == SURROUNDINGS_HIT) {
        *h = NO_HIT;
    }
    let leak = gather_all(&leaky, &part_mats, &env, &gp).unwrap();
    let sum = |v: &[[f32; 3]]| v.iter().map(|c| c[0] as f64).sum::<f64>();
    assert!(sum(&leak) > sum(&got) * 1.01, "leak {} vs {}", sum(&leak), sum(&got));
}

/// Relighting's light off the surroundings: each ray ending on them brings the colour the full
/// trace's hit Gaussian shows along the ray, times the new map's gain for the side it meets;
/// under the learned map itself the gain is 1, so that is the captured colour to the bit.
#[test]
fn rays_ending_on_the_surroundings_bring_their_colour_relit() {
    use svgir_trace::{add_surroundings_light, hit_colour, LearnedIrradiance, SurroundingsGain};
    let k = 24;
    let (s, n0, bvh, all, full) = traced_whole(2000, k, 5);
    let p = TraceParams::default();
    let part = MicroBuffer::trace_occlusion_about(&bvh, &s, all[..n0].to_vec(), k, 5, &p).unwrap();
    let mut around = s.clone();
    around.retain(&(0..s.len()).map(|i| i >= n0).collect::<Vec<_>>());
    let learned_map = EnvMap::constant(32, 16, [0.8, 1.0, 1.2]);
    let learned = LearnedIrradiance::new(&around, &learned_map);
    assert_eq!(learned.len(), s.len() - n0);

    let same = SurroundingsGain::new(&learned, &learned_map);
    let start: Vec<[f32; 3]> = (0..n0 * k).map(|i| [i as f32 * 1e-4, 0.0, 0.5]).collect();
    let mut light = start.clone();
    let count = add_surroundings_light(&part, &around, &same, &p, &mut light).unwrap();
    assert_eq!(count, part.surroundings_hits());
    assert!(count > n0 * k / 20, "weak test: {count} rays on the box");
    for i in 0..n0 * k {
        let (j, kk) = (i / k, i % k);
        match full.first_hit[i] {
            h if h != NO_HIT && h as usize >= n0 => {
                let c = hit_colour(&s.sh[h as usize], s.sh_degree, part.direction(j, kk), &p);
                let want: [f32; 3] = std::array::from_fn(|ch| start[i][ch] + c[ch]);
                assert_eq!(light[i], want, "sample {i}");
            }
            _ => assert_eq!(light[i], start[i], "sample {i}: not on the surroundings"),
        }
    }
    // Twice the light: twice the colour, but for the gain's small epsilon.
    let double = SurroundingsGain::new(&learned, &EnvMap::constant(32, 16, [1.6, 2.0, 2.4]));
    let mut twice = vec![[0.0; 3]; n0 * k];
    add_surroundings_light(&part, &around, &double, &p, &mut twice).unwrap();
    for i in 0..n0 * k {
        for ch in 0..3 {
            let once = light[i][ch] - start[i][ch];
            assert!((twice[i][ch] - 2.0 * once).abs() <= 2e-3 * once + 1e-6, "sample {i}");
        }
    }
    // Inputs that do not belong together are refused.
    let mut short = vec![[0.0; 3]; n0 * k - 1];
    assert!(add_surroundings_light(&part, &around, &same, &p, &mut short).is_err());
    let mut few = around.clone();
    few.retain(&(0..around.len()).map(|i| i < 3).collect::<Vec<_>>());
    let few_gain = SurroundingsGain::new(&LearnedIrradiance::new(&few, &learned_map), &learned_map);
    assert!(add_surroundings_light(&part, &few, &few_gain, &p, &mut light).is_err());
}
