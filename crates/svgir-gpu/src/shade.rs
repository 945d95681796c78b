//! Vertex shading on the GPU (SPEC 4, 5): svgir_pbr's `shade_sides_into` in
//! `shaders/shade.wgsl`, one thread per visible Gaussian summing its K micro-buffer samples and
//! its directional lights for each of its M vertices.
//!
//! The host checks the inputs as the CPU does (`svgir_pbr::check_sides`, so both reject the same
//! calls with the same errors) and prepares what does not depend on the sample: each Gaussian's
//! hemisphere frame, the Fibonacci rows of the micro-buffer's own table (interleaved subsets
//! included), the env texels with the lights' mask, the lights, and per vertex the diffuse
//! weight (`Diffuse::weight`, a table lookup that depends on the view only). Samples are packed
//! at 16 bytes (`crate::samples`), as the tracer writes them, and bound in batches of Gaussians
//! of at most [`BATCH_BYTES`], so a K = 384 relighting of a large scene never needs its samples
//! on the GPU at once.
//!
//! The sums run in the CPU's order (directions, then lights; per sample the vertices), so the
//! colours differ from the CPU's only by f32 rounding: the driver may fuse multiply-adds, and
//! the env lookups' acos / atan2 are the driver's (the tests bound both).
//!
//! Each call uploads its small inputs (frames, tables, vertex materials, light visibility) and
//! reads the colours back. The micro-buffer samples, most of the bytes, stay on the GPU across
//! calls (`crate::resident`): packed and uploaded at a micro-buffer's first call, then bound as
//! they are by every iteration's forward and backward and every render that shades it.

use crate::buffers::{grid, kernel_of, read_back, storage, upload};
use crate::consistency::ConsistencyKernel;
use crate::device::{Gpu, GpuError};
use crate::resident::{SampleCache, RESIDENT_BYTES};
use crate::samples::{pack, SAMPLE_BYTES};
use bytemuck::{Pod, Zeroable};
use svgir_pbr::{
    check_sides, Consistency, ConsistencyInputs, Indirect, PbrError, PbrGrads, ShadeInputs, ShadeOutput, Side,
    VertexShader,
};
use svgir_shading::hemisphere::HemiFrame;

/// Most bytes of samples (and given indirect light) bound per dispatch.
pub const BATCH_BYTES: u64 = 256 << 20;

/// The kernel's uniform (`ShadeParams` in shade.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Uniform {
    camera: [f32; 3],
    env_max: f32,
    k: u32,
    m: u32,
    flags: u32,
    count: u32,
    env_w: u32,
    env_h: u32,
    lights: u32,
    n: u32,
    rho: f32,
    scale: f32,
    env_at: u32,
    lights_at: u32,
    base: u32,
    span: u32,
    sbase: u32,
    _pad: u32,
}

const F_VIS: u32 = 1;
const F_TRACED: u32 = 2;
const F_GIVEN: u32 = 4;
const F_SPLIT: u32 = 8;
const F_BACK: u32 = 16;

/// The vertex shader on a GPU.
pub struct GpuShader {
    gpu: Gpu,
    kernel: wgpu::ComputePipeline,
    backward_kernel: wgpu::ComputePipeline,
    /// Most bytes of samples bound per dispatch ([`BATCH_BYTES`]; the tests lower it to
    /// split small scenes into several batches).
    pub batch_bytes: u64,
    /// The micro-buffers' packed samples kept on the GPU across calls (`crate::resident`).
    samples: SampleCache,
    /// Stage 2's radiance-consistency term (`crate::consistency`).
    consistency: ConsistencyKernel,
}

impl GpuShader {
    /// The shader on `gpu` (compiles its kernel).
    pub fn new(gpu: Gpu) -> Self {
        let (pbr, common) = (include_str!("shaders/pbr_common.wgsl"), include_str!("shaders/shade_common.wgsl"));
        let kernel = kernel_of(
            &gpu.device,
            "shade",
            &[pbr, common, crate::buffers::LOOP_GUARD, include_str!("shaders/shade.wgsl")],
        );
        let backward_kernel = kernel_of(
            &gpu.device,
            "shade backward",
            &[pbr, common, crate::buffers::LOOP_GUARD, include_str!("shaders/shade_bwd.wgsl")],
        );
        let consistency = ConsistencyKernel::new(&gpu);
        Self {
            gpu,
            kernel,
            backward_kernel,
            batch_bytes: BATCH_BYTES,
            samples: SampleCache::new(RESIDENT_BYTES),
            consistency,
        }
    }

    /// Keeps at most `bytes` of micro-buffer samples on the GPU across calls (0: none, each
    /// call uploads its own; default 1 GiB).
    pub fn keep_samples(mut self, bytes: u64) -> Self {
        self.samples = SampleCache::new(bytes);
        self
    }

    /// Forgets the kept samples (after a micro-buffer was changed in place).
    pub fn clear_kept_samples(&self) {
        self.samples.clear()
    }

    /// Micro-buffers whose samples are kept on the GPU, and their bytes.
    pub fn kept_samples(&self) -> (usize, u64) {
        self.samples.kept()
    }

    /// Test hook: the radiance-consistency kernel's most pairs per group (at most
    /// `consistency::GROUP_PAIRS`) and groups per dispatch, lowered to exercise the splits.
    pub fn set_consistency_sizes(&mut self, group_pairs: usize, groups: usize) {
        self.consistency.sizes = (group_pairs, groups);
    }

    /// The device it runs on.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// `svgir_pbr::shade_sides_into` on the GPU.
    pub fn shade(&self, front: &Side<f32>, back: Option<&Side<f32>>, out: &mut ShadeOutput) -> Result<(), PbrError> {
        check_sides(front, back)?;
        let inp = &front.inputs;
        let (n, m) = (inp.mb.len(), inp.mats.m);
        let parts = if out.split { 3 } else { 1 };
        let len = n * m * 3;
        if (len * parts) as u64 > u32::MAX as u64 {
            return Err(device_error(GpuError::Runtime(format!(
                "{n} Gaussians x {m} vertices: over the kernel's u32 index"
            ))));
        }
        let d = &self.gpu.device;
        let out_buf = storage(d, "shade out", (len * parts * 4) as u64);
        for side in std::iter::once(front).chain(back) {
            self.shade_side(&side.inputs, out.split, &out_buf).map_err(device_error)?;
        }
        let mut r = read_back::<f32>(d, &self.gpu.queue, &[(&out_buf, len * parts)]).map_err(device_error)?;
        self.gpu.check().map_err(device_error)?;
        let all = r.remove(0);
        out.m = m;
        out.color = all[..len].to_vec();
        if out.split {
            out.direct = all[len..2 * len].to_vec();
            out.indirect = all[2 * len..].to_vec();
        } else {
            out.direct.clear();
            out.indirect.clear();
        }
        Ok(())
    }

    /// One side's dispatches into `out` (its visible Gaussians' entries).
    fn shade_side(&self, inp: &ShadeInputs<f32>, split: bool, out: &wgpu::Buffer) -> Result<(), GpuError> {
        let list: Vec<u32> = (0..inp.mb.len()).filter(|&j| inp.visible[j]).map(|j| j as u32).collect();
        let Some(side) = self.prepare(inp, list, if split { F_SPLIT } else { 0 })? else { return Ok(()) };
        let d = &self.gpu.device;
        for b in side.batches() {
            let (ub, samples, given, sub) = side.batch_buffers(d, &b);
            let bg = crate::buffers::bind(
                d,
                &self.kernel,
                &[
                    &ub,
                    &side.frames,
                    &side.tables,
                    &samples,
                    &side.verts,
                    &given,
                    &side.light_vis,
                    &sub,
                    out,
                    &self.gpu.status,
                ],
            );
            self.submit(&self.kernel, &bg, b.to - b.from);
        }
        self.gpu.check()
    }

    /// `svgir_pbr::shade_sides_backward_into` on the GPU: the material gradients and rho's from
    /// the GPU, the env texels' added here from the samples' light gradients (see
    /// shade_bwd.wgsl), all into `grads`.
    pub fn backward(
        &self,
        front: &Side<f32>,
        back: Option<&Side<f32>>,
        v_color: &[f32],
        grads: &mut PbrGrads,
    ) -> Result<(), PbrError> {
        check_sides(front, back)?;
        let inp = &front.inputs;
        let (n, m) = (inp.mb.len(), inp.mats.m);
        svgir_pbr::expect_sizes(&[
            ("v_color", v_color.len(), n * m * 3),
            ("albedo gradients", grads.v_albedo.len(), n * m * 3),
            ("roughness gradients", grads.v_roughness.len(), n * m),
            ("normal gradients", grads.v_normals.len(), n * m * 3),
            ("environment gradients", grads.v_env.len(), inp.env.len()),
        ])?;
        let stride = 7 * m + 1;
        if (n * stride) as u64 > u32::MAX as u64 {
            return Err(device_error(GpuError::Runtime(format!(
                "{n} Gaussians x {m} vertices: over the kernel's u32 index"
            ))));
        }
        let d = &self.gpu.device;
        let v_color_buf = upload(d, "shade v_color", v_color);
        let out = storage(d, "shade grads", (n * stride * 4) as u64);
        for (side_index, side) in std::iter::once(front).chain(back).enumerate() {
            let si = &side.inputs;
            // Unshaded Gaussians and those no pixel saw have no gradient.
            let list: Vec<u32> = (0..n)
                .filter(|&j| si.visible[j] && v_color[j * m * 3..(j + 1) * m * 3].iter().any(|&g| g != 0.0))
                .map(|j| j as u32)
                .collect();
            let flags = if side_index > 0 { F_BACK } else { 0 };
            let Some(prep) = self.prepare(si, list, flags).map_err(device_error)? else { continue };
            for b in prep.batches() {
                let (ub, samples, given, sub) = prep.batch_buffers(d, &b);
                let per = prep.uniform.k as usize + prep.uniform.lights as usize;
                let v_light = storage(d, "shade v_light", ((b.g1 - b.g0) * per * 12) as u64);
                let bg = crate::buffers::bind(
                    d,
                    &self.backward_kernel,
                    &[
                        &ub,
                        &prep.frames,
                        &prep.tables,
                        &samples,
                        &prep.verts,
                        &given,
                        &prep.light_vis,
                        &sub,
                        &v_color_buf,
                        &out,
                        &v_light,
                        &self.gpu.status,
                    ],
                );
                self.submit(&self.backward_kernel, &bg, b.to - b.from);
                let light = read_back::<[f32; 3]>(d, &self.gpu.queue, &[(&v_light, (b.g1 - b.g0) * per)])
                    .map_err(device_error)?
                    .remove(0);
                add_light_grads(si, side.cache, b.g0, &light, &mut grads.v_env);
            }
        }
        let all = read_back::<f32>(d, &self.gpu.queue, &[(&out, n * stride)]).map_err(device_error)?.remove(0);
        self.gpu.check().map_err(device_error)?;
        for (j, g) in all.chunks_exact(stride).enumerate() {
            let add = |dst: &mut [f32], src: &[f32]| dst.iter_mut().zip(src).for_each(|(o, x)| *o += *x);
            add(&mut grads.v_albedo[j * m * 3..(j + 1) * m * 3], &g[..3 * m]);
            add(&mut grads.v_roughness[j * m..(j + 1) * m], &g[3 * m..4 * m]);
            add(&mut grads.v_normals[j * m * 3..(j + 1) * m * 3], &g[4 * m..7 * m]);
            grads.v_rho += g[7 * m];
        }
        Ok(())
    }

    /// One dispatch of `kernel` over `count` listed Gaussians.
    fn submit(&self, kernel: &wgpu::ComputePipeline, bg: &wgpu::BindGroup, count: usize) {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let (x, y) = grid((count as u32).div_ceil(64));
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(kernel);
        pass.set_bind_group(0, bg, &[]);
        pass.dispatch_workgroups(x, y, 1);
        drop(pass);
        self.gpu.queue.submit([enc.finish()]);
    }

    /// What both kernels read of one side, uploaded: `None` when `list` is empty.
    fn prepare<'a>(
        &self,
        inp: &'a ShadeInputs<'a, f32>,
        list: Vec<u32>,
        flags: u32,
    ) -> Result<Option<Prepared<'a>>, GpuError> {
        if list.is_empty() {
            return Ok(None);
        }
        let mb = inp.mb;
        let (n, m, k) = (mb.len(), inp.mats.m, mb.k);
        let d = &self.gpu.device;
        let frames: Vec<[f32; 4]> = (0..n)
            .flat_map(|j| {
                let (b1, b2, nf, cx, sx) = HemiFrame::new(mb.normals[j], mb.xi[j]).parts();
                let p = inp.positions[j];
                [[b1.x, b1.y, b1.z, cx], [b2.x, b2.y, b2.z, sx], [nf.x, nf.y, nf.z, 0.0], [p.x, p.y, p.z, 0.0]]
            })
            .collect();
        let mut tables: Vec<[f32; 4]> = {
            let table = mb.table();
            let [c, s, r, z] = table.rows();
            (0..k).map(|i| [c[i], s[i], r[i], z[i]]).collect()
        };
        let env_at = tables.len();
        let mask = inp.lights.map(|l| l.mask());
        tables.extend(inp.env.iter().enumerate().map(|(t, c)| {
            let light = mask.is_some_and(|mask| mask[t]);
            [c[0], c[1], c[2], if light { 1.0 } else { 0.0 }]
        }));
        let lights_at = tables.len();
        let lights = inp.lights.filter(|l| !l.is_empty());
        let mut light_vis = Vec::new();
        if let Some(l) = lights {
            for b in 0..l.len() {
                let dir = l.dirs[b];
                tables.push([dir.x, dir.y, dir.z, l.sample_scale(b, k)]);
                // The index as a float value (exact below 2^24), not its bits: a small integer's bits
                // are a subnormal float, which a driver may flush to zero.
                tables.push([l.texels[b] as f32, 0.0, 0.0, 0.0]);
                light_vis.extend((0..n).map(|j| l.visibility(j, b)));
            }
        }
        // Per vertex: (normal, roughness), (albedo, diffuse weight), (its derivatives), the weight
        // at the view of the listed Gaussians (as svgir_pbr::shade's `diffuse_weights`).
        let mats = &inp.mats;
        let mut verts = vec![[0.0f32; 4]; n * m * 3];
        for &j in &list {
            let j = j as usize;
            let wo = (inp.camera_center - inp.positions[j]).normalize_or(glam::Vec3::Z).to_array();
            for v in 0..m {
                let (b, i) = ((j * m + v) * 3, j * m + v);
                let nrm = [mats.normals[b], mats.normals[b + 1], mats.normals[b + 2]];
                let r = mats.roughness[i];
                let nv = nrm[0] * wo[0] + nrm[1] * wo[1] + nrm[2] * wo[2];
                let w = inp.params.diffuse.weight(nv, r);
                verts[3 * i] = [nrm[0], nrm[1], nrm[2], r];
                verts[3 * i + 1] = [mats.albedo[b], mats.albedo[b + 1], mats.albedo[b + 2], w.value];
                verts[3 * i + 2] = [w.v_mu, w.v_r, 0.0, 0.0];
            }
        }
        let (indirect_flag, rho, given) = match inp.indirect {
            Indirect::Off => (0, 0.0, None),
            Indirect::Traced { rho } => (F_TRACED, rho, None),
            Indirect::Given(g) => (F_GIVEN, 0.0, Some(g)),
        };
        let c = inp.camera_center;
        let uniform = Uniform {
            camera: [c.x, c.y, c.z],
            // Uniforms hold no infinity: the largest f32 clamps nothing finite.
            env_max: inp.params.env_max.min(f32::MAX),
            k: k as u32,
            m: m as u32,
            flags: flags | if inp.params.visibility { F_VIS } else { 0 } | indirect_flag,
            count: 0,
            env_w: inp.env_geom.width,
            env_h: inp.env_geom.height,
            lights: lights.map_or(0, |l| l.len() as u32),
            n: n as u32,
            rho,
            scale: (std::f64::consts::TAU / k as f64) as f32,
            env_at: env_at as u32,
            lights_at: lights_at as u32,
            base: 0,
            span: 0,
            sbase: 0,
            _pad: 0,
        };
        let limit = self.gpu.report.max_storage_binding;
        let per_light = lights.map_or(0, |l| l.len() as u64) * 12;
        for (what, bytes) in [
            ("the shading's frames", frames.len() as u64 * 16),
            ("the shading's tables", tables.len() as u64 * 16),
            ("the vertex materials", verts.len() as u64 * 16),
            ("the light visibility", light_vis.len() as u64 * 4),
            ("the shading gradients", n as u64 * (7 * m as u64 + 1) * 4),
        ] {
            if bytes > limit {
                return Err(GpuError::TooLarge { what, bytes, limit });
            }
        }
        // Bound per Gaussian: its samples, its given light, the backward's light gradients.
        let per_gaussian = k as u64 * (SAMPLE_BYTES + 12 + if given.is_some() { 12 } else { 0 }) + per_light;
        if per_gaussian > limit {
            return Err(GpuError::TooLarge { what: "one Gaussian's samples", bytes: per_gaussian, limit });
        }
        let batch = (self.batch_bytes.min(limit) / per_gaussian).max(1) as usize;
        // Kept samples come in chunks of at most a batch of samples alone. Batches end at
        // their edges whether the samples are kept or not, so the env gradient's blocks (added
        // in batch order) and with them its sums are the same either way.
        let chunk = (self.batch_bytes.min(limit) / (k as u64 * SAMPLE_BYTES)).max(1) as usize;
        let kept = self.samples.get(d, mb, chunk);
        Ok(Some(Prepared {
            mb,
            list,
            given,
            batch,
            chunk,
            kept,
            uniform,
            frames: upload(d, "shade frames", &frames),
            tables: upload(d, "shade tables", &tables),
            verts: upload(d, "shade vertices", &verts),
            light_vis: upload(d, "shade light visibility", &light_vis),
        }))
    }
}

/// One side's uploaded inputs and how its Gaussians are batched.
struct Prepared<'a> {
    mb: &'a svgir_trace::MicroBuffer,
    list: Vec<u32>,
    given: Option<&'a [[f32; 3]]>,
    batch: usize,
    /// Gaussians per chunk of kept samples (batches end at chunk edges).
    chunk: usize,
    /// The kept samples' chunks.
    kept: Option<Vec<wgpu::Buffer>>,
    uniform: Uniform,
    frames: wgpu::Buffer,
    tables: wgpu::Buffer,
    verts: wgpu::Buffer,
    light_vis: wgpu::Buffer,
}

/// Gaussians `g0 .. g1` bound, `list[from .. to]` of them listed.
struct Batch {
    g0: usize,
    g1: usize,
    from: usize,
    to: usize,
}

impl Prepared<'_> {
    /// The batches with at least one listed Gaussian; none crosses a chunk's edge.
    fn batches(&self) -> Vec<Batch> {
        let n = self.mb.len();
        let chunk = self.chunk;
        let mut out = Vec::new();
        let (mut from, mut g0) = (0, 0);
        while g0 < n {
            let g1 = (g0 + self.batch).min(n).min((g0 / chunk + 1) * chunk);
            let to = from + self.list[from..].partition_point(|&j| (j as usize) < g1);
            if to > from {
                out.push(Batch { g0, g1, from, to });
            }
            (from, g0) = (to, g1);
        }
        out
    }

    /// A batch's uniform, samples, given light and list.
    fn batch_buffers(&self, d: &wgpu::Device, b: &Batch) -> (wgpu::Buffer, wgpu::Buffer, wgpu::Buffer, wgpu::Buffer) {
        let k = self.mb.k;
        let (samples, sbase) = match &self.kept {
            Some(chunks) => (chunks[b.g0 / self.chunk].clone(), b.g0 / self.chunk * self.chunk),
            None => (upload(d, "shade samples", &pack(self.mb, b.g0..b.g1)), b.g0),
        };
        let u = Uniform {
            count: (b.to - b.from) as u32,
            base: b.g0 as u32,
            span: (b.g1 - b.g0) as u32,
            sbase: sbase as u32,
            ..self.uniform
        };
        (
            crate::buffers::uniform(d, "shade params", &u),
            samples,
            match self.given {
                Some(g) => upload(d, "shade indirect", &g[b.g0 * k..b.g1 * k]),
                None => storage(d, "shade indirect (none)", 16),
            },
            upload(d, "shade list", &self.list[b.from..b.to]),
        )
    }
}

/// Adds the light gradients `light` of Gaussians `g0 ..` (K micro-buffer samples then the
/// directional lights each, per channel `C V dL/dLin`) into the env texels: through the four
/// bilinear taps of each direction (the cache's, else looked up as the CPU does), masked by the
/// lights, and through each light's one texel with its weight. Blocks of Gaussians sum into
/// partial maps added in block order, so the sum is the same for any thread count.
fn add_light_grads(
    inp: &ShadeInputs<f32>,
    cache: Option<&svgir_trace::DirectionCache>,
    g0: usize,
    light: &[[f32; 3]],
    v_env: &mut [[f32; 3]],
) {
    use rayon::prelude::*;
    let mb = inp.mb;
    let k = mb.k;
    let lights = inp.lights.filter(|l| !l.is_empty());
    let per = k + lights.map_or(0, |l| l.len());
    let table = mb.table();
    let texels = v_env.len();
    let partials: Vec<Vec<[f32; 3]>> = light
        .par_chunks(per * 256)
        .enumerate()
        .map(|(bi, block)| {
            let mut part = vec![[0.0f32; 3]; texels];
            for (li, samples) in block.chunks(per).enumerate() {
                let j = g0 + bi * 256 + li;
                let frame = HemiFrame::new(mb.normals[j], mb.xi[j]);
                for (s, gv) in samples.iter().enumerate() {
                    if *gv == [0.0; 3] {
                        continue;
                    }
                    if s < k {
                        let mut taps = match cache {
                            Some(c) => c.taps(j * k + s),
                            None => inp.env_geom.taps(frame.dir(&table, s)),
                        };
                        if let Some(l) = inp.lights {
                            l.mask_taps(&mut taps);
                        }
                        for t in 0..4 {
                            let texel = &mut part[taps.index[t] as usize];
                            for c in 0..3 {
                                texel[c] += taps.weight[t] * gv[c];
                            }
                        }
                    } else if let Some(l) = lights {
                        let b = s - k;
                        let w = l.sample_scale(b, k);
                        let texel = &mut part[l.texels[b] as usize];
                        for c in 0..3 {
                            texel[c] += w * gv[c];
                        }
                    }
                }
            }
            part
        })
        .collect();
    for part in partials {
        for (o, x) in v_env.iter_mut().zip(&part) {
            for c in 0..3 {
                o[c] += x[c];
            }
        }
    }
}

fn device_error(e: GpuError) -> PbrError {
    PbrError::Device(e.to_string())
}

impl VertexShader for GpuShader {
    fn name(&self) -> String {
        self.gpu.report.name.clone()
    }

    fn shade_sides(&self, front: &Side<f32>, back: Option<&Side<f32>>, out: &mut ShadeOutput) -> Result<(), PbrError> {
        self.shade(front, back, out)
    }

    fn shade_sides_backward(
        &self,
        front: &Side<f32>,
        back: Option<&Side<f32>>,
        v_color: &[f32],
        grads: &mut PbrGrads,
    ) -> Result<(), PbrError> {
        self.backward(front, back, v_color, grads)
    }

    /// On the GPU where the kernel holds a Gaussian's escapes (`ConsistencyKernel::takes`),
    /// else the CPU's.
    fn consistency_with_grad(&self, inp: &ConsistencyInputs, v_loss: f32) -> Result<(Consistency, PbrGrads), PbrError> {
        if ConsistencyKernel::takes(inp) {
            self.consistency.run(&self.gpu, inp, v_loss)
        } else {
            svgir_pbr::radiance_consistency_with_grad(inp, v_loss)
        }
    }
}
