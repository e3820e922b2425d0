//! What to fit and how: the model, its roughness form, the method and each method's
//! settings.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::brdf::{Model, Roughness, UnknownName};

/// How to minimise the loss.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FitMethod {
    /// Kd, Ks solved at each m (a convex problem) plus a global search over log m.
    #[default]
    Robust,
    /// Downhill simplex over all parameters (the paper's method).
    NelderMead,
}

/// Settings of the robust method.
#[derive(Debug, Clone, PartialEq)]
pub struct RobustOptions {
    /// Roughness search range [m_min, m_max], searched in log m.
    pub m_min: f64,
    pub m_max: f64,
    /// Grid points over the log m range before Brent refinement (at least 3).
    pub grid_points: usize,
    /// Polish all parameters with Nelder–Mead afterwards (kept only if it lowers the loss).
    pub polish: bool,
}

impl Default for RobustOptions {
    fn default() -> Self {
        RobustOptions {
            m_min: 1e-3,
            m_max: 2.0,
            grid_points: 24,
            polish: false,
        }
    }
}

/// Settings of the Nelder–Mead method: fminsearch's, with its defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct NelderMeadOptions {
    /// Starting roughness; Kd and Ks start from the data (lowest and peak β).
    pub initial_m: f64,
    /// TolX: stop when no vertex is farther than this from the best in any parameter
    /// (absolute) and TolFun also holds.
    pub tol_x: f64,
    /// TolFun: stop when no vertex's loss exceeds the best by more than this (absolute)
    /// and TolX also holds.
    pub tol_fun: f64,
    /// MaxIter; `None` for fminsearch's 200 × the number of parameters.
    pub max_iter: Option<usize>,
    /// MaxFunEvals; `None` for fminsearch's 200 × the number of parameters.
    pub max_fun_evals: Option<usize>,
}

impl Default for NelderMeadOptions {
    fn default() -> Self {
        NelderMeadOptions {
            initial_m: 0.3,
            tol_x: 1e-4,
            tol_fun: 1e-4,
            max_iter: None,
            max_fun_evals: None,
        }
    }
}

/// What to fit and how.
#[derive(Debug, Clone, PartialEq)]
pub struct FitOptions {
    pub model: Model,
    pub roughness: Roughness,
    pub method: FitMethod,
    pub robust: RobustOptions,
    pub nelder_mead: NelderMeadOptions,
    /// Estimate the parameters' standard uncertainty, intervals and correlation (default
    /// true); without it they are absent from the result. The colour-shift test of
    /// Cook–Torrance–Fresnel runs either way (it decides the fit).
    pub uncertainty: bool,
}

impl FitOptions {
    /// Default options for `model`: shared roughness, robust method, with uncertainty.
    pub fn new(model: Model) -> Self {
        FitOptions {
            model,
            roughness: Roughness::Shared,
            method: FitMethod::Robust,
            robust: RobustOptions::default(),
            nelder_mead: NelderMeadOptions::default(),
            uncertainty: true,
        }
    }
}

impl FitMethod {
    /// Name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            FitMethod::Robust => "robust",
            FitMethod::NelderMead => "nelder-mead",
        }
    }
}

impl FromStr for FitMethod {
    type Err = UnknownName;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "robust" => Ok(FitMethod::Robust),
            "nelder-mead" => Ok(FitMethod::NelderMead),
            _ => Err(UnknownName {
                what: "fit method",
                name: s.to_owned(),
                expected: "robust or nelder-mead",
            }),
        }
    }
}

impl fmt::Display for FitMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}
