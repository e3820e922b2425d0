//! Why a scene could not be loaded, and the checks of scene values that say so, each
//! naming the key.

use std::path::PathBuf;

use thiserror::Error;

/// Why a scene could not be loaded.
#[derive(Debug, Error)]
pub enum SceneError {
    #[error("cannot read {path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("scene {origin}: {message}")]
    Parse { origin: String, message: String },
    #[error("scene key `{key}`: {reason}")]
    Invalid { key: String, reason: String },
    #[error("{}: {reason}", path.display())]
    Bsdf { path: PathBuf, reason: String },
    #[error("{what}, line {line}: {reason}")]
    Table {
        what: String,
        line: usize,
        reason: String,
    },
}

/// The error of key `key` holding a bad value.
pub(super) fn invalid(key: &str, reason: impl Into<String>) -> SceneError {
    SceneError::Invalid {
        key: key.to_string(),
        reason: reason.into(),
    }
}

/// `value` at `key` must be finite and above 0.
pub(super) fn check_positive(key: &str, value: f64) -> Result<(), SceneError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(invalid(key, format!("{value} must be a positive number")))
    }
}

/// Every value at `key` must be finite and at least 0.
pub(super) fn check_non_negative(key: &str, values: &[f64]) -> Result<(), SceneError> {
    match values.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
        Some(v) => Err(invalid(key, format!("{v} must be a non-negative number"))),
        None => Ok(()),
    }
}
