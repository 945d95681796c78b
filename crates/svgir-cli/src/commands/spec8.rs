//! The flags of SPEC 8's evaluation (`svgir_eval::spec8`) that `svgir inverse`, `svgir eval`
//! and `svgir demo` share: how the test views are relit, and extra maps to relight under.

use std::path::PathBuf;
use svgir_core::LightInfo;
use svgir_train::relight::RelightSampling;

/// How the evaluation relights (SPEC 7), for `svgir inverse` and `svgir eval`.
#[derive(clap::Args, Clone, Debug)]
pub struct EvalRelightArgs {
    /// Directions per Gaussian when relighting for the evaluation (SPEC 7: 384; memory is
    /// Gaussians x K x 16 bytes).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = svgir_train::relight::RELIGHT_DIRECTIONS)]
    pub relight_directions: usize,
    /// Brightest texels of each relighting map shaded as directional lights with traced
    /// visibility when relighting for the evaluation (0: the K directions alone, as SPEC 7).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = svgir_train::relight::RELIGHT_LIGHTS)]
    pub relight_lights: usize,
    /// Diffuse bounces of indirect light added to SPEC 7's one-bounce term when relighting for
    /// the evaluation (0: Eqn 13 alone).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = svgir_train::relight::RELIGHT_BOUNCES)]
    pub relight_bounces: usize,
    /// Also relight under these HDR maps: test views and a turntable. Repeatable.
    ///
    /// Without metrics (a capture has no relit ground truth).
    #[arg(long = "relight-with", value_name = "MAP.hdr")]
    pub relight_with: Vec<PathBuf>,
    /// Strength of the --relight-with maps (default: exposed like the photos).
    ///
    /// By default each map is scaled to the mean radiance of the learned light, so relit
    /// pictures are exposed like the photos.
    #[arg(long)]
    pub relight_strength: Option<f32>,
}

impl EvalRelightArgs {
    /// `--relight-with` maps as lights named by their file stems.
    pub fn extra_lights(&self) -> Vec<LightInfo> {
        self.relight_with
            .iter()
            .map(|p| LightInfo {
                name: p.file_stem().map_or("map".into(), |s| s.to_string_lossy().into_owned()),
                envmap_path: Some(p.clone()),
                // NaN: matched to the learned light in `evaluate`.
                strength: self.relight_strength.unwrap_or(f32::NAN),
            })
            .collect()
    }

    /// The relighting sampling these flags ask for.
    pub fn sampling(&self) -> RelightSampling {
        RelightSampling {
            directions: self.relight_directions,
            lights: self.relight_lights,
            bounces: self.relight_bounces,
        }
    }
}
