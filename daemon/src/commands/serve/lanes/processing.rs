//! The processing lane: one thread that runs the processing steps of every scan as
//! soon as their inputs exist (docs/ARCHITECTURE.md, "Daemon"), in journal order,
//! while the hardware lane goes on capturing. A step that was running when the daemon
//! stopped is run again. With nothing to run, it decodes the frames of the bracket
//! being captured ahead of their HDR step.
//!
//! Its parallel work runs on its own thread pool at a lower priority than the rest of
//! the daemon, so the hardware lane (and an emulated camera's rendering, on the
//! global pool) never waits for it.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use super::step::{self, Outcome, StepError};
use crate::commands::serve::process::{self, Prefetched};
use crate::commands::serve::shared::Shared;
use crate::commands::serve::step_guard;
use crate::commands::serve::store::{StepRecord, Store, StoreError, PROCESSABLE};

/// How often the lane looks for ready steps when nothing wakes it.
const IDLE_POLL: Duration = Duration::from_millis(500);

/// The processing lane's state.
pub struct ProcessingLane {
    shared: Arc<Shared>,
    store: Store,
    prefetched: Prefetched,
}

impl ProcessingLane {
    pub fn new(shared: Arc<Shared>, store: Store) -> Self {
        Self {
            shared,
            store,
            prefetched: Prefetched::default(),
        }
    }

    /// Runs forever on a thread pool of its own, at a lower priority.
    pub fn run(self) {
        let pool = rayon::ThreadPoolBuilder::new()
            .thread_name(|n| format!("processing-{n}"))
            .start_handler(|_| lower_priority())
            .build();
        match pool {
            Ok(pool) => pool.install(|| self.work()),
            Err(err) => {
                tracing::warn!("processing lane on the global thread pool: {err}");
                self.work()
            }
        }
    }

    fn work(mut self) {
        loop {
            match self.store.next_for_processing() {
                Ok(Some((id, step))) => {
                    if let Err(err) = self.run_step(id, &step) {
                        tracing::error!("processing lane: {err}");
                        std::thread::sleep(Duration::from_secs(1));
                    }
                }
                Ok(None) => match self.prefetch() {
                    Ok(true) => {}
                    // A timeout and a wake-up both mean: look again.
                    Ok(false) => {
                        self.shared.processing_wake.take(IDLE_POLL);
                    }
                    Err(err) => {
                        tracing::error!("processing lane: {err}");
                        std::thread::sleep(Duration::from_secs(1));
                    }
                },
                Err(err) => {
                    tracing::error!("processing lane: {err}");
                    std::thread::sleep(Duration::from_secs(1));
                }
            }
        }
    }

    /// Decodes one frame awaiting its HDR step ahead of it; returns whether it did.
    fn prefetch(&mut self) -> Result<bool, StoreError> {
        let wanted: Vec<PathBuf> = self
            .store
            .frames_awaiting_hdr()?
            .into_iter()
            .map(|(id, path)| self.shared.scan_dir(id).join(path))
            .collect();
        Ok(self.prefetched.advance(&wanted))
    }

    fn run_step(&mut self, id: i64, record: &StepRecord) -> Result<(), StoreError> {
        let Some(scan) = self.store.scan(id)? else {
            return Ok(());
        };
        step::begin(&self.shared, &mut self.store, id, record.index)?;
        let dir = self.shared.scan_dir(id);
        // A panic fails the step, not the daemon.
        let outcome: Outcome = step_guard::run_processing(&record.step.describe(), || {
            process::run(&record.step, &dir, &scan.plan, &mut self.prefetched)
        })
        .map(|result| (result, Vec::new()))
        .map_err(StepError::Failed);
        step::finish(
            &self.shared,
            &mut self.store,
            id,
            record.index,
            &PROCESSABLE,
            outcome,
        )?;
        // The hardware lane may be waiting for a bracket to be processed.
        self.shared.hardware_wake.post(|wake| *wake = true);
        Ok(())
    }
}

/// How much less urgent the processing threads are than the others (nice levels).
const NICER_BY: i32 = 10;

/// Lowers the calling thread's scheduling priority by [`NICER_BY`] (on Linux the nice
/// value is per thread); a failure leaves it as it is.
fn lower_priority() {
    #[cfg(unix)]
    // SAFETY: getpriority and setpriority only read and set the calling thread's nice
    // value; errors are reported through the return value, which is ignored (the
    // thread then keeps its priority).
    unsafe {
        let now = libc::getpriority(libc::PRIO_PROCESS, 0);
        libc::setpriority(libc::PRIO_PROCESS, 0, (now + NICER_BY).min(19));
    }
}
