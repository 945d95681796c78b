//! The ground-truth materials (`svgir inverse --gt-materials`): a diagnostic that replaces the learned albedo and
//! roughness by the dataset's ground truth before the evaluation, so the relighting scores
//! measure our geometry, visibility, one-bounce indirect and shading with perfect materials: the
//! ceiling of the relighting pipeline on that scene, to compare with the learned materials.
//!
//! Each Gaussian first takes the mean ground-truth albedo and roughness at its centre's pixel over
//! the training views that see it ([`visible_from`]), on every vertex (Gaussians seen in no view
//! keep their learned materials). That projection blurs textures finer than a surfel, so
//! [`fit`] then fits the vertex materials to the ground-truth maps through the rasteriser (the
//! splatted albedo and roughness against the training views' maps, L2 over the mask), which is
//! what the learned materials could reach at best. Normal offsets and opacities stay as learned.

use crate::adam::AdamGroup;
use crate::orient::visible_from;
use crate::Stage2;
use svgir_core::Dataset;
use svgir_pbr::material::{albedo_raw_for, roughness_raw_for};
use svgir_pbr::PbrError;
use svgir_raster::{backward, render, Background, ColorSource, Features, OutputGrads, RenderInput};

/// How many Gaussians got ground-truth materials, and from how many views.
pub struct OracleStats {
    /// Gaussians that took ground-truth materials.
    pub assigned: usize,
    /// All Gaussians.
    pub total: usize,
    /// Training views with ground-truth albedo and roughness.
    pub views: usize,
}

/// Gives every Gaussian seen by a training view the mean ground-truth albedo and roughness at its
/// centre's pixel, on all its vertices.
pub fn apply(s2: &mut Stage2, ds: &Dataset) -> Result<OracleStats, PbrError> {
    let n = s2.surfels.len();
    // Per Gaussian: albedo r, g, b, roughness, count.
    let mut acc = vec![[0.0f64; 5]; n];
    let mut views = 0;
    for v in &ds.train {
        let (Some(alb), Some(rough)) = (&v.albedo, &v.roughness) else { continue };
        views += 1;
        let seen = visible_from(&s2.surfels, &v.camera, &s2.raster);
        for (i, a) in acc.iter_mut().enumerate() {
            if !seen[i] {
                continue;
            }
            // Visible implies in front of the camera and inside the image.
            let Some((x, y, _)) = v.camera.project(s2.surfels.positions[i]) else { continue };
            let (xi, yi) = (x as u32, y as u32);
            let c = alb.pixel(xi, yi);
            for ch in 0..3 {
                a[ch] += c[ch] as f64;
            }
            a[3] += rough.pixel(xi, yi)[0] as f64;
            a[4] += 1.0;
        }
    }
    let m = s2.materials.m;
    let mut assigned = 0;
    for (i, a) in acc.iter().enumerate() {
        if a[4] == 0.0 {
            continue;
        }
        assigned += 1;
        for vtx in 0..m {
            let k = i * m + vtx;
            for ch in 0..3 {
                s2.materials.albedo_raw[3 * k + ch] = albedo_raw_for((a[ch] / a[4]) as f32);
            }
            s2.materials.roughness_raw[k] = roughness_raw_for((a[3] / a[4]) as f32);
        }
    }
    Ok(OracleStats { assigned, total: n, views })
}

/// Fit the vertex albedo and roughness to the ground-truth maps of the training views for
/// `epochs` passes over them (Adam on the raw parameters, lr 0.05). The loss per view is the
/// mean over GT-masked pixels of the squared error of the splatted albedo and roughness, each
/// divided by the rendered opacity as the evaluation does (no gradient through the opacity,
/// which stays fixed). Returns the last epoch's mean loss.
pub fn fit(s2: &mut Stage2, ds: &Dataset, epochs: usize) -> Result<f64, PbrError> {
    const CH: usize = 4;
    let m = s2.materials.m;
    let rows = s2.materials.albedo_raw.len() / (3 * m);
    let mut g_albedo = AdamGroup::new("albedo", 0.05, 3 * m, rows);
    let mut g_rough = AdamGroup::new("roughness", 0.05, m, rows);
    let views: Vec<_> = ds.train.iter().filter_map(|v| Some((v, v.albedo.as_ref()?, v.roughness.as_ref()?))).collect();
    let mut last = 0.0;
    for _ in 0..epochs {
        let mut sum = 0.0;
        for &(v, alb, rough) in &views {
            let act = s2.materials.activated(&s2.normals)?;
            let feats: Vec<f32> = (0..rows * m)
                .flat_map(|k| [act.albedo[3 * k], act.albedo[3 * k + 1], act.albedo[3 * k + 2], act.roughness[k]])
                .collect();
            let input = RenderInput {
                surfels: &s2.surfels,
                camera: &v.camera,
                colors: ColorSource::Sh,
                extra: Some(Features { data: &feats, vertices: m, channels: CH, uniform: 0 }),
                background: Background::Color([0.0; 3]),
            };
            let (out, state) = render(&input, &s2.raster);
            let npix = out.alpha.len();
            let mask: Vec<bool> = crate::stage1::alpha_of(&v.image).iter().map(|a| *a > 0.5).collect();
            let count = mask.iter().filter(|b| **b).count().max(1) as f32;
            let ac = alb.channels as usize;
            let mut v_extra = vec![0.0f32; npix * CH];
            let mut loss = 0.0f64;
            for p in (0..npix).filter(|p| mask[*p]) {
                let a = out.alpha[p].max(1e-3);
                let gt = [
                    alb.data[ac * p],
                    alb.data[ac * p + 1],
                    alb.data[ac * p + 2],
                    rough.data[p * rough.channels as usize],
                ];
                for c in 0..CH {
                    let r = out.extra[CH * p + c] / a - gt[c];
                    loss += (r * r) as f64;
                    v_extra[CH * p + c] = 2.0 * r / a / count;
                }
            }
            sum += loss / count as f64;
            let grads = OutputGrads { extra: Some(&v_extra), ..Default::default() };
            let g = backward(&input, &s2.raster, &state, &out, &grads);
            let v_albedo: Vec<f32> = (0..rows * m).flat_map(|k| [0, 1, 2].map(|c| g.v_extra[CH * k + c])).collect();
            let v_rough: Vec<f32> = (0..rows * m).map(|k| g.v_extra[CH * k + 3]).collect();
            let mg = s2.materials.backward(&s2.normals, &v_albedo, &v_rough, &vec![0.0; v_albedo.len()])?;
            g_albedo.step(&mut s2.materials.albedo_raw, &mg.v_albedo_raw);
            g_rough.step(&mut s2.materials.roughness_raw, &mg.v_roughness_raw);
        }
        last = sum / views.len().max(1) as f64;
    }
    Ok(last)
}
