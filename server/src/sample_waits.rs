//! When the queue will stop for a person: the scans that will wait for the operator to
//! mount their sample, and the estimated time each wait begins.
//!
//! The queue is played forward from now in the order the hardware lane takes it (the
//! scan running first, then queued scans oldest first, each not before its start
//! time; paused scans are left out until resumed). Each scan lasts the time left the
//! time-left model (`progress`) gives it, processing included, learning from the last
//! scan that ended done. A scan whose sample differs from the one mounted before it
//! (without a carousel) waits; the times after a wait assume the operator confirms at
//! once.
//!
//! The waits are planned again at every look (every poll of the sweeps); the time left
//! of a queued scan that has not begun is kept between looks ([`QueuedTimes`]), so a
//! poll reads one journal per scan under way, not one per queued scan.

use time::OffsetDateTime;

use crate::progress::progress;
use crate::queued_times::QueuedTimes;
use crate::shared::Shared;
use crate::store::{ScanRecord, ScanState, Store, StoreError};
use crate::timing::Timing;

/// A wait for a sample change, as planned.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedWait {
    pub scan_id: i64,
    pub sweep_id: Option<i64>,
    /// The sample to mount.
    pub sample: String,
    /// When the wait is expected to begin (Unix seconds); for a scan already waiting,
    /// when it began.
    pub at: i64,
    /// The scan waits already.
    pub waiting: bool,
}

/// The waits for a sample change the queue will make, in order, from `now`.
pub fn planned_waits(
    shared: &Shared,
    store: &Store,
    now: OffsetDateTime,
) -> Result<Vec<PlannedWait>, StoreError> {
    if shared.config.carousel.is_some() {
        return Ok(Vec::new());
    }
    let mounted = |sample: &str| shared.mount.is_mounted(sample);
    let times = &shared.queued_times;
    waits(store, &shared.timing_now(), &mounted, times, now)
}

/// [`planned_waits`] without a carousel, the sample on the cylinder told by `mounted`
/// and the queued scans' times kept in `times`.
fn waits(
    store: &Store,
    timing: &Timing,
    mounted: &dyn Fn(&str) -> bool,
    times: &QueuedTimes,
    now: OffsetDateTime,
) -> Result<Vec<PlannedWait>, StoreError> {
    let last_done = store.last_done_before(i64::MAX)?;
    let earlier = match &last_done {
        Some(done) => store.steps(done.id)?,
        None => Vec::new(),
    };
    let took = |scan: &ScanRecord| {
        times.took(scan, last_done.as_ref().map(|s| s.id), timing, || {
            let left = progress(&store.steps(scan.id)?, &earlier, timing, now).eta_s;
            Ok(if left.is_finite() { left.max(0.0) } else { 0.0 })
        })
    };
    let mut scans = store.scans()?;
    scans.retain(|s| !s.state.is_final() && s.state != ScanState::Paused);
    times.retain(&scans.iter().map(|s| s.id).collect::<Vec<_>>());
    // The scans past their sample check (running, interrupted) or stopped at it come
    // first, as the hardware lane finishes them before starting another.
    let (first, mut rest): (Vec<_>, Vec<_>) = scans.into_iter().partition(|s| {
        matches!(s.state, ScanState::Running | ScanState::Interrupted) || s.waits_for_sample()
    });
    let mut at = now.unix_timestamp() as f64;
    let mut on_cylinder: Option<String> = None;
    let mut waits = Vec::new();
    for scan in &first {
        if scan.waits_for_sample() {
            let since = store.waiting_since(scan.id)?.and_then(|t| {
                OffsetDateTime::parse(&t, &time::format_description::well_known::Rfc3339).ok()
            });
            waits.push(PlannedWait {
                scan_id: scan.id,
                sweep_id: scan.sweep_id,
                sample: scan.plan.sample.clone(),
                at: since.unwrap_or(now).unix_timestamp(),
                waiting: true,
            });
        }
        on_cylinder = Some(scan.plan.sample.clone());
        at += took(scan)?;
    }
    while !rest.is_empty() {
        let ready = rest
            .iter()
            .position(|s| s.not_before.is_none_or(|t| t as f64 <= at));
        let next = match ready {
            Some(index) => rest.remove(index),
            None => {
                // Nothing may start before the earliest start time.
                let soonest = rest.iter().filter_map(|s| s.not_before).min();
                at = at.max(soonest.unwrap_or(0) as f64);
                continue;
            }
        };
        let sample = &next.plan.sample;
        let mounted = match &on_cylinder {
            Some(before) => before == sample,
            None => mounted(sample),
        };
        if !mounted {
            waits.push(PlannedWait {
                scan_id: next.id,
                sweep_id: next.sweep_id,
                sample: sample.clone(),
                at: at.round() as i64,
                waiting: false,
            });
        }
        on_cylinder = Some(sample.clone());
        at += took(&next)?;
    }
    Ok(waits)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::ScanPlan;
    use crate::store::{now_rfc3339, NewScan};

    fn scan(sample: &str) -> NewScan {
        NewScan {
            plan: ScanPlan {
                sample: sample.into(),
                theta_l: vec![-20.0, -30.0, -40.0],
                shutter_s: vec![0.5, 0.05],
                auto_bracket: false,
            },
            sweep_id: None,
            not_before: None,
        }
    }

    /// The waits as planned with the queued scans' times kept in `times`, and planned
    /// afresh: the same.
    /// Runs the steps `range` (journal order) of scan `id` to done.
    fn run_steps(store: &mut Store, id: i64, range: std::ops::Range<usize>) {
        for step in &store.steps(id).unwrap()[range] {
            store.step_started(id, step.index).unwrap();
            let done = &serde_json::Value::Null;
            store
                .step_done(id, step.index, done, &[], &now_rfc3339())
                .unwrap();
        }
    }

    fn kept_and_fresh(store: &Store, times: &QueuedTimes) -> Vec<PlannedWait> {
        let timing = Timing::real();
        let now = OffsetDateTime::now_utc();
        let nothing_mounted = |_: &str| false;
        let kept = waits(store, &timing, &nothing_mounted, times, now).unwrap();
        let fresh = waits(
            store,
            &timing,
            &nothing_mounted,
            &QueuedTimes::default(),
            now,
        );
        assert_eq!(kept, fresh.unwrap());
        kept
    }

    #[test]
    fn kept_times_of_queued_scans_give_the_waits_planned_afresh() {
        let dir = std::env::temp_dir().join(format!("gonio-waits-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut store = Store::open(&dir.join("gonio.sqlite")).unwrap();
        let ids = store
            .insert_scans(&[scan("red"), scan("blue"), scan("red")])
            .unwrap();
        let times = QueuedTimes::default();
        let first = kept_and_fresh(&store, &times);
        let samples: Vec<&str> = first.iter().map(|w| w.sample.as_str()).collect();
        assert_eq!(samples, ["red", "blue", "red"]);
        // Kept: a second plan of the waits is the first.
        assert_eq!(times.len(), 3);
        assert_eq!(kept_and_fresh(&store, &times), first);
        // The first scan runs its first steps: its time is estimated again from its
        // journal, the others' are kept.
        store
            .transition(ids[0], &[ScanState::Queued], ScanState::Running, None)
            .unwrap();
        run_steps(&mut store, ids[0], 0..3);
        kept_and_fresh(&store, &times);
        assert_eq!(times.len(), 2);
        // The first scan ends done: the others are estimated again with its journal.
        let all = store.steps(ids[0]).unwrap().len();
        run_steps(&mut store, ids[0], 3..all);
        let after = kept_and_fresh(&store, &times);
        assert_eq!(after.len(), 2, "{after:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
