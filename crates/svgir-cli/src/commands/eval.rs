//! `svgir eval`: image-quality metrics between predicted and ground-truth images, as the
//! standard evaluations compute them (PSNR, SSIM with the 11x11 sigma-1.5 window, LPIPS v0.1).
//! Pairs images by file name; RGBA images are composited over `--background` first.

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use serde_json::json;
use std::path::{Path, PathBuf};
use svgir_core::Image;
use svgir_metrics::{Shape, SsimVariant};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum LpipsNet {
    Vgg,
    Alex,
    None,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum SsimKind {
    /// 3DGS/2DGS: zero-padded "same" convolution.
    Padded,
    /// TensoIR: "valid" convolution, no padding.
    Valid,
}

#[derive(Args)]
pub struct EvalArgs {
    /// Folder of predicted images.
    #[arg(long, requires = "gt", conflicts_with = "run")]
    pub pred: Option<PathBuf>,
    /// Folder of ground-truth images with the same file names.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// A run folder instead: its test renders (`test/NAME_rgb.png` from `svgir train`, or
    /// `test/NAME_pbr.png` from `svgir inverse`) against the ground truth saved beside them.
    #[arg(long, required_unless_present = "pred")]
    pub run: Option<PathBuf>,
    /// LPIPS network (weights from --lpips-weights or ../shared/data/lpips).
    #[arg(long, value_enum, default_value_t = LpipsNet::Vgg)]
    pub lpips: LpipsNet,
    /// LPIPS safetensors file.
    #[arg(long)]
    pub lpips_weights: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = SsimKind::Padded)]
    pub ssim: SsimKind,
    /// Background for RGBA images, as r,g,b in [0,1].
    #[arg(long, default_value = "0,0,0", value_parser = parse_rgb)]
    pub background: [f32; 3],
    /// Write the per-image and mean metrics here as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

pub fn parse_rgb(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> =
        s.split(',').map(|x| x.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    v.try_into().map_err(|_| "expected r,g,b".to_string())
}

pub fn rgb(img: &Image, bg: [f32; 3]) -> Image {
    match img.channels {
        4 => img.composite_over(bg),
        3 => img.clone(),
        1 => Image::from_data(img.width, img.height, 3, img.data.iter().flat_map(|v| [*v; 3]).collect()),
        _ => img.select_channels(0..3),
    }
}

pub fn default_lpips_weights(net: LpipsNet) -> Option<PathBuf> {
    let name = match net {
        LpipsNet::Vgg => "lpips_vgg_v0.1.safetensors",
        LpipsNet::Alex => "lpips_alex_v0.1.safetensors",
        LpipsNet::None => return None,
    };
    let exe_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(Path::to_path_buf));
    let candidates =
        [Some(PathBuf::from("../shared/data/lpips")), exe_dir.map(|d| d.join("../../../shared/data/lpips"))];
    candidates.into_iter().flatten().map(|d| d.join(name)).find(|p| p.exists())
}

/// (prediction, ground truth) file pairs to compare, with a display name.
fn pairs(args: &EvalArgs) -> Result<Vec<(String, PathBuf, PathBuf)>> {
    let (dir, list) = match (&args.pred, &args.run) {
        (Some(p), _) => (p.clone(), true),
        (None, Some(r)) => (r.join("test"), false),
        (None, None) => bail!("give --pred and --gt, or --run"),
    };
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .with_context(|| format!("{}: cannot list folder", dir.display()))?
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| [".png", ".jpg", ".exr", ".hdr"].iter().any(|ext| n.to_lowercase().ends_with(ext)))
        .collect();
    names.sort();
    let out: Vec<_> = if list {
        let gt = args.gt.clone().context("--gt is required with --pred")?;
        names.iter().map(|n| (n.clone(), dir.join(n), gt.join(n))).collect()
    } else {
        let suffix = if names.iter().any(|n| n.ends_with("_pbr.png")) { "_pbr.png" } else { "_rgb.png" };
        names
            .iter()
            .filter(|n| n.ends_with(suffix) && !n.contains("_gt_"))
            .map(|n| {
                let stem = n.trim_end_matches(suffix);
                (stem.to_string(), dir.join(n), dir.join(format!("{stem}_gt_rgb.png")))
            })
            .collect()
    };
    if out.is_empty() {
        bail!("{}: no images to evaluate", dir.display());
    }
    Ok(out)
}

pub fn run(args: EvalArgs) -> Result<()> {
    let pairs = pairs(&args)?;
    let lpips = match args.lpips {
        LpipsNet::None => None,
        net => {
            let path =
                args.lpips_weights.clone().or_else(|| default_lpips_weights(net)).with_context(|| {
                    "LPIPS weights not found: pass --lpips-weights FILE (or --lpips none)".to_string()
                })?;
            let bytes = std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?;
            let kind = if matches!(net, LpipsNet::Vgg) {
                svgir_metrics::lpips::Net::Vgg
            } else {
                svgir_metrics::lpips::Net::Alex
            };
            Some(
                svgir_metrics::lpips::Lpips::from_safetensors(&bytes, kind)
                    .with_context(|| format!("{}", path.display()))?,
            )
        }
    };
    let variant = match args.ssim {
        SsimKind::Padded => SsimVariant::GaussianSplatting,
        SsimKind::Valid => SsimVariant::TensoIR,
    };
    println!("{:<32} {:>8} {:>8} {:>8}", "image", "PSNR", "SSIM", "LPIPS");
    let mut rows = Vec::new();
    let (mut sp, mut ss, mut sl) = (0.0, 0.0, 0.0);
    for (name, pred_path, gt_path) in &pairs {
        let pred = rgb(&svgir_io::read_image(pred_path)?, args.background);
        let gt = rgb(&svgir_io::read_image(gt_path)?, args.background);
        if (pred.width, pred.height) != (gt.width, gt.height) {
            bail!(
                "{}: image is {}x{} but the prediction is {}x{}",
                gt_path.display(),
                gt.width,
                gt.height,
                pred.width,
                pred.height
            );
        }
        let p: Vec<f32> = pred.data.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        let g: Vec<f32> = gt.data.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        let psnr = svgir_metrics::psnr(&p, &g, 3, None)?;
        let ssim =
            svgir_metrics::ssim(&p, &g, Shape::new(pred.width as usize, pred.height as usize, 3), variant)? as f64;
        let lp = match &lpips {
            Some(l) => Some(l.distance_rgb(&p, &g, pred.width as usize, pred.height as usize)?.total as f64),
            None => None,
        };
        println!("{:<32} {:>8.3} {:>8.4} {:>8}", name, psnr, ssim, lp.map_or("-".into(), |v| format!("{v:.4}")));
        sp += psnr;
        ss += ssim;
        sl += lp.unwrap_or(0.0);
        rows.push(json!({"image": name, "psnr": psnr, "ssim": ssim, "lpips": lp}));
    }
    let n = pairs.len() as f64;
    let mean = json!({"psnr": sp / n, "ssim": ss / n, "lpips": lpips.as_ref().map(|_| sl / n), "images": pairs.len()});
    println!(
        "{:<32} {:>8.3} {:>8.4} {:>8}",
        format!("mean of {}", pairs.len()),
        sp / n,
        ss / n,
        if lpips.is_some() { format!("{:.4}", sl / n) } else { "-".into() }
    );
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&json!({"mean": mean, "images": rows}))?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
