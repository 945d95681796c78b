//! The two LPIPS backbones as layer tables (torchvision VGG16 / AlexNet `features`, up to the last
//! tap) and their weights, loaded from the LPIPS safetensors files (`features.convN.{weight,bias}`,
//! `linN.weight`, OIHW).

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::conv::Conv;
use super::safetensors::Tensor;
use crate::error::{MetricsError, Result};

/// Which LPIPS v0.1 backbone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Net {
    /// VGG16; taps relu1_2, relu2_2, relu3_3, relu4_3, relu5_3.
    Vgg,
    /// AlexNet; taps relu1 .. relu5.
    Alex,
}

/// One step of a backbone. Every conv is followed by a ReLU (fused in the kernel).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Op {
    /// Conv layer `features.conv{index}`.
    Conv { index: usize, stride: usize, pad: usize },
    /// Max-pooling, kernel `k`, stride `s`.
    Pool { k: usize, s: usize },
    /// The current activation feeds LPIPS head `lin{n}` (taps are numbered in order).
    Tap,
}

impl Net {
    pub(crate) fn ops(self) -> Vec<Op> {
        let c3 = |index| Op::Conv { index, stride: 1, pad: 1 };
        match self {
            Net::Vgg => {
                let pool = Op::Pool { k: 2, s: 2 };
                vec![
                    c3(0),
                    c3(1),
                    Op::Tap,
                    pool,
                    c3(2),
                    c3(3),
                    Op::Tap,
                    pool,
                    c3(4),
                    c3(5),
                    c3(6),
                    Op::Tap,
                    pool,
                    c3(7),
                    c3(8),
                    c3(9),
                    Op::Tap,
                    pool,
                    c3(10),
                    c3(11),
                    c3(12),
                    Op::Tap,
                ]
            }
            Net::Alex => {
                let pool = Op::Pool { k: 3, s: 2 };
                vec![
                    Op::Conv { index: 0, stride: 4, pad: 2 },
                    Op::Tap,
                    pool,
                    Op::Conv { index: 1, stride: 1, pad: 2 },
                    Op::Tap,
                    pool,
                    c3(2),
                    Op::Tap,
                    c3(3),
                    Op::Tap,
                    c3(4),
                    Op::Tap,
                ]
            }
        }
    }

    /// Short lowercase name (`"vgg"` or `"alex"`), as in the weight file names.
    pub fn name(self) -> &'static str {
        match self {
            Net::Vgg => "vgg",
            Net::Alex => "alex",
        }
    }
}

/// Convs (indexed as in the file) and the non-negative 1x1 head weights, one per tap.
pub(crate) struct Weights {
    pub convs: Vec<Conv>,
    pub heads: Vec<Vec<f32>>,
}

fn take(tensors: &mut HashMap<String, Tensor>, name: &str) -> Result<Tensor> {
    tensors.remove(name).ok_or_else(|| MetricsError::Weights(format!("missing tensor {name}")))
}

pub(crate) fn load(mut tensors: HashMap<String, Tensor>, net: Net) -> Result<Weights> {
    let ops = net.ops();
    let mut convs: Vec<Conv> = Vec::new();
    let mut channels = 3usize;
    let mut tap_channels = Vec::new();
    for op in &ops {
        match *op {
            Op::Conv { index, stride, pad } => {
                debug_assert_eq!(index, convs.len());
                let w = take(&mut tensors, &format!("features.conv{index}.weight"))?;
                let b = take(&mut tensors, &format!("features.conv{index}.bias"))?;
                let [cout, cin, kh, kw] = w.shape[..] else {
                    return Err(MetricsError::Weights(format!("conv{index}: weight shape {:?}", w.shape)));
                };
                if cin != channels || kh != kw || b.shape != [cout] {
                    return Err(MetricsError::Weights(format!(
                        "conv{index}: weight {:?}, bias {:?}, expected {channels} input channels",
                        w.shape, b.shape
                    )));
                }
                convs.push(Conv::new(cout, cin, kh, stride, pad, w.data, b.data));
                channels = cout;
            }
            Op::Pool { .. } => {}
            Op::Tap => tap_channels.push(channels),
        }
    }
    let mut heads = Vec::new();
    for (n, &c) in tap_channels.iter().enumerate() {
        let t = take(&mut tensors, &format!("lin{n}.weight"))?;
        if t.shape != [1, c, 1, 1] {
            return Err(MetricsError::Weights(format!("lin{n}: shape {:?}, expected [1, {c}, 1, 1]", t.shape)));
        }
        heads.push(t.data);
    }
    Ok(Weights { convs, heads })
}
