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

/// The setup.json of a scan starting now: the calibrated setup (with its `calibration`
/// and `provenance`) if there is a valid one, else `configured` with `source` as the
/// provenance of every field.
pub fn current_setup_json(
    data_dir: &Path,
    configured: Option<&Setup>,
    source: &str,
) -> Option<Value> {
    let path = calibrated_path(data_dir);
    if path.is_file() {
        let stored = std::fs::read(&path)
            .map_err(anyhow::Error::from)
            .and_then(|bytes| Ok(serde_json::from_slice::<Value>(&bytes)?));
        match (read_setup(&path), stored) {
            (Ok(_), Ok(stored)) => return Some(stored),
            (Err(err), _) => tracing::warn!("ignoring the calibrated setup: {err}"),
            (_, Err(err)) => tracing::warn!("ignoring the calibrated setup: {err}"),
        }
    }
    let mut value = json!(configured?);
    let provenance: serde_json::Map<String, Value> = value
        .as_object()?
        .iter()
        .map(|(field, v)| {
            let source = match (field.as_str(), v.as_object()) {
                (UNCERTAINTY, Some(block)) => {
                    block.keys().map(|k| (k.clone(), json!(source))).collect()
                }
                _ => json!(source),
            };
            (field.clone(), source)
        })
        .collect();
    value["provenance"] = Value::Object(provenance);
    Some(value)
}

/// setup.json's block of standard uncertainties, whose provenance is per key.
const UNCERTAINTY: &str = "uncertainty";

/// The fields a calibration estimates (a `null` estimate leaves the prior's value).
const ESTIMATED: [&str; 6] = [
    "sample_row",
    "white_row",
    "camera_offset_mm",
    "camera_distance_mm",
    "cylinder_tilt_deg",
    "arm_zero_offset_deg",
];

/// Where each field of a setup calibrated from scan `id` came from: the estimated ones
/// from the calibration, the others as the prior's `provenance` says (else the prior,
/// scan `id`'s setup.json). The `uncertainty` block's provenance is per key: the
/// calibration for an estimate's standard uncertainty, else the prior's.
fn provenance(stored: &Value, prior: &Value, id: i64) -> Value {
    let Some(fields) = stored.as_object() else {
        return json!({});
    };
    let calibration = &stored["calibration"];
    let calibrated = json!(format!("calibrated from scan {id}"));
    let from_prior = |source: Option<&Value>| {
        source
            .filter(|s| s.is_string())
            .cloned()
            .unwrap_or_else(|| json!(format!("scan {id}'s setup.json")))
    };
    fields
        .iter()
        .filter(|(field, _)| !matches!(field.as_str(), "calibration" | "provenance"))
        .map(|(field, value)| {
            let prior_source = prior["provenance"].get(field);
            let source = match (field.as_str(), value.as_object()) {
                (UNCERTAINTY, Some(block)) => block
                    .iter()
                    .map(|(key, u)| {
                        let source = if calibration[key]["stderr"] == *u {
                            calibrated.clone()
                        } else {
                            // The prior's per key, or one source for its whole block.
                            from_prior(prior_source.map(|p| p.get(key).unwrap_or(p)))
                        };
                        (key.clone(), source)
                    })
                    .collect(),
                _ if ESTIMATED.contains(&field.as_str()) && !calibration[field].is_null() => {
                    calibrated.clone()
                }
                _ => from_prior(prior_source),
            };
            (field.clone(), source)
        })
        .collect::<serde_json::Map<_, _>>()
        .into()
}

/// Calibrates from the captures in `scan_dir` (scan `id`) and stores the result as the
/// setup of later scans. Returns what the API answers: the setup, its calibration and
/// where each field came from (`provenance`).
pub fn calibrate_and_store(scan_dir: &Path, data_dir: &Path, id: i64) -> anyhow::Result<Value> {
    let prior_path = scan_dir.join("setup.json");
    let prior = read_setup(&prior_path)?;
    let prior_json: Value = serde_json::from_slice(&std::fs::read(&prior_path)?)?;
    let calibration = calibrate_scan(scan_dir, &prior, &CalibrateOptions::default())?;
    let mut stored = calibration.setup_json();
    stored["calibration"]["scan"] = json!(id);
    stored["provenance"] = provenance(&stored, &prior_json, id);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn provenance_names_the_calibration_for_estimates_and_keeps_the_prior_s_otherwise() {
        let stored = json!({
            "sample_row": 10, "white_row": 20, "camera_offset_mm": 0.1,
            "camera_distance_mm": 300.0, "focal_length_mm": 50.0,
            "calibration": { "sample_row": {}, "white_row": {}, "camera_offset_mm": {},
                             "camera_distance_mm": null, "scan": 4 },
        });
        let prior = json!({ "provenance": { "focal_length_mm": "emulated scene" } });
        assert_eq!(
            provenance(&stored, &prior, 4),
            json!({
                "sample_row": "calibrated from scan 4",
                "white_row": "calibrated from scan 4",
                "camera_offset_mm": "calibrated from scan 4",
                "camera_distance_mm": "scan 4's setup.json",
                "focal_length_mm": "emulated scene",
            })
        );
    }

    #[test]
    fn the_uncertainty_block_s_provenance_is_per_key() {
        let stored = json!({
            "camera_offset_mm": 0.1,
            "uncertainty": { "camera_offset_mm": 0.02, "camera_distance_mm": 0.9,
                             "white_reflectance": 0.004, "arm_angle_deg": 0.003 },
            "calibration": { "camera_offset_mm": { "value": 0.1, "stderr": 0.02 },
                             "camera_distance_mm": null },
        });
        let prior = json!({ "provenance": {
            "uncertainty": { "camera_offset_mm": "emulated scene",
                             "camera_distance_mm": "emulated scene",
                             "white_reflectance": "emulated scene" } } });
        assert_eq!(
            provenance(&stored, &prior, 7)["uncertainty"],
            json!({
                "camera_offset_mm": "calibrated from scan 7",
                "camera_distance_mm": "emulated scene",
                "white_reflectance": "emulated scene",
                "arm_angle_deg": "scan 7's setup.json",
            })
        );
        // A prior that names one source for its whole block.
        let prior = json!({ "provenance": { "uncertainty": "configuration [setup]" } });
        assert_eq!(
            provenance(&stored, &prior, 7)["uncertainty"]["white_reflectance"],
            "configuration [setup]"
        );
    }

    #[test]
    fn a_configured_setup_names_its_source_for_every_uncertainty_key() {
        let dir = std::env::temp_dir().join(format!("gonio-setup-json-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let config = crate::config::Config::from_toml_str(CONFIGURED).unwrap();
        let value =
            current_setup_json(&dir, config.setup().as_ref(), "configuration [setup]").unwrap();
        std::fs::remove_dir_all(&dir).ok();
        assert_eq!(
            value["uncertainty"],
            json!({ "white_reflectance": [0.004, 0.003, 0.005], "arm_angle_deg": 0.002 })
        );
        assert_eq!(
            value["provenance"]["uncertainty"],
            json!({ "white_reflectance": "configuration [setup]",
                    "arm_angle_deg": "configuration [setup]" })
        );
        assert_eq!(
            value["provenance"]["focal_length_mm"],
            "configuration [setup]"
        );
    }

    /// A configured real setup with two of its standard uncertainties.
    const CONFIGURED: &str = "[setup]\ncylinder_radius_mm = 40.0\ncamera_distance_mm = 700.0\n\
        light_distance_mm = 1000.0\nfocal_length_mm = 85.0\npixel_pitch_um = 6.1\n\
        image_width = 3872\nimage_height = 2592\nsample_row = 1100\nwhite_row = 1491\n\
        [setup.uncertainty]\nwhite_reflectance = [0.004, 0.003, 0.005]\narm_angle_deg = 0.002\n";
}
