//! One module per subcommand.

/// The help heading of research switches, ablations and diagnostics: listed by `--help`, left
/// out of `-h` so that the everyday options fit on one screen.
pub const ADVANCED: &str = "Advanced (research switches, ablations, diagnostics)";

pub mod bench;
pub mod bench_stages;
pub mod bench_train;
pub mod capture;
pub mod demo;
pub mod engine;
pub mod eval;
pub mod export;
pub mod info;
pub mod inverse;
pub mod masks;
pub mod relight;
pub mod report;
pub mod spec8;
pub mod train;
pub mod view;

use clap::Args;
use svgir_io::LoadOptions;

/// Dataset loading options shared by every command that reads a dataset.
#[derive(Args, Clone, Debug)]
pub struct DataArgs {
    /// Dataset folder: NeRF/Blender (transforms_*.json), TensoIR (per-view folders) or COLMAP (sparse/ + images/).
    pub data: std::path::PathBuf,
    /// Resize images on load to this width (keeps aspect; area filter).
    #[arg(long, conflicts_with = "downscale")]
    pub resolution: Option<u32>,
    /// Divide the image size by this factor on load (area filter).
    #[arg(long)]
    pub downscale: Option<f32>,
    /// Load at most this many views per split (for quick experiments).
    #[arg(long)]
    pub max_views: Option<usize>,
    /// Foreground masks from this folder (one image per photo, named like it, e.g. from
    /// `svgir masks`) instead of DATASET/masks; captures only.
    #[arg(long)]
    pub masks: Option<std::path::PathBuf>,
}

impl DataArgs {
    pub fn load_options(&self, load_test: bool) -> LoadOptions {
        LoadOptions {
            resolution: self.resolution,
            downscale: self.downscale,
            load_test,
            max_views: self.max_views,
            masks: self.masks.clone(),
        }
    }
}

/// `base` (a profile's loss weights) with each `NAME=VALUE` of `--weight` applied; a bad name or
/// value is an error that names it.
pub fn loss_weights_over<W: svgir_train::NamedWeights>(mut weights: W, overrides: &[String]) -> anyhow::Result<W> {
    use anyhow::Context;
    for item in overrides {
        let (name, value) = item.split_once('=').with_context(|| format!("--weight {item}: expected NAME=VALUE"))?;
        let value: f32 = value.trim().parse().with_context(|| format!("--weight {item}: {value:?} is not a number"))?;
        anyhow::ensure!(value.is_finite() && value >= 0.0, "--weight {item}: a weight must be finite and >= 0");
        weights
            .set(name.trim(), value)
            .with_context(|| format!("--weight {item}: no weight named {name:?} (one of {})", W::NAMES.join(", ")))?;
    }
    Ok(weights)
}

/// `(flag, value)` pairs as the argument list `args_of` takes.
pub fn flag_list(pairs: &[(&str, String)]) -> Vec<String> {
    pairs.iter().flat_map(|(k, v)| [k.to_string(), v.clone()]).collect()
}

/// A command's arguments with its own defaults and the given `flags` (as typed after the command
/// name), for commands that run other commands (`demo`, `bench train`).
pub fn args_of<T: clap::Args>(command: &str, flags: &[String]) -> anyhow::Result<T> {
    use anyhow::Context;
    #[derive(clap::Parser)]
    struct Wrap<A: clap::Args> {
        #[command(flatten)]
        args: A,
    }
    let argv = std::iter::once(command.to_string()).chain(flags.iter().cloned());
    Ok(<Wrap<T> as clap::Parser>::try_parse_from(argv).with_context(|| format!("building `{command}` arguments"))?.args)
}

#[cfg(test)]
mod tests {
    use super::loss_weights_over;
    use svgir_train::stage2::Stage2Weights;

    #[test]
    fn weight_overrides_apply_and_bad_ones_are_named() {
        let w =
            loss_weights_over(Stage2Weights::default(), &["smooth_albedo=0.5".into(), " env_tv = 0 ".into()]).unwrap();
        assert_eq!((w.smooth_albedo, w.env_tv), (0.5, 0.0));
        assert_eq!(w.l1, 0.9);
        for (bad, says) in [
            ("albedo=1", "no weight named"),
            ("smooth_albedo", "expected NAME=VALUE"),
            ("l1=x", "not a number"),
            ("l1=-1", ">= 0"),
            ("l1=NaN", "finite"),
        ] {
            let err = format!("{:#}", loss_weights_over(Stage2Weights::default(), &[bad.into()]).unwrap_err());
            assert!(err.contains(says) && err.contains(bad), "{bad}: {err}");
        }
    }
}
