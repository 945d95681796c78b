//! Per-Gaussian preprocess (SPEC 1): culling, the ray-splat matrix H, projected centre, camera-
//! facing normal, the screen box from the 3-sigma extent, and the SH colour.
//!
//! Work split: one rayon task per chunk of Gaussians, no shared writes. Saved for backward (in
//! [`crate::ForwardStateOf`]): the [`Splat`] records and SH colours with their clamp bits; the raw
//! parameters are re-read from the input.
//!
//! Culling: a Gaussian is skipped when its centre is closer than `near` (2DGS's frustum test),
//! when its quaternion or H is degenerate, or when its plane contains the camera centre (edge-on).
//!
//! Screen box: the pixels whose centres can pass the per-pixel cuts (see [`crate::splat`]) have
//! `rho <= R`, with `R = min(9, 2 ln(255 o))` the opacity-aware limit ([`crate::splat::rho_limit`]:
//! beyond it alpha is under 1/255 anyway, so a faint Gaussian gets a smaller box and fewer tiles
//! without changing a single pixel). They lie inside the projected ellipse `u^2 + v^2 <= R` (when
//! the filter is inactive) or within `sqrt(R/2)` px of the projected centre (when it is). The
//! ellipse's box comes from its dual conic (2DGS's `compute_aabb`), computed in f64 so it is exact
//! for the H the kernels evaluate. The union, plus a 0.01 px margin, is the Gaussian's box; if
//! the ellipse crosses the camera plane its projection is unbounded and the box is the whole
//! image. `max_radius` keeps 2DGS's 3-sigma `ceil(max(extent, 3*0.707))` (densification reads it).

// Negated comparisons are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::preprocess_simd::BLOCK;
use crate::vec3::{dot3, matvec, sub3};
use crate::{ColorSourceOf, GaussianParams, RasterConfig};
use rayon::prelude::*;
use std::mem::MaybeUninit;
use svgir_core::Camera;
use svgir_core::Float;

/// Support cut-off in sigma units (SPEC 1).
pub const CUTOFF: f64 = 3.0;
/// 2DGS's low-pass filter radius factor: the filter disk has radius `CUTOFF * FILTER_SIZE` px.
pub const FILTER_SIZE: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// A camera in the kernels' scalar type.
#[derive(Clone, Copy, Debug)]
pub struct Cam<F> {
    /// World-to-camera rotation, row-major.
    pub r: [[F; 3]; 3],
    /// World-to-camera translation (`x_cam = R x_world + t`).
    pub t: [F; 3],
    /// Focal length along x, pixels.
    pub fx: F,
    /// Focal length along y, pixels.
    pub fy: F,
    /// Principal point x, pixels (pixel-centre convention: pixel i has centre i + 0.5).
    pub cx: F,
    /// Principal point y, pixels.
    pub cy: F,
    /// Camera centre in world space.
    pub center: [F; 3],
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl<F: Float> Cam<F> {
    /// Converts a [`Camera`] to the kernels' scalar type (and precomputes its centre `-R^T t`).
    pub fn new(cam: &Camera) -> Self {
        let rows = [0, 1, 2].map(|i| cam.rotation.row(i).to_array().map(F::from_f32));
        let t = cam.translation.to_array().map(F::from_f32);
        let k = &cam.intrinsics;
        // centre = -R^T t, in F so that f64 runs see a consistent camera.
        let mut center = [F::ZERO; 3];
        for i in 0..3 {
            for j in 0..3 {
                center[j] -= rows[i][j] * t[i];
            }
        }
        Self {
            r: rows,
            t,
            fx: F::from_f32(k.fx),
            fy: F::from_f32(k.fy),
            cx: F::from_f32(k.cx),
            cy: F::from_f32(k.cy),
            center,
            width: k.width,
            height: k.height,
        }
    }
}

/// What the tile kernels read per Gaussian (one record, read together, so stored as a struct).
#[derive(Clone, Copy, Debug, Default)]
pub struct Splat<F> {
    /// Rows `T_u, T_v, T_w` of H, row-major.
    pub h: [F; 9],
    /// Projected centre in pixels (for the low-pass filter).
    pub center: [F; 2],
    /// Opacity `o = sigmoid(opacity logit)`.
    pub opacity: F,
    /// The tangent-axis scales `(s_u, s_v)`, `exp` of the log-scales (kept for the backward,
    /// where recomputing them was a third of its per-Gaussian cost in lanes).
    pub scale: [F; 2],
    /// Camera depth of the centre: the sort key.
    pub depth: F,
    /// World normal flipped to face the camera.
    pub normal: [F; 3],
    /// +1 or -1: the flip applied to the normal.
    pub flip: F,
    /// Pixel box `[x0, x1, y0, y1]`, ends exclusive; empty (x0 == x1) when culled.
    pub rect: [u32; 4],
    /// Per-row chords of the pixels that can pass the cut ([`crate::splat::RowConic`]).
    pub conic: crate::splat::RowConic,
    /// Screen radius in pixels (2DGS's 3-sigma rule), reported as `max_radius`.
    pub radius: f32,
    /// Bit c set when SH colour channel c was clamped at 0.
    pub clamped: u8,
}

impl<F> Splat<F> {
    /// Whether the pixel box is non-empty (the Gaussian survived culling).
    #[inline]
    pub fn visible(&self) -> bool {
        self.rect[0] < self.rect[1] && self.rect[2] < self.rect[3]
    }
}

/// Unit quaternion and its rotation matrix (row-major; columns are t_u, t_v, n).
#[inline]
pub fn quat_to_rot<F: Float>(q: [F; 4]) -> Option<([F; 4], F, [[F; 3]; 3])> {
    let len = dot3([q[0], q[1], q[2]], [q[0], q[1], q[2]]) + q[3] * q[3];
    let len = len.sqrt();
    if !(len > F::ZERO) {
        return None;
    }
    let [x, y, z, w] = q.map(|v| v / len);
    let one = F::ONE;
    let two = F::c(2.0);
    let r = [
        [one - two * (y * y + z * z), two * (x * y - w * z), two * (x * z + w * y)],
        [two * (x * y + w * z), one - two * (x * x + z * z), two * (y * z - w * x)],
        [two * (x * z - w * y), two * (y * z + w * x), one - two * (x * x + y * y)],
    ];
    Some(([x, y, z, w], len, r))
}

/// Column `c` of a row-major matrix.
#[inline]
pub fn col<F: Float>(m: &[[F; 3]; 3], c: usize) -> [F; 3] {
    [m[0][c], m[1][c], m[2][c]]
}

/// Preprocesses every Gaussian; returns the splats and (for SH colours) per-Gaussian RGB.
pub fn preprocess<F: Float, P: GaussianParams<F> + ?Sized>(
    params: &P,
    cam: &Cam<F>,
    colors: &ColorSourceOf<F>,
    cfg: &RasterConfig,
) -> (Vec<Splat<F>>, Vec<[F; 3]>) {
    let n = params.count();
    let want_sh = matches!(colors, ColorSourceOf::Sh);
    let path = if crate::simd::is_f32::<F>() { cfg.simd.resolve() } else { crate::Simd::Scalar };
    if path != crate::Simd::Scalar {
        // Eight Gaussians per block, in lanes, colours included.
        let mut splats = uninit_vec::<Splat<F>>(n);
        let mut colors = uninit_vec::<[F; 3]>(if want_sh { n } else { 0 });
        // SAFETY: `path` is only a SIMD one when `F` is `f32` (above): the same type.
        let cam32 = unsafe { &*(cam as *const Cam<F> as *const Cam<f32>) };
        let run = |x: &mut Box<crate::preprocess_simd::Inputs>,
                   b: usize,
                   out: &mut [MaybeUninit<Splat<F>>],
                   rgb: Option<&mut [MaybeUninit<[F; 3]>]>| {
            // SAFETY: `path` is only a SIMD one when `F` is `f32` (above), so these are the
            // same types.
            let done = unsafe {
                crate::preprocess_simd::project_block(
                    path,
                    params,
                    cam32,
                    cfg,
                    b * BLOCK,
                    x,
                    &mut *(out as *mut [MaybeUninit<Splat<F>>] as *mut [MaybeUninit<Splat<f32>>]),
                    rgb.map(|c| &mut *(c as *mut [MaybeUninit<[F; 3]>] as *mut [MaybeUninit<[f32; 3]>])),
                )
            };
            assert!(done, "a SIMD path without a lane preprocess");
        };
        if want_sh {
            splats
                .par_chunks_mut(BLOCK)
                .zip(colors.par_chunks_mut(BLOCK))
                .enumerate()
                .with_min_len(128)
                .for_each_init(crate::preprocess_simd::Inputs::new, |x, (b, (out, rgb))| run(x, b, out, Some(rgb)));
        } else {
            splats
                .par_chunks_mut(BLOCK)
                .enumerate()
                .with_min_len(128)
                .for_each_init(crate::preprocess_simd::Inputs::new, |x, (b, out)| run(x, b, out, None));
        }
        // SAFETY: every block wrote each of its slots.
        return unsafe { (assume_init(splats), assume_init(colors)) };
    }
    let mut splats: Vec<Splat<F>> = (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| project_one(params, cam, cfg, i).unwrap_or_default())
        .collect();
    let sh_colors = if want_sh {
        splats
            .par_iter_mut()
            .enumerate()
            .with_min_len(1024)
            .map(|(i, s)| {
                if !s.visible() {
                    return [F::ZERO; 3];
                }
                let (rgb, clamped) = sh_color(params, cam, i);
                s.clamped = clamped;
                rgb
            })
            .collect()
    } else {
        Vec::new()
    };
    (splats, sh_colors)
}

/// The splat record of Gaussian `i`, or `None` when culled.
pub fn project_one<F: Float, P: GaussianParams<F> + ?Sized>(
    params: &P,
    cam: &Cam<F>,
    cfg: &RasterConfig,
    i: usize,
) -> Option<Splat<F>> {
    let p = params.position(i);
    let (_, _, rot) = quat_to_rot(params.rotation(i))?;
    let ls = params.log_scale(i);
    let (su, sv) = (ls[0].exp(), ls[1].exp());
    let a0 = {
        let v = matvec(&cam.r, p);
        [v[0] + cam.t[0], v[1] + cam.t[1], v[2] + cam.t[2]]
    };
    // 2DGS frustum test on the centre (also rejects NaN).
    if !(a0[2] >= F::from_f32(cfg.near)) {
        return None;
    }
    let tu = col(&rot, 0);
    let tv = col(&rot, 1);
    let nrm = col(&rot, 2);
    let au = matvec(&cam.r, tu.map(|v| v * su));
    let av = matvec(&cam.r, tv.map(|v| v * sv));
    let h = [
        cam.fx * au[0] + cam.cx * au[2],
        cam.fx * av[0] + cam.cx * av[2],
        cam.fx * a0[0] + cam.cx * a0[2],
        cam.fy * au[1] + cam.cy * au[2],
        cam.fy * av[1] + cam.cy * av[2],
        cam.fy * a0[1] + cam.cy * a0[2],
        au[2],
        av[2],
        a0[2],
    ];
    let center = [h[2] / h[8], h[5] / h[8]];
    // Double-sided: flip n to face the camera; an edge-on plane is invisible.
    let cosv = dot3(sub3(cam.center, p), nrm);
    if !(cosv.abs() > F::ZERO) {
        return None;
    }
    let flip = if cosv > F::ZERO { F::ONE } else { -F::ONE };
    let o = F::ONE / (F::ONE + (-params.opacity_logit(i)).exp());
    let rho_max = crate::splat::rho_limit(o.to_f64());
    let (rect, radius) = screen_box(&h, center, rho_max, cam.width, cam.height)?;
    let conic = crate::splat::RowConic::new(&h.map(|v| v.to_f64()), center.map(|v| v.to_f64()), rho_max);
    Some(Splat {
        h,
        center,
        opacity: o,
        scale: [su, sv],
        depth: a0[2],
        normal: nrm.map(|v| v * flip),
        flip,
        rect,
        conic,
        radius,
        clamped: 0,
    })
}

/// Pixel box and radius (see the module docs).
fn screen_box<F: Float>(h: &[F; 9], center: [F; 2], rho_max: f64, w: u32, hh: u32) -> Option<([u32; 4], f32)> {
    let t: [f64; 9] = h.map(|v| v.to_f64());
    let c = [center[0].to_f64(), center[1].to_f64()];
    if !t.iter().chain(c.iter()).all(|v| v.is_finite()) {
        return None;
    }
    if !(rho_max > 0.0) {
        return None;
    }
    // Filter disk: 2 d^2 <= R.
    let rf = (0.5 * rho_max).sqrt() + 1e-4;
    let (xmin, xmax, ymin, ymax) = match conic_extent(&t, rho_max) {
        Some([px, ex, py, ey]) => {
            let m = 0.01;
            (
                (px - ex).min(c[0] - rf) - m,
                (px + ex).max(c[0] + rf) + m,
                (py - ey).min(c[1] - rf) - m,
                (py + ey).max(c[1] + rf) + m,
            )
        }
        // The ellipse reaches behind the camera: unbounded projection.
        None => (f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY),
    };
    // 3-sigma extent for densification, whatever the opacity.
    let radius = match conic_extent(&t, CUTOFF * CUTOFF) {
        Some([_, ex, _, ey]) => ex.max(ey).max(CUTOFF * FILTER_SIZE).ceil() as f32,
        None => w.max(hh) as f32,
    };
    // Pixel i is inside when its centre i + 0.5 is in [min, max].
    let lo = |v: f64, n: u32| (v - 0.5).ceil().clamp(0.0, n as f64) as u32;
    let hi = |v: f64, n: u32| ((v - 0.5).floor() + 1.0).clamp(0.0, n as f64) as u32;
    let rect = [lo(xmin, w), hi(xmax, w), lo(ymin, hh), hi(ymax, hh)];
    if rect[0] >= rect[1] || rect[2] >= rect[3] {
        return None;
    }
    Some((rect, radius))
}

/// Centre and half extents `[px, ex, py, ey]` of the projected ellipse `u^2 + v^2 <= cut2` of
/// the splat matrix `t`, or `None` when it crosses the camera plane (unbounded). Dual conic as in
/// 2DGS's `compute_aabb`: the x extremes are the roots of `C*_22 x^2 - 2 C*_02 x + C*_00 = 0`.
fn conic_extent(t: &[f64; 9], cut2: f64) -> Option<[f64; 4]> {
    let (tu, tv, tw) = ([t[0], t[1], t[2]], [t[3], t[4], t[5]], [t[6], t[7], t[8]]);
    let q = |a: [f64; 3], b: [f64; 3]| cut2 * (a[0] * b[0] + a[1] * b[1]) - a[2] * b[2];
    let d = q(tw, tw);
    if !(d < 0.0) {
        return None;
    }
    let px = q(tu, tw) / d;
    let py = q(tv, tw) / d;
    let ex = (px * px - q(tu, tu) / d).max(1e-4).sqrt();
    let ey = (py * py - q(tv, tv) / d).max(1e-4).sqrt();
    Some([px, ex, py, ey])
}

/// SH colour `max(0, 0.5 + SH(normalize(p - cam)))` (3DGS) and the clamp bits.
pub fn sh_color<F: Float, P: GaussianParams<F> + ?Sized>(params: &P, cam: &Cam<F>, i: usize) -> ([F; 3], u8) {
    let deg = params.sh_degree().min(3);
    let dir = sub3(params.position(i), cam.center);
    let len = dot3(dir, dir).sqrt();
    let d = dir.map(|v| v / len);
    let mut b = [F::ZERO; 16];
    F::sh_basis(deg, d, &mut b);
    let mut c = [F::c(0.5); 3];
    for k in 0..svgir_core::sh::num_coeffs(deg) {
        for ch in 0..3 {
            c[ch] += b[k] * params.sh(i, k, ch);
        }
    }
    let mut clamped = 0u8;
    for ch in 0..3 {
        if c[ch] < F::ZERO {
            clamped |= 1 << ch;
            c[ch] = F::ZERO;
        }
    }
    (c, clamped)
}

/// A vector of `n` slots to be written once each (the per-Gaussian outputs of the preprocess
/// and its backward), then [`assume_init`]ed.
pub(crate) fn uninit_vec<T>(n: usize) -> Vec<MaybeUninit<T>> {
    let mut v = Vec::with_capacity(n);
    // SAFETY: `MaybeUninit` needs no initialisation, and the capacity is `n`.
    unsafe { v.set_len(n) };
    v
}

/// The vector of a [`uninit_vec`] whose every slot has been written.
///
/// # Safety
/// Every element of `v` is initialised.
pub(crate) unsafe fn assume_init<T>(v: Vec<MaybeUninit<T>>) -> Vec<T> {
    let mut v = std::mem::ManuallyDrop::new(v);
    // SAFETY: `MaybeUninit<T>` has `T`'s layout, and the caller vouches for the contents.
    unsafe { Vec::from_raw_parts(v.as_mut_ptr() as *mut T, v.len(), v.capacity()) }
}
