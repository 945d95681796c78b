//! Checkpoints: everything a run needs to continue bit-identically.
//!
//! One container format for both stages: `SVGIRCK2`, u64 little-endian header length, a JSON
//! header (configuration, scalars, and the name and byte length of every array), then the arrays
//! as raw bytes of their `Pod` element type in header order (little-endian hosts, as every
//! platform svgir builds for). Written to `<path>.tmp` and renamed, so a crash never
//! leaves a half-written checkpoint.
//! - Stage 1: surfels, Adam moments and step counters, densification statistics, iteration,
//!   RNG state, config.
//! - Stage 2: the trained surfel attributes, materials, env parameters, rho, Adam state,
//!   iteration, RNG state, config, and the micro-buffers (traced with stage-2's initial opacity
//!   and SH, which keep training, so they are stored rather than re-traced).

use crate::adam::AdamGroup;
use crate::config::Stage1Config;
use crate::densify::DensifyStats;
use crate::exposure::{self, ExposureCorrection};
use crate::stage1::{PhaseTimes, Stage1};
use crate::stage2::{Stage2, Stage2Config, ViewSets};
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use svgir_core::{Dataset, Rng, ShCoeffs, Surfels};
use svgir_trace::MicroBuffer;

const MAGIC: &[u8; 8] = b"SVGIRCK2";

/// Why a checkpoint could not be written, read or turned back into a trainer.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// Reading or writing the file failed.
    #[error("{path}: {err}")]
    Io {
        /// The checkpoint file.
        path: PathBuf,
        /// The operating-system error.
        err: std::io::Error,
    },
    /// The file is not an svgir checkpoint, or its content is inconsistent.
    #[error("{path}: not an svgir checkpoint or corrupt: {what}")]
    Corrupt {
        /// The checkpoint file.
        path: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// The content is readable but a stage-2 trainer cannot be rebuilt from it.
    #[error("{path}: cannot rebuild stage 2: {what}")]
    Rebuild {
        /// The checkpoint file.
        path: PathBuf,
        /// Why the trainer cannot be rebuilt.
        what: String,
    },
}

fn bytes<T: bytemuck::Pod>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}

fn cast<T: bytemuck::Pod>(v: Vec<u8>) -> Vec<T> {
    bytemuck::pod_collect_to_vec(&v)
}

/// Write `header` and named arrays atomically.
fn write_container<H: Serialize>(path: &Path, header: &H, arrays: &[(String, &[u8])]) -> Result<(), CheckpointError> {
    #[derive(Serialize)]
    struct Outer<'a, H> {
        header: &'a H,
        arrays: Vec<(&'a str, usize)>,
    }
    let outer = Outer { header, arrays: arrays.iter().map(|(n, a)| (n.as_str(), a.len())).collect() };
    let json = serde_json::to_vec(&outer).expect("header serialises");
    let mut bytes = Vec::with_capacity(16 + json.len() + arrays.iter().map(|a| a.1.len()).sum::<usize>());
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&(json.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&json);
    for (_, a) in arrays {
        bytes.extend_from_slice(a);
    }
    let tmp = path.with_extension("tmp");
    // The error names the file that failed: the temporary one while writing, the final one when renaming.
    std::fs::write(&tmp, &bytes).map_err(|err| CheckpointError::Io { path: tmp.clone(), err })?;
    std::fs::rename(&tmp, path).map_err(|err| CheckpointError::Io { path: path.to_path_buf(), err })
}

/// The arrays of a container, consumed in order by name.
struct Arrays {
    path: PathBuf,
    items: VecDeque<(String, Vec<u8>)>,
}

impl Arrays {
    fn next_bytes(&mut self, want: &str) -> Result<Vec<u8>, CheckpointError> {
        match self.items.pop_front() {
            Some((name, v)) if name == want => Ok(v),
            Some((name, _)) => Err(corrupt(&self.path, &format!("expected array {want}, found {name}"))),
            None => Err(corrupt(&self.path, &format!("missing array {want}"))),
        }
    }

    fn next(&mut self, want: &str) -> Result<Vec<f32>, CheckpointError> {
        self.next_as(want)
    }

    fn next_as<T: bytemuck::Pod>(&mut self, want: &str) -> Result<Vec<T>, CheckpointError> {
        let b = self.next_bytes(want)?;
        if b.len() % std::mem::size_of::<T>() != 0 {
            return Err(corrupt(&self.path, &format!("array {want} has a partial element")));
        }
        Ok(cast(b))
    }
}

fn corrupt(path: &Path, what: &str) -> CheckpointError {
    CheckpointError::Corrupt { path: path.to_path_buf(), what: what.to_string() }
}

fn read_container<H: DeserializeOwned>(path: &Path) -> Result<(H, Arrays), CheckpointError> {
    #[derive(Deserialize)]
    struct Outer<H> {
        header: H,
        arrays: Vec<(String, usize)>,
    }
    let bytes = std::fs::read(path).map_err(|err| CheckpointError::Io { path: path.to_path_buf(), err })?;
    if bytes.len() < 16 || &bytes[..8] != MAGIC {
        return Err(corrupt(path, "bad magic"));
    }
    let hlen = u64::from_le_bytes(bytes[8..16].try_into().unwrap()) as usize;
    let body = bytes.get(16..16usize.saturating_add(hlen)).ok_or_else(|| corrupt(path, "truncated header"))?;
    let outer: Outer<H> = serde_json::from_slice(body).map_err(|e| corrupt(path, &format!("header: {e}")))?;
    let mut off = 16 + hlen;
    let mut items = VecDeque::new();
    for (name, len) in outer.arrays {
        let end = off.checked_add(len).ok_or_else(|| corrupt(path, "array too large"))?;
        let raw = bytes.get(off..end).ok_or_else(|| corrupt(path, &format!("truncated in {name}")))?;
        off = end;
        items.push_back((name, raw.to_vec()));
    }
    Ok((outer.header, Arrays { path: path.to_path_buf(), items }))
}

fn surfel_arrays(s: &Surfels) -> Vec<(String, &[u8])> {
    surfel_arrays_named(s, "")
}

/// The surfels' arrays, each name after `prefix`.
fn surfel_arrays_named<'a>(s: &'a Surfels, prefix: &str) -> Vec<(String, &'a [u8])> {
    vec![
        (format!("{prefix}positions"), bytes(&s.positions)),
        (format!("{prefix}rotations"), bytes(&s.rotations)),
        (format!("{prefix}log_scales"), bytes(&s.log_scales)),
        (format!("{prefix}opacity_logits"), bytes(&s.opacity_logits)),
        (format!("{prefix}sh"), bytes(&s.sh)),
    ]
}

fn read_surfels(a: &mut Arrays, sh_degree: u32) -> Result<Surfels, CheckpointError> {
    read_surfels_named(a, sh_degree, "")
}

fn read_surfels_named(a: &mut Arrays, sh_degree: u32, prefix: &str) -> Result<Surfels, CheckpointError> {
    let s = Surfels {
        positions: a.next_as(&format!("{prefix}positions"))?,
        rotations: a.next_as(&format!("{prefix}rotations"))?,
        log_scales: a.next_as(&format!("{prefix}log_scales"))?,
        opacity_logits: a.next(&format!("{prefix}opacity_logits"))?,
        sh: a.next_as::<ShCoeffs>(&format!("{prefix}sh"))?,
        sh_degree,
    };
    s.check().map_err(|e| corrupt(&a.path, &e))?;
    Ok(s)
}

fn push_groups<'a>(arrays: &mut Vec<(String, &'a [u8])>, groups: &'a [AdamGroup]) {
    for g in groups {
        arrays.push((format!("adam.{}.m", g.name), bytes(&g.m)));
        arrays.push((format!("adam.{}.v", g.name), bytes(&g.v)));
    }
}

/// Adam groups from their stored hyper-parameters plus their moment arrays.
fn read_groups<const N: usize>(
    a: &mut Arrays,
    stored: &[AdamGroup],
    rows: &[usize],
) -> Result<[AdamGroup; N], CheckpointError> {
    let mut groups = stored.to_vec();
    for (g, rows) in groups.iter_mut().zip(rows) {
        g.m = a.next(&format!("adam.{}.m", g.name))?;
        g.v = a.next(&format!("adam.{}.v", g.name))?;
        if g.m.len() != rows * g.stride || g.v.len() != g.m.len() {
            return Err(corrupt(&a.path, &format!("Adam group {} has the wrong size", g.name)));
        }
    }
    groups.try_into().map_err(|_| corrupt(&a.path, &format!("expected {N} Adam groups")))
}

fn strip(groups: &[AdamGroup]) -> Vec<AdamGroup> {
    groups.iter().map(|g| AdamGroup { m: vec![], v: vec![], ..g.clone() }).collect()
}

#[derive(Serialize, Deserialize)]
struct Header1 {
    config: Stage1Config,
    iteration: u64,
    rng_state: u64,
    extent: f32,
    sh_degree: u32,
    times: PhaseTimes,
    /// Adam groups without their moments (which follow as arrays).
    groups: Vec<AdamGroup>,
    /// Per-photo colour corrections' Adam step counts (their values and moments follow as
    /// arrays); empty without corrections.
    #[serde(default)]
    exposure_steps: Vec<u64>,
}

/// Write a stage-1 trainer (surfels, Adam state, statistics, RNG) to `path` atomically.
pub fn save(trainer: &Stage1, path: &Path) -> Result<(), CheckpointError> {
    let st = &trainer.stats;
    let mut arrays = surfel_arrays(&trainer.surfels);
    arrays.push(("stats.grad_accum".into(), bytes(&st.grad_accum)));
    arrays.push(("stats.denom".into(), bytes(&st.denom)));
    arrays.push(("stats.max_radius".into(), bytes(&st.max_radius)));
    arrays.push(("stats.accum_weight".into(), bytes(&st.accum_weight)));
    push_groups(&mut arrays, &trainer.groups);
    let ex = trainer.exposure.as_ref();
    // Every photo's correction and Adam moments, one row per photo (empty without corrections).
    let rows = |f: fn(&ExposureCorrection, usize) -> &[f32]| -> Vec<f32> {
        ex.map(|e| (0..e.params.len()).flat_map(|i| f(e, i).iter().copied()).collect()).unwrap_or_default()
    };
    let ex_params = rows(|e, i| &e.params[i]);
    let ex_m = rows(|e, i| &e.adam[i].m);
    let ex_v = rows(|e, i| &e.adam[i].v);
    if ex.is_some() {
        arrays.push(("exposure.params".into(), bytes(&ex_params)));
        arrays.push(("exposure.m".into(), bytes(&ex_m)));
        arrays.push(("exposure.v".into(), bytes(&ex_v)));
    }
    let header = Header1 {
        config: trainer.config.clone(),
        iteration: trainer.iteration,
        rng_state: trainer.rng.state(),
        extent: trainer.extent,
        sh_degree: trainer.surfels.sh_degree,
        times: trainer.times.clone(),
        groups: strip(&trainer.groups),
        exposure_steps: ex.map(|e| e.adam.iter().map(|g| g.step).collect()).unwrap_or_default(),
    };
    write_container(path, &header, &arrays)
}

/// Read a stage-1 checkpoint written by [`save`] for `dataset`, ready to resume.
pub fn load(path: &Path, dataset: &Dataset) -> Result<Stage1, CheckpointError> {
    let (header, mut a): (Header1, Arrays) = read_container(path)?;
    let surfels = read_surfels(&mut a, header.sh_degree)?;
    let stats = DensifyStats {
        grad_accum: a.next("stats.grad_accum")?,
        denom: a.next_as("stats.denom")?,
        max_radius: a.next("stats.max_radius")?,
        accum_weight: a.next("stats.accum_weight")?,
    };
    let n = surfels.len();
    // Densification indexes every statistic by Gaussian: a mismatched array would panic there,
    // thousands of iterations into the resumed run, instead of failing here with the file's name.
    let stat_lens = [
        ("grad_accum", stats.grad_accum.len()),
        ("denom", stats.denom.len()),
        ("max_radius", stats.max_radius.len()),
        ("accum_weight", stats.accum_weight.len()),
    ];
    if let Some((name, len)) = stat_lens.iter().find(|(_, len)| *len != n) {
        return Err(corrupt(
            &a.path,
            &format!("densification statistics stats.{name} has {len} entries for {n} Gaussians"),
        ));
    }
    let groups = read_groups::<5>(&mut a, &header.groups, &[n; 5])?;
    let exposure = read_exposure(&mut a, &header.exposure_steps)?;
    let mut trainer = Stage1::new(header.config, surfels, dataset);
    if trainer.exposure.is_some() {
        let e = exposure.ok_or_else(|| corrupt(&a.path, "colour corrections missing"))?;
        if e.params.len() != dataset.train.len() {
            return Err(corrupt(&a.path, "colour corrections for a different number of training photos"));
        }
        trainer.exposure = Some(e);
    }
    trainer.surfels.sh_degree = header.sh_degree;
    trainer.groups = groups;
    trainer.stats = stats;
    trainer.iteration = header.iteration;
    trainer.rng = Rng::from_state(header.rng_state);
    trainer.extent = header.extent;
    trainer.times = header.times;
    Ok(trainer)
}

/// The per-photo colour corrections saved by [`save`], if any.
fn read_exposure(a: &mut Arrays, steps: &[u64]) -> Result<Option<ExposureCorrection>, CheckpointError> {
    if steps.is_empty() {
        return Ok(None);
    }
    let (params, m, v) = (a.next("exposure.params")?, a.next("exposure.m")?, a.next("exposure.v")?);
    let n = steps.len();
    if params.len() != n * exposure::PARAMS || m.len() != params.len() || v.len() != params.len() {
        return Err(corrupt(&a.path, "colour corrections have the wrong size"));
    }
    let mut e = ExposureCorrection::new(n);
    for i in 0..n {
        let rows = i * exposure::PARAMS..(i + 1) * exposure::PARAMS;
        e.params[i].copy_from_slice(&params[rows.clone()]);
        e.adam[i].m.copy_from_slice(&m[rows.clone()]);
        e.adam[i].v.copy_from_slice(&v[rows]);
        e.adam[i].step = steps[i];
    }
    Ok(Some(e))
}

#[derive(Serialize, Deserialize)]
struct Header2 {
    config: Stage2Config,
    iteration: u64,
    rng_state: u64,
    sh_degree: u32,
    rho: f32,
    vertices: usize,
    env_size: (u32, u32),
    directions: usize,
    trace_seconds: f64,
    times: PhaseTimes,
    groups: Vec<AdamGroup>,
    /// Texels of the learned map that are directional lights (visibility is re-traced on load).
    #[serde(default)]
    light_texels: Vec<u32>,
    /// Their directions (a searched sun sits off its texel's centre; absent in older checkpoints).
    #[serde(default)]
    light_dirs: Vec<[f32; 3]>,
    /// A `trace_opacity` array follows the Adam state (absent in older checkpoints).
    #[serde(default)]
    has_trace_opacity: bool,
    /// Back-side micro-buffer arrays follow (two-sided runs; their traced radiance holds the SH
    /// of stage 2's start, which keeps training, so they are saved rather than re-traced).
    #[serde(default)]
    has_back: bool,
    /// The sun searches' schedule (absent in older checkpoints, whose runs had a fixed one).
    #[serde(default)]
    sun_schedule: crate::stage2::SunSchedule,
    /// The views with a shaded set from their last render (`ShadeSets::LastVisit`); their
    /// words follow as the array `shade_sets` (absent in older checkpoints).
    #[serde(default)]
    shade_set_views: Vec<u32>,
    #[serde(default)]
    has_shade_sets: bool,
    /// Stage 1's per-photo colour corrections, applied unchanged (empty for none).
    #[serde(default)]
    photo_corrections: Vec<[f32; exposure::PARAMS]>,
    /// Surroundings' Gaussians stored after every other array (`Stage2::surroundings`).
    #[serde(default)]
    surroundings: usize,
}

fn push_microbuffer<'a>(arrays: &mut Vec<(String, &'a [u8])>, prefix: &str, mb: &'a MicroBuffer) {
    arrays.push((format!("{prefix}.normals"), bytes(&mb.normals)));
    arrays.push((format!("{prefix}.xi"), bytes(&mb.xi)));
    arrays.push((format!("{prefix}.vis"), bytes(&mb.vis)));
    arrays.push((format!("{prefix}.radiance"), bytes(&mb.radiance)));
    arrays.push((format!("{prefix}.first_hit"), bytes(&mb.first_hit)));
    arrays.push((format!("{prefix}.uv"), bytes(&mb.uv)));
}

/// The micro-buffer saved under `prefix` by [`push_microbuffer`], checked against `n` Gaussians
/// and `k` directions.
fn read_microbuffer(
    a: &mut Arrays,
    prefix: &str,
    k: usize,
    n: usize,
    path: &Path,
) -> Result<MicroBuffer, CheckpointError> {
    let mb = MicroBuffer {
        k,
        normals: a.next_as(&format!("{prefix}.normals"))?,
        xi: a.next_as(&format!("{prefix}.xi"))?,
        vis: a.next_as(&format!("{prefix}.vis"))?,
        radiance: a.next_as(&format!("{prefix}.radiance"))?,
        first_hit: a.next_as(&format!("{prefix}.first_hit"))?,
        uv: a.next_as(&format!("{prefix}.uv"))?,
        interleave: Default::default(),
    };
    let samples = n * k;
    if mb.normals.len() != n
        || mb.xi.len() != n
        || [mb.vis.len(), mb.radiance.len(), mb.first_hit.len(), mb.uv.len()].iter().any(|l| *l != samples)
    {
        return Err(corrupt(path, &format!("{prefix} micro-buffer arrays have the wrong size")));
    }
    Ok(mb)
}

/// Write a stage-2 trainer (geometry, materials, light, micro-buffers, Adam state) to `path` atomically.
pub fn save_stage2(t: &Stage2, path: &Path) -> Result<(), CheckpointError> {
    let mut arrays = surfel_arrays(&t.surfels);
    let (mb, mat) = (&t.mb, &t.materials);
    arrays.push(("albedo_raw".into(), bytes(&mat.albedo_raw)));
    arrays.push(("roughness_raw".into(), bytes(&mat.roughness_raw)));
    arrays.push(("normal_offset".into(), bytes(&mat.normal_offset)));
    arrays.push(("env".into(), bytes(&t.env.param)));
    push_microbuffer(&mut arrays, "mb", mb);
    push_groups(&mut arrays, &t.groups);
    arrays.push(("trace_opacity".into(), bytes(&t.trace_opacity)));
    if let Some(b) = &t.back {
        push_microbuffer(&mut arrays, "back", &b.mb);
    }
    let (shade_set_views, shade_set_words) = t.view_sets.parts();
    arrays.push(("shade_sets".into(), bytes(&shade_set_words)));
    if !t.surroundings.is_empty() {
        arrays.extend(surfel_arrays_named(&t.surroundings, "surroundings."));
    }
    let header = Header2 {
        config: t.config.clone(),
        iteration: t.iteration,
        rng_state: t.rng.state(),
        sh_degree: t.surfels.sh_degree,
        rho: t.rho,
        vertices: t.materials.m,
        env_size: (t.env.width, t.env.height),
        directions: t.mb.k,
        trace_seconds: t.trace_seconds,
        times: t.times.clone(),
        groups: strip(&t.groups),
        light_texels: t.lights.texels.clone(),
        light_dirs: t.lights.dirs.iter().map(|d| d.to_array()).collect(),
        has_trace_opacity: true,
        has_back: t.back.is_some(),
        sun_schedule: t.sun_schedule,
        shade_set_views,
        has_shade_sets: true,
        photo_corrections: t.photo_corrections.clone(),
        surroundings: t.surroundings.len(),
    };
    write_container(path, &header, &arrays)
}

/// Restore a stage-2 run.
pub fn load_stage2(path: &Path) -> Result<Stage2, CheckpointError> {
    let (h, mut a): (Header2, Arrays) = read_container(path)?;
    let surfels = read_surfels(&mut a, h.sh_degree)?;
    let n = surfels.len();
    let (albedo, rough, offset) = (a.next("albedo_raw")?, a.next("roughness_raw")?, a.next("normal_offset")?);
    let env: Vec<[f32; 3]> = a.next_as("env")?;
    let mb = read_microbuffer(&mut a, "mb", h.directions, n, path)?;
    let m = h.vertices;
    let texels = (h.env_size.0 * h.env_size.1) as usize;
    if albedo.len() != n * m * 3 || rough.len() != n * m || offset.len() != n * m * 3 || env.len() != texels {
        return Err(corrupt(path, "material or light arrays have the wrong size"));
    }
    let groups = read_groups::<7>(&mut a, &h.groups, &[n, n, n, n, n, texels, 1])?;
    let trace_opacity = if h.has_trace_opacity { Some(a.next("trace_opacity")?) } else { None };
    if trace_opacity.as_ref().is_some_and(|o| o.len() != n) {
        return Err(corrupt(path, "trace_opacity has the wrong size"));
    }
    let back_mb = if h.has_back { Some(read_microbuffer(&mut a, "back", h.directions, n, path)?) } else { None };
    let view_sets = if h.has_shade_sets {
        let words: Vec<u64> = a.next_as("shade_sets")?;
        ViewSets::from_parts(&h.shade_set_views, &words, n)
            .ok_or_else(|| corrupt(path, "shade_sets has the wrong size"))?
    } else {
        ViewSets::default()
    };
    let surroundings = if h.surroundings > 0 {
        let s = read_surfels_named(&mut a, h.sh_degree, "surroundings.")?;
        if s.len() != h.surroundings {
            return Err(corrupt(path, "surroundings have the wrong size"));
        }
        s
    } else {
        Surfels::default()
    };
    let rebuild = |e: svgir_pbr::PbrError| CheckpointError::Rebuild { path: path.to_path_buf(), what: e.to_string() };
    let mut t = Stage2::from_parts(h.config, surfels, mb, h.trace_seconds).map_err(rebuild)?;
    t.surroundings = surroundings;
    t.materials.albedo_raw = albedo;
    t.materials.roughness_raw = rough;
    t.materials.normal_offset = offset;
    t.env.param = env;
    t.rho = h.rho;
    t.groups = groups;
    t.iteration = h.iteration;
    t.rng = Rng::from_state(h.rng_state);
    t.times = h.times;
    t.sun_schedule = h.sun_schedule;
    t.view_sets = view_sets;
    t.photo_corrections = h.photo_corrections;
    if let Some(o) = trace_opacity {
        t.trace_opacity = o;
    }
    match back_mb {
        Some(mb) => t.set_back_side(mb).map_err(rebuild)?,
        None => t.trace_back_side().map_err(rebuild)?,
    }
    t.set_lights(&h.light_texels).map_err(rebuild)?;
    for (b, d) in h.light_dirs.iter().enumerate().take(t.lights.len()) {
        let d = glam::Vec3::from_array(*d);
        if d != t.lights.dirs[b] {
            t.move_light(b, d).map_err(rebuild)?;
        }
    }
    Ok(t)
}
