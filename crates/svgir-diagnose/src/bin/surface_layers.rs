//! Diagnostic: how opaque and how thin stage 1's surfaces are. For a model and a dataset's test
//! views it prints
//! - the surfels that carry 90% of the composited weight (alpha_i T_i, SPEC 1, summed over the
//!   views' pixels), with their mean and median opacity;
//! - the share of that weight from surfels of opacity >= 0.8;
//! - the layers per covered pixel (alpha >= 0.5), from the dense oracle's weights
//!   (`svgir_raster::reference::layer_weights`) on every `stride`-th pixel of each row and column:
//!   the surfels whose weight there is above 0.1, and the depth layers above 0.1, hits within
//!   1% of the first one's depth merged into one (neighbouring disks of one surface overlap at
//!   their faint rims; stacked surfaces lie at different depths).
//!
//! An opaque, thin surface has one layer and opacities near 1; stage 1's stacked, semi-transparent
//! surfels show as more layers and a low median.
//!
//! `cargo run --release -p svgir-diagnose --bin surface_layers -- PLY DATA [--views N] [--stride S]`

use anyhow::{bail, Result};
use clap::Parser;
use rayon::prelude::*;
use std::path::PathBuf;
use svgir_io::LoadOptions;
use svgir_raster::reference::{layer_weights, LayerHit};
use svgir_raster::{render, Background, ColorSource, RasterConfig, RenderInput};

/// A surfel at or above this opacity counts as opaque.
const OPAQUE: f32 = 0.8;
/// A surfel (or a depth layer) whose weight at a pixel is above this is a layer there.
const LAYER_WEIGHT: f32 = 0.1;
/// Hits within this share of the layer's first depth are one depth layer.
const LAYER_GAP: f32 = 0.01;

/// Depth layers of one pixel's hits (in the composite's centre-depth order, which a tilted
/// splat's intersection depth may break slightly) with more than `LAYER_WEIGHT` weight.
fn depth_layers(hits: &[LayerHit<f32>]) -> usize {
    let (mut count, mut start, mut weight) = (0, f32::NEG_INFINITY, 0.0);
    for h in hits {
        if h.depth > start * (1.0 + LAYER_GAP) {
            count += (weight > LAYER_WEIGHT) as usize;
            (start, weight) = (h.depth, 0.0);
        }
        weight += h.weight;
    }
    count + (weight > LAYER_WEIGHT) as usize
}

/// How opaque and how thin stage 1's surfaces are (see the file's docs).
#[derive(Parser)]
struct Args {
    /// The model: a run's point_cloud.ply.
    ply: PathBuf,
    /// The dataset whose test views are rendered.
    data: PathBuf,
    /// Test views used (the first N).
    #[arg(long, default_value_t = 8)]
    views: usize,
    /// Every this-many-th pixel of each row and column gets the oracle's per-pixel weights.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..))]
    stride: u32,
}

fn median(v: &mut [f32]) -> f32 {
    v.sort_by(f32::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

fn main() -> Result<()> {
    let args = Args::parse();
    let (surfels, _) = svgir_io::read_gaussians_ply(&args.ply)?;
    let ds = svgir_io::load_dataset(&args.data, &LoadOptions { load_test: true, ..Default::default() })?;
    if ds.test.is_empty() {
        bail!("{}: no test views", args.data.display());
    }
    let raster = RasterConfig::default();
    let n = surfels.len();
    let mut weight = vec![0.0f64; n];
    let mut layer_counts = [0usize; 4]; // 0, 1, 2, 3+ surfels above LAYER_WEIGHT
    let (mut layers_sum, mut depth_sum) = (0usize, 0usize);
    for view in ds.test.iter().take(args.views) {
        let input = RenderInput {
            surfels: &surfels,
            camera: &view.camera,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color([0.0; 3]),
        };
        let (out, _) = render(&input, &raster);
        for (w, &a) in weight.iter_mut().zip(&out.accum_weight) {
            *w += a as f64;
        }
        let width = out.width as usize;
        let pixels: Vec<(u32, u32)> = (0..out.height)
            .step_by(args.stride as usize)
            .flat_map(|y| (0..out.width).step_by(args.stride as usize).map(move |x| (x, y)))
            .filter(|&(x, y)| out.alpha[y as usize * width + x as usize] >= 0.5)
            .collect();
        let counts: Vec<(usize, usize)> = pixels
            .par_chunks(256)
            .flat_map_iter(|chunk| {
                layer_weights(&input, &raster, chunk)
                    .into_iter()
                    .map(|l| (l.iter().filter(|h| h.weight > LAYER_WEIGHT).count(), depth_layers(&l)))
            })
            .collect();
        for (c, d) in counts {
            layer_counts[c.min(3)] += 1;
            layers_sum += c;
            depth_sum += d;
        }
    }
    let total: f64 = weight.iter().sum();
    if total <= 0.0 {
        bail!("{}: the model covers no pixel of the test views", args.ply.display());
    }
    let mut by_weight: Vec<usize> = (0..n).collect();
    by_weight.sort_by(|&a, &b| weight[b].total_cmp(&weight[a]).then(a.cmp(&b)));
    let (mut carried, mut carriers) = (0.0, Vec::new());
    for &i in &by_weight {
        if carried >= 0.9 * total {
            break;
        }
        carried += weight[i];
        carriers.push(surfels.opacity(i));
    }
    let opaque_share: f64 = (0..n).filter(|&i| surfels.opacity(i) >= OPAQUE).map(|i| weight[i]).sum::<f64>() / total;
    let mut all: Vec<f32> = (0..n).map(|i| surfels.opacity(i)).collect();
    let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64;
    let pixels: usize = layer_counts.iter().sum();
    let share = |c: usize| 100.0 * c as f64 / pixels.max(1) as f64;
    println!("{}: {} Gaussians, {} test views", args.ply.display(), n, args.views.min(ds.test.len()));
    println!("opacity of all: mean {:.3}, median {:.3}", mean(&all), median(&mut all));
    println!(
        "carriers of 90% of the weight: {} ({:.1}%), opacity mean {:.3}, median {:.3}",
        carriers.len(),
        100.0 * carriers.len() as f64 / n as f64,
        mean(&carriers),
        median(&mut carriers)
    );
    println!("weight from surfels of opacity >= {OPAQUE}: {:.1}%", 100.0 * opaque_share);
    println!(
        "per covered pixel, surfels of weight > {LAYER_WEIGHT}: {:.2} (0: {:.1}%, 1: {:.1}%, 2: {:.1}%, 3+: {:.1}%); \
         depth layers: {:.2}; over {} pixels",
        layers_sum as f64 / pixels.max(1) as f64,
        share(layer_counts[0]),
        share(layer_counts[1]),
        share(layer_counts[2]),
        share(layer_counts[3]),
        depth_sum as f64 / pixels.max(1) as f64,
        pixels
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(depth: f32, weight: f32) -> LayerHit<f32> {
        LayerHit { gaussian: 0, weight, depth }
    }

    /// Neighbouring rims at one depth are one layer; a second surface behind is another; a faint
    /// one is none.
    #[test]
    fn depth_layers_merge_one_surface() {
        assert_eq!(depth_layers(&[]), 0);
        assert_eq!(depth_layers(&[hit(2.0, 0.06), hit(2.01, 0.06)]), 1);
        assert_eq!(depth_layers(&[hit(2.0, 0.5), hit(2.01, 0.3), hit(2.5, 0.15)]), 2);
        assert_eq!(depth_layers(&[hit(2.0, 0.9), hit(2.5, 0.05)]), 1);
    }
}
