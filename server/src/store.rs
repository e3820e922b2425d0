//! The durable queue: scans, their steps, sweeps and the hardware log in SQLite
//! (WAL journal, `synchronous = FULL`, so a committed step survives power loss).

use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{params, Connection, OptionalExtension, Transaction, TransactionBehavior};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::plan::{mount_reason, Lane, ScanPlan, Step};
use super::storage;

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
const STEP_SPACING: u32 = 1000;

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

fn json_err(what: &'static str) -> impl FnOnce(serde_json::Error) -> StoreError {
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

    fn parse(text: &str) -> Result<Self, StoreError> {
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
    fn parse(text: &str) -> Result<Self, StoreError> {
        Ok(match text {
            "pending" => StepState::Pending,
            "started" => StepState::Started,
            "done" => StepState::Done,
            other => return Err(StoreError::State(other.to_owned())),
        })
    }

    fn as_str(self) -> &'static str {
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
        self.state == ScanState::Waiting
            && self.error.as_deref() == Some(mount_reason(&self.plan.sample).as_str())
    }
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

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS sweeps (
    id INTEGER PRIMARY KEY,
    request TEXT NOT NULL,
    created TEXT NOT NULL,
    start_at INTEGER
);
CREATE TABLE IF NOT EXISTS scans (
    id INTEGER PRIMARY KEY,
    plan TEXT NOT NULL,
    state TEXT NOT NULL,
    error TEXT,
    sweep_id INTEGER REFERENCES sweeps(id),
    not_before INTEGER,
    created TEXT NOT NULL,
    started TEXT,
    finished TEXT
);
CREATE TABLE IF NOT EXISTS steps (
    scan_id INTEGER NOT NULL REFERENCES scans(id),
    idx INTEGER NOT NULL,
    step TEXT NOT NULL,
    state TEXT NOT NULL,
    started TEXT,
    finished TEXT,
    result TEXT,
    crashes INTEGER NOT NULL DEFAULT 0,
    started_boot INTEGER,
    PRIMARY KEY (scan_id, idx)
);
CREATE TABLE IF NOT EXISTS hardware_log (
    id INTEGER PRIMARY KEY,
    boot INTEGER NOT NULL,
    time TEXT NOT NULL,
    scan_id INTEGER,
    action TEXT NOT NULL,
    detail TEXT NOT NULL
);
";

/// Marks scan `?1` done at time `?2` if it is running and every step is done.
const COMPLETE_SCAN: &str = "UPDATE scans SET state = 'done', finished = ?2, error = NULL
    WHERE id = ?1 AND state = 'running'
      AND NOT EXISTS (SELECT 1 FROM steps WHERE scan_id = ?1 AND state != 'done')";

/// The columns of a [`ScanRecord`], counts and current step included.
fn scan_columns() -> String {
    format!(
        "id, plan, state, error, sweep_id, not_before, created, started, finished,
        (SELECT COUNT(*) FROM steps s WHERE s.scan_id = scans.id AND s.idx % {STEP_SPACING} = 0
            AND s.state = 'done'
            AND NOT EXISTS (SELECT 1 FROM steps f WHERE f.scan_id = s.scan_id
                AND f.idx > s.idx AND f.idx < s.idx + {STEP_SPACING} AND f.state != 'done')),
        (SELECT COUNT(*) FROM steps WHERE scan_id = scans.id AND idx % {STEP_SPACING} = 0),
        (SELECT COUNT(*) FROM steps WHERE scan_id = scans.id AND state = 'done'),
        (SELECT COUNT(*) FROM steps WHERE scan_id = scans.id),
        (SELECT step FROM steps WHERE scan_id = scans.id AND state != 'done'
            ORDER BY json_extract(step, '$.kind') NOT IN ('home', 'move', 'meter', 'capture'), idx
            LIMIT 1)"
    )
}

/// A connection to the store. Each thread opens its own.
pub struct Store {
    conn: Connection,
    /// The journal's reserve file ([`storage::JOURNAL_RESERVE_FILE`]), deleted when a
    /// write finds the disk full.
    reserve: PathBuf,
}

impl Store {
    /// Opens (creating if needed) the database at `path`.
    pub fn open(path: &Path) -> Result<Self, StoreError> {
        let conn = Connection::open(path)?;
        conn.busy_timeout(Duration::from_secs(10))?;
        conn.pragma_update(None, "journal_mode", "WAL")?;
        conn.pragma_update(None, "synchronous", "FULL")?;
        conn.pragma_update(None, "foreign_keys", "ON")?;
        conn.execute_batch(SCHEMA)?;
        // Databases made before steps counted the daemon deaths they were running at.
        for (column, definition) in [
            ("crashes", "INTEGER NOT NULL DEFAULT 0"),
            ("started_boot", "INTEGER"),
        ] {
            let present: bool = conn.query_row(
                "SELECT COUNT(*) FROM pragma_table_info('steps') WHERE name = ?1",
                [column],
                |r| r.get::<_, i64>(0).map(|n| n > 0),
            )?;
            if !present {
                conn.execute_batch(&format!(
                    "ALTER TABLE steps ADD COLUMN {column} {definition}"
                ))?;
            }
        }
        Ok(Self {
            conn,
            reserve: storage::journal_reserve_path(path),
        })
    }

    /// Runs `write`; when it finds the disk full, deletes the journal's reserve file, if
    /// there is one, and runs it again in the space that frees (a write that failed
    /// changed nothing). The reserve is made again once there is room
    /// (`storage::Probe::keep_journal_reserve`).
    fn writing<T>(
        &mut self,
        mut write: impl FnMut(&mut Self) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        match write(self) {
            Err(err) if err.is_disk_full() && std::fs::remove_file(&self.reserve).is_ok() => {
                tracing::warn!(
                    "the disk is full: {} deleted to let the journal write",
                    self.reserve.display()
                );
                write(self)
            }
            result => result,
        }
    }

    /// Called once at start, after [`Store::begin_boot`] and before anything runs.
    /// `faulted`: the lane at fault when the previous daemon died of its own fault
    /// (`step_guard`); each step of that lane it had started and not finished counts
    /// that death (a kill or a power cut, which leave no record, count against none). A
    /// step that has now been running at `limit` deaths fails its scan ("... crashed
    /// the daemon N times") and goes back to pending, so the queue goes on (and a
    /// resume retries it). Returns the ids of the scans failed.
    pub fn count_crashes(
        &mut self,
        limit: u32,
        faulted: Option<Lane>,
    ) -> Result<Vec<i64>, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            if let Some(lane) = faulted {
                let previous: i64 =
                    tx.query_row("SELECT value - 1 FROM meta WHERE key = 'boot'", [], |r| {
                        r.get(0)
                    })?;
                // Steps started before boots were recorded on them count too.
                let started: Vec<(i64, u32, String)> = {
                    let mut stmt = tx.prepare(
                        "SELECT scan_id, idx, step FROM steps WHERE state = 'started'
                         AND (started_boot = ?1 OR started_boot IS NULL)",
                    )?;
                    let rows = stmt
                        .query_map([previous], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))?
                        .collect::<Result<_, _>>()?;
                    rows
                };
                for (scan_id, idx, step) in started {
                    let step: Step = serde_json::from_str(&step).map_err(json_err("step"))?;
                    if step.lane() == lane {
                        tx.execute(
                            "UPDATE steps SET crashes = crashes + 1 WHERE scan_id = ?1 AND idx = ?2",
                            params![scan_id, idx],
                        )?;
                    }
                }
            }
            let looping: Vec<(i64, u32, String, u32)> = {
                let mut stmt = tx.prepare(
                    "SELECT scan_id, idx, step, crashes FROM steps
                     WHERE state = 'started' AND crashes >= ?1 ORDER BY scan_id, idx",
                )?;
                let rows = stmt
                    .query_map([limit], |r| {
                        Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?))
                    })?
                    .collect::<Result<_, _>>()?;
                rows
            };
            let now = now_rfc3339();
            let mut failed = Vec::new();
            for (scan_id, idx, step, crashes) in looping {
                let step: Step = serde_json::from_str(&step).map_err(json_err("step"))?;
                let reason = format!(
                    "step \"{}\" crashed the daemon {crashes} times",
                    step.describe()
                );
                tx.execute(
                    "UPDATE steps SET state = 'pending', started = NULL WHERE scan_id = ?1 AND idx = ?2",
                    params![scan_id, idx],
                )?;
                let changed = tx.execute(
                    "UPDATE scans SET state = 'failed', error = ?2, finished = ?3
                     WHERE id = ?1 AND state NOT IN ('done', 'failed', 'cancelled')",
                    params![scan_id, reason, now],
                )?;
                if changed > 0 {
                    failed.push(scan_id);
                }
            }
            tx.commit()?;
            Ok(failed)
        })
    }

    /// A transaction that takes the write lock at once (`BEGIN IMMEDIATE`): one that
    /// reads and then writes in a deferred transaction fails with `database is locked`
    /// when another connection wrote in between, without waiting for the busy timeout.
    fn write_transaction(&mut self) -> Result<Transaction<'_>, StoreError> {
        Ok(self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)?)
    }

    /// Counts a daemon start and returns its number.
    pub fn begin_boot(&mut self) -> Result<i64, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            tx.execute(
                "INSERT INTO meta (key, value) VALUES ('boot', 1)
                 ON CONFLICT(key) DO UPDATE SET value = value + 1",
                [],
            )?;
            let boot = tx.query_row("SELECT value FROM meta WHERE key = 'boot'", [], |r| {
                r.get(0)
            })?;
            tx.commit()?;
            Ok(boot)
        })
    }

    /// Queues scans, plans and steps included, in one transaction.
    pub fn insert_scans(&mut self, scans: &[NewScan]) -> Result<Vec<i64>, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            let ids = insert_scans_tx(&tx, scans)?;
            tx.commit()?;
            Ok(ids)
        })
    }

    /// Stores a sweep and queues its scans, in one transaction.
    pub fn insert_sweep(
        &mut self,
        request: &Value,
        start_at: Option<i64>,
        plans: Vec<ScanPlan>,
    ) -> Result<(i64, Vec<i64>), StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            tx.execute(
                "INSERT INTO sweeps (request, created, start_at) VALUES (?1, ?2, ?3)",
                params![request.to_string(), now_rfc3339(), start_at],
            )?;
            let sweep_id = tx.last_insert_rowid();
            let scans: Vec<NewScan> = plans
                .iter()
                .map(|plan| NewScan {
                    plan: plan.clone(),
                    sweep_id: Some(sweep_id),
                    not_before: start_at,
                })
                .collect();
            let ids = insert_scans_tx(&tx, &scans)?;
            tx.commit()?;
            Ok((sweep_id, ids))
        })
    }

    pub fn sweep(&self, id: i64) -> Result<Option<SweepRecord>, StoreError> {
        let row = self
            .conn
            .query_row(
                "SELECT id, request, created, start_at FROM sweeps WHERE id = ?1",
                [id],
                |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        r.get::<_, String>(1)?,
                        r.get::<_, String>(2)?,
                        r.get::<_, Option<i64>>(3)?,
                    ))
                },
            )
            .optional()?;
        row.map(|(id, request, created, start_at)| {
            Ok(SweepRecord {
                id,
                request: serde_json::from_str(&request).map_err(json_err("sweep request"))?,
                created,
                start_at,
            })
        })
        .transpose()
    }

    pub fn sweep_ids(&self) -> Result<Vec<i64>, StoreError> {
        let mut stmt = self.conn.prepare("SELECT id FROM sweeps ORDER BY id")?;
        let ids = stmt
            .query_map([], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(ids)
    }

    fn query_scans(
        &self,
        filter: &str,
        args: impl rusqlite::Params,
    ) -> Result<Vec<ScanRecord>, StoreError> {
        let sql = format!("SELECT {} FROM scans {filter}", scan_columns());
        let mut stmt = self.conn.prepare(&sql)?;
        let rows = stmt
            .query_map(args, |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                    r.get::<_, Option<String>>(3)?,
                    r.get::<_, Option<i64>>(4)?,
                    r.get::<_, Option<i64>>(5)?,
                    r.get::<_, String>(6)?,
                    r.get::<_, Option<String>>(7)?,
                    r.get::<_, Option<String>>(8)?,
                    [
                        r.get::<_, u32>(9)?,
                        r.get::<_, u32>(10)?,
                        r.get::<_, u32>(11)?,
                        r.get::<_, u32>(12)?,
                    ],
                    r.get::<_, Option<String>>(13)?,
                ))
            })?
            .collect::<Result<Vec<_>, _>>()?;
        rows.into_iter()
            .map(
                |(
                    id,
                    plan,
                    state,
                    error,
                    sweep_id,
                    not_before,
                    created,
                    started,
                    finished,
                    [done, total, steps_done, steps_total],
                    current,
                )| {
                    let current_step = current
                        .map(|s| serde_json::from_str::<Step>(&s).map(|s| s.describe()))
                        .transpose()
                        .map_err(json_err("step"))?;
                    Ok(ScanRecord {
                        id,
                        plan: serde_json::from_str(&plan).map_err(json_err("scan plan"))?,
                        state: ScanState::parse(&state)?,
                        error,
                        sweep_id,
                        not_before,
                        created,
                        started,
                        finished,
                        done,
                        total,
                        steps_done,
                        steps_total,
                        current_step,
                    })
                },
            )
            .collect()
    }

    pub fn scans(&self) -> Result<Vec<ScanRecord>, StoreError> {
        self.query_scans("ORDER BY id", [])
    }

    /// The scans in `state`, oldest first.
    pub fn scans_in(&self, state: ScanState) -> Result<Vec<ScanRecord>, StoreError> {
        self.query_scans("WHERE state = ?1 ORDER BY id", [state.as_str()])
    }

    pub fn scans_of_sweep(&self, sweep_id: i64) -> Result<Vec<ScanRecord>, StoreError> {
        self.query_scans("WHERE sweep_id = ?1 ORDER BY id", [sweep_id])
    }

    /// The latest scan before `id` that ended done: the step times it measured.
    pub fn last_done_before(&self, id: i64) -> Result<Option<ScanRecord>, StoreError> {
        Ok(self
            .query_scans(
                "WHERE state = 'done' AND id < ?1 ORDER BY id DESC LIMIT 1",
                [id],
            )?
            .into_iter()
            .next())
    }

    pub fn scan(&self, id: i64) -> Result<Option<ScanRecord>, StoreError> {
        Ok(self.query_scans("WHERE id = ?1", [id])?.into_iter().next())
    }

    /// The scan the hardware lane works on next: a running scan with hardware steps
    /// left (resumed after a crash or a reconnect), oldest first, else the oldest queued
    /// scan whose start time has come and whose sweep has no earlier scan waiting (a
    /// scan waiting on the arm holds the samples after it).
    pub fn next_for_hardware(&self, now: i64) -> Result<Option<ScanRecord>, StoreError> {
        for scan in self.query_scans("WHERE state = 'running' ORDER BY id", [])? {
            if ready_step(&self.steps(scan.id)?, Lane::Hardware).is_some() {
                return Ok(Some(scan));
            }
        }
        Ok(self
            .query_scans(
                "WHERE state = 'queued' AND (not_before IS NULL OR not_before <= ?1)
                   AND NOT EXISTS (SELECT 1 FROM scans AS held WHERE held.state = 'waiting'
                       AND held.sweep_id = scans.sweep_id AND held.id < scans.id)
                 ORDER BY id LIMIT 1",
                [now],
            )?
            .pop())
    }

    /// The oldest scan waiting for its sample to be mounted, if any: the hardware lane
    /// starts no scan meanwhile.
    pub fn waiting_for_sample(&self) -> Result<Option<ScanRecord>, StoreError> {
        Ok(self
            .query_scans("WHERE state = 'waiting' ORDER BY id", [])?
            .into_iter()
            .find(ScanRecord::waits_for_sample))
    }

    /// Ids of the scans whose captured brackets are processed now, oldest first.
    fn processable_ids(&self) -> Result<Vec<i64>, StoreError> {
        let mut stmt = self
            .conn
            .prepare("SELECT id FROM scans WHERE state IN (?1, ?2, ?3) ORDER BY id")?;
        let ids = stmt
            .query_map(PROCESSABLE.map(ScanState::as_str), |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(ids)
    }

    /// The processing step to run next: the first one ready ([`ready_step`]) in the
    /// oldest scan that has one, with that scan's id. `running` (scan id, step index),
    /// a step the lane runs in the background, counts as done here.
    pub fn next_for_processing(
        &self,
        running: Option<(i64, u32)>,
    ) -> Result<Option<(i64, StepRecord)>, StoreError> {
        for id in self.processable_ids()? {
            let mut steps = self.steps(id)?;
            steps.retain(|s| running != Some((id, s.index)));
            if let Some(step) = ready_step(&steps, Lane::Processing) {
                return Ok(Some((id, step.clone())));
            }
        }
        Ok(None)
    }

    /// The first HDR step whose bracket is captured (no hardware step pending before it)
    /// in the oldest scan being processed that has one, with that scan's id: the step
    /// the processing lane starts in the background ahead of the steps before it.
    pub fn next_hdr(&self) -> Result<Option<(i64, StepRecord)>, StoreError> {
        for id in self.processable_ids()? {
            let hdr = self
                .steps(id)?
                .into_iter()
                .filter(|s| s.state != StepState::Done)
                .take_while(|s| s.step.lane() == Lane::Processing)
                .find(|s| matches!(s.step, Step::Hdr { .. }));
            if let Some(step) = hdr {
                return Ok(Some((id, step)));
            }
        }
        Ok(None)
    }

    /// The frames captured for HDR maps not made yet, in the scans being processed,
    /// oldest first: (scan id, frame path relative to the scan directory).
    pub fn frames_awaiting_hdr(&self) -> Result<Vec<(i64, String)>, StoreError> {
        let mut frames = Vec::new();
        for id in self.processable_ids()? {
            let steps = self.steps(id)?;
            frames.extend(frames_awaiting_hdr(&steps).into_iter().map(|p| (id, p)));
        }
        Ok(frames)
    }

    /// Brackets captured but not processed yet, over every scan being processed.
    pub fn unprocessed_brackets(&self) -> Result<usize, StoreError> {
        let mut count = 0;
        for id in self.processable_ids()? {
            count += unprocessed_brackets(&self.steps(id)?);
        }
        Ok(count)
    }

    /// Sets the state of a scan if it is currently one of `from`; returns whether it
    /// changed. `error` replaces the stored reason.
    pub fn transition(
        &mut self,
        id: i64,
        from: &[ScanState],
        to: ScanState,
        error: Option<&str>,
    ) -> Result<bool, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            let current: Option<String> = tx
                .query_row("SELECT state FROM scans WHERE id = ?1", [id], |r| r.get(0))
                .optional()?;
            let Some(current) = current else {
                return Ok(false);
            };
            if !from.contains(&ScanState::parse(&current)?) {
                return Ok(false);
            }
            let now = now_rfc3339();
            tx.execute(
                "UPDATE scans SET state = ?2, error = ?3,
                    started = CASE WHEN ?2 = 'running' AND started IS NULL THEN ?4 ELSE started END,
                    finished = CASE WHEN ?2 IN ('done', 'failed', 'cancelled') THEN ?4
                                    WHEN ?2 IN ('queued', 'running') THEN NULL
                                    ELSE finished END
                 WHERE id = ?1",
                params![id, to.as_str(), error, now],
            )?;
            tx.commit()?;
            Ok(true)
        })
    }

    /// Moves every scan in state `from` to `to` with reason `error` (e.g. interrupted ->
    /// running once the device is back); returns their ids.
    pub fn transition_all(
        &mut self,
        from: ScanState,
        to: ScanState,
        error: Option<&str>,
    ) -> Result<Vec<i64>, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            let ids: Vec<i64> = {
                let mut stmt = tx.prepare("SELECT id FROM scans WHERE state = ?1")?;
                let ids = stmt
                    .query_map([from.as_str()], |r| r.get(0))?
                    .collect::<Result<_, _>>()?;
                ids
            };
            tx.execute(
                "UPDATE scans SET state = ?2, error = ?3 WHERE state = ?1",
                params![from.as_str(), to.as_str(), error],
            )?;
            tx.commit()?;
            Ok(ids)
        })
    }

    pub fn steps(&self, scan_id: i64) -> Result<Vec<StepRecord>, StoreError> {
        self.query_steps("WHERE scan_id = ?1 ORDER BY idx", scan_id)
    }

    /// The step of a scan that `lane` runs next, if it has one ready.
    pub fn next_step(&self, scan_id: i64, lane: Lane) -> Result<Option<StepRecord>, StoreError> {
        Ok(ready_step(&self.steps(scan_id)?, lane).cloned())
    }

    fn query_steps(&self, filter: &str, scan_id: i64) -> Result<Vec<StepRecord>, StoreError> {
        let mut stmt = self.conn.prepare(&format!(
            "SELECT idx, step, state, started, finished, result FROM steps {filter}"
        ))?;
        let rows = stmt
            .query_map([scan_id], |r| {
                Ok((
                    r.get::<_, u32>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                    r.get::<_, Option<String>>(3)?,
                    r.get::<_, Option<String>>(4)?,
                    r.get::<_, Option<String>>(5)?,
                ))
            })?
            .collect::<Result<Vec<_>, _>>()?;
        rows.into_iter()
            .map(|(index, step, state, started, finished, result)| {
                Ok(StepRecord {
                    index,
                    step: serde_json::from_str(&step).map_err(json_err("step"))?,
                    state: StepState::parse(&state)?,
                    started,
                    finished,
                    result: result
                        .map(|r| serde_json::from_str(&r))
                        .transpose()
                        .map_err(json_err("step result"))?,
                })
            })
            .collect()
    }

    /// Records that a step begins (committed before the hardware is touched), in this
    /// daemon start.
    pub fn step_started(&mut self, scan_id: i64, index: u32) -> Result<(), StoreError> {
        self.writing(|store| {
            store.conn.execute(
                "UPDATE steps SET state = ?3, started = ?4,
                    started_boot = (SELECT value FROM meta WHERE key = 'boot')
                 WHERE scan_id = ?1 AND idx = ?2",
                params![scan_id, index, StepState::Started.as_str(), now_rfc3339()],
            )?;
            Ok(())
        })
    }

    /// Records a step as done with its result and inserts the steps it planned
    /// (`followers`, right after it), in one transaction; when it was the last step of
    /// a still running scan, the scan becomes done in the same transaction. Returns
    /// whether it did.
    pub fn step_done(
        &mut self,
        scan_id: i64,
        index: u32,
        result: &Value,
        followers: &[Step],
    ) -> Result<bool, StoreError> {
        self.writing(|store| {
            if followers.len() >= STEP_SPACING as usize {
                return Err(StoreError::TooManySteps(followers.len()));
            }
            let tx = store.write_transaction()?;
            let now = now_rfc3339();
            for (k, step) in (1..).zip(followers) {
                let step = serde_json::to_string(step).map_err(json_err("step"))?;
                tx.execute(
                    "INSERT INTO steps (scan_id, idx, step, state) VALUES (?1, ?2, ?3, 'pending')",
                    params![scan_id, index + k, step],
                )?;
            }
            tx.execute(
                "UPDATE steps SET state = ?3, finished = ?4, result = ?5
                 WHERE scan_id = ?1 AND idx = ?2",
                params![
                    scan_id,
                    index,
                    StepState::Done.as_str(),
                    now,
                    result.to_string()
                ],
            )?;
            let completed = tx.execute(COMPLETE_SCAN, params![scan_id, now])? > 0;
            tx.commit()?;
            Ok(completed)
        })
    }

    /// Marks a running scan with every step done as done (its last step was done
    /// while it was paused); returns whether it was.
    pub fn complete_if_done(&mut self, scan_id: i64) -> Result<bool, StoreError> {
        self.writing(|store| {
            Ok(store
                .conn
                .execute(COMPLETE_SCAN, params![scan_id, now_rfc3339()])?
                > 0)
        })
    }

    /// Appends to the hardware log.
    pub fn log(
        &mut self,
        boot: i64,
        scan_id: Option<i64>,
        action: &str,
        detail: &str,
    ) -> Result<(), StoreError> {
        self.writing(|store| {
            store.conn.execute(
                "INSERT INTO hardware_log (boot, time, scan_id, action, detail)
                 VALUES (?1, ?2, ?3, ?4, ?5)",
                params![boot, now_rfc3339(), scan_id, action, detail],
            )?;
            Ok(())
        })
    }

    /// The hardware log entries after `after_id`, oldest first.
    pub fn hardware_log(&self, after_id: i64) -> Result<Vec<LogEntry>, StoreError> {
        let mut stmt = self.conn.prepare(
            "SELECT id, boot, time, scan_id, action, detail FROM hardware_log
             WHERE id > ?1 ORDER BY id",
        )?;
        let rows = stmt
            .query_map([after_id], |r| {
                Ok(LogEntry {
                    id: r.get(0)?,
                    boot: r.get(1)?,
                    time: r.get(2)?,
                    scan_id: r.get(3)?,
                    action: r.get(4)?,
                    detail: r.get(5)?,
                })
            })?
            .collect::<Result<_, _>>()?;
        Ok(rows)
    }
}

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

/// θL whose bracket is captured (every hardware step before its processing is done)
/// but not processed yet, in a scan's journal.
pub fn unprocessed_brackets(steps: &[StepRecord]) -> usize {
    let mut count = 0;
    let mut counted = None;
    for record in steps {
        if record.state == StepState::Done {
            continue;
        }
        match (record.step.lane(), record.step.theta_l()) {
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
/// the θL whose HDR step is not done, in a scan's journal.
pub fn frames_awaiting_hdr(steps: &[StepRecord]) -> Vec<String> {
    let pending: Vec<f64> = steps
        .iter()
        .filter(|s| s.state != StepState::Done)
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

fn insert_scans_tx(tx: &Transaction<'_>, scans: &[NewScan]) -> Result<Vec<i64>, StoreError> {
    let created = now_rfc3339();
    let mut ids = Vec::with_capacity(scans.len());
    for scan in scans {
        let plan = serde_json::to_string(&scan.plan).map_err(json_err("scan plan"))?;
        tx.execute(
            "INSERT INTO scans (plan, state, sweep_id, not_before, created)
             VALUES (?1, 'queued', ?2, ?3, ?4)",
            params![plan, scan.sweep_id, scan.not_before, created],
        )?;
        let id = tx.last_insert_rowid();
        for (k, step) in (0u32..).zip(scan.plan.steps()) {
            let step = serde_json::to_string(&step).map_err(json_err("step"))?;
            tx.execute(
                "INSERT INTO steps (scan_id, idx, step, state) VALUES (?1, ?2, ?3, 'pending')",
                params![id, k * STEP_SPACING, step],
            )?;
        }
        ids.push(id);
    }
    Ok(ids)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan() -> ScanPlan {
        ScanPlan {
            sample: "gold".into(),
            theta_l: vec![-20.0],
            shutter_s: vec![0.1, 0.01],
            auto_bracket: false,
        }
    }

    fn temp_store(name: &str) -> (std::path::PathBuf, Store) {
        let dir = std::env::temp_dir().join(format!("gonio-store-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let store = Store::open(&dir.join("gonio.sqlite")).unwrap();
        (dir, store)
    }

    fn done(store: &mut Store, id: i64, step: &StepRecord, followers: &[Step]) {
        store.step_started(id, step.index).unwrap();
        store
            .step_done(id, step.index, &Value::Null, followers)
            .unwrap();
    }

    fn next(store: &Store, id: i64, lane: Lane) -> Option<Step> {
        store.next_step(id, lane).unwrap().map(|s| s.step)
    }

    /// A write that finds the disk full deletes the journal's reserve file and runs
    /// once more in the space it frees; with no reserve left, the full disk is the
    /// error, told from others (as SQLite reports it: here at its page limit).
    #[test]
    fn a_full_disk_frees_the_journal_reserve_for_one_more_try() {
        let (dir, mut store) = temp_store("reserve");
        let reserve = dir.join(storage::JOURNAL_RESERVE_FILE);
        std::fs::write(&reserve, vec![0u8; 4096]).unwrap();
        let full = || {
            StoreError::Sql(rusqlite::Error::SqliteFailure(
                rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_FULL),
                None,
            ))
        };
        let mut tries = 0;
        let written = store.writing(|_| {
            tries += 1;
            if tries == 1 {
                Err(full())
            } else {
                Ok(tries)
            }
        });
        assert_eq!(written.unwrap(), 2);
        assert!(!reserve.exists());
        tries = 0;
        let failed = store.writing(|_| -> Result<(), StoreError> {
            tries += 1;
            Err(full())
        });
        assert!(failed.unwrap_err().is_disk_full());
        assert_eq!(tries, 1);
        // What SQLite says when the database cannot grow.
        let pages: i64 = store
            .conn
            .query_row("PRAGMA page_count", [], |r| r.get(0))
            .unwrap();
        store
            .conn
            .pragma_update(None, "max_page_count", pages)
            .unwrap();
        let detail = "x".repeat(4000);
        let err = (0..100)
            .find_map(|_| store.log(1, None, "test", &detail).err())
            .expect("the page limit is reached");
        assert!(err.is_disk_full(), "{err}");
        assert!(!StoreError::State("?".into()).is_disk_full());
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn lanes_take_their_own_steps_and_the_scan_is_done_when_both_are() {
        let (dir, mut store) = temp_store("lanes");
        let auto = ScanPlan {
            theta_l: vec![-20.0, -25.0],
            shutter_s: vec![],
            auto_bracket: true,
            ..plan()
        };
        let id = store
            .insert_scans(&[NewScan {
                plan: auto,
                sweep_id: None,
                not_before: None,
            }])
            .unwrap()[0];
        let scan = store.next_for_hardware(now_unix()).unwrap().unwrap();
        // Home, then per θL move, meter, samples, HDR; extract, three fits and the
        // fit that chooses the model.
        assert_eq!(
            (scan.id, scan.state, scan.done, scan.total),
            (id, ScanState::Queued, 0, 14)
        );
        assert!(store
            .transition(id, &[ScanState::Queued], ScanState::Running, None)
            .unwrap());
        assert_eq!(next(&store, id, Lane::Hardware), Some(Step::Home));
        assert_eq!(next(&store, id, Lane::Processing), None);
        let steps = store.steps(id).unwrap();
        done(&mut store, id, &steps[0], &[]);
        done(&mut store, id, &steps[1], &[]);
        // Metering plans two captures after itself: the step total grows, the planned
        // total does not, and the metering counts once its bracket is captured.
        let bracket = ScanPlan::captures(-20.0, &[0.1, 0.01]);
        done(&mut store, id, &steps[2], &bracket);
        let scan = store.scan(id).unwrap().unwrap();
        assert_eq!(
            (scan.done, scan.total, scan.steps_done, scan.steps_total),
            (2, 14, 3, 16)
        );
        assert_eq!(scan.current_step.as_deref(), Some(&*bracket[0].describe()));
        assert_eq!(next(&store, id, Lane::Processing), None);
        assert_eq!(store.unprocessed_brackets().unwrap(), 0);
        let steps = store.steps(id).unwrap();
        done(&mut store, id, &steps[3], &[]);
        done(&mut store, id, &steps[4], &[]);
        assert_eq!(store.scan(id).unwrap().unwrap().done, 3);
        // The bracket is captured: processing may start while the arm moves on.
        assert_eq!(store.unprocessed_brackets().unwrap(), 1);
        assert_eq!(
            next(&store, id, Lane::Processing),
            Some(Step::Samples { theta_l: -20.0 })
        );
        assert_eq!(
            next(&store, id, Lane::Hardware),
            Some(Step::Move { theta_l: -25.0 })
        );
        let (processing_scan, samples) = store.next_for_processing(None).unwrap().unwrap();
        assert_eq!(processing_scan, id);
        // With the samples step running in the background, the HDR step is next; it is
        // also the HDR step ready to start ahead of the samples.
        let (_, beside) = store
            .next_for_processing(Some((id, samples.index)))
            .unwrap()
            .unwrap();
        assert_eq!(beside.step, Step::Hdr { theta_l: -20.0 });
        let (_, ahead) = store.next_hdr().unwrap().unwrap();
        assert_eq!(ahead.index, beside.index);
        store.step_started(id, samples.index).unwrap();
        drop(store);
        // Reopened after a crash: the processing step that was running runs again.
        let mut store = Store::open(&dir.join("gonio.sqlite")).unwrap();
        let (_, again) = store.next_for_processing(None).unwrap().unwrap();
        assert_eq!(
            (again.index, again.state),
            (samples.index, StepState::Started)
        );
        assert_eq!(store.next_for_hardware(now_unix()).unwrap().unwrap().id, id);
        // The hardware lane finishes first; the scan is done with the last processing
        // step, whichever lane ends last.
        while let Some(step) = store.next_step(id, Lane::Hardware).unwrap() {
            let followers = if matches!(step.step, Step::Meter { .. }) {
                ScanPlan::captures(-25.0, &[0.1])
            } else {
                Vec::new()
            };
            done(&mut store, id, &step, &followers);
        }
        assert!(store.next_for_hardware(now_unix()).unwrap().is_none());
        assert_eq!(store.unprocessed_brackets().unwrap(), 2);
        while let Some((_, step)) = store.next_for_processing(None).unwrap() {
            assert_eq!(store.scan(id).unwrap().unwrap().state, ScanState::Running);
            done(&mut store, id, &step, &[]);
        }
        let scan = store.scan(id).unwrap().unwrap();
        assert_eq!(
            (scan.state, scan.done, scan.total, scan.steps_done),
            (ScanState::Done, 14, 14, 17)
        );
        assert!(scan.finished.is_some() && scan.current_step.is_none());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn frames_awaiting_hdr_are_the_captures_of_brackets_not_merged() {
        let record = |index: u32, step: Step, done: bool, path: Option<&str>| StepRecord {
            index,
            step,
            state: if done {
                StepState::Done
            } else {
                StepState::Pending
            },
            started: None,
            finished: None,
            result: path.map(|p| serde_json::json!({ "path": p })),
        };
        let capture = |theta_l: f64, index: usize| Step::Capture {
            theta_l,
            index,
            shutter_s: 0.1,
        };
        let steps = [
            record(
                0,
                capture(-20.0, 0),
                true,
                Some("theta_l_-20.0/exp_00.tiff"),
            ),
            record(1, Step::Hdr { theta_l: -20.0 }, true, None),
            record(
                2,
                capture(-25.0, 0),
                true,
                Some("theta_l_-25.0/exp_00.tiff"),
            ),
            record(3, capture(-25.0, 1), false, None),
            record(4, Step::Hdr { theta_l: -25.0 }, false, None),
        ];
        assert_eq!(
            frames_awaiting_hdr(&steps),
            vec!["theta_l_-25.0/exp_00.tiff".to_owned()]
        );
    }

    #[test]
    fn processing_goes_on_while_a_device_is_away_but_not_when_paused() {
        let (dir, mut store) = temp_store("processable");
        let id = store
            .insert_scans(&[NewScan {
                plan: plan(),
                sweep_id: None,
                not_before: None,
            }])
            .unwrap()[0];
        store
            .transition(id, &[ScanState::Queued], ScanState::Running, None)
            .unwrap();
        for step in &store.steps(id).unwrap()[..4] {
            done(&mut store, id, step, &[]);
        }
        assert!(store.next_for_processing(None).unwrap().is_some());
        store
            .transition(id, &[ScanState::Running], ScanState::Interrupted, None)
            .unwrap();
        assert!(store.next_for_processing(None).unwrap().is_some());
        assert!(store.next_for_hardware(now_unix()).unwrap().is_none());
        store
            .transition(id, &[ScanState::Interrupted], ScanState::Paused, None)
            .unwrap();
        assert!(store.next_for_processing(None).unwrap().is_none());
        assert_eq!(store.unprocessed_brackets().unwrap(), 0);
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// A daemon start as `gonio serve` makes it: open, count the start, count the
    /// crashes (limit 3) of a previous daemon that died of a fault in lane `faulted`.
    /// Returns the store, the boot and the scans failed.
    fn restart(dir: &std::path::Path, faulted: Option<Lane>) -> (Store, i64, Vec<i64>) {
        let mut store = Store::open(&dir.join("gonio.sqlite")).unwrap();
        let boot = store.begin_boot().unwrap();
        let failed = store.count_crashes(3, faulted).unwrap();
        (store, boot, failed)
    }

    /// A running scan of two queued ones, and the index of its first step.
    fn running_scan(store: &mut Store) -> (Vec<i64>, u32) {
        let new = || NewScan {
            plan: plan(),
            sweep_id: None,
            not_before: None,
        };
        let ids = store.insert_scans(&[new(), new()]).unwrap();
        assert!(store
            .transition(ids[0], &[ScanState::Queued], ScanState::Running, None)
            .unwrap());
        let first = store.steps(ids[0]).unwrap()[0].index;
        (ids, first)
    }

    #[test]
    fn a_step_running_at_three_faults_of_its_lane_fails_its_scan_and_the_queue_goes_on() {
        let (dir, mut store) = temp_store("crashes");
        store.begin_boot().unwrap();
        let (ids, first) = running_scan(&mut store);
        for death in 1..=3 {
            // The step starts, then the daemon dies of a fault in the hardware lane:
            // the next start counts it.
            store.step_started(ids[0], first).unwrap();
            drop(store);
            let failed;
            (store, _, failed) = restart(&dir, Some(Lane::Hardware));
            let scan = store.scan(ids[0]).unwrap().unwrap();
            if death < 3 {
                assert!(failed.is_empty());
                assert_eq!(scan.state, ScanState::Running);
                assert_eq!(
                    store.next_for_hardware(now_unix()).unwrap().unwrap().id,
                    ids[0]
                );
            } else {
                assert_eq!(failed, vec![ids[0]]);
                assert_eq!(scan.state, ScanState::Failed);
                assert_eq!(
                    scan.error.as_deref(),
                    Some("step \"home the arm\" crashed the daemon 3 times")
                );
                assert_eq!(store.steps(ids[0]).unwrap()[0].state, StepState::Pending);
            }
        }
        // The queue goes on with the next scan; a further start counts nothing more.
        assert_eq!(
            store.next_for_hardware(now_unix()).unwrap().unwrap().id,
            ids[1]
        );
        drop(store);
        assert!(restart(&dir, Some(Lane::Hardware)).2.is_empty());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn kills_faults_of_another_lane_and_deaths_a_step_did_not_run_at_are_not_its_crashes() {
        let (dir, mut store) = temp_store("kills");
        store.begin_boot().unwrap();
        let (ids, first) = running_scan(&mut store);
        // Killed (or a power cut) five times while the step ran: no fault recorded, no
        // crash.
        for _ in 0..5 {
            store.step_started(ids[0], first).unwrap();
            drop(store);
            let failed;
            (store, _, failed) = restart(&dir, None);
            assert!(failed.is_empty());
        }
        // Faults of the processing lane while this hardware step ran: not its.
        for _ in 0..3 {
            store.step_started(ids[0], first).unwrap();
            drop(store);
            let failed;
            (store, _, failed) = restart(&dir, Some(Lane::Processing));
            assert!(failed.is_empty());
        }
        // Two faults while it ran, each followed by a fault in a start that had not
        // run it again yet: two crashes, not four.
        for _ in 0..2 {
            store.step_started(ids[0], first).unwrap();
            for _ in 0..2 {
                drop(store);
                let failed;
                (store, _, failed) = restart(&dir, Some(Lane::Hardware));
                assert!(failed.is_empty());
            }
        }
        let scan = store.scan(ids[0]).unwrap().unwrap();
        assert_eq!(scan.state, ScanState::Running);
        // The third fault it runs at fails it.
        store.step_started(ids[0], first).unwrap();
        drop(store);
        let (store, _, failed) = restart(&dir, Some(Lane::Hardware));
        assert_eq!(failed, vec![ids[0]]);
        drop(store);
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn start_time_and_transitions_gate_the_queue() {
        let (dir, mut store) = temp_store("gate");
        let later = now_unix() + 3600;
        let (sweep, ids) = store
            .insert_sweep(&serde_json::json!({}), Some(later), vec![plan(), plan()])
            .unwrap();
        assert_eq!(store.scans_of_sweep(sweep).unwrap().len(), 2);
        assert!(store.next_for_hardware(now_unix()).unwrap().is_none());
        assert_eq!(store.next_for_hardware(later).unwrap().unwrap().id, ids[0]);
        assert!(!store
            .transition(ids[0], &[ScanState::Running], ScanState::Paused, None)
            .unwrap());
        assert!(store
            .transition(ids[0], &[ScanState::Queued], ScanState::Cancelled, None)
            .unwrap());
        assert_eq!(store.next_for_hardware(later).unwrap().unwrap().id, ids[1]);
        assert_eq!(store.begin_boot().unwrap(), 1);
        assert_eq!(store.begin_boot().unwrap(), 2);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
