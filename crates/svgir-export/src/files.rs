//! The only file I/O of the crate: reading a reference mesh (binary or ASCII PLY with a face
//! list) and writing finished exports atomically. A set of files is written all or nothing:
//! each goes to `NAME.tmp` first, then all are renamed; on any failure the temporary files are
//! removed and files already renamed in this call are removed again, so a failed export leaves
//! nothing behind.

use crate::mesh::Mesh;
use crate::ExportError;
use glam::Vec3;
use std::path::{Path, PathBuf};

fn file_err(path: &Path, detail: impl std::fmt::Display) -> ExportError {
    ExportError::File { path: path.display().to_string(), detail: detail.to_string() }
}

/// Writes every `(path, bytes)` or none of them (module docs). The parent folders must exist.
pub fn write_all_or_nothing(files: &[(PathBuf, Vec<u8>)]) -> Result<(), ExportError> {
    let tmp = |p: &Path| {
        let mut s = p.as_os_str().to_owned();
        s.push(".tmp");
        PathBuf::from(s)
    };
    for (path, _) in files {
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        if !dir.is_dir() {
            return Err(file_err(path, format!("folder {} does not exist", dir.display())));
        }
        if path.is_dir() {
            return Err(file_err(path, "is a folder"));
        }
    }
    let mut written: Vec<PathBuf> = Vec::new();
    let cleanup = |written: &[PathBuf]| {
        for p in written {
            let _ = std::fs::remove_file(tmp(p));
        }
    };
    for (path, bytes) in files {
        written.push(path.clone());
        if let Err(e) = std::fs::write(tmp(path), bytes) {
            cleanup(&written);
            return Err(file_err(path, format!("cannot write: {e}")));
        }
    }
    for (i, (path, _)) in files.iter().enumerate() {
        if let Err(e) = std::fs::rename(tmp(path), path) {
            cleanup(&written[i..]);
            for (done, _) in &files[..i] {
                let _ = std::fs::remove_file(done);
            }
            return Err(file_err(path, format!("cannot rename into place: {e}")));
        }
    }
    Ok(())
}

/// Reads a triangle mesh from a PLY file (vertex x, y, z; faces as a list of indices; polygons
/// are fanned into triangles).
pub fn read_mesh_ply(path: &Path) -> Result<Mesh, ExportError> {
    let bytes = std::fs::read(path).map_err(|e| file_err(path, e))?;
    decode_mesh_ply(&bytes).map_err(|e| file_err(path, e))
}

/// The mesh of a PLY file's bytes ([`read_mesh_ply`]).
pub fn decode_mesh_ply(bytes: &[u8]) -> Result<Mesh, String> {
    let end = bytes.windows(11).position(|w| w == b"end_header\n").ok_or("no end_header")? + 11;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "header is not text")?;
    let mut lines = header.lines();
    if lines.next() != Some("ply") {
        return Err("not a PLY file".into());
    }
    // Elements: (name, count, properties as (type, list count type or None, name)).
    type Property = (String, Option<String>, String);
    let mut elements: Vec<(String, usize, Vec<Property>)> = Vec::new();
    let mut format = "";
    for l in lines {
        let w: Vec<&str> = l.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => format = f,
            ["element", name, n] => elements.push((name.to_string(), n.parse().map_err(|_| "bad count")?, Vec::new())),
            ["property", "list", ct, it, name] => elements.last_mut().ok_or("property before element")?.2.push((
                it.to_string(),
                Some(ct.to_string()),
                name.to_string(),
            )),
            ["property", t, name] => {
                elements.last_mut().ok_or("property before element")?.2.push((t.to_string(), None, name.to_string()))
            }
            _ => {}
        }
    }
    let size = |t: &str| -> Result<usize, String> {
        Ok(match t {
            "char" | "uchar" | "int8" | "uint8" => 1,
            "short" | "ushort" | "int16" | "uint16" => 2,
            "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
            "double" | "float64" => 8,
            _ => return Err(format!("unknown PLY type {t}")),
        })
    };
    let ascii = format == "ascii";
    if !(ascii || format == "binary_little_endian") {
        return Err(format!("unsupported PLY format '{format}'"));
    }
    let mut tokens = if ascii {
        std::str::from_utf8(&bytes[end..]).map_err(|_| "body is not text")?.split_whitespace().collect()
    } else {
        Vec::new()
    };
    tokens.reverse();
    let mut pos = end;
    let mut read = |t: &str| -> Result<f64, String> {
        if ascii {
            return tokens.pop().ok_or("file ends early")?.parse::<f64>().map_err(|_| "bad number".into());
        }
        let n = size(t)?;
        let b = bytes.get(pos..pos + n).ok_or("file ends early")?;
        pos += n;
        Ok(match t {
            "char" | "int8" => b[0] as i8 as f64,
            "uchar" | "uint8" => b[0] as f64,
            "short" | "int16" => i16::from_le_bytes([b[0], b[1]]) as f64,
            "ushort" | "uint16" => u16::from_le_bytes([b[0], b[1]]) as f64,
            "int" | "int32" => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            "uint" | "uint32" => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            "float" | "float32" => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            _ => f64::from_le_bytes(b.try_into().map_err(|_| "bad double")?),
        })
    };
    let mut mesh = Mesh::default();
    for (name, count, props) in &elements {
        for _ in 0..*count {
            let mut xyz = [0.0f32; 3];
            for (t, list, pname) in props {
                if let Some(ct) = list {
                    let k = read(ct)? as usize;
                    let idx: Vec<u32> = (0..k).map(|_| read(t).map(|v| v as u32)).collect::<Result<_, _>>()?;
                    if name == "face" {
                        for j in 1..k.saturating_sub(1) {
                            mesh.triangles.push([idx[0], idx[j], idx[j + 1]]);
                        }
                    }
                } else {
                    let v = read(t)?;
                    match pname.as_str() {
                        "x" => xyz[0] = v as f32,
                        "y" => xyz[1] = v as f32,
                        "z" => xyz[2] = v as f32,
                        _ => {}
                    }
                }
            }
            if name == "vertex" {
                mesh.positions.push(Vec3::from_array(xyz));
            }
        }
    }
    mesh.validate().map_err(|e| e.to_string())?;
    Ok(mesh)
}

/// Writes a triangle mesh as binary PLY bytes (vertex x y z float, face list uchar int).
pub fn encode_mesh_ply(mesh: &Mesh) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment svgir export\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.len()
    )
    .into_bytes();
    for p in &mesh.positions {
        for v in p.to_array() {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        out.push(3);
        for i in t {
            out.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mesh_ply_round_trips_and_fans_quads() {
        let m = Mesh { positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z], triangles: vec![[0, 1, 2], [0, 2, 3]] };
        assert_eq!(decode_mesh_ply(&encode_mesh_ply(&m)).unwrap(), m);
        let ascii = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
        let q = decode_mesh_ply(ascii.as_bytes()).unwrap();
        assert_eq!(q.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert!(decode_mesh_ply(b"ply\nformat ascii 1.0\nend_header\n").is_err());
    }

    #[test]
    fn failed_set_leaves_nothing() {
        let dir = std::env::temp_dir().join(format!("svgir-export-files-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("a.glb");
        let bad = dir.join("missing_folder").join("b.hdr");
        let err = write_all_or_nothing(&[(good.clone(), vec![1, 2]), (bad, vec![3])]).unwrap_err();
        assert!(err.to_string().contains("does not exist"), "{err}");
        assert!(!good.exists());
        write_all_or_nothing(&[(good.clone(), vec![1, 2])]).unwrap();
        assert_eq!(std::fs::read(&good).unwrap(), vec![1, 2]);
        assert!(std::fs::read_dir(&dir).unwrap().count() == 1, "no temporary files left");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
