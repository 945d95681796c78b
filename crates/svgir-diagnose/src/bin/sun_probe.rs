//! Diagnostic: the photo loss of a stage-2 model as a function of its sun's direction. Loads a
//! checkpoint and its dataset, moves the most powerful light (the sun, `Stage2::sun_light`) over a
//! grid of directions (polar angle from +z, azimuth), and prints the mean L1 of the PBR renders of
//! every `EVERY`-th training view against the photos, as the sun search scores it. If the true
//! sun's direction does not score best, the search cannot find it: the geometry, visibility or
//! materials favour another.
//!
//! `--true-light MAP STRENGTH` replaces the learned light by a map (e.g. the training light).
//! `--scale-invariant` scores each view after a least-squares scale per channel.
//! With `--initial-materials` the materials are reset to stage 2's initial ones (as at the first
//! search, before the warm-up releases them), keeping the checkpoint's light.
//!
//! `cargo run --release -p svgir-diagnose --bin sun_probe -- CHECKPOINT DATA [--initial-materials] [EVERY=4] [x,y,z ...]`

use anyhow::{Context, Result};
use glam::Vec3;

fn main() -> Result<()> {
    let mut args: Vec<String> = std::env::args().collect();
    let initial = args.iter().any(|a| a == "--initial-materials");
    let invariant = args.iter().any(|a| a == "--scale-invariant");
    args.retain(|a| a != "--initial-materials" && a != "--scale-invariant");
    anyhow::ensure!(args.len() >= 3, "usage: sun_probe CHECKPOINT DATA [--initial-materials] [EVERY] [x,y,z ...]");
    let mut s2 = svgir_train::checkpoint::load_stage2(std::path::Path::new(&args[1]))?;
    let ds = svgir_io::load_dataset(std::path::Path::new(&args[2]), &svgir_io::LoadOptions::default())?;
    if let Some(i) = args.iter().position(|a| a == "--true-light") {
        anyhow::ensure!(args.len() > i + 2, "--true-light MAP STRENGTH");
        let strength: f32 = args[i + 2].parse().context("STRENGTH")?;
        let map = svgir_io::read_envmap(&args[i + 1], strength, s2.config.env_height)?;
        s2.env = svgir_pbr::EnvLight::from_radiance(&map)?.with_activation(s2.config.env_activation)?;
        s2.set_lights(&svgir_trace::brightest_texels(&map, s2.lights.len().max(1)))?;
        println!("light: {} x {strength}", args[i + 1]);
        args.drain(i..i + 3);
    }
    if initial {
        let fresh = svgir_train::Stage2::new(s2.config.clone(), s2.surfels.clone(), &ds)?;
        s2.materials = fresh.materials;
        println!("materials reset to their initial values");
    }
    let every: usize = args.get(3).map_or(Ok(4), |c| c.parse()).context("EVERY")?;
    let views: Vec<usize> = (0..ds.train.len()).step_by(every.max(1)).collect();
    let b = s2.sun_light().context("the checkpoint has no directional lights")?;
    let now = s2.lights.dirs[b];
    println!("sun = light {b} (texel {}), now at {now:.3}; {} views", s2.lights.texels[b], views.len());
    let probe = |d: Vec3, s2: &mut svgir_train::Stage2| -> Result<f32> {
        s2.move_light(b, d)?;
        Ok(s2.photo_loss(&ds, &views, invariant)?)
    };
    let extra: Vec<Vec3> = args[4.min(args.len())..]
        .iter()
        .map(|a| {
            let v: Vec<f32> = a.split(',').map(|x| x.parse().unwrap_or(f32::NAN)).collect();
            Vec3::new(v[0], v[1], *v.get(2).unwrap_or(&f32::NAN)).normalize()
        })
        .collect();
    println!("current: L1 {:.5}", probe(now, &mut s2)?);
    for d in extra {
        println!("{d:.3}: L1 {:.5}", probe(d, &mut s2)?);
    }
    let azimuths = 8;
    print!("polar\\azimuth");
    for a in 0..azimuths {
        print!(" {:>8}", a * 360 / azimuths);
    }
    println!();
    for polar in (0..=60).step_by(10) {
        print!("{polar:>13}");
        let th = (polar as f32).to_radians();
        for a in 0..azimuths {
            let ph = (a as f32 / azimuths as f32) * std::f32::consts::TAU;
            let d = Vec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
            print!(" {:>8.5}", probe(d, &mut s2)?);
            if polar == 0 {
                break;
            }
        }
        println!();
    }
    Ok(())
}
