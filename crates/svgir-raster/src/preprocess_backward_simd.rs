//! [`crate::preprocess_backward::gaussian_backward`] for eight Gaussians at a time, compiled for
//! AVX2 and AVX-512 and chosen at run time ([`crate::simd`]).
//!
//! Work split: the caller's parallel loop hands over blocks of eight consecutive Gaussians. Their
//! raw parameters, splat records (the scales among them, so no `exp` here) and summed splat
//! gradients are transposed into lanes (one Gaussian per lane, one [`Inputs`] per task), and
//! every expression of the scalar function is evaluated lane by lane in its order, without FMA.
//! So every gradient is bit-identical to the scalar path, which stays the oracle (the tests
//! compare them) and the fallback for f64 and other architectures. Nothing is saved: this is the
//! last step of the backward.
//!
//! Why lanes: the per-Gaussian backward is a few hundred dependent scalar operations per
//! Gaussian (quaternion, camera chain, degree-3 SH basis and its Jacobian): 7.7 ms of a 400x400 /
//! 100k forward+backward on 2 cores in scalar code, 3.8 ms in lanes, about half of which is now
//! the transposition into lanes.

// The lane methods are `unsafe fn`s with one contract -- the CPU has the features of the path
// that runs them (checked once by `Simd::resolve`) -- so the operations inside need no block.
#![allow(unsafe_op_in_unsafe_fn)]

use crate::backward::OFF_COL;
use crate::preprocess::{Cam, Splat};
use crate::preprocess_backward::{GradSlots, ParamGrad};
use crate::simd::{Lanes, Simd};
use crate::GaussianParams;
use glam::{Quat, Vec2, Vec3};
use svgir_core::sh::ShCoeffs;
use svgir_core::Float;

/// Gaussians per block.
pub(crate) const BLOCK: usize = 8;

/// The parameter gradients of one block's Gaussians (gathered in `x`, at most [`BLOCK`]) into
/// `out`, on the SIMD path `path` (already resolved); false when `path` is scalar (the caller
/// runs [`crate::preprocess_backward::gaussian_backward`]). Every slot of `out` is written (zeros
/// for invisible Gaussians, as the scalar path).
pub(crate) fn gaussian_backward_block(
    path: Simd,
    x: &Inputs,
    cam: &Cam<f32>,
    splats: &[Splat<f32>],
    out: &mut GradSlots<f32>,
) -> bool {
    debug_assert!(splats.len() <= BLOCK && out.len() == splats.len());
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: `resolve` only returns a path whose features the CPU has.
        unsafe {
            match path {
                Simd::Avx2 => block_avx2(x, cam, splats, out),
                Simd::Avx512 => block_avx512(x, cam, splats, out),
                _ => return false,
            }
        }
        true
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (path, x, cam, splats, out);
        false
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_avx2(x: &Inputs, cam: &Cam<f32>, splats: &[Splat<f32>], out: &mut GradSlots<f32>) {
    block::<crate::simd::F8>(x, cam, splats, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
unsafe fn block_avx512(x: &Inputs, cam: &Cam<f32>, splats: &[Splat<f32>], out: &mut GradSlots<f32>) {
    block::<crate::simd::F8k>(x, cam, splats, out)
}

/// One block's inputs, transposed: `[field][lane]`.
pub(crate) struct Inputs {
    p: [[f32; BLOCK]; 3],
    q: [[f32; BLOCK]; 4],
    /// The two scales (`exp` of the log-scales, from the splat record).
    s: [[f32; BLOCK]; 2],
    /// H's last column `(H02, H12, H22)`, all the projected centre's gradient reads of H.
    hc: [[f32; BLOCK]; 3],
    opacity: [f32; BLOCK],
    flip: [f32; BLOCK],
    depth: [f32; BLOCK],
    /// The summed splat gradients in the backward's entry-slot layout: H (9), centre (2),
    /// opacity, normal (3), colour (3).
    g: [[f32; BLOCK]; 18],
    /// The colour gradient with clamped channels zeroed (SH mode).
    gc: [[f32; BLOCK]; 3],
    /// The SH coefficients `[k][channel]` of the first `nk` bands (SH mode), else `nk == 0`.
    sh: [[[f32; BLOCK]; 3]; 16],
    nk: usize,
}

impl Inputs {
    /// Zeros, to be filled block after block ([`Inputs::fill`]).
    pub(crate) fn new() -> Box<Self> {
        let z = [0.0; BLOCK];
        Box::new(Self {
            p: [z; 3],
            q: [z; 4],
            s: [z; 2],
            hc: [z; 3],
            opacity: z,
            flip: z,
            depth: z,
            g: [z; 18],
            gc: [z; 3],
            sh: [[z; 3]; 16],
            nk: 0,
        })
    }

    /// The inputs of Gaussians `g0..g0 + splats.len()`, read in the scalar type `F` (which is
    /// `f32` on the SIMD paths, so `to_f32` is exact). Lanes past the block's end keep an earlier
    /// block's values, which are finite and whose results are never stored; reusing one
    /// `Inputs` per task instead of zeroing a new one per block saved a 31 MB memset per
    /// backward of 100k Gaussians.
    pub(crate) fn fill<F: Float, P: GaussianParams<F> + ?Sized>(
        &mut self,
        params: &P,
        splats: &[Splat<F>],
        sums: &[[F; OFF_COL + 3]],
        sh_mode: bool,
        g0: usize,
    ) {
        let nk = if sh_mode { svgir_core::sh::num_coeffs(params.sh_degree().min(3)) } else { 0 };
        let x = self;
        x.nk = nk;
        for (l, (sp, sg)) in splats.iter().zip(sums).enumerate() {
            let i = g0 + l;
            let (p, q) = (params.position(i), params.rotation(i));
            for c in 0..3 {
                x.p[c][l] = p[c].to_f32();
            }
            for c in 0..4 {
                x.q[c][l] = q[c].to_f32();
            }
            for c in 0..2 {
                x.s[c][l] = sp.scale[c].to_f32();
            }
            for (c, &k) in [2, 5, 8].iter().enumerate() {
                x.hc[c][l] = sp.h[k].to_f32();
            }
            for (c, v) in sg.iter().enumerate() {
                x.g[c][l] = v.to_f32();
            }
            x.opacity[l] = sp.opacity.to_f32();
            x.flip[l] = sp.flip.to_f32();
            x.depth[l] = sp.depth.to_f32();
            for ch in 0..3 {
                x.gc[ch][l] = if sp.clamped & (1 << ch) == 0 { x.g[OFF_COL + ch][l] } else { 0.0 };
            }
            for k in 0..nk {
                for ch in 0..3 {
                    x.sh[k][ch][l] = params.sh(i, k, ch).to_f32();
                }
            }
        }
    }
}

/// Lanes of a transposed field.
#[inline(always)]
unsafe fn ld<S: Lanes>(a: &[f32; BLOCK]) -> S {
    S::load(a.as_ptr())
}

/// Lanes to a transposed field.
#[inline(always)]
unsafe fn st<S: Lanes>(v: S) -> [f32; BLOCK] {
    let mut a = [0.0; BLOCK];
    v.store(a.as_mut_ptr());
    a
}

/// `a0 b0 + a1 b1 + a2 b2` ([`crate::vec3::dot3`]'s order).
#[inline(always)]
unsafe fn dot3<S: Lanes>(a: [S; 3], b: [S; 3]) -> S {
    a[0].mul(b[0]).add(a[1].mul(b[1])).add(a[2].mul(b[2]))
}

/// `m^T v` for a row-major camera rotation ([`crate::vec3::matvec_t`]'s order, summed from 0).
#[inline(always)]
unsafe fn matvec_t<S: Lanes>(m: &[[f32; 3]; 3], v: [S; 3]) -> [S; 3] {
    let mut r = [S::splat(0.0); 3];
    for i in 0..3 {
        for j in 0..3 {
            r[j] = r[j].add(S::splat(m[i][j]).mul(v[i]));
        }
    }
    r
}

/// The scalar function's operations, lane by lane (see the module docs).
#[inline(always)]
unsafe fn block<S: Lanes>(x: &Inputs, cam: &Cam<f32>, splats: &[Splat<f32>], out: &mut GradSlots<f32>) {
    let sp = |v: f32| S::splat(v);
    let (one, two) = (sp(1.0), sp(2.0));
    let g = |k: usize| ld::<S>(&x.g[k]);

    // `quat_to_rot`: the normalised quaternion and R (columns t_u, t_v, n).
    let q: [S; 4] = std::array::from_fn(|c| ld(&x.q[c]));
    let len = dot3([q[0], q[1], q[2]], [q[0], q[1], q[2]]).add(q[3].mul(q[3])).sqrt();
    let valid = S::bits(len.gt(sp(0.0)));
    let [qx, qy, qz, qw] = q.map(|v| v.div(len));
    let rot = [
        [
            one.sub(two.mul(qy.mul(qy).add(qz.mul(qz)))),
            two.mul(qx.mul(qy).sub(qw.mul(qz))),
            two.mul(qx.mul(qz).add(qw.mul(qy))),
        ],
        [
            two.mul(qx.mul(qy).add(qw.mul(qz))),
            one.sub(two.mul(qx.mul(qx).add(qz.mul(qz)))),
            two.mul(qy.mul(qz).sub(qw.mul(qx))),
        ],
        [
            two.mul(qx.mul(qz).sub(qw.mul(qy))),
            two.mul(qy.mul(qz).add(qw.mul(qx))),
            one.sub(two.mul(qx.mul(qx).add(qy.mul(qy)))),
        ],
    ];
    let (su, sv) = (ld::<S>(&x.s[0]), ld::<S>(&x.s[1]));
    let (h02, h12, h22) = (ld::<S>(&x.hc[0]), ld::<S>(&x.hc[1]), ld::<S>(&x.hc[2]));

    // Projected centre c = (H02 / H22, H12 / H22).
    let mut vh: [S; 9] = std::array::from_fn(g);
    let (gc0, gc1) = (g(9), g(10));
    let inv = one.div(h22);
    vh[2] = vh[2].add(gc0.mul(inv));
    vh[5] = vh[5].add(gc1.mul(inv));
    vh[8] = vh[8].sub(gc0.mul(h02).add(gc1.mul(h12)).mul(inv).mul(inv));

    // H = K M with M = [a_u a_v a_0]: v_M = K^T v_H.
    let (fx, fy, cx, cy) = (sp(cam.fx), sp(cam.fy), sp(cam.cx), sp(cam.cy));
    let k3 = |a: S, b: S, c: S| cx.mul(a).add(cy.mul(b)).add(c);
    let vm = [
        [fx.mul(vh[0]), fx.mul(vh[1]), fx.mul(vh[2])],
        [fy.mul(vh[3]), fy.mul(vh[4]), fy.mul(vh[5])],
        [k3(vh[0], vh[3], vh[6]), k3(vh[1], vh[4], vh[7]), k3(vh[2], vh[5], vh[8])],
    ];
    let col = |m: &[[S; 3]; 3], c: usize| [m[0][c], m[1][c], m[2][c]];
    let v_au = matvec_t(&cam.r, col(&vm, 0));
    let v_av = matvec_t(&cam.r, col(&vm, 1));
    let mut v_p = matvec_t(&cam.r, col(&vm, 2));

    let v_ls = [su.mul(dot3(col(&rot, 0), v_au)), sv.mul(dot3(col(&rot, 1), v_av))];
    let flip = ld::<S>(&x.flip);
    let vr: [[S; 3]; 3] = std::array::from_fn(|r| [su.mul(v_au[r]), sv.mul(v_av[r]), flip.mul(g(12 + r))]);
    let v_q = quat_backward([qx, qy, qz, qw], len, &vr);
    let o = ld::<S>(&x.opacity);
    let v_o = g(11).mul(o).mul(one.sub(o));

    let mut v_sh = [[[0.0f32; BLOCK]; 3]; 16];
    if x.nk > 0 {
        let p: [S; 3] = std::array::from_fn(|c| ld(&x.p[c]));
        let dir: [S; 3] = std::array::from_fn(|c| p[c].sub(sp(cam.center[c])));
        let dlen = dot3(dir, dir).sqrt();
        let d = dir.map(|v| v.div(dlen));
        let gc: [S; 3] = std::array::from_fn(|ch| ld(&x.gc[ch]));
        let b = sh_basis(d);
        let bg = sh_basis_grad(d);
        let mut v_d = [sp(0.0); 3];
        for k in 0..x.nk {
            let mut s = sp(0.0);
            for ch in 0..3 {
                v_sh[k][ch] = st(b[k].mul(gc[ch]));
                s = s.add(ld::<S>(&x.sh[k][ch]).mul(gc[ch]));
            }
            for j in 0..3 {
                v_d[j] = v_d[j].add(bg[k][j].mul(s));
            }
        }
        let dd = dot3(d, v_d);
        for j in 0..3 {
            v_p[j] = v_p[j].add(v_d[j].sub(d[j].mul(dd)).div(dlen));
        }
    }

    // Densification statistic (see `GradsOf::v_mean2d_norm`).
    let rr = cam.r.map(|row| row.map(sp));
    let gcam = [dot3(rr[0], v_p), dot3(rr[1], v_p)];
    let z = ld::<S>(&x.depth);
    let nx = gcam[0].mul(z).div(fx);
    let ny = gcam[1].mul(z).div(fy);
    let m2d = st(nx.mul(nx).add(ny.mul(ny)).sqrt());

    let (v_p, v_q, v_ls, v_o) = (v_p.map(|v| st(v)), v_q.map(|v| st(v)), v_ls.map(|v| st(v)), st(v_o));
    for (l, s) in splats.iter().enumerate() {
        if !s.visible() || valid & (1 << l) == 0 {
            // Invisible, or a degenerate quaternion: the scalar path writes zeros.
            out.put(l, &ParamGrad::default(), false);
            continue;
        }
        out.position[l].write(Vec3::new(v_p[0][l], v_p[1][l], v_p[2][l]));
        out.rotation[l].write(Quat::from_xyzw(v_q[0][l], v_q[1][l], v_q[2][l], v_q[3][l]));
        out.log_scale[l].write(Vec2::new(v_ls[0][l], v_ls[1][l]));
        out.opacity_logit[l].write(v_o[l]);
        out.mean2d_norm[l].write(m2d[l]);
        out.sh[l].write(ShCoeffs(std::array::from_fn(|k| [v_sh[k][0][l], v_sh[k][1][l], v_sh[k][2][l]])));
    }
}

/// [`crate::preprocess_backward::quat_backward`] from the normalised quaternion `[x, y, z, w]`
/// and its length, lane by lane.
#[inline(always)]
unsafe fn quat_backward<S: Lanes>(qh: [S; 4], len: S, g: &[[S; 3]; 3]) -> [S; 4] {
    let [x, y, z, w] = qh;
    let (two, m1, m2) = (S::splat(2.0), S::splat(-1.0), S::splat(-2.0));
    // `-z * g` in the scalar code is `(-z) * g`; `-1 * z` is that negation, exactly.
    let vw = two.mul(
        m1.mul(z)
            .mul(g[0][1])
            .add(y.mul(g[0][2]))
            .add(z.mul(g[1][0]))
            .sub(x.mul(g[1][2]))
            .sub(y.mul(g[2][0]))
            .add(x.mul(g[2][1])),
    );
    let vx = two.mul(
        y.mul(g[0][1])
            .add(z.mul(g[0][2]))
            .add(y.mul(g[1][0]))
            .sub(two.mul(x).mul(g[1][1]))
            .sub(w.mul(g[1][2]))
            .add(z.mul(g[2][0]))
            .add(w.mul(g[2][1]))
            .sub(two.mul(x).mul(g[2][2])),
    );
    let vy = two.mul(
        m2.mul(y)
            .mul(g[0][0])
            .add(x.mul(g[0][1]))
            .add(w.mul(g[0][2]))
            .add(x.mul(g[1][0]))
            .add(z.mul(g[1][2]))
            .sub(w.mul(g[2][0]))
            .add(z.mul(g[2][1]))
            .sub(two.mul(y).mul(g[2][2])),
    );
    let vz = two.mul(
        m2.mul(z)
            .mul(g[0][0])
            .sub(w.mul(g[0][1]))
            .add(x.mul(g[0][2]))
            .add(w.mul(g[1][0]))
            .sub(two.mul(z).mul(g[1][1]))
            .add(y.mul(g[1][2]))
            .add(x.mul(g[2][0]))
            .add(y.mul(g[2][1])),
    );
    // Through the normalisation q^ = q / |q|.
    let gq = [vx, vy, vz, vw];
    let d = gq[0].mul(qh[0]).add(gq[1].mul(qh[1])).add(gq[2].mul(qh[2])).add(gq[3].mul(qh[3]));
    std::array::from_fn(|i| gq[i].sub(qh[i].mul(d)).div(len))
}

/// [`svgir_core::sh::basis`] (degree 3) lane by lane, in its order.
#[inline(always)]
unsafe fn sh_basis<S: Lanes>(d: [S; 3]) -> [S; 16] {
    use svgir_core::sh::{SH_C0, SH_C1, SH_C2, SH_C3};
    let sp = |v: f32| S::splat(v);
    let [x, y, z] = d;
    let (xx, yy, zz, xy, yz, xz) = (x.mul(x), y.mul(y), z.mul(z), x.mul(y), y.mul(z), x.mul(z));
    let (two, three, four) = (sp(2.0), sp(3.0), sp(4.0));
    let c3 = |k: usize, a: S, b: S| sp(SH_C3[k]).mul(a).mul(b);
    [
        sp(SH_C0),
        sp(-SH_C1).mul(y),
        sp(SH_C1).mul(z),
        sp(-SH_C1).mul(x),
        sp(SH_C2[0]).mul(xy),
        sp(SH_C2[1]).mul(yz),
        sp(SH_C2[2]).mul(two.mul(zz).sub(xx).sub(yy)),
        sp(SH_C2[3]).mul(xz),
        sp(SH_C2[4]).mul(xx.sub(yy)),
        c3(0, y, three.mul(xx).sub(yy)),
        c3(1, xy, z),
        c3(2, y, four.mul(zz).sub(xx).sub(yy)),
        c3(3, z, two.mul(zz).sub(three.mul(xx)).sub(three.mul(yy))),
        c3(4, x, four.mul(zz).sub(xx).sub(yy)),
        c3(5, z, xx.sub(yy)),
        c3(6, x, xx.sub(three.mul(yy))),
    ]
}

/// [`svgir_core::sh::basis_grad`] (degree 3) lane by lane, in its order: `out[k][j] =
/// d basis_k / d d_j`.
#[inline(always)]
unsafe fn sh_basis_grad<S: Lanes>(d: [S; 3]) -> [[S; 3]; 16] {
    use svgir_core::sh::{SH_C1, SH_C2, SH_C3};
    let sp = |v: f32| S::splat(v);
    let [x, y, z] = d;
    let (xx, yy, zz) = (x.mul(x), y.mul(y), z.mul(z));
    let zero = sp(0.0);
    // `C * Vec3::new(a, b, c)` scales each component (a zero one too: C * 0 keeps C's sign).
    let sc = |c: f32, v: [S; 3]| v.map(|e| sp(c).mul(e));
    let k = |v: f32, a: S| sp(v).mul(a);
    [
        [zero; 3],
        [zero, sp(-SH_C1), zero],
        [zero, zero, sp(SH_C1)],
        [sp(-SH_C1), zero, zero],
        sc(SH_C2[0], [y, x, zero]),
        sc(SH_C2[1], [zero, z, y]),
        sc(SH_C2[2], [k(-2.0, x), k(-2.0, y), k(4.0, z)]),
        sc(SH_C2[3], [z, zero, x]),
        sc(SH_C2[4], [k(2.0, x), k(-2.0, y), zero]),
        sc(SH_C3[0], [k(6.0, x).mul(y), k(3.0, xx).sub(k(3.0, yy)), zero]),
        sc(SH_C3[1], [y.mul(z), x.mul(z), x.mul(y)]),
        sc(SH_C3[2], [k(-2.0, x).mul(y), k(4.0, zz).sub(xx).sub(k(3.0, yy)), k(8.0, y).mul(z)]),
        sc(SH_C3[3], [k(-6.0, x).mul(z), k(-6.0, y).mul(z), k(6.0, zz).sub(k(3.0, xx)).sub(k(3.0, yy))]),
        sc(SH_C3[4], [k(4.0, zz).sub(k(3.0, xx)).sub(yy), k(-2.0, x).mul(y), k(8.0, x).mul(z)]),
        sc(SH_C3[5], [k(2.0, x).mul(z), k(-2.0, y).mul(z), xx.sub(yy)]),
        sc(SH_C3[6], [k(3.0, xx).sub(k(3.0, yy)), k(-6.0, x).mul(y), zero]),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::{bench_camera, random_scene};
    use crate::preprocess::preprocess;
    use crate::preprocess::{assume_init, uninit_vec};
    use crate::preprocess_backward::{gaussian_backward, SplatGradSum};
    use crate::{ColorSourceOf, RasterConfig};
    use svgir_core::Rng;

    /// The gradients of every Gaussian of `splats`, in blocks on `path` or one by one on the
    /// scalar oracle, as bits.
    fn grads(
        path: Simd,
        s: &svgir_core::Surfels,
        cam: &Cam<f32>,
        splats: &[Splat<f32>],
        sums: &[[f32; 18]],
    ) -> Vec<u32> {
        let n = splats.len();
        let sh_mode = true;
        let (mut p, mut q, mut ls) = (uninit_vec(n), uninit_vec(n), uninit_vec(n));
        let (mut o, mut sh, mut m) = (uninit_vec(n), uninit_vec(n), uninit_vec(n));
        let (mut g0, mut x) = (0, Inputs::new());
        while g0 < n {
            let e = (g0 + BLOCK).min(n);
            let mut out = GradSlots::<f32> {
                position: &mut p[g0..e],
                rotation: &mut q[g0..e],
                log_scale: &mut ls[g0..e],
                opacity_logit: &mut o[g0..e],
                sh: &mut sh[g0..e],
                mean2d_norm: &mut m[g0..e],
            };
            x.fill(s, &splats[g0..e], &sums[g0..e], sh_mode, g0);
            if !gaussian_backward_block(path, &x, cam, &splats[g0..e], &mut out) {
                for l in 0..e - g0 {
                    let (sp, a) = (&splats[g0 + l], &sums[g0 + l]);
                    let mut sg = SplatGradSum::<f32>::default();
                    sg.h.copy_from_slice(&a[0..9]);
                    sg.center.copy_from_slice(&a[9..11]);
                    sg.opacity = a[11];
                    sg.normal.copy_from_slice(&a[12..15]);
                    sg.color.copy_from_slice(&a[15..18]);
                    let pg = if sp.visible() {
                        gaussian_backward(s, cam, sp, &sg, sh_mode, g0 + l)
                    } else {
                        ParamGrad::default()
                    };
                    out.put(l, &pg, sh_mode);
                }
            }
            g0 = e;
        }
        // SAFETY: every block wrote each of its slots.
        let (p, q, ls, o, sh, m) = unsafe {
            (assume_init(p), assume_init(q), assume_init(ls), assume_init(o), assume_init(sh), assume_init(m))
        };
        let mut bits = Vec::new();
        for i in 0..n {
            let v = p[i].to_array().into_iter().chain(q[i].to_array()).chain(ls[i].to_array());
            let v = v.chain([o[i], m[i]]).chain(sh[i].0.iter().flatten().copied());
            bits.extend(v.map(f32::to_bits));
        }
        bits
    }

    /// Each lane path gives the scalar function's gradients to the bit: every SH degree, a
    /// block tail, culled Gaussians, clamped colour channels and degenerate quaternions.
    #[test]
    fn lanes_match_the_scalar_function_bit_for_bit() {
        let paths: Vec<Simd> = Simd::available().into_iter().filter(|&p| p != Simd::Scalar).collect();
        if paths.is_empty() {
            eprintln!("no SIMD path on this CPU: the lane kernel is not exercised");
            return;
        }
        let camera = bench_camera(64, 48);
        let cam = Cam::<f32>::new(&camera);
        for (seed, degree) in [(1u64, 3u32), (2, 2), (3, 1), (4, 0)] {
            let n = 1003;
            let mut s = random_scene(n, seed);
            s.sh_degree = degree;
            let mut rng = Rng::new(seed);
            for i in 0..n {
                for k in 0..16 {
                    s.sh[i].0[k] = [rng.normal(), rng.normal(), rng.normal()].map(|v| 0.5 * v);
                }
            }
            // A zero quaternion is culled by the forward; keep its splat so the backward meets it.
            let (mut splats, _) = preprocess(&s, &cam, &ColorSourceOf::Sh, &RasterConfig::default());
            let visible = splats.iter().filter(|sp| sp.visible()).count();
            assert!(visible > n / 4 && visible < n, "seed {seed}: {visible} of {n} visible");
            for i in (5..n).step_by(97) {
                s.rotations[i] = glam::Quat::from_xyzw(0.0, 0.0, 0.0, 0.0);
                splats[i] = splats[i - 1];
                splats[i].rect = [0, 4, 0, 4];
            }
            for (i, sp) in splats.iter_mut().enumerate() {
                sp.clamped = (i % 8) as u8;
            }
            let sums: Vec<[f32; 18]> = (0..n).map(|_| std::array::from_fn(|_| rng.normal())).collect();
            let want = grads(Simd::Scalar, &s, &cam, &splats, &sums);
            assert!(want.iter().any(|&b| f32::from_bits(b) != 0.0));
            for &path in &paths {
                let got = grads(path, &s, &cam, &splats, &sums);
                let per = want.len() / n;
                if let Some(i) = (0..want.len()).find(|&i| got[i] != want[i]) {
                    panic!(
                        "seed {seed} {}: Gaussian {} value {}: {} vs scalar {}",
                        path.name(),
                        i / per,
                        i % per,
                        f32::from_bits(got[i]),
                        f32::from_bits(want[i])
                    );
                }
            }
        }
    }
}
