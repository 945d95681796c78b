//! nerfstudio / instant-ngp single-file `transforms.json`, what `ns-process-data` and phone
//! capture apps export.
//!
//! - Intrinsics `fl_x fl_y cx cy w h`, top-level or per frame (a frame's value wins). `fl_y`
//!   defaults to `fl_x`; `camera_angle_x` / `camera_angle_y` stand in for missing focal lengths;
//!   `cx`, `cy` default to the image centre, `w`, `h` to the image file's size. Views may differ
//!   in size: each keeps its own camera.
//! - `camera_model`: `PINHOLE`, `OPENCV` (`k1 k2 p1 p2`, optional `k3`), `OPENCV_FISHEYE`
//!   (`k1..k4`; instant-ngp's `is_fisheye` means the same). Absent, the distortion terms decide,
//!   as instant-ngp and nerfstudio read such files: any nonzero `k1 k2 k3 p1 p2` is OPENCV
//!   (instant-ngp's own `transforms.json` carry them with no model), none is PINHOLE. The lens maps
//!   onto COLMAP's parameter vectors and photos are undistorted on load ([`undistort_image`]).
//!   OPENCV's `k4` is nerfstudio's r^8 radial term, which COLMAP's models lack: a nonzero one is
//!   refused rather than silently dropped. Other models (`EQUIRECTANGULAR`, ...) are refused.
//! - `transform_matrix`: camera-to-world in OpenGL/Blender axes ([`svgir_core::Camera::from_blender_c2w`]).
//! - `file_path`, `mask_path`: relative to the json's folder. A mask's grey value becomes the
//!   photo's alpha before undistortion; as in nerfstudio, all frames have a mask or none does.
//! - Split: `train_filenames` and `test_filenames` (else `val_filenames`) when present, a list
//!   missing its partner meaning "all other frames"; otherwise every 8th frame (index 0, 8, ...)
//!   after sorting by `file_path` is a test view, like the COLMAP loader (`llffhold = 8`).
//! - `ply_file_path` (nerfstudio's initial point cloud) -> [`Dataset::points`]; none when absent
//!   or empty, so training falls back to its own initialisation. It is read in the frames' world
//!   frame: `ns-process-data` writes the points and the poses with the same `applied_transform`.
//! - Read and left alone, since they change no camera: `applied_transform` and `applied_scale`
//!   (what `ns-process-data` already applied to the poses and points), instant-ngp's `aabb_scale`,
//!   `scale` and `offset` (its own scene box and normalisation, applied inside instant-ngp, not
//!   to the file's poses) and per-frame `sharpness` (colmap2nerf's blur score for picking frames).
//!   Where both levels give an intrinsic or a distortion term, the frame's wins, as in instant-ngp
//!   (nerfstudio would take the top level's).

use crate::camera_model::{undistort_image, CameraModel};
use crate::error::{ErrorKind, Result, WithPath};
use crate::load::{check_size, finish_view, read_json, read_view_image, select_views, LoadOptions};
use crate::mask::{apply_mask, stored_alpha_is_mask};
use crate::nerf::{blender_camera, dataset_name, parse_matrix, resolve_image_path};
use glam::Mat4;
use rayon::prelude::*;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use svgir_core::{Dataset, Intrinsics, MaskSource, View};

/// The lens models this loader undistorts, by their nerfstudio names.
const SUPPORTED: &str = "PINHOLE, OPENCV, OPENCV_FISHEYE";

/// The distortion terms instant-ngp and nerfstudio read, with or without a `camera_model`.
const DISTORTION_KEYS: [&str; 6] = ["k1", "k2", "k3", "k4", "p1", "p2"];

/// One frame's lens as the json states it; focal lengths from angles and the default principal
/// point need the image size, so they are resolved in [`Lens::params`].
#[derive(Clone, Debug, PartialEq)]
pub struct Lens {
    /// The json's `camera_model` (upper case), for reporting.
    pub model_name: String,
    /// The COLMAP model the distortion maps onto (`Pinhole` when there is none).
    pub model: CameraModel,
    /// Distortion coefficients in `model`'s COLMAP order (after fx, fy, cx, cy).
    pub distortion: Vec<f64>,
    /// `fl_x`: horizontal focal length in pixels.
    pub fl_x: Option<f64>,
    /// `fl_y`: vertical focal length in pixels.
    pub fl_y: Option<f64>,
    /// `camera_angle_x`: horizontal field of view in radians.
    pub angle_x: Option<f64>,
    /// `camera_angle_y`: vertical field of view in radians.
    pub angle_y: Option<f64>,
    /// `cx`: principal point x in pixels (default: image centre).
    pub cx: Option<f64>,
    /// `cy`: principal point y in pixels (default: image centre).
    pub cy: Option<f64>,
    /// `w`: image width in pixels, if stated.
    pub w: Option<u32>,
    /// `h`: image height in pixels, if stated.
    pub h: Option<u32>,
}

impl Lens {
    /// COLMAP parameter vector (fx, fy, cx, cy, distortion...) for a `w` x `h` image.
    pub fn params(&self, w: u32, h: u32) -> Option<Vec<f64>> {
        let from_angle = |a: f64, side: u32| 0.5 * side as f64 / (0.5 * a).tan();
        let fx0 = self.fl_x.or_else(|| self.angle_x.map(|a| from_angle(a, w)));
        let fy0 = self.fl_y.or_else(|| self.angle_y.map(|a| from_angle(a, h)));
        let (fx, fy) = (fx0.or(fy0)?, fy0.or(fx0)?);
        let (cx, cy) = (self.cx.unwrap_or(0.5 * w as f64), self.cy.unwrap_or(0.5 * h as f64));
        Some([fx, fy, cx, cy].into_iter().chain(self.distortion.iter().copied()).collect())
    }
}

/// One frame of the file.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Position in the file's `frames` list (what error messages count).
    pub index: usize,
    /// `file_path` as written (frames are sorted by the path it resolves to).
    pub file_path: String,
    /// Image file, resolved against the json's folder.
    pub image_path: PathBuf,
    /// Mask file from the frame's `mask_path`, if any.
    pub mask_path: Option<PathBuf>,
    /// `transform_matrix`: camera-to-world in OpenGL/Blender axes.
    pub c2w: Mat4,
    /// The frame's lens (its own values over the top-level ones).
    pub lens: Lens,
}

/// A parsed `transforms.json`: frames sorted by `file_path`, and the split.
#[derive(Clone, Debug)]
pub struct Capture {
    /// All frames, sorted by `file_path`.
    pub frames: Vec<Frame>,
    /// Indices into `frames`.
    pub train: Vec<usize>,
    /// Indices into `frames` of the test views.
    pub test: Vec<usize>,
    /// Sparse point cloud from `ply_file_path`, resolved against the json's folder.
    pub ply_path: Option<PathBuf>,
}

/// Top-level values with a frame's own ones taking precedence.
struct Src<'a> {
    frame: &'a Value,
    top: &'a Value,
}

impl Src<'_> {
    fn get(&self, key: &str) -> Option<&Value> {
        self.frame.get(key).or_else(|| self.top.get(key))
    }

    /// A present key must hold a finite number (`null` is what a Python `NaN` became).
    fn num(&self, key: &str) -> std::result::Result<Option<f64>, String> {
        match self.get(key) {
            None => Ok(None),
            Some(v) => v.as_f64().filter(|x| x.is_finite()).map(Some).ok_or(format!("{key} is not a finite number")),
        }
    }

    fn positive(&self, key: &str) -> std::result::Result<Option<f64>, String> {
        match self.num(key)? {
            Some(x) if x <= 0.0 => Err(format!("{key} = {x} is not positive")),
            x => Ok(x),
        }
    }

    fn angle(&self, key: &str) -> std::result::Result<Option<f64>, String> {
        match self.num(key)? {
            Some(a) if !(a > 0.0 && a < std::f64::consts::PI) => Err(format!("{key} = {a} is not an angle in (0, pi)")),
            a => Ok(a),
        }
    }

    /// An image side: a whole number of pixels (`1920.0` is fine), within the image limits.
    fn side(&self, key: &str) -> std::result::Result<Option<u32>, String> {
        match self.num(key)? {
            None => Ok(None),
            Some(x) if x.fract() == 0.0 && x >= 1.0 && x <= crate::image_io::MAX_IMAGE_SIDE as f64 => {
                Ok(Some(x as u32))
            }
            Some(x) => Err(format!("{key} = {x} is not a plausible image size")),
        }
    }
}

/// The lens model's name, its COLMAP counterpart and distortion; an error for models this
/// loader does not handle.
fn lens_model(src: &Src) -> std::result::Result<(String, CameraModel, Vec<f64>), String> {
    let fisheye = src.get("is_fisheye").and_then(Value::as_bool) == Some(true);
    let k = |key: &str| src.num(key).map(|v| v.unwrap_or(0.0));
    let mut implied = false;
    let name = match src.get("camera_model") {
        None | Some(Value::Null) if fisheye => "OPENCV_FISHEYE".to_string(),
        None | Some(Value::Null) => {
            // instant-ngp's own files and nerfstudio both undistort with the terms they find
            // when no model is named (nerfstudio's PERSPECTIVE camera applies k1..k4, p1, p2).
            let mut terms = Vec::new();
            for key in DISTORTION_KEYS {
                terms.push(k(key)?);
            }
            implied = terms.iter().any(|&c| c != 0.0);
            if implied { "OPENCV" } else { "PINHOLE" }.to_string()
        }
        Some(Value::String(s)) => s.to_ascii_uppercase(),
        Some(v) => return Err(format!("camera_model {v} is not a name")),
    };
    let (model, dist) = match name.as_str() {
        "PINHOLE" | "SIMPLE_PINHOLE" => (CameraModel::Pinhole, vec![]),
        "OPENCV" => {
            let (k1, k2, p1, p2, k3, k4) = (k("k1")?, k("k2")?, k("p1")?, k("p2")?, k("k3")?, k("k4")?);
            if k4 != 0.0 {
                return Err(format!("OPENCV k4 = {k4} (an r^8 radial term) is not supported; only k1, k2, k3, p1, p2"));
            }
            if [k1, k2, p1, p2, k3].iter().all(|&c| c == 0.0) {
                // ns-process-data writes undistorted cameras as OPENCV with zeros: skip the resampling.
                (CameraModel::Pinhole, vec![])
            } else if k3 != 0.0 {
                // FULL_OPENCV's numerator is nerfstudio's k1..k3 polynomial; its denominator stays 1.
                (CameraModel::FullOpenCv, vec![k1, k2, p1, p2, k3, 0.0, 0.0, 0.0])
            } else {
                (CameraModel::OpenCv, vec![k1, k2, p1, p2])
            }
        }
        "OPENCV_FISHEYE" => (CameraModel::OpenCvFisheye, vec![k("k1")?, k("k2")?, k("k3")?, k("k4")?]),
        _ => return Err(format!("unsupported camera_model {name} (supported: {SUPPORTED})")),
    };
    let name = if implied { format!("{name} (distortion terms without a camera_model)") } else { name };
    Ok((name, model, dist))
}

fn parse_lens(src: &Src) -> std::result::Result<Lens, String> {
    let (model_name, model, distortion) = lens_model(src)?;
    let lens = Lens {
        model_name,
        model,
        distortion,
        fl_x: src.positive("fl_x")?,
        fl_y: src.positive("fl_y")?,
        angle_x: src.angle("camera_angle_x")?,
        angle_y: src.angle("camera_angle_y")?,
        cx: src.num("cx")?,
        cy: src.num("cy")?,
        w: src.side("w")?,
        h: src.side("h")?,
    };
    if [lens.fl_x, lens.fl_y, lens.angle_x, lens.angle_y].iter().all(Option::is_none) {
        return Err("no focal length (fl_x or camera_angle_x)".into());
    }
    Ok(lens)
}

fn frame_path(f: &Value, key: &str) -> std::result::Result<Option<String>, String> {
    match f.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::String(s)) => Ok(Some(s.clone())),
        Some(_) => Err(format!("{key} is not a string")),
    }
}

/// A path made comparable: `./` and repeated separators normalised away.
fn norm(p: &Path) -> PathBuf {
    p.components().collect()
}

/// Frames named by the split list `key`, if the file has one.
fn split_list(
    json: &Value,
    key: &str,
    frames: &[Frame],
    dir: &Path,
) -> std::result::Result<Option<Vec<bool>>, ErrorKind> {
    let Some(list) = json.get(key).filter(|v| !v.is_null()) else { return Ok(None) };
    let list = list.as_array().ok_or_else(|| ErrorKind::invalid(format!("{key} is not a list")))?;
    let index: BTreeMap<PathBuf, usize> = frames.iter().enumerate().map(|(i, f)| (norm(&f.image_path), i)).collect();
    let mut member = vec![false; frames.len()];
    for name in list {
        let name = name.as_str().ok_or_else(|| ErrorKind::invalid(format!("{key}: {name} is not a file name")))?;
        let i = index
            .get(&norm(&resolve_image_path(dir, name)))
            .ok_or_else(|| ErrorKind::invalid(format!("{key}: {name} is not the file_path of any frame")))?;
        member[*i] = true;
    }
    Ok(Some(member))
}

/// Parses a `transforms.json` whose relative paths start at `dir` (no file is read).
pub fn parse_capture(json: &Value, dir: &Path) -> std::result::Result<Capture, ErrorKind> {
    if !json.is_object() {
        return Err(ErrorKind::invalid("not a JSON object"));
    }
    // A bad top-level model is reported once, not as a problem of camera 0.
    if json.get("camera_model").is_some() {
        lens_model(&Src { frame: &Value::Null, top: json }).map_err(ErrorKind::Invalid)?;
    }
    let list = json.get("frames").and_then(Value::as_array).ok_or_else(|| ErrorKind::Missing("frames list".into()))?;
    let mut frames = list
        .iter()
        .enumerate()
        .map(|(index, f)| {
            let cam_err = |problem: String| ErrorKind::Camera { index, problem };
            if !f.is_object() {
                return Err(cam_err("frame is not an object".into()));
            }
            let file_path =
                frame_path(f, "file_path").map_err(cam_err)?.ok_or_else(|| cam_err("no file_path".into()))?;
            let mask_path = frame_path(f, "mask_path").map_err(cam_err)?.map(|m| resolve_image_path(dir, &m));
            let c2w = f.get("transform_matrix").ok_or_else(|| cam_err("no transform_matrix".into()))?;
            let c2w = parse_matrix(c2w).map_err(|p| cam_err(format!("{p} in transform_matrix")))?;
            let lens = parse_lens(&Src { frame: f, top: json }).map_err(cam_err)?;
            // A placeholder size is enough to reject non-rigid or NaN matrices before any image is read.
            blender_camera(c2w, Intrinsics::from_fov_x(1.0, 1, 1), index)?;
            let image_path = resolve_image_path(dir, &file_path);
            Ok(Frame { index, file_path, image_path, mask_path, c2w, lens })
        })
        .collect::<std::result::Result<Vec<_>, ErrorKind>>()?;
    if frames.is_empty() {
        return Err(ErrorKind::invalid("frames list is empty"));
    }
    if let (Some(with), Some(without)) =
        (frames.iter().find(|f| f.mask_path.is_some()), frames.iter().find(|f| f.mask_path.is_none()))
    {
        return Err(ErrorKind::invalid(format!(
            "frame {} ({}) has a mask_path but frame {} ({}) has none; give every frame a mask or none",
            with.index, with.file_path, without.index, without.file_path
        )));
    }
    // By resolved path, as nerfstudio sorts, so "./images/a.png" and "images/b.png" interleave.
    frames.sort_by_cached_key(|f| norm(&f.image_path));
    let train_set = split_list(json, "train_filenames", &frames, dir)?;
    let test_set = match split_list(json, "test_filenames", &frames, dir)? {
        Some(t) => Some(t),
        None => split_list(json, "val_filenames", &frames, dir)?,
    };
    let n = frames.len();
    let (train, test): (Vec<usize>, Vec<usize>) = match (train_set, test_set) {
        (None, None) => ((0..n).filter(|i| i % 8 != 0).collect(), (0..n).filter(|i| i % 8 == 0).collect()),
        (Some(tr), None) => (0..n).partition(|&i| tr[i]),
        (None, Some(te)) => {
            let (te, tr) = (0..n).partition(|&i| te[i]);
            (tr, te)
        }
        (Some(tr), Some(te)) => ((0..n).filter(|&i| tr[i]).collect(), (0..n).filter(|&i| te[i]).collect()),
    };
    let ply_path = match json.get("ply_file_path") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(dir.join(s.strip_prefix("./").unwrap_or(s))),
        Some(_) => return Err(ErrorKind::invalid("ply_file_path is not a string")),
    };
    Ok(Capture { frames, train, test, ply_path })
}

/// The json file and its folder for a dataset path that is either.
pub fn json_and_dir(path: &Path) -> (PathBuf, PathBuf) {
    if path.is_file() {
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        (path.to_path_buf(), dir.to_path_buf())
    } else {
        (path.join("transforms.json"), path.to_path_buf())
    }
}

/// Loads one frame; the flag says whether the image file's own alpha was a mask.
fn load_view(f: &Frame, json_path: &Path, opts: &LoadOptions) -> Result<(View, bool)> {
    let photo = read_view_image(&f.image_path, "view image")?;
    let want = (f.lens.w.unwrap_or(photo.width), f.lens.h.unwrap_or(photo.height));
    check_size(&photo, f.index, want, &f.image_path)?;
    let stored_mask = stored_alpha_is_mask(&photo);
    let photo = match &f.mask_path {
        Some(m) => apply_mask(photo, &f.image_path, m)?,
        None => crate::image_io::to_rgba(photo),
    };
    let cam_err = |problem: &str| ErrorKind::Camera { index: f.index, problem: problem.into() }.at(json_path);
    let params = f.lens.params(want.0, want.1).ok_or_else(|| cam_err("no focal length"))?;
    let [fx, fy, cx, cy] = f.lens.model.pinhole(&params).ok_or_else(|| cam_err("wrong lens parameter count"))?;
    let k = Intrinsics { fx: fx as f32, fy: fy as f32, cx: cx as f32, cy: cy as f32, width: want.0, height: want.1 };
    let camera = blender_camera(f.c2w, k, f.index).at(json_path)?;
    let image = if f.lens.model.is_pinhole() { photo } else { undistort_image(&photo, f.lens.model, &params) };
    let name = f.image_path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let v = View { name, camera, image, albedo: None, normal: None, roughness: None, relit: BTreeMap::new() };
    Ok((finish_view(v, opts, &f.image_path)?, stored_mask))
}

/// Loads a `transforms.json` dataset; `path` is its folder or the json file itself.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let (json_path, dir) = json_and_dir(path);
    let json = read_json(&json_path)?;
    let mut cap = parse_capture(&json, &dir).at(&json_path)?;
    // A masks folder given on load replaces the frames' own mask paths.
    if let Some(masks) = &opts.masks {
        for f in &mut cap.frames {
            let name = f.image_path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            f.mask_path = Some(crate::mask::find_colmap_mask(masks, &name)?);
        }
    }
    let load_split = |idx: &[usize]| -> Result<Vec<(View, bool)>> {
        let keep = select_views(idx.len(), opts.max_views);
        let views: Vec<Result<(View, bool)>> =
            keep.par_iter().map(|&k| load_view(&cap.frames[idx[k]], &json_path, opts)).collect();
        views.into_iter().collect()
    };
    let train = load_split(&cap.train)?;
    let test = if opts.load_test { load_split(&cap.test)? } else { Vec::new() };
    let masks = if let Some(m) = &opts.masks {
        MaskSource::Folder(m.clone())
    } else if cap.frames.iter().any(|f| f.mask_path.is_some()) {
        MaskSource::PerFrame
    } else if train.iter().chain(&test).any(|v| v.1) {
        MaskSource::Alpha
    } else {
        MaskSource::None
    };
    let points = match &cap.ply_path {
        Some(p) => Some(crate::ply::read_points_ply(p)?).filter(|pc| !pc.positions.is_empty()),
        None => None,
    };
    let models: BTreeSet<&str> = cap.frames.iter().map(|f| f.lens.model_name.as_str()).collect();
    Ok(Dataset {
        name: dataset_name(&dir),
        // The path as given, so the layout can be recognised again (e.g. by `svgir info`).
        root: path.to_path_buf(),
        train: train.into_iter().map(|v| v.0).collect(),
        test: test.into_iter().map(|v| v.0).collect(),
        points,
        train_light: None,
        relight_lights: Vec::new(),
        camera_model: models.into_iter().collect::<Vec<_>>().join("+"),
        masks,
        world_rotation: glam::Mat3::IDENTITY,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    const M: [[f64; 4]; 4] = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]];

    fn frames(n: usize) -> Vec<Value> {
        (0..n).map(|i| json!({"file_path": format!("images/f{i:02}.png"), "transform_matrix": M})).collect()
    }

    #[test]
    fn intrinsics_resolve_with_fallbacks() {
        let mut j = json!({"fl_x": 100.0, "w": 64, "h": 48, "frames": frames(2)});
        j["frames"][1]["fl_y"] = json!(120.0);
        j["frames"][1]["cx"] = json!(30.0);
        let cap = parse_capture(&j, Path::new("/d")).unwrap();
        assert_eq!(cap.frames[0].lens.params(64, 48).unwrap(), vec![100.0, 100.0, 32.0, 24.0]);
        assert_eq!(cap.frames[1].lens.params(64, 48).unwrap(), vec![100.0, 120.0, 30.0, 24.0]);
        let j = json!({"camera_angle_x": std::f64::consts::FRAC_PI_2, "frames": frames(1)});
        let p = parse_capture(&j, Path::new("/d")).unwrap().frames[0].lens.params(64, 48).unwrap();
        assert!((p[0] - 32.0).abs() < 1e-9 && (p[1] - 32.0).abs() < 1e-9);
    }

    #[test]
    fn lens_models_map_onto_colmap() {
        let lens = |extra: Value| {
            let mut j = json!({"fl_x": 100.0, "frames": frames(1)});
            for (k, v) in extra.as_object().unwrap() {
                j[k] = v.clone();
            }
            parse_capture(&j, Path::new("/d")).map(|c| c.frames[0].lens.clone())
        };
        let l = lens(json!({"camera_model": "OPENCV", "k1": -0.1, "p2": 0.01})).unwrap();
        assert_eq!((l.model, l.distortion), (CameraModel::OpenCv, vec![-0.1, 0.0, 0.0, 0.01]));
        let l = lens(json!({"camera_model": "OPENCV", "k1": 0.0})).unwrap();
        assert_eq!(l.model, CameraModel::Pinhole);
        let l = lens(json!({"camera_model": "OPENCV", "k1": 0.1, "k3": 0.02})).unwrap();
        assert_eq!(l.model, CameraModel::FullOpenCv);
        assert_eq!(l.params(10, 10).unwrap().len(), 12);
        let l = lens(json!({"is_fisheye": true, "k1": 0.05})).unwrap();
        assert_eq!((l.model, l.model_name.as_str()), (CameraModel::OpenCvFisheye, "OPENCV_FISHEYE"));
        let e = lens(json!({"camera_model": "EQUIRECTANGULAR"})).unwrap_err().to_string();
        assert_eq!(e, "unsupported camera_model EQUIRECTANGULAR (supported: PINHOLE, OPENCV, OPENCV_FISHEYE)");
        assert!(lens(json!({"camera_model": "OPENCV", "k4": 0.1})).unwrap_err().to_string().contains("k4"));
    }

    /// What instant-ngp and nerfstudio do with a file that names no model, or keys that are
    /// not about the camera.
    #[test]
    fn implicit_conventions_of_instant_ngp_and_nerfstudio() {
        let capture = |extra: Value, frame: Value| {
            let mut j = json!({"fl_x": 100.0, "w": 64, "h": 48, "frames": frames(2)});
            for (k, v) in extra.as_object().unwrap() {
                j[k] = v.clone();
            }
            for (k, v) in frame.as_object().unwrap() {
                j["frames"][1][k] = v.clone();
            }
            parse_capture(&j, Path::new("/d"))
        };
        let none = json!({});
        // Distortion terms without camera_model: OPENCV; with k3, the k1..k3 polynomial.
        let c = capture(json!({"k1": -0.1, "p1": 0.001}), none.clone()).unwrap();
        let l = &c.frames[0].lens;
        assert_eq!((l.model, l.distortion.clone()), (CameraModel::OpenCv, vec![-0.1, 0.0, 0.001, 0.0]));
        assert_eq!(l.model_name, "OPENCV (distortion terms without a camera_model)");
        let c = capture(json!({"k1": 0.1, "k3": 0.01}), none.clone()).unwrap();
        assert_eq!(c.frames[0].lens.model, CameraModel::FullOpenCv);
        // All zero, or none: a pinhole; k4 without a fisheye is refused, not dropped.
        let c = capture(json!({"k1": 0.0, "k2": 0.0}), none.clone()).unwrap();
        assert_eq!((c.frames[0].lens.model, c.frames[0].lens.model_name.as_str()), (CameraModel::Pinhole, "PINHOLE"));
        assert!(capture(json!({"k4": 0.1}), none.clone()).unwrap_err().to_string().contains("k4"));
        // Per-frame terms (and w, h, fl_x) apply to their frame only.
        let c = capture(none.clone(), json!({"k2": 0.05, "w": 80, "h": 60, "fl_x": 90.0})).unwrap();
        let (l0, l1) = (&c.frames[0].lens, &c.frames[1].lens);
        assert_eq!((l0.model, l1.model), (CameraModel::Pinhole, CameraModel::OpenCv));
        assert_eq!((l0.w, l0.h, l1.w, l1.h), (Some(64), Some(48), Some(80), Some(60)));
        assert_eq!(l1.params(80, 60).unwrap()[..2], [90.0, 90.0]);
        // is_fisheye (instant-ngp) is OPENCV_FISHEYE.
        let c = capture(json!({"is_fisheye": true, "k1": 0.05, "k4": 0.001}), none.clone()).unwrap();
        assert_eq!(c.frames[0].lens.distortion, vec![0.05, 0.0, 0.0, 0.001]);
        // Keys that change no camera leave every frame as it was.
        let plain = capture(none.clone(), none.clone()).unwrap();
        let other = capture(
            json!({"aabb_scale": 16, "scale": 0.33, "offset": [0.5, 0.5, 0.5], "applied_scale": 0.2,
                   "applied_transform": [[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]]}),
            json!({"sharpness": 812.5}),
        )
        .unwrap();
        for (a, b) in plain.frames.iter().zip(&other.frames) {
            assert_eq!((&a.lens, a.c2w), (&b.lens, b.c2w));
        }
        // ply_file_path resolves against the json's folder, "./" or not.
        let c = capture(json!({"ply_file_path": "./sparse_pc.ply"}), none).unwrap();
        assert_eq!(c.ply_path, Some(PathBuf::from("/d/sparse_pc.ply")));
    }

    #[test]
    fn splits_from_lists_or_every_eighth() {
        let j = json!({"fl_x": 10.0, "frames": frames(17)});
        let cap = parse_capture(&j, Path::new("/d")).unwrap();
        assert_eq!(cap.test, vec![0, 8, 16]);
        assert_eq!(cap.train.len(), 14);
        let mut fr = frames(4);
        fr.reverse();
        let j = json!({"fl_x": 10.0, "frames": fr, "train_filenames": ["images/f00.png", "./images/f02.png"],
            "val_filenames": ["images/f03.png"]});
        let cap = parse_capture(&j, Path::new("/d")).unwrap();
        assert_eq!(cap.frames[0].file_path, "images/f00.png");
        assert_eq!((cap.train.clone(), cap.test.clone()), (vec![0, 2], vec![3]));
        let j = json!({"fl_x": 10.0, "frames": frames(2), "test_filenames": ["images/nope.png"]});
        let e = parse_capture(&j, Path::new("/d")).unwrap_err().to_string();
        assert_eq!(e, "test_filenames: images/nope.png is not the file_path of any frame");
    }
}
