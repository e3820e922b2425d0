//! Metering θL for an automatic bracket: a capture at a middle shutter (shortened
//! while the strips clip), read like any capture, and the fewest allowed shutters that
//! expose every pixel of the strips well.

use std::path::Path;

use gonio_drivers::bracket::{auto_bracket, BracketError, BracketRegion, MeteringFrame};
use gonio_drivers::Exposure;
use gonio_processing::capture::{sidecar_path, Frame};
use gonio_processing::geometry::{column_angles, Setup};
use serde_json::json;

use super::HardwareLane;
use crate::lanes::step::{Outcome, StepError};
use crate::plan::{theta_dir_name, ScanPlan};
use crate::timing::METER_START_S;

impl HardwareLane {
    /// Meters θL and plans its bracket: a capture at a middle shutter (shortened while
    /// the strips clip), then the fewest allowed shutters that expose every strip pixel
    /// well ([`auto_bracket`]).
    pub(super) fn meter(&mut self, id: i64, theta_l: f64) -> Outcome {
        // The scan's own setup (written when it started), whatever was calibrated since.
        let own =
            gonio_processing::extract::read_setup(&self.shared.scan_dir(id).join("setup.json"));
        let setup = own.ok().or_else(|| self.setup()).ok_or_else(|| {
            StepError::Failed("an automatic bracket needs the setup geometry ([setup])".into())
        })?;
        let allowed = self.allowed_s.clone();
        let Some(mut shutter_s) = nearest_at_most(&allowed, METER_START_S) else {
            return Err(StepError::Failed(
                "the camera reported no shutter speeds to meter with".into(),
            ));
        };
        self.place_for_capture(id, theta_l)?;
        let path = self
            .shared
            .config
            .data_dir
            .join("metering")
            .join(format!("scan-{id}-{}.tiff", theta_dir_name(theta_l)));
        let failed = |what: String| StepError::Failed(format!("metering θL {theta_l:.1}°: {what}"));
        std::fs::create_dir_all(path.parent().unwrap_or(Path::new(".")))
            .map_err(|e| failed(e.to_string()))?;
        for _ in 0..METER_ATTEMPTS {
            let exposure = Exposure {
                shutter_s,
                iso: self.iso,
            };
            self.camera_op(id, "metering exposure", |c| c.set_exposure(exposure))?;
            let capture = self.camera_op(id, "metering capture", |c| c.capture_to(&path))?;
            self.log(
                Some(id),
                "meter",
                &format!("θL {theta_l:.1}° at {shutter_s} s"),
            )?;
            // Read like any capture (TIFF or camera raw, with its levels).
            let sidecar = sidecar_path(&capture.path);
            let frame = self
                .write_sidecar(&sidecar, capture.exposure, theta_l)
                .and_then(|()| Frame::read(&capture.path).map_err(|e| e.to_string()));
            // The metering frame is not part of the scan.
            let _ = std::fs::remove_file(&capture.path);
            let _ = std::fs::remove_file(&sidecar);
            let frame = frame.map_err(|e| failed(format!("reading the frame: {e}")))?;
            let metering = MeteringFrame {
                width: frame.width,
                height: frame.height,
                channels: 3,
                data: &frame.data,
                shutter_s: capture.exposure.shutter_s,
            };
            let region = strip_region(&setup, theta_l, &frame);
            match auto_bracket(&metering, &region, &allowed) {
                Ok(bracket) => {
                    let mut shutters = bracket.shutters_s.clone();
                    shutters.reverse();
                    let result = json!({
                        "shutter_s": shutters,
                        "metering_shutter_s": capture.exposure.shutter_s,
                        "clipped_at_shortest": bracket.clipped_at_shortest,
                        "dark_at_longest": bracket.dark_at_longest,
                    });
                    return Ok((result, ScanPlan::captures(theta_l, &shutters)));
                }
                Err(BracketError::MeteringClipped { .. }) => {
                    shutter_s = nearest_at_most(&allowed, shutter_s / 16.0)
                        .filter(|s| *s < shutter_s)
                        .ok_or_else(|| failed("clipped even at the shortest shutter".into()))?;
                }
                Err(err) => return Err(failed(err.to_string())),
            }
        }
        Err(failed(format!(
            "still clipped after {METER_ATTEMPTS} metering captures"
        )))
    }
}

/// Metering captures before giving up on a scene that clips.
const METER_ATTEMPTS: u32 = 4;

/// The longest of `allowed` (seconds) at most `target`, else the shortest allowed.
fn nearest_at_most(allowed: &[f64], target: f64) -> Option<f64> {
    let shortest = allowed.iter().copied().min_by(f64::total_cmp)?;
    Some(
        allowed
            .iter()
            .copied()
            .filter(|s| *s <= target * (1.0 + 1e-9))
            .max_by(f64::total_cmp)
            .unwrap_or(shortest),
    )
}

/// The rows (±2 around each strip's centre) and the cylinder's columns at θL that the
/// bracket must expose well in `frame`, with its levels.
fn strip_region(setup: &Setup, theta_l: f64, frame: &Frame) -> BracketRegion {
    let (width, height) = (frame.width, frame.height);
    let rows: Vec<usize> = [setup.sample_row, setup.white_row]
        .iter()
        .flat_map(|&centre| {
            let centre = centre as usize;
            centre.saturating_sub(2)..=centre + 2
        })
        .filter(|&r| r < height)
        .collect();
    let on_cylinder: Vec<usize> = column_angles(setup, theta_l)
        .iter()
        .enumerate()
        .filter_map(|(u, a)| a.map(|_| u))
        .filter(|&u| u < width)
        .collect();
    let columns = match (on_cylinder.first(), on_cylinder.last()) {
        (Some(&first), Some(&last)) => first..last + 1,
        _ => 0..width,
    };
    let span = (frame.white_level - frame.black_level).max(1.0);
    BracketRegion {
        rows,
        columns,
        black_level: frame.black_level,
        clip_level: frame.black_level + 0.95 * span,
        noise_floor: (0.01 * span).max(1.0),
    }
}
