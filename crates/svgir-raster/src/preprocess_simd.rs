//! [`crate::preprocess::project_one`] and [`crate::preprocess::sh_color`] for eight Gaussians at
//! a time, compiled for AVX2 and AVX-512 and chosen at run time ([`crate::simd`]).
//!
//! Work split: the caller's parallel loop hands over blocks of eight consecutive Gaussians; one
//! Gaussian per lane. The lanes are plain arrays ([`V`]) whose element-wise operators the
//! compiler turns into vector instructions inside the `#[target_feature]` functions below; the f32
//! and f64 steps are the scalar functions' operations in their order, without FMA, and where the
//! scalar code returns early (culling) the lanes compute on and a mask drops them. `exp` and the
//! logarithm of [`crate::splat::rho_limit`] are libm's, lane by lane, as in the scalar code. So
//! every splat record and SH colour is bit-identical to the scalar path, which stays the oracle
//! (the tests compare them) and the fallback for f64 and other architectures.

use crate::preprocess::{Cam, Splat, CUTOFF, FILTER_SIZE};
use crate::simd::Simd;
use crate::splat::{rho_limit, RowConic};
use crate::{GaussianParams, RasterConfig};
use std::mem::MaybeUninit;
use std::ops::{Add, Div, Mul, Sub};
use svgir_core::Float;

/// Gaussians per block.
pub(crate) const BLOCK: usize = 8;

/// One value per lane.
#[derive(Clone, Copy)]
struct V<T>([T; BLOCK]);

macro_rules! lane_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<T: Copy + $tr<Output = T>> $tr for V<T> {
            type Output = V<T>;
            #[inline(always)]
            fn $f(self, o: V<T>) -> V<T> {
                let mut r = self.0;
                for l in 0..BLOCK {
                    r[l] = self.0[l] $op o.0[l];
                }
                V(r)
            }
        }
    };
}
lane_op!(Add, add, +);
lane_op!(Sub, sub, -);
lane_op!(Mul, mul, *);
lane_op!(Div, div, /);

impl<T: Copy> V<T> {
    #[inline(always)]
    fn splat(v: T) -> Self {
        V([v; BLOCK])
    }
    #[inline(always)]
    fn map<U: Copy>(self, f: impl Fn(T) -> U) -> V<U> {
        V(each(&self.0, f))
    }
    #[inline(always)]
    fn zip<U: Copy, R: Copy>(self, o: V<U>, f: impl Fn(T, U) -> R) -> V<R> {
        let mut r = [f(self.0[0], o.0[0]); BLOCK];
        for l in 1..BLOCK {
            r[l] = f(self.0[l], o.0[l]);
        }
        V(r)
    }
}

/// `a.map(f)` as a plain loop: `array::map` and `array::from_fn` on these arrays of lanes were
/// not inlined (a closure call per element), which cost half the block's time.
#[inline(always)]
fn each<T: Copy, U: Copy, const K: usize>(a: &[T; K], f: impl Fn(T) -> U) -> [U; K] {
    let mut r = [f(a[0]); K];
    for i in 1..K {
        r[i] = f(a[i]);
    }
    r
}

/// Per-lane mask.
type M = V<bool>;

impl M {
    #[inline(always)]
    fn and(self, o: M) -> M {
        self.zip(o, |a, b| a & b)
    }
}

/// `a0 b0 + a1 b1 + a2 b2` ([`crate::vec3::dot3`]'s order).
#[inline(always)]
fn dot3<T: Copy + Add<Output = T> + Mul<Output = T>>(a: [V<T>; 3], b: [V<T>; 3]) -> V<T> {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `m v` for a row-major camera rotation ([`crate::vec3::matvec`]).
#[inline(always)]
fn matvec(m: &[[f32; 3]; 3], v: [V<f32>; 3]) -> [V<f32>; 3] {
    each(m, |row| dot3(each(&row, V::splat), v))
}

/// The splat records of Gaussians `g0..g0 + out.len()` (at most [`BLOCK`]) into `out` (culled
/// ones as `Splat::default()`), with their SH colours and clamp bits when `colors` is `Some`,
/// on the SIMD path `path` (already resolved); false when `path` is scalar (the caller runs the
/// scalar functions). Every slot is written.
pub(crate) fn project_block<F: Float, P: GaussianParams<F> + ?Sized>(
    path: Simd,
    params: &P,
    cam: &Cam<f32>,
    cfg: &RasterConfig,
    g0: usize,
    x: &mut Inputs,
    out: &mut [MaybeUninit<Splat<f32>>],
    colors: Option<&mut [MaybeUninit<[f32; 3]>]>,
) -> bool {
    debug_assert!(out.len() <= BLOCK);
    if path == Simd::Scalar {
        return false;
    }
    x.fill(params, g0, out.len(), colors.is_some());
    let job = Job { x, cam, cfg, out, colors };
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: `resolve` only returns a path whose features the CPU has.
        unsafe {
            match path {
                Simd::Avx2 => block_avx2(job),
                Simd::Avx512 => block_avx512(job),
                _ => return false,
            }
        }
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = job;
        false
    }
}

/// What one block reads and writes.
struct Job<'a> {
    x: &'a Inputs,
    cam: &'a Cam<f32>,
    cfg: &'a RasterConfig,
    out: &'a mut [MaybeUninit<Splat<f32>>],
    colors: Option<&'a mut [MaybeUninit<[f32; 3]>]>,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_avx2(job: Job) {
    block(job)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
unsafe fn block_avx512(job: Job) {
    block(job)
}

/// One block's parameters, one Gaussian per lane (lanes past the block's end keep an earlier
/// block's values; their results are never stored). One per task, reused block after block.
pub(crate) struct Inputs {
    p: [V<f32>; 3],
    q: [V<f32>; 4],
    /// `exp` of the two log-scales.
    s: [V<f32>; 2],
    /// `exp(-logit)`.
    e: V<f32>,
    /// The SH coefficients `[k][channel]` of the first `nk` bands (the active ones, when
    /// colours are wanted).
    sh: [[V<f32>; 3]; 16],
    nk: usize,
}

impl Inputs {
    /// Zeros, to be filled block after block ([`Inputs::fill`]).
    pub(crate) fn new() -> Box<Self> {
        let z = V::splat(0.0);
        Box::new(Self { p: [z; 3], q: [z; 4], s: [z; 2], e: z, sh: [[z; 3]; 16], nk: 0 })
    }

    /// The parameters of Gaussians `g0..g0 + m`, read in the scalar type `F` (which is `f32` on
    /// the SIMD paths, so `to_f32` is exact).
    fn fill<F: Float, P: GaussianParams<F> + ?Sized>(&mut self, params: &P, g0: usize, m: usize, sh: bool) {
        let nk = if sh { svgir_core::sh::num_coeffs(params.sh_degree().min(3)) } else { 0 };
        let x = self;
        x.nk = nk;
        for l in 0..m {
            let i = g0 + l;
            let (p, q, ls) = (params.position(i), params.rotation(i), params.log_scale(i));
            for c in 0..3 {
                x.p[c].0[l] = p[c].to_f32();
            }
            for c in 0..4 {
                x.q[c].0[l] = q[c].to_f32();
            }
            for c in 0..2 {
                x.s[c].0[l] = ls[c].to_f32().exp();
            }
            x.e.0[l] = (-params.opacity_logit(i).to_f32()).exp();
            for (k, row) in x.sh[..nk].iter_mut().enumerate() {
                for (ch, v) in row.iter_mut().enumerate() {
                    v.0[l] = params.sh(i, k, ch).to_f32();
                }
            }
        }
    }
}

/// The scalar functions' operations, lane by lane (see the module docs).
#[inline(always)]
fn block(job: Job) {
    let Job { x, cam, cfg, out, colors } = job;
    let sp = V::<f32>::splat;
    let (one, two) = (sp(1.0), sp(2.0));

    // `quat_to_rot`.
    let q = x.q;
    let len = (dot3([q[0], q[1], q[2]], [q[0], q[1], q[2]]) + q[3] * q[3]).map(f32::sqrt);
    let mut keep: M = len.map(|v| v > 0.0);
    let [qx, qy, qz, qw] = each(&q, |v| v / len);
    let rot = [
        [one - two * (qy * qy + qz * qz), two * (qx * qy - qw * qz), two * (qx * qz + qw * qy)],
        [two * (qx * qy + qw * qz), one - two * (qx * qx + qz * qz), two * (qy * qz - qw * qx)],
        [two * (qx * qz - qw * qy), two * (qy * qz + qw * qx), one - two * (qx * qx + qy * qy)],
    ];
    let (su, sv) = (x.s[0], x.s[1]);
    let p = x.p;
    let a0 = {
        let v = matvec(&cam.r, p);
        [v[0] + sp(cam.t[0]), v[1] + sp(cam.t[1]), v[2] + sp(cam.t[2])]
    };
    // 2DGS frustum test on the centre (also rejects NaN).
    keep = keep.and(a0[2].map(|z| z >= cfg.near));
    let col = |c: usize| [rot[0][c], rot[1][c], rot[2][c]];
    let (tu, tv, nrm) = (col(0), col(1), col(2));
    let au = matvec(&cam.r, each(&tu, |v| v * su));
    let av = matvec(&cam.r, each(&tv, |v| v * sv));
    let (fx, fy, cx, cy) = (sp(cam.fx), sp(cam.fy), sp(cam.cx), sp(cam.cy));
    let h = [
        fx * au[0] + cx * au[2],
        fx * av[0] + cx * av[2],
        fx * a0[0] + cx * a0[2],
        fy * au[1] + cy * au[2],
        fy * av[1] + cy * av[2],
        fy * a0[1] + cy * a0[2],
        au[2],
        av[2],
        a0[2],
    ];
    let center = [h[2] / h[8], h[5] / h[8]];
    // Double-sided: flip n to face the camera; an edge-on plane is invisible.
    let cosv = dot3([sp(cam.center[0]) - p[0], sp(cam.center[1]) - p[1], sp(cam.center[2]) - p[2]], nrm);
    keep = keep.and(cosv.map(|v| v.abs() > 0.0));
    let flip = cosv.map(|v| if v > 0.0 { 1.0 } else { -1.0 });
    let o = one / (one + x.e);
    let rho_max = o.map(|v| rho_limit(v as f64));
    let (rect, radius, boxed) = screen_box(&h, center, rho_max, cam.width, cam.height);
    keep = keep.and(boxed);

    // `sh_color`: `max(0, 0.5 + SH(normalize(p - cam)))` and its clamp bits.
    let mut c = [sp(0.5); 3];
    if colors.is_some() {
        let dir = [p[0] - sp(cam.center[0]), p[1] - sp(cam.center[1]), p[2] - sp(cam.center[2])];
        let dlen = dot3(dir, dir).map(f32::sqrt);
        let b = sh_basis(each(&dir, |v| v / dlen));
        for (k, row) in x.sh[..x.nk].iter().enumerate() {
            for ch in 0..3 {
                c[ch] = c[ch] + b[k] * row[ch];
            }
        }
    }
    let (k, a_pos) = row_conic(&h, center, rho_max);
    let mut colors = colors;
    for (l, s) in out.iter_mut().enumerate() {
        let mut rgb = [0.0f32; 3];
        if !keep.0[l] {
            s.write(Splat::default());
        } else {
            let mut clamped = 0u8;
            for ch in 0..3 {
                let v = c[ch].0[l];
                if v < 0.0 {
                    clamped |= 1 << ch;
                } else {
                    rgb[ch] = v;
                }
            }
            let hl = each(&h, |v| v.0[l]);
            let cl = [center[0].0[l], center[1].0[l]];
            s.write(Splat {
                h: hl,
                center: cl,
                opacity: o.0[l],
                scale: [su.0[l], sv.0[l]],
                depth: a0[2].0[l],
                normal: each(&nrm, |v| v.0[l] * flip.0[l]),
                flip: flip.0[l],
                rect: each(&rect, |v| v.0[l]),
                conic: RowConic::from_coefficients(each(&k, |v| v.0[l]), rho_max.0[l], a_pos.0[l]),
                radius: radius.0[l],
                clamped: if colors.is_some() { clamped } else { 0 },
            });
        }
        if let Some(cs) = colors.as_deref_mut() {
            cs[l].write(rgb);
        }
    }
}

/// [`crate::preprocess`]'s `screen_box` in f64 lanes: the pixel box, the 3-sigma radius, and
/// whether the splat survives (finite, a positive cut, a non-empty box).
#[inline(always)]
fn screen_box(h: &[V<f32>; 9], center: [V<f32>; 2], rho_max: V<f64>, w: u32, hh: u32) -> ([V<u32>; 4], V<f32>, M) {
    let t: [V<f64>; 9] = each(h, |v| v.map(f64::from));
    let c = each(&center, |v| v.map(f64::from));
    let mut finite = V::splat(true);
    for v in t.iter().chain(&c) {
        finite = finite.and(v.map(f64::is_finite));
    }
    let keep = finite.and(rho_max.map(|r| r > 0.0));
    // Filter disk: 2 d^2 <= R.
    let rf = (V::splat(0.5) * rho_max).map(f64::sqrt) + V::splat(1e-4);
    let (bounded, [px, ex, py, ey]) = conic_extent(&t, rho_max);
    let m = V::splat(0.01);
    let sel = |b: M, a: V<f64>, inf: f64| b.zip(a, move |b, a| if b { a } else { inf });
    // Compare-and-select, not f64::min / max: they differ only on NaN, and a lane with a NaN
    // here is one that `keep` drops (H and the centre finite and the ellipse bounded leave none).
    let min = |a: V<f64>, b: V<f64>| a.zip(b, |a, b| if b < a { b } else { a });
    let max = |a: V<f64>, b: V<f64>| a.zip(b, |a, b| if b > a { b } else { a });
    let xmin = sel(bounded, min(px - ex, c[0] - rf) - m, f64::NEG_INFINITY);
    let xmax = sel(bounded, max(px + ex, c[0] + rf) + m, f64::INFINITY);
    let ymin = sel(bounded, min(py - ey, c[1] - rf) - m, f64::NEG_INFINITY);
    let ymax = sel(bounded, max(py + ey, c[1] + rf) + m, f64::INFINITY);
    // 3-sigma extent for densification, whatever the opacity.
    let (b3, [_, ex3, _, ey3]) = conic_extent(&t, V::splat(CUTOFF * CUTOFF));
    let r3 = max(max(ex3, ey3), V::splat(CUTOFF * FILTER_SIZE)).map(|v| v.ceil() as f32);
    let radius = b3.zip(r3, move |b, r| if b { r } else { w.max(hh) as f32 });
    // Pixel i is inside when its centre i + 0.5 is in [min, max].
    let lo = move |v: V<f64>, n: u32| v.map(move |v| (v - 0.5).ceil().clamp(0.0, n as f64) as u32);
    let hi = move |v: V<f64>, n: u32| v.map(move |v| ((v - 0.5).floor() + 1.0).clamp(0.0, n as f64) as u32);
    let rect = [lo(xmin, w), hi(xmax, w), lo(ymin, hh), hi(ymax, hh)];
    let nonempty = rect[0].zip(rect[1], |a, b| a < b).and(rect[2].zip(rect[3], |a, b| a < b));
    (rect, radius, keep.and(nonempty))
}

/// [`RowConic::new`]'s coefficients in f64 lanes, in its order, and whether `A > 0`.
#[inline(always)]
fn row_conic(h: &[V<f32>; 9], center: [V<f32>; 2], rho_max: V<f64>) -> ([V<f64>; 5], M) {
    let t: [V<f64>; 9] = each(h, |v| v.map(f64::from));
    let c = each(&center, |v| v.map(f64::from));
    let cross = |a: [V<f64>; 3], b: [V<f64>; 3]| {
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    };
    let (tu, tv, tw) = ([t[0], t[1], t[2]], [t[3], t[4], t[5]], [t[6], t[7], t[8]]);
    let alpha = cross(tv, tw);
    let beta = cross(tw, tu);
    let g0 = cross(tu, tv);
    let gamma = each(&[0, 1, 2], |j| c[0] * alpha[j] + c[1] * beta[j] + g0[j]);
    let dot = |a: [V<f64>; 3], b: [V<f64>; 3]| a[0] * b[0] + a[1] * b[1] - rho_max * a[2] * b[2];
    let a = dot(alpha, alpha);
    let k = [
        dot(alpha, gamma) / a,
        dot(alpha, beta) / a,
        dot(gamma, gamma) / a,
        V::splat(2.0) * dot(beta, gamma) / a,
        dot(beta, beta) / a,
    ];
    (k, a.map(|v| v > 0.0))
}

/// `conic_extent` in f64 lanes: whether the ellipse is bounded, and `[px, ex, py, ey]`.
#[inline(always)]
fn conic_extent(t: &[V<f64>; 9], cut2: V<f64>) -> (M, [V<f64>; 4]) {
    let (tu, tv, tw) = ([t[0], t[1], t[2]], [t[3], t[4], t[5]], [t[6], t[7], t[8]]);
    let q = |a: [V<f64>; 3], b: [V<f64>; 3]| cut2 * (a[0] * b[0] + a[1] * b[1]) - a[2] * b[2];
    let d = q(tw, tw);
    let px = q(tu, tw) / d;
    let py = q(tv, tw) / d;
    // `max(1e-4)` as a select: equal to f64::max but on NaN, which only unbounded lanes have.
    let ex = (px * px - q(tu, tu) / d).map(|v| if v > 1e-4 { v } else { 1e-4 }.sqrt());
    let ey = (py * py - q(tv, tv) / d).map(|v| if v > 1e-4 { v } else { 1e-4 }.sqrt());
    (d.map(|v| v < 0.0), [px, ex, py, ey])
}

/// [`svgir_core::sh::basis`] (degree 3) lane by lane, in its order.
#[inline(always)]
fn sh_basis(d: [V<f32>; 3]) -> [V<f32>; 16] {
    use svgir_core::sh::{SH_C0, SH_C1, SH_C2, SH_C3};
    let sp = V::<f32>::splat;
    let [x, y, z] = d;
    let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
    let (two, three, four) = (sp(2.0), sp(3.0), sp(4.0));
    [
        sp(SH_C0),
        sp(-SH_C1) * y,
        sp(SH_C1) * z,
        sp(-SH_C1) * x,
        sp(SH_C2[0]) * xy,
        sp(SH_C2[1]) * yz,
        sp(SH_C2[2]) * (two * zz - xx - yy),
        sp(SH_C2[3]) * xz,
        sp(SH_C2[4]) * (xx - yy),
        sp(SH_C3[0]) * y * (three * xx - yy),
        sp(SH_C3[1]) * xy * z,
        sp(SH_C3[2]) * y * (four * zz - xx - yy),
        sp(SH_C3[3]) * z * (two * zz - three * xx - three * yy),
        sp(SH_C3[4]) * x * (four * zz - xx - yy),
        sp(SH_C3[5]) * z * (xx - yy),
        sp(SH_C3[6]) * x * (xx - three * yy),
    ]
}

#[cfg(test)]
mod tests {
    use crate::fixtures::{bench_camera, random_scene};
    use crate::preprocess::{preprocess, Cam};
    use crate::{ColorSourceOf, RasterConfig, Simd};
    use glam::{Quat, Vec2, Vec3};
    use svgir_core::Rng;

    /// Each lane path gives the scalar functions' splat records and SH colours to the bit (as
    /// their `Debug` text, which tells every f32 apart, signed zeros included), on scenes with
    /// every kind of culled Gaussian: behind the near plane, degenerate quaternions, edge-on,
    /// NaN, too faint to pass a pixel, and large ones whose ellipse crosses the camera plane.
    #[test]
    fn lanes_match_the_scalar_functions_bit_for_bit() {
        let paths: Vec<Simd> = Simd::available().into_iter().filter(|&p| p != Simd::Scalar).collect();
        if paths.is_empty() {
            eprintln!("no SIMD path on this CPU: the lane preprocess is not exercised");
            return;
        }
        let camera = bench_camera(64, 48);
        let cam = Cam::<f32>::new(&camera);
        let eye = Vec3::from_array(cam.center);
        for (seed, degree) in [(1u64, 3u32), (2, 2), (3, 1), (4, 0)] {
            let n = 2003;
            let mut s = random_scene(n, seed);
            s.sh_degree = degree;
            let mut rng = Rng::new(seed);
            for i in 0..n {
                for k in 0..16 {
                    s.sh[i].0[k] = [rng.normal(), rng.normal(), rng.normal()];
                }
                s.opacity_logits[i] = 4.0 * rng.normal();
                match i % 23 {
                    0 => s.positions[i] = eye + 0.05 * (s.positions[i] - eye).normalize(),
                    1 => s.rotations[i] = Quat::from_xyzw(0.0, 0.0, 0.0, 0.0),
                    2 => s.positions[i] = Vec3::new(f32::NAN, 0.0, 0.0),
                    3 => s.log_scales[i] = Vec2::splat(3.0),
                    4 => s.opacity_logits[i] = -9.0,
                    5 => {
                        // Edge-on: the normal perpendicular to the view ray.
                        let ray = (s.positions[i] - eye).normalize();
                        s.rotations[i] = Quat::from_rotation_arc(Vec3::Z, ray.any_orthonormal_vector());
                    }
                    _ => {}
                }
            }
            let colors = [
                ColorSourceOf::Sh,
                ColorSourceOf::Features(crate::FeaturesOf { data: &[], vertices: 1, channels: 3, uniform: 0 }),
            ];
            for c in &colors {
                let cfg = RasterConfig { simd: Simd::Scalar, ..Default::default() };
                let (want, want_rgb) = preprocess(&s, &cam, c, &cfg);
                let visible = want.iter().filter(|sp| sp.visible()).count();
                assert!(visible > n / 4 && visible < n * 9 / 10, "seed {seed}: {visible} of {n} visible");
                assert!(want.iter().any(|sp| sp.visible() && !sp.conic.bounded()), "no unbounded chord");
                for &path in &paths {
                    let (got, got_rgb) = preprocess(&s, &cam, c, &RasterConfig { simd: path, ..cfg });
                    for i in 0..n {
                        assert_eq!(
                            format!("{:?}", got[i]),
                            format!("{:?}", want[i]),
                            "seed {seed} {}: splat {i}",
                            path.name()
                        );
                    }
                    assert_eq!(format!("{got_rgb:?}"), format!("{want_rgb:?}"), "seed {seed} {}: colours", path.name());
                }
            }
        }
    }
}
