//! Gaussians for splat viewers.
//!
//! - [`fit_sh`]: view-dependent colour samples of one Gaussian -> SH coefficients (weighted
//!   least squares with a small ridge, 3DGS's convention `colour = 0.5 + sum_k c_k Y_k(dir)`
//!   with `dir` from the camera to the Gaussian), how radiance shaded under a light becomes a
//!   radiance field viewers can draw. The 16x16 normal equations are solved by a hand-written
//!   Cholesky in f64 (no linear-algebra crate for one fixed small system).
//! - [`oriented`]: surfels turned so their normal (rotation z axis) is the stage-2 oriented
//!   normal: a half turn about the tangent u axis, which leaves the splat's shape unchanged.
//! - [`splat_glb`]: a `KHR_gaussian_splatting` glTF binary (Khronos, 2025): POINTS primitive with
//!   POSITION, COLOR_0 (fallback colour and opacity), `KHR_gaussian_splatting:ROTATION` (unit
//!   xyzw), `:SCALE` (log), `:OPACITY` (sigmoid applied), `:SH_DEGREE_l_COEF_m`, kernel
//!   `ellipse`, colour space `srgb_rec709_display`; material columns as application-specific
//!   attributes (`_ALBEDO`, `_ROUGHNESS`, `_NORMAL`). Written in glTF's +Y-up frame directly (no
//!   node rotation, so no viewer has to rotate SH coefficients): positions, rotations and the
//!   fitted directions are all turned by [`to_y_up`].

use crate::gltf::{glb_bytes, GlbBuilder};
use crate::ExportError;
use glam::{Quat, Vec3};
use serde_json::{json, Value};
use svgir_core::sh::{basis, num_coeffs};
use svgir_core::{ShCoeffs, Surfels};

/// ln(1e-3): third scale of a flat surfel relative to its smaller axis (as `svgir_io::ply`).
pub const FLAT_LOG_RATIO: f32 = -6.907_755;

/// Our +Z-up world to glTF's +Y-up frame: (x, y, z) -> (x, z, -y).
pub fn to_y_up(v: Vec3) -> Vec3 {
    Vec3::new(v.x, v.z, -v.y)
}

/// The rotation [`to_y_up`] applies, as a quaternion.
pub fn y_up_rotation() -> Quat {
    Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2)
}

/// Least-squares SH of degree `degree` for colours `colours[i]` seen along `dirs[i]` (camera ->
/// Gaussian), weighted by `weights[i]`, with ridge `lambda` on every coefficient but the DC.
pub fn fit_sh(dirs: &[Vec3], colours: &[[f32; 3]], weights: &[f32], degree: u32, lambda: f64) -> ShCoeffs {
    let k = num_coeffs(degree);
    let mut ata = [[0.0f64; 16]; 16];
    let mut atb = [[0.0f64; 3]; 16];
    let mut b = [0.0f32; 16];
    for ((d, c), &w) in dirs.iter().zip(colours).zip(weights) {
        basis(degree, d.normalize_or(Vec3::Z), &mut b);
        for i in 0..k {
            for j in 0..k {
                ata[i][j] += w as f64 * b[i] as f64 * b[j] as f64;
            }
            for ch in 0..3 {
                atb[i][ch] += w as f64 * b[i] as f64 * (c[ch] as f64 - 0.5);
            }
        }
    }
    for (i, row) in ata.iter_mut().enumerate().take(k) {
        row[i] += if i == 0 { 1e-9 } else { lambda };
    }
    let x = cholesky_solve(&ata, &atb, k);
    let mut out = ShCoeffs::default();
    for i in 0..k {
        out.0[i] = x[i].map(|v| v as f32);
    }
    out
}

/// Solves `A x = B` (A symmetric positive definite, `k` x `k`, three right-hand sides).
fn cholesky_solve(a: &[[f64; 16]; 16], b: &[[f64; 3]; 16], k: usize) -> [[f64; 3]; 16] {
    let mut l = [[0.0f64; 16]; 16];
    for i in 0..k {
        for j in 0..=i {
            let s: f64 = (0..j).map(|p| l[i][p] * l[j][p]).sum();
            if i == j {
                l[i][i] = (a[i][i] - s).max(1e-12).sqrt();
            } else {
                l[i][j] = (a[i][j] - s) / l[j][j];
            }
        }
    }
    let mut y = [[0.0f64; 3]; 16];
    for i in 0..k {
        for ch in 0..3 {
            let s: f64 = (0..i).map(|p| l[i][p] * y[p][ch]).sum();
            y[i][ch] = (b[i][ch] - s) / l[i][i];
        }
    }
    let mut x = [[0.0f64; 3]; 16];
    for i in (0..k).rev() {
        for ch in 0..3 {
            let s: f64 = (i + 1..k).map(|p| l[p][i] * x[p][ch]).sum();
            x[i][ch] = (y[i][ch] - s) / l[i][i];
        }
    }
    x
}

/// `s` with each surfel turned (half turn about its u axis) where its normal disagrees with
/// `normals`, so the rotation's z axis is the oriented normal.
pub fn oriented(s: &Surfels, normals: &[Vec3]) -> Surfels {
    let mut out = s.clone();
    for i in 0..s.len() {
        if s.normal(i).dot(normals[i]) < 0.0 {
            out.rotations[i] = s.rotations[i].normalize() * Quat::from_rotation_x(std::f32::consts::PI);
        }
    }
    out
}

/// One extra per-Gaussian attribute: `_NAME` with `comps` floats per Gaussian.
pub struct ExtraAttribute {
    /// Attribute name without the leading underscore (upper case by glTF custom).
    pub name: String,
    /// Values per Gaussian (1, 3 or 4).
    pub comps: usize,
    /// `n * comps` values.
    pub data: Vec<f32>,
}

/// The splats as a `KHR_gaussian_splatting` GLB (module docs). `s` is in our +Z-up world with
/// SH coefficients already fitted in the +Y-up frame; directions in `extras` named `NORMAL`
/// are turned too.
pub fn splat_glb(s: &Surfels, extras: &[ExtraAttribute]) -> Result<Vec<u8>, ExportError> {
    s.check().map_err(ExportError::Invalid)?;
    let n = s.len();
    if n == 0 {
        return Err(ExportError::Degenerate("no Gaussians to write".into()));
    }
    let r = y_up_rotation();
    let mut b = GlbBuilder::default();
    let pos: Vec<f32> = s.positions.iter().flat_map(|p| to_y_up(*p).to_array()).collect();
    let rot: Vec<f32> = s.rotations.iter().flat_map(|q| (r * q.normalize()).normalize().to_array()).collect();
    let scale: Vec<f32> = s.log_scales.iter().flat_map(|l| [l.x, l.y, l.x.min(l.y) + FLAT_LOG_RATIO]).collect();
    let opacity: Vec<f32> = (0..n).map(|i| s.opacity(i)).collect();
    let colour: Vec<f32> = (0..n)
        .flat_map(|i| {
            let c = s.sh[i].0[0].map(|v| (0.5 + svgir_core::sh::SH_C0 * v).clamp(0.0, 1.0));
            [c[0], c[1], c[2], opacity[i]]
        })
        .collect();
    let mut attrs = serde_json::Map::new();
    attrs.insert("POSITION".into(), json!(b.push_floats(&pos, 3, "VEC3", true)?));
    attrs.insert("COLOR_0".into(), json!(b.push_floats(&colour, 4, "VEC4", false)?));
    attrs.insert("KHR_gaussian_splatting:ROTATION".into(), json!(b.push_floats(&rot, 4, "VEC4", false)?));
    attrs.insert("KHR_gaussian_splatting:SCALE".into(), json!(b.push_floats(&scale, 3, "VEC3", false)?));
    attrs.insert("KHR_gaussian_splatting:OPACITY".into(), json!(b.push_floats(&opacity, 1, "SCALAR", false)?));
    for degree in 0..=s.sh_degree {
        for m in 0..(2 * degree + 1) as usize {
            let k = (degree * degree) as usize + m;
            let data: Vec<f32> = s.sh.iter().flat_map(|c| c.0[k]).collect();
            let name = format!("KHR_gaussian_splatting:SH_DEGREE_{degree}_COEF_{m}");
            attrs.insert(name, json!(b.push_floats(&data, 3, "VEC3", false)?));
        }
    }
    for e in extras {
        let ty = match e.comps {
            1 => "SCALAR",
            3 => "VEC3",
            4 => "VEC4",
            c => return Err(ExportError::Invalid(format!("extra attribute {} has {c} components", e.name))),
        };
        if e.data.len() != n * e.comps {
            return Err(ExportError::Invalid(format!(
                "extra attribute {} has {} values for {n} Gaussians",
                e.name,
                e.data.len()
            )));
        }
        let data: Vec<f32> = if e.name == "NORMAL" && e.comps == 3 {
            e.data.chunks_exact(3).flat_map(|c| to_y_up(Vec3::from_slice(c)).to_array()).collect()
        } else {
            e.data.clone()
        };
        attrs.insert(format!("_{}", e.name), json!(b.push_floats(&data, e.comps, ty, false)?));
    }
    let json: Value = json!({
        "asset": { "version": "2.0", "generator": "svgir export" },
        "extensionsUsed": ["KHR_gaussian_splatting"],
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "name": "svgir splats", "mesh": 0 }],
        "meshes": [{ "name": "svgir splats", "primitives": [{
            "attributes": attrs,
            "mode": 0,
            "extensions": { "KHR_gaussian_splatting": {
                "kernel": "ellipse", "colorSpace": "srgb_rec709_display",
                "sortingMethod": "cameraDistance", "projection": "perspective" } }
        }] }],
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": b.buffer(),
    });
    glb_bytes(&json, &b.bin)
}

/// `n` unit directions spread evenly over the whole sphere (Fibonacci lattice), the view
/// directions the radiance of a splat is sampled from before the SH fit.
pub fn sphere_directions(n: usize) -> Vec<Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            Vec3::new(r * (golden * i as f32).cos(), r * (golden * i as f32).sin(), z)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    #[test]
    fn sh_fit_recovers_a_degree_two_field() {
        let mut truth = ShCoeffs::default();
        for k in 0..9 {
            truth.0[k] = [0.3 / (k + 1) as f32, -0.2 * (k as f32 - 4.0) / 9.0, 0.1];
        }
        let dirs = sphere_directions(200);
        let cols: Vec<[f32; 3]> = dirs.iter().map(|d| truth.eval(2, *d)).collect();
        let fit = fit_sh(&dirs, &cols, &vec![1.0; dirs.len()], 2, 1e-9);
        for k in 0..9 {
            for ch in 0..3 {
                assert!(
                    (fit.0[k][ch] - truth.0[k][ch]).abs() < 1e-4,
                    "coef {k} ch {ch}: {:?} vs {:?}",
                    fit.0[k],
                    truth.0[k]
                );
            }
        }
    }

    #[test]
    fn orienting_flips_only_disagreeing_normals_and_keeps_the_disc() {
        let mut s = Surfels::with_capacity(2, 0);
        s.push(Vec3::ZERO, Quat::from_rotation_y(0.3), Vec2::new(0.1, -0.4), 0.0, ShCoeffs::default());
        s.push(Vec3::X, Quat::from_rotation_y(0.3), Vec2::new(0.1, -0.4), 0.0, ShCoeffs::default());
        let n0 = s.normal(0);
        let o = oriented(&s, &[n0, -n0]);
        assert!((o.normal(0) - n0).length() < 1e-6);
        assert!((o.normal(1) + n0).length() < 1e-5);
        // Same tangent u axis (up to sign), so the same ellipse.
        assert!(o.rotation_matrix(1).x_axis.dot(s.rotation_matrix(1).x_axis).abs() > 0.9999);
    }

    #[test]
    fn splat_glb_has_the_extension_attributes() {
        let mut s = Surfels::with_capacity(3, 1);
        for i in 0..3 {
            s.push(Vec3::splat(i as f32), Quat::IDENTITY, Vec2::splat(-2.0), 1.0, ShCoeffs::from_rgb([0.2, 0.5, 0.9]));
        }
        let extras = [ExtraAttribute { name: "ROUGHNESS".into(), comps: 1, data: vec![0.5; 3] }];
        let bytes = splat_glb(&s, &extras).unwrap();
        let (json, bin) = crate::gltf::parse_glb(&bytes).unwrap();
        let prim = &json["meshes"][0]["primitives"][0];
        assert_eq!(prim["mode"], 0);
        for a in [
            "POSITION",
            "COLOR_0",
            "KHR_gaussian_splatting:SCALE",
            "KHR_gaussian_splatting:SH_DEGREE_1_COEF_2",
            "_ROUGHNESS",
        ] {
            let acc = prim["attributes"][a].as_u64().unwrap_or_else(|| panic!("{a} missing")) as usize;
            assert_eq!(json["accessors"][acc]["count"], 3);
        }
        assert!(prim["attributes"].get("KHR_gaussian_splatting:SH_DEGREE_2_COEF_0").is_none());
        // Opacity is the sigmoid of the logit, read back from the buffer.
        let acc = &json["accessors"][prim["attributes"]["KHR_gaussian_splatting:OPACITY"].as_u64().unwrap() as usize];
        let view = &json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let off = view["byteOffset"].as_u64().unwrap() as usize;
        let v = f32::from_le_bytes(bin[off..off + 4].try_into().unwrap());
        assert!((v - svgir_core::surfel::sigmoid(1.0)).abs() < 1e-6);
        assert!(splat_glb(&Surfels::default(), &[]).is_err());
    }
}
