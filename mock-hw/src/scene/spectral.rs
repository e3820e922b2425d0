//! Spectral tables on the goniospectrophotometer grid (390–730 nm, 10 nm steps) and the
//! camera-RGB domain of paper eq. 4/5.
//!
//! The emulated camera integrates over 400–700 nm, the range of eq. 4, so the ratio a
//! capture gives, times the white's camera-RGB value, is exactly the eq. 5 value of the
//! sample's spectral radiance factor.

use std::path::Path;

use super::error::SceneError;

/// Number of bands: 390, 400, …, 730 nm.
pub const BANDS: usize = 35;
/// First wavelength of the grid, nm.
pub const FIRST_NM: f64 = 390.0;
/// Wavelength step, nm.
pub const STEP_NM: f64 = 10.0;

/// Wavelength of band `i` in nm.
pub fn wavelength_nm(i: usize) -> f64 {
    FIRST_NM + STEP_NM * i as f64
}

/// One value per band.
pub type Spectrum = [f64; BANDS];

const ILLUMINANT_A_CSV: &str =
    include_str!("../../../processing/data/cie_illuminant_a_390_730_10nm.csv");
const CIE_1931_CSV: &str =
    include_str!("../../../processing/data/cie1931_2deg_cmf_390_730_10nm.csv");
const NIKON_D5100_CSV: &str =
    include_str!("../../../processing/data/nikon_d5100_npl_sensitivities_390_730_10nm.csv");

/// CIE standard illuminant A, relative power (100 at 560 nm).
pub fn illuminant_a() -> Spectrum {
    parse_table::<1>(ILLUMINANT_A_CSV, "built-in illuminant A")
        .map(|t| t[0])
        .expect("embedded illuminant A table is valid")
}

/// Nikon D5100 spectral sensitivities (NPL measurement), relative, R G B.
pub fn nikon_d5100() -> [Spectrum; 3] {
    parse_table::<3>(NIKON_D5100_CSV, "built-in Nikon D5100 sensitivities")
        .expect("embedded Nikon D5100 table is valid")
}

/// Linear sRGB (IEC 61966-2-1) from CIE XYZ.
const XYZ_TO_SRGB: [[f64; 3]; 3] = [
    [3.2406, -1.5372, -0.4986],
    [-0.9689, 1.8758, 0.0415],
    [0.0557, -0.2040, 1.0570],
];

/// The three smooth spectra (combinations of the Gaussian basis of
/// [`CameraDomain::spectrum_from_rgb`]) whose linear sRGB are (1, 0, 0), (0, 1, 0) and
/// (0, 0, 1): sRGB of a radiance factor taken from the CIE 1931 observer under an
/// equal-energy light, each channel scaled so that a perfect white is 1.
pub fn srgb_unit_spectra() -> [Spectrum; 3] {
    let cmf = parse_table::<3>(CIE_1931_CSV, "built-in CIE 1931 observer")
        .expect("embedded CIE 1931 table is valid");
    let raw: [Spectrum; 3] =
        XYZ_TO_SRGB.map(|row| std::array::from_fn(|i| (0..3).map(|k| row[k] * cmf[k][i]).sum()));
    let weights = raw.map(|w| {
        let white: f64 = w.iter().sum();
        w.map(|v| v / white)
    });
    let basis = CameraDomain::basis();
    let matrix: [[f64; 3]; 3] = std::array::from_fn(|c| {
        std::array::from_fn(|j| weights[c].iter().zip(&basis[j]).map(|(w, b)| w * b).sum())
    });
    std::array::from_fn(|k| {
        let a = solve3(matrix, std::array::from_fn(|c| f64::from(u8::from(c == k))));
        std::array::from_fn(|i| (0..3).map(|j| a[j] * basis[j][i]).sum())
    })
}

/// Reads a table with a header line and rows `wavelength_nm,v1,..,vN` covering exactly
/// 390–730 nm in 10 nm steps.
/// At most `MAX_TABLE_BYTES` are read: a scene may name any path (even `/dev/zero`).
pub fn read_table<const N: usize>(path: &Path) -> Result<[Spectrum; N], SceneError> {
    let text = read_capped(path, MAX_TABLE_BYTES)?;
    parse_table::<N>(&text, &path.display().to_string())
}

/// Largest spectral table file read (35 rows of a few numbers need far less).
const MAX_TABLE_BYTES: u64 = 1 << 20;

/// The text of the input file at `path` (`gonio_files::input`: a regular file of at
/// most `max_bytes`, never read beyond them).
pub fn read_capped(path: &Path, max_bytes: u64) -> Result<String, SceneError> {
    gonio_files::input::read_input_to_string(path, max_bytes).map_err(|error| SceneError::Io {
        path: path.to_path_buf(),
        error,
    })
}

fn parse_table<const N: usize>(text: &str, what: &str) -> Result<[Spectrum; N], SceneError> {
    let bad = |line: usize, reason: String| SceneError::Table {
        what: what.to_string(),
        line,
        reason,
    };
    let mut out = [[0.0; BANDS]; N];
    let mut rows = 0;
    for (index, line) in text.lines().enumerate().skip(1) {
        let line_no = index + 1;
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        if rows == BANDS {
            return Err(bad(line_no, format!("more than {BANDS} wavelength rows")));
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != N + 1 {
            return Err(bad(
                line_no,
                format!("expected {} columns, found {}", N + 1, fields.len()),
            ));
        }
        let parse = |s: &str| {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(line_no, format!("`{s}` is not a finite number")))
        };
        let wl = parse(fields[0])?;
        if (wl - wavelength_nm(rows)).abs() > 1e-6 {
            return Err(bad(
                line_no,
                format!("wavelength {wl} nm, expected {} nm", wavelength_nm(rows)),
            ));
        }
        for (c, field) in fields[1..].iter().enumerate() {
            out[c][rows] = parse(field)?;
        }
        rows += 1;
    }
    if rows != BANDS {
        return Err(bad(
            text.lines().count(),
            format!("{rows} wavelength rows, expected {BANDS} (390–730 nm)"),
        ));
    }
    Ok(out)
}

/// The camera-RGB domain of eq. 4/5 for one camera and light: per-channel weights
/// k·c̄(λ)·I(λ) on 400–700 nm (zero outside), k = 100 / Σ ḡ I.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraDomain {
    weights: [Spectrum; 3],
}

/// Centres (nm) and width (nm, standard deviation) of the three smooth basis spectra
/// used to turn camera-RGB values back into spectra.
const BASIS_CENTRES_NM: [f64; 3] = [610.0, 535.0, 460.0];
const BASIS_SIGMA_NM: f64 = 40.0;

impl CameraDomain {
    /// Builds the domain; fails when the light gives no green signal at all.
    pub fn new(sensitivities: &[Spectrum; 3], light: &Spectrum) -> Result<Self, SceneError> {
        let in_range = |i: usize| (400.0..=700.0).contains(&wavelength_nm(i));
        let green: f64 = (0..BANDS)
            .filter(|&i| in_range(i))
            .map(|i| sensitivities[1][i] * light[i])
            .sum();
        if !(green > 0.0 && green.is_finite()) {
            return Err(SceneError::Invalid {
                key: "light.spectrum".into(),
                reason: "the light gives no green camera signal on 400–700 nm".into(),
            });
        }
        let k = 100.0 / green;
        let mut weights = [[0.0; BANDS]; 3];
        for (c, w) in weights.iter_mut().enumerate() {
            for (i, wi) in w.iter_mut().enumerate() {
                if in_range(i) {
                    *wi = k * sensitivities[c][i] * light[i];
                }
            }
        }
        Ok(Self { weights })
    }

    /// Camera-RGB value (eq. 5) of a spectral radiance factor.
    pub fn rgb(&self, beta: &Spectrum) -> [f64; 3] {
        self.weights
            .map(|w| w.iter().zip(beta).map(|(w, b)| w * b).sum())
    }

    /// The per-channel weights k·c̄(λ)·I(λ) of each band (zero outside 400–700 nm).
    pub fn weights(&self) -> &[Spectrum; 3] {
        &self.weights
    }

    /// Camera-RGB value of a perfect reflecting diffuser (G = 100).
    pub fn white_rgb(&self) -> [f64; 3] {
        self.weights.map(|w| w.iter().sum())
    }

    /// The basis spectra, Gaussians at 610, 535 and 460 nm (σ 40 nm).
    fn basis() -> [Spectrum; 3] {
        BASIS_CENTRES_NM.map(|centre| {
            std::array::from_fn(|i| {
                let x = (wavelength_nm(i) - centre) / BASIS_SIGMA_NM;
                (-0.5 * x * x).exp()
            })
        })
    }

    /// A smooth spectrum whose camera-RGB value is `rgb`: a combination of three
    /// Gaussian basis spectra solved from the 3×3 system. Linear in `rgb`, so a model
    /// written in camera RGB has a spectral counterpart with the same eq. 5 value at
    /// every geometry. Out-of-gamut RGB gives a spectrum with negative lobes.
    pub fn spectrum_from_rgb(&self, rgb: [f64; 3]) -> Spectrum {
        let basis = Self::basis();
        let mut matrix = [[0.0; 3]; 3];
        for (c, row) in matrix.iter_mut().enumerate() {
            for (j, entry) in row.iter_mut().enumerate() {
                *entry = self.weights[c]
                    .iter()
                    .zip(&basis[j])
                    .map(|(w, b)| w * b)
                    .sum();
            }
        }
        let a = solve3(matrix, rgb);
        std::array::from_fn(|i| (0..3).map(|j| a[j] * basis[j][i]).sum())
    }
}

/// Solves a 3×3 system by Cramer's rule (the basis matrix is well conditioned: each
/// Gaussian sits on one channel's peak).
fn solve3(m: [[f64; 3]; 3], b: [f64; 3]) -> [f64; 3] {
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(&m);
    std::array::from_fn(|j| {
        let mut mj = m;
        for (row, bi) in mj.iter_mut().zip(b) {
            row[j] = bi;
        }
        det(&mj) / d
    })
}
