//! Samples prepared for fitting, and what a method finds in them.

use std::sync::Arc;

use super::error::FitError;
use super::lobe_columns::{LobeColumns, PlainModel};
use crate::brdf::{Basis, Model, Params, Prepared};
use crate::metrics;
use crate::samples::{distinct_theta_l, Sample};

/// Whether a fit of `model` to `samples` may fit a specular colour at 90° apart from Ks:
/// only for Cook–Torrance–Fresnel, and only from two θL or more. One θL sees one facet
/// incidence θd ≈ |θL|/2 where the lobe is (its spread there is the parallax of the
/// setup, about 0.1°), which cannot tell a colour changing with θd from the lobe's own
/// shape; the fit then ties Ks_90 to Ks, which is Cook–Torrance. From several θL
/// the shift is kept only when significant ([`super::COLOUR_SHIFT_LEVEL`]).
pub fn fits_colour_shift(model: Model, samples: &[Sample]) -> bool {
    model.has_fresnel_colour() && distinct_theta_l(samples).len() >= 2
}

/// Samples prepared for fitting. What depends on the points' geometry alone is shared
/// between the copies that differ in their measured values ([`Data::with_measured`]).
#[derive(Clone)]
pub(crate) struct Data {
    pub bases: Arc<[Basis]>,
    /// The lobe's terms of `bases` as columns, for the loops over every point.
    pub columns: Arc<LobeColumns>,
    /// Diffuse basis per point (copied out of `bases` for the inner loops).
    pub diffuse: Arc<[f64]>,
    /// Weight of the specular colour at 90° per point (`Basis::shift_weight`), for the models
    /// that have one, when the samples span several θL (see [`fits_colour_shift`]).
    pub shift_weight: Option<Arc<[f64]>>,
    /// Measured β per point; 0 where a channel was dropped.
    pub y: Vec<[f64; 3]>,
    /// Per point and channel 1 (measured) or 0 (dropped: left out of the loss);
    /// `None` when no value was dropped.
    pub keep: Option<Arc<[[f64; 3]]>>,
    /// Residual norms below this count as this in reweighting.
    pub residual_floor: f64,
    /// Eq. 10 loss of the all-zero model, Σ_p ‖y_p‖: the scale of the data.
    pub zero_loss: f64,
}

impl Data {
    /// `samples` at the basis of `model`, checked to have at least `parameters` points,
    /// finite values, no grazing direction and signal in every channel.
    pub fn new(samples: &[Sample], model: Model, parameters: usize) -> Result<Data, FitError> {
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
            let cosines = s.cosines();
            let basis = model.basis_at(&cosines);
            if basis.diffuse == 0.0 {
                return Err(FitError::Grazing {
                    index,
                    theta_i: s.theta_i,
                    theta_r: s.theta_r,
                    n_dot_l: cosines.n_dot_l,
                    n_dot_v: cosines.n_dot_v,
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
            if samples.iter().all(|s| s.dropped[c]) {
                return Err(FitError::AllDropped { channel });
            }
            if y.iter().map(|v| v[c]).sum::<f64>() <= 0.0 {
                return Err(FitError::NoSignal { channel });
            }
        }
        let zero_loss: f64 = y.iter().map(|v| metrics::point_loss(v, &[0.0; 3])).sum();
        let mean_norm = zero_loss / y.len() as f64;
        Ok(Data {
            diffuse: bases.iter().map(|b| b.diffuse).collect(),
            columns: Arc::new(LobeColumns::of(&bases)),
            shift_weight: fits_colour_shift(model, samples)
                .then(|| bases.iter().map(Basis::shift_weight).collect()),
            bases: bases.into(),
            y,
            keep,
            residual_floor: 1e-12 * mean_norm + f64::MIN_POSITIVE,
            zero_loss,
        })
    }

    /// The same points with the measured values `y` (one per point; dropped values stay
    /// left out).
    pub fn with_measured(&self, mut y: Vec<[f64; 3]>) -> Data {
        if let Some(keep) = &self.keep {
            for (v, keep) in y.iter_mut().zip(keep.iter()) {
                *v = std::array::from_fn(|c| v[c] * keep[c]);
            }
        }
        let zero_loss: f64 = y.iter().map(|v| metrics::point_loss(v, &[0.0; 3])).sum();
        let mean_norm = zero_loss / y.len().max(1) as f64;
        Data {
            bases: Arc::clone(&self.bases),
            columns: Arc::clone(&self.columns),
            diffuse: Arc::clone(&self.diffuse),
            shift_weight: self.shift_weight.clone(),
            y,
            keep: self.keep.clone(),
            residual_floor: 1e-12 * mean_norm + f64::MIN_POSITIVE,
            zero_loss,
        }
    }

    /// Eq. 10 loss of `params` (specular colour constant) over the measured values.
    pub fn loss(&self, params: &Params) -> f64 {
        self.loss_fresnel(params, &params.ks)
    }

    /// Eq. 10 loss of `params` with the specular colour at 90° `ks_90`, over the measured
    /// values (the inner loop of Nelder–Mead: the parameters are prepared once).
    pub fn loss_fresnel(&self, params: &Params, ks_90: &[f64; 3]) -> f64 {
        let prepared = Prepared::new(params, ks_90);
        if prepared.is_plain() {
            // One lobe and a constant specular colour: the columns' loop.
            return self.columns.plain_loss(&PlainModel {
                kd: params.kd,
                ks: params.ks,
                m: params.m[0],
                diffuse: &self.diffuse,
                y: &self.y,
                keep: self.keep.as_deref(),
            });
        }
        let points = self.bases.iter().zip(&self.y);
        match &self.keep {
            None => points
                .map(|(b, y)| metrics::point_loss(y, &b.evaluate_prepared(&prepared)))
                .sum(),
            Some(keep) => points
                .zip(keep.iter())
                .map(|((b, y), keep)| {
                    let estimate = b.evaluate_prepared(&prepared);
                    metrics::point_loss(y, &std::array::from_fn(|c| estimate[c] * keep[c]))
                })
                .sum(),
        }
    }

    /// The model's β at every point, 0 where the measured value was dropped (so dropped
    /// values count in neither the loss nor ΔErr_p).
    pub fn estimates(&self, params: &Params, ks_90: &[f64; 3]) -> Vec<[f64; 3]> {
        let prepared = Prepared::new(params, ks_90);
        let mut estimates: Vec<[f64; 3]> = self
            .bases
            .iter()
            .map(|b| b.evaluate_prepared(&prepared))
            .collect();
        if let Some(keep) = &self.keep {
            for (estimate, keep) in estimates.iter_mut().zip(keep.iter()) {
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
