//! NeRF/Blender layout: `transforms_{train,test}.json` with `camera_angle_x` and per-frame
//! `file_path` (extension optional, `.png` assumed) and camera-to-world `transform_matrix`
//! (row-major, Blender camera axes), converted with [`Camera::from_blender_c2w`] (SPEC 8).
//! Images are loaded in parallel (rayon), one task per view.
//!
//! Test-view normals (`r_N_normal_0001.png` in nerf_synthetic) are *not* loaded: see
//! `tests/nerf_normals.rs` for the check that showed they are not the `(n + 1) / 2` world-space
//! encoding the [`svgir_core::dataset`] contract needs.

use crate::error::{ErrorKind, Result, WithPath};
use crate::load::{check_size, finish_view, read_json, read_view_image, select_views, LoadOptions};
use crate::mask::stored_alpha_is_mask;
use glam::Mat4;
use rayon::prelude::*;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use svgir_core::{Camera, Dataset, Intrinsics, MaskSource, View};

/// One frame of a transforms file.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Image file (resolved against the dataset root, `.png` added when the extension is absent).
    pub image_path: PathBuf,
    /// Camera-to-world matrix in Blender axes (x right, y up, looking along -z).
    pub c2w: Mat4,
}

/// A parsed `transforms_*.json`.
#[derive(Clone, Debug)]
pub struct Transforms {
    /// Horizontal field of view in radians.
    pub camera_angle_x: f32,
    /// Image size if the file states it (`w`, `h`).
    pub size: Option<(u32, u32)>,
    /// The frames in file order.
    pub frames: Vec<Frame>,
}

/// Reads a number that must be finite; `null` (from a Python `NaN`) counts as NaN.
fn finite(v: &Value) -> Option<f32> {
    v.as_f64().map(|x| x as f32).filter(|x| x.is_finite())
}

/// A row-major 4x4 from nested arrays (NeRF) or a flat list of 16 numbers / a comma-separated
/// string of 16 numbers (TensoIR's `cam_transform_mat`).
pub fn parse_matrix(v: &Value) -> std::result::Result<Mat4, String> {
    let nums: Vec<&Value> = match v {
        Value::Array(rows) if rows.iter().all(|r| r.is_array()) => {
            if rows.len() != 4 && rows.len() != 3 {
                return Err(format!("has {} rows, expected 4", rows.len()));
            }
            let mut n = Vec::new();
            for r in rows {
                let r = r.as_array().ok_or("row is not an array")?;
                if r.len() != 4 {
                    return Err(format!("a row has {} entries, expected 4", r.len()));
                }
                n.extend(r.iter());
            }
            n
        }
        Value::Array(flat) => flat.iter().collect(),
        Value::String(s) => {
            let parsed: Vec<Value> = s
                .split(',')
                .map(|t| t.trim().parse::<f64>().map(Value::from))
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| "is not a list of numbers".to_string())?;
            return parse_matrix(&Value::Array(parsed));
        }
        _ => return Err("is not an array".into()),
    };
    if nums.len() != 16 && nums.len() != 12 {
        return Err(format!("has {} numbers, expected 16", nums.len()));
    }
    let mut m = [0.0f32; 16];
    for (i, v) in nums.iter().enumerate() {
        m[i] = match v.as_f64() {
            Some(x) if x.is_finite() && (x as f32).is_finite() => x as f32,
            _ => return Err("NaN".into()),
        };
    }
    if nums.len() == 12 {
        m[12..].copy_from_slice(&[0.0, 0.0, 0.0, 1.0]);
    }
    // Row-major in the file; glam is column-major.
    Ok(Mat4::from_cols_array(&m).transpose())
}

/// The frame's image path: relative to `root`, `.png` appended when there is no extension.
pub fn resolve_image_path(root: &Path, file_path: &str) -> PathBuf {
    let rel = file_path.strip_prefix("./").unwrap_or(file_path);
    let mut p = root.join(rel);
    if p.extension().is_none() {
        p.set_extension("png");
    }
    p
}

/// Reads `transforms_<split>.json` of a NeRF-style dataset.
pub fn read_transforms(root: &Path, split: &str) -> Result<Transforms> {
    let path = root.join(format!("transforms_{split}.json"));
    let json = read_json(&path).map_err(|e| match e.kind {
        ErrorKind::NotFound => ErrorKind::Missing(format!("transforms_{split}.json")).at(&path),
        _ => e,
    })?;
    parse_transforms(&json, root).at(&path)
}

fn parse_transforms(json: &Value, root: &Path) -> std::result::Result<Transforms, ErrorKind> {
    let camera_angle_x = finite(&json["camera_angle_x"])
        .filter(|a| *a > 0.0 && *a < std::f32::consts::PI)
        .ok_or_else(|| ErrorKind::invalid("camera_angle_x is missing or not an angle in (0, pi)"))?;
    let size = match (json["w"].as_u64(), json["h"].as_u64()) {
        (Some(w), Some(h)) if w > 0 && h > 0 && w <= u32::MAX as u64 && h <= u32::MAX as u64 => {
            Some((w as u32, h as u32))
        }
        _ => None,
    };
    let frames = json["frames"].as_array().ok_or_else(|| ErrorKind::Missing("frames list".into()))?;
    let frames = frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let cam_err = |problem: String| ErrorKind::Camera { index: i, problem };
            let file_path = f["file_path"].as_str().ok_or_else(|| cam_err("no file_path".into()))?;
            let c2w = parse_matrix(&f["transform_matrix"]).map_err(|p| cam_err(format!("{p} in transform_matrix")))?;
            Ok(Frame { image_path: resolve_image_path(root, file_path), c2w })
        })
        .collect::<std::result::Result<Vec<_>, ErrorKind>>()?;
    Ok(Transforms { camera_angle_x, size, frames })
}

/// A camera from a Blender c2w, with frame index `i` in the error.
pub fn blender_camera(c2w: Mat4, k: Intrinsics, i: usize) -> std::result::Result<Camera, ErrorKind> {
    Camera::from_blender_c2w(c2w, k).map_err(|e| ErrorKind::Camera { index: i, problem: format!("{e}") })
}

/// Loads one split; each flag says whether that image file's alpha was a mask.
fn load_split(root: &Path, split: &str, opts: &LoadOptions) -> Result<Vec<(View, bool)>> {
    let tf = read_transforms(root, split)?;
    let json_path = root.join(format!("transforms_{split}.json"));
    // Validate all cameras first (cheap) so a bad matrix is reported before any image is read.
    let k0 = Intrinsics::from_fov_x(tf.camera_angle_x, 1, 1);
    for (i, f) in tf.frames.iter().enumerate() {
        blender_camera(f.c2w, k0, i).at(&json_path)?;
    }
    let keep = select_views(tf.frames.len(), opts.max_views);
    let views: Vec<Result<(View, bool)>> = keep
        .par_iter()
        .map(|&i| {
            let f = &tf.frames[i];
            let img = read_view_image(&f.image_path, "view image")?;
            let want = tf.size.unwrap_or((img.width, img.height));
            check_size(&img, i, want, &f.image_path)?;
            let stored_mask = stored_alpha_is_mask(&img);
            let image = crate::image_io::to_rgba(img);
            let k = Intrinsics::from_fov_x(tf.camera_angle_x, image.width, image.height);
            let camera = blender_camera(f.c2w, k, i).at(&json_path)?;
            let name = f.image_path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            let v = View { name, camera, image, albedo: None, normal: None, roughness: None, relit: BTreeMap::new() };
            Ok((finish_view(v, opts, &f.image_path)?, stored_mask))
        })
        .collect();
    let views = views.into_iter().collect::<Result<Vec<_>>>()?;
    // Without w/h in the file, all images must still agree with the first one.
    if let Some((first, _)) = views.first() {
        let want = (first.image.width, first.image.height);
        for ((v, _), &i) in views.iter().zip(&keep) {
            check_size(&v.image, i, want, &tf.frames[i].image_path)?;
        }
    }
    Ok(views)
}

/// Loads a NeRF/Blender dataset; RGBA images with transparency make [`MaskSource::Alpha`].
pub fn load(root: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let train = load_split(root, "train", opts)?;
    let test = if opts.load_test && root.join("transforms_test.json").is_file() {
        load_split(root, "test", opts)?
    } else {
        Vec::new()
    };
    let masks = if train.iter().chain(&test).any(|v| v.1) { MaskSource::Alpha } else { MaskSource::None };
    Ok(Dataset {
        name: dataset_name(root),
        root: root.to_path_buf(),
        train: train.into_iter().map(|v| v.0).collect(),
        test: test.into_iter().map(|v| v.0).collect(),
        points: None,
        train_light: None,
        relight_lights: Vec::new(),
        camera_model: "blender".into(),
        masks,
        world_rotation: glam::Mat3::IDENTITY,
    })
}

/// The folder name, used as the dataset name.
pub fn dataset_name(root: &Path) -> String {
    let canon = root.canonicalize().unwrap_or_else(|_| root.to_path_buf());
    canon.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "dataset".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matrices_parse_row_major_and_reject_nan() {
        let rows = serde_json::json!([[1, 0, 0, 5], [0, 1, 0, 6], [0, 0, 1, 7], [0, 0, 0, 1]]);
        let m = parse_matrix(&rows).unwrap();
        assert_eq!(m.w_axis.truncate(), glam::Vec3::new(5.0, 6.0, 7.0));
        let s = Value::String("1,0,0,5,0,1,0,6,0,0,1,7,0,0,0,1".into());
        assert_eq!(parse_matrix(&s).unwrap(), m);
        let bad = serde_json::json!([[1, 0, 0, null], [0, 1, 0, 6], [0, 0, 1, 7], [0, 0, 0, 1]]);
        assert_eq!(parse_matrix(&bad).unwrap_err(), "NaN");
        assert_eq!(resolve_image_path(Path::new("/d"), "./train/r_0"), PathBuf::from("/d/train/r_0.png"));
    }
}
