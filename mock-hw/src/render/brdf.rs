//! Reflection models in vector form (half vector, n·h, v·h from 3D directions),
//! independent of processing's angle-form code. β is the radiance factor in the
//! camera-RGB domain (a perfect white gives β_G = 100).

use std::path::Path;

use crate::scene::spectral::{self, CameraDomain, Spectrum, BANDS};
use crate::scene::{Sample, SceneError};

/// Cosines below this are clamped, so grazing geometry stays finite.
const MIN_COS: f64 = 1e-4;

/// The local geometry at one surface point. `cos_i` = n·l, `cos_r` = n·v, `l_dot_v` =
/// l·v with unit vectors; `theta_i_deg`/`theta_r_deg` the signed in-plane angles
/// (specular at θr = θi) of the directions projected on the horizontal plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geom {
    pub cos_i: f64,
    pub cos_r: f64,
    /// n·h with h the unit half vector.
    pub n_h: f64,
    /// v·h (= l·h).
    pub v_h: f64,
    pub l_dot_v: f64,
    pub theta_i_deg: f64,
    pub theta_r_deg: f64,
}

impl Geom {
    /// From the cosines of unit vectors n·l, n·v, l·v (h = (l + v)/|l + v|).
    pub fn new(cos_i: f64, cos_r: f64, l_dot_v: f64, theta_i_deg: f64, theta_r_deg: f64) -> Self {
        let h_len = (2.0 + 2.0 * l_dot_v).max(1e-12).sqrt();
        Self {
            cos_i,
            cos_r,
            n_h: ((cos_i + cos_r) / h_len).clamp(0.0, 1.0),
            v_h: ((1.0 + l_dot_v) / h_len).clamp(MIN_COS, 1.0),
            l_dot_v,
            theta_i_deg,
            theta_r_deg,
        }
    }

    /// In-plane geometry of a distant light and viewer at signed angles (degrees).
    pub fn in_plane(theta_i_deg: f64, theta_r_deg: f64) -> Self {
        let (ti, tr) = (theta_i_deg.to_radians(), theta_r_deg.to_radians());
        // n = (1, 0), l = (cos θi, sin θi), v = (cos θr, −sin θr).
        let l_dot_v = ti.cos() * tr.cos() - ti.sin() * tr.sin();
        Self::new(ti.cos(), tr.cos(), l_dot_v, theta_i_deg, theta_r_deg)
    }
}

/// Beckmann distribution D = exp(−tan²α/m²)/(m² cos⁴α), cos α = n·h, tan²α from the
/// cosine.
fn beckmann(n_h: f64, m: f64) -> f64 {
    let c = n_h.max(MIN_COS);
    let c2 = c * c;
    let tan2 = (1.0 - c2) / c2;
    (-tan2 / (m * m)).exp() / (m * m * c2 * c2)
}

/// Geometric attenuation G = min(1, 2(n·h)(n·v)/(v·h), 2(n·h)(n·l)/(v·h)).
fn masking(g: &Geom) -> f64 {
    let k = 2.0 * g.n_h / g.v_h;
    (k * g.cos_r).min(k * g.cos_i).min(1.0)
}

/// The Cook–Torrance specular factor D·G/(π (n·l)(n·v)) with F = 1.
fn cook_torrance_lobe(g: &Geom, m: f64) -> f64 {
    beckmann(g.n_h, m) * masking(g)
        / (std::f64::consts::PI * g.cos_i.max(MIN_COS) * g.cos_r.max(MIN_COS))
}

/// The isotropic Ward lobe exp(−tan²α/m²)/(4π m² √(cosθi cosθr)).
fn ward_lobe(g: &Geom, m: f64) -> f64 {
    let c = g.n_h.max(MIN_COS);
    let tan2 = (1.0 - c * c) / (c * c);
    (-tan2 / (m * m)).exp()
        / (4.0 * std::f64::consts::PI * m * m * (g.cos_i * g.cos_r).max(MIN_COS).sqrt())
}

/// Retro-reflection lobe exp(−tan²(γ/2)/w²), cos γ = l·v, `w2` = w²; tan²(γ/2) from the
/// cosine as (1 − c)/(1 + c).
pub fn retro_lobe(l_dot_v: f64, w2: f64) -> f64 {
    let c = l_dot_v.clamp(-1.0 + 1e-9, 1.0);
    (-((1.0 - c) / (1.0 + c)) / w2).exp()
}

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
fn table_at(table: &[[f64; 3]], v_h: f64) -> [f64; 3] {
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
        let text = std::fs::read_to_string(path).map_err(|error| SceneError::Io {
            path: path.to_path_buf(),
            error,
        })?;
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

    fn rgb_at(&self, theta_i: f64, theta_r: f64) -> [f64; 3] {
        let mut out = [0.0; 3];
        for (k, w) in self.corners(theta_i, theta_r) {
            for (o, v) in out.iter_mut().zip(self.rgb[k]) {
                *o += w * v;
            }
        }
        out
    }

    fn spectrum_at(&self, theta_i: f64, theta_r: f64) -> Spectrum {
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

    /// β per camera channel at `g`.
    pub fn beta(&self, g: &Geom) -> [f64; 3] {
        match self {
            Material::Lambertian { kd } => *kd,
            Material::CookTorrance { kd, ks, m } => {
                std::array::from_fn(|c| ks[c] * cook_torrance_lobe(g, m[c]) + kd[c])
            }
            Material::Ward { kd, ks, m } => {
                std::array::from_fn(|c| kd[c] / std::f64::consts::PI + ks[c] * ward_lobe(g, m[c]))
            }
            Material::SpectralLobe { kd, m, table, .. } => {
                let lobe = cook_torrance_lobe(g, *m);
                let colour = table_at(table, g.v_h);
                std::array::from_fn(|c| lobe * colour[c] + kd[c])
            }
            Material::Measured(table) => table.rgb_at(g.theta_i_deg, g.theta_r_deg),
        }
    }

    /// Spectral radiance factor at `g`: exact for spectral samples; for camera-RGB
    /// models the smooth spectrum of [`CameraDomain::spectrum_from_rgb`], whose
    /// camera RGB equals [`Material::beta`].
    pub fn beta_spectrum(&self, g: &Geom, domain: &CameraDomain) -> Spectrum {
        match self {
            Material::SpectralLobe {
                kd_spectrum,
                ks,
                m,
                reflector,
                ..
            } => {
                let lobe = ks * cook_torrance_lobe(g, *m);
                let reflectance = reflector.spectrum(g.v_h);
                std::array::from_fn(|i| lobe * reflectance[i] + kd_spectrum[i])
            }
            Material::Measured(table) => table.spectrum_at(g.theta_i_deg, g.theta_r_deg),
            _ => domain.spectrum_from_rgb(self.beta(g)),
        }
    }
}
