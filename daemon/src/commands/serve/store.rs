//! The durable queue: scans, their steps, sweeps and the hardware log in SQLite
//! (WAL journal, `synchronous = FULL`, so a committed step survives power loss).

use std::path::Path;
use std::time::Duration;

use rusqlite::{params, Connection, OptionalExtension, Transaction, TransactionBehavior};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::plan::{ScanPlan, Step};

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

impl From<rusqlite::Error> for StoreError {
    fn from(error: rusqlite::Error) -> Self {
        StoreError::Sql(error)
    }
}

fn json_err(what: &'static str) -> impl FnOnce(serde_json::Error) -> StoreError {
    move |error| StoreError::Json { what, error }
}

/// Life cycle of a scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
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
    /// operator resumes it). The reason is stored with it.
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
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
    pub done: u32,
    pub total: u32,
    /// The step being executed or next in line.
    pub current_step: Option<String>,
}

/// One step as stored.
#[derive(Debug, Clone, Serialize)]
pub struct StepRecord {
    /// Position key: increasing in execution order, not contiguous.
    pub index: u32,
    pub step: Step,
    pub state: StepState,
    pub started: Option<String>,
    pub finished: Option<String>,
    pub result: Option<Value>,
}

/// One entry of the hardware log: what the hardware owner did, in which daemon run.
#[derive(Debug, Clone, Serialize)]
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

const SCAN_COLUMNS: &str =
    "id, plan, state, error, sweep_id, not_before, created, started, finished,
    (SELECT COUNT(*) FROM steps WHERE scan_id = scans.id AND state = 'done'),
    (SELECT COUNT(*) FROM steps WHERE scan_id = scans.id),
    (SELECT step FROM steps WHERE scan_id = scans.id AND state != 'done' ORDER BY idx LIMIT 1)";

/// A connection to the store. Each thread opens its own.
pub struct Store {
    conn: Connection,
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
        Ok(Self { conn })
    }

    /// Called once at start, after [`Store::begin_boot`] and before anything runs.
    /// Unless the previous daemon stopped cleanly ([`Store::record_clean_stop`]), it
    /// died, and each step it had started and not finished counts that death. A step
    /// that has now been running at `limit` deaths fails its scan ("... crashed the
    /// daemon N times") and goes back to pending, so the queue goes on (and a resume
    /// retries it). Returns the ids of the scans failed.
    pub fn count_crashes(&mut self, limit: u32) -> Result<Vec<i64>, StoreError> {
        let tx = self.write_transaction()?;
        let died: Option<i64> = tx
            .query_row(
                "SELECT value - 1 FROM meta WHERE key = 'boot' AND NOT EXISTS
                   (SELECT 1 FROM meta clean WHERE clean.key = 'clean_stop'
                    AND clean.value = meta.value - 1)",
                [],
                |r| r.get(0),
            )
            .optional()?;
        if let Some(previous) = died {
            // Steps started before boots were recorded on them count too.
            tx.execute(
                "UPDATE steps SET crashes = crashes + 1
                 WHERE state = 'started' AND (started_boot = ?1 OR started_boot IS NULL)",
                [previous],
            )?;
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
    }

    /// A transaction that takes the write lock at once (`BEGIN IMMEDIATE`): one that
    /// reads and then writes in a deferred transaction fails with `database is locked`
    /// when another connection wrote in between, without waiting for the busy timeout.
    fn write_transaction(&mut self) -> Result<Transaction<'_>, StoreError> {
        Ok(self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)?)
    }

    /// Records that daemon start `boot` is stopping on request (a signal), so the
    /// steps it leaves unfinished do not count as crashes at the next start.
    pub fn record_clean_stop(&mut self, boot: i64) -> Result<(), StoreError> {
        self.conn.execute(
            "INSERT INTO meta (key, value) VALUES ('clean_stop', ?1)
             ON CONFLICT(key) DO UPDATE SET value = excluded.value",
            [boot],
        )?;
        Ok(())
    }

    /// Counts a daemon start and returns its number.
    pub fn begin_boot(&mut self) -> Result<i64, StoreError> {
        let tx = self.write_transaction()?;
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
    }

    /// Queues scans, plans and steps included, in one transaction.
    pub fn insert_scans(&mut self, scans: &[NewScan]) -> Result<Vec<i64>, StoreError> {
        let tx = self.write_transaction()?;
        let ids = insert_scans_tx(&tx, scans)?;
        tx.commit()?;
        Ok(ids)
    }

    /// Stores a sweep and queues its scans, in one transaction.
    pub fn insert_sweep(
        &mut self,
        request: &Value,
        start_at: Option<i64>,
        plans: Vec<ScanPlan>,
    ) -> Result<(i64, Vec<i64>), StoreError> {
        let tx = self.write_transaction()?;
        tx.execute(
            "INSERT INTO sweeps (request, created, start_at) VALUES (?1, ?2, ?3)",
            params![request.to_string(), now_rfc3339(), start_at],
        )?;
        let sweep_id = tx.last_insert_rowid();
        let scans: Vec<NewScan> = plans
            .into_iter()
            .map(|plan| NewScan {
                plan,
                sweep_id: Some(sweep_id),
                not_before: start_at,
            })
            .collect();
        let ids = insert_scans_tx(&tx, &scans)?;
        tx.commit()?;
        Ok((sweep_id, ids))
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
        let sql = format!("SELECT {SCAN_COLUMNS} FROM scans {filter}");
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
                    r.get::<_, u32>(9)?,
                    r.get::<_, u32>(10)?,
                    r.get::<_, Option<String>>(11)?,
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
                    done,
                    total,
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
                        current_step,
                    })
                },
            )
            .collect()
    }

    pub fn scans(&self) -> Result<Vec<ScanRecord>, StoreError> {
        self.query_scans("ORDER BY id", [])
    }

    pub fn scans_of_sweep(&self, sweep_id: i64) -> Result<Vec<ScanRecord>, StoreError> {
        self.query_scans("WHERE sweep_id = ?1 ORDER BY id", [sweep_id])
    }

    pub fn scan(&self, id: i64) -> Result<Option<ScanRecord>, StoreError> {
        Ok(self.query_scans("WHERE id = ?1", [id])?.into_iter().next())
    }

    /// The scan the hardware owner should work on: one left running (resume after a
    /// crash) first, else the oldest queued scan whose start time has come.
    pub fn next_runnable(&self, now: i64) -> Result<Option<ScanRecord>, StoreError> {
        let mut scans = self.query_scans(
            "WHERE state = 'running'
                OR (state = 'queued' AND (not_before IS NULL OR not_before <= ?1))
             ORDER BY state = 'running' DESC, id LIMIT 1",
            [now],
        )?;
        Ok(scans.pop())
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
        let tx = self.write_transaction()?;
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
    }

    /// Moves every scan in state `from` to `to` with reason `error` (e.g. interrupted ->
    /// running once the device is back); returns their ids.
    pub fn transition_all(
        &mut self,
        from: ScanState,
        to: ScanState,
        error: Option<&str>,
    ) -> Result<Vec<i64>, StoreError> {
        let tx = self.write_transaction()?;
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
    }

    pub fn steps(&self, scan_id: i64) -> Result<Vec<StepRecord>, StoreError> {
        self.query_steps("WHERE scan_id = ?1 ORDER BY idx", scan_id)
    }

    /// The first step of a scan not done yet.
    pub fn next_step(&self, scan_id: i64) -> Result<Option<StepRecord>, StoreError> {
        Ok(self
            .query_steps(
                "WHERE scan_id = ?1 AND state != 'done' ORDER BY idx LIMIT 1",
                scan_id,
            )?
            .pop())
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
        self.conn.execute(
            "UPDATE steps SET state = ?3, started = ?4,
                started_boot = (SELECT value FROM meta WHERE key = 'boot')
             WHERE scan_id = ?1 AND idx = ?2",
            params![scan_id, index, StepState::Started.as_str(), now_rfc3339()],
        )?;
        Ok(())
    }

    /// Records a step as done with its result and inserts the steps it planned
    /// (`followers`, right after it), in one transaction; when it was the last step of
    /// a still running scan, the scan becomes done in the same transaction.
    pub fn step_done(
        &mut self,
        scan_id: i64,
        index: u32,
        result: &Value,
        followers: &[Step],
    ) -> Result<(), StoreError> {
        if followers.len() >= STEP_SPACING as usize {
            return Err(StoreError::TooManySteps(followers.len()));
        }
        let tx = self.write_transaction()?;
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
        tx.execute(
            "UPDATE scans SET state = 'done', finished = ?2, error = NULL
             WHERE id = ?1 AND state = 'running'
               AND NOT EXISTS (SELECT 1 FROM steps WHERE scan_id = ?1 AND state != 'done')",
            params![scan_id, now],
        )?;
        tx.commit()?;
        Ok(())
    }

    /// Appends to the hardware log.
    pub fn log(
        &mut self,
        boot: i64,
        scan_id: Option<i64>,
        action: &str,
        detail: &str,
    ) -> Result<(), StoreError> {
        self.conn.execute(
            "INSERT INTO hardware_log (boot, time, scan_id, action, detail)
             VALUES (?1, ?2, ?3, ?4, ?5)",
            params![boot, now_rfc3339(), scan_id, action, detail],
        )?;
        Ok(())
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

    #[test]
    fn scan_completes_when_its_last_step_is_done_and_survives_reopen() {
        let (dir, mut store) = temp_store("done");
        let ids = store
            .insert_scans(&[NewScan {
                plan: plan(),
                sweep_id: None,
                not_before: None,
            }])
            .unwrap();
        let id = ids[0];
        let scan = store.next_runnable(now_unix()).unwrap().unwrap();
        assert_eq!(
            (scan.id, scan.state, scan.done, scan.total),
            (id, ScanState::Queued, 0, 9)
        );
        assert!(store
            .transition(id, &[ScanState::Queued], ScanState::Running, None)
            .unwrap());
        let steps = store.steps(id).unwrap();
        // The first step plans one more right after itself.
        let extra = Step::Capture {
            theta_l: -20.0,
            index: 2,
            shutter_s: 0.001,
        };
        store.step_started(id, steps[0].index).unwrap();
        store
            .step_done(
                id,
                steps[0].index,
                &Value::Null,
                std::slice::from_ref(&extra),
            )
            .unwrap();
        let steps = store.steps(id).unwrap();
        assert_eq!((steps.len(), &steps[1].step), (10, &extra));
        for step in &steps[1..steps.len() - 1] {
            store.step_started(id, step.index).unwrap();
            store.step_done(id, step.index, &Value::Null, &[]).unwrap();
        }
        assert_eq!(store.scan(id).unwrap().unwrap().state, ScanState::Running);
        let last = steps[9].index;
        store.step_started(id, last).unwrap();
        drop(store);
        // Reopened after a crash: the started step is not done and the scan resumes.
        let mut store = Store::open(&dir.join("gonio.sqlite")).unwrap();
        let scan = store.next_runnable(now_unix()).unwrap().unwrap();
        assert_eq!(
            (scan.id, scan.state, scan.done),
            (id, ScanState::Running, 9)
        );
        assert_eq!(store.steps(id).unwrap()[9].state, StepState::Started);
        store
            .step_done(id, last, &serde_json::json!({"ok": true}), &[])
            .unwrap();
        let scan = store.scan(id).unwrap().unwrap();
        assert_eq!((scan.state, scan.done), (ScanState::Done, 10));
        assert!(scan.finished.is_some());
        assert!(store.next_runnable(now_unix()).unwrap().is_none());
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// A daemon start as `gonio serve` makes it: open, count the start, count the
    /// crashes (limit 3). Returns the store, the boot and the scans failed.
    fn restart(dir: &std::path::Path) -> (Store, i64, Vec<i64>) {
        let mut store = Store::open(&dir.join("gonio.sqlite")).unwrap();
        let boot = store.begin_boot().unwrap();
        let failed = store.count_crashes(3).unwrap();
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
    fn a_step_running_at_three_deaths_fails_its_scan_and_the_queue_goes_on() {
        let (dir, mut store) = temp_store("crashes");
        store.begin_boot().unwrap();
        let (ids, first) = running_scan(&mut store);
        for death in 1..=3 {
            // The step starts, then the daemon dies: the next start counts it.
            store.step_started(ids[0], first).unwrap();
            drop(store);
            let failed;
            (store, _, failed) = restart(&dir);
            let scan = store.scan(ids[0]).unwrap().unwrap();
            if death < 3 {
                assert!(failed.is_empty());
                assert_eq!(scan.state, ScanState::Running);
                assert_eq!(store.next_runnable(now_unix()).unwrap().unwrap().id, ids[0]);
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
        assert_eq!(store.next_runnable(now_unix()).unwrap().unwrap().id, ids[1]);
        drop(store);
        assert!(restart(&dir).2.is_empty());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn clean_stops_and_deaths_a_step_did_not_run_at_are_not_its_crashes() {
        let (dir, mut store) = temp_store("clean-stops");
        let mut boot = store.begin_boot().unwrap();
        let (ids, first) = running_scan(&mut store);
        // Stopped on a signal three times while the step ran: no crash.
        for _ in 0..3 {
            store.step_started(ids[0], first).unwrap();
            store.record_clean_stop(boot).unwrap();
            drop(store);
            let failed;
            (store, boot, failed) = restart(&dir);
            assert!(failed.is_empty());
        }
        // Two deaths while it ran, each followed by a death in a start that had not
        // run it again yet: two crashes, not four.
        for _ in 0..2 {
            store.step_started(ids[0], first).unwrap();
            for _ in 0..2 {
                drop(store);
                let failed;
                (store, _, failed) = restart(&dir);
                assert!(failed.is_empty());
            }
        }
        let scan = store.scan(ids[0]).unwrap().unwrap();
        assert_eq!(scan.state, ScanState::Running);
        // The third death it runs at fails it.
        store.step_started(ids[0], first).unwrap();
        drop(store);
        let (store, _, failed) = restart(&dir);
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
        assert!(store.next_runnable(now_unix()).unwrap().is_none());
        assert_eq!(store.next_runnable(later).unwrap().unwrap().id, ids[0]);
        assert!(!store
            .transition(ids[0], &[ScanState::Running], ScanState::Paused, None)
            .unwrap());
        assert!(store
            .transition(ids[0], &[ScanState::Queued], ScanState::Cancelled, None)
            .unwrap());
        assert_eq!(store.next_runnable(later).unwrap().unwrap().id, ids[1]);
        assert_eq!(store.begin_boot().unwrap(), 1);
        assert_eq!(store.begin_boot().unwrap(), 2);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
