//! The per-photo colour correction of stage 1 (`--exposure`, svgir_train::exposure, which is
//! its oracle) on the GPU, resident with the rest of an iteration: every training photo's 3x3
//! matrix and offset and their Adam moments live in GPU buffers, a row of 64 floats a photo (12
//! used) so that the photo's row binds at a 256-byte offset.
//!
//! In an iteration, between the raster forward and its backward (`shaders/exposure/`):
//! `apply` turns the render's colour into its object's corrected colour over the background in
//! place, for the loss, saving the colour; after the loss `backward` turns the colour gradient
//! into `A^T v`, adds the opacity's share, puts the render's colour back and sums the 12
//! parameter gradients per workgroup; `sum` adds the workgroups in order, and the photo's row
//! takes one step of the Adam kernel (`adam.wgsl`). No atomics, nothing read back; the host
//! counts each photo's Adam steps, as the CPU does.

use crate::buffers::{bind, dispatch, kernel_of, read_back, storage, uniform_slot, upload};
use crate::device::{Gpu, GpuError};
use crate::raster::Frame;
use crate::stage1::AdamParams;
use bytemuck::{Pod, Zeroable};
use svgir_train::exposure::{ExposureCorrection, PARAMS};

/// Floats of a photo's row in the resident buffers (256 bytes, the binding-offset alignment).
const ROW: usize = 64;

/// The `ExposureParams` uniform of `shaders/exposure/common.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Uniform {
    npx: u32,
    row: u32,
    groups: u32,
    pad: u32,
    bg: [f32; 4],
}

/// The correction's kernels and resident state, for renders of up to `npx` pixels.
pub(crate) struct GpuExposure {
    apply: wgpu::ComputePipeline,
    backward: wgpu::ComputePipeline,
    sum: wgpu::ComputePipeline,
    /// Per photo a row: parameters, first and second moments.
    params: wgpu::Buffer,
    m: wgpu::Buffer,
    v: wgpu::Buffer,
    /// The render's colour while the loss reads the corrected one (3 floats a pixel).
    raw: wgpu::Buffer,
    partials: wgpu::Buffer,
    grad: wgpu::Buffer,
    uniform: wgpu::Buffer,
    adam_uniform: wgpu::Buffer,
    photos: usize,
}

fn kernel(device: &wgpu::Device, label: &str, body: &str) -> wgpu::ComputePipeline {
    kernel_of(device, label, &[include_str!("shaders/exposure/common.wgsl"), body])
}

/// `rows` of 12 floats spread to rows of [`ROW`].
fn spread(rows: impl Iterator<Item = [f32; PARAMS]>) -> Vec<f32> {
    rows.flat_map(|r| {
        let mut row = [0.0f32; ROW];
        row[..PARAMS].copy_from_slice(&r);
        row
    })
    .collect()
}

impl GpuExposure {
    /// Uploads the corrections `e` (parameters and moments) for renders of up to `npx` pixels.
    pub(crate) fn new(gpu: &Gpu, e: &ExposureCorrection, npx: u64) -> Result<Self, GpuError> {
        let d = &gpu.device;
        let row = |x: &[f32]| -> [f32; PARAMS] { x.try_into().unwrap_or([0.0; PARAMS]) };
        if e.adam.iter().any(|a| a.m.len() != PARAMS || a.v.len() != PARAMS) || e.adam.len() != e.params.len() {
            return Err(GpuError::Runtime("the exposure correction's Adam state does not match its photos".into()));
        }
        Ok(Self {
            apply: kernel(d, "exposure apply", include_str!("shaders/exposure/apply.wgsl")),
            backward: kernel(d, "exposure backward", include_str!("shaders/exposure/backward.wgsl")),
            sum: kernel(d, "exposure sum", include_str!("shaders/exposure/sum.wgsl")),
            params: upload(d, "exposure params", &spread(e.params.iter().copied())),
            m: upload(d, "exposure adam m", &spread(e.adam.iter().map(|a| row(&a.m)))),
            v: upload(d, "exposure adam v", &spread(e.adam.iter().map(|a| row(&a.v)))),
            raw: storage(d, "exposure raw colour", npx * 3 * 4),
            partials: storage(d, "exposure partials", npx.div_ceil(256) * PARAMS as u64 * 4),
            grad: storage(d, "exposure grad", PARAMS as u64 * 4),
            uniform: uniform_slot::<Uniform>(d, "exposure params uniform"),
            adam_uniform: uniform_slot::<AdamParams>(d, "exposure adam uniform"),
            photos: e.params.len(),
        })
    }

    fn write_uniform(&self, gpu: &Gpu, photo: usize, npx: u32, bg: [f32; 3]) -> u32 {
        let groups = npx.div_ceil(256);
        let u = Uniform { npx, row: (photo * ROW) as u32, groups, pad: 0, bg: [bg[0], bg[1], bg[2], 0.0] };
        gpu.queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&u));
        groups
    }

    /// Records the forward on the render in `frame` (`npx` pixels, composited over `bg`) of
    /// training photo `photo`; the backward reads the same settings.
    pub(crate) fn encode_forward(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        frame: &Frame,
        photo: usize,
        npx: u32,
        bg: [f32; 3],
    ) {
        let groups = self.write_uniform(gpu, photo, npx, bg);
        let b = bind(&gpu.device, &self.apply, &[&self.uniform, &self.params, &frame.img, &self.raw]);
        dispatch(enc, &self.apply, &b, groups);
    }

    /// Records the backward after the loss, and photo `photo`'s Adam step with the kernel
    /// `adam` (its steps counted in `e`, the host's state).
    pub(crate) fn encode_backward_and_step(
        &self,
        gpu: &Gpu,
        enc: &mut wgpu::CommandEncoder,
        frame: &Frame,
        adam: &wgpu::ComputePipeline,
        e: &mut ExposureCorrection,
        photo: usize,
        npx: u32,
    ) -> Result<(), GpuError> {
        let d = &gpu.device;
        let groups = npx.div_ceil(256);
        let b =
            bind(d, &self.backward, &[&self.uniform, &self.params, &self.raw, &frame.vout, &frame.img, &self.partials]);
        dispatch(enc, &self.backward, &b, groups);
        let b = bind(d, &self.sum, &[&self.uniform, &self.partials, &self.grad]);
        dispatch(enc, &self.sum, &b, 1);
        let ap = AdamParams::step(&mut e.adam[photo], 1, PARAMS as u32, 0)?;
        gpu.queue.write_buffer(&self.adam_uniform, 0, bytemuck::bytes_of(&ap));
        fn at(buf: &wgpu::Buffer, photo: usize) -> wgpu::BufferBinding<'_> {
            wgpu::BufferBinding {
                buffer: buf,
                offset: (photo * ROW * 4) as u64,
                size: wgpu::BufferSize::new((PARAMS * 4) as u64),
            }
        }
        let entries = [
            self.adam_uniform.as_entire_binding(),
            wgpu::BindingResource::Buffer(at(&self.params, photo)),
            self.grad.as_entire_binding(),
            wgpu::BindingResource::Buffer(at(&self.m, photo)),
            wgpu::BindingResource::Buffer(at(&self.v, photo)),
            frame.count.as_entire_binding(),
        ];
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .into_iter()
            .enumerate()
            .map(|(i, resource)| wgpu::BindGroupEntry { binding: i as u32, resource })
            .collect();
        let b = d.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("exposure adam"),
            layout: &adam.get_bind_group_layout(0),
            entries: &entries,
        });
        dispatch(enc, adam, &b, 1);
        Ok(())
    }

    /// Reads the parameters and moments into `e`.
    pub(crate) fn download_into(&self, gpu: &Gpu, e: &mut ExposureCorrection) -> Result<(), GpuError> {
        let n = self.photos * ROW;
        let r = read_back::<f32>(&gpu.device, &gpu.queue, &[(&self.params, n), (&self.m, n), (&self.v, n)])?;
        for i in 0..self.photos.min(e.params.len()) {
            let row = |x: &[f32]| -> [f32; PARAMS] { x[i * ROW..i * ROW + PARAMS].try_into().unwrap_or([0.0; PARAMS]) };
            e.params[i] = row(&r[0]);
            e.adam[i].m.copy_from_slice(&row(&r[1]));
            e.adam[i].v.copy_from_slice(&row(&r[2]));
        }
        Ok(())
    }
}
