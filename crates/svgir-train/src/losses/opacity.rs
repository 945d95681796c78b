//! The binary-opacity term: the mean over the Gaussians of the binary entropy of their opacity,
//! `L = (1/N) sum_i H(o_i)`, `H(o) = -o ln o - (1 - o) ln(1 - o)`, `o_i = sigmoid(x_i)` of the
//! opacity logit. It is 0 at opacities 0 and 1, so it pushes each surfel to be a surface or
//! nothing (the per-Gaussian form of the binary-opacity regularisers later surfel methods use;
//! the mask entropy of SPEC 2 acts on the rendered alpha instead).
//!
//! With `dH/do = ln((1 - o) / o) = -x` and `do/dx = o (1 - o)`, the gradient is
//! `dL/dx_i = -x_i o_i (1 - o_i) / N`: it moves each logit away from 0, the way it leans.

use svgir_core::surfel::sigmoid;

/// The term's value over `logits`, and `weight * dL/dx` added to `v_logits`.
pub fn binary_opacity(logits: &[f32], weight: f32, v_logits: &mut [f32]) -> f64 {
    assert_eq!(logits.len(), v_logits.len());
    if logits.is_empty() {
        return 0.0;
    }
    let n = logits.len() as f64;
    let scale = weight / logits.len() as f32;
    let mut sum = 0.0f64;
    for (&x, g) in logits.iter().zip(v_logits.iter_mut()) {
        let o = sigmoid(x);
        sum += entropy(o as f64);
        *g += scale * (-x * o * (1.0 - o));
    }
    sum / n
}

/// Binary entropy in nats, 0 at 0 and 1.
fn entropy(o: f64) -> f64 {
    let h = |p: f64| if p > 0.0 { -p * p.ln() } else { 0.0 };
    h(o) + h(1.0 - o)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gradient against f64 central differences of the value, over logits from -8 to 8.
    #[test]
    fn gradient_matches_finite_differences() {
        let logits: Vec<f32> = (0..33).map(|k| -8.0 + 0.5 * k as f32).collect();
        let mut g = vec![0.0f32; logits.len()];
        binary_opacity(&logits, 1.0, &mut g);
        let n = logits.len() as f64;
        for (i, &x) in logits.iter().enumerate() {
            let sig = |x: f64| 1.0 / (1.0 + (-x).exp());
            let eps = 1e-5;
            let fd = (entropy(sig(x as f64 + eps)) - entropy(sig(x as f64 - eps))) / (2.0 * eps) / n;
            assert!((g[i] as f64 - fd).abs() < 1e-6 + 1e-4 * fd.abs(), "logit {x}: {} vs {fd}", g[i]);
        }
    }

    /// Largest at opacity one half (ln 2), 0 at the ends; the weight scales the gradient only.
    #[test]
    fn value_and_weight() {
        let mut g = vec![0.0f32; 3];
        let v = binary_opacity(&[0.0, 30.0, -30.0], 0.5, &mut g);
        assert!((v - std::f64::consts::LN_2 / 3.0).abs() < 1e-6, "{v}");
        assert_eq!(g[0], 0.0);
        let mut g2 = vec![0.0f32; 1];
        binary_opacity(&[1.5], 2.0, &mut g2);
        let mut g1 = vec![0.0f32; 1];
        binary_opacity(&[1.5], 1.0, &mut g1);
        assert!((g2[0] - 2.0 * g1[0]).abs() < 1e-7 && g1[0] < 0.0);
    }
}
