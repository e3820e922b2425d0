//! The geometric model of the observations and its weighted least-squares fit
//! (Levenberg–Marquardt with a numerical Jacobian).
//!
//! Each observation gives a residual in units of its standard uncertainty:
//! - a limb: the mean over rows of the measured minus the modelled limb column (the
//!   column whose ray is tangent to the cylinder), in sensor pixels; its uncertainty is
//!   the pixel quantisation, 1/√12 capture pixel, which rows do not average away; and
//!   the slope of that difference over the rows (a camera roll or a cylinder tilt
//!   slants the limb);
//! - a terminator row: the white strip's brightness W(u) regressed on the model's
//!   irradiance c(u) = n·(L − P)/|L − P|³ (signed, so it extends past the shadow line)
//!   as W = a + b·c + e·c²; where the model is right, W vanishes where c does, a = 0.
//!   The residual is how far the measured shadow line lies from the modelled one,
//!   −a/(b·dc/du), in pixels (smooth gains such as vignetting do not move a zero);
//! - a specular row: ln((β − baseline)·(n·l)(n·v)) regressed on x = h_t/h_n, the
//!   tangent of the half vector's tilt from the normal along the row (h_t its component
//!   along the surface tangent perpendicular to the axis, from each pixel's true 3D
//!   directions), as a parabola. With h_a the component along the axis,
//!   tan²α = x² + (h_a/h_n)², and the second term barely changes along a row, so a lobe
//!   symmetric in α peaks at x = 0. The factor (n·l)(n·v) undoes Cook–Torrance's
//!   1/(cos θi cos θr), which finite distances make lopsided along a row, leaving D·G.
//!   The residual is the parabola's vertex x₀ = −c₁/(2c₂) (≈ radians).
//!
//! - a prior: a parameter's distance from its stated value in its stated standard
//!   uncertainty (the camera's yaw and roll, which the images tell apart from the
//!   camera's offset and the cylinder's tilt only in part).
//!
//! Terminator and peak uncertainties come from their regressions' residuals, computed
//! once at the starting geometry so that the objective stays smooth.

use nalgebra::{DMatrix, DVector};

use super::observe::Side;
use crate::geometry::Setup;

/// One row of the white strip's ramp toward its shadow line at one θL.
#[derive(Debug, Clone)]
pub struct TerminatorRow {
    pub theta_l: f64,
    /// Sensor row.
    pub v: f64,
    /// (sensor column, brightness).
    pub points: Vec<(f64, f64)>,
    pub sigma: f64,
}

/// One row of the sample strip's specular peak at one θL.
#[derive(Debug, Clone)]
pub struct PeakRow {
    pub theta_l: f64,
    pub v: f64,
    /// (sensor column, ratio to the white minus the baseline, > 0).
    pub points: Vec<(f64, f64)>,
    pub sigma: f64,
}

/// The limb on one side: measured columns at sensor rows.
#[derive(Debug, Clone)]
pub struct Limb {
    pub side: Side,
    /// (sensor row, measured sensor column).
    pub points: Vec<(f64, f64)>,
    pub sigma: f64,
}

/// Everything the fit sees.
#[derive(Debug, Clone, Default)]
pub struct Observations {
    pub limbs: Vec<Limb>,
    pub terminators: Vec<TerminatorRow>,
    pub peaks: Vec<PeakRow>,
    /// What is known of a parameter before the images: its stated value and standard
    /// uncertainty, one residual each.
    pub priors: Vec<Prior>,
}

/// A parameter's stated value and standard uncertainty (> 0).
#[derive(Debug, Clone, Copy)]
pub struct Prior {
    pub parameter: Parameter,
    pub value: f64,
    pub sigma: f64,
}

/// Which setup fields are free, in parameter-vector order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parameter {
    CameraOffset,
    CylinderTilt,
    ArmZeroOffset,
    CameraDistance,
    CameraYaw,
    CameraRoll,
}

impl Parameter {
    fn get(self, s: &Setup) -> f64 {
        match self {
            Parameter::CameraOffset => s.camera_offset_mm,
            Parameter::CylinderTilt => s.cylinder_tilt_deg,
            Parameter::ArmZeroOffset => s.arm_zero_offset_deg,
            Parameter::CameraDistance => s.camera_distance_mm,
            Parameter::CameraYaw => s.camera_yaw_deg,
            Parameter::CameraRoll => s.camera_roll_deg,
        }
    }

    fn set(self, s: &mut Setup, value: f64) {
        match self {
            Parameter::CameraOffset => s.camera_offset_mm = value,
            Parameter::CylinderTilt => s.cylinder_tilt_deg = value,
            Parameter::ArmZeroOffset => s.arm_zero_offset_deg = value,
            Parameter::CameraDistance => s.camera_distance_mm = value,
            Parameter::CameraYaw => s.camera_yaw_deg = value,
            Parameter::CameraRoll => s.camera_roll_deg = value,
        }
    }

    /// Step of the numerical derivative.
    fn step(self) -> f64 {
        match self {
            Parameter::CameraOffset => 1e-3,
            Parameter::CylinderTilt
            | Parameter::ArmZeroOffset
            | Parameter::CameraYaw
            | Parameter::CameraRoll => 1e-4,
            Parameter::CameraDistance => 1e-2,
        }
    }
}

/// The sensor column where the ray of sensor row `v` is tangent to the cylinder on
/// `side` (bisection on the ray's signed distance from the axis, which grows with u).
pub fn limb_column(setup: &Setup, v: f64, side: Side) -> f64 {
    let frame = setup.frame();
    let target = match side {
        Side::Left => -setup.cylinder_radius_mm,
        Side::Right => setup.cylinder_radius_mm,
    };
    let width = f64::from(setup.image_width);
    let (mut lo, mut hi) = (-2.0 * width, 3.0 * width);
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        if frame.signed_axis_distance(mid, v) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Signed irradiance n·(L − P)/|L − P|³ at pixel (u, v), `None` where the ray misses.
fn signed_irradiance(setup: &Setup, u: f64, v: f64, theta_l: f64) -> Option<f64> {
    let hit = setup.frame().hit(u, v)?;
    let light = setup.light_position(theta_l);
    let l: Vec<f64> = (0..3).map(|k| light[k] - hit.point[k]).collect();
    let l2: f64 = l.iter().map(|x| x * x).sum();
    let n_l: f64 = (0..3).map(|k| hit.normal[k] * l[k]).sum();
    Some(n_l / (l2 * l2.sqrt()))
}

/// At pixel (u, v): x = h_t/h_n, the half vector's tilt along the row (h ∝ l̂ + v̂;
/// l̂_t = (n·l) tan θi and v̂_t = −(n·v) tan θr from the in-plane angles), and
/// (n·l)(n·v).
fn lobe_coordinates(setup: &Setup, u: f64, v: f64, theta_l: f64) -> Option<(f64, f64)> {
    let g = setup.pixel_geometry(u, v, theta_l)?;
    let (n_l, n_v) = (g.cosines.n_dot_l, g.cosines.n_dot_v);
    if !(n_l > 0.0 && n_v > 0.0) {
        return None;
    }
    let tangential = n_l * g.theta_i.to_radians().tan() - n_v * g.theta_r.to_radians().tan();
    Some((tangential / (n_l + n_v), n_l * n_v))
}

/// Weighted least squares y ≈ Σ_k β_k f_k: coefficients, their covariance (scaled by
/// the residual variance) and the residual variance; `None` when singular or short.
fn least_squares(rows: &[(Vec<f64>, f64, f64)]) -> Option<(DVector<f64>, DMatrix<f64>, f64)> {
    let k = rows.first()?.0.len();
    if rows.len() <= k {
        return None;
    }
    let mut ata = DMatrix::<f64>::zeros(k, k);
    let mut atb = DVector::<f64>::zeros(k);
    for (f, y, w) in rows {
        for i in 0..k {
            atb[i] += w * f[i] * y;
            for j in 0..k {
                ata[(i, j)] += w * f[i] * f[j];
            }
        }
    }
    let inverse = ata.clone().try_inverse()?;
    let beta = &inverse * &atb;
    let rss: f64 = rows
        .iter()
        .map(|(f, y, w)| {
            let fit: f64 = f.iter().zip(beta.iter()).map(|(a, b)| a * b).sum();
            w * (y - fit).powi(2)
        })
        .sum();
    let variance = rss / (rows.len() - k) as f64;
    let covariance = inverse * variance;
    beta.iter()
        .all(|b| b.is_finite())
        .then_some((beta, covariance, variance))
}

/// The terminator residual (pixels) of a row and its standard uncertainty.
pub fn terminator_offset(setup: &Setup, row: &TerminatorRow) -> Option<(f64, f64)> {
    let mut fits = Vec::with_capacity(row.points.len());
    let mut slope_rows = Vec::with_capacity(row.points.len());
    for &(u, w) in &row.points {
        let c = signed_irradiance(setup, u, row.v, row.theta_l)?;
        fits.push((vec![1.0, c, c * c], w, 1.0));
        slope_rows.push((vec![1.0, u], c, 1.0));
    }
    let (coef, cov, _) = least_squares(&fits)?;
    let (slope, _, _) = least_squares(&slope_rows)?;
    let (a, b, dc_du) = (coef[0], coef[1], slope[1]);
    // The brightness must follow the irradiance clearly (b five standard errors from 0).
    if !(b > 5.0 * cov[(1, 1)].max(0.0).sqrt() && dc_du != 0.0) {
        return None;
    }
    let offset = -a / (b * dc_du);
    // Uncertainty of a (b's is a second-order effect near a = 0).
    let sigma = cov[(0, 0)].max(0.0).sqrt() / (b * dc_du).abs();
    Some((offset, sigma))
}

/// The specular residual (vertex of the ln-parabola in tan α) of a row and its
/// standard uncertainty.
pub fn peak_vertex(setup: &Setup, row: &PeakRow) -> Option<(f64, f64)> {
    let mut fits = Vec::with_capacity(row.points.len());
    for &(u, excess) in &row.points {
        let (x, foreshortening) = lobe_coordinates(setup, u, row.v, row.theta_l)?;
        // ln-domain weights (excess)² treat the ratio's noise as constant.
        let lobe = excess * foreshortening;
        fits.push((vec![1.0, x, x * x], lobe.ln(), excess * excess));
    }
    let (coef, cov, _) = least_squares(&fits)?;
    let (c1, c2) = (coef[1], coef[2]);
    // A clearly curved peak (c2 five standard errors below 0) whose vertex lies among
    // the points: otherwise the vertex is ill-determined and swings with the geometry.
    if !(c2.is_finite() && c2 < -5.0 * cov[(2, 2)].max(0.0).sqrt()) {
        return None;
    }
    let x0 = -c1 / (2.0 * c2);
    let (lowest, highest) = fits
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), f| {
            (lo.min(f.0[1]), hi.max(f.0[1]))
        });
    if !(x0 > lowest && x0 < highest) {
        return None;
    }
    // Delta method: ∂x0/∂c1 = −1/(2c2), ∂x0/∂c2 = c1/(2c2²).
    let (d1, d2) = (-1.0 / (2.0 * c2), c1 / (2.0 * c2 * c2));
    let var = d1 * d1 * cov[(1, 1)] + d2 * d2 * cov[(2, 2)] + 2.0 * d1 * d2 * cov[(1, 2)];
    Some((x0, var.max(0.0).sqrt()))
}

/// Residuals of every observation at `setup`, in units of their uncertainties, in a
/// fixed order; `None` entries where the model cannot be evaluated (counted as large).
fn residuals(setup: &Setup, obs: &Observations) -> Vec<f64> {
    const UNUSABLE: f64 = 1e3;
    let mut out = Vec::new();
    for limb in &obs.limbs {
        let (mean, slope) = limb_misfit(setup, limb);
        out.push(mean / limb.sigma);
        out.push(slope.map_or(0.0, |(slope, sigma)| slope / sigma));
    }
    for row in &obs.terminators {
        out.push(terminator_offset(setup, row).map_or(UNUSABLE, |(r, _)| r / row.sigma));
    }
    for row in &obs.peaks {
        out.push(peak_vertex(setup, row).map_or(UNUSABLE, |(r, _)| r / row.sigma));
    }
    for prior in &obs.priors {
        out.push((prior.parameter.get(setup) - prior.value) / prior.sigma);
    }
    out
}

/// A limb's measured minus modelled columns: their mean (pixels) and, over its rows,
/// their least-squares slope (pixels per row) with its standard uncertainty (the
/// limb's per-row uncertainty over √Σ(v − v̄)²; rows' quantisation errors independent,
/// as they are along a limb that is not exactly vertical in the image); `None` for
/// rows that do not spread.
pub fn limb_misfit(setup: &Setup, limb: &Limb) -> (f64, Option<(f64, f64)>) {
    let n = limb.points.len() as f64;
    let misfit: Vec<(f64, f64)> = limb
        .points
        .iter()
        .map(|&(v, u)| (v, u - limb_column(setup, v, limb.side)))
        .collect();
    let mean = misfit.iter().map(|p| p.1).sum::<f64>() / n;
    let mean_v = misfit.iter().map(|p| p.0).sum::<f64>() / n;
    let svv: f64 = misfit.iter().map(|p| (p.0 - mean_v).powi(2)).sum();
    let svd: f64 = misfit.iter().map(|p| (p.0 - mean_v) * (p.1 - mean)).sum();
    let slope = (svv > 0.0).then(|| (svd / svv, limb.sigma / svv.sqrt()));
    (mean, slope)
}

/// Drops the terminator and peak rows whose residual at `setup` exceeds `limit`
/// standard uncertainties (a row spoilt by a stuck pixel, say), returning how many.
pub fn drop_outliers(setup: &Setup, obs: &mut Observations, limit: f64) -> usize {
    let before = obs.terminators.len() + obs.peaks.len();
    obs.terminators.retain(|row| {
        terminator_offset(setup, row).is_some_and(|(r, _)| (r / row.sigma).abs() <= limit)
    });
    obs.peaks
        .retain(|row| peak_vertex(setup, row).is_some_and(|(r, _)| (r / row.sigma).abs() <= limit));
    before - obs.terminators.len() - obs.peaks.len()
}

/// The fitted setup, the parameters' covariance and χ² per degree of freedom.
#[derive(Debug, Clone)]
pub struct Solution {
    pub setup: Setup,
    pub covariance: DMatrix<f64>,
    pub chi2_per_dof: f64,
    pub residuals: Vec<f64>,
}

/// Levenberg–Marquardt over `parameters` from `start`.
pub fn fit(start: &Setup, obs: &Observations, parameters: &[Parameter]) -> Option<Solution> {
    let n_p = parameters.len();
    let mut setup = start.clone();
    let mut r = residuals(&setup, obs);
    let n = r.len();
    if n <= n_p {
        return None;
    }
    let cost = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    let jacobian = |setup: &Setup, r: &[f64]| {
        let mut j = DMatrix::<f64>::zeros(n, n_p);
        for (k, p) in parameters.iter().enumerate() {
            let mut moved = setup.clone();
            p.set(&mut moved, p.get(setup) + p.step());
            let r2 = residuals(&moved, obs);
            for i in 0..n {
                j[(i, k)] = (r2[i] - r[i]) / p.step();
            }
        }
        j
    };
    let mut lambda = 1e-3;
    let mut current = cost(&r);
    for _ in 0..50 {
        let j = jacobian(&setup, &r);
        let jtj = j.transpose() * &j;
        let jtr = j.transpose() * DVector::from_vec(r.clone());
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = jtj.clone();
            for k in 0..n_p {
                damped[(k, k)] += lambda * jtj[(k, k)].max(1e-12);
            }
            let Some(step) = damped.try_inverse().map(|inv| -(inv * &jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = setup.clone();
            for (k, p) in parameters.iter().enumerate() {
                p.set(&mut trial, p.get(&setup) + step[k]);
            }
            if trial.validate().is_err() {
                lambda *= 10.0;
                continue;
            }
            let r_trial = residuals(&trial, obs);
            let c_trial = cost(&r_trial);
            if c_trial < current {
                let small = step
                    .iter()
                    .zip(parameters)
                    .all(|(s, p)| s.abs() < 1e-3 * p.step());
                setup = trial;
                r = r_trial;
                let relative = (current - c_trial) / current.max(f64::MIN_POSITIVE);
                current = c_trial;
                lambda = (lambda / 10.0).max(1e-9);
                improved = true;
                if small || relative < 1e-12 {
                    return finish(setup, obs, parameters, r, current);
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    finish(setup, obs, parameters, r, current)
}

fn finish(
    setup: Setup,
    obs: &Observations,
    parameters: &[Parameter],
    r: Vec<f64>,
    cost: f64,
) -> Option<Solution> {
    let n_p = parameters.len();
    let n = r.len();
    let mut j = DMatrix::<f64>::zeros(n, n_p);
    for (k, p) in parameters.iter().enumerate() {
        // Central differences for the covariance.
        let mut up = setup.clone();
        let mut down = setup.clone();
        p.set(&mut up, p.get(&setup) + p.step());
        p.set(&mut down, p.get(&setup) - p.step());
        let (ru, rd) = (residuals(&up, obs), residuals(&down, obs));
        for i in 0..n {
            j[(i, k)] = (ru[i] - rd[i]) / (2.0 * p.step());
        }
    }
    let chi2_per_dof = cost / (n - n_p) as f64;
    let covariance = (j.transpose() * j).try_inverse()? * chi2_per_dof.max(1.0);
    Some(Solution {
        setup,
        covariance,
        chi2_per_dof,
        residuals: r,
    })
}
