//! The viewer's model: per surfel its geometry, its M = 4 Gaussian vertices' materials and
//! their precomputed radiance transfer (PRT), flattened exactly as the page uploads them.
//!
//! Transfer (SPEC 4's rendering equation with the light factored out): for vertex m of
//! Gaussian i with shading normal n_m, over the K Fibonacci directions of i's micro-buffer,
//! `T_{m,j} = 2 pi / K sum_k V_ik max(0, n_m . w_k) Y_j(w_k)`, so that the diffuse irradiance
//! under a light with SH coefficients `L_j` is `sum_j L_j T_{m,j}`. Visibility is the traced
//! micro-buffer's (SPEC 5).
//!
//! Optionally (`bounce`) the transfer also carries a diffuse one-bounce term, per colour channel:
//! a direction k that hits Gaussian h at (u~, v~) receives h's diffuse radiance
//! `a_h(u~, v~) / pi * sum_j L_j E_{h,j}(u~, v~)` (h's albedo and its transfer over the directions
//! that escape, as Eqn 13 gathers, bilinear so `T_{m,j,c} += 2 pi / K sum_k [hit] max(0, n_m . w_k) a_{h,c} / pi E_{h,j}`.
//! It is SPEC 7's Eqn 13 with the hit's BRDF reduced to its diffuse lobe and the light to its
//! SH projection.
//!
//! Materials and transfer are rounded to IEEE half floats, as the page file stores them.
//!
//! Work split: rayon over Gaussians, each writing its own rows.

use glam::Vec3;
use rayon::prelude::*;
use svgir_core::sh::{basis, num_coeffs, SH_C0};
use svgir_trace::pack::{f16_from_f32, f16_to_f32};
use svgir_trace::MicroBuffer;

/// Floats of geometry per surfel: centre, opacity; t_u, s_u; t_v, s_v; normal, 0.
pub const GEOM_FLOATS: usize = 16;
/// Floats of material per vertex: albedo, roughness; shading normal, front visibility; back
/// visibility, 0, 0, 0.
pub const MAT_FLOATS: usize = 12;
/// Gaussian vertices per surfel the viewer supports (SPEC 3's default).
pub const VERTICES: usize = 4;

/// Why a model cannot be viewed.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// The model's Gaussian vertices per surfel (M) is not [`VERTICES`].
    #[error("the model has M = {0} Gaussian vertices per surfel; the viewer supports M = 4 (SPEC 3's default)")]
    Vertices(usize),
    /// The requested SH degree of the transfer is outside 1..=3.
    #[error("SH degree {0} is not supported (1..=3)")]
    Degree(u32),
    /// The model has no surfels.
    #[error("the model has no Gaussians")]
    Empty,
    /// Array lengths disagree (surfels, micro-buffers, vertex materials) or the materials
    /// cannot be activated; the message says which.
    #[error("{0}")]
    Inconsistent(String),
}

/// Everything the page (and the oracle) renders, as flat f32 arrays.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewModel {
    /// Surfels.
    pub n: usize,
    /// SH degree of the transfer (1..=3).
    pub degree: u32,
    /// Transfer channels: 1 (visibility only, grey) or 3 (with the coloured one-bounce term).
    pub channels: usize,
    /// Transfer for both sides (the back side's follows the front's: `n x VERTICES` vertices
    /// each); a surfel seen from behind is shaded with its back side and negated normals.
    pub two_sided: bool,
    /// Diffuse weighted by `1 - (F0 A + B)` (svgir's layered diffuse, `--diffuse layered`).
    pub layered: bool,
    /// `n x GEOM_FLOATS`.
    pub geom: Vec<f32>,
    /// `n x VERTICES x MAT_FLOATS`.
    pub mats: Vec<f32>,
    /// `sides x n x VERTICES x channels x coeffs()` transfer coefficients (channel-major per
    /// vertex).
    pub transfer: Vec<f32>,
}

/// How the transfer is built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Options {
    /// SH degree (1..=3).
    pub degree: u32,
    /// Add the diffuse one-bounce term (3 channels).
    pub bounce: bool,
    /// The model's diffuse is layered under the specular (`Diffuse::Layered`).
    pub layered: bool,
}

/// Per-vertex activated materials (SPEC 3), as `svgir_pbr::ActivatedMaterials` lays them out.
#[derive(Clone, Copy)]
pub struct VertexData<'a> {
    /// RGB per vertex.
    pub albedo: &'a [f32],
    /// One per vertex.
    pub roughness: &'a [f32],
    /// Unit shading normal per vertex.
    pub normals: &'a [f32],
}

impl ViewModel {
    /// SH coefficients per channel.
    pub fn coeffs(&self) -> usize {
        num_coeffs(self.degree)
    }

    /// 1, or 2 for a two-sided model.
    pub fn sides(&self) -> usize {
        1 + usize::from(self.two_sided)
    }

    /// Transfer values per vertex and side (`channels x coeffs()`).
    pub fn per_vertex(&self) -> usize {
        self.channels * self.coeffs()
    }

    /// Bytes per surfel of the arrays the page uploads (float32 textures; the page file holds
    /// materials and transfer as f16, [`ViewModel::file_bytes_per_surfel`]).
    pub fn bytes_per_surfel(&self) -> usize {
        4 * (GEOM_FLOATS + VERTICES * (MAT_FLOATS + self.sides() * self.per_vertex()))
    }

    /// Bytes per surfel in the page file (before base64): geometry f32, the rest f16.
    pub fn file_bytes_per_surfel(&self) -> usize {
        4 * GEOM_FLOATS + 2 * VERTICES * (MAT_FLOATS + self.sides() * self.per_vertex())
    }

    /// Builds the model from surfels, their vertex materials and micro-buffers traced over the
    /// surfels' normals (`front.len() == surfels.len()`), and for a model shaded two-sided
    /// (svgir's measured profile) micro-buffers over the negated normals (`back`).
    pub fn build(
        surfels: &svgir_core::Surfels,
        mats: &VertexData,
        m: usize,
        front: &MicroBuffer,
        back: Option<&MicroBuffer>,
        opts: Options,
    ) -> Result<Self, ViewError> {
        let n = surfels.len();
        let Options { degree, bounce, layered } = opts;
        if m != VERTICES {
            return Err(ViewError::Vertices(m));
        }
        if !(1..=3).contains(&degree) {
            return Err(ViewError::Degree(degree));
        }
        if n == 0 {
            return Err(ViewError::Empty);
        }
        if front.len() != n
            || back.is_some_and(|b| b.len() != n)
            || mats.albedo.len() != n * m * 3
            || mats.roughness.len() != n * m
            || mats.normals.len() != n * m * 3
        {
            return Err(ViewError::Inconsistent(format!(
                "{n} surfels but {} micro-buffers and {} vertex albedos",
                front.len(),
                mats.albedo.len() / 3
            )));
        }
        let mut geom = vec![0.0f32; n * GEOM_FLOATS];
        for (i, g) in geom.chunks_exact_mut(GEOM_FLOATS).enumerate() {
            let r = surfels.rotation_matrix(i);
            let s = surfels.scale(i);
            let p = surfels.positions[i];
            g.copy_from_slice(&[
                p.x,
                p.y,
                p.z,
                surfels.opacity(i),
                r.x_axis.x,
                r.x_axis.y,
                r.x_axis.z,
                s.x,
                r.y_axis.x,
                r.y_axis.y,
                r.y_axis.z,
                s.y,
                r.z_axis.x,
                r.z_axis.y,
                r.z_axis.z,
                0.0,
            ]);
        }
        let c = num_coeffs(degree);
        let flipped: Vec<f32> = mats.normals.iter().map(|x| -x).collect();
        let back_mats = VertexData { normals: &flipped, ..*mats };
        let sides: Vec<(&MicroBuffer, &VertexData)> =
            std::iter::once((front, mats)).chain(back.map(|b| (b, &back_mats))).collect();
        let direct: Vec<Vec<f32>> = sides.iter().map(|(mb, md)| direct_transfer(mb, md, m, degree, false)).collect();
        // What a hit Gaussian reflects: Eqn 13 gathers only its escaping directions.
        let escape = if bounce { direct_transfer(front, mats, m, degree, true) } else { Vec::new() };
        let channels = if bounce { 3 } else { 1 };
        let mut transfer = Vec::with_capacity(sides.len() * n * m * channels * c);
        for ((mb, md), d) in sides.iter().zip(&direct) {
            // The bounce reads the hit Gaussians' front-side transfer (the side a ray meets is
            // not tracked here).
            if bounce {
                transfer.extend(with_bounce(d, &escape, md, mats, m, c, mb));
            } else {
                transfer.extend_from_slice(d);
            }
        }
        let mut mat = vec![0.0f32; n * m * MAT_FLOATS];
        // Unoccluded transfer DC is pi * Y_00 (the cosine lobe): the ratio is the cosine-weighted
        // visibility, the page's "visibility" view and its specular occlusion.
        let vis = |side: usize, q: usize| (direct[side][q * c] / (std::f32::consts::PI * SH_C0)).clamp(0.0, 1.0);
        for (q, o) in mat.chunks_exact_mut(MAT_FLOATS).enumerate() {
            let a = &mats.albedo[3 * q..3 * q + 3];
            let nm = vec3(mats.normals, q);
            let back_vis = if direct.len() > 1 { vis(1, q) } else { 0.0 };
            o.copy_from_slice(&[
                a[0],
                a[1],
                a[2],
                mats.roughness[q],
                nm.x,
                nm.y,
                nm.z,
                vis(0, q),
                back_vis,
                0.0,
                0.0,
                0.0,
            ]);
        }
        // The page stores materials and transfer as IEEE half floats (half the page size); the
        // model holds the same rounded values so the oracle shades what the page shades.
        for v in mat.iter_mut().chain(transfer.iter_mut()) {
            *v = f16_to_f32(f16_from_f32(*v));
        }
        Ok(Self { n, degree, channels, two_sided: back.is_some(), layered, geom, mats: mat, transfer })
    }
}

/// `T_{m,j}` of every vertex (`n x m x c`) over `mb`'s directions, weighted by the traced
/// visibility, or with `escape_only` by "the ray hit nothing" (Eqn 13's `[I_h^s = -1]`).
pub fn direct_transfer(mb: &MicroBuffer, mats: &VertexData, m: usize, degree: u32, escape_only: bool) -> Vec<f32> {
    let c = num_coeffs(degree);
    let mut transfer = vec![0.0f32; mb.len() * m * c];
    transfer.par_chunks_mut(m * c).enumerate().for_each(|(i, t)| {
        let mut acc = vec![0.0f64; m * c];
        let mut b = [0.0f32; 16];
        for k in 0..mb.k {
            let v = if escape_only { f32::from(mb.escaped(i, k)) } else { mb.visibility(i, k) };
            if v <= 0.0 {
                continue;
            }
            let d = mb.direction(i, k);
            basis(degree, d, &mut b);
            for vtx in 0..m {
                let nm = vec3(mats.normals, i * m + vtx);
                let cos = nm.dot(d).max(0.0);
                for j in 0..c {
                    acc[vtx * c + j] += (v * cos * b[j]) as f64;
                }
            }
        }
        let w = std::f64::consts::TAU / mb.k as f64;
        for (o, a) in t.iter_mut().zip(&acc) {
            *o = (a * w) as f32;
        }
    });
    transfer
}

/// Direct transfer (`n x m x c`) plus the diffuse one-bounce term, per channel (`n x m x 3 x c`);
/// `hits` and `hit_mats` give the hit Gaussians' transfer and albedo.
fn with_bounce(
    direct: &[f32],
    hits: &[f32],
    mats: &VertexData,
    hit_mats: &VertexData,
    m: usize,
    c: usize,
    mb: &MicroBuffer,
) -> Vec<f32> {
    let n = mb.len();
    let mut out = vec![0.0f32; n * m * 3 * c];
    out.par_chunks_mut(m * 3 * c).enumerate().for_each(|(i, t)| {
        let mut acc = vec![0.0f64; m * 3 * c];
        let mut th = vec![0.0f32; c];
        for k in 0..mb.k {
            let Some(h) = mb.hit(i, k) else { continue };
            let h = h as usize;
            let [u, v] = mb.uv(i, k);
            let w = [(1.0 - u) * (1.0 - v), u * (1.0 - v), (1.0 - u) * v, u * v];
            let mut a = [0.0f32; 3];
            th.iter_mut().for_each(|x| *x = 0.0);
            for (vm, wm) in w.iter().enumerate().take(m) {
                let q = h * m + vm;
                for ch in 0..3 {
                    a[ch] += wm * hit_mats.albedo[3 * q + ch];
                }
                for j in 0..c {
                    th[j] += wm * hits[q * c + j];
                }
            }
            let d = mb.direction(i, k);
            for vtx in 0..m {
                let cos = vec3(mats.normals, i * m + vtx).dot(d).max(0.0);
                if cos <= 0.0 {
                    continue;
                }
                for ch in 0..3 {
                    let s = cos * a[ch] / std::f32::consts::PI;
                    for j in 0..c {
                        acc[(vtx * 3 + ch) * c + j] += (s * th[j]) as f64;
                    }
                }
            }
        }
        let wk = std::f64::consts::TAU / mb.k as f64;
        for vtx in 0..m {
            for ch in 0..3 {
                for j in 0..c {
                    let o = (vtx * 3 + ch) * c + j;
                    t[o] = direct[(i * m + vtx) * c + j] + (acc[o] * wk) as f32;
                }
            }
        }
    });
    out
}

fn vec3(v: &[f32], q: usize) -> Vec3 {
    Vec3::new(v[3 * q], v[3 * q + 1], v[3 * q + 2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec2};
    use svgir_core::{ShCoeffs, Surfels};
    use svgir_trace::{Bvh, TraceParams};

    fn opts(degree: u32, bounce: bool) -> Options {
        Options { degree, bounce, layered: false }
    }

    /// Two facing disks: each half-occludes the other's hemisphere.
    fn pair() -> (Surfels, MicroBuffer) {
        let mut s = Surfels::with_capacity(3, 0);
        s.push(Vec3::ZERO, Quat::IDENTITY, Vec2::splat(0.1f32.ln()), 3.0, ShCoeffs::default());
        s.push(
            Vec3::new(0.3, 0.0, 0.8),
            Quat::from_rotation_y(2.8),
            Vec2::splat(0.5f32.ln()),
            3.0,
            ShCoeffs::default(),
        );
        s.push(
            Vec3::new(-2.0, 0.0, 0.0),
            Quat::from_rotation_y(-0.4),
            Vec2::splat(0.1f32.ln()),
            3.0,
            ShCoeffs::default(),
        );
        let mb = MicroBuffer::trace(&Bvh::build(&s), &s, 256, 1, &TraceParams::default()).unwrap();
        (s, mb)
    }

    #[test]
    fn transfer_under_a_constant_light_is_the_direct_cosine_sum() {
        let (s, mb) = pair();
        let n = s.len();
        let normals: Vec<f32> = (0..n)
            .flat_map(|i| {
                let g = s.normal(i);
                (0..VERTICES).flat_map(move |m| (g + Vec3::new(0.1 * m as f32, -0.05, 0.0)).normalize().to_array())
            })
            .collect();
        let albedo = vec![0.5; n * VERTICES * 3];
        let rough = vec![0.5; n * VERTICES];
        let data = VertexData { albedo: &albedo, roughness: &rough, normals: &normals };
        let model = ViewModel::build(&s, &data, VERTICES, &mb, None, opts(2, false)).unwrap();
        // A constant light L has SH (L * 4 pi Y_00, 0, ...): irradiance L * T_0 * 4 pi Y_00 must
        // equal the obvious sum 2 pi / K sum_k V_k max(0, n_m . w_k) L.
        let mut occluded = false;
        for i in 0..n {
            for m in 0..VERTICES {
                let q = i * VERTICES + m;
                let nm = Vec3::new(normals[3 * q], normals[3 * q + 1], normals[3 * q + 2]);
                let want: f64 =
                    (0..mb.k).map(|k| (mb.visibility(i, k) * nm.dot(mb.direction(i, k)).max(0.0)) as f64).sum::<f64>()
                        * std::f64::consts::TAU
                        / mb.k as f64;
                let got = model.transfer[q * 9] as f64 * 4.0 * std::f64::consts::PI * SH_C0 as f64;
                assert!((got - want).abs() < 2e-3 * want.max(0.1), "vertex {q}: {got} vs {want}");
                occluded |= model.mats[q * MAT_FLOATS + 7] < 0.9;
            }
        }
        assert!(occluded, "the facing disks shadow each other");
        assert_eq!(model.bytes_per_surfel(), 4 * (16 + 4 * (12 + 9)));
    }

    #[test]
    fn the_bounce_term_is_coloured_by_the_hit_albedo() {
        let (s, mb) = pair();
        let n = s.len();
        let normals: Vec<f32> = (0..n * VERTICES).flat_map(|q| s.normal(q / VERTICES).to_array()).collect();
        let albedo: Vec<f32> = (0..n * VERTICES).flat_map(|_| [0.8, 0.4, 0.0]).collect();
        let rough = vec![0.5; n * VERTICES];
        let data = VertexData { albedo: &albedo, roughness: &rough, normals: &normals };
        let direct = ViewModel::build(&s, &data, VERTICES, &mb, None, opts(2, false)).unwrap();
        let bounce = ViewModel::build(&s, &data, VERTICES, &mb, None, opts(2, true)).unwrap();
        assert_eq!((bounce.channels, bounce.per_vertex()), (3, 27));
        let mut lit = 0;
        for q in 0..n * VERTICES {
            let d = &direct.transfer[q * 9..q * 9 + 9];
            let b = &bounce.transfer[q * 27..q * 27 + 27];
            // Blue: albedo 0, no bounce. Red: twice green's bounce (f16 rounding aside).
            for j in 0..9 {
                assert!((b[18 + j] - d[j]).abs() <= 1e-3 * d[j].abs().max(1e-3), "q {q} j {j}");
                let (red, green) = (b[j] - d[j], b[9 + j] - d[j]);
                assert!((red - 2.0 * green).abs() <= 2e-3 * red.abs().max(1e-2), "q {q} j {j}: {red} {green}");
            }
            lit += usize::from(b[0] - d[0] > 1e-3);
        }
        assert!(lit > 0, "the facing disks light each other");
    }

    #[test]
    fn bad_shapes_are_errors() {
        let (s, mb) = pair();
        let v = vec![0.5; s.len() * 6 * 3];
        let data = VertexData { albedo: &v, roughness: &v[..s.len() * 6], normals: &v };
        assert!(matches!(ViewModel::build(&s, &data, 6, &mb, None, opts(2, false)), Err(ViewError::Vertices(6))));
        let v4 = vec![0.5; s.len() * 4 * 3];
        let data = VertexData { albedo: &v4, roughness: &v4[..s.len() * 4], normals: &v4 };
        assert!(matches!(ViewModel::build(&s, &data, 4, &mb, None, opts(4, false)), Err(ViewError::Degree(4))));
        assert!(ViewModel::build(&s, &data, 4, &mb, None, opts(2, false)).is_ok());
    }
}
