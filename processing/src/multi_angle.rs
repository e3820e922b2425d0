//! Colour as the coatings trade states it: CIELAB at the standard aspecular angles of
//! 45° illumination (`color::geometry`), from a fit and, inside the measured (θh, θd)
//! range, from the measured table, each coordinate with its uncertainty
//! (docs/ARCHITECTURE.md, "Multi-angle colour").
//!
//! Each value carries its **lines**: the signed change of its L*a*b* for one standard
//! uncertainty of one source, named so that the same source in another scan (or at
//! another angle) can be matched: `shared` lines are systematics of the instrument's
//! setup (the white's reflectance, the geometry, the colour transform), common to every
//! scan made with it; the others (noise, misfit, the arm's repeatability) are
//! independent from scan to scan. A coordinate's standard uncertainty is the root sum of
//! squares of its lines, U = k·u with k = 2.
//! - From the **model**: each line of the fit's budget (per source and parameter, the
//!   parameter moved by its contribution) propagated through the model's β at the
//!   geometry; a fit without a budget has its standard uncertainties as noise lines.
//! - From the **data** (the table in (θh, θd)): the signed changes of β the samples state
//!   per source (`u_<source>_*`) and their noise, taken from the sample nearest in θh in
//!   each of the two columns whose θd bracket the geometry's, weighted as the table
//!   interpolates between them.
//! - The **transform** (camera RGB → XYZ): one line per principal axis of its relative
//!   covariance, √λ·Y·e in XYZ.
#![doc = include_str!("multi_angle.md")]

pub mod compare;
mod extrapolation;

pub use extrapolation::FRESNEL_RISE;

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::color::delta_e::flop_index;
use crate::color::geometry::{half_difference, incidence_and_view};
use crate::color::lab::{chroma, hue_deg, lab_from_xyz};
use crate::color::observer::Conditions;
use crate::color::transform::{ColourTransform, TransformError};
use crate::fit::table::{Table, TableError};
use crate::fit::{FitResult, FittedRoughness};
use crate::samples::{Sample, THETA_L_TOLERANCE};
use crate::setup_uncertainty::Source;

/// k of U = k·u.
pub const COVERAGE_FACTOR: f64 = 2.0;

/// How far (degrees of θd) beyond the measured columns' mean θd a geometry still counts
/// as measured: a column's θd varies by about this much along it (parallax).
pub const THETA_D_MARGIN_DEG: f64 = 0.5;

/// Source name of the model's misfit carried to a geometry from the measured columns
/// (`multi_angle::extrapolation`): the sample's and the model's, alike for alike samples
/// whatever their mounting.
pub const EXTRAPOLATION: &str = "extrapolation";

/// Why colour could not be computed.
#[derive(Debug, Error)]
pub enum MultiAngleError {
    #[error("no aspecular angle given")]
    NoAngles,
    #[error("the colour at aspecular {aspecular}° is not finite")]
    NotFinite { aspecular: f64 },
}

/// Where a value comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Origin {
    /// The measured table: the geometry lies inside the measured (θh, θd) range.
    Data,
    /// The fitted model: outside the measured range, or no samples were given.
    Model,
}

/// One line: the signed change of L*a*b* for one standard uncertainty of `source`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Line {
    /// The source, with what it moved (`camera_offset:ks_g`, `noise:r`, `transform:1`).
    pub source: String,
    /// A systematic of the setup, common to scans made with it.
    pub shared: bool,
    /// ΔL*, Δa*, Δb*.
    pub lab: [f64; 3],
}

/// A coordinate with its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Coordinate {
    pub value: f64,
    /// Standard uncertainty of the lines independent from scan to scan.
    pub u_independent: f64,
    /// Standard uncertainty of the setup's shared systematics.
    pub u_shared: f64,
    /// Expanded uncertainty U = k·√(u_independent² + u_shared²).
    pub expanded: f64,
}

impl Coordinate {
    fn new(value: f64, lines: &[Line], project: impl Fn(&[f64; 3]) -> f64) -> Self {
        let (mut independent, mut shared) = (0.0, 0.0);
        for line in lines {
            let d = project(&line.lab).powi(2);
            if line.shared {
                shared += d;
            } else {
                independent += d;
            }
        }
        Coordinate {
            value,
            u_independent: independent.sqrt(),
            u_shared: shared.sqrt(),
            expanded: COVERAGE_FACTOR * (independent + shared).sqrt(),
        }
    }
}

/// The colour at one geometry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AngleColour {
    /// Aspecular angle, degrees (positive towards the illumination).
    pub aspecular: f64,
    /// In-plane incidence and view (gonio's signed angles) and the table's (θh, θd).
    pub theta_i: f64,
    pub theta_r: f64,
    pub theta_h: f64,
    pub theta_d: f64,
    pub origin: Origin,
    /// A model value brighter than the measured columns support at its geometry for any
    /// lobe of the microfacet form (`multi_angle::extrapolation::luminance_bound`): the
    /// model's guess, not a reading.
    #[serde(default)]
    pub beyond_data: bool,
    /// Camera RGB β (white G = 100) and XYZ (white Y = 100).
    pub beta: [f64; 3],
    pub xyz: [f64; 3],
    #[serde(rename = "L")]
    pub l: Coordinate,
    pub a: Coordinate,
    pub b: Coordinate,
    #[serde(rename = "C")]
    pub c: Coordinate,
    /// Hue angle h_ab, degrees.
    pub h: Coordinate,
    pub lines: Vec<Line>,
}

impl AngleColour {
    /// L*, a*, b*.
    pub fn lab(&self) -> [f64; 3] {
        [self.l.value, self.a.value, self.b.value]
    }
}

/// colour.json: the colour of a sample at every geometry asked for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ColourReport {
    /// Illuminant and observer.
    pub conditions: Conditions,
    pub coverage_factor: f64,
    /// The fit's model (`table` when it predicts with one).
    pub model: String,
    /// θd (degrees) of the measured columns, lowest and highest; `null` without data.
    pub measured_theta_d: Option<[f64; 2]>,
    /// The camera RGB → XYZ transform's own error.
    pub transform: TransformError,
    pub angles: Vec<AngleColour>,
    /// The flop index from L* at 15°, 45° and 110°, when all three were asked for.
    pub flop_index: Option<Coordinate>,
    /// What the values rest on (a fit without a budget, samples without uncertainty).
    pub notes: Vec<String>,
}

/// The measured data a colour may come from: the table and the samples it was made of.
pub struct Measured<'a> {
    pub table: Table,
    pub samples: &'a [Sample],
}

impl<'a> Measured<'a> {
    /// `samples` as `fit` reads them: through the fit's own table when it predicts with
    /// one, else through the samples' table.
    pub fn of(fit: &FitResult, samples: &'a [Sample]) -> Result<Self, TableError> {
        let table = match &fit.table {
            Some(table) => table.clone(),
            None => Table::new(samples, 0.0)?,
        };
        Ok(Measured { table, samples })
    }
}

/// The colour of `fit` (and inside the measured range of `measured`) at each aspecular
/// angle of `aspecular`, under `transform`'s conditions.
pub fn colour(
    fit: &FitResult,
    measured: Option<&Measured>,
    transform: &ColourTransform,
    aspecular: &[f64],
) -> Result<ColourReport, MultiAngleError> {
    if aspecular.is_empty() {
        return Err(MultiAngleError::NoAngles);
    }
    let mut notes = Vec::new();
    let model_lines = parameter_lines(fit, &mut notes);
    let mut parametric = fit.clone();
    parametric.table = None;
    // The light on the side of the normal the scan's light was on.
    let side = measured.map_or(1.0, |m| {
        let negative = m.samples.iter().filter(|s| s.theta_l < 0.0).count();
        if 2 * negative > m.samples.len() {
            -1.0
        } else {
            1.0
        }
    });
    if let Some(m) = measured {
        if m.samples.iter().any(|s| s.uncertainty.is_none()) {
            notes.push("the samples carry no uncertainty columns: the data's values have no noise or setup lines".into());
        }
    }
    let measured_theta_d = measured.map(|m| {
        let cols = m.table.columns();
        [cols[0].theta_d, cols[cols.len() - 1].theta_d]
    });
    let mut angles = Vec::with_capacity(aspecular.len());
    for &angle in aspecular {
        let (theta_i, theta_r) = incidence_and_view(angle, side);
        let (theta_h, theta_d) = half_difference(angle, side);
        let data = measured.and_then(|m| data_value(m, theta_h, theta_d, &format!("{angle}")));
        let y_row = transform.matrix()[1];
        let (origin, beta, beta_lines, bound) = match data {
            Some((beta, lines)) => (Origin::Data, beta, lines, None),
            None => {
                let beta = parametric.predict(theta_i, theta_r);
                let mut lines: Vec<BetaLine> = model_lines
                    .iter()
                    .map(|(source, moved)| {
                        let b = moved.predict(theta_i, theta_r);
                        (source.clone(), std::array::from_fn(|c| b[c] - beta[c]))
                    })
                    .collect();
                let misfit = measured
                    .and_then(|m| extrapolation::drift_lines(&m.table, beta, theta_h, theta_d));
                for (c, change) in misfit.into_iter().flatten().enumerate() {
                    let mut d = [0.0; 3];
                    d[c] = change;
                    lines.push(((format!("{EXTRAPOLATION}:{c}"), true), d));
                }
                let bound = measured.and_then(|m| {
                    extrapolation::luminance_bound(&m.table, y_row, theta_h, theta_d)
                });
                (Origin::Model, beta, lines, bound)
            }
        };
        let xyz = transform.xyz(beta);
        let beyond_data = bound.is_some_and(|b| xyz[1] > b);
        let white = transform.observer().white();
        let lab = lab_from_xyz(xyz, white);
        let jacobian = lab_jacobian(xyz, white);
        let m = Matrix3::from(transform.matrix()).transpose();
        let mut lines: Vec<Line> = beta_lines
            .into_iter()
            .map(|((source, shared), d)| {
                let d_xyz = m * Vector3::from(d);
                Line {
                    source,
                    shared,
                    lab: apply(&jacobian, [d_xyz[0], d_xyz[1], d_xyz[2]]),
                }
            })
            .collect();
        lines.extend(transform_lines(transform, beta, xyz));
        let c_value = chroma(lab);
        let hue_row = |d: &[f64; 3]| {
            if c_value > 1e-9 {
                (lab[1] * d[2] - lab[2] * d[1]) / (c_value * c_value) * 180.0 / std::f64::consts::PI
            } else {
                180.0
            }
        };
        let colour = AngleColour {
            aspecular: angle,
            theta_i,
            theta_r,
            theta_h,
            theta_d,
            origin,
            beyond_data,
            beta,
            xyz,
            l: Coordinate::new(lab[0], &lines, |d| d[0]),
            a: Coordinate::new(lab[1], &lines, |d| d[1]),
            b: Coordinate::new(lab[2], &lines, |d| d[2]),
            c: Coordinate::new(c_value, &lines, |d| {
                if c_value > 1e-9 {
                    (lab[1] * d[1] + lab[2] * d[2]) / c_value
                } else {
                    d[1].hypot(d[2])
                }
            }),
            h: Coordinate::new(hue_deg(lab), &lines, hue_row),
            lines,
        };
        let finite = [colour.l, colour.a, colour.b, colour.c, colour.h]
            .iter()
            .all(|c| c.value.is_finite() && c.expanded.is_finite());
        if !finite {
            return Err(MultiAngleError::NotFinite { aspecular: angle });
        }
        angles.push(colour);
    }
    if angles.iter().any(|a| a.beyond_data) {
        notes.push(format!(
            "beyond_data: a model value brighter than the measured columns support at its \
             geometry, {FRESNEL_RISE}·max over columns of Y(θh)·cos θi·cos θr there over the \
             geometry's cos θi·cos θr, is the model's guess, not a reading"
        ));
    }
    let flop = flop_of(&angles);
    Ok(ColourReport {
        conditions: transform.observer().conditions(),
        coverage_factor: COVERAGE_FACTOR,
        model: if fit.table.is_some() {
            "table".into()
        } else {
            fit.model.name().into()
        },
        measured_theta_d,
        transform: transform.error().clone(),
        angles,
        flop_index: flop,
        notes,
    })
}

/// The colour transform's own error at camera RGB `beta` (XYZ `xyz`) as lines of
/// L*a*b*: one per principal axis of its covariance, √λ·e in XYZ.
pub fn transform_lines(transform: &ColourTransform, beta: [f64; 3], xyz: [f64; 3]) -> Vec<Line> {
    let jacobian = lab_jacobian(xyz, transform.observer().white());
    let covariance = Matrix3::from(transform.xyz_covariance(beta, xyz)).transpose();
    let eigen = SymmetricEigen::new(covariance);
    (0..3)
        .map(|k| {
            let size = eigen.eigenvalues[k].max(0.0).sqrt();
            let axis = eigen.eigenvectors.column(k) * size;
            Line {
                source: format!("transform:{k}"),
                shared: true,
                lab: apply(&jacobian, [axis[0], axis[1], axis[2]]),
            }
        })
        .collect()
}

/// The flop index of `angles` with its uncertainty (lines matched by name across the
/// three angles), when 15°, 45° and 110° are among them.
pub fn flop_of(angles: &[AngleColour]) -> Option<Coordinate> {
    let find = |a: f64| angles.iter().find(|c| (c.aspecular - a).abs() < 1e-9);
    let (a15, a45, a110) = (find(15.0)?, find(45.0)?, find(110.0)?);
    let value = flop_index(a15.l.value, a45.l.value, a110.l.value)?;
    let lines = merged_l_lines(&[a15, a45, a110]);
    let (mut independent, mut shared) = (0.0, 0.0);
    for (shared_line, d) in lines {
        let moved = flop_index(a15.l.value + d[0], a45.l.value + d[1], a110.l.value + d[2])?;
        let back = flop_index(a15.l.value - d[0], a45.l.value - d[1], a110.l.value - d[2])?;
        let change = ((moved - back) / 2.0).powi(2);
        if shared_line {
            shared += change;
        } else {
            independent += change;
        }
    }
    Some(Coordinate {
        value,
        u_independent: independent.sqrt(),
        u_shared: shared.sqrt(),
        expanded: COVERAGE_FACTOR * (independent + shared).sqrt(),
    })
}

/// The L* lines of `angles`, merged by name: per line, its ΔL* at each angle (0 where an
/// angle has no line of that name).
fn merged_l_lines(angles: &[&AngleColour]) -> Vec<(bool, [f64; 3])> {
    let mut merged: Vec<(String, bool, [f64; 3])> = Vec::new();
    for (k, angle) in angles.iter().enumerate() {
        for line in &angle.lines {
            match merged
                .iter_mut()
                .find(|(s, sh, _)| *s == line.source && *sh == line.shared)
            {
                Some((_, _, d)) => d[k] += line.lab[0],
                None => {
                    let mut d = [0.0; 3];
                    d[k] = line.lab[0];
                    merged.push((line.source.clone(), line.shared, d));
                }
            }
        }
    }
    merged.into_iter().map(|(_, s, d)| (s, d)).collect()
}

/// ∂(L*, a*, b*)/∂(X, Y, Z) at `xyz` (central differences), row-major.
fn lab_jacobian(xyz: [f64; 3], white: [f64; 3]) -> [[f64; 3]; 3] {
    let mut j = [[0.0; 3]; 3];
    for c in 0..3 {
        let h = 1e-6 * (xyz[c].abs() + 1.0);
        let (mut up, mut down) = (xyz, xyz);
        up[c] += h;
        down[c] -= h;
        let (a, b) = (lab_from_xyz(up, white), lab_from_xyz(down, white));
        for (row, (x, y)) in j.iter_mut().zip(a.iter().zip(&b)) {
            row[c] = (x - y) / (2.0 * h);
        }
    }
    j
}

fn apply(j: &[[f64; 3]; 3], d: [f64; 3]) -> [f64; 3] {
    j.map(|row| row[0] * d[0] + row[1] * d[1] + row[2] * d[2])
}

/// A named β line: (name, shared) and the change of β.
type BetaLine = ((String, bool), [f64; 3]);

/// The fit moved by each line of its budget (per source and parameter), or by its
/// standard uncertainties as noise lines when it has no budget.
fn parameter_lines(fit: &FitResult, notes: &mut Vec<String>) -> Vec<((String, bool), FitResult)> {
    let mut base = fit.clone();
    base.table = None;
    let names = parameter_names(fit);
    let mut out = Vec::new();
    if let Some(budget) = &fit.budget {
        for (i, (name, parameter)) in budget.named().into_iter().enumerate() {
            for line in &parameter.contributions {
                if line.u > 0.0 && line.u.is_finite() {
                    let shared = !matches!(line.source.as_str(), "noise" | "misfit" | "arm_angle");
                    out.push((
                        (format!("{}:{name}", line.source), shared),
                        moved(&base, i, line.u),
                    ));
                }
            }
        }
    } else if let Some(stderr) = &fit.stderr {
        notes.push("the fit has no uncertainty budget: the model's values carry its standard uncertainties (noise and misfit) alone".into());
        for (i, (u, name)) in stderr.flat().into_iter().zip(&names).enumerate() {
            if *u > 0.0 && u.is_finite() {
                out.push(((format!("noise:{name}"), false), moved(&base, i, *u)));
            }
        }
    } else {
        notes.push(
            "the fit states no uncertainty: the model's values carry the transform's alone".into(),
        );
    }
    out
}

/// Names of the fit's parameters in [`crate::fit::ParameterSet::flat`]'s order.
fn parameter_names(fit: &FitResult) -> Vec<String> {
    let mut names = Vec::new();
    let groups: &[&str] = if fit.ks_90.is_some() {
        &["kd", "ks", "ks_90"]
    } else {
        &["kd", "ks"]
    };
    for g in groups {
        for c in ["r", "g", "b"] {
            names.push(format!("{g}_{c}"));
        }
    }
    match fit.m {
        FittedRoughness::Shared(_) => names.push("m".into()),
        FittedRoughness::PerChannel(_) => names.extend(["m_r", "m_g", "m_b"].map(String::from)),
    }
    names
}

/// `fit` with its parameter `index` (flat order) moved by `delta`.
fn moved(fit: &FitResult, index: usize, delta: f64) -> FitResult {
    let mut out = fit.clone();
    let colours = if fit.ks_90.is_some() { 9 } else { 6 };
    match index {
        0..=2 => out.kd[index] += delta,
        3..=5 => out.ks[index - 3] += delta,
        i if i < colours => {
            if let Some(k) = out.ks_90.as_mut() {
                k[i - 6] += delta;
            }
        }
        i => match &mut out.m {
            FittedRoughness::Shared(m) => m[0] += delta,
            FittedRoughness::PerChannel(m) => m[(i - colours).min(2)] += delta,
        },
    }
    out
}

/// β of the measured table at (θh, θd) with its lines, when the geometry lies inside the
/// measured range: θd within the columns' (± [`THETA_D_MARGIN_DEG`]) and θh within the
/// points of the columns it is read from.
fn data_value(
    measured: &Measured,
    theta_h: f64,
    theta_d: f64,
    angle: &str,
) -> Option<([f64; 3], Vec<BetaLine>)> {
    let columns = measured.table.columns();
    let (first, last) = (columns[0].theta_d, columns[columns.len() - 1].theta_d);
    if theta_d < first - THETA_D_MARGIN_DEG || theta_d > last + THETA_D_MARGIN_DEG {
        return None;
    }
    let k = columns.partition_point(|c| c.theta_d <= theta_d);
    let (lo, hi) = (k.saturating_sub(1), k.min(columns.len() - 1));
    let weight = if hi > lo {
        ((theta_d - columns[lo].theta_d) / (columns[hi].theta_d - columns[lo].theta_d))
            .clamp(0.0, 1.0)
    } else {
        0.0
    };
    let reads: Vec<(usize, f64)> = if hi > lo {
        vec![(lo, 1.0 - weight), (hi, weight)]
    } else {
        vec![(lo, 1.0)]
    };
    let mut shared = [[0.0; 3]; Source::COUNT];
    let mut independent: Vec<BetaLine> = Vec::new();
    for &(col, w) in &reads {
        let column = &columns[col];
        let (h_lo, h_hi) = (
            column.points[0][0],
            column.points[column.points.len() - 1][0],
        );
        if theta_h < h_lo || theta_h > h_hi {
            return None;
        }
        let nearest = measured
            .samples
            .iter()
            .filter(|s| (s.theta_l - column.theta_l).abs() <= THETA_L_TOLERANCE)
            .min_by(|a, b| {
                let d = |s: &Sample| (s.half_difference().0.to_degrees() - theta_h).abs();
                d(a).total_cmp(&d(b))
            })?;
        if let Some(u) = &nearest.uncertainty {
            for (j, source) in Source::ALL.iter().enumerate() {
                if *source == Source::ArmAngle {
                    for c in 0..3 {
                        let mut d = [0.0; 3];
                        d[c] = w * u.sources[j][c];
                        independent.push((
                            (format!("arm_angle@{angle}:{}:{c}", column.theta_l), false),
                            d,
                        ));
                    }
                } else {
                    for (total, change) in shared[j].iter_mut().zip(u.sources[j]) {
                        *total += w * change;
                    }
                }
            }
            for c in 0..3 {
                let mut d = [0.0; 3];
                d[c] = w * u.noise[c];
                independent.push(((format!("noise@{angle}:{}:{c}", column.theta_l), false), d));
            }
        }
    }
    // Linear in the measured β between the points around (θh, θd), as the lines above
    // are taken: no model's shape.
    let beta = measured.table.predict(theta_h, theta_d, None);
    let mut lines: Vec<BetaLine> = Source::ALL
        .iter()
        .zip(shared)
        .filter(|(s, _)| **s != Source::ArmAngle)
        .map(|(s, d)| ((s.name().to_string(), true), d))
        .collect();
    lines.extend(independent);
    Some((beta, lines))
}
