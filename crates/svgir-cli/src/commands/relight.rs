//! `svgir relight --run RUN --envmap X.hdr`: render a stage-2 model under a new environment map
//! (SPEC 7): the map is resampled to the model's light resolution with the area filter, K = 384
//! directions are traced per Gaussian, the one-bounce indirect light is gathered under the map
//! (rho = 1, radiance not clamped), and the dataset's test cameras (and optionally a turntable)
//! are rendered to PNG.

use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;
use svgir_core::{Camera, Image};
use svgir_eval::turntable_cameras;
use svgir_train::checkpoint;
use svgir_train::relight::{RelightSampling, Relighter};

#[derive(Args)]
pub struct RelightArgs {
    /// Stage-1 run folder whose `stage2/` holds the stage-2 checkpoint (from `svgir inverse`).
    #[arg(long)]
    pub run: PathBuf,
    /// Equirectangular HDR or EXR environment map (Blender convention, +Z up).
    #[arg(long)]
    pub envmap: PathBuf,
    /// Radiance = strength x map value.
    #[arg(long, default_value_t = 1.0)]
    pub strength: f32,
    /// Turntable frames to render as well (0: only the dataset's test cameras).
    #[arg(long, default_value_t = 0)]
    pub turntable: usize,
    /// Output folder (default `RUN/stage2/relit_MAP`, MAP the map file name).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Directions per Gaussian (SPEC 7: 384; memory is Gaussians x K x 16 bytes).
    #[arg(long, default_value_t = svgir_train::relight::RELIGHT_DIRECTIONS)]
    pub directions: usize,
    /// Brightest texels of the map shaded as directional lights with traced visibility (0: the
    /// K directions alone, as SPEC 7).
    #[arg(long, default_value_t = svgir_train::relight::RELIGHT_LIGHTS)]
    pub lights: usize,
    /// Diffuse bounces of indirect light added to SPEC 7's one-bounce term (0: Eqn 13 alone).
    #[arg(long, default_value_t = svgir_train::relight::RELIGHT_BOUNCES)]
    pub bounces: usize,
    /// Where to trace the K directions and the lights and shade the renders: auto (a hardware
    /// GPU if any), cpu or gpu.
    #[arg(long, default_value_t = svgir_gpu::DeviceChoice::Auto)]
    pub device: svgir_gpu::DeviceChoice,
}

pub fn run(args: RelightArgs) -> Result<()> {
    let stage2_dir = args.run.join("stage2");
    let cfg_path = stage2_dir.join("config.json");
    let cfg = svgir_eval::read_json(&cfg_path, "run `svgir inverse` first")?;
    let data = PathBuf::from(cfg["data"].as_str().with_context(|| format!("{}: no data path", cfg_path.display()))?);
    let mut s2 = checkpoint::load_stage2(&stage2_dir.join("checkpoint.bin"))?;
    let gpu;
    (s2.kernels, gpu) = super::engine::stage2_kernels(args.device)?;
    let env = svgir_io::read_envmap(&args.envmap, args.strength, s2.config.env_height)?;
    let relighter = Relighter::new(
        &s2,
        RelightSampling { directions: args.directions, lights: args.lights, bounces: args.bounces },
    )?;
    let lit = relighter.prepare(&s2, env)?;
    let name = args.envmap.file_stem().map_or("env".into(), |s| s.to_string_lossy().into_owned());
    let out = args.out.clone().unwrap_or_else(|| stage2_dir.join(format!("relit_{name}")));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let opts = svgir_io::LoadOptions::default();
    let dataset = svgir_io::load_dataset(&data, &opts)?;
    let mut cams: Vec<(String, Camera)> = dataset.test.iter().map(|v| (v.name.clone(), v.camera)).collect();
    if let Some(first) = dataset.test.first().or(dataset.train.first()) {
        for (f, c) in turntable_cameras(&dataset, &first.camera, args.turntable).into_iter().enumerate() {
            cams.push((format!("turntable_{f:03}"), c));
        }
    }
    for (name, cam) in &cams {
        let r = relighter.render(&s2, cam, [0.0; 3], &lit, [1.0; 3])?;
        let img = Image::from_data(r.width, r.height, 3, r.image.iter().map(|c| c.clamp(0.0, 1.0)).collect());
        svgir_io::write_png(out.join(format!("{name}.png")), &img, 8)?;
    }
    println!("relit {} views under {} (x{}): {}", cams.len(), args.envmap.display(), args.strength, out.display());
    // The K-direction relighting buffers are resident: what they cost per surfel.
    if let Some(line) = gpu.as_ref().and_then(|g| super::engine::gpu_memory_line(g, s2.surfels.len())) {
        eprintln!("{line} with the relighting's K = {} micro-buffers", args.directions);
    }
    Ok(())
}
