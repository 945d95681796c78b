//! The learnable environment light (SPEC 4): a lat-long map of H x 2H texels (H = 32) in the
//! frame and aligned-corner grid of `svgir_core::EnvMap`, parameter initialised to `3.0 U(0,1)`
//! from a seeded `Rng`, radiance `2 softplus(param)` (the [0, 64] clamp is applied inside the
//! rendering equation, not here). Also the TV-L2 regulariser on the radiance map (SPEC 4,
//! weight 0.02 in the total loss).
//!
//! Work split: texels are few (2048), everything runs sequentially; the generic functions take
//! f64 in the gradient tests.

use crate::activation::{sigmoid, softplus, softplus_inv};
use crate::{expect_len, PbrError};
use svgir_core::Float;
use svgir_core::{EnvMap, Rng};

/// Default map height (SPEC 4); width is twice this.
pub const ENV_HEIGHT: u32 = 32;
/// Parameter init is `ENV_INIT * U(0, 1)` per channel (SPEC 4).
pub const ENV_INIT: f32 = 3.0;

/// How a texel's parameter becomes radiance.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum EnvActivation {
    /// `2 softplus(x)` (SPEC 4). Adam moves x by ~lr per step, so radiance grows by at most
    /// ~0.05 per step: a sun of 1000+ is out of reach of any schedule.
    #[default]
    Softplus,
    /// `exp(x)` (our option): steps are relative (~2.5% at lr 0.025), so a texel can grow from
    /// 1 to 3000 in ~300 steps; for lights with a sun, shaded as a directional light.
    Exp,
}

/// The learnable environment light: raw parameters of an H x 2H lat-long map and their activation.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvLight {
    /// Map width in texels (2H).
    pub width: u32,
    /// Map height in texels (H).
    pub height: u32,
    /// Raw parameter per texel, row-major (row 0 = zenith).
    pub param: Vec<[f32; 3]>,
    /// How `param` becomes radiance.
    pub activation: EnvActivation,
}

/// Radiance `2 softplus(param)` per texel.
pub fn env_radiance<F: Float>(param: &[[F; 3]]) -> Vec<[F; 3]> {
    let two = F::from_f64(2.0);
    param.iter().map(|p| p.map(|x| two * softplus(x))).collect()
}

/// Backward of [`env_radiance`]: `d/dx 2 softplus(x) = 2 sigmoid(x)`.
pub fn env_radiance_backward<F: Float>(param: &[[F; 3]], v_radiance: &[[F; 3]]) -> Vec<[F; 3]> {
    let two = F::from_f64(2.0);
    param.iter().zip(v_radiance).map(|(p, g)| [0, 1, 2].map(|c| two * sigmoid(p[c]) * g[c])).collect()
}

impl EnvLight {
    /// A `height` x `2 height` map with parameters `3.0 U(0,1)` drawn from `Rng::new(seed)`.
    pub fn new(height: u32, seed: u64) -> Result<Self, PbrError> {
        if height < 2 {
            return Err(PbrError::InvalidParameter(format!("environment height {height} (must be >= 2)")));
        }
        let width = 2 * height;
        let mut rng = Rng::new(seed);
        let param = (0..width * height)
            .map(|_| [rng.uniform() * ENV_INIT, rng.uniform() * ENV_INIT, rng.uniform() * ENV_INIT])
            .collect();
        Ok(Self { width, height, param, activation: EnvActivation::Softplus })
    }

    /// Every parameter at the mean of SPEC 4's init, `ENV_INIT / 2` (a grey light): the
    /// per-texel noise of the random init needs thousands of iterations to wash out, which a
    /// short schedule does not have (see `Stage2Config::env_init`).
    pub fn uniform(height: u32) -> Result<Self, PbrError> {
        let mut e = Self::new(height, 0)?;
        e.param.iter_mut().for_each(|p| *p = [0.5 * ENV_INIT; 3]);
        Ok(e)
    }

    /// Parameters reproducing `map` (radiance floored at 1e-6, where softplus is invertible).
    pub fn from_radiance(map: &EnvMap) -> Result<Self, PbrError> {
        if map.width < 2 || map.height < 2 {
            return Err(PbrError::InvalidParameter(format!("environment {}x{}", map.width, map.height)));
        }
        expect_len("environment map", map.data.len(), (map.width * map.height) as usize)?;
        let param = map.data.iter().map(|t| t.map(|y| softplus_inv((0.5 * y).max(1e-6)))).collect();
        Ok(Self { width: map.width, height: map.height, param, activation: EnvActivation::Softplus })
    }

    /// The same radiance map under another activation (radiance floored at 1e-6 for `Exp`).
    pub fn with_activation(self, activation: EnvActivation) -> Result<Self, PbrError> {
        if activation == self.activation {
            return Ok(self);
        }
        let rad = self.radiance();
        match activation {
            EnvActivation::Softplus => Self::from_radiance(&rad),
            EnvActivation::Exp => {
                Ok(Self { param: rad.data.iter().map(|t| t.map(|y| y.max(1e-6).ln())).collect(), activation, ..self })
            }
        }
    }

    /// Number of texels, W x H.
    pub fn texels(&self) -> usize {
        self.param.len()
    }

    /// The radiance map (`2 softplus(param)` or `exp(param)`).
    pub fn radiance(&self) -> EnvMap {
        let data = match self.activation {
            EnvActivation::Softplus => env_radiance(&self.param),
            EnvActivation::Exp => self.param.iter().map(|p| p.map(f32::exp)).collect(),
        };
        EnvMap { width: self.width, height: self.height, data }
    }

    /// Chain a gradient on the radiance texels (e.g. `PbrGrads::v_env`) to the parameters.
    pub fn backward(&self, v_radiance: &[[f32; 3]]) -> Result<Vec<[f32; 3]>, PbrError> {
        expect_len("v_radiance", v_radiance.len(), self.param.len())?;
        Ok(match self.activation {
            EnvActivation::Softplus => env_radiance_backward(&self.param, v_radiance),
            EnvActivation::Exp => {
                self.param.iter().zip(v_radiance).map(|(p, g)| [0, 1, 2].map(|c| p[c].exp() * g[c])).collect()
            }
        })
    }

    /// TV-L2 of the radiance map: mean over horizontally and vertically adjacent texel pairs and
    /// channels of the squared difference; returns the value and its gradient w.r.t. `param`.
    /// Pairs touching a texel with `skip[t]` (a directional light: a sun is one bright texel,
    /// which TV would flatten) are left out.
    pub fn tv_l2(&self, skip: Option<&[bool]>) -> (f32, Vec<[f32; 3]>) {
        let (value, v_rad) = tv_l2_masked(&self.radiance().data, self.width as usize, self.height as usize, skip);
        let v_param = self.backward(&v_rad).expect("one gradient per texel");
        (value, v_param)
    }
}

/// TV-L2 of a `w` x `h` map and its gradient w.r.t. the texels (generic for the tests).
pub fn tv_l2<F: Float>(rad: &[[F; 3]], w: usize, h: usize) -> (F, Vec<[F; 3]>) {
    tv_l2_masked(rad, w, h, None)
}

/// [`tv_l2`] without the pairs that touch a texel with `skip[t]` (the mean keeps the full pair
/// count, so the weight of the remaining pairs does not change).
pub fn tv_l2_masked<F: Float>(rad: &[[F; 3]], w: usize, h: usize, skip: Option<&[bool]>) -> (F, Vec<[F; 3]>) {
    let mut grad = vec![[F::ZERO; 3]; rad.len()];
    if rad.len() != w * h || w < 2 || h < 2 || skip.is_some_and(|s| s.len() != rad.len()) {
        return (F::ZERO, grad);
    }
    let skipped = |i: usize| skip.is_some_and(|s| s[i]);
    let pairs = (w - 1) * h + w * (h - 1);
    let inv = F::ONE / F::from_f64((3 * pairs) as f64);
    let two = F::from_f64(2.0);
    let mut sum = F::ZERO;
    let mut add = |a: usize, b: usize, grad: &mut [[F; 3]]| {
        if skipped(a) || skipped(b) {
            return;
        }
        for c in 0..3 {
            let d = rad[a][c] - rad[b][c];
            sum += d * d;
            grad[a][c] += two * d * inv;
            grad[b][c] -= two * d * inv;
        }
    };
    for r in 0..h {
        for c in 0..w {
            let i = r * w + c;
            if c + 1 < w {
                add(i, i + 1, &mut grad);
            }
            if r + 1 < h {
                add(i, i + w, &mut grad);
            }
        }
    }
    (sum * inv, grad)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn init_radiance_and_round_trip() {
        let e = EnvLight::new(ENV_HEIGHT, 5).unwrap();
        assert_eq!((e.width, e.height, e.texels()), (64, 32, 2048));
        assert!(e.param.iter().flatten().all(|&x| (0.0..3.0).contains(&x)));
        let mean = e.param.iter().flatten().sum::<f32>() / (3.0 * 2048.0);
        assert!((mean - 1.5).abs() < 0.1, "{mean}");
        assert_eq!(e, EnvLight::new(ENV_HEIGHT, 5).unwrap());
        assert_ne!(e, EnvLight::new(ENV_HEIGHT, 6).unwrap());
        let rad = e.radiance();
        // 2 softplus(0) = 2 ln 2.
        let z =
            EnvLight { width: 2, height: 2, param: vec![[0.0; 3]; 4], activation: EnvActivation::Softplus }.radiance();
        assert!((z.data[0][0] - 2.0 * 2f32.ln()).abs() < 1e-6);
        let back = EnvLight::from_radiance(&rad).unwrap();
        for (a, b) in back.param.iter().flatten().zip(e.param.iter().flatten()) {
            assert!((a - b).abs() < 1e-4, "{a} vs {b}");
        }
        assert!(EnvLight::new(1, 0).is_err());
        assert!(e.backward(&[[1.0; 3]; 3]).is_err());
    }

    #[test]
    fn gradients_match_finite_differences_f64() {
        let mut rng = Rng::new(9);
        let (w, h) = (6, 3);
        let mut p: Vec<[f64; 3]> = (0..w * h).map(|_| [0, 1, 2].map(|_| 3.0 * rng.normal() as f64)).collect();
        let g: Vec<[f64; 3]> = (0..w * h).map(|_| [0, 1, 2].map(|_| rng.normal() as f64)).collect();
        let lin = |p: &[[f64; 3]]| -> f64 {
            env_radiance(p).iter().zip(&g).map(|(r, g)| (0..3).map(|c| r[c] * g[c]).sum::<f64>()).sum()
        };
        let tv = |p: &[[f64; 3]]| tv_l2(&env_radiance(p), w, h).0;
        let v_lin = env_radiance_backward(&p, &g);
        let v_tv = env_radiance_backward(&p, &tv_l2(&env_radiance(&p), w, h).1);
        let eps = 1e-6;
        for i in 0..w * h {
            for c in 0..3 {
                let x = p[i][c];
                p[i][c] = x + eps;
                let (a, b) = (lin(&p), tv(&p));
                p[i][c] = x - eps;
                let (a2, b2) = (lin(&p), tv(&p));
                p[i][c] = x;
                let fd = (a - a2) / (2.0 * eps);
                assert!((fd - v_lin[i][c]).abs() < 1e-7 * (1.0 + fd.abs()), "{fd} vs {}", v_lin[i][c]);
                let fd = (b - b2) / (2.0 * eps);
                assert!((fd - v_tv[i][c]).abs() < 1e-7 * (1.0 + fd.abs()), "tv {fd} vs {}", v_tv[i][c]);
            }
        }
        // A constant map has zero TV.
        let flat =
            EnvLight { width: 4, height: 2, param: vec![[0.3, 0.1, 2.0]; 8], activation: EnvActivation::Softplus };
        let (v, g) = flat.tv_l2(None);
        assert_eq!(v, 0.0);
        assert!(g.iter().flatten().all(|&x| x == 0.0));
    }

    #[test]
    fn exp_activation_and_masked_tv() {
        let soft = EnvLight::new(4, 2).unwrap();
        let e = soft.clone().with_activation(EnvActivation::Exp).unwrap();
        for (a, b) in soft.radiance().data.iter().flatten().zip(e.radiance().data.iter().flatten()) {
            assert!((a - b).abs() < 1e-5 * a.max(1.0), "{a} vs {b}");
        }
        let back = e.clone().with_activation(EnvActivation::Softplus).unwrap();
        assert!(back.param.iter().flatten().zip(soft.param.iter().flatten()).all(|(a, b)| (a - b).abs() < 1e-4));
        // d exp(x)/dx = exp(x), and the masked TV by central differences (f64 sums of f32 maps).
        let mut rng = Rng::new(4);
        let g: Vec<[f32; 3]> = (0..e.texels()).map(|_| [rng.normal(), rng.normal(), rng.normal()]).collect();
        let v = e.backward(&g).unwrap();
        let mut skip = vec![false; e.texels()];
        skip[9] = true;
        skip[20] = true;
        let (_, v_tv) = e.tv_l2(Some(&skip));
        let lin = |l: &EnvLight| -> f64 {
            l.radiance().data.iter().zip(&g).map(|(r, g)| (0..3).map(|c| (r[c] * g[c]) as f64).sum::<f64>()).sum()
        };
        for t in [0usize, 9, 13, 20] {
            for c in 0..3 {
                let (mut p, mut q) = (e.clone(), e.clone());
                p.param[t][c] += 1e-2;
                q.param[t][c] -= 1e-2;
                let fd = (lin(&p) - lin(&q)) / 2e-2;
                assert!((fd - v[t][c] as f64).abs() < 1e-3 * (1.0 + fd.abs()), "exp {t}: {fd} vs {}", v[t][c]);
                let fd = (p.tv_l2(Some(&skip)).0 as f64 - q.tv_l2(Some(&skip)).0 as f64) / 2e-2;
                assert!((fd - v_tv[t][c] as f64).abs() < 2e-3 * (1e-3 + fd.abs()), "tv {t}: {fd} vs {}", v_tv[t][c]);
            }
        }
        // A skipped texel is outside TV entirely: any value, zero gradient, same loss.
        assert!(v_tv[9].iter().chain(&v_tv[20]).all(|&x| x == 0.0));
        let mut sun = e.clone();
        sun.param[9] = [8.0; 3];
        assert_eq!(sun.tv_l2(Some(&skip)).0, e.tv_l2(Some(&skip)).0);
        assert!(sun.tv_l2(None).0 > 10.0 * e.tv_l2(None).0);
    }
}
