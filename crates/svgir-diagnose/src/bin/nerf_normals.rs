//! Diagnostic: normal error of a stage-1 run on NeRF-synthetic test views (lego_400).
//!
//! NeRF-synthetic's `r_N_normal_0001.png` have every negative component clipped to 0, so the
//! loader does not take them as ground truth; this measures the run's rendered normals on the
//! object pixels where the stored normal was not clipped ([`svgir_diagnose::clipped_normals`]),
//! and prints each view's mean error and the share of its object pixels that were measured.
//!
//! It writes `OUT/VIEW_normals.png` for the first `--pictures` views: the rendered normal, the
//! stored normal, and the error (black 0, white >= 45 degrees, magenta where not measured).
//!
//! `cargo run --release -p svgir-diagnose --bin nerf_normals -- PLY DATA [--views N] [--pictures N] [--out DIR]`

use anyhow::{bail, Context, Result};
use glam::Vec3;
use std::path::PathBuf;
use svgir_core::Image;
use svgir_diagnose::clipped_normals::{classify, Pixel, Tally};
use svgir_io::LoadOptions;
use svgir_raster::{render, Background, ColorSource, RasterConfig, RenderInput};

/// Errors at or above this are white in the pictures.
const PICTURE_MAX_DEG: f32 = 45.0;

struct Args {
    ply: PathBuf,
    data: PathBuf,
    views: usize,
    pictures: usize,
    out: PathBuf,
}

fn parse_args() -> Result<Args> {
    let mut pos = Vec::new();
    let (mut views, mut pictures, mut out) = (usize::MAX, 4, PathBuf::from("nerf_normals"));
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().with_context(|| format!("{name} needs a value"));
        match a.as_str() {
            "--views" => views = value("--views")?.parse().context("--views: not a count")?,
            "--pictures" => pictures = value("--pictures")?.parse().context("--pictures: not a count")?,
            "--out" => out = PathBuf::from(value("--out")?),
            _ if a.starts_with("--") => bail!("unknown option {a}"),
            _ => pos.push(PathBuf::from(a)),
        }
    }
    let [ply, data]: [PathBuf; 2] = pos
        .try_into()
        .map_err(|_| anyhow::anyhow!("usage: nerf_normals PLY DATA [--views N] [--pictures N] [--out DIR]"))?;
    Ok(Args { ply, data, views, pictures, out })
}

fn main() -> Result<()> {
    let args = parse_args()?;
    let (surfels, _) = svgir_io::read_gaussians_ply(&args.ply)?;
    let ds = svgir_io::load_dataset(&args.data, &LoadOptions { load_test: true, ..Default::default() })?;
    if ds.test.is_empty() {
        bail!("{}: no test views", args.data.display());
    }
    let k = args.views.min(ds.test.len());
    let raster = RasterConfig::default();
    std::fs::create_dir_all(&args.out).with_context(|| format!("{}: cannot create", args.out.display()))?;
    let mut total = Tally::default();
    println!("{:<10} {:>10} {:>12}", "view", "MAE (deg)", "measured");
    for (i, v) in (0..k).map(|i| (i, &ds.test[i * ds.test.len() / k])) {
        let path = args.data.join("test").join(format!("{}_normal_0001.png", v.name));
        let stored = svgir_io::read_image(&path)?;
        let (w, h) = (v.camera.intrinsics.width, v.camera.intrinsics.height);
        if (stored.width, stored.height) != (w, h) || stored.channels < 3 {
            bail!(
                "{}: {}x{}x{}, but the view is {w}x{h} RGB",
                path.display(),
                stored.width,
                stored.height,
                stored.channels
            );
        }
        if v.image.channels != 4 {
            bail!("{}: test photo {} has no alpha channel to tell the object", args.data.display(), v.name);
        }
        let input = RenderInput {
            surfels: &surfels,
            camera: &v.camera,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color([0.0; 3]),
        };
        let (out, _) = render(&input, &raster);
        let photo_alpha: Vec<f32> = v.image.data.chunks_exact(4).map(|p| p[3]).collect();
        let pixels = classify(&out.normal, &out.alpha, &stored.data, stored.channels as usize, &photo_alpha);
        let t = Tally::of(&pixels);
        println!("{:<10} {:>10.2} {:>11.1}%", v.name, t.mean_deg().unwrap_or(f64::NAN), 100.0 * t.measured_share());
        total = total.merge(t);
        if i < args.pictures {
            let file = args.out.join(format!("{}_normals.png", v.name));
            svgir_io::write_png(&file, &picture(&out.normal, &stored, &pixels, w, h), 8)?;
        }
    }
    let mean = total.mean_deg().context("no test pixel has an unclipped stored normal")?;
    println!(
        "mean of {k} views: normal MAE {mean:.2} deg over the {:.1}% of object pixels with unclipped stored normals",
        100.0 * total.measured_share()
    );
    println!("pictures: {}", args.out.display());
    Ok(())
}

/// Rendered normal | stored normal | error, side by side.
fn picture(normal: &[f32], stored: &Image, pixels: &[Pixel], w: u32, h: u32) -> Image {
    let (w, h) = (w as usize, h as usize);
    let mut img = vec![0.0f32; 3 * w * 3 * h];
    let c = stored.channels as usize;
    for (p, px) in pixels.iter().enumerate() {
        let (x, y) = (p % w, p / w);
        let row = y * 3 * w;
        let n = Vec3::from_slice(&normal[3 * p..3 * p + 3]).normalize_or_zero();
        let left = if matches!(px, Pixel::Background) { [0.0; 3] } else { (n * 0.5 + 0.5).to_array() };
        let mid = [0, 1, 2].map(|k| if matches!(px, Pixel::Error(_)) { stored.data[c * p + k] } else { 0.0 });
        let right = match px {
            Pixel::Background => [0.0; 3],
            Pixel::Unmeasured => [0.6, 0.0, 0.6],
            Pixel::Error(e) => [(e / PICTURE_MAX_DEG).min(1.0); 3],
        };
        for (panel, rgb) in [left, mid, right].into_iter().enumerate() {
            img[3 * (row + panel * w + x)..][..3].copy_from_slice(&rgb);
        }
    }
    Image::from_data(3 * w as u32, h as u32, 3, img)
}
