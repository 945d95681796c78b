//! Diagnostic: how opaque the traced surfaces are. Loads a stage-2 checkpoint and prints, over
//! every (Gaussian, direction) of its micro-buffers, the histogram of the visibility V split by
//! whether the ray hit anything. On a closed opaque object a ray that hits a surface should end
//! with V = 0; hit rays with V > 0.2 either pass through a surface (too few or too transparent
//! surfels along the ray) or only graze the faint rim of a surfel; this count cannot tell which.
//!
//! `cargo run --release -p svgir-diagnose --bin microbuffer_stats -- CHECKPOINT`

use anyhow::Result;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() >= 2, "usage: microbuffer_stats CHECKPOINT");
    let s2 = svgir_train::checkpoint::load_stage2(std::path::Path::new(&args[1]))?;
    let mb = &s2.mb;
    let edges = [0.0f32, 0.2, 0.5, 0.9, 1.01];
    let mut hit = [0usize; 4];
    let mut miss = [0usize; 4];
    for j in 0..mb.len() {
        for k in 0..mb.k {
            let v = mb.visibility(j, k);
            let b = edges.windows(2).position(|w| v >= w[0] && v < w[1]).unwrap_or(3);
            if mb.hit(j, k).is_some() {
                hit[b] += 1;
            } else {
                miss[b] += 1;
            }
        }
    }
    let total = (mb.len() * mb.k) as f64;
    println!("{} Gaussians x {} directions", mb.len(), mb.k);
    println!("V bucket      hit     miss   (fractions of all rays)");
    for b in 0..4 {
        println!(
            "[{:.1},{:.1})  {:.4}  {:.4}",
            edges[b],
            edges[b + 1].min(1.0),
            hit[b] as f64 / total,
            miss[b] as f64 / total
        );
    }
    Ok(())
}
