//! Colorimetry in the camera-RGB domain (paper eq. 4, 5 and 12).
//!
//! A spectral radiance factor f(λ) maps to camera RGB as
//! β_c = k · Σλ f(λ) c̄(λ) I(λ) with k = 100 / Σλ ḡ(λ) I(λ), the sums over 400–700 nm
//! at 10 nm, c̄ the camera's spectral sensitivities and I the illuminant. A perfect
//! white (f ≡ 1) therefore has β_G = 100. Camera RGB goes to CIE XYZ through a 3×3
//! matrix fitted by least squares so that M·(c̄ I) ≈ (x̄ȳz̄ I) over the same wavelengths.
//!
//! Built-in tables (processing/data, 390–730 nm at 10 nm): CIE 1931 2° colour matching
//! functions, CIE illuminant A, Nikon D5100 sensitivities (NPL); for colour as the
//! coatings trade states it, CIE 1964 10°, D65 and D50 ([`observer`]).
//!
//! Colour beyond u′v′ lives in the children: [`observer`] (illuminant and observer),
//! [`lab`] (CIELAB), [`delta_e`] (ΔL*, ΔC*, ΔH*, CIEDE2000, flop index), [`geometry`]
//! (multi-angle geometries) and [`transform`] (camera RGB → XYZ under stated conditions,
//! with its error).

pub mod delta_e;
pub mod geometry;
pub mod lab;
pub mod observer;
pub mod srgb;
pub mod transform;

use nalgebra::{DMatrix, Matrix3, Vector3};
use thiserror::Error;

const CMF_CSV: &str = include_str!("../data/cie1931_2deg_cmf_390_730_10nm.csv");
const ILLUMINANT_A_CSV: &str = include_str!("../data/cie_illuminant_a_390_730_10nm.csv");
const NIKON_D5100_CSV: &str =
    include_str!("../data/nikon_d5100_npl_sensitivities_390_730_10nm.csv");

/// First and last wavelength (nm) of the eq. 4/5 sums.
pub const SUM_RANGE_NM: (f64, f64) = (400.0, 700.0);

/// β_G of a perfect reflecting diffuser: the camera-RGB domain's scale (eq. 5).
pub const WHITE_BETA_G: f64 = 100.0;

/// Errors of spectral tables and spectra.
#[derive(Debug, Error)]
pub enum ColorError {
    #[error("{table}: line {line}: {reason}")]
    Table {
        table: String,
        line: usize,
        reason: String,
    },
    #[error("{table}: no value at {wavelength_nm} nm (needed for 400–700 nm at 10 nm)")]
    MissingWavelength { table: String, wavelength_nm: f64 },
    #[error("spectrum has {found} values, expected {expected} (one per model wavelength)")]
    SpectrumLength { expected: usize, found: usize },
    #[error("{what} is not finite or not positive")]
    Degenerate { what: String },
}

/// A table of spectral values: wavelengths in nm, ascending, and `N` values per row.
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralTable<const N: usize> {
    pub wavelengths_nm: Vec<f64>,
    pub values: Vec<[f64; N]>,
}

impl<const N: usize> SpectralTable<N> {
    /// Parses a CSV with a header line, then `wavelength,v1..vN` per line.
    pub fn parse_csv(name: &str, text: &str) -> Result<Self, ColorError> {
        let err = |line: usize, reason: String| ColorError::Table {
            table: name.to_string(),
            line,
            reason,
        };
        let mut wavelengths_nm = Vec::new();
        let mut values = Vec::new();
        for (index, raw) in text.lines().enumerate().skip(1) {
            let line = index + 1;
            if raw.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = raw.split(',').map(str::trim).collect();
            if fields.len() != N + 1 {
                return Err(err(
                    line,
                    format!("{} fields, expected {}", fields.len(), N + 1),
                ));
            }
            let mut numbers = [0.0; N];
            let parse = |s: &str| -> Result<f64, ColorError> {
                s.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| err(line, format!("'{s}' is not a finite number")))
            };
            let wavelength = parse(fields[0])?;
            if let Some(&last) = wavelengths_nm.last() {
                if wavelength <= last {
                    return Err(err(line, "wavelengths must ascend".into()));
                }
            }
            for (slot, field) in numbers.iter_mut().zip(&fields[1..]) {
                *slot = parse(field)?;
            }
            wavelengths_nm.push(wavelength);
            values.push(numbers);
        }
        if values.is_empty() {
            return Err(err(1, "no data rows".into()));
        }
        Ok(Self {
            wavelengths_nm,
            values,
        })
    }

    /// The values at each wavelength of `grid` (exact match within 1e-6 nm).
    pub(crate) fn at(&self, name: &str, grid: &[f64]) -> Result<Vec<[f64; N]>, ColorError> {
        grid.iter()
            .map(|&w| {
                self.wavelengths_nm
                    .iter()
                    .position(|&x| (x - w).abs() < 1e-6)
                    .map(|i| self.values[i])
                    .ok_or_else(|| ColorError::MissingWavelength {
                        table: name.to_string(),
                        wavelength_nm: w,
                    })
            })
            .collect()
    }
}

/// The 10 nm grid of the eq. 4/5 sums, 400–700 nm.
pub fn sum_wavelengths_nm() -> Vec<f64> {
    let (first, last) = SUM_RANGE_NM;
    let steps = ((last - first) / 10.0).round() as usize;
    (0..=steps).map(|i| first + 10.0 * i as f64).collect()
}

/// A camera (sensitivities) under an illuminant, with the CIE observer for XYZ.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraModel {
    wavelengths_nm: Vec<f64>,
    /// c̄(λ)·I(λ) per channel on `wavelengths_nm`.
    weighted_sensitivity: Vec<[f64; 3]>,
    k: f64,
    white_rgb: [f64; 3],
    rgb_to_xyz: Matrix3<f64>,
}

impl CameraModel {
    /// Nikon D5100 sensitivities under CIE illuminant A with the CIE 1931 2° observer.
    pub fn builtin() -> Self {
        Self::from_csv(NIKON_D5100_CSV, ILLUMINANT_A_CSV, CMF_CSV)
            .expect("embedded spectral tables are valid (checked by the tests)")
    }

    /// Builds a model from CSV texts of sensitivities, illuminant and CMFs.
    pub fn from_csv(sensitivities: &str, illuminant: &str, cmf: &str) -> Result<Self, ColorError> {
        Self::new(
            &SpectralTable::parse_csv("sensitivities", sensitivities)?,
            &SpectralTable::parse_csv("illuminant", illuminant)?,
            &SpectralTable::parse_csv("colour matching functions", cmf)?,
        )
    }

    /// Builds a model from camera sensitivities (r̄ ḡ b̄), an illuminant and CIE x̄ȳz̄,
    /// each of which must hold every wavelength of 400–700 nm at 10 nm.
    pub fn new(
        sensitivities: &SpectralTable<3>,
        illuminant: &SpectralTable<1>,
        cmf: &SpectralTable<3>,
    ) -> Result<Self, ColorError> {
        let grid = sum_wavelengths_nm();
        let sens = sensitivities.at("sensitivities", &grid)?;
        let light = illuminant.at("illuminant", &grid)?;
        let xyz_bar = cmf.at("colour matching functions", &grid)?;
        let weighted_sensitivity: Vec<[f64; 3]> = sens
            .iter()
            .zip(&light)
            .map(|(s, i)| [s[0] * i[0], s[1] * i[0], s[2] * i[0]])
            .collect();
        let g_sum: f64 = weighted_sensitivity.iter().map(|s| s[1]).sum();
        if !(g_sum.is_finite() && g_sum > 0.0) {
            return Err(ColorError::Degenerate {
                what: "Σ ḡ(λ) I(λ)".into(),
            });
        }
        let k = WHITE_BETA_G / g_sum;
        let mut white_rgb = [0.0; 3];
        for s in &weighted_sensitivity {
            for c in 0..3 {
                white_rgb[c] += k * s[c];
            }
        }
        let rgb_to_xyz = fit_rgb_to_xyz(&weighted_sensitivity, &xyz_bar, &light)?;
        Ok(Self {
            wavelengths_nm: grid,
            weighted_sensitivity,
            k,
            white_rgb,
            rgb_to_xyz,
        })
    }

    /// The wavelengths (nm) a spectrum passed to [`CameraModel::camera_rgb`] is sampled on.
    pub fn wavelengths_nm(&self) -> &[f64] {
        &self.wavelengths_nm
    }

    /// The normalising coefficient k = 100 / Σ ḡ I.
    pub fn k(&self) -> f64 {
        self.k
    }

    /// Camera RGB of a perfect reflecting diffuser (f ≡ 1): G is 100.
    pub fn white_rgb(&self) -> [f64; 3] {
        self.white_rgb
    }

    /// Eq. 4/5: camera RGB of a spectral radiance factor sampled on
    /// [`CameraModel::wavelengths_nm`].
    pub fn camera_rgb(&self, radiance_factor: &[f64]) -> Result<[f64; 3], ColorError> {
        if radiance_factor.len() != self.weighted_sensitivity.len() {
            return Err(ColorError::SpectrumLength {
                expected: self.weighted_sensitivity.len(),
                found: radiance_factor.len(),
            });
        }
        let mut rgb = [0.0; 3];
        for (f, s) in radiance_factor.iter().zip(&self.weighted_sensitivity) {
            for c in 0..3 {
                rgb[c] += self.k * f * s[c];
            }
        }
        Ok(rgb)
    }

    /// The fitted camera-RGB → CIE XYZ matrix (row-major, XYZ = M · RGB).
    pub fn rgb_to_xyz_matrix(&self) -> [[f64; 3]; 3] {
        let m = &self.rgb_to_xyz;
        [
            [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
            [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
            [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
        ]
    }

    /// CIE XYZ of a camera-RGB triple, normalised so that a perfect white has Y ≈ 100.
    pub fn xyz(&self, rgb: [f64; 3]) -> [f64; 3] {
        let v = self.rgb_to_xyz * Vector3::from(rgb);
        [v[0], v[1], v[2]]
    }

    /// CIE 1976 u′v′ of a camera-RGB triple (eq. 12); `None` when it has no chromaticity.
    pub fn uv_prime(&self, rgb: [f64; 3]) -> Option<[f64; 2]> {
        uv_prime_from_xyz(self.xyz(rgb))
    }
}

/// Least-squares M with M·(c̄ I)(λ) ≈ s·(x̄ȳz̄ I)(λ) over the grid, s = Σ ḡ I / Σ ȳ I;
/// the rows are the signals a flat spectrum would give at each wavelength, so the fit
/// is weighted as the camera sees the illuminant.
fn fit_rgb_to_xyz(
    weighted_sensitivity: &[[f64; 3]],
    xyz_bar: &[[f64; 3]],
    light: &[[f64; 1]],
) -> Result<Matrix3<f64>, ColorError> {
    let n = weighted_sensitivity.len();
    let a = DMatrix::from_fn(n, 3, |i, c| weighted_sensitivity[i][c]);
    // Scale the targets so that XYZ carries the conventional normalisation
    // 100 / Σ ȳ I while camera RGB carries 100 / Σ ḡ I.
    let g_sum: f64 = weighted_sensitivity.iter().map(|s| s[1]).sum();
    let y_sum: f64 = xyz_bar.iter().zip(light).map(|(x, i)| x[1] * i[0]).sum();
    if !(y_sum.is_finite() && y_sum > 0.0) {
        return Err(ColorError::Degenerate {
            what: "Σ ȳ(λ) I(λ)".into(),
        });
    }
    let scale = g_sum / y_sum;
    let b = DMatrix::from_fn(n, 3, |i, c| xyz_bar[i][c] * light[i][0] * scale);
    let solution = a
        .svd(true, true)
        .solve(&b, 1e-12)
        .map_err(|reason| ColorError::Degenerate {
            what: format!("RGB→XYZ least squares ({reason})"),
        })?;
    // solution is 3×3 with A·S ≈ B, i.e. rgbᵀ·S = xyzᵀ, so M = Sᵀ.
    let m = Matrix3::from_fn(|r, c| solution[(c, r)]);
    if m.iter().all(|v| v.is_finite()) {
        Ok(m)
    } else {
        Err(ColorError::Degenerate {
            what: "RGB→XYZ matrix".into(),
        })
    }
}

/// CIE 1976 u′ = 4X/(X+15Y+3Z), v′ = 9Y/(X+15Y+3Z) (eq. 12). `None` when the
/// denominator is not positive (black, or a negative XYZ from a noisy measurement)
/// or any value is not finite: such a colour has no chromaticity.
pub fn uv_prime_from_xyz(xyz: [f64; 3]) -> Option<[f64; 2]> {
    let [x, y, z] = xyz;
    let d = x + 15.0 * y + 3.0 * z;
    if !(d.is_finite() && d > 1e-12) {
        return None;
    }
    let uv = [4.0 * x / d, 9.0 * y / d];
    uv.iter().all(|v| v.is_finite()).then_some(uv)
}
