//! Lane forms of [`crate::split`]'s GGX terms, over `svgir_core::simd::Lanes` (8 f32 lanes in
//! the AVX2 kernels of the vertex shading and of the one-bounce gather): the same operations in
//! the same order and without FMA, so each lane computes the scalar value bit for bit, except
//! [`half_lanes`]' Fresnel, whose `exp2` is the lanes' polynomial `exp_fast` (within a few ulp of
//! the scalar one; its users compare with a tolerance).
//!
//! Every function is `#[inline(always)]` and `unsafe`: it must be inlined into a kernel compiled
//! with the features of the lane type (`#[target_feature]`), which is the caller's contract.

// The lane functions are `unsafe fn`s with one contract -- the CPU has the features of the lane
// type -- so the operations inside need no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]
#![allow(clippy::missing_safety_doc)]

use crate::split::Lobe;
use crate::{DOT_EPS, F0};
use svgir_core::simd::Lanes;

/// `[e(0), e(1), e(2)]` written out: `array::map` would call the closure through code compiled
/// without AVX, where the lane intrinsics cannot be inlined.
#[macro_export]
macro_rules! tri {
    ($c:ident => $e:expr) => {
        [
            {
                let $c = 0;
                $e
            },
            {
                let $c = 1;
                $e
            },
            {
                let $c = 2;
                $e
            },
        ]
    };
}

/// `cdot` of `svgir_shading::split` per lane: x clamped to [DOT_EPS, 1] (as `clampf`: max, then min).
#[inline(always)]
pub unsafe fn cdot<L: Lanes>(x: L) -> L {
    let (lo, one) = (L::splat(DOT_EPS as f32), L::splat(1.0));
    let x = L::select(x.gt(lo), x, lo);
    L::select(x.lt(one), x, one)
}

/// Whether `cdot`'s clamp is inactive: `DOT_EPS < x < 1`.
#[inline(always)]
pub unsafe fn cdot_live<L: Lanes>(x: L) -> L::M {
    L::and(x.gt(L::splat(DOT_EPS as f32)), x.lt(L::splat(1.0)))
}

/// `a . b` for lane vectors, in `dot`'s order.
#[inline(always)]
pub unsafe fn dot_l<L: Lanes>(a: [f32; 3], b: &[L; 3]) -> L {
    L::splat(a[0]).mul(b[0]).add(L::splat(a[1]).mul(b[1])).add(L::splat(a[2]).mul(b[2]))
}

/// A vertex's lobe broadcast to lanes.
#[derive(Clone, Copy)]
pub struct LobeL<L> {
    /// `alpha^2 = r^4`.
    pub a2: L,
    /// `alpha^2 - 1`.
    pub a2m1: L,
    /// Schlick-GGX `k = (r + 1)^2 / 8`.
    pub k: L,
    /// `1 - k`.
    pub omk: L,
    /// The view-only factor `alpha^2 G1(n.v) / (4 pi)`.
    pub c0: L,
}

/// Broadcast a vertex's scalar lobe to every lane.
#[inline(always)]
pub unsafe fn lobe_l<L: Lanes>(lb: &Lobe<f32>) -> LobeL<L> {
    LobeL {
        a2: L::splat(lb.a2),
        a2m1: L::splat(lb.a2 - 1.0),
        k: L::splat(lb.k),
        omk: L::splat(lb.omk),
        c0: L::splat(lb.c0),
    }
}

/// `split::spec` per lane: `S = F c0 / (q^2 (n.l (1-k) + k))`, `q = (n.h)^2 (a^2-1) + 1`.
#[inline(always)]
pub unsafe fn spec_lanes<L: Lanes>(lb: &LobeL<L>, nh_raw: L, fr: L, nl_raw: L) -> L {
    let nl = cdot(nl_raw);
    let nh = cdot(nh_raw);
    let q = nh.mul(nh).mul(lb.a2m1).add(L::splat(1.0));
    fr.mul(lb.c0).div(q.mul(q).mul(nl.mul(lb.omk).add(lb.k)))
}

/// `split::spec_grad` per lane: S, dS/dr and dS/dn.
pub struct SpecGradL<L> {
    /// S.
    pub value: L,
    /// dS / d roughness.
    pub v_r: L,
    /// dS / d (unit) normal.
    pub v_n: [L; 3],
}

/// `split::spec_grad` per lane for a vertex's lobe `lb` (and its broadcast `ll`): the half
/// vectors `h` with their Fresnel `fr`, the shared view `v`, the light directions `l` and the
/// raw `n.l`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub unsafe fn spec_grad_lanes<L: Lanes>(
    lb: &Lobe<f32>,
    ll: &LobeL<L>,
    h: &[L; 3],
    fr: L,
    v: [f32; 3],
    l: &[L; 3],
    nl_raw: L,
) -> SpecGradL<L> {
    let s = L::splat;
    let zero = s(0.0);
    let one = s(1.0);
    let nh_raw = dot_l(lb.n, h);
    let (nl, nl_live) = (cdot(nl_raw), cdot_live(nl_raw));
    let (nh, nh_live) = (cdot(nh_raw), cdot_live(nh_raw));
    let a2 = ll.a2;
    let q = nh.mul(nh).mul(ll.a2m1).add(one);
    // One division for 1/q and g(n.l), as the scalar form.
    let den = nl.mul(ll.omk).add(ll.k);
    let t = one.div(q.mul(den));
    let inv_q = den.mul(t);
    let gl = q.mul(t);
    let d = s(lb.d0).mul(inv_q).mul(inv_q);
    let gv = s(lb.gv);
    let fq = fr.mul(s(0.25));
    let value = fq.mul(d).mul(gv).mul(gl);
    let inv_q3 = inv_q.mul(inv_q).mul(inv_q);
    let dd_dr = q.sub(s(2.0).mul(a2).mul(nh).mul(nh)).mul(inv_q3).mul(s(lb.cr));
    let dk_dr = s((lb.r + 1.0) * 0.25);
    let dgv_dk = s(-(1.0 - lb.nv) * lb.gv * lb.gv);
    let dgl_dk = zero.sub(one.sub(nl)).mul(gl).mul(gl);
    let v_r = fq.mul(dd_dr.mul(gv).mul(gl).add(d.mul(dgv_dk.mul(gl).add(gv.mul(dgl_dk))).mul(dk_dr)));
    let ds_dnh = fq.mul(gv).mul(gl).mul(s(lb.cn).mul(nh).mul(inv_q3));
    let ds_dnh = L::select(nh_live, ds_dnh, zero);
    let ds_dnv = if lb.nv_live { zero.sub(fq).mul(d).mul(gl).mul(ll.omk).mul(gv).mul(gv) } else { zero };
    let ds_dnl = zero.sub(fq).mul(d).mul(gv).mul(ll.omk).mul(gl).mul(gl);
    let ds_dnl = L::select(nl_live, ds_dnl, zero);
    let v_n = tri!(i => ds_dnh.mul(h[i]).add(ds_dnv.mul(s(v[i]))).add(ds_dnl.mul(l[i])));
    SpecGradL { value, v_r, v_n }
}

/// [`crate::split::half`] per lane, for a view direction `v` shared by all lanes and light
/// directions `l`: the unit half vector and the Schlick-Gaussian Fresnel. `exp2` is `exp_fast`
/// of `x ln 2`.
#[inline(always)]
pub unsafe fn half_lanes<L: Lanes>(v: [f32; 3], l: &[L; 3]) -> ([L; 3], L) {
    let s = L::splat;
    let hv = tri!(i => s(v[i]).add(l[i]));
    let len2 = hv[0].mul(hv[0]).add(hv[1].mul(hv[1])).add(hv[2].mul(hv[2]));
    let len = len2.sqrt();
    let lo = s(1e-12);
    let len = L::select(len.gt(lo), len, lo);
    let h = tri!(i => hv[i].div(len));
    let vh = cdot(dot_l(v, &h));
    let x = s(-5.55473).mul(vh).sub(s(6.98316)).mul(vh);
    let f0 = s(F0 as f32);
    let fr = f0.add(s(1.0).sub(f0).mul(x.mul(s(std::f32::consts::LN_2)).exp_fast()));
    (h, fr)
}
