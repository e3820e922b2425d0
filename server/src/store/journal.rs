//! Readings of one scan's journal (its steps in index order, as [`StepRecord`]s): the
//! step a lane runs next, the brackets captured but not processed yet, and the frames
//! waiting for their HDR map.

use super::records::{StepRecord, StepState};
use crate::plan::{Lane, Step};

/// The step `lane` runs next in a scan's journal (`steps` in index order): for the
/// hardware lane its first step not done; for the processing lane its first step not
/// done once every step before it is done (its inputs exist), which is then the first
/// step of the scan not done. `None` when the lane has nothing to do in this scan now.
pub fn ready_step(steps: &[StepRecord], lane: Lane) -> Option<&StepRecord> {
    let mut pending = steps.iter().filter(|s| s.state != StepState::Done);
    match lane {
        Lane::Hardware => pending.find(|s| s.step.lane() == Lane::Hardware),
        Lane::Processing => pending.next().filter(|s| s.step.lane() == Lane::Processing),
    }
}

/// The steps of a scan's journal (`steps` in index order) that the processing lane may
/// start beside its others ([`Step::runs_beside`]), in journal order: not done, not in
/// `running` (indices of steps it runs), and every step before it not done yet a
/// processing step it does not [`need`](Step::needs).
pub fn beside_steps<'a>(
    steps: &'a [StepRecord],
    running: &'a [u32],
) -> impl Iterator<Item = &'a StepRecord> + 'a {
    let pending: Vec<&StepRecord> = steps
        .iter()
        .filter(|s| s.state != StepState::Done)
        .collect();
    (0..pending.len()).filter_map(move |i| {
        let step = pending[i];
        let ready = step.step.runs_beside()
            && !running.contains(&step.index)
            && pending[..i]
                .iter()
                .all(|b| b.step.lane() == Lane::Processing && !step.step.needs(&b.step));
        ready.then_some(step)
    })
}

/// θL whose bracket is captured (every hardware step before its processing is done)
/// but not processed yet, in a scan's journal.
pub fn unprocessed_brackets(steps: &[StepRecord]) -> usize {
    brackets_behind(steps.iter().map(|r| (&r.step, r.state == StepState::Done)))
}

/// [`unprocessed_brackets`] of a journal given as its steps, each with whether it is
/// done, in order.
pub fn brackets_behind<'a>(steps: impl IntoIterator<Item = (&'a Step, bool)>) -> usize {
    let mut count = 0;
    let mut counted = None;
    for (step, done) in steps {
        if done {
            continue;
        }
        match (step.lane(), step.theta_l()) {
            (Lane::Hardware, _) => break,
            (Lane::Processing, Some(theta_l)) if counted != Some(theta_l) => {
                count += 1;
                counted = Some(theta_l);
            }
            (Lane::Processing, _) => {}
        }
    }
    count
}

/// The frames (paths relative to the scan directory, as capture steps record them) of
/// the θL whose HDR step has not begun (one under way has decoded its own), in a
/// scan's journal.
pub fn frames_awaiting_hdr(steps: &[StepRecord]) -> Vec<String> {
    let pending: Vec<f64> = steps
        .iter()
        .filter(|s| s.state == StepState::Pending)
        .filter_map(|s| match s.step {
            Step::Hdr { theta_l } => Some(theta_l),
            _ => None,
        })
        .collect();
    steps
        .iter()
        .filter(|s| {
            s.state == StepState::Done
                && matches!(s.step, Step::Capture { theta_l, .. } if pending.contains(&theta_l))
        })
        .filter_map(|s| s.result.as_ref()?.get("path")?.as_str().map(str::to_owned))
        .collect()
}
