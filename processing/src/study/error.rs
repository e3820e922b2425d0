//! The error of a study: bad samples or options, or an output that could not be written.

use std::path::PathBuf;

use super::figures::FigureError;
use crate::metrics::MetricsError;

/// Why a study could not be run or written.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error("the samples are empty")]
    NoSamples,
    #[error("sample {index}: {field} is not finite")]
    NonFinite { index: usize, field: &'static str },
    #[error("{count} distinct θL in the samples; a study enumerates at most {max}")]
    TooManyThetaL { count: usize, max: usize },
    #[error("the reference covers none of the {samples} sample angles (θi, θr)")]
    NoOverlap { samples: usize },
    #[error("no model variant to fit")]
    NoVariants,
    #[error("the column stride must be at least 1")]
    ZeroStride,
    #[error("reference at the sample angles: {0}")]
    Reference(MetricsError),
    #[error("cannot write {path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error(transparent)]
    Figure(#[from] FigureError),
}

impl From<MetricsError> for StudyError {
    fn from(error: MetricsError) -> Self {
        StudyError::Reference(error)
    }
}
