//! Environment lighting as a lat-long map in the frame SPEC 4 fixes (TensoIR's, z-up).
//!
//! A direction `d` maps to `phi = acos(z)`, `theta = atan2(y, x)` and grid coordinates
//! `(gx, gy) = (-theta/pi, 2 phi/pi - 1)` in [-1, 1]^2, sampled bilinearly with *aligned corners*:
//! column `c` sits at `gx = -1 + 2c/(W-1)`, row `r` at `gy = -1 + 2r/(H-1)`. So row 0 is the
//! zenith (+z) and row H-1 the nadir; columns 0 and W-1 both sit on the seam theta = +-pi.
//! Files on disk (Blender/Poly Haven equirectangular) use pixel-centred coordinates instead:
//! `u = 0.5 - theta/(2 pi)`, `v` from the top; [`EnvMap::from_equirect`] converts with an
//! area-correct (solid-angle weighted) filter, SPEC 9.

use crate::image::Image;
use glam::Vec3;
use std::f32::consts::PI;

/// A lat-long environment map of linear RGB radiance, `height` x `width` (normally W = 2H).
#[derive(Clone, Debug, PartialEq)]
pub struct EnvMap {
    /// Map width in texels (normally 2 x height).
    pub width: u32,
    /// Map height in texels; row 0 is the zenith (+z).
    pub height: u32,
    /// RGB per texel, row-major.
    pub data: Vec<[f32; 3]>,
}

/// Bilinear taps of a lookup: 4 texel indices and weights.
#[derive(Clone, Copy, Debug)]
pub struct Taps {
    /// Texel indices `row * width + col` of the four corners.
    pub index: [u32; 4],
    /// Bilinear weight of each corner; they sum to 1.
    pub weight: [f32; 4],
}

/// Continuous texel coordinates `(fx, fy)` of direction `d` in a `width` x `height` map, clamped
/// to the grid (SPEC 4). Split from [`Taps::at`] so callers with fixed directions can cache them.
#[inline]
pub fn grid_coords(width: u32, height: u32, d: Vec3) -> [f32; 2] {
    let d = d.normalize_or(Vec3::Z);
    let phi = d.z.clamp(-1.0, 1.0).acos();
    let theta = d.y.atan2(d.x);
    let gx = -theta / PI;
    let gy = 2.0 * phi / PI - 1.0;
    let fx = ((gx + 1.0) * 0.5 * (width - 1) as f32).clamp(0.0, (width - 1) as f32);
    let fy = ((gy + 1.0) * 0.5 * (height - 1) as f32).clamp(0.0, (height - 1) as f32);
    [fx, fy]
}

impl Taps {
    /// Taps at clamped continuous coordinates from [`grid_coords`].
    #[inline]
    pub fn at(fx: f32, fy: f32, width: u32, height: u32) -> Taps {
        // fx, fy are finite and >= 0, so truncation is `floor`.
        let (x0, y0) = (fx as u32, fy as u32);
        let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        Taps {
            index: [y0 * width + x0, y0 * width + x1, y1 * width + x0, y1 * width + x1],
            weight: [(1.0 - tx) * (1.0 - ty), tx * (1.0 - ty), (1.0 - tx) * ty, tx * ty],
        }
    }
}

impl EnvMap {
    /// A `width` x `height` map with the same radiance `rgb` in every texel.
    pub fn constant(width: u32, height: u32, rgb: [f32; 3]) -> Self {
        Self { width, height, data: vec![rgb; (width * height) as usize] }
    }

    /// Direction (unit) of texel (row, col) in the aligned-corner grid.
    pub fn texel_dir(&self, row: u32, col: u32) -> Vec3 {
        let gx = -1.0 + 2.0 * col as f32 / (self.width - 1).max(1) as f32;
        let gy = -1.0 + 2.0 * row as f32 / (self.height - 1).max(1) as f32;
        let theta = -gx * PI;
        let phi = 0.5 * PI * (gy + 1.0);
        Vec3::new(phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos())
    }

    /// Solid angle "owned" by texel (row, col): the sphere integral of its bilinear hat function,
    /// so that `sum_t L_t * texel_solid_angle(t)` is exactly the power of the bilinear map over
    /// the sphere (the weights sum to 4 pi). With `dphi = pi/(H-1)`, a row's share is
    /// `sin(phi_r) 2(1 - cos dphi)/dphi` (poles: `1 - sin(dphi)/dphi`), a column's `2pi/(W-1)`
    /// (the two seam columns half each). Used where a texel acts as a directional light.
    pub fn texel_solid_angle(&self, row: u32, col: u32) -> f32 {
        let (w, h) = (self.width.max(2) as f64, self.height.max(2) as f64);
        let dphi = std::f64::consts::PI / (h - 1.0);
        let rows = if row == 0 || row + 1 >= self.height {
            1.0 - dphi.sin() / dphi
        } else {
            (row as f64 * dphi).sin() * 2.0 * (1.0 - dphi.cos()) / dphi
        };
        let dtheta = std::f64::consts::TAU / (w - 1.0);
        let cols = if col == 0 || col + 1 >= self.width { 0.5 * dtheta } else { dtheta };
        (rows * cols) as f32
    }

    /// The four texels and weights of a bilinear lookup (SPEC 4); shared by forward and backward.
    pub fn taps(&self, d: Vec3) -> Taps {
        let [fx, fy] = grid_coords(self.width, self.height, d);
        Taps::at(fx, fy, self.width, self.height)
    }

    /// Radiance arriving from direction `d`.
    pub fn lookup(&self, d: Vec3) -> [f32; 3] {
        let t = self.taps(d);
        let mut c = [0.0; 3];
        for k in 0..4 {
            let v = self.data[t.index[k] as usize];
            for ch in 0..3 {
                c[ch] += t.weight[k] * v[ch];
            }
        }
        c
    }

    /// Resample a pixel-centred equirectangular image (Blender convention, top row = +z) into an
    /// aligned-corner map of `height` x `2 height`, scaling by `strength`. Each target texel
    /// averages the source texels its footprint covers, weighted by overlapping solid angle.
    pub fn from_equirect(img: &Image, strength: f32, height: u32) -> Self {
        assert!(img.channels >= 3 && height >= 2);
        let width = 2 * height;
        let (sw, sh) = (img.width as usize, img.height as usize);
        let dphi = PI / (height - 1) as f32;
        let dtheta = 2.0 * PI / (width - 1) as f32;
        let mut data = vec![[0.0f32; 3]; (width * height) as usize];
        for r in 0..height {
            let phi_c = r as f32 * dphi;
            let (phi_a, phi_b) = ((phi_c - 0.5 * dphi).max(0.0), (phi_c + 0.5 * dphi).min(PI));
            // Source rows: row j covers phi in [j, j+1) * pi / sh.
            let rows = overlap_cells(phi_a / PI * sh as f32, phi_b / PI * sh as f32, sh, false);
            for c in 0..width {
                // theta of column c: theta = -gx*pi with gx = -1 + 2c/(W-1); in Blender's u that
                // is u = 0.5 - theta/(2pi) = c/(W-1).
                let u_c = c as f32 / (width - 1) as f32;
                let du = 0.5 * dtheta / (2.0 * PI);
                let cols = overlap_cells((u_c - du) * sw as f32, (u_c + du) * sw as f32, sw, true);
                let mut acc = [0.0f64; 3];
                let mut wsum = 0.0f64;
                for &(j, a, b) in &rows {
                    // Solid angle of the row band [a, b] (source-row units) is proportional to
                    // cos(phi_a) - cos(phi_b).
                    let pa = a as f64 / sh as f64 * std::f64::consts::PI;
                    let pb = b as f64 / sh as f64 * std::f64::consts::PI;
                    let wr = pa.cos() - pb.cos();
                    for &(i, ca, cb) in &cols {
                        let w = wr * (cb - ca) as f64;
                        let p = img.pixel(i as u32, j as u32);
                        for ch in 0..3 {
                            acc[ch] += w * p[ch] as f64;
                        }
                        wsum += w;
                    }
                }
                let t = &mut data[(r * width + c) as usize];
                for ch in 0..3 {
                    t[ch] = if wsum > 0.0 { (acc[ch] / wsum) as f32 * strength } else { 0.0 };
                }
            }
        }
        Self { width, height, data }
    }

    /// The map as an RGB image (row 0 = zenith), e.g. for writing to `.hdr`.
    pub fn to_image(&self) -> Image {
        let data = self.data.iter().flat_map(|p| p.iter().copied()).collect();
        Image::from_data(self.width, self.height, 3, data)
    }

    /// Mean radiance weighted by solid angle (a quick brightness summary).
    pub fn mean_radiance(&self) -> [f32; 3] {
        let mut acc = [0.0f64; 3];
        let mut wsum = 0.0;
        for r in 0..self.height {
            let phi = PI * r as f32 / (self.height - 1) as f32;
            let w = phi.sin().max(1e-3) as f64;
            for c in 0..self.width {
                let p = self.data[(r * self.width + c) as usize];
                for ch in 0..3 {
                    acc[ch] += w * p[ch] as f64;
                }
                wsum += w;
            }
        }
        acc.map(|a| (a / wsum) as f32)
    }
}

/// Cells of a 1-D grid of `n` unit cells overlapped by the interval [a, b] as (index, start, end);
/// with `wrap` the grid is periodic.
fn overlap_cells(a: f32, b: f32, n: usize, wrap: bool) -> Vec<(usize, f32, f32)> {
    let mut out = Vec::new();
    let mut x = a;
    while x < b - 1e-6 {
        let cell = x.floor();
        let end = (cell + 1.0).min(b);
        let idx = if wrap { (cell as i64).rem_euclid(n as i64) as usize } else { (cell.max(0.0) as usize).min(n - 1) };
        out.push((idx, x, end));
        x = end;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_directions_round_trip_through_lookup() {
        let mut m = EnvMap::constant(16, 8, [0.0; 3]);
        for (i, t) in m.data.iter_mut().enumerate() {
            *t = [i as f32, 0.0, 0.0];
        }
        for r in 1..7 {
            for c in 1..15 {
                let d = m.texel_dir(r, c);
                let v = m.lookup(d)[0];
                assert!((v - (r * 16 + c) as f32).abs() < 1e-2, "r={r} c={c} v={v}");
            }
        }
        // Zenith is row 0, +x (theta = 0) is the middle column.
        assert!(m.texel_dir(0, 3).z > 0.999);
        let d = m.texel_dir(4, 0);
        assert!(d.x < -0.9, "seam faces -x: {d}");
    }

    #[test]
    fn texel_solid_angles_are_the_power_of_each_bilinear_hat() {
        let mut m = EnvMap::constant(16, 8, [0.0; 3]);
        let total: f64 =
            (0..8).flat_map(|r| (0..16).map(move |c| (r, c))).map(|(r, c)| m.texel_solid_angle(r, c) as f64).sum();
        assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-4, "{total}");
        // Brute-force sphere integral of a one-hot map's bilinear lookup (midpoint rule in
        // (phi, theta)), for a pole, an interior and a seam texel.
        for (r, c) in [(0u32, 5u32), (3, 7), (5, 0), (7, 15)] {
            m.data.iter_mut().for_each(|t| *t = [0.0; 3]);
            m.data[(r * 16 + c) as usize] = [1.0; 3];
            let (nphi, nth) = (800, 1600);
            let mut acc = 0.0f64;
            for i in 0..nphi {
                let phi = (i as f64 + 0.5) / nphi as f64 * std::f64::consts::PI;
                for j in 0..nth {
                    let th = (j as f64 + 0.5) / nth as f64 * std::f64::consts::TAU - std::f64::consts::PI;
                    let d = Vec3::new((phi.sin() * th.cos()) as f32, (phi.sin() * th.sin()) as f32, phi.cos() as f32);
                    acc += m.lookup(d)[0] as f64 * phi.sin();
                }
            }
            acc *= std::f64::consts::PI / nphi as f64 * std::f64::consts::TAU / nth as f64;
            let want = m.texel_solid_angle(r, c) as f64;
            assert!((acc - want).abs() < 2e-3 * want.max(1e-3), "texel ({r},{c}): {acc} vs {want}");
        }
    }

    #[test]
    fn equirect_conversion_matches_blender_convention() {
        // A source map that is bright only in the quadrant around +y (theta = pi/2), upper half.
        let (w, h) = (256, 128);
        let mut img = Image::new(w, h, 3);
        for j in 0..h {
            for i in 0..w {
                let u = (i as f32 + 0.5) / w as f32;
                let v_top = (j as f32 + 0.5) / h as f32;
                let theta = (0.5 - u) * 2.0 * PI;
                let z = (0.5 * PI - v_top * PI).sin();
                let d = Vec3::new(theta.cos() * (1.0 - z * z).sqrt(), theta.sin() * (1.0 - z * z).sqrt(), z);
                img.pixel_mut(i, j).copy_from_slice(&[d.x.max(0.0), d.y.max(0.0), d.z.max(0.0)]);
            }
        }
        let m = EnvMap::from_equirect(&img, 2.0, 32);
        for d in [Vec3::new(0.6, 0.3, 0.74), Vec3::new(-0.2, 0.9, -0.3), Vec3::new(0.1, -0.8, 0.5)] {
            let d = d.normalize();
            let got = m.lookup(d);
            let want = [2.0 * d.x.max(0.0), 2.0 * d.y.max(0.0), 2.0 * d.z.max(0.0)];
            for ch in 0..3 {
                assert!((got[ch] - want[ch]).abs() < 0.08, "{d}: {got:?} vs {want:?}");
            }
        }
        // Energy: a constant map stays constant.
        let flat = EnvMap::from_equirect(&Image::filled(64, 32, &[1.0, 2.0, 3.0]), 1.0, 8);
        assert!(flat.data.iter().all(|p| (p[0] - 1.0).abs() < 1e-4 && (p[2] - 3.0).abs() < 1e-4));
    }
}
