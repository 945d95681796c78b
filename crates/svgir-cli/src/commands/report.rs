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

fn base64(bytes: &[u8]) -> String {
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

/// An inline SVG line plot of (x, y) points.
fn svg_plot(points: &[(f64, f64)], title: &str, xlabel: &str) -> String {
    if points.len() < 2 {
        return String::new();
    }
    let (w, h, m) = (420.0, 220.0, 40.0);
    let (x0, x1) = points.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (y0, y1) = points.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    let sx = |x: f64| m + (x - x0) / (x1 - x0).max(1e-12) * (w - 1.5 * m);
    let sy = |y: f64| h - m + -(y - y0) / (y1 - y0).max(1e-12) * (h - 1.6 * m);
    let mut path = String::new();
    for (i, p) in points.iter().enumerate() {
        let _ = write!(path, "{}{:.1},{:.1} ", if i == 0 { "M" } else { "L" }, sx(p.0), sy(p.1));
    }
    format!(
        "<svg width=\"{w}\" height=\"{h}\" class=plot><text x=\"{m}\" y=\"16\">{title}</text>\
<path d=\"{path}\" fill=none stroke=\"#2a6fdb\" stroke-width=1.5 />\
<line x1=\"{m}\" y1=\"{b}\" x2=\"{r}\" y2=\"{b}\" stroke=\"#888\"/><line x1=\"{m}\" y1=\"{t}\" x2=\"{m}\" y2=\"{b}\" stroke=\"#888\"/>\
<text x=\"{m}\" y=\"{lb}\">{x0:.0}</text><text x=\"{r}\" y=\"{lb}\" text-anchor=end>{x1:.0} {xlabel}</text>\
<text x=\"2\" y=\"{t}\">{y1:.3}</text><text x=\"2\" y=\"{b}\">{y0:.3}</text></svg>",
        b = h - m,
        t = 0.6 * m,
        r = w - 0.5 * m,
        lb = h - m + 16.0,
    )
}

fn metrics_table(v: &Value) -> String {
    let mut rows = Vec::new();
    flatten("", v, &mut rows);
    let mut s = String::from("<table><tr><th>metric</th><th>value</th></tr>");
    for (k, v) in rows {
        let _ = write!(s, "<tr><td>{}</td><td>{v}</td></tr>", label(&k));
    }
    s + "</table>"
}

/// A readable label for a flattened metric key (`relight.per_light.night.psnr` -> `relit under
/// night: PSNR (dB)`); unknown parts are kept as they are.
fn label(key: &str) -> String {
    let parts: Vec<&str> = key.split('.').collect();
    let word = |p: &str| -> String {
        match p {
            "nvs" => "novel views".into(),
            "psnr" => "PSNR (dB)".into(),
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
        other => out.push((prefix.to_string(), other.to_string())),
    }
}

fn stage2_section(dir: &Path) -> String {
    let Some(eval) =
        std::fs::read_to_string(dir.join("eval.json")).ok().and_then(|t| serde_json::from_str::<Value>(&t).ok())
    else {
        return String::new();
    };
    let mut table =
        String::from("<h3>Stage 2 metrics (SPEC 8 evaluation)</h3><table><tr><th>metric</th><th>value</th></tr>");
    let mut rows = Vec::new();
    flatten("", &eval, &mut rows);
    for (k, v) in rows {
        let _ = write!(table, "<tr><td>{}</td><td>{v}</td></tr>", label(&k));
    }
    table += "</table>";
    let mut s = String::from("<h2>Relit object, materials and light (stage 2)</h2>");
    let has_truth = dir.join("env_true.png").exists();
    let _ = write!(
        s,
        "<h3>Environment light: {}</h3><div class=row>",
        if has_truth { "learned vs true" } else { "learned" }
    );
    s += &img_tag(&dir.join("env_learned.png"), "learned").replace("width:192px", "");
    if has_truth {
        s += &img_tag(&dir.join("env_true.png"), "true (training light)");
    }
    s += "</div>";
    let mut frames: Vec<PathBuf> = std::fs::read_dir(dir.join("turntable"))
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.path()).collect())
        .unwrap_or_default();
    frames.sort();
    // One turntable row per light (frames are LIGHT_NNN.png).
    let light_of = |f: &PathBuf| {
        f.file_name().unwrap_or_default().to_string_lossy().rsplit_once('_').map_or(String::new(), |x| x.0.to_string())
    };
    let mut lights: Vec<String> = frames.iter().map(light_of).collect();
    lights.dedup();
    for light in lights {
        let mine: Vec<&PathBuf> = frames.iter().filter(|f| light_of(f) == light).collect();
        let step = mine.len().div_ceil(8).max(1);
        let _ = write!(s, "<h3>Relit turntable ({light})</h3><div class=row>");
        for f in mine.iter().step_by(step) {
            s += &img_tag(f, &f.file_name().unwrap_or_default().to_string_lossy());
        }
        s += "</div>";
    }
    s += "<h3>Test views</h3>";
    let test = dir.join("test");
    let mut names: Vec<String> = std::fs::read_dir(&test)
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    names.retain(|n| n.ends_with("_pbr.png"));
    names.sort();
    let mut relit: Vec<String> = std::fs::read_dir(&test)
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    relit.retain(|n| n.contains("_relit_") && !n.contains("_gt_"));
    for n in names.iter().take(4) {
        let stem = n.trim_end_matches("_pbr.png");
        s += "<div class=row>";
        let mut pairs: Vec<(String, String)> = ["rgb", "albedo", "roughness", "normal"]
            .iter()
            .map(|k| (format!("gt_{k}"), if *k == "rgb" { "pbr".to_string() } else { k.to_string() }))
            .collect();
        let mut lights: Vec<String> = relit
            .iter()
            .filter(|r| r.starts_with(&format!("{stem}_relit_")))
            .map(|r| r.trim_start_matches(&format!("{stem}_relit_")).trim_end_matches(".png").to_string())
            .collect();
        lights.sort();
        for l in lights {
            pairs.push((format!("gt_relit_{l}"), format!("relit_{l}")));
        }
        for (gt, ours) in pairs {
            let gt_path = test.join(format!("{stem}_{gt}.png"));
            if gt_path.exists() {
                s += &img_tag(&gt_path, &format!("{stem} {gt}"));
            }
            s += &img_tag(&test.join(format!("{stem}_{ours}.png")), &format!("{stem} ours: {ours}"));
        }
        s += "</div>";
    }
    s + &table
}

pub fn write_report(run: &Path, out: &Path) -> Result<()> {
    let read_json =
        |name: &str| -> Option<Value> { serde_json::from_str(&std::fs::read_to_string(run.join(name)).ok()?).ok() };
    let config =
        read_json("config.json").with_context(|| format!("{}: no config.json (not a run folder?)", run.display()))?;
    let eval = read_json("eval.json").unwrap_or(Value::Null);
    let timings = read_json("timings.json").unwrap_or(Value::Null);
    let mut loss = Vec::new();
    let mut psnr = Vec::new();
    let mut test_psnr = Vec::new();
    if let Ok(text) = std::fs::read_to_string(run.join("metrics.jsonl")) {
        for line in text.lines() {
            let Ok(v) = serde_json::from_str::<Value>(line) else { continue };
            let it = v["iteration"].as_f64().unwrap_or(0.0);
            if let (Some(l), Some(p)) = (v["loss"].as_f64(), v["psnr"].as_f64()) {
                loss.push((it, l));
                psnr.push((it, p));
            }
            if let Some(p) = v["test"]["psnr"].as_f64() {
                test_psnr.push((v["elapsed_s"].as_f64().unwrap_or(0.0) / 60.0, p));
            }
        }
    }
    let mut html = String::from(
        "<!doctype html><html><head><meta charset=utf-8><title>svgir report</title><style>\
body{font-family:sans-serif;margin:24px;color:#222}table{border-collapse:collapse;margin:8px 0}\
td,th{border:1px solid #ccc;padding:4px 10px;text-align:left}figure{display:inline-block;margin:4px;text-align:center}\
img{image-rendering:pixelated;width:192px}figcaption{font-size:12px}.plot{margin:8px;border:1px solid #eee}\
.missing{width:192px;height:192px;background:#eee}.row{margin-bottom:12px}</style></head><body>",
    );
    let _ = write!(html, "<h1>svgir run: {}</h1>", run.display());
    let _ = write!(html, "<p>data: <code>{}</code></p>", config["data"].as_str().unwrap_or("?"));
    // Results first: the relit object, its materials and light (stage 2), then stage 1.
    html += &stage2_section(&run.join("stage2"));
    html += "<h2>Stage 1: test metrics</h2>";
    html += &metrics_table(&eval);
    if !timings.is_null() {
        html += "<h2>Time per iteration (ms)</h2>";
        html += &metrics_table(&timings["ms_per_iteration"]);
    }
    html += "<h2>Training curves</h2>";
    html += &svg_plot(&loss, "training loss", "it");
    html += &svg_plot(&psnr, "training PSNR (dB)", "it");
    html += &svg_plot(&test_psnr, "test PSNR (dB)", "min");
    html += "<h2>Test views: ground truth vs ours</h2>";
    let test_dir = run.join("test");
    let mut names: Vec<String> = std::fs::read_dir(&test_dir)
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    names.retain(|n| n.ends_with("_rgb.png") && !n.contains("_gt_"));
    names.sort();
    for n in names.iter().take(8) {
        let stem = n.trim_end_matches("_rgb.png");
        html += "<div class=row>";
        for (suffix, title) in [
            ("gt_rgb", "ground truth"),
            ("rgb", "ours"),
            ("gt_normal", "true normal"),
            ("normal", "our normal"),
            ("depth", "our depth"),
        ] {
            let p = test_dir.join(format!("{stem}_{suffix}.png"));
            if suffix.starts_with("gt") && !p.exists() {
                continue;
            }
            html += &img_tag(&p, &format!("{stem} {title}"));
        }
        html += "</div>";
    }
    let _ = write!(html, "<h2>Configuration</h2><pre>{}</pre></body></html>", serde_json::to_string_pretty(&config)?);
    let tmp = out.with_extension("html.tmp");
    std::fs::write(&tmp, html).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, out).with_context(|| format!("writing {}", out.display()))?;
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

    #[test]
    fn base64_matches_rfc4648_vectors() {
        assert_eq!(super::base64(b""), "");
        assert_eq!(super::base64(b"f"), "Zg==");
        assert_eq!(super::base64(b"fo"), "Zm8=");
        assert_eq!(super::base64(b"foo"), "Zm9v");
        assert_eq!(super::base64(b"foobar"), "Zm9vYmFy");
    }
}
