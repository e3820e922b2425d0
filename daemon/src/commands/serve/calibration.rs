//! The setup later scans use, and calibrating it from a scan (docs/ARCHITECTURE.md,
//! "Calibration").
//!
//! `POST /api/scans/{id}/calibrate` runs the calibration of `gonio calibrate` on scan
//! `id`'s captures, with that scan's setup.json as the prior, and stores the result in
//! DATA/setup.json (the setup's fields plus its `calibration`). Scans started afterwards
//! write that as their setup.json, instead of the configuration's `[setup]` or the
//! emulated scene's; `DELETE /api/setup` goes back to those.

use std::path::{Path, PathBuf};

use anyhow::Context;
use gonio_processing::calibrate::{calibrate_scan, CalibrateOptions};
use gonio_processing::extract::read_setup;
use gonio_processing::geometry::Setup;
use serde_json::{json, Value};

use super::files::write_atomic;

/// Where the calibrated setup is kept.
pub fn calibrated_path(data_dir: &Path) -> PathBuf {
    data_dir.join("setup.json")
}

/// The setup a scan starting now uses: the calibrated one if there is one (and it is
/// valid), else `configured`.
pub fn current_setup(data_dir: &Path, configured: Option<&Setup>) -> Option<Setup> {
    let path = calibrated_path(data_dir);
    if path.is_file() {
        match read_setup(&path) {
            Ok(setup) => return Some(setup),
            Err(err) => tracing::warn!("ignoring the calibrated setup: {err}"),
        }
    }
    configured.cloned()
}

/// Calibrates from the captures in `scan_dir` (scan `id`) and stores the result as the
/// setup of later scans. Returns what the API answers: the setup and its calibration.
pub fn calibrate_and_store(scan_dir: &Path, data_dir: &Path, id: i64) -> anyhow::Result<Value> {
    let prior = read_setup(&scan_dir.join("setup.json"))?;
    let calibration = calibrate_scan(scan_dir, &prior, &CalibrateOptions::default())?;
    let mut stored = calibration.setup_json();
    stored["calibration"]["scan"] = json!(id);
    let mut text = serde_json::to_vec_pretty(&stored)?;
    text.push(b'\n');
    let path = calibrated_path(data_dir);
    write_atomic(&path, &text).with_context(|| format!("writing {}", path.display()))?;
    tracing::info!(
        "setup calibrated from scan {id}; later scans use {}",
        path.display()
    );
    Ok(stored)
}

/// Forgets the calibrated setup; returns whether there was one.
pub fn forget(data_dir: &Path) -> std::io::Result<bool> {
    match std::fs::remove_file(calibrated_path(data_dir)) {
        Ok(()) => Ok(true),
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(err) => Err(err),
    }
}
