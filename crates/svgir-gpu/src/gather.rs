//! The one-bounce gather on the GPU (SPEC 5, Eqn 13): `svgir_trace::gather_all` and
//! `gather_two_sided`, relighting's L1b, in `shaders/gather.wgsl`.
//!
//! The host checks the inputs as the CPU does (`svgir_trace::gather::check_sides`), groups the
//! rays by (side, hit Gaussian) with a counting sort, as the CPU does (the side a ray meets is
//! `gather::side_met`, computed here as there), and uploads what the kernel reads: each
//! micro-buffer's frames and Fibonacci rows, each side's escape mask (one bit a sample), vertex
//! materials, env texels with the lights' mask and lights, and per ray its flat index and
//! (u~, v~). Groups go in dispatches of at most [`PAIRS`] rays, read back and scattered to
//! `j * K + k`.
//!
//! A ray's value differs from the CPU's by f32 rounding: the view direction is rotated from the
//! Fibonacci table here (`MicroBuffer::direction` makes a sine and cosine), and the kernel's env
//! lookups use its own atan2 (as the shading's do).

use crate::buffers::{grid, kernel_of, read_back, storage, upload};
use crate::device::{Gpu, GpuError};
use bytemuck::{Pod, Zeroable};
use svgir_core::EnvMap;
use svgir_shading::hemisphere::HemiFrame;
use svgir_shading::layering::{specular_albedo_table, Diffuse};
use svgir_trace::{GatherParams, HitSide, MicroBuffer, TraceError, NO_HIT};

/// Most rays per dispatch.
pub const PAIRS: usize = 1 << 22;

/// The kernel's uniform (`GatherParams` in gather.wgsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Uniform {
    k: u32,
    m: u32,
    n: u32,
    layered: u32,
    env_w: u32,
    env_h: u32,
    e_at: u32,
    words: u32,
    side: [[u32; 4]; 2],
    env_max: f32,
    scale: f32,
    groups: u32,
    _pad: u32,
}

/// The gather's pipeline.
pub(crate) struct Gather {
    kernel: wgpu::ComputePipeline,
    /// Rays per dispatch ([`PAIRS`]; the tests lower it).
    pub pairs: usize,
}

impl Gather {
    pub fn new(gpu: &Gpu) -> Self {
        Self {
            kernel: kernel_of(
                &gpu.device,
                "gather",
                &[
                    include_str!("shaders/pbr_common.wgsl"),
                    crate::buffers::LOOP_GUARD,
                    include_str!("shaders/gather.wgsl"),
                ],
            ),
            pairs: PAIRS,
        }
    }

    /// Eqn 13 for every ray of `rays` off the side of its hit that `two_sided` picks (`sides`
    /// is `[front]` or `[front, back]`).
    pub fn run(
        &self,
        gpu: &Gpu,
        rays: &MicroBuffer,
        sides: &[HitSide],
        env: &EnvMap,
        p: &GatherParams,
    ) -> Result<Vec<[f32; 3]>, TraceError> {
        svgir_trace::gather::check_sides(rays, sides, env, p)?;
        if sides.iter().any(|s| s.mb.interleave != rays.interleave) {
            return Err(TraceError::InvalidParameter("the GPU gather takes sides traced like the rays".into()));
        }
        let (n, k) = (rays.len(), rays.k);
        let m = sides[0].mats.m;
        let mut out = vec![[0.0f32; 3]; n * k];
        if n == 0 {
            return Ok(out);
        }
        let err = |e: GpuError| TraceError::Device(e.to_string());
        let limit = gpu.report.max_storage_binding;
        let words = k.div_ceil(32);
        // Group the rays by (side, h), increasing flat index within a group.
        let groups_n = sides.len() * n;
        let mut count = vec![0usize; groups_n + 1];
        let mut key = vec![u32::MAX; n * k];
        for j in 0..n {
            for kk in 0..k {
                // No bounce off an escape or the surroundings (no materials of their own).
                let Some(h) = rays.hit(j, kk) else { continue };
                let h = h as usize;
                let s = if sides.len() > 1 {
                    svgir_trace::gather::side_met(rays, &sides[0].mb.normals, j, kk, h)
                } else {
                    0
                };
                key[j * k + kk] = (s * n + h) as u32;
                count[s * n + h + 1] += 1;
            }
        }
        for g in 0..groups_n {
            count[g + 1] += count[g];
        }
        let mut fill = count.clone();
        let mut pairs = vec![[0u32; 2]; count[groups_n]];
        for (flat, &g) in key.iter().enumerate() {
            if g == u32::MAX {
                continue;
            }
            let uv = rays.uv[flat];
            pairs[fill[g as usize]] = [flat as u32, u32::from(uv[0]) | (u32::from(uv[1]) << 16)];
            fill[g as usize] += 1;
        }
        // Tables: the rays' Fibonacci rows, the layered table, then each side's texels and lights.
        let table = rays.table();
        let [c, s, r, z] = table.rows();
        let mut tables: Vec<[f32; 4]> = (0..k).map(|i| [c[i], s[i], r[i], z[i]]).collect();
        let e_at = tables.len();
        tables.extend(specular_albedo_table().iter().map(|&e| [e as f32, 0.0, 0.0, 0.0]));
        let mut side_u = [[0u32; 4]; 2];
        let mut light_vis = Vec::new();
        let mut hit_frames = Vec::with_capacity(sides.len() * n * 4);
        let mut escaped = vec![0u32; sides.len() * n * words];
        let mut verts = Vec::with_capacity(sides.len() * n * m * 2);
        for (si, side) in sides.iter().enumerate() {
            let env_at = tables.len();
            let mask = side.lights.map(|l| l.mask());
            tables.extend(
                env.data
                    .iter()
                    .enumerate()
                    .map(|(t, c)| [c[0], c[1], c[2], if mask.is_some_and(|mask| mask[t]) { 1.0 } else { 0.0 }]),
            );
            let lights_at = tables.len();
            let lights = side.lights.filter(|l| !l.is_empty());
            let vis_at = light_vis.len();
            if let Some(l) = lights {
                for b in 0..l.len() {
                    let d = l.dirs[b];
                    tables.push([d.x, d.y, d.z, l.sample_scale(b, k)]);
                    tables.push([l.texels[b] as f32, 0.0, 0.0, 0.0]);
                    light_vis.extend((0..n).map(|h| l.visibility(h, b)));
                }
            }
            side_u[si] = [env_at as u32, lights_at as u32, lights.map_or(0, |l| l.len() as u32), vis_at as u32];
            hit_frames.extend(frames(side.mb));
            for h in 0..n {
                for kk in 0..k {
                    if side.mb.first_hit[h * k + kk] == NO_HIT {
                        escaped[(si * n + h) * words + kk / 32] |= 1 << (kk % 32);
                    }
                }
            }
            let mats = &side.mats;
            for i in 0..n * m {
                let b = i * 3;
                verts.push([mats.normals[b], mats.normals[b + 1], mats.normals[b + 2], mats.roughness[i]]);
                verts.push([mats.albedo[b], mats.albedo[b + 1], mats.albedo[b + 2], 0.0]);
            }
        }
        let ray_frames = frames(rays);
        for (what, bytes) in [
            ("the gather's ray frames", ray_frames.len() as u64 * 16),
            ("the gather's hit frames", hit_frames.len() as u64 * 16),
            ("the gather's tables", tables.len() as u64 * 16),
            ("the gather's escape masks", escaped.len() as u64 * 4),
            ("the gather's vertex materials", verts.len() as u64 * 16),
            ("the gather's light visibility", light_vis.len() as u64 * 4),
        ] {
            if bytes > limit {
                return Err(err(GpuError::TooLarge { what, bytes, limit }));
            }
        }
        let d = &gpu.device;
        let base = Uniform {
            k: k as u32,
            m: m as u32,
            n: n as u32,
            layered: u32::from(p.diffuse == Diffuse::Layered),
            env_w: env.width,
            env_h: env.height,
            e_at: e_at as u32,
            words: words as u32,
            side: side_u,
            // Uniforms hold no infinity: the largest f32 clamps nothing finite.
            env_max: p.env_max.min(f32::MAX),
            scale: (std::f64::consts::TAU / k as f64) as f32,
            groups: 0,
            _pad: 0,
        };
        let bufs = [
            upload(d, "gather ray frames", &ray_frames),
            upload(d, "gather hit frames", &hit_frames),
            upload(d, "gather tables", &tables),
            upload(d, "gather escapes", &escaped),
            upload(d, "gather vertices", &verts),
            upload(d, "gather light visibility", &light_vis),
        ];
        // Dispatches of whole groups, at most `self.pairs` rays each (a larger group alone).
        let mut g = 0;
        while g < groups_n {
            let first = count[g];
            let mut batch = Vec::new();
            while g < groups_n && (batch.is_empty() || count[g + 1] - first <= self.pairs) {
                if count[g + 1] > count[g] {
                    let (side, h) = (g / n, g % n);
                    batch.push([side as u32, h as u32, (count[g] - first) as u32, (count[g + 1] - count[g]) as u32]);
                }
                g += 1;
            }
            if batch.is_empty() {
                continue;
            }
            let last = count[g];
            let ub = crate::buffers::uniform(d, "gather params", &Uniform { groups: batch.len() as u32, ..base });
            let group_buf = upload(d, "gather groups", &batch);
            let pair_buf = upload(d, "gather pairs", &pairs[first..last]);
            let out_buf = storage(d, "gather out", ((last - first) * 12) as u64);
            let bg = crate::buffers::bind(
                d,
                &self.kernel,
                &[
                    &ub,
                    &bufs[0],
                    &bufs[1],
                    &bufs[2],
                    &bufs[3],
                    &bufs[4],
                    &bufs[5],
                    &group_buf,
                    &pair_buf,
                    &out_buf,
                    &gpu.status,
                ],
            );
            let mut enc = d.create_command_encoder(&Default::default());
            let (x, y) = grid(batch.len() as u32);
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.kernel);
            pass.set_bind_group(0, &bg, &[]);
            pass.dispatch_workgroups(x, y, 1);
            drop(pass);
            gpu.queue.submit([enc.finish()]);
            let values = read_back::<[f32; 3]>(d, &gpu.queue, &[(&out_buf, last - first)]).map_err(err)?.remove(0);
            for (pair, v) in pairs[first..last].iter().zip(values) {
                out[pair[0] as usize] = v;
            }
        }
        gpu.check().map_err(err)?;
        Ok(out)
    }
}

/// Each Gaussian's hemisphere frame of `mb`: (b1, cos xi), (b2, sin xi), (n, 0), (0).
fn frames(mb: &MicroBuffer) -> Vec<[f32; 4]> {
    frames_of(mb, 0..mb.len())
}

/// The hemisphere frames of Gaussians `ids` of `mb`, in that order, as [`frames`] lays them out.
pub(crate) fn frames_of(mb: &MicroBuffer, ids: impl IntoIterator<Item = usize>) -> Vec<[f32; 4]> {
    ids.into_iter()
        .flat_map(|j| {
            let (b1, b2, nf, cx, sx) = HemiFrame::new(mb.normals[j], mb.xi[j]).parts();
            [[b1.x, b1.y, b1.z, cx], [b2.x, b2.y, b2.z, sx], [nf.x, nf.y, nf.z, 0.0], [0.0; 4]]
        })
        .collect()
}
