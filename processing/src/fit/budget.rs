//! The uncertainty budget of a fit, as the GUM states one (JCGM 100; docs/ARCHITECTURE.md,
//! "Uncertainty budget").
//!
//! Measurement model: the fitted parameters θ = F(β₁ … β_N) are the eq. 10 minimum over
//! the samples' β, and each β_p = β̂_p + Σ_j c_pj·z_j + e_p: the value measured, the
//! inputs of the setup (white reflectance, geometry, arm) each off by z_j standard
//! uncertainties, with c_pj the change of β_p for z_j = 1 ([`SampleUncertainty::sources`],
//! common to every point, or to one θL's points for the arm's angle), and e_p the
//! independent noise. The noise and misfit lines are taken at the values with the setup's
//! departure that best explains the residuals removed (`super::departure`), the sources'
//! lines at the values as measured. Each source's contribution
//! to a parameter comes from fitting again with the samples moved by ±k·c_·j and unmoved:
//! the secant's slope and the second difference per standard uncertainty (the law of
//! propagation with numerical sensitivity coefficients and its second-order term, JCGM 100
//! §5.1.2–5.1.3). The arm's angle is one source per θL, its contributions added in
//! quadrature. The noise and the model misfit come from the unmoved fit's residuals (the
//! HC1 sandwich, see `super::uncertainty`): its variance is split between them in the
//! ratio of the residuals' Σ r² to the noise's Σ u² the samples state (what the residuals
//! show beyond the noise is misfit). The combined standard uncertainty is the root sum of
//! squares of the lines (the sources are independent); U = k·u_c with k = 2.
//! Kd, Ks and Ks_90 are reported as they are; the roughness on the log scale (its lines are
//! m times those of ln m; its interval m·exp(±k·u_c(ln m))).
//!
//! [`monte_carlo`] propagates the same model by JCGM 101: every source and the noise drawn
//! at once, the fit repeated per draw.
#![doc = include_str!("budget.md")]

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::data::Data;
use super::draws::Normal;
pub use super::draws::{Convergence, Distribution};
use super::robust::Precision;
use super::secant::{Secant, LINEAR_TOLERANCE, SECANT_SPAN};
use super::{
    departure, newton, parameter_count, robust, uncertainty, FitError, FitMethod, FitOptions,
    FitResult, ParameterSet,
};
use crate::brdf::{Params, Roughness, M_MAX, M_MIN};
use crate::samples::{distinct_theta_l, Sample, SampleUncertainty, THETA_L_TOLERANCE};
use crate::setup_uncertainty::Source;

pub use super::secant::COVERAGE_FACTOR;

/// The refits search m within this factor of the fit's roughness (each way).
const REFIT_M_RANGE: f64 = 1.5;

/// Points of the refits' grid over log m (the fit's own search uses 24 over a wider range).
const REFIT_GRID_POINTS: usize = 6;

/// A refit warm-started from a nearby fit brackets its minimum from that fit's ln m in
/// steps of this (a factor 1.02 in m), doubling downhill, within the refit range
/// ([`robust::fit_near`]).
const WARM_STEP: f64 = 0.02;

/// The Monte Carlo's refits: each solve to 1e-6 of the loss and m to 0.1 % of itself (the
/// law of propagation's to about 1e-6), inside the spread of the draws: on gold, red
/// and opal the intervals' ends move by at most 3 % of their width against the fine refits
/// (red at binning 4, whose m interval is 1.6 % wide), below the 2.5 % percentile's own
/// noise (about 3.4 % of the width of a normal's interval at 400 draws).
const MONTE_CARLO_PRECISION: Precision = Precision {
    solve: 1e-6,
    ln_m_relative: 0.0,
    ln_m_absolute: 1e-3,
};

/// The Monte Carlo's Gauss–Newton refits stop at steps of 1e-5 (ln m, and colour
/// coefficients relative to the largest of their kind), a predicted decrease of 1e-8 of
/// the loss, or after a step taken whole that predicted 1e-6: on the full-size gold scan,
/// 1,000 draws' standard deviations move by 4e-6 of themselves and m's interval ends by
/// 1e-4 of its width against the fine refits (the step taken whole by a further 4e-6,
/// and the interval's ends not at all).
const MONTE_CARLO_TOLERANCE: newton::Tolerance = newton::Tolerance {
    step: 1e-5,
    decrement: 1e-8,
    last: 1e-6,
};

/// One line of a parameter's budget: a source and its contribution (a standard
/// uncertainty in the parameter's unit).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Contribution {
    /// `noise`, `misfit`, or a [`Source::name`].
    pub source: String,
    pub u: f64,
}

/// The budget of one parameter.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ParameterBudget {
    /// The fitted value.
    pub value: f64,
    /// Every line, noise and misfit first, then the sources in [`Source::ALL`]'s order.
    pub contributions: Vec<Contribution>,
    /// Combined standard uncertainty u_c.
    pub combined: f64,
    /// Expanded uncertainty U = k·u_c.
    pub expanded: f64,
    /// The interval value ± U (the roughness: m·exp(±k·u_c(ln m))), its lower end at
    /// least 0; or, where the parameter does not follow a source linearly over ±k u, its
    /// ends from the refits ([`IntervalFrom`]).
    pub interval: [f64; 2],
    /// How the interval was found (older files lack it: the law of propagation).
    #[serde(default)]
    pub interval_from: IntervalFrom,
}

/// How a parameter's interval was found.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum IntervalFrom {
    /// value ± k·u_c: every source moves the parameter linearly over ±k u.
    #[default]
    LawOfPropagation,
    /// Some source does not (`Secant::bend`) and its refits within ±k u reach farther
    /// than k times its line on a side: on that side, the distance from the fit to its
    /// refits' farthest value in place of k times its line, added in quadrature with
    /// k times the other lines.
    RefitEnds,
}

impl IntervalFrom {
    /// "law of propagation" or "refit ends", for a person.
    pub fn describe(self) -> &'static str {
        match self {
            IntervalFrom::LawOfPropagation => "law of propagation",
            IntervalFrom::RefitEnds => "refit ends",
        }
    }
}

/// The uncertainty budget of a fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Budget {
    /// k of U = k·u_c.
    pub coverage_factor: f64,
    /// √(Σ r² / Σ u_noise²) over the measured values with the setup's departure removed:
    /// the residuals' scatter over the noise the samples state (1: the model fits to the
    /// noise).
    pub residual_to_noise: f64,
    /// The departure of the setup that best explains the fit's residuals, for each source
    /// the residuals identify (the arm's angle per θL; see `departure`'s criterion), in
    /// standard uncertainties: the noise and misfit lines are taken at the values with it
    /// removed. Not a calibration: the fitted values keep the stated setup.
    #[serde(default)]
    pub departure: Vec<SourceDeparture>,
    pub parameters: ParameterSet<ParameterBudget>,
    /// The same propagation by Monte Carlo, when asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub monte_carlo: Option<MonteCarlo>,
    /// The refits' passes over the points (loss evaluations and Gauss–Newton passes):
    /// the budget's work (older files lack it).
    #[serde(default)]
    pub evaluations: u64,
}

/// One source's departure from the stated setup, as the residuals suggest it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceDeparture {
    /// A [`Source::name`].
    pub source: String,
    /// The arm angle θL (degrees) whose angle this is, for `arm_angle`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_l: Option<f64>,
    /// The world's setup as the residuals suggest it: the stated one plus `z` standard
    /// uncertainties of the source.
    pub z: f64,
    /// Its posterior standard deviation, in standard uncertainties (older files lack it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std: Option<f64>,
}

/// A Monte Carlo propagation (JCGM 101) of the budget's model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MonteCarlo {
    pub draws: usize,
    pub parameters: ParameterSet<Distribution>,
    /// Per parameter, whether its interval agrees with the budget's and which holds
    /// ([`super::agreement::compare`]; older files lack it).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub agreement: Vec<super::agreement::Agreement>,
    /// The draws' refits' passes over the points, as [`Budget::evaluations`] counts them.
    #[serde(default)]
    pub evaluations: u64,
}

impl Budget {
    /// Every parameter's budget with its name (`kd_r`, …, `m` or `m_r`, …), in order.
    pub fn named(&self) -> Vec<(String, &ParameterBudget)> {
        let p = &self.parameters;
        let channel = ["r", "g", "b"];
        let mut out = Vec::new();
        for (name, set) in [
            ("kd", Some(&p.kd)),
            ("ks", Some(&p.ks)),
            ("ks_90", p.ks_90.as_ref()),
        ] {
            if let Some(set) = set {
                for (c, b) in set.iter().enumerate() {
                    out.push((format!("{name}_{}", channel[c]), b));
                }
            }
        }
        for (c, b) in p.m.iter().enumerate() {
            let name = if p.m.len() == 1 {
                "m".to_string()
            } else {
                format!("m_{}", channel[c])
            };
            out.push((name, b));
        }
        out
    }
}

/// The parameters of a fit as one vector: Kd, Ks, Ks_90 (models with one) per channel,
/// then ln m (one or per channel).
fn vector(kd: [f64; 3], ks: [f64; 3], ks_90: Option<[f64; 3]>, m: &[f64]) -> Vec<f64> {
    kd.iter()
        .chain(&ks)
        .chain(ks_90.iter().flatten())
        .copied()
        .chain(m.iter().map(|m| m.ln()))
        .collect()
}

/// The fitter of the perturbed samples: the fit's model, roughness and colour-shift
/// decision, by the robust method, on the same points with other β.
#[derive(Clone)]
struct Refit<'a> {
    data: Data,
    options: FitOptions,
    fresnel: bool,
    samples: &'a [Sample],
    /// A fit near the refits' (its parameters and specular colour at 90°), which they
    /// start from ([`robust::fit_near`]); `None`: each searches the whole refit range
    /// ([`robust::fit`]).
    near: Option<(Params, [f64; 3])>,
    /// How finely a refit started from `near` converges: by Gauss–Newton steps, and
    /// where they give up by the search along ln m.
    tolerance: newton::Tolerance,
    precision: Precision,
    /// Passes over the points of every solve by this refitter and its clones.
    work: Arc<AtomicU64>,
}

impl Refit<'_> {
    /// θ of the fit to the measured values `moved` (one per sample).
    fn fit(&self, moved: &[[f64; 3]]) -> Result<Vec<f64>, FitError> {
        self.fit_from(moved.to_vec(), self.near.as_ref())
    }

    /// θ of the fit to the measured values `moved`, started from `near` as
    /// [`Refit::solve_from`] starts.
    fn fit_from(
        &self,
        moved: Vec<[f64; 3]>,
        near: Option<&(Params, [f64; 3])>,
    ) -> Result<Vec<f64>, FitError> {
        let (params, ks_90) = self.solve_from(&self.data.with_measured(moved), near)?;
        let m = &params.m[..self.options.roughness.count()];
        let ks_90 = self.fresnel.then_some(ks_90);
        Ok(vector(params.kd, params.ks, ks_90, m))
    }

    /// The parameters and specular colour at 90° of θ in [`vector`]'s order, the colour
    /// coefficients clamped at 0.
    fn parameters(&self, theta: &[f64]) -> (Params, [f64; 3]) {
        let colour = |i: usize| theta[i].max(0.0);
        let kd = std::array::from_fn(colour);
        let ks = std::array::from_fn(|c| colour(3 + c));
        let ks_90 = if self.fresnel {
            std::array::from_fn(|c| colour(6 + c))
        } else {
            ks
        };
        let ln_m = &theta[if self.fresnel { 9 } else { 6 }..];
        let m = std::array::from_fn(|c| ln_m[c.min(ln_m.len() - 1)].exp());
        (Params { kd, ks, m }, ks_90)
    }

    /// The fit to `data` (the refitter's points): from `near` by Gauss–Newton steps.
    fn solve(&self, data: &Data) -> Result<(Params, [f64; 3]), FitError> {
        self.solve_from(data, self.near.as_ref())
    }

    /// The fit to `data` (the refitter's points): from `near` by Gauss–Newton steps
    /// ([`newton::refit`]), or where they give up by a search along ln m from there
    /// ([`robust::fit_near`]); without `near` by a search of the whole refit range
    /// ([`robust::fit`]); the parameters and specular colour at 90°.
    fn solve_from(
        &self,
        data: &Data,
        near: Option<&(Params, [f64; 3])>,
    ) -> Result<(Params, [f64; 3]), FitError> {
        let (found, ks_90) = match near {
            Some((start, kg)) => {
                match newton::refit(data, &self.options, start, *kg, self.tolerance) {
                    Some(found) => found,
                    None => robust::fit_near(
                        data,
                        &self.options,
                        start,
                        *kg,
                        WARM_STEP,
                        self.precision,
                    )?,
                }
            }
            None => robust::fit(data, &self.options)?,
        };
        self.work.fetch_add(found.evaluations, Ordering::Relaxed);
        Ok((found.params, ks_90))
    }

    /// The measured β moved by `scale` × `change(sample)` where `at(sample)`.
    fn moved(
        &self,
        scale: f64,
        change: impl Fn(&SampleUncertainty) -> [f64; 3],
        at: impl Fn(&Sample) -> bool,
    ) -> Vec<[f64; 3]> {
        self.samples
            .iter()
            .zip(&self.data.y)
            .map(|(s, y)| match (&s.uncertainty, at(s)) {
                (Some(u), true) => {
                    let d = change(u);
                    std::array::from_fn(|c| y[c] + scale * d[c])
                }
                _ => *y,
            })
            .collect()
    }

    /// A source's refits per parameter: the fits with the samples moved by
    /// ±[`SECANT_SPAN`]·`change` where `at`, against `base`, the fit of the unmoved values.
    fn secants(
        &self,
        base: &[f64],
        change: impl Fn(&SampleUncertainty) -> [f64; 3] + Copy,
        at: impl Fn(&Sample) -> bool + Copy,
    ) -> Result<Vec<Secant>, FitError> {
        let h = SECANT_SPAN;
        // Values the source does not move refit to `base` itself.
        let refit = |scale: f64, near: Option<&(Params, [f64; 3])>| {
            let moved = self.moved(scale, change, at);
            if moved == self.data.y {
                Ok(base.to_vec())
            } else {
                self.fit_from(moved, near)
            }
        };
        let plus = refit(h, self.near.as_ref())?;
        // The other side starts where the parameters would be if they followed the
        // source linearly: base − (plus − base), which leaves it a step of the order of
        // the source's bend to go rather than of its line.
        let mirrored: Vec<f64> = base.iter().zip(&plus).map(|(b, p)| 2.0 * b - p).collect();
        let start = self.near.as_ref().map(|_| self.parameters(&mirrored));
        let minus = refit(-h, start.as_ref().or(self.near.as_ref()))?;
        Ok(plus
            .iter()
            .zip(&minus)
            .zip(base)
            .map(|((&plus, &minus), &base)| Secant { base, plus, minus })
            .collect())
    }
}

/// [`budget`] when `samples` carry their uncertainty and `result` its standard
/// uncertainties; `None` otherwise (nothing to propagate).
pub fn budget_if_possible(
    samples: &[Sample],
    result: &FitResult,
) -> Result<Option<Budget>, FitError> {
    if result.stderr.is_none() || samples.iter().any(|s| s.uncertainty.is_none()) {
        return Ok(None);
    }
    budget(samples, result).map(Some)
}

/// β the fit's parametric model predicts at a sample (a fit that predicts with a table
/// keeps its parametric fit beside it: that is the fit the budget is of).
fn parametric(result: &FitResult, sample: &Sample) -> [f64; 3] {
    result
        .model
        .basis_at(&sample.cosines())
        .evaluate_fresnel(&result.params(), &result.specular_90())
}

/// Why a budget could not be made.
fn missing(what: &str) -> FitError {
    FitError::InvalidOptions(format!("no uncertainty budget: {what}"))
}

/// The refitter of `result`'s model on `samples`, which must carry their uncertainty.
fn refitter<'a>(samples: &'a [Sample], result: &FitResult) -> Result<Refit<'a>, FitError> {
    let mut options = FitOptions::new(result.model);
    options.roughness = result.roughness;
    if samples.iter().any(|s| s.uncertainty.is_none()) {
        return Err(missing(
            "the samples carry no uncertainty columns (extract them again with this version)",
        ));
    }
    let mut data = Data::new(
        samples,
        result.model,
        parameter_count(result.model, result.roughness),
    )?;
    // The colour shift stays as the fit decided it.
    let fresnel = result.model.has_fresnel_colour();
    if !result.colour_shift.is_some_and(|c| c.fitted) {
        data.shift_weight = None;
    }
    options.method = FitMethod::Robust;
    options.uncertainty = false;
    options.robust.polish = false;
    // A perturbation of one standard uncertainty moves m little: the refits search
    // within a factor [`REFIT_M_RANGE`] of the fit's roughness, on a coarser grid.
    let m = result.m.per_channel();
    let (lo, hi) = (
        m.iter().copied().fold(f64::INFINITY, f64::min),
        m.iter().copied().fold(0.0, f64::max),
    );
    options.robust.m_min = (lo / REFIT_M_RANGE).max(M_MIN);
    options.robust.m_max = (hi * REFIT_M_RANGE).min(M_MAX);
    options.robust.grid_points = REFIT_GRID_POINTS;
    Ok(Refit {
        data,
        options,
        fresnel,
        samples,
        near: None,
        tolerance: newton::Tolerance::FINE,
        precision: Precision::FINE,
        work: Arc::default(),
    })
}

/// The budget of `result`, a fit of `samples` (its model and roughness; the refits are
/// robust). The samples must carry their uncertainty ([`Sample::uncertainty`]) and the
/// fit its standard uncertainties (`stderr`, the noise and misfit lines).
pub fn budget(samples: &[Sample], result: &FitResult) -> Result<Budget, FitError> {
    let stderr = result
        .stderr
        .as_ref()
        .ok_or_else(|| missing("the fit has no standard uncertainties"))?;
    let mut refit = refitter(samples, result)?;
    let m = result.m.per_channel();
    let m = &m[..result.roughness.count()];
    let value = vector(result.kd, result.ks, result.ks_90, m);
    let fresnel = result.ks_90.is_some();
    let theta_l = distinct_theta_l(samples);

    // The noise and misfit lines are taken at the values with the setup's departure removed.
    let departure = departure::estimate(
        &refit.data,
        samples,
        &result.params(),
        &result.specular_90(),
        &theta_l,
        fresnel,
        result.roughness == Roughness::Shared,
    )?;
    let departures: Vec<SourceDeparture> = departure
        .z
        .iter()
        .map(|found| SourceDeparture {
            source: found.source.name().into(),
            theta_l: found.theta_l,
            // The residuals are the measured values less the truth's, −c·d for a world at
            // the stated setup + d·u.
            z: -found.z,
            std: Some(found.std),
        })
        .collect();
    // The values as measured, when a departure is removed from them: the sources' lines
    // are taken there (the values with the departure removed are the measured ones moved
    // linearly along the columns, which distorts a sharp lobe rather than shifting it).
    // Each refit starts from the unmoved fit of its values.
    let measured = (!departures.is_empty()).then(|| Refit {
        near: Some((result.params(), result.specular_90())),
        ..refit.clone()
    });
    // Their fit starts from the fit of the values as measured, which differ from them by
    // the departure only (a few standard uncertainties of the sources at most).
    refit.data = refit.data.with_measured(departure.corrected);
    refit.near = Some((result.params(), result.specular_90()));
    // The fit of the values as measured (where the sources' lines are taken when a
    // departure is removed) runs alongside that of the corrected values.
    let (solved, measured_base) = rayon::join(
        || refit.solve(&refit.data),
        || measured.as_ref().map(|m| m.fit(&m.data.y)).transpose(),
    );
    let (params, ks_90) = solved?;
    let measured_base = measured_base?;
    let base = vector(
        params.kd,
        params.ks,
        refit.fresnel.then_some(ks_90),
        &params.m[..m.len()],
    );
    refit.near = Some((params, ks_90));
    let spread = uncertainty::estimate(&refit.data, &refit.options, &params, &ks_90);
    // The HC1 standard uncertainties in the same layout (stderr.m is m·σ(ln m)); the
    // fit's own where the corrected values' are not defined.
    let stderr = spread.as_ref().map_or(stderr, |s| &s.stderr);
    let scatter: Vec<f64> = stderr
        .kd
        .iter()
        .chain(&stderr.ks)
        .chain(
            result
                .ks_90
                .map(|_| stderr.ks_90.unwrap_or(stderr.ks))
                .iter()
                .flatten(),
        )
        .copied()
        .chain(stderr.m.iter().zip(m).map(|(s, m)| s / m))
        .collect();

    // What is left of the residuals against the noise the samples state.
    let estimates = refit.data.estimates(&params, &ks_90);
    let (mut residual2, mut noise2) = (0.0, 0.0);
    for ((s, e), y) in samples.iter().zip(&estimates).zip(&refit.data.y) {
        let u = s.uncertainty.as_ref().map_or([0.0; 3], |u| u.noise);
        for c in (0..3).filter(|&c| !s.dropped[c]) {
            residual2 += (y[c] - e[c]).powi(2);
            noise2 += u[c] * u[c];
        }
    }
    let ratio = if noise2 > 0.0 {
        (residual2 / noise2).sqrt()
    } else {
        f64::INFINITY
    };
    let noise_share = if ratio > 1.0 { 1.0 / ratio } else { 1.0 };
    let misfit_share = (1.0 - noise_share * noise_share).max(0.0).sqrt();

    // Common sources: one fit pair each; the arm's angle: one pair per θL.
    let mut jobs: Vec<(usize, Option<f64>)> = (0..Source::COUNT)
        .filter(|&j| Source::ALL[j] != Source::ArmAngle)
        .map(|j| (j, None))
        .collect();
    let angle = Source::ArmAngle.index();
    jobs.extend(theta_l.iter().map(|&t| (angle, Some(t))));
    let (state, state_base) = match (&measured, measured_base) {
        (Some(measured), Some(fit)) => (measured, fit),
        _ => (&refit, base.clone()),
    };
    let secants: Vec<(usize, Vec<Secant>)> = jobs
        .par_iter()
        .map(|&(j, at)| {
            let change = move |u: &SampleUncertainty| u.sources[j];
            let within =
                move |s: &Sample| at.is_none_or(|t| (s.theta_l - t).abs() <= THETA_L_TOLERANCE);
            Ok((j, state.secants(&state_base, change, within)?))
        })
        .collect::<Result<_, FitError>>()?;
    // Per source and parameter: the line, the excursions above and below within ±k u
    // (the arm's angle's per θL added in quadrature), and whether it is linear.
    let mut lines = vec![vec![0.0f64; value.len()]; Source::COUNT];
    let mut ends = vec![vec![[0.0f64; 2]; value.len()]; Source::COUNT];
    let mut bent = vec![vec![[0.0f64; 2]; value.len()]; Source::COUNT];
    for (j, secants) in &secants {
        for (i, secant) in secants.iter().enumerate() {
            let d = secant.line();
            lines[*j][i] = lines[*j][i].hypot(d);
            let [up, down] = secant.excursions();
            ends[*j][i] = [ends[*j][i][0].hypot(up), ends[*j][i][1].hypot(down)];
            bent[*j][i] = [
                bent[*j][i][0].hypot(secant.bend()),
                bent[*j][i][1].hypot(secant.bend_bound()),
            ];
        }
    }

    let k = COVERAGE_FACTOR;
    let logs = value.len() - m.len();
    let parameter = |i: usize| {
        let log = i >= logs;
        // Lines of ln m are reported as lines of m.
        let unit = if log { value[i].exp() } else { 1.0 };
        let scatter = scatter[i];
        let mut contributions = vec![
            Contribution {
                source: "noise".into(),
                u: unit * scatter * noise_share,
            },
            Contribution {
                source: "misfit".into(),
                u: unit * scatter * misfit_share,
            },
        ];
        contributions.extend(
            Source::ALL
                .iter()
                .zip(&lines)
                .map(|(s, line)| Contribution {
                    source: s.name().into(),
                    u: unit * line[i],
                }),
        );
        let combined_raw =
            (scatter * scatter + lines.iter().map(|l| l[i] * l[i]).sum::<f64>()).sqrt();
        // The half-widths above and below the value (in ln m for the roughness): k·u_c,
        // or on a side where a source that bends (see [`Secant::bend`]; a bend under a
        // tenth of k·u_c is immaterial) moves the parameter farther within ±k u than k
        // times its line, that source's own excursion in its place.
        let linear =
            |j: usize| bent[j][i][0] <= bent[j][i][1].max(LINEAR_TOLERANCE * k * combined_raw);
        let half_width = |side: usize| {
            let sources: f64 = (0..Source::COUNT)
                .map(|j| {
                    let d = k * lines[j][i];
                    let d = if linear(j) {
                        d
                    } else {
                        d.max(ends[j][i][side])
                    };
                    d * d
                })
                .sum();
            ((k * scatter).powi(2) + sources).sqrt()
        };
        let [above, below] = [half_width(0), half_width(1)];
        let from = if above.max(below) > k * combined_raw * (1.0 + 1e-9) {
            IntervalFrom::RefitEnds
        } else {
            IntervalFrom::LawOfPropagation
        };
        let (reported, interval) = if log {
            let m = value[i].exp();
            (m, [m * (-below).exp(), m * above.exp()])
        } else {
            (value[i], [(value[i] - below).max(0.0), value[i] + above])
        };
        ParameterBudget {
            value: reported,
            contributions,
            combined: unit * combined_raw,
            expanded: k * unit * combined_raw,
            interval,
            interval_from: from,
        }
    };
    let n_colour = if fresnel { 9 } else { 6 };
    let budget = Budget {
        coverage_factor: k,
        residual_to_noise: if ratio.is_finite() { ratio } else { 0.0 },
        departure: departures,
        parameters: ParameterSet {
            kd: std::array::from_fn(parameter),
            ks: std::array::from_fn(|c| parameter(3 + c)),
            ks_90: fresnel.then(|| std::array::from_fn(|c| parameter(6 + c))),
            m: (n_colour..value.len()).map(parameter).collect(),
        },
        monte_carlo: None,
        evaluations: refit.work.load(Ordering::Relaxed),
    };
    let finite = budget
        .named()
        .iter()
        .all(|(_, b)| b.combined.is_finite() && b.interval.iter().all(|v| v.is_finite()));
    if !finite {
        return Err(FitError::Overflow("uncertainty budget"));
    }
    Ok(budget)
}

/// What a Monte Carlo draw moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Draw {
    /// The setup's sources only (the part the law of propagation computes by sensitivity).
    Sources,
    /// The sources and each value's noise (scaled by the residuals' scatter over the noise
    /// when it is larger: misfit drawn as if independent).
    All,
}

/// The distribution of every parameter of `result` (a fit of `samples`) over `draws`
/// Monte Carlo draws of the measurement model, reproducible from `seed`: in each draw
/// every common source, each θL's arm angle and (with [`Draw::All`]) each value's noise
/// are drawn from their normal distributions and the fit is repeated. Its `agreement` is
/// left to the caller ([`super::agreement::compare`] with the budget).
pub fn monte_carlo(
    samples: &[Sample],
    result: &FitResult,
    draws: usize,
    what: Draw,
    seed: u64,
) -> Result<MonteCarlo, FitError> {
    if draws < 2 {
        return Err(FitError::InvalidOptions(format!(
            "a Monte Carlo needs 2 draws or more, got {draws}"
        )));
    }
    let mut refit = refitter(samples, result)?;
    // Each draw's fit starts from the fit of the values drawn around.
    refit.near = Some((result.params(), result.specular_90()));
    refit.tolerance = MONTE_CARLO_TOLERANCE;
    refit.precision = MONTE_CARLO_PRECISION;
    let theta_l = distinct_theta_l(samples);
    let scale = match what {
        Draw::Sources => 0.0,
        Draw::All => {
            let (mut r2, mut u2) = (0.0, 0.0);
            for s in samples {
                let e = parametric(result, s);
                let u = s.uncertainty.as_ref().map_or([0.0; 3], |u| u.noise);
                for c in (0..3).filter(|&c| !s.dropped[c]) {
                    r2 += (s.rgb[c] - e[c]).powi(2);
                    u2 += u[c] * u[c];
                }
            }
            if u2 > 0.0 {
                (r2 / u2).sqrt().max(1.0)
            } else {
                1.0
            }
        }
    };
    let angle = Source::ArmAngle.index();
    let fits: Vec<Vec<f64>> = (0..draws)
        .into_par_iter()
        .map(|d| {
            let mut normal = Normal::new(seed ^ (d as u64).wrapping_mul(0xd6e8_feb8_6659_fd93));
            // The sources added later draw from a stream of their own, so that adding
            // them left every other draw as it was.
            let mut later = Normal::new(!seed ^ (d as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            let z: Vec<f64> = Source::ALL
                .iter()
                .map(|s| {
                    if Source::LATER.contains(s) {
                        later.next()
                    } else {
                        normal.next()
                    }
                })
                .collect();
            let z_angle: Vec<f64> = theta_l.iter().map(|_| normal.next()).collect();
            let moved: Vec<[f64; 3]> = samples
                .iter()
                .zip(&refit.data.y)
                .map(|(s, y)| {
                    let u = s.uncertainty.as_ref().expect("checked by the refitter");
                    let k = theta_l
                        .iter()
                        .position(|t| (s.theta_l - t).abs() <= THETA_L_TOLERANCE)
                        .unwrap_or(0);
                    std::array::from_fn(|c| {
                        let mut v = y[c];
                        for (j, zj) in z.iter().enumerate() {
                            let zj = if j == angle { z_angle[k] } else { *zj };
                            v += zj * u.sources[j][c];
                        }
                        if scale > 0.0 && !s.dropped[c] {
                            v += scale * u.noise[c] * normal.next();
                        }
                        v
                    })
                })
                .collect();
            refit.fit(&moved)
        })
        .collect::<Result<_, FitError>>()?;
    let m_count = result.roughness.count();
    let fresnel = result.ks_90.is_some();
    let distribution = |i: usize| {
        let log = i >= fits[0].len() - m_count;
        let values: Vec<f64> = fits
            .iter()
            .map(|f| if log { f[i].exp() } else { f[i] })
            .collect();
        Distribution::of(values)
    };
    let n_colour = if fresnel { 9 } else { 6 };
    let parameters = ParameterSet {
        kd: std::array::from_fn(distribution),
        ks: std::array::from_fn(|c| distribution(3 + c)),
        ks_90: fresnel.then(|| std::array::from_fn(|c| distribution(6 + c))),
        m: (n_colour..n_colour + m_count).map(distribution).collect(),
    };
    Ok(MonteCarlo {
        draws,
        parameters,
        agreement: Vec::new(),
        evaluations: refit.work.load(Ordering::Relaxed),
    })
}
