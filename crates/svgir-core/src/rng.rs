//! A small seeded generator (SplitMix64) for every random choice in svgir: initial points, view
//! order, per-Gaussian Fibonacci offsets, background colours. Runs record their seed, and
//! [`Rng::fork`] derives independent streams so that parallel or reordered work stays reproducible.

/// Seeded SplitMix64 random generator; every random choice in svgir draws from one.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
}

impl Rng {
    /// A generator seeded with `seed` (the same seed gives the same stream).
    pub fn new(seed: u64) -> Self {
        Self { state: seed ^ 0x9E37_79B9_7F4A_7C15 }
    }

    /// The internal state, for checkpoints ([`Rng::from_state`] restores it exactly).
    pub fn state(&self) -> u64 {
        self.state
    }

    /// Restore a generator saved with [`Rng::state`].
    pub fn from_state(state: u64) -> Self {
        Self { state }
    }

    /// An independent stream named by `stream` (e.g. a Gaussian index or a purpose tag).
    pub fn fork(&self, stream: u64) -> Rng {
        let mut r = Rng { state: self.state ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03) };
        r.next_u64();
        r
    }

    /// Next 64 random bits (SplitMix64 step).
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// Uniform in [0, 1) with 53 random bits.
    pub fn uniform_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform integer in [0, n).
    pub fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f32 {
        let u1 = self.uniform_f64().max(1e-300);
        let u2 = self.uniform_f64();
        ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
    }

    /// Fisher-Yates shuffle.
    pub fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            let j = self.below(i + 1);
            v.swap(i, j);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproducible_and_roughly_uniform() {
        let mut a = Rng::new(7);
        let mut b = Rng::new(7);
        let xs: Vec<f32> = (0..10000).map(|_| a.uniform()).collect();
        assert!(xs.iter().zip((0..10000).map(|_| b.uniform())).all(|(x, y)| *x == y));
        let mean = xs.iter().sum::<f32>() / xs.len() as f32;
        assert!((mean - 0.5).abs() < 0.02);
        assert!(xs.iter().all(|&x| (0.0..1.0).contains(&x)));
        let mut c = Rng::new(7);
        let n: Vec<f32> = (0..20000).map(|_| c.normal()).collect();
        let var = n.iter().map(|x| x * x).sum::<f32>() / n.len() as f32;
        assert!((var - 1.0).abs() < 0.05, "{var}");
        assert_ne!(Rng::new(7).fork(1).next_u64(), Rng::new(7).fork(2).next_u64());
    }
}
