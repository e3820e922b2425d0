//! The processing steps of a scan: the HDR map of a θL once its bracket is complete,
//! then extraction and the model fits. Results are written atomically.

use std::path::{Path, PathBuf};

use gonio_processing::brdf::Model;
use gonio_processing::capture::{is_capture_path, Frame};
use gonio_processing::extract::{extract_scan, ExtractOptions};
use gonio_processing::fit::{fit, FitOptions, FitResult};
use gonio_processing::hdr::{merge, MergeOptions};
use gonio_processing::samples::{read_csv, write_csv};
use serde_json::{json, Value};

use super::files::{write_atomic, write_atomic_with};
use super::plan::{theta_dir_name, Step, FIT_MODELS};

/// Runs one processing step in scan directory `dir`; `white_reflectance` is that of
/// the white reference strip. Returns the step's result record.
pub fn run(step: &Step, dir: &Path, white_reflectance: f64) -> Result<Value, String> {
    match step {
        Step::Hdr { theta_l } => hdr(dir, *theta_l),
        Step::Extract => extract(dir, white_reflectance),
        Step::Fit { model } => fit_model(dir, model),
        Step::Home | Step::Move { .. } | Step::Meter { .. } | Step::Capture { .. } => {
            Err(format!("{} is not a processing step", step.describe()))
        }
    }
}

fn hdr(dir: &Path, theta_l: f64) -> Result<Value, String> {
    let frame_dir = dir.join(theta_dir_name(theta_l));
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&frame_dir)
        .map_err(|e| format!("{}: {e}", frame_dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| is_capture_path(p))
        .collect();
    paths.sort();
    let frames = paths
        .iter()
        .map(|p| Frame::read(p).map_err(|e| e.to_string()))
        .collect::<Result<Vec<_>, _>>()?;
    let image = merge(&frames, &MergeOptions::default()).map_err(|e| e.to_string())?;
    let rel = format!("hdr/{}.exr", theta_dir_name(theta_l));
    write_atomic_with(&dir.join(&rel), |tmp| image.write_exr(tmp)).map_err(|e| e.to_string())?;
    Ok(json!({ "path": rel, "frames": frames.len() }))
}

fn extract(dir: &Path, white_reflectance: f64) -> Result<Value, String> {
    let options = ExtractOptions {
        white_reflectance,
        ..ExtractOptions::default()
    };
    let extraction = extract_scan(dir, &options).map_err(|e| e.to_string())?;
    let path = dir.join("samples.csv");
    write_atomic_with(&path, |tmp| write_csv(tmp, &extraction.samples))
        .map_err(|e| e.to_string())?;
    Ok(json!({ "path": "samples.csv", "samples": extraction.samples.len() }))
}

fn fit_model(dir: &Path, model: &str) -> Result<Value, String> {
    let samples = read_csv(&dir.join("samples.csv")).map_err(|e| e.to_string())?;
    let options = FitOptions::new(model.parse::<Model>().map_err(|e| e.to_string())?);
    let result = fit(&samples, &options).map_err(|e| e.to_string())?;
    let name = FIT_MODELS
        .iter()
        .find(|(m, _)| *m == model)
        .map(|(_, name)| *name)
        .ok_or_else(|| format!("unknown model {model:?}"))?;
    let text = serde_json::to_vec_pretty(&result).map_err(|e| e.to_string())?;
    write_atomic(&dir.join(name), &text).map_err(|e| format!("{name}: {e}"))?;
    Ok(json!({ "path": name, "loss": result.loss }))
}

/// Parses a fit result JSON.
pub fn read_fit(text: &str) -> Result<FitResult, serde_json::Error> {
    serde_json::from_str(text)
}

/// β (camera RGB) a fitted model predicts at (θi, θr), degrees.
pub fn predict(fit: &FitResult, theta_i: f64, theta_r: f64) -> [f64; 3] {
    fit.predict(theta_i, theta_r)
}
