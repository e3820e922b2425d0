//! Scans in the store: queued (plan and planned steps in one transaction), read back
//! with their progress and current step, and moved from state to state.

use rusqlite::{params, OptionalExtension, Transaction};

use super::records::{
    json_err, now_rfc3339, waits_for_sample, NewScan, ScanRecord, ScanState, StoreError,
    STEP_SPACING,
};
use super::Store;
use crate::plan::Step;

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

impl Store {
    /// Queues scans, plans and steps included, in one transaction.
    pub fn insert_scans(&mut self, scans: &[NewScan]) -> Result<Vec<i64>, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            let ids = insert_scans_tx(&tx, scans)?;
            tx.commit()?;
            Ok(ids)
        })
    }
    pub(super) fn query_scans(
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
            set_state_tx(&tx, id, to, error)?;
            tx.commit()?;
            Ok(true)
        })
    }

    /// An operator's control: as [`Store::transition`] with the reason cleared, but
    /// never for a scan that waits for its sample to be mounted unless `sample_waits`
    /// is set (only confirming or cancelling ends that wait).
    pub fn control(
        &mut self,
        id: i64,
        from: &[ScanState],
        to: ScanState,
        sample_waits: bool,
    ) -> Result<bool, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            let moved = control_tx(&tx, "id = ?1", id, from, to, sample_waits)?;
            tx.commit()?;
            Ok(!moved.is_empty())
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
}

/// Moves the scans `filter` selects (an SQL condition on `arg`, `?1`) that are in one
/// of the states `from` to `to`, clearing their reason, except those waiting for their
/// sample to be mounted unless `sample_waits` is set; returns their ids.
pub(super) fn control_tx(
    tx: &Transaction<'_>,
    filter: &str,
    arg: i64,
    from: &[ScanState],
    to: ScanState,
    sample_waits: bool,
) -> Result<Vec<i64>, StoreError> {
    let scans: Vec<(i64, String, Option<String>, String)> = {
        let mut stmt = tx.prepare(&format!(
            "SELECT id, state, error, json_extract(plan, '$.sample') FROM scans
             WHERE {filter} ORDER BY id"
        ))?;
        let rows = stmt
            .query_map([arg], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)))?
            .collect::<Result<_, _>>()?;
        rows
    };
    let mut moved = Vec::new();
    for (id, state, error, sample) in scans {
        let state = ScanState::parse(&state)?;
        let waiting = waits_for_sample(state, error.as_deref(), &sample);
        if from.contains(&state) && (sample_waits || !waiting) {
            set_state_tx(tx, id, to, None)?;
            moved.push(id);
        }
    }
    Ok(moved)
}

/// Sets the state of scan `id` to `to` with reason `error`, stamping when it started
/// running and when it ended.
pub(super) fn set_state_tx(
    tx: &Transaction<'_>,
    id: i64,
    to: ScanState,
    error: Option<&str>,
) -> Result<(), StoreError> {
    tx.execute(
        "UPDATE scans SET state = ?2, error = ?3,
            started = CASE WHEN ?2 = 'running' AND started IS NULL THEN ?4 ELSE started END,
            finished = CASE WHEN ?2 IN ('done', 'failed', 'cancelled') THEN ?4
                            WHEN ?2 IN ('queued', 'running') THEN NULL
                            ELSE finished END
         WHERE id = ?1",
        params![id, to.as_str(), error, now_rfc3339()],
    )?;
    Ok(())
}

pub(super) fn insert_scans_tx(
    tx: &Transaction<'_>,
    scans: &[NewScan],
) -> Result<Vec<i64>, StoreError> {
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
