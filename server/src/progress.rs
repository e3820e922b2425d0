//! What a scan's journal says beyond its step counts: the θL captured and processed,
//! the processing lane's current step, the live fits after each θL, and the time left
//! (docs/ARCHITECTURE.md, "Daemon").
//!
//! Time left: every step not done is given its prior from the [`Timing`] model, scaled
//! by how long the steps of its kind already done in this scan took against their
//! priors (a kind this scan has not measured yet, such as the fits at its end, by what
//! it took in the previous scan that ended done); a metering step not done brings the
//! bracket the scan last metered (or a typical one). The lanes are then played
//! forward: hardware steps one after the other, each processing step once the steps
//! before it and the previous processing step are done, HDR merges beside them (the
//! processing lane runs them in the background, one at a time). The estimate is when
//! the last of them finishes.

use std::collections::HashMap;
use std::mem::Discriminant;

use serde::Serialize;
use serde_json::Value;
use time::OffsetDateTime;

use super::plan::{Lane, Step};
use super::store::{StepRecord, StepState};
use super::timing::Timing;

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

/// Seconds from `started` to `finished` (journal times), if both parse.
fn seconds_between(started: Option<&str>, finished: Option<&str>) -> Option<f64> {
    let (started, finished) = (parse_time(started?)?, parse_time(finished?)?);
    Some((finished - started).as_seconds_f64().max(0.0))
}

/// Measured over prior seconds of the done steps of each kind.
#[derive(Default)]
struct Calibration {
    sums: HashMap<Discriminant<Step>, (f64, f64)>,
}

impl Calibration {
    /// What the done steps of `steps` (one scan's journal) took against their priors.
    fn of(steps: &[StepRecord], timing: &Timing) -> Self {
        let mut calibration = Calibration::default();
        for (record, from) in steps.iter().zip(arm_angles(steps)) {
            if record.state != StepState::Done {
                continue;
            }
            let measured = seconds_between(record.started.as_deref(), record.finished.as_deref());
            if let Some(measured) = measured {
                calibration.add(&record.step, measured, timing.prior_s(&record.step, from));
            }
        }
        calibration
    }

    fn add(&mut self, step: &Step, measured_s: f64, prior_s: f64) {
        let sum = self.sums.entry(std::mem::discriminant(step)).or_default();
        sum.0 += measured_s;
        sum.1 += prior_s;
    }

    /// Measured over prior seconds of `step`'s kind, if measured.
    fn ratio(&self, step: &Step) -> Option<f64> {
        match self.sums.get(&std::mem::discriminant(step)) {
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

/// The shutter times a done metering step planned (its result's `shutter_s`).
pub fn metered_bracket(record: &StepRecord) -> Option<Vec<f64>> {
    let list = record.result.as_ref()?.get("shutter_s")?.as_array()?;
    list.iter().map(Value::as_f64).collect()
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
    let (own, before) = (
        Calibration::of(steps, timing),
        Calibration::of(earlier, timing),
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
    let (mut hardware_s, mut processing_s, mut hdr_s) = (0.0_f64, 0.0_f64, 0.0_f64);
    for (record, &from) in steps.iter().zip(&from_deg) {
        if record.state == StepState::Done {
            if let Some(bracket) = metered_bracket(record) {
                bracket_s = capture_scale(bracket.iter().map(|&s| timing.capture_s(s)).sum());
            }
            continue;
        }
        let mut left_s = scale(&record.step, timing.prior_s(&record.step, from));
        if record.state == StepState::Started {
            let elapsed = record
                .started
                .as_deref()
                .and_then(parse_time)
                .map_or(0.0, |started| (now - started).as_seconds_f64());
            left_s = (left_s - elapsed).max(0.0);
        }
        match record.step.lane() {
            Lane::Hardware => {
                hardware_s += left_s;
                if matches!(record.step, Step::Meter { .. }) {
                    hardware_s += bracket_s;
                }
            }
            Lane::Processing if matches!(record.step, Step::Hdr { .. }) => {
                hdr_s = hdr_s.max(hardware_s) + left_s;
            }
            Lane::Processing => processing_s = processing_s.max(hardware_s) + left_s,
        }
    }
    Progress {
        theta_l: theta_progress(steps),
        processing_step: steps
            .iter()
            .find(|s| s.step.lane() == Lane::Processing && s.state == StepState::Started)
            .map(|s| s.step.describe()),
        eta_s: hardware_s.max(processing_s).max(hdr_s),
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
    use crate::plan::{ScanPlan, AUTO_FIT, FINAL_FITS, FIT_MODELS};
    use serde_json::json;
    use time::Duration;

    /// Real-time devices: the hardware lane is the slower one.
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

    #[test]
    fn time_left_plays_both_lanes_forward_and_learns_from_done_steps() {
        let timing = timing();
        let now = OffsetDateTime::now_utc();
        let fixed = plan(false);
        let fresh = journal(&fixed, 0, now, |_| 0.0);
        let full = progress(&fresh, &[], &timing, now);
        // Nothing done: every hardware prior, then the last θL's processing and the
        // extraction and fits after the hardware, its HDR merge beside them.
        let hardware: f64 = fresh
            .iter()
            .scan(0.0, |at, r| {
                let from = *at;
                if let Step::Move { theta_l } = r.step {
                    *at = theta_l;
                }
                Some((r.step.lane() == Lane::Hardware).then(|| timing.prior_s(&r.step, from)))
            })
            .flatten()
            .sum();
        let tail = timing.prior_s(&Step::Samples { theta_l: 0.0 }, 0.0)
            + timing.prior_s(&Step::Extract, 0.0)
            + FIT_MODELS
                .iter()
                .chain([&AUTO_FIT])
                .map(|(model, _)| {
                    timing.prior_s(
                        &Step::Fit {
                            model: (*model).into(),
                        },
                        0.0,
                    )
                })
                .sum::<f64>();
        let tail = tail.max(timing.prior_s(&Step::Hdr { theta_l: 0.0 }, 0.0));
        assert!((full.eta_s - (hardware + tail)).abs() < 1e-9, "{full:?}");
        assert_eq!(
            full.theta_l,
            ThetaProgress {
                captured: 0,
                processed: 0,
                total: 3
            }
        );
        // Captures that took twice their prior make the remaining ones count double;
        // the time left shrinks as steps get done.
        let slow = |step: &Step| match step {
            Step::Capture { shutter_s, .. } => 2.0 * timing.capture_s(*shutter_s),
            _ => 0.01,
        };
        let first_theta = journal(&fixed, 4, now - Duration::seconds(60), slow);
        let later = progress(&first_theta, &[], &timing, now);
        let captures_left = 4.0 * (timing.capture_s(0.5) + timing.capture_s(0.05)) / 2.0;
        assert!(later.eta_s > 2.0 * captures_left, "{later:?}");
        assert!(later.eta_s < full.eta_s + 2.0 * captures_left);
        assert_eq!(later.theta_l.captured, 1);
        let end = journal(&fixed, fixed.steps().len(), now, |_| 0.1);
        assert_eq!(progress(&end, &[], &timing, now).eta_s, 0.0);
        assert_eq!(progress(&end, &[], &timing, now).theta_l.processed, 3);
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
        let fits = FINAL_FITS as f64;
        let prior = |step: Step| timing.prior_s(&step, 0.0);
        let fit_prior = prior(Step::Fit {
            model: "ward".into(),
        });
        let (samples, extract) = (prior(Step::Samples { theta_l: 0.0 }), prior(Step::Extract));
        // After the hardware: the last θL's samples, the extraction and the fits, its
        // HDR merge beside them.
        let hardware =
            alone - (samples + extract + fits * fit_prior).max(prior(Step::Hdr { theta_l: 0.0 }));
        assert!(
            (informed - (hardware + samples + extract + fits * fit_s)).abs() < 1e-6,
            "{informed} vs {alone}"
        );
        // What this scan measured itself wins over the earlier scan: its last fit is
        // expected to take the 1 s its other fits took.
        let own = journal(
            &fixed,
            fixed.steps().len() - 1,
            now - Duration::seconds(30),
            |s| match s {
                Step::Fit { .. } => 1.0,
                _ => 0.1,
            },
        );
        assert!(matches!(own.last().unwrap().step, Step::Fit { .. }));
        let left = progress(&own, &earlier, &timing, now).eta_s;
        assert!((left - 1.0).abs() < 1e-6, "{left}");
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
