//! The standard uncertainties of a setup's inputs (setup.json's `uncertainty` block), the
//! sources of a measurement's uncertainty budget besides the images' noise.
//!
//! Every value is a standard uncertainty (one standard deviation, coverage factor k = 1):
//! of the white reference's reflectance as a fraction of it (per channel R, G, B, or one
//! value for all three), of the geometry in its setup.json unit, and of the arm's angle at
//! each θL (its repeatability: independent from one θL to the next, where an arm zero
//! error is common to all of them); of the white's falloff toward grazing (relative, see
//! `processing/src/white_angular.rs`). A value absent from setup.json takes its
//! [`Source::default_uncertainty`], and the output says it is a default.

use serde::{Deserialize, Serialize};

/// One input quantity whose uncertainty is propagated to β and to fitted parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// The white reference's reflectance (relative): scales every β of a channel.
    WhiteReflectance,
    /// `camera_offset_mm`.
    CameraOffset,
    /// `camera_distance_mm`.
    CameraDistance,
    /// `light_distance_mm`.
    LightDistance,
    /// `cylinder_tilt_deg`.
    CylinderTilt,
    /// `arm_zero_offset_deg`: one error common to every θL.
    ArmZero,
    /// The arm's angle at each θL (repeatability): one error per θL, independent.
    ArmAngle,
    /// `camera_yaw_deg`.
    CameraYaw,
    /// `camera_roll_deg`.
    CameraRoll,
    /// The white reference's reflectance factor against the angle of incidence: the
    /// falloff toward grazing, or a certificate's table (its `u` column, one error for
    /// every angle).
    WhiteFalloff,
}

impl Source {
    /// Every source, in the order of the samples CSV columns and of the budget.
    pub const ALL: [Source; 10] = [
        Source::WhiteReflectance,
        Source::CameraOffset,
        Source::CameraDistance,
        Source::LightDistance,
        Source::CylinderTilt,
        Source::ArmZero,
        Source::ArmAngle,
        Source::CameraYaw,
        Source::CameraRoll,
        Source::WhiteFalloff,
    ];

    /// The sources added after the first seven: a samples CSV may lack their columns
    /// (written by an earlier extraction; read as no change), and the Monte Carlo draws
    /// them from a stream of their own (the others' draws are as they were).
    pub const LATER: [Source; 3] = [Source::CameraYaw, Source::CameraRoll, Source::WhiteFalloff];

    /// Number of sources.
    pub const COUNT: usize = Self::ALL.len();

    /// This source's place in [`Source::ALL`] (the order the enum declares).
    pub fn index(self) -> usize {
        self as usize
    }

    /// The key of this source in setup.json's `uncertainty` block.
    pub fn key(self) -> &'static str {
        match self {
            Source::WhiteReflectance => "white_reflectance",
            Source::CameraOffset => "camera_offset_mm",
            Source::CameraDistance => "camera_distance_mm",
            Source::LightDistance => "light_distance_mm",
            Source::CylinderTilt => "cylinder_tilt_deg",
            Source::ArmZero => "arm_zero_offset_deg",
            Source::ArmAngle => "arm_angle_deg",
            Source::CameraYaw => "camera_yaw_deg",
            Source::CameraRoll => "camera_roll_deg",
            Source::WhiteFalloff => "white_falloff",
        }
    }

    /// Short name used in the samples CSV columns (`u_<name>_r`, …) and the budget.
    pub fn name(self) -> &'static str {
        match self {
            Source::WhiteReflectance => "white_reflectance",
            Source::CameraOffset => "camera_offset",
            Source::CameraDistance => "camera_distance",
            Source::LightDistance => "light_distance",
            Source::CylinderTilt => "cylinder_tilt",
            Source::ArmZero => "arm_zero",
            Source::ArmAngle => "arm_angle",
            Source::CameraYaw => "camera_yaw",
            Source::CameraRoll => "camera_roll",
            Source::WhiteFalloff => "white_falloff",
        }
    }

    /// The unit of its standard uncertainty.
    pub fn unit(self) -> &'static str {
        match self {
            Source::WhiteReflectance | Source::WhiteFalloff => "relative",
            Source::CameraOffset | Source::CameraDistance | Source::LightDistance => "mm",
            Source::CylinderTilt
            | Source::ArmZero
            | Source::ArmAngle
            | Source::CameraYaw
            | Source::CameraRoll => "°",
        }
    }

    /// The standard uncertainty taken when setup.json gives none: a certified diffuse
    /// reflectance standard's ±1 % (k = 2); a setup measured with a ruler and a square
    /// (0.5 mm sideways, 1 mm along the optical axis, 2 mm to the lamp, 0.1° of tilt and of
    /// arm zero); a stepper arm's repeatability of 0.01°; a camera aimed so that the
    /// cylinder's limbs sit symmetric about the image's centre column to about two pixels
    /// (0.01° of yaw at 85 mm and 6.1 µm: beyond that the live view shows it) and levelled
    /// with a bubble level (0.1° of roll, as the tilt); a white's falloff toward grazing
    /// known to 1.5 % (the default falloff, [`crate::white_angular::DEFAULT_FALLOFF`],
    /// 1 u from a Lambertian white and 1 u from one 3 % darker at grazing).
    pub fn default_uncertainty(self) -> f64 {
        match self {
            Source::WhiteReflectance => 0.005,
            Source::CameraOffset => 0.5,
            Source::CameraDistance => 1.0,
            Source::LightDistance => 2.0,
            Source::CylinderTilt => 0.1,
            Source::ArmZero => 0.1,
            Source::ArmAngle => 0.01,
            Source::CameraYaw => 0.01,
            Source::CameraRoll => 0.1,
            Source::WhiteFalloff => crate::white_angular::DEFAULT_FALLOFF_UNCERTAINTY,
        }
    }
}

/// The white reference's relative standard uncertainty: one value for every channel,
/// or one per channel (R, G, B).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum WhiteUncertainty {
    All(f64),
    PerChannel([f64; 3]),
}

impl WhiteUncertainty {
    /// The relative standard uncertainty per channel.
    pub fn per_channel(self) -> [f64; 3] {
        match self {
            WhiteUncertainty::All(u) => [u; 3],
            WhiteUncertainty::PerChannel(u) => u,
        }
    }
}

/// setup.json's `uncertainty` block: standard uncertainties (k = 1), each optional.
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
    /// The standard uncertainty of the default falloff (a certificate's table in
    /// setup.json's `white_angular` carries its own).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_falloff: Option<f64>,
}

/// Largest standard uncertainty accepted, in each source's unit (a relative white
/// uncertainty of 1 is already meaningless; lengths and angles beyond this are not a
/// measured setup).
pub const MAX_UNCERTAINTY: f64 = 100.0;

/// One source's standard uncertainty as used, and whether setup.json gave it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Input {
    pub source: Source,
    /// Standard uncertainty per channel (R, G, B); the same value in all three except
    /// for a white reflectance given per channel.
    pub u: [f64; 3],
    /// `false`: the default ([`Source::default_uncertainty`]).
    pub given: bool,
}

impl Input {
    /// "0.5 % (default)", "0.1 mm", … for a person.
    pub fn describe(&self) -> String {
        let value = if self.u[0] == self.u[1] && self.u[1] == self.u[2] {
            self.format(self.u[0])
        } else {
            self.u.map(|u| self.format(u)).join(" / ")
        };
        let origin = if self.given { "" } else { " (default)" };
        format!("{} {value}{origin}", self.source.name().replace('_', " "))
    }

    fn format(&self, u: f64) -> String {
        match self.source.unit() {
            "relative" => format!("{} %", three_significant(u * 100.0)),
            unit => format!("{} {unit}", three_significant(u)),
        }
    }
}

/// `x` to three significant digits, without trailing zeros (0.0312 for
/// 0.031234567, 2 for 2.0): an uncertainty is stated to two or three digits (GUM 7.2.6).
fn three_significant(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return x.to_string();
    }
    let decimals = (2 - x.abs().log10().floor() as i32).clamp(0, 15) as usize;
    let text = format!("{x:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        text
    }
}

impl SetupUncertainty {
    /// Whether setup.json gives no value (every source takes its default).
    pub fn is_empty(&self) -> bool {
        *self == SetupUncertainty::default()
    }

    /// The value setup.json gives for `source`, if any.
    fn given(&self, source: Source) -> Option<[f64; 3]> {
        match source {
            Source::WhiteReflectance => self.white_reflectance.map(WhiteUncertainty::per_channel),
            Source::CameraOffset => self.camera_offset_mm.map(|u| [u; 3]),
            Source::CameraDistance => self.camera_distance_mm.map(|u| [u; 3]),
            Source::LightDistance => self.light_distance_mm.map(|u| [u; 3]),
            Source::CylinderTilt => self.cylinder_tilt_deg.map(|u| [u; 3]),
            Source::ArmZero => self.arm_zero_offset_deg.map(|u| [u; 3]),
            Source::ArmAngle => self.arm_angle_deg.map(|u| [u; 3]),
            Source::CameraYaw => self.camera_yaw_deg.map(|u| [u; 3]),
            Source::CameraRoll => self.camera_roll_deg.map(|u| [u; 3]),
            Source::WhiteFalloff => self.white_falloff.map(|u| [u; 3]),
        }
    }

    /// Every source's standard uncertainty: setup.json's, else the default.
    pub fn inputs(&self) -> [Input; Source::COUNT] {
        Source::ALL.map(|source| match self.given(source) {
            Some(u) => Input {
                source,
                u,
                given: true,
            },
            None => Input {
                source,
                u: [source.default_uncertainty(); 3],
                given: false,
            },
        })
    }

    /// The first value that is not a standard uncertainty: negative, not finite or above
    /// [`MAX_UNCERTAINTY`]; as (key, value).
    pub fn invalid(&self) -> Option<(&'static str, f64)> {
        Source::ALL.iter().find_map(|&source| {
            self.given(source)?
                .into_iter()
                .find(|u| !(u.is_finite() && (0.0..=MAX_UNCERTAINTY).contains(u)))
                .map(|u| (source.key(), u))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_source_s_index_is_its_place_in_all() {
        for (i, source) in Source::ALL.iter().enumerate() {
            assert_eq!(source.index(), i, "{source:?}");
        }
    }

    #[test]
    fn absent_values_take_their_defaults_and_say_so() {
        let block: SetupUncertainty = serde_json::from_str(
            r#"{"white_reflectance":[0.01,0.004,0.006],"arm_angle_deg":0.002}"#,
        )
        .unwrap();
        let inputs = block.inputs();
        assert_eq!(inputs[0].u, [0.01, 0.004, 0.006]);
        assert!(inputs[0].given);
        assert_eq!(inputs[1].u, [0.5; 3]);
        assert!(!inputs[1].given);
        assert_eq!(inputs[6].u, [0.002; 3]);
        assert_eq!(inputs[1].describe(), "camera offset 0.5 mm (default)");
        assert_eq!(inputs[6].describe(), "arm angle 0.002 °");
        assert_eq!(three_significant(0.031234567890123), "0.0312");
        assert_eq!(three_significant(2.0), "2");
        assert_eq!(three_significant(123.456), "123");
        assert_eq!(three_significant(0.5), "0.5");
        assert_eq!(block.invalid(), None);
    }

    #[test]
    fn hostile_values_are_named() {
        let block: SetupUncertainty =
            serde_json::from_str(r#"{"cylinder_tilt_deg":-0.1}"#).unwrap();
        assert_eq!(block.invalid(), Some(("cylinder_tilt_deg", -0.1)));
        let block: SetupUncertainty =
            serde_json::from_str(r#"{"light_distance_mm":1e300}"#).unwrap();
        assert_eq!(block.invalid(), Some(("light_distance_mm", 1e300)));
        assert!(serde_json::from_str::<SetupUncertainty>(r#"{"yaw":1}"#).is_err());
        let block: SetupUncertainty = serde_json::from_str(r#"{"camera_yaw_deg":-0.01}"#).unwrap();
        assert_eq!(block.invalid(), Some(("camera_yaw_deg", -0.01)));
    }
}
