//! glTF 2.0 binary (GLB) assembly. The JSON is written with `serde_json` and, for the mesh,
//! parsed into `gltf-json`'s typed [`gltf_json::Root`] and checked with its validator before it
//! is serialised, so a field of the wrong shape or an index out of range is an error here
//! rather than in a viewer. (The splat file's `KHR_gaussian_splatting:*` attribute semantics
//! are not in `gltf-json`'s vocabulary; its JSON is written directly, see [`crate::splats`].)
//!
//! Our world is +Z up; glTF's is +Y up. Vertex data stays in world coordinates and the root
//! node carries the rotation (-90 degrees about X), as Blender's exporter does, so importers
//! that convert back (Blender) recover our coordinates exactly.

use crate::atlas::AtlasMesh;
use crate::bake::BakedTextures;
use crate::ExportError;
use serde_json::{json, Value};

/// Root-node rotation taking +Z up to glTF's +Y up (x, y, z, w).
pub const Z_UP_TO_Y_UP: [f32; 4] = [-std::f32::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f32::consts::FRAC_1_SQRT_2];

/// glTF component types and buffer-view targets.
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// Binary buffer, buffer views, accessors and images of one GLB under construction.
#[derive(Default)]
pub struct GlbBuilder {
    /// The BIN chunk.
    pub bin: Vec<u8>,
    /// `bufferViews`.
    pub views: Vec<Value>,
    /// `accessors`.
    pub accessors: Vec<Value>,
    /// `images`.
    pub images: Vec<Value>,
}

impl GlbBuilder {
    /// Appends `bytes` 4-byte aligned as a buffer view; returns its index.
    pub fn push_view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v = json!({ "buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }

    /// A float accessor of `type_` ("SCALAR", "VEC2", ...) with `comps` values per element;
    /// `min`/`max` are written when `bounds` (glTF requires them for POSITION).
    pub fn push_floats(&mut self, data: &[f32], comps: usize, type_: &str, bounds: bool) -> Result<usize, ExportError> {
        if data.is_empty() || !data.len().is_multiple_of(comps) || data.iter().any(|v| !v.is_finite()) {
            return Err(ExportError::Invalid(format!(
                "{type_} data: {} values, empty, ragged or not finite",
                data.len()
            )));
        }
        let view = self.push_view(bytemuck::cast_slice(data), Some(ARRAY_BUFFER));
        let mut a = json!({ "bufferView": view, "componentType": FLOAT, "count": data.len() / comps, "type": type_ });
        if bounds {
            let mut lo = vec![f32::INFINITY; comps];
            let mut hi = vec![f32::NEG_INFINITY; comps];
            for c in data.chunks_exact(comps) {
                for k in 0..comps {
                    lo[k] = lo[k].min(c[k]);
                    hi[k] = hi[k].max(c[k]);
                }
            }
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        self.accessors.push(a);
        Ok(self.accessors.len() - 1)
    }

    /// A u32 index accessor.
    pub fn push_indices(&mut self, idx: &[u32]) -> usize {
        let view = self.push_view(bytemuck::cast_slice(idx), Some(ELEMENT_ARRAY_BUFFER));
        self.accessors
            .push(json!({ "bufferView": view, "componentType": UNSIGNED_INT, "count": idx.len(), "type": "SCALAR" }));
        self.accessors.len() - 1
    }

    /// A PNG image stored in the buffer.
    pub fn push_png(&mut self, png: &[u8]) -> usize {
        let view = self.push_view(png, None);
        self.images.push(json!({ "bufferView": view, "mimeType": "image/png" }));
        self.images.len() - 1
    }

    /// The `buffers` entry.
    pub fn buffer(&self) -> Value {
        json!([{ "byteLength": self.bin.len() }])
    }
}

/// GLB container: 12-byte header, JSON chunk (space-padded), BIN chunk (zero-padded).
pub fn glb_bytes(json: &Value, bin: &[u8]) -> Result<Vec<u8>, ExportError> {
    let mut text =
        serde_json::to_vec(json).map_err(|e| ExportError::Encode { what: "glTF JSON", detail: e.to_string() })?;
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let mut binp = bin.to_vec();
    while !binp.len().is_multiple_of(4) {
        binp.push(0);
    }
    let total = 12 + 8 + text.len() + if binp.is_empty() { 0 } else { 8 + binp.len() };
    let total = u32::try_from(total).map_err(|_| ExportError::Encode { what: "GLB", detail: "over 4 GiB".into() })?;
    let mut out = Vec::with_capacity(total as usize);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total.to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    if !binp.is_empty() {
        out.extend_from_slice(&(binp.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&binp);
    }
    Ok(out)
}

/// Splits a GLB into its JSON and BIN chunk (checks the header and chunk lengths).
pub fn parse_glb(bytes: &[u8]) -> Result<(Value, Vec<u8>), ExportError> {
    let bad = |d: &str| ExportError::Invalid(format!("not a GLB: {d}"));
    let u32_at = |o: usize| bytes.get(o..o + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    if bytes.get(0..4) != Some(b"glTF") || u32_at(4) != Some(2) {
        return Err(bad("magic or version"));
    }
    if u32_at(8) != Some(bytes.len() as u32) {
        return Err(bad("length field"));
    }
    let jl = u32_at(12).ok_or_else(|| bad("truncated"))? as usize;
    if bytes.get(16..20) != Some(b"JSON") || 20 + jl > bytes.len() {
        return Err(bad("JSON chunk"));
    }
    let json: Value = serde_json::from_slice(&bytes[20..20 + jl]).map_err(|e| bad(&e.to_string()))?;
    let mut bin = Vec::new();
    let o = 20 + jl;
    if o < bytes.len() {
        let bl = u32_at(o).ok_or_else(|| bad("truncated"))? as usize;
        if bytes.get(o + 4..o + 8) != Some(b"BIN\0") || o + 8 + bl > bytes.len() {
            return Err(bad("BIN chunk"));
        }
        bin = bytes[o + 8..o + 8 + bl].to_vec();
    }
    Ok((json, bin))
}

/// Parses `json` as a typed glTF root and runs `gltf-json`'s validation (schema shapes and
/// index ranges); returns the typed root's serialisation.
pub fn checked(json: &Value) -> Result<Value, ExportError> {
    use gltf_json::validation::Validate;
    let root: gltf_json::Root = serde_json::from_value(json.clone())
        .map_err(|e| ExportError::Encode { what: "glTF JSON", detail: e.to_string() })?;
    let mut errors = Vec::new();
    root.validate(&root, gltf_json::Path::new, &mut |path, err| errors.push(format!("{}: {err}", path())));
    if !errors.is_empty() {
        return Err(ExportError::Encode { what: "glTF JSON", detail: errors.join("; ") });
    }
    serde_json::to_value(&root).map_err(|e| ExportError::Encode { what: "glTF JSON", detail: e.to_string() })
}

/// The textured mesh as GLB bytes: one primitive with POSITION, NORMAL, TANGENT, TEXCOORD_0,
/// u32 indices, and a metallic-roughness material with the three baked PNGs (sampled linearly
/// without mipmaps, clamped: the atlas's cells touch).
pub fn mesh_glb(atlas: &AtlasMesh, tex: &BakedTextures, name: &str) -> Result<Vec<u8>, ExportError> {
    let png = |img: &svgir_core::Image, what: &'static str| {
        svgir_io::image_io::encode_png(img, 8).map_err(|e| ExportError::Encode { what, detail: e.to_string() })
    };
    let mut b = GlbBuilder::default();
    let flat3 = |v: &[glam::Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
    let pos = b.push_floats(&flat3(&atlas.positions), 3, "VEC3", true)?;
    let nrm = b.push_floats(&flat3(&atlas.normals), 3, "VEC3", false)?;
    let tan_data: Vec<f32> = atlas.tangents.iter().flat_map(|t| t.to_array()).collect();
    let tan = b.push_floats(&tan_data, 4, "VEC4", false)?;
    let uv_data: Vec<f32> = atlas.uvs.iter().flat_map(|t| t.to_array()).collect();
    let uv = b.push_floats(&uv_data, 2, "VEC2", false)?;
    let idx: Vec<u32> = (0..atlas.positions.len() as u32).collect();
    let ind = b.push_indices(&idx);
    let img_base = b.push_png(&png(&tex.base_color, "base colour PNG")?);
    let img_mr = b.push_png(&png(&tex.metallic_roughness, "metallic-roughness PNG")?);
    let img_n = b.push_png(&png(&tex.normal, "normal-map PNG")?);
    let json = json!({
        "asset": { "version": "2.0", "generator": "svgir export" },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "name": name, "mesh": 0, "rotation": Z_UP_TO_Y_UP }],
        "meshes": [{ "name": name, "primitives": [{
            "attributes": { "POSITION": pos, "NORMAL": nrm, "TANGENT": tan, "TEXCOORD_0": uv },
            "indices": ind, "material": 0, "mode": 4 }] }],
        "materials": [{
            "name": format!("{name} (svgir stage 2)"),
            "pbrMetallicRoughness": {
                "baseColorTexture": { "index": 0 },
                "metallicRoughnessTexture": { "index": 1 },
                "metallicFactor": 1.0,
                "roughnessFactor": 1.0
            },
            "normalTexture": { "index": 2 }
        }],
        "samplers": [{ "magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071 }],
        "textures": [
            { "sampler": 0, "source": img_base },
            { "sampler": 0, "source": img_mr },
            { "sampler": 0, "source": img_n }
        ],
        "images": b.images,
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": b.buffer(),
    });
    let json = checked(&json)?;
    glb_bytes(&json, &b.bin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glb_container_round_trips() {
        let json = json!({ "asset": { "version": "2.0" }, "x": [1, 2, 3] });
        let bytes = glb_bytes(&json, &[1, 2, 3, 4, 5]).unwrap();
        assert_eq!(bytes.len() % 4, 0);
        let (j, bin) = parse_glb(&bytes).unwrap();
        assert_eq!(j, json);
        assert_eq!(&bin[..5], &[1, 2, 3, 4, 5]);
        assert!(parse_glb(&bytes[..bytes.len() - 4]).is_err(), "truncated file is rejected");
    }

    #[test]
    fn mesh_glb_round_trips_through_gltf_json() {
        use crate::mesh::Mesh;
        use glam::Vec3;
        let m = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        };
        let atlas = crate::atlas::build_atlas(&m, 64, 1.0).unwrap();
        let img = |v: f32| svgir_core::Image::filled(64, 64, &[v, 0.5, 0.25]);
        let tex = BakedTextures { base_color: img(0.8), metallic_roughness: img(1.0), normal: img(0.5), covered: 1.0 };
        let bytes = mesh_glb(&atlas, &tex, "tetra").unwrap();
        let (json, bin) = parse_glb(&bytes).unwrap();
        let root: gltf_json::Root = serde_json::from_value(json.clone()).unwrap();
        assert_eq!(root.meshes.len(), 1);
        assert_eq!(root.images.len(), 3);
        let prim = &json["meshes"][0]["primitives"][0];
        let count =
            |a: &str| json["accessors"][prim["attributes"][a].as_u64().unwrap() as usize]["count"].as_u64().unwrap();
        for a in ["POSITION", "NORMAL", "TANGENT", "TEXCOORD_0"] {
            assert_eq!(count(a), 12, "{a}");
        }
        // The PNGs decode back to the baked values.
        let view = &json["bufferViews"][json["images"][0]["bufferView"].as_u64().unwrap() as usize];
        let (o, l) = (view["byteOffset"].as_u64().unwrap() as usize, view["byteLength"].as_u64().unwrap() as usize);
        let png = svgir_io::image_io::decode_image(&bin[o..o + l], svgir_io::image_io::ImageKind::Png).unwrap();
        assert!((png.pixel(3, 3)[0] - 0.8).abs() < 1.0 / 255.0 + 1e-6);
        // Positions read back from the buffer equal the atlas corners.
        let acc = &json["accessors"][prim["attributes"]["POSITION"].as_u64().unwrap() as usize];
        let v = &json["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let o = v["byteOffset"].as_u64().unwrap() as usize;
        let p: Vec<f32> = bin[o..o + 36].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
        assert_eq!(
            p,
            [atlas.positions[0], atlas.positions[1], atlas.positions[2]]
                .iter()
                .flat_map(|v| v.to_array())
                .collect::<Vec<_>>()
        );
    }

    #[test]
    fn typed_check_rejects_a_dangling_index() {
        let ok = json!({ "asset": { "version": "2.0" }, "scenes": [{ "nodes": [] }] });
        assert!(checked(&ok).is_ok());
        let bad = json!({ "asset": { "version": "2.0" }, "scenes": [{ "nodes": [3] }] });
        assert!(checked(&bad).is_err());
    }
}
