//! Samples CSV: one row per surface point, header `theta_l,theta_i,theta_r,r,g,b`.

use serde::{Deserialize, Serialize};

/// One measured surface point: angles in degrees, β per camera channel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    pub theta_l: f64,
    pub theta_i: f64,
    pub theta_r: f64,
    pub rgb: [f64; 3],
}
