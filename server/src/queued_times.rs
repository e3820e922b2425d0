//! The time left of the queued scans that have not begun, kept between the plans of
//! the waits for a sample change (`sample_waits`): it depends only on the scan's
//! journal (its planned steps, none begun), the last scan that ended done (whose
//! journal stands in for the kinds of step not measured yet) and the timing model,
//! not on the time, so it is estimated again only when one of those changes.

use std::collections::HashMap;
use std::sync::{Mutex, PoisonError};

use crate::store::{ScanRecord, ScanState, StoreError};
use crate::timing::Timing;

/// What a kept time left was estimated from: the scan's step count, the scan that
/// ended done before it (its journal stands in for the kinds not measured yet) and
/// the timing model.
type QueuedKey = (u32, Option<i64>, String);

/// The time left of queued scans that have not begun, by scan id, with what it was
/// estimated from.
#[derive(Debug, Default)]
pub struct QueuedTimes {
    kept: Mutex<HashMap<i64, (QueuedKey, f64)>>,
}

impl QueuedTimes {
    /// The seconds `scan` is expected to take: kept if it is queued, has not begun and
    /// nothing its estimate depends on changed; else `estimate`d (and kept if it can be).
    pub fn took(
        &self,
        scan: &ScanRecord,
        earlier: Option<i64>,
        timing: &Timing,
        estimate: impl FnOnce() -> Result<f64, StoreError>,
    ) -> Result<f64, StoreError> {
        let begun = scan.state != ScanState::Queued || scan.started.is_some();
        let lock = || self.kept.lock().unwrap_or_else(PoisonError::into_inner);
        if begun {
            lock().remove(&scan.id);
            return estimate();
        }
        let key = (scan.steps_total, earlier, format!("{timing:?}"));
        if let Some((kept, took)) = lock().get(&scan.id) {
            if *kept == key {
                return Ok(*took);
            }
        }
        let took = estimate()?;
        lock().insert(scan.id, (key, took));
        Ok(took)
    }

    /// How many scans' times are kept.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.kept
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len()
    }

    /// Forgets the scans not in `ids`.
    pub fn retain(&self, ids: &[i64]) {
        let mut kept = self.kept.lock().unwrap_or_else(PoisonError::into_inner);
        kept.retain(|id, _| ids.contains(id));
    }
}
