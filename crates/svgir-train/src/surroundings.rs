//! The surroundings of an object in a whole capture (issue 75 item 3): the Gaussians of a
//! model of the whole scene that lie near the object and are not part of it. Stage 2 keeps them
//! as occluders and as sources of traced radiance (SPEC 5: the micro-buffers see every
//! Gaussian), so the table under a vase shadows its foot and lights it with its own colour,
//! instead of the learned map standing in for both; they are never rendered, shaded or
//! trained (material and light are learned on the masked object). Relighting keeps them as
//! occluders: the object stays on its support under the new map.
//!
//! A scene Gaussian is kept when all three hold:
//! - it lies within `radius` object radii of the object's centre (the near field; what lies
//!   further, a room's walls, stays part of the learned map, as it must under a new map);
//! - it is outside the object's visual hull: its centre falls on the mask in fewer than
//!   `hull_share` of the photos that see it (a Gaussian of the object in the scene model, or a
//!   floater inside it, is on the mask in all of them);
//! - no object Gaussian's centre is within `margin` of the object's median surfel size times
//!   `margin` (the two models fit the same surface about a voxel apart; a scene Gaussian there
//!   would shadow the object's own surface from its first step).
//!
//! Work split: rayon over scene Gaussians; the object's centres go into a hash grid of cell
//! `margin` for the neighbour test. No I/O: the front end reads the models and the photos.

use glam::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;
use svgir_core::{Surfels, View};

/// How the surroundings are chosen (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurroundingsRule {
    /// Kept within this many object radii of the object's centre.
    pub radius: f32,
    /// A Gaussian on the mask in at least this share of the photos that see it is the object's.
    pub hull_share: f32,
    /// Dropped within this many median object surfel sizes of an object Gaussian.
    pub margin: f32,
}

impl Default for SurroundingsRule {
    fn default() -> Self {
        Self { radius: 2.0, hull_share: 0.9, margin: 3.0 }
    }
}

/// What the selection found, for the log and `config.json`.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SurroundingsReport {
    /// Gaussians of the scene model.
    pub scene: usize,
    /// Of them, within the near field.
    pub near: usize,
    /// Of those, inside the object's visual hull (dropped).
    pub in_hull: usize,
    /// Of the rest, within the margin of an object Gaussian (dropped).
    pub touching: usize,
    /// Kept.
    pub kept: usize,
    /// The object's centre (per-axis median of its Gaussians' centres).
    pub centre: [f32; 3],
    /// The object's radius (95th percentile distance from the centre).
    pub radius: f32,
}

/// Why the surroundings cannot be chosen.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SurroundingsError {
    /// The object model is empty.
    #[error("the object model has no Gaussians")]
    NoObject,
    #[error(
        "the photos carry no mask (every pixel is foreground), so the object's hull is unknown: \
         train the object with --masks first"
    )]
    /// No photo has a background pixel.
    NoMasks,
}

/// The object's centre (per-axis median of its centres) and radius (95th percentile distance
/// from it: a few floaters do not set it).
pub fn object_extent(object: &Surfels) -> Option<(Vec3, f32)> {
    if object.is_empty() {
        return None;
    }
    let median = |f: fn(&Vec3) -> f32| {
        let mut v: Vec<f32> = object.positions.iter().map(f).collect();
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    let c = Vec3::new(median(|p| p.x), median(|p| p.y), median(|p| p.z));
    let mut d: Vec<f32> = object.positions.iter().map(|p| p.distance(c)).collect();
    d.sort_by(f32::total_cmp);
    let r = d[((d.len() - 1) as f32 * 0.95) as usize];
    Some((c, r.max(1e-6)))
}

/// The median of the object's larger surfel scales.
fn median_size(object: &Surfels) -> f32 {
    let mut s: Vec<f32> = (0..object.len()).map(|i| object.scale(i).max_element()).collect();
    s.sort_by(f32::total_cmp);
    s[s.len() / 2]
}

/// True when the photo's alpha marks some pixels as background.
fn has_mask(view: &View) -> bool {
    let img = &view.image;
    img.channels == 4 && img.data.chunks_exact(4).any(|p| p[3] < 0.5)
}

/// True when `p` is on the mask in at least `share` of the photos whose frame holds it.
fn in_hull(p: Vec3, views: &[&View], share: f32) -> bool {
    let (mut seen, mut on) = (0usize, 0usize);
    for v in views {
        let img = &v.image;
        let Some((x, y, _)) = v.camera.project(p) else { continue };
        if !(x >= 0.0 && y >= 0.0 && x < img.width as f32 && y < img.height as f32) {
            continue;
        }
        seen += 1;
        on += usize::from(img.pixel(x as u32, y as u32)[3] >= 0.5);
    }
    seen > 0 && on as f32 >= share * seen as f32
}

/// The surroundings of `object` in `scene` under `rule`, judged against the masked photos
/// `views` (image alpha: the object's mask), and what the selection found.
pub fn select(
    scene: &Surfels,
    object: &Surfels,
    views: &[View],
    rule: &SurroundingsRule,
) -> Result<(Surfels, SurroundingsReport), SurroundingsError> {
    let (centre, radius) = object_extent(object).ok_or(SurroundingsError::NoObject)?;
    let masked: Vec<&View> = views.iter().filter(|v| has_mask(v)).collect();
    if masked.is_empty() {
        return Err(SurroundingsError::NoMasks);
    }
    let cell = (rule.margin * median_size(object)).max(1e-9);
    let key = |p: Vec3| (p / cell).floor().as_ivec3();
    let mut grid: HashMap<glam::IVec3, Vec<u32>> = HashMap::new();
    for (i, p) in object.positions.iter().enumerate() {
        grid.entry(key(*p)).or_default().push(i as u32);
    }
    let touches = |p: Vec3| {
        let k = key(p);
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    grid.get(&(k + glam::IVec3::new(dx, dy, dz)))
                        .is_some_and(|ids| ids.iter().any(|&i| object.positions[i as usize].distance(p) < cell))
                })
            })
        })
    };
    // Per scene Gaussian: 0 far, 1 in the hull, 2 touching, 3 kept.
    let class: Vec<u8> = scene
        .positions
        .par_iter()
        .map(|&p| {
            if p.distance(centre) > rule.radius * radius {
                0
            } else if in_hull(p, &masked, rule.hull_share) {
                1
            } else if touches(p) {
                2
            } else {
                3
            }
        })
        .collect();
    let count = |c: u8| class.iter().filter(|&&x| x == c).count();
    let mut kept = scene.clone();
    kept.retain(&class.iter().map(|&c| c == 3).collect::<Vec<_>>());
    let report = SurroundingsReport {
        scene: scene.len(),
        near: scene.len() - count(0),
        in_hull: count(1),
        touching: count(2),
        kept: kept.len(),
        centre: centre.to_array(),
        radius,
    };
    Ok((kept, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat4, Quat, Vec2};
    use svgir_core::{Camera, Image, Intrinsics, ShCoeffs};

    fn view(name: String, camera: Camera, image: Image) -> View {
        View { name, camera, image, albedo: None, normal: None, roughness: None, relit: Default::default() }
    }

    fn surfels(points: &[Vec3], log_scale: f32) -> Surfels {
        let mut s = Surfels::with_capacity(points.len(), 0);
        for &p in points {
            s.push(p, Quat::IDENTITY, Vec2::splat(log_scale), 2.0, ShCoeffs::default());
        }
        s
    }

    /// A ball of radius 0.5 at the origin on a floor at z = -0.5, photographed from a ring of
    /// cameras above, the masks being the ball's exact silhouette.
    #[test]
    fn keeps_the_floor_and_drops_the_ball_and_what_is_far() {
        let ball: Vec<Vec3> = (0..400)
            .map(|i| {
                let t = (i as f32 + 0.5) / 400.0;
                let z = 1.0 - 2.0 * t;
                let a = i as f32 * 2.399_963;
                let r = (1.0 - z * z).sqrt();
                0.5 * Vec3::new(r * a.cos(), r * a.sin(), z)
            })
            .collect();
        let object = surfels(&ball, (0.03f32).ln());
        // The scene model: the same ball a little off, a floater inside it, and a floor grid
        // out to 3 m (only the part within 2 object radii is near).
        let mut scene_points: Vec<Vec3> = ball.iter().map(|p| *p * 1.01).collect();
        scene_points.push(Vec3::new(0.05, 0.0, 0.1));
        let mut floor = 0;
        for ix in -30..=30 {
            for iy in -30..=30 {
                scene_points.push(Vec3::new(ix as f32 * 0.1, iy as f32 * 0.1, -0.5));
                floor += 1;
            }
        }
        let scene = surfels(&scene_points, (0.05f32).ln());
        let views: Vec<View> = (0..12)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 12.0;
                let eye = Vec3::new(3.0 * a.cos(), 3.0 * a.sin(), 1.5);
                let c2w = Mat4::look_at_rh(eye, Vec3::ZERO, Vec3::Z).inverse();
                let camera = Camera::from_blender_c2w(c2w, Intrinsics::from_fov_x(0.9, 64, 64)).unwrap();
                let mut image = Image::new(64, 64, 4);
                for y in 0..64 {
                    for x in 0..64 {
                        let d = camera.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
                        // Ray-sphere test for the silhouette.
                        let b = eye.dot(d);
                        let hit = b * b - (eye.length_squared() - 0.25) >= 0.0;
                        image.pixel_mut(x, y).copy_from_slice(&[0.5, 0.5, 0.5, f32::from(hit)]);
                    }
                }
                view(format!("v{i}"), camera, image)
            })
            .collect();
        let (kept, report) = select(&scene, &object, &views, &SurroundingsRule::default()).unwrap();
        assert!((report.radius - 0.5).abs() < 0.01, "{report:?}");
        // Every ball Gaussian and the floater go; so does the floor under the ball (inside the
        // hull seen from above) and beyond 1 m; the floor ring between stays.
        assert!(kept.positions.iter().all(|p| (p.z + 0.5).abs() < 1e-6), "only floor kept");
        let ring = scene_points
            .iter()
            .filter(|p| (p.z + 0.5).abs() < 1e-6 && p.length() <= 1.0 && p.truncate().length() > 0.6)
            .count();
        assert!(
            kept.len() >= ring * 9 / 10 && kept.len() < floor / 4,
            "kept {} of ring {ring}: {report:?}",
            kept.len()
        );
        assert_eq!(report.kept + report.in_hull + report.touching, report.near);
        // Photos without masks are refused.
        let unmasked: Vec<View> = views
            .iter()
            .map(|v| view(v.name.clone(), v.camera, Image::filled(64, 64, &[0.5, 0.5, 0.5, 1.0])))
            .collect();
        assert_eq!(
            select(&scene, &object, &unmasked, &SurroundingsRule::default()).unwrap_err(),
            SurroundingsError::NoMasks
        );
    }
}
