//! Diagnostic: where a model's micro-buffer rays spend their work. For a PLY it traces the
//! K = 16 micro-buffer directions of every `--every`-th Gaussian (SPEC 5's rays: from the
//! Gaussian's centre over its oriented hemisphere, starting at its own 3-sigma rim) and prints,
//! over the hits the march consumes (SPEC 5: until T < 1e-3):
//! - hits per ray, and the share of rays with more than 4 and more than 16;
//! - the hits by distance from the ray's start, in multiples of the source surfel's 3-sigma
//!   radius: a hit within 2 of them lies on the source's own surface (its neighbours' disks, or a
//!   layer stacked on it), one beyond 10 is another part of the scene;
//! - the hits by alpha: faint ones (under 0.05) barely occlude but cost as much as any;
//! - the transmittance the rays end with.
//!
//! The trace bench (`svgir bench trace`) times the same rays; this says why a trained model
//! costs more per ray than its random scenes.
//!
//! `cargo run --release -p svgir-diagnose --bin trace_hits -- PLY [--every N]`

use anyhow::{bail, Result};
use clap::Parser;
use rayon::prelude::*;
use std::path::PathBuf;
use svgir_shading::{gaussian_xi, hemisphere_dir};
use svgir_trace::{Bvh, HitSource, Ray, TraceParams};

/// Directions per traced Gaussian.
const K: usize = 16;

/// Where the micro-buffer rays of a model spend their work (see the file's docs).
#[derive(Parser)]
struct Args {
    /// The model: a run's point_cloud.ply (3DGS / 2DGS / svgir layout).
    ply: PathBuf,
    /// Trace every N-th Gaussian's rays.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
}

/// Per ray: hits, and per hit (distance from the ray's start over the source's 3-sigma radius,
/// alpha); the final transmittance.
struct RayHits {
    hits: Vec<(f32, f32)>,
    transmittance: f32,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let (surfels, _) = svgir_io::read_gaussians_ply(&args.ply)?;
    if surfels.is_empty() {
        bail!("{}: no Gaussians", args.ply.display());
    }
    let p = TraceParams::default();
    let bvh = Bvh::build(&surfels);
    // The micro-buffer's directions (MicroBuffer::trace: each surfel's normal, seed 0).
    let sources: Vec<usize> = (0..surfels.len()).step_by(args.every as usize).collect();
    let rays: Vec<RayHits> = sources
        .par_iter()
        .flat_map_iter(|&j| {
            let radius = 3.0 * surfels.scale(j).max_element();
            let (normal, xi) = (surfels.normal(j), gaussian_xi(0, j));
            let (bvh, surfels) = (&bvh, &surfels);
            (0..K).map(move |k| {
                let ray = Ray::from_gaussian(surfels, j, hemisphere_dir(normal, k, K, xi), &p);
                let mut hits = Vec::new();
                let mut t = 1.0f32;
                bvh.for_each_hit(&ray, &p, |h| {
                    hits.push(((h.t - ray.t_start) / radius.max(1e-12), h.alpha));
                    t *= 1.0 - h.alpha;
                    t >= p.t_stop
                });
                RayHits { hits, transmittance: t }
            })
        })
        .collect();
    let n = rays.len() as f64;
    let hits: Vec<(f32, f32)> = rays.iter().flat_map(|r| r.hits.iter().copied()).collect();
    let h = hits.len().max(1) as f64;
    let share = |f: &dyn Fn(&(f32, f32)) -> bool| hits.iter().filter(|x| f(x)).count() as f64 / h;
    let rays_over = |m: usize| rays.iter().filter(|r| r.hits.len() > m).count() as f64 / n;
    println!("{}: {} Gaussians, {} traced x {K} directions", args.ply.display(), surfels.len(), sources.len());
    println!(
        "hits per ray {:.2}; rays with more than 4 hits {:.1}%, more than 16 {:.1}%",
        hits.len() as f64 / n,
        100.0 * rays_over(4),
        100.0 * rays_over(16)
    );
    println!(
        "hits by distance from the start (source 3-sigma radii): < 2: {:.1}%, 2-10: {:.1}%, > 10: {:.1}%",
        100.0 * share(&|x| x.0 < 2.0),
        100.0 * share(&|x| x.0 >= 2.0 && x.0 <= 10.0),
        100.0 * share(&|x| x.0 > 10.0)
    );
    println!(
        "hits by alpha: < 0.05: {:.1}%, 0.05-0.5: {:.1}%, >= 0.5: {:.1}%",
        100.0 * share(&|x| x.1 < 0.05),
        100.0 * share(&|x| x.1 >= 0.05 && x.1 < 0.5),
        100.0 * share(&|x| x.1 >= 0.5)
    );
    let ended =
        |lo: f32, hi: f32| rays.iter().filter(|r| r.transmittance >= lo && r.transmittance < hi).count() as f64 / n;
    println!(
        "final transmittance: < 0.2 (V = 0): {:.1}%, 0.2-0.9: {:.1}%, >= 0.9: {:.1}%",
        100.0 * ended(0.0, 0.2),
        100.0 * ended(0.2, 0.9),
        100.0 * ended(0.9, 1.01)
    );
    Ok(())
}
