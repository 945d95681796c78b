//! Are nerf_synthetic's `r_N_normal_0001.png` usable as world-space ground-truth normals?
//! The data README says to verify; without the mesh, geometry gives two checks:
//! (1) decoded vectors must be unit length on the object (tests the encoding);
//! (2) on visible surfaces the normal faces the camera, `n . (-ray) > 0` (tests the space).
//!
//! Finding (asserted below, so a changed file set makes this fail and the loader gets
//! revisited): the files are NOT `(n + 1) / 2` (neither on stored nor on sRGB-decoded values:
//! few unit vectors, background opaque black). They are the raw world-space Normal pass with
//! negative components clipped to 0: wherever `rgb` has unit length it faces the camera, and
//! most non-unit object pixels have a zero component (about 60% of object pixels are clipped
//! over 5 test views). A normal with any negative component is
//! lost, so these cannot serve as ground truth and the NeRF loader does not load them.

mod common;

use glam::Vec3;
use std::path::PathBuf;
use svgir_core::color::srgb_to_linear;
use svgir_io::{load_dataset, read_image, LoadOptions};

#[test]
fn lego_normal_pass_is_not_a_unit_normal_encoding() {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/nerf_synthetic/lego_400"));
    if !root.exists() {
        common::missing_data(&root.display().to_string());
        return;
    }
    let ds = load_dataset(&root, &LoadOptions { max_views: Some(5), ..Default::default() }).unwrap();
    type Decode = fn([f32; 3]) -> Vec3;
    let decodings: [(&str, Decode); 3] = [
        ("2rgb-1", |p| Vec3::from(p) * 2.0 - Vec3::ONE),
        ("2srgb_to_linear(rgb)-1", |p| Vec3::from(p.map(srgb_to_linear)) * 2.0 - Vec3::ONE),
        ("rgb", Vec3::from),
    ];
    let (mut clipped_all, mut obj_all) = (0usize, 0usize);
    for v in ds.test.iter() {
        let img = read_image(root.join("test").join(format!("{}_normal_0001.png", v.name))).unwrap();
        assert!(img.data.chunks(4).all(|p| p[3] == 1.0), "normal pass has no mask");
        for (k, (name, dec)) in decodings.into_iter().enumerate() {
            let (mut unit, mut facing, mut n_obj, mut zero_comp) = (0usize, 0usize, 0usize, 0usize);
            for y in 0..img.height {
                for x in 0..img.width {
                    if v.image.pixel(x, y)[3] < 1.0 {
                        continue;
                    }
                    let p = img.pixel(x, y);
                    let n = dec([p[0], p[1], p[2]]);
                    n_obj += 1;
                    if (n.length() - 1.0).abs() < 0.02 {
                        unit += 1;
                        facing += (n.dot(-v.camera.ray_dir(x as f32 + 0.5, y as f32 + 0.5)) > 0.0) as usize;
                    } else if p[..3].contains(&0.0) {
                        zero_comp += 1;
                    }
                }
            }
            let (u, f) = (unit as f32 / n_obj as f32, facing as f32 / unit.max(1) as f32);
            eprintln!("{} {name}: unit {u:.3} (of which facing the camera {f:.3}) of {n_obj} object pixels", v.name);
            if k < 2 {
                assert!(u < 0.5, "{}: {name} decodes to unit normals ({u}); revisit loading them", v.name);
            } else {
                assert!(f > 0.99, "{}: unclipped raw normals should be world space and face the camera", v.name);
                eprintln!("  non-unit with a zero component: {zero_comp} of {}", n_obj - unit);
                clipped_all += n_obj - unit;
                obj_all += n_obj;
            }
        }
    }
    eprintln!("clipped (unusable) object pixels: {clipped_all} of {obj_all}");
    assert!(clipped_all as f32 > 0.2 * obj_all as f32, "most normals survive; revisit loading them");
}
