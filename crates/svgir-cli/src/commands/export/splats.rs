//! Splat outputs of `svgir export`: the stage-2 model's radiance under a chosen light as a
//! radiance field viewers can draw.
//!
//! Every Gaussian is shaded (SPEC 4, with the relighting's one-bounce indirect light and
//! directional lights, `svgir_train::relight`) as seen from 64 Fibonacci directions; its colour
//! (vertex blend at the centre, sRGB-encoded: 3DGS viewers blend display values) is fitted by an
//! SH of `--splat-sh-degree`, each view weighted by how squarely it faces the oriented normal.
//! `--ply` writes the 3DGS layout (`f_dc_*`, `f_rest_*`, opacity, scales, rotation, the oriented
//! normal in `nx ny nz`) with the materials as extra columns; `--splats` the
//! `KHR_gaussian_splatting` glTF (`svgir_export::splats`).

use super::ExportArgs;
use anyhow::{Context, Result};
use glam::Vec3;
use rayon::prelude::*;
use serde_json::json;
use std::path::PathBuf;
use svgir_core::color::linear_to_srgb;
use svgir_core::ShCoeffs;
use svgir_export::splats::{fit_sh, oriented, sphere_directions, splat_glb, to_y_up, ExtraAttribute};
use svgir_pbr::{shade_into_cached, Indirect, ShadeInputs, ShadeOutput, ShadeParams};
use svgir_train::relight::{RelightSampling, Relighter, RELIGHT_LIGHTS};
use svgir_train::stage2::Stage2;

/// View directions the radiance is sampled from.
const VIEWS: usize = 64;

pub fn export(
    args: &ExportArgs,
    s2: &Stage2,
    out: &mut Vec<(PathBuf, Vec<u8>)>,
    report: &mut serde_json::Value,
) -> Result<()> {
    let degree = args.splat_sh_degree.min(3);
    let env = match &args.light {
        Some(p) => svgir_io::read_envmap(p, args.strength, s2.config.env_height)?,
        None => s2.env.radiance(),
    };
    // The training micro-buffers (K as trained) are reused: no re-trace.
    let sampling = RelightSampling { directions: s2.mb.k, lights: RELIGHT_LIGHTS, bounces: 0 };
    let relighter = Relighter::new(s2, sampling)?;
    let lit = relighter.prepare(s2, env)?;
    let act = s2.materials.activated(&s2.normals)?;
    let n = s2.surfels.len();
    let m = act.m;
    let centre_w = svgir_shading::vertex_weights(m, 0.5f32, 0.5);
    let (lo, hi) = s2.surfels.bounds().context("the model has no Gaussians")?;
    let centroid = 0.5 * (lo + hi);
    let far = 1e3 * (hi - lo).length().max(1.0);
    let visible = vec![true; n];
    let views = sphere_directions(VIEWS);
    // colours[d * n + i]: Gaussian i seen from direction d (towards the viewer), sRGB.
    let mut colours = vec![[0.0f32; 3]; VIEWS * n];
    let mut shaded = ShadeOutput::new();
    for (d, w) in views.iter().enumerate() {
        let inputs = ShadeInputs {
            mb: &relighter.mb,
            positions: &s2.surfels.positions,
            camera_center: centroid + *w * far,
            visible: &visible,
            mats: act.view(),
            env_geom: &lit.env,
            env: &lit.env.data,
            indirect: lit.one_bounce.as_deref().map_or(Indirect::Off, Indirect::Given),
            params: ShadeParams {
                visibility: s2.config.visibility,
                env_max: f32::INFINITY,
                diffuse: s2.config.diffuse,
                ..ShadeParams::default()
            },
            lights: lit.lights.as_ref(),
        };
        shade_into_cached(&inputs, None, &mut shaded)?;
        colours[d * n..(d + 1) * n].par_iter_mut().enumerate().for_each(|(i, c)| {
            for k in 0..m {
                for ch in 0..3 {
                    c[ch] += centre_w[k] * shaded.color[(i * m + k) * 3 + ch];
                }
            }
            *c = c.map(|v| linear_to_srgb(v.clamp(0.0, 1.0)));
        });
    }
    let fit = |frame: &(dyn Fn(Vec3) -> Vec3 + Sync)| -> Vec<ShCoeffs> {
        (0..n)
            .into_par_iter()
            .map(|i| {
                let nrm = s2.normals[i];
                let dirs: Vec<Vec3> = views.iter().map(|w| frame(-*w)).collect();
                let cols: Vec<[f32; 3]> = (0..VIEWS).map(|d| colours[d * n + i]).collect();
                let weights: Vec<f32> = views.iter().map(|w| nrm.dot(*w).max(0.0).powi(2) + 1e-3).collect();
                let total: f32 = weights.iter().sum();
                fit_sh(&dirs, &cols, &weights, degree, 1e-2 * total as f64)
            })
            .collect()
    };
    let mut surfels = oriented(&s2.surfels, &s2.normals);
    surfels.sh_degree = degree;
    let a = &act.albedo;
    let albedo: Vec<f32> =
        (0..n * 3).map(|j| (0..m).map(|k| centre_w[k] * a[((j / 3) * m + k) * 3 + j % 3]).sum()).collect();
    let roughness: Vec<f32> = (0..n).map(|i| (0..m).map(|k| centre_w[k] * act.roughness[i * m + k]).sum()).collect();
    if let Some(p) = &args.ply {
        surfels.sh = fit(&|v| v);
        let extras: Vec<(String, Vec<f32>)> = vec![
            ("albedo_r".into(), albedo.iter().step_by(3).copied().collect()),
            ("albedo_g".into(), albedo.iter().skip(1).step_by(3).copied().collect()),
            ("albedo_b".into(), albedo.iter().skip(2).step_by(3).copied().collect()),
            ("roughness".into(), roughness.clone()),
        ];
        let bytes = svgir_io::ply::encode_gaussians_ply(&surfels, &extras)
            .map_err(|e| anyhow::anyhow!("{}: encoding the splat PLY: {e}", p.display()))?;
        out.push((p.clone(), bytes));
    }
    if let Some(p) = &args.splats {
        surfels.sh = fit(&to_y_up);
        let normals: Vec<f32> = s2.normals.iter().flat_map(|v| v.to_array()).collect();
        let extras = [
            ExtraAttribute { name: "ALBEDO".into(), comps: 3, data: albedo.clone() },
            ExtraAttribute { name: "ROUGHNESS".into(), comps: 1, data: roughness.clone() },
            ExtraAttribute { name: "NORMAL".into(), comps: 3, data: normals },
        ];
        out.push((p.clone(), splat_glb(&surfels, &extras)?));
    }
    report["splats"] = json!({
        "gaussians": n, "sh_degree": degree, "views": VIEWS,
        "light": args.light.as_ref().map_or("learned".to_string(), |p| p.display().to_string()), "strength": args.strength,
    });
    Ok(())
}
