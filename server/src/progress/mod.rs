//! What a scan's journal says beyond its step counts: the θL captured and processed,
//! the processing lane's current step, the live fits after each θL, and the time left
//! (docs/ARCHITECTURE.md, "Daemon"; server/src/daemon.md, "Time left").
//!
//! Time left: every step not done is given its prior from the [`Timing`] model at its
//! place in the scan (its bracket's frames, its θL's rank, the θL count), scaled by how
//! long the steps of its kind already done in this scan took against their priors (a
//! kind this scan has not measured yet, such as the fits at its end, by what it took in
//! the previous scan that ended done, else, for a processing kind, as far off its prior
//! as this scan's θL processing is: every processing prior is the same probe's measure
//! of this machine); a metering step not done brings the bracket the
//! scan last metered (or a typical one). Each model's fit is a kind of its own, the
//! automatic choice another, a θL's samples and HDR merge a third. A processing step
//! is measured by the time it would have taken with the cores to itself: the steps
//! that draw on the cores at once (the processing steps, and an emulated camera's
//! rendering, and frames decoded ahead of their HDR step) share them, each moment
//! counted over their number. The lanes are then played forward from now under the
//! daemon's own rules ([`play`]): each step under way the rest of its expectation after
//! the work it has done (measured as the done steps are), a bracket not metered yet
//! its captures as the bracket last metered; the estimate is when the last step ends.

mod calibration;
mod journal;
mod play;

use serde::Serialize;
use serde_json::Value;
use time::OffsetDateTime;

use crate::plan::{Lane, Step};
use crate::store::{StepRecord, StepState};
use crate::timing::{Timing, EXPECTED_BRACKET_S};
use calibration::{Calibration, CoreRuns, Kind};
pub use journal::metered_bracket;
use journal::{arm_angles, elapsed_s, parse_time, places};
use play::{play, Rules, Work};

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
    let runs = CoreRuns::of(steps, timing, now);
    let (own, before) = (
        Calibration::of(steps, timing, &runs),
        Calibration::of(earlier, timing, &CoreRuns::of(earlier, timing, now)),
    );
    // A processing kind measured neither in this scan nor in the one before (the fits
    // of a new data directory's first scan) is off its prior as this scan's θL
    // processing is: both priors are the timing probe's measures on this machine.
    let scale = |step: &Step, prior_s: f64| {
        own.ratio(step)
            .or_else(|| before.ratio(step))
            .or_else(|| {
                (step.lane() == Lane::Processing)
                    .then(|| own.ratio_of(Kind::Theta))
                    .flatten()
            })
            .map_or(prior_s, |ratio| prior_s * ratio)
    };
    let work = work_ahead(steps, timing, now, &runs, &scale);
    let rules = Rules {
        max_backlog: timing.max_backlog,
        share_while_rendering: timing.processing_share_while_rendering(),
    };
    let eta_s = play(&work, &rules);
    tracing::debug!(
        eta_s,
        "time left: measured/prior this scan {:.2?}, the scan before {:.2?}",
        own.sums,
        before.sums
    );
    Progress {
        theta_l: theta_progress(steps),
        processing_step: steps
            .iter()
            .find(|s| s.step.lane() == Lane::Processing && s.state == StepState::Started)
            .map(|s| s.step.describe()),
        eta_s,
        live: steps
            .iter()
            .filter(|s| s.state == StepState::Done && matches!(s.step, Step::Samples { .. }))
            .filter_map(|s| s.result.as_ref()?.get("live").cloned())
            .collect(),
    }
}

/// The steps of `steps` (one scan's journal) not done at `now`, as the play runs them:
/// each its prior at its place, scaled by `scale` (step, prior seconds → expected
/// seconds); one under way the rest of it after the time it has run (a processing step:
/// the work it has done, measured as the done steps are); a metering step not done
/// followed by its bracket's captures. `runs`: the journal's [`CoreRuns`] at `now`.
fn work_ahead(
    steps: &[StepRecord],
    timing: &Timing,
    now: OffsetDateTime,
    runs: &CoreRuns,
    scale: &dyn Fn(&Step, f64) -> f64,
) -> Vec<Work> {
    let capture_scale = |prior_s: f64| {
        let any_capture = Step::Capture {
            theta_l: 0.0,
            index: 0,
            shutter_s: 0.0,
        };
        scale(&any_capture, prior_s)
    };
    let mut bracket_s = capture_scale(timing.expected_bracket_s());
    let mut bracket_rendering = timing.render_fraction(&EXPECTED_BRACKET_S);
    let from_deg = arm_angles(steps);
    let places = places(steps, timing);
    let mut work: Vec<Work> = Vec::with_capacity(steps.len());
    for ((record, &from), place) in steps.iter().zip(&from_deg).zip(&places) {
        if record.state == StepState::Done {
            if let Some(bracket) = metered_bracket(record) {
                bracket_s = capture_scale(bracket.iter().map(|&s| timing.capture_s(s)).sum());
                bracket_rendering = timing.render_fraction(&bracket);
            }
            continue;
        }
        let expected = scale(&record.step, timing.prior_s(&record.step, from, place));
        let started = record.state == StepState::Started;
        let mut item = Work {
            step: record.step.clone(),
            left_s: expected,
            render_s: 0.0,
            started,
            decode_s_per_frame: 0.0,
            captured: 0,
        };
        match record.step.lane() {
            Lane::Hardware => {
                let elapsed = if started { elapsed_s(record, now) } else { 0.0 };
                item.left_s = left_of(expected, elapsed);
                item.render_s = match record.step {
                    // A metering step renders its frame, then decodes it.
                    Step::Meter { .. } if timing.rendered => item.left_s,
                    Step::Capture { shutter_s, .. } => {
                        (expected * timing.render_fraction(&[shutter_s]) - elapsed).max(0.0)
                    }
                    _ => 0.0,
                };
            }
            Lane::Processing => {
                if started {
                    let done_s = record
                        .started
                        .as_deref()
                        .and_then(parse_time)
                        .map_or(0.0, |started| runs.alone_s((started, now.max(started))));
                    item.left_s = left_of(expected, done_s);
                }
                if let Step::Hdr { theta_l } = record.step {
                    item.decode_s_per_frame = scale(&record.step, timing.decode_s());
                    item.captured = steps
                        .iter()
                        .filter(|r| r.state == StepState::Done)
                        .filter(
                            |r| matches!(r.step, Step::Capture { theta_l: t, .. } if t == theta_l),
                        )
                        .count();
                }
            }
        }
        work.push(item);
        // A bracket not metered yet: its captures (journalled once it is), each a share
        // of the bracket the scan last metered.
        if let Step::Meter { theta_l } = record.step {
            let frames = place.frames.max(1);
            let each_s = bracket_s / frames as f64;
            for index in 0..frames {
                work.push(Work {
                    step: Step::Capture {
                        theta_l,
                        index,
                        shutter_s: 0.0,
                    },
                    left_s: each_s,
                    render_s: each_s * bracket_rendering,
                    started: false,
                    decode_s_per_frame: 0.0,
                    captured: 0,
                });
            }
        }
    }
    work
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
