//! Buffers and dispatches: storage buffers, uploads, read-backs, bind groups, and dispatches split
//! over two grid dimensions where one would pass the 65535-workgroup limit.

use crate::device::GpuError;
use wgpu::util::DeviceExt;

/// Largest workgroup count in one grid dimension (WebGPU's portable limit; lavapipe's too).
pub(crate) const MAX_GROUPS: u32 = 65535;

/// A storage buffer of `bytes` (at least 16, since bindings may not be empty).
pub(crate) fn storage(device: &wgpu::Device, label: &str, bytes: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(16).next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// A storage buffer holding `data` (padded to 16 bytes).
pub(crate) fn upload<T: bytemuck::Pod>(device: &wgpu::Device, label: &str, data: &[T]) -> wgpu::Buffer {
    let bytes: &[u8] = bytemuck::cast_slice(data);
    if bytes.len() >= 16 {
        return device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        });
    }
    let mut padded = [0u8; 16];
    padded[..bytes.len()].copy_from_slice(bytes);
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: &padded,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
    })
}

/// A uniform buffer the size of `T`, written each time it is used (`Queue::write_buffer`).
pub(crate) fn uniform_slot<T>(device: &wgpu::Device, label: &str) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: std::mem::size_of::<T>() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// A uniform buffer holding `value`.
pub(crate) fn uniform<T: bytemuck::Pod>(device: &wgpu::Device, label: &str, value: &T) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: bytemuck::bytes_of(value),
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

/// A compute pipeline, entry point `main`, from the WGSL `parts` joined in order (shared
/// declarations first; the layout is the one the entry point's bindings imply).
/// `guard_loops` (`shaders/loop_guard.wgsl`), for the kernels whose loops run as long as their
/// data (tile lists, ray marches, direction sets), which bind [`Gpu`]'s status buffer.
///
/// [`Gpu`]: crate::Gpu
pub(crate) const LOOP_GUARD: &str = include_str!("shaders/loop_guard.wgsl");

pub(crate) fn kernel_of(device: &wgpu::Device, label: &str, parts: &[&str]) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(parts.join("\n").into()),
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: None,
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    })
}

/// A bind group for group 0 of `pipeline` with `buffers` at bindings 0, 1, ...
pub(crate) fn bind(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry { binding: i as u32, resource: b.as_entire_binding() })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// The grid for `groups` workgroups: `(x, y)` with `x <= MAX_GROUPS`; kernels rebuild the flat
/// index as `wid.x + wid.y * num_workgroups.x` and return beyond their count.
pub(crate) fn grid(groups: u32) -> (u32, u32) {
    if groups <= MAX_GROUPS {
        (groups.max(1), 1)
    } else {
        (MAX_GROUPS, groups.div_ceil(MAX_GROUPS))
    }
}

/// Records one dispatch of `groups` workgroups (flattened, see [`grid`]).
pub(crate) fn dispatch(
    enc: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    bg: &wgpu::BindGroup,
    groups: u32,
) {
    let (x, y) = grid(groups);
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bg, &[]);
    pass.dispatch_workgroups(x, y, 1);
}

/// Records one dispatch of an exact 2D grid (tiles).
pub(crate) fn dispatch_2d(
    enc: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    bg: &wgpu::BindGroup,
    x: u32,
    y: u32,
) {
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bg, &[]);
    pass.dispatch_workgroups(x, y, 1);
}

/// Reads `count` values of type `T` from the start of each buffer, after everything submitted
/// so far (one wait for all of them).
pub(crate) fn read_back<T: bytemuck::Pod>(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    reads: &[(&wgpu::Buffer, usize)],
) -> Result<Vec<Vec<T>>, GpuError> {
    let size = std::mem::size_of::<T>() as u64;
    let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("read back") });
    let staging: Vec<(wgpu::Buffer, usize)> = reads
        .iter()
        .map(|(b, count)| {
            let bytes = (*count as u64 * size).max(4).next_multiple_of(4);
            let s = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("staging"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            if *count > 0 {
                enc.copy_buffer_to_buffer(b, 0, &s, 0, *count as u64 * size);
            }
            (s, *count)
        })
        .collect();
    queue.submit([enc.finish()]);
    for (s, _) in &staging {
        s.slice(..).map_async(wgpu::MapMode::Read, |_| {});
    }
    device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Runtime(e.to_string()))?;
    let mut out = Vec::with_capacity(staging.len());
    for (s, count) in &staging {
        let view = s.slice(..).get_mapped_range().map_err(|e| GpuError::Runtime(format!("{e:?}")))?;
        let v: Vec<T> = bytemuck::cast_slice::<u8, T>(&view[..*count * size as usize]).to_vec();
        drop(view);
        s.unmap();
        out.push(v);
    }
    Ok(out)
}
