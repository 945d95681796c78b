//! `svgir bench raster --device gpu`: the rasterizer's forward and forward + backward on the
//! GPU for svgir-raster's benchmark scenes (random surfels, its bench camera), the buffers
//! resident and reused as in training, each timing the wall clock over `reps` renders submitted
//! back to back and waited for once (so a render's host work overlaps the GPU's).

use crate::buffers::read_back;
use crate::device::{Gpu, GpuError};
use crate::raster::{Frame, GpuRaster, Params, SurfelBuffers, COUNTERS, VPIX};
use std::time::Instant;
use svgir_raster::fixtures::{bench_camera, random_scene};
use svgir_raster::RasterConfig;

fn wait(gpu: &Gpu) -> Result<(), GpuError> {
    gpu.device.poll(wgpu::PollType::wait_indefinitely()).map(|_| ()).map_err(|e| GpuError::Runtime(e.to_string()))
}

/// The table: one row per (size, Gaussians), milliseconds per render.
pub fn raster_table(gpu: &Gpu, sizes: &[u32], gaussians: &[usize], reps: usize) -> Result<String, GpuError> {
    let raster = GpuRaster::new(gpu);
    let mut s = format!(
        "svgir-gpu raster bench on {}\n| size | Gaussians | entries | forward ms | forward+backward ms |\n|---|---|---|---|---|\n",
        gpu.report
    );
    let cfg = RasterConfig { distortion: true, ..RasterConfig::default() };
    for &size in sizes {
        for &n in gaussians {
            let mut surfels = random_scene(n, 7);
            surfels.sh_degree = 3;
            let cam = bench_camera(size, size);
            let surf = SurfelBuffers::upload(gpu, &surfels)?;
            let p0 = Params::new(surf.n, 3, &cam, [1.0; 3], &cfg, 0);
            let entries = raster.count_entries(gpu, &surf, &p0)?;
            let params = Params::new(surf.n, 3, &cam, [1.0; 3], &cfg, entries);
            let npx = size as u64 * size as u64;
            let frame = Frame::new(gpu, surf.n, npx, params.tiles(), entries)?;
            gpu.queue.write_buffer(&frame.vout, 0, bytemuck::cast_slice(&vec![1e-3f32; npx as usize * VPIX]));
            let time = |backward: bool| -> Result<f64, GpuError> {
                let run = |k: usize| {
                    for _ in 0..k {
                        let mut enc = gpu.device.create_command_encoder(&Default::default());
                        raster.encode_forward(gpu, &mut enc, &surf, &frame, &params);
                        if backward {
                            raster.encode_backward(gpu, &mut enc, &surf, &frame, &params);
                        }
                        gpu.queue.submit([enc.finish()]);
                    }
                };
                run(1);
                wait(gpu)?;
                let t0 = Instant::now();
                run(reps.max(1));
                wait(gpu)?;
                Ok(t0.elapsed().as_secs_f64() * 1e3 / reps.max(1) as f64)
            };
            let (f, fb) = (time(false)?, time(true)?);
            let c = read_back::<u32>(&gpu.device, &gpu.queue, &[(&frame.count, COUNTERS)])?.remove(0);
            if c[4] > 0 {
                return Err(GpuError::Runtime("the bench's renders overflowed their entry buffers".into()));
            }
            s += &format!("| {size} x {size} | {n} | {entries} | {f:.3} | {fb:.3} |\n");
        }
    }
    Ok(s)
}

/// `svgir bench trace --device gpu`: micro-buffers on svgir-trace's object scene (surfels on
/// two surfaces, the CPU bench's scene) for each count in `gaussians`: the CPU BVH build, the
/// K = 64 fill with radiance (stage 2's) and the K = 384 occlusion trace (relighting's), each
/// the wall clock from host surfels to host samples (upload, trace, read-back), and the GPU
/// bytes per surfel such a trace holds (its scene, the samples of one read-back batch).
pub fn trace_table(gpu: Gpu, gaussians: &[usize], reps: usize) -> Result<String, GpuError> {
    use svgir_trace::{scenes::object_scene, Bvh, TraceParams};
    let name = gpu.report.to_string();
    let tracer = crate::trace::GpuTracer::new(gpu);
    let mut s = format!(
        "svgir-gpu trace bench on {name}\n| Gaussians | BVH build ms | K = 64 fill s | Mray/s | K = 384 occlusion s | GPU bytes/surfel (K = 64) |\n|---|---|---|---|---|---|\n"
    );
    let p = TraceParams::default();
    for &n in gaussians {
        let surfels = object_scene(n, 1);
        let axes: Vec<glam::Vec3> = (0..n).map(|j| surfels.normal(j)).collect();
        let t0 = Instant::now();
        let bvh = Bvh::build(&surfels);
        let build = t0.elapsed().as_secs_f64();
        let time = |k: usize, radiance: bool| -> Result<f64, GpuError> {
            let req = || svgir_trace::TraceRequest { axes: axes.clone(), k, seed: 3, params: &p, radiance };
            tracer.micro_buffer(&bvh, &surfels, req())?;
            let t0 = Instant::now();
            for _ in 0..reps.max(1) {
                std::hint::black_box(tracer.micro_buffer(&bvh, &surfels, req())?);
            }
            Ok(t0.elapsed().as_secs_f64() / reps.max(1) as f64)
        };
        let fill = time(64, true)?;
        let occ = time(384, false)?;
        // The scene, and the samples of one read-back batch (K = 64 x 16 bytes while they fit).
        let bytes = crate::trace::scene_bytes(&bvh, n) as f64 / n as f64
            + (64.0 * 16.0f64).min(crate::trace::BATCH_BYTES as f64 / n as f64);
        s += &format!(
            "| {n} | {:.1} | {fill:.3} | {:.1} | {occ:.3} | {bytes:.0} |\n",
            build * 1e3,
            (n * 64) as f64 / fill / 1e6
        );
    }
    Ok(s)
}

/// `svgir bench pbr --device gpu`: the vertex shading of svgir-pbr's synthetic problem (M = 4,
/// every Gaussian visible) at stage 2's K = 64 with traced indirect light and at relighting's
/// K = 384 with given indirect light, forward and backward, on the GPU (wall clock from host
/// inputs to host outputs: upload, shade, read-back, and the backward's env scatter on the
/// host) beside the CPU kernels on `threads` threads, in the same run; then the
/// radiance-consistency term the same way (`consistency_rows`).
pub fn shade_table(gpu: Gpu, gaussians: &[usize], reps: usize, threads: usize) -> Result<String, GpuError> {
    use svgir_pbr::fixtures::Problem;
    use svgir_pbr::{CpuShader, Indirect, ShadeOutput, Side, VertexShader};
    let name = gpu.report.to_string();
    let shader = crate::shade::GpuShader::new(gpu);
    let mut s = format!(
        "svgir-gpu shade bench on {name} (CPU: {threads} threads)\n| Gaussians | K | indirect | GPU forward ms | CPU forward ms | GPU backward ms | CPU backward ms |\n|---|---|---|---|---|---|---|\n"
    );
    let err = |e: svgir_pbr::PbrError| GpuError::Runtime(e.to_string());
    for &n in gaussians {
        for (k, given) in [(64usize, false), (384, true)] {
            let problem = Problem::new(n, 4, k).map_err(err)?;
            let light: Vec<[f32; 3]> = (0..n * k).map(|i| [0.1 + (i % 7) as f32 * 0.05; 3]).collect();
            let mut inputs = problem.inputs();
            if given {
                inputs.indirect = Indirect::Given(&light);
            }
            let side = Side { inputs, cache: None };
            let mut grads = svgir_pbr::PbrGrads::zeros(n, 4, problem.env.data.len());
            let mut time = |backend: &dyn VertexShader, backward: bool| -> Result<f64, GpuError> {
                let mut out = ShadeOutput::colour_only();
                let mut once = |out: &mut ShadeOutput| {
                    if backward {
                        backend.shade_sides_backward(&side, None, &problem.v_color, &mut grads)
                    } else {
                        backend.shade_sides(&side, None, out)
                    }
                };
                once(&mut out).map_err(err)?;
                let t0 = Instant::now();
                for _ in 0..reps.max(1) {
                    once(&mut out).map_err(err)?;
                    std::hint::black_box(&out.color);
                }
                Ok(t0.elapsed().as_secs_f64() * 1e3 / reps.max(1) as f64)
            };
            let (gf, cf) = (time(&shader, false)?, time(&CpuShader, false)?);
            let (gb, cb) = (time(&shader, true)?, time(&CpuShader, true)?);
            let ind = if given { "given" } else { "traced" };
            s += &format!("| {n} | {k} | {ind} | {gf:.1} | {cf:.1} | {gb:.1} | {cb:.1} |\n");
        }
    }
    s += &consistency_rows(&shader, gaussians, reps, threads)?;
    Ok(s)
}

/// The radiance-consistency term (L1b, the loss and its gradients, SPEC 6 Eqn 14/16) on the same
/// synthetic problem at K = 64, every Gaussian visible (a pair each where a direction is
/// occluded: an upper bound on training's, which samples 2048-8192), GPU beside CPU.
fn consistency_rows(
    shader: &crate::shade::GpuShader,
    gaussians: &[usize],
    reps: usize,
    threads: usize,
) -> Result<String, GpuError> {
    use svgir_pbr::fixtures::Problem;
    use svgir_pbr::{ConsistencyInputs, CpuShader, VertexShader};
    use svgir_trace::GatherParams;
    let err = |e: svgir_pbr::PbrError| GpuError::Runtime(e.to_string());
    let mut s = format!(
        "\nradiance consistency (K = 64, CPU: {threads} threads)\n| Gaussians | pairs | GPU ms | CPU ms |\n|---|---|---|---|\n"
    );
    for &n in gaussians {
        let problem = Problem::new(n, 4, 64).map_err(err)?;
        let inp = ConsistencyInputs {
            mb: &problem.mb,
            positions: &problem.positions,
            camera_center: glam::Vec3::ZERO,
            visible: &problem.visible,
            mats: problem.mats.view(),
            env: &problem.env,
            rho: 0.8,
            params: GatherParams::default(),
        };
        let mut pairs = 0;
        let mut time = |backend: &dyn VertexShader| -> Result<f64, GpuError> {
            pairs = backend.consistency_with_grad(&inp, 1.0).map_err(err)?.0.pairs.len();
            let t0 = Instant::now();
            for _ in 0..reps.max(1) {
                std::hint::black_box(backend.consistency_with_grad(&inp, 1.0).map_err(err)?);
            }
            Ok(t0.elapsed().as_secs_f64() * 1e3 / reps.max(1) as f64)
        };
        let (g, c) = (time(shader)?, time(&CpuShader)?);
        s += &format!("| {n} | {pairs} | {g:.1} | {c:.1} |\n");
    }
    Ok(s)
}
