//! Choosing the model (`--model auto`): among candidate variants, the one that best
//! predicts the θL it did not see, and whether its specular colour changes with angle.
//!
//! - Three θL or more: leave-one-θL-out ([`super::held_out`]); the score is the relative
//!   held-out eq. 10 loss, Σ over the folds of the loss at the left-out θL over Σ ‖β‖
//!   there. The same loss the fits minimise, judged on data they did not see.
//! - Fewer (a fold would fit one θL, where a colour shift cannot be told from the
//!   lobe): the Bayesian information criterion of the fit on all samples, taking the
//!   eq. 10 loss as the likelihood it is the maximum of — RGB residuals r with density
//!   ∝ exp(−‖r‖/b), whose maximum over b gives −2 ln L = 6N ln(L/3N) + const, so
//!   BIC = 6N ln(L/3N) + k ln N (N points, k parameters; a tied colour shift counts as
//!   Cook–Torrance's).
//!
//! Candidates are listed simplest first; a later one wins only with a score lower by
//! more than [`TIE`] (relative), so equal scores keep the simpler model.
//!
//! A colour shift is reported only when the chosen fit keeps one (Cook–Torrance–Fresnel,
//! Wald test) **and** its specular colour F_c changes chromaticity over the scanned
//! angles: the u′v′ distance between F at the smallest and at the largest |θL| (light and
//! camera γ = |θL| apart, F = Ks + (1 − cos γ)(Ks_90 − Ks)) is at least
//! [`COLOUR_SHIFT_MIN_UV`]. A Ks_90 of Ks's chromaticity changes the highlight's
//! brightness only (a Fresnel factor, or the lobe's misfit between θL): not a colour
//! shift.

use serde::{Deserialize, Serialize};

use super::held_out::{leave_one_theta_l_out, HeldOut, Variant};
use super::{fit, parameter_count, FitError, FitResult};
use crate::brdf::Roughness;
use crate::color::CameraModel;
use crate::samples::{distinct_theta_l, Sample};

/// A later candidate replaces the best so far only with a score lower by more than this
/// fraction of it (BIC: of the best's |BIC|).
pub const TIE: f64 = 1e-6;

/// Smallest u′v′ distance between the specular colours at the smallest and largest |θL|
/// of a scan that counts as a colour shift: about a just-noticeable difference of
/// chromaticity (0.004, the one-step MacAdam ellipse's scale used for lamp tolerances).
pub const COLOUR_SHIFT_MIN_UV: f64 = 0.004;

/// How the candidates were compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Criterion {
    /// Relative held-out eq. 10 loss, every θL left out in turn (≥ 3 θL).
    LeaveOneThetaLOut,
    /// Bayesian information criterion on the eq. 10 loss (fewer than 3 θL).
    Bic,
}

/// One candidate's scores.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    #[serde(flatten)]
    pub variant: Variant,
    /// Fitted parameters (a tied colour shift counts as Cook–Torrance's).
    pub parameters: usize,
    /// The criterion's value (lower is better); `None` when a fit failed.
    pub score: Option<f64>,
    /// Leave-one-θL-out only: medians over the folds of ΔE_u′v′ and ΔErr_p (R, G, B),
    /// over all points and over the specular lobe.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out_delta_e_uv: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out_delta_e_uv_lobe: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out_err_p: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out_err_p_lobe: Option<[f64; 3]>,
    /// Why it could not be scored.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// The model choice recorded in an `auto` fit's JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    pub criterion: Criterion,
    pub candidates: Vec<Candidate>,
    /// Index of the chosen candidate.
    pub chosen: usize,
    /// Whether a colour shift is reported (see the module's rule).
    pub colour_shift: bool,
    /// u′v′ distance between the chosen fit's specular colours at the smallest and
    /// largest |θL|; `None` without a fitted shift.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub specular_uv_change: Option<f64>,
    /// Why the chosen one won, in words.
    pub reason: String,
}

/// u′v′ distance between the specular colours of `result` at the smallest and largest
/// |θL| of `theta_l`; `None` without a fitted colour shift or where a colour has no
/// chromaticity.
pub fn specular_uv_change(
    result: &FitResult,
    theta_l: &[f64],
    camera: &CameraModel,
) -> Option<f64> {
    if !result.colour_shift.is_some_and(|c| c.fitted) {
        return None;
    }
    let ks_90 = result.ks_90?;
    let colour = |gamma_deg: f64| -> Option<[f64; 2]> {
        let w = (1.0 - gamma_deg.to_radians().cos()).clamp(0.0, 1.0);
        camera.uv_prime(std::array::from_fn(|c| {
            result.ks[c] + w * (ks_90[c] - result.ks[c])
        }))
    };
    let gammas = theta_l.iter().map(|t| t.abs());
    let lo = gammas.clone().fold(f64::INFINITY, f64::min);
    let hi = gammas.fold(0.0, f64::max);
    let (a, b) = (colour(lo)?, colour(hi)?);
    Some(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
}

/// Parameters of a fit as fitted: a Cook–Torrance–Fresnel fit whose shift was tied has
/// Cook–Torrance's.
fn fitted_parameters(result: &FitResult) -> usize {
    let tied = result.colour_shift.is_some_and(|c| !c.fitted);
    parameter_count(result.model, result.roughness) - if tied { 3 } else { 0 }
}

/// BIC of a fit on `points` points (see the module).
fn bic(result: &FitResult, points: usize) -> f64 {
    let n = points as f64;
    6.0 * n * (result.loss.max(f64::MIN_POSITIVE) / (3.0 * n)).ln()
        + fitted_parameters(result) as f64 * n.ln()
}

/// The index of the lowest score, a later candidate winning only by more than [`TIE`].
fn best(scores: &[Option<f64>]) -> Option<usize> {
    let mut chosen: Option<usize> = None;
    for (i, s) in scores.iter().enumerate() {
        let Some(s) = *s else { continue };
        match chosen {
            Some(c) => {
                let b = scores[c].unwrap_or(f64::INFINITY);
                if s < b - TIE * b.abs() {
                    chosen = Some(i);
                }
            }
            None => chosen = Some(i),
        }
    }
    chosen
}

fn held_out_candidate(h: &HeldOut) -> Candidate {
    let shift_tied = h.colour_shift_count() == (0, h.folds.len()) && !h.folds.is_empty();
    let full = parameter_count(h.variant.model, h.variant.roughness);
    Candidate {
        variant: h.variant,
        parameters: if h.variant.model.has_fresnel_colour() && shift_tied {
            full - 3
        } else {
            full
        },
        score: h.relative_loss(),
        held_out_delta_e_uv: h.median_delta_e_uv(false),
        held_out_delta_e_uv_lobe: h.median_delta_e_uv(true),
        held_out_err_p: h.median_err_p(false),
        held_out_err_p_lobe: h.median_err_p(true),
        error: h
            .failed
            .first()
            .map(|(t, e)| format!("θL {t} left out: {e}")),
    }
}

/// Fits the candidate among `variants` that `samples` favour (see the module), with its
/// uncertainty, and records the choice in the result's `selection`.
pub fn fit_auto(
    samples: &[Sample],
    variants: &[Variant],
    camera: &CameraModel,
) -> Result<FitResult, FitError> {
    if variants.is_empty() {
        return Err(FitError::InvalidOptions("no candidate model".into()));
    }
    let theta_l = distinct_theta_l(samples);
    let (criterion, candidates, mut fits) = if theta_l.len() >= 3 {
        let held = leave_one_theta_l_out(samples, variants, camera)?;
        let candidates: Vec<Candidate> = held.iter().map(held_out_candidate).collect();
        (Criterion::LeaveOneThetaLOut, candidates, Vec::new())
    } else {
        let fits: Vec<Result<FitResult, FitError>> = variants
            .iter()
            .map(|v| fit(samples, &v.options()))
            .collect();
        let candidates = variants
            .iter()
            .zip(&fits)
            .map(|(&variant, f)| Candidate {
                variant,
                parameters: f.as_ref().map_or_else(
                    |_| parameter_count(variant.model, variant.roughness),
                    fitted_parameters,
                ),
                score: f.as_ref().ok().map(|r| bic(r, samples.len())),
                held_out_delta_e_uv: None,
                held_out_delta_e_uv_lobe: None,
                held_out_err_p: None,
                held_out_err_p_lobe: None,
                error: f.as_ref().err().map(|e| e.to_string()),
            })
            .collect();
        (Criterion::Bic, candidates, fits)
    };
    let scores: Vec<Option<f64>> = candidates.iter().map(|c| c.score).collect();
    let Some(chosen) = best(&scores) else {
        let why = candidates
            .iter()
            .filter_map(|c| Some(format!("{}: {}", c.variant.label(), c.error.as_ref()?)))
            .collect::<Vec<_>>()
            .join("; ");
        return Err(FitError::Optimizer(format!(
            "no candidate model could be scored ({why})"
        )));
    };
    let mut result = match fits.get_mut(chosen) {
        Some(Ok(f)) => f.clone(),
        _ => fit(samples, &variants[chosen].options())?,
    };
    let change = specular_uv_change(&result, &theta_l, camera);
    let colour_shift = change.is_some_and(|d| d >= COLOUR_SHIFT_MIN_UV);
    let reason = reason(criterion, &candidates, chosen, &result, change);
    result.selection = Some(Selection {
        criterion,
        candidates,
        chosen,
        colour_shift,
        specular_uv_change: change,
        reason,
    });
    Ok(result)
}

/// The choice in words: the winner's score against the runner-up's, and the colour
/// shift's verdict.
fn reason(
    criterion: Criterion,
    candidates: &[Candidate],
    chosen: usize,
    result: &FitResult,
    change: Option<f64>,
) -> String {
    let winner = &candidates[chosen];
    let what = match criterion {
        Criterion::LeaveOneThetaLOut => {
            "relative held-out loss (every θL predicted from the others)"
        }
        Criterion::Bic => "BIC on the eq. 10 loss (fewer than 3 θL)",
    };
    let score = winner.score.unwrap_or(f64::NAN);
    let runner_up = candidates
        .iter()
        .enumerate()
        .filter(|(i, c)| *i != chosen && c.score.is_some())
        .min_by(|a, b| a.1.score.unwrap().total_cmp(&b.1.score.unwrap()));
    let mut text = match runner_up {
        Some((_, r)) if r.score.unwrap() <= score => format!(
            "{} has the lowest {what} among the simplest: {score:.6}, equal within {TIE:e} to {} \
             ({:.6}) with fewer or as many parameters",
            winner.variant.label(),
            r.variant.label(),
            r.score.unwrap()
        ),
        Some((_, r)) => format!(
            "{} has the lowest {what}: {score:.6}, against {:.6} for {} (next best)",
            winner.variant.label(),
            r.score.unwrap(),
            r.variant.label()
        ),
        None => format!(
            "{} is the only candidate scored: {what} {score:.6}",
            winner.variant.label()
        ),
    };
    if result.model.has_fresnel_colour() {
        text.push_str(&match (result.colour_shift.map(|c| c.fitted), change) {
            (Some(true), Some(d)) if d >= COLOUR_SHIFT_MIN_UV => format!(
                "; its specular colour changes over the scanned angles by Δu′v′ = {d:.4} \
                 (≥ {COLOUR_SHIFT_MIN_UV}): a colour shift"
            ),
            (Some(true), Some(d)) => format!(
                "; its Ks_90 changes the highlight's brightness, its chromaticity only by \
                 Δu′v′ = {d:.4} (< {COLOUR_SHIFT_MIN_UV}): no colour shift"
            ),
            (Some(true), None) => {
                "; its specular colour has no chromaticity: no colour shift".into()
            }
            _ => "; no significant change of the specular colour: no colour shift".into(),
        });
    }
    if result.roughness == Roughness::PerChannel {
        text.push_str("; one roughness per channel");
    }
    text
}
