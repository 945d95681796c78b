//! Image files <-> [`Image`] (f32, interleaved, channels kept as stored).
//!
//! Reading: PNG (8/16-bit gray, gray+alpha, RGB, RGBA) and JPEG map integer codes `q` to
//! `q / (2^bits - 1)` in [0, 1], i.e. the stored (normally sRGB-encoded) values, no transfer
//! function applied. Radiance `.hdr` and OpenEXR give linear f32 RGB(A) as stored; non-finite
//! values are rejected rather than passed on. The format comes from the file extension.
//!
//! Writing is atomic (`<path>.tmp` then rename, see [`write_atomic`]).

use crate::error::{read_bytes, write_atomic, ErrorKind, Result, WithPath};
use image::{DynamicImage, ImageBuffer, ImageFormat, Limits};
use std::io::Cursor;
use std::path::Path;
use svgir_core::Image;

/// Largest width or height accepted from a file, so a corrupt header cannot demand gigabytes.
pub const MAX_IMAGE_SIDE: u32 = 1 << 15;

/// The image file formats svgir reads and writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageKind {
    /// PNG (`.png`), 8 or 16 bits per channel.
    Png,
    /// JPEG (`.jpg`, `.jpeg`), 8 bits per channel.
    Jpeg,
    /// Radiance HDR (`.hdr`), linear floats.
    Hdr,
    /// OpenEXR (`.exr`), linear floats.
    Exr,
}

impl ImageKind {
    /// From a file extension (case-insensitive).
    pub fn from_path(path: &Path) -> std::result::Result<Self, ErrorKind> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        match ext.as_str() {
            "png" => Ok(Self::Png),
            "jpg" | "jpeg" => Ok(Self::Jpeg),
            "hdr" => Ok(Self::Hdr),
            "exr" => Ok(Self::Exr),
            _ => Err(ErrorKind::UnknownImageFormat(format!(".{ext}"))),
        }
    }

    fn name(self) -> &'static str {
        match self {
            Self::Png => "PNG",
            Self::Jpeg => "JPEG",
            Self::Hdr => "HDR",
            Self::Exr => "EXR",
        }
    }

    fn format(self) -> ImageFormat {
        match self {
            Self::Png => ImageFormat::Png,
            Self::Jpeg => ImageFormat::Jpeg,
            Self::Hdr => ImageFormat::Hdr,
            Self::Exr => ImageFormat::OpenExr,
        }
    }
}

/// Reads a PNG, JPEG, HDR or EXR file (format from the extension).
pub fn read_image(path: impl AsRef<Path>) -> Result<Image> {
    let path = path.as_ref();
    let kind = ImageKind::from_path(path).at(path)?;
    let bytes = read_bytes(path)?;
    decode_image(&bytes, kind).at(path)
}

/// Decodes an in-memory image file; the parser behind [`read_image`] (fuzzed in the tests).
pub fn decode_image(bytes: &[u8], kind: ImageKind) -> std::result::Result<Image, ErrorKind> {
    let mut reader = image::ImageReader::with_format(Cursor::new(bytes), kind.format());
    let mut limits = Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| decode_error(kind, e))?;
    let (w, h) = (img.width(), img.height());
    if w == 0 || h == 0 {
        return Err(ErrorKind::corrupt(kind.name(), format!("empty image {w}x{h}")));
    }
    let (channels, data) = to_f32(img);
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        let p = i / channels as usize;
        let (x, y) = (p % w as usize, p / w as usize);
        return Err(ErrorKind::corrupt(kind.name(), format!("non-finite value at pixel ({x}, {y})")));
    }
    Ok(Image::from_data(w, h, channels, data))
}

fn decode_error(kind: ImageKind, e: image::ImageError) -> ErrorKind {
    match e {
        image::ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            ErrorKind::Truncated(format!("{} data ends early", kind.name()))
        }
        e => ErrorKind::corrupt(kind.name(), e),
    }
}

/// Channels kept as stored; integer codes scaled to [0, 1].
fn to_f32(img: DynamicImage) -> (u32, Vec<f32>) {
    fn norm8(v: Vec<u8>) -> Vec<f32> {
        v.into_iter().map(|q| q as f32 / 255.0).collect()
    }
    fn norm16(v: Vec<u16>) -> Vec<f32> {
        v.into_iter().map(|q| q as f32 / 65535.0).collect()
    }
    match img {
        DynamicImage::ImageLuma8(b) => (1, norm8(b.into_raw())),
        DynamicImage::ImageLumaA8(b) => (2, norm8(b.into_raw())),
        DynamicImage::ImageRgb8(b) => (3, norm8(b.into_raw())),
        DynamicImage::ImageRgba8(b) => (4, norm8(b.into_raw())),
        DynamicImage::ImageLuma16(b) => (1, norm16(b.into_raw())),
        DynamicImage::ImageLumaA16(b) => (2, norm16(b.into_raw())),
        DynamicImage::ImageRgb16(b) => (3, norm16(b.into_raw())),
        DynamicImage::ImageRgba16(b) => (4, norm16(b.into_raw())),
        DynamicImage::ImageRgb32F(b) => (3, b.into_raw()),
        DynamicImage::ImageRgba32F(b) => (4, b.into_raw()),
        other if other.color().has_alpha() => (4, other.into_rgba32f().into_raw()),
        other => (3, other.into_rgb32f().into_raw()),
    }
}

fn check_writable(img: &Image, allowed: &[u32], what: &str) -> std::result::Result<(), ErrorKind> {
    if img.width == 0 || img.height == 0 {
        return Err(ErrorKind::invalid(format!("cannot write an empty {}x{} image", img.width, img.height)));
    }
    if !allowed.contains(&img.channels) {
        return Err(ErrorKind::invalid(format!(
            "cannot write {} channels as {what} (allowed {allowed:?})",
            img.channels
        )));
    }
    if img.data.len() != img.pixel_count() * img.channels as usize {
        return Err(ErrorKind::invalid("image data length does not match its size"));
    }
    Ok(())
}

fn encode(img: DynamicImage, format: ImageFormat) -> std::result::Result<Vec<u8>, ErrorKind> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, format).map_err(|e| ErrorKind::invalid(format!("encoding failed: {e}")))?;
    Ok(out.into_inner())
}

/// Writes 1 (gray), 2 (gray+alpha), 3 (RGB) or 4 (RGBA) channels as an 8- or 16-bit PNG.
/// Values are clamped to [0, 1] (NaN -> 0) and rounded to the nearest code; no transfer
/// function is applied, so pass sRGB-encoded values for a normal-looking picture.
pub fn write_png(path: impl AsRef<Path>, img: &Image, bit_depth: u8) -> Result<()> {
    let path = path.as_ref();
    encode_png(img, bit_depth).and_then(|bytes| write_atomic(path, &bytes).map_err(|e| e.kind)).at(path)
}

/// The bytes of [`write_png`].
pub fn encode_png(img: &Image, bit_depth: u8) -> std::result::Result<Vec<u8>, ErrorKind> {
    check_writable(img, &[1, 2, 3, 4], "PNG")?;
    let (w, h) = (img.width, img.height);
    let clamp = |v: f32| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    let dynimg = match bit_depth {
        8 => {
            let q: Vec<u8> = img.data.iter().map(|&v| (clamp(v) * 255.0).round() as u8).collect();
            match img.channels {
                1 => ImageBuffer::from_raw(w, h, q).map(DynamicImage::ImageLuma8),
                2 => ImageBuffer::from_raw(w, h, q).map(DynamicImage::ImageLumaA8),
                3 => ImageBuffer::from_raw(w, h, q).map(DynamicImage::ImageRgb8),
                _ => ImageBuffer::from_raw(w, h, q).map(DynamicImage::ImageRgba8),
            }
        }
        16 => {
            let q: Vec<u16> = img.data.iter().map(|&v| (clamp(v) * 65535.0).round() as u16).collect();
            match img.channels {
                1 => ImageBuffer::from_raw(w, h, q).map(DynamicImage::ImageLuma16),
                2 => ImageBuffer::from_raw(w, h, q).map(DynamicImage::ImageLumaA16),
                3 => ImageBuffer::from_raw(w, h, q).map(DynamicImage::ImageRgb16),
                _ => ImageBuffer::from_raw(w, h, q).map(DynamicImage::ImageRgba16),
            }
        }
        b => return Err(ErrorKind::invalid(format!("PNG bit depth must be 8 or 16, not {b}"))),
    };
    let dynimg = dynimg.ok_or_else(|| ErrorKind::invalid("image buffer size mismatch"))?;
    encode(dynimg, ImageFormat::Png)
}

/// Linear RGB f32 of a 1-, 3- or 4-channel image (gray replicated, alpha dropped).
fn rgb_f32(img: &Image) -> Vec<f32> {
    match img.channels {
        1 => img.data.iter().flat_map(|&v| [v, v, v]).collect(),
        3 => img.data.clone(),
        _ => img.data.chunks_exact(img.channels as usize).flat_map(|p| [p[0], p[1], p[2]]).collect(),
    }
}

/// Writes linear radiance as Radiance RGBE `.hdr` (1, 3 or 4 channels; alpha is dropped,
/// negatives and NaN become 0 because RGBE cannot hold them).
pub fn write_hdr(path: impl AsRef<Path>, img: &Image) -> Result<()> {
    let path = path.as_ref();
    encode_hdr(img).and_then(|bytes| write_atomic(path, &bytes).map_err(|e| e.kind)).at(path)
}

/// The bytes of [`write_hdr`].
pub fn encode_hdr(img: &Image) -> std::result::Result<Vec<u8>, ErrorKind> {
    check_writable(img, &[1, 3, 4], "HDR")?;
    let data: Vec<f32> = rgb_f32(img).into_iter().map(|v| if v > 0.0 { v.min(f32::MAX) } else { 0.0 }).collect();
    let buf = ImageBuffer::from_raw(img.width, img.height, data).ok_or_else(|| ErrorKind::invalid("size mismatch"))?;
    encode(DynamicImage::ImageRgb32F(buf), ImageFormat::Hdr)
}

/// Writes linear f32 OpenEXR: RGBA for 4 channels, RGB for 1 (replicated) or 3.
pub fn write_exr(path: impl AsRef<Path>, img: &Image) -> Result<()> {
    let path = path.as_ref();
    encode_exr(img).and_then(|bytes| write_atomic(path, &bytes).map_err(|e| e.kind)).at(path)
}

/// The bytes of [`write_exr`].
pub fn encode_exr(img: &Image) -> std::result::Result<Vec<u8>, ErrorKind> {
    check_writable(img, &[1, 3, 4], "EXR")?;
    let dynimg = if img.channels == 4 {
        ImageBuffer::from_raw(img.width, img.height, img.data.clone()).map(DynamicImage::ImageRgba32F)
    } else {
        ImageBuffer::from_raw(img.width, img.height, rgb_f32(img)).map(DynamicImage::ImageRgb32F)
    };
    encode(dynimg.ok_or_else(|| ErrorKind::invalid("size mismatch"))?, ImageFormat::OpenExr)
}

/// `img` as 4-channel RGBA: gray is replicated, a missing alpha is 1.
pub fn to_rgba(img: Image) -> Image {
    let c = img.channels as usize;
    if c == 4 {
        return img;
    }
    let data = img
        .data
        .chunks_exact(c)
        .flat_map(|p| match c {
            1 => [p[0], p[0], p[0], 1.0],
            2 => [p[0], p[0], p[0], p[1]],
            _ => [p[0], p[1], p[2], 1.0],
        })
        .collect();
    Image::from_data(img.width, img.height, 4, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: u32, h: u32, c: u32) -> Image {
        let n = (w * h * c) as usize;
        Image::from_data(w, h, c, (0..n).map(|i| (i * 7919 % 1000) as f32 / 999.0).collect())
    }

    #[test]
    fn png_round_trips_at_8_and_16_bits_all_channel_counts() {
        for c in 1..=4 {
            let img = ramp(5, 3, c);
            for (bits, tol) in [(8u8, 0.5 / 255.0 + 1e-6), (16, 0.5 / 65535.0 + 1e-7)] {
                let back = decode_image(&encode_png(&img, bits).unwrap(), ImageKind::Png).unwrap();
                assert_eq!((back.width, back.height, back.channels), (5, 3, c));
                let err = img.data.iter().zip(&back.data).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                assert!(err <= tol, "c={c} bits={bits} err={err}");
            }
        }
        // Clamping: out-of-range values and NaN.
        let img = Image::from_data(3, 1, 1, vec![-1.0, 2.0, f32::NAN]);
        let back = decode_image(&encode_png(&img, 8).unwrap(), ImageKind::Png).unwrap();
        assert_eq!(back.data, vec![0.0, 1.0, 0.0]);
        assert!(encode_png(&img, 12).is_err());
    }

    #[test]
    fn hdr_and_exr_round_trip() {
        let mut img = ramp(6, 4, 3).map(|v| v * 40.0);
        img.data[0] = 0.0;
        let back = decode_image(&encode_hdr(&img).unwrap(), ImageKind::Hdr).unwrap();
        assert_eq!(back.channels, 3);
        for (a, b) in img.data.iter().zip(&back.data) {
            // RGBE keeps 8 mantissa bits relative to the pixel's largest channel.
            assert!((a - b).abs() <= 40.0 / 128.0, "{a} {b}");
        }
        let rgba = ramp(4, 5, 4).map(|v| v * 3.0 - 0.5);
        let back = decode_image(&encode_exr(&rgba).unwrap(), ImageKind::Exr).unwrap();
        assert_eq!(back, rgba, "EXR f32 is lossless");
        let rgb = ramp(4, 5, 3);
        assert_eq!(decode_image(&encode_exr(&rgb).unwrap(), ImageKind::Exr).unwrap(), rgb);
    }

    #[test]
    fn atomic_write_and_bad_inputs() {
        let dir = std::env::temp_dir().join(format!("svgir-io-img-{}", std::process::id()));
        let p = dir.join("sub/a.png");
        write_png(&p, &ramp(2, 2, 3), 8).unwrap();
        assert!(p.exists() && !dir.join("sub/a.png.tmp").exists());
        assert_eq!(read_image(&p).unwrap().channels, 3);
        let bad = dir.join("bad.png");
        std::fs::write(&bad, b"\x89PNG\r\n\x1a\nnot really").unwrap();
        let msg = read_image(&bad).unwrap_err().to_string();
        assert!(msg.starts_with(&format!("{}: ", bad.display())) && msg.contains("PNG"), "{msg}");
        let msg = read_image(dir.join("x.foo")).unwrap_err().to_string();
        assert!(msg.ends_with("unknown image format '.foo' (expected png, jpg, hdr, exr)"), "{msg}");
        let msg = read_image(dir.join("missing.png")).unwrap_err().to_string();
        assert!(msg.ends_with("missing.png: file not found"), "{msg}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
