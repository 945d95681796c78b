//! Automatic foreground masks for object-centred captures that come without masks, derived from
//! the stage-1 reconstruction itself (no learned segmentation, no downloaded weights).
//!
//! 1. **Focus**: the point nearest to every training camera's optical axis (least squares):
//!    what the photographer circled.
//! 2. **Candidates**: Gaussians inside the image of at least `seen_fraction` of the cameras, in
//!    front of them: the region every photo looks at.
//! 3. **Support**: if the candidates' dominant plane (RANSAC) holds a large share of them, has
//!    every camera and the focus on one side, it is what the object stands on; its inliers and
//!    everything beyond it are background.
//! 4. **One object**: the connected cluster (26-neighbour voxel grid) with the most candidates
//!    is the seed; it grows over every Gaussian connected to it above the support and within
//!    `grow` times its radius (the parts some photos cut off). Near the support it grows only
//!    over the seed's footprint on it: beyond the object's base, what lies there is the
//!    support's own scatter in front of it, thicker than the slab (nothing behind a wall holds
//!    its depth) and connected to the object. Floaters and the rest of the scene go.
//! 5. **Masks by rendering**: each view renders the foreground share of its pixels (foreground
//!    Gaussians carry 1, the rest 0, composited as colour), so occlusion by the background is
//!    the renderer's; the mask is that share over the pixel's opacity, 0.5 the threshold.
//!
//! Gaussians seen clipped (every channel at the photo's maximum) from a good share of the photos
//! take no part in steps 2-4: a blown-out region has no texture nor shading, so any depth fits
//! it, and stage 1 leaves sheets of such Gaussians where densification happened to put them
//! (beside a white object in front of an overexposed wall, at the object's depth). They still
//! render. The object's own blown-out parts are taken back after step 4: those touching it, and
//! those inside its outline's convex hull in most photos.
//!
//! Every size is relative to the candidates' spread around the focus, so the result does not
//! depend on the capture's units. All random choices come from the given [`Rng`].

use glam::{DMat3, DVec3, Vec3};
use serde::{Deserialize, Serialize};
use svgir_core::{Camera, Rng, Surfels};
use svgir_raster::{render, Background, ColorSource, Features, RasterConfig, RenderInput};

mod cells;
mod hull;

use cells::{Clusters, Footprint};
use hull::{hull, in_hull};

/// Thresholds of the foreground selection of a capture's Gaussians.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ForegroundConfig {
    /// A candidate is inside at least this share of the cameras' images.
    pub seen_fraction: f32,
    /// Image border (share of the image side) a candidate must be inside of.
    pub image_margin: f32,
    /// A support plane must hold at least this share of the points searched (the opaque
    /// Gaussians' centres, or the seen surface points).
    pub min_plane_share: f32,
    /// Seen surface points count within this many times the candidates' median distance to the
    /// focus: what the object stands on, not the far room.
    pub support_radius: f32,
    /// Seen points beyond a plane count against it within this many times the candidates'
    /// median distance to the focus.
    pub beyond_radius: f32,
    /// Longer side (pixels) of the renders whose depths give the seen surface points.
    pub surface_samples_side: u32,
    /// Plane inlier distance, as a share of the candidates' median distance to the focus.
    pub plane_tolerance: f32,
    /// RANSAC plane hypotheses.
    pub ransac_iterations: usize,
    /// Connectivity voxel side, as a share of the candidates' median distance to the focus.
    pub voxel: f32,
    /// Gaussians below this opacity take no part in the selection (they still render).
    pub min_opacity: f32,
    /// The object may extend to this many times the seed cluster's distance from the focus.
    pub grow: f32,
    /// Connectivity voxel of the growth, as a multiple of `voxel` (coarser: it bridges the
    /// sparser, fainter Gaussians of the parts few photos see).
    pub grow_voxel: f32,
    /// A photo's pixel is clipped when every colour channel is at least this (8-bit photos load
    /// as stored over 255, so 0.99 is 252.5 and up).
    pub clipped_level: f32,
    /// A Gaussian whose centre lands on a clipped pixel in at least this share of the photos it
    /// is inside of is no evidence of the object (module docs).
    pub clipped_share: f32,
    /// Below this height over the support (a share of the candidates' median distance to the
    /// focus), the object grows only over the seed cluster's footprint on the support.
    pub low_height: f32,
}

impl Default for ForegroundConfig {
    fn default() -> Self {
        Self {
            seen_fraction: 0.9,
            image_margin: 0.02,
            min_plane_share: 0.1,
            support_radius: 3.0,
            beyond_radius: 1.5,
            surface_samples_side: 64,
            plane_tolerance: 0.04,
            ransac_iterations: 500,
            voxel: 0.05,
            min_opacity: 0.05,
            grow: 2.5,
            grow_voxel: 2.0,
            clipped_level: 0.99,
            clipped_share: 0.3,
            low_height: 0.5,
        }
    }
}

/// A plane `n . x = d` with `n` unit, the cameras on its positive side.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Plane {
    /// Unit normal n, pointing to the cameras' side.
    pub normal: Vec3,
    /// Offset d of `n . x = d`, world units.
    pub d: f32,
}

impl Plane {
    /// Signed distance of `p` from the plane, positive on the cameras' side.
    pub fn signed_distance(&self, p: Vec3) -> f32 {
        self.normal.dot(p) - self.d
    }
}

/// What the selection found, for the masks and for the report.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Foreground {
    /// Point nearest to the cameras' optical axes, world space.
    pub focus: Vec3,
    /// Median distance of the candidates from the focus: the unit of every tolerance.
    pub scale: f32,
    /// Number of candidate Gaussians considered.
    pub candidates: usize,
    /// The supporting plane (table, floor) under the object, if one was found.
    pub support: Option<Plane>,
    /// Gaussians within the plane tolerance of the support.
    pub support_inliers: usize,
    /// Thickness of the slab in front of the support that was removed with it, as a share of
    /// `scale` (0 without a support).
    pub support_slab: f32,
    /// Size and radius (from the focus) of the seed cluster.
    pub seed_count: usize,
    /// Radius of the seed cluster from the focus, world units.
    pub seed_radius: f32,
    /// Candidates' heights above the support: 10th, 50th and 90th percentiles (in `scale`).
    pub candidate_heights: Option<[f32; 3]>,
    /// Per Gaussian: part of the object.
    #[serde(skip)]
    pub selected: Vec<bool>,
    /// Number of Gaussians selected as the object.
    pub selected_count: usize,
    /// Opaque Gaussians left out of the selection because the photos see them clipped.
    pub clipped: usize,
}

/// The point nearest to all cameras' optical axes; `None` when they are (nearly) parallel.
pub fn focus_point(cameras: &[Camera]) -> Option<Vec3> {
    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for cam in cameras {
        let d = cam.forward().as_dvec3().normalize();
        let p = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += p;
        b += p * cam.center().as_dvec3();
    }
    // Parallel axes leave the system singular along them.
    let det = a.determinant();
    (cameras.len() >= 2 && det.abs() > 1e-6 * (cameras.len() as f64).powi(3)).then(|| (a.inverse() * b).as_vec3())
}

/// The image position of `p` in `cam`, if it falls inside the image.
fn pixel_of(cam: &Camera, p: Vec3) -> Option<(f32, f32)> {
    pixel_within(cam, p, 0.0)
}

/// The image position of `p` in `cam`, if it falls inside the image less `margin` (a share of
/// its width and height) on every side.
fn pixel_within(cam: &Camera, p: Vec3, margin: f32) -> Option<(f32, f32)> {
    let (x, y, _) = cam.project(p)?;
    let (w, h) = (cam.width() as f32, cam.height() as f32);
    (x >= margin * w && x < (1.0 - margin) * w && y >= margin * h && y < (1.0 - margin) * h).then_some((x, y))
}

/// Per Gaussian: its centre lands on a clipped pixel (every colour channel at least
/// `cfg.clipped_level`) in at least `cfg.clipped_share` of the photos it is inside of. `photos`
/// are the cameras' images: interleaved values, `channels` a pixel, colour first.
pub fn clipped_gaussians(
    surfels: &Surfels,
    cameras: &[Camera],
    photos: &[(&[f32], usize)],
    cfg: &ForegroundConfig,
) -> Vec<bool> {
    assert_eq!(cameras.len(), photos.len(), "one photo per camera");
    (0..surfels.len())
        .map(|i| {
            let p = surfels.positions[i];
            let (mut inside, mut clipped) = (0usize, 0usize);
            for (cam, &(data, ch)) in cameras.iter().zip(photos) {
                let Some((x, y)) = pixel_of(cam, p) else { continue };
                inside += 1;
                let k = (y as usize * cam.width() as usize + x as usize) * ch;
                if data[k..k + ch.min(3)].iter().all(|&v| v >= cfg.clipped_level) {
                    clipped += 1;
                }
            }
            inside > 0 && clipped as f32 >= cfg.clipped_share * inside as f32
        })
        .collect()
}

/// Steps 1-4 of the module docs; `clipped` (per Gaussian, from [`clipped_gaussians`], or empty)
/// marks the Gaussians that take no part in the object.
pub fn select_foreground(
    surfels: &Surfels,
    cameras: &[Camera],
    clipped: &[bool],
    raster: &RasterConfig,
    cfg: &ForegroundConfig,
    rng: &mut Rng,
) -> Result<Foreground, String> {
    let focus = focus_point(cameras).ok_or("the cameras' optical axes do not meet: not an object-centred capture")?;
    let n = surfels.len();
    let need = (cfg.seen_fraction * cameras.len() as f32).ceil() as usize;
    let opaque: Vec<usize> = (0..n).filter(|&i| surfels.opacity(i) >= cfg.min_opacity).collect();
    let seen_by_all =
        |p: Vec3| cameras.iter().filter(|c| pixel_within(c, p, cfg.image_margin).is_some()).count() >= need;
    let is_clipped = |i: usize| clipped.get(i).copied().unwrap_or(false);
    let idx: Vec<usize> =
        opaque.iter().copied().filter(|&i| !is_clipped(i) && seen_by_all(surfels.positions[i])).collect();
    if idx.len() < 10 {
        return Err(format!(
            "only {} Gaussians lie where every camera looks; is this an object-centred capture?",
            idx.len()
        ));
    }
    let mut dists: Vec<f32> = idx.iter().map(|&i| (surfels.positions[i] - focus).length()).collect();
    dists.sort_by(f32::total_cmp);
    let scale = dists[dists.len() / 2].max(1e-9);

    // The support is searched first among every opaque Gaussian's centre (a table is large, and
    // photos framed on the object show only part of it), then, if none qualifies, among the
    // surface points the photos see near the focus (each view's median depth, back-projected):
    // a plain table may be a few large Gaussians, and a capture without sparse points keeps a
    // random start's floaters where no photo sees them, but every pixel votes the same.
    let tol = cfg.plane_tolerance * scale;
    let near_support = |p: &Vec3| (*p - focus).length() <= cfg.support_radius * scale;
    let centres: Vec<Vec3> = opaque.iter().map(|&i| surfels.positions[i]).collect();
    let found = support_plane(&centres, cameras, focus, scale, false, cfg, rng).or_else(|| {
        let seen: Vec<Vec3> =
            seen_surface(surfels, cameras, raster, cfg.surface_samples_side).into_iter().filter(near_support).collect();
        support_plane(&seen, cameras, focus, scale, true, cfg, rng)
    });
    let (support, support_inliers) = match found {
        Some((pl, c)) => (Some(pl), c),
        None => (None, 0),
    };
    let candidate_heights = support.map(|pl| {
        let mut h: Vec<f32> = idx.iter().map(|&i| pl.signed_distance(surfels.positions[i]) / scale).collect();
        h.sort_by(f32::total_cmp);
        let q = |f: f32| h[((h.len() - 1) as f32 * f) as usize];
        [q(0.1), q(0.5), q(0.9)]
    });
    // The support's own Gaussians scatter about its plane, the more the plainer it is (a white
    // wall's depth is weakly held by the photos). Nothing lies behind a support, so what lies
    // within 5 tolerances behind it is that scatter; in front it is as wide, so the slab removed
    // is its 90th percentile, between 1 and 3 tolerances.
    let slab = support.map_or(tol, |pl| {
        let mut behind: Vec<f32> = centres
            .iter()
            .filter(|p| near_support(p))
            .map(|p| -pl.signed_distance(*p))
            .filter(|&d| d > 0.0 && d < 5.0 * tol)
            .collect();
        behind.sort_by(f32::total_cmp);
        behind.get(behind.len() * 9 / 10).map_or(tol, |&q| q.clamp(tol, 3.0 * tol))
    });
    let above_support = |p: Vec3| support.is_none_or(|pl| pl.signed_distance(p) >= slab);
    // The seed: the largest cluster of what every camera sees, above the support.
    let kept: Vec<usize> = idx.iter().copied().filter(|&i| above_support(surfels.positions[i])).collect();
    let voxel = cfg.voxel * scale;
    let seed = Clusters::new(surfels, &kept, voxel);
    let seed_members = seed.largest().map(|c| seed.members(&[c], n)).unwrap_or_else(|| vec![false; n]);
    let seed_radius =
        (0..n).filter(|&i| seed_members[i]).map(|i| (surfels.positions[i] - focus).length()).fold(0.0f32, f32::max);
    // Grow it over every Gaussian connected to it (parts of the object that some photos cut
    // off), above the support and within `grow` times the seed's radius.
    // Near the support it grows only over the seed's footprint on it: what lies there beyond
    // the object's own base is the support's scatter in front of it, which is thicker than the
    // slab (nothing is seen behind a wall to hold it), and connected.
    let footprint = support.map(|pl| {
        Footprint::new(pl, voxel * cfg.grow_voxel, (0..n).filter(|&i| seed_members[i]).map(|i| surfels.positions[i]))
    });
    let low = cfg.low_height * scale;
    let over_base = |p: Vec3| footprint.as_ref().is_none_or(|f| f.admits(p, low));
    let eligible: Vec<usize> = opaque
        .iter()
        .copied()
        .filter(|&i| {
            let p = surfels.positions[i];
            !is_clipped(i) && (p - focus).length() <= cfg.grow * seed_radius && above_support(p) && over_base(p)
        })
        .collect();
    let all = Clusters::new(surfels, &eligible, voxel * cfg.grow_voxel);
    let mut comps: Vec<usize> = (0..n)
        .filter(|&i| seed_members[i])
        .filter_map(|i| all.label.get(&all.key(surfels.positions[i])).copied())
        .collect();
    comps.sort_unstable();
    comps.dedup();
    let mut selected = all.members(&comps, n);
    let joining: Vec<usize> = opaque
        .iter()
        .copied()
        .filter(|&i| {
            let p = surfels.positions[i];
            is_clipped(i) && above_support(p) && (p - focus).length() <= cfg.grow * seed_radius
        })
        .collect();
    readmit_clipped(surfels, cameras, raster, voxel, &joining, &mut selected);
    let selected_count = selected.iter().filter(|s| **s).count();
    let clipped_out = opaque.iter().filter(|&&i| is_clipped(i) && !selected[i]).count();
    if selected_count == 0 {
        return Err("no object left after removing the support plane".into());
    }
    Ok(Foreground {
        focus,
        scale,
        candidates: idx.len(),
        support,
        support_inliers,
        support_slab: if support.is_some() { slab / scale } else { 0.0 },
        seed_count: seed_members.iter().filter(|s| **s).count(),
        seed_radius,
        candidate_heights,
        selected,
        selected_count,
        clipped: clipped_out,
    })
}

/// Clipped Gaussians (`joining`) next to the object, within a voxel of a selected one (no
/// chaining), are its own blown-out parts, a white stripe between coloured ones; a sheet beside
/// it is not. So are those inside the convex hull of the object's silhouette in most of the
/// photos they are inside of: a highlight on a white bust, which may reach its outline.
fn readmit_clipped(
    surfels: &Surfels,
    cameras: &[Camera],
    raster: &RasterConfig,
    voxel: f32,
    joining: &[usize],
    selected: &mut [bool],
) {
    if joining.is_empty() {
        return;
    }
    let sel_idx: Vec<usize> = (0..selected.len()).filter(|&i| selected[i]).collect();
    let near = Clusters::new(surfels, &sel_idx, voxel);
    let hulls: Vec<Vec<(f32, f32)>> =
        cameras.iter().map(|cam| hull(&render_share(surfels, selected, cam, raster), cam.width() as usize)).collect();
    for &i in joining {
        let p = surfels.positions[i];
        let (mut inside, mut within) = (0usize, 0usize);
        for (cam, h) in cameras.iter().zip(&hulls) {
            if let Some(px) = pixel_of(cam, p) {
                inside += 1;
                within += in_hull(h, px) as usize;
            }
        }
        if near.touches(p) || 2 * within > inside {
            selected[i] = true;
        }
    }
}

/// Points on the surfaces each camera sees: its median depth back-projected at the pixels of a
/// render whose longer side is `side` pixels and whose opacity is at least a half.
pub fn seen_surface(surfels: &Surfels, cameras: &[Camera], raster: &RasterConfig, side: u32) -> Vec<Vec3> {
    let feats = vec![0.0f32; 3 * surfels.len()];
    let raster = RasterConfig { geometry: true, ..*raster };
    let mut out = Vec::new();
    for cam in cameras {
        let f = side as f32 / cam.width().max(cam.height()) as f32;
        let small = if f < 1.0 {
            cam.resized(
                ((cam.width() as f32 * f).round() as u32).max(1),
                ((cam.height() as f32 * f).round() as u32).max(1),
            )
        } else {
            *cam
        };
        let input = RenderInput {
            surfels,
            camera: &small,
            colors: ColorSource::Features(Features { data: &feats, vertices: 1, channels: 3, uniform: 0 }),
            extra: None,
            background: Background::Color([0.0; 3]),
        };
        let (img, _) = render(&input, &raster);
        let (w, fwd) = (small.width() as usize, small.forward());
        for (i, (&a, &z)) in img.alpha.iter().zip(&img.median_depth).enumerate() {
            if a >= 0.5 && z > 0.0 {
                let d = small.ray_dir((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                out.push(small.center() + d * (z / d.dot(fwd)));
            }
        }
    }
    out
}

/// RANSAC over points on the scene's surfaces, sizes relative to `scale` (the candidates' median
/// distance to the focus); a plane counts as a support only under the module's conditions
/// (share, every camera and the focus on one side).
fn support_plane(
    pts: &[Vec3],
    cameras: &[Camera],
    focus: Vec3,
    scale: f32,
    seen_points: bool,
    cfg: &ForegroundConfig,
    rng: &mut Rng,
) -> Option<(Plane, usize)> {
    if pts.len() < 3 {
        return None;
    }
    // Each hypothesis faces the cameras and scores its inliers, less, for `seen_points`, the
    // points beyond it: a flat part of the object (a saucer, a plinth) fills many pixels too,
    // but the photos see the table beyond it, while nothing is seen beyond the table. (Centres
    // beyond a plane are no such evidence: a random start leaves floaters under the table.)
    // Only what is seen beyond it near the object counts against a plane: under a saucer lies
    // the table, but past a table's far edge the photos may well see the floor.
    let mean_cam = cameras.iter().map(|c| c.center()).sum::<Vec3>() / cameras.len() as f32;
    let tol = cfg.plane_tolerance * scale;
    let near_focus = cfg.beyond_radius * scale;
    let mut best: Option<(i64, usize, Plane)> = None;
    for _ in 0..cfg.ransac_iterations {
        let (a, b, c) = (pts[rng.below(pts.len())], pts[rng.below(pts.len())], pts[rng.below(pts.len())]);
        let nrm = (b - a).cross(c - a);
        if nrm.length_squared() < 1e-20 {
            continue;
        }
        let mut nrm = nrm.normalize();
        if nrm.dot(mean_cam - a) < 0.0 {
            nrm = -nrm;
        }
        let pl = Plane { normal: nrm, d: nrm.dot(a) };
        let (mut inliers, mut beyond) = (0usize, 0usize);
        for p in pts {
            let h = pl.signed_distance(*p);
            if h.abs() < tol {
                inliers += 1;
            } else if seen_points && h < 0.0 && (*p - focus).length() <= near_focus {
                beyond += 1;
            }
        }
        let score = inliers as i64 - beyond as i64;
        if best.as_ref().is_none_or(|(s, _, _)| score > *s) {
            best = Some((score, inliers, pl));
        }
    }
    let (_, count, pl) = best?;
    if (count as f32) < cfg.min_plane_share * pts.len() as f32 {
        return None;
    }
    // All the cameras, and the object's centre, must be on the cameras' side.
    let all_above = cameras.iter().all(|c| pl.signed_distance(c.center()) > tol);
    (all_above && pl.signed_distance(focus) > tol).then_some((pl, count))
}

/// Soft mask of one view: the foreground's share of each pixel's opacity (0 where nothing is).
pub fn render_share(surfels: &Surfels, selected: &[bool], camera: &Camera, raster: &RasterConfig) -> Vec<f32> {
    let feats: Vec<f32> = selected.iter().flat_map(|&s| [if s { 1.0 } else { 0.0 }; 3]).collect();
    let input = RenderInput {
        surfels,
        camera,
        colors: ColorSource::Features(Features { data: &feats, vertices: 1, channels: 3, uniform: 0 }),
        extra: None,
        background: Background::Color([0.0; 3]),
    };
    let (out, _) = render(&input, raster);
    out.color
        .chunks_exact(3)
        .zip(&out.alpha)
        .map(|(c, &a)| if a > 1e-3 { (c[0] / a).clamp(0.0, 1.0) } else { 0.0 })
        .collect()
}

#[cfg(test)]
mod tests;
