//! The run loop of a stage, the same for every front end (`svgir train`, `svgir inverse`,
//! `svgir demo` through them, `svgir bench train`): iterate to the trainer's length, append
//! statistics to `RUN/metrics.jsonl`, run the periodic evaluations, write the checkpoint
//! atomically on its period and on an interruption, and hand back how the run ended. The front
//! end only parses flags, builds the configuration, opens the run ([`open_stage1`], [`open_stage2`]: new or
//! resumed, with the changes a resume may make) and watches through an [`Observer`] (progress
//! bar, evaluation renders, Ctrl-C).
//!
//! A [`Trainer`] is stage 1 on the CPU ([`crate::Stage1`]), stage 2 ([`crate::Stage2`]), or any
//! other engine with the same iteration (the CLI's GPU engine).

use crate::checkpoint::{self, CheckpointError};
use crate::config::Stage1Config;
use crate::stage1::{Stage1, StepStats};
use crate::stage2::{Stage2, Stage2Config, Stage2Step};
use serde::Serialize;
use serde_json::json;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;
use svgir_core::{Dataset, Surfels};

/// What a run loop can fail with.
#[derive(Debug, thiserror::Error)]
pub enum DriverError {
    /// The trainer's iteration (or an observer's evaluation) failed.
    #[error(transparent)]
    Step(Box<dyn std::error::Error + Send + Sync>),
    /// Writing the checkpoint failed.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// Writing a run file (`metrics.jsonl`, `config.json`) failed.
    #[error("{path}: {err}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        err: std::io::Error,
    },
}

impl DriverError {
    /// A trainer's or observer's own error.
    pub fn step(e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> Self {
        Self::Step(e.into())
    }
}

/// One stage's trainer, as the loop drives it.
pub trait Trainer {
    /// One iteration's statistics (a `metrics.jsonl` row).
    type Stats: Serialize;
    /// Iterations done.
    fn iteration(&self) -> u64;
    /// Whether the run has reached its length.
    fn is_done(&self) -> bool;
    /// One iteration. `read`: the loop logs it, so an engine that reads its loss back from a
    /// device only at times must read it now.
    fn step(&mut self, dataset: &Dataset, read: bool) -> Result<Self::Stats, DriverError>;
    /// The iteration a row belongs to.
    fn stats_iteration(stats: &Self::Stats) -> u64;
    /// Whether the row is logged whatever the period (a densification, a sun search).
    fn always_logged(stats: &Self::Stats) -> bool;
    /// Whether an evaluation due at iteration `next` must run before that step rather than after
    /// it (stage 1: an opacity reset would knock every opacity down just before it scores).
    fn evaluates_before(&self, _next: u64) -> bool {
        false
    }
    /// Writes the checkpoint to `path` atomically (bringing device state up to date first).
    fn save(&mut self, path: &Path) -> Result<(), DriverError>;
}

/// How often the loop logs, evaluates and checkpoints (0: never; the end of the run and an
/// interruption always checkpoint).
#[derive(Clone, Copy, Debug)]
pub struct Periods {
    /// Append a statistics row every this many iterations.
    pub log_every: u64,
    /// Run the observer's evaluation every this many iterations (not at the last one: the front
    /// end's final evaluation covers it).
    pub eval_every: u64,
    /// Write the checkpoint every this many iterations.
    pub checkpoint_every: u64,
}

/// What the front end hooks into the loop.
pub trait Observer<T: Trainer> {
    /// After each iteration (progress, messages).
    fn stepped(&mut self, _trainer: &T, _stats: &T::Stats) {}
    /// A periodic evaluation at the trainer's iteration: the metrics for the row's `test` field.
    fn evaluate(&mut self, _trainer: &mut T, _dataset: &Dataset) -> Result<serde_json::Value, DriverError> {
        Ok(serde_json::Value::Null)
    }
    /// Checked after each iteration: stop, with a checkpoint, when true (Ctrl-C).
    fn interrupted(&self) -> bool {
        false
    }
}

/// An observer that watches nothing (library use, tests).
pub struct Unobserved;

impl<T: Trainer> Observer<T> for Unobserved {}

/// How a run loop ended; the checkpoint holds the state either way.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ended {
    /// The trainer reached its length.
    Finished,
    /// The observer asked to stop after this iteration.
    Interrupted {
        /// The last iteration done (and saved).
        iteration: u64,
    },
}

/// The run's wall time, and the part of it the periodic evaluations took (left out of `train_s`).
struct Clock {
    start: Instant,
    eval_s: f64,
}

impl Clock {
    fn elapsed_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    fn train_s(&self) -> f64 {
        self.elapsed_s() - self.eval_s
    }
}

/// Whether iteration `it` falls on a period of `n` (0: never).
fn on_period(it: u64, n: u64) -> bool {
    n > 0 && it.is_multiple_of(n)
}

/// Runs `trainer` to its length (or an interruption) in the run folder `out`: rows appended to
/// `out/metrics.jsonl` with the wall time (`elapsed_s`) and the training time without the
/// evaluations (`train_s`), the checkpoint at `out/checkpoint.bin`.
pub fn run<T: Trainer>(
    trainer: &mut T,
    dataset: &Dataset,
    out: &Path,
    periods: Periods,
    observer: &mut dyn Observer<T>,
) -> Result<Ended, DriverError> {
    let log_path = out.join("metrics.jsonl");
    let ckpt = out.join("checkpoint.bin");
    let log_err = |err| DriverError::Io { path: log_path.clone(), err };
    let mut log = std::fs::OpenOptions::new().create(true).append(true).open(&log_path).map_err(log_err)?;
    let mut clock = Clock { start: Instant::now(), eval_s: 0.0 };
    let evaluate = |trainer: &mut T, observer: &mut dyn Observer<T>, clock: &mut Clock, log: &mut std::fs::File| {
        let train_s = clock.train_s();
        let t0 = Instant::now();
        let m = observer.evaluate(trainer, dataset)?;
        clock.eval_s += t0.elapsed().as_secs_f64();
        let row =
            json!({"iteration": trainer.iteration(), "elapsed_s": clock.elapsed_s(), "train_s": train_s, "test": m});
        writeln!(log, "{row}").map_err(log_err)
    };
    while !trainer.is_done() {
        let next = trainer.iteration() + 1;
        let eval_due = on_period(next, periods.eval_every);
        let eval_before = eval_due && next > 1 && trainer.evaluates_before(next);
        if eval_before {
            evaluate(trainer, observer, &mut clock, &mut log)?;
        }
        let stats = trainer.step(dataset, on_period(next, periods.log_every) || next <= 10)?;
        let it = T::stats_iteration(&stats);
        observer.stepped(trainer, &stats);
        if on_period(it, periods.log_every) || T::always_logged(&stats) {
            let mut row = serde_json::to_value(&stats).map_err(DriverError::step)?;
            row["elapsed_s"] = json!(clock.elapsed_s());
            row["train_s"] = json!(clock.train_s());
            writeln!(log, "{row}").map_err(log_err)?;
        }
        if eval_due && !eval_before && !trainer.is_done() {
            evaluate(trainer, observer, &mut clock, &mut log)?;
        }
        let interrupted = observer.interrupted();
        // The last iteration's checkpoint is written once, after the loop.
        if (on_period(it, periods.checkpoint_every) && !trainer.is_done()) || interrupted {
            trainer.save(&ckpt)?;
        }
        if interrupted {
            return Ok(Ended::Interrupted { iteration: it });
        }
    }
    trainer.save(&ckpt)?;
    Ok(Ended::Finished)
}

/// A new run's folder: `meta` written as `config.json`, an earlier run's `metrics.jsonl` cleared.
fn start_run_folder(out: &Path, meta: &serde_json::Value) -> Result<(), DriverError> {
    let path = out.join("config.json");
    let text = serde_json::to_string_pretty(meta).map_err(DriverError::step)?;
    std::fs::write(&path, text).map_err(|err| DriverError::Io { path, err })?;
    let _ = std::fs::remove_file(out.join("metrics.jsonl"));
    Ok(())
}

/// How stage 1 starts in its run folder.
pub enum Stage1Start {
    /// A new run of `config` from `surfels`; `meta` is written as `config.json`.
    New {
        /// The run's configuration.
        config: Box<Stage1Config>,
        /// The initial Gaussians.
        surfels: Surfels,
        /// What `config.json` records (the configuration and the run's provenance).
        meta: serde_json::Value,
    },
    /// The run's checkpoint; `iterations`, when given, sets the run's length (it may extend a
    /// finished run).
    Resume {
        /// The new length, if the user gave one.
        iterations: Option<u64>,
    },
}

/// Opens stage 1 in `out`: a new run (its `config.json` written, an old `metrics.jsonl`
/// cleared) or its checkpoint resumed. Each step is told to `note`, for the front end to print.
pub fn open_stage1(
    out: &Path,
    start: Stage1Start,
    dataset: &Dataset,
    note: &mut dyn FnMut(String),
) -> Result<Stage1, DriverError> {
    match start {
        Stage1Start::New { config, surfels, meta } => {
            start_run_folder(out, &meta)?;
            Ok(Stage1::new(*config, surfels, dataset))
        }
        Stage1Start::Resume { iterations } => {
            let ckpt = out.join("checkpoint.bin");
            let mut t = checkpoint::load(&ckpt, dataset)?;
            note(format!("resumed {} at iteration {}", ckpt.display(), t.iteration));
            match iterations {
                Some(n) if n != t.config.iterations => {
                    note(format!(
                        "stage 1: iterations {} -> {n}: densification and SH upgrades keep the checkpoint's schedule; \
                         the position learning rate's decay and the depth-normal ramp stretch to the new length",
                        t.config.iterations
                    ));
                    t.config.iterations = n;
                }
                _ => note(format!("stage 1: continuing to the checkpoint's {} iterations", t.config.iterations)),
            }
            Ok(t)
        }
    }
}

/// What a resumed stage-2 run may change; every other setting comes from its checkpoint.
#[derive(Clone, Debug, Default)]
pub struct Stage2Changes {
    /// The run's length (may extend a finished run: stage 2's rates are constant, so this is
    /// the same as a longer run).
    pub iterations: Option<u64>,
    /// The BRDF's diffuse lobe (e.g. to re-evaluate under the other one).
    pub diffuse: Option<svgir_shading::Diffuse>,
    /// Where the training views' shaded sets come from.
    pub shade_sets: Option<crate::stage2::ShadeSets>,
    /// Until which iteration the direction subsets are shaded.
    pub shade_directions_until: Option<u64>,
    /// Directions shaded per iteration.
    pub shade_directions: Option<usize>,
    /// Directions the shading's gradients are estimated on.
    pub gradient_directions: Option<usize>,
}

/// How stage 2 starts in its run folder.
pub enum Stage2Start<'a> {
    /// A new run: `config` on the stage-1 `surfels`; `meta` is written as `config.json`.
    New {
        /// The run's configuration.
        config: Box<Stage2Config>,
        /// The stage-1 model's Gaussians.
        surfels: &'a Surfels,
        /// The object's surroundings, kept as occluders and traced radiance
        /// (`Stage2::surroundings`; empty for none).
        surroundings: Surfels,
        /// What `config.json` records (the configuration and the run's provenance).
        meta: serde_json::Value,
    },
    /// The run's checkpoint, with these changes.
    Resume(Stage2Changes),
}

/// Opens stage 2 in `out`: a new run (its `config.json` written, an old `metrics.jsonl`
/// cleared, the micro-buffers traced) or its checkpoint resumed with the changes applied. Each
/// step and change is told to `note`, for the front end to print.
pub fn open_stage2(
    out: &Path,
    start: Stage2Start,
    dataset: &Dataset,
    kernels: crate::stage2::Kernels,
    note: &mut dyn FnMut(String),
) -> Result<Stage2, DriverError> {
    let ckpt = out.join("checkpoint.bin");
    match start {
        Stage2Start::New { config, surfels, surroundings, meta } => {
            start_run_folder(out, &meta)?;
            let around = if surroundings.is_empty() {
                String::new()
            } else {
                format!(" among {} Gaussians of surroundings", surroundings.len())
            };
            note(format!(
                "stage 2: tracing {} Gaussians x {} directions{around} on {}...",
                surfels.len(),
                config.directions,
                kernels.name()
            ));
            let s2 = Stage2::new_around(*config, surfels.clone(), surroundings, dataset, kernels)
                .map_err(DriverError::step)?;
            if !s2.surroundings.is_empty() {
                let hits = s2.mb.surroundings_hits();
                note(format!(
                    "stage 2: {:.1}% of the micro-buffers' rays end on the surroundings",
                    100.0 * hits as f64 / s2.mb.first_hit.len().max(1) as f64
                ));
            }
            note(format!("micro-buffers traced in {:.1} s", s2.trace_seconds));
            Ok(s2)
        }
        Stage2Start::Resume(c) => {
            note(format!("stage 2: resuming {}", ckpt.display()));
            let mut s2 = checkpoint::load_stage2(&ckpt)?;
            s2.kernels = kernels;
            if let Some(n) = c.iterations.filter(|&n| n != s2.config.iterations) {
                note(format!("stage 2: iterations {} -> {n}", s2.config.iterations));
                s2.config.iterations = n;
            }
            if let Some(d) = c.diffuse.filter(|&d| d != s2.config.diffuse) {
                note(format!("stage 2: diffuse lobe {:?} -> {d:?}", s2.config.diffuse));
                s2.config.diffuse = d;
            }
            if let Some(sets) = c.shade_sets.filter(|&s| s != s2.config.shade_sets) {
                note(format!("stage 2: shaded sets {:?} -> {sets:?}", s2.config.shade_sets));
                s2.config.shade_sets = sets;
            }
            if let Some(until) = c.shade_directions_until.filter(|&u| u != s2.config.shade_directions_until) {
                note(format!(
                    "stage 2: subsets of the directions until iteration {} -> {until}",
                    s2.config.shade_directions_until
                ));
                s2.config.shade_directions_until = until;
            }
            let shade = c.shade_directions.or(s2.config.shade_directions);
            let grads = c.gradient_directions.or(s2.config.gradient_directions);
            if (shade, grads) != (s2.config.shade_directions, s2.config.gradient_directions) {
                note(format!(
                    "stage 2: directions shaded / for the gradients per iteration {:?} / {:?} -> {shade:?} / {grads:?}",
                    s2.config.shade_directions, s2.config.gradient_directions
                ));
                s2.set_directions(shade, grads).map_err(DriverError::step)?;
            }
            Ok(s2)
        }
    }
}

impl Trainer for Stage1 {
    type Stats = StepStats;
    fn iteration(&self) -> u64 {
        self.iteration
    }
    fn is_done(&self) -> bool {
        Stage1::is_done(self)
    }
    fn step(&mut self, dataset: &Dataset, _read: bool) -> Result<StepStats, DriverError> {
        Ok(Stage1::step(self, dataset))
    }
    fn stats_iteration(stats: &StepStats) -> u64 {
        stats.iteration
    }
    fn always_logged(stats: &StepStats) -> bool {
        stats.densify.is_some()
    }
    fn evaluates_before(&self, next: u64) -> bool {
        self.config.resets_opacity_at(next)
    }
    fn save(&mut self, path: &Path) -> Result<(), DriverError> {
        Ok(checkpoint::save(self, path)?)
    }
}

impl Trainer for Stage2 {
    type Stats = Stage2Step;
    fn iteration(&self) -> u64 {
        self.iteration
    }
    fn is_done(&self) -> bool {
        Stage2::is_done(self)
    }
    fn step(&mut self, dataset: &Dataset, _read: bool) -> Result<Stage2Step, DriverError> {
        Stage2::step(self, dataset).map_err(DriverError::step)
    }
    fn stats_iteration(stats: &Stage2Step) -> u64 {
        stats.iteration
    }
    fn always_logged(stats: &Stage2Step) -> bool {
        stats.sun_search.is_some()
    }
    fn save(&mut self, path: &Path) -> Result<(), DriverError> {
        Ok(checkpoint::save_stage2(self, path)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A trainer that counts, to check the loop's schedule on its own.
    struct Counter {
        it: u64,
        len: u64,
        saves: Vec<u64>,
    }

    #[derive(Serialize)]
    struct Row {
        iteration: u64,
    }

    impl Trainer for Counter {
        type Stats = Row;
        fn iteration(&self) -> u64 {
            self.it
        }
        fn is_done(&self) -> bool {
            self.it >= self.len
        }
        fn step(&mut self, _: &Dataset, _: bool) -> Result<Row, DriverError> {
            self.it += 1;
            Ok(Row { iteration: self.it })
        }
        fn stats_iteration(r: &Row) -> u64 {
            r.iteration
        }
        fn always_logged(r: &Row) -> bool {
            r.iteration == 7
        }
        fn evaluates_before(&self, next: u64) -> bool {
            next == 20
        }
        fn save(&mut self, _: &Path) -> Result<(), DriverError> {
            self.saves.push(self.it);
            Ok(())
        }
    }

    struct Watch {
        evaluated_at: Vec<u64>,
        stop_at: Option<u64>,
        last: u64,
    }

    impl Observer<Counter> for Watch {
        fn stepped(&mut self, _: &Counter, r: &Row) {
            self.last = r.iteration;
        }
        fn evaluate(&mut self, t: &mut Counter, _: &Dataset) -> Result<serde_json::Value, DriverError> {
            self.evaluated_at.push(t.it);
            Ok(json!({"psnr": 1.0}))
        }
        fn interrupted(&self) -> bool {
            self.stop_at == Some(self.last)
        }
    }

    fn dataset() -> Dataset {
        Dataset {
            name: "none".into(),
            root: PathBuf::new(),
            train: Vec::new(),
            test: Vec::new(),
            points: None,
            train_light: None,
            relight_lights: Vec::new(),
            camera_model: String::new(),
            masks: svgir_core::MaskSource::None,
            world_rotation: glam::Mat3::IDENTITY,
        }
    }

    fn rows(dir: &Path) -> Vec<serde_json::Value> {
        let text = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap();
        text.lines().map(|l| serde_json::from_str(l).unwrap()).collect()
    }

    #[test]
    fn logs_evaluates_and_checkpoints_on_their_periods() {
        let dir = std::env::temp_dir().join(format!("svgir_driver_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let _ = std::fs::remove_file(dir.join("metrics.jsonl"));
        let mut t = Counter { it: 0, len: 30, saves: Vec::new() };
        let mut w = Watch { evaluated_at: Vec::new(), stop_at: None, last: 0 };
        let p = Periods { log_every: 10, eval_every: 10, checkpoint_every: 15 };
        assert_eq!(run(&mut t, &dataset(), &dir, p, &mut w).unwrap(), Ended::Finished);
        // Evaluations after iteration 10, before step 20 (at 19), none at the end (30).
        assert_eq!(w.evaluated_at, vec![10, 19]);
        // Checkpoints at 15 and once at the end (30 is on the period but written once).
        assert_eq!(t.saves, vec![15, 30]);
        let its: Vec<u64> = rows(&dir).iter().map(|r| r["iteration"].as_u64().unwrap()).collect();
        // Row 7 always, 10 and 20 and 30 on the period, the evaluations at 10 and 19.
        assert_eq!(its, vec![7, 10, 10, 19, 20, 30]);
        assert!(rows(&dir).iter().all(|r| r["elapsed_s"].is_number() && r["train_s"].is_number()));

        // Periods of 0 never log, evaluate or checkpoint; an interruption saves and stops.
        let _ = std::fs::remove_file(dir.join("metrics.jsonl"));
        let mut t = Counter { it: 0, len: 30, saves: Vec::new() };
        let mut w = Watch { evaluated_at: Vec::new(), stop_at: Some(12), last: 0 };
        let p = Periods { log_every: 0, eval_every: 0, checkpoint_every: 0 };
        assert_eq!(run(&mut t, &dataset(), &dir, p, &mut w).unwrap(), Ended::Interrupted { iteration: 12 });
        assert_eq!((t.saves.clone(), w.evaluated_at.len()), (vec![12], 0));
        assert_eq!(rows(&dir).len(), 1, "only the always-logged row 7");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
