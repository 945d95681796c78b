//! Depth-normal consistency (2DGS; SPEC 1 and 6, Eqn 18): `L = mean_pixels(1 - N . N_D)` where N
//! is the rendered (composited, unnormalised) normal and N_D the normal of the surface
//! back-projected from the expected depth `D = S / O` (S = sum w z, O = opacity), estimated with
//! central differences, normalised and multiplied by the detached opacity. Border pixels have
//! N_D = 0, as 2DGS pads them.
//!
//! Work split: the back-projected points once per pixel; then one pass, rows in parallel, computes
//! N_D and the gradients of the two difference vectors, and a second pass gathers them onto each
//! pixel's depth (no scattered writes; the loss is summed in pixel order, so every value is the
//! same for any thread count).
//! Computed in f64 so the same code is the finite-difference oracle.

use glam::DVec3;
use rayon::prelude::*;
use svgir_core::par::filled;
use svgir_core::Camera;

/// Gradients of [`depth_normal_loss`] with respect to its rendered inputs.
pub struct DepthNormalGrads {
    /// dL / d `sum w z` per pixel.
    pub v_depth_sum: Vec<f32>,
    /// dL / d opacity per pixel.
    pub v_opacity: Vec<f32>,
    /// dL / d rendered normal per pixel, 3 values each.
    pub v_normal: Vec<f32>,
}

/// Opacity below which the expected depth is not formed (avoids dividing by ~0).
const MIN_OPACITY: f64 = 1e-4;

fn ray_of_pixel(cam: &Camera) -> impl Fn(usize, usize) -> DVec3 + '_ {
    let k = cam.intrinsics;
    let rt = cam.rotation.transpose().as_dmat3();
    move |x, y| {
        rt * DVec3::new((x as f64 + 0.5 - k.cx as f64) / k.fx as f64, (y as f64 + 0.5 - k.cy as f64) / k.fy as f64, 1.0)
    }
}

/// Surface normal from depth (unit, facing the camera), for visualisation and the loss.
pub fn normal_from_depth(depth: &[f64], cam: &Camera) -> Vec<DVec3> {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let ray = ray_of_pixel(cam);
    let c = cam.center().as_dvec3();
    let p = |x: usize, y: usize| c + depth[y * w + x] * ray(x, y);
    let mut out = vec![DVec3::ZERO; w * h];
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let dx = p(x + 1, y) - p(x - 1, y);
            let dy = p(x, y + 1) - p(x, y - 1);
            out[y * w + x] = dy.cross(dx).normalize_or_zero();
        }
    }
    out
}

/// Loss value and gradients; inputs as the rasterizer outputs them (f32). The arithmetic is
/// [`depth_normal_loss_f64`]'s: each f32 is widened where it is read (exactly), and each
/// gradient rounded to f32 where it is written, without f64 copies of the buffers.
pub fn depth_normal_loss(depth_sum: &[f32], opacity: &[f32], normal: &[f32], cam: &Camera) -> (f32, DepthNormalGrads) {
    let (loss, vs, vo, vn) = depth_normal_loss_in(depth_sum, opacity, normal, cam, |g| g as f32);
    (loss as f32, DepthNormalGrads { v_depth_sum: vs, v_opacity: vo, v_normal: vn })
}

/// The f64 computation behind [`depth_normal_loss`] (also its finite-difference oracle): loss and gradients w.r.t. S, O, N.
#[allow(clippy::type_complexity)]
pub fn depth_normal_loss_f64(s: &[f64], o: &[f64], n: &[f64], cam: &Camera) -> (f64, Vec<f64>, Vec<f64>, Vec<f64>) {
    depth_normal_loss_in(s, o, n, cam, |g| g)
}

/// [`depth_normal_loss_f64`] on inputs of any float type that widens to f64 exactly, the
/// gradients stored through `out`.
#[allow(clippy::type_complexity)]
fn depth_normal_loss_in<T, G>(
    s: &[T],
    o: &[T],
    n: &[T],
    cam: &Camera,
    out: impl Fn(f64) -> G + Sync,
) -> (f64, Vec<G>, Vec<G>, Vec<G>)
where
    T: Copy + Into<f64> + Sync,
    G: Copy + Default + Send + Sync,
{
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let np = (w * h) as f64;
    let ray = ray_of_pixel(cam);
    let c = cam.center().as_dvec3();
    let (s, o) = (|i: usize| -> f64 { s[i].into() }, |i: usize| -> f64 { o[i].into() });
    // The back-projected points, once per pixel (each is read by four neighbours).
    let pts: Vec<DVec3> = (0..w * h)
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| c + s(i) / o(i).max(MIN_OPACITY) * ray(i % w, i / w))
        .collect();
    let nvec = |i: usize| DVec3::new(n[3 * i].into(), n[3 * i + 1].into(), n[3 * i + 2].into());

    // Pass 1, rows in parallel: per-pixel loss, dL/dN and the gradients of the two differences.
    let mut pix_loss = filled(w * h, 1.0);
    let mut v_n = filled(3 * w * h, G::default());
    let mut v_dx = filled(w * h, DVec3::ZERO);
    let mut v_dy = filled(w * h, DVec3::ZERO);
    let rows = pix_loss
        .par_chunks_mut(w)
        .zip(v_n.par_chunks_mut(3 * w))
        .zip(v_dx.par_chunks_mut(w))
        .zip(v_dy.par_chunks_mut(w));
    rows.enumerate().for_each(|(y, (((l_row, vn_row), vdx_row), vdy_row))| {
        if y == 0 || y + 1 >= h {
            return;
        }
        for x in 1..w.saturating_sub(1) {
            let i = y * w + x;
            let dx = pts[i + 1] - pts[i - 1];
            let dy = pts[i + w] - pts[i - w];
            let cr = dy.cross(dx);
            let len = cr.length();
            if len < 1e-20 {
                continue;
            }
            let nd = cr / len;
            let nd_masked = nd * o(i); // opacity detached here: no gradient through this factor
            let ni = nvec(i);
            l_row[x] = 1.0 - ni.dot(nd_masked);
            let g_n = -nd_masked / np;
            vn_row[3 * x..3 * x + 3].copy_from_slice(&g_n.to_array().map(&out));
            let v_nd = -ni * o(i) / np;
            let v_cr = (v_nd - nd * nd.dot(v_nd)) / len;
            // cr = dy x dx: d/d dy = dx x v_cr, d/d dx = v_cr x dy.
            vdy_row[x] = dx.cross(v_cr);
            vdx_row[x] = v_cr.cross(dy);
        }
    });
    // Summed in pixel order, so the value does not depend on the thread count.
    let loss: f64 = pix_loss.iter().fold(0.0, |a, &l| a + l);

    // Pass 2, rows in parallel: gather the differences' gradients onto each pixel's depth.
    let mut v_s = filled(w * h, G::default());
    let mut v_o = filled(w * h, G::default());
    v_s.par_chunks_mut(w).zip(v_o.par_chunks_mut(w)).enumerate().for_each(|(y, (vs_row, vo_row))| {
        for x in 0..w {
            let i = y * w + x;
            let mut v_p = DVec3::ZERO;
            if x > 0 {
                v_p += v_dx[i - 1];
            }
            if x + 1 < w {
                v_p -= v_dx[i + 1];
            }
            if y > 0 {
                v_p += v_dy[i - w];
            }
            if y + 1 < h {
                v_p -= v_dy[i + w];
            }
            let v_d = v_p.dot(ray(x, y));
            let (oi, si) = (o(i), s(i));
            if oi > MIN_OPACITY {
                vs_row[x] = out(v_d / oi);
                vo_row[x] = out(-v_d * si / (oi * oi));
            } else {
                vs_row[x] = out(v_d / MIN_OPACITY);
            }
        }
    });
    (loss / np, v_s, v_o, v_n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat4, Vec3};
    use svgir_core::{Intrinsics, Rng};

    fn camera(w: u32, h: u32) -> Camera {
        let eye = Vec3::new(0.3, -2.5, 1.0);
        let back = eye.normalize();
        let right = Vec3::Z.cross(back).normalize();
        let up = back.cross(right);
        let c2w = Mat4::from_cols(right.extend(0.0), up.extend(0.0), back.extend(0.0), eye.extend(1.0));
        Camera::from_blender_c2w(c2w, Intrinsics::from_fov_x(0.8, w, h)).unwrap()
    }

    #[test]
    fn plane_facing_camera_gives_its_normal() {
        // Depth of the plane z_cam = 2 everywhere: its normal is -forward (towards the camera).
        let cam = camera(8, 6);
        let depth = vec![2.0; 48];
        let nd = normal_from_depth(&depth, &cam);
        let want = -cam.forward().as_dvec3();
        assert!((nd[2 * 8 + 3] - want).length() < 1e-6, "{:?} vs {want:?}", nd[2 * 8 + 3]);
    }

    #[test]
    fn f32_buffers_give_the_f64_function_rounded() {
        // The f32 entry point runs the f64 arithmetic on the f32 values: its loss and gradients
        // are the f64 function's on the widened inputs, rounded once.
        let cam = camera(9, 7);
        let n = 63;
        let mut rng = Rng::new(5);
        let o: Vec<f32> = (0..n).map(|i| if i % 7 == 3 { 0.0 } else { 0.2 + 0.7 * rng.uniform() }).collect();
        let s: Vec<f32> = o.iter().map(|o| o * (2.0 + 0.3 * rng.uniform())).collect();
        let nn: Vec<f32> = (0..3 * n).map(|_| rng.normal()).collect();
        let wide = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
        let (loss, vs, vo, vn) = depth_normal_loss_f64(&wide(&s), &wide(&o), &wide(&nn), &cam);
        let (loss32, g) = depth_normal_loss(&s, &o, &nn, &cam);
        assert_eq!(loss32.to_bits(), (loss as f32).to_bits());
        for (got, want) in [(&g.v_depth_sum, &vs), (&g.v_opacity, &vo), (&g.v_normal, &vn)] {
            assert!(want.iter().any(|w| *w != 0.0));
            let same = got.iter().zip(want).all(|(a, b)| a.to_bits() == (*b as f32).to_bits());
            assert!(same && got.len() == want.len());
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let cam = camera(7, 6);
        let n = 42;
        let mut rng = Rng::new(3);
        let o: Vec<f64> = (0..n).map(|_| 0.3 + 0.6 * rng.uniform_f64()).collect();
        let s: Vec<f64> = o.iter().map(|o| o * (2.0 + 0.3 * rng.uniform_f64())).collect();
        let nn: Vec<f64> = (0..3 * n).map(|_| rng.normal() as f64).collect();
        let (_, vs, vo, vn) = depth_normal_loss_f64(&s, &o, &nn, &cam);
        let h = 1e-6;
        let check = |which: usize, i: usize, analytic: f64| {
            let (mut s2, mut o2, mut n2) = (s.clone(), o.clone(), nn.clone());
            let (mut s3, mut o3, mut n3) = (s.clone(), o.clone(), nn.clone());
            match which {
                0 => {
                    s2[i] += h;
                    s3[i] -= h
                }
                1 => {
                    o2[i] += h;
                    o3[i] -= h
                }
                _ => {
                    n2[i] += h;
                    n3[i] -= h
                }
            }
            // The opacity mask factor is detached in the analytic gradient; hold it fixed in the
            // finite difference by perturbing only through the depth division.
            let lp = if which == 1 {
                loss_detached(&s2, &o2, &o, &n2, &cam)
            } else {
                depth_normal_loss_f64(&s2, &o2, &n2, &cam).0
            };
            let lm = if which == 1 {
                loss_detached(&s3, &o3, &o, &n3, &cam)
            } else {
                depth_normal_loss_f64(&s3, &o3, &n3, &cam).0
            };
            let fd = (lp - lm) / (2.0 * h);
            assert!((fd - analytic).abs() < 1e-6 + 1e-5 * fd.abs(), "input {which}[{i}]: fd {fd} vs {analytic}");
        };
        for i in 0..n {
            check(0, i, vs[i]);
            check(1, i, vo[i]);
        }
        for i in 0..3 * n {
            check(2, i, vn[i]);
        }
    }

    /// The loss with the mask factor taken from `o_mask` (held constant) and depth from `o`.
    fn loss_detached(s: &[f64], o: &[f64], o_mask: &[f64], n: &[f64], cam: &Camera) -> f64 {
        // Scale the rendered normal so that N . (nd * o_mask) is what the loss sees with o's depth.
        let (w, h) = (cam.width() as usize, cam.height() as usize);
        let depth: Vec<f64> = s.iter().zip(o).map(|(s, o)| s / o.max(MIN_OPACITY)).collect();
        let nd = normal_from_depth(&depth, cam);
        let mut loss = 0.0;
        for i in 0..w * h {
            let ni = DVec3::new(n[3 * i], n[3 * i + 1], n[3 * i + 2]);
            loss += 1.0 - ni.dot(nd[i] * o_mask[i]);
        }
        loss / (w * h) as f64
    }
}
