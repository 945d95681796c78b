//! A per-sample cache of the environment lookups of the micro-buffer directions.
//!
//! In stage 2 the micro-buffer (its normals, azimuth offsets and hence the K directions of every
//! Gaussian) is frozen (SPEC 5), and so is the environment map's size; only its texels are
//! learned. The bilinear taps of `EnvMap::taps` (a normalisation, an `acos` and an `atan2` per
//! (Gaussian, direction), a third of the shading time) therefore never change, and this cache
//! computes them once. It stores the clamped continuous texel coordinates `(fx, fy)` per sample
//! (**8 bytes per sample**, e.g. 51 MB for 100k Gaussians x K = 64), from which the four indices
//! and weights follow with a floor and a few products, the same f32 operations as
//! `EnvMap::taps`, so cached and uncached shading are bit-identical (tested). The directions
//! themselves are not stored: rotating the Fibonacci table per Gaussian costs a dozen flops.
//!
//! The cache records N, K, the map size and a fingerprint of the micro-buffer's normals and
//! azimuths; the shading entry points reject a cache built for other inputs (a stale cache would
//! silently shade with the wrong light). Work split: rayon over Gaussians.

use crate::{MicroBuffer, TraceError};
use rayon::prelude::*;
use svgir_shading::hemisphere::HemiFrame;

/// Gaussians per rayon task.
const MIN_TASK: usize = 64;
use svgir_core::envmap::{grid_coords, Taps};
use svgir_core::EnvMap;

/// Precomputed env-map coordinates of every (Gaussian, direction) of one micro-buffer.
#[derive(Clone, Debug, PartialEq)]
pub struct DirectionCache {
    n: usize,
    k: usize,
    width: u32,
    height: u32,
    fingerprint: u64,
    /// `(fx, fy)` per sample `i * K + k`, already clamped to the map.
    coords: Vec<[f32; 2]>,
}

/// FNV-style hash of the bits that fix the directions (normals, azimuths, K, interleave).
///
/// Checked at every shading and gather call (several per stage-2 iteration), so it is cheap:
/// FNV-1a over fixed chunks of Gaussians in parallel, four independent streams per chunk (one
/// per field, so the multiplies overlap), the chunk hashes combined in order. The value depends
/// on the inputs only, not on the thread count.
fn fingerprint(mb: &MicroBuffer) -> u64 {
    use rayon::prelude::*;
    const CHUNK: usize = 4096;
    const BASIS: u64 = 0xcbf2_9ce4_8422_2325;
    let mix = |h: u64, x: u32| (h ^ x as u64).wrapping_mul(0x0000_0100_0000_01b3);
    let chunks: Vec<u64> = mb
        .normals
        .par_chunks(CHUNK)
        .zip(mb.xi.par_chunks(CHUNK))
        .map(|(ns, xs)| {
            let mut h = [BASIS; 4];
            for (n, xi) in ns.iter().zip(xs) {
                h = [
                    mix(h[0], n.x.to_bits()),
                    mix(h[1], n.y.to_bits()),
                    mix(h[2], n.z.to_bits()),
                    mix(h[3], xi.to_bits()),
                ];
            }
            h.iter().fold(BASIS, |a, &b| mix(mix(a, b as u32), (b >> 32) as u32))
        })
        .collect();
    let h = (BASIS ^ mb.k as u64) ^ ((mb.normals.len() as u64) << 20);
    let h = mix(mix(h, mb.interleave.stride as u32), mb.interleave.phase as u32);
    chunks.iter().fold(h, |a, &b| mix(mix(a, b as u32), (b >> 32) as u32))
}

impl DirectionCache {
    /// Bytes stored per (Gaussian, direction) sample.
    pub const BYTES_PER_SAMPLE: usize = 8;

    /// The cache of `mb`'s directions looked up in maps of `env`'s size.
    pub fn new(mb: &MicroBuffer, env: &EnvMap) -> Result<Self, TraceError> {
        let (n, k) = (mb.len(), mb.k);
        if k == 0 {
            return Err(TraceError::InvalidParameter("micro-buffer has K = 0".into()));
        }
        if env.width < 2 || env.height < 2 {
            return Err(TraceError::InvalidParameter(format!("environment {}x{}", env.width, env.height)));
        }
        if mb.xi.len() != n {
            return Err(TraceError::SizeMismatch { what: "micro-buffer azimuths", got: mb.xi.len(), want: n });
        }
        let (width, height) = (env.width, env.height);
        let table = mb.table();
        let mut coords = vec![[0.0f32; 2]; n * k];
        coords.par_chunks_mut(k).enumerate().with_min_len(MIN_TASK).for_each(|(i, row)| {
            let frame = HemiFrame::new(mb.normals[i], mb.xi[i]);
            for (kk, c) in row.iter_mut().enumerate() {
                *c = grid_coords(width, height, frame.dir(&table, kk));
            }
        });
        Ok(Self { n, k, width, height, fingerprint: fingerprint(mb), coords })
    }

    /// The cache of `sub`, an interleaved subset of the micro-buffer this cache was built for
    /// (`MicroBuffer::interleaved`): its samples' coordinates copied, the bits of
    /// [`DirectionCache::new`] on `sub`.
    pub fn interleaved(&self, sub: &MicroBuffer) -> Result<Self, TraceError> {
        let stride = sub.interleave.stride;
        if sub.len() != self.n || sub.k * stride != self.k {
            return Err(TraceError::InvalidParameter(format!(
                "an interleaved subset of N = {}, K = {} / {stride} cannot come from a cache of N = {}, K = {}",
                sub.len(),
                sub.k * stride,
                self.n,
                self.k
            )));
        }
        let coords = sub.interleave.whole_indices(self.n, sub.k).map(|s| self.coords[s]).collect();
        Ok(Self { n: self.n, k: sub.k, width: self.width, height: self.height, fingerprint: fingerprint(sub), coords })
    }

    /// Heap bytes held.
    pub fn memory_bytes(&self) -> usize {
        self.coords.len() * Self::BYTES_PER_SAMPLE
    }

    /// `Ok` iff the cache was built from this micro-buffer (same N, K, normals and azimuths) and
    /// a map of this size. O(N).
    pub fn check(&self, mb: &MicroBuffer, env: &EnvMap) -> Result<(), TraceError> {
        if self.n != mb.len()
            || self.k != mb.k
            || (self.width, self.height) != (env.width, env.height)
            || self.fingerprint != fingerprint(mb)
        {
            return Err(TraceError::InvalidParameter(format!(
                "direction cache built for N = {}, K = {}, env {}x{} does not match these inputs \
                 (N = {}, K = {}, env {}x{}, or other directions)",
                self.n,
                self.k,
                self.width,
                self.height,
                mb.len(),
                mb.k,
                env.width,
                env.height
            )));
        }
        Ok(())
    }

    /// The clamped `(fx, fy)` of samples `s..s + len` and the map size `(width, height)` they
    /// index ([`DirectionCache::taps`] is `Taps::at` of one of them).
    #[inline]
    pub fn coords(&self, s: usize, len: usize) -> (&[[f32; 2]], u32, u32) {
        (&self.coords[s..s + len], self.width, self.height)
    }

    /// The bilinear taps of sample `s = i * K + k`, equal to `EnvMap::taps` of its direction.
    #[inline]
    pub fn taps(&self, s: usize) -> Taps {
        let [fx, fy] = self.coords[s];
        Taps::at(fx, fy, self.width, self.height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::object_scene;
    use crate::{Bvh, TraceParams};
    use glam::Vec3;
    use svgir_core::Rng;
    use svgir_shading::hemisphere::FibTable;

    /// A traced micro-buffer of a small random object.
    fn synthetic_microbuffer(n: usize, k: usize, seed: u64) -> MicroBuffer {
        let surfels = object_scene(n, seed);
        MicroBuffer::trace(&Bvh::build(&surfels), &surfels, k, seed, &TraceParams::default()).unwrap()
    }

    fn same(a: &Taps, b: &Taps) -> bool {
        a.index == b.index && a.weight.map(f32::to_bits) == b.weight.map(f32::to_bits)
    }

    #[test]
    fn an_interleaved_subset_caches_its_own_directions() {
        let env = EnvMap::constant(64, 32, [1.0; 3]);
        let mb = synthetic_microbuffer(40, 24, 5);
        let full = DirectionCache::new(&mb, &env).unwrap();
        for phase in 0..3 {
            let sub = mb.interleaved(3, phase).unwrap();
            let cache = full.interleaved(&sub).unwrap();
            assert_eq!(cache, DirectionCache::new(&sub, &env).unwrap(), "phase {phase}");
            cache.check(&sub, &env).unwrap();
            assert!(cache.check(&mb.interleaved(3, (phase + 1) % 3).unwrap(), &env).is_err(), "another phase");
            assert!(full.check(&sub, &env).is_err());
            for i in [0, 17, 39] {
                for s in 0..sub.k {
                    assert_eq!(sub.direction(i, s), mb.direction(i, phase + 3 * s));
                    assert_eq!(sub.visibility(i, s), mb.visibility(i, phase + 3 * s));
                    assert_eq!(sub.radiance(i, s), mb.radiance(i, phase + 3 * s));
                    assert_eq!(sub.hit(i, s), mb.hit(i, phase + 3 * s));
                    assert_eq!(sub.uv(i, s), mb.uv(i, phase + 3 * s));
                }
            }
        }
        assert!(mb.interleaved(5, 0).is_err(), "5 does not divide 24");
        assert!(mb.interleaved(3, 3).is_err());
        assert!(mb.interleaved(3, 0).unwrap().interleaved(2, 0).is_err());
    }

    #[test]
    fn taps_are_bit_identical_to_the_env_map() {
        let env = EnvMap::constant(64, 32, [1.0; 3]);
        let mb = synthetic_microbuffer(50, 37, 3);
        let cache = DirectionCache::new(&mb, &env).unwrap();
        assert_eq!(cache.memory_bytes(), mb.len() * 37 * 8);
        let table = FibTable::new(mb.k);
        for i in 0..mb.len() {
            let frame = HemiFrame::new(mb.normals[i], mb.xi[i]);
            for k in 0..mb.k {
                let d = frame.dir(&table, k);
                assert!(same(&cache.taps(i * mb.k + k), &env.taps(d)), "sample ({i}, {k}) d = {d}");
            }
        }
        // Poles, the seam (atan2 = +-pi), unnormalised and degenerate directions.
        let mut rng = Rng::new(4);
        let mut dirs = vec![Vec3::Z, -Vec3::Z, -Vec3::X, Vec3::new(-1.0, -0.0, 0.0), Vec3::ZERO, 7.0 * Vec3::Y];
        dirs.extend((0..2000).map(|_| Vec3::new(rng.normal(), rng.normal(), rng.normal())));
        for env in [env, EnvMap::constant(6, 3, [1.0; 3])] {
            let one = DirectionCache {
                n: 1,
                k: dirs.len(),
                width: env.width,
                height: env.height,
                fingerprint: 0,
                coords: dirs.iter().map(|&d| grid_coords(env.width, env.height, d)).collect(),
            };
            for (s, &d) in dirs.iter().enumerate() {
                assert!(same(&one.taps(s), &env.taps(d)), "d = {d}");
            }
        }
    }

    #[test]
    fn rejects_other_inputs() {
        let env = EnvMap::constant(8, 4, [1.0; 3]);
        let mb = synthetic_microbuffer(20, 8, 1);
        let cache = DirectionCache::new(&mb, &env).unwrap();
        assert!(cache.check(&mb, &env).is_ok());
        assert!(cache.check(&mb, &EnvMap::constant(16, 8, [1.0; 3])).is_err());
        assert!(cache.check(&synthetic_microbuffer(20, 8, 2), &env).is_err());
        assert!(cache.check(&synthetic_microbuffer(21, 8, 1), &env).is_err());
        let mut moved = mb.clone();
        moved.xi[3] += 0.1;
        assert!(cache.check(&moved, &env).is_err());
        assert!(DirectionCache::new(&mb, &EnvMap::constant(1, 1, [1.0; 3])).is_err());
    }

    /// The one-bounce gather and its backward give the same bits with the cache as without, and
    /// refuse a cache built for another micro-buffer.
    #[test]
    fn cached_gather_is_bit_identical_and_checked() {
        use crate::{gather_pairs, gather_pairs_backward, GatherParams, VertexMaterials};
        let (n, m, k) = (200, 4, 16);
        let mb = synthetic_microbuffer(n, k, 5);
        let mut rng = Rng::new(6);
        let mut env = EnvMap::constant(16, 8, [0.0; 3]);
        for t in env.data.iter_mut() {
            *t = [rng.range(0.1, 3.0), rng.range(0.1, 3.0), rng.range(0.1, 3.0)];
        }
        let albedo: Vec<f32> = (0..mb.len() * m * 3).map(|_| rng.range(0.05, 0.9)).collect();
        let roughness: Vec<f32> = (0..mb.len() * m).map(|_| rng.range(0.1, 0.9)).collect();
        let normals: Vec<f32> =
            mb.normals.iter().flat_map(|a| std::iter::repeat_n(a.to_array(), m)).flatten().collect();
        let mats = VertexMaterials { m, albedo: &albedo, roughness: &roughness, normals: &normals };
        let pairs: Vec<(u32, u32)> = (0..mb.len() as u32)
            .flat_map(|j| (0..k as u32).map(move |s| (j, s)))
            .filter(|&(j, s)| mb.hit(j as usize, s as usize).is_some())
            .collect();
        assert!(pairs.len() > 50, "too few hits: {}", pairs.len());
        let cache = DirectionCache::new(&mb, &env).unwrap();
        let plain = GatherParams::default();
        let cached = GatherParams { cache: Some(&cache), ..plain };
        let a = gather_pairs(&mb, &mats, &env, &plain, &pairs).unwrap();
        let b = gather_pairs(&mb, &mats, &env, &cached, &pairs).unwrap();
        assert_eq!(a, b);
        assert!(a.iter().any(|x| x[0] > 0.0));
        let v: Vec<[f32; 3]> = (0..pairs.len()).map(|_| [rng.normal(), rng.normal(), rng.normal()]).collect();
        let ga = gather_pairs_backward(&mb, &mats, &env, &plain, &pairs, &v).unwrap();
        let gb = gather_pairs_backward(&mb, &mats, &env, &cached, &pairs, &v).unwrap();
        assert_eq!(ga, gb);
        let other = DirectionCache::new(&synthetic_microbuffer(n, k, 7), &env).unwrap();
        assert!(gather_pairs(&mb, &mats, &env, &GatherParams { cache: Some(&other), ..plain }, &pairs).is_err());
    }
}
