//! Exclusive scans and stable radix sorts of u32 (key, value) pairs on the GPU (`scan.wgsl`,
//! `radix.wgsl`), recorded into a command encoder: no read-back between passes.

use crate::buffers::{bind, dispatch, storage, uniform};
use bytemuck::{Pod, Zeroable};

/// Values one scan workgroup handles.
const SCAN_BLOCK: u32 = 1024;
/// Pairs one sort workgroup handles.
const SORT_BLOCK: u32 = 1024;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ScanParams {
    n: u32,
    pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct SortParams {
    n: u32,
    shift: u32,
    blocks: u32,
    counted: u32,
}

/// The scan and sort pipelines.
pub(crate) struct SortKernels {
    scan_block: wgpu::ComputePipeline,
    scan_add: wgpu::ComputePipeline,
    histogram: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    /// Bound as the pair count of a sort whose length the host knows.
    no_count: wgpu::Buffer,
}

fn pipeline(device: &wgpu::Device, module: &wgpu::ShaderModule, entry: &str) -> wgpu::ComputePipeline {
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: None,
        module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    })
}

impl SortKernels {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        let scan = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("scan"),
            source: wgpu::ShaderSource::Wgsl(include_str!("shaders/scan.wgsl").into()),
        });
        let radix = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("radix"),
            source: wgpu::ShaderSource::Wgsl(include_str!("shaders/radix.wgsl").into()),
        });
        Self {
            scan_block: pipeline(device, &scan, "scan_block"),
            scan_add: pipeline(device, &scan, "add"),
            histogram: pipeline(device, &radix, "histogram"),
            scatter: pipeline(device, &radix, "scatter"),
            no_count: storage(device, "no pair count", 16),
        }
    }

    /// Records an exclusive scan of the first `n` u32s of `data`, in place.
    pub(crate) fn scan(&self, device: &wgpu::Device, enc: &mut wgpu::CommandEncoder, data: &wgpu::Buffer, n: u32) {
        if n == 0 {
            return;
        }
        let blocks = n.div_ceil(SCAN_BLOCK);
        let sums = storage(device, "scan sums", blocks as u64 * 4);
        let params = uniform(device, "scan params", &ScanParams { n, pad: [0; 3] });
        let bg = bind(device, &self.scan_block, &[&params, data, &sums]);
        dispatch(enc, &self.scan_block, &bg, blocks);
        if blocks > 1 {
            self.scan(device, enc, &sums, blocks);
            let bg = bind(device, &self.scan_add, &[&params, data, &sums]);
            dispatch(enc, &self.scan_add, &bg, blocks);
        }
    }

    /// Records a stable sort of `n` pairs on the low `bits` bits of the keys (rounded up to
    /// whole 4-bit passes). The sorted pairs end in `keys`/`vals` (the `tmp_*` buffers, of the
    /// same size, are scratch). With `count`, only its first u32's worth of pairs (at most `n`)
    /// are sorted: a length known on the GPU alone, with the dispatch sized for `n`.
    pub(crate) fn sort(
        &self,
        device: &wgpu::Device,
        enc: &mut wgpu::CommandEncoder,
        keys: &wgpu::Buffer,
        vals: &wgpu::Buffer,
        tmp_keys: &wgpu::Buffer,
        tmp_vals: &wgpu::Buffer,
        n: u32,
        bits: u32,
        count: Option<&wgpu::Buffer>,
    ) {
        if n <= 1 {
            return;
        }
        let blocks = n.div_ceil(SORT_BLOCK);
        let counts = storage(device, "sort counts", 16 * blocks as u64 * 4);
        // An even number of passes leaves the result in `keys`.
        let passes = bits.div_ceil(4).next_multiple_of(2);
        for pass in 0..passes {
            let (ki, vi, ko, vo) =
                if pass % 2 == 0 { (keys, vals, tmp_keys, tmp_vals) } else { (tmp_keys, tmp_vals, keys, vals) };
            let counted = u32::from(count.is_some());
            let params = uniform(device, "sort params", &SortParams { n, shift: 4 * pass, blocks, counted });
            let nbuf = count.unwrap_or(&self.no_count);
            let h = bind(device, &self.histogram, &[&params, ki, vi, &counts, ko, vo, nbuf]);
            dispatch(enc, &self.histogram, &h, blocks);
            self.scan(device, enc, &counts, 16 * blocks);
            let s = bind(device, &self.scatter, &[&params, ki, vi, &counts, ko, vo, nbuf]);
            dispatch(enc, &self.scatter, &s, blocks);
        }
    }
}
