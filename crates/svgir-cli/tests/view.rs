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
