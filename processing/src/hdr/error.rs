//! Errors of the HDR merge and of OpenEXR reading and writing.

use std::path::PathBuf;

use thiserror::Error;

use crate::capture::Response;

/// Errors of [`merge`](super::merge) and [`HdrImage::write_exr`](super::HdrImage::write_exr).
#[derive(Debug, Error)]
pub enum HdrError {
    #[error("no frames to merge")]
    NoFrames,
    #[error("{path}: {found_w}×{found_h} pixels, but the bracket is {width}×{height}")]
    SizeMismatch {
        path: PathBuf,
        width: usize,
        height: usize,
        found_w: usize,
        found_h: usize,
    },
    #[error("{path}: θL {found}° differs from the bracket's {expected}°")]
    ThetaMismatch {
        path: PathBuf,
        expected: f64,
        found: f64,
    },
    #[error("{path}: response '{found:?}' differs from the bracket's '{expected:?}'")]
    MixedResponse {
        path: PathBuf,
        expected: Response,
        found: Response,
    },
    #[error("Debevec–Malik response recovery needs at least two different exposures")]
    SingleExposure,
    #[error("response recovery failed: {0}")]
    Response(String),
    #[error("invalid merge option: {0}")]
    Options(String),
    #[error("{path}: cannot write OpenEXR: {reason}")]
    Exr { path: PathBuf, reason: String },
    #[error("{path}: cannot read OpenEXR: {reason}")]
    ExrRead { path: PathBuf, reason: String },
}
