//! The paper's method: fminsearch (see `simplex`) over all parameters at once,
//! x = [Kd_R, Kd_G, Kd_B, Ks_R, Ks_G, Ks_B, m…] with one or three m, minimising the
//! eq. 10 loss with fminsearch's defaults (TolX = TolFun = 1e-4, 200·n iterations and
//! evaluations). Kd, Ks ≥ 0 and M_MIN ≤ m ≤ M_MAX hold because every trial point is
//! clipped onto those bounds; the loss itself is never altered.

use super::data::{Data, Found};
use super::error::FitError;
use super::options::FitOptions;
use super::simplex::{self, Settings};
use crate::brdf::{Params, Roughness, M_MAX, M_MIN};

fn pack(params: &Params, roughness: Roughness) -> Vec<f64> {
    let mut x = Vec::with_capacity(9);
    x.extend_from_slice(&params.kd);
    x.extend_from_slice(&params.ks);
    x.extend_from_slice(&params.m[..roughness.count()]);
    x
}

/// Parameters of a point inside the bounds.
fn unpack(x: &[f64], roughness: Roughness) -> Params {
    let kd = std::array::from_fn(|c| x[c]);
    let ks = std::array::from_fn(|c| x[3 + c]);
    let m = match roughness {
        Roughness::Shared => [x[6]; 3],
        Roughness::PerChannel => std::array::from_fn(|c| x[6 + c]),
    };
    Params { kd, ks, m }
}

/// fminsearch from `start`.
fn search(data: &Data, options: &FitOptions, start: &Params) -> Result<Found, FitError> {
    let nm = &options.nelder_mead;
    let roughness = options.roughness;
    let x0 = pack(start, roughness);
    let n = x0.len();
    let defaults = Settings::fminsearch(n);
    let settings = Settings {
        tol_x: nm.tol_x,
        tol_fun: nm.tol_fun,
        max_iter: nm.max_iter.unwrap_or(defaults.max_iter),
        max_fun_evals: nm.max_fun_evals.unwrap_or(defaults.max_fun_evals),
    };
    let lower: Vec<f64> = (0..n).map(|i| if i < 6 { 0.0 } else { M_MIN }).collect();
    let upper: Vec<f64> = (0..n)
        .map(|i| if i < 6 { f64::INFINITY } else { M_MAX })
        .collect();
    let found = simplex::minimize(
        |x| data.loss(&unpack(x, roughness)),
        &x0,
        &lower,
        &upper,
        &settings,
    );
    if !found.value.is_finite() {
        return Err(FitError::Optimizer(format!(
            "Nelder–Mead found no finite loss in {} evaluations",
            found.evaluations
        )));
    }
    Ok(Found {
        params: unpack(&found.x, roughness),
        evaluations: found.evaluations as u64,
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
            .zip(data.diffuse.iter())
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

fn check_options(options: &FitOptions) -> Result<(), FitError> {
    let nm = &options.nelder_mead;
    let bad = |what: String| Err(FitError::InvalidOptions(what));
    if !(nm.initial_m > 0.0 && nm.initial_m.is_finite()) {
        return bad(format!("initial_m = {} must be positive", nm.initial_m));
    }
    if !(nm.tol_x >= 0.0 && nm.tol_fun >= 0.0) {
        return bad(format!(
            "tol_x = {}, tol_fun = {} must be ≥ 0",
            nm.tol_x, nm.tol_fun
        ));
    }
    Ok(())
}

pub(crate) fn fit(data: &Data, options: &FitOptions) -> Result<Found, FitError> {
    check_options(options)?;
    let start = initial_params(data, options.nelder_mead.initial_m);
    search(data, options, &start)
}

/// fminsearch from a robust solution (its default simplex is 5 % of each value).
pub(crate) fn polish(data: &Data, options: &FitOptions, start: &Params) -> Result<Found, FitError> {
    check_options(options)?;
    search(data, options, start)
}
