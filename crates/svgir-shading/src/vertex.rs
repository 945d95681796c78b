//! Gaussian-vertex interpolation weights (SPEC 3, 9.1): the weight of each of a surfel's M
//! vertices at normalised tangent coordinates (u~, v~) in [0, 1]^2, shared by the rasteriser and
//! the tracer's gather so both interpolate identically.
//!
//! Vertex order (u fastest):
//! - M = 1: one vertex, weight 1 (constant material).
//! - M = 2: (0, 1/2), (1, 1/2); linear in u~.
//! - M = 4: (0,0), (1,0), (0,1), (1,1); bilinear.
//! - M = 6: u~ in {0, 1/2, 1} x v~ in {0, 1}: quadratic Lagrange in u~ times linear in v~.
//!
//! Any other M yields all-zero weights; callers validate M once up front.

use crate::float::Float;

/// Most vertices a spatially-varying Gaussian can carry (M = 6); weight arrays have this length.
pub const MAX_VERTICES: usize = 6;

#[inline]
fn lagrange3<F: Float>(u: F) -> ([F; 3], [F; 3]) {
    let (half, one, two, four) = (F::from_f64(0.5), F::ONE, F::from_f64(2.0), F::from_f64(4.0));
    let l = [two * (u - half) * (u - one), -four * u * (u - one), two * u * (u - half)];
    let dl = [four * u - F::from_f64(3.0), -F::from_f64(8.0) * u + four, four * u - one];
    (l, dl)
}

/// Weights of the `m` vertices at (u~, v~); entries `m..6` are zero.
#[inline]
pub fn vertex_weights<F: Float>(m: usize, u: F, v: F) -> [F; MAX_VERTICES] {
    vertex_weights_grad(m, u, v).0
}

/// Weights and their derivatives with respect to u~ and v~.
#[inline]
pub fn vertex_weights_grad<F: Float>(
    m: usize,
    u: F,
    v: F,
) -> ([F; MAX_VERTICES], [F; MAX_VERTICES], [F; MAX_VERTICES]) {
    let z = F::ZERO;
    let one = F::ONE;
    let mut w = [z; MAX_VERTICES];
    let mut du = [z; MAX_VERTICES];
    let mut dv = [z; MAX_VERTICES];
    match m {
        1 => w[0] = one,
        2 => {
            w[0] = one - u;
            w[1] = u;
            du[0] = -one;
            du[1] = one;
        }
        4 => {
            w = [(one - u) * (one - v), u * (one - v), (one - u) * v, u * v, z, z];
            du = [-(one - v), one - v, -v, v, z, z];
            dv = [-(one - u), -u, one - u, u, z, z];
        }
        6 => {
            let (l, dl) = lagrange3(u);
            for i in 0..3 {
                w[i] = l[i] * (one - v);
                w[3 + i] = l[i] * v;
                du[i] = dl[i] * (one - v);
                du[3 + i] = dl[i] * v;
                dv[i] = -l[i];
                dv[3 + i] = l[i];
            }
        }
        _ => {}
    }
    (w, du, dv)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partition_of_unity_interpolation_and_gradients() {
        let nodes: [(usize, Vec<(f64, f64)>); 4] = [
            (1, vec![(0.3, 0.7)]),
            (2, vec![(0.0, 0.5), (1.0, 0.5)]),
            (4, vec![(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]),
            (6, vec![(0.0, 0.0), (0.5, 0.0), (1.0, 0.0), (0.0, 1.0), (0.5, 1.0), (1.0, 1.0)]),
        ];
        for (m, pts) in nodes.iter() {
            // Each vertex gets weight 1 at its own position (M = 1 trivially).
            if *m > 1 {
                for (i, &(u, v)) in pts.iter().enumerate() {
                    let w = vertex_weights(*m, u, v);
                    for k in 0..*m {
                        let want = if k == i { 1.0 } else { 0.0 };
                        assert!((w[k] - want).abs() < 1e-12, "M={m} vertex {i} weight {k} = {}", w[k]);
                    }
                }
            }
            for &(u, v) in &[(0.1, 0.2), (0.5, 0.9), (0.77, 0.33)] {
                let (w, du, dv) = vertex_weights_grad(*m, u, v);
                assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
                let h = 1e-6;
                let (wu, wv) = (vertex_weights(*m, u + h, v), vertex_weights(*m, u, v + h));
                let (wu2, wv2) = (vertex_weights(*m, u - h, v), vertex_weights(*m, u, v - h));
                for k in 0..MAX_VERTICES {
                    assert!(((wu[k] - wu2[k]) / (2.0 * h) - du[k]).abs() < 1e-6);
                    assert!(((wv[k] - wv2[k]) / (2.0 * h) - dv[k]).abs() < 1e-6);
                }
            }
        }
        assert_eq!(vertex_weights(3, 0.5f32, 0.5), [0.0; 6]);
    }
}
