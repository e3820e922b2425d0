//! Reading a scan's journal: step times, the arm's angle before each step, each
//! step's place in its scan, the brackets its metering planned.

use serde_json::Value;
use time::OffsetDateTime;

use crate::plan::Step;
use crate::store::{StepRecord, StepState};
use crate::timing::{Place, Timing};

/// Parses a journal time (RFC 3339).
pub(super) fn parse_time(text: &str) -> Option<OffsetDateTime> {
    OffsetDateTime::parse(text, &time::format_description::well_known::Rfc3339).ok()
}

/// The arm's angle before each step of `steps`, walking the plan (home is θL 0).
pub(super) fn arm_angles(steps: &[StepRecord]) -> Vec<f64> {
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
pub(super) fn places(steps: &[StepRecord], timing: &Timing) -> Vec<Place> {
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

/// Seconds since a started step began (0 if its time does not parse).
pub(super) fn elapsed_s(record: &StepRecord, now: OffsetDateTime) -> f64 {
    record
        .started
        .as_deref()
        .and_then(parse_time)
        .map_or(0.0, |started| (now - started).as_seconds_f64())
}
