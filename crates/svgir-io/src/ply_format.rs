//! A small PLY reader: header parsing and column extraction for one element, from ASCII,
//! binary little-endian or binary big-endian bodies. Scalar properties come back as `f32`
//! columns (f32 exactly, other types converted); list properties are skipped.
//!
//! Every count is checked against the bytes left before anything is allocated, so a corrupt or
//! truncated file gives an error, never a huge allocation or a panic.

use crate::error::ErrorKind;

const FMT: &str = "PLY";

/// Named columns of one element, in file order.
pub type Columns = Vec<(String, Vec<f32>)>;

/// Body encoding of a PLY file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `format ascii 1.0`: whitespace-separated text.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLe,
    /// `format binary_big_endian 1.0`.
    BinaryBe,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scalar {
    /// `char` / `int8`.
    I8,
    /// `uchar` / `uint8`.
    U8,
    /// `short` / `int16`.
    I16,
    /// `ushort` / `uint16`.
    U16,
    /// `int` / `int32`.
    I32,
    /// `uint` / `uint32`.
    U32,
    /// `float` / `float32`.
    F32,
    /// `double` / `float64`.
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    /// Size in bytes of one binary value.
    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// Decodes one binary value (`b.len() == self.size()`).
    fn decode(self, b: &[u8], le: bool) -> f64 {
        macro_rules! num {
            ($t:ty) => {{
                let a = b.try_into().unwrap_or_default();
                (if le { <$t>::from_le_bytes(a) } else { <$t>::from_be_bytes(a) }) as f64
            }};
        }
        match self {
            Self::I8 => b[0] as i8 as f64,
            Self::U8 => b[0] as f64,
            Self::I16 => num!(i16),
            Self::U16 => num!(u16),
            Self::I32 => num!(i32),
            Self::U32 => num!(u32),
            Self::F32 => num!(f32),
            Self::F64 => num!(f64),
        }
    }
}

/// One property (column) of a PLY element.
#[derive(Clone, Debug, PartialEq)]
pub struct Property {
    /// Property name as in the header (e.g. `x`, `f_dc_0`).
    pub name: String,
    /// Value type (of the list items for a list property).
    pub ty: Scalar,
    /// `Some(count type)` for a list property.
    pub list: Option<Scalar>,
}

/// One element of a PLY header (e.g. `vertex`) with its properties.
#[derive(Clone, Debug, PartialEq)]
pub struct Element {
    /// Element name as in the header.
    pub name: String,
    /// Number of rows.
    pub count: usize,
    /// Properties in file order.
    pub props: Vec<Property>,
}

/// A parsed PLY header.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    /// Body encoding.
    pub format: Format,
    /// Elements in file order.
    pub elements: Vec<Element>,
    /// Text of the `comment` lines, in order.
    pub comments: Vec<String>,
    /// Offset of the first body byte.
    pub body_start: usize,
}

fn bad(detail: impl std::fmt::Display) -> ErrorKind {
    ErrorKind::corrupt(FMT, detail)
}

/// Parses the header (everything up to and including `end_header\n`).
pub fn parse_header(bytes: &[u8]) -> Result<Header, ErrorKind> {
    if !bytes.starts_with(b"ply") {
        return Err(if bytes.is_empty() || b"ply".starts_with(bytes) {
            ErrorKind::Truncated(String::new())
        } else {
            bad("does not start with 'ply'")
        });
    }
    let end = find(bytes, b"end_header").ok_or_else(|| ErrorKind::Truncated("no end_header".into()))?;
    let mut body_start = end + b"end_header".len();
    // The header ends with "\n" (or "\r\n").
    match bytes.get(body_start..) {
        Some([b'\r', b'\n', ..]) => body_start += 2,
        Some([b'\n', ..]) => body_start += 1,
        _ => return Err(ErrorKind::Truncated("header ends without a newline".into())),
    }
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| bad("header is not text"))?;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut comments = Vec::new();
    for line in text.lines().skip(1) {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            [] => {}
            ["format", f, _] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::BinaryLe,
                    "binary_big_endian" => Format::BinaryBe,
                    other => return Err(bad(format!("unknown format '{other}'"))),
                })
            }
            ["comment", ..] => comments.push(line.trim_start()["comment".len()..].trim().to_string()),
            ["obj_info", ..] => {}
            ["element", name, count] => {
                let count = count.parse().map_err(|_| bad(format!("bad element count '{count}'")))?;
                elements.push(Element { name: name.to_string(), count, props: Vec::new() });
            }
            ["property", "list", ct, ty, name] => {
                let (ct, ty) = (Scalar::parse(ct), Scalar::parse(ty));
                let (Some(ct), Some(ty)) = (ct, ty) else { return Err(bad(format!("bad list property '{line}'"))) };
                let el = elements.last_mut().ok_or_else(|| bad("property before any element"))?;
                el.props.push(Property { name: name.to_string(), ty, list: Some(ct) });
            }
            ["property", ty, name] => {
                let ty = Scalar::parse(ty).ok_or_else(|| bad(format!("unknown property type '{ty}'")))?;
                let el = elements.last_mut().ok_or_else(|| bad("property before any element"))?;
                el.props.push(Property { name: name.to_string(), ty, list: None });
            }
            _ => return Err(bad(format!("unexpected header line '{}'", line.chars().take(60).collect::<String>()))),
        }
    }
    let format = format.ok_or_else(|| bad("no format line"))?;
    Ok(Header { format, elements, comments, body_start })
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Scalar columns `(name, values)` of element `name`, or `None` if the file has no such element.
pub fn read_element(bytes: &[u8], h: &Header, name: &str) -> Result<Option<Columns>, ErrorKind> {
    let Some(target) = h.elements.iter().position(|e| e.name == name) else { return Ok(None) };
    let body = &bytes[h.body_start..];
    match h.format {
        Format::Ascii => read_ascii(body, h, target).map(Some),
        Format::BinaryLe => read_binary(body, h, target, true).map(Some),
        Format::BinaryBe => read_binary(body, h, target, false).map(Some),
    }
}

fn columns(el: &Element) -> Columns {
    el.props.iter().filter(|p| p.list.is_none()).map(|p| (p.name.clone(), Vec::new())).collect()
}

fn read_binary(body: &[u8], h: &Header, target: usize, le: bool) -> Result<Columns, ErrorKind> {
    let mut pos = 0usize;
    let truncated = |el: &Element| ErrorKind::Truncated(format!("element '{}' ends early", el.name));
    for (ei, el) in h.elements.iter().enumerate() {
        let fixed = el.props.iter().all(|p| p.list.is_none());
        let row: usize = el.props.iter().map(|p| p.ty.size()).sum();
        if ei < target && fixed {
            // Skip a whole fixed-size element at once.
            let n = el.count.checked_mul(row).ok_or_else(|| truncated(el))?;
            pos = pos.checked_add(n).filter(|&e| e <= body.len()).ok_or_else(|| truncated(el))?;
            continue;
        }
        let mut cols = columns(el);
        if ei == target && fixed {
            // Every row needs `row` bytes: check before reserving.
            if el.count.checked_mul(row).is_none_or(|n| n > body.len() - pos) {
                return Err(truncated(el));
            }
            for c in &mut cols {
                c.1.reserve_exact(el.count);
            }
        }
        for _ in 0..el.count {
            let mut ci = 0;
            for p in &el.props {
                if let Some(ct) = p.list {
                    let b = body.get(pos..pos + ct.size()).ok_or_else(|| truncated(el))?;
                    let n = ct.decode(b, le);
                    if !(n >= 0.0 && n <= (body.len() - pos) as f64) {
                        return Err(truncated(el));
                    }
                    pos += ct.size();
                    let skip = (n as usize).checked_mul(p.ty.size()).ok_or_else(|| truncated(el))?;
                    pos = pos.checked_add(skip).filter(|&e| e <= body.len()).ok_or_else(|| truncated(el))?;
                } else {
                    let b = body.get(pos..pos + p.ty.size()).ok_or_else(|| truncated(el))?;
                    pos += p.ty.size();
                    if ei == target {
                        // f32 stays bit-exact; other types convert.
                        let v = if p.ty == Scalar::F32 {
                            let a = b.try_into().unwrap_or_default();
                            if le {
                                f32::from_le_bytes(a)
                            } else {
                                f32::from_be_bytes(a)
                            }
                        } else {
                            p.ty.decode(b, le) as f32
                        };
                        cols[ci].1.push(v);
                    }
                    ci += 1;
                }
            }
        }
        if ei == target {
            return Ok(cols);
        }
    }
    Ok(Vec::new())
}

fn read_ascii(body: &[u8], h: &Header, target: usize) -> Result<Columns, ErrorKind> {
    let text = std::str::from_utf8(body).map_err(|_| bad("ASCII body is not text"))?;
    let mut tok = text.split_ascii_whitespace();
    let mut next =
        |el: &Element| tok.next().ok_or_else(|| ErrorKind::Truncated(format!("element '{}' ends early", el.name)));
    for (ei, el) in h.elements.iter().enumerate() {
        let mut cols = columns(el);
        for _ in 0..el.count {
            let mut ci = 0;
            for p in &el.props {
                if p.list.is_some() {
                    let t = next(el)?;
                    let n: usize = t.parse().map_err(|_| bad(format!("bad list length '{t}'")))?;
                    for _ in 0..n {
                        next(el)?;
                    }
                } else {
                    let t = next(el)?;
                    let v: f32 = t
                        .parse()
                        .map_err(|_| bad(format!("bad number '{}'", t.chars().take(30).collect::<String>())))?;
                    if ei == target {
                        cols[ci].1.push(v);
                    }
                    ci += 1;
                }
            }
        }
        if ei == target {
            return Ok(cols);
        }
    }
    Ok(Vec::new())
}
