//! The stage-1 rasterizer on the GPU: the same images and gradients as svgir-raster's kernels
//! (SH colours, the stage-1 outputs), from the WGSL kernels in `shaders/`.
//!
//! A render records, in order: projection (`project.wgsl`), a stable radix sort of the Gaussians
//! by depth (ties keep id order), per Gaussian in depth order its tile count and a scan of them
//! (`bin_count.wgsl`), the entry count against the buffers' capacity (`bin_total.wgsl`), one
//! entry per touched tile (`bin_emit.wgsl`), a stable sort of the entries by tile, so that each
//! tile's list is in (depth, id) order, the tiles' ranges (`bin_ranges.wgsl`), and the forward
//! (`raster_fwd.wgsl`). Nothing is read back: the entry count stays on the GPU, where the sort
//! and the ranges read it, and the entry buffers ([`Frame`]) have a capacity that the trainer
//! sizes from the counts it reads at its own cadence (a render past it is flagged, and its
//! step skipped). The backward runs `raster_bwd.wgsl` (per-entry slots, no atomics) and
//! `project_bwd.wgsl` (per Gaussian, summing its slots in entry order), so its gradients are
//! the same at every run.
//!
//! Tiles are 16 px (one 256-thread workgroup each); the CPU's default is 32. Tiling changes no
//! image bit on the CPU and only the order of gradient sums, so the two compare as the tests do.

use crate::buffers::{bind, dispatch, dispatch_2d, kernel_of, read_back, storage, upload, LOOP_GUARD};
use crate::device::{Gpu, GpuError};
use crate::sort::{scan_plan, sort_plan, ScanPlan, SortKernels, SortPlan};
use bytemuck::{Pod, Zeroable};
use svgir_core::{Camera, Surfels};
use svgir_raster::{Grads, OutputGrads, RasterConfig, RenderOutput};

/// Tile side in pixels (`TILE` in common.wgsl).
pub const TILE: u32 = 16;
/// Floats per splat record (`SPLAT` in common.wgsl).
pub(crate) const SPLAT: u64 = 24;
/// Floats per pixel of the forward's output (`PIX` in raster_fwd.wgsl).
pub(crate) const PIX: usize = 13;
/// Floats per pixel of the output gradients (`VPIX` in raster_bwd.wgsl).
pub(crate) const VPIX: usize = 9;
/// Floats per entry slot of the backward (`DIM` in raster_bwd.wgsl).
const DIM: u64 = 24;
/// Floats per Gaussian of the parameter gradients besides SH (`VP` in project_bwd.wgsl).
pub(crate) const VP: usize = 12;
/// u32s of the binning counters (`count` in bin_total.wgsl; `C_*` in common.wgsl).
pub(crate) const COUNTERS: usize = 8;

/// The per-render uniform (`Params` in common.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct Params {
    r: [[f32; 4]; 3],
    t: [f32; 4],
    center: [f32; 4],
    k: [f32; 4],
    clip: [f32; 4],
    bg: [f32; 4],
    pub(crate) n: u32,
    pub(crate) width: u32,
    pub(crate) height: u32,
    sh_degree: u32,
    pub(crate) tiles_x: u32,
    pub(crate) tiles_y: u32,
    flags: u32,
    pub(crate) capacity: u32,
}

impl Params {
    /// The uniform of a render of `surfels` (their count and SH degree) into entry buffers of
    /// `capacity` entries.
    pub(crate) fn new(
        n: u32,
        sh_degree: u32,
        camera: &Camera,
        bg: [f32; 3],
        cfg: &RasterConfig,
        capacity: u32,
    ) -> Self {
        let cam = svgir_raster::preprocess::Cam::<f32>::new(camera);
        let row = |i: usize| [cam.r[i][0], cam.r[i][1], cam.r[i][2], 0.0];
        let flags = u32::from(cfg.distortion) | (u32::from(cfg.geometry) << 1) | (u32::from(cfg.normals) << 2);
        Self {
            r: [row(0), row(1), row(2)],
            t: [cam.t[0], cam.t[1], cam.t[2], 0.0],
            center: [cam.center[0], cam.center[1], cam.center[2], 0.0],
            k: [cam.fx, cam.fy, cam.cx, cam.cy],
            clip: [cfg.near, cfg.far, cfg.t_stop, 0.0],
            bg: [bg[0], bg[1], bg[2], 0.0],
            n,
            width: cam.width,
            height: cam.height,
            sh_degree,
            tiles_x: cam.width.div_ceil(TILE),
            tiles_y: cam.height.div_ceil(TILE),
            flags,
            capacity,
        }
    }

    /// Tiles of the image.
    pub(crate) fn tiles(&self) -> u32 {
        self.tiles_x * self.tiles_y
    }
}

/// The compiled kernels.
pub struct GpuRaster {
    sort: SortKernels,
    project: wgpu::ComputePipeline,
    bin_count: wgpu::ComputePipeline,
    bin_total: wgpu::ComputePipeline,
    bin_emit: wgpu::ComputePipeline,
    bin_ranges: wgpu::ComputePipeline,
    forward: wgpu::ComputePipeline,
    backward: wgpu::ComputePipeline,
    project_bwd: wgpu::ComputePipeline,
}

/// A kernel of `body` after the shared declarations (`shaders/common.wgsl`).
pub(crate) fn kernel(device: &wgpu::Device, label: &str, body: &str) -> wgpu::ComputePipeline {
    kernel_of(device, label, &[include_str!("shaders/common.wgsl"), body])
}

/// The tile backwards' last reduction step (`shaders/partials.wgsl`).
pub(crate) const PARTIALS: &str = include_str!("shaders/partials.wgsl");

/// A compositing kernel: `parts` after the shared declarations, the batch staging (`stage.wgsl`)
/// and the loop guard.
fn staged_kernel(device: &wgpu::Device, label: &str, parts: &[&str]) -> wgpu::ComputePipeline {
    let mut all = vec![include_str!("shaders/common.wgsl"), include_str!("shaders/stage.wgsl"), LOOP_GUARD];
    all.extend_from_slice(parts);
    kernel_of(device, label, &all)
}

/// Surfel parameters resident on the GPU, in [`Surfels`]' layouts (positions 3, rotations 4 as
/// x y z w, log-scales 2, opacity logits 1, SH 48 floats per Gaussian).
pub struct SurfelBuffers {
    pub(crate) pos: wgpu::Buffer,
    pub(crate) rot: wgpu::Buffer,
    pub(crate) lsc: wgpu::Buffer,
    pub(crate) opa: wgpu::Buffer,
    pub(crate) sh: wgpu::Buffer,
    /// Gaussians held.
    pub n: u32,
}

impl SurfelBuffers {
    /// Uploads the parameters of `surfels` (checked for consistent arrays and the binding limit).
    pub fn upload(gpu: &Gpu, surfels: &Surfels) -> Result<Self, GpuError> {
        surfels.check().map_err(|e| GpuError::Runtime(format!("surfel arrays are inconsistent: {e}")))?;
        check_binding(gpu, "the SH coefficients", surfels.len() as u64 * 48 * 4)?;
        let d = &gpu.device;
        Ok(Self {
            pos: upload(d, "positions", bytemuck::cast_slice::<_, f32>(&surfels.positions)),
            rot: upload(d, "rotations", bytemuck::cast_slice::<_, f32>(&surfels.rotations)),
            lsc: upload(d, "log scales", bytemuck::cast_slice::<_, f32>(&surfels.log_scales)),
            opa: upload(d, "opacity logits", &surfels.opacity_logits),
            sh: upload(d, "sh", bytemuck::cast_slice::<_, f32>(&surfels.sh)),
            n: surfels.len() as u32,
        })
    }

    /// The five parameter buffers in Adam-group order (position, rotation, log scale, opacity, SH).
    pub(crate) fn groups(&self) -> [&wgpu::Buffer; 5] {
        [&self.pos, &self.rot, &self.lsc, &self.opa, &self.sh]
    }

    /// Reads the parameters back into `surfels` (which must hold as many Gaussians).
    pub fn download_into(&self, gpu: &Gpu, surfels: &mut Surfels) -> Result<(), GpuError> {
        let n = self.n as usize;
        if surfels.len() != n {
            return Err(GpuError::Runtime(format!("download of {n} Gaussians into {}", surfels.len())));
        }
        let r = read_back::<f32>(
            &gpu.device,
            &gpu.queue,
            &[(&self.pos, n * 3), (&self.rot, n * 4), (&self.lsc, n * 2), (&self.opa, n), (&self.sh, n * 48)],
        )?;
        bytemuck::cast_slice_mut::<_, f32>(&mut surfels.positions).copy_from_slice(&r[0]);
        bytemuck::cast_slice_mut::<_, f32>(&mut surfels.rotations).copy_from_slice(&r[1]);
        bytemuck::cast_slice_mut::<_, f32>(&mut surfels.log_scales).copy_from_slice(&r[2]);
        surfels.opacity_logits.copy_from_slice(&r[3]);
        bytemuck::cast_slice_mut::<_, f32>(&mut surfels.sh).copy_from_slice(&r[4]);
        Ok(())
    }
}

/// Bits of a tile index for `tiles` tiles (the tile sort's key length).
fn tile_bits(tiles: u32) -> u32 {
    32 - (tiles.max(2) - 1).leading_zeros()
}

/// An error when one binding of `bytes` passes the adapter's storage-binding limit.
pub(crate) fn check_binding(gpu: &Gpu, what: &'static str, bytes: u64) -> Result<(), GpuError> {
    let limit = gpu.report.max_storage_binding;
    if bytes > limit {
        Err(GpuError::TooLarge { what, bytes, limit })
    } else {
        Ok(())
    }
}

/// The buffers of one render and its backward, allocated once and reused: per Gaussian (splat
/// records, boxes, sort keys, offsets, gradients), per entry (up to `capacity` tile entries and
/// their gradient slots), per pixel (outputs and output gradients) and per tile (ranges).
pub struct Frame {
    pub(crate) params: wgpu::Buffer,
    pub(crate) splat: wgpu::Buffer,
    pub(crate) rect: wgpu::Buffer,
    pub(crate) tiles_n: wgpu::Buffer,
    pub(crate) key: wgpu::Buffer,
    pub(crate) val: wgpu::Buffer,
    tmp_k: wgpu::Buffer,
    tmp_v: wgpu::Buffer,
    pub(crate) cnt: wgpu::Buffer,
    pub(crate) off: wgpu::Buffer,
    pub(crate) rank: wgpu::Buffer,
    /// The binning counters (`COUNTERS` u32s, see bin_total.wgsl).
    pub(crate) count: wgpu::Buffer,
    tkey: wgpu::Buffer,
    pub(crate) tval: wgpu::Buffer,
    tk2: wgpu::Buffer,
    tv2: wgpu::Buffer,
    pub(crate) egauss: wgpu::Buffer,
    pub(crate) slots: wgpu::Buffer,
    pub(crate) ranges: wgpu::Buffer,
    /// Per pixel, the forward's outputs (`PIX` floats).
    pub(crate) img: wgpu::Buffer,
    pub(crate) ncon: wgpu::Buffer,
    /// Per pixel, the loss's output gradients (`VPIX` floats), what the backward reads.
    pub(crate) vout: wgpu::Buffer,
    /// Per Gaussian, the gradients besides SH (`VP` floats) and the SH gradients (48).
    pub(crate) vparam: wgpu::Buffer,
    pub(crate) vsh: wgpu::Buffer,
    /// The depth sort's, the offsets' scan's and the tile sort's buffers.
    depth_sort: SortPlan,
    offsets_scan: ScanPlan,
    tile_sort: SortPlan,
    capacity: u32,
}

impl Frame {
    /// Buffers for `n` Gaussians, images of up to `npx` pixels and `tiles` tiles, and
    /// `capacity` tile entries, in the stage-1 kernels' layouts.
    pub fn new(gpu: &Gpu, n: u32, npx: u64, tiles: u32, capacity: u32) -> Result<Self, GpuError> {
        let layout = Layout { slot: DIM, pix: PIX as u64, vpix: VPIX as u64 };
        Self::with_layout(gpu, n, npx, tiles, capacity, layout)
    }

    /// [`Frame::new`] with `layout`'s floats per entry slot, output pixel and output-gradient
    /// pixel (the feature raster's depend on its tables).
    pub(crate) fn with_layout(
        gpu: &Gpu,
        n: u32,
        npx: u64,
        tiles: u32,
        capacity: u32,
        layout: Layout,
    ) -> Result<Self, GpuError> {
        let Layout { slot, pix, vpix } = layout;
        check_binding(gpu, "the forward's per-pixel outputs", npx * pix * 4)?;
        check_binding(gpu, "the tile entries' gradient slots", capacity as u64 * slot * 4)?;
        check_binding(gpu, "the SH gradients", n as u64 * 48 * 4)?;
        let d = &gpu.device;
        let nb = n as u64 * 4;
        let eb = capacity as u64 * 4;
        let params = crate::buffers::uniform_slot::<Params>(d, "render params");
        Ok(Self {
            params,
            splat: storage(d, "splats", nb * SPLAT),
            rect: storage(d, "rects", nb * 4),
            tiles_n: storage(d, "tile counts", nb),
            key: storage(d, "depth keys", nb),
            val: storage(d, "depth order", nb),
            tmp_k: storage(d, "sort scratch keys", nb),
            tmp_v: storage(d, "sort scratch values", nb),
            cnt: storage(d, "counts", nb),
            off: storage(d, "offsets", nb),
            rank: storage(d, "ranks", nb),
            count: storage(d, "binning counters", COUNTERS as u64 * 4),
            tkey: storage(d, "tile keys", eb),
            tval: storage(d, "tile values", eb),
            tk2: storage(d, "tile sort scratch keys", eb),
            tv2: storage(d, "tile sort scratch values", eb),
            egauss: storage(d, "entry gaussians", eb),
            slots: storage(d, "entry gradient slots", eb * slot),
            ranges: storage(d, "tile ranges", tiles as u64 * 8),
            img: storage(d, "forward outputs", npx * pix * 4),
            ncon: storage(d, "n_contrib", npx * 4),
            vout: storage(d, "output gradients", npx * vpix * 4),
            vparam: storage(d, "parameter gradients", nb * VP as u64),
            vsh: storage(d, "sh gradients", nb * 48),
            depth_sort: sort_plan(d, n, 32, false),
            offsets_scan: scan_plan(d, n),
            tile_sort: sort_plan(d, capacity, tile_bits(tiles), true),
            capacity,
        })
    }

    /// Tile entries the buffers hold.
    pub fn capacity(&self) -> u32 {
        self.capacity
    }
}

/// Floats per entry slot, per pixel of the forward's outputs and per pixel of the output
/// gradients, for [`Frame::with_layout`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Layout {
    pub(crate) slot: u64,
    pub(crate) pix: u64,
    pub(crate) vpix: u64,
}

/// A render's state on the GPU: its surfels, buffers and uniform (what its backward reads).
pub struct GpuForward {
    params: Params,
    surf: SurfelBuffers,
    frame: Frame,
    /// Number of (tile, Gaussian) entries binned.
    pub entries: u32,
}

/// A render's binning, read back: per Gaussian its screen box `[x0, x1, y0, y1]` and camera
/// depth, and per tile its list of Gaussians in compositing order.
pub type TileLists = (Vec<[u32; 4]>, Vec<f32>, Vec<Vec<u32>>);

impl GpuForward {
    /// The render's binning, read back (for tests).
    pub fn tile_lists(&self, gpu: &Gpu) -> Result<TileLists, GpuError> {
        let (n, e, t) = (self.params.n as usize, self.entries as usize, self.params.tiles() as usize);
        let f = &self.frame;
        let u = read_back::<u32>(
            &gpu.device,
            &gpu.queue,
            &[(&f.rect, n * 4), (&f.ranges, t * 2), (&f.tval, e), (&f.egauss, e)],
        )?;
        let splat = read_back::<f32>(&gpu.device, &gpu.queue, &[(&f.splat, n * SPLAT as usize)])?.remove(0);
        let rects = u[0].chunks_exact(4).map(|r| [r[0], r[1], r[2], r[3]]).collect();
        let depth = (0..n).map(|g| splat[g * SPLAT as usize + 12]).collect();
        let lists =
            (0..t).map(|k| (u[1][2 * k]..u[1][2 * k + 1]).map(|s| u[3][u[2][s as usize] as usize]).collect()).collect();
        Ok((rects, depth, lists))
    }
}

/// The backward's results beyond [`Grads`]: per Gaussian, the weight it composited over the
/// view's pixels (what [`RenderOutput::accum_weight`] holds on the CPU, for pruning).
pub struct GpuGrads {
    /// Gradients, as svgir-raster's backward returns them (`v_color_features`, `v_extra` empty,
    /// `v_background` 3 values, computed on the CPU from the final T).
    pub grads: Grads,
    /// Per Gaussian, the sum of its weights `alpha T` over the pixels it composited.
    pub accum_weight: Vec<f32>,
}

impl GpuRaster {
    /// Compiles the kernels on `gpu`.
    pub fn new(gpu: &Gpu) -> Self {
        let d = &gpu.device;
        Self {
            sort: SortKernels::new(d),
            project: kernel(d, "project", include_str!("shaders/project.wgsl")),
            bin_count: kernel(d, "bin_count", include_str!("shaders/bin_count.wgsl")),
            bin_total: kernel(d, "bin_total", include_str!("shaders/bin_total.wgsl")),
            bin_emit: kernel(d, "bin_emit", include_str!("shaders/bin_emit.wgsl")),
            bin_ranges: kernel(d, "bin_ranges", include_str!("shaders/bin_ranges.wgsl")),
            forward: staged_kernel(d, "raster_fwd", &[include_str!("shaders/raster_fwd.wgsl")]),
            backward: staged_kernel(d, "raster_bwd", &[PARTIALS, include_str!("shaders/raster_bwd.wgsl")]),
            project_bwd: kernel(d, "project_bwd", include_str!("shaders/project_bwd.wgsl")),
        }
    }

    /// Records a render of `surf` with `params` into `frame` (the uniform is written through the
    /// queue, so one render per frame per submission). The counters keep their running maximum
    /// and overflow count until the caller clears them.
    pub(crate) fn encode_forward(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        surf: &SurfelBuffers,
        frame: &Frame,
        params: &Params,
    ) {
        self.encode_binning(gpu, enc, surf, frame, params);
        let (d, f, p) = (&gpu.device, frame, &frame.params);
        let bg4 = bind(
            d,
            &self.forward,
            &[p, &f.splat, &f.rect, &f.ranges, &f.tval, &f.egauss, &f.img, &f.ncon, &gpu.status],
        );
        dispatch_2d(enc, &self.forward, &bg4, params.tiles_x, params.tiles_y);
    }

    /// Records everything of a render before its compositing: the projection, the depth sort,
    /// the binning and the tile ranges (the uniform is written through the queue).
    pub(crate) fn encode_binning(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        surf: &SurfelBuffers,
        frame: &Frame,
        params: &Params,
    ) {
        let d = &gpu.device;
        let f = frame;
        gpu.queue.write_buffer(&f.params, 0, bytemuck::bytes_of(params));
        let n = params.n;
        let groups = n.div_ceil(256);
        let p = &f.params;
        let bg0 = bind(
            d,
            &self.project,
            &[p, &surf.pos, &surf.rot, &surf.lsc, &surf.opa, &surf.sh, &f.splat, &f.rect, &f.tiles_n, &f.key, &f.val],
        );
        dispatch(enc, &self.project, &bg0, groups);
        self.sort.sort_with(d, enc, [&f.key, &f.val, &f.tmp_k, &f.tmp_v], &f.depth_sort, None);
        let bg1 = bind(d, &self.bin_count, &[p, &f.val, &f.tiles_n, &f.cnt, &f.off, &f.rank]);
        dispatch(enc, &self.bin_count, &bg1, groups);
        self.sort.scan_with(d, enc, &f.off, &f.offsets_scan);
        let bgt = bind(d, &self.bin_total, &[p, &f.off, &f.cnt, &f.count]);
        dispatch(enc, &self.bin_total, &bgt, 1);
        enc.clear_buffer(&f.ranges, 0, None);
        let cap = params.capacity;
        if cap > 0 && n > 0 {
            let bg2 = bind(d, &self.bin_emit, &[p, &f.val, &f.off, &f.cnt, &f.rect, &f.tkey, &f.tval, &f.egauss]);
            dispatch(enc, &self.bin_emit, &bg2, groups);
            self.sort.sort_with(d, enc, [&f.tkey, &f.tval, &f.tk2, &f.tv2], &f.tile_sort, Some(&f.count));
            let bg3 = bind(d, &self.bin_ranges, &[p, &f.tkey, &f.ranges, &f.count]);
            dispatch(enc, &self.bin_ranges, &bg3, cap.div_ceil(256));
        }
    }

    /// Records the backward of the render last recorded into `frame`, from the output
    /// gradients in `frame.vout`, into `frame.vparam` and `frame.vsh`.
    pub(crate) fn encode_backward(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        surf: &SurfelBuffers,
        frame: &Frame,
        params: &Params,
    ) {
        let d = &gpu.device;
        let f = frame;
        let p = &f.params;
        enc.clear_buffer(&f.slots, 0, None);
        let b = bind(
            d,
            &self.backward,
            &[p, &f.splat, &f.rect, &f.ranges, &f.tval, &f.egauss, &f.img, &f.ncon, &f.vout, &f.slots, &gpu.status],
        );
        dispatch_2d(enc, &self.backward, &b, params.tiles_x, params.tiles_y);
        let b = bind(
            d,
            &self.project_bwd,
            &[p, &surf.pos, &surf.rot, &surf.sh, &f.splat, &f.rank, &f.off, &f.cnt, &f.slots, &f.vparam, &f.vsh],
        );
        dispatch(enc, &self.project_bwd, &b, params.n.div_ceil(256));
    }

    /// The entries a render of `surf` with `params` bins (one read-back; for sizing).
    pub(crate) fn count_entries(&self, gpu: &Gpu, surf: &SurfelBuffers, params: &Params) -> Result<u32, GpuError> {
        let p = Params { capacity: 0, ..*params };
        let frame = Frame::new(gpu, p.n, p.width as u64 * p.height as u64, p.tiles(), 0)?;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.encode_binning(gpu, &mut enc, surf, &frame, &p);
        gpu.queue.submit([enc.finish()]);
        Ok(read_back::<u32>(&gpu.device, &gpu.queue, &[(&frame.count, COUNTERS)])?[0][1])
    }

    /// Renders the SH colours of `surfels` from `camera` over the colour `bg`: the outputs of
    /// svgir-raster's `render` with `ColorSource::Sh` and no extra features (`accum_weight` is
    /// left empty: the backward returns it), and the state its backward reads. The entry
    /// buffers are sized exactly, from a first pass that only counts.
    pub fn render(
        &self,
        gpu: &Gpu,
        surfels: &Surfels,
        camera: &Camera,
        bg: [f32; 3],
        cfg: &RasterConfig,
    ) -> Result<(RenderOutput, GpuForward), GpuError> {
        let surf = SurfelBuffers::upload(gpu, surfels)?;
        let (out, params, frame) = self.render_with(gpu, &surf, surfels.sh_degree, camera, bg, cfg)?;
        let entries = params.capacity;
        Ok((out, GpuForward { params, surf, frame, entries }))
    }

    /// [`GpuRaster::render`] of resident surfels of SH degree `sh_degree`, with the render's
    /// uniform and buffers.
    pub(crate) fn render_with(
        &self,
        gpu: &Gpu,
        surf: &SurfelBuffers,
        sh_degree: u32,
        camera: &Camera,
        bg: [f32; 3],
        cfg: &RasterConfig,
    ) -> Result<(RenderOutput, Params, Frame), GpuError> {
        let params = Params::new(surf.n, sh_degree, camera, bg, cfg, 0);
        let entries = self.count_entries(gpu, surf, &params)?;
        let params = Params { capacity: entries, ..params };
        let npx = camera.width() as u64 * camera.height() as u64;
        let frame = Frame::new(gpu, surf.n, npx, params.tiles(), entries)?;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        self.encode_forward(gpu, &mut enc, surf, &frame, &params);
        gpu.queue.submit([enc.finish()]);
        let out = read_output(gpu, &params, &frame)?;
        gpu.check()?;
        Ok((out, params, frame))
    }

    /// Gradients of a loss with output gradients `grads` (colour, alpha, depth, normal,
    /// distortion; `extra` must be `None`) for the render `fwd`.
    pub fn backward(&self, gpu: &Gpu, fwd: &GpuForward, grads: &OutputGrads) -> Result<GpuGrads, GpuError> {
        let (d, q) = (&gpu.device, &gpu.queue);
        let p = &fwd.params;
        let npx = p.width as usize * p.height as usize;
        let n = p.n as usize;
        if grads.extra.is_some() {
            return Err(GpuError::Runtime("the GPU rasterizer has no extra feature channels".into()));
        }
        // Output gradients, interleaved per pixel (VPIX floats).
        let mut vout = vec![0.0f32; npx * VPIX];
        let put = |vout: &mut [f32], src: Option<&[f32]>, ch: usize, at: usize, what: &str| -> Result<(), GpuError> {
            if let Some(s) = src {
                if s.len() != npx * ch {
                    return Err(GpuError::Runtime(format!(
                        "{what} gradient: expected {} values, got {}",
                        npx * ch,
                        s.len()
                    )));
                }
                for i in 0..npx {
                    vout[i * VPIX + at..i * VPIX + at + ch].copy_from_slice(&s[i * ch..(i + 1) * ch]);
                }
            }
            Ok(())
        };
        put(&mut vout, grads.color, 3, 0, "colour")?;
        put(&mut vout, grads.alpha, 1, 3, "alpha")?;
        put(&mut vout, grads.depth, 1, 4, "depth")?;
        put(&mut vout, grads.normal, 3, 5, "normal")?;
        put(&mut vout, grads.distortion, 1, 8, "distortion")?;
        q.write_buffer(&fwd.frame.vout, 0, bytemuck::cast_slice(&vout));
        let mut enc = d.create_command_encoder(&Default::default());
        self.encode_backward(gpu, &mut enc, &fwd.surf, &fwd.frame, p);
        q.submit([enc.finish()]);
        let f = &fwd.frame;
        let r = read_back::<f32>(d, q, &[(&f.vparam, n * VP), (&f.vsh, n * 48), (&f.img, npx * PIX)])?;
        gpu.check()?;
        let (vp, vs, img) = (&r[0], &r[1], &r[2]);
        let mut g = Grads {
            v_positions: vec![glam::Vec3::ZERO; n],
            v_rotations: vec![glam::Quat::from_xyzw(0.0, 0.0, 0.0, 0.0); n],
            v_log_scales: vec![glam::Vec2::ZERO; n],
            v_opacity_logits: vec![0.0; n],
            v_sh: vec![svgir_core::ShCoeffs::default(); n],
            v_color_features: Vec::new(),
            v_extra: Vec::new(),
            v_background: vec![0.0; 3],
            v_mean2d_norm: vec![0.0; n],
            phases: Default::default(),
        };
        let mut accum_weight = vec![0.0; n];
        for i in 0..n {
            let r = &vp[i * VP..(i + 1) * VP];
            g.v_positions[i] = glam::Vec3::new(r[0], r[1], r[2]);
            g.v_rotations[i] = glam::Quat::from_xyzw(r[3], r[4], r[5], r[6]);
            g.v_log_scales[i] = glam::Vec2::new(r[7], r[8]);
            g.v_opacity_logits[i] = r[9];
            g.v_mean2d_norm[i] = r[10];
            accum_weight[i] = r[11];
            let mut s = svgir_core::ShCoeffs::default();
            for k in 0..16 {
                for ch in 0..3 {
                    s.0[k][ch] = vs[i * 48 + k * 3 + ch];
                }
            }
            g.v_sh[i] = s;
        }
        if let Some(gc) = grads.color {
            g.v_background = background_grad(img, PIX, 10, gc);
        }
        Ok(GpuGrads { grads: g, accum_weight })
    }
}

/// The gradient of a constant background colour, `sum over pixels of T_N dL/dC`, from the
/// forward's outputs `img` (`pix` floats a pixel, the final T at `t_at`) and the colour
/// gradients `gc` (3 a pixel).
pub(crate) fn background_grad(img: &[f32], pix: usize, t_at: usize, gc: &[f32]) -> Vec<f32> {
    let mut vb = [0.0f64; 3];
    for (o, g) in img.chunks_exact(pix).zip(gc.chunks_exact(3)) {
        let t = o[t_at] as f64;
        for ch in 0..3 {
            vb[ch] += t * g[ch] as f64;
        }
    }
    vb.iter().map(|&v| v as f32).collect()
}

/// Reads the images of the render last recorded into `frame` into svgir-raster's output type.
pub(crate) fn read_output(gpu: &Gpu, p: &Params, frame: &Frame) -> Result<RenderOutput, GpuError> {
    let npx = p.width as usize * p.height as usize;
    let n = p.n as usize;
    let r = read_back::<f32>(&gpu.device, &gpu.queue, &[(&frame.img, npx * PIX), (&frame.splat, n * SPLAT as usize)])?;
    let rects = read_back::<u32>(&gpu.device, &gpu.queue, &[(&frame.rect, n * 4)])?;
    let (img, splat) = (&r[0], &r[1]);
    let mut out = RenderOutput {
        width: p.width,
        height: p.height,
        color: vec![0.0; npx * 3],
        alpha: vec![0.0; npx],
        depth: vec![0.0; npx],
        median_depth: vec![0.0; npx],
        normal: vec![0.0; npx * 3],
        distortion: vec![0.0; npx],
        extra: Vec::new(),
        extra_channels: 0,
        accum_weight: Vec::new(),
        max_radius: vec![0.0; n],
    };
    for i in 0..npx {
        let o = &img[i * PIX..(i + 1) * PIX];
        out.color[i * 3..i * 3 + 3].copy_from_slice(&o[0..3]);
        out.alpha[i] = o[3];
        out.depth[i] = o[4];
        out.median_depth[i] = o[5];
        out.normal[i * 3..i * 3 + 3].copy_from_slice(&o[6..9]);
        out.distortion[i] = o[9];
    }
    for g in 0..n {
        let rc = &rects[0][g * 4..g * 4 + 4];
        if rc[0] < rc[1] && rc[2] < rc[3] {
            out.max_radius[g] = splat[g * SPLAT as usize + 23];
        }
    }
    Ok(out)
}
