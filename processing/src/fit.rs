//! Fitting Cook–Torrance or Ward to β samples by minimising the eq. 10 loss,
//! Σ_p sqrt(Σ_c (β_c,mea − β_c,est)²) (a sum of Euclidean norms, not of squares).
//!
//! Two methods:
//! - [`FitMethod::Robust`] (default): at fixed m the models are linear in Kd, Ks and the
//!   loss is convex in them, so it is minimised over Kd, Ks ≥ 0 for each trial m by
//!   reweighted non-negative least squares (see `linear`; relative tolerance 1e-9, 1e-3
//!   while scanning the grid; each solve after the first starts from the previous m's
//!   solution). log m is searched globally: a grid over the whole range
//!   (default 24 points on [1e-3, 2]), then Brent's method between the neighbours of every
//!   grid local minimum within 5 % of the best. Per-channel roughness starts from the
//!   shared optimum and searches each channel's m in turn (first round: grid then Brent;
//!   later rounds: Brent near the current value) until a round stops lowering the loss.
//!   Optionally polished by Nelder–Mead.
//! - [`FitMethod::NelderMead`]: the paper's downhill simplex over all parameters at once,
//!   MATLAB's fminsearch with its defaults (see `nelder_mead`), kept as the baseline.
//!
//! β are in the camera-RGB domain (a white gives G = 100), so Kd is typically 0–100.

mod linear;
mod nelder_mead;
mod robust;
mod simplex;

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::brdf::{Basis, Model, Params, Roughness, UnknownName};
use crate::metrics;
use crate::samples::Sample;

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
}

impl FitOptions {
    /// Default options for `model`: shared roughness, robust method.
    pub fn new(model: Model) -> Self {
        FitOptions {
            model,
            roughness: Roughness::Shared,
            method: FitMethod::Robust,
            robust: RobustOptions::default(),
            nelder_mead: NelderMeadOptions::default(),
        }
    }
}

/// Fitted roughness as written in the fit JSON: `[m]` or `[mr, mg, mb]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum FittedRoughness {
    Shared([f64; 1]),
    PerChannel([f64; 3]),
}

impl FittedRoughness {
    /// m per channel (R, G, B).
    pub fn per_channel(&self) -> [f64; 3] {
        match *self {
            FittedRoughness::Shared([m]) => [m; 3],
            FittedRoughness::PerChannel(m) => m,
        }
    }
}

/// A fit, serialised as the fit JSON (docs/ARCHITECTURE.md, "File formats").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitResult {
    pub model: Model,
    pub roughness: Roughness,
    pub kd: [f64; 3],
    pub ks: [f64; 3],
    pub m: FittedRoughness,
    /// Diffuse albedo per channel, on one scale for every model
    /// ([`Model::diffuse_albedo`] of `kd`); `None` only in fit files written before it
    /// was added.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rho_d: Option<[f64; 3]>,
    /// Eq. 10 loss at the fitted parameters.
    pub loss: f64,
    /// Eq. 11 per channel on the fitted samples.
    pub err_p: [f64; 3],
    pub method: FitMethod,
    /// Robust: evaluations of the loss profile at one m (one model evaluation at every
    /// point plus the reweighted Kd, Ks solve). Nelder–Mead: evaluations of the loss.
    pub evaluations: u64,
    /// Wall time of the fit in seconds.
    pub seconds: f64,
}

impl FitResult {
    /// The fitted parameters for [`Model::evaluate`].
    pub fn params(&self) -> Params {
        Params {
            kd: self.kd,
            ks: self.ks,
            m: self.m.per_channel(),
        }
    }

    /// β the fit predicts at in-plane (θi, θr) in degrees.
    pub fn predict(&self, theta_i_deg: f64, theta_r_deg: f64) -> [f64; 3] {
        self.model
            .evaluate(&self.params(), theta_i_deg, theta_r_deg)
    }

    /// β the fit predicts at a sample's point (its 3D cosines when it has them).
    pub fn predict_sample(&self, sample: &Sample) -> [f64; 3] {
        self.model.evaluate_at(&self.params(), &sample.cosines())
    }
}

/// Why a fit could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error("{points} sample points but the model has {parameters} parameters")]
    TooFewPoints { points: usize, parameters: usize },
    #[error("sample {index}: {field} is not finite")]
    NonFinite { index: usize, field: &'static str },
    #[error("sample {index}: direction at or past grazing (θi = {theta_i}°, θr = {theta_r}°)")]
    Grazing {
        index: usize,
        theta_i: f64,
        theta_r: f64,
    },
    #[error("channel {channel} has no signal (sum of β ≤ 0)")]
    NoSignal { channel: char },
    #[error("invalid fit options: {0}")]
    InvalidOptions(String),
    #[error("optimiser failed: {0}")]
    Optimizer(String),
    #[error("the fit's {0} is not finite: the β values are too large to fit")]
    Overflow(&'static str),
    #[error(transparent)]
    Metric(#[from] metrics::MetricsError),
}

/// Samples prepared for fitting.
pub(crate) struct Data {
    pub bases: Vec<Basis>,
    /// Diffuse basis per point (copied out of `bases` for the inner loops).
    pub diffuse: Vec<f64>,
    /// Measured β per point; 0 where a channel was dropped.
    pub y: Vec<[f64; 3]>,
    /// Per point and channel 1 (measured) or 0 (dropped: left out of the loss);
    /// `None` when no value was dropped.
    pub keep: Option<Vec<[f64; 3]>>,
    /// Residual norms below this count as this in reweighting.
    pub residual_floor: f64,
    /// Eq. 10 loss of the all-zero model, Σ_p ‖y_p‖: the scale of the data.
    pub zero_loss: f64,
}

impl Data {
    fn new(samples: &[Sample], model: Model, parameters: usize) -> Result<Data, FitError> {
        if samples.len() < parameters {
            return Err(FitError::TooFewPoints {
                points: samples.len(),
                parameters,
            });
        }
        let mut bases = Vec::with_capacity(samples.len());
        for (index, s) in samples.iter().enumerate() {
            if let Some(field) = s.non_finite_field() {
                return Err(FitError::NonFinite { index, field });
            }
            let basis = model.basis_at(&s.cosines());
            if basis.diffuse == 0.0 {
                return Err(FitError::Grazing {
                    index,
                    theta_i: s.theta_i,
                    theta_r: s.theta_r,
                });
            }
            bases.push(basis);
        }
        let y: Vec<[f64; 3]> = samples
            .iter()
            .map(|s| [0, 1, 2].map(|c| s.channel(c).unwrap_or(0.0)))
            .collect();
        let keep = samples.iter().any(|s| s.dropped.contains(&true)).then(|| {
            samples
                .iter()
                .map(|s| s.dropped.map(|d| if d { 0.0 } else { 1.0 }))
                .collect()
        });
        for (c, channel) in ['R', 'G', 'B'].into_iter().enumerate() {
            if y.iter().map(|v| v[c]).sum::<f64>() <= 0.0 {
                return Err(FitError::NoSignal { channel });
            }
        }
        let zero_loss: f64 = y.iter().map(|v| metrics::point_loss(v, &[0.0; 3])).sum();
        let mean_norm = zero_loss / y.len() as f64;
        Ok(Data {
            diffuse: bases.iter().map(|b| b.diffuse).collect(),
            bases,
            y,
            keep,
            residual_floor: 1e-12 * mean_norm + f64::MIN_POSITIVE,
            zero_loss,
        })
    }

    /// Eq. 10 loss of `params` over the measured values.
    pub fn loss(&self, params: &Params) -> f64 {
        self.estimates(params)
            .iter()
            .zip(&self.y)
            .map(|(estimate, y)| metrics::point_loss(y, estimate))
            .sum()
    }

    /// The model's β at every point, 0 where the measured value was dropped (so dropped
    /// values count in neither the loss nor ΔErr_p).
    fn estimates(&self, params: &Params) -> Vec<[f64; 3]> {
        let mut estimates: Vec<[f64; 3]> = self.bases.iter().map(|b| b.evaluate(params)).collect();
        if let Some(keep) = &self.keep {
            for (estimate, keep) in estimates.iter_mut().zip(keep) {
                for (e, k) in estimate.iter_mut().zip(keep) {
                    *e *= k;
                }
            }
        }
        estimates
    }
}

/// Parameters found by a method, before the result is assembled.
pub(crate) struct Found {
    pub params: Params,
    pub evaluations: u64,
}

/// Fits `options.model` to `samples`.
pub fn fit(samples: &[Sample], options: &FitOptions) -> Result<FitResult, FitError> {
    let start = Instant::now();
    let parameters = 6 + options.roughness.count();
    let data = Data::new(samples, options.model, parameters)?;
    let found = match options.method {
        FitMethod::Robust => robust::fit(&data, options)?,
        FitMethod::NelderMead => nelder_mead::fit(&data, options)?,
    };
    let params = found.params;
    let m = match options.roughness {
        Roughness::Shared => FittedRoughness::Shared([params.m[0]]),
        Roughness::PerChannel => FittedRoughness::PerChannel(params.m),
    };
    let err_p = metrics::err_p(&data.y, &data.estimates(&params))?;
    let loss = data.loss(&params);
    // JSON has no NaN or infinity: a fit that overflowed is an error, never `null`.
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    for (what, ok) in [
        ("loss", loss.is_finite()),
        ("kd", finite(&params.kd)),
        ("ks", finite(&params.ks)),
        ("m", finite(&params.m)),
        ("err_p", finite(&err_p)),
    ] {
        if !ok {
            return Err(FitError::Overflow(what));
        }
    }
    Ok(FitResult {
        model: options.model,
        roughness: options.roughness,
        kd: params.kd,
        ks: params.ks,
        m,
        rho_d: Some(options.model.diffuse_albedo(params.kd)),
        loss,
        err_p,
        method: options.method,
        evaluations: found.evaluations,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The eq. 10 minimum over Kd, Ks ≥ 0 at the given roughness per channel, with its loss.
/// The robust method's inner solve, exposed for profiles and brute-force checks.
pub fn solve_at_roughness(
    samples: &[Sample],
    model: Model,
    m: [f64; 3],
) -> Result<(Params, f64), FitError> {
    let data = Data::new(samples, model, 6)?;
    let spec: Vec<Vec<f64>> = m
        .iter()
        .map(|&mc| data.bases.iter().map(|b| b.specular(mc)).collect())
        .collect();
    let fit = linear::solve(
        &data,
        [&spec[0], &spec[1], &spec[2]],
        linear::FINE_TOLERANCE,
        false,
        &mut linear::Workspace::default(),
    );
    Ok((
        Params {
            kd: fit.kd,
            ks: fit.ks,
            m,
        },
        fit.loss,
    ))
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
