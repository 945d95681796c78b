//! Grid cells of Gaussian centres: 26-connected clusters on a voxel grid (which Gaussians touch),
//! and a footprint on a plane (which points lie over a set of others).

use super::Plane;
use glam::Vec3;
use svgir_core::Surfels;

/// The cells of a square grid on a plane that points project into, for "lies over them".
pub(super) struct Footprint {
    plane: Plane,
    u: Vec3,
    v: Vec3,
    cell: f32,
    cells: std::collections::HashSet<(i64, i64)>,
}

impl Footprint {
    pub(super) fn new(pl: Plane, cell: f32, points: impl Iterator<Item = Vec3>) -> Self {
        let u = pl.normal.any_orthonormal_vector();
        let v = pl.normal.cross(u);
        let mut f = Self { plane: pl, u, v, cell, cells: Default::default() };
        for p in points {
            let k = f.key(p);
            f.cells.insert(k);
        }
        f
    }

    fn key(&self, p: Vec3) -> (i64, i64) {
        ((self.u.dot(p) / self.cell).floor() as i64, (self.v.dot(p) / self.cell).floor() as i64)
    }

    /// `p` projects into a cell of the footprint or one of its 8 neighbours.
    pub(super) fn covers(&self, p: Vec3) -> bool {
        let k = self.key(p);
        (-1..=1).any(|a| (-1..=1).any(|b| self.cells.contains(&(k.0 + a, k.1 + b))))
    }

    /// `p` lies at least `low` above the plane, or low over the footprint.
    pub(super) fn admits(&self, p: Vec3, low: f32) -> bool {
        self.plane.signed_distance(p) >= low || self.covers(p)
    }
}

/// Voxel cells of the given Gaussians and their 26-connected components.
pub(super) struct Clusters {
    voxel: f32,
    cells: std::collections::HashMap<(i64, i64, i64), Vec<usize>>,
    /// Component of each cell, and each component's Gaussian count.
    pub(super) label: std::collections::HashMap<(i64, i64, i64), usize>,
    sizes: Vec<usize>,
}

impl Clusters {
    pub(super) fn key(&self, p: Vec3) -> (i64, i64, i64) {
        let v = (p / self.voxel).floor();
        (v.x as i64, v.y as i64, v.z as i64)
    }

    pub(super) fn new(s: &Surfels, idx: &[usize], voxel: f32) -> Self {
        let mut c = Self { voxel, cells: Default::default(), label: Default::default(), sizes: Vec::new() };
        for &i in idx {
            let k = c.key(s.positions[i]);
            c.cells.entry(k).or_default().push(i);
        }
        // Flood fill over occupied cells in a fixed order, so that ties resolve the same way.
        let mut keys: Vec<_> = c.cells.keys().copied().collect();
        keys.sort_unstable();
        for &k in &keys {
            if c.label.contains_key(&k) {
                continue;
            }
            let id = c.sizes.len();
            let mut size = 0;
            let mut stack = vec![k];
            c.label.insert(k, id);
            while let Some(q) = stack.pop() {
                size += c.cells[&q].len();
                for dz in -1..=1 {
                    for dy in -1..=1 {
                        for dx in -1..=1 {
                            let nb = (q.0 + dx, q.1 + dy, q.2 + dz);
                            if c.cells.contains_key(&nb) && !c.label.contains_key(&nb) {
                                c.label.insert(nb, id);
                                stack.push(nb);
                            }
                        }
                    }
                }
            }
            c.sizes.push(size);
        }
        c
    }

    /// Whether the cell of `p` or one of its 26 neighbours is occupied.
    pub(super) fn touches(&self, p: Vec3) -> bool {
        let k = self.key(p);
        (-1..=1)
            .any(|dz| (-1..=1).any(|dy| (-1..=1).any(|dx| self.cells.contains_key(&(k.0 + dx, k.1 + dy, k.2 + dz)))))
    }

    /// The component with the most Gaussians.
    pub(super) fn largest(&self) -> Option<usize> {
        (0..self.sizes.len()).max_by_key(|&c| (self.sizes[c], std::cmp::Reverse(c)))
    }

    /// Per-Gaussian flags (over `n`) of the members of `components`.
    pub(super) fn members(&self, components: &[usize], n: usize) -> Vec<bool> {
        let mut out = vec![false; n];
        for (k, members) in &self.cells {
            if components.contains(&self.label[k]) {
                for &i in members {
                    out[i] = true;
                }
            }
        }
        out
    }
}
