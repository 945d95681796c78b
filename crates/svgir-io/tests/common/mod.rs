//! Helpers shared by the integration tests: tiny COLMAP writers and a panic assertion.
#![allow(dead_code)]

/// Runs `f`, failing the test with `what` if it panics (an assertion helper; the library
/// itself never catches panics).
pub fn no_panic<T>(what: &str, f: impl FnOnce() -> T + std::panic::UnwindSafe) -> T {
    match std::panic::catch_unwind(f) {
        Ok(v) => v,
        Err(_) => panic!("parser panicked on {what}"),
    }
}

pub fn cameras_bin(cams: &[(u32, i32, u64, u64, Vec<f64>)]) -> Vec<u8> {
    let mut b = (cams.len() as u64).to_le_bytes().to_vec();
    for (id, model, w, h, params) in cams {
        b.extend(id.to_le_bytes());
        b.extend(model.to_le_bytes());
        b.extend(w.to_le_bytes());
        b.extend(h.to_le_bytes());
        for p in params {
            b.extend(p.to_le_bytes());
        }
    }
    b
}

/// One image: id, quaternion (w x y z), translation, camera id, name, keypoints (x, y, point id).
pub type ImageRec = (u32, [f64; 4], [f64; 3], u32, String, Vec<(f64, f64, u64)>);

pub fn images_bin(images: &[ImageRec]) -> Vec<u8> {
    let mut b = (images.len() as u64).to_le_bytes().to_vec();
    for (id, q, t, cam, name, kps) in images {
        b.extend(id.to_le_bytes());
        for v in q.iter().chain(t) {
            b.extend(v.to_le_bytes());
        }
        b.extend(cam.to_le_bytes());
        b.extend(name.as_bytes());
        b.push(0);
        b.extend((kps.len() as u64).to_le_bytes());
        for (x, y, pid) in kps {
            b.extend(x.to_le_bytes());
            b.extend(y.to_le_bytes());
            b.extend(pid.to_le_bytes());
        }
    }
    b
}

/// One point: id, position, colour, track (image id, keypoint index).
pub type PointRec = (u64, [f64; 3], [u8; 3], Vec<(u32, u32)>);

pub fn points_bin(points: &[PointRec]) -> Vec<u8> {
    let mut b = (points.len() as u64).to_le_bytes().to_vec();
    for (id, xyz, rgb, track) in points {
        b.extend(id.to_le_bytes());
        for v in xyz {
            b.extend(v.to_le_bytes());
        }
        b.extend(rgb);
        b.extend(0.5f64.to_le_bytes());
        b.extend((track.len() as u64).to_le_bytes());
        for (i, k) in track {
            b.extend(i.to_le_bytes());
            b.extend(k.to_le_bytes());
        }
    }
    b
}

/// A small valid model: 2 cameras, 2 images, 3 points.
pub fn small_model() -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    let cams = cameras_bin(&[
        (1, 1, 8, 6, vec![10.0, 10.0, 4.0, 3.0]),
        (2, 4, 8, 6, vec![10.0, 11.0, 4.0, 3.0, 2.0, 0.01, 0.0, 0.0]),
    ]);
    let imgs = images_bin(&[
        (1, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 4.0], 1, "a.png".into(), vec![(4.0, 3.0, 1), (1.0, 1.0, u64::MAX)]),
        (2, [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 4.0], 2, "b.png".into(), vec![(4.0, 3.0, 1)]),
    ]);
    let pts = points_bin(&[
        (1, [0.0, 0.0, 0.0], [255, 0, 10], vec![(1, 0), (2, 0)]),
        (2, [0.1, 0.2, 0.3], [1, 2, 3], vec![]),
        (3, [0.1, -0.2, 0.3], [1, 2, 3], vec![(1, 1)]),
    ]);
    (cams, imgs, pts)
}

/// A fresh empty folder under the system temp dir, unique to this process and `name`.
pub fn tmp_dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("svgir-io-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A `w` x `h` grey image (1 channel) with a Gaussian spot of sigma 1.2 px centred at the
/// continuous pixel position (x, y) (pixel centres at +0.5).
pub fn spot(w: u32, h: u32, x: f64, y: f64) -> svgir_core::Image {
    let mut img = svgir_core::Image::new(w, h, 1);
    for j in 0..h {
        for i in 0..w {
            let d2 = (i as f64 + 0.5 - x).powi(2) + (j as f64 + 0.5 - y).powi(2);
            img.pixel_mut(i, j)[0] = (-d2 / (2.0 * 1.2 * 1.2)).exp() as f32;
        }
    }
    img
}

/// Sub-pixel peak of channel `ch`, in continuous pixels: the brightest pixel refined by a
/// parabola through the logarithms of it and its neighbours (exact for a Gaussian spot, and
/// unlike a centroid unmoved by the uneven stretching a lens warp gives the spot's flanks).
pub fn peak(img: &svgir_core::Image, ch: u32) -> (f64, f64) {
    let c = ch as usize;
    let (mut bi, mut bj, mut best) = (1, 1, f32::MIN);
    for j in 1..img.height - 1 {
        for i in 1..img.width - 1 {
            if img.pixel(i, j)[c] > best {
                (bi, bj, best) = (i, j, img.pixel(i, j)[c]);
            }
        }
    }
    let ln = |i: u32, j: u32| (img.pixel(i, j)[c].max(1e-6) as f64).ln();
    let vertex = |a: f64, b: f64, c: f64| if a - 2.0 * b + c < 0.0 { (a - c) / (2.0 * (a - 2.0 * b + c)) } else { 0.0 };
    let dx = vertex(ln(bi - 1, bj), ln(bi, bj), ln(bi + 1, bj));
    let dy = vertex(ln(bi, bj - 1), ln(bi, bj), ln(bi, bj + 1));
    (bi as f64 + 0.5 + dx, bj as f64 + 0.5 + dy)
}

/// COLMAP/OpenCV forward distortion (k1, k2, p1, p2) of normalised coordinates, written out
/// here independently of the library's.
pub fn opencv_distort(k: [f64; 4], u: f64, v: f64) -> (f64, f64) {
    let [k1, k2, p1, p2] = k;
    let r2 = u * u + v * v;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
    (u * radial + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u), v * radial + 2.0 * p2 * u * v + p1 * (r2 + 2.0 * v * v))
}

/// A folder of `../shared/data` that a test needs is missing (`what` names it). With
/// `SVGIR_REQUIRE_DATA=1` (set by `.ci/run`) the test fails; otherwise it prints `SKIPPED` and
/// the caller returns.
pub fn missing_data(what: &str) {
    let msg = format!("{what} not found; this test needs ../shared/data");
    if std::env::var("SVGIR_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!("SVGIR_REQUIRE_DATA=1: {msg}");
    }
    eprintln!("SKIPPED: {msg}");
}
