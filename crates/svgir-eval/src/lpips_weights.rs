//! The LPIPS network weights the evaluation uses, found next to the checkout.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use svgir_metrics::{Lpips, Net};

/// The weights file of `net` in `../shared/data/lpips` (from the working directory, or from the
/// executable's location in a checkout), if present.
pub fn default_lpips_weights(net: Net) -> Option<PathBuf> {
    let name = match net {
        Net::Vgg => "lpips_vgg_v0.1.safetensors",
        Net::Alex => "lpips_alex_v0.1.safetensors",
    };
    let exe_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(Path::to_path_buf));
    let candidates =
        [Some(PathBuf::from("../shared/data/lpips")), exe_dir.map(|d| d.join("../../../shared/data/lpips"))];
    candidates.into_iter().flatten().map(|d| d.join(name)).find(|p| p.exists())
}

/// LPIPS with `net`'s weights (`None`: no LPIPS). Missing weights leave LPIPS out with a warning.
pub fn load_lpips(net: Option<Net>) -> Result<Option<Lpips>> {
    let Some(net) = net else { return Ok(None) };
    let Some(path) = default_lpips_weights(net) else {
        eprintln!("warning: LPIPS weights not found next to the checkout; LPIPS is left out");
        return Ok(None);
    };
    let bytes = std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?;
    Ok(Some(Lpips::from_safetensors(&bytes, net).with_context(|| path.display().to_string())?))
}
