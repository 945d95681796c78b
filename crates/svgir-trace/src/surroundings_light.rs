//! Light the object receives from its surroundings under a new map (our addition to SPEC 7's
//! relighting, issue 75).
//!
//! The surroundings (the rest of a capture, traced as occluders: [`crate::SURROUNDINGS_HIT`])
//! have no material, only their captured colour `c_s(w)`, the SH colour a ray along `w` reads
//! off them ([`crate::traverse::hit_colour`], as SPEC 5's traced radiance does). Relighting's
//! one-bounce gather (Eqn 13) has nothing to shade them with, so a ray from the object that ends
//! on surroundings Gaussian s would bring no light. Here it brings
//!
//! `L(w) = c_s(w) * (E_new(n_s) + eps) / (E_learned(n_s) + eps)`   per channel,
//!
//! the captured colour scaled by how the new map changes the irradiance of the side of s that
//! faces the ray (`n_s` turned towards `-w`): the radiance of a diffuse surface is proportional
//! to its irradiance, and the learned light stands for the light the photos were taken under.
//! Both irradiances are unoccluded (`E(n) = sum_t L_t Omega_t max(0, n . w_t)` over the maps'
//! texels), so the surroundings' own shadowing is assumed to scale alike under both maps: their
//! shadows do not move with the new light. `eps`, a thousandth of the learned map's uniform
//! irradiance (`pi` times its mean radiance), keeps a side the learned light leaves dark from
//! taking an unbounded gain.
//!
//! Work split: the gains per surroundings Gaussian and side (an irradiance sum over the texels),
//! then the samples, each written alone; rayon over Gaussians in both. Nothing is trained through
//! it, so there is no backward.

use crate::microbuffer::MicroBuffer;
use crate::traverse::{hit_colour, TraceParams};
use crate::TraceError;
use glam::Vec3;
use rayon::prelude::*;
use svgir_core::{EnvMap, Surfels};

/// Share of the learned map's uniform irradiance added to both irradiances of a gain.
pub const GAIN_EPS: f32 = 1e-3;

/// A map's texels as (direction, radiance x solid angle): what an irradiance sums.
fn weighted_texels(env: &EnvMap) -> Vec<(Vec3, [f32; 3])> {
    let mut out = Vec::with_capacity((env.width * env.height) as usize);
    for row in 0..env.height {
        for col in 0..env.width {
            let l = env.data[(row * env.width + col) as usize];
            let omega = env.texel_solid_angle(row, col);
            if l.iter().any(|&c| c != 0.0) {
                out.push((env.texel_dir(row, col), l.map(|c| c * omega)));
            }
        }
    }
    out
}

fn irradiance_of(texels: &[(Vec3, [f32; 3])], n: Vec3) -> [f32; 3] {
    let mut e = [0.0f32; 3];
    for (d, l) in texels {
        let c = n.dot(*d);
        if c > 0.0 {
            for ch in 0..3 {
                e[ch] += l[ch] * c;
            }
        }
    }
    e
}

/// Unoccluded irradiance `E(n) = sum_t L_t Omega_t max(0, n . w_t)` of a map at unit normal `n`
/// (the texels' solid angles of [`EnvMap::texel_solid_angle`]).
pub fn irradiance(env: &EnvMap, n: Vec3) -> [f32; 3] {
    irradiance_of(&weighted_texels(env), n)
}

/// The learned light's irradiance of each surroundings Gaussian's two sides, computed once per
/// model and shared by every new map ([`SurroundingsGain::new`]).
#[derive(Clone, Debug)]
pub struct LearnedIrradiance {
    /// Per surroundings Gaussian: its normals `[n, -n]` and the learned irradiance of each.
    sides: Vec<[(Vec3, [f32; 3]); 2]>,
    eps: f32,
}

impl LearnedIrradiance {
    /// The irradiance of both sides of every Gaussian of `surroundings` under `learned`.
    pub fn new(surroundings: &Surfels, learned: &EnvMap) -> Self {
        let texels = weighted_texels(learned);
        let sides = (0..surroundings.len())
            .into_par_iter()
            .map(|s| {
                let n = surroundings.normal(s);
                [(n, irradiance_of(&texels, n)), (-n, irradiance_of(&texels, -n))]
            })
            .collect();
        let mean = learned.mean_radiance();
        let eps = GAIN_EPS * std::f32::consts::PI * (mean[0] + mean[1] + mean[2]) / 3.0;
        Self { sides, eps: eps.max(f32::MIN_POSITIVE) }
    }

    /// Surroundings Gaussians covered.
    pub fn len(&self) -> usize {
        self.sides.len()
    }

    /// True when there are no surroundings.
    pub fn is_empty(&self) -> bool {
        self.sides.is_empty()
    }
}

/// Per surroundings Gaussian and side, how a new map scales its captured colour.
#[derive(Clone, Debug)]
pub struct SurroundingsGain {
    /// `[gain of n, gain of -n]` per Gaussian, RGB.
    gains: Vec<[[f32; 3]; 2]>,
    normals: Vec<Vec3>,
}

impl SurroundingsGain {
    /// The gains of `new` over the learned light (see the module note).
    pub fn new(learned: &LearnedIrradiance, new: &EnvMap) -> Self {
        let texels = weighted_texels(new);
        let eps = learned.eps;
        let gains = learned
            .sides
            .par_iter()
            .map(|sides| {
                sides.map(|(n, e_old)| {
                    let e_new = irradiance_of(&texels, n);
                    std::array::from_fn(|ch| (e_new[ch] + eps) / (e_old[ch] + eps))
                })
            })
            .collect();
        Self { gains, normals: learned.sides.iter().map(|s| s[0].0).collect() }
    }

    /// The gain of surroundings Gaussian `s` seen along `w` (the side facing `-w`).
    pub fn gain(&self, s: usize, w: Vec3) -> [f32; 3] {
        self.gains[s][usize::from(self.normals[s].dot(w) > 0.0)]
    }

    /// Surroundings Gaussians covered.
    pub fn len(&self) -> usize {
        self.gains.len()
    }

    /// True when there are no surroundings.
    pub fn is_empty(&self) -> bool {
        self.gains.is_empty()
    }
}

/// Adds to `light[j * K + k]` (a gather's one-bounce light of the micro-buffer `mb`) the relit
/// captured colour of the surroundings Gaussian each sample's ray ended on, `c_s(w) gain_s(w)`
/// (module note), with `surroundings` the Gaussians traced past the object and `p` the trace's
/// parameters (how colours are read). Returns how many samples took light; on an error (a ray
/// ending on a Gaussian that `gain` does not cover) `light` is left partly added.
pub fn add_surroundings_light(
    mb: &MicroBuffer,
    surroundings: &Surfels,
    gain: &SurroundingsGain,
    p: &TraceParams,
    light: &mut [[f32; 3]],
) -> Result<usize, TraceError> {
    let k = mb.k;
    if light.len() != mb.len() * k {
        return Err(TraceError::SizeMismatch { what: "one-bounce light", got: light.len(), want: mb.len() * k });
    }
    if gain.len() != surroundings.len() {
        return Err(TraceError::SizeMismatch { what: "surroundings gains", got: gain.len(), want: surroundings.len() });
    }
    if k == 0 {
        return Ok(0);
    }
    // One pass: each row checks its own indices as it adds (a caller that gets the error drops
    // the light, so rows added before it do not matter).
    light
        .par_chunks_mut(k)
        .enumerate()
        .map(|(j, row)| {
            let mut count = 0;
            for (kk, out) in row.iter_mut().enumerate() {
                let Some(s) = mb.surroundings_hit(j, kk) else { continue };
                let s = s as usize;
                if s >= gain.len() {
                    return Err(TraceError::InvalidParameter(format!(
                        "a micro-buffer ray ends on surroundings Gaussian {s} of {}",
                        gain.len()
                    )));
                }
                let w = mb.direction(j, kk);
                let c = hit_colour(&surroundings.sh[s], surroundings.sh_degree, w, p);
                let g = gain.gain(s, w);
                for ch in 0..3 {
                    out[ch] += c[ch] * g[ch];
                }
                count += 1;
            }
            Ok(count)
        })
        .try_reduce(|| 0, |a, b| Ok(a + b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_uniform_map_gives_pi_l_and_a_texel_its_cosine() {
        let env = EnvMap::constant(64, 32, [1.0, 2.0, 0.5]);
        for n in [Vec3::Z, -Vec3::Z, Vec3::X, Vec3::new(0.3, -0.5, 0.81).normalize()] {
            let e = irradiance(&env, n);
            for (ch, want) in [1.0f32, 2.0, 0.5].iter().enumerate() {
                let want = std::f32::consts::PI * want;
                assert!((e[ch] - want).abs() < 2e-3 * want, "{n}: {e:?}");
            }
        }
        let mut one = EnvMap::constant(64, 32, [0.0; 3]);
        one.data[(10 * 64 + 20) as usize] = [3.0; 3];
        let (d, omega) = (one.texel_dir(10, 20), one.texel_solid_angle(10, 20));
        let n = Vec3::new(0.2, 0.4, 0.9).normalize();
        assert_eq!(irradiance(&one, n)[0], 3.0 * omega * n.dot(d).max(0.0));
        assert_eq!(irradiance(&one, -d)[0], 0.0);
    }

    #[test]
    fn the_gain_is_the_side_facing_the_ray() {
        // A floor facing +z under a uniform learned light; the new light comes from above only.
        let mut s = Surfels::default();
        s.push(Vec3::ZERO, glam::Quat::IDENTITY, glam::Vec2::splat(-3.0), 2.0, svgir_core::ShCoeffs([[0.0; 3]; 16]));
        let learned = LearnedIrradiance::new(&s, &EnvMap::constant(64, 32, [1.0; 3]));
        let mut sky = EnvMap::constant(64, 32, [0.0; 3]);
        for row in 0..16 {
            for col in 0..64 {
                sky.data[(row * 64 + col) as usize] = [2.0; 3];
            }
        }
        let gain = SurroundingsGain::new(&learned, &sky);
        let top = gain.gain(0, -Vec3::Z); // a ray going down meets the top side
        let bottom = gain.gain(0, Vec3::Z);
        // Top: the sky's irradiance is 2 pi (its texels reach the equator's row, whose half
        // counts), against pi: a gain near 2. Bottom: only the equator's row reaches it.
        assert!((top[0] - 2.0).abs() < 0.05, "{top:?}");
        assert!(bottom[0] < 0.05, "{bottom:?}");
        assert_eq!(gain.gain(0, Vec3::new(0.1, 0.0, -1.0).normalize()), top);
    }
}
