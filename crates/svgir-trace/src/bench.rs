//! Timing table for `svgir bench trace`: BVH build, ray throughput (all-hits march, the
//! visibility-only march and first hit),
//! K = 64 micro-buffer fill and the one-bounce gather over it (Eqn 13, M = 4, a constant map) on
//! [`crate::scenes::object_scene`] scenes of 10k / 100k / 300k surfels, on 1 thread and on
//! `threads` threads (each in its own rayon pool).

use crate::scenes::{object_scene, rays_for, RAYS};
use crate::traverse::{march, march_visibility, HitSource, TraceParams};
use crate::{gather_all, Bvh, GatherParams, MicroBuffer, VertexMaterials};
use rayon::prelude::*;
use std::fmt::Write;
use std::time::Instant;

fn header(out: &mut String) {
    let _ = writeln!(
        out,
        "{:>8} {:>7} {:>10} {:>6} {:>12} {:>12} {:>12} {:>10} {:>10} {:>9} {:>9}",
        "surfels",
        "threads",
        "build ms",
        "depth",
        "march Mray/s",
        "V only Mray/s",
        "first Mray/s",
        "hits/ray",
        "mb fill s",
        "mb MB",
        "gather s"
    );
}

/// How much the surfels' hittable disks overlap, which sets a ray's work more than their count:
/// the median and 90th-percentile disk radius (the reach `bounds` gives a hit: sqrt(min(9,
/// 2 ln(255 o))) sigma along the larger axis) as a share of the centres' bounding-box diagonal,
/// and the disks' summed area over the area of that diagonal's disk (`sum r^2 / (d/2)^2`): how
/// many disks a ray through the scene's middle meets, roughly, if they all faced it.
pub fn coverage(s: &svgir_core::Surfels) -> (f32, f32, f32) {
    if s.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let (lo, hi) =
        s.positions.iter().fold((glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY), |(a, b), p| (a.min(*p), b.max(*p)));
    let diag = (hi - lo).length().max(1e-12);
    let mut r: Vec<f32> =
        (0..s.len()).map(|i| crate::hit::reach_sigma(s.opacity(i)) * s.scale(i).max_element() / diag).collect();
    let overlap = r.iter().map(|x| 4.0 * x * x).sum::<f32>();
    r.sort_by(f32::total_cmp);
    let at = |q: f32| r[((r.len() - 1) as f32 * q) as usize];
    (at(0.5), at(0.9), overlap)
}

fn coverage_line(out: &mut String, s: &svgir_core::Surfels) {
    let (median, p90, overlap) = coverage(s);
    let _ = writeln!(
        out,
        "  disk radius median {:.4}, 90th percentile {:.4} of the diagonal; overlap {overlap:.1} (sum r^2 / (diagonal/2)^2)",
        median, p90
    );
}

/// One row per thread count (1 and `threads`) for the surfels `s`.
fn scene_rows(out: &mut String, s: &svgir_core::Surfels, threads: usize) {
    let mut counts = vec![1usize];
    if threads > 1 {
        counts.push(threads);
    }
    let p = TraceParams::default();
    let rays = rays_for(s, &p, 2);
    for &t in &counts {
        let pool = match rayon::ThreadPoolBuilder::new().num_threads(t).build() {
            Ok(pool) => pool,
            Err(e) => {
                let _ = writeln!(out, "cannot build a {t}-thread pool: {e}");
                return;
            }
        };
        pool.install(|| {
            let t0 = Instant::now();
            let bvh = Bvh::build(s);
            let build = t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let hits: u64 = rays.par_iter().map(|r| march(&bvh, &s.sh, s.sh_degree, r, &p).hits as u64).sum();
            let all = t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let vis: f64 = rays.par_iter().map(|r| march_visibility(&bvh, r, &p).visibility as f64).sum();
            let vis_only = t0.elapsed().as_secs_f64();
            std::hint::black_box(vis);
            let t0 = Instant::now();
            let firsts = rays.par_iter().filter(|r| bvh.first_hit(r, &p).is_some()).count();
            let first = t0.elapsed().as_secs_f64();
            std::hint::black_box(firsts);
            let t0 = Instant::now();
            let mb = MicroBuffer::trace(&bvh, s, 64, 3, &p);
            let fill = t0.elapsed().as_secs_f64();
            let mb_mb = mb.as_ref().map(|m| m.memory_bytes() as f64 / 1e6).unwrap_or(f64::NAN);
            let gather = mb.as_ref().map(gather_seconds).unwrap_or(f64::NAN);
            let _ = writeln!(
                out,
                "{:>8} {:>7} {:>10.1} {:>6} {:>12.2} {:>12.2} {:>12.2} {:>10.2} {:>10.2} {:>9.0} {:>9.2}",
                s.len(),
                t,
                build * 1e3,
                bvh.depth(),
                RAYS as f64 / all / 1e6,
                RAYS as f64 / vis_only / 1e6,
                RAYS as f64 / first / 1e6,
                hits as f64 / RAYS as f64,
                fill,
                mb_mb,
                gather
            );
        });
    }
}

/// One row per (surfel count, thread count); `sizes` defaults to 10k, 100k, 300k.
pub fn bench_table_sizes(threads: usize, sizes: &[usize]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "svgir-trace: object_scene surfels, K = 64, default TraceParams (eps 0.05, start at own 3-sigma rim)"
    );
    header(&mut out);
    for &n in sizes {
        let s = object_scene(n, 1);
        scene_rows(&mut out, &s, threads);
        coverage_line(&mut out, &s);
    }
    out
}

/// The same table for trained surfels (`svgir bench trace --ply`), labelled `label`: their
/// rays meet the stacked, semi-transparent surfels of a real surface, where the random object
/// scene's mostly escape.
pub fn bench_table_scene(threads: usize, s: &svgir_core::Surfels, label: &str) -> String {
    let mut out = format!("svgir-trace: {label} ({} surfels), K = 64, default TraceParams\n", s.len());
    header(&mut out);
    scene_rows(&mut out, s, threads);
    coverage_line(&mut out, s);
    out
}

/// Seconds for Eqn 13 over every sample of `mb` (M = 4 grey vertices, roughness 0.5, a 16 x 32
/// constant map).
fn gather_seconds(mb: &MicroBuffer) -> f64 {
    let m = 4;
    let albedo = vec![0.5f32; mb.len() * m * 3];
    let roughness = vec![0.5f32; mb.len() * m];
    let normals: Vec<f32> = mb.normals.iter().flat_map(|n| std::iter::repeat_n(n.to_array(), m)).flatten().collect();
    let mats = VertexMaterials { m, albedo: &albedo, roughness: &roughness, normals: &normals };
    let env = svgir_core::EnvMap::constant(32, 16, [1.0; 3]);
    let t0 = Instant::now();
    match gather_all(mb, &mats, &env, &GatherParams::default()) {
        Ok(l) => {
            std::hint::black_box(l);
            t0.elapsed().as_secs_f64()
        }
        Err(_) => f64::NAN,
    }
}

/// The table for `svgir bench trace` at the standard sizes.
pub fn bench_table(threads: usize) -> String {
    bench_table_sizes(threads, &[10_000, 100_000, 300_000])
}

#[cfg(test)]
mod tests {
    use super::coverage;
    use glam::{Quat, Vec2, Vec3};
    use svgir_core::surfel::logit;

    /// Opaque disks reach 3 sigma, one at opacity 1/255 nothing; radii are shares of the
    /// diagonal and the overlap sums `(2 r)^2`.
    #[test]
    fn coverage_of_known_disks() {
        let mut s = svgir_core::Surfels::with_capacity(3, 0);
        let sh = Default::default();
        let ln = |x: f32| Vec2::splat(x.ln());
        s.push(Vec3::ZERO, Quat::IDENTITY, ln(0.1), logit(0.999_999), sh);
        s.push(Vec3::new(1.0, 0.0, 0.0), Quat::IDENTITY, Vec2::new(0.05f32.ln(), 0.1f32.ln()), logit(0.999_999), sh);
        s.push(Vec3::new(0.5, 0.0, 0.0), Quat::IDENTITY, ln(0.2), logit(1.0 / 255.0), sh);
        let (median, p90, overlap) = coverage(&s);
        assert!((median - 0.3).abs() < 1e-4, "{median}");
        assert!((p90 - 0.3).abs() < 1e-4, "{p90}");
        assert!((overlap - 2.0 * 0.36).abs() < 1e-3, "{overlap}");
    }
}
