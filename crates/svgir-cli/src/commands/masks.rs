//! `svgir masks DATASET --out DIR`: foreground masks for an object-centred capture that has
//! none, derived from a stage-1 reconstruction ([`svgir_train::foreground`]), written as one PNG
//! per photo (`DIR/NAME.png`, white = object) at the photo's size, so that a person can check
//! and edit them. Put them in `DATASET/masks/` and the next `svgir train` uses the object profile
//! with SPEC 2's mask and entropy losses.
//!
//! The reconstruction is `--run RUN` (a finished `svgir train` run on this dataset), or, without
//! it, a short capture-profile stage 1 trained here into `--work`.

use super::train;
use super::DataArgs;
use crate::progress;
use anyhow::{bail, Context, Result};
use clap::Args;
use serde_json::json;
use std::path::PathBuf;
use svgir_core::{Image, Rng};
use svgir_train::foreground::{clipped_gaussians, render_share, select_foreground, ForegroundConfig};
use svgir_train::mask_check::check_masks;
use svgir_train::mask_refine::{refine, RefineConfig};

#[derive(Args)]
pub struct MasksArgs {
    /// The capture (COLMAP or transforms.json); masks are made for every photo, train and test.
    pub data: PathBuf,
    /// Folder for the mask PNGs (created); `DATASET/masks` makes the next run use them.
    #[arg(long, short)]
    pub out: PathBuf,
    /// A finished stage-1 run on this dataset to derive the masks from.
    #[arg(long)]
    pub run: Option<PathBuf>,
    /// Without --run: where to train the short stage 1 (default: `runs/masks-NAME`, NAME the dataset folder).
    #[arg(long)]
    pub work: Option<PathBuf>,
    /// Without --run: stage-1 iterations.
    #[arg(long, default_value_t = 3000)]
    pub iterations: u64,
    /// Without --run: train on images downscaled by this factor.
    #[arg(long, default_value_t = 4.0)]
    pub downscale: f32,
    /// Seed of the plane search, the colour models (and of the stage 1 trained here); recorded in foreground.json.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Keep the 3D estimate's edges (no per-photo colour refinement).
    #[arg(long)]
    pub no_refine: bool,
    /// Refinement: half-width of the band where edges may move, as a share of the image diagonal.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = RefineConfig::default().band)]
    pub refine_band: f32,
    /// Refinement: weight of the 3D estimate against the photo's colours.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = RefineConfig::default().prior)]
    pub refine_prior: f32,
}

pub fn run(args: MasksArgs) -> Result<()> {
    let run = match &args.run {
        Some(r) => r.clone(),
        None => train_reconstruction(&args)?,
    };
    let ply = run.join("point_cloud.ply");
    if !ply.is_file() {
        bail!("{}: no model (run `svgir train` to the end first, or leave out --run)", ply.display());
    }
    let (surfels, _) = svgir_io::read_gaussians_ply(&ply)?;
    // Masks at the photos' own size: the loader's masks must match the photos.
    let dataset = svgir_io::load_dataset(&args.data, &svgir_io::LoadOptions::default())?;
    if !dataset.camera_model.split('+').all(|m| m.contains("PINHOLE")) {
        // Photos are undistorted on load and masks applied before that, so these masks, drawn in
        // the undistorted geometry, are off by the lens's displacement (small near the centre).
        eprintln!(
            "warning: {} has distorted cameras ({}): the masks are drawn in the undistorted geometry",
            args.data.display(),
            dataset.camera_model
        );
    }
    let cameras: Vec<_> = dataset.train.iter().map(|v| v.camera).collect();
    let raster = svgir_raster::RasterConfig {
        near: svgir_train::config::CAPTURE_NEAR_FRACTION * dataset.camera_extent(),
        ..Default::default()
    };
    let cfg = ForegroundConfig::default();
    let photos: Vec<(&[f32], usize)> =
        dataset.train.iter().map(|v| (v.image.data.as_slice(), v.image.channels as usize)).collect();
    let clipped = clipped_gaussians(&surfels, &cameras, &photos, &cfg);
    let fg = select_foreground(&surfels, &cameras, &clipped, &raster, &cfg, &mut Rng::new(args.seed))
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.data.display()))?;
    eprintln!(
        "foreground: {} of {} Gaussians ({} where every camera looks, {} seen clipped left out{})",
        fg.selected_count,
        surfels.len(),
        fg.candidates,
        fg.clipped,
        if fg.support.is_some() { "; support plane removed" } else { "" }
    );
    let views: Vec<_> = dataset.all_views().collect();
    let pb = progress::bar(views.len() as u64, "masks");
    let refine_cfg = RefineConfig { band: args.refine_band, prior: args.refine_prior, ..RefineConfig::default() };
    let mut masks = Vec::new();
    let mut refined = Vec::new();
    for (n, v) in views.iter().enumerate() {
        let share = render_share(&surfels, &fg.selected, &v.camera, &raster);
        let (w, h) = (v.camera.width() as usize, v.camera.height() as usize);
        let mask: Vec<f32> = if args.no_refine || v.image.channels < 3 {
            share.iter().map(|&s| if s >= 0.5 { 1.0 } else { 0.0 }).collect()
        } else {
            let mut rng = Rng::new(args.seed).fork(n as u64 + 1);
            let r = refine(&v.image.data, v.image.channels as usize, &share, w, h, &refine_cfg, &mut rng);
            refined.push(json!({"view": v.name, "band_px": r.band, "changed_px": r.changed}));
            r.mask.iter().map(|&m| if m { 1.0 } else { 0.0 }).collect()
        };
        masks.push(Image::from_data(w as u32, h as u32, 1, mask));
        pb.inc(1);
    }
    pb.finish();
    let check = check_masks(&masks.iter().map(|m| (m.data.as_slice(), m.width, m.height)).collect::<Vec<_>>());
    let thumbs: Vec<Image> = views.iter().zip(&masks).map(|(v, m)| overlay_thumbnail(&v.image, m, 240)).collect();
    let sheet = contact_sheet(&thumbs, 6);
    svgir_io::write_png(run.join("masks_overview.png"), &sheet, 8)?;
    let record = json!({
        "data": args.data, "run": run, "out": args.out, "seed": args.seed, "config": cfg, "foreground": fg,
        "refine": if args.no_refine { serde_json::Value::Null } else { json!({"config": refine_cfg, "per_view": refined}) },
        "confidence": check.confidence, "failure": check.failure.as_ref().map(|f| f.to_string()),
        "per_view": views.iter().zip(&check.views).map(|(v, c)| json!({"view": v.name, "check": c})).collect::<Vec<_>>(),
    });
    std::fs::write(run.join("foreground.json"), serde_json::to_string_pretty(&record)?)?;
    let mut worst: Vec<(&str, f32)> =
        views.iter().zip(&check.views).map(|(v, c)| (v.name.as_str(), c.confidence)).collect();
    worst.sort_by(|a, b| a.1.total_cmp(&b.1));
    let listed: Vec<String> = worst.iter().take(3).map(|(n, c)| format!("{n} {c:.2}")).collect();
    eprintln!("masks: confidence {:.2} (median over the photos; lowest: {})", check.confidence, listed.join(", "));
    if let Some(f) = &check.failure {
        bail!(
            "{}: no masks written: {f}. Give masks of your own with `svgir train --masks DIR` (one PNG per photo, \
             white on the object), or look at {} and {}",
            args.data.display(),
            run.join("masks_overview.png").display(),
            run.join("foreground.json").display()
        );
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    for (v, m) in views.iter().zip(&masks) {
        svgir_io::write_png(args.out.join(format!("{}.png", v.name)), m, 8)?;
    }
    println!(
        "wrote {} masks to {} (overview: {})",
        views.len(),
        args.out.display(),
        run.join("masks_overview.png").display()
    );
    Ok(())
}

/// A capture-profile stage 1 for the masks (no masks yet, so the profile is forced).
fn train_reconstruction(args: &MasksArgs) -> Result<PathBuf> {
    let name = args.data.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "data".into());
    let work = args.work.clone().unwrap_or_else(|| PathBuf::from("runs").join(format!("masks-{name}")));
    eprintln!("svgir masks: stage 1 ({} iterations) -> {}", args.iterations, work.display());
    train::run(train::TrainArgs {
        data: DataArgs {
            data: args.data.clone(),
            resolution: None,
            downscale: Some(args.downscale),
            max_views: None,
            masks: None,
        },
        out: work.clone(),
        iterations: args.iterations,
        seed: args.seed,
        profile: train::ProfileArg::Capture,
        background: None,
        exposure: false,
        view_order: None,
        sh_degree: None,
        distortion_from: 0,
        half_res_until: 0,
        init_ply: None,
        init_points: 100_000,
        max_gaussians: None,
        device: svgir_gpu::DeviceChoice::Auto,
        resume: false,
        checkpoint_every: 1000,
        eval_every: 0,
        eval_views: 8,
        log_every: 50,
        no_mask: true,
        densify_every: None,
        densify_until: None,
        opacity_reset_every: None,
        densify_grad: None,
        weights: Vec::new(),
    })?;
    Ok(work)
}

/// The photo at `width` pixels wide, darkened and tinted outside the mask.
fn overlay_thumbnail(photo: &Image, mask: &Image, width: u32) -> Image {
    let h = ((photo.height as f32 * width as f32 / photo.width as f32).round() as u32).max(1);
    let rgb = photo.select_channels(0..3).resize_area(width, h);
    let m = mask.resize_area(width, h);
    let data = rgb
        .data
        .chunks_exact(3)
        .zip(&m.data)
        .flat_map(|(p, &a)| {
            let dim = |c: f32, t: f32| a * c + (1.0 - a) * (0.25 * c + t);
            [dim(p[0], 0.3), dim(p[1], 0.0), dim(p[2], 0.3)]
        })
        .collect();
    Image::from_data(width, h, 3, data)
}

/// Thumbnails in rows of `cols` (cells as large as the largest thumbnail).
fn contact_sheet(thumbs: &[Image], cols: usize) -> Image {
    let cw = thumbs.iter().map(|t| t.width).max().unwrap_or(1);
    let ch = thumbs.iter().map(|t| t.height).max().unwrap_or(1);
    let rows = thumbs.len().div_ceil(cols).max(1);
    let mut out = Image::new(cw * cols.min(thumbs.len().max(1)) as u32, ch * rows as u32, 3);
    for (k, t) in thumbs.iter().enumerate() {
        let (ox, oy) = ((k % cols) as u32 * cw, (k / cols) as u32 * ch);
        for y in 0..t.height {
            for x in 0..t.width {
                let src = 3 * (y * t.width + x) as usize;
                let dst = 3 * ((oy + y) * out.width + ox + x) as usize;
                out.data[dst..dst + 3].copy_from_slice(&t.data[src..src + 3]);
            }
        }
    }
    out
}
