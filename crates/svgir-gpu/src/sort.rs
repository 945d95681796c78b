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

    /// Records an exclusive scan of the first `n` u32s of `data`, in place (buffers made here).
    pub(crate) fn scan(&self, device: &wgpu::Device, enc: &mut wgpu::CommandEncoder, data: &wgpu::Buffer, n: u32) {
        let plan = scan_plan(device, n);
        self.scan_with(device, enc, data, &plan);
    }

    /// Records the exclusive scan `plan` was made for of `data`, in place: each level's blocks
    /// scanned and their sums written to the next level, then each level's offsets added back,
    /// from the top.
    pub(crate) fn scan_with(
        &self,
        device: &wgpu::Device,
        enc: &mut wgpu::CommandEncoder,
        data: &wgpu::Buffer,
        plan: &ScanPlan,
    ) {
        let l = &plan.levels;
        for i in 0..l.len() {
            let src = if i == 0 { data } else { &l[i - 1].1 };
            let bg = bind(device, &self.scan_block, &[&l[i].0, src, &l[i].1]);
            dispatch(enc, &self.scan_block, &bg, l[i].2.div_ceil(SCAN_BLOCK));
        }
        for i in (0..l.len().saturating_sub(1)).rev() {
            let src = if i == 0 { data } else { &l[i - 1].1 };
            let bg = bind(device, &self.scan_add, &[&l[i].0, src, &l[i].1]);
            dispatch(enc, &self.scan_add, &bg, l[i].2.div_ceil(SCAN_BLOCK));
        }
    }

    /// Records a stable sort of `n` pairs on the low `bits` bits of the keys (rounded up to
    /// whole 4-bit passes), buffers made here. See [`SortKernels::sort_with`].
    #[allow(clippy::too_many_arguments)]
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
        let plan = sort_plan(device, n, bits, count.is_some());
        self.sort_with(device, enc, [keys, vals, tmp_keys, tmp_vals], &plan, count);
    }

    /// Records the sort `plan` was made for: the sorted pairs end in `keys`/`vals` (the first two
    /// of `bufs`; the other two, of the same size, are scratch). With `count` (a plan made
    /// `counted`), only its first u32's worth of pairs (at most the plan's) are sorted: a length
    /// known on the GPU alone, with the dispatch sized for the plan.
    pub(crate) fn sort_with(
        &self,
        device: &wgpu::Device,
        enc: &mut wgpu::CommandEncoder,
        bufs: [&wgpu::Buffer; 4],
        plan: &SortPlan,
        count: Option<&wgpu::Buffer>,
    ) {
        if plan.n <= 1 {
            return;
        }
        let [keys, vals, tmp_keys, tmp_vals] = bufs;
        let nbuf = count.unwrap_or(&self.no_count);
        for (pass, params) in plan.passes.iter().enumerate() {
            let (ki, vi, ko, vo) =
                if pass % 2 == 0 { (keys, vals, tmp_keys, tmp_vals) } else { (tmp_keys, tmp_vals, keys, vals) };
            let h = bind(device, &self.histogram, &[params, ki, vi, &plan.counts, ko, vo, nbuf]);
            dispatch(enc, &self.histogram, &h, plan.blocks);
            self.scan_with(device, enc, &plan.counts, &plan.scan);
            let s = bind(device, &self.scatter, &[params, ki, vi, &plan.counts, ko, vo, nbuf]);
            dispatch(enc, &self.scatter, &s, plan.blocks);
        }
    }
}

/// The buffers of a scan of `n` values: per level of the recursion its uniform and the
/// block sums (made once, reused by every scan of that length).
pub(crate) fn scan_plan(device: &wgpu::Device, n: u32) -> ScanPlan {
    let mut levels = Vec::new();
    let mut m = n;
    while m > 0 {
        let blocks = m.div_ceil(SCAN_BLOCK);
        let params = uniform(device, "scan params", &ScanParams { n: m, pad: [0; 3] });
        levels.push((params, storage(device, "scan sums", blocks as u64 * 4), m));
        if blocks <= 1 {
            break;
        }
        m = blocks;
    }
    ScanPlan { levels }
}

/// The buffers of one scan length (see [`scan_plan`]).
pub(crate) struct ScanPlan {
    levels: Vec<(wgpu::Buffer, wgpu::Buffer, u32)>,
}

/// The buffers of a sort of `n` pairs on `bits` bits, its length `counted` on the GPU or not.
pub(crate) fn sort_plan(device: &wgpu::Device, n: u32, bits: u32, counted: bool) -> SortPlan {
    let blocks = n.div_ceil(SORT_BLOCK).max(1);
    // An even number of passes leaves the result in the input buffers.
    let passes = bits.div_ceil(4).next_multiple_of(2);
    let counted = u32::from(counted);
    SortPlan {
        n,
        blocks,
        counts: storage(device, "sort counts", 16 * blocks as u64 * 4),
        passes: (0..passes)
            .map(|p| uniform(device, "sort params", &SortParams { n, shift: 4 * p, blocks, counted }))
            .collect(),
        scan: scan_plan(device, 16 * blocks),
    }
}

/// The buffers of one sort (see [`sort_plan`]).
pub(crate) struct SortPlan {
    n: u32,
    blocks: u32,
    counts: wgpu::Buffer,
    passes: Vec<wgpu::Buffer>,
    scan: ScanPlan,
}
