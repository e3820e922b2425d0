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
