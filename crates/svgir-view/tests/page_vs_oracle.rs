//! The page's WebGL2 frame (headless Chromium, SwiftShader) against the Rust oracle for the
//! same camera and light: PSNR >= 35 dB, with the one-bounce transfer (3 channels) and without. Also the page's messages for bad input. A small scene
//! is built in memory (a sphere of surfels over a ground disk, traced with the BVH), so the test
//! needs no run folder. Skips (loudly) without Chromium or tools/browser/node_modules unless
//! SVGIR_REQUIRE_DATA=1.

use glam::{Quat, Vec2, Vec3};
use std::path::{Path, PathBuf};
use std::process::Command;
use svgir_core::{EnvMap, Rng, ShCoeffs, Surfels};
use svgir_trace::{Bvh, MicroBuffer, TraceParams};
use svgir_view::light::{prefilter, project_sh};
use svgir_view::{Light, Options, Orbit, PageLight, VertexData, ViewMode, ViewModel};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Node and Chromium are there, or the test is skipped (failed with SVGIR_REQUIRE_DATA=1).
fn browser_ready() -> bool {
    let ok = repo().join("tools/browser/node_modules/playwright-core").is_dir()
        && Path::new(&std::env::var("CHROMIUM").unwrap_or("/usr/bin/chromium".into())).exists()
        && Command::new("node").arg("--version").output().is_ok();
    if !ok {
        assert!(
            std::env::var("SVGIR_REQUIRE_DATA").as_deref() != Ok("1"),
            "SVGIR_REQUIRE_DATA=1 but Chromium or tools/browser/node_modules is missing (cd tools/browser && npm ci)"
        );
        eprintln!("SKIPPED: no Chromium or tools/browser/node_modules (cd tools/browser && npm ci)");
    }
    ok
}

fn scene(seed: u64) -> (Surfels, Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut rng = Rng::new(seed);
    let mut s = Surfels::with_capacity(3000, 0);
    let add = |p: Vec3, n: Vec3, scale: f32, s: &mut Surfels| {
        let q = Quat::from_rotation_arc(Vec3::Z, n);
        s.push(p, q, Vec2::splat(scale.ln()), 2.5, ShCoeffs::from_rgb([0.5; 3]));
    };
    let count = 1200;
    for k in 0..count {
        let z = 1.0 - 2.0 * (k as f32 + 0.5) / count as f32;
        let phi = k as f32 * std::f32::consts::PI * (3.0 - 5f32.sqrt());
        let r = (1.0 - z * z).sqrt();
        let n = Vec3::new(r * phi.cos(), r * phi.sin(), z);
        add(n * 0.5, n, 0.035, &mut s);
    }
    for i in -14..=14 {
        for j in -14..=14 {
            let p = Vec3::new(i as f32 * 0.08, j as f32 * 0.08, -0.52);
            if p.truncate().length() < 1.1 {
                add(p, Vec3::Z, 0.04, &mut s);
            }
        }
    }
    let m = 4;
    let n = s.len();
    let mut albedo = Vec::with_capacity(n * m * 3);
    let mut rough = Vec::with_capacity(n * m);
    let mut normals = Vec::with_capacity(n * m * 3);
    for i in 0..n {
        let base = [0.2 + 0.6 * rng.uniform(), 0.2 + 0.6 * rng.uniform(), 0.2 + 0.6 * rng.uniform()];
        for _ in 0..m {
            albedo.extend(base.map(|a| (a + 0.1 * rng.uniform()).min(0.8)));
            rough.push(0.09 + 0.9 * rng.uniform());
            let nv = (s.normal(i) + 0.15 * Vec3::new(rng.normal(), rng.normal(), rng.normal())).normalize();
            normals.extend(nv.to_array());
        }
    }
    (s, albedo, rough, normals)
}

/// A sky with a sun and a coloured horizon, 32 x 64.
fn sky() -> EnvMap {
    let mut env = EnvMap::constant(64, 32, [0.0; 3]);
    let sun = Vec3::new(0.5, -0.3, 0.8).normalize();
    for r in 0..32 {
        for c in 0..64 {
            let d = env.texel_dir(r, c);
            let mut l = [0.3 + 0.4 * d.z.max(0.0), 0.35 + 0.3 * d.z.max(0.0), 0.5 + 0.5 * d.z.max(0.0)];
            if d.z < 0.0 {
                l = [0.25, 0.2, 0.15];
            }
            if d.dot(sun) > 0.97 {
                l = [30.0, 27.0, 22.0];
            }
            if d.x > 0.9 {
                l[0] += 2.0;
            }
            env.data[(r * 64 + c) as usize] = l;
        }
    }
    env
}

struct Fixture {
    dir: PathBuf,
    page: PathBuf,
    model: ViewModel,
    env: EnvMap,
    orbit: Orbit,
}

fn fixture(name: &str, bounce: bool) -> Fixture {
    let (s, albedo, rough, normals) = scene(7);
    let bvh = Bvh::build(&s);
    let mb = MicroBuffer::trace(&bvh, &s, 64, 3, &TraceParams::default()).unwrap();
    // The one-bounce fixture is also two-sided with the layered diffuse (every page path).
    let back = bounce.then(|| {
        let axes = (0..s.len()).map(|i| -s.normal(i)).collect();
        MicroBuffer::trace_about(&bvh, &s, axes, 64, 3, &TraceParams::default()).unwrap()
    });
    let data = VertexData { albedo: &albedo, roughness: &rough, normals: &normals };
    let model =
        ViewModel::build(&s, &data, 4, &mb, back.as_ref(), Options { degree: 3, bounce, layered: bounce }).unwrap();
    let env = sky();
    let orbit = Orbit { target: [0.0, 0.0, -0.1], yaw: 0.6, pitch: 0.4, dist: 3.2, fov_y: 40f64.to_radians() };
    let lights = [PageLight { name: "sky".into(), env: env.clone(), strength: 1.0 }];
    let html = svgir_view::page(&model, &lights, &orbit, "test scene");
    let dir = std::env::temp_dir().join(format!("svgir_view_{name}_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let page = dir.join("viewer.html");
    std::fs::write(&page, html).unwrap();
    Fixture { dir, page, model, env, orbit }
}

fn check(page: &Path, args: &[&str]) -> serde_json::Value {
    let out = Command::new("node")
        .arg(repo().join("tools/browser/viewer_check.mjs"))
        .arg(page)
        .args(args)
        .output()
        .expect("node runs");
    assert!(out.status.success(), "viewer_check failed: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.lines().last().unwrap_or("")).unwrap_or_else(|e| panic!("{e}: {text}"))
}

fn psnr_u8(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len());
    let mse = a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>() / a.len() as f64;
    10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10()
}

#[test]
fn page_frames_match_the_oracle() {
    if !browser_ready() {
        return;
    }
    let f = fixture("match", true);
    let (w, h) = (200u32, 160u32);
    // (yaw, pitch, dist, rotation, strength, mode)
    let cases = [
        (40.0, 25.0, 3.2, 0.0, 1.0, ViewMode::Rgb),
        (-100.0, 50.0, 2.6, 130.0, 0.6, ViewMode::Rgb),
        (10.0, 15.0, 3.0, 0.0, 1.0, ViewMode::Normal),
        // From below the ground: its surfels are seen from their back sides.
        (200.0, -25.0, 3.0, 60.0, 1.0, ViewMode::Rgb),
    ];
    for (k, &(yaw, pitch, dist, rot, strength, mode)) in cases.iter().enumerate() {
        let shot = f.dir.join(format!("shot_{k}.png"));
        let hash = format!(
            "yaw={yaw}&pitch={pitch}&dist={dist}&rot={rot}&strength={strength}&mode={}&ui=0&w={w}&h={h}",
            mode.name()
        );
        let r = check(
            &f.page,
            &["--hash", &hash, "--width", &w.to_string(), "--height", &h.to_string(), "--out", shot.to_str().unwrap()],
        );
        assert_eq!(r["ready"], true, "{r}");
        assert!(r["error"].is_null(), "{r}");
        let img = svgir_io::read_image(&shot).unwrap();
        let page: Vec<u8> = (0..(w * h) as usize)
            .flat_map(|p| (0..3).map(move |c| (p, c)))
            .map(|(p, c)| (img.data[p * img.channels as usize + c] * 255.0).round() as u8)
            .collect();
        let orbit = Orbit { yaw: f64::to_radians(yaw), pitch: f64::to_radians(pitch), dist, ..f.orbit };
        let angle = (rot as f32).to_radians();
        let sh = project_sh(&f.env, f.model.degree, angle, strength);
        let chain = prefilter(&f.env);
        let light = Light { sh: &sh, chain: &chain, width: 64, height: 32, angle, strength };
        let frame = svgir_view::render(&f.model, &orbit.view(w, h), &light, mode, [0.0; 3]);
        let covered = frame.accum.iter().filter(|a| a[3] > 0.5).count();
        assert!(covered > (w * h / 10) as usize, "the object covers {covered} pixels only");
        let psnr = psnr_u8(&page, &frame.rgb8);
        eprintln!("case {k} ({}): page vs oracle {psnr:.2} dB", mode.name());
        if psnr < 35.0 {
            let bytes: Vec<f32> = frame.rgb8.iter().map(|&b| b as f32 / 255.0).collect();
            let _ = svgir_io::write_png(
                f.dir.join(format!("oracle_{k}.png")),
                &svgir_core::Image::from_data(w, h, 3, bytes),
                8,
            );
        }
        assert!(psnr >= 35.0, "case {k}: {psnr:.2} dB < 35 (see {})", f.dir.display());
    }
    let _ = std::fs::remove_dir_all(&f.dir);
}

#[test]
fn a_dropped_hdr_relights_as_the_oracle_and_a_broken_one_says_why() {
    if !browser_ready() {
        return;
    }
    let f = fixture("drop", false);
    // A map at another resolution, written as a Radiance file: the page's RGBE reader and area
    // resampling must give the light svgir-io and EnvMap::from_equirect give.
    let src = {
        let mut img = svgir_core::Image::from_data(96, 48, 3, vec![0.0; 96 * 48 * 3]);
        for y in 0..48 {
            for x in 0..96 {
                let p = img.pixel_mut(x, y);
                p[0] = 0.2 + x as f32 / 96.0;
                p[1] = if y < 12 { 3.0 } else { 0.4 };
                p[2] = if (20..26).contains(&x) && y < 20 { 12.0 } else { 0.3 };
            }
        }
        img
    };
    let hdr = f.dir.join("ramp.hdr");
    svgir_io::write_hdr(&hdr, &src).unwrap();
    let (w, h) = (160u32, 128u32);
    let shot = f.dir.join("dropped.png");
    let hash = format!("yaw=70&pitch=30&dist=3.0&rot=25&ui=0&w={w}&h={h}");
    let r = check(
        &f.page,
        &[
            "--hash",
            &hash,
            "--width",
            &w.to_string(),
            "--height",
            &h.to_string(),
            "--drop",
            hdr.to_str().unwrap(),
            "--out",
            shot.to_str().unwrap(),
        ],
    );
    assert!(r["drop"]["error"].is_null(), "{r}");
    let env = svgir_io::read_envmap(&hdr, 1.0, 32).unwrap();
    let angle = 25f32.to_radians();
    let sh = project_sh(&env, 3, angle, 1.0);
    let chain = prefilter(&env);
    let light = Light { sh: &sh, chain: &chain, width: env.width, height: env.height, angle, strength: 1.0 };
    let orbit = Orbit { yaw: 70f64.to_radians(), pitch: 30f64.to_radians(), dist: 3.0, ..f.orbit };
    let frame = svgir_view::render(&f.model, &orbit.view(w, h), &light, ViewMode::Rgb, [0.0; 3]);
    let img = svgir_io::read_image(&shot).unwrap();
    let page: Vec<u8> = (0..(w * h) as usize)
        .flat_map(|p| (0..3).map(move |c| (p, c)))
        .map(|(p, c)| (img.data[p * img.channels as usize + c] * 255.0).round() as u8)
        .collect();
    let psnr = psnr_u8(&page, &frame.rgb8);
    eprintln!("dropped .hdr: page vs oracle {psnr:.2} dB");
    assert!(psnr >= 35.0, "{psnr:.2} dB");

    // Broken files: a message that names the file and the problem, and the page keeps working.
    let bytes = std::fs::read(&hdr).unwrap();
    for (name, content, says) in [
        ("truncated.hdr", bytes[..bytes.len() / 2].to_vec(), "ends"),
        ("picture.hdr", b"\x89PNG\r\n\x1a\nnot a radiance file\n".to_vec(), "not a Radiance"),
    ] {
        let bad = f.dir.join(name);
        std::fs::write(&bad, content).unwrap();
        let r = check(&f.page, &["--hash", "ui=0", "--drop", bad.to_str().unwrap()]);
        let err = r["drop"]["error"].as_str().unwrap_or_else(|| panic!("no error for {name}: {r}"));
        assert!(err.contains(name) && err.contains(says), "{name}: {err}");
        assert_eq!(r["drop"]["message"].as_str(), Some(err), "the message is shown in the page");
    }
    let _ = std::fs::remove_dir_all(&f.dir);
}
