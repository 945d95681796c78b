//! A multi-view dataset in memory, whatever layout it came from (NeRF/Blender, TensoIR, COLMAP,
//! nerfstudio `transforms.json`). Loaders live in `svgir-io`; this is only the data.
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

#[derive(Clone, Debug)]
pub struct View {
    /// Stable name from the dataset (file stem or folder name), used for output files.
    pub name: String,
    pub camera: Camera,
    pub image: Image,
    pub albedo: Option<Image>,
    /// World normals (3 channels, unit length on the object, 0 elsewhere).
    pub normal: Option<Image>,
    pub roughness: Option<Image>,
    pub relit: BTreeMap<String, Image>,
}

/// An environment light used to render a dataset: radiance = strength x map value.
#[derive(Clone, Debug, PartialEq)]
pub struct LightInfo {
    pub name: String,
    /// Equirectangular HDR file, if the dataset ships it.
    pub envmap_path: Option<PathBuf>,
    pub strength: f32,
}

/// Sparse points (e.g. COLMAP's) for initialisation, with colours in [0, 1] sRGB.
#[derive(Clone, Debug, Default)]
pub struct PointCloud {
    pub positions: Vec<Vec3>,
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

#[derive(Clone, Debug)]
pub struct Dataset {
    pub name: String,
    /// Where it was loaded from: the dataset folder, or the json file when a `transforms.json`
    /// capture was given by its file.
    pub root: PathBuf,
    pub train: Vec<View>,
    pub test: Vec<View>,
    pub points: Option<PointCloud>,
    /// The light the training images were rendered under (if known).
    pub train_light: Option<LightInfo>,
    /// Lights of `View::relit`, by name.
    pub relight_lights: Vec<LightInfo>,
    /// Camera model name as read (e.g. "PINHOLE", "blender"), for reporting.
    pub camera_model: String,
    /// Whether the images' alpha is a foreground mask, and its source.
    pub masks: MaskSource,
}

impl Dataset {
    /// True when the views' alpha channel is a foreground mask (see [`MaskSource`]).
    pub fn has_masks(&self) -> bool {
        self.masks != MaskSource::None
    }

    pub fn all_views(&self) -> impl Iterator<Item = &View> {
        self.train.iter().chain(self.test.iter())
    }

    /// Mean of the training cameras' centres (the origin without training views).
    pub fn camera_centroid(&self) -> Vec3 {
        let n = self.train.len().max(1) as f32;
        self.train.iter().map(|v| v.camera.center()).sum::<Vec3>() / n
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
