//! COLMAP captures as they come from a phone or camera: mixed image sizes, distorted lenses,
//! photos the model did not register, models without points, and `masks/` folders.

mod common;

use common::{cameras_bin, images_bin, opencv_distort, peak, points_bin, spot, tmp_dir, ImageRec};
use glam::Vec3;
use std::path::Path;
use svgir_core::{Image, MaskSource};
use svgir_io::{load_dataset, write_png, LoadOptions};

/// An image record looking down +z from (0, 0, -4) (identity rotation), no keypoints.
fn image(id: u32, cam: u32, name: &str) -> ImageRec {
    (id, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 4.0], cam, name.into(), vec![])
}

fn write_model(root: &Path, cams: &[(u32, i32, u64, u64, Vec<f64>)], imgs: &[ImageRec]) {
    std::fs::create_dir_all(root.join("sparse/0")).unwrap();
    std::fs::create_dir_all(root.join("images")).unwrap();
    std::fs::write(root.join("sparse/0/cameras.bin"), cameras_bin(cams)).unwrap();
    std::fs::write(root.join("sparse/0/images.bin"), images_bin(imgs)).unwrap();
}

fn grey(w: u32, h: u32, v: f32) -> Image {
    Image::filled(w, h, &[v, v, v])
}

fn err(root: &Path) -> String {
    load_dataset(root, &LoadOptions::default()).unwrap_err().to_string()
}

#[test]
fn mixed_sizes_unregistered_photos_and_models_without_points() {
    let d = tmp_dir("colmap-sizes");
    let cams = [(1, 1, 16, 12, vec![20.0, 20.0, 8.0, 6.0]), (2, 0, 10, 8, vec![15.0, 5.0, 4.0])];
    write_model(&d, &cams, &[image(1, 1, "a.png"), image(2, 2, "b.png")]);
    write_png(d.join("images/a.png"), &grey(16, 12, 0.2), 8).unwrap();
    write_png(d.join("images/b.png"), &grey(10, 8, 0.4), 8).unwrap();
    // Photos COLMAP did not register (another size, another format) are not the model's business.
    write_png(d.join("images/unregistered.png"), &grey(5, 5, 0.1), 8).unwrap();
    std::fs::write(d.join("images/notes.txt"), b"not a photo").unwrap();

    // No points3D.bin at all: points None (training then initialises on its own).
    let ds = load_dataset(&d, &LoadOptions::default()).unwrap();
    assert_eq!((ds.train.len(), ds.test.len()), (1, 1));
    let (a, b) = (&ds.test[0], &ds.train[0]);
    assert_eq!((a.name.as_str(), a.image.width, a.image.height), ("a", 16, 12));
    assert_eq!((b.name.as_str(), b.image.width, b.image.height), ("b", 10, 8));
    assert_eq!((a.camera.width(), a.camera.height(), b.camera.width(), b.camera.height()), (16, 12, 10, 8));
    assert_eq!(b.camera.intrinsics.fx, 15.0);
    assert!(ds.points.is_none());
    assert_eq!(ds.masks, MaskSource::None);
    assert!(!ds.has_masks());
    assert_eq!(ds.camera_model, "PINHOLE+SIMPLE_PINHOLE");

    // points3D.bin with zero points: the same.
    std::fs::write(d.join("sparse/0/points3D.bin"), points_bin(&[])).unwrap();
    assert!(load_dataset(&d, &LoadOptions::default()).unwrap().points.is_none());
    std::fs::write(d.join("sparse/0/points3D.bin"), points_bin(&[(7, [0.1, 0.2, 0.3], [255, 0, 0], vec![])])).unwrap();
    assert_eq!(load_dataset(&d, &LoadOptions::default()).unwrap().points.unwrap().positions.len(), 1);

    // Downscaling keeps each view's aspect and its own intrinsics.
    let half = load_dataset(&d, &LoadOptions { downscale: Some(2.0), ..Default::default() }).unwrap();
    assert_eq!((half.test[0].image.width, half.train[0].image.width), (8, 5));

    // A registered photo that is missing is an error naming it.
    std::fs::remove_file(d.join("images/b.png")).unwrap();
    assert_eq!(err(&d), format!("{}: missing view image", d.join("images/b.png").display()));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn distorted_photos_are_undistorted_on_load() {
    let d = tmp_dir("colmap-opencv");
    let (w, h) = (64u32, 48u32);
    let (fx, fy, cx, cy) = (50.0, 52.0, 31.5, 24.5);
    let k = [-0.5, 0.05, 0.002, -0.001];
    let params = vec![fx, fy, cx, cy, k[0], k[1], k[2], k[3]];
    write_model(&d, &[(1, 4, w as u64, h as u64, params)], &[image(1, 1, "a.png"), image(2, 1, "b.png")]);
    // A world point 4 in front of the camera at normalised (0.4, -0.25): the pinhole image has
    // it at (fx 0.4 + cx, fy (-0.25) + cy); the photo shows it where the lens bent it.
    let x = Vec3::new(1.6, -1.0, 0.0);
    let (u, v) = (0.4, -0.25);
    let (ud, vd) = opencv_distort(k, u, v);
    let (px, py) = (fx * ud + cx, fy * vd + cy);
    let (ex, ey) = (fx * u + cx, fy * v + cy);
    assert!((px - ex).hypot(py - ey) > 2.0, "distortion too weak for the test to tell");
    for name in ["a.png", "b.png"] {
        write_png(d.join("images").join(name), &spot(w, h, px, py), 16).unwrap();
    }
    let ds = load_dataset(&d, &LoadOptions::default()).unwrap();
    assert_eq!(ds.camera_model, "OPENCV");
    for view in ds.all_views() {
        let (gx, gy, _) = view.camera.project(ds.world_rotation * x).unwrap();
        assert!((gx as f64 - ex).abs() < 1e-3 && (gy as f64 - ey).abs() < 1e-3, "camera: ({gx}, {gy})");
        let (sx, sy) = peak(&view.image, 0);
        eprintln!("{}: spot {:.3} px from the pinhole projection", view.name, (sx - ex).hypot(sy - ey));
        assert!((sx - ex).hypot(sy - ey) < 0.25, "{}: spot at ({sx:.2}, {sy:.2}), expected ({ex}, {ey})", view.name);
    }
    // Models this loader cannot undistort are refused by name.
    std::fs::write(d.join("sparse/0/cameras.bin"), cameras_bin(&[(1, 10, 64, 48, vec![1.0; 12])])).unwrap();
    assert!(err(&d).contains("unsupported camera model THIN_PRISM_FISHEYE (id 10)"), "{}", err(&d));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn masks_folder_gives_alpha_before_undistortion() {
    let d = tmp_dir("colmap-masks");
    let (w, h) = (48u32, 36u32);
    let (fx, fy, cx, cy) = (40.0, 40.0, 24.0, 18.0);
    let k = [-0.3, 0.0, 0.0, 0.0];
    let cams = [(1, 4, w as u64, h as u64, vec![fx, fy, cx, cy, k[0], k[1], k[2], k[3]])];
    write_model(&d, &cams, &[image(1, 1, "a.jpg"), image(2, 1, "b.jpg"), image(3, 1, "c.png")]);
    image::RgbImage::from_pixel(w, h, image::Rgb([100, 150, 200])).save(d.join("images/a.jpg")).unwrap();
    image::RgbImage::from_pixel(w, h, image::Rgb([100, 150, 200])).save(d.join("images/b.jpg")).unwrap();
    write_png(d.join("images/c.png"), &grey(w, h, 0.5), 8).unwrap();
    // The masks show a spot where the lens put the point at normalised (0.35, 0.25); after
    // undistortion the alpha spot must sit at its pinhole position.
    let (ud, vd) = opencv_distort(k, 0.35, 0.25);
    let mask = spot(w, h, fx * ud + cx, fy * vd + cy);
    let (ex, ey) = (fx * 0.35 + cx, fy * 0.25 + cy);
    std::fs::create_dir_all(d.join("masks")).unwrap();
    // The three naming conventions: NAME.png, COLMAP's NAME.EXT.png, NAME.jpeg.
    write_png(d.join("masks/a.png"), &mask, 16).unwrap();
    write_png(d.join("masks/b.jpg.png"), &mask, 16).unwrap();
    let m8: Vec<u8> = mask.data.iter().map(|v| (v * 255.0).round() as u8).collect();
    image::GrayImage::from_raw(w, h, m8)
        .unwrap()
        .save_with_format(d.join("masks/c.jpeg"), image::ImageFormat::Jpeg)
        .unwrap();

    let ds = load_dataset(&d, &LoadOptions::default()).unwrap();
    assert_eq!(ds.masks, MaskSource::Folder(d.join("masks")));
    assert!(ds.has_masks());
    for view in ds.all_views() {
        let (sx, sy) = peak(&view.image, 3);
        let tol = if view.name == "c" { 0.5 } else { 0.25 }; // JPEG mask: lossy
        assert!(
            (sx - ex).hypot(sy - ey) < tol,
            "{}: alpha spot at ({sx:.2}, {sy:.2}), expected ({ex}, {ey})",
            view.name
        );
        // Colours untouched by the mask.
        let p = view.image.pixel(ex as u32, ey as u32);
        assert!(p[3] > 0.5 && (p[0] - 100.0 / 255.0).abs() < 0.05 || view.name == "c", "{}: {p:?}", view.name);
    }

    // A mask of the wrong size, a missing mask: errors naming the mask file.
    write_png(d.join("masks/a.png"), &grey(4, 4, 1.0), 8).unwrap();
    assert_eq!(
        err(&d),
        format!(
            "{}: mask is 4x4 but its photo {} is 48x36",
            d.join("masks/a.png").display(),
            d.join("images/a.jpg").display()
        )
    );
    write_png(d.join("masks/a.png"), &mask, 16).unwrap();
    // The same masks from a folder outside the dataset (`--masks DIR`) replace DATASET/masks.
    let outside = tmp_dir("colmap-masks-outside");
    for name in ["a.png", "b.jpg.png", "c.jpeg"] {
        std::fs::copy(d.join("masks").join(name), outside.join(name)).unwrap();
    }
    std::fs::write(d.join("masks/a.png"), b"not a png").unwrap();
    let given = LoadOptions { masks: Some(outside.clone()), ..Default::default() };
    let ds = load_dataset(&d, &given).unwrap();
    assert_eq!(ds.masks, MaskSource::Folder(outside.clone()));
    for view in ds.all_views() {
        let (sx, sy) = peak(&view.image, 3);
        assert!((sx - ex).hypot(sy - ey) < 0.5, "{}: alpha spot at ({sx:.2}, {sy:.2})", view.name);
    }
    let missing = LoadOptions { masks: Some(outside.join("nope")), ..Default::default() };
    let e = load_dataset(&d, &missing).unwrap_err().to_string();
    assert!(e.contains("nope") && e.contains("missing masks folder"), "{e}");
    let _ = std::fs::remove_dir_all(&outside);
    write_png(d.join("masks/a.png"), &mask, 16).unwrap();
    std::fs::remove_file(d.join("masks/b.jpg.png")).unwrap();
    assert_eq!(
        err(&d),
        format!(
            "{}: missing mask for photo b.jpg (also looked for b.jpg, b.jpeg, b.jpg.png)",
            d.join("masks/b.png").display()
        )
    );

    // Without a masks folder an RGBA photo keeps its own alpha.
    std::fs::remove_dir_all(d.join("masks")).unwrap();
    let mut rgba = Image::filled(w, h, &[0.5, 0.5, 0.5, 1.0]);
    for y in 0..h {
        for x in 0..w / 2 {
            rgba.pixel_mut(x, y)[3] = 0.0;
        }
    }
    write_model(&d, &[(1, 1, w as u64, h as u64, vec![fx, fy, cx, cy])], &[image(1, 1, "c.png")]);
    write_png(d.join("images/c.png"), &rgba, 8).unwrap();
    let ds = load_dataset(&d, &LoadOptions::default()).unwrap();
    assert_eq!(ds.masks, MaskSource::Alpha);
    assert_eq!((ds.test[0].image.pixel(2, 2)[3], ds.test[0].image.pixel(40, 2)[3]), (0.0, 1.0));
    let _ = std::fs::remove_dir_all(&d);
}
