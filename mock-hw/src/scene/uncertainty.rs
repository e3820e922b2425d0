//! A scene's `[setup.uncertainty]`: the standard uncertainties (k = 1) of its nominal
//! setup that its setup.json states (the `uncertainty` block of
//! docs/ARCHITECTURE.md's setup.json), for the measurement's uncertainty budget.

use serde::{Deserialize, Serialize};

use super::error::{invalid, SceneError};

/// Largest standard uncertainty a scene may state, in each key's unit (setup.json's
/// own limit).
const MAX_UNCERTAINTY: f64 = 100.0;

/// The white reference's relative standard uncertainty: one value, or one per channel
/// (R, G, B).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum WhiteUncertainty {
    All(f64),
    PerChannel([f64; 3]),
}

/// Standard uncertainties (k = 1) of the stated setup, each optional (setup.json's
/// defaults apply to those absent): the white reflectance relative, lengths in mm,
/// angles in degrees; `arm_angle_deg` is the arm's repeatability at each θL.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SetupUncertainty {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_reflectance: Option<WhiteUncertainty>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_offset_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_distance_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light_distance_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cylinder_tilt_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_zero_offset_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_angle_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_yaw_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_roll_deg: Option<f64>,
    /// Of the white's falloff toward grazing (relative).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_falloff: Option<f64>,
}

impl SetupUncertainty {
    /// Every value must be finite, at least 0 and at most [`MAX_UNCERTAINTY`].
    pub(super) fn validate(&self) -> Result<(), SceneError> {
        let white = match self.white_reflectance {
            Some(WhiteUncertainty::All(u)) => vec![u],
            Some(WhiteUncertainty::PerChannel(u)) => u.to_vec(),
            None => Vec::new(),
        };
        let one = |key, value: Option<f64>| (key, value.into_iter().collect::<Vec<_>>());
        for (key, values) in [
            ("white_reflectance", white),
            one("camera_offset_mm", self.camera_offset_mm),
            one("camera_distance_mm", self.camera_distance_mm),
            one("light_distance_mm", self.light_distance_mm),
            one("cylinder_tilt_deg", self.cylinder_tilt_deg),
            one("arm_zero_offset_deg", self.arm_zero_offset_deg),
            one("arm_angle_deg", self.arm_angle_deg),
            one("camera_yaw_deg", self.camera_yaw_deg),
            one("camera_roll_deg", self.camera_roll_deg),
            one("white_falloff", self.white_falloff),
        ] {
            if let Some(u) = values
                .iter()
                .find(|u| !(u.is_finite() && (0.0..=MAX_UNCERTAINTY).contains(*u)))
            {
                return Err(invalid(
                    &format!("setup.uncertainty.{key}"),
                    format!("{u} must be a standard uncertainty in [0, {MAX_UNCERTAINTY}]"),
                ));
            }
        }
        Ok(())
    }
}
