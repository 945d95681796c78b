//! Which pixels of a held-out view the training photos saw: each pixel's surface point (from
//! the model's rendered depth) is projected into every training view and counted where it lands
//! inside the image and is not behind that view's own rendered surface. On a sparse capture
//! this separates the error of what the model could have learnt from the error of what no
//! training photo showed, e.g. a background only a test photo looks at.
//!
//! Depth maps are the model's expected depth (`sum w z / sum w`) where the opacity is above
//! one half; the occlusion test allows `tolerance` relative depth.

use glam::Vec3;
use svgir_core::Camera;

/// A training view's camera with its rendered depth (`NaN` where the model is transparent).
pub struct DepthView<'a> {
    /// The view's camera.
    pub camera: &'a Camera,
    /// Rendered expected depth per pixel, row-major, `NaN` where transparent.
    pub depth: &'a [f32],
}

/// Camera depth per pixel from the rasterizer's `sum w z` and opacity; `NaN` below half opacity.
pub fn expected_depth(depth_sum: &[f32], alpha: &[f32]) -> Vec<f32> {
    depth_sum.iter().zip(alpha).map(|(z, a)| if *a > 0.5 { z / a } else { f32::NAN }).collect()
}

/// For each pixel of `camera` with depth `depth`, how many of `views` see its surface point
/// (0 where the depth is unknown).
pub fn seen_count(camera: &Camera, depth: &[f32], views: &[DepthView], tolerance: f32) -> Vec<u32> {
    use rayon::prelude::*;
    let w = camera.width() as usize;
    depth
        .par_iter()
        .enumerate()
        .map(|(i, &z)| {
            if !z.is_finite() {
                return 0;
            }
            let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            let d = camera.ray_dir(x, y);
            let p: Vec3 = camera.center() + d * (z / d.dot(camera.forward()));
            views.iter().filter(|v| sees(v, p, tolerance)).count() as u32
        })
        .collect()
}

fn sees(v: &DepthView, p: Vec3, tolerance: f32) -> bool {
    let Some((x, y, z)) = v.camera.project(p) else { return false };
    let (w, h) = (v.camera.width() as f32, v.camera.height() as f32);
    if !(x >= 0.0 && y >= 0.0 && x < w && y < h) {
        return false;
    }
    let surface = v.depth[y as usize * w as usize + x as usize];
    surface.is_finite() && z <= surface * (1.0 + tolerance)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Mat3;
    use svgir_core::Intrinsics;

    /// A wall at z = 5 seen by a camera looking along +z; a second camera shifted right sees
    /// only the part of the wall inside its own image, and a third one behind an occluder
    /// sees nothing.
    #[test]
    fn counts_views_that_see_the_point() {
        let k = Intrinsics { fx: 10.0, fy: 10.0, cx: 5.0, cy: 5.0, width: 10, height: 10 };
        let cam = |x: f32| Camera::from_w2c(Mat3::IDENTITY, Vec3::new(-x, 0.0, 0.0), k).unwrap();
        let (a, b, c) = (cam(0.0), cam(2.5), cam(0.0));
        let wall = vec![5.0f32; 100];
        let near = vec![1.0f32; 100];
        let views = [DepthView { camera: &b, depth: &wall }, DepthView { camera: &c, depth: &near }];
        let n = seen_count(&a, &wall, &views, 0.02);
        // Camera b (centre x = 2.5) sees the wall for world x in [0, 5]: pixels x >= 5 of a.
        for y in 0..10 {
            for x in 0..10 {
                assert_eq!(n[y * 10 + x], (x >= 5) as u32, "pixel {x},{y}");
            }
        }
        let unknown = vec![f32::NAN; 100];
        assert!(seen_count(&a, &unknown, &views, 0.02).iter().all(|&c| c == 0));
    }
}
