//! The optional `[effects]` a camera emulator renders: noise, vignetting, a non-linear
//! response, hot pixels, retro-reflection and misalignment of the rendered world
//! against the nominal setup.

use serde::{Deserialize, Serialize};

use super::error::{check_non_negative, check_positive, invalid, SceneError};
use super::setup::SceneSetup;

/// Shot noise (Gaussian approximation of Poisson) and read noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Noise {
    /// Conversion gain at ISO 100, electrons per raw count; divided by ISO/100.
    pub electrons_per_dn: f64,
    /// Read noise, standard deviation in raw counts.
    pub read_noise_dn: f64,
}

/// Natural vignetting: gain (1 − s) + s·cos⁴ of the pixel ray's off-axis angle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Vignetting {
    pub strength: f64,
}

/// 8-bit, JPEG-like response: y = x^(1/gamma) of the normalised linear value, quantised
/// to 8 bits and stored ×257 in the 16-bit file (sidecar `"response":"nonlinear"`,
/// black level 0, white level 65535).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Response {
    pub gamma: f64,
}

/// Stuck pixels: `count` pixels at seeded positions read the white level in every
/// channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HotPixels {
    pub count: u32,
}

/// A retro-reflection lobe added to the sample: β_c += kr_c·exp(−tan²(γ/2)/w²), γ the
/// angle between the light and view directions, w = tan(width_deg).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RetroReflection {
    pub kr: [f64; 3],
    pub width_deg: f64,
}

/// How the rendered world differs from the nominal `[setup]` (which setup.json states),
/// as in a real lab that measured it imperfectly. Every key defaults to 0. Naming this
/// table renders every pixel by its own ray in 3D, with the strips as bands on the
/// cylinder (between the heights the nominal strip rows see at the cylinder's front);
/// without it the faster separable renderer runs, with strips as image rows.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Misalignment {
    /// The camera centre moved sideways by this (toward +y, the image's right), mm.
    pub camera_offset_mm: f64,
    /// The camera turned about the vertical through its centre, counter-clockwise seen
    /// from above (its optical axis from −x toward −y: the cylinder moves toward the
    /// image's right), degrees.
    pub camera_yaw_deg: f64,
    /// The camera turned about its optical axis after the yaw, the image's right toward
    /// its up (counter-clockwise seen from behind the camera: the scene turns clockwise
    /// in the image), degrees.
    pub camera_roll_deg: f64,
    /// The cylinder's axis turned about the world x axis, its top toward +y (leaning
    /// right in the image), degrees; the arm still turns about the vertical.
    pub cylinder_tilt_deg: f64,
    /// The light stands at θL plus this (the arm's zero is off), degrees.
    pub arm_zero_offset_deg: f64,
    /// The light is this much farther from the axis than `setup.light_distance_mm`, mm.
    pub light_distance_error_mm: f64,
    /// The rendered white reference's reflectance is `white.reflectance` × (1 + this)
    /// (setup.json keeps stating the nominal one); relative.
    pub white_reflectance_error: f64,
    /// The white's falloff toward grazing departs from the stated `[white] falloff` by
    /// this: its reflectance renders × (1 − a·(1 − cos θi)), a the sum, θi the light's
    /// angle of incidence on it (setup.json keeps stating the nominal one); relative,
    /// within ±`MAX_WHITE_FALLOFF`.
    pub white_falloff: f64,
    /// The camera is this much farther from the axis than `setup.camera_distance_mm`, mm.
    pub camera_distance_error_mm: f64,
    /// The arm's repeatability: one error per θL of `[scan] theta_l_deg` (same length,
    /// or empty for none), added to that θL's light angle on top of
    /// `arm_zero_offset_deg`, degrees. An arm angle that is none of the scan's θL (to
    /// within [`ARM_ANGLE_MATCH_DEG`]) gets none.
    pub arm_angle_errors_deg: Vec<f64>,
}

/// Largest |yaw|, |roll|, |tilt|, |arm zero offset| and |arm angle error| a scene may name,
/// degrees.
const MAX_MISALIGNMENT_DEG: f64 = 10.0;

/// Largest |white falloff| a scene may name (the factor stays within [0.5, 1.5]).
pub const MAX_WHITE_FALLOFF: f64 = 0.5;

/// Largest rendered white reflectance a white reflectance error may give.
const MAX_RENDERED_WHITE: f64 = 2.0;

/// How close an arm angle must be to one of the scan's θL to take its
/// `arm_angle_errors_deg` entry: half the 0.001° the arm's G-code resolves, degrees.
pub const ARM_ANGLE_MATCH_DEG: f64 = 5e-4;

impl Misalignment {
    /// The arm angle error of the light at arm angle `theta_l_deg` in a scan of the
    /// light angles `scan_theta_l_deg` (the scene's `[scan] theta_l_deg`), degrees.
    pub fn arm_angle_error_deg(&self, scan_theta_l_deg: &[f64], theta_l_deg: f64) -> f64 {
        scan_theta_l_deg
            .iter()
            .zip(&self.arm_angle_errors_deg)
            .find(|(t, _)| (*t - theta_l_deg).abs() <= ARM_ANGLE_MATCH_DEG)
            .map_or(0.0, |(_, e)| *e)
    }

    /// Checks the values against the nominal `setup`, the stated white reflectance and
    /// the scan's light angles.
    fn validate(
        &self,
        setup: &SceneSetup,
        white_reflectance: f64,
        theta_l_deg: &[f64],
    ) -> Result<(), SceneError> {
        for (key, value) in [
            ("effects.misalignment.camera_yaw_deg", self.camera_yaw_deg),
            ("effects.misalignment.camera_roll_deg", self.camera_roll_deg),
            (
                "effects.misalignment.cylinder_tilt_deg",
                self.cylinder_tilt_deg,
            ),
            (
                "effects.misalignment.arm_zero_offset_deg",
                self.arm_zero_offset_deg,
            ),
        ] {
            if !(value.is_finite() && value.abs() <= MAX_MISALIGNMENT_DEG) {
                return Err(invalid(
                    key,
                    format!("{value} must be in [-{MAX_MISALIGNMENT_DEG}, {MAX_MISALIGNMENT_DEG}]"),
                ));
            }
        }
        let gap = setup.camera_distance_mm - setup.cylinder_radius_mm;
        if !(self.camera_offset_mm.is_finite() && self.camera_offset_mm.abs() < 0.5 * gap) {
            return Err(invalid(
                "effects.misalignment.camera_offset_mm",
                format!(
                    "{} must be smaller in size than half the camera's gap to the cylinder ({} mm)",
                    self.camera_offset_mm,
                    0.5 * gap
                ),
            ));
        }
        if !(self.camera_distance_error_mm.is_finite()
            && self.camera_distance_error_mm.abs() < 0.5 * gap)
        {
            return Err(invalid(
                "effects.misalignment.camera_distance_error_mm",
                format!(
                    "{} must be smaller in size than half the camera's gap to the cylinder ({} mm)",
                    self.camera_distance_error_mm,
                    0.5 * gap
                ),
            ));
        }
        let light = setup.light_distance_mm + self.light_distance_error_mm;
        if !(light.is_finite() && light > setup.cylinder_radius_mm) {
            return Err(invalid(
                "effects.misalignment.light_distance_error_mm",
                "puts the light inside the cylinder",
            ));
        }
        let white = white_reflectance * (1.0 + self.white_reflectance_error);
        if !(self.white_reflectance_error.is_finite()
            && self.white_reflectance_error > -1.0
            && white <= MAX_RENDERED_WHITE)
        {
            return Err(invalid(
                "effects.misalignment.white_reflectance_error",
                format!(
                    "{} must exceed -1 and keep the rendered reflectance at most {MAX_RENDERED_WHITE}",
                    self.white_reflectance_error
                ),
            ));
        }
        if !(self.white_falloff.is_finite() && self.white_falloff.abs() <= MAX_WHITE_FALLOFF) {
            return Err(invalid(
                "effects.misalignment.white_falloff",
                format!(
                    "{} must be in [-{MAX_WHITE_FALLOFF}, {MAX_WHITE_FALLOFF}]",
                    self.white_falloff
                ),
            ));
        }
        let errors = &self.arm_angle_errors_deg;
        if !errors.is_empty() && errors.len() != theta_l_deg.len() {
            return Err(invalid(
                "effects.misalignment.arm_angle_errors_deg",
                format!(
                    "has {} values for the scan's {} light angles",
                    errors.len(),
                    theta_l_deg.len()
                ),
            ));
        }
        if let Some(e) = errors
            .iter()
            .find(|e| !(e.is_finite() && e.abs() <= MAX_MISALIGNMENT_DEG))
        {
            return Err(invalid(
                "effects.misalignment.arm_angle_errors_deg",
                format!("{e} must be in [-{MAX_MISALIGNMENT_DEG}, {MAX_MISALIGNMENT_DEG}]"),
            ));
        }
        Ok(())
    }
}

/// The optional effects; each is off unless the scene names it.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Effects {
    /// Seed of noise and hot-pixel positions.
    #[serde(default)]
    pub seed: u64,
    pub noise: Option<Noise>,
    pub vignetting: Option<Vignetting>,
    pub response: Option<Response>,
    pub hot_pixels: Option<HotPixels>,
    pub retro_reflection: Option<RetroReflection>,
    pub misalignment: Option<Misalignment>,
}

impl Effects {
    /// Checks the effects of a scene with this nominal `setup`, stated white reflectance
    /// and scan light angles.
    pub(super) fn validate(
        &self,
        setup: &SceneSetup,
        white_reflectance: f64,
        theta_l_deg: &[f64],
    ) -> Result<(), SceneError> {
        if let Some(m) = &self.misalignment {
            m.validate(setup, white_reflectance, theta_l_deg)?;
        }
        if let Some(noise) = &self.noise {
            check_positive("effects.noise.electrons_per_dn", noise.electrons_per_dn)?;
            check_non_negative("effects.noise.read_noise_dn", &[noise.read_noise_dn])?;
        }
        if let Some(v) = &self.vignetting {
            if !(0.0..=1.0).contains(&v.strength) {
                return Err(invalid("effects.vignetting.strength", "must be in [0, 1]"));
            }
        }
        if let Some(r) = &self.response {
            if !(r.gamma.is_finite() && (0.2..=5.0).contains(&r.gamma)) {
                return Err(invalid("effects.response.gamma", "must be in [0.2, 5]"));
            }
        }
        if let Some(h) = &self.hot_pixels {
            if h.count > 100_000 {
                return Err(invalid(
                    "effects.hot_pixels.count",
                    "must be at most 100000",
                ));
            }
        }
        if let Some(r) = &self.retro_reflection {
            check_non_negative("effects.retro_reflection.kr", &r.kr)?;
            if !(r.width_deg > 0.0 && r.width_deg < 80.0) {
                return Err(invalid(
                    "effects.retro_reflection.width_deg",
                    "must be in (0, 80)",
                ));
            }
        }
        Ok(())
    }
}
