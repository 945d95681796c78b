//! Rendering a stage-2 model: shade every Gaussian's vertices (SPEC 4), splat the colours and
//! the material buffers (SPEC 3), divide by coverage and encode to sRGB. Used by the evaluation
//! and relighting; training's own forward pass lives in [`super::Stage2::step`], which also keeps
//! what the backward needs.

use super::objective::{extra_features, EXTRA_CHANNELS, MIN_OPACITY};
use super::shaded_set::{visible_of, weighted};
use super::Stage2;
use crate::composite::pbr_composite;
use glam::Vec3;
use svgir_core::Camera;
use svgir_pbr::{negated, DirectionCache, Indirect, PbrError, ShadeInputs, ShadeOutput, ShadeParams, Side};
use svgir_raster::{render, Background, ColorSource, Features, RasterConfig, RenderInput};
use svgir_trace::VertexMaterials;
use svgir_trace::{BrightLights, MicroBuffer};

/// Everything a PBR render produces, per pixel, after dividing by opacity.
pub struct PbrRender {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// sRGB image composited over the background.
    pub image: Vec<f32>,
    /// Rendered opacity per pixel.
    pub alpha: Vec<f32>,
    /// Linear albedo, roughness and unit shading normal (0 where nothing was hit).
    pub albedo: Vec<f32>,
    /// Roughness per pixel (0 where nothing was hit).
    pub roughness: Vec<f32>,
    /// Unit world shading normal per pixel, 3 values (0 where nothing was hit).
    pub normal: Vec<f32>,
}

impl PbrRender {
    /// Blend the image with `bg` by `cover` (one alpha per pixel, e.g. the photo's) instead of
    /// the render's own opacity: its straight colour, `(I - bg (1 - O)) / O`, re-blended.
    pub fn recomposite(&mut self, cover: &[f32], bg: [f32; 3]) {
        for ((px, &o), &m) in self.image.chunks_exact_mut(3).zip(&self.alpha).zip(cover) {
            for (c, b) in px.iter_mut().zip(bg) {
                let straight = if o > MIN_OPACITY { (*c - b * (1.0 - o)) / o } else { 0.0 };
                *c = straight * m + b * (1.0 - m);
            }
        }
    }
}

/// What a PBR render shades with: micro-buffers (and their direction cache), the light, the
/// indirect term and the shading parameters.
pub struct Shading<'a> {
    /// Front-side micro-buffers.
    pub mb: &'a MicroBuffer,
    /// Their direction cache (`None`: lookups computed on the fly).
    pub cache: Option<&'a DirectionCache>,
    /// The environment light.
    pub env: &'a svgir_core::EnvMap,
    /// The indirect term.
    pub indirect: Indirect<'a, f32>,
    /// Switches of the rendering equation.
    pub params: ShadeParams,
    /// Texels of `env` shaded as directional lights.
    pub lights: Option<&'a BrightLights>,
    /// The back sides (two-sided shading; `None`: every Gaussian on its oriented side).
    pub back: Option<BackShading<'a>>,
}

/// The back sides' micro-buffers (over -n), direction cache, indirect term and light visibility.
pub struct BackShading<'a> {
    /// Back-side micro-buffers (over -n).
    pub mb: &'a MicroBuffer,
    /// Their direction cache (`None`: lookups computed on the fly).
    pub cache: Option<&'a DirectionCache>,
    /// The back sides' indirect term.
    pub indirect: Indirect<'a, f32>,
    /// The back sides' directional-light visibility.
    pub lights: Option<&'a BrightLights>,
}

impl Stage2 {
    /// Render the PBR image and material buffers for `camera` over `bg` as training does (the
    /// training micro-buffers, traced indirect light and the clamp of SPEC 4); `albedo_scale`
    /// multiplies every vertex albedo (SPEC 8 evaluation). Relighting at SPEC 7's K goes through
    /// [`crate::relight::Relighter`].
    pub fn render_pbr(
        &self,
        camera: &Camera,
        bg: [f32; 3],
        env: &svgir_core::EnvMap,
        albedo_scale: [f32; 3],
    ) -> Result<PbrRender, PbrError> {
        let shading = Shading {
            mb: &self.mb,
            cache: Some(&self.dir_cache),
            env,
            indirect: self.indirect(),
            params: self.shade_params(),
            lights: self.active_lights(),
            back: self.back.as_ref().map(|b| BackShading {
                mb: &b.mb,
                cache: Some(&b.dir_cache),
                indirect: self.indirect(),
                lights: self.active_back_lights(),
            }),
        };
        self.render_shaded(camera, bg, &shading, albedo_scale)
    }

    /// Render with the given micro-buffers, light and shading parameters.
    pub fn render_shaded(
        &self,
        camera: &Camera,
        bg: [f32; 3],
        shading: &Shading,
        albedo_scale: [f32; 3],
    ) -> Result<PbrRender, PbrError> {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        let npix = w * h;
        let m = self.config.vertices;
        let mut act = self.materials.activated(&self.normals)?;
        for (i, a) in act.albedo.iter_mut().enumerate() {
            *a *= albedo_scale[i % 3];
        }
        // A colour-only pass finds the Gaussians this view blends, and only they are shaded
        // (`weighted`); the images equal those of shading every Gaussian.
        let probe = RenderInput {
            surfels: &self.surfels,
            camera,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color([0.0; 3]),
        };
        let (seen, seen_state) = render(&probe, &RasterConfig { geometry: false, for_backward: false, ..self.raster });
        let blended = weighted(&visible_of(&seen.max_radius), &seen.accum_weight, 0.0);
        let (front_vis, back_vis) = self.sides(camera, &blended, shading.back.is_some());
        let back_normals = shading.back.as_ref().map(|_| negated(&act.normals));
        let front = Side {
            inputs: ShadeInputs {
                mb: shading.mb,
                positions: &self.surfels.positions,
                camera_center: camera.center(),
                visible: &front_vis,
                mats: act.view(),
                env_geom: shading.env,
                env: &shading.env.data,
                indirect: shading.indirect,
                params: shading.params,
                lights: shading.lights,
            },
            cache: shading.cache,
        };
        let back = back_side(&front, shading.back.as_ref(), &back_vis, back_normals.as_deref());
        let mut shaded = ShadeOutput::new();
        self.kernels.shader.shade_sides(&front, back.as_ref(), &mut shaded)?;
        let extra = extra_features(&act, &self.facing(camera));
        let input = RenderInput {
            surfels: &self.surfels,
            camera,
            colors: ColorSource::Features(Features { data: &shaded.color, vertices: m, channels: 3, uniform: 0 }),
            extra: Some(Features { data: &extra, vertices: m, channels: EXTRA_CHANNELS, uniform: 0 }),
            background: Background::Color([0.0; 3]),
        };
        // The normal image is the shading normals' (feature channels), not the splats'.
        let cfg = RasterConfig { normals: false, ..self.raster };
        let (out, _) =
            self.kernels.raster.render(&input, &cfg, &seen_state.projected()).map_err(super::raster_error)?;
        let mut r = PbrRender {
            width: w as u32,
            height: h as u32,
            image: Vec::new(),
            alpha: out.alpha.clone(),
            albedo: vec![0.0; npix * 3],
            roughness: vec![0.0; npix],
            normal: vec![0.0; npix * 3],
        };
        r.image = pbr_composite(&out.color, &out.alpha, None, bg);
        for p in 0..npix {
            let inv = 1.0 / out.alpha[p].max(MIN_OPACITY);
            let e = &out.extra[EXTRA_CHANNELS * p..EXTRA_CHANNELS * (p + 1)];
            let n = Vec3::new(e[4], e[5], e[6]).normalize_or_zero();
            for c in 0..3 {
                r.albedo[3 * p + c] = e[c] * inv;
                r.normal[3 * p + c] = n[c];
            }
            r.roughness[p] = e[3] * inv;
        }
        Ok(r)
    }
}

/// The back side's shading inputs: `front`'s, with the back micro-buffers, indirect term and
/// lights, the Gaussians `visible` seen from behind and the negated shading `normals`.
pub(crate) fn back_side<'a>(
    front: &Side<'a, f32>,
    back: Option<&BackShading<'a>>,
    visible: &'a [bool],
    normals: Option<&'a [f32]>,
) -> Option<Side<'a, f32>> {
    let (b, normals) = (back?, normals?);
    let f = &front.inputs;
    Some(Side {
        inputs: ShadeInputs {
            mb: b.mb,
            visible,
            mats: VertexMaterials { normals, ..f.mats },
            indirect: b.indirect,
            lights: b.lights,
            ..*f
        },
        cache: b.cache,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recomposite_keeps_the_straight_colour_and_swaps_the_coverage() {
        let bg = [0.2, 0.4, 0.6];
        let (straight, o) = ([0.9f32, 0.5, 0.1], [0.25f32, 1.0, 0.0]);
        let image = o.iter().flat_map(|&o| (0..3).map(move |c| straight[c] * o + bg[c] * (1.0 - o))).collect();
        let mut r = PbrRender {
            width: 3,
            height: 1,
            image,
            alpha: o.to_vec(),
            albedo: vec![0.0; 9],
            roughness: vec![0.0; 3],
            normal: vec![0.0; 9],
        };
        r.recomposite(&[1.0, 0.5, 1.0], bg);
        let want = [straight, [0, 1, 2].map(|c| 0.5 * straight[c] + 0.5 * bg[c]), [0.0; 3]];
        for (got, want) in r.image.chunks(3).zip(want) {
            for (g, w) in got.iter().zip(want) {
                assert!((g - w).abs() < 1e-6, "{got:?} vs {want:?}");
            }
        }
    }
}
