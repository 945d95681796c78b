//! Compact number formats for micro-buffers: IEEE binary16 (round to nearest even) and 16-bit
//! unsigned-normalised values. Hand-written to avoid a dependency; the f16 conversion is checked
//! exhaustively against its inverse.

/// f32 -> IEEE half bits, round to nearest even; overflow gives +-inf, NaN stays NaN.
pub fn f16_from_f32(x: f32) -> u16 {
    let b = x.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32;
    let man = b & 0x007f_ffff;
    if exp == 0xff {
        return sign | 0x7c00 | if man != 0 { 0x200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    if e <= 0 {
        // Subnormal half (or zero): value = m * 2^(exp-150), unit 2^-24, so shift by 14 - e.
        if e < -10 {
            return sign;
        }
        let m = man | 0x0080_0000;
        let shift = (14 - e) as u32;
        let half = 1u32 << (shift - 1);
        let rem = m & ((1u32 << shift) - 1);
        let mut r = m >> shift;
        if rem > half || (rem == half && (r & 1) == 1) {
            r += 1;
        }
        return sign | r as u16;
    }
    let mut r = ((e as u32) << 10) | (man >> 13);
    let rem = man & 0x1fff;
    if rem > 0x1000 || (rem == 0x1000 && (r & 1) == 1) {
        r += 1; // a carry into the exponent is the correct rounding (up to inf)
    }
    sign | r as u16
}

/// Decode IEEE half-precision bits to f32 (exact, subnormals, inf and NaN included).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = ((h & 0x8000) as u32) << 16;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x3ff) as u32;
    if exp == 0 {
        let v = man as f32 * (1.0 / 16_777_216.0);
        return if sign != 0 { -v } else { v };
    }
    if exp == 31 {
        return f32::from_bits(sign | 0x7f80_0000 | (man << 13));
    }
    f32::from_bits(sign | ((exp + 112) << 23) | (man << 13))
}

/// Quantise `x` clamped to [0, 1] to u16 unorm, rounding to nearest.
#[inline]
pub fn unorm16(x: f32) -> u16 {
    (x.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16
}

/// Decode a u16 unorm to [0, 1].
#[inline]
pub fn from_unorm16(q: u16) -> f32 {
    q as f32 * (1.0 / 65535.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_round_trips_exhaustively_and_rounds_to_nearest() {
        for h in 0..=u16::MAX {
            let x = f16_to_f32(h);
            if x.is_nan() {
                assert!(f16_to_f32(f16_from_f32(x)).is_nan());
            } else {
                assert_eq!(f16_from_f32(x), h, "{h:#06x} -> {x}");
            }
        }
        assert_eq!(f16_to_f32(f16_from_f32(1.0)), 1.0);
        assert_eq!(f16_to_f32(f16_from_f32(65504.0)), 65504.0);
        assert!(f16_to_f32(f16_from_f32(1e6)).is_infinite());
        // Ties go to even: 1 + 2^-11 is halfway between 1 and 1 + 2^-10.
        assert_eq!(f16_to_f32(f16_from_f32(1.0 + 2f32.powi(-11))), 1.0);
        assert_eq!(f16_to_f32(f16_from_f32(1.0 + 3.0 * 2f32.powi(-11))), 1.0 + 2.0 * 2f32.powi(-10));
        // Nearest: relative error <= 2^-11 over the radiance range [1e-4, 10].
        let mut rng = svgir_core::Rng::new(5);
        for _ in 0..100_000 {
            let x = 10f32.powf(rng.range(-4.0, 1.0));
            let y = f16_to_f32(f16_from_f32(x));
            assert!(((y - x) / x).abs() <= 2f32.powi(-11) * 1.0001, "{x} -> {y}");
        }
        for q in [0u16, 1, 32767, 65535] {
            assert_eq!(unorm16(from_unorm16(q)), q);
        }
    }
}
