//! The dataset entry point: layout detection, [`LoadOptions`], and what every layout loader
//! shares (view subsets, resizing a view with its ground truth, normal decoding, size checks).
//!
//! Resizing uses the area filter ([`Image::resize_area`]) with coverage weighting: colours and
//! material maps are averaged over the *covered* part of each output pixel (premultiply by
//! alpha, filter, divide), so object edges do not darken towards the transparent background.
//! Normals are renormalised after filtering. Only downscaling is allowed.

use crate::error::{ErrorKind, Result, WithPath};
use crate::{colmap, nerf, tensoir, transforms};
use std::path::Path;
/// Alpha channel of an RGBA image (shared with `svgir-core`'s resizing).
pub use svgir_core::dataset::alpha_of;
use svgir_core::dataset::downscaled_size;
use svgir_core::{Dataset, Image, View};

/// How much of a dataset to load, and at what size.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    /// Target image width in pixels; the height keeps the aspect ratio (rounded).
    pub resolution: Option<u32>,
    /// Divide both image sides by this factor (rounded), e.g. 2.0 for half size.
    pub downscale: Option<f32>,
    /// Also load the test split (with its ground truth and relit images).
    pub load_test: bool,
    /// At most this many views per split, evenly spaced over the split (first one included).
    pub max_views: Option<usize>,
    /// Foreground masks from this folder (named like the photos, as `DATASET/masks/`) instead
    /// of the dataset's own; captures only (COLMAP, transforms.json).
    pub masks: Option<std::path::PathBuf>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self { resolution: None, downscale: None, load_test: true, max_views: None, masks: None }
    }
}

/// The dataset layouts svgir understands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// NeRF/Blender: `transforms_{train,test}.json` + RGBA PNGs.
    Nerf,
    /// TensoIR: per-view folders with `rgba.png`, `albedo.png`, `normal.png`, `metadata.json`.
    TensoIr,
    /// COLMAP: `sparse/{cameras,images,points3D}.bin` (or `sparse/0/`) + `images/`.
    Colmap,
    /// nerfstudio / instant-ngp: one `transforms.json` for all frames ([`transforms`]).
    Transforms,
}

impl Layout {
    /// The layout's name as `svgir info` prints it.
    pub fn name(self) -> &'static str {
        match self {
            Layout::Nerf => "NeRF/Blender",
            Layout::TensoIr => "TensoIR",
            Layout::Colmap => "COLMAP",
            Layout::Transforms => "transforms.json",
        }
    }
}

/// The folder of a dataset path: `root` itself, or the folder of a json file given instead.
fn dataset_dir(root: &Path) -> &Path {
    match root.parent() {
        Some(p) if root.is_file() => {
            if p.as_os_str().is_empty() {
                Path::new(".")
            } else {
                p
            }
        }
        _ => root,
    }
}

/// Which layout the folder `root` holds. A json file is accepted too: `transforms_<split>.json`
/// stands for its folder, any other json for a single-file `transforms.json` capture.
pub fn detect_layout(root: &Path) -> Result<Layout> {
    if root.is_file() && root.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        let name = root.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        return if name.starts_with("transforms_") { detect_layout(dataset_dir(root)) } else { Ok(Layout::Transforms) };
    }
    if !root.is_dir() {
        let kind = if root.exists() { ErrorKind::invalid("not a folder") } else { ErrorKind::NotFound };
        return Err(kind.at(root));
    }
    if colmap::sparse_dir(root).is_some() {
        return Ok(Layout::Colmap);
    }
    if tensoir::is_tensoir(root) {
        return Ok(Layout::TensoIr);
    }
    if root.join("transforms_train.json").is_file() {
        return Ok(Layout::Nerf);
    }
    if root.join("transforms.json").is_file() {
        return Ok(Layout::Transforms);
    }
    Err(ErrorKind::invalid(
        "not a dataset: expected transforms_train.json (NeRF), train_000/metadata.json (TensoIR), sparse/cameras.bin (COLMAP) or transforms.json (nerfstudio)",
    )
    .at(root))
}

/// Loads the dataset in folder `root` (or given by its json file), whatever its layout.
pub fn load_dataset(root: impl AsRef<Path>, opts: &LoadOptions) -> Result<Dataset> {
    let root = root.as_ref();
    check_options(opts).at(root)?;
    let layout = detect_layout(root)?;
    if let (Some(m), Layout::Nerf | Layout::TensoIr) = (&opts.masks, layout) {
        let why = format!(
            "a masks folder ({}) is for captures; {} datasets carry masks as alpha",
            m.display(),
            layout.name()
        );
        return Err(ErrorKind::invalid(why).at(root));
    }
    if let Some(m) = opts.masks.as_ref().filter(|m| !m.is_dir()) {
        return Err(ErrorKind::Missing("masks folder".into()).at(m));
    }
    match layout {
        Layout::Nerf => nerf::load(dataset_dir(root), opts),
        Layout::TensoIr => tensoir::load(dataset_dir(root), opts),
        Layout::Colmap => colmap::load(dataset_dir(root), opts).map(upright),
        Layout::Transforms => transforms::load(root, opts).map(upright),
    }
}

/// Captures come in their reconstruction's arbitrary frame; environment maps and relighting
/// need +Z up (see [`Dataset::orient_upright`]). Synthetic layouts are +Z up already.
fn upright(mut ds: Dataset) -> Dataset {
    if let Some(a) = ds.orient_upright() {
        ds.world_rotation = a;
    }
    ds
}

fn check_options(opts: &LoadOptions) -> std::result::Result<(), ErrorKind> {
    match (opts.resolution, opts.downscale) {
        (Some(_), Some(_)) => Err(ErrorKind::invalid("give either a resolution or a downscale factor, not both")),
        (Some(0), _) => Err(ErrorKind::invalid("resolution must be positive")),
        (_, Some(f)) if !(f.is_finite() && f >= 1.0) => {
            Err(ErrorKind::invalid(format!("downscale factor must be >= 1 (got {f}); only downscaling is supported")))
        }
        _ => Ok(()),
    }
}

/// Output size of a `w` x `h` image under `opts`, `None` when it stays as it is.
pub fn target_size(opts: &LoadOptions, w: u32, h: u32) -> std::result::Result<Option<(u32, u32)>, ErrorKind> {
    let (tw, th) = match (opts.resolution, opts.downscale) {
        (Some(rw), _) => (rw, ((h as f64 * rw as f64 / w as f64).round() as u32).max(1)),
        (None, Some(f)) => downscaled_size(w, h, f),
        (None, None) => return Ok(None),
    };
    if tw > w || th > h {
        return Err(ErrorKind::invalid(format!(
            "resolution {tw}x{th} is larger than the {w}x{h} images (only downscaling is supported)"
        )));
    }
    Ok(if (tw, th) == (w, h) { None } else { Some((tw, th)) })
}

/// Indices of the views to keep out of `n`: all, or `max` evenly spaced ones.
pub fn select_views(n: usize, max: Option<usize>) -> Vec<usize> {
    match max {
        Some(m) if m < n => (0..m).map(|i| i * n / m).collect(),
        _ => (0..n).collect(),
    }
}

/// Errs unless `img` is `want` in size; `view` is the index used in the message.
pub fn check_size(img: &Image, view: usize, want: (u32, u32), path: &Path) -> Result<()> {
    if (img.width, img.height) != want {
        let (got_w, got_h) = (img.width, img.height);
        return Err(ErrorKind::SizeMismatch { view, got_w, got_h, want_w: want.0, want_h: want.1 }.at(path));
    }
    Ok(())
}

/// Reads a view's image file, reporting an absent file as "missing WHAT".
pub fn read_view_image(path: &Path, what: &str) -> Result<Image> {
    crate::image_io::read_image(path).map_err(|e| match e.kind {
        ErrorKind::NotFound => ErrorKind::Missing(what.to_string()).at(path),
        _ => e,
    })
}

/// Decodes a normal map stored as `rgb = (n + 1) / 2`: `n = 2 rgb - 1`, renormalised where
/// `alpha > 0`, zero elsewhere (the [`svgir_core::dataset`] encoding). 3 channels.
pub fn decode_normals(img: &Image, alpha: &[f32]) -> Image {
    let c = img.channels as usize;
    let mut out = Image::new(img.width, img.height, 3);
    for (i, (p, o)) in img.data.chunks_exact(c).zip(out.data.chunks_exact_mut(3)).enumerate() {
        if alpha[i] > 0.0 && c >= 3 {
            let n = glam::Vec3::new(2.0 * p[0] - 1.0, 2.0 * p[1] - 1.0, 2.0 * p[2] - 1.0).normalize_or_zero();
            o.copy_from_slice(&n.to_array());
        }
    }
    out
}

/// Applies `opts`' resizing to a loaded view.
pub fn finish_view(v: View, opts: &LoadOptions, path: &Path) -> Result<View> {
    match target_size(opts, v.image.width, v.image.height).at(path)? {
        Some((w, h)) => Ok(v.resized(w, h)),
        None => Ok(v),
    }
}

/// Parses JSON written by Python, whose `json.dump` emits bare `NaN` / `Infinity` tokens that
/// strict JSON forbids: those become `null`, which number readers then report as not finite.
pub fn parse_json_lenient(text: &str) -> std::result::Result<serde_json::Value, ErrorKind> {
    let mut out = String::with_capacity(text.len());
    let mut in_str = false;
    let mut escaped = false;
    let mut rest = text;
    while let Some(ch) = rest.chars().next() {
        if in_str {
            in_str = ch != '"' || escaped;
            escaped = ch == '\\' && !escaped;
        } else if ch == '"' {
            in_str = true;
        } else {
            let tok = ["-Infinity", "Infinity", "NaN"].into_iter().find(|t| rest.starts_with(t));
            if let Some(t) = tok {
                out.push_str("null");
                rest = &rest[t.len()..];
                continue;
            }
        }
        out.push(ch);
        rest = &rest[ch.len_utf8()..];
    }
    serde_json::from_str(&out).map_err(|e| ErrorKind::corrupt("JSON", e))
}

/// Reads and parses a JSON file.
pub fn read_json(path: &Path) -> Result<serde_json::Value> {
    let bytes = crate::error::read_bytes(path)?;
    let text = std::str::from_utf8(&bytes).map_err(|e| ErrorKind::corrupt("JSON", e)).at(path)?;
    parse_json_lenient(text).at(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_sizes_and_subsets() {
        let o = LoadOptions { resolution: Some(200), ..Default::default() };
        assert_eq!(target_size(&o, 400, 300).unwrap(), Some((200, 150)));
        let o = LoadOptions { downscale: Some(3.0), ..Default::default() };
        assert_eq!(target_size(&o, 1000, 658).unwrap(), Some((333, 219)));
        let o = LoadOptions { resolution: Some(800), ..Default::default() };
        assert!(target_size(&o, 400, 400).is_err());
        assert_eq!(select_views(10, Some(3)), vec![0, 3, 6]);
        assert_eq!(select_views(2, Some(5)), vec![0, 1]);
        assert!(check_options(&LoadOptions { downscale: Some(0.5), ..Default::default() }).is_err());
    }

    #[test]
    fn lenient_json_maps_nan_to_null_outside_strings() {
        let v = parse_json_lenient(r#"{"a": [1, NaN, -Infinity], "s": "NaN \" Infinity"}"#).unwrap();
        assert!(v["a"][1].is_null() && v["a"][2].is_null());
        assert_eq!(v["s"], "NaN \" Infinity");
    }
}
