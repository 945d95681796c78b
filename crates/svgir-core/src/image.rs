//! A plain f32 image: row-major, interleaved channels.

/// `data[(y * width + x) * channels + c]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Interleaved values per pixel (1, 3 or 4 in practice).
    pub channels: u32,
    /// Pixel values, row-major, channels interleaved.
    pub data: Vec<f32>,
}

impl Image {
    /// A zero-filled `width` x `height` image with `channels` channels.
    pub fn new(width: u32, height: u32, channels: u32) -> Self {
        Self { width, height, channels, data: vec![0.0; width as usize * height as usize * channels as usize] }
    }

    /// Wrap row-major interleaved `data`; panics if its length is not width x height x channels.
    pub fn from_data(width: u32, height: u32, channels: u32, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width as usize * height as usize * channels as usize, "image data length");
        Self { width, height, channels, data }
    }

    /// An image with every pixel equal to `value` (its length is the channel count).
    pub fn filled(width: u32, height: u32, value: &[f32]) -> Self {
        let channels = value.len() as u32;
        let data = value.iter().copied().cycle().take(width as usize * height as usize * channels as usize).collect();
        Self { width, height, channels, data }
    }

    /// Number of pixels, width x height.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The channels of pixel (x, y), x from the left, y from the top.
    #[inline]
    pub fn pixel(&self, x: u32, y: u32) -> &[f32] {
        let c = self.channels as usize;
        let i = (y * self.width + x) as usize * c;
        &self.data[i..i + c]
    }

    /// Mutable channels of pixel (x, y), x from the left, y from the top.
    #[inline]
    pub fn pixel_mut(&mut self, x: u32, y: u32) -> &mut [f32] {
        let c = self.channels as usize;
        let i = (y * self.width + x) as usize * c;
        &mut self.data[i..i + c]
    }

    /// A new image with only channels `range` (e.g. `0..3` for RGB of RGBA).
    pub fn select_channels(&self, range: std::ops::Range<u32>) -> Image {
        let c = self.channels as usize;
        let (a, b) = (range.start as usize, range.end as usize);
        assert!(a < b && b <= c, "channel range");
        let data = self.data.chunks_exact(c).flat_map(|p| p[a..b].iter().copied()).collect();
        Image::from_data(self.width, self.height, (b - a) as u32, data)
    }

    /// RGB from RGBA composited over a background colour: `rgb * a + bg * (1 - a)`.
    pub fn composite_over(&self, bg: [f32; 3]) -> Image {
        assert_eq!(self.channels, 4, "composite_over needs RGBA");
        use rayon::prelude::*;
        // In parallel: training composites a photo every iteration.
        let mut data = crate::par::filled(self.data.len() / 4 * 3, 0.0f32);
        data.par_chunks_exact_mut(3).zip(self.data.par_chunks_exact(4)).with_min_len(4096).for_each(|(o, p)| {
            for c in 0..3 {
                o[c] = p[c] * p[3] + bg[c] * (1.0 - p[3]);
            }
        });
        Image::from_data(self.width, self.height, 3, data)
    }

    /// A new image with `f` applied to every value.
    pub fn map(&self, f: impl Fn(f32) -> f32) -> Image {
        Image { data: self.data.iter().map(|&v| f(v)).collect(), ..*self }
    }

    /// Box (area) filter to a smaller size: each output pixel averages the input area it covers,
    /// with fractional weights at the edges, so any ratio works, not only integer factors.
    pub fn resize_area(&self, width: u32, height: u32) -> Image {
        let c = self.channels as usize;
        let xs = area_weights(self.width, width);
        let ys = area_weights(self.height, height);
        // Separable: horizontal pass then vertical.
        let mut tmp = vec![0.0f32; (width * self.height) as usize * c];
        for y in 0..self.height as usize {
            for (ox, taps) in xs.iter().enumerate() {
                let dst = &mut tmp[(y * width as usize + ox) * c..][..c];
                for &(ix, w) in taps {
                    let src = &self.data[(y * self.width as usize + ix) * c..][..c];
                    for k in 0..c {
                        dst[k] += w * src[k];
                    }
                }
            }
        }
        let mut out = Image::new(width, height, self.channels);
        for (oy, taps) in ys.iter().enumerate() {
            for x in 0..width as usize {
                let dst = &mut out.data[(oy * width as usize + x) * c..][..c];
                for &(iy, w) in taps {
                    let src = &tmp[(iy * width as usize + x) * c..][..c];
                    for k in 0..c {
                        dst[k] += w * src[k];
                    }
                }
            }
        }
        out
    }
}

/// For each of `n_out` output cells, the input cells it overlaps with normalised weights.
pub fn area_weights(n_in: u32, n_out: u32) -> Vec<Vec<(usize, f32)>> {
    let scale = n_in as f64 / n_out as f64;
    (0..n_out)
        .map(|o| {
            let (a, b) = (o as f64 * scale, (o + 1) as f64 * scale);
            let mut taps = Vec::new();
            let mut i = a.floor() as usize;
            while (i as f64) < b && i < n_in as usize {
                let overlap = (b.min(i as f64 + 1.0) - a.max(i as f64)).max(0.0);
                if overlap > 0.0 {
                    taps.push((i, (overlap / scale) as f32));
                }
                i += 1;
            }
            taps
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_resize_preserves_mean_and_constants() {
        let w = 13;
        let h = 7;
        let data: Vec<f32> = (0..w * h).map(|i| (i * 37 % 11) as f32).collect();
        let img = Image::from_data(w, h, 1, data.clone());
        let small = img.resize_area(5, 3);
        let mean_in: f32 = data.iter().sum::<f32>() / (w * h) as f32;
        let mean_out: f32 = small.data.iter().sum::<f32>() / 15.0;
        assert!((mean_in - mean_out).abs() < 1e-4, "{mean_in} {mean_out}");
        let flat = Image::filled(9, 9, &[0.25, 0.5]).resize_area(4, 2);
        assert!(flat.data.chunks(2).all(|p| (p[0] - 0.25).abs() < 1e-6 && (p[1] - 0.5).abs() < 1e-6));
    }

    #[test]
    fn composite() {
        let img = Image::from_data(1, 1, 4, vec![1.0, 0.0, 0.0, 0.25]);
        assert_eq!(img.composite_over([0.0, 0.0, 1.0]).data, vec![0.25, 0.0, 0.75]);
    }
}
