//! Writes a viewer page for a synthetic model of N surfels (a sphere over a ground disk, random
//! materials, K = 16 traced directions), to time the page at sizes no shipped run has:
//!
//! `cargo run --release -p svgir-view --example synthetic_page -- 100000 /tmp/page100k.html`
//! `node tools/browser/viewer_check.mjs /tmp/page100k.html --hash "ui=0" --width 800 --height 600 --frames 10`

use glam::{Quat, Vec2, Vec3};
use svgir_core::{EnvMap, Rng, ShCoeffs, Surfels};
use svgir_trace::{Bvh, MicroBuffer, TraceParams};
use svgir_view::{Orbit, PageLight, VertexData, ViewModel};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (Some(n), Some(out)) = (args.get(1).and_then(|s| s.parse::<usize>().ok()), args.get(2)) else {
        eprintln!("usage: synthetic_page N OUT.html");
        std::process::exit(2);
    };
    let mut rng = Rng::new(1);
    let mut s = Surfels::with_capacity(n, 0);
    let sphere = n * 2 / 3;
    // Surfel radius so that the sphere (area 4 pi 0.5^2) is covered about twice.
    let scale = (2.0 * std::f32::consts::PI * 0.25 / sphere as f32).sqrt() * 0.8;
    for k in 0..sphere {
        let z = 1.0 - 2.0 * (k as f32 + 0.5) / sphere as f32;
        let phi = k as f32 * std::f32::consts::PI * (3.0 - 5f32.sqrt());
        let r = (1.0 - z * z).sqrt();
        let nrm = Vec3::new(r * phi.cos(), r * phi.sin(), z);
        s.push(nrm * 0.5, Quat::from_rotation_arc(Vec3::Z, nrm), Vec2::splat(scale.ln()), 2.5, ShCoeffs::default());
    }
    while s.len() < n {
        let p = Vec3::new(2.2 * rng.uniform() - 1.1, 2.2 * rng.uniform() - 1.1, -0.52);
        s.push(p, Quat::IDENTITY, Vec2::splat((1.5 * scale).ln()), 2.5, ShCoeffs::default());
    }
    let m = 4;
    let albedo: Vec<f32> = (0..n * m * 3).map(|_| 0.2 + 0.6 * rng.uniform()).collect();
    let rough: Vec<f32> = (0..n * m).map(|_| 0.1 + 0.8 * rng.uniform()).collect();
    let normals: Vec<f32> = (0..n * m).flat_map(|q| s.normal(q / m).to_array()).collect();
    let mb = MicroBuffer::trace(&Bvh::build(&s), &s, 16, 1, &TraceParams::default()).expect("trace");
    let data = VertexData { albedo: &albedo, roughness: &rough, normals: &normals };
    let model =
        ViewModel::build(&s, &data, m, &mb, None, svgir_view::Options { degree: 3, bounce: false, layered: false })
            .expect("model");
    let mut env = EnvMap::constant(64, 32, [0.4, 0.45, 0.5]);
    env.data[5 * 64 + 20] = [200.0; 3];
    let orbit = Orbit { target: [0.0, 0.0, -0.1], yaw: 0.6, pitch: 0.4, dist: 3.2, fov_y: 40f64.to_radians() };
    let html = svgir_view::page(
        &model,
        &[PageLight { name: "sky".into(), env: env.clone(), strength: 1.0 }],
        &orbit,
        "synthetic",
    );
    std::fs::write(out, &html).expect("write");
    println!("{out}: {n} surfels, {:.1} MB", html.len() as f64 / 1e6);
    // The work of one frame at the page's first view, counted by the oracle (and its CPU time).
    let sh = svgir_view::light::project_sh(&env, 3, 0.0, 1.0);
    let chain = svgir_view::light::prefilter(&env);
    let light = svgir_view::Light { sh: &sh, chain: &chain, width: 64, height: 32, angle: 0.0, strength: 1.0 };
    for (w, h) in [(800, 600), (1280, 720)] {
        let t0 = std::time::Instant::now();
        let f = svgir_view::render(&model, &orbit.view(w, h), &light, svgir_view::ViewMode::Rgb, [0.0; 3]);
        println!(
            "{w}x{h}: {} surfels drawn, {:.2} M fragments ({:.2} M blended), oracle {:.2} s on {} threads",
            f.drawn,
            f.fragments as f64 / 1e6,
            f.blended as f64 / 1e6,
            t0.elapsed().as_secs_f64(),
            rayon::current_num_threads()
        );
    }
}
