//! A human-readable summary of a loaded dataset (what `svgir info` prints).
//!
//! Masks are reported from [`Dataset::masks`], not guessed from pixels: area resizing leaves
//! alpha just below 1 on unmasked photos, which a pixel count would call masked.

use crate::load::detect_layout;
use std::collections::BTreeSet;
use std::fmt::Write;
use svgir_core::{Dataset, MaskSource, View};

fn sizes(views: &[View]) -> String {
    let set: BTreeSet<(u32, u32)> = views.iter().map(|v| (v.image.width, v.image.height)).collect();
    match set.len() {
        0 => "-".into(),
        1..=3 => set.iter().map(|(w, h)| format!("{w}x{h}")).collect::<Vec<_>>().join(", "),
        n => format!("{n} sizes"),
    }
}

fn count(views: &[&View], f: impl Fn(&View) -> bool) -> usize {
    views.iter().filter(|v| f(v)).count()
}

fn masks(m: &MaskSource) -> String {
    match m {
        MaskSource::None => "none".into(),
        MaskSource::Alpha => "alpha channel of the images".into(),
        MaskSource::Folder(d) => format!("mask files in {}", d.display()),
        MaskSource::PerFrame => "per-frame mask_path".into(),
    }
}

/// Layout, views, resolution, camera model, masks, ground truth present, lights and points, one
/// item a line. The layout is detected again from `ds.root` ("unknown" if that fails).
pub fn dataset_summary(ds: &Dataset) -> String {
    let mut s = String::new();
    let all: Vec<&View> = ds.all_views().collect();
    let _ = writeln!(s, "dataset   {} ({})", ds.name, ds.root.display());
    let layout = detect_layout(&ds.root).map(|l| l.name()).unwrap_or("unknown");
    let _ = writeln!(s, "layout    {layout}");
    let _ = writeln!(s, "views     {} train, {} test", ds.train.len(), ds.test.len());
    let _ = writeln!(s, "size      train {}; test {}", sizes(&ds.train), sizes(&ds.test));
    let fov = ds.train.first().map(|v| v.camera.intrinsics.fov_x().to_degrees());
    let fov = fov.map(|f| format!(", fov_x {f:.1} deg")).unwrap_or_default();
    let _ = writeln!(s, "cameras   {}{fov}, extent {:.3}", ds.camera_model, ds.camera_extent());
    if ds.world_rotation != glam::Mat3::IDENTITY {
        let angle = glam::Quat::from_mat3(&ds.world_rotation).angle_between(glam::Quat::IDENTITY).to_degrees();
        let _ = writeln!(s, "up        turned upright: the cameras' mean up is +Z (world rotated by {angle:.1} deg)");
    }
    let _ = writeln!(s, "masks     {}", masks(&ds.masks));
    let gt = [
        ("albedo", count(&all, |v| v.albedo.is_some())),
        ("normal", count(&all, |v| v.normal.is_some())),
        ("roughness", count(&all, |v| v.roughness.is_some())),
        ("relit", count(&all, |v| !v.relit.is_empty())),
    ];
    let gt: Vec<String> = gt.iter().filter(|g| g.1 > 0).map(|(n, c)| format!("{n} {c}/{}", all.len())).collect();
    let _ = writeln!(s, "truth     {}", if gt.is_empty() { "none".to_string() } else { gt.join(", ") });
    let light = |l: &svgir_core::LightInfo| {
        let file = if l.envmap_path.is_some() { "" } else { " (no map file)" };
        format!("{} x{}{file}", l.name, l.strength)
    };
    match &ds.train_light {
        Some(l) => _ = writeln!(s, "light     train: {}", light(l)),
        None => _ = writeln!(s, "light     train: unknown"),
    }
    if !ds.relight_lights.is_empty() {
        let r: Vec<String> = ds.relight_lights.iter().map(light).collect();
        let _ = writeln!(s, "relight   {}", r.join(", "));
    }
    match &ds.points {
        Some(p) => _ = writeln!(s, "points    {}", p.positions.len()),
        None => _ = writeln!(s, "points    none"),
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::{Camera, Image, Intrinsics};

    #[test]
    fn masks_come_from_the_field_not_the_pixels() {
        let k = Intrinsics::from_fov_x(0.7, 4, 4);
        let cam = Camera::from_w2c(glam::Mat3::IDENTITY, glam::Vec3::new(0.0, 0.0, 4.0), k).unwrap();
        // Alpha a hair below 1, as area resizing leaves it on a photo without a mask.
        let image = Image::filled(4, 4, &[0.5, 0.5, 0.5, 0.99999]);
        let view = View {
            name: "v".into(),
            camera: cam,
            image,
            albedo: None,
            normal: None,
            roughness: None,
            relit: Default::default(),
        };
        let mut ds = Dataset {
            name: "d".into(),
            root: "/nonexistent/d".into(),
            train: vec![view],
            test: vec![],
            points: None,
            train_light: None,
            relight_lights: vec![],
            camera_model: "PINHOLE".into(),
            masks: MaskSource::None,
            world_rotation: glam::Mat3::IDENTITY,
        };
        let s = dataset_summary(&ds);
        assert!(
            s.contains("masks     none\n") && s.contains("layout    unknown\n") && s.contains("truth     none"),
            "{s}"
        );
        ds.masks = MaskSource::Folder("/d/masks".into());
        assert!(dataset_summary(&ds).contains("masks     mask files in /d/masks\n"));
        assert!(ds.has_masks());
    }
}
