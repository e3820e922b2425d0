//! What both lanes do around one step of the journal: record it as started before
//! anything happens, then record its outcome, the step done with its result (and the
//! steps it planned after itself) or the scan failed, interrupted or waiting, in one
//! transaction each, and announce the change.

use serde_json::Value;

use crate::files::without_server_paths;
use crate::plan::Step;
use crate::shared::Shared;
use crate::store::{now_rfc3339, ScanState, Store, StoreError};

/// Why a step did not complete.
#[derive(Debug)]
pub enum StepError {
    /// The operator paused, cancelled or stopped the scan: leave it as they set it.
    Halted,
    /// A device went away: the scan waits until it is back.
    Interrupted(String),
    /// The arm is refused, unhomed or its position undeclared: the scan waits for the
    /// operator to change that (no retries meanwhile), with the reason.
    Waiting(String),
    /// The scan cannot complete.
    Failed(String),
    Store(StoreError),
}

impl From<StoreError> for StepError {
    fn from(err: StoreError) -> Self {
        StepError::Store(err)
    }
}

/// A step's result record and the steps it adds after itself.
pub type Outcome = Result<(Value, Vec<Step>), StepError>;

/// Whether a lane goes on with the scan after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    Next,
    Stop,
}

/// Records that step `index` of scan `id` begins (committed before it runs).
pub fn begin(shared: &Shared, store: &mut Store, id: i64, index: u32) -> Result<(), StoreError> {
    store.step_started(id, index)?;
    shared.changed(id);
    Ok(())
}

/// Records the outcome of step `index` of scan `id`, which ended now. A failure or an
/// interruption moves the scan out of `from` (a scan the operator changed meanwhile
/// stays as they set it).
pub fn finish(
    shared: &Shared,
    store: &mut Store,
    id: i64,
    index: u32,
    from: &[ScanState],
    outcome: Outcome,
) -> Result<Flow, StoreError> {
    finish_at(shared, store, id, index, from, outcome, &now_rfc3339())
}

/// [`finish`] for a step that ended at `finished` (RFC 3339), before it is recorded.
pub fn finish_at(
    shared: &Shared,
    store: &mut Store,
    id: i64,
    index: u32,
    from: &[ScanState],
    outcome: Outcome,
    finished: &str,
) -> Result<Flow, StoreError> {
    match outcome {
        Ok((result, followers)) => {
            if store.step_done(id, index, &result, &followers, finished)? {
                tracing::info!("scan {id}: done");
            }
            shared.changed(id);
            Ok(Flow::Next)
        }
        Err(err) => stop(shared, store, id, from, err),
    }
}

/// Records why scan `id` stopped: failed, interrupted or waiting, out of `from` (a scan
/// the operator changed meanwhile stays as they set it).
pub fn stop(
    shared: &Shared,
    store: &mut Store,
    id: i64,
    from: &[ScanState],
    err: StepError,
) -> Result<Flow, StoreError> {
    // What is stored is shown to clients: no path of the server in it.
    let (scan_dir, data_dir) = (shared.scan_dir(id), shared.config.data_dir.clone());
    let relative = |reason: String| without_server_paths(&reason, &[&scan_dir, &data_dir]);
    match err {
        StepError::Halted => {}
        StepError::Interrupted(reason) => {
            let reason = relative(reason);
            tracing::warn!("scan {id} interrupted: {reason}");
            store.transition(id, from, ScanState::Interrupted, Some(&reason))?;
        }
        StepError::Waiting(reason) => {
            let reason = relative(reason);
            tracing::warn!("scan {id} waiting: {reason}");
            store.log(shared.boot, Some(id), "wait", &reason)?;
            store.transition(id, from, ScanState::Waiting, Some(&reason))?;
        }
        StepError::Failed(reason) => {
            let reason = relative(reason);
            tracing::error!("scan {id} failed: {reason}");
            store.transition(id, from, ScanState::Failed, Some(&reason))?;
        }
        StepError::Store(err) => return Err(err),
    }
    shared.changed(id);
    Ok(Flow::Stop)
}
