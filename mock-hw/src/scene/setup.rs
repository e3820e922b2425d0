//! The `[setup]` table: the nominal geometry of cylinder, camera and light, the strip
//! rows, and the standard uncertainties setup.json states.

use gonio_files::input::DEFAULT_MAX_FRAME_PIXELS;
use serde::{Deserialize, Serialize};

use super::error::{check_positive, invalid, SceneError};
use super::uncertainty::SetupUncertainty;

/// The physical setup. Lengths in mm, pixel pitch in µm, rows and columns in pixels.
/// Field names match `processing::geometry::Setup` where they overlap (see
/// [`Scene::setup_json`](super::Scene::setup_json)). This is the nominal setup, what
/// setup.json states; the optional [`Misalignment`](super::Misalignment) effect says how
/// the rendered world differs from it.
///
/// World frame: origin on the (vertical) cylinder axis, z up; the camera centre at
/// (`camera_distance_mm`, 0, 0) looking at the axis, optical axis horizontal; the
/// point light at angle θL, distance `light_distance_mm`, in the horizontal plane z = 0
/// through the camera centre. Columns right of the principal point look toward +y
/// (larger azimuth φ); rows below it look down. Strips whose rows lie symmetric about
/// `principal_point_y` see identical light (mirror symmetry about z = 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSetup {
    pub cylinder_radius_mm: f64,
    pub camera_distance_mm: f64,
    pub light_distance_mm: f64,
    pub focal_length_mm: f64,
    pub pixel_pitch_um: f64,
    pub image_width: u32,
    pub image_height: u32,
    /// Principal point column; `None`: (width − 1)/2.
    #[serde(default)]
    pub principal_point_x: Option<f64>,
    /// Principal point row; `None`: (height − 1)/2.
    #[serde(default)]
    pub principal_point_y: Option<f64>,
    /// First and last row (inclusive) of the sample strip.
    pub sample_rows: [u32; 2],
    /// First and last row (inclusive) of the white-reference strip.
    pub white_rows: [u32; 2],
    /// `[setup.uncertainty]`: the standard uncertainties setup.json states; `None`:
    /// setup.json has no `uncertainty` block (its defaults apply).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<SetupUncertainty>,
}

impl SceneSetup {
    pub fn cx(&self) -> f64 {
        self.principal_point_x
            .unwrap_or((f64::from(self.image_width) - 1.0) / 2.0)
    }

    pub fn cy(&self) -> f64 {
        self.principal_point_y
            .unwrap_or((f64::from(self.image_height) - 1.0) / 2.0)
    }

    /// Centre row of the sample strip.
    pub fn sample_row(&self) -> u32 {
        (self.sample_rows[0] + self.sample_rows[1]) / 2
    }

    /// Centre row of the white strip.
    pub fn white_row(&self) -> u32 {
        (self.white_rows[0] + self.white_rows[1]) / 2
    }

    /// Height along the cylinder axis (mm, 0 at the camera's height) that sensor row
    /// coordinate `row` sees at the front of the cylinder (the point nearest the camera)
    /// in the nominal geometry.
    pub fn front_height_mm(&self, row: f64) -> f64 {
        let depth = self.camera_distance_mm - self.cylinder_radius_mm;
        -depth / self.focal_length_mm * (row - self.cy()) * self.pixel_pitch_um / 1000.0
    }

    pub(super) fn validate(&self) -> Result<(), SceneError> {
        let positive = [
            ("setup.cylinder_radius_mm", self.cylinder_radius_mm),
            ("setup.camera_distance_mm", self.camera_distance_mm),
            ("setup.light_distance_mm", self.light_distance_mm),
            ("setup.focal_length_mm", self.focal_length_mm),
            ("setup.pixel_pitch_um", self.pixel_pitch_um),
        ];
        for (key, value) in positive {
            check_positive(key, value)?;
        }
        if self.camera_distance_mm <= self.cylinder_radius_mm {
            return Err(invalid(
                "setup.camera_distance_mm",
                "must exceed the cylinder radius",
            ));
        }
        if self.light_distance_mm <= self.cylinder_radius_mm {
            return Err(invalid(
                "setup.light_distance_mm",
                "must exceed the cylinder radius",
            ));
        }
        if self.image_width == 0 || self.image_width > 20_000 {
            return Err(invalid("setup.image_width", "must be in 1..=20000"));
        }
        if self.image_height == 0 || self.image_height > 20_000 {
            return Err(invalid("setup.image_height", "must be in 1..=20000"));
        }
        // A frame gonio's readers would refuse is not rendered.
        let pixels = u64::from(self.image_width) * u64::from(self.image_height);
        if pixels > DEFAULT_MAX_FRAME_PIXELS {
            return Err(invalid(
                "setup.image_width × setup.image_height",
                format!(
                    "{pixels} pixels, more than the {DEFAULT_MAX_FRAME_PIXELS} gonio \
                     decodes by default (max_frame_pixels)"
                ),
            ));
        }
        for (key, value) in [
            ("setup.principal_point_x", self.principal_point_x),
            ("setup.principal_point_y", self.principal_point_y),
        ] {
            if value.is_some_and(|v| !v.is_finite()) {
                return Err(invalid(key, "must be a finite number"));
            }
        }
        for (key, rows) in [
            ("setup.sample_rows", self.sample_rows),
            ("setup.white_rows", self.white_rows),
        ] {
            if rows[0] > rows[1] || rows[1] >= self.image_height {
                return Err(invalid(
                    key,
                    format!(
                        "[{}, {}] must be ascending rows inside the image height {}",
                        rows[0], rows[1], self.image_height
                    ),
                ));
            }
        }
        let [s0, s1] = self.sample_rows;
        let [w0, w1] = self.white_rows;
        if s0 <= w1 && w0 <= s1 {
            return Err(invalid("setup.white_rows", "overlaps setup.sample_rows"));
        }
        if let Some(uncertainty) = &self.uncertainty {
            uncertainty.validate()?;
        }
        Ok(())
    }
}
