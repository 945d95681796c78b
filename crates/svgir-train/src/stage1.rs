//! Stage 1 (SPEC 2): fit Gaussian surfels with SH colour to the training photos.
//!
//! One iteration: pick a random training view, render it, form the SPEC 2 loss and its per-pixel
//! gradients, run the rasterizer's backward, take one Adam step per attribute group, and every
//! so often densify, prune and reset opacity. All randomness comes from one seeded [`Rng`]
//! whose state is part of the checkpoint, so a resumed run continues bit-identically.

use crate::adam::{exp_lr, AdamGroup};
use crate::config::{LossWeights, Stage1Config, ViewOrder};
use crate::densify::{densify_and_prune, reset_opacity, DensifyReport, DensifyStats, Groups};
use crate::exposure::{self, ExposureCorrection};
use crate::losses::mask;
use crate::losses::objective::{depth_normal_weight, stage1_objective, ObjectiveInput, ObjectiveTarget};
use serde::{Deserialize, Serialize};
use std::time::Instant;
use svgir_core::dataset::downscaled_size;
use svgir_core::{Camera, Dataset, Image, Rng, Surfels, View};
use svgir_raster::{backward, render, Background, ColorSource, OutputGrads, RasterConfig, RenderInput, RenderOutput};

/// Wall time per phase, summed over iterations (seconds).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct PhaseTimes {
    /// Rendering.
    pub forward: f64,
    /// Loss and its output gradients.
    pub loss: f64,
    /// Rasteriser backward pass.
    pub backward: f64,
    /// Adam updates.
    pub optimizer: f64,
    /// Densification and pruning.
    pub densify: f64,
}

impl PhaseTimes {
    /// The time spent since `before` (an earlier reading of the same run), per phase.
    pub fn since(&self, before: &PhaseTimes) -> PhaseTimes {
        PhaseTimes {
            forward: self.forward - before.forward,
            loss: self.loss - before.loss,
            backward: self.backward - before.backward,
            optimizer: self.optimizer - before.optimizer,
            densify: self.densify - before.densify,
        }
    }

    /// Adds `other` phase by phase.
    pub fn add(&mut self, other: &PhaseTimes) {
        self.forward += other.forward;
        self.loss += other.loss;
        self.backward += other.backward;
        self.optimizer += other.optimizer;
        self.densify += other.densify;
    }

    /// The iteration's own phases (render, loss, backward, Adam), without densification: what
    /// stage 2's "ms per iteration" counts.
    pub fn step_seconds(&self) -> f64 {
        self.forward + self.loss + self.backward + self.optimizer
    }
}

/// What one iteration reports.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StepStats {
    /// Iteration number (1-based after the step).
    pub iteration: u64,
    /// Index of the training view used.
    pub view: usize,
    /// Total weighted loss.
    pub loss: f32,
    /// Mean absolute colour error.
    pub l1: f32,
    /// SSIM of render and photo.
    pub ssim: f32,
    /// PSNR of render and photo in dB.
    pub psnr: f32,
    /// Gaussians after the step.
    pub num_gaussians: usize,
    /// What densification did this step, if it ran.
    pub densify: Option<DensifyReport>,
}

/// A training view prepared once: target RGB over the fixed background, alpha, dilated mask.
struct Target {
    alpha: Vec<f32>,
    dilated: Vec<bool>,
}

impl Target {
    fn of(image: &Image) -> Self {
        let alpha = alpha_of(image);
        let dilated = mask::dilated_mask(&alpha, image.width as usize, image.height as usize, 4);
        Target { alpha, dilated }
    }
}

/// The training views at half size and their targets, for the iterations up to
/// [`Stage1Config::half_res_until`]: photo, alpha and intrinsics scaled as `--downscale 2` loads
/// them ([`View::resized`] to the rounded half size), so such an iteration is the one a run on a
/// half-size dataset would take.
struct HalfRes {
    views: Vec<View>,
    targets: Vec<Target>,
}

impl HalfRes {
    fn of(dataset: &Dataset) -> Self {
        let views = Self::views_of(dataset);
        let targets = views.iter().map(|v| Target::of(&v.image)).collect();
        Self { views, targets }
    }

    fn views_of(dataset: &Dataset) -> Vec<View> {
        dataset
            .train
            .iter()
            .map(|v| {
                let photo = View {
                    name: v.name.clone(),
                    camera: v.camera,
                    image: v.image.clone(),
                    albedo: None,
                    normal: None,
                    roughness: None,
                    relit: Default::default(),
                };
                let (w, h) = downscaled_size(v.image.width, v.image.height, 2.0);
                photo.resized(w, h)
            })
            .collect()
    }
}

/// The stage-1 trainer (SPEC 2): surfels, their Adam state and everything needed to resume.
pub struct Stage1 {
    /// The run's configuration.
    pub config: Stage1Config,
    /// The Gaussians being trained.
    pub surfels: Surfels,
    /// Adam groups: position, rotation, log scale, opacity, SH.
    pub groups: Groups,
    /// Per-Gaussian statistics for the next densification.
    pub stats: DensifyStats,
    /// Iterations done.
    pub iteration: u64,
    /// Source of every random choice (view order, backgrounds, splits).
    pub rng: Rng,
    /// Scene extent from the training cameras, world units; scales position rates and densification.
    pub extent: f32,
    /// Wall time per phase so far.
    pub times: PhaseTimes,
    /// Rasteriser settings.
    pub raster: RasterConfig,
    /// Per-photo colour corrections (`config.exposure`).
    pub exposure: Option<ExposureCorrection>,
    targets: Vec<Target>,
    /// The half-size views, made at the first iteration that needs them and dropped after
    /// `config.half_res_until`.
    half: Option<HalfRes>,
}

/// Adam groups for the five surfel attributes with the SPEC 2 learning rates.
pub fn make_groups(cfg: &Stage1Config, n: usize, extent: f32) -> Groups {
    let lr = &cfg.lr;
    let mut sh_scale = vec![1.0 / lr.sh_rest_divisor; 48];
    sh_scale[..3].fill(1.0);
    [
        AdamGroup::new("position", lr.position_init * extent, 3, n),
        AdamGroup::new("rotation", lr.rotation, 4, n),
        AdamGroup::new("log_scale", lr.scale, 2, n),
        AdamGroup::new("opacity", lr.opacity, 1, n),
        AdamGroup::new("sh", lr.sh_dc, 48, n).with_lr_scale(sh_scale),
    ]
}

/// The training view of iteration `it` (1-based) under [`ViewOrder::Epochs`]: epoch
/// `(it - 1) / n` visits the `n` views in an order shuffled from the seed and the epoch, so the
/// order needs no state of its own (a resumed run draws the same views).
pub fn view_of_iteration(seed: u64, it: u64, n: usize) -> usize {
    // Stream tag of the view order (ASCII "VIEWS"), so it shares no draws with other choices.
    const STREAM: u64 = 0x56_4945_5753;
    let (epoch, pos) = ((it - 1) / n as u64, ((it - 1) % n as u64) as usize);
    let mut order: Vec<usize> = (0..n).collect();
    Rng::new(seed).fork(STREAM).fork(epoch).shuffle(&mut order);
    order[pos]
}

/// What one iteration uses, drawn by [`Stage1::plan`].
#[derive(Clone, Debug)]
pub struct IterationPlan {
    /// The iteration (1-based).
    pub iteration: u64,
    /// Index of its training view.
    pub view: usize,
    /// Whether it trains on the half-size photos ([`half_size_views`]).
    pub half: bool,
    /// The background colour the render and the photo are composited over.
    pub bg: [f32; 3],
    /// Training progress in [0, 1] (the depth-normal ramp).
    pub t_frac: f32,
    /// Its loss weights.
    pub weights: LossWeights,
    /// Its rasterizer settings.
    pub raster: RasterConfig,
}

/// The factor from a pixel-space position gradient to 3DGS's NDC one on a `w` x `h` view
/// (SPEC 2's densification threshold is on the latter).
pub fn ndc_scale(w: usize, h: usize) -> f32 {
    0.5 * ((w * h) as f32).sqrt()
}

/// The training views at half size, as the iterations up to [`Stage1Config::half_res_until`]
/// see them (the same views and intrinsics a `--downscale 2` load gives).
pub fn half_size_views(dataset: &Dataset) -> Vec<View> {
    HalfRes::views_of(dataset)
}

/// A photo's alpha and its dilated mask, as the loss reads them (SPEC 2's mask loss).
pub fn photo_target(image: &Image) -> (Vec<f32>, Vec<bool>) {
    let t = Target::of(image);
    (t.alpha, t.dilated)
}

/// RGB of a view's photo composited over `bg` (sRGB values, as compared in the loss).
pub fn target_rgb(image: &Image, bg: [f32; 3]) -> Vec<f32> {
    if image.channels == 4 {
        image.composite_over(bg).data
    } else {
        image.select_channels(0..3).data
    }
}

/// The photo's alpha per pixel (1 for a photo without alpha).
pub fn alpha_of(image: &Image) -> Vec<f32> {
    if image.channels == 4 {
        image.data.chunks_exact(4).map(|p| p[3]).collect()
    } else {
        vec![1.0; image.pixel_count()]
    }
}

/// PSNR in dB of a mean squared error on [0, 1] values (MSE floored at 1e-12).
pub fn psnr_of_mse(mse: f64) -> f32 {
    (-10.0 * mse.max(1e-12).log10()) as f32
}

impl Stage1 {
    /// A fresh run from initial surfels.
    pub fn new(config: Stage1Config, mut surfels: Surfels, dataset: &Dataset) -> Self {
        let extent = dataset.camera_extent();
        surfels.sh_degree = 0;
        let n = surfels.len();
        let groups = make_groups(&config, n, extent);
        let rng = Rng::new(config.seed).fork(1);
        let targets = dataset.train.iter().map(|v| Target::of(&v.image)).collect();
        // The distortion output costs a division per composited pixel; only pay when it is in the loss.
        let raster = RasterConfig {
            distortion: config.loss.distortion > 0.0,
            near: config.near_fraction.map_or(RasterConfig::default().near, |f| f * extent),
            ..RasterConfig::default()
        };
        let exposure = config.exposure.then(|| ExposureCorrection::new(dataset.train.len()));
        Self {
            config,
            surfels,
            groups,
            stats: DensifyStats::new(n),
            iteration: 0,
            rng,
            extent,
            times: PhaseTimes::default(),
            raster,
            exposure,
            targets,
            half: None,
        }
    }

    /// True once `config.iterations` iterations have run.
    pub fn is_done(&self) -> bool {
        self.iteration >= self.config.iterations
    }

    /// Draws what iteration `self.iteration + 1` uses and counts it: its view, its background,
    /// its loss weights and rasterizer settings. Every device runs the iteration it plans, so
    /// a run draws the same views and backgrounds on the CPU and on a GPU.
    pub fn plan(&mut self, dataset: &Dataset) -> IterationPlan {
        let cfg = &self.config;
        self.iteration += 1;
        let it = self.iteration;
        let view = match cfg.view_order {
            ViewOrder::Uniform => self.rng.below(dataset.train.len()),
            ViewOrder::Epochs => view_of_iteration(cfg.seed, it, dataset.train.len()),
        };
        let bg = match cfg.background.fixed_color() {
            Some(c) => c,
            None => [self.rng.uniform(), self.rng.uniform(), self.rng.uniform()],
        };
        let t_frac = (it as f32 / cfg.iterations as f32).min(1.0);
        let weights = cfg.weights_at(it);
        // Depth and normal feed only the depth-normal loss: without it (3DGS's loss) the
        // rasterizer skips them.
        let raster = RasterConfig { geometry: depth_normal_weight(&weights, t_frac) != 0.0, ..self.raster };
        IterationPlan { iteration: it, view, half: it <= cfg.half_res_until, bg, t_frac, weights, raster }
    }

    /// The position learning rate of iteration `it` set on its Adam group (SPEC 2's decay).
    pub fn set_position_lr(&mut self, it: u64) {
        let (cfg, e) = (&self.config, self.extent);
        self.groups[0].lr = exp_lr(it - 1, cfg.lr.position_init * e, cfg.lr.position_final * e, cfg.iterations);
    }

    /// Whether iteration `it` ends with work on the surfels themselves (densification, an
    /// opacity reset, or the binary-opacity term's final pruning), which [`Stage1::finish`] does on the host.
    pub fn changes_surfels_at(&self, it: u64) -> bool {
        let d = &self.config.densify;
        let densifies = it <= d.until_iter
            && ((it >= d.from_iter && it.is_multiple_of(d.interval)) || self.config.resets_opacity_at(it));
        // The binary-opacity term's run ends by dropping its invisible surfels.
        densifies || (it == self.config.iterations && self.config.loss.opacity_binary > 0.0)
    }

    /// One training iteration on a random training view.
    pub fn step(&mut self, dataset: &Dataset) -> StepStats {
        let plan = self.plan(dataset);
        let cfg = self.config.clone();
        let (it, view_idx, bg) = (plan.iteration, plan.view, plan.bg);
        // Coarse to fine: the half-size photo until `half_res_until`, then the photo itself. The
        // half-size views are made when first needed (a run resumed past them never makes them).
        if plan.half && self.half.is_none() {
            self.half = Some(HalfRes::of(dataset));
        }
        let half = self.half.as_ref().filter(|_| plan.half);
        let (view, target) = match half {
            Some(h) => (&h.views[view_idx], &h.targets[view_idx]),
            None => (&dataset.train[view_idx], &self.targets[view_idx]),
        };
        let gt = target_rgb(&view.image, bg);

        let t0 = Instant::now();
        let input = RenderInput {
            surfels: &self.surfels,
            camera: &view.camera,
            colors: ColorSource::Sh,
            extra: None,
            background: Background::Color(bg),
        };
        let (weights, raster) = (&plan.weights, &plan.raster);
        let (out, state) = render(&input, raster);
        let t1 = Instant::now();

        let (w, h) = (view.camera.width() as usize, view.camera.height() as usize);
        // The loss sees the photo's colour correction applied to the render.
        let corrected =
            self.exposure.as_ref().map(|e| exposure::apply(&e.params[view_idx], &out.color, &out.alpha, bg));
        let color = corrected.as_deref().unwrap_or(&out.color);
        let mut obj = stage1_objective(
            weights,
            plan.t_frac,
            cfg.use_mask,
            &ObjectiveInput {
                color,
                alpha: &out.alpha,
                depth: &out.depth,
                normal: &out.normal,
                distortion: &out.distortion,
            },
            &ObjectiveTarget { rgb: &gt, alpha: &target.alpha, dilated: &target.dilated },
            &view.camera,
        );
        let mse = crate::losses::mse(color, &gt, false);
        if let Some(e) = &mut self.exposure {
            let g = exposure::apply_backward(&e.params[view_idx], &out.color, &out.alpha, bg, &obj.v_color);
            obj.v_color = g.v_color;
            obj.v_alpha.iter_mut().zip(&g.v_alpha).for_each(|(v, a)| *v += a);
            e.step(view_idx, &g.v_params);
        }
        let t2 = Instant::now();

        let grads = backward(
            &input,
            raster,
            &state,
            &out,
            &OutputGrads {
                color: Some(&obj.v_color),
                alpha: Some(&obj.v_alpha),
                depth: Some(&obj.v_depth),
                normal: Some(&obj.v_normal),
                distortion: obj.v_distortion.as_deref(),
                extra: None,
            },
        );
        let t3 = Instant::now();

        if it <= cfg.densify.until_iter {
            // 3DGS's threshold (SPEC 2: 2.5e-4) is on the gradient w.r.t. NDC coordinates, i.e. the
            // per-pixel gradient times W/2 (H/2 vertically; equal for square images).
            let to_ndc = ndc_scale(w, h);
            let g: Vec<f32> = grads.v_mean2d_norm.iter().map(|g| g * to_ndc).collect();
            self.stats.add(&g, &out.max_radius, &out.accum_weight);
        }
        let mut grads = grads;
        if weights.opacity_binary > 0.0 && it > cfg.densify.until_iter {
            crate::losses::opacity::binary_opacity(
                &self.surfels.opacity_logits,
                weights.opacity_binary,
                &mut grads.v_opacity_logits,
            );
        }
        self.set_position_lr(it);
        let s = &mut self.surfels;
        self.groups[0].step(bytemuck::cast_slice_mut(&mut s.positions), bytemuck::cast_slice(&grads.v_positions));
        self.groups[1].step(bytemuck::cast_slice_mut(&mut s.rotations), bytemuck::cast_slice(&grads.v_rotations));
        self.groups[2].step(bytemuck::cast_slice_mut(&mut s.log_scales), bytemuck::cast_slice(&grads.v_log_scales));
        self.groups[3].step(&mut s.opacity_logits, &grads.v_opacity_logits);
        self.groups[4].step(bytemuck::cast_slice_mut(&mut s.sh), bytemuck::cast_slice(&grads.v_sh));
        let t4 = Instant::now();

        let densify = self.finish(it);
        let t5 = Instant::now();
        let secs = |a: Instant, b: Instant| (b - a).as_secs_f64();
        self.times.forward += secs(t0, t1);
        self.times.loss += secs(t1, t2);
        self.times.backward += secs(t2, t3);
        self.times.optimizer += secs(t3, t4);
        self.times.densify += secs(t4, t5);

        StepStats {
            iteration: it,
            view: view_idx,
            loss: obj.loss,
            l1: obj.l1,
            ssim: obj.ssim,
            psnr: psnr_of_mse(mse),
            num_gaussians: self.surfels.len(),
            densify,
        }
    }

    /// The end of iteration `it`, after its Adam step: densification, pruning and the opacity
    /// reset at their cadence (on the surfels, moments and statistics held here), the SH
    /// degree's upgrade, and dropping the half-size views once past them.
    pub fn finish(&mut self, it: u64) -> Option<DensifyReport> {
        let cfg = &self.config;
        let mut densify = None;
        let d = &cfg.densify;
        if it <= d.until_iter {
            if it >= d.from_iter && it.is_multiple_of(d.interval) {
                let prune_big = it > d.opacity_reset_interval;
                densify = Some(densify_and_prune(
                    &mut self.surfels,
                    &mut self.groups,
                    &self.stats,
                    d,
                    self.extent,
                    prune_big,
                    &mut self.rng,
                ));
                self.stats = DensifyStats::new(self.surfels.len());
                // Densification appends its children at the end, so the Gaussians a view sees
                // drift apart in every per-Gaussian array; Morton order puts them back in runs
                // (a seventh off lego's tile kernels, docs/performance.md). The statistics were
                // just zeroed, so only the Adam moments follow the parameters.
                let order = self.surfels.sort_morton();
                for g in self.groups.iter_mut() {
                    g.permute_rows(&order);
                }
            }
            if cfg.resets_opacity_at(it) {
                reset_opacity(&mut self.surfels, &mut self.groups[3]);
            }
        }
        if it == cfg.iterations && cfg.loss.opacity_binary > 0.0 {
            // The binary-opacity term drives most surfels to opacity 0 once densification has
            // ended; those under the rasterizer's and tracer's 1/255 cut render and trace as
            // nothing, so the run ends without them (stage 2 and the exports are the faster).
            let keep: Vec<bool> =
                (0..self.surfels.len()).map(|i| self.surfels.opacity(i) >= svgir_trace::hit::ALPHA_MIN).collect();
            if keep.iter().any(|k| !k) && keep.iter().any(|k| *k) {
                self.surfels.retain(&keep);
                for g in self.groups.iter_mut() {
                    g.retain_rows(&keep);
                }
                self.stats = DensifyStats::new(self.surfels.len());
            }
        }
        if it.is_multiple_of(cfg.sh_upgrade_interval) && self.surfels.sh_degree < cfg.max_sh_degree {
            self.surfels.sh_degree += 1;
        }
        if it >= cfg.half_res_until {
            self.half = None;
        }
        densify
    }

    /// Render a camera with the current model over a fixed background.
    pub fn render_view(&self, camera: &Camera, bg: [f32; 3]) -> RenderOutput {
        render_surfels(&self.surfels, camera, bg, &self.raster)
    }
}

/// Render SH-coloured surfels from `camera` over `bg`.
pub fn render_surfels(surfels: &Surfels, camera: &Camera, bg: [f32; 3], raster: &RasterConfig) -> RenderOutput {
    let input =
        RenderInput { surfels, camera, colors: ColorSource::Sh, extra: None, background: Background::Color(bg) };
    render(&input, raster).0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_epoch_visits_every_view_once_in_a_new_order() {
        let n = 7;
        let epoch = |e: u64| (1..=n as u64).map(|i| view_of_iteration(3, e * n as u64 + i, n)).collect::<Vec<_>>();
        let (first, second) = (epoch(0), epoch(1));
        for order in [&first, &second] {
            let mut sorted = order.clone();
            sorted.sort();
            assert_eq!(sorted, (0..n).collect::<Vec<_>>(), "{order:?}");
        }
        assert_ne!(first, second, "epochs should be shuffled afresh");
        assert_ne!(first, (0..n).collect::<Vec<_>>(), "the order should be shuffled");
        assert_ne!(
            epoch(0),
            (1..=n as u64).map(|i| view_of_iteration(4, i, n)).collect::<Vec<_>>(),
            "the seed picks it"
        );
    }
}
