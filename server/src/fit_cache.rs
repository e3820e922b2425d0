//! What a scan's processing steps share of its fits: the [`fingerprint`] that tells
//! which samples a saved fit was made on, and the uncertainty budgets made since the
//! daemon started ([`Budgets`]), so that two fits that are the same fit (the auto fit
//! choosing a model and roughness form as one of the scan's per-model fits has it) pay
//! for one budget.

use std::sync::{Mutex, PoisonError};

use gonio_processing::fit::budget::{budget_if_possible, Budget};
use gonio_processing::fit::{FitError, FitResult};
use gonio_processing::samples::Sample;

/// Most budgets kept: the fits at the end of a few scans.
const KEPT: usize = 8;

/// A fingerprint of samples in their order: every field, as serialised exactly (to
/// JSON, which cannot fail for samples).
pub fn fingerprint(samples: &[Sample]) -> String {
    use std::hash::{DefaultHasher, Hasher};
    let mut hasher = DefaultHasher::new();
    hasher.write(&serde_json::to_vec(samples).unwrap_or_default());
    format!("{}:{:016x}", samples.len(), hasher.finish())
}

/// The budgets made, by the samples and the parametric fit they are of (the last
/// [`KEPT`]). Shared by the processing lane's steps, in the foreground and beside.
#[derive(Debug, Default)]
pub struct Budgets {
    made: Mutex<Vec<(String, Option<Budget>)>>,
}

impl Budgets {
    /// The budget of `fit`, a fit of `samples` ([`budget_if_possible`]): the one made
    /// already for a fit of the same samples with the same parametric fit, else made
    /// now. The budget is of the parametric fit alone (a table beside it, the choice
    /// recorded and the seconds taken are not part of it), so it is the same budget.
    pub fn of(&self, samples: &[Sample], fit: &FitResult) -> Result<Option<Budget>, FitError> {
        let Some(key) = key(samples, fit) else {
            return budget_if_possible(samples, fit);
        };
        let lock = || self.made.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some((_, budget)) = lock().iter().find(|(k, _)| *k == key) {
            return Ok(budget.clone());
        }
        let budget = budget_if_possible(samples, fit)?;
        let mut made = lock();
        if !made.iter().any(|(k, _)| *k == key) {
            if made.len() >= KEPT {
                made.remove(0);
            }
            made.push((key, budget.clone()));
        }
        Ok(budget)
    }
}

/// What a budget of `fit` on `samples` depends on: the samples' [`fingerprint`] and
/// every field of the fit but those the budget does not read; none if the fit cannot
/// be written out.
fn key(samples: &[Sample], fit: &FitResult) -> Option<String> {
    let parametric = FitResult {
        seconds: 0.0,
        selection: None,
        table: None,
        budget: None,
        ..fit.clone()
    };
    let fields = serde_json::to_string(&parametric).ok()?;
    Some(format!("{}|{fields}", fingerprint(samples)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_processing::brdf::Model;
    use gonio_processing::fit::{fit, FitOptions};
    use gonio_processing::samples::SampleUncertainty;
    use gonio_processing::setup_uncertainty::Source;

    /// Three θL of a lobe over a coloured diffuse, with a little deterministic scatter
    /// and their uncertainty.
    fn samples() -> Vec<Sample> {
        [-20.0, -30.0, -40.0]
            .iter()
            .flat_map(|&theta_l| {
                (0..40).map(move |i| {
                    let theta_i = -30.0 + 1.5 * f64::from(i);
                    let theta_r = theta_l - theta_i;
                    let lobe = 2.0 * (-((theta_i - theta_r) / 12.0).powi(2)).exp();
                    let scatter = 1.0 + 0.01 * (1.7 * f64::from(i) + theta_l).sin();
                    let rgb = [0.3 + lobe, 0.2 + lobe, 0.1 + lobe].map(|v| v * scatter);
                    let mut sample = Sample::in_plane(theta_l, theta_i, theta_r, rgb);
                    sample.uncertainty = Some(SampleUncertainty {
                        noise: rgb.map(|v| 0.01 * v),
                        sources: [rgb.map(|v| 0.002 * v); Source::COUNT],
                    });
                    sample
                })
            })
            .collect()
    }

    #[test]
    fn a_fit_that_differs_only_in_its_choice_table_or_seconds_shares_the_budget() {
        let samples = samples();
        let fitted = fit(&samples, &FitOptions::new(Model::CookTorrance)).unwrap();
        let budgets = Budgets::default();
        let made = budgets.of(&samples, &fitted).unwrap();
        assert!(made.is_some());
        assert_eq!(made, budget_if_possible(&samples, &fitted).unwrap());
        // The same fit chosen by the auto fit: a table beside it, other seconds.
        let chosen = FitResult {
            seconds: fitted.seconds + 1.0,
            table: Some(gonio_processing::fit::table::Table::new(&samples, 0.0).unwrap()),
            ..fitted.clone()
        };
        assert_eq!(budgets.of(&samples, &chosen).unwrap(), made);
        assert_eq!(budgets.made.lock().unwrap().len(), 1);
        // Another fit, or the same fit of other samples: budgets of their own.
        let ward = fit(&samples, &FitOptions::new(Model::Ward)).unwrap();
        budgets.of(&samples, &ward).unwrap();
        budgets.of(&samples[1..], &fitted).unwrap();
        assert_eq!(budgets.made.lock().unwrap().len(), 3);
        // At most the last few are kept.
        for k in 0..2 * KEPT {
            let other = FitResult {
                loss: fitted.loss + k as f64,
                ..fitted.clone()
            };
            budgets.of(&samples, &other).unwrap();
        }
        assert_eq!(budgets.made.lock().unwrap().len(), KEPT);
    }
}
