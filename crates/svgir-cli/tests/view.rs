//! `svgir view` on bad input: a clear message naming the problem and a non-zero exit.

use std::process::Command;

fn svgir(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_svgir")).args(args).output().expect("svgir runs");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn a_run_without_stage_two_is_refused_with_a_hint() {
    let dir = std::env::temp_dir().join(format!("svgir_view_cli_{}", std::process::id()));
    std::fs::create_dir_all(dir.join("stage2")).unwrap();
    let run = dir.to_str().unwrap();
    let (ok, err) = svgir(&["view", run]);
    assert!(!ok, "must fail");
    assert!(
        err.contains("checkpoint.bin") && err.contains("no stage-2 model") && err.contains("svgir inverse"),
        "{err}"
    );
    assert!(!dir.join("viewer.html").exists(), "no page is written");

    // A damaged checkpoint names the file.
    std::fs::write(dir.join("stage2/checkpoint.bin"), b"not a checkpoint").unwrap();
    let (ok, err) = svgir(&["view", run]);
    assert!(!ok && err.contains("checkpoint.bin"), "{err}");

    let (ok, err) = svgir(&["view", dir.join("missing").to_str().unwrap()]);
    assert!(!ok && err.contains("no such run folder"), "{err}");
    let (ok, err) = svgir(&["view", run, "--degree", "5"]);
    assert!(!ok && err.contains("--degree 5"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Node and Chromium are there (else SKIPPED, or a failure with SVGIR_REQUIRE_DATA=1).
fn browser_ready(repo: &std::path::Path) -> bool {
    let ok = repo.join("tools/browser/node_modules/playwright-core").is_dir()
        && std::path::Path::new(&std::env::var("CHROMIUM").unwrap_or("/usr/bin/chromium".into())).exists();
    if !ok {
        assert!(
            std::env::var("SVGIR_REQUIRE_DATA").as_deref() != Ok("1"),
            "SVGIR_REQUIRE_DATA=1 but Chromium or tools/browser/node_modules is missing"
        );
        eprintln!("SKIPPED (page screenshot): no Chromium or tools/browser/node_modules (cd tools/browser && npm ci)");
    }
    ok
}

#[test]
fn view_writes_a_page_that_matches_its_oracle_on_a_quick_run() {
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let dir = std::env::temp_dir().join(format!("svgir_view_quick_{}", std::process::id()));
    let run = dir.join("run");
    let status = Command::new(env!("CARGO_BIN_EXE_svgir"))
        .args(["--threads", "2", "demo", "--quick", "--out"])
        .arg(&run)
        .status()
        .expect("runs");
    assert!(status.success(), "svgir demo --quick failed");
    let (page, oracle) = (dir.join("viewer.html"), dir.join("oracle.png"));
    let (ok, err) = svgir(&[
        "view",
        run.to_str().unwrap(),
        "--directions",
        "16",
        "--out",
        page.to_str().unwrap(),
        "--oracle",
        oracle.to_str().unwrap(),
        "--camera",
        "30,25,4",
        "--light",
        "night",
        "--rotate",
        "40",
        "--width",
        "128",
        "--height",
        "96",
    ]);
    assert!(ok, "{err}");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains("\"name\":\"night\"") && html.contains("\"name\":\"learned\""), "the page ships the lights");
    if !browser_ready(&repo) {
        return;
    }
    let shot = dir.join("page.png");
    let out = Command::new("node")
        .arg(repo.join("tools/browser/viewer_check.mjs"))
        .arg(&page)
        .args([
            "--hash",
            "yaw=30&pitch=25&dist=4&light=night&rot=40&ui=0&w=128&h=96",
            "--width",
            "128",
            "--height",
            "96",
        ])
        .arg("--out")
        .arg(&shot)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("\"ready\":true"), "{text} {}", String::from_utf8_lossy(&out.stderr));
    let (a, b) = (svgir_io::read_image(&shot).unwrap(), svgir_io::read_image(&oracle).unwrap());
    let px = |img: &svgir_core::Image, p: usize, c: usize| img.data[p * img.channels as usize + c];
    let mut se = 0.0f64;
    for p in 0..(128 * 96) {
        for c in 0..3 {
            se += ((px(&a, p, c) - px(&b, p, c)) as f64 * 255.0).powi(2);
        }
    }
    let lit = (0..128 * 96).filter(|&p| px(&b, p, 1) > 0.05).count();
    assert!(lit > 300, "the oracle frame shows the object ({lit} pixels)");
    let psnr = 10.0 * (255.0f64.powi(2) / (se / (128.0 * 96.0 * 3.0)).max(1e-12)).log10();
    eprintln!("quick run: page vs oracle {psnr:.2} dB");
    assert!(psnr >= 35.0, "{psnr:.2} dB");
    let _ = std::fs::remove_dir_all(&dir);
}
