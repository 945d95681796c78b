//! A run folder as the evaluation reads it: its JSON files and the dataset it was trained on.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use svgir_core::Dataset;

/// A JSON file (a run's `config.json` or `eval.json`); errors name the file, and a missing or
/// unreadable one says `missing_hint` (e.g. which command writes it) when that is not empty.
pub fn read_json(path: &Path, missing_hint: &str) -> Result<serde_json::Value> {
    let hint = if missing_hint.is_empty() { String::new() } else { format!(" ({missing_hint})") };
    let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read{hint}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))
}

/// The dataset a stage-1 run was trained on, with its test views (`data` overrides the path in
/// `RUN/config.json`), loaded with the run's own resolution options; and its path.
pub fn load_run_dataset(stage1_run: &Path, data: Option<&Path>) -> Result<(Dataset, PathBuf)> {
    let cfg_path = stage1_run.join("config.json");
    let run_cfg = read_json(&cfg_path, "")?;
    let data = match data {
        Some(d) => d.to_path_buf(),
        None => {
            PathBuf::from(run_cfg["data"].as_str().with_context(|| format!("{}: no data path", cfg_path.display()))?)
        }
    };
    let load = &run_cfg["load"];
    let opts = svgir_io::LoadOptions {
        resolution: load["resolution"].as_u64().map(|v| v as u32),
        downscale: load["downscale"].as_f64().map(|v| v as f32),
        load_test: true,
        max_views: load["max_views"].as_u64().map(|v| v as usize),
        masks: load["masks"].as_str().map(PathBuf::from),
    };
    Ok((svgir_io::load_dataset(&data, &opts)?, data))
}
