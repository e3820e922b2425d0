//! A sweep's state as the API shows it, from its scans' states and its start time.

use crate::store::{ScanRecord, ScanState};

/// The state of a sweep whose scans are `scans`, starting at `start_at` (Unix seconds),
/// at `now`: `done` once every scan is done; `finished` once every scan has ended,
/// some not done; `running` while one runs; `paused` when every scan not ended is
/// paused; `scheduled` while its start time is ahead and none has started; else `waiting`
/// (its scans queued behind others, or waiting for a device, a sample or disk space).
pub fn sweep_state(scans: &[ScanRecord], start_at: Option<i64>, now: i64) -> &'static str {
    let all = |state: ScanState| scans.iter().all(|s| s.state == state);
    let open = || scans.iter().filter(|s| !s.state.is_final());
    if open().next().is_none() {
        if all(ScanState::Done) {
            "done"
        } else {
            "finished"
        }
    } else if scans.iter().any(|s| s.state == ScanState::Running) {
        "running"
    } else if open().all(|s| s.state == ScanState::Paused) {
        "paused"
    } else if start_at.is_some_and(|t| t > now) && scans.iter().all(|s| s.started.is_none()) {
        "scheduled"
    } else {
        "waiting"
    }
}
