//! A texture atlas with one square cell per pair of triangles (hand-written: a chart packer such
//! as xatlas would need a C++ build for a layout that this one gets without search). Each
//! triangle is mapped affinely onto half a cell: the first of a pair onto the lower-left half,
//! the second onto the upper-right, with a gutter of `gutter` texels around and between them.
//! Charts never overlap and every UV lies in [0, 1]; the cost is texels spent on gutters and
//! seams along every edge, which the baker hides by filling each cell completely (texels in a
//! gutter take the value of the nearest point of their triangle), and which sampling without
//! mipmaps keeps invisible.
//!
//! Vertices are not shared between triangles (each corner has its own UV); positions and smooth
//! normals come from the input mesh, tangents from each triangle's UV mapping (glTF's TANGENT,
//! with the bitangent sign in w, the bitangent along -dP/dv: glTF's "green up").

use crate::mesh::Mesh;
use crate::ExportError;
use glam::{Vec2, Vec3, Vec4};

/// A mesh laid out in an atlas: three unshared corners per triangle, in triangle order.
#[derive(Clone, Debug, PartialEq)]
pub struct AtlasMesh {
    /// Corner positions (`3 * triangles`).
    pub positions: Vec<Vec3>,
    /// Smooth unit normals per corner.
    pub normals: Vec<Vec3>,
    /// Unit tangent (xyz) and bitangent sign (w) per corner, glTF convention.
    pub tangents: Vec<Vec4>,
    /// UV per corner, (0, 0) the image's top-left, v downwards (glTF).
    pub uvs: Vec<Vec2>,
    /// Texture side in texels.
    pub size: u32,
    /// Cell side in texels.
    pub cell: u32,
    /// Cells per row.
    pub cells_per_row: u32,
    /// Gutter in texels.
    pub gutter: f32,
}

impl AtlasMesh {
    /// Number of triangles.
    pub fn triangles(&self) -> usize {
        self.positions.len() / 3
    }

    /// Texel-space corners of triangle `t`'s chart.
    pub fn chart(&self, t: usize) -> [Vec2; 3] {
        [0, 1, 2].map(|k| self.uvs[3 * t + k] * self.size as f32)
    }

    /// Top-left texel of the cell of triangle `t`.
    pub fn cell_origin(&self, t: usize) -> (u32, u32) {
        let c = (t / 2) as u32;
        ((c % self.cells_per_row) * self.cell, (c / self.cells_per_row) * self.cell)
    }
}

/// Lays `mesh` out on a `size`-texel square texture. Fails if a cell would be under 6 texels
/// (too many triangles for the texture).
pub fn build_atlas(mesh: &Mesh, size: u32, gutter: f32) -> Result<AtlasMesh, ExportError> {
    mesh.validate()?;
    let cells = mesh.len().div_ceil(2) as u32;
    let per_row = (cells as f64).sqrt().ceil() as u32;
    let cell = size / per_row.max(1);
    if cell < 6 || (cell as f32) < 4.0 * gutter + 2.0 {
        return Err(ExportError::Invalid(format!(
            "{} triangles leave {cell}-texel cells in a {size} texture: use a larger texture or fewer triangles",
            mesh.len()
        )));
    }
    let normals = mesh.vertex_normals();
    let n = mesh.len() * 3;
    let mut out = AtlasMesh {
        positions: Vec::with_capacity(n),
        normals: Vec::with_capacity(n),
        tangents: Vec::with_capacity(n),
        uvs: Vec::with_capacity(n),
        size,
        cell,
        cells_per_row: per_row,
        gutter,
    };
    let (c, g, d) = (cell as f32, gutter, 0.5 * gutter);
    for t in 0..mesh.len() {
        let (ox, oy) = out.cell_origin(t);
        let o = Vec2::new(ox as f32, oy as f32);
        // Lower-left half: legs along +x and +y; upper-right half mirrored. The hypotenuses
        // sit `d` texels either side of the cell's diagonal x + y = c.
        let local = if t % 2 == 0 {
            [Vec2::new(g, g), Vec2::new(c - g - d, g), Vec2::new(g, c - g - d)]
        } else {
            [Vec2::new(c - g, c - g), Vec2::new(g + d, c - g), Vec2::new(c - g, g + d)]
        };
        let uv = local.map(|l| (o + l) / size as f32);
        let tri = mesh.triangles[t];
        let p = tri.map(|i| mesh.positions[i as usize]);
        // glTF normal maps are "+Y up" in the image, i.e. along -v (v points down): the
        // bitangent cross(N, T) * w is made to follow -dP/dv.
        let (du, dv) = triangle_tangent(p, uv);
        let tangent = (du, -dv);
        for k in 0..3 {
            let nrm = normals[tri[k] as usize];
            out.positions.push(p[k]);
            out.normals.push(nrm);
            out.uvs.push(uv[k]);
            out.tangents.push(orthogonal_tangent(tangent, nrm));
        }
    }
    Ok(out)
}

/// dP/du and dP/dv of a triangle's affine UV mapping.
fn triangle_tangent(p: [Vec3; 3], uv: [Vec2; 3]) -> (Vec3, Vec3) {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let det = d1.x * d2.y - d2.x * d1.y;
    let r = if det.abs() > 0.0 { 1.0 / det } else { 0.0 };
    ((e1 * d2.y - e2 * d1.y) * r, (e2 * d1.x - e1 * d2.x) * r)
}

/// Gram-Schmidt of dP/du against `n`, with the handedness of (dP/du, dP/dv) in w.
pub fn orthogonal_tangent((du, dv): (Vec3, Vec3), n: Vec3) -> Vec4 {
    let t = (du - n * n.dot(du)).try_normalize().unwrap_or_else(|| n.any_orthonormal_vector());
    let w = if n.cross(t).dot(dv) < 0.0 { -1.0 } else { 1.0 };
    t.extend(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_mesh(k: u32) -> Mesh {
        let mut m = Mesh::default();
        for y in 0..=k {
            for x in 0..=k {
                let (fx, fy) = (x as f32 / k as f32, y as f32 / k as f32);
                m.positions.push(Vec3::new(fx, fy, 0.3 * (fx * 3.0).sin() * fy));
            }
        }
        for y in 0..k {
            for x in 0..k {
                let i = y * (k + 1) + x;
                m.triangles.push([i, i + 1, i + k + 2]);
                m.triangles.push([i, i + k + 2, i + k + 1]);
            }
        }
        m
    }

    fn inside(p: Vec2, t: [Vec2; 3]) -> bool {
        let e = |a: Vec2, b: Vec2| (b - a).perp_dot(p - a);
        let s = [e(t[0], t[1]), e(t[1], t[2]), e(t[2], t[0])];
        s.iter().all(|&v| v > 1e-4) || s.iter().all(|&v| v < -1e-4)
    }

    #[test]
    fn charts_are_disjoint_and_inside_the_unit_square() {
        let m = grid_mesh(9); // 162 triangles
        let a = build_atlas(&m, 256, 1.0).unwrap();
        assert!(a.uvs.iter().all(|uv| uv.cmpge(Vec2::ZERO).all() && uv.cmple(Vec2::ONE).all()));
        // Every texel centre lies in at most one chart.
        let charts: Vec<[Vec2; 3]> = (0..a.triangles()).map(|t| a.chart(t)).collect();
        let mut covered = 0;
        for y in 0..a.size {
            for x in 0..a.size {
                let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let hits = charts.iter().filter(|c| inside(p, **c)).count();
                assert!(hits <= 1, "texel ({x}, {y}) in {hits} charts");
                covered += hits;
            }
        }
        assert!(covered > (a.size * a.size / 4) as usize, "charts cover {covered} texels");
        // Tangents are unit, orthogonal to the normal, and follow +u.
        for t in 0..a.triangles() {
            let tan = a.tangents[3 * t].truncate();
            assert!((tan.length() - 1.0).abs() < 1e-4 && tan.dot(a.normals[3 * t]).abs() < 1e-4);
        }
    }

    #[test]
    fn too_many_triangles_for_the_texture_is_an_error() {
        assert!(build_atlas(&grid_mesh(40), 64, 1.0).is_err());
    }
}
