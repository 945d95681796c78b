//! One ray-splat evaluation (SPEC 1, 2DGS Eqns 8-10) and its backward: the hit (u, v), depth and
//! alpha of one Gaussian at one pixel centre. Shared by the tile kernels and the dense reference.
//!
//! Per-pixel rules, in our convention (pixel centre `(i + 0.5, j + 0.5)`):
//! - `k = x T_w - T_u`, `l = y T_w - T_v`, `p = k x l`; skip if `p.z == 0` (ray parallel to the plane);
//!   `(u, v) = (p.x / p.z, p.y / p.z)` in sigma units; depth `z = T_w . (u, v, 1)`; skip `z < near`.
//! - Low-pass filter `rho = min(u^2 + v^2, 2 |c_px - x|^2)` (2DGS's FilterInvSquare = 2).
//! - Cut-off: skip `rho > 9`. 2DGS itself only bounds a Gaussian by its 3-sigma screen box, so
//!   which pixels see its tail depends on tile alignment; we cut on the effective rho instead, so
//!   the result is independent of tiling (and the dense reference matches exactly).
//! - `alpha = min(0.99, o exp(-rho / 2))`, skip `alpha < 1/255`.
//!
//! Kernels evaluate a whole row segment at once ([`eval_row`]: `l` is constant along a row, so
//! `p = x (T_w x l) - (T_u x l)`); [`intersect`] is the same arithmetic for one pixel (the dense
//! reference), so both paths agree bit for bit.
//!
//! Backward is exact (including the depth and interpolation paths through (u, v) when the filter
//! branch is active, which 2DGS drops); the clamps at 0.99 and the branch of the min are treated as
//! piecewise (derivative of the active piece).

use crate::vec3::cross3;
use svgir_core::Float;

/// Result of a successful evaluation.
#[derive(Clone, Copy, Debug)]
pub struct Hit<F> {
    /// Tangent coordinate u of the ray-splat hit, sigma units.
    pub u: F,
    /// Tangent coordinate v of the ray-splat hit, sigma units.
    pub v: F,
    /// Camera depth of the hit, `z = u T_w.x + v T_w.y + T_w.z` (SPEC 1).
    pub z: F,
    /// `exp(-rho / 2)`.
    pub g: F,
    /// `alpha = min(0.99, o g)` (SPEC 1).
    pub alpha: F,
    /// `o * g > 0.99` (alpha clamped: no gradient to opacity or rho).
    pub clamped: bool,
    /// `rho3d <= rho2d`: the Gaussian (not the filter) decided rho.
    pub use3d: bool,
    /// `1 / p.z` (saved by the evaluation, so backward divides once less).
    pub inv_pz: F,
}

/// Largest rho kept (3 sigma).
#[inline(always)]
pub fn max_rho<F: Float>() -> F {
    F::c(9.0)
}

/// The largest rho at which a splat of opacity `o` can pass both cuts: `rho <= 9` and
/// `o exp(-rho / 2) >= 1/255`, i.e. `rho <= 2 ln(255 o)`. A bound for culling only (the kernels
/// still apply the exact tests), so it carries a margin for `exp_fast` and rounding; `<= 0` means
/// no pixel can pass.
pub fn rho_limit(o: f64) -> f64 {
    const MARGIN: f64 = 0.02;
    // From this opacity up `2 ln(255 o) + MARGIN >= 9` (the cap is at 0.34950): the cap without the
    // logarithm, which `perf` put at a quarter of the preprocess of the bench scene.
    const CAPPED: f64 = 0.3496;
    if o >= CAPPED {
        return 9.0;
    }
    (2.0 * (255.0 * o).ln() + MARGIN).min(9.0)
}

/// Where on each pixel row a splat can pass the cut `rho <= R` ([`rho_limit`]): the chord of
/// the projected ellipse `u^2 + v^2 <= R`, joined with the chord of the filter disk
/// `2 |c - x|^2 <= R`. A culling bound only -- the kernels still test every pixel exactly -- so
/// it skips the empty corners of a tilted splat's box for a few flops per row.
///
/// With `T_u, T_v, T_w` the rows of H, the hit plane cross product at pixel `(x, y)` is
/// `p = x (T_v x T_w) + y (T_w x T_u) + (T_u x T_v)`; around the centre, `x = cx + s`,
/// `y = cy + t`, `p = s alpha + t beta + gamma` and the ellipse is
/// `s^2 A + 2 s B(t) + C(t) <= 0` with `<a, b> = a0 b0 + a1 b1 - R a2 b2`, `A = <alpha, alpha>`,
/// `B = t <alpha, beta> + <alpha, gamma>`, `C = t^2 <beta, beta> + 2 t <beta, gamma> +
/// <gamma, gamma>`. The coefficients (divided by A) are computed once per splat in f64 and kept
/// in f32; the chord is widened by a pixel on each side against rounding.
#[derive(Clone, Copy, Debug, Default)]
pub struct RowConic {
    /// `[B0, B1, C0, C1, C2] / A`: `B/A = B0 + t B1`, `C/A = C0 + t (C1 + t C2)`.
    k: [f32; 5],
    /// `R / 2`: the filter disk's squared radius.
    disk_r2: f32,
    /// `A > 0`: the ellipse does not cross the camera plane, so its chords are bounded.
    bounded: bool,
}

impl RowConic {
    /// Chord coefficients of the splat with rows `h`, projected centre `c` (pixels) and cut `rho <= rho_max`.
    pub fn new(h: &[f64; 9], c: [f64; 2], rho_max: f64) -> Self {
        let (tu, tv, tw) = ([h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], h[8]]);
        let alpha = cross3(tv, tw);
        let beta = cross3(tw, tu);
        let g0 = cross3(tu, tv);
        let gamma: [f64; 3] = std::array::from_fn(|j| c[0] * alpha[j] + c[1] * beta[j] + g0[j]);
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] - rho_max * a[2] * b[2];
        let a = dot(alpha, alpha);
        let k = [
            dot(alpha, gamma) / a,
            dot(alpha, beta) / a,
            dot(gamma, gamma) / a,
            2.0 * dot(beta, gamma) / a,
            dot(beta, beta) / a,
        ];
        Self::from_coefficients(k, rho_max, a > 0.0)
    }

    /// The pixels `[lo, hi)` of `[x0, x1)` on the row with centre `y` that can pass the cut, for
    /// a splat with projected centre `c` (a superset; empty as `lo == hi`).
    #[inline(always)]
    pub fn span(&self, c: [f32; 2], y: f32, x0: usize, x1: usize) -> (usize, usize) {
        if !self.bounded {
            return (x0, x1);
        }
        let (lo, hi) = self.chord(c, y);
        chord_pixels(lo, hi, x0, x1)
    }

    /// The record [`RowConic::new`] makes of its coefficients (`[B0, B1, C0, C1, C2] / A` in
    /// f64), the cut and whether `A > 0`, for a lane version of it.
    #[inline(always)]
    pub(crate) fn from_coefficients(k: [f64; 5], rho_max: f64, a_positive: bool) -> Self {
        let bounded = a_positive && k.iter().all(|v| v.is_finite() && v.abs() < 1e30);
        Self { k: k.map(|v| v as f32), disk_r2: (0.5 * rho_max) as f32, bounded }
    }

    /// Whether the chords are bounded (else every pixel of the box may pass).
    #[inline(always)]
    pub fn bounded(&self) -> bool {
        self.bounded
    }

    /// The chord `[lo, hi]` (continuous x) of the row with centre `y`: the ellipse's joined with
    /// the filter disk's, `lo > hi` when the row misses both.
    #[inline(always)]
    pub fn chord(&self, c: [f32; 2], y: f32) -> (f32, f32) {
        let t = y - c[1];
        let k = &self.k;
        let bh = k[0] + t * k[1];
        let ch = k[2] + t * (k[3] + t * k[4]);
        let disc = bh * bh - ch;
        let e2 = self.disk_r2 - t * t;
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        if disc >= 0.0 {
            let sq = disc.sqrt();
            lo = c[0] - bh - sq;
            hi = c[0] - bh + sq;
        }
        if e2 >= 0.0 {
            let e = e2.sqrt();
            lo = lo.min(c[0] - e);
            hi = hi.max(c[0] + e);
        }
        (lo, hi)
    }

    /// The coefficients `[B0, B1, C0, C1, C2] / A` and the filter disk's squared radius, for
    /// lane versions of [`RowConic::chord`].
    #[inline(always)]
    pub(crate) fn coefficients(&self) -> ([f32; 5], f32) {
        (self.k, self.disk_r2)
    }
}

/// The pixels `[lo_px, hi_px)` of `[x0, x1)` whose centres lie within a pixel of the chord
/// `[lo, hi]` ([`RowConic::chord`]); empty as `lo_px == hi_px`.
#[inline(always)]
pub fn chord_pixels(lo: f32, hi: f32, x0: usize, x1: usize) -> (usize, usize) {
    if lo.partial_cmp(&hi).is_none_or(|o| o.is_gt()) {
        return (x0, x0);
    }
    // Pixel i (centre i + 0.5) with a one-pixel margin: i in [lo - 1.5, hi + 0.5].
    let (fx0, fx1) = (x0 as f32, x1 as f32);
    let lo_px = floor_clamped(lo - 1.5, fx0, fx1);
    let lo_px = if (lo_px as f32) < lo - 1.5 { lo_px + 1 } else { lo_px }.min(x1);
    let hi_px = (floor_clamped(hi + 0.5, fx0, fx1) + 1).min(x1);
    (lo_px, hi_px.max(lo_px))
}

/// `floor(v)` clamped to `[lo, hi]` (both non-negative and below 2^24) as an index, without a
/// libm call (baseline x86-64 has no SSE4.1 `round`) or the fix-ups of a saturating cast.
#[inline(always)]
fn floor_clamped(v: f32, lo: f32, hi: f32) -> usize {
    // Clamping first makes the value non-negative, where truncation is floor; a NaN `v` clamps
    // to `lo` (f32::max returns the non-NaN operand).
    let c = v.max(lo).min(hi);
    debug_assert!((0.0..16_777_216.0).contains(&c));
    // SAFETY: `c` is finite and in [0, 2^24) (see above), so it fits an i32.
    (unsafe { c.to_int_unchecked::<i32>() }) as usize
}

/// Per-splat constants of the hit plane. With `k = x T_w - T_u` and `l = y T_w - T_v` the
/// homogeneous hit is `p = k x l = x (T_v x T_w) - (y (T_u x T_w) - T_u x T_v)`: the `x y T_w x T_w`
/// term vanishes, so `p` is affine in the pixel centre. Forming these three cross products once
/// per splat costs less than two per row, and leaves no `y T_w` term to cancel in f32.
#[derive(Clone, Copy, Debug, Default)]
pub struct PlaneSetup<F> {
    /// `T_v x T_w`, the row setup's `a` on every row.
    pub a: [F; 3],
    /// `T_u x T_w`, the factor of `y` in the row setup's `b`.
    pub bw: [F; 3],
    /// `T_u x T_v`, the constant of the row setup's `b`.
    pub b0: [F; 3],
}

/// The [`PlaneSetup`] of the splat with rows `h`.
#[inline(always)]
pub fn plane_setup<F: Float>(h: &[F; 9]) -> PlaneSetup<F> {
    let (tu, tv, tw) = ([h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], h[8]]);
    PlaneSetup { a: cross3(tv, tw), bw: cross3(tu, tw), b0: cross3(tu, tv) }
}

/// Per (splat, pixel row) constants: the hit plane cross product is `p = x a - b` at pixel
/// centre x of the row.
#[derive(Clone, Copy, Debug, Default)]
pub struct RowSetup<F> {
    /// `T_w x l = T_v x T_w`.
    pub a: [F; 3],
    /// `T_u x l = y (T_u x T_w) - T_u x T_v`.
    pub b: [F; 3],
}

/// The [`RowSetup`] of the splat with plane `p` on the pixel row with centre `y`.
#[inline(always)]
pub fn row_setup<F: Float>(p: &PlaneSetup<F>, y: F) -> RowSetup<F> {
    RowSetup { a: p.a, b: std::array::from_fn(|j| y * p.bw[j] - p.b0[j]) }
}

/// Largest row segment [`eval_row`] handles (the largest tile side).
pub const MAX_ROW: usize = 64;

/// One row segment's evaluations; `alpha == 0` marks a skipped pixel.
#[derive(Clone, Copy, Debug)]
pub struct RowEval<F> {
    /// Alpha per pixel (0 = skipped).
    pub alpha: [F; MAX_ROW],
    /// Tangent coordinate u of the hit per pixel.
    pub u: [F; MAX_ROW],
    /// Tangent coordinate v of the hit per pixel.
    pub v: [F; MAX_ROW],
    /// Camera depth of the hit per pixel.
    pub z: [F; MAX_ROW],
    /// Gaussian falloff `exp(-rho / 2)` per pixel.
    pub g: [F; MAX_ROW],
    /// `1 / p.z` per pixel.
    pub inv_pz: [F; MAX_ROW],
}

impl<F: Float> Default for RowEval<F> {
    fn default() -> Self {
        let z = [F::ZERO; MAX_ROW];
        Self { alpha: z, u: z, v: z, z, g: z, inv_pz: z }
    }
}

/// Branch-free evaluation at pixel centre x of a row: `(alpha or 0 if skipped, u, v, z, g, 1/p.z)`.
/// Every skip test is a comparison that NaN (from `p.z == 0`) fails, so invalid pixels get 0.
#[inline(always)]
fn eval_px<F: Float>(h: &[F; 9], c: [F; 2], o: F, rs: &RowSetup<F>, x: F, y: F, near: F) -> (F, F, F, F, F, F) {
    let px = x * rs.a[0] - rs.b[0];
    let py = x * rs.a[1] - rs.b[1];
    let pz = x * rs.a[2] - rs.b[2];
    let inv = F::ONE / pz;
    let u = px * inv;
    let v = py * inv;
    let rho3 = u * u + v * v;
    let dx = c[0] - x;
    let dy = c[1] - y;
    let rho2 = F::c(2.0) * (dx * dx + dy * dy);
    let rho = if rho3 <= rho2 { rho3 } else { rho2 };
    let z = u * h[6] + v * h[7] + h[8];
    let g = (F::c(-0.5) * rho).exp_fast();
    let a = o * g;
    let alpha = if a > F::c(0.99) { F::c(0.99) } else { a };
    let valid = pz != F::ZERO && rho <= max_rho::<F>() && z >= near && alpha >= F::c(1.0 / 255.0);
    (if valid { alpha } else { F::ZERO }, u, v, z, g, inv)
}

/// `[0, 1, 2, ...]` in `F`, for [`eval_row`].
pub fn row_offsets<F: Float>() -> [F; MAX_ROW] {
    std::array::from_fn(|i| F::c(i as f64))
}

/// Evaluates pixels `x0 + 0.5 + offsets[i]`, `i < n`, of row centre `y` set up by [`row_setup`]
/// (a loop the compiler can vectorise: no branches); `offsets` is [`row_offsets`].
#[inline(always)]
pub fn eval_row<F: Float>(
    h: &[F; 9],
    c: [F; 2],
    o: F,
    rs: &RowSetup<F>,
    y: F,
    x0: usize,
    n: usize,
    near: F,
    offsets: &[F; MAX_ROW],
    out: &mut RowEval<F>,
) {
    let xs = F::c(x0 as f64 + 0.5);
    let n = n.min(MAX_ROW);
    for i in 0..n {
        let x = xs + offsets[i];
        let (alpha, u, v, z, g, inv_pz) = eval_px(h, c, o, rs, x, y, near);
        out.alpha[i] = alpha;
        out.u[i] = u;
        out.v[i] = v;
        out.z[i] = z;
        out.g[i] = g;
        out.inv_pz[i] = inv_pz;
    }
}

/// The full hit record of pixel `i` of a row evaluated by [`eval_row`] (for backward).
#[inline(always)]
pub fn hit_from_row<F: Float>(c: [F; 2], o: F, e: &RowEval<F>, i: usize, x: F, y: F) -> Hit<F> {
    hit_from_parts(c, o, [e.alpha[i], e.u[i], e.v[i], e.z[i], e.g[i], e.inv_pz[i]], x, y)
}

#[inline(always)]
fn hit_from_parts<F: Float>(c: [F; 2], o: F, parts: [F; 6], x: F, y: F) -> Hit<F> {
    let [alpha, u, v, z, g, inv_pz] = parts;
    let dx = c[0] - x;
    let dy = c[1] - y;
    let rho3 = u * u + v * v;
    let rho2 = F::c(2.0) * (dx * dx + dy * dy);
    Hit { u, v, z, g, alpha, clamped: o * g > F::c(0.99), use3d: rho3 <= rho2, inv_pz }
}

/// Evaluates the splat with matrix `h`, projected centre `c` and opacity `o` at pixel centre
/// `(x, y)`; `None` when the pixel is skipped. Same arithmetic as [`eval_row`].
#[inline(always)]
pub fn intersect<F: Float>(h: &[F; 9], c: [F; 2], o: F, x: F, y: F, near: F) -> Option<Hit<F>> {
    let rs = row_setup(&plane_setup(h), y);
    let (alpha, u, v, z, g, inv_pz) = eval_px(h, c, o, &rs, x, y, near);
    if alpha == F::ZERO {
        return None;
    }
    Some(hit_from_parts(c, o, [alpha, u, v, z, g, inv_pz], x, y))
}

/// Gradients w.r.t. one splat record, accumulated over the pixels it was evaluated at.
///
/// The matrix part is kept as three sums of `dL/dp` (p = k x l, the un-normalised hit): since
/// `k = x T_w - T_u` and `l = y T_w - T_v` are linear in the pixel centre, the per-pixel chain
/// `dL/dk = l x gp`, `dL/dl = gp x k` sums to cross products of `sum gp`, `sum x gp` and `sum y gp`
/// with the rows of H ([`SplatGrad::h_grad`]). Per pixel that is 9 multiply-adds instead of two
/// cross products and 9 scattered updates; the `x y` terms cancel exactly in the sum.
#[derive(Clone, Copy, Debug, Default)]
pub struct SplatGrad<F> {
    /// dL/dH[6..9] through the explicit depth term `z = u T_w.x + v T_w.y + T_w.z`.
    pub h_depth: [F; 3],
    /// dL/d(projected centre), pixels (through the low-pass filter).
    pub center: [F; 2],
    /// dL/d(opacity `o`).
    pub opacity: F,
    /// `sum gp`, `sum x gp`, `sum y gp` over the evaluated pixels.
    gp: [F; 3],
    gp_x: [F; 3],
    gp_y: [F; 3],
}

impl<F: Float> SplatGrad<F> {
    /// From sums accumulated elsewhere (the SIMD kernels): `sum gp`, `sum x gp`, `sum y gp`.
    pub(crate) fn from_sums(
        h_depth: [F; 3],
        center: [F; 2],
        opacity: F,
        gp: [F; 3],
        gp_x: [F; 3],
        gp_y: [F; 3],
    ) -> Self {
        Self { h_depth, center, opacity, gp, gp_x, gp_y }
    }

    /// dL/dH from the accumulated sums.
    pub fn h_grad(&self, h: &[F; 9]) -> [F; 9] {
        let (tu, tv, tw) = ([h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], h[8]]);
        // dL/dT_u = -sum l x gp = -(T_w x sum y gp - T_v x sum gp).
        let a = cross3(tw, self.gp_y);
        let b = cross3(tv, self.gp);
        // dL/dT_v = -sum gp x k = -(sum x gp x T_w - sum gp x T_u).
        let c = cross3(self.gp_x, tw);
        let d = cross3(self.gp, tu);
        // dL/dT_w = sum x (l x gp) + y (gp x k) = T_u x sum y gp - T_v x sum x gp, plus depth.
        let e = cross3(tu, self.gp_y);
        let f = cross3(tv, self.gp_x);
        let mut out = [F::ZERO; 9];
        for j in 0..3 {
            out[j] = b[j] - a[j];
            out[3 + j] = d[j] - c[j];
            out[6 + j] = e[j] - f[j] + self.h_depth[j];
        }
        out
    }
}

/// Adds to `out` the gradient given `dL/dalpha`, `dL/dz` and `dL/du`, `dL/dv` (the latter from
/// the interpolation weights only; the depth and rho paths are added here).
#[inline(always)]
pub fn intersect_backward<F: Float>(
    hit: &Hit<F>,
    h: &[F; 9],
    c: [F; 2],
    o: F,
    x: F,
    y: F,
    v_alpha: F,
    v_z: F,
    v_u: F,
    v_v: F,
    out: &mut SplatGrad<F>,
) {
    let (mut gu, mut gv) = (v_u + v_z * h[6], v_v + v_z * h[7]);
    out.h_depth[0] += v_z * hit.u;
    out.h_depth[1] += v_z * hit.v;
    out.h_depth[2] += v_z;
    if !hit.clamped {
        out.opacity += v_alpha * hit.g;
        let v_rho = F::c(-0.5) * v_alpha * o * hit.g;
        if hit.use3d {
            gu += F::c(2.0) * v_rho * hit.u;
            gv += F::c(2.0) * v_rho * hit.v;
        } else {
            out.center[0] += F::c(4.0) * v_rho * (c[0] - x);
            out.center[1] += F::c(4.0) * v_rho * (c[1] - y);
        }
    }
    // (u, v) = (p.x, p.y) / p.z.
    let inv = hit.inv_pz;
    let gp = [gu * inv, gv * inv, -(gu * hit.u + gv * hit.v) * inv];
    for j in 0..3 {
        out.gp[j] += gp[j];
        out.gp_x[j] += x * gp[j];
        out.gp_y[j] += y * gp[j];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cap of `rho_limit` without the logarithm is where the logarithm puts it.
    #[test]
    fn rho_limit_caps_where_the_logarithm_does() {
        let full = |o: f64| (2.0 * (255.0 * o).ln() + 0.02).min(9.0);
        for i in 0..=100_000 {
            let o = i as f64 / 100_000.0;
            assert_eq!(rho_limit(o), full(o), "o = {o}");
        }
        assert!(full(0.3494) < 9.0, "the cap starts above 0.3494: the shortcut is not the tightest");
    }
}
