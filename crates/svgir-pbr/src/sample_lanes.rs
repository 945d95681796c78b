//! The micro-buffer samples of one Gaussian ([`crate::shade::sample`] for k = 0..K), eight
//! directions at a time in AVX2 lanes, for the lane kernels of [`crate::shade_simd`] on the
//! stage-2 path (env taps from a [`DirectionCache`], traced or no indirect light).
//!
//! Per sample the scalar code rotates a Fibonacci direction into the Gaussian's frame, decodes
//! the visibility, turns the cached texel coordinates into four bilinear taps, masks the taps
//! that are directional lights, reads and clamps the environment, and decodes the traced
//! radiance: about 200 cycles of scalar work, done for the forward and again for the backward
//! (a fifth of a stage-2 iteration on the shipped scene, docs/performance.md). Here the
//! direction, the visibility, the taps, the env reads (gathers), the clamp and the f16 decode of
//! the traced radiance run over eight samples at once with the scalar operations in the scalar
//! order (no FMA), so every value is the scalar one bit for bit; the light mask and the skip of
//! samples that carry nothing stay scalar per lane, and the samples come out in the scalar
//! order. [`Samples8::write_rows`] hands them to the shading's rows, eight at a time when all
//! eight are samples.
//!
//! A tail of fewer than eight directions (the backward's four gradient directions) runs in the
//! same lanes on zero-padded copies of its inputs ([`samples_tail`]), its padded lanes yielding
//! nothing.
//!
//! Work split: one call per (Gaussian, 8 directions); nothing is allocated or saved.

// The kernel is an `unsafe fn` with one contract -- the CPU has AVX2 and the sample range lies
// inside the micro-buffer -- so the operations inside need no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]

#[cfg(test)]
use crate::shade::{half_to_f32, Sample};
use crate::shade::{FibTable, Frame, Indirect, ShadeInputs};
use crate::shade_backward::light_grads;
use core::arch::x86_64::*;
use svgir_core::envmap::Taps;
use svgir_trace::DirectionCache;

/// Directions per call.
pub(crate) const LANES: usize = 8;

/// Eight consecutive samples `(i, k0..k0 + 8)`, lane-major; `yields` has bit l set when lane l is
/// a sample ([`crate::shade::sample`] returns `Some`).
pub(crate) struct Samples8 {
    pub yields: u32,
    dir: [[f32; LANES]; 3],
    vis: [f32; LANES],
    direct: [[f32; LANES]; 3],
    live: [[f32; LANES]; 3],
    index: [[u32; LANES]; 4],
    weight: [[f32; LANES]; 4],
    /// Sample-major (lane l's three channels together): decoded in place, read per lane.
    traced: [[f32; 3]; LANES],
    ind: [[f32; 3]; LANES],
}

impl Samples8 {
    /// Appends the direction, direct and indirect light of the lanes that are samples, in lane
    /// order, to `dir`, `direct` and `ind`. All eight (the common case) go as whole rows.
    #[inline(always)]
    pub(crate) fn write_rows(&self, dir: &mut [Vec<f32>; 3], direct: &mut [Vec<f32>; 3], ind: &mut [Vec<f32>; 3]) {
        if self.yields == (1 << LANES) - 1 {
            for c in 0..3 {
                dir[c].extend_from_slice(&self.dir[c]);
                direct[c].extend_from_slice(&self.direct[c]);
                ind[c].extend(self.ind.iter().map(|l| l[c]));
            }
            return;
        }
        let mut y = self.yields;
        while y != 0 {
            let l = y.trailing_zeros() as usize;
            y &= y - 1;
            for c in 0..3 {
                dir[c].push(self.dir[c][l]);
                direct[c].push(self.direct[c][l]);
                ind[c].push(self.ind[l][c]);
            }
        }
    }

    /// The light gradients of the lanes that are samples, in lane order, with `dL/dLin` from
    /// rows `k..` of `v_lin` ([`light_grads`] per sample, as the scalar loop); returns the next
    /// row. Reads the lanes in place instead of building each lane's [`Sample`].
    #[inline(always)]
    pub(crate) fn light_grads(
        &self,
        v_lin: &[Vec<f32>; 3],
        k: usize,
        scale: f32,
        v_env: &mut [[f32; 3]],
        v_rho: &mut f32,
    ) -> usize {
        let mut k = k;
        let mut y = self.yields;
        while y != 0 {
            let l = y.trailing_zeros() as usize;
            y &= y - 1;
            // `each_ref`: indexing lane l of each row in place (`map` by value copied every
            // row to the stack first: a tenth of the shading backward on a Zen 3 VM).
            let taps =
                Taps { index: self.index.each_ref().map(|t| t[l]), weight: self.weight.each_ref().map(|t| t[l]) };
            let live = [0, 1, 2].map(|c| self.live[c][l] != 0.0);
            let g = [v_lin[0][k], v_lin[1][k], v_lin[2][k]];
            light_grads(self.vis[l], live, &taps, self.traced[l], g, scale, v_env, v_rho);
            k += 1;
        }
        k
    }

    /// Lane l as the scalar [`Sample`] (the tests compare it with the scalar kernel's).
    #[cfg(test)]
    #[inline(always)]
    pub(crate) fn sample(&self, l: usize) -> Sample<f32> {
        let g = |a: &[[f32; LANES]; 3]| [a[0][l], a[1][l], a[2][l]];
        let (dir, direct, ind) = (g(&self.dir), g(&self.direct), self.ind[l]);
        Sample {
            dir,
            vis: self.vis[l],
            direct,
            live: [0, 1, 2].map(|c| self.live[c][l] != 0.0),
            taps: Taps { index: self.index.map(|t| t[l]), weight: self.weight.map(|t| t[l]) },
            traced: self.traced[l],
            ind,
        }
    }
}

/// Whether [`samples8`] serves these inputs (given cached taps): traced or no indirect light.
pub(crate) fn serves(inp: &ShadeInputs<f32>) -> bool {
    matches!(inp.indirect, Indirect::Off | Indirect::Traced { .. })
}

/// Lights compared with the taps in lanes in [`samples8`]; beyond this, the mask lookup.
const MAX_COMPARED_LIGHTS: usize = 16;

/// Where the eight lanes' inputs are read: the table rows of the directions, the visibility,
/// the cached texel coordinates and the traced radiance, eight consecutive entries each.
struct Lanes8 {
    table: [*const f32; 4],
    vis: *const u16,
    coords: *const [f32; 2],
    radiance: *const [u16; 3],
}

/// A tail's inputs copied into zero-padded rows of eight.
struct Padded {
    table: [[f32; LANES]; 4],
    vis: [u16; LANES],
    coords: [[f32; 2]; LANES],
    radiance: [[u16; 3]; LANES],
}

/// Samples `(i, k0..k0 + 8)` of Gaussian i with frame `frame`.
///
/// # Safety
/// The CPU has AVX2, `k0 + 8 <= K`, `cache` is the micro-buffer's, and [`serves`] holds.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn samples8(
    inp: &ShadeInputs<f32>,
    table: &FibTable,
    cache: &DirectionCache,
    frame: &Frame,
    i: usize,
    k0: usize,
) -> Samples8 {
    let mb = inp.mb;
    let s0 = i * mb.k + k0;
    let (coords, width, height) = cache.coords(s0, LANES);
    let src = Lanes8 {
        table: table.rows().map(|r| r[k0..k0 + LANES].as_ptr()),
        vis: mb.vis[s0..s0 + LANES].as_ptr(),
        coords: coords.as_ptr(),
        radiance: mb.radiance[s0..s0 + LANES].as_ptr(),
    };
    samples_from(inp, frame, &src, width, height, LANES)
}

/// Samples `(i, k0..k0 + lanes)` for a tail of `1 <= lanes < 8` directions (the backward's four
/// gradient directions): [`samples8`] on zero-padded copies, whose lanes past `lanes` yield
/// nothing.
///
/// # Safety
/// The CPU has AVX2, `1 <= lanes < 8`, `k0 + lanes <= K`, `cache` is the micro-buffer's, and
/// [`serves`] holds.
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn samples_tail(
    inp: &ShadeInputs<f32>,
    table: &FibTable,
    cache: &DirectionCache,
    frame: &Frame,
    i: usize,
    k0: usize,
    lanes: usize,
) -> Samples8 {
    let mb = inp.mb;
    let s0 = i * mb.k + k0;
    debug_assert!((1..LANES).contains(&lanes) && k0 + lanes <= mb.k);
    let (coords, width, height) = cache.coords(s0, lanes);
    let mut pad =
        Padded { table: [[0.0; LANES]; 4], vis: [0; LANES], coords: [[0.0; 2]; LANES], radiance: [[0; 3]; LANES] };
    for (dst, row) in pad.table.iter_mut().zip(table.rows()) {
        dst[..lanes].copy_from_slice(&row[k0..k0 + lanes]);
    }
    pad.vis[..lanes].copy_from_slice(&mb.vis[s0..s0 + lanes]);
    pad.coords[..lanes].copy_from_slice(coords);
    pad.radiance[..lanes].copy_from_slice(&mb.radiance[s0..s0 + lanes]);
    let src = Lanes8 {
        table: pad.table.each_ref().map(|r| r.as_ptr()),
        vis: pad.vis.as_ptr(),
        coords: pad.coords.as_ptr(),
        radiance: pad.radiance.as_ptr(),
    };
    samples_from(inp, frame, &src, width, height, lanes)
}

/// The body of [`samples8`] and [`samples_tail`]: lanes `0..lanes` of `src` are samples, on a
/// `width x height` map.
#[inline(always)]
unsafe fn samples_from(
    inp: &ShadeInputs<f32>,
    frame: &Frame,
    src: &Lanes8,
    width: u32,
    height: u32,
    lanes: usize,
) -> Samples8 {
    let zero = _mm256_setzero_ps();
    let mut out = Samples8 {
        yields: 0,
        dir: [[0.0; LANES]; 3],
        vis: [0.0; LANES],
        direct: [[0.0; LANES]; 3],
        live: [[0.0; LANES]; 3],
        index: [[0; LANES]; 4],
        weight: [[0.0; LANES]; 4],
        traced: [[0.0; 3]; LANES],
        ind: [[0.0; 3]; LANES],
    };

    // The direction (`HemiFrame::dir`): c = c_k cx - s_k sx, s = s_k cx + c_k sx,
    // d = (b1 (r c) + b2 (r s)) + n z.
    let (b1, b2, n, cx, sx) = frame.parts();
    let [ck, sk, rk, zk] = src.table.map(|r| _mm256_loadu_ps(r));
    let (cxv, sxv) = (_mm256_set1_ps(cx), _mm256_set1_ps(sx));
    let c = _mm256_sub_ps(_mm256_mul_ps(ck, cxv), _mm256_mul_ps(sk, sxv));
    let s = _mm256_add_ps(_mm256_mul_ps(sk, cxv), _mm256_mul_ps(ck, sxv));
    let (rc, rs) = (_mm256_mul_ps(rk, c), _mm256_mul_ps(rk, s));
    for a in 0..3 {
        let d = _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(b1[a]), rc), _mm256_mul_ps(_mm256_set1_ps(b2[a]), rs)),
            _mm256_mul_ps(_mm256_set1_ps(n[a]), zk),
        );
        _mm256_storeu_ps(out.dir[a].as_mut_ptr(), d);
    }

    // The visibility: u16 unorm as `q as f32 * (1 / 65535)`, or 1 with the switch off.
    let vis = if inp.params.visibility {
        let q = _mm_loadu_si128(src.vis as *const __m128i);
        const INV: f32 = 1.0 / 65535.0;
        _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(q)), _mm256_set1_ps(INV))
    } else {
        _mm256_set1_ps(1.0)
    };
    _mm256_storeu_ps(out.vis.as_mut_ptr(), vis);

    // The taps (`Taps::at` of the cached coordinates): truncation is floor for fx, fy >= 0.
    // The eight (fx, fy) pairs as two rows: two loads of four pairs, then shuffles (moves only).
    let xy = src.coords as *const f32;
    let (lo, hi) = (_mm256_loadu_ps(xy), _mm256_loadu_ps(xy.add(LANES)));
    // Per 128-bit half: x0 x1 x4 x5 | x2 x3 x6 x7 (and y), then the 64-bit pairs reordered.
    let unpair = |v: __m256| _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)));
    let fx = unpair(_mm256_shuffle_ps::<0b10_00_10_00>(lo, hi));
    let fy = unpair(_mm256_shuffle_ps::<0b11_01_11_01>(lo, hi));
    let (x0, y0) = (_mm256_cvttps_epi32(fx), _mm256_cvttps_epi32(fy));
    let one_i = _mm256_set1_epi32(1);
    let x1 = _mm256_min_epi32(_mm256_add_epi32(x0, one_i), _mm256_set1_epi32(width as i32 - 1));
    let y1 = _mm256_min_epi32(_mm256_add_epi32(y0, one_i), _mm256_set1_epi32(height as i32 - 1));
    let tx = _mm256_sub_ps(fx, _mm256_cvtepi32_ps(x0));
    let ty = _mm256_sub_ps(fy, _mm256_cvtepi32_ps(y0));
    let one = _mm256_set1_ps(1.0);
    let (ux, uy) = (_mm256_sub_ps(one, tx), _mm256_sub_ps(one, ty));
    let wv = _mm256_set1_epi32(width as i32);
    let (r0, r1) = (_mm256_mullo_epi32(y0, wv), _mm256_mullo_epi32(y1, wv));
    let index =
        [_mm256_add_epi32(r0, x0), _mm256_add_epi32(r0, x1), _mm256_add_epi32(r1, x0), _mm256_add_epi32(r1, x1)];
    let mut weight = [_mm256_mul_ps(ux, uy), _mm256_mul_ps(tx, uy), _mm256_mul_ps(ux, ty), _mm256_mul_ps(tx, ty)];
    for t in 0..4 {
        _mm256_storeu_si256(out.index[t].as_mut_ptr() as *mut __m256i, index[t]);
    }
    // Taps on directional lights carry nothing (`BrightLights::mask_taps`): a few lights are
    // compared with the taps' indices in lanes, more looked up in the mask lane by lane.
    if let Some(lights) = inp.lights.filter(|l| !l.is_empty()) {
        if lights.texels.len() <= MAX_COMPARED_LIGHTS {
            for t in 0..4 {
                let mut hit = _mm256_setzero_si256();
                for &texel in &lights.texels {
                    hit = _mm256_or_si256(hit, _mm256_cmpeq_epi32(index[t], _mm256_set1_epi32(texel as i32)));
                }
                weight[t] = _mm256_andnot_ps(_mm256_castsi256_ps(hit), weight[t]);
            }
        } else {
            for t in 0..4 {
                let mut w = [0f32; LANES];
                _mm256_storeu_ps(w.as_mut_ptr(), weight[t]);
                for l in 0..LANES {
                    if lights.is_light(out.index[t][l]) {
                        w[l] = 0.0;
                    }
                }
                weight[t] = _mm256_loadu_ps(w.as_ptr());
            }
        }
    }

    // The environment: raw_c = sum_t w_t L[idx_t]_c from 0, clamped to [0, env_max] as
    // `maxf` then `minf`, times V; live where the clamp is inactive. Lanes with V <= 0 get no
    // light, no live channel and empty taps, as the scalar branch.
    let env = inp.env.as_ptr() as *const f32;
    let three = _mm256_set1_epi32(3);
    let base = index.map(|ix| _mm256_mullo_epi32(ix, three));
    let emax = _mm256_set1_ps(inp.params.env_max);
    let seen = _mm256_cmp_ps::<_CMP_GT_OQ>(vis, zero);
    for ch in 0..3 {
        let chv = _mm256_set1_epi32(ch as i32);
        let mut raw = zero;
        for t in 0..4 {
            let texel = _mm256_i32gather_ps::<4>(env, _mm256_add_epi32(base[t], chv));
            raw = _mm256_add_ps(raw, _mm256_mul_ps(weight[t], texel));
        }
        let lo = _mm256_blendv_ps(zero, raw, _mm256_cmp_ps::<_CMP_GT_OQ>(raw, zero));
        let cl = _mm256_blendv_ps(emax, lo, _mm256_cmp_ps::<_CMP_LT_OQ>(lo, emax));
        let direct = _mm256_and_ps(_mm256_mul_ps(vis, cl), seen);
        let live = _mm256_and_ps(
            _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(raw, zero), _mm256_cmp_ps::<_CMP_LE_OQ>(raw, emax)),
            seen,
        );
        _mm256_storeu_ps(out.direct[ch].as_mut_ptr(), direct);
        _mm256_storeu_ps(out.live[ch].as_mut_ptr(), _mm256_and_ps(live, one));
    }
    for t in 0..4 {
        _mm256_storeu_ps(out.weight[t].as_mut_ptr(), _mm256_and_ps(weight[t], seen));
        let ix = _mm256_and_si256(index[t], _mm256_castps_si256(seen));
        _mm256_storeu_si256(out.index[t].as_mut_ptr() as *mut __m256i, ix);
    }

    // Traced radiance: the eight samples' 24 halves decoded in place (the decode and the
    // product with rho are per element, so the interleaved order needs no shuffle).
    if let Indirect::Traced { rho } = inp.indirect {
        let rad = src.radiance as *const __m128i;
        let traced = out.traced.as_mut_ptr() as *mut f32;
        let ind = out.ind.as_mut_ptr() as *mut f32;
        for q in 0..3 {
            let x = half_lanes(_mm256_cvtepu16_epi32(_mm_loadu_si128(rad.add(q))));
            _mm256_storeu_ps(traced.add(8 * q), x);
            _mm256_storeu_ps(ind.add(8 * q), _mm256_mul_ps(x, _mm256_set1_ps(rho)));
        }
    }
    // Which lanes carry anything (the scalar `sample`'s test, `!(V <= 0 && traced == 0 && ind
    // == 0)`): bit 3l + c of `nonzero` says that channel c of lane l's traced or indirect
    // radiance is not 0 (NaN included, as `==` reads it).
    let dark = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(vis, zero)) as u32;
    let mut nonzero = 0u32;
    for rows in [out.traced.as_ptr() as *const f32, out.ind.as_ptr() as *const f32] {
        for part in 0..3 {
            let x = _mm256_loadu_ps(rows.add(8 * part));
            nonzero |= (_mm256_movemask_ps(_mm256_cmp_ps::<_CMP_NEQ_UQ>(x, zero)) as u32) << (8 * part);
        }
    }
    for l in 0..lanes {
        if dark >> l & 1 == 0 || nonzero >> (3 * l) & 7 != 0 {
            out.yields |= 1 << l;
        }
    }
    out
}

/// [`crate::shade::half_to_f32`] of eight halves held as u32 lanes, the same operations: exponent and
/// mantissa shifted into place and rescaled by 2^112, Inf / NaN selected.
#[inline(always)]
unsafe fn half_lanes(h: __m256i) -> __m256 {
    let sign = _mm256_slli_epi32::<16>(_mm256_and_si256(h, _mm256_set1_epi32(0x8000)));
    let mag = _mm256_and_si256(h, _mm256_set1_epi32(0x7fff));
    let scaled = _mm256_mul_ps(
        _mm256_castsi256_ps(_mm256_slli_epi32::<13>(mag)),
        _mm256_castsi256_ps(_mm256_set1_epi32((127 + 112) << 23)),
    );
    let special = _mm256_or_si256(
        _mm256_set1_epi32(0x7f80_0000),
        _mm256_slli_epi32::<13>(_mm256_and_si256(mag, _mm256_set1_epi32(0x3ff))),
    );
    let is_special = _mm256_cmpgt_epi32(mag, _mm256_set1_epi32(0x7bff));
    let body = _mm256_blendv_epi8(_mm256_castps_si256(scaled), special, is_special);
    _mm256_castsi256_ps(_mm256_or_si256(sign, body))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::{synthetic_materials, synthetic_microbuffer, synthetic_positions};
    use crate::shade::{sample, ShadeParams};
    use crate::EnvLight;
    use glam::Vec3;
    use svgir_core::Rng;
    use svgir_trace::{brightest_texels, BrightLights, VertexMaterials};

    fn same(a: &Sample<f32>, b: &Sample<f32>) -> bool {
        let bits = |s: &Sample<f32>| {
            let mut v: Vec<u32> =
                s.dir.iter().chain(&s.direct).chain(&s.traced).chain(&s.ind).map(|x| x.to_bits()).collect();
            v.push(s.vis.to_bits());
            v.extend(s.taps.weight.map(f32::to_bits));
            v.extend(s.taps.index);
            v.extend(s.live.map(u32::from));
            v
        };
        bits(a) == bits(b)
    }

    /// The lane decode is `half_to_f32` for every bit pattern, Inf and NaN included.
    #[test]
    fn lane_half_decode_is_the_scalar_one_for_every_bit_pattern() {
        if !std::is_x86_feature_detected!("avx2") {
            eprintln!("SKIPPED: this CPU has no AVX2, so the sample lanes cannot run here");
            return;
        }
        #[target_feature(enable = "avx2")]
        unsafe fn decode(h: &[u16; LANES]) -> [f32; LANES] {
            let mut out = [0f32; LANES];
            let x = half_lanes(_mm256_cvtepu16_epi32(_mm_loadu_si128(h.as_ptr() as *const __m128i)));
            _mm256_storeu_ps(out.as_mut_ptr(), x);
            out
        }
        for base in (0..=u16::MAX as u32).step_by(LANES) {
            let h: [u16; LANES] = std::array::from_fn(|l| (base + l as u32) as u16);
            // SAFETY: AVX2 checked above.
            let got = unsafe { decode(&h) };
            for l in 0..LANES {
                assert_eq!(got[l].to_bits(), half_to_f32(h[l]).to_bits(), "{:#06x}", h[l]);
            }
        }
    }

    /// Every lane is `shade::sample` bit for bit (or both say "no sample"), with and without
    /// visibility, lights, traced or no indirect light, and env values past the clamp.
    #[test]
    fn lane_samples_are_the_scalar_ones() {
        if !std::is_x86_feature_detected!("avx2") {
            eprintln!("SKIPPED: this CPU has no AVX2, so the sample lanes cannot run here");
            return;
        }
        // K = 68: eight blocks of eight and a tail of four (padded lanes).
        let (n, k) = (60, 68);
        let mb = synthetic_microbuffer(n, k, 3);
        let positions = synthetic_positions(&mb, 3);
        let mut env = EnvLight::new(8, 3).unwrap().radiance();
        // Some texels beyond the clamp and some negative, so that `live` varies.
        let mut rng = Rng::new(9);
        for t in env.data.iter_mut() {
            if rng.uniform() < 0.2 {
                *t = t.map(|x| x * 80.0);
            } else if rng.uniform() < 0.1 {
                t[1] = -0.5;
            }
        }
        let act = synthetic_materials(n, 2, 3).activated(&mb.normals).unwrap();
        let cache = DirectionCache::new(&mb, &env).unwrap();
        // A few lights (compared in lanes) and more than MAX_COMPARED_LIGHTS (looked up).
        let mut lights_of = |count| {
            let texels = brightest_texels(&env, count);
            let cols: Vec<Vec<f32>> = texels.iter().map(|_| (0..n).map(|_| rng.uniform()).collect()).collect();
            BrightLights::from_visibility(&env, &texels, &cols).unwrap()
        };
        let (few, many) = (lights_of(3), lights_of(MAX_COMPARED_LIGHTS + 4));
        assert_eq!(many.len(), MAX_COMPARED_LIGHTS + 4);
        let visible = vec![true; n];
        let table = FibTable::new(k);
        let (mut yielded, mut skipped) = (0, 0);
        for (visibility, indirect, lights) in [
            (true, Indirect::Traced { rho: 0.7 }, Some(&few)),
            (true, Indirect::Off, None),
            (false, Indirect::Traced { rho: 1.3 }, None),
            (true, Indirect::Traced { rho: 0.0 }, Some(&few)),
            (true, Indirect::Traced { rho: 0.4 }, Some(&many)),
        ] {
            let inp = ShadeInputs {
                mb: &mb,
                positions: &positions,
                camera_center: Vec3::new(0.3, -2.5, 1.2),
                visible: &visible,
                mats: VertexMaterials { m: 2, albedo: &act.albedo, roughness: &act.roughness, normals: &act.normals },
                env_geom: &env,
                env: &env.data,
                indirect,
                params: ShadeParams { visibility, ..ShadeParams::default() },
                lights,
            };
            assert!(serves(&inp));
            for i in 0..n {
                let frame = Frame::new(mb.normals[i], mb.xi[i]);
                for k0 in (0..k).step_by(LANES) {
                    let lanes = LANES.min(k - k0);
                    // SAFETY: AVX2 checked above; k0 + lanes <= K.
                    let got = unsafe {
                        if lanes == LANES {
                            samples8(&inp, &table, &cache, &frame, i, k0)
                        } else {
                            samples_tail(&inp, &table, &cache, &frame, i, k0, lanes)
                        }
                    };
                    assert_eq!(got.yields >> lanes, 0, "padded lanes yield nothing");
                    for l in 0..lanes {
                        let want = sample(&inp, &table, Some(&cache), &frame, i, k0 + l);
                        match want {
                            Some(w) => {
                                assert!(got.yields >> l & 1 == 1, "sample ({i}, {}) missing", k0 + l);
                                assert!(same(&got.sample(l), &w), "sample ({i}, {}) differs", k0 + l);
                                yielded += 1;
                            }
                            None => {
                                assert!(got.yields >> l & 1 == 0, "sample ({i}, {}) should be skipped", k0 + l);
                                skipped += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(yielded > 1000 && skipped > 100, "{yielded} samples, {skipped} skipped: too few of one kind");
    }
}
