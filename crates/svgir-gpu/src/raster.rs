//! The stage-1 rasterizer on the GPU: the same images and gradients as svgir-raster's kernels
//! (SH colours, the stage-1 outputs), from the WGSL kernels in `shaders/`.
//!
//! A render records, in order: projection (`project.wgsl`), a stable radix sort of the Gaussians
//! by depth (ties keep id order), per Gaussian in depth order its tile count and a scan of them
//! (`bin_count.wgsl`), one entry per touched tile (`bin_emit.wgsl`), a stable sort of the entries
//! by tile, so that each tile's list is in (depth, id) order, the tiles' ranges
//! (`bin_ranges.wgsl`), and the forward (`raster_fwd.wgsl`). The number of entries is read back
//! once (eight bytes) between the scan and the emission, to size the entry buffers. The backward
//! runs `raster_bwd.wgsl` (per-entry slots, no atomics) and `project_bwd.wgsl` (per Gaussian,
//! summing its slots in entry order), so its gradients are the same at every run.
//!
//! Tiles are 16 px (one 256-thread workgroup each); the CPU's default is 32. Tiling changes no
//! image bit on the CPU and only the order of gradient sums, so the two compare as the tests do.

use crate::buffers::{bind, dispatch, dispatch_2d, read_back, storage, uniform, upload};
use crate::device::{Gpu, GpuError};
use crate::sort::SortKernels;
use bytemuck::{Pod, Zeroable};
use svgir_core::{Camera, Surfels};
use svgir_raster::{Grads, OutputGrads, RasterConfig, RenderOutput};

/// Tile side in pixels (`TILE` in common.wgsl).
pub const TILE: u32 = 16;
/// Floats per splat record (`SPLAT` in common.wgsl).
const SPLAT: u64 = 24;
/// Floats per pixel of the forward's output (`PIX` in raster_fwd.wgsl).
const PIX: usize = 13;
/// Floats per pixel of the output gradients (`VPIX` in raster_bwd.wgsl).
const VPIX: usize = 9;
/// Floats per entry slot of the backward (`DIM` in raster_bwd.wgsl).
const DIM: u64 = 24;
/// Floats per Gaussian of the parameter gradients besides SH (`VP` in project_bwd.wgsl).
const VP: usize = 12;

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
    n: u32,
    width: u32,
    height: u32,
    sh_degree: u32,
    tiles_x: u32,
    tiles_y: u32,
    flags: u32,
    entries: u32,
}

impl Params {
    fn new(surfels: &Surfels, camera: &Camera, bg: [f32; 3], cfg: &RasterConfig) -> Self {
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
            n: surfels.len() as u32,
            width: cam.width,
            height: cam.height,
            sh_degree: surfels.sh_degree,
            tiles_x: cam.width.div_ceil(TILE),
            tiles_y: cam.height.div_ceil(TILE),
            flags,
            entries: 0,
        }
    }
}

/// The compiled kernels.
pub struct GpuRaster {
    sort: SortKernels,
    project: wgpu::ComputePipeline,
    bin_count: wgpu::ComputePipeline,
    bin_emit: wgpu::ComputePipeline,
    bin_ranges: wgpu::ComputePipeline,
    forward: wgpu::ComputePipeline,
    backward: wgpu::ComputePipeline,
    project_bwd: wgpu::ComputePipeline,
}

fn module(device: &wgpu::Device, label: &str, body: &str) -> wgpu::ShaderModule {
    let src = format!("{}\n{}", include_str!("shaders/common.wgsl"), body);
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(src.into()),
    })
}

fn kernel(device: &wgpu::Device, label: &str, body: &str) -> wgpu::ComputePipeline {
    let m = module(device, label, body);
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: None,
        module: &m,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    })
}

/// What the backward of a render reads, resident on the GPU.
pub struct GpuForward {
    params: Params,
    params_buf: wgpu::Buffer,
    pos: wgpu::Buffer,
    rot: wgpu::Buffer,
    sh: wgpu::Buffer,
    splat: wgpu::Buffer,
    rect: wgpu::Buffer,
    rank: wgpu::Buffer,
    off: wgpu::Buffer,
    cnt: wgpu::Buffer,
    ranges: wgpu::Buffer,
    tval: wgpu::Buffer,
    egauss: wgpu::Buffer,
    img: wgpu::Buffer,
    ncon: wgpu::Buffer,
    /// Number of (tile, Gaussian) entries binned.
    pub entries: u32,
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
            bin_emit: kernel(d, "bin_emit", include_str!("shaders/bin_emit.wgsl")),
            bin_ranges: kernel(d, "bin_ranges", include_str!("shaders/bin_ranges.wgsl")),
            forward: kernel(d, "raster_fwd", include_str!("shaders/raster_fwd.wgsl")),
            backward: kernel(d, "raster_bwd", include_str!("shaders/raster_bwd.wgsl")),
            project_bwd: kernel(d, "project_bwd", include_str!("shaders/project_bwd.wgsl")),
        }
    }

    /// Renders the SH colours of `surfels` from `camera` over the colour `bg`: the outputs of
    /// svgir-raster's `render` with `ColorSource::Sh` and no extra features (`accum_weight` is
    /// left empty: the backward returns it), and the state its backward reads.
    pub fn render(
        &self,
        gpu: &Gpu,
        surfels: &Surfels,
        camera: &Camera,
        bg: [f32; 3],
        cfg: &RasterConfig,
    ) -> Result<(RenderOutput, GpuForward), GpuError> {
        let fwd = self.render_resident(gpu, surfels, camera, bg, cfg)?;
        let out = self.read_output(gpu, &fwd)?;
        Ok((out, fwd))
    }

    /// [`GpuRaster::render`] without reading the images back.
    pub fn render_resident(
        &self,
        gpu: &Gpu,
        surfels: &Surfels,
        camera: &Camera,
        bg: [f32; 3],
        cfg: &RasterConfig,
    ) -> Result<GpuForward, GpuError> {
        surfels.check().map_err(|e| GpuError::Runtime(format!("surfel arrays are inconsistent: {e}")))?;
        let (d, q) = (&gpu.device, &gpu.queue);
        let mut params = Params::new(surfels, camera, bg, cfg);
        let n = params.n;
        let npx = camera.width() as u64 * camera.height() as u64;
        let limit = gpu.report.max_storage_binding;
        let check = |what: &'static str, bytes: u64| {
            if bytes > limit {
                Err(GpuError::TooLarge { what, bytes, limit })
            } else {
                Ok(())
            }
        };
        check("the SH coefficients", n as u64 * 48 * 4)?;
        check("the forward's per-pixel outputs", npx * PIX as u64 * 4)?;
        let nb = n as u64 * 4;
        let pos = upload(d, "positions", bytemuck::cast_slice::<_, f32>(&surfels.positions));
        let rot = upload(d, "rotations", bytemuck::cast_slice::<_, f32>(&surfels.rotations));
        let lsc = upload(d, "log scales", bytemuck::cast_slice::<_, f32>(&surfels.log_scales));
        let opa = upload(d, "opacity logits", &surfels.opacity_logits);
        let sh = upload(d, "sh", bytemuck::cast_slice::<_, f32>(&surfels.sh));
        let splat = storage(d, "splats", nb * SPLAT);
        let rect = storage(d, "rects", nb * 4);
        let tiles_n = storage(d, "tile counts", nb);
        let key = storage(d, "depth keys", nb);
        let val = storage(d, "depth order", nb);
        let tmp_k = storage(d, "sort scratch keys", nb);
        let tmp_v = storage(d, "sort scratch values", nb);
        let cnt = storage(d, "counts", nb);
        let off = storage(d, "offsets", nb);
        let rank = storage(d, "ranks", nb);
        let pbuf = uniform(d, "params", &params);
        let groups = n.div_ceil(256);

        let mut enc = d.create_command_encoder(&Default::default());
        let bg0 = bind(d, &self.project, &[&pbuf, &pos, &rot, &lsc, &opa, &sh, &splat, &rect, &tiles_n, &key, &val]);
        dispatch(&mut enc, &self.project, &bg0, groups);
        self.sort.sort(d, &mut enc, &key, &val, &tmp_k, &tmp_v, n, 32);
        let bg1 = bind(d, &self.bin_count, &[&pbuf, &val, &tiles_n, &cnt, &off, &rank]);
        dispatch(&mut enc, &self.bin_count, &bg1, groups);
        self.sort.scan(d, &mut enc, &off, n);
        q.submit([enc.finish()]);
        // The entry count sizes the entry buffers: the one read-back of a render.
        let entries = if n == 0 {
            0u64
        } else {
            let last = (n - 1) as usize;
            let tail = read_back::<u32>(d, q, &[(&off, n as usize), (&cnt, n as usize)])?;
            tail[0][last] as u64 + tail[1][last] as u64
        };
        check("the tile entries' gradient slots", entries * DIM * 4)?;
        params.entries = entries as u32;
        let pbuf = uniform(d, "params", &params);
        let ntiles = params.tiles_x as u64 * params.tiles_y as u64;
        let tkey = storage(d, "tile keys", entries * 4);
        let tval = storage(d, "tile values", entries * 4);
        let tk2 = storage(d, "tile sort scratch keys", entries * 4);
        let tv2 = storage(d, "tile sort scratch values", entries * 4);
        let egauss = storage(d, "entry gaussians", entries * 4);
        let ranges = storage(d, "tile ranges", ntiles * 8);
        let img = storage(d, "forward outputs", npx * PIX as u64 * 4);
        let ncon = storage(d, "n_contrib", npx * 4);
        let mut enc = d.create_command_encoder(&Default::default());
        enc.clear_buffer(&ranges, 0, None);
        if entries > 0 {
            let bg2 = bind(d, &self.bin_emit, &[&pbuf, &val, &off, &cnt, &rect, &tkey, &tval, &egauss]);
            dispatch(&mut enc, &self.bin_emit, &bg2, groups);
            let tile_bits = 32 - (ntiles.max(2) as u32 - 1).leading_zeros();
            self.sort.sort(d, &mut enc, &tkey, &tval, &tk2, &tv2, entries as u32, tile_bits);
            let bg3 = bind(d, &self.bin_ranges, &[&pbuf, &tkey, &ranges]);
            dispatch(&mut enc, &self.bin_ranges, &bg3, (entries as u32).div_ceil(256));
        }
        let bg4 = bind(d, &self.forward, &[&pbuf, &splat, &rect, &ranges, &tval, &egauss, &img, &ncon]);
        dispatch_2d(&mut enc, &self.forward, &bg4, params.tiles_x, params.tiles_y);
        q.submit([enc.finish()]);
        Ok(GpuForward {
            params,
            params_buf: pbuf,
            pos,
            rot,
            sh,
            splat,
            rect,
            rank,
            off,
            cnt,
            ranges,
            tval,
            egauss,
            img,
            ncon,
            entries: entries as u32,
        })
    }

    /// Reads a render's images back into svgir-raster's output type.
    pub fn read_output(&self, gpu: &Gpu, fwd: &GpuForward) -> Result<RenderOutput, GpuError> {
        let p = &fwd.params;
        let npx = p.width as usize * p.height as usize;
        let n = p.n as usize;
        let r = read_back::<f32>(&gpu.device, &gpu.queue, &[(&fwd.img, npx * PIX), (&fwd.splat, n * SPLAT as usize)])?;
        let rects = read_back::<u32>(&gpu.device, &gpu.queue, &[(&fwd.rect, n * 4)])?;
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

    /// Gradients of a loss with output gradients `grads` (colour, alpha, depth, normal,
    /// distortion; `extra` must be `None`) for the render `fwd` of `surfels`.
    pub fn backward(
        &self,
        gpu: &Gpu,
        surfels: &Surfels,
        fwd: &GpuForward,
        grads: &OutputGrads,
    ) -> Result<GpuGrads, GpuError> {
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
        let vbuf = upload(d, "output gradients", &vout);
        let slots = storage(d, "entry gradient slots", fwd.entries as u64 * DIM * 4);
        let vparam = storage(d, "parameter gradients", n as u64 * VP as u64 * 4);
        let vsh = storage(d, "sh gradients", n as u64 * 48 * 4);
        let mut enc = d.create_command_encoder(&Default::default());
        enc.clear_buffer(&slots, 0, None);
        let b = bind(
            d,
            &self.backward,
            &[
                &fwd.params_buf,
                &fwd.splat,
                &fwd.rect,
                &fwd.ranges,
                &fwd.tval,
                &fwd.egauss,
                &fwd.img,
                &fwd.ncon,
                &vbuf,
                &slots,
            ],
        );
        dispatch_2d(&mut enc, &self.backward, &b, p.tiles_x, p.tiles_y);
        let b = bind(
            d,
            &self.project_bwd,
            &[
                &fwd.params_buf,
                &fwd.pos,
                &fwd.rot,
                &fwd.sh,
                &fwd.splat,
                &fwd.rank,
                &fwd.off,
                &fwd.cnt,
                &slots,
                &vparam,
                &vsh,
            ],
        );
        dispatch(&mut enc, &self.project_bwd, &b, (n as u32).div_ceil(256));
        q.submit([enc.finish()]);
        let r = read_back::<f32>(d, q, &[(&vparam, n * VP), (&vsh, n * 48), (&fwd.img, npx * PIX)])?;
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
        // The background's gradient, sum over pixels of T_N dL/dC (a constant colour).
        if let Some(gc) = grads.color {
            let mut vb = [0.0f64; 3];
            for i in 0..npx {
                let t = img[i * PIX + 10] as f64;
                for ch in 0..3 {
                    vb[ch] += t * gc[i * 3 + ch] as f64;
                }
            }
            g.v_background = vb.iter().map(|&v| v as f32).collect();
        }
        let _ = surfels;
        Ok(GpuGrads { grads: g, accum_weight })
    }
}
