//! Camera RGB (the scan's camera under the scan's lamp, paper eq. 4/5) → CIE XYZ under
//! the illuminant and observer a colour is stated in, and that transform's own error
//! (docs/ARCHITECTURE.md, "Multi-angle colour").
//!
//! A camera whose sensitivities are not a linear combination of the CIE colour matching
//! functions (it misses the Luther condition) sees some spectra that differ in XYZ as one
//! camera RGB, so no 3×3 matrix is exact; and the lamp the scan is lit by (CIE A) is not
//! the illuminant the colour is stated under. The matrix M (XYZ ≈ M·β) is fitted by least
//! squares over a family of reflectance spectra ([`smooth_spectra`], seed
//! [`TRAINING_SEED`]) plus a perfect white weighted as the whole family (its row × N), so that the white
//! maps to the white point. Its error is then measured on another draw of the same family
//! ([`TEST_SEED`]): the relative residuals r = (M·β − XYZ)/Y; a colour gets the
//! covariance C of those of the [`NEIGHBOURS`] test spectra nearest to it in camera
//! chromaticity (tricube-weighted mean of r rᵀ, bias included), and with luminance Y the
//! transform's covariance Y²·C in XYZ; the ΔE00 between the transformed and the true
//! colours over the whole test draw summarises it ([`TransformError`]).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::delta_e::ciede2000;
use super::lab::lab_from_xyz;
use super::observer::{Conditions, Observer, BANDS, FIRST_NM};
use super::{CameraModel, ColorError};

/// Seed of the spectra the matrix is fitted on.
pub const TRAINING_SEED: u64 = 1;
/// Seed of the spectra its error is measured on.
pub const TEST_SEED: u64 = 2;
/// Spectra drawn for each.
pub const SPECTRA: usize = 2000;

/// The family the transform is fitted and judged on, as colour.json states it.
pub const SPECTRA_FAMILY: &str = "smooth reflectances 0.02 + 0.96/(1 + exp(−g(λ))), \
g(λ) = Σ_{j=0..5} c_j cos(jπx), x = (λ − 390 nm)/340 nm, c_0 ~ U(−3, 3), \
c_j ~ U(−3, 3)/√j (splitmix64)";

/// A small deterministic generator (splitmix64): the family of spectra is the same on
/// every machine.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform on [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `count` smooth reflectance spectra on 390–730 nm at 10 nm ([`SPECTRA_FAMILY`]).
pub fn smooth_spectra(seed: u64, count: usize) -> Vec<[f64; BANDS]> {
    let mut rng = SplitMix64::new(seed);
    (0..count)
        .map(|_| {
            let c: Vec<f64> = (0..6)
                .map(|j| {
                    let u = 6.0 * rng.uniform() - 3.0;
                    if j == 0 {
                        u
                    } else {
                        u / (j as f64).sqrt()
                    }
                })
                .collect();
            std::array::from_fn(|i| {
                let x = (10.0 * i as f64) / 340.0;
                let g: f64 = c
                    .iter()
                    .enumerate()
                    .map(|(j, cj)| cj * (j as f64 * std::f64::consts::PI * x).cos())
                    .sum();
                0.02 + 0.96 / (1.0 + (-g).exp())
            })
        })
        .collect()
}

/// The transform's error over the test spectra.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransformError {
    /// The spectra it was measured on ([`SPECTRA_FAMILY`], seed, count).
    pub spectra: String,
    /// Median, 95th percentile and largest ΔE00 between the transformed colour and the
    /// colour computed from the spectrum with the observer.
    pub delta_e00_median: f64,
    pub delta_e00_p95: f64,
    pub delta_e00_max: f64,
    /// The mean over the test spectra of r rᵀ, r = (estimate − XYZ)/Y, row-major: what
    /// the error is on average. A colour gets the covariance of its own neighbourhood
    /// ([`ColourTransform::xyz_covariance`]).
    pub relative_covariance: [[f64; 3]; 3],
    /// Test spectra in the neighbourhood of a colour, for its error's covariance.
    #[serde(default)]
    pub neighbours: usize,
}

/// Test spectra in the neighbourhood of a colour.
pub const NEIGHBOURS: usize = 150;

/// Camera chromaticity of `rgb` (r/(r+g+b), g/(r+g+b)); `None` when its sum is not
/// positive.
fn chroma(rgb: [f64; 3]) -> Option<[f64; 2]> {
    let sum = rgb[0] + rgb[1] + rgb[2];
    (sum > 1e-12 && sum.is_finite()).then(|| [rgb[0] / sum, rgb[1] / sum])
}

/// The relative residuals of the [`NEIGHBOURS`] test spectra nearest to `at` in
/// chromaticity, each with its tricube weight (1 − (d/d_k)³)³ against the distance d_k
/// just beyond the farthest of them.
fn nearest(residuals: &[([f64; 2], [f64; 3])], at: [f64; 2]) -> Vec<([f64; 3], f64)> {
    let mut by_distance: Vec<(f64, [f64; 3])> = residuals
        .iter()
        .map(|(c, r)| ((c[0] - at[0]).hypot(c[1] - at[1]), *r))
        .collect();
    let k = NEIGHBOURS.min(by_distance.len());
    if k == 0 {
        return Vec::new();
    }
    by_distance.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
    by_distance.truncate(k);
    let reach = by_distance.iter().map(|d| d.0).fold(0.0, f64::max) * 1.0001 + 1e-12;
    by_distance
        .into_iter()
        .map(|(d, r)| (r, (1.0 - (d / reach).powi(3)).powi(3)))
        .collect()
}

/// Adds w·r rᵀ / total to `c`.
fn add_outer(c: &mut [[f64; 3]; 3], r: &[f64; 3], w: f64, total: f64) {
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v += w * r[i] * r[j] / total;
        }
    }
}

/// Weighted least squares XYZ ≈ M·rgb over `rows` (rgb, xyz, weight in the normal
/// equations); `None` when they are singular.
fn fit_matrix(rows: &[([f64; 3], [f64; 3], f64)]) -> Option<Matrix3<f64>> {
    let mut ata = Matrix3::zeros();
    let mut atb = Matrix3::zeros();
    for (rgb, xyz, w) in rows {
        let a = Vector3::from(*rgb);
        let b = Vector3::from(*xyz);
        ata += *w * a * a.transpose();
        atb += *w * a * b.transpose();
    }
    let scale = ata.trace().abs();
    if scale.is_nan() || scale <= 0.0 || ata.determinant().abs() <= 1e-12 * scale.powi(3) {
        return None;
    }
    let solution = ata.try_inverse()? * atb;
    let matrix = solution.transpose();
    matrix.iter().all(|v| v.is_finite()).then_some(matrix)
}

/// Camera RGB → XYZ under stated conditions, with its error.
#[derive(Debug, Clone, PartialEq)]
pub struct ColourTransform {
    observer: Observer,
    matrix: Matrix3<f64>,
    /// The test spectra's chromaticities and relative residuals (estimate − XYZ)/Y.
    residuals: Vec<([f64; 2], [f64; 3])>,
    error: TransformError,
}

impl ColourTransform {
    /// The transform of `camera` (its sensitivities under its lamp) to `conditions`.
    pub fn new(camera: &CameraModel, conditions: Conditions) -> Result<Self, ColorError> {
        let observer = Observer::new(conditions);
        let pair = |f: &[f64; BANDS]| -> Result<([f64; 3], [f64; 3]), ColorError> {
            Ok((camera_rgb(camera, f)?, observer.xyz(f)?))
        };
        // Least squares over the family, the white's row counting as the whole family
        // (its row × N, so its weight in the normal equations N²).
        let mut rows = Vec::with_capacity(SPECTRA + 1);
        for f in &smooth_spectra(TRAINING_SEED, SPECTRA) {
            let (rgb, xyz) = pair(f)?;
            rows.push((rgb, xyz, 1.0));
        }
        let (white_rgb, white_xyz) = pair(&[1.0; BANDS])?;
        rows.push((white_rgb, white_xyz, (SPECTRA * SPECTRA) as f64));
        let matrix = fit_matrix(&rows).ok_or_else(|| ColorError::Degenerate {
            what: "camera RGB → XYZ least squares".into(),
        })?;
        let mut transform = Self {
            observer: observer.clone(),
            matrix,
            residuals: Vec::with_capacity(SPECTRA),
            error: TransformError {
                spectra: String::new(),
                delta_e00_median: 0.0,
                delta_e00_p95: 0.0,
                delta_e00_max: 0.0,
                relative_covariance: [[0.0; 3]; 3],
                neighbours: NEIGHBOURS,
            },
        };
        let white_point = transform.observer.white();
        let mut covariance = [[0.0; 3]; 3];
        let mut delta_e = Vec::with_capacity(SPECTRA);
        for f in &smooth_spectra(TEST_SEED, SPECTRA) {
            let (rgb, xyz) = pair(f)?;
            let estimate = transform.xyz(rgb);
            let r: [f64; 3] = std::array::from_fn(|c| (estimate[c] - xyz[c]) / xyz[1]);
            add_outer(&mut covariance, &r, 1.0, SPECTRA as f64);
            transform
                .residuals
                .push((chroma(rgb).unwrap_or([1.0 / 3.0; 2]), r));
            delta_e.push(ciede2000(
                lab_from_xyz(xyz, white_point),
                lab_from_xyz(estimate, white_point),
            ));
        }
        delta_e.sort_by(f64::total_cmp);
        let at = |q: f64| delta_e[((q * (SPECTRA - 1) as f64).round() as usize).min(SPECTRA - 1)];
        transform.error = TransformError {
            spectra: format!(
                "{SPECTRA_FAMILY}; fitted on seed {TRAINING_SEED}, judged on seed {TEST_SEED}, \
                 {SPECTRA} spectra each; a colour's error from its {NEIGHBOURS} nearest \
                 spectra in camera chromaticity"
            ),
            delta_e00_median: at(0.5),
            delta_e00_p95: at(0.95),
            delta_e00_max: delta_e[SPECTRA - 1],
            relative_covariance: covariance,
            neighbours: NEIGHBOURS,
        };
        Ok(transform)
    }

    /// The observer and illuminant colours are stated under.
    pub fn observer(&self) -> &Observer {
        &self.observer
    }

    /// XYZ of camera RGB β (white at β_G = 100 → Y ≈ 100).
    pub fn xyz(&self, rgb: [f64; 3]) -> [f64; 3] {
        let v = self.matrix * Vector3::from(rgb);
        [v[0], v[1], v[2]]
    }

    /// L*a*b* of camera RGB β.
    pub fn lab(&self, rgb: [f64; 3]) -> [f64; 3] {
        lab_from_xyz(self.xyz(rgb), self.observer.white())
    }

    /// The matrix M, row-major (XYZ = M·β).
    pub fn matrix(&self) -> [[f64; 3]; 3] {
        std::array::from_fn(|r| std::array::from_fn(|c| self.matrix[(r, c)]))
    }

    /// The transform's error over the test spectra.
    pub fn error(&self) -> &TransformError {
        &self.error
    }

    /// The covariance of the transform's error in XYZ at a colour of camera RGB `rgb`
    /// and XYZ `xyz`: Y²·C with C the tricube-weighted mean of r rᵀ over the
    /// [`NEIGHBOURS`] test spectra nearest in camera chromaticity (bias included); the
    /// whole family's mean for a colour with no chromaticity. |Y|, so a noisy black keeps
    /// a positive covariance.
    pub fn xyz_covariance(&self, rgb: [f64; 3], xyz: [f64; 3]) -> [[f64; 3]; 3] {
        let y2 = xyz[1] * xyz[1];
        let Some(at) = chroma(rgb) else {
            return self
                .error
                .relative_covariance
                .map(|row| row.map(|v| v * y2));
        };
        let near = nearest(&self.residuals, at);
        let total: f64 = near.iter().map(|(_, w)| w).sum();
        let mut c = [[0.0; 3]; 3];
        if total > 0.0 {
            for (r, w) in &near {
                add_outer(&mut c, r, *w, total);
            }
        }
        c.map(|row| row.map(|v| v * y2))
    }
}

/// Camera RGB of a spectrum on 390–730 nm: the camera model sums 400–700 nm.
pub fn camera_rgb(camera: &CameraModel, spectrum: &[f64; BANDS]) -> Result<[f64; 3], ColorError> {
    let first = camera.wavelengths_nm()[0];
    let skip = ((first - FIRST_NM) / 10.0).round().max(0.0) as usize;
    let len = camera.wavelengths_nm().len();
    let band = spectrum
        .get(skip..skip + len)
        .ok_or(ColorError::SpectrumLength {
            expected: skip + len,
            found: BANDS,
        })?;
    camera.camera_rgb(band)
}
