//! Sweeps in the store: a sweep's request stored with the scans it queues, in one
//! transaction, and read back.

use rusqlite::{params, OptionalExtension};
use serde_json::Value;

use super::records::{json_err, now_rfc3339, NewScan, StoreError, SweepRecord};
use super::scans::insert_scans_tx;
use super::Store;
use crate::plan::ScanPlan;

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
}
