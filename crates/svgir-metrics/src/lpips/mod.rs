//! LPIPS v0.1 (Zhang et al. 2018) with the VGG16 and AlexNet backbones, as the `lpips` package
//! computes it: RGB in \[0,1\] -> \[-1,1\] -> ScalingLayer `(x - shift) / scale` -> backbone features at
//! five taps -> unit-normalise each feature vector over channels (`x / (|x| + 1e-10)`) -> squared
//! difference -> 1x1 linear head (non-negative weights) -> spatial mean -> sum over taps.
//!
//! Work split: both images run through the backbone layer by layer (a batch of two); each conv is
//! Winograd F(4x4,3x3) (3x3 layers, `winograd.rs`) or im2col + sgemm (`conv.rs`), in row bands;
//! the head runs on pixel chunks in parallel with rayon. Inference only, nothing saved for backward.

#[cfg(feature = "bench")]
mod bench;
mod conv;
mod net;
pub mod safetensors;
mod winograd;

#[cfg(feature = "bench")]
pub use bench::bench_table;
pub use conv::{max_pool, Conv, ConvScratch};
pub use net::Net;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use svgir_core::Image;

use crate::error::{MetricsError, Result};
use net::Op;

/// The lpips package's ScalingLayer constants (ImageNet statistics expressed for [-1,1] inputs).
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// `lpips.normalize_tensor` eps.
const NORM_EPS: f32 = 1e-10;

/// An LPIPS distance: the total and each tap's contribution (they sum to the total).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LpipsDistance {
    /// The LPIPS distance: sum of the per-layer terms.
    pub total: f32,
    /// Each tap's contribution (spatial mean of the weighted squared feature difference), in tap order.
    pub per_layer: Vec<f32>,
}

/// A loaded LPIPS model.
pub struct Lpips {
    net: Net,
    weights: net::Weights,
}

impl Lpips {
    /// Load from the bytes of an LPIPS safetensors file (`lpips_{vgg,alex}_v0.1.safetensors`).
    pub fn from_safetensors(bytes: &[u8], net: Net) -> Result<Self> {
        let weights = net::load(safetensors::parse(bytes)?, net)?;
        Ok(Self { net, weights })
    }

    /// The backbone this model was loaded for.
    pub fn net(&self) -> Net {
        self.net
    }

    /// LPIPS between two RGB images with values in [0, 1] (3 channels, same size).
    pub fn distance(&self, a: &Image, b: &Image) -> Result<LpipsDistance> {
        if a.channels != 3 || b.channels != 3 {
            return Err(MetricsError::ShapeMismatch(format!(
                "LPIPS needs RGB, got {} and {} channels",
                a.channels, b.channels
            )));
        }
        if (a.width, a.height) != (b.width, b.height) {
            return Err(MetricsError::ShapeMismatch(format!("{}x{} vs {}x{}", a.width, a.height, b.width, b.height)));
        }
        self.distance_rgb(&a.data, &b.data, a.width as usize, a.height as usize)
    }

    /// LPIPS between two interleaved RGB buffers (`w * h * 3` values in [0, 1]).
    pub fn distance_rgb(&self, a: &[f32], b: &[f32], w: usize, h: usize) -> Result<LpipsDistance> {
        for (name, img) in [("first", a), ("second", b)] {
            if img.len() != w * h * 3 {
                return Err(MetricsError::ShapeMismatch(format!(
                    "{name} image has {} values, expected {w}x{h}x3",
                    img.len()
                )));
            }
        }
        let mut act = [to_scaled_planar(a, w * h), to_scaled_planar(b, w * h)];
        let mut next: [Vec<f32>; 2] = [Vec::new(), Vec::new()];
        let mut scratch = ConvScratch::default();
        let (mut c, mut hh, mut ww) = (3usize, h, w);
        let mut per_layer = Vec::with_capacity(5);
        for op in self.net.ops() {
            match op {
                Op::Conv { index, .. } => {
                    let conv = &self.weights.convs[index];
                    if conv.out_size(hh, ww).is_none() {
                        return Err(too_small(self.net, w, h));
                    }
                    let mut size = (0, 0);
                    for i in 0..2 {
                        size = conv.forward_relu(&act[i], hh, ww, &mut next[i], &mut scratch, conv::BAND_FLOATS);
                    }
                    std::mem::swap(&mut act, &mut next);
                    (c, hh, ww) = (conv.cout, size.0, size.1);
                }
                Op::Pool { k, s } => {
                    if hh < k || ww < k {
                        return Err(too_small(self.net, w, h));
                    }
                    let mut size = (0, 0);
                    for i in 0..2 {
                        size = max_pool(&act[i], c, hh, ww, k, s, &mut next[i]);
                    }
                    std::mem::swap(&mut act, &mut next);
                    (hh, ww) = size;
                }
                Op::Tap => {
                    let head = &self.weights.heads[per_layer.len()];
                    per_layer.push(head_distance(&act[0], &act[1], c, hh * ww, head) as f32);
                }
            }
        }
        Ok(LpipsDistance { total: per_layer.iter().sum(), per_layer })
    }
}

fn too_small(net: Net, w: usize, h: usize) -> MetricsError {
    MetricsError::TooSmall(format!("{w}x{h} is too small for LPIPS-{}", net.name()))
}

/// Interleaved RGB in [0,1] -> planar CHW, scaled to [-1,1] then by the ScalingLayer.
fn to_scaled_planar(rgb: &[f32], pixels: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; 3 * pixels];
    out.par_chunks_mut(pixels).enumerate().for_each(|(c, plane)| {
        for (v, px) in plane.iter_mut().zip(rgb.chunks_exact(3)) {
            *v = ((px[c] * 2.0 - 1.0) - SHIFT[c]) / SCALE[c];
        }
    });
    out
}

/// One tap's term: spatial mean of `sum_c w_c (f0/|f0| - f1/|f1|)^2` (norms over channels).
fn head_distance(f0: &[f32], f1: &[f32], c: usize, pixels: usize, head: &[f32]) -> f64 {
    const CHUNK: usize = 256;
    let chunks = pixels.div_ceil(CHUNK);
    let sum: f64 = (0..chunks)
        .into_par_iter()
        .map(|ci| {
            let (p0, p1) = (ci * CHUNK, ((ci + 1) * CHUNK).min(pixels));
            let n = p1 - p0;
            let (mut n0, mut n1) = ([0.0f32; CHUNK], [0.0f32; CHUNK]);
            for ch in 0..c {
                let (r0, r1) = (&f0[ch * pixels + p0..][..n], &f1[ch * pixels + p0..][..n]);
                for j in 0..n {
                    n0[j] += r0[j] * r0[j];
                    n1[j] += r1[j] * r1[j];
                }
            }
            for j in 0..n {
                n0[j] = 1.0 / (n0[j].sqrt() + NORM_EPS);
                n1[j] = 1.0 / (n1[j].sqrt() + NORM_EPS);
            }
            let mut d = [0.0f32; CHUNK];
            for ch in 0..c {
                let (r0, r1) = (&f0[ch * pixels + p0..][..n], &f1[ch * pixels + p0..][..n]);
                let wc = head[ch];
                for j in 0..n {
                    let e = r0[j] * n0[j] - r1[j] * n1[j];
                    d[j] += wc * e * e;
                }
            }
            d[..n].iter().map(|&v| v as f64).sum::<f64>()
        })
        .sum();
    sum / pixels as f64
}

#[cfg(test)]
mod tests;
