//! Stage 1's loss on the GPU (SPEC 2; svgir_train's `stage1_objective`): L1 + D-SSIM on colour,
//! the mask and entropy terms on opacity, depth-normal consistency and 2DGS's distortion, with
//! the per-pixel output gradients the raster backward reads, from the kernels in
//! `shaders/loss/` (two blur passes forward, two backward, with the depth-normal term's two
//! passes folded into them) and one sum into a ring of per-iteration records that the host
//! reads every few iterations.

use crate::buffers::{bind, dispatch, kernel_of, storage};
use crate::device::Gpu;
use crate::raster::Frame;
use bytemuck::{Pod, Zeroable};
use svgir_core::Camera;
use svgir_train::config::LossWeights;

/// Floats per pixel of a resident photo: RGB, alpha, dilated mask (`TGT` in loss/common.wgsl).
pub(crate) const TGT: usize = 5;
/// Floats per record of the loss ring (`PARTS`): L1, SSIM, mask, entropy, depth-normal,
/// distortion, mean squared error, total.
pub const RECORD: usize = 8;

/// The per-view uniform (`LossParams` in loss/common.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(crate) struct LossParams {
    rt: [[f32; 4]; 3],
    center: [f32; 4],
    k: [f32; 4],
    bg: [f32; 4],
    taps: [f32; 12],
    width: u32,
    height: u32,
    use_mask: u32,
    slot: u32,
    w_l1: f32,
    w_ssim: f32,
    w_mask: f32,
    w_entropy: f32,
    w_dn: f32,
    w_dist: f32,
    groups: u32,
    pad: u32,
}

impl LossParams {
    /// The uniform for a view seen by `camera` over `bg`, with weights `w`, the depth-normal
    /// weight `w_dn` of this iteration, writing ring slot `slot`.
    pub(crate) fn new(camera: &Camera, bg: [f32; 3], w: &LossWeights, w_dn: f32, use_mask: bool, slot: u32) -> Self {
        let rt = camera.rotation.transpose();
        let row = |i: usize| {
            let r = rt.row(i);
            [r.x, r.y, r.z, 0.0]
        };
        let k = camera.intrinsics;
        let c = camera.center();
        let win = svgir_metrics::ssim::gaussian_window::<f32>();
        let mut taps = [0.0; 12];
        taps[..11].copy_from_slice(&win);
        let (width, height) = (camera.width(), camera.height());
        Self {
            rt: [row(0), row(1), row(2)],
            center: [c.x, c.y, c.z, 0.0],
            k: [k.fx, k.fy, k.cx, k.cy],
            bg: [bg[0], bg[1], bg[2], 0.0],
            taps,
            width,
            height,
            use_mask: u32::from(use_mask),
            slot,
            w_l1: w.l1,
            w_ssim: w.ssim,
            w_mask: w.mask,
            w_entropy: w.entropy,
            w_dn,
            w_dist: w.distortion,
            groups: (width * height).div_ceil(256),
            pad: 0,
        }
    }
}

/// The loss kernels.
pub(crate) struct LossKernels {
    ssim_h: wgpu::ComputePipeline,
    ssim_map: wgpu::ComputePipeline,
    ssim_bh: wgpu::ComputePipeline,
    grad: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
}

/// A loss kernel of `body` after the loss kernels' shared declarations.
fn kernel(device: &wgpu::Device, label: &str, body: &str) -> wgpu::ComputePipeline {
    kernel_of(device, label, &[include_str!("shaders/loss/common.wgsl"), body])
}

/// The loss's scratch buffers for images of up to `npx` pixels, its uniform and the ring.
pub(crate) struct LossBuffers {
    params: wgpu::Buffer,
    hbuf: wgpu::Buffer,
    pbuf: wgpu::Buffer,
    qbuf: wgpu::Buffer,
    dbuf: wgpu::Buffer,
    partials: wgpu::Buffer,
    /// `slots` records of [`RECORD`] floats.
    pub(crate) ring: wgpu::Buffer,
}

impl LossBuffers {
    pub(crate) fn new(gpu: &Gpu, npx: u64, slots: u32) -> Self {
        let d = &gpu.device;
        let f = |k: u64| npx * k * 4;
        Self {
            params: crate::buffers::uniform_slot::<LossParams>(d, "loss params"),
            hbuf: storage(d, "ssim moments, horizontal pass", f(15)),
            pbuf: storage(d, "ssim partials", f(9)),
            qbuf: storage(d, "ssim partials, horizontal pass", f(9)),
            dbuf: storage(d, "depth-normal difference gradients", f(6)),
            partials: storage(d, "loss partial sums", npx.div_ceil(256) * RECORD as u64 * 4),
            ring: storage(d, "loss ring", slots as u64 * RECORD as u64 * 4),
        }
    }
}

impl LossKernels {
    pub(crate) fn new(gpu: &Gpu) -> Self {
        let d = &gpu.device;
        Self {
            ssim_h: kernel(d, "loss ssim_h", include_str!("shaders/loss/ssim_h.wgsl")),
            ssim_map: kernel(d, "loss ssim_map", include_str!("shaders/loss/ssim_map.wgsl")),
            ssim_bh: kernel(d, "loss ssim_bh", include_str!("shaders/loss/ssim_bh.wgsl")),
            grad: kernel(d, "loss grad", include_str!("shaders/loss/grad.wgsl")),
            reduce: kernel(d, "loss reduce", include_str!("shaders/loss/reduce.wgsl")),
        }
    }

    /// Records the loss of the render in `frame` against the resident photo `target` (TGT
    /// floats a pixel): the output gradients into `frame.vout`, the iteration's record into
    /// ring slot `params.slot`.
    pub(crate) fn encode(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        frame: &Frame,
        target: &wgpu::Buffer,
        bufs: &LossBuffers,
        params: &LossParams,
    ) {
        let d = &gpu.device;
        gpu.queue.write_buffer(&bufs.params, 0, bytemuck::bytes_of(params));
        let (p, b) = (&bufs.params, bufs);
        let groups = params.groups;
        let g = bind(d, &self.ssim_h, &[p, &frame.img, target, &b.hbuf]);
        dispatch(enc, &self.ssim_h, &g, groups);
        let g = bind(d, &self.ssim_map, &[p, &b.hbuf, &frame.img, &b.pbuf, &b.dbuf, &frame.vout, &b.partials]);
        dispatch(enc, &self.ssim_map, &g, groups);
        let g = bind(d, &self.ssim_bh, &[p, &b.pbuf, &b.qbuf]);
        dispatch(enc, &self.ssim_bh, &g, groups);
        let g = bind(d, &self.grad, &[p, &frame.img, target, &b.qbuf, &b.dbuf, &frame.vout, &b.partials]);
        dispatch(enc, &self.grad, &g, groups);
        let g = bind(d, &self.reduce, &[p, &b.partials, &b.ring]);
        dispatch(enc, &self.reduce, &g, 1);
    }
}

/// A photo as the loss reads it: RGB, alpha (1 without one) and the dilated mask per pixel.
pub(crate) fn photo_record(image: &svgir_core::Image) -> Vec<f32> {
    let (alpha, dilated) = svgir_train::stage1::photo_target(image);
    let n = image.pixel_count();
    let c = image.channels as usize;
    let mut out = vec![0.0f32; n * TGT];
    for i in 0..n {
        for ch in 0..3 {
            out[i * TGT + ch] = image.data[i * c + ch.min(c - 1)];
        }
        out[i * TGT + 3] = alpha[i];
        out[i * TGT + 4] = if dilated[i] { 1.0 } else { 0.0 };
    }
    out
}
