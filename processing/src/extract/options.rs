//! Options of scan extraction ([`extract_scan`](super::extract_scan)) and their checks.
//! Angles in degrees; reflectance and fractions are plain ratios.

use std::path::PathBuf;

use super::error::ExtractError;
use crate::color::CameraModel;
use crate::hdr::MergeOptions;

/// Options of [`extract_scan`](super::extract_scan).
#[derive(Debug, Clone, PartialEq)]
pub struct ExtractOptions {
    pub merge: MergeOptions,
    /// Reflectance of the white reference (1 = perfect reflecting diffuser), overriding
    /// setup.json's `white_reflectance`; `None`: setup.json's (1 if it has none).
    pub white_reflectance: Option<f64>,
    /// Columns with |θi| or |θr| above this (degrees) are dropped.
    pub grazing_limit_deg: f64,
    /// A channel whose white strip is below this fraction of the brightest white column
    /// of the same θL and channel is dropped at that column.
    pub min_white_fraction: f64,
    /// Camera and illuminant that define the camera-RGB domain.
    pub camera: CameraModel,
    /// When set, each θL's radiance map is written there as `theta_l_<θL>.exr`.
    pub hdr_dir: Option<PathBuf>,
    /// The setup to use instead of the scan's `setup.json` (say, one `gonio calibrate`
    /// wrote).
    pub setup: Option<PathBuf>,
    /// When set, only the captures of this θL (degrees) are extracted.
    pub theta_l: Option<f64>,
    /// Whether each sample gets its uncertainty ([`Sample::uncertainty`](crate::samples::Sample::uncertainty)): its noise,
    /// and its change under each of the setup's uncertain inputs (for a geometric one,
    /// from the geometry the setup moved by ± its uncertainty gives each sample's column).
    pub uncertainty: bool,
}

impl Default for ExtractOptions {
    fn default() -> Self {
        Self {
            merge: MergeOptions::default(),
            white_reflectance: None,
            grazing_limit_deg: 80.0,
            min_white_fraction: 0.02,
            camera: CameraModel::builtin(),
            hdr_dir: None,
            setup: None,
            theta_l: None,
            uncertainty: true,
        }
    }
}

pub(super) fn check_options(o: &ExtractOptions) -> Result<(), ExtractError> {
    if let Some(white) = o.white_reflectance {
        if !(white.is_finite() && white > 0.0 && white <= 2.0) {
            return Err(ExtractError::Options(format!(
                "white reflectance {white} is not in (0, 2]"
            )));
        }
    }
    if !(o.grazing_limit_deg.is_finite()
        && o.grazing_limit_deg > 0.0
        && o.grazing_limit_deg <= 90.0)
    {
        return Err(ExtractError::Options(format!(
            "grazing limit {}° is not in (0, 90]",
            o.grazing_limit_deg
        )));
    }
    if !(o.min_white_fraction.is_finite() && (0.0..1.0).contains(&o.min_white_fraction)) {
        return Err(ExtractError::Options(format!(
            "minimum white fraction {} is not in [0, 1)",
            o.min_white_fraction
        )));
    }
    Ok(())
}
