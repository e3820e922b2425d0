//! Fitting a reflection model (Cook–Torrance, Ward, Cook–Torrance–Fresnel) to β samples by
//! minimising the eq. 10 loss, Σ_p sqrt(Σ_c (β_c,mea − β_c,est)²) (a sum of Euclidean
//! norms, not of squares). Every fit also reports the standard uncertainty of its
//! parameters (see `uncertainty`).
//!
//! Two methods:
//! - [`FitMethod::Robust`] (default): at fixed m the models are linear in Kd, Ks (and
//!   Ks_90) and the loss is convex in them, so it is minimised over them (≥ 0) for each trial m by
//!   reweighted non-negative least squares (see `linear`; relative tolerance 1e-9, 1e-3
//!   while scanning the grid; each solve after the first starts from the previous m's
//!   solution). log m is searched globally: a grid over the whole range
//!   (default 24 points on [1e-3, 2]), then Brent's method between the neighbours of every
//!   grid local minimum within 5 % of the best. Per-channel roughness starts from the
//!   shared optimum and searches each channel's m in turn (first round: grid then Brent;
//!   later rounds: Brent near the current value) until a round stops lowering the loss.
//!   Optionally polished by Nelder–Mead.
//! - [`FitMethod::NelderMead`]: the paper's downhill simplex over all parameters at once,
//!   MATLAB's fminsearch with its defaults (see `nelder_mead`), kept as the baseline for
//!   the paper's two models.
//!
//! β are in the camera-RGB domain (a white gives G = 100), so Kd is typically 0–100.
//!
//! A fit may also carry a measured table in (θh, θd) (`table`; [`fit_table`], or chosen
//! by `--model auto`): it then predicts with the table, and its parametric fields are a
//! parametric fit of the same samples, kept for renderers.
#![doc = include_str!("fit.md")]
#![doc = include_str!("fit/choice.md")]

pub mod agreement;
mod block_sums;
pub mod budget;
mod choice;
pub mod colour_change;
mod data;
mod departure;
mod draws;
mod error;
pub mod fold_score;
pub mod held_out;
mod linear;
mod lobe_columns;
mod nelder_mead;
mod newton;
mod options;
mod robust;
mod secant;
mod simplex;
mod stride;
pub mod table;
mod uncertainty;

use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::brdf::{Cosines, Model, Params, Roughness};
use crate::color::CameraModel;
use crate::metrics;
use crate::samples::distinct_theta_l;
use crate::samples::Sample;
use data::{Data, Found};
use table::{Shape, Table};

pub use choice::{
    best_parametric, choose_held_out, fit_auto, specular_uv_change, Candidate, Criterion,
    Selection, COLOUR_SHIFT_GAIN,
};
pub use data::fits_colour_shift;
pub use error::FitError;
pub use held_out::{leave_one_theta_l_out, Form, Variant, AUTO_CANDIDATES, CANDIDATES};
pub use options::{FitMethod, FitOptions, NelderMeadOptions, RobustOptions};
pub use stride::JUDGED_PER_THETA_L;
pub use uncertainty::{chi2_3_survival, ColourShift, Correlation, ParameterSet, Z95};

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
    /// Specular colour (Cook–Torrance–Fresnel: with light and camera together, γ = 0).
    pub ks: [f64; 3],
    /// Cook–Torrance–Fresnel only: the specular colour with light and camera 90° apart
    /// (θd = 45°); F_c is linear in cos γ = l·v between `ks` and this.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ks_90: Option<[f64; 3]>,
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
    /// Standard uncertainty of each parameter (`None` in files written without it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stderr: Option<ParameterSet<f64>>,
    /// 95 % interval of each parameter, `[lo, hi]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ci95: Option<ParameterSet<[f64; 2]>>,
    /// Correlations between fitted parameters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub correlation: Option<Correlation>,
    /// Cook–Torrance–Fresnel only: whether the colour shift was fitted, and its test.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour_shift: Option<ColourShift>,
    /// Nelder–Mead only: its loss against the global minimum of the same samples. A fit
    /// that ends above it reports no uncertainty.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub global_minimum: Option<GlobalMinimum>,
    /// `--model auto` only: the candidates' scores and why this model was chosen.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub selection: Option<Selection>,
    /// The uncertainty budget ([`budget::budget`]), when the samples carry their
    /// uncertainty and it was asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget: Option<budget::Budget>,
    /// The measured table in (θh, θd) the fit predicts with (`--model table`, or the
    /// table chosen by `--model auto`); the fields above are then a parametric fit of
    /// the same samples (loss and ΔErr_p its own), for renderers and readers that know
    /// no table.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub table: Option<Table>,
}

/// Where a local method (Nelder–Mead) ended, against the global minimum of the eq. 10
/// loss on the same samples: the robust method's (exact Kd, Ks at each m, a global
/// search over log m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GlobalMinimum {
    /// Whether the fit's loss is within [`LOCAL_MINIMUM_MARGIN`] of `loss`; when false
    /// the fit ended in a local minimum (or at its evaluation cap) and is not the
    /// optimum.
    pub reached: bool,
    /// Eq. 10 loss of the robust fit.
    pub loss: f64,
    /// Wall time of the robust fit, seconds (not in the fit's `seconds`).
    pub seconds: f64,
}

impl FitResult {
    /// Whether the fit is known to have ended above the global minimum.
    pub fn above_global_minimum(&self) -> bool {
        self.global_minimum.is_some_and(|g| !g.reached)
    }

    /// Its loss evaluations beyond those of `given`, the fit it was given as its tied
    /// form ([`fit_fresnel_given`] counts that fit's in its own); all of them without.
    pub(crate) fn evaluations_beyond(&self, given: Option<&FitResult>) -> u64 {
        self.evaluations
            .saturating_sub(given.map_or(0, |g| g.evaluations))
    }
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

    /// The specular colour with light and camera 90° apart: `ks_90`, or `ks` for the
    /// models whose specular colour is constant.
    pub fn specular_90(&self) -> [f64; 3] {
        self.ks_90.unwrap_or(self.ks)
    }

    /// The fit's model and coefficients as the shape a table predicts relative to.
    pub fn shape(&self) -> Shape {
        Shape {
            model: self.model,
            params: self.params(),
            ks_90: self.specular_90(),
        }
    }

    /// β the fit predicts at in-plane (θi, θr) in degrees.
    pub fn predict(&self, theta_i_deg: f64, theta_r_deg: f64) -> [f64; 3] {
        self.predict_at(
            &Cosines::in_plane(theta_i_deg, theta_r_deg),
            theta_i_deg >= theta_r_deg,
        )
    }

    /// β the fit predicts at a sample's point (its 3D cosines when it has them).
    pub fn predict_sample(&self, sample: &Sample) -> [f64; 3] {
        self.predict_at(&sample.cosines(), sample.theta_i >= sample.theta_r)
    }

    /// β the fit predicts at a point given by its 3D cosines, on the side `side`
    /// (θi ≥ θr) of the specular peak: the table's when it has one, else the model's.
    fn predict_at(&self, cosines: &Cosines, side: bool) -> [f64; 3] {
        match &self.table {
            Some(table) => table.predict_at(cosines, side, Some(&self.shape())),
            None => self
                .model
                .basis_at(cosines)
                .evaluate_fresnel(&self.params(), &self.specular_90()),
        }
    }
}

/// A fit whose loss exceeds the global minimum by more than this fraction of it ended
/// above it: in a local minimum, or stopped by its evaluation cap before the optimum.
pub const LOCAL_MINIMUM_MARGIN: f64 = 1e-3;

/// Significance level of the colour-shift test: Ks_90 is kept when the Wald test of
/// Ks_90 = Ks rejects it at this level.
pub const COLOUR_SHIFT_LEVEL: f64 = 0.01;

/// Decides whether a Cook–Torrance–Fresnel fit keeps its colour shift: by the Wald test
/// of Ks_90 = Ks at [`COLOUR_SHIFT_LEVEL`]; when the test is undefined (residuals without
/// noise leave the covariance singular), by whether the shift lowers the loss by more than
/// 1e-6 of the data's scale Σ‖y‖.
/// When it is dropped, `data` loses its shift weights and the fit is redone with
/// Ks_90 = Ks (`found`, `ks_90` replaced), or `tied` (that fit, done already, and its
/// seconds) is taken. Returns the test and the seconds of `tied` when it was taken.
fn test_colour_shift(
    data: &mut Data,
    options: &FitOptions,
    found: &mut Found,
    ks_90: &mut [f64; 3],
    tied: Option<(Found, f64)>,
) -> Result<(ColourShift, f64), FitError> {
    if data.shift_weight.is_none() {
        let untested = ColourShift {
            fitted: false,
            chi2: None,
            p_value: None,
        };
        return Ok((untested, 0.0));
    }
    let chi2 = uncertainty::shift_statistic(data, options, &found.params, ks_90);
    let p_value = chi2.map(chi2_3_survival);
    if p_value.is_some_and(|p| p < COLOUR_SHIFT_LEVEL) {
        let kept = ColourShift {
            fitted: true,
            chi2,
            p_value,
        };
        return Ok((kept, 0.0));
    }
    let shifted_loss = data.loss_fresnel(&found.params, ks_90);
    let weights = data.shift_weight.take();
    let ((mut tied, tied_90), reused_seconds) = match tied {
        Some((tied, seconds)) => {
            let ks = tied.params.ks;
            ((tied, ks), seconds)
        }
        None => (robust::fit(data, options)?, 0.0),
    };
    tied.evaluations += found.evaluations;
    // Without a test (no noise), a real decrease of the loss keeps the shift.
    let fitted =
        p_value.is_none() && data.loss(&tied.params) - shifted_loss > 1e-6 * data.zero_loss;
    if fitted {
        data.shift_weight = weights;
        found.evaluations = tied.evaluations;
    } else {
        (*found, *ks_90) = (tied, tied_90);
    }
    let tested = ColourShift {
        fitted,
        chi2,
        p_value,
    };
    Ok((tested, reused_seconds))
}

/// The eq. 10 loss of a model on samples, prepared once and evaluated at any parameters
/// the way the fits evaluate it (a shared roughness and one specular colour through the
/// columns' loop): what one evaluation costs, for the cost table's floors.
pub struct PreparedLoss(Data);

impl PreparedLoss {
    /// `model` on `samples` (more of them than its parameters with a shared roughness).
    pub fn new(samples: &[Sample], model: Model) -> Result<Self, FitError> {
        Data::new(samples, model, parameter_count(model, Roughness::Shared)).map(PreparedLoss)
    }

    /// Σ_p ‖y_p − β_p‖ at `params` and the specular colour at 90° `ks_90`.
    pub fn at(&self, params: &Params, ks_90: &[f64; 3]) -> f64 {
        self.0.loss_fresnel(params, ks_90)
    }
}

/// Number of fitted parameters of `model` with `roughness`.
pub fn parameter_count(model: Model, roughness: Roughness) -> usize {
    let colours = if model.has_fresnel_colour() { 9 } else { 6 };
    colours + roughness.count()
}

/// What a method ends at, before the result is assembled.
struct Minimised {
    /// The prepared samples (without the colour shift's weights when it was tied).
    data: Data,
    found: Found,
    ks_90: [f64; 3],
    colour_shift: Option<ColourShift>,
    /// Seconds of the given tied fit, when the colour-shift test used it.
    reused_seconds: f64,
}

/// The robust minimum of a fit near which another is sought: its parameters and
/// specular colour at 90°, before any colour-shift test (Ks_90 its own where the model
/// and samples have one).
pub(crate) type Start = (Params, [f64; 3]);

/// Runs `options.method` on `samples` (the robust method by Gauss–Newton steps from
/// `start` when given, [`newton`], its full search where they give up), and the
/// colour-shift test where the model has one (with the fit it falls back to, `tied`,
/// when given).
fn minimise(
    samples: &[Sample],
    options: &FitOptions,
    tied: Option<(Found, f64)>,
    start: Option<&Start>,
) -> Result<Minimised, FitError> {
    if options.model.has_fresnel_colour() {
        if options.method == FitMethod::NelderMead {
            return Err(FitError::InvalidOptions(format!(
                "{} is fitted by the robust method only (Nelder–Mead is the baseline of \
                 cook-torrance and ward)",
                options.model
            )));
        }
        if options.robust.polish {
            return Err(FitError::InvalidOptions(format!(
                "polishing applies to cook-torrance and ward, not {}",
                options.model
            )));
        }
    }
    let parameters = parameter_count(options.model, options.roughness);
    let mut data = Data::new(samples, options.model, parameters)?;
    let (mut found, mut ks_90) = match options.method {
        FitMethod::Robust => {
            match start
                .and_then(|(p, kg)| newton::refit(&data, options, p, *kg, newton::Tolerance::FINE))
            {
                Some(found) => found,
                None => robust::fit(&data, options)?,
            }
        }
        FitMethod::NelderMead => {
            let found = nelder_mead::fit(&data, options)?;
            let ks = found.params.ks;
            (found, ks)
        }
    };
    let (colour_shift, reused_seconds) = if options.model.has_fresnel_colour() {
        let (test, seconds) = test_colour_shift(&mut data, options, &mut found, &mut ks_90, tied)?;
        (Some(test), seconds)
    } else {
        (None, 0.0)
    };
    Ok(Minimised {
        data,
        found,
        ks_90,
        colour_shift,
        reused_seconds,
    })
}

/// The eq. 10 loss `options.method` ends at on `samples`: the fit alone, without its
/// metrics, uncertainty or check against the global minimum (what a comparison of
/// methods keeps); with its loss evaluations.
pub fn loss_reached(samples: &[Sample], options: &FitOptions) -> Result<(f64, u64), FitError> {
    let Minimised {
        data, found, ks_90, ..
    } = minimise(samples, options, None, None)?;
    let loss = data.loss_fresnel(&found.params, &ks_90);
    if !loss.is_finite() {
        return Err(FitError::Overflow("loss"));
    }
    Ok((loss, found.evaluations))
}

/// Fits `options.model` to `samples`.
pub fn fit(samples: &[Sample], options: &FitOptions) -> Result<FitResult, FitError> {
    fit_given(samples, options, None, None)
}

/// The robust minimum of `options`' model on `samples` ([`Start`]): where fits of
/// samples near these start from ([`fit_from`]). From `near` when given (a minimum of
/// the same samples with fewer free parameters: a shared roughness, or a constant
/// specular colour) by Gauss–Newton steps to the minimum within reach of it ([`newton`]),
/// by the full search where they give up or without it; with its loss evaluations.
pub(crate) fn robust_minimum_near(
    samples: &[Sample],
    options: &FitOptions,
    near: Option<&Start>,
) -> Result<(Start, u64), FitError> {
    let data = Data::new(
        samples,
        options.model,
        parameter_count(options.model, options.roughness),
    )?;
    let (found, ks_90) = match near
        .and_then(|(p, kg)| newton::refit(&data, options, p, *kg, newton::Tolerance::FINE))
    {
        Some(found) => found,
        None => robust::fit(&data, options)?,
    };
    Ok(((found.params, ks_90), found.evaluations))
}

/// [`fit`] of samples near those whose robust minimum is `start` (a subset of them): by
/// Gauss–Newton steps from it to the minimum within reach ([`newton`]), by the full
/// search where they give up or without a start; with [`fit_fresnel_given`]'s `tied`
/// when given.
pub(crate) fn fit_from(
    samples: &[Sample],
    options: &FitOptions,
    start: Option<&Start>,
    tied: Option<&FitResult>,
) -> Result<FitResult, FitError> {
    match tied {
        Some(tied) => fresnel_given(samples, options, tied, start),
        None => fit_given(samples, options, None, start),
    }
}

/// The table of `samples` ([`table`]) with `options`' parametric fit of the same
/// samples for its parametric fields, the shape it predicts relative to. With three θL
/// or more its chromaticity window is the one that predicts unseen θL best
/// ([`held_out::table_held_out`], ΔE_u′v′ through `camera`, each θL relative to the same
/// model fitted without it); with fewer, none.
pub fn fit_table(
    samples: &[Sample],
    options: &FitOptions,
    camera: &CameraModel,
) -> Result<FitResult, FitError> {
    let mut result = fit(samples, options)?;
    let judged = if distinct_theta_l(samples).len() >= 3 {
        let variant = Variant::new(options.model, options.roughness);
        let base = leave_one_theta_l_out(samples, &[variant], camera)?;
        held_out::table_held_out(samples, base.first(), camera).table
    } else {
        None
    };
    result.table = Some(match judged {
        Some(table) => table,
        None => Table::new(samples, 0.0)?,
    });
    Ok(result)
}

/// [`fit`] of Cook–Torrance–Fresnel given `tied`, the robust Cook–Torrance fit of the
/// same samples with the same options but the model: the fit its colour-shift test falls
/// back to when the shift is not significant, taken as it is instead of fitted again (its
/// evaluations and seconds are counted in the result's).
pub fn fit_fresnel_given(
    samples: &[Sample],
    options: &FitOptions,
    tied: &FitResult,
) -> Result<FitResult, FitError> {
    fresnel_given(samples, options, tied, None)
}

/// [`fit_fresnel_given`], from `start` when given ([`fit_from`]).
fn fresnel_given(
    samples: &[Sample],
    options: &FitOptions,
    tied: &FitResult,
    start: Option<&Start>,
) -> Result<FitResult, FitError> {
    let consistent = options.model == Model::CookTorranceFresnel
        && options.method == FitMethod::Robust
        && tied.model == Model::CookTorrance
        && tied.method == FitMethod::Robust
        && tied.roughness == options.roughness;
    if !consistent {
        return Err(FitError::InvalidOptions(format!(
            "a {} fit by the {} method with {} roughness is not the tied form of a robust {} \
             fit with {} roughness",
            tied.model, tied.method, tied.roughness, options.model, options.roughness
        )));
    }
    let found = Found {
        params: tied.params(),
        evaluations: tied.evaluations,
    };
    fit_given(samples, options, Some((found, tied.seconds)), start)
}

/// [`fit`], with the colour-shift test's tied fit and its seconds when given, from
/// `start` when given ([`fit_from`]).
fn fit_given(
    samples: &[Sample],
    options: &FitOptions,
    tied: Option<(Found, f64)>,
    from: Option<&Start>,
) -> Result<FitResult, FitError> {
    let start = Instant::now();
    let Minimised {
        data,
        found,
        ks_90,
        colour_shift,
        reused_seconds,
    } = minimise(samples, options, tied, from)?;
    let params = found.params;
    let m = match options.roughness {
        Roughness::Shared => FittedRoughness::Shared([params.m[0]]),
        Roughness::PerChannel => FittedRoughness::PerChannel(params.m),
    };
    let err_p = metrics::err_p(&data.y, &data.estimates(&params, &ks_90))?;
    let loss = data.loss_fresnel(&params, &ks_90);
    // JSON has no NaN or infinity: a fit that overflowed is an error, never `null`.
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    for (what, ok) in [
        ("loss", loss.is_finite()),
        ("kd", finite(&params.kd)),
        ("ks", finite(&params.ks)),
        ("ks_90", finite(&ks_90)),
        ("m", finite(&params.m)),
        ("err_p", finite(&err_p)),
    ] {
        if !ok {
            return Err(FitError::Overflow(what));
        }
    }
    let global_minimum = match options.method {
        FitMethod::NelderMead => Some(global_minimum(&data, options, loss)?),
        FitMethod::Robust => None,
    };
    // Intervals around a point that is not the optimum would describe nothing.
    let spread = (options.uncertainty && global_minimum.is_none_or(|g| g.reached))
        .then(|| uncertainty::estimate(&data, options, &params, &ks_90))
        .flatten();
    let (stderr, ci95, correlation) = match spread {
        Some(s) => (Some(s.stderr), Some(s.ci95), Some(s.correlation)),
        None => (None, None, None),
    };
    Ok(FitResult {
        model: options.model,
        roughness: options.roughness,
        kd: params.kd,
        ks: params.ks,
        ks_90: options.model.has_fresnel_colour().then_some(ks_90),
        m,
        rho_d: Some(options.model.diffuse_albedo(params.kd)),
        loss,
        err_p,
        method: options.method,
        evaluations: found.evaluations,
        seconds: start.elapsed().as_secs_f64() - global_minimum.map_or(0.0, |g| g.seconds)
            + reused_seconds,
        stderr,
        ci95,
        correlation,
        colour_shift,
        global_minimum,
        selection: None,
        budget: None,
        table: None,
    })
}

/// The robust fit of the same data and roughness as `options`, as the global minimum a
/// fit of loss `loss` is checked against.
fn global_minimum(data: &Data, options: &FitOptions, loss: f64) -> Result<GlobalMinimum, FitError> {
    let start = Instant::now();
    let mut robust = options.clone();
    robust.method = FitMethod::Robust;
    robust.robust.polish = false;
    let (found, ks_90) = robust::fit(data, &robust)?;
    let minimum = data.loss_fresnel(&found.params, &ks_90);
    Ok(GlobalMinimum {
        reached: loss <= minimum * (1.0 + LOCAL_MINIMUM_MARGIN),
        loss: minimum,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The eq. 10 minimum over the colour coefficients at one roughness.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoughnessSolve {
    /// Kd, Ks and the given m.
    pub params: Params,
    /// The specular colour at 90° (equal to Ks for the models without one).
    pub ks_90: [f64; 3],
    /// Eq. 10 loss there.
    pub loss: f64,
}

/// The eq. 10 minimum over Kd, Ks (Ks_90) ≥ 0 at the given roughness per channel.
/// The robust method's inner solve, exposed for profiles and brute-force checks.
pub fn solve_at_roughness(
    samples: &[Sample],
    model: Model,
    m: [f64; 3],
) -> Result<RoughnessSolve, FitError> {
    let data = Data::new(
        samples,
        model,
        parameter_count(model, Roughness::Shared) - 1,
    )?;
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
    Ok(RoughnessSolve {
        params: Params {
            kd: fit.kd,
            ks: fit.ks,
            m,
        },
        ks_90: fit.kg,
        loss: fit.loss,
    })
}
