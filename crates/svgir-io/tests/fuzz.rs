//! Robustness: the PLY, HDR and COLMAP parsers on random bytes, on every truncation of a valid
//! file, and on valid files with random byte flips. Truncations and random bytes must give
//! `Err`; flips may give `Ok` (a flipped pixel is still an image) but nothing may panic.
//! The `transforms.json` parser gets every value of a valid file replaced by odd ones. Each test
//! prints how many inputs it ran.

mod common;

use common::{no_panic, small_model};
use glam::{Quat, Vec2, Vec3};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use svgir_core::{Image, ShCoeffs, Surfels};
use svgir_io::colmap::{parse_cameras, parse_images, parse_points};
use svgir_io::image_io::{decode_image, encode_hdr, encode_png, ImageKind};
use svgir_io::ply::{decode_gaussians_ply, decode_points_ply, encode_gaussians_ply};

const CASES: u32 = 2000;

fn small_ply() -> Vec<u8> {
    let mut s = Surfels::with_capacity(3, 3);
    for i in 0..3 {
        let sh = ShCoeffs::from_rgb([0.1 * i as f32, 0.5, 0.9]);
        s.push(Vec3::splat(i as f32), Quat::from_rotation_z(i as f32), Vec2::new(-3.0, -4.0), 0.5, sh);
    }
    encode_gaussians_ply(&s, &[("albedo_0_r".into(), vec![0.1, 0.2, 0.3])]).unwrap()
}

fn small_hdr() -> Vec<u8> {
    let img = Image::from_data(8, 4, 3, (0..96).map(|i| i as f32 * 0.37).collect());
    encode_hdr(&img).unwrap()
}

fn colmap_all(b: &[u8]) -> [bool; 3] {
    [parse_cameras(b).is_err(), parse_images(b).is_err(), parse_points(b).is_err()]
}

/// Every strict prefix of `full` must be rejected by `parse`.
fn all_truncations_fail(name: &str, full: &[u8], parse: impl Fn(&[u8]) -> bool + std::panic::RefUnwindSafe) -> usize {
    for len in 0..full.len() {
        let is_err = no_panic(&format!("{name} truncated to {len}"), || parse(&full[..len]));
        assert!(is_err, "{name} truncated to {len} of {} bytes was accepted", full.len());
    }
    assert!(!parse(full), "{name}: the full file must parse");
    full.len()
}

#[test]
fn truncations_at_every_length_are_errors() {
    let ply = small_ply();
    let (cams, imgs, pts) = small_model();
    let n = all_truncations_fail("PLY", &ply, |b| decode_gaussians_ply(b).is_err())
        + all_truncations_fail("PLY points", &ply, |b| decode_points_ply(b).is_err())
        + all_truncations_fail("HDR", &small_hdr(), |b| decode_image(b, ImageKind::Hdr).is_err())
        + all_truncations_fail("cameras.bin", &cams, |b| parse_cameras(b).is_err())
        + all_truncations_fail("images.bin", &imgs, |b| parse_images(b).is_err())
        + all_truncations_fail("points3D.bin", &pts, |b| parse_points(b).is_err());
    let png = encode_png(&Image::filled(5, 4, &[0.2, 0.4, 0.6, 1.0]), 8).unwrap();
    // The last 12 bytes are the IEND chunk: cutting into it leaves the pixels intact.
    let png_body = png.len() - 12;
    for len in 0..png_body {
        assert!(no_panic("PNG truncated", || decode_image(&png[..len], ImageKind::Png).is_err()), "PNG cut at {len}");
    }
    let n = n + png_body;
    eprintln!("truncation cases run: {n}");
}

fn flip(mut bytes: Vec<u8>, flips: &[(usize, u8)]) -> Vec<u8> {
    let n = bytes.len();
    for &(i, v) in flips {
        bytes[i % n] ^= v | 1;
    }
    bytes
}

#[test]
fn random_bytes_are_rejected() {
    let mut runner = TestRunner::new(Config { cases: CASES, failure_persistence: None, ..Config::default() });
    let ply = small_ply();
    let head = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let count = std::cell::Cell::new(0usize);
    let result = runner.run(&proptest::collection::vec(any::<u8>(), 0..600), |bytes| {
        count.set(count.get() + 1);
        let b = &bytes[..];
        prop_assert!(no_panic("random PLY", || decode_gaussians_ply(b).is_err()));
        prop_assert!(no_panic("random HDR", || decode_image(b, ImageKind::Hdr).is_err()));
        let r = no_panic("random COLMAP", || colmap_all(b));
        // Random bytes can encode a valid count of 0 records; anything else must fail.
        prop_assert!(r.iter().all(|&e| e) || b.len() >= 8 && b[..8] == [0; 8]);
        // Past the magic: valid headers followed by random bytes (may parse; must not panic).
        let mut hdr = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 8\n".to_vec();
        hdr.extend_from_slice(b);
        no_panic("HDR header + random", || decode_image(&hdr, ImageKind::Hdr).is_err());
        let mut p = ply[..head].to_vec();
        p.extend_from_slice(b);
        no_panic("PLY header + random", || decode_gaussians_ply(&p).is_err());
        Ok(())
    });
    result.unwrap();
    eprintln!("random-byte cases run: {} (x 5 parsers, + 2 header-prefixed parses each)", count.get());
}

#[test]
fn byte_flips_never_panic() {
    let mut runner = TestRunner::new(Config { cases: CASES, failure_persistence: None, ..Config::default() });
    let (ply, hdr, (c, i, p)) = (small_ply(), small_hdr(), small_model());
    let count = std::cell::Cell::new(0usize);
    let result = runner.run(&proptest::collection::vec((any::<usize>(), any::<u8>()), 1..6), |flips| {
        count.set(count.get() + 1);
        let ply = flip(ply.clone(), &flips);
        no_panic("flipped PLY", || decode_gaussians_ply(&ply).is_ok());
        no_panic("flipped PLY points", || decode_points_ply(&ply).is_ok());
        let hdr = flip(hdr.clone(), &flips);
        no_panic("flipped HDR", || decode_image(&hdr, ImageKind::Hdr).is_ok());
        let (c, i, p) = (flip(c.clone(), &flips), flip(i.clone(), &flips), flip(p.clone(), &flips));
        no_panic("flipped cameras.bin", || parse_cameras(&c).is_ok());
        no_panic("flipped images.bin", || parse_images(&i).is_ok());
        no_panic("flipped points3D.bin", || parse_points(&p).is_ok());
        Ok(())
    });
    result.unwrap();
    eprintln!("byte-flip cases run: {} (x 6 parsers)", count.get());
}

/// Every JSON pointer into `v` (objects and arrays included).
fn pointers(v: &serde_json::Value, at: String, out: &mut Vec<String>) {
    match v {
        serde_json::Value::Object(m) => m.iter().for_each(|(k, x)| pointers(x, format!("{at}/{k}"), out)),
        serde_json::Value::Array(a) => a.iter().enumerate().for_each(|(i, x)| pointers(x, format!("{at}/{i}"), out)),
        _ => {}
    }
    out.push(at);
}

#[test]
fn transforms_json_with_odd_values_never_panics() {
    use serde_json::json;
    let m = json!([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]);
    let base = json!({
        "camera_model": "OPENCV", "fl_x": 50, "fl_y": 52, "cx": 32, "cy": 24, "w": 64, "h": 48,
        "k1": -0.1, "k2": 0.01, "p1": 0.0, "p2": 0.0, "ply_file_path": "p.ply",
        "train_filenames": ["images/a.png"], "test_filenames": ["images/b.png"],
        "frames": [
            {"file_path": "images/a.png", "mask_path": "m/a.png", "transform_matrix": m, "fl_x": 40},
            {"file_path": "./images/b.png", "mask_path": "m/b.png", "transform_matrix": m, "camera_angle_x": 1.0},
        ],
    });
    let odd = [
        json!(null),
        json!(0),
        json!(-1),
        json!(1e308),
        json!(-1e308),
        json!(1e-308),
        json!(0.5),
        json!(u64::MAX),
        json!(true),
        json!(""),
        json!("EQUIRECTANGULAR"),
        json!([]),
        json!([[1, 2], [3]]),
        json!({}),
    ];
    let mut at = Vec::new();
    pointers(&base, String::new(), &mut at);
    let mut n = 0;
    for p in &at {
        for o in &odd {
            let mut v = base.clone();
            match v.pointer_mut(p) {
                Some(slot) => *slot = o.clone(),
                None => continue,
            }
            no_panic(&format!("transforms.json with {p} = {o}"), || {
                if let Ok(cap) = svgir_io::transforms::parse_capture(&v, std::path::Path::new("/d")) {
                    for f in &cap.frames {
                        if let Some(params) = f.lens.params(64, 48) {
                            let _ = f.lens.model.pinhole(&params);
                        }
                    }
                }
            });
            n += 1;
        }
    }
    eprintln!("transforms.json odd-value cases run: {n}");
}
