//! nerfstudio / instant-ngp `transforms.json` captures: built in a temp folder, loaded, and
//! checked against hand-computed projections; then the real COLMAP statue converted to one.

mod common;

use common::{opencv_distort, peak, spot, tmp_dir};
use glam::{Mat3, Vec3};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use svgir_core::{Image, MaskSource, PointCloud};
use svgir_io::{
    colmap, dataset_summary, detect_layout, load_dataset, write_png, write_points_ply, Layout, LoadOptions,
};

/// Blender camera-to-world (columns right, up, back, centre) of a camera at `c` looking at
/// `target` with +z up, as a row-major nested list.
fn look_at(c: Vec3, target: Vec3) -> ([Vec3; 3], Value) {
    let fwd = (target - c).normalize();
    let right = fwd.cross(Vec3::Z).normalize();
    let up = right.cross(fwd);
    let back = -fwd;
    let rows: Vec<Vec<f32>> =
        (0..3).map(|r| vec![right[r], up[r], back[r], c[r]]).chain([vec![0.0, 0.0, 0.0, 1.0]]).collect();
    ([right, up, back], json!(rows))
}

/// Normalised image coordinates (x right, y down) of world point `x` for a Blender camera.
fn normalised(axes: &[Vec3; 3], c: Vec3, x: Vec3) -> (f64, f64) {
    let d = x - c;
    let (px, py, pz) = (axes[0].dot(d) as f64, axes[1].dot(d) as f64, axes[2].dot(d) as f64);
    assert!(pz < 0.0, "point behind the camera");
    (px / -pz, -py / -pz)
}

const K: [f64; 4] = [-0.6, 0.1, 0.002, -0.003];
const POINT: Vec3 = Vec3::new(0.0, 0.0, 0.1);

struct Expect {
    name: String,
    size: (u32, u32),
    pixel: (f64, f64),
}

/// Ten frames f00..f09 around the origin, looking past it so that `POINT` is well off-centre
/// where the lens bends it by pixels; f03 has its own size and intrinsics. Each photo shows
/// `POINT` as a spot where the OPENCV lens puts it, each mask is opaque in its left half.
fn write_capture(d: &Path) -> (Value, Vec<Expect>) {
    std::fs::create_dir_all(d.join("images")).unwrap();
    std::fs::create_dir_all(d.join("masks")).unwrap();
    let mut frames = Vec::new();
    let mut expect = Vec::new();
    for i in 0..10 {
        let t = i as f32 * 0.6;
        let c = Vec3::new(4.0 * t.cos(), 4.0 * t.sin(), 1.0 + 0.1 * i as f32);
        let (axes, m) = look_at(c, 1.6 * Vec3::new(-t.sin(), t.cos(), 0.0));
        // f03: per-frame w, h, fl_x, cx, cy (fl_y still comes from the top level).
        let (w, h, fx, fy, cx, cy) =
            if i == 3 { (80, 60, 70.0, 52.0, 40.5, 29.5) } else { (64, 48, 50.0, 52.0, 32.0, 24.0) };
        let (u, v) = normalised(&axes, c, POINT);
        let (ud, vd) = opencv_distort(K, u, v);
        assert!((fx * (ud - u)).hypot(fy * (vd - v)) > 1.0, "frame {i}: distortion too weak for the test to tell");
        let name = format!("f{i:02}");
        write_png(d.join(format!("images/{name}.png")), &spot(w, h, fx * ud + cx, fy * vd + cy), 16).unwrap();
        let mut mask = Image::new(w, h, 1);
        for y in 0..h {
            for x in 0..w / 2 {
                mask.pixel_mut(x, y)[0] = 1.0;
            }
        }
        write_png(d.join(format!("masks/{name}.png")), &mask, 8).unwrap();
        // Some paths with "./", as instant-ngp writes them.
        let dot = if i % 2 == 0 { "./" } else { "" };
        let mut f = json!({
            "file_path": format!("{dot}images/{name}.png"),
            "mask_path": format!("masks/{name}.png"),
            "transform_matrix": m,
        });
        if i == 3 {
            for (k, v) in [("w", 80.0), ("h", 60.0), ("fl_x", fx), ("cx", cx), ("cy", cy)] {
                f[k] = json!(v);
            }
        }
        frames.push(f);
        expect.push(Expect { name, size: (w, h), pixel: (fx * u + cx, fy * v + cy) });
    }
    frames.reverse(); // file order must not matter: frames are sorted by file_path
    let pts = PointCloud { positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y], colors: vec![[0.5; 3]; 3] };
    write_points_ply(d.join("sparse_pc.ply"), &pts).unwrap();
    let tf = json!({
        "camera_model": "OPENCV", "fl_x": 50.0, "fl_y": 52.0, "w": 64, "h": 48,
        "k1": K[0], "k2": K[1], "p1": K[2], "p2": K[3],
        "ply_file_path": "sparse_pc.ply",
        "frames": frames,
    });
    std::fs::write(d.join("transforms.json"), serde_json::to_string_pretty(&tf).unwrap()).unwrap();
    (tf, expect)
}

fn err(root: &Path) -> String {
    load_dataset(root, &LoadOptions::default()).unwrap_err().to_string()
}

#[test]
fn capture_with_distortion_per_frame_intrinsics_and_masks() {
    let d = tmp_dir("tf-capture");
    let (_, expect) = write_capture(&d);
    assert_eq!(detect_layout(&d).unwrap(), Layout::Transforms);
    let ds = load_dataset(&d, &LoadOptions::default()).unwrap();
    assert_eq!(ds.camera_model, "OPENCV");
    check_capture(&ds, &expect);
    let _ = std::fs::remove_dir_all(&d);
}

/// instant-ngp's own files: distortion terms with no `camera_model` (read as OPENCV, as
/// instant-ngp and nerfstudio do, and `svgir info` says so), beside keys that change no camera
/// (`aabb_scale`, `scale`, `offset`, `applied_transform`, `applied_scale`, per-frame
/// `sharpness`): the same cameras, undistorted photos and points as the explicit OPENCV file.
#[test]
fn instant_ngp_conventions_read_as_its_tools_read_them() {
    let d = tmp_dir("tf-ngp");
    let (mut tf, expect) = write_capture(&d);
    let top = tf.as_object_mut().unwrap();
    top.remove("camera_model");
    top.insert("aabb_scale".into(), json!(16));
    top.insert("scale".into(), json!(0.33));
    top.insert("offset".into(), json!([0.5, 0.5, 0.5]));
    top.insert("applied_transform".into(), json!([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]]));
    top.insert("applied_scale".into(), json!(0.25));
    for (i, f) in tf["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
        f["sharpness"] = json!(100.0 + i as f64);
    }
    std::fs::write(d.join("transforms.json"), serde_json::to_string_pretty(&tf).unwrap()).unwrap();
    let ds = load_dataset(&d, &LoadOptions::default()).unwrap();
    assert_eq!(ds.camera_model, "OPENCV (distortion terms without a camera_model)");
    check_capture(&ds, &expect);
    assert!(dataset_summary(&ds).contains("cameras   OPENCV (distortion terms without a camera_model)"));
    // The same file without its distortion terms is a pinhole capture: the spots stay where the
    // lens put them, pixels away from the pinhole projection.
    for k in ["k1", "k2", "p1", "p2"] {
        tf.as_object_mut().unwrap().remove(k);
    }
    std::fs::write(d.join("transforms.json"), serde_json::to_string_pretty(&tf).unwrap()).unwrap();
    let ds = load_dataset(&d, &LoadOptions::default()).unwrap();
    assert_eq!(ds.camera_model, "PINHOLE");
    let v = &ds.train[0];
    let e = expect.iter().find(|e| e.name == v.name).unwrap();
    let (sx, sy) = peak(&v.image, 0);
    assert!((sx - e.pixel.0).hypot(sy - e.pixel.1) > 1.0, "{}: no distortion left to see", v.name);
    let _ = std::fs::remove_dir_all(&d);
}

/// The cameras, photos, masks, points and summary of [`write_capture`]'s capture.
fn check_capture(ds: &svgir_core::Dataset, expect: &[Expect]) {
    // Every 8th frame after sorting by file path is a test view.
    let names = |v: &[svgir_core::View]| v.iter().map(|v| v.name.clone()).collect::<Vec<_>>();
    assert_eq!(names(&ds.test), ["f00", "f08"]);
    assert_eq!(names(&ds.train), ["f01", "f02", "f03", "f04", "f05", "f06", "f07", "f09"]);
    assert_eq!(ds.masks, MaskSource::PerFrame);
    assert!(ds.has_masks());
    assert_eq!(ds.points.as_ref().unwrap().positions.len(), 3);
    for view in ds.all_views() {
        let e = expect.iter().find(|e| e.name == view.name).unwrap();
        assert_eq!((view.image.width, view.image.height), e.size, "{}", view.name);
        // The camera convention: the world point projects where the hand computation says.
        let (gx, gy, _) = view.camera.project(ds.world_rotation * POINT).unwrap();
        assert!((gx as f64 - e.pixel.0).abs() < 1e-3 && (gy as f64 - e.pixel.1).abs() < 1e-3, "{}", view.name);
        // The photo was undistorted: the spot sits at the pinhole projection.
        let (sx, sy) = peak(&view.image, 0);
        eprintln!("{}: spot {:.3} px from the pinhole projection", view.name, (sx - e.pixel.0).hypot(sy - e.pixel.1));
        assert!(
            (sx - e.pixel.0).hypot(sy - e.pixel.1) < 0.25,
            "{}: spot ({sx:.2}, {sy:.2}) vs {:?}",
            view.name,
            e.pixel
        );
        // The mask became alpha: opaque left of centre, transparent right of it.
        let (w, h) = e.size;
        assert_eq!(
            (view.image.pixel(w / 4, h / 2)[3], view.image.pixel(3 * w / 4, h / 2)[3]),
            (1.0, 0.0),
            "{}",
            view.name
        );
    }
    let f03 = ds.train.iter().find(|v| v.name == "f03").unwrap().camera.intrinsics;
    assert_eq!((f03.fx, f03.fy, f03.cx, f03.cy, f03.width), (70.0, 52.0, 40.5, 29.5, 80));

    // `svgir info` on the folder.
    let s = dataset_summary(ds);
    eprintln!("{s}");
    for line in ["layout    transforms.json\n", "masks     per-frame mask_path\n", "points    3\n", "8 train, 2 test"] {
        assert!(s.contains(line), "{line:?} not in\n{s}");
    }
    assert!(s.contains("cameras   OPENCV"), "{s}");
}

#[test]
fn split_lists_json_path_and_layout_precedence() {
    let d = tmp_dir("tf-split");
    let (mut tf, _) = write_capture(&d);
    tf["train_filenames"] = json!(["images/f01.png", "./images/f02.png", "images/f05.png"]);
    tf["test_filenames"] = json!(["images/f09.png"]);
    tf["val_filenames"] = json!(["images/f00.png"]); // test_filenames wins
    let json_path = d.join("capture.json");
    std::fs::write(&json_path, tf.to_string()).unwrap();
    assert_eq!(detect_layout(&json_path).unwrap(), Layout::Transforms);
    let ds = load_dataset(&json_path, &LoadOptions::default()).unwrap();
    let names: Vec<&str> = ds.train.iter().map(|v| v.name.as_str()).collect();
    assert_eq!((names, ds.test[0].name.as_str(), ds.test.len()), (vec!["f01", "f02", "f05"], "f09", 1));
    assert!(dataset_summary(&ds).contains("layout    transforms.json"));
    let ds =
        load_dataset(&json_path, &LoadOptions { load_test: false, max_views: Some(2), ..Default::default() }).unwrap();
    assert_eq!((ds.train.len(), ds.test.len()), (2, 0));

    // Only val_filenames: the test split, everything else trains.
    tf.as_object_mut().unwrap().remove("train_filenames");
    tf.as_object_mut().unwrap().remove("test_filenames");
    std::fs::write(&json_path, tf.to_string()).unwrap();
    let ds = load_dataset(&json_path, &LoadOptions::default()).unwrap();
    assert_eq!((ds.train.len(), ds.test[0].name.as_str()), (9, "f00"));

    // A folder with transforms_train.json stays a NeRF dataset.
    std::fs::write(d.join("transforms_train.json"), "{}").unwrap();
    assert_eq!(detect_layout(&d).unwrap(), Layout::Nerf);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn errors_name_the_file_and_the_problem() {
    let d = tmp_dir("tf-errors");
    let (tf, _) = write_capture(&d);
    let json_path = d.join("transforms.json");
    let write = |v: &Value| std::fs::write(&json_path, v.to_string()).unwrap();

    let mut bad = tf.clone();
    bad["camera_model"] = json!("EQUIRECTANGULAR");
    write(&bad);
    assert_eq!(
        err(&d),
        format!(
            "{}: unsupported camera_model EQUIRECTANGULAR (supported: PINHOLE, OPENCV, OPENCV_FISHEYE)",
            json_path.display()
        )
    );
    let mut bad = tf.clone();
    bad["frames"][2]["camera_model"] = json!("FISHEYE624");
    write(&bad);
    assert_eq!(
        err(&d),
        format!(
            "{}: camera 2: unsupported camera_model FISHEYE624 (supported: PINHOLE, OPENCV, OPENCV_FISHEYE)",
            json_path.display()
        )
    );
    let mut bad = tf.clone();
    bad["frames"][0]["transform_matrix"][0][0] = json!(2.0);
    write(&bad);
    assert!(err(&d).contains("transforms.json: camera 0: camera rotation is not a rotation"), "{}", err(&d));
    let mut bad = tf.clone();
    bad["frames"][1].as_object_mut().unwrap().remove("mask_path");
    write(&bad);
    assert!(err(&d).contains("has a mask_path but frame 1 (./images/f08.png) has none"), "{}", err(&d));
    let mut bad = tf.clone();
    for k in ["fl_x", "fl_y"] {
        bad.as_object_mut().unwrap().remove(k);
    }
    write(&bad);
    assert_eq!(err(&d), format!("{}: camera 0: no focal length (fl_x or camera_angle_x)", json_path.display()));
    // camera_angle_x stands in for fl_x.
    bad["camera_angle_x"] = json!(1.2);
    write(&bad);
    assert!(load_dataset(&d, &LoadOptions::default()).is_ok());

    write(&tf);
    let mask = d.join("masks/f04.png");
    write_png(&mask, &Image::filled(8, 8, &[1.0]), 8).unwrap();
    let photo = d.join("images/f04.png");
    assert_eq!(err(&d), format!("{}: mask is 8x8 but its photo {} is 64x48", mask.display(), photo.display()));
    std::fs::remove_file(&mask).unwrap();
    assert_eq!(err(&d), format!("{}: missing mask", mask.display()));
    std::fs::remove_file(&photo).unwrap();
    // The photo is read before its mask.
    assert_eq!(err(&d), format!("{}: missing view image", photo.display()));
    write_png(&photo, &Image::filled(60, 48, &[0.5]), 8).unwrap();
    assert_eq!(err(&d), format!("{}: image is 60x48 but view 5 is 64x48", photo.display()));
    let _ = std::fs::remove_dir_all(&d);
}

fn data(rel: &str) -> Option<PathBuf> {
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data")).join(rel);
    if p.exists() {
        Some(p)
    } else {
        common::missing_data(&p.display().to_string());
        None
    }
}

/// The real statue capture written as a nerfstudio `transforms.json` (COLMAP w2c -> OpenGL c2w,
/// as `ns-process-data` does, absolute image paths) loads to the COLMAP loader's cameras.
#[test]
fn statue_as_transforms_json_matches_the_colmap_loader() {
    let Some(root) = data("colmap/statue") else { return };
    let model = colmap::read_model(&root.join("sparse")).unwrap();
    // The statue has a camera per photo (sizes differ by a pixel): per-frame intrinsics.
    let frames: Vec<Value> = (0..model.images.len())
        .map(|i| {
            let c = colmap::image_camera(&model, i).unwrap();
            let r_c2w: Mat3 = c.rotation.transpose();
            // OpenCV camera axes -> OpenGL: flip the y and z columns.
            let cols = [r_c2w.x_axis, -r_c2w.y_axis, -r_c2w.z_axis, c.center()];
            let rows: Vec<Vec<f32>> = (0..3).map(|r| cols.iter().map(|v| v[r]).collect()).collect();
            let im = &model.images[i];
            let cam = &model.cameras[&im.camera_id];
            let p = &cam.params;
            let path = root.join("images").join(&im.name);
            json!({"file_path": path.to_string_lossy(), "transform_matrix": rows,
                "fl_x": p[0], "fl_y": p[1], "cx": p[2], "cy": p[3], "w": cam.width, "h": cam.height})
        })
        .collect();
    let tf = json!({"camera_model": "PINHOLE", "frames": frames});
    let d = tmp_dir("tf-statue");
    std::fs::write(d.join("transforms.json"), tf.to_string()).unwrap();
    let opts = LoadOptions { max_views: Some(3), ..Default::default() };
    let (a, b) = (load_dataset(&root, &opts).unwrap(), load_dataset(&d, &opts).unwrap());
    assert_eq!((b.train.len(), b.test.len()), (3, 3));
    assert!(!a.has_masks() && !b.has_masks());
    for (va, vb) in a.all_views().zip(b.all_views()) {
        assert_eq!(va.name, vb.name);
        assert_eq!(va.image.data, vb.image.data);
        for x in [Vec3::ZERO, Vec3::new(0.5, -0.3, 1.0)] {
            let (pa, pb) = (va.camera.project(x).unwrap(), vb.camera.project(x).unwrap());
            assert!((pa.0 - pb.0).abs() < 1e-2 && (pa.1 - pb.1).abs() < 1e-2, "{}: {pa:?} vs {pb:?}", va.name);
        }
    }
    let _ = std::fs::remove_dir_all(&d);
}
