//! Diagnostic: how right is the traced visibility? Loads a stage-2 checkpoint and the dataset's
//! ground-truth `mesh.ply`, and for every (Gaussian, direction) of the micro-buffers casts the
//! same direction against the mesh from the Gaussian's centre moved onto the mesh along its
//! normal (Gaussians farther than `--snap` x the mesh's bounding diagonal from the mesh, along
//! their normal, are skipped and counted).
//!
//! It prints, weighted by the cosine `n . w_k` (what diffuse shading weighs a direction by):
//! - the mean cosine-weighted visible fraction of the hemisphere, traced vs mesh (a bias here
//!   is a bias in irradiance, which the albedo absorbs);
//! - the confusion of traced V (>= 0.5 or not) against mesh visibility: "false shadow" (mesh
//!   open, V < 0.5) and "leak" (mesh blocked, V >= 0.5), split by elevation (grazing rays vs
//!   steep ones), and leaks by whether the traced ray hit anything at all (a miss: a hole in the
//!   surfels; a hit with V >= 0.5: a surface too transparent or only grazed at its faint rim).
//!
//! `cargo run --release -p svgir-diagnose --bin visibility_vs_mesh -- CHECKPOINT DATA [--stride N] [--snap F]`

use anyhow::{Context, Result};
use glam::Vec3;
use rayon::prelude::*;
use std::path::Path;
use svgir_diagnose::mesh::{read_mesh, Bvh};

/// Elevation bins of `n . w` (SPEC 4's lowest direction is at sin 10 deg = 0.17).
const ELEV: [f32; 4] = [0.0, 0.3, 0.6, 1.01];
/// Gaussians whose normal is farther than this from the mesh's where they snap are not compared.
const MAX_NORMAL_ERROR_DEG: f32 = 30.0;

#[derive(Default, Clone)]
struct Tally {
    /// Cosine-weighted sums.
    w: f64,
    vis_mb: f64,
    vis_mesh: f64,
    abs_diff: f64,
    /// Confusion `[mesh open?][traced V >= 0.5?]` per elevation bin.
    conf: [[[f64; 2]; 2]; 3],
    /// Leaks (mesh blocked, V >= 0.5) whose traced ray hit nothing vs hit something.
    leak_miss: f64,
    leak_hit: f64,
    /// Per-Gaussian |E_mb - E_mesh| of the cosine-weighted visible fraction, summed.
    gauss_abs: f64,
    gaussians: usize,
    skipped: usize,
    /// Snapped, but the mesh normal there is more than `MAX_NORMAL_ERROR_DEG` off.
    disagree: usize,
    /// Directional lights, cosine-weighted: total, traced V, mesh open, leak, false shadow.
    light: [f64; 5],
    /// Of those, the ones whose normal is within `MAX_NORMAL_ERROR_DEG` of the mesh's reversed
    /// (mesh files do not always orient their vertex normals outwards either).
    flipped: usize,
}

impl Tally {
    fn merge(mut self, o: Tally) -> Tally {
        self.w += o.w;
        self.vis_mb += o.vis_mb;
        self.vis_mesh += o.vis_mesh;
        self.abs_diff += o.abs_diff;
        for e in 0..3 {
            for a in 0..2 {
                for b in 0..2 {
                    self.conf[e][a][b] += o.conf[e][a][b];
                }
            }
        }
        self.leak_miss += o.leak_miss;
        self.leak_hit += o.leak_hit;
        self.gauss_abs += o.gauss_abs;
        self.gaussians += o.gaussians;
        self.skipped += o.skipped;
        self.disagree += o.disagree;
        self.flipped += o.flipped;
        for i in 0..5 {
            self.light[i] += o.light[i];
        }
        self
    }
}

/// One `--dump` row: Gaussian, centre, normal, opacity, then `cols` ("nan" where not compared).
fn csv_row(j: usize, p: Vec3, n: Vec3, opacity: f32, cols: &[f64]) -> String {
    let rest: Vec<String> =
        cols.iter().map(|x| if x.is_nan() { "nan".to_string() } else { format!("{x:.4}") }).collect();
    format!("{j},{},{},{},{},{},{},{opacity:.4},{}", p.x, p.y, p.z, n.x, n.y, n.z, rest.join(","))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() >= 3, "usage: visibility_vs_mesh CHECKPOINT DATA [--stride N] [--snap F]");
    let mut stride = 1usize;
    let mut snap = 0.01f32;
    let mut dump: Option<String> = None;
    let mut light_map: Option<(String, f32, usize)> = None;
    let mut i = 3;
    while i < args.len() {
        match args[i].as_str() {
            "--stride" => stride = args.get(i + 1).context("--stride N")?.parse()?,
            "--snap" => snap = args.get(i + 1).context("--snap F")?.parse()?,
            "--dump" => dump = Some(args.get(i + 1).context("--dump CSV")?.clone()),
            "--lights" => {
                let a = args.get(i + 1..i + 4).context("--lights MAP STRENGTH COUNT")?;
                light_map = Some((a[0].clone(), a[1].parse()?, a[2].parse()?));
                i += 2;
            }
            a => anyhow::bail!("unknown argument {a}"),
        }
        i += 2;
    }
    let mut s2 = svgir_train::checkpoint::load_stage2(Path::new(&args[1]))?;
    if let Some((map, strength, count)) = &light_map {
        let env = svgir_io::read_envmap(map, *strength, s2.config.env_height)?;
        s2.set_lights(&svgir_trace::brightest_texels(&env, *count))?;
    }
    let lights = &s2.lights;
    let mesh_path = Path::new(&args[2]).join("mesh.ply");
    let mesh = read_mesh(&mesh_path).with_context(|| format!("reading {}", mesh_path.display()))?;
    let bvh = Bvh::build(&mesh);
    let (lo, hi) =
        mesh.verts.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(l, h), p| (l.min(*p), h.max(*p)));
    let diag = (hi - lo).length();
    let reach = snap * diag;
    let lift = 1e-4 * diag;
    let mb = &s2.mb;
    let k = mb.k;

    let rows = std::sync::Mutex::new(Vec::<String>::new());
    let t = (0..mb.len())
        .into_par_iter()
        .step_by(stride)
        .fold(Tally::default, |mut t, j| {
            let n = mb.normals[j];
            let p = s2.surfels.positions[j];
            // Snap the centre onto the mesh along +-n: the nearer crossing after which the mesh is
            // open along +n (inside a thin wall, the nearer crossing can be the far side).
            let normal_at = |h: &svgir_diagnose::mesh::Hit| {
                let t = mesh.idx[h.tri as usize].map(|i| mesh.vnormals[i as usize]);
                (t[0] * (1.0 - h.u - h.v) + t[1] * h.u + t[2] * h.v).normalize_or_zero()
            };
            let up = bvh.intersect(p, n, 0.0, reach, false).map(|h| (p + n * (h.t + lift), normal_at(&h)));
            let down = bvh.intersect(p, -n, 0.0, reach, false).map(|h| (p - n * (h.t - lift), normal_at(&h)));
            let mut cands: Vec<(Vec3, Vec3)> = up.into_iter().chain(down).collect();
            cands.sort_by(|a, b| (a.0 - p).length().total_cmp(&(b.0 - p).length()));
            let Some((origin, n_mesh)) =
                cands.into_iter().find(|(o, _)| bvh.intersect(*o, n, 0.0, reach, true).is_none())
            else {
                t.skipped += 1;
                return t;
            };
            // Gaussians on edges or with wrong normals are not comparable: their hemisphere is not
            // the true surface's.
            if n_mesh.dot(n) < MAX_NORMAL_ERROR_DEG.to_radians().cos() {
                t.disagree += 1;
                if n_mesh.dot(n) < -MAX_NORMAL_ERROR_DEG.to_radians().cos() {
                    t.flipped += 1;
                }
                if dump.is_some() {
                    let nan = f64::NAN;
                    let cols = [nan, nan, nan, nan, n_mesh.dot(n) as f64, nan, nan];
                    rows.lock().unwrap().push(csv_row(j, p, n, s2.surfels.opacity(j), &cols));
                }
                return t;
            }
            let (mut e_mb, mut e_mesh, mut wsum) = (0.0f64, 0.0f64, 0.0f64);
            let (mut leak_miss, mut leak_hit) = (0.0f64, 0.0f64);
            for kk in 0..k {
                let d = mb.direction(j, kk);
                let c = n.dot(d).max(0.0) as f64;
                let v = mb.visibility(j, kk) as f64;
                let open = bvh.intersect(origin, d, 0.0, f32::MAX, true).is_none();
                let vm = if open { 1.0 } else { 0.0 };
                wsum += c;
                e_mb += c * v;
                e_mesh += c * vm;
                t.abs_diff += c * (v - vm).abs();
                let e = ELEV.windows(2).position(|b| (c as f32) >= b[0] && (c as f32) < b[1]).unwrap_or(2);
                t.conf[e][open as usize][(v >= 0.5) as usize] += c;
                if !open && v >= 0.5 {
                    if mb.hit(j, kk).is_some() {
                        leak_hit += c;
                    } else {
                        leak_miss += c;
                    }
                }
            }
            // Directional lights: traced light visibility against the mesh.
            let mut lit = [0.0f64; 5];
            for b in 0..lights.len() {
                let d = lights.dirs[b];
                let c = n.dot(d) as f64;
                if c <= 0.0 {
                    continue;
                }
                let open = bvh.intersect(origin, d, 0.0, f32::MAX, true).is_none();
                let v = lights.visibility(j, b) as f64;
                lit[0] += c;
                lit[1] += c * v;
                lit[2] += if open { c } else { 0.0 };
                lit[3] += if !open && v >= 0.5 { c } else { 0.0 };
                lit[4] += if open && v < 0.5 { c } else { 0.0 };
            }
            for (a, b) in t.light.iter_mut().zip(lit) {
                *a += b;
            }
            t.leak_hit += leak_hit;
            t.leak_miss += leak_miss;
            if dump.is_some() {
                let w = wsum.max(1e-12);
                let lw = lit[0].max(1e-12);
                let cols =
                    [e_mb / w, e_mesh / w, leak_miss / w, leak_hit / w, n_mesh.dot(n) as f64, lit[1] / lw, lit[2] / lw];
                rows.lock().unwrap().push(csv_row(j, p, n, s2.surfels.opacity(j), &cols));
            }
            t.w += wsum;
            t.vis_mb += e_mb;
            t.vis_mesh += e_mesh;
            if wsum > 0.0 {
                t.gauss_abs += ((e_mb - e_mesh) / wsum).abs();
            }
            t.gaussians += 1;
            t
        })
        .reduce(Tally::default, Tally::merge);

    println!(
        "{} Gaussians x {} directions (every {stride}th); {} compared, {} skipped (no mesh within {snap} x diagonal along the normal), {} with a normal more than {MAX_NORMAL_ERROR_DEG} deg off the mesh's ({} of them reversed)",
        mb.len(),
        k,
        t.gaussians,
        t.skipped,
        t.disagree,
        t.flipped
    );
    let w = t.w.max(1e-12);
    println!("cosine-weighted visible fraction: traced {:.4}, mesh {:.4}", t.vis_mb / w, t.vis_mesh / w);
    println!(
        "mean |V - V_mesh| per ray {:.4}; per Gaussian |E_traced - E_mesh| {:.4}",
        t.abs_diff / w,
        t.gauss_abs / t.gaussians.max(1) as f64
    );
    println!("confusion (fractions of all cosine weight):");
    println!("elevation n.w   mesh open: V>=.5  V<.5 (false shadow) | mesh blocked: V>=.5 (leak)  V<.5");
    for e in 0..3 {
        let c = &t.conf[e];
        println!(
            "[{:.1},{:.1})        {:.4}  {:.4}                 | {:.4}  {:.4}",
            ELEV[e],
            ELEV[e + 1].min(1.0),
            c[1][1] / w,
            c[1][0] / w,
            c[0][1] / w,
            c[0][0] / w
        );
    }
    if let Some(path) = dump {
        let mut rows = rows.into_inner().unwrap();
        rows.sort_by_key(|r| r.split(',').next().and_then(|x| x.parse::<usize>().ok()));
        let body = format!(
            "j,x,y,z,nx,ny,nz,opacity,e_traced,e_mesh,leak_miss,leak_hit,normal_dot,light_traced,light_mesh\n{}\n",
            rows.join("\n")
        );
        std::fs::write(&path, body).with_context(|| format!("writing {path}"))?;
    }
    if t.light[0] > 0.0 {
        let l = t.light.map(|x| x / t.light[0]);
        println!(
            "directional lights ({}): lit fraction traced {:.4}, mesh {:.4}; leak {:.4}, false shadow {:.4}",
            lights.len(),
            l[1],
            l[2],
            l[3],
            l[4]
        );
    }
    println!("leaks whose traced ray hit nothing {:.4}, hit something {:.4}", t.leak_miss / w, t.leak_hit / w);
    Ok(())
}
