//! Where a stage-1 run's iterations run (`--device auto|cpu|gpu`): the CPU trainer itself, or
//! the same run resident on a GPU. Both keep the run's [`Stage1`], so checkpoints, evaluation
//! and outputs are device-blind, and a run resumes on either device.

use anyhow::Result;
use std::time::Instant;
use svgir_core::{Camera, Dataset};
use svgir_gpu::{AdapterReport, DeviceChoice, GpuStage1};
use svgir_raster::RenderOutput;
use svgir_train::driver::DriverError;
use svgir_train::{Stage1, StepStats};

/// A stage-1 run on its device.
pub enum Engine {
    /// The CPU kernels (the oracle).
    Cpu(Box<Stage1>),
    /// The run resident on a GPU, the wall time its steps took (seconds) and the overflowed
    /// renders already reported.
    Gpu(Box<GpuStage1>, f64, u64),
}

/// Opens the device `choice` asks for: `None` for the CPU. Prints what it chose.
pub fn open_device(choice: DeviceChoice) -> Result<Option<svgir_gpu::Gpu>> {
    let gpu = svgir_gpu::open(choice)?;
    match &gpu {
        Some(g) => eprintln!("device: GPU {}", g.report),
        None => eprintln!("device: CPU ({} threads)", rayon::current_num_threads()),
    }
    Ok(gpu)
}

/// Stage 2's and relighting's tracer, vertex shader and feature raster on the device `choice`
/// asks for, and the GPU they run on (`None`: the CPU).
pub fn stage2_kernels(choice: DeviceChoice) -> Result<(svgir_train::Kernels, Option<svgir_gpu::Gpu>)> {
    let gpu = open_device(choice)?;
    let kernels = match &gpu {
        Some(gpu) => svgir_train::Kernels {
            tracer: std::sync::Arc::new(svgir_gpu::GpuTracer::new(gpu.clone())),
            shader: std::sync::Arc::new(svgir_gpu::GpuShader::new(gpu.clone())),
            raster: std::sync::Arc::new(svgir_gpu::GpuFeatureRaster::new(gpu.clone())),
        },
        None => svgir_train::Kernels::cpu(),
    };
    Ok((kernels, gpu))
}

/// The GPU memory `gpu`'s buffers hold, in all and per surfel of the `surfels` a run keeps
/// there, as a line for the run's summary (the paper's figure: 14 GB at K = 64).
pub fn gpu_memory_line(gpu: &svgir_gpu::Gpu, surfels: usize) -> Option<String> {
    let bytes = gpu.allocated_bytes()?;
    Some(format!(
        "GPU memory: {:.1} MiB in buffers, {:.0} bytes per surfel ({surfels} surfels)",
        bytes as f64 / (1 << 20) as f64,
        bytes as f64 / surfels.max(1) as f64
    ))
}

impl Engine {
    /// Puts `trainer` on `gpu`, or keeps it on the CPU.
    pub fn new(trainer: Stage1, gpu: Option<svgir_gpu::Gpu>, dataset: &Dataset) -> Result<Self> {
        let Some(gpu) = gpu else { return Ok(Self::Cpu(Box::new(trainer))) };
        Ok(Self::Gpu(Box::new(GpuStage1::new(trainer, gpu, dataset)?), 0.0, 0))
    }

    /// The run's state (surfels, moments and statistics current after [`Engine::sync`]).
    pub fn host(&self) -> &Stage1 {
        match self {
            Self::Cpu(t) => t,
            Self::Gpu(g, ..) => &g.host,
        }
    }

    /// The adapter, on a GPU.
    pub fn adapter(&self) -> Option<&AdapterReport> {
        match self {
            Self::Cpu(_) => None,
            Self::Gpu(g, ..) => Some(&g.gpu().report),
        }
    }

    /// One iteration. On a GPU the loss comes back only when `read` (or at the trainer's own
    /// cadence); otherwise its fields are NaN.
    pub fn step(&mut self, dataset: &Dataset, read: bool) -> Result<StepStats> {
        match self {
            Self::Cpu(t) => Ok(t.step(dataset)),
            Self::Gpu(g, secs, told) => {
                let t0 = Instant::now();
                let s = g.step(dataset, read)?;
                *secs += t0.elapsed().as_secs_f64();
                if g.overflows > *told {
                    eprintln!(
                        "warning: {} GPU renders by iteration {} binned more tile entries than their buffers held; \
                         their steps were skipped and the buffers grown",
                        g.overflows - *told,
                        s.iteration
                    );
                    *told = g.overflows;
                }
                Ok(s)
            }
        }
    }

    /// Brings the run's state up to date (before a checkpoint, an evaluation, the outputs).
    pub fn sync(&mut self) -> Result<()> {
        if let Self::Gpu(g, ..) = self {
            g.sync()?;
        }
        Ok(())
    }

    /// Renders `camera` with the current surfels over `bg` on the run's device.
    pub fn render_view(&self, camera: &Camera, bg: [f32; 3]) -> Result<RenderOutput> {
        match self {
            Self::Cpu(t) => Ok(t.render_view(camera, bg)),
            Self::Gpu(g, ..) => Ok(g.render_view(camera, bg)?),
        }
    }

    /// Milliseconds per iteration by phase, as `timings.json` records them: the CPU's phases,
    /// or on a GPU the whole step (its kernels are not timed one by one).
    pub fn ms_per_iteration(&self) -> serde_json::Value {
        let t = self.host();
        let its = t.iteration.max(1) as f64;
        match self {
            Self::Cpu(_) => {
                let p = &t.times;
                serde_json::json!({
                    "forward": 1e3 * p.forward / its, "loss": 1e3 * p.loss / its, "backward": 1e3 * p.backward / its,
                    "optimizer": 1e3 * p.optimizer / its, "densify": 1e3 * p.densify / its,
                })
            }
            Self::Gpu(_, secs, _) => serde_json::json!({ "gpu_step": 1e3 * secs / its }),
        }
    }
}

/// The run loop drives either device alike (`svgir_train::driver`).
impl svgir_train::driver::Trainer for Engine {
    type Stats = StepStats;
    fn iteration(&self) -> u64 {
        self.host().iteration
    }
    fn is_done(&self) -> bool {
        self.host().is_done()
    }
    fn step(&mut self, dataset: &Dataset, read: bool) -> Result<StepStats, DriverError> {
        Engine::step(self, dataset, read).map_err(DriverError::step)
    }
    fn stats_iteration(stats: &StepStats) -> u64 {
        stats.iteration
    }
    fn always_logged(stats: &StepStats) -> bool {
        stats.densify.is_some()
    }
    fn evaluates_before(&self, next: u64) -> bool {
        self.host().config.resets_opacity_at(next)
    }
    fn save(&mut self, path: &std::path::Path) -> Result<(), DriverError> {
        self.sync().map_err(DriverError::step)?;
        Ok(svgir_train::checkpoint::save(self.host(), path)?)
    }
}
