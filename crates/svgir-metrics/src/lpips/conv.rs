//! The two backbone kernels of LPIPS, on planar CHW f32 images: conv2d + bias + ReLU (fused) and
//! max-pooling (floor mode, no padding, as torchvision's VGG16 / AlexNet).
//!
//! Convolution is im2col + `matrixmultiply::sgemm`: out[Cout, P] = W[Cout, Cin k k] x col[Cin k k, P].
//! To keep memory bounded the output is produced in bands of whole rows (the col buffer holds at most
//! ~`BAND_FLOATS` values and is reused across bands and layers); sgemm writes each band straight into
//! its columns of the output planes, then bias + ReLU are applied to the band while it is in cache.
//! im2col, bias/ReLU and pooling are parallel over channels with rayon; sgemm runs its own threads
//! (`MATMUL_NUM_THREADS`, default the physical cores). 3x3 / stride 1 / pad 1 layers go through
//! Winograd F(4x4,3x3) instead (`winograd.rs`). Inference only: nothing is saved for backward.

use rayon::prelude::*;

use super::winograd;

/// Upper bound on the im2col band size in f32 values (32 MiB).
pub(crate) const BAND_FLOATS: usize = 8 << 20;

/// A conv layer in OIHW layout (`weight` is `cout x (cin k k)` row-major), square kernel.
#[derive(Clone, Debug)]
pub struct Conv {
    /// Output channels.
    pub cout: usize,
    /// Input channels.
    pub cin: usize,
    /// Kernel side length in pixels (square kernel).
    pub k: usize,
    /// Stride in pixels, both axes.
    pub stride: usize,
    /// Zero padding in pixels on every side.
    pub pad: usize,
    /// Weights in OIHW order, `cout x cin x k x k` row-major.
    pub weight: Vec<f32>,
    /// One bias per output channel.
    pub bias: Vec<f32>,
    /// Winograd-transformed weights for 3x3 / stride 1 / pad 1 layers, else empty.
    winograd: Vec<f32>,
}

/// Scratch memory of the conv kernels, reused across bands and layers.
#[derive(Default)]
pub struct ConvScratch {
    col: Vec<f32>,
    wino: winograd::Scratch,
}

impl Conv {
    /// A layer from its shape and weights (panics if the lengths disagree); precomputes Winograd weights for 3x3/stride 1/pad 1.
    pub fn new(cout: usize, cin: usize, k: usize, stride: usize, pad: usize, weight: Vec<f32>, bias: Vec<f32>) -> Self {
        assert_eq!(weight.len(), cout * cin * k * k, "conv weight size");
        assert_eq!(bias.len(), cout, "conv bias size");
        let winograd =
            if (k, stride, pad) == (3, 1, 1) { winograd::transform_weights(&weight, cout, cin) } else { Vec::new() };
        Self { cout, cin, k, stride, pad, weight, bias, winograd }
    }

    /// Output (height, width) for an `h x w` input, or None if the input is smaller than the kernel.
    pub fn out_size(&self, h: usize, w: usize) -> Option<(usize, usize)> {
        let (hp, wp) = (h + 2 * self.pad, w + 2 * self.pad);
        (hp >= self.k && wp >= self.k).then(|| ((hp - self.k) / self.stride + 1, (wp - self.k) / self.stride + 1))
    }

    /// `out = relu(conv(input) + bias)`; `input` is `cin x h x w`, `out` is resized to `cout x ho x wo`.
    /// `band_floats` bounds the scratch size of one band.
    pub fn forward_relu(
        &self,
        input: &[f32],
        h: usize,
        w: usize,
        out: &mut Vec<f32>,
        scratch: &mut ConvScratch,
        band_floats: usize,
    ) -> (usize, usize) {
        debug_assert_eq!(input.len(), self.cin * h * w);
        // Winograd measured faster than im2col at every VGG layer size down to 16x16.
        if !self.winograd.is_empty() {
            let (u, b) = (&self.winograd, &self.bias);
            winograd::conv3x3_relu(u, b, self.cin, self.cout, input, h, w, out, &mut scratch.wino, band_floats);
            return (h, w);
        }
        self.forward_relu_im2col(input, h, w, out, &mut scratch.col, band_floats)
    }

    /// The im2col + sgemm path (any kernel, stride, padding).
    pub fn forward_relu_im2col(
        &self,
        input: &[f32],
        h: usize,
        w: usize,
        out: &mut Vec<f32>,
        col: &mut Vec<f32>,
        band_floats: usize,
    ) -> (usize, usize) {
        let (ho, wo) = self.out_size(h, w).expect("caller checks the input size");
        let kk = self.cin * self.k * self.k;
        let plane = ho * wo;
        out.resize(self.cout * plane, 0.0);
        let rows_per_band = (band_floats / (kk * wo)).clamp(1, ho);
        let mut r0 = 0;
        while r0 < ho {
            let r1 = (r0 + rows_per_band).min(ho);
            let nb = (r1 - r0) * wo;
            col.resize(kk * nb, 0.0);
            self.im2col(input, h, w, wo, r0, r1, col);
            // SAFETY: A is cout x kk (row-major), B is kk x nb (row-major), C addresses columns
            // r0*wo .. r1*wo of each of the cout output planes (row stride `plane`), all in bounds.
            unsafe {
                matrixmultiply::sgemm(
                    self.cout,
                    kk,
                    nb,
                    1.0,
                    self.weight.as_ptr(),
                    kk as isize,
                    1,
                    col.as_ptr(),
                    nb as isize,
                    1,
                    0.0,
                    out.as_mut_ptr().add(r0 * wo),
                    plane as isize,
                    1,
                );
            }
            out.par_chunks_mut(plane).zip(&self.bias).for_each(|(p, &b)| {
                for v in &mut p[r0 * wo..r1 * wo] {
                    *v = (*v + b).max(0.0);
                }
            });
            r0 = r1;
        }
        (ho, wo)
    }

    /// Rows of the col matrix for output rows `r0..r1`: row (ci, ky, kx), column (r - r0) wo + ox.
    fn im2col(&self, input: &[f32], h: usize, w: usize, wo: usize, r0: usize, r1: usize, col: &mut [f32]) {
        let (k, s, p) = (self.k, self.stride, self.pad);
        let nb = (r1 - r0) * wo;
        col.par_chunks_mut(nb).enumerate().for_each(|(row, dst)| {
            let (ci, ky, kx) = (row / (k * k), row / k % k, row % k);
            let src = &input[ci * h * w..(ci + 1) * h * w];
            // Output columns whose input column ox*s + kx - p lies inside [0, w).
            let ox0 = p.saturating_sub(kx).div_ceil(s);
            let ox1 = if w + p > kx { ((w + p - kx - 1) / s + 1).min(wo) } else { 0 };
            for (r, d) in (r0..r1).zip(dst.chunks_exact_mut(wo)) {
                let iy = (r * s + ky) as isize - p as isize;
                if iy < 0 || iy >= h as isize || ox0 >= ox1 {
                    d.fill(0.0);
                    continue;
                }
                let srow = &src[iy as usize * w..(iy as usize + 1) * w];
                d[..ox0].fill(0.0);
                d[ox1..].fill(0.0);
                let ix0 = ox0 * s + kx - p;
                if s == 1 {
                    d[ox0..ox1].copy_from_slice(&srow[ix0..ix0 + (ox1 - ox0)]);
                } else {
                    for (j, v) in d[ox0..ox1].iter_mut().enumerate() {
                        *v = srow[ix0 + j * s];
                    }
                }
            }
        });
    }
}

/// Max-pooling `k x k`, stride `s`, floor mode; `input` is `c x h x w`. Returns (ho, wo).
pub fn max_pool(input: &[f32], c: usize, h: usize, w: usize, k: usize, s: usize, out: &mut Vec<f32>) -> (usize, usize) {
    let (ho, wo) = ((h - k) / s + 1, (w - k) / s + 1);
    out.resize(c * ho * wo, 0.0);
    out.par_chunks_mut(ho * wo).zip(input.par_chunks(h * w)).for_each(|(dst, src)| {
        for oy in 0..ho {
            for ox in 0..wo {
                let mut m = f32::NEG_INFINITY;
                for ky in 0..k {
                    let row = &src[(oy * s + ky) * w + ox * s..][..k];
                    for &v in row {
                        m = m.max(v);
                    }
                }
                dst[oy * wo + ox] = m;
            }
        }
    });
    (ho, wo)
}

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;

    fn naive_conv_relu(c: &Conv, x: &[f32], h: usize, w: usize) -> Vec<f32> {
        let (ho, wo) = c.out_size(h, w).unwrap();
        let mut out = vec![0.0f32; c.cout * ho * wo];
        for co in 0..c.cout {
            for oy in 0..ho {
                for ox in 0..wo {
                    let mut acc = c.bias[co] as f64;
                    for ci in 0..c.cin {
                        for ky in 0..c.k {
                            for kx in 0..c.k {
                                let iy = (oy * c.stride + ky) as isize - c.pad as isize;
                                let ix = (ox * c.stride + kx) as isize - c.pad as isize;
                                if iy >= 0 && ix >= 0 && (iy as usize) < h && (ix as usize) < w {
                                    let wv = c.weight[((co * c.cin + ci) * c.k + ky) * c.k + kx];
                                    acc += wv as f64 * x[(ci * h + iy as usize) * w + ix as usize] as f64;
                                }
                            }
                        }
                    }
                    out[(co * ho + oy) * wo + ox] = acc.max(0.0) as f32;
                }
            }
        }
        out
    }

    #[test]
    fn conv_matches_direct_loops() {
        let mut rng = Rng::new(1);
        // (cin, cout, k, stride, pad, h, w): VGG-like, AlexNet conv1-like, conv2-like; tiny bands too.
        for &(cin, cout, k, s, p, h, w) in &[
            (3, 5, 3, 1, 1, 9, 7),
            (6, 7, 3, 1, 1, 12, 10),
            (3, 4, 11, 4, 2, 23, 19),
            (4, 6, 5, 1, 2, 8, 10),
            (2, 3, 3, 1, 1, 1, 1),
            (2, 3, 3, 1, 1, 2, 3),
        ] {
            let weight = (0..cout * cin * k * k).map(|_| rng.range(-1.0, 1.0)).collect();
            let conv = Conv::new(cout, cin, k, s, p, weight, (0..cout).map(|_| rng.range(-0.5, 0.5)).collect());
            let x: Vec<f32> = (0..cin * h * w).map(|_| rng.range(-1.0, 1.0)).collect();
            let want = naive_conv_relu(&conv, &x, h, w);
            if want.len() > 20 {
                assert!(want.iter().any(|&v| v > 0.0) && want.contains(&0.0));
            }
            for band in [BAND_FLOATS, 1] {
                let (mut out, mut scratch, mut col) = (Vec::new(), ConvScratch::default(), Vec::new());
                conv.forward_relu(&x, h, w, &mut out, &mut scratch, band);
                assert_eq!(out.len(), want.len());
                // Winograd F(4x4,3x3) (3x3 layers) rounds differently: ~1e-5 of the terms' magnitude.
                for (a, b) in out.iter().zip(&want) {
                    assert!((a - b).abs() < 5e-5, "k{k} s{s} {h}x{w}: {a} vs {b}");
                }
                conv.forward_relu_im2col(&x, h, w, &mut out, &mut col, band);
                for (a, b) in out.iter().zip(&want) {
                    assert!((a - b).abs() < 1e-5, "im2col k{k} s{s}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn pool_matches_direct_max() {
        let mut rng = Rng::new(2);
        let (c, h, w) = (2, 15, 14);
        let x: Vec<f32> = (0..c * h * w).map(|_| rng.uniform()).collect();
        for (k, s) in [(2, 2), (3, 2)] {
            let mut out = Vec::new();
            let (ho, wo) = max_pool(&x, c, h, w, k, s, &mut out);
            assert_eq!((ho, wo), ((h - k) / s + 1, (w - k) / s + 1));
            for ch in 0..c {
                for oy in 0..ho {
                    for ox in 0..wo {
                        let mut m = f32::MIN;
                        for dy in 0..k {
                            for dx in 0..k {
                                m = m.max(x[(ch * h + oy * s + dy) * w + ox * s + dx]);
                            }
                        }
                        assert_eq!(out[(ch * ho + oy) * wo + ox], m);
                    }
                }
            }
        }
    }
}
