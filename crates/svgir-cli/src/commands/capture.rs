//! `svgir capture PHOTOS --out RUN`: the whole own-photos path in one command, each step
//! resuming where it stopped (a step whose result exists is skipped; a stage with a checkpoint
//! continues from it):
//!
//! 0. poses: PHOTOS as a dataset (COLMAP `sparse/` + `images/`, or `transforms.json`), or a
//!    folder of photos posed here with COLMAP (`automatic_reconstructor`, then
//!    `image_undistorter` into `RUN/colmap/dense`);
//! 1. stage 1 on the whole capture (`RUN/scene`, the capture profile);
//! 2. masks from that reconstruction (`RUN/masks`), or the user's `--masks DIR`;
//! 3. stage 1 on the object (`RUN/object`, the object profile);
//! 4. stage 2 and relighting under the maps shipped with the demo scene and any `--relight-with`
//!    (`RUN/object/stage2`);
//! 5. exports: textured mesh and splats (`RUN/export/object.glb`, `RUN/export/splats.glb`);
//! 6. the viewer (`RUN/object/viewer.html`), the object's report, and `RUN/report.html`: the
//!    masks first, then each step's figures, with links to the rest.

use super::{args_of, demo::EMBEDDED_SCENE, export, flag_list as flags, inverse, masks, report, train, view};
use anyhow::{bail, Context, Result};
use clap::Args;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

#[derive(Args)]
pub struct CaptureArgs {
    /// The photos: a folder of images to pose with COLMAP, or a posed capture (COLMAP or
    /// transforms.json).
    pub photos: PathBuf,
    /// Run folder (created; run the same command again to continue).
    #[arg(long, short)]
    pub out: PathBuf,
    /// Foreground masks of your own (one PNG per photo, white on the object) instead of step 2.
    #[arg(long)]
    pub masks: Option<PathBuf>,
    /// Train on the photos downscaled by this factor (the README's figures use 4 on 2 cores).
    #[arg(long, default_value_t = 4.0)]
    pub downscale: f32,
    /// Stage-1 iterations of steps 1 and 3.
    #[arg(long, default_value_t = 7000)]
    pub iterations: u64,
    /// Stage-2 iterations (step 4).
    #[arg(long, default_value_t = 1500)]
    pub stage2_iterations: u64,
    /// Directions of the relighting trace (SPEC 7: 384).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = svgir_train::relight::RELIGHT_DIRECTIONS)]
    pub relight_directions: usize,
    /// Also relight under this HDR map (repeatable).
    #[arg(long = "relight-with", value_name = "MAP.hdr")]
    pub relight_with: Vec<PathBuf>,
    /// Relit turntable frames per light.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 24)]
    pub turntable: usize,
    /// Where stage 1 trains and stage 2 traces and shades.
    #[arg(long, default_value_t = svgir_gpu::DeviceChoice::Auto)]
    pub device: svgir_gpu::DeviceChoice,
    /// Seed of every random choice.
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value_t = 0)]
    pub seed: u64,
    /// COLMAP's quality preset for posing a plain folder (low, medium, high, extreme).
    #[arg(hide_short_help = true, help_heading = super::ADVANCED, long, default_value = "high")]
    pub colmap_quality: String,
}

fn s(p: &Path) -> String {
    p.display().to_string()
}

/// Step 0: the dataset to train on, posing a plain folder of photos with COLMAP.
fn posed_dataset(args: &CaptureArgs) -> Result<PathBuf> {
    if !args.photos.is_dir() {
        bail!("{}: not a folder of photos or a capture", args.photos.display());
    }
    if svgir_io::detect_layout(&args.photos).is_ok() {
        return Ok(args.photos.clone());
    }
    let work = args.out.join("colmap");
    let dense = work.join("dense");
    if svgir_io::detect_layout(&dense).is_ok() {
        eprintln!("svgir capture: poses from {} (done before)", dense.display());
        return Ok(dense);
    }
    let colmap = |step: &str, a: &[String]| -> Result<()> {
        eprintln!("svgir capture: colmap {step} {}", a.join(" "));
        let status = Command::new("colmap").arg(step).args(a).status().map_err(|e| {
            anyhow::anyhow!(
                "{}: no poses, and COLMAP could not be started ({e}); install it (Debian/Ubuntu: `apt install colmap`) \
                 or give a posed capture",
                args.photos.display()
            )
        })?;
        anyhow::ensure!(status.success(), "colmap {step} failed ({status}) on {}", args.photos.display());
        Ok(())
    };
    std::fs::create_dir_all(&work).with_context(|| format!("creating {}", work.display()))?;
    // COLMAP's GPU SIFT needs an OpenGL context; without a display it would crash, so it runs
    // on the CPU there (Debian's build has no CUDA either way).
    let headless = std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none();
    colmap(
        "automatic_reconstructor",
        &flags(&[
            ("--workspace_path", s(&work)),
            ("--image_path", s(&args.photos)),
            ("--quality", args.colmap_quality.clone()),
            ("--use_gpu", if headless { "0" } else { "1" }.into()),
        ]),
    )?;
    let sparse = work.join("sparse/0");
    anyhow::ensure!(sparse.is_dir(), "{}: COLMAP posed no photos (no sparse/0)", args.photos.display());
    colmap(
        "image_undistorter",
        &flags(&[("--image_path", s(&args.photos)), ("--input_path", s(&sparse)), ("--output_path", s(&dense))]),
    )?;
    Ok(dense)
}

/// A stage-1 run's flags, continuing it when it has a checkpoint.
fn stage1(args: &CaptureArgs, data: &Path, out: &Path, extra: &[(&str, String)]) -> Result<()> {
    if out.join("point_cloud.ply").is_file() && out.join("eval.json").is_file() {
        eprintln!("svgir capture: {} (done before)", out.display());
        return Ok(());
    }
    let mut f = vec![s(data)];
    f.extend(flags(&[
        ("--out", s(out)),
        ("--iterations", args.iterations.to_string()),
        ("--downscale", args.downscale.to_string()),
        ("--device", args.device.to_string()),
        ("--seed", args.seed.to_string()),
    ]));
    f.extend(flags(extra));
    if out.join("checkpoint.bin").is_file() {
        f.push("--resume".into());
    }
    train::run(args_of("train", &f)?)
}

/// The relighting maps: the demo scene's, where the binary's source tree has them, and the user's.
fn relight_maps(args: &CaptureArgs) -> Vec<PathBuf> {
    let shipped = Path::new(EMBEDDED_SCENE).join("envmaps");
    let mut maps: Vec<PathBuf> = std::fs::read_dir(&shipped)
        .map(|d| d.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "hdr")).collect())
        .unwrap_or_default();
    maps.sort();
    if maps.is_empty() {
        eprintln!(
            "svgir capture: the demo scene's maps are not here ({}); relighting with --relight-with only",
            s(&shipped)
        );
    }
    maps.extend(args.relight_with.iter().cloned());
    maps
}

pub fn run(args: CaptureArgs) -> Result<()> {
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let data = posed_dataset(&args)?;
    let (scene, object) = (args.out.join("scene"), args.out.join("object"));

    // Steps 1-2: the masks, from a reconstruction of the whole capture unless given.
    let masks = match &args.masks {
        Some(m) => m.clone(),
        None => {
            stage1(&args, &data, &scene, &[("--profile", "capture".into())])?;
            let masks = args.out.join("masks");
            if scene.join("foreground.json").is_file() && masks.is_dir() {
                eprintln!("svgir capture: {} (done before)", masks.display());
            } else {
                let f = [s(&data)].into_iter().chain(flags(&[
                    ("--run", s(&scene)),
                    ("--out", s(&masks)),
                    ("--seed", args.seed.to_string()),
                ]));
                masks::run(args_of("masks", &f.collect::<Vec<_>>())?)?;
            }
            masks
        }
    };

    // Step 3: the object alone.
    stage1(&args, &data, &object, &[("--masks", s(&masks)), ("--background", "black".into())])?;

    // Step 4: materials, light and relighting.
    let stage2 = object.join("stage2");
    if stage2.join("eval.json").is_file() {
        eprintln!("svgir capture: {} (done before)", stage2.display());
    } else {
        let mut f = flags(&[
            ("--run", s(&object)),
            ("--iterations", args.stage2_iterations.to_string()),
            ("--relight-directions", args.relight_directions.to_string()),
            ("--turntable", args.turntable.to_string()),
            ("--seed", args.seed.to_string()),
            ("--device", args.device.to_string()),
        ]);
        for map in relight_maps(&args) {
            f.extend(["--relight-with".to_string(), s(&map)]);
        }
        if stage2.join("checkpoint.bin").is_file() {
            f.push("--resume".into());
        }
        inverse::run(args_of("inverse", &f)?)?;
    }

    // Step 5: assets other tools open.
    let exports = args.out.join("export");
    let (mesh, splats) = (exports.join("object.glb"), exports.join("splats.glb"));
    if mesh.is_file() && splats.is_file() {
        eprintln!("svgir capture: {} (done before)", exports.display());
    } else {
        std::fs::create_dir_all(&exports).with_context(|| format!("creating {}", exports.display()))?;
        let f = flags(&[("--run", s(&object)), ("--mesh", s(&mesh)), ("--splats", s(&splats))]);
        export::run(args_of("export", &f)?)?;
    }

    // Step 6: the viewer and the reports.
    if !object.join("viewer.html").is_file() {
        view::run(args_of("view", &[s(&object)])?)?;
    }
    report::write_report(&object, &object.join("report.html"))?;
    let page = args.out.join("report.html");
    write_capture_report(&args.out, &scene, &object, args.masks.is_some(), &page)?;
    println!("report: {}", page.display());
    Ok(())
}

fn read_json(path: &Path) -> Option<Value> {
    svgir_eval::read_json(path, "").ok()
}

/// `RUN/report.html`: the masks and their check first (where a capture goes wrong first), each
/// step's figures, and links to the object's own report, the viewer and the exports.
fn write_capture_report(out: &Path, scene: &Path, object: &Path, own_masks: bool, page: &Path) -> Result<()> {
    let mut html = String::from(
        "<!doctype html><html><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width, \
         initial-scale=1\"><title>svgir capture</title><style>body{font-family:sans-serif;max-width:1100px;margin:\
         auto;padding:1em}img{max-width:100%;height:auto}table{border-collapse:collapse}td,th{padding:2px 8px;\
         border-bottom:1px solid #ddd;text-align:left;overflow-wrap:anywhere}</style></head><body>\
         <h1>svgir capture</h1>",
    );
    html += "<h2>1. Masks</h2>";
    if own_masks {
        html += "<p>Masks given with <code>--masks</code>.</p>";
    } else if let Some(fg) = read_json(&scene.join("foreground.json")) {
        let conf = fg["confidence"].as_f64().unwrap_or(f64::NAN);
        html += &format!("<p>Confidence {conf:.2} (median over the photos; 1 is a framed, separated object).</p>");
        if let Ok(png) = std::fs::read(scene.join("masks_overview.png")) {
            html +=
                &format!("<img alt=\"masks over the photos\" src=\"data:image/png;base64,{}\">", report::base64(&png));
        }
        let mut rows: Vec<(String, f64, f64)> = fg["per_view"]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|v| {
                        let c = &v["check"];
                        (
                            v["view"].as_str().unwrap_or("").to_string(),
                            c["confidence"].as_f64().unwrap_or(f64::NAN),
                            c["coverage"].as_f64().unwrap_or(f64::NAN),
                        )
                    })
                    .collect()
            })
            .unwrap_or_default();
        rows.sort_by(|a, b| a.1.total_cmp(&b.1));
        html += "<table><tr><th>photo (least trusted first)</th><th>confidence</th><th>foreground</th></tr>";
        for (name, c, cov) in rows.iter().take(8) {
            html += &format!(
                "<tr><td>{}</td><td>{c:.2}</td><td>{:.0}%</td></tr>",
                svgir_view::page::html_escape(name),
                100.0 * cov
            );
        }
        html += "</table>";
    }
    let psnr = |run: &Path| {
        read_json(&run.join("eval.json")).and_then(|e| e["psnr"].as_f64()).map_or("-".into(), |p| format!("{p:.2} dB"))
    };
    html += "<h2>2. Reconstructions (held-out photos)</h2><table>";
    if !own_masks {
        html += &format!("<tr><td>stage 1, whole capture</td><td>{}</td></tr>", psnr(scene));
    }
    html += &format!("<tr><td>stage 1, object</td><td>{}</td></tr>", psnr(object));
    if let Some(e) = read_json(&object.join("stage2/eval.json")) {
        if let Some(p) = e["nvs"]["psnr"].as_f64() {
            html += &format!("<tr><td>stage 2, PBR re-render</td><td>{p:.2} dB</td></tr>");
        }
    }
    html += "</table>";
    let rel = |p: &Path| p.strip_prefix(out).unwrap_or(p).display().to_string();
    html += &format!(
        "<h2>3. Materials, light, relighting</h2><p><a href=\"{}\">The object's report</a> (relit views, \
         materials, curves) · <a href=\"{}\">interactive viewer</a> · exports: <a href=\"{}\">mesh</a>, \
         <a href=\"{}\">splats</a></p></body></html>",
        rel(&object.join("report.html")),
        rel(&object.join("viewer.html")),
        rel(&out.join("export/object.glb")),
        rel(&out.join("export/splats.glb")),
    );
    svgir_io::error::write_atomic(page, html.as_bytes())?;
    Ok(())
}
