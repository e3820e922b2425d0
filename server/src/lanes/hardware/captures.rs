//! Captures: the camera's operations with bounded retries of transient faults, and
//! one exposure of a bracket captured into the scan directory with its JSON sidecar
//! (docs/ARCHITECTURE.md, "File formats"); a frame already there (the daemon died
//! after capturing it) is reused.

use std::path::{Path, PathBuf};

use gonio_drivers::{Camera, DeviceError, Exposure};
use gonio_processing::capture::Sidecar;
use serde_json::{json, Value};

use super::{backoff, camera_state_after, is_camera_gone, HardwareLane};
use crate::files::write_atomic;
use crate::lanes::backoff::Backoff;
use crate::lanes::step::StepError;
use crate::plan::{exposure_stem, theta_dir_name};
use crate::storage;
use crate::store::now_rfc3339;
use crate::sync::lock;

impl HardwareLane {
    /// Runs `op` on the camera with bounded retries of transient faults (busy, timeout,
    /// I/O). A camera that is gone (disconnected, not found) interrupts the scan until
    /// it is back.
    pub(super) fn camera_op<T>(
        &mut self,
        id: i64,
        what: &str,
        mut op: impl FnMut(&mut dyn Camera) -> Result<T, DeviceError>,
    ) -> Result<T, StepError> {
        let retry = self.shared.config.retry;
        let mut last = String::new();
        for attempt in 0..retry.attempts {
            if attempt > 0 {
                std::thread::sleep(backoff(retry.backoff_ms, attempt));
            }
            if !self.still_running(id)? {
                return Err(StepError::Halted);
            }
            lock(&self.shared.hardware).camera.state = "capturing";
            let result = op(self.camera.as_mut());
            let mut status = lock(&self.shared.hardware);
            match result {
                Ok(value) => {
                    status.camera.state = "idle";
                    status.camera.error = None;
                    return Ok(value);
                }
                Err(err) if storage::says_disk_full(&err.to_string()) => {
                    // The camera did its part: the host's disk is full.
                    status.camera.state = "idle";
                    tracing::warn!("scan {id}: camera {what}: {err}");
                    return Err(StepError::Waiting(
                        self.shared.storage.full_reason(self.need),
                    ));
                }
                Err(err) => {
                    tracing::warn!("scan {id}: camera {what} (try {}): {err}", attempt + 1);
                    status.camera.state = camera_state_after(&err);
                    status.camera.error = Some(err.to_string());
                    if is_camera_gone(&err) {
                        self.camera_retry = Some(Backoff::now());
                        return Err(StepError::Interrupted(format!(
                            "camera {what}: {err}; waiting for the camera to come back"
                        )));
                    }
                    if !err.is_transient() {
                        return Err(StepError::Failed(format!("camera {what}: {err}")));
                    }
                    last = err.to_string();
                }
            }
        }
        Err(StepError::Failed(format!(
            "camera {what} failed after {} attempts: {last}",
            retry.attempts
        )))
    }

    pub(super) fn capture(
        &mut self,
        id: i64,
        dir: &Path,
        theta_l: f64,
        index: usize,
        shutter_s: f64,
    ) -> Result<Value, StepError> {
        let frame_dir = dir.join(theta_dir_name(theta_l));
        let stem = exposure_stem(index);
        let sidecar_path = frame_dir.join(format!("{stem}.json"));
        let existing = find_frame(&frame_dir, &stem);
        if let (Some(image), true) = (&existing, sidecar_path.exists()) {
            return Ok(frame_result(dir, image, true));
        }
        let requested = Exposure {
            shutter_s,
            iso: self.iso,
        };
        let what = format!("θL {theta_l:.1}° {stem}");
        let (image, exposure) = match existing {
            // The image landed but the crash came before its sidecar: only the
            // exposure actually set is missing.
            Some(image) => {
                let exposure = self.camera_op(id, &format!("exposure for {what}"), |c| {
                    c.set_exposure(requested)
                })?;
                (image, exposure)
            }
            None => {
                // The board may have reset (or gone) since the last capture: asked
                // before each one, so that the arm is homed and placed again first and
                // /api/hardware says so at once.
                self.refresh_arm_status();
                self.place_for_capture(id, theta_l)?;
                self.camera_op(id, &format!("exposure for {what}"), |c| {
                    c.set_exposure(requested)
                })?;
                std::fs::create_dir_all(&frame_dir)
                    .map_err(|e| self.write_error(format!("{}: {e}", frame_dir.display())))?;
                let target = frame_dir.join(format!("{stem}.tiff"));
                let capture =
                    self.camera_op(id, &format!("capture {what}"), |c| c.capture_to(&target))?;
                self.log(Some(id), "capture", &what)?;
                (capture.path, capture.exposure)
            }
        };
        self.write_sidecar(&sidecar_path, exposure, theta_l)
            .map_err(|e| self.write_error(e))?;
        Ok(frame_result(dir, &image, false))
    }

    /// The step error of a write that failed with `message`: waiting for space when the
    /// disk is full, else a failure.
    fn write_error(&self, message: String) -> StepError {
        if storage::says_disk_full(&message) {
            tracing::warn!("{message}");
            StepError::Waiting(self.shared.storage.full_reason(self.need))
        } else {
            StepError::Failed(message)
        }
    }

    /// Writes the JSON sidecar of a capture (docs/ARCHITECTURE.md, "File formats") atomically at `path`.
    pub(super) fn write_sidecar(
        &self,
        path: &Path,
        exposure: Exposure,
        theta_l: f64,
    ) -> Result<(), String> {
        let sidecar = Sidecar {
            shutter_s: exposure.shutter_s,
            iso: exposure.iso.map(f64::from),
            theta_l,
            camera: self.camera_model.clone(),
            time: now_rfc3339(),
            black_level: self.sidecar.black_level,
            white_level: self.sidecar.white_level,
            response: self.sidecar.response,
            significant_bits: self.sidecar.significant_bits,
            aperture: None,
            width: None,
            height: None,
        };
        let text = serde_json::to_vec_pretty(&sidecar).map_err(|e| e.to_string())?;
        write_atomic(path, &text).map_err(|e| format!("{}: {e}", path.display()))
    }
}

/// The captured image of `stem` in `dir`, whatever its extension (sidecars excluded).
fn find_frame(dir: &Path, stem: &str) -> Option<PathBuf> {
    let entries = std::fs::read_dir(dir).ok()?;
    entries.filter_map(Result::ok).map(|e| e.path()).find(|p| {
        p.file_stem().is_some_and(|s| s == stem) && p.extension().is_some_and(|e| e != "json")
    })
}

fn frame_result(scan_dir: &Path, image: &Path, reused: bool) -> Value {
    let rel = image
        .strip_prefix(scan_dir)
        .unwrap_or(image)
        .to_string_lossy()
        .into_owned();
    json!({ "path": rel, "reused": reused })
}
