//! `svgir eval`: image-quality metrics between predicted and ground-truth images, as the
//! standard evaluations compute them (PSNR, SSIM with the 11x11 sigma-1.5 window, LPIPS v0.1).
//! Pairs images by file name; RGBA images are composited over `--background` first.
//!
//! On stage-2 runs (`svgir inverse`) it runs SPEC 8's whole evaluation instead ([`super::spec8`]):
//! NVS, albedo, roughness, normals and relighting per light, a table per run and one markdown
//! row per run.

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use serde_json::json;
use std::path::{Path, PathBuf};
use svgir_eval::lpips_weights::{find_lpips_weights, HOW_TO_GET, NOT_COMPUTED};
use svgir_eval::spec8::rgb;
use svgir_metrics::{Shape, SsimVariant};

/// Which LPIPS network scores the images.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum LpipsNet {
    Vgg,
    Alex,
    None,
}

impl LpipsNet {
    /// The metrics crate's network, `None` for no LPIPS.
    pub fn net(self) -> Option<svgir_metrics::Net> {
        match self {
            LpipsNet::Vgg => Some(svgir_metrics::Net::Vgg),
            LpipsNet::Alex => Some(svgir_metrics::Net::Alex),
            LpipsNet::None => None,
        }
    }
}

/// `--lpips` and `--lpips-weights`, for every command that evaluates.
#[derive(Args, Clone, Debug)]
pub struct LpipsArgs {
    /// LPIPS network of the evaluation (`none`: PSNR and SSIM only).
    #[arg(long, value_enum, default_value_t = LpipsNet::Vgg)]
    pub lpips: LpipsNet,
    /// LPIPS v0.1 weights: a folder holding lpips_vgg_v0.1.safetensors and
    /// lpips_alex_v0.1.safetensors, or one such file (default: $SVGIR_LPIPS_DIR, then
    /// ../shared/data/lpips). `python3 tools/lpips_weights.py DIR` fetches them. Without them
    /// LPIPS is "not computed".
    #[arg(hide_short_help = true, long, value_name = "DIR")]
    pub lpips_weights: Option<PathBuf>,
}

impl LpipsArgs {
    /// The network, or `None` with a warning when no weights were found and none were named.
    pub fn load(&self) -> Result<Option<svgir_metrics::Lpips>> {
        svgir_eval::load_lpips(self.lpips.net(), self.lpips_weights.as_deref())
    }
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
    /// A run folder instead. A stage-1 run (`svgir train`): its test renders against the ground
    /// truth saved beside them. A stage-2 run (`RUN/stage2` from `svgir inverse`, or RUN holding
    /// one): SPEC 8's evaluation on the dataset's test views, written to its `eval.json`.
    /// Several stage-2 runs may be given (one table row each).
    #[arg(long, num_args = 1.., required_unless_present = "pred")]
    pub run: Vec<PathBuf>,
    /// Stage-2 runs: print the evaluation `svgir inverse` saved (`eval.json`) instead of
    /// evaluating again.
    #[arg(long)]
    pub cached: bool,
    /// Stage-2 runs: the dataset, if it moved (default: the path in the run's config.json).
    #[arg(long)]
    pub data: Option<PathBuf>,
    #[command(flatten)]
    pub relight: super::spec8::EvalRelightArgs,
    #[command(flatten)]
    pub lpips: LpipsArgs,
    #[arg(long, value_enum, default_value_t = SsimKind::Padded)]
    pub ssim: SsimKind,
    /// Background for RGBA images, as r,g,b in `[0, 1]`.
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

/// (prediction, ground truth) file pairs to compare, with a display name.
fn pairs(args: &EvalArgs) -> Result<Vec<(String, PathBuf, PathBuf)>> {
    let (dir, list) = match (&args.pred, args.run.as_slice()) {
        (Some(p), _) => (p.clone(), true),
        (None, [r]) => (r.join("test"), false),
        (None, []) => bail!("give --pred and --gt, or --run"),
        (None, _) => bail!("several --run folders: only for stage-2 runs (`svgir inverse`)"),
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

/// The stage-2 folder of `run`: `run` itself or `run/stage2`, if its config.json is stage 2's.
fn stage2_folder(run: &Path) -> Option<PathBuf> {
    let is_stage2 =
        |d: &Path| svgir_eval::read_json(&d.join("config.json"), "").is_ok_and(|c| c.get("stage2").is_some());
    [run.to_path_buf(), run.join("stage2")].into_iter().find(|d| is_stage2(d))
}

/// A name for a stage-2 folder in the table: the stage-1 run's folder for `RUN/stage2`.
fn scene_name(dir: &Path) -> String {
    let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    match name(dir) {
        Some(n) if n == "stage2" => dir.parent().and_then(name).unwrap_or(n),
        Some(n) => n,
        None => dir.display().to_string(),
    }
}

/// SPEC 8 on each stage-2 run (or its saved `eval.json` with `--cached`).
fn run_stage2(args: &EvalArgs, dirs: &[PathBuf]) -> Result<()> {
    let lpips = if args.cached { None } else { args.lpips.load()? };
    let sampling = args.relight.sampling();
    let mut rows = Vec::new();
    for dir in dirs {
        let saved_path = dir.join("eval.json");
        let read_saved = || svgir_eval::read_json(&saved_path, "evaluate without --cached");
        let result = if args.cached {
            read_saved()?
        } else {
            let cfg_path = dir.join("config.json");
            let cfg = svgir_eval::read_json(&cfg_path, "")?;
            // The stage-1 run: RUN for RUN/stage2, else the one the config records.
            let stage1 = match dir.parent() {
                Some(p) if dir.ends_with("stage2") && p.join("config.json").exists() => p.to_path_buf(),
                _ => PathBuf::from(
                    cfg["stage1_run"].as_str().with_context(|| format!("{}: no stage1_run", cfg_path.display()))?,
                ),
            };
            let data = args.data.clone().or_else(|| cfg["data"].as_str().map(PathBuf::from));
            let (dataset, _) = svgir_eval::load_run_dataset(&stage1, data.as_deref())?;
            let s2 = svgir_train::checkpoint::load_stage2(&dir.join("checkpoint.bin"))?;
            eprintln!("{}: SPEC 8 evaluation on {} test views", dir.display(), dataset.test.len());
            let fresh = svgir_eval::evaluate(
                &s2,
                &dataset,
                lpips.as_ref(),
                0,
                sampling,
                &args.relight.extra_lights(),
                &mut svgir_eval::EvalWriter::new(dir),
            )?;
            // Keep what `svgir inverse` recorded beside the metrics (timings, sizes).
            let mut merged = read_saved().unwrap_or_else(|_| json!({}));
            for (k, v) in fresh.as_object().into_iter().flatten() {
                merged[k] = v.clone();
            }
            std::fs::write(&saved_path, serde_json::to_string_pretty(&merged)?)
                .with_context(|| format!("writing {}", saved_path.display()))?;
            merged
        };
        println!("{} ({} test views)", dir.display(), result["views"]);
        println!("{}", svgir_eval::table::metric_table(&result));
        rows.push((scene_name(dir), dir.display().to_string(), result));
    }
    println!("{}", svgir_eval::table::TABLE_HEADER);
    for (name, _, r) in &rows {
        println!("{}", svgir_eval::table::table_row(name, r));
    }
    if let Some(path) = &args.json {
        let all: serde_json::Map<String, serde_json::Value> = rows.into_iter().map(|(_, d, r)| (d, r)).collect();
        std::fs::write(path, serde_json::to_string_pretty(&all)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

pub fn run(args: EvalArgs) -> Result<()> {
    if args.pred.is_none() && !args.run.is_empty() {
        let stage2: Vec<Option<PathBuf>> = args.run.iter().map(|r| stage2_folder(r)).collect();
        if stage2.iter().all(Option::is_some) {
            return run_stage2(&args, &stage2.into_iter().flatten().collect::<Vec<_>>());
        }
        if args.run.len() > 1 {
            let not: Vec<String> = args
                .run
                .iter()
                .zip(&stage2)
                .filter(|(_, s)| s.is_none())
                .map(|(r, _)| r.display().to_string())
                .collect();
            bail!("several --run folders need stage-2 runs (`svgir inverse`); not one: {}", not.join(", "));
        }
    }
    let pairs = pairs(&args)?;
    // Image pairs: LPIPS was asked for, so missing weights are an error, not a silent gap.
    let lpips = match args.lpips.lpips.net() {
        None => None,
        Some(net) => {
            let path = find_lpips_weights(net, args.lpips.lpips_weights.as_deref())?
                .with_context(|| format!("LPIPS weights not found (or pass --lpips none). {HOW_TO_GET}"))?;
            let bytes = std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?;
            Some(
                svgir_metrics::lpips::Lpips::from_safetensors(&bytes, net)
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
        rows.push(
            json!({"image": name, "psnr": psnr, "ssim": ssim, "lpips": lp.map_or(json!(NOT_COMPUTED), |v| json!(v))}),
        );
    }
    let n = pairs.len() as f64;
    let mean = json!({"psnr": sp / n, "ssim": ss / n, "lpips": lpips.as_ref().map_or(json!(NOT_COMPUTED), |_| json!(sl / n)), "images": pairs.len()});
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
