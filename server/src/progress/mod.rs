//! What a scan's journal says beyond its step counts: the θL captured and processed,
//! the processing lane's current step, the live fits after each θL, and the time left
//! (docs/ARCHITECTURE.md, "Daemon"; server/src/daemon.md, "Time left").
//!
//! Time left: every step not done is given its prior from the [`Timing`] model at its
//! place in the scan (its bracket's frames, its θL's rank, the θL count), scaled by how
//! long the steps of its kind already done in this scan took against their priors (a
//! kind this scan has not measured yet, such as the fits at its end, by what it took in
//! the previous scan that ended done); a metering step not done brings the bracket the
//! scan last metered (or a typical one). Each model's fit is a kind of its own, the
//! automatic choice another, a θL's samples and HDR merge a third. A processing step
//! is measured by the time it would have taken with the cores to itself: the steps
//! that draw on the cores at once (the processing steps, and an emulated camera's
//! rendering) share them, each moment counted over their number. The lanes are then
//! played forward: hardware steps one after the other; the processing steps under way
//! each the rest of its expectation after the work it has done (measured as the done
//! steps are), the lane's own step
//! before the steps not begun, a step in the background (an HDR merge, the automatic
//! choice) beside them, sharing the cores with the lane's work (together they take the
//! sum of their times); each processing step not begun once the hardware steps before
//! it and the processing before it are done, at half speed while an emulated camera
//! renders. The estimate is when the last of them finishes, so processing that runs
//! beside the hardware counts only where it ends later.

mod calibration;
mod journal;

use serde::Serialize;
use serde_json::Value;
use time::OffsetDateTime;

use crate::plan::{Lane, Step};
use crate::store::{StepRecord, StepState};
use crate::timing::Timing;
use calibration::{Calibration, CoreRuns, Kind};
pub use journal::metered_bracket;
use journal::{arm_angles, elapsed_s, parse_time, places};

/// What a step that has run longer than expected is still given, as a share of the
/// time it has run: it is not about to end just because its prior said so.
const OVERRUN_SHARE: f64 = 0.25;

/// θL of a scan by how far their bracket got.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct ThetaProgress {
    /// Brackets captured.
    pub captured: usize,
    /// Brackets whose samples and HDR map are made.
    pub processed: usize,
    pub total: usize,
}

/// A scan's progress as its journal tells it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Progress {
    pub theta_l: ThetaProgress,
    /// The processing step under way, if any.
    pub processing_step: Option<String>,
    /// Estimated seconds until both lanes are done.
    pub eta_s: f64,
    /// The live fits after each θL (`live` of each done samples step), in order.
    pub live: Vec<Value>,
}

/// When work of `work_s` seconds (with the cores to itself) begun at `start_s` ends,
/// played forward beside the `rendering` (ascending, disjoint intervals of an emulated
/// camera rendering, seconds from now): it has `share` of the cores while a frame
/// renders.
fn share_cores(start_s: f64, work_s: f64, rendering: &[(f64, f64)], share: f64) -> f64 {
    let (mut at, mut left) = (start_s, work_s);
    for &(from, to) in rendering.iter().filter(|(_, to)| *to > start_s) {
        let alone = (from - at).max(0.0);
        if left <= alone {
            return at + left;
        }
        left -= alone;
        at = at.max(from);
        let shared = share * (to - at);
        if left <= shared {
            return at + left / share;
        }
        left -= shared;
        at = to;
    }
    at + left
}

/// Seconds still expected of work expected to take `expected_s` that has run for
/// `elapsed_s`; past its expectation, a share of the time it has run.
fn left_of(expected_s: f64, elapsed_s: f64) -> f64 {
    (expected_s - elapsed_s).max(OVERRUN_SHARE * elapsed_s.max(0.0))
}

/// The progress of a scan from its journal (`steps` in index order) at `now`;
/// `earlier` is the journal of the previous scan that ended done (or empty), whose
/// step times stand in for the kinds this scan has not measured yet.
pub fn progress(
    steps: &[StepRecord],
    earlier: &[StepRecord],
    timing: &Timing,
    now: OffsetDateTime,
) -> Progress {
    let from_deg = arm_angles(steps);
    let places = places(steps, timing);
    let (own, before) = (
        Calibration::of(steps, timing, now),
        Calibration::of(earlier, timing, now),
    );
    let scale = |step: &Step, prior_s: f64| {
        own.ratio(step)
            .or_else(|| before.ratio(step))
            .map_or(prior_s, |ratio| prior_s * ratio)
    };
    let capture_scale = |prior_s: f64| {
        let any_capture = Step::Capture {
            theta_l: 0.0,
            index: 0,
            shutter_s: 0.0,
        };
        scale(&any_capture, prior_s)
    };
    let mut bracket_s = capture_scale(timing.expected_bracket_s());
    // The hardware lane played forward: when each step would begin (counted from now),
    // and when an emulated camera would be rendering on the cores.
    let mut hardware_s = 0.0_f64;
    let mut hardware_before = Vec::with_capacity(steps.len());
    let mut rendering: Vec<(f64, f64)> = Vec::new();
    for ((record, &from), place) in steps.iter().zip(&from_deg).zip(&places) {
        hardware_before.push(hardware_s);
        if record.state == StepState::Done {
            if let Some(bracket) = metered_bracket(record) {
                bracket_s = capture_scale(bracket.iter().map(|&s| timing.capture_s(s)).sum());
            }
            continue;
        }
        if record.step.lane() != Lane::Hardware {
            continue;
        }
        let mut left_s = scale(&record.step, timing.prior_s(&record.step, from, place));
        let mut render_s = timing.render_s();
        if record.state == StepState::Started {
            let elapsed = elapsed_s(record, now);
            left_s = left_of(left_s, elapsed);
            render_s = (render_s - elapsed).max(0.0);
        }
        if timing.rendered {
            match record.step {
                // A metering step renders its frame and decodes it, then its bracket's
                // captures each render theirs.
                Step::Meter { .. } => {
                    rendering.push((hardware_s, hardware_s + left_s));
                    let frames = place.frames.max(1);
                    let each_s = bracket_s / frames as f64;
                    for frame in 0..frames {
                        let at = hardware_s + left_s + frame as f64 * each_s;
                        rendering.push((at, at + each_s.min(timing.render_s())));
                    }
                    left_s += bracket_s;
                }
                Step::Capture { .. } => {
                    rendering.push((hardware_s, hardware_s + left_s.min(render_s)));
                }
                _ => {}
            }
        } else if matches!(record.step, Step::Meter { .. }) {
            left_s += bracket_s;
        }
        hardware_s += left_s;
    }
    // The processing steps under way: each the rest of its expectation after the work
    // it has done, the time since it began with the cores it shared counted over the
    // steps sharing them (as the done steps are measured). The lane's own step comes
    // before the steps not begun; a step in the background (an HDR merge, the automatic
    // choice) goes on beside them, sharing the cores.
    let runs = CoreRuns::of(steps, timing, now);
    let (mut running_s, mut beside_s) = (0.0, 0.0_f64);
    for ((record, &from), place) in steps.iter().zip(&from_deg).zip(&places) {
        if record.state == StepState::Started && record.step.lane() == Lane::Processing {
            let expected = scale(&record.step, timing.prior_s(&record.step, from, place));
            let done_s = record
                .started
                .as_deref()
                .and_then(parse_time)
                .map_or(0.0, |started| runs.alone_s((started, now.max(started))));
            let left_s = left_of(expected, done_s);
            if record.step.runs_beside() {
                beside_s = beside_s.max(left_s);
            } else {
                running_s += left_s;
            }
        }
    }
    // Then each processing step not begun, once the hardware steps before it and the
    // processing before it are done; the lane shares the cores with the rendering.
    // `work_s`: the lane's work without its waits for the hardware.
    let mut work_s = running_s;
    let share = timing.processing_share_while_rendering();
    let mut processing_s = share_cores(0.0, running_s, &rendering, share);
    let mut parts: Vec<(Kind, f64)> = Vec::new();
    for (((record, &from), place), &after) in steps
        .iter()
        .zip(&from_deg)
        .zip(&places)
        .zip(&hardware_before)
    {
        if record.state == StepState::Pending && record.step.lane() == Lane::Processing {
            let left_s = scale(&record.step, timing.prior_s(&record.step, from, place));
            work_s += left_s;
            processing_s = share_cores(processing_s.max(after), left_s, &rendering, share);
            match parts
                .iter_mut()
                .find(|(kind, _)| *kind == Kind::of(&record.step))
            {
                Some(part) => part.1 += left_s,
                None => parts.push((Kind::of(&record.step), left_s)),
            }
        }
    }
    tracing::debug!(
        hardware_s,
        running_s,
        beside_s,
        processing_s,
        "time left: processing not started {parts:.2?}; measured/prior this scan {:.2?}, \
         the scan before {:.2?}",
        own.sums,
        before.sums
    );
    Progress {
        theta_l: theta_progress(steps),
        processing_step: steps
            .iter()
            .find(|s| s.step.lane() == Lane::Processing && s.state == StepState::Started)
            .map(|s| s.step.describe()),
        // A step in the background shares the cores with the lane's work: both use
        // every core, so together they take the sum of their times (the lane's waits
        // for the hardware leave the cores to it).
        eta_s: hardware_s.max(processing_s).max(work_s + beside_s),
        live: steps
            .iter()
            .filter(|s| s.state == StepState::Done && matches!(s.step, Step::Samples { .. }))
            .filter_map(|s| s.result.as_ref()?.get("live").cloned())
            .collect(),
    }
}

/// How many θL of the journal are captured and processed.
fn theta_progress(steps: &[StepRecord]) -> ThetaProgress {
    // (θL, every hardware step done, every step done), in plan order.
    let mut per_theta: Vec<(f64, bool, bool)> = Vec::new();
    for record in steps {
        let Some(theta_l) = record.step.theta_l() else {
            continue;
        };
        let index = match per_theta.iter().position(|(t, _, _)| *t == theta_l) {
            Some(index) => index,
            None => {
                per_theta.push((theta_l, true, true));
                per_theta.len() - 1
            }
        };
        if record.state != StepState::Done {
            let entry = &mut per_theta[index];
            entry.2 = false;
            if record.step.lane() == Lane::Hardware {
                entry.1 = false;
            }
        }
    }
    ThetaProgress {
        captured: per_theta.iter().filter(|t| t.1).count(),
        processed: per_theta.iter().filter(|t| t.2).count(),
        total: per_theta.len(),
    }
}

#[cfg(test)]
mod tests;
