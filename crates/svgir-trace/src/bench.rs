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
        scene_rows(&mut out, &object_scene(n, 1), threads);
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
