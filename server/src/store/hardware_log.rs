//! The hardware log: what the hardware lane did, in which daemon start, appended and
//! read back in order.

use rusqlite::params;

use super::records::{now_rfc3339, LogEntry, StoreError};
use super::Store;

impl Store {
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
    /// When scan `id` last began to wait (its last `wait` entry), RFC 3339.
    pub fn waiting_since(&self, id: i64) -> Result<Option<String>, StoreError> {
        let mut stmt = self.conn.prepare(
            "SELECT time FROM hardware_log WHERE scan_id = ?1 AND action = 'wait'
             ORDER BY id DESC LIMIT 1",
        )?;
        let mut rows = stmt.query_map([id], |r| r.get::<_, String>(0))?;
        Ok(rows.next().transpose()?)
    }

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
