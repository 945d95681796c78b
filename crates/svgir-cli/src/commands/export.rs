//! `svgir export --run RUN`: relightable assets for other tools.
//!
//! - `--mesh X.glb`: the surface of the stage-2 surfels (TSDF fusion of their rendered depth
//!   from the training cameras, surface nets, largest components, meshopt simplification), a
//!   per-triangle-pair UV atlas and the stage-2 materials baked into base colour,
//!   metallic-roughness and a tangent-space normal map, as glTF 2.0 binary; the learned light is
//!   written beside it as `X.hdr` (equirectangular, Blender's convention, +Z up in our world).
//! - `--mesh-ply X.ply`: the same surface untextured (also from a stage-1 run), for geometry
//!   checks; `--reference mesh.ply` measures the Chamfer distance against a true mesh.
//! - `--ply X.ply` / `--splats X.glb`: the Gaussians for splat viewers (see `export/splats.rs`).
//!
//! All outputs of one call are encoded in memory first and written all-or-nothing
//! (`svgir_export::files`), so a failure leaves no file behind.

use anyhow::{bail, Context, Result};
use clap::Args;
use glam::Vec3;
use serde_json::json;
use std::path::{Path, PathBuf};
use svgir_core::{Camera, EnvMap, Image, Surfels};
use svgir_export::{files, isosurface, mesh, tsdf, Mesh};

mod compare;
mod splats;

#[derive(Args)]
pub struct ExportArgs {
    /// Run folder from `svgir train` (with `stage2/` from `svgir inverse` for textured assets).
    #[arg(long)]
    pub run: PathBuf,
    /// Textured mesh as glTF binary (stage 2 required); the learned light goes beside it as `.hdr`.
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// The untextured surface as PLY (works on a stage-1 run too).
    #[arg(long)]
    pub mesh_ply: Option<PathBuf>,
    /// True mesh (PLY) to measure the Chamfer distance of the exported surface against.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Write the measurements (Chamfer, sizes, settings) to this JSON file.
    #[arg(long)]
    pub report_json: Option<PathBuf>,
    /// Gaussians as a 3DGS-layout PLY for splat viewers (radiance under --light, real normals,
    /// materials as extra columns).
    #[arg(long)]
    pub ply: Option<PathBuf>,
    /// Gaussians as a KHR_gaussian_splatting glTF binary (radiance under --light).
    #[arg(long)]
    pub splats: Option<PathBuf>,
    /// Light the splats' radiance is baked under (default: the learned light).
    #[arg(long)]
    pub light: Option<PathBuf>,
    /// Radiance = strength x map value for --light.
    #[arg(long, default_value_t = 1.0)]
    pub strength: f32,
    /// SH degree of the baked splat radiance (0-3).
    #[arg(long, default_value_t = 2)]
    pub splat_sh_degree: u32,
    /// Voxel side in world units (default: a pixel's footprint at the nearest camera / --detail).
    #[arg(long)]
    pub voxel: Option<f32>,
    /// Voxels per pixel footprint when the voxel size is derived from the cameras.
    #[arg(long, default_value_t = 1.0)]
    pub detail: f32,
    /// TSDF truncation in world units (default 5 voxels, as 2DGS).
    #[arg(long)]
    pub trunc: Option<f32>,
    /// Depths beyond this are ignored (default twice the farthest camera distance).
    #[arg(long)]
    pub depth_max: Option<f32>,
    /// Fuse the expected depth instead of the median depth (2DGS: median for bounded objects).
    #[arg(long)]
    pub mean_depth: bool,
    /// Keep components with at least this fraction of the largest one's triangles.
    #[arg(long, default_value_t = 0.05)]
    pub keep_fraction: f32,
    /// Triangle budget after simplification.
    #[arg(long, default_value_t = 30000)]
    pub triangles: usize,
    /// Stop simplifying before the surface moves more than this many voxels (default: the
    /// triangle budget decides).
    #[arg(long)]
    pub simplify_error: Option<f32>,
    /// Texture side in texels.
    #[arg(long, default_value_t = 2048)]
    pub texture: u32,
    /// Largest TSDF grid, in voxels.
    #[arg(long, default_value_t = 40_000_000)]
    pub max_voxels: usize,
    /// After writing --mesh: render it with three.js (headless Chromium) and with `svgir relight`
    /// under the exported light, and write both, their PSNR and a side-by-side image here.
    #[arg(long, requires = "mesh")]
    pub compare: Option<PathBuf>,
    /// Test view (index) for --compare.
    #[arg(long, default_value_t = 0)]
    pub compare_view: usize,
    /// Samples per surface for the Chamfer distance.
    #[arg(long, default_value_t = 200_000)]
    pub chamfer_samples: usize,
}

/// What the command extracted, for the report.
struct Extraction {
    mesh: Mesh,
    raw_triangles: usize,
    kept_triangles: usize,
    simplify_error: f32,
    params: tsdf::TsdfParams,
    dims: [u32; 3],
}

fn check_output(path: &Path, ext: &str, flag: &str) -> Result<()> {
    let ok = path.extension().is_some_and(|e| e.eq_ignore_ascii_case(ext));
    if !ok {
        bail!("{flag} {}: expected a .{ext} file name", path.display());
    }
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if !dir.is_dir() {
        bail!("{flag} {}: folder {} does not exist", path.display(), dir.display());
    }
    let meta = std::fs::metadata(dir).with_context(|| format!("{flag} {}: cannot inspect folder", path.display()))?;
    if meta.permissions().readonly() {
        bail!("{flag} {}: folder {} is read-only", path.display(), dir.display());
    }
    Ok(())
}

/// The surface of `surfels` from depth rendered at the `cameras`.
fn extract(args: &ExportArgs, surfels: &Surfels, cameras: &[Camera]) -> Result<Extraction> {
    if surfels.is_empty() {
        bail!("the model has no Gaussians: nothing to export");
    }
    let t0 = std::time::Instant::now();
    let depths: Vec<Vec<f32>> =
        cameras.iter().map(|c| tsdf::render_depth(surfels, c, !args.mean_depth)).collect::<Result<_, _>>()?;
    let views: Vec<tsdf::DepthView> =
        cameras.iter().zip(&depths).map(|(camera, depth)| tsdf::DepthView { camera, depth }).collect();
    let (lo, hi) = tsdf::depth_bounds(&views, 0.001)
        .context("the model renders no opaque pixel from any training camera: nothing to mesh")?;
    let derived = tsdf::TsdfParams::from_cameras(cameras, 0.5 * (lo + hi), args.detail)?;
    let voxel = args.voxel.unwrap_or(derived.voxel);
    let params = tsdf::TsdfParams {
        voxel,
        trunc: args.trunc.unwrap_or(5.0 * voxel),
        depth_max: args.depth_max.unwrap_or(derived.depth_max),
    };
    let pad = Vec3::splat(params.trunc + 2.0 * voxel);
    let grid = tsdf::fuse(lo - pad, hi + pad, &params, &views, args.max_voxels)?;
    let raw = isosurface::extract(&grid)?;
    let kept = mesh::keep_largest_components(&raw, args.keep_fraction);
    let (simplified, moved) = mesh::simplify(&kept, args.triangles, args.simplify_error.map(|e| e * voxel))?;
    eprintln!(
        "surface: {}x{}x{} voxels of {voxel:.4}, {} -> {} (largest components) -> {} triangles (moved <= {moved:.4}) in {:.1} s",
        grid.dims[0],
        grid.dims[1],
        grid.dims[2],
        raw.len(),
        kept.len(),
        simplified.len(),
        t0.elapsed().as_secs_f64()
    );
    Ok(Extraction {
        mesh: simplified,
        raw_triangles: raw.len(),
        kept_triangles: kept.len(),
        simplify_error: moved,
        params,
        dims: grid.dims,
    })
}

/// The light as an equirectangular image of at least 128 rows (bilinear from the learned map).
pub fn light_image(map: &EnvMap) -> Image {
    let h = map.height.max(128);
    let w = 2 * h;
    let mut img = Image::new(w, h, 3);
    for j in 0..h {
        let phi = (j as f32 + 0.5) / h as f32 * std::f32::consts::PI;
        for i in 0..w {
            let theta = (0.5 - (i as f32 + 0.5) / w as f32) * 2.0 * std::f32::consts::PI;
            let d = Vec3::new(phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos());
            img.pixel_mut(i, j).copy_from_slice(&map.lookup(d));
        }
    }
    img
}

pub fn run(args: ExportArgs) -> Result<()> {
    let wants_stage2 = args.mesh.is_some() || args.ply.is_some() || args.splats.is_some();
    if !wants_stage2 && args.mesh_ply.is_none() {
        bail!("nothing to export: give --mesh, --mesh-ply, --ply and/or --splats");
    }
    for (p, ext, flag) in [
        (&args.mesh, "glb", "--mesh"),
        (&args.mesh_ply, "ply", "--mesh-ply"),
        (&args.ply, "ply", "--ply"),
        (&args.splats, "glb", "--splats"),
    ] {
        if let Some(p) = p {
            check_output(p, ext, flag)?;
        }
    }
    if !args.run.join("config.json").is_file() {
        bail!("{}: not a run folder (no config.json from `svgir train`)", args.run.display());
    }
    let s2_path = args.run.join("stage2").join("checkpoint.bin");
    let s2 = if s2_path.is_file() {
        Some(svgir_train::checkpoint::load_stage2(&s2_path).with_context(|| s2_path.display().to_string())?)
    } else if wants_stage2 {
        bail!(
            "{}: no stage-2 model ({} is missing). Materials and light come from stage 2: run `svgir inverse --run {}` \
             first (a stage-1 run can export its untextured surface with --mesh-ply)",
            args.run.display(),
            s2_path.display(),
            args.run.display()
        );
    } else {
        None
    };
    let (dataset, _) = svgir_eval::load_run_dataset(&args.run, None)?;
    let cameras: Vec<Camera> = dataset.train.iter().map(|v| v.camera).collect();
    let stage1;
    let surfels = match &s2 {
        Some(s2) => &s2.surfels,
        None => {
            let p = args.run.join("checkpoint.bin");
            stage1 = svgir_train::checkpoint::load(&p, &dataset).with_context(|| p.display().to_string())?;
            &stage1.surfels
        }
    };
    let mut outputs: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    let mut report =
        json!({ "run": args.run, "command": std::env::args().collect::<Vec<_>>(), "gaussians": surfels.len() });
    if args.mesh.is_some() || args.mesh_ply.is_some() {
        let ex = extract(&args, surfels, &cameras)?;
        report["surface"] = json!({
            "voxel": ex.params.voxel, "trunc": ex.params.trunc, "depth_max": ex.params.depth_max, "grid": ex.dims,
            "depth": if args.mean_depth { "expected" } else { "median" },
            "triangles_raw": ex.raw_triangles, "triangles_kept": ex.kept_triangles, "triangles": ex.mesh.len(),
            "simplify_error": ex.simplify_error,
        });
        if let Some(reference) = &args.reference {
            let truth = files::read_mesh_ply(reference)?;
            let (lo, hi) = truth.bounds().context("reference mesh has no triangles")?;
            let diag = (hi - lo).length() as f64;
            let c = svgir_export::chamfer::chamfer(&ex.mesh, &truth, args.chamfer_samples, 0)?;
            println!(
                "Chamfer vs {}: {:.5} ({:.3}% of the {diag:.3} bounding-box diagonal; accuracy {:.5}, completeness {:.5})",
                reference.display(),
                c.chamfer,
                100.0 * c.chamfer / diag,
                c.accuracy,
                c.completeness
            );
            report["chamfer"] = json!({
                "reference": reference, "diagonal": diag, "chamfer": c.chamfer, "accuracy": c.accuracy,
                "completeness": c.completeness, "chamfer_percent_of_diagonal": 100.0 * c.chamfer / diag,
                "samples": args.chamfer_samples,
            });
        }
        if let Some(p) = &args.mesh_ply {
            outputs.push((p.clone(), files::encode_mesh_ply(&ex.mesh)));
        }
        if let (Some(p), Some(s2)) = (&args.mesh, &s2) {
            let t0 = std::time::Instant::now();
            let atlas = svgir_export::build_atlas(&ex.mesh, args.texture, 1.0)?;
            let act = s2.materials.activated(&s2.normals)?;
            let field = svgir_export::GaussianField {
                surfels,
                normals: &s2.normals,
                m: act.m,
                albedo: &act.albedo,
                roughness: &act.roughness,
                shading_normals: &act.normals,
            };
            let tex = svgir_export::bake_textures(&atlas, field, 2.0 * ex.params.voxel)?;
            let name = p.file_stem().map_or("svgir".into(), |s| s.to_string_lossy().into_owned());
            let glb = svgir_export::gltf::mesh_glb(&atlas, &tex, &name)?;
            let hdr = svgir_io::image_io::encode_hdr(&light_image(&s2.env.radiance()))
                .map_err(|e| anyhow::anyhow!("encoding the light: {e}"))?;
            eprintln!(
                "baked {}x{} textures ({:.1}% of texels covered by a Gaussian) in {:.1} s",
                args.texture,
                args.texture,
                100.0 * tex.covered,
                t0.elapsed().as_secs_f64()
            );
            report["mesh_glb"] =
                json!({ "path": p, "bytes": glb.len(), "texture": args.texture, "covered": tex.covered });
            outputs.push((p.clone(), glb));
            outputs.push((p.with_extension("hdr"), hdr));
        }
    }
    if let Some(s2) = &s2 {
        if args.ply.is_some() || args.splats.is_some() {
            splats::export(&args, s2, &mut outputs, &mut report)?;
        }
    }
    if let Some(p) = &args.report_json {
        outputs.push((p.clone(), serde_json::to_vec_pretty(&report)?));
    }
    files::write_all_or_nothing(&outputs)?;
    for (p, b) in &outputs {
        println!("wrote {} ({} bytes)", p.display(), b.len());
    }
    if let (Some(dir), Some(glb), Some(s2)) = (&args.compare, &args.mesh, &s2) {
        compare::compare(s2, &dataset, glb, &glb.with_extension("hdr"), args.compare_view, dir)?;
    }
    Ok(())
}
