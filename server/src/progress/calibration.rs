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
pub(super) type Run = (OffsetDateTime, OffsetDateTime);

/// What draws on this machine's cores: the runs of the processing steps (and of the
/// frames decoded ahead of an HDR step), and while an
/// emulated camera renders a frame (the first [`Timing::render_fraction`] of each
/// capture's seconds, a metering step whole: it renders, then decodes its frame), the
/// renderer's, which
/// leaves the processing lane [`Timing::processing_share_while_rendering`] of them.
pub(super) struct CoreRuns {
    processing: Vec<Run>,
    rendering: Vec<Run>,
    rendering_share: f64,
}

impl CoreRuns {
    /// The core users of `steps` (one scan's journal) at `now`.
    pub(super) fn of(steps: &[StepRecord], timing: &Timing, now: OffsetDateTime) -> Self {
        let mut runs = CoreRuns {
            processing: Vec::new(),
            rendering: Vec::new(),
            rendering_share: timing.processing_share_while_rendering(),
        };
        for r in steps {
            let Some(started) = r.started.as_deref().and_then(parse_time) else {
                continue;
            };
            let finished = match r.state {
                StepState::Done => match r.finished.as_deref().and_then(parse_time) {
                    Some(finished) => finished.max(started),
                    None => continue,
                },
                StepState::Started => now.max(started),
                StepState::Pending => continue,
            };
            match r.step {
                _ if r.step.lane() == Lane::Processing => {
                    runs.processing.push((started, finished));
                    runs.processing.extend(decoded_ahead(r));
                }
                Step::Meter { .. } if timing.rendered => runs.rendering.push((started, finished)),
                Step::Capture { shutter_s, .. } if timing.rendered => {
                    let rendering = (finished - started) * timing.render_fraction(&[shutter_s]);
                    runs.rendering.push((started, started + rendering));
                }
                _ => {}
            }
        }
        runs
    }

    /// The seconds of `run` a processing step would have taken with the cores to
    /// itself: each moment counted as its share of the lane's (all of the cores, or
    /// their share while a frame renders) over the processing steps under way then.
    pub(super) fn alone_s(&self, run: Run) -> f64 {
        let mut cuts: Vec<OffsetDateTime> = self
            .processing
            .iter()
            .chain(&self.rendering)
            .flat_map(|&(s, f)| [s, f])
            .filter(|t| (run.0..=run.1).contains(t))
            .chain([run.0, run.1])
            .collect();
        cuts.sort();
        cuts.dedup();
        let covering = |runs: &[Run], w: &[OffsetDateTime]| {
            runs.iter()
                .filter(|&&(s, f)| s <= w[0] && f >= w[1])
                .count()
        };
        cuts.windows(2)
            .map(|w| {
                let sharing = covering(&self.processing, w).max(1) as f64;
                let share = if covering(&self.rendering, w) > 0 {
                    self.rendering_share
                } else {
                    1.0
                };
                (w[1] - w[0]).as_seconds_f64() * share / sharing
            })
            .sum()
    }
}

/// When the frames an HDR step took were decoded ahead of it (its result's
/// `decoded_ahead`: the processing lane's work for the step before it began).
pub(super) fn decoded_ahead(record: &StepRecord) -> impl Iterator<Item = Run> + '_ {
    record
        .result
        .as_ref()
        .and_then(|r| r.get("decoded_ahead"))
        .and_then(|d| d.as_array())
        .into_iter()
        .flatten()
        .filter_map(|run| {
            let from = parse_time(run.get(0)?.as_str()?)?;
            let to = parse_time(run.get(1)?.as_str()?)?;
            Some((from, to.max(from)))
        })
}

/// Measured over prior seconds of the done steps of each kind.
#[derive(Default)]
pub(super) struct Calibration {
    pub(super) sums: HashMap<Kind, (f64, f64)>,
}

impl Calibration {
    /// What the done steps of `steps` (one scan's journal, at `now`) took against
    /// their priors: a hardware step its wall time, a processing step the time it
    /// would have taken with the cores to itself ([`CoreRuns::alone_s`]: beside other
    /// processing, or beside an emulated camera rendering, it had a share of them); a
    /// θL's samples and HDR steps only once both are done. `runs`: the journal's
    /// [`CoreRuns`].
    pub(super) fn of(steps: &[StepRecord], timing: &Timing, runs: &CoreRuns) -> Self {
        let mut calibration = Calibration::default();
        let places = places(steps, timing);
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
                Lane::Processing => {
                    runs.alone_s(run) + decoded_ahead(record).map(|r| runs.alone_s(r)).sum::<f64>()
                }
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
        self.ratio_of(Kind::of(step))
    }

    /// Measured over prior seconds of the steps of `kind`, if measured.
    pub(super) fn ratio_of(&self, kind: Kind) -> Option<f64> {
        match self.sums.get(&kind) {
            Some(&(measured, prior)) if prior > 0.0 => Some(measured / prior),
            _ => None,
        }
    }
}
