//! What a scan's done steps took against their priors: the measured-over-prior ratio of
//! each kind of step, a processing step counted by the time it would have taken with the
//! cores to itself.

use std::collections::HashMap;

use time::OffsetDateTime;

use super::journal::{arm_angles, parse_time, places};
use crate::plan::{Lane, Step, AUTO_FIT, FIT_MODELS};
use crate::store::{StepRecord, StepState};
use crate::timing::Timing;

/// The kinds of step whose measured times scale the priors of the others.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) enum Kind {
    Home,
    Move,
    Meter,
    Capture,
    /// A θL's samples and HDR merge.
    Theta,
    Extract,
    /// The fit of one model (fitting and the budget): its index in [`FIT_MODELS`]
    /// (their costs differ, and one model's time says little of another's).
    Fit(usize),
    /// The automatic choice among the models.
    Choice,
}

impl Kind {
    pub(super) fn of(step: &Step) -> Kind {
        match step {
            Step::Home => Kind::Home,
            Step::Move { .. } => Kind::Move,
            Step::Meter { .. } => Kind::Meter,
            Step::Capture { .. } => Kind::Capture,
            Step::Samples { .. } | Step::Hdr { .. } => Kind::Theta,
            Step::Extract => Kind::Extract,
            Step::Fit { model } if model == AUTO_FIT.0 => Kind::Choice,
            Step::Fit { model } => Kind::Fit(
                FIT_MODELS
                    .iter()
                    .position(|(name, _)| name == model)
                    .unwrap_or(FIT_MODELS.len()),
            ),
        }
    }
}

/// A step's run: when it began and ended (now for a step still under way).
type Run = (OffsetDateTime, OffsetDateTime);

/// The runs of the steps of `steps` that draw on this machine's cores: every
/// processing step started, and with an emulated camera (`rendered`) the captures and
/// metering steps, whose frames are rendered here.
pub(super) fn core_runs(steps: &[StepRecord], rendered: bool, now: OffsetDateTime) -> Vec<Run> {
    steps
        .iter()
        .filter(|r| {
            r.step.lane() == Lane::Processing
                || (rendered && matches!(r.step, Step::Capture { .. } | Step::Meter { .. }))
        })
        .filter_map(|r| {
            let started = r.started.as_deref().and_then(parse_time)?;
            let finished = match r.state {
                StepState::Done => r.finished.as_deref().and_then(parse_time)?,
                StepState::Started => now,
                StepState::Pending => return None,
            };
            Some((started, finished.max(started)))
        })
        .collect()
}

/// The seconds of `run` the step would have taken with the cores to itself: each
/// moment counted over the number of `runs` (itself among them) under way then, as
/// the steps running at once share the cores.
pub(super) fn alone_s(run: Run, runs: &[Run]) -> f64 {
    let mut cuts: Vec<OffsetDateTime> = runs
        .iter()
        .flat_map(|&(s, f)| [s, f])
        .filter(|t| (run.0..=run.1).contains(t))
        .chain([run.0, run.1])
        .collect();
    cuts.sort();
    cuts.dedup();
    cuts.windows(2)
        .map(|w| {
            let sharing = runs
                .iter()
                .filter(|&&(s, f)| s <= w[0] && f >= w[1])
                .count();
            (w[1] - w[0]).as_seconds_f64() / sharing.max(1) as f64
        })
        .sum()
}

/// Measured over prior seconds of the done steps of each kind.
#[derive(Default)]
pub(super) struct Calibration {
    pub(super) sums: HashMap<Kind, (f64, f64)>,
}

impl Calibration {
    /// What the done steps of `steps` (one scan's journal, at `now`) took against
    /// their priors: a hardware step its wall time, a processing step the time it
    /// would have taken with the cores to itself ([`alone_s`]: beside other
    /// processing, or beside an emulated camera rendering, it had a share of them); a
    /// θL's samples and HDR steps only once both are done.
    pub(super) fn of(steps: &[StepRecord], timing: &Timing, now: OffsetDateTime) -> Self {
        let mut calibration = Calibration::default();
        let places = places(steps, timing);
        let runs = core_runs(steps, timing.rendered, now);
        let unfinished: Vec<f64> = steps
            .iter()
            .filter(|r| Kind::of(&r.step) == Kind::Theta && r.state != StepState::Done)
            .filter_map(|r| r.step.theta_l())
            .collect();
        for ((record, from), place) in steps.iter().zip(arm_angles(steps)).zip(&places) {
            let theta_unfinished = Kind::of(&record.step) == Kind::Theta
                && record
                    .step
                    .theta_l()
                    .is_some_and(|t| unfinished.contains(&t));
            if record.state != StepState::Done || theta_unfinished {
                continue;
            }
            let started = record.started.as_deref().and_then(parse_time);
            let finished = record.finished.as_deref().and_then(parse_time);
            let (Some(started), Some(finished)) = (started, finished) else {
                continue;
            };
            let run = (started, finished.max(started));
            let measured = match record.step.lane() {
                Lane::Processing => alone_s(run, &runs),
                Lane::Hardware => (run.1 - run.0).as_seconds_f64(),
            };
            let sum = calibration.sums.entry(Kind::of(&record.step)).or_default();
            sum.0 += measured;
            sum.1 += timing.prior_s(&record.step, from, place);
        }
        calibration
    }

    /// Measured over prior seconds of `step`'s kind, if measured.
    pub(super) fn ratio(&self, step: &Step) -> Option<f64> {
        match self.sums.get(&Kind::of(step)) {
            Some(&(measured, prior)) if prior > 0.0 => Some(measured / prior),
            _ => None,
        }
    }
}
