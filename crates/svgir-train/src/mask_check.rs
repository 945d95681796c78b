//! How far masks made from a reconstruction ([`crate::foreground`]) can be trusted, per photo
//! and overall, and the failures that must stop `svgir masks` instead of writing masks that
//! only look like an answer: foreground over nearly every pixel of every photo (an object on a
//! wall, or one the selection could not tell from its surroundings), or no foreground at all.
//!
//! A photo's confidence is the product of two terms, each 1 for a well-separated object:
//! - coverage: the share of foreground pixels, 1 between [`MIN_COVER`] and [`MAX_COVER`], falling
//!   linearly to 0 at no pixel and at [`FULL_COVER`];
//! - frame: 1 minus the share of the image's outermost pixel ring that is foreground. An object
//!   the photographer framed leaves most of the ring to its surroundings; a mask that holds the
//!   whole ring has not separated anything.
//!
//! The overall confidence is the median over the photos; the capture fails when it is below
//! [`MIN_CONFIDENCE`], and the failure names the cause.

use serde::Serialize;

/// Coverage below which a photo's object is suspiciously small (it may be cut away).
pub const MIN_COVER: f32 = 0.01;
/// Coverage above which a photo's mask is suspiciously large.
pub const MAX_COVER: f32 = 0.6;
/// Coverage at which the coverage term reaches 0: the mask is the photo.
pub const FULL_COVER: f32 = 0.95;
/// Below this overall confidence the masks are refused.
pub const MIN_CONFIDENCE: f32 = 0.3;

/// One photo's mask, as the check reads it.
#[derive(Clone, Debug, Serialize)]
pub struct ViewCheck {
    /// Share of the photo's pixels in the foreground.
    pub coverage: f32,
    /// Share of the image's outermost pixel ring in the foreground.
    pub border: f32,
    /// The photo's confidence in [0, 1] (module docs).
    pub confidence: f32,
}

/// Why masks were refused.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum MaskFailure {
    /// The foreground covers most of most photos (median coverage given).
    CoversEverything {
        /// Median share of the photos' pixels in the foreground.
        median_coverage: f32,
    },
    /// The foreground is (nearly) empty in most photos.
    Empty {
        /// Median share of the photos' pixels in the foreground.
        median_coverage: f32,
    },
    /// The foreground reaches the image borders all round in most photos: it is not a framed
    /// object.
    NotFramed {
        /// Median share of the border ring in the foreground.
        median_border: f32,
    },
}

impl std::fmt::Display for MaskFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MaskFailure::CoversEverything { median_coverage } => write!(
                f,
                "the foreground covers {:.0}% of the median photo: the object could not be told from its surroundings \
                 (an object on a wall, or a scene with no object in the middle)",
                100.0 * median_coverage
            ),
            MaskFailure::Empty { median_coverage } => write!(
                f,
                "the foreground covers {:.2}% of the median photo: no object was found where the cameras look",
                100.0 * median_coverage
            ),
            MaskFailure::NotFramed { median_border } => write!(
                f,
                "the foreground holds {:.0}% of the median photo's border: it is the surroundings, not a framed object",
                100.0 * median_border
            ),
        }
    }
}

/// The check of a capture's masks.
#[derive(Clone, Debug, Serialize)]
pub struct MaskCheck {
    /// Per photo, in the order given.
    pub views: Vec<ViewCheck>,
    /// Median of the photos' confidences.
    pub confidence: f32,
    /// Why the masks must not be used, if they must not.
    pub failure: Option<MaskFailure>,
}

fn median(mut v: Vec<f32>) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    v[v.len() / 2]
}

/// The check of one mask (`w x h`, 1 for foreground, 0 for background).
pub fn check_view(mask: &[f32], w: u32, h: u32) -> ViewCheck {
    let (w, h) = (w as usize, h as usize);
    let fg = |x: usize, y: usize| mask[y * w + x] >= 0.5;
    let coverage = mask.iter().filter(|&&m| m >= 0.5).count() as f32 / mask.len().max(1) as f32;
    let ring: Vec<(usize, usize)> = (0..w)
        .flat_map(|x| [(x, 0), (x, h - 1)])
        .chain((1..h.saturating_sub(1)).flat_map(|y| [(0, y), (w - 1, y)]))
        .collect();
    let border = ring.iter().filter(|&&(x, y)| fg(x, y)).count() as f32 / ring.len().max(1) as f32;
    let cover_term = if coverage < MIN_COVER {
        coverage / MIN_COVER
    } else if coverage <= MAX_COVER {
        1.0
    } else {
        ((FULL_COVER - coverage) / (FULL_COVER - MAX_COVER)).clamp(0.0, 1.0)
    };
    ViewCheck { coverage, border, confidence: cover_term * (1.0 - border) }
}

/// The check of a capture's masks: each `(mask, width, height)`.
pub fn check_masks(masks: &[(&[f32], u32, u32)]) -> MaskCheck {
    let views: Vec<ViewCheck> = masks.iter().map(|(m, w, h)| check_view(m, *w, *h)).collect();
    let confidence = median(views.iter().map(|v| v.confidence).collect());
    let median_coverage = median(views.iter().map(|v| v.coverage).collect());
    let median_border = median(views.iter().map(|v| v.border).collect());
    let cause = if median_coverage > MAX_COVER {
        MaskFailure::CoversEverything { median_coverage }
    } else if median_coverage < MIN_COVER {
        MaskFailure::Empty { median_coverage }
    } else {
        MaskFailure::NotFramed { median_border }
    };
    let failure = (confidence < MIN_CONFIDENCE).then_some(cause);
    MaskCheck { views, confidence, failure }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w x h` mask that is 1 inside the disk of `radius` (share of the width) round `centre`.
    fn disk(w: u32, h: u32, centre: (f32, f32), radius: f32) -> Vec<f32> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let (dx, dy) = (x as f32 / w as f32 - centre.0, y as f32 / w as f32 - centre.1);
                if dx.hypot(dy) < radius {
                    1.0
                } else {
                    0.0
                }
            })
            .collect()
    }

    #[test]
    fn a_framed_object_is_trusted() {
        let m = disk(64, 48, (0.5, 0.375), 0.25);
        let c = check_view(&m, 64, 48);
        assert!((c.coverage - 0.27).abs() < 0.02 && c.border == 0.0 && c.confidence == 1.0, "{c:?}");
        // An object cut by the photo's bottom edge is still trusted, a little less.
        let cut = disk(64, 48, (0.5, 0.7), 0.25);
        let c = check_view(&cut, 64, 48);
        assert!(c.border > 0.0 && c.confidence > 0.8, "{c:?}");
        let all = check_masks(&[(&m, 64, 48), (&cut, 64, 48), (&m, 64, 48)]);
        assert!(all.failure.is_none() && all.confidence == 1.0, "{all:?}");
    }

    #[test]
    fn masks_that_separate_nothing_are_refused_with_their_cause() {
        // All white but for specks, as on a capture of an object on a wall.
        let mut white = vec![1.0; 64 * 48];
        for i in (0..white.len()).step_by(97) {
            white[i] = 0.0;
        }
        let c = check_masks(&[(&white, 64, 48), (&white, 64, 48)]);
        assert!(matches!(c.failure, Some(MaskFailure::CoversEverything { .. })), "{c:?}");
        assert!(c.failure.unwrap().to_string().contains("wall"));
        // Nothing found.
        let empty = vec![0.0; 64 * 48];
        let c = check_masks(&[(&empty, 64, 48)]);
        assert!(matches!(c.failure, Some(MaskFailure::Empty { .. })), "{c:?}");
        // A band across the whole photo (a table top, the lower half): it holds the border.
        let band: Vec<f32> = (0..48).flat_map(|y| (0..64).map(move |_| if y >= 24 { 1.0 } else { 0.0 })).collect();
        let c = check_view(&band, 64, 48);
        assert!(c.coverage == 0.5 && c.border > 0.4 && c.confidence < 0.6, "{c:?}");
        // One bad photo among good ones does not sink the capture (the median), most bad do.
        let good = disk(64, 48, (0.5, 0.375), 0.25);
        let c = check_masks(&[(&good, 64, 48), (&white, 64, 48), (&good, 64, 48)]);
        assert!(c.failure.is_none(), "{c:?}");
        let c = check_masks(&[(&good, 64, 48), (&white, 64, 48), (&white, 64, 48)]);
        assert!(c.failure.is_some(), "{c:?}");
    }
}
