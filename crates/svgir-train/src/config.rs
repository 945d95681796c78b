//! Stage-1 training configuration (SPEC 2). Serialised into every run folder so a run can be
//! reproduced and resumed; every random choice derives from `seed`.

use crate::densify::DensifyConfig;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackgroundMode {
    White,
    Black,
    /// A new uniformly random colour every iteration (the photo is composited over the same).
    Random,
}

impl BackgroundMode {
    pub fn fixed_color(self) -> Option<[f32; 3]> {
        match self {
            BackgroundMode::White => Some([1.0; 3]),
            BackgroundMode::Black => Some([0.0; 3]),
            BackgroundMode::Random => None,
        }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LearningRates {
    /// Multiplied by the scene extent (SPEC 2), decayed exponentially to `position_final`.
    pub position_init: f32,
    pub position_final: f32,
    pub sh_dc: f32,
    /// Higher SH bands learn at `sh_dc / sh_rest_divisor`.
    pub sh_rest_divisor: f32,
    pub opacity: f32,
    pub scale: f32,
    pub rotation: f32,
}

impl Default for LearningRates {
    fn default() -> Self {
        Self {
            position_init: 1.6e-4,
            position_final: 1.6e-6,
            sh_dc: 2.5e-3,
            sh_rest_divisor: 20.0,
            opacity: 0.05,
            scale: 0.005,
            rotation: 0.001,
        }
    }
}

/// SPEC 2 stage-1 loss weights.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LossWeights {
    pub l1: f32,
    pub ssim: f32,
    pub mask: f32,
    /// Depth-normal weight ramps from `normal_start` to `normal_start + normal_ramp` over the run.
    pub normal_start: f32,
    pub normal_ramp: f32,
    pub entropy: f32,
    /// 2DGS depth distortion; 0 for object datasets as 2DGS's synthetic setting.
    pub distortion: f32,
}

/// Loss weights that can be set by name (`svgir train/inverse --weight NAME=VALUE`).
pub trait NamedWeights: Default {
    /// The weights' names, as `set` and the run config spell them.
    const NAMES: &'static [&'static str];
    /// Set one weight by name; `None` when no weight has that name (see `NAMES`).
    fn set(&mut self, name: &str, value: f32) -> Option<()>;
}

impl NamedWeights for LossWeights {
    const NAMES: &'static [&'static str] =
        &["l1", "ssim", "mask", "normal_start", "normal_ramp", "entropy", "distortion"];

    fn set(&mut self, name: &str, value: f32) -> Option<()> {
        let w = match name {
            "l1" => &mut self.l1,
            "ssim" => &mut self.ssim,
            "mask" => &mut self.mask,
            "normal_start" => &mut self.normal_start,
            "normal_ramp" => &mut self.normal_ramp,
            "entropy" => &mut self.entropy,
            "distortion" => &mut self.distortion,
            _ => return None,
        };
        *w = value;
        Some(())
    }
}

impl Default for LossWeights {
    fn default() -> Self {
        Self { l1: 0.9, ssim: 0.1, mask: 0.01, normal_start: 0.01, normal_ramp: 0.01, entropy: 0.1, distortion: 0.0 }
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Stage1Config {
    pub iterations: u64,
    pub seed: u64,
    pub max_sh_degree: u32,
    /// Raise the active SH degree by one every this many iterations (3DGS: 1000).
    pub sh_upgrade_interval: u64,
    pub background: BackgroundMode,
    /// Random initial points when the dataset has none (SPEC 2: 100k in [-1.3, 1.3]^3).
    pub init_points: usize,
    pub init_half_extent: f32,
    pub lr: LearningRates,
    pub loss: LossWeights,
    pub densify: DensifyConfig,
    /// Use the mask and entropy losses (datasets with a meaningful alpha channel).
    pub use_mask: bool,
}

impl Default for Stage1Config {
    fn default() -> Self {
        Self {
            iterations: 30_000,
            seed: 0,
            max_sh_degree: 3,
            sh_upgrade_interval: 1000,
            background: BackgroundMode::White,
            init_points: 100_000,
            init_half_extent: 1.3,
            lr: LearningRates::default(),
            loss: LossWeights::default(),
            densify: DensifyConfig::default(),
            use_mask: true,
        }
    }
}

impl Stage1Config {
    /// Scale the schedule (densification window, resets, SH upgrades) to a shorter run, keeping
    /// the proportions of the 30k-iteration reference schedule.
    pub fn scaled_to(mut self, iterations: u64) -> Self {
        let f = iterations as f64 / self.iterations as f64;
        let sc = |x: u64| ((x as f64 * f).round() as u64).max(1);
        self.iterations = iterations;
        self.sh_upgrade_interval = sc(self.sh_upgrade_interval);
        self.densify.from_iter = sc(self.densify.from_iter);
        self.densify.until_iter = sc(self.densify.until_iter);
        self.densify.interval = sc(self.densify.interval).max(10);
        self.densify.opacity_reset_interval = sc(self.densify.opacity_reset_interval);
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stage2::Stage2Weights;

    /// Every listed name sets exactly one field, and an unknown name sets nothing.
    fn names_are_settable<W: NamedWeights + Serialize>() {
        let base = serde_json::to_value(W::default()).unwrap();
        for name in W::NAMES {
            let mut w = W::default();
            assert!(w.set(name, 123.0).is_some(), "{name}");
            let v = serde_json::to_value(&w).unwrap();
            assert_eq!(v[name], 123.0, "{name}");
            let changed = base.as_object().unwrap().iter().filter(|(k, x)| v[k.as_str()] != **x).count();
            assert_eq!(changed, 1, "{name}");
        }
        assert!(W::default().set("no_such_weight", 1.0).is_none());
    }

    #[test]
    fn loss_weights_set_by_name() {
        names_are_settable::<LossWeights>();
        names_are_settable::<Stage2Weights>();
    }
}
