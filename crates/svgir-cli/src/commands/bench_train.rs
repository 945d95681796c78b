//! `svgir bench train`: the convergence benchmark. Trains stage 1 on each scene with periodic
//! test evaluations, then prints test PSNR against training wall time (evaluations excluded) as
//! a table and draws it as `OUT/convergence.svg`, stamped with the date, commit, machine and
//! threads, so that a regression in speed or quality shows as a curve that moved.

use super::train::{self, TrainArgs};
use anyhow::{Context, Result};
use clap::Args;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use svgir_eval::plot::{line_plot, Series};
use svgir_gpu::DeviceChoice;

/// `svgir bench train` settings.
#[derive(Args, Clone, Debug)]
pub struct TrainBenchArgs {
    /// train: scenes to train (default: NeRF-synthetic lego_400 from ../shared/data and the
    /// shipped bowl_fruit_128). Repeatable.
    #[arg(long = "scene", value_name = "DATA")]
    pub scenes: Vec<PathBuf>,
    /// train: stage-1 iterations per scene.
    #[arg(long = "train-iterations", default_value_t = 10_000)]
    pub iterations: u64,
    /// train: evaluate on the test views every this many iterations.
    #[arg(long = "train-eval-every", default_value_t = 1000)]
    pub eval_every: u64,
    /// train: test views per intermediate evaluation (spread over the test set; the last point
    /// uses all of them).
    #[arg(long = "train-eval-views", default_value_t = 20)]
    pub eval_views: usize,
    /// train: folder of the runs and the curve.
    #[arg(long = "train-out", default_value = "runs/convergence")]
    pub out: PathBuf,
    /// train: draw the curve from the runs already in --train-out instead of training.
    #[arg(long = "plot-only")]
    pub plot_only: bool,
}

/// The default scenes: lego_400 (when the shared data is there) and the shipped scene.
fn default_scenes() -> Vec<PathBuf> {
    let lego = PathBuf::from("../shared/data/nerf_synthetic/lego_400");
    let shipped = PathBuf::from(super::demo::EMBEDDED_SCENE);
    if lego.exists() {
        vec![lego, shipped]
    } else {
        eprintln!("warning: {} not found; benchmarking the shipped scene only", lego.display());
        vec![shipped]
    }
}

/// One scene's convergence: its (training minutes, test PSNR) points, the final PSNR on all
/// test views and the iterations trained.
struct Curve {
    points: Vec<(f64, f64)>,
    final_psnr: f64,
    iterations: u64,
}

/// A run's [`Curve`] from its `metrics.jsonl`, ending with the final evaluation on all test
/// views (`eval.json`).
fn curve(run: &Path) -> Result<Curve> {
    let text = std::fs::read_to_string(run.join("metrics.jsonl"))
        .with_context(|| format!("{}: no metrics.jsonl (train it first)", run.display()))?;
    let lines: Vec<Value> = text.lines().filter_map(|l| serde_json::from_str(l).ok()).collect();
    let mut points: Vec<(f64, f64)> =
        lines.iter().filter_map(|v| Some((v["train_s"].as_f64()? / 60.0, v["test"]["psnr"].as_f64()?))).collect();
    let last_s = lines.iter().filter_map(|v| v["train_s"].as_f64()).fold(0.0, f64::max);
    let iterations = lines.iter().filter_map(|v| v["iteration"].as_u64()).max().unwrap_or(0);
    let eval = svgir_eval::read_json(&run.join("eval.json"), "the run did not finish")?;
    let final_psnr = eval["psnr"].as_f64().with_context(|| format!("{}: no PSNR in eval.json", run.display()))?;
    points.push((last_s / 60.0, final_psnr));
    Ok(Curve { points, final_psnr, iterations })
}

/// Minutes until the curve first reaches `db` (linear between evaluations), if it does.
fn minutes_to(points: &[(f64, f64)], db: f64) -> Option<f64> {
    let first = points.first()?;
    if first.1 >= db {
        return Some(first.0);
    }
    points.windows(2).find(|w| w[1].1 >= db).map(|w| w[0].0 + (db - w[0].1) / (w[1].1 - w[0].1) * (w[1].0 - w[0].0))
}

fn commit() -> String {
    std::process::Command::new("git")
        .args(["rev-parse", "--short", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_else(|| "unknown".into())
}

fn today() -> String {
    std::process::Command::new("date")
        .arg("+%Y-%m-%d")
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default()
}

/// The device a run trained on (`timings.json`): `cpu` or the adapter's name.
fn device_of(run: &Path) -> String {
    std::fs::read_to_string(run.join("timings.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
        .and_then(|v| v["device"].as_str().map(str::to_string))
        .unwrap_or_else(|| "cpu".into())
}

/// Runs the benchmark and returns its table.
pub fn run(args: &TrainBenchArgs, devices: &[DeviceChoice], machine: &str, threads: usize) -> Result<String> {
    let scenes = if args.scenes.is_empty() { default_scenes() } else { args.scenes.clone() };
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let name_of = |p: &Path| p.file_name().map_or("scene".into(), |n| n.to_string_lossy().into_owned());
    let mut series = Vec::new();
    let mut table = String::from(
        "| scene | device | iterations | training min | final test PSNR | min to 30 dB | min to 32 dB |\n\
         |---|---|---|---|---|---|---|\n",
    );
    let mut record = Vec::new();
    for (scene, &device) in scenes.iter().flat_map(|s| devices.iter().map(move |d| (s, d))) {
        let label = if devices.len() > 1 { format!("{}-{device}", name_of(scene)) } else { name_of(scene) };
        let run = args.out.join(&label);
        if !args.plot_only {
            if run.exists() {
                std::fs::remove_dir_all(&run).with_context(|| format!("clearing {}", run.display()))?;
            }
            let flags: Vec<String> = [
                scene.display().to_string(),
                "--out".into(),
                run.display().to_string(),
                "--iterations".into(),
                args.iterations.to_string(),
                "--eval-every".into(),
                args.eval_every.to_string(),
                "--eval-views".into(),
                args.eval_views.to_string(),
                "--device".into(),
                device.to_string(),
            ]
            .into();
            eprintln!("svgir bench train: {} ({} iterations)", scene.display(), args.iterations);
            train::run(super::args_of::<TrainArgs>("train", &flags)?)?;
        }
        let Curve { points, final_psnr, iterations } = curve(&run)?;
        let fmt = |m: Option<f64>| m.map_or("-".to_string(), |m| format!("{m:.1}"));
        let total = points.last().map_or(0.0, |p| p.0);
        table += &format!(
            "| {} | {} | {iterations} | {total:.1} | {final_psnr:.2} | {} | {} |\n",
            name_of(scene),
            device_of(&run),
            fmt(minutes_to(&points, 30.0)),
            fmt(minutes_to(&points, 32.0)),
        );
        record.push(json!({"scene": scene, "device": device_of(&run), "iterations": iterations,
            "points_min_psnr": points, "final_psnr": final_psnr}));
        series.push(Series { name: label, points });
    }
    let stamp = format!("{}, commit {}, {machine}, {threads} threads", today(), commit());
    let xlabel = format!("training minutes, evaluations excluded ({}, {}, {threads} threads)", today(), commit());
    let svg = line_plot(&series, "svgir stage 1: test PSNR vs training time", &xlabel, "test PSNR (dB)", 760.0, 340.0);
    let write = |name: &str, text: String| -> Result<()> {
        let path = args.out.join(name);
        let tmp = path.with_extension("tmp");
        std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, &path).with_context(|| format!("writing {}", path.display()))
    };
    write("convergence.svg", svg)?;
    write("convergence.json", serde_json::to_string_pretty(&json!({"stamp": stamp, "scenes": record}))?)?;
    Ok(format!("svgir bench train ({stamp})\n{table}curve: {}", args.out.join("convergence.svg").display()))
}

#[cfg(test)]
mod tests {
    use super::minutes_to;

    #[test]
    fn minutes_to_interpolates_between_evaluations() {
        let pts = [(1.0, 20.0), (3.0, 28.0), (5.0, 32.0)];
        assert_eq!(minutes_to(&pts, 30.0), Some(4.0));
        assert_eq!(minutes_to(&pts, 10.0), Some(1.0));
        assert_eq!(minutes_to(&pts, 33.0), None);
    }

    #[test]
    fn train_args_take_the_command_defaults() {
        let a: super::TrainArgs =
            super::super::args_of("train", &["scene".into(), "--out".into(), "x".into()]).unwrap();
        assert_eq!((a.iterations, a.seed, a.eval_every), (30_000, 0, 0));
    }
}
