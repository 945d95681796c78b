//! Splat outputs of `svgir export` (filled in below).

use super::ExportArgs;
use anyhow::Result;
use std::path::PathBuf;
use svgir_train::stage2::Stage2;

pub fn export(
    _args: &ExportArgs,
    _s2: &Stage2,
    _out: &mut Vec<(PathBuf, Vec<u8>)>,
    _report: &mut serde_json::Value,
) -> Result<()> {
    anyhow::bail!("splat export is not available yet")
}
