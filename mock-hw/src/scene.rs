//! Scene files: the setup, scan plan, sample, white reference, light, camera and the
//! optional effects a camera emulator renders.
//!
//! A scene is TOML (see `mock-hw/scenes/*.toml`); unknown keys and bad values are errors
//! naming the key. Sample parameters are in the camera-RGB β domain of paper eq. 4/5 (a
//! perfect white gives β_G = 100), the domain of fit results and `truth.json`.
//! Relative paths inside a scene file resolve against the file's directory.
#![doc = include_str!("scene.md")]
#![doc = include_str!("scene/rgl.md")]

mod effects;
mod empty_slot;
mod error;
pub mod material;
pub mod rgl;
mod sample;
mod setup;
pub mod spectral;
mod uncertainty;

use std::path::Path;

use gonio_files::scan_layout::same_theta_dir;
use serde::Deserialize;

use effects::MAX_WHITE_FALLOFF;
use error::{check_positive, invalid};
use material::Material;
use spectral::{CameraDomain, Spectrum};

pub use effects::{
    Effects, HotPixels, Misalignment, Noise, Response, RetroReflection, Vignetting,
    ARM_ANGLE_MATCH_DEG,
};
pub use error::SceneError;
pub use sample::{BraggFlakes, Sample, ThinFilm};
pub use setup::SceneSetup;
pub use uncertainty::{SetupUncertainty, WhiteUncertainty};

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
    /// The white's falloff toward grazing, stated in setup.json and rendered; 0: Lambertian.
    #[serde(default)]
    falloff: f64,
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
    white_falloff: f64,
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
        check_theta_l(&file.scan.theta_l_deg)?;
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
        let falloff = file.white.falloff;
        if !(falloff.is_finite() && falloff.abs() <= MAX_WHITE_FALLOFF) {
            return Err(invalid(
                "white.falloff",
                format!("{falloff} must be in [-{MAX_WHITE_FALLOFF}, {MAX_WHITE_FALLOFF}]"),
            ));
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
            white_falloff: falloff,
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

    /// The white's falloff toward grazing as rendered (its reflectance × (1 − a·(1 − cos θi))):
    /// the stated `[white] falloff` plus the misalignment's `white_falloff`.
    pub fn rendered_white_falloff(&self) -> f64 {
        self.white_falloff
            + self
                .effects
                .misalignment
                .as_ref()
                .map_or(0.0, |m| m.white_falloff)
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
        // The scene was valid unbinned: what fails now is the binning's.
        setup.validate().map_err(|e| {
            invalid(
                "binning factor",
                format!(
                    "{factor} is too coarse for this scene (binned {}×{}: {e})",
                    setup.image_width, setup.image_height
                ),
            )
        })?;
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
        check_theta_l(&theta_l_deg)?;
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
            "white_falloff": self.white_falloff,
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

/// The light angles of a scan: some, each within [−90°, 90°], no two in one θL
/// directory (named to 0.1°: `theta_l_-30.0`).
fn check_theta_l(theta_l_deg: &[f64]) -> Result<(), SceneError> {
    if theta_l_deg.is_empty() {
        return Err(invalid("scan.theta_l_deg", "must not be empty"));
    }
    for (i, &t) in theta_l_deg.iter().enumerate() {
        if !(t.is_finite() && (-90.0..=90.0).contains(&t)) {
            return Err(invalid(
                "scan.theta_l_deg",
                format!("{t} must be in [-90, 90]"),
            ));
        }
        if let Some(same) = theta_l_deg[..i].iter().find(|s| same_theta_dir(**s, t)) {
            return Err(invalid(
                "scan.theta_l_deg",
                format!("{t} is listed twice (as {same} before, to 0.1°)"),
            ));
        }
    }
    Ok(())
}
