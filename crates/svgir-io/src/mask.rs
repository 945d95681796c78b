//! Foreground masks: a mask file's grey value becomes its photo's alpha channel, the `masks/`
//! folder naming conventions of COLMAP captures, and telling a stored alpha channel that is a
//! mask from one that is opaque everywhere.
//!
//! Loaders apply masks to the photo *before* undistortion and resizing, so the mask is warped
//! and filtered exactly like the colours it cuts out.

use crate::error::{ErrorKind, Result};
use crate::image_io::to_rgba;
use crate::load::read_view_image;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use svgir_core::Image;

/// True if `img`, as decoded from its file, has an alpha channel that is below 1 somewhere: the
/// file carries a mask. An all-opaque alpha (common in phone PNG exports) is no mask.
pub fn stored_alpha_is_mask(img: &Image) -> bool {
    let c = img.channels as usize;
    (c == 2 || c == 4) && img.data.chunks_exact(c).any(|p| p[c - 1] < 1.0)
}

/// Grey value of a mask pixel: the first channel of grey masks, the mean of R, G and B of
/// colour ones. A mask's own alpha channel is ignored.
fn grey(p: &[f32]) -> f32 {
    if p.len() >= 3 {
        (p[0] + p[1] + p[2]) / 3.0
    } else {
        p[0]
    }
}

/// `photo` (read from `photo_path`) as RGBA whose alpha is the mask in `mask_path`; the mask
/// must have the photo's size.
pub fn apply_mask(photo: Image, photo_path: &Path, mask_path: &Path) -> Result<Image> {
    let mask = read_view_image(mask_path, "mask")?;
    if (mask.width, mask.height) != (photo.width, photo.height) {
        return Err(ErrorKind::invalid(format!(
            "mask is {}x{} but its photo {} is {}x{}",
            mask.width,
            mask.height,
            photo_path.display(),
            photo.width,
            photo.height
        ))
        .at(mask_path));
    }
    let mut image = to_rgba(photo);
    let mc = mask.channels as usize;
    for (p, m) in image.data.chunks_exact_mut(4).zip(mask.data.chunks_exact(mc)) {
        p[3] = grey(m).clamp(0.0, 1.0);
    }
    Ok(image)
}

fn with_suffix(p: &Path, suffix: &str) -> PathBuf {
    let mut s = OsString::from(p.as_os_str());
    s.push(suffix);
    PathBuf::from(s)
}

/// The mask of COLMAP photo `name` (its path under `images/`) in the folder `dir`: `NAME.png`,
/// `NAME.jpg`, `NAME.jpeg` (NAME without the photo's extension) or COLMAP's own convention
/// `NAME.EXT.png`, the first that exists. None existing is an error naming the first.
pub fn find_colmap_mask(dir: &Path, name: &str) -> Result<PathBuf> {
    // Suffixes are appended to the stem, not set with `with_extension`, so "a.b.jpg" -> "a.b.png".
    let stem = dir.join(Path::new(name).with_extension(""));
    let candidates = [
        with_suffix(&stem, ".png"),
        with_suffix(&stem, ".jpg"),
        with_suffix(&stem, ".jpeg"),
        with_suffix(&dir.join(name), ".png"),
    ];
    if let Some(p) = candidates.iter().find(|p| p.is_file()) {
        return Ok(p.clone());
    }
    let others: Vec<String> =
        candidates[1..].iter().filter_map(|p| p.file_name().map(|s| s.to_string_lossy().into_owned())).collect();
    Err(ErrorKind::Missing(format!("mask for photo {name} (also looked for {})", others.join(", "))).at(&candidates[0]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stored_alpha_counts_only_when_not_opaque() {
        assert!(!stored_alpha_is_mask(&Image::filled(2, 2, &[0.5, 0.5, 0.5])));
        assert!(!stored_alpha_is_mask(&Image::filled(2, 2, &[0.5, 0.5, 0.5, 1.0])));
        assert!(stored_alpha_is_mask(&Image::from_data(2, 1, 2, vec![0.5, 1.0, 0.5, 0.0])));
    }

    #[test]
    fn colmap_mask_names() {
        let d = std::env::temp_dir().join(format!("svgir-io-mask-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("sub")).unwrap();
        std::fs::write(d.join("a.b.jpg"), b"").unwrap();
        std::fs::write(d.join("sub/c.JPG.png"), b"").unwrap();
        assert_eq!(find_colmap_mask(&d, "a.b.png").unwrap(), d.join("a.b.jpg"));
        assert_eq!(find_colmap_mask(&d, "sub/c.JPG").unwrap(), d.join("sub/c.JPG.png"));
        let e = find_colmap_mask(&d, "x.jpg").unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "{}: missing mask for photo x.jpg (also looked for x.jpg, x.jpeg, x.jpg.png)",
                d.join("x.png").display()
            )
        );
        let _ = std::fs::remove_dir_all(&d);
    }
}
