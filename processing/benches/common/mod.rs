//! Scaffolding shared by the benchmarks: the paper's setup (Nikon D200-sized sensor)
//! and its six light angles.

use gonio_processing::geometry::Setup;

/// The six θL of a full scan, degrees.
pub const THETA_L: [f64; 6] = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];

/// A 3872×2592 sensor at 6.1 µm behind an 85 mm lens, 700 mm from a 40 mm cylinder.
pub fn d200_setup() -> Setup {
    Setup {
        cylinder_radius_mm: 40.0,
        camera_distance_mm: 700.0,
        light_distance_mm: 1000.0,
        focal_length_mm: 85.0,
        pixel_pitch_um: 6.1,
        image_width: 3872,
        image_height: 2592,
        principal_point_x: None,
        sample_row: 1100,
        white_row: 1491,
        principal_point_y: None,
        white_reflectance: None,
        camera_offset_mm: 0.0,
        cylinder_tilt_deg: 0.0,
        arm_zero_offset_deg: 0.0,
        camera_yaw_deg: 0.0,
        camera_roll_deg: 0.0,
        white_falloff: None,
        white_angular: None,
        uncertainty: Default::default(),
    }
}
