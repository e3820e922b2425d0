//! Calibration of a scan's setup from its own captures (docs/ARCHITECTURE.md,
//! "Calibration"): the strip rows, the cylinder's silhouette and axis in the image,
//! the camera's sideways offset (and its distance when both limbs show), the cylinder's
//! tilt and the arm's zero offset, each with a standard uncertainty (which the calibrated
//! setup.json's `uncertainty` block states), and residuals that say whether the model
//! fits.
//!
//! The known quantities come from a prior [`Setup`] (the scan's setup.json): cylinder
//! radius, focal length, pixel pitch, principal point, light distance, and the camera
//! distance when only one limb is lit. Per θL the bracket is merged ([`hdr::merge`]),
//! and `observe` measures, with no model: the lit bands of rows (the two strips),
//! the white strip's limbs (a step to black where the camera ray grazes the cylinder),
//! its terminator ramp (where the light grazes it) and the sample strip's specular peak
//! relative to the white. `solve` then fits the free setup fields to all of them.
#![doc = include_str!("calibrate.md")]

mod observe;
mod solve;

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;
use thiserror::Error;

use crate::capture::Frame;
use crate::extract::{self, ExtractError};
use crate::geometry::{GeometryError, Setup};
use crate::hdr::{self, HdrError, MergeOptions, SATURATED, UNDEREXPOSED};
use crate::setup_uncertainty::{SetupUncertainty, Source, MAX_UNCERTAINTY};
use observe::{Band, Side};
use solve::{Limb, Observations, Parameter, PeakRow, Prior, TerminatorRow};

/// Largest share of the white strip's lit pixels (in the rows measured) that may be
/// clipped in every frame: a scan exposed for it has none (the bracket's shortest
/// exposure reads the white), an overexposed one most.
const MAX_SATURATED_SHARE: f64 = 0.25;

/// Options of [`calibrate_scan`].
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrateOptions {
    pub merge: MergeOptions,
    /// Rows of each strip's core measured per θL (evenly spread).
    pub rows_per_strip: usize,
}

impl Default for CalibrateOptions {
    fn default() -> Self {
        Self {
            merge: MergeOptions::default(),
            rows_per_strip: 24,
        }
    }
}

/// Why a calibration could not be made.
#[derive(Debug, Error)]
pub enum CalibrateError {
    #[error(transparent)]
    Extract(#[from] ExtractError),
    #[error("prior setup: {0}")]
    Prior(GeometryError),
    #[error("θL {theta_l}°: {source}")]
    Hdr { theta_l: f64, source: HdrError },
    #[error(
        "θL {theta_l}°: {found} lit band(s) of rows; the sample and white strips need two, each the nearest to its row of the prior setup (sample_row, white_row)"
    )]
    Strips { theta_l: f64, found: usize },
    #[error("θL {theta_l}°: {percent:.0} % of the white strip's lit pixels are saturated in every frame: its edges cannot be measured (shorten the bracket's exposures)")]
    Saturated { theta_l: f64, percent: f64 },
    #[error("nothing to fit the geometry to: {0}")]
    Underdetermined(String),
}

/// An estimated quantity and its standard uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Estimate {
    pub value: f64,
    pub stderr: f64,
}

/// The cylinder's axis in the image (sensor pixels), from the calibrated geometry.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AxisInImage {
    /// Column where the axis crosses the principal point's row.
    pub column: f64,
    /// Its angle from the image's vertical, clockwise (top toward the right), degrees.
    pub tilt_deg: f64,
}

/// The silhouette on one side: mean limb column over the rows measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SilhouetteEdge {
    pub side: Side,
    /// Mean sensor row of the measurements.
    pub row: f64,
    pub measured_column: f64,
    pub model_column: f64,
}

/// How well the model fits: root-mean-square residual per kind of observation (limb
/// and terminator in sensor pixels, specular peak in degrees of α), how many there are,
/// and χ² per degree of freedom of the whole fit (near 1 when the model fits to the
/// observations' uncertainties; much larger means it does not).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Residuals {
    pub limb_px: Option<f64>,
    pub terminator_px: Option<f64>,
    pub peak_deg: Option<f64>,
    pub limbs: usize,
    pub terminator_rows: usize,
    pub peak_rows: usize,
    pub chi2_per_dof: f64,
}

/// The result of [`calibrate_scan`]; the `Option`s are `None` when not estimated (see
/// `notes`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Calibration {
    /// The prior with the estimated fields replaced, and in its `uncertainty` block each
    /// estimate's standard uncertainty (the prior's block for the rest).
    #[serde(skip)]
    pub setup: Setup,
    pub theta_l: Vec<f64>,
    pub sample_row: Estimate,
    pub white_row: Estimate,
    pub camera_offset_mm: Option<Estimate>,
    pub camera_distance_mm: Option<Estimate>,
    pub cylinder_tilt_deg: Option<Estimate>,
    pub arm_zero_offset_deg: Option<Estimate>,
    /// The camera's yaw and roll, estimated from the images and their stated values.
    pub camera_yaw_deg: Option<Estimate>,
    pub camera_roll_deg: Option<Estimate>,
    pub axis_in_image: AxisInImage,
    pub silhouette: Vec<SilhouetteEdge>,
    pub residuals: Residuals,
    /// What could not be estimated, and why.
    pub notes: Vec<String>,
}

impl Calibration {
    /// The calibrated setup as setup.json: its fields, plus this calibration under
    /// `calibration` (which reading a [`Setup`] ignores).
    pub fn setup_json(&self) -> serde_json::Value {
        let mut value = serde_json::to_value(&self.setup).unwrap_or_default();
        if let (Some(map), Ok(calibration)) = (value.as_object_mut(), serde_json::to_value(self)) {
            map.insert("calibration".to_owned(), calibration);
        }
        value
    }
}

/// What one θL's captures showed.
struct Measured {
    /// Sensor rows of the strips' centres.
    sample_centre: f64,
    white_centre: f64,
    /// (side, sensor row, sensor column) of limb steps.
    limbs: Vec<(Side, f64, f64)>,
    terminators: Vec<TerminatorRow>,
    peaks: Vec<PeakRow>,
}

/// The sample and white bands among `bands`: the two nearest the prior's strip rows.
fn strips(bands: &[Band], prior: &Setup, scale: usize) -> Option<(Band, Band)> {
    let nearest = |row: u32| {
        bands.iter().copied().min_by(|a, b| {
            let d = |band: &Band| (observe::sensor(band.centre(), scale) - f64::from(row)).abs();
            d(a).total_cmp(&d(b))
        })
    };
    let (sample, white) = (nearest(prior.sample_row)?, nearest(prior.white_row)?);
    (sample != white).then_some((sample, white))
}

/// Merges and measures the captures of one θL.
fn measure(
    theta_l: f64,
    paths: &[std::path::PathBuf],
    prior: &Setup,
    options: &CalibrateOptions,
) -> Result<Measured, CalibrateError> {
    let frames = paths
        .par_iter()
        .map(|p| Frame::read(p))
        .collect::<Result<Vec<_>, _>>()
        .map_err(ExtractError::from)?;
    let scale = extract::capture_scale(prior, frames[0].width, frames[0].height, theta_l)?;
    let map = hdr::merge(&frames, &options.merge)
        .map_err(|source| CalibrateError::Hdr { theta_l, source })?;
    drop(frames);
    let bands = observe::lit_bands(&map, extract::STRIP_ROWS);
    let (sample, white) = strips(&bands, prior, scale).ok_or(CalibrateError::Strips {
        theta_l,
        found: bands.len(),
    })?;
    let at = |i: f64| observe::sensor(i, scale);
    let white_rows = white.core_rows(options.rows_per_strip);
    // A white clipped in every frame has no edge to find: its limbs would be the
    // clipping's, not the cylinder's.
    let (mut lit, mut clipped) = (0usize, 0usize);
    for &y in &white_rows {
        for x in 0..map.width {
            let flags = map.flags(x, y);
            lit += usize::from(flags & UNDEREXPOSED == 0);
            clipped += usize::from(flags & SATURATED != 0);
        }
    }
    if lit > 0 && clipped as f64 > MAX_SATURATED_SHARE * lit as f64 {
        return Err(CalibrateError::Saturated {
            theta_l,
            percent: 100.0 * clipped as f64 / lit as f64,
        });
    }
    let mut measured = Measured {
        sample_centre: at(sample.centre()),
        white_centre: at(white.centre()),
        limbs: Vec::new(),
        terminators: Vec::new(),
        peaks: Vec::new(),
    };
    for &y in &white_rows {
        let profile = observe::row_profile(&map, y);
        for side in [Side::Left, Side::Right] {
            if let Some(u) = observe::limb(&profile, side) {
                measured.limbs.push((side, at(y as f64), at(u)));
            }
            let ramp = observe::terminator_ramp(&profile, side);
            if !ramp.is_empty() {
                measured.terminators.push(TerminatorRow {
                    theta_l,
                    v: at(y as f64),
                    points: ramp.iter().map(|&(u, w)| (at(u as f64), w)).collect(),
                    sigma: f64::NAN,
                });
            }
        }
    }
    // The white under every sample row: the mean of the whole white core, so that its
    // noise, common to all the peak rows of this θL, stays small.
    let white_profile = observe::white_profile(&map, &white.core_rows(usize::MAX));
    for y in sample.core_rows(options.rows_per_strip) {
        let peak = observe::specular_peak(&map, y, &white_profile);
        if !peak.is_empty() {
            measured.peaks.push(PeakRow {
                theta_l,
                v: at(y as f64),
                points: peak.iter().map(|&(u, b)| (at(u as f64), b)).collect(),
                sigma: f64::NAN,
            });
        }
    }
    Ok(measured)
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

/// A strip's centre row over all θL: the median, with the spread's standard error or
/// the quantisation of a centre between two pixel edges, whichever is larger.
fn row_estimate(centres: Vec<f64>, scale: f64) -> Estimate {
    let n = centres.len() as f64;
    let mean = centres.iter().sum::<f64>() / n;
    let spread = (centres.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / n).sqrt();
    Estimate {
        value: median(centres),
        stderr: (spread / n.sqrt()).max(scale / 12f64.sqrt() / 2f64.sqrt()),
    }
}

/// Sets the uncertainty of every terminator and peak row from its regression at
/// `setup`, dropping the rows the model cannot evaluate there. A row's uncertainty is
/// at least the median of its kind's: a regression on a few points can come out
/// lucky, and would then outweigh all the others.
fn set_uncertainties(obs: &mut Observations, setup: &Setup) {
    regression_uncertainties(
        &mut obs.terminators,
        1e-3,
        |row| solve::terminator_offset(setup, row),
        |row| &mut row.sigma,
    );
    regression_uncertainties(
        &mut obs.peaks,
        1e-7,
        |row| solve::peak_vertex(setup, row),
        |row| &mut row.sigma,
    );
}

/// Sets each row's uncertainty (`sigma`) to its regression's (`regress`: the residual
/// and its uncertainty), at least `least` and at least the median of them; drops the
/// rows whose regression fails.
fn regression_uncertainties<R>(
    rows: &mut Vec<R>,
    least: f64,
    regress: impl Fn(&R) -> Option<(f64, f64)>,
    sigma: fn(&mut R) -> &mut f64,
) {
    rows.retain_mut(|row| match regress(row) {
        Some((_, s)) if s.is_finite() => {
            *sigma(row) = s.max(least);
            true
        }
        _ => false,
    });
    let floor = median(rows.iter_mut().map(|row| *sigma(row)).collect());
    for row in rows.iter_mut() {
        let s = sigma(row);
        *s = s.max(floor);
    }
}

/// Image position (sensor pixels) of a point given in the setup's frame.
fn project(setup: &Setup, point: [f64; 3]) -> (f64, f64) {
    let depth = setup.camera_distance_mm - point[0];
    let k = setup.focal_length_mm / depth / (setup.pixel_pitch_um * 1e-3);
    (
        setup.principal_point() + k * (point[1] - setup.camera_offset_mm),
        setup.principal_row() - k * point[2],
    )
}

fn axis_in_image(setup: &Setup) -> AxisInImage {
    let tilt = setup.cylinder_tilt_deg.to_radians();
    let along = |h: f64| project(setup, [0.0, h * tilt.sin(), h * tilt.cos()]);
    let (top, bottom) = (along(50.0), along(-50.0));
    AxisInImage {
        column: along(0.0).0,
        tilt_deg: (top.0 - bottom.0).atan2(bottom.1 - top.1).to_degrees(),
    }
}

fn rms(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    (n > 0).then(|| (sum / n as f64).sqrt())
}

/// Calibrates the setup of the scan in `dir` (captures with sidecars, grouped by θL)
/// starting from `prior`.
pub fn calibrate_scan(
    dir: &Path,
    prior: &Setup,
    options: &CalibrateOptions,
) -> Result<Calibration, CalibrateError> {
    prior.validate().map_err(CalibrateError::Prior)?;
    let (groups, _) = extract::theta_groups(dir)?;
    let scale = {
        let frame = Frame::read(&groups[0].1[0]).map_err(ExtractError::from)?;
        extract::capture_scale(prior, frame.width, frame.height, groups[0].0)?
    };
    let mut measured = Vec::with_capacity(groups.len());
    for (theta_l, paths) in &groups {
        measured.push(measure(*theta_l, paths, prior, options)?);
    }
    let mut notes = Vec::new();
    let sample_row = row_estimate(
        measured.iter().map(|m| m.sample_centre).collect(),
        scale as f64,
    );
    let white_row = row_estimate(
        measured.iter().map(|m| m.white_centre).collect(),
        scale as f64,
    );
    let mut start = prior.clone();
    start.sample_row = sample_row.value.round().max(0.0) as u32;
    start.white_row = white_row.value.round().max(0.0) as u32;

    // Limbs: the same pixels at every θL, so one column per row (the median over θL)
    // and one observation per side.
    let mut obs = Observations::default();
    for side in [Side::Left, Side::Right] {
        let mut by_row: BTreeMap<i64, (f64, Vec<f64>)> = BTreeMap::new();
        for m in &measured {
            for &(s, v, u) in &m.limbs {
                if s == side {
                    by_row
                        .entry(v.round() as i64)
                        .or_insert((v, Vec::new()))
                        .1
                        .push(u);
                }
            }
        }
        if by_row.len() >= 3 {
            obs.limbs.push(Limb {
                side,
                points: by_row
                    .into_values()
                    .map(|(v, us)| (v, median(us)))
                    .collect(),
                sigma: scale as f64 / 12f64.sqrt(),
            });
        }
    }
    for m in measured.iter_mut() {
        obs.terminators.append(&mut m.terminators);
        obs.peaks.append(&mut m.peaks);
    }
    set_uncertainties(&mut obs, &start);

    let mut parameters = Vec::new();
    if obs.limbs.is_empty() {
        notes.push("no lit limb in the white strip: the camera offset is the prior's".to_owned());
    } else {
        parameters.push(Parameter::CameraOffset);
    }
    if obs.limbs.len() == 2 {
        parameters.push(Parameter::CameraDistance);
    } else {
        notes.push(
            "one limb only (light on one side in every capture): the camera distance is the prior's"
                .to_owned(),
        );
    }
    if obs.terminators.is_empty() && obs.peaks.is_empty() {
        notes.push(
            "no terminator ramp and no specular peak: the arm zero offset and cylinder tilt are the prior's"
                .to_owned(),
        );
    } else {
        parameters.push(Parameter::ArmZeroOffset);
        parameters.push(Parameter::CylinderTilt);
    }
    if obs.peaks.is_empty() {
        notes.push("no specular peak found in the sample strip".to_owned());
    }
    if parameters.is_empty() {
        return Err(CalibrateError::Underdetermined(notes.join("; ")));
    }
    // The camera's turn: its yaw moves the picture as its offset does, its roll slants
    // the limbs as the cylinder's tilt does; each is estimated with what setup.json
    // states of it as a prior, so the images refine it as far as they tell it apart.
    if !obs.limbs.is_empty() {
        for (parameter, value, source) in [
            (
                Parameter::CameraYaw,
                prior.camera_yaw_deg,
                Source::CameraYaw,
            ),
            (
                Parameter::CameraRoll,
                prior.camera_roll_deg,
                Source::CameraRoll,
            ),
        ] {
            let sigma = prior
                .inputs()
                .iter()
                .find(|i| i.source == source)
                .map_or(0.0, |i| i.u[0]);
            if sigma > 0.0 {
                parameters.push(parameter);
                obs.priors.push(Prior {
                    parameter,
                    value,
                    sigma,
                });
            }
        }
    }
    let first = solve::fit(&start, &obs, &parameters)
        .ok_or_else(|| CalibrateError::Underdetermined("the least-squares fit failed".into()))?;
    // Uncertainties of the regressions at the fitted geometry, without the rows that
    // disagree with it by more than 5 of them, then refit.
    set_uncertainties(&mut obs, &first.setup);
    let outliers = solve::drop_outliers(&first.setup, &mut obs, 5.0);
    if outliers > 0 {
        notes.push(format!(
            "{outliers} terminator or peak row(s) left out: more than 5 standard uncertainties off"
        ));
    }
    let solution = solve::fit(&first.setup, &obs, &parameters)
        .ok_or_else(|| CalibrateError::Underdetermined("the least-squares fit failed".into()))?;
    let mut setup = solution.setup.clone();
    let estimate = |p: Parameter, value: f64| {
        parameters.iter().position(|&q| q == p).map(|k| Estimate {
            value,
            stderr: solution.covariance[(k, k)].max(0.0).sqrt(),
        })
    };
    let camera_offset_mm = estimate(Parameter::CameraOffset, setup.camera_offset_mm);
    let camera_distance_mm = estimate(Parameter::CameraDistance, setup.camera_distance_mm);
    let cylinder_tilt_deg = estimate(Parameter::CylinderTilt, setup.cylinder_tilt_deg);
    let arm_zero_offset_deg = estimate(Parameter::ArmZeroOffset, setup.arm_zero_offset_deg);
    let camera_yaw_deg = estimate(Parameter::CameraYaw, setup.camera_yaw_deg);
    let camera_roll_deg = estimate(Parameter::CameraRoll, setup.camera_roll_deg);
    for p in &obs.priors {
        let (name, estimate) = match p.parameter {
            Parameter::CameraYaw => ("camera yaw", camera_yaw_deg),
            _ => ("camera roll", camera_roll_deg),
        };
        let Some(estimate) = estimate else { continue };
        let prior = p.sigma;
        if estimate.stderr > 0.9 * prior {
            notes.push(format!(
                "{name}: the images tell little beyond its stated uncertainty ({:.3}° against {prior}°)",
                estimate.stderr
            ));
        }
    }
    setup.uncertainty = SetupUncertainty {
        camera_offset_mm: standard_uncertainty(
            camera_offset_mm,
            prior.uncertainty.camera_offset_mm,
        ),
        camera_distance_mm: standard_uncertainty(
            camera_distance_mm,
            prior.uncertainty.camera_distance_mm,
        ),
        cylinder_tilt_deg: standard_uncertainty(
            cylinder_tilt_deg,
            prior.uncertainty.cylinder_tilt_deg,
        ),
        arm_zero_offset_deg: standard_uncertainty(
            arm_zero_offset_deg,
            prior.uncertainty.arm_zero_offset_deg,
        ),
        camera_yaw_deg: standard_uncertainty(camera_yaw_deg, prior.uncertainty.camera_yaw_deg),
        camera_roll_deg: standard_uncertainty(camera_roll_deg, prior.uncertainty.camera_roll_deg),
        ..prior.uncertainty
    };

    let n_limbs = obs.limbs.len();
    let n_term = obs.terminators.len();
    let r = &solution.residuals;
    let silhouette = obs
        .limbs
        .iter()
        .map(|limb| {
            let n = limb.points.len() as f64;
            let row = limb.points.iter().map(|p| p.0).sum::<f64>() / n;
            let measured_column = limb.points.iter().map(|p| p.1).sum::<f64>() / n;
            let model_column = limb
                .points
                .iter()
                .map(|&(v, _)| solve::limb_column(&setup, v, limb.side))
                .sum::<f64>()
                / n;
            SilhouetteEdge {
                side: limb.side,
                row,
                measured_column,
                model_column,
            }
        })
        .collect();
    let residuals = Residuals {
        // Two residuals per limb: its mean, then its slope.
        limb_px: rms(obs
            .limbs
            .iter()
            .zip(r.iter().step_by(2))
            .map(|(l, r)| r * l.sigma)),
        terminator_px: rms(obs
            .terminators
            .iter()
            .zip(&r[2 * n_limbs..])
            .map(|(t, r)| r * t.sigma)),
        peak_deg: rms(obs
            .peaks
            .iter()
            .zip(&r[2 * n_limbs + n_term..])
            .map(|(p, r)| (r * p.sigma).atan().to_degrees())),
        limbs: n_limbs,
        terminator_rows: n_term,
        peak_rows: obs.peaks.len(),
        chi2_per_dof: solution.chi2_per_dof,
    };
    Ok(Calibration {
        theta_l: groups.iter().map(|g| g.0).collect(),
        sample_row,
        white_row,
        camera_offset_mm,
        camera_distance_mm,
        cylinder_tilt_deg,
        arm_zero_offset_deg,
        camera_yaw_deg,
        camera_roll_deg,
        axis_in_image: axis_in_image(&setup),
        silhouette,
        residuals,
        notes,
        setup,
    })
}

/// The standard uncertainty the calibrated setup.json states for a field: its estimate's
/// (when estimated, and a valid standard uncertainty), else the prior's, if any.
fn standard_uncertainty(estimate: Option<Estimate>, prior: Option<f64>) -> Option<f64> {
    estimate
        .map(|e| e.stderr)
        .filter(|u| u.is_finite() && (0.0..=MAX_UNCERTAINTY).contains(u))
        .or(prior)
}
