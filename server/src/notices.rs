//! Which changes call a person (server/src/daemon.md, "Notifications"): a scan that
//! starts waiting for its sample to be mounted, a scan that fails, a sweep whose scans
//! have all ended. The publisher shows each changed scan here; each of these is
//! noticed once, when it happens in this daemon run (what was so at start is not); a
//! sweep that ends again after one of its scans was resumed, again.

use std::collections::{BTreeSet, HashMap};

use crate::notify::{Notice, Notifier};
use crate::store::{now_unix, ScanRecord, ScanState, Store, StoreError};
use crate::sweep_state::sweep_state;

/// What of a scan calls for a person, if anything.
fn calls_for(scan: &ScanRecord) -> Option<&'static str> {
    if scan.waits_for_sample() {
        Some("scan-waiting")
    } else if scan.state == ScanState::Failed {
        Some("scan-failed")
    } else {
        None
    }
}

/// The scans and sweeps as last seen, and where notices go.
pub struct Notices {
    notifier: Notifier,
    /// What each scan last called for.
    seen: HashMap<i64, Option<&'static str>>,
    /// Sweeps whose scans have all ended.
    ended: BTreeSet<i64>,
}

impl Notices {
    /// Starts from the store as it is: nothing already so is noticed.
    pub fn new(store: &Store, notifier: Notifier) -> Result<Self, StoreError> {
        let mut seen = HashMap::new();
        for scan in store.scans()? {
            seen.insert(scan.id, calls_for(&scan));
        }
        let mut ended = BTreeSet::new();
        for id in store.sweep_ids()? {
            if store.scans_of_sweep(id)?.iter().all(|s| s.state.is_final()) {
                ended.insert(id);
            }
        }
        Ok(Self {
            notifier,
            seen,
            ended,
        })
    }

    /// Looks at `scan` as it changed: notices what it now calls for, if it did not
    /// before, and the end of its sweep when this was its sweep's last scan to end.
    pub fn changed(&mut self, store: &Store, scan: &ScanRecord) -> Result<(), StoreError> {
        let now = calls_for(scan);
        let before = self.seen.insert(scan.id, now).flatten();
        if let Some(event) = now.filter(|e| Some(*e) != before) {
            self.notifier.send(Notice {
                event,
                scan_id: scan.id,
                sweep_id: scan.sweep_id,
                sample: scan.plan.sample.clone(),
                state: scan.state.as_str().to_owned(),
                reason: scan.error.clone().unwrap_or_default(),
            });
        }
        let Some(sweep_id) = scan.sweep_id else {
            return Ok(());
        };
        if !scan.state.is_final() {
            // A scan of an ended sweep resumed: the sweep's next end is noticed again.
            self.ended.remove(&sweep_id);
            return Ok(());
        }
        if self.ended.contains(&sweep_id) {
            return Ok(());
        }
        let scans = store.scans_of_sweep(sweep_id)?;
        if !scans.iter().all(|s| s.state.is_final()) {
            return Ok(());
        }
        self.ended.insert(sweep_id);
        let count = |state: ScanState| scans.iter().filter(|s| s.state == state).count();
        self.notifier.send(Notice {
            event: "sweep-ended",
            scan_id: scan.id,
            sweep_id: Some(sweep_id),
            sample: scan.plan.sample.clone(),
            state: sweep_state(&scans, None, now_unix()).to_owned(),
            reason: format!(
                "{} done, {} failed, {} cancelled",
                count(ScanState::Done),
                count(ScanState::Failed),
                count(ScanState::Cancelled)
            ),
        });
        Ok(())
    }
}
