//! Ray-disk intersection for Gaussian surfels (SPEC 5, "Hit test").
//!
//! Each surfel is an elliptical disk with semi-axes 3 s_u t_u and 3 s_v t_v (the 3-sigma support)
//! and zero thickness. A ray hits it at the plane crossing `t = n.(p - o) / n.d` when the tangent
//! coordinates in sigma units `(u, v) = (t_u.(x-p)/s_u, t_v.(x-p)/s_v)` satisfy `u^2+v^2 <= 9` and
//! `alpha = min(0.99, o exp(-(u^2+v^2)/2)) >= 1/255`. [`Disk`] precomputes `t_u/s_u`, `t_v/s_v` so
//! a test is two dot products after the plane crossing; it is one 64-byte cache line, `Pod`, and
//! is stored in BVH leaf order.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use svgir_core::Surfels;

/// Smallest accepted alpha (SPEC 1/5).
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Largest alpha (SPEC 1/5).
pub const ALPHA_MAX: f32 = 0.99;
/// Support radius in sigma units, squared.
pub const SUPPORT_R2: f32 = 9.0;

/// How far from its centre a disk of opacity `o` can be hit, in sigma units:
/// `sqrt(min(9, 2 ln(255 o)))` (a hit needs `u^2 + v^2 <= 9` and `o exp(-(u^2 + v^2)/2) >= 1/255`;
/// 0 below 1/255).
pub fn reach_sigma(o: f32) -> f32 {
    (2.0 * (o / ALPHA_MIN).ln()).clamp(0.0, SUPPORT_R2).sqrt()
}
/// |n.d| below this counts as parallel (the disk has ~1e-12 thickness, SPEC 5).
pub const PARALLEL_EPS: f32 = 1e-12;

/// One surfel prepared for ray tests.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Disk {
    /// Centre of the disk, world space.
    pub center: [f32; 3],
    /// Activated opacity o in (0, 1).
    pub opacity: f32,
    /// Unit normal.
    pub normal: [f32; 3],
    /// max(s_u, s_v), for scale-aware offsets.
    pub max_scale: f32,
    /// t_u / s_u.
    pub axis_u: [f32; 3],
    /// Gaussian index in the `Surfels` the disk came from.
    pub id: u32,
    /// t_v / s_v.
    pub axis_v: [f32; 3],
    /// Padding to 64 bytes (Pod layout); always 0.
    pub _pad: u32,
}

/// One accepted ray-disk intersection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit, world units along the unit direction.
    pub t: f32,
    /// Gaussian index of the hit disk.
    pub id: u32,
    /// `min(0.99, o exp(-(u^2 + v^2)/2))`, at least 1/255 (SPEC 1/5).
    pub alpha: f32,
    /// Tangent coordinates in sigma units.
    pub u: f32,
    /// Tangent coordinate along t_v, in sigma units.
    pub v: f32,
}

impl Hit {
    /// SPEC 3 / 9.1 normalised tangent coordinates `u~ = clamp(0.5 + 0.5 u, 0.001, 0.999)`.
    /// (`u` is in sigma units and the vertex square has half-width one sigma.)
    pub fn uv_normalised(&self) -> [f32; 2] {
        [(0.5 + 0.5 * self.u).clamp(0.001, 0.999), (0.5 + 0.5 * self.v).clamp(0.001, 0.999)]
    }
}

impl Disk {
    /// Prepare Gaussian `i` of `s` for ray tests.
    pub fn from_surfel(s: &Surfels, i: usize) -> Self {
        let r = s.rotation_matrix(i);
        let sc = s.scale(i);
        Self {
            center: s.positions[i].to_array(),
            opacity: s.opacity(i),
            normal: r.z_axis.to_array(),
            max_scale: sc.x.max(sc.y),
            axis_u: (r.x_axis / sc.x).to_array(),
            id: i as u32,
            axis_v: (r.y_axis / sc.y).to_array(),
            _pad: 0,
        }
    }

    /// Axis-aligned bounds of the part of the disk a ray can hit, padded by `pad` on every side.
    /// A hit needs `u^2 + v^2 <= 9` and `o exp(-(u^2 + v^2)/2) >= 1/255`, so its radius in sigma
    /// units is `r = sqrt(min(9, 2 ln(255 o)))`: 3 from opacity 0.35 up, 2.26 at 0.05, none
    /// below 1/255 (the faint, large floaters of a real capture span far less than their
    /// 3-sigma ellipse). The extent along world axis a is `r sqrt((s_u t_u.a)^2 + (s_v t_v.a)^2)`,
    /// with `r` raised by 1e-3 relative so that f32 rounding in the alpha test cannot reach past it.
    pub fn bounds(s: &Surfels, i: usize, pad_rel: f32) -> (Vec3, Vec3) {
        let r = s.rotation_matrix(i);
        let sc = s.scale(i);
        let eu = r.x_axis * sc.x;
        let ev = r.y_axis * sc.y;
        let ext = reach_sigma(s.opacity(i)) * (1.0 + 1e-3) * (eu * eu + ev * ev).map(f32::sqrt);
        let p = s.positions[i];
        // Padding absorbs rounding in the plane-crossing hit point, so box culling can never reject
        // a hit the exact test would accept (BVH results must equal brute force bit for bit).
        let pad = pad_rel * (p.abs().max_element() + ext.max_element()) + 1e-7;
        (p - ext - Vec3::splat(pad), p + ext + Vec3::splat(pad))
    }

    /// The intersection of the ray `o + t d` with this disk (any t; callers filter the range).
    #[inline(always)]
    pub fn intersect(&self, o: Vec3, d: Vec3) -> Option<Hit> {
        self.intersect_if(o, d, |_| true)
    }

    /// [`Self::intersect`] for a caller that will drop a hit at some plane distances anyway
    /// (behind the traversal's cursor, beyond its buffer's last key): `keep(t)` is asked before
    /// the tangent coordinates and the `exp`, and the hits it keeps are [`Self::intersect`]'s,
    /// bit for bit.
    #[inline(always)]
    pub fn intersect_if(&self, o: Vec3, d: Vec3, keep: impl FnOnce(f32) -> bool) -> Option<Hit> {
        let n = Vec3::from_array(self.normal);
        let denom = n.dot(d);
        if denom.abs() < PARALLEL_EPS {
            return None;
        }
        let rel = o - Vec3::from_array(self.center);
        let t = -n.dot(rel) / denom;
        if !keep(t) {
            return None;
        }
        let x = rel + t * d;
        let u = x.dot(Vec3::from_array(self.axis_u));
        let v = x.dot(Vec3::from_array(self.axis_v));
        let r2 = u * u + v * v;
        if r2.is_nan() || r2 > SUPPORT_R2 {
            return None;
        }
        let alpha = (self.opacity * (-0.5 * r2).exp()).min(ALPHA_MAX);
        if alpha < ALPHA_MIN {
            return None;
        }
        Some(Hit { t, id: self.id, alpha, u, v })
    }
}

/// Prepared disks for every surfel, in Gaussian order.
pub fn disks_of(s: &Surfels) -> Vec<Disk> {
    (0..s.len()).map(|i| Disk::from_surfel(s, i)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec2};
    use svgir_core::{surfel::logit, ShCoeffs};

    #[test]
    fn hit_coordinates_alpha_and_rejections() {
        let mut s = Surfels::with_capacity(1, 0);
        let q = Quat::from_rotation_z(0.3) * Quat::from_rotation_x(0.4);
        s.push(Vec3::new(0.1, 0.2, 0.3), q, Vec2::new(0.1f32.ln(), 0.05f32.ln()), logit(0.8), ShCoeffs::default());
        let disk = Disk::from_surfel(&s, 0);
        // Aim at the world point of (u, v) = (1.5, -2) from somewhere off the plane.
        let target = s.local_to_world(0, 1.5, -2.0);
        let o = target + Vec3::new(0.3, -0.7, 1.1);
        let d = (target - o).normalize();
        let h = disk.intersect(o, d).expect("hit");
        assert!((h.u - 1.5).abs() < 1e-4 && (h.v + 2.0).abs() < 1e-4, "{h:?}");
        assert!((h.t - (target - o).length()).abs() < 1e-5);
        assert!((h.alpha - 0.8 * (-0.5f32 * 6.25).exp()).abs() < 1e-5);
        assert_eq!(h.uv_normalised(), [0.999, 0.001]);
        // Outside the 3-sigma ellipse.
        let far = s.local_to_world(0, 2.5, -2.0);
        assert!(disk.intersect(o, (far - o).normalize()).is_none());
        // Inside the ellipse but alpha < 1/255: u^2+v^2 = 8.9 gives 0.8*exp(-4.45) = 0.0093 -> kept;
        // with opacity 0.3 it is 0.0035 -> rejected.
        let mut s2 = s.clone();
        s2.opacity_logits[0] = logit(0.3);
        let edge = s.local_to_world(0, 0.0, 8.9f32.sqrt());
        let de = (edge - o).normalize();
        assert!(disk.intersect(o, de).is_some());
        assert!(Disk::from_surfel(&s2, 0).intersect(o, de).is_none());
        // Parallel ray.
        let n = s.normal(0);
        let tangent = n.any_orthonormal_vector();
        assert!(disk.intersect(s.positions[0] + n, tangent).is_none());
        // Bounds contain the whole support at high opacity, and at low opacity exactly the
        // radius where alpha reaches 1/255: rays just inside it hit, just outside they miss.
        let (lo, hi) = Disk::bounds(&s, 0, 1e-5);
        for a in 0..64 {
            let ang = a as f32 / 64.0 * std::f32::consts::TAU;
            let p = s.local_to_world(0, 3.0 * ang.cos(), 3.0 * ang.sin());
            assert!(p.cmpge(lo).all() && p.cmple(hi).all());
        }
        let mut faint = s.clone();
        faint.opacity_logits[0] = logit(0.05);
        let reach = (2.0 * (0.05f32 * 255.0).ln()).sqrt();
        let (lo, hi) = Disk::bounds(&faint, 0, 1e-5);
        let fd = Disk::from_surfel(&faint, 0);
        let (mut inside_hits, mut outside_hits) = (0, 0);
        for a in 0..64 {
            let ang = a as f32 / 64.0 * std::f32::consts::TAU;
            let p = faint.local_to_world(0, 0.999 * reach * ang.cos(), 0.999 * reach * ang.sin());
            assert!(p.cmpge(lo).all() && p.cmple(hi).all());
            inside_hits += fd.intersect(o, (p - o).normalize()).is_some() as usize;
            let q = faint.local_to_world(0, 1.001 * reach * ang.cos(), 1.001 * reach * ang.sin());
            outside_hits += fd.intersect(o, (q - o).normalize()).is_some() as usize;
        }
        assert_eq!((inside_hits, outside_hits), (64, 0));
        let mut invisible = s.clone();
        invisible.opacity_logits[0] = logit(0.003);
        let (lo, hi) = Disk::bounds(&invisible, 0, 1e-5);
        assert!((hi - lo).max_element() < 1e-3, "a disk no ray can hit has a point-sized box");
    }
}
