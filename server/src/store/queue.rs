//! What the lanes take next from the queue: the scan the hardware lane works on, the
//! step a lane runs next in a scan, the processing steps ready in the scans being
//! processed, and the brackets and frames still waiting for processing.

use super::journal::{beside_steps, frames_awaiting_hdr, ready_step, unprocessed_brackets};
use super::records::{ScanRecord, ScanState, StepRecord, StoreError, PROCESSABLE};
use super::Store;
use crate::plan::{Lane, Step};

impl Store {
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
    /// the steps the lane runs beside the others, count as done here.
    pub fn next_for_processing(
        &self,
        running: &[(i64, u32)],
    ) -> Result<Option<(i64, StepRecord)>, StoreError> {
        for id in self.processable_ids()? {
            let mut steps = self.steps(id)?;
            steps.retain(|s| !running.contains(&(id, s.index)));
            if let Some(step) = ready_step(&steps, Lane::Processing) {
                return Ok(Some((id, step.clone())));
            }
        }
        Ok(None)
    }

    /// The step the processing lane starts next beside the others ([`beside_steps`]), in
    /// the oldest scan being processed that has one, with that scan's id: one of each
    /// kind at a time, so none of a kind among `running` (scan id, step index), the
    /// steps it runs beside the others now. An HDR step is ready once its bracket is
    /// captured, the auto fit once `samples.csv` is gathered.
    pub fn next_beside(
        &self,
        running: &[(i64, u32)],
    ) -> Result<Option<(i64, StepRecord)>, StoreError> {
        let ids = self.processable_ids()?;
        let mut journals = Vec::with_capacity(ids.len());
        for id in ids {
            journals.push((id, self.steps(id)?));
        }
        let busy: Vec<std::mem::Discriminant<Step>> = journals
            .iter()
            .flat_map(|(id, steps)| {
                steps
                    .iter()
                    .filter(|s| running.contains(&(*id, s.index)))
                    .map(|s| std::mem::discriminant(&s.step))
            })
            .collect();
        for (id, steps) in &journals {
            let own: Vec<u32> = running
                .iter()
                .filter(|(scan, _)| scan == id)
                .map(|(_, index)| *index)
                .collect();
            let next = beside_steps(steps, &own)
                .find(|s| !busy.contains(&std::mem::discriminant(&s.step)));
            if let Some(step) = next {
                return Ok(Some((*id, step.clone())));
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
    /// The step of a scan that `lane` runs next, if it has one ready.
    pub fn next_step(&self, scan_id: i64, lane: Lane) -> Result<Option<StepRecord>, StoreError> {
        Ok(ready_step(&self.steps(scan_id)?, lane).cloned())
    }
}
