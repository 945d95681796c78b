//! A real capture through the binary, small and short: the statue (COLMAP, no masks) trains with
//! the capture profile, reports which test pixels the training photos saw, gets masks from
//! `svgir masks`, and with those masks trains with the object profile.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The statue masks' confidence (svgir_train::mask_check), measured 1.00 on this short run.
const CONFIDENCE_FLOOR: f64 = 0.9;

fn svgir() -> Command {
    Command::new(env!("CARGO_BIN_EXE_svgir"))
}

fn statue() -> Option<PathBuf> {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/colmap/statue"));
    if root.exists() {
        Some(root)
    } else {
        missing_data(&root.display().to_string());
        None
    }
}

/// A folder of `../shared/data` that a test needs is missing (`what` names it). With
/// `SVGIR_REQUIRE_DATA=1` (set by `.ci/run`) the test fails; otherwise it prints `SKIPPED` and
/// the caller returns.
fn missing_data(what: &str) {
    let msg = format!("{what} not found; this test needs ../shared/data");
    if std::env::var("SVGIR_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!("SVGIR_REQUIRE_DATA=1: {msg}");
    }
    eprintln!("SKIPPED: {msg}");
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().expect("svgir runs");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "svgir failed: {text}");
    text
}

#[test]
fn statue_capture_profile_masks_then_object_profile() {
    let Some(data) = statue() else { return };
    let tmp = std::env::temp_dir().join(format!("svgir_capture_test_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let run1 = tmp.join("capture");

    // Upright on load.
    let info = run(svgir().arg("info").arg(&data));
    assert!(info.contains("turned upright") && info.contains("masks     none"), "{info}");

    // Stage 1, capture profile chosen from the data.
    let log = run(svgir().args(["train", "--downscale", "8", "--iterations", "600", "--out"]).arg(&run1).arg(&data));
    assert!(log.contains("profile: capture (the dataset has no foreground masks)"), "{log}");
    let cfg = json(&run1.join("config.json"));
    assert_eq!(cfg["profile"]["name"], "capture");
    assert_eq!(cfg["stage1"]["background"], "random");
    assert_eq!(cfg["stage1"]["densify"]["interval"], 100, "absolute 3DGS cadence, not scaled to the run");
    assert_eq!(cfg["stage1"]["sh_upgrade_interval"], 1000);
    assert!(cfg["stage1"]["densify"]["max_gaussians"].as_u64().unwrap() > 1 << 40, "no budget");
    let eval = json(&run1.join("eval.json"));
    let psnr = eval["psnr"].as_f64().unwrap();
    // Measured: 16.15 dB (600 iterations at an eighth of the size); the floor leaves 1 dB for
    // other CPUs' SIMD paths.
    eprintln!("capture profile: test PSNR {psnr:.2} dB");
    assert!(psnr > 15.0, "test PSNR {psnr}");
    let cov = eval["coverage"].as_array().expect("coverage per test view");
    assert_eq!(cov.len(), 3);
    for c in cov {
        let share = c["seen_share"].as_f64().unwrap();
        assert!(share > 0.2 && share <= 1.0, "{c}");
    }
    assert!(run1.join("test/DSC_5283_seen.png").exists());

    // Masks from that reconstruction: one PNG per photo, at the photo's size.
    let masks = tmp.join("masks");
    let log = run(svgir().arg("masks").arg(&data).arg("--run").arg(&run1).arg("--out").arg(&masks));
    assert!(log.contains("wrote 23 masks"), "{log}");
    let m = image::open(masks.join("DSC_5283.png")).expect("mask PNG").to_luma8();
    let photo = image::image_dimensions(data.join("images/DSC_5283.jpg")).unwrap();
    assert_eq!(m.dimensions(), photo);
    let fg = m.pixels().filter(|p| p.0[0] > 127).count() as f64 / (photo.0 * photo.1) as f64;
    assert!(fg > 0.01 && fg < 0.9, "foreground share {fg}");
    // The masks' own check passed and says how far they are trusted.
    let conf = json(&run1.join("foreground.json"))["confidence"].as_f64().expect("confidence recorded");
    eprintln!("statue masks: confidence {conf:.3}");
    assert!(log.contains("masks: confidence") && conf > CONFIDENCE_FLOOR, "confidence {conf}");

    // With the masks the same command picks the object profile and the mask losses.
    let run2 = tmp.join("object");
    let log = run(svgir()
        .args(["train", "--downscale", "8", "--iterations", "100", "--masks"])
        .arg(&masks)
        .arg("--out")
        .arg(&run2)
        .arg(&data));
    assert!(log.contains("profile: object (the dataset has foreground masks)"), "{log}");
    let cfg = json(&run2.join("config.json"));
    assert_eq!(cfg["stage1"]["use_mask"], true);
    assert_eq!(cfg["load"]["masks"], masks.to_str().unwrap());
    let _ = std::fs::remove_dir_all(&tmp);
}

/// `svgir capture` on the statue at a small size: every step's result, the report with the masks
/// first, and a second run that finds every step done.
#[test]
fn capture_command_runs_every_step_and_resumes() {
    let Some(data) = statue() else { return };
    let out = std::env::temp_dir().join(format!("svgir_capture_cmd_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let cmd = || {
        let mut c = svgir();
        c.args(["--threads", "2", "capture"]).arg(&data).arg("--out").arg(&out);
        c.args(["--downscale", "8", "--iterations", "100", "--stage2-iterations", "10"]);
        c.args(["--relight-directions", "16", "--turntable", "2", "--device", "cpu"]);
        c
    };
    let log = run(&mut cmd());
    assert!(log.contains("masks: confidence"), "{log}");
    for f in [
        "scene/eval.json",
        "masks/DSC_5283.png",
        "object/eval.json",
        "object/stage2/eval.json",
        "object/stage2/surroundings.json",
        "object/stage2/turntable/sunset_001.png",
        "export/object.glb",
        "export/splats.glb",
        "object/viewer.html",
        "object/report.html",
    ] {
        assert!(out.join(f).is_file(), "{f} not written");
    }
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    let at = |s: &str| page.find(s).unwrap_or_else(|| panic!("report lacks {s:?}"));
    assert!(at("1. Masks") < at("2. Reconstructions") && at("2. Reconstructions") < at("3. Materials"));
    assert!(page.contains("Confidence") && page.contains("data:image/png;base64,") && page.contains("DSC_"));
    // Stage 2 traced through the rest of the statue's scene: the paper and table it stands on.
    let sur = json(&out.join("object/stage2/surroundings.json"));
    let r = &sur["report"];
    let n = |k: &str| r[k].as_u64().unwrap();
    assert!(n("kept") > 0 && n("in_hull") > 0, "{sur}");
    assert_eq!(n("kept") + n("in_hull") + n("touching"), n("near"), "{sur}");
    assert!(log.contains("of the micro-buffers' rays end on the surroundings"), "{log}");
    assert!(page.contains("Stage 2 traced through"), "report lacks the surroundings");
    // Again: every step is found done.
    let log = run(&mut cmd());
    assert_eq!(log.matches("(done before)").count(), 5, "{log}");
    report_holds_phone_capture_names(&out.join("object"));
    let _ = std::fs::remove_dir_all(&out);
}

/// A plain folder of photos is posed with Debian's COLMAP (CPU SIFT, low quality to fit CI) and
/// undistorted, and the rest of the path runs on the result.
#[test]
fn capture_poses_a_plain_folder_with_colmap() {
    let Some(data) = statue() else { return };
    if Command::new("colmap").arg("-h").output().is_err() {
        assert!(std::env::var_os("SVGIR_REQUIRE_COLMAP").is_none(), "SVGIR_REQUIRE_COLMAP=1 but colmap is missing");
        eprintln!("SKIPPED: colmap is not installed");
        return;
    }
    let out = std::env::temp_dir().join(format!("svgir_capture_colmap_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let mut c = svgir();
    c.args(["--threads", "2", "capture"]).arg(data.join("images")).arg("--out").arg(&out);
    c.args(["--colmap-quality", "low", "--downscale", "8", "--iterations", "100", "--stage2-iterations", "10"]);
    c.args(["--relight-directions", "16", "--turntable", "2", "--device", "cpu"]);
    let res = c.output().expect("svgir runs");
    let log = format!("{}{}", String::from_utf8_lossy(&res.stdout), String::from_utf8_lossy(&res.stderr));
    assert!(log.contains("colmap automatic_reconstructor") && log.contains("colmap image_undistorter"), "{log}");
    let dense = out.join("colmap/dense");
    let info = run(svgir().arg("info").arg(&dense));
    // Measured: all 23 photos registered at low quality, undistorted to PINHOLE.
    assert!(info.contains("views     20 train, 3 test") && info.contains("cameras   PINHOLE"), "{info}");
    assert!(out.join("scene/eval.json").is_file(), "stage 1 on the posed capture did not run: {log}");
    // After posing the path is the one the test above checks on the statue's own poses. Here
    // COLMAP's poses differ from run to run (threads), and a 100-iteration stage 1 on them at an
    // eighth of the size sometimes leaves too little to find the object (1 run in 4 measured):
    // then the masks step must refuse with its cause, as it does.
    if !res.status.success() {
        assert!(log.contains("no masks written") && log.contains("--masks DIR"), "{log}");
    } else {
        assert!(out.join("object/report.html").is_file(), "{log}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// The object's report with photos named as phones name them (long, no spaces): in Chromium at
/// desktop and phone widths the labels wrap and the page does not scroll sideways (it did:
/// 1497 px in a 1280 px window).
fn report_holds_phone_capture_names(object: &Path) {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tools/browser"));
    if !(dir.join("node_modules/playwright-core").exists() && Path::new("/usr/bin/chromium").exists()) {
        let why = format!("SKIPPED: browser check (run `npm ci` in {} and install Chromium)", dir.display());
        assert!(std::env::var_os("SVGIR_REQUIRE_DATA").is_none(), "{why}");
        eprintln!("{why}");
        return;
    }
    let hashed = "PXL_20261201_093412345_MP_3f9a2c7e1b4d4e8f9a0b1c2d3e4f5a6b";
    for sub in ["test", "stage2/test"] {
        for e in std::fs::read_dir(object.join(sub)).unwrap().flatten() {
            let name = e.file_name().to_string_lossy().replace("DSC_", &format!("{hashed}_"));
            std::fs::rename(e.path(), object.join(sub).join(name)).unwrap();
        }
    }
    run(svgir().arg("report").arg(object));
    let res = Command::new("node")
        .arg(dir.join("report_check.mjs"))
        .arg(object.join("report.html"))
        .arg(object.join("shots"))
        .output()
        .expect("node runs");
    let stdout = String::from_utf8_lossy(&res.stdout);
    assert!(res.status.success(), "report check failed: {stdout}{}", String::from_utf8_lossy(&res.stderr));
}

/// A folder of photos without poses needs COLMAP; without it the command says how to get it.
#[test]
fn capture_without_poses_or_colmap_says_what_to_install() {
    if Command::new("colmap").arg("-h").output().is_ok() {
        eprintln!("colmap is installed: the message for its absence is not shown here");
        return;
    }
    let dir = std::env::temp_dir().join(format!("svgir_capture_nocolmap_{}", std::process::id()));
    std::fs::create_dir_all(dir.join("photos")).unwrap();
    image::RgbImage::new(8, 8).save(dir.join("photos/a.png")).unwrap();
    let res = svgir().arg("capture").arg(dir.join("photos")).arg("--out").arg(dir.join("run")).output().unwrap();
    let err = String::from_utf8_lossy(&res.stderr);
    assert!(!res.status.success() && err.contains("apt install colmap") && err.contains("photos"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
