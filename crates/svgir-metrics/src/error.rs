//! The one error type of the metrics crate: bad shapes, empty masks, malformed weight files.

/// Everything a metric can reject: mismatched shapes, too-small images, empty masks, bad LPIPS weights.
#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    /// Two inputs disagree in length or size; the message names the quantity and both values.
    #[error("shape mismatch: {0}")]
    ShapeMismatch(String),
    /// The image is empty or smaller than the metric needs (SSIM TensoIR window, LPIPS backbone).
    #[error("image too small: {0}")]
    TooSmall(String),
    /// The mask selects no pixel, so a masked mean is undefined.
    #[error("mask selects no pixel")]
    EmptyMask,
    /// A malformed safetensors byte stream (header, dtype or offsets).
    #[error("safetensors: {0}")]
    Safetensors(String),
    /// LPIPS weights are missing a tensor or have the wrong shape for the chosen net.
    #[error("LPIPS weights: {0}")]
    Weights(String),
}

/// Result of every fallible metrics function.
pub type Result<T> = std::result::Result<T, MetricsError>;

/// `Err(ShapeMismatch)` unless `a == b`; `what` names the quantity in the message.
pub(crate) fn check_eq(what: &str, a: usize, b: usize) -> Result<()> {
    if a == b {
        Ok(())
    } else {
        Err(MetricsError::ShapeMismatch(format!("{what}: {a} vs {b}")))
    }
}
