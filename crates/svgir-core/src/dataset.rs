//! A multi-view dataset in memory, whatever layout it came from (NeRF/Blender, TensoIR, COLMAP,
//! nerfstudio `transforms.json`). Loaders live in `svgir-io`; this is the data and its resizing
//! ([`View::resized`], which `--downscale` and stage 1's half-size iterations share).
//!
//! Image encodings, fixed for all loaders:
//! - `View::image`: RGBA as stored in the file, sRGB-encoded colour in [0, 1], straight (not
//!   premultiplied) alpha; alpha is 1 everywhere for photos without a mask.
//! - `albedo`: linear RGB in [0, 1] (TensoIR stores linear values in 8 bits), 3 channels.
//! - `normal`: world-space unit normals, 3 channels, decoded as `2 rgb - 1` and renormalised
//!   where the object is (alpha > 0), zero elsewhere.
//! - `roughness`: 1 channel in [0, 1].
//! - `relit[name]`: RGBA like `image`, the same view under light `name`.
//!
//! Foreground masks always arrive as `View::image`'s alpha; [`Dataset::masks`] says whether that
//! alpha *is* a mask (and where it came from) or just 1 everywhere, so callers need not guess
//! from pixel values (area resizing leaves alpha at 0.99999 on photos that have no mask).

use crate::{Camera, Image};
use glam::Vec3;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// One camera with its photo and, for synthetic scenes, its ground-truth maps.
#[derive(Clone, Debug)]
pub struct View {
    /// Stable name from the dataset (file stem or folder name), used for output files.
    pub name: String,
    /// The view's camera (OpenCV axes, world-to-camera).
    pub camera: Camera,
    /// RGBA, sRGB-encoded colour in [0, 1], straight alpha (see the module docs).
    pub image: Image,
    /// Ground-truth linear albedo, 3 channels in [0, 1], if the dataset has it.
    pub albedo: Option<Image>,
    /// World normals (3 channels, unit length on the object, 0 elsewhere).
    pub normal: Option<Image>,
    /// Ground-truth roughness, 1 channel in [0, 1], if the dataset has it.
    pub roughness: Option<Image>,
    /// The same view rendered under other lights (RGBA like `image`), by light name.
    pub relit: BTreeMap<String, Image>,
}

/// An environment light used to render a dataset: radiance = strength x map value.
#[derive(Clone, Debug, PartialEq)]
pub struct LightInfo {
    /// Light name (e.g. the env map's file stem), as used in `View::relit`.
    pub name: String,
    /// Equirectangular HDR file, if the dataset ships it.
    pub envmap_path: Option<PathBuf>,
    /// Radiance multiplier applied to the map's values.
    pub strength: f32,
}

/// Sparse points (e.g. COLMAP's) for initialisation, with colours in [0, 1] sRGB.
#[derive(Clone, Debug, Default)]
pub struct PointCloud {
    /// Point positions in world space.
    pub positions: Vec<Vec3>,
    /// sRGB colour per point in [0, 1].
    pub colors: Vec<[f32; 3]>,
}

/// Where the views' foreground masks (their alpha channel) came from.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum MaskSource {
    /// No masks: alpha is 1 except where undistortion looked outside a photo.
    #[default]
    None,
    /// The image files' own alpha channel (rendered RGBA datasets, RGBA photos).
    Alpha,
    /// One mask file per photo in this folder (COLMAP captures with `masks/`).
    Folder(PathBuf),
    /// Per-frame `mask_path` entries of a nerfstudio `transforms.json`.
    PerFrame,
}

/// A loaded multi-view dataset: train and test views, optional points, lights and mask source.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// Dataset name, shown in summaries and reports.
    pub name: String,
    /// Where it was loaded from: the dataset folder, or the json file when a `transforms.json`
    /// capture was given by its file.
    pub root: PathBuf,
    /// Training views.
    pub train: Vec<View>,
    /// Held-out test views (SPEC 8 evaluates on these).
    pub test: Vec<View>,
    /// Sparse initialisation points, if the dataset ships any.
    pub points: Option<PointCloud>,
    /// The light the training images were rendered under (if known).
    pub train_light: Option<LightInfo>,
    /// Lights of `View::relit`, by name.
    pub relight_lights: Vec<LightInfo>,
    /// Camera model name as read (e.g. "PINHOLE", "blender"), for reporting.
    pub camera_model: String,
    /// Whether the images' alpha is a foreground mask, and its source.
    pub masks: MaskSource,
    /// Rotation applied to the capture's own world frame on load ([`Dataset::orient_upright`]);
    /// identity for datasets used as stored.
    pub world_rotation: glam::Mat3,
}

/// A `w` x `h` image's size shrunk by `factor` (>= 1), each side rounded and at least 1: the
/// size `--downscale` loads and stage 1's half-size iterations train on.
pub fn downscaled_size(w: u32, h: u32, factor: f32) -> (u32, u32) {
    let f = factor as f64;
    (((w as f64 / f).round() as u32).max(1), ((h as f64 / f).round() as u32).max(1))
}

impl View {
    /// The view at `w` x `h`: images, ground truth and intrinsics all scaled together.
    pub fn resized(self, w: u32, h: u32) -> Self {
        let alpha = alpha_of(&self.image);
        let image = resize_rgba(&self.image, w, h);
        let small_alpha = alpha_of(&image);
        let normal = self.normal.map(|n| {
            let mut n = resize_covered(&n, &alpha, w, h);
            for (p, &a) in n.data.chunks_exact_mut(3).zip(&small_alpha) {
                let m = if a > 0.0 { glam::Vec3::from_slice(p).normalize_or_zero() } else { glam::Vec3::ZERO };
                p.copy_from_slice(&m.to_array());
            }
            n
        });
        Self {
            name: self.name,
            camera: self.camera.resized(w, h),
            image,
            albedo: self.albedo.map(|m| resize_covered(&m, &alpha, w, h)),
            normal,
            roughness: self.roughness.map(|m| resize_covered(&m, &alpha, w, h)),
            relit: self.relit.into_iter().map(|(k, m)| (k, resize_rgba(&m, w, h))).collect(),
        }
    }
}

/// Alpha channel of an RGBA image (its last channel).
pub fn alpha_of(img: &Image) -> Vec<f32> {
    img.data.chunks_exact(img.channels as usize).map(|p| p[p.len() - 1]).collect()
}

/// Area-filters `map` to `w` x `h`, averaging over coverage `alpha` (full resolution):
/// `out = filter(alpha * map) / filter(alpha)`, 0 where nothing is covered.
fn resize_covered(map: &Image, alpha: &[f32], w: u32, h: u32) -> Image {
    let c = map.channels as usize;
    let mut pre = Image::new(map.width, map.height, map.channels + 1);
    for ((src, dst), &a) in map.data.chunks_exact(c).zip(pre.data.chunks_exact_mut(c + 1)).zip(alpha) {
        for k in 0..c {
            dst[k] = src[k] * a;
        }
        dst[c] = a;
    }
    let small = pre.resize_area(w, h);
    let data = small
        .data
        .chunks_exact(c + 1)
        .flat_map(|p| {
            let a = p[c];
            (0..c).map(move |k| if a > 0.0 { p[k] / a } else { 0.0 })
        })
        .collect();
    Image::from_data(w, h, map.channels, data)
}

/// Straight-alpha RGBA resized with coverage weighting; the alpha itself is box-filtered.
fn resize_rgba(img: &Image, w: u32, h: u32) -> Image {
    let alpha = alpha_of(img);
    let rgb = resize_covered(&img.select_channels(0..3), &alpha, w, h);
    let a = Image::from_data(img.width, img.height, 1, alpha).resize_area(w, h);
    let data = rgb.data.chunks_exact(3).zip(&a.data).flat_map(|(p, &a)| [p[0], p[1], p[2], a]).collect();
    Image::from_data(w, h, 4, data)
}

impl Dataset {
    /// True when the views' alpha channel is a foreground mask (see [`MaskSource`]).
    pub fn has_masks(&self) -> bool {
        self.masks != MaskSource::None
    }

    /// Training views, then test views.
    pub fn all_views(&self) -> impl Iterator<Item = &View> {
        self.train.iter().chain(self.test.iter())
    }

    /// Mean of the training cameras' centres (the origin without training views).
    pub fn camera_centroid(&self) -> Vec3 {
        let n = self.train.len().max(1) as f32;
        self.train.iter().map(|v| v.camera.center()).sum::<Vec3>() / n
    }

    /// Mean of the training cameras' up directions (image -y in world space), unit length;
    /// `None` without training views or when they cancel out.
    pub fn mean_camera_up(&self) -> Option<Vec3> {
        let sum: Vec3 = self.train.iter().map(|v| -v.camera.rotation.row(1)).sum();
        (sum.length() > 1e-3 * self.train.len() as f32).then(|| sum.normalize())
    }

    /// Rotates the world by `a` (cameras and points together, about the origin): every image
    /// stays exactly as it was.
    pub fn rotate_world(&mut self, a: glam::Mat3) {
        for v in self.train.iter_mut().chain(self.test.iter_mut()) {
            // x_cam = R x + t = (R A^T)(A x) + t.
            v.camera.rotation *= a.transpose();
            if let Some(n) = &mut v.normal {
                for p in n.data.chunks_exact_mut(3) {
                    let r = a * Vec3::from_slice(p);
                    p.copy_from_slice(&r.to_array());
                }
            }
        }
        if let Some(pc) = &mut self.points {
            pc.positions.iter_mut().for_each(|p| *p = a * *p);
        }
    }

    /// Turns a capture upright: the rotation taking the cameras' mean up direction to world +Z
    /// (SPEC's environment maps are +Z up), applied with [`Self::rotate_world`] and returned.
    /// Photographers hold the camera upright, so this is the room's up to within a few degrees
    /// (nerfstudio's "up" orientation does the same).
    pub fn orient_upright(&mut self) -> Option<glam::Mat3> {
        let up = self.mean_camera_up()?;
        let a = glam::Mat3::from_quat(glam::Quat::from_rotation_arc(up, Vec3::Z));
        self.rotate_world(a);
        Some(a)
    }

    /// Scene extent as 3DGS defines it (SPEC 2): 1.1 x the largest distance of a training camera
    /// from the training cameras' centroid.
    pub fn camera_extent(&self) -> f32 {
        let centers: Vec<Vec3> = self.train.iter().map(|v| v.camera.center()).collect();
        if centers.is_empty() {
            return 1.0;
        }
        let centroid = self.camera_centroid();
        1.1 * centers.iter().map(|c| (*c - centroid).length()).fold(0.0, f32::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Intrinsics;
    use glam::{Mat3, Mat4, Quat};

    #[test]
    fn coverage_weighted_resize_keeps_edge_colour() {
        // Left half opaque red, right half transparent black: the 2x -> 1x pixel stays red.
        let img = Image::from_data(2, 1, 4, vec![1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
        let small = resize_rgba(&img, 1, 1);
        assert_eq!(small.data, vec![1.0, 0.0, 0.0, 0.5]);
    }

    /// Cameras on a ring looking at the origin, in a world whose up is `up`.
    fn tilted_dataset(up: Vec3) -> Dataset {
        let tilt = Mat3::from_quat(Quat::from_rotation_arc(Vec3::Z, up));
        let views = (0..6)
            .map(|k| {
                let a = k as f32;
                let eye = tilt * Vec3::new(3.0 * a.cos(), 3.0 * a.sin(), 1.5);
                let c2w = Mat4::look_at_rh(eye, Vec3::ZERO, up).inverse();
                let camera = Camera::from_blender_c2w(c2w, Intrinsics::from_fov_x(0.8, 32, 24)).unwrap();
                View {
                    name: k.to_string(),
                    camera,
                    image: Image::new(32, 24, 4),
                    albedo: None,
                    normal: None,
                    roughness: None,
                    relit: BTreeMap::new(),
                }
            })
            .collect();
        let points = PointCloud { positions: vec![tilt * Vec3::new(0.2, -0.1, 0.4)], colors: vec![[1.0; 3]] };
        Dataset {
            name: "t".into(),
            root: PathBuf::new(),
            train: views,
            test: Vec::new(),
            points: Some(points),
            train_light: None,
            relight_lights: Vec::new(),
            camera_model: "PINHOLE".into(),
            masks: MaskSource::None,
            world_rotation: Mat3::IDENTITY,
        }
    }

    #[test]
    fn orient_upright_turns_the_cameras_up_to_z_and_keeps_the_images() {
        let up = Vec3::new(0.3, -0.9, 0.2).normalize();
        let mut ds = tilted_dataset(up);
        let before: Vec<_> =
            ds.train.iter().map(|v| v.camera.project(ds.points.as_ref().unwrap().positions[0])).collect();
        assert!((ds.mean_camera_up().unwrap() - up).length() < 0.2, "the ring's mean up is near the world's up");
        let a = ds.orient_upright().unwrap();
        assert!((ds.mean_camera_up().unwrap() - Vec3::Z).length() < 1e-5);
        assert!((a * up - Vec3::Z).length() < 0.2);
        let p = ds.points.as_ref().unwrap().positions[0];
        for (v, b) in ds.train.iter().zip(before) {
            let (x0, y0, z0) = b.unwrap();
            let (x, y, z) = v.camera.project(p).unwrap();
            assert!((x - x0).abs() < 1e-3 && (y - y0).abs() < 1e-3 && (z - z0).abs() < 1e-4);
            v.camera.validate().unwrap();
        }
    }
}
