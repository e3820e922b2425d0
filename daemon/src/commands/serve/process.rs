//! The processing steps of a scan: the HDR map of a θL once its bracket is complete,
//! then extraction and the model fits. Results are written atomically.

use std::path::{Path, PathBuf};

use anyhow::Context;
use gonio_processing::brdf::Model;
use gonio_processing::capture::{is_capture_path, Frame};
use gonio_processing::extract::{extract_scan, ExtractOptions};
use gonio_processing::fit::{fit, FitOptions};
use gonio_processing::hdr::{merge, MergeOptions};
use gonio_processing::samples::{read_csv, write_csv};
use serde_json::{json, Value};

use super::files::{write_atomic, write_atomic_with};
use super::plan::{theta_dir_name, Step, FIT_MODELS};

/// Runs one processing step in scan directory `dir`. Returns the step's result record.
pub fn run(step: &Step, dir: &Path) -> anyhow::Result<Value> {
    match step {
        Step::Hdr { theta_l } => hdr(dir, *theta_l),
        Step::Extract => extract(dir),
        Step::Fit { model } => fit_model(dir, model),
        Step::Home | Step::Move { .. } | Step::Meter { .. } | Step::Capture { .. } => {
            anyhow::bail!("{} is not a processing step", step.describe())
        }
    }
}

fn hdr(dir: &Path, theta_l: f64) -> anyhow::Result<Value> {
    let frame_dir = dir.join(theta_dir_name(theta_l));
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&frame_dir)
        .with_context(|| frame_dir.display().to_string())?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| is_capture_path(p))
        .collect();
    paths.sort();
    let frames = paths
        .iter()
        .map(|p| Frame::read(p))
        .collect::<Result<Vec<_>, _>>()?;
    let image = merge(&frames, &MergeOptions::default())?;
    let rel = format!("hdr/{}.exr", theta_dir_name(theta_l));
    write_atomic_with(&dir.join(&rel), |tmp| image.write_exr(tmp))?;
    Ok(json!({ "path": rel, "frames": frames.len() }))
}

/// Extracts with setup.json's white reflectance.
fn extract(dir: &Path) -> anyhow::Result<Value> {
    let extraction = extract_scan(dir, &ExtractOptions::default())?;
    anyhow::ensure!(
        !extraction.samples.is_empty(),
        "{}",
        extraction.dropped.explain_empty()
    );
    write_atomic_with(&dir.join("samples.csv"), |tmp| {
        write_csv(tmp, &extraction.samples)
    })?;
    Ok(json!({ "path": "samples.csv", "samples": extraction.samples.len() }))
}

fn fit_model(dir: &Path, model: &str) -> anyhow::Result<Value> {
    let name = FIT_MODELS
        .iter()
        .find(|(m, _)| *m == model)
        .map(|(_, name)| *name)
        .with_context(|| format!("unknown model {model:?}"))?;
    let samples = read_csv(&dir.join("samples.csv"))?;
    let result = fit(&samples, &FitOptions::new(model.parse::<Model>()?))?;
    write_atomic(&dir.join(name), &serde_json::to_vec_pretty(&result)?)
        .with_context(|| name.to_owned())?;
    Ok(json!({ "path": name, "loss": result.loss }))
}
