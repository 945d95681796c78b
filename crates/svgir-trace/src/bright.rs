//! Bright texels of the environment map as directional lights (our addition; docs/method.md,
//! "Where svgir differs from SPEC").
//!
//! SPEC 4 estimates the light integral with K Fibonacci directions of weight 2pi/K each. A sun
//! in a 32 x 64 map is one texel of ~0.01 sr holding up to 60% of the map's power (the training
//! lights of cup_and_ball and bowl_fruit_128): K = 64 samples hit it for ~1% of the Gaussians,
//! and the [0, 64] clamp removes most of it where they do. So the map is split in two:
//! - the `count` texels of highest power `luminance x solid angle` are *directional lights*:
//!   direction = texel direction, weight = the texel's exact solid angle
//!   ([`EnvMap::texel_solid_angle`], the integral of its bilinear hat, so the split conserves the
//!   bilinear map's power), visibility traced per (Gaussian, light) here, no clamp;
//! - every other texel stays in the K-sample estimate, where lookups treat the light texels as
//!   black ([`BrightLights::mask_taps`]) so nothing is counted twice.
//!
//! With `count = 0` the split is empty and everything is SPEC 4.
//!
//! Visibility of light b from Gaussian j is the transmittance march of SPEC 5 (V = T_final, 0
//! below 0.2) from j's centre towards the texel, and 0 when the texel lies below j's geometric
//! horizon (the hemisphere of the micro-buffer normal). Stored light-major as u16 unorm, N per
//! light, so a re-selection keeps the columns of texels already traced. The columns come from a
//! [`ColumnTracer`]: on the CPU, rayon over Gaussians per light column (deterministic for any
//! thread count); or a [`MicroTracer`]'s own (`Via`, e.g. the GPU's), every column in one call.

use crate::bvh::Bvh;
use crate::pack::{from_unorm16, unorm16};
use crate::tracer::MicroTracer;
use crate::traverse::{march_visibility, HitSource, Ray, TraceParams};
use crate::TraceError;
use glam::Vec3;
use rayon::prelude::*;
use svgir_core::envmap::Taps;
use svgir_core::{EnvMap, Surfels};

/// The brightest environment texels shaded as directional lights, with their traced visibility per Gaussian.
#[derive(Clone, Debug, PartialEq)]
pub struct BrightLights {
    /// Size of the environment grid the texel indices refer to.
    pub width: u32,
    /// Height of that grid (width is 2 x height).
    pub height: u32,
    /// Texel index (`row * width + col`) of each light.
    pub texels: Vec<u32>,
    /// Unit direction of each light: the texel's grid direction unless moved by
    /// [`BrightLights::with_direction`] (the texel then only holds the light's radiance).
    pub dirs: Vec<Vec3>,
    /// Weight of each light: the texel's solid angle.
    pub solid_angle: Vec<f32>,
    /// Per texel of the map: is it a light (and so black in the K-sample lookups)?
    mask: Vec<bool>,
    /// Visibility per light, N entries each (u16 unorm).
    vis: Vec<Vec<u16>>,
}

/// `dir` scaled to unit length, and left as it is when it already has unit length to within
/// rounding: normalising in f32 is not idempotent (about one direction in a few hundred moves by
/// an ulp when normalised twice), and a light's direction restored from a checkpoint must trace
/// the same visibility as the direction it was saved from.
pub fn unit_direction(dir: Vec3) -> Vec3 {
    if (dir.length_squared() - 1.0).abs() <= 4.0 * f32::EPSILON {
        dir
    } else {
        dir.normalize()
    }
}

/// The `count` texels of highest power `luminance(L_t) x solid angle` (ties by index), among
/// those with positive power.
pub fn brightest_texels(env: &EnvMap, count: usize) -> Vec<u32> {
    let mut power: Vec<(f32, u32)> = (0..env.height)
        .flat_map(|r| (0..env.width).map(move |c| (r, c)))
        .map(|(r, c)| {
            let t = env.data[(r * env.width + c) as usize];
            let lum = 0.2126 * t[0] + 0.7152 * t[1] + 0.0722 * t[2];
            (lum * env.texel_solid_angle(r, c), r * env.width + c)
        })
        .filter(|(p, _)| *p > 0.0)
        .collect();
    power.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    power.into_iter().take(count).map(|(_, t)| t).collect()
}

/// Gather the power of the map's brightest lobe into one texel (the sun as a light).
///
/// SPEC 4's K-direction estimator can only learn a sun as a broad lobe: a single texel is hit by
/// a sample for about 1% of the Gaussians. Once that lobe has formed, this moves its power above
/// the surrounding sky into the lobe's brightest texel, where a directional light
/// ([`BrightLights`]) can cast the sun's hard shadows. The lobe is every texel within
/// `radius` radians of the peak; the sky level is the per-channel median over the ring between
/// `radius` and `2 radius`. Per channel, the lobe's excess `sum max(L_t - sky, 0) Omega_t` is
/// removed from its texels and added to the peak texel divided by the peak's solid angle, so the
/// map's total power `sum L_t Omega_t` is unchanged. Returns the new map and the peak texel.
pub fn concentrate_lobe(env: &EnvMap, radius: f32) -> (EnvMap, u32) {
    let (w, h) = (env.width, env.height);
    let lum = |t: [f32; 3]| 0.2126 * t[0] + 0.7152 * t[1] + 0.0722 * t[2];
    // Brightest by radiance (ties by index): the lobe's peak, not the largest-area texel.
    let peak = (0..w * h).fold(
        0u32,
        |best, t| {
            if lum(env.data[t as usize]) > lum(env.data[best as usize]) {
                t
            } else {
                best
            }
        },
    );
    let dir = |t: u32| env.texel_dir(t / w, t % w).normalize();
    let d0 = dir(peak);
    let angle = |t: u32| d0.dot(dir(t)).clamp(-1.0, 1.0).acos();
    let mut sky = [0.0f32; 3];
    for (c, s) in sky.iter_mut().enumerate() {
        let mut ring: Vec<f32> = (0..w * h)
            .filter(|&t| (radius..2.0 * radius).contains(&angle(t)))
            .map(|t| env.data[t as usize][c])
            .collect();
        ring.sort_by(f32::total_cmp);
        *s = ring.get(ring.len() / 2).copied().unwrap_or(0.0);
    }
    let mut out = env.clone();
    let mut excess = [0.0f64; 3];
    for t in (0..w * h).filter(|&t| angle(t) < radius) {
        let omega = env.texel_solid_angle(t / w, t % w) as f64;
        for c in 0..3 {
            let x = env.data[t as usize][c];
            if x > sky[c] {
                excess[c] += (x - sky[c]) as f64 * omega;
                out.data[t as usize][c] = sky[c];
            }
        }
    }
    let omega = env.texel_solid_angle(peak / w, peak % w) as f64;
    for c in 0..3 {
        out.data[peak as usize][c] += (excess[c] / omega) as f32;
    }
    (out, peak)
}

/// The ray sources of a column trace: the first `normals.len()` of `surfels` (the rest are
/// surroundings, occluders only).
fn sources(surfels: &Surfels, normals: &[Vec3]) -> Result<usize, TraceError> {
    if normals.len() > surfels.len() {
        return Err(TraceError::SizeMismatch { what: "normals", got: normals.len(), want: surfels.len() });
    }
    Ok(normals.len())
}

/// Visibility of direction `dir` from each of the first `normals.len()` Gaussians (0 below its
/// hemisphere; the Gaussians past them are surroundings, occluders only), u16 unorm.
fn trace_column<S: HitSource + Sync>(
    src: &S,
    surfels: &Surfels,
    normals: &[Vec3],
    dir: Vec3,
    p: &TraceParams,
) -> Vec<u16> {
    (0..normals.len().min(surfels.len()))
        .into_par_iter()
        .with_min_len(256)
        .map(|j| {
            if normals[j].dot(dir) <= 0.0 {
                return 0;
            }
            let ray = Ray::from_gaussian(surfels, j, dir, p);
            unorm16(march_visibility(src, &ray, p).visibility)
        })
        .collect()
}

/// What traces the lights' visibility columns: every [`HitSource`] (the rayon march above), or
/// a [`MicroTracer`] with its BVH ([`Via`], e.g. a GPU's).
pub trait ColumnTracer {
    /// For each of `dirs`, the visibility (u16 unorm) from every Gaussian of `surfels`: the
    /// visibility march from its centre, 0 where `dir` is below its hemisphere about `normals`.
    fn columns(
        &self,
        surfels: &Surfels,
        normals: &[Vec3],
        dirs: &[Vec3],
        p: &TraceParams,
    ) -> Result<Vec<Vec<u16>>, TraceError>;
}

impl<S: HitSource + Sync> ColumnTracer for S {
    fn columns(
        &self,
        surfels: &Surfels,
        normals: &[Vec3],
        dirs: &[Vec3],
        p: &TraceParams,
    ) -> Result<Vec<Vec<u16>>, TraceError> {
        Ok(dirs.iter().map(|&d| trace_column(self, surfels, normals, d, p)).collect())
    }
}

/// A [`MicroTracer`] and the BVH it traces through, as a [`ColumnTracer`].
pub struct Via<'a>(pub &'a dyn MicroTracer, pub &'a Bvh);

impl ColumnTracer for Via<'_> {
    fn columns(
        &self,
        surfels: &Surfels,
        normals: &[Vec3],
        dirs: &[Vec3],
        p: &TraceParams,
    ) -> Result<Vec<Vec<u16>>, TraceError> {
        self.0.visibility_columns(self.1, surfels, normals, dirs, p)
    }
}

impl BrightLights {
    /// No lights: every texel is sampled as in SPEC 4.
    pub fn empty(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            texels: Vec::new(),
            dirs: Vec::new(),
            solid_angle: Vec::new(),
            mask: vec![false; (width * height) as usize],
            vis: Vec::new(),
        }
    }

    /// Lights at `texels` of a `geom`-sized map, seen from every Gaussian of `surfels` (hemisphere
    /// axes `normals`, normally the micro-buffer's). Texels that `reuse` already holds (same map
    /// size and surfels) keep its direction and visibility instead of being traced again.
    pub fn trace<S: ColumnTracer + ?Sized>(
        src: &S,
        surfels: &Surfels,
        normals: &[Vec3],
        geom: &EnvMap,
        texels: &[u32],
        p: &TraceParams,
        reuse: Option<&BrightLights>,
    ) -> Result<Self, TraceError> {
        let n = sources(surfels, normals)?;
        // Each texel's reused column, or its direction to trace (all traced in one call).
        let mut columns: Vec<(Vec3, Option<Vec<u16>>)> = texels
            .iter()
            .map(|&t| {
                let reused = reuse.and_then(|r| Some((r, r.reusable(geom.width, geom.height, t, None, n)?)));
                if let Some((r, b)) = reused {
                    return (r.dirs[b], Some(r.vis[b].clone()));
                }
                if t >= geom.width * geom.height {
                    return (Vec3::Z, Some(Vec::new())); // rejected by `assemble`
                }
                (geom.texel_dir(t / geom.width, t % geom.width).normalize(), None)
            })
            .collect();
        let dirs: Vec<Vec3> = columns.iter().filter(|(_, c)| c.is_none()).map(|(d, _)| *d).collect();
        let mut traced = src.columns(surfels, normals, &dirs, p)?.into_iter();
        for (_, c) in columns.iter_mut().filter(|(_, c)| c.is_none()) {
            *c = traced.next();
        }
        let columns = columns.into_iter().map(|(d, c)| (d, c.unwrap_or_default())).collect();
        Self::assemble(geom, texels, columns)
    }

    /// These lights with light b moved to the unit direction `dir` (its visibility traced again;
    /// its radiance and solid angle stay its texel's): a sun need not sit at a texel centre.
    #[allow(clippy::too_many_arguments)]
    pub fn with_direction<S: ColumnTracer + ?Sized>(
        &self,
        src: &S,
        surfels: &Surfels,
        normals: &[Vec3],
        b: usize,
        dir: Vec3,
        p: &TraceParams,
    ) -> Result<Self, TraceError> {
        if b >= self.len() {
            return Err(TraceError::InvalidParameter(format!("light {b} of {}", self.len())));
        }
        sources(surfels, normals)?;
        if !dir.is_finite() || dir.length_squared() == 0.0 {
            return Err(TraceError::InvalidParameter(format!("light direction {dir} or normals")));
        }
        let mut out = self.clone();
        out.dirs[b] = unit_direction(dir);
        out.vis[b] = src.columns(surfels, normals, &[out.dirs[b]], p)?.remove(0);
        Ok(out)
    }

    /// The same lights (texels, directions, weights) seen from the hemispheres of other axes,
    /// e.g. every Gaussian's back side `-n` (two-sided shading). `reuse` holds earlier lights
    /// for the same axes, surfels and map size (e.g. the back sides' before a re-selection): a
    /// light of the same texel and direction keeps its column, the others are traced.
    pub fn for_normals<S: ColumnTracer + ?Sized>(
        &self,
        src: &S,
        surfels: &Surfels,
        normals: &[Vec3],
        p: &TraceParams,
        reuse: Option<&BrightLights>,
    ) -> Result<Self, TraceError> {
        let n = sources(surfels, normals)?;
        let mut out = self.clone();
        let mut columns: Vec<Option<Vec<u16>>> = self
            .texels
            .iter()
            .zip(&self.dirs)
            .map(|(&t, &d)| {
                reuse.and_then(|r| Some(r.vis[r.reusable(self.width, self.height, t, Some(d), n)?].clone()))
            })
            .collect();
        let dirs: Vec<Vec3> = columns.iter().zip(&self.dirs).filter(|(c, _)| c.is_none()).map(|(_, d)| *d).collect();
        let mut traced = src.columns(surfels, normals, &dirs, p)?.into_iter();
        for c in columns.iter_mut().filter(|c| c.is_none()) {
            *c = traced.next();
        }
        out.vis = columns.into_iter().map(Option::unwrap_or_default).collect();
        Ok(out)
    }

    /// Which of these lights, made for a `width x height` map, is texel `t` (along `dir` when
    /// given: a moved sun is another light) with a visibility column for `n` Gaussians.
    fn reusable(&self, width: u32, height: u32, t: u32, dir: Option<Vec3>, n: usize) -> Option<usize> {
        if (self.width, self.height) != (width, height) {
            return None;
        }
        let b = self.texels.iter().zip(&self.dirs).position(|(&x, &d)| x == t && dir.is_none_or(|dir| d == dir))?;
        (self.vis[b].len() == n).then_some(b)
    }

    /// Lights at `texels` with given visibility columns (`columns[b][j]` in [0, 1], e.g. from
    /// another tracer or a test).
    pub fn from_visibility(geom: &EnvMap, texels: &[u32], columns: &[Vec<f32>]) -> Result<Self, TraceError> {
        let columns = texels
            .iter()
            .zip(columns)
            .map(|(&t, c)| {
                let dir = (t < geom.width * geom.height).then(|| geom.texel_dir(t / geom.width, t % geom.width));
                (dir.unwrap_or(Vec3::Z).normalize(), c.iter().map(|&v| unorm16(v)).collect())
            })
            .collect();
        Self::assemble(geom, texels, columns)
    }

    /// Lights at `texels` with their (direction, visibility column).
    fn assemble(geom: &EnvMap, texels: &[u32], columns: Vec<(Vec3, Vec<u16>)>) -> Result<Self, TraceError> {
        if columns.len() != texels.len() {
            return Err(TraceError::SizeMismatch { what: "light columns", got: columns.len(), want: texels.len() });
        }
        let mut out = Self::empty(geom.width, geom.height);
        for (&t, (dir, column)) in texels.iter().zip(columns) {
            if t >= geom.width * geom.height {
                return Err(TraceError::InvalidParameter(format!(
                    "light texel {t} outside a {}x{} map",
                    geom.width, geom.height
                )));
            }
            if out.mask[t as usize] {
                return Err(TraceError::InvalidParameter(format!("light texel {t} given twice")));
            }
            if let Some(first) = out.vis.first() {
                if first.len() != column.len() {
                    return Err(TraceError::SizeMismatch {
                        what: "light column",
                        got: column.len(),
                        want: first.len(),
                    });
                }
            }
            let (row, col) = (t / geom.width, t % geom.width);
            out.mask[t as usize] = true;
            out.texels.push(t);
            out.dirs.push(dir);
            out.solid_angle.push(geom.texel_solid_angle(row, col));
            out.vis.push(column);
        }
        Ok(out)
    }

    /// Number of directional lights.
    pub fn len(&self) -> usize {
        self.texels.len()
    }

    /// True when no texel is a directional light (pure SPEC 4 shading).
    pub fn is_empty(&self) -> bool {
        self.texels.is_empty()
    }

    /// Is texel `t` a light?
    #[inline]
    pub fn is_light(&self, t: u32) -> bool {
        self.mask[t as usize]
    }

    /// Per texel of the map: is it a light?
    pub fn mask(&self) -> &[bool] {
        &self.mask
    }

    /// Zero the weights of taps on light texels: the K-sample estimate sees them as black.
    #[inline]
    pub fn mask_taps(&self, taps: &mut Taps) {
        if self.texels.is_empty() {
            return;
        }
        for k in 0..4 {
            if self.mask[taps.index[k] as usize] {
                taps.weight[k] = 0.0;
            }
        }
    }

    /// Light b as one of K samples of weight 2pi/K: its radiance is scaled by `Omega_b K / 2pi`
    /// so that the shared 2pi/K factor gives it its solid angle.
    #[inline]
    pub fn sample_scale(&self, b: usize, k: usize) -> f32 {
        self.solid_angle[b] * k as f32 / std::f32::consts::TAU
    }

    /// Visibility of light b from Gaussian j.
    #[inline]
    pub fn visibility(&self, j: usize, b: usize) -> f32 {
        from_unorm16(self.vis[b][j])
    }

    /// `Err` unless the lights index a `width` x `height` map and cover `n` Gaussians.
    pub fn check(&self, n: usize, width: u32, height: u32) -> Result<(), TraceError> {
        if (self.width, self.height) != (width, height) {
            return Err(TraceError::InvalidParameter(format!(
                "lights for a {}x{} map used with a {width}x{height} map",
                self.width, self.height
            )));
        }
        match self.vis.iter().find(|v| v.len() != n) {
            Some(v) => Err(TraceError::SizeMismatch { what: "light visibility", got: v.len(), want: n }),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenes::object_scene;
    use crate::traverse::march;
    use crate::{Bvh, MicroBuffer};

    /// A unit direction comes back unchanged, so a light moved to a saved direction keeps it
    /// to the bit; `Vec3::normalize` alone moves some of them (the count checks that this test
    /// meets such directions).
    #[test]
    fn unit_directions_are_kept_to_the_bit() {
        let mut rng = svgir_core::Rng::new(29);
        let mut moved_by_normalize = 0;
        for _ in 0..20_000 {
            let d = Vec3::new(rng.uniform() - 0.5, rng.uniform() - 0.5, rng.uniform() - 0.5) * 7.0;
            if d.length_squared() < 1e-6 {
                continue;
            }
            let u = unit_direction(d);
            assert!((u.length() - 1.0).abs() < 1e-6, "{d} -> {u}");
            assert_eq!(unit_direction(u), u, "{d}");
            moved_by_normalize += (u.normalize() != u) as usize;
        }
        assert!(moved_by_normalize > 10, "only {moved_by_normalize} directions move when normalised twice");
    }

    #[test]
    fn concentrate_lobe_moves_the_lobe_power_into_its_peak() {
        let mut env = EnvMap::constant(64, 32, [1.0, 2.0, 3.0]);
        let (w, h) = (env.width, env.height);
        let sun = env.texel_dir(8, 20).normalize();
        for t in 0..w * h {
            let a = sun.dot(env.texel_dir(t / w, t % w).normalize()).clamp(-1.0, 1.0).acos();
            let bump = 40.0 * (-(a / 0.15).powi(2)).exp();
            env.data[t as usize] = [1.0 + bump, 2.0 + 0.5 * bump, 3.0];
        }
        let power = |m: &EnvMap| {
            let mut p = [0.0f64; 3];
            for t in 0..w * h {
                let o = m.texel_solid_angle(t / w, t % w) as f64;
                (0..3).for_each(|c| p[c] += m.data[t as usize][c] as f64 * o);
            }
            p
        };
        let (out, peak) = concentrate_lobe(&env, 0.5);
        assert_eq!(peak, 8 * w + 20);
        let (before, after) = (power(&env), power(&out));
        for c in 0..3 {
            assert!((before[c] - after[c]).abs() < 1e-4 * before[c], "channel {c}: {} vs {}", before[c], after[c]);
        }
        // The lobe is flattened to the sky level, the peak holds its power, the rest is untouched.
        assert_eq!(out.data[(8 * w + 22) as usize], [1.0, 2.0, 3.0]);
        assert_eq!(out.data[(24 * w + 50) as usize], env.data[(24 * w + 50) as usize]);
        let o = env.texel_solid_angle(8, 20) as f64;
        let lobe_r =
            (before[0] - 1.0 * (0..w * h).map(|t| env.texel_solid_angle(t / w, t % w) as f64).sum::<f64>()) / o;
        assert!(((out.data[peak as usize][0] as f64 - 1.0) - lobe_r).abs() < 1e-2 * lobe_r);
        assert!(out.data[peak as usize][2] == 3.0, "a channel without a lobe gains nothing");
    }

    #[test]
    fn brightest_texels_rank_by_power() {
        let mut env = EnvMap::constant(8, 4, [1.0; 3]);
        env.data[9] = [50.0; 3];
        env.data[20] = [0.0, 10.0, 0.0];
        // A pole texel (row 0) owns a tiny solid angle: bright but little power.
        env.data[2] = [20.0; 3];
        let top = brightest_texels(&env, 2);
        assert_eq!(top, vec![9, 20]);
        assert_eq!(brightest_texels(&EnvMap::constant(8, 4, [0.0; 3]), 3), Vec::<u32>::new());
    }

    #[test]
    fn visibility_matches_the_micro_buffer_march() {
        let s = object_scene(600, 4);
        let bvh = Bvh::build(&s);
        let p = TraceParams::default();
        let mb = MicroBuffer::trace(&bvh, &s, 4, 1, &p).unwrap();
        let geom = EnvMap::constant(16, 8, [1.0; 3]);
        let texels = [17u32, 40, 77, 100];
        let lights = BrightLights::trace(&bvh, &s, &mb.normals, &geom, &texels, &p, None).unwrap();
        assert_eq!(lights.len(), 4);
        let (mut seen, mut blocked) = (0, 0);
        for (b, &t) in texels.iter().enumerate() {
            assert!(lights.is_light(t));
            let d = geom.texel_dir(t / 16, t % 16).normalize();
            for j in 0..s.len() {
                let v = lights.visibility(j, b);
                let want = if mb.normals[j].dot(d) <= 0.0 {
                    0.0
                } else {
                    march(&bvh, &s.sh, s.sh_degree, &Ray::from_gaussian(&s, j, d, &p), &p).visibility
                };
                assert!((v - want).abs() < 2e-5, "j={j} b={b}: {v} vs {want}");
                seen += (v > 0.5) as usize;
                blocked += (v == 0.0 && mb.normals[j].dot(d) > 0.0) as usize;
            }
        }
        assert!(seen > 0 && blocked > 0, "the scene should both show and shadow the lights");
        // Re-selection reuses traced columns and rejects bad texels.
        let again = BrightLights::trace(&bvh, &s, &mb.normals, &geom, &[100, 3], &p, Some(&lights)).unwrap();
        assert_eq!(again.vis[0], lights.vis[3]);
        assert!(!again.is_light(17));
        // A light moved off its texel centre: its visibility is the march along the new
        // direction, the others are untouched, and re-selection keeps the move.
        let d = (geom.texel_dir(40 / 16, 40 % 16).normalize() + Vec3::new(0.1, -0.05, 0.08)).normalize();
        let moved = lights.with_direction(&bvh, &s, &mb.normals, 1, d, &p).unwrap();
        assert_eq!((moved.dirs[1], moved.texels.clone()), (d, lights.texels.clone()));
        for j in 0..s.len() {
            let want = if mb.normals[j].dot(d) <= 0.0 {
                0.0
            } else {
                march(&bvh, &s.sh, s.sh_degree, &Ray::from_gaussian(&s, j, d, &p), &p).visibility
            };
            assert!((moved.visibility(j, 1) - want).abs() < 2e-5);
        }
        assert_eq!((&moved.vis[0], &moved.vis[2]), (&lights.vis[0], &lights.vis[2]));
        assert_ne!(moved.vis[1], lights.vis[1], "a different direction should change some visibility");
        let kept = BrightLights::trace(&bvh, &s, &mb.normals, &geom, &[40, 3], &p, Some(&moved)).unwrap();
        assert_eq!((kept.dirs[0], &kept.vis[0]), (d, &moved.vis[1]));
        // The back side sees the lights behind each Gaussian: the same march, the other horizon.
        let back_n: Vec<Vec3> = mb.normals.iter().map(|n| -*n).collect();
        let back = moved.for_normals(&bvh, &s, &back_n, &p, None).unwrap();
        // Re-selected lights keep the back columns of the texels and directions they share.
        let again = kept.for_normals(&bvh, &s, &back_n, &p, Some(&back)).unwrap();
        assert_eq!(again, kept.for_normals(&bvh, &s, &back_n, &p, None).unwrap());
        assert_eq!(again.vis[0], back.vis[1]);
        assert_eq!((&back.dirs, &back.texels, &back.solid_angle), (&moved.dirs, &moved.texels, &moved.solid_angle));
        let (mut lit_back, mut both) = (0, 0);
        for b in 0..back.len() {
            let d = back.dirs[b];
            for j in 0..s.len() {
                let want = if back_n[j].dot(d) <= 0.0 {
                    0.0
                } else {
                    march(&bvh, &s.sh, s.sh_degree, &Ray::from_gaussian(&s, j, d, &p), &p).visibility
                };
                assert!((back.visibility(j, b) - want).abs() < 2e-5);
                lit_back += (want > 0.0) as usize;
                both += (want > 0.0 && moved.visibility(j, b) > 0.0) as usize;
            }
        }
        assert!(lit_back > 0 && both == 0, "a light lights one side at most: {lit_back} {both}");
        // Fewer axes than Gaussians trace from the first ones (the rest are surroundings); more are refused.
        assert!(moved.for_normals(&bvh, &s, &[back_n.clone(), vec![Vec3::Z]].concat(), &p, None).is_err());
        assert!(lights.with_direction(&bvh, &s, &mb.normals, 4, d, &p).is_err());
        assert!(lights.with_direction(&bvh, &s, &mb.normals, 0, Vec3::ZERO, &p).is_err());
        assert!(BrightLights::trace(&bvh, &s, &mb.normals, &geom, &[128], &p, None).is_err());
        assert!(BrightLights::trace(&bvh, &s, &mb.normals, &geom, &[5, 5], &p, None).is_err());
        assert!(lights.check(s.len(), 16, 8).is_ok());
        assert!(lights.check(s.len() + 1, 16, 8).is_err());
        assert!(lights.check(s.len(), 32, 16).is_err());
        // Masked taps drop exactly the light texels.
        let mut taps = Taps { index: [17, 18, 40, 41], weight: [0.25; 4] };
        lights.mask_taps(&mut taps);
        assert_eq!(taps.weight, [0.0, 0.25, 0.0, 0.25]);
    }
}
