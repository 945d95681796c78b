//! Triangle mesh (binary little-endian PLY) and a small median-split BVH over it, for the
//! diagnostics that compare our surfel pipeline with a scene's ground-truth mesh.
//! Diagnostic only: no SAH, no SIMD; correct and simple.

use anyhow::{bail, Context, Result};
use glam::Vec3;
use std::path::Path;

/// A triangle mesh: vertex positions, optional vertex normals, triangles.
pub struct Mesh {
    /// Vertex positions.
    pub verts: Vec<Vec3>,
    /// Per-vertex normals from the file (zero if absent).
    pub vnormals: Vec<Vec3>,
    /// Triangles as vertex indices.
    pub idx: Vec<[u32; 3]>,
}

/// Reads a binary little-endian PLY with `vertex` (x, y, z, optional nx, ny, nz) and `face` elements.
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    let bytes = std::fs::read(path).with_context(|| format!("{}", path.display()))?;
    let end = bytes.windows(11).position(|w| w == b"end_header\n").context("no end_header")? + 11;
    let header = std::str::from_utf8(&bytes[..end])?;
    let (mut nv, mut nf, mut vprops, mut in_vertex) = (0usize, 0usize, Vec::new(), false);
    let mut face_idx_ty = String::new();
    for line in header.lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["format", f, ..] if *f != "binary_little_endian" => bail!("unsupported PLY format {f}"),
            ["element", "vertex", n] => (nv, in_vertex) = (n.parse()?, true),
            ["element", "face", n] => (nf, in_vertex) = (n.parse()?, false),
            ["property", "list", c, i, _] => {
                if *c != "uchar" {
                    bail!("face count type {c}");
                }
                face_idx_ty = i.to_string();
            }
            ["property", ty, name] if in_vertex => {
                if *ty != "float" {
                    bail!("vertex property {name} has type {ty}");
                }
                vprops.push(name.to_string());
            }
            _ => {}
        }
    }
    if !(face_idx_ty == "uint" || face_idx_ty == "int") {
        bail!("face index type {face_idx_ty}");
    }
    let stride = vprops.len() * 4;
    let col = |n: &str| vprops.iter().position(|p| p == n).context("missing x/y/z");
    let (cx, cy, cz) = (col("x")?, col("y")?, col("z")?);
    let ncol = (col("nx").ok(), col("ny").ok(), col("nz").ok());
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let verts: Vec<Vec3> = (0..nv)
        .map(|i| {
            let b = end + i * stride;
            Vec3::new(f32_at(b + 4 * cx), f32_at(b + 4 * cy), f32_at(b + 4 * cz))
        })
        .collect();
    let vnormals: Vec<Vec3> = (0..nv)
        .map(|i| {
            let b = end + i * stride;
            match ncol {
                (Some(x), Some(y), Some(z)) => {
                    Vec3::new(f32_at(b + 4 * x), f32_at(b + 4 * y), f32_at(b + 4 * z)).normalize_or_zero()
                }
                _ => Vec3::ZERO,
            }
        })
        .collect();
    let mut o = end + nv * stride;
    let mut tris = Vec::with_capacity(nf);
    for _ in 0..nf {
        let c = bytes[o] as usize;
        o += 1;
        let idx: Vec<u32> =
            (0..c).map(|k| u32::from_le_bytes(bytes[o + 4 * k..o + 4 * k + 4].try_into().unwrap())).collect();
        o += 4 * c;
        if idx.iter().any(|&i| i as usize >= nv) {
            bail!("face index out of range");
        }
        for k in 1..c.saturating_sub(1) {
            tris.push([idx[0], idx[k], idx[k + 1]]);
        }
    }
    Ok(Mesh { verts, vnormals, idx: tris })
}

/// A BVH node: bounds and either two children or a triangle range.
#[derive(Clone, Copy)]
pub struct Node {
    lo: Vec3,
    hi: Vec3,
    /// Leaf: first triangle; inner: left child (right = left + 1).
    first: u32,
    /// Triangle count for a leaf, 0 for an inner node.
    count: u32,
}

/// A median-split BVH over a mesh's triangles.
pub struct Bvh {
    /// Nodes, the root first.
    pub nodes: Vec<Node>,
    /// Triangles in BVH order, with their index in the mesh.
    tris: Vec<([Vec3; 3], u32)>,
}

/// A closest hit: distance, mesh triangle, barycentrics (of vertices 1 and 2).
#[derive(Clone, Copy)]
pub struct Hit {
    /// Ray distance.
    pub t: f32,
    /// Index of the triangle in the mesh.
    pub tri: u32,
    /// Barycentric of vertex 1.
    pub u: f32,
    /// Barycentric of vertex 2.
    pub v: f32,
}

impl Bvh {
    /// Builds the BVH by median splits along the longest axis.
    pub fn build(mesh: &Mesh) -> Bvh {
        let mut tris: Vec<([Vec3; 3], u32)> =
            mesh.idx.iter().enumerate().map(|(i, t)| (t.map(|k| mesh.verts[k as usize]), i as u32)).collect();
        let mut nodes = vec![Node { lo: Vec3::ZERO, hi: Vec3::ZERO, first: 0, count: 0 }];
        let n = tris.len();
        Self::build_rec(&mut nodes, &mut tris, 0, 0, n);
        Bvh { nodes, tris }
    }

    fn build_rec(nodes: &mut Vec<Node>, tris: &mut [([Vec3; 3], u32)], node: usize, a: usize, b: usize) {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        let (mut clo, mut chi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for (t, _) in &tris[a..b] {
            for p in t {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
            let c = (t[0] + t[1] + t[2]) / 3.0;
            clo = clo.min(c);
            chi = chi.max(c);
        }
        nodes[node].lo = lo;
        nodes[node].hi = hi;
        if b - a <= 4 {
            nodes[node].first = a as u32;
            nodes[node].count = (b - a) as u32;
            return;
        }
        let ext = chi - clo;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        let mid = (a + b) / 2;
        let key = |t: &([Vec3; 3], u32)| t.0[0][axis] + t.0[1][axis] + t.0[2][axis];
        tris[a..b].select_nth_unstable_by(mid - a, |p, q| key(p).total_cmp(&key(q)));
        let left = nodes.len();
        nodes.push(Node { lo: Vec3::ZERO, hi: Vec3::ZERO, first: 0, count: 0 });
        nodes.push(Node { lo: Vec3::ZERO, hi: Vec3::ZERO, first: 0, count: 0 });
        nodes[node].first = left as u32;
        nodes[node].count = 0;
        Self::build_rec(nodes, tris, left, a, mid);
        Self::build_rec(nodes, tris, left + 1, mid, b);
    }

    /// Closest hit with t in (tmin, tmax), or with `any` the first hit found.
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, mut tmax: f32, any: bool) -> Option<Hit> {
        let inv = d.recip();
        let mut stack = [0u32; 64];
        let mut sp = 1;
        let mut best = None;
        while sp > 0 {
            sp -= 1;
            let nd = &self.nodes[stack[sp] as usize];
            let t0 = (nd.lo - o) * inv;
            let t1 = (nd.hi - o) * inv;
            let tn = t0.min(t1).max_element().max(tmin);
            let tf = t0.max(t1).min_element().min(tmax);
            if tn > tf {
                continue;
            }
            if nd.count > 0 {
                for i in nd.first as usize..(nd.first + nd.count) as usize {
                    if let Some((t, u, v)) = tri_hit(&self.tris[i].0, o, d) {
                        if t > tmin && t < tmax {
                            tmax = t;
                            best = Some(Hit { t, tri: self.tris[i].1, u, v });
                            if any {
                                return best;
                            }
                        }
                    }
                }
            } else {
                stack[sp] = nd.first;
                stack[sp + 1] = nd.first + 1;
                sp += 2;
            }
        }
        best
    }
}

/// Moeller-Trumbore; both faces.
#[inline]
pub fn tri_hit(t: &[Vec3; 3], o: Vec3, d: Vec3) -> Option<(f32, f32, f32)> {
    let e1 = t[1] - t[0];
    let e2 = t[2] - t[0];
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - t[0];
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some((e2.dot(q) * inv, u, v))
}
