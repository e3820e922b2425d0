//! Scene files: the setup, scan plan, sample, white reference, light, camera and the
//! optional effects a camera emulator renders.
//!
//! A scene is TOML (see `mock-hw/scenes/*.toml`); unknown keys and bad values are errors
//! naming the key. Sample parameters are in the camera-RGB β domain of paper eq. 4/5 (a
//! perfect white gives β_G = 100), the domain of fit results and `truth.json`.
//! Relative paths inside a scene file resolve against the file's directory.
#![doc = include_str!("scene.md")]
#![doc = include_str!("scene/rgl.md")]

mod empty_slot;
mod error;
pub mod material;
pub mod rgl;
mod sample;
pub mod spectral;
mod uncertainty;

use std::path::Path;

use serde::{Deserialize, Serialize};

use error::{check_non_negative, check_positive, invalid};
use material::Material;
use spectral::{CameraDomain, Spectrum};

pub use error::SceneError;
pub use sample::{BraggFlakes, Sample, ThinFilm};
pub use uncertainty::{SetupUncertainty, WhiteUncertainty};

/// The physical setup. Lengths in mm, pixel pitch in µm, rows and columns in pixels.
/// Field names match `processing::geometry::Setup` where they overlap (see
/// [`Scene::setup_json`]). This is the nominal setup, what setup.json states; the
/// optional [`Misalignment`] effect says how the rendered world differs from it.
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

    fn validate(&self) -> Result<(), SceneError> {
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

/// The scan a scene describes: light angles and shutter bracket.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct ScanFile {
    theta_l_deg: Vec<f64>,
    bracket_s: Vec<f64>,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct WhiteFile {
    reflectance: f64,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct LightFile {
    /// "illuminant-a" or a CSV path (`wavelength_nm,relative_power`, 390–730 nm).
    spectrum: String,
    intensity: f64,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    model: String,
    /// "nikon-d5100" or a CSV path (`wavelength_nm,r,g,b`, 390–730 nm).
    sensitivities: String,
    bit_depth: u32,
    black_level: u32,
    white_level: u32,
    iso: u32,
}

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
    /// The camera is this much farther from the axis than `setup.camera_distance_mm`, mm.
    pub camera_distance_error_mm: f64,
    /// The arm's repeatability: one error per θL of `[scan] theta_l_deg` (same length,
    /// or empty for none), added to that θL's light angle on top of
    /// `arm_zero_offset_deg`, degrees. An arm angle that is none of the scan's θL (to
    /// within [`ARM_ANGLE_MATCH_DEG`]) gets none.
    pub arm_angle_errors_deg: Vec<f64>,
}

/// Largest |yaw|, |tilt|, |arm zero offset| and |arm angle error| a scene may name,
/// degrees.
const MAX_MISALIGNMENT_DEG: f64 = 10.0;

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
    fn validate(
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

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    name: String,
    setup: SceneSetup,
    scan: ScanFile,
    sample: Sample,
    white: WhiteFile,
    light: LightFile,
    camera: CameraFile,
    #[serde(default)]
    effects: Effects,
}

/// The emulated camera body.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraBody {
    pub model: String,
    pub bit_depth: u32,
    pub black_level: u32,
    pub white_level: u32,
    pub iso: u32,
}

/// A loaded, validated scene, with what rendering needs precomputed.
#[derive(Debug, Clone)]
pub struct Scene {
    name: String,
    setup: SceneSetup,
    theta_l_deg: Vec<f64>,
    bracket_s: Vec<f64>,
    sample: Sample,
    white_reflectance: f64,
    light_intensity: f64,
    camera: CameraBody,
    effects: Effects,
    domain: CameraDomain,
    material: Material,
}

const GOLD: &str = include_str!("../scenes/gold.toml");
const RED: &str = include_str!("../scenes/red.toml");
const BLUE_GREEN: &str = include_str!("../scenes/blue-green.toml");
const OPAL: &str = include_str!("../scenes/opal.toml");

impl Scene {
    /// Reads a scene file; relative paths inside resolve against its directory.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = spectral::read_capped(path, gonio_files::input::MAX_SMALL_FILE_BYTES)?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::parse(&text, &path.display().to_string(), base)
    }

    /// Parses a scene; relative paths resolve against the working directory.
    pub fn from_toml_str(text: &str) -> Result<Scene, SceneError> {
        Self::parse(text, "(string)", Path::new("."))
    }

    /// One of the built-in scenes "gold", "red", "blue-green", "opal".
    pub fn builtin(name: &str) -> Option<Scene> {
        let text = match name {
            "gold" => GOLD,
            "red" => RED,
            "blue-green" => BLUE_GREEN,
            "opal" => OPAL,
            _ => return None,
        };
        Some(
            Self::parse(text, name, Path::new("."))
                .expect("built-in scenes are valid (checked by tests)"),
        )
    }

    /// Names of the built-in scenes.
    pub const BUILTIN: [&'static str; 4] = ["gold", "red", "blue-green", "opal"];

    fn parse(text: &str, origin: &str, base: &Path) -> Result<Scene, SceneError> {
        let file: SceneFile = toml::from_str(text).map_err(|e| SceneError::Parse {
            origin: origin.to_string(),
            message: crate::toml_error::one_line(text, &e),
        })?;
        file.setup.validate()?;
        if file.scan.theta_l_deg.is_empty() {
            return Err(invalid("scan.theta_l_deg", "must not be empty"));
        }
        if let Some(t) = file
            .scan
            .theta_l_deg
            .iter()
            .find(|t| !(t.is_finite() && (-90.0..=90.0).contains(*t)))
        {
            return Err(invalid(
                "scan.theta_l_deg",
                format!("{t} must be in [-90, 90]"),
            ));
        }
        if file.scan.bracket_s.is_empty() {
            return Err(invalid("scan.bracket_s", "must not be empty"));
        }
        for t in &file.scan.bracket_s {
            check_positive("scan.bracket_s", *t)?;
        }
        file.sample.validate()?;
        let white = file.white.reflectance;
        if !(white.is_finite() && white > 0.0 && white <= 1.5) {
            return Err(invalid("white.reflectance", "must be in (0, 1.5]"));
        }
        check_positive("light.intensity", file.light.intensity)?;
        let camera = file.camera;
        if !(8..=16).contains(&camera.bit_depth) {
            return Err(invalid("camera.bit_depth", "must be in 8..=16"));
        }
        let adc_max = (1u32 << camera.bit_depth) - 1;
        if camera.white_level > adc_max || camera.white_level <= camera.black_level {
            return Err(invalid(
                "camera.white_level",
                format!(
                    "{} must exceed black_level {} and fit {} bits",
                    camera.white_level, camera.black_level, camera.bit_depth
                ),
            ));
        }
        if !(25..=102_400).contains(&camera.iso) {
            return Err(invalid("camera.iso", "must be in 25..=102400"));
        }
        file.effects
            .validate(&file.setup, white, &file.scan.theta_l_deg)?;

        let resolve = |p: &str| {
            let p = Path::new(p);
            if p.is_absolute() {
                p.to_path_buf()
            } else {
                base.join(p)
            }
        };
        let light: Spectrum = match file.light.spectrum.as_str() {
            "illuminant-a" => spectral::illuminant_a(),
            path => spectral::read_table::<1>(&resolve(path))?[0],
        };
        let sensitivities = match camera.sensitivities.as_str() {
            "nikon-d5100" => spectral::nikon_d5100(),
            path => spectral::read_table::<3>(&resolve(path))?,
        };
        let domain = CameraDomain::new(&sensitivities, &light)?;
        let sample = match file.sample {
            Sample::Measured { path } => Sample::Measured {
                path: resolve(&path.to_string_lossy()),
            },
            Sample::Rgl { bsdf } => Sample::Rgl {
                bsdf: resolve(&bsdf.to_string_lossy()),
            },
            other => other,
        };
        let material = Material::new(&sample, &domain)?;
        Ok(Scene {
            name: file.name,
            setup: file.setup,
            theta_l_deg: file.scan.theta_l_deg,
            bracket_s: file.scan.bracket_s,
            sample,
            white_reflectance: white,
            light_intensity: file.light.intensity,
            camera: CameraBody {
                model: camera.model,
                bit_depth: camera.bit_depth,
                black_level: camera.black_level,
                white_level: camera.white_level,
                iso: camera.iso,
            },
            effects: file.effects,
            domain,
            material,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Light angles θL of a scan, degrees.
    pub fn theta_l_deg(&self) -> &[f64] {
        &self.theta_l_deg
    }

    /// Shutter times of the bracket, seconds.
    pub fn bracket_s(&self) -> &[f64] {
        &self.bracket_s
    }

    pub fn setup(&self) -> &SceneSetup {
        &self.setup
    }

    pub fn sample(&self) -> &Sample {
        &self.sample
    }

    /// Reflectance of the white reference (a Lambertian, spectrally flat), as stated.
    pub fn white_reflectance(&self) -> f64 {
        self.white_reflectance
    }

    /// Reflectance of the white reference as rendered: the stated one, times
    /// (1 + the misalignment's `white_reflectance_error`) when the scene names one.
    pub fn rendered_white_reflectance(&self) -> f64 {
        match &self.effects.misalignment {
            Some(m) => self.white_reflectance * (1.0 + m.white_reflectance_error),
            None => self.white_reflectance,
        }
    }

    /// Light intensity: raw G counts per second at ISO 100 of a perfect white facing
    /// light and camera at 1000 mm from the light.
    pub fn light_intensity(&self) -> f64 {
        self.light_intensity
    }

    pub fn camera(&self) -> &CameraBody {
        &self.camera
    }

    pub fn effects(&self) -> &Effects {
        &self.effects
    }

    /// The eq. 4/5 camera-RGB domain of this camera and light.
    pub fn camera_domain(&self) -> &CameraDomain {
        &self.domain
    }

    /// The sample prepared for rendering (its spectral radiance factor at a geometry:
    /// `Material::beta_spectrum`).
    pub fn material(&self) -> &Material {
        &self.material
    }

    /// Replaces the seed of noise and hot-pixel positions.
    pub fn set_seed(&mut self, seed: u64) {
        self.effects.seed = seed;
    }

    /// The same scene seen by a sensor binned `factor`×`factor`: image size divided,
    /// pixel pitch multiplied, principal point and strip rows mapped to the binned
    /// grid (rows to within one binned row). Fast tests and demos use it.
    pub fn binned(&self, factor: u32) -> Result<Scene, SceneError> {
        if factor == 0 || factor > self.setup.image_width.min(self.setup.image_height) {
            return Err(invalid(
                "binning factor",
                format!("{factor} does not fit the image"),
            ));
        }
        let k = f64::from(factor);
        let s = &self.setup;
        let setup = SceneSetup {
            pixel_pitch_um: s.pixel_pitch_um * k,
            image_width: s.image_width / factor,
            image_height: s.image_height / factor,
            principal_point_x: s.principal_point_x.map(|c| (c + 0.5) / k - 0.5),
            principal_point_y: s.principal_point_y.map(|c| (c + 0.5) / k - 0.5),
            sample_rows: s.sample_rows.map(|r| r / factor),
            white_rows: s.white_rows.map(|r| r / factor),
            ..s.clone()
        };
        setup.validate()?;
        Ok(Scene {
            setup,
            ..self.clone()
        })
    }

    /// Replaces the optional effects.
    pub fn set_effects(&mut self, effects: Effects) -> Result<(), SceneError> {
        effects.validate(&self.setup, self.white_reflectance, &self.theta_l_deg)?;
        self.effects = effects;
        Ok(())
    }

    /// Replaces the light angles of the scan (a misalignment's `arm_angle_errors_deg`,
    /// if any, must have one value per new angle).
    pub fn set_theta_l_deg(&mut self, theta_l_deg: Vec<f64>) -> Result<(), SceneError> {
        if theta_l_deg.is_empty() {
            return Err(invalid("scan.theta_l_deg", "must not be empty"));
        }
        if let Some(t) = theta_l_deg
            .iter()
            .find(|t| !(t.is_finite() && (-90.0..=90.0).contains(*t)))
        {
            return Err(invalid(
                "scan.theta_l_deg",
                format!("{t} must be in [-90, 90]"),
            ));
        }
        self.effects
            .validate(&self.setup, self.white_reflectance, &theta_l_deg)?;
        self.theta_l_deg = theta_l_deg;
        Ok(())
    }

    /// The nominal setup as `processing::geometry::Setup`'s JSON (setup.json): the
    /// geometry of `[setup]`, the white reference's reflectance and, when the scene
    /// names `[setup.uncertainty]`, its `uncertainty` block.
    pub fn setup_json(&self) -> serde_json::Value {
        let s = &self.setup;
        let mut json = serde_json::json!({
            "cylinder_radius_mm": s.cylinder_radius_mm,
            "camera_distance_mm": s.camera_distance_mm,
            "light_distance_mm": s.light_distance_mm,
            "focal_length_mm": s.focal_length_mm,
            "pixel_pitch_um": s.pixel_pitch_um,
            "image_width": s.image_width,
            "image_height": s.image_height,
            "principal_point_x": s.principal_point_x,
            "principal_point_y": s.principal_point_y,
            "sample_row": s.sample_row(),
            "white_row": s.white_row(),
            "white_reflectance": self.white_reflectance,
        });
        if let Some(uncertainty) = &s.uncertainty {
            json["uncertainty"] = serde_json::json!(uncertainty);
        }
        json
    }

    /// The true model parameters (camera-RGB β domain) as `truth.json`.
    pub fn truth_json(&self) -> serde_json::Value {
        let mut truth = serde_json::json!({
            "scene": self.name,
            "model": self.sample.model_name(),
            "white_reflectance": self.white_reflectance,
            "white_rgb": self.domain.white_rgb(),
        });
        let map = truth.as_object_mut().expect("truth is an object");
        let mut put = |k: &str, v: serde_json::Value| {
            map.insert(k.to_string(), v);
        };
        match &self.sample {
            Sample::Lambertian { kd } => put("kd", serde_json::json!(kd)),
            Sample::CookTorrance { kd, ks, m } | Sample::Ward { kd, ks, m } => {
                let shared = if m.len() == 1 {
                    "shared"
                } else {
                    "per-channel"
                };
                put("roughness", shared.into());
                put("kd", serde_json::json!(kd));
                put("ks", serde_json::json!(ks));
                put("m", serde_json::json!(m));
            }
            Sample::ThinFilm(film) => {
                spectral_lobe(&mut put, (&film.kd, film.ks, film.m), "film", film.truth())
            }
            Sample::BraggFlakes(flakes) => spectral_lobe(
                &mut put,
                (&flakes.kd, flakes.ks, flakes.m),
                "flakes",
                flakes.truth(),
            ),
            Sample::Measured { path } => put("table", path.display().to_string().into()),
            Sample::Rgl { bsdf } => put("bsdf", bsdf.display().to_string().into()),
        }
        if let Some(retro) = &self.effects.retro_reflection {
            put("retro_reflection", serde_json::json!(retro));
        }
        if let Some(misalignment) = &self.effects.misalignment {
            put("misalignment", serde_json::json!(misalignment));
        }
        truth
    }
}

/// `truth.json`'s keys of a lobe whose colour a spectral mechanism sets: Kd, one m, the
/// scale of the specular term, and the mechanism's parameters under `key`.
fn spectral_lobe(
    put: &mut impl FnMut(&str, serde_json::Value),
    (kd, ks_scale, m): (&[f64; 3], f64, f64),
    key: &str,
    mechanism: serde_json::Value,
) {
    put("roughness", "shared".into());
    put("kd", serde_json::json!(kd));
    put("m", serde_json::json!([m]));
    put("ks_scale", serde_json::json!(ks_scale));
    put(key, mechanism);
}
