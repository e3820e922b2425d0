//! A refit of data near those of a known fit by projected Gauss–Newton steps on every
//! parameter at once (the budget's and the Monte Carlo's refits).
//!
//! The eq. 10 loss L(θ) = Σ_p ‖r_p‖ is smooth where no residual vanishes, and a refit's
//! values differ from the known fit's by a few standard uncertainties of the setup: its
//! minimum lies near the known fit's. From there each step solves A·d = Σ_p g_p, with A
//! the Gauss–Newton Hessian Σ_p J_pᵀ (I − u_p u_pᵀ)/‖r_p‖ J_p and g_p = J_pᵀ u_p the
//! points' gradients (`super::uncertainty`, the sandwich's own terms), over the
//! parameters free of their bound (a colour coefficient at 0, or ln m at an end of the
//! search range, whose gradient pushes it past stays there), and halves the step until
//! the loss falls, the coefficients clamped at 0 and ln m to the range. Each step costs two passes over the points, where a search along ln m
//! with the colour coefficients solved at each m costs dozens; the minimum it ends at is
//! the same one (the loss's stationary point on the free parameters), to the precision of
//! the loss's sum.
//!
//! It gives up (`None`) where the minimum is not a smooth one within reach: A singular
//! (ln m without a lobe), no decrease of the loss while the step is still large, or no
//! convergence within [`MAX_STEPS`]; the caller then searches along ln m
//! ([`super::robust::fit_near`]).

use nalgebra::{DMatrix, DVector};

use super::data::{Data, Found};
use super::options::FitOptions;
use super::uncertainty::{gauss_newton, Layout};
use crate::brdf::Params;

/// Most Gauss–Newton steps of a refit.
const MAX_STEPS: usize = 40;

/// Most halvings of one step.
const MAX_HALVINGS: usize = 30;

/// When a refit has converged.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Tolerance {
    /// A step moves ln m by at most this and every colour coefficient by at most this
    /// fraction of the largest of its kind's …
    pub step: f64,
    /// … or its predicted decrease of the loss, dᵀ·Σ_p g_p (twice the decrease of its
    /// quadratic model), is at most this fraction of the loss.
    pub decrement: f64,
    /// A step taken whole (no halving) whose predicted decrease was at most this
    /// fraction of the loss ends the refit where it lands: near the minimum the steps
    /// shrink tenfold or more each (on the full-size gold scan), so what is left is far
    /// below the step just taken, and no Gauss–Newton system is computed to confirm it.
    pub last: f64,
}

impl Tolerance {
    /// The law of propagation's refits, whose differences are the sensitivities: steps
    /// of a thousandth of the search's own precision on ln m
    /// ([`super::robust::Precision::FINE`]); ln m then moves by a few 1e-9 (on gold, red
    /// and opal). A last step taken whole below 1e-9 of the loss moves the budget's
    /// combined uncertainties by 2e-6 of themselves on gold.
    pub(crate) const FINE: Tolerance = Tolerance {
        step: 1e-9,
        decrement: 1e-14,
        last: 1e-9,
    };
}

/// A step along which the loss does not fall at any length is at the loss's rounding,
/// converged, when its predicted decrease is at most this fraction of the loss.
const STALL_TOLERANCE: f64 = 1e-12;

/// The parameters of a fit as one vector in `layout`'s order (ln m for the roughness).
fn vector(layout: &Layout, params: &Params, ks_90: &[f64; 3]) -> Vec<f64> {
    let mut theta = vec![0.0; layout.len()];
    for c in 0..3 {
        theta[layout.kd(c)] = params.kd[c];
        theta[layout.ks(c)] = params.ks[c];
        if let Some(kg) = layout.kg(c) {
            theta[kg] = ks_90[c];
        }
        theta[layout.ln_m(c)] = params.m[c].ln();
    }
    theta
}

/// The parameters and specular colour at 90° of `theta` (Ks_90 = Ks without one).
fn parameters(layout: &Layout, theta: &[f64]) -> (Params, [f64; 3]) {
    let params = Params {
        kd: std::array::from_fn(|c| theta[layout.kd(c)]),
        ks: std::array::from_fn(|c| theta[layout.ks(c)]),
        m: std::array::from_fn(|c| theta[layout.ln_m(c)].exp()),
    };
    let ks_90 = std::array::from_fn(|c| layout.kg(c).map_or(params.ks[c], |kg| theta[kg]));
    (params, ks_90)
}

/// Whether θ's entry `i` is a colour coefficient (bounded below by 0), not ln m.
fn is_colour(layout: &Layout, i: usize) -> bool {
    i < layout.ln_m(0)
}

/// The Gauss–Newton step on the free parameters: A_FF·d_F = s_F, d = 0 elsewhere, solved
/// with A scaled to a unit diagonal; `None` when A_FF is not positive definite.
fn step(hessian: &DMatrix<f64>, descent: &DVector<f64>, free: &[bool]) -> Option<Vec<f64>> {
    let index: Vec<usize> = (0..free.len()).filter(|&i| free[i]).collect();
    let n = index.len();
    let scale: Vec<f64> = index
        .iter()
        .map(|&i| {
            let d = hessian[(i, i)];
            (d > 0.0 && d.is_finite()).then(|| 1.0 / d.sqrt())
        })
        .collect::<Option<_>>()?;
    let a = DMatrix::from_fn(n, n, |r, c| {
        hessian[(index[r], index[c])] * scale[r] * scale[c]
    });
    let b = DVector::from_fn(n, |r, _| descent[index[r]] * scale[r]);
    let x = a.cholesky()?.solve(&b);
    let mut d = vec![0.0; free.len()];
    for (r, &i) in index.iter().enumerate() {
        d[i] = x[r] * scale[r];
    }
    d.iter().all(|v| v.is_finite()).then_some(d)
}

/// The fit of `data` near the known fit (`start`, its specular colour at 90° `start_kg`)
/// by projected Gauss–Newton steps (see the module), with `options`' roughness form and
/// search range, until `tolerance`; `None` where it gives up.
pub(crate) fn refit(
    data: &Data,
    options: &FitOptions,
    start: &Params,
    start_kg: [f64; 3],
    tolerance: Tolerance,
) -> Option<(Found, [f64; 3])> {
    let layout = Layout::of(data, options);
    let (lo, hi) = (options.robust.m_min.ln(), options.robust.m_max.ln());
    // Colour coefficients are at least 0, ln m within the search range.
    let bounds = |i: usize| {
        if is_colour(&layout, i) {
            (0.0, f64::INFINITY)
        } else {
            (lo, hi)
        }
    };
    let mut theta: Vec<f64> = vector(&layout, start, &start_kg)
        .iter()
        .enumerate()
        .map(|(i, v)| v.clamp(bounds(i).0, bounds(i).1))
        .collect();
    let (mut params, mut ks_90) = parameters(&layout, &theta);
    let mut loss = data.loss_fresnel(&params, &ks_90);
    let mut evaluations = 1;
    for _ in 0..MAX_STEPS {
        let (hessian, descent) = gauss_newton(data, options, &params, &ks_90)?;
        evaluations += 1;
        // A parameter at a bound whose gradient pushes it past stays there.
        let free: Vec<bool> = (0..theta.len())
            .map(|i| {
                let (low, high) = bounds(i);
                !((theta[i] <= low && descent[i] <= 0.0) || (theta[i] >= high && descent[i] >= 0.0))
            })
            .collect();
        let d = step(&hessian, &descent, &free)?;
        // Colour coefficients come in threes of a kind (Kd, Ks, Ks_90), each step
        // measured against the largest of its kind.
        let scale = |i: usize| {
            let kind = i / 3 * 3;
            theta[kind..kind + 3]
                .iter()
                .fold(f64::MIN_POSITIVE, |a, b| a.max(b.abs()))
        };
        let small = d.iter().enumerate().all(|(i, &v)| {
            let bound = if is_colour(&layout, i) { scale(i) } else { 1.0 };
            v.abs() <= tolerance.step * bound
        });
        let predicted: f64 = d.iter().zip(descent.iter()).map(|(a, b)| a * b).sum();
        if small || predicted <= tolerance.decrement * loss {
            return Some((
                Found {
                    params,
                    evaluations,
                },
                ks_90,
            ));
        }
        let mut t = 1.0;
        let mut accepted = false;
        for _ in 0..MAX_HALVINGS {
            let trial: Vec<f64> = (0..theta.len())
                .map(|i| {
                    let (low, high) = bounds(i);
                    (theta[i] + t * d[i]).clamp(low, high)
                })
                .collect();
            let (p, k) = parameters(&layout, &trial);
            let trial_loss = data.loss_fresnel(&p, &k);
            evaluations += 1;
            if trial_loss < loss {
                accepted = true;
                (theta, params, ks_90, loss) = (trial, p, k, trial_loss);
                break;
            }
            t *= 0.5;
        }
        if accepted && t == 1.0 && predicted <= tolerance.last * loss {
            return Some((
                Found {
                    params,
                    evaluations,
                },
                ks_90,
            ));
        }
        if !accepted {
            // No decrease: converged where the step's decrease is below the loss's
            // rounding, else not a smooth minimum within reach.
            return (predicted <= STALL_TOLERANCE * loss).then_some((
                Found {
                    params,
                    evaluations,
                },
                ks_90,
            ));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{Model, Roughness};
    use crate::fit::parameter_count;
    use crate::fit::robust;
    use crate::fit::uncertainty::tests::samples;

    /// From the fit of a scan, Gauss–Newton steps reach the minimum of the same scan with
    /// its values moved as a setup error moves them (more at one end of the range of
    /// incidence than at the other, in one θL more than in the other) that a full search
    /// along ln m finds, for every layout of θ.
    #[test]
    fn a_refit_reaches_the_minimum_a_full_search_finds() {
        for (model, roughness) in [
            (Model::CookTorrance, Roughness::Shared),
            (Model::Ward, Roughness::PerChannel),
            (Model::CookTorranceFresnel, Roughness::Shared),
            (Model::CookTorranceFresnel, Roughness::PerChannel),
        ] {
            let samples = samples(model);
            let mut options = FitOptions::new(model);
            options.roughness = roughness;
            let data = Data::new(&samples, model, parameter_count(model, roughness)).unwrap();
            let (start, start_kg) = robust::fit(&data, &options).unwrap();
            let moved: Vec<[f64; 3]> = data
                .y
                .iter()
                .zip(&samples)
                .map(|(y, s)| {
                    let f = 1.0 + 0.03 * (s.theta_i / 40.0) + 0.01 * (s.theta_l / 45.0);
                    y.map(|v| v * f)
                })
                .collect();
            let moved = data.with_measured(moved);
            let (found, kg) = refit(&moved, &options, &start.params, start_kg, Tolerance::FINE)
                .unwrap_or_else(|| panic!("{model} {roughness}: no convergence"));
            let (search, search_kg) = robust::fit(&moved, &options).unwrap();
            let label = format!(
                "{model} {roughness}: {:?} against {:?}",
                found.params, search.params
            );
            let (loss, search_loss) = (
                moved.loss_fresnel(&found.params, &kg),
                moved.loss_fresnel(&search.params, &search_kg),
            );
            assert!(
                loss <= search_loss * (1.0 + 1e-9),
                "{label}: {loss} > {search_loss}"
            );
            for c in 0..3 {
                let near = |a: f64, b: f64| (a - b).abs() <= 1e-4 * a.abs().max(b.abs()).max(1e-3);
                assert!(near(found.params.kd[c], search.params.kd[c]), "{label}");
                assert!(near(found.params.ks[c], search.params.ks[c]), "{label}");
                assert!(near(kg[c], search_kg[c]), "{label}");
                assert!(
                    (found.params.m[c].ln() - search.params.m[c].ln()).abs() <= 1e-5,
                    "{label}"
                );
            }
            // The refit moved from where it started.
            assert!(
                (found.params.kd[0] / start.params.kd[0] - 1.0).abs() > 1e-3,
                "{label}"
            );
        }
    }
}
