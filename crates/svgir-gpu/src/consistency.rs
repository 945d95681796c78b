//! The radiance-consistency term on the GPU (SPEC 6, Eqn 14/16): `svgir_pbr::
//! radiance_consistency_with_grad`, its gather's forward and backward in
//! `shaders/consistency.wgsl`.
//!
//! The host checks the inputs as the CPU does, selects the pairs (j, k_j) with the CPU's
//! `select_pairs` (one pass over the visible Gaussians' K directions, frozen geometry), groups
//! them by hit Gaussian h in increasing pair order, at most [`GROUP_PAIRS`] a group, and uploads
//! what the pairs touch, renumbered (training samples a few thousand pairs of a large model):
//! the frames of their Gaussians, the hits' escape masks, vertex materials and light visibility,
//! the Fibonacci rows, the env texels with the lights' mask and the lights, and per pair its
//! flat index, (u~, v~) and traced L. One dispatch per batch of groups, read back once: L1b per pair, and per group h's material
//! gradients and each escape's dL/dL. The host adds the groups of one h in order and routes the
//! light gradients through the env taps (the direction cache's, as the CPU's backward does;
//! channels outside the clamp take none) in group order: no atomics, the same sums at every run.
//! The loss and rho's gradient come from the read-back L1b with the CPU's `l1_loss`.
//!
//! Values differ from the CPU's by f32 rounding (the sums' order; the kernel's env lookups are
//! made from the direction, the CPU's through the cache). A pair whose L1b lies within rounding
//! of `rho L` may take the other sign of the L1 gradient than on the CPU.

use crate::buffers::{grid, kernel_of, read_back, storage, upload};
use crate::device::{Gpu, GpuError};
use bytemuck::{Pod, Zeroable};
use svgir_pbr::{
    check_inputs, l1_loss, pbr_grads, select_pairs, traced_of, Consistency, ConsistencyInputs, PbrError, PbrGrads,
};
use svgir_shading::hemisphere::HemiFrame;
use svgir_shading::layering::{specular_albedo_table, Diffuse};
use svgir_trace::{GatherGrads, NO_HIT};

/// Most pairs of one workgroup (the kernel's threads take a group's pairs one at a time).
pub const GROUP_PAIRS: usize = 64;
/// Most escapes (directions and lights) of a Gaussian the kernel holds in shared memory.
pub const MAX_ESCAPES: usize = 512;
/// Most groups per dispatch.
pub const GROUPS: usize = 1 << 16;

/// The kernel's uniform (`ConsParams` in consistency.wgsl).
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
    env_at: u32,
    lights_at: u32,
    lights: u32,
    vis_at: u32,
    env_max: f32,
    scale: f32,
    groups: u32,
    stride: u32,
    rho: f32,
    up: f32,
    _pad: [u32; 2],
}

/// The consistency kernel.
pub(crate) struct ConsistencyKernel {
    kernel: wgpu::ComputePipeline,
    /// Most pairs a group ([`GROUP_PAIRS`]) and groups a dispatch ([`GROUPS`]); the tests lower
    /// both.
    pub sizes: (usize, usize),
}

impl ConsistencyKernel {
    pub fn new(gpu: &Gpu) -> Self {
        Self {
            kernel: kernel_of(
                &gpu.device,
                "radiance consistency",
                &[
                    include_str!("shaders/pbr_common.wgsl"),
                    crate::buffers::LOOP_GUARD,
                    include_str!("shaders/consistency.wgsl"),
                ],
            ),
            sizes: (GROUP_PAIRS, GROUPS),
        }
    }

    /// Whether the kernel takes `inp` (at most [`MAX_ESCAPES`] directions and lights per
    /// Gaussian); the caller runs the CPU's otherwise.
    pub fn takes(inp: &ConsistencyInputs) -> bool {
        inp.mb.k + inp.params.lights.map_or(0, |l| l.len()) <= MAX_ESCAPES
    }

    /// `svgir_pbr::radiance_consistency_with_grad` on the GPU.
    pub fn run(&self, gpu: &Gpu, inp: &ConsistencyInputs, v_loss: f32) -> Result<(Consistency, PbrGrads), PbrError> {
        check_inputs(inp)?;
        let (mb, mats, env, p) = (inp.mb, &inp.mats, inp.env, &inp.params);
        let pairs = select_pairs(mb, inp.positions, inp.camera_center, inp.visible);
        svgir_trace::gather::check_pair_call(mb, mats, env, p, &pairs)?;
        if !Self::takes(inp) {
            return Err(PbrError::InvalidParameter(format!(
                "the GPU consistency gather takes at most {MAX_ESCAPES} directions and lights per Gaussian"
            )));
        }
        let traced = traced_of(mb, &pairs);
        let (n, k, m) = (mb.len(), mb.k, mats.m);
        let lights = p.lights.filter(|l| !l.is_empty());
        let per = k + lights.map_or(0, |l| l.len());
        let stride = 7 * m + 3 * per;
        let mut g = GatherGrads::zeros(n, m, env.data.len());
        let mut l1b = vec![[0.0f32; 3]; pairs.len()];
        if pairs.is_empty() {
            let (loss, _, v_rho) = l1_loss(&l1b, &traced, inp.rho);
            return Ok((Consistency { loss, pairs, l1b, traced }, pbr_grads(g, v_rho, v_loss)));
        }
        let err = |e: GpuError| PbrError::Device(e.to_string());
        let (group_pairs, dispatch_groups) = (self.sizes.0.clamp(1, GROUP_PAIRS), self.sizes.1.clamp(1, GROUPS));
        // Pairs by hit, in increasing pair order within a hit (a counting sort).
        let mut count = vec![0usize; n + 1];
        for &(j, kk) in &pairs {
            count[mb.first_hit[j as usize * k + kk as usize] as usize + 1] += 1;
        }
        for h in 0..n {
            count[h + 1] += count[h];
        }
        let mut fill = count.clone();
        let mut order = vec![0usize; pairs.len()];
        for (i, &(j, kk)) in pairs.iter().enumerate() {
            let h = mb.first_hit[j as usize * k + kk as usize] as usize;
            order[fill[h]] = i;
            fill[h] += 1;
        }
        // Only the Gaussians the pairs touch go to the GPU, renumbered: the hits first (local
        // index = rank among the hits, which the escapes, vertices and light visibility are
        // sized for), then the rays' Gaussians that are no hit (their frames only).
        let mut local = vec![u32::MAX; n];
        let mut ids: Vec<usize> = (0..n).filter(|&h| count[h + 1] > count[h]).collect();
        for (l, &h) in ids.iter().enumerate() {
            local[h] = l as u32;
        }
        let hits = ids.len();
        for &(j, _) in &pairs {
            if local[j as usize] == u32::MAX {
                local[j as usize] = ids.len() as u32;
                ids.push(j as usize);
            }
        }
        // Groups (local h, first, count) of at most `group_pairs` pairs, in order of h.
        let mut groups: Vec<[u32; 4]> = Vec::new();
        for (hl, &h) in ids[..hits].iter().enumerate() {
            let mut at = count[h];
            while at < count[h + 1] {
                let c = (count[h + 1] - at).min(group_pairs);
                groups.push([hl as u32, at as u32, c as u32, 0]);
                at += c;
            }
        }
        let mut pair_words = Vec::with_capacity(pairs.len() * 5);
        for &i in &order {
            let (j, kk) = (pairs[i].0 as usize, pairs[i].1 as usize);
            let uv = mb.uv[j * k + kk];
            let t = traced[i];
            pair_words.extend([
                local[j] * k as u32 + kk as u32,
                u32::from(uv[0]) | (u32::from(uv[1]) << 16),
                t[0].to_bits(),
                t[1].to_bits(),
                t[2].to_bits(),
            ]);
        }
        // Tables: the Fibonacci rows, the layered table, the texels, the lights.
        let table = mb.table();
        let [c, s, r, z] = table.rows();
        let mut tables: Vec<[f32; 4]> = (0..k).map(|i| [c[i], s[i], r[i], z[i]]).collect();
        let e_at = tables.len();
        tables.extend(specular_albedo_table().iter().map(|&e| [e as f32, 0.0, 0.0, 0.0]));
        let env_at = tables.len();
        let mask = p.lights.map(|l| l.mask());
        tables.extend(
            env.data
                .iter()
                .enumerate()
                .map(|(t, c)| [c[0], c[1], c[2], if mask.is_some_and(|mask| mask[t]) { 1.0 } else { 0.0 }]),
        );
        let lights_at = tables.len();
        let mut light_vis = Vec::new();
        if let Some(l) = lights {
            for b in 0..l.len() {
                let d = l.dirs[b];
                tables.push([d.x, d.y, d.z, l.sample_scale(b, k)]);
                tables.push([l.texels[b] as f32, 0.0, 0.0, 0.0]);
                light_vis.extend(ids[..hits].iter().map(|&h| l.visibility(h, b)));
            }
        }
        if light_vis.is_empty() {
            light_vis.push(0.0); // a binding is never empty
        }
        let words = k.div_ceil(32);
        let mut escaped = vec![0u32; hits * words];
        let mut verts = Vec::with_capacity(hits * m * 2);
        for (hl, &h) in ids[..hits].iter().enumerate() {
            for kk in 0..k {
                if mb.first_hit[h * k + kk] == NO_HIT {
                    escaped[hl * words + kk / 32] |= 1 << (kk % 32);
                }
            }
            for i in h * m..(h + 1) * m {
                let b = i * 3;
                verts.push([mats.normals[b], mats.normals[b + 1], mats.normals[b + 2], mats.roughness[i]]);
                verts.push([mats.albedo[b], mats.albedo[b + 1], mats.albedo[b + 2], 0.0]);
            }
        }
        let frames = crate::gather::frames_of(mb, ids.iter().copied());
        let limit = gpu.report.max_storage_binding;
        for (what, bytes) in [
            ("the consistency gather's frames", frames.len() as u64 * 16),
            ("the consistency gather's tables", tables.len() as u64 * 16),
            ("the consistency gather's vertex materials", verts.len() as u64 * 16),
            ("the consistency gather's light visibility", light_vis.len() as u64 * 4),
            ("the consistency gather's pairs", pair_words.len() as u64 * 4),
            ("the consistency gather's gradients", (dispatch_groups * stride) as u64 * 4),
        ] {
            if bytes > limit {
                return Err(err(GpuError::TooLarge { what, bytes, limit }));
            }
        }
        let d = &gpu.device;
        let base = Uniform {
            k: k as u32,
            m: m as u32,
            n: hits as u32,
            layered: u32::from(p.diffuse == Diffuse::Layered),
            env_w: env.width,
            env_h: env.height,
            e_at: e_at as u32,
            words: words as u32,
            env_at: env_at as u32,
            lights_at: lights_at as u32,
            lights: lights.map_or(0, |l| l.len() as u32),
            vis_at: 0,
            // Uniforms hold no infinity: the largest f32 clamps nothing finite.
            env_max: p.env_max.min(f32::MAX),
            scale: (std::f64::consts::TAU / k as f64) as f32,
            groups: 0,
            stride: stride as u32,
            rho: inp.rho,
            up: 1.0 / (3 * pairs.len()) as f32 * v_loss,
            _pad: [0; 2],
        };
        let bufs = [
            upload(d, "consistency frames", &frames),
            upload(d, "consistency tables", &tables),
            upload(d, "consistency escapes", &escaped),
            upload(d, "consistency vertices", &verts),
            upload(d, "consistency light visibility", &light_vis),
        ];
        let taps_of = |h: usize, s: usize| match p.cache {
            Some(c) => c.taps(h * k + s),
            None => env.taps(HemiFrame::new(mb.normals[h], mb.xi[h]).dir(&table, s)),
        };
        for batch in groups.chunks(dispatch_groups) {
            let first = batch[0][1] as usize;
            let last = batch.last().map_or(first, |b| (b[1] + b[2]) as usize);
            let local: Vec<[u32; 4]> = batch.iter().map(|b| [b[0], b[1] - first as u32, b[2], 0]).collect();
            let ub = crate::buffers::uniform(d, "consistency params", &Uniform { groups: batch.len() as u32, ..base });
            let group_buf = upload(d, "consistency groups", &local);
            let pair_buf = upload(d, "consistency pairs", &pair_words[first * 5..last * 5]);
            let l1b_buf = storage(d, "consistency L1b", ((last - first) * 12) as u64);
            let grad_buf = storage(d, "consistency gradients", (batch.len() * stride * 4) as u64);
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
                    &group_buf,
                    &pair_buf,
                    &l1b_buf,
                    &grad_buf,
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
            let mut back =
                read_back::<f32>(d, &gpu.queue, &[(&l1b_buf, (last - first) * 3), (&grad_buf, batch.len() * stride)])
                    .map_err(err)?;
            let (values, grads) = (back.remove(0), back.remove(0));
            for (slot, &i) in order[first..last].iter().enumerate() {
                l1b[i] = [values[slot * 3], values[slot * 3 + 1], values[slot * 3 + 2]];
            }
            for (b, gr) in batch.iter().zip(grads.chunks(stride)) {
                let h = ids[b[0] as usize];
                for i in 0..m * 3 {
                    g.v_albedo[h * m * 3 + i] += gr[i];
                    g.v_normals[h * m * 3 + i] += gr[4 * m + i];
                }
                for i in 0..m {
                    g.v_roughness[h * m + i] += gr[3 * m + i];
                }
                // The light gradients through the taps, as `Escapes::fill` made them.
                for s in 0..per {
                    let gv = &gr[7 * m + 3 * s..7 * m + 3 * s + 3];
                    if gv.iter().all(|&x| x == 0.0) {
                        continue;
                    }
                    if s < k {
                        if mb.first_hit[h * k + s] != NO_HIT {
                            continue;
                        }
                        let mut taps = taps_of(h, s);
                        if let Some(l) = p.lights {
                            l.mask_taps(&mut taps);
                        }
                        let mut raw = [0.0f32; 3];
                        for t in 0..4 {
                            let texel = env.data[taps.index[t] as usize];
                            for c in 0..3 {
                                raw[c] += taps.weight[t] * texel[c];
                            }
                        }
                        for c in 0..3 {
                            if raw[c] >= 0.0 && raw[c] <= p.env_max {
                                for t in 0..4 {
                                    g.v_env[taps.index[t] as usize][c] += taps.weight[t] * gv[c];
                                }
                            }
                        }
                    } else if let Some(l) = lights {
                        let b = s - k;
                        let w = l.visibility(h, b) * l.sample_scale(b, k);
                        for c in 0..3 {
                            g.v_env[l.texels[b] as usize][c] += w * gv[c];
                        }
                    }
                }
            }
        }
        gpu.check().map_err(err)?;
        let (loss, _, v_rho) = l1_loss(&l1b, &traced, inp.rho);
        Ok((Consistency { loss, pairs, l1b, traced }, pbr_grads(g, v_rho, v_loss)))
    }
}
