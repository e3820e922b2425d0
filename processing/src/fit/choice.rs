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
//! more than [`TIE`] (relative), so equal scores keep the simpler model, and, judged on
//! held-out θL, only with a median held-out ΔE_u′v′ and a median held-out ΔErr_p (all
//! points, the mean over R, G, B) no higher than the best's so far: a larger model that
//! lowers the loss but predicts the unseen colours or brightness worse (one roughness
//! per channel bending the lobe's colour; a table whose lower loss comes from the few
//! bright points of the peak) does not replace a simpler one.
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
//!
//! The table in (θh, θd) ([`super::table`]) is the last candidate (the most complex:
//! every measured value is a parameter), judged by the same held-out loss with three θL
//! or more; with fewer it is not a candidate (one θL left out would leave at most one
//! column, which predicts nothing across θd). When it wins, the fit predicts with it and
//! keeps the best parametric candidate's fields (fitted to every sample) for renderers.
//! A table reproduces whatever colour change the material has, so a table choice reports
//! a colour shift by the same rule: when it predicts the unseen highlight's chromaticity
//! at least [`COLOUR_SHIFT_GAIN`] times better than every candidate without a colour
//! shift, the same table with a specular of one colour among them
//! ([`super::held_out::one_specular_colour_lobe_uv`]): a table also follows a lobe's shape,
//! which no model may, and that alone can predict the highlight's chromaticity better.

use serde::{Deserialize, Serialize};

use super::colour_change::{lobe_colour_change, LobeColourChange, MIN_UV_CHANGE};
use super::data::Data;
use super::held_out::{leave_one_theta_l_out, table_held_out, Form, HeldOut};
use super::stride::judged;
use super::table::Table;
use super::{fit, fit_from, parameter_count, FitError, FitResult, Start};
use crate::brdf::{Model, Roughness};
use crate::color::CameraModel;
use crate::samples::{distinct_theta_l, Sample};

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
    pub form: Form,
    /// Fitted parameters (a tied colour shift counts as Cook–Torrance's; the table's
    /// stored β values).
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
    /// The table only: the median held-out ΔE_u′v′ over the lobe of the same table with
    /// one specular colour ([`super::held_out::one_specular_colour_lobe_uv`]), a candidate
    /// without a colour shift.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out_delta_e_uv_lobe_one_specular_colour: Option<f64>,
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
    /// The model-free test of the lobe's chromaticity across θL
    /// ([`super::colour_change`]), which a reported colour shift requires; `None` when
    /// the choice was not made on held-out θL or no two θL have a lobe.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lobe_colour_change: Option<LobeColourChange>,
    /// The best held-out ΔE_u′v′ over the lobe of the candidates without a colour shift
    /// over the chosen one's; `None` when undefined (or the choice was by BIC).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chromatic_gain: Option<f64>,
    /// u′v′ distance between the chosen fit's specular colours at the smallest and
    /// largest |θL|; `None` without a fitted shift.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub specular_uv_change: Option<f64>,
    /// Leave-one-θL-out on a large scan: the candidates were judged on every
    /// `judged_stride`-th sample of each θL
    /// ([`super::stride::JUDGED_PER_THETA_L`]); `None`: on all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judged_stride: Option<usize>,
    /// Why the chosen one won, in words.
    pub reason: String,
    /// The loss evaluations × points of the fits made to judge the candidates, beyond
    /// the chosen fit's own (`evaluations`): the choice's work (older files lack it).
    #[serde(default)]
    pub point_evaluations: u64,
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

/// A candidate's held-out medians over all points of the θL left out: ΔE_u′v′, and
/// ΔErr_p averaged over R, G, B.
#[derive(Debug, Clone, Copy)]
struct Judged {
    colour: Option<f64>,
    brightness: Option<f64>,
}

impl Judged {
    fn of(c: &Candidate) -> Self {
        Self {
            colour: c.held_out_delta_e_uv,
            brightness: c.held_out_err_p.map(|e| (e[0] + e[1] + e[2]) / 3.0),
        }
    }
}

/// The index of the lowest score, a later candidate winning only by more than [`TIE`]
/// and, where `judged` gives both its and the best's held-out medians, only with a
/// ΔE_u′v′ and a brightness error ΔErr_p no higher: a larger model that lowers the loss
/// but predicts the unseen θL's colours or brightness worse does not replace a simpler
/// one.
fn best(scores: &[Option<f64>], judged: &[Judged]) -> Option<usize> {
    let mut chosen: Option<usize> = None;
    for (i, s) in scores.iter().enumerate() {
        let Some(s) = *s else { continue };
        match chosen {
            Some(c) => {
                let b = scores[c].unwrap_or(f64::INFINITY);
                let no_worse = |of: fn(&Judged) -> Option<f64>| match (
                    judged.get(i).and_then(of),
                    judged.get(c).and_then(of),
                ) {
                    (Some(own), Some(best)) => own <= best,
                    _ => true,
                };
                if s < b - TIE * b.abs() && no_worse(|j| j.colour) && no_worse(|j| j.brightness) {
                    chosen = Some(i);
                }
            }
            None => chosen = Some(i),
        }
    }
    chosen
}

/// The best parametric variant of `held` by the choice's rule (`best`): the shape a
/// table judged beside them predicts relative to.
pub fn best_parametric(held: &[HeldOut]) -> Option<&HeldOut> {
    let candidates: Vec<Candidate> = held.iter().map(|h| held_out_candidate(h, 0)).collect();
    let scores: Vec<Option<f64>> = candidates
        .iter()
        .map(|c| c.score.filter(|_| c.form.variant().is_some()))
        .collect();
    let judged: Vec<Judged> = candidates.iter().map(Judged::of).collect();
    best(&scores, &judged).map(|i| &held[i])
}

/// The scores of `h`; `table_values`: the stored values of the table of every θL.
fn held_out_candidate(h: &HeldOut, table_values: usize) -> Candidate {
    let shift_tied = h.colour_shift_count() == (0, h.folds.len()) && !h.folds.is_empty();
    let parameters = match h.form {
        Form::Parametric(v) => {
            let full = parameter_count(v.model, v.roughness);
            if v.model.has_fresnel_colour() && shift_tied {
                full - 3
            } else {
                full
            }
        }
        Form::Table(_) => table_values,
    };
    Candidate {
        form: h.form,
        parameters,
        score: h.relative_loss(),
        held_out_delta_e_uv: h.median_delta_e_uv(false),
        held_out_delta_e_uv_lobe: h.median_delta_e_uv(true),
        held_out_err_p: h.median_err_p(false),
        held_out_err_p_lobe: h.median_err_p(true),
        held_out_delta_e_uv_lobe_one_specular_colour: h.one_specular_colour_lobe_uv,
        error: h
            .failed
            .first()
            .map(|(t, e)| format!("θL {t} left out: {e}")),
    }
}

/// Fits the candidate among `forms` that `samples` favour (see the module), with its
/// uncertainty, and records the choice in the result's `selection`.
pub fn fit_auto(
    samples: &[Sample],
    forms: &[Form],
    camera: &CameraModel,
) -> Result<FitResult, FitError> {
    let variants: Vec<_> = forms.iter().filter_map(Form::variant).collect();
    if variants.is_empty() {
        return Err(FitError::InvalidOptions(
            "no parametric candidate model".into(),
        ));
    }
    let theta_l = distinct_theta_l(samples);
    if theta_l.len() >= 3 {
        let (judged, stride) = judged(samples);
        let parametric = leave_one_theta_l_out(&judged, &variants, camera)?;
        let table = forms
            .contains(&Form::TABLE)
            .then(|| table_held_out(&judged, best_parametric(&parametric), camera));
        let mut parametric = parametric.into_iter();
        let mut table = table.into_iter();
        let held: Vec<HeldOut> = forms
            .iter()
            .filter_map(|form| match form {
                Form::Parametric(_) => parametric.next(),
                Form::Table(_) => table.next(),
            })
            .collect();
        let mut result = choose_held_out(samples, &held, camera)?;
        if let Some(selection) = result.selection.as_mut() {
            selection.judged_stride = (stride > 1).then_some(stride);
        }
        return Ok(result);
    }
    let fits: Vec<Option<Result<FitResult, FitError>>> = forms
        .iter()
        .map(|form| form.variant().map(|v| fit(samples, &v.options())))
        .collect();
    let candidates = forms
        .iter()
        .zip(&fits)
        .map(|(&form, f)| {
            let (parameters, score, error) = match (form, f) {
                (Form::Parametric(v), Some(f)) => (
                    f.as_ref()
                        .map_or_else(|_| parameter_count(v.model, v.roughness), fitted_parameters),
                    f.as_ref().ok().map(|r| bic(r, samples.len())),
                    f.as_ref().err().map(|e| e.to_string()),
                ),
                _ => (
                    0,
                    None,
                    Some(format!(
                        "not a candidate with {} θL: it is judged only on θL it did not see \
                         (three θL or more)",
                        theta_l.len()
                    )),
                ),
            };
            Candidate {
                form,
                parameters,
                score,
                held_out_delta_e_uv: None,
                held_out_delta_e_uv_lobe: None,
                held_out_err_p: None,
                held_out_err_p_lobe: None,
                held_out_delta_e_uv_lobe_one_specular_colour: None,
                error,
            }
        })
        .collect();
    choose(samples, Criterion::Bic, candidates, fits, &[], None, camera)
}

/// The choice among variants already judged by leave-one-θL-out (`held`, from
/// [`leave_one_theta_l_out`] on `samples` or on every k-th of them, `fit::stride`): the
/// chosen variant fitted to every sample, from its robust minimum on the samples judged
/// (by Gauss–Newton steps, `fit::newton`), with the choice recorded.
pub fn choose_held_out(
    samples: &[Sample],
    held: &[HeldOut],
    camera: &CameraModel,
) -> Result<FitResult, FitError> {
    let table = held.iter().find_map(|h| h.table.clone());
    let values = table.as_ref().map_or(0, Table::values);
    let candidates = held.iter().map(|h| held_out_candidate(h, values)).collect();
    let starts: Vec<Option<Start>> = held.iter().map(|h| h.start).collect();
    let mut result = choose(
        samples,
        Criterion::LeaveOneThetaLOut,
        candidates,
        Vec::new(),
        &starts,
        table,
        camera,
    )?;
    // The fits that judged the variants.
    if let Some(selection) = result.selection.as_mut() {
        selection.point_evaluations += held.iter().map(|h| h.point_evaluations).sum::<u64>();
    }
    Ok(result)
}

/// The best of `candidates` (fitted to every sample in `fits` when already done, else
/// from its robust minimum in `starts` on samples near these when given) with the choice
/// recorded in its `selection` (its `point_evaluations`: those of the other `fits`).
/// When the table (`table`, of every sample) wins, the result is the best parametric
/// candidate's fit predicting with it.
fn choose(
    samples: &[Sample],
    criterion: Criterion,
    candidates: Vec<Candidate>,
    fits: Vec<Option<Result<FitResult, FitError>>>,
    starts: &[Option<Start>],
    table: Option<Table>,
    camera: &CameraModel,
) -> Result<FitResult, FitError> {
    let theta_l = distinct_theta_l(samples);
    let scores: Vec<Option<f64>> = candidates.iter().map(|c| c.score).collect();
    let parametric_scores: Vec<Option<f64>> = candidates
        .iter()
        .map(|c| c.score.filter(|_| c.form.variant().is_some()))
        .collect();
    let judged: Vec<Judged> = candidates.iter().map(Judged::of).collect();
    let (Some(chosen), Some(parametric)) =
        (best(&scores, &judged), best(&parametric_scores, &judged))
    else {
        // What is wrong with the samples themselves is said once, not per candidate.
        Data::new(samples, Model::CookTorrance, 0)?;
        let why = candidates
            .iter()
            .filter_map(|c| Some(format!("{}: {}", c.form.label(), c.error.as_ref()?)))
            .collect::<Vec<_>>()
            .join("; ");
        return Err(FitError::Optimizer(format!(
            "no parametric candidate model could be scored ({why})"
        )));
    };
    // The fits of every sample made beside the chosen one.
    let beside: u64 = (fits.iter().enumerate())
        .filter(|&(i, _)| i != parametric)
        .filter_map(|(_, f)| f.as_ref()?.as_ref().ok())
        .map(|f| f.evaluations * samples.len() as u64)
        .sum();
    let mut result = match (
        fits.into_iter().nth(parametric).flatten(),
        candidates[parametric].form,
    ) {
        (Some(Ok(f)), _) => f,
        (_, form) => {
            let variant = form.variant().ok_or_else(|| {
                FitError::Optimizer(format!("{} is not a parametric model", form.label()))
            })?;
            let start = starts.get(parametric).and_then(Option::as_ref);
            fit_from(samples, &variant.options(), start, None)?
        }
    };
    let tabulated = chosen != parametric;
    if tabulated {
        result.table = Some(match table {
            Some(table) => table,
            None => Table::new(samples, 0.0)?,
        });
    }
    let change = specular_uv_change(&result, &theta_l, camera).filter(|_| !tabulated);
    let gain = chromatic_gain(&candidates, chosen);
    let lobe_change = (criterion == Criterion::LeaveOneThetaLOut)
        .then(|| lobe_colour_change(samples, camera))
        .flatten();
    let colour_shift = criterion == Criterion::LeaveOneThetaLOut
        && (tabulated || result.colour_shift.is_some_and(|c| c.fitted))
        && gain.is_some_and(|g| g >= COLOUR_SHIFT_GAIN)
        && lobe_change.as_ref().is_some_and(|l| l.changes);
    let mut reason = reason(
        criterion,
        &candidates,
        chosen,
        parametric,
        &result,
        gain,
        change,
    );
    if let Some(l) = &lobe_change {
        reason.push_str(&lobe_words(l, colour_shift));
    }
    result.selection = Some(Selection {
        criterion,
        candidates,
        chosen,
        colour_shift,
        lobe_colour_change: lobe_change,
        chromatic_gain: gain,
        specular_uv_change: change,
        judged_stride: None,
        reason,
        point_evaluations: beside,
    });
    Ok(result)
}

/// The best held-out lobe ΔE_u′v′ among the candidates without a colour shift over the
/// chosen candidate's. A table is also judged against itself with one specular colour.
fn chromatic_gain(candidates: &[Candidate], chosen: usize) -> Option<f64> {
    let own = candidates[chosen].held_out_delta_e_uv_lobe?;
    let others = candidates
        .iter()
        .filter(|c| {
            c.form
                .variant()
                .is_some_and(|v| !v.model.has_fresnel_colour())
        })
        .filter_map(|c| c.held_out_delta_e_uv_lobe)
        .chain(candidates[chosen].held_out_delta_e_uv_lobe_one_specular_colour)
        .fold(f64::INFINITY, f64::min);
    (others.is_finite() && own > 0.0).then(|| others / own)
}

/// The lobe's chromaticity test in words.
fn lobe_words(l: &LobeColourChange, reported: bool) -> String {
    let changes = if l.changes {
        "a change"
    } else if l.size_uv < MIN_UV_CHANGE {
        "below the smallest change reported"
    } else {
        "not significant given the noise"
    };
    let verdict = match (l.changes, reported) {
        (_, true) => ": a colour shift",
        (true, false) => {
            ", but no candidate predicts it at the unseen θL: no colour shift reported"
        }
        (false, false) => ": no colour shift reported",
    };
    format!(
        "; the lobe's u′v′ across {} θL moves by up to {:.4} (≥ {MIN_UV_CHANGE} needed), p = {:.3} \
         (< {} needed), {changes}{verdict}",
        l.theta_l,
        l.size_uv,
        l.p_value,
        super::colour_change::LEVEL
    )
}

/// The choice in words: the winner's score against the runner-up's, and the colour
/// shift's verdict.
fn reason(
    criterion: Criterion,
    candidates: &[Candidate],
    chosen: usize,
    parametric: usize,
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
    let colour = |c: &Candidate| c.held_out_delta_e_uv.unwrap_or(f64::NAN);
    let mut text = match runner_up {
        Some((_, r))
            if r.score.unwrap() < score - TIE * score.abs() && colour(r) > colour(winner) =>
        {
            format!(
                "{} is kept with a {what} of {score:.6}: {} has a lower one ({:.6}) but \
                 predicts the unseen θL's colours worse (median ΔE_u′v′ {:.5} against {:.5}), \
                 and a larger model replaces a simpler one only where it predicts both better",
                winner.form.label(),
                r.form.label(),
                r.score.unwrap(),
                colour(r),
                colour(winner)
            )
        }
        Some((_, r)) if r.score.unwrap() <= score => format!(
            "{} has the lowest {what} among the simplest: {score:.6}, equal within {TIE:e} to {} \
             ({:.6}) with fewer or as many parameters",
            winner.form.label(),
            r.form.label(),
            r.score.unwrap()
        ),
        Some((_, r)) => format!(
            "{} has the lowest {what}: {score:.6}, against {:.6} for {} (next best)",
            winner.form.label(),
            r.score.unwrap(),
            r.form.label()
        ),
        None => format!(
            "{} is the only candidate scored: {what} {score:.6}",
            winner.form.label()
        ),
    };
    if chosen != parametric {
        text.push_str(&format!(
            "; predictions use the table of the measured θL in (θh, θd), and its parametric \
             fields are those of {}, the best parametric candidate",
            candidates[parametric].form.label()
        ));
        text.push_str(&match gain {
            Some(g) if g >= COLOUR_SHIFT_GAIN => format!(
                "; it predicts the unseen highlight's chromaticity {g:.2}× better than any \
                 model without a shift and than itself with one specular colour \
                 (≥ {COLOUR_SHIFT_GAIN}×)"
            ),
            Some(g) => format!(
                "; it predicts the unseen highlight's chromaticity only {g:.2}× better than a \
                 model without a shift or itself with one specular colour \
                 (< {COLOUR_SHIFT_GAIN}×): no colour shift"
            ),
            None => "; no chromaticity of the highlight judged: no colour shift reported".into(),
        });
        return text;
    }
    if result.model.has_fresnel_colour() {
        let uv = change.map_or(String::new(), |d| {
            format!(" (its specular colour moves by Δu′v′ = {d:.4} over the scanned angles)")
        });
        text.push_str(&match (result.colour_shift.map(|c| c.fitted), gain, criterion) {
            (Some(true), Some(g), Criterion::LeaveOneThetaLOut) if g >= COLOUR_SHIFT_GAIN => {
                format!(
                    "; it predicts the unseen highlight's chromaticity {g:.2}× better than any \
                     model without a shift (≥ {COLOUR_SHIFT_GAIN}×){uv}"
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
    use super::{best, Judged};

    fn judged(colour: f64, brightness: f64) -> Judged {
        Judged {
            colour: Some(colour),
            brightness: Some(brightness),
        }
    }

    #[test]
    fn a_lower_loss_wins_only_with_colour_and_brightness_no_worse() {
        let scores = [Some(1.0), Some(0.5)];
        assert_eq!(
            best(&scores, &[judged(0.01, 0.2), judged(0.01, 0.2)]),
            Some(1)
        );
        // Lower loss, colours no worse, most points' brightness worse: the first stays.
        assert_eq!(
            best(&scores, &[judged(0.01, 0.2), judged(0.005, 0.25)]),
            Some(0)
        );
        // Lower loss, brightness no worse, colours worse: the first stays.
        assert_eq!(
            best(&scores, &[judged(0.01, 0.2), judged(0.02, 0.1)]),
            Some(0)
        );
        // Not judged on held-out θL (BIC): the score alone.
        let unjudged = Judged {
            colour: None,
            brightness: None,
        };
        assert_eq!(best(&scores, &[unjudged, unjudged]), Some(1));
        // A tie keeps the simpler.
        assert_eq!(
            best(&[Some(1.0), Some(1.0)], &[judged(0.0, 0.0); 2]),
            Some(0)
        );
    }
}
