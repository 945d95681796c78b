//! Vertex shading, the rendering equation of SPEC 4 for every Gaussian i and vertex m:
//!
//! `c_i^m = 1/K sum_k f(w_o, w_k; a_m, r_m, n_m) [V_i^k L_env(w_k) + L_ind_{i,k}] 2pi max(0, n_m.w_k)`
//!
//! with `w_o = normalize(cam - p_i)` (one view direction per Gaussian, SPEC 3), `w_k` the
//! micro-buffer's Fibonacci directions, V its visibility, `L_env` the bilinear lookup
//! (`EnvMap::taps`) clamped to [0, env_max] (SPEC 4: 64), and `L_ind = rho L_{i,k}` (training:
//! traced radiance, detached; SPEC 5) or a given N x K array with rho = 1 (relighting: the
//! one-bounce L1b of `svgir_trace::gather_all`, SPEC 7). Ablation switches: no visibility
//! (V = 1), no indirect (`Indirect::Off`). Gaussians with `visible[i] == false` output 0.
//!
//! The BRDF `f = t a/pi + S` (t = 1 in SPEC 4, `1 - E(n.v, r)` with `Diffuse::Layered`) has a grey specular S, so per vertex we accumulate the irradiance-like
//! sums `E_c = sum_k cos L_c` and `P_c = sum_k S cos L_c` and finish with `2pi/K (a_c/pi E_c + P_c)`;
//! the per-(i,k) work (direction, env taps, V, L) is done once and shared by the M vertices.
//! Direct (`V L_env`) and indirect parts are kept apart for the visualisation buffers.
//!
//! The GGX specular is split (`svgir_shading::split`): per vertex (alpha, k, g(n.v)) once per
//! Gaussian, per (i, k) the half vector and Fresnel, leaving two dots and a division per
//! (vertex, direction). Directions come from a per-call table of the K Fibonacci directions
//! rotated by each Gaussian's azimuth (equal to `MicroBuffer::direction` up to f32 rounding).
//!
//! The env taps depend only on the (frozen) directions and the map size, so stage 2 computes them
//! once in a [`crate::DirectionCache`] and passes it to [`shade_into_cached`] (bit-identical to
//! the uncached path, which looks them up per sample). Traced radiance is decoded from f16 with
//! a branch-light conversion (`half_to_f32`).
//!
//! Work split: rayon over Gaussians, each task owns its M x 3 outputs; no allocation per Gaussian.
//! Nothing is saved for backward: [`crate::shade_backward()`] recomputes the per-(i,k) samples,
//! which is cheaper than storing N x K x 3 lights.

use crate::{expect_len, PbrError};
use glam::Vec3;
use rayon::prelude::*;
use svgir_core::envmap::Taps;
use svgir_core::simd::Simd;
use svgir_core::EnvMap;
use svgir_shading::float::{dot, to_f};
pub(crate) use svgir_shading::hemisphere::{FibTable, HemiFrame as Frame};
use svgir_shading::split::{half, lobe, spec, Lobe};
use svgir_shading::{Diffuse, DiffuseWeight, Float, MAX_VERTICES};
use svgir_trace::DirectionCache;
use svgir_trace::{BrightLights, MicroBuffer, VertexMaterials};

/// Upper clamp of the environment radiance in the rendering equation (SPEC 4).
pub const ENV_MAX: f32 = 64.0;

/// Gaussians per rayon task (enough work to amortise the split, small enough to balance).
pub(crate) const MIN_TASK: usize = 64;

/// The indirect term `L_ind`.
#[derive(Clone, Copy, Debug)]
pub enum Indirect<'a, F> {
    /// No indirect light (ablation).
    Off,
    /// Training: `rho * L_{i,k}` with L the micro-buffer's traced radiance (SPEC 5).
    Traced {
        /// Scale applied to the traced radiance (learned in stage 2).
        rho: F,
    },
    /// Relighting: a given N x K array (`j * K + k`), e.g. one-bounce L1b; rho = 1.
    Given(&'a [[f32; 3]]),
}

/// Switches of the rendering equation (SPEC 4); the default is SPEC 4's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadeParams {
    /// Multiply the environment term by the micro-buffer visibility (off: V = 1, ablation).
    pub visibility: bool,
    /// Environment radiance clamp (SPEC 4: 64).
    pub env_max: f32,
    /// How the diffuse lobe combines with the specular one (SPEC 4: added).
    pub diffuse: Diffuse,
    /// Which f32 kernels run (`Simd::Auto`: the lane kernels of `shade_simd` on the widest of
    /// AVX-512F+VL and AVX2 the CPU has, unless `SVGIR_SIMD` says otherwise); f64 always runs
    /// the generic ones.
    pub simd: Simd,
}

impl Default for ShadeParams {
    fn default() -> Self {
        Self { visibility: true, env_max: ENV_MAX, diffuse: Diffuse::Added, simd: Simd::Auto }
    }
}

/// Everything the shading reads. `env_geom` supplies the map's size for the bilinear taps;
/// `env` the radiance texels (normally `&env_geom.data`; f64 copies in the tests).
#[derive(Clone, Copy, Debug)]
pub struct ShadeInputs<'a, F> {
    /// Frozen micro-buffers: directions, visibility, hits and traced radiance per Gaussian (SPEC 5).
    pub mb: &'a MicroBuffer,
    /// Gaussian centres, N.
    pub positions: &'a [Vec3],
    /// Camera centre in world space; view directions run from each Gaussian to it.
    pub camera_center: Vec3,
    /// Which Gaussians to shade (the rasteriser's visibility), N.
    pub visible: &'a [bool],
    /// Activated vertex materials (unit shading normals).
    pub mats: VertexMaterials<'a, F>,
    /// The environment map whose size the bilinear lookups use.
    pub env_geom: &'a EnvMap,
    /// Environment radiance per texel, row-major like `EnvMap::data`.
    pub env: &'a [[F; 3]],
    /// Which indirect term to add.
    pub indirect: Indirect<'a, F>,
    /// Switches of the rendering equation.
    pub params: ShadeParams,
    /// Texels of the map shaded as directional lights (see `svgir_trace::bright`); `None`: the
    /// K-sample estimate of SPEC 4 alone.
    pub lights: Option<&'a BrightLights>,
}

/// Per-vertex linear HDR colour and its direct / indirect parts, each `(i * M + m) * 3 + c`.
#[derive(Clone, Debug, PartialEq)]
pub struct ShadeOutput<F = f32> {
    /// Vertices per Gaussian.
    pub m: usize,
    /// Linear HDR colour per vertex: direct + indirect.
    pub color: Vec<F>,
    /// Environment (direct) part of the colour per vertex.
    pub direct: Vec<F>,
    /// Indirect part of the colour per vertex.
    pub indirect: Vec<F>,
    /// Whether [`shade_into`] fills `direct` and `indirect` (else they stay empty).
    pub split: bool,
}

impl<F> ShadeOutput<F> {
    /// Empty buffers, to be filled (and reused across iterations) by [`shade_into`].
    pub fn new() -> Self {
        Self { m: 0, color: Vec::new(), direct: Vec::new(), indirect: Vec::new(), split: true }
    }

    /// [`ShadeOutput::new`] for the colour alone (training reads nothing else): the lane
    /// kernel then sums each sample's direct and indirect light once instead of keeping two
    /// sums per channel, and the direct and indirect buffers are neither zeroed nor written.
    pub fn colour_only() -> Self {
        Self { split: false, ..Self::new() }
    }
}

impl<F> Default for ShadeOutput<F> {
    fn default() -> Self {
        Self::new()
    }
}

impl<F: Float> ShadeInputs<'_, F> {
    /// Check every array against the micro-buffer's N and K and the map's texel count.
    pub fn validate(&self) -> Result<(), PbrError> {
        let n = self.mb.len();
        self.mats.validate(n)?;
        if self.mb.k == 0 {
            return Err(PbrError::InvalidParameter("micro-buffer has K = 0".into()));
        }
        expect_len("positions", self.positions.len(), n)?;
        expect_len("visible", self.visible.len(), n)?;
        let g = self.env_geom;
        if g.width < 2 || g.height < 2 {
            return Err(PbrError::InvalidParameter(format!("environment {}x{}", g.width, g.height)));
        }
        expect_len("environment texels", self.env.len(), (g.width * g.height) as usize)?;
        if let Indirect::Given(l) = self.indirect {
            expect_len("indirect radiance", l.len(), n * self.mb.k)?;
        }
        if let Some(l) = self.lights {
            l.check(n, g.width, g.height)?;
        }
        if self.params.env_max.is_nan() || self.params.env_max < 0.0 {
            return Err(PbrError::InvalidParameter(format!("env_max = {}", self.params.env_max)));
        }
        Ok(())
    }
}

/// The light arriving at Gaussian i from direction k, shared by its M vertices.
pub(crate) struct Sample<F> {
    pub dir: [F; 3],
    /// Effective visibility (1 with the visibility switch off).
    pub vis: F,
    /// `V * clamp(L_env)`.
    pub direct: [F; 3],
    /// Channels whose env lookup is inside the clamp (gradient passes).
    pub live: [bool; 3],
    /// Bilinear taps; meaningful only when `vis > 0`.
    pub taps: Taps,
    /// Traced radiance L (Traced mode, else 0): `d L_ind / d rho`.
    pub traced: [F; 3],
    /// `L_ind`.
    pub ind: [F; 3],
}

/// The sample (i, k), or `None` when nothing can flow through it (V = 0 and no indirect light):
/// then it adds nothing to the colour and receives no gradient.
#[inline]
pub(crate) fn sample<F: Float>(
    inp: &ShadeInputs<F>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    frame: &Frame,
    i: usize,
    k: usize,
) -> Option<Sample<F>> {
    let mb = inp.mb;
    let zero = [F::ZERO; 3];
    let vis = if inp.params.visibility { F::from_f32(mb.visibility(i, k)) } else { F::ONE };
    let (traced, ind) = match inp.indirect {
        Indirect::Off => (zero, zero),
        Indirect::Traced { rho } => {
            let l: [F; 3] = to_f(mb.radiance[i * mb.k + k].map(half_to_f32));
            (l, l.map(|x| x * rho))
        }
        Indirect::Given(g) => (zero, to_f(g[i * mb.k + k])),
    };
    if vis <= F::ZERO && traced == zero && ind == zero {
        return None;
    }
    let d = frame.dir(table, k);
    let (direct, live, taps) = if vis > F::ZERO {
        let mut taps = match cache {
            Some(c) => c.taps(i * mb.k + k),
            None => inp.env_geom.taps(d),
        };
        if let Some(l) = inp.lights {
            l.mask_taps(&mut taps);
        }
        let mut raw = zero;
        for t in 0..4 {
            let w = F::from_f32(taps.weight[t]);
            let texel = inp.env[taps.index[t] as usize];
            for c in 0..3 {
                raw[c] += w * texel[c];
            }
        }
        let emax = F::from_f32(inp.params.env_max);
        (raw.map(|x| vis * x.clampf(F::ZERO, emax)), raw.map(|x| x >= F::ZERO && x <= emax), taps)
    } else {
        (zero, [false; 3], Taps { index: [0; 4], weight: [0.0; 4] })
    };
    Some(Sample { dir: to_f(d.to_array()), vis, direct, live, taps, traced, ind })
}

/// Directional light b seen from Gaussian i, as a sample of the same 2pi/K-weighted sum: its
/// one tap carries `Omega_b K / 2pi` times the texel (no clamp), V is the traced visibility (or
/// 1 above the geometric horizon with the visibility switch off). `None` when it is not seen.
#[inline]
pub(crate) fn light_sample<F: Float>(
    inp: &ShadeInputs<F>,
    lights: &BrightLights,
    i: usize,
    b: usize,
) -> Option<Sample<F>> {
    let dir = lights.dirs[b];
    let vis = if inp.params.visibility {
        lights.visibility(i, b)
    } else if inp.mb.normals[i].dot(dir) > 0.0 {
        1.0
    } else {
        0.0
    };
    if vis <= 0.0 {
        return None;
    }
    let t = lights.texels[b];
    let w = lights.sample_scale(b, inp.mb.k);
    let (vis, wf) = (F::from_f32(vis), F::from_f32(w));
    let texel = inp.env[t as usize];
    let zero = [F::ZERO; 3];
    Some(Sample {
        dir: to_f(dir.to_array()),
        vis,
        direct: texel.map(|x| vis * wf * x),
        live: [true; 3],
        taps: Taps { index: [t; 4], weight: [w, 0.0, 0.0, 0.0] },
        traced: zero,
        ind: zero,
    })
}

/// Every sample of Gaussian i that carries light: the K micro-buffer directions, then the
/// directional lights.
#[inline]
pub(crate) fn samples<'s, F: Float>(
    inp: &'s ShadeInputs<'s, F>,
    table: &'s FibTable,
    cache: Option<&'s DirectionCache>,
    frame: &'s Frame,
    i: usize,
) -> impl Iterator<Item = Sample<F>> + 's {
    (0..inp.mb.k).filter_map(move |k| sample(inp, table, cache, frame, i, k)).chain(light_samples(inp, i))
}

/// The directional-light samples of Gaussian i (the tail of [`samples`]).
#[inline]
pub(crate) fn light_samples<'s, F: Float>(
    inp: &'s ShadeInputs<'s, F>,
    i: usize,
) -> impl Iterator<Item = Sample<F>> + 's {
    let lights = inp.lights.filter(|l| !l.is_empty());
    lights.into_iter().flat_map(move |l| (0..l.len()).filter_map(move |b| light_sample(inp, l, i, b)))
}

/// Calls `f` with each directional-light sample of Gaussian i, in the order of
/// [`light_samples`], as a plain loop: behind the SIMD kernels' K directions the iterator's
/// chain was not inlined, and it took about 4% of a stage-2 iteration's samples in `perf`.
#[inline(always)]
pub(crate) fn for_light_samples<F: Float>(inp: &ShadeInputs<F>, i: usize, mut f: impl FnMut(Sample<F>)) {
    if let Some(l) = inp.lights.filter(|l| !l.is_empty()) {
        for b in 0..l.len() {
            if let Some(s) = light_sample(inp, l, i, b) {
                f(s);
            }
        }
    }
}

/// IEEE binary16 to f32, equal to `svgir_trace::pack::f16_to_f32` for every input (tested
/// exhaustively) but branch-light: shift the exponent and mantissa into place and rescale by
/// 2^112 (exact, also for subnormal halves); only Inf / NaN take the branch.
#[inline]
pub(crate) fn half_to_f32(h: u16) -> f32 {
    let sign = ((h & 0x8000) as u32) << 16;
    let mag = (h & 0x7fff) as u32;
    if mag >= 0x7c00 {
        return f32::from_bits(sign | 0x7f80_0000 | ((mag & 0x3ff) << 13));
    }
    let v = f32::from_bits(mag << 13) * f32::from_bits((127 + 112) << 23);
    f32::from_bits(sign | v.to_bits())
}

/// Gaussian i's per-vertex shading normals, albedos and roughnesses, copied to the stack.
pub(crate) struct Vertices<F> {
    pub n: [[F; 3]; MAX_VERTICES],
    pub a: [[F; 3]; MAX_VERTICES],
    pub r: [F; MAX_VERTICES],
}

#[inline]
pub(crate) fn vertices<F: Float>(mats: &VertexMaterials<F>, i: usize) -> Vertices<F> {
    let m = mats.m;
    let mut v =
        Vertices { n: [[F::ZERO; 3]; MAX_VERTICES], a: [[F::ZERO; 3]; MAX_VERTICES], r: [F::ZERO; MAX_VERTICES] };
    for mm in 0..m {
        let b = (i * m + mm) * 3;
        v.n[mm] = [mats.normals[b], mats.normals[b + 1], mats.normals[b + 2]];
        v.a[mm] = [mats.albedo[b], mats.albedo[b + 1], mats.albedo[b + 2]];
        v.r[mm] = mats.roughness[i * m + mm];
    }
    v
}

/// `w_o = normalize(cam - p_i)` (SPEC 3: per-Gaussian view direction).
#[inline]
pub(crate) fn view_dir<F: Float>(inp: &ShadeInputs<F>, i: usize) -> [F; 3] {
    to_f((inp.camera_center - inp.positions[i]).normalize_or(Vec3::Z).to_array())
}

/// The per-vertex specular lobes of Gaussian i (entries past M repeat the last vertex).
#[inline]
pub(crate) fn lobes<F: Float>(vx: &Vertices<F>, wo: [F; 3], m: usize) -> [Lobe<F>; MAX_VERTICES] {
    past_m_repeat_last(m, |mm| lobe(vx.n[mm], wo, vx.r[mm]))
}

/// `[f(0), .., f(m-1), f(m-1), ..]`, calling `f` only M times (the entries past M are copies,
/// where computing them again cost a third of the per-Gaussian set-up at M = 4).
#[inline]
fn past_m_repeat_last<T: Copy>(m: usize, mut f: impl FnMut(usize) -> T) -> [T; MAX_VERTICES] {
    let mut out = [f(0); MAX_VERTICES];
    for mm in 1..MAX_VERTICES {
        out[mm] = if mm < m { f(mm) } else { out[m - 1] };
    }
    out
}

/// The per-vertex diffuse weights of Gaussian i (`t = 1 - E(n.v, r)` when layered, else 1).
#[inline]
pub(crate) fn diffuse_weights<F: Float>(
    vx: &Vertices<F>,
    wo: [F; 3],
    m: usize,
    diffuse: Diffuse,
) -> [DiffuseWeight<F>; MAX_VERTICES] {
    past_m_repeat_last(m, |mm| diffuse.weight(dot(vx.n[mm], wo), vx.r[mm]))
}

/// Everything of Gaussian i that does not depend on the light direction: its vertices, the
/// view direction, the per-vertex specular lobes and diffuse weights.
pub(crate) struct Gaussian<F> {
    pub vx: Vertices<F>,
    pub wo: [F; 3],
    pub lb: [Lobe<F>; MAX_VERTICES],
    pub dw: [DiffuseWeight<F>; MAX_VERTICES],
}

#[inline]
pub(crate) fn gaussian<F: Float>(inp: &ShadeInputs<F>, i: usize) -> Gaussian<F> {
    let m = inp.mats.m;
    let vx = vertices(&inp.mats, i);
    let wo = view_dir(inp, i);
    let lb = lobes(&vx, wo, m);
    let dw = diffuse_weights(&vx, wo, m, inp.params.diffuse);
    Gaussian { vx, wo, lb, dw }
}

/// Shade Gaussian i into its M x 3 slices of colour / direct / indirect.
fn shade_gaussian<F: Float>(
    inp: &ShadeInputs<F>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    i: usize,
    color: &mut [F],
    direct: &mut [F],
    indirect: &mut [F],
) {
    let m = inp.mats.m;
    let Gaussian { vx, wo, lb, dw } = gaussian(inp, i);
    let frame = Frame::new(inp.mb.normals[i], inp.mb.xi[i]);
    let z = [[F::ZERO; 3]; MAX_VERTICES];
    // E: sum cos L; P: sum S cos L; split into direct (d) and indirect (i) light.
    let (mut e_d, mut e_i, mut p_d, mut p_i) = (z, z, z, z);
    for s in samples(inp, table, cache, &frame, i) {
        let hv = half(wo, s.dir);
        for mm in 0..m {
            let cos = dot(vx.n[mm], s.dir);
            if cos <= F::ZERO {
                continue;
            }
            let sc = spec(&lb[mm], &hv, cos) * cos;
            for c in 0..3 {
                e_d[mm][c] += cos * s.direct[c];
                e_i[mm][c] += cos * s.ind[c];
                p_d[mm][c] += sc * s.direct[c];
                p_i[mm][c] += sc * s.ind[c];
            }
        }
    }
    let scale = F::from_f64(std::f64::consts::TAU / inp.mb.k as f64);
    let inv_pi = F::from_f64(std::f64::consts::FRAC_1_PI);
    for mm in 0..m {
        for c in 0..3 {
            let kd = vx.a[mm][c] * inv_pi * dw[mm].value;
            let d = scale * (kd * e_d[mm][c] + p_d[mm][c]);
            let ind = scale * (kd * e_i[mm][c] + p_i[mm][c]);
            direct[mm * 3 + c] = d;
            indirect[mm * 3 + c] = ind;
            color[mm * 3 + c] = d + ind;
        }
    }
}

/// Shade every visible Gaussian's vertices into `out` (buffers resized and overwritten).
pub fn shade_into<F: Float>(inp: &ShadeInputs<F>, out: &mut ShadeOutput<F>) -> Result<(), PbrError> {
    shade_into_cached(inp, None, out)
}

/// [`shade_into`] with the env lookups taken from `cache` (built from `inp.mb` and a map of
/// `inp.env_geom`'s size, else an error); bit-identical to the uncached result.
pub fn shade_into_cached<F: Float>(
    inp: &ShadeInputs<F>,
    cache: Option<&DirectionCache>,
    out: &mut ShadeOutput<F>,
) -> Result<(), PbrError> {
    shade_sides_into_cached(&[(inp, cache)], out)
}

/// One side's inputs and direction cache, as the shading passes take them.
pub(crate) type SideRef<'a, F> = (&'a ShadeInputs<'a, F>, Option<&'a DirectionCache>);

/// Checks one side's inputs and cache, and that they match the first side's N, M and map (the
/// sides of [`shade_sides_into_cached`] and the backward's).
pub(crate) fn check_sides<F: Float>(sides: &[SideRef<F>]) -> Result<(), PbrError> {
    let first = sides.first().ok_or_else(|| PbrError::InvalidParameter("no side to shade".into()))?.0;
    for (inp, cache) in sides {
        inp.validate()?;
        if let Some(c) = cache {
            c.check(inp.mb, inp.env_geom)?;
        }
        expect_len("side's Gaussians", inp.mb.len(), first.mb.len())?;
        expect_len("side's vertices", inp.mats.m, first.mats.m)?;
        expect_len("side's environment texels", inp.env.len(), first.env.len())?;
    }
    Ok(())
}

/// The side that shades Gaussian i: the first whose `visible` holds it.
#[inline(always)]
pub(crate) fn side_of<'s, 'a, F>(sides: &'s [SideRef<'a, F>], i: usize) -> Option<(usize, &'s SideRef<'a, F>)> {
    sides.iter().enumerate().find(|(_, (inp, _))| inp.visible[i])
}

/// [`shade_into_cached`] over several sides in one pass: each Gaussian is shaded by the first
/// side whose `visible` holds it (the two-sided shading's sides hold disjoint sets, so this is
/// the sum of the sides' outputs without a second buffer or a pass to add them).
pub(crate) fn shade_sides_into_cached<F: Float>(
    sides: &[SideRef<F>],
    out: &mut ShadeOutput<F>,
) -> Result<(), PbrError> {
    check_sides(sides)?;
    let inp0 = sides[0].0;
    let m = inp0.mats.m;
    let len = inp0.mb.len() * m * 3;
    out.m = m;
    let split_len = if out.split { len } else { 0 };
    for (buf, len) in [(&mut out.color, len), (&mut out.direct, split_len), (&mut out.indirect, split_len)] {
        svgir_core::par::refill(buf, len, F::ZERO);
    }
    let tables: Vec<FibTable> = sides.iter().map(|(inp, _)| inp.mb.table()).collect();
    let lanes: Vec<Simd> = sides.iter().map(|(inp, _)| lane_kernels::<F>(inp.params.simd)).collect();
    // Without the split, the direct and indirect parts go to per-task scratch (scalar kernel)
    // or are not formed (lane kernel).
    if out.split {
        out.color
            .par_chunks_mut(m * 3)
            .zip(out.direct.par_chunks_mut(m * 3))
            .zip(out.indirect.par_chunks_mut(m * 3))
            .enumerate()
            .with_min_len(MIN_TASK)
            .for_each_init(LaneScratch::default, |rows, (i, ((c, d), ind))| {
                if let Some((s, &(inp, cache))) = side_of(sides, i) {
                    shade_one(inp, &tables[s], cache, rows, lanes[s], i, c, Some((d, ind)));
                }
            });
    } else {
        out.color.par_chunks_mut(m * 3).enumerate().with_min_len(MIN_TASK).for_each_init(
            || (LaneScratch::default(), vec![F::ZERO; 2 * m * 3]),
            |(rows, scratch), (i, c)| {
                if let Some((s, &(inp, cache))) = side_of(sides, i) {
                    let parts = (lanes[s] == Simd::Scalar).then(|| scratch.split_at_mut(m * 3));
                    shade_one(inp, &tables[s], cache, rows, lanes[s], i, c, parts);
                }
            },
        );
    }
    Ok(())
}

/// Gaussian i's vertex colours into `c`, with its direct and indirect parts into `parts` (the
/// lane kernel may go without them; the scalar one needs them).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn shade_one<F: Float>(
    inp: &ShadeInputs<F>,
    table: &FibTable,
    cache: Option<&DirectionCache>,
    rows: &mut LaneScratch,
    lane: Simd,
    i: usize,
    c: &mut [F],
    parts: Option<(&mut [F], &mut [F])>,
) {
    #[cfg(target_arch = "x86_64")]
    if lane != Simd::Scalar {
        // SAFETY: `lane_kernels` checked that `F` is `f32` and that the CPU has the path's
        // features.
        unsafe {
            let parts = parts.map(|(d, ind)| (as_f32_mut(d), as_f32_mut(ind)));
            let (inp, c) = (as_f32_inputs(inp), as_f32_mut(c));
            match lane {
                Simd::Avx512 => crate::shade_simd::shade_gaussian_avx512(inp, table, cache, rows, i, c, parts),
                _ => crate::shade_simd::shade_gaussian_avx2(inp, table, cache, rows, i, c, parts),
            }
        }
        return;
    }
    let _ = (&rows, lane);
    let (d, ind) = parts.expect("the scalar kernel writes the direct and indirect parts");
    shade_gaussian(inp, table, cache, i, c, d, ind);
}

/// Per-task scratch of the lane kernels (none where there are none).
#[cfg(target_arch = "x86_64")]
pub(crate) type LaneScratch = crate::shade_simd::SampleRows;
/// Per-task scratch of the lane kernels (none where there are none).
#[cfg(not(target_arch = "x86_64"))]
pub(crate) type LaneScratch = ();

/// `inp` as f32 inputs.
///
/// # Safety
/// `F` is `f32` (as [`lane_kernels`] checks).
#[cfg(target_arch = "x86_64")]
pub(crate) unsafe fn as_f32_inputs<'a, F>(inp: &'a ShadeInputs<'a, F>) -> &'a ShadeInputs<'a, f32> {
    // SAFETY: the caller's contract.
    unsafe { &*(inp as *const ShadeInputs<F> as *const ShadeInputs<f32>) }
}

/// `x` as a slice of `U`.
///
/// # Safety
/// `T` and `U` are the same type (`F` and `f32`, or `[F; 3]` and `[f32; 3]`, where `F` is
/// `f32` as [`lane_kernels`] checks).
#[cfg(target_arch = "x86_64")]
pub(crate) unsafe fn as_f32_mut<T, U>(x: &mut [T]) -> &mut [U] {
    // SAFETY: the caller's contract.
    unsafe { std::slice::from_raw_parts_mut(x.as_mut_ptr() as *mut U, x.len()) }
}

/// Which f32 lane kernels (`shade_simd`) run for scalar type `F` under `simd`: the AVX-512 or
/// AVX2 ones for f32 on an x86-64 CPU that has them, else `Simd::Scalar` (the generic kernels).
pub(crate) fn lane_kernels<F: 'static>(simd: Simd) -> Simd {
    if cfg!(target_arch = "x86_64") && svgir_core::simd::is_f32::<F>() {
        simd.resolve()
    } else {
        Simd::Scalar
    }
}

/// [`shade_into`] with fresh buffers.
pub fn shade<F: Float>(inp: &ShadeInputs<F>) -> Result<ShadeOutput<F>, PbrError> {
    let mut out = ShadeOutput::new();
    shade_into(inp, &mut out)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_trace::pack::f16_to_f32;

    #[test]
    fn half_decode_equals_the_reference_for_every_bit_pattern() {
        for h in 0..=u16::MAX {
            assert_eq!(half_to_f32(h).to_bits(), f16_to_f32(h).to_bits(), "{h:#06x}");
        }
    }
}
