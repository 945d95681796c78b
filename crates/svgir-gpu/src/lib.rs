//! svgir-gpu: svgir's GPU backend on wgpu, with WGSL compute shaders (one source for Vulkan,
//! Metal and DX12; no CUDA toolkit). wgpu loads the system's driver at run time, so a binary
//! with this crate runs on a machine without a GPU and then stays on the CPU.
//!
//! What runs here: stage 1's rasterizer -- projection, binning (counts, scan, a stable radix
//! sort of the entries, tile ranges), the forward with every stage-1 output, its backward and the
//! projection backward -- with the same rules as svgir-raster, against whose scalar kernels the
//! tests check it (`tests/raster.rs`, on Mesa's lavapipe in CI).
//!
//! No kernel uses atomics to add gradients: the raster backward adds each (tile, Gaussian)
//! entry's gradient within the tile's workgroup (subgroup sums, then the subgroups' partials in
//! order) and writes it to that entry's own slot; the projection backward sums each Gaussian's
//! slots in entry order. So there is no float-atomic path and no compare-and-swap fallback to
//! keep apart, and a run's gradients are the same at every run, as on the CPU (SPEC 9.4).
//! The one host read-back of a render is the entry count (eight bytes) that sizes the entry
//! buffers.

pub mod buffers;
pub mod device;
pub mod raster;
mod sort;

pub use device::{open, open_named, AdapterReport, DeviceChoice, Gpu, GpuError, ADAPTER_ENV};
pub use raster::{GpuForward, GpuGrads, GpuRaster, TILE};

/// Test hooks: the scan and the sort alone, on host data.
pub mod testing {
    use crate::buffers::{read_back, upload};
    use crate::{Gpu, GpuError};

    /// The exclusive prefix sum of `data` computed on the GPU.
    pub fn exclusive_scan(gpu: &Gpu, data: &[u32]) -> Result<Vec<u32>, GpuError> {
        let k = crate::sort::SortKernels::new(&gpu.device);
        let buf = upload(&gpu.device, "scan test", data);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        k.scan(&gpu.device, &mut enc, &buf, data.len() as u32);
        gpu.queue.submit([enc.finish()]);
        Ok(read_back::<u32>(&gpu.device, &gpu.queue, &[(&buf, data.len())])?.remove(0))
    }

    /// `(keys, vals)` sorted stably on the low `bits` bits of the keys, on the GPU.
    pub fn sort_pairs(gpu: &Gpu, keys: &[u32], vals: &[u32], bits: u32) -> Result<(Vec<u32>, Vec<u32>), GpuError> {
        let k = crate::sort::SortKernels::new(&gpu.device);
        let d = &gpu.device;
        let (kb, vb) = (upload(d, "keys", keys), upload(d, "vals", vals));
        let (k2, v2) = (upload(d, "keys2", keys), upload(d, "vals2", vals));
        let mut enc = d.create_command_encoder(&Default::default());
        k.sort(d, &mut enc, &kb, &vb, &k2, &v2, keys.len() as u32, bits, None);
        gpu.queue.submit([enc.finish()]);
        let mut r = read_back::<u32>(d, &gpu.queue, &[(&kb, keys.len()), (&vb, vals.len())])?;
        let v = r.pop().unwrap_or_default();
        Ok((r.pop().unwrap_or_default(), v))
    }
}
