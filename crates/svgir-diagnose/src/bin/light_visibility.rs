//! Diagnostic: how the directional lights see a stage-2 model. Loads `RUN/stage2/checkpoint.bin`
//! (or the checkpoint given), makes the `count` brightest texels of MAP (scaled by STRENGTH)
//! the lights, and prints per light the power share and, bucketed by `n . d` (the cosine
//! between a Gaussian's geometric normal and the light), how many Gaussians face it and their
//! mean traced visibility. Low visibility at grazing cosines means the surfel's own surface
//! occludes the light (neighbouring coplanar disks).
//!
//! `cargo run --release -p svgir-diagnose --bin light_visibility -- CKPT MAP STRENGTH [COUNT]`

use anyhow::{Context, Result};
use svgir_trace::brightest_texels;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() >= 4, "usage: light_visibility CHECKPOINT MAP.hdr STRENGTH [COUNT]");
    let mut s2 = svgir_train::checkpoint::load_stage2(std::path::Path::new(&args[1]))?;
    let strength: f32 = args[3].parse().context("STRENGTH")?;
    let count: usize = args.get(4).map_or(Ok(4), |c| c.parse()).context("COUNT")?;
    let map = svgir_io::read_envmap(&args[2], strength, s2.config.env_height)?;
    s2.set_lights(&brightest_texels(&map, count))?;
    let l = &s2.lights;
    let total: f64 = (0..map.height)
        .flat_map(|r| (0..map.width).map(move |c| (r, c)))
        .map(|(r, c)| {
            let t = map.data[(r * map.width + c) as usize];
            (t[0] + t[1] + t[2]) as f64 / 3.0 * map.texel_solid_angle(r, c) as f64
        })
        .sum();
    println!("{} Gaussians, {} lights", s2.surfels.len(), l.len());
    for b in 0..l.len() {
        let t = map.data[l.texels[b] as usize];
        let power = (t[0] + t[1] + t[2]) as f64 / 3.0 * l.solid_angle[b] as f64;
        println!(
            "light {b}: texel {} dir {:.3} radiance {:.1} power share {:.3}",
            l.texels[b],
            l.dirs[b],
            (t[0] + t[1] + t[2]) / 3.0,
            power / total
        );
        let mut buckets = [(0usize, 0.0f64, 0usize); 5];
        for j in 0..s2.surfels.len() {
            let c = s2.mb.normals[j].dot(l.dirs[b]);
            if c <= 0.0 {
                continue;
            }
            let k = ((c * 5.0) as usize).min(4);
            let v = l.visibility(j, b) as f64;
            buckets[k].0 += 1;
            buckets[k].1 += v;
            buckets[k].2 += (v > 0.0) as usize;
        }
        for (k, (n, vs, seen)) in buckets.iter().enumerate() {
            if *n > 0 {
                println!(
                    "  n.d in [{:.1},{:.1}): {n:6} Gaussians, mean V {:.3}, V>0 for {:.1}%",
                    k as f32 / 5.0,
                    (k + 1) as f32 / 5.0,
                    vs / *n as f64,
                    100.0 * *seen as f64 / *n as f64
                );
            }
        }
    }
    Ok(())
}
