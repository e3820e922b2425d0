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
//! A colour shift is reported only when the choice was made on held-out θL, the chosen
//! fit keeps one (Cook–Torrance–Fresnel, Wald test) **and** it predicts the chromaticity
//! of the highlight at the θL it did not see at least [`COLOUR_SHIFT_GAIN`] times better
//! than every candidate without one: its median held-out ΔE_u′v′ over the specular lobe
//! is at most 1/[`COLOUR_SHIFT_GAIN`] of theirs. A Ks_90 that only changes the
//! highlight's brightness (a Fresnel factor, or the lobe's misfit between θL, which the
//! Wald test also rejects Ks_90 = Ks for) does not predict a new chromaticity, and is not
//! a colour shift. With fewer than three θL no chromaticity is predicted unseen and no
//! colour shift is reported. The fit's u′v′ change of its specular colour between the
//! smallest and the largest |θL| is recorded beside ([`specular_uv_change`]).

use serde::{Deserialize, Serialize};

use super::held_out::{leave_one_theta_l_out, HeldOut, Variant};
use super::{fit, parameter_count, FitError, FitResult};
use crate::brdf::Roughness;
use crate::color::CameraModel;
use crate::samples::{distinct_theta_l, Sample, THETA_L_TOLERANCE};

/// A later candidate replaces the best so far only with a score lower by more than this
/// fraction of it (BIC: of the best's |BIC|).
pub const TIE: f64 = 1e-6;

/// How many times lower than every candidate without a colour shift the chosen fit's
/// held-out ΔE_u′v′ over the specular lobe must be for its colour shift to be reported.
pub const COLOUR_SHIFT_GAIN: f64 = 2.0;

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
    /// The best held-out ΔE_u′v′ over the lobe of the candidates without a colour shift
    /// over the chosen one's; `None` when undefined (or the choice was by BIC).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chromatic_gain: Option<f64>,
    /// u′v′ distance between the chosen fit's specular colours at the smallest and
    /// largest |θL|; `None` without a fitted shift.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub specular_uv_change: Option<f64>,
    /// Leave-one-θL-out on a large scan: the candidates were judged on every
    /// `judged_stride`-th sample of each θL ([`JUDGED_PER_THETA_L`]); `None`: on all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judged_stride: Option<usize>,
    /// Why the chosen one won, in words.
    pub reason: String,
}

/// Most samples of one θL the candidates are judged on by leave-one-θL-out: a larger
/// scan is judged on every k-th sample of each θL, k the smallest stride that keeps each
/// θL within it (neighbouring columns differ little in geometry), and the chosen
/// candidate is then fitted to every sample.
pub const JUDGED_PER_THETA_L: usize = 500;

/// Every `stride`-th sample of each θL of `samples` (in their order), and the stride:
/// the smallest that keeps each θL within [`JUDGED_PER_THETA_L`].
fn judged(samples: &[Sample]) -> (Vec<Sample>, usize) {
    let theta_l = distinct_theta_l(samples);
    let at = |s: &Sample| {
        theta_l
            .iter()
            .position(|t| (t - s.theta_l).abs() <= THETA_L_TOLERANCE)
    };
    let mut counts = vec![0usize; theta_l.len()];
    for i in samples.iter().filter_map(at) {
        counts[i] += 1;
    }
    let most = counts.iter().copied().max().unwrap_or(0);
    let stride = most.div_ceil(JUDGED_PER_THETA_L).max(1);
    let mut seen = vec![0usize; theta_l.len()];
    let kept = samples
        .iter()
        .filter(|s| {
            at(s).is_some_and(|i| {
                seen[i] += 1;
                (seen[i] - 1).is_multiple_of(stride)
            })
        })
        .copied()
        .collect();
    (kept, stride)
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
    if theta_l.len() >= 3 {
        let (judged, stride) = judged(samples);
        let held = leave_one_theta_l_out(&judged, variants, camera)?;
        let mut result = choose_held_out(samples, &held, camera)?;
        if let Some(selection) = result.selection.as_mut() {
            selection.judged_stride = (stride > 1).then_some(stride);
        }
        return Ok(result);
    }
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
    choose(samples, Criterion::Bic, candidates, fits, camera)
}

/// The choice among variants already judged by leave-one-θL-out (`held`, from
/// [`leave_one_theta_l_out`] on `samples`): the chosen variant fitted to every sample,
/// with the choice recorded.
pub fn choose_held_out(
    samples: &[Sample],
    held: &[HeldOut],
    camera: &CameraModel,
) -> Result<FitResult, FitError> {
    let candidates = held.iter().map(held_out_candidate).collect();
    choose(
        samples,
        Criterion::LeaveOneThetaLOut,
        candidates,
        Vec::new(),
        camera,
    )
}

/// The best of `candidates` (fitted to every sample in `fits` when already done) with
/// the choice recorded in its `selection`.
fn choose(
    samples: &[Sample],
    criterion: Criterion,
    candidates: Vec<Candidate>,
    fits: Vec<Result<FitResult, FitError>>,
    camera: &CameraModel,
) -> Result<FitResult, FitError> {
    let theta_l = distinct_theta_l(samples);
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
    let mut result = match fits.into_iter().nth(chosen) {
        Some(Ok(f)) => f,
        _ => fit(samples, &candidates[chosen].variant.options())?,
    };
    let change = specular_uv_change(&result, &theta_l, camera);
    let gain = chromatic_gain(&candidates, chosen);
    let colour_shift = criterion == Criterion::LeaveOneThetaLOut
        && result.colour_shift.is_some_and(|c| c.fitted)
        && gain.is_some_and(|g| g >= COLOUR_SHIFT_GAIN);
    let reason = reason(criterion, &candidates, chosen, &result, gain, change);
    result.selection = Some(Selection {
        criterion,
        candidates,
        chosen,
        colour_shift,
        chromatic_gain: gain,
        specular_uv_change: change,
        judged_stride: None,
        reason,
    });
    Ok(result)
}

/// The best held-out lobe ΔE_u′v′ among the candidates without a colour shift over the
/// chosen candidate's.
fn chromatic_gain(candidates: &[Candidate], chosen: usize) -> Option<f64> {
    let own = candidates[chosen].held_out_delta_e_uv_lobe?;
    let others = candidates
        .iter()
        .filter(|c| !c.variant.model.has_fresnel_colour())
        .filter_map(|c| c.held_out_delta_e_uv_lobe)
        .fold(f64::INFINITY, f64::min);
    (others.is_finite() && own > 0.0).then(|| others / own)
}

/// The choice in words: the winner's score against the runner-up's, and the colour
/// shift's verdict.
fn reason(
    criterion: Criterion,
    candidates: &[Candidate],
    chosen: usize,
    result: &FitResult,
    gain: Option<f64>,
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
        let uv = change.map_or(String::new(), |d| {
            format!(" (its specular colour moves by Δu′v′ = {d:.4} over the scanned angles)")
        });
        text.push_str(&match (result.colour_shift.map(|c| c.fitted), gain, criterion) {
            (Some(true), Some(g), Criterion::LeaveOneThetaLOut) if g >= COLOUR_SHIFT_GAIN => {
                format!(
                    "; it predicts the unseen highlight's chromaticity {g:.2}× better than any \
                     model without a shift (≥ {COLOUR_SHIFT_GAIN}×){uv}: a colour shift"
                )
            }
            (Some(true), Some(g), Criterion::LeaveOneThetaLOut) => format!(
                "; its Ks_90 ≠ Ks predicts the unseen highlight's chromaticity only {g:.2}× \
                 better than a model without a shift (< {COLOUR_SHIFT_GAIN}×){uv}: a change of \
                 brightness or of the lobe, not a colour shift"
            ),
            (Some(true), _, _) => {
                format!("; no chromaticity judged unseen (fewer than 3 θL){uv}: no colour shift reported")
            }
            _ => "; no significant change of the specular colour: no colour shift".into(),
        });
    }
    if result.roughness == Roughness::PerChannel {
        text.push_str("; one roughness per channel");
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_large_scan_is_judged_on_every_kth_sample_of_each_theta_l() {
        let scan = |counts: &[usize]| -> Vec<Sample> {
            counts
                .iter()
                .enumerate()
                .flat_map(|(i, &n)| {
                    (0..n).map(move |k| {
                        Sample::in_plane(-20.0 - 5.0 * i as f64, k as f64 * 0.01, 0.0, [1.0; 3])
                    })
                })
                .collect()
        };
        let count = |samples: &[Sample], theta_l: f64| {
            samples.iter().filter(|s| s.theta_l == theta_l).count()
        };
        let (kept, stride) = judged(&scan(&[1200, 300, 1001]));
        assert_eq!(stride, 3);
        assert_eq!(
            [
                count(&kept, -20.0),
                count(&kept, -25.0),
                count(&kept, -30.0)
            ],
            [400, 100, 334]
        );
        assert_eq!(kept[1].theta_i, 0.03);
        let small = scan(&[500, 20, 499]);
        assert_eq!(judged(&small), (small.clone(), 1));
    }
}
