//! A scan's steps in the store (its journal): read back, recorded as started (before
//! the hardware is touched) and as done with their result and the steps they plan
//! after themselves; a scan is done with its last step.

use rusqlite::params;
use serde_json::Value;

use super::records::{json_err, now_rfc3339, StepRecord, StepState, StoreError, STEP_SPACING};
use super::Store;
use crate::plan::Step;

/// Marks scan `?1` done at time `?2` if it is running and every step is done.
const COMPLETE_SCAN: &str = "UPDATE scans SET state = 'done', finished = ?2, error = NULL
    WHERE id = ?1 AND state = 'running'
      AND NOT EXISTS (SELECT 1 FROM steps WHERE scan_id = ?1 AND state != 'done')";

impl Store {
    pub fn steps(&self, scan_id: i64) -> Result<Vec<StepRecord>, StoreError> {
        self.query_steps("WHERE scan_id = ?1 ORDER BY idx", scan_id)
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

    /// Records a step as done at `finished` (RFC 3339: a step run in the background is
    /// recorded when the lane next looks, after it ended) with its result and inserts
    /// the steps it planned (`followers`, right after it), in one transaction; when it
    /// was the last step of a still running scan, the scan becomes done in the same
    /// transaction (finished now). Returns whether it did.
    pub fn step_done(
        &mut self,
        scan_id: i64,
        index: u32,
        result: &Value,
        followers: &[Step],
        finished: &str,
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
                    finished,
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
}
