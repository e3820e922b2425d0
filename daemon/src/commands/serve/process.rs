//! The processing steps of a scan: the HDR map of a θL once its bracket is complete,
//! then extraction and the model fits. Results are written atomically.

use std::path::{Path, PathBuf};

use gonio_processing::capture::{is_capture_path, Frame};
use gonio_processing::hdr::{merge, MergeOptions};
use serde_json::{json, Value};

use super::files::{write_atomic, write_atomic_with};
use super::plan::{theta_dir_name, Step, FIT_MODELS};

/// Runs one processing step in scan directory `dir`; returns its result record.
pub fn run(step: &Step, dir: &Path) -> Result<Value, String> {
    match step {
        Step::Hdr { theta_l } => hdr(dir, *theta_l),
        Step::Extract => extract(dir),
        Step::Fit { model } => fit_model(dir, model),
        Step::Home | Step::Move { .. } | Step::Capture { .. } => {
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

fn extract(_dir: &Path) -> Result<Value, String> { Err("TEMP".into()) }
fn fit_model(_dir: &Path, _m: &str) -> Result<Value, String> { Err("TEMP".into()) }
pub struct FitResult;
pub fn read_fit(_text: &str) -> Result<FitResult, String> { Err("TEMP".into()) }
pub fn predict(_fit: &FitResult, _theta_i: f64, _theta_r: f64) -> [f64; 3] { [0.0; 3] }
