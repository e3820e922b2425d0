//! Daemon starts: each one counted, and the deaths of the previous daemon counted
//! against the steps it was running, so a step that keeps crashing it fails its scan
//! instead of crashing every start.

use rusqlite::params;

use super::records::{json_err, now_rfc3339, StoreError};
use super::Store;
use crate::plan::{Lane, Step};

impl Store {
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
}
