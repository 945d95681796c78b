//! COLMAP camera models: parameter layouts, the forward lens distortion of each supported
//! model, and undistortion of a photo into a pinhole image with the same fx, fy, cx, cy.
//!
//! Undistortion inverts nothing: for every output pixel centre (pinhole), the forward
//! distortion of its normalised coordinates gives where that ray landed in the photo, which is
//! sampled bilinearly (COLMAP's pixel convention, centre at +0.5, is ours). Output pixels whose
//! ray fell outside the photo get alpha 0, so training ignores them. Rows run in parallel.

use rayon::prelude::*;
use svgir_core::Image;

/// COLMAP's camera model ids (`colmap/src/colmap/sensor/models.h`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraModel {
    /// `SIMPLE_PINHOLE` (id 0): f, cx, cy.
    SimplePinhole,
    /// `PINHOLE` (id 1): fx, fy, cx, cy.
    Pinhole,
    /// `SIMPLE_RADIAL` (id 2): f, cx, cy, k.
    SimpleRadial,
    /// `RADIAL` (id 3): f, cx, cy, k1, k2.
    Radial,
    /// `OPENCV` (id 4): fx, fy, cx, cy, k1, k2, p1, p2.
    OpenCv,
    /// `OPENCV_FISHEYE` (id 5): fx, fy, cx, cy, k1, k2, k3, k4.
    OpenCvFisheye,
    /// `FULL_OPENCV` (id 6): fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6.
    FullOpenCv,
    /// `FOV` (id 7): fx, fy, cx, cy, omega (not supported for undistortion).
    Fov,
    /// `SIMPLE_RADIAL_FISHEYE` (id 8): f, cx, cy, k (not supported for undistortion).
    SimpleRadialFisheye,
    /// `RADIAL_FISHEYE` (id 9): f, cx, cy, k1, k2 (not supported for undistortion).
    RadialFisheye,
    /// `THIN_PRISM_FISHEYE` (id 10): 12 parameters (not supported for undistortion).
    ThinPrismFisheye,
    /// `RAD_TAN_THIN_PRISM_FISHEYE` (id 11): 16 parameters (not supported for undistortion).
    RadTanThinPrismFisheye,
}

const MODELS: [(CameraModel, &str, usize); 12] = [
    (CameraModel::SimplePinhole, "SIMPLE_PINHOLE", 3),
    (CameraModel::Pinhole, "PINHOLE", 4),
    (CameraModel::SimpleRadial, "SIMPLE_RADIAL", 4),
    (CameraModel::Radial, "RADIAL", 5),
    (CameraModel::OpenCv, "OPENCV", 8),
    (CameraModel::OpenCvFisheye, "OPENCV_FISHEYE", 8),
    (CameraModel::FullOpenCv, "FULL_OPENCV", 12),
    (CameraModel::Fov, "FOV", 5),
    (CameraModel::SimpleRadialFisheye, "SIMPLE_RADIAL_FISHEYE", 4),
    (CameraModel::RadialFisheye, "RADIAL_FISHEYE", 5),
    (CameraModel::ThinPrismFisheye, "THIN_PRISM_FISHEYE", 12),
    (CameraModel::RadTanThinPrismFisheye, "RAD_TAN_THIN_PRISM_FISHEYE", 16),
];

impl CameraModel {
    /// The model with COLMAP id `id`, `None` for an unknown id.
    pub fn from_id(id: i32) -> Option<Self> {
        usize::try_from(id).ok().and_then(|i| MODELS.get(i)).map(|m| m.0)
    }

    /// COLMAP's numeric id of the model.
    pub fn id(self) -> i32 {
        MODELS.iter().position(|m| m.0 == self).unwrap_or(0) as i32
    }

    /// COLMAP's upper-case name of the model (e.g. `"OPENCV"`).
    pub fn name(self) -> &'static str {
        MODELS[self.id() as usize].1
    }

    /// Number of parameters COLMAP stores for the model.
    pub fn num_params(self) -> usize {
        MODELS[self.id() as usize].2
    }

    /// Whether [`distort`] and the loader handle this model.
    pub fn is_supported(self) -> bool {
        (self.id() as usize) <= 6
    }

    /// True for models without distortion.
    pub fn is_pinhole(self) -> bool {
        matches!(self, Self::SimplePinhole | Self::Pinhole)
    }

    /// (fx, fy, cx, cy) of a parameter vector of this model.
    pub fn pinhole(self, p: &[f64]) -> Option<[f64; 4]> {
        if p.len() != self.num_params() {
            return None;
        }
        match self {
            Self::SimplePinhole | Self::SimpleRadial | Self::Radial => Some([p[0], p[0], p[1], p[2]]),
            Self::SimpleRadialFisheye | Self::RadialFisheye => Some([p[0], p[0], p[1], p[2]]),
            _ => Some([p[0], p[1], p[2], p[3]]),
        }
    }
}

/// Forward distortion of normalised image coordinates (u, v) = (X/Z, Y/Z) for a supported model
/// with parameters `p` (COLMAP's formulas); unsupported models return the input.
pub fn distort(model: CameraModel, p: &[f64], u: f64, v: f64) -> (f64, f64) {
    let (u2, v2, uv) = (u * u, v * v, u * v);
    let r2 = u2 + v2;
    let (du, dv) = match model {
        CameraModel::SimpleRadial => (u * p[3] * r2, v * p[3] * r2),
        CameraModel::Radial => {
            let radial = p[3] * r2 + p[4] * r2 * r2;
            (u * radial, v * radial)
        }
        CameraModel::OpenCv => {
            let (k1, k2, p1, p2) = (p[4], p[5], p[6], p[7]);
            let radial = k1 * r2 + k2 * r2 * r2;
            (u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2), v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2))
        }
        CameraModel::FullOpenCv => {
            let (k1, k2, p1, p2, k3, k4, k5, k6) = (p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11]);
            let (r4, r6) = (r2 * r2, r2 * r2 * r2);
            let radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
            (
                u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2) - u,
                v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2) - v,
            )
        }
        CameraModel::OpenCvFisheye => {
            let r = r2.sqrt();
            if r > f64::EPSILON {
                let (k1, k2, k3, k4) = (p[4], p[5], p[6], p[7]);
                let th = r.atan();
                let t2 = th * th;
                let thd = th * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))));
                (u * thd / r - u, v * thd / r - v)
            } else {
                (0.0, 0.0)
            }
        }
        _ => (0.0, 0.0),
    };
    (u + du, v + dv)
}

/// Bilinear sample of all channels at continuous pixel coordinates (x, y) (pixel centres at
/// +0.5); `false` if (x, y) lies outside the image.
fn sample(img: &Image, x: f64, y: f64, out: &mut [f32]) -> bool {
    let (w, h) = (img.width as f64, img.height as f64);
    if !(x >= 0.0 && y >= 0.0 && x <= w && y <= h) {
        return false;
    }
    let sx = (x - 0.5).clamp(0.0, w - 1.0);
    let sy = (y - 0.5).clamp(0.0, h - 1.0);
    let (x0, y0) = (sx.floor() as u32, sy.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
    let (tx, ty) = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
    // Lerp form, so a constant image (e.g. alpha 1) samples to exactly that constant.
    let (p00, p10, p01, p11) = (img.pixel(x0, y0), img.pixel(x1, y0), img.pixel(x0, y1), img.pixel(x1, y1));
    for (k, o) in out.iter_mut().enumerate() {
        let top = p00[k] + (p10[k] - p00[k]) * tx;
        let bottom = p01[k] + (p11[k] - p01[k]) * tx;
        *o = top + (bottom - top) * ty;
    }
    true
}

/// Undistorts an RGBA photo taken with `model`/`params` into the pinhole image with the same
/// fx, fy, cx, cy and size. Pixels that see outside the photo are transparent black.
pub fn undistort_image(img: &Image, model: CameraModel, params: &[f64]) -> Image {
    let Some([fx, fy, cx, cy]) = model.pinhole(params) else { return img.clone() };
    if model.is_pinhole() || img.width == 0 || img.height == 0 {
        return img.clone();
    }
    let c = img.channels as usize;
    let mut out = Image::new(img.width, img.height, img.channels);
    out.data.par_chunks_mut(img.width as usize * c).enumerate().for_each(|(y, row)| {
        let mut px = vec![0.0f32; c];
        for (x, o) in row.chunks_exact_mut(c).enumerate() {
            let u = (x as f64 + 0.5 - cx) / fx;
            let v = (y as f64 + 0.5 - cy) / fy;
            let (ud, vd) = distort(model, params, u, v);
            if sample(img, fx * ud + cx, fy * vd + cy, &mut px) {
                o.copy_from_slice(&px);
            }
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Inverse distortion by fixed-point iteration, only for building the test input.
    fn undistort_point(model: CameraModel, p: &[f64], ud: f64, vd: f64) -> (f64, f64) {
        let (mut u, mut v) = (ud, vd);
        for _ in 0..200 {
            let (du, dv) = distort(model, p, u, v);
            u -= du - ud;
            v -= dv - vd;
        }
        (u, v)
    }

    #[test]
    fn undistortion_recovers_the_pinhole_image() {
        let (w, h) = (96u32, 64u32);
        let pattern = |u: f64, v: f64| [(0.5 + 0.5 * (7.0 * u).sin()) as f32, (0.5 + 0.5 * (5.0 * v).cos()) as f32];
        let cases: [(CameraModel, Vec<f64>); 5] = [
            (CameraModel::SimpleRadial, vec![80.0, 47.0, 33.0, -0.12]),
            (CameraModel::Radial, vec![80.0, 47.0, 33.0, -0.1, 0.03]),
            (CameraModel::OpenCv, vec![80.0, 84.0, 47.0, 33.0, -0.1, 0.02, 0.003, -0.002]),
            (CameraModel::FullOpenCv, vec![80.0, 84.0, 47.0, 33.0, -0.1, 0.02, 0.003, -0.002, 0.001, 0.01, 0.0, 0.0]),
            (CameraModel::OpenCvFisheye, vec![80.0, 84.0, 47.0, 33.0, 0.05, -0.01, 0.0, 0.0]),
        ];
        for (model, p) in cases {
            let [fx, fy, cx, cy] = model.pinhole(&p).unwrap();
            // The photo: each pixel shows the pattern at its undistorted ray; alpha 1.
            let mut photo = Image::new(w, h, 4);
            for y in 0..h {
                for x in 0..w {
                    let (ud, vd) = ((x as f64 + 0.5 - cx) / fx, (y as f64 + 0.5 - cy) / fy);
                    let (u, v) = undistort_point(model, &p, ud, vd);
                    let [a, b] = pattern(u, v);
                    photo.pixel_mut(x, y).copy_from_slice(&[a, b, 0.0, 1.0]);
                }
            }
            let out = undistort_image(&photo, model, &p);
            let (mut err, mut n) = (0.0f32, 0);
            for y in 0..h {
                for x in 0..w {
                    let q = out.pixel(x, y);
                    if q[3] > 0.999 {
                        let (u, v) = ((x as f64 + 0.5 - cx) / fx, (y as f64 + 0.5 - cy) / fy);
                        let [a, b] = pattern(u, v);
                        err = err.max((q[0] - a).abs()).max((q[1] - b).abs());
                        n += 1;
                    }
                }
            }
            assert!(n > (w * h) as usize / 2, "{model:?}: only {n} valid pixels");
            assert!(err < 0.02, "{model:?}: max error {err}");
            // Without undistortion the same comparison fails: the test can tell.
            let (mut raw_err, cx0) = (0.0f32, photo.pixel(2, 2)[0]);
            let (u, v) = ((2.5 - cx) / fx, (2.5 - cy) / fy);
            raw_err = raw_err.max((cx0 - pattern(u, v)[0]).abs());
            if model != CameraModel::OpenCvFisheye {
                assert!(raw_err > 0.02, "{model:?}: distortion too weak to test ({raw_err})");
            }
        }
    }

    #[test]
    fn ids_and_names() {
        assert_eq!(CameraModel::from_id(4), Some(CameraModel::OpenCv));
        assert_eq!(CameraModel::OpenCv.name(), "OPENCV");
        assert_eq!(CameraModel::FullOpenCv.num_params(), 12);
        assert_eq!(CameraModel::from_id(99), None);
        assert_eq!(CameraModel::from_id(-1), None);
    }
}
