//! Edge-aware smoothness (SPEC 6, Eqn 17) on a splatted material buffer `a` (albedo or
//! roughness) guided by the photo `I`:
//! `L = 1/|a| sum_ij exp(-|I_ij - I_{i-1,j}|) (a_ij - a_{i-1,j})^2 + exp(-|I_ij - I_{i,j-1}|) (a_ij - a_{i,j-1})^2`
//! where `|I_ij - I_kl|` is the mean absolute difference over the photo's channels and `|a|` the
//! number of elements of `a` (pixels x channels). The photo carries no gradient.

use rayon::prelude::*;
use svgir_core::par::filled;
use svgir_core::Float;

/// The edge weights of Eqn 17 for a guide image: `exp(-mean_c |I_p - I_q|)` of each pixel's edge
/// to its left (`x`) and upper (`y`) neighbour, 0 where it has none. One set serves every buffer
/// smoothed against the same guide (stage 2's albedo and roughness share the photo's).
pub struct EdgeWeights<F> {
    width: usize,
    height: usize,
    x: Vec<F>,
    y: Vec<F>,
}

impl<F: Float> EdgeWeights<F> {
    /// Weights of the guide `img` (`ci` channels, `width x height`), rows in parallel.
    pub fn new(img: &[F], ci: usize, width: usize, height: usize) -> Self {
        let (mut x, mut y) = (filled(width * height, F::ZERO), filled(width * height, F::ZERO));
        x.par_chunks_mut(width).zip(y.par_chunks_mut(width)).enumerate().for_each(|(r, (ex, ey))| {
            for c in 0..width {
                let p = r * width + c;
                if c > 0 {
                    ex[c] = edge(img, ci, p, p - 1);
                }
                if r > 0 {
                    ey[c] = edge(img, ci, p, p - width);
                }
            }
        });
        Self { width, height, x, y }
    }
}

/// Loss value; accumulates `weight * dL/da` into `v_a`. `a` has `ca` channels, `img` has `ci`.
/// Generic so the f64 instantiation checks the gradient by finite differences.
#[allow(clippy::too_many_arguments)]
pub fn edge_aware_smoothness<F: Float>(
    a: &[F],
    ca: usize,
    img: &[F],
    ci: usize,
    width: usize,
    height: usize,
    weight: F,
    v_a: &mut [F],
) -> F {
    edge_aware_smoothness_with(a, ca, &EdgeWeights::new(img, ci, width, height), weight, v_a)
}

/// [`edge_aware_smoothness`] with the guide's edge weights computed beforehand.
///
/// Work split: each edge's gradient is computed once, rows in parallel, and each element of
/// `v_a` then adds its (up to) four edges in the order the serial loop
/// ([`edge_aware_smoothness_serial`], the oracle) visits them, so `v_a` gets the same bits. The
/// loss is summed per row in f64, which can differ from the serial sum in its last f64 bits.
pub fn edge_aware_smoothness_with<F: Float>(a: &[F], ca: usize, edges: &EdgeWeights<F>, weight: F, v_a: &mut [F]) -> F {
    let (width, height) = (edges.width, edges.height);
    let n = F::from_f64((width * height * ca) as f64);
    let two = F::from_f64(2.0);
    let row = width * ca;
    // gx[p * ca + c]: the gradient of the edge from p's left neighbour to p; gy: from the pixel
    // above. Zero where there is no such neighbour.
    let (mut gx, mut gy) = (filled(a.len(), F::ZERO), filled(a.len(), F::ZERO));
    let loss: f64 = gx
        .par_chunks_mut(row)
        .zip(gy.par_chunks_mut(row))
        .enumerate()
        .map(|(y, (gx, gy))| {
            let mut loss = 0.0f64;
            // Per pixel its left edge, then its upper one, as the serial loop.
            let mut one = |e: F, p: usize, q: usize, g: &mut [F]| {
                for c in 0..ca {
                    let d = a[p * ca + c] - a[q * ca + c];
                    loss += (e * d * d).to_f64();
                    g[c] = weight * two * e * d / n;
                }
            };
            for x in 0..width {
                let p = y * width + x;
                if x > 0 {
                    one(edges.x[p], p, p - 1, &mut gx[x * ca..(x + 1) * ca]);
                }
                if y > 0 {
                    one(edges.y[p], p, p - width, &mut gy[x * ca..(x + 1) * ca]);
                }
            }
            loss
        })
        // Row sums collected and added in row order: the same loss for any thread count
        // (a rayon `sum` would depend on how the rows were split).
        .collect::<Vec<f64>>()
        .iter()
        .sum();
    v_a.par_chunks_mut(row).enumerate().for_each(|(y, out)| {
        for (i, o) in out.iter_mut().enumerate() {
            let (x, k) = (i / ca, y * row + i);
            // The serial loop's order: this pixel's own edges, then its right and lower
            // neighbours' edges towards it.
            if x > 0 {
                *o += gx[k];
            }
            if y > 0 {
                *o += gy[k];
            }
            if x + 1 < width {
                *o -= gx[k + ca];
            }
            if y + 1 < height {
                *o -= gy[k + row];
            }
        }
    });
    F::from_f64(loss / n.to_f64())
}

/// `exp(-mean_c |img_p - img_q|)`.
#[inline]
fn edge<F: Float>(img: &[F], ci: usize, p: usize, q: usize) -> F {
    let mut d = F::ZERO;
    for c in 0..ci {
        d += (img[p * ci + c] - img[q * ci + c]).abs();
    }
    (-(d / F::from_f64(ci as f64))).exp()
}

/// [`edge_aware_smoothness`] as one serial loop over pixels and their left and upper edges: the
/// oracle of the parallel version.
#[allow(clippy::too_many_arguments)]
pub fn edge_aware_smoothness_serial<F: Float>(
    a: &[F],
    ca: usize,
    img: &[F],
    ci: usize,
    width: usize,
    height: usize,
    weight: F,
    v_a: &mut [F],
) -> F {
    let n = F::from_f64((width * height * ca) as f64);
    let two = F::from_f64(2.0);
    let mut loss = 0.0f64;
    for y in 0..height {
        for x in 0..width {
            let p = y * width + x;
            for q in [(x > 0).then(|| p - 1), (y > 0).then(|| p - width)].into_iter().flatten() {
                let e = edge(img, ci, p, q);
                for c in 0..ca {
                    let d = a[p * ca + c] - a[q * ca + c];
                    loss += (e * d * d).to_f64();
                    let g = weight * two * e * d / n;
                    v_a[p * ca + c] += g;
                    v_a[q * ca + c] -= g;
                }
            }
        }
    }
    F::from_f64(loss / n.to_f64())
}

/// Guide for [`edge_aware_smoothness`] of the splatted shading normals (our addition,
/// `Stage2Weights::smooth_normal`): `sharpness * ln(depth)` where the render covers the pixel
/// (opacity > 0.5), so a relative depth step of `1/sharpness` between neighbours halves their
/// weight by e and a silhouette cuts it; [`BACKGROUND_GUIDE`] elsewhere, which no foreground pixel
/// is smoothed towards. `depth_sum` is the rasteriser's `sum w_i z_i`.
pub fn depth_guide(depth_sum: &[f32], alpha: &[f32], sharpness: f32) -> Vec<f32> {
    depth_sum
        .par_iter()
        .zip(alpha)
        .with_min_len(super::CHUNK)
        .map(|(&d, &a)| if a > 0.5 { sharpness * (d / a).max(1e-6).ln() } else { BACKGROUND_GUIDE })
        .collect()
}

/// Guide value of uncovered pixels: `exp(-|BACKGROUND_GUIDE - g|)` is 0 for any depth guide `g`.
pub const BACKGROUND_GUIDE: f32 = 1e6;

#[cfg(test)]
mod tests {
    use super::*;
    use svgir_core::Rng;

    fn loss(a: &[f64], ca: usize, img: &[f64], w: usize, h: usize) -> f64 {
        edge_aware_smoothness(a, ca, img, 3, w, h, 1.0, &mut vec![0.0; a.len()])
    }

    #[test]
    fn gradient_matches_finite_differences_and_edges_gate() {
        let (w, h, ca, ci) = (5, 4, 3, 3);
        let mut rng = Rng::new(9);
        let a: Vec<f64> = (0..w * h * ca).map(|_| rng.uniform_f64()).collect();
        let img: Vec<f64> = (0..w * h * ci).map(|_| rng.uniform_f64()).collect();
        let mut g = vec![0.0; a.len()];
        edge_aware_smoothness(&a, ca, &img, ci, w, h, 1.0, &mut g);
        for i in 0..a.len() {
            let hstep = 1e-6;
            let (mut ap, mut am) = (a.clone(), a.clone());
            ap[i] += hstep;
            am[i] -= hstep;
            let fd = (loss(&ap, ca, &img, w, h) - loss(&am, ca, &img, w, h)) / (2.0 * hstep);
            assert!((fd - g[i]).abs() < 1e-8 + 1e-6 * fd.abs(), "{i}: {fd} vs {}", g[i]);
        }
        // A strong photo edge between two pixels suppresses the penalty across it.
        let a2 = [0.0f32, 1.0];
        let flat = [0.5f32, 0.5];
        let edged = [0.0f32, 1.0];
        let mut s = [0.0f32; 2];
        let l_flat = edge_aware_smoothness(&a2, 1, &flat, 1, 2, 1, 1.0, &mut s);
        let l_edge = edge_aware_smoothness(&a2, 1, &edged, 1, 2, 1, 1.0, &mut s);
        assert!(l_edge < 0.4 * l_flat);
    }

    /// The parallel version adds the same edge gradients in the serial loop's order: the same
    /// bits in `v_a` (which starts non-zero, as in the stage-2 objective), on odd sizes and
    /// single rows or columns; the loss to f64 rounding.
    #[test]
    fn parallel_is_the_serial_loop() {
        let mut rng = Rng::new(17);
        for (w, h, ca, ci) in [(37usize, 23usize, 3usize, 3usize), (64, 9, 1, 3), (1, 11, 3, 1), (13, 1, 1, 1)] {
            let a: Vec<f32> = (0..w * h * ca).map(|_| rng.uniform()).collect();
            let img: Vec<f32> = (0..w * h * ci).map(|_| rng.uniform()).collect();
            let start: Vec<f32> = (0..a.len()).map(|_| rng.normal()).collect();
            let (mut par, mut ser) = (start.clone(), start.clone());
            let lp = edge_aware_smoothness(&a, ca, &img, ci, w, h, 0.3, &mut par);
            let ls = edge_aware_smoothness_serial(&a, ca, &img, ci, w, h, 0.3, &mut ser);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
            assert_eq!(bits(&par), bits(&ser), "{w}x{h}x{ca}: gradients");
            assert!(par != start || w * h == 1, "{w}x{h}: no gradient");
            assert!((lp - ls).abs() <= 1e-6 * ls.abs(), "{w}x{h}: loss {lp} vs {ls}");
        }
    }

    #[test]
    fn depth_guide_cuts_silhouettes_and_keeps_smooth_surfaces() {
        // Pixels: surface at depth 2 (opacity 1), the same surface 0.2% further, an object behind
        // at depth 3, and background.
        let alpha = [1.0f32, 1.0, 1.0, 0.0];
        let depth = [2.0f32, 2.004, 3.0, 0.0];
        let g = depth_guide(&depth, &alpha, 100.0);
        let a = [0.0f32, 1.0, 0.0, 1.0];
        let pair = |p: usize, q: usize| {
            let mut v = [0.0f32; 2];
            edge_aware_smoothness(&[a[p], a[q]], 1, &[g[p], g[q]], 1, 2, 1, 1.0, &mut v)
        };
        assert!(pair(0, 1) > 0.3, "smooth surface: weight exp(-0.2)");
        assert!(pair(1, 2) < 1e-10, "depth discontinuity");
        assert_eq!(pair(0, 3), 0.0, "background");
    }
}
