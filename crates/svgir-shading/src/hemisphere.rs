//! Fibonacci hemisphere directions (SPEC 4): the K shading/tracing directions of a Gaussian.
//!
//! In the local frame of the geometric normal n: `z_k = max(1 - 2k/(2K-1), sin 10deg)`,
//! `phi_k = k pi (3 - sqrt5) + xi`, `d_k = (sqrt(1-z_k^2) cos phi_k, sqrt(1-z_k^2) sin phi_k, z_k)`,
//! k = 0..K-1, each carrying solid-angle weight 2pi/K. `xi` is drawn once per Gaussian
//! ([`gaussian_xi`]), so the rasteriser, the tracer and the gather all regenerate identical
//! directions from (n, K, xi) instead of storing them.
//!
//! Frame: [`tangent_frame`] is the branchless orthonormal basis of Duff et al. 2017 ("Building an
//! Orthonormal Basis, Revisited"): no normalisation, no singularity anywhere on the sphere, and
//! exactly orthonormal up to rounding. It is continuous except across the plane n.z = 0, where the
//! sign switch rotates the tangents about n; that only re-rolls the azimuth, which `xi` randomises
//! anyway, so no estimator is biased by it. `phi_k` is reduced modulo 2pi in f64 first so that
//! K = 384 directions keep full f32 accuracy.

use glam::Vec3;
use std::f64::consts::PI;
use svgir_core::Rng;

/// sin(10 degrees): the lowest elevation a direction may have (SPEC 4).
pub const MIN_ELEVATION_SIN: f32 = 0.173_648_18;

/// Tangents (b1, b2) with (b1, b2, n) a right-handed orthonormal basis (Duff et al. 2017).
#[inline]
pub fn tangent_frame(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let b1 = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let b2 = Vec3::new(b, sign + n.y * n.y * a, -n.y);
    (b1, b2)
}

/// Direction `k` of `count` in the local frame (z = normal).
#[inline]
pub fn fibonacci_local(k: usize, count: usize, xi: f32) -> Vec3 {
    let z = (1.0 - 2.0 * k as f32 / (2 * count - 1) as f32).max(MIN_ELEVATION_SIN);
    let golden = PI * (3.0 - 5f64.sqrt());
    let phi = (k as f64 * golden).rem_euclid(2.0 * PI) as f32 + xi;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = phi.sin_cos();
    Vec3::new(r * c, r * s, z)
}

/// World direction `k` of `count` around the unit normal `n`.
#[inline]
pub fn hemisphere_dir(n: Vec3, k: usize, count: usize, xi: f32) -> Vec3 {
    let (b1, b2) = tangent_frame(n);
    let d = fibonacci_local(k, count, xi);
    b1 * d.x + b2 * d.y + n * d.z
}

/// The K Fibonacci directions of SPEC 4 in the local frame *without* the per-Gaussian azimuth:
/// `z_k`, `sqrt(1 - z_k^2)` and the cosine / sine of `g_k = k pi (3 - sqrt5) mod 2pi`. Rotating
/// by `xi_i` per Gaussian ([`HemiFrame::dir`]) reproduces [`hemisphere_dir`] up to f32 rounding
/// (~1e-7) without a sine, cosine and f64 remainder per sample.
pub struct FibTable {
    z: Vec<f32>,
    r: Vec<f32>,
    c: Vec<f32>,
    s: Vec<f32>,
}

impl FibTable {
    /// The table's rows `[cos g_k, sin g_k, r_k, z_k]` (lane kernels read them directly).
    pub fn rows(&self) -> [&[f32]; 4] {
        [&self.c, &self.s, &self.r, &self.z]
    }

    /// Number of directions.
    pub fn len(&self) -> usize {
        self.z.len()
    }

    /// Whether the table is empty.
    pub fn is_empty(&self) -> bool {
        self.z.is_empty()
    }

    /// The table for `count` directions.
    pub fn new(count: usize) -> Self {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let z: Vec<f32> =
            (0..count).map(|k| (1.0 - 2.0 * k as f32 / (2 * count - 1) as f32).max(MIN_ELEVATION_SIN)).collect();
        let r = z.iter().map(|z| (1.0 - z * z).max(0.0).sqrt()).collect();
        let g: Vec<f64> = (0..count).map(|k| (k as f64 * golden).rem_euclid(std::f64::consts::TAU)).collect();
        Self { z, r, c: g.iter().map(|g| g.cos() as f32).collect(), s: g.iter().map(|g| g.sin() as f32).collect() }
    }

    /// Rows `phase, phase + stride, ..` of the table for `count` directions (`count / stride`
    /// rows, each with the bits of the full table's row): one of the `stride` interleaved
    /// subsets that an iteration may shade in place of all `count` directions.
    pub fn interleaved(count: usize, stride: usize, phase: usize) -> Self {
        let full = Self::new(count);
        if stride <= 1 {
            return full;
        }
        let pick = |v: &[f32]| v.iter().skip(phase).step_by(stride).copied().collect();
        Self { z: pick(&full.z), r: pick(&full.r), c: pick(&full.c), s: pick(&full.s) }
    }
}

/// One Gaussian's hemisphere frame: its normal, tangents and azimuth offset `xi`, so that
/// `dir(table, k)` equals `hemisphere_dir(n, k, count, xi)` up to f32 rounding.
pub struct HemiFrame {
    b1: Vec3,
    b2: Vec3,
    n: Vec3,
    cx: f32,
    sx: f32,
}

impl HemiFrame {
    /// The frame about unit normal `n` with azimuth offset `xi`.
    #[inline]
    pub fn new(n: Vec3, xi: f32) -> Self {
        let (b1, b2) = tangent_frame(n);
        let (sx, cx) = xi.sin_cos();
        Self { b1, b2, n, cx, sx }
    }

    /// `(b1, b2, n, cos xi, sin xi)`: what [`HemiFrame::dir`] combines (for lane kernels).
    pub fn parts(&self) -> (Vec3, Vec3, Vec3, f32, f32) {
        (self.b1, self.b2, self.n, self.cx, self.sx)
    }

    /// Direction k: `b1 r cos(g_k + xi) + b2 r sin(g_k + xi) + n z`.
    #[inline]
    pub fn dir(&self, t: &FibTable, k: usize) -> Vec3 {
        let c = t.c[k] * self.cx - t.s[k] * self.sx;
        let s = t.s[k] * self.cx + t.c[k] * self.sx;
        self.b1 * (t.r[k] * c) + self.b2 * (t.r[k] * s) + self.n * t.z[k]
    }
}

/// The per-Gaussian azimuth offset `xi_j` in [0, 2pi), a pure function of (seed, j).
#[inline]
pub fn gaussian_xi(seed: u64, j: usize) -> f32 {
    Rng::new(seed).fork(j as u64).uniform() * std::f32::consts::TAU
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_everywhere() {
        let mut rng = Rng::new(1);
        let mut ns = vec![Vec3::Z, -Vec3::Z, Vec3::X, -Vec3::Y, Vec3::new(0.0, 1e-8, -1.0).normalize()];
        for _ in 0..1000 {
            ns.push(Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize());
        }
        for n in ns {
            let (b1, b2) = tangent_frame(n);
            assert!((b1.length() - 1.0).abs() < 1e-5 && (b2.length() - 1.0).abs() < 1e-5, "{n}");
            assert!(b1.dot(b2).abs() < 1e-5 && b1.dot(n).abs() < 1e-5 && b2.dot(n).abs() < 1e-5, "{n}");
            assert!((b1.cross(b2) - n).length() < 1e-5, "right-handed at {n}");
        }
    }

    #[test]
    fn directions_are_unit_on_the_hemisphere_and_distinct() {
        let mut rng = Rng::new(2);
        for &count in &[16usize, 64, 384] {
            for j in 0..20 {
                let n = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
                let xi = gaussian_xi(42, j);
                assert!((0.0..std::f32::consts::TAU).contains(&xi));
                let dirs: Vec<Vec3> = (0..count).map(|k| hemisphere_dir(n, k, count, xi)).collect();
                assert!((dirs[0] - n).length() < 1e-5, "k = 0 is the normal");
                for (k, d) in dirs.iter().enumerate() {
                    assert!((d.length() - 1.0).abs() < 1e-5);
                    assert!(d.dot(n) >= MIN_ELEVATION_SIN - 1e-5, "k={k} below 10 degrees");
                    let want_z = (1.0 - 2.0 * k as f32 / (2 * count - 1) as f32).max(MIN_ELEVATION_SIN);
                    assert!((d.dot(n) - want_z).abs() < 1e-5);
                }
                let mut min_sep = f32::MAX;
                for a in 0..count {
                    for b in 0..a {
                        min_sep = min_sep.min((dirs[a] - dirs[b]).length());
                    }
                }
                assert!(min_sep > 1e-3, "K={count}: two directions coincide ({min_sep})");
            }
        }
        // Roughly uniform over the hemisphere: the mean direction of K = 384 is near n/2.
        let n = Vec3::new(0.3, -0.2, 0.9).normalize();
        let mean = (0..384).map(|k| hemisphere_dir(n, k, 384, 1.0)).sum::<Vec3>() / 384.0;
        assert!((mean.dot(n) - 0.5).abs() < 0.05 && (mean - mean.dot(n) * n).length() < 0.02, "{mean}");
    }

    #[test]
    fn interleaved_rows_are_the_full_tables_rows() {
        let full = FibTable::new(64);
        for phase in 0..4 {
            let sub = FibTable::interleaved(64, 4, phase);
            assert_eq!(sub.len(), 16);
            for (j, row) in (0..4).map(|r| sub.rows()[r]).enumerate() {
                let want: Vec<u32> = full.rows()[j].iter().skip(phase).step_by(4).map(|x| x.to_bits()).collect();
                assert_eq!(row.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), want, "row {j}, phase {phase}");
            }
        }
        assert_eq!(FibTable::interleaved(64, 1, 0).rows(), full.rows());
    }

    #[test]
    fn xi_is_reproducible_and_varies() {
        assert_eq!(gaussian_xi(7, 3), gaussian_xi(7, 3));
        assert_ne!(gaussian_xi(7, 3), gaussian_xi(7, 4));
        assert_ne!(gaussian_xi(7, 3), gaussian_xi(8, 3));
    }
}
