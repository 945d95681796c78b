//! Baking the stage-2 Gaussians' materials into the atlas textures.
//!
//! Every texel of a cell is mapped to a point of its triangle (texels in a gutter to the nearest
//! point of the triangle, which fills gutters with edge values). At that point the Gaussians
//! near it are blended as the renderer blends them along a ray through the surface: weight
//! `opacity * exp(-(u^2 + v^2) / 2) * exp(-(h / thickness)^2 / 2)`, with (u, v) the point's
//! tangent coordinates in sigma units and `h` its height above the surfel's plane, over surfels
//! whose oriented normal faces the same side as the mesh (thin parts keep their two sides
//! apart). Each Gaussian's material at (u, v) is its vertices' SPEC 3 interpolation. Where no
//! Gaussian covers a texel, the nearest centre (by (distance, id)) gives its material.
//!
//! Outputs: base colour = albedo (sRGB-encoded, as glTF's baseColorTexture), metallic-roughness
//! with roughness in G and metallic 0 in B (R, glTF's unused slot, 1), and the shading normal in
//! the tangent frame of the atlas (glTF's normalTexture, +Y = bitangent). Our BRDF (SPEC 4) is
//! glTF's metallic-roughness model at metallic 0: Lambertian albedo plus GGX with F0 = 0.04 and
//! alpha = roughness^2, so the values carry over unchanged.
//! Work split: rayon over atlas rows of cells; a uniform hash grid finds the Gaussians.

use crate::atlas::AtlasMesh;
use crate::ExportError;
use glam::{Mat3, Vec2, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use svgir_core::color::linear_to_srgb;
use svgir_core::{Image, Surfels};
use svgir_shading::vertex_weights;

/// The Gaussians and their per-vertex stage-2 materials (SPEC 3 layout, `N * m (* 3)`).
#[derive(Clone, Copy, Debug)]
pub struct GaussianField<'a> {
    /// Geometry.
    pub surfels: &'a Surfels,
    /// Oriented geometric normals (stage 2's, towards the outside).
    pub normals: &'a [Vec3],
    /// Vertices per Gaussian.
    pub m: usize,
    /// Linear albedo per vertex.
    pub albedo: &'a [f32],
    /// Roughness per vertex.
    pub roughness: &'a [f32],
    /// Unit shading normals per vertex.
    pub shading_normals: &'a [f32],
}

impl GaussianField<'_> {
    fn validate(&self) -> Result<(), ExportError> {
        let n = self.surfels.len();
        self.surfels.check().map_err(ExportError::Invalid)?;
        let ok = self.normals.len() == n
            && self.albedo.len() == n * self.m * 3
            && self.roughness.len() == n * self.m
            && self.shading_normals.len() == n * self.m * 3
            && matches!(self.m, 1 | 2 | 4 | 6);
        if !ok {
            return Err(ExportError::Invalid(format!(
                "material arrays do not match {n} Gaussians x {} vertices",
                self.m
            )));
        }
        if n == 0 {
            return Err(ExportError::Degenerate("the model has no Gaussians".into()));
        }
        Ok(())
    }
}

/// The three baked textures (linear values in [0, 1] except base colour, already sRGB).
#[derive(Clone, Debug, PartialEq)]
pub struct BakedTextures {
    /// sRGB base colour, 3 channels.
    pub base_color: Image,
    /// (1, roughness, 0).
    pub metallic_roughness: Image,
    /// Tangent-space normal encoded `0.5 + 0.5 n`.
    pub normal: Image,
    /// Fraction of texels covered by at least one Gaussian (the rest took the nearest one).
    pub covered: f32,
}

/// Material blended at one point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointMaterial {
    /// Linear albedo.
    pub albedo: Vec3,
    /// GGX roughness.
    pub roughness: f32,
    /// Unit shading normal (world).
    pub normal: Vec3,
    /// Total blend weight (0: nearest-Gaussian fallback).
    pub weight: f32,
}

/// Uniform hash grid of Gaussians by their 3-sigma spheres.
pub struct GaussianIndex<'a> {
    field: GaussianField<'a>,
    cell: f32,
    cells: HashMap<[i32; 3], Vec<u32>>,
    axes: Vec<Mat3>,
    thickness: f32,
}

impl<'a> GaussianIndex<'a> {
    /// Indexes `field`; `thickness` is the height scale above a surfel's plane (about the
    /// distance between the fused mesh and the surfels: a voxel or two).
    pub fn new(field: GaussianField<'a>, thickness: f32) -> Result<Self, ExportError> {
        field.validate()?;
        let n = field.surfels.len();
        let mut radii: Vec<f32> = (0..n).map(|i| 3.0 * field.surfels.scale(i).max_element()).collect();
        let mut sorted = radii.clone();
        sorted.sort_by(f32::total_cmp);
        let cell = sorted[(n - 1) * 9 / 10].max(thickness * 3.0).max(1e-6);
        let mut cells: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
        for (i, r) in radii.iter_mut().enumerate() {
            // Spheres larger than two cells are clipped: their tails carry little weight.
            let r = r.min(2.0 * cell).max(3.0 * thickness);
            let p = field.surfels.positions[i];
            let lo = ((p - r) / cell).floor().as_ivec3();
            let hi = ((p + r) / cell).floor().as_ivec3();
            for z in lo.z..=hi.z {
                for y in lo.y..=hi.y {
                    for x in lo.x..=hi.x {
                        cells.entry([x, y, z]).or_default().push(i as u32);
                    }
                }
            }
        }
        let axes = (0..n).map(|i| field.surfels.rotation_matrix(i)).collect();
        Ok(Self { field, cell, cells, axes, thickness })
    }

    /// The blended material at `p` on a surface with unit normal `n`.
    pub fn material_at(&self, p: Vec3, n: Vec3) -> PointMaterial {
        let f = &self.field;
        let key = (p / self.cell).floor().as_ivec3().to_array();
        let empty = Vec::new();
        let ids = self.cells.get(&key).unwrap_or(&empty);
        let (mut a, mut r, mut sn, mut wsum) = (Vec3::ZERO, 0.0f32, Vec3::ZERO, 0.0f32);
        let mut nearest: Option<(f32, u32)> = None;
        for &g in ids {
            let gi = g as usize;
            let d = p - f.surfels.positions[gi];
            let dist = d.length_squared();
            if nearest.is_none_or(|b| (dist, g) < b) {
                nearest = Some((dist, g));
            }
            if f.normals[gi].dot(n) <= 0.0 {
                continue;
            }
            let ax = &self.axes[gi];
            let s = f.surfels.scale(gi);
            let (u, v, h) = (d.dot(ax.x_axis) / s.x, d.dot(ax.y_axis) / s.y, d.dot(ax.z_axis) / self.thickness);
            let q = u * u + v * v;
            if q > 9.0 {
                continue;
            }
            let w = f.surfels.opacity(gi) * (-0.5 * (q + h * h)).exp();
            if w < 1e-6 {
                continue;
            }
            let (mat_a, mat_r, mat_n) = self.vertex_blend(gi, u, v);
            a += w * mat_a;
            r += w * mat_r;
            sn += w * mat_n;
            wsum += w;
        }
        if wsum > 1e-6 {
            return PointMaterial { albedo: a / wsum, roughness: r / wsum, normal: sn.normalize_or(n), weight: wsum };
        }
        let g = match nearest {
            Some((_, g)) => g as usize,
            None => self.nearest_anywhere(p),
        };
        let ax = &self.axes[g];
        let s = f.surfels.scale(g);
        let d = p - f.surfels.positions[g];
        let (mat_a, mat_r, mat_n) = self.vertex_blend(g, d.dot(ax.x_axis) / s.x, d.dot(ax.y_axis) / s.y);
        let normal = if mat_n.dot(n) > 0.0 { mat_n.normalize_or(n) } else { n };
        PointMaterial { albedo: mat_a, roughness: mat_r, normal, weight: 0.0 }
    }

    fn nearest_anywhere(&self, p: Vec3) -> usize {
        let pos = &self.field.surfels.positions;
        (0..pos.len()).map(|i| (p.distance_squared(pos[i]), i)).min_by(|a, b| a.partial_cmp(b).unwrap()).unwrap().1
    }

    /// Albedo, roughness and (unnormalised) shading normal of Gaussian `g` at sigma-unit (u, v).
    fn vertex_blend(&self, g: usize, u: f32, v: f32) -> (Vec3, f32, Vec3) {
        let f = &self.field;
        let m = f.m;
        let nc = |x: f32| (0.5 + 0.5 * x).clamp(0.001, 0.999);
        let w = vertex_weights(m, nc(u), nc(v));
        let (mut a, mut r, mut n) = (Vec3::ZERO, 0.0, Vec3::ZERO);
        for k in 0..m {
            let j = g * m + k;
            a += w[k] * Vec3::from_slice(&f.albedo[3 * j..3 * j + 3]);
            r += w[k] * f.roughness[j];
            n += w[k] * Vec3::from_slice(&f.shading_normals[3 * j..3 * j + 3]);
        }
        (a, r, n)
    }
}

/// Barycentric coordinates of `p` in triangle `t`, clamped onto the triangle (nearest point
/// for points outside, so gutters take edge values).
pub fn clamped_barycentric(p: Vec2, t: [Vec2; 3]) -> Vec3 {
    let (v0, v1, v2) = (t[1] - t[0], t[2] - t[0], p - t[0]);
    let d00 = v0.dot(v0);
    let d01 = v0.dot(v1);
    let d11 = v1.dot(v1);
    let (d20, d21) = (v2.dot(v0), v2.dot(v1));
    let den = d00 * d11 - d01 * d01;
    if den.abs() < 1e-12 {
        return Vec3::new(1.0, 0.0, 0.0);
    }
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    let b = Vec3::new(1.0 - v - w, v, w);
    if b.min_element() >= 0.0 {
        return b;
    }
    // Outside: the nearest point on the three edges.
    let mut best = (f32::INFINITY, Vec3::X);
    for (i, j) in [(0usize, 1usize), (1, 2), (2, 0)] {
        let e = t[j] - t[i];
        let s = ((p - t[i]).dot(e) / e.length_squared().max(1e-12)).clamp(0.0, 1.0);
        let q = t[i] + e * s;
        let d = q.distance_squared(p);
        if d < best.0 {
            let mut bc = Vec3::ZERO;
            bc[i] = 1.0 - s;
            bc[j] = s;
            best = (d, bc);
        }
    }
    best.1
}

/// Bakes the field's materials into `atlas`'s textures.
pub fn bake_textures(atlas: &AtlasMesh, field: GaussianField, thickness: f32) -> Result<BakedTextures, ExportError> {
    let index = GaussianIndex::new(field, thickness)?;
    let size = atlas.size as usize;
    let cell = atlas.cell as usize;
    let mut base = vec![0.0f32; size * size * 3];
    let mut mr = vec![0.0f32; size * size * 3];
    let mut nm = vec![0.0f32; size * size * 3];
    // Texels outside every cell: flat normal, mid grey.
    for px in 0..size * size {
        base[3 * px..3 * px + 3].copy_from_slice(&[0.5; 3]);
        mr[3 * px..3 * px + 3].copy_from_slice(&[1.0, 0.5, 0.0]);
        nm[3 * px..3 * px + 3].copy_from_slice(&[0.5, 0.5, 1.0]);
    }
    let per_row = atlas.cells_per_row as usize;
    let row_len = size * 3 * cell;
    let tris = atlas.triangles();
    let covered: usize = base
        .par_chunks_mut(row_len)
        .zip(mr.par_chunks_mut(row_len))
        .zip(nm.par_chunks_mut(row_len))
        .enumerate()
        .map(|(row, ((b, m), n))| {
            let mut covered = 0;
            for col in 0..per_row {
                let first = 2 * (row * per_row + col);
                if first >= tris {
                    break;
                }
                for ty in 0..cell.min(b.len() / (size * 3)) {
                    for tx in 0..cell {
                        let (lx, ly) = (tx as f32 + 0.5, ty as f32 + 0.5);
                        let t = if lx + ly < cell as f32 || first + 1 >= tris { first } else { first + 1 };
                        let x = col * cell + tx;
                        let p = Vec2::new(x as f32 + 0.5, (row * cell + ty) as f32 + 0.5);
                        let bc = clamped_barycentric(p, atlas.chart(t));
                        let c = |v: &[Vec3]| bc.x * v[3 * t] + bc.y * v[3 * t + 1] + bc.z * v[3 * t + 2];
                        let pos = c(&atlas.positions);
                        let nrm = c(&atlas.normals).normalize_or(Vec3::Z);
                        let tan4 = atlas.tangents[3 * t];
                        let tan = (tan4.truncate() - nrm * nrm.dot(tan4.truncate()))
                            .normalize_or(nrm.any_orthonormal_vector());
                        let bit = nrm.cross(tan) * tan4.w;
                        let mat = index.material_at(pos, nrm);
                        covered += (mat.weight > 0.0) as usize;
                        let i = 3 * (ty * size + x);
                        let srgb = mat.albedo.to_array().map(|v| linear_to_srgb(v.clamp(0.0, 1.0)));
                        b[i..i + 3].copy_from_slice(&srgb);
                        m[i..i + 3].copy_from_slice(&[1.0, mat.roughness.clamp(0.0, 1.0), 0.0]);
                        let mut ts = Vec3::new(mat.normal.dot(tan), mat.normal.dot(bit), mat.normal.dot(nrm));
                        // Keep the normal in the front hemisphere of the surface.
                        ts.z = ts.z.max(0.05);
                        let ts = ts.normalize();
                        n[i..i + 3].copy_from_slice(&(0.5 * ts + 0.5).to_array());
                    }
                }
            }
            covered
        })
        .sum();
    let cell_texels = tris.div_ceil(2) * cell * cell;
    let s = atlas.size;
    Ok(BakedTextures {
        base_color: Image::from_data(s, s, 3, base),
        metallic_roughness: Image::from_data(s, s, 3, mr),
        normal: Image::from_data(s, s, 3, nm),
        covered: covered as f32 / cell_texels.max(1) as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec2 as V2};
    use svgir_core::ShCoeffs;

    #[test]
    fn barycentric_clamps_onto_the_triangle() {
        let t = [V2::ZERO, V2::X, V2::Y];
        let b = clamped_barycentric(V2::new(0.25, 0.25), t);
        assert!((b - Vec3::new(0.5, 0.25, 0.25)).length() < 1e-6);
        let b = clamped_barycentric(V2::new(2.0, -1.0), t);
        assert!((b - Vec3::new(0.0, 1.0, 0.0)).length() < 1e-6, "{b}");
        let b = clamped_barycentric(V2::new(0.5, -0.3), t);
        assert!((b - Vec3::new(0.5, 0.5, 0.0)).length() < 1e-6, "{b}");
    }

    #[test]
    fn blends_the_covering_gaussian_and_its_vertices() {
        // Two surfels in the plane z = 0, one red (M = 2: red -> green along u), one blue far away.
        let mut s = Surfels::with_capacity(2, 0);
        s.push(Vec3::ZERO, Quat::IDENTITY, V2::splat(0.1f32.ln()), 5.0, ShCoeffs::from_rgb([0.0; 3]));
        s.push(Vec3::X * 5.0, Quat::IDENTITY, V2::splat(0.1f32.ln()), 5.0, ShCoeffs::from_rgb([0.0; 3]));
        let normals = [Vec3::Z; 2];
        let albedo = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0];
        let rough = [0.2, 0.2, 0.7, 0.7];
        let sn = [0.0, 0.0, 1.0].repeat(4);
        let field = GaussianField {
            surfels: &s,
            normals: &normals,
            m: 2,
            albedo: &albedo,
            roughness: &rough,
            shading_normals: &sn,
        };
        let idx = GaussianIndex::new(field, 0.01).unwrap();
        let at_centre = idx.material_at(Vec3::ZERO, Vec3::Z);
        assert!((at_centre.albedo - Vec3::new(0.5, 0.5, 0.0)).length() < 1e-4, "{:?}", at_centre.albedo);
        let right = idx.material_at(Vec3::X * 0.1, Vec3::Z); // u = 1 sigma: u~ = 1 -> green
        assert!((right.albedo - Vec3::Y).length() < 3e-3, "{:?}", right.albedo);
        assert!((right.roughness - 0.2).abs() < 1e-5 && right.weight > 0.0);
        // The far surfel, and a point seen from below takes the nearest one as fallback.
        let far = idx.material_at(Vec3::X * 5.0, Vec3::Z);
        assert!((far.albedo - Vec3::Z).length() < 1e-4 && (far.roughness - 0.7).abs() < 1e-5);
        let below = idx.material_at(Vec3::ZERO, -Vec3::Z);
        assert_eq!(below.weight, 0.0);
        assert_eq!(below.normal, -Vec3::Z);
    }
}
