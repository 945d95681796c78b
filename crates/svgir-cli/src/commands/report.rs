//! `svgir report RUN`: a self-contained HTML page for a run folder (images embedded as base64
//! PNG, curves as inline SVG), so the file can be mailed or opened anywhere.

use anyhow::{Context, Result};
use clap::Args;
use serde_json::Value;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct ReportArgs {
    /// Run folder written by `svgir train` or `svgir demo`.
    pub run: PathBuf,
    /// Output HTML file (default RUN/report.html).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(args: ReportArgs) -> Result<()> {
    let out = args.out.clone().unwrap_or_else(|| args.run.join("report.html"));
    write_report(&args.run, &out)?;
    println!("report: {}", out.display());
    Ok(())
}

pub(crate) fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(T[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

fn img_tag(path: &Path, title: &str) -> String {
    match std::fs::read(path) {
        Ok(b) => format!(
            "<figure><img src=\"data:image/png;base64,{}\" title=\"{title}\"><figcaption>{title}</figcaption></figure>",
            base64(&b)
        ),
        Err(_) => format!("<figure><div class=missing>missing</div><figcaption>{title}</figcaption></figure>"),
    }
}

/// One curve without a legend, in the report's plot size.
fn svg_plot(points: &[(f64, f64)], title: &str, xlabel: &str) -> String {
    let series = [svgir_eval::plot::Series { name: String::new(), points: points.to_vec() }];
    svgir_eval::plot::line_plot(&series, title, xlabel, "", 420.0, 220.0)
}

/// A readable label for a flattened metric key (`relight.per_light.night.psnr` -> `relit under
/// night: PSNR (dB)`); unknown parts are kept as they are.
fn label(key: &str) -> String {
    let parts: Vec<&str> = key.split('.').collect();
    let word = |p: &str| -> String {
        match p {
            "nvs" => "novel views".into(),
            "psnr" => "PSNR (dB)".into(),
            "psnr_matched" => "PSNR colour-matched to each photo (dB)".into(),
            "ssim" => "SSIM".into(),
            "lpips" => "LPIPS".into(),
            "albedo" => "albedo (median-scaled)".into(),
            "albedo_scale" => "albedo scale (R, G, B)".into(),
            "roughness_mse" => "roughness MSE".into(),
            "normal_mae_deg" => "normal MAE (deg)".into(),
            "relight" => "relighting".into(),
            "mean" => "mean".into(),
            "views" => "test views".into(),
            "gaussians" => "Gaussians".into(),
            "trace_seconds" => "tracing (s)".into(),
            "ms_per_iteration" => "time per iteration (ms)".into(),
            "relight_directions" => "relighting directions K".into(),
            "relight_lights" => "relighting directional lights".into(),
            "relight_bounces" => "relighting extra bounces".into(),
            other => other.replace('_', " "),
        }
    };
    match parts.as_slice() {
        ["relight", "per_light", light, m] => format!("relit under {light}: {}", word(m)),
        [head, m] => format!("{}: {}", word(head), word(m)),
        _ => parts.iter().map(|p| word(p)).collect::<Vec<_>>().join(": "),
    }
}

/// Flatten nested metrics into `a.b.c -> value` rows.
fn flatten(prefix: &str, v: &Value, out: &mut Vec<(String, String)>) {
    match v {
        Value::Object(o) => o
            .iter()
            .for_each(|(k, v)| flatten(&if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") }, v, out)),
        Value::Number(n) => out.push((prefix.to_string(), n.as_f64().map_or(n.to_string(), |f| format!("{f:.4}")))),
        Value::Array(a) => out.push((
            prefix.to_string(),
            a.iter().map(|x| x.as_f64().map_or(x.to_string(), |f| format!("{f:.3}"))).collect::<Vec<_>>().join(", "),
        )),
        Value::Null => {}
        Value::String(text) => out.push((prefix.to_string(), text.clone())),
        other => out.push((prefix.to_string(), other.to_string())),
    }
}

/// The rows of a metrics JSON as an HTML table with readable labels.
fn labelled_table(caption: &str, v: &Value) -> String {
    let mut rows = Vec::new();
    flatten("", v, &mut rows);
    if rows.is_empty() {
        return String::new();
    }
    let mut s = format!("<h3>{caption}</h3><div class=scroll><table><tr><th>metric</th><th>value</th></tr>");
    for (k, v) in rows {
        let _ = write!(s, "<tr><td>{}</td><td>{v}</td></tr>", label(&k));
    }
    s + "</table></div>"
}

/// File names in `dir` (empty if it cannot be listed), sorted.
fn file_names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    names.sort();
    names
}

/// Stage 2's pictures, in the order a reader wants them: the relit turntables, then photo vs
/// ours and the recovered materials vs truth per test view, then the learned light vs the true.
fn stage2_pictures(dir: &Path) -> String {
    let mut s = String::from("<h2>Relit object, materials and light</h2>");
    // One turntable row per light (frames are LIGHT_NNN.png).
    let frames = file_names(&dir.join("turntable"));
    let light_of = |f: &String| f.rsplit_once('_').map_or(String::new(), |x| x.0.to_string());
    let mut lights: Vec<String> = frames.iter().map(light_of).collect();
    lights.dedup();
    for light in lights {
        let mine: Vec<&String> = frames.iter().filter(|f| light_of(f) == light).collect();
        let step = mine.len().div_ceil(8).max(1);
        let _ = write!(s, "<h3>Relit under {light} (turntable)</h3><div class=row>");
        for f in mine.iter().step_by(step) {
            s += &img_tag(&dir.join("turntable").join(f), f.trim_end_matches(".png"));
        }
        s += "</div>";
    }
    let test = dir.join("test");
    let all = file_names(&test);
    let relit: Vec<&String> = all.iter().filter(|n| n.contains("_relit_") && !n.contains("_gt_")).collect();
    let views: Vec<&str> = all.iter().filter_map(|n| n.strip_suffix("_pbr.png")).collect();
    if !views.is_empty() {
        s += "<h3>Test views: photo vs ours, recovered materials vs truth, relit vs truth</h3>";
    }
    for stem in views.iter().take(4) {
        s += "<div class=row>";
        let mut pairs: Vec<(String, String, String)> = [
            ("rgb", "pbr", "photo", "ours (learned light)"),
            ("albedo", "albedo", "true albedo", "our albedo"),
            ("roughness", "roughness", "true roughness", "our roughness"),
            ("normal", "normal", "true normal", "our normal"),
        ]
        .iter()
        .map(|(gt, ours, tg, to)| (format!("gt_{gt}|{tg}"), ours.to_string(), to.to_string()))
        .collect();
        let mut lights: Vec<String> = relit
            .iter()
            .filter_map(|r| r.strip_prefix(&format!("{stem}_relit_")))
            .map(|r| r.trim_end_matches(".png").to_string())
            .collect();
        lights.sort();
        for l in lights {
            pairs.push((
                format!("gt_relit_{l}|true, relit under {l}"),
                format!("relit_{l}"),
                format!("ours, relit under {l}"),
            ));
        }
        for (gt, ours, ours_title) in pairs {
            let (gt, gt_title) = gt.split_once('|').unwrap_or((&gt, ""));
            let gt_path = test.join(format!("{stem}_{gt}.png"));
            if gt_path.exists() {
                s += &img_tag(&gt_path, &format!("{stem}: {gt_title}"));
            }
            let ours_path = test.join(format!("{stem}_{ours}.png"));
            if ours_path.exists() {
                s += &img_tag(&ours_path, &format!("{stem}: {ours_title}"));
            }
        }
        s += "</div>";
    }
    let has_truth = dir.join("env_true.png").exists();
    let _ = write!(
        s,
        "<h3>Environment light: {}</h3><div class=row>",
        if has_truth { "learned vs true" } else { "learned" }
    );
    s += &img_tag(&dir.join("env_learned.png"), "learned");
    if has_truth {
        s += &img_tag(&dir.join("env_true.png"), "true (training light)");
    }
    s + "</div>"
}

/// The exported mesh in a real engine beside `svgir relight`, when `svgir export --compare
/// RUN/export/compare` has run: the three images and their PSNR.
fn export_compare(run: &Path) -> String {
    let dir = run.join("export/compare");
    let Some(cmp) =
        std::fs::read_to_string(dir.join("compare.json")).ok().and_then(|t| serde_json::from_str::<Value>(&t).ok())
    else {
        return String::new();
    };
    let num = |k: &str| cmp[k].as_f64().map_or("-".to_string(), |x| format!("{x:.2}"));
    let mut s = format!(
        "<h3>Exported mesh in three.js vs svgir relight ({}, view {})</h3><p>PSNR {} dB over the image, {} dB on the \
object; silhouette IoU {}</p><div class=row>",
        cmp["engine"].as_str().unwrap_or("three.js"),
        cmp["view"].as_str().unwrap_or("?"),
        num("psnr_db"),
        num("psnr_masked_db"),
        num("silhouette_iou"),
    );
    s += &img_tag(&dir.join("relight.png"), "svgir relight");
    s += &img_tag(&dir.join("threejs.png"), "three.js, the exported GLB under the exported .hdr");
    s + "</div>"
}

/// Stage 1's test views: the photo against our render, normals and depth.
fn stage1_pictures(run: &Path) -> String {
    let test_dir = run.join("test");
    let names = file_names(&test_dir);
    let views: Vec<&str> =
        names.iter().filter(|n| !n.contains("_gt_")).filter_map(|n| n.strip_suffix("_rgb.png")).collect();
    if views.is_empty() {
        return String::new();
    }
    let mut html = String::from("<h2>Geometry and radiance field (stage 1): photo vs ours</h2>");
    for stem in views.iter().take(8) {
        html += "<div class=row>";
        for (suffix, title) in [
            ("gt_rgb", "photo"),
            ("rgb", "ours"),
            ("gt_normal", "true normal"),
            ("normal", "our normal"),
            ("depth", "our depth"),
        ] {
            let p = test_dir.join(format!("{stem}_{suffix}.png"));
            if suffix.starts_with("gt") && !p.exists() {
                continue;
            }
            html += &img_tag(&p, &format!("{stem}: {title}"));
        }
        html += "</div>";
    }
    html
}

/// `(x, y)` series of a run's `metrics.jsonl`: `x_key` against `y_key` (nested keys with `.`),
/// over the lines that have both.
fn series(run: &Path, x_key: &str, y_key: &str) -> Vec<(f64, f64)> {
    let get = |v: &Value, key: &str| key.split('.').try_fold(v, |v, k| v.get(k)).and_then(Value::as_f64);
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .map(|text| {
            text.lines()
                .filter_map(|l| serde_json::from_str::<Value>(l).ok())
                .filter_map(|v| Some((get(&v, x_key)?, get(&v, y_key)?)))
                .collect()
        })
        .unwrap_or_default()
}

pub fn write_report(run: &Path, out: &Path) -> Result<()> {
    let read_json = |path: &Path| -> Option<Value> { serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok() };
    let config = read_json(&run.join("config.json"))
        .with_context(|| format!("{}: no config.json (not a run folder?)", run.display()))?;
    let stage2 = run.join("stage2");
    let mut html = String::from(
        "<!doctype html><html><head><meta charset=utf-8><meta name=viewport content=\"width=device-width, initial-scale=1\">\
<title>svgir report</title><style>\
body{font-family:sans-serif;margin:24px;color:#222;max-width:1400px;overflow-wrap:anywhere}table{border-collapse:collapse;margin:8px 0}\
td,th{border:1px solid #ccc;padding:4px 10px;text-align:left}figure{display:inline-block;margin:4px;text-align:center;vertical-align:top}\
img{image-rendering:pixelated;width:192px;max-width:42vw}figcaption{font-size:12px;max-width:192px;overflow-wrap:anywhere}\
.plot{margin:8px;border:1px solid #eee;max-width:100%;height:auto}.scroll{overflow-x:auto}\
pre{overflow-x:auto;background:#f6f6f6;padding:8px}\
.missing{width:192px;max-width:42vw;height:192px;background:#eee}.row{margin-bottom:12px}\
@media (max-width:600px){body{margin:10px}}</style></head><body>",
    );
    let _ = write!(html, "<h1>svgir run: {}</h1>", run.display());
    let _ = write!(html, "<p>data: <code>{}</code></p>", config["data"].as_str().unwrap_or("?"));
    if run.join("viewer.html").exists() {
        html += "<p><a href=\"viewer.html\"><b>Open the interactive relighting viewer</b></a> (turn the light, \
change the map, look at albedo, roughness, normals and visibility)</p>";
    }
    // Pictures first (the relit object, its materials and light; then stage 1), then the
    // metric tables, then the curves, then the configuration.
    html += &stage2_pictures(&stage2);
    html += &export_compare(run);
    html += &stage1_pictures(run);
    html += "<h2>Metrics</h2>";
    if let Some(eval2) = read_json(&stage2.join("eval.json")) {
        html += &labelled_table("Stage 2 (SPEC 8 evaluation on the test views)", &eval2);
    }
    html += &labelled_table("Stage 1 (test views)", &read_json(&run.join("eval.json")).unwrap_or(Value::Null));
    if let Some(timings) = read_json(&run.join("timings.json")) {
        html += &labelled_table("Stage 1: time per iteration (ms)", &timings["ms_per_iteration"]);
    }
    html += "<h2>Curves</h2><div class=row>";
    let minutes = |v: Vec<(f64, f64)>| v.into_iter().map(|(t, p)| (t / 60.0, p)).collect::<Vec<_>>();
    html += &svg_plot(&minutes(series(run, "elapsed_s", "test.psnr")), "stage 1: test PSNR (dB)", "min");
    html += &svg_plot(&series(run, "iteration", "psnr"), "stage 1: training PSNR (dB)", "it");
    html += &svg_plot(&series(run, "iteration", "loss"), "stage 1: training loss", "it");
    html += &svg_plot(&series(&stage2, "iteration", "psnr_pbr"), "stage 2: training PSNR of the PBR image (dB)", "it");
    html += &svg_plot(&series(&stage2, "iteration", "loss"), "stage 2: training loss", "it");
    html += "</div>";
    let _ = write!(html, "<h2>Configuration</h2><h3>Stage 1</h3><pre>{}</pre>", serde_json::to_string_pretty(&config)?);
    if let Some(c2) = read_json(&stage2.join("config.json")) {
        let _ = write!(html, "<h3>Stage 2</h3><pre>{}</pre>", serde_json::to_string_pretty(&c2)?);
    }
    html += "</body></html>";
    svgir_io::error::write_atomic(out, html.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn labels_are_readable() {
        assert_eq!(super::label("relight.per_light.night.psnr"), "relit under night: PSNR (dB)");
        assert_eq!(super::label("nvs.lpips"), "novel views: LPIPS");
        assert_eq!(super::label("normal_mae_deg"), "normal MAE (deg)");
        assert_eq!(super::label("ms_per_iteration.forward"), "time per iteration (ms): forward");
    }

    /// An evaluation without LPIPS weights says so in the report, as in eval.json.
    #[test]
    fn lpips_not_computed_is_shown() {
        let mut rows = Vec::new();
        let v = serde_json::json!({"nvs": {"psnr": 20.0, "lpips": svgir_eval::lpips_weights::NOT_COMPUTED}});
        super::flatten("", &v, &mut rows);
        assert!(rows.contains(&("nvs.lpips".to_string(), "not computed".to_string())), "{rows:?}");
    }

    #[test]
    fn base64_matches_rfc4648_vectors() {
        assert_eq!(super::base64(b""), "");
        assert_eq!(super::base64(b"f"), "Zg==");
        assert_eq!(super::base64(b"fo"), "Zm8=");
        assert_eq!(super::base64(b"foo"), "Zm9v");
        assert_eq!(super::base64(b"foobar"), "Zm9vYmFy");
    }
}
