//! LPIPS tests: the reference distances of the official example images (EXPECTED.txt, 1e-4), and
//! properties on a tiny synthetic network that needs no data.

use super::*;
use svgir_core::Rng;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/lpips");

fn load_png(name: &str) -> Image {
    let img = image::open(format!("{DATA}/{name}")).expect("decode png").to_rgb8();
    let data = img.as_raw().iter().map(|&v| v as f32 / 255.0).collect();
    Image::from_data(img.width(), img.height(), 3, data)
}

/// Data the test needs is missing (`what` names it). With `SVGIR_REQUIRE_DATA=1` (set by
/// `.ci/run`) the test fails; otherwise it prints `SKIPPED` and the caller returns.
fn missing_data(what: &str) {
    let msg = format!("{what} not found; this test needs ../shared/data");
    if std::env::var("SVGIR_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!("SVGIR_REQUIRE_DATA=1: {msg}");
    }
    eprintln!("SKIPPED: {msg}");
}

/// Numbers after `key` on the line that starts with `prefix` in EXPECTED.txt.
fn expected_numbers(text: &str, prefix: &str) -> Vec<f32> {
    let line = text.lines().find(|l| l.starts_with(prefix)).unwrap_or_else(|| panic!("no line {prefix}"));
    let rest = &line[prefix.len()..];
    rest.split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .filter(|s| s.contains('.'))
        .map(|s| s.parse().unwrap())
        .collect()
}

#[test]
fn reproduces_reference_distances() {
    let Ok(text) = std::fs::read_to_string(format!("{DATA}/EXPECTED.txt")) else {
        missing_data(&format!("LPIPS reference data ({DATA}/EXPECTED.txt)"));
        return;
    };
    let (r, p0, p1) = (load_png("ex_ref.png"), load_png("ex_p0.png"), load_png("ex_p1.png"));
    for (net, tag) in [(Net::Alex, "alex"), (Net::Vgg, "vgg")] {
        let bytes = std::fs::read(format!("{DATA}/lpips_{tag}_v0.1.safetensors")).unwrap();
        let lp = Lpips::from_safetensors(&bytes, net).unwrap();
        let totals = expected_numbers(&text, &format!("{tag:<4}:"));
        assert_eq!(totals.len(), 2, "{totals:?}");
        for (i, p) in [&p0, &p1].into_iter().enumerate() {
            let d = lp.distance(&r, p).unwrap();
            let want = expected_numbers(&text, &format!("per-layer {tag:<4} ex_p{i}:"));
            assert_eq!(want.len(), 5);
            let worst = d.per_layer.iter().zip(&want).map(|(g, w)| (g - w).abs()).fold(0.0f32, f32::max);
            eprintln!("{tag} ex_p{i}: total {:.6} (expected {:.6}), worst layer error {worst:.2e}", d.total, totals[i]);
            assert!((d.total - totals[i]).abs() < 1e-4, "{tag} p{i}: {} vs {}", d.total, totals[i]);
            for (got, want) in d.per_layer.iter().zip(&want) {
                assert!((got - want).abs() < 1e-4, "{tag} p{i} layers {:?} vs {want:?}", d.per_layer);
            }
            // LPIPS is symmetric in its arguments.
            let back = lp.distance(p, &r).unwrap();
            assert!((back.total - d.total).abs() < 1e-5);
        }
    }
}

/// A tiny AlexNet-shaped network (few channels) with random weights, in safetensors form.
fn tiny_alex(rng: &mut Rng) -> Vec<u8> {
    let chans = [3usize, 4, 5, 6, 4, 3];
    let ks = [11usize, 5, 3, 3, 3];
    let mut tensors = Vec::new();
    let mut names = Vec::new();
    for i in 0..5 {
        names.push((format!("features.conv{i}.weight"), format!("features.conv{i}.bias"), format!("lin{i}.weight")));
    }
    for i in 0..5 {
        let (cin, cout, k) = (chans[i], chans[i + 1], ks[i]);
        let w: Vec<f32> = (0..cout * cin * k * k).map(|_| rng.range(-0.3, 0.3)).collect();
        let b: Vec<f32> = (0..cout).map(|_| rng.range(0.1, 0.4)).collect();
        let l: Vec<f32> = (0..cout).map(|_| rng.range(0.0, 1.0)).collect();
        tensors.push((names[i].0.as_str(), vec![cout, cin, k, k], w));
        tensors.push((names[i].1.as_str(), vec![cout], b));
        tensors.push((names[i].2.as_str(), vec![1, cout, 1, 1], l));
    }
    super::safetensors::tests::write(&tensors)
}

#[test]
fn tiny_network_properties() {
    let mut rng = Rng::new(9);
    let bytes = tiny_alex(&mut rng);
    let lp = Lpips::from_safetensors(&bytes, Net::Alex).unwrap();
    assert!(Lpips::from_safetensors(&bytes, Net::Vgg).is_err(), "VGG needs conv5..12");
    let (w, h) = (72, 68);
    let a = Image::from_data(w, h, 3, (0..w * h * 3).map(|_| rng.uniform()).collect());
    let b = Image::from_data(w, h, 3, (0..w * h * 3).map(|_| rng.uniform()).collect());
    let same = lp.distance(&a, &a).unwrap();
    assert!(same.total.abs() < 1e-7, "{same:?}");
    let d = lp.distance(&a, &b).unwrap();
    assert_eq!(d.per_layer.len(), 5);
    assert!(d.per_layer.iter().all(|&v| v > 0.0), "{d:?}");
    assert!((d.per_layer.iter().sum::<f32>() - d.total).abs() < 1e-6);
    let back = lp.distance(&b, &a).unwrap();
    assert!((back.total - d.total).abs() < 1e-6);
    // Errors, not panics, on bad input.
    let small = Image::new(8, 8, 3);
    assert!(lp.distance(&small, &small).is_err());
    assert!(lp.distance(&a, &Image::new(w, h, 4)).is_err());
    assert!(lp.distance(&a, &Image::new(w + 1, h, 3)).is_err());
}

/// The `svgir bench` table; slow (~1 min), so only on request:
/// `cargo test --release -p svgir-metrics --features bench bench_table -- --ignored --nocapture`.
#[cfg(feature = "bench")]
#[test]
#[ignore]
fn bench_table_runs() {
    let (Ok(vgg), Ok(alex)) = (
        std::fs::read(format!("{DATA}/lpips_vgg_v0.1.safetensors")),
        std::fs::read(format!("{DATA}/lpips_alex_v0.1.safetensors")),
    ) else {
        missing_data(&format!("LPIPS weights ({DATA}/lpips_*_v0.1.safetensors)"));
        return;
    };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let table = bench_table(&vgg, &alex, threads).unwrap();
    eprintln!("{table}");
    assert_eq!(table.lines().count(), 2 + super::bench::BENCH_SIZES.len());
}
