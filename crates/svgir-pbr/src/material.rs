//! Spatially-varying Gaussian materials (SPEC 3): every surfel carries M in {1, 2, 4, 6} Gaussian
//! vertices, each with raw albedo (3), raw roughness (1) and a normal offset (3), all initialised
//! to 0. Activations: `albedo = 0.77 sigmoid(x) + 0.03`, `roughness = 0.9 sigmoid(x) + 0.09`,
//! shading normal `n_m = normalize(n + dN_m)` with n the Gaussian's geometric normal as the caller
//! gives it. No metallic channel (F0 = 0.04 lives in the BRDF).
//!
//! Layout: structure of arrays indexed by vertex `i * M + m` (x3 for albedo and offsets), the
//! layout `svgir_trace::VertexMaterials` reads. Work split: rayon over Gaussians; nothing is saved
//! for backward, which recomputes the (cheap) activations from the raw values.

use crate::activation::sigmoid;
use crate::{expect_len, PbrError};
use glam::Vec3;
use rayon::prelude::*;
use svgir_core::Float;
use svgir_shading::float::dot;
use svgir_trace::VertexMaterials;

/// Albedo activation `ALBEDO_SCALE sigmoid(x) + ALBEDO_BIAS` (SPEC 3): range [0.03, 0.8].
pub const ALBEDO_SCALE: f64 = 0.77;
/// Albedo activation offset (see [`ALBEDO_SCALE`]).
pub const ALBEDO_BIAS: f64 = 0.03;
/// Roughness activation `ROUGHNESS_SCALE sigmoid(x) + ROUGHNESS_BIAS` (SPEC 3): range [0.09, 0.99].
pub const ROUGHNESS_SCALE: f64 = 0.9;
/// Roughness activation offset (see [`ROUGHNESS_SCALE`]).
pub const ROUGHNESS_BIAS: f64 = 0.09;
/// Below this length `n + dN` has no direction; the vertex falls back to n (zero gradient).
const MIN_NORMAL_LEN: f64 = 1e-12;

/// Whether `m` is a supported vertex count (SPEC 3).
pub fn valid_m(m: usize) -> bool {
    matches!(m, 1 | 2 | 4 | 6)
}

/// Raw, trainable per-vertex materials of N Gaussians.
#[derive(Clone, Debug, PartialEq)]
pub struct SvgMaterials {
    /// Vertices per Gaussian: 1, 2, 4 or 6.
    pub m: usize,
    /// N * M * 3.
    pub albedo_raw: Vec<f32>,
    /// N * M.
    pub roughness_raw: Vec<f32>,
    /// N * M * 3, no activation.
    pub normal_offset: Vec<f32>,
}

/// Activated materials in the `VertexMaterials` layout.
#[derive(Clone, Debug, PartialEq)]
pub struct ActivatedMaterials<F = f32> {
    /// Vertices per Gaussian: 1, 2, 4 or 6.
    pub m: usize,
    /// Linear albedo per vertex and channel, N x M x 3, in [0.03, 0.8].
    pub albedo: Vec<F>,
    /// Roughness per vertex, N x M, in [0.09, 0.99].
    pub roughness: Vec<F>,
    /// Unit shading normals.
    pub normals: Vec<F>,
}

impl<F> ActivatedMaterials<F> {
    /// Borrow as the [`VertexMaterials`] the tracer and shading read.
    pub fn view(&self) -> VertexMaterials<'_, F> {
        VertexMaterials { m: self.m, albedo: &self.albedo, roughness: &self.roughness, normals: &self.normals }
    }
}

/// Gradients with respect to the raw parameters, laid out like [`SvgMaterials`].
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialGrads<F = f32> {
    /// dL / d raw albedo, N x M x 3.
    pub v_albedo_raw: Vec<F>,
    /// dL / d raw roughness, N x M.
    pub v_roughness_raw: Vec<F>,
    /// dL / d normal offset, N x M x 3.
    pub v_normal_offset: Vec<F>,
}

impl SvgMaterials {
    /// N Gaussians with M vertices each, all raw values 0 (SPEC 3).
    pub fn new(n: usize, m: usize) -> Result<Self, PbrError> {
        if !valid_m(m) {
            return Err(PbrError::InvalidParameter(format!("M = {m} (must be 1, 2, 4 or 6)")));
        }
        Ok(Self {
            m,
            albedo_raw: vec![0.0; n * m * 3],
            roughness_raw: vec![0.0; n * m],
            normal_offset: vec![0.0; n * m * 3],
        })
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.roughness_raw.len() / self.m.max(1)
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.roughness_raw.is_empty()
    }

    /// Check M and that the arrays hold N Gaussians' worth of values.
    pub fn validate(&self, n: usize) -> Result<(), PbrError> {
        check_shapes(self.m, n, &self.albedo_raw, &self.roughness_raw, &self.normal_offset)
    }

    /// Keep the Gaussians with `keep[i]` (mirrors `Surfels::retain`).
    pub fn retain(&mut self, keep: &[bool]) -> Result<(), PbrError> {
        let n = self.len();
        self.validate(n)?;
        expect_len("keep", keep.len(), n)?;
        let m = self.m;
        let filter = |v: &mut Vec<f32>, w: usize| {
            let mut o = 0;
            for i in 0..n {
                if keep[i] {
                    v.copy_within(i * w..(i + 1) * w, o * w);
                    o += 1;
                }
            }
            v.truncate(o * w);
        };
        filter(&mut self.albedo_raw, m * 3);
        filter(&mut self.roughness_raw, m);
        filter(&mut self.normal_offset, m * 3);
        Ok(())
    }

    /// Activated albedo, roughness and shading normals; `normals` are the N geometric normals.
    pub fn activated(&self, normals: &[Vec3]) -> Result<ActivatedMaterials, PbrError> {
        activate(self.m, &self.albedo_raw, &self.roughness_raw, &self.normal_offset, normals)
    }

    /// Chain gradients of the activated quantities (e.g. from [`crate::PbrGrads`]) to the raw ones.
    pub fn backward(
        &self,
        normals: &[Vec3],
        v_albedo: &[f32],
        v_roughness: &[f32],
        v_normals: &[f32],
    ) -> Result<MaterialGrads, PbrError> {
        activate_backward(
            self.m,
            &self.albedo_raw,
            &self.roughness_raw,
            &self.normal_offset,
            normals,
            v_albedo,
            v_roughness,
            v_normals,
        )
    }

    /// Mean over vertices of `|dN|^2` and its gradient (the normal-offset regulariser, SPEC 6 / 9.7).
    pub fn offset_penalty(&self) -> (f32, Vec<f32>) {
        let count = (self.normal_offset.len() / 3).max(1) as f32;
        let value = self.normal_offset.iter().map(|x| x * x).sum::<f32>() / count;
        (value, self.normal_offset.par_iter().with_min_len(4096).map(|x| 2.0 * x / count).collect())
    }
}

fn check_shapes<F>(m: usize, n: usize, albedo: &[F], rough: &[F], offset: &[F]) -> Result<(), PbrError> {
    if !valid_m(m) {
        return Err(PbrError::InvalidParameter(format!("M = {m} (must be 1, 2, 4 or 6)")));
    }
    expect_len("albedo_raw", albedo.len(), n * m * 3)?;
    expect_len("roughness_raw", rough.len(), n * m)?;
    expect_len("normal_offset", offset.len(), n * m * 3)
}

#[inline(always)]
fn albedo_of<F: Float>(x: F) -> F {
    F::from_f64(ALBEDO_SCALE) * sigmoid(x) + F::from_f64(ALBEDO_BIAS)
}

/// Raw parameter whose activated albedo is `a` (clamped into the activation's open range), for
/// setting materials from outside (diagnostics that load ground truth).
pub fn albedo_raw_for(a: f32) -> f32 {
    logit_clamped((a as f64 - ALBEDO_BIAS) / ALBEDO_SCALE)
}

/// Raw parameter whose activated roughness is `r` (clamped as [`albedo_raw_for`]).
pub fn roughness_raw_for(r: f32) -> f32 {
    logit_clamped((r as f64 - ROUGHNESS_BIAS) / ROUGHNESS_SCALE)
}

fn logit_clamped(s: f64) -> f32 {
    let s = s.clamp(1e-4, 1.0 - 1e-4);
    (s / (1.0 - s)).ln() as f32
}

#[inline(always)]
fn roughness_of<F: Float>(x: F) -> F {
    F::from_f64(ROUGHNESS_SCALE) * sigmoid(x) + F::from_f64(ROUGHNESS_BIAS)
}

/// `u = n + dN`, its length, and the unit shading normal (n itself if u is degenerate).
#[inline]
fn offset_normal<F: Float>(n: Vec3, d: &[F]) -> ([F; 3], F, bool) {
    let u = [F::from_f32(n.x) + d[0], F::from_f32(n.y) + d[1], F::from_f32(n.z) + d[2]];
    let len = dot(u, u).sqrt();
    if len > F::from_f64(MIN_NORMAL_LEN) {
        (u.map(|x| x / len), len, true)
    } else {
        ([n.x, n.y, n.z].map(F::from_f32), F::ONE, false)
    }
}

/// Values per rayon task of the element-wise activations.
const CHUNK: usize = 4096;

/// `x.map(f)` as plain loops over chunks, in parallel: the loop bodies vectorise (a `map` over a
/// parallel iterator left each value to a scalar call).
fn map_in_chunks<F: Float>(x: &[F], f: impl Fn(F) -> F + Sync) -> Vec<F> {
    let mut out = vec![F::ZERO; x.len()];
    out.par_chunks_mut(CHUNK).zip(x.par_chunks(CHUNK)).for_each(|(o, x)| {
        for (o, &x) in o.iter_mut().zip(x) {
            *o = f(x);
        }
    });
    out
}

/// `x.zip(y).map(f)` as [`map_in_chunks`].
fn zip_in_chunks<F: Float>(x: &[F], y: &[F], f: impl Fn(F, F) -> F + Sync) -> Vec<F> {
    let mut out = vec![F::ZERO; x.len()];
    out.par_chunks_mut(CHUNK).zip(x.par_chunks(CHUNK).zip(y.par_chunks(CHUNK))).for_each(|(o, (x, y))| {
        for ((o, &x), &y) in o.iter_mut().zip(x).zip(y) {
            *o = f(x, y);
        }
    });
    out
}

/// SPEC 3 activations for N = `normals.len()` Gaussians (generic; f64 for the tests).
pub fn activate<F: Float>(
    m: usize,
    albedo_raw: &[F],
    roughness_raw: &[F],
    normal_offset: &[F],
    normals: &[Vec3],
) -> Result<ActivatedMaterials<F>, PbrError> {
    check_shapes(m, normals.len(), albedo_raw, roughness_raw, normal_offset)?;
    let albedo = map_in_chunks(albedo_raw, albedo_of);
    let roughness = map_in_chunks(roughness_raw, roughness_of);
    let mut shading = vec![F::ZERO; normal_offset.len()];
    shading.par_chunks_mut(3).zip(normal_offset.par_chunks(3)).enumerate().with_min_len(1024).for_each(
        |(v, (out, d))| {
            out.copy_from_slice(&offset_normal(normals[v / m], d).0);
        },
    );
    Ok(ActivatedMaterials { m, albedo, roughness, normals: shading })
}

/// Backward of [`activate`]: sigmoid chains for albedo and roughness, and for the normals
/// `d n_m / d dN = (I - n_m n_m^T) / |n + dN|`.
pub fn activate_backward<F: Float>(
    m: usize,
    albedo_raw: &[F],
    roughness_raw: &[F],
    normal_offset: &[F],
    normals: &[Vec3],
    v_albedo: &[F],
    v_roughness: &[F],
    v_normals: &[F],
) -> Result<MaterialGrads<F>, PbrError> {
    check_shapes(m, normals.len(), albedo_raw, roughness_raw, normal_offset)?;
    check_shapes(m, normals.len(), v_albedo, v_roughness, v_normals)?;
    // A Gaussian no view pixel saw has zero gradients (about half of them per view): it keeps
    // the zero itself (its sign included), selected rather than branched to so that the loop
    // vectorises.
    let dsig = |x: F, g: F, scale: f64| {
        let s = sigmoid(x);
        let d = g * F::from_f64(scale) * s * (F::ONE - s);
        if g == F::ZERO {
            g
        } else {
            d
        }
    };
    let v_albedo_raw = zip_in_chunks(albedo_raw, v_albedo, |x, g| dsig(x, g, ALBEDO_SCALE));
    let v_roughness_raw = zip_in_chunks(roughness_raw, v_roughness, |x, g| dsig(x, g, ROUGHNESS_SCALE));
    let mut v_normal_offset = vec![F::ZERO; normal_offset.len()];
    v_normal_offset
        .par_chunks_mut(3)
        .zip(normal_offset.par_chunks(3))
        .zip(v_normals.par_chunks(3))
        .enumerate()
        .with_min_len(1024)
        .for_each(|(v, ((out, d), g))| {
            // A vertex without a gradient keeps its zero: `(0 - n 0) / len` is +0 as well.
            if g.iter().all(|&x| x == F::ZERO) {
                return;
            }
            let (nm, len, ok) = offset_normal(normals[v / m], d);
            if ok {
                let g = [g[0], g[1], g[2]];
                let proj = dot(nm, g);
                for c in 0..3 {
                    out[c] = (g[c] - nm[c] * proj) / len;
                }
            }
        });
    Ok(MaterialGrads { v_albedo_raw, v_roughness_raw, v_normal_offset })
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;

    #[test]
    fn init_values_and_ranges() {
        let mats = SvgMaterials::new(3, 4).unwrap();
        let normals = vec![Vec3::Z, Vec3::X, -Vec3::Y];
        let a = mats.activated(&normals).unwrap();
        assert!(a.albedo.iter().all(|&x| (x - 0.415).abs() < 1e-6));
        assert!(a.roughness.iter().all(|&x| (x - 0.54).abs() < 1e-6));
        assert_eq!(&a.normals[12..15], &[1.0, 0.0, 0.0]);
        assert!(SvgMaterials::new(3, 3).is_err());
        assert!(mats.activated(&normals[..2]).is_err());
        let mut mats = SvgMaterials::new(3, 2).unwrap();
        mats.roughness_raw = vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        mats.retain(&[true, false, true]).unwrap();
        assert_eq!(mats.roughness_raw, vec![0.0, 1.0, 4.0, 5.0]);
        assert_eq!(mats.albedo_raw.len(), 12);
    }

    #[test]
    fn backward_matches_finite_differences_f64() {
        let mut rng = Rng::new(4);
        for m in [1usize, 2, 4, 6] {
            let n = 3;
            let normals: Vec<Vec3> =
                (0..n).map(|_| Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize()).collect();
            let mut a: Vec<f64> = (0..n * m * 3).map(|_| 2.0 * rng.normal() as f64).collect();
            let mut r: Vec<f64> = (0..n * m).map(|_| 2.0 * rng.normal() as f64).collect();
            let mut d: Vec<f64> = (0..n * m * 3).map(|_| 0.4 * rng.normal() as f64).collect();
            let ga: Vec<f64> = (0..n * m * 3).map(|_| rng.normal() as f64).collect();
            let gr: Vec<f64> = (0..n * m).map(|_| rng.normal() as f64).collect();
            let gn: Vec<f64> = (0..n * m * 3).map(|_| rng.normal() as f64).collect();
            let loss = |a: &[f64], r: &[f64], d: &[f64]| {
                let act = activate(m, a, r, d, &normals).unwrap();
                let s = |x: &[f64], g: &[f64]| x.iter().zip(g).map(|(x, g)| x * g).sum::<f64>();
                s(&act.albedo, &ga) + s(&act.roughness, &gr) + s(&act.normals, &gn)
            };
            let g = activate_backward(m, &a, &r, &d, &normals, &ga, &gr, &gn).unwrap();
            let h = 1e-6;
            let close = |fd: f64, an: f64, what: &str| {
                assert!((fd - an).abs() < 1e-7 * (1.0 + fd.abs()), "M={m} {what}: fd {fd} vs {an}");
            };
            for i in 0..a.len() {
                let x = a[i];
                a[i] = x + h;
                let p = loss(&a, &r, &d);
                a[i] = x - h;
                let q = loss(&a, &r, &d);
                a[i] = x;
                close((p - q) / (2.0 * h), g.v_albedo_raw[i], "albedo");
            }
            for i in 0..r.len() {
                let x = r[i];
                r[i] = x + h;
                let p = loss(&a, &r, &d);
                r[i] = x - h;
                let q = loss(&a, &r, &d);
                r[i] = x;
                close((p - q) / (2.0 * h), g.v_roughness_raw[i], "roughness");
            }
            for i in 0..d.len() {
                let x = d[i];
                d[i] = x + h;
                let p = loss(&a, &r, &d);
                d[i] = x - h;
                let q = loss(&a, &r, &d);
                d[i] = x;
                close((p - q) / (2.0 * h), g.v_normal_offset[i], "offset");
            }
        }
    }

    /// Vertices without a gradient are passed by: their raw gradients are +0 (what the formulas
    /// give), and the other vertices' keep their bits.
    #[test]
    fn backward_passes_by_vertices_without_a_gradient() {
        let mut rng = Rng::new(5);
        let (n, m) = (40usize, 4usize);
        let normals: Vec<Vec3> =
            (0..n).map(|_| Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize()).collect();
        let mut draw = |len: usize, s: f32| (0..len).map(|_| s * rng.normal()).collect::<Vec<f32>>();
        let (a, r, d) = (draw(n * m * 3, 2.0), draw(n * m, 2.0), draw(n * m * 3, 0.4));
        let (ga, gr, gn) = (draw(n * m * 3, 1.0), draw(n * m, 1.0), draw(n * m * 3, 1.0));
        let full = activate_backward(m, &a, &r, &d, &normals, &ga, &gr, &gn).unwrap();
        // Every third vertex without a gradient.
        let quiet = |v: usize| v.is_multiple_of(3);
        let zeroed = |g: &[f32], w: usize| -> Vec<f32> {
            g.iter().enumerate().map(|(i, &x)| if quiet(i / w) { 0.0 } else { x }).collect()
        };
        let part =
            activate_backward(m, &a, &r, &d, &normals, &zeroed(&ga, 3), &zeroed(&gr, 1), &zeroed(&gn, 3)).unwrap();
        let check = |x: &[f32], y: &[f32], w: usize, what: &str| {
            for (i, (x, y)) in x.iter().zip(y).enumerate() {
                let want = if quiet(i / w) { 0.0f32 } else { *x };
                assert_eq!(y.to_bits(), want.to_bits(), "{what} {i}");
            }
        };
        check(&full.v_albedo_raw, &part.v_albedo_raw, 3, "albedo");
        check(&full.v_roughness_raw, &part.v_roughness_raw, 1, "roughness");
        check(&full.v_normal_offset, &part.v_normal_offset, 3, "offset");
    }

    #[test]
    fn raw_for_inverts_the_activations() {
        for &a in &[0.05f32, 0.3, 0.79] {
            assert!((albedo_of(albedo_raw_for(a) as f64) as f32 - a).abs() < 1e-5);
        }
        for &r in &[0.1f32, 0.5, 0.98] {
            assert!((roughness_of(roughness_raw_for(r) as f64) as f32 - r).abs() < 1e-5);
        }
        // Outside the activation's range: the nearest reachable value.
        assert!(albedo_of(albedo_raw_for(1.0) as f64) > 0.79);
    }
}
