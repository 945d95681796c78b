//! Tables of SPEC 8 results: one markdown row per scene, and a per-metric table for the terminal.

/// The scene table's header (markdown), one [`table_row`] per stage-2 run below it.
pub const TABLE_HEADER: &str = "| scene | NVS PSNR | albedo PSNR | roughness MSE | normal MAE | relight PSNR / SSIM / LPIPS | per light |\n|---|---|---|---|---|---|---|";

/// One markdown row of [`TABLE_HEADER`] from an [`evaluate`](crate::spec8::evaluate) result.
pub fn table_row(scene: &str, e: &serde_json::Value) -> String {
    let num = |v: &serde_json::Value, prec: usize| {
        v.as_f64().map_or_else(|| v.as_str().unwrap_or("-").to_string(), |x| format!("{x:.prec$}"))
    };
    let r = &e["relight"]["mean"];
    let per = e["relight"]["per_light"]
        .as_object()
        .map(|m| m.iter().map(|(k, v)| format!("{k} {}", num(&v["psnr"], 2))).collect::<Vec<_>>().join(", "))
        .unwrap_or_default();
    format!(
        "| {scene} | {} | {} | {} | {} | {} / {} / {} | {per} |",
        num(&e["nvs"]["psnr"], 2),
        num(&e["albedo"]["psnr"], 2),
        num(&e["roughness_mse"], 4),
        num(&e["normal_mae_deg"], 2),
        num(&r["psnr"], 2),
        num(&r["ssim"], 3),
        num(&r["lpips"], 3),
    )
}

/// The per-metric table of one [`evaluate`](crate::spec8::evaluate) result, for the terminal.
pub fn metric_table(e: &serde_json::Value) -> String {
    let num = |v: &serde_json::Value, prec: usize| {
        v.as_f64().map_or_else(|| v.as_str().unwrap_or("-").to_string(), |x| format!("{x:.prec$}"))
    };
    let line = |name: &str, m: &serde_json::Value| {
        format!("{name:<24} {:>8} {:>8} {:>8}\n", num(&m["psnr"], 3), num(&m["ssim"], 4), num(&m["lpips"], 4))
    };
    let mut out = format!("{:<24} {:>8} {:>8} {:>8}\n", "", "PSNR", "SSIM", "LPIPS");
    out += &line("novel views", &e["nvs"]);
    out += &line("albedo (median-scaled)", &e["albedo"]);
    if let Some(per) = e["relight"]["per_light"].as_object() {
        for (name, m) in per {
            out += &line(&format!("relit: {name}"), m);
        }
        out += &line("relit: mean", &e["relight"]["mean"]);
    }
    out += &format!("{:<24} {:>8}\n", "roughness MSE", num(&e["roughness_mse"], 4));
    out += &format!("{:<24} {:>8}\n", "normal MAE (deg)", num(&e["normal_mae_deg"], 2));
    out
}
