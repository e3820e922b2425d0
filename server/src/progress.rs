//! What a scan's journal says beyond its step counts: the θL captured and processed,
//! the processing lane's current step, the live fits after each θL, and the time left
//! (docs/ARCHITECTURE.md, "Daemon"; server/src/daemon.md, "Time left").
//!
//! Time left: every step not done is given its prior from the [`Timing`] model at its
//! place in the scan (its bracket's frames, its θL's rank, the θL count), scaled by how
//! long the steps of its kind already done in this scan took against their priors (a
//! kind this scan has not measured yet, such as the fits at its end, by what it took in
//! the previous scan that ended done); a metering step not done brings the bracket the
//! scan last metered (or a typical one). The fits of one model each are one kind, the
//! automatic choice another, a θL's samples and HDR merge a third. A processing step
//! is measured by the time it would have taken with the cores to itself: the steps
//! that draw on the cores at once (the processing steps, and an emulated camera's
//! rendering) share them, each moment counted over their number. The lanes are then
//! played forward: hardware steps one after the other; the processing steps under way
//! each the rest of its expectation after the time since it began, the lane's own step
//! before the steps not begun, a step in the background (an HDR merge, the automatic
//! choice) beside them, sharing the cores with the lane's work (together they take the
//! sum of their times); each processing step not begun once the hardware steps before
//! it and the processing before it are done, at half speed while an emulated camera
//! renders. The estimate is when the last of them finishes, so processing that runs
//! beside the hardware counts only where it ends later.

use std::collections::HashMap;

use serde::Serialize;
use serde_json::Value;
use time::OffsetDateTime;

use super::plan::{Lane, Step, AUTO_FIT};
use super::store::{StepRecord, StepState};
use super::timing::{Place, Timing};

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

/// Parses a journal time (RFC 3339).
fn parse_time(text: &str) -> Option<OffsetDateTime> {
    OffsetDateTime::parse(text, &time::format_description::well_known::Rfc3339).ok()
}

/// The kinds of step whose measured times scale the priors of the others.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum Kind {
    Home,
    Move,
    Meter,
    Capture,
    /// A θL's samples and HDR merge.
    Theta,
    Extract,
    /// The fits of one model each (fitting and the budget).
    Fit,
    /// The automatic choice among the models.
    Choice,
}

impl Kind {
    fn of(step: &Step) -> Kind {
        match step {
            Step::Home => Kind::Home,
            Step::Move { .. } => Kind::Move,
            Step::Meter { .. } => Kind::Meter,
            Step::Capture { .. } => Kind::Capture,
            Step::Samples { .. } | Step::Hdr { .. } => Kind::Theta,
            Step::Extract => Kind::Extract,
            Step::Fit { model } if model == AUTO_FIT.0 => Kind::Choice,
            Step::Fit { .. } => Kind::Fit,
        }
    }
}

/// A step's run: when it began and ended (now for a step still under way).
type Run = (OffsetDateTime, OffsetDateTime);

/// The runs of the steps of `steps` that draw on this machine's cores: every
/// processing step started, and with an emulated camera (`rendered`) the captures and
/// metering steps, whose frames are rendered here.
fn core_runs(steps: &[StepRecord], rendered: bool, now: OffsetDateTime) -> Vec<Run> {
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
fn alone_s(run: Run, runs: &[Run]) -> f64 {
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
struct Calibration {
    sums: HashMap<Kind, (f64, f64)>,
}

impl Calibration {
    /// What the done steps of `steps` (one scan's journal, at `now`) took against
    /// their priors: a hardware step its wall time, a processing step the time it
    /// would have taken with the cores to itself ([`alone_s`]: beside other
    /// processing, or beside an emulated camera rendering, it had a share of them); a
    /// θL's samples and HDR steps only once both are done.
    fn of(steps: &[StepRecord], timing: &Timing, now: OffsetDateTime) -> Self {
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
    fn ratio(&self, step: &Step) -> Option<f64> {
        match self.sums.get(&Kind::of(step)) {
            Some(&(measured, prior)) if prior > 0.0 => Some(measured / prior),
            _ => None,
        }
    }
}

/// The arm's angle before each step of `steps`, walking the plan (home is θL 0).
fn arm_angles(steps: &[StepRecord]) -> Vec<f64> {
    let mut from_deg = Vec::with_capacity(steps.len());
    let mut at = 0.0;
    for record in steps {
        from_deg.push(at);
        match record.step {
            Step::Home => at = 0.0,
            Step::Move { theta_l } => at = theta_l,
            _ => {}
        }
    }
    from_deg
}

/// Each step's place in its scan: the θL count, its θL's rank in acquisition order,
/// the frames of its bracket (the captures journalled for it, else those of the
/// bracket the scan last metered, else a typical bracket's).
fn places(steps: &[StepRecord], timing: &Timing) -> Vec<Place> {
    let mut thetas: Vec<(f64, usize)> = Vec::new();
    for record in steps {
        let Some(theta_l) = record.step.theta_l() else {
            continue;
        };
        let index = match thetas.iter().position(|(t, _)| *t == theta_l) {
            Some(index) => index,
            None => {
                thetas.push((theta_l, 0));
                thetas.len() - 1
            }
        };
        if matches!(record.step, Step::Capture { .. }) {
            thetas[index].1 += 1;
        }
    }
    let metered = steps
        .iter()
        .rev()
        .filter(|r| r.state == StepState::Done)
        .find_map(metered_bracket)
        .map_or(timing.expected_frames(), |bracket| bracket.len());
    steps
        .iter()
        .map(|record| {
            let rank = record
                .step
                .theta_l()
                .and_then(|t| thetas.iter().position(|(theta, _)| *theta == t));
            let frames = rank.map_or(0, |i| thetas[i].1);
            Place {
                theta_count: thetas.len(),
                theta_rank: rank.map_or(thetas.len(), |i| i + 1),
                frames: if frames > 0 { frames } else { metered },
            }
        })
        .collect()
}

/// The shutter times a done metering step planned (its result's `shutter_s`).
pub fn metered_bracket(record: &StepRecord) -> Option<Vec<f64>> {
    let list = record.result.as_ref()?.get("shutter_s")?.as_array()?;
    list.iter().map(Value::as_f64).collect()
}

/// When work of `work_s` seconds (with the cores to itself) begun at `start_s` ends,
/// played forward beside the `rendering` (ascending, disjoint intervals of an emulated
/// camera rendering, seconds from now): it has half the cores while a frame renders.
fn share_cores(start_s: f64, work_s: f64, rendering: &[(f64, f64)]) -> f64 {
    let (mut at, mut left) = (start_s, work_s);
    for &(from, to) in rendering.iter().filter(|(_, to)| *to > start_s) {
        let alone = (from - at).max(0.0);
        if left <= alone {
            return at + left;
        }
        left -= alone;
        at = at.max(from);
        let shared = 0.5 * (to - at);
        if left <= shared {
            return at + 2.0 * left;
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

/// Seconds since a started step began (0 if its time does not parse).
fn elapsed_s(record: &StepRecord, now: OffsetDateTime) -> f64 {
    record
        .started
        .as_deref()
        .and_then(parse_time)
        .map_or(0.0, |started| (now - started).as_seconds_f64())
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
        if record.state == StepState::Started {
            left_s = left_of(left_s, elapsed_s(record, now));
        }
        if matches!(record.step, Step::Meter { .. }) {
            left_s += bracket_s;
        }
        let renders = matches!(record.step, Step::Capture { .. } | Step::Meter { .. });
        if timing.rendered && renders {
            rendering.push((hardware_s, hardware_s + left_s));
        }
        hardware_s += left_s;
    }
    // The processing steps under way: each the rest of its expectation after the time
    // since it began (what share of the cores it has had is not known before it ends:
    // a step that does not use every core loses little beside others). The lane's own
    // step comes before the steps not begun; a step in the background (an HDR merge,
    // the automatic choice) goes on beside them, sharing the cores.
    let (mut running_s, mut beside_s) = (0.0, 0.0_f64);
    for ((record, &from), place) in steps.iter().zip(&from_deg).zip(&places) {
        if record.state == StepState::Started && record.step.lane() == Lane::Processing {
            let expected = scale(&record.step, timing.prior_s(&record.step, from, place));
            let left_s = left_of(expected, elapsed_s(record, now));
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
    let mut processing_s = share_cores(0.0, running_s, &rendering);
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
            processing_s = share_cores(processing_s.max(after), left_s, &rendering);
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
mod tests {
    use super::*;
    use crate::plan::{ScanPlan, FIT_MODELS};
    use serde_json::json;
    use time::Duration;

    /// Real-time devices.
    fn timing() -> Timing {
        Timing::real()
    }

    fn at(t0: OffsetDateTime, seconds: f64) -> Option<String> {
        let t = t0 + Duration::seconds_f64(seconds);
        t.format(&time::format_description::well_known::Rfc3339)
            .ok()
    }

    /// The journal of `plan` with its first `done` steps done, each taking `took(step)`
    /// seconds back to back from `t0`.
    fn journal(
        plan: &ScanPlan,
        done: usize,
        t0: OffsetDateTime,
        took: impl Fn(&Step) -> f64,
    ) -> Vec<StepRecord> {
        let mut t = 0.0;
        (0u32..)
            .zip(plan.steps())
            .map(|(index, step)| {
                let mut record = StepRecord {
                    index: index * 1000,
                    step,
                    state: StepState::Pending,
                    started: None,
                    finished: None,
                    result: None,
                };
                if (index as usize) < done {
                    let d = took(&record.step);
                    record.state = StepState::Done;
                    record.started = at(t0, t);
                    record.finished = at(t0, t + d);
                    t += d;
                }
                record
            })
            .collect()
    }

    fn plan(auto: bool) -> ScanPlan {
        ScanPlan {
            sample: "gold".into(),
            theta_l: vec![-20.0, -25.0, -30.0],
            shutter_s: if auto { vec![] } else { vec![0.5, 0.05] },
            auto_bracket: auto,
        }
    }

    /// The prior of `step` in a scan of `thetas` θL with 2-frame brackets, at θL rank
    /// `rank`.
    fn prior(timing: &Timing, step: &Step, from: f64, thetas: usize, rank: usize) -> f64 {
        let place = Place {
            theta_count: thetas,
            theta_rank: rank,
            frames: 2,
        };
        timing.prior_s(step, from, &place)
    }

    #[test]
    fn time_left_plays_both_lanes_forward_and_learns_from_done_steps() {
        let timing = timing();
        let now = OffsetDateTime::now_utc();
        let fixed = plan(false);
        let fresh = journal(&fixed, 0, now, |_| 0.0);
        let full = progress(&fresh, &[], &timing, now);
        // Nothing done: each θL's processing once its bracket is captured and the
        // processing before it is done, then the extraction and the fits.
        let (mut hardware, mut processing, mut from) = (0.0_f64, 0.0_f64, 0.0);
        hardware += prior(&timing, &Step::Home, 0.0, 3, 3);
        for (rank, &theta_l) in fixed.theta_l.iter().enumerate() {
            hardware += prior(&timing, &Step::Move { theta_l }, from, 3, rank + 1);
            from = theta_l;
            for &shutter_s in &fixed.shutter_s {
                hardware += timing.capture_s(shutter_s);
            }
            processing = processing.max(hardware)
                + prior(&timing, &Step::Samples { theta_l }, 0.0, 3, rank + 1)
                + prior(&timing, &Step::Hdr { theta_l }, 0.0, 3, rank + 1);
        }
        processing += prior(&timing, &Step::Extract, 0.0, 3, 3);
        for (model, _) in FIT_MODELS.iter().chain([&AUTO_FIT]) {
            let fit = Step::Fit {
                model: (*model).into(),
            };
            processing += prior(&timing, &fit, 0.0, 3, 3);
        }
        let expected = hardware.max(processing);
        assert!(
            (full.eta_s - expected).abs() < 1e-9,
            "{full:?} vs {expected}"
        );
        assert_eq!(
            full.theta_l,
            ThetaProgress {
                captured: 0,
                processed: 0,
                total: 3
            }
        );
        // Captures that took twice their prior make the remaining ones count double.
        let slow = |step: &Step| match step {
            Step::Capture { shutter_s, .. } => 2.0 * timing.capture_s(*shutter_s),
            _ => 0.01,
        };
        let first_theta = journal(&fixed, 4, now - Duration::seconds(60), slow);
        let later = progress(&first_theta, &[], &timing, now);
        let captures_left = 4.0 * (timing.capture_s(0.5) + timing.capture_s(0.05)) / 2.0;
        assert!(later.eta_s > 2.0 * captures_left, "{later:?}");
        assert_eq!(later.theta_l.captured, 1);
        let end = journal(&fixed, fixed.steps().len(), now, |_| 0.1);
        assert_eq!(progress(&end, &[], &timing, now).eta_s, 0.0);
        assert_eq!(progress(&end, &[], &timing, now).theta_l.processed, 3);
    }

    #[test]
    fn a_theta_s_processing_is_measured_by_the_time_the_lane_was_busy() {
        let timing = timing();
        let now = OffsetDateTime::now_utc();
        let fixed = plan(false);
        // θL −20 captured, its samples (4 s) and HDR merge (6 s) run side by side.
        let mut steps = journal(&fixed, 4, now - Duration::seconds(60), |_| 0.5);
        let t0 = now - Duration::seconds(20);
        for (record, took) in steps[4..6].iter_mut().zip([4.0, 6.0]) {
            record.state = StepState::Done;
            record.started = at(t0, 0.0);
            record.finished = at(t0, took);
        }
        let own = Calibration::of(&steps, &timing, now);
        let priors =
            prior(&timing, &steps[4].step, 0.0, 3, 1) + prior(&timing, &steps[5].step, 0.0, 3, 1);
        let ratio = own.ratio(&Step::Hdr { theta_l: -25.0 }).unwrap();
        assert!(
            (ratio - 6.0 / priors).abs() < 1e-9,
            "{ratio} vs {}",
            6.0 / priors
        );
        // While its merge still runs, a θL's samples alone say nothing.
        steps[5].state = StepState::Started;
        assert_eq!(
            Calibration::of(&steps, &timing, now).ratio(&steps[4].step),
            None
        );
    }

    #[test]
    fn processing_shares_the_cores_with_an_emulated_camera_s_rendering() {
        let now = OffsetDateTime::now_utc();
        let fixed = plan(false);
        // θL −20 captured; its samples step ran 4 s, the first 2 s beside the capture
        // of θL −25's first frame, which an emulated camera renders on the cores.
        let mut steps = journal(&fixed, 4, now - Duration::seconds(60), |_| 0.5);
        let t0 = now - Duration::seconds(20);
        let timed = |record: &mut StepRecord, from: f64, to: f64| {
            record.state = StepState::Done;
            record.started = at(t0, from);
            record.finished = at(t0, to);
        };
        timed(&mut steps[4], 0.0, 4.0);
        timed(&mut steps[5], 4.0, 5.0);
        let capture = steps
            .iter()
            .position(|r| matches!(r.step, Step::Capture { theta_l, .. } if theta_l == -25.0))
            .unwrap();
        timed(&mut steps[capture], 0.0, 2.0);
        let rendered = Timing {
            rendered: true,
            ..timing()
        };
        let runs = core_runs(&steps, true, now);
        let samples = (
            parse_time(&at(t0, 0.0).unwrap()).unwrap(),
            parse_time(&at(t0, 4.0).unwrap()).unwrap(),
        );
        assert!((alone_s(samples, &runs) - 3.0).abs() < 1e-6);
        // A real camera renders nothing here: the step had the cores to itself.
        assert!((alone_s(samples, &core_runs(&steps, false, now)) - 4.0).abs() < 1e-6);
        let priors = prior(&rendered, &steps[4].step, 0.0, 3, 1)
            + prior(&rendered, &steps[5].step, 0.0, 3, 1);
        let ratio = Calibration::of(&steps, &rendered, now)
            .ratio(&Step::Samples { theta_l: -30.0 })
            .unwrap();
        assert!(
            (ratio - 4.0 / priors).abs() < 1e-9,
            "{ratio} vs {}",
            4.0 / priors
        );
        // Played forward, work has half the cores while a frame renders.
        assert_eq!(share_cores(0.0, 3.0, &[(1.0, 3.0)]), 4.0);
        assert_eq!(share_cores(0.0, 0.5, &[(1.0, 3.0)]), 0.5);
        assert_eq!(share_cores(2.0, 0.5, &[(1.0, 3.0)]), 3.0);
        assert_eq!(share_cores(5.0, 1.0, &[(1.0, 3.0)]), 6.0);
    }

    #[test]
    fn a_step_in_the_background_shares_the_cores_with_the_lane_s_steps() {
        let timing = timing();
        let now = OffsetDateTime::now_utc();
        let fixed = plan(false);
        let all = fixed.steps();
        let last_hdr = all
            .iter()
            .rposition(|s| matches!(s, Step::Hdr { .. }))
            .unwrap();
        // Every step before the last θL's merge done; the merge began a second ago,
        // the gathering and the fits wait.
        let mut steps = journal(&fixed, last_hdr, now - Duration::seconds(60), |_| 0.1);
        steps[last_hdr].state = StepState::Started;
        steps[last_hdr].started = at(now, -1.0);
        let hdr_left = prior(&timing, &steps[last_hdr].step, 0.0, 3, 3) - 1.0;
        let chain: f64 = steps[last_hdr + 1..]
            .iter()
            .map(|r| prior(&timing, &r.step, 0.0, 3, 3))
            .sum();
        // The chain, then the merge's rest (its prior scaled by the scan's measured
        // steps, less the second it has run) on top: the two share the cores.
        let left = progress(&steps, &[], &timing, now).eta_s;
        assert!(
            left > chain + 0.1 && left <= chain + hdr_left,
            "{left} vs {hdr_left} and {chain}"
        );
    }

    #[test]
    fn a_step_past_its_expectation_is_never_counted_as_ending_now() {
        let timing = timing();
        let now = OffsetDateTime::now_utc();
        let fixed = plan(false);
        let last = fixed.steps().len() - 1;
        let mut steps = journal(&fixed, last, now - Duration::seconds(600), |_| 0.1);
        // The auto fit has run for 100 s, far past its prior.
        let fit = &mut steps[last];
        assert!(matches!(&fit.step, Step::Fit { model } if model == AUTO_FIT.0));
        fit.state = StepState::Started;
        fit.started = at(now, -100.0);
        let left = progress(&steps, &[], &timing, now).eta_s;
        assert!((left - OVERRUN_SHARE * 100.0).abs() < 1e-6, "{left}");
        // Within its expectation it counts down.
        assert_eq!(left_of(10.0, 4.0), 6.0);
    }

    #[test]
    fn kinds_not_measured_yet_take_the_earlier_scan_s_times() {
        let timing = timing();
        let now = OffsetDateTime::now_utc();
        let fixed = plan(false);
        let fresh = journal(&fixed, 0, now, |_| 0.0);
        let alone = progress(&fresh, &[], &timing, now).eta_s;
        // An earlier scan whose fits each took 20 s (only its fits count here).
        let fit_s = 20.0;
        let slow_fits = |step: &Step| match step {
            Step::Fit { .. } => fit_s,
            _ => 0.1,
        };
        let mut earlier = journal(
            &fixed,
            fixed.steps().len(),
            now - Duration::hours(1),
            slow_fits,
        );
        for record in &mut earlier {
            if !matches!(record.step, Step::Fit { .. }) {
                record.state = StepState::Pending;
            }
        }
        let informed = progress(&fresh, &earlier, &timing, now).eta_s;
        let fits: Vec<Step> = FIT_MODELS
            .iter()
            .chain([&AUTO_FIT])
            .map(|(model, _)| Step::Fit {
                model: (*model).into(),
            })
            .collect();
        let fit_priors: f64 = fits.iter().map(|f| prior(&timing, f, 0.0, 3, 3)).sum();
        // The fits end the scan: they count as the earlier scan measured them, at its
        // ratio of measured to prior seconds.
        let ratio = fits.len() as f64 * fit_s / fit_priors;
        assert!(
            (informed - (alone + fit_priors * (ratio - 1.0))).abs() < 1e-6,
            "{informed} vs {alone}"
        );
        // What this scan measured itself wins over the earlier scan: its third fit is
        // expected to take what its first two took against their priors; the
        // automatic choice, a kind of its own, what the earlier scan's took.
        let own = journal(
            &fixed,
            fixed.steps().len() - 2,
            now - Duration::seconds(30),
            |s| match s {
                Step::Fit { .. } => 1.0,
                _ => 0.1,
            },
        );
        let done_priors: f64 = fits[..2].iter().map(|f| prior(&timing, f, 0.0, 3, 3)).sum();
        let left = progress(&own, &earlier, &timing, now).eta_s;
        let expected = prior(&timing, &fits[2], 0.0, 3, 3) * 2.0 / done_priors + fit_s;
        assert!((left - expected).abs() < 1e-6, "{left} vs {expected}");
    }

    #[test]
    fn metered_brackets_and_live_fits_come_from_step_results() {
        let timing = timing();
        let now = OffsetDateTime::now_utc();
        let auto = plan(true);
        let mut steps = journal(&auto, 5, now - Duration::seconds(10), |_| 0.05);
        // Home, move, meter (planning one long exposure), samples, HDR of θL −20.
        assert!(matches!(steps[2].step, Step::Meter { .. }));
        let unknown = progress(&steps, &[], &timing, now).eta_s;
        steps[2].result = Some(json!({ "shutter_s": [30.0] }));
        let metered = progress(&steps, &[], &timing, now);
        // Two θL left, each with one 30 s exposure instead of a typical bracket.
        assert!(
            metered.eta_s > unknown + 2.0 * 20.0,
            "{} vs {unknown}",
            metered.eta_s
        );
        steps[3].result = Some(json!({ "live": { "samples": 10 } }));
        let live = progress(&steps, &[], &timing, now).live;
        assert_eq!(live, vec![json!({ "samples": 10 })]);
        // A processing step under way is named.
        steps[4].state = StepState::Started;
        assert_eq!(
            progress(&steps, &[], &timing, now)
                .processing_step
                .as_deref(),
            Some("HDR merge θL -20.0°")
        );
    }
}
