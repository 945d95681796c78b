//! `svgir bench KERNEL`: performance tables (sizes, threads and machine in the output).

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use std::path::{Path, PathBuf};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Kernel {
    /// Rasterizer forward and forward+backward.
    Raster,
    /// BVH build, ray throughput, micro-buffer fill.
    Trace,
    /// Stage-2 vertex shading forward and backward.
    Pbr,
    /// LPIPS VGG and AlexNet per image pair.
    Lpips,
    /// Convergence: stage-1 test PSNR against training wall time (lego_400 and the shipped scene).
    Train,
    /// A stage-2 iteration against a stage-1 iteration on the same Gaussians, in turn in one
    /// process (`--run RUN` with a stage-2 checkpoint).
    Stages,
}

#[derive(Args)]
pub struct BenchArgs {
    #[arg(value_enum)]
    pub kernel: Kernel,
    /// raster, trace: time a trained scene instead of random ones (a 3DGS/2DGS/svgir PLY, e.g.
    /// a run's point_cloud.ply); raster views it from the test cameras of --data.
    #[arg(long)]
    pub ply: Option<PathBuf>,
    /// raster: the dataset whose test cameras view --ply.
    #[arg(long, requires = "ply")]
    pub data: Option<PathBuf>,
    /// raster: how many test cameras (spread over the test set) to time with --ply.
    #[arg(long, default_value_t = 5)]
    pub views: usize,
    /// raster: put the Gaussians (--ply's or the random ones) in Morton order of their centres
    /// before timing, the order training keeps them in, instead of the file's or drawn order.
    #[arg(long)]
    pub morton: bool,
    /// raster: background colour r,g,b for --ply.
    #[arg(long, default_value = "1,1,1", value_parser = super::eval::parse_rgb)]
    pub background: [f32; 3],
    /// raster: image sides of the random-scene table (comma-separated; default 256,400,800).
    #[arg(long, value_delimiter = ',')]
    pub size: Vec<u32>,
    /// raster, trace, pbr on a GPU: Gaussian counts of the random-scene table (raster default
    /// 10000,100000,300000; trace and pbr 10000,100000).
    #[arg(long, value_delimiter = ',')]
    pub gaussians: Vec<usize>,
    /// raster: kernel paths to compare, interleaved call by call: scalar, avx2, avx512, auto
    /// (comma-separated; default every path the CPU has).
    #[arg(long, value_delimiter = ',', value_parser = parse_simd)]
    pub simd: Vec<svgir_raster::Simd>,
    /// raster: timed calls per path and case.
    #[arg(long, default_value_t = 5)]
    pub reps: usize,
    /// raster, trace, pbr, train: the devices to time, side by side in one run (e.g. `cpu,gpu`; `gpu` takes
    /// the adapter `--device` of `svgir train` takes).
    #[arg(long, value_delimiter = ',', default_value = "cpu")]
    pub device: Vec<svgir_gpu::DeviceChoice>,
    #[command(flatten)]
    pub train: super::bench_train::TrainBenchArgs,
    #[command(flatten)]
    pub stages: super::bench_stages::StagesBenchArgs,
}

fn parse_simd(s: &str) -> Result<svgir_raster::Simd, String> {
    svgir_raster::Simd::parse(s).ok_or_else(|| format!("unknown kernel path {s:?} (scalar, avx2, avx512 or auto)"))
}

/// `svgir bench raster --ply --data`: the scene's timing table.
fn raster_scene(args: &BenchArgs, ply: &Path, data: &Path, threads: usize) -> Result<String> {
    let (mut surfels, _) = svgir_io::read_gaussians_ply(ply)?;
    if args.morton {
        surfels.sort_morton();
    }
    let opts = svgir_io::LoadOptions::default();
    let ds = svgir_io::load_dataset(data, &opts)?;
    let pool = if ds.test.is_empty() { &ds.train } else { &ds.test };
    anyhow::ensure!(!pool.is_empty(), "{}: no views to take cameras from", data.display());
    let k = args.views.clamp(1, pool.len());
    let cams: Vec<_> = (0..k).map(|i| pool[i * pool.len() / k].camera).collect();
    let mut s = format!(
        "svgir-raster bench, trained scene {} ({} Gaussians, SH degree {}, {} order), {} cameras of {}\n",
        ply.display(),
        surfels.len(),
        surfels.sh_degree,
        if args.morton { "Morton" } else { "file" },
        k,
        data.display()
    );
    s += &svgir_raster::bench::bench_scene(surfels, &cams, args.background, threads, args.reps.max(1));
    Ok(s)
}

pub fn run(args: BenchArgs) -> Result<()> {
    if let Some(ply) = args.ply.as_ref().filter(|_| !matches!(args.kernel, Kernel::Raster | Kernel::Trace)) {
        anyhow::bail!("--ply {}: only the raster and trace tables time a trained scene", ply.display());
    }
    // The rasterizer table prints its own machine line.
    if !matches!(args.kernel, Kernel::Raster | Kernel::Stages) {
        println!("machine: {}", svgir_raster::bench::machine_line());
    }
    let threads = rayon::current_num_threads();
    let on_cpu = args.device.contains(&svgir_gpu::DeviceChoice::Cpu);
    if matches!(args.kernel, Kernel::Raster) && args.ply.is_none() {
        for &d in args.device.iter().filter(|&&d| d != svgir_gpu::DeviceChoice::Cpu) {
            let Some(gpu) = super::engine::open_device(d)? else { continue };
            let sizes = if args.size.is_empty() { vec![256, 400, 800] } else { args.size.clone() };
            let ns = if args.gaussians.is_empty() { vec![10_000, 100_000, 300_000] } else { args.gaussians.clone() };
            println!("{}", svgir_gpu::bench::raster_table(&gpu, &sizes, &ns, args.reps.max(1))?);
        }
        if !on_cpu {
            return Ok(());
        }
    }
    if matches!(args.kernel, Kernel::Trace) && args.ply.is_none() {
        for &d in args.device.iter().filter(|&&d| d != svgir_gpu::DeviceChoice::Cpu) {
            let Some(gpu) = super::engine::open_device(d)? else { continue };
            let ns = if args.gaussians.is_empty() { vec![10_000, 100_000] } else { args.gaussians.clone() };
            println!("{}", svgir_gpu::bench::trace_table(gpu, &ns, args.reps.max(1))?);
        }
        if !on_cpu {
            return Ok(());
        }
    }
    if matches!(args.kernel, Kernel::Pbr) {
        for &d in args.device.iter().filter(|&&d| d != svgir_gpu::DeviceChoice::Cpu) {
            let Some(gpu) = super::engine::open_device(d)? else { continue };
            let ns = if args.gaussians.is_empty() { vec![10_000, 100_000] } else { args.gaussians.clone() };
            println!("{}", svgir_gpu::bench::shade_table(gpu, &ns, args.reps.max(1), threads)?);
        }
        if !on_cpu {
            return Ok(());
        }
    }
    let table = match args.kernel {
        Kernel::Raster => match (&args.ply, &args.data) {
            (Some(ply), Some(data)) => raster_scene(&args, ply, data, threads)?,
            (Some(ply), None) => anyhow::bail!("--ply {}: raster needs --data for the cameras", ply.display()),
            _ => {
                let mut o = svgir_raster::bench::BenchOptions::full(threads);
                if !args.size.is_empty() {
                    o.sizes = args.size.clone();
                }
                if !args.gaussians.is_empty() {
                    o.gaussians = args.gaussians.clone();
                }
                if !args.simd.is_empty() {
                    o.paths = args.simd.clone();
                }
                o.reps = args.reps.max(1);
                o.morton = args.morton;
                svgir_raster::bench::bench_table_with(&o)
            }
        },
        Kernel::Trace => match &args.ply {
            Some(ply) => {
                let (surfels, _) = svgir_io::read_gaussians_ply(ply)?;
                svgir_trace::bench::bench_table_scene(threads, &surfels, &ply.display().to_string())
            }
            None => svgir_trace::bench::bench_table(threads),
        },
        Kernel::Pbr => svgir_pbr::bench::bench_table(threads),
        Kernel::Lpips => {
            use svgir_eval::lpips_weights::{find_lpips_weights, HOW_TO_GET};
            let find = |net| {
                find_lpips_weights(net, None)?.with_context(|| format!("LPIPS {net:?} weights not found. {HOW_TO_GET}"))
            };
            let (vgg, alex) = (find(svgir_metrics::Net::Vgg)?, find(svgir_metrics::Net::Alex)?);
            svgir_metrics::lpips::bench_table(&std::fs::read(vgg)?, &std::fs::read(alex)?, threads)?
        }
        Kernel::Train => {
            super::bench_train::run(&args.train, &args.device, &svgir_raster::bench::machine_line(), threads)?
        }
        Kernel::Stages => super::bench_stages::run(&args.stages, &svgir_raster::bench::machine_line(), threads)?,
    };
    println!("{table}");
    Ok(())
}
