//! Ground-truth shading: renders every covered pixel of a synthetic scene's test views from the
//! GROUND-TRUTH albedo, roughness and normal maps under the ground-truth lights with our own BRDF
//! (SPEC 4, `svgir_shading::brdf`) and our environment-map code (`EnvMap`, SPEC 4 grid,
//! `read_envmap` with the dataset's strength), then compares with the Cycles images (SPEC 8).
//!
//! Why: stage 2 can only reach the ground truth if our shading model and conventions can
//! reproduce it. If this render is far from the Cycles images, a convention is wrong (env-map
//! direction, strength, sRGB, albedo or normal encoding, F0, 1/pi, integration); if it is close,
//! the gap is in the optimisation.
//!
//! Outgoing radiance per pixel, `L_o = int f(n, v, l) L_env(l) V(l) (n.l) dl`, split as
//! - diffuse `a/pi * E`, `E = sum_texels L V (n.d) dOmega`: a deterministic quadrature over the
//!   texels of the area-filtered `EnvMap` (aligned-corner rows at phi = r pi/(H-1), seam columns
//!   half weight, `dOmega = (cos phi_a - cos phi_b) dtheta`), exact for the filtered map;
//! - specular: GGX-NDF importance sampling (stratified, per-pixel Cranley-Patterson shift) of our
//!   `ggx_specular`, radiance from `EnvMap::lookup` on a finer map.
//!
//! - the brightest file pixels (sun, lamps; > `--bright` radiance, at most `--max-bright`) are
//!   split off before filtering and evaluated as explicit directional sources (no fireflies).
//!
//! V = 1 and V from rays against the true mesh (`mesh.ply`, small median-split BVH) are
//! accumulated together. "+ind(GT)" adds indirect light: an occluded direction receives the GT
//! radiance of the surface it hits, interpolated from mesh vertices that were looked up (linearised)
//! in the most frontal GT image that sees them under the same light -- the best case of SPEC 5's
//! traced-radiance indirect term.
//! Extra modes: Cycles-like layering (diffuse x (1 - E_spec(n.v)), E_spec the directional albedo
//! of the specular lobe), and SPEC 4's own K-direction Fibonacci estimator (K = 64 as in
//! training, 384 as at relighting evaluation) with the [0, 64] radiance clamp of the pipeline.
//! `--variants` tries env-lookup transforms (rotations about z, mirrors, y-up) and strength off
//! with V = 1 (`--variants-vis`: with V = mesh and GT indirect).
//!
//! Usage: `gt_shading DATA [OUT=/tmp/gt_shading] [--every N] [--diff-h H] [--spec-h H]
//!         [--spec M] [--no-vis] [--variants | --variants-vis] [--no-png] [--no-k] [--bright R] [--max-bright N]`

use anyhow::{Context, Result};
use glam::{Mat3, Vec3};
use rayon::prelude::*;
use std::f32::consts::PI;
use std::path::{Path, PathBuf};
use svgir_core::color::{linear_to_srgb, srgb_to_linear};
use svgir_core::{EnvMap, Image, View};
use svgir_shading::{brdf, hemisphere};

/// Environment radiance clamp inside the rendering equation in our pipeline (SPEC 4).
const ENV_MAX: f32 = 64.0;

use svgir_diagnose::mesh::{read_mesh, Bvh, Hit, Mesh};

// ---------------------------------------------------------------------------------------------
// Lights and shading.

/// One light: the quadrature texels (diffuse), the fine map (specular lookups), the brightest
/// file pixels (sun, lamps) as explicit directional sources, and GT radiance at mesh vertices.
struct Light {
    name: String,
    strength: f32,
    /// Radiance of each quadrature texel (same order as `Quad::dirs`), bright pixels removed.
    quad_rad: Vec<[f32; 3]>,
    /// Coarse map of the pipeline (SPEC 4: 32 x 64, everything included) for the K modes.
    coarse: EnvMap,
    /// Fine map for specular lookups, bright pixels removed.
    fine: EnvMap,
    /// Bright file pixels: world direction, solid angle, radiance (x strength).
    bright: Vec<(Vec3, f32, [f32; 3])>,
    /// Linear GT radiance at each mesh vertex (from the most frontal GT image that sees it under
    /// this light), None where no image sees it: the "perfect traced radiance" for indirect.
    vrad: Vec<Option<[f32; 3]>>,
}

/// Texel-quadrature directions (world) and solid angles of an aligned-corner grid (SPEC 4).
struct Quad {
    dirs: Vec<Vec3>,
    omega: Vec<f32>,
}

/// `t` maps a world direction to the direction at which the env map is looked up.
fn quadrature(m: &EnvMap, t: Mat3) -> Quad {
    let (w, h) = (m.width, m.height);
    let dphi = PI / (h - 1) as f32;
    let dtheta = 2.0 * PI / (w - 1) as f32;
    let (mut dirs, mut omega) = (Vec::new(), Vec::new());
    for r in 0..h {
        let phi = r as f32 * dphi;
        let (a, b) = ((phi - 0.5 * dphi).max(0.0), (phi + 0.5 * dphi).min(PI));
        let band = a.cos() - b.cos();
        for c in 0..w {
            let wc = if c == 0 || c == w - 1 { 0.5 } else { 1.0 };
            dirs.push(t.transpose() * m.texel_dir(r, c));
            omega.push(band * dtheta * wc);
        }
    }
    Quad { dirs, omega }
}

/// Shading inputs of one pixel.
#[derive(Clone, Copy)]
struct Px {
    index: usize,
    alpha: f32,
    n: Vec3,
    v: Vec3,
    albedo: [f32; 3],
    rough: f32,
    /// Surface point and geometric normal (facing the camera) from the mesh, if the pixel-centre
    /// ray hits it.
    hit: Option<(Vec3, Vec3)>,
    seed: u64,
}

/// Per-pixel, per-light sums; the final colour is assembled afterwards so that albedo and
/// layering variants need no re-shading.
#[derive(Clone, Default)]
struct PxOut {
    /// Irradiance-like `sum L V (n.d) dOmega` per light: V = 1, V = mesh, and the indirect
    /// radiance of occluded directions (GT radiance at the hit point).
    e1: Vec<[f32; 3]>,
    ev: Vec<[f32; 3]>,
    ei: Vec<[f32; 3]>,
    /// Specular radiance per light, same three parts.
    s1: Vec<[f32; 3]>,
    sv: Vec<[f32; 3]>,
    si: Vec<[f32; 3]>,
    /// Directional albedo of the specular lobe (L = 1, V = 1).
    es: f32,
    /// Occluded fraction of the cosine-weighted hemisphere without an indirect estimate.
    ind_missing: f32,
    /// SPEC 4 estimator per (K mode, light): full colour with V = mesh.
    k: Vec<Vec<[f32; 3]>>,
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = x;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn u01(h: u64) -> f32 {
    (h >> 40) as f32 / (1u64 << 24) as f32
}

fn add3(a: &mut [f32; 3], b: [f32; 3], w: f32) {
    for c in 0..3 {
        a[c] += w * b[c];
    }
}

/// The K-direction modes: (K, clamp at ENV_MAX).
const K_MODES: [(usize, bool); 4] = [(64, true), (384, true), (64, false), (384, false)];

struct Params {
    spec_samples: usize,
    vis: bool,
    /// Env lookup transform (world dir -> lookup dir).
    t: Mat3,
    k_modes: bool,
}

/// The first surface hit along `d` from the pixel's surface point (None: sky visible).
fn occluder(bvh: Option<&Bvh>, px: &Px, d: Vec3) -> Option<Hit> {
    match (bvh, px.hit) {
        (Some(b), Some((p, ng))) => {
            let o = p + ng * 1e-3 + d * 1e-4;
            b.intersect(o, d, 1e-5, f32::MAX, false)
        }
        _ => None,
    }
}

/// GT radiance at a hit point, interpolated from the vertices that have one.
fn hit_radiance(mesh: &Mesh, light: &Light, h: &Hit) -> Option<[f32; 3]> {
    let tri = mesh.idx[h.tri as usize];
    let w = [1.0 - h.u - h.v, h.u, h.v];
    let (mut acc, mut ws) = ([0.0f32; 3], 0.0);
    for k in 0..3 {
        if let Some(r) = light.vrad[tri[k] as usize] {
            add3(&mut acc, r, w[k]);
            ws += w[k];
        }
    }
    (ws > 1e-3).then(|| acc.map(|x| x / ws))
}

fn shade_px(px: &Px, lights: &[Light], quad: &Quad, p: &Params, bvh: Option<&Bvh>, mesh: &Mesh) -> PxOut {
    let nl = lights.len();
    let z = vec![[0.0; 3]; nl];
    let mut out = PxOut {
        e1: z.clone(),
        ev: z.clone(),
        ei: z.clone(),
        s1: z.clone(),
        sv: z.clone(),
        si: z,
        es: 0.0,
        ind_missing: 0.0,
        k: Vec::new(),
    };
    let bvh = if p.vis { bvh } else { None };
    let n = px.n;
    let (nn, vv) = (n.to_array(), px.v.to_array());
    let r = px.rough.max(0.02);
    // Diffuse: texel quadrature (exact for the area-filtered map).
    for (i, (&d, &om)) in quad.dirs.iter().zip(&quad.omega).enumerate() {
        let c = n.dot(d);
        if c <= 0.0 {
            continue;
        }
        let occ = occluder(bvh, px, d);
        for (li, l) in lights.iter().enumerate() {
            add3(&mut out.e1[li], l.quad_rad[i], c * om);
            match &occ {
                None => add3(&mut out.ev[li], l.quad_rad[i], c * om),
                Some(h) => match hit_radiance(mesh, l, h) {
                    Some(rad) => add3(&mut out.ei[li], rad, c * om),
                    None if li == 0 => out.ind_missing += c * om / PI,
                    None => {}
                },
            }
        }
    }
    // Bright file pixels (sun, lamps): explicit sources, full BRDF.
    for (li, l) in lights.iter().enumerate() {
        for &(d, om, rad) in &l.bright {
            let c = n.dot(d);
            if c <= 0.0 {
                continue;
            }
            let s = brdf::ggx_specular(nn, vv, d.to_array(), r);
            add3(&mut out.e1[li], rad, c * om);
            add3(&mut out.s1[li], rad, s * c * om);
            if occluder(bvh, px, d).is_none() {
                add3(&mut out.ev[li], rad, c * om);
                add3(&mut out.sv[li], rad, s * c * om);
            }
        }
    }
    // Specular: sample the GGX NDF, pdf_l = D (n.h) / (4 v.h), weight S (n.l) / pdf_l.
    let alpha = r * r;
    let a2 = alpha * alpha;
    let (b1, b2) = hemisphere::tangent_frame(n);
    let (r1, r2) = (u01(splitmix(px.seed)), u01(splitmix(px.seed ^ 0xABCD)));
    let m = p.spec_samples;
    for k in 0..m {
        let u1 = ((k as f32 + 0.5) / m as f32 + r1).fract();
        let u2 = (k as f32 * 0.618_034 + r2).fract();
        let cos2 = (1.0 - u1) / (1.0 + (a2 - 1.0) * u1);
        let (ch, sh) = (cos2.sqrt(), (1.0 - cos2).max(0.0).sqrt());
        let ph = 2.0 * PI * u2;
        let h = (b1 * (sh * ph.cos()) + b2 * (sh * ph.sin()) + n * ch).normalize();
        let vh = px.v.dot(h);
        if vh <= 0.0 {
            continue;
        }
        let l = 2.0 * vh * h - px.v;
        let nl_ = n.dot(l);
        if nl_ <= 0.0 {
            continue;
        }
        let q = cos2 * (a2 - 1.0) + 1.0;
        let dd = a2 / (PI * q * q);
        let pdf = dd * ch / (4.0 * vh);
        let s = brdf::ggx_specular(nn, vv, l.to_array(), r);
        let w = s * nl_ / pdf / m as f32;
        out.es += w;
        let occ = occluder(bvh, px, l);
        let ld = p.t * l;
        for (li, lt) in lights.iter().enumerate() {
            let rad = lt.fine.lookup(ld);
            add3(&mut out.s1[li], rad, w);
            match &occ {
                None => add3(&mut out.sv[li], rad, w),
                Some(h) => {
                    if let Some(ir) = hit_radiance(mesh, lt, h) {
                        add3(&mut out.si[li], ir, w);
                    }
                }
            }
        }
    }
    // SPEC 4's estimator: K Fibonacci directions around n, weight 2pi/K, coarse map (all of the
    // light, bright pixels included, as the pipeline sees it).
    if p.k_modes {
        let xi = u01(splitmix(px.seed ^ 0x5555)) * std::f32::consts::TAU;
        for &(kk, clamp) in &K_MODES {
            let mut acc = vec![[0.0f32; 3]; nl];
            for k in 0..kk {
                let d = hemisphere::hemisphere_dir(n, k, kk, xi);
                let c = n.dot(d).max(0.0);
                if c <= 0.0 || occluder(bvh, px, d).is_some() {
                    continue;
                }
                let f = brdf::ggx(nn, vv, d.to_array(), px.albedo, r, svgir_shading::Diffuse::Added);
                for (li, lt) in lights.iter().enumerate() {
                    let rad = lt.coarse.lookup(p.t * d);
                    for ch in 0..3 {
                        let lr = if clamp { rad[ch].clamp(0.0, ENV_MAX) } else { rad[ch] };
                        acc[li][ch] += f[ch] * lr * c * std::f32::consts::TAU / kk as f32;
                    }
                }
            }
            out.k.push(acc);
        }
    }
    out
}

/// Splits an equirectangular file (Blender convention, SPEC-4-compatible: `u = 0.5 -
/// atan2(y, x)/2pi`, top row +z) into its `max_bright` brightest pixels above `thresh` (as
/// explicit sources, directions through `t^T`) and the residual image with those pixels zeroed.
fn split_bright(
    img: &Image,
    strength: f32,
    t: Mat3,
    thresh: f32,
    max_bright: usize,
) -> (Image, Vec<(Vec3, f32, [f32; 3])>) {
    let (w, h) = (img.width, img.height);
    let mut cand: Vec<(f32, u32, u32)> = Vec::new();
    for j in 0..h {
        for i in 0..w {
            let p = img.pixel(i, j);
            let m = p[0].max(p[1]).max(p[2]) * strength;
            if m > thresh {
                cand.push((m, i, j));
            }
        }
    }
    cand.sort_by(|a, b| b.0.total_cmp(&a.0));
    cand.truncate(max_bright);
    let mut res = img.clone();
    let mut bright = Vec::new();
    for &(_, i, j) in &cand {
        let u = (i as f32 + 0.5) / w as f32;
        let theta = (0.5 - u) * 2.0 * PI;
        let (el_top, el_bot) = (0.5 * PI - j as f32 * PI / h as f32, 0.5 * PI - (j + 1) as f32 * PI / h as f32);
        let el = 0.5 * (el_top + el_bot);
        let d = Vec3::new(el.cos() * theta.cos(), el.cos() * theta.sin(), el.sin());
        let om = (el_top.sin() - el_bot.sin()) * 2.0 * PI / w as f32;
        let p = img.pixel(i, j);
        bright.push((t.transpose() * d, om, [p[0] * strength, p[1] * strength, p[2] * strength]));
        res.pixel_mut(i, j)[..3].fill(0.0);
    }
    (res, bright)
}

/// GT radiance (linear) at each mesh vertex under one light, from the given GT images.
fn vertex_radiance(mesh: &Mesh, bvh: &Bvh, images: &[(&svgir_core::Camera, &Image)]) -> Vec<Option<[f32; 3]>> {
    (0..mesh.verts.len())
        .into_par_iter()
        .map(|vi| {
            let x = mesh.verts[vi];
            let nv = mesh.vnormals[vi];
            let mut best: Option<(f32, [f32; 3])> = None;
            for (cam, img) in images {
                let c = cam.center();
                let to_cam = (c - x).normalize();
                let score = if nv == Vec3::ZERO { 1.0 } else { nv.dot(to_cam).abs() };
                if best.is_some_and(|b| b.0 >= score) || score < 0.2 {
                    continue;
                }
                let Some((px, py, _)) = cam.project(x) else { continue };
                let (ix, iy) = (px.floor() as i64, py.floor() as i64);
                if ix < 0 || iy < 0 || ix >= img.width as i64 || iy >= img.height as i64 {
                    continue;
                }
                let q = img.pixel(ix as u32, iy as u32);
                if q[3] < 0.99 {
                    continue;
                }
                let dist = (c - x).length();
                let d = (x - c) / dist;
                let seen = bvh.intersect(c, d, 1e-4, f32::MAX, false).is_some_and(|h| (h.t - dist).abs() < 2e-3 * dist);
                if seen {
                    best = Some((score, [q[0], q[1], q[2]].map(srgb_to_linear)));
                }
            }
            best.map(|b| b.1)
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Views, metrics, output.

fn pixels(view: &View, vi: usize, bvh: &Bvh, mesh: &Mesh, srgb_albedo: bool) -> Result<(Vec<Px>, [usize; 3], f64)> {
    let cam = &view.camera;
    let (w, h) = (cam.width(), cam.height());
    let albedo = view.albedo.as_ref().context("no albedo")?;
    let normal = view.normal.as_ref().context("no normal")?;
    let rough = view.roughness.as_ref().context("no roughness")?;
    let o = cam.center();
    let list: Vec<Px> = (0..(w * h) as usize)
        .into_par_iter()
        .filter_map(|i| {
            let alpha = view.image.data[4 * i + 3];
            if alpha <= 0.0 {
                return None;
            }
            let (x, y) = ((i as u32 % w) as f32 + 0.5, (i as u32 / w) as f32 + 0.5);
            let dir = cam.ray_dir(x, y);
            let n = Vec3::from_slice(&normal.data[3 * i..3 * i + 3]);
            if n.length_squared() < 0.5 {
                return None;
            }
            let hit = bvh.intersect(o, dir, 1e-4, f32::MAX, false).map(|hh| {
                let tr = mesh.idx[hh.tri as usize].map(|k| mesh.verts[k as usize]);
                let t = hh.t;
                let mut ng = (tr[1] - tr[0]).cross(tr[2] - tr[0]).normalize();
                if ng.dot(dir) > 0.0 {
                    ng = -ng;
                }
                (o + dir * t, ng)
            });
            let mut a = [albedo.data[3 * i], albedo.data[3 * i + 1], albedo.data[3 * i + 2]];
            if srgb_albedo {
                a = a.map(srgb_to_linear);
            }
            Some(Px {
                index: i,
                alpha,
                n,
                v: -dir,
                albedo: a,
                rough: rough.data[i],
                hit,
                seed: splitmix((vi as u64) << 32 | i as u64),
            })
        })
        .collect();
    // Sanity: how well do mesh normals agree with the GT normals (degrees), misses.
    let (mut ang, mut cnt, mut miss) = (0.0f64, 0usize, 0usize);
    for p in &list {
        match p.hit {
            Some((_, ng)) if p.alpha > 0.99 => {
                ang += (ng.dot(p.n).clamp(-1.0, 1.0) as f64).acos().to_degrees();
                cnt += 1;
            }
            None => miss += 1,
            _ => {}
        }
    }
    let fg = list.iter().filter(|p| p.alpha > 0.99).count();
    let covered = list.len();
    Ok((list, [covered, fg, miss], ang / cnt.max(1) as f64))
}

/// Error statistics of one (mode, light) over many views.
#[derive(Default, Clone)]
struct Stats {
    fg_se: f64,
    fg_n: f64,
    /// Full image, composited over black by GT alpha on both sides (correct SPEC 8).
    full_se: f64,
    full_n: f64,
    /// As `eval`'s relighting does: prediction (already x alpha) x mask again.
    relit_eval_se: f64,
    /// As `eval`'s NVS does: prediction over black vs the GT's straight (un-composited) RGB.
    nvs_eval_se: f64,
    gt_lin: [f64; 3],
    or_lin: [f64; 3],
    psnr_views: Vec<f64>,
}

fn psnr(se: f64, n: f64) -> f64 {
    -10.0 * (se / n).log10()
}

impl Stats {
    /// Adds one view; `lin` is the ground-truth shading's linear radiance per pixel (RGB), `gt` RGBA straight.
    fn add(&mut self, lin: &[f32], gt: &Image, covered: &[bool]) {
        let (mut vse, mut vn) = (0.0, 0.0);
        for i in 0..gt.pixel_count() {
            let g = &gt.data[4 * i..4 * i + 4];
            let a = g[3];
            let pr: [f32; 3] = [0, 1, 2].map(|c| linear_to_srgb(lin[3 * i + c]).clamp(0.0, 1.0));
            let pr = if covered[i] { pr } else { [0.0; 3] };
            for c in 0..3 {
                let gc = g[c].clamp(0.0, 1.0);
                let e_full = (pr[c] * a - gc * a) as f64;
                self.full_se += e_full * e_full;
                let e_rel = (pr[c] * a * a - gc * a) as f64;
                self.relit_eval_se += e_rel * e_rel;
                let e_nvs = (pr[c] * a - gc) as f64;
                self.nvs_eval_se += e_nvs * e_nvs;
            }
            self.full_n += 3.0;
            if a > 0.99 {
                let mut unclipped = true;
                for c in 0..3 {
                    let e = (pr[c] - g[c]) as f64;
                    self.fg_se += e * e;
                    vse += e * e;
                    unclipped &= g[c] < 0.99;
                }
                self.fg_n += 3.0;
                vn += 3.0;
                if unclipped {
                    for c in 0..3 {
                        self.gt_lin[c] += srgb_to_linear(g[c]) as f64;
                        self.or_lin[c] += lin[3 * i + c] as f64;
                    }
                }
            }
        }
        self.psnr_views.push(psnr(vse, vn));
    }

    fn line(&self) -> String {
        let r = [0, 1, 2].map(|c| self.gt_lin[c] / self.or_lin[c].max(1e-12));
        format!(
            "fg {:6.2} | full {:6.2} | eval-relit-style {:6.2} | eval-nvs-style {:6.2} | GT/ours {:.3} {:.3} {:.3} | worst view fg {:5.2}",
            psnr(self.fg_se, self.fg_n),
            psnr(self.full_se, self.full_n),
            psnr(self.relit_eval_se, self.full_n),
            psnr(self.nvs_eval_se, self.full_n),
            r[0],
            r[1],
            r[2],
            self.psnr_views.iter().cloned().fold(f64::INFINITY, f64::min)
        )
    }
}

/// Colour modes assembled from the per-pixel sums.
const MODES: [&str; 10] = [
    "ref V=1",
    "ref V=mesh",
    "ref V=mesh+ind(GT)",
    "layered V=1",
    "layered V=mesh",
    "layered V=mesh+ind(GT)",
    "SPEC4 K=64 clamp64 V=mesh",
    "SPEC4 K=384 clamp64 V=mesh",
    "SPEC4 K=64 noclamp V=mesh",
    "SPEC4 K=384 noclamp V=mesh",
];

fn mode_color(mode: usize, px: &Px, o: &PxOut, li: usize) -> [f32; 3] {
    let a = px.albedo;
    let diff = |e: [f32; 3], wgt: f32| [0, 1, 2].map(|c| wgt * a[c] / PI * e[c]);
    let sum = |d: [f32; 3], s: [f32; 3]| [d[0] + s[0], d[1] + s[1], d[2] + s[2]];
    let lay = (1.0 - o.es).max(0.0);
    let ei = sum(o.ev[li], o.ei[li]);
    let si = sum(o.sv[li], o.si[li]);
    match mode {
        0 => sum(diff(o.e1[li], 1.0), o.s1[li]),
        1 => sum(diff(o.ev[li], 1.0), o.sv[li]),
        2 => sum(diff(ei, 1.0), si),
        3 => sum(diff(o.e1[li], lay), o.s1[li]),
        4 => sum(diff(o.ev[li], lay), o.sv[li]),
        5 => sum(diff(ei, lay), si),
        m => o.k.get(m - 6).map_or([0.0; 3], |k| k[li]),
    }
}

fn gt_image<'a>(view: &'a View, light: &str, train_name: &str) -> Option<&'a Image> {
    if light == train_name {
        Some(&view.image)
    } else {
        view.relit.get(light)
    }
}

fn write_side_by_side(path: &Path, lin: &[f32], gt: &Image, covered: &[bool]) -> Result<()> {
    let (w, h) = (gt.width, gt.height);
    let mut img = Image::new(3 * w, h, 3);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let a = gt.data[4 * i + 3];
            let pr: [f32; 3] =
                [0, 1, 2].map(|c| if covered[i] { linear_to_srgb(lin[3 * i + c]).min(1.0) * a } else { 0.0 });
            let g: [f32; 3] = [0, 1, 2].map(|c| gt.data[4 * i + c] * a);
            for c in 0..3 {
                img.pixel_mut(x, y)[c] = pr[c];
                img.pixel_mut(x + w, y)[c] = g[c];
                img.pixel_mut(x + 2 * w, y)[c] = 4.0 * (pr[c] - g[c]).abs();
            }
        }
    }
    svgir_io::write_png(path, &img, 8)?;
    Ok(())
}

struct Args {
    data: PathBuf,
    out: PathBuf,
    every: usize,
    diff_h: u32,
    spec_h: u32,
    spec: usize,
    vis: bool,
    variants: bool,
    /// Variants with V = mesh and GT indirect (slower) instead of V = 1.
    variants_vis: bool,
    /// Also run SPEC 4's K-direction estimator (modes "SPEC4 ...").
    k_modes: bool,
    png: bool,
    /// Radiance above which file pixels become explicit sources, and at most how many.
    bright_thresh: f32,
    max_bright: usize,
}

fn parse_args() -> Result<Args> {
    let mut a = Args {
        data: PathBuf::new(),
        out: PathBuf::from("/tmp/gt_shading"),
        every: 1,
        diff_h: 32,
        spec_h: 256,
        spec: 512,
        vis: true,
        variants: false,
        variants_vis: false,
        k_modes: true,
        png: true,
        bright_thresh: 20.0,
        max_bright: 512,
    };
    let mut pos = Vec::new();
    let mut it = std::env::args().skip(1);
    while let Some(s) = it.next() {
        let mut num =
            |name: &str| -> Result<usize> { Ok(it.next().with_context(|| format!("{name} value"))?.parse()?) };
        match s.as_str() {
            "--every" => a.every = num("--every")?.max(1),
            "--diff-h" => a.diff_h = num("--diff-h")? as u32,
            "--spec-h" => a.spec_h = num("--spec-h")? as u32,
            "--spec" => a.spec = num("--spec")?,
            "--no-vis" => a.vis = false,
            "--variants" => a.variants = true,
            "--variants-vis" => (a.variants, a.variants_vis) = (true, true),
            "--no-png" => a.png = false,
            "--no-k" => a.k_modes = false,
            "--bright" => a.bright_thresh = num("--bright")? as f32,
            "--max-bright" => a.max_bright = num("--max-bright")?,
            _ => pos.push(s),
        }
    }
    a.data = PathBuf::from(pos.first().context("usage: gt_shading DATA [OUT] [options]")?);
    if let Some(o) = pos.get(1) {
        a.out = PathBuf::from(o);
    }
    Ok(a)
}

fn load_lights(
    ds: &svgir_core::Dataset,
    args: &Args,
    t: Mat3,
    strength_on: bool,
    mesh: &Mesh,
    bvh: &Bvh,
    with_indirect: bool,
) -> Result<(Vec<Light>, Quad)> {
    let train_name = ds.train_light.as_ref().map(|l| l.name.clone()).unwrap_or_default();
    let infos: Vec<_> = ds.train_light.iter().chain(ds.relight_lights.iter()).cloned().collect();
    let mut lights = Vec::new();
    let mut quad = None;
    for li in infos {
        let path = li.envmap_path.clone().with_context(|| format!("light {} has no map", li.name))?;
        let s = if strength_on { li.strength } else { 1.0 };
        let coarse = svgir_io::read_envmap(&path, s, 32)?;
        // Same steps as `read_envmap`, with the brightest pixels split off first.
        let file = svgir_io::read_image(&path)?.map(|v| v.max(0.0));
        let (residual, bright) = split_bright(&file, s, t, args.bright_thresh, args.max_bright);
        let dmap = EnvMap::from_equirect(&residual, s, args.diff_h);
        let fine = EnvMap::from_equirect(&residual, s, args.spec_h);
        let bright_energy: f32 = bright.iter().map(|b| b.1 * (b.2[0] + b.2[1] + b.2[2]) / 3.0).sum();
        let vrad = if with_indirect {
            let images: Vec<(&svgir_core::Camera, &Image)> = if li.name == train_name {
                ds.train.iter().chain(ds.test.iter()).map(|v| (&v.camera, &v.image)).collect()
            } else {
                ds.test.iter().filter_map(|v| v.relit.get(&li.name).map(|im| (&v.camera, im))).collect()
            };
            let vr = vertex_radiance(mesh, bvh, &images);
            let known = vr.iter().filter(|x| x.is_some()).count();
            println!("  {}: GT radiance known at {known} / {} vertices ({} images)", li.name, vr.len(), images.len());
            vr
        } else {
            vec![None; mesh.verts.len()]
        };
        let q = quadrature(&dmap, t);
        // Radiance of each quadrature texel: the texel itself (lookup at T d == texel dir).
        let quad_rad = dmap.data.clone();
        let maxc = coarse.data.iter().map(|p| p[0].max(p[1]).max(p[2])).fold(0.0f32, f32::max);
        let above = coarse.data.iter().filter(|p| p[0].max(p[1]).max(p[2]) > ENV_MAX).count();
        let mean = coarse.mean_radiance();
        let total: f32 = {
            let q = quadrature(&coarse, Mat3::IDENTITY);
            q.omega.iter().zip(&coarse.data).map(|(o, p)| o * (p[0] + p[1] + p[2]) / 3.0).sum()
        };
        println!(
            "light {:<12} strength {:.3} map {}: 32x64 max texel {:.1}, texels > {ENV_MAX}: {above}, mean radiance {:.3} {:.3} {:.3}; {} bright pixels carry {:.1}% of the power",
            li.name,
            li.strength,
            path.display(),
            maxc,
            mean[0],
            mean[1],
            mean[2],
            bright.len(),
            100.0 * bright_energy / total.max(1e-9)
        );
        quad.get_or_insert(q);
        lights.push(Light { name: li.name.clone(), strength: li.strength, quad_rad, coarse, fine, bright, vrad });
    }
    Ok((lights, quad.context("no lights")?))
}

fn main() -> Result<()> {
    let args = parse_args()?;
    let t0 = std::time::Instant::now();
    let ds = svgir_io::load_dataset(&args.data, &svgir_io::LoadOptions::default())?;
    let train_name = ds.train_light.as_ref().map(|l| l.name.clone()).unwrap_or_default();
    let mesh = read_mesh(&args.data.join("mesh.ply"))?;
    let bvh = Bvh::build(&mesh);
    println!(
        "{}: {} test views (every {}), mesh {} triangles, BVH {} nodes, loaded in {:.1}s",
        ds.name,
        ds.test.len(),
        args.every,
        mesh.idx.len(),
        bvh.nodes.len(),
        t0.elapsed().as_secs_f32()
    );
    let views: Vec<(usize, &View)> = ds.test.iter().enumerate().step_by(args.every).collect();
    std::fs::create_dir_all(&args.out)?;

    if args.variants {
        return run_variants(&ds, &views, &bvh, &mesh, &args, &train_name);
    }

    let (lights, quad) = load_lights(&ds, &args, Mat3::IDENTITY, true, &mesh, &bvh, args.vis)?;
    let params =
        Params { spec_samples: args.spec, vis: args.vis, t: Mat3::IDENTITY, k_modes: args.vis && args.k_modes };
    let nmodes = match (args.vis, args.k_modes) {
        (false, _) => 1,
        (true, false) => 6,
        (true, true) => MODES.len(),
    };
    let mut stats = vec![vec![Stats::default(); lights.len()]; nmodes];
    // Albedo decoded as sRGB (wrong by the data README, tested as a variant) on "ref V=mesh".
    let mut stats_srgb_albedo = vec![Stats::default(); lights.len()];
    for &(vi, view) in &views {
        let tv = std::time::Instant::now();
        let (pxs, [cov, fg, miss], ang) = pixels(view, vi, &bvh, &mesh, false)?;
        let outs: Vec<PxOut> =
            pxs.par_iter().map(|p| shade_px(p, &lights, &quad, &params, Some(&bvh), &mesh)).collect();
        let ind_missing = outs.iter().map(|o| o.ind_missing as f64).sum::<f64>() / outs.len().max(1) as f64;
        let np = view.image.pixel_count();
        let mut covered = vec![false; np];
        for p in &pxs {
            covered[p.index] = true;
        }
        for (li, light) in lights.iter().enumerate() {
            let Some(gt) = gt_image(view, &light.name, &train_name) else { continue };
            for (m, st) in stats.iter_mut().enumerate() {
                let mut lin = vec![0.0f32; 3 * np];
                for (p, o) in pxs.iter().zip(&outs) {
                    lin[3 * p.index..3 * p.index + 3].copy_from_slice(&mode_color(m, p, o, li));
                }
                st[li].add(&lin, gt, &covered);
                if args.png && (m == 1 || m == 2 || m == 5) {
                    let tag = MODES[m].replace([' ', '='], "_");
                    write_side_by_side(
                        &args.out.join(format!("{}_{}_{}.png", view.name, light.name, tag)),
                        &lin,
                        gt,
                        &covered,
                    )?;
                }
            }
            if args.vis {
                let mut lin = vec![0.0f32; 3 * np];
                for (p, o) in pxs.iter().zip(&outs) {
                    let p2 = Px { albedo: p.albedo.map(srgb_to_linear), ..*p };
                    lin[3 * p.index..3 * p.index + 3].copy_from_slice(&mode_color(1, &p2, o, li));
                }
                stats_srgb_albedo[li].add(&lin, gt, &covered);
            }
        }
        println!(
            "  {}: {cov} covered px, {fg} fg, {miss} miss the mesh, mesh-vs-GT normal {ang:.2} deg, occluded cos-weight without GT radiance {:.4}, {:.1}s",
            view.name,
            ind_missing,
            tv.elapsed().as_secs_f32()
        );
    }
    println!(
        "\n== {} (diffuse quadrature on {}x{} map, {} GGX samples on {}x{} map) ==",
        ds.name,
        args.diff_h,
        2 * args.diff_h,
        args.spec,
        args.spec_h,
        2 * args.spec_h
    );
    for (li, l) in lights.iter().enumerate() {
        println!(
            "light {} (strength {}){}",
            l.name,
            l.strength,
            if l.name == train_name { " [training light, rgba.png]" } else { "" }
        );
        for (m, st) in stats.iter().enumerate() {
            println!("  {:<28} {}", MODES[m], st[li].line());
        }
        if args.vis {
            println!("  {:<28} {}", "ref V=mesh, albedo sRGB-dec", stats_srgb_albedo[li].line());
        }
    }
    println!("total {:.1}s", t0.elapsed().as_secs_f32());
    Ok(())
}

/// Env-lookup transforms and strength on/off with the reference estimator, V = 1 (or V = mesh
/// plus GT indirect with `--variants-vis`).
fn run_variants(
    ds: &svgir_core::Dataset,
    views: &[(usize, &View)],
    bvh: &Bvh,
    mesh: &Mesh,
    args: &Args,
    train_name: &str,
) -> Result<()> {
    let rz = |deg: f32| Mat3::from_rotation_z(deg.to_radians());
    let variants: Vec<(&str, Mat3, bool)> = vec![
        ("identity", Mat3::IDENTITY, true),
        ("rot z +90", rz(90.0), true),
        ("rot z 180", rz(180.0), true),
        ("rot z -90", rz(-90.0), true),
        ("mirror y (theta -> -theta)", Mat3::from_diagonal(Vec3::new(1.0, -1.0, 1.0)), true),
        ("mirror x", Mat3::from_diagonal(Vec3::new(-1.0, 1.0, 1.0)), true),
        ("flip z (upside down)", Mat3::from_diagonal(Vec3::new(1.0, 1.0, -1.0)), true),
        ("y-up (lookup (x,z,-y))", Mat3::from_cols(Vec3::X, -Vec3::Z, Vec3::Y), true),
        ("identity, strength off", Mat3::IDENTITY, false),
    ];
    let pxs: Vec<Vec<Px>> =
        views.iter().map(|&(vi, v)| pixels(v, vi, bvh, mesh, false).map(|r| r.0)).collect::<Result<_>>()?;
    for (name, t, strength_on) in variants {
        let vis = args.variants_vis;
        let (lights, quad) = load_lights(ds, args, t, strength_on, mesh, bvh, vis)?;
        let params = Params { spec_samples: args.spec, vis, t, k_modes: false };
        let mode = if vis { 2 } else { 0 };
        let mut stats = vec![Stats::default(); lights.len()];
        for (&(_, view), px) in views.iter().zip(&pxs) {
            let outs: Vec<PxOut> =
                px.par_iter().map(|p| shade_px(p, &lights, &quad, &params, Some(bvh), mesh)).collect();
            let np = view.image.pixel_count();
            let mut covered = vec![false; np];
            for p in px {
                covered[p.index] = true;
            }
            for (li, light) in lights.iter().enumerate() {
                let Some(gt) = gt_image(view, &light.name, train_name) else { continue };
                let mut lin = vec![0.0f32; 3 * np];
                for (p, o) in px.iter().zip(&outs) {
                    lin[3 * p.index..3 * p.index + 3].copy_from_slice(&mode_color(mode, p, o, li));
                }
                stats[li].add(&lin, gt, &covered);
            }
        }
        println!("variant {name} ({}):", MODES[mode]);
        for (li, l) in lights.iter().enumerate() {
            println!("  {:<12} {}", l.name, stats[li].line());
        }
    }
    Ok(())
}
