//! The Nelder–Mead method (argmin's `NelderMead`) over all parameters at once:
//! x = [Kd_R, Kd_G, Kd_B, Ks_R, Ks_G, Ks_B, m…] with one or three m.
//!
//! Constraints Kd, Ks ≥ 0 and m > 0 are kept by a penalty: outside them the cost is the
//! loss at the clamped parameters plus Σ‖y‖·(1 + violation), more than the loss of any
//! feasible point (the all-zero model's loss is Σ‖y‖), so the simplex stays feasible.

use std::cell::Cell;

use argmin::core::{CostFunction, Error as ArgminError, Executor, State};
use argmin::solver::neldermead::NelderMead;

use super::{Data, FitError, FitOptions, Found};
use crate::brdf::{Params, Roughness, M_MIN};

/// The penalised loss over a parameter vector.
struct Objective<'a> {
    data: &'a Data,
    roughness: Roughness,
    penalty: f64,
    evaluations: &'a Cell<u64>,
}

fn pack(params: &Params, roughness: Roughness) -> Vec<f64> {
    let mut x = Vec::with_capacity(9);
    x.extend_from_slice(&params.kd);
    x.extend_from_slice(&params.ks);
    x.extend_from_slice(&params.m[..roughness.count()]);
    x
}

/// Parameters of `x`, clamped to the feasible set, and how far `x` lies outside it.
fn unpack(x: &[f64], roughness: Roughness) -> (Params, f64) {
    let mut violation = 0.0;
    let mut clamp = |v: f64, min: f64| {
        if v.is_nan() {
            violation += 1.0;
            min
        } else if v < min {
            violation += min - v;
            min
        } else {
            v
        }
    };
    let kd = std::array::from_fn(|c| clamp(x[c], 0.0));
    let ks = std::array::from_fn(|c| clamp(x[3 + c], 0.0));
    let m = match roughness {
        Roughness::Shared => [clamp(x[6], M_MIN); 3],
        Roughness::PerChannel => std::array::from_fn(|c| clamp(x[6 + c], M_MIN)),
    };
    (Params { kd, ks, m }, violation)
}

impl CostFunction for Objective<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, x: &Vec<f64>) -> Result<f64, ArgminError> {
        self.evaluations.set(self.evaluations.get() + 1);
        let (params, violation) = unpack(x, self.roughness);
        let loss = self.data.loss(&params);
        let cost = if violation > 0.0 {
            loss + self.penalty * (1.0 + violation)
        } else {
            loss
        };
        Ok(if cost.is_finite() { cost } else { f64::MAX })
    }
}

/// Runs the simplex from `start`, vertex i moving parameter i by `steps[i]`.
fn run(
    data: &Data,
    options: &FitOptions,
    start: &Params,
    steps: &[f64],
) -> Result<Found, FitError> {
    let nm = &options.nelder_mead;
    let x0 = pack(start, options.roughness);
    let mut simplex = vec![x0.clone()];
    for (i, step) in steps.iter().enumerate() {
        let mut vertex = x0.clone();
        vertex[i] += step;
        simplex.push(vertex);
    }
    let evaluations = Cell::new(0);
    let objective = Objective {
        data,
        roughness: options.roughness,
        penalty: data.zero_loss,
        evaluations: &evaluations,
    };
    let solver = NelderMead::new(simplex)
        .with_sd_tolerance(nm.sd_tolerance)
        .map_err(|e| FitError::InvalidOptions(e.to_string()))?;
    let result = Executor::new(objective, solver)
        .configure(|state| state.max_iters(nm.max_iters))
        .run()
        .map_err(|e| FitError::Optimizer(e.to_string()))?;
    let best = result
        .state()
        .get_best_param()
        .ok_or_else(|| FitError::Optimizer("Nelder–Mead returned no parameters".into()))?;
    Ok(Found {
        params: unpack(best, options.roughness).0,
        evaluations: evaluations.get(),
    })
}

/// Start from the data: Kd at the lowest β/a, Ks matching the peak at the initial m.
fn initial_params(data: &Data, m: f64) -> Params {
    let mut kd = [0.0; 3];
    let mut ks = [0.0; 3];
    for c in 0..3 {
        kd[c] = data
            .y
            .iter()
            .zip(&data.diffuse)
            .map(|(y, a)| y[c] / a)
            .fold(f64::INFINITY, f64::min)
            .max(0.0);
        let peak = data
            .y
            .iter()
            .enumerate()
            .max_by(|(_, a), (_, b)| a[c].total_cmp(&b[c]))
            .map_or(0, |(p, _)| p);
        let s = data.bases[peak].specular(m);
        if s > 0.0 {
            ks[c] = ((data.y[peak][c] - kd[c] * data.diffuse[peak]) / s).max(0.0);
        }
    }
    Params::shared(kd, ks, m)
}

pub(crate) fn fit(data: &Data, options: &FitOptions) -> Result<Found, FitError> {
    let nm = &options.nelder_mead;
    if !(nm.initial_m > 0.0 && nm.initial_m.is_finite()) {
        return Err(FitError::InvalidOptions(format!(
            "initial_m = {} must be positive",
            nm.initial_m
        )));
    }
    if !(nm.simplex_scale > 0.0 && nm.simplex_scale.is_finite()) {
        return Err(FitError::InvalidOptions(format!(
            "simplex_scale = {} must be positive",
            nm.simplex_scale
        )));
    }
    let start = initial_params(data, nm.initial_m);
    let y_max = data
        .y
        .iter()
        .flat_map(|y| y.iter().copied())
        .fold(0.0, f64::max);
    let steps = step_sizes(&start, options.roughness, nm.simplex_scale, 1e-2 * y_max);
    run(data, options, &start, &steps)
}

/// A small simplex (5 % of each value) around a robust solution.
pub(crate) fn polish(data: &Data, options: &FitOptions, start: &Params) -> Result<Found, FitError> {
    let floor = 1e-3
        * start
            .kd
            .iter()
            .chain(&start.ks)
            .fold(0.0, |a: f64, &b| a.max(b));
    let steps = step_sizes(start, options.roughness, 0.05, floor.max(1e-9));
    run(data, options, start, &steps)
}

fn step_sizes(start: &Params, roughness: Roughness, scale: f64, floor: f64) -> Vec<f64> {
    pack(start, roughness)
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            if i < 6 {
                scale * v.abs().max(floor)
            } else {
                scale * v
            }
        })
        .collect()
}
