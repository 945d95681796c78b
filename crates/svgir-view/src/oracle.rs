//! The oracle: a CPU renderer of exactly the page's frame (its WebGL2 passes in `viewer.js`),
//! so that a screenshot of the page can be compared with it pixel for pixel.
//!
//! Per frame: sort the surfels back to front by the view depth of their centres (the depth is
//! computed in f64 and rounded to f32, as the page's sort does; ties by id), shade each surfel's
//! four vertices ([`crate::shade`]), and splat each over the pixels of its screen box with the
//! exact ray-splat intersection of SPEC 1 (the ray-plane form of the 2DGS homography, the same
//! low-pass filter, cut-offs and near plane), interpolating the vertex colours bilinearly
//! (SPEC 3), blending premultiplied colour back to front in f32 ("over", as the page's float
//! framebuffer does), then dividing by coverage, encoding to sRGB, blending over the background
//! and rounding to 8 bits (SPEC 3's order). Unlike the training rasteriser there is no early
//! stop at T < 1e-4 and no tiles.
//!
//! Work split: rayon over image rows; each row walks the sorted surfels whose box covers it.

use crate::model::{ViewModel, GEOM_FLOATS};
use crate::shade::{shade_surfel, Light, ViewMode};
use glam::{Mat3, Vec3};
use rayon::prelude::*;

/// Near plane (SPEC 1).
pub const NEAR: f32 = 0.2;

/// A pinhole view in the OpenCV convention, in f64 as the page holds it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// World-to-camera rotation, rows right, down, forward.
    pub rot: [[f64; 3]; 3],
    /// World-to-camera translation.
    pub trans: [f64; 3],
    /// Camera centre.
    pub eye: [f64; 3],
    /// Horizontal focal length in pixels.
    pub fx: f64,
    /// Vertical focal length in pixels.
    pub fy: f64,
    /// Principal point x in pixels.
    pub cx: f64,
    /// Principal point y in pixels.
    pub cy: f64,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
}

/// The page's orbit camera: around `target`, azimuth `yaw` and elevation `pitch` (radians, +Z
/// up), at distance `dist`, vertical field of view `fov_y` (radians).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    /// Point looked at.
    pub target: [f64; 3],
    /// Azimuth about +Z in radians.
    pub yaw: f64,
    /// Elevation above the XY plane in radians.
    pub pitch: f64,
    /// Distance from the target.
    pub dist: f64,
    /// Vertical field of view in radians.
    pub fov_y: f64,
}

impl Orbit {
    /// The view of a `width` x `height` canvas (the page's `orbitView`).
    pub fn view(&self, width: u32, height: u32) -> View {
        let (cp, sp) = (self.pitch.cos(), self.pitch.sin());
        let (cy, sy) = (self.yaw.cos(), self.yaw.sin());
        let t = self.target;
        let eye = [t[0] + self.dist * cp * cy, t[1] + self.dist * cp * sy, t[2] + self.dist * sp];
        let f = normalize([t[0] - eye[0], t[1] - eye[1], t[2] - eye[2]]);
        let right = normalize(cross(f, [0.0, 0.0, 1.0]));
        let down = cross(f, right);
        let rot = [right, down, f];
        let trans = [0, 1, 2].map(|r| -(rot[r][0] * eye[0] + rot[r][1] * eye[1] + rot[r][2] * eye[2]));
        let fy = 0.5 * height as f64 / (0.5 * self.fov_y).tan();
        View { rot, trans, eye, fx: fy, fy, cx: 0.5 * width as f64, cy: 0.5 * height as f64, width, height }
    }
}

impl View {
    /// The view of a dataset camera.
    pub fn from_camera(cam: &svgir_core::Camera) -> Self {
        let r = cam.rotation;
        let rot = [0, 1, 2].map(|i| r.row(i).to_array().map(|v| v as f64));
        let k = &cam.intrinsics;
        let c = cam.center();
        View {
            rot,
            trans: cam.translation.to_array().map(|v| v as f64),
            eye: c.to_array().map(|v| v as f64),
            fx: k.fx as f64,
            fy: k.fy as f64,
            cx: k.cx as f64,
            cy: k.cy as f64,
            width: k.width,
            height: k.height,
        }
    }

    /// View depth of a point, rounded to f32 (the sort key; the page computes it identically).
    pub fn depth(&self, p: [f32; 3]) -> f32 {
        let r = self.rot[2];
        (r[0] * p[0] as f64 + r[1] * p[1] as f64 + r[2] * p[2] as f64 + self.trans[2]) as f32
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    a.map(|v| v / l)
}

/// Surfel indices back to front: depth descending, ties by id ascending.
pub fn sort_back_to_front(model: &ViewModel, view: &View) -> Vec<u32> {
    let keys: Vec<f32> = (0..model.n).map(|i| view.depth([0, 1, 2].map(|k| model.geom[i * GEOM_FLOATS + k]))).collect();
    let mut order: Vec<u32> = (0..model.n as u32).collect();
    order.sort_by(|&a, &b| keys[b as usize].total_cmp(&keys[a as usize]).then(a.cmp(&b)));
    order
}

/// One surfel set up in camera space (what the page's vertex shader computes).
struct Splat {
    pc: Vec3,
    tu: Vec3,
    tv: Vec3,
    nc: Vec3,
    su: f32,
    sv: f32,
    o: f32,
    centre: [f32; 2],
    /// Pixel-centre box, inclusive: columns x0..=x1, rows y0..=y1.
    x0: i64,
    x1: i64,
    y0: i64,
    y1: i64,
    colours: [[f32; 3]; 4],
}

struct Intr {
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
}

fn setup(model: &ViewModel, i: usize, r: &Mat3, t: Vec3, k: &Intr) -> Option<Splat> {
    let g = &model.geom[i * GEOM_FLOATS..(i + 1) * GEOM_FLOATS];
    let pc = *r * Vec3::new(g[0], g[1], g[2]) + t;
    if pc.z <= NEAR {
        return None;
    }
    let (tu, tv, nc) =
        (*r * Vec3::new(g[4], g[5], g[6]), *r * Vec3::new(g[8], g[9], g[10]), *r * Vec3::new(g[12], g[13], g[14]));
    let (su, sv) = (g[7], g[11]);
    let centre = [k.fx * pc.x / pc.z + k.cx, k.fy * pc.y / pc.z + k.cy];
    let (mut lo, mut hi) = ([centre[0] - 3.0, centre[1] - 3.0], [centre[0] + 3.0, centre[1] + 3.0]);
    for (a, b) in [(-3.0f32, -3.0f32), (3.0, -3.0), (-3.0, 3.0), (3.0, 3.0)] {
        let q = pc + (a * su) * tu + (b * sv) * tv;
        if q.z <= NEAR {
            return None;
        }
        let (x, y) = (k.fx * q.x / q.z + k.cx, k.fy * q.y / q.z + k.cy);
        lo = [lo[0].min(x), lo[1].min(y)];
        hi = [hi[0].max(x), hi[1].max(y)];
    }
    // One pixel of margin; pixel column c is inside when its centre c + 0.5 is.
    let x0 = (lo[0] - 1.0 - 0.5).ceil() as i64;
    let x1 = (hi[0] + 1.0 - 0.5).floor() as i64;
    let y0 = (lo[1] - 1.0 - 0.5).ceil() as i64;
    let y1 = (hi[1] + 1.0 - 0.5).floor() as i64;
    Some(Splat { pc, tu, tv, nc, su, sv, o: g[3], centre, x0, x1, y0, y1, colours: [[0.0; 3]; 4] })
}

/// Alpha and interpolation weights of `s` at pixel centre `(x, y)`; `None` where SPEC 1 skips.
fn hit(s: &Splat, k: &Intr, x: f32, y: f32) -> Option<(f32, [f32; 4])> {
    let d = Vec3::new((x - k.cx) / k.fx, (y - k.cy) / k.fy, 1.0);
    let denom = s.nc.dot(d);
    if denom.abs() < 1e-10 {
        return None;
    }
    let t = s.nc.dot(s.pc) / denom;
    if t < NEAR {
        return None;
    }
    let dv = d * t - s.pc;
    let (u, v) = (s.tu.dot(dv) / s.su, s.tv.dot(dv) / s.sv);
    let rho3 = u * u + v * v;
    let (dx, dy) = (s.centre[0] - x, s.centre[1] - y);
    let rho2 = 2.0 * (dx * dx + dy * dy);
    let rho = rho3.min(rho2);
    if rho > 9.0 {
        return None;
    }
    let alpha = (s.o * (-0.5 * rho).exp()).min(0.99);
    if alpha < 1.0 / 255.0 {
        return None;
    }
    let uu = (0.5 + 0.5 * u).clamp(0.001, 0.999);
    let vv = (0.5 + 0.5 * v).clamp(0.001, 0.999);
    Some((alpha, [(1.0 - uu) * (1.0 - vv), uu * (1.0 - vv), (1.0 - uu) * vv, uu * vv]))
}

/// A rendered frame.
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Premultiplied linear colour and coverage per pixel (RGBA), before the final pass.
    pub accum: Vec<[f32; 4]>,
    /// The displayed 8-bit RGB image.
    pub rgb8: Vec<u8>,
    /// Surfels drawn (in front of the near plane).
    pub drawn: usize,
    /// Pixels inside the drawn surfels' screen boxes (the page's fragment shader invocations).
    pub fragments: u64,
    /// Fragments that passed the cuts and were blended.
    pub blended: u64,
}

/// Renders `model` as the page does for `view`, `light` and `mode` over background `bg`.
pub fn render(model: &ViewModel, view: &View, light: &Light, mode: ViewMode, bg: [f32; 3]) -> Frame {
    let r = Mat3::from_cols_array_2d(&view.rot.map(|row| row.map(|v| v as f32))).transpose();
    let t = Vec3::from_array(view.trans.map(|v| v as f32));
    let eye = Vec3::from_array(view.eye.map(|v| v as f32));
    let k = Intr { fx: view.fx as f32, fy: view.fy as f32, cx: view.cx as f32, cy: view.cy as f32 };
    let order = sort_back_to_front(model, view);
    let splats: Vec<Splat> = order
        .par_iter()
        .filter_map(|&i| {
            let mut s = setup(model, i as usize, &r, t, &k)?;
            s.colours = shade_surfel(model, i as usize, eye, light, mode);
            Some(s)
        })
        .collect();
    let (w, h) = (view.width as usize, view.height as usize);
    let mut accum = vec![[0.0f32; 4]; w * h];
    let mut counts = vec![[0u64; 2]; h];
    accum.par_chunks_mut(w).zip(counts.par_iter_mut()).enumerate().for_each(|(row, (px, count))| {
        let y = row as f32 + 0.5;
        for s in &splats {
            if (row as i64) < s.y0 || (row as i64) > s.y1 {
                continue;
            }
            for col in s.x0.max(0)..=s.x1.min(w as i64 - 1) {
                count[0] += 1;
                let Some((alpha, wts)) = hit(s, &k, col as f32 + 0.5, y) else { continue };
                count[1] += 1;
                let a = &mut px[col as usize];
                for ch in 0..3 {
                    let c = wts[0] * s.colours[0][ch]
                        + wts[1] * s.colours[1][ch]
                        + wts[2] * s.colours[2][ch]
                        + wts[3] * s.colours[3][ch];
                    a[ch] = c * alpha + a[ch] * (1.0 - alpha);
                }
                a[3] = alpha + a[3] * (1.0 - alpha);
            }
        }
    });
    let rgb8 = accum.iter().flat_map(|a| display(*a, mode, bg)).collect();
    let fragments = counts.iter().map(|c| c[0]).sum();
    let blended = counts.iter().map(|c| c[1]).sum();
    Frame { width: view.width, height: view.height, accum, rgb8, drawn: splats.len(), fragments, blended }
}

/// The final pass: divide by coverage, encode, blend over the background, round to 8 bits.
pub fn display(a: [f32; 4], mode: ViewMode, bg: [f32; 3]) -> [u8; 3] {
    let cover = a[3];
    [0, 1, 2].map(|ch| {
        let lin = a[ch] / cover.max(1e-5);
        let enc = if mode.srgb() { srgb(lin) } else { lin };
        let v = enc * cover + bg[ch] * (1.0 - cover);
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    })
}

/// Linear to sRGB as the page's shader writes it (IEC 61966-2-1).
pub fn srgb(c: f32) -> f32 {
    let c = c.max(0.0);
    if c <= 0.0031308 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}
