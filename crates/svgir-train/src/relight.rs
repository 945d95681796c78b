//! Relighting (SPEC 7): shade a trained stage-2 model under a new environment map.
//!
//! A [`Relighter`] traces its own micro-buffers with the evaluation's K (SPEC 7: 384; the
//! training buffers have 64, too few for a map with a sun or bright lamps), then per light
//! gathers the one-bounce indirect L1b under that map (Eqn 13, rho = 1), optionally adds further
//! diffuse bounces ([`svgir_trace::add_bounces`]), and renders with it.
//!
//! A given map is used as is: its radiance is not clamped at SPEC 4's 64, which bounds the
//! *learned* map during training. A measured HDR sun reaches thousands (the noon_grass map of
//! the synthetic scenes: 2815 in a 32x64 texel, more than half of the map's power), and
//! clamping it removes most of the light (the `gt_shading` diagnostic shows a 2-4x darker
//! shading under the training light).
//!
//! The new map's brightest texels become directional lights with traced visibility, in the
//! direct term and in the one-bounce gather ([`svgir_trace::BrightLights`]); the rest of the map
//! stays in the K-sample estimate. The count is a setting of the relighting, not of the model:
//! the lights only split the same integral into an exact part and a sampled part. A studio map
//! with three soft boxes holds 90% of its power in 16 of its 2048 texels, which K = 384 samples
//! hit only a few times each; [`RELIGHT_LIGHTS`] of them are traced exactly. (Measured on
//! cup_and_ball the gain is small: 4 -> 64 lights, relighting +0.07 dB; README.)
//!
//! A model trained with surroundings (`Stage2::surroundings`, the rest of a capture) is traced
//! through them: they shadow the object, and the rays that end on them bring their captured
//! colour scaled by the new map's irradiance over the learned light's
//! (`svgir_trace::surroundings_light`), the light a table or wall throws back onto the object.

use crate::stage2::{BackShading, PbrRender, Shading, Stage2};
use svgir_core::{Camera, EnvMap};
use svgir_pbr::{DirectionCache, Indirect, PbrError, ShadeParams};
use svgir_trace::{
    add_surroundings_light, brightest_texels, BrightLights, Bvh, GatherParams, HitSide, LearnedIrradiance, MicroBuffer,
    SurroundingsGain, TraceRequest, VertexMaterials, Via,
};

/// SPEC 7: directions per Gaussian at relighting evaluation.
pub const RELIGHT_DIRECTIONS: usize = 384;

/// Default number of directional lights when relighting (our addition, see the module note).
pub const RELIGHT_LIGHTS: usize = 32;

/// Default number of diffuse bounces added to Eqn 13's one-bounce light when relighting (our
/// addition, [`svgir_trace::add_bounces`]; 0 is SPEC 7).
pub const RELIGHT_BOUNCES: usize = 0;

/// How the light integral is estimated when relighting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RelightSampling {
    /// Fibonacci directions per Gaussian (SPEC 7: 384).
    pub directions: usize,
    /// Brightest texels of each new map shaded as directional lights (0: SPEC 4's K samples
    /// alone, as the reference does).
    pub lights: usize,
    /// Diffuse bounces added to the one-bounce indirect light (0: SPEC 7's Eqn 13 alone).
    pub bounces: usize,
}

/// Micro-buffers for relighting a stage-2 model.
pub struct Relighter {
    /// Front-side micro-buffers for relighting: V, I and U. Traced here (K other than
    /// training's), they hold no traced radiance (L = 0, `MicroBuffer::trace_occlusion_about`):
    /// relighting's indirect light is the one-bounce gather under the new map (SPEC 7).
    pub mb: MicroBuffer,
    cache: DirectionCache,
    /// The back sides' micro-buffers and cache, for a model trained two-sided.
    back: Option<(MicroBuffer, DirectionCache)>,
    /// For tracing K directions and the directional lights; built only when one is needed.
    bvh: Option<Bvh>,
    /// Directional lights per new map.
    lights: usize,
    /// Extra diffuse bounces of indirect light.
    bounces: usize,
    /// The learned light's irradiance of the surroundings (`Stage2::surroundings`), whose
    /// captured colour the rays ending on them bring, relit (`svgir_trace::surroundings_light`).
    surroundings: Option<LearnedIrradiance>,
    /// Seconds spent building the BVH and tracing.
    pub trace_seconds: f64,
}

/// One light prepared for rendering: the map and its one-bounce indirect per (Gaussian, direction)
/// (`None` for a model trained without indirect light).
pub struct PreparedLight {
    /// The new environment map (linear radiance).
    pub env: EnvMap,
    /// One-bounce indirect radiance per (Gaussian, direction), `j * K + k`.
    pub one_bounce: Option<Vec<[f32; 3]>>,
    /// The map's brightest texels as directional lights (`None` with `RelightSampling::lights = 0`).
    pub lights: Option<BrightLights>,
    /// Two-sided models: the back sides' one-bounce light and light visibility (front and back
    /// rays are reflected off the side of their hit they meet, `svgir_trace::gather_two_sided`).
    pub back_one_bounce: Option<Vec<[f32; 3]>>,
    /// The back sides' directional-light visibility (two-sided models).
    pub back_lights: Option<BrightLights>,
}

impl Relighter {
    /// Traces `sampling.directions` per Gaussian of `s2` (the training buffers are reused when K
    /// matches).
    pub fn new(s2: &Stage2, sampling: RelightSampling) -> Result<Self, PbrError> {
        let t0 = std::time::Instant::now();
        let RelightSampling { directions, lights, bounces } = sampling;
        // The object, then its surroundings (occluders only: no bounce is gathered off them).
        let occluders = s2.relight_occluders();
        let bvh = (directions != s2.mb.k || lights > 0).then(|| Bvh::build(&occluders));
        let p = s2.config.trace_params();
        let mb = match &bvh {
            Some(bvh) if directions != s2.mb.k => {
                let axes = (0..s2.surfels.len()).map(|j| s2.surfels.normal(j)).collect();
                let req = TraceRequest { axes, k: directions, seed: s2.config.seed, params: &p, radiance: false };
                s2.kernels.tracer.trace(bvh, &occluders, req)?
            }
            _ => s2.mb.clone(),
        };
        let cache = DirectionCache::new(&mb, &s2.env.radiance())?;
        let back = match (&s2.back, &bvh) {
            (None, _) => None,
            (Some(b), Some(bvh)) if directions != b.mb.k => {
                let axes = mb.normals.iter().map(|n| -*n).collect();
                let req = TraceRequest { axes, k: directions, seed: s2.config.seed, params: &p, radiance: false };
                let back = s2.kernels.tracer.trace(bvh, &occluders, req)?;
                let cache = DirectionCache::new(&back, &s2.env.radiance())?;
                Some((back, cache))
            }
            (Some(b), _) => Some((b.mb.clone(), b.dir_cache.clone())),
        };
        let surroundings = (s2.config.indirect && !s2.surroundings.is_empty())
            .then(|| LearnedIrradiance::new(&s2.surroundings, &s2.env.radiance()));
        Ok(Self { mb, cache, back, bvh, lights, bounces, surroundings, trace_seconds: t0.elapsed().as_secs_f64() })
    }

    /// Eqn 13 under `env` (unclamped) with the model's current materials; nothing for a model
    /// trained without indirect light (the ablation relights as it was trained).
    pub fn prepare(&self, s2: &Stage2, env: EnvMap) -> Result<PreparedLight, PbrError> {
        let occluders = s2.relight_occluders();
        let lights = match (&self.bvh, self.lights) {
            (Some(bvh), count) if count > 0 => {
                let texels = brightest_texels(&env, count);
                let p = s2.config.trace_params();
                let via = Via(s2.kernels.tracer.as_ref(), bvh);
                Some(BrightLights::trace(&via, &occluders, &self.mb.normals, &env, &texels, &p, None)?)
            }
            _ => None,
        };
        let back_lights = match (&self.back, &self.bvh, &lights) {
            (Some((back, _)), Some(bvh), Some(l)) => {
                let via = Via(s2.kernels.tracer.as_ref(), bvh);
                Some(l.for_normals(&via, &occluders, &back.normals, &s2.config.trace_params(), None)?)
            }
            _ => None,
        };
        if !s2.config.indirect {
            return Ok(PreparedLight { env, one_bounce: None, lights, back_one_bounce: None, back_lights });
        }
        let act = s2.materials.activated(&s2.normals)?;
        let p = GatherParams {
            env_max: f32::INFINITY,
            lights: lights.as_ref(),
            diffuse: s2.config.diffuse,
            cache: None,
            ..Default::default()
        };
        // Rays ending on the surroundings bring their captured colour, relit.
        let gain = self.surroundings.as_ref().map(|l| SurroundingsGain::new(l, &env));
        let tp = s2.config.trace_params();
        let from_surroundings = |mb: &MicroBuffer, light: &mut [[f32; 3]]| match &gain {
            Some(g) => add_surroundings_light(mb, &s2.surroundings, g, &tp, light).map(|_| ()),
            None => Ok(()),
        };
        let Some((back, _)) = &self.back else {
            let mut one_bounce = s2.kernels.tracer.gather_all(&self.mb, &act.view(), &env, &p)?;
            from_surroundings(&self.mb, &mut one_bounce)?;
            svgir_trace::add_bounces(&self.mb, &act.view(), &mut one_bounce, self.bounces)?;
            return Ok(PreparedLight { env, one_bounce: Some(one_bounce), lights, back_one_bounce: None, back_lights });
        };
        // Two-sided: every ray, front or back, is reflected off the side of its hit it meets.
        let flipped = svgir_pbr::two_sided::negated(&act.normals);
        let front_side = HitSide { mb: &self.mb, mats: act.view(), lights: lights.as_ref() };
        let back_side = HitSide {
            mb: back,
            mats: VertexMaterials { normals: &flipped, ..act.view() },
            lights: back_lights.as_ref(),
        };
        let mut one_bounce = s2.kernels.tracer.gather_two_sided(&self.mb, front_side, back_side, &env, &p)?;
        from_surroundings(&self.mb, &mut one_bounce)?;
        // `add_bounces` follows the front sides' paths only.
        svgir_trace::add_bounces(&self.mb, &act.view(), &mut one_bounce, self.bounces)?;
        let mut back_one_bounce = s2.kernels.tracer.gather_two_sided(back, front_side, back_side, &env, &p)?;
        from_surroundings(back, &mut back_one_bounce)?;
        let back_one_bounce = Some(back_one_bounce);
        Ok(PreparedLight { env, one_bounce: Some(one_bounce), lights, back_one_bounce, back_lights })
    }

    /// The PBR render of `camera` under a prepared light (`albedo_scale` as in SPEC 8).
    pub fn render(
        &self,
        s2: &Stage2,
        camera: &Camera,
        bg: [f32; 3],
        light: &PreparedLight,
        albedo_scale: [f32; 3],
    ) -> Result<PbrRender, PbrError> {
        let shading = Shading {
            mb: &self.mb,
            cache: Some(&self.cache),
            env: &light.env,
            indirect: light.one_bounce.as_deref().map_or(Indirect::Off, Indirect::Given),
            params: ShadeParams {
                visibility: s2.config.visibility,
                env_max: f32::INFINITY,
                diffuse: s2.config.diffuse,
                ..ShadeParams::default()
            },
            lights: light.lights.as_ref(),
            back: self.back.as_ref().map(|(mb, cache)| BackShading {
                mb,
                cache: Some(cache),
                indirect: light.back_one_bounce.as_deref().map_or(Indirect::Off, Indirect::Given),
                lights: light.back_lights.as_ref(),
            }),
        };
        s2.render_shaded(camera, bg, &shading, albedo_scale)
    }
}
