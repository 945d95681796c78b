//! The timing table behind `svgir bench raster` (feature `bench`: it reads `/proc` and the
//! clock, so it stays out of the library's default build), on the scenes of
//! [`crate::fixtures`]. Timing: median of repeated calls in a rayon pool of the given size.

use crate::fixtures::{random_scene, Problem};
use crate::{render, Background, ColorSource, PhaseTimes, RasterConfig, Simd};
use std::fmt::Write;
use std::time::Instant;
use svgir_core::{Camera, Surfels};

/// Milliseconds one call of `f` takes.
fn elapsed_ms(f: impl FnOnce()) -> f64 {
    let t0 = Instant::now();
    f();
    t0.elapsed().as_secs_f64() * 1e3
}

fn median(t: &mut [f64]) -> f64 {
    t.sort_by(|a, b| a.total_cmp(b));
    t[t.len() / 2]
}

fn thread_counts(threads: usize) -> Vec<usize> {
    let mut t = vec![1, threads.max(1)];
    t.dedup();
    t
}

/// CPU seconds (user + system) this process has used so far, from `/proc/self/stat` (10 ms
/// ticks); `None` where that file does not exist. Wall time on a shared machine also counts the
/// other processes' time slices, CPU time does not.
pub fn process_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// What [`bench_table_with`] times.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Largest thread count (1 is always timed too).
    pub threads: usize,
    /// Image sides.
    pub sizes: Vec<u32>,
    /// Gaussian counts.
    pub gaussians: Vec<usize>,
    /// Kernel paths; each is lowered to what the CPU has ([`Simd::resolve`]), duplicates dropped.
    pub paths: Vec<Simd>,
    /// Timed calls per path (interleaved across paths, so they share the machine's noise).
    pub reps: usize,
    /// Put the random Gaussians in Morton order of their centres, the order training keeps
    /// them in, instead of the order they were drawn in.
    pub morton: bool,
}

impl BenchOptions {
    /// The full grid: 10k / 100k / 300k Gaussians at 256, 400, 800 px, every path the CPU has.
    pub fn full(threads: usize) -> Self {
        Self {
            threads,
            sizes: vec![256, 400, 800],
            gaussians: vec![10_000, 100_000, 300_000],
            paths: Simd::available(),
            reps: 5,
            morton: false,
        }
    }
}

/// The machine line of the tables: CPU model (with its family, model number and nominal clock,
/// which tell apart VMs whose model name is generic), threads, detected features, the `Auto` path.
pub fn machine_line() -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let field = |name: &str| {
        info.lines()
            .find(|l| l.split(':').next().is_some_and(|k| k.trim() == name))
            .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
            .filter(|v| !v.is_empty())
    };
    let mut cpu = field("model name").unwrap_or_else(|| std::env::consts::ARCH.to_string());
    if let (Some(f), Some(m)) = (field("cpu family"), field("model")) {
        cpu += &format!(" (family {f} model {m})");
    }
    if let Some(mhz) = field("cpu MHz").and_then(|v| v.parse::<f64>().ok()) {
        cpu += &format!(" at {mhz:.0} MHz");
    }
    format!(
        "{cpu}, {} threads available; features {}; default path {}",
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        crate::simd::cpu_features(),
        Simd::Auto.resolve().name()
    )
}

fn header(s: &mut String) {
    let _ = writeln!(
        s,
        "{:>9} {:>8} {:>7} {:>7} {:>8} {:>10} {:>8} {:>8} {:>9} {:>8} {:>10}",
        "size", "gauss", "threads", "path", "pairs", "box evals", "fwd ms", "bwd ms", "total ms", "cpu ms", "Mevals/s"
    );
}

/// Forward and forward+backward timings at 256^2, 400^2, 800^2 with 10k, 100k, 300k random
/// Gaussians, on 1 and `threads` threads, for every kernel path the CPU has.
pub fn bench_table(threads: usize) -> String {
    bench_table_with(&BenchOptions::full(threads))
}

/// The random-scene table for the given sizes, counts, threads and paths (see [`BenchOptions`]).
pub fn bench_table_with(o: &BenchOptions) -> String {
    let mut s = String::new();
    let order = if o.morton { "Morton order" } else { "drawn order" };
    let _ = writeln!(s, "svgir-raster bench, random object scene ({order}): SH degree 3, colour + all aux outputs");
    let _ = writeln!(s, "machine: {}", machine_line());
    header(&mut s);
    let mut paths: Vec<Simd> = o.paths.iter().map(|p| p.resolve()).collect();
    paths.dedup();
    let mut breakdown = Vec::new();
    for t in thread_counts(o.threads) {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().expect("rayon pool");
        for &n in &o.gaussians {
            let mut scene = random_scene(n, 7);
            if o.morton {
                scene.sort_morton();
            }
            let mut surfels = Some(scene);
            for &res in &o.sizes {
                let problem = Problem::with_surfels(surfels.take().expect("scene"), res);
                bench_problem(
                    &mut s,
                    &pool,
                    &problem,
                    &format!("{res}x{res}"),
                    t,
                    &paths,
                    o.reps,
                    RasterConfig::default(),
                    &mut breakdown,
                );
                surfels = Some(problem.surfels);
            }
        }
    }
    let _ = writeln!(
        s,
        "box evals: Gaussian-pixel pairs inside each Gaussian's box (upper bound, before early stop); \
         fwd / bwd / total: medians of {} calls; cpu ms: process CPU time per forward+backward; \
         Mevals/s: 2 x box evals / total.",
        o.reps
    );
    let _ = writeln!(s, "phases (ms, medians; tiles = the tile kernels, reduce = per-Gaussian sums):");
    for line in breakdown {
        let _ = writeln!(s, "{line}");
    }
    s
}

/// Times `problem` on every path, the paths interleaved call by call, one row each.
#[allow(clippy::too_many_arguments)]
fn bench_problem(
    s: &mut String,
    pool: &rayon::ThreadPool,
    problem: &Problem,
    size: &str,
    threads: usize,
    paths: &[Simd],
    reps: usize,
    base: RasterConfig,
    breakdown: &mut Vec<String>,
) {
    let (input, grads) = (problem.input(), problem.grads());
    let (pairs, evals) = pool.install(|| {
        let (_, st) = render(&input, &base);
        (st.num_tile_entries(), st.box_evaluations())
    });
    let k = paths.len();
    let (mut fwd, mut bwd, mut tot) = (vec![Vec::new(); k], vec![Vec::new(); k], vec![Vec::new(); k]);
    let mut cpu = vec![0.0f64; k];
    let mut phases: Vec<Vec<Vec<(String, f64)>>> = vec![Vec::new(); k];
    for rep in 0..reps + 1 {
        for (i, &path) in paths.iter().enumerate() {
            let cfg = RasterConfig { simd: path, ..base };
            let c0 = process_cpu_seconds();
            let (f, b, ph) = pool.install(|| {
                let t0 = Instant::now();
                let (out, st) = render(&input, &cfg);
                let f = t0.elapsed().as_secs_f64() * 1e3;
                let t1 = Instant::now();
                let g = crate::backward(&input, &cfg, &st, &out, &grads);
                let b = t1.elapsed().as_secs_f64() * 1e3;
                let ph = phases_of(&st.phases, &g.phases);
                drop(g);
                (f, b, ph)
            });
            // The first round warms the pool and the allocator up.
            if rep > 0 {
                fwd[i].push(f);
                bwd[i].push(b);
                tot[i].push(f + b);
                phases[i].push(ph);
                if let (Some(a), Some(b)) = (c0, process_cpu_seconds()) {
                    cpu[i] += b - a;
                }
            }
        }
    }
    for (i, path) in paths.iter().enumerate() {
        let total = median(&mut tot[i]);
        let _ = writeln!(
            s,
            "{:>9} {:>8} {:>7} {:>7} {:>8} {:>10} {:>8.1} {:>8.1} {:>9.1} {:>8.1} {:>10.1}",
            size,
            problem.surfels.len(),
            threads,
            path.name(),
            pairs,
            evals,
            median(&mut fwd[i]),
            median(&mut bwd[i]),
            total,
            cpu[i] * 1e3 / reps as f64,
            2.0 * evals as f64 / total / 1e3
        );
    }
    for (i, path) in paths.iter().enumerate() {
        let label = format!("{size} {} {threads}t {}", problem.surfels.len(), path.name());
        breakdown.push(phase_line(&label, &phases[i]));
    }
}

/// The phases of one forward and its backward, named `fwd <phase>` and `bwd <phase>`.
fn phases_of(fwd: &PhaseTimes, bwd: &PhaseTimes) -> Vec<(String, f64)> {
    let named = |pre: &str, p: &PhaseTimes| p.ms.iter().map(|(n, t)| (format!("{pre} {n}"), *t)).collect::<Vec<_>>();
    let mut ph = named("fwd", fwd);
    ph.extend(named("bwd", bwd));
    ph
}

/// One line of the phase breakdown: the median milliseconds of each phase over the calls.
fn phase_line(label: &str, calls: &[Vec<(String, f64)>]) -> String {
    let mut line = format!("{label:>24}:");
    let Some(first) = calls.first() else { return line };
    for (j, (name, _)) in first.iter().enumerate() {
        let mut t: Vec<f64> = calls.iter().filter_map(|c| c.get(j).map(|p| p.1)).collect();
        let _ = write!(line, " {name} {:.1}", median(&mut t));
    }
    line
}

#[allow(clippy::too_many_arguments)]
fn row(s: &mut String, size: &str, n: usize, threads: usize, pairs: u64, evals: u64, fwd: f64, fb: f64) {
    let _ = writeln!(
        s,
        "{:>9} {:>8} {:>7} {:>7} {:>8} {:>10} {:>8.1} {:>8.1} {:>9.1} {:>8} {:>10.1}",
        size,
        n,
        threads,
        Simd::Auto.resolve().name(),
        pairs,
        evals,
        fwd,
        fb - fwd,
        fb,
        "-",
        2.0 * evals as f64 / fb / 1e3
    );
}

/// Forward and forward+backward timings of a given (trained) scene seen from `cameras`, on 1
/// and `threads` threads, for each variant of the outputs differentiated: the variants and
/// cameras take turns call by call, `reps` rounds after an untimed one; the median over each
/// camera's calls, then over the cameras, is reported, with pair counts averaged over them.
pub fn bench_scene(surfels: Surfels, cameras: &[Camera], background: [f32; 3], threads: usize, reps: usize) -> String {
    assert!(!cameras.is_empty(), "bench_scene needs at least one camera");
    let mut s = String::new();
    let n = surfels.len();
    header(&mut s);
    let mut problems: Vec<Problem> = Vec::new();
    let mut surfels = Some(surfels);
    for cam in cameras {
        // Every problem needs the surfels; cloning keeps the bench simple (this is not timed).
        let sf = surfels.take().unwrap_or_else(|| problems[0].surfels.clone());
        problems.push(Problem::with_camera(sf, *cam));
    }
    let (w, h) = (cameras[0].intrinsics.width, cameras[0].intrinsics.height);
    // "all": a gradient on every output (as the random table); "stage 1": the outputs stage-1
    // training differentiates (colour, opacity, depth, normal; distortion off, as its weight);
    // "colour": 3DGS's loss (`--profile views`), no distortion and no geometry outputs;
    // "stage 2 SH" and "stage 2 PBR": stage 2's two renders, whose geometry is frozen (the SH
    // colour alone; colours interpolated from 4 vertices with the training pass's extra
    // channels: 7 material channels interpolated and the SH colour uniform, or interpolated as
    // well to compare; the PBR pass's depth without its splat normals, or with them to compare),
    // each also with the geometry gradients stage 2 does not need.
    let colour = RasterConfig { distortion: false, geometry: false, ..Default::default() };
    let pbr = RasterConfig { distortion: false, ..Default::default() };
    let frozen_normals = RasterConfig { geometry_grads: false, ..pbr };
    let frozen = RasterConfig { normals: false, ..frozen_normals };
    // The feature tables' uniform channels (`None`: SH colours, no extra table).
    let variants = [
        ("all", RasterConfig::default(), None),
        ("stage 1", pbr, None),
        ("colour", colour, None),
        ("stage 2 SH", RasterConfig { geometry_grads: false, ..colour }, None),
        ("stage 2 PBR, with geometry gradients", RasterConfig { normals: false, ..pbr }, Some(UNIFORM)),
        ("stage 2 PBR", frozen, Some(UNIFORM)),
        ("stage 2 PBR, with the normal output", frozen_normals, Some(UNIFORM)),
        ("stage 2 PBR, the SH colour interpolated too", frozen, Some(0)),
    ];
    // Stage 2's feature tables: smooth made-up values (the timing does not depend on them).
    const M: usize = 4;
    const CE: usize = 10;
    const UNIFORM: usize = 3;
    let colf: Vec<f32> = (0..n * M * 3).map(|i| 0.2 + 0.6 * ((i % 17) as f32 / 17.0)).collect();
    let extf: Vec<f32> = (0..n * M * CE).map(|i| 0.1 + 0.8 * ((i % 13) as f32 / 13.0)).collect();
    let npx = w as usize * h as usize;
    let g_ext = vec![1e-3f32; npx * CE];
    // The variants take turns call by call (each rep runs every camera under every variant), so
    // that a slow minute of a noisy machine falls on all of them alike.
    let nv = variants.len();
    let mut rows: Vec<String> = vec![String::new(); nv];
    for t in thread_counts(threads) {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().expect("rayon pool");
        let k = problems.len();
        let (mut pairs, mut evals) = (vec![0usize; nv], vec![0u64; nv]);
        // Per variant and camera, the calls' milliseconds; per variant, every call's phases.
        let (mut fwd, mut fb) = (vec![vec![Vec::new(); k]; nv], vec![vec![Vec::new(); k]; nv]);
        let mut phases: Vec<Vec<Vec<(String, f64)>>> = vec![Vec::new(); nv];
        pool.install(|| {
            for rep in 0..=reps {
                for (j, p) in problems.iter().enumerate() {
                    for (v, (_, cfg, feat)) in variants.iter().enumerate() {
                        let mut input = p.input();
                        input.background = Background::Color(background);
                        let mut grads = p.grads();
                        if let Some(uniform) = *feat {
                            let colors = crate::Features { data: &colf, vertices: M, channels: 3, uniform: 0 };
                            input.colors = ColorSource::Features(colors);
                            input.extra = Some(crate::Features { data: &extf, vertices: M, channels: CE, uniform });
                            grads.extra = Some(&g_ext);
                            grads.normal = None;
                        }
                        if !cfg.distortion {
                            grads.distortion = None;
                        }
                        if rep == 0 {
                            // The first round counts the work and warms the caches, untimed.
                            let (_, st) = render(&input, cfg);
                            pairs[v] += st.num_tile_entries();
                            evals[v] += st.box_evaluations();
                            continue;
                        }
                        fwd[v][j].push(elapsed_ms(|| drop(render(&input, cfg))));
                        fb[v][j].push(elapsed_ms(|| {
                            let (out, st) = render(&input, cfg);
                            let g = crate::backward(&input, cfg, &st, &out, &grads);
                            phases[v].push(phases_of(&st.phases, &g.phases));
                        }));
                    }
                }
            }
        });
        // The median over each camera's calls, then over the cameras.
        let med = |per_camera: &mut Vec<Vec<f64>>| {
            let mut m: Vec<f64> = per_camera.iter_mut().map(|c| median(c)).collect();
            median(&mut m)
        };
        for v in 0..nv {
            let (p, e) = ((pairs[v] / k) as u64, evals[v] / k as u64);
            row(&mut rows[v], &format!("{w}x{h}"), n, t, p, e, med(&mut fwd[v]), med(&mut fb[v]));
            rows[v] += &phase_line(&format!("phases, {t}t"), &phases[v]);
            rows[v].push('\n');
        }
    }
    for ((label, cfg, _), r) in variants.iter().zip(&rows) {
        let _ = writeln!(
            s,
            "gradients on: {label} outputs{}",
            if cfg.geometry_grads { "" } else { " (no geometry gradients)" }
        );
        s += r;
    }
    s
}
