//! `svgir view RUN`: the interactive relighting viewer. Writes one self-contained HTML file
//! (`RUN/viewer.html`) that relights the stage-2 model in real time with WebGL2 by precomputed
//! radiance transfer (`svgir-view`). With `--oracle OUT.png` it also renders the page's frame
//! for one camera and light on the CPU (the oracle the page is tested against); with `--table`
//! it prints how far the real-time shading is from SPEC 7's relighting on the test views.

use anyhow::{bail, Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};
use svgir_core::{EnvMap, Image};
use svgir_train::checkpoint;
use svgir_train::relight::{RelightSampling, Relighter};
use svgir_view::light::{prefilter, project_sh};
use svgir_view::{Light, Orbit, PageLight, View, ViewMode, ViewModel};

#[derive(Args)]
pub struct ViewArgs {
    /// Stage-1 run folder whose `stage2/` holds the stage-2 checkpoint (from `svgir inverse` or `svgir demo`).
    pub run: PathBuf,
    /// The page to write (default `RUN/viewer.html`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// SH degree of the transfer vectors (1..=3: 4, 9 or 16 coefficients per vertex).
    #[arg(long, default_value_t = 3)]
    pub degree: u32,
    /// Add the diffuse one-bounce light to the transfer (per colour channel: 3x its size).
    #[arg(long)]
    pub bounce: bool,
    /// Directions traced per Gaussian for the transfer (SPEC 7's K).
    #[arg(long, default_value_t = svgir_train::relight::RELIGHT_DIRECTIONS)]
    pub directions: usize,
    /// Further HDR/EXR maps to ship in the page (strength 1), besides the learned light and
    /// the dataset's maps.
    #[arg(long)]
    pub envmap: Vec<PathBuf>,
    /// Also render the page's frame on the CPU to this PNG (the oracle).
    #[arg(long)]
    pub oracle: Option<PathBuf>,
    /// Oracle camera: `yaw,pitch,dist` (degrees, degrees, scene units) around the page's target.
    #[arg(long)]
    pub camera: Option<String>,
    /// Oracle image size.
    #[arg(long, default_value_t = 512)]
    pub width: u32,
    /// Oracle image height.
    #[arg(long, default_value_t = 512)]
    pub height: u32,
    /// Oracle light (a name from the page's light menu; default the first).
    #[arg(long)]
    pub light: Option<String>,
    /// Oracle light rotation about +Z in degrees.
    #[arg(long, default_value_t = 0.0)]
    pub rotate: f32,
    /// Oracle light strength (default the light's own).
    #[arg(long)]
    pub strength: Option<f32>,
    /// Oracle view: rgb, albedo, roughness, normal or visibility.
    #[arg(long, default_value = "rgb")]
    pub mode: String,
    /// Print PSNR of the real-time shading against SPEC 7's relighting on the test views
    /// under the dataset's relighting maps (SH degrees 1 to 3), and write no page.
    #[arg(long)]
    pub table: bool,
}

/// Everything `view` needs from a run.
struct Loaded {
    s2: svgir_train::stage2::Stage2,
    data: Option<PathBuf>,
    lights: Vec<PageLight>,
}

fn load(args: &ViewArgs) -> Result<Loaded> {
    let stage2_dir = args.run.join("stage2");
    let ckpt = stage2_dir.join("checkpoint.bin");
    if !args.run.is_dir() {
        bail!("{}: no such run folder", args.run.display());
    }
    if !ckpt.is_file() {
        bail!(
            "{}: no stage-2 model in this run (the viewer shows materials and light from stage 2; run `svgir inverse --run {}` first)",
            ckpt.display(),
            args.run.display()
        );
    }
    let s2 = checkpoint::load_stage2(&ckpt).with_context(|| format!("{}: cannot load", ckpt.display()))?;
    let data = svgir_eval::read_json(&stage2_dir.join("config.json"), "")
        .ok()
        .and_then(|c| c["data"].as_str().map(PathBuf::from));
    let h = s2.config.env_height;
    let mut lights = vec![PageLight { name: "learned".into(), env: s2.env.radiance(), strength: 1.0 }];
    if let Some(ds) = data.as_deref().and_then(|d| scene_lights(d).ok()) {
        for (name, path, strength) in ds {
            let env = svgir_io::read_envmap(&path, 1.0, h)?;
            lights.push(PageLight { name, env, strength });
        }
    }
    for path in &args.envmap {
        let env = svgir_io::read_envmap(path, 1.0, h)?;
        let name = path.file_stem().map_or("map".into(), |s| s.to_string_lossy().into_owned());
        lights.push(PageLight { name, env, strength: 1.0 });
    }
    Ok(Loaded { s2, data, lights })
}

/// The dataset's training and relighting maps: (name, file, strength).
fn scene_lights(data: &Path) -> Result<Vec<(String, PathBuf, f32)>> {
    let opts = svgir_io::LoadOptions { load_test: false, ..Default::default() };
    let ds = svgir_io::load_dataset(data, &opts)?;
    Ok(ds
        .train_light
        .iter()
        .chain(&ds.relight_lights)
        .filter_map(|l| Some((l.name.clone(), l.envmap_path.clone()?, l.strength)))
        .filter(|(_, _, s)| s.is_finite())
        .collect())
}

/// The initial orbit: around the opaque surfels' centroid, from the dataset's first test (or
/// training) camera when there is one.
fn initial_orbit(s2: &svgir_train::stage2::Stage2, data: Option<&Path>) -> Orbit {
    let (mut sum, mut count) = (glam::DVec3::ZERO, 0.0);
    for i in 0..s2.surfels.len() {
        if s2.surfels.opacity(i) > 0.5 {
            sum += s2.surfels.positions[i].as_dvec3();
            count += 1.0;
        }
    }
    let target = if count > 0.0 { sum / count } else { glam::DVec3::ZERO };
    let cam = data.and_then(|d| {
        let ds = svgir_io::load_dataset(d, &svgir_io::LoadOptions::default()).ok()?;
        ds.test.first().or(ds.train.first()).map(|v| v.camera)
    });
    let (eye, fov_y) = match cam {
        Some(c) => (c.center().as_dvec3(), c.intrinsics.fov_y() as f64),
        None => (target + glam::DVec3::new(3.0, 0.0, 1.5), 40f64.to_radians()),
    };
    let d = eye - target;
    let dist = d.length().max(1e-3);
    Orbit { target: target.to_array(), yaw: d.y.atan2(d.x), pitch: (d.z / dist).clamp(-1.0, 1.0).asin(), dist, fov_y }
}

pub fn run(args: ViewArgs) -> Result<()> {
    let mode = ViewMode::parse(&args.mode)
        .with_context(|| format!("--mode {}: expected rgb, albedo, roughness, normal or visibility", args.mode))?;
    if !(1..=3).contains(&args.degree) {
        bail!("--degree {}: must be 1, 2 or 3", args.degree);
    }
    let loaded = load(&args)?;
    let s2 = &loaded.s2;
    let t0 = std::time::Instant::now();
    // The table compares with SPEC 7's relighting, which also traces the maps' brightest texels.
    let lights = if args.table { svgir_train::relight::RELIGHT_LIGHTS } else { 0 };
    let sampling = RelightSampling { directions: args.directions, lights, bounces: 0 };
    let relighter = Relighter::new(s2, sampling)?;
    // A model trained two-sided shades each side with its own hemisphere (as Relighter does).
    let back = match &s2.back {
        Some(b) if b.mb.k == args.directions => Some(b.mb.clone()),
        Some(_) => {
            let occluders = s2.relight_occluders();
            let bvh = svgir_trace::Bvh::build(&occluders);
            let axes = relighter.mb.normals.iter().map(|n| -*n).collect();
            let p = s2.config.trace_params();
            // The viewer's indirect light is the one-bounce gather: no traced radiance needed.
            Some(svgir_trace::MicroBuffer::trace_occlusion_about(
                &bvh,
                &occluders,
                axes,
                args.directions,
                s2.config.seed,
                &p,
            )?)
        }
        None => None,
    };
    eprintln!(
        "view: traced K = {} directions for {} Gaussians in {:.1} s",
        args.directions,
        s2.surfels.len(),
        t0.elapsed().as_secs_f64()
    );
    if args.table {
        return table(&loaded, &relighter, back.as_ref());
    }
    let model = svgir_view::model_from_stage2(s2, &relighter.mb, back.as_ref(), args.degree, args.bounce)?;
    let orbit = initial_orbit(s2, loaded.data.as_deref());
    let title = format!("svgir viewer: {}", args.run.display());
    let html = svgir_view::page(&model, &loaded.lights, &orbit, &title);
    let out = args.out.clone().unwrap_or_else(|| args.run.join("viewer.html"));
    svgir_io::error::write_atomic(&out, html.as_bytes())?;
    println!(
        "wrote {} ({:.1} MB): {} surfels x {} bytes (SH degree {}{}{}), {} lights",
        out.display(),
        html.len() as f64 / 1e6,
        model.n,
        model.bytes_per_surfel(),
        args.degree,
        if model.two_sided { ", two-sided" } else { "" },
        if model.channels == 3 { ", one bounce" } else { "" },
        loaded.lights.len()
    );
    if let Some(png) = &args.oracle {
        let mut cam = orbit;
        if let Some(c) = &args.camera {
            let v: Vec<f64> = c
                .split(',')
                .map(|s| s.trim().parse())
                .collect::<Result<_, _>>()
                .with_context(|| format!("--camera {c}: expected yaw,pitch,dist"))?;
            let [yaw, pitch, dist] = v[..] else { bail!("--camera {c}: expected three numbers yaw,pitch,dist") };
            (cam.yaw, cam.pitch, cam.dist) = (yaw.to_radians(), pitch.to_radians(), dist);
        }
        let light = match &args.light {
            Some(name) => loaded.lights.iter().find(|l| &l.name == name).with_context(|| {
                let names: Vec<_> = loaded.lights.iter().map(|l| l.name.as_str()).collect();
                format!("--light {name}: not one of {names:?}")
            })?,
            None => &loaded.lights[0],
        };
        let strength = args.strength.unwrap_or(light.strength);
        let t0 = std::time::Instant::now();
        let frame = oracle_frame(
            &model,
            &light.env,
            &cam.view(args.width, args.height),
            args.rotate.to_radians(),
            strength,
            mode,
        );
        write_png(png, &frame)?;
        println!(
            "oracle frame: {} ({}x{}, {} surfels drawn, {:.2} M fragments, {:.2} M blended; {:.2} s on {} threads)",
            png.display(),
            args.width,
            args.height,
            frame.drawn,
            frame.fragments as f64 / 1e6,
            frame.blended as f64 / 1e6,
            t0.elapsed().as_secs_f64(),
            rayon::current_num_threads()
        );
    }
    Ok(())
}

/// The page's frame on the CPU.
fn oracle_frame(
    model: &ViewModel,
    env: &EnvMap,
    view: &View,
    angle: f32,
    strength: f32,
    mode: ViewMode,
) -> svgir_view::Frame {
    let sh = project_sh(env, model.degree, angle, strength);
    let chain = prefilter(env);
    let light = Light { sh: &sh, chain: &chain, width: env.width, height: env.height, angle, strength };
    svgir_view::render(model, view, &light, mode, [0.0; 3])
}

fn write_png(path: &Path, f: &svgir_view::Frame) -> Result<()> {
    let img = Image::from_data(f.width, f.height, 3, f.rgb8.iter().map(|&b| b as f32 / 255.0).collect());
    svgir_io::write_png(path, &img, 8)?;
    Ok(())
}

/// PRT (this viewer, per SH degree) against SPEC 7's relighting, per relighting light, mean
/// PSNR over the test views (both 8-bit, over black); and both against the dataset's relit
/// photos where it has them (over black with each image's own coverage, not SPEC 8's masked
/// protocol).
fn table(loaded: &Loaded, relighter: &Relighter, back: Option<&svgir_trace::MicroBuffer>) -> Result<()> {
    let s2 = &loaded.s2;
    let data =
        loaded.data.as_deref().context("the run's stage2/config.json names no dataset (needed for its test views)")?;
    let ds = svgir_io::load_dataset(data, &svgir_io::LoadOptions::default())?;
    if ds.test.is_empty() {
        bail!("{}: no test views", data.display());
    }
    let models: Vec<ViewModel> = [(1, false), (2, false), (3, false), (3, true)]
        .into_iter()
        .map(|(d, b)| svgir_view::model_from_stage2(s2, &relighter.mb, back, d, b))
        .collect::<Result<_, _>>()?;
    println!(
        "| light | SPEC 7 gather s | PRT vs SPEC 7, degree 1 (4) dB | degree 2 (9) dB | degree 3 (16) dB | degree 3 + bounce dB | SPEC 7 vs photos dB | PRT degree 3 vs photos dB | degree 3 + bounce vs photos dB |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let q8 = |v: &[f32]| -> Vec<f32> { v.iter().map(|c| (c.clamp(0.0, 1.0) * 255.0).round() / 255.0).collect() };
    for l in &ds.relight_lights {
        let Some(path) = &l.envmap_path else { continue };
        let env = svgir_io::read_envmap(path, 1.0, s2.config.env_height)?;
        let t0 = std::time::Instant::now();
        let full = relighter;
        let mut scaled = env.clone();
        scaled.data.iter_mut().for_each(|c| *c = c.map(|v| v * l.strength));
        let lit = full.prepare(s2, scaled)?;
        let secs = t0.elapsed().as_secs_f64();
        let mut psnr = [0.0f64; 4];
        let (mut full_gt, mut prt_gt, mut bounce_gt, mut with_gt) = (0.0f64, 0.0f64, 0.0f64, 0usize);
        for v in &ds.test {
            let r = full.render(s2, &v.camera, [0.0; 3], &lit, [1.0; 3])?;
            let reference = q8(&r.image);
            let gt = v
                .relit
                .get(&l.name)
                .map(|g| q8(&if g.channels == 4 { g.composite_over([0.0; 3]) } else { g.clone() }.data));
            for (d, m) in models.iter().enumerate() {
                let f = oracle_frame(m, &env, &View::from_camera(&v.camera), 0.0, l.strength, ViewMode::Rgb);
                let ours: Vec<f32> = f.rgb8.iter().map(|&b| b as f32 / 255.0).collect();
                psnr[d] += svgir_metrics::psnr(&ours, &reference, 3, None)? / ds.test.len() as f64;
                match (&gt, d) {
                    (Some(gt), 2) => {
                        prt_gt += svgir_metrics::psnr(&ours, gt, 3, None)?;
                        full_gt += svgir_metrics::psnr(&reference, gt, 3, None)?;
                        with_gt += 1;
                    }
                    (Some(gt), 3) => bounce_gt += svgir_metrics::psnr(&ours, gt, 3, None)?,
                    _ => {}
                }
            }
        }
        let k = with_gt.max(1) as f64;
        println!(
            "| {} | {:.1} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
            l.name,
            secs,
            psnr[0],
            psnr[1],
            psnr[2],
            psnr[3],
            full_gt / k,
            prt_gt / k,
            bounce_gt / k
        );
    }
    Ok(())
}
