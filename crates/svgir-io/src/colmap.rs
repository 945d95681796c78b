//! COLMAP binary models (`cameras.bin`, `images.bin`, `points3D.bin`) and the COLMAP dataset
//! layout: `sparse/` (or `sparse/0/`) plus the photos in `images/`.
//!
//! Parsers work on byte slices, check every count against the bytes left before allocating,
//! and report truncation and unknown camera models as errors (fuzzed in `tests/fuzz.rs`).
//! Loading: images sorted by name; **every 8th image (index 0, 8, 16, ...) is a test view**, the
//! Mip-NeRF 360 / 3DGS `llffhold = 8` convention. Distorted cameras are undistorted on load
//! into pinhole images with the same fx, fy, cx, cy ([`undistort_image`]); each image keeps its
//! own camera's size. Photos in `images/` that the model does not register are ignored.
//!
//! Masks: with a `masks/` folder, every photo `images/NAME.EXT` takes its alpha from
//! `masks/NAME.{png,jpg,jpeg}` or COLMAP's `masks/NAME.EXT.png` ([`find_colmap_mask`]); a
//! missing or wrongly sized mask is an error. Without one, a photo's own alpha channel is kept
//! (a mask if it is below 1 somewhere), else alpha is 1 except where undistortion looks
//! outside the photo. Masks are applied before undistortion so they warp with the photo.
//!
//! Sparse points become [`Dataset::points`] with colours / 255; a model without `points3D.bin`
//! or with zero points gives `None`, so training falls back to its own initialisation instead
//! of starting from no surfels at all.

use crate::camera_model::{undistort_image, CameraModel};
use crate::error::{read_bytes, ErrorKind, Result, WithPath};
use crate::image_io::to_rgba;
use crate::load::{check_size, finish_view, read_view_image, select_views, LoadOptions};
use crate::mask::{apply_mask, find_colmap_mask, stored_alpha_is_mask};
use crate::nerf::dataset_name;
use glam::{DMat3, DQuat, Vec3};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use svgir_core::{Camera, Dataset, Intrinsics, MaskSource, PointCloud, View};

/// One camera of `cameras.bin` / `cameras.txt`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// COLMAP camera id (images refer to it).
    pub id: u32,
    /// Lens model, which fixes the layout of `params`.
    pub model: CameraModel,
    /// Photo width in pixels.
    pub width: u32,
    /// Photo height in pixels.
    pub height: u32,
    /// Model parameters in COLMAP order (focal lengths and principal point in pixels, then distortion).
    pub params: Vec<f64>,
}

/// One registered photo of `images.bin` / `images.txt`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// COLMAP image id (point tracks refer to it).
    pub id: u32,
    /// World-to-camera rotation quaternion (w, x, y, z).
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// Id of the [`ColmapCamera`] that took it.
    pub camera_id: u32,
    /// Photo file name relative to the images folder.
    pub name: String,
    /// Keypoints (x, y) in pixels of the *distorted* photo.
    pub xys: Vec<[f64; 2]>,
    /// 3D point id of each keypoint, `None` if unmatched.
    pub point3d_ids: Vec<Option<u64>>,
}

/// One sparse point of `points3D.bin` / `points3D.txt`.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    /// COLMAP point id (keypoints refer to it).
    pub id: u64,
    /// Position in COLMAP's world frame.
    pub xyz: [f64; 3],
    /// sRGB colour, 0-255.
    pub rgb: [u8; 3],
    /// Mean reprojection error in pixels.
    pub error: f64,
    /// (image id, keypoint index) observations.
    pub track: Vec<(u32, u32)>,
}

/// A whole sparse model.
#[derive(Clone, Debug, Default)]
pub struct ColmapModel {
    /// Cameras by id.
    pub cameras: BTreeMap<u32, ColmapCamera>,
    /// Registered photos, in file order.
    pub images: Vec<ColmapImage>,
    /// Sparse points, in file order.
    pub points: Vec<ColmapPoint>,
}

/// Little-endian cursor that turns running out of bytes into [`ErrorKind::Truncated`].
struct Cursor<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> std::result::Result<&'a [u8], ErrorKind> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        let end = end.ok_or_else(|| ErrorKind::Truncated(format!("needs {n} more bytes at offset {}", self.pos)))?;
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn arr<const N: usize>(&mut self) -> std::result::Result<[u8; N], ErrorKind> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
    fn u32(&mut self) -> std::result::Result<u32, ErrorKind> {
        Ok(u32::from_le_bytes(self.arr()?))
    }
    fn i32(&mut self) -> std::result::Result<i32, ErrorKind> {
        Ok(i32::from_le_bytes(self.arr()?))
    }
    fn u64(&mut self) -> std::result::Result<u64, ErrorKind> {
        Ok(u64::from_le_bytes(self.arr()?))
    }
    fn f64(&mut self) -> std::result::Result<f64, ErrorKind> {
        Ok(f64::from_le_bytes(self.arr()?))
    }
    fn left(&self) -> usize {
        self.data.len() - self.pos
    }
    /// A record count, rejected if `n` records of at least `min_size` bytes cannot fit.
    fn count(&mut self, min_size: usize, what: &str) -> std::result::Result<usize, ErrorKind> {
        let n = self.u64()?;
        match usize::try_from(n).ok().and_then(|n| n.checked_mul(min_size).map(|b| (n, b))) {
            Some((n, bytes)) if bytes <= self.left() => Ok(n),
            _ => Err(ErrorKind::Truncated(format!("{n} {what} cannot fit in the {} bytes left", self.left()))),
        }
    }
    fn cstring(&mut self) -> std::result::Result<String, ErrorKind> {
        let rest = &self.data[self.pos..];
        let len = rest.iter().position(|&b| b == 0).ok_or_else(|| ErrorKind::Truncated("unterminated name".into()))?;
        let s = std::str::from_utf8(&rest[..len])
            .map_err(|_| ErrorKind::corrupt("COLMAP images.bin", "image name is not UTF-8"))?;
        self.pos += len + 1;
        Ok(s.to_string())
    }
}

/// Parses `cameras.bin`.
pub fn parse_cameras(bytes: &[u8]) -> std::result::Result<Vec<ColmapCamera>, ErrorKind> {
    let mut c = Cursor { data: bytes, pos: 0 };
    let n = c.count(24, "cameras")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = c.u32()?;
        let model_id = c.i32()?;
        let model = CameraModel::from_id(model_id).ok_or(ErrorKind::UnknownCameraModel(model_id))?;
        let (w, h) = (c.u64()?, c.u64()?);
        let params = (0..model.num_params()).map(|_| c.f64()).collect::<std::result::Result<Vec<_>, _>>()?;
        let side_ok = |s: u64| s > 0 && s <= crate::image_io::MAX_IMAGE_SIDE as u64;
        if !side_ok(w) || !side_ok(h) {
            return Err(ErrorKind::Camera {
                index: id as usize,
                problem: format!("image size {w}x{h} is not plausible"),
            });
        }
        out.push(ColmapCamera { id, model, width: w as u32, height: h as u32, params });
    }
    Ok(out)
}

/// Parses `images.bin`.
pub fn parse_images(bytes: &[u8]) -> std::result::Result<Vec<ColmapImage>, ErrorKind> {
    let mut c = Cursor { data: bytes, pos: 0 };
    let n = c.count(73, "images")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = c.u32()?;
        let qvec = [c.f64()?, c.f64()?, c.f64()?, c.f64()?];
        let tvec = [c.f64()?, c.f64()?, c.f64()?];
        let camera_id = c.u32()?;
        let name = c.cstring()?;
        let np = c.count(24, "keypoints")?;
        let (mut xys, mut ids) = (Vec::with_capacity(np), Vec::with_capacity(np));
        for _ in 0..np {
            xys.push([c.f64()?, c.f64()?]);
            let pid = c.u64()?;
            // COLMAP marks unmatched keypoints with the invalid id (u64::MAX, i.e. -1).
            ids.push((pid != u64::MAX).then_some(pid));
        }
        out.push(ColmapImage { id, qvec, tvec, camera_id, name, xys, point3d_ids: ids });
    }
    Ok(out)
}

/// Parses `points3D.bin`.
pub fn parse_points(bytes: &[u8]) -> std::result::Result<Vec<ColmapPoint>, ErrorKind> {
    let mut c = Cursor { data: bytes, pos: 0 };
    let n = c.count(51, "points")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = c.u64()?;
        let xyz = [c.f64()?, c.f64()?, c.f64()?];
        let rgb = c.arr::<3>()?;
        let error = c.f64()?;
        let nt = c.count(8, "track entries")?;
        let track = (0..nt).map(|_| Ok((c.u32()?, c.u32()?))).collect::<std::result::Result<Vec<_>, ErrorKind>>()?;
        out.push(ColmapPoint { id, xyz, rgb, error, track });
    }
    Ok(out)
}

/// The folder holding the binary model: `sparse/0/` or `sparse/`.
pub fn sparse_dir(root: &Path) -> Option<PathBuf> {
    ["sparse/0", "sparse"].iter().map(|d| root.join(d)).find(|d| d.join("cameras.bin").is_file())
}

/// Reads the three binary files in `dir` (a `sparse/` folder).
pub fn read_model(dir: &Path) -> Result<ColmapModel> {
    let read = |name: &str| {
        let p = dir.join(name);
        read_bytes(&p).map(|b| (b, p))
    };
    let (b, p) = read("cameras.bin")?;
    let cameras = parse_cameras(&b).at(&p)?.into_iter().map(|c| (c.id, c)).collect();
    let (b, p) = read("images.bin")?;
    let images = parse_images(&b).at(&p)?;
    let p = dir.join("points3D.bin");
    // A model without points is still usable (cameras from another source); `load` gives None.
    let points = if p.is_file() { parse_points(&read_bytes(&p)?).at(&p)? } else { Vec::new() };
    Ok(ColmapModel { cameras, images, points })
}

/// Our [`Camera`] for an image of the model (pinhole part of its camera's intrinsics).
pub fn image_camera(model: &ColmapModel, index: usize) -> std::result::Result<Camera, ErrorKind> {
    let im = &model.images[index];
    let err = |p: String| ErrorKind::Camera { index, problem: format!("image {}: {p}", im.name) };
    let cam = model
        .cameras
        .get(&im.camera_id)
        .ok_or_else(|| err(format!("camera id {} not in cameras.bin", im.camera_id)))?;
    if !cam.model.is_supported() {
        return Err(ErrorKind::UnsupportedCameraModel { name: cam.model.name(), id: cam.model.id() });
    }
    let [fx, fy, cx, cy] = cam.model.pinhole(&cam.params).ok_or_else(|| err("wrong parameter count".into()))?;
    let k =
        Intrinsics { fx: fx as f32, fy: fy as f32, cx: cx as f32, cy: cy as f32, width: cam.width, height: cam.height };
    let [w, x, y, z] = im.qvec;
    let q = DQuat::from_xyzw(x, y, z, w);
    if !(q.is_finite() && q.length() > 1e-6) {
        return Err(err("NaN or zero rotation quaternion".into()));
    }
    let r = DMat3::from_quat(q.normalize()).as_mat3();
    let t = Vec3::new(im.tvec[0] as f32, im.tvec[1] as f32, im.tvec[2] as f32);
    Camera::from_w2c(r, t, k).map_err(|e| err(e.to_string()))
}

/// Loads one registered image; the flag says whether the photo file's own alpha was a mask.
fn load_view(
    root: &Path,
    model: &ColmapModel,
    index: usize,
    masks: Option<&Path>,
    opts: &LoadOptions,
) -> Result<(View, bool)> {
    let images_bin = sparse_dir(root).unwrap_or_else(|| root.join("sparse")).join("images.bin");
    let im = &model.images[index];
    let camera = image_camera(model, index).at(&images_bin)?;
    let cam = &model.cameras[&im.camera_id];
    let path = root.join("images").join(&im.name);
    let photo = read_view_image(&path, "view image")?;
    check_size(&photo, index, (cam.width, cam.height), &path)?;
    let stored_mask = stored_alpha_is_mask(&photo);
    let photo = match masks {
        Some(dir) => apply_mask(photo, &path, &find_colmap_mask(dir, &im.name)?)?,
        None => to_rgba(photo),
    };
    let image = if cam.model.is_pinhole() { photo } else { undistort_image(&photo, cam.model, &cam.params) };
    let name = Path::new(&im.name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let v = View { name, camera, image, albedo: None, normal: None, roughness: None, relit: BTreeMap::new() };
    Ok((finish_view(v, opts, &path)?, stored_mask))
}

/// Loads a COLMAP dataset (see the module docs for the split, masks and points).
pub fn load(root: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let dir = sparse_dir(root).ok_or_else(|| ErrorKind::Missing("sparse/cameras.bin".into()).at(root))?;
    let mut model = read_model(&dir)?;
    model.images.sort_by(|a, b| a.name.cmp(&b.name));
    let masks_dir = opts.masks.clone().or_else(|| Some(root.join("masks")).filter(|d| d.is_dir()));
    let (test_idx, train_idx): (Vec<usize>, Vec<usize>) = (0..model.images.len()).partition(|i| i % 8 == 0);
    let load_split = |idx: &[usize]| -> Result<Vec<(View, bool)>> {
        let keep = select_views(idx.len(), opts.max_views);
        let views: Vec<Result<(View, bool)>> =
            keep.par_iter().map(|&k| load_view(root, &model, idx[k], masks_dir.as_deref(), opts)).collect();
        views.into_iter().collect()
    };
    let train = load_split(&train_idx)?;
    let test = if opts.load_test { load_split(&test_idx)? } else { Vec::new() };
    let masks = match masks_dir {
        Some(d) => MaskSource::Folder(d),
        None if train.iter().chain(&test).any(|v| v.1) => MaskSource::Alpha,
        None => MaskSource::None,
    };
    let points = PointCloud {
        positions: model.points.iter().map(|p| Vec3::new(p.xyz[0] as f32, p.xyz[1] as f32, p.xyz[2] as f32)).collect(),
        colors: model.points.iter().map(|p| p.rgb.map(|c| c as f32 / 255.0)).collect(),
    };
    let mut models: Vec<&str> = model.cameras.values().map(|c| c.model.name()).collect();
    models.sort();
    models.dedup();
    Ok(Dataset {
        name: dataset_name(root),
        root: root.to_path_buf(),
        train: train.into_iter().map(|v| v.0).collect(),
        test: test.into_iter().map(|v| v.0).collect(),
        points: Some(points).filter(|p| !p.positions.is_empty()),
        train_light: None,
        relight_lights: Vec::new(),
        camera_model: models.join("+"),
        masks,
        world_rotation: glam::Mat3::IDENTITY,
    })
}
