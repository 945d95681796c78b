//! The exposure settings a photo's EXIF block records (camera make and model, exposure time,
//! f-number, ISO, exposure bias), so that `svgir capture` can tell whether its photos were taken
//! with one exposure or several. Written by hand: the well-kept EXIF crates are not among the
//! workspace's dependencies, and these five tags need only the TIFF structure (a byte order,
//! IFD0 and its Exif sub-IFD); `image` hands over the raw block.

use crate::error::{ErrorKind, IoError};
use std::path::Path;

/// What a photo's EXIF says about how it was exposed; `None` where a tag is absent.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExposureSettings {
    /// `Make` and `Model`, joined.
    pub camera: Option<String>,
    /// Seconds.
    pub exposure_time: Option<f64>,
    /// The aperture's f-number.
    pub f_number: Option<f64>,
    /// ISO speed.
    pub iso: Option<u32>,
    /// EV.
    pub bias: Option<f64>,
}

impl ExposureSettings {
    /// Whether any exposure tag is present.
    pub fn is_known(&self) -> bool {
        self.exposure_time.is_some() || self.f_number.is_some() || self.iso.is_some()
    }
}

/// The exposure settings in the EXIF block of the photo at `path`; `None` when it has none.
pub fn read_exposure_settings(path: &Path) -> Result<Option<ExposureSettings>, IoError> {
    use image::ImageDecoder;
    let bad = |e: image::ImageError| ErrorKind::invalid(format!("cannot read its metadata: {e}")).at(path);
    let reader = image::ImageReader::open(path).map_err(|e| ErrorKind::invalid(e).at(path))?;
    let mut decoder = reader.with_guessed_format().map_err(|e| ErrorKind::invalid(e).at(path))?;
    decoder.no_limits();
    let mut decoder = decoder.into_decoder().map_err(bad)?;
    Ok(decoder.exif_metadata().map_err(bad)?.and_then(|b| parse(&b)))
}

/// The settings in an EXIF block (TIFF structure, optionally behind JPEG's `Exif\0\0`); `None`
/// when it is not one.
pub fn parse(block: &[u8]) -> Option<ExposureSettings> {
    let t = block.strip_prefix(b"Exif\0\0").unwrap_or(block);
    let le = match t.get(..4)? {
        b"II*\0" => true,
        b"MM\0*" => false,
        _ => return None,
    };
    let tiff = Tiff { b: t, le };
    let mut s = ExposureSettings::default();
    let (mut make, mut model) = (None, None);
    let mut exif_ifd = None;
    tiff.entries(tiff.u32(4)? as usize, |tag, e| match tag {
        0x010F => make = tiff.ascii(e),
        0x0110 => model = tiff.ascii(e),
        0x8769 => exif_ifd = tiff.u32(e + 8),
        _ => {}
    });
    s.camera = match (make, model) {
        (None, None) => None,
        (a, b) => Some(format!("{} {}", a.unwrap_or_default(), b.unwrap_or_default()).trim().to_string()),
    };
    if let Some(off) = exif_ifd {
        tiff.entries(off as usize, |tag, e| match tag {
            0x829A => s.exposure_time = tiff.rational(e, false),
            0x829D => s.f_number = tiff.rational(e, false),
            0x8827 => s.iso = tiff.short_or_long(e),
            0x9204 => s.bias = tiff.rational(e, true),
            _ => {}
        });
    }
    Some(s)
}

/// A TIFF block and its byte order.
struct Tiff<'a> {
    b: &'a [u8],
    le: bool,
}

impl Tiff<'_> {
    fn u16(&self, at: usize) -> Option<u16> {
        let x: [u8; 2] = self.b.get(at..at + 2)?.try_into().ok()?;
        Some(if self.le { u16::from_le_bytes(x) } else { u16::from_be_bytes(x) })
    }

    fn u32(&self, at: usize) -> Option<u32> {
        let x: [u8; 4] = self.b.get(at..at + 4)?.try_into().ok()?;
        Some(if self.le { u32::from_le_bytes(x) } else { u32::from_be_bytes(x) })
    }

    /// Calls `f(tag, entry offset)` for each 12-byte entry of the IFD at `at` (a truncated
    /// IFD ends early).
    fn entries(&self, at: usize, mut f: impl FnMut(u16, usize)) {
        let Some(n) = self.u16(at) else { return };
        for i in 0..n as usize {
            let e = at + 2 + 12 * i;
            match self.u16(e) {
                Some(tag) if e + 12 <= self.b.len() => f(tag, e),
                _ => return,
            }
        }
    }

    /// The entry's value bytes: inline when they fit in 4, else at the offset it holds.
    fn value(&self, e: usize, size: usize) -> Option<&[u8]> {
        if size <= 4 {
            self.b.get(e + 8..e + 8 + size)
        } else {
            let off = self.u32(e + 8)? as usize;
            self.b.get(off..off.checked_add(size)?)
        }
    }

    fn ascii(&self, e: usize) -> Option<String> {
        let count = self.u32(e + 4)? as usize;
        let bytes = self.value(e, count)?;
        let text = String::from_utf8_lossy(bytes).trim_end_matches('\0').trim().to_string();
        (!text.is_empty()).then_some(text)
    }

    fn rational(&self, e: usize, signed: bool) -> Option<f64> {
        let v = self.value(e, 8)?;
        let t = Tiff { b: v, le: self.le };
        let (n, d) = (t.u32(0)?, t.u32(4)?);
        let (n, d) = if signed { (n as i32 as f64, d as i32 as f64) } else { (n as f64, d as f64) };
        (d != 0.0).then(|| n / d)
    }

    fn short_or_long(&self, e: usize) -> Option<u32> {
        match self.u16(e + 2)? {
            3 => self.u16(e + 8).map(u32::from),
            4 => self.u32(e + 8),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A TIFF block with IFD0 (Make, Model, the Exif pointer) and an Exif IFD (exposure time,
    /// f-number, ISO, bias), in either byte order.
    fn block(le: bool, exposure: (u32, u32), iso: u16) -> Vec<u8> {
        let w16 = |v: u16| if le { v.to_le_bytes() } else { v.to_be_bytes() };
        let w32 = |v: u32| if le { v.to_le_bytes() } else { v.to_be_bytes() };
        let mut b: Vec<u8> = if le { b"II*\0".to_vec() } else { b"MM\0*".to_vec() };
        b.extend(w32(8));
        // IFD0 at 8: 3 entries, then the next-IFD offset; data follows at 8 + 2 + 36 + 4 = 50.
        let (make, model) = (b"Phone\0", b"X 12 Pro\0");
        let exif_at = 50 + make.len() + model.len();
        b.extend(w16(3));
        let entry = |b: &mut Vec<u8>, tag: u16, ty: u16, count: u32, value: [u8; 4]| {
            b.extend(w16(tag));
            b.extend(w16(ty));
            b.extend(w32(count));
            b.extend(value);
        };
        entry(&mut b, 0x010F, 2, make.len() as u32, w32(50));
        entry(&mut b, 0x0110, 2, model.len() as u32, w32((50 + make.len()) as u32));
        entry(&mut b, 0x8769, 4, 1, w32(exif_at as u32));
        b.extend(w32(0));
        b.extend(make);
        b.extend(model);
        assert_eq!(b.len(), exif_at);
        // Exif IFD: 4 entries; the rationals follow it.
        let data = exif_at + 2 + 48 + 4;
        b.extend(w16(4));
        entry(&mut b, 0x829A, 5, 1, w32(data as u32));
        entry(&mut b, 0x829D, 5, 1, w32(data as u32 + 8));
        let mut iso_value = [0u8; 4];
        iso_value[..2].copy_from_slice(&w16(iso));
        entry(&mut b, 0x8827, 3, 1, iso_value);
        entry(&mut b, 0x9204, 10, 1, w32(data as u32 + 16));
        b.extend(w32(0));
        b.extend(w32(exposure.0));
        b.extend(w32(exposure.1));
        b.extend(w32(18));
        b.extend(w32(10));
        b.extend(w32((-2i32) as u32));
        b.extend(w32(3));
        b
    }

    #[test]
    fn reads_the_exposure_tags_in_both_byte_orders() {
        for le in [true, false] {
            let s = parse(&block(le, (1, 125), 200)).expect("a TIFF block");
            assert_eq!(s.camera.as_deref(), Some("Phone X 12 Pro"), "le {le}");
            assert_eq!(s.exposure_time, Some(1.0 / 125.0));
            assert_eq!(s.f_number, Some(1.8));
            assert_eq!(s.iso, Some(200));
            assert_eq!(s.bias, Some(-2.0 / 3.0));
            assert!(s.is_known());
            // Behind JPEG's APP1 prefix too.
            let mut jpeg = b"Exif\0\0".to_vec();
            jpeg.extend(block(le, (1, 60), 800));
            let t = parse(&jpeg).unwrap();
            assert_eq!((t.exposure_time, t.iso), (Some(1.0 / 60.0), Some(800)));
        }
    }

    /// Through `image`'s JPEG decoder: a photo with the block in its APP1 segment, and one
    /// without.
    #[test]
    fn reads_a_jpeg_photos_exif() {
        let mut jpeg = Vec::new();
        let img = image::RgbImage::from_pixel(8, 8, image::Rgb([100, 150, 200]));
        img.write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg).unwrap();
        let dir = std::env::temp_dir().join(format!("svgir_exif_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let plain = dir.join("plain.jpg");
        std::fs::write(&plain, &jpeg).unwrap();
        let mut payload = b"Exif\0\0".to_vec();
        payload.extend(block(false, (1, 30), 1600));
        let mut tagged = jpeg[..2].to_vec();
        tagged.extend([0xFF, 0xE1]);
        tagged.extend(((payload.len() + 2) as u16).to_be_bytes());
        tagged.extend(&payload);
        tagged.extend(&jpeg[2..]);
        let with = dir.join("tagged.jpg");
        std::fs::write(&with, &tagged).unwrap();
        let s = read_exposure_settings(&with).unwrap().expect("EXIF");
        assert_eq!((s.exposure_time, s.iso), (Some(1.0 / 30.0), Some(1600)));
        assert_eq!(read_exposure_settings(&plain).unwrap(), None);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn truncated_or_foreign_blocks_give_what_they_hold() {
        assert_eq!(parse(b"JFIF"), None);
        let b = block(true, (1, 125), 200);
        // Cut inside the Exif IFD: the camera survives, the exposure tags do not all.
        let cut = parse(&b[..b.len() - 30]).unwrap();
        assert_eq!(cut.camera.as_deref(), Some("Phone X 12 Pro"));
        assert_eq!(cut.exposure_time, None);
        for n in 0..b.len() {
            let _ = parse(&b[..n]);
        }
    }
}
