//! Judging a model by the θL it did not see (leave-one-θL-out): for each θL of a scan
//! the model is fitted (robust method, no uncertainty) to the samples of every other θL
//! and scored at that θL's samples, whose measured β stand for the truth:
//! - the eq. 10 loss there, and its scale Σ_p ‖β_p‖ (the loss of predicting 0);
//! - ΔErr_p per channel (eq. 11) and the mean ΔE_u′v′ (eq. 13, through the camera's
//!   RGB → XYZ matrix), over all of the θL's points and over its specular lobe
//!   ([`lobe`]).
//!
//! Only points whose three channels are known are scored (a dropped value has no
//! chromaticity).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{fit, FitError, FitOptions};
use crate::brdf::{Model, Roughness};
use crate::color::CameraModel;
use crate::metrics::{self, MetricsError};
use crate::samples::{distinct_theta_l, Sample, THETA_L_TOLERANCE};

/// A model with its roughness form: one candidate of a comparison.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Variant {
    pub model: Model,
    pub roughness: Roughness,
}

impl Variant {
    /// `model` with `roughness`.
    pub const fn new(model: Model, roughness: Roughness) -> Self {
        Variant { model, roughness }
    }

    /// `cook-torrance` for shared roughness, `cook-torrance/per-channel` otherwise.
    pub fn label(&self) -> String {
        match self.roughness {
            Roughness::Shared => self.model.name().to_string(),
            Roughness::PerChannel => format!("{}/{}", self.model, self.roughness),
        }
    }

    /// Robust fit options of this variant.
    pub fn options(self) -> FitOptions {
        let mut options = FitOptions::new(self.model);
        options.roughness = self.roughness;
        options
    }
}

/// Every model with both roughness forms, in order of their number of parameters (7, 7,
/// 9, 9, 10, 12): the candidates of `gonio fit --model auto`.
pub const CANDIDATES: [Variant; 6] = [
    Variant::new(Model::CookTorrance, Roughness::Shared),
    Variant::new(Model::Ward, Roughness::Shared),
    Variant::new(Model::CookTorrance, Roughness::PerChannel),
    Variant::new(Model::Ward, Roughness::PerChannel),
    Variant::new(Model::CookTorranceFresnel, Roughness::Shared),
    Variant::new(Model::CookTorranceFresnel, Roughness::PerChannel),
];

/// A point of a θL is in its specular lobe when its excess over the θL's darkest point,
/// in R + G + B, is at least this fraction of the θL's largest excess.
pub const LOBE_FRACTION: f64 = 0.1;

/// Errors of predictions against measured (or reference) values on a set of points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Errors {
    /// Number of points.
    pub points: usize,
    /// ΔErr_p (eq. 11) per channel.
    pub err_p: [f64; 3],
    /// Mean ΔE_u′v′ (eq. 13) over the points with a defined chromaticity; `None` if none.
    pub delta_e_uv: Option<f64>,
}

/// ΔErr_p per channel and mean ΔE_u′v′ of `estimated` (camera RGB) against `measured`
/// (camera RGB, and its XYZ `measured_xyz`), paired by index.
pub fn errors(
    measured: &[[f64; 3]],
    measured_xyz: &[[f64; 3]],
    estimated: &[[f64; 3]],
    camera: &CameraModel,
) -> Result<Errors, MetricsError> {
    let err_p = metrics::err_p(measured, estimated)?;
    let estimated_xyz: Vec<[f64; 3]> = estimated.iter().map(|&rgb| camera.xyz(rgb)).collect();
    Ok(Errors {
        points: measured.len(),
        err_p,
        delta_e_uv: metrics::delta_e_uv(measured_xyz, &estimated_xyz).ok(),
    })
}

/// Which of `rgb` (one θL's measured values) are in its specular lobe ([`LOBE_FRACTION`]).
pub fn lobe(rgb: &[[f64; 3]]) -> Vec<bool> {
    let sum = |v: &[f64; 3]| v[0] + v[1] + v[2];
    let floor = rgb.iter().map(sum).fold(f64::INFINITY, f64::min);
    let peak = rgb.iter().map(|v| sum(v) - floor).fold(0.0, f64::max);
    rgb.iter()
        .map(|v| peak > 0.0 && sum(v) - floor >= LOBE_FRACTION * peak)
        .collect()
}

/// The scores of one fit at the θL it left out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fold {
    /// The θL left out.
    pub theta_l: f64,
    /// Eq. 10 loss of the prediction at its points.
    pub loss: f64,
    /// Σ_p ‖β_p‖ at its points: the loss of predicting 0.
    pub scale: f64,
    /// Errors over all of its points and over its specular lobe.
    pub all: Errors,
    pub lobe: Option<Errors>,
    /// Whether the fit kept a colour shift (Cook–Torrance–Fresnel only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour_shift: Option<bool>,
}

/// A variant judged at every θL in turn.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOut {
    pub variant: Variant,
    /// The folds that were fitted and scored, in the samples' θL order.
    pub folds: Vec<Fold>,
    /// The θL whose fold failed, and why.
    pub failed: Vec<(f64, String)>,
}

/// The median of `values` (mean of the middle two for an even count); `None` if empty.
pub fn median(values: &[f64]) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    })
}

impl HeldOut {
    /// Σ fold losses / Σ fold scales: the relative eq. 10 error of predicting every θL
    /// from the others; `None` when a fold failed.
    pub fn relative_loss(&self) -> Option<f64> {
        if !self.failed.is_empty() || self.folds.is_empty() {
            return None;
        }
        let loss: f64 = self.folds.iter().map(|f| f.loss).sum();
        let scale: f64 = self.folds.iter().map(|f| f.scale).sum();
        (scale > 0.0).then(|| loss / scale)
    }

    fn errors(&self, lobe: bool) -> impl Iterator<Item = &Errors> {
        self.folds
            .iter()
            .filter_map(move |f| if lobe { f.lobe.as_ref() } else { Some(&f.all) })
    }

    /// Median over the folds of ΔE_u′v′, over all points or over the lobe.
    pub fn median_delta_e_uv(&self, lobe: bool) -> Option<f64> {
        median(
            &self
                .errors(lobe)
                .filter_map(|e| e.delta_e_uv)
                .collect::<Vec<_>>(),
        )
    }

    /// Median over the folds of ΔErr_p per channel, over all points or over the lobe.
    pub fn median_err_p(&self, lobe: bool) -> Option<[f64; 3]> {
        let channel = |c: usize| median(&self.errors(lobe).map(|e| e.err_p[c]).collect::<Vec<_>>());
        Some([channel(0)?, channel(1)?, channel(2)?])
    }

    /// Folds whose fit kept a colour shift, of those that could.
    pub fn colour_shift_count(&self) -> (usize, usize) {
        let tested: Vec<bool> = self.folds.iter().filter_map(|f| f.colour_shift).collect();
        (tested.iter().filter(|&&k| k).count(), tested.len())
    }
}

/// The samples at θL `theta_l` (`held == true`) or at every other θL.
fn split(samples: &[Sample], theta_l: f64, held: bool) -> Vec<Sample> {
    samples
        .iter()
        .filter(|s| ((s.theta_l - theta_l).abs() <= THETA_L_TOLERANCE) == held)
        .copied()
        .collect()
}

/// Fits `variant` without θL `theta_l` and scores it there.
fn fold(
    samples: &[Sample],
    variant: Variant,
    theta_l: f64,
    camera: &CameraModel,
) -> Result<Fold, String> {
    let mut options = variant.options();
    options.uncertainty = false;
    let fitted = fit(&split(samples, theta_l, false), &options).map_err(|e| e.to_string())?;
    let held = known(samples, theta_l)?;
    let estimated: Vec<[f64; 3]> = held.iter().map(|s| fitted.predict_sample(s)).collect();
    let mut scored = score(theta_l, &held, &estimated, camera)?;
    scored.colour_shift = fitted.colour_shift.map(|c| c.fitted);
    Ok(scored)
}

/// The samples of θL `theta_l` whose three channels are known.
fn known(samples: &[Sample], theta_l: f64) -> Result<Vec<Sample>, String> {
    let held: Vec<Sample> = split(samples, theta_l, true)
        .into_iter()
        .filter(|s| !s.dropped.contains(&true))
        .collect();
    if held.is_empty() {
        return Err(format!(
            "θL {theta_l} has no point with every channel known"
        ));
    }
    Ok(held)
}

/// The fold of θL `theta_l`: `estimated` scored against the samples `held`.
fn score(
    theta_l: f64,
    held: &[Sample],
    estimated: &[[f64; 3]],
    camera: &CameraModel,
) -> Result<Fold, String> {
    let measured: Vec<[f64; 3]> = held.iter().map(|s| s.rgb).collect();
    let measured_xyz: Vec<[f64; 3]> = measured.iter().map(|&v| camera.xyz(v)).collect();
    let all = errors(&measured, &measured_xyz, estimated, camera).map_err(|e| e.to_string())?;
    let in_lobe = lobe(&measured);
    let pick = |values: &[[f64; 3]]| -> Vec<[f64; 3]> {
        values
            .iter()
            .zip(&in_lobe)
            .filter(|(_, &l)| l)
            .map(|(v, _)| *v)
            .collect()
    };
    let lobe_errors = errors(
        &pick(&measured),
        &pick(&measured_xyz),
        &pick(estimated),
        camera,
    )
    .ok();
    let loss = metrics::loss(&measured, estimated).map_err(|e| e.to_string())?;
    let scale = measured
        .iter()
        .map(|v| metrics::point_loss(v, &[0.0; 3]))
        .sum();
    if !loss.is_finite() {
        return Err(FitError::Overflow("held-out loss").to_string());
    }
    Ok(Fold {
        theta_l,
        loss,
        scale,
        all,
        lobe: lobe_errors,
        colour_shift: None,
    })
}

/// One θL as a table: its mean θd (radians) and its points' (signed θh, β), sorted by θh.
type ThetaTable = (f64, Vec<(f64, [f64; 3])>);

/// A sample's half-vector and difference angles (radians): θh signed by the side of the
/// specular peak it lies on (the sign of θi − θr), θd = acos(v·h).
fn half_difference(s: &Sample) -> (f64, f64) {
    let c = s.cosines();
    let theta_h = c.n_dot_h.clamp(-1.0, 1.0).acos();
    let side = if s.theta_i >= s.theta_r { 1.0 } else { -1.0 };
    (side * theta_h, c.v_dot_h.clamp(-1.0, 1.0).acos())
}

/// β of one θL's points (sorted by signed θh) at signed θh `h`: linear between the two
/// points around it, the end point's beyond.
fn along(points: &[(f64, [f64; 3])], h: f64) -> [f64; 3] {
    let k = points.partition_point(|p| p.0 <= h);
    if k == 0 {
        return points[0].1;
    }
    if k == points.len() {
        return points[k - 1].1;
    }
    let (a, b) = (points[k - 1], points[k]);
    let w = if b.0 > a.0 {
        (h - a.0) / (b.0 - a.0)
    } else {
        0.0
    };
    std::array::from_fn(|c| a.1[c] + w * (b.1[c] - a.1[c]))
}

/// The model-free bound of a model's held-out error: each θL predicted from the other
/// θL's own samples, as a table in (θh, θd) (an isotropic BRDF is nearly bivariate in
/// them; Romeiro et al. 2008): along each other θL linear in signed θh, then linear in θd
/// between the two θL whose mean θd bracket the point's (the nearest θL beyond the ends).
/// No model reaches below what its own data interpolate to, except by extrapolating
/// better beyond the measured θd.
pub fn interpolation_folds(samples: &[Sample], camera: &CameraModel) -> Vec<Result<Fold, String>> {
    let theta_l = distinct_theta_l(samples);
    let tables: Vec<ThetaTable> = theta_l
        .iter()
        .filter_map(|&t| {
            let held = known(samples, t).ok()?;
            let mut points: Vec<(f64, [f64; 3])> =
                held.iter().map(|s| (half_difference(s).0, s.rgb)).collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mean_d = held.iter().map(|s| half_difference(s).1).sum::<f64>() / held.len() as f64;
            Some((mean_d, points))
        })
        .collect();
    theta_l
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let held = known(samples, t)?;
            let mut others: Vec<&ThetaTable> = tables
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, table)| table)
                .collect();
            others.sort_by(|a, b| a.0.total_cmp(&b.0));
            if others.is_empty() {
                return Err("no other θL to interpolate".into());
            }
            let estimated: Vec<[f64; 3]> = held
                .iter()
                .map(|s| {
                    let (h, d) = half_difference(s);
                    let k = others.partition_point(|o| o.0 <= d);
                    if k == 0 || k == others.len() {
                        return along(&others[k.min(others.len() - 1)].1, h);
                    }
                    let (lo, hi) = (others[k - 1], others[k]);
                    let (a, b) = (along(&lo.1, h), along(&hi.1, h));
                    let w = (d - lo.0) / (hi.0 - lo.0);
                    std::array::from_fn(|c| a[c] + w * (b[c] - a[c]))
                })
                .collect();
            score(t, &held, &estimated, camera)
        })
        .collect()
}

/// Every variant judged at every θL of `samples` in turn, fits in parallel. Needs two
/// θL at least (each fit sees the others).
pub fn leave_one_theta_l_out(
    samples: &[Sample],
    variants: &[Variant],
    camera: &CameraModel,
) -> Result<Vec<HeldOut>, FitError> {
    let theta_l = distinct_theta_l(samples);
    if theta_l.len() < 2 {
        return Err(FitError::TooFewThetaL {
            count: theta_l.len(),
            needed: 2,
        });
    }
    let jobs: Vec<(usize, f64)> = (0..variants.len())
        .flat_map(|v| theta_l.iter().map(move |&t| (v, t)))
        .collect();
    let outcomes: Vec<(usize, f64, Result<Fold, String>)> = jobs
        .par_iter()
        .map(|&(v, t)| (v, t, fold(samples, variants[v], t, camera)))
        .collect();
    Ok(variants
        .iter()
        .enumerate()
        .map(|(v, &variant)| {
            let mut held = HeldOut {
                variant,
                folds: Vec::new(),
                failed: Vec::new(),
            };
            for (_, t, outcome) in outcomes.iter().filter(|(w, _, _)| *w == v) {
                match outcome {
                    Ok(f) => held.folds.push(f.clone()),
                    Err(e) => held.failed.push((*t, e.clone())),
                }
            }
            held
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lobe_is_what_rises_a_tenth_of_the_peak_above_the_floor() {
        let rgb = [
            [1.0; 3],
            [1.2, 1.2, 1.2],
            [1.4, 1.4, 1.4],
            [11.0, 11.0, 11.0],
        ];
        // Excesses 0, 0.6, 1.2, 30 (R + G + B): the threshold is 3.
        assert_eq!(lobe(&rgb), [false, false, false, true]);
        // A flat θL has no lobe.
        assert_eq!(lobe(&[[2.0; 3]; 3]), [false; 3]);
    }

    #[test]
    fn interpolation_predicts_a_brdf_of_the_half_angle_alone() {
        // β depends on signed θh only: every θL, interior or at an end of the θd range,
        // is predicted from the others to the accuracy of linear interpolation along θh.
        let beta = |h: f64| {
            let lobe = 50.0 * (-(h / 0.08).powi(2)).exp();
            [2.0 + lobe, 3.0 + 0.8 * lobe, 1.0 + 0.5 * lobe]
        };
        let mut samples = Vec::new();
        for theta_l in [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0] {
            // Every θL covers the lobe's θh (|θh| ≤ 17.5°): no extrapolation along θh.
            for k in 0..=320 {
                let theta_i = -40.0 + 0.25 * f64::from(k);
                let theta_r = theta_l - theta_i;
                let h = ((theta_i - theta_r) / 2.0f64).to_radians();
                samples.push(Sample::in_plane(theta_l, theta_i, theta_r, beta(h)));
            }
        }
        let folds = interpolation_folds(&samples, &CameraModel::builtin());
        assert_eq!(folds.len(), 6);
        for fold in folds {
            let fold = fold.unwrap();
            assert!(fold.all.err_p.iter().all(|&e| e < 1e-3), "{fold:?}");
            assert!(fold.lobe.is_some(), "{fold:?}");
        }
    }

    #[test]
    fn medians_skip_non_finite_values() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, f64::NAN, 2.0, 3.0]), Some(2.5));
        assert_eq!(median(&[]), None);
    }
}
