//! Stage 2 (SPEC 6): spatially-varying materials and environment light on frozen stage-1
//! geometry.
//!
//! Set-up: orient every surfel's normal towards the training cameras that see it (the hemisphere
//! of its micro-buffer must be the visible side; [`crate::orient`]), build the BVH, trace the
//! K-direction micro-buffers once, attach M Gaussian vertices of raw materials (SPEC 3) and
//! create the learnable env map. With `config.two_sided` it also traces every Gaussian's back
//! hemisphere ([`BackSide`]), and each view shades a Gaussian on the side its camera sees
//! (`svgir_pbr::two_sided`).
//! One iteration on a random view (`step`):
//! 1. SH pass: rasterise the SH colours, which finds the Gaussians the view blends.
//! 2. PBR pass: shade the vertices (SPEC 4) of every Gaussian the SH pass blended into some
//!    pixel (`weighted`: the others' colours are never read), rasterise the vertex colours
//!    plus albedo, roughness, shading normal and the SH colour as extra channels (the SH image
//!    keeps training, SPEC 6 Eqn 15; `sh_channels`), divide by opacity, linear -> sRGB,
//!    composite over the background.
//! 3. Losses of Eqn 15 on both images plus L_rc, L_n, smoothness, |dN|^2 and env TV; backward
//!    through the PBR pass (for both images), the shading (over `config.gradient_directions`,
//!    an unbiased estimate of the shaded directions' gradients) and the activations; one Adam
//!    step per group.

mod config;
pub mod objective;
mod profile;
mod render;
mod sh_channels;
mod shaded_set;
mod step;
mod sun_search;

pub use crate::composite::Coverage;
pub use config::{EnvInit, GreyLight, Stage2Config, Stage2Rates, Stage2Weights, DEFAULT_TRACE_EPS};
pub use objective::EXTRA_CHANNELS;
pub use profile::{Stage2Profile, MEASURED_CONSISTENCY_SAMPLES, MEASURED_MIN_SHADE_DIRECTIONS};
pub use render::{BackShading, PbrRender, Shading};
pub use sun_search::{SunSchedule, SunSearch};

use crate::adam::AdamGroup;
use crate::orient::orient_normals;
use crate::stage1::{alpha_of, psnr_of_mse, target_rgb, PhaseTimes};
use glam::Vec3;
use objective::{extra_features_backward, stage2_objective, Stage2Outputs, Stage2Target};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sh_channels::{join_pass_grads, pass_features, sh_colour_grads, split_pass, PASS_CHANNELS, SH_CHANNELS};
pub use shaded_set::ShadeSets;
pub(crate) use shaded_set::ViewSets;
use shaded_set::{faint, in_set_of, outside_set, stand_in_colours, visible_of, weighted};
use std::sync::Arc;
use std::time::Instant;
use svgir_core::{Camera, Dataset, Image, Rng, Surfels};
use svgir_pbr::{
    negated, split_by_side, ColourProjector, ConsistencyInputs, CpuShader, DirectionCache, EnvLight, Indirect,
    PbrError, PbrGrads, ShadeInputs, ShadeOutput, ShadeParams, Side, SvgMaterials, VertexShader,
};
use svgir_raster::{
    render, Background, ColorSource, CpuFeatureRaster, FeatureRaster, Features, OutputGrads, RasterConfig, RenderInput,
};
use svgir_trace::{
    brightest_texels, concentrate_lobe, BrightLights, Bvh, CpuTracer, GatherParams, MicroBuffer, MicroTracer,
    TraceRequest, Via,
};

/// What one stage-2 iteration reports (a line of `metrics.jsonl`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Stage2Step {
    /// Iteration number.
    pub iteration: u64,
    /// The per-pixel part of Eqn 15.
    pub loss: f32,
    /// PSNR in dB of the PBR image against the photo.
    pub psnr_pbr: f32,
    /// PSNR in dB of the SH (stage-1 radiance) image against the photo.
    pub psnr_sh: f32,
    /// Radiance-consistency loss L_rc.
    pub consistency: f32,
    /// Current indirect scale rho.
    pub rho: f32,
    /// The sun direction search run before this step, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sun_search: Option<SunSearch>,
}

/// The stage-2 trainer (SPEC 6): frozen geometry, materials, light, micro-buffers and Adam state.
pub struct Stage2 {
    /// The run's configuration.
    pub config: Stage2Config,
    /// Frozen geometry; opacity and SH keep training.
    pub surfels: Surfels,
    /// Geometric normal per Gaussian, oriented towards the training cameras.
    pub normals: Vec<Vec3>,
    /// Raw spatially-varying materials (SPEC 3).
    pub materials: SvgMaterials,
    /// The learned environment light (SPEC 4).
    pub env: EnvLight,
    /// Indirect scale rho (SPEC 6).
    pub rho: f32,
    /// Front-side micro-buffers, traced once (SPEC 5).
    pub mb: MicroBuffer,
    /// Env-map lookup coordinates of every micro-buffer direction (fixed in stage 2).
    pub dir_cache: DirectionCache,
    /// The interleaved direction subsets training shades in turn (`config.shade_directions`;
    /// empty: all directions at every iteration).
    pub subsets: Vec<DirectionSubset>,
    /// The interleaved subsets training estimates the shading's gradients on in turn
    /// (`config.gradient_directions`; empty: `subsets` serve, or the directions shaded).
    pub grad_subsets: Vec<DirectionSubset>,
    /// Adam groups: opacity, sh, albedo, roughness, normal offset, env, rho.
    pub groups: [AdamGroup; 7],
    /// Iterations done.
    pub iteration: u64,
    /// Source of every random choice (view order, backgrounds).
    pub rng: Rng,
    /// Rasteriser settings.
    pub raster: RasterConfig,
    /// Wall time per phase so far.
    pub times: PhaseTimes,
    /// Seconds spent building the BVH and tracing.
    pub trace_seconds: f64,
    /// Directional lights of the learned map (empty unless `config.lights > 0`).
    pub lights: BrightLights,
    /// BVH for tracing light visibility, built on first use.
    bvh: Option<Bvh>,
    /// Opacity logits at the start of stage 2, when the micro-buffers were traced: light
    /// visibility is traced against the same frozen occluders (and so is reproducible on resume).
    pub trace_opacity: Vec<f32>,
    /// Holds the light grey or its colour smooth while `config.grey_light` holds.
    colour: ColourProjector,
    /// Every Gaussian's back side, with `config.two_sided` ([`Stage2::trace_back_side`]).
    pub back: Option<BackSide>,
    /// When the next sun search is due.
    pub sun_schedule: SunSchedule,
    /// Per training view, the Gaussians its last render blended (`config.shade_sets`).
    pub(crate) view_sets: ViewSets,
    /// Per training photo, stage 1's colour correction (`exposure`, a 3x3 matrix then the
    /// offset), applied unchanged to both images before the loss; empty for none.
    pub photo_corrections: Vec<[f32; crate::exposure::PARAMS]>,
    /// The rest of a captured scene around the object (`crate::surroundings`): frozen
    /// Gaussians traced after the object's as occluders and sources of traced radiance,
    /// never rendered, shaded or trained; empty for the object alone.
    pub surroundings: Surfels,
    /// Where micro-buffers are traced (the back sides, relighting's) and the renders' vertices
    /// shaded: the CPU unless the front end chose a device. Not saved: a run resumes on
    /// whichever device the front end opens.
    pub kernels: Kernels,
}

/// Where stage 2's device kernels run: the micro-buffer tracer, the vertex shader (training's
/// shading forward and backward, and every render: evaluation, relighting) and the feature
/// raster (the PBR pass, forward and backward, and every render's). The CPU's by default; the
/// front end swaps in a device's (svgir-gpu), so this crate never depends on a GPU crate.
#[derive(Clone)]
pub struct Kernels {
    /// Traces micro-buffers (SPEC 5).
    pub tracer: Arc<dyn MicroTracer>,
    /// Shades the vertices (SPEC 4).
    pub shader: Arc<dyn VertexShader>,
    /// Composites the shaded colours and the material channels (SPEC 6's PBR pass).
    pub raster: Arc<dyn FeatureRaster>,
}

impl Kernels {
    /// The CPU kernels.
    pub fn cpu() -> Self {
        Self { tracer: Arc::new(CpuTracer), shader: Arc::new(CpuShader), raster: Arc::new(CpuFeatureRaster) }
    }

    /// What runs them, for logs: "cpu", or the adapter.
    pub fn name(&self) -> String {
        self.tracer.name()
    }
}

impl Default for Kernels {
    fn default() -> Self {
        Self::cpu()
    }
}

impl std::fmt::Debug for Kernels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (t, s, r) = (self.tracer.name(), self.shader.name(), self.raster.name());
        write!(f, "Kernels(tracer {t}, shader {s}, raster {r})")
    }
}

/// The back side of every Gaussian for two-sided shading (`svgir_pbr::two_sided`): traced once,
/// against the same frozen occluders as the front, and saved with the checkpoint like the front.
pub struct BackSide {
    /// Micro-buffers over the hemisphere of `-n`, with the front's K and azimuths.
    pub mb: MicroBuffer,
    /// Env-map lookup coordinates of every back micro-buffer direction.
    pub dir_cache: DirectionCache,
    /// The back side's interleaved direction subsets, as the front's.
    pub subsets: Vec<DirectionSubset>,
    /// The back side's gradient subsets, as the front's.
    pub grad_subsets: Vec<DirectionSubset>,
    /// The directional lights' visibility from the back side (same texels and directions).
    pub lights: BrightLights,
}

/// One interleaved subset of a side's micro-buffer directions with its direction cache
/// (`Stage2Config::shade_directions`): copies of the full buffer's samples, derived at set-up
/// and not saved with the checkpoint.
pub struct DirectionSubset {
    /// The subset's samples (`MicroBuffer::interleaved`).
    pub mb: MicroBuffer,
    /// Their env-map lookup coordinates.
    pub dir_cache: DirectionCache,
}

/// What iteration `iteration` shades a side with: its direction subsets in turn up to
/// `config.shade_directions_until` (0: throughout), else all directions (`mb`, `cache`).
fn shading_set<'a>(
    config: &Stage2Config,
    iteration: u64,
    mb: &'a MicroBuffer,
    cache: &'a DirectionCache,
    subsets: &'a [DirectionSubset],
) -> (&'a MicroBuffer, &'a DirectionCache) {
    let until = config.shade_directions_until;
    let subset = in_turn(subsets, iteration).filter(|_| until == 0 || iteration <= until);
    subset.map_or((mb, cache), |s| (&s.mb, &s.dir_cache))
}

/// The subset of `family` whose turn iteration `iteration` is (none for an empty family).
fn in_turn(family: &[DirectionSubset], iteration: u64) -> Option<&DirectionSubset> {
    family.get((iteration % family.len().max(1) as u64) as usize)
}

/// What iteration `iteration` estimates a side's shading gradients with: its shading set, or,
/// with `config.gradient_directions`, the gradient subsets in turn (the shading subsets when the
/// two strides agree, else `grad_subsets`).
fn gradient_set<'a>(
    config: &Stage2Config,
    iteration: u64,
    mb: &'a MicroBuffer,
    cache: &'a DirectionCache,
    subsets: &'a [DirectionSubset],
    grad_subsets: &'a [DirectionSubset],
) -> (&'a MicroBuffer, &'a DirectionCache) {
    if config.gradient_directions.is_none() {
        return shading_set(config, iteration, mb, cache, subsets);
    }
    let family = if grad_subsets.is_empty() { subsets } else { grad_subsets };
    in_turn(family, iteration).map_or((mb, cache), |s| (&s.mb, &s.dir_cache))
}

/// The `config.shade_stride()` subsets of `mb`'s directions, none when that is 1.
fn direction_subsets(
    config: &Stage2Config,
    mb: &MicroBuffer,
    cache: &DirectionCache,
) -> Result<Vec<DirectionSubset>, PbrError> {
    let stride = config.shade_stride().map_err(PbrError::InvalidParameter)?;
    interleaved_subsets(stride, mb, cache)
}

/// The `config.gradient_stride()` subsets of `mb`'s directions, none when that is 1 or equals
/// the shading stride (the shading subsets serve).
fn gradient_subsets(
    config: &Stage2Config,
    mb: &MicroBuffer,
    cache: &DirectionCache,
) -> Result<Vec<DirectionSubset>, PbrError> {
    let stride = config.gradient_stride().map_err(PbrError::InvalidParameter)?;
    if stride == config.shade_stride().map_err(PbrError::InvalidParameter)? {
        return Ok(Vec::new());
    }
    interleaved_subsets(stride, mb, cache)
}

/// The `stride` interleaved subsets of `mb`'s directions with their caches, none when that is 1.
fn interleaved_subsets(
    stride: usize,
    mb: &MicroBuffer,
    cache: &DirectionCache,
) -> Result<Vec<DirectionSubset>, PbrError> {
    if stride == 1 {
        return Ok(Vec::new());
    }
    (0..stride)
        .map(|phase| {
            let sub = mb.interleaved(stride, phase)?;
            let dir_cache = cache.interleaved(&sub)?;
            Ok(DirectionSubset { mb: sub, dir_cache })
        })
        .collect()
}

/// Stage 2's rasteriser settings: no distortion output (no loss uses it), and no gradients for
/// the frozen positions, rotations and scales (SPEC 6).
/// `own` with `surroundings` after it: the rays leave `own`'s Gaussians only, and hits past
/// them are the surroundings' (`svgir_trace::SURROUNDINGS_HIT`).
fn with_surroundings(mut own: Surfels, surroundings: &Surfels) -> Surfels {
    own.extend_from(surroundings);
    own
}

fn raster_config() -> RasterConfig {
    RasterConfig { distortion: false, geometry_grads: false, ..RasterConfig::default() }
}

/// The per-pixel coverage `mode` blends the PBR image by for a view whose photo is `image`: its
/// alpha under [`Coverage::Photo`] (none for a photo without alpha), else `None` (the render's
/// opacity; `crate::composite`).
fn photo_coverage(mode: Coverage, image: &Image) -> Option<Vec<f32>> {
    (mode == Coverage::Photo && image.channels == 4).then(|| alpha_of(image))
}

/// A feature raster's refusal as stage 2's error.
fn raster_error(e: svgir_raster::RasterError) -> PbrError {
    PbrError::InvalidParameter(format!("the PBR pass: {e}"))
}

impl Stage2 {
    /// Set up stage 2 on stage 1's `surfels`: put them in Morton order, orient normals, trace the
    /// micro-buffers, initialise materials and light.
    pub fn new(config: Stage2Config, surfels: Surfels, dataset: &Dataset) -> Result<Self, PbrError> {
        Self::new_on(config, surfels, dataset, Kernels::cpu())
    }

    /// [`Stage2::new`] with the micro-buffers traced by `kernels` (kept as the run's kernels).
    pub fn new_on(
        config: Stage2Config,
        surfels: Surfels,
        dataset: &Dataset,
        kernels: Kernels,
    ) -> Result<Self, PbrError> {
        Self::new_around(config, surfels, Surfels::default(), dataset, kernels)
    }

    /// [`Stage2::new_on`] with `surroundings` ([`Stage2::surroundings`]) kept as occluders and
    /// sources of traced radiance in every trace.
    pub fn new_around(
        config: Stage2Config,
        mut surfels: Surfels,
        surroundings: Surfels,
        dataset: &Dataset,
        kernels: Kernels,
    ) -> Result<Self, PbrError> {
        // The geometry is frozen from here on: put the Gaussians in Morton order of their
        // centres once, so that the ones a view sees lie in runs of every per-Gaussian array.
        surfels.sort_morton();
        let cams: Vec<Camera> = dataset.train.iter().map(|v| v.camera).collect();
        orient_normals(&mut surfels, &cams, &raster_config());
        let t0 = Instant::now();
        let occluders = with_surroundings(surfels.clone(), &surroundings);
        let bvh = Bvh::build(&occluders);
        let axes = (0..surfels.len()).map(|j| surfels.normal(j)).collect();
        let p = config.trace_params();
        let req = TraceRequest { axes, k: config.directions, seed: config.seed, params: &p, radiance: true };
        let mb = kernels.tracer.trace(&bvh, &occluders, req)?;
        let trace_seconds = t0.elapsed().as_secs_f64();
        let mut s2 = Self::from_parts(config, surfels, mb, trace_seconds)?;
        s2.surroundings = surroundings;
        s2.bvh = Some(bvh);
        s2.kernels = kernels;
        s2.trace_back_side()?;
        Ok(s2)
    }

    /// Trace the back sides' micro-buffers and light visibility if `config.two_sided` asks for
    /// them and they are missing (a new or a restored run; call after `trace_opacity` is set).
    pub fn trace_back_side(&mut self) -> Result<(), PbrError> {
        if !self.config.two_sided || self.back.is_some() {
            return Ok(());
        }
        let t0 = Instant::now();
        let occluders = self.occluders();
        let bvh = self.bvh.get_or_insert_with(|| Bvh::build(&occluders));
        let axes = self.mb.normals.iter().map(|n| -*n).collect();
        let p = self.config.trace_params();
        let req = TraceRequest { axes, k: self.mb.k, seed: self.config.seed, params: &p, radiance: true };
        let mb = self.kernels.tracer.trace(bvh, &occluders, req)?;
        self.attach_back_side(mb, &occluders)?;
        self.trace_seconds += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// Make `mb` (e.g. restored from a checkpoint) the back sides' micro-buffers, with their
    /// direction cache and the current lights' visibility from the back.
    pub fn set_back_side(&mut self, mb: MicroBuffer) -> Result<(), PbrError> {
        let occluders = self.occluders();
        self.attach_back_side(mb, &occluders)
    }

    /// [`Stage2::set_back_side`] with the occluders (`self.occluders()`) already at hand.
    fn attach_back_side(&mut self, mb: MicroBuffer, occluders: &Surfels) -> Result<(), PbrError> {
        if (mb.len(), mb.k) != (self.mb.len(), self.mb.k) {
            return Err(PbrError::SizeMismatch {
                what: "back micro-buffer",
                got: mb.len() * mb.k,
                want: self.mb.len() * self.mb.k,
            });
        }
        let bvh = self.bvh.get_or_insert_with(|| Bvh::build(occluders));
        let dir_cache = DirectionCache::new(&mb, &self.env.radiance())?;
        let subsets = direction_subsets(&self.config, &mb, &dir_cache)?;
        let grad_subsets = gradient_subsets(&self.config, &mb, &dir_cache)?;
        let via = Via(self.kernels.tracer.as_ref(), bvh);
        let lights = self.lights.for_normals(&via, occluders, &mb.normals, &self.config.trace_params(), None)?;
        self.back = Some(BackSide { mb, dir_cache, subsets, grad_subsets, lights });
        Ok(())
    }

    /// Shade `shade_directions` of the directions per iteration and estimate the shading's
    /// gradients on `gradient_directions` from now on (`Stage2Config::shade_directions`,
    /// `Stage2Config::gradient_directions`), deriving both sides' subsets again.
    pub fn set_directions(
        &mut self,
        shade_directions: Option<usize>,
        gradient_directions: Option<usize>,
    ) -> Result<(), PbrError> {
        let config = Stage2Config { shade_directions, gradient_directions, ..self.config.clone() };
        let derive = |mb: &MicroBuffer, cache: &DirectionCache| -> Result<_, PbrError> {
            Ok((direction_subsets(&config, mb, cache)?, gradient_subsets(&config, mb, cache)?))
        };
        let front = derive(&self.mb, &self.dir_cache)?;
        let back = self.back.as_ref().map(|b| derive(&b.mb, &b.dir_cache)).transpose()?;
        (self.subsets, self.grad_subsets) = front;
        if let (Some(b), Some(s)) = (&mut self.back, back) {
            (b.subsets, b.grad_subsets) = s;
        }
        self.config = config;
        Ok(())
    }

    /// The back sides' light visibility, `None` without lights or back sides.
    pub fn active_back_lights(&self) -> Option<&BrightLights> {
        self.back.as_ref().map(|b| &b.lights).filter(|l| !l.is_empty())
    }

    /// `(front, back)`: the Gaussians of `visible` that `camera` sees on their oriented side and
    /// from behind (`svgir_pbr::split_by_side`); one-sided, all of them on the front.
    fn sides(&self, camera: &Camera, visible: &[bool], two_sided: bool) -> (Vec<bool>, Vec<bool>) {
        if two_sided {
            split_by_side(&self.normals, &self.surfels.positions, camera.center(), visible)
        } else {
            (visible.to_vec(), vec![false; visible.len()])
        }
    }

    /// A fresh stage-2 state around oriented surfels and their traced micro-buffers.
    pub fn from_parts(
        config: Stage2Config,
        surfels: Surfels,
        mb: MicroBuffer,
        trace_seconds: f64,
    ) -> Result<Self, PbrError> {
        let n = surfels.len();
        let normals: Vec<Vec3> = (0..n).map(|i| surfels.normal(i)).collect();
        let m = config.vertices;
        let materials = SvgMaterials::new(n, m)?;
        let env = match config.env_init {
            EnvInit::Random => EnvLight::new(config.env_height, Rng::new(config.seed).fork(2).next_u64())?,
            EnvInit::Uniform => EnvLight::uniform(config.env_height)?,
        }
        .with_activation(config.env_activation)?;
        let lights = BrightLights::empty(env.width, env.height);
        let colour = ColourProjector::new(env.width, env.height, config.light_colour_degree)?;
        let surfels_opacity = surfels.opacity_logits.clone();
        let dir_cache = DirectionCache::new(&mb, &env.radiance())?;
        let subsets = direction_subsets(&config, &mb, &dir_cache)?;
        let grad_subsets = gradient_subsets(&config, &mb, &dir_cache)?;
        let lr = &config.lr;
        let groups = [
            AdamGroup::new("opacity", lr.opacity, 1, n),
            AdamGroup::new("sh", lr.sh, 48, n),
            AdamGroup::new("albedo", lr.albedo, 3 * m, n),
            AdamGroup::new("roughness", lr.roughness, m, n),
            AdamGroup::new("normal_offset", lr.normal_offset, 3 * m, n),
            AdamGroup::new("env", lr.env, 3, env.texels()),
            AdamGroup::new("rho", lr.rho, 1, 1),
        ];
        let rng = Rng::new(config.seed).fork(3);
        Ok(Self {
            config,
            surfels,
            normals,
            materials,
            env,
            rho: 1.0,
            mb,
            dir_cache,
            subsets,
            grad_subsets,
            groups,
            iteration: 0,
            rng,
            // Stage 2 has no distortion term (Eqn 15).
            raster: raster_config(),
            times: PhaseTimes::default(),
            trace_seconds,
            lights,
            bvh: None,
            trace_opacity: surfels_opacity,
            colour,
            back: None,
            sun_schedule: SunSchedule::default(),
            view_sets: ViewSets::default(),
            photo_corrections: Vec::new(),
            surroundings: Surfels::default(),
            kernels: Kernels::cpu(),
        })
    }

    /// Make the texels `texels` of the learned map the directional lights, tracing visibility
    /// for the ones not already traced.
    pub fn set_lights(&mut self, texels: &[u32]) -> Result<(), PbrError> {
        if texels == self.lights.texels.as_slice() {
            return Ok(());
        }
        let t0 = Instant::now();
        let occluders = self.occluders();
        let tracer = self.kernels.tracer.clone();
        let bvh = &Via(tracer.as_ref(), self.bvh.get_or_insert_with(|| Bvh::build(&occluders)));
        let geom = svgir_core::EnvMap::constant(self.env.width, self.env.height, [0.0; 3]);
        let p = self.config.trace_params();
        self.lights = BrightLights::trace(bvh, &occluders, &self.mb.normals, &geom, texels, &p, Some(&self.lights))?;
        if let Some(back) = &mut self.back {
            back.lights = self.lights.for_normals(bvh, &occluders, &back.mb.normals, &p, Some(&back.lights))?;
        }
        self.trace_seconds += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// The surfels as the tracer sees them (opacity frozen at stage 2's start), then the
    /// surroundings.
    fn occluders(&self) -> Surfels {
        let own = Surfels { opacity_logits: self.trace_opacity.clone(), ..self.surfels.clone() };
        with_surroundings(own, &self.surroundings)
    }

    /// The surfels as they are now, then the surroundings: what relighting traces through.
    pub fn relight_occluders(&self) -> Surfels {
        with_surroundings(self.surfels.clone(), &self.surroundings)
    }

    /// Gather the learned map's brightest lobe into its peak texel and make that texel a light
    /// (see `Stage2Config::sun_at`). The map's Adam moments restart: they belong to the old map.
    pub fn concentrate_sun(&mut self) -> Result<(), PbrError> {
        let (map, peak) = concentrate_lobe(&self.env.radiance(), self.config.sun_radius_deg.to_radians());
        self.env = EnvLight::from_radiance(&map)?.with_activation(self.config.env_activation)?;
        let env_group = &mut self.groups[5];
        (0..env_group.rows()).for_each(|r| env_group.reset_row(r));
        let mut texels = brightest_texels(&map, self.config.lights);
        if !texels.contains(&peak) {
            texels.insert(0, peak);
            texels.truncate(self.config.lights.max(1));
        }
        self.set_lights(&texels)
    }

    /// The lights to shade with, `None` when there are none.
    pub fn active_lights(&self) -> Option<&BrightLights> {
        (!self.lights.is_empty()).then_some(&self.lights)
    }

    /// True once `config.iterations` iterations have run.
    pub fn is_done(&self) -> bool {
        self.iteration >= self.config.iterations
    }

    fn indirect(&self) -> Indirect<'_, f32> {
        if self.config.indirect {
            Indirect::Traced { rho: self.rho }
        } else {
            Indirect::Off
        }
    }

    fn shade_params(&self) -> ShadeParams {
        ShadeParams { visibility: self.config.visibility, diffuse: self.config.diffuse, ..ShadeParams::default() }
    }

    /// +1 or -1 per Gaussian: whether its oriented normal faces `camera` ([`objective::facing`]).
    fn facing(&self, camera: &Camera) -> Vec<f32> {
        objective::facing(&self.normals, &self.surfels.positions, camera.center())
    }

    /// The Gaussians training view `view`'s last render blended with at least
    /// `config.shade_min_weight` (bit g for Gaussian g), with `ShadeSets::LastVisit` once the
    /// view was rendered; else None.
    pub fn view_set(&self, view: usize) -> Option<&[u64]> {
        self.view_sets.get(view)
    }
}
