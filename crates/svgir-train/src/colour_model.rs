//! A Gaussian mixture over RGB colours, fitted as GrabCut fits its foreground and background
//! models (Rother et al. 2004): k-means++ seeds, Lloyd iterations, then one full-covariance
//! Gaussian per cluster, weighted by its share. Its negative log-likelihood is the per-pixel cost
//! of a label in [`crate::mask_refine`].

use glam::{DMat3, DVec3};
use svgir_core::Rng;

/// Added to each covariance's diagonal: the noise floor of 8-bit colour (about 2 levels), so
/// that a flat-coloured cluster does not become a spike.
const COVARIANCE_FLOOR: f64 = 1e-4;

/// One mixture component.
#[derive(Clone, Debug)]
struct Component {
    mean: DVec3,
    inv_cov: DMat3,
    /// ln(weight) - ln((2 pi)^{3/2} sqrt(det cov)).
    log_scale: f64,
}

/// A mixture of full-covariance Gaussians over RGB.
#[derive(Clone, Debug)]
pub struct ColourModel {
    components: Vec<Component>,
}

impl ColourModel {
    /// Fit `k` components to `colours` (at most `max_samples` of them, drawn with `rng`).
    /// `None` when there are fewer colours than components.
    pub fn fit(colours: &[[f32; 3]], k: usize, max_samples: usize, rng: &mut Rng) -> Option<Self> {
        if colours.len() < k.max(1) {
            return None;
        }
        let samples: Vec<DVec3> = if colours.len() > max_samples {
            (0..max_samples).map(|_| to_dvec(colours[rng.below(colours.len())])).collect()
        } else {
            colours.iter().map(|&c| to_dvec(c)).collect()
        };
        let mut centres = kmeans_pp(&samples, k, rng);
        let mut label = vec![0usize; samples.len()];
        for _ in 0..10 {
            for (l, s) in label.iter_mut().zip(&samples) {
                *l = nearest(&centres, *s);
            }
            let mut sum = vec![DVec3::ZERO; k];
            let mut count = vec![0usize; k];
            for (&l, s) in label.iter().zip(&samples) {
                sum[l] += *s;
                count[l] += 1;
            }
            for c in 0..k {
                if count[c] > 0 {
                    centres[c] = sum[c] / count[c] as f64;
                }
            }
        }
        let n = samples.len() as f64;
        let mut components = Vec::with_capacity(k);
        for (c, &mean) in centres.iter().enumerate() {
            let members: Vec<DVec3> =
                label.iter().zip(&samples).filter(|(&l, _)| l == c).map(|(_, s)| *s - mean).collect();
            if members.is_empty() {
                continue;
            }
            let mut cov = DMat3::ZERO;
            for d in &members {
                cov += outer(*d, *d);
            }
            cov = cov * (1.0 / members.len() as f64) + DMat3::from_diagonal(DVec3::splat(COVARIANCE_FLOOR));
            let weight = members.len() as f64 / n;
            let log_scale =
                weight.ln() - 1.5 * (2.0 * std::f64::consts::PI).ln() - 0.5 * cov.determinant().max(1e-300).ln();
            components.push(Component { mean, inv_cov: cov.inverse(), log_scale });
        }
        Some(Self { components })
    }

    /// -ln p(colour) under the mixture.
    pub fn neg_log_likelihood(&self, colour: [f32; 3]) -> f64 {
        let x = to_dvec(colour);
        let logs: Vec<f64> = self
            .components
            .iter()
            .map(|c| {
                let d = x - c.mean;
                c.log_scale - 0.5 * d.dot(c.inv_cov * d)
            })
            .collect();
        let top = logs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        -(top + logs.iter().map(|l| (l - top).exp()).sum::<f64>().ln())
    }
}

fn to_dvec(c: [f32; 3]) -> DVec3 {
    DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64)
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

fn nearest(centres: &[DVec3], s: DVec3) -> usize {
    let mut best = (0, f64::INFINITY);
    for (i, c) in centres.iter().enumerate() {
        let d = c.distance_squared(s);
        if d < best.1 {
            best = (i, d);
        }
    }
    best.0
}

/// k-means++ seeding: each next centre drawn with probability proportional to the squared
/// distance to the nearest centre so far.
fn kmeans_pp(samples: &[DVec3], k: usize, rng: &mut Rng) -> Vec<DVec3> {
    let mut centres = vec![samples[rng.below(samples.len())]];
    let mut d2: Vec<f64> = samples.iter().map(|s| s.distance_squared(centres[0])).collect();
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        let next = if total <= 0.0 {
            samples[rng.below(samples.len())]
        } else {
            let mut r = rng.uniform_f64() * total;
            let mut pick = samples.len() - 1;
            for (i, &d) in d2.iter().enumerate() {
                if r < d {
                    pick = i;
                    break;
                }
                r -= d;
            }
            samples[pick]
        };
        for (d, s) in d2.iter_mut().zip(samples) {
            *d = d.min(s.distance_squared(next));
        }
        centres.push(next);
    }
    centres
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_two_cluster_mixture_prefers_its_own_colours() {
        let mut rng = Rng::new(3);
        let jitter = |rng: &mut Rng, c: [f32; 3]| c.map(|v| v + 0.03 * rng.normal());
        let reds: Vec<[f32; 3]> = (0..500).map(|_| jitter(&mut rng, [0.8, 0.1, 0.1])).collect();
        let blues: Vec<[f32; 3]> = (0..500).map(|_| jitter(&mut rng, [0.1, 0.2, 0.9])).collect();
        let both: Vec<[f32; 3]> = reds.iter().chain(&blues).cloned().collect();
        let m = ColourModel::fit(&both, 2, 10_000, &mut rng).unwrap();
        let red = ColourModel::fit(&reds, 2, 10_000, &mut rng).unwrap();
        // The mixture fits both clusters: a Gaussian's NLL at its mean with sigma 0.03 per channel
        // and weight 1/2 is ln 2 + 1.5 ln(2 pi) + 3 ln 0.03 = -6.77.
        let at_red = m.neg_log_likelihood([0.8, 0.1, 0.1]);
        assert!((at_red - (-6.77)).abs() < 0.4, "{at_red}");
        assert!((m.neg_log_likelihood([0.1, 0.2, 0.9]) - at_red).abs() < 0.4);
        // The red-only model finds blue far less likely than red.
        assert!(red.neg_log_likelihood([0.1, 0.2, 0.9]) - red.neg_log_likelihood([0.8, 0.1, 0.1]) > 100.0);
    }
}
