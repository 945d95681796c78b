//! `svgir`: inverse rendering with spatially-varying Gaussian surfels, from the command line.
//!
//! Each subcommand lives in `commands/`; this file only parses arguments and dispatches.

mod commands;
mod malloc_tuning;
mod progress;

use clap::{Parser, Subcommand};

/// svgir recovers geometry, materials and lighting of an object from posed photos (SVG-IR) and
/// relights it. Start with `svgir demo`, which runs the whole pipeline on a scene shipped in the
/// repository.
#[derive(Parser)]
#[command(name = "svgir", version, propagate_version = true)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Describe a dataset: views, resolution, camera model, ground truth present.
    Info(commands::info::InfoArgs),
    /// Stage 1: fit Gaussian surfels with SH colour (geometry + radiance field) to a dataset.
    #[command(after_help = "Research switches and loss weights: `svgir train --help`.")]
    Train(commands::train::TrainArgs),
    /// Foreground masks for a capture without them, from a stage-1 reconstruction (PNGs to check and edit).
    Masks(commands::masks::MasksArgs),
    /// Stage 2: recover materials and lighting on a stage-1 run, relight and evaluate (SPEC 6-8).
    #[command(after_help = "Research switches, ablations and diagnostics: `svgir inverse --help`.")]
    Inverse(commands::inverse::InverseArgs),
    /// Render a stage-2 model under a new HDR environment map.
    Relight(commands::relight::RelightArgs),
    /// Export relightable assets: a textured PBR mesh (GLB + light .hdr) and splats (PLY, glTF).
    Export(commands::export::ExportArgs),
    /// Compare images (two folders, or a run's test renders with its dataset) and print PSNR/SSIM/LPIPS.
    Eval(commands::eval::EvalArgs),
    /// Write a self-contained HTML report for a run folder.
    Report(commands::report::ReportArgs),
    /// Run the pipeline on the scene shipped in the repository and write a report.
    Demo(commands::demo::DemoArgs),
    #[command(after_help = "Seed, relighting samples and turntable length: `svgir capture --help`.")]
    /// Your own photos to a relit object in one command: poses (COLMAP), stage 1, masks, stage 1 on
    /// the object, stage 2, relighting, exports, viewer and report; each step resumes.
    Capture(commands::capture::CaptureArgs),
    /// Print performance tables of the kernels (rasterizer, tracer, LPIPS).
    Bench(commands::bench::BenchArgs),
    /// Write an interactive relighting viewer (one HTML file, WebGL2) for a stage-2 run.
    View(commands::view::ViewArgs),
}

fn main() {
    malloc_tuning::keep_freed_memory();
    let cli = Cli::parse();
    if let Some(t) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(t).build_global() {
            eprintln!("error: cannot set {t} threads: {e}");
            std::process::exit(2);
        }
    }
    let result = match cli.command {
        Command::Info(a) => commands::info::run(a),
        Command::Train(a) => commands::train::run(a),
        Command::Masks(a) => commands::masks::run(a),
        Command::Eval(a) => commands::eval::run(a),
        Command::Inverse(a) => commands::inverse::run(a),
        Command::Relight(a) => commands::relight::run(a),
        Command::Export(a) => commands::export::run(a),
        Command::Bench(a) => commands::bench::run(a),
        Command::Report(a) => commands::report::run(a),
        Command::Capture(a) => commands::capture::run(a),
        Command::Demo(a) => commands::demo::run(a),
        Command::View(a) => commands::view::run(a),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
