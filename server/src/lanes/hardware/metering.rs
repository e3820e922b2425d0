//! Metering θL for an automatic bracket: a capture at a middle shutter (shortened
//! while the strips clip), read like any capture, and the fewest allowed shutters that
//! expose every pixel of the strips well.

use std::path::Path;

use gonio_drivers::bracket::{auto_bracket, Bracket, BracketError, BracketRegion, MeteringFrame};
use gonio_drivers::Exposure;
use gonio_processing::capture::{sidecar_path, Frame};
use gonio_processing::geometry::{column_angles, Setup};
use serde_json::json;

use super::HardwareLane;
use crate::lanes::step::{Outcome, StepError};
use crate::plan::{theta_dir_name, ScanPlan};
use crate::timing::METER_START_S;

impl HardwareLane {
    /// Meters θL and plans its bracket ([`plan_bracket`]) from the camera's captures,
    /// each read like any capture (TIFF or camera raw, with its levels).
    pub(super) fn meter(&mut self, id: i64, theta_l: f64) -> Outcome {
        // The scan's own setup (written when it started), whatever was calibrated since.
        let own =
            gonio_processing::extract::read_setup(&self.shared.scan_dir(id).join("setup.json"));
        let setup = own.ok().or_else(|| self.setup()).ok_or_else(|| {
            StepError::Failed("an automatic bracket needs the setup geometry ([setup])".into())
        })?;
        let allowed = self.allowed_s.clone();
        self.place_for_capture(id, theta_l)?;
        let path = self
            .shared
            .config
            .data_dir
            .join("metering")
            .join(format!("scan-{id}-{}.tiff", theta_dir_name(theta_l)));
        std::fs::create_dir_all(path.parent().unwrap_or(Path::new(".")))
            .map_err(|e| metering_failed(theta_l, e.to_string()))?;
        let (bracket, metering_shutter_s) = plan_bracket(&setup, theta_l, &allowed, |shutter_s| {
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
            let sidecar = sidecar_path(&capture.path);
            let frame = self
                .write_sidecar(&sidecar, capture.exposure, theta_l)
                .and_then(|()| Frame::read(&capture.path).map_err(|e| e.to_string()));
            // The metering frame is not part of the scan.
            let _ = std::fs::remove_file(&capture.path);
            let _ = std::fs::remove_file(&sidecar);
            let frame =
                frame.map_err(|e| metering_failed(theta_l, format!("reading the frame: {e}")))?;
            Ok(Metered {
                width: frame.width,
                height: frame.height,
                data: frame.data,
                black_level: frame.black_level,
                white_level: frame.white_level,
                shutter_s: capture.exposure.shutter_s,
            })
        })?;
        let mut shutters = bracket.shutters_s.clone();
        shutters.reverse();
        let result = json!({
            "shutter_s": shutters,
            "metering_shutter_s": metering_shutter_s,
            "clipped_at_shortest": bracket.clipped_at_shortest,
            "dark_at_longest": bracket.dark_at_longest,
        });
        Ok((result, ScanPlan::captures(theta_l, &shutters)))
    }
}

/// Metering captures before giving up on a scene that clips.
const METER_ATTEMPTS: u32 = 4;

/// One metering capture: RGB-interleaved values, row-major, with the frame's levels
/// (in the values' units) and the shutter it was taken at (seconds).
pub(crate) struct Metered {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u16>,
    pub black_level: f64,
    pub white_level: f64,
    pub shutter_s: f64,
}

fn metering_failed(theta_l: f64, what: String) -> StepError {
    StepError::Failed(format!("metering θL {theta_l:.1}°: {what}"))
}

/// θL's bracket from metering captures taken by `capture(shutter_s)`: the first at the
/// longest allowed shutter at most [`METER_START_S`], each next 16× shorter while the
/// strips clip (at most [`METER_ATTEMPTS`]); then the fewest of `allowed` (seconds)
/// that expose every strip pixel well ([`auto_bracket`]). Returns the bracket and the
/// shutter of the capture it was planned from.
pub(crate) fn plan_bracket(
    setup: &Setup,
    theta_l: f64,
    allowed: &[f64],
    mut capture: impl FnMut(f64) -> Result<Metered, StepError>,
) -> Result<(Bracket, f64), StepError> {
    let Some(mut shutter_s) = nearest_at_most(allowed, METER_START_S) else {
        return Err(StepError::Failed(
            "the camera reported no shutter speeds to meter with".into(),
        ));
    };
    for _ in 0..METER_ATTEMPTS {
        let metered = capture(shutter_s)?;
        let frame = MeteringFrame {
            width: metered.width,
            height: metered.height,
            channels: 3,
            data: &metered.data,
            shutter_s: metered.shutter_s,
        };
        let region = strip_region(setup, theta_l, &metered);
        match auto_bracket(&frame, &region, allowed) {
            Ok(bracket) => return Ok((bracket, metered.shutter_s)),
            Err(BracketError::MeteringClipped { .. }) => {
                shutter_s = nearest_at_most(allowed, shutter_s / 16.0)
                    .filter(|s| *s < shutter_s)
                    .ok_or_else(|| {
                        metering_failed(theta_l, "clipped even at the shortest shutter".into())
                    })?;
            }
            Err(err) => return Err(metering_failed(theta_l, err.to_string())),
        }
    }
    Err(metering_failed(
        theta_l,
        format!("still clipped after {METER_ATTEMPTS} metering captures"),
    ))
}

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
fn strip_region(setup: &Setup, theta_l: f64, frame: &Metered) -> BracketRegion {
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

#[cfg(test)]
mod tests {
    use gonio_mock_hw::camera::SHUTTER_SPEEDS_S;
    use gonio_mock_hw::render::{file_levels, render_frame};
    use gonio_mock_hw::scene::Scene;

    use super::*;
    use crate::devices::SceneFacts;
    use crate::timing::EXPECTED_BRACKET_S;

    /// Binned for speed: a pixel's rate, and so the bracket, does not depend on the
    /// binning (the full-size scenes meter to the same brackets through the daemon).
    const BINNING: u32 = 4;

    /// The median of `values` (the upper one of an even count).
    fn upper_median(values: &mut [f64]) -> f64 {
        values.sort_by(f64::total_cmp);
        values[values.len() / 2]
    }

    /// The bracket assumed before a θL is metered is the typical one of the example
    /// scenes: every built-in scene metered (as the lane does, through the emulated
    /// camera's rendering and shutter list) at each θL of its own scan; the frame count
    /// and each frame's shutter are the medians over those brackets (of that count).
    #[test]
    fn the_expected_bracket_is_the_example_scenes_median() {
        let mut brackets = Vec::new();
        for name in Scene::BUILTIN {
            let scene = Scene::builtin(name).unwrap().binned(BINNING).unwrap();
            let setup = SceneFacts::of(&scene).unwrap().setup;
            let levels = file_levels(&scene);
            for &theta_l in scene.theta_l_deg() {
                let (bracket, _) = plan_bracket(&setup, theta_l, &SHUTTER_SPEEDS_S, |shutter_s| {
                    let frame = render_frame(&scene, theta_l, shutter_s);
                    Ok(Metered {
                        width: frame.width() as usize,
                        height: frame.height() as usize,
                        data: frame.stored(),
                        black_level: f64::from(levels.black_level),
                        white_level: f64::from(levels.white_level),
                        shutter_s,
                    })
                })
                .unwrap();
                eprintln!("{name} θL {theta_l}: {:?}", bracket.shutters_s);
                brackets.push(bracket.shutters_s);
            }
        }
        let mut counts: Vec<f64> = brackets.iter().map(|b| b.len() as f64).collect();
        let frames = upper_median(&mut counts) as usize;
        // Longest first, as the metering step plans them.
        let typical: Vec<f64> = (0..frames)
            .map(|i| {
                let mut shutters: Vec<f64> = brackets
                    .iter()
                    .filter(|b| b.len() == frames)
                    .map(|b| b[frames - 1 - i])
                    .collect();
                upper_median(&mut shutters)
            })
            .collect();
        assert_eq!(typical, EXPECTED_BRACKET_S, "{brackets:?}");
    }
}
