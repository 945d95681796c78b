//! The selection on synthetic scenes: a ball on a table, with scatter, a blown-out sheet, floaters.
use super::*;
use glam::{Mat4, Quat, Vec2};
use svgir_core::{Intrinsics, ShCoeffs};

/// `n` cameras on a ring looking at (0, 0, 0.3), the centre of the test's ball.
fn ring_cameras(n: usize, radius: f32, height: f32) -> Vec<Camera> {
    (0..n)
        .map(|k| {
            let a = k as f32 / n as f32 * std::f32::consts::TAU;
            let eye = Vec3::new(radius * a.cos(), radius * a.sin(), height);
            let c2w = Mat4::look_at_rh(eye, Vec3::new(0.0, 0.0, 0.3), Vec3::Z).inverse();
            Camera::from_blender_c2w(c2w, Intrinsics::from_fov_x(0.8, 64, 48)).unwrap()
        })
        .collect()
}

/// A ball of Gaussians on a large table, plus a floater: the ball alone is selected, and
/// its rendered share is high on the ball's centre and low on the table.
#[test]
fn ball_on_a_table() {
    let cams = ring_cameras(12, 4.0, 2.5);
    let f = focus_point(&cams).unwrap();
    assert!((f - Vec3::new(0.0, 0.0, 0.3)).length() < 1e-3, "focus {f}");
    let mut rng = Rng::new(1);
    let mut s = Surfels::with_capacity(0, 0);
    let q = Quat::IDENTITY;
    let push = |s: &mut Surfels, p: Vec3, scale: f32| {
        s.push(p, q, Vec2::splat(scale.ln()), 3.0, ShCoeffs::from_rgb([0.5; 3]));
    };
    for _ in 0..2000 {
        let d = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * 0.3;
        push(&mut s, d + Vec3::new(0.0, 0.0, 0.3), 0.03);
    }
    let table_start = s.len();
    for _ in 0..3000 {
        push(&mut s, Vec3::new(rng.range(-2.0, 2.0), rng.range(-2.0, 2.0), 0.0), 0.05);
    }
    push(&mut s, Vec3::new(0.0, 0.0, 1.2), 0.02);
    let fg =
        select_foreground(&s, &cams, &[], &RasterConfig::default(), &ForegroundConfig::default(), &mut Rng::new(2))
            .unwrap();
    let pl = fg.support.expect("the table is found");
    assert!(pl.normal.z > 0.99 && pl.d.abs() < 0.05, "{pl:?}");
    let ball = fg.selected[..table_start].iter().filter(|x| **x).count();
    let table = fg.selected[table_start..s.len() - 1].iter().filter(|x| **x).count();
    assert!(ball > 1700, "ball {ball}");
    assert!(table < 30, "table {table}");
    assert!(!fg.selected[s.len() - 1], "floater selected");
    let cam = &cams[0];
    let share = render_share(&s, &fg.selected, cam, &RasterConfig::default());
    let (x, y, _) = cam.project(Vec3::new(0.0, 0.0, 0.3)).unwrap();
    let at = |x: f32, y: f32| share[y as usize * cam.width() as usize + x as usize];
    assert!(at(x, y) > 0.9, "ball centre share {}", at(x, y));
    let (tx, ty, _) = cam.project(Vec3::new(0.5, -1.5, 0.0)).unwrap();
    assert!(at(tx, ty) < 0.1, "table share {}", at(tx, ty));
}

/// The test scenes' Gaussians: a ball of radius 0.3 at (0, 0, 0.3) on a 4 x 4 table at z = 0.
fn ball_and_table(rng: &mut Rng) -> (Surfels, usize) {
    let mut s = Surfels::with_capacity(0, 0);
    for _ in 0..2000 {
        let d = Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * 0.3;
        push(&mut s, d + Vec3::new(0.0, 0.0, 0.3), 0.03);
    }
    let ball = s.len();
    for _ in 0..3000 {
        push(&mut s, Vec3::new(rng.range(-2.0, 2.0), rng.range(-2.0, 2.0), 0.0), 0.05);
    }
    (s, ball)
}

fn push(s: &mut Surfels, p: Vec3, scale: f32) {
    s.push(p, Quat::IDENTITY, Vec2::splat(scale.ln()), 3.0, ShCoeffs::from_rgb([0.5; 3]));
}

fn select(s: &Surfels, cams: &[Camera], clipped: &[bool], cfg: &ForegroundConfig) -> Foreground {
    select_foreground(s, cams, clipped, &RasterConfig::default(), cfg, &mut Rng::new(2)).unwrap()
}

/// The support's scatter in front of it, thicker than the slab and touching the object's
/// base, is left out beyond the object's footprint; without the footprint rule it is taken.
#[test]
fn scatter_in_front_of_the_support_stays_out() {
    let cams = ring_cameras(12, 4.0, 2.5);
    let mut rng = Rng::new(3);
    let (mut s, ball) = ball_and_table(&mut rng);
    let scatter = s.len();
    for _ in 0..1500 {
        let (r, a) = (rng.range(0.2, 1.0), rng.range(0.0, std::f32::consts::TAU));
        push(&mut s, Vec3::new(r * a.cos(), r * a.sin(), rng.range(0.08, 0.16)), 0.03);
    }
    let taken = |fg: &Foreground| {
        fg.selected[scatter..]
            .iter()
            .zip(&s.positions[scatter..])
            .filter(|(t, p)| **t && p.truncate().length() > 0.45)
            .count()
    };
    let fg = select(&s, &cams, &[], &ForegroundConfig::default());
    let ball_kept = fg.selected[..ball].iter().filter(|x| **x).count();
    assert!(ball_kept > 1850, "ball {ball_kept}");
    let without = select(&s, &cams, &[], &ForegroundConfig { low_height: 0.0, ..Default::default() });
    eprintln!("scatter taken: {} without the rule, {} with it; ball {ball_kept}", taken(&without), taken(&fg));
    assert!(taken(&without) > 900, "the scatter is connected: {} taken without the rule", taken(&without));
    assert!(taken(&fg) < 150, "scatter beyond the footprint taken: {}", taken(&fg));
}

/// A blown-out sheet beside the ball, at its top's height, is left out; the ball's own
/// blown-out patch (a highlight on its side) stays with it.
#[test]
fn clipped_sheet_goes_and_clipped_cap_stays() {
    let cams = ring_cameras(12, 4.0, 2.5);
    let mut rng = Rng::new(4);
    let (mut s, ball) = ball_and_table(&mut rng);
    let sheet = s.len();
    for _ in 0..1500 {
        push(&mut s, Vec3::new(rng.range(0.2, 0.9), rng.range(-0.3, 0.3), rng.range(0.5, 0.56)), 0.03);
    }
    let mut clipped = vec![false; s.len()];
    for (i, c) in clipped.iter_mut().enumerate() {
        let p = s.positions[i];
        *c = i >= sheet || (i < ball && (p.z - 0.3).abs() < 0.1 && p.x < -0.2);
    }
    let patch = (0..ball).filter(|&i| clipped[i]).count();
    let without = select(&s, &cams, &[], &ForegroundConfig::default());
    let sheet_taken = |fg: &Foreground| fg.selected[sheet..].iter().filter(|x| **x).count();
    assert!(sheet_taken(&without) > 1000, "the sheet joins without clipping: {}", sheet_taken(&without));
    let fg = select(&s, &cams, &clipped, &ForegroundConfig::default());
    let patch_kept = (0..ball).filter(|&i| clipped[i] && fg.selected[i]).count();
    eprintln!(
        "sheet taken {} without clipping, {} with; patch {patch_kept} of {patch}; left out {}",
        sheet_taken(&without),
        sheet_taken(&fg),
        fg.clipped
    );
    assert!(sheet_taken(&fg) < 150, "sheet taken: {}", sheet_taken(&fg));
    assert!(patch_kept * 10 > patch * 9, "patch kept {patch_kept} of {patch}");
    assert!(fg.clipped >= 1300, "clipped left out {}", fg.clipped);
}

/// A Gaussian is clipped where the photos it is in are white at its centre in at least the
/// configured share of them.
#[test]
fn clipped_gaussians_follow_the_photos() {
    let cams = ring_cameras(4, 4.0, 2.5);
    let mut s = Surfels::with_capacity(0, 0);
    push(&mut s, Vec3::new(0.0, 0.0, 0.3), 0.03);
    push(&mut s, Vec3::new(0.0, 0.0, 20.0), 0.03); // outside every image
    let (w, h) = (cams[0].width() as usize, cams[0].height() as usize);
    // The first two photos are white everywhere, the others white but for the blue channel.
    let white = vec![1.0f32; 3 * w * h];
    let mut off = white.clone();
    off.iter_mut().skip(2).step_by(3).for_each(|b| *b = 0.5);
    let photos: Vec<(&[f32], usize)> = vec![(&white, 3), (&white, 3), (&off, 3), (&off, 3)];
    let at = |share: f32| {
        clipped_gaussians(&s, &cams, &photos, &ForegroundConfig { clipped_share: share, ..Default::default() })
    };
    assert_eq!(at(0.5), vec![true, false]);
    assert_eq!(at(0.6), vec![false, false]);
}

#[test]
fn parallel_cameras_have_no_focus() {
    let k = Intrinsics::from_fov_x(0.8, 8, 8);
    let cams: Vec<Camera> =
        (0..3).map(|i| Camera::from_w2c(glam::Mat3::IDENTITY, Vec3::new(i as f32, 0.0, 0.0), k).unwrap()).collect();
    assert!(focus_point(&cams).is_none());
}
