//! Stage-1 training configuration (SPEC 2). Serialised into every run folder so a run can be
//! reproduced and resumed; every random choice derives from `seed`.

use crate::densify::DensifyConfig;
use serde::{Deserialize, Serialize};

/// Colour the renders and photos are composited over during training.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackgroundMode {
    /// White (1, 1, 1).
    White,
    /// Black (0, 0, 0).
    Black,
    /// A new uniformly random colour every iteration (the photo is composited over the same).
    Random,
}

/// How the training view of each iteration is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ViewOrder {
    /// Independently at random every iteration (with replacement; runs before `view_order`
    /// existed, so their checkpoints resume as they ran).
    Uniform,
    /// Each view once per epoch, in a fresh random order (3DGS's `viewpoint_stack`).
    Epochs,
}

impl ViewOrder {
    fn before_the_option() -> Self {
        Self::Uniform
    }
}

impl BackgroundMode {
    /// The constant colour of this mode, `None` for `Random`.
    pub fn fixed_color(self) -> Option<[f32; 3]> {
        match self {
            BackgroundMode::White => Some([1.0; 3]),
            BackgroundMode::Black => Some([0.0; 3]),
            BackgroundMode::Random => None,
        }
    }
}

/// Which family of defaults a run starts from; chosen from the dataset ([`Profile::for_dataset`])
/// unless the user names one, printed, and recorded in `config.json`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    /// A masked object over a plain background (NeRF-synthetic, TensoIR, masked captures): SPEC 2's
    /// schedule scaled to the run, mask and entropy losses, a Gaussian budget against overfitting
    /// few small views.
    #[default]
    Object,
    /// Photos of a real scene, background included: 3DGS's real-data schedule in absolute
    /// iterations, no budget, and a random background during training so that the scene's own
    /// background is modelled by Gaussians.
    Capture,
    /// Novel views of a masked object, as 3DGS is benchmarked: the object schedule with 3DGS's
    /// loss alone (L1 0.8 + D-SSIM 0.2; no mask, entropy or depth-normal terms). Its test PSNR is
    /// higher, but nothing holds its surfels to the surface or the mask, so its normals are not
    /// what `svgir inverse` needs.
    Views,
}

impl Profile {
    /// Masked datasets are objects; everything else is a capture.
    pub fn for_dataset(has_masks: bool) -> Self {
        if has_masks {
            Profile::Object
        } else {
            Profile::Capture
        }
    }

    /// Lowercase name as written in `config.json` and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Profile::Object => "object",
            Profile::Capture => "capture",
            Profile::Views => "views",
        }
    }

    /// One line for the console: what the profile does.
    pub fn describe(self) -> &'static str {
        match self {
            Profile::Object => {
                "masked object: SPEC 2 schedule scaled to the run, mask + entropy losses, Gaussian budget"
            }
            Profile::Capture => {
                "real capture: 3DGS schedule (densify every 100 from 500 to min(15k, half the run), opacity reset \
                 every 3k, SH +1 every 1k), no budget, background modelled by Gaussians (random bg)"
            }
            Profile::Views => {
                "novel views of an object: SPEC 2 schedule scaled to the run, 3DGS's loss alone (L1 + D-SSIM), \
                 Gaussian budget; not a stage 1 for svgir inverse"
            }
        }
    }
}

/// Stage-1 Adam learning rates per Gaussian attribute (SPEC 2).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LearningRates {
    /// Multiplied by the scene extent (SPEC 2), decayed exponentially to `position_final`.
    pub position_init: f32,
    /// Position learning rate at the end of the run, times the scene extent.
    pub position_final: f32,
    /// Learning rate of the SH DC (base colour) coefficients.
    pub sh_dc: f32,
    /// Higher SH bands learn at `sh_dc / sh_rest_divisor`.
    pub sh_rest_divisor: f32,
    /// Learning rate of the opacity logits.
    pub opacity: f32,
    /// Learning rate of the log scales.
    pub scale: f32,
    /// Learning rate of the rotation quaternions.
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
    /// Weight of the L1 photometric term.
    pub l1: f32,
    /// Weight of the D-SSIM term.
    pub ssim: f32,
    /// Weight of the mask (alpha) loss.
    pub mask: f32,
    /// Depth-normal weight ramps from `normal_start` to `normal_start + normal_ramp` over the run.
    pub normal_start: f32,
    /// Added to the depth-normal weight over the run (see `normal_start`).
    pub normal_ramp: f32,
    /// Weight of the opacity entropy loss.
    pub entropy: f32,
    /// 2DGS depth distortion; 0 for object datasets as 2DGS's synthetic setting.
    pub distortion: f32,
    /// Weight of the binary-opacity term: the mean over the Gaussians of their opacity's binary
    /// entropy, once densification has ended (`crate::losses::opacity`). Off by default.
    #[serde(default)]
    pub opacity_binary: f32,
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
        &["l1", "ssim", "mask", "normal_start", "normal_ramp", "entropy", "distortion", "opacity_binary"];

    fn set(&mut self, name: &str, value: f32) -> Option<()> {
        let w = match name {
            "l1" => &mut self.l1,
            "ssim" => &mut self.ssim,
            "mask" => &mut self.mask,
            "normal_start" => &mut self.normal_start,
            "normal_ramp" => &mut self.normal_ramp,
            "entropy" => &mut self.entropy,
            "distortion" => &mut self.distortion,
            "opacity_binary" => &mut self.opacity_binary,
            _ => return None,
        };
        *w = value;
        Some(())
    }
}

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            l1: 0.9,
            ssim: 0.1,
            mask: 0.01,
            normal_start: 0.01,
            normal_ramp: 0.01,
            entropy: 0.1,
            distortion: 0.0,
            opacity_binary: 0.0,
        }
    }
}

/// Everything stage 1 (SPEC 2) needs to run; saved as the run's `config.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Stage1Config {
    /// Training iterations (one view each).
    pub iterations: u64,
    /// Seed of every random choice of the run.
    pub seed: u64,
    /// Highest SH degree the radiance reaches (0..=3).
    pub max_sh_degree: u32,
    /// Raise the active SH degree by one every this many iterations (3DGS: 1000).
    pub sh_upgrade_interval: u64,
    /// Background the renders and photos are composited over.
    pub background: BackgroundMode,
    /// Random initial points when the dataset has none (SPEC 2: 100k in [-1.3, 1.3]^3).
    pub init_points: usize,
    /// Half side of the cube the random initial points fill, world units.
    pub init_half_extent: f32,
    /// Learning rates per attribute.
    pub lr: LearningRates,
    /// Loss weights.
    pub loss: LossWeights,
    /// Densification, pruning and opacity-reset schedule.
    pub densify: DensifyConfig,
    /// Use the mask and entropy losses (datasets with a meaningful alpha channel).
    pub use_mask: bool,
    /// The depth-distortion term (`loss.distortion`) applies from this iteration on (2DGS: 3000).
    #[serde(default)]
    pub distortion_from: u64,
    /// The defaults this configuration started from.
    #[serde(default)]
    pub profile: Profile,
    /// Near plane as a fraction of the camera extent, for captures in arbitrary units; `None`:
    /// the rasteriser's 0.2 world units, the synthetic scenes' setting (their cameras are 4 units
    /// away).
    #[serde(default)]
    pub near_fraction: Option<f32>,
    /// Learn a per-image affine colour correction (exposure / white balance of phone photos).
    /// Test views are rendered without one.
    #[serde(default)]
    pub exposure: bool,
    /// How each iteration's training view is drawn.
    #[serde(default = "ViewOrder::before_the_option")]
    pub view_order: ViewOrder,
    /// Iterations `1..=half_res_until` train on the photos area-filtered to half their size
    /// (0: none). A coarse-to-fine schedule: those iterations cost about half as much, and on
    /// lego_400 the first half of a run at half size loses 0.3 dB for a quarter of the time
    /// (docs/experiments.md).
    #[serde(default)]
    pub half_res_until: u64,
}

/// [`Stage1Config::near_fraction`] of captures: 0.2 units at an extent of 4.4.
pub const CAPTURE_NEAR_FRACTION: f32 = 0.045;

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
            distortion_from: 0,
            profile: Profile::Object,
            near_fraction: None,
            exposure: false,
            view_order: ViewOrder::Epochs,
            half_res_until: 0,
        }
    }
}

impl Stage1Config {
    /// The loss weights at iteration `it` (1-based): the distortion weight is 0 before
    /// `distortion_from`.
    pub fn weights_at(&self, it: u64) -> LossWeights {
        let mut w = self.loss.clone();
        if it < self.distortion_from {
            w.distortion = 0.0;
        }
        w
    }

    /// Whether iteration `it` (1-based) ends by resetting every opacity (SPEC 2: every
    /// `opacity_reset_interval` iterations while densifying).
    pub fn resets_opacity_at(&self, it: u64) -> bool {
        it <= self.densify.until_iter && it.is_multiple_of(self.densify.opacity_reset_interval)
    }

    /// The defaults of `profile` for a run of `iterations` on `training_pixels` pixels.
    pub fn for_profile(profile: Profile, iterations: u64, training_pixels: usize) -> Self {
        match profile {
            Profile::Object => {
                let mut c = Self::default().scaled_to(iterations);
                c.densify.max_gaussians = crate::densify::default_max_gaussians(training_pixels);
                // Measured on the synthetic table (docs/experiments.md): with views drawn by
                // epoch, bowl_fruit_128's albedo after stage 2 is 0.18 dB lower and its normal
                // MAE 0.17 deg higher than with independent draws, at both seeds tried.
                c.view_order = ViewOrder::Uniform;
                c
            }
            Profile::Views => {
                let mut c = Self {
                    profile,
                    use_mask: false,
                    // 3DGS's protocol (its `viewpoint_stack`).
                    view_order: ViewOrder::Epochs,
                    ..Self::for_profile(Profile::Object, iterations, training_pixels)
                };
                c.loss = LossWeights {
                    l1: 0.8,
                    ssim: 0.2,
                    mask: 0.0,
                    normal_start: 0.0,
                    normal_ramp: 0.0,
                    entropy: 0.0,
                    distortion: 0.0,
                    opacity_binary: 0.0,
                };
                c
            }
            Profile::Capture => {
                let mut c = Self { iterations, profile, use_mask: false, ..Self::default() };
                // 3DGS's real-data settings, in absolute iterations: its 7k results are snapshots
                // of the 30k schedule, so a short run keeps the cadence instead of compressing it.
                c.background = BackgroundMode::Random;
                c.near_fraction = Some(CAPTURE_NEAR_FRACTION);
                c.loss.l1 = 0.8;
                c.loss.ssim = 0.2;
                // Runs shorter than 1000 iterations (tests, previews) start densifying earlier
                // so that they densify at all.
                c.densify.from_iter = (iterations / 10).min(500);
                c.densify.until_iter = (iterations / 2).min(15_000);
                c.densify.grad_threshold = 2e-4;
                c.densify.max_gaussians = usize::MAX;
                c
            }
        }
    }

    /// Switch the mask and entropy losses off unless `masks` (the dataset has foreground masks
    /// and the user did not turn them off). Never on: a profile without them (`views`,
    /// `capture`) keeps them off on a masked dataset, or `config.json` would record them on and
    /// the losses would be computed at weight 0.
    pub fn mask_losses_only_with(&mut self, masks: bool) {
        self.use_mask &= masks;
    }

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
    fn distortion_starts_at_its_iteration() {
        let mut c = Stage1Config::default();
        c.loss.distortion = 100.0;
        c.distortion_from = 3000;
        assert_eq!(c.weights_at(2999).distortion, 0.0);
        assert_eq!(c.weights_at(3000).distortion, 100.0);
        assert_eq!(c.weights_at(2999).l1, c.loss.l1);
    }

    #[test]
    fn opacity_resets_stop_with_densification() {
        let c = Stage1Config::default().scaled_to(5000);
        assert_eq!(c.densify.opacity_reset_interval, 500);
        assert!(c.resets_opacity_at(500) && c.resets_opacity_at(2500));
        assert!(!c.resets_opacity_at(501) && !c.resets_opacity_at(3000));
    }

    #[test]
    fn views_profile_is_the_object_schedule_with_3dgs_loss() {
        let (obj, views) = (
            Stage1Config::for_profile(Profile::Object, 5000, 100 * 400 * 400),
            Stage1Config::for_profile(Profile::Views, 5000, 100 * 400 * 400),
        );
        assert_eq!(serde_json::to_value(&views.densify).unwrap(), serde_json::to_value(&obj.densify).unwrap());
        assert_eq!((views.iterations, views.background, views.profile), (5000, obj.background, Profile::Views));
        let l = &views.loss;
        assert_eq!((l.l1, l.ssim), (0.8, 0.2));
        assert_eq!([l.mask, l.entropy, l.normal_start, l.normal_ramp, l.distortion], [0.0; 5]);
        assert!(!views.use_mask && obj.use_mask && obj.loss.entropy > 0.0);
        // Views are drawn as 3DGS does for the novel-view profile, independently for objects.
        let capture = Stage1Config::for_profile(Profile::Capture, 5000, 100 * 400 * 400);
        assert_eq!(
            (obj.view_order, views.view_order, capture.view_order),
            (ViewOrder::Uniform, ViewOrder::Epochs, ViewOrder::Epochs)
        );
    }

    /// The dataset's masks switch the mask losses on only for a profile that has them; the
    /// `views` and `capture` profiles keep them off on a masked dataset.
    #[test]
    fn masks_are_used_only_when_the_profile_wants_them() {
        let with = |profile, masks| {
            let mut c = Stage1Config::for_profile(profile, 5000, 100 * 400 * 400);
            c.mask_losses_only_with(masks);
            c.use_mask
        };
        assert!(with(Profile::Object, true));
        assert!(!with(Profile::Object, false), "no masks in the dataset (or --no-mask)");
        assert!(!with(Profile::Views, true), "views profile on a masked dataset");
        assert!(!with(Profile::Capture, true), "capture profile on a masked dataset");
    }

    #[test]
    fn loss_weights_set_by_name() {
        names_are_settable::<LossWeights>();
        names_are_settable::<Stage2Weights>();
    }
}
