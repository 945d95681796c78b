//! The self-contained HTML page: `web/viewer.html` with `web/light.js`, `web/hdr.js` and
//! `web/viewer.js` inlined, a JSON header
//! and the model and light maps as one base64 block (geometry and maps little-endian f32,
//! materials and transfer IEEE f16; the page decodes all into float32 textures). Base64 is written by hand here (a dozen lines) rather than adding a
//! dependency for it.

use crate::model::{ViewModel, GEOM_FLOATS, MAT_FLOATS, VERTICES};
use crate::oracle::Orbit;
use svgir_core::EnvMap;
use svgir_trace::pack::f16_from_f32;

const HTML: &str = include_str!("../web/viewer.html");
/// The page's script: the light's maths, the `.hdr` reader, then the viewer that uses both.
const SCRIPTS: [&str; 3] =
    [include_str!("../web/light.js"), include_str!("../web/hdr.js"), include_str!("../web/viewer.js")];

/// A light shipped inside the page: a map at the model's light resolution and its strength.
pub struct PageLight {
    /// Name shown in the light menu.
    pub name: String,
    /// The map (SPEC 4 grid), unscaled.
    pub env: EnvMap,
    /// Default strength (radiance = strength x map).
    pub strength: f32,
}

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let v = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(v >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// The page for `model` with `lights` (the first is shown first) and an initial camera.
pub fn page(model: &ViewModel, lights: &[PageLight], camera: &Orbit, title: &str) -> String {
    // Little-endian blob: f32 geometry and light maps first (4-byte aligned), then f16
    // materials and transfer.
    let mut bytes: Vec<u8> = Vec::with_capacity(4 * model.geom.len() + 2 * (model.mats.len() + model.transfer.len()));
    bytes.extend(model.geom.iter().flat_map(|f| f.to_le_bytes()));
    let mut meta_lights = Vec::new();
    for l in lights {
        meta_lights.push(serde_json::json!({
            "name": l.name, "strength": l.strength, "width": l.env.width, "height": l.env.height,
            "offset": bytes.len(),
        }));
        bytes.extend(l.env.data.iter().flatten().flat_map(|f| f.to_le_bytes()));
    }
    let mats_at = bytes.len();
    bytes.extend(model.mats.iter().flat_map(|&f| f16_from_f32(f).to_le_bytes()));
    let transfer_at = bytes.len();
    bytes.extend(model.transfer.iter().flat_map(|&f| f16_from_f32(f).to_le_bytes()));
    let meta = serde_json::json!({
        "title": title,
        "n": model.n,
        "degree": model.degree,
        "coeffs": model.coeffs(),
        "channels": model.channels,
        "twoSided": model.two_sided,
        "layered": model.layered,
        "vertices": VERTICES,
        "geomFloats": GEOM_FLOATS,
        "matFloats": MAT_FLOATS,
        "bytesPerSurfel": model.bytes_per_surfel(),
        "fileBytesPerSurfel": model.file_bytes_per_surfel(),
        "offsets": { "geom": 0, "mats": mats_at, "transfer": transfer_at },
        "lights": meta_lights,
        "camera": {
            "target": camera.target, "yaw": camera.yaw, "pitch": camera.pitch,
            "dist": camera.dist, "fovY": camera.fov_y,
        },
    });
    // `</` must not appear inside a script element.
    let meta = meta.to_string().replace("</", "<\\/");
    HTML.replace("__SVGIR_TITLE__", &html_escape(title))
        .replace("__SVGIR_META__", &meta)
        .replace("__SVGIR_DATA__", &base64(&bytes))
        .replace("__SVGIR_SCRIPT__", &SCRIPTS.join("\n"))
}

/// `s` with `&`, `<` and `>` escaped for HTML text.
pub fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (input, want) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(input.as_bytes()), want);
        }
        assert_eq!(base64(&[0xff, 0xfe, 0x00]), "//4A");
    }
}
