//! Sweeps in the store: a sweep's request stored with the scans it queues, in one
//! transaction, and read back; its scans moved together (pause, resume, cancel) and
//! its start time changed while it is scheduled, each in one transaction.

use rusqlite::{params, OptionalExtension};
use serde_json::Value;

use super::records::{json_err, now_rfc3339, NewScan, ScanState, StoreError, SweepRecord};
use super::scans::{control_tx, insert_scans_tx};
use super::Store;
use crate::plan::ScanPlan;

/// What changing a sweep's start time found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rescheduled {
    /// The start time is changed, for the sweep and each of its scans.
    Done,
    NoSuchSweep,
    /// The sweep is not scheduled: its start time has come (or it had none), or a scan
    /// of it has started, or none is left to start.
    NotScheduled,
}

impl Store {
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

    /// Moves to `to`, in one transaction, every scan of sweep `id` that is in one of the
    /// states `from` and, unless `sample_waits` is set, does not wait for its sample to
    /// be mounted; returns their ids (none: no scan of the sweep allowed it).
    pub fn transition_sweep(
        &mut self,
        id: i64,
        from: &[ScanState],
        to: ScanState,
        sample_waits: bool,
    ) -> Result<Vec<i64>, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            let moved = control_tx(&tx, "sweep_id = ?1", id, from, to, sample_waits)?;
            tx.commit()?;
            Ok(moved)
        })
    }

    /// Changes the start time of sweep `id` to `start_at` (Unix seconds; `None`: now),
    /// with its scans', if it is scheduled at `now`: its start time is still ahead, no
    /// scan of it has started and one is queued.
    pub fn reschedule_sweep(
        &mut self,
        id: i64,
        start_at: Option<i64>,
        now: i64,
    ) -> Result<Rescheduled, StoreError> {
        self.writing(|store| {
            let tx = store.write_transaction()?;
            let current: Option<Option<i64>> = tx
                .query_row("SELECT start_at FROM sweeps WHERE id = ?1", [id], |r| {
                    r.get(0)
                })
                .optional()?;
            let Some(current) = current else {
                return Ok(Rescheduled::NoSuchSweep);
            };
            let (started, queued): (i64, i64) = tx.query_row(
                "SELECT COUNT(*) FILTER (WHERE started IS NOT NULL),
                        COUNT(*) FILTER (WHERE state = 'queued')
                 FROM scans WHERE sweep_id = ?1",
                [id],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )?;
            if current.is_none_or(|t| t <= now) || started > 0 || queued == 0 {
                return Ok(Rescheduled::NotScheduled);
            }
            tx.execute(
                "UPDATE sweeps SET start_at = ?2 WHERE id = ?1",
                params![id, start_at],
            )?;
            tx.execute(
                "UPDATE scans SET not_before = ?2 WHERE sweep_id = ?1",
                params![id, start_at],
            )?;
            tx.commit()?;
            Ok(Rescheduled::Done)
        })
    }
}
