//! The processing lane: one thread that runs the processing steps of every scan as
//! soon as their inputs exist (docs/ARCHITECTURE.md, "Daemon"), in journal order,
//! while the hardware lane goes on capturing. Two kinds of step run in the background,
//! beside the others, one of each kind at a time ([`Step::runs_beside`]): an HDR step as
//! soon as its bracket is captured (a θL's map is an input of no other step), and the
//! fit that chooses the model as soon as `samples.csv` is gathered, beside the fits of
//! the other models (it needs none of them; it shares their budget when it chooses
//! one of them as they are fitted, see [`process::Budgets`]).
//! A step that was running when the daemon stopped is run again. With nothing to run,
//! it decodes the frames of the bracket being captured ahead of their HDR step.
//!
//! Its parallel work runs on its own thread pool at a lower priority than the rest of
//! the daemon, so the hardware lane (and an emulated camera's rendering, on the
//! global pool) never waits for it.

use std::path::{Path, PathBuf};
use std::sync::{mpsc, Arc};
use std::time::Duration;

use super::backoff::{Backoff, Failures};
use super::step::{self, Outcome, StepError};
use crate::plan::{Lane, ScanPlan, Step};
use crate::process::{self, Prefetched};
use crate::shared::Shared;
use crate::step_guard;
use crate::storage::{self, Probe};
use crate::store::{now_rfc3339, ScanState, StepRecord, Store, StoreError, PROCESSABLE};

/// How often the lane looks for ready steps when nothing wakes it.
const IDLE_POLL: Duration = Duration::from_millis(500);

/// A step running on the lane's pool beside the others: scan id and step index.
type Background = (i64, u32);

/// What a background step hands back: its scan id and step index, its outcome, and
/// the frames decoded ahead if it took them (an HDR step).
type Finished = (i64, u32, Outcome, Option<Prefetched>, String);

/// The processing lane's state.
pub struct ProcessingLane {
    shared: Arc<Shared>,
    store: Store,
    prefetched: Prefetched,
    /// The steps running beside the others, and where they send their outcome.
    background: Vec<Background>,
    finished: (mpsc::Sender<Finished>, mpsc::Receiver<Finished>),
    /// The budgets of the scans' fits, shared between the fits in the foreground and
    /// the one in the background.
    budgets: Arc<process::Budgets>,
    /// When to look at the free space again after a step did not fit.
    disk_retry: Backoff,
}

impl ProcessingLane {
    pub fn new(shared: Arc<Shared>, store: Store) -> Self {
        Self {
            shared,
            store,
            prefetched: Prefetched::default(),
            background: Vec::new(),
            finished: mpsc::channel(),
            budgets: Arc::default(),
            disk_retry: Backoff::now(),
        }
    }

    /// Runs forever on a thread pool of its own, at a lower priority, with a thread per
    /// core beside the lane's own: the lane's thread waits for the background step
    /// most of the time (blocked, not stealing its work), and the step's parallel
    /// parts must still get every core.
    pub fn run(self) {
        let threads = std::thread::available_parallelism().map_or(2, |n| n.get()) + 1;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|n| format!("processing-{n}"))
            .start_handler(|_| {
                step_guard::mark_lane(Lane::Processing);
                lower_priority()
            })
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
        let mut failures = Failures::default();
        loop {
            match self.turn() {
                Ok(()) => failures.ok("processing lane"),
                Err(err) => std::thread::sleep(failures.failed("processing lane", &err)),
            }
        }
    }

    /// One turn of the lane: makes the journal's reserve again if the store used it and
    /// there is room, records the finished background steps, starts the next steps that
    /// run beside the others in the background (a captured bracket's map, the longest
    /// step, and the auto fit: so first), then runs the next other step, or waits for a
    /// background one, or decodes ahead.
    fn turn(&mut self) -> Result<(), StoreError> {
        if self
            .shared
            .storage
            .keep_journal_reserve()
            .is_ok_and(|made| made)
        {
            tracing::info!("space held for the journal again");
        }
        self.collect(false)?;
        while let Some((id, step)) = self.store.next_beside(&self.background)? {
            if !self.fits(id, &step)? {
                return self.wait_for_space();
            }
            if !self.start_background(id, &step)? {
                break;
            }
        }
        match self.store.next_for_processing(&self.background)? {
            // One step of a kind beside the others at a time: the next waits for the
            // running one.
            Some((_, record)) if record.step.runs_beside() && !self.background.is_empty() => {
                self.collect(true)
            }
            Some((id, record)) if !self.fits(id, &record)? => self.wait_for_space(),
            Some((id, record)) => self.run_step(id, &record),
            // Nothing else to do: wait for a background step.
            None if !self.background.is_empty() => self.collect(true),
            None => {
                if !self.prefetch()? {
                    // A timeout and a wake-up both mean: look again.
                    self.shared.processing_wake.take(IDLE_POLL);
                }
                Ok(())
            }
        }
    }

    /// Whether what step `record` of scan `id` writes fits above the journal's reserve;
    /// if not, the scan waits for space (the hardware lane queues it again once there
    /// is), and the lane looks again with backoff.
    fn fits(&mut self, id: i64, record: &StepRecord) -> Result<bool, StoreError> {
        if !self.disk_retry.due() {
            return Ok(false);
        }
        let Some(scan) = self.store.scan(id)? else {
            return Ok(false);
        };
        let setup =
            gonio_processing::extract::read_setup(&self.shared.scan_dir(id).join("setup.json"));
        let pixels = storage::frame_pixels(setup.ok().as_ref());
        let need = storage::step_need(&record.step, &scan.plan, pixels);
        match self.shared.storage.check(need) {
            Ok(()) => {
                self.disk_retry = Backoff::now();
                Ok(true)
            }
            Err(reason) => {
                self.disk_retry = self.disk_retry.later();
                let waits = scan.state == ScanState::Waiting
                    && scan.error.as_deref().is_some_and(storage::is_disk_wait);
                if !waits {
                    tracing::warn!("scan {id} waiting: {reason}");
                    self.store
                        .log(self.shared.boot, Some(id), "wait", &reason)?;
                    self.store
                        .transition(id, &PROCESSABLE, ScanState::Waiting, Some(&reason))?;
                    self.shared.changed(id);
                }
                Ok(false)
            }
        }
    }

    /// Waits while no step fits on the disk (the background steps, if any, go on).
    fn wait_for_space(&mut self) -> Result<(), StoreError> {
        self.collect(false)?;
        self.shared.processing_wake.take(IDLE_POLL);
        Ok(())
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

    /// Starts step `record` of scan `id` in the background, an HDR step with the frames
    /// decoded ahead; returns whether it started (not if the scan is gone).
    fn start_background(&mut self, id: i64, record: &StepRecord) -> Result<bool, StoreError> {
        let Some(scan) = self.store.scan(id)? else {
            return Ok(false);
        };
        step::begin(&self.shared, &mut self.store, id, record.index)?;
        let dir = self.shared.scan_dir(id);
        let takes_frames = matches!(record.step, Step::Hdr { .. });
        let mut prefetched = if takes_frames {
            std::mem::take(&mut self.prefetched)
        } else {
            Prefetched::default()
        };
        let step = record.step.clone();
        let storage = self.shared.storage.clone();
        let budgets = Arc::clone(&self.budgets);
        let sender = self.finished.0.clone();
        let index = record.index;
        rayon::spawn(move || {
            let outcome = run(&step, &dir, &scan.plan, &mut prefetched, &budgets, &storage);
            // The lane holds the receiver as long as it runs; it records the step when
            // its own step is done, with the time it ended here.
            let prefetched = takes_frames.then_some(prefetched);
            let _ = sender.send((id, index, outcome, prefetched, now_rfc3339()));
        });
        self.background.push((id, index));
        Ok(true)
    }

    /// Records the outcomes of the background steps that have one (waiting for one at
    /// least if `wait` and one runs), and takes back the frames decoded ahead.
    fn collect(&mut self, wait: bool) -> Result<(), StoreError> {
        let mut received = Vec::new();
        while let Ok(finished) = self.finished.1.try_recv() {
            received.push(finished);
        }
        if received.is_empty() && wait && !self.background.is_empty() {
            // The lane holds a sender itself: the channel never disconnects.
            received.extend(self.finished.1.recv().ok());
        }
        for (id, index, outcome, prefetched, finished) in received {
            self.background.retain(|b| *b != (id, index));
            if let Some(prefetched) = prefetched {
                self.prefetched = prefetched;
            }
            self.finish(id, index, outcome, &finished)?;
        }
        Ok(())
    }

    fn run_step(&mut self, id: i64, record: &StepRecord) -> Result<(), StoreError> {
        let Some(scan) = self.store.scan(id)? else {
            return Ok(());
        };
        step::begin(&self.shared, &mut self.store, id, record.index)?;
        let dir = self.shared.scan_dir(id);
        let outcome = run(
            &record.step,
            &dir,
            &scan.plan,
            &mut self.prefetched,
            &self.budgets,
            &self.shared.storage,
        );
        self.finish(id, record.index, outcome, &now_rfc3339())
    }

    /// Records the outcome of step `index` of scan `id`.
    /// Records the outcome of a step that ended at `finished` (RFC 3339).
    fn finish(
        &mut self,
        id: i64,
        index: u32,
        outcome: Outcome,
        finished: &str,
    ) -> Result<(), StoreError> {
        step::finish_at(
            &self.shared,
            &mut self.store,
            id,
            index,
            &PROCESSABLE,
            outcome,
            finished,
        )?;
        // The hardware lane may be waiting for a bracket to be processed.
        self.shared.hardware_wake.post(|wake| *wake = true);
        Ok(())
    }
}

/// Runs processing step `step` of a scan planned as `plan` in `dir`; a panic fails
/// the step, not the daemon, and a full disk makes the scan wait for space.
fn run(
    step: &Step,
    dir: &Path,
    plan: &ScanPlan,
    prefetched: &mut Prefetched,
    budgets: &process::Budgets,
    storage: &Probe,
) -> Outcome {
    step_guard::run_processing(&step.describe(), || {
        process::run(step, dir, plan, prefetched, budgets)
    })
    .map(|result| (result, Vec::new()))
    .map_err(|message| {
        if storage::says_disk_full(&message) {
            tracing::warn!("{message}");
            let setup = gonio_processing::extract::read_setup(&dir.join("setup.json"));
            let pixels = storage::frame_pixels(setup.ok().as_ref());
            StepError::Waiting(storage.full_reason(storage::step_need(step, plan, pixels)))
        } else {
            StepError::Failed(message)
        }
    })
}

/// How much less urgent the processing threads are than the others (nice levels).
const NICER_BY: i32 = 10;

/// Lowers the calling thread's scheduling priority by [`NICER_BY`] (on Linux the nice
/// value is per thread); a failure leaves it as it is.
pub(super) fn lower_priority() {
    #[cfg(unix)]
    // SAFETY: getpriority and setpriority only read and set the calling thread's nice
    // value; errors are reported through the return value, which is ignored (the
    // thread then keeps its priority).
    unsafe {
        let now = libc::getpriority(libc::PRIO_PROCESS, 0);
        libc::setpriority(libc::PRIO_PROCESS, 0, (now + NICER_BY).min(19));
    }
}
