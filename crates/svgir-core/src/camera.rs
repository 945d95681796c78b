//! Pinhole cameras in the OpenCV convention (see the crate docs).
//!
//! A [`Camera`] is intrinsics plus a rigid world-to-camera transform. Loaders convert every
//! dataset's own convention (Blender/NeRF camera-to-world with -z forward, COLMAP world-to-camera
//! quaternions) into this one, and [`Camera::validate`] rejects NaNs and non-rigid rotations so
//! that a bad file fails at load time instead of rendering garbage.

use glam::{Mat3, Mat4, Vec3, Vec4};
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics in pixels; the image is `width` x `height` pixels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Horizontal focal length in pixels.
    pub fx: f32,
    /// Vertical focal length in pixels.
    pub fy: f32,
    /// Principal point x in pixels (pixel i spans [i, i+1)).
    pub cx: f32,
    /// Principal point y in pixels, measured downwards from the top edge.
    pub cy: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl Intrinsics {
    /// Centred principal point and square pixels from a horizontal field of view (radians),
    /// as NeRF's `camera_angle_x`.
    pub fn from_fov_x(fov_x: f32, width: u32, height: u32) -> Self {
        let fx = 0.5 * width as f32 / (0.5 * fov_x).tan();
        Self { fx, fy: fx, cx: 0.5 * width as f32, cy: 0.5 * height as f32, width, height }
    }

    /// Horizontal field of view in radians.
    pub fn fov_x(&self) -> f32 {
        2.0 * (0.5 * self.width as f32 / self.fx).atan()
    }

    /// Vertical field of view in radians.
    pub fn fov_y(&self) -> f32 {
        2.0 * (0.5 * self.height as f32 / self.fy).atan()
    }

    /// Intrinsics of the same camera rendered at `width` x `height` (pixel-edge scaling, so a
    /// centred principal point stays centred).
    pub fn resized(&self, width: u32, height: u32) -> Self {
        let sx = width as f32 / self.width as f32;
        let sy = height as f32 / self.height as f32;
        Self { fx: self.fx * sx, fy: self.fy * sy, cx: self.cx * sx, cy: self.cy * sy, width, height }
    }
}

/// Why a camera is unusable.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    /// The rotation, translation or intrinsics hold a NaN or an infinity.
    #[error("camera matrix contains NaN or infinite values")]
    NotFinite,
    /// The rotation is not orthonormal with det +1: (max deviation of R R^T from I, det R).
    #[error("camera rotation is not a rotation (R R^T deviates from I by {0:.3e}, det {1:.4})")]
    NotRigid(f32, f32),
    /// A focal length or the image size is not positive.
    #[error("intrinsics are degenerate (fx={fx}, fy={fy}, size {width}x{height})")]
    BadIntrinsics {
        /// Horizontal focal length in pixels.
        fx: f32,
        /// Vertical focal length in pixels.
        fy: f32,
        /// Image width in pixels.
        width: u32,
        /// Image height in pixels.
        height: u32,
    },
}

/// A pinhole camera: `x_cam = rotation * x_world + translation` (OpenCV axes).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Pinhole intrinsics in pixels.
    pub intrinsics: Intrinsics,
    /// World-to-camera rotation.
    pub rotation: Mat3,
    /// World-to-camera translation.
    pub translation: Vec3,
}

impl Camera {
    /// From a Blender/NeRF camera-to-world matrix (camera looks along its -z, +y up).
    /// SPEC 8: flip the y and z columns to get OpenCV axes, then invert.
    pub fn from_blender_c2w(c2w: Mat4, intrinsics: Intrinsics) -> Result<Self, CameraError> {
        let flip = Mat4::from_cols(Vec4::X, -Vec4::Y, -Vec4::Z, Vec4::W);
        Self::from_opencv_c2w(c2w * flip, intrinsics)
    }

    /// From an OpenCV-axes camera-to-world matrix.
    pub fn from_opencv_c2w(c2w: Mat4, intrinsics: Intrinsics) -> Result<Self, CameraError> {
        if !c2w.is_finite() {
            return Err(CameraError::NotFinite);
        }
        let r_c2w = Mat3::from_mat4(c2w);
        let center = c2w.w_axis.truncate();
        let rotation = r_c2w.transpose();
        let cam = Self { intrinsics, rotation, translation: -(rotation * center) };
        cam.validate()?;
        Ok(cam)
    }

    /// From a world-to-camera rotation and translation (COLMAP's convention).
    pub fn from_w2c(rotation: Mat3, translation: Vec3, intrinsics: Intrinsics) -> Result<Self, CameraError> {
        let cam = Self { intrinsics, rotation, translation };
        cam.validate()?;
        Ok(cam)
    }

    /// Rejects NaNs, non-orthonormal rotations (tolerance 1e-3) and degenerate intrinsics.
    pub fn validate(&self) -> Result<(), CameraError> {
        let k = &self.intrinsics;
        let finite = self.rotation.is_finite()
            && self.translation.is_finite()
            && [k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite());
        if !finite {
            return Err(CameraError::NotFinite);
        }
        let rrt = self.rotation * self.rotation.transpose();
        let dev = (rrt - Mat3::IDENTITY).to_cols_array().iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let det = self.rotation.determinant();
        if dev > 1e-3 || (det - 1.0).abs() > 1e-3 {
            return Err(CameraError::NotRigid(dev, det));
        }
        if !(k.fx > 0.0 && k.fy > 0.0 && k.width > 0 && k.height > 0) {
            return Err(CameraError::BadIntrinsics { fx: k.fx, fy: k.fy, width: k.width, height: k.height });
        }
        Ok(())
    }

    /// Camera centre in world space.
    pub fn center(&self) -> Vec3 {
        -(self.rotation.transpose() * self.translation)
    }

    /// World direction the camera looks along (+z of camera space).
    pub fn forward(&self) -> Vec3 {
        self.rotation.row(2)
    }

    /// Camera-space coordinates (OpenCV axes) of world point `p`.
    pub fn world_to_camera(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }

    /// The 4x4 world-to-camera matrix.
    pub fn view_matrix(&self) -> Mat4 {
        let mut m = Mat4::from_mat3(self.rotation);
        m.w_axis = self.translation.extend(1.0);
        m
    }

    /// Pixel coordinates and camera depth of a world point; `None` behind the camera.
    pub fn project(&self, p: Vec3) -> Option<(f32, f32, f32)> {
        let c = self.world_to_camera(p);
        if c.z <= 1e-8 {
            return None;
        }
        let k = &self.intrinsics;
        Some((k.fx * c.x / c.z + k.cx, k.fy * c.y / c.z + k.cy, c.z))
    }

    /// Unit world-space direction of the ray through continuous pixel coordinates (x, y).
    pub fn ray_dir(&self, x: f32, y: f32) -> Vec3 {
        let k = &self.intrinsics;
        let d = Vec3::new((x - k.cx) / k.fx, (y - k.cy) / k.fy, 1.0);
        (self.rotation.transpose() * d).normalize()
    }

    /// The same camera rendered at another resolution.
    pub fn resized(&self, width: u32, height: u32) -> Self {
        Self { intrinsics: self.intrinsics.resized(width, height), ..*self }
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.intrinsics.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.intrinsics.height
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn look_at_c2w(eye: Vec3) -> Mat4 {
        // Blender camera: -z looks at the origin, +y roughly up (+Z world).
        let back = eye.normalize();
        let right = Vec3::Z.cross(back).normalize();
        let up = back.cross(right);
        Mat4::from_cols(right.extend(0.0), up.extend(0.0), back.extend(0.0), eye.extend(1.0))
    }

    #[test]
    fn blender_camera_sees_origin_at_principal_point() {
        let k = Intrinsics::from_fov_x(0.69, 400, 300);
        let cam = Camera::from_blender_c2w(look_at_c2w(Vec3::new(3.0, -2.0, 1.5)), k).unwrap();
        let (x, y, z) = cam.project(Vec3::ZERO).unwrap();
        assert!((x - 200.0).abs() < 1e-3 && (y - 150.0).abs() < 1e-3, "{x} {y}");
        assert!((z - Vec3::new(3.0, -2.0, 1.5).length()).abs() < 1e-4);
        // World up projects upwards in the image (smaller y).
        let (_, y_up, _) = cam.project(Vec3::new(0.0, 0.0, 0.1)).unwrap();
        assert!(y_up < y);
        assert!((cam.center() - Vec3::new(3.0, -2.0, 1.5)).length() < 1e-5);
    }

    #[test]
    fn ray_dir_inverts_project() {
        let k = Intrinsics { fx: 300.0, fy: 310.0, cx: 190.0, cy: 140.0, width: 400, height: 300 };
        let cam = Camera::from_blender_c2w(look_at_c2w(Vec3::new(-1.0, 4.0, 2.0)), k).unwrap();
        let p = Vec3::new(0.3, -0.2, 0.4);
        let (x, y, z) = cam.project(p).unwrap();
        let d = cam.ray_dir(x, y);
        let q = cam.center() + d * (z / d.dot(cam.forward()));
        assert!((q - p).length() < 1e-4);
    }

    #[test]
    fn rejects_nan_and_shear() {
        let k = Intrinsics::from_fov_x(0.7, 8, 8);
        let mut m = look_at_c2w(Vec3::new(1.0, 2.0, 3.0));
        m.x_axis.x = f32::NAN;
        assert_eq!(Camera::from_blender_c2w(m, k), Err(CameraError::NotFinite));
        let mut m = look_at_c2w(Vec3::new(1.0, 2.0, 3.0));
        m.x_axis *= 2.0;
        assert!(matches!(Camera::from_blender_c2w(m, k), Err(CameraError::NotRigid(..))));
    }
}
