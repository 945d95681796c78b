//! `svgir export --compare DIR`: the exported mesh rendered by a real engine next to
//! `svgir relight`'s image of the same view and light.
//!
//! Writes `DIR/relight.png` (the stage-2 model relit under the exported `.hdr`, SPEC 7's
//! renderer with `svgir relight`'s defaults), `DIR/camera.json` (the test view's camera),
//! `DIR/threejs.png` (three.js in headless Chromium, `tools/browser/gltf_render.mjs`),
//! `DIR/side_by_side.png` (relight | three.js | 4x absolute difference) and
//! `DIR/compare.json` (PSNR of the whole image, both over black, and inside the relit
//! object's mask: opacity > 0.5; and the IoU of that mask with three.js's non-black pixels).

use anyhow::{bail, Context, Result};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::Command;
use svgir_core::Image;
use svgir_train::relight::{RelightSampling, Relighter, RELIGHT_BOUNCES, RELIGHT_DIRECTIONS, RELIGHT_LIGHTS};
use svgir_train::stage2::Stage2;

/// tools/browser of the checkout (from the working folder or beside the binary), with its npm packages.
pub fn browser_tools() -> Option<PathBuf> {
    let exe_dir = std::env::current_exe().ok().and_then(|p| p.parent().map(Path::to_path_buf));
    let candidates = [
        std::env::var_os("SVGIR_BROWSER_TOOLS").map(PathBuf::from),
        Some(PathBuf::from("tools/browser")),
        exe_dir.map(|d| d.join("../../tools/browser")),
    ];
    candidates
        .into_iter()
        .flatten()
        .find(|d| d.join("node_modules/three").is_dir() && d.join("gltf_render.mjs").is_file())
}

pub fn compare(
    s2: &Stage2,
    dataset: &svgir_core::Dataset,
    glb: &Path,
    hdr: &Path,
    view: usize,
    dir: &Path,
) -> Result<serde_json::Value> {
    let v = dataset
        .test
        .get(view)
        .or(dataset.train.get(view))
        .with_context(|| format!("--compare-view {view}: no such view"))?;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let env = svgir_io::read_envmap(hdr, 1.0, s2.config.env_height)?;
    let sampling = RelightSampling { directions: RELIGHT_DIRECTIONS, lights: RELIGHT_LIGHTS, bounces: RELIGHT_BOUNCES };
    let relighter = Relighter::new(s2, sampling)?;
    let lit = relighter.prepare(s2, env)?;
    let r = relighter.render(s2, &v.camera, [0.0; 3], &lit, [1.0; 3])?;
    let relit = Image::from_data(r.width, r.height, 3, r.image.iter().map(|c| c.clamp(0.0, 1.0)).collect());
    svgir_io::write_png(dir.join("relight.png"), &relit, 8)?;
    let c = &v.camera;
    let k = &c.intrinsics;
    let cam = json!({
        "view": v.name, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height,
        "rotation": c.rotation.transpose().to_cols_array(), "translation": c.translation.to_array(),
    });
    let cam_path = dir.join("camera.json");
    std::fs::write(&cam_path, serde_json::to_vec_pretty(&cam)?).with_context(|| cam_path.display().to_string())?;
    let Some(tools) = browser_tools() else {
        bail!("tools/browser with its npm packages not found (run `cd tools/browser && npm ci`, or set SVGIR_BROWSER_TOOLS)");
    };
    let three_path = dir.join("threejs.png");
    let status = Command::new("node")
        .arg(tools.join("gltf_render.mjs"))
        .args([glb, hdr, &cam_path, &three_path])
        .status()
        .context("running node (is Node.js installed?)")?;
    if !status.success() {
        bail!("three.js render failed ({status})");
    }
    let three = svgir_io::read_image(&three_path)?;
    if (three.width, three.height) != (relit.width, relit.height) {
        bail!("three.js image is {}x{}, expected {}x{}", three.width, three.height, relit.width, relit.height);
    }
    let three = if three.channels == 4 { three.select_channels(0..3) } else { three };
    let mask: Vec<f32> = r.alpha.iter().map(|&a| if a > 0.5 { 1.0 } else { 0.0 }).collect();
    let psnr = svgir_metrics::psnr(&relit.data, &three.data, 3, None)?;
    let psnr_masked = svgir_metrics::psnr(&relit.data, &three.data, 3, Some(&mask))?;
    // Silhouette agreement: the relit opacity > 0.5 against three.js's non-background pixels
    // (any channel > 0.02).
    let fa: Vec<bool> = mask.iter().map(|&m| m > 0.0).collect();
    let fb: Vec<bool> = three.data.chunks_exact(3).map(|p| p.iter().any(|&c| c > 0.02)).collect();
    let inter = fa.iter().zip(&fb).filter(|(a, b)| **a && **b).count();
    let union = fa.iter().zip(&fb).filter(|(a, b)| **a || **b).count();
    let iou = inter as f64 / union.max(1) as f64;
    let (w, h) = (relit.width, relit.height);
    // Small renders are enlarged (nearest) so the report shows them at a readable size.
    let s = (384 / h).max(1);
    let mut side = Image::new(3 * w * s, h * s, 3);
    for y in 0..h * s {
        for x in 0..w * s {
            let (a, b) = (relit.pixel(x / s, y / s).to_vec(), three.pixel(x / s, y / s).to_vec());
            side.pixel_mut(x, y).copy_from_slice(&a);
            side.pixel_mut(w * s + x, y).copy_from_slice(&b);
            let d: Vec<f32> = a.iter().zip(&b).map(|(p, q)| (4.0 * (p - q).abs()).min(1.0)).collect();
            side.pixel_mut(2 * w * s + x, y).copy_from_slice(&d);
        }
    }
    svgir_io::write_png(dir.join("side_by_side.png"), &side, 8)?;
    let out = json!({
        "view": v.name, "glb": glb, "hdr": hdr, "width": w, "height": h,
        "psnr_db": psnr, "psnr_masked_db": psnr_masked, "silhouette_iou": iou,
        "mask": "relit opacity > 0.5", "engine": "three.js 0.187.0, WebGL2 (SwiftShader), NoToneMapping, sRGB output, PMREM of the .hdr",
        "images": { "relight": "relight.png", "threejs": "threejs.png", "side_by_side": "side_by_side.png (relight | three.js | 4x |difference|)" },
    });
    std::fs::write(dir.join("compare.json"), serde_json::to_vec_pretty(&out)?)?;
    println!(
        "three.js vs svgir relight ({}): PSNR {psnr:.2} dB, {psnr_masked:.2} dB inside the object, silhouette IoU {iou:.3}: {}",
        v.name,
        dir.display()
    );
    Ok(out)
}
