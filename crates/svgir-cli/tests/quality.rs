//! The quality regression test: a short deterministic run of both stages on the shipped scene
//! (`scenes/bowl_fruit_128`), held to the figures recorded in `tests/quality.json`.
//!
//! The run is deterministic for a given SIMD path and thread count, so it pins both (AVX2, which
//! every CI machine has, and 2 threads); two runs give the same figures to the last digit. A
//! figure more than `tolerance_db` below its record fails the test. A change that is meant to
//! move the figures records the new ones in `quality.json` in the same commit, with the reason.

use serde_json::Value;
use std::path::Path;
use std::process::Command;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/bowl_fruit_128");

fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn svgir(args: &[&str], out: &Path) {
    let status = Command::new(env!("CARGO_BIN_EXE_svgir"))
        .env("SVGIR_SIMD", "avx2")
        .args(["--threads", "2"])
        .args(args)
        .arg(out)
        .status()
        .expect("svgir runs");
    assert!(status.success(), "svgir {args:?} {} failed", out.display());
}

#[test]
fn both_stages_hold_the_recorded_quality() {
    let record = read_json(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/quality.json"));
    let run = std::env::temp_dir().join(format!("svgir_quality_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&run);
    let flags = &record["train_flags"];
    let train: Vec<&str> = flags.as_array().unwrap().iter().map(|f| f.as_str().unwrap()).collect();
    let mut args = vec!["train", SCENE];
    args.extend(&train);
    args.extend(["--device", "cpu", "--out"]);
    svgir(&args, &run);
    let flags = &record["inverse_flags"];
    let mut args: Vec<&str> = vec!["inverse"];
    args.extend(flags.as_array().unwrap().iter().map(|f| f.as_str().unwrap()));
    args.push("--run");
    svgir(&args, &run);

    let stage1 = read_json(&run.join("eval.json"));
    let stage2 = read_json(&run.join("stage2/eval.json"));
    let measured = [
        ("stage1_test_psnr", &stage1["psnr"]),
        ("nvs_psnr", &stage2["nvs"]["psnr"]),
        ("relight_psnr", &stage2["relight"]["mean"]["psnr"]),
        ("albedo_psnr", &stage2["albedo"]["psnr"]),
    ];
    let tolerance = record["tolerance_db"].as_f64().unwrap();
    println!("quality on the shipped scene (held-out views), dB:");
    println!("{:<18} {:>9} {:>9} {:>7}", "figure", "recorded", "now", "change");
    let mut drops = Vec::new();
    for (name, value) in measured {
        let now = value.as_f64().unwrap_or_else(|| panic!("{name} missing from the run's eval.json"));
        let was = record["figures"][name].as_f64().unwrap_or_else(|| panic!("quality.json lacks {name}"));
        println!("{name:<18} {was:>9.3} {now:>9.3} {:>+7.3}", now - was);
        if now < was - tolerance {
            drops.push(format!("{name} {now:.3} dB, recorded {was:.3}"));
        } else if now > was + tolerance {
            println!("  {name} rose by more than {tolerance} dB: record the new figure in tests/quality.json");
        }
    }
    let _ = std::fs::remove_dir_all(&run);
    assert!(drops.is_empty(), "quality fell more than {tolerance} dB below the record: {}", drops.join("; "));
}
