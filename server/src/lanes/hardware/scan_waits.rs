//! A scan the hardware lane cannot go on with waits, with its reason: for the arm or
//! the camera, for its sample to be mounted, for disk space (looked at again with
//! backoff, against what its next steps will write); waiting scans go back to the
//! queue once what they waited for may have changed.

use super::{waiting_for_space, HardwareLane};
use crate::lanes::backoff::Backoff;
use crate::plan::{mount_reason, Lane};
use crate::storage;
use crate::store::{now_unix, ScanRecord, ScanState, StepState, StoreError};
use crate::sync::lock;

impl HardwareLane {
    /// Without an arm or a camera, the scan next in line waits, with the reason.
    pub(super) fn wait_for_devices(&mut self) -> Result<(), StoreError> {
        let Some(scan) = self.store.next_for_hardware(now_unix())? else {
            return Ok(());
        };
        let reason = if self.arm.is_none() {
            format!(
                "arm not available: {}",
                self.arm_error.as_deref().unwrap_or("not connected")
            )
        } else {
            let camera = lock(&self.shared.hardware).camera.error.clone();
            format!(
                "camera not available: {}",
                camera.as_deref().unwrap_or("not connected")
            )
        };
        if scan.state == ScanState::Queued
            && self.store.transition(
                scan.id,
                &[ScanState::Queued],
                ScanState::Waiting,
                Some(&reason),
            )?
        {
            tracing::info!("scan {}: waiting: {reason}", scan.id);
            self.shared.changed(scan.id);
        }
        Ok(())
    }

    /// Whether the sample `scan` measures is known to be on the cylinder, or the
    /// carousel brings it; if neither, the scan waits for the operator to mount it and
    /// confirm, before any of its steps.
    pub(super) fn sample_ready(&mut self, scan: &ScanRecord) -> Result<bool, StoreError> {
        let sample = &scan.plan.sample;
        if self.shared.mount.is_mounted(sample) || self.shared.config.carousel.is_some() {
            return Ok(true);
        }
        let reason = mount_reason(sample);
        if self.store.transition(
            scan.id,
            &[ScanState::Queued, ScanState::Running],
            ScanState::Waiting,
            Some(&reason),
        )? {
            tracing::info!("scan {}: waiting: {reason}", scan.id);
            self.log(Some(scan.id), "wait", &reason)?;
            self.shared.changed(scan.id);
        }
        Ok(false)
    }

    /// Waiting scans go back to the queue (what they waited for may have changed).
    pub(super) fn requeue_waiting(&mut self, why: &str) -> Result<(), StoreError> {
        for id in self
            .store
            .transition_all(ScanState::Waiting, ScanState::Queued, None)?
        {
            tracing::info!("scan {id}: {why}, queued again");
            self.shared.changed(id);
        }
        Ok(())
    }

    /// While scans wait for disk space nothing starts: the scan next in line waits too,
    /// and the free space is looked at again with backoff; once the next steps of every
    /// scan waiting for it fit, those scans are queued again. Returns whether scans
    /// still wait for space.
    pub(super) fn waiting_for_disk(&mut self) -> Result<bool, StoreError> {
        let waiting: Vec<ScanRecord> = self
            .store
            .scans_in(ScanState::Waiting)?
            .into_iter()
            .filter(|s| s.error.as_deref().is_some_and(storage::is_disk_wait))
            .collect();
        if waiting.is_empty() {
            self.disk_retry = Backoff::now();
            return Ok(false);
        }
        if !self.disk_retry.due() {
            return Ok(true);
        }
        let mut need = 0;
        for scan in &waiting {
            need = need.max(self.scan_need(scan)?);
        }
        match self.shared.storage.check(need) {
            Ok(()) => {
                self.disk_retry = Backoff::now();
                self.log(None, "disk", "space for the waiting scans")?;
                for scan in waiting {
                    if self.store.transition(
                        scan.id,
                        &[ScanState::Waiting],
                        ScanState::Queued,
                        None,
                    )? {
                        tracing::info!("scan {}: disk space back, queued again", scan.id);
                        self.shared.changed(scan.id);
                    }
                }
                Ok(false)
            }
            Err(reason) => {
                self.disk_retry = self.disk_retry.later();
                if let Some(next) = self.store.next_for_hardware(now_unix())? {
                    waiting_for_space(&self.shared, &mut self.store, &next, &reason)?;
                }
                for scan in &waiting {
                    waiting_for_space(&self.shared, &mut self.store, scan, &reason)?;
                }
                Ok(true)
            }
        }
    }

    /// Pixels of the frames of scan `id`: from its own setup, else the current one.
    pub(super) fn frame_pixels(&self, id: i64) -> u64 {
        let own =
            gonio_processing::extract::read_setup(&self.shared.scan_dir(id).join("setup.json"));
        storage::frame_pixels(own.ok().or_else(|| self.setup()).as_ref())
    }

    /// The most that the next hardware step and the next processing step of `scan`
    /// will write.
    fn scan_need(&self, scan: &ScanRecord) -> Result<u64, StoreError> {
        let pixels = self.frame_pixels(scan.id);
        let steps = self.store.steps(scan.id)?;
        let pending = || steps.iter().filter(|s| s.state != StepState::Done);
        Ok([Lane::Hardware, Lane::Processing]
            .into_iter()
            .filter_map(|lane| pending().find(|s| s.step.lane() == lane))
            .map(|s| storage::step_need(&s.step, &scan.plan, pixels))
            .max()
            .unwrap_or(0))
    }
}
