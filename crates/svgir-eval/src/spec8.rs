//! SPEC 8's evaluation of a stage-2 model on the dataset's test views: novel views (the PBR
//! image under the learned light), albedo after the per-channel median scale, roughness MSE,
//! normal MAE, and relighting under every map the dataset names (SPEC 7), per light and on
//! average. Used by `svgir inverse` at the end of training and by `svgir eval --run`.
//!
//! [`evaluate`] computes and returns the metrics; the pictures it scores (with their ground
//! truth) and the relit turntables go to an [`EvalSink`], and only a sink writes files:
//! [`EvalWriter`] puts them under the run's `test/` and `turntable/` folders.

use crate::turntable::turntable_cameras;
use anyhow::Result;
use serde_json::json;
use std::path::Path;
use svgir_core::{Dataset, Image, LightInfo};
use svgir_metrics::{evaluate_pair, ImageMetrics, Lpips, SsimVariant};
use svgir_train::relight::{RelightSampling, Relighter};
use svgir_train::stage1::alpha_of;
use svgir_train::Stage2;

/// An image as RGB: RGBA composited over `bg`, grey repeated, extra channels dropped.
pub fn rgb(img: &Image, bg: [f32; 3]) -> Image {
    match img.channels {
        4 => img.composite_over(bg),
        3 => img.clone(),
        1 => Image::from_data(img.width, img.height, 3, img.data.iter().flat_map(|v| [*v; 3]).collect()),
        _ => img.select_channels(0..3),
    }
}

/// Colour over black divided by its opacity: the render's straight colour (0 where nothing was hit).
pub fn straight_colour(over_black: &[f32], alpha: &[f32]) -> Vec<f32> {
    over_black
        .chunks(3)
        .zip(alpha)
        .flat_map(|(c, a)| {
            let inv = if *a > 1e-5 { 1.0 / a } else { 0.0 };
            c.iter().map(move |x| (x * inv).clamp(0.0, 1.0))
        })
        .collect()
}

/// Where the evaluation's pictures go, and its progress lines.
pub trait EvalSink {
    /// A picture the evaluation scored or made; `rel` is its path under the run's output folder
    /// (`test/<view>_<kind>.png` or `.exr`, `turntable/<light>_<frame>.png`).
    fn picture(&mut self, rel: &str, image: Image) -> Result<()>;
    /// One line of progress (timings of the relighting traces).
    fn progress(&mut self, line: &str);
}

/// Writes the pictures under `out` (8-bit PNG, or full-precision EXR by the name's extension)
/// and prints progress to stderr: what `svgir inverse` and `svgir eval --run` use.
pub struct EvalWriter {
    out: std::path::PathBuf,
}

impl EvalWriter {
    /// A writer into the folder `out` (created with its subfolders as pictures arrive).
    pub fn new(out: &Path) -> Self {
        Self { out: out.to_path_buf() }
    }
}

impl EvalSink for EvalWriter {
    fn picture(&mut self, rel: &str, image: Image) -> Result<()> {
        let path = self.out.join(rel);
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        if rel.ends_with(".exr") {
            svgir_io::write_exr(&path, &image)?;
        } else {
            svgir_io::write_png(&path, &image, 8)?;
        }
        Ok(())
    }

    fn progress(&mut self, line: &str) {
        eprintln!("{line}");
    }
}

/// Keeps no picture and prints nothing: the metrics alone.
pub struct MetricsOnly;

impl EvalSink for MetricsOnly {
    fn picture(&mut self, _rel: &str, _image: Image) -> Result<()> {
        Ok(())
    }

    fn progress(&mut self, _line: &str) {}
}

/// `data` (1 or 3 channels, `w x h`) as a picture for the sink.
fn picture(sink: &mut dyn EvalSink, rel: String, w: u32, h: u32, data: Vec<f32>) -> Result<()> {
    let ch = (data.len() / (w * h) as usize) as u32;
    sink.picture(&rel, Image::from_data(w, h, ch, data))
}

/// The mean metrics of `all` as JSON; without an LPIPS model its entry says so
/// (`lpips_weights::NOT_COMPUTED`) instead of being left out.
fn mean_json(all: &[ImageMetrics]) -> serde_json::Value {
    ImageMetrics::mean(all).map_or(serde_json::Value::Null, |m| {
        let mut v = json!(m);
        if m.lpips.is_none() {
            v["lpips"] = json!(crate::lpips_weights::NOT_COMPUTED);
        }
        v
    })
}

/// SPEC 8 on the test views: NVS, albedo (median-scaled), roughness MSE, normal MAE, relighting.
pub fn evaluate(
    s2: &Stage2,
    ds: &Dataset,
    lpips: Option<&Lpips>,
    turntable: usize,
    sampling: RelightSampling,
    extra_lights: &[LightInfo],
    sink: &mut dyn EvalSink,
) -> Result<serde_json::Value> {
    let env = s2.env.radiance();
    let black = [0.0f32; 3];
    let variant = SsimVariant::GaussianSplatting;
    let mut nvs = Vec::new();
    let mut renders = Vec::new();
    let mut scale_acc = svgir_metrics::AlbedoScale::new();
    let mut normal_mae = svgir_metrics::NormalMae::new();
    let (mut rough_se, mut rough_n) = (0.0f64, 0u64);
    for v in &ds.test {
        let r = s2.render_pbr(&v.camera, black, &env, [1.0; 3])?;
        let (w, h) = (r.width, r.height);
        let mask = alpha_of(&v.image);
        let pred = Image::from_data(w, h, 3, r.image.clone());
        // SPEC 8: both over black (the photo is straight-alpha RGBA; the render already is).
        nvs.push(evaluate_pair(&pred, &rgb(&v.image, black), None, variant, lpips)?);
        picture(sink, format!("test/{}_pbr.png", v.name), w, h, r.image.iter().map(|x| x.clamp(0.0, 1.0)).collect())?;
        picture(sink, format!("test/{}_gt_rgb.png", v.name), w, h, v.image.composite_over(black).data)?;
        picture(sink, format!("test/{}_normal.png", v.name), w, h, r.normal.iter().map(|n| 0.5 + 0.5 * n).collect())?;
        picture(sink, format!("test/{}_roughness.png", v.name), w, h, r.roughness.clone())?;
        // Full-precision material maps for other tools.
        sink.picture(&format!("test/{}_albedo.exr", v.name), Image::from_data(w, h, 3, r.albedo.clone()))?;
        sink.picture(&format!("test/{}_roughness.exr", v.name), Image::from_data(w, h, 1, r.roughness.clone()))?;
        sink.picture(&format!("test/{}_normal.exr", v.name), Image::from_data(w, h, 3, r.normal.clone()))?;
        match &v.albedo {
            Some(gt) => scale_acc.add_view(&r.albedo, &gt.data, &mask)?,
            // No truth to scale against: the albedo as learned, for a person to look at.
            None => picture(
                sink,
                format!("test/{}_albedo.png", v.name),
                w,
                h,
                r.albedo.iter().map(|c| svgir_core::color::linear_to_srgb(c.clamp(0.0, 1.0))).collect(),
            )?,
        }
        if let Some(gt) = &v.normal {
            normal_mae.add_view(&r.normal, &gt.data, &mask)?;
            picture(
                sink,
                format!("test/{}_gt_normal.png", v.name),
                w,
                h,
                gt.data.iter().map(|n| 0.5 + 0.5 * n).collect(),
            )?;
        }
        if let Some(gt) = &v.roughness {
            for (p, (g, m)) in r.roughness.iter().zip(gt.data.iter().zip(&mask)) {
                if *m > 0.5 {
                    rough_se += ((p - g) as f64).powi(2);
                    rough_n += 1;
                }
            }
            picture(sink, format!("test/{}_gt_roughness.png", v.name), w, h, gt.data.clone())?;
        }
        renders.push((r, mask));
    }
    let mut result = json!({ "nvs": mean_json(&nvs), "views": ds.test.len() });
    if let Some(mae) = normal_mae.mean_deg() {
        result["normal_mae_deg"] = json!(mae);
    }
    if rough_n > 0 {
        result["roughness_mse"] = json!(rough_se / rough_n as f64);
    }
    let scale = scale_acc.scale().unwrap_or([1.0; 3]);
    let mut albedo = Vec::new();
    for (v, (r, mask)) in ds.test.iter().zip(&renders) {
        let Some(gt) = &v.albedo else { continue };
        let (w, h) = (r.width, r.height);
        let srgb = |x: &[f32]| x.iter().map(|c| svgir_core::color::linear_to_srgb(*c)).collect::<Vec<f32>>();
        let pred = srgb(&svgir_metrics::apply_albedo_scale(&r.albedo, scale, mask, black)?);
        let gt_s = srgb(&svgir_metrics::apply_albedo_scale(&gt.data, [1.0; 3], mask, black)?);
        albedo.push(evaluate_pair(
            &Image::from_data(w, h, 3, pred.clone()),
            &Image::from_data(w, h, 3, gt_s.clone()),
            None,
            variant,
            lpips,
        )?);
        picture(sink, format!("test/{}_albedo.png", v.name), w, h, pred)?;
        picture(sink, format!("test/{}_gt_albedo.png", v.name), w, h, gt_s)?;
    }
    if !albedo.is_empty() {
        result["albedo"] = mean_json(&albedo);
        result["albedo_scale"] = json!(scale);
    }
    // Relighting (SPEC 7): K micro-buffers, one-bounce indirect per light.
    let mut per_light = serde_json::Map::new();
    let mut all = Vec::new();
    let lights: Vec<&LightInfo> = ds.relight_lights.iter().chain(extra_lights).collect();
    let relighter = if lights.iter().any(|l| l.envmap_path.is_some()) {
        let r = Relighter::new(s2, sampling)?;
        sink.progress(&format!(
            "relighting: traced K = {} directions and {} lights in {:.1} s",
            sampling.directions, sampling.lights, r.trace_seconds
        ));
        result["relight_directions"] = json!(sampling.directions);
        result["relight_lights"] = json!(sampling.lights);
        result["relight_bounces"] = json!(sampling.bounces);
        Some(r)
    } else {
        None
    };
    for light in lights {
        let (Some(path), Some(relighter)) = (&light.envmap_path, &relighter) else { continue };
        let t0 = std::time::Instant::now();
        let map = if light.strength.is_nan() {
            exposure_matched(path, &env, s2.config.env_height, sink)?
        } else {
            svgir_io::read_envmap(path, light.strength, s2.config.env_height)?
        };
        let lit = relighter.prepare(s2, map)?;
        sink.progress(&format!(
            "relighting: one-bounce light under {} in {:.1} s",
            light.name,
            t0.elapsed().as_secs_f64()
        ));
        let mut ms = Vec::new();
        for (v, (_, mask)) in ds.test.iter().zip(&renders) {
            let r = relighter.render(s2, &v.camera, black, &lit, scale)?;
            let Some(gt) = v.relit.get(&light.name) else {
                // No truth (a capture, or a map given with --relight-with): the picture only.
                let img = r.image.iter().map(|c| c.clamp(0.0, 1.0)).collect();
                picture(sink, format!("test/{}_relit_{}.png", v.name, light.name), r.width, r.height, img)?;
                continue;
            };
            // SPEC 8: the predicted colour and the photo are both composited with the GT mask on
            // black, so the prediction enters as straight colour (not already multiplied by its
            // own opacity, which would count the coverage twice at edges).
            let pred = Image::from_data(r.width, r.height, 3, straight_colour(&r.image, &r.alpha));
            ms.push(evaluate_pair(&pred, gt, Some(mask), variant, lpips)?);
            let masked: Vec<f32> = pred
                .data
                .chunks(3)
                .zip(mask)
                .flat_map(|(p, m)| p.iter().map(move |c| (c * m).clamp(0.0, 1.0)))
                .collect();
            picture(sink, format!("test/{}_relit_{}.png", v.name, light.name), r.width, r.height, masked)?;
            picture(
                sink,
                format!("test/{}_gt_relit_{}.png", v.name, light.name),
                r.width,
                r.height,
                gt.composite_over(black).data,
            )?;
        }
        if let Some(first) = ds.test.first() {
            for (f, cam) in turntable_cameras(ds, &first.camera, turntable).iter().enumerate() {
                let r = relighter.render(s2, cam, black, &lit, scale)?;
                picture(
                    sink,
                    format!("turntable/{}_{f:03}.png", light.name),
                    r.width,
                    r.height,
                    r.image.iter().map(|c| c.clamp(0.0, 1.0)).collect(),
                )?;
            }
        }
        all.extend_from_slice(&ms);
        if !ms.is_empty() {
            per_light.insert(light.name.clone(), mean_json(&ms));
        }
    }
    if !all.is_empty() {
        result["relight"] = json!({"mean": mean_json(&all), "per_light": per_light});
    }
    Ok(result)
}

/// The map at `path` scaled so that its mean luminance equals `like`'s (a capture's learned
/// light), so the object relit under it is exposed as in the photos.
fn exposure_matched(
    path: &Path,
    like: &svgir_core::EnvMap,
    height: u32,
    sink: &mut dyn EvalSink,
) -> Result<svgir_core::EnvMap> {
    let lum = |c: [f32; 3]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
    let mut map = svgir_io::read_envmap(path, 1.0, height)?;
    let m = lum(map.mean_radiance());
    anyhow::ensure!(m > 0.0 && m.is_finite(), "{}: the map is black", path.display());
    let strength = lum(like.mean_radiance()) / m;
    sink.progress(&format!(
        "relighting: {} at strength {strength:.3} (the learned light's mean luminance)",
        path.display()
    ));
    // Radiance is strength x map value: scale the map read once at strength 1.
    map.data.iter_mut().flatten().for_each(|c| *c *= strength);
    Ok(map)
}
