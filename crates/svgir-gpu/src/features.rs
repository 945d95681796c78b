//! The feature raster on the GPU: stage 2's PBR pass (SPEC 6) -- per-vertex colour and extra
//! feature tables composited over Gaussians whose geometry is frozen, and its backward to the
//! opacities and the tables -- with the same rules as svgir-raster's kernels
//! ([`svgir_raster::CpuFeatureRaster`]), against which the tests check it.
//!
//! A render records the stage-1 rasterizer's projection and binning ([`GpuRaster`]), then
//! `feat_fwd.wgsl` (a workgroup per tile, the tables read at each hit). The backward runs
//! `feat_bwd.wgsl` (per-entry slots, no atomics) and `feat_sum.wgsl` (per Gaussian and slot
//! float, its entries in order), so its sums are the same at every run. One table holds both:
//! the colours (3 channels a vertex), then the extra channels, with the same vertex count.

use crate::buffers::{bind, dispatch, dispatch_2d, kernel_of, read_back, storage, uniform, upload, LOOP_GUARD};
use crate::device::{Gpu, GpuError};
use crate::raster::{background_grad, check_binding, Frame, GpuRaster, Layout, Params, SurfelBuffers, PARTIALS, SPLAT};
use bytemuck::{Pod, Zeroable};
use svgir_raster::{
    BackgroundOf, ColorSourceOf, FeatureRaster, Grads, OutputGrads, PassGrads, PassState, Projected, RasterConfig,
    RasterError, RenderInput, RenderOutput,
};

/// Most extra channels a vertex (`MAX_EXTRA` in features.wgsl).
pub const MAX_EXTRA: usize = 16;
/// Floats per pixel of the outputs before the extra channels: colour 3, alpha, depth, median
/// depth, final T (feat_fwd.wgsl).
const PIX0: usize = 7;
/// Floats per pixel of the output gradients before the extra channels: colour 3, alpha, depth.
const VPIX0: usize = 5;

/// The feature tables' uniform (`Feat` in features.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Feat {
    m: u32,
    ce: u32,
    lerped: u32,
    fd: u32,
    pix: u32,
    vpix: u32,
    ext_at: u32,
    pad: u32,
}

impl Feat {
    /// The layout of `n` Gaussians' tables with `m` vertices, `ce` extra channels of which
    /// `uniform` hold one value per Gaussian.
    fn new(n: usize, m: usize, ce: usize, uniform: usize) -> Self {
        let lerped = if m > 1 { ce - uniform } else { ce };
        Self {
            m: m as u32,
            ce: ce as u32,
            lerped: lerped as u32,
            fd: (2 + 3 * m + m * ce) as u32,
            pix: (PIX0 + ce) as u32,
            vpix: (VPIX0 + ce) as u32,
            ext_at: (n * m * 3) as u32,
            pad: 0,
        }
    }

    fn layout(&self) -> Layout {
        Layout { slot: self.fd as u64, pix: self.pix as u64, vpix: self.vpix as u64 }
    }
}

/// The compiled kernels, with the stage-1 rasterizer's for the projection and binning.
pub struct GpuFeatureRaster {
    gpu: Gpu,
    raster: GpuRaster,
    forward: wgpu::ComputePipeline,
    backward: wgpu::ComputePipeline,
    sum: wgpu::ComputePipeline,
}

/// A feature render's state on the GPU: its uniforms, binning, outputs and tables (what its
/// backward reads).
pub struct FeatureForward {
    params: Params,
    feat: Feat,
    feat_buf: wgpu::Buffer,
    frame: Frame,
    table: wgpu::Buffer,
}

impl GpuFeatureRaster {
    /// Compiles the kernels on `gpu`.
    pub fn new(gpu: Gpu) -> Self {
        let d = &gpu.device;
        let common = include_str!("shaders/common.wgsl");
        let layout = include_str!("shaders/features.wgsl");
        let interp = include_str!("shaders/feat_interp.wgsl");
        let stage = include_str!("shaders/stage.wgsl");
        let forward = kernel_of(
            d,
            "feat_fwd",
            &[common, layout, stage, interp, LOOP_GUARD, include_str!("shaders/feat_fwd.wgsl")],
        );
        let backward = kernel_of(
            d,
            "feat_bwd",
            &[common, layout, stage, interp, LOOP_GUARD, PARTIALS, include_str!("shaders/feat_bwd.wgsl")],
        );
        let sum = kernel_of(d, "feat_sum", &[common, layout, include_str!("shaders/feat_sum.wgsl")]);
        Self { raster: GpuRaster::new(&gpu), gpu, forward, backward, sum }
    }

    /// Renders `input` with `cfg`: the outputs of svgir-raster's render of the same input
    /// (colour, alpha, depth and median depth, the extra channels; no normals or distortion:
    /// asked for, they are an error), `accum_weight` left empty (the backward returns it).
    pub fn render(&self, input: &RenderInput, cfg: &RasterConfig) -> Result<(RenderOutput, FeatureForward), GpuError> {
        let tables = tables(input, cfg).map_err(|e| GpuError::Runtime(e.to_string()))?;
        self.render_tables(input, cfg, tables)
    }

    /// [`GpuFeatureRaster::render`] of `input`'s checked tables.
    fn render_tables(
        &self,
        input: &RenderInput,
        cfg: &RasterConfig,
        (feat, table, bg): (Feat, Vec<f32>, [f32; 3]),
    ) -> Result<(RenderOutput, FeatureForward), GpuError> {
        let gpu = &self.gpu;
        let surf = SurfelBuffers::upload(gpu, input.surfels)?;
        check_binding(gpu, "the feature tables", table.len() as u64 * 4)?;
        let cam = input.camera;
        let params = Params::new(surf.n, input.surfels.sh_degree, cam, bg, cfg, 0);
        let entries = self.raster.count_entries(gpu, &surf, &params)?;
        let mut params = params;
        params.capacity = entries;
        let npx = cam.width() as u64 * cam.height() as u64;
        let frame = Frame::with_layout(gpu, surf.n, npx, params.tiles(), entries, feat.layout())?;
        let d = &gpu.device;
        let table = upload(d, "feature tables", &table);
        let feat_buf = uniform(d, "feature layout", &feat);
        let mut enc = d.create_command_encoder(&Default::default());
        self.raster.encode_binning(gpu, &mut enc, &surf, &frame, &params);
        let f = &frame;
        let b = bind(
            d,
            &self.forward,
            &[
                &f.params,
                &feat_buf,
                &f.splat,
                &f.rect,
                &f.ranges,
                &f.tval,
                &f.egauss,
                &table,
                &f.img,
                &f.ncon,
                &gpu.status,
            ],
        );
        dispatch_2d(&mut enc, &self.forward, &b, params.tiles_x, params.tiles_y);
        gpu.queue.submit([enc.finish()]);
        let out = read_features(gpu, &params, &feat, &frame)?;
        gpu.check()?;
        Ok((out, FeatureForward { params, feat, feat_buf, frame, table }))
    }

    /// Gradients of a loss with output gradients `grads` (colour, alpha, depth, extra; normal
    /// and distortion must be `None`) for the render `fwd`: svgir-raster's frozen-geometry
    /// backward, and per Gaussian its composited weight.
    pub fn backward(&self, fwd: &FeatureForward, grads: &OutputGrads) -> Result<PassGrads, GpuError> {
        let (gpu, p, ft) = (&self.gpu, &fwd.params, &fwd.feat);
        let (d, q) = (&gpu.device, &gpu.queue);
        let npx = p.width as usize * p.height as usize;
        let (n, ce, fd, vpix) = (p.n as usize, ft.ce as usize, ft.fd as usize, ft.vpix as usize);
        if grads.normal.is_some() || grads.distortion.is_some() {
            return Err(GpuError::Runtime("the GPU feature raster renders no normals or distortion".into()));
        }
        let mut vout = vec![0.0f32; npx * vpix];
        let channels = [(grads.color, 3, 0, "colour"), (grads.alpha, 1, 3, "alpha"), (grads.depth, 1, 4, "depth")];
        for (src, ch, at, what) in channels.into_iter().chain([(grads.extra, ce, VPIX0, "extra")]) {
            let Some(s) = src else { continue };
            if s.len() != npx * ch {
                return Err(GpuError::Runtime(format!(
                    "{what} gradient: expected {} values, got {}",
                    npx * ch,
                    s.len()
                )));
            }
            if ch > 0 {
                for (o, v) in vout.chunks_exact_mut(vpix).zip(s.chunks_exact(ch)) {
                    o[at..at + ch].copy_from_slice(v);
                }
            }
        }
        let f = &fwd.frame;
        q.write_buffer(&f.vout, 0, bytemuck::cast_slice(&vout));
        let vfeat = storage(d, "feature gradients", (n * fd) as u64 * 4);
        let mut enc = d.create_command_encoder(&Default::default());
        enc.clear_buffer(&f.slots, 0, None);
        let u = [&f.params, &fwd.feat_buf];
        let b = bind(
            d,
            &self.backward,
            &[
                u[0],
                u[1],
                &f.splat,
                &f.rect,
                &f.ranges,
                &f.tval,
                &f.egauss,
                &fwd.table,
                &f.img,
                &f.ncon,
                &f.vout,
                &f.slots,
                &gpu.status,
            ],
        );
        dispatch_2d(&mut enc, &self.backward, &b, p.tiles_x, p.tiles_y);
        let b = bind(d, &self.sum, &[u[0], u[1], &f.splat, &f.rank, &f.off, &f.cnt, &f.slots, &vfeat]);
        dispatch(&mut enc, &self.sum, &b, ((n * fd) as u32).div_ceil(256));
        q.submit([enc.finish()]);
        let r = read_back::<f32>(d, q, &[(&vfeat, n * fd), (&f.img, npx * ft.pix as usize)])?;
        gpu.check()?;
        let (vf, img) = (&r[0], &r[1]);
        let (m, ne) = (ft.m as usize, ft.m as usize * ce);
        let mut g = Grads {
            v_positions: vec![glam::Vec3::ZERO; n],
            v_rotations: vec![glam::Quat::from_xyzw(0.0, 0.0, 0.0, 0.0); n],
            v_log_scales: vec![glam::Vec2::ZERO; n],
            v_opacity_logits: Vec::with_capacity(n),
            v_sh: vec![svgir_core::ShCoeffs::default(); n],
            v_color_features: Vec::with_capacity(n * 3 * m),
            v_extra: Vec::with_capacity(n * ne),
            v_background: vec![0.0; 3],
            v_mean2d_norm: vec![0.0; n],
            phases: Default::default(),
        };
        let mut accum_weight = Vec::with_capacity(n);
        for row in vf.chunks_exact(fd) {
            g.v_opacity_logits.push(row[0]);
            accum_weight.push(row[1]);
            g.v_color_features.extend_from_slice(&row[2..2 + 3 * m]);
            g.v_extra.extend_from_slice(&row[2 + 3 * m..]);
        }
        if let Some(gc) = grads.color {
            g.v_background = background_grad(img, ft.pix as usize, 6, gc);
        }
        Ok(PassGrads { grads: g, accum_weight })
    }
}

/// The layout and the one table (colours, then extra channels) of `input`, and its background
/// colour; what the GPU kernels cannot take is an error naming it (after svgir-raster's own
/// checks, with its errors).
fn tables(input: &RenderInput, cfg: &RasterConfig) -> Result<(Feat, Vec<f32>, [f32; 3]), RasterError> {
    input.surfels.check().map_err(RasterError::Surfels)?;
    svgir_raster::check_input(input, cfg)?;
    let refuse = |why: &str| Err(RasterError::Device(format!("the GPU feature raster {why}")));
    if cfg.normals || cfg.distortion {
        return refuse("renders no normals or distortion (RasterConfig::normals and ::distortion must be off)");
    }
    let ColorSourceOf::Features(cf) = &input.colors else {
        return refuse("takes colours from a feature table (SH colours: GpuRaster)");
    };
    let BackgroundOf::Color(bg) = input.background else {
        return refuse("takes a constant background colour");
    };
    let n = input.surfels.len();
    let (ce, uniform) = match &input.extra {
        Some(e) if e.vertices != cf.vertices => {
            return refuse(&format!(
                "needs as many vertices in the extra table ({}) as in the colours' ({})",
                e.vertices, cf.vertices
            ))
        }
        Some(e) if e.channels > MAX_EXTRA => {
            return refuse(&format!("takes at most {MAX_EXTRA} extra channels, got {}", e.channels))
        }
        Some(e) => (e.channels, e.uniform),
        None => (0, 0),
    };
    let feat = Feat::new(n, cf.vertices, ce, uniform);
    let mut table = Vec::with_capacity(cf.data.len() + input.extra.map_or(0, |e| e.data.len()));
    table.extend_from_slice(cf.data);
    if let Some(e) = &input.extra {
        table.extend_from_slice(e.data);
    }
    if table.len() > u32::MAX as usize {
        return refuse("takes tables of at most 2^32 floats");
    }
    Ok((feat, table, bg))
}

/// Reads the images of the feature render last recorded into `frame`.
fn read_features(gpu: &Gpu, p: &Params, ft: &Feat, frame: &Frame) -> Result<RenderOutput, GpuError> {
    let npx = p.width as usize * p.height as usize;
    let n = p.n as usize;
    let pix = ft.pix as usize;
    let ce = ft.ce as usize;
    let r = read_back::<f32>(&gpu.device, &gpu.queue, &[(&frame.img, npx * pix), (&frame.splat, n * SPLAT as usize)])?;
    let rects = read_back::<u32>(&gpu.device, &gpu.queue, &[(&frame.rect, n * 4)])?.remove(0);
    let (img, splat) = (&r[0], &r[1]);
    let mut out = RenderOutput {
        width: p.width,
        height: p.height,
        color: Vec::with_capacity(npx * 3),
        alpha: Vec::with_capacity(npx),
        depth: Vec::with_capacity(npx),
        median_depth: Vec::with_capacity(npx),
        normal: vec![0.0; npx * 3],
        distortion: vec![0.0; npx],
        extra: Vec::with_capacity(npx * ce),
        extra_channels: ce,
        accum_weight: Vec::new(),
        max_radius: vec![0.0; n],
    };
    for o in img.chunks_exact(pix) {
        out.color.extend_from_slice(&o[0..3]);
        out.alpha.push(o[3]);
        out.depth.push(o[4]);
        out.median_depth.push(o[5]);
        out.extra.extend_from_slice(&o[PIX0..]);
    }
    for (g, rc) in rects.chunks_exact(4).enumerate() {
        if rc[0] < rc[1] && rc[2] < rc[3] {
            out.max_radius[g] = splat[g * SPLAT as usize + 23];
        }
    }
    Ok(out)
}

fn device_error(e: GpuError) -> RasterError {
    RasterError::Device(e.to_string())
}

impl FeatureRaster for GpuFeatureRaster {
    fn name(&self) -> String {
        self.gpu.report.name.clone()
    }

    /// Makes its own projection on the GPU (`prior` is the CPU's).
    fn render(
        &self,
        input: &RenderInput,
        cfg: &RasterConfig,
        _prior: &Projected,
    ) -> Result<(RenderOutput, PassState), RasterError> {
        // The kernels' refusals keep their own error; the device's are `Device`.
        let tables = tables(input, cfg)?;
        let (out, fwd) = self.render_tables(input, cfg, tables).map_err(device_error)?;
        Ok((out, Box::new(fwd)))
    }

    fn backward(
        &self,
        _input: &RenderInput,
        _cfg: &RasterConfig,
        state: &PassState,
        _out: &RenderOutput,
        grads: &OutputGrads,
    ) -> Result<PassGrads, RasterError> {
        let fwd = state.downcast_ref::<FeatureForward>().ok_or(RasterError::State)?;
        self.backward(fwd, grads).map_err(device_error)
    }
}
