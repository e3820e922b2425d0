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

use time::OffsetDateTime;

use crate::progress::progress;
use crate::shared::Shared;
use crate::store::{ScanState, Store, StoreError};

/// A wait for a sample change, as planned.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedWait {
    pub scan_id: i64,
    pub sweep_id: Option<i64>,
    /// The sample to mount.
    pub sample: String,
    /// When the wait is expected to begin (Unix seconds); now for a scan already
    /// waiting.
    pub at: i64,
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
    let earlier = match store.last_done_before(i64::MAX)? {
        Some(done) => store.steps(done.id)?,
        None => Vec::new(),
    };
    let took = |id: i64| -> Result<f64, StoreError> {
        let left = progress(&store.steps(id)?, &earlier, &shared.timing, now).eta_s;
        Ok(if left.is_finite() { left.max(0.0) } else { 0.0 })
    };
    let mut scans = store.scans()?;
    scans.retain(|s| !s.state.is_final() && s.state != ScanState::Paused);
    // The scans past their sample check (running, interrupted) or stopped at it come
    // first, as the hardware lane finishes them before starting another.
    let (first, mut rest): (Vec<_>, Vec<_>) = scans.into_iter().partition(|s| {
        matches!(s.state, ScanState::Running | ScanState::Interrupted) || s.waits_for_sample()
    });
    let mut at = now.unix_timestamp() as f64;
    let mut mounted: Option<String> = None;
    let mut waits = Vec::new();
    for scan in &first {
        if scan.waits_for_sample() {
            waits.push(PlannedWait {
                scan_id: scan.id,
                sweep_id: scan.sweep_id,
                sample: scan.plan.sample.clone(),
                at: now.unix_timestamp(),
            });
        }
        mounted = Some(scan.plan.sample.clone());
        at += took(scan.id)?;
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
        let on_cylinder = match &mounted {
            Some(mounted) => mounted == sample,
            None => shared.mount.is_mounted(sample),
        };
        if !on_cylinder {
            waits.push(PlannedWait {
                scan_id: next.id,
                sweep_id: next.sweep_id,
                sample: sample.clone(),
                at: at.round() as i64,
            });
        }
        mounted = Some(sample.clone());
        at += took(next.id)?;
    }
    Ok(waits)
}
