//! One-bounce indirect light from the micro-buffers (SPEC 5, Eqn 13, with 9.2 and 9.3).
//!
//! For Gaussian j, direction k and first hit h = I_j^k:
//! `L1b = [h != -1] 2pi/K sum_s [I_h^s == -1] (sum_m w_m(U_j^k) f(-w_k, w_{h,s}; a_h^m, r_h^m, n_h^m)
//!        max(1e-6, n_h^m . w_{h,s})) L_env(w_{h,s})`,
//! i.e. the hit surfel, interpolated at the hit's own (u~, v~) (SPEC 9.2), reflects the
//! environment it sees unoccluded in its own micro-buffer towards j; no re-tracing. `L_env` is the
//! bilinear lookup (`EnvMap::taps`) clamped to [0, env_max] (SPEC 4: 64). With
//! `GatherParams::lights` the escape list also holds h's directional lights ([`BrightLights`]),
//! weighted by solid angle and traced visibility, and the K samples see those texels as black.
//!
//! Work split: [`gather_all`] / [`gather_from`] sort the rays by their hit Gaussian h and run
//! rayon over h: each task builds h's escape list (directions and env radiance of its unoccluded
//! samples) once and shades every ray that hit h (building it per ray cost as much as the
//! shading). [`gather_pairs`] runs over its pairs, reusing the escape list while consecutive
//! pairs hit the same h.
//! Nothing is saved for backward: [`crate::gather_backward`] recomputes the (cheap) escape lists.
//! All maths is generic over `Float` so the tests check the gradients in f64.

use crate::bright::BrightLights;
use crate::direction_cache::DirectionCache;
use crate::gather_lanes::{lane_kernels, EscapeRows};
use crate::microbuffer::{Interleave, MicroBuffer, NO_HIT, SURROUNDINGS_HIT};
use crate::TraceError;
use rayon::prelude::*;
use svgir_core::envmap::Taps;
use svgir_core::simd::Simd;
use svgir_core::EnvMap;
use svgir_shading::float::{dot, to_f};
use svgir_shading::hemisphere::{FibTable, HemiFrame};
use svgir_shading::split::{half, lobe, spec, Lobe};
use svgir_shading::{vertex_weights, Diffuse, DiffuseWeight, Float, DOT_EPS, MAX_VERTICES};

/// Per-vertex materials of all Gaussians, structure of arrays: `albedo[(i*M + m)*3 + c]`,
/// `roughness[i*M + m]`, `normals[(i*M + m)*3 + c]` (unit shading normals, already activated).
#[derive(Clone, Copy, Debug)]
pub struct VertexMaterials<'a, F> {
    /// Vertices per Gaussian: 1, 2, 4 or 6.
    pub m: usize,
    /// Linear albedo, N x M x 3.
    pub albedo: &'a [F],
    /// Roughness, N x M.
    pub roughness: &'a [F],
    /// Unit shading normals, N x M x 3.
    pub normals: &'a [F],
}

impl<F> VertexMaterials<'_, F> {
    /// Check M and that every array holds N Gaussians' worth of values.
    pub fn validate(&self, n: usize) -> Result<(), TraceError> {
        if ![1, 2, 4, 6].contains(&self.m) {
            return Err(TraceError::InvalidParameter(format!("M = {} (must be 1, 2, 4 or 6)", self.m)));
        }
        let m = self.m;
        for (what, got, want) in [
            ("albedo", self.albedo.len(), n * m * 3),
            ("roughness", self.roughness.len(), n * m),
            ("normals", self.normals.len(), n * m * 3),
        ] {
            if got != want {
                return Err(TraceError::SizeMismatch { what, got, want });
            }
        }
        Ok(())
    }
}

/// Settings of the one-bounce gather (Eqn 13) shared by the consistency loss and relighting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GatherParams<'a> {
    /// Upper clamp of the environment radiance inside the rendering equation (SPEC 4).
    pub env_max: f32,
    /// Texels of the map that act as directional lights ([`BrightLights`]): the hit Gaussian
    /// also reflects each of them, weighted by its solid angle and its traced visibility.
    pub lights: Option<&'a BrightLights>,
    /// How the hit Gaussian's diffuse lobe combines with its specular one.
    pub diffuse: Diffuse,
    /// The env-map lookups of the micro-buffer's directions, computed once ([`DirectionCache`]):
    /// the same taps without an `acos` and `atan2` per escaping direction. Must be built from
    /// the gathered micro-buffer and a map of this size (checked); ignored by the two-sided
    /// gathers, whose sides have micro-buffers of their own.
    pub cache: Option<&'a DirectionCache>,
    /// Which f32 kernels shade the rays (`Simd::Auto`: the lane kernels of `gather_lanes` where
    /// the CPU has AVX2; `Simd::Scalar`: the scalar oracle).
    pub simd: Simd,
}

impl Default for GatherParams<'_> {
    fn default() -> Self {
        Self { env_max: 64.0, lights: None, diffuse: Diffuse::Added, cache: None, simd: Simd::Auto }
    }
}

/// The light the gather reads: map geometry, radiance texels (f64 in the tests), clamp, lights.
#[derive(Clone, Copy)]
pub(crate) struct LightIn<'a, F> {
    pub geom: &'a EnvMap,
    pub env: &'a [[F; 3]],
    pub env_max: F,
    pub lights: Option<&'a BrightLights>,
    pub diffuse: Diffuse,
    pub cache: Option<&'a DirectionCache>,
}

impl<'a> LightIn<'a, f32> {
    pub fn new(env: &'a EnvMap, p: &GatherParams<'a>) -> Self {
        Self { geom: env, env: &env.data, env_max: p.env_max, lights: p.lights, diffuse: p.diffuse, cache: p.cache }
    }
}

/// The unoccluded samples of one hit Gaussian h: direction, clamped env radiance, which channels
/// are inside the clamp (gradient passes), and the bilinear taps.
pub(crate) struct Escapes<F> {
    pub h: u32,
    pub dirs: Vec<[F; 3]>,
    pub light: Vec<[F; 3]>,
    pub live: Vec<[bool; 3]>,
    pub taps: Vec<Taps>,
    /// The directions and light again as padded lane rows, for [`crate::gather_lanes`].
    pub rows: EscapeRows,
    /// The micro-buffer's Fibonacci table (built on the first fill) and what it was built for.
    table: FibTable,
    table_of: Option<(usize, Interleave)>,
}

impl<F: Float> Escapes<F> {
    pub fn new() -> Self {
        Self {
            h: NO_HIT,
            dirs: Vec::new(),
            light: Vec::new(),
            live: Vec::new(),
            taps: Vec::new(),
            rows: EscapeRows::default(),
            table: FibTable::new(0),
            table_of: None,
        }
    }

    pub fn fill(&mut self, mb: &MicroBuffer, light: &LightIn<F>, h: u32) {
        if self.h == h {
            return;
        }
        self.h = h;
        self.dirs.clear();
        self.light.clear();
        self.live.clear();
        self.taps.clear();
        self.rows.clear();
        let hu = h as usize;
        if self.table_of != Some((mb.k, mb.interleave)) {
            self.table = mb.table();
            self.table_of = Some((mb.k, mb.interleave));
        }
        // The directions by rotating the Fibonacci table (`MicroBuffer::direction` up to f32
        // rounding, without a sine, cosine and remainder each), as the vertex shading does.
        let frame = HemiFrame::new(mb.normals[hu], mb.xi[hu]);
        for s in 0..mb.k {
            if mb.first_hit[hu * mb.k + s] != NO_HIT {
                continue;
            }
            let d = frame.dir(&self.table, s);
            let mut taps = match light.cache {
                Some(c) => c.taps(hu * mb.k + s),
                None => light.geom.taps(d),
            };
            if let Some(b) = light.lights {
                b.mask_taps(&mut taps);
            }
            let mut raw = [F::ZERO; 3];
            for t in 0..4 {
                let texel = light.env[taps.index[t] as usize];
                let w = F::from_f32(taps.weight[t]);
                for c in 0..3 {
                    raw[c] += w * texel[c];
                }
            }
            self.push(d.to_array(), raw.map(|x| x.clampf(F::ZERO, light.env_max)), taps);
            self.live.push(raw.map(|x| x >= F::ZERO && x <= light.env_max));
        }
        // Directional lights: the sample weight is 2pi/K, so each carries `V Omega K / 2pi`
        // times its texel as a one-tap lookup (unclamped; the backward routes through the tap).
        if let Some(l) = light.lights {
            self.push_lights(mb, light, l, hu);
        }
        self.rows.pad();
    }

    /// One escape, in both layouts (`live` is the caller's).
    fn push(&mut self, d: [f32; 3], light: [F; 3], taps: Taps) {
        self.dirs.push(to_f(d));
        self.light.push(light);
        self.rows.push(d, light.map(F::to_f32));
        self.taps.push(taps);
    }

    /// h's directional lights as escapes.
    fn push_lights(&mut self, mb: &MicroBuffer, light: &LightIn<F>, l: &BrightLights, hu: usize) {
        for (b, &t) in l.texels.iter().enumerate() {
            let v = l.visibility(hu, b);
            if v <= 0.0 {
                continue;
            }
            let w = v * l.sample_scale(b, mb.k);
            let texel = light.env[t as usize];
            self.push(
                l.dirs[b].to_array(),
                texel.map(|x| F::from_f32(w) * x),
                Taps { index: [t; 4], weight: [w, 0.0, 0.0, 0.0] },
            );
            self.live.push([true; 3]);
        }
    }
}

/// The per-ray set-up of the gather's kernels (forward and backward, scalar and lanes): the view
/// direction towards j, the vertex weights at the hit's (u~, v~), and per vertex of h its
/// normal, albedo, diffuse weight `t(n.v, r)` (1 for SPEC 4's added lobes) and specular lobe
/// split per vertex and per direction (`svgir_shading::split`). Only h's M vertices are built;
/// vertex 0 fills the unused slots.
#[derive(Clone, Copy)]
pub(crate) struct RaySetup<F> {
    pub v: [F; 3],
    pub w: [F; MAX_VERTICES],
    pub n: [[F; 3]; MAX_VERTICES],
    pub a: [[F; 3]; MAX_VERTICES],
    pub dw: [DiffuseWeight<F>; MAX_VERTICES],
    pub lobes: [Lobe<F>; MAX_VERTICES],
}

impl<F: Float> RaySetup<F> {
    /// Ray (j, k) of `mb` hitting Gaussian h.
    pub fn new(mb: &MicroBuffer, mats: &VertexMaterials<F>, diffuse: Diffuse, h: usize, j: usize, k: usize) -> Self {
        let m = mats.m;
        let v: [F; 3] = to_f((-mb.direction(j, k)).to_array());
        let uv = mb.uv(j, k);
        let w = vertex_weights(m, F::from_f32(uv[0]), F::from_f32(uv[1]));
        let vertex = |mm: usize| {
            let b = (h * m + mm) * 3;
            let n = [mats.normals[b], mats.normals[b + 1], mats.normals[b + 2]];
            let a = [mats.albedo[b], mats.albedo[b + 1], mats.albedo[b + 2]];
            (n, a, mats.roughness[h * m + mm])
        };
        let (n0, a0, r0) = vertex(0);
        let mut ray = Self {
            v,
            w,
            n: [n0; MAX_VERTICES],
            a: [a0; MAX_VERTICES],
            dw: [diffuse.weight(dot(n0, v), r0); MAX_VERTICES],
            lobes: [lobe(n0, v, r0); MAX_VERTICES],
        };
        for mm in 1..m {
            let (n, a, r) = vertex(mm);
            ray.n[mm] = n;
            ray.a[mm] = a;
            ray.dw[mm] = diffuse.weight(dot(n, v), r);
            ray.lobes[mm] = lobe(n, v, r);
        }
        ray
    }
}

/// Eqn 13 for one (j, k) given the escape list of its hit Gaussian.
pub(crate) fn shade_pair<F: Float>(
    mb: &MicroBuffer,
    mats: &VertexMaterials<F>,
    esc: &Escapes<F>,
    diffuse: Diffuse,
    j: usize,
    k: usize,
) -> [F; 3] {
    let m = mats.m;
    let ray = RaySetup::new(mb, mats, diffuse, esc.h as usize, j, k);
    let v = ray.v;
    let mut acc = [F::ZERO; 3];
    let eps = F::from_f64(DOT_EPS);
    // The diffuse term `t a/pi` per vertex (`t` depends on the view, not on the escape
    // direction), so the loop below evaluates only the specular lobe.
    let inv_pi = F::from_f64(std::f64::consts::FRAC_1_PI);
    let mut diffuse_part = [[F::ZERO; 3]; MAX_VERTICES];
    for mm in 0..m {
        let kd = inv_pi * ray.dw[mm].value;
        diffuse_part[mm] = ray.a[mm].map(|x| x * kd);
    }
    for (l, light) in esc.dirs.iter().zip(&esc.light) {
        let mut f_cos = [F::ZERO; 3];
        let hv = half(v, *l);
        for mm in 0..m {
            let nl = dot(ray.n[mm], *l);
            let s = spec(&ray.lobes[mm], &hv, nl);
            let f = diffuse_part[mm].map(|d| d + s);
            let cw = nl.maxf(eps) * ray.w[mm];
            for c in 0..3 {
                f_cos[c] += f[c] * cw;
            }
        }
        for c in 0..3 {
            acc[c] += f_cos[c] * light[c];
        }
    }
    let scale = F::from_f64(std::f64::consts::TAU / mb.k as f64);
    acc.map(|x| x * scale)
}

/// `Err` unless every (j, k) names a sample of `mb`.
pub(crate) fn check_pairs(mb: &MicroBuffer, pairs: impl IntoIterator<Item = (usize, usize)>) -> Result<(), TraceError> {
    match pairs.into_iter().find(|&(j, k)| j >= mb.len() || k >= mb.k) {
        Some((j, k)) => Err(TraceError::InvalidParameter(format!("(j, k) = ({j}, {k}) out of range"))),
        None => Ok(()),
    }
}

pub(crate) fn check(mb: &MicroBuffer, mats: &VertexMaterials<impl Sized>, env: &EnvMap) -> Result<(), TraceError> {
    mats.validate(mb.len())?;
    let want = (env.width * env.height) as usize;
    if env.data.len() != want || env.width < 2 || env.height < 2 {
        return Err(TraceError::SizeMismatch { what: "environment map", got: env.data.len(), want });
    }
    Ok(())
}

/// The checks of a call on the (j, k) pairs `pairs`: the buffers, every pair in range, the
/// lights.
pub fn check_pair_call(
    mb: &MicroBuffer,
    mats: &VertexMaterials<impl Sized>,
    env: &EnvMap,
    p: &GatherParams,
    pairs: &[(u32, u32)],
) -> Result<(), TraceError> {
    check(mb, mats, env)?;
    check_pairs(mb, pairs.iter().map(|&(j, k)| (j as usize, k as usize)))?;
    check_lights(mb, env, p)
}

/// `Err` unless `p.lights` (if any) index `env`'s grid and cover every Gaussian of `mb`, and
/// `p.cache` (if any) was built from `mb` and a map of `env`'s size.
pub(crate) fn check_lights(mb: &MicroBuffer, env: &EnvMap, p: &GatherParams) -> Result<(), TraceError> {
    if let Some(c) = p.cache {
        c.check(mb, env)?;
    }
    match p.lights {
        Some(l) => l.check(mb.len(), env.width, env.height),
        None => Ok(()),
    }
}

/// Generic single (j, k) forward (used by the f64 gradient tests).
pub(crate) fn gather_one_generic<F: Float>(
    mb: &MicroBuffer,
    mats: &VertexMaterials<F>,
    light: &LightIn<F>,
    j: usize,
    k: usize,
) -> [F; 3] {
    match mb.hit(j, k) {
        None => [F::ZERO; 3],
        Some(h) => {
            let mut esc = Escapes::new();
            esc.fill(mb, light, h);
            shade_pair(mb, mats, &esc, light.diffuse, j, k)
        }
    }
}

/// L1b for one (Gaussian j, direction k) (e.g. the radiance-consistency loss, SPEC 6).
pub fn gather_one(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    env: &EnvMap,
    p: &GatherParams,
    j: usize,
    k: usize,
) -> Result<[f32; 3], TraceError> {
    check(mb, mats, env)?;
    check_pairs(mb, [(j, k)])?;
    check_lights(mb, env, p)?;
    Ok(gather_one_generic(mb, mats, &LightIn::new(env, p), j, k))
}

/// L1b for every (j, k), row-major `j * K + k` (relighting, SPEC 7).
pub fn gather_all(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    env: &EnvMap,
    p: &GatherParams,
) -> Result<Vec<[f32; 3]>, TraceError> {
    gather_from(mb, mb, mats, env, p)
}

/// Eqn 13 for the rays of `rays`, each reflected by its hit Gaussian h as lit in `hits` (h's
/// escapes and `p.lights` index `hits`' Gaussians); `gather_all(mb)` is `gather_from(mb, mb)`.
pub fn gather_from(
    rays: &MicroBuffer,
    hits: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    env: &EnvMap,
    p: &GatherParams,
) -> Result<Vec<[f32; 3]>, TraceError> {
    let side = HitSide { mb: hits, mats: *mats, lights: p.lights };
    gather_grouped(rays, &[side], env, p, |_, _, _| 0)
}

/// One side of every Gaussian as the gather reflects it: the micro-buffer traced about that
/// side's normals (its escapes), the materials with their normals pointing out of that side, and
/// that side's directional-light visibility.
#[derive(Clone, Copy, Debug)]
pub struct HitSide<'a> {
    /// Micro-buffer traced about this side's normals.
    pub mb: &'a MicroBuffer,
    /// Activated vertex materials with the normals pointing out of this side.
    pub mats: VertexMaterials<'a, f32>,
    /// This side's directional lights and their visibility, if any.
    pub lights: Option<&'a BrightLights>,
}

/// Two-sided shading's Eqn 13: each ray of `rays` is reflected off the side of its hit Gaussian h
/// that it meets, `front` when the ray runs against h's front normal (`front.mb.normals[h]`),
/// `back` otherwise (`back.mb` traced about `-n`, `back.mats` with negated normals). Inside a
/// bowl, a ray from one wall meets the opposite wall's inner side, which the interior lights;
/// `gather_from(rays, front)` would reflect the outside's light instead. `p.lights` is unused:
/// each side brings its own.
pub fn gather_two_sided(
    rays: &MicroBuffer,
    front: HitSide,
    back: HitSide,
    env: &EnvMap,
    p: &GatherParams,
) -> Result<Vec<[f32; 3]>, TraceError> {
    let normals = &front.mb.normals;
    gather_grouped(rays, &[front, back], env, p, |j, k, h| side_met(rays, normals, j, k, h))
}

/// Every check [`gather_from`] and [`gather_two_sided`] make of the rays, the hit sides
/// (`[front]`, or `[front, back]`), the map and the settings, with their errors: for a device
/// backend, which must reject what the CPU rejects.
pub fn check_sides(rays: &MicroBuffer, sides: &[HitSide], env: &EnvMap, p: &GatherParams) -> Result<(), TraceError> {
    for side in sides {
        check(side.mb, &side.mats, env)?;
        check_lights(side.mb, env, &GatherParams { lights: side.lights, cache: None, ..*p })?;
        if (rays.len(), rays.k) != (side.mb.len(), side.mb.k) {
            return Err(TraceError::InvalidParameter(format!(
                "rays for {} Gaussians x {} directions, hits for {} x {}",
                rays.len(),
                rays.k,
                side.mb.len(),
                side.mb.k
            )));
        }
    }
    Ok(())
}

/// Which side of its hit Gaussian h ray (j, k) of `rays` meets in [`gather_two_sided`]: 1 (the
/// back) when the ray runs along h's front normal, else 0.
pub fn side_met(rays: &MicroBuffer, front_normals: &[glam::Vec3], j: usize, k: usize, h: usize) -> usize {
    usize::from(rays.direction(j, k).dot(front_normals[h]) > 0.0)
}

/// Eqn 13 for every ray of `rays` off side `side_of(j, k, h)` of its hit Gaussian h.
fn gather_grouped(
    rays: &MicroBuffer,
    sides: &[HitSide],
    env: &EnvMap,
    p: &GatherParams,
    side_of: impl Fn(usize, usize, usize) -> usize + Sync,
) -> Result<Vec<[f32; 3]>, TraceError> {
    check_sides(rays, sides, env, p)?;
    let lights: Vec<LightIn<f32>> =
        sides.iter().map(|side| LightIn::new(env, &GatherParams { lights: side.lights, cache: None, ..*p })).collect();
    let n = rays.len();
    let by_hit = PairsByHit::new(rays, sides.len(), side_of)?;
    let lanes = lane_kernels::<f32>(p.simd);
    // One task per (side, hit Gaussian h): its escape list is built once and shades every ray
    // that hit it. Each value is the same `shade_pair` as a ray-by-ray loop gives (bit for bit).
    let mut shaded = vec![[0.0f32; 3]; by_hit.pairs.len()];
    let mut groups = Vec::with_capacity(sides.len() * n);
    let mut rest = shaded.as_mut_slice();
    for group in 0..sides.len() * n {
        let (values, tail) = rest.split_at_mut(by_hit.range(group).len());
        groups.push((group, values));
        rest = tail;
    }
    groups.into_par_iter().for_each_init(Escapes::new, |esc, (group, values)| {
        if values.is_empty() {
            return;
        }
        let (s, h) = (group / n, group % n);
        // A scratch list may hold the same h's escapes from the other side.
        esc.h = NO_HIT;
        esc.fill(sides[s].mb, &lights[s], h as u32);
        for (o, &pair) in values.iter_mut().zip(&by_hit.pairs[by_hit.range(group)]) {
            let (j, k) = (pair as usize / rays.k, pair as usize % rays.k);
            *o = shade_f32(lanes, rays, &sides[s].mats, esc, p.diffuse, j, k);
        }
    });
    let mut out = vec![[0.0f32; 3]; n * rays.k];
    for (&pair, v) in by_hit.pairs.iter().zip(&shaded) {
        out[pair as usize] = *v;
    }
    Ok(out)
}

/// The (j, k) samples of a micro-buffer grouped by (side, first-hit Gaussian h) with a counting
/// sort: `pairs[range(side * N + h)]` are the flat indices `j * K + k` of the rays that hit h's
/// side `side`, in increasing order.
struct PairsByHit {
    start: Vec<usize>,
    pairs: Vec<u32>,
}

impl PairsByHit {
    fn new(
        rays: &MicroBuffer,
        side_count: usize,
        side_of: impl Fn(usize, usize, usize) -> usize + Sync,
    ) -> Result<Self, TraceError> {
        let (n, k) = (rays.len(), rays.k);
        if u32::try_from(rays.first_hit.len().max(side_count * n)).is_err() {
            return Err(TraceError::InvalidParameter(format!(
                "{n} Gaussians x {k} samples x {side_count} sides: more than a u32 can index"
            )));
        }
        if let Some(&h) = rays.first_hit.iter().find(|&&h| h < SURROUNDINGS_HIT && h as usize >= n) {
            return Err(TraceError::InvalidParameter(format!("first hit {h} of {n} Gaussians")));
        }
        let mut group = vec![NO_HIT; n * k];
        if k > 0 {
            group.par_chunks_mut(k).enumerate().for_each(|(j, row)| {
                for (kk, g) in row.iter_mut().enumerate() {
                    if let Some(h) = rays.hit(j, kk) {
                        let side = side_of(j, kk, h as usize).min(side_count - 1);
                        *g = (side * n + h as usize) as u32;
                    }
                }
            });
        }
        let groups = side_count * n;
        let mut start = vec![0usize; groups + 1];
        for &g in group.iter().filter(|&&g| g != NO_HIT) {
            start[g as usize + 1] += 1;
        }
        for g in 0..groups {
            start[g + 1] += start[g];
        }
        let mut next = start.clone();
        let mut pairs = vec![0u32; start[groups]];
        for (i, &g) in group.iter().enumerate().filter(|(_, &g)| g != NO_HIT) {
            pairs[next[g as usize]] = i as u32;
            next[g as usize] += 1;
        }
        Ok(Self { start, pairs })
    }

    fn range(&self, group: usize) -> std::ops::Range<usize> {
        self.start[group]..self.start[group + 1]
    }
}

/// L1b for a list of (j, k) pairs, in parallel.
pub fn gather_pairs(
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    env: &EnvMap,
    p: &GatherParams,
    pairs: &[(u32, u32)],
) -> Result<Vec<[f32; 3]>, TraceError> {
    check_pair_call(mb, mats, env, p, pairs)?;
    let light = LightIn::new(env, p);
    let lanes = lane_kernels::<f32>(p.simd);
    Ok(pairs
        .par_iter()
        .map_init(Escapes::new, |esc, &(j, k)| match mb.hit(j as usize, k as usize) {
            None => [0.0; 3],
            Some(h) => {
                esc.fill(mb, &light, h);
                shade_f32(lanes, mb, mats, esc, light.diffuse, j as usize, k as usize)
            }
        })
        .collect())
}

/// [`shade_pair`], in the lane kernels when `lanes` ([`lane_kernels`]).
pub(crate) fn shade_f32(
    lanes: bool,
    mb: &MicroBuffer,
    mats: &VertexMaterials<f32>,
    esc: &Escapes<f32>,
    diffuse: Diffuse,
    j: usize,
    k: usize,
) -> [f32; 3] {
    #[cfg(target_arch = "x86_64")]
    if lanes {
        // SAFETY: `lane_kernels` checked that the CPU has AVX2.
        return unsafe { crate::gather_lanes::shade_pair_avx2(mb, mats, esc, diffuse, j, k) };
    }
    let _ = lanes;
    shade_pair(mb, mats, esc, diffuse, j, k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::object_scene;
    use crate::{brightest_texels, Bvh, TraceParams};
    use svgir_core::Rng;

    /// Each ray of either side's micro-buffer is reflected off the side of its hit it meets: the
    /// value equals `gather_from` off that side alone, and both sides occur.
    #[test]
    fn two_sided_gather_reflects_off_the_side_each_ray_meets() {
        let (m, k) = (2, 16);
        let surfels = object_scene(300, 9);
        let bvh = Bvh::build(&surfels);
        let tp = TraceParams::default();
        let front = MicroBuffer::trace(&bvh, &surfels, k, 9, &tp).unwrap();
        let back =
            MicroBuffer::trace_about(&bvh, &surfels, front.normals.iter().map(|a| -*a).collect(), k, 9, &tp).unwrap();
        let n = front.len();
        let mut rng = Rng::new(9);
        let albedo: Vec<f32> = (0..n * m * 3).map(|_| rng.range(0.05, 0.9)).collect();
        let roughness: Vec<f32> = (0..n * m).map(|_| rng.range(0.1, 0.9)).collect();
        let normals: Vec<f32> =
            front.normals.iter().flat_map(|a| std::iter::repeat_n(a.to_array(), m)).flatten().collect();
        let flipped: Vec<f32> = normals.iter().map(|x| -x).collect();
        let mut env = EnvMap::constant(16, 8, [0.0; 3]);
        for t in env.data.iter_mut() {
            *t = [rng.range(0.1, 3.0), rng.range(0.1, 3.0), rng.range(0.1, 3.0)];
        }
        let texels = brightest_texels(&env, 3);
        let front_lights = BrightLights::trace(&bvh, &surfels, &front.normals, &env, &texels, &tp, None).unwrap();
        let back_lights = front_lights.for_normals(&bvh, &surfels, &back.normals, &tp, None).unwrap();
        let lit_front = HitSide {
            mb: &front,
            mats: VertexMaterials { m, albedo: &albedo, roughness: &roughness, normals: &normals },
            lights: Some(&front_lights),
        };
        let lit_back = HitSide {
            mats: VertexMaterials { normals: &flipped, ..lit_front.mats },
            mb: &back,
            lights: Some(&back_lights),
        };
        let p = GatherParams::default();
        let off = |rays: &MicroBuffer, side: &HitSide| {
            gather_from(rays, side.mb, &side.mats, &env, &GatherParams { lights: side.lights, ..p }).unwrap()
        };
        for rays in [&front, &back] {
            let got = gather_two_sided(rays, lit_front, lit_back, &env, &p).unwrap();
            let (want_front, want_back) = (off(rays, &lit_front), off(rays, &lit_back));
            let mut met = [0, 0];
            for j in 0..n {
                for kk in 0..k {
                    let i = j * k + kk;
                    match rays.hit(j, kk) {
                        None => assert_eq!(got[i], [0.0; 3]),
                        Some(h) if rays.direction(j, kk).dot(front.normals[h as usize]) > 0.0 => {
                            assert_eq!(got[i], want_back[i]);
                            met[1] += 1;
                        }
                        Some(_) => {
                            assert_eq!(got[i], want_front[i]);
                            met[0] += 1;
                        }
                    }
                }
            }
            assert!(met[0] > 50 && met[1] > 50, "both sides should be met: {met:?}");
        }
        let short = VertexMaterials { albedo: &albedo[1..], ..lit_front.mats };
        assert!(gather_two_sided(&front, HitSide { mats: short, ..lit_front }, lit_back, &env, &p).is_err());
    }
}
