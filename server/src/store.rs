//! The durable queue: scans, their steps, sweeps and the hardware log in SQLite
//! (WAL journal, `synchronous = FULL`, so a committed step survives power loss).
//!
//! Here: the schema and the connection (opened, written with the journal's reserve as
//! the last room). What is stored is in `records`; reading and writing scans, sweeps,
//! steps, the queue the lanes take from, daemon starts and the hardware log, in
//! submodules of those names.

mod boots;
mod hardware_log;
mod journal;
mod queue;
mod records;
mod scans;
mod steps;
mod sweeps;
#[cfg(test)]
mod tests;

use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{Connection, Transaction, TransactionBehavior};

use super::storage;

pub use journal::brackets_behind;
pub use records::{
    now_rfc3339, now_unix, LogEntry, NewScan, ScanRecord, ScanState, StepRecord, StepState,
    StoreError, PROCESSABLE,
};
pub use sweeps::Rescheduled;

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
    /// A transaction that takes the write lock at once (`BEGIN IMMEDIATE`): one that
    /// reads and then writes in a deferred transaction fails with `database is locked`
    /// when another connection wrote in between, without waiting for the busy timeout.
    fn write_transaction(&mut self) -> Result<Transaction<'_>, StoreError> {
        Ok(self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)?)
    }
}
