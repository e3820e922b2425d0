//! The sample prepared for rendering: the camera-RGB colour of spectral lobes
//! integrated once over the facet incidence, measured tables and `.bsdf` files read and
//! converted, when the scene loads (so an unreadable table is an error of the scene).
//! The renderer evaluates a [`Material`] at a surface point (`render::brdf`).

use std::path::Path;

use super::error::SceneError;
use super::rgl::{RglBsdf, RglMaterial};
use super::sample::Sample;
use super::spectral::{self, CameraDomain, Spectrum, BANDS};

/// Unpolarised reflectance of a thin film: medium n0 | film n1, thickness d | substrate
/// n2, light at incidence cosine `cos0` in the medium (Airy summation, real indices).
pub fn thin_film_reflectance(
    cos0: f64,
    lambda_nm: f64,
    n0: f64,
    n1: f64,
    n2: f64,
    d_nm: f64,
) -> f64 {
    let c0 = cos0.clamp(0.0, 1.0);
    let s0 = (1.0 - c0 * c0).sqrt();
    let refract = |n: f64| {
        let s = n0 * s0 / n;
        (1.0 - s * s).max(0.0).sqrt()
    };
    let (c1, c2) = (refract(n1), refract(n2));
    let cos_delta = (4.0 * std::f64::consts::PI * n1 * d_nm * c1 / lambda_nm).cos();
    let airy = |r01: f64, r12: f64| {
        let cross = 2.0 * r01 * r12 * cos_delta;
        (r01 * r01 + r12 * r12 + cross) / (1.0 + r01 * r01 * r12 * r12 + cross)
    };
    let ratio = |a: f64, b: f64| if a + b > 0.0 { (a - b) / (a + b) } else { 0.0 };
    let rs = airy(ratio(n0 * c0, n1 * c1), ratio(n1 * c1, n2 * c2));
    let rp = airy(ratio(n1 * c0, n0 * c1), ratio(n2 * c1, n1 * c2));
    0.5 * (rs + rp)
}

/// Entries of the thin-film and Bragg tables over the facet incidence cosine l·h ∈ [0, 1].
const FILM_TABLE_STEPS: usize = 1024;

/// The first-order Bragg reflection band of a periodic multilayer (a photonic crystal):
/// a Gaussian band of unit peak whose centre follows the Bragg–Snell law
/// λc(θ) = λ0·√(1 − sin²θ/n²) for light at incidence θ on the layers, n the stack's
/// effective index.
#[derive(Debug, Clone, PartialEq)]
pub struct BraggBand {
    pub wavelength_nm: f64,
    pub effective_index: f64,
    pub width_nm: f64,
}

impl BraggBand {
    /// Reflectance spectrum at facet incidence cosine `cos0`.
    pub fn spectrum(&self, cos0: f64) -> Spectrum {
        let c = cos0.clamp(0.0, 1.0);
        let n2 = self.effective_index * self.effective_index;
        let centre = self.wavelength_nm * (1.0 - (1.0 - c * c) / n2).max(0.0).sqrt();
        std::array::from_fn(|i| {
            let x = (spectral::wavelength_nm(i) - centre) / self.width_nm;
            (-0.5 * x * x).exp()
        })
    }
}

/// `scale`·camera RGB of `spectrum(l·h)` at l·h = k/[`FILM_TABLE_STEPS`].
fn incidence_table(
    domain: &CameraDomain,
    scale: f64,
    spectrum: impl Fn(f64) -> Spectrum,
) -> Vec<[f64; 3]> {
    (0..=FILM_TABLE_STEPS)
        .map(|k| {
            let rgb = domain.rgb(&spectrum(k as f64 / FILM_TABLE_STEPS as f64));
            rgb.map(|v| scale * v)
        })
        .collect()
}

/// Linear interpolation of an [`incidence_table`] at l·h = `v_h`.
pub(crate) fn table_at(table: &[[f64; 3]], v_h: f64) -> [f64; 3] {
    let x = v_h.clamp(0.0, 1.0) * FILM_TABLE_STEPS as f64;
    let k = (x as usize).min(FILM_TABLE_STEPS - 1);
    let t = x - k as f64;
    let (a, b) = (table[k], table[k + 1]);
    std::array::from_fn(|c| a[c] + t * (b[c] - a[c]))
}

/// Film parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Film {
    pub thickness_nm: f64,
    pub index: f64,
    pub medium_index: f64,
    pub substrate_index: f64,
}

impl Film {
    /// R_film(λ) at facet incidence cosine `cos0`.
    pub fn spectrum(&self, cos0: f64) -> Spectrum {
        std::array::from_fn(|i| {
            thin_film_reflectance(
                cos0,
                spectral::wavelength_nm(i),
                self.medium_index,
                self.index,
                self.substrate_index,
                self.thickness_nm,
            )
        })
    }
}

/// What sets the colour of a [`Material::SpectralLobe`]'s facets.
#[derive(Debug, Clone, PartialEq)]
pub enum Reflector {
    /// A thin film on the facets (thin-film interference).
    Film(Film),
    /// Flakes of a periodic multilayer (first-order Bragg reflection).
    Bragg(BraggBand),
}

impl Reflector {
    /// Reflectance spectrum at facet incidence cosine `cos0`.
    pub fn spectrum(&self, cos0: f64) -> Spectrum {
        match self {
            Reflector::Film(film) => film.spectrum(cos0),
            Reflector::Bragg(band) => band.spectrum(cos0),
        }
    }
}

/// Largest measured table file read: a 1° grid over ±90° (181² rows of 35 values) is
/// about 15 MB; a scene may name any path (even `/dev/zero`).
const MAX_MEASURED_BYTES: u64 = 64 << 20;

/// A measured table on a regular (θi, θr) grid, spectral and as camera RGB.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    theta_i: Vec<f64>,
    theta_r: Vec<f64>,
    /// Row-major [θi][θr].
    spectra: Vec<Spectrum>,
    rgb: Vec<[f64; 3]>,
}

impl Table {
    fn read(path: &Path, domain: &CameraDomain) -> Result<Self, SceneError> {
        let text = spectral::read_capped(path, MAX_MEASURED_BYTES)?;
        let what = path.display().to_string();
        let bad = |line: usize, reason: String| SceneError::Table {
            what: what.clone(),
            line,
            reason,
        };
        let mut rows: Vec<(f64, f64, Spectrum)> = Vec::new();
        for (index, line) in text.lines().enumerate().skip(1) {
            let line = line.trim();
            if line.is_empty() {
                continue;
            }
            let values: Vec<f64> = line
                .split(',')
                .map(|s| s.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
                .collect::<Option<_>>()
                .ok_or_else(|| bad(index + 1, "a value is not a finite number".into()))?;
            if values.len() != BANDS + 2 {
                return Err(bad(
                    index + 1,
                    format!("expected {} columns, found {}", BANDS + 2, values.len()),
                ));
            }
            let spectrum: Spectrum = std::array::from_fn(|i| values[i + 2]);
            rows.push((values[0], values[1], spectrum));
        }
        let axis = |pick: fn(&(f64, f64, Spectrum)) -> f64| {
            let mut v: Vec<f64> = rows.iter().map(pick).collect();
            v.sort_by(f64::total_cmp);
            v.dedup();
            v
        };
        let theta_i = axis(|r| r.0);
        let theta_r = axis(|r| r.1);
        let lines = text.lines().count();
        if theta_i.len() < 2 || theta_r.len() < 2 || rows.len() != theta_i.len() * theta_r.len() {
            return Err(bad(
                lines,
                format!(
                    "{} rows do not form a full grid of at least 2×2 (θi, θr)",
                    rows.len()
                ),
            ));
        }
        let mut spectra = vec![[0.0; BANDS]; rows.len()];
        let mut seen = vec![false; rows.len()];
        for (ti, tr, s) in rows {
            let i = theta_i.partition_point(|v| *v < ti);
            let j = theta_r.partition_point(|v| *v < tr);
            let k = i * theta_r.len() + j;
            if seen[k] {
                return Err(bad(lines, format!("duplicate row θi {ti}, θr {tr}")));
            }
            seen[k] = true;
            spectra[k] = s;
        }
        let rgb = spectra.iter().map(|s| domain.rgb(s)).collect();
        Ok(Self {
            theta_i,
            theta_r,
            spectra,
            rgb,
        })
    }

    /// Bilinear weights on the grid, angles clamped to its range.
    fn corners(&self, theta_i: f64, theta_r: f64) -> [(usize, f64); 4] {
        let locate = |axis: &[f64], x: f64| {
            let x = x.clamp(axis[0], axis[axis.len() - 1]);
            let hi = axis.partition_point(|v| *v < x).clamp(1, axis.len() - 1);
            let t = (x - axis[hi - 1]) / (axis[hi] - axis[hi - 1]);
            (hi - 1, t)
        };
        let (i, ti) = locate(&self.theta_i, theta_i);
        let (j, tj) = locate(&self.theta_r, theta_r);
        let n = self.theta_r.len();
        [
            (i * n + j, (1.0 - ti) * (1.0 - tj)),
            (i * n + j + 1, (1.0 - ti) * tj),
            ((i + 1) * n + j, ti * (1.0 - tj)),
            ((i + 1) * n + j + 1, ti * tj),
        ]
    }

    /// Camera RGB at (θi, θr) in degrees, bilinear, angles clamped to the grid.
    pub(crate) fn rgb_at(&self, theta_i: f64, theta_r: f64) -> [f64; 3] {
        let mut out = [0.0; 3];
        for (k, w) in self.corners(theta_i, theta_r) {
            for (o, v) in out.iter_mut().zip(self.rgb[k]) {
                *o += w * v;
            }
        }
        out
    }

    /// Spectral radiance factor at (θi, θr) in degrees, bilinear, angles clamped to the
    /// grid.
    pub(crate) fn spectrum_at(&self, theta_i: f64, theta_r: f64) -> Spectrum {
        let mut out = [0.0; BANDS];
        for (k, w) in self.corners(theta_i, theta_r) {
            for (o, v) in out.iter_mut().zip(self.spectra[k]) {
                *o += w * v;
            }
        }
        out
    }
}

/// A sample prepared for rendering.
#[derive(Debug, Clone, PartialEq)]
pub enum Material {
    Lambertian {
        kd: [f64; 3],
    },
    CookTorrance {
        kd: [f64; 3],
        ks: [f64; 3],
        m: [f64; 3],
    },
    Ward {
        kd: [f64; 3],
        ks: [f64; 3],
        m: [f64; 3],
    },
    /// A Cook–Torrance lobe of slope roughness `m` whose facets reflect the spectrum
    /// R(λ, l·h) of `reflector`, over a diffuse base:
    /// ks·R(λ, l·h)·D·G/(π (n·l)(n·v)) + Kd(λ). R enters camera RGB linearly, so it is
    /// integrated once into `table`: ks·camera-RGB of R at l·h = k/(steps), linear
    /// interpolation in between (below 1e-4 relative error for the built-in 156 nm film,
    /// checked by the tests; thicker films oscillate faster in l·h).
    SpectralLobe {
        kd: [f64; 3],
        kd_spectrum: Box<Spectrum>,
        ks: f64,
        m: f64,
        reflector: Reflector,
        table: Vec<[f64; 3]>,
    },
    Measured(Table),
    /// An RGL-EPFL `.bsdf` file, prepared for the scene's camera and light.
    Rgl(Box<RglMaterial>),
}

fn roughness3(m: &[f64]) -> [f64; 3] {
    match m {
        [m] => [*m; 3],
        _ => std::array::from_fn(|c| m[c]),
    }
}

impl Material {
    /// Prepares a validated sample.
    pub fn new(sample: &Sample, domain: &CameraDomain) -> Result<Self, SceneError> {
        Ok(match sample {
            Sample::Lambertian { kd } => Material::Lambertian { kd: *kd },
            Sample::CookTorrance { kd, ks, m } => Material::CookTorrance {
                kd: *kd,
                ks: *ks,
                m: roughness3(m),
            },
            Sample::Ward { kd, ks, m } => Material::Ward {
                kd: *kd,
                ks: *ks,
                m: roughness3(m),
            },
            Sample::ThinFilm(film) => Material::spectral_lobe(
                domain,
                (film.kd, film.ks, film.m),
                Reflector::Film(Film {
                    thickness_nm: film.film_thickness_nm,
                    index: film.film_index,
                    medium_index: film.medium_index,
                    substrate_index: film.substrate_index,
                }),
            ),
            Sample::BraggFlakes(flakes) => Material::spectral_lobe(
                domain,
                (flakes.kd, flakes.ks, flakes.m),
                Reflector::Bragg(BraggBand {
                    wavelength_nm: flakes.wavelength_nm,
                    effective_index: flakes.effective_index,
                    width_nm: flakes.band_width_nm,
                }),
            ),
            Sample::Measured { path } => Material::Measured(Table::read(path, domain)?),
            Sample::Rgl { bsdf } => {
                let material =
                    RglMaterial::new(RglBsdf::read(bsdf)?, domain).map_err(|reason| {
                        SceneError::Bsdf {
                            path: bsdf.clone(),
                            reason,
                        }
                    })?;
                Material::Rgl(Box::new(material))
            }
        })
    }

    /// A [`Material::SpectralLobe`] of diffuse camera RGB `kd`, scale `ks` and
    /// roughness `m`, its camera-RGB table integrated once.
    fn spectral_lobe(
        domain: &CameraDomain,
        (kd, ks, m): ([f64; 3], f64, f64),
        reflector: Reflector,
    ) -> Self {
        Material::SpectralLobe {
            kd,
            kd_spectrum: Box::new(domain.spectrum_from_rgb(kd)),
            ks,
            m,
            table: incidence_table(domain, ks, |c| reflector.spectrum(c)),
            reflector,
        }
    }
}
