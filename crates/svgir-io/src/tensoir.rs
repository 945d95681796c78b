//! TensoIR layout: one folder per view (`train_000/`, `test_000/`, ...) holding `rgba.png`,
//! `albedo.png` (linear, 8-bit), `normal.png` (world, `(n + 1) / 2`), `roughness.png`,
//! `rgba_<light>.png` (relit, test views) and `metadata.json` (`cam_transform_mat` row-major
//! Blender c2w, `cam_angle_x`, `imw`, `imh`, `envmap`, `envmap_inten`, ...).
//!
//! Views are listed by `transforms_<split>.json` when present (the frame's `file_path` names the
//! folder), else by the `<split>_NNN` folders in name order with cameras from `metadata.json`.
//! Lights come from `scene.json` (names, strengths, copies of the maps) when present, else from
//! the first view's `metadata.json`. Views load in parallel (rayon).

use crate::error::{ErrorKind, Result, WithPath};
use crate::image_io::to_rgba;
use crate::load::{
    alpha_of, check_size, decode_normals, finish_view, read_json, read_view_image, select_views, LoadOptions,
};
use crate::mask::stored_alpha_is_mask;
use crate::nerf::{blender_camera, dataset_name, parse_matrix, read_transforms};
use glam::Mat4;
use rayon::prelude::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use svgir_core::{Dataset, Image, Intrinsics, LightInfo, MaskSource, View};

/// True if `root` looks like a TensoIR dataset (a `train_000/metadata.json`, or transforms whose
/// first frame lives in a folder with `metadata.json`).
pub fn is_tensoir(root: &Path) -> bool {
    if root.join("train_000/metadata.json").is_file() {
        return true;
    }
    match read_transforms(root, "train") {
        Ok(tf) => {
            tf.frames.first().and_then(|f| f.image_path.parent()).is_some_and(|d| d.join("metadata.json").is_file())
        }
        Err(_) => false,
    }
}

/// One view to load: its folder, camera matrix, and field of view.
struct Entry {
    dir: PathBuf,
    c2w: Mat4,
    fov_x: f32,
    size: Option<(u32, u32)>,
    /// Where the camera came from, for error messages.
    source: PathBuf,
}

fn entries(root: &Path, split: &str) -> Result<Vec<Entry>> {
    if root.join(format!("transforms_{split}.json")).is_file() {
        let tf = read_transforms(root, split)?;
        let source = root.join(format!("transforms_{split}.json"));
        return Ok(tf
            .frames
            .into_iter()
            .map(|f| Entry {
                dir: f.image_path.parent().map(Path::to_path_buf).unwrap_or_else(|| root.to_path_buf()),
                c2w: f.c2w,
                fov_x: tf.camera_angle_x,
                size: tf.size,
                source: source.clone(),
            })
            .collect());
    }
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(root)
        .at(root)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let name = p.file_name().and_then(|s| s.to_str()).unwrap_or("");
            name.strip_prefix(split)
                .and_then(|r| r.strip_prefix('_'))
                .is_some_and(|n| n.chars().all(|c| c.is_ascii_digit()))
                && p.join("metadata.json").is_file()
        })
        .collect();
    dirs.sort();
    dirs.into_iter()
        .enumerate()
        .map(|(i, dir)| {
            let source = dir.join("metadata.json");
            let meta = read_json(&source)?;
            let cam_err = |p: String| ErrorKind::Camera { index: i, problem: p }.at(&source);
            let c2w =
                parse_matrix(&meta["cam_transform_mat"]).map_err(|p| cam_err(format!("{p} in cam_transform_mat")))?;
            let fov_x = meta["cam_angle_x"]
                .as_f64()
                .map(|a| a as f32)
                .filter(|a| a.is_finite() && *a > 0.0 && *a < std::f32::consts::PI)
                .ok_or_else(|| cam_err("cam_angle_x missing or not an angle".into()))?;
            let size = match (meta["imw"].as_u64(), meta["imh"].as_u64()) {
                (Some(w), Some(h)) if w > 0 && h > 0 && w < 1 << 20 && h < 1 << 20 => Some((w as u32, h as u32)),
                _ => None,
            };
            Ok(Entry { dir, c2w, fov_x, size, source })
        })
        .collect()
}

/// An optional ground-truth file of a view: absent is fine, unreadable or the wrong size is not.
fn optional(path: &Path, view: usize, size: (u32, u32)) -> Result<Option<Image>> {
    if !path.exists() {
        return Ok(None);
    }
    let img = read_view_image(path, "image")?;
    check_size(&img, view, size, path)?;
    Ok(Some(img))
}

/// Loads one view; the flag says whether `rgba.png`'s alpha was a mask.
fn load_view(e: &Entry, i: usize, opts: &LoadOptions) -> Result<(View, bool)> {
    let rgba_path = e.dir.join("rgba.png");
    let img = read_view_image(&rgba_path, "view image")?;
    let size = e.size.unwrap_or((img.width, img.height));
    check_size(&img, i, size, &rgba_path)?;
    let stored_mask = stored_alpha_is_mask(&img);
    let image = to_rgba(img);
    let alpha = alpha_of(&image);
    let camera = blender_camera(e.c2w, Intrinsics::from_fov_x(e.fov_x, size.0, size.1), i).at(&e.source)?;
    let albedo = optional(&e.dir.join("albedo.png"), i, size)?.map(|m| to_rgba(m).select_channels(0..3));
    let normal = optional(&e.dir.join("normal.png"), i, size)?.map(|m| {
        // Prefer the normal pass's own alpha (identical to rgba.png's in our data).
        let a = if m.channels == 4 { alpha_of(&m) } else { alpha.clone() };
        decode_normals(&m, &a)
    });
    let roughness = optional(&e.dir.join("roughness.png"), i, size)?.map(|m| m.select_channels(0..1));
    let mut relit = BTreeMap::new();
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(&e.dir).at(&e.dir)?.filter_map(|d| d.ok().map(|d| d.path())).collect();
    files.sort();
    for p in files {
        let light = p.file_name().and_then(|s| s.to_str()).and_then(|n| n.strip_prefix("rgba_")?.strip_suffix(".png"));
        if let Some(light) = light {
            let m = read_view_image(&p, "relit image")?;
            check_size(&m, i, size, &p)?;
            relit.insert(light.to_string(), to_rgba(m));
        }
    }
    let name = e.dir.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    Ok((finish_view(View { name, camera, image, albedo, normal, roughness, relit }, opts, &rgba_path)?, stored_mask))
}

fn load_split(root: &Path, split: &str, opts: &LoadOptions) -> Result<Vec<(View, bool)>> {
    let entries = entries(root, split)?;
    let keep = select_views(entries.len(), opts.max_views);
    let views: Vec<Result<(View, bool)>> = keep.par_iter().map(|&i| load_view(&entries[i], i, opts)).collect();
    views.into_iter().collect()
}

fn light(root: &Path, name: &str, strength: f32, file: Option<&str>) -> LightInfo {
    let envmap_path = file.map(|f| root.join(f)).filter(|p| p.is_file());
    LightInfo { name: name.to_string(), envmap_path, strength }
}

/// Training light and relighting lights: from `scene.json`, else from a view's `metadata.json`.
fn lights(root: &Path, test: &[View]) -> Result<(Option<LightInfo>, Vec<LightInfo>)> {
    let scene_path = root.join("scene.json");
    let relit_names = || -> Vec<String> {
        let mut names: Vec<String> = test.iter().flat_map(|v| v.relit.keys().cloned()).collect();
        names.sort();
        names.dedup();
        names
    };
    if scene_path.is_file() {
        let scene = read_json(&scene_path)?;
        let maps = &scene["envmaps"];
        let get = |name: &str| -> Result<LightInfo> {
            let m = &maps[name];
            let strength = match &m["strength"] {
                Value::Null => 1.0,
                v => v.as_f64().map(|s| s as f32).filter(|s| s.is_finite() && *s >= 0.0).ok_or_else(|| {
                    ErrorKind::invalid(format!("light '{name}': strength is not a non-negative number")).at(&scene_path)
                })?,
            };
            Ok(light(root, name, strength, m["copy"].as_str()))
        };
        let train = scene["train_light"].as_str().map(get).transpose()?;
        let mut names: Vec<String> = scene["relight_lights"]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_str().map(String::from)).collect())
            .unwrap_or_default();
        if names.is_empty() {
            names = relit_names();
        }
        let relight = names.iter().map(|n| get(n)).collect::<Result<Vec<_>>>()?;
        return Ok((train, relight));
    }
    // Original TensoIR: the first view's metadata names the training light and its strength.
    let meta_path = root.join("train_000/metadata.json");
    let meta = if meta_path.is_file() { read_json(&meta_path)? } else { Value::Null };
    let strength_of = |v: &Value| v.as_f64().map(|s| s as f32).filter(|s| s.is_finite() && *s >= 0.0).unwrap_or(1.0);
    let train = meta["envmap"]
        .as_str()
        .map(|n| light(root, n, strength_of(&meta["envmap_inten"]), meta["envmap_file"].as_str()));
    let test_meta_path = root.join("test_000/metadata.json");
    let test_meta = if test_meta_path.is_file() { read_json(&test_meta_path)? } else { Value::Null };
    let relight = relit_names()
        .iter()
        .map(|n| light(root, n, strength_of(&test_meta["relight_envmap_inten"][n]), None))
        .collect();
    Ok((train, relight))
}

/// Loads a TensoIR dataset; RGBA images with transparency make [`MaskSource::Alpha`].
pub fn load(root: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let train = load_split(root, "train", opts)?;
    let test = if opts.load_test { load_split(root, "test", opts)? } else { Vec::new() };
    let masks = if train.iter().chain(&test).any(|v| v.1) { MaskSource::Alpha } else { MaskSource::None };
    let train: Vec<View> = train.into_iter().map(|v| v.0).collect();
    let test: Vec<View> = test.into_iter().map(|v| v.0).collect();
    let (train_light, relight_lights) = lights(root, &test)?;
    Ok(Dataset {
        name: dataset_name(root),
        root: root.to_path_buf(),
        train,
        test,
        points: None,
        train_light,
        relight_lights,
        camera_model: "blender".into(),
        masks,
        world_rotation: glam::Mat3::IDENTITY,
    })
}
