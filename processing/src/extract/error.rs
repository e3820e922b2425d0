//! Errors of scan extraction ([`extract_scan`](super::extract_scan)).

use std::path::PathBuf;

use thiserror::Error;

use super::captures::FindError;
use crate::capture::CaptureError;
use crate::geometry::GeometryError;
use crate::hdr::HdrError;

/// Errors of [`extract_scan`](super::extract_scan).
#[derive(Debug, Error)]
pub enum ExtractError {
    #[error("{path}: {reason}")]
    Setup { path: PathBuf, reason: String },
    #[error("{path}: invalid setup: {error}")]
    Geometry { path: PathBuf, error: GeometryError },
    #[error("{path}: cannot list directory: {error}")]
    Walk {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error(
        "{path}: a symbolic link: θL folders and captures must be plain directories and \
         files (a link is not followed)"
    )]
    Link { path: PathBuf },
    #[error("{dir}: no captures (image files with a .json sidecar) found")]
    NoCaptures { dir: PathBuf },
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error("θL {theta_l}°: {error}")]
    Hdr { theta_l: f64, error: HdrError },
    #[error("θL {theta_l}°: captures are {width}×{height}, but the setup is {setup_width}×{setup_height} (or half of it)")]
    SizeMismatch {
        theta_l: f64,
        width: usize,
        height: usize,
        setup_width: u32,
        setup_height: u32,
    },
    #[error("{which} row {row} ± 2 lies outside the {height}-row image")]
    RowOutside {
        which: &'static str,
        row: usize,
        height: usize,
    },
    #[error("sample row {sample} and white row {white} (setup's sample_row, white_row in capture rows) are closer than the {rows} rows a strip spans: the strips overlap")]
    StripsOverlap {
        sample: usize,
        white: usize,
        rows: usize,
    },
    #[error("invalid extraction option: {0}")]
    Options(String),
}

impl From<FindError> for ExtractError {
    fn from(err: FindError) -> Self {
        match err {
            FindError::Walk { path, error } => ExtractError::Walk { path, error },
            FindError::Link { path } => ExtractError::Link { path },
        }
    }
}
