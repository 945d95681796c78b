//! Run-time choice of the instruction set of the f32 SIMD kernels (rasteriser tiles, vertex
//! shading).
//!
//! One binary runs everywhere: the release build targets baseline x86-64 (SSE2), and the
//! explicitly vectorised kernels are compiled a second time with `#[target_feature]` and picked
//! once per call from `is_x86_feature_detected!`. The generic scalar kernels stay the oracle and
//! the fallback (f64, other architectures).
//!
//! [`Simd::Auto`] runs the widest path the CPU has (AVX-512F+VL, then AVX2); `SVGIR_SIMD=scalar|avx2|avx512` (read once)
//! overrides it, and a path the CPU lacks falls back to the best one below it.

// The lane methods are `unsafe fn`s with one contract -- the CPU has the features of the path
// that runs them (checked once by `Simd::resolve`) and every pointer stays inside its buffer --
// so the operations inside need no block of their own.
#![allow(unsafe_op_in_unsafe_fn)]

use std::sync::OnceLock;

/// Which tile kernels run for f32 renders.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Simd {
    /// `SVGIR_SIMD` if set, else the widest path the CPU has (AVX-512, AVX2, scalar).
    #[default]
    Auto,
    /// The generic kernels (what f64 always runs).
    Scalar,
    /// 8-lane AVX2 kernels.
    Avx2,
    /// 8-lane kernels on AVX-512F + VL: mask registers and 32 vector registers.
    Avx512,
}

impl Simd {
    /// Parses `scalar`, `avx2`, `avx512` or `auto`.
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" | "" => Some(Self::Auto),
            "scalar" => Some(Self::Scalar),
            "avx2" => Some(Self::Avx2),
            "avx512" => Some(Self::Avx512),
            _ => None,
        }
    }

    /// Lower-case name as [`Simd::parse`] reads it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Scalar => "scalar",
            Self::Avx2 => "avx2",
            Self::Avx512 => "avx512",
        }
    }

    /// The path that actually runs: `Auto` resolved, and a path the CPU lacks lowered to the
    /// best one below it (never `Auto`).
    pub fn resolve(self) -> Self {
        let want = match self {
            Self::Auto => env_choice().unwrap_or(Self::Auto),
            s => s,
        };
        let best = best_available();
        match (want, best) {
            // The widest path: the AVX-512 kernels (8 lanes with mask registers, since 16
            // lanes idled on splat rows of a handful of pixels) measured 10% faster than AVX2
            // on the 400x400 / 100k raster bench (docs/performance.md).
            (Self::Auto, b) => b,
            (Self::Scalar, _) | (_, Self::Scalar) => Self::Scalar,
            (Self::Avx512, b) => b,
            (Self::Avx2, _) => Self::Avx2,
        }
    }

    /// The paths this CPU can run, scalar first.
    pub fn available() -> Vec<Self> {
        let mut v = vec![Self::Scalar];
        let best = best_available();
        if matches!(best, Self::Avx2 | Self::Avx512) {
            v.push(Self::Avx2);
        }
        if best == Self::Avx512 {
            v.push(Self::Avx512);
        }
        v
    }
}

fn env_choice() -> Option<Simd> {
    static ENV: OnceLock<Option<Simd>> = OnceLock::new();
    *ENV.get_or_init(|| std::env::var("SVGIR_SIMD").ok().and_then(|s| Simd::parse(&s)))
}

/// The widest kernels this CPU runs.
pub fn best_available() -> Simd {
    static BEST: OnceLock<Simd> = OnceLock::new();
    *BEST.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            if is_x86_feature_detected!("avx512f")
                && is_x86_feature_detected!("avx512vl")
                && is_x86_feature_detected!("avx2")
            {
                return Simd::Avx512;
            }
            if is_x86_feature_detected!("avx2") {
                return Simd::Avx2;
            }
        }
        Simd::Scalar
    })
}

/// The CPU features relevant to the kernels, as `name+` / `name-` words (for benchmark tables).
pub fn cpu_features() -> String {
    #[cfg(target_arch = "x86_64")]
    {
        let f = [
            ("sse4.1", is_x86_feature_detected!("sse4.1")),
            ("avx", is_x86_feature_detected!("avx")),
            ("avx2", is_x86_feature_detected!("avx2")),
            ("fma", is_x86_feature_detected!("fma")),
            ("avx512f", is_x86_feature_detected!("avx512f")),
            ("avx512vl", is_x86_feature_detected!("avx512vl")),
        ];
        f.iter().map(|(n, on)| format!("{n}{}", if *on { "+" } else { "-" })).collect::<Vec<_>>().join(" ")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        format!("{} (no x86 SIMD kernels; scalar path, compiler-vectorised)", std::env::consts::ARCH)
    }
}

/// Whether the kernels' scalar type is `f32` (the SIMD kernels exist for f32 only).
#[inline]
pub fn is_f32<F: 'static>() -> bool {
    std::any::TypeId::of::<F>() == std::any::TypeId::of::<f32>()
}

/// An f32 vector of `N` lanes and its lane mask. Every method is `#[inline(always)]` so that it
/// compiles inside the `#[target_feature]` kernel that calls it.
#[allow(clippy::missing_safety_doc)]
#[allow(missing_docs)]
pub trait Lanes: Copy {
    const N: usize;
    type M: Copy;
    unsafe fn splat(v: f32) -> Self;
    /// `[0, 1, 2, ...]`.
    unsafe fn iota() -> Self;
    unsafe fn load(p: *const f32) -> Self;
    unsafe fn store(self, p: *mut f32);
    /// Lanes `0..N/2` set to `lo`, the others to `hi`.
    unsafe fn halves(lo: f32, hi: f32) -> Self;
    /// `[0, 1, .., N/2 - 1, 0, 1, .., N/2 - 1]`.
    unsafe fn iota2() -> Self;
    /// `N/2` lanes from `lo`, then `N/2` from `hi`.
    unsafe fn load2(lo: *const f32, hi: *const f32) -> Self;
    /// Lanes `0..N/2` to `lo`, the others to `hi` (the two ranges must not overlap).
    unsafe fn store2(self, lo: *mut f32, hi: *mut f32);
    /// Stores the lanes of `m` to `p`, leaving the others as they are.
    #[inline(always)]
    unsafe fn store_where(self, m: Self::M, p: *mut f32) {
        Self::select(m, self, Self::load(p)).store(p)
    }
    /// [`Lanes::store2`] of the lanes of `m`, leaving the others as they are.
    #[inline(always)]
    unsafe fn store2_where(self, m: Self::M, lo: *mut f32, hi: *mut f32) {
        Self::select(m, self, Self::load2(lo, hi)).store2(lo, hi)
    }
    unsafe fn add(self, o: Self) -> Self;
    unsafe fn sub(self, o: Self) -> Self;
    unsafe fn mul(self, o: Self) -> Self;
    /// `self * a + b` with one rounding (FMA): for the backward's per-lane sums, and where a value
    /// must match the scalar path bit for bit only if the scalar path calls `mul_add` there too.
    unsafe fn mul_add(self, a: Self, b: Self) -> Self;
    unsafe fn div(self, o: Self) -> Self;
    /// Correctly rounded square root (as `f32::sqrt`).
    unsafe fn sqrt(self) -> Self;
    /// Rounded toward zero (as `f32::trunc`).
    unsafe fn trunc(self) -> Self;
    /// The lanes truncated to i32 (as `v as i32` for values in its range), stored to `p`.
    unsafe fn store_i32(self, p: *mut i32);
    unsafe fn lt(self, o: Self) -> Self::M;
    unsafe fn le(self, o: Self) -> Self::M;
    unsafe fn gt(self, o: Self) -> Self::M;
    unsafe fn ge(self, o: Self) -> Self::M;
    /// `!=` as Rust's (true when either is NaN).
    unsafe fn ne(self, o: Self) -> Self::M;
    /// `m ? a : b` per lane.
    unsafe fn select(m: Self::M, a: Self, b: Self) -> Self;
    unsafe fn and(a: Self::M, b: Self::M) -> Self::M;
    /// `a & !b`.
    unsafe fn andnot(a: Self::M, b: Self::M) -> Self::M;
    /// Lane `i` of the mask as bit `i`.
    unsafe fn bits(m: Self::M) -> u32;
    /// The mask with lane `i` set when bit `i` is.
    unsafe fn from_bits(b: u32) -> Self::M;
    /// Sum of the lanes (pairwise; not the scalar order).
    unsafe fn hsum(self) -> f32;
    /// `[v[0].hsum(), .., v[7].hsum()]` to the bit. The lane types override it with one sum tree
    /// over all eight vectors (the same pairs added in the same order as [`Lanes::hsum`]), which
    /// takes a third of the instructions of eight separate sums.
    #[inline(always)]
    unsafe fn hsum8(v: &[Self; 8]) -> [f32; 8] {
        [v[0].hsum(), v[1].hsum(), v[2].hsum(), v[3].hsum(), v[4].hsum(), v[5].hsum(), v[6].hsum(), v[7].hsum()]
    }
    /// `svgir_core::float::exp_f32` per lane, same operations in the same order.
    #[inline(always)]
    unsafe fn exp_fast(self) -> Self {
        exp_fast_k([self])[0]
    }
    /// `2^n` from `t = x log2(e) + 1.5 * 2^23`, whose low mantissa bits hold `n + 2^22` (integer
    /// operations, as `svgir_core::float::exp_f32`).
    unsafe fn pow2_shifted(t: Self) -> Self;
    /// `if o < self { o } else { self }` per lane: `self` when they are equal or `o` is NaN (the
    /// scalar kernels' `min`). One instruction where a compare and a select are two, and a
    /// shorter chain for the tile kernels to wait on.
    #[inline(always)]
    unsafe fn min(self, o: Self) -> Self {
        Self::select(o.lt(self), o, self)
    }
    /// `if o > self { o } else { self }` per lane (the scalar kernels' `max`).
    #[inline(always)]
    unsafe fn max(self, o: Self) -> Self {
        Self::select(o.gt(self), o, self)
    }
    /// `f32::clamp(self, -87, 88)` (a NaN lane stays NaN).
    #[inline(always)]
    unsafe fn clamp_exp(self) -> Self {
        self.max(Self::splat(-87.0)).min(Self::splat(88.0))
    }
}

/// [`Lanes::exp_fast`] of `K` vectors, each step taken for all of them before the next: the
/// steps of one vector form a chain of dependent operations that the tile kernels wait on, and
/// written side by side, the chains of several lane groups overlap. Per vector, the operations
/// of `svgir_core::float::exp_f32` in its order, so the same bits.
///
/// # Safety
/// The CPU has the features of `S`.
#[inline(always)]
pub unsafe fn exp_fast_k<S: Lanes, const K: usize>(x: [S; K]) -> [S; K] {
    // Plain loops over the K vectors: closures (`map`, `from_fn`) are compiled without the
    // kernel's CPU features and their lane operations stay calls.
    let z = S::splat(0.0);
    let (mut t, mut r, mut p) = ([z; K], [z; K], [z; K]);
    let shifter = S::splat(12_582_912.0);
    for i in 0..K {
        let xc = x[i].clamp_exp();
        t[i] = xc.mul(S::splat(std::f32::consts::LOG2_E)).add(shifter);
        let n = t[i].sub(shifter);
        r[i] = xc.sub(n.mul(S::splat(0.693_145_75))).sub(n.mul(S::splat(1.428_606_8e-6)));
    }
    // Estrin's scheme, as the scalar code groups it.
    for i in 0..K {
        let r = r[i];
        let r2 = r.mul(r);
        let r4 = r2.mul(r2);
        let a = S::splat(1.0).add(r);
        let b = S::splat(0.5).add(r.mul(S::splat(1.0 / 6.0)));
        let c = S::splat(1.0 / 24.0).add(r.mul(S::splat(1.0 / 120.0)));
        let d = c.add(r2.mul(S::splat(1.0 / 720.0)));
        p[i] = a.add(r2.mul(b)).add(r4.mul(d));
    }
    for i in 0..K {
        p[i] = p[i].mul(S::pow2_shifted(t[i]));
    }
    p
}

#[cfg(target_arch = "x86_64")]
pub use x86::{F8k, F8};

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::Lanes;
    use std::arch::x86_64::*;

    /// The methods of an 8-lane type over `__m256` that do not involve masks.
    macro_rules! lanes8 {
        ($t:ident) => {
            const N: usize = 8;
            #[inline(always)]
            unsafe fn splat(v: f32) -> Self {
                $t(_mm256_set1_ps(v))
            }
            #[inline(always)]
            unsafe fn iota() -> Self {
                $t(_mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0))
            }
            #[inline(always)]
            unsafe fn load(p: *const f32) -> Self {
                $t(_mm256_loadu_ps(p))
            }
            #[inline(always)]
            unsafe fn store(self, p: *mut f32) {
                _mm256_storeu_ps(p, self.0)
            }
            #[inline(always)]
            unsafe fn halves(lo: f32, hi: f32) -> Self {
                $t(_mm256_set_m128(_mm_set1_ps(hi), _mm_set1_ps(lo)))
            }
            #[inline(always)]
            unsafe fn iota2() -> Self {
                $t(_mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 0.0, 1.0, 2.0, 3.0))
            }
            #[inline(always)]
            unsafe fn load2(lo: *const f32, hi: *const f32) -> Self {
                $t(_mm256_loadu2_m128(hi, lo))
            }
            #[inline(always)]
            unsafe fn store2(self, lo: *mut f32, hi: *mut f32) {
                _mm256_storeu2_m128(hi, lo, self.0)
            }
            #[inline(always)]
            unsafe fn add(self, o: Self) -> Self {
                $t(_mm256_add_ps(self.0, o.0))
            }
            #[inline(always)]
            unsafe fn sub(self, o: Self) -> Self {
                $t(_mm256_sub_ps(self.0, o.0))
            }
            #[inline(always)]
            unsafe fn mul(self, o: Self) -> Self {
                $t(_mm256_mul_ps(self.0, o.0))
            }
            #[inline(always)]
            unsafe fn mul_add(self, a: Self, b: Self) -> Self {
                $t(_mm256_fmadd_ps(self.0, a.0, b.0))
            }
            #[inline(always)]
            unsafe fn min(self, o: Self) -> Self {
                // `minps a, b` is `a < b ? a : b`.
                $t(_mm256_min_ps(o.0, self.0))
            }
            #[inline(always)]
            unsafe fn max(self, o: Self) -> Self {
                $t(_mm256_max_ps(o.0, self.0))
            }
            #[inline(always)]
            unsafe fn div(self, o: Self) -> Self {
                $t(_mm256_div_ps(self.0, o.0))
            }
            #[inline(always)]
            unsafe fn sqrt(self) -> Self {
                $t(_mm256_sqrt_ps(self.0))
            }
            #[inline(always)]
            unsafe fn trunc(self) -> Self {
                $t(_mm256_round_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(self.0))
            }
            #[inline(always)]
            unsafe fn store_i32(self, p: *mut i32) {
                _mm256_storeu_si256(p as *mut __m256i, _mm256_cvttps_epi32(self.0))
            }
            #[inline(always)]
            unsafe fn hsum(self) -> f32 {
                let s = _mm_add_ps(_mm256_castps256_ps128(self.0), _mm256_extractf128_ps::<1>(self.0));
                let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
                let s = _mm_add_ss(s, _mm_shuffle_ps::<1>(s, s));
                _mm_cvtss_f32(s)
            }
            #[inline(always)]
            unsafe fn hsum8(v: &[Self; 8]) -> [f32; 8] {
                // `hsum`'s tree for eight vectors at once, written out (a closure would be
                // compiled without the lane features). The 128-bit halves added, lo + hi:
                // [a' | b'] for the pair (a, b), four lanes each.
                let (a, b, c, d) = (v[0].0, v[1].0, v[2].0, v[3].0);
                let (e, f, g, h) = (v[4].0, v[5].0, v[6].0, v[7].0);
                let ab = _mm256_add_ps(_mm256_permute2f128_ps::<0x20>(a, b), _mm256_permute2f128_ps::<0x31>(a, b));
                let cd = _mm256_add_ps(_mm256_permute2f128_ps::<0x20>(c, d), _mm256_permute2f128_ps::<0x31>(c, d));
                let ef = _mm256_add_ps(_mm256_permute2f128_ps::<0x20>(e, f), _mm256_permute2f128_ps::<0x31>(e, f));
                let gh = _mm256_add_ps(_mm256_permute2f128_ps::<0x20>(g, h), _mm256_permute2f128_ps::<0x31>(g, h));
                // Lanes 0 + 2 and 1 + 3 of each: [a, c | b, d] and [e, g | f, h], two lanes each.
                let abcd = _mm256_add_ps(_mm256_shuffle_ps::<0x44>(ab, cd), _mm256_shuffle_ps::<0xEE>(ab, cd));
                let efgh = _mm256_add_ps(_mm256_shuffle_ps::<0x44>(ef, gh), _mm256_shuffle_ps::<0xEE>(ef, gh));
                // (0 + 2) + (1 + 3): [a, c, e, g | b, d, f, h].
                let r = _mm256_add_ps(_mm256_shuffle_ps::<0x88>(abcd, efgh), _mm256_shuffle_ps::<0xDD>(abcd, efgh));
                let mut t = [0f32; 8];
                _mm256_storeu_ps(t.as_mut_ptr(), r);
                [t[0], t[4], t[1], t[5], t[2], t[6], t[3], t[7]]
            }
            #[inline(always)]
            unsafe fn pow2_shifted(t: Self) -> Self {
                let ni = _mm256_sub_epi32(_mm256_castps_si256(t.0), _mm256_set1_epi32(0x4B40_0000));
                let bits = _mm256_slli_epi32::<23>(_mm256_add_epi32(ni, _mm256_set1_epi32(127)));
                $t(_mm256_castsi256_ps(bits))
            }
        };
    }

    /// `m ? a : b` per lane, as `_mm256_blendv_ps`, but out of LLVM's sight.
    ///
    /// Given `store(p, blendv(m, x, load(p)))` -- how the kernels write the lanes of a mask to
    /// their tile arrays -- LLVM emits one `vmaskmovps` store instead of the blend and a plain
    /// store. On AMD Zen 3 that masked store is slow, and a masked store does not forward to
    /// the next entry's load of the same pixels: the forward tile kernel spent about a quarter
    /// of its samples behind those stores, and the blend with a plain store took it from 80 to
    /// 54-59 ms on one thread (docs/performance.md, "Masked stores on AVX2"). The blend in
    /// `asm!` is the same instruction, so every lane keeps its bits.
    #[target_feature(enable = "avx")]
    #[inline]
    unsafe fn blend_opaque(m: __m256, a: __m256, b: __m256) -> __m256 {
        let r: __m256;
        std::arch::asm!(
            "vblendvps {r}, {b}, {a}, {m}",
            r = lateout(ymm_reg) r,
            a = in(ymm_reg) a,
            b = in(ymm_reg) b,
            m = in(ymm_reg) m,
            options(pure, nomem, nostack)
        );
        r
    }

    /// 8 f32 lanes with vector masks (AVX2).
    #[derive(Clone, Copy)]
    pub struct F8(__m256);

    impl Lanes for F8 {
        type M = __m256;
        lanes8!(F8);
        #[inline(always)]
        unsafe fn lt(self, o: Self) -> __m256 {
            _mm256_cmp_ps::<_CMP_LT_OQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn le(self, o: Self) -> __m256 {
            _mm256_cmp_ps::<_CMP_LE_OQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn gt(self, o: Self) -> __m256 {
            _mm256_cmp_ps::<_CMP_GT_OQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn ge(self, o: Self) -> __m256 {
            _mm256_cmp_ps::<_CMP_GE_OQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn ne(self, o: Self) -> __m256 {
            _mm256_cmp_ps::<_CMP_NEQ_UQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn select(m: __m256, a: Self, b: Self) -> Self {
            F8(blend_opaque(m, a.0, b.0))
        }
        #[inline(always)]
        unsafe fn and(a: __m256, b: __m256) -> __m256 {
            _mm256_and_ps(a, b)
        }
        #[inline(always)]
        unsafe fn andnot(a: __m256, b: __m256) -> __m256 {
            _mm256_andnot_ps(b, a)
        }
        #[inline(always)]
        unsafe fn bits(m: __m256) -> u32 {
            _mm256_movemask_ps(m) as u32
        }
        #[inline(always)]
        unsafe fn from_bits(b: u32) -> __m256 {
            let sel = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
            let v = _mm256_and_si256(_mm256_set1_epi32(b as i32), sel);
            _mm256_castsi256_ps(_mm256_cmpeq_epi32(v, sel))
        }
    }

    /// 8 f32 lanes with mask registers (AVX-512F + VL): compares write `k` registers, selects
    /// and masked stores take them directly, and the kernels get 32 vector registers.
    #[derive(Clone, Copy)]
    pub struct F8k(__m256);

    impl Lanes for F8k {
        type M = __mmask8;
        lanes8!(F8k);
        #[inline(always)]
        unsafe fn lt(self, o: Self) -> __mmask8 {
            _mm256_cmp_ps_mask::<_CMP_LT_OQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn le(self, o: Self) -> __mmask8 {
            _mm256_cmp_ps_mask::<_CMP_LE_OQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn gt(self, o: Self) -> __mmask8 {
            _mm256_cmp_ps_mask::<_CMP_GT_OQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn ge(self, o: Self) -> __mmask8 {
            _mm256_cmp_ps_mask::<_CMP_GE_OQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn ne(self, o: Self) -> __mmask8 {
            _mm256_cmp_ps_mask::<_CMP_NEQ_UQ>(self.0, o.0)
        }
        #[inline(always)]
        unsafe fn select(m: __mmask8, a: Self, b: Self) -> Self {
            F8k(_mm256_mask_blend_ps(m, b.0, a.0))
        }
        #[inline(always)]
        unsafe fn and(a: __mmask8, b: __mmask8) -> __mmask8 {
            a & b
        }
        #[inline(always)]
        unsafe fn andnot(a: __mmask8, b: __mmask8) -> __mmask8 {
            a & !b
        }
        #[inline(always)]
        unsafe fn bits(m: __mmask8) -> u32 {
            m as u32
        }
        #[inline(always)]
        unsafe fn from_bits(b: u32) -> __mmask8 {
            b as __mmask8
        }
        #[inline(always)]
        unsafe fn store_where(self, m: __mmask8, p: *mut f32) {
            _mm256_mask_storeu_ps(p, m, self.0)
        }
        #[inline(always)]
        unsafe fn store2_where(self, m: __mmask8, lo: *mut f32, hi: *mut f32) {
            _mm_mask_storeu_ps(lo, m & 0xF, _mm256_castps256_ps128(self.0));
            _mm_mask_storeu_ps(hi, m >> 4, _mm256_extractf128_ps::<1>(self.0));
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;

    /// `select`, `store_where` and `store2_where` of every 8-lane mask, against the lanes
    /// picked one by one: the AVX2 blend is written in `asm!`, whose operand order no compiler
    /// checks.
    unsafe fn masked_lanes_are_picked<S: Lanes>() {
        let a: [f32; 8] = std::array::from_fn(|i| i as f32 + 0.5);
        let b: [f32; 8] = std::array::from_fn(|i| -(i as f32) - 10.0);
        for bits in 0..256u32 {
            let m = S::from_bits(bits);
            assert_eq!(S::bits(m), bits);
            let want: [f32; 8] = std::array::from_fn(|i| if bits >> i & 1 == 1 { a[i] } else { b[i] });
            let mut got = [0f32; 8];
            S::select(m, S::load(a.as_ptr()), S::load(b.as_ptr())).store(got.as_mut_ptr());
            assert_eq!(got, want, "select, mask {bits:08b}");
            let mut mem = b;
            S::load(a.as_ptr()).store_where(m, mem.as_mut_ptr());
            assert_eq!(mem, want, "store_where, mask {bits:08b}");
            // The two halves to two places, with untouched floats between them.
            let mut mem2 = [7f32; 12];
            mem2[..4].copy_from_slice(&b[..4]);
            mem2[8..].copy_from_slice(&b[4..]);
            let p = mem2.as_mut_ptr();
            S::load(a.as_ptr()).store2_where(m, p, p.add(8));
            assert_eq!(mem2[..4], want[..4], "store2_where low half, mask {bits:08b}");
            assert_eq!(mem2[8..], want[4..], "store2_where high half, mask {bits:08b}");
            assert_eq!(mem2[4..8], [7.0; 4], "store2_where wrote between the halves");
        }
    }

    /// `hsum8` against eight `hsum`s, bit for bit, on sums whose value depends on the order of
    /// the additions (magnitudes from 1e-6 to 1e6, both signs).
    unsafe fn hsum8_is_eight_hsums<S: Lanes>() {
        let mut rng = crate::Rng::new(8);
        for case in 0..2000 {
            let vals: [[f32; 8]; 8] =
                std::array::from_fn(|_| std::array::from_fn(|_| rng.normal() * 10f32.powf(rng.range(-6.0, 6.0))));
            let v: [S; 8] = std::array::from_fn(|k| S::load(vals[k].as_ptr()));
            let got = S::hsum8(&v);
            for k in 0..8 {
                assert_eq!(got[k].to_bits(), v[k].hsum().to_bits(), "case {case} vector {k}: {vals:?}");
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    unsafe fn sums_avx2() {
        hsum8_is_eight_hsums::<F8>();
    }

    #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
    unsafe fn sums_avx512() {
        hsum8_is_eight_hsums::<F8k>();
    }

    #[test]
    fn eight_sums_at_once_keep_each_sums_bits() {
        on_each_lane_type(sums_avx2, sums_avx512);
    }

    /// `min`, `max` and `clamp_exp` against their definitions by compare and select (the scalar
    /// kernels' `if o < self { o } else { self }` and `f32::clamp`), bit for bit, on every pair
    /// of special and ordinary values: NaN, both zeros, infinities, equal values, the clamp's ends.
    unsafe fn min_max_are_the_selects<S: Lanes>() {
        let vals = [
            f32::NAN,
            0.0,
            -0.0,
            1.0,
            -1.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -87.0,
            88.0,
            -90.0,
            1e30,
            0.99,
            0.990_000_1,
            f32::MIN_POSITIVE,
        ];
        for (i, &a) in vals.iter().enumerate() {
            for b in vals.iter().cycle().skip(i).take(8) {
                let (la, lb) = (S::splat(a), S::splat(*b));
                let mut got = [[0f32; 8]; 3];
                la.min(lb).store(got[0].as_mut_ptr());
                la.max(lb).store(got[1].as_mut_ptr());
                la.clamp_exp().store(got[2].as_mut_ptr());
                let want_min = if *b < a { *b } else { a };
                let want_max = if *b > a { *b } else { a };
                assert_eq!(got[0][3].to_bits(), want_min.to_bits(), "min({a}, {b})");
                assert_eq!(got[1][5].to_bits(), want_max.to_bits(), "max({a}, {b})");
                assert_eq!(got[2][7].to_bits(), a.clamp(-87.0, 88.0).to_bits(), "clamp_exp({a})");
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    unsafe fn min_max_avx2() {
        min_max_are_the_selects::<F8>();
    }

    #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
    unsafe fn min_max_avx512() {
        min_max_are_the_selects::<F8k>();
    }

    #[test]
    fn min_and_max_are_the_scalar_selects() {
        on_each_lane_type(min_max_avx2, min_max_avx512);
    }

    #[target_feature(enable = "avx2,fma")]
    unsafe fn check_avx2() {
        masked_lanes_are_picked::<F8>();
    }

    #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
    unsafe fn check_avx512() {
        masked_lanes_are_picked::<F8k>();
    }

    #[test]
    fn masked_writes_pick_the_mask_lanes() {
        on_each_lane_type(check_avx2, check_avx512);
    }

    /// Runs `avx2` where the CPU has AVX2 and FMA and `avx512` where it has AVX-512F+VL, saying
    /// which were skipped.
    fn on_each_lane_type(avx2: unsafe fn(), avx512: unsafe fn()) {
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            // SAFETY: the features were just detected.
            unsafe { avx2() };
        } else {
            eprintln!("SKIPPED: this CPU has no AVX2, so the 8-lane type cannot run here");
        }
        if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vl") {
            // SAFETY: the features were just detected.
            unsafe { avx512() };
        } else {
            eprintln!("SKIPPED: this CPU has no AVX-512, so the mask-register type is not checked here");
        }
    }
}
