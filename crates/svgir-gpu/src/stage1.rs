//! Stage 1 (SPEC 2) on the GPU with its data resident there: the surfels, their Adam moments,
//! the densification statistics and the training photos (RGB, alpha, dilated mask) live in GPU
//! buffers, and an iteration is one submission -- render, loss, backward, statistics, Adam --
//! with nothing read back. The host keeps the run's [`Stage1`]: its configuration, random
//! stream, schedules and Adam step counts draw every iteration exactly as the CPU trainer does
//! ([`Stage1::plan`]), so the two devices see the same views and backgrounds.
//!
//! The host reads back:
//! - one loss record when asked (the CLI asks at its logging cadence) and at least every
//!   [`READ_EVERY`] iterations, with the binning counters, which size the entry buffers;
//! - the surfels, moments and statistics at a densification or an opacity reset (run on the
//!   host by [`Stage1::finish`], the same code as on the CPU, then uploaded) and at
//!   [`GpuStage1::sync`] (checkpoints, evaluation, the end of a run).
//!
//! A checkpoint is the host's [`Stage1`], so a run resumes on either device.

use crate::buffers::{bind, dispatch, read_back, storage, uniform_slot, upload};
use crate::device::{Gpu, GpuError};
use crate::exposure::GpuExposure;
use crate::loss::{photo_record, LossBuffers, LossKernels, LossParams, RECORD};
use crate::raster::{kernel, Frame, GpuRaster, Params, SurfelBuffers, COUNTERS, VP};
use bytemuck::{Pod, Zeroable};
use svgir_core::{Camera, Dataset, View};
use svgir_raster::{RasterConfig, RenderOutput};
use svgir_train::adam::AdamGroup;
use svgir_train::densify::DensifyStats;
use svgir_train::losses::objective::depth_normal_weight;
use svgir_train::stage1::{half_size_views, ndc_scale, psnr_of_mse};
use svgir_train::{Stage1, StepStats};

/// The most iterations between two reads of the loss record and the binning counters.
pub const READ_EVERY: u64 = 50;
/// Records in the loss ring (iterations whose record can wait to be read).
const RING: u32 = 64;
/// Entry capacity over the most entries seen: the headroom that keeps renders from overflowing.
const HEADROOM: f64 = 1.5;

/// The `AdamParams` uniform of adam.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct AdamParams {
    count: u32,
    stride: u32,
    gstride: u32,
    goff: u32,
    b1: f32,
    b2: f32,
    eps: f32,
    bc2_sqrt: f32,
    lr_first: f32,
    lr_rest: f32,
    first: u32,
    /// The binary-opacity term's weight over the Gaussian count (0: off).
    binary: f32,
}

impl AdamParams {
    /// Counts a step of `group` (rows of `n` Gaussians) and returns its uniform, the gradient
    /// at row stride `gstride` from column `goff`.
    pub(crate) fn step(group: &mut AdamGroup, n: u32, gstride: u32, goff: u32) -> Result<Self, GpuError> {
        let c = group.count_step();
        let stride = group.stride as u32;
        // The CPU forms `step_size * lr_scale[c]` per component; SH's scale is 1 on the DC
        // terms and one value on the rest (SPEC 2): two values cover every group.
        let s0 = group.lr_scale[0];
        let first = group.lr_scale.iter().take_while(|&&s| s == s0).count();
        let rest = group.lr_scale.get(first).copied().unwrap_or(s0);
        if group.lr_scale[first..].iter().any(|&s| s != rest) {
            return Err(GpuError::Runtime(format!("Adam group {}: more than two learning-rate scales", group.name)));
        }
        Ok(Self {
            count: n * stride,
            stride,
            gstride,
            goff,
            b1: c.b1,
            b2: c.b2,
            eps: c.eps,
            bc2_sqrt: c.bc2_sqrt,
            lr_first: c.step_size * s0,
            lr_rest: c.step_size * rest,
            first: first as u32,
            binary: 0.0,
        })
    }

    /// With the binary-opacity term's gradient (svgir_train::losses::opacity) at `weight`
    /// added to an opacity group of `n` Gaussians before the step.
    pub(crate) fn with_binary_opacity(self, weight: f32, n: u32) -> Self {
        Self { binary: if n == 0 { 0.0 } else { weight / n as f32 }, ..self }
    }
}

/// The `StatsParams` uniform of densify_stats.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct StatsParams {
    n: u32,
    to_ndc: f32,
    pad: [u32; 2],
}

/// Where each Adam group's gradient lies: (row stride, first column) in `vparam` or `vsh`.
const GRAD_AT: [(u32, u32); 5] = [(VP as u32, 0), (VP as u32, 3), (VP as u32, 7), (VP as u32, 9), (48, 0)];

/// Everything resident that follows the Gaussian count.
struct Resident {
    surf: SurfelBuffers,
    /// Per Adam group, its first and second moments.
    moments: Vec<(wgpu::Buffer, wgpu::Buffer)>,
    /// 4 floats a Gaussian (densify_stats.wgsl).
    stats: wgpu::Buffer,
}

impl Resident {
    fn upload(gpu: &Gpu, host: &Stage1) -> Result<Self, GpuError> {
        let d = &gpu.device;
        let surf = SurfelBuffers::upload(gpu, &host.surfels)?;
        let moments = host.groups.iter().map(|g| (upload(d, "adam m", &g.m), upload(d, "adam v", &g.v))).collect();
        let st = &host.stats;
        let stats: Vec<f32> = (0..host.surfels.len())
            .flat_map(|i| [st.grad_accum[i], st.denom[i] as f32, st.max_radius[i], st.accum_weight[i]])
            .collect();
        Ok(Self { surf, moments, stats: upload(d, "densify stats", &stats) })
    }

    /// Reads the surfels, moments and statistics into `host`.
    fn download_into(&self, gpu: &Gpu, host: &mut Stage1) -> Result<(), GpuError> {
        self.surf.download_into(gpu, &mut host.surfels)?;
        let n = host.surfels.len();
        let mut reads: Vec<(&wgpu::Buffer, usize)> = Vec::new();
        for (g, (m, v)) in host.groups.iter().zip(&self.moments) {
            reads.push((m, n * g.stride));
            reads.push((v, n * g.stride));
        }
        reads.push((&self.stats, n * 4));
        let mut r = read_back::<f32>(&gpu.device, &gpu.queue, &reads)?;
        let st = r.pop().unwrap_or_default();
        for (k, g) in host.groups.iter_mut().enumerate() {
            g.m.copy_from_slice(&r[2 * k]);
            g.v.copy_from_slice(&r[2 * k + 1]);
        }
        let mut s = DensifyStats::new(n);
        for i in 0..n {
            s.grad_accum[i] = st[i * 4];
            s.denom[i] = st[i * 4 + 1] as u32;
            s.max_radius[i] = st[i * 4 + 2];
            s.accum_weight[i] = st[i * 4 + 3];
        }
        host.stats = s;
        Ok(())
    }
}

/// Photos resident on the GPU, one buffer a view (`TGT` floats a pixel).
fn upload_photos(gpu: &Gpu, views: &[View]) -> Vec<wgpu::Buffer> {
    views.iter().map(|v| upload(&gpu.device, "photo", &photo_record(&v.image))).collect()
}

/// The stage-1 trainer on a GPU.
pub struct GpuStage1 {
    /// The run's host state: configuration, random stream, schedules, Adam step counts. Its
    /// surfels, moments and statistics are current after [`GpuStage1::sync`] only.
    pub host: Stage1,
    gpu: Gpu,
    raster: GpuRaster,
    loss: LossKernels,
    adam: wgpu::ComputePipeline,
    stats_kernel: wgpu::ComputePipeline,
    res: Resident,
    frame: Frame,
    loss_bufs: LossBuffers,
    adam_params: Vec<wgpu::Buffer>,
    stats_params: wgpu::Buffer,
    photos: Vec<wgpu::Buffer>,
    half: Option<(Vec<View>, Vec<wgpu::Buffer>)>,
    /// The per-photo colour corrections (`--exposure`), resident.
    exposure: Option<GpuExposure>,
    /// Whether the host's surfels, moments and statistics are those on the GPU.
    synced: bool,
    last_read: u64,
    /// Most entries a render binned since the buffers were last sized.
    max_entries: u32,
    /// Renders whose entries overflowed the buffers (their steps were skipped).
    pub overflows: u64,
    /// The largest training image (pixels, tiles), which the buffers are sized for.
    npx: u64,
    tiles: u32,
}

impl GpuStage1 {
    /// Puts the run `host` (fresh or resumed) on `gpu`: uploads its surfels, moments,
    /// statistics and the training photos.
    pub fn new(host: Stage1, gpu: Gpu, dataset: &Dataset) -> Result<Self, GpuError> {
        let d = &gpu.device;
        let raster = GpuRaster::new(&gpu);
        let loss = LossKernels::new(&gpu);
        let adam = kernel(d, "adam", include_str!("shaders/adam.wgsl"));
        let stats_kernel = kernel(d, "densify_stats", include_str!("shaders/densify_stats.wgsl"));
        let res = Resident::upload(&gpu, &host)?;
        let npx = dataset.train.iter().map(|v| v.camera.width() as u64 * v.camera.height() as u64).max().unwrap_or(1);
        let tiles = dataset
            .train
            .iter()
            .map(|v| v.camera.width().div_ceil(crate::TILE) * v.camera.height().div_ceil(crate::TILE))
            .max()
            .unwrap_or(1);
        let frame = Frame::new(&gpu, res.surf.n, npx, tiles, 0)?;
        let loss_bufs = LossBuffers::new(&gpu, npx, RING);
        let adam_params = (0..5).map(|_| uniform_slot::<AdamParams>(d, "adam params")).collect();
        let stats_params = uniform_slot::<StatsParams>(d, "stats params");
        let photos = upload_photos(&gpu, &dataset.train);
        let exposure = host.exposure.as_ref().map(|e| GpuExposure::new(&gpu, e, npx)).transpose()?;
        let last_read = host.iteration;
        Ok(Self {
            host,
            gpu,
            raster,
            loss,
            adam,
            stats_kernel,
            res,
            frame,
            loss_bufs,
            adam_params,
            stats_params,
            photos,
            half: None,
            exposure,
            synced: true,
            last_read,
            max_entries: 0,
            overflows: 0,
            npx,
            tiles,
        })
    }

    /// The adapter the run uses.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// One iteration. With `read`, the iteration's loss record comes back (one small read);
    /// otherwise its loss fields are NaN, unless the periodic read falls on it.
    pub fn step(&mut self, dataset: &Dataset, read: bool) -> Result<StepStats, GpuError> {
        let plan = self.host.plan(dataset);
        let it = plan.iteration;
        if plan.half && self.half.is_none() {
            let views = half_size_views(dataset);
            let photos = upload_photos(&self.gpu, &views);
            self.half = Some((views, photos));
        }
        let camera = match (&self.half, plan.half) {
            (Some((views, _)), true) => views[plan.view].camera,
            _ => dataset.train[plan.view].camera,
        };
        let (w, h) = (camera.width(), camera.height());
        if self.frame.capacity() == 0 {
            self.size_entries(&camera, plan.bg, &plan.raster)?;
        }
        let params = Params::new(
            self.res.surf.n,
            self.host.surfels.sh_degree,
            &camera,
            plan.bg,
            &plan.raster,
            self.frame.capacity(),
        );
        let slot = (it % RING as u64) as u32;
        let w_dn = depth_normal_weight(&plan.weights, plan.t_frac);
        let lp = LossParams::new(&camera, plan.bg, &plan.weights, w_dn, self.host.config.use_mask, slot);
        let q = &self.gpu.queue;
        let d = &self.gpu.device;
        let mut enc = d.create_command_encoder(&Default::default());
        self.raster.encode_forward(&self.gpu, &mut enc, &self.res.surf, &self.frame, &params);
        let photo = match (&self.half, plan.half) {
            (Some((_, photos)), true) => &photos[plan.view],
            _ => &self.photos[plan.view],
        };
        let npx = w * h;
        // The loss sees the photo's colour correction applied to the render (Stage1::step).
        if let Some(e) = &self.exposure {
            e.encode_forward(&self.gpu, &mut enc, &self.frame, plan.view, npx, plan.bg);
        }
        self.loss.encode(&self.gpu, &mut enc, &self.frame, photo, &self.loss_bufs, &lp);
        if let (Some(e), Some(host_e)) = (&self.exposure, self.host.exposure.as_mut()) {
            e.encode_backward_and_step(&self.gpu, &mut enc, &self.frame, &self.adam, host_e, plan.view, npx)?;
        }
        self.raster.encode_backward(&self.gpu, &mut enc, &self.res.surf, &self.frame, &params);
        let n = self.res.surf.n;
        if it <= self.host.config.densify.until_iter {
            let sp = StatsParams { n, to_ndc: ndc_scale(w as usize, h as usize), pad: [0; 2] };
            q.write_buffer(&self.stats_params, 0, bytemuck::bytes_of(&sp));
            let f = &self.frame;
            let b = bind(
                d,
                &self.stats_kernel,
                &[&self.stats_params, &f.splat, &f.rect, &f.vparam, &f.count, &self.res.stats],
            );
            dispatch(&mut enc, &self.stats_kernel, &b, n.div_ceil(256));
        }
        self.host.set_position_lr(it);
        let params_bufs = self.res.surf.groups();
        for (k, group) in self.host.groups.iter_mut().enumerate() {
            let (gstride, goff) = GRAD_AT[k];
            let mut ap = AdamParams::step(group, n, gstride, goff)?;
            // The CPU adds the term to the opacity gradient after densification (Stage1::step).
            if k == 3 && plan.weights.opacity_binary > 0.0 && it > self.host.config.densify.until_iter {
                ap = ap.with_binary_opacity(plan.weights.opacity_binary, n);
            }
            let stride = group.stride as u32;
            q.write_buffer(&self.adam_params[k], 0, bytemuck::bytes_of(&ap));
            let grad = if k == 4 { &self.frame.vsh } else { &self.frame.vparam };
            let (m, v) = &self.res.moments[k];
            let b = bind(d, &self.adam, &[&self.adam_params[k], params_bufs[k], grad, m, v, &self.frame.count]);
            dispatch(&mut enc, &self.adam, &b, (n * stride).div_ceil(256));
        }
        q.submit([enc.finish()]);
        self.synced = false;

        let mut stats = StepStats {
            iteration: it,
            view: plan.view,
            loss: f32::NAN,
            l1: f32::NAN,
            ssim: f32::NAN,
            psnr: f32::NAN,
            num_gaussians: n as usize,
            densify: None,
        };
        let changes = self.host.changes_surfels_at(it);
        if read || changes || it - self.last_read >= READ_EVERY || self.host.is_done() {
            let rec = self.read_record(slot)?;
            stats.l1 = rec[0];
            stats.ssim = rec[1];
            stats.psnr = psnr_of_mse(rec[6] as f64);
            stats.loss = rec[7];
            self.last_read = it;
        }
        // Densification and resets change the surfels on the host (the CPU's own code): bring
        // them there first, and the new set back after. Otherwise only the SH degree and the
        // half-size views change.
        if changes {
            self.sync()?;
        }
        stats.densify = self.host.finish(it);
        if changes {
            let before = self.res.surf.n.max(1) as f64;
            self.res = Resident::upload(&self.gpu, &self.host)?;
            // The entry buffers follow the Gaussian count, their capacity in proportion.
            let grown = self.frame.capacity() as f64 * self.res.surf.n as f64 / before;
            self.frame = Frame::new(&self.gpu, self.res.surf.n, self.npx, self.tiles, grown.ceil() as u32)?;
            stats.num_gaussians = self.res.surf.n as usize;
        }
        if self.host.iteration >= self.host.config.half_res_until {
            self.half = None;
        }
        self.gpu.check()?;
        Ok(stats)
    }

    /// Reads ring slot `slot` and the binning counters; grows the entry buffers when the
    /// renders since the last read came near their capacity (or past it: those steps were
    /// skipped, and are counted in [`GpuStage1::overflows`]).
    fn read_record(&mut self, slot: u32) -> Result<Vec<f32>, GpuError> {
        let (d, q) = (&self.gpu.device, &self.gpu.queue);
        let mut enc = d.create_command_encoder(&Default::default());
        let off = slot as u64 * RECORD as u64 * 4;
        let tmp = storage(d, "loss record", RECORD as u64 * 4);
        enc.copy_buffer_to_buffer(&self.loss_bufs.ring, off, &tmp, 0, RECORD as u64 * 4);
        q.submit([enc.finish()]);
        // One wait for both (the record's floats read as their bits).
        let mut r = read_back::<u32>(d, q, &[(&tmp, RECORD), (&self.frame.count, COUNTERS)])?;
        let counters = r.pop().unwrap_or_default();
        let rec: Vec<f32> = r.pop().unwrap_or_default().into_iter().map(f32::from_bits).collect();
        // Clear the running maximum and the overflow count (C_MAX, C_OVERFLOWS).
        q.write_buffer(&self.frame.count, 12, bytemuck::cast_slice(&[0u32, 0u32]));
        self.overflows += counters[4] as u64;
        self.max_entries = self.max_entries.max(counters[3]);
        if self.max_entries as f64 * 1.2 > self.frame.capacity() as f64 {
            let cap = (self.max_entries as f64 * HEADROOM).ceil() as u32;
            self.frame = Frame::new(&self.gpu, self.res.surf.n, self.npx, self.tiles, cap)?;
        }
        self.max_entries = 0;
        Ok(rec)
    }

    /// Sizes the entry buffers from an exact count of one render (a read-back; at the start).
    fn size_entries(&mut self, camera: &Camera, bg: [f32; 3], cfg: &RasterConfig) -> Result<(), GpuError> {
        let p = Params::new(self.res.surf.n, self.host.surfels.sh_degree, camera, bg, cfg, 0);
        let entries = self.raster.count_entries(&self.gpu, &self.res.surf, &p)?;
        let cap = ((entries as f64 * HEADROOM).ceil() as u32).max(1024);
        self.frame = Frame::new(&self.gpu, self.res.surf.n, self.npx, self.tiles, cap)?;
        Ok(())
    }

    /// Brings the host's surfels, moments and statistics up to date (for a checkpoint, an
    /// evaluation or the run's outputs).
    pub fn sync(&mut self) -> Result<(), GpuError> {
        self.gpu.check()?;
        if !self.synced {
            self.res.download_into(&self.gpu, &mut self.host)?;
            if let (Some(e), Some(host_e)) = (&self.exposure, self.host.exposure.as_mut()) {
                e.download_into(&self.gpu, host_e)?;
            }
            self.synced = true;
        }
        Ok(())
    }

    /// Renders `camera` with the current surfels over `bg`, on the GPU.
    pub fn render_view(&self, camera: &Camera, bg: [f32; 3]) -> Result<RenderOutput, GpuError> {
        let sh = self.host.surfels.sh_degree;
        let (out, _, _) = self.raster.render_with(&self.gpu, &self.res.surf, sh, camera, bg, &self.host.raster)?;
        Ok(out)
    }

    /// The run's host state, synced, and the GPU (at the end of a run).
    pub fn into_parts(mut self) -> Result<(Stage1, Gpu), GpuError> {
        self.sync()?;
        Ok((self.host, self.gpu))
    }
}
