//! Turntable cameras about the object, for relit videos.

use glam::{Mat4, Vec3};
use svgir_core::{Camera, Dataset};

/// `frames` cameras on a circle around the world origin (where the synthetic scenes sit; +Z up),
/// at the training cameras' mean distance and 20 degrees elevation, with `like`'s intrinsics.
pub fn turntable_cameras(ds: &Dataset, like: &Camera, frames: usize) -> Vec<Camera> {
    // About the point every camera looks at (the origin for the synthetic scenes), at the
    // cameras' mean distance and elevation, +Z up.
    let cams: Vec<_> = ds.train.iter().map(|v| v.camera).collect();
    let centre = svgir_train::foreground::focus_point(&cams).unwrap_or(Vec3::ZERO);
    let offsets: Vec<Vec3> = cams.iter().map(|c| c.center() - centre).collect();
    let n = offsets.len().max(1) as f32;
    let dist = offsets.iter().map(|o| o.length()).sum::<f32>() / n;
    let elev = (offsets.iter().map(|o| (o.z / o.length().max(1e-9)).clamp(-1.0, 1.0).asin()).sum::<f32>() / n)
        .clamp(-1.2, 1.2);
    (0..frames)
        .filter_map(|f| {
            let az = std::f32::consts::TAU * f as f32 / frames as f32;
            let back = Vec3::new(elev.cos() * az.cos(), elev.cos() * az.sin(), elev.sin());
            let eye = centre + dist * back;
            let right = Vec3::Z.cross(back).normalize();
            let up = back.cross(right);
            let c2w = Mat4::from_cols(right.extend(0.0), up.extend(0.0), back.extend(0.0), eye.extend(1.0));
            Camera::from_blender_c2w(c2w, like.intrinsics).ok()
        })
        .collect()
}
