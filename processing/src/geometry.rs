//! Cylinder setup geometry: which (φ, θi, θr) each pixel column sees.
//!
//! World frame: the horizontal plane through the cylinder axis, origin on the axis,
//! angles counter-clockwise from +x. The camera sits at angle 0 (on +x) at
//! `camera_distance_mm` looking at the axis; the point light at angle θL at
//! `light_distance_mm`. A surface point at azimuth φ has its normal at angle φ.
//! Image columns: pixel `u` has its centre at coordinate `u`; a column right of the
//! principal point (u > cx) looks toward +y, i.e. toward larger φ.

use serde::{Deserialize, Serialize};

/// The physical setup of one scan. Lengths in millimetres, pixel pitch in micrometres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Setup {
    pub cylinder_radius_mm: f64,
    pub camera_distance_mm: f64,
    pub light_distance_mm: f64,
    pub focal_length_mm: f64,
    pub pixel_pitch_um: f64,
    pub image_width: u32,
    pub image_height: u32,
    /// Principal point column in pixels; `None` means the image centre, (width − 1)/2.
    #[serde(default)]
    pub principal_point_x: Option<f64>,
    /// Centre row of the sample strip.
    pub sample_row: u32,
    /// Centre row of the white-reference strip.
    pub white_row: u32,
}

/// What one pixel column sees on the cylinder, angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceAngles {
    pub phi: f64,
    pub theta_i: f64,
    pub theta_r: f64,
}

/// Why a [`Setup`] cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    #[error("setup field `{field}` must be finite and positive, got {value}")]
    NotPositive { field: &'static str, value: f64 },
    #[error("setup field `{field}` must be finite, got {value}")]
    NotFinite { field: &'static str, value: f64 },
    #[error("the {what} ({distance} mm from the axis) must lie outside the cylinder of radius {radius} mm")]
    InsideCylinder {
        what: &'static str,
        distance: f64,
        radius: f64,
    },
    #[error("setup field `{field}` must be 1 to {MAX_IMAGE_SIDE} pixels, got {value}")]
    ImageSize { field: &'static str, value: u32 },
    #[error("setup field `{field}` = {value} is not a row of the {height}-row image")]
    RowOutside {
        field: &'static str,
        value: u32,
        height: u32,
    },
}

/// Largest image side a setup may describe, pixels (per-column tables are sized from it).
pub const MAX_IMAGE_SIDE: u32 = 100_000;

impl Setup {
    /// Checks that the setup describes a real geometry: positive lengths, the camera and
    /// the light outside the cylinder, a finite principal point.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let positive = [
            ("cylinder_radius_mm", self.cylinder_radius_mm),
            ("camera_distance_mm", self.camera_distance_mm),
            ("light_distance_mm", self.light_distance_mm),
            ("focal_length_mm", self.focal_length_mm),
            ("pixel_pitch_um", self.pixel_pitch_um),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(GeometryError::NotPositive { field, value });
            }
        }
        for (field, value) in [
            ("image_width", self.image_width),
            ("image_height", self.image_height),
        ] {
            if !(1..=MAX_IMAGE_SIDE).contains(&value) {
                return Err(GeometryError::ImageSize { field, value });
            }
        }
        for (field, value) in [
            ("sample_row", self.sample_row),
            ("white_row", self.white_row),
        ] {
            if value >= self.image_height {
                return Err(GeometryError::RowOutside {
                    field,
                    value,
                    height: self.image_height,
                });
            }
        }
        if let Some(cx) = self.principal_point_x {
            if !cx.is_finite() {
                return Err(GeometryError::NotFinite {
                    field: "principal_point_x",
                    value: cx,
                });
            }
        }
        for (what, distance) in [
            ("camera", self.camera_distance_mm),
            ("light", self.light_distance_mm),
        ] {
            if distance <= self.cylinder_radius_mm {
                return Err(GeometryError::InsideCylinder {
                    what,
                    distance,
                    radius: self.cylinder_radius_mm,
                });
            }
        }
        Ok(())
    }

    /// Principal point column in pixels: the given one or the image centre (width − 1)/2.
    pub fn principal_point(&self) -> f64 {
        self.principal_point_x
            .unwrap_or((f64::from(self.image_width) - 1.0) / 2.0)
    }

    /// The surface point seen by pixel column `u` (centre at coordinate `u`) for a light at
    /// `theta_l_deg`, or `None` when the column's ray misses the cylinder (or only grazes it).
    ///
    /// θi is the signed angle from the normal to the light direction and θr minus the
    /// signed angle from the normal to the viewing direction (both counter-clockwise), so
    /// the distant limit gives θi = θL − φ and θr = φ. |θi| ≥ 90° means the point is
    /// not lit; callers that need lit points filter on it.
    pub fn angles_at_column(&self, u: f64, theta_l_deg: f64) -> Option<SurfaceAngles> {
        let radius = self.cylinder_radius_mm;
        let camera = [self.camera_distance_mm, 0.0];
        // Ray from the camera centre: along −x, tilted toward +y for u > cx.
        let lateral_mm = (u - self.principal_point()) * self.pixel_pitch_um * 1e-3;
        let norm = self.focal_length_mm.hypot(lateral_mm);
        let dir = [-self.focal_length_mm / norm, lateral_mm / norm];
        // Closest point of the ray to the axis, (C·e)e with e ⟂ dir; then step back along
        // the ray to the near intersection. This form stays exact for distant cameras.
        let e = [-dir[1], dir[0]];
        let offset = camera[0] * e[0] + camera[1] * e[1];
        let half_chord_sq = radius * radius - offset * offset;
        if half_chord_sq.is_nan() || half_chord_sq <= 0.0 {
            return None;
        }
        let half_chord = half_chord_sq.sqrt();
        let p = [
            offset * e[0] - half_chord * dir[0],
            offset * e[1] - half_chord * dir[1],
        ];
        let phi = p[1].atan2(p[0]);
        let normal = [phi.cos(), phi.sin()];
        let theta_l = theta_l_deg.to_radians();
        let light = [
            self.light_distance_mm * theta_l.cos(),
            self.light_distance_mm * theta_l.sin(),
        ];
        let to_light = [light[0] - p[0], light[1] - p[1]];
        let to_camera = [camera[0] - p[0], camera[1] - p[1]];
        let theta_i = signed_angle(normal, to_light);
        let theta_r = -signed_angle(normal, to_camera);
        Some(SurfaceAngles {
            phi: phi.to_degrees(),
            theta_i: theta_i.to_degrees(),
            theta_r: theta_r.to_degrees(),
        })
    }
}

/// Signed counter-clockwise angle in radians from unit vector `from` to vector `to`.
fn signed_angle(from: [f64; 2], to: [f64; 2]) -> f64 {
    let cross = from[0] * to[1] - from[1] * to[0];
    let dot = from[0] * to[0] + from[1] * to[1];
    cross.atan2(dot)
}

/// (φ, θi, θr) in degrees of every pixel column (index = column) for a light at
/// `theta_l_deg`, with the finite camera and light distances of `setup`; `None` where the
/// column misses the cylinder. An invalid setup (see [`Setup::validate`]) gives all `None`.
pub fn column_angles(setup: &Setup, theta_l_deg: f64) -> Vec<Option<SurfaceAngles>> {
    let valid = setup.validate().is_ok() && theta_l_deg.is_finite();
    (0..setup.image_width)
        .map(|u| {
            if valid {
                setup.angles_at_column(f64::from(u), theta_l_deg)
            } else {
                None
            }
        })
        .collect()
}
