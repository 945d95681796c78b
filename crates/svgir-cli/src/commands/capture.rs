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
//!    (`RUN/object/stage2`), with step 1's model of the rest of the scene kept as occluder and
//!    indirect light (`svgir inverse --surroundings`; `--object-alone` leaves it out);
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
    /// Train on the photos downscaled by this factor (default: 4 on the CPU; on a GPU the photos'
    /// own size, at most 1600 px wide).
    #[arg(long)]
    pub downscale: Option<f32>,
    /// Stage-1 iterations of steps 1 and 3 (default: 7000 on the CPU, SPEC's 30000 on a GPU).
    #[arg(long)]
    pub iterations: Option<u64>,
    /// Learn a per-photo colour correction in both stage-1 steps (photos of varying exposure or
    /// white balance: a phone on auto, a photo collection); on by itself when the photos' EXIF
    /// names several cameras or exposures.
    #[arg(long)]
    pub exposure: bool,
    /// Stage 2 on the object alone: without the rest of the capture (step 1's model near the
    /// object, outside its masks) as occluder and source of indirect light.
    #[arg(long)]
    pub object_alone: bool,
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

/// The photo size and stage-1 length the run trains with, and whether it learns per-photo
/// colour corrections: chosen once (by the device, by the photos' EXIF) and kept in
/// `RUN/capture.json` so that a continued run (on any device) trains as it began.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
struct Sizing {
    /// `--downscale`, or `--resolution` (a width), or neither (the photos' own size).
    downscale: Option<f32>,
    resolution: Option<u32>,
    iterations: u64,
    /// `--exposure` in both stage-1 steps.
    #[serde(default)]
    exposure: bool,
}

/// The object step's binary-opacity term: fewer, opaque surfels, whose stage-2 traces meet
/// fewer faint rims. Measured on the rendered table capture (docs/capture.md): 2585 Gaussians
/// instead of 4374, the K = 64 trace 1.8 s instead of 3.4 s, held-out views 0.1 dB lower.
const OBJECT_WEIGHTS: &str = "opacity_binary=0.05";

/// Widest photos a GPU run trains on at their own size (3DGS's rule: wider ones are scaled to it).
const GPU_MAX_WIDTH: u32 = 1600;

impl Sizing {
    /// The defaults: on the CPU a quarter of the photos' size and 7000 iterations (a run of
    /// about an hour on 2 cores); on a hardware GPU the photos' own size up to 1600 px wide and
    /// SPEC 2's 30000 iterations. Explicit options win.
    fn defaults(gpu: bool, photo_width: u32, downscale: Option<f32>, iterations: Option<u64>) -> Self {
        let iterations = iterations.unwrap_or(if gpu { 30_000 } else { 7000 });
        let exposure = false;
        match downscale {
            Some(d) => Self { downscale: Some(d), resolution: None, iterations, exposure },
            None if !gpu => Self { downscale: Some(4.0), resolution: None, iterations, exposure },
            None => Self {
                downscale: None,
                resolution: (photo_width > GPU_MAX_WIDTH).then_some(GPU_MAX_WIDTH),
                iterations,
                exposure,
            },
        }
    }

    fn flags(&self) -> Vec<(&'static str, String)> {
        let mut f = vec![("--iterations", self.iterations.to_string())];
        if let Some(d) = self.downscale {
            f.push(("--downscale", d.to_string()));
        }
        if let Some(r) = self.resolution {
            f.push(("--resolution", r.to_string()));
        }
        f
    }

    fn describe(&self) -> String {
        let size = match (self.downscale, self.resolution) {
            (Some(d), _) => format!("photos downscaled {d}x"),
            (None, Some(r)) => format!("photos at {r} px wide"),
            (None, None) => "photos at their own size".into(),
        };
        let corrections = if self.exposure { ", a colour correction per photo" } else { "" };
        format!("{size}, {} stage-1 iterations{corrections}", self.iterations)
    }

    /// The run's sizing: `RUN/capture.json` when the run was begun (options given now win and
    /// are kept), else the device's defaults for these photos.
    fn of_run(args: &CaptureArgs, data: &Path) -> Result<Self> {
        let path = args.out.join("capture.json");
        let kept: Option<Sizing> = match std::fs::read_to_string(&path) {
            Ok(text) => Some(
                serde_json::from_str(&text).with_context(|| format!("{}: not a capture's settings", path.display()))?,
            ),
            Err(_) => None,
        };
        let sizing = match kept {
            Some(k) => Sizing {
                downscale: args.downscale.or(k.downscale),
                resolution: if args.downscale.is_some() { None } else { k.resolution },
                iterations: args.iterations.unwrap_or(k.iterations),
                exposure: args.exposure || k.exposure,
            },
            None => {
                let gpu = match svgir_gpu::open(args.device)? {
                    Some(g) => g.report.device_type != "Cpu",
                    None => false,
                };
                let one = svgir_io::LoadOptions { load_test: false, max_views: Some(1), ..Default::default() };
                let width = svgir_io::load_dataset(data, &one)?.train.first().map_or(0, |v| v.camera.width());
                let mut sizing = Self::defaults(gpu, width, args.downscale, args.iterations);
                sizing.exposure = args.exposure;
                if !args.exposure {
                    let settings = photo_settings(&args.photos, &args.out);
                    if let Some(why) = varying_exposure(&settings) {
                        eprintln!("svgir capture: {why}: learning a colour correction per photo (as --exposure)");
                        sizing.exposure = true;
                    }
                }
                sizing
            }
        };
        let text = serde_json::to_string_pretty(&sizing)?;
        svgir_io::error::write_atomic(&path, text.as_bytes())?;
        eprintln!("svgir capture: {} ({})", sizing.describe(), s(&path));
        Ok(sizing)
    }
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

/// The EXIF exposure settings of the photos under `photos` (the folder and its subfolders, not
/// `out`), in name order; photos without any are left out.
fn photo_settings(photos: &Path, out: &Path) -> Vec<svgir_io::exif::ExposureSettings> {
    const PHOTO: [&str; 5] = ["jpg", "jpeg", "png", "tif", "tiff"];
    let mut files = Vec::new();
    let mut dirs = vec![(photos.to_path_buf(), 0)];
    while let Some((dir, depth)) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for p in entries.flatten().map(|e| e.path()) {
            if p.is_dir() && depth < 2 && !p.starts_with(out) {
                dirs.push((p, depth + 1));
            } else if p.extension().is_some_and(|x| PHOTO.iter().any(|e| x.eq_ignore_ascii_case(e))) {
                files.push(p);
            }
        }
    }
    files.sort();
    files
        .iter()
        .filter_map(|p| svgir_io::exif::read_exposure_settings(p).ok().flatten())
        .filter(|s| s.is_known())
        .collect()
}

/// Why photos with these EXIF settings need a colour correction each: they come from several
/// cameras or were exposed differently. `None` when fewer than two photos say, or all agree.
fn varying_exposure(settings: &[svgir_io::exif::ExposureSettings]) -> Option<String> {
    if settings.len() < 2 {
        return None;
    }
    let distinct = |key: &dyn Fn(&svgir_io::exif::ExposureSettings) -> String| {
        let mut k: Vec<String> = settings.iter().map(key).collect();
        k.sort();
        k.dedup();
        k.len()
    };
    let cameras = distinct(&|s| s.camera.clone().unwrap_or_default());
    let exposures = distinct(&|s| format!("{:?} {:?} {:?} {:?}", s.exposure_time, s.f_number, s.iso, s.bias));
    match (cameras, exposures) {
        (c, _) if c > 1 => Some(format!("the photos' EXIF names {c} cameras")),
        (_, e) if e > 1 => Some(format!("the photos' EXIF gives {e} different exposures (time, aperture, ISO, bias)")),
        _ => None,
    }
}

/// A stage-1 run's flags, continuing it when it has a checkpoint.
fn stage1(args: &CaptureArgs, sizing: &Sizing, data: &Path, out: &Path, extra: &[(&str, String)]) -> Result<()> {
    if out.join("point_cloud.ply").is_file() && out.join("eval.json").is_file() {
        eprintln!("svgir capture: {} (done before)", out.display());
        return Ok(());
    }
    let mut f = vec![s(data)];
    f.extend(flags(&[("--out", s(out)), ("--device", args.device.to_string()), ("--seed", args.seed.to_string())]));
    f.extend(flags(&sizing.flags()));
    if sizing.exposure {
        f.push("--exposure".into());
    }
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
    let sizing = Sizing::of_run(&args, &data)?;
    let (scene, object) = (args.out.join("scene"), args.out.join("object"));

    // Steps 1-2: the masks, from a reconstruction of the whole capture unless given.
    let masks = match &args.masks {
        Some(m) => m.clone(),
        None => {
            stage1(&args, &sizing, &data, &scene, &[("--profile", "capture".into())])?;
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

    // Step 3: the object alone, its surfels driven opaque (`OBJECT_WEIGHTS`).
    stage1(
        &args,
        &sizing,
        &data,
        &object,
        &[("--masks", s(&masks)), ("--background", "black".into()), ("--weight", OBJECT_WEIGHTS.into())],
    )?;

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
        // The rest of the scene shadows and lights the object (issue 75 item 3), where step 1
        // made a model of it.
        let scene_model = scene.join("point_cloud.ply");
        if !args.object_alone && scene_model.is_file() {
            f.extend(["--surroundings".to_string(), s(&scene_model)]);
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
    // With --exposure, also the score through each held-out photo's own correction.
    let psnr = |run: &Path| {
        let e = read_json(&run.join("eval.json"));
        let p = e.as_ref().and_then(|e| e["psnr"].as_f64()).map_or("-".into(), |p| format!("{p:.2} dB"));
        match e.and_then(|e| e["psnr_matched"].as_f64()) {
            Some(m) => format!("{p} ({m:.2} dB colour-matched to each photo)"),
            None => p,
        }
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
    html += &match read_json(&object.join("stage2/surroundings.json")) {
        Some(j) => {
            let r = &j["report"];
            let n = |k: &str| r[k].as_u64().unwrap_or(0);
            format!(
                "<p>Stage 2 traced through {} Gaussians of the whole capture around the object, as occluders and \
                 indirect light ({} lie within {} object radii; {} inside the masks and {} touching the object were \
                 left to it).</p>",
                n("kept"),
                n("near"),
                j["rule"]["radius"].as_f64().unwrap_or(f64::NAN),
                n("in_hull"),
                n("touching")
            )
        }
        None => "<p>Stage 2 ran on the object alone, without the rest of the capture.</p>".into(),
    };
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The CPU trains a quarter of the photos' size for 7000 iterations; a GPU their own size up
    /// to 1600 px wide for SPEC's 30000; options given win on either.
    #[test]
    fn sizing_by_device() {
        let cpu = Sizing::defaults(false, 4032, None, None);
        assert_eq!(cpu, Sizing { downscale: Some(4.0), resolution: None, iterations: 7000, exposure: false });
        let phone = Sizing::defaults(true, 4032, None, None);
        assert_eq!(phone, Sizing { downscale: None, resolution: Some(1600), iterations: 30_000, exposure: false });
        let small = Sizing::defaults(true, 1280, None, None);
        assert_eq!(small, Sizing { downscale: None, resolution: None, iterations: 30_000, exposure: false });
        assert_eq!(small.flags(), vec![("--iterations", "30000".to_string())]);
        let given = Sizing::defaults(true, 4032, Some(2.0), Some(500));
        assert_eq!(given, Sizing { downscale: Some(2.0), resolution: None, iterations: 500, exposure: false });
        assert_eq!(phone.flags()[1], ("--resolution", "1600".to_string()));
    }

    /// Per-photo corrections are learned when the EXIF names several cameras or exposures, not
    /// when it agrees or too few photos have any.
    #[test]
    fn colour_corrections_when_the_exif_says_the_exposure_varied() {
        use svgir_io::exif::ExposureSettings;
        let phone = |t: f64, iso: u32| ExposureSettings {
            camera: Some("Phone X".into()),
            exposure_time: Some(t),
            f_number: Some(1.8),
            iso: Some(iso),
            bias: None,
        };
        assert_eq!(varying_exposure(&[]), None);
        assert_eq!(varying_exposure(&[phone(0.01, 100)]), None);
        assert_eq!(varying_exposure(&[phone(0.01, 100), phone(0.01, 100), phone(0.01, 100)]), None);
        let auto = varying_exposure(&[phone(0.01, 100), phone(0.02, 100), phone(0.01, 400)]).unwrap();
        assert!(auto.contains("3 different exposures"), "{auto}");
        let other = ExposureSettings { camera: Some("Camera Y".into()), ..phone(0.01, 100) };
        let many = varying_exposure(&[phone(0.01, 100), other]).unwrap();
        assert!(many.contains("2 cameras"), "{many}");
        // The statue's photos carry no EXIF: nothing is decided from them.
        let statue = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/colmap/statue"));
        if statue.is_dir() {
            assert!(photo_settings(statue, Path::new("/nonexistent")).is_empty());
        }
    }
}
