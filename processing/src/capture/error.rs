//! Errors reading or writing a capture, and the one-line image error every decoder
//! reports through.

use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::guard;

/// Errors reading a capture.
#[derive(Debug, Error)]
pub enum CaptureError {
    #[error("{image}: sidecar {sidecar} is missing")]
    MissingSidecar { image: PathBuf, sidecar: PathBuf },
    #[error("{path}: cannot read sidecar: {error}")]
    SidecarIo {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{path}: invalid sidecar JSON: {error}")]
    SidecarJson {
        path: PathBuf,
        error: serde_json::Error,
    },
    #[error("{path}: sidecar field '{field}': {reason}")]
    InvalidSidecar {
        path: PathBuf,
        field: &'static str,
        reason: String,
    },
    #[error("{path}: cannot decode image: {reason}")]
    Image { path: PathBuf, reason: String },
    #[error("{path}: unsupported image layout: {reason}")]
    Layout { path: PathBuf, reason: String },
    #[error("{path}: refused: {reason}")]
    TooLarge { path: PathBuf, reason: String },
    #[error("{path}: unsupported file type (expected .tif, .tiff{raw})", raw = if cfg!(feature = "raw") { " or a camera raw file" } else { "; camera raw support is not built in" })]
    UnsupportedFormat { path: PathBuf },
}

/// The error of an image `path` that cannot be read or written, for `reason` (on one
/// line: rawler's messages may span several).
pub(super) fn image_error(path: &Path, reason: impl std::fmt::Display) -> CaptureError {
    CaptureError::Image {
        path: path.to_path_buf(),
        reason: guard::one_line(&reason.to_string()),
    }
}
