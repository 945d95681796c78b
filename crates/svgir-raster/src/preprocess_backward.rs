//! Backward of [`crate::preprocess`]: from the per-Gaussian gradients of the splat record (H,
//! projected centre, opacity, flipped normal, SH colour) to the raw parameters (position, raw
//! quaternion, log-scales, opacity logit, SH coefficients).
//!
//! Work split: called once per Gaussian from the parallel reduction in [`crate::backward()`];
//! everything is recomputed from the raw parameters (nothing beyond the splat record is saved).

use crate::preprocess::{col, quat_to_rot, Cam, Splat};
use crate::vec3::{dot3, matvec, matvec_t, sub3};
use crate::GaussianParams;
use std::mem::MaybeUninit;
use svgir_core::Float;

/// Summed gradients of one Gaussian's splat record.
#[derive(Clone, Copy, Debug, Default)]
pub struct SplatGradSum<F> {
    /// W.r.t. H (rows `T_u, T_v, T_w`, row-major).
    pub h: [F; 9],
    /// W.r.t. the projected centre, pixels (through the low-pass filter).
    pub center: [F; 2],
    /// W.r.t. the opacity `o` (after the sigmoid).
    pub opacity: F,
    /// W.r.t. the flipped (camera-facing) world normal.
    pub normal: [F; 3],
    /// W.r.t. the clamped SH colour (SH mode only).
    pub color: [F; 3],
}

/// Gradients w.r.t. one Gaussian's raw parameters.
#[derive(Clone, Copy, Debug)]
pub struct ParamGrad<F> {
    /// W.r.t. the world-space centre.
    pub position: [F; 3],
    /// W.r.t. the raw unnormalised quaternion (`x, y, z, w`).
    pub rotation: [F; 4],
    /// W.r.t. the log-scales `(log s_u, log s_v)`.
    pub log_scale: [F; 2],
    /// W.r.t. the opacity logit.
    pub opacity_logit: F,
    /// W.r.t. the SH coefficients, `[k][channel]` (zero unless colours come from SH).
    pub sh: [[F; 3]; 16],
    /// Densification statistic, see [`crate::GradsOf::v_mean2d_norm`].
    pub mean2d_norm: F,
}

impl<F: Float> Default for ParamGrad<F> {
    fn default() -> Self {
        Self {
            position: [F::ZERO; 3],
            rotation: [F::ZERO; 4],
            log_scale: [F::ZERO; 2],
            opacity_logit: F::ZERO,
            sh: [[F::ZERO; 3]; 16],
            mean2d_norm: F::ZERO,
        }
    }
}

/// d(loss)/d(raw quaternion) from d(loss)/dR (row-major), for R = R(q / |q|).
pub fn quat_backward<F: Float>(q: [F; 4], v_r: &[[F; 3]; 3]) -> [F; 4] {
    let Some(([x, y, z, w], len, _)) = quat_to_rot(q) else { return [F::ZERO; 4] };
    let g = v_r;
    let two = F::c(2.0);
    let vw = two * (-z * g[0][1] + y * g[0][2] + z * g[1][0] - x * g[1][2] - y * g[2][0] + x * g[2][1]);
    let vx = two
        * (y * g[0][1] + z * g[0][2] + y * g[1][0] - two * x * g[1][1] - w * g[1][2] + z * g[2][0] + w * g[2][1]
            - two * x * g[2][2]);
    let vy = two
        * (-two * y * g[0][0] + x * g[0][1] + w * g[0][2] + x * g[1][0] + z * g[1][2] - w * g[2][0] + z * g[2][1]
            - two * y * g[2][2]);
    let vz = two
        * (-two * z * g[0][0] - w * g[0][1] + x * g[0][2] + w * g[1][0] - two * z * g[1][1]
            + y * g[1][2]
            + x * g[2][0]
            + y * g[2][1]);
    // Through the normalisation q^ = q / |q|.
    let gq = [vx, vy, vz, vw];
    let qh = [x, y, z, w];
    let d = gq[0] * qh[0] + gq[1] * qh[1] + gq[2] * qh[2] + gq[3] * qh[3];
    [0, 1, 2, 3].map(|i| (gq[i] - qh[i] * d) / len)
}

/// `dL/d(logit)` of an opacity `o = sigmoid(logit)` from `dL/do` (the lane kernel of
/// `preprocess_backward_simd` forms the same product in the same order).
#[inline]
pub(crate) fn opacity_logit_grad<F: Float>(v_o: F, o: F) -> F {
    v_o * o * (F::ONE - o)
}

/// Parameter gradients of Gaussian `i` given its summed splat-record gradients.
pub fn gaussian_backward<F: Float, P: GaussianParams<F> + ?Sized>(
    params: &P,
    cam: &Cam<F>,
    splat: &Splat<F>,
    g: &SplatGradSum<F>,
    sh_mode: bool,
    i: usize,
) -> ParamGrad<F> {
    let mut out = ParamGrad::default();
    if !splat.visible() {
        return out;
    }
    let q = params.rotation(i);
    let Some((_, _, rot)) = quat_to_rot(q) else { return out };
    let [su, sv] = splat.scale;
    let h = &splat.h;

    // Projected centre c = (H02 / H22, H12 / H22).
    let mut vh = g.h;
    let inv = F::ONE / h[8];
    vh[2] += g.center[0] * inv;
    vh[5] += g.center[1] * inv;
    vh[8] -= (g.center[0] * h[2] + g.center[1] * h[5]) * inv * inv;

    // H = K M with M = [a_u a_v a_0]: v_M = K^T v_H.
    let vm = [
        [cam.fx * vh[0], cam.fx * vh[1], cam.fx * vh[2]],
        [cam.fy * vh[3], cam.fy * vh[4], cam.fy * vh[5]],
        [
            cam.cx * vh[0] + cam.cy * vh[3] + vh[6],
            cam.cx * vh[1] + cam.cy * vh[4] + vh[7],
            cam.cx * vh[2] + cam.cy * vh[5] + vh[8],
        ],
    ];
    let v_au = matvec_t(&cam.r, col(&vm, 0));
    let v_av = matvec_t(&cam.r, col(&vm, 1));
    let v_a0 = matvec_t(&cam.r, col(&vm, 2));
    let mut v_p = v_a0;

    let tu = col(&rot, 0);
    let tv = col(&rot, 1);
    out.log_scale = [su * dot3(tu, v_au), sv * dot3(tv, v_av)];
    let mut v_r = [[F::ZERO; 3]; 3];
    for r in 0..3 {
        v_r[r][0] = su * v_au[r];
        v_r[r][1] = sv * v_av[r];
        v_r[r][2] = splat.flip * g.normal[r];
    }
    out.rotation = quat_backward(q, &v_r);
    out.opacity_logit = opacity_logit_grad(g.opacity, splat.opacity);

    if sh_mode {
        let (rows, v_dir) = sh_color_backward(params, cam, splat, &g.color, i);
        out.sh = rows;
        for j in 0..3 {
            v_p[j] += v_dir[j];
        }
    }
    out.position = v_p;

    // Densification statistic (see `GradsOf::v_mean2d_norm`).
    let gcam = matvec(&cam.r, v_p);
    let z = splat.depth;
    let nx = gcam[0] * z / cam.fx;
    let ny = gcam[1] * z / cam.fy;
    out.mean2d_norm = (nx * nx + ny * ny).sqrt();
    out
}

/// Backward of Gaussian `i`'s SH colour `max(0, 0.5 + SH(d))`, `d` the unit direction from the
/// camera centre: the coefficient rows (`[k][channel]`, as [`sh_color_rows`]) and the gradient reaching the
/// centre through `d`, from `v_color` (a clamped channel passes none). Visible Gaussians only.
pub fn sh_color_backward<F: Float, P: GaussianParams<F> + ?Sized>(
    params: &P,
    cam: &Cam<F>,
    splat: &Splat<F>,
    v_color: &[F; 3],
    i: usize,
) -> ([[F; 3]; 16], [F; 3]) {
    let (d, len) = view_direction(params, cam, i);
    let gc = unclamped(splat, v_color);
    let deg = params.sh_degree().min(3);
    let rows = sh_rows(deg, d, &gc);
    let mut bg = [[F::ZERO; 3]; 16];
    F::sh_basis_grad(deg, d, &mut bg);
    let mut v_d = [F::ZERO; 3];
    for (k, bgk) in bg.iter().enumerate().take(svgir_core::sh::num_coeffs(deg)) {
        let mut s = F::ZERO;
        for ch in 0..3 {
            s += params.sh(i, k, ch) * gc[ch];
        }
        for j in 0..3 {
            v_d[j] += bgk[j] * s;
        }
    }
    let dd = dot3(d, v_d);
    (rows, [0, 1, 2].map(|j| (v_d[j] - d[j] * dd) / len))
}

/// The coefficient rows alone of [`sh_color_backward`] (its bits), for a caller that keeps the
/// centres fixed.
pub fn sh_color_rows<F: Float, P: GaussianParams<F> + ?Sized>(
    params: &P,
    cam: &Cam<F>,
    splat: &Splat<F>,
    v_color: &[F; 3],
    i: usize,
) -> [[F; 3]; 16] {
    let (d, _) = view_direction(params, cam, i);
    sh_rows(params.sh_degree().min(3), d, &unclamped(splat, v_color))
}

/// Unit direction from the camera centre to Gaussian `i`, and the distance.
fn view_direction<F: Float, P: GaussianParams<F> + ?Sized>(params: &P, cam: &Cam<F>, i: usize) -> ([F; 3], F) {
    let dir = sub3(params.position(i), cam.center);
    let len = dot3(dir, dir).sqrt();
    (dir.map(|v| v / len), len)
}

/// `v_color` with the channels the forward clamped to zero.
fn unclamped<F: Float>(splat: &Splat<F>, v_color: &[F; 3]) -> [F; 3] {
    let mut gc = *v_color;
    for (ch, g) in gc.iter_mut().enumerate() {
        if splat.clamped & (1 << ch) != 0 {
            *g = F::ZERO;
        }
    }
    gc
}

/// `rows[k][ch] = Y_k(d) gc[ch]`: the colour is linear in the coefficients.
fn sh_rows<F: Float>(deg: u32, d: [F; 3], gc: &[F; 3]) -> [[F; 3]; 16] {
    let mut b = [F::ZERO; 16];
    F::sh_basis(deg, d, &mut b);
    let mut rows = [[F::ZERO; 3]; 16];
    for (row, bk) in rows.iter_mut().zip(b).take(svgir_core::sh::num_coeffs(deg)) {
        for ch in 0..3 {
            row[ch] = bk * gc[ch];
        }
    }
    rows
}

/// The gradient outputs of a run of Gaussians, each slot written exactly once: the backward
/// allocates its output vectors without zeroing them (a zeroing pass over the 19 MB of SH rows
/// of 100k Gaussians is serial, inside `calloc`, and cost a third of the per-Gaussian phase).
pub(crate) struct GradSlots<'a, F: Float> {
    pub position: &'a mut [MaybeUninit<F::V3>],
    pub rotation: &'a mut [MaybeUninit<F::Q>],
    pub log_scale: &'a mut [MaybeUninit<F::V2>],
    pub opacity_logit: &'a mut [MaybeUninit<F>],
    pub sh: &'a mut [MaybeUninit<F::Sh>],
    pub mean2d_norm: &'a mut [MaybeUninit<F>],
}

impl<F: Float> GradSlots<'_, F> {
    /// Number of slots.
    pub(crate) fn len(&self) -> usize {
        self.position.len()
    }

    /// Writes slot `l` from `pg` (the SH rows as zeros unless `sh`).
    pub(crate) fn put(&mut self, l: usize, pg: &ParamGrad<F>, sh: bool) {
        self.position[l].write(F::v3(pg.position));
        self.rotation[l].write(F::quat(pg.rotation));
        self.log_scale[l].write(F::v2(pg.log_scale));
        self.opacity_logit[l].write(pg.opacity_logit);
        self.sh[l].write(if sh { F::sh(&pg.sh) } else { bytemuck::Zeroable::zeroed() });
        self.mean2d_norm[l].write(pg.mean2d_norm);
    }
}
