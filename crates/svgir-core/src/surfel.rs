//! Gaussian surfels (SPEC 1) in structure-of-arrays form: one `Vec` per attribute, indexed by
//! Gaussian, so kernels stream only the attributes they read and a GPU backend can upload each
//! array as-is (all element types are `Pod`).
//!
//! Stored values are the optimiser's raw parameters; activations are applied by the accessors:
//! scale = exp(log_scale), opacity = sigmoid(logit), rotation = normalize(quaternion).

use crate::sh::ShCoeffs;
use glam::{Mat3, Quat, Vec2, Vec3};
use rayon::prelude::*;

/// N Gaussian surfels (SPEC 1) as raw optimiser parameters, one array per attribute.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Surfels {
    /// Centres `p` in world space.
    pub positions: Vec<Vec3>,
    /// Unnormalised rotation quaternions (glam order x, y, z, w). Columns of the rotation are
    /// the tangent axes t_u, t_v and the normal n.
    pub rotations: Vec<Quat>,
    /// Log of the two tangent-axis standard deviations; the third scale is 0 by construction.
    pub log_scales: Vec<Vec2>,
    /// Opacity before the sigmoid.
    pub opacity_logits: Vec<f32>,
    /// View-dependent radiance, degree 3 storage.
    pub sh: Vec<ShCoeffs>,
    /// Active SH degree (0..=3).
    pub sh_degree: u32,
}

/// Logistic function `1 / (1 + e^-x)`.
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Inverse of [`sigmoid`], with `p` clamped to [1e-6, 1 - 1e-6].
#[inline]
pub fn logit(p: f32) -> f32 {
    let p = p.clamp(1e-6, 1.0 - 1e-6);
    (p / (1.0 - p)).ln()
}

impl Surfels {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// No Gaussians, room for `n`, SH degree `sh_degree`.
    pub fn with_capacity(n: usize, sh_degree: u32) -> Self {
        Self {
            positions: Vec::with_capacity(n),
            rotations: Vec::with_capacity(n),
            log_scales: Vec::with_capacity(n),
            opacity_logits: Vec::with_capacity(n),
            sh: Vec::with_capacity(n),
            sh_degree,
        }
    }

    /// Append one Gaussian given its raw parameters.
    pub fn push(&mut self, position: Vec3, rotation: Quat, log_scale: Vec2, opacity_logit: f32, sh: ShCoeffs) {
        self.positions.push(position);
        self.rotations.push(rotation);
        self.log_scales.push(log_scale);
        self.opacity_logits.push(opacity_logit);
        self.sh.push(sh);
    }

    /// Append `other`'s Gaussians after these (this set's SH degree stays).
    pub fn extend_from(&mut self, other: &Surfels) {
        self.positions.extend_from_slice(&other.positions);
        self.rotations.extend_from_slice(&other.rotations);
        self.log_scales.extend_from_slice(&other.log_scales);
        self.opacity_logits.extend_from_slice(&other.opacity_logits);
        self.sh.extend_from_slice(&other.sh);
    }

    /// Keep only Gaussians where `keep[i]` (pruning).
    pub fn retain(&mut self, keep: &[bool]) {
        assert_eq!(keep.len(), self.len());
        fn filter<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
            let mut i = 0;
            v.retain(|_| {
                i += 1;
                keep[i - 1]
            });
        }
        filter(&mut self.positions, keep);
        filter(&mut self.rotations, keep);
        filter(&mut self.log_scales, keep);
        filter(&mut self.opacity_logits, keep);
        filter(&mut self.sh, keep);
    }

    /// The Gaussians in the order `order`, a permutation of `0..len` (Gaussian `order[j]`
    /// becomes Gaussian `j`).
    pub fn reorder(&mut self, order: &[usize]) {
        let mut seen = vec![false; self.len()];
        assert!(
            order.len() == self.len()
                && order.iter().all(|&i| i < seen.len() && !std::mem::replace(&mut seen[i], true)),
            "reorder needs a permutation of 0..{}",
            self.len()
        );
        fn take<T: Copy>(v: &mut Vec<T>, order: &[usize]) {
            *v = order.iter().map(|&i| v[i]).collect();
        }
        take(&mut self.positions, order);
        take(&mut self.rotations, order);
        take(&mut self.log_scales, order);
        take(&mut self.opacity_logits, order);
        take(&mut self.sh, order);
    }

    /// Put the Gaussians in Morton order of their centres over their bounds
    /// ([`crate::morton`]), so that the ones a view sees lie in runs of every per-Gaussian
    /// array; returns the permutation applied (as [`Self::reorder`] takes it) for arrays kept
    /// beside the surfels.
    pub fn sort_morton(&mut self) -> Vec<usize> {
        let order = match self.bounds() {
            Some((lo, hi)) => crate::morton::morton_order(&self.positions, lo, hi),
            None => Vec::new(),
        };
        self.reorder(&order);
        order
    }

    /// All arrays have the same length and every value is finite.
    pub fn check(&self) -> Result<(), String> {
        let n = self.len();
        if self.rotations.len() != n
            || self.log_scales.len() != n
            || self.opacity_logits.len() != n
            || self.sh.len() != n
        {
            return Err("surfel attribute arrays differ in length".into());
        }
        if self.sh_degree > 3 {
            return Err(format!("SH degree {} > 3", self.sh_degree));
        }
        // Fast path, run on every render: a value is finite unless its exponent bits are all
        // set; OR-ing that test over a chunk is branch-free integer work the compiler vectorises
        // (a float fold would be one serial add per value), in parallel: the SH alone are 19 MB
        // at 100k Gaussians, read at memory speed.
        let all_finite = |v: &[f32]| {
            let bits: &[u32] = bytemuck::cast_slice(v);
            bits.par_chunks(1 << 14)
                .all(|c| c.iter().fold(0u32, |a, &b| a | ((b & 0x7f80_0000) == 0x7f80_0000) as u32) == 0)
        };
        let fast_ok = all_finite(bytemuck::cast_slice(&self.positions))
            && all_finite(bytemuck::cast_slice(&self.rotations))
            && all_finite(bytemuck::cast_slice(&self.log_scales))
            && all_finite(&self.opacity_logits)
            && all_finite(bytemuck::cast_slice(&self.sh))
            && self.rotations.iter().fold(true, |ok, q| ok & (q.length_squared() > 0.0));
        if fast_ok {
            return Ok(());
        }
        for i in 0..n {
            let ok = self.positions[i].is_finite()
                && self.rotations[i].is_finite()
                && self.rotations[i].length_squared() > 0.0
                && self.log_scales[i].is_finite()
                && self.opacity_logits[i].is_finite()
                && self.sh[i].0.iter().flatten().all(|v| v.is_finite());
            if !ok {
                return Err(format!("Gaussian {i} has a non-finite or zero parameter"));
            }
        }
        Ok(())
    }

    /// Tangent standard deviations (s_u, s_v) of Gaussian i, world units (exp of the raw value).
    pub fn scale(&self, i: usize) -> Vec2 {
        Vec2::new(self.log_scales[i].x.exp(), self.log_scales[i].y.exp())
    }

    /// Opacity of Gaussian i in (0, 1) (sigmoid of the raw logit).
    pub fn opacity(&self, i: usize) -> f32 {
        sigmoid(self.opacity_logits[i])
    }

    /// Rotation matrix `[t_u t_v n]`.
    pub fn rotation_matrix(&self, i: usize) -> Mat3 {
        Mat3::from_quat(self.rotations[i].normalize())
    }

    /// Unit normal n of Gaussian i (third column of its rotation).
    pub fn normal(&self, i: usize) -> Vec3 {
        self.rotation_matrix(i).z_axis
    }

    /// World position of tangent coordinates (u, v) in sigma units (SPEC 1).
    pub fn local_to_world(&self, i: usize, u: f32, v: f32) -> Vec3 {
        let r = self.rotation_matrix(i);
        let s = self.scale(i);
        self.positions[i] + s.x * u * r.x_axis + s.y * v * r.y_axis
    }

    /// Axis-aligned bounds of all centres.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.positions.first()?;
        Some(self.positions.iter().fold((first, first), |(lo, hi), p| (lo.min(*p), hi.max(*p))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accessors_and_retain() {
        let mut s = Surfels::with_capacity(2, 0);
        let q = Quat::from_rotation_x(0.5) * 3.0;
        s.push(Vec3::X, q, Vec2::new(0.0, 1.0_f32.ln()), 0.0, ShCoeffs::from_rgb([0.2, 0.4, 0.6]));
        s.push(Vec3::Y, Quat::IDENTITY, Vec2::ZERO, logit(0.9), ShCoeffs::default());
        assert!((s.opacity(0) - 0.5).abs() < 1e-6);
        assert!((s.opacity(1) - 0.9).abs() < 1e-5);
        let n = s.normal(0);
        assert!((n - Vec3::new(0.0, -(0.5f32).sin(), 0.5f32.cos())).length() < 1e-5);
        let c = s.sh[0].eval(0, Vec3::Z);
        assert!((c[1] - 0.4).abs() < 1e-6);
        s.retain(&[false, true]);
        assert_eq!(s.len(), 1);
        assert_eq!(s.positions[0], Vec3::Y);
        assert!(s.check().is_ok());
    }

    /// Every array follows the permutation; a list that is not one is refused.
    #[test]
    fn reorder_moves_every_array() {
        let mut s = Surfels::with_capacity(3, 0);
        for i in 0..3 {
            let f = i as f32;
            s.push(Vec3::splat(f), Quat::from_rotation_z(f), Vec2::splat(-f), f, ShCoeffs::from_rgb([f / 4.0; 3]));
        }
        let want = |s: &Surfels, j: usize, i: usize| {
            let f = i as f32;
            s.positions[j] == Vec3::splat(f)
                && s.rotations[j] == Quat::from_rotation_z(f)
                && s.log_scales[j] == Vec2::splat(-f)
                && s.opacity_logits[j] == f
                && s.sh[j] == ShCoeffs::from_rgb([f / 4.0; 3])
        };
        s.reorder(&[2, 0, 1]);
        assert!(want(&s, 0, 2) && want(&s, 1, 0) && want(&s, 2, 1));
        for bad in [vec![0, 0, 1], vec![0, 1], vec![0, 1, 3]] {
            let mut t = s.clone();
            assert!(std::panic::catch_unwind(move || t.reorder(&bad)).is_err());
        }
    }

    #[test]
    fn check_names_the_first_bad_gaussian() {
        let mut s = Surfels::with_capacity(600, 3);
        for i in 0..600 {
            s.push(Vec3::splat(i as f32 * 1e30), Quat::IDENTITY, Vec2::ZERO, -3.0, ShCoeffs::default());
        }
        assert!(s.check().is_ok(), "large finite values are fine");
        type Spoil = fn(&mut Surfels, usize);
        let bad: [(usize, Spoil); 6] = [
            (7, |s, i| s.positions[i].y = f32::INFINITY),
            (300, |s, i| s.rotations[i] = Quat::from_xyzw(0.0, 0.0, 0.0, 0.0)),
            (301, |s, i| s.rotations[i].x = f32::NAN),
            (512, |s, i| s.log_scales[i].x = f32::NEG_INFINITY),
            (599, |s, i| s.opacity_logits[i] = f32::NAN),
            (42, |s, i| s.sh[i].0[15][2] = f32::INFINITY),
        ];
        for (i, spoil) in bad {
            let mut t = s.clone();
            spoil(&mut t, i);
            let e = t.check().unwrap_err();
            assert!(e.contains(&format!("Gaussian {i} ")), "{e}");
        }
    }
}
