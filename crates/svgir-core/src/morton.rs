//! A Z-order (Morton) curve over points in a box: sorting by it puts points that are close in
//! space close in memory, so that passes which visit the Gaussians one view sees (a connected
//! part of the object) read contiguous runs of their per-Gaussian arrays instead of lines
//! scattered over all of them.

use glam::Vec3;

/// Bits per axis of [`morton_code`] (30 in all).
pub const BITS: u32 = 10;

/// The 10 low bits of `v` spread to every third bit (bit i to bit 3i).
#[inline]
fn spread(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x | x << 16) & 0x0300_00ff;
    x = (x | x << 8) & 0x0300_f00f;
    x = (x | x << 4) & 0x030c_30c3;
    x = (x | x << 2) & 0x0924_9249;
    x
}

/// The Morton code of `p` on a 2^10 grid over the box `[lo, hi]` (coordinates outside it
/// clamp to its faces; a flat axis maps to 0).
pub fn morton_code(p: Vec3, lo: Vec3, hi: Vec3) -> u32 {
    let cells = ((1u32 << BITS) - 1) as f32;
    let q = |x: f32, l: f32, h: f32| {
        let t = if h > l { (x - l) / (h - l) } else { 0.0 };
        // NaN clamps to 0 as well (`as` saturates).
        (t.clamp(0.0, 1.0) * cells) as u32
    };
    spread(q(p.x, lo.x, hi.x)) | spread(q(p.y, lo.y, hi.y)) << 1 | spread(q(p.z, lo.z, hi.z)) << 2
}

/// The indices of `points` in Morton order over the box `[lo, hi]` (their bounds, e.g.
/// [`crate::Surfels::bounds`]); ties keep index order, so the order is a function of the points
/// and the box alone.
pub fn morton_order(points: &[Vec3], lo: Vec3, hi: Vec3) -> Vec<usize> {
    let codes: Vec<u32> = points.iter().map(|p| morton_code(*p, lo, hi)).collect();
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by_key(|&i| (codes[i], i));
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The code interleaves the three axes' bits, x lowest; the order is a permutation that
    /// visits a grid's cells octant by octant.
    #[test]
    fn codes_interleave_the_axes_and_the_order_is_a_permutation() {
        let (lo, hi) = (Vec3::ZERO, Vec3::ONE);
        assert_eq!(morton_code(Vec3::ZERO, lo, hi), 0);
        assert_eq!(morton_code(Vec3::ONE, lo, hi), (1 << 30) - 1);
        assert_eq!(morton_code(Vec3::X, lo, hi), 0x0924_9249);
        assert_eq!(morton_code(Vec3::Y, lo, hi), 0x0924_9249 << 1);
        assert_eq!(morton_code(Vec3::Z, lo, hi), 0x0924_9249 << 2);
        assert_eq!(morton_code(Vec3::new(f32::NAN, 2.0, -1.0), lo, hi), 0x0924_9249 << 1);
        // A 4x4x4 grid in scrambled order: each octant's 8 points come out together.
        let mut pts = Vec::new();
        for i in 0..64u32 {
            let j = (i * 37) % 64;
            pts.push(Vec3::new((j % 4) as f32, (j / 4 % 4) as f32, (j / 16) as f32));
        }
        let order = morton_order(&pts, Vec3::ZERO, Vec3::splat(3.0));
        let mut seen = order.clone();
        seen.sort();
        assert_eq!(seen, (0..64).collect::<Vec<_>>());
        for block in order.chunks(8) {
            let oct = |p: Vec3| (p.x >= 2.0, p.y >= 2.0, p.z >= 2.0);
            assert!(block.iter().all(|&i| oct(pts[i]) == oct(pts[block[0]])), "an octant split: {block:?}");
        }
    }
}
