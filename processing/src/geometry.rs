//! Cylinder setup geometry in 3D: which surface point, normal, light and viewing
//! directions each pixel sees (docs/ARCHITECTURE.md, "Angles and geometry").
//!
//! Frame: origin on the cylinder axis at the height of the camera centre; x parallel to
//! the camera's optical axis, from the cylinder toward the camera; z up, the axis the
//! light arm turns about; y = z × x (toward the image's right). The camera centre is at
//! (`camera_distance_mm`, `camera_offset_mm`, 0) looking along −x; pixel (u, v), with
//! its centre at coordinates (u, v), sees along (−f, (u − cx)·p, −(v − cy)·p) (columns
//! right of the principal point look toward +y, rows below it look down). The point
//! light is at `light_distance_mm` from the origin, in the plane z = 0, at the angle
//! θL + `arm_zero_offset_deg` counter-clockwise from +x. The cylinder's axis passes
//! through the origin along (0, sin τ, cos τ), τ = `cylinder_tilt_deg` (its top leans
//! toward +y). A surface point's azimuth φ is that of its normal, counter-clockwise
//! from +x about the cylinder's axis.
#![doc = include_str!("geometry.md")]

use serde::{Deserialize, Serialize};

use crate::brdf::Cosines;
use crate::decimal::Brief;
use crate::setup_uncertainty::{Input, SetupUncertainty, Source};
use crate::white_angular::{
    WhiteAngular, WhiteAngularError, WhiteTable, DEFAULT_FALLOFF, MAX_FALLOFF,
};

/// The physical setup of one scan. Lengths in millimetres, pixel pitch in micrometres,
/// angles in degrees; see the module documentation for the frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Setup {
    pub cylinder_radius_mm: f64,
    /// Distance of the camera centre from the cylinder axis along the optical axis.
    pub camera_distance_mm: f64,
    pub light_distance_mm: f64,
    pub focal_length_mm: f64,
    pub pixel_pitch_um: f64,
    pub image_width: u32,
    pub image_height: u32,
    /// Principal point column in pixels; `None` means the image centre, (width − 1)/2.
    #[serde(default)]
    pub principal_point_x: Option<f64>,
    /// Principal point row in pixels; `None` means the image centre, (height − 1)/2.
    #[serde(default)]
    pub principal_point_y: Option<f64>,
    /// Centre row of the sample strip.
    pub sample_row: u32,
    /// Centre row of the white-reference strip.
    pub white_row: u32,
    /// Reflectance of the white reference strip (1 = perfect reflecting diffuser);
    /// `None`: not recorded (extraction then takes 1).
    #[serde(default)]
    pub white_reflectance: Option<f64>,
    /// The white's falloff toward grazing incidence (relative; see
    /// [`crate::white_angular`]); `None`: the default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_falloff: Option<f64>,
    /// A certificate's table of the white's reflectance factor against the angle of
    /// incidence; it replaces the falloff.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_angular: Option<WhiteTable>,
    /// Sideways offset of the camera centre (+y, toward the image's right) from the
    /// plane through the cylinder axis parallel to the optical axis.
    #[serde(default)]
    pub camera_offset_mm: f64,
    /// Tilt of the cylinder axis about the optical axis, its top toward +y.
    #[serde(default)]
    pub cylinder_tilt_deg: f64,
    /// The light is at θL plus this (the arm's zero is off by this much).
    #[serde(default)]
    pub arm_zero_offset_deg: f64,
    /// Yaw of the camera about the vertical through its centre, counter-clockwise seen
    /// from above (the optical axis turned from −x toward −y).
    #[serde(default)]
    pub camera_yaw_deg: f64,
    /// Roll of the camera about its optical axis, the image's right turned toward its
    /// up (counter-clockwise seen from behind the camera).
    #[serde(default)]
    pub camera_roll_deg: f64,
    /// Standard uncertainties of the white reflectance, the geometry and the arm's angle
    /// (setup.json's `uncertainty` block; absent values take their defaults).
    #[serde(default, skip_serializing_if = "SetupUncertainty::is_empty")]
    pub uncertainty: SetupUncertainty,
}

/// What one pixel column sees on the cylinder, angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceAngles {
    pub phi: f64,
    pub theta_i: f64,
    pub theta_r: f64,
}

/// What one pixel sees on the cylinder: angles in degrees, the true 3D cosines, and the
/// point light's irradiance up to its intensity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelGeometry {
    /// Signed in-plane angles (specular at θr = θi) of the light and viewing directions
    /// projected on the cylinder's cross-section plane through the point.
    pub theta_i: f64,
    pub theta_r: f64,
    /// n·l, n·v, n·h, v·h of the true 3D directions.
    pub cosines: Cosines,
    /// cos θi / |L − P|², mm⁻² (0 where the point is not lit).
    pub irradiance: f64,
    /// Position of the point along the cylinder axis, mm (0 at the camera's height).
    pub height_mm: f64,
    /// The normal's components (n·ey, n·ex) in the plane ⊥ the axis, whence φ.
    azimuth: (f64, f64),
}

impl PixelGeometry {
    /// Azimuth φ of the point's normal about the cylinder axis, degrees.
    pub fn phi(&self) -> f64 {
        self.azimuth.0.atan2(self.azimuth.1).to_degrees()
    }
}

/// How the light reaches one pixel's point (the white strip's share of
/// [`PixelGeometry`]): cos θi of the true 3D direction and the irradiance up to the
/// light's intensity, cos θi / |L − P|² in mm⁻²; only for a lit point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Lighting {
    pub n_dot_l: f64,
    pub irradiance: f64,
}

/// A range of a setup field as a message writes it: `[min, max]`, or `(0, max]` for the
/// positive values up to `max` (a lower bound of the least positive number).
fn range_text(min: f64, max: f64) -> String {
    if min == f64::MIN_POSITIVE {
        format!("(0, {}]", Brief(max))
    } else {
        format!("[{}, {}]", Brief(min), Brief(max))
    }
}

/// Why a [`Setup`] cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    #[error("setup field `{field}` must be finite and positive, got {}", Brief(*.value))]
    NotPositive { field: &'static str, value: f64 },
    #[error("setup field `{field}` must be finite, got {}", Brief(*.value))]
    NotFinite { field: &'static str, value: f64 },
    #[error("setup field `{field}` is {}, outside {}", Brief(*.value), range_text(*.min, *.max))]
    OutOfRange {
        field: &'static str,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error("the {what} ({} mm from the axis) must lie outside the cylinder of radius {} mm", Brief(*.distance), Brief(*.radius))]
    InsideCylinder {
        what: &'static str,
        distance: f64,
        radius: f64,
    },
    #[error("setup field `{field}` must be 1 to {MAX_IMAGE_SIDE} pixels, got {value}")]
    ImageSize { field: &'static str, value: u32 },
    #[error(
        "setup field `uncertainty.{key}` must be a standard uncertainty in [0, {max}], got {value}"
    )]
    Uncertainty {
        key: &'static str,
        value: f64,
        max: f64,
    },
    #[error(transparent)]
    WhiteAngular(#[from] WhiteAngularError),
    #[error("setup field `{field}` = {value} is not a row of the {height}-row image")]
    RowOutside {
        field: &'static str,
        value: u32,
        height: u32,
    },
}

/// Largest image side a setup may describe, pixels (per-column tables are sized from it).
pub const MAX_IMAGE_SIDE: u32 = 100_000;

/// Largest |tilt| and |arm zero offset| a setup may state, degrees.
pub const MAX_MISALIGNMENT_DEG: f64 = 30.0;

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(a: [f64; 3], k: f64) -> [f64; 3] {
    a.map(|x| x * k)
}

/// The setup's frame, precomputed: camera centre, axis direction and image scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SetupFrame {
    pub camera: [f64; 3],
    /// Unit direction of the cylinder axis.
    pub axis: [f64; 3],
    /// The camera's component ⊥ the axis, and its position along it (mm).
    camera_perp: [f64; 3],
    camera_along: f64,
    /// Unit vectors ⊥ the axis from which φ is measured: φ = atan2(n·ey, n·ex).
    ex: [f64; 3],
    ey: [f64; 3],
    pub radius: f64,
    /// f times the unit optical axis, and the unit image right and up vectors.
    forward: [f64; 3],
    right: [f64; 3],
    up: [f64; 3],
    /// Pixel pitch, mm.
    pitch: f64,
    cx: f64,
    cy: f64,
}

/// A setup's frame and its light's position for one θL ([`Setup::view`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SetupView {
    frame: SetupFrame,
    light: [f64; 3],
}

impl SetupView {
    /// [`Setup::pixel_geometry`] of pixel (u, v).
    pub(crate) fn pixel_geometry(&self, u: f64, v: f64) -> Option<PixelGeometry> {
        let hit = self.frame.hit(u, v)?;
        Some(self.frame.geometry(&hit, self.light))
    }

    /// The [`Lighting`] of pixel (u, v); `None` where it misses the cylinder or is unlit.
    pub(crate) fn lighting(&self, u: f64, v: f64) -> Option<Lighting> {
        let hit = self.frame.hit(u, v)?;
        lighting(hit.normal, sub(self.light, hit.point))
    }
}

/// [`Lighting`] at a point of unit normal `n` seen from it at `to_light`; `None` where
/// the light is behind the surface.
fn lighting(n: [f64; 3], to_light: [f64; 3]) -> Option<Lighting> {
    let l2 = dot(to_light, to_light);
    let n_l = dot(to_light, n);
    (n_l > 0.0 && l2 > 0.0).then(|| {
        let distance = l2.sqrt();
        Lighting {
            n_dot_l: n_l / distance,
            irradiance: n_l / (l2 * distance),
        }
    })
}

/// A ray's nearest meeting with the cylinder.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Hit {
    pub point: [f64; 3],
    pub normal: [f64; 3],
}

impl SetupFrame {
    /// Direction (not unit) of the ray through pixel (u, v).
    pub fn ray(&self, u: f64, v: f64) -> [f64; 3] {
        let (x, y) = ((u - self.cx) * self.pitch, -(v - self.cy) * self.pitch);
        std::array::from_fn(|k| self.forward[k] + x * self.right[k] + y * self.up[k])
    }

    /// The ray's closest approach to the axis, in the plane ⊥ the axis: the point Q
    /// (component ⊥ axis), the unit direction of the ray's ⊥ component and that
    /// component itself. Computed with cross products, so a distant camera loses no
    /// precision. `None` for a ray parallel to the axis.
    fn closest_approach(&self, d: [f64; 3]) -> Option<([f64; 3], [f64; 3], [f64; 3])> {
        let a = self.axis;
        let d_perp = sub(d, scale(a, dot(d, a)));
        let len = dot(d_perp, d_perp).sqrt();
        if !(len.is_finite() && len > 0.0) {
            return None;
        }
        let dh = scale(d_perp, 1.0 / len);
        // (d̂ × C) × d̂ = C − (C·d̂)d̂.
        Some((cross(cross(dh, self.camera_perp), dh), dh, d_perp))
    }

    /// Signed distance of the ray through (u, v) from the axis (mm): positive when the
    /// ray passes the axis on the +y side (toward larger φ as seen from the camera).
    pub fn signed_axis_distance(&self, u: f64, v: f64) -> f64 {
        match self.closest_approach(self.ray(u, v)) {
            Some((q, dh, _)) => dot(cross(q, dh), self.axis).signum() * dot(q, q).sqrt(),
            None => f64::NAN,
        }
    }

    /// Where the ray through (u, v) first meets the cylinder, if it does (not grazing).
    pub fn hit(&self, u: f64, v: f64) -> Option<Hit> {
        let d = self.ray(u, v);
        let (q, dh, d_perp) = self.closest_approach(d)?;
        let half_chord_sq = self.radius * self.radius - dot(q, q);
        if !(half_chord_sq.is_finite() && half_chord_sq > 0.0) {
            return None;
        }
        let half_chord = half_chord_sq.sqrt();
        let a = self.axis;
        let p_perp = sub(q, scale(dh, half_chord));
        // Distance along d̂⊥ from the camera's ⊥ component to the hit, then along d.
        let along = dot(sub(p_perp, self.camera_perp), dh);
        let d_perp_len = dot(d_perp, dh);
        let s = along / d_perp_len;
        if !(s.is_finite() && s > 0.0) {
            return None;
        }
        let axial = self.camera_along + s * dot(d, a);
        Some(Hit {
            point: [
                p_perp[0] + axial * a[0],
                p_perp[1] + axial * a[1],
                p_perp[2] + axial * a[2],
            ],
            normal: scale(p_perp, 1.0 / self.radius),
        })
    }

    /// Position along the axis of a point.
    pub fn height(&self, point: [f64; 3]) -> f64 {
        dot(point, self.axis)
    }

    /// Everything a model needs at a hit, for a light at `light`.
    pub fn geometry(&self, hit: &Hit, light: [f64; 3]) -> PixelGeometry {
        let n = hit.normal;
        let to_light = sub(light, hit.point);
        let to_camera = sub(self.camera, hit.point);
        let tangent = cross(self.axis, n);
        let theta_i = dot(to_light, tangent).atan2(dot(to_light, n));
        let theta_r = -dot(to_camera, tangent).atan2(dot(to_camera, n));
        PixelGeometry {
            theta_i: theta_i.to_degrees(),
            theta_r: theta_r.to_degrees(),
            cosines: Cosines::from_directions(n, to_light, to_camera),
            irradiance: lighting(n, to_light).map_or(0.0, |l| l.irradiance),
            height_mm: self.height(hit.point),
            azimuth: (dot(n, self.ey), dot(n, self.ex)),
        }
    }
}

impl Setup {
    /// Checks that the setup describes a real geometry: positive lengths, the camera and
    /// the light outside the cylinder, image sides up to [`MAX_IMAGE_SIDE`] with the
    /// strip rows inside, finite principal point and misalignments within
    /// ±[`MAX_MISALIGNMENT_DEG`], a white reflectance in (0, 2].
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
        let finite = [
            ("principal_point_x", self.principal_point_x),
            ("principal_point_y", self.principal_point_y),
            ("camera_offset_mm", Some(self.camera_offset_mm)),
        ];
        for (field, value) in finite {
            if let Some(value) = value.filter(|v| !v.is_finite()) {
                return Err(GeometryError::NotFinite { field, value });
            }
        }
        let ranged = [
            (
                "cylinder_tilt_deg",
                self.cylinder_tilt_deg,
                -MAX_MISALIGNMENT_DEG,
                MAX_MISALIGNMENT_DEG,
            ),
            (
                "arm_zero_offset_deg",
                self.arm_zero_offset_deg,
                -MAX_MISALIGNMENT_DEG,
                MAX_MISALIGNMENT_DEG,
            ),
            (
                "camera_yaw_deg",
                self.camera_yaw_deg,
                -MAX_MISALIGNMENT_DEG,
                MAX_MISALIGNMENT_DEG,
            ),
            (
                "camera_roll_deg",
                self.camera_roll_deg,
                -MAX_MISALIGNMENT_DEG,
                MAX_MISALIGNMENT_DEG,
            ),
            (
                "white_reflectance",
                self.white_reflectance.unwrap_or(1.0),
                f64::MIN_POSITIVE,
                2.0,
            ),
            (
                "white_falloff",
                self.white_falloff.unwrap_or(DEFAULT_FALLOFF),
                -MAX_FALLOFF,
                MAX_FALLOFF,
            ),
        ];
        for (field, value, min, max) in ranged {
            if !(value >= min && value <= max) {
                return Err(GeometryError::OutOfRange {
                    field,
                    value,
                    min,
                    max,
                });
            }
        }
        if let Some(table) = &self.white_angular {
            table.validate()?;
            if self.white_falloff.is_some() {
                return Err(WhiteAngularError {
                    field: "white_falloff",
                    reason: "give either a falloff or a `white_angular` table, not both".into(),
                }
                .into());
            }
        }
        if let Some((key, value)) = self.uncertainty.invalid() {
            return Err(GeometryError::Uncertainty {
                key,
                value,
                max: crate::setup_uncertainty::MAX_UNCERTAINTY,
            });
        }
        let camera_perp = self.frame().camera_perp;
        for (what, distance) in [
            ("camera", dot(camera_perp, camera_perp).sqrt()),
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

    /// Principal point row in pixels: the given one or the image centre (height − 1)/2.
    pub fn principal_row(&self) -> f64 {
        self.principal_point_y
            .unwrap_or((f64::from(self.image_height) - 1.0) / 2.0)
    }

    /// The white reference's reflectance, 1 (a perfect reflecting diffuser) when the
    /// setup does not record it.
    pub fn white_reflectance(&self) -> f64 {
        self.white_reflectance.unwrap_or(1.0)
    }

    /// The white's angular dependence: setup.json's table, else its falloff (default
    /// [`DEFAULT_FALLOFF`]) with the `uncertainty` block's `white_falloff` (or its default).
    pub fn white_angular(&self) -> WhiteAngular<'_> {
        match &self.white_angular {
            Some(table) => WhiteAngular::Table(table),
            None => WhiteAngular::Falloff {
                a: self.white_falloff.unwrap_or(DEFAULT_FALLOFF),
                u: self
                    .uncertainty
                    .white_falloff
                    .unwrap_or(Source::WhiteFalloff.default_uncertainty()),
            },
        }
    }

    /// Every source's standard uncertainty ([`SetupUncertainty::inputs`]), the white's
    /// falloff taken from a certificate's table where setup.json gives one (its
    /// uncertainty at grazing, stated).
    pub fn inputs(&self) -> [Input; Source::COUNT] {
        let mut inputs = self.uncertainty.inputs();
        if self.white_angular.is_some() {
            for input in inputs
                .iter_mut()
                .filter(|i| i.source == Source::WhiteFalloff)
            {
                input.u = [self.white_angular().grazing_uncertainty(); 3];
                input.given = true;
            }
        }
        inputs
    }

    /// The frame of this setup (see the module documentation).
    pub(crate) fn frame(&self) -> SetupFrame {
        let tilt = self.cylinder_tilt_deg.to_radians();
        let axis = [0.0, tilt.sin(), tilt.cos()];
        let ex = [1.0, 0.0, 0.0];
        let (sin_y, cos_y) = self.camera_yaw_deg.to_radians().sin_cos();
        let (sin_r, cos_r) = self.camera_roll_deg.to_radians().sin_cos();
        // Yawed: optical axis (−cos ψ, −sin ψ, 0), right (−sin ψ, cos ψ, 0), up +z; the
        // roll then turns right and up about the optical axis.
        let (right, up) = ([-sin_y, cos_y, 0.0], [0.0, 0.0, 1.0]);
        let f = self.focal_length_mm;
        let camera = [self.camera_distance_mm, self.camera_offset_mm, 0.0];
        let camera_along = dot(camera, axis);
        SetupFrame {
            camera,
            axis,
            camera_perp: sub(camera, scale(axis, camera_along)),
            camera_along,
            ex,
            ey: cross(axis, ex),
            radius: self.cylinder_radius_mm,
            forward: [-f * cos_y, -f * sin_y, 0.0],
            right: std::array::from_fn(|k| cos_r * right[k] + sin_r * up[k]),
            up: std::array::from_fn(|k| cos_r * up[k] - sin_r * right[k]),
            pitch: self.pixel_pitch_um * 1e-3,
            cx: self.principal_point(),
            cy: self.principal_row(),
        }
    }

    /// Position of the point light for the arm at `theta_l_deg`.
    pub(crate) fn light_position(&self, theta_l_deg: f64) -> [f64; 3] {
        let angle = (theta_l_deg + self.arm_zero_offset_deg).to_radians();
        [
            self.light_distance_mm * angle.cos(),
            self.light_distance_mm * angle.sin(),
            0.0,
        ]
    }

    /// What pixel (u, v) (centre at those coordinates) sees for a light at
    /// `theta_l_deg`, or `None` when its ray misses the cylinder (or only grazes it).
    /// |θi| ≥ 90° (irradiance 0) means the point is not lit; callers that need lit
    /// points filter on it. Assumes a valid setup ([`Setup::validate`]).
    pub fn pixel_geometry(&self, u: f64, v: f64, theta_l_deg: f64) -> Option<PixelGeometry> {
        self.view(theta_l_deg).pixel_geometry(u, v)
    }

    /// The frame and the light for `theta_l_deg`, computed once for many pixels.
    pub(crate) fn view(&self, theta_l_deg: f64) -> SetupView {
        SetupView {
            frame: self.frame(),
            light: self.light_position(theta_l_deg),
        }
    }

    /// The in-plane angles seen by pixel column `u` on the principal point's row (the
    /// plane of the light for an untilted cylinder), or `None` when the ray misses.
    ///
    /// θi is the signed angle from the normal to the light direction and θr minus the
    /// signed angle from the normal to the viewing direction (both counter-clockwise), so
    /// the distant limit gives θi = θL − φ and θr = φ.
    pub fn angles_at_column(&self, u: f64, theta_l_deg: f64) -> Option<SurfaceAngles> {
        self.pixel_geometry(u, self.principal_row(), theta_l_deg)
            .map(|g| SurfaceAngles {
                phi: g.phi(),
                theta_i: g.theta_i,
                theta_r: g.theta_r,
            })
    }
}

/// (φ, θi, θr) in degrees of every pixel column (index = column) on the principal
/// point's row for a light at `theta_l_deg`, with the finite camera and light distances
/// of `setup`; `None` where the column misses the cylinder. An invalid setup (see
/// [`Setup::validate`]) gives all `None`.
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
