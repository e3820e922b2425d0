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
//! ([`TEST_SEED`]): the relative residuals r = (M·β − XYZ)/Y give the covariance
//! C = mean(r rᵀ) (bias included), and a colour of luminance Y gets the transform's
//! covariance Y²·C in XYZ; the ΔE00 between the transformed and the true colours
//! summarises it ([`TransformError`]).

use nalgebra::{DMatrix, Matrix3, Vector3};
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
    /// C: the covariance of (M·β − XYZ)/Y, row-major.
    pub relative_covariance: [[f64; 3]; 3],
}

/// Camera RGB → XYZ under stated conditions, with its error.
#[derive(Debug, Clone, PartialEq)]
pub struct ColourTransform {
    observer: Observer,
    matrix: Matrix3<f64>,
    error: TransformError,
}

impl ColourTransform {
    /// The transform of `camera` (its sensitivities under its lamp) to `conditions`.
    pub fn new(camera: &CameraModel, conditions: Conditions) -> Result<Self, ColorError> {
        let observer = Observer::new(conditions);
        let pair = |f: &[f64; BANDS]| -> Result<([f64; 3], [f64; 3]), ColorError> {
            Ok((camera_rgb(camera, f)?, observer.xyz(f)?))
        };
        let training = smooth_spectra(TRAINING_SEED, SPECTRA);
        let mut rows: Vec<([f64; 3], [f64; 3], f64)> = Vec::with_capacity(SPECTRA + 1);
        for f in &training {
            let (rgb, xyz) = pair(f)?;
            rows.push((rgb, xyz, 1.0));
        }
        let (white_rgb, white_xyz) = pair(&[1.0; BANDS])?;
        rows.push((white_rgb, white_xyz, SPECTRA as f64));
        let n = rows.len();
        let a = DMatrix::from_fn(n, 3, |i, c| rows[i].2 * rows[i].0[c]);
        let b = DMatrix::from_fn(n, 3, |i, c| rows[i].2 * rows[i].1[c]);
        let solution =
            a.svd(true, true)
                .solve(&b, 1e-12)
                .map_err(|reason| ColorError::Degenerate {
                    what: format!("camera RGB → XYZ least squares ({reason})"),
                })?;
        let matrix = Matrix3::from_fn(|r, c| solution[(c, r)]);
        if !matrix.iter().all(|v| v.is_finite()) {
            return Err(ColorError::Degenerate {
                what: "camera RGB → XYZ matrix".into(),
            });
        }
        let white = observer.white();
        let mut covariance = [[0.0; 3]; 3];
        let mut delta_e = Vec::with_capacity(SPECTRA);
        for f in &smooth_spectra(TEST_SEED, SPECTRA) {
            let (rgb, xyz) = pair(f)?;
            let estimate = matrix * Vector3::from(rgb);
            let r: [f64; 3] = std::array::from_fn(|c| (estimate[c] - xyz[c]) / xyz[1]);
            for (i, row) in covariance.iter_mut().enumerate() {
                for (j, v) in row.iter_mut().enumerate() {
                    *v += r[i] * r[j] / SPECTRA as f64;
                }
            }
            delta_e.push(ciede2000(
                lab_from_xyz(xyz, white),
                lab_from_xyz([estimate[0], estimate[1], estimate[2]], white),
            ));
        }
        delta_e.sort_by(f64::total_cmp);
        let at = |q: f64| delta_e[((q * (SPECTRA - 1) as f64).round() as usize).min(SPECTRA - 1)];
        let error = TransformError {
            spectra: format!("{SPECTRA_FAMILY}; fitted on seed {TRAINING_SEED}, judged on seed {TEST_SEED}, {SPECTRA} spectra each"),
            delta_e00_median: at(0.5),
            delta_e00_p95: at(0.95),
            delta_e00_max: delta_e[SPECTRA - 1],
            relative_covariance: covariance,
        };
        Ok(Self {
            observer,
            matrix,
            error,
        })
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

    /// The covariance of the transform's error in XYZ at a colour of XYZ `xyz`: Y²·C
    /// (|Y|, so a noisy black keeps a positive covariance).
    pub fn xyz_covariance(&self, xyz: [f64; 3]) -> [[f64; 3]; 3] {
        let y2 = xyz[1] * xyz[1];
        self.error
            .relative_covariance
            .map(|row| row.map(|v| v * y2))
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
