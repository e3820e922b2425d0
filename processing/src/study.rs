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
mod error;
pub mod figures;
pub mod pareto;
mod plots;
mod report;
mod tables;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;
use std::time::Instant;

use rayon::prelude::*;

use crate::brdf::{Model, Roughness};
use crate::color::CameraModel;
use crate::fit::{self, held_out, FitMethod, FitOptions, FitResult};
use crate::metrics;
use crate::reference::Reference;
pub use crate::samples::distinct_theta_l;
use crate::samples::{Sample, THETA_L_TOLERANCE};

pub use error::StudyError;
pub use plots::write_figures;
pub use report::{
    CombinationResult, Errors, EvalPoint, GroupSummary, HeldOutSummary, Scores, StudyOptions,
    StudyReport, Variant,
};
pub use tables::write_tables;

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

    let jobs: Vec<(usize, &Vec<f64>, Variant)> = combos
        .iter()
        .enumerate()
        .flat_map(|(k, c)| options.variants.iter().map(move |v| (k, c, *v)))
        .collect();
    let context = Context {
        samples: &fitted,
        points: &points,
        measured: &measured,
        camera,
        options,
    };
    let shared_fits: Vec<SharedFits> = combos.iter().map(|_| SharedFits::default()).collect();
    let done = AtomicUsize::new(0);
    let results = jobs
        .par_iter()
        .map(|&(k, combo, variant)| {
            let outcome = score_combination(&context, combo, variant, &shared_fits[k]);
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

/// The robust Cook–Torrance fit of one combination per roughness, made once: the
/// Cook–Torrance variant reports it, and Cook–Torrance–Fresnel takes it when its colour
/// shift is not significant ([`fit::fit_fresnel_given`]) instead of fitting it again.
#[derive(Default)]
struct SharedFits {
    cook_torrance: [OnceLock<Result<FitResult, String>>; 2],
}

impl SharedFits {
    /// The robust fit of `variant` to `subset`, sharing Cook–Torrance's between the two
    /// variants that need it when both are in `variants`; with the loss evaluations it
    /// made itself (Cook–Torrance–Fresnel's without those of the fit it took).
    fn robust(
        &self,
        subset: &[Sample],
        variant: Variant,
        variants: &[Variant],
    ) -> Result<(FitResult, u64), String> {
        let options = |model| FitOptions {
            roughness: variant.roughness,
            ..FitOptions::new(model)
        };
        let present = |model| variants.contains(&Variant { model, ..variant });
        let cell = &self.cook_torrance[usize::from(variant.roughness == Roughness::PerChannel)];
        let cook_torrance = || {
            cell.get_or_init(|| {
                fit::fit(subset, &options(Model::CookTorrance)).map_err(|e| e.to_string())
            })
        };
        let both = present(Model::CookTorrance) && present(Model::CookTorranceFresnel);
        let own = |f: FitResult, given: Option<&FitResult>| {
            let evaluations = f.evaluations_beyond(given);
            (f, evaluations)
        };
        let fitted = match variant.model {
            Model::CookTorrance if both => {
                return cook_torrance().clone().map(|f| own(f, None));
            }
            Model::CookTorranceFresnel if both => match cook_torrance() {
                Ok(tied) => fit::fit_fresnel_given(subset, &options(variant.model), tied)
                    .map(|f| own(f, Some(tied))),
                Err(_) => fit::fit(subset, &options(variant.model)).map(|f| own(f, None)),
            },
            model => fit::fit(subset, &options(model)).map(|f| own(f, None)),
        };
        fitted.map_err(|e| e.to_string())
    }
}

/// What every combination is fitted to and scored against.
struct Context<'a> {
    /// The samples fitted (subsampled by the stride).
    samples: &'a [Sample],
    points: &'a [EvalPoint],
    /// The reference β at `points`.
    measured: &'a [[f64; 3]],
    camera: &'a CameraModel,
    options: &'a StudyOptions,
}

fn score_combination(
    context: &Context,
    combo: &[f64],
    variant: Variant,
    shared: &SharedFits,
) -> Result<Scores, String> {
    let &Context {
        samples,
        points,
        measured,
        camera,
        options,
    } = context;
    let subset = samples_at(samples, combo);
    // Nelder–Mead is the baseline of the paper's two models only; it runs beside the
    // robust fit (either takes the other core when the combinations run out).
    let compare = options.compare_nelder_mead && !variant.model.has_fresnel_colour();
    let nelder_mead = FitOptions {
        method: FitMethod::NelderMead,
        roughness: variant.roughness,
        ..FitOptions::new(variant.model)
    };
    let (robust, compared) = rayon::join(
        || shared.robust(&subset, variant, &options.variants),
        || {
            compare
                .then(|| fit::loss_reached(&subset, &nelder_mead).ok())
                .flatten()
        },
    );
    let (robust, evaluations) = robust?;
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
    let point_evaluations = (evaluations + compared.map_or(0, |(_, e)| e)) * subset.len() as u64;
    Ok(Scores {
        fit: robust,
        err_p: all.err_p,
        delta_e_uv: all.delta_e_uv,
        held_out,
        nelder_mead_loss: compared.map(|(loss, _)| loss),
        point_evaluations,
    })
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
    let reference_xyz: Vec<[f64; 3]> = chosen.iter().map(|&i| points[i].reference_xyz).collect();
    held_out::errors(&pick(measured), &reference_xyz, &pick(estimated), camera)
        .map_err(|e| e.to_string())
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
