//! svgir's BVH vs Embree 3 on the same surfel disks and rays (first-hit mode, one thread).
//!
//! `cargo run --release -p svgir-trace --example embree_compare -- EMBREE_BIN [N ...]`
//! where EMBREE_BIN is `tools/embree_compare/disks_embree.c` built against Debian's
//! `libembree-dev` (see that file). For each N it writes the scene and the benchmark rays, times
//! svgir's `first_hit`, runs the Embree program on the same file, checks both found the same
//! hits, and prints the throughput ratio.

use rayon::prelude::*;
use std::io::Write;
use std::time::Instant;
use svgir_trace::scenes::object_scene;
use svgir_trace::scenes::rays_for;
use svgir_trace::{disks_of, Bvh, HitSource, TraceParams};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let Some(embree) = args.get(1) else {
        return Err("usage: embree_compare EMBREE_BIN [N ...]".into());
    };
    let sizes: Vec<usize> = if args.len() > 2 {
        args[2..].iter().map(|a| a.parse()).collect::<Result<_, _>>()?
    } else {
        vec![10_000, 100_000, 300_000]
    };
    let p = TraceParams::default();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    println!(
        "{:>8} {:>8} {:>14} {:>14} {:>8} {:>14} {:>14} {:>7}",
        "surfels", "rays", "svgir build ms", "svgir Mray/s", "hits", "embree build", "embree Mray/s", "ratio"
    );
    for n in sizes {
        let s = object_scene(n, 1);
        let rays = rays_for(&s, &p, 2);
        let (build, secs, hits, id_sum) = pool.install(|| {
            let t0 = Instant::now();
            let bvh = Bvh::build(&s);
            let build = t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let found: Vec<Option<u32>> = rays.par_iter().map(|r| bvh.first_hit(r, &p).map(|h| h.id)).collect();
            let secs = t0.elapsed().as_secs_f64();
            let hits = found.iter().flatten().count();
            let id_sum: u64 = found.iter().flatten().map(|&i| i as u64).sum();
            (build, secs, hits, id_sum)
        });
        let path = std::env::temp_dir().join(format!("svgir_embree_{n}.bin"));
        let mut f = std::io::BufWriter::new(std::fs::File::create(&path)?);
        let disks = disks_of(&s);
        f.write_all(&(disks.len() as u32).to_le_bytes())?;
        f.write_all(&(rays.len() as u32).to_le_bytes())?;
        f.write_all(bytemuck::cast_slice(&disks))?;
        for r in &rays {
            for v in [r.origin.x, r.origin.y, r.origin.z, r.dir.x, r.dir.y, r.dir.z, r.t_start] {
                f.write_all(&v.to_le_bytes())?;
            }
            f.write_all(&r.ignore.to_le_bytes())?;
        }
        drop(f);
        let out = std::process::Command::new(embree).arg(&path).output()?;
        std::fs::remove_file(&path).ok();
        let text = String::from_utf8_lossy(&out.stdout);
        let field = |k: &str| -> Option<f64> {
            text.split_whitespace().find_map(|w| w.strip_prefix(&format!("{k}=")).and_then(|v| v.parse().ok()))
        };
        let (Some(eb), Some(erps), Some(eh), Some(eid)) =
            (field("build_ms"), field("rays_per_s"), field("hits"), field("id_sum"))
        else {
            return Err(format!("embree program failed: {}{}", text, String::from_utf8_lossy(&out.stderr)).into());
        };
        let ours = rays.len() as f64 / secs;
        let agree = if eh as usize == hits && eid as u64 == id_sum { "" } else { " (hit sets differ!)" };
        println!(
            "{:>8} {:>8} {:>14.1} {:>14.3} {:>8} {:>14.1} {:>14.3} {:>7.2}{agree}",
            n,
            rays.len(),
            1e3 * build,
            ours / 1e6,
            hits,
            eb,
            erps / 1e6,
            ours / erps
        );
    }
    Ok(())
}
