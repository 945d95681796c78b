//! Tracing with surroundings: rays leave only the first Gaussians (the object), the rest (a
//! box under the ball of `object_scene`) occlude and carry radiance. Checked against the trace
//! of every Gaussian: the object's rows must be the same samples, with hits on the
//! surroundings recorded as `SURROUNDINGS_HIT`, and the gather must treat those as neither a
//! bounce nor an escape.

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

#[test]
fn object_rows_equal_the_full_trace_with_surroundings_hits_marked() {
    let (s, n0) = ball_then_box(2500);
    let bvh = Bvh::build(&s);
    let p = TraceParams::default();
    let k = 32;
    let all: Vec<Vec3> = (0..s.len()).map(|j| s.normal(j)).collect();
    let full = MicroBuffer::trace_about(&bvh, &s, all.clone(), k, 3, &p).unwrap();
    let part = MicroBuffer::trace_about(&bvh, &s, all[..n0].to_vec(), k, 3, &p).unwrap();
    assert_eq!(part.len(), n0);
    let rows = n0 * k;
    assert_eq!(part.vis, full.vis[..rows]);
    assert_eq!(part.radiance, full.radiance[..rows]);
    assert_eq!(part.uv, full.uv[..rows]);
    let mut on_surroundings = 0;
    for (i, (&a, &b)) in part.first_hit.iter().zip(&full.first_hit[..rows]).enumerate() {
        if b != NO_HIT && b as usize >= n0 {
            assert_eq!(a, SURROUNDINGS_HIT, "sample {i}");
            on_surroundings += 1;
        } else {
            assert_eq!(a, b, "sample {i}");
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
    let (s, n0) = ball_then_box(2000);
    let bvh = Bvh::build(&s);
    let p = TraceParams::default();
    let k = 24;
    let all: Vec<Vec3> = (0..s.len()).map(|j| s.normal(j)).collect();
    let full = MicroBuffer::trace_about(&bvh, &s, all.clone(), k, 5, &p).unwrap();
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
