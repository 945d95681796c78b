//! The light as the viewer sees it (the page's `web/light.js` implements the same functions):
//! SH coefficients of a rotated environment map, a chain of GGX-prefiltered copies of the map
//! for the specular term, the hand-written bilinear-plus-level lookup into it, and the analytic
//! split-sum factor of the specular BRDF.
//!
//! Maps are the SPEC 4 lat-long grid (H x 2H, aligned corners, +Z up). Rotating the light by
//! `angle` about +Z gives `L'(w) = L(Rz(-angle) w)`; the SH projection uses the rotated texel
//! directions and the prefiltered lookup un-rotates the query, so nothing is re-filtered.

use glam::Vec3;
use svgir_core::sh::{basis, num_coeffs};
use svgir_core::EnvMap;

/// Roughness of prefiltered level `l` is `LEVEL_R0 + l * LEVEL_STEP` (SPEC 3's range 0.09..0.99).
pub const LEVEL_R0: f32 = 0.09;
/// Roughness step between prefiltered levels.
pub const LEVEL_STEP: f32 = 0.18;
/// Prefiltered levels: level 0 is the map itself (a lobe of roughness 0.09 is narrower than a
/// texel of the 32 x 64 map), levels 1..5 are GGX-convolved.
pub const LEVELS: usize = 6;

/// Rotation about +Z by `angle` radians.
pub fn rotate_z(d: Vec3, angle: f32) -> Vec3 {
    let (s, c) = angle.sin_cos();
    Vec3::new(c * d.x - s * d.y, s * d.x + c * d.y, d.z)
}

/// SH coefficients (`(degree + 1)^2`, RGB) of `env` rotated by `angle` about +Z and scaled by
/// `strength`: `L_j = sum_t L_t Y_j(Rz(angle) w_t) Omega_t` with the texels' bilinear solid
/// angles ([`EnvMap::texel_solid_angle`]).
pub fn project_sh(env: &EnvMap, degree: u32, angle: f32, strength: f32) -> Vec<[f32; 3]> {
    let c = num_coeffs(degree);
    let mut acc = vec![[0.0f64; 3]; c];
    let mut b = [0.0f32; 16];
    for r in 0..env.height {
        for col in 0..env.width {
            let d = rotate_z(env.texel_dir(r, col), angle);
            basis(degree, d, &mut b);
            let w = env.texel_solid_angle(r, col) as f64;
            let l = env.data[(r * env.width + col) as usize];
            for j in 0..c {
                for ch in 0..3 {
                    acc[j][ch] += w * b[j] as f64 * l[ch] as f64;
                }
            }
        }
    }
    acc.iter().map(|a| a.map(|v| (v * strength as f64) as f32)).collect()
}

/// GGX normal distribution `D(n.h)` with `alpha = r^2` (SPEC 4).
pub fn ggx_d(nh: f32, r: f32) -> f32 {
    let a2 = (r * r) * (r * r);
    let t = nh * nh * (a2 - 1.0) + 1.0;
    a2 / (std::f32::consts::PI * t * t)
}

/// The prefiltered chain: [`LEVELS`] maps of `env`'s size, stacked (level-major, row-major).
/// Level `l > 0` at direction `R` is the split-sum convolution with `n = v = R`:
/// `sum_t L_t w_t / sum_t w_t`, `w_t = D(R.h_t; r_l) max(0, R.w_t) Omega_t`, `h_t = norm(R + w_t)`.
pub fn prefilter(env: &EnvMap) -> Vec<[f32; 3]> {
    let (w, h) = (env.width, env.height);
    let texels: Vec<(Vec3, f32, [f32; 3])> = (0..h)
        .flat_map(|r| (0..w).map(move |c| (r, c)))
        .map(|(r, c)| (env.texel_dir(r, c), env.texel_solid_angle(r, c), env.data[(r * w + c) as usize]))
        .collect();
    let mut out = env.data.clone();
    for level in 1..LEVELS {
        let rough = LEVEL_R0 + level as f32 * LEVEL_STEP;
        for r in 0..h {
            for c in 0..w {
                let dir = env.texel_dir(r, c);
                let (mut acc, mut wsum) = ([0.0f64; 3], 0.0f64);
                for &(d, omega, l) in &texels {
                    let nl = dir.dot(d);
                    if nl <= 0.0 {
                        continue;
                    }
                    let hv = (dir + d).normalize();
                    let wt = (ggx_d(dir.dot(hv), rough) * nl * omega) as f64;
                    for ch in 0..3 {
                        acc[ch] += wt * l[ch] as f64;
                    }
                    wsum += wt;
                }
                out.push(acc.map(|a| if wsum > 0.0 { (a / wsum) as f32 } else { 0.0 }));
            }
        }
    }
    out
}

/// Bilinear lookup of level `level` of a prefiltered chain (SPEC 4's grid and taps).
pub fn lookup_level(chain: &[[f32; 3]], width: u32, height: u32, level: usize, d: Vec3) -> [f32; 3] {
    let [fx, fy] = svgir_core::envmap::grid_coords(width, height, d);
    let t = svgir_core::envmap::Taps::at(fx, fy, width, height);
    let base = level * (width * height) as usize;
    let mut c = [0.0f32; 3];
    for k in 0..4 {
        let v = chain[base + t.index[k] as usize];
        for ch in 0..3 {
            c[ch] += t.weight[k] * v[ch];
        }
    }
    c
}

/// Prefiltered radiance around `r_dir` for roughness `rough`: linear between the two nearest
/// levels, of a light rotated by `angle` about +Z.
pub fn lookup_prefiltered(
    chain: &[[f32; 3]],
    width: u32,
    height: u32,
    r_dir: Vec3,
    rough: f32,
    angle: f32,
) -> [f32; 3] {
    let d = rotate_z(r_dir, -angle);
    let lv = ((rough - LEVEL_R0) / LEVEL_STEP).clamp(0.0, (LEVELS - 1) as f32);
    let l0 = lv.floor() as usize;
    let l1 = (l0 + 1).min(LEVELS - 1);
    let t = lv - l0 as f32;
    let a = lookup_level(chain, width, height, l0, d);
    let b = lookup_level(chain, width, height, l1, d);
    [0, 1, 2].map(|ch| a[ch] + (b[ch] - a[ch]) * t)
}

/// Karis's analytic fit of the split-sum BRDF integral (Unreal Engine 4 mobile): the specular
/// reflectance under a prefiltered light is `F0 * A + B`.
pub fn env_brdf(rough: f32, nv: f32) -> (f32, f32) {
    let c0 = [-1.0f32, -0.0275, -0.572, 0.022];
    let c1 = [1.0f32, 0.0425, 1.04, -0.04];
    let r = [0, 1, 2, 3].map(|k| rough * c0[k] + c1[k]);
    let a004 = (r[0] * r[0]).min((-9.28 * nv).exp2()) * r[0] + r[1];
    (-1.04 * a004 + r[2], 1.04 * a004 + r[3])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_map_projects_to_its_dc_and_prefilters_to_itself() {
        let env = EnvMap::constant(64, 32, [2.0, 1.0, 0.5]);
        let sh = project_sh(&env, 2, 0.7, 1.5);
        // Integral of a constant c over the sphere against Y_00: c * 4 pi * Y_00.
        let want = 4.0 * std::f32::consts::PI * svgir_core::sh::SH_C0 * 1.5;
        for (ch, v) in [2.0f32, 1.0, 0.5].iter().enumerate() {
            assert!((sh[0][ch] - want * v).abs() < 1e-3 * want * v, "{:?}", sh[0]);
        }
        // Higher bands vanish up to the quadrature error of texel-centre sampling (~0.3% of DC
        // for Y_20 at 32 rows).
        for j in 1..9 {
            assert!(sh[j].iter().all(|v| v.abs() < 5e-3 * want * 2.0), "{j}: {:?}", sh[j]);
        }
        let chain = prefilter(&env);
        assert_eq!(chain.len(), LEVELS * 64 * 32);
        assert!(chain.iter().all(|c| (c[0] - 2.0).abs() < 1e-4 && (c[2] - 0.5).abs() < 1e-4));
    }

    #[test]
    fn rotating_the_light_moves_its_sh_and_lookup() {
        // A map bright towards +X only: rotated by 90 degrees it lights +Y.
        let mut env = EnvMap::constant(32, 16, [0.0; 3]);
        for r in 0..16 {
            for c in 0..32 {
                if env.texel_dir(r, c).dot(Vec3::X) > 0.8 {
                    env.data[(r * 32 + c) as usize] = [1.0; 3];
                }
            }
        }
        let sh = project_sh(&env, 1, std::f32::consts::FRAC_PI_2, 1.0);
        // Band 1 is (-y, z, -x) * C1: the light towards +Y makes coefficient 1 negative, 3 ~ 0.
        assert!(sh[1][0] < -0.1 && sh[3][0].abs() < 1e-3, "{sh:?}");
        let chain = prefilter(&env);
        let lit = lookup_prefiltered(&chain, 32, 16, Vec3::Y, 0.09, std::f32::consts::FRAC_PI_2);
        let dark = lookup_prefiltered(&chain, 32, 16, Vec3::X, 0.09, std::f32::consts::FRAC_PI_2);
        assert!(lit[0] > 0.9 && dark[0] < 0.1, "{lit:?} {dark:?}");
    }

    #[test]
    fn env_brdf_is_a_plausible_reflectance() {
        for &r in &[0.09f32, 0.5, 0.99] {
            for &nv in &[1e-6f32, 0.3, 1.0] {
                let (a, b) = env_brdf(r, nv);
                let f = 0.04 * a + b;
                assert!((0.0..=1.0).contains(&f), "r {r} nv {nv}: {f}");
            }
        }
        // Smooth surfaces seen head-on reflect about F0.
        let (a, b) = env_brdf(0.09, 1.0);
        assert!((0.04 * a + b - 0.04).abs() < 0.01);
    }
}
