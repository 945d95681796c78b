//! Adam (Kingma & Ba) over flat `f32` parameter arrays, one group per Gaussian attribute, with
//! the 3DGS conventions: eps 1e-15 (SPEC 2), one step counter per group, and rows that can be
//! appended (densification: new rows start with zero moments) or removed (pruning).
//!
//! A group's rows have `stride` floats; `lr_scale[c]` scales the learning rate of component `c`
//! of every row (SH: DC at full rate, the rest at 1/20, SPEC 2).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Rows per rayon task of an update (large enough to amortise the split).
const ROWS_PER_TASK: usize = 4096;

/// Adam state of one parameter array: hyper-parameters, step count and both moments.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AdamGroup {
    /// Attribute name (e.g. "position"), for checkpoints and messages.
    pub name: String,
    /// Base learning rate.
    pub lr: f32,
    /// Floats per row (one row per Gaussian).
    pub stride: usize,
    /// Per-component learning-rate factor, `stride` entries.
    pub lr_scale: Vec<f32>,
    /// First-moment decay (0.9).
    pub beta1: f32,
    /// Second-moment decay (0.999).
    pub beta2: f32,
    /// Denominator epsilon (1e-15, SPEC 2).
    pub eps: f32,
    /// Updates taken so far (for bias correction).
    pub step: u64,
    /// First moment per float, rows x stride.
    pub m: Vec<f32>,
    /// Second moment per float, rows x stride.
    pub v: Vec<f32>,
}

impl AdamGroup {
    /// A group of `rows` rows of `stride` floats with zero moments and 3DGS's betas and eps.
    pub fn new(name: &str, lr: f32, stride: usize, rows: usize) -> Self {
        Self {
            name: name.to_string(),
            lr,
            stride,
            lr_scale: vec![1.0; stride],
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
            step: 0,
            m: vec![0.0; rows * stride],
            v: vec![0.0; rows * stride],
        }
    }

    /// Set the per-component learning-rate factors (`stride` of them; panics otherwise).
    pub fn with_lr_scale(mut self, lr_scale: Vec<f32>) -> Self {
        assert_eq!(lr_scale.len(), self.stride);
        self.lr_scale = lr_scale;
        self
    }

    /// Number of rows (Gaussians) the moments cover.
    pub fn rows(&self) -> usize {
        self.m.len() / self.stride
    }

    /// One Adam update of `params` with gradient `grad` (same length).
    ///
    /// Every float is updated on its own, in torch.optim.Adam's (non-fused) order of operations,
    /// so the result does not depend on how the rows are split over threads or over SIMD lanes:
    /// it is bit-identical to [`AdamGroup::step_reference`], the per-float oracle. The update is
    /// memory-bound; the loops run over whole slices so that the compiler vectorises them (SSE2
    /// already saturates memory: an AVX2 build of the same loops measured no faster,
    /// `benches/adam.rs`).
    pub fn step(&mut self, params: &mut [f32], grad: &[f32]) {
        let k = self.begin_step(params, grad);
        let stride = self.stride;
        // `step_size * lr_scale[c]` once per component: the product the oracle forms per float.
        let lr: Vec<f32> = self.lr_scale.iter().map(|s| k.step_size * s).collect();
        let uniform = lr.iter().all(|&l| l == lr[0]);
        let block = ROWS_PER_TASK * stride;
        params
            .par_chunks_mut(block)
            .zip(grad.par_chunks(block))
            .zip(self.m.par_chunks_mut(block).zip(self.v.par_chunks_mut(block)))
            .for_each(|((p, g), (m, v))| {
                let mut slices = Slices { p, g, m, v };
                if uniform {
                    k.update_uniform(&mut slices, lr[0]);
                } else {
                    k.update_rows(&mut slices, &lr);
                }
            });
    }

    /// The same update one float at a time, as the formula reads: the oracle of [`AdamGroup::step`].
    pub fn step_reference(&mut self, params: &mut [f32], grad: &[f32]) {
        let k = self.begin_step(params, grad);
        let stride = self.stride;
        for (i, ((p, g), (m, v))) in
            params.iter_mut().zip(grad).zip(self.m.iter_mut().zip(self.v.iter_mut())).enumerate()
        {
            *m = k.b1 * *m + (1.0 - k.b1) * g;
            *v = k.b2 * *v + (1.0 - k.b2) * g * g;
            let denom = v.sqrt() / k.bc2_sqrt + k.eps;
            *p -= k.step_size * self.lr_scale[i % stride] * *m / denom;
        }
    }

    /// Checks the sizes, counts the step and returns its constants (bias corrections included).
    fn begin_step(&mut self, params: &[f32], grad: &[f32]) -> AdamConsts {
        assert_eq!(params.len(), self.m.len(), "Adam group '{}' size mismatch", self.name);
        assert_eq!(grad.len(), params.len());
        self.count_step()
    }

    /// Counts one step and returns its constants, for an update whose moments live elsewhere
    /// (a GPU's buffers: `m` and `v` here are then stale until read back).
    pub fn count_step(&mut self) -> AdamConsts {
        self.step += 1;
        let bc1 = 1.0 - (self.beta1 as f64).powi(self.step as i32);
        let bc2 = 1.0 - (self.beta2 as f64).powi(self.step as i32);
        AdamConsts {
            b1: self.beta1,
            b2: self.beta2,
            eps: self.eps,
            step_size: (self.lr as f64 / bc1) as f32,
            bc2_sqrt: bc2.sqrt() as f32,
        }
    }

    /// Keep rows where `keep[row]`.
    pub fn retain_rows(&mut self, keep: &[bool]) {
        let s = self.stride;
        let filter = |x: &mut Vec<f32>| {
            let mut out = Vec::with_capacity(x.len());
            for (r, k) in keep.iter().enumerate() {
                if *k {
                    out.extend_from_slice(&x[r * s..(r + 1) * s]);
                }
            }
            *x = out;
        };
        filter(&mut self.m);
        filter(&mut self.v);
    }

    /// Put the rows in the order `order`, a permutation of the rows (row `order[j]` becomes row
    /// `j`), as [`svgir_core::Surfels::reorder`] does to the parameters.
    pub fn permute_rows(&mut self, order: &[usize]) {
        assert_eq!(order.len(), self.rows(), "{}: permutation of {} rows for {}", self.name, order.len(), self.rows());
        let s = self.stride;
        let permute = |x: &mut Vec<f32>| {
            let mut out = Vec::with_capacity(x.len());
            for &r in order {
                out.extend_from_slice(&x[r * s..(r + 1) * s]);
            }
            *x = out;
        };
        permute(&mut self.m);
        permute(&mut self.v);
    }

    /// Append `rows` rows of zero moments.
    pub fn append_rows(&mut self, rows: usize) {
        self.m.resize(self.m.len() + rows * self.stride, 0.0);
        self.v.resize(self.v.len() + rows * self.stride, 0.0);
    }

    /// Zero the moments of one row (used after an opacity reset, as 3DGS does).
    pub fn reset_row(&mut self, row: usize) {
        let s = self.stride;
        self.m[row * s..(row + 1) * s].fill(0.0);
        self.v[row * s..(row + 1) * s].fill(0.0);
    }
}

/// One block of rows: parameters, gradient and both moments.
struct Slices<'a> {
    p: &'a mut [f32],
    g: &'a [f32],
    m: &'a mut [f32],
    v: &'a mut [f32],
}

/// The constants of one Adam step: `p -= step_size lr_scale[c] m / (sqrt(v) / bc2_sqrt + eps)`.
#[derive(Clone, Copy, Debug)]
pub struct AdamConsts {
    /// First-moment decay.
    pub b1: f32,
    /// Second-moment decay.
    pub b2: f32,
    /// Denominator epsilon.
    pub eps: f32,
    /// The learning rate over the first moment's bias correction.
    pub step_size: f32,
    /// Square root of the second moment's bias correction.
    pub bc2_sqrt: f32,
}

impl AdamConsts {
    /// Update one float; `lr` is `step_size * lr_scale[c]`.
    #[inline(always)]
    fn update(&self, p: &mut f32, g: f32, m: &mut f32, v: &mut f32, lr: f32) {
        *m = self.b1 * *m + (1.0 - self.b1) * g;
        *v = self.b2 * *v + (1.0 - self.b2) * g * g;
        let denom = v.sqrt() / self.bc2_sqrt + self.eps;
        *p -= lr * *m / denom;
    }

    /// Every float of the block at one rate: one flat loop.
    #[inline(always)]
    fn update_uniform(&self, s: &mut Slices, lr: f32) {
        for ((p, g), (m, v)) in s.p.iter_mut().zip(s.g).zip(s.m.iter_mut().zip(s.v.iter_mut())) {
            self.update(p, *g, m, v, lr);
        }
    }

    /// Rows of `lr.len()` floats, component `c` at rate `lr[c]`.
    #[inline(always)]
    fn update_rows(&self, s: &mut Slices, lr: &[f32]) {
        let n = lr.len();
        for ((p, g), (m, v)) in
            s.p.chunks_exact_mut(n).zip(s.g.chunks_exact(n)).zip(s.m.chunks_exact_mut(n).zip(s.v.chunks_exact_mut(n)))
        {
            for ((((p, g), m), v), &lr) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()).zip(lr) {
                self.update(p, *g, m, v, lr);
            }
        }
    }
}

/// 3DGS's exponential learning-rate schedule: log-linear from `lr_init` to `lr_final` over
/// `max_steps` (no delay phase: 3DGS sets lr_delay_steps = 0, so delay_mult has no effect).
pub fn exp_lr(step: u64, lr_init: f32, lr_final: f32, max_steps: u64) -> f32 {
    let t = (step as f64 / max_steps.max(1) as f64).clamp(0.0, 1.0);
    ((lr_init as f64).ln() * (1.0 - t) + (lr_final as f64).ln() * t).exp() as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimises_a_quadratic_and_first_step_is_lr() {
        let mut p = vec![3.0f32, -2.0];
        let mut adam = AdamGroup::new("x", 0.1, 1, 2);
        // First Adam step moves every coordinate by exactly lr * sign(grad).
        adam.step(&mut p, &[6.0, -4.0]);
        assert!((p[0] - 2.9).abs() < 1e-6 && (p[1] + 1.9).abs() < 1e-6);
        for _ in 0..500 {
            let g: Vec<f32> = p.iter().map(|x| 2.0 * x).collect();
            adam.step(&mut p, &g);
        }
        assert!(p.iter().all(|x| x.abs() < 0.05), "{p:?}");
    }

    /// Rows are updated independently, so moving the rows (parameters, gradients and moments
    /// alike) between two steps moves the results and nothing else.
    #[test]
    fn permuted_rows_step_as_before() {
        let mut rng = svgir_core::Rng::new(9);
        let (stride, rows) = (3, 50);
        let mut a = AdamGroup::new("x", 0.01, stride, rows);
        let mut p: Vec<f32> = (0..rows * stride).map(|_| rng.normal()).collect();
        let g1: Vec<f32> = (0..rows * stride).map(|_| rng.normal()).collect();
        let g2: Vec<f32> = (0..rows * stride).map(|_| rng.normal()).collect();
        a.step(&mut p, &g1);
        let mut order: Vec<usize> = (0..rows).collect();
        order.reverse();
        order.swap(3, 17);
        let permute =
            |x: &[f32]| -> Vec<f32> { order.iter().flat_map(|&r| x[r * stride..(r + 1) * stride].to_vec()).collect() };
        let (mut b, mut q) = (a.clone(), permute(&p));
        b.permute_rows(&order);
        assert_eq!(b.m, permute(&a.m));
        assert_ne!(b.m, a.m);
        a.step(&mut p, &g2);
        b.step(&mut q, &permute(&g2));
        assert_eq!(q, permute(&p));
        assert_eq!((b.m, b.v), (permute(&a.m), permute(&a.v)));
    }

    #[test]
    fn step_is_bit_identical_to_the_per_float_oracle() {
        let mut rng = svgir_core::Rng::new(5);
        // Strides of every stage-1/2 group; rows past one rayon block; uniform and mixed rates.
        for (stride, rows, mixed) in
            [(1, 9000, false), (3, 5000, false), (4, 4097, false), (48, 4500, true), (7, 300, true)]
        {
            let scale: Vec<f32> = (0..stride).map(|c| if mixed && c >= 3 { 0.05 } else { 1.0 }).collect();
            let mut fast = AdamGroup::new("x", 0.01, stride, rows).with_lr_scale(scale.clone());
            let mut slow = fast.clone();
            let mut p: Vec<f32> = (0..rows * stride).map(|_| rng.normal()).collect();
            let mut q = p.clone();
            for _ in 0..3 {
                let g: Vec<f32> = (0..rows * stride).map(|_| 1e-3 * rng.normal()).collect();
                fast.step(&mut p, &g);
                slow.step_reference(&mut q, &g);
            }
            assert!(p.iter().zip(&q).all(|(a, b)| a.to_bits() == b.to_bits()), "stride {stride}: params differ");
            assert_eq!(fast, slow, "stride {stride}: moments differ");
        }
    }

    #[test]
    fn rows_retain_and_append() {
        let mut adam = AdamGroup::new("x", 0.1, 2, 3);
        adam.m = vec![1.0, 1.0, 2.0, 2.0, 3.0, 3.0];
        adam.v = adam.m.clone();
        adam.retain_rows(&[true, false, true]);
        assert_eq!(adam.m, vec![1.0, 1.0, 3.0, 3.0]);
        adam.append_rows(1);
        assert_eq!(adam.rows(), 3);
        assert_eq!(adam.m[4..], [0.0, 0.0]);
    }

    #[test]
    fn schedule_endpoints() {
        assert!((exp_lr(0, 1e-3, 1e-5, 100) - 1e-3).abs() < 1e-9);
        assert!((exp_lr(100, 1e-3, 1e-5, 100) - 1e-5).abs() < 1e-9);
        assert!((exp_lr(50, 1e-3, 1e-5, 100) - 1e-4).abs() < 1e-8);
    }
}
