//! Normal error against a normal pass whose negative components were clipped to 0, as
//! NeRF-synthetic's `r_N_normal_0001.png` (`svgir-io/tests/nerf_normals.rs` shows they are).
//!
//! Where the stored vector still has unit length no component was clipped, so the true normal
//! is known exactly there; elsewhere it is not known at all. The pixels kept are chosen by the
//! ground truth alone (surfaces facing the +x, +y, +z octant), so the mean is not biased towards
//! pixels the render gets right; it is a subset of the object, not TensoIR's all-pixel protocol
//! (SPEC 8).

use glam::Vec3;

/// A stored normal counts as unclipped when its length is this close to 1.
pub const UNIT_TOLERANCE: f32 = 0.02;
/// A pixel belongs to the object when the photo's alpha is at least this.
pub const OBJECT_ALPHA: f32 = 0.5;
/// A rendered pixel with less opacity than this has no normal.
pub const EMPTY_ALPHA: f32 = 1e-3;
/// The error of an object pixel the render leaves empty.
pub const EMPTY_ERROR_DEG: f32 = 90.0;

/// What one pixel contributes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pixel {
    /// Not on the object.
    Background,
    /// On the object, but the stored normal was clipped.
    Unmeasured,
    /// Angular error in degrees.
    Error(f32),
}

/// Per pixel: the rendered normal sum (`H*W*3`, any length), the render's opacity (`H*W`), the
/// stored normal pass (`channels` per pixel, first three used) and the photo's alpha (`H*W`).
pub fn classify(
    render_normal: &[f32],
    render_alpha: &[f32],
    stored: &[f32],
    channels: usize,
    photo_alpha: &[f32],
) -> Vec<Pixel> {
    photo_alpha
        .iter()
        .enumerate()
        .map(|(p, &a)| {
            if a < OBJECT_ALPHA {
                return Pixel::Background;
            }
            let g = Vec3::from_slice(&stored[channels * p..][..3]);
            if (g.length() - 1.0).abs() > UNIT_TOLERANCE {
                return Pixel::Unmeasured;
            }
            let n = Vec3::from_slice(&render_normal[3 * p..][..3]);
            if render_alpha[p] < EMPTY_ALPHA || n.length() == 0.0 {
                return Pixel::Error(EMPTY_ERROR_DEG);
            }
            Pixel::Error(n.normalize().dot(g.normalize()).clamp(-1.0, 1.0).acos().to_degrees())
        })
        .collect()
}

/// Sums over pixels: error in degrees, measured pixels, object pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Tally {
    /// Sum of the measured pixels' errors, degrees.
    pub sum_deg: f64,
    /// Object pixels with an unclipped stored normal.
    pub measured: u64,
    /// All object pixels.
    pub object: u64,
}

impl Tally {
    /// The tally of one view's pixels.
    pub fn of(pixels: &[Pixel]) -> Self {
        pixels.iter().fold(Self::default(), |t, px| match px {
            Pixel::Background => t,
            Pixel::Unmeasured => Self { object: t.object + 1, ..t },
            Pixel::Error(e) => Self { sum_deg: t.sum_deg + *e as f64, measured: t.measured + 1, object: t.object + 1 },
        })
    }

    /// Both tallies together.
    pub fn merge(self, o: Self) -> Self {
        Self { sum_deg: self.sum_deg + o.sum_deg, measured: self.measured + o.measured, object: self.object + o.object }
    }

    /// Mean error over the measured pixels, `None` without any.
    pub fn mean_deg(&self) -> Option<f64> {
        (self.measured > 0).then(|| self.sum_deg / self.measured as f64)
    }

    /// Share of the object pixels that were measured.
    pub fn measured_share(&self) -> f64 {
        self.measured as f64 / self.object.max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_unclipped_object_pixels_are_measured() {
        // Pixels: background; clipped (0.6, 0, 0); exact up (rendered twice as long); up
        // against a render along x; up where the render is empty.
        let photo_alpha = [0.0, 1.0, 1.0, 0.8, 1.0];
        let stored = [
            0.3, 0.2, 0.1, 1.0, //
            0.6, 0.0, 0.0, 1.0, //
            0.0, 0.0, 1.0, 1.0, //
            0.0, 0.0, 1.0, 1.0, //
            0.0, 0.0, 1.0, 1.0,
        ];
        let render = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let alpha = [1.0, 1.0, 1.0, 1.0, 0.0];
        let px = classify(&render, &alpha, &stored, 4, &photo_alpha);
        assert_eq!(px[0], Pixel::Background);
        assert_eq!(px[1], Pixel::Unmeasured);
        assert!(matches!(px[2], Pixel::Error(e) if e.abs() < 1e-3));
        assert!(matches!(px[3], Pixel::Error(e) if (e - 90.0).abs() < 1e-3));
        assert_eq!(px[4], Pixel::Error(EMPTY_ERROR_DEG));
        let t = Tally::of(&px);
        assert_eq!((t.measured, t.object), (3, 4));
        assert!((t.mean_deg().unwrap() - 60.0).abs() < 1e-3);
        assert!((t.merge(t).measured_share() - 0.75).abs() < 1e-12);
        assert_eq!(Tally::of(&px[..2]).mean_deg(), None);
    }
}
