//! Sun direction search (our addition, off by default; `Stage2Config::sun_search_views`).
//!
//! The learned sun is a directional light sitting on a texel of the 32 x 64 map (`sun_at`), so its
//! direction is quantised to ~6 degrees, and the lobe it was gathered from forms where the K
//! samples put it, not necessarily where the sun is: on bowl_fruit_128, whose training sun stands
//! 4 degrees from the zenith, the gathered sun sat 31 degrees away. Texels near the pole own tiny
//! solid angles, and a sun there needs a radiance the map reaches last. The sun's direction is
//! not differentiable through its traced shadows, so we search it: a compass (pattern) search on
//! the sphere around the current direction, steps of `FIRST_STEP_DEG` halving to
//! `LAST_STEP_DEG`, each candidate scored by the mean L1 of the PBR renders of a fixed, evenly
//! spaced set of training views (shadows traced again per candidate), each render scaled per
//! channel by its least-squares factor first. Unscaled, the score mixes the sun's direction with
//! the overall level: at the first search the materials are still uniform, and on bowl_fruit_128
//! even the *true* light with uniform materials scored best with the sun tilted 30 degrees, while
//! scaled it scored best within 10 degrees of the true sun (`examples/sun_probe`). The light keeps its
//! texel's radiance and solid angle; only its direction moves (`BrightLights::with_direction`).
//! Optionally (`sun_search_cone_deg`) the first search scans a cone around the gathered sun on
//! rings `CONE_SPACING_DEG` apart before the compass starts from the best of them.
//! Deterministic: no random numbers, so a resumed run repeats it exactly.

use super::{photo_coverage, Stage2, Stage2Config};
use crate::stage1::target_rgb;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use svgir_core::Dataset;
use svgir_pbr::PbrError;
use svgir_shading::tangent_frame;

/// First and last step of the compass search, degrees.
pub const FIRST_STEP_DEG: f32 = 8.0;
pub const LAST_STEP_DEG: f32 = 0.5;
/// Compass candidates per search at most (each rendering `sun_search_views` views).
pub const MAX_EVALUATIONS: usize = 40;
/// Ring and azimuth spacing of the first search's cone scan (`sun_search_cone_deg`), degrees.
pub const CONE_SPACING_DEG: f32 = 15.0;

/// What one search did (logged in `metrics.jsonl`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SunSearch {
    /// Sun direction before the search (unit, world).
    pub from: [f32; 3],
    /// Sun direction after the search (unit, world).
    pub to: [f32; 3],
    /// Angle between `from` and `to`, degrees.
    pub moved_deg: f32,
    /// Photo loss on the search views with the sun at `from`.
    pub loss_before: f32,
    /// Photo loss on the search views with the sun at `to`.
    pub loss_after: f32,
    /// Candidate directions scored, the start included.
    pub evaluations: usize,
    /// Iteration of the next search (absent without one, and in older logs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next_at: Option<u64>,
}

/// When the next sun search is due (`Stage2Config::sun_search_settled_deg`); saved with the
/// checkpoint, so a resumed run keeps its schedule.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SunSchedule {
    /// Iteration of the next search after the first (0: no search done yet).
    pub next: u64,
    /// Iterations from the last search to `next`.
    pub wait: u64,
}

impl SunSchedule {
    /// Is a search due before step `iteration` + 1? At `sun_at`, then: with
    /// `sun_search_settled_deg` at `next`, else every `sun_search_every` iterations.
    pub fn due(&self, cfg: &Stage2Config, iteration: u64) -> bool {
        if cfg.sun_search_settled_deg <= 0.0 {
            return cfg.sun_search_due(iteration);
        }
        cfg.sun_at > 0
            && (iteration == cfg.sun_at
                || (cfg.sun_search_every > 0 && self.next > cfg.sun_at && iteration == self.next))
    }

    /// After a search at `iteration` that moved the sun by `moved_deg`: a settled sun (a move
    /// under `sun_search_settled_deg`) doubles the wait, a moving one restores
    /// `sun_search_every`. Returns the next search's iteration (`None`: none).
    pub fn searched(&mut self, cfg: &Stage2Config, iteration: u64, moved_deg: f32) -> Option<u64> {
        let every = cfg.sun_search_every;
        if every == 0 {
            return None;
        }
        if cfg.sun_search_settled_deg <= 0.0 {
            return Some(iteration + every);
        }
        self.wait = if moved_deg < cfg.sun_search_settled_deg { self.wait.max(every) * 2 } else { every };
        self.next = iteration + self.wait;
        Some(self.next)
    }
}

impl Stage2 {
    /// The light with the most power (luminance x solid angle): the sun.
    pub fn sun_light(&self) -> Option<usize> {
        let env = self.env.radiance();
        (0..self.lights.len())
            .map(|b| {
                let t = env.data[self.lights.texels[b] as usize];
                (b, (0.2126 * t[0] + 0.7152 * t[1] + 0.0722 * t[2]) * self.lights.solid_angle[b])
            })
            .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
            .map(|(b, _)| b)
    }

    /// Move light `b` to the unit direction `dir`, tracing its shadows again.
    pub fn move_light(&mut self, b: usize, dir: Vec3) -> Result<(), PbrError> {
        let occluders = self.occluders();
        let tracer = self.kernels.tracer.clone();
        let bvh =
            &svgir_trace::Via(tracer.as_ref(), self.bvh.get_or_insert_with(|| svgir_trace::Bvh::build(&occluders)));
        let p = self.config.trace_params();
        self.lights = self.lights.with_direction(bvh, &occluders, &self.mb.normals, b, dir, &p)?;
        if let Some(back) = &mut self.back {
            back.lights = back.lights.with_direction(bvh, &occluders, &back.mb.normals, b, dir, &p)?;
        }
        Ok(())
    }

    /// Mean absolute error of the PBR renders of training views `views` against their photos;
    /// `scale_invariant`: each view's render first scaled per channel by its least-squares
    /// factor, so that only the pattern of light and shadow counts, not the overall level.
    pub fn photo_loss(&self, dataset: &Dataset, views: &[usize], scale_invariant: bool) -> Result<f32, PbrError> {
        let bg = self.config.background.fixed_color().unwrap_or([0.0; 3]);
        let env = self.env.radiance();
        let (mut sum, mut count) = (0.0f64, 0usize);
        for &v in views {
            let view = &dataset.train[v];
            let mut r = self.render_pbr(&view.camera, bg, &env, [1.0; 3])?;
            if let Some(cover) = photo_coverage(self.config.pbr_coverage, &view.image) {
                r.recomposite(&cover, bg);
            }
            let gt = target_rgb(&view.image, bg);
            let mut scale = [1.0f64; 3];
            if scale_invariant {
                let (mut rp, mut rr) = ([0.0f64; 3], [0.0f64; 3]);
                for (i, (a, b)) in r.image.iter().zip(&gt).enumerate() {
                    let a = a.clamp(0.0, 1.0) as f64;
                    rp[i % 3] += a * *b as f64;
                    rr[i % 3] += a * a;
                }
                scale = [0, 1, 2].map(|c| if rr[c] > 0.0 { rp[c] / rr[c] } else { 1.0 });
            }
            sum += r
                .image
                .iter()
                .zip(&gt)
                .enumerate()
                .map(|(i, (a, b))| (a.clamp(0.0, 1.0) as f64 * scale[i % 3] - *b as f64).abs())
                .sum::<f64>();
            count += gt.len();
        }
        Ok((sum / count.max(1) as f64) as f32)
    }

    /// Search the sun's direction (see the module note); `None` without lights or views.
    pub fn search_sun(&mut self, dataset: &Dataset) -> Result<Option<SunSearch>, PbrError> {
        let n_views = self.config.sun_search_views.min(dataset.train.len());
        let Some(b) = self.sun_light().filter(|_| n_views > 0) else {
            return Ok(None);
        };
        let views: Vec<usize> = (0..n_views).map(|i| i * dataset.train.len() / n_views).collect();
        let from = self.lights.dirs[b];
        let loss_before = self.photo_loss(dataset, &views, true)?;
        let (mut best, mut best_loss, mut evaluations) = (from, loss_before, 1);
        // First search: a coarse scan of the cone first, so that the compass starts near the
        // best basin (its steps move at most FIRST_STEP_DEG each).
        let cone = self.config.sun_search_cone_deg;
        if cone > 0.0 && self.iteration == self.config.sun_at {
            let (t1, t2) = tangent_frame(from);
            let mut ring = CONE_SPACING_DEG;
            while ring <= cone + 1e-3 {
                let th = ring.to_radians();
                let count =
                    ((std::f32::consts::TAU * th.sin() / CONE_SPACING_DEG.to_radians()).round() as usize).max(6);
                for a in 0..count {
                    let ph = std::f32::consts::TAU * a as f32 / count as f32;
                    let candidate = (th.cos() * from + th.sin() * (ph.cos() * t1 + ph.sin() * t2)).normalize();
                    self.move_light(b, candidate)?;
                    let loss = self.photo_loss(dataset, &views, true)?;
                    evaluations += 1;
                    if loss < best_loss {
                        (best, best_loss) = (candidate, loss);
                    }
                }
                ring += CONE_SPACING_DEG;
            }
        }
        let compass_start = evaluations;
        let mut step = FIRST_STEP_DEG.to_radians();
        while step >= LAST_STEP_DEG.to_radians() * 0.999 && evaluations - compass_start < MAX_EVALUATIONS {
            let (t1, t2) = tangent_frame(best);
            let mut improved = false;
            for offset in [t1, -t1, t2, -t2] {
                if evaluations - compass_start >= MAX_EVALUATIONS {
                    break;
                }
                let candidate = (best + step.tan() * offset).normalize();
                self.move_light(b, candidate)?;
                let loss = self.photo_loss(dataset, &views, true)?;
                evaluations += 1;
                if loss < best_loss {
                    (best, best_loss, improved) = (candidate, loss, true);
                    break;
                }
            }
            if !improved {
                step *= 0.5;
            }
        }
        self.move_light(b, best)?;
        // Report the direction the light now has: setting it normalises again, which can move
        // the last bit of an already unit vector.
        let best = self.lights.dirs[b];
        Ok(Some(SunSearch {
            from: from.to_array(),
            to: best.to_array(),
            moved_deg: from.dot(best).clamp(-1.0, 1.0).acos().to_degrees(),
            loss_before,
            loss_after: best_loss,
            evaluations,
            next_at: None,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(settled: f32) -> Stage2Config {
        Stage2Config { sun_at: 400, sun_search_every: 300, sun_search_settled_deg: settled, ..Stage2Config::default() }
    }

    /// The searches a run of `n` iterations does, each moving the sun by `moved(iteration)`.
    fn searches(c: &Stage2Config, n: u64, moved: impl Fn(u64) -> f32) -> Vec<u64> {
        let mut s = SunSchedule::default();
        let mut done = Vec::new();
        for it in 0..n {
            if s.due(c, it) {
                done.push(it);
                let next = s.searched(c, it, moved(it));
                assert_eq!(next.is_some(), c.sun_search_every > 0);
                assert!(next.is_none_or(|x| x > it), "the next search comes later");
            }
        }
        done
    }

    #[test]
    fn settled_searches_double_their_wait_and_a_move_restores_it() {
        let c = cfg(1.0);
        // Only the first search moves the sun: the waits double from 300.
        assert_eq!(
            searches(&c, 20_000, |it| if it == 400 { 10.0 } else { 0.0 }),
            [400, 700, 1300, 2500, 4900, 9700, 19300]
        );
        // A move of 1 degree or more at 1300 restores the 300-iteration wait.
        let moved = |it| if it == 400 || it == 1300 { 5.0 } else { 0.5 };
        assert_eq!(searches(&c, 4000, moved), [400, 700, 1300, 1600, 2200, 3400]);
        // A first search that settles at once waits twice the interval.
        assert_eq!(searches(&c, 2000, |_| 0.0), [400, 1000]);
    }

    #[test]
    fn without_a_settling_angle_the_interval_is_fixed() {
        let c = cfg(0.0);
        let fixed: Vec<u64> = (0..5000).filter(|it| c.sun_search_due(*it)).collect();
        assert_eq!(fixed.len(), 16);
        assert_eq!(searches(&c, 5000, |_| 0.0), fixed);
        let once = Stage2Config { sun_search_every: 0, ..cfg(1.0) };
        assert_eq!(searches(&once, 5000, |_| 0.0), [400]);
    }
}
