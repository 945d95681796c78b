//! `svgir inverse --run RUN`: stage 2 (materials + light) on a stage-1 run, then relighting and
//! the SPEC 8 evaluation. Writes into `RUN/stage2/`: `config.json`, `metrics.jsonl`,
//! `eval.json`, `envmap.hdr` (learned light), `point_cloud_svg.ply` (3DGS layout plus per-vertex
//! raw materials), and `test/` images (PBR, albedo, roughness, normal, each relit light, with
//! ground truth beside them).

use crate::progress;
use anyhow::{Context, Result};
use clap::Args;
use serde_json::json;
use std::path::{Path, PathBuf};
use svgir_core::{Dataset, LightInfo};
use svgir_pbr::EnvActivation;
use svgir_shading::Diffuse;
use svgir_train::driver::{self, Ended, Observer, Periods, Stage2Changes, Stage2Start};
use svgir_train::stage2::{Coverage, EnvInit, GreyLight, ShadeSets};
use svgir_train::{checkpoint, Stage2, Stage2Config, Stage2Profile};

#[derive(Args)]
pub struct InverseArgs {
    /// Stage-1 run folder (from `svgir train`).
    #[arg(long)]
    pub run: PathBuf,
    /// Dataset (default: the one recorded in RUN/config.json).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// The whole capture around the object (a stage-1 `point_cloud.ply`), kept as occluder.
    ///
    /// A stage-1 run's `point_cloud.ply`, as `svgir capture` makes in RUN/scene: the part of it
    /// near the object and outside its masks
    /// is kept as occluder and source of indirect light in every trace (the object's support
    /// shadows and lights it), while material and light are learned on the masked object.
    #[arg(long, value_name = "PLY")]
    pub surroundings: Option<PathBuf>,
    /// Stage-2 iterations (SPEC 6: 20000).
    #[arg(long, default_value_t = 20_000)]
    pub iterations: u64,
    /// Where to trace and shade: auto (a hardware GPU if any), cpu or gpu.
    ///
    /// The micro-buffers' and lights' traces and the vertex shading, training's and relighting's.
    #[arg(long, default_value_t = svgir_gpu::DeviceChoice::Auto)]
    pub device: svgir_gpu::DeviceChoice,
    /// Diagnostic: before the evaluation, replace the learned albedo and roughness by the
    /// ground truth of the training views projected onto each Gaussian (the relighting ceiling
    /// of this geometry and shading with perfect materials). Not a result: it reads ground truth.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, alias = "oracle-materials")]
    pub gt_materials: bool,
    /// With --gt-materials: passes over the training views fitting the vertex materials to
    /// the ground-truth maps through the rasteriser after the per-Gaussian projection (0: the
    /// projection alone, constant per Gaussian).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, alias = "oracle-fit-epochs", default_value_t = 6)]
    pub gt_fit_epochs: usize,
    /// Diagnostic: before the evaluation, replace the learned light by the dataset's training
    /// light (its brightest texels as directional lights when --lights > 0), so NVS measures
    /// the model under the true light. Not a result: it reads ground truth.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, alias = "oracle-light")]
    pub gt_light: bool,
    /// Diagnostic: train the materials under the dataset's true training light, held fixed
    /// (its brightest texels as directional lights when --lights > 0): how well the materials
    /// are recovered when the light is known. Not a result: it reads ground truth.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, alias = "train-true-light")]
    pub train_gt_light: bool,
    /// Seed of every random choice (recorded in the run's config.json).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Gaussian vertices per surfel: 1 (constant material), 2, 4 or 6.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 4)]
    pub vertices: usize,
    /// Micro-buffer directions per Gaussian (SPEC 4: 64 for training).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 64)]
    pub directions: usize,
    /// Directions each training iteration shades per Gaussian: an interleaved subset of the
    /// --directions, a different one at each iteration in turn, so that every direction is
    /// shaded equally often (must divide --directions; evaluation shades all). `measured`:
    /// a quarter of them (16 of 64) where that leaves at least 16, until
    /// --shade-directions-until; `spec`: all (SPEC 4). With --resume it changes the resumed
    /// run's setting. (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub shade_directions: Option<usize>,
    /// With fewer --shade-directions than --directions: only iterations 1..=N shade the
    /// subsets, the later ones every direction (0: the subsets throughout). `measured`: the
    /// first two thirds of --iterations. (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub shade_directions_until: Option<u64>,
    /// Directions each training iteration estimates the shading's gradients (materials, light)
    /// on: an interleaved subset of the --directions, a different one at each iteration in
    /// turn, inside the subset the iteration shades (must divide --shade-directions, or
    /// --directions without it). Given the image's gradient the estimate is unbiased; the image
    /// itself is shaded as --shade-directions says. `measured`: a quarter of --shade-directions
    /// (4 of 64), also after --shade-directions-until, where the image shades every direction;
    /// `spec`: every direction shaded. With --resume it changes the resumed run's setting.
    /// (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub gradient_directions: Option<usize>,
    /// Ablation: ignore visibility (V = 1).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub no_visibility: bool,
    /// Ablation: no indirect light.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub no_indirect: bool,
    /// Ablation: no radiance-consistency loss.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub no_consistency: bool,
    #[command(flatten)]
    pub lpips: super::eval::LpipsArgs,
    /// Append training statistics to OUT/metrics.jsonl every this many iterations (0: only the
    /// sun searches' rows).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 25)]
    pub log_every: u64,
    /// Continue the stage-2 run in the output folder from its checkpoint.
    ///
    /// Up to --iterations, which may extend a finished run.
    #[arg(long)]
    pub resume: bool,
    /// Write OUT/checkpoint.bin every this many iterations (0: at Ctrl-C and the end only).
    ///
    /// Atomically; Ctrl-C and the end of the run always save.
    #[arg(long, default_value_t = 500)]
    pub checkpoint_every: u64,
    /// Relit turntable frames per relighting light (0: none).
    #[arg(long, default_value_t = 24)]
    pub turntable: usize,
    /// Output folder (default RUN/stage2).
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub relight: super::spec8::EvalRelightArgs,
    /// Initial learned light: SPEC 4's per-texel random init, or a uniform grey at its mean.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum, default_value_t = EnvInitArg::Random)]
    pub env_init: EnvInitArg,
    /// Defaults of the advanced settings marked (profile) in `--help`.
    ///
    /// `measured`, the settings behind the README's table (4 lights, exp light, sun at 400, sun search on 4 views, searches spaced
    /// out once the sun settles, rho fixed, materials from 500, layered diffuse, two-sided,
    /// Gaussians blended under 0.01 pixels not shaded in training, L_rc on 2048 Gaussians, a
    /// quarter of the directions shaded per iteration for two thirds of the run); `spec`, SPEC
    /// 6's literal ones.
    #[arg(long, value_enum, default_value_t = InverseProfile::Measured)]
    pub profile: InverseProfile,
    /// (profile) Learning rate of the indirect scale rho (SPEC 6: 0.01; 0 keeps rho = 1).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub rho_lr: Option<f32>,
    /// Learning rate of the albedo (SPEC 6: 0.01).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 0.01)]
    pub albedo_lr: f32,
    /// Light warm-up: hold the materials (albedo, roughness, normal offsets) at their initial
    /// values for this many iterations, so that the light must explain shading and shadows
    /// first (0: train them from the start, as SPEC 6). (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub materials_from: Option<u64>,
    /// Factor on the light's learning rate after the warm-up (--materials-from): below 1 the
    /// light mostly keeps what it learned while the materials were held.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 1.0)]
    pub env_lr_after_warm_up: f32,
    /// Hold the learned light grey: `warm-up` while the materials are held (`--materials-from`),
    /// `always`, or `off` (SPEC 6). A grey light leaves the objects' colours to the albedo.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum, default_value_t = GreyLightArg::Off)]
    pub grey_light: GreyLightArg,
    /// With --grey-light: instead of grey, keep the light's colour within spherical harmonics of
    /// this degree (0-3) and each texel's brightness free (a blue sky over green ground, but no
    /// coloured glow round the sun).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub light_colour_degree: Option<u32>,
    /// BRDF diffuse lobe: SPEC 4 adds it to the specular one; `layered` dims it by the specular
    /// layer's albedo, as Cycles' Principled BSDF (which renders the synthetic scenes) does.
    /// (profile) With --resume it replaces the checkpoint's model (e.g. to re-evaluate).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum)]
    pub diffuse: Option<DiffuseArg>,
    /// What blends the PBR image with the background in the photo loss: SPEC 3's `render`
    /// opacity, or the `photo`'s alpha, as the evaluation composites the prediction. With the
    /// render's, a surface can look darker by being thinner over the black background, which the
    /// evaluation divides out again.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum, default_value_t = CoverageArg::Render)]
    pub pbr_coverage: CoverageArg,
    /// Shade every Gaussian on the side its camera sees (thin walls are one layer of surfels seen
    /// from both sides), tracing a second set of micro-buffers over the back hemispheres: twice
    /// the tracing time and micro-buffer memory. (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, conflicts_with = "one_sided")]
    pub two_sided: bool,
    /// SPEC 4's oriented side only (the `spec` profile's default).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub one_sided: bool,
    /// Shade this many of the learned map's brightest texels as directional lights with traced
    /// visibility and no clamp (re-selected every --lights-every iterations; relighting splits
    /// the new map by --relight-lights). For training lights with a sun; 0: SPEC 4's K samples
    /// alone. (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub lights: Option<usize>,
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 100)]
    pub lights_every: u64,
    /// Radiance of the learned map: SPEC 4's 2 softplus(x), or exp(x), which can reach a sun's
    /// radiance within a schedule (use with --lights). (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum)]
    pub env_activation: Option<EnvActivationArg>,
    /// At this iteration, gather the learned map's brightest lobe (within --sun-radius degrees)
    /// into one texel, shaded from then on as a directional light (a sun; needs --lights; use
    /// with --env-activation exp so its radiance stays trainable). 0: never. (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub sun_at: Option<u64>,
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = Stage2Config::default().sun_radius_deg)]
    pub sun_radius: f32,
    /// Search the sun's direction off the map's texel grid at --sun-at and every
    /// --sun-search-every iterations after, scoring directions on this many training views
    /// (0: never; the sun stays at its texel's centre). (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub sun_search_views: Option<usize>,
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = Stage2Config::default().sun_search_every)]
    pub sun_search_every: u64,
    /// The first sun search first scans a cone of this half-angle (degrees) around the gathered
    /// sun on rings 15 degrees apart (0: compass search alone).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 0.0)]
    pub sun_search_cone: f32,
    /// A sun search that moves the sun by less than this many degrees doubles the wait before
    /// the next; a larger move restores --sun-search-every (0: a search every
    /// --sun-search-every iterations). (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub sun_search_settled: Option<f32>,
    /// Training shades only the Gaussians a view blends with a total weight of at least this
    /// many pixels; fainter ones composite their SH colour instead, without material gradients
    /// (0: shade every blended Gaussian). Evaluation always shades all. (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub shade_min_weight: Option<f32>,
    /// Where a training view's shaded set comes from: `this-render`, the view's SH pass of the
    /// iteration (exact); `last-visit`, the view's previous training render, which spares the
    /// SH pass its pixels (a view's first render is exact). `this-render` in `spec`,
    /// `last-visit` in the measured profile. (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum)]
    pub shade_sets: Option<ShadeSetsArg>,
    /// L_rc (Eqn 14/16) is a mean over the visible Gaussians; each iteration estimates it on at
    /// most this many of them, drawn at random (unbiased): 2048 in the measured profile, 8192 in
    /// `spec`. (profile)
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long)]
    pub consistency_samples: Option<usize>,
    /// Tracing: continuation offset after a hit, world units (SPEC 5: 0.05, which lets light
    /// leak through surfaces made of overlapping surfels; see `DEFAULT_TRACE_EPS`).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = Stage2Config::default().trace_eps)]
    pub trace_eps: f32,
    /// Tracing: extra continuation offset in multiples of the hit surfel's max scale.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = Stage2Config::default().trace_eps_scale)]
    pub trace_eps_scale: f32,
    /// Tracing: rays start this many of their own surfel's max scales away (3: the rim of its
    /// 3-sigma disk, so neighbours on the same surface do not occlude it).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = Stage2Config::default().trace_start_scale)]
    pub trace_start_scale: f32,
    /// Tracing: visibility is 0 where the final transmittance is below this (SPEC 5: 0.2; higher
    /// treats partly transparent surfaces as opaque, against light leaking through them).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = Stage2Config::default().trace_visibility_cut)]
    pub visibility_cut: f32,
    /// Tracing: each hit occludes with min(0.99, gain x alpha) in the visibility march only (SPEC
    /// 5: 1; the traced radiance is unchanged). Against light leaking through surfaces.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = Stage2Config::default().trace_visibility_alpha_gain)]
    pub visibility_alpha_gain: f32,
    /// Colour space of the traced SH radiance used as indirect light (SPEC 5): stage 1 fits the
    /// SH to sRGB photos, so `linear` decodes each hit's colour before it lights linear shading;
    /// `srgb` uses it as it is, as the reference code does.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, value_enum, default_value_t = TracedRadianceArg::from_config(&Stage2Config::default()))]
    pub traced_radiance: TracedRadianceArg,
    /// Highest SH degree of the traced radiance used as indirect light (SPEC 5: 3); 0 uses each
    /// hit's mean colour, since the micro-buffer rays see surfaces from directions no camera did.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = Stage2Config::default().trace_radiance_sh_degree)]
    pub traced_sh_degree: u32,
    /// Loss weight, repeatable: l1, ssim, consistency, normal, smooth_albedo, smooth_roughness,
    /// normal_offset or env_tv (defaults: SPEC 6, Eqn 15).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long = "weight", value_name = "NAME=VALUE")]
    pub weights: Vec<String>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ShadeSetsArg {
    ThisRender,
    LastVisit,
}

impl ShadeSetsArg {
    fn model(self) -> ShadeSets {
        match self {
            ShadeSetsArg::ThisRender => ShadeSets::ThisRender,
            ShadeSetsArg::LastVisit => ShadeSets::LastVisit,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum GreyLightArg {
    Off,
    WarmUp,
    Always,
}

impl GreyLightArg {
    fn model(self) -> GreyLight {
        match self {
            GreyLightArg::Off => GreyLight::Off,
            GreyLightArg::WarmUp => GreyLight::WarmUp,
            GreyLightArg::Always => GreyLight::Always,
        }
    }
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum DiffuseArg {
    Added,
    Layered,
}

impl DiffuseArg {
    fn model(self) -> Diffuse {
        match self {
            DiffuseArg::Added => Diffuse::Added,
            DiffuseArg::Layered => Diffuse::Layered,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CoverageArg {
    Render,
    Photo,
}

impl CoverageArg {
    fn model(self) -> Coverage {
        match self {
            CoverageArg::Render => Coverage::Render,
            CoverageArg::Photo => Coverage::Photo,
        }
    }
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum EnvActivationArg {
    Softplus,
    Exp,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TracedRadianceArg {
    Srgb,
    Linear,
}

impl TracedRadianceArg {
    pub fn from_config(c: &Stage2Config) -> Self {
        if c.trace_linear_radiance {
            Self::Linear
        } else {
            Self::Srgb
        }
    }
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum EnvInitArg {
    Random,
    Uniform,
}

/// `svgir inverse --profile`: which defaults the (profile) settings take.
#[derive(Clone, Copy, Debug, clap::ValueEnum, PartialEq, serde::Serialize)]
pub enum InverseProfile {
    /// The best measured settings (the README's table).
    Measured,
    /// SPEC 6's literal settings, for reproducing the paper.
    Spec,
}

impl InverseProfile {
    pub fn model(self) -> Stage2Profile {
        match self {
            InverseProfile::Measured => Stage2Profile::Measured,
            InverseProfile::Spec => Stage2Profile::Spec,
        }
    }
}

/// The run's configuration: the profile's (`Stage2Config::for_profile`), with every option the
/// user gave applied over it.
pub fn config_of(args: &InverseArgs) -> Result<Stage2Config> {
    let profile = args.profile.model();
    let mut c = Stage2Config::for_profile(profile, args.iterations, args.directions);
    c.seed = args.seed;
    c.vertices = args.vertices;
    if let Some(s) = args.shade_directions {
        c.shade_directions = Some(s);
        c.gradient_directions = profile.gradient_directions(Some(s));
    }
    if let Some(g) = args.gradient_directions {
        c.gradient_directions = Some(g);
    }
    if let Some(u) = args.shade_directions_until {
        c.shade_directions_until = u;
    }
    c.visibility = !args.no_visibility;
    c.indirect = !args.no_indirect;
    c.consistency = !args.no_consistency;
    c.env_init = match args.env_init {
        EnvInitArg::Random => EnvInit::Random,
        EnvInitArg::Uniform => EnvInit::Uniform,
    };
    if let Some(r) = args.rho_lr {
        c.lr.rho = r;
    }
    c.lr.albedo = args.albedo_lr;
    if args.train_gt_light {
        c.lr.env = 0.0;
    }
    if let Some(n) = args.lights {
        c.lights = n;
    }
    c.lights_every = args.lights_every.max(1);
    if let Some(a) = args.env_activation {
        c.env_activation = match a {
            EnvActivationArg::Softplus => EnvActivation::Softplus,
            EnvActivationArg::Exp => EnvActivation::Exp,
        };
    }
    c.trace_eps = args.trace_eps;
    c.trace_eps_scale = args.trace_eps_scale;
    c.trace_start_scale = args.trace_start_scale;
    c.trace_visibility_cut = args.visibility_cut;
    c.trace_visibility_alpha_gain = args.visibility_alpha_gain;
    c.trace_radiance_sh_degree = args.traced_sh_degree;
    c.trace_linear_radiance = args.traced_radiance == TracedRadianceArg::Linear;
    if let Some(at) = args.sun_at {
        c.sun_at = at;
    }
    c.sun_radius_deg = args.sun_radius;
    if let Some(from) = args.materials_from {
        c.materials_from = from;
    }
    c.env_lr_after_warm_up = args.env_lr_after_warm_up;
    c.grey_light = args.grey_light.model();
    c.light_colour_degree = args.light_colour_degree;
    if let Some(d) = args.diffuse {
        c.diffuse = d.model();
    }
    c.pbr_coverage = args.pbr_coverage.model();
    if args.two_sided {
        c.two_sided = true;
    }
    if args.one_sided {
        c.two_sided = false;
    }
    if let Some(v) = args.sun_search_views {
        c.sun_search_views = v;
    }
    c.sun_search_every = args.sun_search_every;
    c.sun_search_cone_deg = args.sun_search_cone;
    if let Some(d) = args.sun_search_settled {
        c.sun_search_settled_deg = d;
    }
    if let Some(w) = args.shade_min_weight {
        c.shade_min_weight = w;
    }
    if let Some(sets) = args.shade_sets {
        c.shade_sets = sets.model();
    }
    if let Some(n) = args.consistency_samples {
        c.consistency_samples = n;
    }
    c.weights = super::loss_weights_over(c.weights.clone(), &args.weights)?;
    Ok(c)
}

/// The part of the whole-capture model `ply` that surrounds the object (`svgir_train::surroundings`),
/// its selection written to OUT/surroundings.json.
fn surroundings_of(
    ply: &Path,
    object: &svgir_core::Surfels,
    dataset: &svgir_core::Dataset,
    out: &Path,
) -> Result<svgir_core::Surfels> {
    use svgir_train::surroundings::{select, SurroundingsRule};
    let (scene, _) =
        svgir_io::ply::read_gaussians_ply(ply).with_context(|| format!("--surroundings {}", ply.display()))?;
    let rule = SurroundingsRule::default();
    let (kept, report) = select(&scene, object, &dataset.train, &rule)
        .map_err(|e| anyhow::anyhow!("--surroundings {}: {e}", ply.display()))?;
    eprintln!(
        "stage 2: surroundings from {}: {} of its {} Gaussians lie within {} object radii ({:.3}); {} inside the \
         object's masks and {} touching it are the object's; {} kept",
        ply.display(),
        report.near,
        report.scene,
        rule.radius,
        report.radius,
        report.in_hull,
        report.touching,
        report.kept
    );
    if report.in_hull == 0 {
        eprintln!(
            "warning: no Gaussian of {} lies inside the object's masks: is it a model of the same capture?",
            ply.display()
        );
    }
    let json = serde_json::json!({"ply": ply, "rule": {"radius": rule.radius, "hull_share": rule.hull_share, "margin": rule.margin}, "report": report});
    svgir_io::error::write_atomic(&out.join("surroundings.json"), serde_json::to_string_pretty(&json)?.as_bytes())?;
    Ok(kept)
}

pub fn run(args: InverseArgs) -> Result<()> {
    anyhow::ensure!(
        (0.0..=1.0).contains(&args.visibility_cut),
        "--visibility-cut {} is not a transmittance in [0, 1]",
        args.visibility_cut
    );
    anyhow::ensure!(
        args.visibility_alpha_gain.is_finite() && args.visibility_alpha_gain >= 1.0,
        "--visibility-alpha-gain {} must be at least 1",
        args.visibility_alpha_gain
    );
    anyhow::ensure!(
        args.sun_search_settled.is_none_or(|d| d.is_finite() && d >= 0.0),
        "--sun-search-settled {} is not an angle of 0 degrees or more",
        args.sun_search_settled.unwrap_or(0.0)
    );
    anyhow::ensure!(
        args.shade_min_weight.is_none_or(|w| w.is_finite() && w >= 0.0),
        "--shade-min-weight {} is not a weight of 0 or more",
        args.shade_min_weight.unwrap_or(0.0)
    );
    anyhow::ensure!(
        args.consistency_samples != Some(0),
        "--consistency-samples 0 would leave L_rc without a sample (--no-consistency turns it off)"
    );
    anyhow::ensure!(
        args.light_colour_degree.is_none() || args.grey_light != GreyLightArg::Off,
        "--light-colour-degree needs --grey-light warm-up or always (it says how the light's colour is held)"
    );
    anyhow::ensure!(
        args.light_colour_degree.is_none_or(|d| d <= 3),
        "--light-colour-degree {} is above 3",
        args.light_colour_degree.unwrap_or(0)
    );
    let (dataset, data) = svgir_eval::load_run_dataset(&args.run, args.data.as_deref())?;
    let stage1 = checkpoint::load(&args.run.join("checkpoint.bin"), &dataset)?;
    if stage1.config.profile == svgir_train::Profile::Views {
        eprintln!(
            "warning: {} was trained with --profile views (3DGS's loss alone): its surfels are not held to the \
             surface, so normals and materials will be poor; retrain with --profile object",
            args.run.display()
        );
    }
    // Checked before the micro-buffers are traced and stage 2 trains, not after.
    for (given, flag) in [(args.train_gt_light, "--train-gt-light"), (args.gt_light, "--gt-light")] {
        if given {
            true_light(&dataset, flag)?;
        }
    }
    let out = args.out.clone().unwrap_or_else(|| args.run.join("stage2"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;

    eprintln!("stage 2 profile: {:?}", args.profile);
    let config = config_of(&args)?;
    if !args.resume {
        config.shade_stride().map_err(|e| anyhow::anyhow!("--shade-directions: {e}"))?;
    }
    let start = if args.resume {
        Stage2Start::Resume(Stage2Changes {
            iterations: Some(args.iterations),
            diffuse: args.diffuse.map(DiffuseArg::model),
            shade_sets: args.shade_sets.map(ShadeSetsArg::model),
            shade_directions_until: args.shade_directions_until,
            shade_directions: args.shade_directions,
            gradient_directions: args.gradient_directions,
        })
    } else {
        let meta = json!({"stage2": config, "profile": args.profile, "data": data, "stage1_run": args.run, "command": std::env::args().collect::<Vec<_>>()});
        let surroundings = match &args.surroundings {
            Some(ply) => surroundings_of(ply, &stage1.surfels, &dataset, &out)?,
            None => svgir_core::Surfels::default(),
        };
        Stage2Start::New { config: Box::new(config), surfels: &stage1.surfels, surroundings, meta }
    };
    let (kernels, gpu) = super::engine::stage2_kernels(args.device)?;
    let mut s2 = driver::open_stage2(&out, start, &dataset, kernels, &mut |line| eprintln!("{line}"))?;
    if args.train_gt_light && !args.resume {
        set_true_light(&mut s2, &dataset, "--train-gt-light")?;
    }
    if !args.resume {
        if let Some(e) = &stage1.exposure {
            // Stage 1 learned how each photo departs from the shared radiance (`--exposure`):
            // stage 2 compares its renders with the photos through the same corrections.
            eprintln!("stage 2: applying stage 1's colour corrections of {} photos", e.params.len());
            s2.photo_corrections = e.params.clone();
        }
    }
    let pb = progress::bar(s2.config.iterations, "stage 2");
    pb.set_position(s2.iteration);
    let first_iteration = s2.iteration;
    let traced_before = s2.trace_seconds;
    // A resumed run restores the phase times of the iterations before it; the summary reports
    // this session's, as its wall time.
    let times_before = s2.times.clone();
    let start = std::time::Instant::now();
    let mut watch = Stage2Watch { pb, stop: super::train::interrupt_flag() };
    let periods = Periods { log_every: args.log_every, eval_every: 0, checkpoint_every: args.checkpoint_every };
    if let Ended::Interrupted { iteration } = driver::run(&mut s2, &dataset, &out, periods, &mut watch)? {
        watch.pb.abandon_with_message("interrupted");
        eprintln!("interrupted: checkpoint saved at iteration {iteration}; continue with --resume");
        std::process::exit(130);
    }
    let pb = watch.pb;
    pb.finish();
    {
        // The iteration's phases, and the wall time per iteration including the light updates
        // and sun searches that run between iterations.
        let t = s2.times.since(&times_before);
        let its = (s2.iteration - first_iteration).max(1) as f64;
        let ms2 = 1e3 * t.step_seconds() / its;
        let wall_ms = 1e3 * start.elapsed().as_secs_f64() / its;
        eprintln!(
            "stage 2: {ms2:.1} ms per iteration (forward {:.1}, loss {:.1}, backward {:.1}, Adam {:.1}) over this session's {} iterations; {:.1} ms of wall time per iteration, {:.1} of them the lights' visibility traces",
            1e3 * t.forward / its,
            1e3 * t.loss / its,
            1e3 * t.backward / its,
            1e3 * t.optimizer / its,
            s2.iteration - first_iteration,
            wall_ms,
            1e3 * (s2.trace_seconds - traced_before) / its,
        );
        if let Some((ms1, threads1)) = stage1_iteration_ms(&args.run) {
            eprintln!(
                "stage 2 / stage 1 per iteration: {:.1}x (stage 1: {ms1:.1} ms averaged over its run on {threads1} threads, RUN/timings.json)",
                ms2 / ms1
            );
        }
        if let Some(line) = gpu.as_ref().and_then(|g| super::engine::gpu_memory_line(g, s2.surfels.len())) {
            eprintln!("{line} after training");
        }
        if let Some(f) = stage1_final_ms(&args.run) {
            eprintln!(
                "stage 2 / stage 1 per iteration on the same Gaussians: {:.1}x (stage 1: {:.1} ms over its iterations {}-{} with the final {} Gaussians, RUN/metrics.jsonl; stage 2's wall time per iteration in this session against stage 1's, both with everything between iterations)",
                wall_ms / f.ms,
                f.ms,
                f.from,
                f.to,
                f.gaussians
            );
        }
    }
    if args.gt_materials {
        let st = svgir_train::gt_materials::apply(&mut s2, &dataset)?;
        eprintln!(
            "oracle materials: ground truth from {} training views on {} of {} Gaussians",
            st.views, st.assigned, st.total
        );
        anyhow::ensure!(st.views > 0, "--gt-materials: the training views have no albedo/roughness maps");
        if args.gt_fit_epochs > 0 {
            let loss = svgir_train::gt_materials::fit(&mut s2, &dataset, args.gt_fit_epochs)?;
            eprintln!(
                "oracle materials: fitted to the training views' maps, {} epochs, last loss {loss:.5}",
                args.gt_fit_epochs
            );
        }
    }
    if args.gt_light {
        set_true_light(&mut s2, &dataset, "--gt-light")?;
    }
    let lpips = args.lpips.load()?;
    let sampling = args.relight.sampling();
    let eval = svgir_eval::evaluate(
        &s2,
        &dataset,
        lpips.as_ref(),
        args.turntable,
        sampling,
        &args.relight.extra_lights(),
        &mut svgir_eval::EvalWriter::new(&out),
    )?;
    let its = s2.iteration.max(1) as f64;
    let t = &s2.times;
    let mut eval_out = eval;
    eval_out["ms_per_iteration"] = json!({
        "forward": 1e3 * t.forward / its, "loss": 1e3 * t.loss / its, "backward": 1e3 * t.backward / its, "optimizer": 1e3 * t.optimizer / its,
    });
    eval_out["trace_seconds"] = json!(s2.trace_seconds);
    eval_out["gaussians"] = json!(s2.surfels.len());
    std::fs::write(out.join("eval.json"), serde_json::to_string_pretty(&eval_out)?)?;
    svgir_io::write_envmap_hdr(out.join("envmap.hdr"), &s2.env.radiance())?;
    write_env_previews(&s2, &dataset, &out)?;
    let m = &s2.materials;
    let mut extras = Vec::new();
    for (name, data, ch) in
        [("albedo", &m.albedo_raw, 3), ("roughness", &m.roughness_raw, 1), ("normal_offset", &m.normal_offset, 3)]
    {
        for v in 0..m.m {
            for c in 0..ch {
                let col: Vec<f32> = (0..s2.surfels.len()).map(|i| data[(i * m.m + v) * ch + c]).collect();
                extras.push((format!("svg_{name}_raw_{v}_{c}"), col));
            }
        }
    }
    svgir_io::ply::write_gaussians_ply(out.join("point_cloud_svg.ply"), &s2.surfels, &extras)?;
    println!("stage 2: {}", serde_json::to_string(&eval_out)?);
    println!("results: {}", out.display());
    Ok(())
}

/// Stage 2's side of the run loop: the progress bar, the sun searches' messages, and Ctrl-C.
struct Stage2Watch {
    pb: indicatif::ProgressBar,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl Observer<Stage2> for Stage2Watch {
    fn stepped(&mut self, _: &Stage2, st: &svgir_train::stage2::Stage2Step) {
        self.pb.set_position(st.iteration);
        if let Some(s) = &st.sun_search {
            self.pb.suspend(|| {
                eprintln!(
                    "sun search before iteration {}: moved {:.1} deg, photo L1 {:.5} -> {:.5} ({} directions scored)",
                    st.iteration, s.moved_deg, s.loss_before, s.loss_after, s.evaluations
                )
            });
        }
        self.pb.set_message(format!("loss {:.4} PBR PSNR {:.2} dB, rho {:.3}", st.loss, st.psnr_pbr, st.rho));
    }

    fn interrupted(&self) -> bool {
        self.stop.load(std::sync::atomic::Ordering::SeqCst)
    }
}

/// Stage 1's mean time per iteration (all its phases) and thread count from `run`'s
/// `timings.json`, `None` when the file is missing or lacks them (the ratio is then not
/// printed; nothing else reads it).
fn stage1_iteration_ms(run: &Path) -> Option<(f64, u64)> {
    let text = std::fs::read_to_string(run.join("timings.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    let ms: f64 = v["ms_per_iteration"].as_object()?.values().filter_map(|x| x.as_f64()).sum();
    (ms > 0.0).then_some((ms, v["threads"].as_u64().unwrap_or(0)))
}

/// Stage 1's training time per iteration once its model had its final size (no densification or
/// pruning any more), from the last uninterrupted stretch of `run`'s `metrics.jsonl` rows with
/// the final Gaussian count.
struct Stage1Final {
    ms: f64,
    from: u64,
    to: u64,
    gaussians: u64,
}

/// [`Stage1Final`] of `run`, `None` without a log or with a stretch under 100 iterations.
fn stage1_final_ms(run: &Path) -> Option<Stage1Final> {
    let text = std::fs::read_to_string(run.join("metrics.jsonl")).ok()?;
    // Step rows only (the evaluation rows carry no Gaussian count).
    let rows: Vec<(u64, f64, u64)> = text
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| Some((v["iteration"].as_u64()?, v["train_s"].as_f64()?, v["num_gaussians"].as_u64()?)))
        .collect();
    let &(to, end_s, gaussians) = rows.last()?;
    // Back from the end while the count holds and the clock runs back (a resumed run restarts
    // `train_s`).
    let mut first = rows.len() - 1;
    while first > 0 && rows[first - 1].2 == gaussians && rows[first - 1].1 < rows[first].1 {
        first -= 1;
    }
    let (from, start_s, _) = rows[first];
    (to >= from + 100).then(|| Stage1Final { ms: 1e3 * (end_s - start_s) / (to - from) as f64, from, to, gaussians })
}

/// The dataset's training light and its map, for the diagnostic `flag` that asked for them
/// (`--gt-light` or `--train-gt-light`, named in the error).
fn true_light<'a>(dataset: &'a Dataset, flag: &str) -> Result<(&'a LightInfo, &'a Path)> {
    let root = dataset.root.display();
    let light = dataset.train_light.as_ref().with_context(|| format!("{flag}: {root} names no training light"))?;
    let path = light
        .envmap_path
        .as_deref()
        .with_context(|| format!("{flag}: {root} does not ship the map of its training light {:?}", light.name))?;
    Ok((light, path))
}

/// Replace the learned light by the dataset's training light (diagnostics; reads ground truth);
/// `flag` is the option that asked for it.
fn set_true_light(s2: &mut Stage2, dataset: &Dataset, flag: &str) -> Result<()> {
    let (light, path) = true_light(dataset, flag)?;
    let map = svgir_io::read_envmap(path, light.strength, s2.config.env_height)?;
    s2.env = svgir_pbr::EnvLight::from_radiance(&map)?.with_activation(s2.config.env_activation)?;
    s2.set_lights(&svgir_trace::brightest_texels(&map, s2.config.lights))?;
    eprintln!("true light: {} (strength {})", path.display(), light.strength);
    Ok(())
}

/// PNG previews of the learned light and, if the dataset ships it, the true training light at
/// the same resolution (sRGB of the radiance clamped to [0, 1]; the learned map is only known up
/// to the albedo-light scale ambiguity, so the two are shown, not compared numerically).
fn write_env_previews(s2: &Stage2, ds: &Dataset, out: &Path) -> Result<()> {
    let tone = |m: &svgir_core::EnvMap| m.to_image().map(|v| svgir_core::color::linear_to_srgb(v.min(1.0)));
    svgir_io::write_png(out.join("env_learned.png"), &tone(&s2.env.radiance()), 8)?;
    if let Some(LightInfo { envmap_path: Some(p), strength, .. }) = &ds.train_light {
        let truth = svgir_io::read_envmap(p, *strength, s2.config.env_height)?;
        svgir_io::write_png(out.join("env_true.png"), &tone(&truth), 8)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A period of 0 iterations is never due (it divided by zero), others on their multiples.
    /// The missing-light error names the flag that asked for the light, and the dataset.
    #[test]
    fn true_light_error_names_the_flag_given() {
        let mut ds = Dataset {
            name: "d".into(),
            root: PathBuf::from("/data/scene_x"),
            train: vec![],
            test: vec![],
            points: None,
            train_light: None,
            relight_lights: vec![],
            camera_model: String::new(),
            masks: Default::default(),
            world_rotation: glam::Mat3::IDENTITY,
        };
        for flag in ["--train-gt-light", "--gt-light"] {
            let other = if flag == "--gt-light" { "--train-gt-light" } else { "--gt-light" };
            let err = format!("{:#}", true_light(&ds, flag).unwrap_err());
            assert!(err.starts_with(flag) && !err.contains(other) && err.contains("/data/scene_x"), "{err}");
        }
        ds.train_light = Some(LightInfo { name: "noon".into(), envmap_path: None, strength: 1.0 });
        let err = format!("{:#}", true_light(&ds, "--train-gt-light").unwrap_err());
        assert!(err.starts_with("--train-gt-light") && err.contains("\"noon\""), "{err}");
        ds.train_light.as_mut().unwrap().envmap_path = Some(PathBuf::from("/data/noon.hdr"));
        let (light, path) = true_light(&ds, "--gt-light").unwrap();
        assert_eq!((light.name.as_str(), path), ("noon", Path::new("/data/noon.hdr")));
    }

    /// The ground-truth switches' old names still parse, hidden from the help.
    #[test]
    fn ground_truth_switches_keep_their_old_names() {
        let flags: Vec<String> = ["--run", "r", "--oracle-materials", "--oracle-fit-epochs", "2", "--oracle-light"]
            .iter()
            .chain(&["--train-true-light"])
            .map(|s| s.to_string())
            .collect();
        let a = super::super::args_of::<InverseArgs>("inverse", &flags).unwrap();
        assert!(a.gt_materials && a.gt_light && a.train_gt_light && a.gt_fit_epochs == 2);
    }

    /// `svgir inverse` starts from the library's profile and changes only what a flag names.
    #[test]
    fn config_is_the_profiles_with_the_flags_over_it() {
        let args = |flags: &[&str]| {
            let flags: Vec<String> = ["--run", "r"].iter().chain(flags).map(|s| s.to_string()).collect();
            config_of(&super::super::args_of::<InverseArgs>("inverse", &flags).unwrap()).unwrap()
        };
        let json = |c: &Stage2Config| serde_json::to_value(c).unwrap();
        let measured = Stage2Config::for_profile(Stage2Profile::Measured, 20_000, 64);
        assert_eq!(json(&args(&[])), json(&measured));
        let spec = Stage2Config::for_profile(Stage2Profile::Spec, 1500, 32);
        assert_eq!(json(&args(&["--profile", "spec", "--iterations", "1500", "--directions", "32"])), json(&spec));
        // The measured profile's gradient subset follows a given shaded subset; spec's does not.
        let c = args(&["--shade-directions", "32"]);
        assert_eq!((c.shade_directions, c.gradient_directions), (Some(32), Some(8)));
        let c = args(&["--profile", "spec", "--shade-directions", "32"]);
        assert_eq!((c.shade_directions, c.gradient_directions), (Some(32), None));
        let c = args(&["--one-sided", "--materials-from", "7", "--rho-lr", "0.5", "--weight", "env_tv=0"]);
        assert_eq!((c.two_sided, c.materials_from, c.lr.rho, c.weights.env_tv), (false, 7, 0.5, 0.0));
        assert_eq!((c.sun_at, c.lights), (measured.sun_at, measured.lights));
    }

    /// The stretch is the last one with the final count and a running clock: rows before a
    /// change of count or before a resume (the clock restarts) are left out.
    #[test]
    fn stage1_final_stretch_skips_growth_and_resumes() {
        let dir = std::env::temp_dir().join(format!("svgir_final_ms_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let row = |it: u64, s: f64, n: u64| format!("{{\"iteration\":{it},\"train_s\":{s},\"num_gaussians\":{n}}}\n");
        let eval = "{\"iteration\":300,\"train_s\":2.0,\"test\":{\"psnr\":30.0}}\n";
        // Growth to 900 at iteration 200, a resume at 400 (clock back to 0), then 400-1000.
        let log = [row(100, 1.0, 500), row(200, 2.0, 900), eval.to_string(), row(300, 3.0, 900), row(400, 4.0, 900)]
            .concat()
            + &row(500, 0.5, 900)
            + &row(1000, 3.0, 900);
        std::fs::write(dir.join("metrics.jsonl"), log).unwrap();
        let f = stage1_final_ms(&dir).unwrap();
        assert_eq!((f.from, f.to, f.gaussians), (500, 1000, 900));
        assert!((f.ms - 5.0).abs() < 1e-9, "{}", f.ms);
        // Too short a stretch gives no figure.
        std::fs::write(dir.join("metrics.jsonl"), row(100, 1.0, 500) + &row(150, 2.0, 900)).unwrap();
        assert!(stage1_final_ms(&dir).is_none());
        std::fs::remove_dir_all(&dir).ok();
    }
}
