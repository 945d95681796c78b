//! SSIM against another implementation: `tools/ssim_reference.py`, the two evaluations' SSIM
//! (3DGS's and TensoIR's) written from their own Python definitions in pure Python (2-D window,
//! no separable passes, nothing shared with this crate), on the same two images.

use svgir_metrics::{ssim, Shape, SsimVariant};

const W: usize = 23;
const H: usize = 17;

/// The script's images: k/255 from a 31-bit LCG, and the same plus LCG noise, clamped.
fn images() -> (Vec<f64>, Vec<f64>) {
    let lcg = |seed: u64| {
        let mut s = seed;
        move || {
            s = (s * 1_103_515_245 + 12_345) % (1 << 31);
            (s >> 16) % 256
        }
    };
    let mut g = lcg(7);
    let a: Vec<f64> = (0..W * H * 3).map(|_| g() as f64 / 255.0).collect();
    let mut n = lcg(11);
    let b = a.iter().map(|&x| (x + (n() as f64 - 128.0) / 256.0).clamp(0.0, 1.0)).collect();
    (a, b)
}

#[test]
fn ssim_matches_the_evaluations_python_definitions() {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tools/ssim_reference.py");
    let out = std::process::Command::new("python3").arg(script).output().expect("python3 runs");
    assert!(out.status.success(), "{script}: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    let value = |name: &str| -> f64 {
        let line = text.lines().find(|l| l.starts_with(name)).unwrap_or_else(|| panic!("no {name} in {text}"));
        line[name.len()..].trim().parse().expect("a number")
    };
    let (a, b) = images();
    let shape = Shape::new(W, H, 3);
    for (name, variant) in [("gs", SsimVariant::GaussianSplatting), ("tensoir", SsimVariant::TensoIR)] {
        let want = value(name);
        let got = ssim(&a, &b, shape, variant).unwrap();
        let (a32, b32): (Vec<f32>, Vec<f32>) =
            (a.iter().map(|&x| x as f32).collect(), b.iter().map(|&x| x as f32).collect());
        let got32 = ssim(&a32, &b32, shape, variant).unwrap() as f64;
        eprintln!("{name}: reference {want:.15}, f64 {got:.15}, f32 {got32:.9}");
        assert!(want < 0.9 && want > 0.1, "{name}: a test pair should be far from identical ({want})");
        // Both in f64: only the order of the sums differs.
        assert!((got - want).abs() < 1e-12, "{name}: {got} vs {want}");
        assert!((got32 - want).abs() < 1e-6, "{name} (f32): {got32} vs {want}");
    }
}
