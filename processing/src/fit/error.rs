//! The error of a fit: what in the samples or the options prevents it.

use crate::metrics;

/// Why a fit could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error("{points} sample points but the model has {parameters} parameters")]
    TooFewPoints { points: usize, parameters: usize },
    #[error("sample {index}: {field} is not finite")]
    NonFinite { index: usize, field: &'static str },
    #[error("sample {index}: direction at or past grazing (θi = {theta_i}°, θr = {theta_r}°; n·l = {n_dot_l}, n·v = {n_dot_v})")]
    Grazing {
        index: usize,
        theta_i: f64,
        theta_r: f64,
        n_dot_l: f64,
        n_dot_v: f64,
    },
    #[error("channel {channel} has no signal (sum of β ≤ 0)")]
    NoSignal { channel: char },
    #[error("channel {channel} has no value: every sample's is dropped (saturated, underexposed or against a dark white)")]
    AllDropped { channel: char },
    #[error("{count} distinct θL in the samples; at least {needed} needed")]
    TooFewThetaL { count: usize, needed: usize },
    #[error("invalid fit options: {0}")]
    InvalidOptions(String),
    #[error("optimiser failed: {0}")]
    Optimizer(String),
    #[error("the fit's {0} is not finite: the β values are too large to fit")]
    Overflow(&'static str),
    #[error(transparent)]
    Metric(#[from] metrics::MetricsError),
    #[error("table: {0}")]
    Table(#[from] super::table::TableError),
}
