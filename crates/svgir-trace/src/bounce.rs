//! Further bounces of indirect light for relighting, from the micro-buffers (our addition to
//! SPEC 7; see docs/method.md).
//!
//! Eqn 13's one-bounce term L1b lights j by what its hit Gaussian h reflects of the environment
//! h sees *unoccluded*; the light h receives from its own occluded directions is dropped. In a
//! concave object (a cup's inside, a bowl) that second bounce is a visible part of the image,
//! and stage 2 trained the materials with the traced radiance, which holds every bounce of the
//! training light. So relighting with L1b alone is darker there than the materials were fitted
//! for. One more bounce:
//!
//! `L_{b+1}(j,k) = L1b(j,k) + [h != -1] sum_m w_m(U_j^k) a_h^m / pi * E_h^m[L_b]`,
//! `E_h^m[L] = 2pi/K sum_{s: I_h^s != -1} max(1e-6, n_h^m . w_{h,s}) L(h,s)`,
//!
//! the irradiance h's vertex m receives from the surfaces it sees, reflected diffusely (the
//! specular lobe of a secondary bounce is dropped: it is a small part of an already small
//! term, and keeping the GGX lobe would cost K times more per pair). Iterating from L_1 = L1b is
//! a Jacobi iteration of the rendering equation restricted to the micro-buffers.
//!
//! Work split: rayon over Gaussians, twice per bounce: first the per-vertex irradiance E (each
//! task reads its own K samples), then the per-(j, k) update (each task owns its K outputs).
//! Relighting only: nothing is differentiated.

use crate::gather::VertexMaterials;
use crate::microbuffer::MicroBuffer;
use crate::TraceError;
use rayon::prelude::*;
use svgir_shading::{vertex_weights, DOT_EPS};

/// `bounces` further diffuse bounces on top of `one_bounce` (Eqn 13's L1b, `j * K + k`), in
/// place. `bounces = 0` leaves it unchanged.
pub fn add_bounces(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    one_bounce: &mut [[f32; 3]],
    bounces: usize,
) -> Result<(), TraceError> {
    mats.validate(mb.len())?;
    let (n, k, m) = (mb.len(), mb.k, mats.m);
    if one_bounce.len() != n * k {
        return Err(TraceError::SizeMismatch { what: "one-bounce light", got: one_bounce.len(), want: n * k });
    }
    if bounces == 0 || k == 0 {
        return Ok(());
    }
    let first = one_bounce.to_vec();
    let mut irradiance = vec![[0.0f32; 3]; n * m];
    for _ in 0..bounces {
        vertex_irradiance(mb, mats, one_bounce, &mut irradiance);
        one_bounce.par_chunks_mut(k).zip(first.par_chunks(k)).enumerate().for_each(|(j, (row, l1b))| {
            for kk in 0..k {
                row[kk] = l1b[kk];
                let Some(h) = mb.hit(j, kk) else { continue };
                let h = h as usize;
                let uv = mb.uv(j, kk);
                let w = vertex_weights(m, uv[0], uv[1]);
                for mm in 0..m {
                    let e = irradiance[h * m + mm];
                    for c in 0..3 {
                        row[kk][c] += w[mm] * mats.albedo[(h * m + mm) * 3 + c] * std::f32::consts::FRAC_1_PI * e[c];
                    }
                }
            }
        });
    }
    Ok(())
}

/// `E_h^m[L]` for every Gaussian h and vertex m (`h * M + m`).
fn vertex_irradiance(mb: &MicroBuffer, mats: &VertexMaterials<f32>, light: &[[f32; 3]], out: &mut [[f32; 3]]) {
    let (k, m) = (mb.k, mats.m);
    let scale = std::f32::consts::TAU / k as f32;
    out.par_chunks_mut(m).enumerate().for_each(|(h, e)| {
        e.fill([0.0; 3]);
        for s in 0..k {
            if mb.hit(h, s).is_none() {
                continue;
            }
            let l = light[h * k + s];
            let d = mb.direction(h, s);
            for (mm, em) in e.iter_mut().enumerate() {
                let b = (h * m + mm) * 3;
                let cos =
                    (mats.normals[b] * d.x + mats.normals[b + 1] * d.y + mats.normals[b + 2] * d.z).max(DOT_EPS as f32);
                for c in 0..3 {
                    em[c] += scale * cos * l[c];
                }
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::object_scene;
    use crate::{Bvh, TraceParams};
    use svgir_core::Rng;

    /// Micro-buffers of a small object with random materials and a random one-bounce light.
    struct Case {
        mb: MicroBuffer,
        albedo: Vec<f32>,
        rough: Vec<f32>,
        normals: Vec<f32>,
        l1b: Vec<[f32; 3]>,
    }

    impl Case {
        fn mats(&self, m: usize) -> VertexMaterials<'_, f32> {
            VertexMaterials { m, albedo: &self.albedo, roughness: &self.rough, normals: &self.normals }
        }
    }

    fn case(m: usize, seed: u64) -> Case {
        let surfels = object_scene(300, seed);
        let bvh = Bvh::build(&surfels);
        let mb = MicroBuffer::trace(&bvh, &surfels, 16, seed, &TraceParams::default()).unwrap();
        let mut rng = Rng::new(seed);
        let n = surfels.len();
        let albedo: Vec<f32> = (0..n * m * 3).map(|_| rng.range(0.03, 0.8)).collect();
        let rough: Vec<f32> = (0..n * m).map(|_| rng.range(0.09, 0.99)).collect();
        let mut normals = Vec::with_capacity(n * m * 3);
        for i in 0..n {
            for _ in 0..m {
                normals.extend(surfels.normal(i).to_array());
            }
        }
        let l1b: Vec<[f32; 3]> =
            (0..n * 16).map(|_| [rng.range(0.0, 2.0), rng.range(0.0, 2.0), rng.range(0.0, 2.0)]).collect();
        Case { mb, albedo, rough, normals, l1b }
    }

    /// The definition, one (j, k) at a time, in f64, with no shared irradiance.
    fn reference(mb: &MicroBuffer, mats: &VertexMaterials<f32>, l1b: &[[f32; 3]], bounces: usize) -> Vec<[f64; 3]> {
        let (n, k, m) = (mb.len(), mb.k, mats.m);
        let first: Vec<[f64; 3]> = l1b.iter().map(|x| x.map(f64::from)).collect();
        let mut cur = first.clone();
        for _ in 0..bounces {
            let mut next = first.clone();
            for j in 0..n {
                for kk in 0..k {
                    let Some(h) = mb.hit(j, kk) else { continue };
                    let h = h as usize;
                    let uv = mb.uv(j, kk);
                    let w = vertex_weights(m, uv[0] as f64, uv[1] as f64);
                    for s in 0..k {
                        if mb.hit(h, s).is_none() {
                            continue;
                        }
                        let d = mb.direction(h, s);
                        for mm in 0..m {
                            let b = (h * m + mm) * 3;
                            let nrm = [mats.normals[b], mats.normals[b + 1], mats.normals[b + 2]];
                            let cos = (nrm[0] * d.x + nrm[1] * d.y + nrm[2] * d.z).max(DOT_EPS as f32) as f64;
                            for c in 0..3 {
                                next[j * k + kk][c] += w[mm] * mats.albedo[b + c] as f64 / std::f64::consts::PI
                                    * std::f64::consts::TAU
                                    / k as f64
                                    * cos
                                    * cur[h * k + s][c];
                            }
                        }
                    }
                }
            }
            cur = next;
        }
        cur
    }

    #[test]
    fn bounces_match_the_definition() {
        for (m, seed, bounces) in [(4usize, 1u64, 1usize), (1, 2, 2), (6, 3, 3)] {
            let c = case(m, seed);
            let (mb, mats, l1b) = (&c.mb, c.mats(m), &c.l1b);
            let mut got = l1b.clone();
            add_bounces(mb, &mats, &mut got, bounces).unwrap();
            let want = reference(mb, &mats, l1b, bounces);
            let mut added = 0.0;
            for (g, w) in got.iter().zip(&want) {
                for c in 0..3 {
                    assert!((g[c] as f64 - w[c]).abs() <= 1e-4 * (1.0 + w[c].abs()), "{g:?} vs {w:?}");
                }
                added += w[0];
            }
            let base: f64 = l1b.iter().map(|x| x[0] as f64).sum();
            assert!(added > base * 1.001, "the bounces add light: {added} vs {base}");
        }
    }

    #[test]
    fn zero_bounces_or_black_albedo_change_nothing_and_bad_sizes_fail() {
        let m = 4;
        let c = case(m, 7);
        let (mb, mats, l1b) = (&c.mb, c.mats(m), &c.l1b);
        let mut same = l1b.clone();
        add_bounces(mb, &mats, &mut same, 0).unwrap();
        assert_eq!(&same, l1b);
        let black = vec![0.0; c.albedo.len()];
        let dark = VertexMaterials { albedo: &black, ..mats };
        add_bounces(mb, &dark, &mut same, 3).unwrap();
        assert_eq!(&same, l1b);
        let mut short = l1b[1..].to_vec();
        assert!(add_bounces(mb, &mats, &mut short, 1).is_err());
    }

    #[test]
    fn more_bounces_converge_for_albedo_below_one() {
        let m = 4;
        let c = case(m, 9);
        let mats = c.mats(m);
        let total = |b: usize| {
            let mut l = c.l1b.clone();
            add_bounces(&c.mb, &mats, &mut l, b).unwrap();
            l.iter().map(|x| x[1] as f64).sum::<f64>()
        };
        let (t1, t2, t8, t9) = (total(1), total(2), total(8), total(9));
        assert!(t1 < t2 && t8 <= t9 * (1.0 + 1e-6));
        assert!(t9 - t8 < 0.5 * (t2 - t1), "increments shrink: {} vs {}", t9 - t8, t2 - t1);
    }
}
