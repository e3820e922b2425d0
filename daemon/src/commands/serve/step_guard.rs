//! The step boundary. A processing step runs under a panic guard, so a panic (a
//! decoder bug hit by a corrupt capture, say) fails that step with the panic's message
//! instead of ending the daemon. And a step that ends the daemon anyway (an abort, a
//! kill) is counted at the next start: one that was running at [`MAX_CRASHES`] deaths
//! fails its scan, so the queue goes on without it.

use gonio_processing::guard;
use serde_json::Value;

use super::shared::Shared;
use super::store::{Store, StoreError};

/// Daemon deaths a step may be running at before its scan fails.
pub const MAX_CRASHES: u32 = 3;

/// Runs processing step `what` under the panic guard: its error, or its panic, becomes
/// the step's error message.
pub fn run_processing(
    what: &str,
    step: impl FnOnce() -> anyhow::Result<Value>,
) -> Result<Value, String> {
    match guard::catch(step) {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(err)) => Err(format!("{what}: {err:#}")),
        Err(panic) => Err(format!("{what}: internal error (panicked: {panic})")),
    }
}

/// At start, before the queue runs: counts the death of the previous daemon against the
/// steps it was running, and fails the scans of steps at [`MAX_CRASHES`].
pub fn fail_crash_looping_scans(shared: &Shared, store: &mut Store) -> Result<(), StoreError> {
    for id in store.count_crashes(MAX_CRASHES)? {
        let scan = store.scan(id)?;
        let reason = scan.and_then(|s| s.error).unwrap_or_default();
        tracing::error!("scan {id} failed: {reason}");
        store.log(shared.boot, Some(id), "crash-loop", &reason)?;
    }
    Ok(())
}
