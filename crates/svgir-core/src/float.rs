//! A minimal float abstraction so kernels run in f32 (production) and f64 (gradient checks
//! against finite differences) from one source. Shared by shading, tracing, PBR and metrics.

use std::fmt::Debug;
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// The float operations shared kernels need, implemented for f32 and f64.
pub trait Float:
    Copy
    + Debug
    + PartialOrd
    + Send
    + Sync
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
{
    /// Additive identity.
    const ZERO: Self;
    /// Multiplicative identity.
    const ONE: Self;
    /// Convert from f64 (rounding for f32).
    fn from_f64(x: f64) -> Self;
    /// Convert from f32 (exact).
    fn from_f32(x: f32) -> Self;
    /// Convert to f64 (exact).
    fn to_f64(self) -> f64;
    /// Convert to f32 (rounding for f64).
    fn to_f32(self) -> f32;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Natural exponential e^x.
    fn exp(self) -> Self;
    /// Base-2 exponential 2^x.
    fn exp2(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// `self` raised to the power `e`.
    fn powf(self, e: Self) -> Self;

    /// Larger of the two (plain comparison; callers never pass NaN).
    #[inline]
    fn maxf(self, o: Self) -> Self {
        if self > o {
            self
        } else {
            o
        }
    }

    /// Smaller of the two (plain comparison; callers never pass NaN).
    #[inline]
    fn minf(self, o: Self) -> Self {
        if self < o {
            self
        } else {
            o
        }
    }

    /// `self` limited to [lo, hi].
    #[inline]
    fn clampf(self, lo: Self, hi: Self) -> Self {
        self.maxf(lo).minf(hi)
    }
}

macro_rules! impl_float {
    ($t:ty) => {
        impl Float for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            #[inline]
            fn from_f64(x: f64) -> Self {
                x as $t
            }
            #[inline]
            fn from_f32(x: f32) -> Self {
                x as $t
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn to_f32(self) -> f32 {
                self as f32
            }
            #[inline]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline]
            fn exp2(self) -> Self {
                <$t>::exp2(self)
            }
            #[inline]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline]
            fn powf(self, e: Self) -> Self {
                <$t>::powf(self, e)
            }
        }
    };
}

impl_float!(f32);
impl_float!(f64);

/// Small 3-vector helpers on `[F; 3]`.
#[inline]
pub fn dot<F: Float>(a: [F; 3], b: [F; 3]) -> F {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Convert an f32 3-vector to `F`.
#[inline]
pub fn to_f<F: Float>(a: [f32; 3]) -> [F; 3] {
    a.map(F::from_f32)
}
