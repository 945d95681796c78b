//! Stage 2's configuration: loss weights (Eqn 15), learning rates (SPEC 6), ablation switches
//! and our tracing and lighting options, all recorded in the run's `config.json`.

use super::ShadeSets;
use crate::composite::Coverage;
use crate::config::{BackgroundMode, NamedWeights};
use serde::{Deserialize, Serialize};
use svgir_pbr::EnvActivation;
use svgir_shading::Diffuse;
use svgir_trace::TraceParams;

/// Stage-2 loss weights (Eqn 15, SPEC 6).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Stage2Weights {
    /// Weight of the L1 photometric term.
    pub l1: f32,
    /// Weight of the D-SSIM term.
    pub ssim: f32,
    /// Weight of the radiance-consistency loss L_rc.
    pub consistency: f32,
    /// Weight of the depth-normal consistency loss.
    pub normal: f32,
    /// Weight of the albedo smoothness loss.
    pub smooth_albedo: f32,
    /// Weight of the roughness smoothness loss.
    pub smooth_roughness: f32,
    /// Weight of the `|dN|^2` normal-offset penalty (SPEC 9.7).
    pub normal_offset: f32,
    /// Weight of the environment map's TV-L2 regulariser.
    pub env_tv: f32,
    /// Edge-aware smoothness of the splatted shading normals over a depth guide (our addition,
    /// 0 = SPEC: stage 1's normals copy textures, tilting with the cup's stripes and the saucer's
    /// checker; [`crate::losses::smoothness::depth_guide`]).
    #[serde(default)]
    pub smooth_normal: f32,
}

impl Default for Stage2Weights {
    /// SPEC 6 (supplementary) weights; SPEC 9.7 for the normal-offset weight.
    fn default() -> Self {
        Self {
            l1: 0.9,
            ssim: 0.1,
            consistency: 0.05,
            normal: 0.02,
            smooth_albedo: 0.1,
            smooth_roughness: 0.05,
            normal_offset: 0.01,
            env_tv: 0.02,
            smooth_normal: 0.0,
        }
    }
}

impl NamedWeights for Stage2Weights {
    const NAMES: &'static [&'static str] = &[
        "l1",
        "ssim",
        "consistency",
        "normal",
        "smooth_albedo",
        "smooth_roughness",
        "normal_offset",
        "env_tv",
        "smooth_normal",
    ];

    fn set(&mut self, name: &str, value: f32) -> Option<()> {
        let w = match name {
            "l1" => &mut self.l1,
            "ssim" => &mut self.ssim,
            "consistency" => &mut self.consistency,
            "normal" => &mut self.normal,
            "smooth_albedo" => &mut self.smooth_albedo,
            "smooth_roughness" => &mut self.smooth_roughness,
            "normal_offset" => &mut self.normal_offset,
            "env_tv" => &mut self.env_tv,
            "smooth_normal" => &mut self.smooth_normal,
            _ => return None,
        };
        *w = value;
        Some(())
    }
}

/// Stage-2 Adam learning rates per parameter (SPEC 6).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Stage2Rates {
    /// Learning rate of the opacity logits.
    pub opacity: f32,
    /// Learning rate of the SH coefficients.
    pub sh: f32,
    /// Learning rate of the vertex normal offsets.
    pub normal_offset: f32,
    /// Learning rate of the raw vertex albedo.
    pub albedo: f32,
    /// Learning rate of the raw vertex roughness.
    pub roughness: f32,
    /// Learning rate of the environment map parameters.
    pub env: f32,
    /// Learning rate of the indirect scale rho.
    pub rho: f32,
}

impl Default for Stage2Rates {
    fn default() -> Self {
        Self { opacity: 0.005, sh: 2.5e-4, normal_offset: 0.001, albedo: 0.01, roughness: 0.01, env: 0.025, rho: 0.01 }
    }
}

/// Everything stage 2 (SPEC 6) needs to run; saved as the run's `config.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Stage2Config {
    /// Training iterations (one view each).
    pub iterations: u64,
    /// Seed of every random choice of the run.
    pub seed: u64,
    /// Gaussian vertices per surfel (1 = constant material ablation, 2, 4, 6).
    pub vertices: usize,
    /// Micro-buffer directions per Gaussian (SPEC 4: 64 in training).
    pub directions: usize,
    /// Directions each training iteration shades per Gaussian: an interleaved subset of the
    /// `directions`, the next of the `directions / shade_directions` subsets at every iteration
    /// (`svgir_trace::Interleave`), each sample weighted by `2pi / shade_directions`. The mean
    /// of the subsets' estimates is SPEC 4's K-direction sum, so the iterations see every
    /// direction in turn. `None` (SPEC 4): all of them. Evaluation always shades all.
    #[serde(default)]
    pub shade_directions: Option<usize>,
    /// With `shade_directions`: iterations 1..=this shade the subsets, the later ones every
    /// direction (0: the subsets throughout).
    #[serde(default)]
    pub shade_directions_until: u64,
    /// Directions each training iteration estimates the shading's gradients (materials, light,
    /// rho) on per Gaussian: an interleaved subset of the `directions`, the next of the
    /// `directions / gradient_directions` subsets at every iteration, each sample weighted by
    /// `2pi / gradient_directions`, while the image is shaded as `shade_directions` says. It
    /// must divide `shade_directions`, so that each iteration's subset lies inside the one it
    /// shades. Given the image's gradient the shaded colour is linear in the per-direction terms,
    /// so the mean of the subsets' gradients is the gradient of what the iteration shades: the
    /// estimate is unbiased, and the backward costs what shading that many directions does.
    /// `None` (SPEC 4): the gradients of what the iteration shades.
    #[serde(default)]
    pub gradient_directions: Option<usize>,
    /// Height of the learned environment map in texels (width is twice this).
    pub env_height: u32,
    /// Background the renders and photos are composited over.
    pub background: BackgroundMode,
    /// Learning rates.
    pub lr: Stage2Rates,
    /// Loss weights (Eqn 15).
    pub weights: Stage2Weights,
    /// Ablation switches.
    pub visibility: bool,
    /// Add the indirect term (off: ablation).
    pub indirect: bool,
    /// Use the radiance-consistency loss (off: ablation).
    pub consistency: bool,
    /// Tracing: continuation offset after a hit, world units. SPEC 5 says 0.05; we default to
    /// [`DEFAULT_TRACE_EPS`] (see there).
    pub trace_eps: f32,
    /// `None`: unbounded (SPEC 9.5).
    pub trace_t_max: Option<f32>,
    /// Extra continuation offset in multiples of the hit surfel's size (`TraceParams::eps_scale`).
    #[serde(default)]
    pub trace_eps_scale: f32,
    /// Rays start this many of their own surfel's max scales away (`TraceParams::t_min_scale`:
    /// 3, the rim of its 3-sigma disk).
    #[serde(default = "default_trace_start_scale")]
    pub trace_start_scale: f32,
    /// Decode the traced SH radiance from sRGB to linear (`TraceParams::linear_radiance`): stage
    /// 1's SH is fitted to sRGB photos, stage 2 shades in linear light. Default on; runs from
    /// before this option read `false` and resume as they were. Measured on cup_and_ball (10k
    /// stage-1 iterations, 1500 stage-2 with `--lights 4 --env-activation exp --sun-at 400`,
    /// relighting K = 128), sRGB -> linear: rho settles at 0.58 instead of 0.34; NVS 33.59 ->
    /// 33.82 dB, albedo 22.68 -> 22.92, relighting 24.84 -> 25.01, roughness MSE 0.0352 ->
    /// 0.0309, normal MAE 4.36 -> 4.28 deg.
    #[serde(default)]
    pub trace_linear_radiance: bool,
    /// Visibility is 0 where the march's final transmittance is below this (`TraceParams::v_cut`,
    /// SPEC 5: 0.2). Surfels are semi-transparent: on the 10k-iteration stage-1 models 29-40% of
    /// the rays that hit a surface keep T >= 0.5 (`examples/microbuffer_stats`). A higher cut did
    /// not improve relighting on cup_and_ball (README).
    #[serde(default = "default_visibility_cut")]
    pub trace_visibility_cut: f32,
    /// Opacity gain of each hit in the visibility march (`TraceParams::visibility_alpha_gain`,
    /// SPEC 5: 1).
    #[serde(default = "default_visibility_alpha_gain")]
    pub trace_visibility_alpha_gain: f32,
    /// Highest SH degree of the traced radiance (`TraceParams::radiance_sh_degree`; SPEC 5:
    /// the model's own, 3). 0: each hit's mean colour, whatever the ray's direction.
    #[serde(default = "default_trace_radiance_sh_degree")]
    pub trace_radiance_sh_degree: u32,
    /// L_rc is a mean over visible Gaussians; estimate it on at most this many, drawn at random
    /// each iteration (unbiased for the mean, and it keeps the loss cheap on the CPU).
    pub consistency_samples: usize,
    /// How the learned light starts (SPEC 4: random).
    #[serde(default)]
    pub env_init: EnvInit,
    /// Brightest texels of the learned map shaded as directional lights with traced visibility
    /// (`svgir_trace::bright`; our addition for lights with a sun). 0: SPEC 4 alone.
    #[serde(default)]
    pub lights: usize,
    /// Re-select the light texels every this many iterations.
    #[serde(default = "default_lights_every")]
    pub lights_every: u64,
    /// Radiance activation of the learned map (SPEC 4: softplus).
    #[serde(default)]
    pub env_activation: EnvActivation,
    /// At this iteration (0: never), gather the learned map's brightest lobe into one texel
    /// (`svgir_trace::concentrate_lobe`), which then becomes a directional light: the K samples
    /// learn a sun only as a broad lobe, whose shadows are soft. Needs `lights > 0`.
    #[serde(default)]
    pub sun_at: u64,
    /// Angular radius of the lobe gathered at `sun_at`, degrees.
    #[serde(default = "default_sun_radius_deg")]
    pub sun_radius_deg: f32,
    /// Light warm-up: the materials (albedo, roughness, normal offsets) are held at their
    /// initial values for the first this many iterations (0: trained from the start, as SPEC 6),
    /// so that the light has to explain shading and shadows before the materials can absorb them.
    #[serde(default)]
    pub materials_from: u64,
    /// Factor on the light's learning rate once the warm-up has released the materials (1: the
    /// same rate throughout, as SPEC 6). Below 1 the light mostly keeps what it learned alone,
    /// instead of drifting with the materials along the light/albedo ambiguity.
    #[serde(default = "default_env_lr_after_warm_up")]
    pub env_lr_after_warm_up: f32,
    /// Keep the learned light grey (each texel's three parameters tied to their mean, start and
    /// gradient): during the warm-up (`materials_from`) or always. SPEC 6 lets it take any colour.
    #[serde(default)]
    pub grey_light: GreyLight,
    /// While `grey_light` holds: `None` ties the channels (grey); `Some(d)` keeps the light's
    /// colour (channel ratios under `EnvActivation::Exp`) within SH degree d and leaves each
    /// texel's brightness free (`svgir_pbr::env_colour`).
    #[serde(default)]
    pub light_colour_degree: Option<u32>,
    /// What blends the PBR image with the background in the photo loss (`crate::composite`):
    /// SPEC 3's render opacity, or the photo's alpha as the evaluation composites.
    #[serde(default)]
    pub pbr_coverage: Coverage,
    /// Shade each Gaussian on the side its camera sees, with back micro-buffers traced over the
    /// hemisphere of -n (`svgir_pbr::two_sided`; SPEC 4 shades the oriented side only).
    #[serde(default)]
    pub two_sided: bool,
    /// Training shades only the Gaussians a view blends with a total weight (`sum_p w_i`, in
    /// pixels) of at least this; the fainter ones composite their SH colour, linearised, as a
    /// stand-in without gradients to their materials (`Stage2::step`). 0: every blended
    /// Gaussian is shaded (exact). Measured on cup_and_ball's trained stage 2: 0.01 leaves out
    /// 22-30% of the shaded Gaussians, which together hold about 0.05% of the views' weight;
    /// the PBR image moves by 65-71 dB PSNR (at most 0.03 at a pixel's edge); a stage-2
    /// iteration is 12% faster; the evaluation moves by 0.02 dB or less on cup and bowl and by
    /// -0.06 dB in relighting on suzanne (two seeds). Evaluation and relighting always shade
    /// every Gaussian.
    #[serde(default)]
    pub shade_min_weight: f32,
    /// Where each training view's shaded set (and `shade_min_weight`'s test) comes from: the
    /// view's SH pass of the iteration (exact), or its previous training render, which spares
    /// the SH pass its pixels ([`ShadeSets`]).
    #[serde(default)]
    pub shade_sets: ShadeSets,
    /// How the BRDF's diffuse lobe combines with the specular one, in training, the one-bounce
    /// gather and relighting (SPEC 4: added; `layered` dims it by the specular layer's albedo,
    /// as Cycles' Principled BSDF does; `svgir_shading::layering`).
    #[serde(default)]
    pub diffuse: Diffuse,
    /// Search the sun's direction off the texel grid (`stage2::sun_search`) at `sun_at` and
    /// every `sun_search_every` iterations after it (or spaced out, `sun_search_settled_deg`),
    /// scoring candidates on this many training
    /// views (0: never). Needs `lights > 0` and `sun_at > 0`.
    #[serde(default)]
    pub sun_search_views: usize,
    /// Iterations between sun searches after the first.
    #[serde(default = "default_sun_search_every")]
    pub sun_search_every: u64,
    /// The first search (at `sun_at`) first scans a cone of this half-angle around the gathered
    /// sun, degrees (0: the compass search alone).
    #[serde(default)]
    pub sun_search_cone_deg: f32,
    /// A search that moves the sun by less than this many degrees doubles the wait before the
    /// next one; a larger move restores `sun_search_every` (0: a search every
    /// `sun_search_every` iterations). Once the sun has settled, SPEC's 20000 iterations need
    /// about 7 searches instead of 65 (each renders the search views for 21-41 candidate
    /// directions, 12-18 s on a 256 x 256 scene).
    #[serde(default)]
    pub sun_search_settled_deg: f32,
}

fn default_sun_search_every() -> u64 {
    300
}

fn default_trace_radiance_sh_degree() -> u32 {
    TraceParams::default().radiance_sh_degree
}

fn default_env_lr_after_warm_up() -> f32 {
    1.0
}

fn default_sun_radius_deg() -> f32 {
    30.0
}

/// Our default continuation offset after a hit. SPEC 5's 0.05 world units skips the other
/// overlapping surfels of the surface just hit (a surfel's 3-sigma radius is ~0.1 on our
/// synthetic scenes), so a surface takes only one surfel's alpha off the transmittance and
/// lets the rest through: visibility leaks. The traversal visits every hit once in (t, id) order
/// anyway, so no offset is needed against re-hits. Measured on cup_and_ball with ground-truth
/// materials and light (relighting K = 128): relighting 23.1 -> 25.6 dB, and the render without
/// indirect light becomes as dark as with visibility against the true mesh (GT/ours 1.14-1.20
/// against visibility traced on the true mesh, 1.16-1.20), where 0.05 left it at 0.96-0.99.
pub const DEFAULT_TRACE_EPS: f32 = 1e-4;

fn default_lights_every() -> u64 {
    100
}

fn default_visibility_alpha_gain() -> f32 {
    TraceParams::default().visibility_alpha_gain
}

fn default_visibility_cut() -> f32 {
    TraceParams::default().v_cut
}

fn default_trace_start_scale() -> f32 {
    TraceParams::default().t_min_scale
}

/// When the learned light is held grey (`Stage2Config::grey_light`).
///
/// Why: on cup_and_ball the learned map holds an orange glow round the sun and twice the true
/// sky-to-sun ratio in red, which the albedo then offsets region by region. A grey light can only
/// say where light comes from and how strong it is, and the albedo takes the colour. Measured
/// (README): grey during the warm-up only, the glow returns once the materials train (no change);
/// grey throughout helps cup (nearly grey overcast sky) and hurts bowl (blue sky, green grass).
/// `Stage2Config::light_colour_degree` keeps a smooth colour instead of none.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GreyLight {
    /// SPEC 6: coloured throughout.
    #[default]
    Off,
    /// Grey while the materials are held (`materials_from`), coloured after.
    WarmUp,
    /// Grey throughout (the evaluation's per-channel albedo scale absorbs the light's tint).
    Always,
}

impl GreyLight {
    /// Is the light grey at step `iteration` (1-based, as `Stage2::iteration` after the step's
    /// increment) when the materials train from `materials_from`?
    pub fn holds(self, iteration: u64, materials_from: u64) -> bool {
        match self {
            GreyLight::Off => false,
            GreyLight::WarmUp => iteration <= materials_from,
            GreyLight::Always => true,
        }
    }
}

/// The learned environment map's initial parameters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum EnvInit {
    /// SPEC 4: `3 U(0, 1)` per texel and channel, from the run's seed.
    #[default]
    Random,
    /// Every texel at the mean of that distribution (grey, no texel noise to wash out).
    Uniform,
}

impl Default for Stage2Config {
    fn default() -> Self {
        Self {
            iterations: 20_000,
            seed: 0,
            vertices: 4,
            directions: 64,
            shade_directions: None,
            shade_directions_until: 0,
            gradient_directions: None,
            env_height: 32,
            background: BackgroundMode::Black,
            lr: Stage2Rates::default(),
            weights: Stage2Weights::default(),
            visibility: true,
            indirect: true,
            consistency: true,
            trace_eps: DEFAULT_TRACE_EPS,
            trace_t_max: None,
            trace_eps_scale: 0.0,
            trace_start_scale: default_trace_start_scale(),
            trace_linear_radiance: true,
            trace_visibility_cut: default_visibility_cut(),
            trace_visibility_alpha_gain: default_visibility_alpha_gain(),
            trace_radiance_sh_degree: default_trace_radiance_sh_degree(),
            consistency_samples: 8192,
            env_init: EnvInit::Random,
            lights: 0,
            lights_every: default_lights_every(),
            env_activation: EnvActivation::Softplus,
            sun_at: 0,
            sun_radius_deg: default_sun_radius_deg(),
            materials_from: 0,
            env_lr_after_warm_up: 1.0,
            grey_light: GreyLight::Off,
            light_colour_degree: None,
            pbr_coverage: Coverage::Render,
            two_sided: false,
            shade_min_weight: 0.0,
            shade_sets: ShadeSets::ThisRender,
            diffuse: Diffuse::Added,
            sun_search_views: 0,
            sun_search_every: default_sun_search_every(),
            sun_search_cone_deg: 0.0,
            sun_search_settled_deg: 0.0,
        }
    }
}

impl Stage2Config {
    /// How many interleaved subsets training shades the directions in (1: all at once), or an
    /// error naming the settings when `shade_directions` does not divide `directions`.
    pub fn shade_stride(&self) -> Result<usize, String> {
        match self.shade_directions {
            None => Ok(1),
            Some(s) if s > 0 && s <= self.directions && self.directions.is_multiple_of(s) => Ok(self.directions / s),
            Some(s) => Err(format!(
                "{s} shaded directions per iteration must divide the {} micro-buffer directions",
                self.directions
            )),
        }
    }

    /// How many interleaved subsets training estimates the shading's gradients in (1: all
    /// directions), or an error naming the settings when `gradient_directions` does not divide
    /// the directions an iteration shades.
    pub fn gradient_stride(&self) -> Result<usize, String> {
        let shaded = self.shade_directions.unwrap_or(self.directions);
        match self.gradient_directions {
            None => self.shade_stride(),
            Some(g) if g > 0 && g <= shaded && shaded.is_multiple_of(g) && self.directions.is_multiple_of(g) => {
                Ok(self.directions / g)
            }
            Some(g) => Err(format!(
                "{g} directions for the shading's gradients must divide the {shaded} directions an iteration shades"
            )),
        }
    }

    /// Is a sun search due before step `iteration` + 1: at `sun_at`, then every
    /// `sun_search_every` iterations (0: only at `sun_at`)?
    pub fn sun_search_due(&self, iteration: u64) -> bool {
        self.sun_at > 0
            && (iteration == self.sun_at
                || (self.sun_search_every > 0
                    && iteration > self.sun_at
                    && (iteration - self.sun_at).is_multiple_of(self.sun_search_every)))
    }

    /// The tracer's parameters for this configuration.
    pub fn trace_params(&self) -> TraceParams {
        TraceParams {
            eps: self.trace_eps,
            eps_scale: self.trace_eps_scale,
            t_min_scale: self.trace_start_scale,
            t_max: self.trace_t_max.unwrap_or(f32::INFINITY),
            linear_radiance: self.trace_linear_radiance,
            v_cut: self.trace_visibility_cut,
            visibility_alpha_gain: self.trace_visibility_alpha_gain,
            radiance_sh_degree: self.trace_radiance_sh_degree,
            ..TraceParams::default()
        }
    }
}
