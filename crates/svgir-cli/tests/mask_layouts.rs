//! `svgir masks` on one small rendered capture per layout (`tests/captures`, made with
//! `tools/blender_capture.py`): an object on a cluttered table, on a plain wall, and on a stand
//! over a cluttered floor, each with its true masks. The masks it writes must keep their recorded
//! IoU against the truth. Pinned to AVX2 and 2 threads like the quality test, so two runs give the
//! same figures; a drop of more than 0.01 in a capture's mean IoU fails.

use std::path::Path;
use std::process::Command;

const CAPTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/captures");

/// (capture, mean IoU measured at 1500 iterations; 100 x 100 photos, 32 views).
const RECORDED: [(&str, f64); 3] = [("table_clutter", 0.8911), ("wall_plain", 0.9395), ("stand_clutter", 0.9255)];

fn mask(path: &Path) -> Vec<bool> {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_luma8();
    img.pixels().map(|p| p.0[0] > 127).collect()
}

#[test]
fn masks_hold_their_iou_on_table_wall_and_stand() {
    let tmp = std::env::temp_dir().join(format!("svgir_mask_layouts_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let mut failed = Vec::new();
    eprintln!("{:>14} {:>9} {:>9} {:>9}", "capture", "mean IoU", "min IoU", "recorded");
    for (name, recorded) in RECORDED {
        let data = Path::new(CAPTURES).join(name);
        let out = tmp.join(name);
        let res = Command::new(env!("CARGO_BIN_EXE_svgir"))
            .env("SVGIR_SIMD", "avx2")
            .args(["--threads", "2", "masks"])
            .arg(&data)
            .arg("--out")
            .arg(out.join("masks"))
            .args(["--downscale", "1", "--iterations", "1500", "--work"])
            .arg(out.join("run"))
            .output()
            .expect("svgir runs");
        let log = format!("{}{}", String::from_utf8_lossy(&res.stdout), String::from_utf8_lossy(&res.stderr));
        assert!(res.status.success(), "{name}: svgir masks failed: {log}");
        let mut ious = Vec::new();
        for entry in std::fs::read_dir(data.join("masks_true")).unwrap() {
            let truth_path = entry.unwrap().path();
            let truth = mask(&truth_path);
            let ours = mask(&out.join("masks").join(truth_path.file_name().unwrap()));
            assert_eq!(ours.len(), truth.len(), "{name}: mask size");
            let inter = ours.iter().zip(&truth).filter(|(a, b)| **a && **b).count() as f64;
            let union = ours.iter().zip(&truth).filter(|(a, b)| **a || **b).count() as f64;
            ious.push(inter / union.max(1.0));
        }
        assert_eq!(ious.len(), 32, "{name}: one mask per photo");
        let mean = ious.iter().sum::<f64>() / ious.len() as f64;
        let min = ious.iter().cloned().fold(1.0, f64::min);
        eprintln!("{name:>14} {mean:>9.4} {min:>9.4} {recorded:>9.4}");
        if mean < recorded - 0.01 {
            failed.push(format!("{name}: mean IoU {mean:.4} < recorded {recorded:.4} - 0.01"));
        }
    }
    let _ = std::fs::remove_dir_all(&tmp);
    assert!(failed.is_empty(), "{}", failed.join("; "));
}
