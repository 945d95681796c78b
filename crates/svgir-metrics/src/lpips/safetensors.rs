//! A minimal safetensors reader over a byte slice (the metrics crate does no I/O): 8-byte
//! little-endian header length, a JSON header `{name: {dtype, shape, data_offsets}}`, then the raw
//! little-endian tensor data; offsets are relative to the end of the header. Only F32 is decoded.

use std::collections::HashMap;

use crate::error::{MetricsError, Result};

/// One decoded tensor: row-major `data` of the given `shape`.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    /// Dimensions, outermost first.
    pub shape: Vec<usize>,
    /// Values in row-major order, decoded from little-endian F32.
    pub data: Vec<f32>,
}

fn err(msg: impl Into<String>) -> MetricsError {
    MetricsError::Safetensors(msg.into())
}

/// Every tensor of the file, by name (`__metadata__` is skipped).
pub fn parse(bytes: &[u8]) -> Result<HashMap<String, Tensor>> {
    let len_bytes: [u8; 8] =
        bytes.get(..8).and_then(|s| s.try_into().ok()).ok_or_else(|| err("shorter than 8 bytes"))?;
    let header_len = usize::try_from(u64::from_le_bytes(len_bytes)).map_err(|_| err("header length overflows"))?;
    let data_start = 8usize.checked_add(header_len).ok_or_else(|| err("header length overflows"))?;
    let header = bytes.get(8..data_start).ok_or_else(|| err("header runs past the end"))?;
    let data = &bytes[data_start..];
    let json: serde_json::Value = serde_json::from_slice(header).map_err(|e| err(format!("header JSON: {e}")))?;
    let obj = json.as_object().ok_or_else(|| err("header is not a JSON object"))?;
    let mut out = HashMap::with_capacity(obj.len());
    for (name, info) in obj {
        if name == "__metadata__" {
            continue;
        }
        let dtype = info.get("dtype").and_then(|d| d.as_str()).ok_or_else(|| err(format!("{name}: no dtype")))?;
        if dtype != "F32" {
            return Err(err(format!("{name}: dtype {dtype} unsupported (only F32)")));
        }
        let shape: Vec<usize> = info
            .get("shape")
            .and_then(|s| s.as_array())
            .ok_or_else(|| err(format!("{name}: no shape")))?
            .iter()
            .map(|d| d.as_u64().map(|d| d as usize).ok_or_else(|| err(format!("{name}: bad shape entry"))))
            .collect::<Result<_>>()?;
        let offsets = info
            .get("data_offsets")
            .and_then(|s| s.as_array())
            .filter(|a| a.len() == 2)
            .ok_or_else(|| err(format!("{name}: no data_offsets")))?;
        let (begin, end) = match (offsets[0].as_u64(), offsets[1].as_u64()) {
            (Some(b), Some(e)) if b <= e => (b as usize, e as usize),
            _ => return Err(err(format!("{name}: bad data_offsets"))),
        };
        let raw = data.get(begin..end).ok_or_else(|| err(format!("{name}: data runs past the end")))?;
        let count: usize = shape.iter().product();
        if raw.len() != count * 4 {
            return Err(err(format!("{name}: {} bytes for shape {shape:?}", raw.len())));
        }
        let values = raw.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        out.insert(name.clone(), Tensor { shape, data: values });
    }
    Ok(out)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Serialise tensors the way the format specifies (used to build test weight files).
    pub(crate) fn write(tensors: &[(&str, Vec<usize>, Vec<f32>)]) -> Vec<u8> {
        let mut header = serde_json::Map::new();
        let mut data = Vec::new();
        for (name, shape, values) in tensors {
            let begin = data.len();
            for v in values {
                data.extend_from_slice(&v.to_le_bytes());
            }
            header.insert(
                name.to_string(),
                serde_json::json!({"dtype": "F32", "shape": shape, "data_offsets": [begin, data.len()]}),
            );
        }
        header.insert("__metadata__".into(), serde_json::json!({"k": "v"}));
        let h = serde_json::to_vec(&serde_json::Value::Object(header)).unwrap();
        let mut out = (h.len() as u64).to_le_bytes().to_vec();
        out.extend_from_slice(&h);
        out.extend_from_slice(&data);
        out
    }

    #[test]
    fn round_trip_and_errors() {
        let bytes = write(&[("a", vec![2, 2], vec![1.0, -2.0, 3.5, 0.0]), ("b", vec![1], vec![7.0])]);
        let t = parse(&bytes).unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t["a"].shape, vec![2, 2]);
        assert_eq!(t["a"].data, vec![1.0, -2.0, 3.5, 0.0]);
        assert_eq!(t["b"].data, vec![7.0]);
        assert!(parse(&bytes[..5]).is_err());
        assert!(parse(&bytes[..bytes.len() - 2]).is_err());
        let mut bad = bytes.clone();
        bad[0] = 0xff;
        assert!(parse(&bad).is_err());
    }
}
