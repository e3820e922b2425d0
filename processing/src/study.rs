//! The θL-combination study (paper §2.3 and §3): fit every non-empty subset of the
//! illumination directions θL present in a samples set, evaluate each fit against a
//! reference interpolated at the setup angles, and summarise the errors as box plots
//! per number of θL used.
//!
//! Evaluation points are the (θi, θr) of every sample (all θL, whatever subset was
//! fitted), where the reference covers them; so every fit is scored on the same points.
//! Per fit: ΔErr_p per channel (eq. 11, reference as "measured") and the mean ΔE_u′v′
//! (eq. 13) through the camera's RGB → XYZ matrix, on all points and, separately, on the
//! held-out points only (those of the θL the combination did not fit: how well a model
//! predicts angles it did not see; the combination of every θL has none). Each
//! combination is also fitted by Nelder–Mead from its default start, to count how often
//! the paper's method ends at a higher loss than the robust fitter (a local minimum);
//! models that only the robust method fits are not compared.

pub mod boxplot;
pub mod combinations;
pub mod figures;
pub mod pareto;
mod plots;
mod tables;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use crate::brdf::{Model, Roughness};
use crate::color::CameraModel;
use crate::fit::{self, FitMethod, FitOptions, FitResult};
use crate::metrics::{self, MetricsError};
use crate::reference::Reference;
pub use crate::samples::distinct_theta_l;
use crate::samples::{Sample, THETA_L_TOLERANCE};
use boxplot::BoxStats;
use figures::FigureError;

pub use plots::write_figures;
pub use tables::write_tables;

/// Why a study could not be run or written.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error("the samples are empty")]
    NoSamples,
    #[error("sample {index}: {field} is not finite")]
    NonFinite { index: usize, field: &'static str },
    #[error("{count} distinct θL in the samples; a study enumerates at most {max}")]
    TooManyThetaL { count: usize, max: usize },
    #[error("the reference covers none of the {samples} sample angles (θi, θr)")]
    NoOverlap { samples: usize },
    #[error("no model variant to fit")]
    NoVariants,
    #[error("the column stride must be at least 1")]
    ZeroStride,
    #[error("reference at the sample angles: {0}")]
    Reference(MetricsError),
    #[error("cannot write {path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error(transparent)]
    Figure(#[from] FigureError),
}

impl From<MetricsError> for StudyError {
    fn from(error: MetricsError) -> Self {
        StudyError::Reference(error)
    }
}

/// A model with its roughness form: one fitted variant of a study.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Variant {
    pub model: Model,
    pub roughness: Roughness,
}

impl Variant {
    /// `cook-torrance` for shared roughness, `cook-torrance/per-channel` otherwise.
    pub fn label(&self) -> String {
        match self.roughness {
            Roughness::Shared => self.model.name().to_string(),
            Roughness::PerChannel => format!("{}/{}", self.model, self.roughness),
        }
    }
}

/// What a study fits.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyOptions {
    pub variants: Vec<Variant>,
    /// Also fit each combination with Nelder–Mead and compare its loss.
    pub compare_nelder_mead: bool,
    /// A Nelder–Mead fit counts as stuck in a local minimum when its loss exceeds the
    /// robust loss by more than this fraction.
    pub local_minimum_margin: f64,
    /// Fit on every `stride`-th sample of each θL (1 = all); scoring uses all points.
    pub stride: usize,
}

impl Default for StudyOptions {
    /// Every model with shared roughness, Nelder–Mead compared at 0.1 %, every sample
    /// fitted.
    fn default() -> Self {
        StudyOptions {
            variants: Model::ALL
                .into_iter()
                .map(|model| Variant {
                    model,
                    roughness: Roughness::Shared,
                })
                .collect(),
            compare_nelder_mead: true,
            local_minimum_margin: 1e-3,
            stride: 1,
        }
    }
}

/// A setup angle pair where fits are scored, with the reference there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalPoint {
    pub theta_l: f64,
    pub theta_i: f64,
    pub theta_r: f64,
    /// Reference β (camera RGB) interpolated at (θi, θr).
    pub reference: [f64; 3],
    /// CIE XYZ of `reference`.
    pub reference_xyz: [f64; 3],
}

/// Errors of a fit against the reference on a set of evaluation points.
#[derive(Debug, Clone, PartialEq)]
pub struct Errors {
    /// Number of evaluation points.
    pub points: usize,
    /// ΔErr_p (eq. 11) per channel.
    pub err_p: [f64; 3],
    /// Mean ΔE_u′v′ (eq. 13) over the points with a defined chromaticity; `None` if none.
    pub delta_e_uv: Option<f64>,
}

/// The scores of one successful fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    /// The robust fit on the combination's samples.
    pub fit: FitResult,
    /// ΔErr_p (eq. 11) per channel against the reference at the evaluation points.
    pub err_p: [f64; 3],
    /// Mean ΔE_u′v′ (eq. 13) over the points with a defined chromaticity; `None` if none.
    pub delta_e_uv: Option<f64>,
    /// The same errors on the points of the θL the combination did not fit; `None` when
    /// it fitted them all (or their reference has no signal in a channel).
    pub held_out: Option<Errors>,
    /// Loss of the Nelder–Mead fit on the same samples (when compared and it succeeded).
    pub nelder_mead_loss: Option<f64>,
}

/// One (θL combination, variant) of a study.
#[derive(Debug, Clone, PartialEq)]
pub struct CombinationResult {
    pub theta_l: Vec<f64>,
    pub variant: Variant,
    /// The scores, or why the fit failed.
    pub outcome: Result<Scores, String>,
}

/// Box-plot statistics of one (variant, number of θL) group.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupSummary {
    pub variant: Variant,
    pub size: usize,
    /// Combinations fitted and failed.
    pub fitted: usize,
    pub failed: usize,
    pub err_p: [Option<BoxStats>; 3],
    pub delta_e_uv: Option<BoxStats>,
    /// The same on the held-out points (combinations that left some θL out).
    pub held_out_err_p: [Option<BoxStats>; 3],
    pub held_out_delta_e_uv: Option<BoxStats>,
    /// Half-widths of the fits' 95 % intervals of Ks_G and of G's m, relative to the
    /// value: the error bars of a group's parameters.
    pub ks_g_ci95_relative: Option<BoxStats>,
    pub m_ci95_relative: Option<BoxStats>,
    /// Nelder–Mead fits compared, and those ending above the robust loss.
    pub nelder_mead_compared: usize,
    pub nelder_mead_above: usize,
}

/// Box-plot statistics of one variant's held-out errors over every combination that left
/// some θL out (62 of the 63 for six θL): the paper's protocol of judging a fit on
/// angles it did not see.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOutSummary {
    pub variant: Variant,
    /// Combinations with held-out points that were fitted.
    pub combinations: usize,
    pub err_p: [Option<BoxStats>; 3],
    pub delta_e_uv: Option<BoxStats>,
}

/// Everything a study computed.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyReport {
    /// Distinct θL of the samples, in order of first appearance.
    pub theta_l: Vec<f64>,
    pub points: Vec<EvalPoint>,
    pub options: StudyOptions,
    /// The camera model whose RGB → XYZ matrix scores chromaticity.
    pub camera: CameraModel,
    /// Per combination (size, then lexicographic) and variant, in that order.
    pub results: Vec<CombinationResult>,
    /// Wall time of the fits and scoring, seconds.
    pub seconds: f64,
}

/// The evaluation points: every sample's (θi, θr) the reference covers.
pub fn evaluation_points(
    samples: &[Sample],
    reference: &Reference,
    camera: &CameraModel,
) -> Vec<EvalPoint> {
    samples
        .iter()
        .filter_map(|s| {
            let rgb = reference.interpolate(s.theta_i, s.theta_r)?;
            Some(EvalPoint {
                theta_l: s.theta_l,
                theta_i: s.theta_i,
                theta_r: s.theta_r,
                reference: rgb,
                reference_xyz: camera.xyz(rgb),
            })
        })
        .collect()
}

fn check_samples(samples: &[Sample]) -> Result<(), StudyError> {
    if samples.is_empty() {
        return Err(StudyError::NoSamples);
    }
    for (index, s) in samples.iter().enumerate() {
        if let Some(field) = s.non_finite_field() {
            return Err(StudyError::NonFinite { index, field });
        }
    }
    Ok(())
}

/// Runs the study: every non-empty θL combination × every variant, in parallel.
pub fn run_study(
    samples: &[Sample],
    reference: &Reference,
    camera: &CameraModel,
    options: &StudyOptions,
) -> Result<StudyReport, StudyError> {
    run_study_with_progress(samples, reference, camera, options, |_, _| {})
}

/// [`run_study`], calling `progress(done, total)` after each (combination, variant) fit
/// (from the worker threads, in completion order).
pub fn run_study_with_progress(
    samples: &[Sample],
    reference: &Reference,
    camera: &CameraModel,
    options: &StudyOptions,
    progress: impl Fn(usize, usize) + Sync,
) -> Result<StudyReport, StudyError> {
    let start = Instant::now();
    check_samples(samples)?;
    if options.variants.is_empty() {
        return Err(StudyError::NoVariants);
    }
    if options.stride == 0 {
        return Err(StudyError::ZeroStride);
    }
    let fitted = subsample(samples, options.stride);
    let theta_l = distinct_theta_l(samples);
    let combos = combinations::combinations(&theta_l).ok_or(StudyError::TooManyThetaL {
        count: theta_l.len(),
        max: combinations::MAX_THETA_L,
    })?;
    let points = evaluation_points(samples, reference, camera);
    if points.is_empty() {
        return Err(StudyError::NoOverlap {
            samples: samples.len(),
        });
    }
    let measured: Vec<[f64; 3]> = points.iter().map(|p| p.reference).collect();
    // ΔErr_p needs signal in every reference channel: check once, not per fit.
    metrics::err_p(&measured, &measured)?;

    let jobs: Vec<(&Vec<f64>, Variant)> = combos
        .iter()
        .flat_map(|c| options.variants.iter().map(move |v| (c, *v)))
        .collect();
    let done = AtomicUsize::new(0);
    let results = jobs
        .par_iter()
        .map(|&(combo, variant)| {
            let outcome =
                score_combination(&fitted, combo, variant, &points, &measured, camera, options);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, jobs.len());
            CombinationResult {
                theta_l: combo.clone(),
                variant,
                outcome,
            }
        })
        .collect();
    Ok(StudyReport {
        theta_l,
        points,
        options: options.clone(),
        camera: camera.clone(),
        results,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Every `stride`-th sample of each θL, counted in file order from each θL's first
/// sample (pixel-column subsampling when samples are in column order); `stride` 0 is
/// taken as 1.
pub fn subsample(samples: &[Sample], stride: usize) -> Vec<Sample> {
    let stride = stride.max(1);
    let mut seen: Vec<(f64, usize)> = Vec::new();
    samples
        .iter()
        .filter(|s| {
            let index = match seen
                .iter_mut()
                .find(|(t, _)| (t - s.theta_l).abs() <= THETA_L_TOLERANCE)
            {
                Some((_, count)) => {
                    *count += 1;
                    *count - 1
                }
                None => {
                    seen.push((s.theta_l, 1));
                    0
                }
            };
            index % stride == 0
        })
        .copied()
        .collect()
}

/// The samples taken at any of the θL in `combo`.
pub fn samples_at(samples: &[Sample], combo: &[f64]) -> Vec<Sample> {
    samples
        .iter()
        .filter(|s| {
            combo
                .iter()
                .any(|t| (t - s.theta_l).abs() <= THETA_L_TOLERANCE)
        })
        .copied()
        .collect()
}

fn score_combination(
    samples: &[Sample],
    combo: &[f64],
    variant: Variant,
    points: &[EvalPoint],
    measured: &[[f64; 3]],
    camera: &CameraModel,
    options: &StudyOptions,
) -> Result<Scores, String> {
    let subset = samples_at(samples, combo);
    let mut fit_options = FitOptions::new(variant.model);
    fit_options.roughness = variant.roughness;
    let robust = fit::fit(&subset, &fit_options).map_err(|e| e.to_string())?;
    // Nelder–Mead is the baseline of the paper's two models only.
    let nelder_mead_loss = (options.compare_nelder_mead && !variant.model.has_fresnel_colour())
        .then(|| {
            fit_options.method = FitMethod::NelderMead;
            fit::fit(&subset, &fit_options).ok().map(|f| f.loss)
        })
        .flatten();
    let estimated: Vec<[f64; 3]> = points
        .iter()
        .map(|p| robust.predict(p.theta_i, p.theta_r))
        .collect();
    let all = errors(points, measured, &estimated, camera, |_| true)?;
    let held_out = errors(points, measured, &estimated, camera, |p| {
        !combo
            .iter()
            .any(|t| (t - p.theta_l).abs() <= THETA_L_TOLERANCE)
    })
    .ok()
    .filter(|e| e.points > 0);
    Ok(Scores {
        fit: robust,
        err_p: all.err_p,
        delta_e_uv: all.delta_e_uv,
        held_out,
        nelder_mead_loss,
    })
}

/// Half the widths of a fit's 95 % intervals of Ks_G and of G's m, relative to their
/// values; `None` without intervals or at a zero value.
fn relative_half_widths(scores: &Scores) -> [Option<f64>; 2] {
    let Some(ci) = scores.fit.ci95.as_ref() else {
        return [None, None];
    };
    let half = |[lo, hi]: [f64; 2], value: f64| (value > 0.0).then(|| (hi - lo) / (2.0 * value));
    [
        half(ci.ks[1], scores.fit.ks[1]),
        half(ci.m[1.min(ci.m.len() - 1)], scores.fit.params().m[1]),
    ]
}

/// ΔErr_p and mean ΔE_u′v′ of `estimated` against the reference on the points `keep`
/// selects.
fn errors(
    points: &[EvalPoint],
    measured: &[[f64; 3]],
    estimated: &[[f64; 3]],
    camera: &CameraModel,
    keep: impl Fn(&EvalPoint) -> bool,
) -> Result<Errors, String> {
    let chosen: Vec<usize> = (0..points.len()).filter(|&i| keep(&points[i])).collect();
    let pick = |values: &[[f64; 3]]| chosen.iter().map(|&i| values[i]).collect::<Vec<_>>();
    let (measured, estimated) = (pick(measured), pick(estimated));
    let err_p = metrics::err_p(&measured, &estimated).map_err(|e| e.to_string())?;
    let reference_xyz: Vec<[f64; 3]> = chosen.iter().map(|&i| points[i].reference_xyz).collect();
    let estimated_xyz: Vec<[f64; 3]> = estimated.iter().map(|&rgb| camera.xyz(rgb)).collect();
    Ok(Errors {
        points: chosen.len(),
        err_p,
        delta_e_uv: metrics::delta_e_uv(&reference_xyz, &estimated_xyz).ok(),
    })
}

impl Scores {
    /// Whether the Nelder–Mead loss exceeds the robust loss by more than `margin`
    /// (relative); `None` when Nelder–Mead was not compared or failed.
    pub fn nelder_mead_above(&self, margin: f64) -> Option<bool> {
        self.nelder_mead_loss
            .map(|nm| nm > self.fit.loss * (1.0 + margin))
    }
}

impl StudyReport {
    /// Box-plot statistics per variant and number of θL, variants in option order.
    pub fn summary(&self) -> Vec<GroupSummary> {
        let mut out = Vec::new();
        for &variant in &self.options.variants {
            for size in 1..=self.theta_l.len() {
                let group: Vec<&CombinationResult> = self
                    .results
                    .iter()
                    .filter(|r| r.variant == variant && r.theta_l.len() == size)
                    .collect();
                let scores: Vec<&Scores> = group
                    .iter()
                    .filter_map(|r| r.outcome.as_ref().ok())
                    .collect();
                let above: Vec<bool> = scores
                    .iter()
                    .filter_map(|s| s.nelder_mead_above(self.options.local_minimum_margin))
                    .collect();
                let channel = |c: usize| {
                    BoxStats::from_values(&scores.iter().map(|s| s.err_p[c]).collect::<Vec<_>>())
                };
                let held_out: Vec<&Errors> =
                    scores.iter().filter_map(|s| s.held_out.as_ref()).collect();
                let held_out_channel = |c: usize| {
                    BoxStats::from_values(&held_out.iter().map(|e| e.err_p[c]).collect::<Vec<_>>())
                };
                out.push(GroupSummary {
                    variant,
                    size,
                    fitted: scores.len(),
                    failed: group.len() - scores.len(),
                    err_p: [channel(0), channel(1), channel(2)],
                    delta_e_uv: BoxStats::from_values(
                        &scores
                            .iter()
                            .filter_map(|s| s.delta_e_uv)
                            .collect::<Vec<_>>(),
                    ),
                    held_out_err_p: [
                        held_out_channel(0),
                        held_out_channel(1),
                        held_out_channel(2),
                    ],
                    held_out_delta_e_uv: BoxStats::from_values(
                        &held_out
                            .iter()
                            .filter_map(|e| e.delta_e_uv)
                            .collect::<Vec<_>>(),
                    ),
                    ks_g_ci95_relative: BoxStats::from_values(
                        &scores
                            .iter()
                            .filter_map(|s| relative_half_widths(s)[0])
                            .collect::<Vec<_>>(),
                    ),
                    m_ci95_relative: BoxStats::from_values(
                        &scores
                            .iter()
                            .filter_map(|s| relative_half_widths(s)[1])
                            .collect::<Vec<_>>(),
                    ),
                    nelder_mead_compared: above.len(),
                    nelder_mead_above: above.iter().filter(|&&a| a).count(),
                });
            }
        }
        out
    }

    /// Held-out errors per variant over every combination that left some θL out,
    /// variants in option order.
    pub fn held_out_summary(&self) -> Vec<HeldOutSummary> {
        self.options
            .variants
            .iter()
            .map(|&variant| {
                let held_out: Vec<&Errors> = self
                    .results
                    .iter()
                    .filter(|r| r.variant == variant)
                    .filter_map(|r| r.outcome.as_ref().ok()?.held_out.as_ref())
                    .collect();
                let stats = |f: &dyn Fn(&Errors) -> Option<f64>| {
                    BoxStats::from_values(&held_out.iter().filter_map(|e| f(e)).collect::<Vec<_>>())
                };
                HeldOutSummary {
                    variant,
                    combinations: held_out.len(),
                    err_p: [
                        stats(&|e| Some(e.err_p[0])),
                        stats(&|e| Some(e.err_p[1])),
                        stats(&|e| Some(e.err_p[2])),
                    ],
                    delta_e_uv: stats(&|e| e.delta_e_uv),
                }
            })
            .collect()
    }

    /// The result of `variant` fitted on the single θL closest to `theta_l`.
    pub fn single(&self, variant: Variant, theta_l: f64) -> Option<&CombinationResult> {
        self.results
            .iter()
            .filter(|r| r.variant == variant && r.theta_l.len() == 1)
            .min_by(|a, b| {
                (a.theta_l[0] - theta_l)
                    .abs()
                    .total_cmp(&(b.theta_l[0] - theta_l).abs())
            })
    }
}

/// Writes the tables and the figures of `report` into `dir` (created if missing);
/// figure titles start with `name` (the sample's) when it is not empty. Returns the
/// files written.
pub fn write_outputs(
    report: &StudyReport,
    dir: &Path,
    name: &str,
) -> Result<Vec<PathBuf>, StudyError> {
    std::fs::create_dir_all(dir).map_err(|error| StudyError::Io {
        path: dir.to_path_buf(),
        error,
    })?;
    let mut written = write_tables(report, dir)?;
    written.extend(write_figures(report, dir, name)?);
    Ok(written)
}
