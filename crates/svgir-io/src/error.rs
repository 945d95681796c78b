//! The one error type of svgir-io: every failure names the file it concerns and what is wrong
//! with it, e.g. `data/lego/transforms_train.json: camera 3: NaN in transform_matrix`.
//!
//! Parsers work on byte slices and return a bare [`ErrorKind`]; the file-level functions attach
//! the path with [`WithPath::at`], so parsers can be fuzzed without touching the file system.

use std::fmt;
use std::path::{Path, PathBuf};

/// A failure to read or write one file (or dataset folder).
#[derive(Debug, thiserror::Error)]
#[error("{}: {kind}", path.display())]
pub struct IoError {
    /// The file or dataset folder concerned.
    pub path: PathBuf,
    /// What is wrong with it.
    pub kind: ErrorKind,
}

/// What went wrong, without the path.
#[derive(Debug, thiserror::Error)]
pub enum ErrorKind {
    /// The file does not exist.
    #[error("file not found")]
    NotFound,
    /// Any other operating-system error while reading or writing.
    #[error("{0}")]
    Os(std::io::Error),
    /// The file ends before its content does.
    #[error("truncated{}", detail_suffix(.0))]
    Truncated(String),
    /// A decoder rejected the content of a `format` file ("PNG", "PLY", "COLMAP cameras.bin").
    #[error("corrupt {format}: {detail}")]
    Corrupt {
        /// Name of the format or file kind, e.g. "PNG", "COLMAP cameras.bin".
        format: &'static str,
        /// What the decoder rejected.
        detail: String,
    },
    /// The file extension is none of png, jpg, hdr, exr (the extension is given).
    #[error("unknown image format '{0}' (expected png, jpg, hdr, exr)")]
    UnknownImageFormat(String),
    /// A file or entry the layout requires is absent ("view image", "transforms_train.json").
    #[error("missing {0}")]
    Missing(String),
    /// Camera `index` (in file order) is unusable.
    #[error("camera {index}: {problem}")]
    Camera {
        /// Camera index in file order, from 0.
        index: usize,
        /// What is wrong with it (e.g. "NaN in transform_matrix").
        problem: String,
    },
    /// An image's size differs from the size its view's camera expects.
    #[error("image is {got_w}x{got_h} but view {view} is {want_w}x{want_h}")]
    SizeMismatch {
        /// View index in file order.
        view: usize,
        /// Width of the image file in pixels.
        got_w: u32,
        /// Height of the image file in pixels.
        got_h: u32,
        /// Width the camera expects in pixels.
        want_w: u32,
        /// Height the camera expects in pixels.
        want_h: u32,
    },
    /// A COLMAP camera model id that COLMAP does not define.
    #[error("unknown camera model {0}")]
    UnknownCameraModel(i32),
    /// A known COLMAP camera model that undistortion does not handle.
    #[error("unsupported camera model {name} (id {id}); supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, OPENCV_FISHEYE, FULL_OPENCV")]
    UnsupportedCameraModel {
        /// COLMAP's name of the model.
        name: &'static str,
        /// COLMAP's id of the model.
        id: i32,
    },
    /// Anything else that makes the content unusable, said in words.
    #[error("{0}")]
    Invalid(String),
}

fn detail_suffix(s: &str) -> String {
    if s.is_empty() {
        String::new()
    } else {
        format!(" ({s})")
    }
}

impl ErrorKind {
    /// A [`ErrorKind::Corrupt`] for a `format` file with a `detail` message.
    pub fn corrupt(format: &'static str, detail: impl fmt::Display) -> Self {
        ErrorKind::Corrupt { format, detail: detail.to_string() }
    }

    /// An [`ErrorKind::Invalid`] with a `detail` message.
    pub fn invalid(detail: impl fmt::Display) -> Self {
        ErrorKind::Invalid(detail.to_string())
    }

    /// Attach the file this error is about.
    pub fn at(self, path: impl AsRef<Path>) -> IoError {
        IoError { path: path.as_ref().to_path_buf(), kind: self }
    }
}

impl From<std::io::Error> for ErrorKind {
    fn from(e: std::io::Error) -> Self {
        match e.kind() {
            std::io::ErrorKind::NotFound => ErrorKind::NotFound,
            std::io::ErrorKind::UnexpectedEof => ErrorKind::Truncated(String::new()),
            _ => ErrorKind::Os(e),
        }
    }
}

/// `result.at(path)`: turn a path-less result into an [`IoError`] result.
pub trait WithPath<T> {
    /// Attach `path` to the error, if any.
    fn at(self, path: impl AsRef<Path>) -> Result<T>;
}

impl<T, E: Into<ErrorKind>> WithPath<T> for std::result::Result<T, E> {
    fn at(self, path: impl AsRef<Path>) -> Result<T> {
        self.map_err(|e| e.into().at(path))
    }
}

/// Result of every file-level function of svgir-io.
pub type Result<T> = std::result::Result<T, IoError>;

/// Reads a whole file, naming it in the error.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).at(path)
}

/// Writes `bytes` atomically: into `<path>.tmp` first, then renamed over `path`, so readers
/// never see a half-written file. Creates missing parent folders.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).at(dir)?;
    }
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, bytes).at(&tmp)?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        ErrorKind::from(e).at(path)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_file_and_problem() {
        let e = ErrorKind::Camera { index: 3, problem: "NaN in transform_matrix".into() }.at("a/b.json");
        assert_eq!(e.to_string(), "a/b.json: camera 3: NaN in transform_matrix");
        let e = ErrorKind::SizeMismatch { view: 0, got_w: 200, got_h: 200, want_w: 400, want_h: 400 }.at("x.png");
        assert_eq!(e.to_string(), "x.png: image is 200x200 but view 0 is 400x400");
        assert_eq!(ErrorKind::Truncated(String::new()).at("p.ply").to_string(), "p.ply: truncated");
        assert_eq!(
            ErrorKind::UnknownImageFormat(".foo".into()).at("a.foo").to_string(),
            "a.foo: unknown image format '.foo' (expected png, jpg, hdr, exr)"
        );
        let e = read_bytes(Path::new("/nonexistent/zz.png")).unwrap_err();
        assert_eq!(e.to_string(), "/nonexistent/zz.png: file not found");
    }
}
