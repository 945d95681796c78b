//! Brute-force tracer for tests: every disk is tested against every ray (no BVH), all hits are
//! sorted by (t, id) and the march's continuation rule is applied to the sorted list. Slow and
//! obviously correct; the BVH traversal must reproduce it exactly.

use crate::hit::{disks_of, Disk, Hit};
use crate::traverse::{may_hit, Cursor, HitSource, Ray, TraceParams};
use svgir_core::Surfels;

/// Brute-force hit source: tests every disk against every ray (the BVH's reference in tests).
pub struct BruteForce {
    /// Every prepared disk, in Gaussian order.
    pub disks: Vec<Disk>,
}

impl BruteForce {
    /// Prepare every surfel of `s` for ray tests.
    pub fn new(s: &Surfels) -> Self {
        Self { disks: disks_of(s) }
    }

    /// Every hit with t in [t_start, t_max), sorted by (t, id).
    pub fn all_hits(&self, ray: &Ray, p: &TraceParams) -> Vec<Hit> {
        let mut v: Vec<Hit> = self
            .disks
            .iter()
            .filter(|d| may_hit(d, ray, p))
            .filter_map(|d| d.intersect(ray.origin, ray.dir))
            .filter(|h| h.t >= ray.t_start && h.t < p.t_max)
            .collect();
        v.sort_by(|a, b| (a.t, a.id).partial_cmp(&(b.t, b.id)).unwrap());
        v
    }
}

impl HitSource for BruteForce {
    fn for_each_hit(&self, ray: &Ray, p: &TraceParams, mut visit: impl FnMut(&Hit) -> bool) {
        let mut cont = Cursor { t: ray.t_start, id: -1 };
        for h in self.all_hits(ray, p) {
            if cont.accepts(h.t, h.id) {
                if !visit(&h) {
                    return;
                }
                cont = Cursor::after(&h, self.max_scale(h.id), p);
            }
        }
    }

    fn first_hit(&self, ray: &Ray, p: &TraceParams) -> Option<Hit> {
        self.all_hits(ray, p).first().copied()
    }

    fn max_scale(&self, id: u32) -> f32 {
        self.disks[id as usize].max_scale
    }
}
