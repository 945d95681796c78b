//! `svgir bench stages --run RUN`: what a stage-2 iteration costs against a stage-1 iteration
//! on the same Gaussians and images, timed in turn inside one process.
//!
//! Whole runs an hour apart do not resolve a ratio near 3 on a shared VM, whose speed can drift
//! by 10-17% from one half hour to the next, and by as much from one second to the next. Here
//! both trainers are resumed from RUN's checkpoints (stage 1's `RUN/checkpoint.bin`, stage 2's
//! `RUN/stage2/checkpoint.bin`) and take turns, one iteration each by default (a round: stage 1,
//! stage 2 on subsets of the directions, stage 2 on all of them), so that a slow spell of the
//! host falls on both. Stage 2's two modes (subsets up to `shade_directions_until`, all after)
//! are weighted as the run's schedule weights them. The rounds are reported in blocks, whose
//! spread shows how far the ratio is resolved. Nothing is written: the trainers live in memory.

use anyhow::{Context, Result};
use clap::Args;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;
use svgir_train::checkpoint;
use svgir_train::stage1::PhaseTimes;

/// `svgir bench stages` settings.
#[derive(Args, Clone, Debug)]
pub struct StagesBenchArgs {
    /// stages: a stage-1 run with a stage-2 checkpoint in RUN/stage2 (e.g. from `svgir inverse
    /// --run RUN --iterations 150`).
    #[arg(long = "run")]
    pub run: Option<PathBuf>,
    /// stages: timed rounds (each: a chunk of stage 1, of stage 2 on subsets, of stage 2 on all
    /// directions), after one untimed round; reported in 8 blocks.
    #[arg(long = "stage-rounds", default_value_t = 160)]
    pub rounds: usize,
    /// stages: iterations per chunk.
    #[arg(long = "stage-chunk", default_value_t = 1)]
    pub chunk: u64,
}

/// Milliseconds per iteration of one round.
#[derive(Clone, Copy)]
struct Round {
    stage1: f64,
    /// Stage 2's phases (render, loss, backward, Adam), on subsets / on all directions.
    subsets: f64,
    all: f64,
    /// Stage 2's whole step (sun searches and light updates included), on subsets / all.
    subsets_wall: f64,
    all_wall: f64,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

pub fn run(args: &StagesBenchArgs, machine: &str, threads: usize) -> Result<String> {
    let run = args.run.as_ref().context("bench stages needs --run RUN (a stage-1 run with RUN/stage2)")?;
    anyhow::ensure!(args.rounds >= 1 && args.chunk >= 1, "--stage-rounds and --stage-chunk must be at least 1");
    let (dataset, data) = svgir_eval::load_run_dataset(run, None)?;
    let mut s1 = checkpoint::load(&run.join("checkpoint.bin"), &dataset)?;
    let s2_path = run.join("stage2").join("checkpoint.bin");
    anyhow::ensure!(
        s2_path.exists(),
        "{}: no stage-2 checkpoint (run `svgir inverse --run {} --iterations 150` first)",
        s2_path.display(),
        run.display()
    );
    let mut s2 = checkpoint::load_stage2(&s2_path)?;
    let g1 = s1.surfels.len();
    let g2 = s2.surfels.len();
    // The schedule's weight of the subsets mode (the measured profile: two thirds).
    let until = s2.config.shade_directions_until;
    let iters = s2.config.iterations.max(1);
    let w_subsets = match (s2.config.shade_directions, until) {
        (None, _) => 0.0,
        (Some(_), 0) => 1.0,
        (Some(_), u) => (u.min(iters) as f64) / iters as f64,
    };
    // The timed iterations train the materials, as every iteration after `materials_from`
    // (most of a run) does, even from a checkpoint made before it.
    let materials_from = s2.config.materials_from;
    s2.config.materials_from = materials_from.min(s2.iteration);
    // Room for the timed iterations past each run's end, so that neither trainer stops.
    let steps = (args.rounds as u64 + 1) * args.chunk;
    s1.config.iterations = s1.config.iterations.max(s1.iteration + steps);
    s2.config.iterations = s2.config.iterations.max(s2.iteration + 2 * steps);
    let view = &dataset.train[0].camera;
    let mut out = String::new();
    writeln!(out, "svgir bench stages: {} (data {})", run.display(), data.display())?;
    writeln!(out, "threads: {threads} (machine: {machine})")?;
    writeln!(
        out,
        "stage 1 at iteration {} with {g1} Gaussians; stage 2 at iteration {} with {g2}; images {}x{}; chunks of {} \
         iterations, {} rounds after one untimed",
        s1.iteration,
        s2.iteration,
        view.width(),
        view.height(),
        args.chunk,
        args.rounds
    )?;
    writeln!(
        out,
        "stage 2: {:?} of {} directions shaded per iteration up to iteration {until} of {iters} (weight {:.3}), all after; \
         gradients on {:?}",
        s2.config.shade_directions, s2.config.directions, w_subsets, s2.config.gradient_directions
    )?;
    if materials_from > s2.iteration {
        writeln!(
            out,
            "stage 2: the materials train from iteration {materials_from} in the run; here from its checkpoint's {}",
            s2.iteration
        )?;
    }
    let stage1_chunk = |s1: &mut svgir_train::Stage1| -> f64 {
        let t = Instant::now();
        for _ in 0..args.chunk {
            s1.step(&dataset);
        }
        1e3 * t.elapsed().as_secs_f64() / args.chunk as f64
    };
    // (phases, whole step) in ms per iteration; `subsets` picks the mode.
    let stage2_chunk = |s2: &mut svgir_train::Stage2, subsets: bool| -> Result<(f64, f64)> {
        s2.config.shade_directions_until = if subsets { u64::MAX / 2 } else { 1 };
        let before = s2.times.clone();
        let t = Instant::now();
        for _ in 0..args.chunk {
            s2.step(&dataset).map_err(|e| anyhow::anyhow!("stage 2: {e}"))?;
        }
        let wall = 1e3 * t.elapsed().as_secs_f64() / args.chunk as f64;
        Ok((1e3 * s2.times.since(&before).step_seconds() / args.chunk as f64, wall))
    };
    let pb = crate::progress::bar(args.rounds as u64 + 1, "rounds");
    let mut rounds = Vec::new();
    // Each mode's phases summed over the timed rounds: stage 1, stage 2 on subsets, on all.
    let mut phases = [PhaseTimes::default(), PhaseTimes::default(), PhaseTimes::default()];
    for r in 0..=args.rounds {
        let before = [s1.times.clone(), s2.times.clone()];
        let stage1 = stage1_chunk(&mut s1);
        let s1_phases = s1.times.since(&before[0]);
        let (subsets, subsets_wall) = stage2_chunk(&mut s2, true)?;
        let mid = s2.times.clone();
        let sub_phases = mid.since(&before[1]);
        let (all, all_wall) = stage2_chunk(&mut s2, false)?;
        if r > 0 {
            rounds.push(Round { stage1, subsets, all, subsets_wall, all_wall });
            for (sum, p) in phases.iter_mut().zip([s1_phases, sub_phases, s2.times.since(&mid)]) {
                sum.add(&p);
            }
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    anyhow::ensure!(
        s1.surfels.len() == g1,
        "stage 1 changed its Gaussians ({g1} -> {}) while timed: its schedule densified or pruned; use a run past \
         densification",
        s1.surfels.len()
    );
    let weighted = |a: f64, b: f64| w_subsets * a + (1.0 - w_subsets) * b;
    writeln!(
        out,
        "{:>5} {:>7} {:>10} {:>14} {:>10} {:>14} {:>8} {:>14}",
        "block", "rounds", "stage 1 ms", "stage 2 subset", "stage 2 all", "stage 2 (wtd)", "ratio", "ratio (steps)"
    )?;
    // Means of a set of rounds: (stage 1, subsets, all, weighted, ratio, ratio of whole steps).
    let summary = |rs: &[Round]| {
        let m = |f: fn(&Round) -> f64| mean(&rs.iter().map(f).collect::<Vec<_>>());
        let (s1, sub, all) = (m(|r| r.stage1), m(|r| r.subsets), m(|r| r.all));
        let w = weighted(sub, all);
        (s1, sub, all, w, w / s1, weighted(m(|r| r.subsets_wall), m(|r| r.all_wall)) / s1)
    };
    let blocks = rounds.len().min(8);
    let mut ratios = Vec::new();
    let row = |out: &mut String, name: &str, rs: &[Round]| -> std::fmt::Result {
        let (s1, sub, all, w, ratio, ratio_wall) = summary(rs);
        writeln!(
            out,
            "{name:>5} {:>7} {s1:>10.2} {sub:>14.2} {all:>10.2} {w:>14.2} {ratio:>8.3} {ratio_wall:>14.3}",
            rs.len()
        )
    };
    for b in 0..blocks {
        let rs = &rounds[b * rounds.len() / blocks..(b + 1) * rounds.len() / blocks];
        ratios.push(summary(rs).4);
        row(&mut out, &(b + 1).to_string(), rs)?;
    }
    row(&mut out, "all", &rounds)?;
    let (lo, hi) = ratios.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    writeln!(
        out,
        "stage 2 / stage 1: {:.3} over all rounds; median of the blocks {:.3} (range {lo:.3}-{hi:.3})",
        summary(&rounds).4,
        median(ratios)
    )?;
    // The phases in ms per iteration (stage 1's densification is outside its steps here).
    let per_iter = 1e3 / (rounds.len() as f64 * args.chunk as f64);
    writeln!(
        out,
        "ms per iteration by phase: {:>10} {:>8} {:>8} {:>8} {:>8}",
        "mode", "render", "loss", "backward", "Adam"
    )?;
    for (name, p) in ["stage 1", "2 subset", "2 all"].iter().zip(&phases) {
        writeln!(
            out,
            "{:>37} {:>8.2} {:>8.2} {:>8.2} {:>8.2}",
            name,
            per_iter * p.forward,
            per_iter * p.loss,
            per_iter * p.backward,
            per_iter * p.optimizer
        )?;
    }
    writeln!(
        out,
        "ratio: stage 2's phases (render, loss, backward, Adam) per iteration, the two modes weighted as the schedule \
         runs them, over stage 1's whole step; ratio (steps): stage 2's whole step, with the sun searches and light \
         updates that fell in the rounds"
    )?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_even_and_odd_counts() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(vec![]).is_nan());
    }
}
