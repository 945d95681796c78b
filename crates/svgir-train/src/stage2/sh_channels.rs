//! The SH image of Eqn 15 splatted inside the PBR pass, so that one backward serves both images.
//!
//! SPEC 6 freezes the geometry, so the SH pass and the PBR pass composite the same entries with
//! the same alphas (the PBR pass reuses the SH pass's projection, `svgir_raster::FeatureRaster::render`). Training gives
//! every vertex of a Gaussian that Gaussian's SH colour as three more extra channels of the PBR
//! pass, declared uniform (`svgir_raster::FeaturesOf::uniform`): the kernels read them once per
//! Gaussian instead of interpolating a constant, so they composite to the SH pass's `sum w c`
//! (to rounding), and with the background `bg (1 - A)` they are its image. The PBR pass's
//! backward then gives the SH image's gradients too:
//! - each Gaussian's colour gradient is the sum of its vertices' SH-channel gradients (all at
//!   vertex 0 with uniform channels), which
//!   `svgir_raster::sh_colors_backward` takes to the SH coefficients;
//! - the opacities' gradient comes with the PBR image's, and the background's share enters
//!   through the opacity output `A`.
//!
//! The SH pass's own backward, a second walk over every tile, is not run. Its forward still runs:
//! it finds the Gaussians the view blends, which are the only ones shaded.

use super::objective::{write_extra_features, EXTRA_CHANNELS};
use crate::losses::CHUNK;
use rayon::prelude::*;
use svgir_core::par::filled;
use svgir_pbr::ActivatedMaterials;

/// Channels of the SH colour.
pub const SH_CHANNELS: usize = 3;
/// Extra channels of training's PBR pass: the materials' ([`EXTRA_CHANNELS`]), then the SH colour.
pub const PASS_CHANNELS: usize = EXTRA_CHANNELS + SH_CHANNELS;

/// Per-vertex extra channels of training's PBR pass: [`super::objective::extra_features`]'s, then
/// the vertex's Gaussian's SH colour (`sh_colors`, one per Gaussian, `act.m` vertices each).
pub fn pass_features(act: &ActivatedMaterials, facing: &[f32], sh_colors: &[[f32; 3]]) -> Vec<f32> {
    let m = act.m;
    let mut out = filled(act.roughness.len() * PASS_CHANNELS, 0.0f32);
    write_extra_features(act, facing, &mut out, PASS_CHANNELS);
    out.par_chunks_exact_mut(PASS_CHANNELS).enumerate().with_min_len(CHUNK).for_each(|(v, e)| {
        e[EXTRA_CHANNELS..].copy_from_slice(&sh_colors[v / m]);
    });
    out
}

/// The PBR pass's extra output (`PASS_CHANNELS` per pixel) as the material channels
/// ([`EXTRA_CHANNELS`] per pixel) and the SH image over `bg`: `sum w c + bg (1 - alpha)`.
pub fn split_pass(extra: &[f32], alpha: &[f32], bg: [f32; 3]) -> (Vec<f32>, Vec<f32>) {
    let npix = alpha.len();
    assert_eq!(extra.len(), npix * PASS_CHANNELS, "split_pass: extra channels of {npix} pixels");
    let mut materials = filled(npix * EXTRA_CHANNELS, 0.0f32);
    let mut sh_image = filled(npix * 3, 0.0f32);
    (materials.par_chunks_exact_mut(EXTRA_CHANNELS), sh_image.par_chunks_exact_mut(3))
        .into_par_iter()
        .zip(extra.par_chunks_exact(PASS_CHANNELS).zip(alpha))
        .with_min_len(CHUNK)
        .for_each(|((mat, sh), (e, &a))| {
            mat.copy_from_slice(&e[..EXTRA_CHANNELS]);
            for c in 0..3 {
                sh[c] = e[EXTRA_CHANNELS + c] + bg[c] * (1.0 - a);
            }
        });
    (materials, sh_image)
}

/// Adjoint of [`split_pass`]: the gradient of the pass's extra channels from those of the material
/// channels (`v_materials`) and the SH image (`v_sh_image`); the background's share,
/// `-sum_c bg_c v_c`, is added to `v_alpha`.
pub fn join_pass_grads(v_materials: &[f32], v_sh_image: &[f32], bg: [f32; 3], v_alpha: &mut [f32]) -> Vec<f32> {
    let npix = v_alpha.len();
    assert!(
        v_materials.len() == npix * EXTRA_CHANNELS && v_sh_image.len() == npix * 3,
        "join_pass_grads: gradients of {npix} pixels"
    );
    let mut v_extra = filled(npix * PASS_CHANNELS, 0.0f32);
    v_extra
        .par_chunks_exact_mut(PASS_CHANNELS)
        .zip(v_alpha.par_iter_mut())
        .zip(v_materials.par_chunks_exact(EXTRA_CHANNELS).zip(v_sh_image.par_chunks_exact(3)))
        .with_min_len(CHUNK)
        .for_each(|((e, va), (vm, vs))| {
            e[..EXTRA_CHANNELS].copy_from_slice(vm);
            e[EXTRA_CHANNELS..].copy_from_slice(vs);
            *va -= bg[0] * vs[0] + bg[1] * vs[1] + bg[2] * vs[2];
        });
    v_extra
}

/// Per Gaussian, the gradient of its SH colour: the sum of its `m` vertices' SH-channel
/// gradients in `v_pass` (the PBR pass's extra-channel gradients, [`PASS_CHANNELS`] per vertex).
pub fn sh_colour_grads(v_pass: &[f32], m: usize) -> Vec<[f32; 3]> {
    v_pass
        .par_chunks_exact(m * PASS_CHANNELS)
        .with_min_len(CHUNK)
        .map(|g| {
            let mut s = [0.0f32; 3];
            for v in g.chunks_exact(PASS_CHANNELS) {
                for c in 0..3 {
                    s[c] += v[EXTRA_CHANNELS + c];
                }
            }
            s
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init;
    use glam::Vec3;
    use svgir_core::Rng;
    use svgir_raster::fixtures::look_at_camera;
    use svgir_raster::{backward, render, Background, ColorSource, Features, OutputGrads, RasterConfig, RenderInput};

    fn random(rng: &mut Rng, n: usize) -> Vec<f32> {
        (0..n).map(|_| rng.uniform() * 2.0 - 1.0).collect()
    }

    /// `join_pass_grads` is the adjoint of `split_pass` (affine in the extra channels and the
    /// opacity): `<J x, y> = <x, J^T y>` for the linear part.
    #[test]
    fn join_is_the_adjoint_of_split() {
        let mut rng = Rng::new(3);
        let npix = 37;
        let bg = [0.2, 0.7, 0.4];
        let (extra, alpha) = (random(&mut rng, npix * PASS_CHANNELS), random(&mut rng, npix));
        let (vm, vs) = (random(&mut rng, npix * EXTRA_CHANNELS), random(&mut rng, npix * 3));
        // J applied to (extra, alpha) = split minus its value at zero (the constant bg).
        let (m1, s1) = split_pass(&extra, &alpha, bg);
        let (_, s0) = split_pass(&vec![0.0; npix * PASS_CHANNELS], &vec![0.0; npix], bg);
        let jx: f64 = m1.iter().zip(&vm).map(|(a, b)| (a * b) as f64).sum::<f64>()
            + s1.iter().zip(&s0).zip(&vs).map(|((a, z), b)| ((a - z) * b) as f64).sum::<f64>();
        let mut v_alpha = vec![0.0; npix];
        let v_extra = join_pass_grads(&vm, &vs, bg, &mut v_alpha);
        let jty: f64 = v_extra.iter().zip(&extra).map(|(a, b)| (a * b) as f64).sum::<f64>()
            + v_alpha.iter().zip(&alpha).map(|(a, b)| (a * b) as f64).sum::<f64>();
        assert!((jx - jty).abs() < 1e-4 * jx.abs().max(1.0), "{jx} vs {jty}");
        // Each part matters: the SH image's gradient reaches both the channels and the opacity.
        assert!(v_alpha.iter().any(|&a| a.abs() > 1e-3));
        assert_eq!(&v_extra[EXTRA_CHANNELS..PASS_CHANNELS], &vs[..3]);
    }

    #[test]
    fn colour_gradients_sum_a_gaussians_vertices() {
        let (m, n) = (4, 3);
        let v: Vec<f32> = (0..n * m * PASS_CHANNELS).map(|i| i as f32).collect();
        let g = sh_colour_grads(&v, m);
        for (i, gi) in g.iter().enumerate() {
            for c in 0..3 {
                let want: f32 = (0..m).map(|k| ((i * m + k) * PASS_CHANNELS + EXTRA_CHANNELS + c) as f32).sum();
                assert_eq!(gi[c], want);
            }
        }
    }

    /// The PBR pass's backward with the SH channels gives the gradients of the SH pass's own
    /// backward: the opacities' and the SH coefficients', for a loss on the SH image alone.
    #[test]
    fn the_pbr_pass_backward_gives_the_sh_pass_gradients() {
        let mut rng = Rng::new(11);
        let pts = init::random_box_points(300, 0.6, &mut rng);
        let mut surfels = init::surfels_from_points(&pts, 3, &mut rng);
        let n = surfels.len();
        for o in surfels.opacity_logits.iter_mut() {
            *o = rng.normal();
        }
        for c in surfels.sh.iter_mut() {
            for k in 1..16 {
                for ch in 0..3 {
                    c.0[k][ch] = 0.3 * rng.normal();
                }
            }
        }
        let (w, h) = (48u32, 40u32);
        let npix = (w * h) as usize;
        let cam = look_at_camera(Vec3::new(2.0, -1.5, 1.0).normalize() * 3.0, 0.8, w, h);
        let bg = [0.3, 0.6, 0.1];
        let cfg = super::super::raster_config();
        let sh_raster = RasterConfig { geometry: false, ..cfg };
        let sh_input = RenderInput {
            surfels: &surfels,
            camera: &cam,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color(bg),
        };
        let (sh_out, sh_state) = render(&sh_input, &sh_raster);
        let v_image = random(&mut rng, npix * 3);
        let separate = backward(
            &sh_input,
            &sh_raster,
            &sh_state,
            &sh_out,
            &OutputGrads { color: Some(&v_image), ..Default::default() },
        );

        let m = 4;
        let unit = |rng: &mut Rng| Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        let act = ActivatedMaterials {
            m,
            albedo: (0..n * m * 3).map(|_| rng.uniform()).collect(),
            roughness: (0..n * m).map(|_| rng.uniform()).collect(),
            normals: (0..n * m).flat_map(|_| unit(&mut rng).to_array()).collect(),
        };
        let facing: Vec<f32> = (0..n).map(|i| if i % 3 == 0 { -1.0 } else { 1.0 }).collect();
        let extra = pass_features(&act, &facing, sh_state.sh_colors());
        let colours: Vec<f32> = (0..n * m * 3).map(|_| rng.uniform()).collect();
        let pbr_input = RenderInput {
            surfels: &surfels,
            camera: &cam,
            colors: ColorSource::Features(Features { data: &colours, vertices: m, channels: 3, uniform: 0 }),
            extra: Some(Features { data: &extra, vertices: m, channels: PASS_CHANNELS, uniform: SH_CHANNELS }),
            background: Background::Color([0.0; 3]),
        };
        let (pbr_out, pbr_state) = svgir_raster::try_render_reusing(&pbr_input, &cfg, &sh_state.projected())
            .expect("M = 4 reuses the SH pass's projection");
        let (_, sh_image) = split_pass(&pbr_out.extra, &pbr_out.alpha, bg);
        let diff = sh_image.iter().zip(&sh_out.color).fold(0.0f32, |d, (a, b)| d.max((a - b).abs()));
        assert!(diff < 1e-5, "the SH image from the PBR pass is {diff} off the SH pass's");

        let mut v_alpha = vec![0.0; npix];
        let v_pass = join_pass_grads(&vec![0.0; npix * EXTRA_CHANNELS], &v_image, bg, &mut v_alpha);
        let zeros = vec![0.0; npix * 3];
        let grads =
            OutputGrads { color: Some(&zeros), alpha: Some(&v_alpha), extra: Some(&v_pass), ..Default::default() };
        let fused = backward(&pbr_input, &cfg, &pbr_state, &pbr_out, &grads);
        let v_sh =
            svgir_raster::sh_colors_backward(&sh_input, &sh_state.projected(), &sh_colour_grads(&fused.v_extra, m))
                .expect("an SH render");

        let close = |what: &str, got: &[f32], want: &[f32]| {
            let scale = want.iter().fold(0.0f32, |s, v| s.max(v.abs()));
            let err = got.iter().zip(want).fold(0.0f32, |d, (a, b)| d.max((a - b).abs()));
            assert!(scale > 1e-3, "{what}: the loss reaches it");
            assert!(err <= 1e-4 * scale, "{what}: {err} off, of {scale}");
        };
        close("opacity logits", &fused.v_opacity_logits, &separate.v_opacity_logits);
        close("SH coefficients", bytemuck::cast_slice(&v_sh), bytemuck::cast_slice(&separate.v_sh));
        // The background's share through the opacity matters: without it the opacities differ.
        let mut no_alpha = vec![0.0; npix];
        let no_bg = join_pass_grads(&vec![0.0; npix * EXTRA_CHANNELS], &v_image, [0.0; 3], &mut no_alpha);
        let g = backward(
            &pbr_input,
            &cfg,
            &pbr_state,
            &pbr_out,
            &OutputGrads { alpha: Some(&no_alpha), extra: Some(&no_bg), ..grads },
        );
        let err =
            g.v_opacity_logits.iter().zip(&separate.v_opacity_logits).fold(0.0f32, |d, (a, b)| d.max((a - b).abs()));
        assert!(err > 1e-2, "{err}");
    }
}
