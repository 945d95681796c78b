//! `svgir inverse --oracle-materials`: a diagnostic that replaces the learned albedo and
//! roughness by the dataset's ground truth before the evaluation, so the relighting scores
//! measure our geometry, visibility, one-bounce indirect and shading with perfect materials: the
//! ceiling of the relighting pipeline on that scene, to compare with the learned materials.
//!
//! Each Gaussian takes the mean ground-truth albedo and roughness at its centre's pixel over the
//! training views that see it ([`visible_from`]). Every vertex of a Gaussian gets that value;
//! normal offsets and opacities stay as learned. Gaussians seen in no view keep their learned materials.

use anyhow::Result;
use svgir_core::Dataset;
use svgir_pbr::material::{albedo_raw_for, roughness_raw_for};
use svgir_train::orient::visible_from;
use svgir_train::Stage2;

/// How many Gaussians got ground-truth materials, and from how many views.
pub struct OracleStats {
    pub assigned: usize,
    pub total: usize,
    pub views: usize,
}

pub fn apply(s2: &mut Stage2, ds: &Dataset) -> Result<OracleStats> {
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
