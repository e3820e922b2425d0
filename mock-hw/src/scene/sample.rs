//! The sample as a scene file describes it, and its validation.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::error::{check_non_negative, check_positive, invalid, SceneError};

/// The sample as written in a scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Sample {
    /// β_c = kd_c.
    Lambertian { kd: [f64; 3] },
    /// β_c = ks_c·D·G/(π (n·l)(n·v)) + kd_c (docs/ARCHITECTURE.md, F = 1).
    CookTorrance {
        kd: [f64; 3],
        ks: [f64; 3],
        m: Vec<f64>,
    },
    /// β_c = kd_c/π + ks_c·exp(−tan²α/m²)/(4π m² √(cosθi cosθr)).
    Ward {
        kd: [f64; 3],
        ks: [f64; 3],
        m: Vec<f64>,
    },
    /// A thin dielectric film on rough facets over a diffuse base ([`ThinFilm`]).
    ThinFilm(ThinFilm),
    /// Photonic-crystal flakes in a clear binder over a diffuse base ([`BraggFlakes`]).
    BraggFlakes(BraggFlakes),
    /// A measured table in the reference CSV format (`theta_i,theta_r,390,…,730`, a
    /// full regular grid of spectral radiance factor).
    Measured { path: PathBuf },
    /// An RGL-EPFL measured material: a `.bsdf` tensor file (RGB or spectral,
    /// isotropic), evaluated as its reference evaluator does (`scene::rgl`).
    Rgl { bsdf: PathBuf },
}

fn default_medium_index() -> f64 {
    1.5
}

/// A thin dielectric film (interference) on facets of slope roughness `m` over a diffuse
/// base: β(λ) = ks·R_film(λ, l·h)·D·G/(π (n·l)(n·v)) + Kd(λ), R_film the unpolarised Airy
/// reflectance of medium | film | substrate; Kd(λ) the smooth spectrum whose camera RGB
/// is `kd`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThinFilm {
    pub kd: [f64; 3],
    pub ks: f64,
    pub m: f64,
    pub film_thickness_nm: f64,
    pub film_index: f64,
    #[serde(default = "default_medium_index")]
    pub medium_index: f64,
    pub substrate_index: f64,
}

impl ThinFilm {
    fn validate(&self) -> Result<(), SceneError> {
        check_lobe(&self.kd, self.ks, self.m)?;
        check_positive("sample.film_thickness_nm", self.film_thickness_nm)?;
        check_index("sample.medium_index", self.medium_index, 1.0)?;
        check_index("sample.film_index", self.film_index, self.medium_index)?;
        check_index(
            "sample.substrate_index",
            self.substrate_index,
            self.medium_index,
        )
    }

    /// `truth.json`'s `film` object.
    pub(super) fn truth(&self) -> serde_json::Value {
        serde_json::json!({
            "thickness_nm": self.film_thickness_nm,
            "film_index": self.film_index,
            "medium_index": self.medium_index,
            "substrate_index": self.substrate_index,
        })
    }
}

/// Flakes of a photonic crystal (a periodic multilayer) in a clear binder over a
/// diffuse base, a goniochromatic mechanism other than the thin film's: each flake
/// reflects a Gaussian band of unit peak and width `band_width_nm` centred at
/// λc = `wavelength_nm`·√(1 − sin²θd/n²) (Bragg–Snell, n = `effective_index`, θd the
/// incidence on the flake), flake slopes of roughness `m` as the thin film's facets:
/// β(λ) = ks·R(λ, θd)·D·G/(π (n·l)(n·v)) + Kd(λ), Kd(λ) the smooth spectrum whose
/// camera RGB is `kd`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BraggFlakes {
    pub kd: [f64; 3],
    pub ks: f64,
    pub m: f64,
    pub wavelength_nm: f64,
    pub effective_index: f64,
    pub band_width_nm: f64,
}

impl BraggFlakes {
    fn validate(&self) -> Result<(), SceneError> {
        check_lobe(&self.kd, self.ks, self.m)?;
        let wavelength_nm = self.wavelength_nm;
        if !(wavelength_nm.is_finite() && (300.0..=1000.0).contains(&wavelength_nm)) {
            return Err(invalid(
                "sample.wavelength_nm",
                format!("{wavelength_nm} must be in [300, 1000]"),
            ));
        }
        check_index("sample.effective_index", self.effective_index, 1.0)?;
        let band_width_nm = self.band_width_nm;
        if !(band_width_nm.is_finite() && (1.0..=500.0).contains(&band_width_nm)) {
            return Err(invalid(
                "sample.band_width_nm",
                format!("{band_width_nm} must be in [1, 500]"),
            ));
        }
        Ok(())
    }

    /// `truth.json`'s `flakes` object.
    pub(super) fn truth(&self) -> serde_json::Value {
        serde_json::json!({
            "bragg_wavelength_nm": self.wavelength_nm,
            "effective_index": self.effective_index,
            "band_width_nm": self.band_width_nm,
        })
    }
}

/// The lobe a spectral mechanism colours: diffuse camera RGB, specular scale, one m.
fn check_lobe(kd: &[f64; 3], ks: f64, m: f64) -> Result<(), SceneError> {
    check_non_negative("sample.kd", kd)?;
    check_non_negative("sample.ks", &[ks])?;
    roughness("sample.m", &[m]).map(drop)
}

impl Sample {
    /// The model name used in `truth.json`.
    pub fn model_name(&self) -> &'static str {
        match self {
            Sample::Lambertian { .. } => "lambertian",
            Sample::CookTorrance { .. } => "cook-torrance",
            Sample::Ward { .. } => "ward",
            Sample::ThinFilm(_) => "thin-film",
            Sample::BraggFlakes(_) => "bragg-flakes",
            Sample::Measured { .. } => "measured",
            Sample::Rgl { .. } => "rgl",
        }
    }

    /// Whether rendering needs spectral bands (goniochromatic or measured spectra).
    pub fn is_spectral(&self) -> bool {
        matches!(
            self,
            Sample::ThinFilm(_)
                | Sample::BraggFlakes(_)
                | Sample::Measured { .. }
                | Sample::Rgl { .. }
        )
    }

    /// Checks the values, naming the key of a bad one.
    pub(super) fn validate(&self) -> Result<(), SceneError> {
        match self {
            Sample::Lambertian { kd } => check_non_negative("sample.kd", kd),
            Sample::CookTorrance { kd, ks, m } | Sample::Ward { kd, ks, m } => {
                check_non_negative("sample.kd", kd)?;
                check_non_negative("sample.ks", ks)?;
                roughness("sample.m", m).map(drop)
            }
            Sample::ThinFilm(film) => film.validate(),
            Sample::BraggFlakes(flakes) => flakes.validate(),
            Sample::Measured { .. } | Sample::Rgl { .. } => Ok(()),
        }
    }
}

/// A refractive index in [lowest, 5] (film and substrate at least the medium's, so no
/// total internal reflection occurs).
fn check_index(key: &str, n: f64, lowest: f64) -> Result<(), SceneError> {
    if n.is_finite() && (lowest..=5.0).contains(&n) {
        Ok(())
    } else {
        Err(invalid(key, format!("{n} must be in [{lowest}, 5]")))
    }
}

/// Roughness `m` given as one shared value or one per channel.
fn roughness(key: &str, m: &[f64]) -> Result<[f64; 3], SceneError> {
    let m3 = match m {
        [m] => [*m; 3],
        [r, g, b] => [*r, *g, *b],
        _ => return Err(invalid(key, "give one value or three (R, G, B)")),
    };
    for v in m3 {
        if !(v.is_finite() && v >= 1e-3) {
            return Err(invalid(key, format!("{v} must be a number ≥ 0.001")));
        }
    }
    Ok(m3)
}
