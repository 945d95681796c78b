//! Which Gaussians a camera sees, and outward normals for stage 2.
//!
//! Stage 2 shades each surfel over the hemisphere of its normal (SPEC 4), so the normal must point
//! out of the surface. A 2D Gaussian's normal has no inherent side; we orient it towards the
//! training cameras that actually *see* it (its centre in front of the rendered median depth at
//! its pixel). Voting with every camera instead flips the surfels under an overhang or on the
//! underside of an object to face the cameras above them, through the object: their hemisphere
//! then lies inside it.

use glam::{Quat, Vec3};
use svgir_core::{Camera, Surfels};
use svgir_raster::{render, Background, ColorSource, RasterConfig, RenderInput};

/// Per Gaussian: whether its centre is the visible surface at its pixel in `camera` (the render
/// covers the pixel with opacity > 0.5 and its median depth is within 1% of the centre's depth:
/// the surface's thickness of overlapping surfels, not the Gaussian's extent, which would let a
/// large surfel count as seen through whatever covers its centre).
pub fn visible_from(surfels: &Surfels, camera: &Camera, raster: &RasterConfig) -> Vec<bool> {
    let input =
        RenderInput { surfels, camera, colors: ColorSource::Sh, extra: None, background: Background::Color([0.0; 3]) };
    let (out, _) = render(&input, raster);
    let (w, h) = (out.width, out.height);
    (0..surfels.len())
        .map(|i| {
            let Some((x, y, z)) = camera.project(surfels.positions[i]) else { return false };
            if !(x >= 0.0 && y >= 0.0 && x < w as f32 && y < h as f32) {
                return false;
            }
            let p = (y as u32 * w + x as u32) as usize;
            out.alpha[p] > 0.5 && (out.median_depth[p] - z).abs() <= 0.01 * z
        })
        .collect()
}

/// Flips each surfel (a rotation by pi about t_u: n -> -n, t_v -> -t_v; the disk is unchanged) so
/// its normal faces the majority of the cameras that see it ([`visible_from`]); a Gaussian no
/// camera sees votes with every camera. Returns how many were flipped.
pub fn orient_normals(s: &mut Surfels, cameras: &[Camera], raster: &RasterConfig) -> usize {
    let centers: Vec<Vec3> = cameras.iter().map(|c| c.center()).collect();
    let seen: Vec<Vec<bool>> = cameras.iter().map(|c| visible_from(s, c, raster)).collect();
    let mut flipped = 0;
    for i in 0..s.len() {
        let n = s.normal(i);
        let p = s.positions[i];
        let (mut all, mut by_seeing, mut seen_by_any) = (0i64, 0i64, false);
        for (c, centre) in centers.iter().enumerate() {
            let vote = if n.dot(*centre - p) >= 0.0 { 1 } else { -1 };
            all += vote;
            if seen[c][i] {
                by_seeing += vote;
                seen_by_any = true;
            }
        }
        let votes = if seen_by_any { by_seeing } else { all };
        if votes < 0 {
            s.rotations[i] *= Quat::from_rotation_x(std::f32::consts::PI);
            flipped += 1;
        }
    }
    flipped
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat4, Vec2};
    use svgir_core::camera::Intrinsics;
    use svgir_core::ShCoeffs;

    fn look_at(eye: Vec3, target: Vec3) -> Camera {
        // OpenCV camera axes: x right, y down, z forward.
        let f = (target - eye).normalize();
        let x = f.cross(Vec3::Y).normalize();
        let y = f.cross(x);
        let c2w = Mat4::from_cols(x.extend(0.0), y.extend(0.0), f.extend(0.0), eye.extend(1.0));
        Camera::from_opencv_c2w(c2w, Intrinsics::from_fov_x(0.8, 64, 64)).unwrap()
    }

    /// A small surfel under a large opaque one, seen from below by one camera and hidden from
    /// the three above: it must face down, although most cameras are above it.
    #[test]
    fn surfels_face_the_cameras_that_see_them() {
        let mut s = Surfels::with_capacity(2, 0);
        s.push(Vec3::ZERO, Quat::IDENTITY, Vec2::splat(0.0), 5.0, ShCoeffs::default());
        s.push(Vec3::new(0.0, 0.0, -0.5), Quat::IDENTITY, Vec2::splat(0.05f32.ln()), 5.0, ShCoeffs::default());
        let cams = [
            look_at(Vec3::new(1.0, 0.0, 4.0), Vec3::ZERO),
            look_at(Vec3::new(-1.0, 0.0, 4.0), Vec3::ZERO),
            look_at(Vec3::new(0.0, 1.0, 4.0), Vec3::ZERO),
            look_at(Vec3::new(0.0, 0.1, -4.0), Vec3::ZERO),
        ];
        let raster = RasterConfig::default();
        let below = visible_from(&s, &cams[3], &raster);
        let above = visible_from(&s, &cams[0], &raster);
        assert_eq!(below, [false, true]);
        assert_eq!(above, [true, false]);
        assert_eq!(orient_normals(&mut s, &cams, &raster), 1);
        assert!(s.normal(0).z > 0.99, "{}", s.normal(0));
        assert!(s.normal(1).z < -0.99, "{}", s.normal(1));
    }
}
