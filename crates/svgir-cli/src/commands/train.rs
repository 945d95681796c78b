//! `svgir train`: stage 1 on a dataset, into a run folder.
//!
//! Run folder: `config.json` (everything needed to reproduce, seed included), `metrics.jsonl`
//! (one JSON object per logged iteration or evaluation), `checkpoint.bin` (atomic, every
//! `--checkpoint-every` iterations and on Ctrl-C), `point_cloud.ply` (3DGS layout),
//! `test/` renders (RGB, depth, normal PNGs), `eval.json`, `timings.json`.

use super::engine::{open_device, Engine};
use super::DataArgs;
use crate::progress;
use anyhow::{bail, ensure, Context, Result};
use clap::{Args, ValueEnum};
use rayon::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use svgir_core::{Dataset, Image, Rng};
use svgir_gpu::DeviceChoice;
use svgir_train::driver::{self, DriverError, Ended, Observer, Periods, Stage1Start};
use svgir_train::{init, BackgroundMode, Profile, Stage1Config, StepStats, ViewOrder};

/// `--profile`: which defaults to start from.
#[derive(Clone, Copy, Debug, ValueEnum, PartialEq)]
pub enum ProfileArg {
    /// Object if the dataset has foreground masks, capture otherwise.
    Auto,
    /// A masked object, for `svgir inverse`: mask, entropy and depth-normal losses.
    Object,
    /// Photos of a real scene, background included.
    Capture,
    /// Novel views of a masked object, as 3DGS is benchmarked: 3DGS's loss alone (higher test
    /// PSNR, but no surface constraints: not a stage 1 for `svgir inverse`).
    Views,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Bg {
    White,
    Black,
    Random,
}

/// `--view-order`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ViewOrderArg {
    /// Each view once per epoch, shuffled afresh (3DGS's `viewpoint_stack`).
    Epochs,
    /// Independently at random every iteration.
    Uniform,
}

#[derive(Args)]
pub struct TrainArgs {
    #[command(flatten)]
    pub data: DataArgs,
    /// Run folder to create (or to continue with --resume).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Iterations; the densification schedule is scaled from the 30k reference to this length.
    #[arg(long, default_value_t = 30_000)]
    pub iterations: u64,
    /// Seed of every random choice (recorded in config.json).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Defaults for a masked object or a real capture (auto: from the dataset's masks).
    #[arg(long, value_enum, default_value_t = ProfileArg::Auto)]
    pub profile: ProfileArg,
    /// Background the renders are composited over, and the photos for masked data (default:
    /// white for objects; random for captures, so that Gaussians model the real background).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum)]
    pub background: Option<Bg>,
    /// The distortion weight (`--weight distortion=X`) applies from this iteration (2DGS: 3000).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 0)]
    pub distortion_from: u64,
    /// Highest SH degree of the view-dependent colour (0-3; default 3, reached one step every 1000
    /// iterations in the capture profile).
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=3))]
    pub sh_degree: Option<u32>,
    /// Learn a per-photo affine colour correction (phone captures with varying exposure or white
    /// balance). Test views are rendered without one.
    #[arg(long)]
    pub exposure: bool,
    /// How each iteration's training view is drawn: each view once per epoch in a shuffled order
    /// (3DGS), or independently at random. Default: the profile's (independent for `object`,
    /// where it measured better after stage 2; by epoch for `views` and `capture`, as 3DGS).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum)]
    pub view_order: Option<ViewOrderArg>,
    /// Initial surfels from a point-cloud PLY instead of the dataset's points / a random box.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub init_ply: Option<PathBuf>,
    /// Number of random initial points when the dataset has none.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 100_000)]
    pub init_points: usize,
    /// Where to train: auto (a hardware GPU if any), cpu or gpu.
    #[arg(long, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
    /// Continue the run in --out from its checkpoint, with its settings (--iterations extends it).
    #[arg(long)]
    pub resume: bool,
    /// Write RUN/checkpoint.bin every this many iterations (atomically; Ctrl-C also saves).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 1000)]
    pub checkpoint_every: u64,
    /// Evaluate on test views every this many iterations (0: only at the end).
    #[arg(long, default_value_t = 0)]
    pub eval_every: u64,
    /// Evaluate on at most this many test views during training (all at the end).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 8)]
    pub eval_views: usize,
    /// Append training statistics to RUN/metrics.jsonl every this many iterations.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 50)]
    pub log_every: u64,
    /// Stop densifying at this many Gaussians (object profile default: one per 64 training
    /// pixels, against overfitting few small photos; capture profile: none; 0: no limit).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub max_gaussians: Option<usize>,
    /// Disable the mask and entropy losses (photos without a meaningful alpha channel).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub no_mask: bool,
    /// Override the scaled schedule: densify every N iterations (3DGS: 100).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub densify_every: Option<u64>,
    /// Override the scaled schedule: stop densifying at this iteration (3DGS: 15000 of 30000).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub densify_until: Option<u64>,
    /// Override the scaled schedule: reset opacities every N iterations while densifying (3DGS: 3000).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub opacity_reset_every: Option<u64>,
    /// Train iterations 1..=N on the photos at half size, then on the photos themselves (coarse
    /// to fine; 0: off). Those iterations cost about half as much: lego_400's 32 dB command uses
    /// half the run (docs/experiments.md).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 0)]
    pub half_res_until: u64,
    /// Override the densification threshold on the mean view-space gradient (SPEC 2: 2.5e-4; 3DGS: 2e-4).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub densify_grad: Option<f32>,
    /// Loss weight, repeatable: l1, ssim, mask, normal_start, normal_ramp, entropy, distortion or
    /// opacity_binary (defaults: SPEC 2, opacity_binary 0; the depth-normal weight ramps from
    /// normal_start to normal_start + normal_ramp over the run; opacity_binary, each surfel's
    /// opacity entropy, acts once densification has ended).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long = "weight", value_name = "NAME=VALUE")]
    pub weights: Vec<String>,
}

pub fn run(args: TrainArgs) -> Result<()> {
    let load = args.data.load_options(true);
    let dataset = svgir_io::load_dataset(&args.data.data, &load)?;
    if dataset.train.is_empty() {
        bail!("{}: no training views", args.data.data.display());
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let ckpt_path = args.out.join("checkpoint.bin");
    let gpu = open_device(args.device)?;
    let adapter = gpu.as_ref().map(|g| g.report.clone());
    let start = if args.resume {
        let ignored = ignored_on_resume(&args)?;
        if !ignored.is_empty() {
            eprintln!(
                "warning: --resume continues with the settings in {}; ignored: {}",
                ckpt_path.display(),
                ignored.join(", ")
            );
        }
        // An --iterations other than its default sets the run's length, which may extend a
        // finished run; without it the run ends where it was meant to.
        let given = args.iterations != default_args()?.iterations;
        Stage1Start::Resume { iterations: given.then_some(args.iterations) }
    } else {
        let (config, why) = make_config(&args, &dataset)?;
        let mut rng = Rng::new(config.seed);
        let points = if let Some(p) = &args.init_ply {
            svgir_io::ply::read_points_ply(p)?
        } else if let Some(p) = dataset.points.as_ref().filter(|p| !p.positions.is_empty()) {
            p.clone()
        } else if config.profile == Profile::Capture {
            // No SfM points: fill the region the cameras surround, at the scene's own scale.
            let mut pc = init::random_box_points(config.init_points, dataset.camera_extent(), &mut rng);
            let centre = dataset.camera_centroid();
            pc.positions.iter_mut().for_each(|p| *p += centre);
            pc
        } else {
            init::random_box_points(config.init_points, config.init_half_extent, &mut rng)
        };
        let surfels = init::surfels_from_points(&points, config.max_sh_degree, &mut rng);
        let meta = json!({
                "stage1": config,
                "profile": { "name": config.profile.name(), "why": why, "defaults": config.profile.describe() },
                "data": args.data.data,
                "load": { "resolution": load.resolution, "downscale": load.downscale, "max_views": load.max_views, "masks": load.masks },
                "init": if args.init_ply.is_some() { "ply" } else if dataset.points.as_ref().is_some_and(|p| !p.positions.is_empty()) { "dataset points" } else { "random box" },
                "initial_gaussians": surfels.len(),
                "device": { "choice": args.device, "adapter": adapter },
                "command": std::env::args().collect::<Vec<_>>(),
        });
        Stage1Start::New { config: Box::new(config), surfels, meta }
    };
    let trainer = driver::open_stage1(&args.out, start, &dataset, &mut |line| eprintln!("{line}"))?;
    let mut engine = Engine::new(trainer, gpu, &dataset)?;
    train_loop(&mut engine, &dataset, &args)?;
    finish(&engine, &dataset, &args.out)
}

/// `svgir train`'s arguments with every flag at its default (the dataset and --out are
/// placeholders).
fn default_args() -> Result<TrainArgs> {
    super::args_of::<TrainArgs>("train", &["DATA".into(), "--out".into(), "OUT".into()])
}

/// The flags of `args` that set up a new run and were given (differ from their defaults): a
/// resumed run takes those settings from its checkpoint.
fn ignored_on_resume(args: &TrainArgs) -> Result<Vec<&'static str>> {
    let d = default_args()?;
    // Compared by their Debug form: the value enums do not all implement PartialEq.
    macro_rules! given {
        ($($flag:literal => $field:ident),* $(,)?) => {
            [$(($flag, format!("{:?}", args.$field) != format!("{:?}", d.$field))),*]
        };
    }
    let flags = given![
        "--seed" => seed,
        "--profile" => profile,
        "--background" => background,
        "--distortion-from" => distortion_from,
        "--sh-degree" => sh_degree,
        "--exposure" => exposure,
        "--view-order" => view_order,
        "--init-ply" => init_ply,
        "--init-points" => init_points,
        "--max-gaussians" => max_gaussians,
        "--no-mask" => no_mask,
        "--densify-every" => densify_every,
        "--densify-until" => densify_until,
        "--opacity-reset-every" => opacity_reset_every,
        "--half-res-until" => half_res_until,
        "--densify-grad" => densify_grad,
        "--weight" => weights,
    ];
    Ok(flags.into_iter().filter_map(|(flag, given)| given.then_some(flag)).collect())
}

/// The profile for `args` and `dataset`, with why it was chosen.
pub fn choose_profile(arg: ProfileArg, dataset: &Dataset) -> (Profile, &'static str) {
    match arg {
        ProfileArg::Object => (Profile::Object, "--profile object"),
        ProfileArg::Capture => (Profile::Capture, "--profile capture"),
        ProfileArg::Views => (Profile::Views, "--profile views"),
        ProfileArg::Auto if dataset.has_masks() => (Profile::Object, "the dataset has foreground masks"),
        ProfileArg::Auto => (Profile::Capture, "the dataset has no foreground masks"),
    }
}

fn make_config(args: &TrainArgs, dataset: &Dataset) -> Result<(Stage1Config, &'static str)> {
    let pixels: usize = dataset.train.iter().map(|v| (v.image.width * v.image.height) as usize).sum();
    let (profile, why) = choose_profile(args.profile, dataset);
    eprintln!("profile: {} ({why}): {}", profile.name(), profile.describe());
    let mut c = Stage1Config::for_profile(profile, args.iterations, pixels);
    c.loss = super::loss_weights_over(c.loss.clone(), &args.weights)?;
    c.seed = args.seed;
    if let Some(bg) = args.background {
        c.background = match bg {
            Bg::White => BackgroundMode::White,
            Bg::Black => BackgroundMode::Black,
            Bg::Random => BackgroundMode::Random,
        };
    }
    c.exposure = args.exposure;
    if let Some(v) = args.view_order {
        c.view_order = match v {
            ViewOrderArg::Epochs => ViewOrder::Epochs,
            ViewOrderArg::Uniform => ViewOrder::Uniform,
        };
    }
    c.distortion_from = args.distortion_from;
    c.half_res_until = args.half_res_until;
    if let Some(d) = args.sh_degree {
        c.max_sh_degree = d;
    }
    c.init_points = args.init_points;
    match args.max_gaussians {
        Some(0) => c.densify.max_gaussians = usize::MAX,
        Some(m) => c.densify.max_gaussians = m,
        None => {}
    }
    // A schedule scaled down to a short run densifies and resets very often (every 10 and
    // 300 iterations at 3000); these let a short run keep 3DGS's cadence instead.
    if let Some(n) = args.densify_every {
        c.densify.interval = n.max(1);
    }
    if let Some(n) = args.densify_until {
        c.densify.until_iter = n;
    }
    if let Some(n) = args.opacity_reset_every {
        c.densify.opacity_reset_interval = n.max(1);
    }
    if let Some(g) = args.densify_grad {
        ensure!(g.is_finite() && g > 0.0, "--densify-grad must be a positive number, got {g}");
        c.densify.grad_threshold = g;
    }
    c.mask_losses_only_with(!args.no_mask && dataset.has_masks());
    // Captures come in arbitrary units: their near plane follows the cameras, whatever the profile.
    if matches!(svgir_io::detect_layout(&dataset.root), Ok(svgir_io::Layout::Colmap | svgir_io::Layout::Transforms)) {
        c.near_fraction = Some(svgir_train::config::CAPTURE_NEAR_FRACTION);
    }
    Ok((c, why))
}

fn write_json(path: &Path, v: &impl serde::Serialize) -> Result<()> {
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_string_pretty(v)?).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Set by Ctrl-C; the training loops save a checkpoint and exit. A second Ctrl-C while saving
/// kills the process as usual. Installed once per process.
pub fn interrupt_flag() -> Arc<AtomicBool> {
    static FLAG: std::sync::OnceLock<Arc<AtomicBool>> = std::sync::OnceLock::new();
    FLAG.get_or_init(|| {
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        let _ = ctrlc::set_handler(move || {
            if s.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        });
        stop
    })
    .clone()
}

/// Stage 1's side of the run loop: the progress bar (a moving average of the loss and PSNR),
/// the periodic evaluations on `eval_views` test views, and Ctrl-C.
struct Stage1Watch {
    pb: indicatif::ProgressBar,
    eval_views: usize,
    stop: Arc<AtomicBool>,
    ema: Option<(f32, f32)>,
}

impl Observer<Engine> for Stage1Watch {
    fn stepped(&mut self, _: &Engine, s: &StepStats) {
        if s.loss.is_finite() {
            self.ema =
                Some(self.ema.map_or((s.loss, s.psnr), |(l, p)| (0.9 * l + 0.1 * s.loss, 0.9 * p + 0.1 * s.psnr)));
        }
        self.pb.set_position(s.iteration);
        if let Some((l, p)) = self.ema {
            self.pb.set_message(format!("loss {l:.4} PSNR {p:.2} dB, {} Gaussians", s.num_gaussians));
        }
    }

    fn evaluate(&mut self, trainer: &mut Engine, dataset: &Dataset) -> Result<serde_json::Value, DriverError> {
        trainer.sync().map_err(DriverError::step)?;
        let m = evaluate(trainer, dataset, self.eval_views, None).map_err(DriverError::step)?;
        self.pb.println(format!("iteration {}: test PSNR {:.2} dB", trainer.host().iteration, m["psnr"]));
        Ok(m)
    }

    fn interrupted(&self) -> bool {
        self.stop.load(Ordering::SeqCst)
    }
}

fn train_loop(trainer: &mut Engine, dataset: &Dataset, args: &TrainArgs) -> Result<()> {
    let pb = progress::bar(trainer.host().config.iterations, "stage 1");
    pb.set_position(trainer.host().iteration);
    let mut watch = Stage1Watch { pb, eval_views: args.eval_views, stop: interrupt_flag(), ema: None };
    let periods =
        Periods { log_every: args.log_every, eval_every: args.eval_every, checkpoint_every: args.checkpoint_every };
    match driver::run(trainer, dataset, &args.out, periods, &mut watch)? {
        Ended::Finished => watch.pb.finish(),
        Ended::Interrupted { iteration } => {
            watch.pb.abandon_with_message("interrupted");
            eprintln!("interrupted: checkpoint saved at iteration {iteration}; continue with --resume");
            std::process::exit(130);
        }
    }
    Ok(())
}

/// Render test views, return mean PSNR/SSIM (and normal MAE where ground truth exists); with
/// `out_dir`, also write the renders.
fn evaluate(
    trainer: &Engine,
    dataset: &Dataset,
    max_views: usize,
    out_dir: Option<&Path>,
) -> Result<serde_json::Value> {
    let bg = trainer.host().config.background.fixed_color().unwrap_or([1.0; 3]);
    // At most `max_views` views, spread over the test set (its first views are often neighbours).
    let k = max_views.min(dataset.test.len());
    let views: Vec<_> = (0..k).map(|i| &dataset.test[i * dataset.test.len() / k]).collect();
    let mut psnr = 0.0;
    let mut ssim = 0.0;
    let mut normal_mae = svgir_metrics::NormalMae::new();
    // Captures, in the final evaluation: which test pixels a training photo saw.
    let train_depths: Vec<Vec<f32>> = if out_dir.is_some() && !dataset.has_masks() {
        let depth = |c| -> Result<Vec<f32>> {
            let o = trainer.render_view(c, bg)?;
            Ok(svgir_train::coverage::expected_depth(&o.depth, &o.alpha))
        };
        dataset.train.iter().map(|v| depth(&v.camera)).collect::<Result<_>>()?
    } else {
        Vec::new()
    };
    let depth_views: Vec<_> = dataset
        .train
        .iter()
        .zip(&train_depths)
        .map(|(t, d)| svgir_train::coverage::DepthView { camera: &t.camera, depth: d })
        .collect();
    let mut coverage = Vec::new();
    // A run with per-photo corrections (--exposure) also scores each held-out photo through its
    // own: fitted on the photo's left half, measured on its right (NeRF-W's protocol), since a
    // held-out photo's exposure is as unknown as a training photo's.
    let matched = trainer.host().exposure.is_some();
    let mut psnr_matched = 0.0;
    // A view's images are encoded together, in parallel (PNG encoding is single-threaded; the
    // 200 lego_400 test views took 22 s instead of 26 written one by one).
    let mut pending: Vec<(PathBuf, Image, u8)> = Vec::new();
    for v in &views {
        let out = trainer.render_view(&v.camera, bg)?;
        let gt = svgir_train::stage1::target_rgb(&v.image, bg);
        let (w, h) = (out.width, out.height);
        let pred: Vec<f32> = out.color.iter().map(|c| c.clamp(0.0, 1.0)).collect();
        psnr += svgir_metrics::psnr(&pred, &gt, 3, None)?;
        let shape = svgir_metrics::Shape::new(w as usize, h as usize, 3);
        ssim += svgir_metrics::ssim(&pred, &gt, shape, svgir_metrics::SsimVariant::GaussianSplatting)? as f64;
        if matched {
            let left = |i: usize| (i % w as usize) < w as usize / 2;
            let p = svgir_train::exposure::fit(&out.color, &out.alpha, bg, &gt, left);
            let fitted: Vec<f32> = svgir_train::exposure::apply(&p, &out.color, &out.alpha, bg)
                .into_iter()
                .map(|c| c.clamp(0.0, 1.0))
                .collect();
            let right: Vec<f32> = (0..(w * h) as usize).map(|i| (!left(i)) as u8 as f32).collect();
            psnr_matched += svgir_metrics::psnr(&fitted, &gt, 3, Some(&right))?;
            if let Some(dir) = out_dir {
                std::fs::create_dir_all(dir)?;
                pending.push((dir.join(format!("{}_rgb_matched.png", v.name)), Image::from_data(w, h, 3, fitted), 8));
            }
        }
        let normal = normal_image(&out.normal, &out.alpha, w, h);
        if let Some(gt_n) = &v.normal {
            let alpha: Vec<f32> = v.image.data.chunks(4).map(|p| p[3]).collect();
            normal_mae.add_view(&normal, &gt_n.data, &alpha)?;
        }
        if !depth_views.is_empty() {
            let depth = svgir_train::coverage::expected_depth(&out.depth, &out.alpha);
            let seen = svgir_train::coverage::seen_count(&v.camera, &depth, &depth_views, 0.03);
            let m: Vec<f32> = seen.iter().map(|&c| (c > 0) as u8 as f32).collect();
            let inv: Vec<f32> = m.iter().map(|x| 1.0 - x).collect();
            let share = m.iter().sum::<f32>() / m.len() as f32;
            let part = |mask: &[f32]| svgir_metrics::psnr(&pred, &gt, 3, Some(mask)).ok().filter(|p| p.is_finite());
            coverage
                .push(json!({"view": v.name, "seen_share": share, "psnr_seen": part(&m), "psnr_unseen": part(&inv)}));
            if let Some(dir) = out_dir {
                std::fs::create_dir_all(dir)?;
                // The photo, tinted magenta where no training photo saw the surface.
                let tint: Vec<f32> = gt
                    .chunks_exact(3)
                    .zip(&m)
                    .flat_map(|(p, &s)| {
                        if s > 0.0 {
                            [p[0], p[1], p[2]]
                        } else {
                            [0.5 + 0.5 * p[0], 0.25 * p[1], 0.5 + 0.5 * p[2]]
                        }
                    })
                    .collect();
                pending.push((dir.join(format!("{}_seen.png", v.name)), Image::from_data(w, h, 3, tint), 8));
            }
        }
        if let Some(dir) = out_dir {
            std::fs::create_dir_all(dir)?;
            let vis: Vec<f32> = normal.iter().map(|n| 0.5 + 0.5 * n).collect();
            pending.push((dir.join(format!("{}_rgb.png", v.name)), Image::from_data(w, h, 3, pred), 8));
            pending.push((dir.join(format!("{}_normal.png", v.name)), Image::from_data(w, h, 3, vis), 8));
            pending.push((dir.join(format!("{}_depth.png", v.name)), depth_image(&out.depth, &out.alpha, w, h), 16));
            pending.push((dir.join(format!("{}_gt_rgb.png", v.name)), Image::from_data(w, h, 3, gt), 8));
            if let Some(gt_n) = &v.normal {
                pending.push((dir.join(format!("{}_gt_normal.png", v.name)), gt_n.map(|n| 0.5 + 0.5 * n), 8));
            }
        }
        pending.par_drain(..).try_for_each(|(path, img, bits)| svgir_io::write_png(path, &img, bits))?;
    }
    let n = views.len().max(1) as f64;
    let mut m = json!({"views": views.len(), "psnr": psnr / n, "ssim": ssim / n});
    if matched {
        m["psnr_matched"] = json!(psnr_matched / n);
    }
    if !coverage.is_empty() {
        m["coverage"] = json!(coverage);
    }
    if let Some(mae) = normal_mae.mean_deg() {
        m["normal_mae_deg"] = json!(mae);
    }
    Ok(m)
}

/// Unit rendered normals (0 where nothing was hit).
fn normal_image(sum_n: &[f32], alpha: &[f32], w: u32, h: u32) -> Vec<f32> {
    let mut out = vec![0.0; (w * h * 3) as usize];
    for i in 0..(w * h) as usize {
        let n = glam::Vec3::from_slice(&sum_n[3 * i..3 * i + 3]);
        if alpha[i] > 1e-3 {
            out[3 * i..3 * i + 3].copy_from_slice(&n.normalize_or_zero().to_array());
        }
    }
    out
}

/// Expected depth normalised to [0, 1] between its 2nd and 98th percentiles over the object
/// (near = dark; robust to a few floaters), background 1.
fn depth_image(sum_z: &[f32], alpha: &[f32], w: u32, h: u32) -> Image {
    let d = svgir_train::coverage::expected_depth(sum_z, alpha);
    let mut fin: Vec<f32> = d.iter().copied().filter(|x| x.is_finite()).collect();
    fin.sort_by(f32::total_cmp);
    let pct = |q: f32| fin.get(((fin.len().saturating_sub(1)) as f32 * q) as usize).copied().unwrap_or(0.0);
    let (lo, hi) = (pct(0.02), pct(0.98));
    let data =
        d.iter().map(|x| if x.is_finite() { ((x - lo) / (hi - lo).max(1e-6)).clamp(0.0, 1.0) } else { 1.0 }).collect();
    Image::from_data(w, h, 1, data)
}

fn finish(engine: &Engine, dataset: &Dataset, out: &Path) -> Result<()> {
    let trainer = engine.host();
    svgir_io::ply::write_gaussians_ply(out.join("point_cloud.ply"), &trainer.surfels, &[])?;
    let timings = json!({
        "iterations": trainer.iteration,
        "ms_per_iteration": engine.ms_per_iteration(),
        "threads": rayon::current_num_threads(),
        "device": engine.adapter().map_or_else(|| "cpu".to_string(), |a| a.name.clone()),
    });
    write_json(&out.join("timings.json"), &timings)?;
    eprintln!("evaluating on {} test views...", dataset.test.len());
    let m = evaluate(engine, dataset, usize::MAX, Some(&out.join("test")))?;
    write_json(&out.join("eval.json"), &m)?;
    println!("time per iteration (ms): {}", timings["ms_per_iteration"]);
    println!("Gaussians: {}", trainer.surfels.len());
    println!("test: {m}");
    println!("run folder: {}", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On resume, the given flags that set up a new run are named; those a resumed run honours
    /// (--iterations, --log-every, ...) and the defaults are not.
    #[test]
    fn resume_names_the_given_setup_flags() {
        let flags: Vec<String> = [
            "DATA",
            "--out",
            "OUT",
            "--resume",
            "--iterations",
            "900",
            "--log-every",
            "5",
            "--weight",
            "l1=0.5",
            "--profile",
            "views",
            "--densify-every",
            "7",
            "--background",
            "black",
        ]
        .map(String::from)
        .to_vec();
        let a = super::super::args_of::<TrainArgs>("train", &flags).unwrap();
        assert_eq!(ignored_on_resume(&a).unwrap(), ["--profile", "--background", "--densify-every", "--weight"]);
        assert!(ignored_on_resume(&default_args().unwrap()).unwrap().is_empty());
    }
}
