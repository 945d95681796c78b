//! svgir-gpu: svgir's GPU backend on wgpu, with WGSL compute shaders (one source for Vulkan,
//! Metal and DX12; no CUDA toolkit). wgpu loads the system's driver at run time, so a binary
//! with this crate runs on a machine without a GPU and then stays on the CPU.
//!
//! What runs here: all of a stage-1 iteration ([`GpuStage1`]) with its data resident --
//! projection, binning (counts, scan, a stable radix sort of the entries, tile ranges), the
//! forward with every stage-1 output (`raster`), the loss and its output gradients (`loss`), the
//! raster and projection backward, the densification statistics and Adam -- with the same rules
//! as the CPU kernels, against which the tests check each (on Mesa's lavapipe in CI).
//!
//! No kernel uses atomics to add gradients: the raster backward adds each (tile, Gaussian)
//! entry's gradient within the tile's workgroup (subgroup sums, then the subgroups' partials in
//! order) and writes it to that entry's own slot; the projection backward sums each Gaussian's
//! slots in entry order. So there is no float-atomic path and no compare-and-swap fallback to
//! keep apart, and a run's gradients are the same at every run, as on the CPU (SPEC 9.4).
//! Nothing is read back per iteration: the entry count stays on the GPU (see `raster`).

/// Timing tables for `svgir bench` (feature `bench`).
#[cfg(feature = "bench")]
pub mod bench;
pub mod buffers;
pub mod consistency;
pub mod device;
mod exposure;
pub mod features;
pub mod gather;
mod loop_guard;
pub mod loss;
pub mod raster;
mod resident;
pub mod samples;
pub mod shade;
mod sort;
pub mod stage1;
pub mod trace;

pub use device::{open, open_named, AdapterReport, DeviceChoice, Gpu, GpuError, ADAPTER_ENV};
pub use features::GpuFeatureRaster;
pub use raster::{Frame, GpuForward, GpuGrads, GpuRaster, SurfelBuffers, TILE};
pub use shade::GpuShader;
pub use stage1::GpuStage1;
pub use trace::GpuTracer;

/// Test hooks: the adapter the tests run on, and the scan and the sort alone, on host data.
pub mod testing {
    use crate::buffers::{read_back, upload};
    use crate::{Gpu, GpuError};

    /// The adapter the GPU tests run on: the one `SVGIR_GPU_ADAPTER` names, else Mesa's
    /// lavapipe; `None` (the test prints SKIPPED) without one, a panic under
    /// `SVGIR_REQUIRE_GPU=1` (as `.ci/run` sets).
    pub fn test_adapter() -> Option<Gpu> {
        let name = std::env::var(crate::ADAPTER_ENV).unwrap_or_else(|_| "llvmpipe".into());
        match crate::open_named(Some(&name)) {
            Ok(g) => {
                eprintln!("GPU tests on {}", g.report);
                Some(g)
            }
            Err(e) => {
                if std::env::var("SVGIR_REQUIRE_GPU").is_ok_and(|v| v == "1") {
                    panic!("SVGIR_REQUIRE_GPU=1 and no GPU adapter: {e}");
                }
                eprintln!("SKIPPED: no GPU adapter ({e})");
                None
            }
        }
    }

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

    /// The render outputs a loss reads, as the CPU rasterizer returns them.
    pub struct LossInput<'a> {
        /// RGB, `H*W*3`.
        pub color: &'a [f32],
        /// Opacity per pixel.
        pub alpha: &'a [f32],
        /// Un-normalised depth per pixel.
        pub depth: &'a [f32],
        /// Composited normal, `H*W*3`.
        pub normal: &'a [f32],
        /// Distortion per pixel.
        pub distortion: &'a [f32],
    }

    /// Stage 1's loss kernels on one view: the loss record (L1, SSIM, mask, entropy,
    /// depth-normal, distortion, MSE, total) and the output gradients, `VPIX` = 9 floats a
    /// pixel (colour 3, alpha, depth, normal 3, distortion).
    #[allow(clippy::too_many_arguments)]
    pub fn stage1_loss(
        gpu: &Gpu,
        out: &LossInput,
        photo: &svgir_core::Image,
        camera: &svgir_core::Camera,
        bg: [f32; 3],
        weights: &svgir_train::config::LossWeights,
        w_dn: f32,
        use_mask: bool,
    ) -> Result<(Vec<f32>, Vec<f32>), GpuError> {
        use crate::raster::{Frame, PIX, VPIX};
        let npx = camera.width() as usize * camera.height() as usize;
        let mut img = vec![0.0f32; npx * PIX];
        for i in 0..npx {
            let o = &mut img[i * PIX..(i + 1) * PIX];
            o[0..3].copy_from_slice(&out.color[i * 3..i * 3 + 3]);
            o[3] = out.alpha[i];
            o[4] = out.depth[i];
            o[6..9].copy_from_slice(&out.normal[i * 3..i * 3 + 3]);
            o[9] = out.distortion[i];
        }
        let frame = Frame::new(gpu, 1, npx as u64, 1, 0)?;
        gpu.queue.write_buffer(&frame.img, 0, bytemuck::cast_slice(&img));
        let target = upload(&gpu.device, "photo", &crate::loss::photo_record(photo));
        let bufs = crate::loss::LossBuffers::new(gpu, npx as u64, 1);
        let k = crate::loss::LossKernels::new(gpu);
        let p = crate::loss::LossParams::new(camera, bg, weights, w_dn, use_mask, 0);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        k.encode(gpu, &mut enc, &frame, &target, &bufs, &p);
        gpu.queue.submit([enc.finish()]);
        let mut r =
            read_back::<f32>(&gpu.device, &gpu.queue, &[(&bufs.ring, crate::loss::RECORD), (&frame.vout, npx * VPIX)])?;
        let vout = r.pop().unwrap_or_default();
        Ok((r.pop().unwrap_or_default(), vout))
    }

    /// One Adam step of `group` on `params` with gradient `grad`, by the GPU kernel; with
    /// `binary_opacity` > 0 (an opacity group) the binary-opacity term's gradient at that weight
    /// is added first, as the trainer does after densification.
    pub fn adam_step(
        gpu: &Gpu,
        group: &mut svgir_train::adam::AdamGroup,
        params: &mut [f32],
        grad: &[f32],
        binary_opacity: f32,
    ) -> Result<(), GpuError> {
        let d = &gpu.device;
        let rows = (params.len() / group.stride) as u32;
        let mut ap = crate::stage1::AdamParams::step(group, rows, group.stride as u32, 0)?;
        if binary_opacity > 0.0 {
            ap = ap.with_binary_opacity(binary_opacity, rows);
        }
        let k = crate::raster::kernel(d, "adam", include_str!("shaders/adam.wgsl"));
        let u = crate::buffers::uniform(d, "adam params", &ap);
        let (p, g) = (upload(d, "params", params), upload(d, "grad", grad));
        let (m, v) = (upload(d, "m", &group.m), upload(d, "v", &group.v));
        let count = crate::buffers::storage(d, "counters", 32);
        let mut enc = d.create_command_encoder(&Default::default());
        let b = crate::buffers::bind(d, &k, &[&u, &p, &g, &m, &v, &count]);
        crate::buffers::dispatch(&mut enc, &k, &b, (params.len() as u32).div_ceil(256));
        gpu.queue.submit([enc.finish()]);
        let n = params.len();
        let r = read_back::<f32>(d, &gpu.queue, &[(&p, n), (&m, n), (&v, n)])?;
        params.copy_from_slice(&r[0]);
        group.m.copy_from_slice(&r[1]);
        group.v.copy_from_slice(&r[2]);
        Ok(())
    }
}
