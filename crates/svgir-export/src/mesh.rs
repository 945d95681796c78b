//! Indexed triangle meshes: validation, vertex normals, connected components (union-find over
//! shared vertices, hand-written: a few lines, no graph crate needed) and simplification with
//! `meshopt` (quadric edge collapse, the simplifier of meshoptimizer).

use crate::ExportError;
use glam::Vec3;

/// An indexed triangle mesh in world coordinates.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.triangles.len()
    }

    /// True without triangles.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// Corner positions of triangle `t`.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }

    /// Area of triangle `t`.
    pub fn triangle_area(&self, t: usize) -> f32 {
        let [a, b, c] = self.corners(t);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        (0..self.len()).map(|t| self.triangle_area(t) as f64).sum()
    }

    /// Axis-aligned bounds of the vertices used by triangles.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self.triangles.iter().flatten().map(|&i| self.positions[i as usize]);
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }

    /// Indices in range, positions finite, at least one triangle with area.
    pub fn validate(&self) -> Result<(), ExportError> {
        let n = self.positions.len() as u32;
        if let Some(t) = self.triangles.iter().position(|t| t.iter().any(|&i| i >= n)) {
            return Err(ExportError::Invalid(format!("triangle {t} indexes past {n} vertices")));
        }
        if self.positions.iter().any(|p| !p.is_finite()) {
            return Err(ExportError::Invalid("a vertex position is not finite".into()));
        }
        if self.is_empty() {
            return Err(ExportError::Degenerate("the mesh has no triangles".into()));
        }
        if self.area() <= 0.0 {
            return Err(ExportError::Degenerate(format!("all {} triangles have zero area", self.len())));
        }
        Ok(())
    }

    /// Area-weighted unit vertex normals (the triangle winding's side); +Z where undefined.
    pub fn vertex_normals(&self) -> Vec<Vec3> {
        let mut n = vec![Vec3::ZERO; self.positions.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.positions[i as usize]);
            let f = (b - a).cross(c - a);
            for &i in t {
                n[i as usize] += f;
            }
        }
        n.into_iter().map(|v| v.try_normalize().unwrap_or(Vec3::Z)).collect()
    }

    /// Drops zero-area triangles and vertices no triangle uses (indices renumbered in order).
    pub fn compact(&self) -> Mesh {
        let mut map = vec![u32::MAX; self.positions.len()];
        let mut out = Mesh::default();
        for t in 0..self.len() {
            let tri = self.triangles[t];
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] || self.triangle_area(t) <= 0.0 {
                continue;
            }
            let mapped = tri.map(|i| {
                let m = &mut map[i as usize];
                if *m == u32::MAX {
                    *m = out.positions.len() as u32;
                    out.positions.push(self.positions[i as usize]);
                }
                *m
            });
            out.triangles.push(mapped);
        }
        out
    }
}

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let p = parent[i as usize];
        parent[i as usize] = parent[p as usize];
        i = p;
    }
    i
}

/// Connected components (triangles sharing a vertex): one label per triangle, labels numbered
/// by decreasing component size, ties by first triangle (deterministic).
pub fn components(mesh: &Mesh) -> (Vec<u32>, Vec<usize>) {
    let mut parent: Vec<u32> = (0..mesh.positions.len() as u32).collect();
    for t in &mesh.triangles {
        for k in 1..3 {
            let (a, b) = (find(&mut parent, t[0]), find(&mut parent, t[k]));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    let roots: Vec<u32> = mesh.triangles.iter().map(|t| find(&mut parent, t[0])).collect();
    let mut order: Vec<(u32, usize, usize)> = Vec::new(); // (root, size, first triangle)
    let mut slot = std::collections::HashMap::new();
    for (t, &r) in roots.iter().enumerate() {
        let s = *slot.entry(r).or_insert_with(|| {
            order.push((r, 0, t));
            order.len() - 1
        });
        order[s].1 += 1;
    }
    let mut ranked: Vec<usize> = (0..order.len()).collect();
    ranked.sort_by_key(|&s| (std::cmp::Reverse(order[s].1), order[s].2));
    let mut label_of = vec![0u32; order.len()];
    for (label, &s) in ranked.iter().enumerate() {
        label_of[s] = label as u32;
    }
    let labels = roots.iter().map(|r| label_of[slot[r]]).collect();
    let sizes = ranked.iter().map(|&s| order[s].1).collect();
    (labels, sizes)
}

/// Keeps the components with at least `min_fraction` of the largest one's triangles (2DGS's
/// post-processing keeps the largest clusters; small floaters of the radiance field go).
pub fn keep_largest_components(mesh: &Mesh, min_fraction: f32) -> Mesh {
    let (labels, sizes) = components(mesh);
    let Some(&largest) = sizes.first() else { return Mesh::default() };
    let keep = sizes.iter().take_while(|&&s| s as f32 >= min_fraction * largest as f32).count() as u32;
    let triangles = mesh.triangles.iter().zip(&labels).filter(|(_, &l)| l < keep).map(|(t, _)| *t).collect();
    Mesh { positions: mesh.positions.clone(), triangles }.compact()
}

/// Simplifies to about `target_triangles` with meshopt's quadric simplifier; with `max_error`
/// (world units) it stops earlier rather than move the surface further. Where the topology
/// stops the edge collapses short of the budget (surface nets leave a few non-manifold
/// vertices), and no `max_error` was given, meshopt's sloppy simplifier (vertex clustering)
/// finishes the job. Returns the mesh and the deviation meshopt reports (world units).
pub fn simplify(mesh: &Mesh, target_triangles: usize, max_error: Option<f32>) -> Result<(Mesh, f32), ExportError> {
    mesh.validate()?;
    if mesh.len() <= target_triangles {
        return Ok((mesh.clone(), 0.0));
    }
    let bytes: &[u8] = bytemuck::cast_slice(&mesh.positions);
    let adapter = meshopt::VertexDataAdapter::new(bytes, 12, 0)
        .map_err(|e| ExportError::Invalid(format!("meshopt vertex data: {e:?}")))?;
    let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let mut error = 0.0f32;
    let mut out = meshopt::simplify(
        &indices,
        &adapter,
        target_triangles * 3,
        max_error.unwrap_or(f32::MAX),
        meshopt::SimplifyOptions::ErrorAbsolute,
        Some(&mut error),
    );
    if max_error.is_none() && out.len() > target_triangles * 3 * 11 / 10 {
        let mut rel = 0.0f32;
        out = meshopt::simplify_sloppy(&out, &adapter, target_triangles * 3, f32::MAX, Some(&mut rel));
        // Sloppy errors are relative to the mesh's extent.
        let (lo, hi) = mesh.bounds().unwrap_or_default();
        error = error.max(rel * (hi - lo).max_element());
    }
    let triangles = out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let m = Mesh { positions: mesh.positions.clone(), triangles }.compact();
    m.validate()?;
    Ok((m, error))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(offset: Vec3) -> Mesh {
        let p = [Vec3::ZERO, Vec3::X, Vec3::X + Vec3::Y, Vec3::Y].map(|v| v + offset).to_vec();
        Mesh { positions: p, triangles: vec![[0, 1, 2], [0, 2, 3]] }
    }

    #[test]
    fn components_keep_the_largest() {
        let mut m = quad(Vec3::ZERO);
        let small = Mesh {
            positions: vec![Vec3::Z * 5.0, Vec3::Z * 5.0 + Vec3::X, Vec3::Z * 5.0 + Vec3::Y],
            triangles: vec![[0, 1, 2]],
        };
        let base = m.positions.len() as u32;
        m.positions.extend(small.positions);
        m.triangles.push([base, base + 1, base + 2]);
        let (labels, sizes) = components(&m);
        assert_eq!(sizes, vec![2, 1]);
        assert_eq!(labels, vec![0, 0, 1]);
        let kept = keep_largest_components(&m, 0.6);
        assert_eq!(kept.len(), 2);
        assert_eq!(kept.positions.len(), 4);
        assert!((kept.area() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn simplify_meets_the_budget_and_keeps_a_sphere_round() {
        // A UV sphere of 2 * 64 * 32 triangles down to 500.
        let (nu, nv) = (64u32, 33u32);
        let mut m = Mesh::default();
        for j in 0..nv {
            for i in 0..nu {
                let (t, p) =
                    (i as f32 / nu as f32 * std::f32::consts::TAU, j as f32 / (nv - 1) as f32 * std::f32::consts::PI);
                m.positions.push(Vec3::new(p.sin() * t.cos(), p.sin() * t.sin(), p.cos()));
            }
        }
        for j in 0..nv - 1 {
            for i in 0..nu {
                let (a, b) = (j * nu + i, j * nu + (i + 1) % nu);
                m.triangles.push([a, a + nu, b]);
                m.triangles.push([b, a + nu, b + nu]);
            }
        }
        let m = m.compact();
        let (s, err) = simplify(&m, 500, None).unwrap();
        assert!(s.len() <= 500 && s.len() > 250, "{} triangles", s.len());
        assert!(err > 0.0 && err < 0.1, "error {err}");
        assert!(s.positions.iter().all(|p| (p.length() - 1.0).abs() < 1e-5), "vertices stay on the sphere");
        // A tight error bound stops early.
        let (t, _) = simplify(&m, 500, Some(1e-4)).unwrap();
        assert!(t.len() > s.len());
    }

    #[test]
    fn validate_rejects_empty_and_flat() {
        assert!(matches!(Mesh::default().validate(), Err(ExportError::Degenerate(_))));
        let flat = Mesh { positions: vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0], triangles: vec![[0, 1, 2]] };
        assert!(matches!(flat.validate(), Err(ExportError::Degenerate(_))));
        let bad = Mesh { positions: vec![Vec3::ZERO], triangles: vec![[0, 1, 2]] };
        assert!(matches!(bad.validate(), Err(ExportError::Invalid(_))));
    }
}
