//! What the store holds and hands out: scans, steps, sweeps and hardware log entries
//! as stored, the states of scans and steps, the store's errors, and the timestamps it
//! writes (RFC 3339, UTC; Unix seconds).

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::plan::{mount_reason, ScanPlan, Step};

/// Errors of the store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database: {0}")]
    Sql(rusqlite::Error),
    #[error("stored JSON of {what}: {error}")]
    Json {
        what: &'static str,
        error: serde_json::Error,
    },
    #[error("unknown state {0:?} in the database")]
    State(String),
    #[error("a step cannot plan {0} further steps")]
    TooManySteps(usize),
}

/// Planned steps are numbered this far apart, leaving room for the steps a step adds
/// after itself (the captures of a metered bracket).
pub(super) const STEP_SPACING: u32 = 1000;

impl StoreError {
    /// Whether SQLite found the disk full (`SQLITE_FULL`, "database or disk is full").
    pub fn is_disk_full(&self) -> bool {
        matches!(self, StoreError::Sql(rusqlite::Error::SqliteFailure(e, _))
            if e.code == rusqlite::ErrorCode::DiskFull)
    }
}

impl From<rusqlite::Error> for StoreError {
    fn from(error: rusqlite::Error) -> Self {
        StoreError::Sql(error)
    }
}

/// States in which a scan's captured brackets are processed: running, or waiting for a
/// device or the operator (processing needs neither).
pub const PROCESSABLE: [ScanState; 3] = [
    ScanState::Running,
    ScanState::Interrupted,
    ScanState::Waiting,
];

pub(super) fn json_err(what: &'static str) -> impl FnOnce(serde_json::Error) -> StoreError {
    move |error| StoreError::Json { what, error }
}

/// Life cycle of a scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum ScanState {
    Queued,
    Running,
    Paused,
    Done,
    Failed,
    Cancelled,
    /// A device went away; resumes by itself once it is back.
    Interrupted,
    /// The arm cannot serve it yet (refused, unhomed, position not declared): queued
    /// again once that changes (the arm reconnects, its position is declared, or the
    /// operator resumes it); or its next step does not fit on the disk: queued again
    /// once it does. The reason is stored with it.
    Waiting,
}

impl ScanState {
    pub fn as_str(self) -> &'static str {
        match self {
            ScanState::Queued => "queued",
            ScanState::Running => "running",
            ScanState::Paused => "paused",
            ScanState::Done => "done",
            ScanState::Failed => "failed",
            ScanState::Cancelled => "cancelled",
            ScanState::Interrupted => "interrupted",
            ScanState::Waiting => "waiting",
        }
    }

    pub(super) fn parse(text: &str) -> Result<Self, StoreError> {
        Ok(match text {
            "queued" => ScanState::Queued,
            "running" => ScanState::Running,
            "paused" => ScanState::Paused,
            "done" => ScanState::Done,
            "failed" => ScanState::Failed,
            "cancelled" => ScanState::Cancelled,
            "interrupted" => ScanState::Interrupted,
            "waiting" => ScanState::Waiting,
            other => return Err(StoreError::State(other.to_owned())),
        })
    }

    /// Done, failed and cancelled scans never run again.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            ScanState::Done | ScanState::Failed | ScanState::Cancelled
        )
    }
}

/// Progress of a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum StepState {
    Pending,
    /// Begun but not recorded done: redone on resume.
    Started,
    Done,
}

impl StepState {
    pub(super) fn parse(text: &str) -> Result<Self, StoreError> {
        Ok(match text {
            "pending" => StepState::Pending,
            "started" => StepState::Started,
            "done" => StepState::Done,
            other => return Err(StoreError::State(other.to_owned())),
        })
    }

    pub(super) fn as_str(self) -> &'static str {
        match self {
            StepState::Pending => "pending",
            StepState::Started => "started",
            StepState::Done => "done",
        }
    }
}

/// One scan as stored.
#[derive(Debug, Clone, Serialize)]
pub struct ScanRecord {
    pub id: i64,
    pub plan: ScanPlan,
    pub state: ScanState,
    /// Why the scan failed, was interrupted or paused by an emergency stop.
    pub error: Option<String>,
    pub sweep_id: Option<i64>,
    /// Not started before this time (Unix seconds).
    pub not_before: Option<i64>,
    pub created: String,
    pub started: Option<String>,
    pub finished: Option<String>,
    /// Progress in the steps planned at creation: fixed from the start, a metering
    /// step counting as done once the bracket it planned is captured.
    pub done: u32,
    pub total: u32,
    /// Progress in journal rows (the total grows as metering plans captures).
    pub steps_done: u32,
    pub steps_total: u32,
    /// The hardware step being executed or next in line, else the processing one.
    pub current_step: Option<String>,
}

impl ScanRecord {
    /// Whether the scan waits for the operator to mount its sample.
    pub fn waits_for_sample(&self) -> bool {
        waits_for_sample(self.state, self.error.as_deref(), &self.plan.sample)
    }
}

/// Whether a scan in `state` with reason `error` waits for the operator to mount its
/// `sample`.
pub(super) fn waits_for_sample(state: ScanState, error: Option<&str>, sample: &str) -> bool {
    state == ScanState::Waiting && error == Some(mount_reason(sample).as_str())
}

/// One step as stored.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
#[schema(as = Step)]
pub struct StepRecord {
    /// Position key: increasing in execution order, not contiguous.
    pub index: u32,
    pub step: Step,
    pub state: StepState,
    pub started: Option<String>,
    pub finished: Option<String>,
    /// What the step produced (a capture's path and exposure, a fit's parameters, …).
    #[schema(value_type = Option<Object>)]
    pub result: Option<Value>,
}

/// One entry of the hardware log: what the hardware lane did, in which daemon run.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct LogEntry {
    pub id: i64,
    /// Daemon start counter (1 for the first start of this data directory).
    pub boot: i64,
    pub time: String,
    pub scan_id: Option<i64>,
    pub action: String,
    pub detail: String,
}

/// A scan to queue.
pub struct NewScan {
    pub plan: ScanPlan,
    pub sweep_id: Option<i64>,
    pub not_before: Option<i64>,
}

/// A sweep as stored.
#[derive(Debug, Clone, Serialize)]
pub struct SweepRecord {
    pub id: i64,
    pub request: Value,
    pub created: String,
    pub start_at: Option<i64>,
}

/// Current UTC time, RFC 3339.
pub fn now_rfc3339() -> String {
    time::OffsetDateTime::now_utc()
        .format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}

/// Current time, Unix seconds.
pub fn now_unix() -> i64 {
    time::OffsetDateTime::now_utc().unix_timestamp()
}
