//! The loaders on the real data in /work/shared/data (skipped loudly if it is absent; a failure
//! with `SVGIR_REQUIRE_DATA=1`).

mod common;

use glam::Vec3;
use std::path::PathBuf;
use svgir_io::{colmap, load_dataset, LoadOptions};

fn data_path(rel: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data")).join(rel)
}

fn data(rel: &str) -> Option<PathBuf> {
    let p = data_path(rel);
    if p.exists() {
        Some(p)
    } else {
        common::missing_data(&p.display().to_string());
        None
    }
}

/// Distance from the origin to the ray through the principal point.
fn principal_ray_miss(cam: &svgir_core::Camera) -> f32 {
    let k = cam.intrinsics;
    let d = cam.ray_dir(k.cx, k.cy);
    let c = cam.center();
    (c - d * c.dot(d)).length()
}

#[test]
fn lego_counts_sizes_and_cameras() {
    let Some(root) = data("nerf_synthetic/lego_400") else { return };
    let ds = load_dataset(&root, &LoadOptions::default()).unwrap();
    assert_eq!((ds.train.len(), ds.test.len()), (100, 200));
    assert_eq!(ds.camera_model, "blender");
    assert_eq!(ds.masks, svgir_core::MaskSource::Alpha);
    for v in ds.all_views() {
        assert_eq!((v.image.width, v.image.height, v.image.channels), (400, 400, 4));
        assert!((v.camera.intrinsics.fov_x() - 0.6911112).abs() < 1e-5);
        assert!(principal_ray_miss(&v.camera) < 1e-3, "{}: {}", v.name, principal_ray_miss(&v.camera));
        // The object is in the middle, background transparent at the corners.
        assert_eq!(v.image.pixel(0, 0)[3], 0.0);
        assert!(v.image.pixel(200, 200)[3] > 0.0 || v.image.data.chunks(4).filter(|p| p[3] > 0.5).count() > 1000);
    }
    assert_eq!(ds.train[0].name, "r_0");
    assert!(ds.test.iter().all(|v| v.normal.is_none()), "lego normals are not loaded (see nerf_normals.rs)");
    assert!(ds.all_views().all(|v| (v.camera.center().length() - 4.031).abs() < 0.01));
}

#[test]
fn downscaling_and_subsets() {
    let Some(root) = data("nerf_synthetic/lego_400") else { return };
    let full =
        load_dataset(&root, &LoadOptions { load_test: false, max_views: Some(4), ..Default::default() }).unwrap();
    let opts = LoadOptions { downscale: Some(4.0), load_test: false, max_views: Some(4), ..Default::default() };
    let ds = load_dataset(&root, &opts).unwrap();
    assert_eq!((ds.train.len(), ds.test.len()), (4, 0));
    assert_eq!(ds.train.iter().map(|v| v.name.as_str()).collect::<Vec<_>>(), ["r_0", "r_25", "r_50", "r_75"]);
    for (a, b) in full.train.iter().zip(&ds.train) {
        assert_eq!((b.image.width, b.image.height), (100, 100));
        let (ka, kb) = (a.camera.intrinsics, b.camera.intrinsics);
        assert!((kb.fx - ka.fx / 4.0).abs() < 1e-3 && (kb.cx - 50.0).abs() < 1e-4);
        // A world point lands at the same relative image position.
        let p = Vec3::new(0.3, -0.2, 0.5);
        let (xa, ya, _) = a.camera.project(p).unwrap();
        let (xb, yb, _) = b.camera.project(p).unwrap();
        assert!((xa / 4.0 - xb).abs() < 1e-3 && (ya / 4.0 - yb).abs() < 1e-3);
        // Coverage is preserved by the area filter.
        let cov = |img: &svgir_core::Image| img.data.chunks(4).map(|p| p[3]).sum::<f32>() / img.pixel_count() as f32;
        assert!((cov(&a.image) - cov(&b.image)).abs() < 1e-4);
    }
    let ds = load_dataset(
        &root,
        &LoadOptions { resolution: Some(160), load_test: false, max_views: Some(1), downscale: None, masks: None },
    )
    .unwrap();
    assert_eq!((ds.train[0].image.width, ds.train[0].image.height), (160, 160));
}

#[test]
fn tensoir_scenes_have_ground_truth_relit_images_and_lights() {
    let mut missing = Vec::new();
    for (scene, size, ntrain, ntest, lights) in [
        ("suzanne_marble", 256, 48, 12, &["city", "forest", "night"][..]),
        ("cup_and_ball", 256, 48, 12, &["courtyard", "studio", "sunrise"][..]),
        ("bowl_fruit_128", 128, 32, 8, &["night", "sunset"][..]),
    ] {
        // Every scene present is checked; the missing ones are reported together at the end.
        let root = data_path(&format!("synthetic/{scene}"));
        if !root.exists() {
            missing.push(root.display().to_string());
            continue;
        }
        let ds = load_dataset(&root, &LoadOptions::default()).unwrap();
        assert_eq!((ds.train.len(), ds.test.len()), (ntrain, ntest), "{scene}");
        assert_eq!(ds.name, scene);
        assert_eq!(ds.masks, svgir_core::MaskSource::Alpha, "{scene}");
        let tl = ds.train_light.as_ref().unwrap();
        assert!(tl.envmap_path.as_ref().unwrap().is_file() && tl.strength > 0.0);
        let mut names: Vec<&str> = ds.relight_lights.iter().map(|l| l.name.as_str()).collect();
        names.sort();
        assert_eq!(names, lights, "{scene}");
        assert!(ds.relight_lights.iter().all(|l| l.envmap_path.as_ref().is_some_and(|p| p.is_file())));
        for v in ds.all_views() {
            assert_eq!((v.image.width, v.image.height), (size, size));
            assert!(principal_ray_miss(&v.camera) < 1e-3);
            assert!((v.camera.center().length() - 4.0).abs() < 1e-3);
            let (albedo, normal, rough) =
                (v.albedo.as_ref().unwrap(), v.normal.as_ref().unwrap(), v.roughness.as_ref().unwrap());
            assert_eq!((albedo.channels, normal.channels, rough.channels), (3, 3, 1));
            // Normals: unit on the object, zero off it, and facing the camera.
            let mut facing = 0;
            let mut on = 0;
            for y in 0..size {
                for x in 0..size {
                    let n = Vec3::from_slice(normal.pixel(x, y));
                    if v.image.pixel(x, y)[3] > 0.0 {
                        assert!((n.length() - 1.0).abs() < 1e-4);
                        on += 1;
                        facing += (n.dot(-v.camera.ray_dir(x as f32 + 0.5, y as f32 + 0.5)) > 0.0) as usize;
                    } else {
                        assert_eq!(n, Vec3::ZERO);
                    }
                }
            }
            assert!(on > 100 && facing as f32 > 0.99 * on as f32, "{scene}/{}: {facing}/{on} facing", v.name);
        }
        let summary = svgir_io::dataset_summary(&ds);
        eprintln!("{summary}");
        assert!(summary.contains(&format!("{ntrain} train, {ntest} test")) && summary.contains("albedo"));
        for v in &ds.test {
            let mut keys: Vec<&str> = v.relit.keys().map(|s| s.as_str()).collect();
            keys.sort();
            assert_eq!(keys, lights);
        }
    }
    if !missing.is_empty() {
        common::missing_data(&missing.join(", "));
    }
}

#[test]
fn tensoir_downscale_keeps_normals_unit() {
    let Some(root) = data("synthetic/bowl_fruit_128") else { return };
    let opts = LoadOptions { downscale: Some(2.0), max_views: Some(2), ..Default::default() };
    let ds = load_dataset(&root, &opts).unwrap();
    assert_eq!((ds.train.len(), ds.test.len()), (2, 2));
    for v in ds.all_views() {
        assert_eq!(
            (v.image.width, v.albedo.as_ref().unwrap().width, v.relit.len()),
            (64, 64, if v.name.starts_with("test") { 2 } else { 0 })
        );
        let n = v.normal.as_ref().unwrap();
        for (p, a) in n.data.chunks(3).zip(v.image.data.chunks(4).map(|p| p[3])) {
            let l = Vec3::from_slice(p).length();
            assert!(if a > 0.0 { (l - 1.0).abs() < 1e-4 } else { l == 0.0 });
        }
        assert!((v.camera.intrinsics.cx - 32.0).abs() < 1e-5);
    }
}

#[test]
fn colmap_statue_points_reproject_onto_their_keypoints() {
    let Some(root) = data("colmap/statue") else { return };
    let model = colmap::read_model(&root.join("sparse")).unwrap();
    assert_eq!(model.images.len(), 23);
    assert!(model.points.len() > 1000, "{} points", model.points.len());
    let index: std::collections::HashMap<u32, usize> =
        model.images.iter().enumerate().map(|(i, im)| (im.id, i)).collect();
    let mut errs = Vec::new();
    for p in &model.points {
        let x = Vec3::new(p.xyz[0] as f32, p.xyz[1] as f32, p.xyz[2] as f32);
        for &(img_id, kp) in &p.track {
            let i = index[&img_id];
            let cam = colmap::image_camera(&model, i).unwrap();
            let (u, v, _) = cam.project(x).expect("point in front of a camera that saw it");
            let [ku, kv] = model.images[i].xys[kp as usize];
            assert_eq!(model.images[i].point3d_ids[kp as usize], Some(p.id));
            errs.push(((u as f64 - ku).powi(2) + (v as f64 - kv).powi(2)).sqrt());
            assert!(u >= 0.0 && v >= 0.0 && u <= cam.width() as f32 && v <= cam.height() as f32);
        }
    }
    errs.sort_by(f64::total_cmp);
    let median = errs[errs.len() / 2];
    eprintln!("statue: {} observations, median reprojection error {median:.3} px", errs.len());
    assert!(median < 2.0, "median reprojection error {median}");

    let ds = load_dataset(&root, &LoadOptions::default()).unwrap();
    assert_eq!((ds.train.len(), ds.test.len()), (20, 3));
    assert_eq!(ds.camera_model, "PINHOLE");
    assert_eq!(ds.test[0].name, "DSC_5283");
    assert_eq!(ds.test[1].name, "DSC_5291");
    let summary = svgir_io::dataset_summary(&ds);
    eprintln!("{summary}");
    assert!(summary.contains("PINHOLE") && summary.contains(&format!("points    {}", model.points.len())));
    // No masks folder, JPEG photos: no masks, whatever resizing later does to alpha.
    assert!(summary.contains("layout    COLMAP\n") && summary.contains("masks     none\n"), "{summary}");
    assert!(!ds.has_masks());
    let pts = ds.points.as_ref().unwrap();
    assert_eq!(pts.positions.len(), model.points.len());
    assert!(pts.colors.iter().flatten().all(|c| (0.0..=1.0).contains(c)));
    for v in ds.all_views() {
        assert_eq!(v.image.channels, 4);
        assert!(v.image.data.chunks(4).all(|p| p[3] == 1.0));
        assert_eq!((v.image.width, v.image.height), (v.camera.width(), v.camera.height()));
    }
    let half =
        load_dataset(&root, &LoadOptions { downscale: Some(2.0), max_views: Some(2), ..Default::default() }).unwrap();
    assert!(svgir_io::dataset_summary(&half).contains("masks     none\n"));
    let (a, b) = (&ds.train[0], &half.train[0]);
    assert_eq!(b.image.width, (a.image.width as f32 / 2.0).round() as u32);
    assert!(
        (b.camera.intrinsics.fx * a.image.width as f32 / b.image.width as f32 - a.camera.intrinsics.fx).abs() < 1e-2
    );
}

#[test]
fn all_envmaps_load() {
    let Some(dir) = data("envmaps") else { return };
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "hdr") {
            let img = svgir_io::read_image(&p).unwrap();
            assert_eq!((img.width, img.height, img.channels), (1024, 512, 3), "{}", p.display());
            assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0));
            let m = svgir_io::read_envmap(&p, 0.5, 32).unwrap();
            assert_eq!((m.width, m.height), (64, 32));
            let (mi, mm) = (img.data.iter().sum::<f32>() / img.data.len() as f32, m.mean_radiance());
            assert!(mm.iter().all(|v| v.is_finite() && *v > 0.0), "{}", p.display());
            assert!(mi > 0.0);
            n += 1;
        }
    }
    assert_eq!(n, 13);
}
