//! Real spherical harmonics up to degree 3 in the basis and sign convention of 3DGS, so PLY files
//! interoperate with its viewers. A Gaussian's radiance towards direction `d` (unit, from the
//! camera to the Gaussian in 3DGS; callers pass whichever SPEC says) is
//! `max(0, 0.5 + sum_k basis_k(d) * coeff_k)`; the +0.5 offset and clamp live in the renderers.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// Degree-0 SH basis constant `1 / (2 sqrt(pi))`.
pub const SH_C0: f32 = 0.282_094_8;
/// Degree-1 SH basis constant (3DGS).
pub const SH_C1: f32 = 0.488_602_52;
/// Degree-2 SH basis constants (3DGS order).
pub const SH_C2: [f32; 5] = [1.092_548_5, -1.092_548_5, 0.315_391_57, -1.092_548_5, 0.546_274_24];
/// Degree-3 SH basis constants (3DGS order).
pub const SH_C3: [f32; 7] =
    [-0.590_043_6, 2.890_611_4, -0.457_045_8, 0.373_176_34, -0.457_045_8, 1.445_305_7, -0.590_043_6];

/// Number of coefficients per colour channel for a degree.
pub const fn num_coeffs(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// Degree-3 SH coefficients of one Gaussian, `[k][rgb]`; unused higher bands stay zero.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct ShCoeffs(pub [[f32; 3]; 16]);

impl Default for ShCoeffs {
    fn default() -> Self {
        Self([[0.0; 3]; 16])
    }
}

impl ShCoeffs {
    /// Coefficients whose DC band gives `rgb` (before the clamp).
    pub fn from_rgb(rgb: [f32; 3]) -> Self {
        let mut s = Self::default();
        s.0[0] = rgb.map(rgb_to_dc);
        s
    }

    /// `0.5 + sum basis * coeff` (no clamp) for the first `degree` bands.
    pub fn eval(&self, degree: u32, dir: Vec3) -> [f32; 3] {
        let mut b = [0.0; 16];
        basis(degree, dir, &mut b);
        let mut c = [0.5f32; 3];
        for k in 0..num_coeffs(degree) {
            for ch in 0..3 {
                c[ch] += b[k] * self.0[k][ch];
            }
        }
        c
    }
}

/// The DC coefficient whose radiance `0.5 + SH_C0 dc` equals colour `c`.
pub fn rgb_to_dc(c: f32) -> f32 {
    (c - 0.5) / SH_C0
}

/// Evaluate the SH basis for a unit direction into `out[0..num_coeffs(degree)]`.
pub fn basis(degree: u32, d: Vec3, out: &mut [f32; 16]) {
    let (x, y, z) = (d.x, d.y, d.z);
    out[0] = SH_C0;
    if degree < 1 {
        return;
    }
    out[1] = -SH_C1 * y;
    out[2] = SH_C1 * z;
    out[3] = -SH_C1 * x;
    if degree < 2 {
        return;
    }
    let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
    out[4] = SH_C2[0] * xy;
    out[5] = SH_C2[1] * yz;
    out[6] = SH_C2[2] * (2.0 * zz - xx - yy);
    out[7] = SH_C2[3] * xz;
    out[8] = SH_C2[4] * (xx - yy);
    if degree < 3 {
        return;
    }
    out[9] = SH_C3[0] * y * (3.0 * xx - yy);
    out[10] = SH_C3[1] * xy * z;
    out[11] = SH_C3[2] * y * (4.0 * zz - xx - yy);
    out[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    out[13] = SH_C3[4] * x * (4.0 * zz - xx - yy);
    out[14] = SH_C3[5] * z * (xx - yy);
    out[15] = SH_C3[6] * x * (xx - 3.0 * yy);
}

/// Jacobian of [`basis`] with respect to the (unnormalised-treated-as-free) direction components:
/// `out[k] = d basis_k / d (x, y, z)`.
pub fn basis_grad(degree: u32, d: Vec3, out: &mut [Vec3; 16]) {
    let (x, y, z) = (d.x, d.y, d.z);
    out[0] = Vec3::ZERO;
    if degree < 1 {
        return;
    }
    out[1] = Vec3::new(0.0, -SH_C1, 0.0);
    out[2] = Vec3::new(0.0, 0.0, SH_C1);
    out[3] = Vec3::new(-SH_C1, 0.0, 0.0);
    if degree < 2 {
        return;
    }
    out[4] = SH_C2[0] * Vec3::new(y, x, 0.0);
    out[5] = SH_C2[1] * Vec3::new(0.0, z, y);
    out[6] = SH_C2[2] * Vec3::new(-2.0 * x, -2.0 * y, 4.0 * z);
    out[7] = SH_C2[3] * Vec3::new(z, 0.0, x);
    out[8] = SH_C2[4] * Vec3::new(2.0 * x, -2.0 * y, 0.0);
    if degree < 3 {
        return;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    out[9] = SH_C3[0] * Vec3::new(6.0 * x * y, 3.0 * xx - 3.0 * yy, 0.0);
    out[10] = SH_C3[1] * Vec3::new(y * z, x * z, x * y);
    out[11] = SH_C3[2] * Vec3::new(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z);
    out[12] = SH_C3[3] * Vec3::new(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy);
    out[13] = SH_C3[4] * Vec3::new(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z);
    out[14] = SH_C3[5] * Vec3::new(2.0 * x * z, -2.0 * y * z, xx - yy);
    out[15] = SH_C3[6] * Vec3::new(3.0 * xx - 3.0 * yy, -6.0 * x * y, 0.0);
}

/// `f64` twin of [`basis`], for the finite-difference checks and the reference kernels (a test
/// asserts the two agree).
pub fn basis_f64(degree: u32, d: [f64; 3], out: &mut [f64; 16]) {
    let c = |v: f32| v as f64;
    let [x, y, z] = d;
    out[0] = c(SH_C0);
    if degree < 1 {
        return;
    }
    out[1] = -c(SH_C1) * y;
    out[2] = c(SH_C1) * z;
    out[3] = -c(SH_C1) * x;
    if degree < 2 {
        return;
    }
    let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
    out[4] = c(SH_C2[0]) * xy;
    out[5] = c(SH_C2[1]) * yz;
    out[6] = c(SH_C2[2]) * (2.0 * zz - xx - yy);
    out[7] = c(SH_C2[3]) * xz;
    out[8] = c(SH_C2[4]) * (xx - yy);
    if degree < 3 {
        return;
    }
    out[9] = c(SH_C3[0]) * y * (3.0 * xx - yy);
    out[10] = c(SH_C3[1]) * xy * z;
    out[11] = c(SH_C3[2]) * y * (4.0 * zz - xx - yy);
    out[12] = c(SH_C3[3]) * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    out[13] = c(SH_C3[4]) * x * (4.0 * zz - xx - yy);
    out[14] = c(SH_C3[5]) * z * (xx - yy);
    out[15] = c(SH_C3[6]) * x * (xx - 3.0 * yy);
}

/// `f64` twin of [`basis_grad`] (see [`basis_f64`]).
pub fn basis_grad_f64(degree: u32, d: [f64; 3], out: &mut [[f64; 3]; 16]) {
    let c = |v: f32| v as f64;
    let [x, y, z] = d;
    let s = |k: f64, v: [f64; 3]| [k * v[0], k * v[1], k * v[2]];
    out[0] = [0.0; 3];
    if degree < 1 {
        return;
    }
    out[1] = [0.0, -c(SH_C1), 0.0];
    out[2] = [0.0, 0.0, c(SH_C1)];
    out[3] = [-c(SH_C1), 0.0, 0.0];
    if degree < 2 {
        return;
    }
    out[4] = s(c(SH_C2[0]), [y, x, 0.0]);
    out[5] = s(c(SH_C2[1]), [0.0, z, y]);
    out[6] = s(c(SH_C2[2]), [-2.0 * x, -2.0 * y, 4.0 * z]);
    out[7] = s(c(SH_C2[3]), [z, 0.0, x]);
    out[8] = s(c(SH_C2[4]), [2.0 * x, -2.0 * y, 0.0]);
    if degree < 3 {
        return;
    }
    let (xx, yy, zz) = (x * x, y * y, z * z);
    out[9] = s(c(SH_C3[0]), [6.0 * x * y, 3.0 * xx - 3.0 * yy, 0.0]);
    out[10] = s(c(SH_C3[1]), [y * z, x * z, x * y]);
    out[11] = s(c(SH_C3[2]), [-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z]);
    out[12] = s(c(SH_C3[3]), [-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy]);
    out[13] = s(c(SH_C3[4]), [4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z]);
    out[14] = s(c(SH_C3[5]), [2.0 * x * z, -2.0 * y * z, xx - yy]);
    out[15] = s(c(SH_C3[6]), [3.0 * xx - 3.0 * yy, -6.0 * x * y, 0.0]);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Closed forms of the real SH (Condon-Shortley phase folded into 3DGS's signs).
    #[test]
    fn basis_matches_closed_form() {
        let d = Vec3::new(0.3, -0.5, 0.81).normalize();
        let mut b = [0.0; 16];
        basis(3, d, &mut b);
        let pi = std::f32::consts::PI;
        assert!((b[0] - 0.5 / pi.sqrt()).abs() < 1e-6);
        assert!((b[2] - (3.0 / (4.0 * pi)).sqrt() * d.z).abs() < 1e-6);
        assert!((b[6] - 0.25 * (5.0 / pi).sqrt() * (3.0 * d.z * d.z - 1.0)).abs() < 1e-5);
        assert!((b[12] - 0.25 * (7.0 / pi).sqrt() * d.z * (5.0 * d.z * d.z - 3.0)).abs() < 1e-5);
    }

    #[test]
    fn basis_is_orthonormal_on_the_sphere() {
        // Monte-Carlo-free check: integrate over a fine Fibonacci sphere.
        let n = 20000;
        let mut gram = [[0.0f64; 16]; 16];
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        for i in 0..n {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            let d = Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
            let mut b = [0.0; 16];
            basis(3, d, &mut b);
            for a in 0..16 {
                for c in 0..16 {
                    gram[a][c] += b[a] as f64 * b[c] as f64 * 4.0 * std::f64::consts::PI / n as f64;
                }
            }
        }
        for a in 0..16 {
            for c in 0..16 {
                let want = if a == c { 1.0 } else { 0.0 };
                assert!((gram[a][c] - want).abs() < 2e-3, "gram[{a}][{c}] = {}", gram[a][c]);
            }
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let d = Vec3::new(0.2, 0.7, -0.4);
        let mut g = [Vec3::ZERO; 16];
        basis_grad(3, d, &mut g);
        let h = 1e-3;
        for axis in 0..3 {
            let mut e = Vec3::ZERO;
            e[axis] = h;
            let (mut bp, mut bm) = ([0.0; 16], [0.0; 16]);
            basis(3, d + e, &mut bp);
            basis(3, d - e, &mut bm);
            for k in 0..16 {
                let fd = (bp[k] - bm[k]) / (2.0 * h);
                assert!((fd - g[k][axis]).abs() < 1e-3, "k={k} axis={axis}: {fd} vs {}", g[k][axis]);
            }
        }
    }
}
