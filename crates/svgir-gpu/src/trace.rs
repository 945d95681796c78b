//! Micro-buffers on the GPU (SPEC 5): the all-hits march with transmittance of
//! `svgir_trace::traverse` in `shaders/trace.wgsl`, over the CPU's BVH uploaded as is.
//!
//! The BVH is built on the CPU (`svgir_trace::Bvh`, binned SAH): its flat 32-byte nodes and
//! 64-byte disks are already the GPU layout, and building it is a small share of a trace (on 2
//! cores, 0.1 s of the 30 s a K = 64 fill of 73k Gaussians takes). Each Gaussian's ray source
//! and hemisphere frame (`svgir_shading::HemiFrame`) and the Fibonacci table are prepared on the
//! host too, so the kernel makes no sine, cosine or f64 remainder.
//!
//! Rays run in chunks of [`CHUNK`] (one dispatch each, bound at an offset of one output
//! buffer), and chunks in batches of at most [`BATCH_BYTES`] of samples, read back per batch:
//! a K = 384 relighting trace of a large scene never needs its 1.8 GB at once.
//!
//! The samples are the CPU's to the rules: the same hits in the same (t, id) order, the same
//! packing (16 bytes a sample: V u16 unorm, L 3 x f16 rounded to nearest even, the first hit,
//! (u~, v~) 2 x u16 unorm). The directions and the plane crossings differ from the CPU's only
//! by f32 rounding (the driver may fuse multiply-adds; `exp` and `pow` are its own), which
//! moves a hit only where it sits on a boundary of the rules (r^2 = 9, alpha = 1/255, a
//! continuation offset); the tests count those.

use crate::buffers::{grid, kernel_of, read_back, storage, upload};
use crate::device::{Gpu, GpuError};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use svgir_core::Surfels;
use svgir_shading::gaussian_xi;
use svgir_shading::hemisphere::{FibTable, HemiFrame};
use svgir_trace::{
    recorded_hit, Bvh, Interleave, MicroBuffer, MicroTracer, TraceError, TraceParams, TraceRequest, NO_HIT,
};

/// Rays per dispatch.
pub const CHUNK: u32 = 1 << 20;
/// Most bytes of samples per read-back.
pub const BATCH_BYTES: u64 = 256 << 20;
/// Bytes per packed sample on the GPU (`samples` in trace.wgsl).
const SAMPLE: u64 = crate::samples::SAMPLE_BYTES;

/// The kernel's uniform (`TraceParams` in trace.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Uniform {
    t_max: f32,
    eps: f32,
    eps_scale: f32,
    t_stop: f32,
    v_cut: f32,
    l_max: f32,
    vis_gain: f32,
    _pad0: f32,
    nodes: u32,
    k: u32,
    base: u32,
    count: u32,
    sh_degree: u32,
    flags: u32,
    record_max: u32,
    _pad1: u32,
}

const F_CULL: u32 = 1;
const F_LINEAR: u32 = 2;
const F_RADIANCE: u32 = 4;
const F_RECORD: u32 = 8;
const F_FIXED: u32 = 16;

/// One recorded hit of [`GpuTracer::record`]: what the march consumed, in order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordedHit {
    /// Ray parameter.
    pub t: f32,
    /// Gaussian hit.
    pub id: u32,
    /// Its alpha.
    pub alpha: f32,
    /// Tangent coordinates, sigma units.
    pub u: f32,
    /// The second tangent coordinate.
    pub v: f32,
}

/// What one ray of [`GpuTracer::record`] did: its direction and the hits it consumed.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordedRay {
    /// The direction the kernel traced.
    pub dir: Vec3,
    /// Hits consumed in all.
    pub hits: u32,
    /// The first `record_max` of them.
    pub recorded: Vec<RecordedHit>,
}

/// A run's packed samples (4 words each) and, when recording, its record vec4s.
type Traced = (Vec<[u32; 4]>, Vec<[f32; 4]>);

/// The micro-buffer tracer on a GPU.
pub struct GpuTracer {
    gpu: Gpu,
    kernel: wgpu::ComputePipeline,
    gather: crate::gather::Gather,
}

/// A trace's scene on the GPU: the BVH, the disks, the SH and the ray sources.
struct Scene {
    nodes: wgpu::Buffer,
    disks: wgpu::Buffer,
    sh: wgpu::Buffer,
    sources: wgpu::Buffer,
    fib: wgpu::Buffer,
    uniform: Uniform,
    rays: u64,
    /// The azimuth offsets the sources were made with (`gaussian_xi`), for the micro-buffer.
    xi: Vec<f32>,
}

impl GpuTracer {
    /// The tracer on `gpu` (compiles its kernel).
    pub fn new(gpu: Gpu) -> Self {
        let parts =
            [include_str!("shaders/common.wgsl"), crate::buffers::LOOP_GUARD, include_str!("shaders/trace.wgsl")];
        let kernel = kernel_of(&gpu.device, "trace", &parts);
        let gather = crate::gather::Gather::new(&gpu);
        Self { gpu, kernel, gather }
    }

    /// The device it runs on.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// Rays per gather dispatch (`gather::PAIRS`; the tests lower it to split small scenes).
    pub fn set_gather_batch(&mut self, pairs: usize) {
        self.gather.pairs = pairs.max(1);
    }

    /// `svgir_trace::MicroTracer::trace` on the GPU: the micro-buffers `req` asks for, of every
    /// Gaussian of `surfels` through `bvh` (built over them).
    pub fn micro_buffer(&self, bvh: &Bvh, surfels: &Surfels, req: TraceRequest) -> Result<MicroBuffer, GpuError> {
        let scene = self.scene(bvh, surfels, &req, None)?;
        let (k, normals) = (req.k, req.axes);
        let words = self.run(&scene, None)?.0;
        let n = words.len();
        let mut mb = MicroBuffer {
            k,
            normals,
            xi: scene.xi,
            vis: Vec::with_capacity(n),
            radiance: Vec::with_capacity(n),
            first_hit: Vec::with_capacity(n),
            uv: Vec::with_capacity(n),
            interleave: Interleave::default(),
        };
        crate::samples::unpack_into(&words, &mut mb);
        // Hits past the ray sources are the surroundings' (MicroBuffer::traced's rule).
        let sources = mb.len();
        for (h, uv) in mb.first_hit.iter_mut().zip(mb.uv.iter_mut()).filter(|(h, _)| **h != NO_HIT) {
            (*h, *uv) = recorded_hit(*h, *uv, sources);
        }
        Ok(mb)
    }

    /// The micro-buffer march of every ray of `req` (j * K + k order) with its direction and
    /// its first `record_max` consumed hits (for the tests against the CPU traversal).
    pub fn record(
        &self,
        bvh: &Bvh,
        surfels: &Surfels,
        req: TraceRequest,
        record_max: u32,
    ) -> Result<Vec<RecordedRay>, GpuError> {
        let scene = self.scene(bvh, surfels, &req, None)?;
        let rec = self.run(&scene, Some(record_max))?.1;
        let per = 1 + 2 * record_max as usize;
        Ok(rec
            .chunks(per)
            .map(|r| {
                let hits = r[0][3].to_bits();
                let recorded = (0..hits.min(record_max) as usize)
                    .map(|h| {
                        let (a, b) = (r[1 + 2 * h], r[2 + 2 * h]);
                        RecordedHit { t: a[0], id: a[1].to_bits(), alpha: a[2], u: a[3], v: b[0] }
                    })
                    .collect();
                RecordedRay { dir: Vec3::new(r[0][0], r[0][1], r[0][2]), hits, recorded }
            })
            .collect())
    }

    /// `svgir_trace::MicroTracer::visibility_columns` on the GPU: one ray per (Gaussian,
    /// direction), all directions in one trace.
    pub fn columns(
        &self,
        bvh: &Bvh,
        surfels: &Surfels,
        normals: &[Vec3],
        dirs: &[Vec3],
        p: &TraceParams,
    ) -> Result<Vec<Vec<u16>>, GpuError> {
        if dirs.is_empty() {
            return Ok(Vec::new());
        }
        let b = dirs.len();
        let req = TraceRequest { axes: normals.to_vec(), k: b, seed: 0, params: p, radiance: false };
        let scene = self.scene(bvh, surfels, &req, Some(dirs))?;
        let words = self.run(&scene, None)?.0;
        Ok((0..b).map(|l| words.iter().skip(l).step_by(b).map(|w| (w[0] & 0xffff) as u16).collect()).collect())
    }

    /// `req`'s scene on the GPU; with `fixed`, the directions themselves (one per k, the same
    /// for every Gaussian) instead of the Fibonacci table.
    fn scene(
        &self,
        bvh: &Bvh,
        surfels: &Surfels,
        req: &TraceRequest,
        fixed: Option<&[Vec3]>,
    ) -> Result<Scene, GpuError> {
        let TraceRequest { axes: normals, k, seed, params: p, radiance: with_radiance } = req;
        let (k, seed, with_radiance) = (*k, *seed, *with_radiance);
        MicroBuffer::check_inputs(surfels, normals, k).map_err(|e| GpuError::Runtime(e.to_string()))?;
        if bvh.max_scales.len() != surfels.len() {
            return Err(GpuError::Runtime(format!(
                "a BVH over {} Gaussians for a trace of {}",
                bvh.max_scales.len(),
                surfels.len()
            )));
        }
        // Rays leave the first `normals.len()` Gaussians; the rest are surroundings.
        let sources = normals.len();
        let rays = sources as u64 * k as u64;
        if rays > u32::MAX as u64 {
            return Err(GpuError::Runtime(format!("{rays} rays: over the kernel's u32 ray index")));
        }
        let limit = self.gpu.report.max_storage_binding;
        for (what, bytes) in scene_buffers(bvh, surfels.len()) {
            if bytes > limit {
                return Err(GpuError::TooLarge { what, bytes, limit });
            }
        }
        let d = &self.gpu.device;
        let xi: Vec<f32> = (0..sources).map(|j| gaussian_xi(seed, j)).collect();
        // Ray::from_gaussian's start and HemiFrame's parts, per ray source.
        let sources: Vec<[f32; 4]> = (0..sources)
            .flat_map(|j| {
                let sc = surfels.scale(j);
                let t_start = p.t_min + p.t_min_scale * sc.x.max(sc.y);
                let (b1, b2, n, cx, sx) = HemiFrame::new(normals[j], xi[j]).parts();
                let o = surfels.positions[j];
                [[o.x, o.y, o.z, t_start], [b1.x, b1.y, b1.z, cx], [b2.x, b2.y, b2.z, sx], [n.x, n.y, n.z, 0.0]]
            })
            .collect();
        let fib: Vec<[f32; 4]> = match fixed {
            Some(dirs) => dirs.iter().map(|d| [d.x, d.y, d.z, 0.0]).collect(),
            None => {
                let table = FibTable::new(k);
                let [c, s, r, z] = table.rows();
                (0..k).map(|i| [c[i], s[i], r[i], z[i]]).collect()
            }
        };
        let flags = if p.cull_backfaces { F_CULL } else { 0 }
            | if fixed.is_some() { F_FIXED } else { 0 }
            | if p.linear_radiance { F_LINEAR } else { 0 }
            | if with_radiance { F_RADIANCE } else { 0 };
        let uniform = Uniform {
            // The kernel compares against t_max only; f32::MAX keeps infinities out of uniforms.
            t_max: p.t_max.min(f32::MAX),
            eps: p.eps,
            eps_scale: p.eps_scale,
            t_stop: p.t_stop,
            v_cut: p.v_cut,
            l_max: p.l_max,
            vis_gain: p.visibility_alpha_gain,
            _pad0: 0.0,
            nodes: bvh.nodes.len() as u32,
            k: k as u32,
            base: 0,
            count: 0,
            sh_degree: surfels.sh_degree.min(p.radiance_sh_degree).min(3),
            flags,
            record_max: 0,
            _pad1: 0,
        };
        Ok(Scene {
            nodes: upload(d, "bvh nodes", &bvh.nodes),
            disks: upload(d, "bvh disks", &bvh.disks),
            sh: upload(d, "sh", bytemuck::cast_slice::<_, f32>(&surfels.sh)),
            sources: upload(d, "ray sources", &sources),
            fib: upload(d, "fibonacci table", &fib),
            uniform,
            rays,
            xi,
        })
    }

    /// Every ray of `scene`: its packed samples, and with `record` its recorded hits.
    fn run(&self, scene: &Scene, record: Option<u32>) -> Result<Traced, GpuError> {
        let d = &self.gpu.device;
        let mut words = Vec::with_capacity(scene.rays as usize);
        let mut recorded = Vec::new();
        let per_batch = (BATCH_BYTES / SAMPLE).max(CHUNK as u64);
        let mut base = 0u64;
        while base < scene.rays {
            let count = per_batch.min(scene.rays - base);
            let out = storage(d, "trace samples", count * SAMPLE);
            let rec_vec4 = record.map_or(1, |m| count * (1 + 2 * m as u64));
            let rec = storage(d, "trace record", rec_vec4 * 16);
            let mut enc = d.create_command_encoder(&Default::default());
            let mut off = 0u64;
            while off < count {
                let n = (CHUNK as u64).min(count - off);
                let u = Uniform {
                    base: (base + off) as u32,
                    count: n as u32,
                    flags: scene.uniform.flags | if record.is_some() { F_RECORD } else { 0 },
                    record_max: record.unwrap_or(0),
                    ..scene.uniform
                };
                let ub = crate::buffers::uniform(d, "trace params", &u);
                let rec_per = record.map_or(0, |m| 16 * (1 + 2 * m as u64));
                let rec_binding =
                    if record.is_some() { bytes(&rec, off * rec_per, n * rec_per) } else { rec.as_entire_binding() };
                let entries = [
                    ub.as_entire_binding(),
                    scene.nodes.as_entire_binding(),
                    scene.disks.as_entire_binding(),
                    scene.sh.as_entire_binding(),
                    scene.sources.as_entire_binding(),
                    scene.fib.as_entire_binding(),
                    bytes(&out, off * SAMPLE, n * SAMPLE),
                    rec_binding,
                    self.gpu.status.as_entire_binding(),
                ];
                let entries: Vec<wgpu::BindGroupEntry> = entries
                    .into_iter()
                    .enumerate()
                    .map(|(i, resource)| wgpu::BindGroupEntry { binding: i as u32, resource })
                    .collect();
                let bg = d.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("trace"),
                    layout: &self.kernel.get_bind_group_layout(0),
                    entries: &entries,
                });
                let (x, y) = grid((n as u32).div_ceil(64));
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.kernel);
                pass.set_bind_group(0, &bg, &[]);
                pass.dispatch_workgroups(x, y, 1);
                drop(pass);
                off += n;
            }
            self.gpu.queue.submit([enc.finish()]);
            let mut r = read_back::<u32>(d, &self.gpu.queue, &[(&out, count as usize * 4)])?;
            words.extend(bytemuck::cast_slice::<u32, [u32; 4]>(&r.remove(0)));
            if record.is_some() {
                let r = read_back::<[f32; 4]>(d, &self.gpu.queue, &[(&rec, rec_vec4 as usize)])?;
                recorded.extend_from_slice(&r[0]);
            }
            self.gpu.check()?;
            base += count;
        }
        Ok((words, recorded))
    }
}

/// The buffers of a trace's scene over `n` Gaussians and their bytes: nodes, disks, SH and
/// ray sources (the Fibonacci table is K x 16 bytes).
fn scene_buffers(bvh: &Bvh, n: usize) -> [(&'static str, u64); 4] {
    [
        ("the BVH's nodes", bvh.nodes.len() as u64 * 32),
        ("the BVH's disks", bvh.disks.len() as u64 * 64),
        ("the SH coefficients", n as u64 * 192),
        ("the ray sources", n as u64 * 64),
    ]
}

/// GPU bytes of a trace's scene (the samples come on top, 16 bytes each, at most
/// [`BATCH_BYTES`] at a time).
pub fn scene_bytes(bvh: &Bvh, n: usize) -> u64 {
    scene_buffers(bvh, n).iter().map(|(_, b)| b).sum()
}

/// Bytes `at .. at + len` of `buffer` as a binding.
fn bytes(buffer: &wgpu::Buffer, at: u64, len: u64) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::Buffer(wgpu::BufferBinding { buffer, offset: at, size: std::num::NonZeroU64::new(len) })
}

impl MicroTracer for GpuTracer {
    fn name(&self) -> String {
        self.gpu.report.name.clone()
    }

    fn trace(&self, bvh: &Bvh, surfels: &Surfels, req: TraceRequest) -> Result<MicroBuffer, TraceError> {
        self.micro_buffer(bvh, surfels, req).map_err(|e| TraceError::Device(e.to_string()))
    }

    fn visibility_columns(
        &self,
        bvh: &Bvh,
        surfels: &Surfels,
        normals: &[Vec3],
        dirs: &[Vec3],
        p: &TraceParams,
    ) -> Result<Vec<Vec<u16>>, TraceError> {
        self.columns(bvh, surfels, normals, dirs, p).map_err(|e| TraceError::Device(e.to_string()))
    }

    fn gather_all(
        &self,
        mb: &MicroBuffer,
        mats: &svgir_trace::VertexMaterials<f32>,
        env: &svgir_core::EnvMap,
        p: &svgir_trace::GatherParams,
    ) -> Result<Vec<[f32; 3]>, TraceError> {
        let side = svgir_trace::HitSide { mb, mats: *mats, lights: p.lights };
        self.gather.run(&self.gpu, mb, &[side], env, p)
    }

    fn gather_two_sided(
        &self,
        rays: &MicroBuffer,
        front: svgir_trace::HitSide,
        back: svgir_trace::HitSide,
        env: &svgir_core::EnvMap,
        p: &svgir_trace::GatherParams,
    ) -> Result<Vec<[f32; 3]>, TraceError> {
        self.gather.run(&self.gpu, rays, &[front, back], env, p)
    }
}
