//! Repeats one forward+backward for profiling with perf/callgrind.
//!
//! `profile [REPS] [PLY DATASET]`: the benchmark's random scene (100k Gaussians, 400x400), or a
//! trained scene (a 3DGS-layout PLY) seen from the first test camera of DATASET.
use svgir_raster::fixtures::Problem;
use svgir_raster::{backward, render, ColorSource, RasterConfig};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let reps: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(5);
    let problem = match (args.get(2), args.get(3)) {
        (Some(ply), Some(data)) => {
            let (surfels, _) = svgir_io::read_gaussians_ply(ply).expect("PLY");
            let opts = svgir_io::LoadOptions {
                resolution: None,
                downscale: None,
                load_test: true,
                max_views: Some(1),
                masks: None,
            };
            let ds = svgir_io::load_dataset(data, &opts).expect("dataset");
            let cam = ds.test.first().or(ds.train.first()).expect("a view").camera;
            Problem::with_camera(surfels, cam)
        }
        _ => Problem::new(100_000, 400),
    };
    let (surfels, cam) = (&problem.surfels, &problem.camera);
    let (input, grads) = (problem.input(), problem.grads());
    let cfg = RasterConfig::default();
    let cam_f = svgir_raster::preprocess::Cam::<f32>::new(cam);
    let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
    for _ in 0..2 {
        let t0 = std::time::Instant::now();
        let (splats, _) = svgir_raster::preprocess::preprocess(surfels, &cam_f, &ColorSource::Sh, &cfg);
        let t1 = t0.elapsed();
        let bins = svgir_raster::tiles::bin(&splats, w, h, cfg.tile);
        eprintln!(
            "preprocess {:.1} ms, bin {:.1} ms ({} pairs)",
            t1.as_secs_f64() * 1e3,
            (t0.elapsed() - t1).as_secs_f64() * 1e3,
            bins.ids.len()
        );
    }
    for _ in 0..reps {
        let t0 = std::time::Instant::now();
        let (out, st) = render(&input, &cfg);
        let t1 = t0.elapsed();
        let g = backward(&input, &cfg, &st, &out, &grads);
        std::hint::black_box(&g);
        eprintln!("fwd {:.1} ms, fwd+bwd {:.1} ms", t1.as_secs_f64() * 1e3, t0.elapsed().as_secs_f64() * 1e3);
    }
}
