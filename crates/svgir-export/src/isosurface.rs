//! The zero level set of a [`TsdfGrid`] as a triangle mesh, with Naive Surface Nets from the
//! `fast-surface-nets` crate (one vertex per cell crossing the surface, at the mean of its edge
//! crossings; quads split into two triangles). The grid is padded with one layer of "outside"
//! so the surface closes at the grid's faces, and each triangle is wound to face along the
//! field's gradient (outwards, towards positive distance).

use crate::mesh::Mesh;
use crate::tsdf::TsdfGrid;
use crate::ExportError;
use fast_surface_nets::ndshape::{RuntimeShape, Shape};
use fast_surface_nets::{surface_nets, SurfaceNetsBuffer};
use glam::Vec3;

/// Extracts the surface `sdf = 0` of `grid` in world coordinates.
pub fn extract(grid: &TsdfGrid) -> Result<Mesh, ExportError> {
    let [nx, ny, nz] = grid.dims;
    if grid.sdf.len() != (nx as usize) * (ny as usize) * (nz as usize) {
        return Err(ExportError::Invalid("grid size does not match its dimensions".into()));
    }
    let padded = [nx + 2, ny + 2, nz + 2];
    let shape = RuntimeShape::<u32, 3>::new(padded);
    let mut field = vec![1.0f32; shape.usize()];
    for z in 0..nz {
        for y in 0..ny {
            let src = ((z * ny + y) * nx) as usize;
            let dst = shape.linearize([1, y + 1, z + 1]) as usize;
            field[dst..dst + nx as usize].copy_from_slice(&grid.sdf[src..src + nx as usize]);
        }
    }
    let mut buf = SurfaceNetsBuffer::default();
    surface_nets(&field, &shape, [0; 3], [padded[0] - 1, padded[1] - 1, padded[2] - 1], &mut buf);
    // Array coordinates -> world: voxel (1, 1, 1) of the padded array is the grid's origin.
    let positions: Vec<Vec3> =
        buf.positions.iter().map(|p| grid.origin + grid.voxel * (Vec3::from_array(*p) - Vec3::ONE)).collect();
    let mut triangles = Vec::with_capacity(buf.indices.len() / 3);
    for c in buf.indices.chunks_exact(3) {
        let t = [c[0], c[1], c[2]];
        let [a, b, d] = t.map(|i| positions[i as usize]);
        let face = (b - a).cross(d - a);
        let grad: Vec3 = t.iter().map(|&i| Vec3::from_array(buf.normals[i as usize])).sum();
        triangles.push(if face.dot(grad) < 0.0 { [t[0], t[2], t[1]] } else { t });
    }
    let mesh = Mesh { positions, triangles }.compact();
    if mesh.is_empty() {
        return Err(ExportError::Degenerate(
            "the fused distance field has no surface (is the model empty or transparent?)".into(),
        ));
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn analytic_sphere_surface_is_close_and_outward() {
        let voxel = 0.05;
        let n = 56u32;
        let origin = Vec3::splat(-1.4);
        let mut sdf = Vec::new();
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let p = origin + voxel * Vec3::new(x as f32, y as f32, z as f32);
                    sdf.push(((p.length() - 1.0) / 0.2).clamp(-1.0, 1.0));
                }
            }
        }
        let grid = TsdfGrid { origin, voxel, dims: [n; 3], sdf, weight: vec![1; (n * n * n) as usize] };
        let m = extract(&grid).unwrap();
        let worst = m.positions.iter().map(|p| (p.length() - 1.0).abs()).fold(0.0f32, f32::max);
        assert!(worst < 0.2 * voxel, "vertex off the sphere by {worst}");
        // Outward winding: the signed volume is positive and close to 4/3 pi.
        let vol: f32 = (0..m.len())
            .map(|t| {
                let [a, b, c] = m.corners(t);
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        assert!((vol - 4.18879).abs() < 0.05, "volume {vol}");
        let (_, sizes) = crate::mesh::components(&m);
        assert_eq!(sizes.len(), 1, "one closed surface");
    }

    #[test]
    fn empty_field_is_a_clear_error() {
        let grid = TsdfGrid { origin: Vec3::ZERO, voxel: 0.1, dims: [4; 3], sdf: vec![1.0; 64], weight: vec![0; 64] };
        assert!(matches!(extract(&grid), Err(ExportError::Degenerate(_))));
    }
}
