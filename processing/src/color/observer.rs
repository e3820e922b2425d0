//! The CIE observer and illuminant a colour is stated under (docs/ARCHITECTURE.md,
//! "Multi-angle colour"): CIE 1964 10° with D65 (the default of the coatings trade) or
//! CIE 1931 2° with D50 (the graphic arts'). Tables in processing/data, 390–730 nm at
//! 10 nm (the goniospectrophotometer grid; the CIE's 360–830 nm tails carry < 0.1 % of
//! Y), sums of 10 nm steps: X = k Σλ f(λ) x̄(λ) S(λ), k = 100 / Σλ ȳ(λ) S(λ), so a perfect
//! reflecting diffuser (f ≡ 1) has Y = 100.

use super::{ColorError, SpectralTable};

const CMF_2_CSV: &str = include_str!("../../data/cie1931_2deg_cmf_390_730_10nm.csv");
const CMF_10_CSV: &str = include_str!("../../data/cie1964_10deg_cmf_390_730_10nm.csv");
const D65_CSV: &str = include_str!("../../data/cie_illuminant_d65_390_730_10nm.csv");
const D50_CSV: &str = include_str!("../../data/cie_illuminant_d50_390_730_10nm.csv");

/// First wavelength (nm) of a spectrum passed to [`Observer::xyz`].
pub const FIRST_NM: f64 = 390.0;

/// Number of 10 nm bands of a spectrum passed to [`Observer::xyz`]: 390, 400, …, 730 nm.
pub const BANDS: usize = 35;

/// An illuminant and observer pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Conditions {
    /// CIE D65 with the CIE 1964 10° observer (default).
    #[serde(rename = "D65/10")]
    D65Ten,
    /// CIE D50 with the CIE 1931 2° observer.
    #[serde(rename = "D50/2")]
    D50Two,
}

impl Conditions {
    /// The name as the command line and colour.json write it: `D65/10` or `D50/2`.
    pub fn name(self) -> &'static str {
        match self {
            Conditions::D65Ten => "D65/10",
            Conditions::D50Two => "D50/2",
        }
    }

    /// Parses [`Conditions::name`] (case-insensitive; `d65-10` and `d50-2` too).
    pub fn parse(text: &str) -> Option<Self> {
        match text.to_ascii_lowercase().replace('-', "/").as_str() {
            "d65/10" => Some(Conditions::D65Ten),
            "d50/2" => Some(Conditions::D50Two),
            _ => None,
        }
    }
}

/// The weights k·x̄ȳz̄(λ)·S(λ) of an observer under an illuminant on 390–730 nm.
#[derive(Debug, Clone, PartialEq)]
pub struct Observer {
    conditions: Conditions,
    weights: Vec<[f64; 3]>,
    white: [f64; 3],
}

impl Observer {
    /// The built-in tables for `conditions`.
    pub fn new(conditions: Conditions) -> Self {
        let (cmf, light) = match conditions {
            Conditions::D65Ten => (CMF_10_CSV, D65_CSV),
            Conditions::D50Two => (CMF_2_CSV, D50_CSV),
        };
        Self::from_csv(conditions, cmf, light)
            .expect("embedded spectral tables are valid (checked by the tests)")
    }

    fn from_csv(conditions: Conditions, cmf: &str, light: &str) -> Result<Self, ColorError> {
        let grid: Vec<f64> = (0..BANDS).map(|i| FIRST_NM + 10.0 * i as f64).collect();
        let cmf = SpectralTable::<3>::parse_csv("colour matching functions", cmf)?
            .at("colour matching functions", &grid)?;
        let light = SpectralTable::<1>::parse_csv("illuminant", light)?.at("illuminant", &grid)?;
        let y_sum: f64 = cmf.iter().zip(&light).map(|(c, s)| c[1] * s[0]).sum();
        if !(y_sum.is_finite() && y_sum > 0.0) {
            return Err(ColorError::Degenerate {
                what: "Σ ȳ(λ) S(λ)".into(),
            });
        }
        let k = 100.0 / y_sum;
        let weights: Vec<[f64; 3]> = cmf
            .iter()
            .zip(&light)
            .map(|(c, s)| c.map(|v| k * v * s[0]))
            .collect();
        let mut white = [0.0; 3];
        for w in &weights {
            for c in 0..3 {
                white[c] += w[c];
            }
        }
        Ok(Self {
            conditions,
            weights,
            white,
        })
    }

    /// The illuminant and observer.
    pub fn conditions(&self) -> Conditions {
        self.conditions
    }

    /// XYZ of a perfect reflecting diffuser: the white point (Y = 100).
    pub fn white(&self) -> [f64; 3] {
        self.white
    }

    /// XYZ of a spectral radiance factor on 390–730 nm at 10 nm ([`BANDS`] values, 1 = a
    /// perfect white).
    pub fn xyz(&self, radiance_factor: &[f64]) -> Result<[f64; 3], ColorError> {
        if radiance_factor.len() != BANDS {
            return Err(ColorError::SpectrumLength {
                expected: BANDS,
                found: radiance_factor.len(),
            });
        }
        let mut xyz = [0.0; 3];
        for (f, w) in radiance_factor.iter().zip(&self.weights) {
            for c in 0..3 {
                xyz[c] += f * w[c];
            }
        }
        Ok(xyz)
    }
}
