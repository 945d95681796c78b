//! Truncated signed distance fusion of rendered depth maps (2DGS's mesh extraction, after
//! Curless & Levoy / Open3D's `ScalableTSDFVolume`), hand-written over a dense grid because the
//! object fits one: a few hundred voxels a side.
//!
//! Each voxel centre is projected into every view; with `z` its camera depth and `D` the depth
//! map at that pixel (nearest), `sdf = D - z`:
//! - `sdf >= -trunc` and `D` valid: fused as the weighted mean of `min(1, sdf / trunc)` (weight 1);
//! - `D` invalid (the model is transparent there, or beyond the depth cut-off): the voxel is seen
//!   to be empty (space carving);
//! - `sdf < -trunc`: hidden behind the surface, no information.
//!
//! Voxels never fused are outside (+1) when some view saw through them or none saw them, inside
//! (-1) otherwise, so the zero level set closes without walls at the band's inner edge.
//! Work split: rayon over z-slices of the grid; each voxel loops over the views.

use crate::ExportError;
use glam::Vec3;
use rayon::prelude::*;
use svgir_core::{Camera, Surfels};

/// Grid and truncation settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TsdfParams {
    /// Voxel side (world units).
    pub voxel: f32,
    /// Truncation distance (world units); 2DGS uses 5 voxels (its `sdf_trunc`).
    pub trunc: f32,
    /// Depths beyond this are ignored (2DGS's `depth_trunc`).
    pub depth_max: f32,
}

impl TsdfParams {
    /// Settings derived from the cameras, as 2DGS derives them from the scene: the voxel is the
    /// footprint of a pixel at the nearest camera distance to the object's centre (divided by
    /// `detail`), the truncation 5 voxels, the depth cut-off twice the farthest camera distance.
    pub fn from_cameras(cameras: &[Camera], center: Vec3, detail: f32) -> Result<Self, ExportError> {
        let mut near = f32::INFINITY;
        let mut far = 0.0f32;
        let mut foot = f32::INFINITY;
        for c in cameras {
            let d = (c.center() - center).length();
            let f = d / c.intrinsics.fx.max(c.intrinsics.fy);
            near = near.min(d);
            far = far.max(d);
            foot = foot.min(f);
        }
        if !(foot.is_finite() && foot > 0.0 && detail > 0.0) {
            return Err(ExportError::Invalid("no cameras to derive the voxel size from".into()));
        }
        let voxel = foot / detail;
        Ok(Self { voxel, trunc: 5.0 * voxel, depth_max: 2.0 * far })
    }
}

/// One depth map: camera depth per pixel (row-major), NaN where there is no surface.
#[derive(Clone, Copy, Debug)]
pub struct DepthView<'a> {
    /// The camera the depth was rendered from.
    pub camera: &'a Camera,
    /// `width * height` camera depths.
    pub depth: &'a [f32],
}

/// A fused grid: `dims` voxels from `origin` (centre of voxel 0), x fastest.
#[derive(Clone, Debug, PartialEq)]
pub struct TsdfGrid {
    /// Centre of voxel (0, 0, 0).
    pub origin: Vec3,
    /// Voxel side.
    pub voxel: f32,
    /// Voxels per axis.
    pub dims: [u32; 3],
    /// Signed distance in units of the truncation, in [-1, 1]; positive outside.
    pub sdf: Vec<f32>,
    /// Views fused per voxel (0: sign from carving).
    pub weight: Vec<u16>,
}

impl TsdfGrid {
    /// World position of voxel `(x, y, z)`.
    pub fn position(&self, x: u32, y: u32, z: u32) -> Vec3 {
        self.origin + self.voxel * Vec3::new(x as f32, y as f32, z as f32)
    }
}

/// Fuses `views` into a grid covering `[lo, hi]`. Fails on more than `max_voxels` voxels.
pub fn fuse(
    lo: Vec3,
    hi: Vec3,
    p: &TsdfParams,
    views: &[DepthView],
    max_voxels: usize,
) -> Result<TsdfGrid, ExportError> {
    if !(p.voxel > 0.0 && p.trunc > 0.0 && p.depth_max > 0.0 && lo.is_finite() && hi.is_finite()) {
        return Err(ExportError::Invalid(format!("bad TSDF settings {p:?} or bounds {lo} .. {hi}")));
    }
    for v in views {
        let n = v.camera.width() as usize * v.camera.height() as usize;
        if v.depth.len() != n {
            return Err(ExportError::Invalid(format!("depth map has {} values for {n} pixels", v.depth.len())));
        }
    }
    let ext = (hi - lo).max(Vec3::ZERO);
    let dims = (ext / p.voxel).ceil().as_uvec3() + 1;
    let count = dims.x as u64 * dims.y as u64 * dims.z as u64;
    if count > max_voxels as u64 {
        return Err(ExportError::Invalid(format!(
            "a {}x{}x{} grid ({count} voxels) exceeds the limit {max_voxels}: use a larger voxel",
            dims.x, dims.y, dims.z
        )));
    }
    let (nx, ny) = (dims.x as usize, dims.y as usize);
    let mut sdf = vec![0.0f32; count as usize];
    let mut weight = vec![0u16; count as usize];
    sdf.par_chunks_mut(nx * ny).zip(weight.par_chunks_mut(nx * ny)).enumerate().for_each(|(z, (s, w))| {
        for i in 0..nx * ny {
            let pos = lo + p.voxel * Vec3::new((i % nx) as f32, (i / nx) as f32, z as f32);
            let (value, n) = fuse_voxel(pos, p, views);
            s[i] = value;
            w[i] = n;
        }
    });
    Ok(TsdfGrid { origin: lo, voxel: p.voxel, dims: dims.to_array(), sdf, weight })
}

fn fuse_voxel(pos: Vec3, p: &TsdfParams, views: &[DepthView]) -> (f32, u16) {
    let (mut sum, mut n, mut free, mut seen) = (0.0f32, 0u16, false, false);
    for v in views {
        let Some((x, y, z)) = v.camera.project(pos) else { continue };
        let (w, h) = (v.camera.width() as f32, v.camera.height() as f32);
        if !(x >= 0.0 && y >= 0.0 && x < w && y < h) {
            continue;
        }
        seen = true;
        let d = v.depth[y as usize * v.camera.width() as usize + x as usize];
        if !(d.is_finite() && d > 0.0 && d <= p.depth_max) {
            free = true;
            continue;
        }
        let s = d - z;
        if s < -p.trunc {
            continue;
        }
        if s > p.trunc {
            free = true;
        }
        sum += (s / p.trunc).min(1.0);
        n += 1;
    }
    if n > 0 {
        (sum / n as f32, n)
    } else if free || !seen {
        (1.0, 0)
    } else {
        (-1.0, 0)
    }
}

/// Camera depth of `surfels` seen from `camera`, NaN below half opacity: the median depth
/// (2DGS's choice for bounded scenes, `depth_ratio = 1`) or the expected depth.
pub fn render_depth(surfels: &Surfels, camera: &Camera, median: bool) -> Result<Vec<f32>, ExportError> {
    use svgir_raster::{try_render, Background, ColorSource, RasterConfig, RenderInput};
    let input =
        RenderInput { surfels, camera, colors: ColorSource::Sh, extra: None, background: Background::Color([0.0; 3]) };
    let cfg = RasterConfig { distortion: false, ..RasterConfig::default() };
    let (out, _) = try_render(&input, &cfg).map_err(|e| ExportError::Invalid(format!("rendering depth: {e}")))?;
    Ok(out
        .alpha
        .iter()
        .enumerate()
        .map(|(i, &a)| match (a > 0.5, median) {
            (false, _) => f32::NAN,
            (true, true) => out.median_depth[i],
            (true, false) => out.depth[i] / a,
        })
        .collect())
}

/// Robust bounds of the surface points the depth maps see: the `q` and `1 - q` quantiles per
/// axis of every back-projected pixel (floaters seen by few pixels fall outside).
pub fn depth_bounds(views: &[DepthView], q: f32) -> Option<(Vec3, Vec3)> {
    let mut pts: [Vec<f32>; 3] = Default::default();
    for v in views {
        let w = v.camera.width() as usize;
        for (i, &d) in v.depth.iter().enumerate() {
            if !d.is_finite() {
                continue;
            }
            let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            let dir = v.camera.ray_dir(x, y);
            let p = v.camera.center() + dir * (d / dir.dot(v.camera.forward()));
            for a in 0..3 {
                pts[a].push(p[a]);
            }
        }
    }
    if pts[0].is_empty() {
        return None;
    }
    let mut lo = Vec3::ZERO;
    let mut hi = Vec3::ZERO;
    for a in 0..3 {
        let v = &mut pts[a];
        v.sort_by(f32::total_cmp);
        let k = ((v.len() - 1) as f32 * q.clamp(0.0, 0.5)) as usize;
        lo[a] = v[k];
        hi[a] = v[v.len() - 1 - k];
    }
    Some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::camera::Intrinsics;

    /// Analytic depth of a sphere seen from `cam` (NaN off the sphere).
    fn sphere_depth(cam: &Camera, c: Vec3, r: f32) -> Vec<f32> {
        let (w, h) = (cam.width(), cam.height());
        let mut out = vec![f32::NAN; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
                let o = cam.center() - c;
                let b = o.dot(d);
                let disc = b * b - (o.length_squared() - r * r);
                if disc >= 0.0 {
                    let t = -b - disc.sqrt();
                    out[(y * w + x) as usize] = t * d.dot(cam.forward());
                }
            }
        }
        out
    }

    pub(crate) fn orbit(n: usize, size: u32) -> Vec<Camera> {
        let k = Intrinsics::from_fov_x(0.7, size, size);
        (0..n)
            .map(|i| {
                let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let r = (1.0 - z * z).sqrt();
                let eye = 4.0 * Vec3::new(r * (golden * i as f32).cos(), r * (golden * i as f32).sin(), z);
                let fwd = (-eye).normalize();
                let up = if fwd.z.abs() > 0.9 { Vec3::X } else { Vec3::Z };
                let right = fwd.cross(up).normalize();
                let down = fwd.cross(right);
                let rot = glam::Mat3::from_cols(right, down, fwd).transpose();
                Camera::from_w2c(rot, -(rot * eye), k).unwrap()
            })
            .collect()
    }

    #[test]
    fn sphere_fuses_to_its_distance() {
        let cams = orbit(24, 64);
        let depths: Vec<Vec<f32>> = cams.iter().map(|c| sphere_depth(c, Vec3::ZERO, 1.0)).collect();
        let views: Vec<DepthView> = cams.iter().zip(&depths).map(|(c, d)| DepthView { camera: c, depth: d }).collect();
        let (lo, hi) = depth_bounds(&views, 0.0).unwrap();
        assert!((hi - Vec3::ONE).abs().max_element() < 0.05 && (lo + Vec3::ONE).abs().max_element() < 0.05);
        let p = TsdfParams { voxel: 0.05, trunc: 0.2, depth_max: 10.0 };
        let g = fuse(lo - 0.3, hi + 0.3, &p, &views, 1 << 22).unwrap();
        let [nx, ny, nz] = g.dims;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let i = ((z * ny + y) * nx + x) as usize;
                    let truth = g.position(x, y, z).length() - 1.0;
                    if truth.abs() < 0.1 {
                        assert!(g.weight[i] > 0, "near-surface voxel not fused");
                    }
                    // Signs agree away from the surface (a pixel footprint is ~0.035 here).
                    if truth.abs() > 0.08 {
                        assert_eq!(g.sdf[i] > 0.0, truth > 0.0, "sign at distance {truth}");
                    }
                    if truth < -0.3 {
                        assert_eq!(g.sdf[i], -1.0, "deep inside must be inside");
                    } else if truth > 0.3 {
                        assert_eq!(g.sdf[i], 1.0, "far outside must be outside");
                    }
                }
            }
        }
        // The extracted surface against the analytic sphere (the Chamfer of the unit test).
        let m = crate::isosurface::extract(&g).unwrap();
        let errs: Vec<f32> = m.positions.iter().map(|p| (p.length() - 1.0).abs()).collect();
        let mean = errs.iter().sum::<f32>() / errs.len() as f32;
        let worst = errs.iter().fold(0.0f32, |a, b| a.max(*b));
        assert!(mean < 0.01 && worst < 0.04, "mean {mean} max {worst}");
    }

    #[test]
    fn bad_settings_are_errors() {
        let p = TsdfParams { voxel: 0.0, trunc: 0.1, depth_max: 1.0 };
        assert!(fuse(Vec3::ZERO, Vec3::ONE, &p, &[], 100).is_err());
        let p = TsdfParams { voxel: 0.01, trunc: 0.1, depth_max: 1.0 };
        assert!(fuse(Vec3::ZERO, Vec3::ONE, &p, &[], 100).is_err(), "too many voxels");
    }
}
